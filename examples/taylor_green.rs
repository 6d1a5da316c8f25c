//! Taylor–Green vortex on the periodic unit square against the exact solution (MISSION §5).
//!
//! ```text
//! cargo run --release --example taylor_green                      # n = 50, t = 2, Re 100
//! cargo run --release --example taylor_green -- --convergence     # spatial and temporal orders
//! ```
//!
//! `summary.json` holds `l1_velocity_error` (Σ|u − u_ex| / Σ|u_ex| over the particles),
//! `linf_decay_error` (relative error of the maximum speed against `U e^{−8π²t/Re}`),
//! `l1_pressure_error` (mean-free L1, relative) and `wall_seconds`.
//! `--particles-csv` also writes `particles.csv` (`x,y,u,v,p` of the particles at the end).
//!
//! **Convergence mode.** Spatial orders: n = 25, 50, 100, 200 at a fixed small Δt, against the
//! exact solution. Temporal orders: n fixed and Δt halved four times, each run compared with a
//! reference run on *the same particles* with Δt/16 of the smallest step: the spatial
//! discretisation is then identical in both runs and its error cancels exactly, leaving the
//! temporal error of each scheme.
#![allow(clippy::type_complexity, clippy::needless_range_loop)]

use anyhow::{Context, Result};
use clap::Parser;
use gpm::flow::{Integrator, Motion, Shifting};
use gpm::kernel::Weight;
use gpm::projection::Scheme;
use gpm::record::{RecordLevel, RecorderOptions};
use gpm::scene::run_recorded;
use gpm::scene::taylor_green::{build, run, TaylorGreenConfig};
use std::io::Write;
use std::ops::ControlFlow;
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

#[derive(Parser, Debug)]
#[command(about = "Taylor–Green vortex with the GPM projection, against the exact solution")]
struct Args {
    /// Particles per side.
    #[arg(long, default_value_t = 50)]
    n: usize,
    /// End time.
    #[arg(long, default_value_t = 2.0)]
    t_end: f64,
    /// Reynolds number.
    #[arg(long, default_value_t = 100.0)]
    re: f64,
    /// Pressure scheme: non-incremental, incremental, rotational.
    #[arg(long, default_value = "rotational")]
    scheme: Scheme,
    /// Gradient of the predictor and the correction: difference (∇h, default) or renormalised.
    #[arg(long, default_value = "difference")]
    gradient: gpm::consistent::GradientKind,
    /// Reference weight.
    #[arg(long, default_value = "wendland2")]
    weight: Weight,
    /// h/Δx.
    #[arg(long, default_value_t = 3.0)]
    h_ratio: f64,
    /// Particle frame: eulerian or lagrangian.
    #[arg(long, default_value = "eulerian")]
    motion: Motion,
    /// Integrator of the explicit terms: ab2 or euler.
    #[arg(long, default_value = "ab2")]
    integrator: Integrator,
    /// Convective term (Eulerian frame): skew-symmetric, central, upwind, muscl or
    /// muscl-van-leer.
    #[arg(long, default_value = "skew-symmetric")]
    convection: gpm::flow::ConvectionForm,
    /// Implicit viscous weight θ.
    #[arg(long, default_value_t = 0.5)]
    theta: f64,
    /// Laplacian of the viscous term: gpm or least-squares (default: the configuration's).
    #[arg(long)]
    laplacian: Option<gpm::consistent::LaplacianKind>,
    /// Lagrangian shifting coefficient (0 = none).
    #[arg(long)]
    shift: Option<f64>,
    /// CFL number on h/U.
    #[arg(long)]
    cfl: Option<f64>,
    /// Fixed time step.
    #[arg(long)]
    dt: Option<f64>,
    /// Run the convergence study instead of one run.
    #[arg(long)]
    convergence: bool,
    /// Smaller convergence study (CI-sized).
    #[arg(long)]
    quick: bool,
    /// Output directory.
    #[arg(long, default_value = "results/taylor_green")]
    out: PathBuf,
    /// Recording into OUT/run.mcap (single runs): none, diagnostics or full.
    #[arg(long, default_value = "diagnostics")]
    record: RecordLevel,
    /// Steps between particle snapshots at --record full.
    #[arg(long, default_value_t = 10)]
    record_every: u64,
    /// Also write the final fluid particles into OUT/particles.csv (`x,y,u,v,p`), e.g. for
    /// `tools/peer/errors.py`.
    #[arg(long)]
    particles_csv: bool,
}

