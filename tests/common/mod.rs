//! Seeded particle families shared by the integration tests.
//!
//! Every family is reproducible from its [`Spec`] (the seed included): lattices, jittered
//! lattices (uniform offsets up to `jitter · Δx` per axis), several kinds of volumes, and four
//! boundary set-ups in 2D and 3D:
//!
//! * [`dirichlet_box`]: fluid in the open unit box `(0,1)^d`, a Dirichlet band `Γ_H` outside it
//!   at least `h` thick (the paper's setting);
//! * [`periodic_box`]: every particle fluid, every axis periodic with period 1;
//! * [`mirror_box`]: fluid in the unit box, mirror-image ghosts across its walls
//!   ([`Walls::closed_box`] + [`Boundary::make_ghosts`] with reach `h`);
//! * [`random_cloud`]: uniform random points (no lattice at all), for the neighbour search.
//!
//! Nothing here computes an expected value: the tests derive those from mathematics.

#![allow(dead_code)]

use gpm::boundary::{Boundary, VectorKind, Walls};
use gpm::geometry::{inside, jitter, lattice, number_density_volumes};
use gpm::kernel::Weight;
use gpm::neighbors::{NeighborConfig, NeighborList, Periodicity};
use gpm::particles::{Particles, Role};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Every weight the crate ships, with a few members of the polynomial family.
pub const WEIGHTS: [Weight; 7] = [
    Weight::CubicSpline,
    Weight::WendlandC2,
    Weight::WendlandC4,
    Weight::Poly { p: 0, m: 1 },
    Weight::Poly { p: 0, m: 3 },
    Weight::Poly { p: 1, m: 2 },
    Weight::Poly { p: 2, m: 4 },
];

/// How the particle volumes `ω_i` are chosen.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Volumes {
    /// `ω_i = Δx^d`.
    Uniform,
    /// `ω_i = 1 / Σ_{j≠i} w_h(r_ij)` ([`number_density_volumes`]).
    NumberDensity,
    /// `ω_i = Δx^d · e^{s}`, `s` uniform in `[−ln spread, ln spread]` (independent per particle,
    /// seeded): strongly non-uniform volumes, which the identities and bounds must not care about.
    Random {
        /// Largest factor away from `Δx^d`.
        spread: f64,
    },
}

/// Parameters of a family.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Spec {
    /// Particles per unit length (`Δx = 1/n`).
    pub n: usize,
    /// `h / Δx`.
    pub h_over_dx: f64,
    /// Jitter amplitude as a fraction of `Δx` (0 for a lattice).
    pub jitter: f64,
    /// Reference weight.
    pub weight: Weight,
    /// Volumes.
    pub volumes: Volumes,
    /// Seed of the jitter and of random volumes.
    pub seed: u64,
}

impl Spec {
    /// A lattice with uniform volumes.
    pub fn lattice(n: usize, h_over_dx: f64, weight: Weight) -> Self {
        Spec {
            n,
            h_over_dx,
            jitter: 0.0,
            weight,
            volumes: Volumes::Uniform,
            seed: 0,
        }
    }
    /// With jitter `amp · Δx` and seed.
    pub fn jittered(mut self, amp: f64, seed: u64) -> Self {
        self.jitter = amp;
        self.seed = seed;
        self
    }
    /// With these volumes.
    pub fn volumes(mut self, v: Volumes) -> Self {
        self.volumes = v;
        self
    }
    /// `Δx`.
    pub fn dx(&self) -> f64 {
        1.0 / self.n as f64
    }
    /// `h`.
    pub fn h(&self) -> f64 {
        self.h_over_dx * self.dx()
    }
}

/// A particle family with its neighbour list.
#[derive(Clone, Debug)]
pub struct Family<const D: usize> {
    /// The parameters it was built from.
    pub spec: Spec,
    /// Positions (ghosts last).
    pub x: Vec<[f64; D]>,
    /// Volumes (ghosts copy their source).
    pub vol: Vec<f64>,
    /// Roles.
    pub role: Vec<Role>,
    /// Neighbour list over every particle (kiddo search, zero skin).
    pub nl: NeighborList<D>,
    /// The walls when the family has mirror ghosts.
    pub walls: Option<Walls<D>>,
}

