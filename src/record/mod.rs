//! Recording runs to MCAP and reading them back (MISSION §6).
//!
//! A [`Recorder`] writes one file per run with JSON Schema schemas and JSON messages (see
//! [`schema`] for the topics): `/config` once, `/diagnostics` every step, and at level
//! [`RecordLevel::Full`] every `k` steps a `/particles` snapshot (`foxglove.PointCloud`, shown by
//! Foxglove Studio's 3D panel) and a `/projection_input` (everything the projection read and
//! wrote, for [`rerun`]). Log times are simulation times in nanoseconds; the sequence number is
//! the step.
//!
//! **Crash safety.** The recorder closes the current chunk (`mcap::Writer::flush`) and hands it
//! to the operating system every `flush_every` steps (default: every step), so a killed process
//! loses at most the steps since the last flush; [`Recorder::finish`] writes the summary and
//! footer and returns any error (never rely on `Drop`, which discards it). [`replay::Replay`]
//! reads complete files and files cut anywhere (killed runs, truncated copies): it keeps every
//! complete chunk and says where the file was cut.
//!
//! Nothing under `projection` or `poisson` knows about this module: a caller records from the
//! observer of a scene's `run` ([`Recorder::write_step`]), or from its own loop
//! ([`Recorder::record`] with a [`StepRecord`]: the projection's [`StepReport`], a
//! [`StepContext`], and optionally the particles and the projection's capture, for any
//! boundary). `examples/own_loop.rs` records a loop of its own this way.
//!
//! ```
//! use gpm::record::{RecordLevel, Recorder};
//! use gpm::scene::cavity::{self, CavityConfig};
//!
//! let dir = tempfile::tempdir().unwrap();
//! let path = dir.path().join("run.mcap");
//! let cfg = CavityConfig::default().with(|c| { c.n = 12; c.t_end = 0.02; });
//! let config = serde_json::json!({ "scene": "cavity", "config": &cfg });
//! let mut rec = Recorder::create(&path, RecordLevel::Diagnostics, 10, &config)?;
//! cavity::run(&cfg, |report, sim| Ok(rec.write_step(report, sim)?))?;
//! let summary = rec.finish()?; // errors of the final write are reported, not dropped
//!
//! let replay = gpm::record::replay::Replay::open(&path)?;
//! assert_eq!(replay.steps.len() as u64, summary.steps);
//! assert!(replay.damage().is_none());
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

#[cfg(feature = "cli")]
pub mod animate;
pub mod output;
pub mod replay;
pub mod rerun;
pub mod schema;

pub use output::OutputLock;

use crate::boundary::Boundary;
use crate::flow::{DtLimit, FlowReport, Simulation};
use crate::neighbors::NeighborConfig;
use crate::particles::{Particles, Role};
use crate::projection::{ProjectionCapture, ProjectionParams, StepReport};
use mcap::records::MessageHeader;
use schema::{
    encode_roles, Array, BoundarySpec, PointCloud, ProjectionInput, RunConfig, StepDiagnostics,
    ToBoundarySpec,
};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// How much a run records.
#[derive(
    Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema,
)]
#[serde(rename_all = "snake_case")]
pub enum RecordLevel {
    /// Nothing (no file is created).
    None,
    /// `/config` and `/diagnostics` (one small message per step).
    #[default]
    Diagnostics,
    /// Also `/particles` and `/projection_input` every `k` steps.
    Full,
}

impl std::str::FromStr for RecordLevel {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s.trim().to_ascii_lowercase().as_str() {
            "none" | "off" => Ok(RecordLevel::None),
            "diagnostics" | "diag" => Ok(RecordLevel::Diagnostics),
            "full" => Ok(RecordLevel::Full),
            _ => Err(format!(
                "unknown record level '{s}': expected none, diagnostics or full"
            )),
        }
    }
}

impl std::fmt::Display for RecordLevel {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            RecordLevel::None => "none",
            RecordLevel::Diagnostics => "diagnostics",
            RecordLevel::Full => "full",
        })
    }
}

