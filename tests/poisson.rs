//! The discrete Poisson problem (MISSION §3, Imoto 2019 Thm 4.1): the assembled matrix is the
//! definition and is SPD exactly when h-connectivity holds; a detached cluster is reported with
//! exactly its particles before any solve; floating (pure Neumann) components are solved with
//! zero mean; Cholesky and CG agree within the bound their residuals give; a manufactured
//! solution converges at the order the consistency analysis predicts; CG failure carries its
//! residuals.

mod common;

use common::{
    deterministic_runner, dirichlet_box, mirror_box, periodic_box, Family, Spec, Volumes, WEIGHTS,
};
use gpm::diagnostics::{connectivity, Components};
use gpm::error::SolveError;
use gpm::geometry::lattice_weight_sum;
use gpm::kernel::{Kernel, Weight};
use gpm::neighbors::NeighborList;
use gpm::operators::{div_sum, laplacian};
use gpm::particles::Role;
use gpm::poisson::{Assembly, PoissonSolver, SolveInfo, SolveParams, SolverKind};
use nalgebra::{DMatrix, DVector, SymmetricEigen};
use proptest::prelude::*;
use std::cell::Cell;
use std::f64::consts::PI;

/// `K` of MISSION §3 from its definition, by brute force over all pairs:
/// `K_ii = ω_i Σ_{k≠i} ω_k a_ik` (every neighbour, band included), `K_ij = −ω_i ω_j a_ij`,
/// `a_ij = 2d w_h(r_ij)/r_ij²`; a ghost stands for its source (its entry goes to the source's
/// column; a particle's own image cancels). Unknowns are the fluid particles in index order.
fn dense_k<const D: usize>(f: &Family<D>) -> DMatrix<f64> {
    let cfg = f.nl.config();
    let k = Kernel::<D>::new(cfg.weight, cfg.h);
    let fluid = f.fluid();
    let mut unk = vec![usize::MAX; f.len()];
    for (u, &i) in fluid.iter().enumerate() {
        unk[i] = u;
    }
    let n = fluid.len();
    let mut m = DMatrix::<f64>::zeros(n, n);
    for &i in &fluid {
        for j in 0..f.len() {
            if j == i {
                continue;
            }
            let mut r2 = 0.0;
            for a in 0..D {
                let mut d = f.x[j][a] - f.x[i][a];
                let l = cfg.periodic.len[a];
                if l > 0.0 {
                    d -= l * (d / l).round();
                }
                r2 += d * d;
            }
            if r2 >= cfg.h * cfg.h {
                continue;
            }
            let src = match f.role[j] {
                Role::Fluid => Some(j),
                Role::Ghost { source, .. } => Some(source as usize),
                Role::Dirichlet => None,
            };
            if src == Some(i) {
                continue;
            }
            let a = 2.0 * D as f64 * k.w_h(r2.sqrt()) / r2;
            let c = f.vol[i] * f.vol[j] * a;
            m[(unk[i], unk[i])] += c;
            if let Some(s) = src {
                m[(unk[i], unk[s])] -= c;
            }
        }
    }
    m
}

/// The crate's assembled `K` as a dense matrix.
fn assembled<const D: usize>(f: &Family<D>) -> (Assembly, DMatrix<f64>) {
    let mut a = Assembly::default();
    a.update_pattern(&f.nl, &f.role);
    a.fill_values(&f.nl, &f.vol, &f.role).unwrap();
    let n = a.n();
    let mut m = DMatrix::<f64>::zeros(n, n);
    for u in 0..n {
        for k in a.offsets[u]..a.offsets[u + 1] {
            m[(u, a.cols[k] as usize)] = a.values[k];
        }
    }
    (a, m)
}

fn max_abs(m: &DMatrix<f64>) -> f64 {
    m.iter().fold(0.0f64, |s, v| s.max(v.abs()))
}

fn solve<const D: usize>(
    f: &Family<D>,
    comps: &Components,
    rhs: &[f64],
    solver: SolverKind,
) -> (Vec<f64>, SolveInfo) {
    let mut u = vec![0.0; f.len()];
    let params = SolveParams {
        solver,
        rel_tol: 1e-13,
        warm_start: false,
        ..SolveParams::default()
    };
    let info = PoissonSolver::new()
        .solve(&f.nl, &f.vol, &f.role, comps, rhs, &mut u, &params)
        .unwrap_or_else(|e| panic!("{:?} {solver:?}: {e}", f.spec));
    (u, info)
}

fn fluid_vec<const D: usize>(f: &Family<D>, u: &[f64]) -> DVector<f64> {
    let fluid = f.fluid();
    DVector::from_iterator(fluid.len(), fluid.iter().map(|&i| u[i]))
}

#[test]
fn assembled_matrix_is_the_definition_symmetric_and_positive_definite() {
    let rv = Volumes::Random { spread: 4.0 };
    check_spd(&dirichlet_box::<2>(
        Spec::lattice(10, 2.4, Weight::WendlandC2)
            .jittered(0.4, 1)
            .volumes(rv),
    ));
    check_spd(&dirichlet_box::<2>(Spec::lattice(
        9,
        1.6,
        Weight::CubicSpline,
    )));
    check_spd(&dirichlet_box::<2>(
        Spec::lattice(10, 3.1, Weight::Poly { p: 2, m: 3 })
            .jittered(0.3, 2)
            .volumes(Volumes::NumberDensity),
    ));
    check_spd(&dirichlet_box::<3>(
        Spec::lattice(5, 1.8, Weight::WendlandC4)
            .jittered(0.35, 3)
            .volumes(rv),
    ));
}

/// Theorem 4.1 on an h-connected family: `K` equals its definition, is symmetric, every
/// eigenvalue is positive and Cholesky (nalgebra's dense one and the crate's sparse one)
/// succeeds; CG, sparse Cholesky and a dense solve of the independently built `K` agree within
/// `(‖r₁‖ + ‖r₂‖)/λ_min` (the bound their residuals give).
fn check_spd<const D: usize>(f: &Family<D>) {
    let comps = connectivity(&f.nl, &f.role);
    assert!(comps.is_h_connected(), "{:?}", f.spec);
    assert!(comps.check(0).is_ok());
    let (_, k) = assembled(f);
    let kd = dense_k(f);
    let scale = max_abs(&kd);
    assert!(
        max_abs(&(&k - &kd)) <= 1e-13 * scale,
        "{:?}: assembled K differs from the definition by {:e}",
        f.spec,
        max_abs(&(&k - &kd))
    );
    assert!(
        max_abs(&(&k - k.transpose())) <= 1e-14 * scale,
        "K not symmetric"
    );
    let eig = SymmetricEigen::new(kd.clone());
    let lmin = eig.eigenvalues.min();
    let lmax = eig.eigenvalues.max();
    assert!(
        lmin > 1e-10 * lmax,
        "{:?}: λ_min = {lmin:e}, λ_max = {lmax:e}",
        f.spec
    );
    assert!(kd.clone().cholesky().is_some());

    // solves
    let psi = f.random_vector(7);
    let rhs = div_sum(&f.nl, &f.vol, &psi);
    let (u_ch, info_ch) = solve(f, &comps, &rhs, SolverKind::Cholesky);
    let (u_cg, info_cg) = solve(f, &comps, &rhs, SolverKind::Cg);
    assert_eq!(info_ch.solver, SolverKind::Cholesky);
    assert_eq!(info_cg.solver, SolverKind::Cg);
    assert!(info_cg.iters > 0);
    let fluid = f.fluid();
    let b = DVector::from_iterator(fluid.len(), fluid.iter().map(|&i| f.vol[i] * rhs[i]));
    let x_dense = kd.clone().cholesky().unwrap().solve(&b);
    let x_ch = fluid_vec(f, &u_ch);
    let x_cg = fluid_vec(f, &u_cg);
    let r_ch = (&kd * &x_ch - &b).norm();
    let r_cg = (&kd * &x_cg - &b).norm();
    let r_de = (&kd * &x_dense - &b).norm();
    // the solver's own report of its residual is the true residual
    assert!((info_ch.abs_residual - r_ch).abs() <= 1e-3 * r_ch + 1e-14 * b.norm());
    assert!((info_cg.abs_residual - r_cg).abs() <= 1e-3 * r_cg + 1e-14 * b.norm());
    assert!(r_cg <= 1e-12 * b.norm(), "CG residual {r_cg:e}");
    assert!(r_ch <= 1e-12 * b.norm(), "Cholesky residual {r_ch:e}");
    let slack = 1.0 + 1e-6;
    assert!((&x_ch - &x_cg).norm() <= slack * (r_ch + r_cg) / lmin + 1e-15 * x_ch.norm());
    assert!((&x_ch - &x_dense).norm() <= slack * (r_ch + r_de) / lmin + 1e-15 * x_ch.norm());
    // Dirichlet values are zero, and the solution is not trivial
    for i in f.dirichlet() {
        assert_eq!(u_ch[i], 0.0);
        assert_eq!(u_cg[i], 0.0);
    }
    assert!(x_ch.norm() > 0.0);
}

