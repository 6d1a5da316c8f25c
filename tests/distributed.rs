//! The distributed Poisson solve and diagnostics on ranks that are threads of this process
//! (`ThreadComm`): the same solution, connectivity and `c0` as the serial solver, for the
//! closed cavity (one floating component: pure Neumann) and the periodic vortex.

mod common;

use gpm::boundary::Boundary;
use gpm::diagnostics::{connectivity, semi_regularity, Region};
use gpm::distributed::{global_diagnostics, DdPreconditioner, DistributedRun, ThreadComm};
use gpm::flow::{Motion, Simulation};
use gpm::poisson::{PoissonSolver, SolveParams, SolverKind};
use gpm::projection::StepReport;
use gpm::scene::{cavity, taylor_green};

/// A smooth right side (its sum need not vanish: the solver projects it).
fn rhs(x: &[[f64; 2]]) -> Vec<f64> {
    x.iter()
        .map(|p| (6.0 * p[0]).sin() * (4.0 * p[1]).cos() + p[0] * p[1])
        .collect()
}

/// The scene of `build`, the solver settings of these tests (CG to 1e-12 for the distributed
/// runs), its connectivity, the right side [`rhs`] and the serial Cholesky solution.
fn serial_solve<B: Boundary<2>>(
    build: &impl Fn() -> Simulation<2, B>,
) -> (
    Simulation<2, B>,
    SolveParams,
    gpm::diagnostics::Components,
    Vec<f64>,
    Vec<f64>,
) {
    let params = SolveParams {
        solver: SolverKind::Cholesky,
        rel_tol: 1e-12,
        ..Default::default()
    };
    let sim = build();
    let (nl, vol, role) = (&sim.nl, &sim.particles.vol, &sim.particles.role);
    let comps = connectivity(nl, role);
    let b = rhs(&sim.particles.x);
    let mut serial = vec![0.0; b.len()];
    PoissonSolver::new()
        .solve(nl, vol, role, &comps, &b, &mut serial, &params)
        .unwrap();
    (sim, params, comps, b, serial)
}

/// Solves on `ranks` thread ranks and compares with the serial Cholesky solve; returns the
/// iterations.
fn check<B: Boundary<2>>(
    build: impl Fn() -> Simulation<2, B> + Sync,
    ranks: usize,
    pre: DdPreconditioner,
) -> usize {
    let (sim, params, comps, b, serial) = serial_solve(&build);
    let (nl, vol, role) = (&sim.nl, &sim.particles.vol, &sim.particles.role);
    let c0 = semi_regularity(nl, vol, role, Region::Omega);
    let summary = comps.summary();
    let scale = serial.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    let iters = ThreadComm::run(ranks, |comm| {
        let mut sim = build();
        let mut run = DistributedRun::new(comm);
        run.solver().preconditioner = pre;
        run.install(&mut sim);
        let (nl, vol, role) = (&sim.nl, &sim.particles.vol, &sim.particles.role);
        let mut phi = vec![0.0; b.len()];
        let solver = &mut sim.projection.solver;
        let info = solver
            .solve(nl, vol, role, &comps, &b, &mut phi, &params)
            .unwrap();
        let diff = phi
            .iter()
            .zip(&serial)
            .fold(0.0f64, |m, (a, b)| m.max((a - b).abs()));
        assert!(
            diff <= 1e-9 * scale,
            "{ranks} ranks, {pre:?}: largest difference {diff:e} (scale {scale:e})"
        );
        // the diagnostics from the ranks' rows equal the serial ones
        let f = vec![[1.0, 0.5]; b.len()];
        let g = global_diagnostics(&mut run.solver(), &solver.assembly, nl, role, vol, &phi, &f);
        assert_eq!(g.connectivity, summary);
        assert_eq!(g.c0, c0);
        info.iters
    });
    assert!(iters.iter().all(|&i| i == iters[0]));
    iters[0]
}

fn cavity_sim() -> Simulation<2, gpm::boundary::Walls<2>> {
    let cfg = cavity::CavityConfig::default().with(|c| {
        c.n = 24;
        c.motion = Motion::Eulerian;
    });
    cavity::build(&cfg).unwrap()
}

fn cavity_moving_sim() -> Simulation<2, gpm::boundary::Walls<2>> {
    let cfg = cavity::CavityConfig::default().with(|c| {
        c.n = 24;
        c.motion = Motion::Lagrangian;
    });
    cavity::build(&cfg).unwrap()
}

fn vortex_moving_sim() -> Simulation<2, gpm::boundary::PeriodicBox<2>> {
    vortex_moving_n(24)
}

fn vortex_moving_n(n: usize) -> Simulation<2, gpm::boundary::PeriodicBox<2>> {
    let cfg = taylor_green::TaylorGreenConfig::default().with(|c| {
        c.n = n;
        c.motion = Motion::Lagrangian;
    });
    taylor_green::build(&cfg).unwrap()
}