/// Chunk compression of the recorder.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ChunkCompression {
    /// zstd at its default level (3), single-threaded. Measured on the cavity at n = 100
    /// (300 steps, 2 threads): diagnostics 815 kB per 1000 steps at 0.15–0.19 ms per step
    /// (lz4: 1050 kB, 0.11–0.14 ms; none: 1225 kB, 0.08–0.10 ms); full with k = 10 88 MB per
    /// 1000 steps at 1.1 ms per step (lz4: 130 MB, 0.8 ms; none: 191 MB, 0.5–0.65 ms), against
    /// 24 ms per step. The smallest files for under 1 % (diagnostics) or 2.5 % (full) more.
    #[default]
    Zstd,
    /// Uncompressed chunks.
    None,
}

impl std::str::FromStr for ChunkCompression {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s.trim().to_ascii_lowercase().as_str() {
            "zstd" => Ok(ChunkCompression::Zstd),
            "none" => Ok(ChunkCompression::None),
            _ => Err(format!("unknown compression '{s}': expected zstd or none")),
        }
    }
}

impl ChunkCompression {
    fn name(self) -> &'static str {
        match self {
            ChunkCompression::Zstd => "zstd",
            ChunkCompression::None => "none",
        }
    }
}

pub use crate::error::RecordError;

impl RecordError {
    pub(crate) fn io(path: &Path, source: std::io::Error) -> Self {
        RecordError::Io {
            path: path.to_path_buf(),
            source,
        }
    }
    pub(crate) fn mcap(path: &Path, source: mcap::McapError) -> Self {
        match source {
            mcap::McapError::Io(e) => Self::io(path, e),
            source => RecordError::Mcap {
                path: path.to_path_buf(),
                source,
            },
        }
    }
}

/// Simulation time (seconds) to MCAP log time (nanoseconds; negative or non-finite → 0).
pub fn time_to_nanos(t: f64) -> u64 {
    if t.is_finite() && t > 0.0 {
        (t * 1e9).round().min(u64::MAX as f64) as u64
    } else {
        0
    }
}

/// Options of a [`Recorder`]; [`RecorderOptions::new`] gives the defaults.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct RecorderOptions {
    /// What to record.
    pub level: RecordLevel,
    /// `k`: at level `full`, a snapshot and a projection input at steps `1, k+1, 2k+1, …`.
    pub particles_every: u64,
    /// Close a chunk and hand it to the OS every this many steps (default 1). A killed process
    /// loses at most the last `flush_every − 1` steps (plus the one being written). Measured at
    /// n = 100: flushing every step costs about 0.1 ms per step more than every 10 steps
    /// (0.15 vs 0.06 ms, under 1 % of a 24 ms step) and triples a diagnostics file (815 vs
    /// 264 kB per 1000 steps: each chunk carries its own header, index and zstd frame).
    pub flush_every: u64,
    /// Chunk compression (default zstd).
    pub compression: ChunkCompression,
}

impl RecorderOptions {
    /// `level`, snapshots every `particles_every` steps, flush every step, zstd.
    pub fn new(level: RecordLevel, particles_every: u64) -> Self {
        RecorderOptions {
            level,
            particles_every: particles_every.max(1),
            flush_every: 1,
            compression: ChunkCompression::Zstd,
        }
    }
}

/// What a finished recording wrote.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct RecordSummary {
    /// The file (`None` at level `none`).
    pub path: Option<PathBuf>,
    /// Steps recorded.
    pub steps: u64,
    /// Messages per topic.
    pub messages: BTreeMap<String, u64>,
    /// File size in bytes.
    pub bytes: u64,
    /// Wall-clock seconds spent in the recorder (encoding, compressing, flushing, finishing).
    pub seconds: f64,
    /// Things the caller should know (e.g. projection inputs that could not be recorded).
    pub notes: Vec<String>,
}

