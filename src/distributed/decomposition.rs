//! The particles themselves decomposed over ranks (issue 18, the first stage of the full
//! decomposition): a parallel recursive coordinate bisection of space computed from every
//! rank's own particles ([`RcbTree::balance`]), migration of the particles that left a rank's
//! box to its new owner ([`migrate`]), and the halo of particles within a reach (`h + skin`) of
//! another rank's box, exchanged as flat per-particle records ([`ParticleHalo`]).
//!
//! Nothing here needs all particles on one rank: the cut values come from global counts (one
//! reduction per round of probes), the counts of every message from one all-gather of `P`
//! numbers per rank, and each owner decides from the boxes alone which of its particles another
//! rank needs. Every rank computes the same tree bit for bit (the reductions add in rank
//! order), so the owner of a position is the same everywhere.

use super::comm::Comm;
use crate::neighbors::Periodicity;

/// One node of an [`RcbTree`].
#[derive(Clone, Copy, Debug, PartialEq)]
enum Node {
    /// A rank's box.
    Leaf(u32),
    /// Points with `x[axis] <= at` go to `left`, the others to `right` (node indices).
    Cut {
        axis: usize,
        at: f64,
        left: usize,
        right: usize,
    },
}

/// A cut of space into one box per rank, the same on every rank.
#[derive(Clone, Debug, PartialEq)]
pub struct RcbTree<const D: usize> {
    nodes: Vec<Node>,
    ranks: usize,
}

/// Probes per reduction of the cut search: each round narrows the interval `PROBES + 1` times.
const PROBES: usize = 31;
/// Rounds of the cut search at most (`32^12 ≈ 10^18`: the resolution of a double).
const ROUNDS: usize = 12;

impl<const D: usize> RcbTree<D> {
    /// The boxes of `comm.size()` ranks, cut from the particles `x` of every rank (each passes
    /// its own; any distribution over the ranks gives the same tree): each cut lies across the
    /// longest extent of its group's particles, at the count that splits them in proportion
    /// to the ranks on either side (exactly, unless particles share the cut coordinate). Every
    /// rank must call it (collective).
    pub fn balance<C: Comm>(comm: &C, x: &[[f64; D]]) -> Self {
        let ranks = comm.size();
        let mut tree = RcbTree {
            nodes: Vec::with_capacity(2 * ranks),
            ranks,
        };
        let idx: Vec<u32> = (0..x.len() as u32).collect();
        tree.split(comm, x, idx, 0, ranks);
        tree
    }

    /// Builds the node for the ranks `first..first + parts` holding this rank's particles
    /// `idx`; returns its index. All ranks recurse alike (the recursion depends on `parts`
    /// only), so their collective calls match.
    fn split<C: Comm>(
        &mut self,
        comm: &C,
        x: &[[f64; D]],
        idx: Vec<u32>,
        first: usize,
        parts: usize,
    ) -> usize {
        let me = self.nodes.len();
        if parts == 1 {
            self.nodes.push(Node::Leaf(first as u32));
            return me;
        }
        self.nodes.push(Node::Leaf(u32::MAX));
        // the group's bounding box: max of (hi, −lo) over the ranks
        let mut ext = vec![f64::NEG_INFINITY; 2 * D];
        for &i in &idx {
            for a in 0..D {
                let v = x[i as usize][a];
                ext[a] = ext[a].max(v);
                ext[D + a] = ext[D + a].max(-v);
            }
        }
        let ext = comm.max(&ext);
        let axis = (0..D)
            .map(|a| (a, ext[a] + ext[D + a]))
            .fold((0, f64::NEG_INFINITY), |b, c| if c.1 > b.1 { c } else { b })
            .0;
        let left_parts = parts / 2;
        let total = comm.sum(&[idx.len() as f64])[0];
        let target = (total * left_parts as f64 / parts as f64).floor();
        let (mut lo, mut hi) = (-ext[D + axis], ext[axis]);
        let mut coord: Vec<f64> = idx.iter().map(|&i| x[i as usize][axis]).collect();
        coord.sort_unstable_by(f64::total_cmp);
        // the smallest probed value whose count (x ≤ value) reaches the target
        let mut at = hi;
        if lo.is_finite() && hi.is_finite() {
            for _ in 0..ROUNDS {
                let probes: Vec<f64> = (1..=PROBES)
                    .map(|k| lo + (hi - lo) * k as f64 / (PROBES + 1) as f64)
                    .collect();
                let counts: Vec<f64> = probes
                    .iter()
                    .map(|&p| coord.partition_point(|&c| c <= p) as f64)
                    .collect();
                let counts = comm.sum(&counts);
                // the interval [lo, hi] keeps the target between its counts
                let k = counts.iter().position(|&c| c >= target);
                match k {
                    Some(k) if counts[k] == target => {
                        at = probes[k];
                        break;
                    }
                    Some(k) => {
                        hi = probes[k];
                        if k > 0 {
                            lo = probes[k - 1];
                        }
                        at = hi;
                    }
                    None => lo = probes[PROBES - 1],
                }
                if hi - lo <= 1e-15 * (ext[axis] + ext[D + axis]).max(f64::MIN_POSITIVE) {
                    break;
                }
            }
        }
        let (l, r): (Vec<u32>, Vec<u32>) =
            idx.into_iter().partition(|&i| x[i as usize][axis] <= at);
        let left = self.split(comm, x, l, first, left_parts);
        let right = self.split(comm, x, r, first + left_parts, parts - left_parts);
        self.nodes[me] = Node::Cut {
            axis,
            at,
            left,
            right,
        };
        me
    }