/// Lattice coordinates that are exact in binary: n = 8 (Δx = 1/8), h = 2Δx = 1/4, a band of
/// three cells: particles at −5/16 + k/8.
fn dyadic_box() -> Family<2> {
    let f = dirichlet_box::<2>(Spec::lattice(8, 2.0, Weight::WendlandC2));
    assert_eq!(f.spec.h(), 0.25);
    assert!(f
        .x
        .iter()
        .all(|p| p.iter().all(|&c| ((c + 0.3125) * 8.0).fract() == 0.0)));
    f
}

/// Appends fluid particles and rebuilds the neighbour list.
fn with_extra(f: &Family<2>, extra: &[[f64; 2]]) -> Family<2> {
    let mut g = f.clone();
    for p in extra {
        g.x.push(*p);
        g.vol.push(f.spec.dx().powi(2));
        g.role.push(Role::Fluid);
    }
    g.nl = NeighborList::build(*f.nl.config(), &g.x).unwrap();
    g
}

#[test]
fn detached_cluster_is_reported_with_exactly_its_particles() {
    let base = dyadic_box();
    let n0 = base.len();
    let h = base.spec.h();
    // the base set is h-connected
    assert!(connectivity(&base.nl, &base.role).check(0).is_ok());
    // a cluster of three far away (hops of 0.6 h among themselves), one isolated particle, a
    // pair exactly h from the outermost band particle (1.3125, 0.4375) — strictly not a
    // neighbour, so cut off — and a pair 0.9 h from the band (anchored: not reported)
    let extra = [
        [3.0, 3.0],
        [3.0 + 0.6 * h, 3.0],
        [3.0 + 0.6 * h, 3.0 + 0.6 * h],
        [-4.0, 2.0],
        [1.3125 + 0.25, 0.4375],
        [1.3125 + 0.25 + 0.125, 0.4375],
        [-0.3125 - 0.9 * h, 0.6875],
        [-0.3125 - 1.5 * h, 0.6875],
    ];
    let f = with_extra(&base, &extra);
    let comps = connectivity(&f.nl, &f.role);
    assert!(!comps.is_h_connected());
    assert_eq!(comps.isolated, vec![n0 + 3]);
    let err = comps
        .check(0)
        .expect_err("a cut-off cluster must be reported");
    let want: Vec<usize> = vec![n0, n0 + 1, n0 + 2, n0 + 3, n0 + 4, n0 + 5];
    assert_eq!(err.offending, want);
    assert_eq!(err.components, 3);
    assert_eq!(err.isolated, 1);
    // the message names them
    let msg = err.to_string();
    assert!(msg.contains(&format!("{}", n0 + 4)), "{msg}");
    // the main fluid and the pair near the band are anchored
    for i in base.fluid() {
        assert!(comps.anchored[comps.label[i] as usize]);
    }
    assert!(comps.anchored[comps.label[n0 + 6] as usize]);
    assert_eq!(comps.label[n0 + 6], comps.label[n0 + 7]);
    let s = comps.summary();
    assert_eq!((s.floating, s.isolated), (3, 1));
    // allowing floating components does not excuse the isolated particle
    let err = comps.check(5).unwrap_err();
    assert_eq!(err.offending, vec![n0 + 3]);

    // why it must be caught before a solve: K is singular on each cut-off component (Thm 4.1
    // needs h-connectivity); the constant vector on a component is in its null space
    let kd = dense_k(&f);
    let fluid = f.fluid();
    for members in [vec![n0, n0 + 1, n0 + 2], vec![n0 + 4, n0 + 5], vec![n0 + 3]] {
        let v = DVector::from_iterator(
            fluid.len(),
            fluid
                .iter()
                .map(|i| if members.contains(i) { 1.0 } else { 0.0 }),
        );
        assert!((&kd * &v).norm() <= 1e-13 * max_abs(&kd), "{members:?}");
    }
    assert!(kd.cholesky().is_none());
}

#[test]
fn a_cluster_farther_than_h_in_3d_is_reported() {
    let base = dirichlet_box::<3>(Spec::lattice(4, 1.7, Weight::CubicSpline).jittered(0.3, 5));
    let n0 = base.len();
    let h = base.spec.h();
    let mut f = base.clone();
    for p in [[5.0, 5.0, 5.0], [5.0, 5.0, 5.0 + 0.5 * h]] {
        f.x.push(p);
        f.vol.push(base.vol[0]);
        f.role.push(Role::Fluid);
    }
    f.nl = NeighborList::build(*base.nl.config(), &f.x).unwrap();
    let err = connectivity(&f.nl, &f.role).check(0).unwrap_err();
    assert_eq!(err.offending, vec![n0, n0 + 1]);
    assert_eq!(err.isolated, 0);
}

#[test]
fn floating_components_have_zero_mean_and_cholesky_matches_cg() {
    for f in [
        mirror_box::<2>(
            Spec::lattice(12, 2.5, Weight::WendlandC2)
                .jittered(0.4, 11)
                .volumes(Volumes::Random { spread: 3.0 }),
        ),
        periodic_box::<2>(Spec::lattice(12, 2.2, Weight::CubicSpline).jittered(0.3, 12)),
    ] {
        check_floating(&f);
    }
    check_floating(&mirror_box::<3>(
        Spec::lattice(5, 1.9, Weight::WendlandC2)
            .jittered(0.3, 13)
            .volumes(Volumes::NumberDensity),
    ));
}

