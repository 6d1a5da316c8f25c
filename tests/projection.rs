//! The projection step: it does exactly the discrete algebra, it removes the divergence of smooth
//! fields by the factor the consistency analysis predicts (MISSION §2), and the flows built on it
//! meet their references.
#![allow(clippy::type_complexity, clippy::needless_range_loop)]

use gpm::boundary::{NoBoundary, PeriodicBox};
use gpm::geometry::{jitter, lattice, number_density_volumes};
use gpm::kernel::{Kernel, Weight};
use gpm::neighbors::{NeighborConfig, NeighborList, Periodicity};
use gpm::operators::div_sum;
use gpm::particles::{Particles, Role};
use gpm::projection::{ProjectionParams, ProjectionStep, Scheme};
use std::f64::consts::PI;

fn rms(v: &[f64]) -> f64 {
    (v.iter().map(|a| a * a).sum::<f64>() / v.len() as f64).sqrt()
}

/// A periodic unit square with `u* = ∇ψ + s`, `ψ = sin 2πx sin 2πy`, `s` divergence-free.
fn periodic_case(n: usize, fixed_volumes: bool) -> (Particles<2>, NeighborList<2>, PeriodicBox<2>) {
    let dx = 1.0 / n as f64;
    let x = lattice([0.0, 0.0], [1.0, 1.0], dx);
    let per = Periodicity::all([0.0, 0.0], [1.0, 1.0]);
    let nl = NeighborList::build(
        NeighborConfig::new(Weight::WendlandC2, 3.0 * dx, 0.0).with_periodicity(per),
        &x,
    )
    .unwrap();
    let vol = if fixed_volumes {
        vec![dx * dx; x.len()]
    } else {
        number_density_volumes(&nl)
    };
    let mut p = Particles::<2>::new();
    for (i, xi) in x.iter().enumerate() {
        let (sx, cx) = (2.0 * PI * xi[0]).sin_cos();
        let (sy, cy) = (2.0 * PI * xi[1]).sin_cos();
        let g = [2.0 * PI * cx * sy, 2.0 * PI * sx * cy];
        let s = [-sx * cy, cx * sy];
        p.push(*xi, [g[0] + s[0], g[1] + s[1]], 0.0, vol[i], Role::Fluid);
    }
    (p, nl, PeriodicBox { periodic: per })
}

fn project_once(p: &mut Particles<2>, nl: &NeighborList<2>, bc: &PeriodicBox<2>) -> (f64, f64) {
    let before = rms(&div_sum(nl, &p.vol, &p.u));
    let mut params = ProjectionParams::<2>::new(0.0);
    params.scheme = Scheme::NonIncremental;
    let mut step = ProjectionStep::new();
    let rep = step.step(p, nl, bc, &params, 0.01, None).unwrap();
    assert!(
        rep.stability_ratio <= 1.0,
        "Theorem 4.5 ratio {}",
        rep.stability_ratio
    );
    let after = rms(&div_sum(nl, &p.vol, &p.u));
    (before, after)
}

/// With ω = 1/Σw (S_i = 1) the divergence left by the approximate projection is the O(h²)
/// mismatch between ∇̂h·∇h and Δh: the factor must fall like Δx² at fixed h/Δx.
#[test]
fn smooth_divergence_is_removed_to_second_order() {
    let mut factors = Vec::new();
    for n in [16usize, 32, 64] {
        let (mut p, nl, bc) = periodic_case(n, false);
        let (b, a) = project_once(&mut p, &nl, &bc);
        factors.push((n as f64, a / b));
    }
    for w in factors.windows(2) {
        let order = (w[0].1 / w[1].1).ln() / (w[1].0 / w[0].0).ln();
        assert!(order > 1.8, "divergence factor order {order} ({factors:?})");
    }
    assert!(factors[2].1 < 0.01, "{factors:?}");
}

