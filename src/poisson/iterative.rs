//! Preconditioned conjugate gradients on the assembled CSR matrix, fused and rayon-parallel.
//!
//! Two entry points: [`pcg`], the Jacobi-preconditioned loop with the preconditioner fused into
//! the vector updates (no extra pass), and [`pcg_with`], the same iteration with any
//! [`Preconditioner`] (the AMG V-cycle of [`super::amg`]) applied between the updates.
//!
//! **Residual.** The solver works on the symmetric system `K x = b` (`b = ω∘rhs`); it stops when
//! `‖r‖₂ ≤ max(abs_tol, rel_tol ‖b‖₂)` for the recursively updated residual `r` (Euclidean norm),
//! then reports the true residual `‖b − K x‖₂` and `‖b − K x‖₂ / ‖b‖₂`, recomputed from `x`.
//! A warm-started scalar run can also stop once it has cut its initial residual by a set
//! factor ([`CgWork::set_warm_tol`], [`stop_tol`]).
//!
//! faer ships a matrix-free CG; this one exists because a fused loop over our own CSR (one pass
//! for `q = Kp` and `p·q`, one for the updates, the preconditioner and the dot products) was
//! measured faster on this kind of machine, and because faer 0.24.4's zero-initial-guess path
//! leaves its residual uninitialised.
//! On a floating component (`K` singular, consistent `b`) CG converges in the range of `K`; the
//! caller fixes the constant afterwards.

use super::assembly::Assembly;
use crate::error::SolveError;
use rayon::prelude::*;

const MIN_LEN: usize = 2048;
// Every parallel sum here splits at `.with_min_len(MIN_LEN).with_max_len(MIN_LEN)`: rayon then
// halves a range exactly while the halves hold at least MIN_LEN items, whatever the threads'
// work stealing did (with a minimum alone, a stolen piece is split further than one that was
// not), so partial sums are added in the same order and a solve gives the same bits every run.
// Measured before: two identical Lagrangian Taylor–Green runs differed in the 15th digit.

/// Result of a CG run.
#[derive(Clone, Copy, Debug, Default)]
pub struct CgInfo {
    /// Iterations.
    pub iters: usize,
    /// `‖b − K x‖₂`.
    pub abs_residual: f64,
    /// `‖b − K x‖₂ / ‖b‖₂` (0 when `b = 0`).
    pub rel_residual: f64,
    /// `‖b − K x₀‖₂` of the initial guess.
    pub initial_residual: f64,
    /// The recursively updated residual norm at the end (what the stopping test saw).
    pub final_residual: f64,
    /// `‖b‖₂` (global in a decomposed solve; 0 when `b = 0`).
    pub b_norm: f64,
}

impl CgInfo {
    /// `‖b − K x₀‖₂ / ‖b‖₂`: how far the initial guess was off (0 when `b = 0`).
    pub fn initial_rel_residual(&self) -> f64 {
        if self.b_norm > 0.0 {
            self.initial_residual / self.b_norm
        } else {
            0.0
        }
    }
}

/// A symmetric positive (semi-)definite approximation `B ≈ K⁻¹` applied as `z = B r`.
pub trait Preconditioner {
    /// `z = B r` (`z` need not be initialised).
    fn apply(&mut self, r: &[f64], z: &mut [f64]);
}

/// `B = D⁻¹` (`1` where the diagonal is not positive), as a [`Preconditioner`]; [`pcg`] is the
/// faster fused form of the same iteration.
#[derive(Clone, Debug)]
pub struct Jacobi {
    inv_diag: Vec<f64>,
}

impl Jacobi {
    /// The Jacobi preconditioner of `a`.
    pub fn new(a: &Assembly) -> Self {
        Jacobi {
            inv_diag: inv_diagonal(a),
        }
    }
}

