//! `gpm`: run scenes with MCAP recording, and replay recorded runs.
//!
//! ```text
//! gpm run cavity --re 100 --n 50 --out results/cavity      # writes results/cavity/run.mcap
//! gpm run taylor-green --n 32 --t-end 0.5 --record full --record-every 10 --out results/tg
//! gpm replay results/cavity/run.mcap --csv steps.csv --plot steps.png
//! gpm replay results/tg/run.mcap --vtk results/tg/vtk --rerun
//! ```
//!
//! Errors are printed as one line (with their causes) and the exit status is non-zero; Ctrl-C
//! stops a run after the current step and finishes the MCAP file (exit status 130). A run that
//! fails finishes its MCAP file too, so every step before the failure reads back. `replay` reads
//! cut or damaged files with a warning naming the byte offset; `--strict` makes that an error
//! (exit status 2).

use anyhow::{bail, Context, Result};
use clap::{Args, Parser, Subcommand};
use gpm::flow::Motion;
use gpm::kernel::Weight;
use gpm::projection::Scheme;
use gpm::record::replay::{export_vtk, Replay};
use gpm::record::rerun::rerun_file;
use gpm::record::{ChunkCompression, RecordLevel, RecorderOptions};
use gpm::scene::{run_recorded, Scene, SceneConfig, SceneVisitor};
use indicatif::{ProgressBar, ProgressStyle};
use std::ops::ControlFlow;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::Arc;

#[derive(Parser, Debug)]
#[command(
    name = "gpm",
    version,
    about = "Incompressible particle flows with the generalized particle method"
)]
struct Cli {
    /// Rayon worker threads (default: all cores).
    #[arg(long, global = true)]
    threads: Option<usize>,
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Run a scene and record it to DIR/run.mcap.
    Run(RunArgs),
    /// Summarise, plot, export or re-run a recorded MCAP file (complete or cut).
    Replay(ReplayArgs),
}

/// A registered scene's name (`gpm::scene::SCENES`; `-` and `_` are the same).
fn scene_name(s: &str) -> Result<String, String> {
    let name = s.trim().to_ascii_lowercase().replace('-', "_");
    if gpm::scene::SCENES.contains(&name.as_str()) {
        Ok(name)
    } else {
        Err(format!(
            "unknown scene '{s}': expected one of {}",
            gpm::scene::SCENES.join(", ").replace('_', "-")
        ))
    }
}

#[derive(Args, Debug)]
struct RunArgs {
    /// Scene: cavity (lid-driven, compared with Ghia et al. 1982) or taylor-green (periodic
    /// vortex, exact solution).
    #[arg(value_parser = scene_name)]
    scene: String,
    /// Full scene configuration (JSON, unknown keys rejected); the flags below override it.
    /// A `/config` message's `{"scene", "config"}` object is accepted too.
    #[arg(long)]
    config: Option<PathBuf>,
    /// Reynolds number.
    #[arg(long)]
    re: Option<f64>,
    /// Particles per side.
    #[arg(long)]
    n: Option<usize>,
    /// End time.
    #[arg(long)]
    t_end: Option<f64>,
    /// Pressure scheme: non-incremental, incremental, rotational.
    #[arg(long)]
    scheme: Option<Scheme>,
    /// Gradient of the predictor and the correction: difference (default) or renormalised.
    #[arg(long)]
    gradient: Option<gpm::consistent::GradientKind>,
    /// Reference weight: cubic, wendland2, wendland4, polyP-M.
    #[arg(long)]
    weight: Option<Weight>,
    /// Influence radius over particle spacing.
    #[arg(long)]
    h_ratio: Option<f64>,
    /// Particle frame: lagrangian or eulerian.
    #[arg(long)]
    motion: Option<Motion>,
    /// What to record: none, diagnostics (every step) or full (plus particles and projection
    /// inputs every --record-every steps).
    #[arg(long, default_value = "diagnostics")]
    record: RecordLevel,
    /// Snapshot interval k of --record full.
    #[arg(long, default_value_t = 10)]
    record_every: u64,
    /// Close a chunk every this many steps (a killed run loses at most these).
    #[arg(long, default_value_t = 1)]
    flush_every: u64,
    /// Chunk compression: zstd or none.
    #[arg(long, default_value = "zstd")]
    compression: ChunkCompression,
    /// Output directory (run.mcap is written there).
    #[arg(long, default_value = ".")]
    out: PathBuf,
    /// No progress bar.
    #[arg(long)]
    quiet: bool,
}

