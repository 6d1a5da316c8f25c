//! What the free-surface examples (and the cube's) share: run a scene recorded into `--out`, then write its
//! tables, `summary.json` and plots there.

use anyhow::{Context, Result};
use gpm::record::{RecordLevel, RecorderOptions};
use gpm::scene::{run_recorded, Scene, SceneConfig};
use std::ops::ControlFlow;
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

/// The command line both examples share.
#[derive(clap::Args, Debug)]
pub struct RunArgs {
    /// Particles across the tank (hydrostatic) or the column (dam break); default 40.
    #[arg(long)]
    pub n: Option<usize>,
    /// End time in the scene's unit: √(H/g) for the tank (default 5), T = t√(2g/a) for the
    /// dam break (default 3).
    #[arg(long)]
    pub t_end: Option<f64>,
    /// Reynolds number √(g L³)/ν (L the depth or the column width).
    #[arg(long)]
    pub re: Option<f64>,
    /// A configuration file (JSON: any of the scene's keys; the flags above override it).
    #[arg(long)]
    pub config: Option<std::path::PathBuf>,
    /// Output directory (default results/<scene>).
    #[arg(long)]
    pub out: Option<std::path::PathBuf>,
}

impl RunArgs {
    /// The configuration file's (or the defaults) with the flags applied; `t_end` is converted
    /// to the simulation's time by `to_time`.
    pub fn config<S: gpm::scene::SceneParams>(
        &self,
        to_time: impl Fn(&SceneConfig<S>, f64) -> f64,
    ) -> Result<SceneConfig<S>> {
        let mut c: SceneConfig<S> = load(self.config.as_deref())?;
        if let Some(n) = self.n {
            c.n = n;
        }
        if let Some(t) = self.t_end {
            c.t_end = to_time(&c, t);
        }
        if let Some(re) = self.re {
            c.re = re;
        }
        Ok(c)
    }

    /// The output directory.
    pub fn out<S: gpm::scene::SceneParams>(&self) -> std::path::PathBuf {
        self.out
            .clone()
            .unwrap_or_else(|| Path::new("results").join(S::NAME))
    }
}

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
/// writes the scene's files into `out` (`particles_csv`: also `particles.csv`, the final fluid
/// particles, [`gpm::particles::Particles::fluid_csv`]); prints the summary. Ctrl-C or SIGTERM
/// stops the run after the current step and still writes the files, of the state then (a long
/// run stopped early keeps its profiles and its particles, e.g. to warm-start another).
pub fn run_into<const D: usize, S: Scene<D>>(
    cfg: &SceneConfig<S>,
    out: &Path,
    full: bool,
    particles_csv: bool,
) -> Result<()> {
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let level = if full {
        RecordLevel::Full
    } else {
        RecordLevel::Diagnostics
    };
    let stop = Arc::new(AtomicBool::new(false));
    {
        let stop = stop.clone();
        ctrlc::set_handler(move || stop.store(true, Ordering::SeqCst))
            .context("installing the Ctrl-C handler")?;
    }
    let done = run_recorded(
        cfg,
        &out.join("run.mcap"),
        RecorderOptions::new(level, 10),
        &cfg.record_header(),
        |_| {},
        |_, _| {
            Ok(if stop.load(Ordering::SeqCst) {
                ControlFlow::Break(())
            } else {
                ControlFlow::Continue(())
            })
        },
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
    if let Some(step) = run.interrupted() {
        eprintln!(
            "interrupted after step {step}: the files in {} describe the state then",
            out.display()
        );
    }
    run.write_tables(out, cfg)
        .with_context(|| format!("writing into {}", out.display()))?;
    run.write_plots(out, cfg)?;
    if particles_csv {
        let path = out.join("particles.csv");
        std::fs::write(&path, run.sim.particles.fluid_csv())
            .with_context(|| format!("writing {}", path.display()))?;
    }
    println!("{}", serde_json::to_string_pretty(&run.summary(cfg))?);
    Ok(())
}
