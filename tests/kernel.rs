//! Reference weights: the defining properties of the set `W` of Imoto 2019 §2
//! (`w > 0` on `(0,1)`, `w = 0` for `r ≥ 1`, `∫_{ℝ^d} w(|x|) dx = 1`) checked against an
//! independent quadrature written here, derivatives against finite differences, and parsing.

mod common;

use common::WEIGHTS;
use gpm::kernel::{Kernel, Weight};
use std::f64::consts::PI;
use std::str::FromStr;

/// Gauss–Legendre nodes and weights on `[−1, 1]` by Newton's method on `P_n` (independent of
/// anything in the crate).
fn gauss_legendre(n: usize) -> Vec<(f64, f64)> {
    let mut out = Vec::with_capacity(n);
    for k in 0..n {
        // Tricomi's initial guess
        let mut x = (PI * (k as f64 + 0.75) / (n as f64 + 0.5)).cos();
        let mut dp = 0.0;
        for _ in 0..100 {
            // P_n(x) and P_n'(x) by the three-term recurrence
            let (mut p0, mut p1) = (1.0, x);
            for m in 2..=n {
                let p2 = ((2 * m - 1) as f64 * x * p1 - (m - 1) as f64 * p0) / m as f64;
                p0 = p1;
                p1 = p2;
            }
            dp = n as f64 * (x * p1 - p0) / (x * x - 1.0);
            let step = p1 / dp;
            x -= step;
            if step.abs() < 1e-16 {
                break;
            }
        }
        out.push((x, 2.0 / ((1.0 - x * x) * dp * dp)));
    }
    out
}

/// `∫_a^b f` by composite Gauss–Legendre (`panels` panels of `gl.len()` points).
fn integrate(f: impl Fn(f64) -> f64, a: f64, b: f64, panels: usize, gl: &[(f64, f64)]) -> f64 {
    let w = (b - a) / panels as f64;
    let mut s = 0.0;
    for p in 0..panels {
        let (lo, hi) = (a + p as f64 * w, a + (p + 1) as f64 * w);
        let (c, r) = (0.5 * (lo + hi), 0.5 * (hi - lo));
        for &(x, wt) in gl {
            s += wt * r * f(c + r * x);
        }
    }
    s
}

/// Every weight of the common list plus more of the polynomial family.
fn all_weights() -> Vec<Weight> {
    let mut v = WEIGHTS.to_vec();
    for p in [0, 1, 2, 5, 20] {
        for m in [1, 2, 3, 6, 20] {
            let w = Weight::Poly { p, m };
            if !v.contains(&w) {
                v.push(w);
            }
        }
    }
    v
}

/// `|S^{d−1}|`: 2π in 2D, 4π in 3D.
fn sphere(d: usize) -> f64 {
    match d {
        2 => 2.0 * PI,
        3 => 4.0 * PI,
        _ => unreachable!(),
    }
}

/// `∫_{ℝ^d} w_h(|x|) dx = |S^{d−1}| ∫_0^h w_h(r) r^{d−1} dr` for the scaled kernel.
fn total_mass<const D: usize>(k: &Kernel<D>, gl: &[(f64, f64)]) -> f64 {
    // panels: 64 over [0, h]; the cubic spline's break at h/2 is a panel boundary
    sphere(D) * integrate(|r| k.w_h(r) * r.powi(D as i32 - 1), 0.0, k.h(), 64, gl)
}

#[test]
fn gauss_legendre_is_exact_for_polynomials() {
    // self-check of the quadrature: ∫_0^1 x^k dx = 1/(k+1) for k ≤ 2n − 1
    let gl = gauss_legendre(10);
    for k in 0..20 {
        let got = integrate(|x| x.powi(k), 0.0, 1.0, 1, &gl);
        assert!((got - 1.0 / (k as f64 + 1.0)).abs() < 1e-14, "x^{k}: {got}");
    }
}