/// What a step record carries besides the projection's [`StepReport`]: where the step sits in
/// the run and what the loop around the projection measured. [`StepContext::new`] gives what
/// any loop knows (the rest zero, `dt_limit` unknown); [`StepContext::from_flow`] takes it all
/// from a driver's [`FlowReport`].
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct StepContext {
    /// Step number, 1 for the first (the MCAP sequence number; snapshots at `1, k+1, …`).
    pub step: u64,
    /// Simulation time after the step (the MCAP log time is this in nanoseconds).
    pub time: f64,
    /// Floating components the run allows (`ProjectionParams::allowed_floating`); the recorded
    /// connectivity is `ok` when `floating ≤ allowed_floating` and nothing is isolated.
    pub allowed_floating: usize,
    /// Which limit set `Δt` (`None`: the loop chose `Δt` itself; recorded as `null`).
    pub dt_limit: Option<DtLimit>,
    /// The neighbour candidates were rebuilt this step.
    pub neighbors_rebuilt: bool,
    /// Largest particle shift this step (0 without shifting).
    pub max_shift: f64,
    /// Seconds spent on ghosts, neighbour list and volumes.
    pub neighbors_seconds: f64,
    /// Seconds spent on advection, shifting, confinement.
    pub advect_seconds: f64,
    /// Kinetic energy after the step over the energy before it (`None`: first step, from rest,
    /// or not known to the loop).
    pub energy_growth: Option<f64>,
    /// Free surfaces: the surface (band) and splash particles of the step (`None` without a
    /// free surface).
    pub surface: Option<crate::flow::SurfaceCount>,
    /// The volume shift's RMS relative volume error before the move (`None` without one).
    pub volume_error: Option<f64>,
    /// Particles the wall margin stopped this step ([`FlowReport::wall_pushes`]).
    pub wall_pushes: usize,
}

impl StepContext {
    /// Step `step` ending at `time`, in a run allowing `allowed_floating` floating components;
    /// no driver extras.
    pub fn new(step: u64, time: f64, allowed_floating: usize) -> Self {
        StepContext {
            step,
            time,
            allowed_floating,
            ..Default::default()
        }
    }

    /// The context of a driver's step.
    pub fn from_flow(report: &FlowReport, allowed_floating: usize) -> Self {
        StepContext {
            step: report.step,
            time: report.time,
            allowed_floating,
            dt_limit: Some(report.dt_limit),
            neighbors_rebuilt: report.neighbors_rebuilt,
            max_shift: report.max_shift,
            neighbors_seconds: report.neighbors_seconds,
            advect_seconds: report.advect_seconds,
            energy_growth: report.energy_growth,
            surface: report.surface,
            volume_error: report.volume_error,
            wall_pushes: report.wall_pushes,
        }
    }
}

/// Particles for a `/particles` snapshot, as plain slices with one entry per particle (ghosts
/// included): positions, velocities, pressures, roles.
#[derive(Clone, Copy, Debug)]
pub struct ParticleView<'a, const D: usize> {
    /// Positions.
    pub x: &'a [[f64; D]],
    /// Velocities.
    pub u: &'a [[f64; D]],
    /// Pressures.
    pub p: &'a [f64],
    /// Roles.
    pub role: &'a [Role],
}

impl<'a, const D: usize> From<&'a Particles<D>> for ParticleView<'a, D> {
    fn from(p: &'a Particles<D>) -> Self {
        ParticleView {
            x: &p.x,
            u: &p.u,
            p: &p.p,
            role: &p.role,
        }
    }
}

impl<const D: usize> ParticleView<'_, D> {
    /// Every slice has one entry per position.
    fn check(&self) -> Result<(), RecordError> {
        let n = self.x.len();
        for (field, len) in [
            ("u", self.u.len()),
            ("p", self.p.len()),
            ("role", self.role.len()),
        ] {
            if len != n {
                return Err(RecordError::Spec {
                    what: "particle snapshot",
                    reason: format!("{field} has {len} entries for {n} positions"),
                });
            }
        }
        Ok(())
    }
}

/// What a `/projection_input` records: the projection's capture (inputs and outputs of one
/// `project` call) and what it ran with, enough for [`rerun`] to run it again.
#[derive(Clone, Copy, Debug)]
pub struct ProjectionRecord<'a, const D: usize> {
    /// The capture of the step's projection (`ProjectionStep::captured` after a `project`
    /// with `capture = true`).
    pub capture: &'a ProjectionCapture<D>,
    /// The neighbour list's configuration.
    pub neighbors: &'a NeighborConfig<D>,
    /// The boundary: [`ToBoundarySpec::to_spec`] for the crate's boundaries,
    /// [`BoundarySpec::Custom`] for one of your own (recorded, not re-runnable).
    pub boundary: &'a BoundarySpec,
    /// The projection's parameters.
    pub params: &'a ProjectionParams<D>,
}