fn config(a: &Args) -> TaylorGreenConfig {
    let mut cfg = TaylorGreenConfig::default().with(|c| {
        c.n = a.n;
        c.t_end = a.t_end;
        c.re = a.re;
        c.scheme = a.scheme;
        c.gradient = a.gradient;
        c.weight = a.weight;
        c.h_over_dx = a.h_ratio;
        c.motion = a.motion;
        c.integrator = a.integrator;
        c.convection = a.convection;
        c.viscous_theta = a.theta;
        if a.laplacian.is_some() {
            c.laplacian = a.laplacian;
        }
    });
    if let Some(s) = a.shift {
        cfg.shifting = (s > 0.0).then(|| Shifting {
            coefficient: s,
            ..Default::default()
        });
    }
    if let Some(c) = a.cfl {
        cfg.limits.cfl = c;
    }
    cfg.limits.dt_fixed = a.dt;
    cfg
}

/// Least-squares slope of log(err) against log(1/size) — positive means convergence.
fn order(pts: &[(f64, f64)]) -> f64 {
    let l: Vec<(f64, f64)> = pts.iter().map(|(s, e)| (s.ln(), e.ln())).collect();
    let m = l.len() as f64;
    let mx = l.iter().map(|p| p.0).sum::<f64>() / m;
    let my = l.iter().map(|p| p.1).sum::<f64>() / m;
    let sxy: f64 = l.iter().map(|p| (p.0 - mx) * (p.1 - my)).sum();
    let sxx: f64 = l.iter().map(|p| (p.0 - mx).powi(2)).sum();
    sxy / sxx
}

/// State at `t_end` with a fixed Δt: (velocities, pressures) at the (fixed) particles.
fn final_state(cfg: &TaylorGreenConfig) -> Result<(Vec<[f64; 2]>, Vec<f64>)> {
    let mut sim = build(cfg)?;
    let dt = cfg.limits.dt_fixed.expect("fixed dt");
    let steps = (cfg.t_end / dt).round() as usize;
    for _ in 0..steps {
        sim.advance()?;
    }
    let p = &sim.particles;
    let k = p.n_fluid();
    let mean = p.p[..k].iter().sum::<f64>() / k as f64;
    Ok((
        p.u[..k].to_vec(),
        p.p[..k].iter().map(|v| v - mean).collect(),
    ))
}

