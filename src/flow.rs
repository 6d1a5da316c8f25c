//! A complete incompressible particle-flow solver around [`ProjectionStep`]: time-step control,
//! neighbour maintenance, ghosts, volumes, advection and particle shifting.
//!
//! One [`Simulation::advance`]:
//! 1. moves ghosts with their sources; when the neighbour candidates have expired, regenerates
//!    the ghosts and searches again (otherwise only re-measures pairs);
//! 2. recomputes volumes (`ω_i = 1/Σ_{j≠i} w_h(r_ij)`) if asked;
//! 3. picks `Δt` from the CFL, viscous and body-force limits;
//! 4. Eulerian frame: predictor with `−(u·∇h)u` and projection on the fixed particles;
//!    Lagrangian frame: predictor at `xⁿ`, particles moved with `u*`, neighbours refreshed, and the
//!    projection at the new positions;
//! 5. Lagrangian frame: shifts particles by Fickian diffusion
//!    (`δx_i = −A h |u_i| Δt ∇C_i`, Skillen et al. 2013's scaling of Lind et al. 2012's law) and
//!    corrects their velocity and pressure to the new position by a first-order Taylor
//!    expansion (Xu et al. 2009), `u_i += (δx_i·∇h) u_i`.

use crate::boundary::{Boundary, VectorKind};
use crate::error::{Error, InputError, StabilityError};
use crate::geometry::number_density_volumes;
use crate::math::norm2;
use crate::neighbors::{closest_pair, NeighborConfig, NeighborList};
use crate::operators::{grad_diff_into, grad_vec_into};
use crate::particles::Particles;
use crate::projection::{ProjectionParams, ProjectionStep, StepReport};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::time::Instant;

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
            guard: StabilityGuard::default(),
        }
    }
}

impl TimeStepLimits {
    /// Checks the factors (positive and finite), `u_ref` (non-negative, finite), `dt_max` and
    /// `dt_fixed` (positive and finite when set) and the guard, naming the first bad one.
    pub fn validate(&self) -> Result<(), InputError> {
        let bad = |name: &'static str, value: f64, reason: &str| {
            Err(InputError::Parameter {
                name,
                value,
                reason: reason.into(),
            })
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
        let g = &self.guard;
        if !(g.energy_floor >= 0.0 && g.energy_floor.is_finite()) {
            return bad(
                "limits.guard.energy_floor",
                g.energy_floor,
                "the energy floor must be non-negative and finite",
            );
        }
        for (name, v) in [
            ("limits.guard.dt_over_limit", g.dt_over_limit),
            ("limits.guard.energy_growth", g.energy_growth),
            ("limits.guard.speed_over_ref", g.speed_over_ref),
            ("limits.guard.stability_ratio", g.stability_ratio),
        ] {
            if let Some(v) = v {
                if v.is_nan() || v <= 0.0 {
                    return bad(name, v, "a guard bound must be positive");
                }
            }
        }
        Ok(())
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
    /// viscous and body-force limits ([`Simulation::dt_bound`]); 1 enforces the limits.
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
}

/// Which limit set the time step.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DtLimit {
    /// Advective CFL.
    #[default]
    Cfl,
    /// Explicit viscous stability.
    Viscous,
    /// Body force.
    Force,
    /// `dt_max`.
    Max,
    /// A fixed step.
    Fixed,
}

impl std::fmt::Display for DtLimit {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            DtLimit::Cfl => "CFL",
            DtLimit::Viscous => "explicit viscous",
            DtLimit::Force => "body-force",
            DtLimit::Max => "dt_max",
            DtLimit::Fixed => "fixed",
        })
    }
}

/// Frame of the particles.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Motion {
    /// Particles move with the flow (plus shifting).
    #[default]
    Lagrangian,
    /// Particles stay; the convective term `−(u·∇h)u` is added to the predictor.
    Eulerian,
}

