//! Consistent (corrected) particle operators, and the classical SPH forms they are compared with.
//!
//! The GPM operators of [`crate::operators`] are consistent only where the neighbourhood is
//! symmetric: on a jittered or flow-deformed distribution the difference gradient `∇h` has an
//! `O(1)` error (its moment matrix is not the identity) and the Laplacian `Δh` and the sum-form
//! divergence `∇̂h·` an `O(1/h)` one (their first moment does not vanish) — Imoto, *Truncation
//! error estimates of approximate operators in a generalized particle method* (JJIAM 37, 2020),
//! Theorem 8 with regularity order 0; Shobuzako et al., *Verification of the discretization error
//! of classical SPH models based on the truncation error of the least squares SPH method*
//! (Table 1). This module holds the corrections that restore consistency and the classical forms
//! used to measure what they buy.
//!
//! Notation: `x_ji = x_j − x_i`, `r = |x_ji|`, `w_h` the kernel of the neighbour list, `ω_j` the
//! volumes; sums over the neighbours `j ≠ i` with `r < h` unless a self term is named.
//!
//! | operator | definition | order on disordered particles |
//! | --- | --- | --- |
//! | [`grad_renormalised`] | `∇ᶜφ_i = B_i ∇h φ_i`, `B_i = M_i⁻¹`, `M_i = d Σ ω_j x_ji⊗x_ji w_h/r²` | 1 (exact on linear fields) |
//! | [`Renormalisation::apply_transpose_into`] + [`crate::operators::div_sum_into`] | `∇̂h·(Bᵀψ)`: the divergence adjoint to `∇ᶜ` | as `∇̂h·` (−1) |
//! | [`div_renormalised`] | `∇ᶜ·ψ_i = Σ_a (B_i ∇h ψ_a)_a` | 1 (exact on linear fields) |
//! | [`ls_gradient_laplacian`] | weighted least squares, quadratic basis, `f_i` known | gradient 2, Laplacian 1 |
//! | [`ls_interpolate`] | weighted least squares, linear basis, self included | 2 |
//! | [`shepard_interpolate`] | `Σ f_j w ω / Σ w ω` (self included) | 1 |
//! | [`sph_gradient`] (standard / difference / sum) | `Σ f_j ∇_iW ω_j`, `Σ (f_j − f_i) ∇_iW ω_j`, `Σ (f_i + f_j) ∇_iW ω_j` | −1 / 0 / −1 |
//! | [`csph_gradient`] | Bonet & Lok: `B̃_i⁻¹ Σ (f_j − f_i) ∇_iW ω_j`, `B̃_i = Σ ∇_iW ⊗ x_ji ω_j` | 1 |
//! | [`sph_laplacian_brookshaw`] | `2 Σ ω_j (f_j − f_i) x_ji·∇_iW / r²` | −1 |
//!
//! with `∇_iW_ij = w_h'(r) (x_i − x_j)/r` (the kernel of the neighbour list plays the SPH kernel
//! `W`). The orders are in `Δx` at fixed `h/Δx` (Shobuzako et al., Table 1; Imoto's Theorem 8 with
//! regularity order 0 gives no convergence for the uncorrected GPM forms); `examples/operator_accuracy.rs`
//! measures them.
//!
//! **How the corrected gradient relates to the others.** `∇ᶜ` is the weighted least-squares
//! gradient with a linear basis, `f_i` known and weights `ω_j w_h/r²`:
//! it minimises `Σ_j ω_j w_h/r² (f_j − f_i − g·x_ji)²`, whose normal equations are
//! `M_i g = ∇h f_i`. With the weight `w̃(s) = −s W'(s)/d` it is exactly the CSPH gradient of an SPH
//! kernel `W` (then `∇h` is the classical difference form). On a lattice whose neighbourhoods
//! are symmetric under the axis reflections, `M_i = S_i I` (`S_i = Σ ω_j w_h`), so with the
//! number-density volumes (`S_i = 1`) `∇ᶜ = ∇h` there.
//!
//! **What it breaks.** The pair `∇̂h·` / `∇h` is discretely adjoint (Imoto 2019, Lemma 4.3):
//! `(∇̂h·ψ, φ) = −(ψ, ∇h φ)` with `(a, b) = Σ ω_i a_i·b_i`. With `∇ᶜ` in place of `∇h` the identity
//! holds with `∇̂h·(Bᵀψ)` in place of `∇̂h·ψ`, not with `∇̂h·ψ`. The projection uses the pair for its
//! source and its correction; [`GradientOperator`] is the plug-in a projection would hold, and the
//! example measures what each choice does to the projection.

use crate::neighbors::NeighborList;
use nalgebra::{DMatrix, DVector, Matrix2, Matrix3};
use rayon::prelude::*;

const MIN_ROWS: usize = 256;

/// A `D × D` matrix, row-major (`m[a][b]`).
pub type Mat<const D: usize> = [[f64; D]; D];

fn identity<const D: usize>() -> Mat<D> {
    std::array::from_fn(|a| std::array::from_fn(|b| if a == b { 1.0 } else { 0.0 }))
}

/// Inverse of a symmetric positive semi-definite `D × D` matrix, or `None` when it is too far
/// from isotropic to invert reliably: `det M / (tr M / D)^D < min_isotropy` (this ratio is 1
/// for a multiple of the identity and 0 for a singular matrix).
pub fn inverse_spd<const D: usize>(m: &Mat<D>, min_isotropy: f64) -> Option<Mat<D>> {
    let tr: f64 = (0..D).map(|a| m[a][a]).sum();
    if tr.is_nan() || tr <= 0.0 || !tr.is_finite() {
        return None;
    }
    let mean = tr / D as f64;
    match D {
        2 => {
            let a = Matrix2::new(m[0][0], m[0][1], m[1][0], m[1][1]);
            let det = a.determinant();
            let iso = det / (mean * mean);
            if iso.is_nan() || iso < min_isotropy {
                return None;
            }
            let inv = a.try_inverse()?;
            Some(std::array::from_fn(|r| {
                std::array::from_fn(|c| inv[(r, c)])
            }))
        }
        3 => {
            let a = Matrix3::from_fn(|r, c| m[r][c]);
            let det = a.determinant();
            let iso = det / (mean * mean * mean);
            if iso.is_nan() || iso < min_isotropy {
                return None;
            }
            let inv = a.try_inverse()?;
            Some(std::array::from_fn(|r| {
                std::array::from_fn(|c| inv[(r, c)])
            }))
        }
        _ => panic!("gpm supports D = 2 and D = 3"),
    }
}

/// The moment matrix `M_i = d Σ_{j≠i} ω_j x_ji⊗x_ji w_h(r_ij)/r_ij²` of row `i`: the difference
/// gradient of the coordinate functions, `(M_i)_{ab} = (∇h x_b)_a` at `x_i`, so that
/// `∇h (c·x) = M_i c` and `M_i = I` is exactly first-order consistency of `∇h`.
pub fn moment_matrix<const D: usize>(nl: &NeighborList<D>, vol: &[f64], i: usize) -> Mat<D> {
    let d = D as f64;
    let mut m = [[0.0; D]; D];
    for k in nl.row(i) {
        let j = nl.indices()[k] as usize;
        let c = d * vol[j] * nl.wr2()[k];
        let x = &nl.dx()[k];
        for a in 0..D {
            for b in 0..D {
                m[a][b] += c * x[a] * x[b];
            }
        }
    }
    m
}

/// Identifies the pair data and volumes a [`Renormalisation`] was computed from.
#[derive(Clone, Debug, PartialEq)]
struct RenormKey {
    epoch: u64,
    generation: u64,
    rows: usize,
    vol: Vec<f64>,
}

