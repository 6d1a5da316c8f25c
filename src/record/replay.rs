//! Reading gpm MCAP files back, complete or damaged: summaries, CSV, plots and VTK snapshots.
//!
//! [`scan`] walks the file record by record (the MCAP framing is `opcode u8, length u64, body`)
//! and hands every message to a visitor. Records are parsed and chunks decompressed and
//! CRC-checked by the `mcap` crate (`mcap::parse_record`, `mcap::read::ChunkReader`); the walk
//! itself is ours so that a damaged file can be described by byte offset. It never trusts a
//! length past the end of the file, stops at the first record that is cut or corrupt, and
//! reports where: a process killed mid-run leaves a file without summary and footer whose last
//! chunk may be partly written; everything before that chunk is read. Files that are not MCAP
//! at all (garbage, other formats) are an error; an empty file is a file cut at byte 0.

use super::schema::{
    self, PointCloud, RunConfig, SolveDiagnostics, StepDiagnostics, TOPIC_CONFIG,
    TOPIC_DIAGNOSTICS, TOPIC_PARTICLES,
};
use super::RecordError;
use mcap::records::{op, Record};
use serde::de::DeserializeOwned;
use serde::{Deserialize, Serialize};
use std::collections::HashMap;
use std::fmt;
use std::fs::File;
use std::io::{BufReader, BufWriter, Read, Write};
use std::path::{Path, PathBuf};

/// Chunks claiming more uncompressed bytes than this (16 MiB) and than 64 times their compressed
/// size
/// are treated as corrupt (gpm closes chunks at 4 MiB; a flipped bit must not allocate 2^60).
const MAX_CHUNK: u64 = 1 << 24;

/// Where and why a file stops early.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Damage {
    /// File size in bytes.
    pub file_len: u64,
    /// Bytes read successfully: the end of the last complete record (chunk) that was used.
    pub valid_bytes: u64,
    /// The last `/diagnostics` step read.
    pub last_step: Option<u64>,
    /// True when every data record is present and only the summary section or footer is
    /// damaged (nothing was lost).
    pub data_complete: bool,
    /// What was found at `valid_bytes`.
    pub reason: String,
}

impl fmt::Display for Damage {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if self.data_complete {
            return write!(
                f,
                "the summary section is damaged at byte offset {} of {} ({}); every recorded \
                 message was read",
                self.valid_bytes, self.file_len, self.reason
            );
        }
        match self.last_step {
            Some(s) => write!(
                f,
                "the file was cut after step {s}: complete records up to byte offset {} of {} \
                 ({})",
                self.valid_bytes, self.file_len, self.reason
            ),
            None => write!(
                f,
                "the file was cut before any step was complete: {} valid bytes of {} ({})",
                self.valid_bytes, self.file_len, self.reason
            ),
        }
    }
}

/// One channel of a file.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct ChannelStats {
    /// Topic.
    pub topic: String,
    /// Schema name.
    pub schema: String,
    /// Message encoding.
    pub encoding: String,
    /// Messages read.
    pub messages: u64,
}

/// What [`scan`] found.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Scan {
    /// The file.
    pub path: PathBuf,
    /// Its size.
    pub file_len: u64,
    /// The file ends with summary, footer and magic (the writer finished it).
    pub complete: bool,
    /// Set when the file is cut or damaged.
    pub damage: Option<Damage>,
    /// Channels in order of their first appearance.
    pub channels: Vec<ChannelStats>,
    /// Messages the file's statistics record announces (complete files).
    pub announced_messages: Option<u64>,
}

impl Scan {
    /// Messages read on `topic`.
    pub fn count(&self, topic: &str) -> u64 {
        self.channels
            .iter()
            .filter(|c| c.topic == topic)
            .map(|c| c.messages)
            .sum()
    }
}

/// A message handed to the visitor of [`scan`].
#[derive(Clone, Copy, Debug)]
pub struct LoggedMessage<'a> {
    /// Topic.
    pub topic: &'a str,
    /// Schema name.
    pub schema: &'a str,
    /// Sequence number (the step).
    pub sequence: u32,
    /// Log time in nanoseconds (simulation time).
    pub log_time: u64,
    /// JSON bytes.
    pub data: &'a [u8],
    /// The file.
    pub path: &'a Path,
}

impl LoggedMessage<'_> {
    /// Decodes the JSON message.
    pub fn decode<T: DeserializeOwned>(&self) -> Result<T, RecordError> {
        serde_json::from_slice(self.data).map_err(|e| RecordError::Json {
            path: self.path.to_path_buf(),
            what: format!("{} message {}", self.topic, self.sequence),
            source: e,
        })
    }
}

fn op_name(op: u8) -> String {
    match op {
        op::HEADER => "header".into(),
        op::FOOTER => "footer".into(),
        op::SCHEMA => "schema".into(),
        op::CHANNEL => "channel".into(),
        op::MESSAGE => "message".into(),
        op::CHUNK => "chunk".into(),
        op::MESSAGE_INDEX => "message index".into(),
        op::CHUNK_INDEX => "chunk index".into(),
        op::ATTACHMENT => "attachment".into(),
        op::ATTACHMENT_INDEX => "attachment index".into(),
        op::STATISTICS => "statistics".into(),
        op::METADATA => "metadata".into(),
        op::METADATA_INDEX => "metadata index".into(),
        op::SUMMARY_OFFSET => "summary offset".into(),
        op::DATA_END => "data end".into(),
        o => format!("opcode {o:#04x}"),
    }
}

