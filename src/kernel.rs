//! Reference weight functions `w` of the generalized particle method.
//!
//! A reference weight (Imoto 2019, §2; Imoto, *Truncation error estimates*, §2) is a function
//! `w : [0, ∞) → ℝ` with `w(r) > 0` on `(0, 1)`, `w(r) = 0` for `r ≥ 1`, normalised so that
//! `∫_{ℝ^d} w(|x|) dx = 1`. The normalisation constant depends on the dimension `d`, so every
//! weight here is evaluated through [`Kernel<D>`], which fixes `d = D` and the influence radius
//! `h`: `w_h(r) = w(r / h) / h^d`.

use serde::{Deserialize, Serialize};
use std::f64::consts::PI;
use std::fmt;
use std::str::FromStr;

/// A reference weight function on `[0, 1]` (support radius 1).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Weight {
    /// Cubic B-spline (Monaghan & Lattanzio 1985), support radius 1:
    /// `1 − 6r² + 6r³` on `[0, ½)`, `2(1 − r)³` on `[½, 1)`.
    CubicSpline,
    /// Wendland C2: `(1 − r)⁴ (1 + 4r)`.
    WendlandC2,
    /// Wendland C4: `(1 − r)⁶ (1 + 6r + 35r²/3)`.
    WendlandC4,
    /// Polynomial family `r^p (1 − r)^m`: `m` sets the smoothness at `r = 1` (`C^{m−1}`), `p` the
    /// order of vanishing at `r = 0` (the property Hypothesis 6 of the truncation-error paper is
    /// about). `p = 0, m = 1` is the lowest-order polynomial weight.
    Poly {
        /// Power of `r` (vanishing order at the centre).
        p: u32,
        /// Power of `(1 − r)` (vanishing order at the support edge).
        m: u32,
    },
}

impl Weight {
    /// The unnormalised shape `f(r)`, `0 ≤ r`.
    #[inline]
    pub fn shape(&self, r: f64) -> f64 {
        if !(r < 1.0) {
            return 0.0;
        }
        match *self {
            Weight::CubicSpline => {
                if r < 0.5 {
                    1.0 - 6.0 * r * r + 6.0 * r * r * r
                } else {
                    let s = 1.0 - r;
                    2.0 * s * s * s
                }
            }
            Weight::WendlandC2 => {
                let s = 1.0 - r;
                let s2 = s * s;
                s2 * s2 * (1.0 + 4.0 * r)
            }
            Weight::WendlandC4 => {
                let s = 1.0 - r;
                let s3 = s * s * s;
                s3 * s3 * (1.0 + 6.0 * r + 35.0 / 3.0 * r * r)
            }
            Weight::Poly { p, m } => r.powi(p as i32) * (1.0 - r).powi(m as i32),
        }
    }

    /// The derivative `f'(r)` of the unnormalised shape.
    #[inline]
    pub fn dshape(&self, r: f64) -> f64 {
        if !(r < 1.0) {
            return 0.0;
        }
        match *self {
            Weight::CubicSpline => {
                if r < 0.5 {
                    -12.0 * r + 18.0 * r * r
                } else {
                    let s = 1.0 - r;
                    -6.0 * s * s
                }
            }
            Weight::WendlandC2 => {
                let s = 1.0 - r;
                -20.0 * r * s * s * s
            }
            Weight::WendlandC4 => {
                let s = 1.0 - r;
                let s5 = s * s * s * s * s;
                -(56.0 / 3.0) * r * (1.0 + 5.0 * r) * s5
            }
            Weight::Poly { p, m } => {
                let (p, m) = (p as i32, m as i32);
                let a = if p > 0 {
                    p as f64 * r.powi(p - 1) * (1.0 - r).powi(m)
                } else {
                    0.0
                };
                a - m as f64 * r.powi(p) * (1.0 - r).powi(m - 1)
            }
        }
    }