fn check_floating<const D: usize>(f: &Family<D>) {
    // the assembled matrix with ghosts standing for their sources is the definition, and
    // symmetric (mirror images: |x_i − R x_s| = |x_s − R x_i|)
    let (_, k) = assembled(f);
    let kd0 = dense_k(f);
    assert!(
        max_abs(&(&k - &kd0)) <= 1e-13 * max_abs(&kd0),
        "{:?}",
        f.spec
    );
    assert!(max_abs(&(&k - k.transpose())) <= 1e-14 * max_abs(&kd0));
    let comps = connectivity(&f.nl, &f.role);
    assert_eq!(comps.len(), 1);
    assert_eq!(comps.floating(), vec![0]);
    assert!(comps.check(1).is_ok());
    // the paper's condition fails: every fluid particle is reported under check(0)
    assert_eq!(comps.check(0).unwrap_err().offending, f.fluid());

    let psi = f.random_vector(3);
    let rhs = div_sum(&f.nl, &f.vol, &psi);
    let (u_ch, i_ch) = solve(f, &comps, &rhs, SolverKind::Cholesky);
    let (u_cg, i_cg) = solve(f, &comps, &rhs, SolverKind::Cg);
    let fluid = f.fluid();
    for (u, info) in [(&u_ch, &i_ch), (&u_cg, &i_cg)] {
        assert_eq!(info.floating, 1);
        // the sum-form source already sums to zero (discrete Gauss theorem)
        assert!(info.compatibility_defect < 1e-13, "{info:?}");
        // zero ω-weighted mean
        let m: f64 = fluid.iter().map(|&i| f.vol[i] * u[i]).sum();
        let a: f64 = fluid.iter().map(|&i| f.vol[i] * u[i].abs()).sum();
        assert!(a > 0.0 && m.abs() <= 1e-13 * a, "mean {m:e} of {a:e}");
        // ghosts carry their source's value
        for (i, r) in f.role.iter().enumerate() {
            if let Role::Ghost { source, .. } = r {
                assert_eq!(u[i], u[*source as usize]);
            }
        }
        // the full (singular) system is solved: −Δh u = rhs on every fluid row
        let lap = laplacian(&f.nl, &f.vol, u);
        let rn: f64 = fluid
            .iter()
            .map(|&i| (lap[i] + rhs[i]).powi(2))
            .sum::<f64>()
            .sqrt();
        let bn: f64 = fluid.iter().map(|&i| rhs[i].powi(2)).sum::<f64>().sqrt();
        assert!(rn <= 1e-10 * bn, "residual {rn:e} of {bn:e}");
    }
    // agreement: K e = r_ch − r_cg; on the complement of the constants ‖e‖ ≤ ‖Δr‖/λ₂, and the
    // ω-weighted mean removal P = I − 1ωᵀ/Σω has ‖P‖₂ ≤ 1 + √n ‖ω‖/Σω
    let kd = dense_k(f);
    let eig = SymmetricEigen::new(kd.clone());
    let mut ev: Vec<f64> = eig.eigenvalues.iter().copied().collect();
    ev.sort_by(f64::total_cmp);
    assert!(
        ev[0].abs() <= 1e-12 * ev[ev.len() - 1],
        "one zero eigenvalue: {}",
        ev[0]
    );
    let l2 = ev[1];
    assert!(l2 > 1e-10 * ev[ev.len() - 1], "only one null vector");
    let w = DVector::from_iterator(fluid.len(), fluid.iter().map(|&i| f.vol[i]));
    let pnorm = 1.0 + (fluid.len() as f64).sqrt() * w.norm() / w.sum();
    let b = DVector::from_iterator(fluid.len(), fluid.iter().map(|&i| f.vol[i] * rhs[i]));
    let x_ch = fluid_vec(f, &u_ch);
    let x_cg = fluid_vec(f, &u_cg);
    let dr = (&kd * (&x_ch - &x_cg)).norm();
    assert!(dr <= 2e-12 * b.norm());
    assert!(
        (&x_ch - &x_cg).norm() <= (1.0 + 1e-6) * pnorm * dr / l2 + 1e-14 * x_ch.norm(),
        "Cholesky and CG differ by {:e}",
        (&x_ch - &x_cg).norm()
    );
}

#[test]
fn incompatible_sources_are_projected_and_reported() {
    // a source that does not sum to zero on a floating component: the solver removes its
    // ω-weighted mean, reports the defect, and solves −Δh u = rhs − mean
    let f = mirror_box::<2>(
        Spec::lattice(10, 2.5, Weight::WendlandC2)
            .jittered(0.3, 21)
            .volumes(Volumes::Random { spread: 2.0 }),
    );
    let comps = connectivity(&f.nl, &f.role);
    let rhs: Vec<f64> = f.random_scalar(8).iter().map(|v| v + 0.5).collect();
    let fluid = f.fluid();
    let sw: f64 = fluid.iter().map(|&i| f.vol[i]).sum();
    let mean = fluid.iter().map(|&i| f.vol[i] * rhs[i]).sum::<f64>() / sw;
    let defect = (mean * sw).abs()
        / fluid
            .iter()
            .map(|&i| (f.vol[i] * rhs[i]).abs())
            .sum::<f64>();
    for kind in [SolverKind::Cholesky, SolverKind::Cg] {
        let (u, info) = solve(&f, &comps, &rhs, kind);
        assert!(
            (info.compatibility_defect - defect).abs() <= 1e-12 * defect,
            "{info:?}"
        );
        let lap = laplacian(&f.nl, &f.vol, &u);
        for &i in &fluid {
            assert!(
                (-lap[i] - (rhs[i] - mean)).abs() <= 1e-9 * (1.0 + rhs[i].abs()),
                "{kind:?} row {i}"
            );
        }
    }
}

/// `u = Π_a sin⁴(π x_a)` in the unit box, 0 outside: C³ across the boundary and exactly zero on
/// the band, so the band values are exact. Returns (u, ∇u, Δu).
fn exact<const D: usize>(x: &[f64; D]) -> (f64, [f64; D], f64) {
    if !x.iter().all(|&c| c > 0.0 && c < 1.0) {
        return (0.0, [0.0; D], 0.0);
    }
    let s: [f64; D] = std::array::from_fn(|a| (PI * x[a]).sin());
    let c: [f64; D] = std::array::from_fn(|a| (PI * x[a]).cos());
    let g1: [f64; D] = std::array::from_fn(|a| s[a].powi(4)); // factor values
    let d1: [f64; D] = std::array::from_fn(|a| 4.0 * PI * s[a].powi(3) * c[a]);
    let d2: [f64; D] =
        std::array::from_fn(|a| 4.0 * PI * PI * (3.0 * s[a] * s[a] * c[a] * c[a] - s[a].powi(4)));
    let prod_except = |b: usize| -> f64 { (0..D).filter(|&a| a != b).map(|a| g1[a]).product() };
    let u = g1.iter().product();
    let grad = std::array::from_fn(|b| d1[b] * prod_except(b));
    let lap = (0..D).map(|b| d2[b] * prod_except(b)).sum();
    (u, grad, lap)
}

/// Relative ℓ2(Ω) error of the discrete solution on a lattice with the `S = 1` volumes
/// `ω = 1 / Σ_{lattice} w_h` (uniform, so every fluid row sees a full symmetric lattice ball),
/// for the point source `−Δu(x_i)` or the paper's divergence-form source `∇̂h·f̂` with
/// `f = −∇u`.
fn mms_error<const D: usize>(n: usize, hdx: f64, divergence_form: bool) -> f64 {
    let spec = Spec::lattice(n, hdx, Weight::WendlandC2);
    let mut f = dirichlet_box::<D>(spec);
    let k = Kernel::<D>::new(spec.weight, spec.h());
    let omega = 1.0 / lattice_weight_sum(&k, spec.dx());
    f.vol.iter_mut().for_each(|v| *v = omega);
    let comps = connectivity(&f.nl, &f.role);
    assert!(comps.check(0).is_ok());
    let rhs: Vec<f64> = if divergence_form {
        let fl: Vec<[f64; D]> = f.x.iter().map(|x| exact(x).1.map(|g| -g)).collect();
        div_sum(&f.nl, &f.vol, &fl)
    } else {
        f.x.iter().map(|x| -exact(x).2).collect()
    };
    let kind = if D == 2 {
        SolverKind::Cholesky
    } else {
        SolverKind::Cg
    };
    let (u, _) = solve(&f, &comps, &rhs, kind);
    let fluid = f.fluid();
    let e2: f64 = fluid
        .iter()
        .map(|&i| f.vol[i] * (u[i] - exact(&f.x[i]).0).powi(2))
        .sum();
    let u2: f64 = fluid
        .iter()
        .map(|&i| f.vol[i] * exact(&f.x[i]).0.powi(2))
        .sum();
    (e2 / u2).sqrt()
}

/// Second order: the truncation error is O(h²) on the symmetric lattice (MISSION §2 Taylor
/// argument, S = 1) and `−Δh` is stable (Thm 4.5 / discrete maximum principle), so the error is
/// `C h² (1 + O(h²))`: the observed order on the finest pair is within 0.2 of 2.
fn assert_order_two(ns: &[usize], errs: &[f64], what: &str) {
    let orders: Vec<f64> = (1..ns.len())
        .map(|m| (errs[m - 1] / errs[m]).ln() / (ns[m] as f64 / ns[m - 1] as f64).ln())
        .collect();
    eprintln!("{what}: errors {errs:?}, orders {orders:?}");
    let last = *orders.last().unwrap();
    assert!(
        (last - 2.0).abs() < 0.2,
        "{what}: orders {orders:?}, errors {errs:?}"
    );
    assert!(errs.windows(2).all(|w| w[1] < w[0]));
}