/// With lattice volumes ω = Δx² the operators approximate S × the derivatives
/// (S = Σ_{j≠i} Δx² w_h(r_ij), MISSION §2), so ∇̂h·∇h Δh⁻¹ ≈ S and the projection leaves the
/// fraction 1 − S of a smooth divergence.
#[test]
fn lattice_volumes_leave_the_predicted_fraction() {
    let n = 64;
    let dx = 1.0 / n as f64;
    // S from an independent lattice sum
    let k = Kernel::<2>::new(Weight::WendlandC2, 3.0 * dx);
    let mut s = 0.0;
    for a in -4i64..=4 {
        for b in -4i64..=4 {
            if a != 0 || b != 0 {
                let r = ((a * a + b * b) as f64).sqrt() * dx;
                s += dx * dx * k.w_h(r);
            }
        }
    }
    assert!((0.70..0.80).contains(&s), "S = {s}");
    let (mut p, nl, bc) = periodic_case(n, true);
    let (b, a) = project_once(&mut p, &nl, &bc);
    let factor = a / b;
    assert!(
        (factor - (1.0 - s)).abs() < 0.02,
        "factor {factor} vs 1 − S = {}",
        1.0 - s
    );
}

/// The projection equals an independent dense implementation of
/// `uⁿ⁺¹ = u* − Δt/ρ ∇h φ`, `−Δh φ = ∇̂h·(−ρ/Δt u*)` (zero-mean φ), with all operators built
/// here from their definitions, on a jittered periodic set.
#[test]
fn projection_equals_dense_algebra() {
    let n = 10;
    let dx = 1.0 / n as f64;
    let h = 2.6 * dx;
    let mut x = lattice([0.0, 0.0], [1.0, 1.0], dx);
    jitter(&mut x, 0.25 * dx, 77);
    let per = Periodicity::all([0.0, 0.0], [1.0, 1.0]);
    let nl = NeighborList::build(
        NeighborConfig::new(Weight::CubicSpline, h, 0.0).with_periodicity(per),
        &x,
    )
    .unwrap();
    let m = x.len();
    // volumes: non-uniform, fixed
    let vol: Vec<f64> = (0..m)
        .map(|i| dx * dx * (0.8 + 0.4 * ((i * 37 % 11) as f64 / 10.0)))
        .collect();
    let ustar: Vec<[f64; 2]> = (0..m)
        .map(|i| {
            [
                ((i * 13 % 7) as f64 - 3.0) * 0.3,
                ((i * 5 % 9) as f64 - 4.0) * 0.2,
            ]
        })
        .collect();
    let (rho, dt) = (1.3, 0.02);
    // dense operators from the definitions
    let kern = Kernel::<2>::new(Weight::CubicSpline, h);
    let mut a = nalgebra::DMatrix::<f64>::zeros(m, m); // a_ij = w/r², j ≠ i, r < h
    let mut dxs = vec![vec![[0.0f64; 2]; m]; m];
    for i in 0..m {
        for j in 0..m {
            if i == j {
                continue;
            }
            let mut d = [x[j][0] - x[i][0], x[j][1] - x[i][1]];
            for c in 0..2 {
                d[c] -= (d[c]).round();
            }
            let r2 = d[0] * d[0] + d[1] * d[1];
            if r2 < h * h {
                a[(i, j)] = kern.w_h(r2.sqrt()) / r2;
                dxs[i][j] = d;
            }
        }
    }
    let dd = 2.0;
    // rhs_i = d Σ ω_j (f_j + f_i)·dx a, f = −ρ/Δt u*
    let f: Vec<[f64; 2]> = ustar
        .iter()
        .map(|u| [-rho / dt * u[0], -rho / dt * u[1]])
        .collect();
    let mut rhs = nalgebra::DVector::<f64>::zeros(m);
    for i in 0..m {
        for j in 0..m {
            if a[(i, j)] > 0.0 {
                let d = dxs[i][j];
                rhs[i] += dd
                    * vol[j]
                    * ((f[j][0] + f[i][0]) * d[0] + (f[j][1] + f[i][1]) * d[1])
                    * a[(i, j)];
            }
        }
    }
    // −Δh as a matrix: (−Δh φ)_i = 2d Σ ω_j (φ_i − φ_j) a_ij
    let mut lap = nalgebra::DMatrix::<f64>::zeros(m, m);
    for i in 0..m {
        for j in 0..m {
            if a[(i, j)] > 0.0 {
                let c = 2.0 * dd * vol[j] * a[(i, j)];
                lap[(i, i)] += c;
                lap[(i, j)] -= c;
            }
        }
    }
    // consistent right side (Σ ω rhs = 0 exactly for the sum form), zero ω-mean solution via
    // the bordered system [L ω; ωᵀ 0]
    let mut big = nalgebra::DMatrix::<f64>::zeros(m + 1, m + 1);
    big.view_mut((0, 0), (m, m)).copy_from(&lap);
    for i in 0..m {
        big[(i, m)] = 1.0;
        big[(m, i)] = vol[i];
    }
    let mut b = nalgebra::DVector::<f64>::zeros(m + 1);
    b.rows_mut(0, m).copy_from(&rhs);
    let sol = big.lu().solve(&b).expect("bordered system solvable");
    assert!(
        sol[m].abs() < 1e-8 * rhs.amax(),
        "Lagrange multiplier {} (inconsistent rhs)",
        sol[m]
    );
    let phi = sol.rows(0, m).into_owned();
    let mut u_new = vec![[0.0; 2]; m];
    for i in 0..m {
        let mut g = [0.0; 2];
        for j in 0..m {
            if a[(i, j)] > 0.0 {
                let c = dd * vol[j] * (phi[j] - phi[i]) * a[(i, j)];
                g[0] += c * dxs[i][j][0];
                g[1] += c * dxs[i][j][1];
            }
        }
        u_new[i] = [ustar[i][0] - dt / rho * g[0], ustar[i][1] - dt / rho * g[1]];
    }
    // the library
    let mut p = Particles::<2>::new();
    for i in 0..m {
        p.push(x[i], ustar[i], 0.0, vol[i], Role::Fluid);
    }
    let mut params = ProjectionParams::<2>::new(0.0);
    params.rho = rho;
    params.scheme = Scheme::NonIncremental;
    let mut step = ProjectionStep::new();
    step.step(
        &mut p,
        &nl,
        &PeriodicBox { periodic: per },
        &params,
        dt,
        None,
    )
    .unwrap();
    let scale = ustar
        .iter()
        .map(|u| u[0].abs().max(u[1].abs()))
        .fold(0.0, f64::max);
    for i in 0..m {
        for c in 0..2 {
            assert!(
                (p.u[i][c] - u_new[i][c]).abs() < 1e-9 * scale,
                "particle {i}: {} vs dense {}",
                p.u[i][c],
                u_new[i][c]
            );
        }
        assert!((p.p[i] - phi[i]).abs() < 1e-9 * phi.amax(), "pressure {i}");
    }
}

