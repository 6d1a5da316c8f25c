//! Warm starts (`gpm::scene::warm_start`, the configuration key `initial`): another run's final
//! fluid particles as the initial state of a run at another resolution.

use gpm::error::{Error, InputError};
use gpm::scene::cavity::{self, CavityConfig};
use gpm::scene::warm_start::{apply, FluidSnapshot};
use gpm::scene::{run_scene, RunEnd};
use std::ops::ControlFlow;

/// A quadratic field (every component a different quadratic in x and y) and a pressure.
fn quad(x: &[f64; 2]) -> ([f64; 2], f64) {
    let (a, b) = (x[0], x[1]);
    (
        [
            0.3 + a - 2.0 * b + a * a - 0.5 * a * b + 2.0 * b * b,
            -1.0 + 0.25 * a + b - 3.0 * a * a + a * b,
        ],
        2.0 - a * b + 0.5 * b * b,
    )
}

/// The fluid particles of the cavity at `n` per side, carrying [`quad`], as a snapshot.
fn quadratic_snapshot(n: usize) -> FluidSnapshot<2> {
    let sim = cavity::build(&CavityConfig::default().with(|c| c.n = n)).unwrap();
    let p = &sim.particles;
    let mut s = FluidSnapshot::default();
    for i in (0..p.len()).filter(|&i| p.role[i].is_fluid()) {
        let (u, pr) = quad(&p.x[i]);
        s.x.push(p.x[i]);
        s.u.push(u);
        s.p.push(pr);
    }
    s
}

#[test]
fn a_warm_start_carries_a_quadratic_field_exactly_to_a_finer_lattice() {
    let snap = quadratic_snapshot(12);
    assert!((snap.spacing().unwrap() - 1.0 / 12.0).abs() < 1e-12);
    // through the CSV the examples write, as a user's file would come
    let mut coarse = cavity::build(&CavityConfig::default().with(|c| c.n = 12)).unwrap();
    for (i, (u, p)) in snap.u.iter().zip(&snap.p).enumerate() {
        coarse.particles.u[i] = *u;
        coarse.particles.p[i] = *p;
    }
    let text = coarse.particles.fluid_csv();
    let read = FluidSnapshot::<2>::from_csv(&text, "coarse.csv").unwrap();
    assert_eq!(read, snap);

    let mut fine = cavity::build(&CavityConfig::default().with(|c| c.n = 30)).unwrap();
    apply(&mut fine, &read).unwrap();
    let p = &fine.particles;
    let mut worst = 0.0f64;
    for i in (0..p.len()).filter(|&i| p.role[i].is_fluid()) {
        let (u, pr) = quad(&p.x[i]);
        worst = worst
            .max((p.u[i][0] - u[0]).abs())
            .max((p.u[i][1] - u[1]).abs())
            .max((p.p[i] - pr).abs());
    }
    // exact up to round-off, the corners and walls (one-sided fits) included
    assert!(
        worst < 1e-9,
        "largest departure from the quadratic: {worst:e}"
    );
}

#[test]
fn a_warm_started_cavity_settles_to_the_cold_runs_steady_state_sooner() {
    let dir = std::env::temp_dir().join(format!("gpm_warm_start_{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let base = |n: usize| {
        CavityConfig::default().with(|c| {
            c.re = 100.0;
            c.n = n;
            c.t_end = 40.0;
        })
    };
    let go =
        |cfg: &CavityConfig| run_scene(cfg, |_| {}, |_, _| Ok(ControlFlow::Continue(()))).unwrap();
    let coarse = go(&base(12));
    assert_eq!(
        coarse.end,
        RunEnd::Scene,
        "the coarse run reaches its steady state"
    );
    let path = dir.join("particles.csv");
    std::fs::write(&path, coarse.sim.particles.fluid_csv()).unwrap();

    let cold = go(&base(20));
    let warm = go(&base(20).with(|c| c.initial = Some(path.clone())));
    for run in [&cold, &warm] {
        assert_eq!(run.end, RunEnd::Scene);
    }
    let (c, w) = (&cold.result, &warm.result);
    // (n = 12 → 20 at Re 100: 334 steps against 567 when this was written; the steadiness
    // rule's sampling and averaging windows put a floor under both)
    assert!(
        4 * w.steps < 3 * c.steps,
        "warm start: {} steps, cold: {}",
        w.steps,
        c.steps
    );
    // the same steady state: within the steadiness rule's reach of each other
    let gap =
        c.u.iter()
            .zip(&w.u)
            .chain(c.v.iter().zip(&w.v))
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max);
    assert!(
        gap < 2e-3,
        "profiles of the warm and the cold run differ by {gap:e}"
    );
    // the coarse run's profiles are further from the fine run's than that
    let coarse_gap = coarse
        .result
        .u
        .iter()
        .zip(&c.u)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f64::max);
    assert!(
        coarse_gap > 2.0 * gap,
        "coarse {coarse_gap:e}, warm {gap:e}"
    );
    std::fs::remove_dir_all(&dir).ok();
}

