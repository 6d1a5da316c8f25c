//! Recording round trips: write → read → equal, snapshots, projection inputs and their re-run,
//! CSV and VTK export, and agreement with the mcap crate's own reader.

mod common;

use common::first_projection_input;
use gpm::boundary::Walls;
use gpm::flow::{FlowReport, Motion, Simulation};
use gpm::projection::ProjectionCapture;
use gpm::record::replay::{export_vtk, scan, Replay};
use gpm::record::rerun::{rerun_file, RerunReport};
use gpm::record::schema::{
    decode_roles, PointCloud, ProjectionInput, StepDiagnostics, TOPIC_CONFIG, TOPIC_DIAGNOSTICS,
    TOPIC_PARTICLES, TOPIC_PROJECTION,
};
use gpm::record::{RecordLevel, RecordSummary, Recorder, RecorderOptions};
use gpm::scene::cavity::{self, CavityConfig};
use gpm::scene::taylor_green::{self, TaylorGreenConfig};
use std::path::Path;

/// (step, x, u, p) at a snapshot step.
type Snapshot = (u64, Vec<[f64; 2]>, Vec<[f64; 2]>, Vec<f64>);

struct Recorded {
    reports: Vec<FlowReport>,
    snapshots: Vec<Snapshot>,
    captures: Vec<(u64, ProjectionCapture<2>)>,
    allowed_floating: usize,
    summary: RecordSummary,
}

fn cavity_config(motion: Motion) -> CavityConfig {
    CavityConfig::default().with(|c| {
        c.n = 12;
        c.t_end = 10.0;
        c.motion = motion;
        if motion == Motion::Lagrangian {
            // the Lagrangian cavity's time step (its lid corners blow up at the default)
            c.limits.cfl = gpm::scene::cavity::LAGRANGIAN_CFL;
        }
    })
}

/// A small cavity run, recorded from our own loop (so that the projection capture is on).
fn record_cavity(
    path: &Path,
    level: RecordLevel,
    k: u64,
    steps: usize,
    motion: Motion,
) -> Recorded {
    let cfg = cavity_config(motion);
    let mut sim: Simulation<2, Walls<2>> = cavity::build(&cfg).unwrap();
    sim.projection.capture = true;
    let config = serde_json::json!({ "scene": "cavity", "config": &cfg });
    let mut rec = Recorder::create(path, level, k, &config).unwrap();
    let mut out = Recorded {
        reports: Vec::new(),
        snapshots: Vec::new(),
        captures: Vec::new(),
        allowed_floating: sim.params.projection.allowed_floating,
        summary: RecordSummary::default(),
    };
    for _ in 0..steps {
        let r = sim.advance().unwrap();
        rec.write_step(&r, &sim).unwrap();
        if (r.step - 1).is_multiple_of(k) {
            let p = &sim.particles;
            out.snapshots
                .push((r.step, p.x.clone(), p.u.clone(), p.p.clone()));
            out.captures
                .push((r.step, sim.projection.captured.clone().unwrap()));
        }
        out.reports.push(r);
    }
    out.summary = rec.finish().unwrap();
    out
}

fn without_record_time(mut d: StepDiagnostics) -> StepDiagnostics {
    d.timings.record = 0.0;
    d
}

