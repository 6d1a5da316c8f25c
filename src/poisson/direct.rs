//! Sparse Cholesky `K = L Lᵀ` with faer, the symbolic analysis (AMD ordering, elimination tree,
//! supernodes) reused while the pattern is unchanged and the numeric factor reused while the
//! values are unchanged.
//!
//! A floating (pure Neumann) component makes `K` singular with the constants of that component as
//! null space. The right-hand side is made consistent beforehand (projected to zero sum), so
//! fixing one unknown of the component to zero and dropping its row and column gives an SPD
//! system whose solution solves the full singular system; the constant is then fixed to zero
//! mean by the caller. No regularisation, no noise on the diagonal.

use super::assembly::Assembly;
use crate::error::SolveError;
use faer::dyn_stack::{MemBuffer, MemStack};
use faer::linalg::cholesky::llt::factor::LltRegularization;
use faer::sparse::linalg::cholesky::{
    factorize_symbolic_cholesky, CholeskySymbolicParams, LltRef, SymbolicCholesky,
    SymbolicCholeskyRaw, SymmetricOrdering,
};
use faer::sparse::linalg::SupernodalThreshold;
use faer::sparse::{SparseColMatRef, SymbolicSparseColMatRef};
use faer::{Conj, MatMut, Par, Side};

/// Cached reduced pattern, symbolic factor and numeric factor.
#[derive(Default)]
pub struct Direct {
    key: Option<(u64, Vec<u32>)>,
    reduced: Vec<u32>,
    col_ptr: Vec<usize>,
    row_idx: Vec<usize>,
    gather: Vec<usize>,
    values: Vec<f64>,
    factored: Vec<f64>,
    symbolic: Option<SymbolicCholesky<usize>>,
    l_values: Vec<f64>,
    fmem: Option<MemBuffer>,
    smem: Option<MemBuffer>,
    has_factor: bool,
    /// Coordinates of the unknowns (`dim` per unknown): when set (and of the right length),
    /// the fill-reducing ordering is a nested dissection guided by them
    /// ([`nested_dissection`]) instead of AMD.
    pub coordinates: Option<(Vec<f64>, usize)>,
    /// Symbolic analyses performed so far.
    pub symbolic_count: u64,
    /// Numeric factorisations performed so far.
    pub numeric_count: u64,
}

impl std::fmt::Debug for Direct {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Direct")
            .field("unknowns", &(self.col_ptr.len().saturating_sub(1)))
            .field("symbolic_count", &self.symbolic_count)
            .field("numeric_count", &self.numeric_count)
            .finish()
    }
}

/// What the direct solve reused.
#[derive(Clone, Copy, Debug, Default)]
pub struct DirectReuse {
    /// The symbolic factorisation was reused.
    pub symbolic: bool,
    /// The numeric factor was reused (matrix values unchanged).
    pub numeric: bool,
    /// Seconds in the symbolic analysis (0 when reused).
    pub symbolic_seconds: f64,
    /// Seconds in the numeric factorisation (0 when reused).
    pub numeric_seconds: f64,
    /// Seconds in the triangular solves.
    pub solve_seconds: f64,
}

impl Direct {
    /// Solves `K x = b` with the unknowns in `pinned` fixed to zero. `reuse_symbolic = false`
    /// forces a new analysis (for benchmarks); `reuse_numeric = false` forces a refactorisation.
    pub fn solve(
        &mut self,
        a: &Assembly,
        pinned: &[u32],
        b: &[f64],
        x: &mut [f64],
        reuse_symbolic: bool,
        reuse_numeric: bool,
    ) -> Result<DirectReuse, SolveError> {
        assert!(
            b.len() == a.n() && x.len() == a.n(),
            "b and x must have one entry per unknown"
        );
        let mut info = self.factor(a, pinned, reuse_symbolic, reuse_numeric)?;
        let symbolic = self.symbolic.as_ref().expect("symbolic factor");
        let t2 = std::time::Instant::now();
        let nr = self.col_ptr.len() - 1;
        let mut rhs = vec![0.0; nr];
        for (u, &r) in self.reduced.iter().enumerate() {
            if r != u32::MAX {
                rhs[r as usize] = b[u];
            }
        }
        let llt = LltRef::<usize, f64>::new(symbolic, &self.l_values);
        let smem = self.smem.as_mut().expect("solve scratch");
        llt.solve_in_place_with_conj(
            Conj::No,
            MatMut::from_column_major_slice_mut(&mut rhs, nr, 1),
            Par::Seq,
            MemStack::new(smem),
        );
        for (u, &r) in self.reduced.iter().enumerate() {
            x[u] = if r == u32::MAX { 0.0 } else { rhs[r as usize] };
        }
        info.solve_seconds = t2.elapsed().as_secs_f64();
        Ok(info)
    }