/// Reads as many bytes as are available, up to `buf.len()`.
fn read_up_to(r: &mut impl Read, buf: &mut [u8]) -> std::io::Result<usize> {
    let mut n = 0;
    while n < buf.len() {
        match r.read(&mut buf[n..]) {
            Ok(0) => break,
            Ok(k) => n += k,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
            Err(e) => return Err(e),
        }
    }
    Ok(n)
}

#[derive(Default)]
struct Linker {
    schemas: HashMap<u16, String>,
    channels: HashMap<u16, usize>,
    stats: Vec<ChannelStats>,
}

impl Linker {
    fn schema(&mut self, id: u16, name: &str) {
        self.schemas.insert(id, name.to_string());
    }
    fn channel(&mut self, id: u16, schema_id: u16, topic: &str, encoding: &str) {
        if self.channels.contains_key(&id) {
            return;
        }
        let schema = self.schemas.get(&schema_id).cloned().unwrap_or_default();
        self.channels.insert(id, self.stats.len());
        self.stats.push(ChannelStats {
            topic: topic.into(),
            schema,
            encoding: encoding.into(),
            messages: 0,
        });
    }
}

/// Walks the file at `path`, calling `visit` for every message in file order and `progress`
/// with `(bytes read, file size)` after every record. Stops without error at the first cut or
/// corrupt record and describes it in [`Scan::damage`]. Errors: the file cannot be read, is not
/// MCAP, or `visit` failed.
pub fn scan(
    path: &Path,
    mut visit: impl FnMut(&LoggedMessage<'_>) -> Result<(), RecordError>,
    mut progress: impl FnMut(u64, u64),
) -> Result<Scan, RecordError> {
    let io = |e| RecordError::io(path, e);
    // a FIFO or a device would block or never end
    super::output::check_input_file(path)?;
    let file = File::open(path).map_err(io)?;
    let file_len = file.metadata().map_err(io)?.len();
    let mut r = BufReader::with_capacity(1 << 16, file);
    let mut out = Scan {
        path: path.to_path_buf(),
        file_len,
        complete: false,
        damage: None,
        channels: Vec::new(),
        announced_messages: None,
    };
    let mut last_step: Option<u64> = None;
    let cut = |valid: u64, last_step: Option<u64>, data_complete: bool, reason: String| Damage {
        file_len,
        valid_bytes: valid,
        last_step,
        data_complete,
        reason,
    };

    let mut magic = [0u8; 8];
    let n = read_up_to(&mut r, &mut magic).map_err(io)?;
    if magic[..n] != mcap::MAGIC[..n] {
        return Err(RecordError::NotMcap {
            path: path.to_path_buf(),
            reason: format!(
                "it does not start with the MCAP magic bytes (starts with {:02x?})",
                &magic[..n.min(8)]
            ),
        });
    }
    if n < 8 {
        out.damage = Some(cut(
            0,
            None,
            false,
            if n == 0 {
                "the file is empty".into()
            } else {
                format!("the file ends inside the MCAP magic after {n} bytes")
            },
        ));
        return Ok(out);
    }

    let mut linker = Linker::default();
    let mut off: u64 = 8;
    let mut data_end = false;
    let mut body = Vec::new();
    let mut emit = |linker: &mut Linker,
                    last_step: &mut Option<u64>,
                    header: &mcap::records::MessageHeader,
                    data: &[u8]|
     -> Result<(), RecordError> {
        let Some(&k) = linker.channels.get(&header.channel_id) else {
            return Err(RecordError::Format {
                path: path.to_path_buf(),
                message: format!(
                    "message {} refers to channel {}, which was never defined",
                    header.sequence, header.channel_id
                ),
            });
        };
        linker.stats[k].messages += 1;
        let c = &linker.stats[k];
        if c.topic == TOPIC_DIAGNOSTICS {
            *last_step = Some(last_step.unwrap_or(0).max(header.sequence as u64));
        }
        visit(&LoggedMessage {
            topic: &c.topic,
            schema: &c.schema,
            sequence: header.sequence,
            log_time: header.log_time,
            data,
            path,
        })
    };

    loop {
        progress(off, file_len);
        let mut head = [0u8; 9];
        let got = read_up_to(&mut r, &mut head).map_err(io)?;
        if got == 0 {
            let reason = if data_end {
                "the summary section ends without footer and magic".to_string()
            } else {
                "the file ends after a complete record, without the data-end record, summary \
                 and footer: the writer did not finish (process killed?)"
                    .to_string()
            };
            out.damage = Some(cut(off, last_step, data_end, reason));
            break;
        }
        if got < 9 {
            out.damage = Some(cut(
                off,
                last_step,
                data_end,
                format!("the file ends {got} bytes into the next record's header"),
            ));
            break;
        }
        let opcode = head[0];
        let len = u64::from_le_bytes(head[1..].try_into().expect("8 bytes"));
        let remaining = file_len.saturating_sub(off + 9);
        if len > remaining {
            out.damage = Some(cut(
                off,
                last_step,
                data_end,
                format!(
                    "a {} record of {len} bytes starts there but only {remaining} bytes follow",
                    op_name(opcode)
                ),
            ));
            break;
        }
        body.resize(len as usize, 0);
        r.read_exact(&mut body).map_err(io)?;
        let start = off;
        off += 9 + len;
        let corrupt = |e: &dyn fmt::Display| {
            format!(
                "the {} record at byte offset {start} is corrupt: {e}",
                op_name(opcode)
            )
        };
        if data_end {
            // summary section: only the footer and the statistics matter
            match opcode {
                op::FOOTER => {
                    let mut m = [0u8; 8];
                    let k = read_up_to(&mut r, &mut m).map_err(io)?;
                    if k == 8 && m == *mcap::MAGIC {
                        out.complete = true;
                    } else {
                        out.damage = Some(cut(
                            off,
                            last_step,
                            true,
                            "the footer is not followed by the MCAP magic".into(),
                        ));
                    }
                    break;
                }
                op::STATISTICS => {
                    if let Ok(Record::Statistics(s)) = parse_checked(opcode, &body) {
                        out.announced_messages = Some(s.message_count);
                    }
                }
                _ => {}
            }
            continue;
        }
        match opcode {
            op::SCHEMA | op::CHANNEL | op::MESSAGE => match parse_checked(opcode, &body) {
                Ok(Record::Schema { header, .. }) => linker.schema(header.id, &header.name),
                Ok(Record::Channel(c)) => {
                    linker.channel(c.id, c.schema_id, &c.topic, &c.message_encoding)
                }
                Ok(Record::Message { header, data }) => {
                    emit(&mut linker, &mut last_step, &header, &data)?
                }
                Ok(_) => {}
                Err(e) => {
                    out.damage = Some(cut(start, last_step, false, corrupt(&e)));
                    break;
                }
            },
            op::CHUNK => {
                let limit = MAX_CHUNK.max(64 * len);
                let records = chunk_records(&head, &body, limit).map_err(|e| corrupt(&e));
                let records = match records {
                    Ok(r) => r,
                    Err(reason) => {
                        out.damage = Some(cut(start, last_step, false, reason));
                        break;
                    }
                };
                for rec in records {
                    match rec {
                        Record::Schema { header, .. } => linker.schema(header.id, &header.name),
                        Record::Channel(c) => {
                            linker.channel(c.id, c.schema_id, &c.topic, &c.message_encoding)
                        }
                        Record::Message { header, data } => {
                            emit(&mut linker, &mut last_step, &header, &data)?
                        }
                        _ => {}
                    }
                }
            }
            op::DATA_END => data_end = true,
            op::FOOTER => {
                out.damage = Some(cut(
                    off,
                    last_step,
                    true,
                    "footer without data-end record".into(),
                ));
                break;
            }
            op::HEADER
            | op::MESSAGE_INDEX
            | op::CHUNK_INDEX
            | op::ATTACHMENT
            | op::ATTACHMENT_INDEX
            | op::STATISTICS
            | op::METADATA
            | op::METADATA_INDEX
            | op::SUMMARY_OFFSET => {}
            o if o >= 0x80 => {} // private records
            o => {
                out.damage = Some(cut(
                    start,
                    last_step,
                    false,
                    format!("unknown record opcode {o:#04x} at byte offset {start}: corrupt data"),
                ));
                break;
            }
        }
    }
    progress(off.min(file_len), file_len);
    out.channels = linker.stats;
    Ok(out)
}

/// The records of one chunk record (`head` + `body`), decompressed and CRC-checked *before*
/// any inner record is parsed, with every length bounded by `limit` (so corrupt lengths inside
/// a damaged chunk cannot make the reader allocate them).
/// `mcap::parse_record` after checking every length prefix of the record against the bytes
/// that remain: the `mcap` crate reserves a string's announced length before reading it, so a
/// corrupt length (found by the fuzzer: `0xFFFFFFFF` in a schema name) would otherwise ask the
/// allocator for 4 GiB.
fn parse_checked(opcode: u8, body: &[u8]) -> Result<Record<'_>, String> {
    if let Err(what) = lengths_fit(opcode, body) {
        return Err(format!(
            "{what} is longer than the {} bytes of the record",
            body.len()
        ));
    }
    mcap::parse_record(opcode, body).map_err(|e| e.to_string())
}

