//! A moving (Lagrangian) step allocates no memory once its buffers have grown: every step
//! without an AMG rebuild — those that search the neighbour candidates again included — is
//! counted by a counting global allocator and must allocate nothing (issue 17: no allocation
//! in the step's hot path). A fixed-particle (Eulerian) step, with its convective term, too.
//! One test only: the allocator counts every thread of this test binary.

use gpm::boundary::PeriodicBox;
use gpm::flow::{FlowParams, Integrator, Motion, Simulation, TimeStepLimits, VolumeRule};
use gpm::geometry::lattice;
use gpm::kernel::Weight;
use gpm::neighbors::{NeighborConfig, Periodicity};
use gpm::particles::{Particles, Role};
use gpm::poisson::amg::AmgSetup;
use gpm::poisson::SolverKind;
use gpm::projection::{ProjectionParams, Scheme};
use std::alloc::{GlobalAlloc, Layout, System};
use std::f64::consts::PI;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};

struct Counting;
static COUNTING: AtomicBool = AtomicBool::new(false);
static COUNT: AtomicUsize = AtomicUsize::new(0);

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        if COUNTING.load(Ordering::Relaxed) {
            COUNT.fetch_add(1, Ordering::Relaxed);
        }
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, size: usize) -> *mut u8 {
        if COUNTING.load(Ordering::Relaxed) {
            COUNT.fetch_add(1, Ordering::Relaxed);
        }
        unsafe { System.realloc(ptr, layout, size) }
    }
}

#[global_allocator]
static ALLOCATOR: Counting = Counting;

/// The Taylor–Green vortex of the bench's cases (periodic box, number-density volumes, the
/// default reuse switches, implicit viscosity), `side²` particles; Lagrangian (the moving
/// case) or Eulerian (fixed particles, the skew-symmetric convective term with AB2).
fn taylor_green(side: usize, solver: SolverKind, motion: Motion) -> Simulation<2, PeriodicBox<2>> {
    let dx = 1.0 / side as f64;
    let mut p = Particles::<2>::new();
    for x in lattice([0.0; 2], [1.0; 2], dx) {
        let (s0, c0) = (2.0 * PI * x[0]).sin_cos();
        let (s1, c1) = (2.0 * PI * x[1]).sin_cos();
        p.push(x, [-c0 * s1, s0 * c1], 0.0, dx * dx, Role::Fluid);
    }
    let mut projection = ProjectionParams::<2>::new(0.01);
    projection.scheme = Scheme::Rotational;
    projection.solve.solver = solver;
    projection.solve.rel_tol = 1e-8;
    let params = FlowParams {
        projection,
        limits: TimeStepLimits {
            dt_fixed: Some(0.1 * dx),
            ..Default::default()
        },
        motion,
        integrator: Integrator::Ab2,
        convection: Default::default(),
        shifting: None,
        volumes: VolumeRule::NumberDensity,
        pair_weights: Default::default(),
        dx,
    };
    let config = NeighborConfig::new_relative(Weight::WendlandC2, dx, 3.0, 0.3);
    let periodic = Periodicity::all([0.0; 2], [1.0; 2]);
    Simulation::new(p, PeriodicBox { periodic }, config, params).expect("simulation")
}

#[test]
fn a_moving_step_allocates_nothing() {
    // the steps run on a thread of rayon's pool, as a solver's own loop in `rayon::scope` or
    // `ThreadPool::install` does: a step called from outside the pool is sent to it as a job,
    // and rayon's injector queue allocates a block of job slots once every 63 such calls
    // (crossbeam-deque's `Injector`), which is rayon's, not the step's
    rayon::scope(|_| counted_steps());
}

fn counted_steps() {
    for (solver, motion) in [
        (SolverKind::Amg, Motion::Lagrangian),
        (SolverKind::Cg, Motion::Lagrangian),
        (SolverKind::Amg, Motion::Eulerian),
    ] {
        let mut sim = taylor_green(60, solver, motion);
        for _ in 0..10 {
            sim.advance().expect("warm-up step");
        }
        let (mut quiet, mut searched) = (0, 0);
        for step in 0..30 {
            COUNT.store(0, Ordering::Relaxed);
            COUNTING.store(true, Ordering::Relaxed);
            let r = sim.advance();
            COUNTING.store(false, Ordering::Relaxed);
            let r = r.expect("step");
            let count = COUNT.load(Ordering::Relaxed);
            // the Poisson or the viscous solve's hierarchy built anew (the AMG lag policy)
            let rebuilt = [
                r.projection.solve.amg_setup,
                r.projection.viscous.unwrap_or_default().amg_setup,
            ]
            .iter()
            .any(|s| matches!(s, AmgSetup::Rebuilt | AmgSetup::Refreshed));
            if rebuilt {
                continue;
            }
            searched += r.neighbors_rebuilt as usize;
            quiet += 1;
            assert_eq!(
                count, 0,
                "{solver:?} {motion:?}: step {step} (search: {}, no AMG rebuild) made {count} \
                 allocations",
                r.neighbors_rebuilt
            );
        }
        // moving particles: some steps search again, most do not; fixed ones never search
        let searches_ok = match motion {
            Motion::Lagrangian => searched > 0,
            Motion::Eulerian => searched == 0,
        };
        assert!(
            searches_ok && quiet >= 15,
            "{solver:?} {motion:?}: {searched} searches, {quiet} quiet steps"
        );
    }
}
