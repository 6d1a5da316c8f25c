//! An inhomogeneous, second-order Dirichlet band: the increment `φ` continued into the band
//! so that it vanishes on a surface beyond it.
//!
//! The paper's Poisson problem holds `φ = 0` on every band particle. A band has the width `h`
//! (it must hold every neighbour outside the fluid), so the zero is imposed over a layer rather
//! than on a surface, and the fluid's `φ` has a kink at the band's inner edge; the gradient
//! fits next to the band see it unevenly wherever the particles are not a lattice. Measured on
//! a Vogel-spiral disk (`examples/spiral_disk.rs`, n = 4000): projecting the source flow
//! `u = (x, y)` leaves a spurious swirl of 8·10⁻² of a vortex's speed with the consistent
//! operators, all of it within `h` of the band.
//!
//! Here the band's values are `g_b = q(x_b) − q(x_s)`: `q` the weighted least-squares
//! quadratic through the fluid's `φ` around the band particle `x_b` (the fluid particles of a
//! separate neighbour list, e.g. of radius `2h`, weighted by its kernel), `x_s` the band
//! particle's foot on the surface, given by the caller. It is exact for every quadratic `φ`
//! that vanishes on the surface. As `g` depends on the fluid's `φ`, which depends on `g`
//! ([`ProjectionStep::set_band_increment`]), the pair is an affine fixed point, solved by
//! Anderson mixing over the projections ([`ProjectionStep::project_to_surface`]).

use super::{ProjectionParams, ProjectionStep, StepReport};
use crate::boundary::Boundary;
use crate::error::{Error, SolveError};
use crate::neighbors::NeighborList;
use crate::particles::{Particles, Role};
use nalgebra::{DMatrix, DVector};
use rayon::prelude::*;

/// The foot on the surface of band particle `i` at `x` (`None`: no value there, `g = 0`).
pub type Foot<'a, const D: usize> = dyn Fn(usize, &[f64; D]) -> Option<[f64; D]> + Sync + 'a;

/// Where the band's surface is and how the fixed point is solved.
pub struct SurfaceBand<'a, const D: usize> {
    /// Neighbours for the fits (radius about `2h`: a band particle at the band's outer edge
    /// needs fluid particles on one side only, at up to `h` and beyond).
    pub fit: &'a NeighborList<D>,
    /// The foot of band particle `i` at `x` on the surface (`None`: no value, `g = 0`).
    pub foot: &'a Foot<'a, D>,
    /// The fixed point is reached when the band values change by at most `tol` times their
    /// largest magnitude (or `tol` absolute when that is below 1).
    pub tol: f64,
    /// At most this many projections.
    pub max_solves: usize,
}

/// Number of terms of a quadratic in `D` variables.
const fn terms(d: usize) -> usize {
    1 + d + d * (d + 1) / 2
}

/// The first `m` terms of the quadratic basis at offset `r` (scaled by `s`): `1, r_a,
/// r_a r_b (a ≤ b)`.
fn basis<const D: usize>(r: &[f64; D], s: f64, m: usize) -> Vec<f64> {
    let mut e = Vec::with_capacity(terms(D));
    e.push(1.0);
    e.extend(r.iter().map(|v| v / s));
    for a in 0..D {
        for b in a..D {
            e.push(r[a] * r[b] / (s * s));
        }
    }
    e.truncate(m);
    e
}

/// The band's values `g_b = q(x_b) − q(x_s)` for the fluid's `phi` ([module docs](self)):
/// indexed like the particles, zero off the band. Where the fluid around a band particle
/// does not determine a quadratic (fewer than twice its terms, or a fit matrix whose
/// eigenvalues spread by more than 10¹² — e.g. only two layers of fluid within reach), the fit
/// is linear (`g_b = ∇q·(x_b − x_s)`), and `g_b = 0` (the paper's value) where not even that
/// is determined or there is no foot.
pub fn extrapolate_to_surface<const D: usize>(
    p: &Particles<D>,
    phi: &[f64],
    fit: &NeighborList<D>,
    foot: &Foot<'_, D>,
) -> Vec<f64> {
    let s = fit.h();
    (0..p.len())
        .into_par_iter()
        .map(|b| {
            if p.role[b] != Role::Dirichlet || b >= fit.len() {
                return 0.0;
            }
            let Some(xs) = foot(b, &p.x[b]) else {
                return 0.0;
            };
            let ds: [f64; D] = std::array::from_fn(|k| xs[k] - p.x[b][k]);
            [terms(D), 1 + D]
                .into_iter()
                .find_map(|m| {
                    let c = fit_at(p, phi, fit, b, m, s)?;
                    Some(c[0] - DVector::from_vec(basis(&ds, s, m)).dot(&c))
                })
                .unwrap_or(0.0)
        })
        .collect()
}

