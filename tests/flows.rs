//! Flows built on the projection: a short cavity against Ghia et al. (checked with code
//! independent of the crate's own error computation), Taylor–Green against the exact solution
//! (accuracy, spatial and temporal orders), and a hydrostatic column under a Dirichlet band.

use gpm::boundary::{Wall, Walls};
use gpm::flow::{FlowParams, Integrator, Motion, Simulation, TimeStepLimits, VolumeRule};
use gpm::geometry::lattice;
use gpm::kernel::Weight;
use gpm::neighbors::{NeighborConfig, Periodicity};
use gpm::particles::{Particles, Role};
use gpm::projection::{ProjectionParams, Scheme};
use gpm::scene::cavity::{self, CavityConfig};
use gpm::scene::taylor_green::{self, TaylorGreenConfig};
use gpm::scene::{run_scene, RunEnd};
use std::ops::ControlFlow;
use std::path::Path;

/// Reads a two-column CSV (with `#` comments and a header), written independently of
/// `gpm::reference`.
fn read_csv(path: &Path) -> Vec<(f64, f64)> {
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{path:?}: {e}"));
    text.lines()
        .filter(|l| !l.trim().is_empty() && !l.starts_with('#'))
        .skip(1)
        .map(|l| {
            let mut it = l.split(',').map(|v| v.trim().parse::<f64>().unwrap());
            (it.next().unwrap(), it.next().unwrap())
        })
        .collect()
}

/// Piecewise-linear interpolation on sorted abscissae.
fn lerp(table: &[(f64, f64)], q: f64) -> f64 {
    for w in table.windows(2) {
        let ((x0, y0), (x1, y1)) = (w[0], w[1]);
        if q >= x0 && q <= x1 {
            return y0 + (y1 - y0) * (q - x0) / (x1 - x0);
        }
    }
    panic!("{q} outside the table");
}

fn rms_against(reference: &[(f64, f64)], profile: &[(f64, f64)]) -> f64 {
    let inner: Vec<f64> = reference
        .iter()
        .filter(|(p, _)| *p > 0.0 && *p < 1.0)
        .map(|(p, r)| lerp(profile, *p) - r)
        .collect();
    (inner.iter().map(|e| e * e).sum::<f64>() / inner.len() as f64).sqrt()
}

