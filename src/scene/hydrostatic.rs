//! A tank at rest: water of depth `H` in an open tank of width `W` (no-slip walls on the two
//! sides and the floor), under gravity `g`, its top a free surface ([`crate::flow::free_surface`]).
//! The exact state is rest with the hydrostatic pressure `p = ρ g (H − y)`.
//!
//! Units: `H = 1`, `g` = the `gravity` key (default 1), so the time unit is `√(H/g)`; the
//! shared key `re` is `√(g H³)/ν`. The particles start on a cell-centred lattice, `n` across
//! the width (`Δx = W/n`), at rest with zero pressure: the first steps find the pressure and
//! any motion they start must decay. The run reports the pressure's relative L2 error against
//! `ρ g (H − y)` over every water particle at the end, the largest displacement of a particle
//! from its initial position over the run (in `Δx`), and the kinetic energy.

use super::{
    run_scene, FlowConfig, MonitorRanges, OperatorSet, Scene, SceneConfig, SceneParams, Table,
};
use crate::boundary::Walls;
use crate::consistent::GradientKind;
use crate::error::{Error, InputError};
use crate::flow::{FlowReport, FreeSurface, Motion, Simulation, VolumeRule};
use crate::geometry::lattice;
use crate::particles::{Particles, Role};
use crate::projection::Scheme;
use serde::{Deserialize, Serialize};
use std::ops::ControlFlow;
use std::time::Instant;

/// The tank's own configuration keys (beside the shared [`FlowConfig`]).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Hydrostatic {
    /// Tank width over water depth `W/H` (default 1).
    pub width: f64,
    /// Gravity `g` (default 1), acting along `−y`.
    pub gravity: f64,
    /// Free-surface detection.
    pub free_surface: FreeSurface,
    /// The walls: `no_slip` (default) or `free_slip`.
    pub walls: WallKind,
}

super::config_fields!(Hydrostatic {
    width,
    gravity,
    free_surface,
    walls
});

/// The walls of a free-surface scene (config key `walls`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum WallKind {
    /// No-slip: the image of a particle moves with `2U − u` ([`crate::boundary::Wall::slip`] false).
    #[default]
    NoSlip,
    /// Free-slip: no penetration, no friction ([`Walls::free_slip`]).
    FreeSlip,
}

impl WallKind {
    /// `walls` with this condition on every wall.
    pub fn apply<const D: usize>(self, walls: Walls<D>) -> Walls<D> {
        match self {
            WallKind::NoSlip => walls,
            WallKind::FreeSlip => walls.free_slip(),
        }
    }
}

impl Default for Hydrostatic {
    fn default() -> Self {
        Hydrostatic {
            width: 1.0,
            gravity: 1.0,
            free_surface: FreeSurface::default(),
            walls: WallKind::NoSlip,
        }
    }
}

/// Configuration of a tank run (one flat object; unknown keys are rejected).
pub type HydrostaticConfig = SceneConfig<Hydrostatic>;

impl SceneParams for Hydrostatic {
    const NAME: &'static str = "hydrostatic";
    const MIN_N: usize = 8;

    fn default_flow() -> FlowConfig {
        free_surface_flow(FlowConfig {
            re: 100.0,
            n: 40,
            t_end: 5.0,
            ..FlowConfig::default()
        })
    }

    fn validate(&self, _flow: &FlowConfig) -> Result<(), InputError> {
        if !(self.width.is_finite() && (0.25..=16.0).contains(&self.width)) {
            return Err(InputError::parameter(
                "width",
                self.width,
                "the tank width over the water depth must be in [0.25, 16]",
            ));
        }
        check_gravity(self.gravity)?;
        self.free_surface.validate()
    }
}

/// The shared defaults of a free-surface scene: Lagrangian particles, the incremental scheme
/// (at rest its pressure balances gravity through the same gradient the predictor uses, so the
/// steady state is exact for that gradient; the band's pressure is reset to zero every step),
/// fixed volumes `Δx^D` (the number density falls at the surface; the volume of a water
/// particle does not), the GPM sum-form source (zero on the band: the paper's problem) with the
/// renormalised gradient (first order at the surface, where the neighbourhood is one-sided;
/// measured on the tank at rest: the least-squares set, whose divergence reads the band's
/// velocity, oscillates and blows up, and the difference gradient, half-weighted at the surface,
/// lets the surface sink).
pub(crate) fn free_surface_flow(flow: FlowConfig) -> FlowConfig {
    FlowConfig {
        motion: Motion::Lagrangian,
        scheme: Scheme::Incremental,
        volumes: VolumeRule::Fixed,
        operators: OperatorSet::Gpm,
        gradient: GradientKind::Renormalised,
        ..flow
    }
}