impl Preconditioner for Jacobi {
    fn apply(&mut self, r: &[f64], z: &mut [f64]) {
        z.par_iter_mut()
            .zip(r.par_iter().zip(self.inv_diag.par_iter()))
            .with_min_len(MIN_LEN)
            .for_each(|(z, (r, m))| *z = r * m);
    }
}

fn inv_diagonal(a: &Assembly) -> Vec<f64> {
    let mut out = Vec::new();
    inv_diagonal_into(a, &mut out);
    out
}

/// [`inv_diagonal`] into `out` (its memory reused).
fn inv_diagonal_into(a: &Assembly, out: &mut Vec<f64>) {
    out.clear();
    out.extend(a.diag.iter().map(|&k| {
        let d = a.values[k];
        if d > 0.0 {
            1.0 / d
        } else {
            1.0
        }
    }));
}

/// `a · b`, split at fixed lengths (see `MIN_LEN`).
fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.par_iter()
        .zip(b.par_iter())
        .with_min_len(MIN_LEN)
        .with_max_len(MIN_LEN)
        .map(|(x, y)| x * y)
        .sum()
}

/// `Σ v_i²`, split at fixed lengths (see `MIN_LEN`).
fn sum_squares(v: &[f64]) -> f64 {
    dot(v, v)
}

pub(crate) fn true_residual(a: &Assembly, b: &[f64], x: &[f64]) -> f64 {
    true_residual_in(a, b, x, &mut Vec::new())
}

/// [`true_residual`] with `K x` in `kx` (its memory reused).
pub(crate) fn true_residual_in(a: &Assembly, b: &[f64], x: &[f64], kx: &mut Vec<f64>) -> f64 {
    kx.resize(a.n(), 0.0);
    a.spmv(x, kx);
    kx.par_iter()
        .zip(b.par_iter())
        .with_min_len(MIN_LEN)
        .with_max_len(MIN_LEN)
        .map(|(k, b)| (b - k) * (b - k))
        .sum::<f64>()
        .sqrt()
}

/// The report of a converged CG run: the true residual `‖b − Kx‖` (not the recursive one)
/// beside the recursive initial and final residuals.
#[allow(clippy::too_many_arguments)]
fn converged(
    a: &Assembly,
    b: &[f64],
    x: &[f64],
    bnorm: f64,
    iters: usize,
    r0: f64,
    rnorm: f64,
    scratch: &mut Vec<f64>,
) -> CgInfo {
    let true_r = true_residual_in(a, b, x, scratch);
    CgInfo {
        iters,
        abs_residual: true_r,
        rel_residual: true_r / bnorm,
        initial_residual: r0,
        final_residual: rnorm,
        b_norm: bnorm,
    }
}

/// `q_c = K p_c` for the `K` interleaved columns of `p`, returning every `p_c·q_c`, in one pass
/// over the matrix.
fn matvec_dot_multi<const K: usize>(
    a: Shifted<'_>,
    p: &[[f64; K]],
    q: &mut [[f64; K]],
) -> [f64; K] {
    q.par_iter_mut()
        .with_min_len(MIN_LEN)
        .with_max_len(MIN_LEN)
        .enumerate()
        .map(|(u, qu)| {
            let s = a.row_dot_multi(u, p);
            *qu = s;
            std::array::from_fn(|c| s[c] * p[u][c])
        })
        .reduce(|| [0.0; K], |x, y| std::array::from_fn(|c| x[c] + y[c]))
}

/// `‖b_c − K x_c‖₂` of every column, in one pass over the matrix.
fn true_residuals<const K: usize>(a: Shifted<'_>, b: &[&[f64]; K], x: &[[f64; K]]) -> [f64; K] {
    let s = (0..a.a.n())
        .into_par_iter()
        .with_min_len(MIN_LEN)
        .with_max_len(MIN_LEN)
        .map(|u| {
            let kx = a.row_dot_multi(u, x);
            std::array::from_fn(|c| (b[c][u] - kx[c]).powi(2))
        })
        .reduce(|| [0.0; K], |x, y| std::array::from_fn(|c| x[c] + y[c]));
    s.map(f64::sqrt)
}

