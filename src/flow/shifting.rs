//! Particle motion in the Lagrangian frame: advection with the projected velocity, the shift
//! that keeps the distribution regular, and the wall margin.
//!
//! The move is `x += Δt u + Δt²/2 a + δ` (`a` the material acceleration of the last step) with
//! the shift `δ_i` the sum of
//! - the **pair repulsion** (default): `κ Σ_j (r_c − r_ij)₊ (x_i − x_j)/r_ij`, `r_c = Δx`: a
//!   pair closer than the spacing moves apart by `2κ` of the overlap; a distribution without
//!   such pairs is left alone, so the shift adds no error where the flow keeps the particles
//!   apart;
//! - the **Fickian shift** (off by default): `−A h |u_i| Δt ∇C_i` with
//!   `∇C_i = Σ_j ω_j (1 + R (w_h(r_ij)/w_h(Δx))^n) ∇_i w_h(r_ij)` (Skillen et al. 2013's
//!   scaling of Lind et al. 2012's law, with Lind's tensile correction `R = 0.2`, `n = 4`),
//! - the **volume shift** ([`Shifting::volume`]): `−β ∇h χ` with `−Δh χ` the relative
//!   volume error, one extra solve with the projection's Poisson matrix
//!   ([`crate::projection::ProjectionStep::volume_shift_into`]),
//!
//! limited to `max_fraction · Δx`. Velocity and pressure are corrected to the shifted position
//! by a Taylor expansion (Xu et al. 2009) with the derivatives before the shift: second order,
//! `u += δ·∇u + ½ δᵀ(∇∇u)δ`, with the least-squares operators (the second derivatives as the
//! least-squares gradients of the first, except in rows that see a wall ghost), first order
//! with the GPM gradient otherwise; the corrected velocity is kept within the range of the
//! particle's and its neighbours' velocities before the move (a centred correction is an
//! unlimited advection by the shift, unstable where the velocity jumps within `h`).

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
    /// `A` in `δx = −A h |u| Δt ∇C` (default 0: off; Lind et al. use 1–6).
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
    /// `κ` of the pair repulsion: every pair closer than `repulsion_radius · Δx` pushes both
    /// particles apart by `κ (r_c − r_ij)` each (default 0.25). A distribution whose pairs
    /// are all at least `r_c` apart (the square and the hexagonal lattice at `r_c ≤ Δx`) is left
    /// alone; a flow that compresses the distribution along one axis (a stagnation point),
    /// which the concentration gradient cannot see, is answered by the pairs it brings close.
    pub repulsion: f64,
    /// `r_c/Δx` of the pair repulsion (default 1).
    pub repulsion_radius: f64,
    /// `β` of the volume shift (default 0: off): `δ_i = −β ∇h χ_i` with `−Δh χ = e`,
    /// `e_i = ω̄/ω_i − 1` (`ω_i = 1/Σ_j w_h(r_ij)` the number-density volumes, `ω̄` their mean,
    /// so that `Σ_i ω_i e_i = 0`), solved with the projection's own Poisson matrix
    /// and solver, `χ` continued evenly into the wall ghosts (a Neumann problem: no shift
    /// through a wall). It moves particles out of compressed regions into emptied ones by a
    /// displacement whose divergence is `β e`: a global correction of the distribution, where the
    /// pair repulsion and the Fickian term only see a particle's own neighbourhood. Not applied
    /// with a free surface (the surface's number-density deficit is not an error).
    pub volume: f64,
    /// Relative tolerance of the volume shift's solve for `χ` (default 10⁻⁶; the projection's
    /// `solve.rel_tol` does not apply to it). The shift is a correction of the particle
    /// distribution — its displacement `β ∇h χ` is at most `max_fraction · Δx` and mostly far
    /// less — so digits of `χ` beyond a few are spent on a displacement no one can see, while
    /// the warm start of the solve (the last step's `χ`) predicts nothing: the shift answers
    /// last step's error, and the new one starts afresh (`‖b − Kχ₀‖/‖b‖ ≈ 1`). Measured on the
    /// Lagrangian cavity (Re 100, n = 100, t = 10, README *Moving particles*): 27 AMG-CG
    /// iterations a step at 10⁻¹⁰ (27 % of the run), 17 at 10⁻⁶, 12 at 10⁻⁴; the RMS errors
    /// against the reference move within the particle noise (which changes them as much
    /// between these runs as between different steps).
    pub volume_tol: f64,
}