impl RenormKey {
    /// Whether `key` describes `nl`, `vol` and `rows` (no allocation); otherwise the key for
    /// them, to be stored once the cache is recomputed.
    fn fresh<const D: usize>(
        key: &Option<RenormKey>,
        nl: &NeighborList<D>,
        vol: &[f64],
        rows: usize,
    ) -> Option<RenormKey> {
        let same = key.as_ref().is_some_and(|k| {
            k.epoch == nl.epoch()
                && k.generation == nl.generation()
                && k.rows == rows
                && k.vol == vol
        });
        (!same).then(|| RenormKey {
            epoch: nl.epoch(),
            generation: nl.generation(),
            rows,
            vol: vol.to_vec(),
        })
    }
}

/// The renormalisation matrices `B_i = M_i⁻¹` of the corrected gradient
/// `∇ᶜφ_i = B_i ∇h φ_i` (Bonet & Lok 1999, *Variational and momentum preservation aspects of
/// smooth particle hydrodynamic formulations*, CMAME 180; Randles & Libersky 1996), with
/// [`moment_matrix`] `M_i`.
///
/// A row whose moment matrix is too anisotropic to invert ([`Self::min_isotropy`], e.g. a particle
/// with all its neighbours on one line) gets the scalar renormalisation `B_i = (D / tr M_i) I`
/// instead, and is listed in [`Self::fallback_rows`]; a row without neighbours gets `B_i = I`.
#[derive(Clone, Debug)]
pub struct Renormalisation<const D: usize> {
    /// `B_i` per row (rows `0..b.len()`).
    pub b: Vec<Mat<D>>,
    /// Rows that got the scalar fallback.
    pub fallback_rows: Vec<usize>,
    /// Threshold on `det M / (tr M / D)^D` below which a row falls back (default `1e-3`).
    pub min_isotropy: f64,
    key: Option<RenormKey>,
}

impl<const D: usize> Default for Renormalisation<D> {
    fn default() -> Self {
        Renormalisation {
            b: Vec::new(),
            fallback_rows: Vec::new(),
            min_isotropy: 1e-3,
            key: None,
        }
    }
}

impl<const D: usize> Renormalisation<D> {
    /// Empty (no rows).
    pub fn new() -> Self {
        Self::default()
    }

    /// `B_i` for the rows `0..rows` of `nl`.
    pub fn compute(nl: &NeighborList<D>, vol: &[f64], rows: usize) -> Self {
        let mut r = Self::new();
        r.update(nl, vol, rows);
        r
    }

    /// Recomputes `B_i` for rows `0..rows` unless the pair data (the list's epoch and
    /// generation), the volumes and the row count are those of the last computation; returns
    /// true when it recomputed.
    pub fn update(&mut self, nl: &NeighborList<D>, vol: &[f64], rows: usize) -> bool {
        assert!(rows <= nl.len(), "rows beyond the neighbour list");
        let Some(key) = RenormKey::fresh(&self.key, nl, vol, rows) else {
            return false;
        };
        let min_iso = self.min_isotropy;
        let res: Vec<(Mat<D>, bool)> = (0..rows)
            .into_par_iter()
            .with_min_len(MIN_ROWS)
            .map(|i| {
                let m = moment_matrix(nl, vol, i);
                match inverse_spd(&m, min_iso) {
                    Some(b) => (b, false),
                    None => {
                        let tr: f64 = (0..D).map(|a| m[a][a]).sum();
                        let s = if tr > 0.0 { D as f64 / tr } else { 1.0 };
                        let mut b = identity::<D>();
                        for (a, row) in b.iter_mut().enumerate() {
                            row[a] = s;
                        }
                        (b, true)
                    }
                }
            })
            .collect();
        self.fallback_rows = res
            .iter()
            .enumerate()
            .filter(|(_, r)| r.1)
            .map(|(i, _)| i)
            .collect();
        self.b = res.into_iter().map(|r| r.0).collect();
        self.key = Some(key);
        true
    }

    /// `out_i = B_iᵀ ψ_i` for the rows of `B`, `out_i = ψ_i` beyond them (ghost rows: the caller
    /// continues the result into its ghosts as it does for `ψ`). `∇̂h·` applied to `out` is the
    /// divergence adjoint to [`grad_renormalised`]:
    /// `(∇̂h·(Bᵀψ), φ) = −(ψ, ∇ᶜφ)` wherever `(∇̂h·ψ, φ) = −(ψ, ∇h φ)` holds.
    pub fn apply_transpose_into(&self, psi: &[[f64; D]], out: &mut [[f64; D]]) {
        assert_eq!(psi.len(), out.len(), "psi and out lengths differ");
        let nb = self.b.len();
        out.par_iter_mut()
            .with_min_len(MIN_ROWS)
            .enumerate()
            .for_each(|(i, o)| {
                if i < nb {
                    let b = &self.b[i];
                    *o = std::array::from_fn(|a| (0..D).map(|c| b[c][a] * psi[i][c]).sum());
                } else {
                    *o = psi[i];
                }
            });
    }
}

/// Corrected gradient `∇ᶜφ_i = B_i ∇h φ_i` into `out` (rows `0..out.len()`, which must not exceed
/// the rows of `renorm`). Exact for linear `φ` on any distribution whose rows did not fall back.
pub fn grad_renormalised_into<const D: usize>(
    nl: &NeighborList<D>,
    vol: &[f64],
    renorm: &Renormalisation<D>,
    phi: &[f64],
    out: &mut [[f64; D]],
) {
    assert!(
        out.len() <= renorm.b.len(),
        "renormalisation computed for {} rows, {} requested",
        renorm.b.len(),
        out.len()
    );
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
            let b = &renorm.b[i];
            *o = std::array::from_fn(|a| d * (0..D).map(|c| b[a][c] * s[c]).sum::<f64>());
        });
}

/// Corrected gradient `∇ᶜφ` at every row of `renorm`.
pub fn grad_renormalised<const D: usize>(
    nl: &NeighborList<D>,
    vol: &[f64],
    renorm: &Renormalisation<D>,
    phi: &[f64],
) -> Vec<[f64; D]> {
    let mut out = vec![[0.0; D]; renorm.b.len()];
    grad_renormalised_into(nl, vol, renorm, phi, &mut out);
    out
}

/// Renormalised divergence `∇ᶜ·ψ_i = Σ_a (B_i ∇h ψ_a)_a = Σ_{a,b} (B_i)_{ab} (∇h ψ_a)_b` into `out`
/// (rows `0..out.len()`): the trace of the corrected velocity gradient, exact for linear `ψ` on
/// any distribution whose rows did not fall back (first-order consistent), Galilean invariant
/// (zero for a uniform field, unlike the sum-form `∇̂h·`, whose value there is
/// `2 ψ_i · d Σ_j ω_j x_ji w_h/r²`). Not adjoint to any gradient of the projection, and its
/// `ω`-weighted sum does not vanish (no discrete Gauss theorem).
pub fn div_renormalised_into<const D: usize>(
    nl: &NeighborList<D>,
    vol: &[f64],
    renorm: &Renormalisation<D>,
    psi: &[[f64; D]],
    out: &mut [f64],
) {
    assert!(
        out.len() <= renorm.b.len(),
        "renormalisation computed for {} rows, {} requested",
        renorm.b.len(),
        out.len()
    );
    out.par_iter_mut()
        .with_min_len(MIN_ROWS)
        .enumerate()
        .for_each(|(i, o)| {
            // g[a][b] = (∇h ψ_a)_b
            let g = crate::operators::grad_vec_row(nl, vol, psi, i);
            *o = trace_product(&renorm.b[i], &g);
        });
}