/// [`pcg`] (Jacobi-preconditioned CG) on `K` right sides at once: each column keeps its own
/// recurrence, stopping test and report, while every product reads the matrix once for all
/// of them (the implicit viscous solve of moving particles, one column per velocity
/// component, whose matrix changes every step and whose solves take one or two iterations:
/// the products dominate). Equal to [`pcg`] on each column up to rounding. `x` holds the
/// initial guesses on entry.
pub fn pcg_multi<const K: usize>(
    a: &Assembly,
    b: [&[f64]; K],
    x: [&mut [f64]; K],
    rel_tol: f64,
    abs_tol: f64,
    max_iters: usize,
) -> Result<[CgInfo; K], SolveError> {
    let mut work = CgWork::default();
    pcg_multi_in(&mut work, a, b, x, rel_tol, abs_tol, max_iters)
}

/// The vectors of a CG run ([`pcg_in`], [`pcg_with_in`], [`pcg_multi_in`]: residual,
/// preconditioned residual, search direction, `K p`, the inverse diagonal of the fused Jacobi
/// loop), kept by a solver between its solves so that a solve every step allocates (and the
/// system clears) no new memory. Their contents between runs mean nothing.
///
/// It also carries the warm-start factor of the stopping test of [`pcg_in`] and
/// [`pcg_with_null_in`] ([`Self::set_warm_tol`]; 0, the default, leaves the test as documented
/// there).
#[derive(Clone, Debug, Default)]
pub struct CgWork {
    warm_tol: f64,
    inv_diag: Vec<f64>,
    xs: Vec<f64>,
    r: Vec<f64>,
    z: Vec<f64>,
    p: Vec<f64>,
    q: Vec<f64>,
}

impl CgWork {
    /// The four single-column vectors sized to `n` (values left as they were: every run
    /// writes each before it reads it).
    fn size(&mut self, n: usize) {
        for v in [&mut self.r, &mut self.z, &mut self.p, &mut self.q] {
            v.resize(n, 0.0);
        }
    }

    /// The warm-start factor `θ` of the next scalar runs on this work ([`stop_tol`]): a run
    /// whose initial guess leaves at most a tenth of `‖b‖₂` also stops once
    /// `‖r‖₂ ≤ θ ‖r₀‖₂` ([`super::SolveParams::warm_tol`]).
    pub fn set_warm_tol(&mut self, theta: f64) {
        self.warm_tol = theta;
    }
}

/// The largest relative warm-start residual `‖r₀‖₂/‖b‖₂` at which [`stop_tol`]'s warm-start
/// factor acts: a warm start that predicted at least 90 % of the right side (the shifted
/// Taylor–Green vortex's leaves 1–8 % of its source, the Lagrangian cavity's 18–800 %).
pub const WARM_RESIDUAL_MAX: f64 = 0.1;

/// The residual a CG run stops at: `max(abs_tol, rel_tol ‖b‖₂, θ ‖r₀‖₂)`, the last term only
/// when `θ > 0` and the initial guess is a warm start that has predicted most of the right
/// side, `‖r₀‖₂ ≤ WARM_RESIDUAL_MAX ‖b‖₂` ([`WARM_RESIDUAL_MAX`]; a cold start, `x₀ = 0`, has
/// `r₀ = b`) ([`super::SolveParams::warm_tol`]): such a run cuts the warm start's
/// residual — what the history did not predict — by `θ` rather than solving to `rel_tol` of
/// the whole right side. A warm start that predicts less leaves `rel_tol` alone.
pub fn stop_tol(abs_tol: f64, rel_tol: f64, warm_tol: f64, b_norm: f64, r0: f64) -> f64 {
    let tol = abs_tol.max(rel_tol * b_norm);
    if warm_tol > 0.0 && r0 <= WARM_RESIDUAL_MAX * b_norm {
        tol.max(warm_tol * r0)
    } else {
        tol
    }
}

