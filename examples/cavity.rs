//! Lid-driven cavity against Ghia, Ghia & Shin (1982).
//!
//! ```text
//! cargo run --release --example cavity                                  # Re 100, n = 50
//! cargo run --release --example cavity -- --re 1000 --n 100 --out results/re1000
//! ```
//!
//! Writes into `--out` (default `results/cavity_re{Re}_n{n}`): `profile_u.csv` (`y,u` along
//! x = 0.5), `profile_v.csv` (`x,v` along y = 0.5), `summary.json` (errors against Ghia in units of
//! the lid speed, run time, how steadiness was judged, the configuration), `profiles.png` and
//! `particles.png`; with `--particles-csv` also `particles.csv` (`x,y,u,v,p` of the fluid
//! particles at the end).

use anyhow::{Context, Result};
use clap::Parser;
use gpm::flow::{Integrator, Motion, Shifting, VolumeRule};
use gpm::kernel::Weight;
use gpm::poisson::SolverKind;
use gpm::projection::Scheme;
use gpm::record::{RecordLevel, RecorderOptions};
use gpm::scene::cavity::CavityConfig;
use gpm::scene::run_recorded;
use indicatif::{ProgressBar, ProgressStyle};
use std::ops::ControlFlow;
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

#[derive(Parser, Debug)]
#[command(about = "Lid-driven cavity with the GPM projection, compared with Ghia et al. (1982)")]
struct Args {
    /// Reynolds number U L / ν (Ghia tables are embedded for 100, 400, 1000, 3200, 5000, 7500
    /// and 10000).
    #[arg(long, default_value_t = 100.0)]
    re: f64,
    /// Fluid particles per side.
    #[arg(long, default_value_t = 50)]
    n: usize,
    /// End time (the run stops earlier once steady); default Re/5 within [40, 800], about
    /// twice the time the cavity takes to settle.
    #[arg(long)]
    t_end: Option<f64>,
    /// Pressure scheme: non-incremental, incremental, rotational.
    #[arg(long, default_value = "rotational")]
    scheme: Scheme,
    /// Gradient of the predictor and the correction: difference (∇h, default) or renormalised.
    #[arg(long, default_value = "difference")]
    gradient: gpm::consistent::GradientKind,
    /// Reference weight: cubic, wendland2, wendland4, polyP-M (r^P (1-r)^M).
    #[arg(long, default_value = "wendland2")]
    weight: Weight,
    /// Influence radius over particle spacing, h/Δx (default 2.5 for fixed particles, 3 with
    /// --motion lagrangian).
    #[arg(long)]
    h_ratio: Option<f64>,
    /// Particle frame: eulerian (fixed particles) or lagrangian (advected + shifting).
    #[arg(long, default_value = "eulerian")]
    motion: Motion,
    /// Integrator of the explicit terms: ab2 or euler.
    #[arg(long, default_value = "ab2")]
    integrator: Integrator,
    /// Convective term (Eulerian frame): skew-symmetric, central, upwind, muscl or
    /// muscl-van-leer.
    #[arg(long, default_value = "skew-symmetric")]
    convection: gpm::flow::ConvectionForm,
    /// Implicit weight of the viscous term (0.5 Crank–Nicolson, 0 explicit).
    #[arg(long, default_value_t = 0.5)]
    theta: f64,
    /// Lagrangian Fickian shifting coefficient A, added to the cavity's shifting (pair
    /// repulsion and volume shift; 0 disables shifting altogether).
    #[arg(long)]
    shift: Option<f64>,
    /// β of the Lagrangian volume shift (`shifting.volume`; default 2, 0 disables it).
    #[arg(long)]
    volume_shift: Option<f64>,
    /// Keep the initial volumes instead of ω = 1/Σw.
    #[arg(long)]
    fixed_volumes: bool,
    /// CFL number on h/U (default 0.2; with --motion lagrangian 0.15 up to a cell Reynolds number Re/n of 4, 0.1 above).
    #[arg(long)]
    cfl: Option<f64>,
    /// Linear solver: cholesky, cg, auto.
    #[arg(long, default_value = "auto")]
    solver: SolverKind,
    /// Steadiness tolerance on max|Δprofile|/Δt (units U²/L).
    #[arg(long)]
    steady_tol: Option<f64>,
    /// Averaging window for the profiles (time units).
    #[arg(long)]
    average: Option<f64>,
    /// Continuation of the Poisson source into wall ghosts: auto (mirror for moving particles,
    /// rest-walls for fixed ones with the GPM operators, no-slip with the consistent ones),
    /// mirror, no-slip, rest-walls (no-slip images across the walls at rest, the mirror
    /// across the lid and at its corners, the two blended within the scene key `source_band`,
    /// ¼ side, of the lid), or rest-walls-linear (rest-walls with the lid's ghosts continued
    /// linearly along the normal from their source and the particle below it; fixed
    /// particles). Before 2026-11-29 auto was the mirror on fixed particles too, with
    /// h = 3Δx: `--source-ghosts mirror --h-ratio 3` reproduces those runs.
    #[arg(long, default_value = "auto")]
    source_ghosts: gpm::scene::cavity::SourceGhosts,
    /// Width of the lid's corner ramp in side lengths (0: the classic lid, discontinuous at the
    /// corners; up to 0.5).
    #[arg(long, default_value_t = 0.0)]
    lid_ramp: f64,
    /// Subtract the lid corners' singular Stokes flow (Botella & Peyret 1998; the scene key
    /// `corner_subtraction`, module `gpm::scene::corner`): fixed particles and the classic lid
    /// only; the reported pressure is then the regular part's.
    #[arg(long)]
    corner_subtraction: bool,
    /// Operator set: auto (gpm on the lattice, consistent for moving particles), gpm or
    /// consistent.
    #[arg(long, default_value = "auto")]
    operators: gpm::scene::OperatorSet,
    /// Laplacian of the viscous term: gpm or least-squares (default: least-squares, the
    /// cavity's).
    #[arg(long)]
    laplacian: Option<gpm::consistent::LaplacianKind>,
    /// Output directory.
    #[arg(long)]
    out: Option<PathBuf>,
    /// Recording into OUT/run.mcap: none, diagnostics (every step) or full (also particles and
    /// projection inputs every --record-every steps).
    #[arg(long, default_value = "diagnostics")]
    record: RecordLevel,
    /// Steps between particle snapshots at --record full.
    #[arg(long, default_value_t = 10)]
    record_every: u64,
    /// No progress bar.
    #[arg(long)]
    quiet: bool,
    /// Also write the final fluid particles into OUT/particles.csv (`x,y,u,v,p`), e.g. for
    /// `tools/peer/errors.py`.
    #[arg(long)]
    particles_csv: bool,
    /// Warm start: the velocity and pressure of another run's OUT/particles.csv (written with
    /// --particles-csv, any resolution), sampled at this run's particles before the first step.
    #[arg(long)]
    initial: Option<PathBuf>,
}