    /// The factor of `K` with the unknowns in `pinned` removed, brought up to date: the
    /// symbolic analysis redone when the pattern or the pinned set changed, the numeric
    /// factorisation when the values changed. [`Self::solve`] calls it first, so a factor
    /// prepared ahead (concurrently with other work) is found current there.
    pub fn factor(
        &mut self,
        a: &Assembly,
        pinned: &[u32],
        reuse_symbolic: bool,
        reuse_numeric: bool,
    ) -> Result<DirectReuse, SolveError> {
        let mut info = DirectReuse::default();
        let key = (a.pattern_id(), pinned.to_vec());
        let t0 = std::time::Instant::now();
        if self.key.as_ref() != Some(&key) || !reuse_symbolic || self.symbolic.is_none() {
            self.build_pattern(a, pinned);
            let nr = self.col_ptr.len() - 1;
            let sym =
                SymbolicSparseColMatRef::new_checked(nr, nr, &self.col_ptr, None, &self.row_idx);
            let order = self.coordinates.as_ref().and_then(|(c, dim)| {
                (c.len() == dim * a.n()).then(|| {
                    // the order of every unknown, then the pinned ones dropped
                    let full = nested_dissection(c, *dim, &a.offsets, &a.cols);
                    let fwd: Vec<usize> = full
                        .into_iter()
                        .filter(|&u| self.reduced[u] != u32::MAX)
                        .map(|u| self.reduced[u] as usize)
                        .collect();
                    let mut inv = vec![0usize; fwd.len()];
                    for (k, &o) in fwd.iter().enumerate() {
                        inv[o] = k;
                    }
                    (fwd, inv)
                })
            });
            let ordering = match &order {
                Some((fwd, inv)) => {
                    SymmetricOrdering::Custom(faer::perm::PermRef::new_checked(fwd, inv, nr))
                }
                None => SymmetricOrdering::Amd,
            };
            let symbolic = factorize_symbolic_cholesky(
                sym,
                Side::Lower,
                ordering,
                // supernodal always: faer's flop-ratio rule picks the simplicial numeric
                // factorisation for the small systems of a moving-particle run (n = 30
                // cavity: 900 unknowns, refactored every step), which was 11 % slower
                // per step there; from a few thousand unknowns both choose supernodal
                CholeskySymbolicParams {
                    supernodal_flop_ratio_threshold: SupernodalThreshold::FORCE_SUPERNODAL,
                    ..Default::default()
                },
            )
            .map_err(|e| SolveError::Backend(format!("symbolic Cholesky: {e:?}")))?;
            self.l_values = vec![0.0; symbolic.len_val()];
            self.fmem = Some(MemBuffer::new(
                symbolic.factorize_numeric_llt_scratch::<f64>(Par::Seq, Default::default()),
            ));
            self.smem = Some(MemBuffer::new(
                symbolic.solve_in_place_scratch::<f64>(1, Par::Seq),
            ));
            self.symbolic = Some(symbolic);
            self.key = Some(key);
            self.has_factor = false;
            self.symbolic_count += 1;
            info.symbolic_seconds = t0.elapsed().as_secs_f64();
        } else {
            info.symbolic = true;
        }
        for (v, &g) in self.values.iter_mut().zip(&self.gather) {
            *v = a.values[g];
        }
        let symbolic = self.symbolic.as_ref().expect("symbolic factor");
        let t1 = std::time::Instant::now();
        if self.has_factor && reuse_numeric && self.values == self.factored {
            info.numeric = true;
        } else {
            let nr = self.col_ptr.len() - 1;
            let sym =
                SymbolicSparseColMatRef::new_checked(nr, nr, &self.col_ptr, None, &self.row_idx);
            let mat = SparseColMatRef::new(sym, &self.values);
            let fmem = self.fmem.as_mut().expect("factor scratch");
            self.has_factor = false;
            symbolic
                .factorize_numeric_llt::<f64>(
                    &mut self.l_values,
                    mat,
                    Side::Lower,
                    LltRegularization::default(),
                    Par::Seq,
                    MemStack::new(fmem),
                    Default::default(),
                )
                .map_err(|e| match e {
                    faer::linalg::solvers::LltError::NonPositivePivot { index } => {
                        // `index` is in the permuted order. faer 0.24's simplicial kernel
                        // reports the failing column as `k + 1`, its supernodal kernel as `k`.
                        let index = match symbolic.raw() {
                            SymbolicCholeskyRaw::Simplicial(_) => index - 1,
                            SymbolicCholeskyRaw::Supernodal(_) => index,
                        };
                        let unknown = symbolic
                            .perm()
                            .map(|p| p.arrays().0[index])
                            .unwrap_or(index);
                        let full = self
                            .reduced
                            .iter()
                            .position(|&r| r as usize == unknown)
                            .unwrap_or(unknown);
                        SolveError::NotPositiveDefinite {
                            unknown: full,
                            particle: a.particle.get(full).map(|&p| p as usize).unwrap_or(full),
                        }
                    }
                })?;
            self.factored.clone_from(&self.values);
            self.has_factor = true;
            self.numeric_count += 1;
            info.numeric_seconds = t1.elapsed().as_secs_f64();
        }
        Ok(info)
    }