/// Walks the length-prefixed fields of the records gpm reads (schema, channel, statistics).
fn lengths_fit(opcode: u8, body: &[u8]) -> Result<(), &'static str> {
    struct Walk<'a> {
        b: &'a [u8],
        at: usize,
    }
    impl Walk<'_> {
        fn skip(&mut self, n: usize, what: &'static str) -> Result<(), &'static str> {
            if self.b.len() - self.at < n {
                return Err(what);
            }
            self.at += n;
            Ok(())
        }
        fn prefixed(&mut self, what: &'static str) -> Result<usize, &'static str> {
            if self.b.len() - self.at < 4 {
                return Err(what);
            }
            let n = u32::from_le_bytes(self.b[self.at..self.at + 4].try_into().unwrap()) as usize;
            self.at += 4;
            let start = self.at;
            self.skip(n, what)?;
            Ok(start)
        }
    }
    let mut w = Walk { b: body, at: 0 };
    match opcode {
        op::SCHEMA => {
            w.skip(2, "the schema id")?;
            w.prefixed("the schema name")?;
            w.prefixed("the schema encoding")?;
            w.prefixed("the schema data")?;
        }
        op::CHANNEL => {
            w.skip(4, "the channel ids")?;
            w.prefixed("the channel topic")?;
            w.prefixed("the channel message encoding")?;
            let start = w.prefixed("the channel metadata")?;
            let mut m = Walk {
                b: &body[start..w.at],
                at: 0,
            };
            while m.at < m.b.len() {
                m.prefixed("a channel metadata key")?;
                m.prefixed("a channel metadata value")?;
            }
        }
        op::STATISTICS => {
            w.skip(8 + 2 + 4 * 4 + 16, "the statistics counts")?;
            w.prefixed("the statistics channel message counts")?;
        }
        _ => {}
    }
    Ok(())
}

