//! AMG-preconditioned CG against Jacobi-CG and sparse Cholesky on GPM Poisson matrices.
//!
//! Systems: a lattice (optionally jittered) over the unit square/cube with `h = 3Δx`,
//! number-density volumes, and either a Dirichlet band (anchored, SPD) or mirror-image ghosts
//! across closed walls (floating: pure Neumann, singular). Right side: the sum-form divergence of
//! `f = −∇u`, `u = Π sin²(π x_a)` (the manufactured problem of `examples/poisson.rs`).
//!
//! ```text
//! cargo run --release --example amg_study -- --d2 100,316,1000 --d3 46 --solvers amg,cg,cholesky
//! ```
//! prints one row per (system, solver): unknowns, stored entries, neighbour-list and assembly
//! seconds, setup seconds (AMG hierarchy or Cholesky symbolic + numeric), iterations, solve
//! seconds, total, AMG levels and operator complexity, relative residual. With `--reuse` it also
//! times a second and third solve on perturbed values (rebuild / values-only refresh / lag).

use anyhow::{Context, Result};
use clap::Parser;
use gpm::boundary::{Boundary, Walls};
use gpm::diagnostics::{connectivity, Components};
use gpm::geometry::{jitter, lattice, number_density_volumes};
use gpm::kernel::Weight;
use gpm::neighbors::{NeighborConfig, NeighborList};
use gpm::operators::div_sum;
use gpm::particles::{Particles, Role};
use gpm::poisson::{PoissonSolver, SolveInfo, SolveParams, SolverKind};
use gpm::scene::manufactured::{exact, BandProblem, BandSpec};
use std::time::Instant;

#[derive(Parser, Debug)]
#[command(about = "AMG-CG vs Jacobi-CG vs Cholesky on GPM Poisson matrices")]
struct Args {
    /// 2D sizes: particles per side.
    #[arg(long, value_delimiter = ',', default_value = "100,316")]
    d2: Vec<usize>,
    /// 3D sizes: particles per side.
    #[arg(long, value_delimiter = ',')]
    d3: Vec<usize>,
    /// Solvers to run (amg, cg, cholesky).
    #[arg(long, value_delimiter = ',', default_value = "amg,cg,cholesky")]
    solvers: Vec<SolverKind>,
    /// Boundary: band (Dirichlet band, SPD) or mirror (mirror ghosts, floating).
    #[arg(long, default_value = "band")]
    boundary: String,
    /// h / Δx.
    #[arg(long, default_value_t = 3.0)]
    h_over_dx: f64,
    /// Jitter amplitude as a fraction of Δx.
    #[arg(long, default_value_t = 0.0)]
    jitter: f64,
    /// CG relative tolerance.
    #[arg(long, default_value_t = 1e-8)]
    rel_tol: f64,
    /// AMG strength threshold θ.
    #[arg(long)]
    theta: Option<f64>,
    /// AMG coarsest size.
    #[arg(long)]
    coarse_size: Option<usize>,
    /// AMG Jacobi sweeps.
    #[arg(long)]
    sweeps: Option<usize>,
    /// AMG smoother weight ω ρ.
    #[arg(long)]
    smoother_weight: Option<f64>,
    /// AMG levels with additive correction.
    #[arg(long)]
    additive: Option<usize>,
    /// AMG prolongator smoothing with the filtered matrix.
    #[arg(long)]
    filter: Option<bool>,
    /// Also time solves after a change of values: full rebuild, values-only refresh, lag.
    #[arg(long)]
    reuse: bool,
    /// Time the kernels (fine SpMV, one V-cycle with the values in `f32` and in `f64`), best
    /// of 10.
    #[arg(long)]
    kernels: bool,
    /// Repeat each cold solve this many times and report the fastest (shared machine).
    #[arg(long, default_value_t = 1)]
    repeat: usize,
}

/// A system ready to solve.
struct System<const D: usize> {
    nl: NeighborList<D>,
    vol: Vec<f64>,
    role: Vec<Role>,
    comps: Components,
    rhs: Vec<f64>,
    setup_seconds: f64,
}