#[test]
fn manufactured_solution_converges_at_second_order_2d() {
    let ns = [16, 32, 64];
    for div in [false, true] {
        let errs: Vec<f64> = ns.iter().map(|&n| mms_error::<2>(n, 2.0, div)).collect();
        assert_order_two(&ns, &errs, &format!("2D MMS (divergence form: {div})"));
    }
}

#[test]
fn manufactured_solution_converges_at_second_order_3d() {
    let ns = [8, 12, 16];
    let errs: Vec<f64> = ns.iter().map(|&n| mms_error::<3>(n, 1.5, true)).collect();
    assert_order_two(&ns, &errs, "3D MMS (divergence form)");
}

#[test]
fn cg_failure_carries_its_residuals() {
    let f = dirichlet_box::<2>(
        Spec::lattice(16, 2.5, Weight::WendlandC2)
            .jittered(0.3, 31)
            .volumes(Volumes::Random { spread: 2.0 }),
    );
    let comps = connectivity(&f.nl, &f.role);
    let rhs = div_sum(&f.nl, &f.vol, &f.random_vector(4));
    let fluid = f.fluid();
    let bnorm = fluid
        .iter()
        .map(|&i| (f.vol[i] * rhs[i]).powi(2))
        .sum::<f64>()
        .sqrt();
    let mut u = vec![0.0; f.len()];
    let params = SolveParams {
        solver: SolverKind::Cg,
        rel_tol: 1e-14,
        max_iters: 3,
        warm_start: false,
        ..SolveParams::default()
    };
    match PoissonSolver::new().solve(&f.nl, &f.vol, &f.role, &comps, &rhs, &mut u, &params) {
        Err(SolveError::NoConvergence {
            iters,
            abs_residual,
            rel_residual,
        }) => {
            assert_eq!(iters, 3);
            assert!(abs_residual.is_finite() && abs_residual > 0.0);
            assert!(rel_residual > 1e-14 && rel_residual < 1.0);
            assert!((rel_residual - abs_residual / bnorm).abs() <= 1e-12 * rel_residual);
            let msg = SolveError::NoConvergence {
                iters,
                abs_residual,
                rel_residual,
            }
            .to_string();
            assert!(msg.contains('3'), "{msg}");
        }
        other => panic!("expected NoConvergence, got {other:?}"),
    }
    // the same problem converges with the default limit, and reports a residual below rel_tol
    let params = SolveParams {
        max_iters: 10_000,
        rel_tol: 1e-10,
        ..params
    };
    let info = PoissonSolver::new()
        .solve(&f.nl, &f.vol, &f.role, &comps, &rhs, &mut u, &params)
        .unwrap();
    assert!(info.iters > 3);
    assert!(info.rel_residual <= 1e-9, "{info:?}");
}

#[test]
fn symbolic_factorisation_is_reused_while_the_pattern_is_unchanged() {
    let f = dirichlet_box::<2>(Spec::lattice(12, 2.5, Weight::CubicSpline).jittered(0.3, 41));
    let comps = connectivity(&f.nl, &f.role);
    let rhs = div_sum(&f.nl, &f.vol, &f.random_vector(1));
    let params = SolveParams {
        solver: SolverKind::Cholesky,
        ..SolveParams::default()
    };
    let mut solver = PoissonSolver::new();
    let mut u1 = vec![0.0; f.len()];
    let i1 = solver
        .solve(&f.nl, &f.vol, &f.role, &comps, &rhs, &mut u1, &params)
        .unwrap();
    assert!(i1.pattern_rebuilt && !i1.reused_symbolic);
    // new volumes: same pattern, new values → symbolic reused, numeric redone, same answer as
    // a fresh solver
    let vol2: Vec<f64> = f
        .vol
        .iter()
        .enumerate()
        .map(|(i, v)| v * (1.0 + 0.1 * (i % 3) as f64))
        .collect();
    let mut u2 = vec![0.0; f.len()];
    let i2 = solver
        .solve(&f.nl, &vol2, &f.role, &comps, &rhs, &mut u2, &params)
        .unwrap();
    assert!(!i2.pattern_rebuilt && i2.reused_symbolic && !i2.reused_numeric);
    let mut u3 = vec![0.0; f.len()];
    PoissonSolver::new()
        .solve(&f.nl, &vol2, &f.role, &comps, &rhs, &mut u3, &params)
        .unwrap();
    for i in 0..f.len() {
        assert!((u2[i] - u3[i]).abs() <= 1e-12 * (1.0 + u3[i].abs()));
    }
}

/// Theorem 4.1 as a property over random Dirichlet families, some of them too sparse to be
/// h-connected (`h/Δx` down to 0.9 with jitter up to 0.45 Δx): when h-connectivity holds the
/// sparse Cholesky factorisation succeeds and the solution solves the system; when it fails,
/// the constants of every cut-off component are null vectors of `K` (so no solve may be
/// attempted) and `check(0)` names exactly the particles of those components.
fn run_theorem_4_1<const D: usize>(cases: u32, seed: u8) {
    let sizes = if D == 2 { 4usize..=10 } else { 3usize..=5 };
    let strategy = (
        sizes,
        0.9f64..2.2,
        0.0f64..0.45,
        0usize..WEIGHTS.len(),
        1.0f64..6.0,
        any::<u64>(),
    );
    let connected = Cell::new(0u32);
    let cut = Cell::new(0u32);
    deterministic_runner(cases, seed)
        .run(&strategy, |(n, hdx, jit, wk, spread, s)| {
            let spec = Spec::lattice(n, hdx, WEIGHTS[wk])
                .jittered(jit, s)
                .volumes(Volumes::Random { spread });
            let f = dirichlet_box::<D>(spec);
            let comps = connectivity(&f.nl, &f.role);
            if comps.is_h_connected() {
                prop_assert!(comps.check(0).is_ok());
                let rhs = div_sum(&f.nl, &f.vol, &f.random_vector(s ^ 9));
                let mut u = vec![0.0; f.len()];
                let params = SolveParams {
                    solver: SolverKind::Cholesky,
                    ..SolveParams::default()
                };
                let info = PoissonSolver::new()
                    .solve(&f.nl, &f.vol, &f.role, &comps, &rhs, &mut u, &params);
                prop_assert!(info.is_ok(), "{spec:?}: Cholesky failed: {info:?}");
                let info = info.unwrap();
                prop_assert_eq!(info.floating, 0);
                prop_assert!(info.rel_residual <= 1e-10, "{spec:?}: {info:?}");
                connected.set(connected.get() + 1);
            } else {
                let err = comps.check(0);
                prop_assert!(err.is_err());
                let offending = err.unwrap_err().offending;
                let mut want: Vec<usize> = comps
                    .floating()
                    .iter()
                    .flat_map(|&c| comps.members(c))
                    .collect();
                want.sort_unstable();
                prop_assert_eq!(&offending, &want);
                let kd = dense_k(&f);
                let fluid = f.fluid();
                for c in comps.floating() {
                    let v = DVector::from_iterator(
                        fluid.len(),
                        fluid.iter().map(|&i| {
                            if comps.label[i] as usize == c {
                                1.0
                            } else {
                                0.0
                            }
                        }),
                    );
                    prop_assert!((&kd * &v).norm() <= 1e-13 * max_abs(&kd) * v.norm());
                }
                cut.set(cut.get() + 1);
            }
            Ok(())
        })
        .unwrap();
    eprintln!(
        "Theorem 4.1 ({D}D): {} h-connected families factorised, {} cut-off families reported",
        connected.get(),
        cut.get()
    );
    // both branches were exercised
    assert!(connected.get() >= cases / 4 && cut.get() >= 1);
}

#[test]
fn theorem_4_1_property_2d() {
    run_theorem_4_1::<2>(192, 51);
}

#[test]
fn theorem_4_1_property_3d() {
    run_theorem_4_1::<3>(64, 52);
}

