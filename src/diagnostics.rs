//! The two conditions of the stability theory and the discrete norms (Imoto 2019, §3–4).
//!
//! * **h-connectivity** (Def. 3.1): every particle of `Ω` has a path of hops shorter than `h`,
//!   through particles of `Ω`, to a particle of the Dirichlet band `Γ_H`. Theorem 4.1: then the
//!   Poisson matrix is symmetric positive definite. [`connectivity`] labels the components of the
//!   fluid neighbour graph (ghost images of fluid particles join their sources, as they do in the
//!   matrix) and marks each as *anchored* (touches a Dirichlet particle) or *floating*.
//! * **semi-regularity** (Def. 3.2): `c0 = max_i Σ_{j≠i} ω_j w_h(r_ij)` ([`semi_regularity`]).
//! * norms `‖φ‖²_ℓ2(S) = Σ_{i∈S} ω_i φ_i²` and
//!   `‖φ‖²_h01(S) = d Σ_{i∈S} ω_i Σ_{j≠i} ω_j (φ_j − φ_i)² w_h(r_ij)/r_ij²`, and the
//!   Theorem 4.5 ratio `‖u‖_h01(Ω) / (√(d c0) ‖f‖_ℓ2(Ω))`, which the theory bounds by 1.

use crate::error::ConnectivityError;
use crate::neighbors::NeighborList;
use crate::particles::Role;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// The rows a norm or constant is taken over.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Region {
    /// `Ω`: the fluid particles.
    Omega,
    /// `Ω_H = Ω ∪ Γ_H`: fluid and Dirichlet particles (ghost rows are never summed: their pairs
    /// are already the fluid rows' ghost pairs).
    OmegaH,
}

impl Region {
    #[inline]
    fn contains(&self, r: Role) -> bool {
        match self {
            Region::Omega => matches!(r, Role::Fluid),
            Region::OmegaH => matches!(r, Role::Fluid | Role::Dirichlet),
        }
    }
}

/// Components of the fluid neighbour graph.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Components {
    /// Component of each particle (`u32::MAX` for non-fluid particles).
    pub label: Vec<u32>,
    /// Per component: true when it touches a Dirichlet particle.
    pub anchored: Vec<bool>,
    /// Per component: number of particles.
    pub size: Vec<usize>,
    /// Fluid particles with no neighbour at all (other than their own images).
    pub isolated: Vec<usize>,
}

/// Summary of [`Components`] for reports.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ConnectivitySummary {
    /// Number of components.
    pub components: usize,
    /// Anchored components.
    pub anchored: usize,
    /// Floating components.
    pub floating: usize,
    /// Isolated particles.
    pub isolated: usize,
}

impl Components {
    /// Number of components.
    pub fn len(&self) -> usize {
        self.size.len()
    }
    /// True when there is no fluid particle.
    pub fn is_empty(&self) -> bool {
        self.size.is_empty()
    }
    /// Floating (pure Neumann) components.
    pub fn floating(&self) -> Vec<usize> {
        (0..self.len()).filter(|&c| !self.anchored[c]).collect()
    }
    /// The paper's h-connectivity: every component anchored.
    pub fn is_h_connected(&self) -> bool {
        self.anchored.iter().all(|&a| a)
    }
    /// Counts for reports.
    pub fn summary(&self) -> ConnectivitySummary {
        let floating = self.anchored.iter().filter(|&&a| !a).count();
        ConnectivitySummary {
            components: self.len(),
            anchored: self.len() - floating,
            floating,
            isolated: self.isolated.len(),
        }
    }
    /// Particles of component `c`, ascending.
    pub fn members(&self, c: usize) -> Vec<usize> {
        self.label
            .iter()
            .enumerate()
            .filter(|(_, &l)| l as usize == c)
            .map(|(i, _)| i)
            .collect()
    }