    /// `1 / ∫_{ℝ^d} f(|x|) dx`, from closed forms (checked against quadrature in the tests).
    pub fn normalisation(&self, d: usize) -> f64 {
        assert!(d == 2 || d == 3, "dimension must be 2 or 3");
        match (*self, d) {
            (Weight::CubicSpline, 2) => 40.0 / (7.0 * PI),
            (Weight::CubicSpline, 3) => 8.0 / PI,
            (Weight::WendlandC2, 2) => 7.0 / PI,
            (Weight::WendlandC2, 3) => 21.0 / (2.0 * PI),
            (Weight::WendlandC4, 2) => 9.0 / PI,
            (Weight::WendlandC4, 3) => 495.0 / (32.0 * PI),
            (Weight::Poly { p, m }, d) => {
                // ∫ r^{d-1} r^p (1-r)^m dr = B(d+p, m+1) = (d+p-1)! m! / (d+p+m)!
                let sphere = if d == 2 { 2.0 * PI } else { 4.0 * PI };
                let a = (d as u32 + p) as f64;
                let b = (m + 1) as f64;
                let beta = (ln_gamma(a) + ln_gamma(b) - ln_gamma(a + b)).exp();
                1.0 / (sphere * beta)
            }
            _ => unreachable!(),
        }
    }

    /// Checks the parameters of the polynomial family (`m ≥ 1` so that `w(1) = 0`).
    pub fn validate(&self) -> Result<(), String> {
        match *self {
            Weight::Poly { m: 0, .. } => {
                Err("poly weight needs m >= 1 (the weight must vanish at r = 1)".into())
            }
            Weight::Poly { p, m } if p > 20 || m > 20 => Err(format!(
                "poly weight p = {p}, m = {m}: powers above 20 are not supported"
            )),
            _ => Ok(()),
        }
    }
}

/// `ln Γ(x)` for positive integers and half-integers used by the polynomial family
/// (exact factorial for integers).
fn ln_gamma(x: f64) -> f64 {
    // x is a positive integer here.
    let n = x.round() as u64;
    debug_assert!((x - n as f64).abs() < 1e-12 && n >= 1);
    (1..n).map(|k| (k as f64).ln()).sum()
}

impl fmt::Display for Weight {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Weight::CubicSpline => write!(f, "cubic"),
            Weight::WendlandC2 => write!(f, "wendland2"),
            Weight::WendlandC4 => write!(f, "wendland4"),
            Weight::Poly { p, m } => write!(f, "poly{p}-{m}"),
        }
    }
}

impl FromStr for Weight {
    type Err = String;
    /// Parses `cubic`, `wendland2`, `wendland4` or `polyP-M` (e.g. `poly0-2`).
    fn from_str(s: &str) -> Result<Self, String> {
        let t = s.trim().to_ascii_lowercase();
        let w = match t.as_str() {
            "cubic" | "cubic_spline" => Weight::CubicSpline,
            "wendland2" | "wendland_c2" | "wendlandc2" => Weight::WendlandC2,
            "wendland4" | "wendland_c4" | "wendlandc4" => Weight::WendlandC4,
            _ => {
                let rest = t.strip_prefix("poly").ok_or_else(|| {
                    format!("unknown weight '{s}': expected cubic, wendland2, wendland4 or polyP-M")
                })?;
                let (p, m) = rest
                    .split_once('-')
                    .ok_or_else(|| format!("weight '{s}': expected polyP-M, e.g. poly0-2"))?;
                let p = p
                    .parse()
                    .map_err(|_| format!("weight '{s}': bad power p '{p}'"))?;
                let m = m
                    .parse()
                    .map_err(|_| format!("weight '{s}': bad power m '{m}'"))?;
                Weight::Poly { p, m }
            }
        };
        w.validate().map(|_| w)
    }
}

/// A weight fixed to dimension `D` and influence radius `h`: evaluates `w_h(r) = w(r/h)/h^D`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Kernel<const D: usize> {
    weight: Weight,
    h: f64,
    /// `1 / h`: `r / h` is taken as `r · (1/h)`, a multiplication where a division would
    /// hold up the measure's divider (see [`Self::w_and_wr2`]).
    inv_h: f64,
    /// normalisation / h^D
    scale: f64,
}