    /// Number of ranks (boxes).
    pub fn ranks(&self) -> usize {
        self.ranks
    }

    /// The rank whose box holds `x`.
    pub fn owner(&self, x: &[f64; D]) -> usize {
        let mut k = 0;
        loop {
            match self.nodes[k] {
                Node::Leaf(r) => return r as usize,
                Node::Cut {
                    axis,
                    at,
                    left,
                    right,
                } => k = if x[axis] <= at { left } else { right },
            }
        }
    }

    /// Each rank's box `(lo, hi)` (unbounded where no cut limits it).
    pub fn boxes(&self) -> Vec<([f64; D], [f64; D])> {
        let mut out = vec![([f64::NEG_INFINITY; D], [f64::INFINITY; D]); self.ranks];
        let mut stack = vec![(0usize, [f64::NEG_INFINITY; D], [f64::INFINITY; D])];
        while let Some((k, lo, hi)) = stack.pop() {
            match self.nodes[k] {
                Node::Leaf(r) => out[r as usize] = (lo, hi),
                Node::Cut {
                    axis,
                    at,
                    left,
                    right,
                } => {
                    let (mut lhi, mut rlo) = (hi, lo);
                    lhi[axis] = at;
                    rlo[axis] = at;
                    stack.push((left, lo, lhi));
                    stack.push((right, rlo, hi));
                }
            }
        }
        out
    }
}

/// Distance from `x` to the box `(lo, hi)`, the nearest periodic image of `x` counted. On a
/// periodic axis the box is first clipped to the periodic cell (a tree's outer boxes are
/// unbounded: unclipped, every image of every particle would lie in them).
pub fn distance_to_box<const D: usize>(
    x: &[f64; D],
    b: &([f64; D], [f64; D]),
    periodic: &Periodicity<D>,
) -> f64 {
    let mut s = 0.0;
    for a in 0..D {
        let len = periodic.len[a];
        let (lo, hi) = if len > 0.0 {
            let cell = periodic.lo[a];
            (b.0[a].max(cell), b.1[a].min(cell + len))
        } else {
            (b.0[a], b.1[a])
        };
        let gap = |v: f64| (lo - v).max(v - hi).max(0.0);
        let mut g = gap(x[a]);
        if len > 0.0 {
            g = g.min(gap(x[a] - len)).min(gap(x[a] + len));
        }
        s += g * g;
    }
    s.sqrt()
}

/// Sends every particle to the rank whose box holds its position: `x` the positions of this
/// rank's particles, `records` their data, `width` numbers each (global ids, velocities, …,
/// whatever the caller packs, as `f64`). Returns the positions and records this rank owns
/// afterwards: the ones it kept, in their order, then those received, by sending rank and in
/// the sender's order. Collective.
pub fn migrate<C: Comm, const D: usize>(
    comm: &C,
    tree: &RcbTree<D>,
    x: &[[f64; D]],
    records: &[f64],
    width: usize,
) -> (Vec<[f64; D]>, Vec<f64>) {
    assert_eq!(records.len(), x.len() * width, "one record per particle");
    let (p, me) = (comm.size(), comm.rank());
    let mut out: Vec<Vec<f64>> = vec![Vec::new(); p];
    let (mut keep_x, mut keep_r) = (Vec::new(), Vec::new());
    for (i, xi) in x.iter().enumerate() {
        let q = tree.owner(xi);
        let rec = &records[i * width..(i + 1) * width];
        if q == me {
            keep_x.push(*xi);
            keep_r.extend_from_slice(rec);
        } else {
            out[q].extend_from_slice(xi);
            out[q].extend_from_slice(rec);
        }
    }
    let counts: Vec<usize> = out.iter().map(|o| o.len() / (D + width)).collect();
    let incoming = comm.transpose_counts(&counts);
    let sends: Vec<(usize, Vec<f64>)> = out
        .into_iter()
        .enumerate()
        .filter(|(q, o)| *q != me && !o.is_empty())
        .collect();
    let mut recvs: Vec<(usize, Vec<f64>)> = incoming
        .iter()
        .enumerate()
        .filter(|&(q, &c)| q != me && c > 0)
        .map(|(q, &c)| (q, vec![0.0; c * (D + width)]))
        .collect();
    comm.exchange(&sends, &mut recvs);
    for (_, data) in recvs {
        for rec in data.chunks_exact(D + width) {
            keep_x.push(std::array::from_fn(|a| rec[a]));
            keep_r.extend_from_slice(&rec[D..]);
        }
    }
    (keep_x, keep_r)
}