/// [`div_renormalised_into`] that also returns `max_i ‖B_i‖_F Σ_j ω_j w_h(r_ij)/r_ij` over the
/// rows `i` with `counted(i)` (0 when none is), read in the same pass over the pairs: the row
/// sums of `|∇ᶜ·|` are `2d` times that at most (`|Σ_a (B_i x_ji)_a δe_a| ≤ ‖B_i‖ r_ij |δe|`).
pub fn div_renormalised_gain_into<const D: usize>(
    nl: &NeighborList<D>,
    vol: &[f64],
    renorm: &Renormalisation<D>,
    psi: &[[f64; D]],
    out: &mut [f64],
    counted: impl Fn(usize) -> bool + Sync,
) -> f64 {
    assert!(
        out.len() <= renorm.b.len(),
        "renormalisation computed for {} rows, {} requested",
        renorm.b.len(),
        out.len()
    );
    let row = |i: usize| {
        let (g, row_sum) = crate::operators::grad_vec_row_gain(nl, vol, psi, i);
        let b = &renorm.b[i];
        let frobenius: f64 = b.iter().flatten().map(|v| v * v).sum::<f64>().sqrt();
        (trace_product(b, &g), frobenius * row_sum)
    };
    crate::operators::rows_and_max(out, row, counted)
}

/// `Σ_{a,c} b[a][c] g[a][c]`.
#[inline(always)]
fn trace_product<const D: usize>(b: &[[f64; D]; D], g: &[[f64; D]; D]) -> f64 {
    let mut s = 0.0;
    for a in 0..D {
        for c in 0..D {
            s += b[a][c] * g[a][c];
        }
    }
    s
}

/// Renormalised divergence at every row of `renorm`.
pub fn div_renormalised<const D: usize>(
    nl: &NeighborList<D>,
    vol: &[f64],
    renorm: &Renormalisation<D>,
    psi: &[[f64; D]],
) -> Vec<f64> {
    let mut out = vec![0.0; renorm.b.len()];
    div_renormalised_into(nl, vol, renorm, psi, &mut out);
    out
}

/// Which gradient a projection uses for `∇pⁿ` in the predictor and `∇φ` in the correction.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum GradientKind {
    /// The difference gradient `∇h` (adjoint to the sum-form divergence; zeroth order on
    /// disordered particles).
    #[default]
    Difference,
    /// The renormalised gradient `∇ᶜ = B ∇h` (first order on any distribution; not adjoint to
    /// `∇̂h·`).
    Renormalised,
    /// The least-squares gradient `∇ˡˢ` of [`LsOperators`] (exact on quadratics, second order
    /// on any distribution; not adjoint to `∇̂h·`).
    LeastSquares,
}

impl std::str::FromStr for GradientKind {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s.trim().to_ascii_lowercase().as_str() {
            "difference" | "diff" => Ok(GradientKind::Difference),
            "renormalised" | "renormalized" | "corrected" => Ok(GradientKind::Renormalised),
            "least-squares" | "least_squares" | "ls" => Ok(GradientKind::LeastSquares),
            _ => Err(format!(
                "unknown gradient '{s}': expected difference, renormalised or least-squares"
            )),
        }
    }
}

impl std::fmt::Display for GradientKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            GradientKind::Difference => "difference",
            GradientKind::Renormalised => "renormalised",
            GradientKind::LeastSquares => "least-squares",
        })
    }
}

/// A gradient a projection step can hold as scratch: `prepare` once per configuration (it
/// recomputes the matrices only when the pair data or volumes changed), then `apply_into` for
/// `∇pⁿ` in the predictor and for `∇φ` in the correction.
///
/// ```
/// use gpm::consistent::{GradientKind, GradientOperator};
/// use gpm::geometry::{jitter, lattice};
/// use gpm::kernel::Weight;
/// use gpm::neighbors::{NeighborConfig, NeighborList};
///
/// let dx = 0.05;
/// let mut x = lattice([0.0, 0.0], [1.0, 1.0], dx);
/// jitter(&mut x, 0.3 * dx, 7);
/// let nl = NeighborList::build(NeighborConfig::new_relative(Weight::WendlandC2, dx, 3.0, 0.0), &x)?;
/// let vol = vec![dx * dx; x.len()];
/// let phi: Vec<f64> = x.iter().map(|p| 2.0 * p[0] - p[1]).collect();
/// let mut g = GradientOperator::<2>::new(GradientKind::Renormalised);
/// g.prepare(&nl, &vol);
/// let mut out = vec![[0.0; 2]; x.len()];
/// g.apply_into(&nl, &vol, &phi, &mut out);
/// // exact for a linear field, at every particle, boundary included
/// assert!(out.iter().all(|v| (v[0] - 2.0).abs() < 1e-9 && (v[1] + 1.0).abs() < 1e-9));
/// # Ok::<(), gpm::error::InputError>(())
/// ```
#[derive(Clone, Debug)]
pub struct GradientOperator<const D: usize> {
    /// The gradient.
    pub kind: GradientKind,
    /// Cached renormalisation matrices (the renormalised gradient and divergences).
    pub renorm: Renormalisation<D>,
    /// Cached least-squares coefficients with ghosts as fit points (gradients of scalars with
    /// the Neumann extension: pressures, pressure increments).
    pub ls: LsOperators<D>,
    /// Cached least-squares coefficients with wall points for ghosts (velocities: the
    /// divergence, the viscous Laplacian).
    pub ls_walls: LsOperators<D>,
    /// The configuration has no ghosts, so the wall variant equals the plain one: the
    /// least-squares gradient reads `ls_walls` and `ls` is never built (one coefficient build
    /// per configuration instead of two).
    pub share_walls: bool,
}

impl<const D: usize> Default for GradientOperator<D> {
    fn default() -> Self {
        Self::new(GradientKind::default())
    }
}

impl<const D: usize> GradientOperator<D> {
    /// A gradient of the given kind with empty caches.
    pub fn new(kind: GradientKind) -> Self {
        GradientOperator {
            kind,
            renorm: Renormalisation::new(),
            ls: LsOperators::new(),
            ls_walls: LsOperators::at_walls(),
            share_walls: false,
        }
    }

    /// The plain least-squares variant (`ls_walls` when [`Self::share_walls`]).
    pub fn plain(&self) -> &LsOperators<D> {
        if self.share_walls {
            &self.ls_walls
        } else {
            &self.ls
        }
    }

    /// Brings the cached matrices up to date with `nl` and `vol` (every row of the list);
    /// returns true when it recomputed them. A no-op for the difference gradient.
    pub fn prepare(&mut self, nl: &NeighborList<D>, vol: &[f64]) -> bool {
        match self.kind {
            GradientKind::Difference => false,
            GradientKind::Renormalised => self.renorm.update(nl, vol, nl.len()),
            GradientKind::LeastSquares if self.share_walls => {
                self.ls_walls.update(nl, vol, nl.len(), None)
            }
            GradientKind::LeastSquares => self.update_plain(nl, vol),
        }
    }

    /// Brings the plain least-squares variant up to date (rows without ghosts copied from the
    /// wall variant when that is current); returns true when it recomputed.
    pub fn update_plain(&mut self, nl: &NeighborList<D>, vol: &[f64]) -> bool {
        self.ls
            .update_sharing(nl, vol, nl.len(), None, &self.ls_walls)
    }

