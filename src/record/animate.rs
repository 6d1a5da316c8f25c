//! `gpm replay --animate`: the `/particles` snapshots of a recording as an animated GIF, the
//! particles coloured by one field on one colour scale for the whole animation (feature `cli`).
//!
//! Two passes over the file, so that no more than one snapshot is held at a time: the first
//! finds the snapshots, the box around every drawn particle and each snapshot's value range; the
//! second draws the chosen frames ([`crate::plot::ParticleGif`]). Ghosts (`role` 2, mirror
//! images outside the walls) are not drawn; 3D snapshots are drawn projected on the x–y plane.
//! The GIF is written to `OUT.partial` and renamed to `OUT` when complete.

use super::output::{check_output_file, partial_path};
use super::replay::{scan, LoggedMessage, Scan};
use super::schema::{PointCloud, SCHEMA_POINT_CLOUD, TOPIC_PARTICLES};
use super::RecordError;
use crate::plot::{quantile_range, Bounds, ParticleGif, PlotError, Snapshot};
use serde::{Deserialize, Serialize};
use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

/// What [`animate`] draws and how; [`Default`]: speed, 10 frames per second, 720 pixels wide,
/// the height from the box's aspect ratio, at most 200 frames.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct AnimateOptions {
    /// The colour: `speed`, `pressure` (`p`), `surface` (1 on the free-surface band, the
    /// Dirichlet particles; 0 elsewhere), `u`, `v`, `w` (`vx`, `vy`, `vz`), or any field name
    /// of the point clouds.
    pub field: String,
    /// Frames per second, 1 to 50.
    pub fps: f64,
    /// Frame width in pixels (the colour bar included).
    pub width: u32,
    /// Frame height in pixels; `None`: as the box's aspect ratio asks.
    pub height: Option<u32>,
    /// At most this many frames: with more snapshots, this many evenly spaced ones (the first
    /// and the last among them).
    pub max_frames: usize,
    /// How the colour scale, fixed for the whole animation, is chosen.
    pub scale: Scale,
}

/// The colour scale of an animation. Values beyond it take the end colours.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Scale {
    /// The smallest to the largest value over the drawn frames.
    #[default]
    MinMax,
    /// The 1 % to the 99 % quantile of the values of all drawn frames (of at most 20 000
    /// evenly strided values per frame): a pressure spike of a few particles does not leave
    /// the rest of the animation in one colour.
    Robust,
    /// Given.
    Given {
        /// Value of the lowest colour.
        low: f64,
        /// Value of the highest colour.
        high: f64,
    },
}

/// The quantile of [`Scale::Robust`] (and `1 −` it).
const ROBUST: f64 = 0.01;
/// At most about this many values of a snapshot are kept for [`Scale::Robust`] (evenly
/// strided), so that the scale of a long run of many particles needs little memory.
const SAMPLE: usize = 20_000;

impl Default for AnimateOptions {
    fn default() -> Self {
        AnimateOptions {
            field: "speed".into(),
            fps: 10.0,
            width: 720,
            height: None,
            max_frames: 200,
            scale: Scale::MinMax,
        }
    }
}

/// What [`animate`] wrote.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct AnimateReport {
    /// The GIF.
    pub path: PathBuf,
    /// Its size in bytes.
    pub bytes: u64,
    /// Frames drawn.
    pub frames: usize,
    /// Snapshots in the file.
    pub snapshots: usize,
    /// Frame width and height in pixels.
    pub size: (u32, u32),
    /// The point-cloud field drawn (`p` for `pressure`, `role` for `surface`).
    pub field: String,
    /// The colour scale (the values of its two ends).
    pub scale: (f64, f64),
    /// Times of the first and last frame.
    pub time_span: (f64, f64),
    /// What the scan found (damage included).
    pub scan: Scan,
}

/// Where a field's values come from.
#[derive(Clone, Debug, PartialEq)]
enum Source {
    /// A point-cloud field as it is.
    Column(String),
    /// 1 where `role` is 1 (Dirichlet: the free-surface band), else 0.
    Surface,
}

/// The named fields besides the point cloud's own: `(name, source field, label)`.
const NAMED: [(&str, &str, &str); 7] = [
    ("speed", "speed", "speed |u|"),
    ("pressure", "p", "pressure p"),
    ("surface", "role", "surface band = 1"),
    ("u", "vx", "velocity u"),
    ("v", "vy", "velocity v"),
    ("w", "vz", "velocity w"),
    ("p", "p", "pressure p"),
];

impl Source {
    /// The field `name` of clouds with the fields `have`, with its colour-bar label; the names
    /// that would work otherwise.
    fn resolve(name: &str, have: &[&str]) -> Result<(Source, String), Vec<String>> {
        if let Some((n, col, label)) = NAMED.iter().find(|(n, ..)| *n == name) {
            if have.contains(col) {
                let source = if *n == "surface" {
                    Source::Surface
                } else {
                    Source::Column((*col).into())
                };
                return Ok((source, (*label).into()));
            }
        } else if have.contains(&name) {
            return Ok((Source::Column(name.into()), name.into()));
        }
        let mut available: Vec<String> = NAMED
            .iter()
            .filter(|(_, col, _)| have.contains(col))
            .map(|(n, ..)| n.to_string())
            .collect();
        for f in have {
            if !available.iter().any(|a| a == f) {
                available.push(f.to_string());
            }
        }
        Err(available)
    }