fn chunk_records(head: &[u8; 9], body: &[u8], limit: u64) -> Result<Vec<Record<'static>>, String> {
    use mcap::sans_io::{LinearReadEvent, LinearReader, LinearReaderOptions};
    let mut reader = LinearReader::new_with_options(
        LinearReaderOptions::default()
            .with_skip_start_magic(true)
            .with_skip_end_magic(true)
            .with_prevalidate_chunk_crcs(true)
            .with_record_length_limit(usize::try_from(limit).unwrap_or(usize::MAX)),
    );
    let mut src = head.iter().chain(body.iter());
    let mut out = Vec::new();
    while let Some(event) = reader.next_event() {
        match event.map_err(|e| e.to_string())? {
            LinearReadEvent::ReadRequest(n) => {
                let dst = reader.insert(n);
                let mut k = 0;
                for (d, s) in dst.iter_mut().zip(&mut src) {
                    *d = *s;
                    k += 1;
                }
                reader.notify_read(k);
            }
            // only the records a chunk may hold are parsed (the fuzzer found a header record
            // inside a chunk whose string length asked for 650 MB)
            LinearReadEvent::Record { data, opcode }
                if matches!(opcode, op::SCHEMA | op::CHANNEL | op::MESSAGE) =>
            {
                out.push(parse_checked(opcode, data)?.into_owned());
            }
            LinearReadEvent::Record { .. } => {}
        }
    }
    Ok(out)
}

/// Minimum, maximum and mean of the finite values of a series (and how many were not finite).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Stat {
    /// Smallest finite value.
    pub min: f64,
    /// Largest finite value.
    pub max: f64,
    /// Mean of the finite values.
    pub mean: f64,
    /// Values that were NaN or infinite.
    pub non_finite: usize,
}

impl Stat {
    /// Over `values`.
    pub fn of(values: impl IntoIterator<Item = f64>) -> Self {
        let (mut min, mut max, mut sum, mut n, mut bad) =
            (f64::INFINITY, f64::NEG_INFINITY, 0.0, 0usize, 0usize);
        for v in values {
            if v.is_finite() {
                min = min.min(v);
                max = max.max(v);
                sum += v;
                n += 1;
            } else {
                bad += 1;
            }
        }
        if n == 0 {
            return Stat {
                min: f64::NAN,
                max: f64::NAN,
                mean: f64::NAN,
                non_finite: bad,
            };
        }
        Stat {
            min,
            max,
            mean: sum / n as f64,
            non_finite: bad,
        }
    }
}

/// Seconds spent in one stage over the recorded steps.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct StageTime {
    /// Total seconds.
    pub total: f64,
    /// Mean seconds per step.
    pub mean: f64,
    /// Share of the total step time (`record` is compared with the step time, not part of it).
    pub share: f64,
}

/// The numbers `gpm replay` prints.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ReplaySummary {
    /// The file.
    pub file: PathBuf,
    /// Its size.
    pub bytes: u64,
    /// Finished by the writer.
    pub complete: bool,
    /// How the file is damaged, in words.
    pub damage: Option<String>,
    /// Channels and message counts.
    pub channels: Vec<ChannelStats>,
    /// Recorded steps.
    pub steps: usize,
    /// First and last step numbers.
    pub step_range: Option<(u64, u64)>,
    /// Simulation time at the start of the first recorded step and at the end of the last.
    pub time_span: Option<(f64, f64)>,
    /// Time steps.
    pub dt: Stat,
    /// Semi-regularity constant.
    pub c0: Stat,
    /// Smallest particle spacing per step (NaN in older logs).
    pub min_spacing: Stat,
    /// Correction over predicted velocity per step (NaN in older logs).
    pub correction_ratio: Stat,
    /// Kinetic-energy growth per step (steps that report it).
    pub energy_growth: Stat,
    /// The volume shift's RMS relative volume error (steps that report it).
    pub volume_error: Stat,
    /// Particles the wall margin stopped, over all steps, and the steps in which it did.
    pub wall_pushes: (u64, usize),
    /// Largest Theorem 4.5 ratio and its step.
    pub max_stability_ratio: Option<(f64, u64)>,
    /// Steps whose ratio exceeds 1 (the theorem's bound).
    pub steps_ratio_above_one: usize,
    /// Steps whose connectivity check failed (more floating components than allowed, or
    /// isolated particles).
    pub connectivity_failures: usize,
    /// Floating components per step.
    pub floating: Stat,
    /// Isolated particles per step.
    pub isolated: Stat,
    /// Solvers used.
    pub solvers: Vec<String>,
    /// CG iterations per step.
    pub iterations: Stat,
    /// The warm start's `‖b − K x₀‖/‖b‖` per step (CG solves).
    pub initial_rel_residual: Stat,
    /// The implicit viscous solve's iterations per step (steps that recorded one).
    pub viscous_iterations: Stat,
    /// The implicit viscous solve's stopping tolerance per step (steps that recorded one).
    pub viscous_rel_tol: Stat,
    /// Relative residual per step.
    pub rel_residual: Stat,
    /// Absolute residual per step.
    pub abs_residual: Stat,
    /// Divergence after the projection.
    pub div_after: Stat,
    /// Kinetic energy.
    pub kinetic_energy: Stat,
    /// Per stage, in step order (`neighbors`, `predictor`, …, `total`, `record`).
    pub stages: Vec<(String, StageTime)>,
}