#[test]
fn diagnostics_round_trip() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("run.mcap");
    let rec = record_cavity(&path, RecordLevel::Diagnostics, 10, 12, Motion::Eulerian);
    assert_eq!(rec.summary.steps, 12);
    assert_eq!(rec.summary.messages[TOPIC_DIAGNOSTICS], 12);
    assert_eq!(rec.summary.bytes, std::fs::metadata(&path).unwrap().len());

    let replay = Replay::open(&path).unwrap();
    assert!(replay.scan.complete, "{:?}", replay.scan.damage);
    assert!(replay.damage().is_none());
    assert_eq!(replay.scan.announced_messages, Some(13));
    assert_eq!(replay.steps.len(), 12);
    for (got, r) in replay.steps.iter().zip(&rec.reports) {
        let want = StepDiagnostics::from_report(r, rec.allowed_floating, 0.0);
        assert_eq!(without_record_time(*got), want, "step {}", r.step);
        assert!(got.timings.record >= 0.0);
    }
    // the recorder measures itself: step 1 has no previous step
    assert_eq!(replay.steps[0].timings.record, 0.0);
    assert!(replay.steps[1].timings.record > 0.0);

    let config = replay.config.clone().expect("/config");
    assert_eq!(config.level, RecordLevel::Diagnostics);
    assert_eq!(config.format, "gpm-mcap");
    assert_eq!(config.config["scene"], "cavity");
    let cfg: CavityConfig = serde_json::from_value({
        let mut c = config.config["config"].clone();
        // ∞ is written as null by serde_json (see the report); the default is ∞
        c["limits"].as_object_mut().unwrap().remove("dt_max");
        c
    })
    .unwrap();
    assert_eq!(cfg, cavity_config(Motion::Eulerian));

    // log time = simulation time in ns, sequence = step; the mcap crate's reader agrees
    let bytes = std::fs::read(&path).unwrap();
    let msgs: Vec<_> = mcap::MessageStream::new(&bytes)
        .unwrap()
        .collect::<Result<_, _>>()
        .unwrap();
    assert_eq!(msgs.len(), 13);
    let diag: Vec<_> = msgs
        .iter()
        .filter(|m| m.channel.topic == TOPIC_DIAGNOSTICS)
        .collect();
    for (m, r) in diag.iter().zip(&rec.reports) {
        assert_eq!(m.sequence as u64, r.step);
        assert_eq!(m.log_time, (r.time * 1e9).round() as u64);
        assert_eq!(m.channel.message_encoding, "json");
        assert_eq!(m.channel.schema.as_ref().unwrap().encoding, "jsonschema");
    }
    assert_eq!(
        msgs.iter()
            .filter(|m| m.channel.topic == TOPIC_CONFIG)
            .count(),
        1
    );

    // summary statistics and CSV
    let s = replay.summary();
    assert_eq!(s.steps, 12);
    assert_eq!(s.step_range, Some((1, 12)));
    assert_eq!(s.connectivity_failures, 0);
    let c0_max = rec
        .reports
        .iter()
        .map(|r| r.projection.c0)
        .fold(0.0, f64::max);
    assert_eq!(s.c0.max, c0_max);
    let text = s.to_string();
    assert!(text.contains("complete"), "{text}");
    let csv = dir.path().join("steps.csv");
    replay.write_csv(&csv).unwrap();
    let table = std::fs::read_to_string(&csv).unwrap();
    let lines: Vec<&str> = table.lines().collect();
    assert_eq!(lines.len(), 13);
    let cols = lines[0].split(',').count();
    assert!(lines.iter().all(|l| l.split(',').count() == cols));
    assert!(lines[1].starts_with("1,"));
}

#[test]
fn level_none_writes_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("none.mcap");
    let rec = record_cavity(&path, RecordLevel::None, 10, 2, Motion::Eulerian);
    assert!(!path.exists());
    assert_eq!(rec.summary.path, None);
    assert_eq!(rec.summary.steps, 0);
}

