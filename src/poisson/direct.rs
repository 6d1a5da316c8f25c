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
        let mut info = DirectReuse::default();
        let key = (a.pattern_id(), pinned.to_vec());
        let t0 = std::time::Instant::now();
        if self.key.as_ref() != Some(&key) || !reuse_symbolic || self.symbolic.is_none() {
            self.build_pattern(a, pinned);
            let nr = self.col_ptr.len() - 1;
            let sym =
                SymbolicSparseColMatRef::new_checked(nr, nr, &self.col_ptr, None, &self.row_idx);
            let symbolic = factorize_symbolic_cholesky(
                sym,
                Side::Lower,
                SymmetricOrdering::Amd,
                CholeskySymbolicParams::default(),
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