impl<const D: usize> Family<D> {
    /// Number of particles (all roles).
    pub fn len(&self) -> usize {
        self.x.len()
    }
    /// Indices of the fluid particles.
    pub fn fluid(&self) -> Vec<usize> {
        (0..self.len())
            .filter(|&i| self.role[i].is_fluid())
            .collect()
    }
    /// Indices of the Dirichlet particles.
    pub fn dirichlet(&self) -> Vec<usize> {
        (0..self.len())
            .filter(|&i| self.role[i] == Role::Dirichlet)
            .collect()
    }
    /// Number of ghosts.
    pub fn n_ghosts(&self) -> usize {
        self.role
            .iter()
            .filter(|r| matches!(r, Role::Ghost { .. }))
            .count()
    }
    /// Sets Dirichlet values to zero and copies values into ghosts (source value): the
    /// continuation under which a scalar field belongs to the paper's `V_h` (band) or satisfies
    /// the homogeneous Neumann condition (mirror ghosts).
    pub fn complete_scalar(&self, phi: &mut [f64]) {
        for (i, r) in self.role.iter().enumerate() {
            if *r == Role::Dirichlet {
                phi[i] = 0.0;
            }
        }
        if let Some(w) = &self.walls {
            w.fill_scalar(&self.role, phi);
        }
    }
    /// Sets Dirichlet vectors to zero and continues vectors into ghosts with the mirror rule
    /// (`v_g = L v_src`, normal components flipped).
    pub fn complete_vector(&self, psi: &mut [[f64; D]]) {
        for (i, r) in self.role.iter().enumerate() {
            if *r == Role::Dirichlet {
                psi[i] = [0.0; D];
            }
        }
        if let Some(w) = &self.walls {
            w.fill_vector(&self.role, psi, VectorKind::Mirror);
        }
    }
    /// A random scalar field, uniform in `[−1, 1]` on the fluid, completed.
    pub fn random_scalar(&self, seed: u64) -> Vec<f64> {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut phi: Vec<f64> = (0..self.len())
            .map(|_| 2.0 * rng.random::<f64>() - 1.0)
            .collect();
        self.complete_scalar(&mut phi);
        phi
    }
    /// A random vector field, components uniform in `[−1, 1]` on the fluid, completed.
    pub fn random_vector(&self, seed: u64) -> Vec<[f64; D]> {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut psi: Vec<[f64; D]> = (0..self.len())
            .map(|_| std::array::from_fn(|_| 2.0 * rng.random::<f64>() - 1.0))
            .collect();
        self.complete_vector(&mut psi);
        psi
    }
    /// A smooth scalar field `f(x)` sampled at the fluid particles, completed.
    pub fn smooth_scalar(&self, f: impl Fn(&[f64; D]) -> f64) -> Vec<f64> {
        let mut phi: Vec<f64> = self.x.iter().map(&f).collect();
        self.complete_scalar(&mut phi);
        phi
    }
    /// A smooth vector field sampled at the fluid particles, completed.
    pub fn smooth_vector(&self, f: impl Fn(&[f64; D]) -> [f64; D]) -> Vec<[f64; D]> {
        let mut psi: Vec<[f64; D]> = self.x.iter().map(&f).collect();
        self.complete_vector(&mut psi);
        psi
    }
}

fn volumes_for<const D: usize>(
    spec: &Spec,
    nl: &NeighborList<D>,
    n_particles: usize,
    rng_seed: u64,
) -> Vec<f64> {
    let cell = spec.dx().powi(D as i32);
    match spec.volumes {
        Volumes::Uniform => vec![cell; n_particles],
        Volumes::NumberDensity => number_density_volumes(nl),
        Volumes::Random { spread } => {
            assert!(spread >= 1.0);
            let mut rng = ChaCha8Rng::seed_from_u64(rng_seed ^ 0x5EED_F01D);
            let l = spread.ln();
            (0..n_particles)
                .map(|_| cell * (l * (2.0 * rng.random::<f64>() - 1.0)).exp())
                .collect()
        }
    }
}

