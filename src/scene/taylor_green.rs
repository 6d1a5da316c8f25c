//! The Taylor–Green vortex on the periodic unit square (MISSION §5), an exact Navier–Stokes
//! solution:
//!
//! `u = −U e^{−8π²t/Re} cos 2πx sin 2πy`, `v = U e^{−8π²t/Re} sin 2πx cos 2πy`,
//! `p = −ρU² e^{−16π²t/Re} (cos 4πx + cos 4πy)/4`.

use crate::boundary::PeriodicBox;
use crate::consistent::GradientKind;
use crate::error::{Error, InputError};
use crate::flow::{
    FlowParams, FlowReport, Integrator, Motion, Shifting, Simulation, TimeStepLimits, VolumeRule,
};
use crate::geometry::lattice;
use crate::kernel::Weight;
use crate::neighbors::{NeighborConfig, Periodicity};
use crate::particles::{Particles, Role};
use crate::poisson::SolveParams;
use crate::projection::{ProjectionParams, Scheme};
use serde::{Deserialize, Serialize};
use std::f64::consts::PI;
use std::time::Instant;

/// Configuration of a Taylor–Green run.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TaylorGreenConfig {
    /// Reynolds number `U L / ν` (L = 1).
    pub re: f64,
    /// Particles per side.
    pub n: usize,
    /// End time.
    pub t_end: f64,
    /// Influence radius over spacing.
    pub h_over_dx: f64,
    /// Neighbour skin over `h`.
    pub skin_over_h: f64,
    /// Reference weight.
    pub weight: Weight,
    /// Pressure scheme.
    pub scheme: Scheme,
    /// Gradient of the predictor and the correction (difference `∇h` or renormalised `B∇h`).
    pub gradient: GradientKind,
    /// Frame.
    pub motion: Motion,
    /// Integrator of the explicit terms.
    pub integrator: Integrator,
    /// Implicit weight of the viscous term (½ = Crank–Nicolson, 0 = explicit).
    pub viscous_theta: f64,
    /// Shifting (Lagrangian).
    pub shifting: Option<Shifting>,
    /// Volumes.
    pub volumes: VolumeRule,
    /// Time-step limits.
    pub limits: TimeStepLimits,
    /// Linear solver.
    pub solve: SolveParams,
    /// Velocity amplitude `U`.
    pub amplitude: f64,
}

impl Default for TaylorGreenConfig {
    fn default() -> Self {
        TaylorGreenConfig {
            re: 100.0,
            n: 50,
            t_end: 2.0,
            h_over_dx: 3.0,
            skin_over_h: 0.3,
            weight: Weight::WendlandC2,
            scheme: Scheme::Rotational,
            gradient: GradientKind::Difference,
            motion: Motion::Eulerian,
            integrator: Integrator::Ab2,
            viscous_theta: 0.5,
            shifting: Some(Shifting::default()),
            volumes: VolumeRule::NumberDensity,
            limits: TimeStepLimits::default(),
            solve: SolveParams::default(),
            amplitude: 1.0,
        }
    }
}

/// The exact velocity and pressure at `(x, t)`.
pub fn exact(re: f64, amp: f64, x: &[f64; 2], t: f64) -> ([f64; 2], f64) {
    let e = (-8.0 * PI * PI * t / re).exp();
    let (s2x, c2x) = (2.0 * PI * x[0]).sin_cos();
    let (s2y, c2y) = (2.0 * PI * x[1]).sin_cos();
    let u = [-amp * e * c2x * s2y, amp * e * s2x * c2y];
    let p = -amp * amp * e * e * ((4.0 * PI * x[0]).cos() + (4.0 * PI * x[1]).cos()) / 4.0;
    (u, p)
}

