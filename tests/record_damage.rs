//! Damaged files: truncated at every position, random garbage, empty files, flipped bytes, and a
//! `gpm run` process killed mid-run (SIGKILL) or interrupted with Ctrl-C (SIGINT). Reading must
//! never panic, must keep every flushed step and must say where the file was cut.

use gpm::record::replay::Replay;
use gpm::record::schema::{StepDiagnostics, TOPIC_DIAGNOSTICS};
use gpm::record::{RecordError, RecordLevel, Recorder};
use gpm::scene::cavity::{self, CavityConfig};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

/// Records `steps` cavity steps (flush every step) and returns the file size after the `/config`
/// chunk and after each step: everything up to `ends[s]` is on disk once step `s` is written.
fn record(path: &Path, steps: usize) -> (Vec<u64>, Vec<StepDiagnostics>) {
    let cfg = CavityConfig::default().with(|c| c.n = 12);
    let mut sim = cavity::build(&cfg).unwrap();
    let mut rec =
        Recorder::create(path, RecordLevel::Diagnostics, 10, &serde_json::json!({})).unwrap();
    // written as `path.partial` until `finish` renames it
    let partial = gpm::record::output::partial_path(path);
    let size = || std::fs::metadata(&partial).unwrap().len();
    let mut ends = vec![size()];
    for _ in 0..steps {
        let r = sim.advance().unwrap();
        rec.write_step(&r, &sim).unwrap();
        ends.push(size());
    }
    rec.finish().unwrap();
    let full = Replay::open(path).unwrap();
    assert!(full.scan.complete);
    (ends, full.steps)
}

#[test]
fn truncated_anywhere_keeps_every_flushed_step() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("full.mcap");
    let steps = 20;
    let (ends, all) = record(&path, steps);
    let bytes = std::fs::read(&path).unwrap();
    let len = bytes.len() as u64;
    let mut cuts: Vec<u64> = (0..=len).step_by(13).collect();
    for &e in &ends {
        cuts.extend([e.saturating_sub(1), e, e + 1]);
    }
    cuts.extend([len - 1, len]);
    cuts.retain(|&c| c <= len);
    cuts.sort_unstable();
    cuts.dedup();
    let cut_path = dir.path().join("cut.mcap");
    for &c in &cuts {
        std::fs::write(&cut_path, &bytes[..c as usize]).unwrap();
        let r = Replay::open(&cut_path).unwrap_or_else(|e| panic!("cut at {c}: {e}"));
        let got = r.steps.len();
        // every step flushed before the cut is there, and none that was not written
        let flushed = (1..=steps).filter(|&s| ends[s] <= c).count();
        let written = (1..=steps).filter(|&s| ends[s - 1] < c).count();
        assert!(
            got >= flushed && got <= written,
            "cut at {c}: {got} steps, flushed {flushed}, written {written}"
        );
        assert_eq!(r.steps[..], all[..got], "cut at {c}");
        if c == len {
            assert!(r.damage().is_none() && r.scan.complete);
            continue;
        }
        let d = r
            .damage()
            .unwrap_or_else(|| panic!("cut at {c}: no damage reported"));
        assert_eq!(d.file_len, c);
        assert!(d.valid_bytes <= c);
        let text = d.to_string();
        if d.data_complete {
            assert_eq!(got, steps, "cut at {c}");
            assert!(text.contains("summary"), "{text}");
        } else if got > 0 {
            assert_eq!(d.last_step, Some(got as u64));
            assert!(
                text.contains(&format!("cut after step {got}")) && text.contains("byte offset"),
                "{text}"
            );
        } else {
            assert!(text.contains("cut before any step"), "{text}");
        }
        // the mcap crate's streaming reader recovers the same messages
        let ours = r.scan.count(TOPIC_DIAGNOSTICS) as usize;
        assert_eq!(ours, got);
        if c >= 8 {
            let theirs = mcap::MessageStream::new_with_options(
                &bytes[..c as usize],
                mcap::read::Options::IgnoreEndMagic.into(),
            )
            .map(|s| {
                s.take_while(|m| m.is_ok())
                    .filter(|m| m.as_ref().unwrap().channel.topic == TOPIC_DIAGNOSTICS)
                    .count()
            })
            .unwrap_or(0);
            assert_eq!(ours, theirs, "cut at {c}");
        }
    }
}

