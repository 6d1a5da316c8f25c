//! `gpm`: run scenes with MCAP recording, and replay recorded runs.
//!
//! ```text
//! gpm run cavity --re 100 --n 50 --out results/cavity      # writes results/cavity/run.mcap
//! gpm run taylor-green --n 32 --t-end 0.5 --record full --record-every 10 --out results/tg
//! gpm replay results/cavity/run.mcap --csv steps.csv --plot steps.png
//! gpm replay results/tg/run.mcap --vtk results/tg/vtk --rerun
//! gpm replay results/tg/run.mcap --animate tg.gif --field pressure
//! ```
//!
//! Errors are printed as one line (with their causes) and the exit status is non-zero. SIGINT
//! (Ctrl-C), SIGTERM and SIGHUP stop a run after the current step and finish the MCAP file (exit
//! status 128 + the signal: 130, 143, 129); a second signal exits at once, keeping every flushed
//! step in `run.mcap.partial`. A run owns its output directory (`DIR/.gpm.lock`; a second run
//! into it fails at once, naming the holder's process id) and writes `run.mcap.partial`, renamed
//! to `run.mcap` when it ends; a run that fails keeps its steps in `run.failed.mcap`, so an
//! earlier good `run.mcap` is never replaced by a failed one. Before a run starts, its memory and
//! step count are estimated and a run that would not fit (or take more than 10⁶ steps) is
//! refused with the estimate unless `--force`. `replay` reads cut or damaged files with a warning
//! naming the byte offset; `--strict` makes that an error (exit status 2); it never writes onto
//! its input, and inputs must be regular files (a FIFO is refused, not waited on). A closed
//! standard output (`gpm replay f | head -1`) ends the program quietly with status 0; a full one
//! is an error.

use anyhow::{bail, Context, Result};
use clap::{Args, Parser, Subcommand};
use gpm::flow::Motion;
use gpm::kernel::Weight;
use gpm::projection::Scheme;
use gpm::record::animate::{animate, AnimateOptions, Scale};
use gpm::record::output::{check_input_file, check_output_file};
use gpm::record::replay::{export_vtk, Replay};
use gpm::record::rerun::rerun_file;
use gpm::record::{ChunkCompression, RecordLevel, RecorderOptions};
use gpm::scene::{run_recorded_with, Scene, SceneConfig, SceneVisitor};
use indicatif::{ProgressBar, ProgressStyle};
use std::io::Write;
use std::ops::ControlFlow;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

/// Prints to standard output; an error (closed pipe, full disk) is returned, not a panic.
macro_rules! outln {
    ($($arg:tt)*) => {
        writeln!(std::io::stdout().lock(), $($arg)*).context("writing to standard output")
    };
}

/// Prints a line to standard error, ignoring a failure (there is nowhere left to report it).
macro_rules! errln {
    ($($arg:tt)*) => {{
        let _ = writeln!(std::io::stderr().lock(), $($arg)*);
    }};
}

/// Largest estimated step count a run may have without `--force`.
const MAX_STEPS: f64 = 1e6;
/// Largest configuration file read (bytes).
const MAX_CONFIG_BYTES: u64 = 16 << 20;

/// SIGINT, SIGTERM and SIGHUP: the first stops a run after its current step (`gpm run`) or
/// exits at once (anything else); a second exits at once. Exit status 128 + the signal.
#[path = "gpm/ranks.rs"]
mod ranks;

mod signals {
    use std::sync::atomic::{AtomicBool, AtomicI32, Ordering};

    static RECEIVED: AtomicI32 = AtomicI32::new(0);
    static GRACEFUL: AtomicBool = AtomicBool::new(false);

    fn on_signal(sig: i32) {
        let first = RECEIVED
            .compare_exchange(0, sig, Ordering::SeqCst, Ordering::SeqCst)
            .is_ok();
        if !(first && GRACEFUL.load(Ordering::SeqCst)) {
            std::process::exit(128 + sig);
        }
    }

