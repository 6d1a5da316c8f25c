//! Bad input, one test per kind, at the library level and through the command-line tool and the
//! examples: coincident particles; NaN or Inf in positions, velocities, pressures; particles
//! outside the domain or escaping through a wall; `h` at or below the minimum spacing;
//! non-positive volumes; a disconnected cluster; solver non-convergence; invalid
//! configurations; unreadable, foreign or truncated MCAP files.
//!
//! Every case asserts the error's variant and that its message names the particle, parameter or
//! file. Nothing may panic: every library call below returns (a panic fails the test), and the
//! spawned programs are checked for a clean one-line error, a non-zero status and no panic or
//! backtrace (with `RUST_BACKTRACE=1` set, so that one would show). A run that fails after it
//! started recording finishes its MCAP file, which then reads back every step before the failure.

mod common;

use gpm::boundary::{Boundary, NoBoundary, PeriodicBox, Walls};
use gpm::error::{Error, InputError, SolveError, StabilityError};
use gpm::flow::{
    DtLimit, FlowParams, Integrator, Motion, Simulation, StabilityGuard, TimeStepLimits, VolumeRule,
};
use gpm::geometry::lattice;
use gpm::kernel::Weight;
use gpm::neighbors::{closest_pair, NeighborConfig, NeighborList, Periodicity};
use gpm::particles::{Particles, Role};
use gpm::poisson::{SolveParams, SolverKind};
use gpm::projection::{ProjectionParams, ProjectionStep};
use gpm::record::replay::{scan, Replay};
use gpm::record::rerun::rerun_file;
use gpm::record::{RecordError, RecordLevel, Recorder};
use gpm::scene::cavity::{self, CavityConfig};
use gpm::scene::taylor_green::{self, TaylorGreenConfig};
use gpm::scene::{config_from_json, config_from_value};
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

// ---------------------------------------------------------------------------------------------
// helpers

/// A cell-centred `n × n` lattice of fluid particles at rest in the unit square.
fn square(n: usize) -> Particles<2> {
    let dx = 1.0 / n as f64;
    let mut p = Particles::<2>::new();
    for x in lattice([0.0, 0.0], [1.0, 1.0], dx) {
        p.push(x, [0.0, 0.0], 0.0, dx * dx, Role::Fluid);
    }
    p
}

fn flow_params(dx: f64, motion: Motion) -> FlowParams<2> {
    FlowParams {
        projection: ProjectionParams::new(0.01),
        limits: TimeStepLimits::default(),
        motion,
        integrator: Integrator::Ab2,
        convection: Default::default(),
        shifting: None,
        volumes: VolumeRule::NumberDensity,
        pair_weights: Default::default(),
        dx,
    }
}

/// A lid-driven cavity simulation on `p` (h = 3 dx).
fn cavity_sim(p: Particles<2>, n: usize, motion: Motion) -> Result<Simulation<2, Walls<2>>, Error> {
    let dx = 1.0 / n as f64;
    Simulation::new(
        p,
        Walls::cavity(1.0, 1.0),
        NeighborConfig::new_relative(Weight::WendlandC2, dx, 3.0, 0.2),
        flow_params(dx, motion),
    )
}

fn input_err<T>(r: Result<T, Error>) -> InputError {
    match r {
        Err(Error::Input(e)) => e,
        Err(e) => panic!("expected an input error, got {e:?}"),
        Ok(_) => panic!("expected an input error, got success"),
    }
}

fn assert_names(msg: &str, needles: &[&str]) {
    for n in needles {
        assert!(msg.contains(n), "message {msg:?} does not name {n:?}");
    }
}

// ---------------------------------------------------------------------------------------------
// coincident particles

#[test]
fn coincident_particles_are_named() {
    // in the neighbour search (2D and 3D)
    let mut x = lattice([0.0, 0.0], [1.0, 1.0], 0.1);
    x[37] = x[12];
    let e = NeighborList::build(NeighborConfig::new(Weight::WendlandC2, 0.3, 0.0), &x).unwrap_err();
    match &e {
        InputError::Coincident { i, j, distance } => {
            assert_eq!((*i.min(j), *i.max(j)), (12, 37));
            assert_eq!(*distance, 0.0);
        }
        other => panic!("{other:?}"),
    }
    assert_names(&e.to_string(), &["12", "37", "coincide"]);
    let mut x3 = lattice([0.0; 3], [1.0; 3], 0.25);
    x3[5] = x3[60];
    match NeighborList::build(NeighborConfig::new(Weight::CubicSpline, 0.6, 0.1), &x3) {
        Err(InputError::Coincident { i, j, .. }) => assert_eq!((i.min(j), i.max(j)), (5, 60)),
        other => panic!("{other:?}"),
    }
    // in a simulation's set-up
    let mut p = square(10);
    p.x[3] = p.x[44];
    match input_err(cavity_sim(p, 10, Motion::Eulerian)) {
        InputError::Coincident { i, j, .. } => assert_eq!((i.min(j), i.max(j)), (3, 44)),
        other => panic!("{other:?}"),
    }
    // moved onto each other by the caller between two steps
    let mut sim = cavity_sim(square(10), 10, Motion::Eulerian).unwrap();
    sim.advance().unwrap();
    sim.particles.x[20] = sim.particles.x[21];
    sim.nl.update(&sim.particles.x).unwrap_err();
}

// ---------------------------------------------------------------------------------------------
// NaN and Inf

#[test]
fn non_finite_positions_velocities_and_pressures_are_named() {
    for bad in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY] {
        // validation of the particle state
        let mut p = square(8);
        p.x[17][1] = bad;
        assert_eq!(
            p.validate(),
            Err(InputError::NonFinite {
                field: "position",
                particle: 17
            })
        );
        let msg = p.validate().unwrap_err().to_string();
        assert_names(&msg, &["particle 17", "position", "not finite"]);
        // the neighbour search
        assert_eq!(
            NeighborList::build(NeighborConfig::new(Weight::WendlandC2, 0.3, 0.0), &p.x)
                .unwrap_err(),
            InputError::NonFinite {
                field: "position",
                particle: 17
            }
        );
        // a simulation's set-up
        assert_eq!(
            input_err(cavity_sim(p, 8, Motion::Eulerian)),
            InputError::NonFinite {
                field: "position",
                particle: 17
            }
        );
        let mut p = square(8);
        p.u[5][0] = bad;
        assert_eq!(
            input_err(cavity_sim(p, 8, Motion::Eulerian)),
            InputError::NonFinite {
                field: "velocity",
                particle: 5
            }
        );
        // set by the caller in the middle of a run: named before the step, nothing changed
        for (field, k) in [("position", 0), ("velocity", 1), ("pressure", 2)] {
            let mut sim = cavity_sim(square(10), 10, Motion::Lagrangian).unwrap();
            sim.advance().unwrap();
            match k {
                0 => sim.particles.x[33][0] = bad,
                1 => sim.particles.u[33][1] = bad,
                _ => sim.particles.p[33] = bad,
            }
            let (t, steps) = (sim.time, sim.steps);
            assert_eq!(
                input_err(sim.advance()),
                InputError::NonFinite {
                    field,
                    particle: 33
                }
            );
            assert_eq!((sim.time, sim.steps), (t, steps));
        }
    }
}

