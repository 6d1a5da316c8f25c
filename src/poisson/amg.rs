//! Smoothed-aggregation algebraic multigrid (SA-AMG) as a preconditioner for conjugate
//! gradients on the symmetric GPM Poisson matrix `K` (and on any symmetric positive
//! (semi-)definite CSR matrix: the hierarchy is built from the matrix alone, not from particles).
//!
//! # Setup (Vaněk, Mandel & Brezina 1996; the PyAMG defaults where they apply)
//!
//! For each level with matrix `A` (diagonal `D`):
//!
//! 1. **strength of connection** (symmetric): `j ≠ i` is a strong neighbour of `i` when
//!    `|a_ij| ≥ θ √(a_ii a_jj)` ([`AmgParams::theta`]);
//! 2. **aggregation** (greedy, sequential, in index order): pass 1 makes an aggregate of every
//!    node whose strong neighbours are all still free, together with those neighbours; pass 2
//!    attaches each remaining node to the aggregate (from pass 1) of its strongest strong
//!    neighbour; pass 3 attaches nodes without strong neighbours to the aggregate of their
//!    strongest neighbour, or makes them singletons. Rows with a zero diagonal (an isolated
//!    unknown: an empty row of `K`) are left out of every aggregate;
//! 3. **tentative prolongator** `T` from the near-null vector `b` (the constants on the finest
//!    level): `T_{i,J} = b_i/‖b_J‖` for `i` in aggregate `J` (orthonormal columns: the QR
//!    factorisation of `b` on each aggregate), and the coarse near-null vector `b_c = (‖b_J‖)_J`
//!    (the `R` factors), so that `T b_c = b` exactly and the next level coarsens the right
//!    vector;
//! 4. **smoothed prolongator** `P = (I − ω_P D⁻¹A) T` with `ω_P = (4/3)/ρ(D⁻¹A)`, `ρ` from a
//!    Lanczos estimate ([`AmgParams::lanczos_steps`]);
//! 5. **Galerkin coarse operator** `A_c = Pᵀ A P` (`R = Pᵀ`), computed as `Pᵀ (A P)` with
//!    row-parallel sparse accumulation and symmetrised exactly (`(A_c + A_cᵀ)/2`, which only
//!    removes round-off) so that the V-cycle is symmetric to round-off.
//!
//! Coarsening stops at [`AmgParams::coarse_size`] unknowns (or [`AmgParams::max_levels`], or when
//! a level coarsens by less than 10%).
//!
//! # Coarsest level and the null space
//!
//! The coarsest matrix is factorised densely (a small Cholesky–Crout written here, after
//! symmetric scaling to a unit diagonal). A floating (pure-Neumann) component of `K` has the
//! constants as null space; since `T` reproduces the carried near-null vector exactly and
//! `(I − ω_P D⁻¹A)` maps a null vector to itself, every coarse matrix inherits exactly one null
//! vector per floating component (the carried `b_c`), supported on it and with no zero entry.
//! In a Cholesky factorisation without pivoting, the only vanishing pivot of such a component is
//! then its last unknown in index order (every proper principal submatrix of a positive
//! semi-definite matrix whose null vector has no zero entry is definite). A pivot `≤ 1e-9`
//! (unit-diagonal scale; round-off leaves `~n ε`, a genuine pivot is at least `λ_min`) **pins**
//! that unknown: its row and column are replaced by the identity's and the solve returns 0
//! there, ignoring its right side. For a consistent right side (orthogonal to the null space, as
//! every restricted CG residual is up to round-off) this is exactly the solution of `A_c x = b`
//! with `x_j = 0`; the coarse solve is the symmetric positive semi-definite `B_c = Z A_r⁻¹ Zᵀ`
//! (`A_r`: the pinned rows and columns removed). Nothing is regularised or pinned on any other
//! level. The number of pinned unknowns is reported ([`AmgStats::coarse_pinned`]): one per
//! floating component.
//!
//! # The V-cycle is a valid CG preconditioner
//!
//! The smoother is damped Jacobi `S = ω D⁻¹` with `ω = (4/3)/ρ(D⁻¹A)`
//! ([`AmgParams::smoother_weight`]), the same number of sweeps before and after the coarse
//! correction, zero initial guess. Written out for one sweep,
//! `B = S(2S⁻¹ − A)S + (I − SA) P B_c Pᵀ (I − AS)`: symmetric because `S` is, and positive
//! definite when `2S⁻¹ − A > 0`, i.e. `ω ρ(D⁻¹A) < 2`, which holds unless the Lanczos estimate is
//! below 2/3 of the true radius (a few steps from a random start are within a few percent for
//! these matrices). `B_c` is the coarse V-cycle (recursively symmetric positive definite) or the
//! pinned coarse inverse above (only semi-definite: the first term alone makes `B` definite). Rows left out of the aggregation with a zero diagonal get
//! `B = 0` (their residual is always zero).
//!
//! Jacobi is used instead of Gauss–Seidel because it is parallel (rayon) and symmetric.
//!
//! # Reuse
//!
//! [`Amg::build`] does everything; [`Amg::refresh`] keeps the aggregates and `P` and recomputes
//! the Galerkin operators, the smoothers and the coarse factor for new matrix values (same
//! sparsity: the caller's `pattern_id`); [`Amg::update_fine_smoother`] only refreshes the finest
//! level's diagonal, so that a lagged hierarchy can precondition a changed matrix (the V-cycle
//! stays symmetric positive definite for any coarse operators, only its quality degrades).
//! [`AmgCache`] applies the policy of MISSION §4 (refresh when the iteration count grows).

use super::assembly::Assembly;
use super::iterative::{CgInfo, Preconditioner};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::time::Instant;

const MIN_LEN: usize = 1024;
/// Rows per parallel task in the sparse products.
const CHUNK: usize = 2048;
/// Relative pivot (unit-diagonal scale) below which the coarsest factorisation pins an unknown.
const PIN_TOL: f64 = 1e-9;

// ---------------------------------------------------------------------------------------------
// CSR matrices

/// A borrowed CSR matrix: row `i` is `offsets[i]..offsets[i + 1]` of `cols` and `values`
/// (`f64`, or `f32` in the V-cycle's single-precision copies).
#[derive(Clone, Copy, Debug)]
pub struct CsrRef<'a, V = f64> {
    /// Row starts (`rows + 1` entries).
    pub offsets: &'a [usize],
    /// Column of each entry.
    pub cols: &'a [u32],
    /// Value of each entry.
    pub values: &'a [V],
}

impl<'a> From<&'a Assembly> for CsrRef<'a> {
    fn from(a: &'a Assembly) -> Self {
        CsrRef {
            offsets: &a.offsets,
            cols: &a.cols,
            values: &a.values,
        }
    }
}

impl<'a> From<&'a CsrMatrix> for CsrRef<'a> {
    fn from(a: &'a CsrMatrix) -> Self {
        a.view()
    }
}

impl<'a, V: Copy + Into<f64> + Sync> CsrRef<'a, V> {
    /// Number of rows.
    pub fn rows(&self) -> usize {
        self.offsets.len().saturating_sub(1)
    }
    /// Stored entries.
    pub fn nnz(&self) -> usize {
        self.cols.len()
    }
    /// `y = A x` (rayon over rows).
    pub fn spmv(&self, x: &[f64], y: &mut [f64]) {
        y.par_iter_mut()
            .with_min_len(MIN_LEN)
            .enumerate()
            .for_each(|(i, yi)| *yi = self.row_dot(i, x));
    }
    #[inline]
    fn row_dot(&self, i: usize, x: &[f64]) -> f64 {
        let r = self.offsets[i]..self.offsets[i + 1];
        crate::math::sparse_dot(&self.values[r.clone()], &self.cols[r], x)
    }
    /// The same pattern with other values (`values.len() == self.nnz()`).
    fn with_values<W>(self, values: &'a [W]) -> CsrRef<'a, W> {
        debug_assert_eq!(values.len(), self.cols.len());
        CsrRef {
            offsets: self.offsets,
            cols: self.cols,
            values,
        }
    }
}

impl CsrRef<'_> {
    /// The diagonal (zero where a row stores none).
    pub fn diagonal(&self) -> Vec<f64> {
        let mut d = Vec::new();
        self.diagonal_into(&mut d);
        d
    }

    /// [`Self::diagonal`] into `out` (its memory reused).
    pub fn diagonal_into(&self, out: &mut Vec<f64>) {
        out.resize(self.rows(), 0.0);
        out.par_iter_mut()
            .with_min_len(MIN_LEN)
            .enumerate()
            .for_each(|(i, d)| {
                let r = self.offsets[i]..self.offsets[i + 1];
                *d = r
                    .clone()
                    .find(|&k| self.cols[k] as usize == i)
                    .map(|k| self.values[k])
                    .unwrap_or(0.0);
            });
    }
}