    /// Accepts the `allowed_floating` largest floating components (e.g. 1 for a closed box whose
    /// walls all carry a Neumann condition, 0 for the paper's Dirichlet problem) and reports every
    /// other floating component, and every isolated particle, with its particle ids.
    pub fn check(&self, allowed_floating: usize) -> Result<(), ConnectivityError> {
        // the usual case, without allocating: few enough floating components, no isolated
        // particle (only those make a floating component fail below)
        if self.isolated.is_empty()
            && self.anchored.iter().filter(|&&a| !a).count() <= allowed_floating
        {
            return Ok(());
        }
        let mut floating = self.floating();
        // largest first; ties by lowest component id for determinism
        floating.sort_by(|&a, &b| self.size[b].cmp(&self.size[a]).then(a.cmp(&b)));
        let isolated_set: std::collections::HashSet<usize> =
            self.isolated.iter().copied().collect();
        let mut bad: Vec<usize> = floating
            .iter()
            .enumerate()
            .filter(|(rank, &c)| {
                *rank >= allowed_floating
                    || (self.size[c] == 1 && isolated_set.contains(&self.members(c)[0]))
            })
            .map(|(_, &c)| c)
            .collect();
        if bad.is_empty() && self.isolated.is_empty() {
            return Ok(());
        }
        bad.sort_unstable();
        let bad_set: std::collections::HashSet<u32> = bad.iter().map(|&c| c as u32).collect();
        let mut offending: Vec<usize> = self
            .label
            .iter()
            .enumerate()
            .filter(|(_, l)| bad_set.contains(l))
            .map(|(i, _)| i)
            .collect();
        offending.extend(self.isolated.iter().copied());
        offending.sort_unstable();
        offending.dedup();
        let components = bad.len()
            + self
                .isolated
                .iter()
                .filter(|&&i| !bad_set.contains(&self.label[i]))
                .count();
        Err(ConnectivityError {
            offending,
            components,
            isolated: self.isolated.len(),
        })
    }
}

/// The fluid particle a particle's value is taken from in the Poisson problem: itself for
/// fluid, the source for a ghost of a fluid particle, none for Dirichlet particles and their
/// ghosts (a free surface that touches a wall has images too: they hold the band's zero).
#[inline]
pub(crate) fn alias(role: &[Role], j: usize) -> Option<usize> {
    match role[j] {
        Role::Fluid => Some(j),
        Role::Ghost { source, .. } => {
            let s = source as usize;
            role[s].is_fluid().then_some(s)
        }
        Role::Dirichlet => None,
    }
}

/// Components of the fluid graph (edges: pairs with `r < h`, ghosts standing for their sources),
/// anchored when some member has a Dirichlet neighbour. Exact per Definition 3.1.
///
/// ```
/// use gpm::diagnostics::connectivity;
/// use gpm::kernel::Weight;
/// use gpm::neighbors::{NeighborConfig, NeighborList};
/// use gpm::particles::Role;
///
/// // a row of fluid particles 0.1 apart ending in a Dirichlet particle, and a far particle
/// let x = vec![[0.0, 0.0], [0.1, 0.0], [0.2, 0.0], [0.3, 0.0], [5.0, 5.0]];
/// let role = vec![Role::Fluid, Role::Fluid, Role::Fluid, Role::Dirichlet, Role::Fluid];
/// let nl = NeighborList::build(NeighborConfig::new(Weight::WendlandC2, 0.15, 0.0), &x)?;
/// let c = connectivity(&nl, &role);
/// let s = c.summary();
/// assert_eq!((s.components, s.anchored, s.floating, s.isolated), (2, 1, 1, 1));
/// assert_eq!(c.isolated, vec![4]);
/// // h-connectivity (Def. 3.1) fails: the error names the particle without a path to the band
/// let err = c.check(0).unwrap_err();
/// assert!(err.to_string().contains('4'));
/// # Ok::<(), gpm::error::InputError>(())
/// ```
pub fn connectivity<const D: usize>(nl: &NeighborList<D>, role: &[Role]) -> Components {
    let mut out = Components::default();
    connectivity_into(nl, role, &mut out, &mut ConnectivityScratch::default());
    out
}

/// The working vectors of [`connectivity_into`], kept between calls.
#[derive(Debug, Default)]
pub struct ConnectivityScratch {
    parent: Vec<std::sync::atomic::AtomicU32>,
    has_nb: Vec<bool>,
    root_to_comp: Vec<u32>,
    samples: Vec<u32>,
}

impl Clone for ConnectivityScratch {
    /// Scratch, not state: a clone starts empty.
    fn clone(&self) -> Self {
        Self::default()
    }
}

/// Pairs per row linked in the sampling round of [`connectivity_into`].
const SAMPLED_LINKS: usize = 2;
/// Particles whose roots pick the largest component after the sampling round.
const ROOT_SAMPLES: usize = 1024;