impl TaylorGreenConfig {
    /// Checks the parameters, naming the first bad one.
    pub fn validate(&self) -> Result<(), InputError> {
        let bad = |name: &'static str, value: f64, reason: &str| {
            Err(InputError::Parameter {
                name: name.into(),
                value,
                reason: reason.into(),
            })
        };
        if !(self.re > 0.0 && self.re.is_finite()) {
            return bad(
                "re",
                self.re,
                "the Reynolds number must be positive and finite",
            );
        }
        if self.n < 8 || self.n > 20_000 {
            return bad(
                "n",
                self.n as f64,
                "particles per side must be in 8..=20000",
            );
        }
        if !(self.t_end > 0.0 && self.t_end.is_finite()) {
            return bad(
                "t_end",
                self.t_end,
                "the end time must be positive and finite",
            );
        }
        if !(self.h_over_dx > 1.0 && self.h_over_dx <= 8.0) {
            return bad("h_over_dx", self.h_over_dx, "need 1 < h/dx ≤ 8");
        }
        if !(self.amplitude.is_finite() && self.amplitude != 0.0) {
            return bad("amplitude", self.amplitude, "must be finite and non-zero");
        }
        if !(self.skin_over_h >= 0.0 && self.skin_over_h <= 2.0) {
            return bad(
                "skin_over_h",
                self.skin_over_h,
                "the skin must be in [0, 2] h",
            );
        }
        if let Err(reason) = self.weight.validate() {
            return bad("weight", f64::NAN, &reason);
        }
        if !(0.0..=1.0).contains(&self.viscous_theta) {
            return bad("viscous_theta", self.viscous_theta, "must be in [0, 1]");
        }
        self.limits.validate()?;
        super::validate_common(&self.solve, self.shifting.as_ref())
    }
}

/// Builds the simulation at `t = 0` with the exact fields.
pub fn build(cfg: &TaylorGreenConfig) -> Result<Simulation<2, PeriodicBox<2>>, Error> {
    cfg.validate()?;
    let dx = 1.0 / cfg.n as f64;
    let mut p = Particles::<2>::new();
    for x in lattice([0.0, 0.0], [1.0, 1.0], dx) {
        let (u, pr) = exact(cfg.re, cfg.amplitude, &x, 0.0);
        p.push(x, u, pr, dx * dx, Role::Fluid);
    }
    let bc = PeriodicBox {
        periodic: Periodicity::all([0.0, 0.0], [1.0, 1.0]),
    };
    let nc = NeighborConfig::new_relative(cfg.weight, dx, cfg.h_over_dx, cfg.skin_over_h);
    let mut projection = ProjectionParams::new(cfg.amplitude.abs() / cfg.re);
    projection.scheme = cfg.scheme;
    projection.gradient = cfg.gradient;
    projection.viscous_theta = cfg.viscous_theta;
    projection.solve = cfg.solve;
    projection.allowed_floating = 1;
    let mut limits = cfg.limits;
    limits.u_ref = limits.u_ref.max(cfg.amplitude.abs());
    let params = FlowParams {
        projection,
        limits,
        motion: cfg.motion,
        integrator: cfg.integrator,
        shifting: if cfg.motion == Motion::Lagrangian {
            cfg.shifting
        } else {
            None
        },
        volumes: cfg.volumes,
        dx,
    };
    Simulation::new(p, bc, nc, params)
}

/// Errors against the exact solution.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct TaylorGreenErrors {
    /// `Σ|u − u_ex| / Σ|u_ex|` over the particles (L1 of the velocity error, normalised by the
    /// exact mean speed).
    pub l1_velocity_error: f64,
    /// `|max|u| − max|u_ex|| / max|u_ex|`: error of the decay of the maximum speed.
    pub linf_decay_error: f64,
    /// `Σ|p − p_ex| / Σ|p_ex|` after removing the mean of `p − p_ex`.
    pub l1_pressure_error: f64,
}