#[test]
fn a_non_positive_pivot_names_its_particle() {
    // a (physically invalid) tiny negative volume at one fluid particle i makes
    // K_ii = ω_i Σ_k ω_k a_ik < 0 while the principal submatrix without i stays positive
    // definite (its diagonal changes by a relative 1e-6), so Cholesky must fail exactly at i,
    // whatever the fill-reducing ordering: the error has to map the permuted pivot back to the
    // particle. Small and large systems (faer picks a simplicial or a supernodal factorisation).
    check_pivot_report(&dirichlet_box::<2>(
        Spec::lattice(10, 2.5, Weight::WendlandC2).jittered(0.3, 61),
    ));
    check_pivot_report(&dirichlet_box::<2>(
        Spec::lattice(48, 3.0, Weight::WendlandC2).jittered(0.3, 62),
    ));
    check_pivot_report(&dirichlet_box::<3>(
        Spec::lattice(10, 2.0, Weight::CubicSpline).jittered(0.3, 63),
    ));
}

fn check_pivot_report<const D: usize>(f: &Family<D>) {
    let comps = connectivity(&f.nl, &f.role);
    let rhs = div_sum(&f.nl, &f.vol, &f.random_vector(1));
    let params = SolveParams {
        solver: SolverKind::Cholesky,
        ..SolveParams::default()
    };
    let fluid = f.fluid();
    for &i in &[fluid[0], fluid[fluid.len() / 3], fluid[fluid.len() - 1]] {
        let mut vol = f.vol.clone();
        vol[i] = -1e-6 * f.vol[i];
        let mut u = vec![0.0; f.len()];
        match PoissonSolver::new().solve(&f.nl, &vol, &f.role, &comps, &rhs, &mut u, &params) {
            Err(SolveError::NotPositiveDefinite { unknown, particle }) => {
                assert_eq!(particle, i, "{:?}", f.spec);
                assert_eq!(fluid[unknown], i);
            }
            other => panic!("expected NotPositiveDefinite at {i}, got {other:?}"),
        }
    }
}

/// The library's manufactured Dirichlet-band problem (`gpm::scene::manufactured`): its exact
/// gradient against central differences of its exact solution, its layout (fluid inside the
/// unit box, a band of ⌈h/Δx⌉ + 1 layers), and second-order convergence on lattices.
#[test]
fn manufactured_band_problem_is_consistent_and_converges() {
    use gpm::scene::manufactured::{exact, BandProblem, BandSpec};
    let x = [0.31, 0.77, 0.12];
    let (_, g) = exact(&x);
    let eps = 1e-6;
    for a in 0..3 {
        let (mut xp, mut xm) = (x, x);
        xp[a] += eps;
        xm[a] -= eps;
        let fd = (exact(&xp).0 - exact(&xm).0) / (2.0 * eps);
        assert!((fd - g[a]).abs() < 1e-8, "axis {a}: {fd} vs {}", g[a]);
    }
    let mut errs = Vec::new();
    for n in [16usize, 32] {
        let p = BandProblem::<2>::build(&BandSpec::new(n, 3.0)).unwrap();
        assert_eq!(p.n_fluid(), n * n);
        // 3 h/Δx + 1 = 4 band layers on each side
        assert_eq!(p.x.len(), (n + 8) * (n + 8));
        assert!(p.comps.check(0).is_ok());
        let (phi, _) = solve_band(&p);
        errs.push(p.errors(&phi).0);
    }
    let order = (errs[0] / errs[1]).log2();
    assert!(order > 1.5, "{errs:?}: order {order}");
}

fn solve_band(p: &gpm::scene::manufactured::BandProblem<2>) -> (Vec<f64>, SolveInfo) {
    let mut phi = vec![0.0; p.x.len()];
    let info = PoissonSolver::new()
        .solve(
            &p.nl,
            &p.vol,
            &p.role,
            &p.comps,
            &p.rhs,
            &mut phi,
            &SolveParams::default(),
        )
        .unwrap();
    (phi, info)
}

/// With a neighbour skin, the pattern of the pairs within `h` (`pattern_within_h`, default)
/// holds fewer entries than the candidates' pattern and gives the same solution; after the
/// particles move (the same list updated, not searched again) it follows the new pairs — no
/// pair is missing and the solution still matches — while the candidates' pattern stays.
#[test]
fn pattern_within_h_drops_the_skin_pairs_and_follows_moving_particles() {
    use gpm::geometry::lattice;
    use gpm::neighbors::NeighborConfig;
    let n = 20;
    let dx = 1.0 / n as f64;
    let h = 3.0 * dx;
    let b = 4.0 * dx;
    let mut x = lattice([-b, -b], [1.0 + b, 1.0 + b], dx);
    let inside = |p: &[f64; 2]| p.iter().all(|&c| c > 0.0 && c < 1.0);
    let role: Vec<Role> = x
        .iter()
        .map(|p| {
            if inside(p) {
                Role::Fluid
            } else {
                Role::Dirichlet
            }
        })
        .collect();
    let vol = vec![dx * dx; x.len()];
    let rhs: Vec<f64> = x.iter().map(|p| (PI * p[0]).sin() + p[1]).collect();
    let mut nl =
        NeighborList::build(NeighborConfig::new(Weight::WendlandC2, h, 0.3 * h), &x).unwrap();
    let params = |within_h: bool| SolveParams {
        solver: SolverKind::Cholesky,
        pattern_within_h: within_h,
        ..SolveParams::default()
    };
    let (mut within, mut candidates) = (PoissonSolver::new(), PoissonSolver::new());
    let len = x.len();
    let solve = |nl: &NeighborList<2>, s: &mut PoissonSolver, within_h: bool| {
        let comps = connectivity(nl, &role);
        let mut phi = vec![0.0; len];
        let info = s
            .solve(nl, &vol, &role, &comps, &rhs, &mut phi, &params(within_h))
            .unwrap();
        (info, phi)
    };
    let max_diff = |a: &[f64], b: &[f64]| {
        a.iter()
            .zip(b)
            .map(|(u, v)| (u - v).abs())
            .fold(0.0, f64::max)
    };
    let (wi0, w0) = solve(&nl, &mut within, true);
    let (ci0, c0) = solve(&nl, &mut candidates, false);
    assert!(
        (wi0.nnz as f64) < 0.75 * ci0.nnz as f64,
        "within h {} vs candidates {}",
        wi0.nnz,
        ci0.nnz
    );
    assert!(max_diff(&w0, &c0) < 1e-10, "{}", max_diff(&w0, &c0));

    // move every particle by up to 0.1 h (within the skin: the list is updated, not searched)
    for (i, p) in x.iter_mut().enumerate() {
        let a = 0.7 * i as f64;
        p[0] += 0.1 * h * a.sin();
        p[1] += 0.1 * h * a.cos();
    }
    let up = nl.update(&x).unwrap();
    assert!(!up.rebuilt, "the move stays within half the skin");
    let (wi1, w1) = solve(&nl, &mut within, true);
    let (ci1, c1) = solve(&nl, &mut candidates, false);
    assert!(
        wi1.pattern_rebuilt && wi1.nnz != wi0.nnz,
        "{wi0:?} -> {wi1:?}"
    );
    assert!(!ci1.pattern_rebuilt && ci1.nnz == ci0.nnz);
    assert!(max_diff(&w1, &c1) < 1e-10, "{}", max_diff(&w1, &c1));
    assert!(max_diff(&w1, &w0) > 1e-6, "the move changed the solution");
}