/// The moving vortex with Fickian shifting on top of the default repulsion (its speed the
/// largest over all particles: a global maximum in a decomposed run), which reads the
/// neighbours' volumes: the deepest chain of reads in a moving step.
fn vortex_fickian_sim() -> Simulation<2, gpm::boundary::PeriodicBox<2>> {
    let mut s = vortex_moving_sim();
    s.params.shifting = Some(gpm::flow::Shifting {
        coefficient: 1.0,
        global_speed: true,
        ..Default::default()
    });
    s
}

/// A small dam break: a free surface (the Dirichlet band, detected every step) on moving
/// particles under gravity.
fn dam_break_sim() -> Simulation<2, gpm::boundary::Walls<2>> {
    let cfg = gpm::scene::dam_break::DamBreakConfig::default().with(|c| c.n = 12);
    gpm::scene::dam_break::build(&cfg).unwrap()
}

fn vortex_sim() -> Simulation<2, gpm::boundary::PeriodicBox<2>> {
    let cfg = taylor_green::TaylorGreenConfig::default().with(|c| {
        c.n = 24;
        c.motion = Motion::Eulerian;
    });
    taylor_green::build(&cfg).unwrap()
}

#[test]
fn distributed_solves_equal_the_serial_one() {
    for pre in [
        DdPreconditioner::Jacobi,
        DdPreconditioner::BlockAmg,
        DdPreconditioner::BlockAmgCoarse,
        DdPreconditioner::Schwarz,
        DdPreconditioner::Chebyshev,
    ] {
        let one = check(cavity_sim, 1, pre);
        let four = check(cavity_sim, 4, pre);
        eprintln!("cavity {pre:?}: {one} iterations on 1 rank, {four} on 4");
        if matches!(pre, DdPreconditioner::Jacobi | DdPreconditioner::Chebyshev) {
            // independent of the partition: issue 18's ≤ 1.3× holds with room to spare
            assert!(
                four.abs_diff(one) <= 1,
                "{pre:?}: {one} iterations on 1 rank, {four} on 4"
            );
        }
        let three = check(vortex_sim, 3, pre);
        eprintln!("vortex {pre:?}: {three} iterations on 3 ranks");
    }
}

