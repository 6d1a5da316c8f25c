//! The convective term `−(u·∇h)u` of the Eulerian frame, integrated explicitly.
//!
//! `N = (u·∇h)u` with the difference gradient ([`grad_vec_into`]) or, with the consistent
//! operators, the least-squares gradient of the wall variant of
//! [`crate::consistent::LsOperators`] (exact on quadratic velocities that take the wall value;
//! the difference gradient is off by `O(1)` on disordered particles); forward Euler adds `−Nⁿ` to
//! the predictor, second-order Adams–Bashforth with variable steps adds
//! `−((1 + r/2) Nⁿ − (r/2) Nⁿ⁻¹)`, `r = Δtⁿ/Δtⁿ⁻¹` (forward Euler on the first step).
//!
//! **Forms** ([`ConvectionForm`], config key `convection`). With the difference gradient the
//! central form `N_i = G_i u_i` is the pair sum `N_i = d Σ_j ω_j w_h(r_ij)/r_ij² (u_i·x_ij)
//! (u_j − u_i)`, `x_ij = x_j − x_i`. Its advecting velocity `u_i` makes the pair coefficient
//! non-antisymmetric, so the pairs exchange kinetic energy unevenly: at cell Reynolds numbers
//! `U Δx/ν ≫ 2` the Re 1000 cavity at n = 48 settles on a spurious, over-energetic state (10 %
//! RMS off the reference at any `Δt`) or blows up at the top-right lid corner at the CFL limit.
//!
//! The **skew-symmetric** form ([`ConvectionForm::SkewSymmetric`], the default) advects with
//! the pair mean `ū_ij = ½(u_i + u_j)`:
//!
//! `N_i = Σ_j c_ij (u_j − u_i)`,  `c_ij = d ω_j w_h(r_ij)/r_ij² (ū_ij·x_ij)`.
//!
//! It is `½[(u·∇h)u + ∇̂h·(u⊗u) − u ∇̂h·u]` with the adjoint pair `∇h` / `∇̂h·` of Lemma 4.3:
//! `ω_i c_ij = −ω_j c_ji`, so (summing over all particles, e.g. a periodic box; wall ghosts
//! add boundary terms) `Σ_i ω_i u_i·N_i = −½ Σ_i ω_i |u_i|² (∇̂h·u)_i`: the convective term
//! makes or destroys kinetic energy only through the discrete divergence `∇̂h·u` that the
//! projection removes (the central form also through `(u_i − u_j)·x_ij` of every pair). It is
//! exact on linear fields wherever the difference gradient is (a symmetric neighbourhood).
//!
//! The **upwind** forms add to it the dissipation of transporting the *upwind* state of a
//! reconstruction at the pair midpoint (MUSCL-type, as in Riemann-solver SPH):
//!
//! `N_i = Σ_j c_ij (u_j − u_i) − Σ_j a_ij (u_ij^R − u_ij^L)`,  `a_ij = d ω_j w_h/r² |u_i·x_ij|`,
//!
//! `u_ij^L = u_i + ½ L(G_i x_ij, u_j − u_i)`, `u_ij^R = u_j − ½ L(G_j x_ij, u_j − u_i)`
//! (per component). With `L(s, Δ) = s` ([`ConvectionForm::Muscl`]) the added term vanishes on
//! quadratic fields wherever `G` is exact on them (on a lattice it acts on fourth
//! derivatives, `∝ |u| r⁴`, but over pairs as long as `h`); the van Leer limiter
//! `L(s, Δ) = 2sΔ/(s + Δ)` for `sΔ > 0`, else `0` ([`ConvectionForm::MusclVanLeer`]) falls back
//! to first order where the particle's slope and the pair's jump disagree; `L = 0`
//! ([`ConvectionForm::Upwind`]) is first-order upwind (numerical viscosity `∝ |u| h`). Every
//! form is exact on linear fields where `G` is. Ghost gradients are those of the no-slip images
//! ([`crate::boundary::Boundary::fill_velocity_gradient`]).
//!
//! With the consistent operators (`least_squares` given: disordered or moving particles) the
//! base term is the central `G_i u_i` with the least-squares `G` for every form, exact on
//! quadratic fields on any distribution (the GPM pair sum of the skew-symmetric form is exact
//! on linear fields only on symmetric neighbourhoods); the upwind forms add their term with
//! the GPM pair weights.
//!
//! Measured (Re 1000 cavity, n = 48, Δt at the CFL limit 0.2 h/U, RMS against the extrapolated
//! reference u / v): central blows up (at 0.15 h/U: 10.3 % / 13.4 %), skew-symmetric 2.8 % /
//! 3.0 %, MUSCL 5.5 % / 4.3 %, MUSCL–van Leer 4.7 % / 4.5 %, first-order upwind 15 % / 17 %:
//! the upwind dissipation over pairs as long as `h` is larger than the physical viscosity in
//! the boundary layers (README, issue 15).

