//! Fixed-radius neighbour lists: one flat list with cached pair data, read by every
//! operator, the Poisson assembly and the diagnostics. Rows are stored in order, each region
//! of 512 rows with room to spare after it, so that a moving step's measure writes the pairs
//! in one pass; [`NeighborList::row`] gives a row's range.
//!
//! The list holds, for each particle `i`, the particles `j ≠ i` with `r_ij < h` (strict, as the
//! paper's sums), the displacement `x_j − x_i` (minimum image on periodic axes),
//! `w_h(r_ij)` and `w_h(r_ij)/r_ij²` (`r_ij²` itself taken from the displacement,
//! [`NeighborList::r2`]).
//!
//! Candidates within `h + skin` are found with a uniform cell grid (default) or a kiddo k-d tree
//! ([`Search`]: the same candidates; a whole build 1.1-1.3x faster with the grid, `benches/core.rs`)
//! and kept while no particle has
//! moved more than `skin / 2` since they were found; in between, [`NeighborList::update`] only
//! re-measures the candidate pairs. The candidate list is also the sparsity pattern of the
//! Poisson matrix, so the pattern (and the symbolic factorisation built on it) survives as long as
//! the candidates do; [`NeighborList::epoch`] changes exactly when they are rebuilt.
//! [`NeighborList::brute_force`] is the O(N²) reference kept for tests.

/// The next candidate-list epoch: process-wide, starting at 1.
fn next_epoch() -> u64 {
    static EPOCHS: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(1);
    EPOCHS.fetch_add(1, std::sync::atomic::Ordering::Relaxed)
}

use crate::error::InputError;
use crate::kernel::{Kernel, Weight};
use crate::math::{first_where, is_finite, norm2, row_pieces, PerRow, SplitParts};
use kiddo::{ImmutableKdTree, SquaredEuclidean};
use rayon::prelude::*;

/// Periodic axes of the domain: axis `k` is periodic with period `len[k]` when `len[k] > 0`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Periodicity<const D: usize> {
    /// Lower corner of the periodic box.
    pub lo: [f64; D],
    /// Period per axis; `0` means not periodic.
    pub len: [f64; D],
}

impl<const D: usize> Default for Periodicity<D> {
    fn default() -> Self {
        Self::none()
    }
}

impl<const D: usize> Periodicity<D> {
    /// No periodic axis.
    pub fn none() -> Self {
        Periodicity {
            lo: [0.0; D],
            len: [0.0; D],
        }
    }
    /// Every axis periodic on the box `[lo, lo + len)`.
    pub fn all(lo: [f64; D], len: [f64; D]) -> Self {
        Periodicity { lo, len }
    }
    /// True when some axis is periodic.
    pub fn any(&self) -> bool {
        self.len.iter().any(|&l| l > 0.0)
    }
    /// True when `x` lies in the box on every periodic axis, `lo ≤ x < lo + len`.
    #[inline]
    fn inside(&self, x: &[f64; D]) -> bool {
        (0..D)
            .all(|k| self.len[k] == 0.0 || (x[k] >= self.lo[k] && x[k] < self.lo[k] + self.len[k]))
    }
    /// Per axis: true when the axis is periodic and `x` lies within `margin` of one of its
    /// faces (not more than `margin` inside).
    #[inline]
    fn near_faces(&self, x: &[f64; D], margin: f64) -> [bool; D] {
        std::array::from_fn(|k| {
            self.len[k] > 0.0
                && !(x[k] > self.lo[k] + margin && x[k] < self.lo[k] + self.len[k] - margin)
        })
    }
    /// Replaces a displacement by its minimum image.
    #[inline(always)]
    pub fn min_image(&self, dx: &mut [f64; D]) {
        for k in 0..D {
            if self.len[k] > 0.0 {
                dx[k] = min_image_1(dx[k], self.len[k]);
            }
        }
    }
    /// [`min_image`](Self::min_image) on the axes with `axes[k]` only.
    #[inline(always)]
    fn min_image_on(&self, dx: &mut [f64; D], axes: &[bool; D]) {
        for k in 0..D {
            if axes[k] && self.len[k] > 0.0 {
                dx[k] = min_image_1(dx[k], self.len[k]);
            }
        }
    }
    /// Maps a position into the periodic box.
    #[inline]
    pub fn wrap(&self, x: &mut [f64; D]) {
        for k in 0..D {
            let l = self.len[k];
            if l > 0.0 {
                let mut y = self.lo[k] + (x[k] - self.lo[k]).rem_euclid(l);
                if y >= self.lo[k] + l {
                    y = self.lo[k];
                }
                x[k] = y;
            }
        }
    }
}

/// The structure the candidate search uses. Both give the same candidate list (each row sorted
/// by index), so the choice changes the run time only.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Search {
    /// A uniform grid of cells of side `≥ h + skin`, the particles bucketed by a counting sort;
    /// a query scans the `3^D` cells around it. A whole list build (search and measure,
    /// `cargo bench --bench core -- neighbors`, h = 3Δx lattices, before the kept buffers of
    /// 2026-11-27): 2D 10⁴ 9.5 vs 12.2 ms, 2D 10⁵ 99 vs 127 ms, 3D 3·10⁴ 266 vs 298 ms against
    /// the k-d tree.
    #[default]
    CellGrid,
    /// kiddo's immutable k-d tree (the design's crate), queried within `h + skin`.
    KdTree,
}

/// What a neighbour list is built with.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NeighborConfig<const D: usize> {
    /// Influence radius `h` (distance units).
    pub h: f64,
    /// Skin (distance units): candidates are searched within `h + skin` and kept while every
    /// particle moves less than `skin / 2`. Zero rebuilds at every update.
    pub skin: f64,
    /// Reference weight.
    pub weight: Weight,
    /// Periodic axes.
    pub periodic: Periodicity<D>,
    /// The candidate search's structure (default: the cell grid).
    pub search: Search,
}

impl<const D: usize> NeighborConfig<D> {
    /// `h` and `skin` given in distance units.
    pub fn new(weight: Weight, h: f64, skin: f64) -> Self {
        NeighborConfig {
            h,
            skin,
            weight,
            periodic: Periodicity::none(),
            search: Search::default(),
        }
    }
    /// `h = h_over_dx · dx` and `skin = skin_over_h · h`, relative to the particle spacing `dx`.
    pub fn new_relative(weight: Weight, dx: f64, h_over_dx: f64, skin_over_h: f64) -> Self {
        let h = h_over_dx * dx;
        Self::new(weight, h, skin_over_h * h)
    }
    /// With the given search structure.
    pub fn with_search(mut self, search: Search) -> Self {
        self.search = search;
        self
    }
    /// With periodic axes.
    pub fn with_periodicity(mut self, periodic: Periodicity<D>) -> Self {
        self.periodic = periodic;
        self
    }
    /// Checks `h > 0`, `skin ≥ 0`, the weight, and periods of at least `2 (h + skin)`.
    pub fn validate(&self) -> Result<(), InputError> {
        if !(self.h > 0.0) || !self.h.is_finite() {
            return Err(InputError::Parameter {
                name: "h".into(),
                value: self.h,
                reason: "the influence radius must be positive and finite".into(),
            });
        }
        if !(self.skin >= 0.0) || !self.skin.is_finite() {
            return Err(InputError::Parameter {
                name: "skin".into(),
                value: self.skin,
                reason: "the skin must be non-negative and finite".into(),
            });
        }
        if let Err(reason) = self.weight.validate() {
            return Err(InputError::Parameter {
                name: "weight".into(),
                value: f64::NAN,
                reason,
            });
        }
        let needed = 2.0 * (self.h + self.skin);
        for k in 0..D {
            let l = self.periodic.len[k];
            if l.is_nan() || l < 0.0 || (l > 0.0 && l < needed) {
                return Err(InputError::PeriodTooShort {
                    axis: k,
                    period: l,
                    needed,
                });
            }
        }
        Ok(())
    }
}

