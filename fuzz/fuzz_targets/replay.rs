//! The damage-tolerant MCAP replay reader on arbitrary bytes: `scan`, `Replay::open`, the
//! summary and its text. Every outcome must be `Ok` (possibly with a damage report) or a typed
//! `RecordError`, never a panic, a hang or an unbounded allocation.
#![no_main]

use gpm::record::replay::{scan, Replay};
use libfuzzer_sys::fuzz_target;
use std::io::Write;
use std::path::PathBuf;

fn path() -> PathBuf {
    let dir = if std::path::Path::new("/dev/shm").is_dir() {
        PathBuf::from("/dev/shm")
    } else {
        std::env::temp_dir()
    };
    dir.join(format!("gpm-fuzz-replay-{}.mcap", std::process::id()))
}

fuzz_target!(|data: &[u8]| {
    let p = path();
    {
        let mut f = std::fs::File::create(&p).expect("temporary file");
        f.write_all(data).expect("write");
    }
    let mut messages = 0u64;
    if let Ok(s) = scan(&p, |_| {
        messages += 1;
        Ok(())
    }, |_, _| {})
    {
        let _ = s.count("/diagnostics");
        if let Some(d) = &s.damage {
            let _ = d.to_string();
        }
    }
    if let Ok(r) = Replay::open(&p) {
        let summary = r.summary();
        let _ = summary.to_string();
        let _ = serde_json::to_string(&summary);
        if let Some(d) = r.damage() {
            let _ = d.to_string();
        }
    }
});
