//! The lid-driven cube (the `cube` scene, `gpm::scene::cube`): the unit cube, lid `y = 1`
//! moving along `+x`, no-slip elsewhere; centre-line profiles `u(0.5, y, 0.5)` and
//! `v(x, 0.5, 0.5)` compared at Re 1000 with Albensoeder & Kuhlmann (2005).
//!
//! ```text
//! cargo run --release --example cube                                    # Re 100, n = 16
//! cargo run --release --example cube -- --re 1000 --n 24 --t-end 40 --out results/cube1000
//! ```
//!
//! Writes into `--out` (default `results/cube_re{Re}_n{n}`): `profile_u.csv`, `profile_v.csv`,
//! `summary.json` (resolution, steps, `wall_seconds`, RMS and max errors against the reference
//! where there is one, the symmetry about z = 0.5, how steadiness was judged, the monitor's
//! ranges, the configuration), `profiles.png`, `particles.png` (the mid-plane) and `run.mcap`.
//! The same run is `gpm run cube --set n=16 …`.

// the free-surface examples' shared runner (their `RunArgs` is not used here: its help texts
// are theirs)
#[path = "common/free_surface.rs"]
#[allow(dead_code)]
mod common;

use anyhow::Result;
use clap::Parser;
use gpm::scene::cube::Cube;
use std::path::PathBuf;

#[derive(Parser, Debug)]
#[command(about = "Lid-driven cube: centre-line profiles against Albensoeder & Kuhlmann (2005)")]
struct Args {
    /// Fluid particles per side (n³ in all); default 16.
    #[arg(long)]
    n: Option<usize>,
    /// Reynolds number U L / ν (a reference table is embedded for 1000); default 100.
    #[arg(long)]
    re: Option<f64>,
    /// End time (the run stops earlier once steady); default 30.
    #[arg(long)]
    t_end: Option<f64>,
    /// A configuration file (JSON: any of the scene's keys; the flags above override it).
    #[arg(long)]
    config: Option<PathBuf>,
    /// Output directory.
    #[arg(long)]
    out: Option<PathBuf>,
    /// Record particle snapshots (every 10 steps) beside the per-step diagnostics.
    #[arg(long)]
    full: bool,
    /// Also write the final fluid particles into OUT/particles.csv (`x,y,z,u,v,w,p`), e.g. the
    /// warm start of a finer run (--initial).
    #[arg(long)]
    particles_csv: bool,
    /// Warm start: the velocity and pressure of another run's OUT/particles.csv (written with
    /// --particles-csv, any resolution), sampled at this run's particles before the first step.
    #[arg(long)]
    initial: Option<PathBuf>,
}

fn main() -> Result<()> {
    let a = Args::parse();
    let mut cfg = common::load::<Cube>(a.config.as_deref())?;
    if let Some(n) = a.n {
        cfg.n = n;
    }
    if let Some(re) = a.re {
        cfg.re = re;
    }
    if let Some(t) = a.t_end {
        cfg.t_end = t;
    }
    if a.initial.is_some() {
        cfg.initial = a.initial;
    }
    let out = a
        .out
        .unwrap_or_else(|| PathBuf::from(format!("results/cube_re{}_n{}", cfg.re, cfg.n)));
    common::run_into(&cfg, &out, a.full, a.particles_csv)
}
