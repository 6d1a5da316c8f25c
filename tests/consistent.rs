//! Corrected operators (`gpm::consistent`): exactness where the mathematics says they are exact
//! (linear fields for the renormalised and CSPH gradients and the linear least-squares
//! interpolant, quadratics for the quadratic least-squares derivatives, constants for Shepard),
//! identity with `∇h` where the moment matrix is the identity, the adjoint divergence to
//! round-off, the classical SPH forms against their definitions, and the convergence orders of
//! Shobuzako et al. (classical SPH, GPM, least squares) on a small jittered case.

mod common;

use common::{mirror_box, periodic_box, Spec, Volumes};
use gpm::consistent::*;
use gpm::geometry::{jitter, lattice, number_density_volumes};
use gpm::kernel::{Kernel, Weight};
use gpm::neighbors::{NeighborConfig, NeighborList};
use gpm::operators::{div_sum, grad_diff, interpolate_at_particles, laplacian};

const TEST_WEIGHTS: [Weight; 4] = [
    Weight::CubicSpline,
    Weight::WendlandC2,
    Weight::Poly { p: 2, m: 4 },
    Weight::Poly { p: 0, m: 1 },
];

/// A jittered lattice filling the unit box and nothing else: particles near the boundary have
/// one-sided neighbourhoods (the hardest case for consistency).
fn open_box<const D: usize>(
    n: usize,
    h_over_dx: f64,
    amp: f64,
    weight: Weight,
    seed: u64,
) -> (Vec<[f64; D]>, NeighborList<D>, f64) {
    let dx = 1.0 / n as f64;
    let mut x = lattice([0.0; D], [1.0; D], dx);
    jitter(&mut x, amp * dx, seed);
    let nl = NeighborList::build(NeighborConfig::new_relative(weight, dx, h_over_dx, 0.0), &x)
        .expect("neighbour list");
    (x, nl, dx)
}

fn random_volumes(n: usize, cell: f64, seed: u64) -> Vec<f64> {
    // volumes within a factor 2 of the cell, deterministic (a simple LCG is enough here)
    let mut s = seed.wrapping_mul(6364136223846793005).wrapping_add(1);
    (0..n)
        .map(|_| {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            let u = (s >> 11) as f64 / (1u64 << 53) as f64;
            cell * 2f64.powf(2.0 * u - 1.0)
        })
        .collect()
}

/// `∇ᶜ(c·x + c0) = c` at every particle, boundary rows included, for any weight and any
/// volumes: `∇h` of a linear field is `M_i c`, and `B_i = M_i⁻¹`; likewise `∇ᶜ·ψ = tr A` for
/// `ψ = A x + b`.
#[test]
fn renormalised_gradient_is_exact_for_linear_fields() {
    for (t, &w) in TEST_WEIGHTS.iter().enumerate() {
        // 2D
        let (x, nl, dx) = open_box::<2>(24, 3.0, 0.3, w, 11 + t as u64);
        let vol = random_volumes(x.len(), dx * dx, 5 + t as u64);
        let c = [1.7, -0.4];
        let phi: Vec<f64> = x.iter().map(|p| c[0] * p[0] + c[1] * p[1] + 3.0).collect();
        let r = Renormalisation::compute(&nl, &vol, nl.len());
        assert!(r.fallback_rows.is_empty(), "{w}: fallback rows in 2D");
        let g = grad_renormalised(&nl, &vol, &r, &phi);
        for (i, gi) in g.iter().enumerate() {
            for a in 0..2 {
                assert!(
                    (gi[a] - c[a]).abs() < 1e-11,
                    "{w} 2D row {i}: {gi:?} vs {c:?}"
                );
            }
        }
        // the renormalised divergence is exact for linear vector fields (trace of the gradient)
        let psi: Vec<[f64; 2]> = x
            .iter()
            .map(|p| [0.5 + 2.0 * p[0] - p[1], -1.0 + 0.25 * p[0] + 3.0 * p[1]])
            .collect();
        let dc = div_renormalised(&nl, &vol, &r, &psi);
        for (i, v) in dc.iter().enumerate() {
            assert!((v - 5.0).abs() < 1e-10, "{w} 2D divergence row {i}: {v}");
        }
        // and the plain difference gradient is not exact there (the correction does something)
        let gd = grad_diff(&nl, &vol, &phi);
        let worst = gd
            .iter()
            .map(|v| ((v[0] - c[0]).powi(2) + (v[1] - c[1]).powi(2)).sqrt())
            .fold(0.0, f64::max);
        assert!(worst > 0.1, "{w}: ∇h unexpectedly exact ({worst})");
        // 3D
        let (x, nl, dx) = open_box::<3>(9, 2.5, 0.3, w, 21 + t as u64);
        let vol = random_volumes(x.len(), dx * dx * dx, 9 + t as u64);
        let c = [0.3, 2.0, -1.1];
        let phi: Vec<f64> = x
            .iter()
            .map(|p| c[0] * p[0] + c[1] * p[1] + c[2] * p[2] - 0.5)
            .collect();
        let r = Renormalisation::compute(&nl, &vol, nl.len());
        assert!(r.fallback_rows.is_empty(), "{w}: fallback rows in 3D");
        let g = grad_renormalised(&nl, &vol, &r, &phi);
        for (i, gi) in g.iter().enumerate() {
            for a in 0..3 {
                assert!(
                    (gi[a] - c[a]).abs() < 1e-10,
                    "{w} 3D row {i}: {gi:?} vs {c:?}"
                );
            }
        }
    }
}