/// The example's end time when `--t-end` is not given: `Re/5` within `[40, 800]`, about twice
/// the time the run needs to settle (it stops once steady). Measured with the defaults: Re 100
/// steady at t ≈ 17, Re 400 at 37.5, Re 1000 at ≈ 85, Re 3200 at n = 64 at 352, Re 5000 at
/// n = 128 at 566 (its slowest mode decays over ≈ 80 time units); Re 10 000 does not settle
/// at n = 128 and runs to t = 800.
fn default_t_end(re: f64) -> f64 {
    (0.2 * re).clamp(40.0, 800.0)
}

fn config(a: &Args) -> CavityConfig {
    let mut cfg = CavityConfig::default().with(|c| {
        c.re = a.re;
        c.n = a.n;
        c.scheme = a.scheme;
        c.gradient = a.gradient;
        c.weight = a.weight;
        c.h_over_dx = a
            .h_ratio
            .unwrap_or(gpm::scene::cavity::default_h_ratio(a.motion));
        c.motion = a.motion;
        c.integrator = a.integrator;
        c.convection = a.convection;
        c.viscous_theta = a.theta;
        c.scene.source_ghosts = a.source_ghosts;
        c.scene.lid_ramp = a.lid_ramp;
        c.scene.corner_subtraction = a.corner_subtraction;
        c.operators = a.operators;
        if a.laplacian.is_some() {
            c.laplacian = a.laplacian;
        }
        c.t_end = a.t_end.unwrap_or(default_t_end(a.re));
        c.initial = a.initial.clone();
    });
    if let Some(s) = a.shift {
        cfg.shifting = (s > 0.0).then(|| Shifting {
            coefficient: s,
            ..cfg.shifting.unwrap_or_default()
        });
    }
    if let (Some(b), Some(sh)) = (a.volume_shift, cfg.shifting.as_mut()) {
        sh.volume = b;
    }
    if a.fixed_volumes {
        cfg.volumes = VolumeRule::Fixed;
    }
    // the Lagrangian cavity needs a smaller step than the default CFL factor (above a cell
    // Reynolds number of 4, a smaller one still: `scene::cavity::lagrangian_cfl`)
    cfg.limits.cfl = a.cfl.unwrap_or(cfg.default_cfl());
    if let Some(t) = a.steady_tol {
        cfg.scene.steady.tol = t;
    }
    if let Some(w) = a.average {
        cfg.scene.steady.average_window = w;
    }
    cfg.solve.solver = a.solver;
    // `summary.json`'s configuration names the rule `auto` stands for in this run
    cfg.scene.source_ghosts = cfg.scene.source_ghosts.resolve::<2>(&cfg);
    cfg
}