    /// Brings the wall least-squares variant up to date for the positions and roles in
    /// `geometry` (rows without ghosts copied from the plain variant when that is current);
    /// returns true when it recomputed.
    pub fn update_walls(
        &mut self,
        nl: &NeighborList<D>,
        vol: &[f64],
        geometry: Option<(&[[f64; D]], &[crate::particles::Role])>,
    ) -> bool {
        match self.share_walls {
            true => self.ls_walls.update(nl, vol, nl.len(), geometry),
            false => self
                .ls_walls
                .update_sharing(nl, vol, nl.len(), geometry, &self.ls),
        }
    }

    /// The gradient of `phi` into `out` (rows `0..out.len()`); call [`Self::prepare`] first.
    pub fn apply_into(&self, nl: &NeighborList<D>, vol: &[f64], phi: &[f64], out: &mut [[f64; D]]) {
        match self.kind {
            GradientKind::Difference => crate::operators::grad_diff_into(nl, vol, phi, out),
            GradientKind::Renormalised => grad_renormalised_into(nl, vol, &self.renorm, phi, out),
            GradientKind::LeastSquares => self.plain().grad_into(nl, phi, out),
        }
    }

    /// The gradients of `f` and `g` into `out_f` and `out_g`: bit for bit
    /// [`Self::apply_into`] of each, in one pass over the pairs for the difference and
    /// least-squares gradients.
    pub fn apply2_into(
        &self,
        nl: &NeighborList<D>,
        vol: &[f64],
        f: &[f64],
        g: &[f64],
        out_f: &mut [[f64; D]],
        out_g: &mut [[f64; D]],
    ) {
        match self.kind {
            GradientKind::Difference => {
                crate::operators::grad_diff2_into(nl, vol, f, g, out_f, out_g)
            }
            GradientKind::LeastSquares => self.plain().grad2_into(nl, f, g, out_f, out_g),
            GradientKind::Renormalised => {
                self.apply_into(nl, vol, f, out_f);
                self.apply_into(nl, vol, g, out_g);
            }
        }
    }
}

// ---------------------------------------------------------------------------------------------
// least squares (MLS "diffuse derivatives", LSSPH)
// ---------------------------------------------------------------------------------------------

/// Number of unknowns of the quadratic least-squares fit with `f_i` known: `D` first and
/// `D (D + 1) / 2` second derivatives.
fn n_quadratic(d: usize) -> usize {
    d + d * (d + 1) / 2
}

/// Weighted least-squares gradient and Laplacian (Shobuzako et al. eqs. (1)–(18) with `q = 2`,
/// `f_i` known; the MLS diffuse derivatives of Nayroles et al. 1992): at each particle the
/// Taylor polynomial `f_j − f_i ≈ g·x_ji + ½ x_jiᵀ H x_ji` is fitted to the neighbours `j ≠ i` with
/// weights `ω_j w_h(r_ij)` (the paper's `ψ_j = W_ij V_j`), and `(g, tr H)` returned. Exact for
/// quadratic `f`; truncation error `O(h²)` for the gradient and `O(h)` for the Laplacian at
/// fixed `h/Δx` on any distribution. Rows whose normal matrix is singular (fewer than
/// `D + D(D+1)/2` neighbours in general position) get NaN.
pub fn ls_gradient_laplacian<const D: usize>(
    nl: &NeighborList<D>,
    vol: &[f64],
    phi: &[f64],
) -> (Vec<[f64; D]>, Vec<f64>) {
    let m = n_quadratic(D);
    let hinv = 1.0 / nl.h();
    let res: Vec<([f64; D], f64)> = (0..nl.len())
        .into_par_iter()
        .with_min_len(64)
        .map(|i| {
            let mut a = DMatrix::<f64>::zeros(m, m);
            let mut rhs = DVector::<f64>::zeros(m);
            let mut p = DVector::<f64>::zeros(m);
            for k in nl.row(i) {
                let j = nl.indices()[k] as usize;
                let z: [f64; D] = std::array::from_fn(|c| nl.dx()[k][c] * hinv);
                quadratic_basis(&z, &mut p);
                let w = vol[j] * nl.w()[k];
                a.ger(w, &p, &p, 1.0);
                rhs.axpy(w * (phi[j] - phi[i]), &p, 1.0);
            }
            match a.cholesky() {
                Some(ch) => {
                    let c = ch.solve(&rhs);
                    let g: [f64; D] = std::array::from_fn(|k| c[k] * hinv);
                    // diagonal second derivatives come first among the quadratic unknowns
                    let lap: f64 = (0..D).map(|k| c[D + k]).sum::<f64>() * hinv * hinv;
                    (g, lap)
                }
                None => ([f64::NAN; D], f64::NAN),
            }
        })
        .collect();
    res.into_iter().unzip()
}

/// Quadratic basis in scaled coordinates `z`: `[z_1..z_D, z_1²/2..z_D²/2, z_a z_b (a < b)]`.
/// Largest quadratic basis ([`n_quadratic`] of 3).
const MAX_Q: usize = 9;

/// [`quadratic_basis`] into the first [`n_quadratic`]`(D)` entries of a stack array.
#[inline(always)]
fn quadratic_basis_into<const D: usize, const M: usize>(z: &[f64; D], p: &mut [f64; M]) {
    for a in 0..D {
        p[a] = z[a];
        p[D + a] = 0.5 * z[a] * z[a];
    }
    let mut k = 2 * D;
    for a in 0..D {
        for b in a + 1..D {
            p[k] = z[a] * z[b];
            k += 1;
        }
    }
}

/// The inverse of the `M × M` matrix `a` into `inv` by Gauss–Jordan elimination with partial
/// pivoting; false when a pivot is zero or the result not finite. `M` is a constant so that the
/// loops unroll (see [`ls_rows`]).
fn invert_small<const M: usize>(a: &[[f64; M]; M], inv: &mut [[f64; M]; M]) -> bool {
    let mut w = *a;
    *inv = [[0.0; M]; M];
    for (r, row) in inv.iter_mut().enumerate() {
        row[r] = 1.0;
    }
    for col in 0..M {
        let piv = (col..M)
            .max_by(|&x, &y| w[x][col].abs().total_cmp(&w[y][col].abs()))
            .unwrap_or(col);
        if w[piv][col] == 0.0 {
            return false;
        }
        if piv != col {
            w.swap(piv, col);
            inv.swap(piv, col);
        }
        let d = 1.0 / w[col][col];
        for c in 0..M {
            w[col][c] *= d;
            inv[col][c] *= d;
        }
        let (wc, ic) = (w[col], inv[col]);
        for r in 0..M {
            if r != col {
                let f = w[r][col];
                if f != 0.0 {
                    for c in 0..M {
                        w[r][c] -= f * wc[c];
                        inv[r][c] -= f * ic[c];
                    }
                }
            }
        }
    }
    inv.iter().flatten().all(|v| v.is_finite())
}

fn quadratic_basis<const D: usize>(z: &[f64; D], p: &mut DVector<f64>) {
    let mut q = [0.0; MAX_Q];
    quadratic_basis_into::<D, MAX_Q>(z, &mut q);
    let m = n_quadratic(D);
    p.as_mut_slice()[..m].copy_from_slice(&q[..m]);
}

