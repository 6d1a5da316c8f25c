//! `Simulation::advance_to` / `advance_toward` (landing on a time without rewriting the limits)
//! and the `validate()` of every parameter type (each bad value named by its key path and value).

use gpm::boundary::Walls;
use gpm::error::{DtLimit, Error, InputError};
use gpm::flow::{
    FlowParams, Integrator, Motion, Shifting, Simulation, StabilityGuard, TimeStepLimits,
    VolumeRule,
};
use gpm::geometry::lattice;
use gpm::kernel::Weight;
use gpm::neighbors::NeighborConfig;
use gpm::particles::{Particles, Role};
use gpm::poisson::SolveParams;
use gpm::projection::ProjectionParams;
use gpm::scene::taylor_green::{self, TaylorGreenConfig};

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

/// An Eulerian lid-driven cavity of `n × n` particles, `h = 3 Δx`.
fn cavity(n: usize, params: impl FnOnce(&mut FlowParams<2>)) -> Simulation<2, Walls<2>> {
    let dx = 1.0 / n as f64;
    let mut fp = flow_params(dx, Motion::Eulerian);
    params(&mut fp);
    Simulation::new(
        square(n),
        Walls::cavity(1.0, 1.0),
        NeighborConfig::new_relative(Weight::WendlandC2, dx, 3.0, 0.0),
        fp,
    )
    .unwrap()
}

#[test]
fn advance_to_lands_exactly_with_the_cfl_step() {
    // n = 12, h = 3/12 = 0.25: CFL step 0.2 h / max(|u|, u_ref = 1) = 0.05 while the fluid is
    // slower than the lid (speed 1); 0.12 = 0.05 + 0.05 + 0.02
    let mut sim = cavity(12, |_| {});
    let (dt, limit) = sim.time_step();
    assert_eq!(limit, DtLimit::Cfl);
    assert!((dt - 0.05).abs() < 1e-15, "{dt}");
    let t = 0.12;
    let last = sim.advance_to(t).unwrap().expect("a step was taken");
    assert_eq!(sim.time, t, "the time after advance_to is exactly t");
    assert_eq!(last.time, t);
    assert_eq!(sim.steps, 3);
    assert_eq!(last.step, 3);
    assert!(
        (last.projection.dt - 0.02).abs() < 1e-15,
        "{}",
        last.projection.dt
    );
    assert_eq!(
        last.dt_limit,
        DtLimit::Fixed,
        "the shortened step is named as fixed"
    );
    assert_eq!(
        sim.params.limits.dt_fixed, None,
        "the limits are not rewritten"
    );
    // already there: no step; going back or to a non-finite time: a named error
    assert!(sim.advance_to(t).unwrap().is_none());
    assert_eq!(sim.steps, 3);
    for bad in [0.1, f64::NAN, f64::INFINITY] {
        match sim.advance_to(bad) {
            Err(Error::Input(InputError::Parameter { name, value, .. })) => {
                assert_eq!(name, "t");
                assert!(value == bad || (value.is_nan() && bad.is_nan()));
            }
            other => panic!("advance_to({bad}): {other:?}"),
        }
    }
    assert!(
        sim.advance_toward(t).is_err(),
        "advance_toward needs t > time"
    );
    assert_eq!(sim.steps, 3);
}

#[test]
fn advance_to_matches_the_dt_fixed_rewriting_loop() {
    // the loop scenes used before advance_to: patch dt_fixed for the last step, restore it
    let t_end = 0.13;
    let mut old = cavity(12, |_| {});
    while old.time < t_end - 1e-12 {
        let (dt, _) = old.time_step();
        let remaining = t_end - old.time;
        if dt > remaining {
            old.params.limits.dt_fixed = Some(remaining);
        }
        old.advance().unwrap();
        old.params.limits.dt_fixed = None;
    }
    let mut new = cavity(12, |_| {});
    let mut steps = 0;
    while new.time < t_end {
        let r = new.advance_toward(t_end).unwrap();
        steps += 1;
        assert!(r.time <= t_end);
    }
    assert_eq!(new.time, t_end);
    assert_eq!(steps, old.steps);
    assert!((old.time - t_end).abs() < 1e-15);
    // bit-identical states
    assert_eq!(new.particles.u, old.particles.u);
    assert_eq!(new.particles.p, old.particles.p);
    assert_eq!(new.particles.x, old.particles.x);
}