impl std::str::FromStr for Motion {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s.trim().to_ascii_lowercase().as_str() {
            "lagrangian" => Ok(Motion::Lagrangian),
            "eulerian" => Ok(Motion::Eulerian),
            _ => Err(format!(
                "unknown motion '{s}': expected lagrangian or eulerian"
            )),
        }
    }
}

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

/// How particle volumes are set.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum VolumeRule {
    /// `ω_i = 1 / Σ_{j≠i} w_h(r_ij)`, recomputed every step (MISSION §2's consistency fix).
    #[default]
    NumberDensity,
    /// Kept as given.
    Fixed,
}

/// Everything the flow solver needs besides the particles and the boundary.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FlowParams<const D: usize> {
    /// Projection parameters (ρ, ν, g, scheme, solver).
    pub projection: ProjectionParams<D>,
    /// Time-step limits.
    pub limits: TimeStepLimits,
    /// Frame.
    pub motion: Motion,
    /// Integrator of the explicit terms.
    pub integrator: Integrator,
    /// Shifting (Lagrangian only; `None` = pure Lagrangian).
    pub shifting: Option<Shifting>,
    /// Volumes.
    pub volumes: VolumeRule,
    /// Initial particle spacing `Δx` (for shift limits).
    pub dx: f64,
}

/// A stage of a flow step. A [`StagePlan`] lists the stages a scene needs; the others never run.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Stage {
    /// Ghost images of fluid particles across walls (placement and value fills).
    Ghosts,
    /// Periodic wrap of positions and minimum-image pairs.
    Periodic,
    /// Neighbour re-measurement after particles move (Lagrangian frame).
    MovingNeighbors,
    /// Volumes `ω = 1/Σw` recomputed.
    Volumes,
    /// Convective term `−(u·∇h)u` (Eulerian frame).
    Convection,
    /// Explicit part of the viscous term.
    ViscousExplicit,
    /// Implicit (Helmholtz) part of the viscous term.
    ViscousImplicit,
    /// Body force.
    BodyForce,
    /// `−∇h pⁿ/ρ` in the predictor (incremental schemes).
    PressureGradient,
    /// Advection with `u*` (Lagrangian frame).
    Advection,
    /// Source, Poisson solve and correction.
    Projection,
    /// Rotational pressure correction `−ρθν ∇̂h·u*`.
    RotationalCorrection,
    /// Particle shifting.
    Shifting,
    /// A Dirichlet band (free surface / open boundary) anchors the pressure.
    DirichletBand,
}

/// What a scene has, and so which stages run (MISSION §4: "a scene skips every stage it does not
/// need"). Built once by [`Simulation::new`] from the boundary, the particles and the parameters.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct StagePlan {
    /// The stages, in execution order.
    pub stages: Vec<Stage>,
}

impl StagePlan {
    /// The plan for a boundary with/without ghosts and periodic axes, the roles present, and the
    /// parameters.
    pub fn new<const D: usize>(
        has_ghosts: bool,
        periodic: bool,
        has_dirichlet: bool,
        params: &FlowParams<D>,
    ) -> Self {
        let pr = &params.projection;
        let lagrangian = params.motion == Motion::Lagrangian;
        let mut s = Vec::new();
        let mut add = |c: bool, st: Stage| {
            if c {
                s.push(st)
            }
        };
        add(has_ghosts, Stage::Ghosts);
        add(periodic, Stage::Periodic);
        add(has_dirichlet, Stage::DirichletBand);
        add(params.volumes == VolumeRule::NumberDensity, Stage::Volumes);
        add(!lagrangian, Stage::Convection);
        add(
            pr.nu > 0.0 && pr.viscous_theta < 1.0,
            Stage::ViscousExplicit,
        );
        add(pr.gravity.iter().any(|&g| g != 0.0), Stage::BodyForce);
        add(
            pr.scheme != crate::projection::Scheme::NonIncremental,
            Stage::PressureGradient,
        );
        add(
            pr.nu > 0.0 && pr.viscous_theta > 0.0,
            Stage::ViscousImplicit,
        );
        add(lagrangian, Stage::Advection);
        add(lagrangian, Stage::MovingNeighbors);
        add(true, Stage::Projection);
        add(
            pr.scheme == crate::projection::Scheme::Rotational
                && pr.nu > 0.0
                && pr.viscous_theta > 0.0,
            Stage::RotationalCorrection,
        );
        add(lagrangian && params.shifting.is_some(), Stage::Shifting);
        StagePlan { stages: s }
    }
    /// True when the plan has `stage`.
    pub fn has(&self, stage: Stage) -> bool {
        self.stages.contains(&stage)
    }
}