impl fmt::Display for ReplaySummary {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let st = |s: &Stat| {
            let mut t = format!("min {:.6e}  max {:.6e}  mean {:.6e}", s.min, s.max, s.mean);
            if s.non_finite > 0 {
                t += &format!("  ({} not finite)", s.non_finite);
            }
            t
        };
        writeln!(
            f,
            "file        {} ({} bytes)",
            self.file.display(),
            self.bytes
        )?;
        match &self.damage {
            Some(d) => writeln!(f, "DAMAGED     {d}")?,
            None => writeln!(f, "status      complete (summary and footer present)")?,
        }
        for c in &self.channels {
            writeln!(
                f,
                "channel     {:<18} {:<22} {:>8} messages",
                c.topic, c.schema, c.messages
            )?;
        }
        writeln!(f, "steps       {}", self.steps)?;
        if let (Some((a, b)), Some((t0, t1))) = (self.step_range, self.time_span) {
            writeln!(f, "            steps {a}..={b}, time {t0:.6} .. {t1:.6}")?;
        }
        if self.steps == 0 {
            return Ok(());
        }
        writeln!(f, "dt          {}", st(&self.dt))?;
        writeln!(f, "c0          {}", st(&self.c0))?;
        writeln!(f, "min spacing {}", st(&self.min_spacing))?;
        writeln!(
            f,
            "correction  {} (‖uⁿ⁺¹ − u*‖/‖u*‖)",
            st(&self.correction_ratio)
        )?;
        writeln!(f, "KE growth   {} (per step)", st(&self.energy_growth))?;
        if !self.volume_error.max.is_nan() {
            writeln!(
                f,
                "volume err  {} (RMS ω̄/ω − 1, volume shift)",
                st(&self.volume_error)
            )?;
        }
        if self.wall_pushes.0 > 0 {
            writeln!(
                f,
                "wall pushes {} particles in {} steps (stopped at the wall margin)",
                self.wall_pushes.0, self.wall_pushes.1
            )?;
        }
        if let Some((r, s)) = self.max_stability_ratio {
            writeln!(
                f,
                "stability   max ratio {r:.6} at step {s} (Thm 4.5 bound 1; {} steps above)",
                self.steps_ratio_above_one
            )?;
        }
        writeln!(
            f,
            "connectivity {} failing steps; floating components {} .. {}; isolated particles max {}",
            self.connectivity_failures, self.floating.min, self.floating.max, self.isolated.max
        )?;
        writeln!(f, "solver      {}", self.solvers.join(", "))?;
        writeln!(f, "iterations  {}", st(&self.iterations))?;
        if self.initial_rel_residual.max > 0.0 {
            writeln!(
                f,
                "warm start  {} (‖b − K x₀‖/‖b‖)",
                st(&self.initial_rel_residual)
            )?;
        }
        if self.viscous_iterations.max >= 0.0 {
            writeln!(f, "viscous     iterations {}", st(&self.viscous_iterations))?;
            writeln!(f, "            tolerance {}", st(&self.viscous_rel_tol))?;
        }
        writeln!(f, "residual    relative {}", st(&self.rel_residual))?;
        writeln!(f, "            absolute {}", st(&self.abs_residual))?;
        writeln!(f, "div after   {}", st(&self.div_after))?;
        writeln!(f, "energy      {}", st(&self.kinetic_energy))?;
        writeln!(f, "time per stage (mean ms per step, share of the step):")?;
        for (name, s) in &self.stages {
            writeln!(
                f,
                "  {:<12} {:>10.4} ms  {:>6.1} %",
                name,
                1e3 * s.mean,
                100.0 * s.share
            )?;
        }
        Ok(())
    }
}

/// A run read back: configuration, every step's diagnostics, and what [`scan`] found.
#[derive(Clone, Debug)]
pub struct Replay {
    /// File-level facts (channels, counts, damage).
    pub scan: Scan,
    /// The `/config` message.
    pub config: Option<RunConfig>,
    /// `/diagnostics`, in file order.
    pub steps: Vec<StepDiagnostics>,
}

impl Replay {
    /// Reads `path` (complete or damaged).
    pub fn open(path: impl AsRef<Path>) -> Result<Self, RecordError> {
        Self::open_with_progress(path, |_, _| {})
    }

    /// [`open`](Self::open), reporting `(bytes read, file size)` as it goes.
    pub fn open_with_progress(
        path: impl AsRef<Path>,
        progress: impl FnMut(u64, u64),
    ) -> Result<Self, RecordError> {
        let mut config = None;
        let mut steps = Vec::new();
        let scan = scan(
            path.as_ref(),
            |m| {
                match m.topic {
                    TOPIC_CONFIG => config = Some(m.decode::<RunConfig>()?),
                    TOPIC_DIAGNOSTICS => steps.push(m.decode::<StepDiagnostics>()?),
                    _ => {}
                }
                Ok(())
            },
            progress,
        )?;
        Ok(Replay {
            scan,
            config,
            steps,
        })
    }

    /// How the file is damaged, if it is.
    pub fn damage(&self) -> Option<&Damage> {
        self.scan.damage.as_ref()
    }