impl<const D: usize> ProjectionRecord<'_, D> {
    /// The message of step `step` ending at `time`.
    fn message(&self, step: u64, time: f64) -> ProjectionInput {
        // exhaustive on purpose: whatever the projection captures is recorded
        let ProjectionCapture {
            x,
            vol,
            role,
            u_star,
            p_in,
            phi_in,
            dt,
            u_out,
            p_out,
            phi,
            singular,
        } = self.capture;
        let (role_kind, ghost_source, ghost_walls) = encode_roles(role);
        ProjectionInput {
            step,
            time,
            dt: *dt,
            dimension: D,
            particles: x.len(),
            threads: rayon::current_num_threads(),
            neighbors: self.neighbors.into(),
            boundary: self.boundary.clone(),
            params: self.params.into(),
            x: Array::from_vectors(x),
            vol: Array::from_f64(vol),
            role_kind,
            ghost_source,
            ghost_walls,
            u_star: Array::from_vectors(u_star),
            p_in: Array::from_f64(p_in),
            phi_in: Array::from_f64(phi_in),
            u_out: Array::from_vectors(u_out),
            p_out: Array::from_f64(p_out),
            phi: Array::from_f64(phi),
            singular_source: singular.as_ref().map(|s| Array::from_vectors(&s.source)),
            singular_no_slip: singular.as_ref().map(|s| Array::from_vectors(&s.no_slip)),
        }
    }
}

/// One step for [`Recorder::record`], from any loop and any boundary.
#[derive(Clone, Copy, Debug)]
pub struct StepRecord<'a, const D: usize> {
    /// Step number, time and what the loop measured.
    pub context: StepContext,
    /// The projection's report of the step.
    pub report: &'a StepReport,
    /// The particles after the step, for a snapshot (used at snapshot steps only).
    pub particles: Option<ParticleView<'a, D>>,
    /// The projection's capture and settings (used at snapshot steps only).
    pub projection: Option<ProjectionRecord<'a, D>>,
}

impl<'a, const D: usize> StepRecord<'a, D> {
    /// The diagnostics of a step only (no snapshot, no projection input).
    pub fn new(context: StepContext, report: &'a StepReport) -> Self {
        StepRecord {
            context,
            report,
            particles: None,
            projection: None,
        }
    }
}

struct Inner {
    /// The file being written ([`output::partial_path`] of `target`).
    path: PathBuf,
    /// Where the finished file goes.
    target: PathBuf,
    writer: mcap::Writer<BufWriter<File>>,
    ch_diagnostics: u16,
    ch_particles: u16,
    ch_projection: u16,
    buf: Vec<u8>,
    since_flush: u64,
    counts: BTreeMap<String, u64>,
    missing_capture: bool,
    missing_particles: bool,
}

/// Writes a run to an MCAP file. Create it before the run, call
/// [`write_step`](Self::write_step) after every step (from a scene's observer or your own loop)
/// and [`finish`](Self::finish) at the end. At level [`RecordLevel::None`] every call is a no-op
/// and no file is created.
pub struct Recorder {
    inner: Option<Inner>,
    options: RecorderOptions,
    steps: u64,
    seconds: f64,
    last_seconds: f64,
}

impl std::fmt::Debug for Recorder {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Recorder")
            .field("path", &self.path())
            .field("options", &self.options)
            .field("steps", &self.steps)
            .finish_non_exhaustive()
    }
}

impl Recorder {
    /// Starts a recording meant for `path` and writes `/config` with `config`: the run's configuration,
    /// any serde-serialisable value, recorded verbatim as JSON (for `gpm run` it is
    /// `{"scene": "cavity", "config": {...}}`; a loop of your own passes its own settings, or
    /// `&()` for none, recorded as `null`). Snapshots every
    /// `particles_every` steps at level `full`; flushes every step; zstd chunks.
    ///
    /// The file is written as `path.partial` ([`output::partial_path`]; created or truncated)
    /// and renamed to `path` by [`finish`](Self::finish), so an earlier recording at `path` is
    /// replaced only by a finished one; a killed process leaves `path.partial`, which
    /// [`replay::Replay`] reads up to its last flushed step. The recorder takes no lock: two
    /// writers of one path are kept apart by an [`OutputLock`] on the directory
    /// ([`crate::scene::run_recorded`] takes one).
    pub fn create<C: Serialize + ?Sized>(
        path: impl AsRef<Path>,
        level: RecordLevel,
        particles_every: u64,
        config: &C,
    ) -> Result<Self, RecordError> {
        Self::create_with(path, RecorderOptions::new(level, particles_every), config)
    }