/// [`connectivity`] into `out`, its vectors and those of `scratch` reused (a moving step's
/// check allocates nothing once they have grown).
///
/// A concurrent union-find in the manner of Afforest (Sutton, Ben-Nun & Barak 2018): a first
/// round links each fluid particle to its first two neighbours only; the root most of 1 024
/// evenly spaced particles reach is taken as the largest component's; a second round links
/// every pair of each particle *not* in that component. Every pair is accounted for: a pair
/// whose two ends were in that component when they were visited is already connected, any other
/// is linked from the end that was not. The components are those of linking every pair (the
/// graph search of `tests/stability_props.rs` checks them), at a few links per particle instead
/// of one per pair when one component holds most particles. Anchoring is read from the rows of
/// the particles that hold the Dirichlet values (their pairs are the fluid rows' Dirichlet pairs
/// seen from the other end: the list holds both directions of every pair).
pub fn connectivity_into<const D: usize>(
    nl: &NeighborList<D>,
    role: &[Role],
    out: &mut Components,
    scratch: &mut ConnectivityScratch,
) {
    use std::sync::atomic::{AtomicU32, Ordering};
    let n = nl.len();
    // a root is only ever linked under a smaller root, so every component's root is its
    // smallest index whatever the order of the unions — the labels below are those of a
    // sequential run
    let parent = &mut scratch.parent;
    parent.truncate(n);
    parent
        .iter_mut()
        .enumerate()
        .for_each(|(i, p)| *p.get_mut() = i as u32);
    let have = parent.len();
    parent.extend((have..n).map(|i| AtomicU32::new(i as u32)));
    let parent = &parent[..];
    fn find(p: &[AtomicU32], mut a: u32) -> u32 {
        loop {
            let pa = p[a as usize].load(Ordering::Acquire);
            if pa == a {
                return a;
            }
            let g = p[pa as usize].load(Ordering::Acquire);
            if g == pa {
                return pa;
            }
            // path halving; losing the race only skips a shortcut
            let _ = p[a as usize].compare_exchange(pa, g, Ordering::AcqRel, Ordering::Acquire);
            a = g;
        }
    }
    fn union(p: &[AtomicU32], a: u32, b: u32) {
        loop {
            let (ra, rb) = (find(p, a), find(p, b));
            if ra == rb {
                return;
            }
            let (lo, hi) = if ra < rb { (ra, rb) } else { (rb, ra) };
            if p[hi as usize]
                .compare_exchange(hi, lo, Ordering::AcqRel, Ordering::Acquire)
                .is_ok()
            {
                return;
            }
        }
    }
    // the fluid particles a row's pairs join row i to (ghosts stand for their sources; pairs
    // with i's own images join nothing), and whether it has a pair other than those
    let links = |i: usize| {
        nl.row(i).filter_map(move |k| {
            let j = nl.indices()[k] as usize;
            alias(role, j).filter(|&s| s != i)
        })
    };
    let has_nb = &mut scratch.has_nb;
    has_nb.resize(n, false);
    // round 1: the first links of each fluid row
    has_nb
        .par_iter_mut()
        .with_min_len(256)
        .enumerate()
        .for_each(|(i, has)| {
            *has = false;
            if !role[i].is_fluid() {
                return;
            }
            // a pair with a Dirichlet particle counts as a neighbour
            *has = nl.row(i).any(|k| {
                let j = nl.indices()[k] as usize;
                alias(role, j) != Some(i)
            });
            for s in links(i).take(SAMPLED_LINKS) {
                union(parent, i as u32, s as u32);
            }
        });
    // the root most sampled fluid particles reach (ties: the smallest)
    let samples = &mut scratch.samples;
    samples.clear();
    let stride = n.div_ceil(ROOT_SAMPLES).max(1);
    samples.extend(
        (0..n)
            .step_by(stride)
            .filter(|&i| role[i].is_fluid())
            .map(|i| find(parent, i as u32)),
    );
    samples.sort_unstable();
    let (mut big, mut best, mut run) = (u32::MAX, 0usize, 0usize);
    for (a, &r) in samples.iter().enumerate() {
        run = if a > 0 && samples[a - 1] == r {
            run + 1
        } else {
            1
        };
        if run > best {
            (big, best) = (r, run);
        }
    }
    // round 2: every link of the fluid rows outside that component
    (0..n)
        .into_par_iter()
        .with_min_len(256)
        .filter(|&i| role[i].is_fluid() && find(parent, i as u32) != big)
        .for_each(|i| {
            for s in links(i) {
                union(parent, i as u32, s as u32);
            }
        });
    // sequential from here: the relaxed loads and stores see every union above
    let root = |mut a: usize| loop {
        let pa = parent[a].load(Ordering::Relaxed) as usize;
        if pa == a {
            return a;
        }
        let g = parent[pa].load(Ordering::Relaxed);
        parent[a].store(g, Ordering::Relaxed);
        a = g as usize;
    };
    let Components {
        label,
        anchored,
        size,
        isolated,
    } = out;
    label.clear();
    label.resize(n, u32::MAX);
    let root_to_comp = &mut scratch.root_to_comp;
    root_to_comp.clear();
    root_to_comp.resize(n, u32::MAX);
    anchored.clear();
    size.clear();
    isolated.clear();
    for i in 0..n {
        if !role[i].is_fluid() {
            continue;
        }
        let r = root(i);
        if root_to_comp[r] == u32::MAX {
            root_to_comp[r] = anchored.len() as u32;
            anchored.push(false);
            size.push(0);
        }
        let c = root_to_comp[r];
        label[i] = c;
        size[c as usize] += 1;
        if !has_nb[i] {
            isolated.push(i);
        }
    }
    // anchoring: the fluid particles in the rows of the particles that carry no fluid value
    // (Dirichlet particles and their images) — the pairs a fluid row has with them
    for d in (0..n).filter(|&d| alias(role, d).is_none()) {
        for k in nl.row(d) {
            let j = nl.indices()[k] as usize;
            if role[j].is_fluid() {
                anchored[label[j] as usize] = true;
            }
        }
    }
}