    /// Statistics of the recorded steps.
    pub fn summary(&self) -> ReplaySummary {
        let s = &self.steps;
        let mut out = ReplaySummary {
            file: self.scan.path.clone(),
            bytes: self.scan.file_len,
            complete: self.scan.complete,
            damage: self.scan.damage.as_ref().map(|d| d.to_string()),
            channels: self.scan.channels.clone(),
            steps: s.len(),
            ..Default::default()
        };
        let (Some(first), Some(last)) = (s.first(), s.last()) else {
            return out;
        };
        out.step_range = Some((first.step, last.step));
        out.time_span = Some((first.time - first.dt, last.time));
        out.dt = Stat::of(s.iter().map(|d| d.dt));
        out.c0 = Stat::of(s.iter().map(|d| d.c0));
        out.min_spacing = Stat::of(s.iter().map(|d| d.min_spacing));
        out.correction_ratio = Stat::of(s.iter().map(|d| d.correction_ratio));
        out.energy_growth = Stat::of(s.iter().filter_map(|d| d.energy_growth));
        out.volume_error = Stat::of(s.iter().filter_map(|d| d.volume_error));
        out.wall_pushes = s.iter().fold((0, 0), |(n, k), d| {
            (n + d.wall_pushes, k + usize::from(d.wall_pushes > 0))
        });
        out.max_stability_ratio = s
            .iter()
            .filter(|d| d.stability_ratio.is_finite())
            .map(|d| (d.stability_ratio, d.step))
            .fold(None, |m: Option<(f64, u64)>, x| match m {
                Some(m) if m.0 >= x.0 => Some(m),
                _ => Some(x),
            });
        out.steps_ratio_above_one = s.iter().filter(|d| d.stability_ratio > 1.0).count();
        out.connectivity_failures = s.iter().filter(|d| !d.connectivity.ok).count();
        out.floating = Stat::of(s.iter().map(|d| d.connectivity.floating as f64));
        out.isolated = Stat::of(s.iter().map(|d| d.connectivity.isolated as f64));
        let mut solvers: Vec<String> = s.iter().map(|d| d.solve.solver.to_string()).collect();
        solvers.sort();
        solvers.dedup();
        out.solvers = solvers;
        out.iterations = Stat::of(s.iter().map(|d| d.solve.iterations as f64));
        out.initial_rel_residual = Stat::of(s.iter().map(|d| d.solve.initial_rel_residual));
        let viscous = || s.iter().filter_map(|d| d.viscous.as_ref());
        out.viscous_iterations = Stat::of(viscous().map(|v| v.iterations as f64));
        out.viscous_rel_tol = Stat::of(viscous().map(|v| v.rel_tol));
        out.rel_residual = Stat::of(s.iter().map(|d| d.solve.rel_residual));
        out.abs_residual = Stat::of(s.iter().map(|d| d.solve.abs_residual));
        out.div_after = Stat::of(s.iter().map(|d| d.div_after));
        out.kinetic_energy = Stat::of(s.iter().map(|d| d.kinetic_energy));
        type Get = fn(&StepDiagnostics) -> f64;
        let stages: [(&str, Get); 9] = [
            ("neighbors", |d| d.timings.neighbors),
            ("predictor", |d| d.timings.predictor),
            ("diagnostics", |d| d.timings.diagnostics),
            ("source", |d| d.timings.source),
            ("solve", |d| d.timings.solve),
            ("correction", |d| d.timings.correction),
            ("advect", |d| d.timings.advect),
            ("total", |d| d.timings.total),
            ("record", |d| d.timings.record),
        ];
        let finite = |v: f64| if v.is_finite() { v } else { 0.0 };
        let total: f64 = s.iter().map(|d| finite(d.timings.total)).sum();
        for (name, get) in stages {
            let t: f64 = s.iter().map(|d| finite(get(d))).sum();
            out.stages.push((
                name.to_string(),
                StageTime {
                    total: t,
                    mean: t / s.len() as f64,
                    share: if total > 0.0 { t / total } else { 0.0 },
                },
            ));
        }
        out
    }

    /// Writes the diagnostics table as CSV (one row per step, a header line first). A value
    /// that is not finite is an empty cell (never `NaN` or `inf`); the file is written under a
    /// temporary name and renamed when complete ([`super::output::write_atomic`]).
    pub fn write_csv(&self, out: &Path) -> Result<(), RecordError> {
        let io = |e| RecordError::io(out, e);
        let mut w = Vec::new();
        writeln!(
            w,
            "step,time,dt,dt_limit,components,anchored,floating,isolated,allowed_floating,\
             connectivity_ok,c0,stability_ratio,min_spacing,correction_ratio,energy_growth,solver,unknowns,nnz,iterations,abs_residual,\
             rel_residual,compatibility_defect,div_before,div_after,kinetic_energy,max_speed,\
             neighbors_rebuilt,max_shift,volume_error,wall_pushes,t_neighbors,t_predictor,t_diagnostics,t_source,\
             t_solve,t_correction,t_advect,t_total,t_record,surface_particles,splash_particles,\
             initial_rel_residual,rel_tol,viscous_iterations,viscous_rel_residual,\
             viscous_initial_rel_residual,viscous_rel_tol"
        )
        .map_err(io)?;
        for d in &self.steps {
            let c = &d.connectivity;
            let t = &d.timings;
            // the viscous solve's cells, empty for a step without one
            let viscous = |f: fn(&SolveDiagnostics) -> String| -> String {
                d.viscous.as_ref().map(f).unwrap_or_default()
            };
            let dt_limit = serde_json::to_value(d.dt_limit)
                .ok()
                .and_then(|v| v.as_str().map(String::from))
                .unwrap_or_default();
            writeln!(
                w,
                "{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{}",
                d.step,
                Num(d.time),
                Num(d.dt),
                dt_limit,
                c.components,
                c.anchored,
                c.floating,
                c.isolated,
                c.allowed_floating,
                c.ok,
                Num(d.c0),
                Num(d.stability_ratio),
                Num(d.min_spacing),
                Num(d.correction_ratio),
                d.energy_growth.map(|g| Num(g).to_string()).unwrap_or_default(),
                d.solve.solver,
                d.solve.unknowns,
                d.solve.nnz,
                d.solve.iterations,
                Num(d.solve.abs_residual),
                Num(d.solve.rel_residual),
                Num(d.solve.compatibility_defect),
                Num(d.div_before),
                Num(d.div_after),
                Num(d.kinetic_energy),
                Num(d.max_speed),
                d.neighbors_rebuilt,
                Num(d.max_shift),
                d.volume_error.map(|v| Num(v).to_string()).unwrap_or_default(),
                d.wall_pushes,
                Num(t.neighbors),
                Num(t.predictor),
                Num(t.diagnostics),
                Num(t.source),
                Num(t.solve),
                Num(t.correction),
                Num(t.advect),
                Num(t.total),
                Num(t.record),
                d.surface_particles.map(|v| v.to_string()).unwrap_or_default(),
                d.splash_particles.map(|v| v.to_string()).unwrap_or_default(),
                Num(d.solve.initial_rel_residual),
                Num(d.solve.rel_tol),
                viscous(|v| v.iterations.to_string()),
                viscous(|v| Num(v.rel_residual).to_string()),
                viscous(|v| Num(v.initial_rel_residual).to_string()),
                viscous(|v| Num(v.rel_tol).to_string())
            )
            .map_err(io)?;
        }
        super::output::write_atomic(out, &w).map_err(io)
    }

