//! The collapse of a water column in a box, in three dimensions (the `dam_break_3d` scene,
//! `gpm::scene::dam_break_3d`): a scale demonstration, compared with Martin & Moyce (1952) as
//! the 2D dam break is (the column spans the tank's whole depth).
//!
//! ```text
//! cargo run --release --example dam_break_3d -- --out results/dam_break_3d
//! cargo run --release --example dam_break_3d -- --n 26 --depth 2.846 --out results/dam3d_1e5
//! ```
//!
//! Defaults: column width a = 1, height 2a (along z), depth b = a (along y), tank length 5a,
//! 16 particles across the column, free-slip walls (no-slip: `--config` with
//! `{"walls": "no_slip"}`), g = 1, `re` = √(g a³)/ν = 4·10⁴, to T = t√(2g/a) = 3.
//! Writes into `--out`: `front.csv` (`T,Z`), `height.csv` (`tau,H`), `dam_break.png`,
//! `pressure.png` (the mid-plane slab y ≈ b/2), `summary.json` (resolution, particle count,
//! steps, `wall_seconds`, `seconds_per_step`, `front_deviation`, `height_deviation`, the
//! volume's largest change, surface and splash counts, the monitor's ranges — `c0_min`,
//! `c0_max`, `max_stability_ratio` — and the configuration) and `run.mcap` (with particle
//! snapshots every 10 steps; `gpm replay run.mcap --vtk DIR` writes them for ParaView).

#[path = "common/free_surface.rs"]
mod common;

use anyhow::Result;
use clap::Parser;
use gpm::scene::dam_break_3d::DamBreak3d;

#[derive(Parser, Debug)]
#[command(about = "3D dam break (a column in a box): surge front, column height, time per step")]
struct Args {
    #[command(flatten)]
    run: common::RunArgs,
    /// Depth of column and tank over the column width (rounded to whole spacings); default 1.
    #[arg(long)]
    depth: Option<f64>,
}

fn main() -> Result<()> {
    let a = Args::parse();
    // T = t √(2g/a) with a = 1
    let mut cfg = a
        .run
        .config::<DamBreak3d>(|c, t| t / (2.0 * c.scene.gravity).sqrt())?;
    if let Some(b) = a.depth {
        cfg.scene.depth = b;
    }
    common::run_into(&cfg, &a.run.out::<DamBreak3d>(), true, false)
}