#[test]
fn nested_dissection_orders_every_unknown_once_and_factorises_like_amd() {
    use gpm::poisson::direct::nested_dissection;
    // a jittered 2D box: the ordering is a permutation, and the Cholesky solve with it (the
    // solver's moving-particle path) gives the AMD solve's solution
    let f = common::dirichlet_box::<2>(
        common::Spec::lattice(30, 3.0, gpm::kernel::Weight::WendlandC2).jittered(0.3, 5),
    );
    let mut a = gpm::poisson::Assembly::default();
    a.update_pattern(&f.nl, &f.role);
    a.fill_values(&f.nl, &f.vol, &f.role).unwrap();
    let n = a.n();
    let coords: Vec<f64> = a.particle.iter().flat_map(|&p| f.x[p as usize]).collect();
    let order = nested_dissection(&coords, 2, &a.offsets, &a.cols);
    let mut seen = vec![false; n];
    for &o in &order {
        assert!(!seen[o], "unknown {o} ordered twice");
        seen[o] = true;
    }
    assert!(seen.iter().all(|&s| s), "an unknown was left out");
    let b: Vec<f64> = (0..n).map(|u| ((u * 37) % 11) as f64 - 5.0).collect();
    let solve = |coordinates: Option<(Vec<f64>, usize)>| {
        let mut d = gpm::poisson::Direct::default();
        d.coordinates = coordinates;
        let mut x = vec![0.0; n];
        d.solve(&a, &[], &b, &mut x, true, true).unwrap();
        x
    };
    let amd = solve(None);
    let nd = solve(Some((coords, 2)));
    let scale = amd.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    let diff = amd
        .iter()
        .zip(&nd)
        .fold(0.0f64, |m, (p, q)| m.max((p - q).abs()));
    assert!(
        diff <= 1e-10 * scale,
        "solutions differ by {diff:e} (scale {scale:e})"
    );
}

/// A jittered lattice in the unit box with the mirror images of a cavity's walls (no-slip or
/// free-slip), its neighbour list with a skin, and each ghost's velocity sign per component.
fn walled_box(free_slip: bool) -> (gpm::particles::Particles<2>, NeighborList<2>, Vec<[f64; 2]>) {
    use gpm::boundary::{Boundary, Walls};
    use gpm::neighbors::NeighborConfig;
    let n = 24;
    let dx = 1.0 / n as f64;
    let h = 3.0 * dx;
    let mut p = gpm::particles::Particles::new();
    for (k, x) in gpm::geometry::lattice([0.5 * dx; 2], [1.0; 2], dx)
        .into_iter()
        .enumerate()
    {
        let a = 1.3 * k as f64;
        let x = [x[0] + 0.2 * dx * a.sin(), x[1] + 0.2 * dx * a.cos()];
        p.push(x, [0.0; 2], 0.0, dx * dx, Role::Fluid);
    }
    let walls = if free_slip {
        Walls::cavity(1.0, 1.0).free_slip()
    } else {
        Walls::cavity(1.0, 1.0)
    };
    let config = NeighborConfig::new(Weight::WendlandC2, h, 0.3 * h);
    walls.make_ghosts(&mut p, h + 0.3 * h);
    let nl = NeighborList::build(config, &p.x).unwrap();
    let sigma = p
        .role
        .iter()
        .map(|r| match r {
            Role::Ghost { walls: w, source } => walls.velocity_affine(*w, &p.x[*source as usize]).0,
            _ => [1.0; 2],
        })
        .collect();
    (p, nl, sigma)
}

#[test]
fn the_viscous_matrix_derived_from_the_poisson_matrix_is_the_assembled_one() {
    // H = W + c K_σ built from the pairs, and derived from K of the same configuration
    // (Assembly::helmholtz_from, what moving particles use): same pattern, same values to
    // rounding, for no-slip images (σ = −1 across a wall, +1 at a corner, self-images on the
    // diagonal) and for free-slip ones (σ per component)
    let c = 0.37;
    for free_slip in [false, true] {
        let (p, nl, signs) = walled_box(free_slip);
        assert!(p.role.iter().any(|r| matches!(r, Role::Ghost { .. })));
        let mut k = Assembly::default();
        k.within_h = true;
        k.update_poisson(&nl, &p.vol, &p.role).unwrap();
        for d in 0..2 {
            let sigma: Vec<f64> = signs.iter().map(|s| s[d]).collect();
            assert!(sigma.iter().any(|&s| s == -1.0));
            let mut built = Assembly::default();
            built.within_h = true;
            built
                .update_helmholtz(&nl, &p.vol, &p.role, c, &sigma)
                .unwrap();
            let mut derived = Assembly::default();
            let rebuilt = derived
                .helmholtz_from(&k, &nl, &p.vol, &p.role, 1.0, c, &sigma)
                .expect("K belongs to this configuration");
            assert!(rebuilt, "the first derivation copies the pattern");
            assert_eq!(built.offsets, derived.offsets);
            assert_eq!(built.cols, derived.cols);
            assert_eq!(built.diag, derived.diag);
            let scale = built.values.iter().map(|v| v.abs()).fold(0.0, f64::max);
            let diff = built
                .values
                .iter()
                .zip(&derived.values)
                .map(|(a, b)| (a - b).abs())
                .fold(0.0, f64::max);
            assert!(
                diff <= 1e-14 * scale,
                "free_slip {free_slip}, component {d}: {diff:e} of {scale:e}"
            );
            // a second derivation for the same K keeps the pattern
            let again = derived
                .helmholtz_from(&k, &nl, &p.vol, &p.role, 1.0, c, &sigma)
                .unwrap();
            assert!(!again);
        }
    }
    // a K of another configuration is refused: the particles moved, the pairs were re-measured
    let (mut p, mut nl, signs) = walled_box(false);
    let mut k = Assembly::default();
    k.within_h = true;
    k.update_poisson(&nl, &p.vol, &p.role).unwrap();
    for x in p.x.iter_mut() {
        x[0] += 1e-3;
    }
    nl.update(&p.x).unwrap();
    let sigma: Vec<f64> = signs.iter().map(|s| s[0]).collect();
    let mut derived = Assembly::default();
    assert!(derived
        .helmholtz_from(&k, &nl, &p.vol, &p.role, 1.0, c, &sigma)
        .is_none());
}

#[test]
fn cg_on_several_right_sides_at_once_equals_cg_on_each() {
    use gpm::poisson::iterative::{pcg, pcg_multi};
    let (p, nl, signs) = walled_box(false);
    let sigma: Vec<f64> = signs.iter().map(|s| s[0]).collect();
    let mut h = Assembly::default();
    h.within_h = true;
    h.update_helmholtz(&nl, &p.vol, &p.role, 0.05, &sigma)
        .unwrap();
    let m = h.n();
    let b0: Vec<f64> = (0..m).map(|i| (0.37 * i as f64).sin()).collect();
    let b1: Vec<f64> = (0..m).map(|i| 1.0 + (0.11 * i as f64).cos()).collect();
    let b2 = vec![0.0; m];
    let guess = |s: f64| -> Vec<f64> { (0..m).map(|i| s * (i % 7) as f64).collect() };
    for (rel_tol, max_iters) in [(1e-10, 1000), (1e-3, 1000)] {
        let (mut x0, mut x1, mut x2) = (guess(0.1), guess(-0.2), guess(0.3));
        let multi = pcg_multi(
            &h,
            [&b0, &b1, &b2],
            [&mut x0, &mut x1, &mut x2],
            rel_tol,
            0.0,
            max_iters,
        )
        .unwrap();
        for (c, (b, x)) in [(&b0, &x0), (&b1, &x1), (&b2, &x2)].into_iter().enumerate() {
            let mut y = guess([0.1, -0.2, 0.3][c]);
            let one = pcg(&h, b, &mut y, rel_tol, 0.0, max_iters).unwrap();
            assert_eq!(multi[c].iters, one.iters, "column {c}, tol {rel_tol}");
            let diff = x
                .iter()
                .zip(&y)
                .map(|(a, b)| (a - b).abs())
                .fold(0.0, f64::max);
            let scale = y.iter().map(|v| v.abs()).fold(0.0, f64::max).max(1e-300);
            assert!(diff <= 1e-12 * scale.max(1.0), "column {c}: {diff:e}");
            assert!(
                (multi[c].abs_residual - one.abs_residual).abs()
                    <= 1e-9 * one.abs_residual.max(1e-30),
                "{:?} vs {one:?}",
                multi[c]
            );
        }
        assert!(x2.iter().all(|&v| v == 0.0), "a zero right side gives zero");
    }
    // the iteration limit is reported per column, like pcg's
    let (mut x0, mut x1) = (vec![0.0; m], vec![0.0; m]);
    let err = pcg_multi(&h, [&b0, &b1], [&mut x0, &mut x1], 1e-14, 0.0, 1).unwrap_err();
    assert!(
        matches!(err, SolveError::NoConvergence { iters: 1, .. }),
        "{err:?}"
    );
}

