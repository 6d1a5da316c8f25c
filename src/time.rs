//! Time-step control and stability guards of a flow run.
//!
//! [`time_step`] picks `Δt = min(dt_max, cfl·h/U, visc/(ν λ (1 − 2θ)), force·√(h/|g|))` (or a
//! fixed `Δt`) and names the limit that set it ([`DtLimit`]); [`dt_bound`] is the smallest of the
//! stability limits alone, which [`StabilityGuard::check_dt`] compares a step against before it
//! runs; [`StabilityGuard::check_report`] checks a step's report after it. The functions take the
//! particles and the neighbour list, not a driver, so that a caller's own loop can use them.

use crate::error::{InputError, StabilityError};
use crate::math::norm2;
use crate::neighbors::NeighborList;
use crate::particles::Particles;
use crate::projection::{ProjectionParams, StepReport};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

pub use crate::error::DtLimit;

/// Limits on the time step. `Δt = min(dt_max, cfl·h/U, visc/(ν λ), force·√(h/|g|))` where `U` is
/// the larger of the maximum speed and `u_ref`, and `λ = max_i 2d Σ_j ω_j w_h/r²` is the
/// Gershgorin bound of `−Δh`'s spectrum divided by 2 (forward Euler on `ν Δh u` is stable for
/// `visc ≤ 1`).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TimeStepLimits {
    /// CFL number on `h / U` (default 0.2).
    pub cfl: f64,
    /// Fraction of the explicit viscous stability limit (default 0.5).
    pub visc: f64,
    /// Factor on `√(h/|g|)` (default 0.25).
    pub force: f64,
    /// Reference speed: the CFL limit never assumes a speed below it (default 1).
    pub u_ref: f64,
    /// Upper bound on `Δt` (default none).
    pub dt_max: Option<f64>,
    /// A fixed `Δt`, overriding the limits (it is checked against them, and the exceeded limit
    /// named, when `guard.dt_over_limit` is set).
    pub dt_fixed: Option<f64>,
    /// Checks that stop a run going unstable with a named error (default: all off).
    pub guard: StabilityGuard,
}

impl Default for TimeStepLimits {
    fn default() -> Self {
        TimeStepLimits {
            cfl: 0.2,
            visc: 0.5,
            force: 0.25,
            u_ref: 1.0,
            dt_max: None,
            dt_fixed: None,
            guard: StabilityGuard::blow_up(),
        }
    }
}

impl TimeStepLimits {
    /// Checks the factors (positive and finite), `u_ref` (non-negative, finite), `dt_max` and
    /// `dt_fixed` (positive and finite when set) and the guard, naming the first bad one by its
    /// key under `limits` (`limits.cfl`, `limits.guard.energy_growth`).
    pub fn validate(&self) -> Result<(), InputError> {
        let bad = |name: &'static str, value: f64, reason: &str| {
            Err(InputError::parameter(name, value, reason))
        };
        for (name, v) in [
            ("limits.cfl", self.cfl),
            ("limits.visc", self.visc),
            ("limits.force", self.force),
        ] {
            if !(v > 0.0 && v.is_finite()) {
                return bad(name, v, "time-step factors must be positive and finite");
            }
        }
        if !(self.u_ref >= 0.0 && self.u_ref.is_finite()) {
            return bad(
                "limits.u_ref",
                self.u_ref,
                "the reference speed must be non-negative and finite",
            );
        }
        for (name, v) in [
            ("limits.dt_max", self.dt_max),
            ("limits.dt_fixed", self.dt_fixed),
        ] {
            if let Some(v) = v {
                if !(v > 0.0 && v.is_finite()) {
                    return bad(name, v, "a time step must be positive and finite");
                }
            }
        }
        self.guard.validate().map_err(|e| e.under("limits"))
    }
}