/// The particle decomposition's solve: each rank holds only its own fluid particles and the
/// halo of particles within `h` of its box (RCB of the particles, `distributed::decomposition`),
/// makes its own ghosts and neighbour list, assembles its *local* matrix, and the distributed
/// CG solves from the local systems (`DistributedPoisson::set_local`). The own values equal
/// the serial solve on all particles.
fn check_local<B: Boundary<2> + Sync>(build: impl Fn() -> Simulation<2, B> + Sync, ranks: usize) {
    use gpm::distributed::decomposition::{migrate, ParticleHalo, RcbTree};
    use gpm::distributed::{Comm, DistributedPoisson};
    use gpm::neighbors::NeighborList;
    use gpm::particles::{Particles, Role};
    let (sim, params, comps, b, serial) = serial_solve(&build);
    let (nl, vol, role) = (&sim.nl, &sim.particles.vol, &sim.particles.role);
    let scale = serial.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    let fluid: Vec<usize> = (0..role.len())
        .filter(|&i| role[i] == Role::Fluid)
        .collect();
    let config = *nl.config();
    let per = config.periodic;
    let out = ThreadComm::run(ranks, |comm| {
        let me = comm.rank();
        // a round-robin share of the fluid particles: where they start does not matter
        let share: Vec<usize> = fluid.iter().copied().filter(|i| i % ranks == me).collect();
        let x: Vec<[f64; 2]> = share.iter().map(|&i| sim.particles.x[i]).collect();
        let tree = RcbTree::balance(&comm, &x);
        let ids: Vec<f64> = share.iter().map(|&i| i as f64).collect();
        let (own_x, own_ids) = migrate(&comm, &tree, &x, &ids, 1);
        let halo = ParticleHalo::new(&comm, &tree, &own_x, config.h + config.skin, &per);
        let halo_ids = halo.exchange(&comm, &own_ids, 1);
        // the local particles: own, then the halo (its owners in receive order), then ghosts
        let mut local = Particles::new();
        let (mut gid, mut owner) = (Vec::new(), Vec::new());
        let mut halo_owner = Vec::new();
        for &(q, n) in &halo.recvs {
            halo_owner.extend(std::iter::repeat_n(q as u32, n));
        }
        for (id, o) in own_ids
            .iter()
            .map(|&v| (v as usize, me as u32))
            .chain(halo_ids.iter().map(|&v| v as usize).zip(halo_owner))
        {
            local.push(sim.particles.x[id], [0.0; 2], 0.0, vol[id], Role::Fluid);
            gid.push(id as u32);
            owner.push(o);
        }
        sim.boundary.make_ghosts(&mut local, config.h + config.skin);
        gid.resize(local.len(), u32::MAX);
        owner.resize(local.len(), me as u32);
        let lnl = NeighborList::build(config, &local.x).unwrap();
        let lcomps = connectivity(&lnl, &local.role);
        let lb: Vec<f64> = gid
            .iter()
            .map(|&g| if g != u32::MAX { b[g as usize] } else { 0.0 })
            .collect();
        let mut dp = DistributedPoisson::new(comm.clone());
        dp.set_local(gid.clone(), owner.clone(), comps.floating().len() == 1);
        let mut solver = PoissonSolver::new();
        solver.external = Some(Box::new(dp));
        let mut phi = vec![0.0; local.len()];
        solver
            .solve(
                &lnl,
                &local.vol,
                &local.role,
                &lcomps,
                &lb,
                &mut phi,
                &params,
            )
            .unwrap();
        // own values, and those of the halo particles that own rows reach (within h of an own
        // particle: what the correction reads) as their owners computed them
        let n_own = own_ids.len();
        let mut read = vec![false; local.len()];
        for i in 0..n_own {
            read[i] = true;
            for k in lnl.row(i) {
                let j = lnl.indices()[k] as usize;
                let j = match local.role[j] {
                    Role::Ghost { source, .. } => source as usize,
                    _ => j,
                };
                read[j] |= lnl.w()[k] > 0.0;
            }
        }
        let mine: Vec<(usize, f64)> = (0..local.len())
            .filter(|&i| gid[i] != u32::MAX && read[i])
            .map(|i| (gid[i] as usize, phi[i]))
            .collect();
        assert!(
            ranks == 1 || mine.len() > n_own,
            "halo values are checked too"
        );
        (own_ids.len(), halo.n_halo(), mine)
    });
    let total: usize = out.iter().map(|o| o.0).sum();
    assert_eq!(total, fluid.len(), "every fluid particle owned once");
    for (rank, (_, n_halo, mine)) in out.iter().enumerate() {
        assert!(ranks == 1 || *n_halo > 0, "rank {rank} has a halo");
        for &(id, v) in mine {
            let diff = (v - serial[id]).abs();
            assert!(
                diff <= 1e-9 * scale,
                "{ranks} ranks, rank {rank}, particle {id}: {v} vs {} ({diff:e})",
                serial[id]
            );
        }
    }
}

#[test]
fn local_systems_of_decomposed_particles_solve_like_the_whole() {
    for ranks in [1, 3, 4] {
        check_local(cavity_sim, ranks);
        check_local(vortex_sim, ranks);
    }
}

/// Holds a run's solves at 10⁻¹² — the Poisson solve's `rel_tol` and the volume shift's own
/// tolerance — so that ranks that iterate and one process that factorises differ by the
/// decomposition, not by a tolerance.
fn hold_tight<const D: usize>(params: &mut gpm::flow::FlowParams<D>) {
    params.projection.solve.rel_tol = 1e-12;
    if let Some(sh) = params.shifting.as_mut() {
        sh.volume_tol = 1e-12;
    }
}