/// Which of a rank's own particles each other rank needs (those within `reach` of its box,
/// periodic images counted), and how many each other rank sends back: the plan of the particle
/// halo for one configuration.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ParticleHalo {
    /// Per neighbour rank (ascending): the own particles it needs, ascending.
    pub sends: Vec<(usize, Vec<u32>)>,
    /// Per neighbour rank (ascending): how many halo particles come from it; the halo lists
    /// them in this order, each rank's in its own order.
    pub recvs: Vec<(usize, usize)>,
}

impl ParticleHalo {
    /// The plan for this rank's own particles at `x` (collective: one all-gather of counts).
    pub fn new<C: Comm, const D: usize>(
        comm: &C,
        tree: &RcbTree<D>,
        x: &[[f64; D]],
        reach: f64,
        periodic: &Periodicity<D>,
    ) -> Self {
        let (p, me) = (comm.size(), comm.rank());
        let boxes = tree.boxes();
        let mut sends = Vec::new();
        for (q, b) in boxes.iter().enumerate().filter(|(q, _)| *q != me) {
            let list: Vec<u32> = (0..x.len() as u32)
                .filter(|&i| distance_to_box(&x[i as usize], b, periodic) < reach)
                .collect();
            if !list.is_empty() {
                sends.push((q, list));
            }
        }
        let mut counts = vec![0usize; p];
        for (q, l) in &sends {
            counts[*q] = l.len();
        }
        let recvs = comm
            .transpose_counts(&counts)
            .into_iter()
            .enumerate()
            .filter(|&(q, c)| q != me && c > 0)
            .collect();
        ParticleHalo { sends, recvs }
    }

    /// Number of halo particles this rank receives.
    pub fn n_halo(&self) -> usize {
        self.recvs.iter().map(|r| r.1).sum()
    }