/// What an update did.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct NeighborUpdate {
    /// True when the candidates (and so the pattern and epoch) were rebuilt.
    pub rebuilt: bool,
}

/// The flat neighbour list with cached pair data. See the module documentation.
#[derive(Clone, Debug)]
pub struct NeighborList<const D: usize> {
    config: NeighborConfig<D>,
    kernel: Kernel<D>,
    // The pair arrays are private: consumers cache values derived from them keyed on
    // `epoch`/`generation`, which only `update` (and so only this module) may change.
    // Row `i` is `offsets[i]..ends[i]`; the rows of each region of `LAYOUT_ROWS` rows follow
    // one another from `regions[c]`, the region's room ending at `regions[c + 1]` (a measure
    // then writes every row in one pass, without counting the rows before it first).
    offsets: Vec<usize>,
    ends: Vec<usize>,
    regions: Vec<usize>,
    /// Pairs stored (within h), `Σ_i |row(i)|`.
    n_pairs: usize,
    indices: Vec<u32>,
    dx: Vec<[f64; D]>,
    w: Vec<f64>,
    wr2: Vec<f64>,
    /// Per row: `Σ_j w_ij` over its pairs in order (the number density), summed by the
    /// measure as it writes the row's weights.
    w_sum: Vec<f64>,
    /// Per row: the smallest `r²` of its pairs (`∞` for none), taken by the measure.
    r2_min: Vec<f64>,
    cand_offsets: Vec<usize>,
    cand_indices: Vec<u32>,
    /// Per candidate pair: 1 when within `h` at the last measure (pass 1 to pass 2).
    cand_keep: Vec<u8>,
    /// The candidate search's per-chunk rows, kept between searches: fresh buffers of this
    /// size (100 MB in 3D at 10⁵ particles) cost more in page faults than the search itself.
    search_rows: Vec<CandidateChunk>,
    /// The search's wrapped positions and cell grid, kept between searches.
    x_wrapped: Vec<[f64; D]>,
    grid: CellGrid<D>,
    x_ref: Vec<[f64; D]>,
    epoch: u64,
    rebuilds: u64,
    generation: u64,
    /// Changes when a measure keeps a different set of pairs than the one before it (and at
    /// every search): [`Self::pair_set`].
    pair_set: u64,
    /// `cand_keep` holds the flags of the current candidates (false after a search).
    keep_current: bool,
    /// [`positions_hash`] of the positions the pair data were last measured at (0: none).
    measured_at: u64,
}

/// A 64-bit fingerprint of `x` (FNV-1a over the bits, in parallel chunks combined in order:
/// the same value on any thread count): the neighbour list records it when it measures the
/// pairs, so that a check that the list belongs to these positions costs `O(N)`, not a pass
/// over every pair ([`NeighborList::measured_at`]).
pub fn positions_hash<const D: usize>(x: &[[f64; D]]) -> u64 {
    bits_hash(x, |p| p.iter())
}

/// [`positions_hash`] of a scalar per particle (a pressure, a volume).
pub fn values_hash(v: &[f64]) -> u64 {
    bits_hash(v, std::slice::from_ref)
}