#[test]
fn projection_step_on_non_finite_input_fails_without_panicking() {
    // the bare projection step validates the particles: a NaN comes back as an input error
    // naming the particle, never as a panic, a solve failure or a "successful" step
    let n = 10;
    let dx = 1.0 / n as f64;
    let walls = Walls::<2>::cavity(1.0, 1.0);
    let config = NeighborConfig::new_relative(Weight::WendlandC2, dx, 3.0, 0.0);
    for what in ["velocity", "pressure", "volume"] {
        for solver in [SolverKind::Cholesky, SolverKind::Cg] {
            let mut p = square(n);
            walls.make_ghosts(&mut p, config.h);
            let nl = NeighborList::build(config, &p.x).unwrap();
            walls.place_ghosts(&mut p);
            match what {
                "velocity" => p.u[42] = [f64::NAN, 0.0],
                "pressure" => p.p[42] = f64::NAN,
                _ => p.vol[42] = f64::NAN,
            }
            let mut params = ProjectionParams::<2>::new(0.01);
            params.solve.solver = solver;
            params.solve.max_iters = 500;
            let r = ProjectionStep::new().step(&mut p, &nl, &walls, &params, 0.005, None);
            match r {
                Err(Error::Input(InputError::NonFinite { particle: 42, .. }))
                | Err(Error::Input(InputError::BadVolume { particle: 42, .. })) => {}
                other => panic!("{what} NaN with {solver}: expected an input error, got {other:?}"),
            }
        }
    }
}

// ---------------------------------------------------------------------------------------------
// outside the domain, escaping

/// Band values of the increment (`ProjectionStep::set_band_increment`) that do not cover the
/// particles, or are not finite on a band particle, are named before any solve.
#[test]
fn bad_band_values_of_the_increment_are_named() {
    let dx = 0.1;
    let mut p = Particles::<2>::new();
    for x in lattice([0.0, 0.0], [1.0, 1.0], dx) {
        let role = if x[1] > 0.85 {
            Role::Dirichlet
        } else {
            Role::Fluid
        };
        p.push(x, [0.0, 0.0], 0.0, dx * dx, role);
    }
    let config = NeighborConfig::new_relative(Weight::WendlandC2, dx, 3.0, 0.0);
    let nl = gpm::setup::prepare(
        &mut p,
        &NoBoundary,
        config,
        gpm::setup::VolumeRule::NumberDensity,
    )
    .unwrap();
    let params = ProjectionParams::<2>::new(0.0);
    let band = (0..p.len())
        .find(|&i| p.role[i] == Role::Dirichlet)
        .unwrap();
    let u_star = p.u.clone();
    let mut step = ProjectionStep::new();
    step.set_band_increment(vec![0.0; 3]);
    let e = input_err(step.project(&mut p, &nl, &NoBoundary, &params, 0.01, &u_star));
    assert!(
        matches!(
            e,
            InputError::LengthMismatch {
                field: "band increment",
                len: 3,
                ..
            }
        ),
        "{e}"
    );
    let mut g = vec![0.0; p.len()];
    g[band] = f64::NAN;
    step.set_band_increment(g);
    let e = input_err(step.project(&mut p, &nl, &NoBoundary, &params, 0.01, &u_star));
    assert_eq!(
        e,
        InputError::NonFinite {
            field: "band increment",
            particle: band
        }
    );
    assert_names(
        &e.to_string(),
        &["band increment", &format!("particle {band}")],
    );
}

#[test]
fn particles_outside_the_domain_are_named() {
    for (pos, wall) in [
        ([1.2, 0.5], "x[0] = 1"),
        ([0.5, -0.01], "x[1] = 0"),
        ([0.5, 1.0], "x[1] = 1"), // on the wall: its mirror image would coincide with it
    ] {
        let mut p = square(10);
        p.push(pos, [0.0, 0.0], 0.0, 0.01, Role::Fluid);
        let e = input_err(cavity_sim(p, 10, Motion::Eulerian));
        match &e {
            InputError::OutsideDomain {
                particle, position, ..
            } => {
                assert_eq!(*particle, 100);
                assert_eq!(position, &pos.to_vec());
            }
            other => panic!("{other:?}"),
        }
        assert_names(
            &e.to_string(),
            &["particle 100", wall, "outside the domain"],
        );
    }
}

#[test]
fn particles_escaping_through_a_wall_are_named() {
    // a Lagrangian cavity with an absurd Δt: the lid flings particles through the walls in the
    // first step; the error names the particle, its position outside and the wall
    let n = 12;
    let mut p = square(n);
    for (x, u) in p.x.iter().zip(p.u.iter_mut()) {
        *u = [2.0 * (x[1] - 0.5), 0.0]; // shear: the top row moves right
    }
    let dx = 1.0 / n as f64;
    let mut params = flow_params(dx, Motion::Lagrangian);
    params.limits.dt_fixed = Some(5.0);
    let mut sim = Simulation::new(
        p,
        Walls::cavity(1.0, 1.0),
        NeighborConfig::new_relative(Weight::WendlandC2, dx, 3.0, 0.2),
        params,
    )
    .unwrap();
    let e = input_err(sim.advance());
    match &e {
        InputError::OutsideDomain {
            particle, position, ..
        } => {
            assert!(sim.particles.role[*particle].is_fluid());
            assert!(
                position.iter().any(|&c| !(0.0..=1.0).contains(&c)),
                "{position:?}"
            );
        }
        other => panic!("{other:?}"),
    }
    assert_names(&e.to_string(), &["outside the domain", "crossed the wall"]);
    // the same Δt with the time-step guard on is named before anything moves
    let mut p = square(n);
    for (x, u) in p.x.iter().zip(p.u.iter_mut()) {
        *u = [2.0 * (x[1] - 0.5), 0.0];
    }
    let mut params = flow_params(dx, Motion::Lagrangian);
    params.limits.dt_fixed = Some(5.0);
    params.limits.guard.dt_over_limit = Some(1.0);
    let mut sim = Simulation::new(
        p,
        Walls::cavity(1.0, 1.0),
        NeighborConfig::new_relative(Weight::WendlandC2, dx, 3.0, 0.2),
        params,
    )
    .unwrap();
    let x0 = sim.particles.x.clone();
    match sim.advance() {
        Err(Error::Stability(e @ StabilityError::TimeStepTooLarge { .. })) => {
            let StabilityError::TimeStepTooLarge {
                step,
                dt,
                limit,
                bound,
                factor,
            } = &e
            else {
                unreachable!()
            };
            assert_eq!((*step, *dt, *limit, *factor), (1, 5.0, DtLimit::Cfl, 1.0));
            // the CFL limit cfl · h / max(|u|, u_ref): the fastest particle, |u| = 1 − dx,
            // is slower than u_ref = 1
            let h = 3.0 * dx;
            assert!((bound - 0.2 * h / 1.0).abs() < 1e-12 * bound, "{bound}");
            assert_names(&e.to_string(), &["step 1", "CFL limit", "limits.dt_fixed"]);
        }
        other => panic!("{other:?}"),
    }
    assert_eq!(sim.particles.x, x0, "nothing may move before the error");
}

