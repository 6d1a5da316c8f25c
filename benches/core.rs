//! Criterion benchmarks of the core: neighbour search, matrix assembly, Cholesky (symbolic,
//! numeric and triangular solve separately) and Jacobi-PCG, at N = 10⁴ and 10⁵ in 2D and 3·10⁴
//! in 3D (cell-centred lattices of the unit box with a Dirichlet band of thickness ≥ h, h = 3Δx,
//! Wendland C2).
//!
//! ```text
//! cargo bench --bench core                     # everything
//! cargo bench --bench core -- 2d_1e4           # one size
//! ```
//!
//! The Cholesky phases are measured through `Direct::solve` with its reuse switches:
//! `full` = symbolic + numeric + solve, `numeric` = numeric + solve (symbolic reused),
//! `solve` = triangular solves only (factor reused); the symbolic and numeric costs are the
//! differences.

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use gpm::neighbors::{NeighborConfig, NeighborList, Search};
use gpm::particles::Role;
use gpm::poisson::iterative::pcg;
use gpm::poisson::{Assembly, Direct};
use gpm::scene::manufactured::{BandProblem, BandSpec};
use std::time::Duration;

struct Problem<const D: usize> {
    x: Vec<[f64; D]>,
    config: NeighborConfig<D>,
    nl: NeighborList<D>,
    vol: Vec<f64>,
    role: Vec<Role>,
}

/// The manufactured Dirichlet-band problem of the library (`scene::manufactured`): the unit box
/// with a band of thickness ≥ h, h = 3Δx, number-density volumes.
fn problem<const D: usize>(side: usize) -> Problem<D> {
    let b = BandProblem::<D>::build(&BandSpec::new(side, 3.0)).expect("finite lattice");
    assert!(b.comps.is_h_connected());
    Problem {
        config: *b.nl.config(),
        x: b.x,
        nl: b.nl,
        vol: b.vol,
        role: b.role,
    }
}

fn bench_size<const D: usize>(c: &mut Criterion, name: &str, side: usize, direct: bool) {
    let p = problem::<D>(side);
    let mut g = c.benchmark_group(name);
    g.sample_size(10)
        .warm_up_time(Duration::from_millis(500))
        .measurement_time(Duration::from_secs(3));
    for (label, search) in [("grid", Search::CellGrid), ("kdtree", Search::KdTree)] {
        let config = p.config.with_search(search);
        g.bench_function(BenchmarkId::new("neighbors/search", label), |b| {
            b.iter(|| NeighborList::build(config, &p.x).unwrap())
        });
    }
    let mut a = Assembly::default();
    a.update_pattern(&p.nl, &p.role);
    g.bench_function("assembly/pattern", |b| {
        b.iter(|| {
            let mut a = Assembly::default();
            a.update_pattern(&p.nl, &p.role);
            a
        })
    });
    g.bench_function("assembly/values", |b| {
        b.iter(|| a.fill_values(&p.nl, &p.vol, &p.role).unwrap())
    });
    a.fill_values(&p.nl, &p.vol, &p.role).unwrap();
    let n = a.n();
    let rhs: Vec<f64> = (0..n)
        .map(|i| ((i * 7919) % 101) as f64 / 50.0 - 1.0)
        .collect();
    let mut x = vec![0.0; n];
    if direct {
        let mut d = Direct::default();
        g.bench_function(BenchmarkId::new("cholesky", "full"), |b| {
            b.iter(|| d.solve(&a, &[], &rhs, &mut x, false, false).unwrap())
        });
        g.bench_function(BenchmarkId::new("cholesky", "numeric+solve"), |b| {
            b.iter(|| d.solve(&a, &[], &rhs, &mut x, true, false).unwrap())
        });
        g.bench_function(BenchmarkId::new("cholesky", "solve"), |b| {
            b.iter(|| d.solve(&a, &[], &rhs, &mut x, true, true).unwrap())
        });
    }
    g.bench_function(BenchmarkId::new("cg_jacobi", "1e-8"), |b| {
        b.iter(|| {
            x.iter_mut().for_each(|v| *v = 0.0);
            pcg(&a, &rhs, &mut x, 1e-8, 0.0, 100_000).unwrap()
        })
    });
    g.finish();
}

fn core(c: &mut Criterion) {
    bench_size::<2>(c, "2d_1e4", 100, true);
    bench_size::<2>(c, "2d_1e5", 316, true);
    bench_size::<3>(c, "3d_3e4", 31, true);
}

criterion_group!(benches, core);
criterion_main!(benches);