fn convergence(a: &Args) -> Result<()> {
    std::fs::create_dir_all(&a.out)?;
    let mut f = std::fs::File::create(a.out.join("convergence.csv"))?;
    writeln!(
        f,
        "study,scheme,n,dt,l1_velocity_error,l1_pressure_error,seconds"
    )?;
    let schemes = [
        Scheme::NonIncremental,
        Scheme::Incremental,
        Scheme::Rotational,
    ];
    // spatial: against the exact solution, small fixed Δt (CFL 0.1 on the finest h)
    let ns: Vec<usize> = if a.quick {
        vec![16, 32, 64]
    } else {
        vec![25, 50, 100, 200]
    };
    let t_space = if a.quick { 0.2 } else { a.t_end };
    println!("spatial convergence (t = {t_space}, against the exact solution):");
    println!(
        "{:>16} {:>5} {:>10} {:>12} {:>12} {:>8}",
        "scheme", "n", "dt", "L1(u)", "L1(p)", "s"
    );
    let mut space: Vec<(Scheme, Vec<(f64, f64, f64)>)> = Vec::new();
    let dt_s = 0.1 * a.h_ratio / *ns.last().unwrap() as f64;
    for &scheme in &schemes {
        let mut pts = Vec::new();
        for &n in &ns {
            let mut cfg = config(a);
            cfg.n = n;
            cfg.scheme = scheme;
            cfg.t_end = t_space;
            cfg.limits.dt_fixed = Some(t_space / (t_space / dt_s).ceil());
            let r = run(&cfg, |_, _| Ok(()))?;
            println!(
                "{:>16} {:>5} {:>10.2e} {:>12.4e} {:>12.4e} {:>8.2}",
                scheme.to_string(),
                n,
                cfg.limits.dt_fixed.unwrap(),
                r.errors.l1_velocity_error,
                r.errors.l1_pressure_error,
                r.wall_seconds
            );
            writeln!(
                f,
                "space,{scheme},{n},{},{},{},{}",
                cfg.limits.dt_fixed.unwrap(),
                r.errors.l1_velocity_error,
                r.errors.l1_pressure_error,
                r.wall_seconds
            )?;
            pts.push((
                n as f64,
                r.errors.l1_velocity_error,
                r.errors.l1_pressure_error,
            ));
        }
        space.push((scheme, pts));
    }
    // temporal: self-convergence on the same particles
    let n_t = if a.quick { 24 } else { a.n };
    let t_time = if a.quick { 0.2 } else { 1.0 };
    let dts: Vec<f64> = if a.quick {
        vec![0.02, 0.01, 0.005]
    } else {
        vec![0.02, 0.01, 0.005, 0.0025]
    };
    let dt_ref = dts.last().unwrap() / 16.0;
    println!(
        "\ntemporal convergence (n = {n_t}, t = {t_time}; each run against a reference with Δt = {dt_ref:.2e} on the same particles):"
    );
    println!(
        "{:>16} {:>10} {:>12} {:>12}",
        "scheme", "dt", "L1(u-uref)", "L1(p-pref)"
    );
    let mut time: Vec<(Scheme, Vec<(f64, f64, f64)>)> = Vec::new();
    for &scheme in &schemes {
        let mut cfg = config(a);
        cfg.n = n_t;
        cfg.scheme = scheme;
        cfg.t_end = t_time;
        cfg.limits.dt_fixed = Some(dt_ref);
        let (uref, pref) = final_state(&cfg)?;
        let nu: f64 = uref
            .iter()
            .map(|u| (u[0] * u[0] + u[1] * u[1]).sqrt())
            .sum();
        let np: f64 = pref.iter().map(|p| p.abs()).sum();
        let mut pts = Vec::new();
        for &dt in &dts {
            cfg.limits.dt_fixed = Some(dt);
            let t0 = std::time::Instant::now();
            let (u, p) = final_state(&cfg)?;
            let eu: f64 = u
                .iter()
                .zip(&uref)
                .map(|(a, b)| ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2)).sqrt())
                .sum::<f64>()
                / nu;
            let ep: f64 = p.iter().zip(&pref).map(|(a, b)| (a - b).abs()).sum::<f64>() / np;
            println!(
                "{:>16} {:>10.2e} {:>12.4e} {:>12.4e}",
                scheme.to_string(),
                dt,
                eu,
                ep
            );
            writeln!(
                f,
                "time,{scheme},{n_t},{dt},{eu},{ep},{}",
                t0.elapsed().as_secs_f64()
            )?;
            pts.push((1.0 / dt, eu, ep));
        }
        time.push((scheme, pts));
    }
    println!("\nobserved orders (least-squares slopes):");
    println!(
        "{:>16} {:>10} {:>10} {:>10} {:>10}",
        "scheme", "space u", "space p", "time u", "time p"
    );
    for ((s, sp), (_, tp)) in space.iter().zip(&time) {
        let o = |v: &Vec<(f64, f64, f64)>, k: usize| {
            -order(
                &v.iter()
                    .map(|x| (x.0, if k == 1 { x.1 } else { x.2 }))
                    .collect::<Vec<_>>(),
            )
        };
        println!(
            "{:>16} {:>10.2} {:>10.2} {:>10.2} {:>10.2}",
            s.to_string(),
            o(sp, 1),
            o(sp, 2),
            o(tp, 1),
            o(tp, 2)
        );
    }
    println!("wrote {}", a.out.join("convergence.csv").display());
    Ok(())
}

fn single(a: &Args) -> Result<ExitCode> {
    let cfg = config(a);
    cfg.validate().context("invalid configuration")?;
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
            if let Err(fe) = &done.record {
                eprintln!("error: finishing {} failed: {fe}", mcap.display());
            }
            return Err(e).context("Taylor–Green run failed");
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
    if a.particles_csv {
        let path = a.out.join("particles.csv");
        std::fs::write(&path, run.sim.particles.fluid_csv())
            .with_context(|| format!("writing {}", path.display()))?;
    }
    let res = &run.result;
    println!(
        "Taylor–Green Re {} n {} t = {:.2} ({} steps, {:.2} s): L1 velocity error {:.3e}, max-speed decay error {:.3e}, L1 pressure error {:.3e}",
        res.re,
        res.n,
        res.t_end,
        res.steps,
        res.wall_seconds,
        res.errors.l1_velocity_error,
        res.errors.linf_decay_error,
        res.errors.l1_pressure_error
    );
    Ok(ExitCode::SUCCESS)
}

fn main() -> ExitCode {
    let a = Args::parse();
    let r = if a.convergence {
        convergence(&a).map(|()| ExitCode::SUCCESS)
    } else {
        single(&a)
    };
    match r {
        Ok(code) => code,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}