/// Weighted least-squares interpolant with a linear basis (Shobuzako et al. with `k = 0`,
/// `q = 1`): at each particle `a + b·x_ji` is fitted to all particles within `h`, the particle
/// itself included, with weights `ω_j w_h(r_ij)`, and `a` returned. Exact for linear `f`; error
/// `O(h²)`. Rows with a singular normal matrix get NaN.
pub fn ls_interpolate<const D: usize>(nl: &NeighborList<D>, vol: &[f64], phi: &[f64]) -> Vec<f64> {
    let w0 = nl.kernel().w_h(0.0);
    let hinv = 1.0 / nl.h();
    (0..nl.len())
        .into_par_iter()
        .with_min_len(64)
        .map(|i| {
            let m = D + 1;
            let mut a = DMatrix::<f64>::zeros(m, m);
            let mut rhs = DVector::<f64>::zeros(m);
            let mut p = DVector::<f64>::zeros(m);
            // self term: basis (1, 0, …)
            a[(0, 0)] += vol[i] * w0;
            rhs[0] += vol[i] * w0 * phi[i];
            for k in nl.row(i) {
                let j = nl.indices()[k] as usize;
                p[0] = 1.0;
                for c in 0..D {
                    p[c + 1] = nl.dx()[k][c] * hinv;
                }
                let w = vol[j] * nl.w()[k];
                a.ger(w, &p, &p, 1.0);
                rhs.axpy(w * phi[j], &p, 1.0);
            }
            match a.cholesky() {
                Some(ch) => ch.solve(&rhs)[0],
                None => f64::NAN,
            }
        })
        .collect()
}

// ---------------------------------------------------------------------------------------------
// classical SPH forms
// ---------------------------------------------------------------------------------------------

/// Shepard (CSPH kernel-corrected) interpolant `Σ_j f_j w_h ω_j / Σ_j w_h ω_j`, self included
/// (Bonet & Lok 1999; Shobuzako et al. eq. (25)). Exact for constants; `O(Δx)` on disordered
/// particles at fixed `h/Δx`.
pub fn shepard_interpolate<const D: usize>(
    nl: &NeighborList<D>,
    vol: &[f64],
    phi: &[f64],
) -> Vec<f64> {
    let w0 = nl.kernel().w_h(0.0);
    (0..nl.len())
        .into_par_iter()
        .with_min_len(MIN_ROWS)
        .map(|i| {
            let (mut s, mut n) = (vol[i] * w0 * phi[i], vol[i] * w0);
            for k in nl.row(i) {
                let j = nl.indices()[k] as usize;
                s += vol[j] * nl.w()[k] * phi[j];
                n += vol[j] * nl.w()[k];
            }
            s / n
        })
        .collect()
}

/// The three classical SPH gradient forms (Shobuzako et al. Table 1), with
/// `∇_iW_ij = w_h'(r_ij) (x_i − x_j)/r_ij`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SphGradient {
    /// `Σ_j ω_j f_j ∇_iW_ij` (Lucy 1977; Gingold & Monaghan 1977): order −1.
    Standard,
    /// `Σ_j ω_j (f_j − f_i) ∇_iW_ij`: order 0. Equal to the GPM `∇h` with the reference weight
    /// `w̃(s) = −s W'(s)/d`.
    Difference,
    /// `Σ_j ω_j (f_i + f_j) ∇_iW_ij` (the momentum-conserving pressure gradient): order −1.
    Sum,
}

/// `∇_iW_ij ω_j` of pair `k`: `−w_h'(r) x_ji / r · ω_j`.
#[inline]
fn grad_w<const D: usize>(nl: &NeighborList<D>, vol: &[f64], k: usize, j: usize) -> [f64; D] {
    let r = nl.r2(k).sqrt();
    let c = -nl.kernel().dw_h(r) / r * vol[j];
    std::array::from_fn(|a| c * nl.dx()[k][a])
}

/// A classical SPH gradient of `phi` at every particle.
pub fn sph_gradient<const D: usize>(
    nl: &NeighborList<D>,
    vol: &[f64],
    phi: &[f64],
    form: SphGradient,
) -> Vec<[f64; D]> {
    (0..nl.len())
        .into_par_iter()
        .with_min_len(MIN_ROWS)
        .map(|i| {
            let mut s = [0.0; D];
            for k in nl.row(i) {
                let j = nl.indices()[k] as usize;
                let f = match form {
                    SphGradient::Standard => phi[j],
                    SphGradient::Difference => phi[j] - phi[i],
                    SphGradient::Sum => phi[j] + phi[i],
                };
                let g = grad_w(nl, vol, k, j);
                for a in 0..D {
                    s[a] += f * g[a];
                }
            }
            s
        })
        .collect()
}

/// The CSPH gradient correction of Bonet & Lok (1999), Shobuzako et al. eq. (32):
/// `B̃_i⁻¹ Σ_j ω_j (f_j − f_i) ∇_iW_ij` with `B̃_i = Σ_j ω_j ∇_iW_ij ⊗ x_ji` (symmetric here). The
/// least-squares gradient with weights `−ω_j w_h'(r)/r`; exact for linear `f`. Rows with a singular
/// `B̃_i` get NaN.
pub fn csph_gradient<const D: usize>(
    nl: &NeighborList<D>,
    vol: &[f64],
    phi: &[f64],
) -> Vec<[f64; D]> {
    (0..nl.len())
        .into_par_iter()
        .with_min_len(MIN_ROWS)
        .map(|i| {
            let mut s = [0.0; D];
            let mut m = [[0.0; D]; D];
            for k in nl.row(i) {
                let j = nl.indices()[k] as usize;
                let g = grad_w(nl, vol, k, j);
                for a in 0..D {
                    s[a] += (phi[j] - phi[i]) * g[a];
                    for (mab, xb) in m[a].iter_mut().zip(&nl.dx()[k]) {
                        *mab += g[a] * xb;
                    }
                }
            }
            match inverse_spd(&m, 1e-12) {
                Some(bi) => std::array::from_fn(|a| (0..D).map(|c| bi[a][c] * s[c]).sum()),
                None => [f64::NAN; D],
            }
        })
        .collect()
}

/// Brookshaw's (1985) SPH Laplacian, as extended by Morris et al. (1997):
/// `2 Σ_j ω_j (f_j − f_i) x_ji·∇_iW_ij / r²  =  −2 Σ_j ω_j (f_j − f_i) w_h'(r)/r`. Equal to the
/// GPM `Δh` with the reference weight `w̃(s) = −s W'(s)/d`; order −1 on disordered particles.
pub fn sph_laplacian_brookshaw<const D: usize>(
    nl: &NeighborList<D>,
    vol: &[f64],
    phi: &[f64],
) -> Vec<f64> {
    let kernel = *nl.kernel();
    (0..nl.len())
        .into_par_iter()
        .with_min_len(MIN_ROWS)
        .map(|i| {
            let mut s = 0.0;
            for k in nl.row(i) {
                let j = nl.indices()[k] as usize;
                let r = nl.r2(k).sqrt();
                s += vol[j] * (phi[j] - phi[i]) * kernel.dw_h(r) / r;
            }
            -2.0 * s
        })
        .collect()
}

// ---------------------------------------------------------------------------------------------
// the least-squares Laplacian as pair coefficients (viscous term on disordered particles)
// ---------------------------------------------------------------------------------------------

/// Which Laplacian the predictor's viscous term uses.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum LaplacianKind {
    /// The GPM Laplacian `Δh` (symmetric; exact on quadratics only where the neighbourhood is
    /// symmetric, an `O(1/h)` error on disordered particles).
    #[default]
    Gpm,
    /// The weighted least-squares Laplacian `Δˡˢ` of [`LsOperators`] (exact on quadratics on
    /// any distribution; not symmetric). With an implicit viscous weight `θ` the predictor
    /// treats `θΔh` implicitly and `Δˡˢ − θΔh` explicitly, so a steady state satisfies the
    /// consistent `νΔˡˢu + … = 0`.
    LeastSquares,
}

impl std::str::FromStr for LaplacianKind {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s.trim().to_ascii_lowercase().replace('-', "_").as_str() {
            "gpm" | "pair" => Ok(LaplacianKind::Gpm),
            "least_squares" | "ls" => Ok(LaplacianKind::LeastSquares),
            _ => Err(format!(
                "unknown Laplacian '{s}': expected gpm or least-squares"
            )),
        }
    }
}