/// The operator `s K + diag(d)` of an assembled `K`, applied without forming it: the implicit
/// viscous matrix `H = W + c K` of moving particles read from the step's Poisson matrix
/// (`s = c`, `d = ω`), whose values are new every step — forming `H` is a pass that writes
/// as many bytes as `K` holds (≈ 3 ms at 2D 10⁵), the products read the same bytes either way.
#[derive(Clone, Copy, Debug)]
pub struct Shifted<'a> {
    /// `K`.
    pub a: &'a Assembly,
    /// `s`.
    pub scale: f64,
    /// `d`, one per unknown (empty: none).
    pub shift: &'a [f64],
}

impl<'a> From<&'a Assembly> for Shifted<'a> {
    fn from(a: &'a Assembly) -> Self {
        Self::plain(a)
    }
}

impl<'a> Shifted<'a> {
    /// `K` itself.
    pub fn plain(a: &'a Assembly) -> Self {
        Self {
            a,
            scale: 1.0,
            shift: &[],
        }
    }

    /// `((s K + diag(d)) x)_u` for `K` columns at once.
    #[inline]
    fn row_dot_multi<const K: usize>(&self, u: usize, x: &[[f64; K]]) -> [f64; K] {
        let (cols, values) = self.a.row(u);
        let kx = crate::math::sparse_dot_multi(values, cols, x);
        if self.shift.is_empty() {
            return kx;
        }
        std::array::from_fn(|c| self.scale * kx[c] + self.shift[u] * x[u][c])
    }

    /// `1 / diag` (1 where the diagonal is not positive), into `out`.
    fn inv_diagonal_into(&self, out: &mut Vec<f64>) {
        if self.shift.is_empty() {
            return inv_diagonal_into(self.a, out);
        }
        out.resize(self.a.n(), 0.0);
        out.par_iter_mut()
            .zip(self.a.diag.par_iter().zip(self.shift.par_iter()))
            .with_min_len(MIN_LEN)
            .for_each(|(o, (&k, &d))| {
                let v = self.scale * self.a.values[k] + d;
                *o = if v > 0.0 { 1.0 / v } else { 1.0 };
            });
    }
}