/// An owned CSR matrix (coarse operators, prolongators).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct CsrMatrix {
    /// Columns (rows are `offsets.len() − 1`).
    pub ncols: usize,
    /// Row starts.
    pub offsets: Vec<usize>,
    /// Column of each entry, ascending within a row.
    pub cols: Vec<u32>,
    /// Value of each entry.
    pub values: Vec<f64>,
}

impl CsrMatrix {
    /// Borrowed view.
    pub fn view(&self) -> CsrRef<'_> {
        CsrRef {
            offsets: &self.offsets,
            cols: &self.cols,
            values: &self.values,
        }
    }
    /// Number of rows.
    pub fn rows(&self) -> usize {
        self.offsets.len().saturating_sub(1)
    }
    /// Stored entries.
    pub fn nnz(&self) -> usize {
        self.cols.len()
    }

    /// Concatenates row blocks `(row lengths, cols, values)` produced in order.
    fn from_blocks(ncols: usize, blocks: Vec<(Vec<u32>, Vec<u32>, Vec<f64>)>) -> Self {
        let rows: usize = blocks.iter().map(|b| b.0.len()).sum();
        let nnz: usize = blocks.iter().map(|b| b.1.len()).sum();
        let mut offsets = Vec::with_capacity(rows + 1);
        let mut cols = Vec::with_capacity(nnz);
        let mut values = Vec::with_capacity(nnz);
        offsets.push(0);
        for (lens, c, v) in blocks {
            for l in lens {
                let last = *offsets.last().expect("offsets start with 0");
                offsets.push(last + l as usize);
            }
            cols.extend_from_slice(&c);
            values.extend_from_slice(&v);
        }
        CsrMatrix {
            ncols,
            offsets,
            cols,
            values,
        }
    }

    /// The transpose (counting sort; columns stay ascending).
    fn transpose(&self) -> CsrMatrix {
        let n = self.rows();
        let mut counts = vec![0usize; self.ncols + 1];
        for &c in &self.cols {
            counts[c as usize + 1] += 1;
        }
        for i in 0..self.ncols {
            counts[i + 1] += counts[i];
        }
        let offsets = counts.clone();
        let mut next = counts;
        let mut cols = vec![0u32; self.nnz()];
        let mut values = vec![0.0; self.nnz()];
        for i in 0..n {
            for k in self.offsets[i]..self.offsets[i + 1] {
                let c = self.cols[k] as usize;
                let pos = next[c];
                next[c] += 1;
                cols[pos] = i as u32;
                values[pos] = self.values[k];
            }
        }
        CsrMatrix {
            ncols: n,
            offsets,
            cols,
            values,
        }
    }
}

/// Row access for the right operand of [`spgemm`].
trait Rows: Sync {
    fn row(&self, i: usize) -> (&[u32], &[f64]);
}

impl Rows for CsrRef<'_> {
    #[inline]
    fn row(&self, i: usize) -> (&[u32], &[f64]) {
        let r = self.offsets[i]..self.offsets[i + 1];
        (&self.cols[r.clone()], &self.values[r])
    }
}

/// A CSR matrix kept as the row blocks the parallel product produced (no concatenation copy).
struct RowBlocks {
    blocks: Vec<Block>,
}

/// Rows `lo..lo + offsets.len() − 1`.
struct Block {
    offsets: Vec<u32>,
    cols: Vec<u32>,
    vals: Vec<f64>,
}

impl Rows for RowBlocks {
    #[inline]
    fn row(&self, i: usize) -> (&[u32], &[f64]) {
        let b = &self.blocks[i / CHUNK];
        let k = i % CHUNK;
        let r = b.offsets[k] as usize..b.offsets[k + 1] as usize;
        (&b.cols[r.clone()], &b.vals[r])
    }
}

impl RowBlocks {
    fn into_csr(self, ncols: usize) -> CsrMatrix {
        let rows: usize = self.blocks.iter().map(|b| b.offsets.len() - 1).sum();
        let nnz: usize = self.blocks.iter().map(|b| b.cols.len()).sum();
        let mut offsets = Vec::with_capacity(rows + 1);
        let mut cols = Vec::with_capacity(nnz);
        let mut values = Vec::with_capacity(nnz);
        offsets.push(0);
        for b in self.blocks {
            let base = cols.len();
            offsets.extend(b.offsets[1..].iter().map(|&o| base + o as usize));
            cols.extend_from_slice(&b.cols);
            values.extend_from_slice(&b.vals);
        }
        CsrMatrix {
            ncols,
            offsets,
            cols,
            values,
        }
    }
}

/// `C = A B` (sparse × sparse, Gustavson, blocks of `CHUNK` rows in parallel with per-thread
/// accumulators); `sorted` sorts the columns of each row.
fn spgemm(a: CsrRef<'_>, b: &dyn Rows, b_cols: usize, sorted: bool) -> RowBlocks {
    let n = a.rows();
    let blocks: Vec<Block> = (0..n.div_ceil(CHUNK))
        .into_par_iter()
        .map_init(
            || (vec![0.0; b_cols], vec![u32::MAX; b_cols], Vec::<u32>::new()),
            |(acc, mark, row), ch| {
                let lo = ch * CHUNK;
                let hi = ((ch + 1) * CHUNK).min(n);
                let guess = (a.offsets[hi] - a.offsets[lo]) * 2;
                let mut offsets = Vec::with_capacity(hi - lo + 1);
                let mut cols = Vec::with_capacity(guess);
                let mut vals = Vec::with_capacity(guess);
                offsets.push(0u32);
                for i in lo..hi {
                    row.clear();
                    for k in a.offsets[i]..a.offsets[i + 1] {
                        let aik = a.values[k];
                        let (bc, bv) = b.row(a.cols[k] as usize);
                        for (&j, &v) in bc.iter().zip(bv) {
                            let j = j as usize;
                            if mark[j] != i as u32 {
                                mark[j] = i as u32;
                                acc[j] = aik * v;
                                row.push(j as u32);
                            } else {
                                acc[j] += aik * v;
                            }
                        }
                    }
                    if sorted {
                        row.sort_unstable();
                    }
                    for &j in row.iter() {
                        cols.push(j);
                        vals.push(acc[j as usize]);
                    }
                    offsets.push(cols.len() as u32);
                }
                Block {
                    offsets,
                    cols,
                    vals,
                }
            },
        )
        .collect();
    RowBlocks { blocks }
}

/// Replaces every entry by `(a_ij + a_ji)/2` (the pattern of a Galerkin product is symmetric).
fn symmetrize(a: &mut CsrMatrix) {
    let n = a.rows();
    let v = a.view();
    let sym: Vec<f64> = (0..n)
        .into_par_iter()
        .with_min_len(256)
        .flat_map_iter(|i| {
            (v.offsets[i]..v.offsets[i + 1]).map(move |k| {
                let j = v.cols[k] as usize;
                let row_j = &v.cols[v.offsets[j]..v.offsets[j + 1]];
                match row_j.binary_search(&(i as u32)) {
                    Ok(p) => 0.5 * (v.values[k] + v.values[v.offsets[j] + p]),
                    Err(_) => v.values[k],
                }
            })
        })
        .collect();
    a.values = sym;
}

// ---------------------------------------------------------------------------------------------
// Parameters and statistics

/// Parameters of the hierarchy.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct AmgParams {
    /// Strength threshold `θ`: `j` is a strong neighbour of `i` when
    /// `|a_ij| ≥ θ √(a_ii a_jj)` (default 0.04).
    pub theta: f64,
    /// Stop coarsening at this many unknowns; the last level is factorised densely
    /// (default 600).
    pub coarse_size: usize,
    /// Most levels, the finest included (default 12).
    pub max_levels: usize,
    /// Jacobi sweeps before and after the coarse correction (default 1).
    pub sweeps: usize,
    /// Jacobi weight `ω ρ(D⁻¹A)` (default 4/3; must stay below 2 for a positive definite
    /// V-cycle).
    pub smoother_weight: f64,
    /// Prolongator smoothing weight `ω_P ρ(D⁻¹A)` (default 4/3).
    pub prolongator_weight: f64,
    /// Lanczos steps of the spectral-radius estimate (default 8).
    pub lanczos_steps: usize,
    /// Largest coarsest level factorised densely (default 3000); a larger one (coarsening
    /// stagnated) is smoothed instead.
    pub dense_limit: usize,
    /// Levels (finest first) with the additive correction `B = S + P B_c Pᵀ` instead of the
    /// multiplicative V-cycle (default 0).
    pub additive_levels: usize,
    /// Smooth the prolongator with the filtered matrix (strong entries only, weak ones lumped
    /// onto the diagonal so that the near-null vector is still reproduced): sparser `P` and
    /// coarse operators (default true).
    pub filter: bool,
    /// Apply the V-cycle with `f32` copies of its matrices' values (the finest operator, the
    /// coarse operators and the prolongators; sums, vectors and the coarsest factor stay in
    /// `f64`, and so does the CG around it): a V-cycle reads 8 instead of 12 bytes per stored
    /// entry. The copies are taken whenever the hierarchy or its finest level is set up, at 4
    /// bytes per entry. The preconditioner changes by the `f32` rounding of its values
    /// (relative 6·10⁻⁸): symmetric and positive definite as before, CG's iteration counts
    /// unchanged. Measured on the Taylor–Green Poisson matrices (2 threads, alternated): a
    /// V-cycle 3.8 → 2.9–3.4 ms at 2D 10⁵, 35 → 30 ms at 2D 10⁶; a settled Lagrangian step
    /// with shifting at 2D 10⁵ 4–10 ms faster (of 142–164), a fixed one 0.5–5 ms (of 51–56);
    /// at 2D 10⁶ the gain is inside the spread of single runs (default true).
    pub single_precision: bool,
}

