//! Recursive coordinate bisection: the unknowns split into `P` parts of near-equal counts, each
//! cut across the longest extent of its points, so a part is a compact box and its boundary
//! (where the halo lies) is short.

/// The owner rank (`0..parts`) of each of the `points` (`d` coordinates each, flat). The cuts
/// depend only on the points (ties broken by index), so every rank computes the same owners.
///
/// ```
/// use gpm::distributed::partition::rcb;
/// // 8 points on a line, 4 parts: two consecutive points each
/// let x: Vec<f64> = (0..8).map(|i| i as f64).collect();
/// assert_eq!(rcb(&x, 1, 4), vec![0, 0, 1, 1, 2, 2, 3, 3]);
/// ```
pub fn rcb(points: &[f64], d: usize, parts: usize) -> Vec<u32> {
    assert!(d > 0 && points.len().is_multiple_of(d) && parts > 0);
    let n = points.len() / d;
    let mut owner = vec![0u32; n];
    let mut idx: Vec<u32> = (0..n as u32).collect();
    split(points, d, &mut idx, 0, parts, &mut owner);
    owner
}

fn split(points: &[f64], d: usize, idx: &mut [u32], first: usize, parts: usize, owner: &mut [u32]) {
    if parts == 1 || idx.len() <= 1 {
        for &i in idx.iter() {
            owner[i as usize] = first as u32;
        }
        return;
    }
    // the axis of the longest extent
    let coord = |i: u32, a: usize| points[i as usize * d + a];
    let axis = (0..d)
        .map(|a| {
            let (lo, hi) = idx
                .iter()
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), &i| {
                    (l.min(coord(i, a)), h.max(coord(i, a)))
                });
            (a, hi - lo)
        })
        .fold((0, f64::NEG_INFINITY), |b, c| if c.1 > b.1 { c } else { b })
        .0;
    let left_parts = parts / 2;
    let cut = idx.len() * left_parts / parts;
    idx.sort_unstable_by(|&i, &j| coord(i, axis).total_cmp(&coord(j, axis)).then(i.cmp(&j)));
    let (l, r) = idx.split_at_mut(cut);
    split(points, d, l, first, left_parts, owner);
    split(points, d, r, first + left_parts, parts - left_parts, owner);
}

/// Largest part size over the mean part size (1 = perfectly balanced).
pub fn imbalance(owner: &[u32], parts: usize) -> f64 {
    let mut count = vec![0usize; parts];
    for &o in owner {
        count[o as usize] += 1;
    }
    let max = count.iter().copied().max().unwrap_or(0) as f64;
    max * parts as f64 / owner.len().max(1) as f64
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_square_lattice_splits_into_equal_boxes() {
        let n = 16;
        let pts: Vec<f64> = (0..n * n)
            .flat_map(|k| [(k % n) as f64, (k / n) as f64])
            .collect();
        for parts in [1, 2, 3, 4, 7, 8] {
            let owner = rcb(&pts, 2, parts);
            assert!(imbalance(&owner, parts) < 1.0 + parts as f64 / (n * n) as f64 + 1e-12);
            assert!(owner.iter().all(|&o| (o as usize) < parts));
        }
        // 4 parts: the four quadrants
        let owner = rcb(&pts, 2, 4);
        let at = |x: usize, y: usize| owner[y * n + x];
        let q = [at(0, 0), at(15, 0), at(0, 15), at(15, 15)];
        let mut sorted = q.to_vec();
        sorted.sort();
        assert_eq!(sorted, vec![0, 1, 2, 3]);
        for y in 0..n {
            for x in 0..n {
                assert_eq!(at(x, y), q[(x >= 8) as usize + 2 * (y >= 8) as usize]);
            }
        }
    }
}