/// On a periodic lattice every neighbourhood is symmetric under the axis reflections and the
/// axis swaps, so `Σ_j ω x_ji⊗x_ji w/r² = (1/d) Σ_j ω w I` and, with the number-density
/// volumes (`Σ_j ω_j w_h = 1`), `M_i = I`: the corrected gradient is `∇h` itself.
#[test]
fn renormalised_equals_difference_gradient_on_a_lattice() {
    for &w in &TEST_WEIGHTS {
        let f = periodic_box::<2>(Spec::lattice(16, 3.0, w).volumes(Volumes::NumberDensity));
        let r = Renormalisation::compute(&f.nl, &f.vol, f.nl.len());
        for b in &r.b {
            for a in 0..2 {
                for c in 0..2 {
                    let e = if a == c { 1.0 } else { 0.0 };
                    assert!((b[a][c] - e).abs() < 1e-12, "{w}: B = {b:?}");
                }
            }
        }
        let phi = f.random_scalar(3);
        let gd = grad_diff(&f.nl, &f.vol, &phi);
        let gc = grad_renormalised(&f.nl, &f.vol, &r, &phi);
        for (a, b) in gd.iter().zip(&gc) {
            for k in 0..2 {
                assert!((a[k] - b[k]).abs() < 1e-10 * (1.0 + a[k].abs()));
            }
        }
    }
}

fn inner<const D: usize>(vol: &[f64], a: &[[f64; D]], b: &[[f64; D]], rows: &[usize]) -> f64 {
    rows.iter()
        .map(|&i| vol[i] * (0..D).map(|k| a[i][k] * b[i][k]).sum::<f64>())
        .sum()
}

fn inner_s(vol: &[f64], a: &[f64], b: &[f64], rows: &[usize]) -> f64 {
    rows.iter().map(|&i| vol[i] * a[i] * b[i]).sum()
}

