//! Work–precision: error against wall time over resolutions and options.
//!
//! ```text
//! cargo run --release --example work_precision -- --out results/work_precision
//! cargo run --release --example work_precision -- --quick
//! ```
//!
//! * Lid-driven cavity, Re 100: RMS error of `u` and `v` against Ghia et al. (1982) (their mean
//!   is plotted) for n = 16 … 100, with the default weight (Wendland C2, h = 3Δx) and variants
//!   (cubic spline, h = 2.5Δx / 4Δx, explicit viscosity with forward Euler).
//! * Taylor–Green, Re 100, t = 1: L1 velocity error against the exact solution for n = 16 … 128.
//!
//! Writes `work_precision.csv` (`case,variant,n,particles,steps,wall_seconds,error`) and
//! `work_precision.png` (error against wall time, log–log).

use anyhow::{Context, Result};
use clap::Parser;
use gpm::flow::Integrator;
use gpm::kernel::Weight;
use gpm::plot::{line_charts, Chart, Series};
use gpm::scene::cavity::{self, CavityConfig};
use gpm::scene::taylor_green::{self, TaylorGreenConfig};
use std::io::Write;
use std::path::PathBuf;

#[derive(Parser, Debug)]
#[command(about = "Error against wall time for the cavity and Taylor–Green")]
struct Args {
    /// Fewer and smaller runs.
    #[arg(long)]
    quick: bool,
    /// Output directory.
    #[arg(long, default_value = "results/work_precision")]
    out: PathBuf,
}

struct Variant {
    name: &'static str,
    weight: Weight,
    h_over_dx: f64,
    explicit: bool,
}

fn main_inner(a: Args) -> Result<()> {
    std::fs::create_dir_all(&a.out)?;
    let mut csv = std::fs::File::create(a.out.join("work_precision.csv"))?;
    writeln!(csv, "case,variant,n,particles,steps,wall_seconds,error")?;
    let variants = [
        Variant {
            name: "wendland2 h=3dx (default)",
            weight: Weight::WendlandC2,
            h_over_dx: 3.0,
            explicit: false,
        },
        Variant {
            name: "cubic h=3dx",
            weight: Weight::CubicSpline,
            h_over_dx: 3.0,
            explicit: false,
        },
        Variant {
            name: "wendland2 h=2.5dx",
            weight: Weight::WendlandC2,
            h_over_dx: 2.5,
            explicit: false,
        },
        Variant {
            name: "wendland2 h=4dx",
            weight: Weight::WendlandC2,
            h_over_dx: 4.0,
            explicit: false,
        },
        Variant {
            name: "explicit Euler viscosity",
            weight: Weight::WendlandC2,
            h_over_dx: 3.0,
            explicit: true,
        },
    ];
    let (cav_ns, tg_ns): (Vec<usize>, Vec<usize>) = if a.quick {
        (vec![16, 24, 32], vec![16, 32])
    } else {
        (vec![16, 24, 32, 50, 70, 100], vec![16, 32, 64, 128])
    };
    let mut cav_series = Vec::new();
    println!(
        "{:<10} {:<28} {:>5} {:>8} {:>7} {:>10} {:>10}",
        "case", "variant", "n", "particles", "steps", "wall s", "error"
    );
    for v in &variants {
        let mut pts = Vec::new();
        for &n in &cav_ns {
            if a.quick && v.name != variants[0].name && n > 24 {
                continue;
            }
            let mut cfg = CavityConfig::default().with(|c| {
                c.n = n;
                c.weight = v.weight;
                c.h_over_dx = v.h_over_dx;
            });
            if v.explicit {
                cfg.viscous_theta = 0.0;
                cfg.integrator = Integrator::Euler;
            }
            let r = cavity::run(&cfg, |_, _| Ok(()))
                .with_context(|| format!("cavity {} n {n}", v.name))?;
            let g = r.ghia.expect("Re 100 table");
            let err = 0.5 * (g.rms_u + g.rms_v);
            println!(
                "{:<10} {:<28} {:>5} {:>8} {:>7} {:>10.2} {:>10.3e}",
                "cavity", v.name, n, r.particles, r.steps, r.wall_seconds, err
            );
            writeln!(
                csv,
                "cavity,{},{n},{},{},{},{}",
                v.name, r.particles, r.steps, r.wall_seconds, err
            )?;
            pts.push((r.wall_seconds, err));
        }
        cav_series.push(Series::line_points(v.name, pts));
    }
    let mut tg_series = Vec::new();
    for v in variants.iter().take(if a.quick { 1 } else { 3 }) {
        let mut pts = Vec::new();
        for &n in &tg_ns {
            let mut cfg = TaylorGreenConfig::default().with(|c| {
                c.n = n;
                c.t_end = 1.0;
                c.weight = v.weight;
                c.h_over_dx = v.h_over_dx;
            });
            if v.explicit {
                cfg.viscous_theta = 0.0;
                cfg.integrator = Integrator::Euler;
            }
            let r = taylor_green::run(&cfg, |_, _| Ok(()))?;
            let err = r.errors.l1_velocity_error;
            println!(
                "{:<10} {:<28} {:>5} {:>8} {:>7} {:>10.2} {:>10.3e}",
                "tg",
                v.name,
                n,
                n * n,
                r.steps,
                r.wall_seconds,
                err
            );
            writeln!(
                csv,
                "taylor_green,{},{n},{},{},{},{}",
                v.name,
                n * n,
                r.steps,
                r.wall_seconds,
                err
            )?;
            pts.push((r.wall_seconds, err));
        }
        tg_series.push(Series::line_points(v.name, pts));
    }
    line_charts(
        &a.out.join("work_precision.png"),
        1500,
        650,
        &[
            (
                Chart {
                    title: "Cavity Re 100: mean RMS error vs Ghia against wall time".into(),
                    x_label: "wall time per run [s]".into(),
                    y_label: "error / lid speed".into(),
                    log_x: true,
                    log_y: true,
                },
                cav_series,
            ),
            (
                Chart {
                    title: "Taylor–Green Re 100, t = 1: L1 velocity error".into(),
                    x_label: "wall time per run [s]".into(),
                    y_label: "relative L1 error".into(),
                    log_x: true,
                    log_y: true,
                },
                tg_series,
            ),
        ],
    )?;
    println!(
        "wrote {} and work_precision.png",
        a.out.join("work_precision.csv").display()
    );
    Ok(())
}

fn main() -> std::process::ExitCode {
    match main_inner(Args::parse()) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            std::process::ExitCode::FAILURE
        }
    }
}