impl Default for AmgParams {
    fn default() -> Self {
        AmgParams {
            theta: 0.04,
            coarse_size: 600,
            max_levels: 12,
            sweeps: 1,
            smoother_weight: 4.0 / 3.0,
            prolongator_weight: 4.0 / 3.0,
            lanczos_steps: 8,
            dense_limit: 3000,
            additive_levels: 0,
            filter: true,
            single_precision: true,
        }
    }
}

/// What a hierarchy looks like and what it cost.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct AmgStats {
    /// Unknowns per level (finest first).
    pub sizes: Vec<usize>,
    /// Stored entries per level (finest first).
    pub nnz: Vec<usize>,
    /// Stored entries of each prolongator.
    pub p_nnz: Vec<usize>,
    /// `ρ(D⁻¹A)` estimate per level (all but the coarsest).
    pub rho: Vec<f64>,
    /// Vanishing pivots of the coarsest factorisation (one per floating component), pinned.
    pub coarse_pinned: usize,
    /// Seconds of the last [`Amg::build`] or [`Amg::refresh`].
    pub setup_seconds: f64,
    /// The same, per phase (summed over levels).
    pub times: SetupTimes,
    /// The coarsest level is smoothed, not factorised (it exceeded
    /// [`AmgParams::dense_limit`]).
    pub coarse_smoothed: bool,
}

/// Seconds of a setup per phase, summed over the levels.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct SetupTimes {
    /// Diagonal, strength of connection and aggregation.
    pub aggregate: f64,
    /// Lanczos estimates of `ρ(D⁻¹A)`.
    pub spectral: f64,
    /// Tentative and smoothed prolongators and their transposes.
    pub prolongator: f64,
    /// Galerkin products `Pᵀ A P`.
    pub galerkin: f64,
    /// Coarsest factorisation.
    pub coarse: f64,
}

/// Seconds since `clock`, which restarts.
fn lap(clock: &mut Instant) -> f64 {
    let s = clock.elapsed().as_secs_f64();
    *clock = Instant::now();
    s
}

impl AmgStats {
    /// Number of levels, the finest and the coarsest included.
    pub fn levels(&self) -> usize {
        self.sizes.len()
    }
    /// Operator complexity `Σ_l nnz(A_l) / nnz(A_0)`.
    pub fn operator_complexity(&self) -> f64 {
        match self.nnz.first() {
            Some(&n0) if n0 > 0 => self.nnz.iter().sum::<usize>() as f64 / n0 as f64,
            _ => 0.0,
        }
    }
    /// Grid complexity `Σ_l n_l / n_0`.
    pub fn grid_complexity(&self) -> f64 {
        match self.sizes.first() {
            Some(&n0) if n0 > 0 => self.sizes.iter().sum::<usize>() as f64 / n0 as f64,
            _ => 0.0,
        }
    }
}

// ---------------------------------------------------------------------------------------------
// The hierarchy

/// Damped Jacobi on one level.
#[derive(Clone, Debug, Default)]
struct Smoother {
    /// `ω / a_ii` (0 where `a_ii ≤ 0`).
    s: Vec<f64>,
    rho: f64,
}

impl Smoother {
    /// `ω = weight / ρ`.
    fn new(inv_diag: &[f64], weight: f64, rho: f64) -> Smoother {
        let w = weight / rho;
        Smoother {
            s: inv_diag.iter().map(|d| d * w).collect(),
            rho,
        }
    }
}

/// Transfer between level `l` and `l + 1`.
#[derive(Clone, Debug, Default)]
struct Transfer {
    p: CsrMatrix,
    pt: CsrMatrix,
}

/// The coarsest level's solver.
#[derive(Clone, Debug)]
enum Coarse {
    /// Dense factor.
    Dense {
        /// `1/√a_ii` (0 where `a_ii ≤ 0` and at pinned unknowns).
        scale: Vec<f64>,
        /// Row-major lower-triangular factor of the scaled, pinned matrix.
        l: Vec<f64>,
        pinned: usize,
    },
    /// Too large to factorise densely (coarsening stagnated, e.g. a strongly diagonally
    /// dominant matrix): two damped Jacobi sweeps from zero, `B = 2S − SAS`, symmetric and
    /// positive definite under the smoother's condition.
    Jacobi(Smoother),
}

/// Work vectors of one level.
#[derive(Clone, Debug, Default)]
struct Work {
    b: Vec<f64>,
    x: Vec<f64>,
    r: Vec<f64>,
}

/// A smoothed-aggregation AMG hierarchy. The finest operator is not stored: every method that
/// needs it takes it as an argument, and it must be the matrix the hierarchy was built or last
/// refreshed from (or, after [`Amg::update_fine_smoother`], a matrix with the same pattern).
#[derive(Clone, Debug)]
pub struct Amg {
    params: AmgParams,
    n: usize,
    fine_nnz: usize,
    /// `A_1 … A_L` (level `l ≥ 1` is `ops[l − 1]`).
    ops: Vec<CsrMatrix>,
    smoothers: Vec<Smoother>,
    transfers: Vec<Transfer>,
    coarse: Coarse,
    work: Vec<Work>,
    stats: AmgStats,
    /// `f32` copies of the values the V-cycle reads ([`AmgParams::single_precision`]).
    single: Single,
}

/// The `f32` copies of the values of the finest operator (as last set up), of `A_1 … A_L`
/// and of the prolongators and their transposes.
#[derive(Clone, Debug, Default)]
struct Single {
    fine: Vec<f32>,
    ops: Vec<Vec<f32>>,
    p: Vec<Vec<f32>>,
    pt: Vec<Vec<f32>>,
}

/// `out = values` rounded to `f32`.
fn round_into(values: &[f64], out: &mut Vec<f32>) {
    out.resize(values.len(), 0.0);
    out.par_iter_mut()
        .zip(values.par_iter())
        .with_min_len(MIN_LEN)
        .for_each(|(o, &v)| *o = v as f32);
}

/// Deterministic start vector of the Lanczos estimate (a hash of the index, in `[−1, 1]`).
fn start_vector(n: usize) -> Vec<f64> {
    (0..n)
        .map(|i| {
            let mut z = (i as u64).wrapping_add(0x9E37_79B9_7F4A_7C15);
            z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
            z ^= z >> 31;
            (z >> 11) as f64 / (1u64 << 52) as f64 - 1.0
        })
        .collect()
}

