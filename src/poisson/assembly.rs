//! Assembly of the symmetric Poisson matrix from the neighbour list.
//!
//! Row `i` of `−Δh u = b` multiplied by `ω_i` (Imoto 2019, proof of Thm 4.1) gives the symmetric
//! system `K u = ω∘b` with, for unknowns `i ≠ j`,
//! `K_ij = −Σ ω_i ω_j a_ij` and `K_ii = ω_i Σ_{k≠i} ω_k a_ik`, `a_ij = 2d w_h(r_ij)/r_ij²`,
//! where `k` runs over every neighbour (Dirichlet ones included) and a ghost image of the fluid
//! particle `j` adds to the entry of `j` (a mirror image keeps `K` symmetric: `|x_i − R x_j| =
//! |x_j − R x_i|` for a reflection `R`). Pairs of a particle with its own image cancel.
//!
//! The pattern is built from the neighbour list's candidate pairs (within `h + skin`), so it is
//! the same for every step until the candidates are rebuilt: the numeric values of pairs that
//! are candidates but currently farther than `h` are zero.

use crate::diagnostics::alias;
use crate::error::SolveError;
use crate::math::{row_pieces, PerRow};
use crate::neighbors::{split_by, NeighborList};
use crate::particles::Role;
use rayon::prelude::*;
use std::sync::atomic::{AtomicBool, Ordering};

/// The assembled matrix `K` over the fluid unknowns, in full symmetric CSR form.
#[derive(Clone, Debug, Default)]
pub struct Assembly {
    key: Option<(u64, u64, u64)>,
    values_key: Option<ValuesKey>,
    pattern_id: u64,
    /// The pattern id of the Poisson matrix this one's pattern was copied from
    /// ([`Self::helmholtz_from`]).
    derived_from: Option<u64>,
    /// Unknown index of each particle (`u32::MAX` when the particle is not an unknown).
    pub unknown: Vec<u32>,
    /// Particle index of each unknown.
    pub particle: Vec<u32>,
    /// Row `u` is `offsets[u]..offsets[u + 1]`.
    pub offsets: Vec<usize>,
    /// Column (unknown) of each entry, ascending within a row.
    pub cols: Vec<u32>,
    /// Position of the diagonal entry of each row.
    pub diag: Vec<usize>,
    /// Values.
    pub values: Vec<f64>,
    /// Skip refilling the values while their inputs are unchanged (default false here; the
    /// solvers switch it on through [`crate::poisson::SolveParams::reuse_values`]).
    pub reuse_values: bool,
    /// Only the pairs within `h` enter the pattern (the neighbour skin's pairs carry zero
    /// values): the pattern then follows the pair set, rebuilt whenever the pair data change
    /// (moving particles: every step) rather than only when the candidates are searched again.
    /// Off by default here; the solvers set it from
    /// [`crate::poisson::SolveParams::pattern_within_h`].
    pub within_h: bool,
    values_reused: bool,
    /// The per-chunk rows of [`Self::update_with_values`], kept between calls (a moving run
    /// builds its pattern every step: no allocation once they have grown).
    chunks: ChunkScratch,
    /// `(epoch, generation, c0)` when the last build of a within-h pattern also summed
    /// `Σ_j ω_j w_h(r_ij)` over every unknown's row in the same pass as its values: `c0`
    /// (Definition 3.2) over `Ω` for those pair data ([`Self::c0_of`]).
    c0: Option<(u64, u64, f64)>,
    /// Gershgorin's bound `max_i Σ_j |a_ij| / a_ii` on the spectral radius of `D⁻¹A` for the
    /// values the last [`Self::update_poisson`] / [`Self::update_helmholtz`] wrote, when it
    /// took the row sums beside them (`None` otherwise): the lagged AMG smoother's stability
    /// check reads it instead of a pass over the matrix ([`Self::jacobi_bound`]).
    jacobi: Option<f64>,
    /// Keep a within-h pattern while the neighbour list's pair set is unchanged
    /// ([`NeighborList::pair_set`]): only the values are refilled, and the pattern's id (which
    /// the AMG and Cholesky caches key on) stays. Off: a new pattern at every measure. The
    /// solvers set it from [`crate::poisson::SolveParams::pattern_keep_pairs`].
    pub keep_pairs: bool,
    /// `(epoch, generation)` of the pair data the values were last filled from.
    filled: Option<(u64, u64)>,
}