// ---------------------------------------------------------------------------------------------
// h at or below the minimum spacing

#[test]
fn radius_at_or_below_the_spacing_is_named() {
    // dx = 1/16: positions and differences are exact, so "h = dx" means exactly at the spacing
    let n = 16;
    let dx = 1.0 / n as f64;
    for h in [dx, 0.9 * dx, 0.5 * dx] {
        let e = input_err(Simulation::new(
            square(n),
            Walls::cavity(1.0, 1.0),
            NeighborConfig::new(Weight::WendlandC2, h, 0.0),
            flow_params(dx, Motion::Eulerian),
        ));
        match &e {
            InputError::RadiusTooSmall {
                h: eh,
                min_spacing,
                i,
                j,
            } => {
                assert_eq!(*eh, h);
                assert_eq!(*min_spacing, dx);
                let p = square(n);
                let d =
                    ((p.x[*i][0] - p.x[*j][0]).powi(2) + (p.x[*i][1] - p.x[*j][1]).powi(2)).sqrt();
                assert_eq!(d, dx);
            }
            other => panic!("h = {h}: {other:?}"),
        }
        assert_names(
            &e.to_string(),
            &[
                &format!("h = {h}"),
                &format!("spacing {dx}"),
                "no particle has a neighbour",
            ],
        );
    }
    // just above the spacing the set-up is accepted
    Simulation::new(
        square(n),
        Walls::cavity(1.0, 1.0),
        NeighborConfig::new(Weight::WendlandC2, dx * (1.0 + 1e-12), 0.0),
        flow_params(dx, Motion::Eulerian),
    )
    .unwrap();
    // periodic: the closest pair may be an image pair across the box
    let x = vec![[0.02, 0.5], [0.5, 0.5], [0.97, 0.5]];
    let per = Periodicity::all([0.0, 0.0], [1.0, 1.0]);
    let (r, i, j) = closest_pair(&x, &per).unwrap();
    assert!((r - 0.05).abs() < 1e-12 && (i, j) == (0, 2), "{r} {i} {j}");
    let (r, i, j) = closest_pair(&x, &Periodicity::none()).unwrap();
    assert!((r - 0.47).abs() < 1e-12 && (i, j) == (1, 2), "{r} {i} {j}");
    // the bare projection step on such a list names h and the spacing too
    let p0 = square(n);
    let nl = NeighborList::build(NeighborConfig::new(Weight::WendlandC2, dx, 0.0), &p0.x).unwrap();
    assert_eq!(nl.n_pairs(), 0);
    let mut p = p0.clone();
    match ProjectionStep::new().step(
        &mut p,
        &nl,
        &NoBoundary,
        &ProjectionParams::new(0.01),
        0.01,
        None,
    ) {
        Err(Error::Input(InputError::RadiusTooSmall { h, min_spacing, .. })) => {
            assert_eq!((h, min_spacing), (dx, dx));
        }
        other => panic!("{other:?}"),
    }
    // a scene configuration cannot ask for it
    for hdx in [1.0, 0.5, 0.0, -2.0, f64::NAN] {
        let cfg = CavityConfig::default().with(|c| c.h_over_dx = hdx);
        match cfg.validate() {
            Err(InputError::Parameter { name, .. }) => assert_eq!(name, "h_over_dx"),
            other => panic!("{other:?}"),
        }
    }
}

// ---------------------------------------------------------------------------------------------
// non-positive volumes

#[test]
fn non_positive_volumes_are_named() {
    for bad in [0.0, -1e-3, f64::NAN, f64::INFINITY] {
        let mut p = square(8);
        p.vol[9] = bad;
        let e = p.validate().unwrap_err();
        match &e {
            InputError::BadVolume { particle, value } => {
                assert_eq!(*particle, 9);
                assert!(value.to_bits() == bad.to_bits());
            }
            other => panic!("{other:?}"),
        }
        assert_names(&e.to_string(), &["particle 9", "volume"]);
        // fixed volumes in a simulation: refused at set-up
        let dx = 1.0 / 8.0;
        let mut params = flow_params(dx, Motion::Eulerian);
        params.volumes = VolumeRule::Fixed;
        let r = Simulation::new(
            p,
            Walls::cavity(1.0, 1.0),
            NeighborConfig::new_relative(Weight::WendlandC2, dx, 3.0, 0.0),
            params,
        );
        assert!(matches!(
            input_err(r),
            InputError::BadVolume { particle: 9, .. }
        ));
        // set by the caller between two steps
        let mut params = flow_params(dx, Motion::Eulerian);
        params.volumes = VolumeRule::Fixed;
        let mut sim = Simulation::new(
            square(8),
            Walls::cavity(1.0, 1.0),
            NeighborConfig::new_relative(Weight::WendlandC2, dx, 3.0, 0.0),
            params,
        )
        .unwrap();
        sim.advance().unwrap();
        sim.particles.vol[9] = bad;
        assert!(matches!(
            input_err(sim.advance()),
            InputError::BadVolume { particle: 9, .. }
        ));
    }
}

// ---------------------------------------------------------------------------------------------
// a disconnected cluster