/// [`pcg_multi`] with its vectors in `work` (reused: no allocation once they have grown to
/// the problem's size), on an assembled matrix or on `s K + diag(d)` ([`Shifted`], not
/// formed).
pub fn pcg_multi_in<'a, const K: usize>(
    work: &mut CgWork,
    a: impl Into<Shifted<'a>>,
    b: [&[f64]; K],
    x: [&mut [f64]; K],
    rel_tol: f64,
    abs_tol: f64,
    max_iters: usize,
) -> Result<[CgInfo; K], SolveError> {
    let a: Shifted<'a> = a.into();
    let n = a.a.n();
    a.inv_diagonal_into(&mut work.inv_diag);
    let inv_diag = &work.inv_diag;
    let bnorm: [f64; K] = std::array::from_fn(|c| sum_squares(b[c]).sqrt());
    let tol: [f64; K] = std::array::from_fn(|c| abs_tol.max(rel_tol * bnorm[c]));
    for v in [
        &mut work.xs,
        &mut work.r,
        &mut work.z,
        &mut work.p,
        &mut work.q,
    ] {
        v.clear();
        v.resize(n * K, 0.0);
    }
    let (xs, _) = work.xs.as_chunks_mut::<K>();
    let (r, _) = work.r.as_chunks_mut::<K>();
    let (z, _) = work.z.as_chunks_mut::<K>();
    let (p, _) = work.p.as_chunks_mut::<K>();
    let (q, _) = work.q.as_chunks_mut::<K>();
    for (i, v) in xs.iter_mut().enumerate() {
        for c in 0..K {
            v[c] = if bnorm[c] == 0.0 { 0.0 } else { x[c][i] };
        }
    }
    matvec_dot_multi(a, xs, r);
    r.par_iter_mut()
        .enumerate()
        .with_min_len(MIN_LEN)
        .for_each(|(i, ri)| {
            for c in 0..K {
                ri[c] = b[c][i] - ri[c];
            }
        });
    for ((zi, ri), m) in z.iter_mut().zip(r.iter()).zip(inv_diag) {
        *zi = ri.map(|v| v * m);
    }
    p.copy_from_slice(z);
    let sums = |u: &[[f64; K]], v: &[[f64; K]]| -> [f64; K] {
        u.par_iter()
            .zip(v.par_iter())
            .with_min_len(MIN_LEN)
            .with_max_len(MIN_LEN)
            .map(|(a, b)| std::array::from_fn(|c| a[c] * b[c]))
            .reduce(|| [0.0; K], |x, y| std::array::from_fn(|c| x[c] + y[c]))
    };
    let mut rz = sums(r, z);
    let mut rnorm = sums(r, r).map(f64::sqrt);
    let r0 = rnorm;
    // a column is active until it has converged (or has a zero right side)
    let mut active: [bool; K] = std::array::from_fn(|c| bnorm[c] > 0.0 && rnorm[c] > tol[c]);
    let mut iters = [0usize; K];
    while active.iter().any(|&a| a) {
        for c in 0..K {
            if active[c] && iters[c] >= max_iters {
                let true_r = true_residuals(a, &b, xs)[c];
                return Err(SolveError::NoConvergence {
                    iters: iters[c],
                    abs_residual: true_r,
                    rel_residual: true_r / bnorm[c],
                });
            }
        }
        let pq = matvec_dot_multi(a, p, q);
        let mut alpha = [0.0; K];
        for c in (0..K).filter(|&c| active[c]) {
            if pq[c].is_nan() || pq[c] <= 0.0 {
                return Err(SolveError::Backend(format!(
                    "conjugate gradients: p·Kp = {:e} ≤ 0 at iteration {} (matrix not positive definite on the search direction)",
                    pq[c], iters[c]
                )));
            }
            alpha[c] = rz[c] / pq[c];
        }
        let (rz_new, rr) = xs
            .par_iter_mut()
            .zip(r.par_iter_mut())
            .zip(z.par_iter_mut())
            .zip(p.par_iter().zip(q.par_iter()).zip(inv_diag.par_iter()))
            .with_min_len(MIN_LEN)
            .with_max_len(MIN_LEN)
            .map(|(((xi, ri), zi), ((pi, qi), mi))| {
                let mut out = ([0.0; K], [0.0; K]);
                for c in 0..K {
                    xi[c] += alpha[c] * pi[c];
                    ri[c] -= alpha[c] * qi[c];
                    zi[c] = ri[c] * mi;
                    out.0[c] = ri[c] * zi[c];
                    out.1[c] = ri[c] * ri[c];
                }
                out
            })
            .reduce(
                || ([0.0; K], [0.0; K]),
                |x, y| {
                    (
                        std::array::from_fn(|c| x.0[c] + y.0[c]),
                        std::array::from_fn(|c| x.1[c] + y.1[c]),
                    )
                },
            );
        let mut beta = [0.0; K];
        for c in (0..K).filter(|&c| active[c]) {
            beta[c] = rz_new[c] / rz[c];
            rz[c] = rz_new[c];
            rnorm[c] = rr[c].sqrt();
            iters[c] += 1;
            if !rnorm[c].is_finite() {
                return Err(SolveError::Backend(format!(
                    "conjugate gradients: residual became {} at iteration {}",
                    rnorm[c], iters[c]
                )));
            }
        }
        p.par_iter_mut()
            .zip(z.par_iter())
            .with_min_len(MIN_LEN)
            .for_each(|(pi, zi)| {
                for c in 0..K {
                    if active[c] {
                        pi[c] = zi[c] + beta[c] * pi[c];
                    }
                }
            });
        for c in 0..K {
            active[c] = active[c] && rnorm[c] > tol[c];
        }
    }
    let true_r = true_residuals(a, &b, xs);
    for (c, xc) in x.into_iter().enumerate() {
        for (xi, v) in xc.iter_mut().zip(xs.iter()) {
            *xi = v[c];
        }
    }
    Ok(std::array::from_fn(|c| CgInfo {
        iters: iters[c],
        abs_residual: true_r[c],
        rel_residual: if bnorm[c] > 0.0 {
            true_r[c] / bnorm[c]
        } else {
            0.0
        },
        initial_residual: r0[c],
        final_residual: rnorm[c],
        b_norm: bnorm[c],
    }))
}

