//! Lid-driven cavity against Ghia, Ghia & Shin (1982).
//!
//! ```text
//! cargo run --release --example cavity                       # Re 100, default resolution
//! cargo run --release --example cavity -- --re 1000 --n 100 --out results/re1000
//! ```

use anyhow::{Context, Result};
use clap::Parser;
use gpm::flow::{Motion, Shifting, VolumeRule};
use gpm::kernel::Weight;
use gpm::poisson::SolverKind;
use gpm::projection::Scheme;
use gpm::scene::cavity::{run, CavityConfig};
use std::path::PathBuf;

#[derive(Parser, Debug)]
#[command(about = "Lid-driven cavity with the GPM projection, compared with Ghia et al. (1982)")]
struct Args {
    /// Reynolds number (Ghia tables exist for 100 and 1000).
    #[arg(long, default_value_t = 100.0)]
    re: f64,
    /// Fluid particles per side.
    #[arg(long, default_value_t = 50)]
    n: usize,
    /// End time (the run stops earlier once steady).
    #[arg(long)]
    t_end: Option<f64>,
    /// Pressure scheme: non-incremental, incremental, rotational.
    #[arg(long, default_value = "rotational")]
    scheme: Scheme,
    /// Reference weight: cubic, wendland2, wendland4, polyP-M.
    #[arg(long, default_value = "wendland2")]
    weight: Weight,
    /// Influence radius over particle spacing.
    #[arg(long, default_value_t = 3.0)]
    h_ratio: f64,
    /// Particle frame: lagrangian or eulerian.
    #[arg(long, default_value = "eulerian")]
    motion: Motion,
    /// Shifting coefficient A (0 disables shifting).
    #[arg(long)]
    shift: Option<f64>,
    /// Fixed volumes instead of number-density volumes.
    #[arg(long)]
    fixed_volumes: bool,
    /// CFL number.
    #[arg(long)]
    cfl: Option<f64>,
    /// Linear solver: cholesky, cg, auto.
    #[arg(long, default_value = "auto")]
    solver: SolverKind,
    /// Steadiness tolerance on max|Δprofile|/Δt.
    #[arg(long)]
    steady_tol: Option<f64>,
    /// Averaging window (time units).
    #[arg(long)]
    average: Option<f64>,
    /// Output directory.
    #[arg(long)]
    out: Option<PathBuf>,
}

fn main() -> Result<()> {
    let a = Args::parse();
    let mut cfg = CavityConfig {
        re: a.re,
        n: a.n,
        scheme: a.scheme,
        weight: a.weight,
        h_over_dx: a.h_ratio,
        motion: a.motion,
        ..Default::default()
    };
    if let Some(t) = a.t_end {
        cfg.t_end = t;
    } else if a.re > 500.0 {
        cfg.t_end = 100.0;
    }
    if let Some(s) = a.shift {
        cfg.shifting = if s > 0.0 {
            Some(Shifting {
                coefficient: s,
                ..Default::default()
            })
        } else {
            None
        };
    }
    if a.fixed_volumes {
        cfg.volumes = VolumeRule::Fixed;
    }
    if let Some(c) = a.cfl {
        cfg.limits.cfl = c;
    }
    if let Some(t) = a.steady_tol {
        cfg.steady.tol = t;
    }
    if let Some(w) = a.average {
        cfg.steady.average_window = w;
    }
    cfg.solve.solver = a.solver;
    let mut last_print = std::time::Instant::now();
    let res = run(&cfg, |rep, sim| {
        if std::env::var_os("GPM_TRACE2").is_some() {
            let p = &sim.particles;
            let (mut im, mut vm) = (0, 0.0);
            for i in 0..p.len() {
                if p.role[i].is_fluid() {
                    let v = (p.u[i][0].powi(2) + p.u[i][1].powi(2)).sqrt();
                    if v > vm { vm = v; im = i; }
                }
            }
            eprintln!("step {} t={:.4} max|u|={:.3} at particle {} x=({:.4},{:.4}) u=({:.3},{:.3}) p={:.3} vol={:.3e}", rep.step, rep.time, vm, im, p.x[im][0], p.x[im][1], p.u[im][0], p.u[im][1], p.p[im], p.vol[im]);
        }
        if std::env::var_os("GPM_TRACE").is_some() || last_print.elapsed().as_secs_f64() > 2.0 {
            last_print = std::time::Instant::now();
            eprintln!(
                "t={:7.3} step={:6} dt={:.2e} ke={:.5} div {:.2e}->{:.2e} ratio={:.3}",
                rep.time,
                rep.step,
                rep.projection.dt,
                rep.projection.kinetic_energy,
                rep.projection.div_before,
                rep.projection.div_after,
                rep.projection.stability_ratio
            );
        }
        Ok(())
    })
    .context("cavity run failed")?;
    println!(
        "Re={} n={} steps={} t={:.2} steady={} (t_s={:?}, rate={:.2e}) wall={:.1}s",
        res.re,
        res.n,
        res.steps,
        res.t_end,
        res.steady,
        res.steady_time,
        res.steady_rate,
        res.wall_seconds
    );
    if let Some(g) = res.ghia {
        println!(
            "Ghia: rms_u={:.4} max_u={:.4} rms_v={:.4} max_v={:.4}",
            g.rms_u, g.max_u, g.rms_v, g.max_v
        );
    }
    println!(
        "max stability ratio {:.3e}, c0 in [{:.4}, {:.4}], max div ratio {:.3e}",
        res.max_stability_ratio, res.c0_min, res.c0_max, res.max_div_ratio
    );
    if let Some(out) = a.out {
        std::fs::create_dir_all(&out)?;
        std::fs::write(
            out.join("summary.json"),
            serde_json::to_string_pretty(&res)?,
        )?;
    }
    Ok(())
}