#[test]
fn cg_on_the_unformed_viscous_matrix_equals_cg_on_the_formed_one() {
    // `W + c K` applied from the Poisson matrix `K` (iterative::Shifted: what a moving step's
    // viscous solve reads when no wall image changes it) against the same matrix formed by
    // Assembly::helmholtz_from: the same iterations and, to rounding, the same solutions
    use gpm::poisson::iterative::{pcg_multi, pcg_multi_in, CgWork, Shifted};
    let (p, nl, _) = jittered_periodic(24, 0.1);
    let c = 0.05;
    let mut k = Assembly::default();
    k.within_h = true;
    k.update_poisson(&nl, &p.vol, &p.role).unwrap();
    let ones = vec![1.0; p.len()];
    let mut h = Assembly::default();
    h.helmholtz_from(&k, &nl, &p.vol, &p.role, 1.0, c, &ones)
        .expect("K belongs to this configuration");
    let m = k.n();
    let shift: Vec<f64> = k.particle.iter().map(|&q| p.vol[q as usize]).collect();
    let b0: Vec<f64> = (0..m).map(|i| (0.37 * i as f64).sin()).collect();
    let b1: Vec<f64> = (0..m).map(|i| 1.0 + (0.11 * i as f64).cos()).collect();
    let guess: Vec<f64> = (0..m).map(|i| 0.1 * (i % 5) as f64).collect();
    let mut work = CgWork::default();
    for rel_tol in [1e-12, 1e-4] {
        let (mut x0, mut x1) = (vec![0.0; m], guess.clone());
        let formed = pcg_multi(&h, [&b0, &b1], [&mut x0, &mut x1], rel_tol, 0.0, 1000).unwrap();
        let (mut y0, mut y1) = (vec![0.0; m], guess.clone());
        let op = Shifted {
            a: &k,
            scale: c,
            shift: &shift,
        };
        let read = pcg_multi_in(
            &mut work,
            op,
            [&b0, &b1],
            [&mut y0, &mut y1],
            rel_tol,
            0.0,
            1000,
        )
        .unwrap();
        for (col, (x, y)) in [(&x0, &y0), (&x1, &y1)].into_iter().enumerate() {
            assert_eq!(
                formed[col].iters, read[col].iters,
                "column {col}, tol {rel_tol}"
            );
            let scale = x.iter().map(|v| v.abs()).fold(0.0, f64::max);
            let diff = x
                .iter()
                .zip(y)
                .map(|(a, b)| (a - b).abs())
                .fold(0.0, f64::max);
            assert!(diff <= 1e-12 * scale, "column {col}: {diff:e} of {scale:e}");
            // the true residuals agree to the rounding of a product (relative to ‖b‖)
            let bnorm = [&b0, &b1][col].iter().map(|v| v * v).sum::<f64>().sqrt();
            let (fr, rr) = (formed[col].abs_residual, read[col].abs_residual);
            assert!(
                (fr - rr).abs() <= 1e-14 * bnorm,
                "{fr:e} vs {rr:e} (‖b‖ {bnorm:e})"
            );
        }
    }
}

#[test]
fn the_viscous_solve_reads_the_poisson_matrix_and_starts_from_the_last_change() {
    // A moving step's viscous solve without wall images reads `K` instead of forming
    // `W + c K` (the solver's own matrix stays empty) and gives the assembled solve's
    // answer; its next solve starts from `r + (u − r)_last`, which needs fewer iterations
    // than the right side alone, and still stops at the tolerance.
    use gpm::poisson::HelmholtzSolver;
    use std::f64::consts::PI;
    let (p, nl, _) = jittered_periodic(24, 0.1);
    let mut k = Assembly::default();
    k.within_h = true;
    k.update_poisson(&nl, &p.vol, &p.role).unwrap();
    let c = 0.05;
    let rule = |_: usize| ([1.0; 2], [0.0; 2]);
    let params = SolveParams {
        solver: SolverKind::Cg,
        ..Default::default()
    };
    let exact = |r: &[[f64; 2]]| -> Vec<[f64; 2]> {
        let tight = SolveParams {
            rel_tol: 1e-15,
            viscous_rel_tol: 1e-15,
            warm_start: false,
            ..params
        };
        let mut u = r.to_vec();
        HelmholtzSolver::new()
            .solve(&nl, &p.vol, &p.role, &rule, c, r, &mut u, &tight)
            .unwrap();
        u
    };
    let err = |u: &[[f64; 2]], v: &[[f64; 2]]| -> f64 {
        u.iter()
            .zip(v)
            .flat_map(|(a, b)| [(a[0] - b[0]).abs(), (a[1] - b[1]).abs()])
            .fold(0.0, f64::max)
    };
    let field = |t: f64| -> Vec<[f64; 2]> {
        p.x.iter()
            .map(|x| {
                [
                    (2.0 * PI * (x[1] + t)).sin(),
                    (2.0 * PI * (x[0] - t)).cos() + 0.3 * (4.0 * PI * x[1]).sin(),
                ]
            })
            .collect()
    };
    // one moving step's solve, reading `k`
    let step = |solver: &mut HelmholtzSolver, r: &[[f64; 2]]| -> (Vec<[f64; 2]>, usize) {
        let mut u = r.to_vec();
        let info = solver
            .solve_with_poisson(Some(&k), &nl, &p.vol, &p.role, &rule, c, r, &mut u, &params)
            .unwrap();
        (u, info.iters)
    };
    let moving = || {
        let mut s = HelmholtzSolver::new();
        s.assume_moving();
        s
    };
    let mut solver = moving();
    let r1 = field(0.0);
    let (u1, _) = step(&mut solver, &r1);
    assert!(
        solver.assembly.values.is_empty(),
        "W + c K was formed ({} values)",
        solver.assembly.values.len()
    );
    let e1 = err(&u1, &exact(&r1));
    assert!(e1 < 1e-10, "first solve off by {e1:e}");
    // the next step's right side, a little later: from the last change, and from scratch
    let r2 = field(0.002);
    let (u2, warm) = step(&mut solver, &r2);
    let (v2, cold) = step(&mut moving(), &r2);
    assert!(
        warm < cold,
        "warm start {warm} iterations, from the right side {cold}"
    );
    let reference = exact(&r2);
    for (what, u) in [("warm", &u2), ("cold", &v2)] {
        let e = err(u, &reference);
        assert!(e < 1e-10, "{what}: off by {e:e}");
    }
}

#[test]
fn the_jacobi_bound_taken_beside_the_values_is_gershgorins() {
    // Assembly::jacobi_bound (summed while a within-h pattern's values are written: what the
    // lagged AMG smoother of moving particles reads instead of a pass) against
    // max_u Σ_j |a_uj| / a_uu computed from the stored matrix
    let check = |a: &Assembly, what: &str| {
        let g = (0..a.n())
            .map(|u| {
                let (_, v) = a.row(u);
                v.iter().map(|x| x.abs()).sum::<f64>() / a.values[a.diag[u]]
            })
            .fold(0.0, f64::max);
        let b = a
            .jacobi_bound()
            .unwrap_or_else(|| panic!("{what}: no bound"));
        assert!((b - g).abs() <= 1e-12 * g, "{what}: {b} against {g}");
        g
    };
    // every particle a fluid unknown (the in-place path); the Poisson rows sum to zero
    let (mut p, mut nl, _) = jittered_periodic(24, 0.1);
    let mut k = Assembly::default();
    k.within_h = true;
    k.keep_pairs = true;
    k.update_poisson(&nl, &p.vol, &p.role).unwrap();
    let g = check(&k, "periodic Poisson");
    assert!((g - 2.0).abs() < 1e-12, "zero row sums give 2, not {g}");
    let mut h = Assembly::default();
    h.within_h = true;
    h.update_helmholtz(&nl, &p.vol, &p.role, 0.05, &vec![1.0; p.len()])
        .unwrap();
    let g = check(&h, "periodic Helmholtz");
    assert!(g < 2.0, "the mass term makes the rows dominant: {g}");
    // moved a little: the values refilled into the kept pattern
    for (i, x) in p.x.iter_mut().enumerate() {
        x[0] += 1e-4 * (i as f64).sin();
    }
    nl.update(&p.x).unwrap();
    k.update_poisson(&nl, &p.vol, &p.role).unwrap();
    check(&k, "periodic Poisson, moved");
    // values written by another path carry no bound
    k.fill_values(&nl, &p.vol, &p.role).unwrap();
    assert_eq!(k.jacobi_bound(), None);
    // wall images (the general path: a source and its images merged into one entry; σ = −1
    // makes off-diagonal entries positive)
    let (p, nl, signs) = walled_box(false);
    let mut k = Assembly::default();
    k.within_h = true;
    k.update_poisson(&nl, &p.vol, &p.role).unwrap();
    check(&k, "walled Poisson");
    let sigma: Vec<f64> = signs.iter().map(|s| s[0]).collect();
    let mut h = Assembly::default();
    h.within_h = true;
    h.update_helmholtz(&nl, &p.vol, &p.role, 0.05, &sigma)
        .unwrap();
    check(&h, "walled Helmholtz");
}

