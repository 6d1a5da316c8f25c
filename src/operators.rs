//! The approximate operators of the generalized particle method (Imoto 2019, eqs. (1), (2) and
//! the gradient of Lemma 4.3; interpolant of Imoto, *Truncation error estimates*, eq. (10)).
//!
//! With `a'_ij = w_h(r_ij) / r_ij²` (cached in [`NeighborList::wr2`]) and sums over `j ≠ i` with
//! `r_ij < h`:
//!
//! | operator | definition |
//! | --- | --- |
//! | sum-form divergence `∇̂h·ψ_i` | `d Σ ω_j (ψ_j + ψ_i)·(x_j − x_i) a'_ij` |
//! | difference gradient `∇h φ_i` | `d Σ ω_j (φ_j − φ_i)(x_j − x_i) a'_ij` |
//! | Laplacian `Δh φ_i` | `2d Σ ω_j (φ_j − φ_i) a'_ij` |
//! | interpolant `Πh φ(x)` | `Σ ω_j φ_j w_h(|x − x_j|)` (all `j`, self included) |
//!
//! **Erratum.** Equation (2) of the stability paper prints `ω_i` inside the Laplacian sum; every
//! proof in the paper (the matrix `A D`, Lemma 4.3) uses `ω_j`, and so does this code.
//!
//! Each operator comes as an allocating function for tests and docs and as an `_into` twin that
//! writes into a caller's buffer. The output length decides how many rows are computed: pass
//! `&mut out[..n_fluid]` to skip the rows of ghosts stored after the fluid particles.

use crate::math::norm2;
use crate::neighbors::NeighborList;
use rayon::prelude::*;

const MIN_ROWS: usize = 256;

/// Sum-form divergence `∇̂h·ψ` into `out` (rows `0..out.len()`).
pub fn div_sum_into<const D: usize>(
    nl: &NeighborList<D>,
    vol: &[f64],
    psi: &[[f64; D]],
    out: &mut [f64],
) {
    out.par_iter_mut()
        .with_min_len(MIN_ROWS)
        .enumerate()
        .for_each(|(i, o)| *o = div_sum_row::<D, false>(nl, vol, psi, i).0);
}

/// [`div_sum_into`] that also returns `max_i Σ_j ω_j w_h(r_ij)/r_ij` over the rows `i` with
/// `counted(i)` (0 when none is): the row sums of `|∇̂h·|` are `2d` times that at most, read in
/// the same pass over the pairs.
pub fn div_sum_gain_into<const D: usize>(
    nl: &NeighborList<D>,
    vol: &[f64],
    psi: &[[f64; D]],
    out: &mut [f64],
    counted: impl Fn(usize) -> bool + Sync,
) -> f64 {
    rows_and_max(out, |i| div_sum_row::<D, true>(nl, vol, psi, i), counted)
}

/// `out[i] = row(i).0` for every row (in parallel), and the largest `row(i).1` over the rows
/// with `counted(i)` (0 when none is): an operator and a bound of its rows read in one pass.
pub(crate) fn rows_and_max(
    out: &mut [f64],
    row: impl Fn(usize) -> (f64, f64) + Sync,
    counted: impl Fn(usize) -> bool + Sync,
) -> f64 {
    out.par_iter_mut()
        .with_min_len(MIN_ROWS)
        .enumerate()
        .map(|(i, o)| {
            let (value, bound) = row(i);
            *o = value;
            if counted(i) {
                bound
            } else {
                0.0
            }
        })
        .reduce(|| 0.0, f64::max)
}

/// Row `i` of `∇̂h·ψ` and, with `GAIN`, `Σ_j ω_j w_h(r_ij)/r_ij` (0 without).
#[inline(always)]
fn div_sum_row<const D: usize, const GAIN: bool>(
    nl: &NeighborList<D>,
    vol: &[f64],
    psi: &[[f64; D]],
    i: usize,
) -> (f64, f64) {
    let pi = psi[i];
    let (mut s, mut g) = (0.0, 0.0);
    for k in nl.row(i) {
        let j = nl.indices()[k] as usize;
        let dx = &nl.dx()[k];
        let mut dot = 0.0;
        for a in 0..D {
            dot += (psi[j][a] + pi[a]) * dx[a];
        }
        s += vol[j] * dot * nl.wr2()[k];
        if GAIN {
            g += vol[j] * nl.wr2()[k] * norm2(dx).sqrt();
        }
    }
    (D as f64 * s, g)
}

/// Difference-form divergence `d Σ ω_j (ψ_j − ψ_i)·(x_j − x_i) a'_ij` (the trace of the
/// difference gradient): Galilean invariant, but not adjoint to `∇h`.
pub fn div_diff_into<const D: usize>(
    nl: &NeighborList<D>,
    vol: &[f64],
    psi: &[[f64; D]],
    out: &mut [f64],
) {
    let d = D as f64;
    out.par_iter_mut()
        .with_min_len(MIN_ROWS)
        .enumerate()
        .for_each(|(i, o)| {
            let pi = psi[i];
            let mut s = 0.0;
            for k in nl.row(i) {
                let j = nl.indices()[k] as usize;
                let dx = &nl.dx()[k];
                let mut dot = 0.0;
                for a in 0..D {
                    dot += (psi[j][a] - pi[a]) * dx[a];
                }
                s += vol[j] * dot * nl.wr2()[k];
            }
            *o = d * s;
        });
}