#[test]
fn a_disconnected_cluster_is_named_with_exactly_its_particles() {
    // fluid in the left 40 % of the cavity, plus a 3 × 3 cluster more than h away from it and
    // from the walls: two floating components where the closed box allows one
    let n = 20;
    let dx = 1.0 / n as f64;
    let mut p = Particles::<2>::new();
    for x in lattice([0.0, 0.0], [0.4, 1.0], dx) {
        p.push(x, [0.0, 0.0], 0.0, dx * dx, Role::Fluid);
    }
    let first = p.len();
    for x in lattice([0.7, 0.45], [0.85, 0.6], dx) {
        p.push(x, [0.0, 0.0], 0.0, dx * dx, Role::Fluid);
    }
    let cluster: Vec<usize> = (first..p.len()).collect();
    assert_eq!(cluster.len(), 9);
    let mut sim = cavity_sim(p, n, Motion::Eulerian).unwrap();
    let before = sim.particles.u.clone();
    match sim.advance() {
        Err(Error::Connectivity(c)) => {
            assert_eq!(c.offending, cluster);
            assert_eq!((c.components, c.isolated), (1, 0));
            assert_names(
                &c.to_string(),
                &["h-connectivity fails", "9 particle(s)", &format!("{first}")],
            );
        }
        other => panic!("{other:?}"),
    }
    assert_eq!(
        sim.particles.u, before,
        "a failed step changed the velocities"
    );
}

// ---------------------------------------------------------------------------------------------
// solver non-convergence

#[test]
fn solver_non_convergence_carries_its_iterations_and_residual() {
    let cfg = CavityConfig::default().with(|c| {
        c.n = 16;
        c.solve = SolveParams {
            solver: SolverKind::Cg,
            max_iters: 3,
            rel_tol: 1e-14,
            ..SolveParams::default()
        };
    });
    let mut sim = cavity::build(&cfg).unwrap();
    match sim.advance() {
        Err(Error::Solve(e @ SolveError::NoConvergence { .. })) => {
            let SolveError::NoConvergence {
                iters,
                rel_residual,
                abs_residual,
            } = e
            else {
                unreachable!()
            };
            assert_eq!(iters, 3);
            assert!(rel_residual > 1e-14 && abs_residual > 0.0);
            assert_names(
                &e.to_string(),
                &["did not converge in 3 iterations", "solve.max_iters"],
            );
        }
        other => panic!("{other:?}"),
    }
    // zero iterations is refused by the configuration
    let cfg = CavityConfig::default().with(|c| {
        c.solve = SolveParams {
            max_iters: 0,
            ..SolveParams::default()
        };
    });
    assert!(matches!(
        cfg.validate(),
        Err(InputError::Parameter { name, .. }) if name == "solve.max_iters"
    ));
}

// ---------------------------------------------------------------------------------------------
// invalid configuration

fn config_key<T: serde::de::DeserializeOwned + serde::Serialize + Default + std::fmt::Debug>(
    json: &str,
) -> (String, String) {
    match config_from_json::<T>(json) {
        Err(InputError::Config { key, reason }) => (key, reason),
        other => panic!("{json}: expected a configuration error, got {other:?}"),
    }
}

fn param_name(r: Result<(), InputError>) -> String {
    match r {
        Err(InputError::Parameter { name, .. }) => name.into_owned(),
        other => panic!("expected a parameter error, got {other:?}"),
    }
}

