//! `gpm replay --animate` (`gpm::record::animate`) and the dam break's `pressure.png`: a small
//! recorded dam break drawn as a GIF that decodes with the expected frames and size, its colour
//! scale the recorded range, and the errors for an unknown field, a file without snapshots and
//! an output that cannot be written.
#![cfg(feature = "cli")]

use gpm::error::RecordError;
use gpm::plot::quantile_range;
use gpm::record::animate::{animate, AnimateOptions, Scale};
use gpm::record::replay::scan;
use gpm::record::schema::{PointCloud, TOPIC_PARTICLES};
use gpm::record::{RecordLevel, RecorderOptions};
use gpm::scene::dam_break::DamBreakConfig;
use std::ops::ControlFlow;
use std::path::Path;

/// A dam break of 8 × 16 particles to `T = 0.3`, recorded into `path` (`full`: a snapshot
/// every second step); returns the number of steps.
fn record_dam_break(path: &Path, level: RecordLevel) -> u64 {
    let cfg = small_dam_break(0.3);
    let done = gpm::scene::run_recorded(
        &cfg,
        path,
        RecorderOptions::new(level, 2),
        &cfg.record_header(),
        |_| {},
        |_, _| Ok(ControlFlow::Continue(())),
    )
    .unwrap();
    done.record.unwrap();
    done.run.unwrap().sim.steps
}

fn small_dam_break(big_t: f64) -> DamBreakConfig {
    DamBreakConfig::default().with(|c| {
        c.n = 8;
        c.t_end = big_t / 2f64.sqrt();
    })
}

/// A decoded frame's width, height and delay (hundredths of a second).
type FrameInfo = (u16, u16, u16);

/// Frames and their sizes of the GIF `path`, and the logical screen size.
fn gif_frames(path: &Path) -> ((u16, u16), Vec<FrameInfo>) {
    let mut opts = gif::DecodeOptions::new();
    opts.set_color_output(gif::ColorOutput::Indexed);
    let mut d = opts.read_info(std::fs::File::open(path).unwrap()).unwrap();
    let screen = (d.width(), d.height());
    let mut frames = Vec::new();
    while let Some(f) = d.read_next_frame().unwrap() {
        frames.push((f.width, f.height, f.delay));
    }
    (screen, frames)
}

/// Smallest and largest `p` of the non-ghost particles over every snapshot of `path`.
fn recorded_pressure_range(path: &Path) -> (f64, f64, usize) {
    let (mut lo, mut hi, mut n) = (f64::INFINITY, f64::NEG_INFINITY, 0);
    scan(
        path,
        |m| {
            if m.topic == TOPIC_PARTICLES {
                let c: PointCloud = m.decode()?;
                let cols = c.decode(&["p", "role"]).unwrap();
                let (p, role) = (cols[0].as_ref().unwrap(), cols[1].as_ref().unwrap());
                for (p, r) in p.iter().zip(role) {
                    if *r != 2.0 {
                        lo = lo.min(*p);
                        hi = hi.max(*p);
                    }
                }
                n += 1;
            }
            Ok(())
        },
        |_, _| {},
    )
    .unwrap();
    (lo, hi, n)
}