/// `S_i = Σ_{j≠i} ω_j w_h(r_ij)` at every particle: the sum whose maximum is `c0`, and the factor
/// by which the operators scale derivatives on a symmetric lattice (`Δh φ ≈ S_i Δφ`).
pub fn shepard_sums<const D: usize>(nl: &NeighborList<D>, vol: &[f64]) -> Vec<f64> {
    (0..nl.len())
        .into_par_iter()
        .with_min_len(256)
        .map(|i| {
            nl.row(i)
                .map(|k| vol[nl.indices()[k] as usize] * nl.w()[k])
                .sum()
        })
        .collect()
}

/// Smallest pair distance `min_{i∈region, j} r_ij` over the neighbour pairs of the rows in
/// `region` (`∞` when they have no neighbour): the closest approach of two particles, or of a
/// particle and its mirror image (twice its distance to a wall). From the rows' smallest `r²`
/// the measure took ([`NeighborList::r2_mins`]): no pass over the pairs.
pub fn min_spacing<const D: usize>(nl: &NeighborList<D>, role: &[Role], region: Region) -> f64 {
    (0..nl.len())
        .into_par_iter()
        .with_min_len(256)
        .filter(|&i| region.contains(role[i]))
        .map(|i| nl.r2_mins()[i])
        .reduce(|| f64::INFINITY, f64::min)
        .sqrt()
}

/// Semi-regularity constant `c0 = max_{i∈region} Σ_{j≠i} ω_j w_h(r_ij)` (Definition 3.2).
/// Lemma 4.4 and Theorem 4.5 only use the rows of `Ω`, so `Region::Omega` is what the
/// stability check needs; `Region::OmegaH` gives the paper's maximum over every particle.
pub fn semi_regularity<const D: usize>(
    nl: &NeighborList<D>,
    vol: &[f64],
    role: &[Role],
    region: Region,
) -> f64 {
    (0..nl.len())
        .into_par_iter()
        .with_min_len(256)
        .filter(|&i| region.contains(role[i]))
        .map(|i| {
            nl.row(i)
                .map(|k| vol[nl.indices()[k] as usize] * nl.w()[k])
                .sum::<f64>()
        })
        .reduce(|| 0.0, f64::max)
}

/// Neighbour-count and spacing statistics.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct NeighborStats {
    /// Fewest neighbours of a fluid particle.
    pub min_neighbors: usize,
    /// Mean neighbours of a fluid particle.
    pub mean_neighbors: f64,
    /// Most neighbours of a fluid particle.
    pub max_neighbors: usize,
    /// Smallest pair distance `min r_ij` (over pairs with a fluid end), `∞` when there is none.
    pub min_distance: f64,
    /// The pair realising `min_distance`.
    pub closest_pair: Option<(usize, usize)>,
}

