//! Issue 16: every input path of the library, `gpm run` and `gpm replay` hardened — corrupt
//! recorded projection inputs, strict configuration, output ownership (lock, partial files,
//! failed runs), non-regular input files, closed and full standard output, signals.

mod common;

use gpm::error::InputError;
use gpm::record::output::{failed_path, partial_path, OutputLock};
use gpm::record::replay::Replay;
use gpm::record::rerun::rerun_input;
use gpm::record::schema::{Array, BoundarySpec, ProjectionInput};
use gpm::record::{RecordError, RecordLevel, Recorder, RecorderOptions};
use gpm::scene::cavity::{self, CavityConfig};
use gpm::scene::taylor_green::{self, TaylorGreenConfig};
use gpm::scene::{config_from_json, run_recorded, scene_config_from_json, strict_json};
use std::ops::ControlFlow;
use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

// ---------------------------------------------------------------------------------------------
// re-running corrupt recorded projection inputs

/// The first recorded projection input of a short full recording of `build`'s simulation.
fn first_input(walls: bool) -> ProjectionInput {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("in.mcap");
    let mut rec = Recorder::create(&path, RecordLevel::Full, 1, &serde_json::json!({})).unwrap();
    if walls {
        let mut sim = cavity::build(&CavityConfig::default().with(|c| c.n = 10)).unwrap();
        sim.projection.capture = true;
        let r = sim.advance().unwrap();
        rec.write_step(&r, &sim).unwrap();
    } else {
        let mut sim =
            taylor_green::build(&TaylorGreenConfig::default().with(|c| c.n = 10)).unwrap();
        sim.projection.capture = true;
        let r = sim.advance().unwrap();
        rec.write_step(&r, &sim).unwrap();
    }
    rec.finish().unwrap();
    common::first_projection_input(&path)
}

fn u32s(a: &Array) -> Vec<u32> {
    a.to_u32("test").unwrap()
}
fn u8s(a: &Array) -> Vec<u8> {
    a.to_u8("test").unwrap()
}