#[derive(Args, Debug)]
struct ReplayArgs {
    /// The MCAP file.
    file: PathBuf,
    /// Export the diagnostics table as CSV.
    #[arg(long)]
    csv: Option<PathBuf>,
    /// Plot the main time series into a PNG.
    #[arg(long)]
    plot: Option<PathBuf>,
    /// Write the particle snapshots as VTK files (ParaView) into this directory.
    #[arg(long)]
    vtk: Option<PathBuf>,
    /// Re-run every recorded projection input and report the largest differences.
    #[arg(long)]
    rerun: bool,
    /// Print the summary as JSON instead of text.
    #[arg(long)]
    json: bool,
    /// No progress bars.
    #[arg(long)]
    quiet: bool,
    /// Exit with status 2 when the file is cut or damaged (by default the steps that survive
    /// are read and the damage is a warning).
    #[arg(long)]
    strict: bool,
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    match real_main(cli) {
        Ok(code) => code,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}

fn real_main(cli: Cli) -> Result<ExitCode> {
    if let Some(t) = cli.threads {
        rayon::ThreadPoolBuilder::new()
            .num_threads(t)
            .build_global()
            .context("setting the thread count")?;
    }
    match cli.command {
        Command::Run(a) => run(a),
        Command::Replay(a) => replay(a),
    }
}

/// Reads a scene configuration: a bare config, or a `/config` message's `{"scene", "config"}`.
fn load_config<T: serde::de::DeserializeOwned>(path: &Path, scene: &str) -> Result<T> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    let mut v: serde_json::Value =
        serde_json::from_str(&text).with_context(|| format!("{} is not JSON", path.display()))?;
    if let Some(inner) = v.get("config").cloned() {
        if let Some(s) = v.get("scene").and_then(|s| s.as_str()) {
            if s != scene {
                bail!(
                    "{} configures the scene '{s}', not '{scene}'",
                    path.display()
                );
            }
        }
        v = inner;
    }
    gpm::scene::config_from_value(v)
        .with_context(|| format!("invalid {scene} configuration in {}", path.display()))
}

fn progress_bar(len: u64, quiet: bool, template: &str) -> ProgressBar {
    if quiet {
        return ProgressBar::hidden();
    }
    let pb = ProgressBar::new(len);
    if let Ok(style) = ProgressStyle::with_template(template) {
        pb.set_style(style.progress_chars("=> "));
    }
    pb
}

fn run(a: RunArgs) -> Result<ExitCode> {
    // Ctrl-C: stop after the current step and finish the file; a second Ctrl-C exits at once
    // (the file then keeps every flushed step).
    let stop = Arc::new(AtomicBool::new(false));
    let presses = Arc::new(AtomicUsize::new(0));
    {
        let (stop, presses) = (stop.clone(), presses.clone());
        ctrlc::set_handler(move || {
            stop.store(true, Ordering::SeqCst);
            if presses.fetch_add(1, Ordering::SeqCst) >= 1 {
                std::process::exit(130);
            }
        })
        .context("installing the Ctrl-C handler")?;
    }
    let scene = a.scene.clone();
    gpm::scene::visit_scene(&scene, RunScene { a, stop })?
}

/// `gpm run <scene>` for any registered scene.
struct RunScene {
    a: RunArgs,
    stop: Arc<AtomicBool>,
}

impl SceneVisitor for RunScene {
    type Output = Result<ExitCode>;

    fn visit<const D: usize, S: Scene<D>>(self) -> Result<ExitCode> {
        let RunScene { a, stop } = self;
        let name = S::NAME;
        let mut cfg: SceneConfig<S> = match &a.config {
            Some(p) => load_config(p, name)?,
            None => Default::default(),
        };
        override_opt(&mut cfg.re, a.re);
        override_opt(&mut cfg.n, a.n);
        override_opt(&mut cfg.t_end, a.t_end);
        override_opt(&mut cfg.scheme, a.scheme);
        override_opt(&mut cfg.gradient, a.gradient);
        override_opt(&mut cfg.weight, a.weight);
        override_opt(&mut cfg.h_over_dx, a.h_ratio);
        override_opt(&mut cfg.motion, a.motion);
        cfg.validate()
            .with_context(|| format!("invalid {name} configuration"))?;
        std::fs::create_dir_all(&a.out).with_context(|| format!("creating {}", a.out.display()))?;
        let path = a.out.join("run.mcap");
        let options = RecorderOptions {
            flush_every: a.flush_every,
            compression: a.compression,
            ..RecorderOptions::new(a.record, a.record_every)
        };
        let bar_template = "{spinner} [{elapsed_precise}] [{bar:40}] {percent:>3}% {msg}";
        let pb = progress_bar(1000, a.quiet, bar_template);
        let t_end = cfg.t_end;
        let done = run_recorded(
            &cfg,
            &path,
            options,
            &cfg.record_header(),
            |_| {},
            |rep, _| Ok(observe(&pb, rep, t_end, &stop)),
        )?;
        pb.finish_and_clear();
        // the file is finished (or its error known) before the run's outcome is reported
        let record = match done.record {
            Ok(s) => {
                for note in &s.notes {
                    eprintln!("note: {note}");
                }
                Some(s)
            }
            Err(e) => {
                eprintln!("error: finishing the recording failed: {e}");
                None
            }
        };
        match done.run {
            Ok(run) => {
                if let Some(step) = run.interrupted() {
                    match &record {
                        Some(r) => eprintln!(
                            "interrupted after step {step}; {} finished cleanly ({} steps, {} bytes)",
                            path.display(),
                            r.steps,
                            r.bytes
                        ),
                        None => eprintln!("interrupted after step {step}"),
                    }
                    return Ok(ExitCode::from(130));
                }
                let out =
                    serde_json::json!({ "scene": name, "result": run.result, "record": record });
                println!("{}", serde_json::to_string_pretty(&out)?);
                Ok(if record.is_some() || a.record == RecordLevel::None {
                    ExitCode::SUCCESS
                } else {
                    ExitCode::FAILURE
                })
            }
            Err(e) => {
                if let Some(r) = &record {
                    if a.record != RecordLevel::None {
                        eprintln!(
                            "the recording of the {} steps before the failure is in {}",
                            r.steps,
                            path.display()
                        );
                    }
                }
                Err(anyhow::Error::new(e).context(format!("{name} run failed")))
            }
        }
    }
}