/// Rows of one chunk: lengths, columns, values, diagonal positions.
type ChunkRows = (Vec<u32>, Vec<u32>, Vec<f64>, Vec<u32>);

/// Scratch rows per chunk (a clone starts empty: it is scratch, not state).
#[derive(Debug, Default)]
struct ChunkScratch(Vec<ChunkRows>);

impl Clone for ChunkScratch {
    fn clone(&self) -> Self {
        ChunkScratch::default()
    }
}

/// What the matrix values were computed from (kept, with its vectors, when forgotten: `valid`
/// false).
#[derive(Clone, Debug, Default, PartialEq)]
struct ValuesKey {
    valid: bool,
    pattern_id: u64,
    generation: u64,
    vol: Vec<f64>,
    mass: u64,
    c: u64,
    sigma: Vec<f64>,
}

/// Rows per parallel piece of the value fills (at least).
const ROW_CHUNK: usize = 256;

/// `dst` resized to `bounds`' last entry and filled with `parts` (part `c` into
/// `bounds[c]..bounds[c + 1]`), the parts copied in parallel (a serial copy of a pattern's
/// columns and values was ~30 ms of a 10⁶-particle step).
fn gather_parts<T: Copy + Default + Send + Sync>(
    dst: &mut Vec<T>,
    bounds: &[usize],
    parts: &[&[T]],
) {
    dst.resize(*bounds.last().expect("one bound"), T::default());
    split_by(dst, bounds)
        .into_par_iter()
        .zip(parts.par_iter())
        .for_each(|(d, s)| d.copy_from_slice(s));
}

fn role_hash(role: &[Role]) -> u64 {
    // FNV-1a over the role tags and ghost sources
    let mut h: u64 = 0xcbf29ce484222325;
    let mut eat = |v: u64| {
        h ^= v;
        h = h.wrapping_mul(0x100000001b3);
    };
    eat(role.len() as u64);
    for r in role {
        match *r {
            Role::Fluid => eat(1),
            Role::Dirichlet => eat(2),
            Role::Ghost { source, .. } => eat(3 | ((source as u64) << 8)),
        }
    }
    h
}

impl Assembly {
    /// Number of unknowns.
    pub fn n(&self) -> usize {
        self.particle.len()
    }
    /// Stored entries of the full symmetric matrix.
    pub fn nnz(&self) -> usize {
        self.cols.len()
    }
    /// Changes whenever the sparsity pattern changes.
    pub fn pattern_id(&self) -> u64 {
        self.pattern_id
    }

    /// Numbers the fluid particles as unknowns, in particle order.
    /// The pair data's part of the pattern key: nothing without `within_h` (the candidates'
    /// pattern holds until the next search), the pair set with `keep_pairs`, the generation
    /// (every measure) otherwise.
    fn pattern_generation<const D: usize>(&self, nl: &NeighborList<D>) -> u64 {
        match (self.within_h && nl.config().skin > 0.0, self.keep_pairs) {
            (false, _) => 0,
            (true, true) => nl.pair_set(),
            (true, false) => nl.generation(),
        }
    }

    fn number_unknowns(&mut self, role: &[Role]) {
        self.unknown.clear();
        self.unknown.resize(role.len(), u32::MAX);
        self.particle.clear();
        for (i, r) in role.iter().enumerate() {
            if r.is_fluid() {
                self.unknown[i] = self.particle.len() as u32;
                self.particle.push(i as u32);
            }
        }
    }

