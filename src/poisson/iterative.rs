//! Preconditioned conjugate gradients on the assembled CSR matrix, fused and rayon-parallel.
//!
//! **Residual.** The solver works on the symmetric system `K x = b` (`b = ω∘rhs`); it stops when
//! `‖r‖₂ ≤ max(abs_tol, rel_tol ‖b‖₂)` for the recursively updated residual `r` (Euclidean norm),
//! then reports the true residual `‖b − K x‖₂` and `‖b − K x‖₂ / ‖b‖₂`, recomputed from `x`.
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

/// Result of a CG run.
#[derive(Clone, Copy, Debug, Default)]
pub struct CgInfo {
    /// Iterations.
    pub iters: usize,
    /// `‖b − K x‖₂`.
    pub abs_residual: f64,
    /// `‖b − K x‖₂ / ‖b‖₂` (0 when `b = 0`).
    pub rel_residual: f64,
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
    let n = a.n();
    let inv_diag: Vec<f64> = a
        .diagonal()
        .iter()
        .map(|&d| if d > 0.0 { 1.0 / d } else { 1.0 })
        .collect();
    let bnorm = b.par_iter().map(|v| v * v).sum::<f64>().sqrt();
    if bnorm == 0.0 {
        x.iter_mut().for_each(|v| *v = 0.0);
        return Ok(CgInfo::default());
    }
    let tol = abs_tol.max(rel_tol * bnorm);
    let mut r = vec![0.0; n];
    a.spmv(x, &mut r);
    r.par_iter_mut()
        .zip(b.par_iter())
        .with_min_len(MIN_LEN)
        .for_each(|(ri, bi)| *ri = bi - *ri);
    let mut z: Vec<f64> = r.iter().zip(&inv_diag).map(|(r, m)| r * m).collect();
    let mut p = z.clone();
    let mut q = vec![0.0; n];
    let mut rz: f64 = r.par_iter().zip(z.par_iter()).map(|(a, b)| a * b).sum();
    let mut rnorm = r.par_iter().map(|v| v * v).sum::<f64>().sqrt();
    let mut iters = 0;
    while rnorm > tol {
        if iters >= max_iters {
            // report the true residual ‖b − K x‖, as documented, not the recursive one
            let mut kx = vec![0.0; n];
            a.spmv(x, &mut kx);
            let true_r = kx
                .par_iter()
                .zip(b.par_iter())
                .map(|(k, b)| (b - k) * (b - k))
                .sum::<f64>()
                .sqrt();
            return Err(SolveError::NoConvergence {
                iters,
                abs_residual: true_r,
                rel_residual: true_r / bnorm,
            });
        }
        // q = K p and p·q in one pass
        let pq: f64 = q
            .par_iter_mut()
            .with_min_len(MIN_LEN)
            .enumerate()
            .map(|(u, qu)| {
                let mut s = 0.0;
                for k in a.offsets[u]..a.offsets[u + 1] {
                    s += a.values[k] * p[a.cols[k] as usize];
                }
                *qu = s;
                s * p[u]
            })
            .sum();
        if !(pq > 0.0) {
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
    // report the true residual, not the recursive one
    let mut kx = vec![0.0; n];
    a.spmv(x, &mut kx);
    let true_r = kx
        .par_iter()
        .zip(b.par_iter())
        .map(|(k, b)| (b - k) * (b - k))
        .sum::<f64>()
        .sqrt();
    Ok(CgInfo {
        iters,
        abs_residual: true_r,
        rel_residual: true_r / bnorm,
    })
}