/// Lanczos estimate of `ρ(D⁻¹A) = λ_max(D^{-1/2} A D^{-1/2})` (`inv_diag` = `1/a_ii` or 0).
fn spectral_radius(a: CsrRef<'_>, inv_diag: &[f64], steps: usize) -> f64 {
    let n = a.rows();
    let s: Vec<f64> = inv_diag.iter().map(|&d| d.sqrt()).collect();
    let mut v: Vec<f64> = start_vector(n)
        .iter()
        .zip(&s)
        .map(|(v, s)| if *s > 0.0 { *v } else { 0.0 })
        .collect();
    let norm = dot(&v, &v).sqrt();
    if norm == 0.0 {
        return 0.0;
    }
    v.iter_mut().for_each(|x| *x /= norm);
    let mut v_prev = vec![0.0; n];
    let mut w = vec![0.0; n];
    let mut sv = vec![0.0; n];
    let (mut alphas, mut betas) = (Vec::new(), Vec::new());
    let mut beta = 0.0;
    for _ in 0..steps.max(1) {
        sv.par_iter_mut()
            .zip(v.par_iter().zip(s.par_iter()))
            .with_min_len(MIN_LEN)
            .for_each(|(o, (v, s))| *o = v * s);
        a.spmv(&sv, &mut w);
        w.par_iter_mut()
            .zip(s.par_iter())
            .zip(v_prev.par_iter())
            .with_min_len(MIN_LEN)
            .for_each(|((wi, si), vp)| *wi = *wi * si - beta * vp);
        let alpha = dot(&w, &v);
        w.par_iter_mut()
            .zip(v.par_iter())
            .with_min_len(MIN_LEN)
            .for_each(|(wi, vi)| *wi -= alpha * vi);
        alphas.push(alpha);
        beta = dot(&w, &w).sqrt();
        if beta <= 1e-12 * alpha.abs() {
            break;
        }
        betas.push(beta);
        std::mem::swap(&mut v_prev, &mut v);
        v.par_iter_mut()
            .zip(w.par_iter())
            .with_min_len(MIN_LEN)
            .for_each(|(vi, wi)| *vi = wi / beta);
    }
    let k = alphas.len();
    let t = nalgebra::DMatrix::<f64>::from_fn(k, k, |i, j| {
        if i == j {
            alphas[i]
        } else if i + 1 == j || j + 1 == i {
            betas[i.min(j)]
        } else {
            0.0
        }
    });
    nalgebra::SymmetricEigen::new(t)
        .eigenvalues
        .iter()
        .fold(0.0f64, |m, &e| m.max(e.abs()))
}

/// Sequential dot product (short vectors).
#[inline]
fn dot_seq(a: &[f64], b: &[f64]) -> f64 {
    // four accumulators: lets the compiler vectorise without reassociating a single sum
    let mut acc = [0.0; 4];
    let (ca, ra) = a.split_at(a.len() - a.len() % 4);
    let (cb, rb) = b.split_at(ca.len());
    for (x, y) in ca.chunks_exact(4).zip(cb.chunks_exact(4)) {
        for k in 0..4 {
            acc[k] += x[k] * y[k];
        }
    }
    let mut s = (acc[0] + acc[1]) + (acc[2] + acc[3]);
    for (x, y) in ra.iter().zip(rb) {
        s += x * y;
    }
    s
}

/// `a·b`, summed in fixed chunks so that the result does not depend on the thread schedule
/// (the setup is then bit-for-bit reproducible).
fn dot(a: &[f64], b: &[f64]) -> f64 {
    let parts: Vec<f64> = a
        .par_chunks(4096)
        .zip(b.par_chunks(4096))
        .map(|(x, y)| x.iter().zip(y).map(|(x, y)| x * y).sum::<f64>())
        .collect();
    parts.iter().sum()
}

/// Gershgorin's bound on the spectral radius of `D⁻¹A`: `max_i Σ_j |a_ij| / a_ii` over the rows
/// with a positive diagonal (`inv_diag` from [`inv_diagonal`]).
fn jacobi_gershgorin(a: CsrRef<'_>, inv_diag: &[f64]) -> f64 {
    (0..a.rows())
        .into_par_iter()
        .with_min_len(MIN_LEN)
        .map(|i| {
            let r = a.offsets[i]..a.offsets[i + 1];
            inv_diag[i] * a.values[r].iter().map(|v| v.abs()).sum::<f64>()
        })
        .reduce(|| 0.0, f64::max)
}

/// The largest `weight g / ρ` (see [`Amg::update_fine`]) a moved matrix's smoother may have
/// (`g` Gershgorin's bound on `ρ(D⁻¹A)`): below 2, so that the smoother provably converges;
/// 1.95 leaves the highest mode's amplification at most 0.95.
const KEEP_RHO: f64 = 1.95;

fn inv_diagonal(a: CsrRef<'_>) -> Vec<f64> {
    let mut d = Vec::new();
    inv_diagonal_into(a, &mut d);
    d
}

/// [`inv_diagonal`] into `out` (its memory reused).
fn inv_diagonal_into(a: CsrRef<'_>, out: &mut Vec<f64>) {
    a.diagonal_into(out);
    for d in out.iter_mut() {
        *d = inv_or_zero(*d);
    }
}

/// `1 / d`, or 0 where the diagonal entry `d` is not positive (the smoother skips that row).
fn inv_or_zero(d: f64) -> f64 {
    if d > 0.0 {
        1.0 / d
    } else {
        0.0
    }
}

/// Strong neighbours of every row with their (signed) entries `a_ij`.
fn strength(a: CsrRef<'_>, diag: &[f64], theta: f64) -> RowBlocks {
    let n = a.rows();
    let blocks: Vec<Block> = (0..n.div_ceil(CHUNK))
        .into_par_iter()
        .map(|ch| {
            let lo = ch * CHUNK;
            let hi = ((ch + 1) * CHUNK).min(n);
            let mut offsets = Vec::with_capacity(hi - lo + 1);
            let mut cols = Vec::with_capacity(a.offsets[hi] - a.offsets[lo]);
            let mut vals = Vec::with_capacity(a.offsets[hi] - a.offsets[lo]);
            offsets.push(0u32);
            for i in lo..hi {
                if diag[i] > 0.0 {
                    for k in a.offsets[i]..a.offsets[i + 1] {
                        let j = a.cols[k] as usize;
                        let v = a.values[k];
                        if j != i
                            && diag[j] > 0.0
                            && v != 0.0
                            && v.abs() >= theta * (diag[i] * diag[j]).sqrt()
                        {
                            cols.push(j as u32);
                            vals.push(v);
                        }
                    }
                }
                offsets.push(cols.len() as u32);
            }
            Block {
                offsets,
                cols,
                vals,
            }
        })
        .collect();
    RowBlocks { blocks }
}

/// The filtered matrix `A_F`: the diagonal and the strong entries of `A`, the weak entries
/// lumped onto the diagonal so that `A_F b = A b` for the near-null vector `b` (the constants
/// on the finest level). Used to smooth the prolongator: `P` then reaches only the aggregates
/// of strong neighbours (sparser `P`, cheaper Galerkin products) and still reproduces `b`.
fn filtered(a: CsrRef<'_>, strong: &RowBlocks, diag: &[f64], b: &[f64]) -> CsrMatrix {
    let n = a.rows();
    let blocks: Vec<Block> = (0..n.div_ceil(CHUNK))
        .into_par_iter()
        .map(|ch| {
            let lo = ch * CHUNK;
            let hi = ((ch + 1) * CHUNK).min(n);
            let mut offsets = Vec::with_capacity(hi - lo + 1);
            let mut cols = Vec::new();
            let mut vals = Vec::new();
            offsets.push(0u32);
            for i in lo..hi {
                let (sc, sv) = strong.row(i);
                // A b over all entries minus the strong part: what the diagonal must absorb
                let mut weak = 0.0;
                let mut strong_sum = 0.0;
                for k in a.offsets[i]..a.offsets[i + 1] {
                    let j = a.cols[k] as usize;
                    if j != i {
                        weak += a.values[k] * b[j];
                    }
                }
                for (&j, &v) in sc.iter().zip(sv) {
                    strong_sum += v * b[j as usize];
                }
                weak -= strong_sum;
                let lumped = if b[i] != 0.0 {
                    diag[i] + weak / b[i]
                } else {
                    diag[i]
                };
                cols.push(i as u32);
                vals.push(if lumped > 0.0 { lumped } else { diag[i] });
                cols.extend_from_slice(sc);
                vals.extend_from_slice(sv);
                offsets.push(cols.len() as u32);
            }
            Block {
                offsets,
                cols,
                vals,
            }
        })
        .collect();
    RowBlocks { blocks }.into_csr(n)
}