    /// The halo's records (`width` numbers per particle, in the halo order) from the owners'
    /// records of their own particles (`own`, `width` numbers each). Collective.
    pub fn exchange<C: Comm>(&self, comm: &C, own: &[f64], width: usize) -> Vec<f64> {
        let sends: Vec<(usize, Vec<f64>)> = self
            .sends
            .iter()
            .map(|(q, list)| {
                let mut d = Vec::with_capacity(list.len() * width);
                for &i in list {
                    d.extend_from_slice(&own[i as usize * width..(i as usize + 1) * width]);
                }
                (*q, d)
            })
            .collect();
        let mut recvs: Vec<(usize, Vec<f64>)> = self
            .recvs
            .iter()
            .map(|&(q, c)| (q, vec![0.0; c * width]))
            .collect();
        comm.exchange(&sends, &mut recvs);
        recvs.into_iter().flat_map(|(_, d)| d).collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::distributed::ThreadComm;

    #[test]
    fn an_unbounded_box_in_a_periodic_cell_is_clipped_to_the_cell() {
        // the lower-left box of a 2 x 2 cut of the unit periodic cell, unbounded below
        let b = ([f64::NEG_INFINITY; 2], [0.5, 0.5]);
        let per = Periodicity {
            lo: [0.0; 2],
            len: [1.0; 2],
        };
        // the middle of the far box is 0.25 away on each axis (through the nearest image)
        let d = distance_to_box(&[0.75, 0.75], &b, &per);
        assert!((d - 0.25 * 2f64.sqrt()).abs() < 1e-12, "{d}");
        // near the cell's edge: close through the image across x = 1
        let d = distance_to_box(&[0.95, 0.25], &b, &per);
        assert!((d - 0.05).abs() < 1e-12, "{d}");
        // not periodic: the unbounded box holds everything below its corner
        assert_eq!(distance_to_box(&[-3.0, 0.2], &b, &Periodicity::none()), 0.0);
    }

    /// A deterministic cloud: `n` points in the unit square, dealt to the ranks round-robin
    /// (not by position: the decomposition must not depend on where they start).
    fn cloud(n: usize, rank: usize, ranks: usize) -> Vec<[f64; 2]> {
        (0..n)
            .filter(|i| i % ranks == rank)
            .map(|i| {
                let t = i as f64;
                [(0.754_877_666 * t).fract(), (0.569_840_291 * t).fract()]
            })
            .collect()
    }

    #[test]
    fn the_tree_is_the_same_on_every_rank_and_balanced() {
        let n = 1000;
        let out = ThreadComm::run(4, |c| {
            let x = cloud(n, c.rank(), 4);
            let tree = RcbTree::balance(&c, &x);
            let mine = x.iter().filter(|p| tree.owner(p) == c.rank()).count();
            (tree, c.sum(&[mine as f64])[0])
        });
        for (t, _) in &out {
            assert_eq!(t, &out[0].0, "every rank cuts alike");
        }
        let all: Vec<[f64; 2]> = (0..4).flat_map(|r| cloud(n, r, 4)).collect();
        let mut count = [0usize; 4];
        for p in &all {
            count[out[0].0.owner(p)] += 1;
        }
        assert_eq!(count, [250; 4], "equal counts on distinct coordinates");
        // a point lies in the box of its owner
        let boxes = out[0].0.boxes();
        for p in &all {
            let (lo, hi) = boxes[out[0].0.owner(p)];
            assert!((0..2).all(|a| p[a] > lo[a] && p[a] <= hi[a]), "{p:?}");
        }
        // one rank: one box, everything
        let one = ThreadComm::run(1, |c| RcbTree::balance(&c, &cloud(n, 0, 1)));
        assert!(all.iter().all(|p| one[0].owner(p) == 0));
    }

    #[test]
    fn migration_moves_every_particle_to_its_owner_exactly_once() {
        let n = 600;
        let out = ThreadComm::run(3, |c| {
            let x = cloud(n, c.rank(), 3);
            let tree = RcbTree::balance(&c, &x);
            // records: a global id and a value derived from it
            let ids: Vec<f64> = (0..n)
                .filter(|i| i % 3 == c.rank())
                .flat_map(|i| [i as f64, 0.5 * i as f64])
                .collect();
            let (y, rec) = migrate(&c, &tree, &x, &ids, 2);
            (tree, y, rec)
        });
        let mut seen = vec![0u32; n];
        for (rank, (tree, y, rec)) in out.iter().enumerate() {
            assert_eq!(rec.len(), 2 * y.len());
            for (p, r) in y.iter().zip(rec.chunks(2)) {
                assert_eq!(tree.owner(p), rank);
                let id = r[0] as usize;
                assert_eq!(r[1], 0.5 * id as f64, "a record travels whole");
                let t = id as f64;
                assert_eq!(
                    *p,
                    [(0.754_877_666 * t).fract(), (0.569_840_291 * t).fract()]
                );
                seen[id] += 1;
            }
        }
        assert!(seen.iter().all(|&s| s == 1), "every particle once");
    }

    #[test]
    fn the_halo_is_every_foreign_particle_within_reach_of_the_box() {
        let n = 800;
        let reach = 0.09;
        for periodic in [Periodicity::none(), Periodicity::all([0.0; 2], [1.0; 2])] {
            let out = ThreadComm::run(4, |c| {
                let x = cloud(n, c.rank(), 4);
                let tree = RcbTree::balance(&c, &x);
                let ids: Vec<f64> = (0..n)
                    .filter(|i| i % 4 == c.rank())
                    .map(|i| i as f64)
                    .collect();
                let (y, own) = migrate(&c, &tree, &x, &ids, 1);
                let halo = ParticleHalo::new(&c, &tree, &y, reach, &periodic);
                let got = halo.exchange(&c, &own, 1);
                assert_eq!(got.len(), halo.n_halo());
                (tree, own, got)
            });
            let tree = &out[0].0;
            let boxes = tree.boxes();
            let pos = |id: usize| {
                let t = id as f64;
                [(0.754_877_666 * t).fract(), (0.569_840_291 * t).fract()]
            };
            for (rank, (_, own, got)) in out.iter().enumerate() {
                let mut expect: Vec<usize> = (0..n)
                    .filter(|&id| {
                        tree.owner(&pos(id)) != rank
                            && distance_to_box(&pos(id), &boxes[rank], &periodic) < reach
                    })
                    .collect();
                expect.sort_unstable();
                let mut ids: Vec<usize> = got.iter().map(|&v| v as usize).collect();
                ids.sort_unstable();
                assert_eq!(ids, expect, "rank {rank}, periodic {}", periodic.any());
                assert!(!own.iter().any(|v| ids.contains(&(*v as usize))));
            }
            if periodic.any() {
                // across the wrap: rank boxes at x ≈ 0 see particles at x ≈ 1
                let wraps = out.iter().enumerate().any(|(rank, (_, _, got))| {
                    got.iter().any(|&v| {
                        let p = pos(v as usize);
                        let (lo, hi) = boxes[rank];
                        (0..2).any(|a| {
                            let d = (lo[a].max(0.0) - p[a]).max(p[a] - hi[a].min(1.0));
                            d > reach
                        })
                    })
                });
                assert!(wraps, "some halo particle comes across the periodic wrap");
            }
        }
    }
}
