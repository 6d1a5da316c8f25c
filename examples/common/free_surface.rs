//! What the free-surface examples share: run a scene recorded into `--out`, then write its
//! tables, `summary.json` and plots there.

use anyhow::{Context, Result};
use gpm::record::{RecordLevel, RecorderOptions};
use gpm::scene::{run_recorded, Scene, SceneConfig};
use std::ops::ControlFlow;
use std::path::Path;

/// The configuration in `path` (a JSON object of the scene's keys, or a recording's
/// `/config`), the scene's defaults without one.
pub fn load<S: gpm::scene::SceneParams>(path: Option<&Path>) -> Result<SceneConfig<S>> {
    match path {
        Some(p) => {
            let text =
                std::fs::read_to_string(p).with_context(|| format!("reading {}", p.display()))?;
            gpm::scene::scene_config_from_json::<S>(&text)
                .with_context(|| format!("reading the configuration {}", p.display()))
        }
        None => Ok(Default::default()),
    }
}

/// Runs `cfg` recording every step (`full`: with particle snapshots) into `out/run.mcap` and
/// writes the scene's files into `out`; prints the summary.
pub fn run_into<S: Scene<2>>(cfg: &SceneConfig<S>, out: &Path, full: bool) -> Result<()> {
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let level = if full {
        RecordLevel::Full
    } else {
        RecordLevel::Diagnostics
    };
    let done = run_recorded(
        cfg,
        &out.join("run.mcap"),
        RecorderOptions::new(level, 10),
        &cfg.record_header(),
        |_| {},
        |_, _| Ok(ControlFlow::Continue(())),
    )?;
    let record = done.record.context("finishing the recording")?;
    let run = done.run.with_context(|| {
        format!(
            "{} run failed (the {} steps before the failure are in {})",
            S::NAME,
            record.steps,
            record
                .path
                .as_ref()
                .map_or("the recording".into(), |p| p.display().to_string())
        )
    })?;
    run.write_tables(out, cfg)
        .with_context(|| format!("writing into {}", out.display()))?;
    run.write_plots(out, cfg)?;
    println!("{}", serde_json::to_string_pretty(&run.summary(cfg))?);
    Ok(())
}
