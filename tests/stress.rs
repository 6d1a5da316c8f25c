//! The stress example's CI-sized suite (`examples/stress.rs --quick`): every failure mode of a
//! run is turned into the expected typed outcome, and every run's MCAP file, finished whatever
//! happened, reads back exactly the steps completed before the failure.

use std::path::PathBuf;
use std::process::Command;

/// `target/<profile>/examples/stress`, built by `cargo test` next to this test's executable.
fn stress_example() -> Option<PathBuf> {
    let exe = std::env::current_exe().ok()?;
    let p = exe
        .parent()?
        .parent()?
        .join("examples")
        .join(format!("stress{}", std::env::consts::EXE_SUFFIX));
    p.is_file().then_some(p)
}

#[test]
fn quick_stress_suite_names_every_failure() {
    let Some(bin) = stress_example() else {
        eprintln!(
            "SKIPPED: examples/stress is not built next to this test (run `cargo test --release`, \
             which builds the examples, not `--test stress` alone)"
        );
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let out = Command::new(&bin)
        .args(["--quick", "--out"])
        .arg(dir.path())
        .env("RUST_BACKTRACE", "1")
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    assert!(!stderr.contains("panicked"), "{stderr}");
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let runs = v.as_array().unwrap();
    assert_eq!(runs.len(), 8);
    let get = |name: &str| {
        runs.iter()
            .find(|r| r["case"]["name"] == name)
            .unwrap_or_else(|| panic!("no run {name}"))
            .clone()
    };
    for r in runs {
        let (c, o) = (&r["case"], &r["outcome"]);
        // the outcome the suite expects, and the recording read back up to the failure
        assert_eq!(o["kind"], c["expect"], "{r}");
        assert_eq!(o["recorded_steps"], o["steps"], "{r}");
        assert_eq!(o["mcap_complete"], true, "{r}");
        if o["kind"] != "completed" {
            let msg = o["error"].as_str().unwrap();
            assert!(!msg.is_empty());
        }
    }
    // a Δt above the CFL limit is named before the first step
    for name in ["cavity_re100_cfl2_dtguard", "tg_re100_cfl2_dtguard"] {
        let o = &get(name)["outcome"];
        assert_eq!(o["steps"], 0);
        let msg = o["error"].as_str().unwrap();
        assert!(
            msg.contains("step 1") && msg.contains("exceeds the CFL limit"),
            "{msg}"
        );
    }
    // blow-ups are named with the quantity and the fastest particle
    let o = &get("cavity_re1000_cfl1")["outcome"];
    assert_eq!(o["quantity"], "max speed / u_ref");
    assert!(o["particle"].is_u64());
    // the fastest particle of the under-resolved cavity is at the lid's downstream corner
    assert!(
        o["error"].as_str().unwrap().contains("[0.96875, 0.96875]"),
        "{o}"
    );
    let o = &get("tg_re100_cfl16")["outcome"];
    assert_eq!(o["quantity"], "kinetic energy growth");
    // without the guard the same run goes to the end with its energy multiplied many times:
    // the failure the guard names is real, not an artefact of the check
    let guarded = &get("tg_re100_cfl16")["outcome"];
    let free = &get("tg_re100_cfl16_noguard")["outcome"];
    let (e0, emax) = (
        free["ke_initial"].as_f64().unwrap(),
        free["ke_max"].as_f64().unwrap(),
    );
    assert!(emax > 1e3 * e0, "{free}");
    assert!(guarded["steps"].as_u64() < free["steps"].as_u64());
    // escaping particles are named with their position outside the box
    let o = &get("cavity_lagr_cfl40")["outcome"];
    assert!(
        o["error"].as_str().unwrap().contains("crossed the wall"),
        "{o}"
    );
    // the runs that complete stay within the theory's bound and keep the divergence down
    for name in ["cavity_re100_cfl1", "tg_re100_cfl1"] {
        let o = &get(name)["outcome"];
        assert!(o["max_stability_ratio"].as_f64().unwrap() <= 1.0, "{o}");
        assert!(o["max_div_ratio"].as_f64().unwrap() < 1.0, "{o}");
        assert_eq!(o["connectivity_failures"], 0);
    }
}