#[test]
fn every_weight_has_unit_integral_in_2d_and_3d() {
    let gl = gauss_legendre(10);
    for w in all_weights() {
        for h in [1.0, 0.37, 2.5] {
            let m2 = total_mass(&Kernel::<2>::new(w, h), &gl);
            let m3 = total_mass(&Kernel::<3>::new(w, h), &gl);
            assert!((m2 - 1.0).abs() < 1e-12, "{w} h={h}: 2D mass {m2}");
            assert!((m3 - 1.0).abs() < 1e-12, "{w} h={h}: 3D mass {m3}");
        }
        // the unscaled reference weight too
        let k2 = Kernel::<2>::new(w, 1.0);
        let k3 = Kernel::<3>::new(w, 1.0);
        let r2 = sphere(2) * integrate(|r| k2.w_ref(r) * r, 0.0, 1.0, 64, &gl);
        let r3 = sphere(3) * integrate(|r| k3.w_ref(r) * r * r, 0.0, 1.0, 64, &gl);
        assert!((r2 - 1.0).abs() < 1e-12, "{w}: 2D w_ref mass {r2}");
        assert!((r3 - 1.0).abs() < 1e-12, "{w}: 3D w_ref mass {r3}");
    }
}

#[test]
fn unnormalised_integrals_match_closed_forms() {
    // |S^{d−1}| ∫_0^1 r^{d−1} f(r) dr worked out by hand with Beta integrals
    // B(a, b) = (a−1)!(b−1)!/(a+b−1)! (independent of the crate's normalisation table):
    // cubic 2D: 2π (7/80); 3D: 4π (1/32);
    // Wendland C2 2D: 2π (B(2,5) + 4B(3,5)) = 2π/14; 3D: 4π (B(3,5) + 4B(4,5)) = 4π/42;
    // Wendland C4 2D: 2π (B(2,7) + 6B(3,7) + 35/3 B(4,7)) = 2π/18;
    //             3D: 4π (B(3,7) + 6B(4,7) + 35/3 B(5,7)) = 4π (8/495).
    let gl = gauss_legendre(10);
    let exact_2d = [
        (Weight::CubicSpline, 7.0 * PI / 40.0),
        (Weight::WendlandC2, PI / 7.0),
        (Weight::WendlandC4, PI / 9.0),
    ];
    let exact_3d = [
        (Weight::CubicSpline, PI / 8.0),
        (Weight::WendlandC2, 2.0 * PI / 21.0),
        (Weight::WendlandC4, 32.0 * PI / 495.0),
    ];
    for (w, v) in exact_2d {
        let q = 2.0 * PI * integrate(|r| w.shape(r) * r, 0.0, 1.0, 64, &gl);
        assert!((q - v).abs() < 1e-14 * v, "{w} 2D: {q} vs {v}");
    }
    for (w, v) in exact_3d {
        let q = 4.0 * PI * integrate(|r| w.shape(r) * r * r, 0.0, 1.0, 64, &gl);
        assert!((q - v).abs() < 1e-14 * v, "{w} 3D: {q} vs {v}");
    }
    // polynomial family: ∫_0^1 r^{d−1+p} (1−r)^m dr = B(d+p, m+1), checked for a small case by
    // hand: p = 0, m = 1, d = 2: ∫ r (1 − r) dr = 1/6
    let q = integrate(
        |r| Weight::Poly { p: 0, m: 1 }.shape(r) * r,
        0.0,
        1.0,
        1,
        &gl,
    );
    assert!((q - 1.0 / 6.0).abs() < 1e-15);
}