/// Cells of band around the unit box: at least `h + Δx` thick before jitter, so at least `h`
/// thick after a jitter below `Δx / 2`.
pub fn band_cells(spec: &Spec) -> usize {
    spec.h_over_dx.ceil() as usize + 1
}

/// The paper's setting: a (jittered) lattice over the unit box grown by a band; particles in the
/// open box `(0,1)^d` are fluid, the others form the Dirichlet band `Γ_H`.
pub fn dirichlet_box<const D: usize>(spec: Spec) -> Family<D> {
    let dx = spec.dx();
    let b = band_cells(&spec) as f64 * dx;
    let mut x = lattice([-b; D], [1.0 + b; D], dx);
    if spec.jitter > 0.0 {
        jitter(&mut x, spec.jitter * dx, spec.seed);
    }
    let role: Vec<Role> = x
        .iter()
        .map(|p| {
            if inside(p, &[0.0; D], &[1.0; D]) {
                Role::Fluid
            } else {
                Role::Dirichlet
            }
        })
        .collect();
    let cfg = NeighborConfig::new(spec.weight, spec.h(), 0.0);
    let nl = NeighborList::build(cfg, &x).expect("neighbour list");
    let vol = volumes_for(&spec, &nl, x.len(), spec.seed);
    Family {
        spec,
        x,
        vol,
        role,
        nl,
        walls: None,
    }
}

/// Every particle fluid, every axis periodic on `[0, 1)`.
pub fn periodic_box<const D: usize>(spec: Spec) -> Family<D> {
    let dx = spec.dx();
    let per = Periodicity::all([0.0; D], [1.0; D]);
    let mut x = lattice([0.0; D], [1.0; D], dx);
    if spec.jitter > 0.0 {
        jitter(&mut x, spec.jitter * dx, spec.seed);
    }
    for p in x.iter_mut() {
        per.wrap(p);
    }
    let role = vec![Role::Fluid; x.len()];
    let cfg = NeighborConfig::new(spec.weight, spec.h(), 0.0).with_periodicity(per);
    let nl = NeighborList::build(cfg, &x).expect("neighbour list");
    let vol = volumes_for(&spec, &nl, x.len(), spec.seed);
    Family {
        spec,
        x,
        vol,
        role,
        nl,
        walls: None,
    }
}

/// Fluid on a (jittered, at most `Δx/2`) lattice in the unit box, walls on every face, mirror
/// ghosts of every fluid particle within `h` of a wall (edge and corner images included).
/// Ghost volumes equal their source's.
pub fn mirror_box<const D: usize>(spec: Spec) -> Family<D> {
    assert!(
        spec.jitter < 0.5,
        "jitter must keep particles inside their cells"
    );
    let dx = spec.dx();
    let h = spec.h();
    let walls = Walls::closed_box([0.0; D], [1.0; D]);
    let mut x = lattice([0.0; D], [1.0; D], dx);
    if spec.jitter > 0.0 {
        jitter(&mut x, spec.jitter * dx, spec.seed);
    }
    let mut p = Particles::<D>::new();
    for xi in &x {
        p.push(*xi, [0.0; D], 0.0, dx.powi(D as i32), Role::Fluid);
    }
    let n_fluid = p.len();
    walls.make_ghosts(&mut p, h);
    let cfg = NeighborConfig::new(spec.weight, h, 0.0);
    let nl = NeighborList::build(cfg, &p.x).expect("neighbour list");
    let vol = volumes_for(&spec, &nl, p.len(), spec.seed);
    p.vol[..n_fluid].copy_from_slice(&vol[..n_fluid]);
    // ghosts take their source's volume
    walls.place_ghosts(&mut p);
    p.validate().expect("valid particles");
    Family {
        spec,
        x: p.x,
        vol: p.vol,
        role: p.role,
        nl,
        walls: Some(walls),
    }
}

/// `n` uniform random points in `[0, 1)^D`.
pub fn random_cloud<const D: usize>(n: usize, seed: u64) -> Vec<[f64; D]> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    (0..n)
        .map(|_| std::array::from_fn(|_| rng.random::<f64>()))
        .collect()
}