fn system<const D: usize>(n: usize, args: &Args) -> Result<System<D>> {
    let dx = 1.0 / n as f64;
    let h = args.h_over_dx * dx;
    let t = Instant::now();
    if args.boundary == "mirror" {
        let mut x = lattice([0.0; D], [1.0; D], dx);
        if args.jitter > 0.0 {
            jitter(&mut x, args.jitter * dx, 7 ^ n as u64);
        }
        let walls = Walls::closed_box([0.0; D], [1.0; D]);
        let mut p = Particles::<D>::new();
        for xi in &x {
            p.push(*xi, [0.0; D], 0.0, dx.powi(D as i32), Role::Fluid);
        }
        let n_fluid = p.len();
        walls.make_ghosts(&mut p, h);
        let nl = NeighborList::build(NeighborConfig::new(Weight::WendlandC2, h, 0.0), &p.x)?;
        let vol = number_density_volumes(&nl);
        p.vol[..n_fluid].copy_from_slice(&vol[..n_fluid]);
        walls.place_ghosts(&mut p);
        let (x, role, vol) = (p.x, p.role, p.vol);
        let setup_seconds = t.elapsed().as_secs_f64();
        let comps = connectivity(&nl, &role);
        // the mirror walls' source: the manufactured problem's f = −∇u on the fluid
        let f: Vec<[f64; D]> = x
            .iter()
            .zip(&role)
            .map(|(p, r)| {
                if r.is_fluid() {
                    exact(p).1.map(|v| -v)
                } else {
                    [0.0; D]
                }
            })
            .collect();
        let rhs = div_sum(&nl, &vol, &f);
        Ok(System {
            nl,
            vol,
            role,
            comps,
            rhs,
            setup_seconds,
        })
    } else {
        // the Dirichlet band: the library's manufactured problem
        let spec = BandSpec::new(n, args.h_over_dx).jittered(args.jitter, 7 ^ n as u64);
        let p = BandProblem::<D>::build(&spec)?;
        Ok(System {
            nl: p.nl,
            vol: p.vol,
            role: p.role,
            comps: p.comps,
            rhs: p.rhs,
            setup_seconds: p.setup_seconds,
        })
    }
}

fn params(kind: SolverKind, args: &Args) -> SolveParams {
    SolveParams {
        solver: kind,
        rel_tol: args.rel_tol,
        warm_start: false,
        max_iters: 20_000,
        ..Default::default()
    }
}

fn new_solver(args: &Args) -> PoissonSolver {
    let mut s = PoissonSolver::new();
    if let Some(t) = args.theta {
        s.amg.params.theta = t;
    }
    if let Some(c) = args.coarse_size {
        s.amg.params.coarse_size = c;
    }
    if let Some(w) = args.sweeps {
        s.amg.params.sweeps = w;
    }
    if let Some(w) = args.smoother_weight {
        s.amg.params.smoother_weight = w;
    }
    if let Some(w) = args.additive {
        s.amg.params.additive_levels = w;
    }
    if let Some(w) = args.filter {
        s.amg.params.filter = w;
    }
    s
}

fn row(label: &str, d: usize, sys_s: f64, info: &SolveInfo, total: f64) {
    let setup = info.amg_setup_seconds + info.symbolic_seconds + info.numeric_seconds;
    println!(
        "{label:<10} {d:>2} {:>9} {:>10} {:>8} {:>8.3} {:>8.3} {:>8.3} {:>6} {:>8.3} {:>8.3} {:>4} {:>6.3} {:>9.2e}",
        info.solver.to_string(),
        info.unknowns,
        info.nnz,
        sys_s,
        info.assemble_seconds,
        setup,
        info.iters,
        info.solve_seconds,
        total,
        info.amg_levels,
        info.amg_operator_complexity,
        info.rel_residual
    );
}

fn run<const D: usize>(n: usize, args: &Args) -> Result<()> {
    let s = system::<D>(n, args)?;
    let label = format!(
        "{}{}",
        args.boundary,
        if args.jitter > 0.0 { "-j" } else { "" }
    );
    for &kind in &args.solvers {
        let p = params(kind, args);
        // best of `repeat` cold solves (each with a new solver: full setup), the machine is shared
        let mut best: Option<(f64, SolveInfo, PoissonSolver)> = None;
        for _ in 0..args.repeat.max(1) {
            let mut solver = new_solver(args);
            let mut phi = vec![0.0; s.rhs.len()];
            let t = Instant::now();
            let info = solver
                .solve(&s.nl, &s.vol, &s.role, &s.comps, &s.rhs, &mut phi, &p)
                .with_context(|| format!("{kind} solve, n = {n}, d = {D}"))?;
            let total = t.elapsed().as_secs_f64();
            if best.as_ref().is_none_or(|b| total < b.0) {
                best = Some((total, info, solver));
            }
        }
        let (total, info, mut solver) = best.expect("at least one run");
        row(&label, D, s.setup_seconds, &info, total);
        if let Some(h) = solver.amg.hierarchy().filter(|_| kind == SolverKind::Amg) {
            let st = h.stats();
            let t = st.times;
            println!(
                "           setup phases: aggregate {:.3} spectral {:.3} prolongator {:.3} galerkin {:.3} coarse {:.3}; sizes {:?} nnz {:?} P nnz {:?} pinned {}",
                t.aggregate, t.spectral, t.prolongator, t.galerkin, t.coarse, st.sizes, st.nnz, st.p_nnz, st.coarse_pinned
            );
        }
        if let (true, SolverKind::Amg) = (args.kernels, kind) {
            kernels(&mut solver);
        }
        if let (true, SolverKind::Amg) = (args.reuse, kind) {
            reuse_rows(&s, args, &mut solver, &p)?;
        }
    }
    Ok(())
}