use crate::boundary::Boundary;
use crate::consistent::LsOperators;
use crate::neighbors::NeighborList;
use crate::operators::grad_vec_into;
use crate::particles::Role;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Time integration of the explicit terms of the predictor (convection in the Eulerian frame).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Integrator {
    /// Forward Euler (first order).
    Euler,
    /// Second-order Adams–Bashforth with variable-step coefficients (forward Euler on the first
    /// step). With Crank–Nicolson viscosity (`viscous_theta = ½`) and an incremental pressure
    /// scheme the step is second order in time.
    #[default]
    Ab2,
}

impl std::str::FromStr for Integrator {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s.trim().to_ascii_lowercase().as_str() {
            "euler" => Ok(Integrator::Euler),
            "ab2" => Ok(Integrator::Ab2),
            _ => Err(format!("unknown integrator '{s}': expected euler or ab2")),
        }
    }
}

/// How the convective term is discretised (config key `convection`; formulas in the
/// [module documentation](self)).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ConvectionForm {
    /// `N_i = G_i u_i` (no dissipation; the default before issue 15).
    Central,
    /// `N_i = Σ_j c_ij (u_j − u_i)` with the pair-mean advecting velocity (energy-conserving up
    /// to the discrete divergence; the default).
    #[default]
    SkewSymmetric,
    /// First-order upwind: `N_i = Σ_j (c_ij − a_ij) (u_j − u_i)`.
    Upwind,
    /// Upwind state of the unlimited MUSCL reconstruction at the pair midpoint.
    Muscl,
    /// Upwind state of the van Leer-limited MUSCL reconstruction.
    MusclVanLeer,
}

impl std::str::FromStr for ConvectionForm {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s.trim().to_ascii_lowercase().replace('-', "_").as_str() {
            "central" => Ok(ConvectionForm::Central),
            "skew" | "skew_symmetric" => Ok(ConvectionForm::SkewSymmetric),
            "upwind" => Ok(ConvectionForm::Upwind),
            "muscl" => Ok(ConvectionForm::Muscl),
            "muscl_van_leer" | "muscl_vanleer" => Ok(ConvectionForm::MusclVanLeer),
            _ => Err(format!(
                "unknown convection form '{s}': expected central, upwind, muscl or muscl-van-leer"
            )),
        }
    }
}

/// The van Leer limiter of a slope `s` against the pair's jump `d`: `2sd/(s + d)` when they
/// agree in sign, else 0.
#[inline]
fn van_leer(s: f64, d: f64) -> f64 {
    if s * d > 0.0 {
        2.0 * s * d / (s + d)
    } else {
        0.0
    }
}

/// `N_i` of the pair forms (every form but [`ConvectionForm::Central`], module docs) at a fluid
/// row `i`: the
/// skew-symmetric pair sum `Σ_j c_ij (u_j − u_i)` with `c_ij = d ω_j w_h/r² (ū_ij·x_ij)`,
/// `ū_ij = ½(u_i + u_j)`, minus the upwind term `Σ_j a_ij (u_ij^R − u_ij^L)`,
/// `a_ij = d ω_j w_h/r² |u_i·x_ij|`. Without `skew` only the upwind term (its negative).
#[inline]
fn pair_row<const D: usize>(
    nl: &NeighborList<D>,
    vol: &[f64],
    u: &[[f64; D]],
    grad: &[[[f64; D]; D]],
    form: ConvectionForm,
    skew: bool,
    i: usize,
) -> [f64; D] {
    let ui = u[i];
    let gi = &grad[i];
    let d = D as f64;
    let mut acc = [0.0; D];
    let skew = if skew { 1.0 } else { 0.0 };
    for k in nl.row(i) {
        let j = nl.indices()[k] as usize;
        let x = &nl.dx()[k];
        let uj = &u[j];
        let pair = d * vol[j] * nl.wr2()[k];
        let c = pair * (0..D).map(|b| 0.5 * (ui[b] + uj[b]) * x[b]).sum::<f64>();
        // the upwind side is judged by the row's own velocity: |c_i·| is then even in x_ij
        // and the first-order term cancels on linear fields over a symmetric neighbourhood
        let c_up = pair * (0..D).map(|b| ui[b] * x[b]).sum::<f64>().abs();
        let gj = &grad[j];
        for a in 0..D {
            let jump = uj[a] - ui[a];
            let (si, sj) = match form {
                ConvectionForm::Central | ConvectionForm::SkewSymmetric => {
                    acc[a] += skew * c * jump;
                    continue;
                }
                ConvectionForm::Upwind => (0.0, 0.0),
                ConvectionForm::Muscl | ConvectionForm::MusclVanLeer => {
                    let si: f64 = (0..D).map(|b| gi[a][b] * x[b]).sum();
                    let sj: f64 = (0..D).map(|b| gj[a][b] * x[b]).sum();
                    if form == ConvectionForm::MusclVanLeer {
                        (van_leer(si, jump), van_leer(sj, jump))
                    } else {
                        (si, sj)
                    }
                }
            };
            // u^R − u^L = (u_j − ½ s_j) − (u_i + ½ s_i)
            acc[a] += skew * c * jump - c_up * (jump - 0.5 * (si + sj));
        }
    }
    acc
}

