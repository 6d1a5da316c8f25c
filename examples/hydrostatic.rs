//! A tank at rest with a free surface (the `hydrostatic` scene, `gpm::scene::hydrostatic`):
//! the pressure against `ρ g (H − y)`, the particles' drift and the decay of the kinetic energy.
//!
//! ```text
//! cargo run --release --example hydrostatic -- --out results/hydrostatic
//! ```
//!
//! Defaults: depth 1, width 1, 40 particles across, g = 1, to t = 5 √(H/g). Writes into
//! `--out`: `summary.json` (`pressure_l2_error`, `max_drift_over_dx`, `kinetic_energy_decay`,
//! `wall_seconds`, surface counts, the monitor's ranges, the configuration), `pressure.csv`
//! (`y,p` of every particle at the end), `energy.csv` (`t,kinetic_energy`) and `run.mcap`.

#[path = "common/free_surface.rs"]
mod common;

use anyhow::Result;
use clap::Parser;
use gpm::scene::hydrostatic::Hydrostatic;

#[derive(Parser, Debug)]
#[command(about = "A tank at rest with a free surface: hydrostatic pressure, drift, energy")]
struct Args {
    #[command(flatten)]
    run: common::RunArgs,
}

fn main() -> Result<()> {
    let a = Args::parse();
    let cfg = a.run.config::<Hydrostatic>(|_, t| t)?;
    common::run_into(&cfg, &a.run.out::<Hydrostatic>(), false, false)
}