/// Each corruption of a recorded input: `rerun_input` returns (an error or a comparison), never
/// panics; `must_fail` ones are errors whose message contains the given words.
#[test]
fn corrupt_projection_inputs_are_errors_not_panics() {
    type Corrupt = Box<dyn Fn(&mut ProjectionInput)>;
    for walls in [true, false] {
        let base = first_input(walls);
        let n = base.particles;
        let kinds = u8s(&base.role_kind);
        let first_ghost = kinds.iter().position(|&k| k == 2).unwrap_or(n);
        let set_source = |v: u32| -> Corrupt {
            Box::new(move |m: &mut ProjectionInput| {
                let mut s = u32s(&m.ghost_source);
                let k = u8s(&m.role_kind);
                for i in 0..s.len() {
                    if k[i] == 2 {
                        s[i] = v;
                    }
                }
                m.ghost_source = Array::from_u32(&s);
            })
        };
        let mut cases: Vec<(&str, Corrupt, Option<&str>)> = vec![
            ("ghost source out of range", set_source(u32::MAX), None),
            ("ghost source = n", set_source(n as u32), None),
            (
                "every particle a ghost of particle 0",
                Box::new(|m: &mut ProjectionInput| {
                    let k = vec![2u8; m.particles];
                    m.role_kind = Array::from_u8(&k);
                    m.ghost_source = Array::from_u32(&vec![0; m.particles]);
                }),
                Some("ghost"),
            ),
            (
                "a ghost in the middle of the fluid",
                Box::new(|m: &mut ProjectionInput| {
                    let mut k = u8s(&m.role_kind);
                    k[1] = 2;
                    m.role_kind = Array::from_u8(&k);
                }),
                Some("ghost particle"),
            ),
            (
                "ghost walls 0xff",
                Box::new(|m: &mut ProjectionInput| {
                    let k = u8s(&m.role_kind);
                    let w: Vec<u8> = k.iter().map(|&c| if c == 2 { 0xff } else { 0 }).collect();
                    m.ghost_walls = Array::from_u8(&w);
                }),
                None,
            ),
            (
                "ghost walls 0",
                Box::new(|m: &mut ProjectionInput| {
                    m.ghost_walls = Array::from_u8(&vec![0; m.particles]);
                }),
                None,
            ),
            (
                "roles shorter than positions",
                Box::new(|m: &mut ProjectionInput| {
                    let k = u8s(&m.role_kind);
                    m.role_kind = Array::from_u8(&k[..k.len() - 1]);
                }),
                Some("roles"),
            ),
            (
                "a NaN position",
                Box::new(|m: &mut ProjectionInput| {
                    let mut x = m.x.to_f64("x").unwrap();
                    x[3] = f64::NAN;
                    m.x = Array {
                        shape: m.x.shape.clone(),
                        ..Array::from_f64(&x)
                    };
                }),
                Some("not finite"),
            ),
            (
                "dimension 3 for 2D arrays",
                Box::new(|m: &mut ProjectionInput| m.dimension = 3),
                None,
            ),
            (
                "h NaN",
                Box::new(|m: &mut ProjectionInput| m.neighbors.h = f64::NAN),
                None,
            ),
            (
                "h huge",
                Box::new(|m: &mut ProjectionInput| m.neighbors.h = 1e300),
                None,
            ),
            (
                "dt NaN",
                Box::new(|m: &mut ProjectionInput| m.dt = f64::NAN),
                None,
            ),
        ];
        if walls {
            cases.push((
                "a wall on axis 7",
                Box::new(|m: &mut ProjectionInput| {
                    if let BoundarySpec::Walls { walls, .. } = &mut m.boundary {
                        walls[0].axis = 7;
                    }
                }),
                Some("axis"),
            ));
            cases.push((
                "nine walls",
                Box::new(|m: &mut ProjectionInput| {
                    if let BoundarySpec::Walls { walls, .. } = &mut m.boundary {
                        let w = walls[0].clone();
                        walls.resize(9, w);
                    }
                }),
                None,
            ));
            cases.push((
                "a wall velocity of the wrong dimension",
                Box::new(|m: &mut ProjectionInput| {
                    if let BoundarySpec::Walls { walls, .. } = &mut m.boundary {
                        walls[0].velocity = vec![1.0];
                    }
                }),
                None,
            ));
        }
        assert!(first_ghost < n || !walls, "the cavity input has ghosts");
        for (what, corrupt, must_fail) in &cases {
            let mut m = base.clone();
            corrupt(&mut m);
            let r = std::panic::catch_unwind(|| rerun_input(&m));
            let r = r.unwrap_or_else(|_| panic!("walls {walls}: '{what}' panicked"));
            if let Some(words) = must_fail {
                let e = r.expect_err(what).to_string();
                assert!(e.contains(words), "walls {walls}: '{what}': {e}");
            }
        }
    }
}

// ---------------------------------------------------------------------------------------------
// strict configuration

fn config_key(text: &str) -> String {
    match config_from_json::<CavityConfig>(text) {
        Err(InputError::Config { key, .. }) => key,
        other => panic!("{text}: expected a configuration error, got {other:?}"),
    }
}