/// A flow step's report: the projection's plus what the flow solver did around it.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct FlowReport {
    /// Step number (1 for the first step).
    pub step: u64,
    /// Time after the step.
    pub time: f64,
    /// Which limit set `Δt`.
    pub dt_limit: DtLimit,
    /// The neighbour candidates were rebuilt this step.
    pub neighbors_rebuilt: bool,
    /// Largest shift this step (distance units).
    pub max_shift: f64,
    /// Seconds: ghosts + neighbour list + volumes.
    pub neighbors_seconds: f64,
    /// Seconds: advection, shifting, confinement.
    pub advect_seconds: f64,
    /// The projection's report.
    pub projection: StepReport,
    /// `Δt` over the smallest of the CFL, explicit viscous and body-force limits at the start
    /// of the step ([`Simulation::dt_bound`]): above 1 the step exceeds a stability limit.
    pub dt_ratio: f64,
}

/// A running flow.
pub struct Simulation<const D: usize, B: Boundary<D>> {
    /// Particle state (fluid, Dirichlet band, then ghosts).
    pub particles: Particles<D>,
    /// The neighbour list at the current positions.
    pub nl: NeighborList<D>,
    /// The boundary.
    pub boundary: B,
    /// Parameters.
    pub params: FlowParams<D>,
    /// Projection scratch.
    pub projection: ProjectionStep<D>,
    /// Current time.
    pub time: f64,
    /// Steps taken.
    pub steps: u64,
    plan: StagePlan,
    grad: Vec<[[f64; D]; D]>,
    work: Vec<[f64; D]>,
    gp: Vec<[f64; D]>,
    stale: bool,
    conv_prev: Option<(Vec<[f64; D]>, f64)>,
    /// Kinetic energy after the last step (for `guard.energy_growth`).
    prev_energy: Option<f64>,
}

impl<const D: usize, B: Boundary<D>> Simulation<D, B> {
    /// Sets up ghosts, the neighbour list and volumes for `particles` (fluid and Dirichlet
    /// particles, no ghosts yet). The neighbour configuration's periodicity is taken from the
    /// boundary.
    pub fn new(
        mut particles: Particles<D>,
        boundary: B,
        neighbors: NeighborConfig<D>,
        params: FlowParams<D>,
    ) -> Result<Self, Error> {
        params.projection.validate()?;
        if !(params.dx > 0.0 && params.dx.is_finite()) {
            return Err(InputError::Parameter {
                name: "dx",
                value: params.dx,
                reason: "the particle spacing must be positive and finite".into(),
            }
            .into());
        }
        particles.validate()?;
        params.limits.validate()?;
        // a fluid particle outside the domain is an input error, not a later blow-up
        boundary.confine(&mut particles)?;
        let mut config = neighbors.with_periodicity(boundary.periodicity());
        if params.motion == Motion::Eulerian {
            // fixed particles never outgrow a skin; without it the matrix pattern holds only
            // the pairs within h (1.7x fewer entries at skin 0.3h, and less Cholesky fill)
            config.skin = 0.0;
        }
        let plan = StagePlan::new(
            boundary.has_ghosts(),
            config.periodic.any(),
            particles.role.contains(&crate::particles::Role::Dirichlet),
            &params,
        );
        let reach = config.h + config.skin;
        if plan.has(Stage::Ghosts) {
            boundary.make_ghosts(&mut particles, reach);
        }
        let nl = NeighborList::build(config, &particles.x)?;
        if nl.n_pairs() == 0 && particles.len() >= 2 {
            // h ≤ min r_ij: name h and the spacing rather than report every particle isolated
            if let Some((min_spacing, i, j)) = closest_pair(&particles.x, &config.periodic) {
                return Err(InputError::RadiusTooSmall {
                    h: config.h,
                    min_spacing,
                    i,
                    j,
                }
                .into());
            }
        }
        let mut sim = Simulation {
            particles,
            nl,
            boundary,
            params,
            projection: ProjectionStep::new(),
            time: 0.0,
            steps: 0,
            plan,
            grad: Vec::new(),
            work: Vec::new(),
            gp: Vec::new(),
            stale: false,
            conv_prev: None,
            prev_energy: None,
        };
        sim.update_volumes();
        Ok(sim)
    }