#[test]
fn empty_garbage_and_flipped_bytes_never_panic() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("x.mcap");
    // empty: a file cut at byte 0
    std::fs::write(&p, b"").unwrap();
    let r = Replay::open(&p).unwrap();
    assert!(r.steps.is_empty());
    let d = r.damage().unwrap();
    assert_eq!((d.file_len, d.valid_bytes), (0, 0));
    assert!(d.reason.contains("empty"));
    // half a magic
    std::fs::write(&p, &mcap::MAGIC[..5]).unwrap();
    assert!(Replay::open(&p).unwrap().damage().is_some());
    // not MCAP
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    for len in [1usize, 9, 100, 5000] {
        let mut g: Vec<u8> = (0..len).map(|_| rng.random()).collect();
        g[0] = b'{';
        std::fs::write(&p, &g).unwrap();
        match Replay::open(&p) {
            Err(RecordError::NotMcap { path, .. }) => assert_eq!(path, p),
            other => panic!("garbage of {len} bytes: {other:?}"),
        }
        // magic followed by garbage: an error or a damaged file, never a panic
        let mut m = mcap::MAGIC.to_vec();
        m.extend_from_slice(&g);
        std::fs::write(&p, &m).unwrap();
        if let Ok(r) = Replay::open(&p) {
            assert!(r.damage().is_some() && r.steps.is_empty());
        }
    }
    // a missing file names itself
    let e = Replay::open(dir.path().join("missing.mcap")).unwrap_err();
    assert!(e.to_string().contains("missing.mcap"), "{e}");
    // flipped bytes in a valid file
    let good = dir.path().join("good.mcap");
    let (_, all) = record(&good, 12);
    let bytes = std::fs::read(&good).unwrap();
    let trials: usize = std::env::var("GPM_FLIP_TRIALS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(400);
    for _ in 0..trials {
        let mut b = bytes.clone();
        let k = rng.random_range(0..b.len());
        b[k] ^= 1 << rng.random_range(0..8);
        std::fs::write(&p, &b).unwrap();
        if let Ok(r) = Replay::open(&p) {
            // whatever is read is a prefix of the true steps or reported damaged/corrupt
            let n = r.steps.len();
            if r.damage().is_none() && n == all.len() {
                continue; // the flip hit an index or a summary field we do not read
            }
            assert!(n <= all.len());
        }
    }
}

fn gpm() -> PathBuf {
    PathBuf::from(env!("CARGO_BIN_EXE_gpm"))
}

