//! A loop of the user's own (`examples/own_loop.rs`, no `Simulation`) records MCAP through
//! `Recorder::record`: the file replays with the library's reader, its diagnostics are the
//! loop's reports, and its projection inputs re-run.

#[allow(dead_code)]
#[path = "../examples/own_loop.rs"]
mod own_loop;

use gpm::record::replay::Replay;
use gpm::record::rerun::rerun_file;
use gpm::record::schema::{
    BoundarySpec, ProjectionInput, TOPIC_DIAGNOSTICS, TOPIC_PARTICLES, TOPIC_PROJECTION,
};
use gpm::record::{RecordLevel, Recorder, StepContext, StepRecord};
use own_loop::{recorded_loop, LoopConfig};

#[test]
fn the_own_loop_records_replays_and_reruns() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("run.mcap");
    let cfg = LoopConfig::new(16, 7);
    let every = 3;
    let (reports, summary) = recorded_loop(&cfg, &path, every).unwrap();
    assert_eq!(reports.len(), 7);
    assert!(summary.notes.is_empty(), "{:?}", summary.notes);
    // snapshots at steps 1, 4, 7
    assert_eq!(summary.messages[TOPIC_DIAGNOSTICS], 7);
    assert_eq!(summary.messages[TOPIC_PARTICLES], 3);
    assert_eq!(summary.messages[TOPIC_PROJECTION], 3);

    let replay = Replay::open(&path).unwrap();
    assert!(replay.damage().is_none());
    let config = replay.config.as_ref().unwrap();
    assert_eq!(config.level, RecordLevel::Full);
    assert_eq!(config.particles_every, every);
    let recorded: LoopConfig = serde_json::from_value(config.config.clone()).unwrap();
    assert_eq!(recorded, cfg);

    assert_eq!(replay.steps.len(), reports.len());
    for (k, (d, r)) in replay.steps.iter().zip(&reports).enumerate() {
        assert_eq!(d.step, k as u64 + 1);
        assert_eq!(d.time, (k + 1) as f64 * cfg.dt);
        assert_eq!(d.dt, cfg.dt);
        // the loop chose Δt itself: no limit is claimed
        assert_eq!(d.dt_limit, None);
        // the recorded diagnostics are the loop's own reports, bit for bit
        assert_eq!(d.c0.to_bits(), r.c0.to_bits());
        assert_eq!(d.div_before.to_bits(), r.div_before.to_bits());
        assert_eq!(d.div_after.to_bits(), r.div_after.to_bits());
        assert_eq!(d.kinetic_energy.to_bits(), r.kinetic_energy.to_bits());
        assert_eq!(d.solve.iterations, r.solve.iters);
        // a periodic box: one floating component (pressure fixed up to a constant), allowed
        let c = &d.connectivity;
        assert_eq!(
            (c.components, c.floating, c.anchored, c.isolated),
            (1, 1, 0, 0)
        );
        assert_eq!(c.allowed_floating, 1);
        assert!(c.ok);
        assert!(
            d.stability_ratio <= 1.0,
            "Theorem 4.5 ratio {}",
            d.stability_ratio
        );
        // no driver: no neighbour or advection time, no shifting
        assert_eq!(d.timings.neighbors, 0.0);
        assert_eq!(d.timings.advect, 0.0);
        assert_eq!(d.max_shift, 0.0);
    }
    // what `gpm replay` prints
    let s = replay.summary();
    assert!(s.complete);
    assert_eq!(s.steps, 7);
    assert_eq!(s.step_range, Some((1, 7)));
    let c0_max = reports.iter().map(|r| r.c0).fold(f64::MIN, f64::max);
    let c0_min = reports.iter().map(|r| r.c0).fold(f64::MAX, f64::min);
    assert_eq!((s.c0.min, s.c0.max), (c0_min, c0_max));
    assert_eq!((s.dt.min, s.dt.max), (cfg.dt, cfg.dt));

    // the projection inputs describe the periodic box and re-run through the current build
    let scan = gpm::record::replay::scan(
        &path,
        |m| {
            if m.topic == TOPIC_PROJECTION {
                let input: ProjectionInput = m.decode()?;
                assert!(matches!(input.boundary, BoundarySpec::Periodic { .. }));
                assert_eq!(input.particles, 16 * 16);
                assert_eq!(input.dt, cfg.dt);
            }
            Ok(())
        },
        |_, _| {},
    )
    .unwrap();
    assert_eq!(scan.count(TOPIC_PROJECTION), 3);
    let rerun = rerun_file(&path, |_, _| {}).unwrap();
    assert_eq!(rerun.steps.len(), 3);
    let (du, dp, dphi) = rerun.max_relative_differences();
    // a fresh neighbour list may order the sparse pattern differently from the loop's list
    // (kept with a skin): round-off of the direct solve, far below any physical difference
    assert!(du < 1e-9 && dp < 1e-9 && dphi < 1e-9, "{:?}", rerun.steps);
}

#[test]
fn a_snapshot_with_ragged_particle_arrays_is_an_error_not_a_panic() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("ragged.mcap");
    let mut rec = Recorder::create(&path, RecordLevel::Full, 1, &()).unwrap();
    let report = gpm::projection::StepReport::default();
    let x = [[0.0, 0.0], [1.0, 0.0]];
    let u = [[0.0, 0.0]];
    let p = [0.0, 0.0];
    let role = [gpm::particles::Role::Fluid; 2];
    let err = rec
        .record(&StepRecord {
            particles: Some(gpm::record::ParticleView {
                x: &x,
                u: &u,
                p: &p,
                role: &role,
            }),
            ..StepRecord::new(StepContext::new(1, 0.1, 1), &report)
        })
        .unwrap_err();
    assert!(
        err.to_string().contains("u has 1 entries for 2 positions"),
        "{err}"
    );
    // nothing of the bad step was written; the file still finishes
    assert_eq!(rec.steps(), 0);
    let s = rec.finish().unwrap();
    assert!(!s.messages.contains_key(TOPIC_DIAGNOSTICS));
}