/// Greedy aggregation on the strength graph; `u32::MAX` for rows left out (zero diagonal).
fn aggregate(a: CsrRef<'_>, diag: &[f64], strong: &RowBlocks) -> (Vec<u32>, usize) {
    const FREE: u32 = u32::MAX - 1;
    const OUT: u32 = u32::MAX;
    let n = a.rows();
    let mut agg: Vec<u32> = diag
        .iter()
        .map(|&d| if d > 0.0 { FREE } else { OUT })
        .collect();
    let mut count = 0u32;
    // pass 1: roots whose strong neighbourhood is entirely free
    for i in 0..n {
        let (si, _) = strong.row(i);
        if agg[i] != FREE || si.is_empty() {
            continue;
        }
        if si.iter().all(|&j| agg[j as usize] == FREE) {
            agg[i] = count;
            for &j in si {
                agg[j as usize] = count;
            }
            count += 1;
        }
    }
    // pass 2: join the pass-1 aggregate of the strongest strong neighbour (every node left
    // with a strong neighbour has an aggregated one: otherwise pass 1 would have made it a root)
    let pass1 = agg.clone();
    for (i, ai) in agg.iter_mut().enumerate() {
        if *ai != FREE {
            continue;
        }
        let (si, sv) = strong.row(i);
        let mut best: Option<(f64, u32)> = None;
        for (&j, &w) in si.iter().zip(sv) {
            let w = w.abs();
            let g = pass1[j as usize];
            if g < FREE && best.is_none_or(|(bw, _)| w > bw) {
                best = Some((w, g));
            }
        }
        if let Some((_, g)) = best {
            *ai = g;
        }
    }
    // pass 3: no strong neighbour: strongest aggregated neighbour, or a singleton
    for i in 0..n {
        if agg[i] != FREE {
            continue;
        }
        let mut best: Option<(f64, u32)> = None;
        for k in a.offsets[i]..a.offsets[i + 1] {
            let j = a.cols[k] as usize;
            let w = a.values[k].abs();
            if j != i && agg[j] < FREE && w > 0.0 && best.is_none_or(|(bw, _)| w > bw) {
                best = Some((w, agg[j]));
            }
        }
        agg[i] = match best {
            Some((_, g)) => g,
            None => {
                count += 1;
                count - 1
            }
        };
    }
    (agg, count as usize)
}

/// Tentative prolongator from the near-null vector `b` of this level: `T_{i,J} = b_i / ‖b_J‖`
/// for `i` in aggregate `J` (the QR factorisation of `b` restricted to each aggregate), and the
/// coarse near-null vector `b_c = (‖b_J‖)_J`, so that `T b_c = b` exactly. Returns the value of
/// `T` in each row (0 for rows outside every aggregate) and `b_c`.
fn tentative(b: &[f64], agg: &[u32], n_agg: usize) -> (Vec<f64>, Vec<f64>) {
    let mut norm2 = vec![0.0; n_agg];
    for (&g, &bi) in agg.iter().zip(b) {
        if g != u32::MAX {
            norm2[g as usize] += bi * bi;
        }
    }
    let bc: Vec<f64> = norm2.iter().map(|v| v.sqrt()).collect();
    let t = agg
        .iter()
        .zip(b)
        .map(|(&g, &bi)| {
            if g == u32::MAX || bc[g as usize] == 0.0 {
                0.0
            } else {
                bi / bc[g as usize]
            }
        })
        .collect();
    (t, bc)
}

/// `P = (I − ω D⁻¹ A) T` with `T_{i,agg(i)} = t_i`.
fn smoothed_prolongator(
    a: CsrRef<'_>,
    inv_diag: &[f64],
    agg: &[u32],
    t: &[f64],
    n_agg: usize,
    omega: f64,
) -> CsrMatrix {
    let n = a.rows();
    let blocks: Vec<(Vec<u32>, Vec<u32>, Vec<f64>)> = (0..n.div_ceil(CHUNK))
        .into_par_iter()
        .map(|ch| {
            let lo = ch * CHUNK;
            let hi = ((ch + 1) * CHUNK).min(n);
            let mut lens = Vec::with_capacity(hi - lo);
            let mut cols = Vec::new();
            let mut vals = Vec::new();
            let mut row: Vec<(u32, f64)> = Vec::new();
            for i in lo..hi {
                row.clear();
                if agg[i] != u32::MAX {
                    row.push((agg[i], t[i]));
                    let f = omega * inv_diag[i];
                    for k in a.offsets[i]..a.offsets[i + 1] {
                        let j = a.cols[k] as usize;
                        if agg[j] == u32::MAX {
                            continue;
                        }
                        let v = -f * a.values[k] * t[j];
                        match row.iter_mut().find(|e| e.0 == agg[j]) {
                            Some(e) => e.1 += v,
                            None => row.push((agg[j], v)),
                        }
                    }
                    row.sort_unstable_by_key(|e| e.0);
                }
                lens.push(row.len() as u32);
                for &(c, v) in &row {
                    cols.push(c);
                    vals.push(v);
                }
            }
            (lens, cols, vals)
        })
        .collect();
    CsrMatrix::from_blocks(n_agg, blocks)
}

/// `Pᵀ A P`, symmetrised.
fn galerkin(a: CsrRef<'_>, tr: &Transfer) -> CsrMatrix {
    let t = Instant::now();
    let ap = spgemm(a, &tr.p.view(), tr.p.ncols, false);
    let t1 = t.elapsed().as_secs_f64();
    let mut c = spgemm(tr.pt.view(), &ap, tr.p.ncols, true).into_csr(tr.p.ncols);
    if std::env::var_os("GPM_AMG_TRACE").is_some() {
        let f1: usize = (0..a.rows())
            .map(|i| {
                (a.offsets[i]..a.offsets[i + 1])
                    .map(|k| {
                        tr.p.offsets[a.cols[k] as usize + 1] - tr.p.offsets[a.cols[k] as usize]
                    })
                    .sum::<usize>()
            })
            .sum();
        let apn: usize = ap.blocks.iter().map(|b| b.cols.len()).sum();
        eprintln!(
            "AP {t1:.3} s ({f1} flops, nnz {apn}), PtAP {:.3} s",
            t.elapsed().as_secs_f64() - t1
        );
    }
    drop(ap);
    symmetrize(&mut c);
    c
}

impl Coarse {
    fn new(a: CsrRef<'_>, params: &AmgParams) -> Coarse {
        if a.rows() <= params.dense_limit {
            return Coarse::factor(a);
        }
        let inv_diag = inv_diagonal(a);
        let rho = spectral_radius(a, &inv_diag, params.lanczos_steps);
        Coarse::Jacobi(Smoother::new(&inv_diag, params.smoother_weight, rho))
    }

    fn pinned(&self) -> usize {
        match self {
            Coarse::Dense { pinned, .. } => *pinned,
            Coarse::Jacobi(_) => 0,
        }
    }

    /// Dense Cholesky `A_s = L Lᵀ` of the unit-diagonal scaling `A_s = S A S`, row by row
    /// (Cholesky–Crout, contiguous dot products), pinning every unknown whose pivot falls to
    /// `PIN_TOL` or below: its row and column are replaced by the identity's and its scale set to
    /// zero, so that the solve returns `x_j = 0` and ignores `b_j`.
    fn factor(a: CsrRef<'_>) -> Coarse {
        let n = a.rows();
        let d = a.diagonal();
        let mut scale: Vec<f64> = d
            .iter()
            .map(|&v| if v > 0.0 { 1.0 / v.sqrt() } else { 0.0 })
            .collect();
        // row-major lower triangle (the strict upper part stays zero)
        let mut l = vec![0.0; n * n];
        for i in 0..n {
            if scale[i] == 0.0 {
                continue;
            }
            for k in a.offsets[i]..a.offsets[i + 1] {
                let j = a.cols[k] as usize;
                if j <= i && scale[j] > 0.0 {
                    l[i * n + j] = a.values[k] * scale[i] * scale[j];
                }
            }
        }
        let mut pinned = 0;
        for i in 0..n {
            let (done, rest) = l.split_at_mut(i * n);
            let row = &mut rest[..n];
            if scale[i] == 0.0 {
                // a zero row (no diagonal): identity, x_i = 0
                row[..i].fill(0.0);
                row[i] = 1.0;
                continue;
            }
            for j in 0..i {
                let lj = &done[j * n..j * n + j];
                let s = row[j] - dot_seq(&row[..j], lj);
                let ljj = done[j * n + j];
                row[j] = if scale[j] == 0.0 { 0.0 } else { s / ljj };
            }
            let piv = row[i] - dot_seq(&row[..i], &row[..i]);
            if piv <= PIN_TOL {
                // the last unknown of a singular (floating) component: pin it
                row[..i].fill(0.0);
                row[i] = 1.0;
                scale[i] = 0.0;
                pinned += 1;
            } else {
                row[i] = piv.sqrt();
            }
        }
        Coarse::Dense { scale, l, pinned }
    }

    /// `x = B_c b`, `a` the coarsest operator, `t` scratch.
    fn solve(&self, a: CsrRef<'_>, b: &[f64], x: &mut [f64], t: &mut [f64]) {
        match self {
            Coarse::Dense { scale, l, .. } => {
                let n = scale.len();
                // L y = S b (forward, row-oriented)
                for i in 0..n {
                    let row = &l[i * n..i * n + i + 1];
                    x[i] = (b[i] * scale[i] - dot_seq(&row[..i], &x[..i])) / row[i];
                }
                // Lᵀ z = y (backward, column-oriented: row i of L is column i of Lᵀ)
                for i in (0..n).rev() {
                    let row = &l[i * n..i * n + i + 1];
                    let xi = x[i] / row[i];
                    x[i] = xi;
                    for (xk, lk) in x[..i].iter_mut().zip(&row[..i]) {
                        *xk -= lk * xi;
                    }
                }
                for i in 0..n {
                    x[i] *= scale[i];
                }
            }
            Coarse::Jacobi(sm) => {
                x.par_iter_mut()
                    .zip(b.par_iter().zip(sm.s.par_iter()))
                    .with_min_len(MIN_LEN)
                    .for_each(|(x, (b, s))| *x = s * b);
                jacobi_sweep(a, &sm.s, b, x, t);
            }
        }
    }
}

