//! Free surfaces: which moving particles form the Dirichlet band `p = 0`.
//!
//! Every step, after the particles moved and their neighbours were brought up to date, each
//! particle of the water (fluid or band) gets its *number density* `n_i = Σ_{j≠i} w_h(r_ij)`
//! (wall images included, so a wall does not look like a surface) and is a surface particle,
//! [`Role::Dirichlet`], when `n_i < β n₀`; otherwise it is [`Role::Fluid`]. `n₀` is the number
//! density of a full lattice of spacing `Δx` (the initial spacing), `β` the
//! [`threshold`](FreeSurface::threshold) (Koshizuka & Oka 1996's test, as in MPS; the default
//! 0.9 selects the outermost row of a lattice at rest with `h = 3Δx`, measured by the tests).
//! A particle that left the bulk — a splash — has a small number density, so it is a surface
//! particle too: it moves ballistically under the body force (the band's pressure is zero, and
//! its neighbours, if any, are band particles) until it rejoins.
//!
//! The band is the paper's Dirichlet band: the Poisson problem on the fluid is then anchored
//! wherever the fluid touches the surface (Theorem 4.1), its h-connectivity to the band is checked
//! before every solve, and a cluster of fluid without a path to the band is a floating component
//! handled by [`crate::projection::Disconnected`]. The band moves with the flow
//! ([`crate::projection::ProjectionParams::free_surface`]): predicted and corrected like fluid, its
//! pressure held at zero.

use crate::error::InputError;
use crate::kernel::Kernel;
use crate::neighbors::NeighborList;
use crate::particles::{Particles, Role};
use serde::{Deserialize, Serialize};

/// Free-surface detection parameters.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct FreeSurface {
    /// `β`: a particle whose number density is below `β n₀` is a surface particle (default 0.9;
    /// in `(0, 1)`).
    pub threshold: f64,
    /// `δ/Δx`: how far outside a surface particle's centre the surface lies, in particle
    /// spacings (default 0.5: a particle stands for a cell of side `Δx`). The band's pressure
    /// is then `p_b = −δ ρ n·(∇p/ρ)_b` (`n` the outward normal, `∇p` of the last step), the
    /// value that puts `p = 0` on the surface rather than at the particle; 0 gives the paper's
    /// `p_b = 0` (measured on the tank at rest, n = 40: pressure error 2.2 % with it at 0, the
    /// offset `ρ g Δx/2` of every particle). The solve holds the band at `p_b` in every
    /// scheme (the incremental ones through `pⁿ + φ` with `φ = 0`, the non-incremental one as
    /// the band's Dirichlet values).
    pub surface_offset: f64,
}

impl Default for FreeSurface {
    fn default() -> Self {
        FreeSurface {
            threshold: 0.9,
            surface_offset: 0.5,
        }
    }
}

impl FreeSurface {
    /// Checks `0 < threshold < 1`.
    pub fn validate(&self) -> Result<(), InputError> {
        if !(self.threshold > 0.0 && self.threshold < 1.0) {
            return Err(InputError::parameter(
                "free_surface.threshold",
                self.threshold,
                "the number-density threshold must be in (0, 1)",
            ));
        }
        if !(self.surface_offset.is_finite() && (0.0..=1.0).contains(&self.surface_offset)) {
            return Err(InputError::parameter(
                "free_surface.surface_offset",
                self.surface_offset,
                "the surface's distance beyond the band particles must be in [0, 1] spacings",
            ));
        }
        Ok(())
    }
}

/// The band's pressure with the surface `delta` beyond each band particle:
/// `p_b = max(0, −δ ρ n·g_b)` with `g = ∇p/ρ` and `n` the outward normal
/// `Σ_j w_ij (x_i − x_j) / |…|` over all neighbours (0 without any).
pub fn set_band_pressure<const D: usize>(
    p: &mut Particles<D>,
    nl: &NeighborList<D>,
    grad_over_rho: &[[f64; D]],
    rho: f64,
    delta: f64,
) {
    for i in 0..p.len() {
        if p.role[i] != Role::Dirichlet {
            continue;
        }
        let mut n = [0.0; D];
        for k in nl.row(i) {
            for a in 0..D {
                n[a] -= nl.w()[k] * nl.dx()[k][a];
            }
        }
        let norm = n.iter().map(|v| v * v).sum::<f64>().sqrt();
        p.p[i] = if norm > 0.0 {
            let dn: f64 = (0..D).map(|a| n[a] * grad_over_rho[i][a]).sum::<f64>() / norm;
            (-delta * rho * dn).max(0.0)
        } else {
            0.0
        };
    }
}

/// What one detection found.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct SurfaceCount {
    /// Particles of the band (surface particles) after the detection.
    pub surface: usize,
    /// Band particles without a fluid neighbour within `h`: particles that left the bulk
    /// (droplets, jets one particle thick, isolated particles).
    pub splash: usize,
}

/// `n₀ = Σ_{k ≠ 0} w_h(|k| Δx)` over the points `k Δx` of a full `D`-dimensional lattice: the
/// number density of a particle deep inside a lattice of spacing `dx`.
pub fn lattice_number_density<const D: usize>(kernel: &Kernel<D>, dx: f64) -> f64 {
    let m = (kernel.h() / dx).ceil() as i64;
    let side = (2 * m + 1) as usize;
    let mut total = 0.0;
    for idx in 0..side.pow(D as u32) {
        let mut rest = idx;
        let mut r2 = 0.0;
        for _ in 0..D {
            let k = (rest % side) as i64 - m;
            rest /= side;
            r2 += (k as f64 * dx).powi(2);
        }
        if r2 > 0.0 {
            total += kernel.w_h(r2.sqrt());
        }
    }
    total
}

/// Sets the role of every fluid and band particle of `p` by its number density against
/// `threshold · n0`; with `reset_pressure` a band particle gets the band's pressure, zero (else
/// it keeps its pressure for [`set_band_pressure`]). Ghosts keep their role (their source's
/// role decides what they stand for).
pub fn detect<const D: usize>(
    p: &mut Particles<D>,
    nl: &NeighborList<D>,
    n0: f64,
    threshold: f64,
    reset_pressure: bool,
) -> SurfaceCount {
    let cut = threshold * n0;
    let mut surface = 0;
    for i in 0..p.len() {
        if !p.role[i].is_real() {
            continue;
        }
        let n: f64 = nl.row(i).map(|k| nl.w()[k]).sum();
        if n < cut {
            p.role[i] = Role::Dirichlet;
            if reset_pressure {
                p.p[i] = 0.0;
            }
            surface += 1;
        } else {
            p.role[i] = Role::Fluid;
        }
    }
    let splash = (0..p.len())
        .filter(|&i| p.role[i] == Role::Dirichlet)
        .filter(|&i| {
            !nl.row(i).any(|k| {
                nl.w()[k] > 0.0
                    && crate::diagnostics::alias(&p.role, nl.indices()[k] as usize).is_some()
            })
        })
        .count();
    SurfaceCount { surface, splash }
}