#[test]
fn configuration_arrays_duplicates_and_ranges_are_named() {
    // arrays for structures, at the top and nested
    assert_eq!(config_key("[100, 32]"), "(top level)");
    assert_eq!(config_key(r#"{"limits": [0.2, 0.5, 0.25, 1]}"#), "limits");
    assert_eq!(config_key(r#"{"steady": [0.5, 1e-3, 2, true]}"#), "steady");
    assert_eq!(
        config_key(r#"{"solve": {"rel_tol": [1e-8]}}"#),
        "solve.rel_tol"
    );
    assert_eq!(
        config_key(r#"{"shifting": [0.1, 0.2, true, false]}"#),
        "shifting"
    );
    // duplicate keys, at the top and nested, named by path
    assert_eq!(config_key(r#"{"n": 10, "n": 20}"#), "n");
    assert_eq!(
        config_key(r#"{"limits": {"cfl": 0.1, "visc": 0.5, "cfl": 0.3}}"#),
        "limits.cfl"
    );
    let e = strict_json(r#"{"a": {"b": [{"c": 1, "c": 2}]}}"#).unwrap_err();
    assert!(
        matches!(e, InputError::Config { ref key, .. } if key == "a.b[0].c"),
        "{e:?}"
    );
    // trailing data and syntax
    assert_eq!(config_key(r#"{"n": 10} {"n": 20}"#), "(top level)");
    assert_eq!(config_key(r#"{"n": 10"#), "(top level)");
    // the wrapped form (a recording's /config) is strict too, and checks the scene's name
    let e = scene_config_from_json::<cavity::Cavity>(
        r#"{"scene": "cavity", "config": {"n": 10, "n": 12}}"#,
    )
    .unwrap_err();
    assert!(
        matches!(e, InputError::Config { ref key, .. } if key == "config.n"),
        "{e:?}"
    );
    let e = scene_config_from_json::<cavity::Cavity>(
        r#"{"scene": "cavity", "config": {"limits": [1, 2]}}"#,
    )
    .unwrap_err();
    assert!(
        matches!(e, InputError::Config { ref key, .. } if key == "config.limits"),
        "{e:?}"
    );
    let e = scene_config_from_json::<cavity::Cavity>(r#"{"scene": "taylor_green", "config": {}}"#)
        .unwrap_err();
    assert!(
        matches!(e, InputError::Config { ref key, .. } if key == "scene"),
        "{e:?}"
    );
    let ok = scene_config_from_json::<cavity::Cavity>(r#"{"scene": "cavity", "config": {"n": 9}}"#)
        .unwrap();
    assert_eq!(ok.n, 9);
    // a file without limits.cfl takes the step the scene needs in its frame: the Lagrangian
    // cavity's 0.15 up to the cell Reynolds number Re/n = 4 and 0.1 above (the default 0.2
    // drives a particle through a wall), everything else the default 0.2
    let cfl = |text: &str| {
        scene_config_from_json::<cavity::Cavity>(text)
            .unwrap()
            .limits
            .cfl
    };
    assert_eq!(
        cfl(r#"{"motion": "lagrangian", "n": 100, "re": 100}"#),
        0.15
    );
    assert_eq!(
        cfl(r#"{"motion": "lagrangian", "n": 100, "re": 1000}"#),
        0.1
    );
    assert_eq!(
        cfl(r#"{"config": {"motion": "lagrangian", "n": 50, "re": 200}}"#),
        0.15
    );
    assert_eq!(
        cfl(r#"{"motion": "lagrangian", "n": 100, "limits": {"cfl": 0.3}}"#),
        0.3
    );
    assert_eq!(cfl(r#"{"n": 100, "re": 1000}"#), 0.2);
    let tg = scene_config_from_json::<gpm::scene::taylor_green::TaylorGreen>(
        r#"{"motion": "lagrangian", "n": 100}"#,
    )
    .unwrap();
    assert_eq!(tg.limits.cfl, 0.2);
    // ranges: cfl, visc, force in (0, 1]; n at most MAX_N
    for (text, key) in [
        (r#"{"limits": {"cfl": 1e300}}"#, "limits.cfl"),
        (r#"{"limits": {"cfl": 1.5}}"#, "limits.cfl"),
        (r#"{"limits": {"visc": 2}}"#, "limits.visc"),
        (r#"{"n": 20000}"#, "n"),
        (r#"{"limits": {"u_ref": 1e300}}"#, "limits.u_ref"),
    ] {
        let cfg: CavityConfig = config_from_json(text).unwrap();
        let e = cfg.validate().unwrap_err();
        assert_eq!(e.parameter_name(), Some(key), "{text}: {e}");
        assert!(e.to_string().contains(key), "{e}");
    }
    let cfg: CavityConfig = config_from_json(r#"{"limits": {"cfl": 1.0}}"#).unwrap();
    cfg.validate().unwrap();
}

#[test]
fn memory_estimate_is_an_upper_bound_of_the_measured_peaks() {
    // README, Performance: 2D, h = 3Δx: 293 MB at 10⁵ and 2.7 GB at 10⁶ particles
    for (n, measured) in [(316usize, 293e6), (1000, 2.7e9)] {
        let cfg = CavityConfig::default().with(|c| c.n = n);
        let (particles, bytes) = cfg.memory_estimate::<2>();
        assert!(particles >= (n * n) as f64);
        assert!(
            bytes > measured && bytes < 2.0 * measured,
            "n {n}: {bytes:e}"
        );
    }
}

#[test]
fn a_run_without_a_step_is_an_error_not_a_result() {
    let cfg = CavityConfig::default().with(|c| {
        c.n = 8;
        c.t_end = 1e-13;
    });
    cfg.validate().unwrap();
    let Err(e) = cavity::run(&cfg, |_, _| Ok(())) else {
        panic!("no step: an error expected");
    };
    assert!(e.to_string().contains("t_end"), "{e}");
    assert!(e.to_string().contains("no step"), "{e}");
}

// ---------------------------------------------------------------------------------------------
// output ownership

#[test]
fn an_output_directory_has_one_owner() {
    let dir = tempfile::tempdir().unwrap();
    let lock = OutputLock::acquire(dir.path()).unwrap();
    let e = OutputLock::acquire(dir.path()).unwrap_err();
    assert!(
        matches!(e, RecordError::Locked { holder: Some(p), .. } if p == std::process::id()),
        "{e:?}"
    );
    assert!(
        e.to_string().contains(&std::process::id().to_string()),
        "{e}"
    );
    // a run into the locked directory fails before writing anything
    let cfg = CavityConfig::default().with(|c| {
        c.n = 8;
        c.t_end = 0.05;
    });
    let path = dir.path().join("run.mcap");
    let r = run_recorded(
        &cfg,
        &path,
        RecorderOptions::new(RecordLevel::Diagnostics, 10),
        &cfg.record_header(),
        |_| {},
        |_, _| Ok(ControlFlow::Continue(())),
    );
    assert!(matches!(r, Err(RecordError::Locked { .. })));
    assert!(!path.exists() && !partial_path(&path).exists());
    drop(lock);
    OutputLock::acquire(dir.path()).unwrap();
}

/// A good recording is replaced by a finished one only; a failed run keeps its steps aside.
#[test]
fn a_failed_run_never_replaces_a_good_recording() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("run.mcap");
    let cfg = CavityConfig::default().with(|c| {
        c.n = 8;
        c.t_end = 0.1;
    });
    let opts = RecorderOptions::new(RecordLevel::Diagnostics, 10);
    let good = run_recorded(
        &cfg,
        &path,
        opts,
        &cfg.record_header(),
        |_| {},
        |_, _| Ok(ControlFlow::Continue(())),
    )
    .unwrap();
    assert!(good.run.is_ok());
    let s = good.record.unwrap();
    assert_eq!(s.path.as_deref(), Some(path.as_path()));
    drop(good.lock);
    let before = std::fs::read(&path).unwrap();
    // a run that fails at its second step (the observer's error; the run has 2 steps)
    let failed = run_recorded(
        &cfg,
        &path,
        opts,
        &cfg.record_header(),
        |_| {},
        |rep, _| {
            if rep.step == 2 {
                Err(InputError::parameter("test", 2.0, "failing on purpose").into())
            } else {
                Ok(ControlFlow::Continue(()))
            }
        },
    )
    .unwrap();
    assert!(failed.run.is_err());
    let s = failed.record.unwrap();
    assert_eq!(s.path.as_deref(), Some(failed_path(&path).as_path()));
    assert_eq!(
        std::fs::read(&path).unwrap(),
        before,
        "the good recording is untouched"
    );
    assert_eq!(Replay::open(failed_path(&path)).unwrap().steps.len(), 2);
    assert!(!partial_path(&path).exists());
    drop(failed.lock);
    // a run that fails before its first step keeps its configuration aside too
    let bad = cfg.clone().with(|c| c.t_end = 1e-13);
    let failed = run_recorded(
        &bad,
        &path,
        opts,
        &bad.record_header(),
        |_| {},
        |_, _| Ok(ControlFlow::Continue(())),
    )
    .unwrap();
    assert!(failed.run.is_err());
    assert_eq!(failed.record.unwrap().path, Some(failed_path(&path)));
    let r = Replay::open(failed_path(&path)).unwrap();
    assert!(r.steps.is_empty() && r.config.is_some() && r.scan.complete);
    assert!(!partial_path(&path).exists());
    assert_eq!(std::fs::read(&path).unwrap(), before);
}

#[test]
fn a_recording_is_written_under_its_partial_name_until_finished() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("own.mcap");
    let mut sim = cavity::build(&CavityConfig::default().with(|c| c.n = 8)).unwrap();
    let mut rec = Recorder::create(&path, RecordLevel::Diagnostics, 1, &()).unwrap();
    assert_eq!(rec.path(), Some(partial_path(&path).as_path()));
    assert_eq!(rec.target(), Some(path.as_path()));
    let r = sim.advance().unwrap();
    rec.write_step(&r, &sim).unwrap();
    assert!(!path.exists());
    // the partial file reads back while the run goes on (a killed run leaves it)
    assert_eq!(Replay::open(partial_path(&path)).unwrap().steps.len(), 1);
    let s = rec.finish().unwrap();
    assert_eq!(s.path.as_deref(), Some(path.as_path()));
    assert!(path.exists() && !partial_path(&path).exists());
}

// ---------------------------------------------------------------------------------------------
// the command line

fn gpm_bin() -> PathBuf {
    PathBuf::from(env!("CARGO_BIN_EXE_gpm"))
}

fn gpm(args: &[&str]) -> Output {
    Command::new(gpm_bin())
        .args(args)
        .env("RUST_BACKTRACE", "1")
        .stdin(Stdio::null())
        .output()
        .unwrap()
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// No panic, and a one-line error.
fn assert_clean_failure(o: &Output, words: &[&str]) {
    let e = stderr(o);
    assert!(!o.status.success(), "succeeded: {e}");
    assert!(!e.contains("panicked"), "{e}");
    for w in words {
        assert!(e.contains(w), "missing '{w}' in: {e}");
    }
}

/// A short recorded cavity run into `dir`.
fn record_cli(dir: &Path, extra: &[&str]) -> Output {
    let mut args = vec![
        "run",
        "cavity",
        "--n",
        "10",
        "--t-end",
        "0.2",
        "--quiet",
        "--out",
        dir.to_str().unwrap(),
    ];
    args.extend_from_slice(extra);
    gpm(&args)
}

#[test]
fn cli_refuses_fifos_and_writing_onto_its_input() {
    let dir = tempfile::tempdir().unwrap();
    let o = record_cli(dir.path(), &[]);
    assert!(o.status.success(), "{}", stderr(&o));
    let file = dir.path().join("run.mcap");
    let f = file.to_str().unwrap();
    let bytes = std::fs::read(&file).unwrap();
    for flag in ["--csv", "--plot"] {
        let o = gpm(&["replay", f, flag, f, "--quiet"]);
        assert_clean_failure(&o, &["input file", "run.mcap"]);
    }
    let o = gpm(&["replay", f, "--vtk", f, "--quiet"]);
    assert_clean_failure(&o, &["input file"]);
    assert_eq!(
        std::fs::read(&file).unwrap(),
        bytes,
        "the input is untouched"
    );
    // a directory and a FIFO as input are refused at once (not waited on)
    let o = gpm(&["replay", dir.path().to_str().unwrap(), "--quiet"]);
    assert_clean_failure(&o, &["directory"]);
    #[cfg(unix)]
    {
        let fifo = dir.path().join("fifo");
        let ok = Command::new("mkfifo")
            .arg(&fifo)
            .status()
            .is_ok_and(|s| s.success());
        if ok {
            let t0 = Instant::now();
            let o = gpm(&["replay", fifo.to_str().unwrap(), "--quiet"]);
            assert_clean_failure(&o, &["FIFO"]);
            let o = gpm(&[
                "run",
                "cavity",
                "--config",
                fifo.to_str().unwrap(),
                "--out",
                dir.path().join("x").to_str().unwrap(),
            ]);
            assert_clean_failure(&o, &["FIFO"]);
            assert!(t0.elapsed() < Duration::from_secs(30));
        }
    }
}

#[test]
fn cli_configuration_threads_and_estimates_are_checked() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("o");
    let o = out.to_str().unwrap();
    let cfg = dir.path().join("c.json");
    let c = cfg.to_str().unwrap();
    for (text, words) in [
        (r#"{"n": 10, "n": 12}"#, &["'n'", "more than once"][..]),
        (r#"{"limits": [0.2, 0.5]}"#, &["'limits'", "array"][..]),
        (
            r#"{"scene": "cavity", "config": {"solve": {"rel_tol": 1e-8, "rel_tol": 1e-9}}}"#,
            &["config.solve.rel_tol"][..],
        ),
        (
            r#"{"limits": {"cfl": 1e300}}"#,
            &["limits.cfl", "(0, 1]"][..],
        ),
    ] {
        std::fs::write(&cfg, text).unwrap();
        let r = gpm(&["run", "cavity", "--config", c, "--out", o, "--quiet"]);
        assert_clean_failure(&r, words);
        assert_eq!(stderr(&r).lines().count(), 1, "{}", stderr(&r));
    }
    // thread counts
    let r = gpm(&["--threads", "5000", "run", "cavity", "--out", o]);
    assert_clean_failure(&r, &["--threads 5000"]);
    let r = gpm(&["--threads", "0", "run", "cavity", "--out", o]);
    assert_clean_failure(&r, &["--threads 0"]);
    // a tiny fixed time step: refused with the estimate, before anything is written
    std::fs::write(
        &cfg,
        r#"{"n": 8, "t_end": 10, "limits": {"dt_fixed": 1e-7}}"#,
    )
    .unwrap();
    let r = gpm(&["run", "cavity", "--config", c, "--out", o, "--quiet"]);
    assert_clean_failure(&r, &["steps", "--force"]);
    assert!(!out.join("run.mcap").exists());
    // more memory than there is
    let r = gpm(&["run", "cavity", "--n", "10000", "--out", o, "--quiet"]);
    assert_clean_failure(&r, &["GB", "--force"]);
}

#[test]
fn cli_second_run_into_one_directory_fails_at_once_naming_the_holder() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().to_str().unwrap();
    // the first run takes a few seconds (n = 64 to t = 8: 4.5 s on 2026-11-27; n = 24 to t = 3
    // had come down to 0.2 s, short enough to end while the second run was starting)
    let mut first = Command::new(gpm_bin())
        .args([
            "run", "cavity", "--n", "64", "--t-end", "8", "--quiet", "--out", out,
        ])
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let lock = dir.path().join(".gpm.lock");
    let t0 = Instant::now();
    while !std::fs::read_to_string(&lock).is_ok_and(|s| !s.trim().is_empty()) {
        assert!(t0.elapsed() < Duration::from_secs(60), "no lock taken");
        std::thread::sleep(Duration::from_millis(20));
    }
    let t1 = Instant::now();
    let second = record_cli(dir.path(), &[]);
    assert!(
        t1.elapsed() < Duration::from_secs(20),
        "the second run waited"
    );
    assert_clean_failure(&second, &["in use", &format!("process {}", first.id())]);
    let status = first.wait().unwrap();
    assert!(status.success());
    assert!(
        Replay::open(dir.path().join("run.mcap"))
            .unwrap()
            .steps
            .len()
            > 10
    );
}

#[test]
fn cli_closed_and_full_stdout() {
    let dir = tempfile::tempdir().unwrap();
    let o = record_cli(dir.path(), &[]);
    assert!(o.status.success());
    let f = dir.path().join("run.mcap");
    // a closed pipe: the reader went away after the first line
    #[cfg(unix)]
    {
        let mut child = Command::new(gpm_bin())
            .args(["replay", f.to_str().unwrap(), "--quiet"])
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        drop(child.stdout.take()); // close the read end before it writes
        let out = child.wait_with_output().unwrap();
        let e = String::from_utf8_lossy(&out.stderr);
        assert!(!e.contains("panicked"), "{e}");
        assert!(out.status.success(), "{e}");
        // a full device: a clear error, non-zero status
        if Path::new("/dev/full").exists() {
            for args in [
                vec!["replay", f.to_str().unwrap(), "--quiet"],
                vec!["replay", f.to_str().unwrap(), "--quiet", "--json"],
            ] {
                let full = std::fs::OpenOptions::new()
                    .write(true)
                    .open("/dev/full")
                    .unwrap();
                let out = Command::new(gpm_bin())
                    .args(&args)
                    .stdout(full)
                    .stderr(Stdio::piped())
                    .output()
                    .unwrap();
                assert_clean_failure(&out, &["standard output", "space"]);
            }
            let full = std::fs::OpenOptions::new()
                .write(true)
                .open("/dev/full")
                .unwrap();
            let d2 = dir.path().join("full");
            let out = Command::new(gpm_bin())
                .args([
                    "run", "cavity", "--n", "8", "--t-end", "0.1", "--quiet", "--out",
                ])
                .arg(&d2)
                .stdout(full)
                .stderr(Stdio::piped())
                .output()
                .unwrap();
            assert_clean_failure(&out, &["standard output"]);
            // the recording itself is complete
            assert!(Replay::open(d2.join("run.mcap")).unwrap().scan.complete);
        }
    }
}

/// SIGINT, SIGTERM, SIGHUP mid-run: the run stops after its step, finishes the file (footer
/// written: a complete file), prints the step it stopped after, and exits with 128 + signal;
/// the steps read back equal the steps printed. SIGKILL: the partial file keeps every flushed
/// step (flush every step: at most the step being written is lost).
#[cfg(unix)]
#[test]
fn cli_signals_finish_the_recording() {
    for (sig, name) in [(2, "INT"), (15, "TERM"), (1, "HUP"), (9, "KILL")] {
        let dir = tempfile::tempdir().unwrap();
        let child = Command::new(gpm_bin())
            .args([
                "run", "cavity", "--n", "30", "--t-end", "20", "--quiet", "--out",
            ])
            .arg(dir.path())
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        let partial = dir.path().join("run.mcap.partial");
        // wait until a few steps are on disk
        let t0 = Instant::now();
        loop {
            let steps = Replay::open(&partial).map(|r| r.steps.len()).unwrap_or(0);
            if steps >= 5 {
                break;
            }
            assert!(
                t0.elapsed() < Duration::from_secs(120),
                "SIG{name}: no steps"
            );
            std::thread::sleep(Duration::from_millis(50));
        }
        let ok = Command::new("kill")
            .args([format!("-{name}"), child.id().to_string()])
            .status()
            .unwrap();
        assert!(ok.success());
        let out = child.wait_with_output().unwrap();
        let e = String::from_utf8_lossy(&out.stderr).into_owned();
        assert!(!e.contains("panicked"), "SIG{name}: {e}");
        if sig == 9 {
            let r = Replay::open(&partial).unwrap();
            assert!(r.steps.len() >= 5, "SIG{name}");
            assert!(!dir.path().join("run.mcap").exists());
            continue;
        }
        use std::os::unix::process::ExitStatusExt;
        assert_eq!(
            out.status.code(),
            Some(128 + sig),
            "SIG{name}: {e} {:?}",
            out.status.signal()
        );
        let printed: usize = e
            .split("after step ")
            .nth(1)
            .and_then(|s| s.split(|c: char| !c.is_ascii_digit()).next())
            .and_then(|s| s.parse().ok())
            .unwrap_or_else(|| panic!("SIG{name}: no step printed: {e}"));
        assert!(e.contains(&format!("SIG{name}")), "{e}");
        let r = Replay::open(dir.path().join("run.mcap")).unwrap();
        assert!(r.scan.complete && r.damage().is_none(), "SIG{name}");
        assert_eq!(r.steps.len(), printed, "SIG{name}: {e}");
        assert!(!partial.exists());
        // `gpm replay` reads it back
        let o = gpm(&[
            "replay",
            dir.path().join("run.mcap").to_str().unwrap(),
            "--quiet",
            "--strict",
        ]);
        assert!(o.status.success(), "{}", stderr(&o));
    }
}