/// `steps` steps of the scene of `build`, serial and decomposed over `ranks` thread ranks
/// (each rank holding its own particles and their halo, `distributed::decomposed`): the own
/// particles' velocities and pressures equal the serial run's.
fn check_steps<B: Boundary<2> + Clone + Sync>(
    build: impl Fn() -> Simulation<2, B> + Sync,
    ranks: usize,
    steps: usize,
) -> f64 {
    use gpm::distributed::decomposed::DecomposedRun;
    let tight = || {
        let mut s = build();
        hold_tight(&mut s.params);
        s
    };
    let mut serial = tight();
    let reports: Vec<_> = (0..steps).map(|_| serial.advance().unwrap()).collect();
    let out = ThreadComm::run(ranks, |comm| {
        let global = tight();
        let mut run = DecomposedRun::new(comm, &global).unwrap();
        let mut t = 0.0;
        let mut iterations = 0;
        for (k, serial_rep) in reports.iter().enumerate() {
            let rep = match run.advance() {
                Ok(r) => r,
                Err(e) => panic!("rank {}: step {k}: {e}", run.n_own()),
            };
            iterations += rep.projection.solve.iters;
            // a free surface's band and splashes, counted over every rank's own particles
            assert_eq!(rep.surface, serial_rep.surface, "step {k}: surface");
            // the global diagnostics of the step equal the serial run's
            let g = run.global_diagnostics(rep.time - t);
            t = rep.time;
            let sp = &serial_rep.projection;
            assert_eq!(g.connectivity, sp.connectivity, "step {k}");
            assert!(
                (g.c0 - sp.c0).abs() <= 1e-12 * sp.c0,
                "step {k}: c0 {} vs {}",
                g.c0,
                sp.c0
            );
            let ratio = (g.stability_ratio - sp.stability_ratio).abs();
            assert!(
                ratio <= 1e-6 * sp.stability_ratio,
                "step {k}: ratio {} vs {}",
                g.stability_ratio,
                sp.stability_ratio
            );
        }
        let p = &run.sim.particles;
        let own = run
            .own_ids()
            .iter()
            .enumerate()
            .map(|(i, &g)| (g as usize, p.x[i], p.u[i], p.p[i]))
            .collect::<Vec<_>>();
        (own, run.counts(), iterations)
    });
    let mean_iterations = out[0].2 as f64 / steps as f64;
    let migrated: u64 = out.iter().map(|o| o.1.migrated).sum();
    let moving = serial.params.motion == Motion::Lagrangian;
    if moving && ranks > 1 {
        assert!(migrated > 0, "particles change ranks in a moving run");
    }
    let out: Vec<_> = out.into_iter().map(|o| o.0).collect();
    let fluid = serial.particles.role.iter().filter(|r| r.is_real()).count();
    assert_eq!(out.iter().map(|o| o.len()).sum::<usize>(), fluid);
    let pscale = serial
        .particles
        .p
        .iter()
        .fold(0.0f64, |m, v| m.max(v.abs()));
    let (mut dx, mut du, mut dp) = (0.0f64, 0.0f64, 0.0f64);
    let mut seen = vec![false; fluid];
    for (g, x, u, p) in out.into_iter().flatten() {
        assert!(
            !std::mem::replace(&mut seen[g], true),
            "particle {g} owned twice"
        );
        let s = &serial.particles;
        dx = dx.max((x[0] - s.x[g][0]).abs().max((x[1] - s.x[g][1]).abs()));
        du = du.max((u[0] - s.u[g][0]).abs().max((u[1] - s.u[g][1]).abs()));
        dp = dp.max((p - s.p[g]).abs());
    }
    eprintln!(
        "{ranks} ranks, {steps} steps ({:?}, {migrated} migrations): largest position \
         difference {dx:e}, velocity {du:e}, pressure {dp:e} (scale {pscale:e})",
        serial.params.motion
    );
    assert!(dx <= 1e-9, "position difference {dx:e}");
    assert!(du <= 1e-9, "velocity difference {du:e}");
    assert!(dp <= 1e-9 * pscale.max(1.0), "pressure difference {dp:e}");
    mean_iterations
}

#[test]
fn decomposed_particles_step_like_the_whole() {
    for ranks in [1, 4] {
        let _ = check_steps(cavity_sim, ranks, 20);
        let _ = check_steps(vortex_sim, ranks, 20);
    }
}

#[test]
fn decomposed_moving_particles_step_like_the_whole() {
    for ranks in [1, 4] {
        let _ = check_steps(cavity_moving_sim, ranks, 20);
        let _ = check_steps(vortex_moving_sim, ranks, 20);
        let _ = check_steps(vortex_fickian_sim, ranks, 20);
        let _ = check_steps(dam_break_sim, ranks, 20);
    }
    // issue 18: iterations at 4 ranks at most 1.3x those at 1 rank, also for moving particles;
    // checked at 1.1x, as the preconditioner is meant not to depend on the partition (the
    // periodic vortex's particles wrap across the boundary: with its coarse aggregates cut
    // from wrapped positions it took 1.28x at n = 48, with unwrapped ones 0.98x)
    let one = check_steps(|| vortex_moving_n(48), 1, 20);
    let four = check_steps(|| vortex_moving_n(48), 4, 20);
    eprintln!("moving vortex: {one} CG iterations per step on 1 rank, {four} on 4");
    assert!(
        four <= 1.3 * one,
        "{four} iterations on 4 ranks, {one} on 1"
    );
}