fn config_error(r: Result<impl Sized, impl Into<Error>>) -> String {
    match r.map_err(Into::into) {
        Err(Error::Input(e @ InputError::Config { .. })) => e.to_string(),
        Err(e) => panic!("expected a configuration error, got {e}"),
        Ok(_) => panic!("expected an error"),
    }
}

#[test]
fn bad_warm_start_files_are_named() {
    let named = |text: &str, needles: &[&str]| {
        let msg = config_error(FluidSnapshot::<2>::from_csv(text, "start.csv"));
        for n in ["initial", "start.csv"].iter().chain(needles) {
            assert!(msg.contains(n), "'{msg}' lacks '{n}'");
        }
    };
    named("", &["empty"]);
    named("x,y,u,v,p\n", &["no particles"]);
    named("x,y,z,u,v,w,p\n0,0,0,0,0,0,0\n", &["line 1", "2D"]);
    named(
        "x,y,u,v,p\n0.1,0.2,1,2,3\n0.3,0.4,1,2\n",
        &["line 3", "4 fields"],
    );
    named("x,y,u,v,p\n0.1,0.2,1,NaN,3\n", &["line 2", "v = 'NaN'"]);
    named("x,y,u,v,p\n0.1,0.2,1,x,3\n", &["line 2", "v = 'x'"]);
    let missing = std::path::Path::new("/nonexistent/gpm/start.csv");
    let msg = config_error(FluidSnapshot::<2>::read(missing));
    assert!(msg.contains("/nonexistent/gpm/start.csv"), "{msg}");

    // one particle has no spacing; a snapshot of another domain reaches no particle
    let mut sim = cavity::build(&CavityConfig::default().with(|c| c.n = 10)).unwrap();
    let one = FluidSnapshot {
        x: vec![[0.5, 0.5]],
        u: vec![[0.0, 0.0]],
        p: vec![0.0],
    };
    let msg = apply(&mut sim, &one).unwrap_err().to_string();
    assert!(msg.contains("initial") && msg.contains("two"), "{msg}");
    let mut far = quadratic_snapshot(10);
    for x in &mut far.x {
        x[0] += 5.0;
    }
    match apply(&mut sim, &far) {
        Err(Error::Input(InputError::OutsideDomain {
            particle, reason, ..
        })) => {
            assert!(reason.contains("initial"), "{reason}");
            assert!(sim.particles.role[particle].is_fluid());
        }
        other => panic!("expected the particle out of reach, got {other:?}"),
    }
    // a run given a bad file fails before its first step, naming it
    let cfg = CavityConfig::default().with(|c| {
        c.n = 10;
        c.initial = Some(missing.into());
    });
    let e = run_scene(&cfg, |_| {}, |_, _| Ok(ControlFlow::Continue(()))).err();
    let msg = e.expect("a missing file fails the run").to_string();
    assert!(msg.contains("start.csv"), "{msg}");
}

#[test]
#[cfg(feature = "cli")]
fn gpm_run_writes_the_particles_and_starts_from_them() {
    let dir = std::env::temp_dir().join(format!("gpm_warm_start_cli_{}", std::process::id()));
    let run = |args: &[&str]| {
        std::process::Command::new(env!("CARGO_BIN_EXE_gpm"))
            .args(["run", "cavity", "--quiet", "--t-end", "0.5"])
            .args(args)
            .output()
            .unwrap()
    };
    let coarse = dir.join("coarse");
    let out = run(&[
        "--n",
        "10",
        "--particles-csv",
        "--out",
        coarse.to_str().unwrap(),
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let csv = coarse.join("particles.csv");
    let snap = FluidSnapshot::<2>::read(&csv).unwrap();
    assert_eq!(snap.x.len(), 100);
    assert!(
        snap.u.iter().any(|u| u[0] != 0.0),
        "the lid moved the fluid"
    );
    let fine = dir.join("fine");
    let out = run(&[
        "--n",
        "14",
        "--initial",
        csv.to_str().unwrap(),
        "--out",
        fine.to_str().unwrap(),
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    // the start took effect: the profiles differ from a cold start's (which moved half as long)
    let cold = run(&["--n", "14", "--out", dir.join("cold").to_str().unwrap()]);
    assert!(cold.status.success());
    let profile = |o: &std::process::Output| -> Vec<f64> {
        let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
        serde_json::from_value(v["result"]["u"].clone()).unwrap()
    };
    let (w, c) = (profile(&out), profile(&cold));
    assert_eq!(w.len(), c.len());
    let gap = w
        .iter()
        .zip(&c)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f64::max);
    assert!(gap > 1e-2, "warm and cold profiles differ by {gap:e} only");
    let out = run(&[
        "--n",
        "14",
        "--initial",
        "/nonexistent/p.csv",
        "--out",
        fine.to_str().unwrap(),
    ]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("initial") && err.contains("/nonexistent/p.csv"),
        "{err}"
    );
    std::fs::remove_dir_all(&dir).ok();
}