/// A detached cluster is reported before any solve, and nothing is changed.
#[test]
fn disconnected_particles_are_reported_before_the_solve() {
    let dx = 0.1;
    let mut p = Particles::<2>::new();
    for x in lattice([0.0, 0.0], [1.0, 1.0], dx) {
        let role = if x[0] < 0.3 {
            Role::Dirichlet
        } else {
            Role::Fluid
        };
        p.push(x, [0.1, 0.0], 0.0, dx * dx, role);
    }
    let lone = p.len();
    p.push([3.0, 3.0], [1.0, 0.0], 0.0, dx * dx, Role::Fluid);
    let nl = NeighborList::build(NeighborConfig::new(Weight::WendlandC2, 0.25, 0.0), &p.x).unwrap();
    let before = p.u.clone();
    let mut params = ProjectionParams::<2>::new(0.01);
    params.allowed_floating = 0;
    let mut step = ProjectionStep::new();
    let err = step
        .step(&mut p, &nl, &NoBoundary, &params, 0.01, None)
        .unwrap_err();
    match err {
        gpm::Error::Connectivity(c) => assert_eq!(c.offending, vec![lone]),
        e => panic!("expected a connectivity error, got {e}"),
    }
    assert_eq!(p.u, before, "velocities changed by a failed step");
}