    fn column(&self) -> &str {
        match self {
            Source::Column(c) => c,
            Source::Surface => "role",
        }
    }
}

/// One snapshot's drawn particles (ghosts left out): x–y positions and the field's values.
fn decode(
    m: &LoggedMessage<'_>,
    cloud: &PointCloud,
    source: &Source,
) -> Result<(Vec<[f64; 2]>, Vec<f64>), RecordError> {
    let bad = |message: String| RecordError::Format {
        path: m.path.to_path_buf(),
        message: format!("/particles message {}: {message}", m.sequence),
    };
    let cols = cloud
        .decode(&["x", "y", "role", source.column()])
        .map_err(bad)?;
    let (Some(x), Some(y), Some(v)) = (&cols[0], &cols[1], &cols[3]) else {
        return Err(bad("the point cloud has no x, y or the field".into()));
    };
    let role = cols[2].as_ref();
    let mut pos = Vec::with_capacity(x.len());
    let mut val = Vec::with_capacity(x.len());
    for i in 0..x.len() {
        let r = role.map_or(0.0, |r| r[i]);
        if r == 2.0 {
            continue;
        }
        pos.push([x[i], y[i]]);
        val.push(match source {
            Source::Column(_) => v[i],
            Source::Surface => f64::from(u8::from(r == 1.0)),
        });
    }
    Ok((pos, val))
}

/// A `/particles` point cloud, or `None` for any other message.
fn cloud(m: &LoggedMessage<'_>) -> Result<Option<PointCloud>, RecordError> {
    if m.topic != TOPIC_PARTICLES || m.schema != SCHEMA_POINT_CLOUD {
        return Ok(None);
    }
    m.decode().map(Some)
}

/// `k` evenly spaced indices of `0..n` (all when `n ≤ k`), the first and last among them.
fn evenly(n: usize, k: usize) -> Vec<usize> {
    if n <= k {
        return (0..n).collect();
    }
    let k = k.max(2);
    let mut out: Vec<usize> = (0..k)
        .map(|j| ((j as f64) * (n - 1) as f64 / (k - 1) as f64).round() as usize)
        .collect();
    out.dedup();
    out
}

/// Writes the `/particles` snapshots of the recording `path` as an animated GIF `out`, coloured
/// by `opts.field` on one scale (the smallest to the largest value over the drawn frames, said
/// under the colour bar), each frame titled with its time and step, the box (every drawn
/// particle of every frame) at equal scales. `progress` gets `(frames drawn, frames)`.
///
/// Errors: the file cannot be read or is not MCAP; [`RecordError::NoSnapshots`];
/// [`RecordError::UnknownField`] naming the fields there are; `out` is the input or cannot be
/// written ([`RecordError::NotAFile`], [`RecordError::Io`] naming `out`); bad options or a failed
/// encoding ([`RecordError::Render`]). On error no `out` is written (an earlier one is kept).
pub fn animate(
    path: &Path,
    out: &Path,
    opts: &AnimateOptions,
    progress: impl FnMut(usize, usize),
) -> Result<AnimateReport, RecordError> {
    check_output_file(out, path)?;
    let tmp = partial_path(out);
    let file = File::create(&tmp).map_err(|e| RecordError::io(out, e))?;
    let result = write_gif(path, out, BufWriter::new(file), opts, progress);
    match result {
        Ok((report, w)) => {
            let finish = (|| {
                w.into_inner().map_err(|e| e.into_error())?.sync_all()?;
                std::fs::rename(&tmp, out)?;
                std::fs::metadata(out).map(|m| m.len())
            })();
            match finish {
                Ok(bytes) => Ok(AnimateReport { bytes, ..report }),
                Err(e) => {
                    let _ = std::fs::remove_file(&tmp);
                    Err(RecordError::io(out, e))
                }
            }
        }
        Err(e) => {
            let _ = std::fs::remove_file(&tmp);
            Err(e)
        }
    }
}