/// Checks that turn a run going unstable into a [`StabilityError`] naming the step, the
/// quantity and the fastest particle, instead of a blow-up (non-finite values, particles
/// flung through walls, a failed solve). Every check is off by default (`None`).
///
/// The time-step check runs before a step and names the exceeded limit (the guard of a fixed
/// `Δt`); the others run after it, on the step's report. The stress example
/// (`examples/stress.rs`) measures what each catches.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct StabilityGuard {
    /// Fail before a step whose `Δt` exceeds this multiple of the smallest of the CFL, explicit
    /// viscous and body-force limits ([`dt_bound`], [`crate::flow::Simulation::dt_bound`]); 1 enforces the limits.
    pub dt_over_limit: Option<f64>,
    /// Fail when the kinetic energy grows by more than this factor in one step, checked when
    /// the previous step's energy exceeds `energy_floor`.
    pub energy_growth: Option<f64>,
    /// Energy below which `energy_growth` is not checked (default 0). A flow started from rest
    /// (the cavity) multiplies its energy by about 4 from the first step to the second: a floor
    /// of 10⁻³ of `½ρU²|Ω|` lets the spin-up pass.
    pub energy_floor: f64,
    /// Fail when the largest fluid speed exceeds this multiple of `limits.u_ref`.
    pub speed_over_ref: Option<f64>,
    /// Fail when the Theorem 4.5 ratio of a step exceeds this (the theory bounds it by 1 with
    /// the mirror source continuation).
    pub stability_ratio: Option<f64>,
    /// Fail when the correction removes more than this share of the predicted velocity,
    /// `‖uⁿ⁺¹ − u*‖/‖u*‖` ([`StepReport::correction_ratio`]), checked when the previous step's
    /// energy exceeds `energy_floor` (a flow started from rest is all correction at first).
    pub correction_ratio: Option<f64>,
}

impl StabilityGuard {
    /// The guard of [`TimeStepLimits::default`] (so every scene and flow runs with it unless
    /// told otherwise): fail when the largest speed exceeds 3 `u_ref`
    /// or the kinetic energy grows tenfold in one step (neither happens in a healthy run of
    /// any scene: the lid, the body force and the initial vortex set the speed scale), so that
    /// a blow-up is named within a few steps of its onset instead of running on to overflow.
    /// [`StabilityGuard::default`] has every check off.
    pub fn blow_up() -> Self {
        StabilityGuard {
            speed_over_ref: Some(3.0),
            energy_growth: Some(10.0),
            ..Default::default()
        }
    }

    /// Checks `energy_floor` (non-negative, finite) and the bounds (positive when set), naming
    /// the first bad one by its key under `guard` (`guard.energy_growth`).
    pub fn validate(&self) -> Result<(), InputError> {
        if !(self.energy_floor >= 0.0 && self.energy_floor.is_finite()) {
            return Err(InputError::parameter(
                "guard.energy_floor",
                self.energy_floor,
                "the energy floor must be non-negative and finite",
            ));
        }
        for (name, v) in [
            ("guard.dt_over_limit", self.dt_over_limit),
            ("guard.energy_growth", self.energy_growth),
            ("guard.speed_over_ref", self.speed_over_ref),
            ("guard.stability_ratio", self.stability_ratio),
            ("guard.correction_ratio", self.correction_ratio),
        ] {
            if let Some(v) = v {
                if v.is_nan() || v <= 0.0 {
                    return Err(InputError::parameter(
                        name,
                        v,
                        "a guard bound must be positive",
                    ));
                }
            }
        }
        Ok(())
    }

    /// The before-step check: fails when `dt` exceeds `dt_over_limit` times `bound`, the
    /// smallest stability limit (`limit` names it; see [`dt_bound`]). `step` is the step about
    /// to be taken.
    pub fn check_dt(
        &self,
        step: u64,
        dt: f64,
        limit: DtLimit,
        bound: f64,
    ) -> Result<(), StabilityError> {
        if let Some(factor) = self.dt_over_limit {
            if dt > factor * bound {
                return Err(StabilityError::TimeStepTooLarge {
                    step,
                    dt,
                    limit,
                    bound,
                    factor,
                });
            }
        }
        Ok(())
    }

    /// The after-step checks on the step's report: kinetic-energy growth against
    /// `*prev_energy` (which is replaced by this step's energy), the largest speed against
    /// `u_ref`, the Theorem 4.5 ratio. The error names `step` and `time` (after the step) and
    /// the fastest fluid particle of `p`.
    pub fn check_report<const D: usize>(
        &self,
        report: &StepReport,
        u_ref: f64,
        prev_energy: &mut Option<f64>,
        p: &Particles<D>,
        step: u64,
        time: f64,
    ) -> Result<(), StabilityError> {
        let g = self;
        let ke = report.kinetic_energy;
        let prev = prev_energy.replace(ke);
        let above_floor = prev.is_some_and(|e0| e0 > 0.0 && e0 >= g.energy_floor);
        let failed = match prev {
            Some(e0) if above_floor && g.energy_growth.is_some_and(|f| ke > f * e0) => {
                Some(("kinetic energy growth", ke / e0, g.energy_growth))
            }
            _ => None,
        }
        .or_else(|| {
            g.speed_over_ref
                .filter(|&f| report.max_speed > f * u_ref)
                .map(|f| ("max speed / u_ref", report.max_speed / u_ref, Some(f)))
        })
        .or_else(|| {
            g.stability_ratio
                .filter(|&f| report.stability_ratio > f)
                .map(|f| ("Theorem 4.5 ratio", report.stability_ratio, Some(f)))
        })
        .or_else(|| {
            g.correction_ratio
                .filter(|&f| above_floor && report.correction_ratio > f)
                .map(|f| {
                    (
                        "correction / predicted velocity",
                        report.correction_ratio,
                        Some(f),
                    )
                })
        });
        let Some((quantity, value, Some(bound))) = failed else {
            return Ok(());
        };
        let (particle, speed2) = (0..p.len())
            .filter(|&i| p.role[i].is_fluid())
            .map(|i| (i, norm2(&p.u[i])))
            .fold((0, -1.0), |a, b| if b.1 > a.1 { b } else { a });
        Err(StabilityError::BlowUp {
            step,
            time,
            quantity,
            value,
            bound,
            particle,
            position: p.x.get(particle).map(|x| x.to_vec()).unwrap_or_default(),
            speed: speed2.max(0.0).sqrt(),
        })
    }
}

