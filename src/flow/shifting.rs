//! Particle motion in the Lagrangian frame: advection with the projected velocity, Fickian
//! shifting, and the wall margin.
//!
//! `δx_i = −A h |u_i| Δt ∇C_i` with `∇C_i = Σ_j ω_j (1 + R (w_h(r_ij)/w_h(Δx))^n) ∇_i w_h(r_ij)`
//! (Skillen et al. 2013's scaling of Lind et al. 2012's law, with Lind's tensile correction
//! `R = 0.2`, `n = 4`), limited to `max_fraction · Δx`; velocity and pressure are
//! corrected to the new position by a first-order Taylor expansion (Xu et al. 2009),
//! `u_i += (δx_i·∇h) u_i`, `p_i += δx_i·∇h p_i`, with the gradients before the shift.

use crate::boundary::Boundary;
use crate::error::{Error, InputError};
use crate::math::norm2;
use crate::neighbors::NeighborList;
use crate::operators::{grad_diff_into, grad_vec_into};
use crate::particles::Particles;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Fickian particle shifting (Lagrangian frame only).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Shifting {
    /// `A` in `δx = −A h |u| Δt ∇C` (default 2).
    pub coefficient: f64,
    /// Largest shift per step as a fraction of the particle spacing (default 0.2).
    pub max_fraction: f64,
    /// Correct velocity and pressure to the shifted position (default true).
    pub correct: bool,
    /// Scale the shift by the global maximum speed instead of the particle's own speed, so that
    /// stagnation regions (where the strain deforms the distribution most) are shifted too
    /// (default true).
    pub global_speed: bool,
    /// `R` of Lind et al. 2012's tensile correction (default 0.2; 0 disables it): each pair's
    /// contribution to `∇C` is weighted by `1 + R (w_h(r_ij)/w_h(Δx))^n`, so that pairs closer
    /// than the spacing push apart more strongly than the concentration gradient alone would
    /// (against clumping and pairing where the flow compresses the distribution).
    pub tensile: f64,
    /// `n` of the tensile correction (default 4).
    pub tensile_exponent: i32,
}

impl Default for Shifting {
    fn default() -> Self {
        Shifting {
            coefficient: 2.0,
            max_fraction: 0.2,
            correct: true,
            global_speed: true,
            tensile: 0.2,
            tensile_exponent: 4,
        }
    }
}

impl Shifting {
    /// Checks `coefficient` (non-negative, finite) and `max_fraction` (in `[0, 1]`), naming the
    /// first bad one by its key under `shifting` (`shifting.coefficient`).
    pub fn validate(&self) -> Result<(), InputError> {
        if !(self.coefficient >= 0.0 && self.coefficient.is_finite()) {
            return Err(InputError::parameter(
                "shifting.coefficient",
                self.coefficient,
                "must be non-negative and finite",
            ));
        }
        if !(self.max_fraction >= 0.0 && self.max_fraction <= 1.0) {
            return Err(InputError::parameter(
                "shifting.max_fraction",
                self.max_fraction,
                "must be in [0, 1]",
            ));
        }
        if !(self.tensile >= 0.0 && self.tensile.is_finite()) {
            return Err(InputError::parameter(
                "shifting.tensile",
                self.tensile,
                "must be non-negative and finite",
            ));
        }
        if !(1..=16).contains(&self.tensile_exponent) {
            return Err(InputError::parameter(
                "shifting.tensile_exponent",
                self.tensile_exponent as f64,
                "must be in 1..=16",
            ));
        }
        Ok(())
    }
}

/// Scratch of [`shift`]: the shifts and the gradients of the correction.
#[derive(Clone, Debug, Default)]
pub(crate) struct ShiftScratch<const D: usize> {
    shift: Vec<[f64; D]>,
    wall: Vec<[f64; D]>,
    grad: Vec<[[f64; D]; D]>,
    gp: Vec<[f64; D]>,
}

/// What [`advance_particles`] did.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub(crate) struct Moved {
    /// Largest shift (Fickian plus wall margin), distance units.
    pub max_shift: f64,
    /// Fluid particles the wall margin moved back this step.
    pub wall_pushes: usize,
}