/// The implicit viscous solve of a decomposed run stops at the viscous tolerance
/// (`SolveParams::viscous_tol`: `10⁻¹²` here), as one process does, not at the pressure's
/// `rel_tol` (`10⁻⁸` here) — until 2026-12-01 the external solver was handed the Poisson
/// solve's tolerance. Checked on the moving vortex at 4 ranks against the single process:
/// each step's viscous solve reaches `10⁻¹²` in its true residual and takes the single
/// process's iterations within one per component (the same Jacobi-CG, summed in another
/// order) where that one iterates too; the Poisson solve keeps `10⁻⁸`.
#[test]
fn decomposed_viscous_solves_stop_at_the_viscous_tolerance() {
    let build = || {
        let mut s = vortex_moving_sim();
        s.params.projection.solve.rel_tol = 1e-8;
        // the tight tolerance on every step (the adaptive rule is the next test's)
        s.params.projection.solve.viscous_adaptive = false;
        s
    };
    let solve = build().params.projection.solve;
    let tol = solve.viscous_tol();
    assert_eq!((tol, solve.rel_tol), (1e-12, 1e-8));
    let (want, got) = one_process_and_four_ranks(build, 8);
    let mut compared = 0;
    for (k, (w, r)) in want.iter().zip(&got[0]).enumerate() {
        let (w, v, p) = (w.viscous.unwrap(), r.viscous.unwrap(), r.solve);
        assert_eq!((v.rel_tol, p.rel_tol), (tol, 1e-8), "step {k}");
        assert!(
            v.rel_residual <= 2.0 * tol,
            "step {k}: viscous residual {:e} against {tol:e} (single process {:e})",
            v.rel_residual,
            w.rel_residual
        );
        if w.solver == SolverKind::Cg {
            compared += 1;
            assert!(
                v.iters.abs_diff(w.iters) <= 2,
                "step {k}: viscous iterations {} on 4 ranks, {} in one process",
                v.iters,
                w.iters
            );
        }
    }
    // one process factorises the first steps' systems (Auto), then iterates
    assert!(compared >= 4, "{compared} steps by CG in one process");
}

/// `steps` steps of `build()` in one process and decomposed over 4 thread ranks: every step's
/// projection report, the one process's and each rank's.
fn one_process_and_four_ranks(
    build: impl Fn() -> Simulation<2, gpm::boundary::PeriodicBox<2>> + Sync,
    steps: usize,
) -> (Vec<StepReport>, Vec<Vec<StepReport>>) {
    use gpm::distributed::decomposed::DecomposedRun;
    let mut serial = build();
    let one = (0..steps)
        .map(|_| serial.advance().unwrap().projection)
        .collect();
    let ranks = ThreadComm::run(4, |comm| {
        let mut run = DecomposedRun::new(comm, &build()).unwrap();
        (0..steps)
            .map(|_| run.advance().unwrap().projection)
            .collect::<Vec<_>>()
    });
    (one, ranks)
}

/// The adaptive viscous tolerance ([`gpm::poisson::SolveParams::viscous_adaptive`]) in a
/// decomposed run: every rank takes the next viscous solve's tolerance from the global sums
/// (the largest gain bound over the ranks' own rows, `‖∇̂h·u*‖` and `‖u*‖` summed, the global
/// warm-start residual), so the ranks stop their distributed viscous CG at the same tolerance,
/// loosen it as one process does (iterative solves in both, so that both have a warm-start
/// residual to read), and reach it. The pressure's tolerance is a loose 10⁻³, so that the
/// candidate (10⁻⁴–10⁻⁶ on this flow) lies between its clamps and is what is compared. Without
/// the global candidate a rank keeps the tight tolerance on every step.
#[test]
fn decomposed_runs_loosen_the_viscous_tolerance_as_one_process_does() {
    let build = || {
        let mut s = vortex_moving_sim();
        s.params.projection.solve.rel_tol = 1e-3;
        s.params.projection.solve.solver = SolverKind::Cg;
        assert!(
            s.params.projection.solve.viscous_adaptive,
            "the rule is on by default"
        );
        s
    };
    let solve = build().params.projection.solve;
    let tight = solve.viscous_tol();
    let steps = 30;
    let (want, got) = one_process_and_four_ranks(build, steps);
    let viscous = |r: &StepReport| r.viscous.expect("an implicit viscous solve");
    for (rank, reports) in got.iter().enumerate() {
        for (k, (r, r0)) in reports.iter().zip(&got[0]).enumerate() {
            let (v, v0) = (viscous(r), viscous(r0));
            assert_eq!(
                v.rel_tol, v0.rel_tol,
                "step {k}: rank {rank} against rank 0"
            );
        }
    }
    let mut loosened = 0;
    for (k, (w, v)) in want.iter().zip(&got[0]).enumerate() {
        let (w, v) = (viscous(w), viscous(v));
        assert!(
            (tight..=solve.rel_tol).contains(&v.rel_tol),
            "step {k}: viscous tolerance {:e} outside [{tight:e}, {:e}]",
            v.rel_tol,
            solve.rel_tol
        );
        assert!(
            v.rel_residual <= 2.0 * v.rel_tol,
            "step {k}: viscous residual {:e} against its tolerance {:e}",
            v.rel_residual,
            v.rel_tol
        );
        // the same rule on the same flow: the warm-start residuals differ as the two runs'
        // pressures do, within the Poisson solves' tolerance
        let ratio = v.rel_tol / w.rel_tol;
        assert!(
            (0.5..=2.0).contains(&ratio),
            "step {k}: viscous tolerance {:e} on 4 ranks, {:e} in one process",
            v.rel_tol,
            w.rel_tol
        );
        if v.rel_tol > 1e3 * tight && v.rel_tol < solve.rel_tol {
            loosened += 1;
        }
    }
    assert!(
        loosened >= steps / 2,
        "loosened within the clamps on {loosened} of {steps} steps"
    );
}

