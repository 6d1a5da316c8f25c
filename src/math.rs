//! Small fixed-size vector helpers over `[f64; D]`, and [`in_pool`] for the entry points that run
//! many parallel loops.
//!
//! Particle state is stored as `Vec<[f64; D]>` so that kiddo, faer and rayon can all borrow it
//! without copies; these helpers keep the arithmetic on those arrays readable.

/// The one scalar type of the crate.
pub type Real = f64;

/// A point or vector in `D` dimensions.
pub type Vector<const D: usize> = [f64; D];

/// `a · b`.
#[inline(always)]
pub fn dot<const D: usize>(a: &[f64; D], b: &[f64; D]) -> f64 {
    let mut s = 0.0;
    for k in 0..D {
        s += a[k] * b[k];
    }
    s
}

/// `|a|²`.
#[inline(always)]
pub fn norm2<const D: usize>(a: &[f64; D]) -> f64 {
    dot(a, a)
}

/// `a − b`.
#[inline(always)]
pub fn sub<const D: usize>(a: &[f64; D], b: &[f64; D]) -> [f64; D] {
    std::array::from_fn(|k| a[k] - b[k])
}

/// `a + b`.
#[inline(always)]
pub fn add<const D: usize>(a: &[f64; D], b: &[f64; D]) -> [f64; D] {
    std::array::from_fn(|k| a[k] + b[k])
}

/// `s a`.
#[inline(always)]
pub fn scale<const D: usize>(s: f64, a: &[f64; D]) -> [f64; D] {
    std::array::from_fn(|k| s * a[k])
}

/// `a + s b`.
#[inline(always)]
pub fn axpy<const D: usize>(a: &[f64; D], s: f64, b: &[f64; D]) -> [f64; D] {
    std::array::from_fn(|k| a[k] + s * b[k])
}

/// True when every component is finite.
#[inline(always)]
pub fn is_finite<const D: usize>(a: &[f64; D]) -> bool {
    a.iter().all(|v| v.is_finite())
}

/// The first `i` in `0..n` with `bad(i)`, tested in parallel chunks of 4 096 indices (each
/// chunk a sequential scan; a per-index parallel search checks a shared flag at every index:
/// the input checks of a 2D 10⁶ step's particles took 12 ms with it, 3.5–4.5 ms chunked).
pub fn first_where(n: usize, bad: impl Fn(usize) -> bool + Sync) -> Option<usize> {
    const CHUNK: usize = 4096;
    use rayon::prelude::*;
    (0..n.div_ceil(CHUNK)).into_par_iter().find_map_first(|c| {
        let (start, end) = (c * CHUNK, ((c + 1) * CHUNK).min(n));
        (start..end).find(|&i| bad(i))
    })
}

/// Runs `f` on a thread of rayon's pool (at once when already on one). A parallel loop started
/// from outside the pool is sent to it and waited for — a futex wake-up and sleep per loop;
/// the entry points that run hundreds of loops (a flow step, a projection, a prediction) go
/// through this so that those loops split inside the pool instead. Measured with perf on the
/// Lagrangian cavity at 2 500 particles and one thread: the step took 52 ms, a third of it in
/// those wake-ups, and 27 ms from a pool thread.
pub fn in_pool<R: Send>(f: impl FnOnce() -> R + Send) -> R {
    if rayon::current_thread_index().is_some() {
        f()
    } else {
        rayon::scope(|_| f())
    }
}

/// Mutable slices cut together at a row boundary: a slice of per-entry values (a CSR's
/// columns or values, cut at the row's first entry), [`PerRow`] (one value per row, cut at the
/// row), or a pair of them (nest pairs for more).
pub(crate) trait SplitParts: Sized + Send {
    /// The parts before and from the boundary after `rows` rows, `entries` entries.
    fn split_parts(self, rows: usize, entries: usize) -> (Self, Self);
}

impl<T: Send> SplitParts for &mut [T] {
    fn split_parts(self, _rows: usize, entries: usize) -> (Self, Self) {
        self.split_at_mut(entries)
    }
}

/// A slice with one value per row, for [`row_pieces`].
pub(crate) struct PerRow<'a, T>(pub &'a mut [T]);

impl<T: Send> SplitParts for PerRow<'_, T> {
    fn split_parts(self, rows: usize, _entries: usize) -> (Self, Self) {
        let (a, b) = self.0.split_at_mut(rows);
        (PerRow(a), PerRow(b))
    }
}

impl<A: SplitParts, B: SplitParts> SplitParts for (A, B) {
    fn split_parts(self, rows: usize, entries: usize) -> (Self, Self) {
        let (a0, a1) = self.0.split_parts(rows, entries);
        let (b0, b1) = self.1.split_parts(rows, entries);
        ((a0, b0), (a1, b1))
    }
}

/// The rows `0..n` as parallel pieces `(rows, parts)`, `parts` cut at the rows' first entries:
/// `start(i)` is where row `i` begins in `parts`' per-entry slices (nondecreasing, `start(n)` their length, e.g.
/// CSR offsets), and a piece's `parts` begin at `start(rows.start)`. Rows are halved while a
/// piece holds more than `min_rows` and rayon asks for work, so the pieces depend on the
/// threads: what is computed for a row must not (a reduction over the pieces sees them in row
/// order). Allocates nothing — the fill loops of a moving step split their outputs with it.
pub(crate) fn row_pieces<P: SplitParts>(
    n: usize,
    min_rows: usize,
    start: impl Fn(usize) -> usize + Sync + Send,
    parts: P,
) -> impl rayon::iter::ParallelIterator<Item = (std::ops::Range<usize>, P)> {
    use rayon::iter::ParallelIterator;
    let first = start(0);
    rayon::iter::split((0..n, first, parts), move |(rows, base, parts)| {
        if rows.len() <= min_rows.max(1) {
            return ((rows, base, parts), None);
        }
        let mid = rows.start + rows.len() / 2;
        let at = start(mid);
        let (a, b) = parts.split_parts(mid - rows.start, at - base);
        ((rows.start..mid, base, a), Some((mid..rows.end, at, b)))
    })
    .map(|(rows, _, parts)| (rows, parts))
}