    /// The stages this simulation runs.
    pub fn plan(&self) -> &StagePlan {
        &self.plan
    }

    fn update_volumes(&mut self) {
        if self.plan.has(Stage::Volumes) {
            let v = number_density_volumes(&self.nl);
            for (i, r) in self.particles.role.iter().enumerate() {
                if r.is_fluid() {
                    self.particles.vol[i] = v[i];
                }
            }
            // ghosts copy their source's volume
            if self.plan.has(Stage::Ghosts) {
                self.boundary.place_ghosts(&mut self.particles);
            }
        }
    }

    /// Forces the next [`advance`](Self::advance) to search neighbours again, re-create the
    /// ghosts and recompute volumes, as if the particles had moved (benchmarks of reuse: a
    /// fixed-particle run otherwise builds its neighbour list once).
    pub fn invalidate_neighbors(&mut self) {
        self.nl.invalidate();
        self.stale = true;
    }

    /// Brings ghosts, neighbours and volumes up to date with the positions.
    fn refresh(&mut self) -> Result<bool, Error> {
        let ghosts = self.plan.has(Stage::Ghosts);
        if ghosts {
            self.boundary.place_ghosts(&mut self.particles);
        }
        let mut rebuilt = false;
        if self.nl.needs_rebuild(&self.particles.x) {
            if ghosts {
                let c = self.nl.config();
                let reach = c.h + c.skin;
                self.boundary.make_ghosts(&mut self.particles, reach);
            }
            self.nl.invalidate();
            rebuilt = true;
        }
        self.nl.update(&self.particles.x)?;
        self.update_volumes();
        Ok(rebuilt)
    }

    /// The time step for the current state, and the limit that set it.
    pub fn time_step(&self) -> (f64, DtLimit) {
        self.time_step_with(&self.params.limits)
    }