/// The Poisson solve's warm-start factor ([`gpm::poisson::SolveParams::warm_tol`]) in a
/// decomposed run: the distributed CG takes it with the global residuals, so every rank stops
/// at the same tolerance, `max(rel_tol, θρ)` with `ρ ≤ 0.1` the global warm-start residual
/// (`rel_tol` above), as one process (CG in both) does on the same flow, and its true residual
/// meets it. The moving vortex at n = 40: its warm start leaves 0.1–0.3 of the source up to
/// step ≈ 33 and 0.06–0.1 after (measured: 28 of 60 steps loosened in both runs); where the two
/// runs' `ρ` lie on the same side of 0.1 their tolerances agree within a factor of 2.
#[test]
fn decomposed_runs_stop_the_poisson_solve_at_the_warm_start_factor_as_one_process_does() {
    let theta = 1e-3;
    let build = || {
        let mut s = vortex_moving_n(40);
        s.params.projection.solve.solver = SolverKind::Cg;
        s.params.projection.solve.warm_tol = theta;
        s
    };
    let rel_tol = build().params.projection.solve.rel_tol;
    let steps = 60;
    let (want, got) = one_process_and_four_ranks(build, steps);
    for (rank, reports) in got.iter().enumerate() {
        for (k, (r, r0)) in reports.iter().zip(&got[0]).enumerate() {
            assert_eq!(
                r.solve.rel_tol, r0.solve.rel_tol,
                "step {k}: rank {rank} against rank 0"
            );
        }
    }
    // each run by the rule, with its own warm-start residual
    let by_the_rule = |reports: &[StepReport], who: &str| {
        let loosened =
            common::assert_warm_start_rule(reports.iter().map(|r| &r.solve), rel_tol, theta, who);
        assert!(
            loosened >= steps / 3,
            "{who}: loosened on {loosened} of {steps} steps"
        );
    };
    by_the_rule(&got[0], "4 ranks");
    by_the_rule(&want, "one process");
    // the same flow: where both warm starts are on the same side of the rule's threshold
    // (the two runs' pressures differ by the loosened tolerances, and so do their `ρ`), the
    // same tolerance within a factor of 2
    for (k, (w, v)) in want.iter().zip(&got[0]).enumerate() {
        let (w, v) = (&w.solve, &v.solve);
        if (v.initial_rel_residual <= 0.1) == (w.initial_rel_residual <= 0.1) {
            let ratio = v.rel_tol / w.rel_tol;
            assert!(
                (0.5..=2.0).contains(&ratio),
                "step {k}: tolerance {:e} on 4 ranks, {:e} in one process",
                v.rel_tol,
                w.rel_tol
            );
        }
    }
}

/// `gpm run` under `mpirun` for every scene: the scene run through [`Decomposed`] (its
/// particles cut over thread ranks, rank 0's copy gathered after every step) reports what the
/// single-process run reports — every number of its summary, the final particles, and every
/// step's diagnostics.
struct CompareDecomposed {
    ranks: usize,
    steps: u64,
    motion: Option<Motion>,
    /// Run to this end time instead (a scene that lands on it shortens its last step).
    t_end: Option<f64>,
}

/// Numbers of two summaries: equal to `tol` relative (wall-clock fields skipped).
fn same_numbers(a: &serde_json::Value, b: &serde_json::Value, path: &str, tol: f64) {
    use serde_json::Value;
    match (a, b) {
        (Value::Object(x), Value::Object(y)) => {
            assert_eq!(x.len(), y.len(), "{path}: keys");
            for (k, v) in x {
                if k.contains("seconds") {
                    continue;
                }
                same_numbers(v, &y[k], &format!("{path}.{k}"), tol);
            }
        }
        (Value::Array(x), Value::Array(y)) => {
            assert_eq!(x.len(), y.len(), "{path}: length");
            for (i, (v, w)) in x.iter().zip(y).enumerate() {
                same_numbers(v, w, &format!("{path}[{i}]"), tol);
            }
        }
        (Value::Number(x), Value::Number(y)) => {
            let (x, y) = (x.as_f64().unwrap(), y.as_f64().unwrap());
            assert!(
                (x - y).abs() <= tol * x.abs().max(y.abs()).max(1e-6),
                "{path}: {x} vs {y}"
            );
        }
        _ => assert_eq!(a, b, "{path}"),
    }
}