    /// Blocks the three signals in this thread (and so in every thread started later: call it
    /// first in `main`) and waits for them on a thread of its own.
    #[cfg(unix)]
    pub fn install() -> std::io::Result<()> {
        use nix::sys::signal::{SigSet, Signal};
        let mut set = SigSet::empty();
        for s in [Signal::SIGINT, Signal::SIGTERM, Signal::SIGHUP] {
            set.add(s);
        }
        set.thread_block().map_err(std::io::Error::from)?;
        std::thread::Builder::new()
            .name("signals".into())
            .spawn(move || {
                while let Ok(sig) = set.wait() {
                    on_signal(sig as i32);
                }
            })?;
        Ok(())
    }

    /// Ctrl-C (and the console's close and shutdown events) where there are no Unix signals.
    #[cfg(not(unix))]
    pub fn install() -> std::io::Result<()> {
        ctrlc::set_handler(|| on_signal(2)).map_err(std::io::Error::other)
    }

    /// From now on the first signal only sets [`received`] (a run stops after its step).
    pub fn graceful() {
        GRACEFUL.store(true, Ordering::SeqCst);
    }

    /// The first signal received, if any.
    pub fn received() -> Option<i32> {
        match RECEIVED.load(Ordering::SeqCst) {
            0 => None,
            s => Some(s),
        }
    }

    /// The signal's name.
    pub fn name(sig: i32) -> &'static str {
        match sig {
            1 => "SIGHUP",
            2 => "SIGINT",
            15 => "SIGTERM",
            _ => "a signal",
        }
    }
}

