//! Particle layouts: lattices, jitter, bands, and volumes.

use crate::neighbors::NeighborList;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Cell-centred lattice points `lo + (k + ½) dx` with `k = 0, 1, …` covering the box
/// `[lo, hi)` (the count per axis is `round((hi − lo) / dx)`), in lexicographic order
/// (last axis fastest).
pub fn lattice<const D: usize>(lo: [f64; D], hi: [f64; D], dx: f64) -> Vec<[f64; D]> {
    let counts: [usize; D] =
        std::array::from_fn(|a| ((hi[a] - lo[a]) / dx).round().max(0.0) as usize);
    let total: usize = counts.iter().product();
    let mut pts = Vec::with_capacity(total);
    let mut idx = [0usize; D];
    for _ in 0..total {
        pts.push(std::array::from_fn(|a| lo[a] + (idx[a] as f64 + 0.5) * dx));
        for a in (0..D).rev() {
            idx[a] += 1;
            if idx[a] < counts[a] {
                break;
            }
            idx[a] = 0;
        }
    }
    pts
}

/// Moves every point by an independent uniform offset in `[−amp, amp]^D` (seeded, reproducible).
pub fn jitter<const D: usize>(pts: &mut [[f64; D]], amp: f64, seed: u64) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    for p in pts.iter_mut() {
        for c in p.iter_mut() {
            *c += amp * (2.0 * rng.random::<f64>() - 1.0);
        }
    }
}

/// `n` points on Vogel's spiral filling the disk of radius `radius` about `centre`:
/// `r_k = radius √((k + ½)/n)`, `θ_k = k · golden angle` (`π(3 − √5)`). Every point has about
/// the same area `πR²/n` (mean spacing `R√(π/n)`) but no two neighbourhoods are alike: a
/// distribution that is nowhere a lattice.
pub fn vogel_disk(n: usize, centre: [f64; 2], radius: f64) -> Vec<[f64; 2]> {
    let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
    (0..n)
        .map(|k| {
            let r = radius * ((k as f64 + 0.5) / n as f64).sqrt();
            let (s, c) = (k as f64 * golden).sin_cos();
            [centre[0] + r * c, centre[1] + r * s]
        })
        .collect()
}

/// True when `x` lies in the open box `(lo, hi)`.
pub fn inside<const D: usize>(x: &[f64; D], lo: &[f64; D], hi: &[f64; D]) -> bool {
    (0..D).all(|a| x[a] > lo[a] && x[a] < hi[a])
}

/// Volumes `ω_i = 1 / Σ_{j≠i} w_h(r_ij)` (MISSION §2): on a uniform distribution this makes the
/// consistency factor `S_i = Σ_{j≠i} ω_j w_h(r_ij)` equal to one, so that `∇h`, `∇̂h·` and `Δh`
/// approximate the derivatives themselves rather than `S` times them. From the sums the list's
/// measure took ([`NeighborList::w_sums`]): no pass over the pairs.
pub fn number_density_volumes<const D: usize>(nl: &NeighborList<D>) -> Vec<f64> {
    nl.w_sums()
        .iter()
        .map(|&s| number_density_volume(s))
        .collect()
}

/// The volume `1 / s` of a particle whose weight sum is `s` (`∞` for `s ≤ 0`: no neighbour),
/// the rule of [`number_density_volumes`] for one particle (the drivers set volumes in place
/// with it).
pub fn number_density_volume(s: f64) -> f64 {
    if s > 0.0 {
        1.0 / s
    } else {
        f64::INFINITY
    }
}

/// `Σ_{j≠i} w_h(r_ij)` on an infinite cell-centred lattice of spacing `dx`: the constant behind
/// [`number_density_volumes`] for particles whose neighbourhood is a full lattice.
pub fn lattice_weight_sum<const D: usize>(kernel: &crate::kernel::Kernel<D>, dx: f64) -> f64 {
    let m = (kernel.h() / dx).ceil() as i64 + 1;
    let mut s = 0.0;
    let mut idx = [-m; D];
    loop {
        if idx.iter().any(|&k| k != 0) {
            let r2: f64 = idx.iter().map(|&k| (k as f64 * dx).powi(2)).sum();
            s += kernel.w_h(r2.sqrt());
        }
        let mut a = D;
        loop {
            if a == 0 {
                return s;
            }
            a -= 1;
            idx[a] += 1;
            if idx[a] <= m {
                break;
            }
            idx[a] = -m;
        }
    }
}