/// Errors of the current state against the exact solution at the current time.
pub fn errors(sim: &Simulation<2, PeriodicBox<2>>, re: f64, amp: f64) -> TaylorGreenErrors {
    let p = &sim.particles;
    let t = sim.time;
    let (mut eu, mut nu, mut vmax, mut vmax_ex) = (0.0, 0.0, 0.0f64, 0.0f64);
    let mut dp = Vec::new();
    let mut pex = Vec::new();
    for i in 0..p.len() {
        if !p.role[i].is_fluid() {
            continue;
        }
        let (ue, pe) = exact(re, amp, &p.x[i], t);
        let d = [p.u[i][0] - ue[0], p.u[i][1] - ue[1]];
        eu += (d[0] * d[0] + d[1] * d[1]).sqrt();
        let se = (ue[0] * ue[0] + ue[1] * ue[1]).sqrt();
        nu += se;
        vmax = vmax.max((p.u[i][0].powi(2) + p.u[i][1].powi(2)).sqrt());
        vmax_ex = vmax_ex.max(se);
        dp.push(p.p[i] - pe);
        pex.push(pe);
    }
    let mean = dp.iter().sum::<f64>() / dp.len() as f64;
    let ep: f64 = dp.iter().map(|v| (v - mean).abs()).sum();
    let np: f64 = pex.iter().map(|v| v.abs()).sum();
    // the exact maximum speed decays as U e^{−8π²t/Re}
    let vmax_exact = amp.abs() * (-8.0 * PI * PI * t / re).exp();
    let _ = vmax_ex;
    TaylorGreenErrors {
        l1_velocity_error: eu / nu,
        linf_decay_error: (vmax - vmax_exact).abs() / vmax_exact,
        l1_pressure_error: ep / np,
    }
}

/// The outcome of [`run`].
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct TaylorGreenResult {
    /// Reynolds number.
    pub re: f64,
    /// Particles per side.
    pub n: usize,
    /// Steps.
    pub steps: u64,
    /// Final time.
    pub t_end: f64,
    /// Wall seconds.
    pub wall_seconds: f64,
    /// Errors at the final time.
    pub errors: TaylorGreenErrors,
    /// Largest Theorem 4.5 ratio.
    pub max_stability_ratio: f64,
}

/// Runs to `t_end` (the last step is shortened to land on it).
pub fn run(
    cfg: &TaylorGreenConfig,
    observer: impl FnMut(&FlowReport, &Simulation<2, PeriodicBox<2>>) -> Result<(), Error>,
) -> Result<TaylorGreenResult, Error> {
    run_with(cfg, |_| {}, observer)
}

/// [`run`] with a `setup` hook that may adjust the simulation after it is built and before the
/// first step (e.g. `sim.projection.capture = true` to record projection inputs).
pub fn run_with(
    cfg: &TaylorGreenConfig,
    setup: impl FnOnce(&mut Simulation<2, PeriodicBox<2>>),
    mut observer: impl FnMut(&FlowReport, &Simulation<2, PeriodicBox<2>>) -> Result<(), Error>,
) -> Result<TaylorGreenResult, Error> {
    let start = Instant::now();
    let mut sim = build(cfg)?;
    setup(&mut sim);
    let mut res = TaylorGreenResult {
        re: cfg.re,
        n: cfg.n,
        ..Default::default()
    };
    while sim.time < cfg.t_end - 1e-12 {
        let (dt, _) = sim.time_step();
        let remaining = cfg.t_end - sim.time;
        if dt > remaining {
            sim.params.limits.dt_fixed = Some(remaining);
        }
        let rep = sim.advance()?;
        sim.params.limits.dt_fixed = cfg.limits.dt_fixed;
        res.max_stability_ratio = res.max_stability_ratio.max(rep.projection.stability_ratio);
        observer(&rep, &sim)?;
    }
    res.steps = sim.steps;
    res.t_end = sim.time;
    res.errors = errors(&sim, cfg.re, cfg.amplitude);
    res.wall_seconds = start.elapsed().as_secs_f64();
    Ok(res)
}