/// Sum-form divergence `∇̂h·ψ` at every particle.
pub fn div_sum<const D: usize>(nl: &NeighborList<D>, vol: &[f64], psi: &[[f64; D]]) -> Vec<f64> {
    let mut out = vec![0.0; nl.len()];
    div_sum_into(nl, vol, psi, &mut out);
    out
}

/// Difference gradient `∇h φ` into `out` (rows `0..out.len()`).
pub fn grad_diff_into<const D: usize>(
    nl: &NeighborList<D>,
    vol: &[f64],
    phi: &[f64],
    out: &mut [[f64; D]],
) {
    let d = D as f64;
    out.par_iter_mut()
        .with_min_len(MIN_ROWS)
        .enumerate()
        .for_each(|(i, o)| {
            let fi = phi[i];
            let mut s = [0.0; D];
            for k in nl.row(i) {
                let j = nl.indices()[k] as usize;
                let c = vol[j] * (phi[j] - fi) * nl.wr2()[k];
                let dx = &nl.dx()[k];
                for a in 0..D {
                    s[a] += c * dx[a];
                }
            }
            for a in 0..D {
                o[a] = d * s[a];
            }
        });
}

/// Difference gradients `∇h a` and `∇h b` of two fields in one pass over the pairs (the
/// pair data read once), into `out_a` and `out_b` (rows `0..out_a.len()`): bit for bit
/// [`grad_diff_into`] of each.
pub fn grad_diff2_into<const D: usize>(
    nl: &NeighborList<D>,
    vol: &[f64],
    a: &[f64],
    b: &[f64],
    out_a: &mut [[f64; D]],
    out_b: &mut [[f64; D]],
) {
    let d = D as f64;
    out_a
        .par_iter_mut()
        .zip(out_b.par_iter_mut())
        .with_min_len(MIN_ROWS)
        .enumerate()
        .for_each(|(i, (oa, ob))| {
            let (ai, bi) = (a[i], b[i]);
            let (mut sa, mut sb) = ([0.0; D], [0.0; D]);
            for k in nl.row(i) {
                let j = nl.indices()[k] as usize;
                let (v, w) = (vol[j], nl.wr2()[k]);
                let ca = v * (a[j] - ai) * w;
                let cb = v * (b[j] - bi) * w;
                let dx = &nl.dx()[k];
                for e in 0..D {
                    sa[e] += ca * dx[e];
                    sb[e] += cb * dx[e];
                }
            }
            for e in 0..D {
                oa[e] = d * sa[e];
                ob[e] = d * sb[e];
            }
        });
}

/// Difference gradient `∇h φ` at every particle.
pub fn grad_diff<const D: usize>(nl: &NeighborList<D>, vol: &[f64], phi: &[f64]) -> Vec<[f64; D]> {
    let mut out = vec![[0.0; D]; nl.len()];
    grad_diff_into(nl, vol, phi, &mut out);
    out
}

/// Laplacian `Δh φ` into `out` (rows `0..out.len()`).
pub fn laplacian_into<const D: usize>(
    nl: &NeighborList<D>,
    vol: &[f64],
    phi: &[f64],
    out: &mut [f64],
) {
    let c2d = 2.0 * D as f64;
    out.par_iter_mut()
        .with_min_len(MIN_ROWS)
        .enumerate()
        .for_each(|(i, o)| {
            let fi = phi[i];
            let mut s = 0.0;
            for k in nl.row(i) {
                let j = nl.indices()[k] as usize;
                s += vol[j] * (phi[j] - fi) * nl.wr2()[k];
            }
            *o = c2d * s;
        });
}

/// Laplacian `Δh φ` at every particle.
pub fn laplacian<const D: usize>(nl: &NeighborList<D>, vol: &[f64], phi: &[f64]) -> Vec<f64> {
    let mut out = vec![0.0; nl.len()];
    laplacian_into(nl, vol, phi, &mut out);
    out
}

/// Componentwise Laplacian `Δh u` of a vector field into `out` (rows `0..out.len()`).
pub fn laplacian_vec_into<const D: usize>(
    nl: &NeighborList<D>,
    vol: &[f64],
    u: &[[f64; D]],
    out: &mut [[f64; D]],
) {
    let c2d = 2.0 * D as f64;
    out.par_iter_mut()
        .with_min_len(MIN_ROWS)
        .enumerate()
        .for_each(|(i, o)| {
            let ui = u[i];
            let mut s = [0.0; D];
            for k in nl.row(i) {
                let j = nl.indices()[k] as usize;
                let c = vol[j] * nl.wr2()[k];
                for a in 0..D {
                    s[a] += c * (u[j][a] - ui[a]);
                }
            }
            for a in 0..D {
                o[a] = c2d * s[a];
            }
        });
}