    /// Lower-triangular CSC pattern of `K` with the pinned unknowns removed.
    fn build_pattern(&mut self, a: &Assembly, pinned: &[u32]) {
        let n = a.n();
        self.reduced = vec![0; n];
        for &p in pinned {
            self.reduced[p as usize] = u32::MAX;
        }
        let mut next = 0u32;
        for r in self.reduced.iter_mut() {
            if *r != u32::MAX {
                *r = next;
                next += 1;
            }
        }
        // K symmetric: column u of the lower triangle = entries (u, v ≥ u) of CSR row u
        self.col_ptr = Vec::with_capacity(next as usize + 1);
        self.col_ptr.push(0);
        self.row_idx.clear();
        self.gather.clear();
        for u in 0..n {
            if self.reduced[u] == u32::MAX {
                continue;
            }
            for k in a.offsets[u]..a.offsets[u + 1] {
                let v = a.cols[k] as usize;
                if v >= u && self.reduced[v] != u32::MAX {
                    self.row_idx.push(self.reduced[v] as usize);
                    self.gather.push(k);
                }
            }
            self.col_ptr.push(self.row_idx.len());
        }
        self.values = vec![0.0; self.gather.len()];
        self.factored.clear();
    }
}

/// A fill-reducing ordering of the unknowns of a symmetric pattern (`offsets`/`cols`, CSR,
/// both triangles) from coordinates of the unknowns (`dim` each): nested dissection, the
/// coordinates choosing the cuts and the pattern the separators. A set of unknowns is split at
/// the median of the longer side of its bounding box; the unknowns of the lower half coupled
/// to one of the upper half form the separator, ordered after both halves, which are ordered
/// the same way down to blocks of at most `LEAF` unknowns. Any ordering factorises the same
/// matrix; this one only decides the fill. Returns `order[new] = old`.
pub fn nested_dissection(
    coords: &[f64],
    dim: usize,
    offsets: &[usize],
    cols: &[u32],
) -> Vec<usize> {
    const LEAF: usize = 16;
    let n = offsets.len().saturating_sub(1);
    assert_eq!(coords.len(), n * dim, "one point per unknown");
    let mut order = Vec::with_capacity(n);
    let mut idx: Vec<usize> = (0..n).collect();
    let mut mark = vec![0u32; n];
    let mut stamp = 0u32;
    struct Ctx<'a> {
        coords: &'a [f64],
        dim: usize,
        offsets: &'a [usize],
        cols: &'a [u32],
    }
    fn recurse(
        idx: &mut [usize],
        c: &Ctx,
        mark: &mut [u32],
        stamp: &mut u32,
        out: &mut Vec<usize>,
    ) {
        let dim = c.dim;
        if idx.len() <= LEAF || dim == 0 {
            out.extend_from_slice(idx);
            return;
        }
        let mut lo = vec![f64::INFINITY; dim];
        let mut hi = vec![f64::NEG_INFINITY; dim];
        for &i in idx.iter() {
            for a in 0..dim {
                let v = c.coords[i * dim + a];
                lo[a] = lo[a].min(v);
                hi[a] = hi[a].max(v);
            }
        }
        let axis = (0..dim)
            .max_by(|&a, &b| (hi[a] - lo[a]).total_cmp(&(hi[b] - lo[b])))
            .unwrap_or(0);
        let key = |i: &usize| c.coords[*i * dim + axis];
        let mid = idx.len() / 2;
        idx.select_nth_unstable_by(mid, |a, b| key(a).total_cmp(&key(b)));
        // idx[..mid] lower half, idx[mid..] upper half: mark the upper half
        *stamp += 1;
        let s = *stamp;
        for &i in idx[mid..].iter() {
            mark[i] = s;
        }
        // the lower half's unknowns coupled to the upper half go to the end of the lower half
        let (lower, upper) = idx.split_at_mut(mid);
        let mut keep = 0;
        for k in 0..lower.len() {
            let i = lower[k];
            let coupled = c.cols[c.offsets[i]..c.offsets[i + 1]]
                .iter()
                .any(|&j| mark[j as usize] == s);
            if !coupled {
                lower.swap(keep, k);
                keep += 1;
            }
        }
        if keep == 0 {
            // no separation possible (the lower half is all separator): one block
            out.extend_from_slice(lower);
            out.extend_from_slice(upper);
            return;
        }
        let (inner, sep) = lower.split_at_mut(keep);
        let sep: Vec<usize> = sep.to_vec();
        recurse(inner, c, mark, stamp, out);
        recurse(upper, c, mark, stamp, out);
        out.extend_from_slice(&sep);
    }
    let ctx = Ctx {
        coords,
        dim,
        offsets,
        cols,
    };
    recurse(&mut idx, &ctx, &mut mark, &mut stamp, &mut order);
    order
}