/// The operators of a free-surface scene's projection: with `operators = gpm` (the scenes'
/// default) the consistent divergence `∇ᶜ·` for the source — it reads the band's velocity,
/// the water's own below it, so water flowing toward the moving surface is not taken for
/// compression (the sum form with `f̂ = 0` on the band treats the band as a wall at rest, and
/// the measured column hardly collapses) — and the renormalised gradient `∇ᶜ`; `consistent`
/// keeps the least-squares set, `auto` is `gpm` here.
pub(crate) fn free_surface_operators<const D: usize>(
    p: &mut crate::projection::ProjectionParams<D>,
    set: OperatorSet,
) {
    if set != OperatorSet::Consistent {
        p.source = crate::projection::SourceKind::Renormalised;
        p.gradient = GradientKind::Renormalised;
    }
}

/// Gravity must be positive and finite.
pub(crate) fn check_gravity(g: f64) -> Result<(), InputError> {
    if !(g.is_finite() && g > 0.0 && g <= 1e3) {
        return Err(InputError::parameter(
            "gravity",
            g,
            "gravity must be positive and at most 1e3",
        ));
    }
    Ok(())
}

/// Builds the tank: water on `[0, W] × [0, 1]` at rest, walls on three sides, gravity, a free
/// surface.
pub fn build(cfg: &HydrostaticConfig) -> Result<Simulation<2, Walls<2>>, Error> {
    cfg.validate()?;
    let width = cfg.scene.width;
    let dx = width / cfg.n as f64;
    let rows = (1.0 / dx).round().max(1.0);
    let depth = rows * dx;
    let mut p = Particles::<2>::new();
    for x in lattice([0.0, 0.0], [width, depth], dx) {
        p.push(x, [0.0, 0.0], 0.0, dx * dx, Role::Fluid);
    }
    let walls = cfg
        .scene
        .walls
        .apply(Walls::tank([0.0, 0.0], [width, depth]));
    let g = cfg.scene.gravity;
    let u_ref = (g * depth).sqrt();
    let mut flow = cfg.flow.clone();
    flow.n = cfg.n;
    let mut params = flow.flow_params(u_ref);
    params.dx = dx;
    params.projection.nu = u_ref * depth / cfg.re;
    params.projection.gravity = [0.0, -g];
    params.projection.allowed_floating = 0;
    free_surface_operators(&mut params.projection, cfg.operators);
    // a tank at rest has only noise-level kinetic energy: judge its growth from ½ρU²|Ω|·10⁻³ on
    if params.limits.guard.energy_floor == 0.0 {
        params.limits.guard.energy_floor = 1e-3 * 0.5 * u_ref * u_ref * width * depth;
    }
    let neighbors = crate::neighbors::NeighborConfig::new_relative(
        cfg.weight,
        dx,
        cfg.h_over_dx,
        cfg.skin_over_h,
    );
    Simulation::new(p, walls, neighbors, params)?.with_free_surface(cfg.scene.free_surface)
}

/// Relative L2 error of the pressure of the water particles against `ρ g (H − y)`.
pub fn pressure_error(sim: &Simulation<2, Walls<2>>, depth: f64, g: f64) -> f64 {
    let p = &sim.particles;
    let rho = sim.params.projection.rho;
    let (mut e2, mut n2) = (0.0, 0.0);
    for i in 0..p.len() {
        if p.role[i].is_real() {
            let exact = rho * g * (depth - p.x[i][1]);
            e2 += (p.p[i] - exact).powi(2);
            n2 += exact * exact;
        }
    }
    (e2 / n2.max(f64::MIN_POSITIVE)).sqrt()
}

/// What a tank run accumulates and reports.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct HydrostaticResult {
    /// Particles across the width.
    pub n: usize,
    /// Water particles.
    pub particles: usize,
    /// Water depth `H` (the lattice's rows times `Δx`).
    pub depth: f64,
    /// Particle spacing.
    pub dx: f64,
    /// Steps.
    pub steps: u64,
    /// Final time.
    pub t_end: f64,
    /// Wall seconds.
    pub wall_seconds: f64,
    /// Relative L2 error of the pressure against `ρ g (H − y)` at the end.
    pub pressure_l2_error: f64,
    /// Largest distance of a particle from its initial position over the run, over `Δx`.
    pub max_drift_over_dx: f64,
    /// Largest kinetic energy over the run.
    pub kinetic_energy_max: f64,
    /// Kinetic energy at the end.
    pub kinetic_energy_final: f64,
    /// Kinetic energy at the end over its largest value (< 1: the motion decays).
    pub kinetic_energy_decay: f64,
    /// Fewest and most surface (band) particles in a step.
    pub surface_min: usize,
    /// Most surface particles in a step.
    pub surface_max: usize,
    /// Ranges of the per-step monitor.
    pub monitor: MonitorRanges,
    /// Initial positions (not serialised).
    #[serde(skip)]
    pub x0: Vec<[f64; 2]>,
    /// `(t, kinetic energy)` per step.
    #[serde(skip)]
    pub energy: Vec<(f64, f64)>,
    /// `(y, p)` of every water particle at the end, sorted by `y`.
    #[serde(skip)]
    pub profile: Vec<(f64, f64)>,
}