/// `q = K p`, returning `p·q`, in one pass.
fn matvec_dot(a: &Assembly, p: &[f64], q: &mut [f64]) -> f64 {
    q.par_iter_mut()
        .with_min_len(MIN_LEN)
        .with_max_len(MIN_LEN)
        .enumerate()
        .map(|(u, qu)| {
            let s = a.row_dot(u, p);
            *qu = s;
            s * p[u]
        })
        .sum()
}

/// Preconditioned CG from the initial guess in `x` with the preconditioner `m` (symmetric
/// positive definite, or semi-definite and positive on the range of `K` for a floating
/// component). Same stopping test and reports as [`pcg`].
#[allow(clippy::too_many_arguments)]
pub fn pcg_with<M: Preconditioner + ?Sized>(
    a: &Assembly,
    b: &[f64],
    x: &mut [f64],
    rel_tol: f64,
    abs_tol: f64,
    max_iters: usize,
    m: &mut M,
) -> Result<CgInfo, SolveError> {
    pcg_with_null(a, b, x, rel_tol, abs_tol, max_iters, m, &[])
}

/// [`pcg_with`] on the vectors of `work` (no allocation once they have grown to `K`'s size).
#[allow(clippy::too_many_arguments)]
pub fn pcg_with_in<M: Preconditioner + ?Sized>(
    a: &Assembly,
    b: &[f64],
    x: &mut [f64],
    rel_tol: f64,
    abs_tol: f64,
    max_iters: usize,
    m: &mut M,
    work: &mut CgWork,
) -> Result<CgInfo, SolveError> {
    pcg_with_null_in(a, b, x, rel_tol, abs_tol, max_iters, m, &[], work)
}

/// Removes the plain mean of `v` over each set of unknowns in `null` (the constant null vector
/// of a floating component); returns `|v|²`.
fn project_null(v: &mut [f64], null: &[&[u32]]) -> f64 {
    for comp in null {
        if comp.is_empty() {
            continue;
        }
        let mean = comp.iter().map(|&u| v[u as usize]).sum::<f64>() / comp.len() as f64;
        for &u in comp.iter() {
            v[u as usize] -= mean;
        }
    }
    sum_squares(v)
}

/// [`pcg_with`] for a singular system whose null space is spanned by the constants on the
/// unknown sets `null` (one per floating component). The residual and the preconditioned
/// residual are kept orthogonal to it at every iteration: in floating point, `1ᵀK p` is not
/// exactly zero, and at 10⁶ unknowns the drift otherwise grows until the search direction is a
/// near-constant with `p·Kp ≈ 0` (found by the benchmark: breakdown at iteration 27). An
/// inconsistent part of `b` (along the constants) is removed as well — the least-squares solution.
#[allow(clippy::too_many_arguments)]
pub fn pcg_with_null<M: Preconditioner + ?Sized>(
    a: &Assembly,
    b: &[f64],
    x: &mut [f64],
    rel_tol: f64,
    abs_tol: f64,
    max_iters: usize,
    m: &mut M,
    null: &[&[u32]],
) -> Result<CgInfo, SolveError> {
    let mut work = CgWork::default();
    pcg_with_null_in(a, b, x, rel_tol, abs_tol, max_iters, m, null, &mut work)
}