/// Lemma 4.3 for the corrected pair: `(∇̂h·(Bᵀψ), φ) = −(ψ, ∇ᶜφ)` to round-off (periodic box:
/// no boundary terms; mirror walls: `Bᵀψ` continued by the mirror rule), while the mixed pair
/// `(∇̂h·ψ, φ) + (ψ, ∇ᶜφ)` is not zero on jittered particles.
#[test]
fn adjoint_of_the_renormalised_gradient() {
    for &w in &[Weight::WendlandC2, Weight::Poly { p: 2, m: 4 }] {
        let per = periodic_box::<2>(
            Spec::lattice(20, 3.0, w)
                .jittered(0.3, 4)
                .volumes(Volumes::NumberDensity),
        );
        let mir = mirror_box::<2>(
            Spec::lattice(20, 3.0, w)
                .jittered(0.3, 8)
                .volumes(Volumes::Random { spread: 1.5 }),
        );
        for f in [&per, &mir] {
            let fluid = f.fluid();
            let r = Renormalisation::compute(&f.nl, &f.vol, f.nl.len());
            let psi = f.random_vector(1);
            let phi = f.random_scalar(2);
            let gc = grad_renormalised(&f.nl, &f.vol, &r, &phi);
            let mut bt = vec![[0.0; 2]; psi.len()];
            r.apply_transpose_into(&psi, &mut bt);
            f.complete_vector(&mut bt);
            let div_c = div_sum(&f.nl, &f.vol, &bt);
            let div = div_sum(&f.nl, &f.vol, &psi);
            let rhs = inner(&f.vol, &psi, &gc, &fluid);
            let scale = rhs.abs() + inner_s(&f.vol, &div_c, &phi, &fluid).abs();
            let defect = inner_s(&f.vol, &div_c, &phi, &fluid) + rhs;
            assert!(defect.abs() < 1e-12 * scale, "{w}: defect {defect:e}");
            let mixed = inner_s(&f.vol, &div, &phi, &fluid) + rhs;
            assert!(
                mixed.abs() > 1e-4 * scale,
                "{w}: the mixed pair is adjoint too? {mixed:e}"
            );
        }
    }
}

/// Quadratic least squares: gradient and Laplacian exact for quadratics at every particle
/// (the fit has the quadratic in its basis); linear least-squares interpolant exact for linear
/// fields; Shepard exact for constants; CSPH gradient exact for linear fields.
#[test]
fn least_squares_and_csph_exactness() {
    for (t, &w) in TEST_WEIGHTS.iter().enumerate() {
        let (x, nl, dx) = open_box::<2>(20, 3.0, 0.3, w, 31 + t as u64);
        let vol = vec![dx * dx; x.len()];
        let q = |p: &[f64; 2]| {
            0.5 + p[0] - 2.0 * p[1] + 1.5 * p[0] * p[0] - p[0] * p[1] + 0.7 * p[1] * p[1]
        };
        let phi: Vec<f64> = x.iter().map(q).collect();
        let (g, lap) = ls_gradient_laplacian(&nl, &vol, &phi);
        for (i, p) in x.iter().enumerate() {
            let ge = [1.0 + 3.0 * p[0] - p[1], -2.0 - p[0] + 1.4 * p[1]];
            assert!(
                (g[i][0] - ge[0]).abs() < 1e-9 && (g[i][1] - ge[1]).abs() < 1e-9,
                "{w} LS gradient row {i}"
            );
            assert!(
                (lap[i] - 4.4).abs() < 1e-7,
                "{w} LS Laplacian row {i}: {}",
                lap[i]
            );
        }
        let lin: Vec<f64> = x.iter().map(|p| 2.0 - p[0] + 3.0 * p[1]).collect();
        let li = ls_interpolate(&nl, &vol, &lin);
        let cs = csph_gradient(&nl, &vol, &lin);
        let sh = shepard_interpolate(&nl, &vol, &vec![2.5; x.len()]);
        for i in 0..x.len() {
            assert!((li[i] - lin[i]).abs() < 1e-11, "{w} LS interpolant row {i}");
            assert!(
                (cs[i][0] + 1.0).abs() < 1e-10 && (cs[i][1] - 3.0).abs() < 1e-10,
                "{w} CSPH row {i}"
            );
            assert!((sh[i] - 2.5).abs() < 1e-13, "{w} Shepard row {i}");
        }
    }
}