/// The default relative tolerance of the volume shift's solve ([`Shifting::volume_tol`]).
pub const VOLUME_TOL: f64 = 1e-6;

impl Default for Shifting {
    /// The pair repulsion alone (`κ = 0.25`, `r_c = Δx`), no Fickian term: measured on the
    /// Lagrangian Taylor–Green vortex (n = 50, t = 2), Fickian shifting (`A = 2`) blows up at
    /// t ≈ 1.3 — its own step is unstable at that strength (particles jump past each other:
    /// minimum spacing 0.07Δx) and weaker ones cannot follow the strain — while the repulsion
    /// keeps every pair above 0.5Δx to the end with L1 error 0.76 %.
    fn default() -> Self {
        Shifting {
            coefficient: 0.0,
            max_fraction: 0.2,
            correct: true,
            global_speed: true,
            tensile: 0.2,
            tensile_exponent: 4,
            repulsion: 0.25,
            repulsion_radius: 1.0,
            volume: 0.0,
            volume_tol: VOLUME_TOL,
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
        if !(0.0..=0.5).contains(&self.repulsion) {
            return Err(InputError::parameter(
                "shifting.repulsion",
                self.repulsion,
                "must be in [0, 0.5] (a pair closer than r_c moves apart by 2κ of the overlap)",
            ));
        }
        if !(0.0..=16.0).contains(&self.volume) {
            return Err(InputError::parameter(
                "shifting.volume",
                self.volume,
                "must be in [0, 16]",
            ));
        }
        if !(self.volume_tol > 0.0 && self.volume_tol < 1.0) {
            return Err(InputError::parameter(
                "shifting.volume_tol",
                self.volume_tol,
                "must be in (0, 1)",
            ));
        }
        if !(self.repulsion_radius > 0.0 && self.repulsion_radius <= 2.0) {
            return Err(InputError::parameter(
                "shifting.repulsion_radius",
                self.repulsion_radius,
                "must be in (0, 2]",
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

/// The least-squares operators of the configuration before the move: the wall variant for
/// velocities and the plain variant for pressures.
pub(crate) type LsPair<'a, const D: usize> = (
    &'a crate::consistent::LsOperators<D>,
    &'a crate::consistent::LsOperators<D>,
);

/// Scratch of [`shift`]: the shifts and the gradients of the correction.
#[derive(Clone, Debug, Default)]
pub(crate) struct ShiftScratch<const D: usize> {
    shift: Vec<[f64; D]>,
    wall: Vec<[f64; D]>,
    grad: Vec<[[f64; D]; D]>,
    gp: Vec<[f64; D]>,
    /// `hess[i][a][c][b] = ∂_b ∂_c u_a` (least-squares gradients of the gradients).
    hess: Vec<[[[f64; D]; D]; D]>,
    /// `hp[i][c][b] = ∂_b ∂_c p`.
    hp: Vec<[[f64; D]; D]>,
    /// Rows with a ghost neighbour (no second-order term there).
    near_wall: Vec<bool>,
    /// Take the Taylor correction's difference gradients and velocity range in passes of their
    /// own (the operators' functions) rather than in the shift's pass over the pairs: the same
    /// bits, a check of the fused pass.
    pub(crate) separate_passes: bool,
    /// Per particle and component: the smallest and largest velocity among the particle and
    /// its neighbours within `h` before the move (ghosts at their wall point), the range the
    /// Taylor-corrected velocity is kept in.
    range: Vec<[[f64; 2]; D]>,
}

impl<const D: usize> ShiftScratch<D> {
    /// Particle `i`'s last move beyond the advection ([`advance_particles`]): the length of
    /// its shift (Fickian plus wall margin) and whether the wall margin pushed it; `None`
    /// before the first move.
    pub(crate) fn last_move(&self, i: usize) -> Option<(f64, bool)> {
        let (s, w) = (self.shift.get(i)?, self.wall.get(i)?);
        let d: [f64; D] = std::array::from_fn(|a| s[a] + w[a]);
        Some((norm2(&d).sqrt(), w.iter().any(|&v| v != 0.0)))
    }
}

/// What [`advance_particles`] did.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub(crate) struct Moved {
    /// Largest shift (Fickian plus wall margin), distance units.
    pub max_shift: f64,
    /// Fluid particles the wall margin moved back this step.
    pub wall_pushes: usize,
}

/// Moves the fluid particles of `p` with the velocity `u` and the material acceleration
/// `accel` of the last step (empty on the first), `x += Δt u + Δt²/2 a` (second order in time:
/// with `x += Δt u` alone the trajectories, and with them the velocity sampled along them, are
/// first order), plus a shift `δ_i`: the
/// Fickian shift of `sh` (when given) computed at the configuration of `nl`, plus
/// `volume_shift` (the volume shift of [`Shifting::volume`], computed by the caller; empty for
/// none) — together limited to `max_fraction · Δx` — and the wall part
/// [`Boundary::wall_margin_push`] that keeps every particle at least `margin` inside the walls.
/// `u` and the pressure are corrected to the shifted position by a first-order Taylor
/// expansion with the gradients at the configuration of `nl` (always for the wall part; for the
/// Fickian part when `sh.correct`). Then confines the particles (periodic wrap, a particle still
/// outside is an error) and returns the largest shift and the number of wall pushes. `dx` is
/// the particle spacing; `u` covers every particle (its ghost entries are refilled here).
/// With `band_moves` (a free surface) the Dirichlet particles move too, and their Fickian shift
/// is only its part tangential to the surface (normal to `∇C`): a surface particle shifted
/// along the normal would change the shape of the surface.
#[allow(clippy::too_many_arguments)]
pub(crate) fn advance_particles<const D: usize, B: Boundary<D>>(
    sh: Option<&Shifting>,
    band_moves: bool,
    dx: f64,
    dt: f64,
    global_speed: Option<f64>,
    margin: f64,
    p: &mut Particles<D>,
    u: &mut [[f64; D]],
    accel: &[[f64; D]],
    rho_g: [f64; D],
    nl: &NeighborList<D>,
    ls: Option<LsPair<'_, D>>,
    boundary: &B,
    s: &mut ShiftScratch<D>,
    volume_shift: &[[f64; D]],
) -> Result<Moved, Error> {
    let n = p.len();
    assert_eq!(u.len(), n, "the advection velocity covers every particle");
    let moves = |r: &crate::particles::Role| {
        r.is_fluid() || band_moves && *r == crate::particles::Role::Dirichlet
    };
    if boundary.has_ghosts() {
        boundary.fill_velocity(&p.x, &p.role, u);
    }
    let kernel = *nl.kernel();
    let h = nl.h();
    // (only a shift at the global speed reads it)
    let umax = match global_speed {
        Some(v) => v,
        None if sh.is_some_and(|sh| sh.global_speed) => u
            .par_iter()
            .zip(&p.role)
            .filter(|(_, r)| moves(r))
            .map(|(ui, _)| norm2(ui).sqrt())
            .reduce(|| 0.0, f64::max),
        None => 0.0,
    };
    let correct_fick = sh.is_some_and(|sh| sh.correct);
    // With the difference gradients (no least-squares operators) the Taylor correction's
    // gradients `∇h u` and `∇h p` and the velocity's range are taken in the shift's own pass
    // over each row, the wall part with them: one pass over the pairs instead of four (the
    // shift, `grad_vec_into`, `grad_diff_into`, `velocity_range`), the same bits.
    let fused = correct_fick && ls.is_none() && !s.separate_passes;
    if fused && boundary.has_ghosts() {
        boundary.fill_pressure(&p.x, &p.role, &mut p.p, rho_g);
    }
    // the advection displacement Δt u + Δt²/2 a
    let half_dt2 = 0.5 * dt * dt;
    let advect = |ui: &[f64; D], i: usize, a: usize| {
        dt * ui[a] + accel.get(i).map_or(0.0, |acc| half_dt2 * acc[a])
    };
    // Fickian part: δx_i = −A h |u_i| Δt ∇C_i,
    // ∇C_i = Σ_j ω_j (1 + R (w_h(r)/w_h(Δx))^n) ∇_i w_h(r_ij) = −Σ_j ω_j (…) w_h'(r) dx/r;
    // then the wall part at the advected and shifted position, the pushes counted and the
    // largest shift taken in the same pass
    s.shift.resize(n, [0.0; D]);
    s.wall.resize(n, [0.0; D]);
    if fused {
        s.grad.resize(n, [[0.0; D]; D]);
        s.gp.resize(n, [0.0; D]);
        s.range.resize(n, [[0.0; 2]; D]);
    }
    s.hess.clear();
    let w_dx = kernel.w_h(dx);
    let dim = D as f64;
    let (wall_pushes, max_shift) = {
        let p = &*p;
        let u = &*u;
        // particle `i`'s shift (a moving particle), and with `out` its fused gradients and range
        let shift_of = |sh: &Shifting, i: usize, out: Option<RowSlots<'_, D>>| -> [f64; D] {
            // ∇C: the Fickian term's direction, and the surface normal of a band particle (the
            // default shifting, pair repulsion alone, reads it only there)
            let is_band = p.role[i] == crate::particles::Role::Dirichlet;
            let mut gc = [0.0; D];
            let pairs = if sh.coefficient > 0.0 || is_band {
                nl.row(i)
            } else {
                0..0
            };
            for k in pairs {
                let j = nl.indices()[k] as usize;
                let r = nl.r2(k).sqrt();
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
            // the pair repulsion, and the fused gradients and range (each summed in the order
            // of its own pass: `grad_vec_row`, `grad_diff_into`, `velocity_range`)
            let repel = sh.repulsion > 0.0;
            let rc = sh.repulsion_radius * dx;
            let kappa = sh.repulsion;
            match out {
                Some((go, gpo, ro)) => {
                    let (g, gp, range) = if repel {
                        row_pass::<D, true, true>(nl, p, u, i, rc, kappa, &mut d)
                    } else {
                        row_pass::<D, false, true>(nl, p, u, i, rc, kappa, &mut d)
                    };
                    *go = g.map(|row| row.map(|v| v * dim));
                    *gpo = gp.map(|v| dim * v);
                    *ro = range;
                }
                None if repel => {
                    row_pass::<D, true, false>(nl, p, u, i, rc, kappa, &mut d);
                }
                None => {}
            }
            if let Some(v) = volume_shift.get(i) {
                for a in 0..D {
                    d[a] += v[a];
                }
            }
            if is_band {
                // tangential only: remove the part along the surface normal ∇C/|∇C|
                let g2 = norm2(&gc);
                if g2 > 0.0 {
                    let dn = (0..D).map(|a| d[a] * gc[a]).sum::<f64>() / g2;
                    for a in 0..D {
                        d[a] -= dn * gc[a];
                    }
                }
            }
            let m = norm2(&d).sqrt();
            let lim = sh.max_fraction * dx;
            if m > lim {
                d = d.map(|v| v * lim / m);
            }
            d
        };
        // one particle: its shift (the fused sums into `slots`), then the wall part; whether
        // it was pushed and the length of its whole shift
        let one = |i: usize,
                   shift: &mut [f64; D],
                   wall: &mut [f64; D],
                   slots: Option<RowSlots<'_, D>>| {
            *shift = [0.0; D];
            *wall = [0.0; D];
            if !moves(&p.role[i]) {
                return (0, 0.0);
            }
            if let Some(sh) = sh {
                *shift = shift_of(sh, i, slots);
            }
            let x: [f64; D] = std::array::from_fn(|a| p.x[i][a] + advect(&u[i], i, a) + shift[a]);
            *wall = boundary.wall_margin_push(&x, margin);
            let pushed = wall.iter().any(|&v| v != 0.0) as usize;
            let d: [f64; D] = std::array::from_fn(|a| shift[a] + wall[a]);
            (pushed, norm2(&d).sqrt())
        };
        let add = |a: (usize, f64), b: (usize, f64)| (a.0 + b.0, a.1.max(b.1));
        let moves_and_shifts = s.shift.par_iter_mut().zip(s.wall.par_iter_mut());
        if fused {
            let sums = s.grad.par_iter_mut().zip(s.gp.par_iter_mut());
            moves_and_shifts
                .zip(sums.zip(s.range.par_iter_mut()))
                .enumerate()
                .with_min_len(1024)
                .map(|(i, ((shift, wall), ((g, gp), r)))| one(i, shift, wall, Some((g, gp, r))))
                .reduce(|| (0, 0.0), add)
        } else {
            moves_and_shifts
                .enumerate()
                .with_min_len(1024)
                .map(|(i, (shift, wall))| one(i, shift, wall, None))
                .reduce(|| (0, 0.0), add)
        }
    };
    if !fused && (correct_fick || wall_pushes > 0) {
        // the gradients at the configuration before the move, for the Taylor correction of
        // u and p to the shifted position
        s.grad.resize(n, [[0.0; D]; D]);
        s.gp.resize(n, [0.0; D]);
        if boundary.has_ghosts() {
            boundary.fill_pressure(&p.x, &p.role, &mut p.p, rho_g);
        }
        match ls {
            Some((lu, lp)) => {
                lu.grad_vec_into(nl, u, &mut s.grad);
                lp.grad_into(nl, &p.p, &mut s.gp);
                second_derivatives(nl, lp, p, s);
            }
            None => {
                grad_vec_into(nl, &p.vol, u, &mut s.grad);
                grad_diff_into(nl, &p.vol, &p.p, &mut s.gp);
            }
        }
    }
    if correct_fick && !fused {
        velocity_range(nl, &p.role, u, &mut s.range);
    }
    let s = &*s;
    let role = &p.role;
    let particle =
        p.x.par_iter_mut()
            .zip(u.par_iter_mut())
            .zip(p.p.par_iter_mut());
    particle
        .enumerate()
        .with_min_len(1024)
        .for_each(|(i, ((x, ui), pi))| {
            if !moves(&role[i]) {
                return;
            }
            // the velocity follows the shift by its Taylor expansion; the wall part is a stop, not
            // a displacement within the flow: the particle keeps its velocity except the part
            // into the wall (extrapolating it to the pushed position instead, with the wall's
            // value a fraction of Δx away, multiplies that part by (s + δ)/s every step — the
            // pushed particle then runs into the wall ever faster)
            let d: [f64; D] = if correct_fick { s.shift[i] } else { [0.0; D] };
            let w = s.wall[i];
            for a in 0..D {
                x[a] += advect(ui, i, a) + s.shift[i][a] + w[a];
            }
            if d.iter().any(|&v| v != 0.0) {
                // u(x + δ) = u + δ·∇u + ½ δᵀ(∇∇u)δ: with the first-order term alone, every shift
                // diffuses the velocity by ½|δ|²∇²u (a decay error growing with the step count)
                let second = !s.hess.is_empty() && !s.near_wall[i];
                let quad = |h: &[[f64; D]; D]| -> f64 {
                    0.5 * (0..D)
                        .map(|c| d[c] * (0..D).map(|b| h[c][b] * d[b]).sum::<f64>())
                        .sum::<f64>()
                };
                for a in 0..D {
                    ui[a] += (0..D).map(|b| s.grad[i][a][b] * d[b]).sum::<f64>();
                    if second {
                        ui[a] += quad(&s.hess[i][a]);
                    }
                    // no new extremum: the correction is an advection by the shift, and a centred
                    // one is unstable where the velocity jumps within h (the lid corners: a
                    // Lagrangian cavity at Re 1000 blew up there within 22 steps)
                    let [lo, hi] = s.range[i][a];
                    ui[a] = ui[a].clamp(lo, hi);
                }
                *pi += (0..D).map(|b| s.gp[i][b] * d[b]).sum::<f64>();
                if second {
                    *pi += quad(&s.hp[i]);
                }
            }
            for a in 0..D {
                if w[a] != 0.0 {
                    // the pressure (a Neumann field at the wall) is expanded to the new position
                    *pi += s.gp[i][a] * w[a];
                    if ui[a] * w[a] < 0.0 {
                        ui[a] = 0.0;
                    }
                }
            }
        });
    boundary.confine_with_band(p, band_moves)?;
    Ok(Moved {
        max_shift,
        wall_pushes,
    })
}

/// One row's difference gradients of `u` and `p` and the range of `u` ([`row_pass`]).
type RowSums<const D: usize> = ([[f64; D]; D], [f64; D], [[f64; 2]; D]);

/// Where [`advance_particles`]'s fused pass writes one row's [`RowSums`].
type RowSlots<'a, const D: usize> = (
    &'a mut [[f64; D]; D],
    &'a mut [f64; D],
    &'a mut [[f64; 2]; D],
);

/// Row `i`'s pass over its pairs in [`advance_particles`]: with `REPEL` the pair repulsion
/// `−κ (r_c − r)/r (x_j − x_i)` of each pair closer than `r_c` added to `d`; with `FUSED` the
/// row's difference gradients of `u` and `p` (without their factor `D`) and the range of `u`
/// (ghosts at their wall point), each summed in the order of its own pass
/// ([`crate::operators::grad_vec_into`], [`crate::operators::grad_diff_into`],
/// [`velocity_range`]): the same bits.
#[inline(always)]
fn row_pass<const D: usize, const REPEL: bool, const FUSED: bool>(
    nl: &NeighborList<D>,
    p: &Particles<D>,
    u: &[[f64; D]],
    i: usize,
    rc: f64,
    kappa: f64,
    d: &mut [f64; D],
) -> RowSums<D> {
    let row = nl.row(i);
    let (idx, dxs) = (&nl.indices()[row.clone()], &nl.dx()[row.clone()]);
    let (ws, wr2s) = (&nl.w()[row.clone()], &nl.wr2()[row]);
    let (ui, pi) = (u[i], p.p[i]);
    let mut g = [[0.0; D]; D];
    let mut gp = [0.0; D];
    let mut range: [[f64; 2]; D] = std::array::from_fn(|a| [ui[a], ui[a]]);
    for (((&j, dxk), &w), &wr2) in idx.iter().zip(dxs).zip(ws).zip(wr2s) {
        if REPEL {
            let r2 = norm2(dxk);
            if r2 < rc * rc && r2 > 0.0 {
                let r = r2.sqrt();
                let c = -kappa * (rc - r) / r;
                for a in 0..D {
                    d[a] += c * dxk[a];
                }
            }
        }
        if FUSED {
            let j = j as usize;
            let uj = u[j];
            let c = p.vol[j] * wr2;
            for a in 0..D {
                let du = c * (uj[a] - ui[a]);
                for b in 0..D {
                    g[a][b] += du * dxk[b];
                }
            }
            let cp = p.vol[j] * (p.p[j] - pi) * wr2;
            for a in 0..D {
                gp[a] += cp * dxk[a];
            }
            if w > 0.0 {
                widen_range(&mut range, &p.role, u, j);
            }
        }
    }
    (g, gp, range)
}

/// `range[i][a] = [min, max]` of `u_a` over particle `i` and its neighbours within `h`, a
/// ghost counted at its wall point (the mean of its value and its source's: the wall's
/// velocity under the no-slip rule) — the bounds of a limited (Barth–Jespersen-type) remap.
fn velocity_range<const D: usize>(
    nl: &NeighborList<D>,
    role: &[crate::particles::Role],
    u: &[[f64; D]],
    range: &mut Vec<[[f64; 2]; D]>,
) {
    let rows = nl.len();
    range.resize(rows, [[0.0; 2]; D]);
    range.par_iter_mut().enumerate().for_each(|(i, r)| {
        *r = std::array::from_fn(|a| [u[i][a], u[i][a]]);
        for k in nl.row(i) {
            if nl.w()[k] <= 0.0 {
                continue;
            }
            widen_range(r, role, u, nl.indices()[k] as usize);
        }
    });
}

/// Widens `r` (per component `[min, max]`) by neighbour `j`'s velocity, a ghost's at its wall
/// point (the mean of its value and its source's): one pair of [`velocity_range`].
#[inline(always)]
fn widen_range<const D: usize>(
    r: &mut [[f64; 2]; D],
    role: &[crate::particles::Role],
    u: &[[f64; D]],
    j: usize,
) {
    let v: [f64; D] = match role[j] {
        crate::particles::Role::Ghost { source, .. } => {
            let s = source as usize;
            std::array::from_fn(|a| 0.5 * (u[j][a] + u[s][a]))
        }
        _ => u[j],
    };
    for a in 0..D {
        r[a][0] = r[a][0].min(v[a]);
        r[a][1] = r[a][1].max(v[a]);
    }
}

/// The second derivatives of the velocity and the pressure for the Taylor correction: the
/// least-squares gradients (plain variant `lp`) of the first derivatives in `s.grad` and
/// `s.gp`, in one pass ([`crate::consistent::LsOperators::grad_of_gradients_into`]), and the
/// rows that see a ghost (whose derivatives' ghost values are undefined: they keep the
/// first-order correction).
fn second_derivatives<const D: usize>(
    nl: &NeighborList<D>,
    lp: &crate::consistent::LsOperators<D>,
    p: &Particles<D>,
    s: &mut ShiftScratch<D>,
) {
    let n = p.len();
    s.hess.resize(n, [[[0.0; D]; D]; D]);
    s.hp.resize(n, [[0.0; D]; D]);
    lp.grad_of_gradients_into(nl, &s.grad, &s.gp, &mut s.hess, &mut s.hp);
    (0..n)
        .into_par_iter()
        .with_min_len(1024)
        .map(|i| {
            nl.row(i).any(|k| {
                matches!(
                    p.role[nl.indices()[k] as usize],
                    crate::particles::Role::Ghost { .. }
                )
            })
        })
        .collect_into_vec(&mut s.near_wall);
}
