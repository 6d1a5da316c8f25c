//! A rank's rows of the global matrix and its halo plan.
//!
//! Rank `r` owns the rows of its unknowns. Their columns are its own unknowns and a halo: the
//! unknowns of other ranks within `h` of one of its own (the pattern of `K` is the neighbour
//! graph). Rank `r` sends to `q` its own unknowns that are columns of `q`'s rows, read from the
//! (replicated) pattern of `q`'s rows — in a fully distributed setting one message of indices
//! per neighbour and pattern. Both sides list those unknowns in ascending global order, so a
//! message is a bare array of values.

use crate::poisson::amg::{CsrMatrix, CsrRef};

/// The own rows of a global symmetric CSR matrix, with local column numbers (own unknowns
/// `0..own.len()`, then the halo), and the exchange plan of the halo.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct LocalRows {
    /// Global index of each own unknown, ascending.
    pub own: Vec<u32>,
    /// Global index of each halo unknown, ordered by owner rank, then global index.
    pub halo: Vec<u32>,
    /// Row starts of the own rows (local CSR).
    pub offsets: Vec<usize>,
    /// Local column of each entry.
    pub cols: Vec<u32>,
    /// Value of each entry.
    pub values: Vec<f64>,
    /// Position of each local entry in the global value array (to refill the values).
    source: Vec<usize>,
    /// Per neighbour rank: the own (local) unknowns it needs, ascending global index.
    pub sends: Vec<(usize, Vec<u32>)>,
    /// Per neighbour rank: the range of `halo` it sends, in the same order as `sends`' ranks
    /// appear on its side.
    pub recvs: Vec<(usize, std::ops::Range<usize>)>,
    /// The own–own block (columns own only): the block-Jacobi preconditioner's matrix.
    pub block: CsrMatrix,
    /// Position of each block entry in `values`.
    block_source: Vec<usize>,
    /// The overlapping block: the rows of the own and the halo unknowns, columns among them
    /// (the halo rows cut where they reach beyond the halo), local numbering, columns
    /// ascending: the additive Schwarz preconditioner's matrix (overlap `h`).
    pub ext: CsrMatrix,
    /// Position of each `ext` entry in the global value array.
    ext_source: Vec<usize>,
}

impl LocalRows {
    /// The rows of `rank` from a global matrix `a` and the owner of every unknown.
    pub fn new(a: CsrRef<'_>, owner: &[u32], rank: usize) -> Self {
        let own: Vec<u32> = (0..owner.len() as u32)
            .filter(|&u| owner[u as usize] as usize == rank)
            .collect();
        // halo: the columns of own rows owned elsewhere, by (owner, global index)
        let mut halo: Vec<u32> = own
            .iter()
            .flat_map(|&u| {
                let u = u as usize;
                a.cols[a.offsets[u]..a.offsets[u + 1]].iter().copied()
            })
            .filter(|&c| owner[c as usize] as usize != rank)
            .collect();
        halo.sort_unstable_by_key(|&c| (owner[c as usize], c));
        halo.dedup();
        // global → local column (own by position in `own`, halo after)
        let local = |c: u32| -> u32 {
            if owner[c as usize] as usize == rank {
                own.binary_search(&c).expect("own unknown") as u32
            } else {
                let k = halo
                    .binary_search_by_key(&(owner[c as usize], c), |&h| (owner[h as usize], h))
                    .expect("halo unknown");
                (own.len() + k) as u32
            }
        };
        let mut offsets = Vec::with_capacity(own.len() + 1);
        offsets.push(0);
        let (mut cols, mut source) = (Vec::new(), Vec::new());
        let mut block = CsrMatrix {
            ncols: own.len(),
            offsets: vec![0],
            ..Default::default()
        };
        let mut block_source = Vec::new();
        for &u in &own {
            let u = u as usize;
            for k in a.offsets[u]..a.offsets[u + 1] {
                let c = a.cols[k];
                let lc = local(c);
                cols.push(lc);
                source.push(k);
                if (lc as usize) < own.len() {
                    block.cols.push(lc);
                    block_source.push(cols.len() - 1);
                }
            }
            offsets.push(cols.len());
            block.offsets.push(block.cols.len());
        }
        // what each other rank needs from this one: the columns of its rows owned here, read
        // from its rows (not from the transpose: a pair at `r = h` within rounding can be in
        // one row and not in the other, so the pattern need not be exactly symmetric)
        let mut wanted: Vec<(u32, u32)> = (0..owner.len())
            .filter(|&u| owner[u] as usize != rank)
            .flat_map(|u| {
                a.cols[a.offsets[u]..a.offsets[u + 1]]
                    .iter()
                    .filter(|&&c| owner[c as usize] as usize == rank)
                    .map(move |&c| (owner[u], c))
            })
            .collect();
        wanted.sort_unstable();
        wanted.dedup();
        let mut sends: Vec<(usize, Vec<u32>)> = Vec::new();
        for (q, c) in wanted {
            let li = own.binary_search(&c).expect("own unknown") as u32;
            match sends.last_mut() {
                Some((r, list)) if *r == q as usize => list.push(li),
                _ => sends.push((q as usize, vec![li])),
            }
        }
        let mut recvs: Vec<(usize, std::ops::Range<usize>)> = Vec::new();
        for (k, &c) in halo.iter().enumerate() {
            let q = owner[c as usize] as usize;
            match recvs.last_mut() {
                Some((r, range)) if *r == q => range.end = k + 1,
                _ => recvs.push((q, k..k + 1)),
            }
        }
        // the overlapping block: own rows, then the halo's rows cut to own ∪ halo
        let mut ext = CsrMatrix {
            ncols: own.len() + halo.len(),
            offsets: vec![0],
            ..Default::default()
        };
        let mut ext_source = Vec::new();
        let lookup = |c: u32| -> Option<u32> {
            if owner[c as usize] as usize == rank {
                own.binary_search(&c).ok().map(|k| k as u32)
            } else {
                halo.binary_search_by_key(&(owner[c as usize], c), |&h| (owner[h as usize], h))
                    .ok()
                    .map(|k| (own.len() + k) as u32)
            }
        };
        for &g in own.iter().chain(&halo) {
            let g = g as usize;
            let mut row: Vec<(u32, usize)> = (a.offsets[g]..a.offsets[g + 1])
                .filter_map(|k| lookup(a.cols[k]).map(|c| (c, k)))
                .collect();
            row.sort_unstable();
            for (c, k) in row {
                ext.cols.push(c);
                ext_source.push(k);
            }
            ext.offsets.push(ext.cols.len());
        }
        let mut rows = LocalRows {
            ext,
            ext_source,
            own,
            halo,
            offsets,
            values: vec![0.0; cols.len()],
            cols,
            source,
            sends,
            recvs,
            block,
            block_source,
        };
        rows.refill(a.values);
        rows
    }

