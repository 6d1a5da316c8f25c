//! The collapse of a water column against Martin & Moyce (1952) (the `dam_break` scene,
//! `gpm::scene::dam_break`).
//!
//! ```text
//! cargo run --release --example dam_break -- --out results/dam_break
//! ```
//!
//! Defaults: column width a = 1, height 2a, tank length 5a, 40 particles across the column,
//! g = 1, `re` = √(g a³)/ν = 4·10⁴, to T = t√(2g/a) = 3. Writes into `--out`: `front.csv`
//! (`T,Z`), `height.csv` (`tau,H`), `dam_break.png` (both against the experiment),
//! `pressure.png` (the water coloured by pressure at T ≈ 0, 1, 2 and at the end),
//! `summary.json` (resolution, steps, `wall_seconds`, `front_deviation`, `height_deviation`,
//! surface and splash counts, the monitor's ranges, the configuration) and `run.mcap` (with
//! particle snapshots every 10 steps).

#[path = "common/free_surface.rs"]
mod common;

use anyhow::Result;
use clap::Parser;
use gpm::scene::dam_break::DamBreak;

#[derive(Parser, Debug)]
#[command(about = "Dam break (Martin & Moyce 1952): surge front and column height")]
struct Args {
    #[command(flatten)]
    run: common::RunArgs,
}

fn main() -> Result<()> {
    let a = Args::parse();
    // T = t √(2g/a) with a = 1
    let cfg = a
        .run
        .config::<DamBreak>(|c, t| t / (2.0 * c.scene.gravity).sqrt())?;
    common::run_into(&cfg, &a.run.out::<DamBreak>(), true, false)
}