/// The weighted least-squares fit of the first `m` basis terms through the fluid's `phi`
/// around particle `b`, `None` when it is not determined.
fn fit_at<const D: usize>(
    p: &Particles<D>,
    phi: &[f64],
    fit: &NeighborList<D>,
    b: usize,
    m: usize,
    s: f64,
) -> Option<DVector<f64>> {
    let (mut a, mut r) = (DMatrix::<f64>::zeros(m, m), DVector::<f64>::zeros(m));
    let mut count = 0;
    for k in fit.row(b) {
        let j = fit.indices()[k] as usize;
        let w = fit.w()[k];
        // fluid particles and their wall images (which carry their sources' φ)
        if w <= 0.0 || crate::diagnostics::alias(&p.role, j).is_none() {
            continue;
        }
        // offset x_j − x_b (the list's dx, minimum image included)
        let e = DVector::from_vec(basis(&fit.dx()[k], s, m));
        a += w * &e * e.transpose();
        r += w * phi[j] * &e;
        count += 1;
    }
    if count < 2 * m {
        return None;
    }
    let ev = a.clone().symmetric_eigenvalues();
    let (lo, hi) = ev.iter().fold((f64::INFINITY, 0.0f64), |(lo, hi), &v| {
        (lo.min(v), hi.max(v))
    });
    if !(lo > 1e-12 * hi) {
        return None;
    }
    a.cholesky().map(|ch| ch.solve(&r))
}

impl<const D: usize> ProjectionStep<D> {
    /// [`project`](Self::project) with the band's increment continued to vanish on a surface
    /// beyond it ([module docs](crate::projection::surface)): projections from the same
    /// `particles` state and `u_star`, each with the band values extrapolated from the last,
    /// Anderson-mixed (depth 6) until they settle. Returns the last projection's report and
    /// the number of projections; the band values stay set
    /// ([`band_increment`](Self::band_increment)) for a warm start of the next call.
    /// Fails like [`project`](Self::project), and with [`SolveError::BandNotConverged`]
    /// after `surface.max_solves` projections.
    #[allow(clippy::too_many_arguments)]
    pub fn project_to_surface(
        &mut self,
        particles: &mut Particles<D>,
        nl: &NeighborList<D>,
        boundary: &dyn Boundary<D>,
        params: &ProjectionParams<D>,
        dt: f64,
        u_star: &[[f64; D]],
        surface: &SurfaceBand<'_, D>,
    ) -> Result<(StepReport, usize), Error> {
        let band: Vec<usize> = (0..particles.len())
            .filter(|&i| particles.role[i] == Role::Dirichlet)
            .collect();
        let (u0, p0) = (particles.u.clone(), particles.p.clone());
        let start = std::mem::take(&mut self.band_phi);
        let mut g: Vec<f64> = band
            .iter()
            .map(|&b| start.get(b).copied().unwrap_or(0.0))
            .collect();
        let (mut hist_f, mut hist_r): (Vec<Vec<f64>>, Vec<Vec<f64>>) = (Vec::new(), Vec::new());
        let mut solves = 0;
        loop {
            let mut full = vec![0.0; particles.len()];
            for (k, &b) in band.iter().enumerate() {
                full[b] = g[k];
            }
            self.band_phi = full;
            particles.u.clone_from(&u0);
            particles.p.clone_from(&p0);
            let report = self.project(particles, nl, boundary, params, dt, u_star)?;
            solves += 1;
            let e = extrapolate_to_surface(particles, &self.phi, surface.fit, surface.foot);
            let fg: Vec<f64> = band.iter().map(|&b| e[b]).collect();
            let r: Vec<f64> = fg.iter().zip(&g).map(|(a, b)| a - b).collect();
            let change = r.iter().fold(0.0f64, |m, v| m.max(v.abs()));
            let scale = fg.iter().fold(1.0f64, |m, v| m.max(v.abs()));
            if change <= surface.tol * scale || band.is_empty() {
                return Ok((report, solves));
            }
            if solves >= surface.max_solves {
                return Err(SolveError::BandNotConverged { solves, change }.into());
            }
            hist_f.push(fg.clone());
            hist_r.push(r.clone());
            if hist_f.len() > 7 {
                hist_f.remove(0);
                hist_r.remove(0);
            }
            g = fg;
            let m = hist_r.len() - 1;
            if m > 0 {
                let dr = DMatrix::from_fn(band.len(), m, |i, j| hist_r[j + 1][i] - hist_r[j][i]);
                if let Ok(gamma) = dr.svd(true, true).solve(&DVector::from_vec(r), 1e-14) {
                    for (j, gj) in gamma.iter().enumerate() {
                        for (i, gi) in g.iter_mut().enumerate() {
                            *gi -= gj * (hist_f[j + 1][i] - hist_f[j][i]);
                        }
                    }
                }
            }
        }
    }
}
