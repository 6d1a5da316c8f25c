//! One projection on a disk of Vogel-spiral particles with a Dirichlet band (`p = 0` on the
//! outer ring of width `h`): the paper's own Poisson problem on a distribution that is not a
//! lattice anywhere.
//!
//! Two fields are projected, with the GPM operators and with the consistent set
//! ([`ProjectionParams::with_consistent_operators`]):
//! - the rigid rotation `u_v = (−y, x)`, divergence-free: the projection should leave it alone
//!   (reported: `max|P u_v − u_v| / max|u_v|` over the fluid particles; the band carries the
//!   field too, which the sum-form source zeroes — the paper's `f̂` — and the least-squares one
//!   keeps);
//! - the source flow `u = (x, y) = ∇(r²/2)`: the projection removes its radial part; by
//!   symmetry it must not create a swirl (reported: `max|u_θ| / max|u_v|` and its RMS, `u_θ`
//!   the azimuthal component of the projected field).
//!
//! Each is projected with the paper's band (`φ = 0`, number-density volumes) and with the
//! band's increment continued to vanish on the rim `r = 1`
//! ([`gpm::projection::surface`]: a quadratic fitted to the fluid's `φ`, the fixed point
//! solved by Anderson mixing over projections), with or without the band's volumes continued
//! from the fluid ([`band_volumes_from_fluid`]).
//!
//! ```text
//! cargo run --release --example spiral_disk -- [--n 4000] [--h-ratio 3] [--out DIR]
//! ```
//! writes `DIR/spiral_disk.csv` (one row per operator set and band treatment: `operators,
//! band, band_volumes, solves, vortex_change, swirl_max, swirl_rms, radial_rms`) and
//! `DIR/summary.json`.

use anyhow::{Context, Result};
use clap::Parser;
use gpm::boundary::NoBoundary;
use gpm::geometry::vogel_disk;
use gpm::kernel::Weight;
use gpm::neighbors::{NeighborConfig, NeighborList};
use gpm::particles::{Particles, Role};
use gpm::projection::surface::SurfaceBand;
use gpm::projection::{ProjectionParams, ProjectionStep, Scheme};
use gpm::setup::{band_volumes_from_fluid, prepare, VolumeRule};
use serde::Serialize;
use std::path::PathBuf;

#[derive(Parser, Debug)]
#[command(about = "Projection on a Vogel-spiral disk with a Dirichlet band")]
struct Args {
    /// Particles in the unit disk.
    #[arg(long, default_value_t = 4000)]
    n: usize,
    /// Influence radius over the mean spacing √(π/n).
    #[arg(long, default_value_t = 3.0)]
    h_ratio: f64,
    /// Output directory.
    #[arg(long, default_value = "results/spiral_disk")]
    out: PathBuf,
}

/// What one operator set does to the two fields.
#[derive(Clone, Debug, Serialize)]
struct Row {
    operators: &'static str,
    /// The band's values of the increment: `zero` or `extrapolated` (to vanish on the rim).
    band: &'static str,
    /// The band's volumes: `number_density` (`1/Σw`) or `fluid` (continued from the fluid).
    band_volumes: &'static str,
    /// Poisson solves of the source flow's projection (the extrapolation's fixed point).
    solves: usize,
    /// `max|P u_v − u_v| / max|u_v|` over the fluid particles.
    vortex_change: f64,
    /// `max|u_θ| / max|u_v|` of the projected source flow.
    swirl_max: f64,
    /// RMS of `u_θ` over the fluid particles, over `max|u_v|`.
    swirl_rms: f64,
    /// RMS of the radial velocity left by the projection of the source flow, over `max|u_v|`.
    radial_rms: f64,
}

#[derive(Serialize)]
struct Summary {
    n: usize,
    h_ratio: f64,
    fluid: usize,
    band: usize,
    rows: Vec<Row>,
}

/// `n` particles on Vogel's spiral in the unit disk ([`vogel_disk`]), with the outer ring
/// `r > 1 − h` as the Dirichlet band.
fn spiral(n: usize, h: f64) -> Particles<2> {
    let vol = std::f64::consts::PI / n as f64;
    let mut p = Particles::new();
    for x in vogel_disk(n, [0.0, 0.0], 1.0) {
        let role = if x[0].hypot(x[1]) > 1.0 - h {
            Role::Dirichlet
        } else {
            Role::Fluid
        };
        p.push(x, [0.0; 2], 0.0, vol, role);
    }
    p
}

/// The band's treatment: `φ = 0` and number-density volumes (the paper's problem), or `φ`
/// continued into the band to vanish on the disk's rim `r = 1`
/// ([`gpm::projection::surface`]), with or without the band's volumes continued from the
/// fluid ([`band_volumes_from_fluid`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Band {
    extrapolated: bool,
    fluid_volumes: bool,
}

fn project(
    base: &Particles<2>,
    config: NeighborConfig<2>,
    params: &ProjectionParams<2>,
    band: Band,
    field: impl Fn(&[f64; 2]) -> [f64; 2],
) -> Result<(Particles<2>, usize)> {
    let mut p = base.clone();
    for i in 0..p.len() {
        p.u[i] = field(&p.x[i]);
    }
    let nl = prepare(&mut p, &NoBoundary, config, VolumeRule::NumberDensity)?;
    if band.fluid_volumes {
        band_volumes_from_fluid(&mut p, &nl);
    }
    let u_star = p.u.clone();
    let mut step = ProjectionStep::new();
    if !band.extrapolated {
        step.project(&mut p, &nl, &NoBoundary, params, 1.0, &u_star)
            .context("projection")?;
        return Ok((p, 1));
    }
    // fits over 2h; the foot of a band particle on the rim r = 1 is x/|x|
    let fit = NeighborList::build(
        NeighborConfig::new(config.weight, 2.0 * config.h, 0.0),
        &p.x,
    )?;
    let foot = |_: usize, x: &[f64; 2]| {
        let r = x[0].hypot(x[1]);
        (r > 0.0).then(|| [x[0] / r, x[1] / r])
    };
    let surface = SurfaceBand {
        fit: &fit,
        foot: &foot,
        tol: 1e-11,
        max_solves: 60,
    };
    let (_, solves) = step
        .project_to_surface(&mut p, &nl, &NoBoundary, params, 1.0, &u_star, &surface)
        .context("projection to the rim")?;
    Ok((p, solves))
}