#[test]
fn full_round_trip_and_exact_rerun() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("full.mcap");
    let k = 3;
    let rec = record_cavity(&path, RecordLevel::Full, k, 8, Motion::Eulerian);
    // snapshots at steps 1, 4, 7
    assert_eq!(rec.summary.messages[TOPIC_PARTICLES], 3);
    assert_eq!(rec.summary.messages[TOPIC_PROJECTION], 3);
    assert!(rec.summary.notes.is_empty(), "{:?}", rec.summary.notes);

    let mut clouds = Vec::new();
    let mut inputs = Vec::new();
    let sc = scan(
        &path,
        |m| {
            match m.topic {
                TOPIC_PARTICLES => {
                    clouds.push((m.sequence as u64, m.log_time, m.decode::<PointCloud>()?))
                }
                TOPIC_PROJECTION => inputs.push(m.decode::<ProjectionInput>()?),
                _ => {}
            }
            Ok(())
        },
        |_, _| {},
    )
    .unwrap();
    assert!(sc.complete);
    assert_eq!(sc.count(TOPIC_DIAGNOSTICS), 8);
    assert_eq!(clouds.len(), 3);

    for ((step, log_time, cloud), (s, x, u, p)) in clouds.iter().zip(&rec.snapshots) {
        assert_eq!(step, s);
        let t = rec.reports[*s as usize - 1].time;
        assert_eq!(*log_time, (t * 1e9).round() as u64);
        assert_eq!(
            cloud.timestamp.sec as u64 * 1_000_000_000 + cloud.timestamp.nsec as u64,
            *log_time
        );
        assert_eq!(cloud.len(), x.len());
        let cols = cloud
            .decode(&["x", "y", "z", "vx", "vy", "p", "role"])
            .unwrap();
        let col = |k: usize| cols[k].as_ref().unwrap();
        for i in 0..x.len() {
            assert_eq!(col(0)[i], x[i][0] as f32 as f64);
            assert_eq!(col(1)[i], x[i][1] as f32 as f64);
            assert_eq!(col(2)[i], 0.0);
            assert_eq!(col(3)[i], u[i][0] as f32 as f64);
            assert_eq!(col(4)[i], u[i][1] as f32 as f64);
            assert_eq!(col(5)[i], p[i] as f32 as f64);
        }
        assert!(col(6).contains(&2.0), "ghosts are in the cloud");
    }

    // projection inputs are bit-exact copies of the capture
    assert_eq!(inputs.len(), 3);
    for (m, (s, c)) in inputs.iter().zip(&rec.captures) {
        assert_eq!(m.step, *s);
        assert_eq!(m.dimension, 2);
        assert_eq!(m.dt.to_bits(), c.dt.to_bits());
        assert_eq!(m.x.to_vectors::<2>("x").unwrap(), c.x);
        assert_eq!(m.vol.to_f64("vol").unwrap(), c.vol);
        assert_eq!(
            decode_roles(&m.role_kind, &m.ghost_source, &m.ghost_walls).unwrap(),
            c.role
        );
        assert_eq!(m.u_star.to_vectors::<2>("u_star").unwrap(), c.u_star);
        assert_eq!(m.p_in.to_f64("p_in").unwrap(), c.p_in);
        assert_eq!(m.u_out.to_vectors::<2>("u_out").unwrap(), c.u_out);
        assert_eq!(m.p_out.to_f64("p_out").unwrap(), c.p_out);
        assert_eq!(m.phi.to_f64("phi").unwrap(), c.phi);
        // the fixed-particle cavity's source rule is the rest-walls one: its band is recorded
        let mut cavity_walls = Walls::cavity(1.0, 1.0);
        let lid = cavity_walls.walls.iter_mut().find(|w| w.moves()).unwrap();
        lid.source_band = cavity::SOURCE_BAND;
        let walls: Walls<2> = m.boundary.to_walls().unwrap();
        assert_eq!(walls, cavity_walls);
    }

    // Eulerian + Cholesky: the re-run through the current build is bit-identical
    let r = rerun_file(&path, |_, _| {}).unwrap();
    assert_eq!(r.steps.len(), 3);
    assert_eq!(r.identical(), 3, "{:?}", r.steps);
    assert_eq!(r.max_differences(), (0.0, 0.0, 0.0));

    // VTK export: one file per snapshot and a ParaView collection
    let vtk = dir.path().join("vtk");
    let out = export_vtk(&path, &vtk, |_, _| {}).unwrap();
    assert_eq!(out.files.len(), 3);
    let first = std::fs::read_to_string(&out.files[0]).unwrap();
    let n = rec.snapshots[0].1.len();
    assert!(first.contains(&format!("NumberOfPoints=\"{n}\"")));
    assert!(first.contains("Name=\"velocity\"") && first.contains("Name=\"p\""));
    assert!(first.trim_end().ends_with("</VTKFile>"));
    let pvd = std::fs::read_to_string(&out.collection).unwrap();
    assert_eq!(pvd.matches("<DataSet").count(), 3);
    assert!(pvd.contains("particles_000004.vtp"));
}