#[test]
fn advance_to_lands_with_a_fixed_step() {
    // 0.01 added seven times is not 0.07 in floating point: the last step absorbs the rounding
    let mut sim = cavity(12, |fp| fp.limits.dt_fixed = Some(0.01));
    let t = 0.07;
    let last = sim.advance_to(t).unwrap().unwrap();
    assert_eq!(sim.steps, 7);
    assert_eq!(sim.time, t);
    assert!((last.projection.dt - 0.01).abs() < 1e-12);
    assert_eq!(sim.params.limits.dt_fixed, Some(0.01));
    // and on from there, to a time that is not a multiple of the step
    let last = sim.advance_to(0.095).unwrap().unwrap();
    assert_eq!(sim.steps, 10);
    assert_eq!(sim.time, 0.095);
    assert!((last.projection.dt - 0.005).abs() < 1e-12);
}

#[test]
fn advance_to_lands_in_the_lagrangian_frame_with_shifting() {
    let cfg = TaylorGreenConfig::default().with(|c| {
        c.n = 16;
        c.motion = Motion::Lagrangian;
        c.shifting = Some(Shifting::default());
    });
    let mut sim = taylor_green::build(&cfg).unwrap();
    assert_eq!(sim.params.motion, Motion::Lagrangian);
    let (dt, _) = sim.time_step();
    let t = 2.37 * dt;
    sim.advance_to(t).unwrap();
    assert_eq!(sim.time, t);
    assert!(sim.steps >= 2);
    assert!(sim.plan().has(gpm::flow::Stage::Shifting));
}

/// The key path and value of a parameter error.
fn param(r: Result<(), InputError>) -> (String, f64) {
    match r {
        Err(InputError::Parameter { name, value, .. }) => (name.into_owned(), value),
        other => panic!("expected a parameter error, got {other:?}"),
    }
}

fn same(a: f64, b: f64) -> bool {
    a == b || (a.is_nan() && b.is_nan())
}

#[track_caller]
fn assert_param(r: Result<(), InputError>, key: &str, value: f64) {
    let (k, v) = param(r);
    assert_eq!(k, key);
    assert!(same(v, value), "{key}: value {v}, expected {value}");
}

#[test]
fn solve_params_name_each_bad_value() {
    assert!(SolveParams::default().validate().is_ok());
    let s = |f: &dyn Fn(&mut SolveParams)| {
        let mut p = SolveParams::default();
        f(&mut p);
        p.validate()
    };
    assert_param(s(&|p| p.abs_tol = -1e-8), "solve.abs_tol", -1e-8);
    assert_param(
        s(&|p| p.abs_tol = f64::INFINITY),
        "solve.abs_tol",
        f64::INFINITY,
    );
    assert_param(s(&|p| p.rel_tol = -0.5), "solve.rel_tol", -0.5);
    assert_param(s(&|p| p.rel_tol = f64::NAN), "solve.rel_tol", f64::NAN);
    assert_param(
        s(&|p| p.viscous_rel_tol = -1e-12),
        "solve.viscous_rel_tol",
        -1e-12,
    );
    assert_param(s(&|p| p.max_iters = 0), "solve.max_iters", 0.0);
    assert_param(s(&|p| p.amg_lag_factor = 0.0), "solve.amg_lag_factor", 0.0);
    assert_param(s(&|p| p.warm_tol = 1.0), "solve.warm_tol", 1.0);
    assert_param(s(&|p| p.warm_tol = -1e-3), "solve.warm_tol", -1e-3);
    assert_param(s(&|p| p.warm_tol = f64::NAN), "solve.warm_tol", f64::NAN);
    // the message names the key and the value
    let e = s(&|p| p.abs_tol = -3.0).unwrap_err();
    let msg = e.to_string();
    assert!(msg.contains("solve.abs_tol") && msg.contains("-3"), "{msg}");
    assert!(!msg.contains("rel_tol"), "{msg}");
}

#[test]
fn projection_params_name_the_solve_key() {
    // a negative abs_tol used to be reported as solve.rel_tol with rel_tol's value
    let mut p = ProjectionParams::<2>::new(0.01);
    p.solve.abs_tol = -1.0;
    assert_param(p.validate(), "solve.abs_tol", -1.0);
    let mut p = ProjectionParams::<2>::new(0.01);
    p.solve.max_iters = 0;
    assert_param(p.validate(), "solve.max_iters", 0.0);
}