/// The hash of [`positions_hash`] over the numbers `each` gives of every item.
fn bits_hash<'a, T: Sync, I: IntoIterator<Item = &'a f64>>(
    items: &'a [T],
    each: impl Fn(&'a T) -> I + Sync,
) -> u64 {
    // FNV-1a within fixed chunks of 4 096 items, the chunk hashes weighted by powers of an
    // odd constant by their index and added (wrapping): order-sensitive, the same for any
    // thread count, and no buffer of chunk hashes (a moving step allocates nothing)
    const PRIME: u64 = 0x100000001b3;
    const BASE: u64 = 0x9e3779b97f4a7c15;
    let fnv = |h: u64, v: u64| (h ^ v).wrapping_mul(PRIME);
    let sum = items
        .par_chunks(4096)
        .enumerate()
        .map(|(c, ch)| {
            let h = ch
                .iter()
                .flat_map(&each)
                .fold(0xcbf29ce484222325, |h, v| fnv(h, v.to_bits()));
            h.wrapping_mul(BASE.wrapping_pow(c as u32 + 1))
        })
        .reduce(|| 0, u64::wrapping_add);
    fnv(fnv(0xcbf29ce484222325, items.len() as u64), sum)
}

impl<const D: usize> NeighborList<D> {
    /// An empty list; call [`update`](Self::update) to fill it.
    pub fn new(config: NeighborConfig<D>) -> Result<Self, InputError> {
        config.validate()?;
        Ok(NeighborList {
            kernel: Kernel::new(config.weight, config.h),
            config,
            offsets: Vec::new(),
            ends: Vec::new(),
            regions: Vec::new(),
            n_pairs: 0,
            indices: Vec::new(),
            dx: Vec::new(),
            w: Vec::new(),
            wr2: Vec::new(),
            w_sum: Vec::new(),
            r2_min: Vec::new(),
            cand_offsets: vec![0],
            cand_indices: Vec::new(),
            cand_keep: Vec::new(),
            search_rows: Vec::new(),
            x_wrapped: Vec::new(),
            grid: CellGrid::default(),
            x_ref: Vec::new(),
            epoch: 0,
            rebuilds: 0,
            generation: 0,
            pair_set: 0,
            keep_current: false,
            measured_at: 0,
        })
    }

    /// Builds a list for `x` in one call (search + measurement).
    pub fn build(config: NeighborConfig<D>, x: &[[f64; D]]) -> Result<Self, InputError> {
        let mut nl = Self::new(config)?;
        nl.update(x)?;
        Ok(nl)
    }

    /// The reference implementation: every pair tested, O(N²). Pairs at exactly `h` are excluded.
    pub fn brute_force(config: NeighborConfig<D>, x: &[[f64; D]]) -> Result<Self, InputError> {
        let mut nl = Self::new(config)?;
        check_finite(x)?;
        let h2 = config.h * config.h;
        let mut offsets = vec![0usize];
        let mut indices = Vec::new();
        for i in 0..x.len() {
            for j in 0..x.len() {
                if j == i {
                    continue;
                }
                let mut d: [f64; D] = std::array::from_fn(|k| x[j][k] - x[i][k]);
                config.periodic.min_image(&mut d);
                if norm2(&d) < h2 {
                    indices.push(j as u32);
                }
            }
            offsets.push(indices.len());
        }
        nl.cand_offsets = offsets;
        nl.cand_indices = indices;
        nl.x_ref = x.to_vec();
        nl.epoch = next_epoch();
        nl.rebuilds = 1;
        nl.measure(x)?;
        Ok(nl)
    }

    /// The configuration.
    pub fn config(&self) -> &NeighborConfig<D> {
        &self.config
    }
    /// The kernel `w_h`.
    pub fn kernel(&self) -> &Kernel<D> {
        &self.kernel
    }
    /// The positions at the last candidate search (each within `skin / 2` of the positions
    /// the list was last measured at; empty before the first search).
    pub fn search_positions(&self) -> &[[f64; D]] {
        &self.x_ref
    }
    /// Influence radius.
    pub fn h(&self) -> f64 {
        self.config.h
    }
    /// Number of particles (rows).
    pub fn len(&self) -> usize {
        self.ends.len()
    }
    /// True when there are no rows.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
    /// Number of stored pairs (each unordered pair is stored twice).
    pub fn n_pairs(&self) -> usize {
        self.n_pairs
    }
    /// Per row, `Σ_j w_h(r_ij)` over its pairs (the number density; with pair factors, of the
    /// scaled weights): summed in the measure's pass over the pairs, equal to summing
    /// [`Self::w`] over [`Self::row`] in order.
    pub fn w_sums(&self) -> &[f64] {
        &self.w_sum
    }
    /// Per row, the smallest `r²` of its pairs (`∞` for a row without pairs), taken by the
    /// measure.
    pub fn r2_mins(&self) -> &[f64] {
        &self.r2_min
    }
    /// The rows' offsets in an array of one value per pair in row order (row 0's pairs, then
    /// row 1's, …, `n_pairs()` in all): row `i` is `pair_offsets()[i]..pair_offsets()[i + 1]`
    /// there. (The list's own pair arrays leave room between regions of rows: index them
    /// through [`row`](Self::row).)
    pub fn pair_offsets(&self) -> Vec<usize> {
        let mut o = Vec::with_capacity(self.len() + 1);
        o.push(0);
        for i in 0..self.len() {
            o.push(o[i] + self.row(i).len());
        }
        o
    }
    /// Neighbour index `j` of each pair (ascending within a row).
    #[inline(always)]
    pub fn indices(&self) -> &[u32] {
        &self.indices
    }
    /// `x_j − x_i` of each pair (minimum image).
    #[inline(always)]
    pub fn dx(&self) -> &[[f64; D]] {
        &self.dx
    }
    /// `r_ij²` of pair `k`: `|dx|²`, the bits the measure compared with `h²` (the list keeps
    /// no array of them: one less array to write every moving step).
    #[inline(always)]
    pub fn r2(&self, k: usize) -> f64 {
        norm2(&self.dx[k])
    }
    /// `w_h(r_ij)` of each pair.
    #[inline(always)]
    pub fn w(&self) -> &[f64] {
        &self.w
    }
    /// `w_h(r_ij) / r_ij²` of each pair: the factor every operator multiplies by.
    #[inline(always)]
    pub fn wr2(&self) -> &[f64] {
        &self.wr2
    }
    /// The neighbour `j` of pair `k` (an index into the pair arrays, from [`row`](Self::row)).
    #[inline(always)]
    pub fn neighbor(&self, k: usize) -> usize {
        self.indices[k] as usize
    }
    /// Row `i`'s pair range: the indices of its pairs in [`indices`](Self::indices),
    /// [`dx`](Self::dx), [`w`](Self::w), … (rows are stored in order, with room left between
    /// regions of rows; nothing outside the rows is a pair).
    #[inline(always)]
    pub fn row(&self, i: usize) -> std::ops::Range<usize> {
        self.offsets[i]..self.ends[i]
    }
    /// Changes exactly when the candidate list (the sparsity pattern) is rebuilt; unique in the
    /// process (never 0 once built), so that caches keyed on it (the Poisson pattern, the
    /// least-squares coefficients) cannot mistake one list for another.
    pub fn epoch(&self) -> u64 {
        self.epoch
    }
    /// [`positions_hash`] of the positions the pair data were measured at (0 before the first
    /// measurement).
    pub fn measured_at(&self) -> u64 {
        self.measured_at
    }
    /// Changes whenever the pair data (`dx`, `w`, `wr2`) are re-measured, i.e. whenever
    /// positions may have changed: consumers that derive values from the pair data (matrix
    /// values, connectivity) can skip the work while it is unchanged.
    pub fn generation(&self) -> u64 {
        self.generation
    }
    /// Changes whenever the set of pairs within `h` changes — at a search, or when a measure
    /// keeps other candidates than the measure before it — but not when the same pairs are
    /// only re-measured at moved positions: a within-h matrix pattern keyed on it
    /// (with [`Self::epoch`]) holds while the pair set does. Costs a byte compare per candidate
    /// in the measure's first pass.
    pub fn pair_set(&self) -> u64 {
        self.pair_set
    }
    /// How many times the candidates were searched.
    pub fn rebuilds(&self) -> u64 {
        self.rebuilds
    }
    /// Candidate pattern (pairs within `h + skin` at the last rebuild): offsets and indices.
    pub fn pattern(&self) -> (&[usize], &[u32]) {
        (&self.cand_offsets, &self.cand_indices)
    }

    /// Multiplies the stored `w_h(r_ij)` and `w_h(r_ij)/r_ij²` of every pair by its factor,
    /// `factors` one per pair in row order ([`pair_offsets`](Self::pair_offsets)):
    /// `F̃_ij = F_ij · f_ij` with `F = w_h/r²` (the pair weight every operator
    /// uses), and `w̃ = F̃ r²`. The factors must be positive, finite and symmetric
    /// (`f_ij = f_ji`, relative difference at most 10⁻⁹), so that the operators stay adjoint and
    /// the Poisson matrix symmetric. Bumps [`generation`](Self::generation), so every cache
    /// of values derived from the pair data refreshes. The next [`update`](Self::update)
    /// re-measures plain weights. Used by [`crate::pair_weights`].
    pub fn scale_pair_weights(&mut self, factors: &[f64]) -> Result<(), InputError> {
        if factors.len() != self.n_pairs {
            return Err(InputError::LengthMismatch {
                field: "pair factors",
                len: factors.len(),
                expected: self.n_pairs,
            });
        }
        let at = self.pair_offsets();
        for i in 0..self.len() {
            for (e, k) in self.row(i).enumerate() {
                let f = factors[at[i] + e];
                if !(f > 0.0 && f.is_finite()) {
                    return Err(InputError::parameter(
                        "pair factor",
                        f,
                        format!(
                            "pair ({i}, {}): must be positive and finite",
                            self.indices[k]
                        ),
                    ));
                }
                let j = self.indices[k] as usize;
                let rj = self.row(j);
                let back = self.indices[rj.clone()]
                    .binary_search(&(i as u32))
                    .map(|p| factors[at[j] + p]);
                let ok = back.is_ok_and(|b| (b - f).abs() <= 1e-9 * f.max(b));
                if !ok {
                    return Err(InputError::parameter(
                        "pair factor",
                        f,
                        format!("pair ({i}, {j}): the factors are not symmetric ({back:?})"),
                    ));
                }
            }
        }
        for i in 0..self.len() {
            for (k, f) in self.row(i).zip(&factors[at[i]..at[i + 1]]) {
                self.w[k] *= f;
                self.wr2[k] *= f;
            }
        }
        for i in 0..self.len() {
            self.w_sum[i] = self.w[self.row(i)].iter().sum();
        }
        self.generation += 1;
        Ok(())
    }

    /// Forgets the candidates so that the next update searches again.
    pub fn invalidate(&mut self) {
        self.x_ref.clear();
    }

    /// True when the candidates no longer cover every pair within `h` of `x`.
    pub fn needs_rebuild(&self, x: &[[f64; D]]) -> bool {
        if self.x_ref.len() != x.len() || self.epoch == 0 {
            return true;
        }
        let lim2 = 0.25 * self.config.skin * self.config.skin;
        let per = self.config.periodic;
        let x_ref = &self.x_ref;
        first_where(x.len(), |i| {
            let mut d: [f64; D] = std::array::from_fn(|k| x[i][k] - x_ref[i][k]);
            per.min_image(&mut d);
            !(norm2(&d) < lim2) // also true for NaN
        })
        .is_some()
    }

    /// Brings the list up to date with positions `x`: searches again only when needed, then
    /// re-measures every candidate pair. Fails on non-finite positions and coincident particles.
    pub fn update(&mut self, x: &[[f64; D]]) -> Result<NeighborUpdate, InputError> {
        check_finite(x)?;
        let rebuilt = self.needs_rebuild(x);
        if rebuilt {
            self.search(x)?;
        }
        self.measure(x)?;
        Ok(NeighborUpdate { rebuilt })
    }

    /// Candidate search with kiddo within `h + skin`.
    fn search(&mut self, x: &[[f64; D]]) -> Result<(), InputError> {
        let n = x.len();
        let per = self.config.periodic;
        // a relative 10⁻⁹ wider than `h + skin`: the candidates are then a superset of the
        // pairs the measure keeps (`r² < h²` by the minimum image, the same from both ends)
        // even where the search's own arithmetic (wrapped positions, image shifts) rounds a
        // pair at exactly `h + skin` — a lattice with `h` a whole number of spacings across a
        // periodic face — the other way; otherwise such a pair could be found from one end only
        let radius = (self.config.h + self.config.skin) * (1.0 + 1e-9);
        let r2 = radius * radius;
        let mut wrapped = std::mem::take(&mut self.x_wrapped);
        wrapped.resize(n, [0.0; D]);
        wrapped.par_iter_mut().zip(x.par_iter()).for_each(|(q, p)| {
            *q = *p;
            per.wrap(q);
        });
        let xw = &wrapped[..];
        let mut rows = std::mem::take(&mut self.search_rows);
        if n > 0 {
            match self.config.search {
                Search::KdTree => {
                    let tree: ImmutableKdTree<f64, D> = ImmutableKdTree::new_from_slice(xw)
                        .map_err(|e| InputError::Parameter {
                            name: "positions".into(),
                            value: n as f64,
                            reason: format!("k-d tree construction failed: {e:?}"),
                        })?;
                    let init = || tree.create_scratch::<SquaredEuclidean<f64>>();
                    candidate_rows(n, &mut rows, init, |scratch, i, row| {
                        for_image_shifts(&xw[i], &per, radius, |shift| {
                            let q: [f64; D] = std::array::from_fn(|k| xw[i][k] + shift[k]);
                            tree.query(&q)
                                .within::<SquaredEuclidean<f64>>(r2)
                                .unsorted()
                                .with_scratch(scratch)
                                .visit(|nb| row.push(nb.item));
                        });
                    })
                }
                Search::CellGrid => {
                    let grid = &mut self.grid;
                    grid.rebuild(xw, radius);
                    let grid = &*grid;
                    candidate_rows(
                        n,
                        &mut rows,
                        || (),
                        |_, i, row| {
                            for_image_shifts(&xw[i], &per, radius, |shift| {
                                let q: [f64; D] = std::array::from_fn(|k| xw[i][k] + shift[k]);
                                grid.within(&q, r2, |j| row.push(j));
                            });
                        },
                    )
                }
            };
        } else {
            rows.clear();
        }
        self.x_wrapped = wrapped;
        // the rows' offsets, then their indices copied in parallel into the kept buffer
        let mut offsets = std::mem::take(&mut self.cand_offsets);
        offsets.clear();
        offsets.reserve(n + 1);
        offsets.push(0usize);
        for (counts, _, _, _) in &rows {
            for &c in counts {
                offsets.push(offsets.last().unwrap() + c as usize);
            }
        }
        let mut indices = std::mem::take(&mut self.cand_indices);
        indices.resize(*offsets.last().unwrap(), 0);
        // (split by chunks of rows without a vector of pieces)
        let first = |c: usize| offsets[(c * SEARCH_CHUNK).min(n)];
        row_pieces(rows.len(), 1, first, &mut indices[..]).for_each(|(chunks, dst)| {
            let base = first(chunks.start);
            for c in chunks {
                let (at, idx) = (first(c) - base, &rows[c].1);
                dst[at..at + idx.len()].copy_from_slice(idx);
            }
        });
        self.search_rows = rows;
        self.cand_offsets = offsets;
        self.cand_indices = indices;
        self.x_ref.clear();
        self.x_ref.extend_from_slice(x);
        self.epoch = next_epoch();
        self.rebuilds += 1;
        self.keep_current = false;
        Ok(())
    }

    /// Re-measures the candidate pairs at positions `x` and keeps those with `r < h`.
    ///
    /// One pass over the candidates when the pairs fit the regions' room (a region holds the
    /// pairs it had when laid out, a sixteenth and 64 more): each row's pairs are written where
    /// the row before it ended. When they do not (the first measure, another particle count, a
    /// region that gained more pairs than its room), a first pass counts each row's pairs and
    /// the regions are laid out again before the pass that writes them. Writing in one pass
    /// saves the counting pass a contiguous list needs (2D 10⁵, moving: 4.3 + 8.5 ms → 9.3 ms).
    fn measure(&mut self, x: &[[f64; D]]) -> Result<(), InputError> {
        self.generation += 1;
        self.measured_at = 0;
        let n = x.len();
        let per = self.config.periodic;
        // A row skips the minimum image on each periodic axis whose faces its particle lies
        // farther from than any candidate can be from it (without the minimum image a 3D
        // measure takes a quarter less time): every candidate was within `h + skin` at the
        // search and each particle has moved less than `skin / 2` since, so with all positions
        // in the box the plain difference along such an axis is the minimum image
        // (`|d_k| < len_k / 2`: `min_image` would return it unchanged — the same bits)
        let reach = ((self.config.h + self.config.skin) * (1.0 + 1e-9) + self.config.skin) * 1.001;
        let geo = Geometry {
            x,
            per,
            reach,
            wrapped: !per.any() || first_where(n, |i| !per.inside(&x[i])).is_none(),
            h2: self.config.h * self.config.h,
            co: &self.cand_offsets,
            ci: &self.cand_indices,
            kernel: self.kernel,
        };
        // each flag is compared as it is overwritten: with the last measure's flags of these
        // candidates, whether the kept pairs change
        let mut keep = std::mem::take(&mut self.cand_keep);
        let same_candidates = self.keep_current && keep.len() == geo.ci.len();
        keep.resize(geo.ci.len(), 0);
        let n_regions = n.div_ceil(LAYOUT_ROWS);
        self.offsets.resize(n, 0);
        self.ends.resize(n, 0);
        self.w_sum.resize(n, 0.0);
        self.r2_min.resize(n, 0.0);
        // (the fields borrowed one by one: `geo` holds the candidates)
        macro_rules! pair_arrays {
            () => {
                PairArrays {
                    idx: &mut self.indices,
                    dx: &mut self.dx,
                    w: &mut self.w,
                    wr2: &mut self.wr2,
                    starts: &mut self.offsets,
                    ends: &mut self.ends,
                    w_sum: &mut self.w_sum,
                    r2_min: &mut self.r2_min,
                }
            };
        }
        let laid_out =
            self.regions.len() == n_regions + 1 && self.regions.last() == Some(&self.indices.len());
        let mut flipped = false;
        let mut filled = None;
        if laid_out {
            let f = fill_regions(&geo, &self.regions, &mut keep, pair_arrays!());
            flipped |= f.flipped;
            filled = (!f.overflow).then_some(f);
        }
        let filled = match filled {
            Some(f) => f,
            None => {
                // count each row's pairs (into `ends`), lay the regions out, then fill
                flipped |= count_rows(&geo, &mut keep, &mut self.ends);
                let rows = |c: usize| (c * LAYOUT_ROWS).min(n);
                self.regions.clear();
                self.regions.push(0);
                for c in 0..n_regions {
                    let pairs: usize = self.ends[rows(c)..rows(c + 1)].iter().sum();
                    self.regions.push(self.regions[c] + pairs + pairs / 16 + 64);
                }
                let room = self.regions[n_regions];
                self.indices.resize(room, 0);
                self.dx.resize(room, [0.0; D]);
                self.w.resize(room, 0.0);
                self.wr2.resize(room, 0.0);
                let f = fill_regions(&geo, &self.regions, &mut keep, pair_arrays!());
                debug_assert!(!f.overflow, "regions laid out for their counts");
                flipped |= f.flipped;
                f
            }
        };
        if flipped || !same_candidates {
            self.pair_set += 1;
        }
        self.keep_current = true;
        self.cand_keep = keep;
        self.n_pairs = filled.pairs;
        if let Some((i, j)) = filled.coincident {
            return Err(InputError::Coincident {
                i,
                j,
                distance: 0.0,
            });
        }
        self.measured_at = positions_hash(x);
        Ok(())
    }
}

/// Rows per region of the pair arrays ([`NeighborList::measure`]).
const LAYOUT_ROWS: usize = 512;

/// What a measure reads: the positions, the candidates, and how a row's displacements are
/// taken.
struct Geometry<'a, const D: usize> {
    x: &'a [[f64; D]],
    per: Periodicity<D>,
    reach: f64,
    /// All positions inside the periodic box (or no periodic axis).
    wrapped: bool,
    h2: f64,
    co: &'a [usize],
    ci: &'a [u32],
    kernel: Kernel<D>,
}