#[test]
fn lagrangian_rerun_is_close() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("lag.mcap");
    record_cavity(&path, RecordLevel::Full, 4, 9, Motion::Lagrangian);
    let r = rerun_file(&path, |_, _| {}).unwrap();
    assert_eq!(r.steps.len(), 3);
    // identical unless the neighbour candidates (matrix pattern) differ: round-off only
    let (du, dp, dphi) = r.max_relative_differences();
    assert!(du < 1e-9 && dp < 1e-9 && dphi < 1e-9, "{:?}", r.steps);
    eprintln!(
        "Lagrangian rerun: {}/{} identical, relative differences u {du:.2e} p {dp:.2e} phi {dphi:.2e}",
        r.identical(),
        r.steps.len()
    );
}

#[test]
fn periodic_projection_input_reruns() {
    // Taylor–Green: periodic box, no ghosts
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("tg.mcap");
    let cfg = TaylorGreenConfig::default().with(|c| {
        c.n = 12;
        c.t_end = 1.0;
    });
    let mut sim = taylor_green::build(&cfg).unwrap();
    sim.projection.capture = true;
    let options = RecorderOptions {
        flush_every: 2,
        ..RecorderOptions::new(RecordLevel::Full, 2)
    };
    let mut rec = Recorder::create_with(
        &path,
        options,
        &serde_json::json!({"scene": "taylor_green"}),
    )
    .unwrap();
    for _ in 0..4 {
        let r = sim.advance().unwrap();
        rec.write_step(&r, &sim).unwrap();
    }
    let s = rec.finish().unwrap();
    assert_eq!(s.messages[TOPIC_PROJECTION], 2);
    let r = rerun_file(&path, |_, _| {}).unwrap();
    assert_eq!(r.steps.len(), 2);
    assert_eq!(r.identical(), 2, "{:?}", r.steps);
    let replay = Replay::open(&path).unwrap();
    assert_eq!(replay.config.unwrap().flush_every, 2);
}

#[test]
fn missing_capture_is_reported() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("nocap.mcap");
    let cfg = cavity_config(Motion::Eulerian);
    let mut rec = Recorder::create(&path, RecordLevel::Full, 1, &serde_json::json!({})).unwrap();
    cavity::run(&cfg.with(|c| c.t_end = 0.05), |r, sim| {
        Ok(rec.write_step(r, sim)?)
    })
    .unwrap();
    let s = rec.finish().unwrap();
    assert!(s.messages[TOPIC_PARTICLES] > 0);
    assert!(!s.messages.contains_key(TOPIC_PROJECTION));
    assert_eq!(s.notes.len(), 1, "{:?}", s.notes);
}