    /// Draws the main time series into one PNG: kinetic energy and maximum speed; `c0` and the
    /// Theorem 4.5 ratio; divergence before and after the projection (log); solver residual and
    /// time per step (log).
    #[cfg(feature = "cli")]
    pub fn plot(&self, out: &Path) -> Result<(), RecordError> {
        use crate::plot::{line_charts, Chart, Series};
        let s = &self.steps;
        let series = |name: &str, f: &dyn Fn(&StepDiagnostics) -> f64| {
            Series::line(name, s.iter().map(|d| (d.time, f(d))).collect())
        };
        let chart = |title: &str, y: &str, log_y: bool| Chart {
            title: title.into(),
            x_label: "time".into(),
            y_label: y.into(),
            log_x: false,
            log_y,
        };
        let charts = vec![
            (
                chart("energy and speed", "", false),
                vec![
                    series("kinetic energy", &|d| d.kinetic_energy),
                    series("max speed", &|d| d.max_speed),
                ],
            ),
            (
                chart("c0 and Thm 4.5 ratio", "", false),
                vec![
                    series("c0", &|d| d.c0),
                    series("stability ratio", &|d| d.stability_ratio),
                ],
            ),
            (
                chart("spacing, correction, energy growth", "", true),
                vec![
                    series("min spacing", &|d| d.min_spacing),
                    series("‖uⁿ⁺¹ − u*‖/‖u*‖", &|d| d.correction_ratio),
                    series("KE growth − 1 (abs)", &|d| {
                        d.energy_growth.map_or(f64::NAN, |g| (g - 1.0).abs())
                    }),
                    series("volume error (RMS)", &|d| {
                        d.volume_error.unwrap_or(f64::NAN)
                    }),
                    series("isolated + floating", &|d| {
                        (d.connectivity.isolated + d.connectivity.floating) as f64
                    }),
                ],
            ),
            (
                chart("divergence (l2)", "", true),
                vec![
                    series("before projection", &|d| d.div_before),
                    series("after projection", &|d| d.div_after),
                ],
            ),
            (
                chart("solver and cost", "", true),
                vec![
                    series("relative residual", &|d| d.solve.rel_residual),
                    series("step seconds", &|d| d.timings.total),
                    series("record seconds", &|d| d.timings.record),
                ],
            ),
        ];
        line_charts(out, 3000, 600, &charts).map_err(|e| RecordError::Render {
            path: out.to_path_buf(),
            message: e.message,
        })
    }
}

/// What [`export_vtk`] wrote.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct VtkExport {
    /// One `.vtp` file per snapshot.
    pub files: Vec<PathBuf>,
    /// The ParaView collection (`particles.pvd`) listing them with their times.
    pub collection: PathBuf,
    /// What the scan found (damage included).
    pub scan: Scan,
}

/// Writes every `/particles` snapshot of `path` into `dir` as VTK XML PolyData
/// (`particles_NNNNNN.vtp`, one vertex per particle with every point-cloud field as point
/// data and the velocity as a vector) and a `particles.pvd` collection for ParaView's time
/// series. Creates `dir`.
pub fn export_vtk(
    path: &Path,
    dir: &Path,
    progress: impl FnMut(u64, u64),
) -> Result<VtkExport, RecordError> {
    std::fs::create_dir_all(dir).map_err(|e| RecordError::io(dir, e))?;
    let mut files = Vec::new();
    let mut times = Vec::new();
    let scan = scan(
        path,
        |m| {
            if m.topic != TOPIC_PARTICLES || m.schema != schema::SCHEMA_POINT_CLOUD {
                return Ok(());
            }
            let cloud: PointCloud = m.decode()?;
            let name = format!("particles_{:06}.vtp", m.sequence);
            let file = dir.join(&name);
            write_vtp(&file, &cloud).map_err(|e| match e {
                VtpError::Io(e) => RecordError::io(&file, e),
                VtpError::Data(message) => RecordError::Format {
                    path: path.to_path_buf(),
                    message: format!("/particles message {}: {message}", m.sequence),
                },
            })?;
            files.push(file);
            times.push((m.log_time as f64 * 1e-9, name));
            Ok(())
        },
        progress,
    )?;
    let collection = dir.join("particles.pvd");
    let io = |e| RecordError::io(&collection, e);
    let mut w = BufWriter::new(File::create(&collection).map_err(io)?);
    writeln!(w, "<?xml version=\"1.0\"?>").map_err(io)?;
    writeln!(
        w,
        "<VTKFile type=\"Collection\" version=\"0.1\">\n  <Collection>"
    )
    .map_err(io)?;
    for (t, name) in &times {
        writeln!(
            w,
            "    <DataSet timestep=\"{t}\" part=\"0\" file=\"{name}\"/>"
        )
        .map_err(io)?;
    }
    writeln!(w, "  </Collection>\n</VTKFile>").map_err(io)?;
    w.flush().map_err(io)?;
    Ok(VtkExport {
        files,
        collection,
        scan,
    })
}