impl<const D: usize> Geometry<'_, D> {
    /// Which axes of row `i` need the minimum image (all when some position is outside).
    #[inline(always)]
    fn near(&self, i: usize) -> [bool; D] {
        if self.wrapped {
            self.per.near_faces(&self.x[i], self.reach)
        } else {
            std::array::from_fn(|k| self.per.len[k] > 0.0)
        }
    }
}

/// Evaluates `$body` with `$disp` bound to row `$i`'s displacement `x_j − x_i` as a closure of
/// `j` (a [`Geometry`] `$g`): the plain difference when no axis needs the minimum image. Each
/// branch has its own closure type, so that the row's loop is compiled for each, the
/// displacement inlined (not called through a pointer).
macro_rules! with_disp {
    ($g:expr, $i:expr, |$disp:ident| $body:expr) => {{
        let (g, i) = ($g, $i);
        let x = g.x;
        let axes = g.near(i);
        if axes == [false; D] {
            let $disp = |j: usize| -> [f64; D] { std::array::from_fn(|k| x[j][k] - x[i][k]) };
            $body
        } else {
            let $disp = |j: usize| -> [f64; D] {
                let mut d: [f64; D] = std::array::from_fn(|k| x[j][k] - x[i][k]);
                g.per.min_image_on(&mut d, &axes);
                d
            };
            $body
        }
    }};
}