impl std::fmt::Display for LaplacianKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            LaplacianKind::Gpm => "gpm",
            LaplacianKind::LeastSquares => "least-squares",
        })
    }
}

/// Largest `max|A| · max|A⁻¹|` of a least-squares normal matrix (in the scaled basis) before the
/// row falls back to the GPM coefficients.
const LS_MAX_CONDITION: f64 = 1e5;

/// The weighted least-squares gradient and Laplacian of [`ls_gradient_laplacian`] written as
/// pair coefficients: `∇ˡˢφ_i = Σ_j g_ij (φ_j − φ_i)` and `Δˡˢφ_i = Σ_j c_ij (φ_j − φ_i)`. With the
/// quadratic basis `p(x̂)` of `x̂ = x_ji/h` and the normal matrix `A_i = Σ_j ω_j w_h p pᵀ`,
/// `(g_ij, c_ij) = ω_j w_h(r_ij) (E A_i⁻¹ p(x̂_ji))` (`E` picks the first derivatives, scaled by
/// `1/h`, and the trace of the Hessian, scaled by `1/h²`). Both are exact for quadratic `φ` on
/// any distribution whose normal matrices are regular (gradient error `O(h²)`, Laplacian
/// `O(h)`); the divergence `∇ˡˢ·ψ_i = Σ_a (∇ˡˢψ_a)_a` is exact for quadratic `ψ`. Computed once
/// per configuration (cached on the list's epoch and generation and the volumes) and then
/// applied as sparse products. Rows with a singular normal matrix fall back to the GPM
/// coefficients (`d ω_j w_h x_ji/r²` and `2d ω_j w_h/r²`) and are listed in
/// [`Self::fallback_rows`].
///
/// **Walls** ([`Self::at_walls`]): a fit through mirror ghosts sees the ghosts' values, which for
/// a velocity under the no-slip rule `u_g = 2u_w − u_s` are the odd extension of `u` across the
/// wall: its second derivative jumps there, and a quadratic fit across the jump has an `O(1)`
/// error in the near-wall rows. The wall variant replaces each ghost `g` (image of the fluid
/// particle `s`) by the point on the wall half-way between them, `(x_g + x_s)/2`, carrying
/// `(u_g + u_s)/2` — the wall velocity under the no-slip rule — so that the fit is one-sided
/// and exact for quadratic fields that take the wall value. The plain variant keeps the ghost
/// points (exact for quadratic scalars with a zero normal derivative, the Neumann extension of
/// pressures).
#[derive(Clone, Debug, Default)]
pub struct LsOperators<const D: usize> {
    /// Per pair: `D` gradient coefficients, then the Laplacian coefficient.
    coef: Vec<f64>,
    /// Wall variant: per pair, the particle whose value is averaged with the neighbour's
    /// (the ghost's source, or the neighbour itself).
    partner: Vec<u32>,
    walls: bool,
    /// Rows that got the GPM coefficients.
    pub fallback_rows: Vec<usize>,
    key: Option<RenormKey>,
}

/// The coefficients of [`LsOperators`] for each `(row, its pair range of the coefficient array)`
/// of `slices`: `point(k, j)` is pair `k`'s fit point (relative position and weight), a row for
/// which `copied` names a donor takes the donor's coefficients. Returns the rows that got the
/// GPM coefficients (an ill-posed fit). `M` = [`n_quadratic`]`(D)`, a constant so that the
/// normal matrix, its inverse and the per-pair products live in fixed-size arrays whose loops
/// unroll (2D 10⁵ jittered particles, 2.6 M pairs: 33 → 19 ms per update on two threads,
/// the same bits).
fn ls_rows<'a, const D: usize, const M: usize>(
    slices: Vec<(usize, &mut [f64])>,
    nl: &NeighborList<D>,
    vol: &[f64],
    point: &(impl Fn(usize, usize) -> ([f64; D], f64) + Sync),
    copied: &(impl Fn(usize) -> Option<&'a LsOperators<D>> + Sync),
    hinv: f64,
) -> Vec<usize> {
    let s = D + 1;
    let hinv2 = hinv * hinv;
    let d = D as f64;
    slices
        .into_par_iter()
        .with_min_len(64)
        .map_init(Vec::new, |fit: &mut Vec<([f64; M], f64)>, (i, out)| {
            let start = nl.row(i).start;
            if let Some(dn) = copied(i) {
                out.copy_from_slice(&dn.coef[start * s..nl.row(i).end * s]);
                return dn.fallback_rows.binary_search(&i).ok().map(|_| i);
            }
            // the basis and weight of each fit point, computed once per row; the normal
            // matrix and its inverse on the stack (a dynamic nalgebra matrix per row made this
            // loop 2-3x slower, the step's largest item on moving particles)
            fit.clear();
            let mut a = [[0.0; M]; M];
            for k in nl.row(i) {
                let (dk, wk) = point(k, nl.indices()[k] as usize);
                let z: [f64; D] = std::array::from_fn(|c| dk[c] * hinv);
                let mut p = [0.0; M];
                quadratic_basis_into(&z, &mut p);
                for r in 0..M {
                    let wr = wk * p[r];
                    for c in r..M {
                        a[r][c] += wr * p[c];
                    }
                }
                fit.push((p, wk));
            }
            for r in 0..M {
                for c in 0..r {
                    a[r][c] = a[c][r];
                }
            }
            // a well-posed fit: the normal matrix is regular and not too ill-conditioned
            let mut inv = [[0.0; M]; M];
            let ok = invert_small(&a, &mut inv) && {
                let na = a.iter().flatten().map(|v| v.abs()).fold(0.0, f64::max);
                let ni = inv.iter().flatten().map(|v| v.abs()).fold(0.0, f64::max);
                na * ni < LS_MAX_CONDITION
            };
            if ok {
                // the rows of A⁻¹ that are used: the first derivatives, and the sum of the
                // Hessian's diagonal rows (the Laplacian)
                let mut lap = [0.0; M];
                for c in 0..D {
                    for (l, v) in lap.iter_mut().zip(&inv[D + c]) {
                        *l += v;
                    }
                }
                for (o, (p, wk)) in out.chunks_exact_mut(s).zip(fit.iter()) {
                    let dot = |row: &[f64; M]| -> f64 {
                        row.iter().zip(p).map(|(x, q)| x * q).sum::<f64>()
                    };
                    for c in 0..D {
                        o[c] = wk * dot(&inv[c]) * hinv;
                    }
                    o[D] = wk * dot(&lap) * hinv2;
                }
                None
            } else {
                for k in nl.row(i) {
                    let j = nl.indices()[k] as usize;
                    let f = vol[j] * nl.wr2()[k];
                    let o = &mut out[(k - start) * s..(k - start + 1) * s];
                    for c in 0..D {
                        o[c] = d * f * nl.dx()[k][c];
                    }
                    o[D] = 2.0 * d * f;
                }
                Some(i)
            }
        })
        .flatten()
        .collect()
}

impl<const D: usize> LsOperators<D> {
    const S: usize = D + 1;

    /// Empty (no rows), the plain variant (ghosts are fit points).
    pub fn new() -> Self {
        Self::default()
    }

    /// Empty (no rows), the wall variant (a ghost stands for the wall point between it and
    /// its source; see the type's docs).
    pub fn at_walls() -> Self {
        LsOperators {
            walls: true,
            ..Self::default()
        }
    }