/// The classical forms equal their definitions, evaluated over every pair from the kernel's
/// derivative (nothing taken from the neighbour list's cached weights).
#[test]
fn classical_forms_equal_their_definitions() {
    let (x, nl, dx) = open_box::<2>(14, 3.0, 0.3, Weight::CubicSpline, 77);
    let vol = random_volumes(x.len(), dx * dx, 2);
    let phi: Vec<f64> = x.iter().map(|p| (3.0 * p[0]).sin() + p[1] * p[1]).collect();
    let k = Kernel::<2>::new(Weight::CubicSpline, nl.h());
    let forms = [
        SphGradient::Standard,
        SphGradient::Difference,
        SphGradient::Sum,
    ];
    let got: Vec<Vec<[f64; 2]>> = forms
        .iter()
        .map(|&f| sph_gradient(&nl, &vol, &phi, f))
        .collect();
    let lap = sph_laplacian_brookshaw(&nl, &vol, &phi);
    for i in 0..x.len() {
        let mut exp = [[0.0; 2]; 3];
        let mut el = 0.0;
        let mut scale = 0.0;
        for j in 0..x.len() {
            let xij = [x[i][0] - x[j][0], x[i][1] - x[j][1]];
            let r = (xij[0] * xij[0] + xij[1] * xij[1]).sqrt();
            if j == i || r >= nl.h() {
                continue;
            }
            // ∇_i W_ij = W'(r) (x_i − x_j) / r
            let gw = [k.dw_h(r) * xij[0] / r, k.dw_h(r) * xij[1] / r];
            for a in 0..2 {
                exp[0][a] += vol[j] * phi[j] * gw[a];
                exp[1][a] += vol[j] * (phi[j] - phi[i]) * gw[a];
                exp[2][a] += vol[j] * (phi[j] + phi[i]) * gw[a];
            }
            // x_ji · ∇_i W_ij = −(x_i − x_j)·∇_i W_ij
            let xg = -(xij[0] * gw[0] + xij[1] * gw[1]);
            el += 2.0 * vol[j] * (phi[j] - phi[i]) * xg / (r * r);
            scale += vol[j] * (phi[j].abs() + phi[i].abs()) * k.dw_h(r).abs() * (1.0 + 2.0 / r);
        }
        for (f, g) in got.iter().enumerate() {
            for a in 0..2 {
                assert!(
                    (g[i][a] - exp[f][a]).abs() < 1e-12 * scale,
                    "form {f} row {i}"
                );
            }
        }
        assert!((lap[i] - el).abs() < 1e-12 * scale, "Brookshaw row {i}");
    }
}

/// `E₂ = √(Σ (approx − exact)²) / √(Σ exact²)` over the rows `set` (Shobuzako et al. eq. (49)).
fn e2(approx: &[f64], exact: &[f64], set: &[usize]) -> f64 {
    let n: f64 = set.iter().map(|&i| (approx[i] - exact[i]).powi(2)).sum();
    let d: f64 = set.iter().map(|&i| exact[i].powi(2)).sum();
    (n / d).sqrt()
}

/// Least-squares slope of `ln e` against `ln Δx`.
fn slope(dx: &[f64], e: &[f64]) -> f64 {
    let m = dx.len() as f64;
    let lx: Vec<f64> = dx.iter().map(|v| v.ln()).collect();
    let ly: Vec<f64> = e.iter().map(|v| v.ln()).collect();
    let (mx, my) = (lx.iter().sum::<f64>() / m, ly.iter().sum::<f64>() / m);
    let num: f64 = lx.iter().zip(&ly).map(|(a, b)| (a - mx) * (b - my)).sum();
    let den: f64 = lx.iter().map(|a| (a - mx).powi(2)).sum();
    num / den
}