#[test]
fn time_step_limits_and_guard_name_each_bad_value() {
    let l = |f: &dyn Fn(&mut TimeStepLimits)| {
        let mut l = TimeStepLimits::default();
        f(&mut l);
        l.validate()
    };
    assert!(l(&|_| {}).is_ok());
    assert_param(l(&|l| l.cfl = 0.0), "limits.cfl", 0.0);
    assert_param(l(&|l| l.force = -2.0), "limits.force", -2.0);
    assert_param(l(&|l| l.dt_fixed = Some(-0.1)), "limits.dt_fixed", -0.1);
    assert_param(
        l(&|l| l.guard.energy_growth = Some(-1.0)),
        "limits.guard.energy_growth",
        -1.0,
    );
    assert_param(
        l(&|l| l.guard.energy_floor = f64::NAN),
        "limits.guard.energy_floor",
        f64::NAN,
    );
    // the guard on its own names its keys under `guard`
    let g = StabilityGuard {
        stability_ratio: Some(0.0),
        ..Default::default()
    };
    assert_param(g.validate(), "guard.stability_ratio", 0.0);
    let g = StabilityGuard {
        speed_over_ref: Some(f64::NAN),
        ..Default::default()
    };
    assert_param(g.validate(), "guard.speed_over_ref", f64::NAN);
    assert!(StabilityGuard::default().validate().is_ok());
}

#[test]
fn shifting_and_neighbor_config_name_each_bad_value() {
    assert!(Shifting::default().validate().is_ok());
    let s = Shifting {
        coefficient: -1.0,
        ..Default::default()
    };
    assert_param(s.validate(), "shifting.coefficient", -1.0);
    let s = Shifting {
        max_fraction: 1.5,
        ..Default::default()
    };
    assert_param(s.validate(), "shifting.max_fraction", 1.5);
    let s = Shifting {
        repulsion: 0.7,
        ..Default::default()
    };
    assert_param(s.validate(), "shifting.repulsion", 0.7);
    let s = Shifting {
        repulsion_radius: 0.0,
        ..Default::default()
    };
    assert_param(s.validate(), "shifting.repulsion_radius", 0.0);
    for bad in [0.0, -1e-6, 1.0, f64::NAN, f64::INFINITY] {
        let s = Shifting {
            volume_tol: bad,
            ..Default::default()
        };
        assert_param(s.validate(), "shifting.volume_tol", bad);
    }
    let c = |h: f64, skin: f64| NeighborConfig::<2>::new(Weight::WendlandC2, h, skin).validate();
    assert!(c(0.1, 0.0).is_ok());
    assert_param(c(-0.1, 0.0), "h", -0.1);
    assert_param(c(0.0, 0.0), "h", 0.0);
    assert_param(c(f64::INFINITY, 0.0), "h", f64::INFINITY);
    assert_param(c(0.1, -0.01), "skin", -0.01);
    assert_param(c(0.1, f64::NAN), "skin", f64::NAN);
}

#[test]
fn flow_params_prefix_the_nested_keys() {
    let ok = flow_params(0.1, Motion::Lagrangian);
    assert!(ok.validate().is_ok());
    let f = |g: &dyn Fn(&mut FlowParams<2>)| {
        let mut p = flow_params(0.1, Motion::Lagrangian);
        g(&mut p);
        p.validate()
    };
    assert_param(
        f(&|p| p.projection.solve.abs_tol = -2.0),
        "projection.solve.abs_tol",
        -2.0,
    );
    assert_param(f(&|p| p.projection.rho = 0.0), "projection.rho", 0.0);
    assert_param(f(&|p| p.limits.visc = -1.0), "limits.visc", -1.0);
    assert_param(
        f(&|p| p.limits.guard.dt_over_limit = Some(0.0)),
        "limits.guard.dt_over_limit",
        0.0,
    );
    assert_param(
        f(&|p| {
            p.shifting = Some(Shifting {
                coefficient: f64::NAN,
                ..Default::default()
            })
        }),
        "shifting.coefficient",
        f64::NAN,
    );
    assert_param(f(&|p| p.dx = 0.0), "dx", 0.0);
    // Simulation::new reports the same key
    let mut fp = flow_params(1.0 / 12.0, Motion::Eulerian);
    fp.projection.solve.abs_tol = -4.0;
    match Simulation::new(
        square(12),
        Walls::cavity(1.0, 1.0),
        NeighborConfig::new_relative(Weight::WendlandC2, 1.0 / 12.0, 3.0, 0.0),
        fp,
    ) {
        Err(Error::Input(e)) => assert_param(Err(e), "projection.solve.abs_tol", -4.0),
        other => panic!("{:?}", other.err()),
    }
}