/// The pair arrays (per pair) and per-row outputs a measure writes.
struct PairArrays<'a, const D: usize> {
    idx: &'a mut [u32],
    dx: &'a mut [[f64; D]],
    w: &'a mut [f64],
    wr2: &'a mut [f64],
    starts: &'a mut [usize],
    ends: &'a mut [usize],
    w_sum: &'a mut [f64],
    r2_min: &'a mut [f64],
}

/// What [`fill_regions`] found.
#[derive(Clone, Copy, Default)]
struct Filled {
    pairs: usize,
    flipped: bool,
    overflow: bool,
    coincident: Option<(usize, usize)>,
}

impl Filled {
    fn join(self, b: Filled) -> Filled {
        Filled {
            pairs: self.pairs + b.pairs,
            flipped: self.flipped || b.flipped,
            overflow: self.overflow || b.overflow,
            coincident: self.coincident.or(b.coincident),
        }
    }
}

/// A slice cut where regions begin: `at(c)` is region `c`'s first element in the whole
/// slice, `first` the region the piece begins with ([`SplitParts`] counts regions as rows).
struct ByRegion<'a, T, F> {
    s: &'a mut [T],
    first: usize,
    at: &'a F,
}

impl<'a, T, F> ByRegion<'a, T, F> {
    fn new(s: &'a mut [T], at: &'a F) -> Self {
        ByRegion { s, first: 0, at }
    }
}

impl<T: Send, F: Fn(usize) -> usize + Sync> SplitParts for ByRegion<'_, T, F> {
    fn split_parts(self, regions: usize, _entries: usize) -> (Self, Self) {
        let (first, at) = (self.first, self.at);
        let (a, b) = self.s.split_at_mut(at(first + regions) - at(first));
        (
            ByRegion { s: a, first, at },
            ByRegion {
                s: b,
                first: first + regions,
                at,
            },
        )
    }
}