/// Neighbour counts of fluid particles and the closest pair (the paper requires
/// `min r_ij < h`; coincident particles are rejected by the neighbour search).
pub fn neighbor_stats<const D: usize>(nl: &NeighborList<D>, role: &[Role]) -> NeighborStats {
    let mut s = NeighborStats {
        min_neighbors: usize::MAX,
        max_neighbors: 0,
        min_distance: f64::INFINITY,
        ..Default::default()
    };
    let mut total = 0usize;
    let mut count = 0usize;
    let mut best = f64::INFINITY;
    for i in 0..nl.len() {
        if !role[i].is_fluid() {
            continue;
        }
        let r = nl.row(i);
        let m = r.len();
        s.min_neighbors = s.min_neighbors.min(m);
        s.max_neighbors = s.max_neighbors.max(m);
        total += m;
        count += 1;
        for k in r {
            if nl.r2(k) < best {
                best = nl.r2(k);
                s.closest_pair = Some((i, nl.indices()[k] as usize));
            }
        }
    }
    if count == 0 {
        s.min_neighbors = 0;
    } else {
        s.mean_neighbors = total as f64 / count as f64;
    }
    s.min_distance = best.sqrt();
    s
}

/// `‖φ‖_ℓ2(S) = (Σ_{i∈S} ω_i φ_i²)^{1/2}` (summed in a fixed order: the same bits every run).
pub fn norm_l2(vol: &[f64], phi: &[f64], role: &[Role], region: Region) -> f64 {
    phi.par_iter()
        .enumerate()
        .with_min_len(1024)
        .with_max_len(1024)
        .filter(|(i, _)| region.contains(role[*i]))
        .map(|(i, v)| vol[i] * v * v)
        .sum::<f64>()
        .sqrt()
}

/// `‖ψ‖_ℓ2(S)` of a vector field: `(Σ_{i∈S} ω_i |ψ_i|²)^{1/2}`.
pub fn norm_l2_vec<const D: usize>(
    vol: &[f64],
    psi: &[[f64; D]],
    role: &[Role],
    region: Region,
) -> f64 {
    psi.par_iter()
        .enumerate()
        .with_min_len(1024)
        .with_max_len(1024)
        .filter(|(i, _)| region.contains(role[*i]))
        .map(|(i, v)| vol[i] * crate::math::norm2(v))
        .sum::<f64>()
        .sqrt()
}

/// `‖φ‖_h01(S) = (d Σ_{i∈S} ω_i Σ_{j≠i} ω_j (φ_j − φ_i)² w_h(r_ij)/r_ij²)^{1/2}`.
/// `phi` must hold the values at every particle (ghost values filled, Dirichlet values zero).
pub fn norm_h01<const D: usize>(
    nl: &NeighborList<D>,
    vol: &[f64],
    phi: &[f64],
    role: &[Role],
    region: Region,
) -> f64 {
    let d = D as f64;
    // fixed split lengths: the same sum, bit for bit, whatever the work stealing did
    ((0..nl.len())
        .into_par_iter()
        .with_min_len(256)
        .with_max_len(256)
        .filter(|&i| region.contains(role[i]))
        .map(|i| {
            let fi = phi[i];
            vol[i]
                * nl.row(i)
                    .map(|k| {
                        let j = nl.indices()[k] as usize;
                        let df = phi[j] - fi;
                        vol[j] * df * df * nl.wr2()[k]
                    })
                    .sum::<f64>()
        })
        .sum::<f64>()
        * d)
        .sqrt()
}

/// The Theorem 4.5 ratio `‖u‖_h01(Ω) / (√(d c0) ‖f‖_ℓ2(Ω))`; the theorem says it is at most 1.
/// Zero when both norms vanish.
pub fn stability_ratio(u_h01: f64, c0: f64, f_l2: f64, d: usize) -> f64 {
    let denom = (d as f64 * c0).sqrt() * f_l2;
    if denom > 0.0 {
        u_h01 / denom
    } else if u_h01 == 0.0 {
        0.0
    } else {
        f64::INFINITY
    }
}