#[test]
fn under_prefixes_only_parameter_errors() {
    let e = InputError::parameter("solve.abs_tol", -1.0, "bad").under("projection");
    assert_eq!(e.parameter_name(), Some("projection.solve.abs_tol"));
    assert_eq!(
        InputError::parameter("h", 1.0, "x")
            .under("")
            .parameter_name(),
        Some("h")
    );
    let other = InputError::NonFinite {
        field: "velocity",
        particle: 3,
    };
    assert_eq!(other.clone().under("projection"), other);
    assert_eq!(other.parameter_name(), None);
}

#[test]
fn pressure_smoothing_outside_zero_one_is_named() {
    let p = |beta: f64| {
        let mut q = gpm::projection::ProjectionParams::<2>::new(0.01);
        q.pressure_smoothing = beta;
        q.validate()
    };
    assert!(p(0.0).is_ok() && p(0.5).is_ok());
    assert_param(p(1.0), "pressure_smoothing", 1.0);
    assert_param(p(-0.1), "pressure_smoothing", -0.1);
    assert_param(p(f64::NAN), "pressure_smoothing", f64::NAN);
    // the consistent set is valid as it stands
    let c = gpm::projection::ProjectionParams::<2>::new(0.01).with_consistent_operators();
    assert!(c.validate().is_ok());
}

/// The `disconnected` key: `null` resolves by the frame (`float` for moving particles, `fail`
/// for fixed ones), an explicit value wins, and a bad value is named by its key.
#[test]
fn disconnected_policy_key_resolves_by_the_frame() {
    use gpm::projection::Disconnected;
    use gpm::scene::config_from_json;
    let policy = |json: &str| {
        let cfg: TaylorGreenConfig = config_from_json(json).expect(json);
        cfg.flow_params::<2>(1.0).projection.disconnected
    };
    assert_eq!(policy(r#"{"motion": "lagrangian"}"#), Disconnected::Float);
    assert_eq!(policy(r#"{"motion": "eulerian"}"#), Disconnected::Fail);
    assert_eq!(
        policy(r#"{"motion": "lagrangian", "disconnected": "fail"}"#),
        Disconnected::Fail
    );
    assert_eq!(policy(r#"{"disconnected": "float"}"#), Disconnected::Float);
    match config_from_json::<TaylorGreenConfig>(r#"{"disconnected": "drop"}"#) {
        Err(gpm::error::InputError::Config { key, reason }) => {
            assert_eq!(key, "disconnected");
            assert!(
                reason.contains("fail") && reason.contains("float"),
                "{reason}"
            );
        }
        other => panic!("expected a configuration error, got {other:?}"),
    }
}

/// The `source` and `gradient` keys: `null` takes the operator set's source (the sum form for
/// fixed lattice particles, least squares for moving ones), an explicit one wins over the set,
/// a renormalised gradient is kept under the consistent set (the default `difference` is
/// replaced by least squares there), and the adjoint source without the gradient it is the
/// adjoint of is refused by name when the flow starts.
#[test]
fn source_and_gradient_keys_resolve_over_the_operator_set() {
    use gpm::consistent::GradientKind;
    use gpm::projection::SourceKind;
    use gpm::scene::config_from_json;
    let params = |json: &str| {
        let cfg: TaylorGreenConfig = config_from_json(json).expect(json);
        let p = cfg.flow_params::<2>(1.0).projection;
        (p.source, p.gradient)
    };
    assert_eq!(
        params(r#"{"motion": "eulerian"}"#),
        (SourceKind::SumForm, GradientKind::Difference)
    );
    assert_eq!(
        params(r#"{"motion": "lagrangian"}"#),
        (SourceKind::LeastSquares, GradientKind::LeastSquares)
    );
    assert_eq!(
        params(r#"{"motion": "lagrangian", "gradient": "renormalised"}"#),
        (SourceKind::LeastSquares, GradientKind::Renormalised)
    );
    assert_eq!(
        params(r#"{"motion": "eulerian", "source": "least_squares"}"#),
        (SourceKind::LeastSquares, GradientKind::Difference)
    );
    assert_eq!(
        params(r#"{"motion": "lagrangian", "source": "sum_form"}"#),
        (SourceKind::SumForm, GradientKind::LeastSquares)
    );
    let cfg: TaylorGreenConfig =
        config_from_json(r#"{"motion": "eulerian", "source": "adjoint_bt"}"#).unwrap();
    let err = cfg.flow_params::<2>(1.0).validate().unwrap_err();
    assert!(err.to_string().contains("source"), "{err}");
    match config_from_json::<TaylorGreenConfig>(r#"{"source": "upwind"}"#) {
        Err(gpm::error::InputError::Config { key, .. }) => assert_eq!(key, "source"),
        other => panic!("expected a configuration error, got {other:?}"),
    }
}