/// The one pass of a measure: every candidate of every row measured, its flag set (and
/// compared with the one it replaces), each row's pairs within `h` written after the row
/// before it in its region, with their weights, `Σw` and smallest `r²`. A region whose pairs
/// outgrow its room is reported (`overflow`; its flags are still set), its rows left unusable.
fn fill_regions<const D: usize>(
    g: &Geometry<'_, D>,
    regions: &[usize],
    keep: &mut [u8],
    out: PairArrays<'_, D>,
) -> Filled {
    let n = g.x.len();
    let n_regions = regions.len() - 1;
    let rows = |c: usize| (c * LAYOUT_ROWS).min(n);
    let cands = |c: usize| g.co[rows(c)];
    let room = |c: usize| regions[c];
    let parts = (
        (
            (ByRegion::new(out.idx, &room), ByRegion::new(out.dx, &room)),
            (ByRegion::new(out.w, &room), ByRegion::new(out.wr2, &room)),
        ),
        (
            ByRegion::new(keep, &cands),
            (
                (
                    ByRegion::new(out.starts, &rows),
                    ByRegion::new(out.ends, &rows),
                ),
                (
                    ByRegion::new(out.w_sum, &rows),
                    ByRegion::new(out.r2_min, &rows),
                ),
            ),
        ),
    );
    row_pieces(n_regions, 1, room, parts)
        .map(|(span, parts)| {
            let (((idx, dx), (w, wr2)), (flags, ((starts, ends), (w_sum, r2_min)))) = parts;
            let (row0, cand0, at0) = (rows(span.start), cands(span.start), room(span.start));
            let mut acc = Filled::default();
            for c in span {
                let (mut k, end) = (room(c) - at0, room(c + 1) - at0);
                for i in rows(c)..rows(c + 1) {
                    let r = i - row0;
                    let (lo, hi) = (g.co[i], g.co[i + 1]);
                    let (m, flip, zero, rmin) = with_disp!(g, i, |disp| {
                        measure_row(
                            &g.ci[lo..hi],
                            &mut flags.s[lo - cand0..hi - cand0],
                            g.h2,
                            &mut idx.s[k..end],
                            &mut dx.s[k..end],
                            &mut w.s[k..end],
                            disp,
                        )
                    });
                    acc.flipped |= flip;
                    if let (Some(j), None) = (zero, acc.coincident) {
                        acc.coincident = Some((i, j));
                    }
                    starts.s[r] = at0 + k;
                    if k + m > end {
                        acc.overflow = true;
                        k = end;
                        ends.s[r] = at0 + k;
                        continue;
                    }
                    g.kernel
                        .w_and_wr2_in_place(&mut w.s[k..k + m], &mut wr2.s[k..k + m]);
                    w_sum.s[r] = w.s[k..k + m].iter().sum();
                    r2_min.s[r] = rmin;
                    k += m;
                    ends.s[r] = at0 + k;
                    acc.pairs += m;
                }
            }
            acc
        })
        .reduce(Filled::default, Filled::join)
}

/// The counting pass of a measure that lays the regions out again: each row's pairs within
/// `h` into `counts`, the flags set; whether any flag changed.
fn count_rows<const D: usize>(g: &Geometry<'_, D>, keep: &mut [u8], counts: &mut [usize]) -> bool {
    const RCHUNK: usize = 512;
    let co = g.co;
    row_pieces(
        g.x.len(),
        RCHUNK,
        |i| co[i],
        (&mut keep[..], PerRow(&mut counts[..])),
    )
    .map(|(rows, (flags, PerRow(counts)))| {
        let base = co[rows.start];
        let mut flipped = false;
        for (i, count) in rows.zip(counts.iter_mut()) {
            let fl = &mut flags[co[i] - base..co[i + 1] - base];
            // (the one pass's row with no room: counted and flagged, nothing written)
            let (c, f, _, _) = with_disp!(g, i, |disp| {
                measure_row(
                    &g.ci[co[i]..co[i + 1]],
                    fl,
                    g.h2,
                    &mut [],
                    &mut [],
                    &mut [],
                    disp,
                )
            });
            *count = c;
            flipped |= f;
        }
        flipped
    })
    .reduce(|| false, |a, b| a || b)
}

/// The pass of a measure for one row: every candidate measured and flagged (`|d|² < h2`,
/// `d = disp(j)`), those within `h` written in order — index, displacement, and the squared
/// distance into `r2o` (the weights' slots, for the kernel to replace) — while the room
/// `idx.len()` lasts. Returns how many are within `h` (more than the room: not all written),
/// whether any flag changed, the first at zero distance, and the smallest squared distance.
#[inline(always)]
fn measure_row<const D: usize>(
    cands: &[u32],
    flags: &mut [u8],
    h2: f64,
    idx: &mut [u32],
    dxo: &mut [[f64; D]],
    r2o: &mut [f64],
    disp: impl Fn(usize) -> [f64; D],
) -> (usize, bool, Option<usize>, f64) {
    let (mut k, mut flipped, mut zero, mut rmin) = (0, 0u8, None, f64::INFINITY);
    let room = idx.len();
    for (&j, f) in cands.iter().zip(flags) {
        let d = disp(j as usize);
        let rr = norm2(&d);
        let inside = (rr < h2) as u8;
        flipped |= *f ^ inside;
        *f = inside;
        if inside != 0 {
            if !(rr > 0.0) && zero.is_none() {
                zero = Some(j as usize);
            }
            if k < room {
                idx[k] = j;
                dxo[k] = d;
                r2o[k] = rr;
            }
            rmin = rmin.min(rr);
            k += 1;
        }
    }
    (k, flipped != 0, zero, rmin)
}

/// The minimum image of the offset `v` along an axis of period `l > 0`: one correction covers
/// `|v| ≤ 1.5 l` (positions within a period of each other); `round` (a libm call here) only
/// for the rare larger offsets.
#[inline(always)]
fn min_image_1(v: f64, l: f64) -> f64 {
    if v > 0.5 * l {
        if v <= 1.5 * l {
            v - l
        } else {
            v - l * (v / l).round()
        }
    } else if v < -0.5 * l {
        if v >= -1.5 * l {
            v + l
        } else {
            v - l * (v / l).round()
        }
    } else {
        v
    }
}