impl<const D: usize> Kernel<D> {
    /// A kernel with influence radius `h` (in distance units).
    pub fn new(weight: Weight, h: f64) -> Self {
        assert!(D == 2 || D == 3, "gpm supports D = 2 and D = 3");
        let scale = weight.normalisation(D) / h.powi(D as i32);
        Kernel {
            weight,
            h,
            inv_h: 1.0 / h,
            scale,
        }
    }
    /// The reference weight.
    pub fn weight(&self) -> Weight {
        self.weight
    }
    /// The influence radius `h`.
    pub fn h(&self) -> f64 {
        self.h
    }
    /// `w_h(r)`; zero for `r ≥ h`.
    #[inline]
    pub fn w_h(&self, r: f64) -> f64 {
        self.shape_at(r, |x| self.weight.shape(x))
    }
    /// `scale · shape(r/h)` with `r/h` as `r · (1/h)`, exactly zero from `r = h` on (where the
    /// product may round to just below 1).
    #[inline(always)]
    fn shape_at(&self, r: f64, shape: impl Fn(f64) -> f64) -> f64 {
        // a select on the argument, not a branch around the formula: the loop of
        // `w_and_wr2` stays vectorised (every shape is zero at 1)
        let x = if r < self.h { r * self.inv_h } else { 1.0 };
        self.scale * shape(x)
    }
    /// `w_h(√q)` and `w_h(√q) / q` (`∞` at `q = 0`) of every squared distance `q` of `rr`:
    /// bit for bit [`w_h`](Self::w_h) pair by pair, in a loop the compiler vectorises (the
    /// weight's formula is chosen once, not per pair) — the neighbour list's measure is
    /// otherwise bound by the divider's throughput (a square root and a division a pair).
    pub fn w_and_wr2(&self, rr: &[f64], w: &mut [f64], wr2: &mut [f64]) {
        match self.weight {
            Weight::CubicSpline => {
                self.w_and_wr2_with(rr, w, wr2, |r| Weight::CubicSpline.shape(r))
            }
            Weight::WendlandC2 => self.w_and_wr2_with(rr, w, wr2, |r| Weight::WendlandC2.shape(r)),
            Weight::WendlandC4 => self.w_and_wr2_with(rr, w, wr2, |r| Weight::WendlandC4.shape(r)),
            poly => self.w_and_wr2_with(rr, w, wr2, |r| poly.shape(r)),
        }
    }

    /// [`w_and_wr2`](Self::w_and_wr2) with the squared distances in `w` on entry, replaced
    /// by the weights (the same bits): the neighbour list's measure writes each pair's `r²`
    /// there and keeps no array of them.
    pub fn w_and_wr2_in_place(&self, w: &mut [f64], wr2: &mut [f64]) {
        match self.weight {
            Weight::CubicSpline => self.w_and_wr2_in(w, wr2, |r| Weight::CubicSpline.shape(r)),
            Weight::WendlandC2 => self.w_and_wr2_in(w, wr2, |r| Weight::WendlandC2.shape(r)),
            Weight::WendlandC4 => self.w_and_wr2_in(w, wr2, |r| Weight::WendlandC4.shape(r)),
            poly => self.w_and_wr2_in(w, wr2, |r| poly.shape(r)),
        }
    }

    #[inline(always)]
    fn w_and_wr2_with(
        &self,
        rr: &[f64],
        w: &mut [f64],
        wr2: &mut [f64],
        shape: impl Fn(f64) -> f64,
    ) {
        for ((&q, wv), wq) in rr.iter().zip(w.iter_mut()).zip(wr2.iter_mut()) {
            (*wv, *wq) = self.w_and_over(q, &shape);
        }
    }

    #[inline(always)]
    fn w_and_wr2_in(&self, w: &mut [f64], wr2: &mut [f64], shape: impl Fn(f64) -> f64) {
        for (wv, wq) in w.iter_mut().zip(wr2.iter_mut()) {
            (*wv, *wq) = self.w_and_over(*wv, &shape);
        }
    }

    /// `(w_h(√q), w_h(√q)/q)`, `∞` for the second at `q = 0`.
    #[inline(always)]
    fn w_and_over(&self, q: f64, shape: impl Fn(f64) -> f64) -> (f64, f64) {
        let v = self.shape_at(q.sqrt(), &shape);
        (v, if q > 0.0 { v / q } else { f64::INFINITY })
    }
    /// `dw_h/dr (r)`.
    #[inline]
    pub fn dw_h(&self, r: f64) -> f64 {
        self.scale * self.weight.dshape(r / self.h) / self.h
    }
    /// The normalised reference weight `w(q)` in dimension `D` (support radius 1).
    #[inline]
    pub fn w_ref(&self, q: f64) -> f64 {
        self.weight.normalisation(D) * self.weight.shape(q)
    }
}