/// Shobuzako et al.'s orders on interior particles (supports inside the unit square) of a
/// 0.3Δx-jittered lattice at fixed `h = 3Δx`, for a smooth test function: the truncation error
/// of the least-squares fit (their eq. (24), `O(Δx^{q+1−k})`) gives 2 for the quadratic LS
/// gradient, 1 for the LS Laplacian and for the CSPH / renormalised gradients (linear basis);
/// the classical difference gradient and the GPM `∇h` do not converge (0), and the standard
/// gradient, the Brookshaw Laplacian and the GPM `Δh` diverge (−1). Bands of ±0.4 around the
/// theoretical order absorb the pre-asymptotic part of a three-level study.
#[test]
fn orders_on_jittered_particles_match_the_truncation_analysis() {
    let f = |p: &[f64; 2]| (2.0 * p[0] + 0.5).sin() * (1.5 * p[1]).cos();
    let fx = |p: &[f64; 2]| 2.0 * (2.0 * p[0] + 0.5).cos() * (1.5 * p[1]).cos();
    let lapf = |p: &[f64; 2]| -(4.0 + 2.25) * f(p);
    let ns = [24usize, 48, 96];
    let mut errs: Vec<[f64; 8]> = Vec::new();
    let mut dxs = Vec::new();
    for &n in &ns {
        let (x, nl, dx) = open_box::<2>(n, 3.0, 0.3, Weight::CubicSpline, 1000 + n as u64);
        let h = nl.h();
        let vol = vec![dx * dx; x.len()];
        let interior: Vec<usize> = (0..x.len())
            .filter(|&i| x[i].iter().all(|&c| c >= h && c <= 1.0 - h))
            .collect();
        let phi: Vec<f64> = x.iter().map(f).collect();
        let ex: Vec<f64> = x.iter().map(fx).collect();
        let el: Vec<f64> = x.iter().map(lapf).collect();
        let gx = |g: Vec<[f64; 2]>| g.iter().map(|v| v[0]).collect::<Vec<f64>>();
        let (lsg, lsl) = ls_gradient_laplacian(&nl, &vol, &phi);
        // the GPM operators with the product's default weight and volumes
        let nlw = NeighborList::build(
            NeighborConfig::new_relative(Weight::WendlandC2, dx, 3.0, 0.0),
            &x,
        )
        .unwrap();
        let volw = number_density_volumes(&nlw);
        let r = Renormalisation::compute(&nlw, &volw, nlw.len());
        errs.push([
            e2(
                &gx(sph_gradient(&nl, &vol, &phi, SphGradient::Standard)),
                &ex,
                &interior,
            ),
            e2(
                &gx(sph_gradient(&nl, &vol, &phi, SphGradient::Difference)),
                &ex,
                &interior,
            ),
            e2(&gx(csph_gradient(&nl, &vol, &phi)), &ex, &interior),
            e2(&gx(lsg), &ex, &interior),
            e2(&sph_laplacian_brookshaw(&nl, &vol, &phi), &el, &interior),
            e2(&lsl, &el, &interior),
            e2(
                &gx(grad_renormalised(&nlw, &volw, &r, &phi)),
                &ex,
                &interior,
            ),
            e2(&laplacian(&nlw, &volw, &phi), &el, &interior),
        ]);
        dxs.push(dx);
        // the classical interpolant does not reproduce constants: Σ_j W V_j ≠ 1 (order 0)
        let one = interpolate_at_particles(&nl, &vol, &vec![1.0; x.len()]);
        let defect = interior
            .iter()
            .map(|&i| (one[i] - 1.0).abs())
            .fold(0.0, f64::max);
        assert!(
            defect > 1e-3,
            "partition of unity unexpectedly exact ({defect:e})"
        );
    }
    let names = [
        ("classical standard gradient", -1.0),
        ("classical difference gradient", 0.0),
        ("CSPH gradient", 1.0),
        ("LS gradient (q = 2)", 2.0),
        ("Brookshaw Laplacian", -1.0),
        ("LS Laplacian (q = 2)", 1.0),
        ("renormalised GPM gradient", 1.0),
        ("GPM Laplacian", -1.0),
    ];
    for (k, (name, theory)) in names.iter().enumerate() {
        let e: Vec<f64> = errs.iter().map(|r| r[k]).collect();
        let s = slope(&dxs, &e);
        assert!(
            (s - theory).abs() <= 0.4,
            "{name}: measured order {s:.2}, theory {theory} (errors {e:?})"
        );
    }
}