/// `(a, b)_S = Σ_{i∈S} ω_i a_i b_i` over the listed rows.
pub fn inner(rows: &[usize], vol: &[f64], a: &[f64], b: &[f64]) -> f64 {
    rows.iter().map(|&i| vol[i] * a[i] * b[i]).sum()
}

/// `(a, b)_S = Σ_{i∈S} ω_i a_i · b_i` for vector fields.
pub fn inner_vec<const D: usize>(
    rows: &[usize],
    vol: &[f64],
    a: &[[f64; D]],
    b: &[[f64; D]],
) -> f64 {
    rows.iter()
        .map(|&i| vol[i] * (0..D).map(|k| a[i][k] * b[i][k]).sum::<f64>())
        .sum()
}

/// `|a − b| / max(|a|, |b|)` (0 when both vanish).
pub fn rel_diff(a: f64, b: f64) -> f64 {
    let s = a.abs().max(b.abs());
    if s == 0.0 {
        0.0
    } else {
        (a - b).abs() / s
    }
}

/// A `proptest` runner whose every setting is fixed here (none read from `PROPTEST_*`
/// environment variables), driven by a ChaCha generator with a fixed seed: the cases run are the
/// same on every machine and every run.
pub fn deterministic_runner(cases: u32, seed: u8) -> proptest::test_runner::TestRunner {
    use proptest::test_runner::{Config, RngAlgorithm, RngSeed, TestRng, TestRunner};
    let c = Config {
        cases,
        max_local_rejects: 65_536,
        max_global_rejects: 1024,
        max_flat_map_regens: 1_000_000,
        failure_persistence: None,
        source_file: None,
        test_name: None,
        fork: false,
        timeout: 0,
        max_shrink_time: 0,
        max_shrink_iters: 256,
        max_default_size_range: 100,
        verbose: 0,
        rng_algorithm: RngAlgorithm::ChaCha,
        rng_seed: RngSeed::Fixed(seed as u64),
        // every other field (the result cache) keeps its built-in default
        ..Config::default()
    };
    let rng = TestRng::from_seed(RngAlgorithm::ChaCha, &[seed; 32]);
    TestRunner::new_with_rng(c, rng)
}

/// The first `/projection_input` message of the recording at `path`.
pub fn first_projection_input(path: &std::path::Path) -> gpm::record::schema::ProjectionInput {
    use gpm::record::schema::{ProjectionInput, TOPIC_PROJECTION};
    let mut first = None;
    gpm::record::replay::scan(
        path,
        |m| {
            if m.topic == TOPIC_PROJECTION && first.is_none() {
                first = Some(m.decode::<ProjectionInput>()?);
            }
            Ok(())
        },
        |_, _| {},
    )
    .unwrap();
    first.expect("a recorded projection input")
}

/// Checks every solve of a run against the warm-start stopping rule
/// ([`gpm::poisson::SolveParams::warm_tol`]), written out here rather than read from the
/// library: a solve whose warm start left `ρ ≤ 0.1` of its right side stops at
/// `max(rel_tol, θ ρ)`, any other at `rel_tol`, and its residual is within 1.5 of that.
/// Returns the number of solves the rule loosened. `who` names the run in a failure.
pub fn assert_warm_start_rule<'a>(
    solves: impl IntoIterator<Item = &'a gpm::poisson::SolveInfo>,
    rel_tol: f64,
    theta: f64,
    who: &str,
) -> usize {
    let mut loosened = 0;
    for (k, s) in solves.into_iter().enumerate() {
        let rho = s.initial_rel_residual;
        let expect = if rho <= 0.1 {
            rel_tol.max(theta * rho)
        } else {
            rel_tol
        };
        assert_eq!(s.rel_tol, expect, "{who}, step {k}: ρ = {rho:e}");
        assert!(
            s.rel_residual <= 1.5 * s.rel_tol,
            "{who}, step {k}: residual {:e} against its tolerance {:e}",
            s.rel_residual,
            s.rel_tol
        );
        loosened += usize::from(s.rel_tol > rel_tol);
    }
    loosened
}