/// Moves the fluid particles of `p` with the velocity `u` (the predictor's `u*`: the
/// projection then runs on the moved configuration), `x += Δt u`, plus a shift `δ_i`: the
/// Fickian shift of `sh` (when given) computed at the configuration of `nl`, and the wall part
/// [`Boundary::wall_margin_push`] that keeps every particle at least `margin` inside the walls.
/// `u` and the pressure are corrected to the shifted position by a first-order Taylor
/// expansion with the gradients at the configuration of `nl` (always for the wall part; for the
/// Fickian part when `sh.correct`). Then confines the particles (periodic wrap, a particle still
/// outside is an error) and returns the largest shift and the number of wall pushes. `dx` is
/// the particle spacing; `u` covers every particle (its ghost entries are refilled here).
#[allow(clippy::too_many_arguments)]
pub(crate) fn advance_particles<const D: usize, B: Boundary<D>>(
    sh: Option<&Shifting>,
    dx: f64,
    dt: f64,
    margin: f64,
    p: &mut Particles<D>,
    u: &mut [[f64; D]],
    nl: &NeighborList<D>,
    boundary: &B,
    s: &mut ShiftScratch<D>,
) -> Result<Moved, Error> {
    let n = p.len();
    assert_eq!(u.len(), n, "the advection velocity covers every particle");
    if boundary.has_ghosts() {
        boundary.fill_vector(&p.role, u, crate::boundary::VectorKind::Velocity);
    }
    let kernel = *nl.kernel();
    let h = nl.h();
    let umax = (0..n)
        .filter(|&i| p.role[i].is_fluid())
        .map(|i| norm2(&u[i]).sqrt())
        .fold(0.0, f64::max);
    // Fickian part: δx_i = −A h |u_i| Δt ∇C_i,
    // ∇C_i = Σ_j ω_j (1 + R (w_h(r)/w_h(Δx))^n) ∇_i w_h(r_ij) = −Σ_j ω_j (…) w_h'(r) dx/r
    s.shift.resize(n, [0.0; D]);
    let w_dx = kernel.w_h(dx);
    {
        let p = &*p;
        let u = &*u;
        s.shift.par_iter_mut().enumerate().for_each(|(i, s)| {
            *s = [0.0; D];
            let Some(sh) = sh else { return };
            if !p.role[i].is_fluid() {
                return;
            }
            let mut gc = [0.0; D];
            for k in nl.row(i) {
                let j = nl.indices()[k] as usize;
                let r = nl.r2()[k].sqrt();
                let tensile = if sh.tensile > 0.0 && w_dx > 0.0 {
                    1.0 + sh.tensile * (kernel.w_h(r) / w_dx).powi(sh.tensile_exponent)
                } else {
                    1.0
                };
                let c = -p.vol[j] * tensile * kernel.dw_h(r) / r;
                for a in 0..D {
                    gc[a] += c * nl.dx()[k][a];
                }
            }
            let speed = if sh.global_speed {
                umax
            } else {
                norm2(&u[i]).sqrt()
            };
            let f = -sh.coefficient * h * speed * dt;
            let mut d: [f64; D] = gc.map(|g| f * g);
            let m = norm2(&d).sqrt();
            let lim = sh.max_fraction * dx;
            if m > lim {
                d = d.map(|v| v * lim / m);
            }
            *s = d;
        });
    }
    let correct_fick = sh.is_some_and(|sh| sh.correct);
    // wall part, at the advected and Fick-shifted position
    s.wall.resize(n, [0.0; D]);
    let mut wall_pushes = 0;
    for i in 0..n {
        s.wall[i] = [0.0; D];
        if !p.role[i].is_fluid() {
            continue;
        }
        let x: [f64; D] = std::array::from_fn(|a| p.x[i][a] + dt * u[i][a] + s.shift[i][a]);
        let w = boundary.wall_margin_push(&x, margin);
        if w.iter().any(|&v| v != 0.0) {
            wall_pushes += 1;
            s.wall[i] = w;
        }
    }
    let max_shift = (0..n)
        .map(|i| {
            let d: [f64; D] = std::array::from_fn(|a| s.shift[i][a] + s.wall[i][a]);
            norm2(&d).sqrt()
        })
        .fold(0.0, f64::max);
    if correct_fick || wall_pushes > 0 {
        // Taylor correction of u and p to the shifted position (gradients before the move)
        s.grad.resize(n, [[0.0; D]; D]);
        grad_vec_into(nl, &p.vol, u, &mut s.grad);
        s.gp.resize(n, [0.0; D]);
        grad_diff_into(nl, &p.vol, &p.p, &mut s.gp);
    }
    for i in 0..n {
        if !p.role[i].is_fluid() {
            continue;
        }
        let d: [f64; D] = if correct_fick {
            std::array::from_fn(|a| s.shift[i][a] + s.wall[i][a])
        } else {
            s.wall[i]
        };
        let ui = u[i];
        for a in 0..D {
            p.x[i][a] += dt * ui[a] + s.shift[i][a] + s.wall[i][a];
        }
        if d.iter().any(|&v| v != 0.0) {
            for a in 0..D {
                u[i][a] += (0..D).map(|b| s.grad[i][a][b] * d[b]).sum::<f64>();
            }
            p.p[i] += (0..D).map(|b| s.gp[i][b] * d[b]).sum::<f64>();
        }
    }
    boundary.confine(p)?;
    Ok(Moved {
        max_shift,
        wall_pushes,
    })
}