fn override_opt<T>(slot: &mut T, v: Option<T>) {
    if let Some(v) = v {
        *slot = v;
    }
}

/// Progress, and the Ctrl-C request: stop after this step.
fn observe(
    pb: &ProgressBar,
    rep: &gpm::flow::FlowReport,
    t_end: f64,
    stop: &AtomicBool,
) -> ControlFlow<()> {
    pb.set_position(((rep.time / t_end).clamp(0.0, 1.0) * 1000.0) as u64);
    if rep.step % 10 == 1 {
        pb.set_message(format!(
            "step {} t={:.4} dt={:.2e} ke={:.4e} ratio={:.3}",
            rep.step,
            rep.time,
            rep.projection.dt,
            rep.projection.kinetic_energy,
            rep.projection.stability_ratio
        ));
    }
    if stop.load(Ordering::SeqCst) {
        ControlFlow::Break(())
    } else {
        ControlFlow::Continue(())
    }
}

fn replay(a: ReplayArgs) -> Result<ExitCode> {
    let bytes_template = "{spinner} {msg} [{bar:40}] {bytes}/{total_bytes}";
    let len = std::fs::metadata(&a.file)
        .with_context(|| format!("reading {}", a.file.display()))?
        .len();
    let pb = progress_bar(len, a.quiet, bytes_template);
    pb.set_message("reading");
    let replay = Replay::open_with_progress(&a.file, |done, _| pb.set_position(done))?;
    pb.finish_and_clear();
    let summary = replay.summary();
    if a.json {
        println!("{}", serde_json::to_string_pretty(&summary)?);
    } else {
        print!("{summary}");
    }
    if let Some(d) = replay.damage() {
        if a.strict {
            eprintln!("error: {}: {d}", a.file.display());
            return Ok(ExitCode::from(2));
        }
        eprintln!("warning: {}: {d}", a.file.display());
    }
    if let Some(csv) = &a.csv {
        replay.write_csv(csv)?;
        eprintln!("wrote {} ({} rows)", csv.display(), replay.steps.len());
    }
    if let Some(png) = &a.plot {
        replay.plot(png)?;
        eprintln!("wrote {}", png.display());
    }
    if let Some(dir) = &a.vtk {
        let pb = progress_bar(len, a.quiet, bytes_template);
        pb.set_message("vtk");
        let out = export_vtk(&a.file, dir, |done, _| pb.set_position(done))?;
        pb.finish_and_clear();
        eprintln!(
            "wrote {} snapshots and {}",
            out.files.len(),
            out.collection.display()
        );
    }
    if a.rerun {
        let pb = progress_bar(len, a.quiet, bytes_template);
        pb.set_message("re-running");
        let r = rerun_file(&a.file, |done, _| pb.set_position(done))?;
        pb.finish_and_clear();
        if r.steps.is_empty() {
            println!(
                "rerun: the file has no /projection_input messages (record with --record full \
                 and the projection capture on)"
            );
        } else {
            let (du, dp, dphi) = r.max_differences();
            let (ru, rp, rphi) = r.max_relative_differences();
            println!(
                "rerun: {} projections re-run, {} bit-identical (recorded with {:?} threads, \
                 re-run with {})",
                r.steps.len(),
                r.identical(),
                r.recorded_threads,
                r.threads
            );
            println!("  max |du|   {du:.3e}  (relative {ru:.3e})");
            println!("  max |dp|   {dp:.3e}  (relative {rp:.3e})");
            println!("  max |dphi| {dphi:.3e}  (relative {rphi:.3e})");
            if r.identical() < r.steps.len() {
                println!(
                    "  not identical: with Cholesky the result is reproducible only when the \
                     neighbour candidates (the matrix pattern) match the run's, which a moving \
                     (Lagrangian) run does not guarantee; with CG the reductions depend on the \
                     thread count and rayon's work split (see gpm::record::rerun)."
                );
            }
        }
    }
    Ok(ExitCode::SUCCESS)
}
