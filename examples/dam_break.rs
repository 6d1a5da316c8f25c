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
//! `summary.json` (resolution, steps, `wall_seconds`, `front_deviation`, `height_deviation`,
//! surface and splash counts, the monitor's ranges, the configuration) and `run.mcap` (with
//! particle snapshots every 10 steps).

#[path = "common/free_surface.rs"]
mod common;

use anyhow::Result;
use clap::Parser;
use gpm::scene::dam_break::DamBreakConfig;
use std::path::PathBuf;

#[derive(Parser, Debug)]
#[command(about = "Dam break (Martin & Moyce 1952): surge front and column height")]
struct Args {
    /// Particles across the column width (default 40).
    #[arg(long)]
    n: Option<usize>,
    /// End time T = t √(2g/a) (default 3).
    #[arg(long)]
    t_end: Option<f64>,
    /// Reynolds number √(g a³)/ν.
    #[arg(long)]
    re: Option<f64>,
    /// A configuration file (JSON: any of the scene's keys; the flags above override it).
    #[arg(long)]
    config: Option<PathBuf>,
    /// Output directory.
    #[arg(long, default_value = "results/dam_break")]
    out: PathBuf,
}

fn main() -> Result<()> {
    let a = Args::parse();
    let base: DamBreakConfig = common::load(a.config.as_deref())?;
    let cfg = base.with(|c| {
        if let Some(n) = a.n {
            c.n = n;
        }
        if let Some(t) = a.t_end {
            c.t_end = t / (2.0 * c.scene.gravity).sqrt();
        }
        if let Some(re) = a.re {
            c.re = re;
        }
    });
    common::run_into(&cfg, &a.out, true)
}