/// Second solves on values scaled by a smooth factor (pair data unchanged, volumes changed):
/// each reuse mode on its own solver primed with the original values.
fn reuse_rows<const D: usize>(
    s: &System<D>,
    args: &Args,
    _primed: &mut PoissonSolver,
    p: &SolveParams,
) -> Result<()> {
    let vol2: Vec<f64> = s
        .vol
        .iter()
        .enumerate()
        .map(|(i, v)| v * (1.0 + 0.05 * ((i % 97) as f64 / 97.0)))
        .collect();
    let modes: [(&str, bool, bool); 3] = [
        ("rebuild", false, false),
        ("refresh", true, false),
        ("lag", true, true),
    ];
    for (name, values, lag) in modes {
        let mut solver = new_solver(args);
        let mut phi = vec![0.0; s.rhs.len()];
        let q = SolveParams {
            amg_reuse_values: values,
            amg_lag: lag,
            ..*p
        };
        solver.solve(&s.nl, &s.vol, &s.role, &s.comps, &s.rhs, &mut phi, &q)?;
        let t = Instant::now();
        let info = solver.solve(&s.nl, &vol2, &s.role, &s.comps, &s.rhs, &mut phi, &q)?;
        let total = t.elapsed().as_secs_f64();
        row(
            &format!("  {name}:{:?}", info.amg_setup),
            D,
            0.0,
            &info,
            total,
        );
    }
    Ok(())
}

/// Best-of-10 seconds of a fine-level product `K x` and of one V-cycle.
fn kernels(solver: &mut PoissonSolver) {
    let a = &solver.assembly;
    let n = a.n();
    let x: Vec<f64> = (0..n)
        .map(|i| ((i * 7919) % 1000) as f64 / 1000.0)
        .collect();
    let mut y = vec![0.0; n];
    let best = |f: &mut dyn FnMut()| {
        (0..10)
            .map(|_| {
                let t = Instant::now();
                f();
                t.elapsed().as_secs_f64()
            })
            .fold(f64::INFINITY, f64::min)
    };
    let spmv = best(&mut || a.spmv(&x, &mut y));
    let m = gpm::poisson::amg::CsrRef::from(a);
    let amg = solver.amg.hierarchy_mut().expect("hierarchy");
    let vc = best(&mut || amg.vcycle(m, &x, &mut y));
    // the same hierarchy with the V-cycle's values in the other precision
    let single = amg.params().single_precision;
    let mut other = gpm::poisson::Amg::build(
        m,
        gpm::poisson::AmgParams {
            single_precision: !single,
            ..*amg.params()
        },
    );
    let vc_other = best(&mut || other.vcycle(m, &x, &mut y));
    let (vc32, vc64) = if single {
        (vc, vc_other)
    } else {
        (vc_other, vc)
    };
    let mut refresh = f64::INFINITY;
    for _ in 0..5 {
        amg.refresh(m);
        refresh = refresh.min(amg.stats().setup_seconds);
    }
    let t = amg.stats().times;
    println!(
        "           refresh (values only) {:.3} s: galerkin {:.3} spectral {:.3} coarse {:.3}",
        refresh, t.galerkin, t.spectral, t.coarse
    );
    println!(
        "           kernels: K x {:.2} ms, V-cycle {:.2} ms ({:.2} products; values in f32 {:.2} ms, in f64 {:.2} ms)",
        spmv * 1e3,
        vc * 1e3,
        vc / spmv,
        vc32 * 1e3,
        vc64 * 1e3
    );
}

fn main() -> Result<()> {
    let args = Args::parse();
    println!(
        "boundary={} h/dx={} jitter={} rel_tol={:e} threads={}",
        args.boundary,
        args.h_over_dx,
        args.jitter,
        args.rel_tol,
        rayon::current_num_threads()
    );
    println!(
        "{:<10} {:>2} {:>9} {:>10} {:>8} {:>8} {:>8} {:>8} {:>6} {:>8} {:>8} {:>4} {:>6} {:>9}",
        "system",
        "d",
        "solver",
        "unknowns",
        "nnz",
        "nlist_s",
        "assem_s",
        "setup_s",
        "iters",
        "solve_s",
        "total_s",
        "lev",
        "opcx",
        "rel_res"
    );
    for &n in &args.d2 {
        run::<2>(n, &args)?;
    }
    for &n in &args.d3 {
        run::<3>(n, &args)?;
    }
    Ok(())
}