/// The closest pair of particles, `(r, i, j)` with `i < j` (minimum image on periodic axes):
/// `None` with fewer than two particles or a non-finite position. Found by neighbour searches
/// of doubling radius from the mean spacing (the smallest pair of the first non-empty search is
/// the closest overall), so it costs a few searches, not `O(N²)`; used to name the spacing when
/// `h` is too small for any particle to have a neighbour.
pub fn closest_pair<const D: usize>(
    x: &[[f64; D]],
    periodic: &Periodicity<D>,
) -> Option<(f64, usize, usize)> {
    if x.len() < 2 || check_finite(x).is_err() {
        return None;
    }
    let (lo, hi) = bounding_box(x);
    let extent = (0..D).map(|k| hi[k] - lo[k]).fold(0.0, f64::max);
    let mut radius = (extent / (x.len() as f64).powf(1.0 / D as f64)).max(f64::MIN_POSITIVE);
    while radius.is_finite() {
        let config =
            NeighborConfig::new(Weight::WendlandC2, radius, 0.0).with_periodicity(*periodic);
        if config.validate().is_err() {
            break; // the radius outgrew a period: few particles, check every pair
        }
        match NeighborList::build(config, x) {
            Err(InputError::Coincident { i, j, .. }) => return Some((0.0, i.min(j), i.max(j))),
            Err(_) => return None,
            Ok(nl) if nl.n_pairs() > 0 => {
                let (mut best, mut pair) = (f64::INFINITY, (0, 0));
                for i in 0..nl.len() {
                    for k in nl.row(i) {
                        let j = nl.indices[k] as usize;
                        if nl.r2(k) < best {
                            best = nl.r2(k);
                            pair = (i.min(j), i.max(j));
                        }
                    }
                }
                return Some((best.sqrt(), pair.0, pair.1));
            }
            Ok(_) => radius *= 2.0,
        }
    }
    let mut best = (f64::INFINITY, 0, 1);
    for i in 0..x.len() {
        for j in i + 1..x.len() {
            let mut d: [f64; D] = std::array::from_fn(|k| x[j][k] - x[i][k]);
            periodic.min_image(&mut d);
            let r = norm2(&d).sqrt();
            if r < best.0 {
                best = (r, i, j);
            }
        }
    }
    Some(best)
}

fn check_finite<const D: usize>(x: &[[f64; D]]) -> Result<(), InputError> {
    if let Some(i) = first_where(x.len(), |i| !is_finite(&x[i])) {
        return Err(InputError::NonFinite {
            field: "position",
            particle: i,
        });
    }
    Ok(())
}

/// Calls `visit` with each periodic image shift under which a ball of `radius` around `x`
/// (already wrapped) can reach across the box: the zero shift, and `±len` on axes where `x` is
/// within `radius` of a face, in every combination.
fn for_image_shifts<const D: usize>(
    x: &[f64; D],
    per: &Periodicity<D>,
    radius: f64,
    mut visit: impl FnMut(&[f64; D]),
) {
    // per axis: no shift, and a period up or down when `x` lies within `radius` of a face
    let mut opts = [[0.0f64; 3]; D];
    let mut count = [1usize; D];
    for k in 0..D {
        let l = per.len[k];
        if l <= 0.0 {
            continue;
        }
        if x[k] - per.lo[k] < radius {
            opts[k][count[k]] = l;
            count[k] += 1;
        }
        if per.lo[k] + l - x[k] < radius {
            opts[k][count[k]] = -l;
            count[k] += 1;
        }
    }
    // every combination, by an odometer (no allocation: called once per particle and search)
    let mut c = [0usize; D];
    loop {
        visit(&std::array::from_fn(|k| opts[k][c[k]]));
        let mut k = 0;
        loop {
            if k == D {
                return;
            }
            c[k] += 1;
            if c[k] < count[k] {
                break;
            }
            c[k] = 0;
            k += 1;
        }
    }
}

/// A chunk of the candidate search's rows: their lengths, their indices, the row being
/// gathered and the bitmap that sorts it.
type CandidateChunk = (Vec<u32>, Vec<u32>, Vec<u32>, Vec<u64>);

/// Particles per chunk of the candidate search's rows.
const SEARCH_CHUNK: usize = 1024;

/// The candidate rows of particles `0..n`, in parallel chunks of `rows` (one per 1024
/// particles, buffers reused): `query(scratch, i, row)` pushes the candidates of `i` (with
/// repeats and `i` itself allowed), which are then sorted, deduplicated and stripped of `i`;
/// `scratch` is made once per chunk by `init` ([`CandidateChunk`]).
fn candidate_rows<S, I, Q>(n: usize, rows: &mut Vec<CandidateChunk>, init: I, query: Q)
where
    I: Fn() -> S + Sync,
    Q: Fn(&mut S, usize, &mut Vec<u32>) + Sync,
{
    const CHUNK: usize = SEARCH_CHUNK;
    rows.resize_with(n.div_ceil(CHUNK), Default::default);
    rows.par_iter_mut()
        .enumerate()
        .for_each(|(c, (counts, idx, row, bits))| {
            let (start, end) = (c * CHUNK, ((c + 1) * CHUNK).min(n));
            counts.clear();
            idx.clear();
            let mut scratch = init();
            for i in start..end {
                row.clear();
                query(&mut scratch, i, row);
                sort_row(row, bits, i as u32);
                counts.push(row.len() as u32);
                idx.extend_from_slice(row);
            }
        });
}

/// Sorts a candidate row, drops repeats and `own`. When the row's indices span at most 8
/// 64-bit words per candidate (particles numbered in a spatial order, as a lattice's rows are)
/// they are set as bits of a bitmap and read back in order — `O(len + span/64)` against the
/// `O(len log len)` of a sort, which took a quarter of a 2D search; otherwise sorted.
fn sort_row(row: &mut Vec<u32>, bits: &mut Vec<u64>, own: u32) {
    if row.is_empty() {
        return;
    }
    let (lo, hi) = row
        .iter()
        .fold((u32::MAX, 0), |(lo, hi), &j| (lo.min(j), hi.max(j)));
    let words = ((hi - lo) / 64) as usize + 1;
    if words > 8 * row.len() {
        row.sort_unstable();
        row.dedup();
        row.retain(|&j| j != own);
        return;
    }
    bits.clear();
    bits.resize(words, 0);
    for &j in row.iter() {
        let o = j - lo;
        bits[(o / 64) as usize] |= 1u64 << (o % 64);
    }
    if (lo..=hi).contains(&own) {
        let o = own - lo;
        bits[(o / 64) as usize] &= !(1u64 << (o % 64));
    }
    row.clear();
    for (w, &b) in bits.iter().enumerate() {
        let mut b = b;
        while b != 0 {
            row.push(lo + 64 * w as u32 + b.trailing_zeros());
            b &= b - 1;
        }
    }
}

/// The smallest and largest coordinate of `x` per axis (`±∞` for no points).
fn bounding_box<const D: usize>(x: &[[f64; D]]) -> ([f64; D], [f64; D]) {
    let mut lo = [f64::INFINITY; D];
    let mut hi = [f64::NEG_INFINITY; D];
    for p in x {
        for k in 0..D {
            lo[k] = lo[k].min(p[k]);
            hi[k] = hi[k].max(p[k]);
        }
    }
    (lo, hi)
}

/// A uniform grid over the bounding box of a point set, the points bucketed by cell (counting
/// sort): `start[c]..start[c + 1]` of `items` are the points of cell `c`, and of `pos` their
/// positions (copied in cell order, so that a query streams through them).
#[derive(Clone, Debug)]
struct CellGrid<const D: usize> {
    lo: [f64; D],
    inv: f64,
    dims: [usize; D],
    start: Vec<u32>,
    items: Vec<u32>,
    pos: Vec<[f64; D]>,
    /// Scratch of the counting sort: each point's cell, then the cells' fill positions.
    cell: Vec<u32>,
    fill: Vec<u32>,
}