/// The convective term's state between steps: the previous `N` and its `Δt` (for AB2), and the
/// velocity-gradient scratch.
#[derive(Clone, Debug, Default)]
pub struct Convection<const D: usize> {
    prev: Option<(Vec<[f64; D]>, f64)>,
    grad: Vec<[[f64; D]; D]>,
    /// The buffer the next `Nⁿ` is written into (the one before last, recycled).
    spare: Vec<[f64; D]>,
}

impl<const D: usize> Convection<D> {
    /// No previous step (the first step is forward Euler).
    pub fn new() -> Self {
        Convection {
            prev: None,
            grad: Vec::new(),
            spare: Vec::new(),
        }
    }

    /// Writes the convective acceleration `−N` (Euler) or `−((1 + r/2) Nⁿ − (r/2) Nⁿ⁻¹)` (AB2)
    /// of velocities `u` (ghosts already filled) of the particles at `x` into `out`, and keeps `Nⁿ` and `dt` for the
    /// next step. AB2 falls back to Euler when there is no previous step or the particle count
    /// changed. With `least_squares` (coefficients for the configuration of `nl`, e.g.
    /// [`crate::projection::ProjectionStep::velocity_least_squares`]) the gradient is the
    /// least-squares one, otherwise the difference gradient. `form` chooses the discretisation
    /// ([`ConvectionForm`]; with `least_squares` the base term is `G u` for every form, module
    /// docs); the MUSCL forms continue the gradient into the ghosts of `boundary` before the
    /// pair sums, which fill only the rows whose `role` is fluid.
    #[allow(clippy::too_many_arguments)]
    pub fn accel_into<B: Boundary<D> + ?Sized>(
        &mut self,
        nl: &NeighborList<D>,
        vol: &[f64],
        x: &[[f64; D]],
        role: &[Role],
        boundary: &B,
        least_squares: Option<&LsOperators<D>>,
        u: &[[f64; D]],
        form: ConvectionForm,
        integrator: Integrator,
        dt: f64,
        out: &mut Vec<[f64; D]>,
    ) {
        let n = u.len();
        self.grad.resize(n, [[0.0; D]; D]);
        // with the least-squares gradient the base term is G u whatever the form; the
        // skew-symmetric and first-order forms need no gradient otherwise
        let skew = least_squares.is_none();
        if !skew
            || matches!(
                form,
                ConvectionForm::Central | ConvectionForm::Muscl | ConvectionForm::MusclVanLeer
            )
        {
            if let Some(ls) = least_squares {
                ls.grad_vec_into(nl, u, &mut self.grad);
            } else {
                grad_vec_into(nl, vol, u, &mut self.grad);
            }
            if form != ConvectionForm::Central && boundary.has_ghosts() {
                boundary.fill_velocity_gradient(x, role, &mut self.grad);
            }
        }
        let grad = &self.grad;
        // `Nⁿ` goes into the buffer of `Nⁿ⁻²`: no allocation once both have grown
        let mut conv = std::mem::take(&mut self.spare);
        conv.clear();
        conv.resize(n, [0.0; D]);
        conv.par_iter_mut()
            .with_min_len(256)
            .enumerate()
            .for_each(|(i, a)| {
                if form == ConvectionForm::Central || !skew {
                    let (g, ui) = (&grad[i], &u[i]);
                    *a = std::array::from_fn(|k| (0..D).map(|b| g[k][b] * ui[b]).sum::<f64>());
                }
                let pairs = form != ConvectionForm::Central
                    && (skew || form != ConvectionForm::SkewSymmetric);
                if pairs && i < nl.len() && role[i].is_fluid() {
                    let p = pair_row(nl, vol, u, grad, form, skew, i);
                    for k in 0..D {
                        a[k] += p[k];
                    }
                }
            });
        out.resize(n, [0.0; D]);
        match (&self.prev, integrator) {
            (Some((prev, dt_prev)), Integrator::Ab2) if prev.len() == n => {
                let r = dt / dt_prev;
                let (c1, c0) = (1.0 + 0.5 * r, 0.5 * r);
                for i in 0..n {
                    out[i] = std::array::from_fn(|k| -(c1 * conv[i][k] - c0 * prev[i][k]));
                }
            }
            _ => {
                for i in 0..n {
                    out[i] = conv[i].map(|v| -v);
                }
            }
        }
        if let Some((old, _)) = self.prev.replace((conv, dt)) {
            self.spare = old;
        }
    }
}