    /// Sets the offsets and diagonal positions from chunks of rows (each chunk's row lengths
    /// and the diagonal's position within each row) and returns the chunks' entry bounds:
    /// chunk `c` holds entries `bounds[c]..bounds[c + 1]`.
    fn set_rows<'a>(&mut self, chunks: impl Iterator<Item = (&'a [u32], &'a [u32])>) -> Vec<usize> {
        self.offsets.clear();
        self.offsets.push(0);
        self.diag.clear();
        let mut bounds = vec![0usize];
        for (lens, diag) in chunks {
            for (&len, &pos) in lens.iter().zip(diag) {
                let base = *self.offsets.last().expect("offsets start at 0");
                self.diag.push(base + pos as usize);
                self.offsets.push(base + len as usize);
            }
            bounds.push(*self.offsets.last().expect("offsets start at 0"));
        }
        bounds
    }

    /// Rebuilds the pattern when the candidate pairs or the roles changed; returns true if it did.
    pub fn update_pattern<const D: usize>(&mut self, nl: &NeighborList<D>, role: &[Role]) -> bool {
        // with a skin, the pairs within h change with the pair data, not only with the list
        let within_h = self.within_h && nl.config().skin > 0.0;
        let key = (nl.epoch(), self.pattern_generation(nl), role_hash(role));
        if self.key == Some(key) && self.unknown.len() == role.len() {
            return false;
        }
        self.number_unknowns(role);
        // the candidates' pattern (stable while the list is not searched again), or the
        // pairs within h of the current pair data
        let (co, ci) = nl.pattern();
        let unknown = &self.unknown;
        let particle = &self.particle;
        // rows in chunks: (row lengths, columns, diagonal position within the row) per chunk
        const CHUNK: usize = 256;
        let parts: Vec<(Vec<u32>, Vec<u32>, Vec<u32>)> = (0..particle.len())
            .into_par_iter()
            .step_by(CHUNK)
            .map(|start| {
                let end = (start + CHUNK).min(particle.len());
                let mut lens = Vec::with_capacity(end - start);
                let mut diag = Vec::with_capacity(end - start);
                let mut cols = Vec::with_capacity((end - start) * 32);
                let mut row: Vec<u32> = Vec::with_capacity(64);
                for u in start..end {
                    let p = particle[u] as usize;
                    row.clear();
                    let mut add = |j: u32| {
                        if let Some(s) = alias(role, j as usize) {
                            if s != p {
                                row.push(unknown[s]);
                            }
                        }
                    };
                    if within_h {
                        for k in nl.row(p) {
                            if nl.w()[k] > 0.0 {
                                add(nl.indices()[k]);
                            }
                        }
                    } else {
                        ci[co[p]..co[p + 1]].iter().for_each(|&j| add(j));
                    }
                    row.push(u as u32);
                    row.sort_unstable();
                    row.dedup();
                    let pos = row.binary_search(&(u as u32)).expect("diagonal in pattern");
                    lens.push(row.len() as u32);
                    diag.push(pos as u32);
                    cols.extend_from_slice(&row);
                }
                (lens, cols, diag)
            })
            .collect();
        let bounds = self.set_rows(parts.iter().map(|(lens, _, diag)| (&lens[..], &diag[..])));
        let cols: Vec<&[u32]> = parts.iter().map(|p| &p.1[..]).collect();
        gather_parts(&mut self.cols, &bounds, &cols);
        self.values = vec![0.0; self.cols.len()];
        self.key = Some(key);
        self.pattern_id += 1;
        self.derived_from = None;
        true
    }

    /// The Poisson matrix for the current pair data: [`Self::update_pattern`] then
    /// [`Self::fill_values`], except that a pattern that follows the pairs within `h`
    /// ([`Self::within_h`] with a skin: moving particles, a new pattern every step) is built
    /// together with its values in one pass over the pairs (each row's entries collected,
    /// sorted by column and merged; ghosts add to their source's column). Returns true when the
    /// pattern was rebuilt.
    pub fn update_poisson<const D: usize>(
        &mut self,
        nl: &NeighborList<D>,
        vol: &[f64],
        role: &[Role],
    ) -> Result<bool, SolveError> {
        self.update_with_values(nl, vol, role, 0.0, 1.0, None)
    }

    /// [`Self::update_poisson`] for the Helmholtz matrix of [`Self::fill_helmholtz`].
    pub fn update_helmholtz<const D: usize>(
        &mut self,
        nl: &NeighborList<D>,
        vol: &[f64],
        role: &[Role],
        c: f64,
        sigma: &[f64],
    ) -> Result<bool, SolveError> {
        self.update_with_values(nl, vol, role, 1.0, c, Some(sigma))
    }

    /// True when this Poisson matrix's pattern and values are those of `nl`'s current pairs
    /// and `role` (what [`Self::helmholtz_from`] and a viscous solve that reads `K` itself
    /// require; the volumes are the caller's to keep the same).
    pub fn is_current<const D: usize>(&self, nl: &NeighborList<D>, role: &[Role]) -> bool {
        let key = (nl.epoch(), self.pattern_generation(nl), role_hash(role));
        self.key == Some(key)
            && self.filled == Some((nl.epoch(), nl.generation()))
            && self.unknown.len() == role.len()
            && self.values.len() == self.cols.len()
    }

    /// The Helmholtz matrix of [`Self::update_helmholtz`] derived from the Poisson matrix `k`
    /// of the same configuration instead of from the pairs: the same pattern (copied when `k`'s
    /// changed), `c` times `k`'s values, `mass ω_i` added on the diagonal, and for every image
    /// `g` of a fluid source `s` with `σ_g ≠ 1` the difference `c a_ig (1 − σ_g)` added at
    /// column `s` (`−c a σ` where `K` has `−a`; on the diagonal when `s` is the row's own
    /// particle). One pass over the entries, plus one over the pairs when some `σ ≠ 1`, where
    /// the builder needs a pass over the pairs, a sort and a merge (moving particles, whose two
    /// matrices change every step: 24 → ≈ 4 ms at 2D 10⁵). Returns `None`, changing nothing,
    /// when `k`'s pattern is not the one of `nl`'s current pairs and `role` (the caller must
    /// also have assembled `k` from the same `vol`); otherwise whether the pattern changed.
    #[allow(clippy::too_many_arguments)]
    pub fn helmholtz_from<const D: usize>(
        &mut self,
        k: &Assembly,
        nl: &NeighborList<D>,
        vol: &[f64],
        role: &[Role],
        mass: f64,
        c: f64,
        sigma: &[f64],
    ) -> Option<bool> {
        if !k.is_current(nl, role) {
            return None;
        }
        let rebuilt = self.key != k.key
            || self.cols.len() != k.cols.len()
            || self.derived_from != Some(k.pattern_id);
        if rebuilt {
            self.unknown.clone_from(&k.unknown);
            self.particle.clone_from(&k.particle);
            self.offsets.clone_from(&k.offsets);
            self.cols.clone_from(&k.cols);
            self.diag.clone_from(&k.diag);
            self.key = k.key;
            self.pattern_id += 1;
            self.derived_from = Some(k.pattern_id);
        }
        self.forget_values();
        self.values_reused = false;
        self.values.resize(k.values.len(), 0.0);
        let two_d = 2.0 * D as f64;
        let corrected = sigma.iter().any(|&s| s != 1.0);
        let n = self.n();
        let (offsets, cols, diag, particle, unknown) = (
            &self.offsets,
            &self.cols,
            &self.diag,
            &self.particle,
            &self.unknown,
        );
        let parts = row_pieces(n, ROW_CHUNK, |u| offsets[u], &mut self.values[..]);
        parts.for_each(|(rows, vals)| {
            let base = offsets[rows.start];
            let kv = &k.values[base..base + vals.len()];
            for (v, kv) in vals.iter_mut().zip(kv) {
                *v = c * kv;
            }
            for u in rows {
                let p = particle[u] as usize;
                vals[diag[u] - base] += mass * vol[p];
                if !corrected {
                    continue;
                }
                let row = &cols[offsets[u]..offsets[u + 1]];
                for e in nl.row(p) {
                    let j = nl.indices()[e] as usize;
                    let sg = sigma[j];
                    if sg == 1.0 || !matches!(role[j], Role::Ghost { .. }) {
                        continue;
                    }
                    let Some(s) = alias(role, j) else { continue };
                    let a = c * two_d * vol[p] * vol[j] * nl.wr2()[e];
                    if a == 0.0 {
                        continue;
                    }
                    if let Ok(pos) = row.binary_search(&unknown[s]) {
                        vals[offsets[u] + pos - base] += a * (1.0 - sg);
                    }
                }
            }
        });
        self.filled = Some((nl.epoch(), nl.generation()));
        Some(rebuilt)
    }

    fn update_with_values<const D: usize>(
        &mut self,
        nl: &NeighborList<D>,
        vol: &[f64],
        role: &[Role],
        mass: f64,
        c: f64,
        sigma: Option<&[f64]>,
    ) -> Result<bool, SolveError> {
        self.c0 = None;
        self.jacobi = None;
        let within_h = self.within_h && nl.config().skin > 0.0;
        let key = (nl.epoch(), self.pattern_generation(nl), role_hash(role));
        let current = self.key == Some(key) && self.unknown.len() == role.len();
        let all_fluid = sigma.is_none() && self.particle.len() == role.len();
        if within_h && current && all_fluid && self.cols.len() == nl.n_pairs() + role.len() {
            // the pair set held (`keep_pairs`): the values refilled by the in-place path,
            // which writes the same columns again, and the pattern kept with its id
            if let Some((c0, g)) = self.fill_all_fluid(nl, vol, mass, c) {
                self.values_reused = false;
                self.forget_values();
                if self.reuse_values {
                    self.remember_values(nl.generation(), vol, mass, c, sigma);
                }
                self.filled = Some((nl.epoch(), nl.generation()));
                self.c0 = Some((nl.epoch(), nl.generation(), c0));
                self.jacobi = Some(g);
                return Ok(false);
            }
        }
        if !within_h || current {
            let rebuilt = self.update_pattern(nl, role);
            self.fill(nl, vol, role, mass, c, sigma)?;
            return Ok(rebuilt);
        }
        self.number_unknowns(role);
        if sigma.is_none() && self.particle.len() == role.len() {
            if let Some((c0, g)) = self.fill_all_fluid(nl, vol, mass, c) {
                self.set_pattern_built(key, nl, vol, mass, c, sigma);
                self.c0 = Some((nl.epoch(), nl.generation(), c0));
                self.jacobi = Some(g);
                return Ok(true);
            }
        }
        let two_d = 2.0 * D as f64;
        let unknown = &self.unknown;
        let particle = &self.particle;
        const CHUNK: usize = 256;
        let mut parts = std::mem::take(&mut self.chunks.0);
        parts.resize_with(particle.len().div_ceil(CHUNK), Default::default);
        let (c0, g) = parts
            .par_iter_mut()
            .enumerate()
            .map(|(chunk, (lens, cols, vals, diag))| {
                let start = chunk * CHUNK;
                let end = (start + CHUNK).min(particle.len());
                lens.clear();
                diag.clear();
                cols.clear();
                vals.clear();
                let mut row: Vec<(u32, f64)> = Vec::with_capacity(64);
                let (mut c0, mut g) = (0.0f64, 0.0f64);
                for u in start..end {
                    let p = particle[u] as usize;
                    row.clear();
                    let mut dsum = 0.0;
                    // c0's row sum Σ_j ω_j w_ij beside the values, in semi_regularity's order
                    let mut vw = 0.0;
                    for k in nl.row(p) {
                        let j = nl.indices()[k] as usize;
                        vw += vol[j] * nl.w()[k];
                        let a = c * two_d * vol[p] * vol[j] * nl.wr2()[k];
                        if a == 0.0 {
                            continue;
                        }
                        let sg = sigma.map_or(1.0, |sg| sg[j]);
                        match alias(role, j) {
                            // a pair with its own image: (σ u_p + b − u_p)
                            Some(s) if s == p => dsum += a * (1.0 - sg),
                            Some(s) => {
                                dsum += a;
                                row.push((unknown[s], -a * sg));
                            }
                            None => dsum += a,
                        }
                    }
                    // the neighbours come in index order: with unknowns numbered in particle
                    // order and no images, the row is sorted and the diagonal is inserted in
                    // place; otherwise a stable sort (duplicates — a source and its images —
                    // add in pair order, as in fill)
                    let d = (u as u32, dsum + mass * vol[p]);
                    if row.is_sorted_by_key(|e| e.0) {
                        let at = row.partition_point(|e| e.0 <= d.0);
                        row.insert(at, d);
                    } else {
                        row.push(d);
                        row.sort_by_key(|e| e.0);
                    }
                    let first = cols.len();
                    for &(c, v) in row.iter() {
                        if cols.len() > first && *cols.last().expect("an entry") == c {
                            *vals.last_mut().expect("an entry") += v;
                        } else {
                            cols.push(c);
                            vals.push(v);
                        }
                    }
                    let pos = cols[first..]
                        .binary_search(&(u as u32))
                        .expect("diagonal in pattern");
                    lens.push((cols.len() - first) as u32);
                    diag.push(pos as u32);
                    c0 = c0.max(vw);
                    let abs_sum = vals[first..].iter().map(|v| v.abs()).sum::<f64>();
                    g = g.max(gershgorin_ratio(abs_sum, vals[first + pos]));
                }
                (c0, g)
            })
            .reduce(|| (0.0, 0.0), |a, b| (a.0.max(b.0), a.1.max(b.1)));
        // offsets and diagonals row by row, the columns and values copied chunk by chunk in
        // parallel
        let bounds = self.set_rows(
            parts
                .iter()
                .map(|(lens, _, _, diag)| (&lens[..], &diag[..])),
        );
        let cols: Vec<&[u32]> = parts.iter().map(|p| &p.1[..]).collect();
        let vals: Vec<&[f64]> = parts.iter().map(|p| &p.2[..]).collect();
        gather_parts(&mut self.cols, &bounds, &cols);
        gather_parts(&mut self.values, &bounds, &vals);
        self.chunks.0 = parts;
        self.set_pattern_built(key, nl, vol, mass, c, sigma);
        self.c0 = Some((nl.epoch(), nl.generation(), c0));
        self.jacobi = Some(g);
        Ok(true)
    }

    /// The bookkeeping after [`Self::update_with_values`] built a new pattern with its values.
    fn set_pattern_built<const D: usize>(
        &mut self,
        key: (u64, u64, u64),
        nl: &NeighborList<D>,
        vol: &[f64],
        mass: f64,
        c: f64,
        sigma: Option<&[f64]>,
    ) {
        self.key = Some(key);
        self.pattern_id += 1;
        self.derived_from = None;
        self.values_reused = false;
        self.filled = Some((nl.epoch(), nl.generation()));
        self.forget_values();
        if self.reuse_values {
            self.remember_values(nl.generation(), vol, mass, c, sigma);
        }
    }

    /// Marks the values as computed from these inputs and the current pattern (the key's
    /// vectors overwritten in place).
    fn remember_values(
        &mut self,
        generation: u64,
        vol: &[f64],
        mass: f64,
        c: f64,
        sigma: Option<&[f64]>,
    ) {
        let k = self.values_key.get_or_insert_with(ValuesKey::default);
        k.valid = true;
        k.pattern_id = self.pattern_id;
        k.generation = generation;
        k.vol.clear();
        k.vol.extend_from_slice(vol);
        k.mass = mass.to_bits();
        k.c = c.to_bits();
        k.sigma.clear();
        k.sigma.extend_from_slice(sigma.unwrap_or_default());
    }

    /// Marks the values as stale: the next update recomputes them (a viscous solve that read
    /// the Poisson matrix instead, [`crate::poisson::iterative::Shifted`], left them behind).
    pub(crate) fn discard_values(&mut self) {
        self.forget_values();
        self.filled = None;
    }

    /// Marks the values as computed from nothing known (the key's memory kept), and drops
    /// Gershgorin's bound taken with the old ones (a fill that computes a new one sets it
    /// after this).
    fn forget_values(&mut self) {
        if let Some(k) = &mut self.values_key {
            k.valid = false;
        }
        self.jacobi = None;
    }

    /// [`Self::update_with_values`] when every particle is a fluid unknown (numbered in
    /// particle order, no ghosts, no band — a periodic box): row `u` is then the neighbour
    /// list's row `u` (sorted, no repeats) with the diagonal inserted, so its place in the
    /// matrix is known before it is filled (`offsets[u]` = the rows before it and `u`) and the rows
    /// are written in place, in parallel, without the general path's per-chunk rows and their
    /// copy. The same entries, values and sums in the same order (the same bits). Returns
    /// `c0` (the largest row sum `Σ_j ω_j w_ij`, summed in the same pass) and Gershgorin's
    /// bound on `ρ(D⁻¹A)` ([`Self::jacobi_bound`]), or `None`, having
    /// written nothing that counts, when some pair's entry is exactly zero (the general path
    /// leaves such entries out of the pattern).
    fn fill_all_fluid<const D: usize>(
        &mut self,
        nl: &NeighborList<D>,
        vol: &[f64],
        mass: f64,
        c: f64,
    ) -> Option<(f64, f64)> {
        let n = self.particle.len();
        if nl.len() != n {
            return None;
        }
        // each row its pairs and the diagonal
        self.offsets.clear();
        self.offsets.push(0);
        let mut m = 0;
        for u in 0..n {
            m += nl.row(u).len() + 1;
            self.offsets.push(m);
        }
        self.cols.resize(m, 0);
        self.values.resize(m, 0.0);
        self.diag.resize(n, 0);
        let two_d = 2.0 * D as f64;
        let offsets = &self.offsets;
        let (idx, w, wr2) = (nl.indices(), nl.w(), nl.wr2());
        let parts = (
            (&mut self.cols[..], &mut self.values[..]),
            PerRow(&mut self.diag[..]),
        );
        row_pieces(n, ROW_CHUNK, |u| offsets[u], parts)
            .map(|(rows, ((cols, vals), PerRow(diag)))| {
                let base = offsets[rows.start];
                let (mut c0, mut g) = (0.0f64, 0.0f64);
                for (du, u) in rows.enumerate() {
                    let row = nl.row(u);
                    let js = &idx[row.clone()];
                    let at = js.partition_point(|&j| (j as usize) < u);
                    let start = offsets[u] - base;
                    let (mut dsum, mut vw) = (0.0, 0.0);
                    for (e, ((&j, &q), &wk)) in
                        js.iter().zip(&wr2[row.clone()]).zip(&w[row]).enumerate()
                    {
                        let a = c * two_d * vol[u] * vol[j as usize] * q;
                        if a == 0.0 {
                            return None;
                        }
                        dsum += a;
                        vw += vol[j as usize] * wk;
                        let o = start + e + (e >= at) as usize;
                        cols[o] = j;
                        vals[o] = -a;
                    }
                    let d = dsum + mass * vol[u];
                    cols[start + at] = u as u32;
                    vals[start + at] = d;
                    diag[du] = offsets[u] + at;
                    c0 = c0.max(vw);
                    // every off-diagonal entry is −a < 0: Σ_j |a_uj| = dsum + d
                    g = g.max(gershgorin_ratio(dsum + d, d));
                }
                Some((c0, g))
            })
            .reduce(
                || Some((0.0, 0.0)),
                |a, b| {
                    let (a, b) = (a?, b?);
                    Some((a.0.max(b.0), a.1.max(b.1)))
                },
            )
    }

    /// Fills the values of `K` for the current pair data (pattern must be up to date).
    pub fn fill_values<const D: usize>(
        &mut self,
        nl: &NeighborList<D>,
        vol: &[f64],
        role: &[Role],
    ) -> Result<(), SolveError> {
        self.fill(nl, vol, role, 0.0, 1.0, None)
    }

    /// Fills the values of the Helmholtz matrix `H = W + c K_σ` with `W = diag(ω_i)`: the
    /// symmetric form of `ω_i (u_i − c Δh u_i)` when ghost values are `u_g = σ_g u_src + b_g`
    /// (`sigma[g]`, ±1 per particle, 1 for non-ghosts; the constants `b` go to the right side).
    /// With `σ = −1` (no-slip image across one wall) a particle's own image adds to its diagonal.
    pub fn fill_helmholtz<const D: usize>(
        &mut self,
        nl: &NeighborList<D>,
        vol: &[f64],
        role: &[Role],
        c: f64,
        sigma: &[f64],
    ) -> Result<(), SolveError> {
        self.fill(nl, vol, role, 1.0, c, Some(sigma))
    }

    /// `c0 = max_{i∈Ω} Σ_{j≠i} ω_j w_h(r_ij)` of `nl`'s pair data, when the last build of the
    /// pattern summed it beside the values (a moving step's within-h pattern: the diagnostic
    /// costs no pass of its own); the same value as [`crate::diagnostics::semi_regularity`]
    /// with the volumes that build used.
    pub fn c0_of<const D: usize>(&self, nl: &NeighborList<D>) -> Option<f64> {
        match self.c0 {
            Some((e, g, c0)) if e == nl.epoch() && g == nl.generation() => Some(c0),
            _ => None,
        }
    }

    /// Gershgorin's bound `max_i Σ_j |a_ij| / a_ii` on `ρ(D⁻¹A)` for the current values, when
    /// the last update took it beside them (a within-`h` pattern's build or refill, as a moving
    /// step does); `None` otherwise (values from [`Self::fill_values`], another path, or
    /// changed by hand: the field is public, the bound then no longer applies).
    pub fn jacobi_bound(&self) -> Option<f64> {
        self.jacobi
    }

    /// True when the last fill used exactly these inputs (same pattern, same pair data
    /// generation, same volumes and coefficients), so the values are already current.
    pub fn values_current(&self) -> bool {
        self.values_reused
    }

    fn fill<const D: usize>(
        &mut self,
        nl: &NeighborList<D>,
        vol: &[f64],
        role: &[Role],
        mass: f64,
        c: f64,
        sigma: Option<&[f64]>,
    ) -> Result<(), SolveError> {
        let key = ValuesKey {
            valid: true,
            pattern_id: self.pattern_id,
            generation: nl.generation(),
            vol: Vec::new(),
            mass: mass.to_bits(),
            c: c.to_bits(),
            sigma: Vec::new(),
        };
        if self.reuse_values {
            if let Some(k) = &self.values_key {
                if k.valid
                    && k.pattern_id == key.pattern_id
                    && k.generation == key.generation
                    && k.mass == key.mass
                    && k.c == key.c
                    && k.vol == vol
                    && sigma.map(|s| k.sigma == s).unwrap_or(k.sigma.is_empty())
                {
                    self.values_reused = true;
                    return Ok(());
                }
            }
        }
        self.values_reused = false;
        self.forget_values();
        let two_d = 2.0 * D as f64;
        let missing = AtomicBool::new(false);
        let n = self.n();
        let (offsets, cols, diag, particle, unknown) = (
            &self.offsets,
            &self.cols,
            &self.diag,
            &self.particle,
            &self.unknown,
        );
        let parts = row_pieces(n, ROW_CHUNK, |u| offsets[u], &mut self.values[..]);
        parts.for_each(|(rows, vals)| {
            let base = offsets[rows.start];
            vals.fill(0.0);
            for u in rows {
                let p = particle[u] as usize;
                let row = &cols[offsets[u]..offsets[u + 1]];
                let mut dsum = 0.0;
                for k in nl.row(p) {
                    let j = nl.indices()[k] as usize;
                    let s = alias(role, j);
                    let sg = sigma.map(|sg| sg[j]).unwrap_or(1.0);
                    let a = c * two_d * vol[p] * vol[j] * nl.wr2()[k];
                    if a == 0.0 {
                        // beyond h (a skin pair, possibly not in the pattern): adds nothing
                        continue;
                    }
                    if s == Some(p) {
                        // own image: (σ u_p + b − u_p)
                        dsum += a * (1.0 - sg);
                        continue;
                    }
                    dsum += a;
                    if let Some(s) = s {
                        match row.binary_search(&unknown[s]) {
                            Ok(pos) => vals[offsets[u] - base + pos] -= a * sg,
                            Err(_) => missing.store(true, Ordering::Relaxed),
                        }
                    }
                }
                vals[diag[u] - base] += dsum + mass * vol[p];
            }
        });
        if missing.load(Ordering::Relaxed) {
            return Err(SolveError::Backend(
                "a neighbour pair is missing from the matrix pattern (roles or positions \
                 changed without a neighbour-list update)"
                    .into(),
            ));
        }
        if self.reuse_values {
            self.remember_values(key.generation, vol, mass, c, sigma);
        }
        self.filled = Some((nl.epoch(), nl.generation()));
        Ok(())
    }

    /// `y = K x`.
    pub fn spmv(&self, x: &[f64], y: &mut [f64]) {
        y.par_iter_mut()
            .with_min_len(1024)
            .enumerate()
            .for_each(|(u, yu)| *yu = self.row_dot(u, x));
    }

    /// Row `u`: its columns and values.
    #[inline]
    pub fn row(&self, u: usize) -> (&[u32], &[f64]) {
        let r = self.offsets[u]..self.offsets[u + 1];
        (&self.cols[r.clone()], &self.values[r])
    }

    /// `(K x)_u` ([`crate::math::sparse_dot`]: four partial sums over the row's slices).
    #[inline]
    pub fn row_dot(&self, u: usize, x: &[f64]) -> f64 {
        let (cols, values) = self.row(u);
        crate::math::sparse_dot(values, cols, x)
    }

    /// The diagonal of `K`.
    pub fn diagonal(&self) -> Vec<f64> {
        self.diag.iter().map(|&k| self.values[k]).collect()
    }
}

/// One row's Gershgorin ratio `Σ_j |a_uj| / a_uu` from the row's absolute sum and its
/// diagonal (0 where the diagonal is not positive, as the Jacobi smoother's inverse diagonal
/// is).
fn gershgorin_ratio(abs_sum: f64, d: f64) -> f64 {
    if d > 0.0 {
        abs_sum / d
    } else {
        0.0
    }
}