#[test]
fn invalid_configurations_name_the_key() {
    // unknown keys, at the top and nested
    let (key, reason) = config_key::<CavityConfig>(r#"{"reynolds": 100}"#);
    assert_eq!(key, "reynolds");
    assert_names(&reason, &["unknown field `reynolds`"]);
    let (key, reason) = config_key::<CavityConfig>(r#"{"limits": {"cfll": 0.1}}"#);
    assert_eq!(key, "limits.cfll");
    assert_names(&reason, &["unknown field `cfll`"]);
    let (key, _) = config_key::<TaylorGreenConfig>(r#"{"solve": {"solver": "magic"}}"#);
    assert_eq!(key, "solve.solver");
    // negative or fractional resolution, wrong types, not JSON, trailing garbage
    for (json, want) in [
        (r#"{"n": -5}"#, "n"),
        (r#"{"n": 12.5}"#, "n"),
        (r#"{"re": "high"}"#, "re"),
        (r#"{"limits": {"dt_fixed": "x"}}"#, "limits.dt_fixed"),
        (r#"{"re": NaN}"#, "re"),
        (r#"{"re": 1e999}"#, "re"),
    ] {
        assert_eq!(config_key::<CavityConfig>(json).0, want, "{json}");
    }
    for json in ["", "[1, 2]", r#"{"re": 100} x"#, "{"] {
        let (key, _) = config_key::<CavityConfig>(json);
        assert_eq!(key, "(top level)", "{json:?}");
    }
    // values of the right type but out of range: named by validate
    let cav = |f: &dyn Fn(&mut CavityConfig)| {
        let mut c = CavityConfig::default();
        f(&mut c);
        param_name(c.validate())
    };
    assert_eq!(cav(&|c| c.re = -100.0), "re");
    assert_eq!(cav(&|c| c.re = 0.0), "re");
    assert_eq!(cav(&|c| c.re = f64::NAN), "re");
    assert_eq!(cav(&|c| c.n = 0), "n");
    assert_eq!(cav(&|c| c.n = 3), "n");
    assert_eq!(cav(&|c| c.t_end = f64::NAN), "t_end");
    assert_eq!(cav(&|c| c.scene.lid = f64::INFINITY), "lid");
    assert_eq!(cav(&|c| c.skin_over_h = -0.1), "skin_over_h");
    assert_eq!(cav(&|c| c.viscous_theta = f64::NAN), "viscous_theta");
    assert_eq!(cav(&|c| c.limits.cfl = f64::NAN), "limits.cfl");
    assert_eq!(cav(&|c| c.limits.visc = 0.0), "limits.visc");
    assert_eq!(cav(&|c| c.limits.u_ref = f64::NAN), "limits.u_ref");
    assert_eq!(cav(&|c| c.limits.dt_max = Some(-1.0)), "limits.dt_max");
    assert_eq!(
        cav(&|c| c.limits.dt_fixed = Some(f64::NAN)),
        "limits.dt_fixed"
    );
    assert_eq!(
        cav(&|c| c.limits.guard.energy_growth = Some(f64::NAN)),
        "limits.guard.energy_growth"
    );
    assert_eq!(
        cav(&|c| c.limits.guard.dt_over_limit = Some(0.0)),
        "limits.guard.dt_over_limit"
    );
    assert_eq!(
        cav(&|c| c.limits.guard.energy_floor = -1.0),
        "limits.guard.energy_floor"
    );
    assert_eq!(cav(&|c| c.solve.rel_tol = f64::NAN), "solve.rel_tol");
    assert_eq!(cav(&|c| c.solve.abs_tol = -1.0), "solve.abs_tol");
    assert_eq!(cav(&|c| c.scene.steady.tol = f64::NAN), "steady.tol");
    assert_eq!(
        cav(&|c| c.scene.steady.distance_tol = Some(0.0)),
        "steady.distance_tol"
    );
    assert_eq!(cav(&|c| c.scene.lid_ramp = 0.7), "lid_ramp");
    assert_eq!(cav(&|c| c.scene.lid_ramp = f64::NAN), "lid_ramp");
    assert_eq!(cav(&|c| c.scene.lid_ramp = -0.1), "lid_ramp");
    assert_eq!(cav(&|c| c.scene.source_band = 1.5), "source_band");
    assert_eq!(cav(&|c| c.scene.source_band = f64::NAN), "source_band");
    assert_eq!(cav(&|c| c.scene.source_band = -0.25), "source_band");
    assert_eq!(
        cav(&|c| c.scene.steady.average_window = f64::NAN),
        "steady.average_window"
    );
    assert_eq!(
        cav(&|c| c.shifting.as_mut().unwrap().max_fraction = f64::NAN),
        "shifting.max_fraction"
    );
    assert_eq!(cav(&|c| c.weight = Weight::Poly { p: 1, m: 0 }), "weight");
    let tg = |f: &dyn Fn(&mut TaylorGreenConfig)| {
        let mut c = TaylorGreenConfig::default();
        f(&mut c);
        param_name(c.validate())
    };
    assert_eq!(tg(&|c| c.re = -1.0), "re");
    assert_eq!(tg(&|c| c.n = 7), "n");
    assert_eq!(tg(&|c| c.scene.amplitude = f64::NAN), "amplitude");
    assert_eq!(tg(&|c| c.h_over_dx = f64::NAN), "h_over_dx");
    assert_eq!(tg(&|c| c.skin_over_h = f64::NAN), "skin_over_h");
    assert_eq!(tg(&|c| c.limits.force = -1.0), "limits.force");
    assert_eq!(tg(&|c| c.solve.max_iters = 0), "solve.max_iters");
    // the scenes' build refuses them too (nothing is allocated for n = 0)
    let e = input_err(cavity::build(&CavityConfig::default().with(|c| c.n = 0)));
    assert_names(&e.to_string(), &["parameter 'n' = 0"]);
    let e = input_err(taylor_green::build(
        &TaylorGreenConfig::default().with(|c| c.re = f64::NAN),
    ));
    assert_names(&e.to_string(), &["parameter 're' = NaN"]);
    // a recorded /config message's config member reads back through the same path
    let v = serde_json::json!({ "re": 400.0, "n": 16, "limits": { "guard": { "speed_over_ref": 3.0 } } });
    let c: CavityConfig = config_from_value(v).unwrap();
    assert_eq!(c.limits.guard.speed_over_ref, Some(3.0));
    // lower-level parameters
    let mut p = ProjectionParams::<2>::new(0.01);
    p.rho = f64::NAN;
    assert_eq!(param_name(p.validate()), "rho");
    let mut p = ProjectionParams::<2>::new(-0.01);
    assert_eq!(param_name(p.validate()), "nu");
    p.nu = 0.01;
    p.gravity = [0.0, f64::INFINITY];
    assert_eq!(param_name(p.validate()), "gravity");
    assert_eq!(
        param_name(NeighborConfig::<2>::new(Weight::WendlandC2, f64::NAN, 0.0).validate()),
        "h"
    );
    assert_eq!(
        param_name(NeighborConfig::<2>::new(Weight::WendlandC2, 0.1, -1.0).validate()),
        "skin"
    );
    let mut fp = flow_params(0.1, Motion::Eulerian);
    fp.dx = f64::NAN;
    match Simulation::new(
        square(10),
        Walls::cavity(1.0, 1.0),
        NeighborConfig::new(Weight::WendlandC2, 0.3, 0.0),
        fp,
    ) {
        Err(Error::Input(InputError::Parameter { name, .. })) if name == "dx" => {}
        other => panic!("{:?}", other.err()),
    }
    // a periodic box too short for the radius
    let per = PeriodicBox {
        periodic: Periodicity::all([0.0, 0.0], [1.0, 1.0]),
    };
    match Simulation::new(
        square(10),
        per,
        NeighborConfig::new(Weight::WendlandC2, 0.6, 0.0),
        flow_params(0.1, Motion::Eulerian),
    ) {
        Err(Error::Input(e @ InputError::PeriodTooShort { .. })) => {
            assert_names(&e.to_string(), &["periodic axis 0", "period 1"])
        }
        other => panic!("{:?}", other.err()),
    }
}

// ---------------------------------------------------------------------------------------------
// the stability guard

#[test]
fn a_blow_up_is_named_by_the_guard_with_step_quantity_and_particle() {
    // speed bound below what the lid drives: the step that first exceeds it is named, with the
    // fastest particle, and the simulation's clock says that step was taken
    let mut cfg = CavityConfig::default().with(|c| c.n = 12);
    cfg.limits.guard = StabilityGuard {
        speed_over_ref: Some(0.3),
        ..Default::default()
    };
    let mut sim = cavity::build(&cfg).unwrap();
    let mut last_speed = 0.0;
    let err = loop {
        match sim.advance() {
            Ok(r) => {
                assert!(r.projection.max_speed <= 0.3);
                last_speed = r.projection.max_speed;
            }
            Err(e) => break e,
        }
    };
    match &err {
        Error::Stability(StabilityError::BlowUp {
            step,
            quantity,
            value,
            bound,
            particle,
            speed,
            ..
        }) => {
            assert_eq!(*step, sim.steps);
            assert_eq!(*quantity, "max speed / u_ref");
            assert!(*value > 0.3 && *bound == 0.3 && *value > last_speed);
            let u = sim.particles.u[*particle];
            assert_eq!(*speed, (u[0] * u[0] + u[1] * u[1]).sqrt());
            assert_eq!(*speed, *value); // u_ref = 1
        }
        other => panic!("{other:?}"),
    }
    assert_names(
        &err.to_string(),
        &["max speed / u_ref", "fastest particle", "step"],
    );
    // Theorem 4.5 ratio: the theory bounds it by 1; a bound below the measured ratio trips
    let mut cfg = CavityConfig::default().with(|c| c.n = 12);
    cfg.limits.guard.stability_ratio = Some(1e-3);
    match cavity::build(&cfg).unwrap().advance() {
        Err(Error::Stability(StabilityError::BlowUp {
            step: 1,
            quantity,
            value,
            ..
        })) => {
            assert_eq!(quantity, "Theorem 4.5 ratio");
            assert!(value > 1e-3 && value <= 1.0);
        }
        other => panic!("{other:?}"),
    }
    // energy growth: from the second step on, above the floor
    let mut cfg = TaylorGreenConfig::default().with(|c| c.n = 16);
    cfg.limits.guard.energy_growth = Some(0.5);
    match taylor_green::build(&cfg).unwrap().advance() {
        Ok(_) => {}
        other => panic!("the first step has no previous energy: {other:?}"),
    }
    let mut sim = taylor_green::build(&cfg).unwrap();
    sim.advance().unwrap();
    // the vortex decays by e^{−16π²Δt/Re} ≈ 0.94 per step at Re 100: above the bound 0.5
    match sim.advance() {
        Err(Error::Stability(StabilityError::BlowUp {
            step: 2,
            quantity,
            value,
            ..
        })) => {
            assert_eq!(quantity, "kinetic energy growth");
            assert!(value > 0.9 && value < 1.0, "{value}");
        }
        other => panic!("{other:?}"),
    }
    // the default limits' guard (speed ≤ 3 u_ref, energy growth ≤ 10 per step) lets a healthy
    // run go on; StabilityGuard::default() has every check off
    assert_eq!(
        CavityConfig::default().limits.guard,
        StabilityGuard::blow_up()
    );
    assert_eq!(StabilityGuard::default().speed_over_ref, None);
    let mut sim = cavity::build(&CavityConfig::default().with(|c| c.n = 12)).unwrap();
    for _ in 0..20 {
        sim.advance().unwrap();
    }
}

#[test]
fn the_default_guard_names_a_blow_up_within_a_few_steps_of_its_onset() {
    // explicit viscosity at 40x its stability limit: the energy grows from the first steps;
    // the scenes' default guard must stop the run within a few steps of the growth, not after
    // the energy has overflowed
    let mut cfg = TaylorGreenConfig::default().with(|c| {
        c.n = 16;
        c.re = 1.0;
        c.viscous_theta = 0.0;
    });
    cfg.limits.dt_fixed = Some(0.02);
    let mut sim = taylor_green::build(&cfg).unwrap();
    let mut growing = 0;
    let err = loop {
        match sim.advance() {
            Ok(r) => {
                if r.energy_growth.is_some_and(|g| g > 1.0) {
                    growing += 1;
                }
                assert!(r.projection.kinetic_energy.is_finite());
            }
            Err(e) => break e,
        }
        assert!(sim.steps < 1000, "no blow-up detected");
    };
    // named at the latest a few steps after the energy starts to grow
    assert!(growing <= 5, "{growing} growing steps before: {err}");
    match &err {
        Error::Stability(StabilityError::BlowUp { quantity, .. }) => {
            assert!(
                *quantity == "max speed / u_ref" || *quantity == "kinetic energy growth",
                "{quantity}"
            );
        }
        other => panic!("{other:?}"),
    }
    // the correction's share of the predicted velocity is a guard of its own
    let mut cfg = TaylorGreenConfig::default().with(|c| c.n = 16);
    cfg.limits.guard.correction_ratio = Some(1e-12);
    let mut sim = taylor_green::build(&cfg).unwrap();
    sim.advance().unwrap();
    match sim.advance() {
        Err(Error::Stability(StabilityError::BlowUp {
            step: 2, quantity, ..
        })) => assert_eq!(quantity, "correction / predicted velocity"),
        other => panic!("{other:?}"),
    }
}

#[test]
fn dt_bound_is_the_smallest_limit_of_time_step() {
    // dt_bound and time_step agree whenever no fixed step or dt_max intervenes
    for theta in [0.0, 0.5] {
        let mut cfg = TaylorGreenConfig::default().with(|c| {
            c.n = 16;
            c.viscous_theta = theta;
            c.re = 5.0;
        });
        cfg.limits.visc = 0.5;
        let mut sim = taylor_green::build(&cfg).unwrap();
        for _ in 0..3 {
            let (dt, which) = sim.time_step();
            assert_eq!(sim.dt_bound(), (which, dt));
            let r = sim.advance().unwrap();
            assert!(r.dt_ratio > 0.0 && r.dt_ratio <= 1.0 + 1e-15);
        }
        // explicit viscosity at Re 5 is limited by the viscous bound, CN by the CFL bound
        let want = if theta == 0.0 {
            DtLimit::Viscous
        } else {
            DtLimit::Cfl
        };
        assert_eq!(sim.dt_bound().0, want);
        sim.params.limits.dt_fixed = Some(3.0 * sim.dt_bound().1);
        sim.params.limits.dt_max = Some(1e-9);
        assert_eq!(sim.time_step(), (3.0 * sim.dt_bound().1, DtLimit::Fixed));
        sim.params.limits.guard.dt_over_limit = Some(2.0);
        match sim.advance() {
            Err(Error::Stability(StabilityError::TimeStepTooLarge { limit, factor, .. })) => {
                assert_eq!((limit, factor), (want, 2.0))
            }
            other => panic!("{other:?}"),
        }
        sim.params.limits.guard.dt_over_limit = Some(3.5);
        sim.advance().unwrap();
    }
}

// ---------------------------------------------------------------------------------------------
// MCAP files: unreadable, foreign, truncated

fn record_run(path: &Path, steps: usize) {
    let mut sim = cavity::build(&CavityConfig::default().with(|c| c.n = 10)).unwrap();
    let mut rec =
        Recorder::create(path, RecordLevel::Diagnostics, 10, &serde_json::json!({})).unwrap();
    for _ in 0..steps {
        let r = sim.advance().unwrap();
        rec.write_step(&r, &sim).unwrap();
    }
    rec.finish().unwrap();
}

#[test]
fn unreadable_foreign_and_truncated_mcap_files_are_named() {
    let dir = tempfile::tempdir().unwrap();
    // missing file and a directory: I/O errors naming the path
    let missing = dir.path().join("missing.mcap");
    let e = Replay::open(&missing).unwrap_err();
    assert!(matches!(e, RecordError::Io { ref path, .. } if path == &missing));
    assert_names(&e.to_string(), &["missing.mcap"]);
    // a directory is refused before it is opened (issue 16: FIFOs and devices alike)
    let e = Replay::open(dir.path()).unwrap_err();
    assert!(matches!(e, RecordError::NotAFile { .. }), "{e:?}");
    assert_names(&e.to_string(), &[&dir.path().display().to_string()]);
    // not MCAP at all
    let garbage = dir.path().join("garbage.mcap");
    std::fs::write(&garbage, b"PK\x03\x04 this is a zip file, not a recording").unwrap();
    let e = Replay::open(&garbage).unwrap_err();
    assert!(matches!(e, RecordError::NotMcap { .. }), "{e:?}");
    assert_names(&e.to_string(), &["garbage.mcap", "not an MCAP file"]);
    assert!(matches!(
        rerun_file(&garbage, |_, _| {}),
        Err(RecordError::NotMcap { .. })
    ));
    // MCAP, but a /diagnostics message that is not gpm's JSON
    let foreign = dir.path().join("foreign.mcap");
    {
        let mut w = mcap::Writer::new(std::io::BufWriter::new(
            std::fs::File::create(&foreign).unwrap(),
        ))
        .unwrap();
        let ch = w
            .add_channel(0, "/diagnostics", "json", &Default::default())
            .unwrap();
        w.write_to_known_channel(
            &mcap::records::MessageHeader {
                channel_id: ch,
                sequence: 4,
                log_time: 0,
                publish_time: 0,
            },
            b"{\"step\": \"four\"}",
        )
        .unwrap();
        w.finish().unwrap();
    }
    let e = Replay::open(&foreign).unwrap_err();
    assert!(matches!(e, RecordError::Json { .. }), "{e:?}");
    assert_names(&e.to_string(), &["foreign.mcap", "/diagnostics message 4"]);
    // truncated: not an error (damage-tolerant replay), but a typed report naming the offset
    let full = dir.path().join("full.mcap");
    record_run(&full, 20);
    let bytes = std::fs::read(&full).unwrap();
    let cut = dir.path().join("cut.mcap");
    std::fs::write(&cut, &bytes[..bytes.len() / 2]).unwrap();
    let r = Replay::open(&cut).unwrap();
    let d = r.damage().expect("damage reported");
    assert!(d.valid_bytes < d.file_len && !d.data_complete);
    assert_eq!(d.file_len, (bytes.len() / 2) as u64);
    assert_eq!(r.scan.path, cut);
    assert_eq!(Some(r.steps.len() as u64), d.last_step);
    assert_names(&d.to_string(), &["cut after step", "byte offset"]);
    // empty file
    let empty = dir.path().join("empty.mcap");
    std::fs::write(&empty, b"").unwrap();
    let s = scan(&empty, |_| Ok(()), |_, _| {}).unwrap();
    assert_names(&s.damage.unwrap().reason, &["empty"]);
    // a recorder that cannot create its file names it
    let bad = dir.path().join("no/such/dir/run.mcap");
    let e =
        Recorder::create(&bad, RecordLevel::Diagnostics, 1, &serde_json::json!({})).unwrap_err();
    assert!(matches!(e, RecordError::Io { .. }));
    assert_names(&e.to_string(), &["no/such/dir/run.mcap"]);
}

// ---------------------------------------------------------------------------------------------
// the command-line tool and the examples

/// `target/<profile>/examples/<name>` next to this test's executable (`target/<profile>/deps/`):
/// built by `cargo test` with the examples; `None` when it is not there.
fn example(name: &str) -> Option<PathBuf> {
    let exe = std::env::current_exe().ok()?;
    let profile_dir = exe.parent()?.parent()?;
    let p = profile_dir
        .join("examples")
        .join(format!("{name}{}", std::env::consts::EXE_SUFFIX));
    p.is_file().then_some(p)
}

fn run(program: &Path, args: &[&str]) -> Output {
    Command::new(program)
        .args(args)
        .env("RUST_BACKTRACE", "1")
        .output()
        .expect("spawn")
}

/// A clean failure: non-zero status, a one-line `error:` naming `needles`, no panic, no backtrace.
fn assert_clean_failure(out: &Output, needles: &[&str]) -> String {
    let stderr = String::from_utf8_lossy(&out.stderr).to_string();
    assert!(!out.status.success(), "succeeded: {stderr}");
    assert!(
        !stderr.contains("panicked") && !stderr.contains("stack backtrace"),
        "panic or backtrace: {stderr}"
    );
    let line = stderr
        .lines()
        .find(|l| l.starts_with("error:"))
        .unwrap_or_else(|| panic!("no error line: {stderr}"));
    assert_names(line, needles);
    stderr
}

fn gpm_bin() -> &'static str {
    env!("CARGO_BIN_EXE_gpm")
}

#[test]
fn cli_rejects_invalid_configurations_cleanly() {
    let dir = tempfile::tempdir().unwrap();
    let out_dir = dir.path().join("out");
    let out = out_dir.to_str().unwrap();
    let gpm = Path::new(gpm_bin());
    for (args, needles) in [
        (vec!["--re=-5"], vec!["parameter 're' = -5"]),
        (vec!["--re", "nan"], vec!["parameter 're' = NaN"]),
        (vec!["--n", "0"], vec!["parameter 'n' = 0"]),
        (
            vec!["--h-ratio", "0.5"],
            vec!["parameter 'h_over_dx' = 0.5"],
        ),
        (vec!["--t-end", "inf"], vec!["parameter 't_end' = inf"]),
        (vec!["--cfl=-1"], vec!["parameter 'limits.cfl' = -1"]),
    ] {
        let mut a = vec!["run", "cavity", "--quiet", "--out", out];
        a.extend(args.iter().copied());
        assert_clean_failure(&run(gpm, &a), &needles);
        // nothing was recorded for a configuration refused before the run
        assert!(!out_dir.join("run.mcap").exists(), "{args:?}");
    }
    // clap refuses a negative count itself, naming the flag
    let o = run(gpm, &["run", "cavity", "--n=-3", "--out", out]);
    assert_eq!(o.status.code(), Some(2));
    assert_names(&String::from_utf8_lossy(&o.stderr), &["--n"]);
    // configuration files
    for (json, needles) in [
        (
            r#"{"reynolds": 100}"#,
            vec!["configuration key 'reynolds'", "unknown field"],
        ),
        (r#"{"n": -4}"#, vec!["configuration key 'n'"]),
        (
            r#"{"limits": {"cfl": null}}"#,
            vec!["configuration key 'limits.cfl'"],
        ),
        (
            r#"{"scene": "taylor_green", "config": {}}"#,
            vec!["configures the scene 'taylor_green'"],
        ),
        ("not json", vec!["is not JSON"]),
    ] {
        let f = dir.path().join("bad.json");
        std::fs::write(&f, json).unwrap();
        let mut needles = needles.clone();
        let fname = f.display().to_string();
        needles.push(&fname);
        assert_clean_failure(
            &run(
                gpm,
                &[
                    "run",
                    "cavity",
                    "--quiet",
                    "--out",
                    out,
                    "--config",
                    f.to_str().unwrap(),
                ],
            ),
            &needles,
        );
    }
    let missing = dir.path().join("missing.json");
    assert_clean_failure(
        &run(
            gpm,
            &[
                "run",
                "taylor-green",
                "--quiet",
                "--out",
                out,
                "--config",
                missing.to_str().unwrap(),
            ],
        ),
        &["missing.json"],
    );
}

/// `gpm run` with `config`, expected to fail: returns stderr and the recording read back.
fn cli_run_failing(config: serde_json::Value, needles: &[&str]) -> (String, Replay) {
    let dir = tempfile::tempdir().unwrap();
    let f = dir.path().join("cfg.json");
    std::fs::write(&f, config.to_string()).unwrap();
    let out = dir.path().join("out");
    let o = run(
        Path::new(gpm_bin()),
        &[
            "run",
            "cavity",
            "--quiet",
            "--out",
            out.to_str().unwrap(),
            "--config",
            f.to_str().unwrap(),
        ],
    );
    let stderr = assert_clean_failure(&o, needles);
    // a failed run keeps its recording aside (run.mcap is only ever a finished run's)
    let path = out.join("run.failed.mcap");
    assert!(!out.join("run.mcap").exists());
    assert!(stderr.contains(&path.display().to_string()), "{stderr}");
    let replay = Replay::open(&path).unwrap();
    assert!(replay.scan.complete, "the recording was not finished");
    assert!(replay.damage().is_none());
    (stderr, replay)
}

#[test]
fn cli_failures_during_a_run_finish_the_recording() {
    // the solver gives up in the first step: a finished file without steps
    let (_, r) = cli_run_failing(
        serde_json::json!({"n": 12, "solve": {"solver": "cg", "max_iters": 2, "rel_tol": 1e-14}}),
        &["cavity run failed", "did not converge in 2 iterations"],
    );
    assert_eq!(r.steps.len(), 0);
    assert!(r.config.is_some());
    // a too-large fixed time step named before the first step
    let (_, r) = cli_run_failing(
        serde_json::json!({"n": 12, "limits": {"dt_fixed": 1.0, "guard": {"dt_over_limit": 1.0}}}),
        &["step 1", "exceeds the CFL limit"],
    );
    assert_eq!(r.steps.len(), 0);
    // a blow-up guard tripping mid-run: every step before it reads back
    let (stderr, r) = cli_run_failing(
        serde_json::json!({"n": 12, "limits": {"guard": {"speed_over_ref": 0.3}}}),
        &["max speed / u_ref", "fastest particle"],
    );
    let step: u64 = stderr
        .split("step ")
        .nth(1)
        .and_then(|s| s.split_whitespace().next())
        .and_then(|s| s.parse().ok())
        .unwrap_or_else(|| panic!("no step in {stderr}"));
    assert!(step > 1);
    assert_eq!(r.steps.len() as u64, step - 1);
    assert_eq!(r.steps.last().unwrap().step, step - 1);
    assert!(r.steps.iter().all(|s| s.max_speed <= 0.3));
    // particles flung through a wall in a Lagrangian run
    let (_, r) = cli_run_failing(
        serde_json::json!({"n": 12, "motion": "lagrangian", "limits": {"dt_fixed": 0.5}}),
        &["outside the domain", "crossed the wall"],
    );
    assert!(r.steps.len() <= 3);
}

#[test]
fn cli_replay_of_bad_files() {
    let dir = tempfile::tempdir().unwrap();
    let gpm = Path::new(gpm_bin());
    let missing = dir.path().join("missing.mcap");
    assert_clean_failure(
        &run(gpm, &["replay", "--quiet", missing.to_str().unwrap()]),
        &["missing.mcap"],
    );
    let garbage = dir.path().join("garbage.mcap");
    std::fs::write(&garbage, vec![0x42u8; 4096]).unwrap();
    assert_clean_failure(
        &run(gpm, &["replay", "--quiet", garbage.to_str().unwrap()]),
        &["garbage.mcap", "not an MCAP file"],
    );
    // truncated: read with a warning naming file and offset; --strict makes it an error
    let full = dir.path().join("full.mcap");
    record_run(&full, 6);
    let bytes = std::fs::read(&full).unwrap();
    let cut = dir.path().join("cut.mcap");
    std::fs::write(&cut, &bytes[..bytes.len() / 2]).unwrap();
    let o = run(gpm, &["replay", "--quiet", cut.to_str().unwrap()]);
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{stderr}");
    assert_names(&stderr, &["warning:", "cut.mcap", "byte offset"]);
    let o = run(
        gpm,
        &["replay", "--quiet", "--strict", cut.to_str().unwrap()],
    );
    assert_eq!(o.status.code(), Some(2));
    assert_clean_failure(&o, &["cut.mcap", "byte offset"]);
    let o = run(
        gpm,
        &["replay", "--quiet", "--strict", full.to_str().unwrap()],
    );
    assert!(o.status.success());
}

#[test]
fn examples_report_bad_input_cleanly() {
    let (Some(cav), Some(tg)) = (example("cavity"), example("taylor_green")) else {
        eprintln!(
            "SKIPPED: the cavity and taylor_green examples are not built next to this test \
             (run `cargo test --release`, which builds them, not `--test bad_input` alone)"
        );
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    let out = out.to_str().unwrap();
    for (args, needles) in [
        (vec!["--re=-1"], vec!["parameter 're' = -1"]),
        (vec!["--n", "2"], vec!["parameter 'n' = 2"]),
        (vec!["--h-ratio", "1"], vec!["parameter 'h_over_dx' = 1"]),
        (vec!["--theta", "nan"], vec!["viscous_theta"]),
    ] {
        let mut a = vec!["--quiet", "--out", out];
        a.extend(args.iter().copied());
        assert_clean_failure(&run(&cav, &a), &needles);
    }
    for (args, needles) in [
        (vec!["--re", "nan"], vec!["parameter 're' = NaN"]),
        (vec!["--n", "4"], vec!["parameter 'n' = 4"]),
        (vec!["--dt=-0.1"], vec!["limits.dt_fixed"]),
    ] {
        let mut a = vec!["--out", out];
        a.extend(args.iter().copied());
        assert_clean_failure(&run(&tg, &a), &needles);
    }
    // a Lagrangian cavity at the largest CFL number (1) blows up in the first steps: a
    // particle escapes, or the energy-growth guard stops the step first (it does since the
    // wall variant of the least-squares operators weighs its wall points continuously);
    // either way the example names the particle and finishes its recording, which reads back
    let o = run(
        &cav,
        &[
            "--quiet",
            "--out",
            out,
            "--n",
            "12",
            "--motion",
            "lagrangian",
            "--cfl",
            "1",
            "--t-end",
            "5",
        ],
    );
    let escaped = String::from_utf8_lossy(&o.stderr).contains("outside the domain");
    let how: &[&str] = if escaped {
        &["cavity run failed", "particle", "outside the domain"]
    } else {
        &["cavity run failed", "exceeds", "fastest particle"]
    };
    assert_clean_failure(&o, how);
    let r = Replay::open(Path::new(out).join("run.failed.mcap")).unwrap();
    assert!(r.scan.complete);
    // a step moves the particles with uⁿ: the first (the lid at rest) does not move them
    assert!(r.steps.len() <= 4, "{} steps recorded", r.steps.len());
}