/// Componentwise Laplacian `Δh u` of a vector field.
pub fn laplacian_vec<const D: usize>(
    nl: &NeighborList<D>,
    vol: &[f64],
    u: &[[f64; D]],
) -> Vec<[f64; D]> {
    let mut out = vec![[0.0; D]; nl.len()];
    laplacian_vec_into(nl, vol, u, &mut out);
    out
}

/// Row `i` of the velocity gradient by the difference gradient, `G_i[a][b] = (∇h u_a)_b`.
#[inline]
pub fn grad_vec_row<const D: usize>(
    nl: &NeighborList<D>,
    vol: &[f64],
    u: &[[f64; D]],
    i: usize,
) -> [[f64; D]; D] {
    grad_vec_row_impl::<D, false>(nl, vol, u, i).0
}

/// [`grad_vec_row`] and `Σ_j ω_j w_h(r_ij)/r_ij` of row `i` from the same pass over its pairs.
#[inline]
pub fn grad_vec_row_gain<const D: usize>(
    nl: &NeighborList<D>,
    vol: &[f64],
    u: &[[f64; D]],
    i: usize,
) -> ([[f64; D]; D], f64) {
    grad_vec_row_impl::<D, true>(nl, vol, u, i)
}

#[inline(always)]
fn grad_vec_row_impl<const D: usize, const GAIN: bool>(
    nl: &NeighborList<D>,
    vol: &[f64],
    u: &[[f64; D]],
    i: usize,
) -> ([[f64; D]; D], f64) {
    let ui = u[i];
    let mut s = [[0.0; D]; D];
    let mut g = 0.0;
    for k in nl.row(i) {
        let j = nl.indices()[k] as usize;
        let c = vol[j] * nl.wr2()[k];
        let dx = &nl.dx()[k];
        for a in 0..D {
            let du = c * (u[j][a] - ui[a]);
            for b in 0..D {
                s[a][b] += du * dx[b];
            }
        }
        if GAIN {
            g += c * norm2(dx).sqrt();
        }
    }
    let d = D as f64;
    for row in s.iter_mut() {
        for v in row.iter_mut() {
            *v *= d;
        }
    }
    (s, g)
}

/// Velocity-gradient tensor by the difference gradient, `G_i[a][b] = (∇h u_a)_b` into `out`.
pub fn grad_vec_into<const D: usize>(
    nl: &NeighborList<D>,
    vol: &[f64],
    u: &[[f64; D]],
    out: &mut [[[f64; D]; D]],
) {
    out.par_iter_mut()
        .with_min_len(MIN_ROWS)
        .enumerate()
        .for_each(|(i, o)| *o = grad_vec_row(nl, vol, u, i));
}

/// Interpolant `Πh φ(x_i) = Σ_j ω_j φ_j w_h(r_ij)` at the particles themselves (the self term
/// `ω_i φ_i w_h(0)` included).
pub fn interpolate_at_particles<const D: usize>(
    nl: &NeighborList<D>,
    vol: &[f64],
    phi: &[f64],
) -> Vec<f64> {
    let w0 = nl.kernel().w_h(0.0);
    (0..nl.len())
        .into_par_iter()
        .with_min_len(MIN_ROWS)
        .map(|i| {
            let mut s = vol[i] * phi[i] * w0;
            for k in nl.row(i) {
                let j = nl.indices()[k] as usize;
                s += vol[j] * phi[j] * nl.w()[k];
            }
            s
        })
        .collect()
}

/// Interpolant `Πh φ(y) = Σ_j ω_j φ_j w_h(|y − x_j|)` at arbitrary points `y` (brute force over
/// the particles within `h`, found with a k-d tree).
pub fn interpolate_at_points<const D: usize>(
    nl: &NeighborList<D>,
    x: &[[f64; D]],
    vol: &[f64],
    phi: &[f64],
    points: &[[f64; D]],
) -> Vec<f64> {
    let kernel = *nl.kernel();
    let h = kernel.h();
    let per = nl.config().periodic;
    let tree: kiddo::ImmutableKdTree<f64, D> =
        kiddo::ImmutableKdTree::new_from_slice(x).expect("k-d tree over finite positions");
    points
        .par_iter()
        .map(|y| {
            let mut s = 0.0;
            if per.any() {
                for (j, xj) in x.iter().enumerate() {
                    let mut d: [f64; D] = std::array::from_fn(|a| xj[a] - y[a]);
                    per.min_image(&mut d);
                    let r2 = norm2(&d);
                    if r2 < h * h {
                        s += vol[j] * phi[j] * kernel.w_h(r2.sqrt());
                    }
                }
            } else {
                tree.query(y)
                    .within::<kiddo::SquaredEuclidean<f64>>(h * h)
                    .unsorted()
                    .visit(|nb| {
                        let j = nb.item as usize;
                        if nb.distance < h * h {
                            s += vol[j] * phi[j] * kernel.w_h(nb.distance.sqrt());
                        }
                    });
            }
            s
        })
        .collect()
}