/// Recording overhead and file size (not part of the test suite):
/// `GPM_BENCH_N=100 GPM_BENCH_STEPS=300 cargo test --release --test record_roundtrip -- --ignored --nocapture overhead`
/// Prints, per configuration, the loop's wall time per step, the recorder's own time per step
/// (encoding, compression, flushing, plus the projection capture at level `full`) and the file
/// size per 1000 steps.
#[test]
#[ignore]
fn overhead() {
    use gpm::record::ChunkCompression;
    use std::time::Instant;
    let env = |k: &str, d: usize| {
        std::env::var(k)
            .ok()
            .and_then(|v| v.parse().ok())
            .unwrap_or(d)
    };
    let (n, steps, reps) = (
        env("GPM_BENCH_N", 100),
        env("GPM_BENCH_STEPS", 300),
        env("GPM_BENCH_REPS", 2),
    );
    let dir = tempfile::tempdir().unwrap();
    let cfg = CavityConfig::default().with(|c| {
        c.n = n;
        c.t_end = 1e9;
    });
    let configs: Vec<(&str, RecordLevel, u64, ChunkCompression)> = vec![
        ("none", RecordLevel::None, 1, ChunkCompression::Zstd),
        (
            "diagnostics zstd flush 1",
            RecordLevel::Diagnostics,
            1,
            ChunkCompression::Zstd,
        ),
        (
            "diagnostics zstd flush 10",
            RecordLevel::Diagnostics,
            10,
            ChunkCompression::Zstd,
        ),
        (
            "diagnostics none flush 1",
            RecordLevel::Diagnostics,
            1,
            ChunkCompression::None,
        ),
        (
            "full k=10 zstd flush 1",
            RecordLevel::Full,
            1,
            ChunkCompression::Zstd,
        ),
        (
            "full k=10 none flush 1",
            RecordLevel::Full,
            1,
            ChunkCompression::None,
        ),
    ];
    println!(
        "cavity n = {n}, {steps} steps, {} threads",
        rayon::current_num_threads()
    );
    for rep in 0..reps {
        for (name, level, flush, compression) in &configs {
            let path = dir.path().join("bench.mcap");
            let mut sim = cavity::build(&cfg).unwrap();
            sim.projection.capture = *level == RecordLevel::Full;
            let options = RecorderOptions {
                flush_every: *flush,
                compression: *compression,
                ..RecorderOptions::new(*level, 10)
            };
            let t0 = Instant::now();
            let mut rec = Recorder::create_with(&path, options, &serde_json::json!({})).unwrap();
            let mut step_seconds = 0.0;
            for _ in 0..steps {
                let r = sim.advance().unwrap();
                step_seconds += r.neighbors_seconds
                    + r.advect_seconds
                    + r.projection.timings.predictor
                    + r.projection.timings.diagnostics
                    + r.projection.timings.source
                    + r.projection.timings.solve
                    + r.projection.timings.correction;
                rec.write_step(&r, &sim).unwrap();
            }
            let s = rec.finish().unwrap();
            let wall = t0.elapsed().as_secs_f64();
            println!(
                "rep {rep} {name:<28} wall {:8.3} ms/step  stages {:8.3} ms/step  recorder {:7.4} ms/step ({:5.2} % of stages)  {:9.1} kB/1000 steps",
                1e3 * wall / steps as f64,
                1e3 * step_seconds / steps as f64,
                1e3 * s.seconds / steps as f64,
                100.0 * s.seconds / step_seconds,
                s.bytes as f64 / steps as f64 * 1000.0 / 1e3
            );
        }
    }
}

/// The command line on a full recording: summary, CSV, plot, VTK and re-run in one call.
#[cfg(feature = "cli")]
#[test]
fn replay_command_line() {
    use std::process::Command;
    let gpm = env!("CARGO_BIN_EXE_gpm");
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("full.mcap");
    record_cavity(&path, RecordLevel::Full, 2, 5, Motion::Eulerian);
    let (csv, png, vtk) = (
        dir.path().join("s.csv"),
        dir.path().join("s.png"),
        dir.path().join("vtk"),
    );
    let out = Command::new(gpm)
        .args(["replay", "--quiet", "--rerun"])
        .arg(&path)
        .arg("--csv")
        .arg(&csv)
        .arg("--plot")
        .arg(&png)
        .arg("--vtk")
        .arg(&vtk)
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    for needle in [
        "complete",
        "/projection_input",
        "foxglove.PointCloud",
        "c0",
        "3 projections re-run, 3 bit-identical",
    ] {
        assert!(stdout.contains(needle), "missing {needle:?} in\n{stdout}");
    }
    assert_eq!(std::fs::read_to_string(&csv).unwrap().lines().count(), 6);
    assert!(std::fs::metadata(&png).unwrap().len() > 10_000);
    assert!(vtk.join("particles.pvd").exists() && vtk.join("particles_000005.vtp").exists());
    // JSON summary
    let out = Command::new(gpm)
        .args(["replay", "--quiet", "--json"])
        .arg(&path)
        .output()
        .unwrap();
    let s: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(s["steps"], 5);
    // errors: one line, the file named, no backtrace, non-zero exit
    let bad = dir.path().join("bad.mcap");
    std::fs::write(&bad, b"not an mcap file").unwrap();
    let out = Command::new(gpm)
        .args(["replay", "--quiet"])
        .arg(&bad)
        .env("RUST_BACKTRACE", "1")
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(
        stderr.starts_with("error: ") && stderr.contains("bad.mcap: not an MCAP file"),
        "{stderr}"
    );
    assert!(!stderr.contains("backtrace"), "{stderr}");
    assert_eq!(stderr.trim_end().lines().count(), 1, "{stderr}");
}