fn measure(
    name: &'static str,
    base: &Particles<2>,
    config: NeighborConfig<2>,
    params: &ProjectionParams<2>,
    band: Band,
) -> Result<Row> {
    let vortex = |x: &[f64; 2]| [-x[1], x[0]];
    let source = |x: &[f64; 2]| [x[0], x[1]];
    let (pv, _) = project(base, config, params, band, vortex)?;
    let (ps, solves) = project(base, config, params, band, source)?;
    let fluid: Vec<usize> = (0..base.len())
        .filter(|&i| base.role[i] == Role::Fluid)
        .collect();
    let vmax = fluid
        .iter()
        .map(|&i| base.x[i][0].hypot(base.x[i][1]))
        .fold(0.0, f64::max);
    let mut change = 0.0f64;
    let (mut smax, mut s2, mut r2) = (0.0f64, 0.0, 0.0);
    for &i in &fluid {
        let x = base.x[i];
        let v = vortex(&x);
        change = change.max((pv.u[i][0] - v[0]).hypot(pv.u[i][1] - v[1]));
        let r = x[0].hypot(x[1]).max(1e-300);
        let ut = (-x[1] * ps.u[i][0] + x[0] * ps.u[i][1]) / r;
        let ur = (x[0] * ps.u[i][0] + x[1] * ps.u[i][1]) / r;
        smax = smax.max(ut.abs());
        s2 += ut * ut;
        r2 += ur * ur;
    }
    let m = fluid.len() as f64;
    Ok(Row {
        operators: name,
        band: if band.extrapolated {
            "extrapolated"
        } else {
            "zero"
        },
        band_volumes: if band.fluid_volumes {
            "fluid"
        } else {
            "number_density"
        },
        solves,
        vortex_change: change / vmax,
        swirl_max: smax / vmax,
        swirl_rms: (s2 / m).sqrt() / vmax,
        radial_rms: (r2 / m).sqrt() / vmax,
    })
}

fn main() -> Result<()> {
    let a = Args::parse();
    anyhow::ensure!(a.n >= 100, "--n must be at least 100 (got {})", a.n);
    anyhow::ensure!(
        a.h_ratio > 1.0 && a.h_ratio <= 8.0,
        "--h-ratio must be in (1, 8] (got {})",
        a.h_ratio
    );
    let dx = (std::f64::consts::PI / a.n as f64).sqrt();
    let h = a.h_ratio * dx;
    let base = spiral(a.n, h);
    let config = NeighborConfig::new(Weight::WendlandC2, h, 0.0);
    let mut gpm = ProjectionParams::<2>::new(0.0);
    gpm.scheme = Scheme::NonIncremental;
    gpm.allowed_floating = 0;
    let consistent = gpm.with_consistent_operators();
    let band = |extrapolated, fluid_volumes| Band {
        extrapolated,
        fluid_volumes,
    };
    let rows = vec![
        measure("gpm", &base, config, &gpm, band(false, false))?,
        measure("consistent", &base, config, &consistent, band(false, false))?,
        measure("consistent", &base, config, &consistent, band(false, true))?,
        measure("consistent", &base, config, &consistent, band(true, false))?,
        measure("consistent", &base, config, &consistent, band(true, true))?,
        measure("gpm", &base, config, &gpm, band(true, true))?,
    ];
    std::fs::create_dir_all(&a.out).with_context(|| format!("creating {}", a.out.display()))?;
    let mut csv = String::from(
        "operators,band,band_volumes,solves,vortex_change,swirl_max,swirl_rms,radial_rms\n",
    );
    println!("spiral disk, n = {}, h = {}Δx", a.n, a.h_ratio);
    println!(
        "{:<11} {:<13} {:<15} {:>6} {:>14} {:>11} {:>11} {:>11}",
        "operators",
        "band",
        "band volumes",
        "solves",
        "vortex change",
        "swirl max",
        "swirl rms",
        "radial rms"
    );
    for r in &rows {
        let numbers = [r.vortex_change, r.swirl_max, r.swirl_rms, r.radial_rms];
        csv += &format!("{},{},{},{}", r.operators, r.band, r.band_volumes, r.solves);
        let mut line = format!(
            "{:<11} {:<13} {:<15} {:>6}",
            r.operators, r.band, r.band_volumes, r.solves
        );
        for (k, v) in numbers.iter().enumerate() {
            csv += &format!(",{v:e}");
            let width = if k == 0 { 14 } else { 11 };
            line += &format!(" {v:>width$.3e}");
        }
        csv.push('\n');
        println!("{line}");
    }
    let band = base.role.iter().filter(|r| **r == Role::Dirichlet).count();
    let summary = Summary {
        n: a.n,
        h_ratio: a.h_ratio,
        fluid: base.len() - band,
        band,
        rows,
    };
    std::fs::write(a.out.join("spiral_disk.csv"), csv)?;
    std::fs::write(
        a.out.join("summary.json"),
        serde_json::to_string_pretty(&summary)?,
    )?;
    Ok(())
}