/// Starts `gpm run cavity` on a run that would last minutes and waits until the file holds at
/// least `min_steps` steps.
fn start_long_run(dir: &Path, min_steps: usize) -> (std::process::Child, PathBuf) {
    let cfg = dir.join("long.json");
    std::fs::write(
        &cfg,
        r#"{"n": 12, "t_end": 100000.0, "steady": {"stop_when_steady": false}}"#,
    )
    .unwrap();
    let child = Command::new(gpm())
        // --force: the step estimate of this deliberately endless run exceeds 10⁶
        .args(["run", "cavity", "--quiet", "--force", "--config"])
        .arg(&cfg)
        .arg("--out")
        .arg(dir)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("spawn gpm");
    // the run writes run.mcap.partial and renames it to run.mcap when it ends
    let path = dir.join("run.mcap.partial");
    let start = Instant::now();
    loop {
        if let Ok(r) = Replay::open(&path) {
            if r.steps.len() >= min_steps {
                break;
            }
        }
        assert!(
            start.elapsed() < Duration::from_secs(60),
            "the run did not record {min_steps} steps in 60 s"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
    (child, path)
}

#[test]
fn killed_run_replays_up_to_the_cut() {
    let dir = tempfile::tempdir().unwrap();
    let (mut child, path) = start_long_run(dir.path(), 30);
    child.kill().unwrap(); // SIGKILL: no chance to finish the file
    child.wait().unwrap();
    let r = Replay::open(&path).unwrap();
    assert!(!dir.path().join("run.mcap").exists(), "never renamed");
    let d = r.damage().expect("a killed run leaves no footer");
    assert!(!d.data_complete);
    let n = r.steps.len();
    assert!(n >= 30, "{n} steps");
    for (k, s) in r.steps.iter().enumerate() {
        assert_eq!(s.step, k as u64 + 1);
    }
    assert_eq!(d.last_step, Some(n as u64));
    assert!(r.config.is_some());
    // the command line says it plainly and succeeds
    let out = Command::new(gpm())
        .args(["replay", "--quiet"])
        .arg(&path)
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    assert!(stdout.contains("DAMAGED"), "{stdout}");
    assert!(
        stderr.contains(&format!("the file was cut after step {n}")),
        "{stderr}"
    );
}

#[test]
fn ctrl_c_finishes_the_file() {
    if Command::new("kill").arg("-l").output().is_err() {
        eprintln!("skipped: no `kill` command to send SIGINT");
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let (child, path) = start_long_run(dir.path(), 10);
    let status = Command::new("kill")
        .args(["-INT", &child.id().to_string()])
        .status()
        .unwrap();
    assert!(status.success());
    let out = child.wait_with_output().unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(130), "{stderr}");
    assert!(
        stderr.contains("interrupted by SIGINT after step"),
        "{stderr}"
    );
    assert!(!path.exists(), "the partial file is renamed");
    let r = Replay::open(dir.path().join("run.mcap")).unwrap();
    assert!(r.scan.complete, "{:?}", r.damage());
    assert!(r.steps.len() >= 10);
    assert_eq!(
        r.scan.announced_messages,
        Some(r.steps.len() as u64 + 1),
        "statistics agree with what was read"
    );
}

/// Found by `cargo fuzz run replay`: a schema record whose name announces 4 GiB. The `mcap`
/// crate reserves the announced length before reading; the reader must check it against the
/// record first and report the corrupt record instead of asking for 4 GiB.
#[test]
fn huge_length_prefix_is_reported_not_allocated() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("fuzz_oom.mcap");
    let mut b = mcap::MAGIC.to_vec();
    b.push(0x03); // schema record
    b.extend_from_slice(&9u64.to_le_bytes()); // record length
    b.extend_from_slice(&[0x01, 0x00]); // schema id
    b.extend_from_slice(&[0xff; 4]); // name length 0xFFFFFFFF
    b.extend_from_slice(b"adv"); // 3 of the 4 GiB
    std::fs::write(&p, &b).unwrap();
    let r = Replay::open(&p).unwrap();
    assert!(r.steps.is_empty());
    let d = r.damage().expect("reported as damaged");
    assert!(
        d.reason.contains("schema name") && d.reason.contains("longer than"),
        "{}",
        d.reason
    );
    // the exact bytes the fuzzer found (two records in one, length fields all 0xFF)
    let found: [u8; 49] = [
        0x89, 0x4d, 0x43, 0x41, 0x50, 0x30, 0x0d, 0x0a, 0x03, 0x06, 0, 0, 0, 0, 0, 0, 0, 0x09,
        0xff, 0xff, 0xff, 0xff, 0xff, 0xff, 0xff, 0xff, 0xff, 0xff, 0xff, 0xff, 0xff, 0xff, 0xff,
        0xff, 0xff, 0xff, 0xff, 0, 0, 0, 0xa4, 0xbf, 0xc1, 0x61, 0x64, 0x76, 0x65, 0x63, 0x74,
    ];
    std::fs::write(&p, found).unwrap();
    if let Ok(r) = Replay::open(&p) {
        assert!(r.steps.is_empty() && r.damage().is_some());
    }
    // a header record inside a zstd chunk with a 650 MB profile length (second fuzzer finding)
    let in_chunk = std::fs::read(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/tests/data/fuzz_header_in_chunk.mcap"
    ))
    .unwrap();
    std::fs::write(&p, in_chunk).unwrap();
    if let Ok(r) = Replay::open(&p) {
        assert!(r.damage().is_some() || r.steps.is_empty());
    }
}