/// [`pcg_with_null`] on the vectors of `work` (no allocation once they have grown to `K`'s
/// size), stopping at [`stop_tol`] with `work`'s warm-start factor ([`CgWork::set_warm_tol`]).
#[allow(clippy::too_many_arguments)]
pub fn pcg_with_null_in<M: Preconditioner + ?Sized>(
    a: &Assembly,
    b: &[f64],
    x: &mut [f64],
    rel_tol: f64,
    abs_tol: f64,
    max_iters: usize,
    m: &mut M,
    null: &[&[u32]],
    work: &mut CgWork,
) -> Result<CgInfo, SolveError> {
    let bnorm = sum_squares(b).sqrt();
    if bnorm == 0.0 {
        x.iter_mut().for_each(|v| *v = 0.0);
        return Ok(CgInfo::default());
    }
    work.size(a.n());
    let warm_tol = work.warm_tol;
    let CgWork { r, z, p, q, .. } = work;
    a.spmv(x, r);
    r.par_iter_mut()
        .zip(b.par_iter())
        .with_min_len(MIN_LEN)
        .for_each(|(ri, bi)| *ri = bi - *ri);
    let mut rnorm = if null.is_empty() {
        sum_squares(r).sqrt()
    } else {
        project_null(r, null).sqrt()
    };
    let r0 = rnorm;
    let tol = stop_tol(abs_tol, rel_tol, warm_tol, bnorm, r0);
    let mut rz = 0.0;
    let mut iters = 0;
    while rnorm > tol {
        if iters >= max_iters {
            let true_r = true_residual_in(a, b, x, q);
            return Err(SolveError::NoConvergence {
                iters,
                abs_residual: true_r,
                rel_residual: true_r / bnorm,
            });
        }
        m.apply(r, z);
        if !null.is_empty() {
            project_null(z, null);
        }
        let rz_new = dot(r, z);
        if rz_new.is_nan() || rz_new <= 0.0 {
            return Err(SolveError::Backend(format!(
                "preconditioned conjugate gradients: r·Br = {rz_new:e} ≤ 0 at iteration {iters} (preconditioner not positive definite)"
            )));
        }
        let beta = if iters == 0 { 0.0 } else { rz_new / rz };
        rz = rz_new;
        if iters == 0 {
            // the kept vector holds the last run's direction (or anything): not read
            p.copy_from_slice(z);
        } else {
            p.par_iter_mut()
                .zip(z.par_iter())
                .with_min_len(MIN_LEN)
                .for_each(|(pi, zi)| *pi = zi + beta * *pi);
        }
        let pq = matvec_dot(a, p, q);
        if pq.is_nan() || pq <= 0.0 {
            return Err(SolveError::Backend(format!(
                "conjugate gradients: p·Kp = {pq:e} ≤ 0 at iteration {iters} (matrix not positive definite on the search direction)"
            )));
        }
        let alpha = rz / pq;
        let rr: f64 = x
            .par_iter_mut()
            .zip(r.par_iter_mut())
            .zip(p.par_iter().zip(q.par_iter()))
            .with_min_len(MIN_LEN)
            .with_max_len(MIN_LEN)
            .map(|((xi, ri), (pi, qi))| {
                *xi += alpha * pi;
                *ri -= alpha * qi;
                *ri * *ri
            })
            .sum();
        rnorm = if null.is_empty() {
            rr.sqrt()
        } else {
            project_null(r, null).sqrt()
        };
        iters += 1;
        if !rnorm.is_finite() {
            return Err(SolveError::Backend(format!(
                "conjugate gradients: residual became {rnorm} at iteration {iters}"
            )));
        }
    }
    Ok(converged(a, b, x, bnorm, iters, r0, rnorm, q))
}