impl gpm::scene::SceneVisitor for CompareDecomposed {
    type Output = ();
    fn visit<const D: usize, S: gpm::scene::Scene<D>>(self) {
        use gpm::scene::ranks::Decomposed;
        use gpm::scene::{run_scene, run_scene_with, SceneConfig};
        use std::ops::ControlFlow;
        let cfg = SceneConfig::<S>::default().with(|c| {
            c.n = if D == 2 { 16 } else { 8 };
            if let Some(m) = self.motion {
                c.motion = m;
            }
            if let Some(t) = self.t_end {
                c.t_end = t;
            }
        });
        let steps = self.steps;
        let tight = |sim: &mut Simulation<D, S::Boundary>| hold_tight(&mut sim.params);
        // stop after `steps` steps (or at the end time)
        let stop = |step: u64| -> gpm::scene::Observed {
            Ok(if step >= steps {
                ControlFlow::Break(())
            } else {
                ControlFlow::Continue(())
            })
        };
        let mut serial_reports = Vec::new();
        let serial = run_scene(&cfg, tight, |rep, _| {
            serial_reports.push(*rep);
            stop(rep.step)
        })
        .unwrap_or_else(|e| panic!("{}: serial run: {e}", S::NAME));
        // (the configuration travels to the rank threads as text: a scene type need not be Sync)
        let text = serde_json::to_string(&cfg).unwrap();
        let out = ThreadComm::run(self.ranks, |comm| {
            let cfg: SceneConfig<S> = gpm::scene::scene_config_from_json(&text).unwrap();
            let mut stepper = Decomposed::new(comm, 0);
            let root = stepper.is_root();
            let mut reports = Vec::new();
            let run = run_scene_with(&cfg, &mut stepper, tight, |rep, _| {
                reports.push(*rep);
                stop(rep.step)
            })
            .unwrap_or_else(|e| panic!("{}: decomposed run: {e}", S::NAME));
            root.then(|| {
                let summary = serde_json::to_value(run.summary(&cfg)).unwrap();
                let p = &run.sim.particles;
                let real: Vec<_> = (0..p.len())
                    .filter(|&i| p.role[i].is_real())
                    .map(|i| (p.x[i], p.u[i], p.p[i]))
                    .collect();
                (summary, real, reports, run.end)
            })
        });
        let (summary, real, reports, end) = out.into_iter().flatten().next().unwrap();
        let name = S::NAME;
        assert_eq!(end, serial.end, "{name}: end");
        assert_eq!(reports.len(), serial_reports.len(), "{name}: steps");
        for (r, s) in reports.iter().zip(&serial_reports) {
            let k = r.step;
            let (a, b) = (&r.projection, &s.projection);
            assert_eq!(a.connectivity, b.connectivity, "{name} step {k}");
            assert_eq!(a.solve.unknowns, b.solve.unknowns, "{name} step {k}");
            // (the matrix's stored entries include pairs between h and h + skin, with weight
            // zero, which depend on when the neighbour candidates were last searched: a
            // moving rank searches every step)
            if cfg.motion == Motion::Eulerian {
                assert_eq!(a.solve.nnz, b.solve.nnz, "{name} step {k}");
            }
            assert_eq!(a.disconnected, b.disconnected, "{name} step {k}");
            assert_eq!(r.dt_limit, s.dt_limit, "{name} step {k}");
            assert_eq!(r.surface, s.surface, "{name} step {k}");
            assert_eq!(r.wall_pushes, s.wall_pushes, "{name} step {k}");
            let close = |what: &str, x: f64, y: f64, tol: f64| {
                assert!(
                    (x - y).abs() <= tol * x.abs().max(y.abs()).max(1e-300),
                    "{name} step {k}: {what} {x:e} vs {y:e}"
                );
            };
            close("dt", a.dt, b.dt, 1e-12);
            assert!(
                (r.max_shift - s.max_shift).abs() <= 1e-9 * s.max_shift.max(1e-3),
                "{name} step {k}: shift {:e} vs {:e}",
                r.max_shift,
                s.max_shift
            );
            let growth = |g: Option<f64>| g.unwrap_or(-1.0);
            close(
                "energy growth",
                growth(r.energy_growth),
                growth(s.energy_growth),
                1e-9,
            );
            close("c0", a.c0, b.c0, 1e-12);
            close("min spacing", a.min_spacing, b.min_spacing, 1e-9);
            close("kinetic energy", a.kinetic_energy, b.kinetic_energy, 1e-9);
            close("max speed", a.max_speed, b.max_speed, 1e-9);
            // (a divergence at round-off, 1e-16, is compared with an absolute floor)
            assert!(
                (a.div_before - b.div_before).abs() <= 1e-6 * b.div_before + 1e-12,
                "{name} step {k}: div before {:e} vs {:e}",
                a.div_before,
                b.div_before
            );
            // after the projection the divergence is the solver's residual: compared with
            // the size of the step's divergence before
            assert!(
                (a.div_after - b.div_after).abs() <= 1e-6 * b.div_before + 1e-12,
                "{name} step {k}: div after {:e} vs {:e}",
                a.div_after,
                b.div_after
            );
            // (the ratio of a flow without divergence is round-off: an absolute floor)
            assert!(
                (a.stability_ratio - b.stability_ratio).abs() <= 1e-6 * b.stability_ratio + 1e-12,
                "{name} step {k}: Theorem 4.5 ratio {:e} vs {:e}",
                a.stability_ratio,
                b.stability_ratio
            );
        }
        let s = &serial.sim.particles;
        let sreal: Vec<usize> = (0..s.len()).filter(|&i| s.role[i].is_real()).collect();
        assert_eq!(real.len(), sreal.len(), "{name}: real particles");
        let (mut dx, mut du) = (0.0f64, 0.0f64);
        for ((x, u, _), &i) in real.iter().zip(&sreal) {
            for a in 0..D {
                dx = dx.max((x[a] - s.x[i][a]).abs());
                du = du.max((u[a] - s.u[i][a]).abs());
            }
        }
        eprintln!(
            "{name} ({:?}) on {} ranks, {} steps: position difference {dx:e}, velocity {du:e}",
            cfg.motion,
            self.ranks,
            reports.len()
        );
        assert!(dx <= 1e-9 && du <= 1e-9, "{name}: {dx:e} {du:e}");
        let expected = serde_json::to_value(serial.summary(&cfg)).unwrap();
        same_numbers(&summary, &expected, name, 1e-7);
    }
}