#[test]
fn compact_support_and_positivity() {
    for w in all_weights() {
        // w = 0 for r ≥ 1, including exactly 1, huge, infinite; NaN gives 0 as well
        for r in [1.0, 1.0 + 1e-15, 1.5, 2.0, 1e10, f64::INFINITY, f64::NAN] {
            assert_eq!(w.shape(r), 0.0, "{w} shape({r})");
            assert_eq!(w.dshape(r), 0.0, "{w} dshape({r})");
        }
        // w > 0 on (0, 1), sampled densely and near both ends
        let mut rs: Vec<f64> = (1..2000).map(|k| k as f64 / 2000.0).collect();
        rs.extend([1e-6, 1e-3, 1.0 - 1e-3, 1.0 - 1e-6, 0.5, 0.5 - 1e-12]);
        for r in rs {
            assert!(w.shape(r) > 0.0, "{w}: w({r}) = {} ≤ 0", w.shape(r));
        }
        // continuity at the support edge
        assert!(w.shape(1.0 - 1e-9) < 1e-8, "{w} not continuous at 1");
        // scaled kernel: zero from h on
        for h in [0.1, 1.0, 3.0] {
            let k2 = Kernel::<2>::new(w, h);
            let k3 = Kernel::<3>::new(w, h);
            assert_eq!(k2.w_h(h), 0.0);
            assert_eq!(k3.w_h(h), 0.0);
            assert_eq!(k2.w_h(2.0 * h), 0.0);
            assert!(k2.w_h(0.5 * h) > 0.0 && k3.w_h(0.5 * h) > 0.0);
        }
    }
}

#[test]
fn cubic_spline_pieces_join_smoothly() {
    // C² at r = ½: value 1/4, slope −3/2, curvature 6 from both pieces
    let w = Weight::CubicSpline;
    let left = |r: f64| 1.0 - 6.0 * r * r + 6.0 * r * r * r;
    let right = |r: f64| 2.0 * (1.0 - r).powi(3);
    assert!((left(0.5) - right(0.5)).abs() < 1e-15);
    assert!((w.shape(0.5) - 0.25).abs() < 1e-15);
    assert!((w.dshape(0.5 - 1e-13) - w.dshape(0.5)).abs() < 1e-11);
    assert!((w.dshape(0.5) + 1.5).abs() < 1e-14);
}

#[test]
fn derivatives_match_finite_differences() {
    // fourth-order central differences: error δ⁴ |f⁽⁵⁾| / 30 + O(ε |f| / δ). For r^p (1−r)^m,
    // |f⁽⁵⁾| / max|f'| grows like (p + m)⁴ ≤ 40⁴, so with δ = 1e-4 the truncation is below
    // 1e-16 · 40⁴ / 30 ≈ 1e-11 of max|f'| and the round-off about 1e-12: a 1e-7 bound is safe
    // and still catches any wrong coefficient.
    let delta = 1e-4;
    let fd = |f: &dyn Fn(f64) -> f64, r: f64| {
        (8.0 * (f(r + delta) - f(r - delta)) - (f(r + 2.0 * delta) - f(r - 2.0 * delta)))
            / (12.0 * delta)
    };
    for w in all_weights() {
        let scale = (1..1000)
            .map(|k| w.dshape(k as f64 / 1000.0).abs())
            .fold(0.0, f64::max)
            .max(1e-300);
        for k in 1..400 {
            let r = k as f64 / 400.0;
            if r < 3.0 * delta || r > 1.0 - 3.0 * delta {
                continue;
            }
            if w == Weight::CubicSpline && (r - 0.5).abs() < 3.0 * delta {
                continue;
            }
            let got = w.dshape(r);
            let want = fd(&|s| w.shape(s), r);
            assert!(
                (got - want).abs() <= 1e-7 * scale,
                "{w}: f'({r}) = {got}, finite difference {want}"
            );
        }
        // the scaled kernel: d/dr w_h(r) = w'(r/h) / h^{d+1} (times the normalisation)
        for h in [0.3, 2.0] {
            let k = Kernel::<3>::new(w, h);
            for q in [0.1, 0.3, 0.7, 0.9] {
                let r = q * h;
                let d = 1e-3 * h;
                let num = (8.0 * (k.w_h(r + d) - k.w_h(r - d))
                    - (k.w_h(r + 2.0 * d) - k.w_h(r - 2.0 * d)))
                    / (12.0 * d);
                let got = k.dw_h(r);
                let s = scale * w.normalisation(3) / h.powi(4);
                assert!(
                    (got - num).abs() <= 1e-7 * s,
                    "{w} h={h} r={r}: dw_h {got} vs {num}"
                );
            }
        }
    }
}