/// Jacobi-preconditioned CG from the initial guess in `x`.
pub fn pcg(
    a: &Assembly,
    b: &[f64],
    x: &mut [f64],
    rel_tol: f64,
    abs_tol: f64,
    max_iters: usize,
) -> Result<CgInfo, SolveError> {
    pcg_in(a, b, x, rel_tol, abs_tol, max_iters, &mut CgWork::default())
}

/// [`pcg`] on the vectors of `work` (no allocation once they have grown to `K`'s size),
/// stopping at [`stop_tol`] with `work`'s warm-start factor ([`CgWork::set_warm_tol`]).
pub fn pcg_in(
    a: &Assembly,
    b: &[f64],
    x: &mut [f64],
    rel_tol: f64,
    abs_tol: f64,
    max_iters: usize,
    work: &mut CgWork,
) -> Result<CgInfo, SolveError> {
    inv_diagonal_into(a, &mut work.inv_diag);
    let bnorm = sum_squares(b).sqrt();
    if bnorm == 0.0 {
        x.iter_mut().for_each(|v| *v = 0.0);
        return Ok(CgInfo::default());
    }
    work.size(a.n());
    let CgWork {
        r,
        z,
        p,
        q,
        inv_diag,
        warm_tol,
        ..
    } = work;
    a.spmv(x, r);
    r.par_iter_mut()
        .zip(b.par_iter())
        .with_min_len(MIN_LEN)
        .for_each(|(ri, bi)| *ri = bi - *ri);
    for ((zi, ri), mi) in z.iter_mut().zip(r.iter()).zip(inv_diag.iter()) {
        *zi = ri * mi;
    }
    p.copy_from_slice(z);
    let mut rz = dot(r, z);
    let mut rnorm = sum_squares(r).sqrt();
    let r0 = rnorm;
    let tol = stop_tol(abs_tol, rel_tol, *warm_tol, bnorm, r0);
    let mut iters = 0;
    while rnorm > tol {
        if iters >= max_iters {
            // report the true residual ‖b − K x‖, as documented, not the recursive one
            let true_r = true_residual_in(a, b, x, q);
            return Err(SolveError::NoConvergence {
                iters,
                abs_residual: true_r,
                rel_residual: true_r / bnorm,
            });
        }
        // q = K p and p·q in one pass
        let pq = matvec_dot(a, p, q);
        if pq.is_nan() || pq <= 0.0 {
            return Err(SolveError::Backend(format!(
                "conjugate gradients: p·Kp = {pq:e} ≤ 0 at iteration {iters} (matrix not positive definite on the search direction)"
            )));
        }
        let alpha = rz / pq;
        // x += αp, r −= αq, z = M⁻¹ r, and the two dot products, in one pass
        let (rz_new, rr) = x
            .par_iter_mut()
            .zip(r.par_iter_mut())
            .zip(z.par_iter_mut())
            .zip(p.par_iter().zip(q.par_iter()).zip(inv_diag.par_iter()))
            .with_min_len(MIN_LEN)
            .with_max_len(MIN_LEN)
            .map(|(((xi, ri), zi), ((pi, qi), mi))| {
                *xi += alpha * pi;
                *ri -= alpha * qi;
                *zi = *ri * mi;
                (*ri * *zi, *ri * *ri)
            })
            .reduce(|| (0.0, 0.0), |a, b| (a.0 + b.0, a.1 + b.1));
        let beta = rz_new / rz;
        rz = rz_new;
        rnorm = rr.sqrt();
        p.par_iter_mut()
            .zip(z.par_iter())
            .with_min_len(MIN_LEN)
            .for_each(|(pi, zi)| *pi = zi + beta * *pi);
        iters += 1;
        if !rnorm.is_finite() {
            return Err(SolveError::Backend(format!(
                "conjugate gradients: residual became {rnorm} at iteration {iters}"
            )));
        }
    }
    Ok(converged(a, b, x, bnorm, iters, r0, rnorm, q))
}