    /// Recomputes the coefficients of rows `0..rows` unless the list and volumes are those of
    /// the last computation; returns true when it recomputed. `geometry` (positions and roles)
    /// is read by the wall variant only (which treats every pair as a plain one without it).
    pub fn update(
        &mut self,
        nl: &NeighborList<D>,
        vol: &[f64],
        rows: usize,
        geometry: Option<(&[[f64; D]], &[crate::particles::Role])>,
    ) -> bool {
        self.update_from(nl, vol, rows, geometry, None)
    }

    /// [`Self::update`] that copies, from `other` (the other variant) when it is current for
    /// the same list, volumes and rows, every row without a ghost neighbour: the plain and the
    /// wall variant differ only in the fit points of ghosts, so those rows are the same fit (in a
    /// 2D cavity with `h = 3Δx`, three rows in four).
    pub fn update_sharing(
        &mut self,
        nl: &NeighborList<D>,
        vol: &[f64],
        rows: usize,
        geometry: Option<(&[[f64; D]], &[crate::particles::Role])>,
        other: &LsOperators<D>,
    ) -> bool {
        let usable =
            self.walls != other.walls && RenormKey::fresh(&other.key, nl, vol, rows).is_none();
        self.update_from(nl, vol, rows, geometry, usable.then_some(other))
    }

    fn update_from(
        &mut self,
        nl: &NeighborList<D>,
        vol: &[f64],
        rows: usize,
        geometry: Option<(&[[f64; D]], &[crate::particles::Role])>,
        donor: Option<&LsOperators<D>>,
    ) -> bool {
        assert!(rows <= nl.len(), "rows beyond the neighbour list");
        let Some(key) = RenormKey::fresh(&self.key, nl, vol, rows) else {
            return false;
        };
        let m = n_quadratic(D);
        assert!(
            m <= MAX_Q,
            "least-squares operators are defined up to 3 dimensions"
        );
        let hinv = 1.0 / nl.h();
        let end = if rows == 0 { 0 } else { nl.row(rows - 1).end };
        // every entry is written below (each row's range, the rows covering `0..end`): only a
        // longer array needs new entries, not a zero fill of the whole (62 MB at 2D 10⁵)
        self.coef.resize(end * Self::S, 0.0);
        // the wall variant's fit points: a ghost g of source s stands for (x_g + x_s)/2
        self.partner.clear();
        let mut shift = Vec::new();
        if let (true, Some((x, role))) = (self.walls, geometry) {
            // (per pair of the list's arrays: the room between regions of rows holds none)
            self.partner.resize(end, u32::MAX);
            shift.resize(end, [0.0; D]);
            for k in (0..rows).flat_map(|i| nl.row(i)) {
                let j = nl.indices()[k] as usize;
                match role[j] {
                    crate::particles::Role::Ghost { source, .. } => {
                        let s = source as usize;
                        self.partner[k] = source;
                        shift[k] = std::array::from_fn::<f64, D, _>(|c| 0.5 * (x[j][c] - x[s][c]));
                    }
                    _ => self.partner[k] = j as u32,
                }
            }
        }
        let shift = &shift;
        // relative position and weight of the fit point of pair k: a ghost's wall point `x_w`
        // weighs `ω_g √(w_h(|x_w − x_i|) w_h(|x_g − x_i|))`, which vanishes continuously as the
        // ghost leaves `h`. Weighing it by its own, shorter distance alone made the fit
        // discontinuous: the list holds pairs out to h + skin (several ghosts share one wall
        // point), and a ghost exactly at r = h on a lattice (w = 0 up to rounding) decided
        // whether a heavy wall point entered — rows at mirrored positions got different
        // operators (a mirror-symmetric field's Laplacian differed by 20 % at the cube's
        // edges, whose steady flow lost its symmetry by 8·10⁻⁴) and the operator depended on
        // the skin. (The ghost's weight alone, `ω_g w_h(|x_g − x_i|)`, is continuous too but
        // weighs the wall less: Re 1000 cavity n = 48, RMS u 1.82 % against 1.69 %.)
        let kernel = *nl.kernel();
        let point = |k: usize, j: usize| -> ([f64; D], f64) {
            let w = nl.w()[k];
            if shift.is_empty() {
                (nl.dx()[k], vol[j] * w)
            } else {
                let d: [f64; D] = std::array::from_fn(|c| nl.dx()[k][c] - shift[k][c]);
                let r = d.iter().map(|v| v * v).sum::<f64>().sqrt();
                (d, vol[j] * (w * kernel.w_h(r)).sqrt())
            }
        };
        // a donor row without ghost neighbours is this variant's row (the wall variant's
        // partners tell the ghosts; a wall variant built without geometry has none)
        let partner: &[u32] = match donor {
            Some(dn) if !self.walls => &dn.partner,
            _ => &self.partner,
        };
        let copied = |i: usize| -> Option<&LsOperators<D>> {
            let dn = donor?;
            (partner.is_empty() || nl.row(i).all(|k| partner[k] == nl.indices()[k])).then_some(dn)
        };
        // rows own disjoint, consecutive pair ranges: split the coefficient array by row
        let mut slices: Vec<(usize, &mut [f64])> = Vec::with_capacity(rows);
        let mut rest: &mut [f64] = &mut self.coef;
        let mut at = 0;
        for i in 0..rows {
            let r = nl.row(i);
            let (_, tail) = rest.split_at_mut((r.start - at) * Self::S);
            let (mine, tail) = tail.split_at_mut(r.len() * Self::S);
            slices.push((i, mine));
            rest = tail;
            at = r.end;
        }
        let fallback = match m {
            2 => ls_rows::<D, 2>(slices, nl, vol, &point, &copied, hinv),
            5 => ls_rows::<D, 5>(slices, nl, vol, &point, &copied, hinv),
            9 => ls_rows::<D, 9>(slices, nl, vol, &point, &copied, hinv),
            _ => unreachable!("quadratic bases have 2, 5 or 9 terms"),
        };
        self.fallback_rows = fallback;
        self.key = Some(key);
        true
    }

    /// Rows the coefficients cover.
    pub fn rows(&self) -> usize {
        self.key.as_ref().map_or(0, |k| k.rows)
    }

    fn check(&self, rows: usize) {
        assert!(
            rows <= self.rows(),
            "least-squares coefficients computed for fewer rows"
        );
    }

    /// The value pair `k` (neighbour `j`) fits: `f_j`, or `(f_g + f_s)/2` for a ghost of the
    /// wall variant.
    #[inline]
    fn scalar(&self, k: usize, j: usize, f: &[f64]) -> f64 {
        match self.partner.get(k) {
            Some(&s) if s as usize != j => 0.5 * (f[j] + f[s as usize]),
            _ => f[j],
        }
    }

    /// [`Self::scalar`] for a vector field.
    #[inline]
    fn vector(&self, k: usize, j: usize, f: &[[f64; D]]) -> [f64; D] {
        match self.partner.get(k) {
            Some(&s) if s as usize != j => {
                std::array::from_fn(|a| 0.5 * (f[j][a] + f[s as usize][a]))
            }
            _ => f[j],
        }
    }

    /// `Δˡˢu` componentwise into `out` (rows `0..out.len()`, at most [`Self::rows`]).
    pub fn laplacian_vec_into(&self, nl: &NeighborList<D>, u: &[[f64; D]], out: &mut [[f64; D]]) {
        self.check(out.len());
        out.par_iter_mut()
            .with_min_len(MIN_ROWS)
            .enumerate()
            .for_each(|(i, o)| {
                let ui = u[i];
                let mut s = [0.0; D];
                for k in nl.row(i) {
                    let uj = self.vector(k, nl.indices()[k] as usize, u);
                    let c = self.coef[k * Self::S + D];
                    for a in 0..D {
                        s[a] += c * (uj[a] - ui[a]);
                    }
                }
                *o = s;
            });
    }