#[test]
fn every_scene_runs_decomposed_like_one_process() {
    for &name in gpm::scene::SCENES {
        gpm::scene::visit_scene(
            name,
            CompareDecomposed {
                ranks: std::env::var("GPM_RANKS").map_or(3, |v| v.parse().unwrap()),
                steps: std::env::var("GPM_STEPS").map_or(8, |v| v.parse().unwrap()),
                motion: None,
                t_end: None,
            },
        )
        .unwrap();
    }
    for name in ["cavity", "taylor_green", "channel"] {
        gpm::scene::visit_scene(
            name,
            CompareDecomposed {
                ranks: 2,
                steps: 8,
                motion: Some(Motion::Lagrangian),
                t_end: None,
            },
        )
        .unwrap();
    }
    // to the end time: the dam break's last step is shortened to land on it
    for name in ["dam_break", "taylor_green"] {
        gpm::scene::visit_scene(
            name,
            CompareDecomposed {
                ranks: 2,
                steps: u64::MAX,
                motion: None,
                t_end: Some(0.1),
            },
        )
        .unwrap();
    }
}

/// A cavity with the lid corners' singular part subtracted is refused by the particle
/// decomposition (its local simulations would run without it), naming the key.
#[test]
fn the_decomposition_refuses_a_subtracted_corner_singularity() {
    let cfg = cavity::CavityConfig {
        flow: gpm::scene::FlowConfig {
            n: 16,
            re: 1000.0,
            ..cavity::CavityConfig::default().flow
        },
        scene: cavity::Cavity {
            corner_subtraction: true,
            ..Default::default()
        },
    };
    assert_decomposition_refuses(&cfg, &["corner_subtraction"]);
}

/// Two ranks decompose the cavity `cfg`: every rank's `DecomposedRun::new` errs, naming `keys`.
fn assert_decomposition_refuses(cfg: &cavity::CavityConfig, keys: &[&str]) {
    use gpm::distributed::decomposed::DecomposedRun;
    let errors = ThreadComm::run(2, |comm| {
        let global = cavity::build(cfg).unwrap();
        DecomposedRun::new(comm, &global)
            .err()
            .map(|e| e.to_string())
    });
    for e in errors {
        let e = e.expect("refused");
        assert!(keys.iter().all(|k| e.contains(k)), "{e}");
    }
}

/// A cavity with the rest-walls-linear source rule is refused by the particle decomposition
/// (a rank does not hold every source's wall-normal partner), naming the key.
#[test]
fn the_decomposition_refuses_the_linear_lid_rule() {
    let cfg = cavity::CavityConfig {
        flow: gpm::scene::FlowConfig {
            n: 16,
            ..cavity::CavityConfig::default().flow
        },
        scene: cavity::Cavity {
            source_ghosts: cavity::SourceGhosts::RestWallsLinear,
            ..Default::default()
        },
    };
    assert_decomposition_refuses(&cfg, &["source_ghosts", "rest_walls_linear"]);
}