impl Amg {
    /// Builds the hierarchy of the symmetric matrix `a` (full storage, both triangles).
    pub fn build(a: CsrRef<'_>, params: AmgParams) -> Amg {
        let t0 = Instant::now();
        let n = a.rows();
        let mut ops: Vec<CsrMatrix> = Vec::new();
        let mut smoothers = Vec::new();
        let mut transfers = Vec::new();
        let mut stats = AmgStats {
            sizes: vec![n],
            nnz: vec![a.nnz()],
            ..Default::default()
        };
        // near-null space: the constants on the finest level, carried down exactly
        let mut near_null = vec![1.0; n];
        loop {
            let cur = ops.last().map(|m| m.view()).unwrap_or(a);
            let nl = cur.rows();
            if nl <= params.coarse_size || stats.sizes.len() >= params.max_levels.max(1) {
                break;
            }
            let mut clock = Instant::now();
            let diag = cur.diagonal();
            let inv_diag: Vec<f64> = diag
                .iter()
                .map(|&d| if d > 0.0 { 1.0 / d } else { 0.0 })
                .collect();
            let strong = strength(cur, &diag, params.theta);
            let (agg, n_agg) = aggregate(cur, &diag, &strong);
            stats.times.aggregate += lap(&mut clock);
            if n_agg == 0 || n_agg as f64 > 0.9 * nl as f64 {
                break;
            }
            let rho = spectral_radius(cur, &inv_diag, params.lanczos_steps);
            stats.times.spectral += lap(&mut clock);
            let (t, bc) = tentative(&near_null, &agg, n_agg);
            let p = if params.filter {
                let af = filtered(cur, &strong, &diag, &near_null);
                let inv_f = inv_diagonal(af.view());
                let rho_f = spectral_radius(af.view(), &inv_f, params.lanczos_steps);
                smoothed_prolongator(
                    af.view(),
                    &inv_f,
                    &agg,
                    &t,
                    n_agg,
                    params.prolongator_weight / rho_f,
                )
            } else {
                smoothed_prolongator(
                    cur,
                    &inv_diag,
                    &agg,
                    &t,
                    n_agg,
                    params.prolongator_weight / rho,
                )
            };
            drop(strong);
            near_null = bc;
            stats.times.prolongator += lap(&mut clock);
            let pt = p.transpose();
            let tr = Transfer { p, pt };
            stats.times.prolongator += lap(&mut clock);
            let c = galerkin(cur, &tr);
            stats.times.galerkin += lap(&mut clock);
            smoothers.push(Smoother::new(&inv_diag, params.smoother_weight, rho));
            stats.rho.push(rho);
            stats.p_nnz.push(tr.p.nnz());
            stats.sizes.push(c.rows());
            stats.nnz.push(c.nnz());
            transfers.push(tr);
            ops.push(c);
        }
        let mut clock = Instant::now();
        let coarse = Coarse::new(ops.last().map(|m| m.view()).unwrap_or(a), &params);
        stats.times.coarse = lap(&mut clock);
        stats.coarse_pinned = coarse.pinned();
        stats.coarse_smoothed = matches!(coarse, Coarse::Jacobi(_));
        let work = stats
            .sizes
            .iter()
            .map(|&m| Work {
                b: vec![0.0; m],
                x: vec![0.0; m],
                r: vec![0.0; m],
            })
            .collect();
        let mut amg = Amg {
            params,
            n,
            fine_nnz: a.nnz(),
            ops,
            smoothers,
            transfers,
            coarse,
            work,
            stats,
            single: Single::default(),
        };
        amg.round_fine(a);
        amg.round_coarse();
        amg.stats.setup_seconds = t0.elapsed().as_secs_f64();
        amg
    }

    /// The `f32` copy of the finest operator's values (with [`AmgParams::single_precision`]
    /// and at least two levels).
    fn round_fine(&mut self, a: CsrRef<'_>) {
        if self.params.single_precision && !self.transfers.is_empty() {
            round_into(a.values, &mut self.single.fine);
        }
    }

    /// The `f32` copies of the coarse operators and the prolongators.
    fn round_coarse(&mut self) {
        if !self.params.single_precision {
            return;
        }
        let levels = self.transfers.len();
        let single = &mut self.single;
        single.ops.resize_with(levels, Vec::new);
        single.p.resize_with(levels, Vec::new);
        single.pt.resize_with(levels, Vec::new);
        for l in 0..levels {
            round_into(&self.ops[l].values, &mut single.ops[l]);
            round_into(&self.transfers[l].p.values, &mut single.p[l]);
            round_into(&self.transfers[l].pt.values, &mut single.pt[l]);
        }
    }

    /// Values-only refresh: same aggregates and prolongators, new Galerkin operators, smoothers
    /// and coarse factor for the new values of `a`. The finest level's spectral radius is kept
    /// from the build (it only sets the Jacobi weight; see the module docs); coarse levels get new
    /// estimates. `a` must have the unknowns the hierarchy was built for; its pattern may
    /// differ (particles that moved: the aggregates then group the same particles as at the
    /// build, which stays a good coarse space while they move less than an aggregate's size).
    pub fn refresh(&mut self, a: CsrRef<'_>) {
        self.refresh_inner(a, false);
    }

    /// [`Self::refresh`]; with `new_pattern` (the same unknowns, a changed pattern) the finest
    /// level's spectral radius is estimated again (see [`Self::update_fine`]).
    fn refresh_inner(&mut self, a: CsrRef<'_>, new_pattern: bool) {
        assert!(
            a.rows() == self.n,
            "Amg::refresh needs the unknowns the hierarchy was built for"
        );
        self.fine_nnz = a.nnz();
        let t0 = Instant::now();
        let mut clock = Instant::now();
        let mut times = SetupTimes::default();
        self.update_fine(a, new_pattern, None, None);
        times.aggregate += lap(&mut clock);
        for l in 0..self.transfers.len() {
            let c = {
                let cur = if l == 0 { a } else { self.ops[l - 1].view() };
                galerkin(cur, &self.transfers[l])
            };
            self.ops[l] = c;
            times.galerkin += lap(&mut clock);
            if l + 1 < self.smoothers.len() {
                let cur = self.ops[l].view();
                let inv_diag = inv_diagonal(cur);
                let rho = spectral_radius(cur, &inv_diag, self.params.lanczos_steps);
                self.smoothers[l + 1] = Smoother::new(&inv_diag, self.params.smoother_weight, rho);
                self.stats.rho[l + 1] = rho;
                times.spectral += lap(&mut clock);
            }
            self.stats.nnz[l + 1] = self.ops[l].nnz();
        }
        self.coarse = Coarse::new(self.ops.last().map(|m| m.view()).unwrap_or(a), &self.params);
        times.coarse = lap(&mut clock);
        self.stats.coarse_pinned = self.coarse.pinned();
        self.round_coarse();
        self.stats.times = times;
        self.stats.setup_seconds = t0.elapsed().as_secs_f64();
    }

    /// Recomputes the finest level's Jacobi diagonal from `a` (same pattern), keeping its
    /// spectral-radius estimate: the cheap step that lets a lagged hierarchy precondition a
    /// changed matrix. A hierarchy of one level (the dense solve) is refactorised instead.
    pub fn update_fine_smoother(&mut self, a: CsrRef<'_>) {
        self.update_fine(a, false, None, None);
    }