    /// `Δˡˢφ` into `out` (rows `0..out.len()`, at most [`Self::rows`]).
    pub fn laplacian_into(&self, nl: &NeighborList<D>, phi: &[f64], out: &mut [f64]) {
        self.check(out.len());
        out.par_iter_mut()
            .with_min_len(MIN_ROWS)
            .enumerate()
            .for_each(|(i, o)| {
                let fi = phi[i];
                *o = nl
                    .row(i)
                    .map(|k| {
                        self.coef[k * Self::S + D]
                            * (self.scalar(k, nl.indices()[k] as usize, phi) - fi)
                    })
                    .sum();
            });
    }

    /// `∇ˡˢφ` into `out` (rows `0..out.len()`, at most [`Self::rows`]).
    pub fn grad_into(&self, nl: &NeighborList<D>, phi: &[f64], out: &mut [[f64; D]]) {
        self.check(out.len());
        out.par_iter_mut()
            .with_min_len(MIN_ROWS)
            .enumerate()
            .for_each(|(i, o)| {
                let fi = phi[i];
                let mut s = [0.0; D];
                for k in nl.row(i) {
                    let df = self.scalar(k, nl.indices()[k] as usize, phi) - fi;
                    for a in 0..D {
                        s[a] += self.coef[k * Self::S + a] * df;
                    }
                }
                *o = s;
            });
    }

    /// [`Self::grad_into`] of two fields in one pass over the pairs: bit for bit each alone.
    pub fn grad2_into(
        &self,
        nl: &NeighborList<D>,
        f: &[f64],
        g: &[f64],
        out_f: &mut [[f64; D]],
        out_g: &mut [[f64; D]],
    ) {
        self.check(out_f.len());
        out_f
            .par_iter_mut()
            .zip(out_g.par_iter_mut())
            .with_min_len(MIN_ROWS)
            .enumerate()
            .for_each(|(i, (of, og))| {
                let (fi, gi) = (f[i], g[i]);
                let (mut sf, mut sg) = ([0.0; D], [0.0; D]);
                for k in nl.row(i) {
                    let j = nl.indices()[k] as usize;
                    let df = self.scalar(k, j, f) - fi;
                    let dg = self.scalar(k, j, g) - gi;
                    for a in 0..D {
                        let c = self.coef[k * Self::S + a];
                        sf[a] += c * df;
                        sg[a] += c * dg;
                    }
                }
                *of = sf;
                *og = sg;
            });
    }

    /// The gradients of the entries of a velocity gradient `gu` and a pressure gradient `gp` in
    /// one pass over the pairs: `hess_i[a][c] = ∇ˡˢ(gu[a][c])` and `hp_i[c] = ∇ˡˢ(gp[c])` (rows
    /// `0..hess.len()`, at most [`Self::rows`]), bit for bit [`Self::grad_into`] of each entry
    /// alone — the second derivatives of the shift's Taylor correction, which took `D (D + 1)`
    /// passes (and as many copies of a field) that way.
    pub fn grad_of_gradients_into(
        &self,
        nl: &NeighborList<D>,
        gu: &[[[f64; D]; D]],
        gp: &[[f64; D]],
        hess: &mut [[[[f64; D]; D]; D]],
        hp: &mut [[[f64; D]; D]],
    ) {
        self.check(hess.len());
        hess.par_iter_mut()
            .zip(hp.par_iter_mut())
            .with_min_len(MIN_ROWS)
            .enumerate()
            .for_each(|(i, (oh, op))| {
                let mut h = [[[0.0; D]; D]; D];
                let mut q = [[0.0; D]; D];
                for k in nl.row(i) {
                    let j = nl.indices()[k] as usize;
                    // the pair's values as `Self::scalar` takes them (a ghost of the wall
                    // variant: the mean of the ghost's and its partner's)
                    let (vu, vp) = match self.partner.get(k) {
                        Some(&s) if s as usize != j => {
                            let s = s as usize;
                            let vu: [[f64; D]; D] = std::array::from_fn(|a| {
                                std::array::from_fn(|c| 0.5 * (gu[j][a][c] + gu[s][a][c]))
                            });
                            let vp: [f64; D] = std::array::from_fn(|c| 0.5 * (gp[j][c] + gp[s][c]));
                            (vu, vp)
                        }
                        _ => (gu[j], gp[j]),
                    };
                    let coef = &self.coef[k * Self::S..k * Self::S + D];
                    for c in 0..D {
                        for a in 0..D {
                            let df = vu[a][c] - gu[i][a][c];
                            for b in 0..D {
                                h[a][c][b] += coef[b] * df;
                            }
                        }
                        let dg = vp[c] - gp[i][c];
                        for b in 0..D {
                            q[c][b] += coef[b] * dg;
                        }
                    }
                }
                *oh = h;
                *op = q;
            });
    }

    /// The gradient of each component of `u`, `out_i[a][b] = (∇ˡˢu_a)_b` (rows `0..out.len()`,
    /// at most [`Self::rows`]).
    pub fn grad_vec_into(&self, nl: &NeighborList<D>, u: &[[f64; D]], out: &mut [[[f64; D]; D]]) {
        self.check(out.len());
        out.par_iter_mut()
            .with_min_len(MIN_ROWS)
            .enumerate()
            .for_each(|(i, o)| {
                let ui = u[i];
                let mut g = [[0.0; D]; D];
                for k in nl.row(i) {
                    let uj = self.vector(k, nl.indices()[k] as usize, u);
                    for a in 0..D {
                        let du = uj[a] - ui[a];
                        for b in 0..D {
                            g[a][b] += self.coef[k * Self::S + b] * du;
                        }
                    }
                }
                *o = g;
            });
    }

    /// `∇ˡˢ·ψ_i = Σ_a (∇ˡˢψ_a)_a` into `out` (rows `0..out.len()`, at most [`Self::rows`]).
    pub fn div_into(&self, nl: &NeighborList<D>, psi: &[[f64; D]], out: &mut [f64]) {
        self.check(out.len());
        out.par_iter_mut()
            .with_min_len(MIN_ROWS)
            .enumerate()
            .for_each(|(i, o)| *o = self.div_row::<false>(nl, psi, i).0);
    }

    /// [`Self::div_into`] that also returns `max_i Σ_k |c_k|` over the rows `i` with
    /// `counted(i)` (0 when none is), `c_k` the pairs' gradient coefficients, read in the same
    /// pass: the row sums of `|∇ˡˢ·|` are twice that at most.
    pub fn div_gain_into(
        &self,
        nl: &NeighborList<D>,
        psi: &[[f64; D]],
        out: &mut [f64],
        counted: impl Fn(usize) -> bool + Sync,
    ) -> f64 {
        self.check(out.len());
        crate::operators::rows_and_max(out, |i| self.div_row::<true>(nl, psi, i), counted)
    }

    /// Row `i` of `∇ˡˢ·ψ` and, with `GAIN`, `Σ_k |c_k|` (0 without).
    #[inline(always)]
    fn div_row<const GAIN: bool>(
        &self,
        nl: &NeighborList<D>,
        psi: &[[f64; D]],
        i: usize,
    ) -> (f64, f64) {
        let pi = psi[i];
        let (mut s, mut g) = (0.0, 0.0);
        for k in nl.row(i) {
            let pj = self.vector(k, nl.indices()[k] as usize, psi);
            let c = &self.coef[k * Self::S..k * Self::S + D];
            for a in 0..D {
                s += c[a] * (pj[a] - pi[a]);
            }
            if GAIN {
                g += c.iter().map(|v| v * v).sum::<f64>().sqrt();
            }
        }
        (s, g)
    }
}