/// `gpm run`: flags over a config file, the printed summary, and config errors.
#[cfg(feature = "cli")]
#[test]
fn run_command_line() {
    use std::process::Command;
    let gpm = env!("CARGO_BIN_EXE_gpm");
    let dir = tempfile::tempdir().unwrap();
    let cfg = dir.path().join("tg.json");
    std::fs::write(&cfg, r#"{"n": 16, "t_end": 0.05, "re": 50.0}"#).unwrap();
    let out = Command::new(gpm)
        .args([
            "run",
            "taylor-green",
            "--quiet",
            "--n",
            "12",
            "--record",
            "full",
        ])
        .args(["--record-every", "1", "--config"])
        .arg(&cfg)
        .arg("--out")
        .arg(dir.path())
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let s: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(s["scene"], "taylor_green");
    assert_eq!(s["result"]["n"], 12, "the flag overrides the file");
    assert_eq!(s["result"]["re"], 50.0, "the file overrides the default");
    let steps = s["result"]["steps"].as_u64().unwrap();
    assert_eq!(s["record"]["messages"]["/particles"].as_u64(), Some(steps));
    let replay = Replay::open(dir.path().join("run.mcap")).unwrap();
    let config = replay.config.unwrap();
    assert_eq!(config.config["scene"], "taylor_green");
    assert_eq!(config.config["config"]["n"], 12);
    // the recorded configuration reproduces the run
    let again = dir.path().join("again");
    std::fs::write(dir.path().join("cfg.json"), config.config.to_string()).unwrap();
    let out = Command::new(gpm)
        .args([
            "run",
            "taylor-green",
            "--quiet",
            "--record",
            "none",
            "--config",
        ])
        .arg(dir.path().join("cfg.json"))
        .arg("--out")
        .arg(&again)
        .output()
        .unwrap();
    let s2: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(s2["result"]["steps"], s["result"]["steps"]);
    assert_eq!(s2["result"]["errors"], s["result"]["errors"]);
    // unknown keys are rejected with the file named
    std::fs::write(&cfg, r#"{"n": 16, "bogus": 1}"#).unwrap();
    let out = Command::new(gpm)
        .args(["run", "cavity", "--quiet", "--config"])
        .arg(&cfg)
        .arg("--out")
        .arg(dir.path())
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(
        stderr.contains("tg.json") && stderr.contains("unknown field"),
        "{stderr}"
    );
}

/// `gpm run cavity` in the Lagrangian frame takes the scene's smaller step (0.15 up to the
/// cell Reynolds number Re/n = 4, 0.1 above; the default 0.2 drives a particle through a wall
/// at n = 100) unless `--cfl` or the configuration file gives one; the flags' frame, Reynolds
/// number and resolution decide, after the file's.
#[cfg(feature = "cli")]
#[test]
fn gpm_run_gives_the_lagrangian_cavity_its_step_unless_one_is_given() {
    use std::process::Command;
    let gpm = env!("CARGO_BIN_EXE_gpm");
    let dir = tempfile::tempdir().unwrap();
    let moving = dir.path().join("moving.json");
    std::fs::write(&moving, r#"{"motion": "lagrangian", "n": 12}"#).unwrap();
    let given = dir.path().join("given.json");
    std::fs::write(&given, r#"{"limits": {"cfl": 0.18}}"#).unwrap();
    let cases: [(&str, &[&str], Option<&Path>, f64); 7] = [
        ("cavity", &["--motion", "lagrangian"], None, 0.1),
        (
            "cavity",
            &["--motion", "lagrangian", "--re", "20"],
            None,
            0.15,
        ),
        (
            "cavity",
            &["--motion", "lagrangian", "--cfl", "0.2"],
            None,
            0.2,
        ),
        ("cavity", &["--motion", "lagrangian"], Some(&given), 0.18),
        ("cavity", &["--re", "40"], Some(&moving), 0.15),
        ("cavity", &["--motion", "eulerian"], Some(&moving), 0.2),
        ("taylor-green", &["--motion", "lagrangian"], None, 0.2),
    ];
    for (k, (scene, flags, file, want)) in cases.into_iter().enumerate() {
        let out_dir = dir.path().join(format!("run{k}"));
        let mut cmd = Command::new(gpm);
        cmd.args(["run", scene, "--quiet", "--n", "12", "--t-end", "0.01"])
            .args(flags)
            .arg("--out")
            .arg(&out_dir);
        if let Some(f) = file {
            cmd.arg("--config").arg(f);
        }
        let out = cmd.output().unwrap();
        assert!(
            out.status.success(),
            "{scene} {flags:?}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        let config = Replay::open(out_dir.join("run.mcap"))
            .unwrap()
            .config
            .unwrap();
        assert_eq!(
            config.config["config"]["limits"]["cfl"].as_f64(),
            Some(want),
            "{scene} {flags:?} {file:?}"
        );
    }
}

/// `steps` steps of `sim` recorded in full every `k` steps (its projection captured), and the
/// re-run of the file.
fn record_full_and_rerun(
    sim: &mut Simulation<2, Walls<2>>,
    path: &Path,
    k: u64,
    steps: usize,
) -> RerunReport {
    sim.projection.capture = true;
    let mut rec = Recorder::create(path, RecordLevel::Full, k, &serde_json::json!({})).unwrap();
    for _ in 0..steps {
        let r = sim.advance().unwrap();
        rec.write_step(&r, sim).unwrap();
    }
    rec.finish().unwrap();
    rerun_file(path, |_, _| {}).unwrap()
}

/// Every projection parameter is recorded: a run with non-default ones re-runs bit for bit.
#[test]
fn rerun_honours_every_projection_parameter() {
    use gpm::boundary::VectorKind;
    use gpm::projection::Scheme;
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("params.mcap");
    let mut sim = cavity::build(&cavity_config(Motion::Eulerian)).unwrap();
    let p = &mut sim.params.projection;
    p.rho = 2.0;
    p.gravity = [0.0, -0.5];
    p.scheme = Scheme::Incremental;
    p.viscous_theta = 1.0;
    p.source_ghosts = VectorKind::Velocity;
    p.solve.reuse_numeric = false;
    let r = record_full_and_rerun(&mut sim, &path, 1, 3);
    assert_eq!(r.steps.len(), 3);
    assert_eq!(r.identical(), 3, "{:?}", r.steps);
    // and the default (mirror) continuation gives a different answer on the same input
    let mut m = first_projection_input(&path);
    m.params.source_ghosts = gpm::record::schema::GhostContinuation::Mirror;
    let changed = gpm::record::rerun::rerun_input(&m).unwrap();
    assert!(!changed.identical && changed.max_dphi > 0.0);
}

/// A run with the lid corners' singular flow subtracted records that part with each projection
/// input and re-runs bit for bit; the same input without it projects a different field, and
/// half of it recorded is refused by name.
#[test]
fn rerun_takes_the_recorded_singular_part() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("corner.mcap");
    let cfg = cavity_config(Motion::Eulerian).with(|c| c.scene.corner_subtraction = true);
    let mut sim = cavity::build(&cfg).unwrap();
    assert!(sim.projection.singular.is_some());
    let r = record_full_and_rerun(&mut sim, &path, 2, 4);
    assert_eq!(r.steps.len(), 2);
    assert_eq!(r.identical(), 2, "{:?}", r.steps);
    let m = first_projection_input(&path);
    let singular = sim.projection.singular.as_ref().unwrap();
    assert_eq!(
        m.singular_source
            .as_ref()
            .unwrap()
            .to_vectors::<2>("s")
            .unwrap(),
        singular.source
    );
    assert_eq!(
        m.singular_no_slip
            .as_ref()
            .unwrap()
            .to_vectors::<2>("s")
            .unwrap(),
        singular.no_slip
    );
    let mut without = m.clone();
    without.singular_source = None;
    without.singular_no_slip = None;
    let changed = gpm::record::rerun::rerun_input(&without).unwrap();
    assert!(!changed.identical && changed.rel_dp > 1e-3, "{changed:?}");
    let mut half = m.clone();
    half.singular_no_slip = None;
    let err = gpm::record::rerun::rerun_input(&half)
        .unwrap_err()
        .to_string();
    assert!(err.contains("singular_no_slip"), "{err}");
}

/// The Lagrangian Taylor–Green of the scene (jitter and shifting: the pressure's warm start is
/// poor, so the viscous tolerance adapts): every step records its implicit viscous solve and
/// both solves' warm-start residual and stopping tolerance, read back as the step reported
/// them, and consistent with what CG does — a solve that iterated started above its
/// tolerance and ended below where it started; the viscous tolerance lies within the
/// adaptive rule's bounds and rises above the fixed one on some step; the replay CSV has the
/// columns and the summary the lines.
#[test]
fn the_viscous_solve_and_the_warm_starts_are_recorded() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("tg.mcap");
    let cfg = TaylorGreenConfig::default().with(|c| {
        // above the moving direct limit (4 000 unknowns): the Poisson solve by AMG-CG
        c.n = 70;
        c.t_end = 1.0;
        c.motion = Motion::Lagrangian;
    });
    let mut sim = taylor_green::build(&cfg).unwrap();
    let solve = sim.params.projection.solve;
    let (tight, loose) = (solve.viscous_tol(), solve.rel_tol);
    assert!(solve.viscous_adaptive && tight < loose);
    let mut rec = Recorder::create(
        &path,
        RecordLevel::Diagnostics,
        1,
        &serde_json::json!({"scene": "taylor_green"}),
    )
    .unwrap();
    let steps = 30;
    let mut reports = Vec::new();
    for _ in 0..steps {
        let r = sim.advance().unwrap();
        rec.write_step(&r, &sim).unwrap();
        reports.push(r);
    }
    rec.finish().unwrap();
    let replay = Replay::open(&path).unwrap();
    assert_eq!(replay.steps.len(), steps);
    let mut loosened = 0;
    for (d, r) in replay.steps.iter().zip(&reports) {
        let v = d
            .viscous
            .expect("Crank–Nicolson: an implicit viscous solve every step");
        let want = r
            .projection
            .viscous
            .expect("the flow step reports its viscous solve");
        assert_eq!(v, gpm::record::schema::SolveDiagnostics::from(&want));
        for (name, s) in [("pressure", &d.solve), ("viscous", &v)] {
            let at = format!("step {}, {name}", d.step);
            if s.solver == gpm::poisson::SolverKind::Cholesky {
                assert_eq!((s.iterations, s.rel_tol), (0, 0.0), "{at}");
                continue;
            }
            assert!(s.rel_tol > 0.0 && s.rel_residual.is_finite(), "{at}: {s:?}");
            assert!(s.initial_rel_residual.is_finite(), "{at}: {s:?}");
            if s.iterations > 0 {
                assert!(s.initial_rel_residual > s.rel_tol, "{at}: {s:?}");
                assert!(s.rel_residual < s.initial_rel_residual, "{at}: {s:?}");
            } else {
                assert!(s.initial_rel_residual <= s.rel_tol, "{at}: {s:?}");
            }
        }
        assert_eq!(
            d.solve.solver,
            gpm::poisson::SolverKind::Amg,
            "step {}",
            d.step
        );
        assert_eq!(d.solve.rel_tol, loose, "step {}", d.step);
        if v.solver != gpm::poisson::SolverKind::Cholesky {
            assert!(
                (tight..=loose).contains(&v.rel_tol),
                "step {}: viscous tolerance {:e}",
                d.step,
                v.rel_tol
            );
            loosened += usize::from(v.rel_tol > tight);
        }
    }
    assert!(
        loosened > 0,
        "the adaptive rule never loosened the viscous solve"
    );
    let csv = dir.path().join("steps.csv");
    replay.write_csv(&csv).unwrap();
    let text = std::fs::read_to_string(&csv).unwrap();
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    for (line, d) in lines.zip(&replay.steps) {
        let row: Vec<&str> = line.split(',').collect();
        assert_eq!(row.len(), header.len());
        let cell = |name: &str| -> f64 {
            row[header.iter().position(|h| *h == name).expect(name)]
                .parse()
                .unwrap()
        };
        let v = d.viscous.unwrap();
        assert_eq!(cell("viscous_iterations"), v.iterations as f64);
        assert_eq!(cell("viscous_rel_tol"), v.rel_tol);
        assert_eq!(cell("initial_rel_residual"), d.solve.initial_rel_residual);
    }
    let text = replay.summary().to_string();
    assert!(text.contains("viscous     iterations"), "{text}");
}
