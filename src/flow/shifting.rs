//! Fickian particle shifting (Lagrangian frame).
//!
//! `δx_i = −A h |u_i| Δt ∇C_i` with `∇C_i = Σ_j ω_j ∇_i w_h(r_ij)` (Skillen et al. 2013's
//! scaling of Lind et al. 2012's law), limited to `max_fraction · Δx`; velocity and pressure are
//! corrected to the new position by a first-order Taylor expansion (Xu et al. 2009),
//! `u_i += (δx_i·∇h) u_i`, `p_i += δx_i·∇h p_i`, with the gradients before the shift.

use crate::boundary::{Boundary, VectorKind};
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
}

impl Default for Shifting {
    fn default() -> Self {
        Shifting {
            coefficient: 2.0,
            max_fraction: 0.2,
            correct: true,
            global_speed: true,
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
        Ok(())
    }
}

/// Scratch of [`shift`]: the shifts and the gradients of the correction.
#[derive(Clone, Debug, Default)]
pub(crate) struct ShiftScratch<const D: usize> {
    shift: Vec<[f64; D]>,
    grad: Vec<[[f64; D]; D]>,
    gp: Vec<[f64; D]>,
}

/// Shifts the fluid particles of `p` by `sh` at the configuration of `nl` (with velocity and
/// pressure correction when `sh.correct`; `ghosts`: fill the ghosts' velocities first), then
/// confines them to the boundary; returns the largest shift. `dx` is the particle spacing.
#[allow(clippy::too_many_arguments)]
pub(crate) fn shift<const D: usize, B: Boundary<D>>(
    sh: &Shifting,
    dx: f64,
    dt: f64,
    p: &mut Particles<D>,
    nl: &NeighborList<D>,
    boundary: &B,
    ghosts: bool,
    s: &mut ShiftScratch<D>,
) -> Result<f64, Error> {
    let n = p.len();
    let kernel = *nl.kernel();
    let h = nl.h();
    let lim = sh.max_fraction * dx;
    let umax =
        p.u.iter()
            .zip(&p.role)
            .filter(|(_, r)| r.is_fluid())
            .map(|(u, _)| norm2(u))
            .fold(0.0f64, f64::max)
            .sqrt();
    // δx_i = −A h |u_i| Δt ∇C_i,  ∇C_i = Σ_j ω_j ∇_i w_h(r_ij) = −Σ_j ω_j w_h'(r) dx/r
    s.shift.resize(n, [0.0; D]);
    {
        let p = &*p;
        s.shift.par_iter_mut().enumerate().for_each(|(i, s)| {
            *s = [0.0; D];
            if !p.role[i].is_fluid() {
                return;
            }
            let mut gc = [0.0; D];
            for k in nl.row(i) {
                let j = nl.indices()[k] as usize;
                let r = nl.r2()[k].sqrt();
                let c = -p.vol[j] * kernel.dw_h(r) / r;
                for a in 0..D {
                    gc[a] += c * nl.dx()[k][a];
                }
            }
            let speed = if sh.global_speed {
                umax
            } else {
                norm2(&p.u[i]).sqrt()
            };
            let f = -sh.coefficient * h * speed * dt;
            let mut d: [f64; D] = gc.map(|g| f * g);
            let m = norm2(&d).sqrt();
            if m > lim {
                d = d.map(|v| v * lim / m);
            }
            *s = d;
        });
    }
    let max_shift = s.shift.iter().map(|d| norm2(d).sqrt()).fold(0.0, f64::max);
    if sh.correct {
        // Taylor correction of u and p to the shifted position (gradients before the shift)
        if ghosts {
            boundary.fill_vector(&p.role, &mut p.u, VectorKind::Velocity);
        }
        s.grad.resize(n, [[0.0; D]; D]);
        grad_vec_into(nl, &p.vol, &p.u, &mut s.grad);
        s.gp.resize(n, [0.0; D]);
        grad_diff_into(nl, &p.vol, &p.p, &mut s.gp);
        for i in 0..n {
            if !p.role[i].is_fluid() {
                continue;
            }
            let d = s.shift[i];
            for a in 0..D {
                p.u[i][a] += (0..D).map(|b| s.grad[i][a][b] * d[b]).sum::<f64>();
            }
            p.p[i] += (0..D).map(|b| s.gp[i][b] * d[b]).sum::<f64>();
        }
    }
    for i in 0..n {
        if p.role[i].is_fluid() {
            for a in 0..D {
                p.x[i][a] += s.shift[i][a];
            }
        }
    }
    boundary.confine(p)?;
    Ok(max_shift)
}
