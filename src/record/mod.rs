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
//! observer of a scene's `run`, or from its own loop.
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

pub mod replay;
pub mod rerun;
pub mod schema;

use crate::boundary::Boundary;
use crate::flow::{FlowReport, Simulation};
use crate::projection::ProjectionCapture;
use mcap::records::MessageHeader;
use schema::{
    encode_roles, Array, PointCloud, ProjectionInput, RunConfig, StepDiagnostics, ToBoundarySpec,
};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// How much a run records.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
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

/// Recording and replay failures; each names the file.
#[derive(Debug, thiserror::Error)]
pub enum RecordError {
    /// Creating, writing or reading the file failed.
    #[error("{}: {source}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// The I/O error.
        source: std::io::Error,
    },
    /// The MCAP writer or a record parser failed.
    #[error("{}: MCAP: {source}", path.display())]
    Mcap {
        /// The file.
        path: PathBuf,
        /// The mcap crate's error.
        source: mcap::McapError,
    },
    /// A message could not be encoded or decoded.
    #[error("{}: {what}: {source}", path.display())]
    Json {
        /// The file.
        path: PathBuf,
        /// Which message (topic and step).
        what: String,
        /// The serde error.
        source: serde_json::Error,
    },
    /// The file is not an MCAP file at all.
    #[error("{}: not an MCAP file: {reason}", path.display())]
    NotMcap {
        /// The file.
        path: PathBuf,
        /// Why.
        reason: String,
    },
    /// The file is MCAP but its content is not what gpm writes (or a later format).
    #[error("{}: {message}", path.display())]
    Format {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// A recorded description (boundary, parameters, arrays) cannot be turned back into the
    /// crate's types.
    #[error("recorded {what}: {reason}")]
    Spec {
        /// Which part.
        what: &'static str,
        /// What is wrong.
        reason: String,
    },
    /// Re-running a recorded projection failed.
    #[error("{}: re-running the projection of step {step} failed: {source}", path.display())]
    Rerun {
        /// The file.
        path: PathBuf,
        /// The recorded step.
        step: u64,
        /// The projection's error.
        source: Box<crate::Error>,
    },
}

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

struct Inner {
    path: PathBuf,
    writer: mcap::Writer<BufWriter<File>>,
    ch_diagnostics: u16,
    ch_particles: u16,
    ch_projection: u16,
    buf: Vec<u8>,
    since_flush: u64,
    counts: BTreeMap<String, u64>,
    missing_capture: bool,
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
    /// Creates (truncates) `path` and writes `/config` with `config` (the run's configuration,
    /// verbatim: for `gpm run` it is `{"scene": "cavity", "config": {...}}`). Snapshots every
    /// `particles_every` steps at level `full`; flushes every step; zstd chunks.
    pub fn create(
        path: impl AsRef<Path>,
        level: RecordLevel,
        particles_every: u64,
        config: &serde_json::Value,
    ) -> Result<Self, RecordError> {
        Self::create_with(path, RecorderOptions::new(level, particles_every), config)
    }

    /// [`create`](Self::create) with every option.
    pub fn create_with(
        path: impl AsRef<Path>,
        options: RecorderOptions,
        config: &serde_json::Value,
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
        let path = path.as_ref().to_path_buf();
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
            config: config.clone(),
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
            writer,
            buf: Vec::with_capacity(4096),
            since_flush: 0,
            counts,
            missing_capture: false,
        });
        rec.seconds += t0.elapsed().as_secs_f64();
        Ok(rec)
    }

    /// The file being written (`None` at level `none`).
    pub fn path(&self) -> Option<&Path> {
        self.inner.as_ref().map(|i| i.path.as_path())
    }

    /// The options in force.
    pub fn options(&self) -> &RecorderOptions {
        &self.options
    }

    /// Steps recorded so far.
    pub fn steps(&self) -> u64 {
        self.steps
    }

    /// Records one step: `/diagnostics` always; at level `full`, every `k` steps, `/particles`
    /// and `/projection_input`. The projection input is the simulation's last projection
    /// capture, so set `sim.projection.capture = true` before the run; without it the input is
    /// skipped and a note is returned by [`finish`](Self::finish). Flushes every `flush_every`
    /// steps.
    pub fn write_step<const D: usize, B: Boundary<D> + ToBoundarySpec<D>>(
        &mut self,
        report: &FlowReport,
        sim: &Simulation<D, B>,
    ) -> Result<(), RecordError> {
        let Some(inner) = self.inner.as_mut() else {
            return Ok(());
        };
        let t0 = Instant::now();
        let step = report.step;
        let log_time = time_to_nanos(report.time);
        let header = |channel_id| MessageHeader {
            channel_id,
            sequence: step as u32,
            log_time,
            publish_time: log_time,
        };
        let diag = StepDiagnostics::from_report(
            report,
            sim.params.projection.allowed_floating,
            self.last_seconds,
        );
        inner.write(
            header(inner.ch_diagnostics),
            schema::TOPIC_DIAGNOSTICS,
            step,
            &diag,
        )?;
        let k = self.options.particles_every;
        if self.options.level == RecordLevel::Full && (step.max(1) - 1) % k == 0 {
            let p = &sim.particles;
            let cloud = PointCloud::from_particles(report.time, &p.x, &p.u, &p.p, &p.role);
            inner.write(
                header(inner.ch_particles),
                schema::TOPIC_PARTICLES,
                step,
                &cloud,
            )?;
            let fresh = sim
                .projection
                .captured
                .as_ref()
                .filter(|c| c.dt == report.projection.dt && c.phi == sim.projection.phi);
            match fresh {
                Some(c) => {
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
                    } = c;
                    let (role_kind, ghost_source, ghost_walls) = encode_roles(role);
                    let msg = ProjectionInput {
                        step,
                        time: report.time,
                        dt: *dt,
                        dimension: D,
                        particles: x.len(),
                        threads: rayon::current_num_threads(),
                        neighbors: sim.nl.config().into(),
                        boundary: sim.boundary.to_spec(),
                        params: (&sim.params.projection).into(),
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
                    };
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

    /// Writes the summary and footer, flushes and syncs the file, and reports any error.
    pub fn finish(self) -> Result<RecordSummary, RecordError> {
        let mut out = RecordSummary {
            steps: self.steps,
            seconds: self.seconds,
            ..Default::default()
        };
        let Some(mut inner) = self.inner else {
            return Ok(out);
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
        if inner.missing_capture {
            out.notes.push(
                "projection inputs were not recorded: the simulation's projection capture was \
                 off (set sim.projection.capture = true before the run)"
                    .into(),
            );
        }
        out.messages = inner.counts;
        out.path = Some(path);
        Ok(out)
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