/// A number for a CSV cell: empty when not finite (a missing value, never `NaN` or `inf`).
struct Num(f64);

impl std::fmt::Display for Num {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        if self.0.is_finite() {
            write!(f, "{}", self.0)
        } else {
            Ok(())
        }
    }
}

enum VtpError {
    Io(std::io::Error),
    Data(String),
}

fn write_vtp(file: &Path, cloud: &PointCloud) -> Result<(), VtpError> {
    let names: Vec<&str> = cloud.fields.iter().map(|f| f.name.as_str()).collect();
    let cols = cloud.decode(&names).map_err(VtpError::Data)?;
    let col = |name: &str| -> Option<&Vec<f64>> {
        names
            .iter()
            .position(|n| *n == name)
            .and_then(|k| cols[k].as_ref())
    };
    let n = cols.iter().flatten().map(|c| c.len()).next().unwrap_or(0);
    for (k, c) in cols.iter().enumerate() {
        let Some(c) = c else { continue };
        if c.len() != n {
            return Err(VtpError::Data(format!(
                "field '{}' has {} values for {n} points",
                names[k],
                c.len()
            )));
        }
        if let Some(i) = c.iter().position(|v| !v.is_finite()) {
            return Err(VtpError::Data(format!(
                "point {i}: field '{}' is not finite ({}): not written to a VTK file",
                names[k], c[i]
            )));
        }
    }
    let zero = vec![0.0; n];
    let coord = |name: &str| col(name).unwrap_or(&zero);
    let (x, y, z) = (coord("x"), coord("y"), coord("z"));
    let mut w = BufWriter::new(File::create(file).map_err(VtpError::Io)?);
    let mut s = String::with_capacity(64 * n + 1024);
    use std::fmt::Write as _;
    let _ = writeln!(
        s,
        "<?xml version=\"1.0\"?>\n<VTKFile type=\"PolyData\" version=\"0.1\" byte_order=\"LittleEndian\">\n  <PolyData>\n    <Piece NumberOfPoints=\"{n}\" NumberOfVerts=\"{n}\" NumberOfLines=\"0\" NumberOfStrips=\"0\" NumberOfPolys=\"0\">"
    );
    let has_velocity = col("vx").is_some();
    let _ = writeln!(
        s,
        "      <PointData{}>",
        if has_velocity {
            " Vectors=\"velocity\""
        } else {
            ""
        }
    );
    if has_velocity {
        let (vx, vy, vz) = (coord("vx"), coord("vy"), coord("vz"));
        let _ = write!(
            s,
            "        <DataArray type=\"Float64\" Name=\"velocity\" NumberOfComponents=\"3\" format=\"ascii\">\n         "
        );
        for i in 0..n {
            let _ = write!(s, " {} {} {}", vx[i], vy[i], vz[i]);
        }
        let _ = writeln!(s, "\n        </DataArray>");
    }
    for (k, name) in names.iter().enumerate() {
        if matches!(*name, "x" | "y" | "z" | "vx" | "vy" | "vz") {
            continue;
        }
        let Some(v) = &cols[k] else { continue };
        let _ = write!(
            s,
            "        <DataArray type=\"Float64\" Name=\"{name}\" format=\"ascii\">\n         "
        );
        for a in v {
            let _ = write!(s, " {a}");
        }
        let _ = writeln!(s, "\n        </DataArray>");
    }
    let _ = writeln!(s, "      </PointData>");
    let _ = write!(
        s,
        "      <Points>\n        <DataArray type=\"Float64\" NumberOfComponents=\"3\" format=\"ascii\">\n         "
    );
    for i in 0..n {
        let _ = write!(s, " {} {} {}", x[i], y[i], z[i]);
    }
    let _ = writeln!(s, "\n        </DataArray>\n      </Points>");
    let _ = write!(
        s,
        "      <Verts>\n        <DataArray type=\"Int64\" Name=\"connectivity\" format=\"ascii\">\n         "
    );
    for i in 0..n {
        let _ = write!(s, " {i}");
    }
    let _ = write!(
        s,
        "\n        </DataArray>\n        <DataArray type=\"Int64\" Name=\"offsets\" format=\"ascii\">\n         "
    );
    for i in 0..n {
        let _ = write!(s, " {}", i + 1);
    }
    let _ = writeln!(
        s,
        "\n        </DataArray>\n      </Verts>\n    </Piece>\n  </PolyData>\n</VTKFile>"
    );
    w.write_all(s.as_bytes()).map_err(VtpError::Io)?;
    w.flush().map_err(VtpError::Io)?;
    Ok(())
}
