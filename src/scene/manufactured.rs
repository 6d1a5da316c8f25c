//! The paper's manufactured Dirichlet-band Poisson problem (used by `examples/poisson.rs`,
//! `examples/amg_study.rs` and the tests), in one place.
//!
//! On the unit box `Ω = (0, 1)^D`, with `u = Π_a sin²(π x_a)` and `f = −∇u`, solve
//!
//! `−Δh φ = ∇̂h·f̂` in `Ω`, `φ = 0` on the Dirichlet band `Γ_H`,
//!
//! where the particles are a lattice of spacing `Δx = 1/n` over the box widened by a band of
//! `⌈h/Δx⌉ + 1` layers (optionally jittered), `f̂ = f` on the fluid and `0` on the band, `∇̂h·`
//! is the sum-form divergence ([`crate::operators::div_sum`]) and the volumes are the number
//! density `ω_i = 1/Σ_j w_ij`. The exact `u` vanishes on `∂Ω` with its gradient, so the band
//! values are exact; [`BandProblem::errors`] gives the relative `ℓ2(Ω)` and `H¹₀(Ω)` errors.
//!
//! ```
//! use gpm::scene::manufactured::{BandProblem, BandSpec};
//! use gpm::poisson::{PoissonSolver, SolveParams};
//!
//! let prob = BandProblem::<2>::build(&BandSpec::new(16, 3.0))?;
//! let mut phi = vec![0.0; prob.x.len()];
//! PoissonSolver::new().solve(
//!     &prob.nl, &prob.vol, &prob.role, &prob.comps, &prob.rhs, &mut phi,
//!     &SolveParams::default(),
//! )?;
//! let (l2, h01) = prob.errors(&phi);
//! assert!(l2 < 0.05 && h01 < 0.2, "{l2} {h01}");
//! # Ok::<(), gpm::Error>(())
//! ```

use crate::diagnostics::{connectivity, norm_h01, norm_l2, Components, Region};
use crate::error::Error;
use crate::geometry::{inside, jitter, lattice, number_density_volumes};
use crate::kernel::Weight;
use crate::neighbors::{NeighborConfig, NeighborList};
use crate::operators::div_sum;
use crate::particles::Role;
use std::f64::consts::PI;
use std::time::Instant;

/// `u(x) = Π_a sin²(π x_a)` and its gradient `∂_a u = π sin(2π x_a) Π_{b≠a} sin²(π x_b)`.
pub fn exact<const D: usize>(x: &[f64; D]) -> (f64, [f64; D]) {
    let s: [f64; D] = std::array::from_fn(|a| (PI * x[a]).sin());
    let u: f64 = s.iter().map(|v| v * v).product();
    let g = std::array::from_fn(|a| {
        let others: f64 = (0..D).filter(|&b| b != a).map(|b| s[b] * s[b]).product();
        PI * (2.0 * PI * x[a]).sin() * others
    });
    (u, g)
}

/// How the particles of a [`BandProblem`] are laid out.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BandSpec {
    /// Lattice points per unit length (`Δx = 1/n`).
    pub n: usize,
    /// `h/Δx`.
    pub h_over_dx: f64,
    /// Reference weight.
    pub weight: Weight,
    /// Jitter amplitude over `Δx` (0 = lattice).
    pub jitter: f64,
    /// Seed of the jitter.
    pub seed: u64,
}

impl BandSpec {
    /// A Wendland C2 lattice, no jitter.
    pub fn new(n: usize, h_over_dx: f64) -> Self {
        BandSpec {
            n,
            h_over_dx,
            weight: Weight::WendlandC2,
            jitter: 0.0,
            seed: 0,
        }
    }

    /// The same, jittered by `amplitude · Δx` with `seed`.
    pub fn jittered(self, amplitude: f64, seed: u64) -> Self {
        BandSpec {
            jitter: amplitude,
            seed,
            ..self
        }
    }

    /// The same with another weight.
    pub fn with_weight(self, weight: Weight) -> Self {
        BandSpec { weight, ..self }
    }
}

/// An assembled manufactured problem: particles, neighbours, volumes, the right side and the
/// exact solution.
pub struct BandProblem<const D: usize> {
    /// Positions (fluid and band, in lattice order).
    pub x: Vec<[f64; D]>,
    /// Fluid inside the box, Dirichlet on the band.
    pub role: Vec<Role>,
    /// Neighbour list (no skin).
    pub nl: NeighborList<D>,
    /// Number-density volumes.
    pub vol: Vec<f64>,
    /// Connectivity of the particles.
    pub comps: Components,
    /// The source `∇̂h·f̂`.
    pub rhs: Vec<f64>,
    /// `u` on the fluid, 0 on the band.
    pub u_exact: Vec<f64>,
    /// Seconds to lay out the particles and build the neighbour list and the volumes.
    pub setup_seconds: f64,
}

impl<const D: usize> BandProblem<D> {
    /// Lays out the particles, builds neighbours and volumes, the source and the exact
    /// solution. Fails on a non-finite position (a bad spec).
    pub fn build(spec: &BandSpec) -> Result<Self, Error> {
        let t = Instant::now();
        let dx = 1.0 / spec.n as f64;
        let h = spec.h_over_dx * dx;
        let band = (h / dx).ceil() + 1.0;
        let mut x = lattice([-band * dx; D], [1.0 + band * dx; D], dx);
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
        let nl = NeighborList::build(NeighborConfig::new(spec.weight, h, 0.0), &x)?;
        let vol = number_density_volumes(&nl);
        let setup_seconds = t.elapsed().as_secs_f64();
        let comps = connectivity(&nl, &role);
        let (u_exact, f): (Vec<f64>, Vec<[f64; D]>) = x
            .iter()
            .zip(&role)
            .map(|(p, r)| {
                let (u, g) = exact(p);
                if r.is_fluid() {
                    (u, g.map(|v| -v))
                } else {
                    (0.0, [0.0; D])
                }
            })
            .unzip();
        let rhs = div_sum(&nl, &vol, &f);
        Ok(BandProblem {
            x,
            role,
            nl,
            vol,
            comps,
            rhs,
            u_exact,
            setup_seconds,
        })
    }

    /// Fluid particles.
    pub fn n_fluid(&self) -> usize {
        self.role.iter().filter(|r| r.is_fluid()).count()
    }

    /// Relative errors of `phi` on `Ω`: `(‖φ − u‖_ℓ2 / ‖u‖_ℓ2, |φ − u|_H¹₀ / |u|_H¹₀)` with
    /// the volume-weighted norms of [`crate::diagnostics`].
    pub fn errors(&self, phi: &[f64]) -> (f64, f64) {
        let (vol, role, u) = (&self.vol, &self.role, &self.u_exact);
        let err: Vec<f64> = phi.iter().zip(u).map(|(a, b)| a - b).collect();
        let l2 = norm_l2(vol, &err, role, Region::Omega) / norm_l2(vol, u, role, Region::Omega);
        let h01 = norm_h01(&self.nl, vol, &err, role, Region::Omega)
            / norm_h01(&self.nl, vol, u, role, Region::Omega);
        (l2, h01)
    }
}