#[test]
fn projection_step_is_send_and_sync() {
    fn check<T: Send + Sync>() {}
    check::<ProjectionStep<2>>();
    check::<ProjectionStep<3>>();
}

/// `ProjectionParams::gradient = Renormalised` puts `∇ᶜ = B∇h` into the correction: on jittered
/// particles the corrected velocity is exactly `u* − (Δt/ρ) ∇ᶜφ` (and differs from the `∇h`
/// correction), while on the lattice `B = I` and both agree to round-off.
#[test]
fn renormalised_gradient_option_is_used_by_the_correction() {
    use gpm::consistent::{grad_renormalised, GradientKind, Renormalisation};
    use gpm::operators::grad_diff;
    for (jit, seed) in [(0.0, 0), (0.3, 11)] {
        let (mut p, _, bc) = periodic_case(24, false);
        let dx = 1.0 / 24.0;
        if jit > 0.0 {
            jitter(&mut p.x, jit * dx, seed);
            for x in p.x.iter_mut() {
                for c in x.iter_mut() {
                    *c = c.rem_euclid(1.0);
                }
            }
        }
        let per = Periodicity::all([0.0, 0.0], [1.0, 1.0]);
        let nl = NeighborList::build(
            NeighborConfig::new(Weight::WendlandC2, 3.0 * dx, 0.0).with_periodicity(per),
            &p.x,
        )
        .unwrap();
        p.vol = number_density_volumes(&nl);
        let dt = 0.01;
        let mut out = Vec::new();
        for kind in [
            GradientKind::Difference,
            GradientKind::Renormalised,
            GradientKind::LeastSquares,
        ] {
            let mut q = p.clone();
            let mut params = ProjectionParams::<2>::new(0.0);
            params.scheme = Scheme::NonIncremental;
            params.gradient = kind;
            let mut step = ProjectionStep::new();
            step.capture = true;
            step.step(&mut q, &nl, &bc, &params, dt, None).unwrap();
            let cap = step.captured.take().unwrap();
            let g = match kind {
                GradientKind::Difference => grad_diff(&nl, &q.vol, &cap.phi),
                GradientKind::Renormalised => {
                    let b = Renormalisation::compute(&nl, &q.vol, nl.len());
                    grad_renormalised(&nl, &q.vol, &b, &cap.phi)
                }
                GradientKind::LeastSquares => {
                    let mut ls = gpm::consistent::LsOperators::new();
                    ls.update(&nl, &q.vol, nl.len(), None);
                    let mut g = vec![[0.0; 2]; nl.len()];
                    ls.grad_into(&nl, &cap.phi, &mut g);
                    g
                }
            };
            let scale = cap
                .u_star
                .iter()
                .map(|u| u[0].abs().max(u[1].abs()))
                .fold(0.0, f64::max);
            for i in 0..q.len() {
                for k in 0..2 {
                    let expect = cap.u_star[i][k] - dt * g[i][k];
                    assert!(
                        (q.u[i][k] - expect).abs() <= 1e-12 * scale,
                        "{kind:?} jitter {jit}: particle {i} component {k}: {} vs {expect}",
                        q.u[i][k]
                    );
                }
            }
            out.push(q.u);
        }
        let diff = out[0]
            .iter()
            .zip(&out[1])
            .map(|(a, b)| (a[0] - b[0]).abs().max((a[1] - b[1]).abs()))
            .fold(0.0, f64::max);
        if jit == 0.0 {
            assert!(
                diff < 1e-10,
                "lattice: B = I, yet the corrections differ by {diff}"
            );
        } else {
            assert!(diff > 1e-3, "jittered: the option changed nothing ({diff})");
        }
    }
}
