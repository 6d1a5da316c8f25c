//! Plane Poiseuille flow between no-slip walls, periodic along the channel, driven by a body
//! force: the test of a projection on disordered particles (the channel scene,
//! `gpm::scene::channel`).
//!
//! ```text
//! cargo run --release --example poiseuille                          # lattice, n = 32
//! cargo run --release --example poiseuille -- --jitter 0.1 --out results/poiseuille_j01
//! cargo run --release --example poiseuille -- --study               # jitter × scheme table
//! ```
//!
//! Defaults: channel height 1, body force G = 1, ν = 0.1 (steady centre speed G/(8ν) = 1.25),
//! t = 20 (steady), n = 32 particles across, fixed particles (Eulerian frame).
//!
//! Writes into `--out`: `profile.csv` (header `y,u`: every fluid particle's height and
//! x-velocity at the end), `summary.json` (`G`, `nu`, `max_rel_error` = max |u − u_exact| / u_max
//! over the fluid particles, `rms_rel_error`, `centre_speed_ratio`, `wall_seconds`, the monitor's
//! ranges and the configuration), `profile.png` and `run.mcap`.
//!
//! `--operators` picks the operator set: `auto` (default: the least-squares operators of
//! `ProjectionParams::with_consistent_operators` on jittered particles, the GPM ones on the
//! lattice), `gpm` or `consistent`.
//!
//! `--study` runs jitter 0, 0.1, 0.3 × the three pressure schemes × {GPM operators with plain
//! pair weights, GPM operators with moment-consistent weights, least-squares operators} and
//! writes `study.csv`.

use anyhow::{Context, Result};
use clap::Parser;
use gpm::flow::Motion;
use gpm::projection::Scheme;
use gpm::record::{RecordLevel, RecorderOptions};
use gpm::scene::channel::{run, ChannelConfig};
use gpm::scene::run_recorded;
use std::io::Write;
use std::ops::ControlFlow;
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

#[derive(Parser, Debug)]
#[command(about = "Plane Poiseuille flow (periodic channel, body force) against the exact profile")]
struct Args {
    /// Jitter of the initial positions, as a fraction of the particle spacing (0 ≤ F ≤ 0.45).
    #[arg(long, default_value_t = 0.0)]
    jitter: f64,
    /// Seed of the jitter.
    #[arg(long, default_value_t = 7)]
    seed: u64,
    /// Particles across the channel.
    #[arg(long, default_value_t = 32)]
    n: usize,
    /// Body force G along the channel.
    #[arg(long, default_value_t = 1.0)]
    g: f64,
    /// Kinematic viscosity ν.
    #[arg(long, default_value_t = 0.1)]
    nu: f64,
    /// End time.
    #[arg(long, default_value_t = 20.0)]
    t_end: f64,
    /// Pressure scheme: non-incremental, incremental, rotational.
    #[arg(long, default_value = "rotational")]
    scheme: Scheme,
    /// Pair weights: plain (GPM's w/r²) or moment (moment-consistent, `gpm::pair_weights`).
    #[arg(long, default_value = "plain")]
    weights: gpm::pair_weights::PairWeights,
    /// Operator set: auto (consistent on jittered or moving particles), gpm or consistent.
    #[arg(long, default_value = "auto")]
    operators: gpm::scene::OperatorSet,
    /// Particle frame: eulerian (fixed particles) or lagrangian.
    #[arg(long, default_value = "eulerian")]
    motion: Motion,
    /// CFL number on h/U.
    #[arg(long)]
    cfl: Option<f64>,
    /// Run the jitter × scheme study instead of one run (writes study.csv).
    #[arg(long)]
    study: bool,
    /// Output directory.
    #[arg(long, default_value = "results/poiseuille")]
    out: PathBuf,
    /// Recording into OUT/run.mcap: none, diagnostics or full.
    #[arg(long, default_value = "diagnostics")]
    record: RecordLevel,
    /// Steps between particle snapshots at --record full.
    #[arg(long, default_value_t = 10)]
    record_every: u64,
}

fn config(a: &Args) -> Result<ChannelConfig> {
    anyhow::ensure!(
        a.nu.is_finite() && a.nu > 0.0,
        "--nu {} must be positive and finite",
        a.nu
    );
    anyhow::ensure!(
        a.g.is_finite() && a.g > 0.0,
        "--g {} must be positive and finite",
        a.g
    );
    let mut cfg = ChannelConfig::default().with(|c| {
        c.n = a.n;
        c.t_end = a.t_end;
        c.scheme = a.scheme;
        c.motion = a.motion;
        c.pair_weights = a.weights;
        c.operators = a.operators;
        c.scene.body_force = a.g;
        c.scene.jitter = a.jitter;
        c.scene.seed = a.seed;
        // Re = U_c H / ν with U_c = G H² / (8ν)
        c.re = a.g / (8.0 * a.nu * a.nu);
    });
    if let Some(c) = a.cfl {
        cfg.limits.cfl = c;
    }
    cfg.validate().context("invalid configuration")?;
    Ok(cfg)
}