    /// Copies the values of the global matrix (same pattern) into the own rows and the block.
    pub fn refill(&mut self, global_values: &[f64]) {
        for (v, &k) in self.values.iter_mut().zip(&self.source) {
            *v = global_values[k];
        }
        self.block.values = self.block_source.iter().map(|&k| self.values[k]).collect();
        self.ext.values = self.ext_source.iter().map(|&k| global_values[k]).collect();
    }

    /// Own unknowns.
    pub fn n_own(&self) -> usize {
        self.own.len()
    }

    /// `y = A x` over the own rows, `x` holding the own values then the halo's.
    pub fn spmv(&self, x: &[f64], y: &mut [f64]) {
        CsrRef {
            offsets: &self.offsets,
            cols: &self.cols,
            values: &self.values,
        }
        .spmv(x, y);
    }

    /// Values sent per exchange (the halo of the other ranks from this one).
    pub fn send_count(&self) -> usize {
        self.sends.iter().map(|(_, l)| l.len()).sum()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The 1D Laplacian on 8 unknowns (stencil radius 2), split into 3 ranks.
    fn chain() -> (Vec<usize>, Vec<u32>, Vec<f64>) {
        let n = 8i64;
        let (mut off, mut cols, mut vals) = (vec![0], vec![], vec![]);
        for i in 0..n {
            for j in (i - 2).max(0)..=(i + 2).min(n - 1) {
                cols.push(j as u32);
                vals.push(if i == j { 4.0 } else { -1.0 } + 0.01 * (i * 10 + j) as f64);
            }
            off.push(cols.len());
        }
        (off, cols, vals)
    }

    #[test]
    fn halo_plans_match_between_ranks_and_products_agree() {
        let (off, cols, vals) = chain();
        let a = CsrRef {
            offsets: &off,
            cols: &cols,
            values: &vals,
        };
        let owner = [0, 0, 0, 1, 1, 1, 2, 2];
        let rows: Vec<LocalRows> = (0..3).map(|r| LocalRows::new(a, &owner, r)).collect();
        assert_eq!(rows[1].own, vec![3, 4, 5]);
        assert_eq!(rows[1].halo, vec![1, 2, 6, 7]);
        // what r sends to q is what q receives from r, in the same order
        for r in 0..3 {
            for (q, list) in &rows[r].sends {
                let sent: Vec<u32> = list.iter().map(|&l| rows[r].own[l as usize]).collect();
                let (_, range) = rows[*q].recvs.iter().find(|(s, _)| *s == r).unwrap();
                assert_eq!(sent, rows[*q].halo[range.clone()].to_vec());
            }
        }
        // the distributed product equals the global one
        let x: Vec<f64> = (0..8).map(|i| (i as f64 * 0.7).sin()).collect();
        let mut y = vec![0.0; 8];
        a.spmv(&x, &mut y);
        for rr in &rows {
            let xl: Vec<f64> = rr
                .own
                .iter()
                .chain(&rr.halo)
                .map(|&g| x[g as usize])
                .collect();
            let mut yl = vec![0.0; rr.n_own()];
            rr.spmv(&xl, &mut yl);
            for (k, &g) in rr.own.iter().enumerate() {
                assert_eq!(yl[k], y[g as usize]);
            }
            // the block holds the own columns only
            assert!(rr.block.cols.iter().all(|&c| (c as usize) < rr.n_own()));
        }
    }
}