    /// [`create`](Self::create) with every option.
    pub fn create_with<C: Serialize + ?Sized>(
        path: impl AsRef<Path>,
        options: RecorderOptions,
        config: &C,
    ) -> Result<Self, RecordError> {
        let options = RecorderOptions {
            particles_every: options.particles_every.max(1),
            flush_every: options.flush_every.max(1),
            ..options
        };
        let mut rec = Recorder {
            inner: None,
            options,
            steps: 0,
            seconds: 0.0,
            last_seconds: 0.0,
        };
        if options.level == RecordLevel::None {
            return Ok(rec);
        }
        let t0 = Instant::now();
        let target = path.as_ref().to_path_buf();
        let path = output::partial_path(&target);
        let config = serde_json::to_value(config).map_err(|e| RecordError::Json {
            path: path.clone(),
            what: "/config".into(),
            source: e,
        })?;
        let file = File::create(&path).map_err(|e| RecordError::io(&path, e))?;
        let compression = match options.compression {
            ChunkCompression::Zstd => Some(mcap::Compression::Zstd),
            ChunkCompression::None => None,
        };
        let me = |e| RecordError::mcap(&path, e);
        let mut writer = mcap::WriteOptions::new()
            .compression(compression)
            .chunk_size(Some(4 << 20))
            // one thread: chunks are small and the run's own threads are busy
            .compression_threads(0)
            .profile("")
            .library(format!("gpm {}", env!("CARGO_PKG_VERSION")))
            .create(BufWriter::with_capacity(1 << 16, file))
            .map_err(me)?;
        let mut ids = BTreeMap::new();
        for (topic, name, schema) in schema::all_schemas() {
            if options.level != RecordLevel::Full
                && (topic == schema::TOPIC_PARTICLES || topic == schema::TOPIC_PROJECTION)
            {
                continue;
            }
            let bytes = serde_json::to_vec(&schema).expect("schemas serialise");
            let sid = writer.add_schema(name, "jsonschema", &bytes).map_err(me)?;
            let cid = writer
                .add_channel(sid, topic, "json", &BTreeMap::new())
                .map_err(me)?;
            ids.insert(topic, cid);
        }
        let run = RunConfig {
            format: "gpm-mcap".into(),
            format_version: schema::FORMAT_VERSION,
            gpm_version: env!("CARGO_PKG_VERSION").into(),
            level: options.level,
            particles_every: options.particles_every,
            flush_every: options.flush_every,
            compression: options.compression.name().into(),
            threads: rayon::current_num_threads(),
            config,
        };
        let data = serde_json::to_vec(&run).map_err(|e| RecordError::Json {
            path: path.clone(),
            what: "/config".into(),
            source: e,
        })?;
        writer
            .write_to_known_channel(
                &MessageHeader {
                    channel_id: ids[schema::TOPIC_CONFIG],
                    sequence: 0,
                    log_time: 0,
                    publish_time: 0,
                },
                &data,
            )
            .map_err(me)?;
        writer.flush().map_err(me)?;
        let mut counts = BTreeMap::new();
        counts.insert(schema::TOPIC_CONFIG.to_string(), 1);
        rec.inner = Some(Inner {
            ch_diagnostics: ids[schema::TOPIC_DIAGNOSTICS],
            ch_particles: ids.get(schema::TOPIC_PARTICLES).copied().unwrap_or(0),
            ch_projection: ids.get(schema::TOPIC_PROJECTION).copied().unwrap_or(0),
            path,
            target,
            writer,
            buf: Vec::with_capacity(4096),
            since_flush: 0,
            counts,
            missing_capture: false,
            missing_particles: false,
        });
        rec.seconds += t0.elapsed().as_secs_f64();
        Ok(rec)
    }

    /// The file being written, `path.partial` until [`finish`](Self::finish) renames it
    /// (`None` at level `none`).
    pub fn path(&self) -> Option<&Path> {
        self.inner.as_ref().map(|i| i.path.as_path())
    }

