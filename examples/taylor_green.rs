//! Taylor–Green vortex against the exact solution (first version; options grow with the study).

use anyhow::{Context, Result};
use clap::Parser;
use gpm::flow::{Motion, Shifting};
use gpm::projection::Scheme;
use gpm::scene::taylor_green::{run, TaylorGreenConfig};

#[derive(Parser, Debug)]
struct Args {
    #[arg(long, default_value_t = 50)]
    n: usize,
    #[arg(long, default_value_t = 2.0)]
    t_end: f64,
    #[arg(long, default_value_t = 100.0)]
    re: f64,
    #[arg(long, default_value = "rotational")]
    scheme: Scheme,
    #[arg(long, default_value = "eulerian")]
    motion: Motion,
    #[arg(long)]
    shift: Option<f64>,
    #[arg(long)]
    cfl: Option<f64>,
}

fn main() -> Result<()> {
    let a = Args::parse();
    let mut cfg = TaylorGreenConfig {
        n: a.n,
        t_end: a.t_end,
        re: a.re,
        scheme: a.scheme,
        motion: a.motion,
        ..Default::default()
    };
    if let Some(s) = a.shift {
        cfg.shifting = (s > 0.0).then(|| Shifting {
            coefficient: s,
            ..Default::default()
        });
    }
    if let Some(c) = a.cfl {
        cfg.limits.cfl = c;
    }
    let mut k = 0;
    let res = run(&cfg, |rep, _| {
        k += 1;
        if std::env::var_os("GPM_TRACE").is_some() && k % 20 == 0 {
            eprintln!(
                "t={:.3} dt={:.2e} ke={:.5} div {:.2e}->{:.2e}",
                rep.time,
                rep.projection.dt,
                rep.projection.kinetic_energy,
                rep.projection.div_before,
                rep.projection.div_after
            );
        }
        Ok(())
    })
    .context("Taylor-Green run failed")?;
    println!("{}", serde_json::to_string_pretty(&res)?);
    Ok(())
}