/// The flat summary written to `summary.json`.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct HydrostaticSummary {
    /// The result.
    #[serde(flatten)]
    pub result: HydrostaticResult,
    /// The configuration of the run.
    pub config: HydrostaticConfig,
}

impl Scene<2> for Hydrostatic {
    type Boundary = Walls<2>;
    type State = HydrostaticResult;
    type Result = HydrostaticResult;
    type Summary = HydrostaticSummary;
    const LAND_ON_T_END: bool = true;

    fn build(cfg: &HydrostaticConfig) -> Result<Simulation<2, Walls<2>>, Error> {
        build(cfg)
    }

    fn start(cfg: &HydrostaticConfig, sim: &Simulation<2, Walls<2>>) -> HydrostaticResult {
        let p = &sim.particles;
        let x0: Vec<[f64; 2]> = (0..p.len())
            .filter(|&i| p.role[i].is_real())
            .map(|i| p.x[i])
            .collect();
        HydrostaticResult {
            n: cfg.n,
            particles: x0.len(),
            dx: sim.params.dx,
            depth: (1.0 / sim.params.dx).round() * sim.params.dx,
            x0,
            surface_min: usize::MAX,
            monitor: MonitorRanges::new(),
            ..Default::default()
        }
    }

    fn observe(
        res: &mut HydrostaticResult,
        _cfg: &HydrostaticConfig,
        rep: &FlowReport,
        sim: &Simulation<2, Walls<2>>,
    ) -> ControlFlow<()> {
        res.monitor.observe(rep);
        let p = &sim.particles;
        let mut ke = 0.0;
        for (i, x0) in res.x0.iter().enumerate() {
            let d = ((p.x[i][0] - x0[0]).powi(2) + (p.x[i][1] - x0[1]).powi(2)).sqrt();
            res.max_drift_over_dx = res.max_drift_over_dx.max(d / res.dx);
            ke += 0.5 * p.vol[i] * (p.u[i][0].powi(2) + p.u[i][1].powi(2));
        }
        ke *= sim.params.projection.rho;
        res.energy.push((rep.time, ke));
        res.kinetic_energy_max = res.kinetic_energy_max.max(ke);
        if let Some(s) = rep.surface {
            res.surface_min = res.surface_min.min(s.surface);
            res.surface_max = res.surface_max.max(s.surface);
        }
        ControlFlow::Continue(())
    }

    fn finish(
        mut res: HydrostaticResult,
        cfg: &HydrostaticConfig,
        sim: &Simulation<2, Walls<2>>,
        started: Instant,
    ) -> HydrostaticResult {
        res.steps = sim.steps;
        res.t_end = sim.time;
        res.pressure_l2_error = pressure_error(sim, res.depth, cfg.scene.gravity);
        res.kinetic_energy_final = res.energy.last().map_or(0.0, |e| e.1);
        res.kinetic_energy_decay = if res.kinetic_energy_max > 0.0 {
            res.kinetic_energy_final / res.kinetic_energy_max
        } else {
            0.0
        };
        if res.surface_min == usize::MAX {
            res.surface_min = 0;
        }
        let p = &sim.particles;
        res.profile = (0..p.len())
            .filter(|&i| p.role[i].is_real())
            .map(|i| (p.x[i][1], p.p[i]))
            .collect();
        res.profile.sort_by(|a, b| a.0.total_cmp(&b.0));
        res.wall_seconds = started.elapsed().as_secs_f64();
        res
    }

    fn summary(cfg: &HydrostaticConfig, res: &HydrostaticResult) -> HydrostaticSummary {
        HydrostaticSummary {
            result: res.clone(),
            config: cfg.clone(),
        }
    }

    fn tables(_cfg: &HydrostaticConfig, res: &HydrostaticResult) -> Vec<Table> {
        vec![
            Table::pairs("pressure.csv", "y,p", &res.profile),
            Table::pairs("energy.csv", "t,kinetic_energy", &res.energy),
        ]
    }
}

/// Runs a tank to `t_end` through [`run_scene`].
pub fn run(cfg: &HydrostaticConfig) -> Result<HydrostaticResult, Error> {
    Ok(run_scene(cfg, |_| {}, |_, _| Ok(ControlFlow::Continue(())))?.result)
}