    /// Where the finished file goes (the `path` given to [`create`](Self::create); `None` at
    /// level `none`).
    pub fn target(&self) -> Option<&Path> {
        self.inner.as_ref().map(|i| i.target.as_path())
    }

    /// The options in force.
    pub fn options(&self) -> &RecorderOptions {
        &self.options
    }

    /// Steps recorded so far.
    pub fn steps(&self) -> u64 {
        self.steps
    }

    /// True when step `step` gets a `/particles` snapshot and a `/projection_input` (level
    /// `full`, steps `1, k+1, 2k+1, …`): a loop of its own sets its projection's `capture` flag
    /// from this before projecting, and passes particles and capture only then.
    pub fn wants_snapshot(&self, step: u64) -> bool {
        self.inner.is_some()
            && self.options.level == RecordLevel::Full
            && (step.max(1) - 1).is_multiple_of(self.options.particles_every)
    }

    /// Records one step of a [`Simulation`]: [`record`](Self::record) with the flow report's
    /// context, the simulation's particles, and its last projection capture when it belongs to
    /// this step. Set `sim.projection.capture = true` before the run to record projection
    /// inputs; without it they are skipped and a note is returned by [`finish`](Self::finish).
    pub fn write_step<const D: usize, B: Boundary<D> + ToBoundarySpec<D>>(
        &mut self,
        report: &FlowReport,
        sim: &Simulation<D, B>,
    ) -> Result<(), RecordError> {
        let context = StepContext::from_flow(report, sim.params.projection.allowed_floating);
        if !self.wants_snapshot(report.step) {
            return self.record::<D>(&StepRecord::new(context, &report.projection));
        }
        let boundary = sim.boundary.to_spec();
        let projection = sim
            .projection
            .captured
            .as_ref()
            .filter(|c| c.dt == report.projection.dt && c.phi == sim.projection.phi)
            .map(|capture| ProjectionRecord {
                capture,
                neighbors: sim.nl.config(),
                boundary: &boundary,
                params: &sim.params.projection,
            });
        self.record(&StepRecord {
            particles: Some((&sim.particles).into()),
            projection,
            ..StepRecord::new(context, &report.projection)
        })
    }

    /// Records one step from any loop: `/diagnostics` always (from `rec.report` and
    /// `rec.context`); at level `full`, at the steps [`wants_snapshot`](Self::wants_snapshot)
    /// names, `/particles` from `rec.particles` and `/projection_input` from `rec.projection`
    /// (either missing: skipped, with a note from [`finish`](Self::finish)). Flushes every
    /// `flush_every` steps. Particle slices of different lengths are an error
    /// ([`RecordError::Spec`]), found before anything of the step is written.
    pub fn record<const D: usize>(&mut self, rec: &StepRecord<'_, D>) -> Result<(), RecordError> {
        let snapshot = self.wants_snapshot(rec.context.step);
        let Some(inner) = self.inner.as_mut() else {
            return Ok(());
        };
        if let (true, Some(view)) = (snapshot, &rec.particles) {
            view.check()?;
        }
        let t0 = Instant::now();
        let step = rec.context.step;
        let time = rec.context.time;
        let log_time = time_to_nanos(time);
        let header = |channel_id| MessageHeader {
            channel_id,
            sequence: step as u32,
            log_time,
            publish_time: log_time,
        };
        let diag = StepDiagnostics::new(&rec.context, rec.report, self.last_seconds);
        inner.write(
            header(inner.ch_diagnostics),
            schema::TOPIC_DIAGNOSTICS,
            step,
            &diag,
        )?;
        if snapshot {
            match &rec.particles {
                Some(v) => {
                    let cloud = PointCloud::from_particles(time, v.x, v.u, v.p, v.role);
                    inner.write(
                        header(inner.ch_particles),
                        schema::TOPIC_PARTICLES,
                        step,
                        &cloud,
                    )?;
                }
                None => inner.missing_particles = true,
            }
            match &rec.projection {
                Some(pr) => {
                    let msg = pr.message(step, time);
                    inner.write(
                        header(inner.ch_projection),
                        schema::TOPIC_PROJECTION,
                        step,
                        &msg,
                    )?;
                }
                None => inner.missing_capture = true,
            }
        }
        inner.since_flush += 1;
        if inner.since_flush >= self.options.flush_every {
            inner
                .writer
                .flush()
                .map_err(|e| RecordError::mcap(&inner.path, e))?;
            inner.since_flush = 0;
        }
        self.steps += 1;
        self.last_seconds = t0.elapsed().as_secs_f64();
        self.seconds += self.last_seconds;
        Ok(())
    }