fn run(a: Args) -> Result<ExitCode> {
    let cfg = config(&a);
    cfg.validate().context("invalid configuration")?;
    let out = a
        .out
        .clone()
        .unwrap_or_else(|| PathBuf::from(format!("results/cavity_re{}_n{}", cfg.re, cfg.n)));
    let bar = if a.quiet {
        ProgressBar::hidden()
    } else {
        let b = ProgressBar::new(1000);
        b.set_style(
            ProgressStyle::with_template("{spinner} t = {msg} [{bar:40}] {elapsed_precise}")
                .expect("valid template"),
        );
        b
    };
    std::fs::create_dir_all(&out).with_context(|| format!("creating {out:?}"))?;
    let mcap = out.join("run.mcap");
    // Ctrl-C stops the run after the current step; the recording is then finished cleanly
    let stop = Arc::new(AtomicBool::new(false));
    {
        let stop = stop.clone();
        ctrlc::set_handler(move || stop.store(true, Ordering::SeqCst))
            .context("installing the Ctrl-C handler")?;
    }
    let t_end = cfg.t_end;
    let done = run_recorded(
        &cfg,
        &mcap,
        RecorderOptions::new(a.record, a.record_every),
        &cfg.record_header(),
        |_| {},
        |rep, _| {
            bar.set_position((1000.0 * rep.time / t_end) as u64);
            bar.set_message(format!(
                "{:.2} step {} ke {:.5}",
                rep.time, rep.step, rep.projection.kinetic_energy
            ));
            Ok(if stop.load(Ordering::SeqCst) {
                ControlFlow::Break(())
            } else {
                ControlFlow::Continue(())
            })
        },
    )?;
    bar.finish_and_clear();
    // the recording is finished whatever happened, so that every recorded step reads back
    let run = match done.run {
        Ok(run) => run,
        Err(e) => {
            if let Err(fe) = &done.record {
                eprintln!("error: finishing {} failed: {fe}", mcap.display());
            } else if let Some(p) = done.record.as_ref().ok().and_then(|s| s.path.as_ref()) {
                eprintln!("the recording up to the failure is in {}", p.display());
            }
            return Err(e).context("cavity run failed");
        }
    };
    let summary = done
        .record
        .with_context(|| format!("finishing {}", mcap.display()))?;
    for note in &summary.notes {
        eprintln!("note: {note}");
    }
    if let Some(step) = run.interrupted() {
        eprintln!(
            "interrupted after step {step}; {} finished cleanly ({} steps)",
            mcap.display(),
            summary.steps
        );
        return Ok(ExitCode::from(130));
    }
    run.write_tables(&out, &cfg)
        .with_context(|| format!("writing tables into {out:?}"))?;
    run.write_plots(&out, &cfg).context("writing plots")?;
    if a.particles_csv {
        let path = out.join("particles.csv");
        std::fs::write(&path, run.sim.particles.fluid_csv())
            .with_context(|| format!("writing {}", path.display()))?;
    }
    let res = &run.result;
    println!(
        "cavity Re {} n {} ({} fluid particles): {} steps to t = {:.2}, {:.1} s wall",
        res.re, res.n, res.particles, res.steps, res.t_end, res.wall_seconds
    );
    match res.steady_time {
        Some(ts) => println!(
            "steady at t = {ts:.2} (max|Δprofile|/Δt = {:.1e} < {:.0e}); profiles averaged over {} samples",
            res.steady_rate, cfg.scene.steady.tol, res.averaged_samples
        ),
        None => println!(
            "NOT steady by t = {:.2} (max|Δprofile|/Δt = {:.1e}, tolerance {:.0e})",
            res.t_end, res.steady_rate, cfg.scene.steady.tol
        ),
    }
    if let Some(d) = res.steady_distance {
        println!(
            "estimated distance of the reported profiles from the steady ones: {d:.1e} (lid-speed units)"
        );
    }
    if let Some(g) = res.ghia {
        println!(
            "error vs Ghia et al. (1982), lid-speed units: u RMS {:.4} max {:.4} | v RMS {:.4} max {:.4}",
            g.rms_u, g.max_u, g.rms_v, g.max_v
        );
    } else {
        println!(
            "no Ghia table for Re = {} (tables: {:?})",
            res.re,
            gpm::reference::GHIA_RE
        );
    }
    if let Some(g) = res.reference {
        println!(
            "error vs the extrapolated reference:          u RMS {:.4} max {:.4} | v RMS {:.4} max {:.4}",
            g.rms_u, g.max_u, g.rms_v, g.max_v
        );
    }
    if a.record != RecordLevel::None {
        println!(
            "recorded {} steps into {} ({} bytes); inspect with `cargo run --release --bin gpm -- replay {}`",
            summary.steps,
            mcap.display(),
            summary.bytes,
            mcap.display()
        );
    }
    println!(
        "max Theorem 4.5 ratio {:.3}, c0 in [{:.4}, {:.4}]; outputs in {}",
        res.monitor.max_stability_ratio,
        res.monitor.c0_min,
        res.monitor.c0_max,
        out.display()
    );
    Ok(ExitCode::SUCCESS)
}

fn main() -> ExitCode {
    match run(Args::parse()) {
        Ok(code) => code,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}