/// Both passes of [`animate`] into `w`.
fn write_gif<W: Write>(
    path: &Path,
    out: &Path,
    w: W,
    opts: &AnimateOptions,
    mut progress: impl FnMut(usize, usize),
) -> Result<(AnimateReport, W), RecordError> {
    let render = |e: PlotError| RecordError::Render {
        path: out.to_path_buf(),
        message: e.message,
    };
    // pass 1: the snapshots, their times, boxes and value ranges
    let mut field: Option<(Source, String)> = None;
    // per snapshot: time, box and value range, values for a robust scale
    let mut frames: Vec<(f64, Bounds, Vec<f64>)> = Vec::new();
    let mut spacing = 0.0;
    scan(
        path,
        |m| {
            let Some(c) = cloud(m)? else { return Ok(()) };
            if field.is_none() {
                let have: Vec<&str> = c.fields.iter().map(|f| f.name.as_str()).collect();
                let found = Source::resolve(&opts.field, &have).map_err(|available| {
                    RecordError::UnknownField {
                        path: path.to_path_buf(),
                        field: opts.field.clone(),
                        available,
                    }
                })?;
                field = Some(found);
            }
            let (source, _) = field.as_ref().expect("resolved above");
            let (x, v) = decode(m, &c, source)?;
            let mut b = Bounds::new();
            b.add(&x, &v);
            if frames.is_empty() {
                spacing = b.spacing(x.len());
            }
            let sample = match opts.scale {
                Scale::Robust => v
                    .iter()
                    .step_by(v.len().div_ceil(SAMPLE).max(1))
                    .copied()
                    .collect(),
                _ => Vec::new(),
            };
            frames.push((m.log_time as f64 * 1e-9, b, sample));
            Ok(())
        },
        |_, _| {},
    )?;
    let Some((source, label)) = field else {
        return Err(RecordError::NoSnapshots {
            path: path.to_path_buf(),
        });
    };
    let chosen = evenly(frames.len(), opts.max_frames.max(1));
    let mut bounds = Bounds::new();
    let mut sample = Vec::new();
    for &k in &chosen {
        bounds.merge(&frames[k].1);
        sample.extend_from_slice(&frames[k].2);
    }
    let mut view = bounds.view(spacing, &label, "");
    let n = chosen.len();
    view.scale_note = match opts.scale {
        Scale::MinMax => format!("fixed scale: min–max\nover all {n} frames"),
        Scale::Robust => {
            if let Some((lo, hi)) = quantile_range(&sample, ROBUST).filter(|(lo, hi)| lo < hi) {
                view.scale = (lo, hi);
            }
            format!("fixed: 1–99 % quantiles\nover all {n} frames")
        }
        Scale::Given { low, high } if low.is_finite() && high.is_finite() && low < high => {
            view.scale = (low, high);
            "fixed scale: given;\nbeyond it: end colours".into()
        }
        Scale::Given { low, high } => {
            return Err(RecordError::Render {
                path: out.to_path_buf(),
                message: format!("colour range {low}..{high}: must be finite with low < high"),
            })
        }
    };
    let scale = view.scale;
    let mut gif =
        ParticleGif::new(w, out, view, opts.width, opts.height, opts.fps).map_err(render)?;

    // pass 2: draw the chosen snapshots
    let (mut ordinal, mut next) = (0usize, 0usize);
    let scan = scan(
        path,
        |m| {
            let Some(c) = cloud(m)? else { return Ok(()) };
            ordinal += 1;
            if chosen.get(next) != Some(&(ordinal - 1)) {
                return Ok(());
            }
            next += 1;
            let (x, value) = decode(m, &c, &source)?;
            let t = m.log_time as f64 * 1e-9;
            let title = format!("t = {t:.4}   (step {})", m.sequence);
            gif.frame(&Snapshot { title, x, value }).map_err(render)?;
            progress(next, chosen.len());
            Ok(())
        },
        |_, _| {},
    )?;
    if next != chosen.len() {
        return Err(RecordError::Format {
            path: path.to_path_buf(),
            message: format!(
                "the second reading found {} of the {} snapshots of the first (the file changed?)",
                next,
                chosen.len()
            ),
        });
    }
    let size = gif.size();
    let w = gif.finish().map_err(render)?;
    let first = chosen.first().map_or(0.0, |&k| frames[k].0);
    let last = chosen.last().map_or(0.0, |&k| frames[k].0);
    Ok((
        AnimateReport {
            path: out.to_path_buf(),
            bytes: 0,
            frames: chosen.len(),
            snapshots: frames.len(),
            size,
            field: source.column().into(),
            scale,
            time_span: (first, last),
            scan,
        },
        w,
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn evenly_keeps_the_ends_and_at_most_k() {
        assert_eq!(evenly(3, 10), vec![0, 1, 2]);
        assert_eq!(evenly(10, 4), vec![0, 3, 6, 9]);
        assert_eq!(evenly(5, 1), vec![0, 4]);
        let e = evenly(1000, 200);
        assert_eq!((e.len(), e[0], e[199]), (200, 0, 999));
    }

    #[test]
    fn fields_resolve_by_alias_or_name_and_list_the_others() {
        let have = ["x", "y", "z", "vx", "vy", "vz", "speed", "p", "role"];
        assert_eq!(
            Source::resolve("pressure", &have).unwrap().0,
            Source::Column("p".into())
        );
        assert_eq!(
            Source::resolve("surface", &have).unwrap().0,
            Source::Surface
        );
        assert_eq!(
            Source::resolve("vy", &have).unwrap().0,
            Source::Column("vy".into())
        );
        let available = Source::resolve("vorticity", &have).unwrap_err();
        assert_eq!(
            available.join(","),
            "speed,pressure,surface,u,v,w,p,x,y,z,vx,vy,vz,role"
        );
        // a cloud without role: no surface field
        assert!(Source::resolve("surface", &["x", "y", "p"]).is_err());
    }
}