    /// Writes the summary and footer, flushes and syncs the file, renames it to its target
    /// (replacing an earlier file there) and reports any error. On an error the file stays at
    /// its `.partial` name (every flushed step reads back) and the target is untouched.
    pub fn finish(self) -> Result<RecordSummary, RecordError> {
        let (mut out, inner) = self.close()?;
        if let Some((partial, target)) = inner {
            std::fs::rename(&partial, &target).map_err(|e| RecordError::io(&target, e))?;
            sync_dir(&target);
            out.path = Some(target);
        }
        Ok(out)
    }

    /// [`finish`](Self::finish) for a run that failed: the file is finished (every step before
    /// the failure reads back, and the `/config` even without a step) and kept as
    /// [`output::failed_path`] of the target (`run.failed.mcap`, replacing an earlier failed
    /// one), so that a good earlier recording at the target is not replaced.
    pub fn finish_failed(self) -> Result<RecordSummary, RecordError> {
        let (mut out, inner) = self.close()?;
        if let Some((partial, target)) = inner {
            let failed = output::failed_path(&target);
            std::fs::rename(&partial, &failed).map_err(|e| RecordError::io(&failed, e))?;
            sync_dir(&failed);
            out.path = Some(failed);
        }
        Ok(out)
    }

    /// Footer, flush and sync; the summary (its `path` the partial file) and the paths.
    fn close(self) -> Result<(RecordSummary, Option<(PathBuf, PathBuf)>), RecordError> {
        let mut out = RecordSummary {
            steps: self.steps,
            seconds: self.seconds,
            ..Default::default()
        };
        let Some(mut inner) = self.inner else {
            return Ok((out, None));
        };
        let t0 = Instant::now();
        let path = inner.path.clone();
        inner
            .writer
            .finish()
            .map_err(|e| RecordError::mcap(&path, e))?;
        let file = inner
            .writer
            .into_inner()
            .into_inner()
            .map_err(|e| RecordError::io(&path, e.into_error()))?;
        file.sync_all().map_err(|e| RecordError::io(&path, e))?;
        out.bytes = file
            .metadata()
            .map_err(|e| RecordError::io(&path, e))?
            .len();
        out.seconds += t0.elapsed().as_secs_f64();
        if inner.missing_particles {
            out.notes.push(
                "particle snapshots were not recorded at some snapshot steps: no particles were \
                 given (StepRecord::particles)"
                    .into(),
            );
        }
        if inner.missing_capture {
            out.notes.push(
                "projection inputs were not recorded at some snapshot steps: no fresh projection \
                 capture was given (set capture = true on the ProjectionStep, \
                 sim.projection.capture for a Simulation, before projecting)"
                    .into(),
            );
        }
        out.messages = inner.counts;
        out.path = Some(path.clone());
        Ok((out, Some((path, inner.target))))
    }
}

/// Syncs the directory holding `path` so that a rename in it is durable (best effort: not every
/// platform can open a directory).
fn sync_dir(path: &Path) {
    if let Some(dir) = path.parent() {
        let dir = if dir.as_os_str().is_empty() {
            Path::new(".")
        } else {
            dir
        };
        if let Ok(d) = File::open(dir) {
            let _ = d.sync_all();
        }
    }
}

impl Inner {
    fn write<T: Serialize>(
        &mut self,
        header: MessageHeader,
        topic: &str,
        step: u64,
        msg: &T,
    ) -> Result<(), RecordError> {
        self.buf.clear();
        serde_json::to_writer(&mut self.buf, msg).map_err(|e| RecordError::Json {
            path: self.path.clone(),
            what: format!("{topic} step {step}"),
            source: e,
        })?;
        self.writer
            .write_to_known_channel(&header, &self.buf)
            .map_err(|e| RecordError::mcap(&self.path, e))?;
        *self.counts.entry(topic.to_string()).or_insert(0) += 1;
        Ok(())
    }
}
