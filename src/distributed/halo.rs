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

/// The own rows' CSR: row starts, local columns, the entry of `a` each came from, the
/// own–own block and the position of each block entry.
type OwnRows = (Vec<usize>, Vec<u32>, Vec<usize>, CsrMatrix, Vec<usize>);

/// The rows `rows` of `a` (in this order) with their columns renumbered by `local` (own
/// unknowns below `n_own`, then the halo), sorted by local column when `sorted` (else in `a`'s
/// order), and their own–own block.
fn own_rows(
    a: CsrRef<'_>,
    rows: &[u32],
    n_own: usize,
    local: impl Fn(u32) -> u32,
    sorted: bool,
) -> OwnRows {
    let mut offsets = Vec::with_capacity(rows.len() + 1);
    offsets.push(0);
    let (mut cols, mut source) = (Vec::new(), Vec::new());
    let mut block = CsrMatrix {
        ncols: n_own,
        offsets: vec![0],
        ..Default::default()
    };
    let mut block_source = Vec::new();
    let mut row: Vec<(u32, usize)> = Vec::new();
    for &u in rows {
        let u = u as usize;
        row.clear();
        row.extend((a.offsets[u]..a.offsets[u + 1]).map(|k| (local(a.cols[k]), k)));
        if sorted {
            row.sort_unstable();
        }
        for &(lc, k) in &row {
            cols.push(lc);
            source.push(k);
            if (lc as usize) < n_own {
                block.cols.push(lc);
                block_source.push(cols.len() - 1);
            }
        }
        offsets.push(cols.len());
        block.offsets.push(block.cols.len());
    }
    (offsets, cols, source, block, block_source)
}

