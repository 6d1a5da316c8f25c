//! The distributed Poisson solve and diagnostics on ranks that are threads of this process
//! (`ThreadComm`): the same solution, connectivity and `c0` as the serial solver, for the
//! closed cavity (one floating component: pure Neumann) and the periodic vortex.

use gpm::boundary::Boundary;
use gpm::diagnostics::{connectivity, semi_regularity, Region};
use gpm::distributed::{global_diagnostics, DdPreconditioner, DistributedRun, ThreadComm};
use gpm::flow::{Motion, Simulation};
use gpm::poisson::{PoissonSolver, SolveParams, SolverKind};
use gpm::scene::{cavity, taylor_green};

/// A smooth right side (its sum need not vanish: the solver projects it).
fn rhs(x: &[[f64; 2]]) -> Vec<f64> {
    x.iter()
        .map(|p| (6.0 * p[0]).sin() * (4.0 * p[1]).cos() + p[0] * p[1])
        .collect()
}

/// Solves on `ranks` thread ranks and compares with the serial Cholesky solve; returns the
/// iterations.
fn check<B: Boundary<2>>(
    build: impl Fn() -> Simulation<2, B> + Sync,
    ranks: usize,
    pre: DdPreconditioner,
) -> usize {
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