#[test]
fn a_recorded_dam_break_animates_into_a_gif_of_every_snapshot() {
    let dir = tempfile::tempdir().unwrap();
    let run = dir.path().join("run.mcap");
    let steps = record_dam_break(&run, RecordLevel::Full);
    let (lo, hi, snapshots) = recorded_pressure_range(&run);
    // snapshots at steps 1, 3, 5, …
    assert_eq!(snapshots as u64, steps.div_ceil(2));
    assert!(snapshots >= 3, "{snapshots} snapshots");

    let out = dir.path().join("p.gif");
    let opts = AnimateOptions {
        field: "pressure".into(),
        width: 400,
        fps: 20.0,
        ..Default::default()
    };
    let mut calls = Vec::new();
    let r = animate(&run, &out, &opts, |done, total| calls.push((done, total))).unwrap();
    assert_eq!((r.frames, r.snapshots), (snapshots, snapshots));
    assert_eq!(calls.last(), Some(&(snapshots, snapshots)));
    assert_eq!(r.field, "p");
    // the scale is the recorded range (the drawn values are the recorded f32s)
    assert_eq!(r.scale, (lo, hi));
    assert_eq!(r.bytes, std::fs::metadata(&out).unwrap().len());
    assert!(!gpm::record::output::partial_path(&out).exists());
    let (screen, frames) = gif_frames(&out);
    assert_eq!(screen, (r.size.0 as u16, r.size.1 as u16));
    assert_eq!(r.size.0, 400);
    assert_eq!(frames.len(), snapshots);
    for f in &frames {
        assert_eq!((f.0, f.1), screen, "every frame covers the screen");
        assert_eq!(f.2, 5, "20 frames per second: 5 hundredths each");
    }

    // at most 3 frames, a given size, the surface flag
    let opts = AnimateOptions {
        field: "surface".into(),
        width: 320,
        height: Some(200),
        max_frames: 3,
        ..Default::default()
    };
    let r = animate(&run, &out, &opts, |_, _| {}).unwrap();
    assert_eq!((r.frames, r.field.as_str()), (3, "role"));
    assert_eq!(r.scale, (0.0, 1.0), "band particles 1, the rest 0");
    let (screen, frames) = gif_frames(&out);
    assert_eq!((screen, frames.len()), ((320, 200), 3));

    // robust: inside the min–max range; given: as given
    let robust = AnimateOptions {
        field: "pressure".into(),
        scale: Scale::Robust,
        ..Default::default()
    };
    let r = animate(&run, &out, &robust, |_, _| {}).unwrap();
    assert!(
        r.scale.0 >= lo && r.scale.1 <= hi && r.scale.0 < r.scale.1,
        "{:?}",
        r.scale
    );
    assert!(
        r.scale != (lo, hi),
        "no pressure spike at all? {:?}",
        r.scale
    );
    let given = AnimateOptions {
        scale: Scale::Given {
            low: -1.0,
            high: 2.0,
        },
        ..robust
    };
    let r = animate(&run, &out, &given, |_, _| {}).unwrap();
    assert_eq!(r.scale, (-1.0, 2.0));
}

#[test]
fn quantile_ranges_ignore_a_few_outliers() {
    let mut v: Vec<f64> = (0..=100).map(f64::from).collect();
    assert_eq!(quantile_range(&v, 0.01), Some((1.0, 99.0)));
    v[50] = 1e9;
    v.push(f64::NAN);
    assert_eq!(quantile_range(&v, 0.01), Some((1.0, 100.0)));
    assert_eq!(quantile_range(&[f64::NAN], 0.01), None);
}

#[test]
fn bad_fields_files_and_outputs_are_errors_that_name_them() {
    let dir = tempfile::tempdir().unwrap();
    let full = dir.path().join("full.mcap");
    record_dam_break(&full, RecordLevel::Full);
    let out = dir.path().join("a.gif");

    let opts = AnimateOptions {
        field: "vorticity".into(),
        ..Default::default()
    };
    let e = animate(&full, &out, &opts, |_, _| {}).unwrap_err();
    match &e {
        RecordError::UnknownField {
            field, available, ..
        } => {
            assert_eq!(field, "vorticity");
            for f in ["speed", "pressure", "surface", "u", "v", "p", "role"] {
                assert!(available.iter().any(|a| a == f), "{f} in {available:?}");
            }
        }
        e => panic!("expected UnknownField, got {e}"),
    }
    let msg = e.to_string();
    assert!(msg.contains("'vorticity'") && msg.contains("speed, pressure, surface"));
    assert!(!out.exists() && !gpm::record::output::partial_path(&out).exists());

    // diagnostics only: nothing to draw
    let diag = dir.path().join("diag.mcap");
    record_dam_break(&diag, RecordLevel::Diagnostics);
    let e = animate(&diag, &out, &AnimateOptions::default(), |_, _| {}).unwrap_err();
    assert!(
        matches!(&e, RecordError::NoSnapshots { path } if path == &diag),
        "{e}"
    );
    assert!(e.to_string().contains("--record full"), "{e}");

    // a directory that does not exist
    let nowhere = dir.path().join("missing").join("a.gif");
    let e = animate(&full, &nowhere, &AnimateOptions::default(), |_, _| {}).unwrap_err();
    assert!(
        matches!(&e, RecordError::Io { path, .. } if path == &nowhere),
        "{e}"
    );
    // the input itself
    let e = animate(&full, &full, &AnimateOptions::default(), |_, _| {}).unwrap_err();
    assert!(matches!(&e, RecordError::NotAFile { .. }), "{e}");
    assert!(full.metadata().unwrap().len() > 1000);
    // an impossible frame rate: no output left behind
    let opts = AnimateOptions {
        fps: 0.0,
        ..Default::default()
    };
    let e = animate(&full, &out, &opts, |_, _| {}).unwrap_err();
    assert!(
        matches!(&e, RecordError::Render { path, .. } if path == &out),
        "{e}"
    );
    assert!(!out.exists() && !gpm::record::output::partial_path(&out).exists());
}