fn study(a: &Args) -> Result<ExitCode> {
    std::fs::create_dir_all(&a.out)?;
    let path = a.out.join("study.csv");
    let mut f = std::fs::File::create(&path)?;
    writeln!(
        f,
        "jitter,operators,weights,scheme,n,max_rel_error,rms_rel_error,centre_speed_ratio,c0_min,c0_max,max_stability_ratio,max_correction_ratio,steps,wall_seconds,error"
    )?;
    println!(
        "{:>6} {:>10} {:>7} {:>16} {:>12} {:>12} {:>8} {:>8} {:>8} {:>8}",
        "jitter",
        "operators",
        "weights",
        "scheme",
        "max err/umax",
        "rms err",
        "centre",
        "c0 max",
        "ratio",
        "s"
    );
    use gpm::pair_weights::PairWeights;
    use gpm::scene::OperatorSet;
    // the GPM operators with the plain and the moment-consistent pair weights, and the
    // least-squares operators (what `auto` picks on disordered particles)
    let sets = [
        (OperatorSet::Gpm, PairWeights::Plain),
        (OperatorSet::Gpm, PairWeights::Moment),
        (OperatorSet::Consistent, PairWeights::Plain),
    ];
    for (jitter, (ops, weights)) in [0.0, 0.1, 0.3]
        .into_iter()
        .flat_map(|j| sets.map(|s| (j, s)))
    {
        for scheme in [
            Scheme::NonIncremental,
            Scheme::Incremental,
            Scheme::Rotational,
        ] {
            let mut cfg = config(a)?;
            cfg.scene.jitter = jitter;
            cfg.scheme = scheme;
            cfg.pair_weights = weights;
            cfg.operators = ops;
            let w = format!("{weights:?}").to_lowercase();
            let o = format!("{ops:?}").to_lowercase();
            match run(&cfg) {
                Ok(r) => {
                    let e = r.errors;
                    println!(
                        "{:>6} {:>10} {:>7} {:>16} {:>12.3e} {:>12.3e} {:>8.4} {:>8.4} {:>8.3} {:>8.2}",
                        jitter,
                        o,
                        w,
                        scheme.to_string(),
                        e.max_rel_error,
                        e.rms_rel_error,
                        e.centre_speed_ratio,
                        r.monitor.c0_max,
                        r.monitor.max_stability_ratio,
                        r.wall_seconds
                    );
                    writeln!(
                        f,
                        "{jitter},{o},{w},{scheme},{},{},{},{},{},{},{},{},{},{},",
                        cfg.n,
                        e.max_rel_error,
                        e.rms_rel_error,
                        e.centre_speed_ratio,
                        r.monitor.c0_min,
                        r.monitor.c0_max,
                        r.monitor.max_stability_ratio,
                        r.monitor.max_correction_ratio,
                        r.steps,
                        r.wall_seconds
                    )?;
                }
                Err(err) => {
                    let msg = err.to_string().replace([',', '\n'], ";");
                    println!(
                        "{jitter:>6} {o:>10} {w:>7} {:>16} failed: {msg}",
                        scheme.to_string()
                    );
                    writeln!(f, "{jitter},{o},{w},{scheme},{},,,,,,,,,,{msg}", cfg.n)?;
                }
            }
        }
    }
    println!("wrote {}", path.display());
    Ok(ExitCode::SUCCESS)
}

fn single(a: &Args) -> Result<ExitCode> {
    let cfg = config(a)?;
    std::fs::create_dir_all(&a.out)?;
    let mcap = a.out.join("run.mcap");
    let stop = Arc::new(AtomicBool::new(false));
    {
        let stop = stop.clone();
        ctrlc::set_handler(move || stop.store(true, Ordering::SeqCst))
            .context("installing the Ctrl-C handler")?;
    }
    let done = run_recorded(
        &cfg,
        &mcap,
        RecorderOptions::new(a.record, a.record_every),
        &cfg.record_header(),
        |_| {},
        |_, _| {
            Ok(if stop.load(Ordering::SeqCst) {
                ControlFlow::Break(())
            } else {
                ControlFlow::Continue(())
            })
        },
    )?;
    let run = match done.run {
        Ok(r) => r,
        Err(e) => {
            match &done.record {
                Ok(_) => eprintln!("the recording up to the failure is in {}", mcap.display()),
                Err(fe) => eprintln!("error: finishing {} failed: {fe}", mcap.display()),
            }
            return Err(e).context("channel run failed");
        }
    };
    let summary = done
        .record
        .with_context(|| format!("finishing {}", mcap.display()))?;
    if let Some(step) = run.interrupted() {
        eprintln!(
            "interrupted after step {step}; {} finished cleanly ({} steps)",
            mcap.display(),
            summary.steps
        );
        return Ok(ExitCode::from(130));
    }
    run.write_tables(&a.out, &cfg)?;
    run.write_plots(&a.out, &cfg)?;
    let res = &run.result;
    let e = res.errors;
    println!(
        "channel n {} jitter {} ({}, {}, {:?} operators, {:?} weights) t = {:.2} ({} steps, {:.2} s): max |u − u_exact|/u_max {:.3e}, RMS {:.3e}, centre speed {:.4} of exact",
        res.n,
        res.jitter,
        cfg.scheme,
        format!("{:?}", cfg.motion).to_lowercase(),
        cfg.operators,
        cfg.pair_weights,
        res.t_end,
        res.steps,
        res.wall_seconds,
        e.max_rel_error,
        e.rms_rel_error,
        e.centre_speed_ratio
    );
    println!(
        "monitor: c0 in [{:.4}, {:.4}], min spacing {:.4} Δx, max Thm 4.5 ratio {:.3}, max correction ratio {:.3e}; outputs in {}",
        res.monitor.c0_min,
        res.monitor.c0_max,
        res.monitor.min_spacing * cfg.n as f64,
        res.monitor.max_stability_ratio,
        res.monitor.max_correction_ratio,
        a.out.display()
    );
    Ok(ExitCode::SUCCESS)
}

fn main() -> ExitCode {
    let a = Args::parse();
    let r = if a.study { study(&a) } else { single(&a) };
    match r {
        Ok(code) => code,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}