#[test]
fn weight_names_round_trip() {
    for w in all_weights() {
        let s = w.to_string();
        assert_eq!(Weight::from_str(&s), Ok(w), "'{s}'");
        // case and surrounding whitespace do not matter
        assert_eq!(
            Weight::from_str(&format!("  {}\t", s.to_uppercase())),
            Ok(w)
        );
        // serde (snake_case) round trip
        let j = serde_json::to_string(&w).unwrap();
        assert_eq!(serde_json::from_str::<Weight>(&j).unwrap(), w, "{j}");
    }
    for (alias, w) in [
        ("cubic_spline", Weight::CubicSpline),
        ("wendland_c2", Weight::WendlandC2),
        ("WendlandC4", Weight::WendlandC4),
        ("poly0-2", Weight::Poly { p: 0, m: 2 }),
    ] {
        assert_eq!(Weight::from_str(alias), Ok(w), "{alias}");
    }
}

#[test]
fn weight_parse_errors() {
    for bad in [
        "",
        "gauss",
        "gaussian",
        "poly",
        "poly3",
        "poly-2",
        "poly3-",
        "polyx-2",
        "poly1-y",
        "poly-1-2",
        "poly1-0",
        "poly21-2",
        "poly2-21",
        "wendland6",
        "cubic2",
    ] {
        let r = Weight::from_str(bad);
        assert!(r.is_err(), "'{bad}' parsed as {r:?}");
        assert!(!r.unwrap_err().is_empty());
    }
    // m = 0 would not vanish at r = 1: not a reference weight
    assert!(Weight::Poly { p: 2, m: 0 }.validate().is_err());
    assert!(Weight::Poly { p: 2, m: 1 }.validate().is_ok());
}

#[test]
#[should_panic]
fn normalisation_rejects_other_dimensions() {
    let _ = Weight::WendlandC2.normalisation(1);
}

#[test]
fn the_slice_evaluation_is_w_h_bit_for_bit() {
    // Kernel::w_and_wr2 (batched, as the neighbour list's measure) against w_h pair by pair:
    // w_h(√q) and w_h(√q)/q with ∞ at q = 0, zero beyond h, for every weight in 2D and 3D
    fn check<const D: usize>(w: Weight) {
        let h = 0.37;
        let k = Kernel::<D>::new(w, h);
        let rr: Vec<f64> = (0..=400)
            .map(|i| (i as f64 / 333.0 * h).powi(2))
            .chain([0.0, h * h, f64::MIN_POSITIVE])
            .collect();
        let (mut wv, mut wr2) = (vec![f64::NAN; rr.len()], vec![f64::NAN; rr.len()]);
        k.w_and_wr2(&rr, &mut wv, &mut wr2);
        for (i, &q) in rr.iter().enumerate() {
            let want = k.w_h(q.sqrt());
            assert_eq!(wv[i].to_bits(), want.to_bits(), "{w:?} D={D} q={q:e}");
            let want_r2 = if q > 0.0 { want / q } else { f64::INFINITY };
            assert_eq!(wr2[i].to_bits(), want_r2.to_bits(), "{w:?} D={D} q={q:e}");
        }
        assert!(wv.iter().zip(&rr).all(|(&v, &q)| q < h * h || v == 0.0));
        // the in-place form (squared distances in, weights out: the list's measure) gives
        // the same bits
        let (mut wi, mut wr2i) = (rr.clone(), vec![f64::NAN; rr.len()]);
        k.w_and_wr2_in_place(&mut wi, &mut wr2i);
        for i in 0..rr.len() {
            assert_eq!(wi[i].to_bits(), wv[i].to_bits(), "{w:?} D={D} in place");
            assert_eq!(wr2i[i].to_bits(), wr2[i].to_bits(), "{w:?} D={D} in place");
        }
    }
    for w in all_weights() {
        check::<2>(w);
        check::<3>(w);
    }
}