    fn time_step_with(&self, l: &TimeStepLimits) -> (f64, DtLimit) {
        let h = self.nl.h();
        let p = &self.particles;
        let umax =
            p.u.iter()
                .zip(&p.role)
                .filter(|(_, r)| r.is_fluid())
                .map(|(u, _)| norm2(u))
                .fold(0.0f64, f64::max)
                .sqrt();
        let mut dt = l.dt_max.unwrap_or(f64::INFINITY);
        let mut which = DtLimit::Max;
        let cfl = l.cfl * h / umax.max(l.u_ref);
        if cfl < dt {
            dt = cfl;
            which = DtLimit::Cfl;
        }
        let nu = self.params.projection.nu;
        let theta = self.params.projection.viscous_theta;
        if nu > 0.0 && theta < 0.5 {
            // θ-scheme on ν Δh: stable for Δt ν λ_max (1 − 2θ) ≤ 2, λ_max ≤ 2λ (Gershgorin)
            let lam = self.viscous_eigen_bound();
            let v = l.visc / (nu * lam * (1.0 - 2.0 * theta));
            if v < dt {
                dt = v;
                which = DtLimit::Viscous;
            }
        }
        let g = norm2(&self.params.projection.gravity).sqrt();
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

    /// `max_i 2d Σ_j ω_j w_h/r²` over fluid rows: half the Gershgorin bound on the spectrum of
    /// `−Δh` (so forward Euler on `ν Δh u` is stable for `ν Δt λ ≤ 1`).
    pub fn viscous_eigen_bound(&self) -> f64 {
        let nl = &self.nl;
        let p = &self.particles;
        let c = 2.0 * D as f64;
        (0..nl.len())
            .into_par_iter()
            .filter(|&i| p.role[i].is_fluid())
            .map(|i| {
                c * nl
                    .row(i)
                    .map(|k| p.vol[nl.indices[k] as usize] * nl.wr2[k])
                    .sum::<f64>()
            })
            .reduce(|| 0.0, f64::max)
    }

    /// The smallest of the stability limits on `Δt` for the current state (CFL, explicit
    /// viscous, body force, as in [`time_step`](Self::time_step) but without `dt_max` and a fixed
    /// step) and which one it is; `∞` (with [`DtLimit::Max`]) when none applies.
    pub fn dt_bound(&self) -> (DtLimit, f64) {
        let mut limits = self.params.limits;
        limits.dt_max = None;
        limits.dt_fixed = None;
        let (dt, which) = self.time_step_with(&limits);
        (which, dt)
    }

    /// Advances one step.
    ///
    /// Eulerian: predictor (with `−(u·∇h)u`) and projection on the fixed configuration.
    /// Lagrangian: predictor at `xⁿ`, particles moved to `x* = xⁿ + Δt u*`, neighbours and volumes
    /// refreshed, projection at `x*` (so the divergence is removed on the configuration the
    /// particles occupy, as in Cummins & Rudman 1999), then shifting.
    pub fn advance(&mut self) -> Result<FlowReport, Error> {
        let t0 = Instant::now();
        let mut rebuilt = false;
        if self.stale {
            rebuilt |= self.refresh()?;
            self.stale = false;
        }
        let mut neighbors_seconds = t0.elapsed().as_secs_f64();
        check_state(&self.particles, &self.nl)?;
        let (dt, dt_limit) = self.time_step();
        let (bound_limit, bound) = self.dt_bound();
        let dt_ratio = if bound.is_finite() { dt / bound } else { 0.0 };
        if let Some(factor) = self.params.limits.guard.dt_over_limit {
            if dt > factor * bound {
                return Err(StabilityError::TimeStepTooLarge {
                    step: self.steps + 1,
                    dt,
                    limit: bound_limit,
                    bound,
                    factor,
                }
                .into());
            }
        }
        let n = self.particles.len();
        let lagrangian = self.plan.has(Stage::Advection);
        let accel = if self.plan.has(Stage::Convection) {
            // N = (u·∇h)u with the difference gradient; AB2: −((1 + r/2) Nⁿ − (r/2) Nⁿ⁻¹)
            if self.plan.has(Stage::Ghosts) {
                self.boundary.fill_vector(
                    &self.particles.role,
                    &mut self.particles.u,
                    VectorKind::Velocity,
                );
            }
            self.grad.resize(n, [[0.0; D]; D]);
            grad_vec_into(
                &self.nl,
                &self.particles.vol,
                &self.particles.u,
                &mut self.grad,
            );
            let mut conv: Vec<[f64; D]> = vec![[0.0; D]; n];
            let u = &self.particles.u;
            conv.par_iter_mut()
                .zip(self.grad.par_iter())
                .zip(u.par_iter())
                .for_each(|((a, g), ui)| {
                    *a = std::array::from_fn(|k| (0..D).map(|b| g[k][b] * ui[b]).sum::<f64>());
                });
            self.work.resize(n, [0.0; D]);
            match (&self.conv_prev, self.params.integrator) {
                (Some((prev, dt_prev)), Integrator::Ab2) if prev.len() == n => {
                    let r = dt / dt_prev;
                    let (c1, c0) = (1.0 + 0.5 * r, 0.5 * r);
                    for i in 0..n {
                        self.work[i] =
                            std::array::from_fn(|k| -(c1 * conv[i][k] - c0 * prev[i][k]));
                    }
                }
                _ => {
                    for i in 0..n {
                        self.work[i] = conv[i].map(|v| -v);
                    }
                }
            }
            self.conv_prev = Some((conv, dt));
            Some(&self.work[..])
        } else {
            None
        };
        let proj = &self.params.projection;
        let mut u_star = Vec::new();
        let pred = self.projection.predict(
            &mut self.particles,
            &self.nl,
            &self.boundary,
            proj,
            dt,
            accel,
            &mut u_star,
        )?;
        let mut advect_seconds = 0.0;
        if lagrangian {
            // move with u* and refresh the configuration before projecting
            let t1 = Instant::now();
            let p = &mut self.particles;
            for i in 0..n {
                if p.role[i].is_fluid() {
                    for a in 0..D {
                        p.x[i][a] += dt * u_star[i][a];
                    }
                }
            }
            self.boundary.confine(p)?;
            advect_seconds += t1.elapsed().as_secs_f64();
            let t2 = Instant::now();
            rebuilt |= self.refresh()?;
            neighbors_seconds += t2.elapsed().as_secs_f64();
        }
        let mut report = self.projection.project(
            &mut self.particles,
            &self.nl,
            &self.boundary,
            &self.params.projection,
            dt,
            &u_star,
        )?;
        pred.add_to(&mut report);
        let mut max_shift = 0.0;
        if self.plan.has(Stage::Shifting) {
            let t1 = Instant::now();
            max_shift = self.shift(dt)?;
            if max_shift > 0.0 {
                self.stale = true;
            }
            advect_seconds += t1.elapsed().as_secs_f64();
        }
        self.time += dt;
        self.steps += 1;
        self.check_guard(&report)?;
        Ok(FlowReport {
            step: self.steps,
            time: self.time,
            dt_limit,
            neighbors_rebuilt: rebuilt,
            max_shift,
            neighbors_seconds,
            advect_seconds,
            projection: report,
            dt_ratio,
        })
    }

    /// The after-step checks of `limits.guard` on the step's report (see [`StabilityGuard`]).
    fn check_guard(&mut self, report: &StepReport) -> Result<(), StabilityError> {
        let g = self.params.limits.guard;
        let ke = report.kinetic_energy;
        let prev = self.prev_energy.replace(ke);
        let u_ref = self.params.limits.u_ref;
        let failed = match prev {
            Some(e0)
                if e0 > 0.0
                    && e0 >= g.energy_floor
                    && g.energy_growth.is_some_and(|f| ke > f * e0) =>
            {
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
        });
        let Some((quantity, value, Some(bound))) = failed else {
            return Ok(());
        };
        let p = &self.particles;
        let (particle, speed2) = (0..p.len())
            .filter(|&i| p.role[i].is_fluid())
            .map(|i| (i, norm2(&p.u[i])))
            .fold((0, -1.0), |a, b| if b.1 > a.1 { b } else { a });
        Err(StabilityError::BlowUp {
            step: self.steps,
            time: self.time,
            quantity,
            value,
            bound,
            particle,
            position: p.x.get(particle).map(|x| x.to_vec()).unwrap_or_default(),
            speed: speed2.max(0.0).sqrt(),
        })
    }

    /// Fickian shifting with velocity/pressure correction at the current configuration;
    /// returns the largest shift.
    fn shift(&mut self, dt: f64) -> Result<f64, Error> {
        let Some(sh) = self.params.shifting else {
            return Ok(0.0);
        };
        let n = self.particles.len();
        let nl = &self.nl;
        let kernel = *nl.kernel();
        let h = nl.h();
        let p = &self.particles;
        let lim = sh.max_fraction * self.params.dx;
        let umax =
            p.u.iter()
                .zip(&p.role)
                .filter(|(_, r)| r.is_fluid())
                .map(|(u, _)| norm2(u))
                .fold(0.0f64, f64::max)
                .sqrt();
        // δx_i = −A h |u_i| Δt ∇C_i,  ∇C_i = Σ_j ω_j ∇_i w_h(r_ij) = −Σ_j ω_j w_h'(r) dx/r
        self.work.resize(n, [0.0; D]);
        self.work.par_iter_mut().enumerate().for_each(|(i, s)| {
            *s = [0.0; D];
            if !p.role[i].is_fluid() {
                return;
            }
            let mut gc = [0.0; D];
            for k in nl.row(i) {
                let j = nl.indices[k] as usize;
                let r = nl.r2[k].sqrt();
                let c = -p.vol[j] * kernel.dw_h(r) / r;
                for a in 0..D {
                    gc[a] += c * nl.dx[k][a];
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
        let max_shift = self
            .work
            .iter()
            .map(|d| norm2(d).sqrt())
            .fold(0.0, f64::max);
        let p = &mut self.particles;
        if sh.correct {
            // Taylor correction of u and p to the shifted position (gradients before the shift)
            if self.plan.has(Stage::Ghosts) {
                self.boundary
                    .fill_vector(&p.role, &mut p.u, VectorKind::Velocity);
            }
            self.grad.resize(n, [[0.0; D]; D]);
            grad_vec_into(&self.nl, &p.vol, &p.u, &mut self.grad);
            self.gp.resize(n, [0.0; D]);
            grad_diff_into(&self.nl, &p.vol, &p.p, &mut self.gp);
            for i in 0..n {
                if !p.role[i].is_fluid() {
                    continue;
                }
                let d = self.work[i];
                for a in 0..D {
                    p.u[i][a] += (0..D).map(|b| self.grad[i][a][b] * d[b]).sum::<f64>();
                }
                p.p[i] += (0..D).map(|b| self.gp[i][b] * d[b]).sum::<f64>();
            }
        }
        for i in 0..n {
            if p.role[i].is_fluid() {
                for a in 0..D {
                    p.x[i][a] += self.work[i][a];
                }
            }
        }
        self.boundary.confine(p)?;
        Ok(max_shift)
    }
}

/// The particle arrays agree in length with each other and the neighbour list, positions,
/// velocities and pressures of the fluid particles are finite, and their volumes positive and
/// finite (except particles without neighbours, whose number-density volume is infinite and
/// which the connectivity check reports). Checked before every step, so that a bad value set
/// by the caller is named at its particle rather than surfacing later as a failed solve.
fn check_state<const D: usize>(p: &Particles<D>, nl: &NeighborList<D>) -> Result<(), InputError> {
    let n = p.x.len();
    for (field, len) in [
        ("neighbor list rows", nl.len()),
        ("u", p.u.len()),
        ("p", p.p.len()),
        ("vol", p.vol.len()),
        ("role", p.role.len()),
    ] {
        if len != n {
            return Err(InputError::LengthMismatch {
                field,
                len,
                expected: n,
            });
        }
    }
    for i in 0..p.len() {
        if !p.role[i].is_fluid() {
            continue;
        }
        let field = if !crate::math::is_finite(&p.x[i]) {
            "position"
        } else if !crate::math::is_finite(&p.u[i]) {
            "velocity"
        } else if !p.p[i].is_finite() {
            "pressure"
        } else if !nl.row(i).is_empty()
            && (p.vol[i].is_nan() || p.vol[i] <= 0.0 || p.vol[i].is_infinite())
        {
            return Err(InputError::BadVolume {
                particle: i,
                value: p.vol[i],
            });
        } else {
            continue;
        };
        return Err(InputError::NonFinite { field, particle: i });
    }
    Ok(())
}