    /// [`Self::update_fine_smoother`]; with `estimate` (a matrix whose pattern changed: the
    /// same particles moved) the finest level's spectral radius is checked against the new
    /// matrix: a Jacobi weight set for the old matrix may exceed the new one's stable range
    /// (the V-cycle is then not positive definite), so the last estimate is raised where
    /// Gershgorin's bound does not prove it stable ([`KEEP_RHO`]). `diag_at` (each row's
    /// diagonal entry's position) and `bound` (Gershgorin's bound, taken when the values were
    /// written: [`Assembly::jacobi_bound`]) spare the passes over the matrix that find them.
    fn update_fine(
        &mut self,
        a: CsrRef<'_>,
        estimate: bool,
        diag_at: Option<&[usize]>,
        bound: Option<f64>,
    ) {
        assert_eq!(a.rows(), self.n, "matrix size changed");
        if self.transfers.is_empty() {
            self.coarse = Coarse::new(a, &self.params);
            self.stats.coarse_pinned = self.coarse.pinned();
            return;
        }
        // the new inverse diagonal in the smoother's own vector, scaled in place below
        let mut inv_diag = std::mem::take(&mut self.smoothers[0].s);
        match diag_at {
            Some(at) => {
                inv_diag.resize(at.len(), 0.0);
                inv_diag
                    .par_iter_mut()
                    .zip(at.par_iter())
                    .with_min_len(MIN_LEN)
                    .for_each(|(d, &k)| *d = inv_or_zero(a.values[k]));
            }
            None => inv_diagonal_into(a, &mut inv_diag),
        }
        let last = self.smoothers[0].rho;
        // a moved matrix keeps the last estimate, raised where needed to the smallest `ρ` for
        // which Gershgorin's bound `g ≥ ρ(D⁻¹A)` of the new matrix proves the smoother
        // convergent (`ω λ ≤ weight g / ρ ≤ KEEP_RHO < 2` for every eigenvalue `λ` of `D⁻¹A`,
        // so the V-cycle stays positive definite): one pass over the matrix instead of the
        // Lanczos steps. Moved particles change `ρ` little (10⁻⁴ per step on a moving 2D 10⁵
        // Taylor–Green, ρ ≈ 1.55, g = 2: kept as it is); in 3D (ρ ≈ 1.33, g = 2) the raise
        // under-relaxes the smoother by 3 %.
        let rho = if !estimate {
            last
        } else {
            let rho = if last > 0.0 {
                let g = bound.unwrap_or_else(|| jacobi_gershgorin(a, &inv_diag));
                last.max(self.params.smoother_weight * g / KEEP_RHO)
            } else {
                spectral_radius(a, &inv_diag, self.params.lanczos_steps)
            };
            self.stats.rho[0] = rho;
            rho
        };
        let w = self.params.smoother_weight / rho;
        inv_diag
            .par_iter_mut()
            .with_min_len(MIN_LEN)
            .for_each(|d| *d *= w);
        self.smoothers[0] = Smoother { s: inv_diag, rho };
        self.round_fine(a);
    }

    /// Statistics: sizes, complexity, setup time.
    pub fn stats(&self) -> &AmgStats {
        &self.stats
    }

    /// Unknowns of the finest level.
    pub fn n(&self) -> usize {
        self.n
    }

    /// The parameters the hierarchy was built with.
    pub fn params(&self) -> &AmgParams {
        &self.params
    }

    /// The Galerkin operator of level `l ≥ 1` (`None` for `l = 0`, which is the caller's matrix,
    /// or past the coarsest level).
    pub fn operator(&self, l: usize) -> Option<&CsrMatrix> {
        l.checked_sub(1).and_then(|k| self.ops.get(k))
    }

    /// The prolongator from level `l + 1` to level `l`.
    pub fn prolongator(&self, l: usize) -> Option<&CsrMatrix> {
        self.transfers.get(l).map(|t| &t.p)
    }

    /// One V-cycle `x = B b` from a zero initial guess, `a` the finest operator (with
    /// [`AmgParams::single_precision`] its values are read from the copy taken when the
    /// hierarchy or its finest level was last set up: `a` must be that matrix, as for the
    /// smoother's diagonal).
    pub fn vcycle(&mut self, a: CsrRef<'_>, b: &[f64], x: &mut [f64]) {
        assert!(b.len() == self.n && x.len() == self.n && a.rows() == self.n);
        let Amg {
            params,
            ops,
            smoothers,
            transfers,
            coarse,
            work,
            single,
            ..
        } = self;
        let levels = Levels {
            count: transfers.len(),
            params,
            smoothers,
            coarse,
            coarsest: ops.last().map_or(a, |m| m.view()),
        };
        if params.single_precision && !transfers.is_empty() {
            assert_eq!(
                single.fine.len(),
                a.nnz(),
                "Amg::vcycle: not the finest operator the hierarchy was set up with"
            );
            levels.cycle(
                work,
                b,
                x,
                |l| match l {
                    0 => a.with_values(&single.fine[..]),
                    _ => ops[l - 1].view().with_values(&single.ops[l - 1][..]),
                },
                |l| transfers[l].p.view().with_values(&single.p[l][..]),
                |l| transfers[l].pt.view().with_values(&single.pt[l][..]),
            );
        } else {
            levels.cycle(
                work,
                b,
                x,
                |l| match l {
                    0 => a,
                    _ => ops[l - 1].view(),
                },
                |l| transfers[l].p.view(),
                |l| transfers[l].pt.view(),
            );
        }
    }
}

/// What a V-cycle reads besides the matrices: the parameters, the smoothers and the coarsest
/// solve with its operator.
struct Levels<'a> {
    /// Levels with a smoother and a transfer (all but the coarsest).
    count: usize,
    params: &'a AmgParams,
    smoothers: &'a [Smoother],
    coarse: &'a Coarse,
    coarsest: CsrRef<'a>,
}

impl Levels<'_> {
    /// The V-cycle on the operators `op(l)` (`op(0)` the finest), the prolongators `p(l)` and
    /// their transposes `pt(l)`, with values of type `V`.
    fn cycle<'m, V: Copy + Into<f64> + Sync + 'm>(
        &self,
        work: &mut [Work],
        b: &[f64],
        x: &mut [f64],
        op: impl Fn(usize) -> CsrRef<'m, V>,
        p: impl Fn(usize) -> CsrRef<'m, V>,
        pt: impl Fn(usize) -> CsrRef<'m, V>,
    ) {
        let nlev = self.count;
        if nlev == 0 {
            self.coarse.solve(self.coarsest, b, x, &mut work[0].r);
            return;
        }
        let sweeps = self.params.sweeps.max(1);
        // down
        for l in 0..nlev {
            let (head, tail) = work.split_at_mut(l + 1);
            let w = &mut head[l];
            let (bl, xl): (&[f64], &mut [f64]) = if l == 0 {
                (b, &mut *x)
            } else {
                (&w.b, &mut w.x)
            };
            let al = op(l);
            let s = &self.smoothers[l].s;
            if l < self.params.additive_levels {
                xl.par_iter_mut()
                    .zip(bl.par_iter().zip(s.par_iter()))
                    .with_min_len(MIN_LEN)
                    .for_each(|(x, (b, s))| *x = s * b);
                let pt = pt(l);
                tail[0]
                    .b
                    .par_iter_mut()
                    .with_min_len(256)
                    .enumerate()
                    .for_each(|(c, bc)| *bc = pt.row_dot(c, bl));
                continue;
            }
            // x = S b (the first sweep from zero), then r = b − A x as a plain product: one
            // gather per entry and the four partial sums of `row_dot`, where forming `S b` inside
            // the product (both in one pass) gathered `s` and `b` and summed in one chain
            xl.par_iter_mut()
                .zip(bl.par_iter().zip(s.par_iter()))
                .with_min_len(MIN_LEN)
                .for_each(|(x, (b, s))| *x = s * b);
            residual(al, bl, xl, &mut w.r);
            for _ in 1..sweeps {
                jacobi_sweep(al, s, bl, xl, &mut w.r);
                residual(al, bl, xl, &mut w.r);
            }
            // restrict: b_{l+1} = Pᵀ r
            let pt = pt(l);
            let r = &w.r;
            tail[0]
                .b
                .par_iter_mut()
                .with_min_len(256)
                .enumerate()
                .for_each(|(c, bc)| *bc = pt.row_dot(c, r));
        }
        {
            let w = &mut work[nlev];
            self.coarse.solve(self.coarsest, &w.b, &mut w.x, &mut w.r);
        }
        // up
        for l in (0..nlev).rev() {
            let (head, tail) = work.split_at_mut(l + 1);
            let w = &mut head[l];
            let (bl, xl): (&[f64], &mut [f64]) = if l == 0 {
                (b, &mut *x)
            } else {
                (&w.b, &mut w.x)
            };
            let al = op(l);
            let p = p(l);
            let xc = &tail[0].x;
            xl.par_iter_mut()
                .with_min_len(MIN_LEN)
                .enumerate()
                .for_each(|(i, xi)| *xi += p.row_dot(i, xc));
            if l < self.params.additive_levels {
                continue;
            }
            let s = &self.smoothers[l].s;
            for _ in 0..sweeps {
                jacobi_sweep(al, s, bl, xl, &mut w.r);
            }
        }
    }
}