impl<const D: usize> Default for CellGrid<D> {
    fn default() -> Self {
        CellGrid {
            lo: [0.0; D],
            inv: 0.0,
            dims: [0; D],
            start: Vec::new(),
            items: Vec::new(),
            pos: Vec::new(),
            cell: Vec::new(),
            fill: Vec::new(),
        }
    }
}

impl<const D: usize> CellGrid<D> {
    /// Cells of side at least `radius` (larger when the box would need more than ~4 cells per
    /// point: a few far-away points must not blow the grid up).
    fn rebuild(&mut self, x: &[[f64; D]], radius: f64) {
        let (lo, hi) = bounding_box(x);
        let mut side = radius;
        let cells = |side: f64| -> ([usize; D], f64) {
            let dims: [usize; D] =
                std::array::from_fn(|k| ((hi[k] - lo[k]) / side).floor().min(1e9) as usize + 1);
            (dims, dims.iter().map(|&d| d as f64).product())
        };
        let limit = 4.0 * x.len() as f64 + 64.0;
        let mut dims = cells(side).0;
        while cells(side).1 > limit {
            side *= 2.0;
            dims = cells(side).0;
        }
        let inv = 1.0 / side;
        let total: usize = dims.iter().product();
        let cell_of = |p: &[f64; D]| -> usize {
            let mut c = 0;
            for k in (0..D).rev() {
                let i = (((p[k] - lo[k]) * inv) as usize).min(dims[k] - 1);
                c = c * dims[k] + i;
            }
            c
        };
        // (every vector overwritten in place: a search allocates nothing once they have grown)
        let cell = &mut self.cell;
        cell.resize(x.len(), 0);
        cell.par_iter_mut()
            .zip(x.par_iter())
            .for_each(|(c, p)| *c = cell_of(p) as u32);
        let start = &mut self.start;
        start.clear();
        start.resize(total + 1, 0);
        for &c in cell.iter() {
            start[c as usize + 1] += 1;
        }
        for c in 0..total {
            start[c + 1] += start[c];
        }
        let fill = &mut self.fill;
        fill.clone_from(start);
        let items = &mut self.items;
        items.resize(x.len(), 0);
        for (i, &c) in cell.iter().enumerate() {
            items[fill[c as usize] as usize] = i as u32;
            fill[c as usize] += 1;
        }
        self.pos.resize(x.len(), [0.0; D]);
        self.pos
            .par_iter_mut()
            .zip(items.par_iter())
            .for_each(|(q, &i)| *q = x[i as usize]);
        (self.lo, self.inv, self.dims) = (lo, inv, dims);
    }

    /// Calls `visit(j)` for every point `j` of the grid with `|x_j − q|² ≤ r2`. The cells of
    /// one run along axis 0 are consecutive in the cell order: each run is one contiguous
    /// stretch of `pos`.
    fn within(&self, q: &[f64; D], r2: f64, mut visit: impl FnMut(u32)) {
        let r = r2.sqrt();
        let mut a = [0usize; D];
        let mut b = [0usize; D];
        for k in 0..D {
            let lo = ((q[k] - r - self.lo[k]) * self.inv).floor();
            let hi = ((q[k] + r - self.lo[k]) * self.inv).floor();
            if hi < 0.0 || lo > (self.dims[k] - 1) as f64 {
                return;
            }
            a[k] = lo.max(0.0) as usize;
            b[k] = (hi as usize).min(self.dims[k] - 1);
        }
        // odometer over the runs (cells a_0..=b_0 at each c_1..c_{D−1} of a..=b), the
        // grid's row-major order
        let mut c = a;
        loop {
            let mut cell = 0;
            for k in (1..D).rev() {
                cell = cell * self.dims[k] + c[k];
            }
            cell *= self.dims[0];
            let s = self.start[cell + a[0]] as usize;
            let e = self.start[cell + b[0] + 1] as usize;
            for (p, &j) in self.pos[s..e].iter().zip(&self.items[s..e]) {
                let mut d2 = 0.0;
                for k in 0..D {
                    let t = p[k] - q[k];
                    d2 += t * t;
                }
                if d2 <= r2 {
                    visit(j);
                }
            }
            let mut k = 1;
            loop {
                if k >= D {
                    return;
                }
                if c[k] < b[k] {
                    c[k] += 1;
                    break;
                }
                c[k] = a[k];
                k += 1;
            }
        }
    }
}

/// Splits `v` into consecutive mutable pieces `v[bounds[c]..bounds[c + 1]]`.
pub(crate) fn split_by<'a, T>(mut v: &'a mut [T], bounds: &[usize]) -> Vec<&'a mut [T]> {
    let mut parts = Vec::with_capacity(bounds.len().saturating_sub(1));
    let mut at = bounds.first().copied().unwrap_or(0);
    for &b in &bounds[1..] {
        let (head, tail) = std::mem::take(&mut v).split_at_mut(b - at);
        parts.push(head);
        v = tail;
        at = b;
    }
    parts
}

#[cfg(test)]
mod tests {
    use super::sort_row;

    /// `sort_row` against sort + dedup + removal of `own`, on rows whose indices span few
    /// words (the bitmap) and many (the sort), with repeats, `own` inside and outside the span,
    /// and indices near `u32::MAX`.
    #[test]
    fn sort_row_equals_a_sort_with_dedup_and_without_own() {
        let mut s: u64 = 0x9e37_79b9_7f4a_7c15;
        let mut next = |m: u64| {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            s % m
        };
        let mut bits = Vec::new();
        let (mut bitmap, mut sorted) = (0, 0);
        for case in 0..4000 {
            let len = next(200) as usize;
            let span = [70, 700, 7000, 1 << 31][case % 4];
            let base = if case % 7 == 0 {
                u32::MAX - span as u32
            } else {
                next(1 << 20) as u32
            };
            let mut row: Vec<u32> = (0..len).map(|_| base + next(span) as u32).collect();
            if len > 3 && case % 3 == 0 {
                let r = row[1];
                row.push(r); // a repeat (a periodic image found twice)
            }
            let own = if case % 2 == 0 && len > 0 {
                row[next(len as u64) as usize]
            } else {
                base.wrapping_add(next(span) as u32)
            };
            let mut want = row.clone();
            want.sort_unstable();
            want.dedup();
            want.retain(|&j| j != own);
            let words = row
                .iter()
                .max()
                .zip(row.iter().min())
                .map(|(h, l)| (h - l) / 64 + 1);
            match words {
                Some(w) if w as usize <= 8 * row.len() => bitmap += 1,
                _ => sorted += 1,
            }
            sort_row(&mut row, &mut bits, own);
            assert_eq!(row, want, "case {case}");
        }
        assert!(
            bitmap > 1000 && sorted > 1000,
            "{bitmap} bitmap, {sorted} sorted"
        );
    }
}