/// `Σ_k values[k] x[cols[k]]`, one row of a sparse product: four partial sums over the entries
/// in turn (entry `k` into sum `k mod 4`), added as `(s0 + s1) + (s2 + s3)`, then the last
/// `len mod 4` entries in order. Four independent chains instead of one: a 3D Poisson row
/// (≈ 110 entries) is otherwise bound by the latency of its additions (stream bandwidth of the
/// product 34 → 38–51 GB/s at 3D 10⁵; 2D rows of ≈ 27 entries gain little). Deterministic: the
/// order depends on the row only, not on threads. The values may be stored in `f32` (the AMG
/// V-cycle's copies, [`crate::poisson::AmgParams::single_precision`]); the sums are in `f64`.
#[inline]
pub fn sparse_dot<V: Copy + Into<f64>>(values: &[V], cols: &[u32], x: &[f64]) -> f64 {
    let (vc, vr) = values.as_chunks::<4>();
    let (cc, cr) = cols[..values.len()].as_chunks::<4>();
    let mut acc = [0.0f64; 4];
    for (v, c) in vc.iter().zip(cc) {
        for t in 0..4 {
            acc[t] += v[t].into() * x[c[t] as usize];
        }
    }
    let mut s = (acc[0] + acc[1]) + (acc[2] + acc[3]);
    for (&v, &c) in vr.iter().zip(cr) {
        s += v.into() * x[c as usize];
    }
    s
}

/// [`sparse_dot`] of `K` columns at once (`x[j][c]`): each column's sum grouped exactly as
/// `sparse_dot` groups it, so that a product of several right sides gives the bits of one.
/// (`sparse_dot` is not this with `K = 1`: that build's products were slower, 3D 10⁵ SpMV
/// 39–42 against 47–49 GB/s.)
#[inline]
pub fn sparse_dot_multi<const K: usize>(values: &[f64], cols: &[u32], x: &[[f64; K]]) -> [f64; K] {
    let (vc, vr) = values.as_chunks::<4>();
    let (cc, cr) = cols[..values.len()].as_chunks::<4>();
    let mut acc = [[0.0f64; K]; 4];
    for (v, c) in vc.iter().zip(cc) {
        for t in 0..4 {
            let xj = &x[c[t] as usize];
            for k in 0..K {
                acc[t][k] += v[t] * xj[k];
            }
        }
    }
    let mut s: [f64; K] =
        std::array::from_fn(|k| (acc[0][k] + acc[1][k]) + (acc[2][k] + acc[3][k]));
    for (v, &c) in vr.iter().zip(cr) {
        let xj = &x[c as usize];
        for k in 0..K {
            s[k] += v * xj[k];
        }
    }
    s
}

#[cfg(test)]
mod sparse_tests {
    use super::{sparse_dot, sparse_dot_multi};

    #[test]
    fn the_partial_sums_follow_the_documented_grouping_and_the_columns_agree() {
        let x: Vec<[f64; 3]> = (0..40)
            .map(|j| {
                let t = j as f64;
                [(0.7 * t).sin(), 1.0 + (0.3 * t).cos(), -0.5 * t]
            })
            .collect();
        for len in 0..14 {
            let values: Vec<f64> = (0..len).map(|k| 1.0 / (k as f64 + 1.3)).collect();
            let cols: Vec<u32> = (0..len).map(|k| ((7 * k + 3) % 40) as u32).collect();
            for c in 0..3 {
                let xc: Vec<f64> = x.iter().map(|v| v[c]).collect();
                // the documented grouping, written out
                let mut acc = [0.0; 4];
                let full = len / 4 * 4;
                for k in 0..full {
                    acc[k % 4] += values[k] * xc[cols[k] as usize];
                }
                let mut want = (acc[0] + acc[1]) + (acc[2] + acc[3]);
                for k in full..len {
                    want += values[k] * xc[cols[k] as usize];
                }
                let got = sparse_dot(&values, &cols, &xc);
                assert_eq!(got.to_bits(), want.to_bits(), "len {len} column {c}");
                let multi = sparse_dot_multi(&values, &cols, &x);
                assert_eq!(multi[c].to_bits(), got.to_bits(), "len {len} column {c}");
                let naive: f64 = (0..len).map(|k| values[k] * xc[cols[k] as usize]).sum();
                assert!((got - naive).abs() <= 1e-14 * (1.0 + naive.abs()));
            }
        }
    }
}

#[cfg(test)]
mod first_where_tests {
    use super::first_where;

    /// The smallest bad index whatever chunk it falls in and however many chunks are bad.
    #[test]
    fn first_where_is_the_smallest_bad_index() {
        let n = 50_000;
        assert_eq!(first_where(n, |_| false), None);
        assert_eq!(first_where(0, |_| true), None);
        for bad in [
            vec![0],
            vec![4095],
            vec![4096, 4097],
            vec![49_999],
            vec![12_000, 8_200, 30_000],
        ] {
            let want = bad.iter().copied().min();
            let got = crate::math::in_pool(|| first_where(n, |i| bad.contains(&i)));
            assert_eq!(got, want, "{bad:?}");
        }
    }
}