#[test]
fn cavity_re100_short_run_against_ghia() {
    let cfg = CavityConfig::default().with(|c| {
        c.n = 24;
        c.t_end = 30.0;
    });
    let mut steps = 0;
    let run = run_scene(
        &cfg,
        |_| {},
        |rep, _| {
            let p = &rep.projection;
            assert!(
                p.stability_ratio <= 1.0,
                "step {}: ratio {}",
                rep.step,
                p.stability_ratio
            );
            assert!(p.kinetic_energy.is_finite() && p.max_speed.is_finite());
            assert_eq!(
                p.connectivity.floating, 1,
                "one floating (all-Neumann) component"
            );
            assert_eq!(p.connectivity.isolated, 0);
            assert!(p.div_after.is_finite());
            steps += 1;
            Ok(ControlFlow::Continue(()))
        },
    )
    .unwrap();
    assert_eq!(
        run.end,
        RunEnd::Scene,
        "the cavity stops itself once steady"
    );
    let res = &run.result;
    assert!(res.steady, "not steady by t = {}", res.t_end);
    assert_eq!(steps as u64, res.steps);
    // the crate's own errors
    let g = res.ghia.expect("Re 100 table");
    // independent check: written profiles against the data files
    let dir = std::env::temp_dir().join(format!("gpm_cavity_test_{}", std::process::id()));
    let written = run.write_tables(&dir, &cfg).unwrap();
    let names: Vec<_> = written
        .iter()
        .filter_map(|p| p.file_name()?.to_str())
        .collect();
    assert_eq!(names, ["profile_u.csv", "profile_v.csv", "summary.json"]);
    let pu = read_csv(&dir.join("profile_u.csv"));
    let pv = read_csv(&dir.join("profile_v.csv"));
    let data = Path::new(env!("CARGO_MANIFEST_DIR")).join("data");
    let gu = read_csv(&data.join("ghia1982_re100_u_vertical.csv"));
    let gv = read_csv(&data.join("ghia1982_re100_v_horizontal.csv"));
    let (ru, rv) = (rms_against(&gu, &pu), rms_against(&gv, &pv));
    assert!(
        (ru - g.rms_u).abs() < 1e-6 && (rv - g.rms_v).abs() < 1e-6,
        "{ru} {rv} vs {g:?}"
    );
    // coarse bound: the issue's target is 1 % at n = 50; at n = 24 (half the resolution) 2.5 %
    assert!(ru < 0.025 && rv < 0.025, "RMS u {ru}, v {rv}");
    // profile sanity independent of Ghia: wall values and the lid
    assert!(lerp(&pu, 0.0).abs() < 0.05 && (lerp(&pu, 1.0) - 1.0).abs() < 0.05);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn taylor_green_accuracy_and_spatial_order() {
    let mut errs = Vec::new();
    for n in [16usize, 32] {
        let cfg = TaylorGreenConfig::default().with(|c| {
            c.n = n;
            c.t_end = 0.5;
        });
        let r = taylor_green::run(&cfg, |rep, _| {
            assert!(rep.projection.stability_ratio <= 1.0);
            Ok(())
        })
        .unwrap();
        errs.push(r.errors.l1_velocity_error);
    }
    let order = (errs[0] / errs[1]).log2();
    assert!(order > 1.5, "spatial order {order} ({errs:?})");
    // the issue's bar is 1 % at n = 50, t = 2; n = 32 at t = 0.5 must already be below it
    assert!(errs[1] < 0.01, "{errs:?}");
}

/// Temporal orders with the spatial error cancelled exactly: every run is compared with a
/// reference on the same particles with a much smaller Δt.
#[test]
fn incremental_schemes_have_higher_temporal_order() {
    let state = |scheme: Scheme, dt: f64| -> Vec<[f64; 2]> {
        let mut cfg = TaylorGreenConfig::default().with(|c| {
            c.n = 16;
            c.t_end = 0.16;
            c.scheme = scheme;
        });
        cfg.limits.dt_fixed = Some(dt);
        let mut sim = taylor_green::build(&cfg).unwrap();
        for _ in 0..(0.16 / dt).round() as usize {
            sim.advance().unwrap();
        }
        sim.particles.u
    };
    let diff = |a: &[[f64; 2]], b: &[[f64; 2]]| -> f64 {
        a.iter()
            .zip(b)
            .map(|(x, y)| ((x[0] - y[0]).powi(2) + (x[1] - y[1]).powi(2)).sqrt())
            .sum::<f64>()
    };
    let mut orders = Vec::new();
    for scheme in [
        Scheme::NonIncremental,
        Scheme::Incremental,
        Scheme::Rotational,
    ] {
        let reference = state(scheme, 0.0005);
        let e1 = diff(&state(scheme, 0.02), &reference);
        let e2 = diff(&state(scheme, 0.01), &reference);
        orders.push((e1 / e2).log2());
    }
    assert!(orders[0] < 1.3, "non-incremental order {orders:?}");
    assert!(
        orders[1] > 1.7 && orders[2] > 1.7,
        "incremental orders {orders:?}"
    );
}

/// A fluid column at rest under gravity, walls on three sides (mirror ghosts) and a Dirichlet
/// band (`p = 0`) above the free surface: the step must reach the hydrostatic state
/// `u = 0`, `p = ρ g (1 − y)`, with an anchored component (no floating one).
fn hydrostatic_error(n: usize, scheme: Scheme) -> (f64, f64) {
    let dx = 1.0 / n as f64;
    let h = 3.0 * dx;
    let g = 1.0;
    let mut p = Particles::<2>::new();
    for x in lattice([0.0, 0.0], [1.0, 1.0], dx) {
        p.push(x, [0.0, 0.0], 0.0, dx * dx, Role::Fluid);
    }
    // band above the surface, wide enough to cover the corner images
    for x in lattice([-4.0 * dx, 1.0], [1.0 + 4.0 * dx, 1.0 + 4.0 * dx], dx) {
        p.push(x, [0.0, 0.0], 0.0, dx * dx, Role::Dirichlet);
    }
    let wall = |axis, position, inward| Wall::at_rest(axis, position, inward);
    let walls = Walls {
        walls: vec![wall(0, 0.0, 1.0), wall(0, 1.0, -1.0), wall(1, 0.0, 1.0)],
        periodic: Periodicity::none(),
    };
    let mut projection = ProjectionParams::<2>::new(0.01);
    projection.gravity = [0.0, -g];
    projection.scheme = scheme;
    projection.allowed_floating = 0;
    let params = FlowParams {
        projection,
        limits: TimeStepLimits::default(),
        motion: Motion::Eulerian,
        integrator: Integrator::Ab2,
        convection: Default::default(),
        shifting: None,
        volumes: VolumeRule::NumberDensity,
        pair_weights: Default::default(),
        dx,
    };
    let mut sim = Simulation::new(
        p,
        walls,
        NeighborConfig::new(Weight::WendlandC2, h, 0.3 * h),
        params,
    )
    .unwrap();
    for _ in 0..100 {
        let r = sim.advance().unwrap();
        assert_eq!(r.projection.connectivity.floating, 0);
        assert!(r.projection.stability_ratio <= 1.0);
    }
    let pr = &sim.particles;
    let mut max_u = 0.0f64;
    let mut err = 0.0f64;
    let mut norm = 0.0f64;
    for i in 0..pr.len() {
        if pr.role[i].is_fluid() {
            max_u = max_u.max(pr.u[i][0].hypot(pr.u[i][1]));
            let exact = g * (1.0 - pr.x[i][1]);
            err += (pr.p[i] - exact).abs();
            norm += exact;
        }
    }
    (max_u / (g * sim.time), err / norm)
}

#[test]
fn hydrostatic_column_under_a_dirichlet_band() {
    // non-incremental: p = φ solves the compact problem every step; the band holds p = 0 from
    // y = 1 + Δx/2 on, so the pressure converges at first order at least
    let r: Vec<(f64, f64)> = [10, 20, 40]
        .iter()
        .map(|&n| hydrostatic_error(n, Scheme::NonIncremental))
        .collect();
    for w in r.windows(2) {
        // the non-incremental splitting leaves a spurious velocity that falls with Δx
        assert!(w[1].0 < w[0].0, "spurious velocity does not fall: {r:?}");
        let order = (w[0].1 / w[1].1).log2();
        assert!(order > 0.8, "pressure order {order}: {r:?}");
    }
    // incremental schemes carry ∇h pⁿ in the predictor, so the O(Δt) splitting velocity of the
    // non-incremental scheme must be much smaller (their pressure keeps an odd-even mode that
    // ∇h does not see — see the README's known limitations — so only u is checked)
    for scheme in [Scheme::Incremental, Scheme::Rotational] {
        let (u, _) = hydrostatic_error(20, scheme);
        assert!(
            u < 0.2 * r[1].0,
            "{scheme}: max |u| / (g t) = {u} vs non-incremental {}",
            r[1].0
        );
    }
}

/// Body-force-driven Poiseuille flow: periodic in x, no-slip walls at y = 0 and 1; the steady
/// state is `u = g y (1 − y) / (2ν)` and second order in Δx is expected.
#[test]
fn poiseuille_channel_with_periodic_axis_and_walls() {
    let run = |n: usize| -> f64 {
        let dx = 1.0 / n as f64;
        let (g, nu) = (1.0, 0.25);
        let mut p = Particles::<2>::new();
        for x in lattice([0.0, 0.0], [1.0, 1.0], dx) {
            p.push(x, [0.0, 0.0], 0.0, dx * dx, Role::Fluid);
        }
        let walls = Walls {
            walls: vec![Wall::at_rest(1, 0.0, 1.0), Wall::at_rest(1, 1.0, -1.0)],
            periodic: Periodicity {
                lo: [0.0, 0.0],
                len: [1.0, 0.0],
            },
        };
        let mut projection = ProjectionParams::<2>::new(nu);
        projection.gravity = [g, 0.0];
        let params = FlowParams {
            projection,
            limits: TimeStepLimits {
                dt_fixed: Some(0.02),
                ..Default::default()
            },
            motion: Motion::Eulerian,
            integrator: Integrator::Ab2,
            convection: Default::default(),
            shifting: None,
            volumes: VolumeRule::NumberDensity,
            pair_weights: Default::default(),
            dx,
        };
        let h = 3.0 * dx;
        let mut sim = Simulation::new(
            p,
            walls,
            NeighborConfig::new(Weight::WendlandC2, h, 0.0),
            params,
        )
        .unwrap();
        // diffusion time 1/ν = 4: run to t = 8 (transient e^{−π²νt} ≈ 7e-9)
        while sim.time < 8.0 {
            sim.advance().unwrap();
        }
        let pr = &sim.particles;
        let (mut err, mut norm) = (0.0f64, 0.0f64);
        for i in 0..pr.len() {
            if pr.role[i].is_fluid() {
                let y = pr.x[i][1];
                let exact = g * y * (1.0 - y) / (2.0 * nu);
                err = err.max((pr.u[i][0] - exact).abs() + pr.u[i][1].abs());
                norm = norm.max(exact);
            }
        }
        err / norm
    };
    let (e1, e2) = (run(16), run(32));
    let order = (e1 / e2).log2();
    assert!(order > 1.5, "order {order}: {e1} {e2}");
    assert!(e2 < 0.01, "max relative error {e2} at n = 32");
}

/// A scene's plan holds only the stages it needs, and the ones it lacks never run.
#[test]
fn stage_plans_follow_the_scene() {
    use gpm::boundary::{Boundary, PeriodicBox, VectorKind};
    use gpm::flow::Stage::*;
    use std::sync::atomic::{AtomicUsize, Ordering};
    let tg = taylor_green::build(&TaylorGreenConfig::default().with(|c| c.n = 16)).unwrap();
    let plan = tg.plan();
    for s in [
        Periodic,
        Convection,
        ViscousExplicit,
        ViscousImplicit,
        PressureGradient,
        RotationalCorrection,
        Projection,
    ] {
        assert!(plan.has(s), "Taylor–Green lacks {s:?}: {plan:?}");
    }
    for s in [
        Ghosts,
        BodyForce,
        DirichletBand,
        Advection,
        Shifting,
        MovingNeighbors,
    ] {
        assert!(!plan.has(s), "Taylor–Green has {s:?}: {plan:?}");
    }
    let cav = cavity::build(&CavityConfig::default().with(|c| c.n = 12)).unwrap();
    assert!(cav.plan().has(Ghosts) && !cav.plan().has(Periodic) && !cav.plan().has(BodyForce));

    /// A periodic box that counts every call a ghost stage would make.
    struct Counting {
        inner: PeriodicBox<2>,
        calls: AtomicUsize,
    }
    impl Boundary<2> for Counting {
        fn has_ghosts(&self) -> bool {
            false
        }
        fn periodicity(&self) -> Periodicity<2> {
            self.inner.periodic
        }
        fn fill_scalar(&self, _: &[Role], _: &mut [f64]) {
            self.calls.fetch_add(1, Ordering::Relaxed);
        }
        fn fill_vector(&self, _: &[Role], _: &mut [[f64; 2]], _: VectorKind) {
            self.calls.fetch_add(1, Ordering::Relaxed);
        }
        fn place_ghosts(&self, _: &mut Particles<2>) {
            self.calls.fetch_add(1, Ordering::Relaxed);
        }
        fn make_ghosts(&self, _: &mut Particles<2>, _: f64) {
            self.calls.fetch_add(1, Ordering::Relaxed);
        }
        fn confine(&self, p: &mut Particles<2>) -> Result<(), gpm::error::InputError> {
            self.inner.confine(p)
        }
    }
    let cfg = TaylorGreenConfig::default().with(|c| c.n = 16);
    let base = taylor_green::build(&cfg).unwrap();
    let counting = Counting {
        inner: PeriodicBox {
            periodic: Periodicity::all([0.0, 0.0], [1.0, 1.0]),
        },
        calls: AtomicUsize::new(0),
    };
    let mut sim = Simulation::new(
        {
            let mut p = base.particles.clone();
            p.truncate(p.n_fluid());
            p
        },
        counting,
        *base.nl.config(),
        base.params,
    )
    .unwrap();
    let before = sim.boundary.calls.load(Ordering::Relaxed);
    for _ in 0..5 {
        sim.advance().unwrap();
    }
    assert_eq!(
        sim.boundary.calls.load(Ordering::Relaxed),
        before,
        "ghost stages ran in a scene without walls"
    );
}

// ---------------------------------------------------------------------------------------------
// scenes: configuration layout, registry, observers that stop a run

/// The keys a configuration reads are exactly the keys it writes (the shared ones first, in
/// the layout of the recorded `/config`), for every registered scene.
#[test]
fn scene_configuration_keys_are_the_serialised_keys() {
    fn check<S: gpm::scene::SceneParams>() {
        let v = serde_json::to_value(gpm::scene::SceneConfig::<S>::default()).unwrap();
        let mut written: Vec<&str> = v.as_object().unwrap().keys().map(|k| k.as_str()).collect();
        let mut read: Vec<&str> = gpm::scene::SceneConfig::<S>::keys().collect();
        written.sort_unstable();
        read.sort_unstable();
        assert_eq!(written, read, "{}", S::NAME);
    }
    check::<cavity::Cavity>();
    check::<taylor_green::TaylorGreen>();
    check::<gpm::scene::channel::Channel>();
    check::<gpm::scene::hydrostatic::Hydrostatic>();
    check::<gpm::scene::dam_break::DamBreak>();
    check::<gpm::scene::cube::Cube>();
    check::<gpm::scene::dam_break_3d::DamBreak3d>();
    assert_eq!(
        gpm::scene::SCENES,
        [
            "cavity",
            "taylor_green",
            "channel",
            "hydrostatic",
            "dam_break",
            "cube",
            "dam_break_3d"
        ]
    );
}

#[test]
fn scene_configuration_round_trips_and_keeps_the_flat_layout() {
    use gpm::scene::config_from_json;
    let cfg = CavityConfig::default().with(|c| {
        c.n = 12;
        c.re = 400.0;
        c.limits.cfl = 0.15;
        c.scene.lid = -2.0;
        c.scene.steady.tol = 1e-4;
    });
    let text = serde_json::to_string(&cfg).unwrap();
    let back: CavityConfig = config_from_json(&text).unwrap();
    assert_eq!(back, cfg);
    // hand-written flat JSON (the layout of configurations recorded before the scene trait):
    // shared and scene keys side by side; missing keys take the scene's defaults
    let flat =
        r#"{"re": 400, "n": 12, "lid": -2, "steady": {"tol": 1e-4}, "limits": {"cfl": 0.15}}"#;
    let read: CavityConfig = config_from_json(flat).unwrap();
    assert_eq!(read, cfg);
    assert_eq!(read.t_end, 40.0, "the cavity's own default end time");
    let tg: TaylorGreenConfig = config_from_json(r#"{"amplitude": 0.5, "n": 16}"#).unwrap();
    assert_eq!((tg.scene.amplitude, tg.n, tg.t_end), (0.5, 16, 2.0));
    // a scene's key is unknown to another scene; a repeated key is refused, naming it
    for (json, key, needle) in [
        (r#"{"lid": 1}"#, "lid", "unknown field `lid`"),
        (r#"{"n": 12, "n": 16}"#, "n", "duplicate field `n`"),
    ] {
        match config_from_json::<TaylorGreenConfig>(json) {
            Err(gpm::error::InputError::Config { key: k, reason }) => {
                assert_eq!(k, key, "{json}");
                assert!(reason.contains(needle), "{json}: {reason}");
            }
            other => panic!("{json}: {other:?}"),
        }
    }
}

#[test]
fn scenes_are_found_by_name() {
    struct Name;
    impl gpm::scene::SceneVisitor for Name {
        type Output = (&'static str, usize);
        fn visit<const D: usize, S: gpm::scene::Scene<D>>(self) -> Self::Output {
            (S::NAME, D)
        }
    }
    assert_eq!(
        gpm::scene::visit_scene("cavity", Name).unwrap(),
        ("cavity", 2)
    );
    assert_eq!(
        gpm::scene::visit_scene("Taylor-Green", Name).unwrap(),
        ("taylor_green", 2)
    );
    assert_eq!(
        gpm::scene::visit_scene("dam-break", Name).unwrap(),
        ("dam_break", 2)
    );
    assert_eq!(gpm::scene::visit_scene("cube", Name).unwrap(), ("cube", 3));
    assert_eq!(
        gpm::scene::visit_scene("dam-break-3d", Name).unwrap(),
        ("dam_break_3d", 3)
    );
    match gpm::scene::visit_scene("sloshing", Name) {
        Err(gpm::error::InputError::Config { key, reason }) => {
            assert_eq!(key, "scene");
            assert!(reason.contains("cavity, taylor_green"), "{reason}");
        }
        other => panic!("{:?}", other.map(|_| ())),
    }
}

/// An observer stops a run by returning `Break`, not an error: the run ends after that step and
/// still reports its result.
#[test]
fn an_observer_stops_a_run_with_a_value() {
    let cfg = TaylorGreenConfig::default().with(|c| c.n = 12);
    let run = run_scene(
        &cfg,
        |_| {},
        |rep, _| {
            Ok(if rep.step == 3 {
                ControlFlow::Break(())
            } else {
                ControlFlow::Continue(())
            })
        },
    )
    .unwrap();
    assert_eq!(run.end, RunEnd::Observer { step: 3 });
    assert_eq!(run.interrupted(), Some(3));
    assert_eq!((run.result.steps, run.sim.steps), (3, 3));
    assert!(run.result.t_end > 0.0 && run.result.t_end < cfg.t_end);
    assert!(run.result.errors.l1_velocity_error.is_finite());
    // run to the end: lands exactly on t_end (the last step is shortened)
    let cfg = cfg.with(|c| c.t_end = 0.05);
    let run = run_scene(&cfg, |_| {}, |_, _| Ok(ControlFlow::Continue(()))).unwrap();
    assert_eq!(run.end, RunEnd::EndTime);
    assert!(
        (run.result.t_end - 0.05).abs() < 1e-15,
        "{}",
        run.result.t_end
    );
}

/// A tiny lid-driven cube (n = 8, Re 100, t = 1.5, seconds): every particle stays in the
/// cube, the flow is mirror-symmetric about z = 0.5 (u, v even, w odd), the centre-line u is
/// positive below the lid and negative in the return flow, v changes sign across the centre
/// (down near x = 1, up near x = 0), and the profiles are written.
#[test]
fn tiny_cube_is_symmetric_and_driven_by_its_lid() {
    use gpm::scene::cube::CubeConfig;
    let cfg = CubeConfig::default().with(|c| {
        c.n = 8;
        c.t_end = 1.5;
    });
    let run = run_scene(&cfg, |_| {}, |_, _| Ok(ControlFlow::Continue(()))).unwrap();
    let res = &run.result;
    let p = &run.sim.particles;
    assert_eq!(p.n_fluid(), 512);
    for i in (0..p.len()).filter(|&i| p.role[i].is_fluid()) {
        assert!(
            p.x[i].iter().all(|&c| c > 0.0 && c < 1.0),
            "particle {i} at {:?}",
            p.x[i]
        );
        assert!(p.u[i].iter().all(|c| c.is_finite()));
    }
    assert!(
        res.symmetry < 1e-8,
        "symmetry about z = 0.5: {}",
        res.symmetry
    );
    let r = &res.profiles;
    assert!(
        r.steps > 10 && (r.t_end - 1.5).abs() < 0.1,
        "{} {}",
        r.steps,
        r.t_end
    );
    let at = |pos: &[f64], val: &[f64], q: f64| cavity::interp(pos, val, q);
    assert!(at(&r.ys, &r.u, 0.9) > 0.1, "u below the lid");
    let return_flow = (1..10)
        .map(|k| at(&r.ys, &r.u, 0.05 * k as f64 + 0.05))
        .fold(f64::INFINITY, f64::min);
    assert!(return_flow < -0.02, "return flow {return_flow}");
    assert!(at(&r.xs, &r.v, 0.85) < 0.0 && at(&r.xs, &r.v, 0.15) > 0.0);
    // no reference at Re 100; the profiles and the summary are written
    assert!(r.reference.is_none() && r.ghia.is_none());
    let dir = std::env::temp_dir().join(format!("gpm_tiny_cube_{}", std::process::id()));
    let written = run.write_tables(&dir, &cfg).unwrap();
    for name in ["profile_u.csv", "profile_v.csv", "summary.json"] {
        assert!(written.iter().any(|f| f.ends_with(name)), "{name}");
    }
    let u = read_csv(&dir.join("profile_u.csv"));
    assert_eq!(u.len(), r.ys.len());
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("summary.json")).unwrap()).unwrap();
    assert_eq!(summary["particles"], 512);
    assert!(summary["symmetry"].as_f64().unwrap() < 1e-8);
    std::fs::remove_dir_all(&dir).ok();
}

/// `Particles::fluid_csv` (the examples' `--particles-csv`, read by `tools/peer/errors.py`):
/// header, fluid particles only, numbers that read back exactly.
#[test]
fn fluid_csv_lists_the_fluid_particles_exactly() {
    let mut p = Particles::<2>::new();
    p.push([0.1, 0.25], [-1.5, 1.0 / 3.0], 2.0, 0.01, Role::Fluid);
    p.push([0.5, 0.5], [0.0, 0.0], 0.0, 0.01, Role::Dirichlet);
    p.push([0.9, 0.75], [1e-17, -0.0], -0.125, 0.01, Role::Fluid);
    p.push(
        [-0.1, 0.25],
        [1.5, 0.0],
        2.0,
        0.01,
        Role::Ghost {
            source: 0,
            walls: 1,
        },
    );
    let text = p.fluid_csv();
    let lines: Vec<&str> = text.lines().collect();
    assert_eq!(lines[0], "x,y,u,v,p");
    assert_eq!(lines.len(), 3, "{text}");
    let row: Vec<f64> = lines[1].split(',').map(|v| v.parse().unwrap()).collect();
    assert_eq!(row, vec![0.1, 0.25, -1.5, 1.0 / 3.0, 2.0]);
    assert_eq!(lines[2], "0.9,0.75,0.00000000000000001,-0,-0.125");
    let mut q = Particles::<3>::new();
    q.push([0.0; 3], [0.0; 3], 0.0, 1.0, Role::Fluid);
    assert_eq!(q.fluid_csv(), "x,y,z,u,v,w,p\n0,0,0,0,0,0,0\n");
}

/// The rest-walls rule on the cavity's ghosts: the no-slip image (`−v`) across walls at rest
/// and at their corners (`+v`), the mirror across the lid and at the lid's corners, and next
/// to the lid the two blended by `S(d/δ)`: half and half (a zero tangential component) where
/// the source is `δ/2` from the lid, the no-slip image from `δ` on. Without positions no band
/// applies.
#[test]
fn rest_walls_rule_mirrors_at_the_lid_and_blends_next_to_it() {
    use gpm::boundary::{Boundary, VectorKind};
    let mut walls = Walls::<2>::cavity(1.0, 1.0);
    let band = 0.25;
    for w in &mut walls.walls {
        if w.velocity[0] != 0.0 {
            w.source_band = band;
        }
    }
    // walls of the closed box: 0 x = 0, 1 x = 1, 2 y = 0, 3 y = 1 (the lid)
    let cases: [(u8, [f64; 2]); 6] = [
        (0b0001, [-0.3, -0.7]), // left wall at rest
        (0b0100, [-0.3, -0.7]), // floor
        (0b0101, [0.3, 0.7]),   // floor and left wall: −(−v)
        (0b1000, [0.3, -0.7]),  // lid: the mirror (normal component flipped)
        (0b1010, [-0.3, -0.7]), // lid and right wall: the mirror of both
        (0b1001, [-0.3, -0.7]), // lid and left wall
    ];
    let far = [0.9, 0.5]; // half a side from the lid: beyond the band
    let mut x = vec![far];
    let mut role = vec![Role::Fluid];
    for &(w, _) in &cases {
        x.push(far);
        role.push(Role::Ghost {
            source: 0,
            walls: w,
        });
    }
    let mut v = vec![[0.3, 0.7]; role.len()];
    walls.fill_vector_at(&x, &role, &mut v, VectorKind::RestWalls);
    for (k, (mask, want)) in cases.iter().enumerate() {
        assert_eq!(v[k + 1], *want, "ghost across walls {mask:04b}");
    }
    // the source δ/2 below the lid: its image across the right wall is half odd, half even
    let mut x2 = x.clone();
    x2[0] = [0.9, 1.0 - 0.5 * band];
    let mut v2 = vec![[0.3, 0.7]; role.len()];
    walls.fill_vector_at(&x2, &role, &mut v2, VectorKind::RestWalls);
    assert!(
        (v2[1][0] + 0.3).abs() < 1e-15 && v2[1][1].abs() < 1e-15,
        "{:?}",
        v2[1]
    );
    // ... the lid's and its corners' images do not depend on the band
    for k in 4..=6 {
        assert_eq!(v2[k], v[k], "ghost {k}");
    }
    // without positions: no band, the walls at rest's images are odd
    let mut v3 = vec![[0.3, 0.7]; role.len()];
    walls.fill_vector(&role, &mut v3, VectorKind::RestWalls);
    assert_eq!(v3[1], [-0.3, -0.7]);
}

/// The Re 1000 cavity at n = 48, Δt at the CFL limit, with the rest-walls source continuation
/// (its band ¼ side, `h = 2.5Δx`): steady, Theorem 4.5's ratio at most 1 at every step, and
/// within issue 15's bar of 1.5 % RMS in u and in v against the extrapolated reference (the
/// defaults miss it: 1.59 % / 1.75 %). Measured: 0.48 % / 0.27 %.
#[test]
fn rest_walls_source_rule_meets_the_re1000_bar_at_n48() {
    let cfg = CavityConfig::default().with(|c| {
        c.re = 1000.0;
        c.n = 48;
        c.t_end = 150.0;
        c.h_over_dx = 2.5;
        c.scene.source_ghosts = cavity::SourceGhosts::RestWalls;
    });
    let r = cavity::run(&cfg, |rep, _| {
        let p = &rep.projection;
        assert!(p.stability_ratio <= 1.0, "ratio {}", p.stability_ratio);
        assert!(p.max_speed.is_finite() && p.max_speed < 1.5);
        Ok(())
    })
    .unwrap();
    assert!(r.steady, "not steady by t = {}", r.t_end);
    let e = r.reference.expect("the extrapolated reference at Re 1000");
    assert!(e.rms_u <= 0.015 && e.rms_v <= 0.015, "{e:?}");
}

/// Second order at Re 100 with the rest-walls source continuation: the RMS errors against the
/// extrapolated reference at n = 16, 24, 32 fall with an observed order of at least 1.8
/// between each pair, in u and in v (measured: 2.05 / 1.97 and 2.92 / 1.99).
#[test]
fn rest_walls_source_rule_converges_at_second_order_at_re100() {
    assert_re100_order(cavity::SourceGhosts::RestWalls, &[16, 24, 32], 1.8);
}

/// Runs the Re 100 cavity (`h = 2.5Δx`) with the source rule `rule` at each `n` to steady
/// state and asserts that the RMS errors in u and in v against the extrapolated reference fall
/// with an observed order of at least `min_order` between neighbouring resolutions.
fn assert_re100_order(rule: cavity::SourceGhosts, ns: &[usize], min_order: f64) {
    let errs: Vec<(usize, f64, f64)> = ns
        .iter()
        .map(|&n| {
            let cfg = CavityConfig::default().with(|c| {
                c.n = n;
                c.h_over_dx = 2.5;
                c.scene.source_ghosts = rule;
            });
            let r = cavity::run(&cfg, |_, _| Ok(())).unwrap();
            assert!(r.steady, "n = {n}: not steady by t = {}", r.t_end);
            let e = r.reference.expect("the extrapolated reference at Re 100");
            (n, e.rms_u, e.rms_v)
        })
        .collect();
    for w in errs.windows(2) {
        let ((n0, u0, v0), (n1, u1, v1)) = (w[0], w[1]);
        let r = (n1 as f64 / n0 as f64).ln();
        let (pu, pv) = ((u0 / u1).ln() / r, (v0 / v1).ln() / r);
        assert!(
            pu >= min_order && pv >= min_order,
            "{rule:?}, n = {n0} → {n1}: orders {pu:.2} / {pv:.2} ({errs:?})"
        );
    }
}

/// The rest-walls-linear rule on the cavity's lattice: every ghost that crossed the lid alone
/// takes the tangential component of a field linear along the normal (`u = a(x) + b(x) y`,
/// `a`, `b` anything) exactly — the value at the ghost's own position — and its source's
/// normal component flipped; every other ghost keeps the rest-walls value. The mirror
/// (the rest-walls rule across the lid) misses the same field by `2 d b(x)`.
#[test]
fn rest_walls_linear_rule_continues_fields_linear_across_the_lid() {
    use gpm::boundary::VectorKind;
    use gpm::projection::stages::{source_field, LinearGhosts};
    use gpm::projection::SourceKind;
    let cfg = CavityConfig::default().with(|c| {
        c.n = 12;
        c.h_over_dx = 2.5;
        c.scene.source_ghosts = cavity::SourceGhosts::RestWallsLinear;
    });
    let sim = cavity::build(&cfg).unwrap();
    assert_eq!(
        sim.params.projection.source_ghosts,
        VectorKind::RestWallsLinear
    );
    let p = &sim.particles;
    let field = |x: &[f64; 2]| {
        [
            (3.0 * x[0]).sin() + (2.0 * x[0]).cos() * x[1],
            0.3 + x[0] * x[0] - 0.5 * x[1] * x[1],
        ]
    };
    let v: Vec<[f64; 2]> = p.x.iter().map(field).collect();
    let mut linear = LinearGhosts::default();
    linear
        .update(&sim.nl, &p.x, &p.role, &sim.boundary)
        .unwrap();
    let fill = |rule: VectorKind| {
        let mut f = Vec::new();
        source_field(
            &p.x,
            &p.role,
            &sim.boundary,
            rule,
            Some(&linear),
            SourceKind::SumForm,
            1.0,
            &v,
            &mut f,
        );
        f
    };
    let (lin, rest) = (
        fill(VectorKind::RestWallsLinear),
        fill(VectorKind::RestWalls),
    );
    let (mut lid_ghosts, mut mirror_off) = (0, 0.0f64);
    for (g, r) in p.role.iter().enumerate() {
        let Role::Ghost { source, .. } = *r else {
            continue;
        };
        let xg = p.x[g];
        let across_lid_alone = xg[1] > 1.0 && xg[0] > 0.0 && xg[0] < 1.0;
        if across_lid_alone {
            lid_ghosts += 1;
            let s = source as usize;
            assert!(
                (lin[g][0] - field(&xg)[0]).abs() < 1e-12,
                "ghost {g}: {} against {}",
                lin[g][0],
                field(&xg)[0]
            );
            assert_eq!(lin[g][1], -v[s][1], "ghost {g}: the normal component");
            mirror_off = mirror_off.max((rest[g][0] - field(&xg)[0]).abs());
        } else {
            assert_eq!(lin[g], rest[g], "ghost {g} at {xg:?}");
        }
    }
    // two rows of sources within h = 2.5 Δx of the lid, twelve per row
    assert_eq!(lid_ghosts, 24);
    assert!(mirror_off > 0.05, "the mirror's miss {mirror_off}");
}

/// The rest-walls-linear rule refuses what it cannot continue: a source off the lattice (no
/// fluid particle straight below it) is named, and the Lagrangian frame is refused by the
/// scene's validation.
#[test]
fn rest_walls_linear_rule_refuses_sources_off_the_lattice() {
    use gpm::boundary::Boundary;
    use gpm::projection::stages::LinearGhosts;
    let cfg = CavityConfig::default().with(|c| {
        c.n = 12;
        c.h_over_dx = 2.5;
        c.scene.source_ghosts = cavity::SourceGhosts::RestWallsLinear;
    });
    let mut sim = cavity::build(&cfg).unwrap();
    // the fluid particle nearest to (0.5, 1): a source of lid ghosts, moved sideways
    let i = (0..sim.particles.len())
        .filter(|&i| sim.particles.role[i] == Role::Fluid)
        .min_by(|&a, &b| {
            let d = |k: usize| {
                let x = sim.particles.x[k];
                (x[0] - 0.5).powi(2) + (x[1] - 1.0).powi(2)
            };
            d(a).total_cmp(&d(b))
        })
        .unwrap();
    sim.particles.x[i][0] += 0.01 / 12.0;
    sim.boundary.place_ghosts(&mut sim.particles);
    let p = &sim.particles;
    let nl = gpm::neighbors::NeighborList::build(*sim.nl.config(), &p.x).unwrap();
    let e = LinearGhosts::default()
        .update(&nl, &p.x, &p.role, &sim.boundary)
        .expect_err("a source off the lattice")
        .to_string();
    assert!(
        e.contains(&format!("its source {i} ")) && e.contains("straight inward"),
        "{e}"
    );
    let moving = cfg.with(|c| c.motion = Motion::Lagrangian);
    let e = cavity::build(&moving)
        .err()
        .expect("the Lagrangian frame is refused")
        .to_string();
    assert!(
        e.contains("source_ghosts") && e.contains("fixed particles"),
        "{e}"
    );
}

/// Second order at Re 100 with the rest-walls-linear rule: the RMS errors against the
/// extrapolated reference at n = 24, 32, 48 fall with an observed order of at least 1.9
/// between each pair, in u and in v (measured 2026-11-30: 2.38 / 2.08 and 2.44 / 2.50).
#[test]
fn rest_walls_linear_rule_converges_at_second_order_at_re100() {
    assert_re100_order(cavity::SourceGhosts::RestWallsLinear, &[24, 32, 48], 1.9);
}