/// The time step for particles `p` with neighbour list `nl` under the limits `l`, and the limit
/// that set it. `U` is the largest fluid speed (at least `l.u_ref`); the viscous limit applies
/// to an explicit or partly explicit viscous term (`θ < ½`): the θ-scheme on `ν Δh` is stable
/// for `Δt ν λ_max (1 − 2θ) ≤ 2` with `λ_max ≤ 2λ`, `λ` = [`viscous_eigen_bound`]. A fixed step
/// (`l.dt_fixed`) overrides the limits and is reported as [`DtLimit::Fixed`].
pub fn time_step<const D: usize>(
    p: &Particles<D>,
    nl: &NeighborList<D>,
    projection: &ProjectionParams<D>,
    l: &TimeStepLimits,
) -> (f64, DtLimit) {
    let h = nl.h();
    // fluid and band: a free surface's particles are often the fastest
    let umax = p.max_speed();
    let mut dt = l.dt_max.unwrap_or(f64::INFINITY);
    let mut which = DtLimit::Max;
    let cfl = l.cfl * h / umax.max(l.u_ref);
    if cfl < dt {
        dt = cfl;
        which = DtLimit::Cfl;
    }
    let nu = projection.nu;
    let theta = projection.viscous_theta;
    if nu > 0.0 && theta < 0.5 {
        // θ-scheme on ν Δh: stable for Δt ν λ_max (1 − 2θ) ≤ 2, λ_max ≤ 2λ (Gershgorin)
        let lam = viscous_eigen_bound(p, nl);
        let v = l.visc / (nu * lam * (1.0 - 2.0 * theta));
        if v < dt {
            dt = v;
            which = DtLimit::Viscous;
        }
    }
    let g = norm2(&projection.gravity).sqrt();
    if g > 0.0 {
        let f = l.force * (h / g).sqrt();
        if f < dt {
            dt = f;
            which = DtLimit::Force;
        }
    }
    if let Some(fixed) = l.dt_fixed {
        return (fixed, DtLimit::Fixed);
    }
    (dt, which)
}

/// The smallest of the stability limits on `Δt` (CFL, explicit viscous, body force, as in
/// [`time_step`] but without `dt_max` and a fixed step) and which one it is; `∞` (with
/// [`DtLimit::Max`]) when none applies.
pub fn dt_bound<const D: usize>(
    p: &Particles<D>,
    nl: &NeighborList<D>,
    projection: &ProjectionParams<D>,
    l: &TimeStepLimits,
) -> (DtLimit, f64) {
    let mut limits = *l;
    limits.dt_max = None;
    limits.dt_fixed = None;
    let (dt, which) = time_step(p, nl, projection, &limits);
    (which, dt)
}

/// `λ = max_i 2d Σ_j ω_j w_h/r²` over fluid rows: half the Gershgorin bound on the spectrum of
/// `−Δh` (so forward Euler on `ν Δh u` is stable for `ν Δt λ ≤ 1`).
pub fn viscous_eigen_bound<const D: usize>(p: &Particles<D>, nl: &NeighborList<D>) -> f64 {
    let c = 2.0 * D as f64;
    (0..nl.len())
        .into_par_iter()
        .filter(|&i| p.role[i].is_fluid())
        .map(|i| {
            c * nl
                .row(i)
                .map(|k| p.vol[nl.indices()[k] as usize] * nl.wr2()[k])
                .sum::<f64>()
        })
        .reduce(|| 0.0, f64::max)
}