/// The range of each owner's run in a halo listed by owner: `(owner, range)` in order.
fn ranges_by_owner(owners: impl Iterator<Item = u32>) -> Vec<(usize, std::ops::Range<usize>)> {
    let mut recvs: Vec<(usize, std::ops::Range<usize>)> = Vec::new();
    for (k, q) in owners.enumerate() {
        let q = q as usize;
        match recvs.last_mut() {
            Some((r, range)) if *r == q => range.end = k + 1,
            _ => recvs.push((q, k..k + 1)),
        }
    }
    recvs
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
        let (offsets, cols, source, block, block_source) =
            own_rows(a, &own, own.len(), local, false);
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
        let recvs = ranges_by_owner(halo.iter().map(|&c| owner[c as usize]));
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

    /// The rows of this rank from its *local* matrix `a`: the matrix a rank assembles over its
    /// own particles and the halo of particles it received (the particle decomposition,
    /// [`super::decomposition`]), whose rows are complete for its own unknowns only. `gid` is
    /// the global index of each local unknown and `owner` its rank. The rows are those of the
    /// unknowns owned here, numbered as in [`Self::new`] (own unknowns by global index, then the
    /// halo by owner and global index); what each neighbour needs from this rank is learnt from
    /// the neighbour itself — each rank sends every owner the global indices of its halo from
    /// that owner (one all-gather of counts and one message per neighbour), so no rank reads
    /// another's rows. [`Self::refill`] then takes the values of `a` (same pattern). The
    /// overlapping block of the Schwarz preconditioner needs the halo's rows, which a local
    /// matrix does not have complete: `ext` is left empty. Collective.
    pub fn from_local<C: super::Comm>(a: CsrRef<'_>, gid: &[u32], owner: &[u32], comm: &C) -> Self {
        let rank = comm.rank();
        let n = gid.len();
        assert_eq!(owner.len(), n, "an owner per local unknown");
        assert_eq!(a.offsets.len(), n + 1, "a row per local unknown");
        // own local unknowns in global order
        let mut own_local: Vec<u32> = (0..n as u32)
            .filter(|&u| owner[u as usize] as usize == rank)
            .collect();
        own_local.sort_unstable_by_key(|&u| gid[u as usize]);
        let own: Vec<u32> = own_local.iter().map(|&u| gid[u as usize]).collect();
        assert!(
            own.windows(2).all(|w| w[0] < w[1]),
            "global indices of the own unknowns must be distinct"
        );
        let mut halo_key: Vec<(u32, u32)> = own_local
            .iter()
            .flat_map(|&u| {
                let u = u as usize;
                a.cols[a.offsets[u]..a.offsets[u + 1]].iter().copied()
            })
            .filter(|&c| owner[c as usize] as usize != rank)
            .map(|c| (owner[c as usize], gid[c as usize]))
            .collect();
        halo_key.sort_unstable();
        halo_key.dedup();
        let halo: Vec<u32> = halo_key.iter().map(|k| k.1).collect();
        let local = |c: u32| -> u32 {
            let (o, g) = (owner[c as usize], gid[c as usize]);
            if o as usize == rank {
                own.binary_search(&g).expect("own unknown") as u32
            } else {
                let k = halo_key.binary_search(&(o, g)).expect("halo unknown");
                (own.len() + k) as u32
            }
        };
        let (offsets, cols, source, block, block_source) =
            own_rows(a, &own_local, own.len(), local, true);
        let recvs = ranges_by_owner(halo_key.iter().map(|k| k.0));
        // ask each owner for its unknowns in this rank's halo; answer the others' requests
        let mut counts = vec![0usize; comm.size()];
        for (q, r) in &recvs {
            counts[*q] = r.len();
        }
        let incoming = comm.transpose_counts(&counts);
        let requests: Vec<(usize, Vec<f64>)> = recvs
            .iter()
            .map(|(q, r)| (*q, halo[r.clone()].iter().map(|&g| g as f64).collect()))
            .collect();
        let mut asked: Vec<(usize, Vec<f64>)> = incoming
            .iter()
            .enumerate()
            .filter(|&(q, &c)| q != rank && c > 0)
            .map(|(q, &c)| (q, vec![0.0; c]))
            .collect();
        comm.exchange(&requests, &mut asked);
        let sends: Vec<(usize, Vec<u32>)> = asked
            .into_iter()
            .map(|(q, list)| {
                let local: Vec<u32> = list
                    .iter()
                    .map(|&g| {
                        own.binary_search(&(g as u32))
                            .expect("a neighbour asks only for unknowns owned here")
                            as u32
                    })
                    .collect();
                (q, local)
            })
            .collect();
        let mut rows = LocalRows {
            ext: CsrMatrix::default(),
            ext_source: Vec::new(),
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

#[cfg(test)]
mod local_tests {
    use super::*;
    use crate::distributed::partition::rcb;
    use crate::distributed::{Comm, ThreadComm};

    /// A 2D grid of `m × m` unknowns with a radius-2 stencil (a particle matrix's pattern in
    /// miniature), values that differ per entry but keep it symmetric.
    fn grid(m: usize) -> (Vec<usize>, Vec<u32>, Vec<f64>, Vec<f64>) {
        let (mut off, mut cols, mut vals) = (vec![0], vec![], vec![]);
        let mut pos = Vec::new();
        for i in 0..m * m {
            let (xi, yi) = ((i % m) as i64, (i / m) as i64);
            pos.extend([xi as f64, yi as f64]);
            for j in 0..m * m {
                let (xj, yj) = ((j % m) as i64, (j / m) as i64);
                let d2 = (xi - xj).pow(2) + (yi - yj).pow(2);
                if d2 <= 4 {
                    cols.push(j as u32);
                    let s = (i.min(j) * 31 + i.max(j) * 7) as f64;
                    vals.push(if i == j { 20.0 } else { -1.0 - 0.001 * s });
                }
            }
            off.push(cols.len());
        }
        (off, cols, vals, pos)
    }

    #[test]
    fn rows_from_local_matrices_equal_the_rows_of_the_global_one() {
        let m = 12;
        let (off, cols, vals, pos) = grid(m);
        let a = CsrRef {
            offsets: &off,
            cols: &cols,
            values: &vals,
        };
        let ranks = 4;
        let owner = rcb(&pos, 2, ranks);
        let out = ThreadComm::run(ranks, |c| {
            let r = c.rank();
            // the local set: own unknowns and everything within two hops, in a scrambled order
            let mut near = vec![false; m * m];
            for u in (0..m * m).filter(|&u| owner[u] as usize == r) {
                near[u] = true;
                for &v in &cols[off[u]..off[u + 1]] {
                    near[v as usize] = true;
                    for &w in &cols[off[v as usize]..off[v as usize + 1]] {
                        near[w as usize] = true;
                    }
                }
            }
            let mut set: Vec<u32> = (0..(m * m) as u32).filter(|&u| near[u as usize]).collect();
            set.sort_unstable_by_key(|&u| (u * 7919) % 1009);
            let local_of = |g: u32| set.iter().position(|&s| s == g);
            // local rows: complete for own unknowns; a halo unknown's row cut to the local set
            // and its values spoiled (they must not be read)
            let (mut lo, mut lc, mut lv) = (vec![0], vec![], vec![]);
            for &g in &set {
                let g = g as usize;
                let mut row: Vec<(u32, f64)> = (off[g]..off[g + 1])
                    .filter_map(|k| {
                        local_of(cols[k]).map(|l| {
                            let spoil = if owner[g] as usize == r { 1.0 } else { 1e6 };
                            (l as u32, vals[k] * spoil)
                        })
                    })
                    .collect();
                row.sort_unstable_by_key(|e| e.0);
                for (l, v) in row {
                    lc.push(l);
                    lv.push(v);
                }
                lo.push(lc.len());
            }
            let local = CsrRef {
                offsets: &lo,
                cols: &lc,
                values: &lv,
            };
            let gid: Vec<u32> = set.clone();
            let own: Vec<u32> = set.iter().map(|&g| owner[g as usize]).collect();
            LocalRows::from_local(local, &gid, &own, &c)
        });
        let x: Vec<f64> = (0..m * m).map(|i| (i as f64 * 0.37).sin()).collect();
        let mut y = vec![0.0; m * m];
        a.spmv(&x, &mut y);
        for (r, rows) in out.iter().enumerate() {
            let reference = LocalRows::new(a, &owner, r);
            assert_eq!(rows.own, reference.own);
            assert_eq!(rows.halo, reference.halo);
            assert_eq!(
                rows.sends, reference.sends,
                "rank {r}: learnt from the neighbours"
            );
            assert_eq!(rows.recvs, reference.recvs);
            assert_eq!(rows.offsets, reference.offsets);
            for i in 0..rows.n_own() {
                let sorted = |rr: &LocalRows| {
                    let mut e: Vec<(u32, u64)> = (rr.offsets[i]..rr.offsets[i + 1])
                        .map(|k| (rr.cols[k], rr.values[k].to_bits()))
                        .collect();
                    e.sort_unstable();
                    e
                };
                assert_eq!(sorted(rows), sorted(&reference), "rank {r}, row {i}");
            }
            assert_eq!(rows.block.offsets, reference.block.offsets);
            let xl: Vec<f64> = rows
                .own
                .iter()
                .chain(&rows.halo)
                .map(|&g| x[g as usize])
                .collect();
            let mut yl = vec![0.0; rows.n_own()];
            rows.spmv(&xl, &mut yl);
            for (k, &g) in rows.own.iter().enumerate() {
                assert!((yl[k] - y[g as usize]).abs() <= 1e-12 * y[g as usize].abs().max(1.0));
            }
        }
    }
}