#[test]
fn the_within_h_pattern_holds_the_candidate_patterns_nonzero_entries_bit_for_bit() {
    // K assembled on the pairs within h (a moving run's pattern, rebuilt each step with the
    // diagonal inserted into the neighbours' sorted row) against K on the candidate pattern
    // (skin pairs stored as zeros, rows filled by `fill`): the same nonzero entries, the same
    // bits — on a box with wall images (rows re-sorted) and on a periodic lattice (every
    // particle a fluid unknown: the rows written in place, each after the rows before it)
    let periodic = jittered_periodic(20, 0.1);
    let (walled, walled_nl, _) = walled_box(false);
    for (name, p, nl) in [
        ("periodic", &periodic.0, &periodic.1),
        ("walled", &walled, &walled_nl),
    ] {
        let mut within = Assembly::default();
        within.within_h = true;
        within.update_poisson(nl, &p.vol, &p.role).unwrap();
        let mut cand = Assembly::default();
        cand.within_h = false;
        cand.update_poisson(nl, &p.vol, &p.role).unwrap();
        assert_eq!(within.n(), cand.n(), "{name}");
        assert!(
            within.nnz() < cand.nnz(),
            "{name}: the skin pairs are dropped"
        );
        for u in 0..within.n() {
            let a: Vec<(u32, u64)> = (within.offsets[u]..within.offsets[u + 1])
                .map(|e| (within.cols[e], within.values[e].to_bits()))
                .collect();
            let b: Vec<(u32, u64)> = (cand.offsets[u]..cand.offsets[u + 1])
                .filter(|&e| cand.values[e] != 0.0 || cand.cols[e] as usize == u)
                .map(|e| (cand.cols[e], cand.values[e].to_bits()))
                .collect();
            assert_eq!(a, b, "{name}: row {u}");
            assert_eq!(
                within.cols[within.diag[u]] as usize, u,
                "{name}: diagonal of {u}"
            );
        }
    }
}

#[test]
fn a_within_h_pattern_is_kept_while_the_pair_set_holds() {
    // `keep_pairs`: particles moved without any pair crossing h keep the pattern and its id
    // (the caches keyed on it hold) and get a fresh build's values bit for bit; a move that
    // takes pairs across h builds a new pattern, again equal to a fresh build — on a periodic
    // lattice (the in-place path) and in a box with wall images (the general path)
    let periodic = jittered_periodic(20, 0.0);
    let (walled, walled_nl, _) = walled_box(false);
    for (name, mut p, mut nl, dx) in [
        ("periodic", periodic.0, periodic.1, periodic.2),
        ("walled", walled, walled_nl, 1.0 / 24.0),
    ] {
        let fresh = |p: &gpm::particles::Particles<2>, nl: &NeighborList<2>| {
            let mut a = Assembly::default();
            a.within_h = true;
            a.update_poisson(nl, &p.vol, &p.role).unwrap();
            a
        };
        let same = |a: &Assembly, b: &Assembly| {
            let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            a.offsets == b.offsets
                && a.cols == b.cols
                && a.diag == b.diag
                && bits(&a.values) == bits(&b.values)
        };
        let mut kept = Assembly::default();
        kept.within_h = true;
        kept.keep_pairs = true;
        assert!(kept.update_poisson(&nl, &p.vol, &p.role).unwrap());
        let id = kept.pattern_id();
        // a move far below any pair's distance to h: the same pairs, new distances
        let set = nl.pair_set();
        for (i, x) in p.x.iter_mut().enumerate() {
            if p.role[i].is_fluid() {
                x[0] += 1e-9 * dx * (i % 7) as f64;
            }
        }
        nl.update(&p.x).unwrap();
        assert_eq!(nl.pair_set(), set, "{name}: the pair set holds");
        let rebuilt = kept.update_poisson(&nl, &p.vol, &p.role).unwrap();
        assert!(!rebuilt, "{name}: pattern kept");
        assert_eq!(kept.pattern_id(), id, "{name}: pattern id kept");
        assert!(
            same(&kept, &fresh(&p, &nl)),
            "{name}: values of a fresh build"
        );
        // one fluid particle moved 0.4 dx: some of its pairs cross h
        let i = p.role.iter().position(|r| r.is_fluid()).unwrap() + 5;
        p.x[i][1] += 0.4 * dx;
        nl.update(&p.x).unwrap();
        assert_ne!(nl.pair_set(), set, "{name}: the pair set changed");
        let rebuilt = kept.update_poisson(&nl, &p.vol, &p.role).unwrap();
        assert!(rebuilt, "{name}: a new pattern");
        assert_ne!(kept.pattern_id(), id, "{name}: a new pattern id");
        assert!(same(&kept, &fresh(&p, &nl)), "{name}: after the change");
    }
}

#[test]
fn the_assemblys_c0_is_semi_regularity_bit_for_bit() {
    // c0 summed beside the values of a within-h pattern (what `predict` reports for moving
    // particles) against the diagnostics' own pass, with unequal volumes: the same bits — on
    // a periodic lattice (the in-place path) and in a box with wall images (the general path)
    use gpm::diagnostics::{semi_regularity, Region};
    let (p, nl, _) = jittered_periodic(20, 0.2);
    let (walled, walled_nl, _) = walled_box(false);
    for (name, p, nl) in [("periodic", &p, &nl), ("walled", &walled, &walled_nl)] {
        let mut a = Assembly::default();
        a.within_h = true;
        a.update_poisson(nl, &p.vol, &p.role).unwrap();
        let c0 = a.c0_of(nl).expect("summed by the build");
        let expected = semi_regularity(nl, &p.vol, &p.role, Region::Omega);
        assert!(expected > 0.5, "{name}: {expected}");
        assert_eq!(
            c0.to_bits(),
            expected.to_bits(),
            "{name}: {c0} vs {expected}"
        );
    }
}

/// A jittered periodic lattice of `n × n` particles (volumes `dx²` times `1 + vol_jitter·cos`)
/// and its list, `h = 3Δx`, skin `0.9Δx`: every particle a fluid unknown.
fn jittered_periodic(
    n: usize,
    vol_jitter: f64,
) -> (gpm::particles::Particles<2>, NeighborList<2>, f64) {
    use gpm::neighbors::{NeighborConfig, Periodicity};
    let dx = 1.0 / n as f64;
    let mut p = gpm::particles::Particles::<2>::new();
    for (k, x) in gpm::geometry::lattice([0.0; 2], [1.0; 2], dx)
        .into_iter()
        .enumerate()
    {
        let a = 2.1 * k as f64;
        let x = [x[0] + 0.15 * dx * a.sin(), x[1] + 0.15 * dx * a.cos()];
        p.push(
            x,
            [0.0; 2],
            0.0,
            dx * dx * (1.0 + vol_jitter * a.cos()),
            Role::Fluid,
        );
    }
    let config = NeighborConfig::new(Weight::WendlandC2, 3.0 * dx, 0.9 * dx)
        .with_periodicity(Periodicity::all([0.0; 2], [1.0; 2]));
    let nl = NeighborList::build(config, &p.x).unwrap();
    (p, nl, dx)
}