#[derive(Parser, Debug)]
#[command(
    name = "gpm",
    version,
    about = "Incompressible particle flows with the generalized particle method"
)]
struct Cli {
    /// Rayon worker threads, 1 to 4 × the available cores (default: all cores).
    #[arg(long, global = true)]
    threads: Option<usize>,
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Run a scene and record it to DIR/run.mcap.
    Run(RunArgs),
    /// Summarise, plot, animate, export or re-run a recorded MCAP file (complete or cut).
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
    /// Scene: cavity (lid-driven, compared with Ghia et al. 1982), cube (the 3D lid-driven
    /// cavity), taylor-green (periodic vortex, exact solution), channel, hydrostatic, dam-break,
    /// dam-break-3d (a column in a box).
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
    /// Influence radius over particle spacing (default: the scene's `h_over_dx`, 3, or 4 for
    /// the dam breaks; unlike the cavity example, which takes 2.5 for fixed particles).
    #[arg(long)]
    h_ratio: Option<f64>,
    /// Particle frame: lagrangian or eulerian.
    #[arg(long)]
    motion: Option<Motion>,
    /// CFL number on h/U (the key `limits.cfl`; default 0.2, except a Lagrangian cavity's:
    /// 0.15 up to the cell Reynolds number Re/n = 4, 0.1 above — `scene::cavity::lagrangian_cfl`).
    #[arg(long)]
    cfl: Option<f64>,
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
    /// Run even when the estimated memory exceeds the available memory or the estimated step
    /// count exceeds 10⁶.
    #[arg(long)]
    force: bool,
    /// Warm start: the velocity and pressure of another run's particles.csv (any resolution),
    /// sampled at this run's particles before the first step (the key `initial`).
    #[arg(long)]
    initial: Option<PathBuf>,
    /// Also write the final fluid particles into OUT/particles.csv (`x,y[,z],u,v[,w],p`), e.g.
    /// the warm start of a finer run.
    #[arg(long)]
    particles_csv: bool,
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
    /// Draw the particle snapshots (a `--record full` run) as an animated GIF.
    #[arg(long, value_name = "OUT.gif")]
    animate: Option<PathBuf>,
    /// Colour of --animate: speed, pressure, surface (the free-surface band), u, v, w, or any
    /// field of the point clouds (x, y, vx, p, role, …).
    #[arg(long, default_value = "speed", requires = "animate")]
    field: String,
    /// Frames per second of --animate (1 to 50).
    #[arg(long, default_value_t = 10.0, requires = "animate")]
    fps: f64,
    /// Frame size of --animate in pixels: WxH, or W alone (the height then follows the
    /// domain's aspect ratio).
    #[arg(long, default_value = "720", value_parser = frame_size, requires = "animate")]
    size: (u32, Option<u32>),
    /// At most this many frames in --animate (evenly spaced snapshots beyond).
    #[arg(long, default_value_t = 200, requires = "animate")]
    max_frames: usize,
    /// Colour scale of --animate, fixed for all frames: min-max (the smallest to the largest
    /// value over all frames), robust (the 1 % to the 99 % quantile over all frames), or
    /// LOW:HIGH; values beyond it take the end colours.
    #[arg(long, value_name = "SCALE", default_value = "min-max", value_parser = colour_scale, requires = "animate")]
    scale: Scale,
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

/// `720x400` or `720`.
fn frame_size(s: &str) -> Result<(u32, Option<u32>), String> {
    let num = |t: &str| {
        t.trim()
            .parse::<u32>()
            .map_err(|_| format!("'{s}': expected WIDTHxHEIGHT or WIDTH in pixels"))
    };
    match s.split_once(['x', 'X']) {
        Some((w, h)) => Ok((num(w)?, Some(num(h)?))),
        None => Ok((num(s)?, None)),
    }
}

/// `min-max`, `robust` or `-0.5:3`.
fn colour_scale(s: &str) -> Result<Scale, String> {
    match s.trim() {
        "min-max" | "minmax" => return Ok(Scale::MinMax),
        "robust" => return Ok(Scale::Robust),
        _ => {}
    }
    let bad =
        || format!("'{s}': expected min-max, robust, or LOW:HIGH (two finite numbers, LOW < HIGH)");
    let (a, b) = s.split_once(':').ok_or_else(bad)?;
    let (low, high): (f64, f64) = (
        a.trim().parse().map_err(|_| bad())?,
        b.trim().parse().map_err(|_| bad())?,
    );
    if low.is_finite() && high.is_finite() && low < high {
        Ok(Scale::Given { low, high })
    } else {
        Err(bad())
    }
}

fn main() -> ExitCode {
    // before any other thread exists, so that every thread inherits the blocked signals
    if let Err(e) = signals::install() {
        errln!("warning: signals will not finish the recording: {e}");
    }
    let cli = Cli::parse();
    let result = real_main(cli).and_then(|code| {
        std::io::stdout()
            .flush()
            .context("writing to standard output")?;
        Ok(code)
    });
    match result {
        Ok(code) => code,
        Err(e) if broken_pipe(&e) => ExitCode::SUCCESS, // `gpm replay f | head -1`
        Err(e) => {
            errln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}

/// True when the error is a write to a closed pipe (the reader has gone: nothing to report).
fn broken_pipe(e: &anyhow::Error) -> bool {
    e.chain().any(|c| {
        c.downcast_ref::<std::io::Error>()
            .is_some_and(|io| io.kind() == std::io::ErrorKind::BrokenPipe)
    })
}

fn real_main(cli: Cli) -> Result<ExitCode> {
    if let Some(t) = cli.threads {
        let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
        let max = 4 * cores;
        if t == 0 || t > max {
            bail!(
                "--threads {t}: must be in 1..={max} (4 × the {cores} available cores; more \
                 threads than cores only add overhead)"
            );
        }
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

/// Reads a scene configuration: a bare config, or a `/config` message's `{"scene", "config"}`
/// (strict: duplicate keys, positional arrays and unknown keys are errors naming the key),
/// and whether it gives `limits.cfl` itself.
fn load_config<S: gpm::scene::SceneParams>(path: &Path) -> Result<(SceneConfig<S>, bool)> {
    let m = check_input_file(path)?;
    if m.len() > MAX_CONFIG_BYTES {
        bail!(
            "{}: {} bytes is too large for a configuration (at most {MAX_CONFIG_BYTES})",
            path.display(),
            m.len()
        );
    }
    let text =
        std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    let cfg = gpm::scene::scene_config_from_json::<S>(&text)
        .with_context(|| format!("invalid {} configuration in {}", S::NAME, path.display()))?;
    Ok((cfg, gpm::scene::scene_config_sets_cfl::<S>(&text)))
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
    // a signal now stops the run after the current step and the file is finished
    signals::graceful();
    let scene = a.scene.clone();
    gpm::scene::visit_scene(&scene, RunScene { a })?
}

/// `gpm run <scene>` for any registered scene.
struct RunScene {
    a: RunArgs,
}

/// Available memory in bytes (`MemAvailable` of `/proc/meminfo`; `None` where unknown).
fn available_memory() -> Option<f64> {
    let text = std::fs::read_to_string("/proc/meminfo").ok()?;
    let line = text.lines().find(|l| l.starts_with("MemAvailable:"))?;
    let kb: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb * 1024.0)
}

/// Refuses a run whose estimated memory exceeds the available memory, or whose estimated step
/// count (`t_end / Δt` with the first step's Δt) exceeds [`MAX_STEPS`], unless `force`.
fn check_estimates<const D: usize, S: Scene<D>>(cfg: &SceneConfig<S>, force: bool) -> Result<()> {
    let (particles, bytes) = cfg.memory_estimate::<D>();
    if let Some(avail) = available_memory() {
        if bytes > avail && !force {
            bail!(
                "the run needs about {:.1} GB ({particles:.2e} particles with n = {}) but {:.1} \
                 GB are available: lower --n, or pass --force to try anyway",
                bytes / 1e9,
                cfg.n,
                avail / 1e9
            );
        }
    }
    let sim = S::build(cfg).context("setting up the run")?;
    let (dt, limit) = sim.time_step();
    let steps = (cfg.t_end - sim.time) / dt;
    if (steps.is_nan() || steps > MAX_STEPS) && !force {
        bail!(
            "the run would take about {steps:.2e} steps (t_end = {} with a first time step of \
             {dt:.3e}, set by {limit:?}), more than {MAX_STEPS:.0e}: shorten t_end, enlarge the \
             time step, or pass --force",
            cfg.t_end
        );
    }
    Ok(())
}

impl SceneVisitor for RunScene {
    type Output = Result<ExitCode>;

    fn visit<const D: usize, S: Scene<D>>(self) -> Result<ExitCode> {
        let RunScene { a } = self;
        let name = S::NAME;
        let (mut cfg, file_cfl): (SceneConfig<S>, bool) = match &a.config {
            Some(p) => load_config::<S>(p)?,
            None => (Default::default(), false),
        };
        override_opt(&mut cfg.re, a.re);
        override_opt(&mut cfg.n, a.n);
        override_opt(&mut cfg.t_end, a.t_end);
        override_opt(&mut cfg.scheme, a.scheme);
        override_opt(&mut cfg.gradient, a.gradient);
        override_opt(&mut cfg.weight, a.weight);
        override_opt(&mut cfg.h_over_dx, a.h_ratio);
        override_opt(&mut cfg.motion, a.motion);
        // without --cfl or the file's limits.cfl: the step the scene needs in the frame,
        // Reynolds number and resolution the flags gave (the Lagrangian cavity's is smaller)
        cfg.limits.cfl = match a.cfl {
            Some(c) => c,
            None if file_cfl => cfg.limits.cfl,
            None => cfg.default_cfl(),
        };
        if a.initial.is_some() {
            cfg.initial = a.initial.clone();
        }
        cfg.validate()
            .with_context(|| format!("invalid {name} configuration"))?;
        check_estimates::<D, S>(&cfg, a.force)?;
        // under mpirun: the particles decomposed over the ranks, rank 0 gathers them after
        // every step and alone observes and writes
        let mut steps = ranks::start::<D, S::Boundary>()?;
        let rank = steps.rank();
        if steps.is_decomposed() && rank == 0 && a.record == RecordLevel::Full {
            errln!(
                "note: a run over several ranks records the gathered particle snapshots but not \
                 the projection inputs (one process's; `gpm replay --rerun` has nothing to re-run)"
            );
        }
        let t_end = cfg.t_end;
        let step_observer =
            |pb: &ProgressBar, rep: &gpm::flow::FlowReport, _: &_| Ok(observe(pb, rep, t_end));
        if rank != 0 {
            let pb = ProgressBar::hidden();
            let run = gpm::scene::run_scene_with(
                &cfg,
                &mut steps,
                |_| {},
                |rep, sim| step_observer(&pb, rep, sim),
            );
            steps.summary();
            run.with_context(|| format!("{name} run failed on rank {rank}"))?;
            return Ok(ExitCode::SUCCESS);
        }
        std::fs::create_dir_all(&a.out).with_context(|| format!("creating {}", a.out.display()))?;
        let path = a.out.join("run.mcap");
        let options = RecorderOptions {
            flush_every: a.flush_every,
            compression: a.compression,
            ..RecorderOptions::new(a.record, a.record_every)
        };
        let bar_template = "{spinner} [{elapsed_precise}] [{bar:40}] {percent:>3}% {msg}";
        let pb = progress_bar(1000, a.quiet, bar_template);
        let done = run_recorded_with(
            &cfg,
            &mut steps,
            &path,
            options,
            &cfg.record_header(),
            |_| {},
            |rep, sim| step_observer(&pb, rep, sim),
        )?;
        pb.finish_and_clear();
        let mpi = steps.summary();
        // the file is finished (or its error known) before the run's outcome is reported
        let record = match done.record {
            Ok(s) => {
                for note in &s.notes {
                    errln!("note: {note}");
                }
                Some(s)
            }
            Err(e) => {
                errln!("error: finishing the recording failed: {e}");
                None
            }
        };
        match done.run {
            Ok(run) => {
                if let Some(step) = run.interrupted() {
                    let sig = signals::received().unwrap_or(2);
                    match &record {
                        Some(r) if a.record != RecordLevel::None => errln!(
                            "interrupted by {} after step {step}; {} finished cleanly ({} steps, \
                             {} bytes)",
                            signals::name(sig),
                            path.display(),
                            r.steps,
                            r.bytes
                        ),
                        _ => errln!("interrupted by {} after step {step}", signals::name(sig)),
                    }
                    return Ok(ExitCode::from((128 + sig).clamp(0, 255) as u8));
                }
                if a.particles_csv {
                    let csv = a.out.join("particles.csv");
                    std::fs::write(&csv, run.sim.particles.fluid_csv())
                        .with_context(|| format!("writing {}", csv.display()))?;
                }
                let mut out =
                    serde_json::json!({ "scene": name, "result": run.result, "record": record });
                if let Some(m) = mpi {
                    out["mpi"] = m;
                }
                outln!("{}", serde_json::to_string_pretty(&out)?)?;
                Ok(if record.is_some() || a.record == RecordLevel::None {
                    ExitCode::SUCCESS
                } else {
                    ExitCode::FAILURE
                })
            }
            Err(e) => {
                if let Some(r) = &record {
                    match &r.path {
                        Some(p) if a.record != RecordLevel::None => errln!(
                            "the recording of the {} steps before the failure is in {} ({} is \
                             left as it was)",
                            r.steps,
                            p.display(),
                            path.display()
                        ),
                        _ => {}
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

/// Progress, and a signal's request: stop after this step.
fn observe(pb: &ProgressBar, rep: &gpm::flow::FlowReport, t_end: f64) -> ControlFlow<()> {
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
    if signals::received().is_some() {
        ControlFlow::Break(())
    } else {
        ControlFlow::Continue(())
    }
}

fn replay(a: ReplayArgs) -> Result<ExitCode> {
    let bytes_template = "{spinner} {msg} [{bar:40}] {bytes}/{total_bytes}";
    let len = check_input_file(&a.file)?.len();
    for out in [&a.csv, &a.plot, &a.animate].into_iter().flatten() {
        check_output_file(out, &a.file)?;
    }
    if let Some(dir) = &a.vtk {
        if gpm::record::output::same_file(dir, &a.file) {
            bail!(
                "{}: is the input file: refusing to write VTK files there",
                dir.display()
            );
        }
    }
    let pb = progress_bar(len, a.quiet, bytes_template);
    pb.set_message("reading");
    let replay = Replay::open_with_progress(&a.file, |done, _| pb.set_position(done))?;
    pb.finish_and_clear();
    let summary = replay.summary();
    if a.json {
        outln!("{}", serde_json::to_string_pretty(&summary)?)?;
    } else {
        write!(std::io::stdout().lock(), "{summary}").context("writing to standard output")?;
    }
    if let Some(d) = replay.damage() {
        if a.strict {
            errln!("error: {}: {d}", a.file.display());
            return Ok(ExitCode::from(2));
        }
        errln!("warning: {}: {d}", a.file.display());
    }
    if let Some(csv) = &a.csv {
        replay.write_csv(csv)?;
        errln!("wrote {} ({} rows)", csv.display(), replay.steps.len());
    }
    if let Some(png) = &a.plot {
        replay.plot(png)?;
        errln!("wrote {}", png.display());
    }
    if let Some(dir) = &a.vtk {
        let pb = progress_bar(len, a.quiet, bytes_template);
        pb.set_message("vtk");
        let out = export_vtk(&a.file, dir, |done, _| pb.set_position(done))?;
        pb.finish_and_clear();
        errln!(
            "wrote {} snapshots and {}",
            out.files.len(),
            out.collection.display()
        );
    }
    if let Some(gif) = &a.animate {
        let opts = AnimateOptions {
            field: a.field.clone(),
            fps: a.fps,
            width: a.size.0,
            height: a.size.1,
            max_frames: a.max_frames,
            scale: a.scale,
        };
        let pb = progress_bar(0, a.quiet, "{spinner} {msg} [{bar:40}] {pos}/{len} frames");
        pb.set_message("animating");
        let r = animate(&a.file, gif, &opts, |done, total| {
            pb.set_length(total as u64);
            pb.set_position(done as u64);
        })?;
        pb.finish_and_clear();
        errln!(
            "wrote {} ({} frames of {} snapshots, {}×{} pixels, {} bytes; '{}' from {:.4e} to \
             {:.4e}, t = {:.4} .. {:.4})",
            gif.display(),
            r.frames,
            r.snapshots,
            r.size.0,
            r.size.1,
            r.bytes,
            r.field,
            r.scale.0,
            r.scale.1,
            r.time_span.0,
            r.time_span.1
        );
    }
    if a.rerun {
        let pb = progress_bar(len, a.quiet, bytes_template);
        pb.set_message("re-running");
        let r = rerun_file(&a.file, |done, _| pb.set_position(done))?;
        pb.finish_and_clear();
        if r.steps.is_empty() {
            outln!(
                "rerun: the file has no /projection_input messages (record with --record full \
                 and the projection capture on)"
            )?;
        } else {
            let (du, dp, dphi) = r.max_differences();
            let (ru, rp, rphi) = r.max_relative_differences();
            outln!(
                "rerun: {} projections re-run, {} bit-identical (recorded with {:?} threads, \
                 re-run with {})",
                r.steps.len(),
                r.identical(),
                r.recorded_threads,
                r.threads
            )?;
            outln!("  max |du|   {du:.3e}  (relative {ru:.3e})")?;
            outln!("  max |dp|   {dp:.3e}  (relative {rp:.3e})")?;
            outln!("  max |dphi| {dphi:.3e}  (relative {rphi:.3e})")?;
            if r.identical() < r.steps.len() {
                outln!(
                    "  not identical: with Cholesky the result is reproducible only when the \
                     neighbour candidates (the matrix pattern) match the run's, which a moving \
                     (Lagrangian) run does not guarantee; with CG the reductions depend on the \
                     thread count and rayon's work split (see gpm::record::rerun)."
                )?;
            }
        }
    }
    Ok(ExitCode::SUCCESS)
}