/// `x += S (b − A x)` (`t` is scratch).
fn jacobi_sweep<V: Copy + Into<f64> + Sync>(
    a: CsrRef<'_, V>,
    s: &[f64],
    b: &[f64],
    x: &mut [f64],
    t: &mut [f64],
) {
    {
        let xr: &[f64] = x;
        t.par_iter_mut()
            .with_min_len(MIN_LEN)
            .enumerate()
            .for_each(|(i, ti)| *ti = s[i] * (b[i] - a.row_dot(i, xr)));
    }
    x.par_iter_mut()
        .zip(t.par_iter())
        .with_min_len(MIN_LEN)
        .for_each(|(xi, ti)| *xi += ti);
}

/// `r = b − A x`.
fn residual<V: Copy + Into<f64> + Sync>(a: CsrRef<'_, V>, b: &[f64], x: &[f64], r: &mut [f64]) {
    r.par_iter_mut()
        .with_min_len(MIN_LEN)
        .enumerate()
        .for_each(|(i, ri)| *ri = b[i] - a.row_dot(i, x));
}

/// [`Amg`] as the preconditioner of [`super::iterative::pcg_with`]: the hierarchy together with
/// the finest operator it preconditions.
pub struct AmgPreconditioner<'a> {
    /// The hierarchy.
    pub amg: &'a mut Amg,
    /// The finest operator (the CG matrix).
    pub a: CsrRef<'a>,
}

impl Preconditioner for AmgPreconditioner<'_> {
    fn apply(&mut self, r: &[f64], z: &mut [f64]) {
        self.amg.vcycle(self.a, r, z);
    }
}

// ---------------------------------------------------------------------------------------------
// Reuse across solves

/// What the cache did to the hierarchy before a solve.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum AmgSetup {
    /// No AMG in this solve.
    #[default]
    None,
    /// Matrix values unchanged: the hierarchy used as it was.
    Reused,
    /// Values changed, hierarchy kept (lag policy); only the finest Jacobi diagonal updated.
    Lagged,
    /// Values-only refresh: Galerkin operators, smoothers and coarse factor recomputed on the
    /// same aggregates and prolongators.
    Refreshed,
    /// Full rebuild.
    Rebuilt,
}

/// Switches of the reuse policy (each can be turned off for benchmarks).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AmgReuse {
    /// Keep the hierarchy unchanged while the matrix values are unchanged.
    pub unchanged: bool,
    /// Same pattern, new values: refresh values only instead of rebuilding.
    pub values: bool,
    /// Same pattern, new values: keep the hierarchy while CG's iterations per decade of residual
    /// reduction stay within `lag_factor` times those right after the last refresh.
    pub lag: bool,
    /// The lag threshold (also: a values-only refresh whose rate exceeds `lag_factor` times the
    /// rate right after the last full rebuild asks for a full rebuild next time).
    pub lag_factor: f64,
    /// New pattern, same unknowns (moved particles keep their indices): treat it as new
    /// values — keep the hierarchy (with `lag`) or its aggregates and prolongators with new
    /// Galerkin operators (with `values`) until the iteration rate asks for more.
    pub aggregates: bool,
}

impl Default for AmgReuse {
    fn default() -> Self {
        AmgReuse {
            unchanged: true,
            values: true,
            lag: true,
            lag_factor: 1.5,
            aggregates: true,
        }
    }
}

#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
enum Want {
    #[default]
    Nothing,
    Refresh,
    Rebuild,
}

/// The AMG state a solver keeps between solves, with the reuse policy of MISSION §4.
///
/// The quality measure is the number of CG iterations per decade of residual reduction,
/// `iters / log10(‖r₀‖/‖r‖)`, rather than the raw count, so that a good warm start (fewer
/// iterations for the same hierarchy) is not mistaken for a better hierarchy and a poor one for
/// a worse hierarchy.
#[derive(Clone, Debug, Default)]
pub struct AmgCache {
    /// Hierarchy parameters (used at the next full rebuild).
    pub params: AmgParams,
    amg: Option<Amg>,
    pattern_id: u64,
    last: AmgSetup,
    want: Want,
    ref_rate: f64,
    full_rate: f64,
    /// The hierarchy is a full build from the matrix values in use (set by a rebuild, cleared
    /// by a lag or a values-only refresh): rebuilding it would give the same hierarchy, so a
    /// worse iteration rate (a warm start that left less to reduce) asks for nothing.
    exact: bool,
    /// Full rebuilds so far.
    pub rebuilds: u64,
    /// Values-only refreshes so far.
    pub refreshes: u64,
    /// Solves that used a lagged (stale) hierarchy.
    pub lagged: u64,
}

impl AmgCache {
    /// A cache with these hierarchy parameters.
    pub fn new(params: AmgParams) -> Self {
        AmgCache {
            params,
            ..Default::default()
        }
    }

    /// The current hierarchy, if any.
    pub fn hierarchy(&self) -> Option<&Amg> {
        self.amg.as_ref()
    }

    /// The current hierarchy, mutably (to apply its V-cycle directly).
    pub fn hierarchy_mut(&mut self) -> Option<&mut Amg> {
        self.amg.as_mut()
    }

    /// Makes the hierarchy ready for the matrix of `a` and says what that took.
    pub fn prepare(&mut self, a: &Assembly, reuse: AmgReuse) -> AmgSetup {
        let m = CsrRef::from(a);
        let same_n = self.amg.as_ref().is_some_and(|h| h.n() == a.n());
        let same = same_n && self.pattern_id == a.pattern_id();
        // the same particles under a new pattern are treated as new values (when allowed)
        let setup = if !same_n || !(same || reuse.aggregates) {
            AmgSetup::Rebuilt
        } else {
            match self.want {
                Want::Rebuild => AmgSetup::Rebuilt,
                Want::Refresh if reuse.values => AmgSetup::Refreshed,
                Want::Refresh => AmgSetup::Rebuilt,
                Want::Nothing if same && reuse.unchanged && a.values_current() => AmgSetup::Reused,
                Want::Nothing if reuse.lag => AmgSetup::Lagged,
                Want::Nothing if reuse.values => AmgSetup::Refreshed,
                Want::Nothing => AmgSetup::Rebuilt,
            }
        };
        match setup {
            AmgSetup::Rebuilt => {
                self.amg = Some(Amg::build(m, self.params));
                self.pattern_id = a.pattern_id();
                self.rebuilds += 1;
                self.exact = true;
            }
            AmgSetup::Refreshed => {
                let h = self.amg.as_mut().expect("hierarchy");
                h.refresh_inner(m, !same);
                self.pattern_id = a.pattern_id();
                self.refreshes += 1;
                self.exact = false;
            }
            AmgSetup::Lagged => {
                let h = self.amg.as_mut().expect("hierarchy");
                h.update_fine(m, !same, Some(&a.diag), a.jacobi_bound());
                self.pattern_id = a.pattern_id();
                self.lagged += 1;
                self.exact = false;
            }
            AmgSetup::Reused | AmgSetup::None => {}
        }
        self.last = setup;
        self.want = Want::Nothing;
        setup
    }

    /// The preconditioner for the matrix of `a` (after [`AmgCache::prepare`]).
    pub fn preconditioner<'a>(&'a mut self, a: &'a Assembly) -> AmgPreconditioner<'a> {
        AmgPreconditioner {
            amg: self.amg.as_mut().expect("AmgCache::prepare before use"),
            a: CsrRef::from(a),
        }
    }

    /// Feeds back the CG run that followed [`AmgCache::prepare`] (lag bookkeeping).
    pub fn record(&mut self, cg: &CgInfo, reuse: AmgReuse) {
        let decades = if cg.initial_residual > 0.0 && cg.final_residual > 0.0 {
            (cg.initial_residual / cg.final_residual).log10()
        } else {
            0.0
        };
        // too little reduction to measure a rate
        if cg.iters < 3 || decades < 0.5 {
            return;
        }
        let rate = cg.iters as f64 / decades;
        match self.last {
            AmgSetup::Rebuilt => {
                self.full_rate = rate;
                self.ref_rate = rate;
            }
            AmgSetup::Refreshed => {
                self.ref_rate = rate;
                if self.full_rate > 0.0 && rate > reuse.lag_factor * self.full_rate {
                    self.want = Want::Rebuild;
                }
            }
            AmgSetup::Reused if self.exact => {
                // the matrix the hierarchy was built from: nothing a setup could improve
                if self.ref_rate == 0.0 {
                    self.ref_rate = rate;
                }
            }
            AmgSetup::Lagged | AmgSetup::Reused => {
                if self.ref_rate == 0.0 {
                    // no reference measured yet (the solves since the last setup reduced the
                    // residual too little): this one is the reference
                    self.ref_rate = rate;
                } else if rate > reuse.lag_factor * self.ref_rate {
                    self.want = if reuse.values {
                        Want::Refresh
                    } else {
                        Want::Rebuild
                    };
                }
            }
            AmgSetup::None => {}
        }
    }
}