/// The command line: `--animate` with `--field`, `--size`, `--range`, and an unknown field.
#[test]
fn replay_animate_command_line() {
    let dir = tempfile::tempdir().unwrap();
    record_dam_break(&dir.path().join("run.mcap"), RecordLevel::Full);
    // `gpm replay --quiet run.mcap ARGS` in the directory: success and standard error
    let replay = |args: &[&str]| {
        let out = std::process::Command::new(env!("CARGO_BIN_EXE_gpm"))
            .args(["replay", "--quiet", "run.mcap"])
            .args(args)
            .current_dir(dir.path())
            .output()
            .unwrap();
        (
            out.status.success(),
            String::from_utf8_lossy(&out.stderr).into_owned(),
        )
    };
    let (ok, stderr) = replay(&[
        "--animate",
        "db.gif",
        "--field",
        "u",
        "--size",
        "360x240",
        "--scale=-1:1",
    ]);
    assert!(ok, "{stderr}");
    assert!(
        stderr.contains("360×240 pixels") && stderr.contains("'vx'"),
        "{stderr}"
    );
    assert_eq!(gif_frames(&dir.path().join("db.gif")).0, (360, 240));

    let (ok, stderr) = replay(&["--animate", "x.gif", "--field", "nope"]);
    assert!(!ok);
    assert!(
        stderr.contains("no field 'nope'") && stderr.contains("available: speed, pressure"),
        "{stderr}"
    );
    // --field without --animate is refused by the parser, and so is a bad scale
    let (ok, stderr) = replay(&["--field", "p"]);
    assert!(!ok && stderr.contains("--animate"), "{stderr}");
    let (ok, stderr) = replay(&["--animate", "x.gif", "--scale", "2:1"]);
    assert!(!ok && stderr.contains("LOW < HIGH"), "{stderr}");
}

/// Width and height from a PNG's header.
fn png_size(path: &Path) -> (u32, u32) {
    let b = std::fs::read(path).unwrap();
    assert_eq!(&b[..8], b"\x89PNG\r\n\x1a\n");
    let be = |k: usize| u32::from_be_bytes(b[k..k + 4].try_into().unwrap());
    (be(16), be(20))
}

#[test]
fn the_dam_break_draws_its_pressure_at_a_few_times() {
    let dir = tempfile::tempdir().unwrap();
    // to T = 1.1: snapshots after the first step and at T ≈ 1, then the end
    let cfg = small_dam_break(1.1);
    let run = gpm::scene::run_scene(&cfg, |_| {}, |_, _| Ok(ControlFlow::Continue(()))).unwrap();
    let kept: Vec<f64> = run.result.pressure.iter().map(|s| s.0).collect();
    assert_eq!(kept.len(), 2, "{kept:?}");
    assert!(
        kept[0] > 0.0 && kept[0] < 0.1 && kept[1] >= 1.0 && kept[1] < 1.1,
        "{kept:?}"
    );
    let water = run.result.particles;
    assert!(run
        .result
        .pressure
        .iter()
        .all(|s| s.1.len() == water && s.2.len() == water));
    run.write_plots(dir.path(), &cfg).unwrap();
    // three panels (T ≈ 0, 1, and 1.1 at the end) in two columns: two rows of 560 pixels
    // wide panels and the colour bar
    let (w, h) = png_size(&dir.path().join("pressure.png"));
    assert_eq!(w, 2 * 560 + 140);
    assert!((300..900).contains(&h), "height {h}");
}
