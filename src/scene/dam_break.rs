//! The collapse of a water column (Martin & Moyce 1952, `n² = 2`): water of width `a` and
//! height `2a` at rest against the left wall of an open tank of length `L a` (no-slip walls at
//! `x = 0`, `x = L a` and the floor), released at `t = 0` under gravity `g`. Its top and its right
//! side are a free surface ([`crate::flow::free_surface`]).
//!
//! Units: `a = 1`, `g` = the `gravity` key (default 1); the shared key `re` is `√(g a³)/ν`
//! (water at Martin & Moyce's `a = 5.7 cm`: about 4·10⁴) and `n` the particles across the
//! column's width (`Δx = a/n`). Observables, every step: the surge front `Z = z/a` against
//! `T = t√(2g/a)` (`z` the largest `x` of the water plus `Δx/2`, the edge of its particle) and
//! the residual column height `H = η/(2a)` against `τ = t√(g/a)` (`η` the largest `y` of the
//! water within `Δx` of the left wall, plus `Δx/2`), compared with the experiment
//! ([`crate::reference::martin_moyce`]) by the mean relative deviation over the measured points
//! with `1 ≤ T ≤ 3` (front) and `τ ≤ 2` (height).

use super::hydrostatic::{check_gravity, free_surface_flow, WallKind};
use super::{run_scene, FlowConfig, MonitorRanges, Scene, SceneConfig, SceneParams, Table};
use crate::boundary::Walls;
use crate::error::{Error, InputError};
use crate::flow::{FlowReport, FreeSurface, Simulation};
use crate::geometry::lattice;
use crate::particles::{Particles, Role};
use serde::{Deserialize, Serialize};
use std::ops::ControlFlow;
use std::time::Instant;

/// The dam break's own configuration keys (beside the shared [`FlowConfig`]).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DamBreak {
    /// Tank length over the column width `L` (default 5: the front travels 4a).
    pub length: f64,
    /// Gravity `g` (default 1), acting along `−y`.
    pub gravity: f64,
    /// Free-surface detection.
    pub free_surface: FreeSurface,
    /// The walls: `no_slip` (default) or `free_slip`.
    pub walls: WallKind,
}

super::config_fields!(DamBreak {
    length,
    gravity,
    free_surface,
    walls
});

impl Default for DamBreak {
    fn default() -> Self {
        DamBreak {
            length: 5.0,
            gravity: 1.0,
            free_surface: FreeSurface::default(),
            walls: WallKind::NoSlip,
        }
    }
}

/// Configuration of a dam-break run (one flat object; unknown keys are rejected).
pub type DamBreakConfig = SceneConfig<DamBreak>;

/// `T = t√(2g/a)` at which the default run ends (the experiment's front table ends at 3.33).
pub const T_END: f64 = 3.0;

impl SceneParams for DamBreak {
    const NAME: &'static str = "dam_break";
    const MIN_N: usize = 8;

    /// The free-surface defaults (`hydrostatic::free_surface_flow`) with the non-incremental scheme and
    /// `h = 4Δx`: measured at n = 40, the incremental scheme's pressure grows in a mode along
    /// the floor until the run blows up (T = 0.76 at `h = 3Δx`, T = 2.0 at `4Δx`), and with
    /// `3Δx` a spurious fast splash shrinks the time step (1 491 steps against 301).
    fn default_flow() -> FlowConfig {
        let flow = free_surface_flow(FlowConfig {
            re: 4.0e4,
            n: 40,
            t_end: T_END / 2f64.sqrt(),
            ..FlowConfig::default()
        });
        FlowConfig {
            scheme: crate::projection::Scheme::NonIncremental,
            h_over_dx: 4.0,
            ..flow
        }
    }

    fn validate(&self, _flow: &FlowConfig) -> Result<(), InputError> {
        if !(self.length.is_finite() && (2.0..=20.0).contains(&self.length)) {
            return Err(InputError::parameter(
                "length",
                self.length,
                "the tank length over the column width must be in [2, 20]",
            ));
        }
        check_gravity(self.gravity)?;
        self.free_surface.validate()
    }
}

/// Builds the dam break: the column `[0, a] × [0, 2a]` at rest in the tank `[0, L a]`, walls on
/// three sides, gravity, a free surface.
pub fn build(cfg: &DamBreakConfig) -> Result<Simulation<2, Walls<2>>, Error> {
    cfg.validate()?;
    let dx = cfg.dx();
    let mut p = Particles::<2>::new();
    for x in lattice([0.0, 0.0], [1.0, 2.0], dx) {
        p.push(x, [0.0, 0.0], 0.0, dx * dx, Role::Fluid);
    }
    let walls = cfg
        .scene
        .walls
        .apply(Walls::tank([0.0, 0.0], [cfg.scene.length, 2.0]));
    let g = cfg.scene.gravity;
    // the front's speed approaches 2√(g h) ≈ 2√(2 g a)
    let u_ref = 2.0 * (2.0 * g).sqrt();
    let mut params = cfg.flow_params(u_ref);
    params.projection.nu = g.sqrt() / cfg.re;
    params.projection.gravity = [0.0, -g];
    params.projection.allowed_floating = 0;
    super::hydrostatic::free_surface_operators(&mut params.projection, cfg.operators);
    if params.limits.guard.energy_floor == 0.0 {
        // from rest the energy grows by large factors in the first steps
        params.limits.guard.energy_floor = 1e-3 * 0.5 * u_ref * u_ref * 2.0;
    }
    Simulation::new(p, walls, cfg.neighbor_config(), params)?
        .with_free_surface(cfg.scene.free_surface)
}

/// The front `z` (largest `x` of the water plus `Δx/2`) and the column height `η` at the left
/// wall (largest `y` of the water within `Δx` of it, plus `Δx/2`). Splash particles — band
/// particles without a fluid neighbour within `h`, drops that left the bulk — are not the
/// water's front or top.
pub fn front_and_height(sim: &Simulation<2, Walls<2>>) -> (f64, f64) {
    let p = &sim.particles;
    let nl = &sim.nl;
    let dx = sim.params.dx;
    let attached = |i: usize| {
        p.role[i].is_fluid()
            || nl
                .row(i)
                .any(|k| nl.w()[k] > 0.0 && p.role[nl.indices()[k] as usize].is_fluid())
    };
    let (mut z, mut eta) = (0.0f64, 0.0f64);
    for i in 0..p.len() {
        if p.role[i].is_real() && attached(i) {
            z = z.max(p.x[i][0]);
            if p.x[i][0] < dx {
                eta = eta.max(p.x[i][1]);
            }
        }
    }
    (z + 0.5 * dx, eta + 0.5 * dx)
}

/// What a dam-break run accumulates and reports.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct DamBreakResult {
    /// Particles across the column width.
    pub n: usize,
    /// Water particles.
    pub particles: usize,
    /// Particle spacing `Δx/a`.
    pub dx: f64,
    /// Steps.
    pub steps: u64,
    /// Final time `t √(g/a)`.
    pub t_end: f64,
    /// Final `T = t√(2g/a)`.
    pub t_end_scaled: f64,
    /// Wall seconds.
    pub wall_seconds: f64,
    /// Mean relative deviation of the front from Martin & Moyce over `1 ≤ T ≤ 3`
    /// (`null` when the run did not reach a measured point).
    pub front_deviation: Option<f64>,
    /// Measured points it was taken over.
    pub front_points: usize,
    /// Mean relative deviation of the column height over `τ ≤ 2`.
    pub height_deviation: Option<f64>,
    /// Measured points it was taken over.
    pub height_points: usize,
    /// Fewest surface (band) particles in a step.
    pub surface_min: usize,
    /// Most surface particles in a step.
    pub surface_max: usize,
    /// Most splash particles (band particles without a fluid neighbour) in a step.
    pub splash_max: usize,
    /// Ranges of the per-step monitor.
    pub monitor: MonitorRanges,
    /// `(T, Z)` per step (and at `t = 0`).
    #[serde(skip)]
    pub front: Vec<(f64, f64)>,
    /// `(τ, H)` per step (and at `t = 0`).
    #[serde(skip)]
    pub height: Vec<(f64, f64)>,
    /// `(T, positions, pressures)` of the water (fluid and band particles) after the first step
    /// at or past each `T` of [`PRESSURE_AT`] (drawn into `pressure.png` with the final state).
    #[serde(skip)]
    pub pressure: Vec<(f64, Vec<[f64; 2]>, Vec<f64>)>,
}

/// `T = t√(2g/a)` at which the water's pressure is kept for `pressure.png` (the final state is
/// drawn as well).
pub const PRESSURE_AT: [f64; 3] = [0.0, 1.0, 2.0];

/// `(T, positions, pressures)` of the water now.
fn water_pressure(sim: &Simulation<2, Walls<2>>, big_t: f64) -> (f64, Vec<[f64; 2]>, Vec<f64>) {
    let p = &sim.particles;
    let water = (0..p.len()).filter(|&i| p.role[i].is_real());
    let (x, pressure) = water.map(|i| (p.x[i], p.p[i])).unzip();
    (big_t, x, pressure)
}

/// The flat summary written to `summary.json`.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct DamBreakSummary {
    /// The result.
    #[serde(flatten)]
    pub result: DamBreakResult,
    /// The configuration of the run.
    pub config: DamBreakConfig,
}

fn sample(res: &mut DamBreakResult, g: f64, t: f64, sim: &Simulation<2, Walls<2>>) {
    let (z, eta) = front_and_height(sim);
    res.front.push((t * (2.0 * g).sqrt(), z));
    res.height.push((t * g.sqrt(), eta / 2.0));
    let big_t = t * (2.0 * g).sqrt();
    // not at t = 0, where no step has set the pressure yet
    if t > 0.0
        && PRESSURE_AT
            .get(res.pressure.len())
            .is_some_and(|&at| big_t >= at)
    {
        res.pressure.push(water_pressure(sim, big_t));
    }
}

impl Scene<2> for DamBreak {
    type Boundary = Walls<2>;
    type State = DamBreakResult;
    type Result = DamBreakResult;
    type Summary = DamBreakSummary;
    const LAND_ON_T_END: bool = true;

    fn build(cfg: &DamBreakConfig) -> Result<Simulation<2, Walls<2>>, Error> {
        build(cfg)
    }

    fn start(cfg: &DamBreakConfig, sim: &Simulation<2, Walls<2>>) -> DamBreakResult {
        let mut res = DamBreakResult {
            n: cfg.n,
            particles: sim.particles.role.iter().filter(|r| r.is_real()).count(),
            dx: sim.params.dx,
            surface_min: usize::MAX,
            monitor: MonitorRanges::new(),
            ..Default::default()
        };
        sample(&mut res, cfg.scene.gravity, 0.0, sim);
        res
    }

    fn observe(
        res: &mut DamBreakResult,
        cfg: &DamBreakConfig,
        rep: &FlowReport,
        sim: &Simulation<2, Walls<2>>,
    ) -> ControlFlow<()> {
        res.monitor.observe(rep);
        if let Some(s) = rep.surface {
            res.surface_min = res.surface_min.min(s.surface);
            res.surface_max = res.surface_max.max(s.surface);
            res.splash_max = res.splash_max.max(s.splash);
        }
        sample(res, cfg.scene.gravity, rep.time, sim);
        ControlFlow::Continue(())
    }

    fn finish(
        mut res: DamBreakResult,
        cfg: &DamBreakConfig,
        sim: &Simulation<2, Walls<2>>,
        started: Instant,
    ) -> DamBreakResult {
        res.steps = sim.steps;
        res.t_end = sim.time * cfg.scene.gravity.sqrt();
        res.t_end_scaled = sim.time * (2.0 * cfg.scene.gravity).sqrt();
        if res.surface_min == usize::MAX {
            res.surface_min = 0;
        }
        let mm = crate::reference::martin_moyce();
        let front = crate::reference::mean_relative_deviation(&res.front, &mm.front, 1.0, 3.0);
        let height = crate::reference::mean_relative_deviation(&res.height, &mm.height, 0.0, 2.0);
        (res.front_deviation, res.front_points) = front.map_or((None, 0), |(d, k)| (Some(d), k));
        (res.height_deviation, res.height_points) = height.map_or((None, 0), |(d, k)| (Some(d), k));
        res.wall_seconds = started.elapsed().as_secs_f64();
        res
    }

    fn summary(cfg: &DamBreakConfig, res: &DamBreakResult) -> DamBreakSummary {
        DamBreakSummary {
            result: res.clone(),
            config: cfg.clone(),
        }
    }

    fn tables(_cfg: &DamBreakConfig, res: &DamBreakResult) -> Vec<Table> {
        vec![
            Table::pairs("front.csv", "T,Z", &res.front),
            Table::pairs("height.csv", "tau,H", &res.height),
        ]
    }

    #[cfg(feature = "cli")]
    fn write_plots(
        dir: &std::path::Path,
        cfg: &DamBreakConfig,
        res: &DamBreakResult,
        sim: &Simulation<2, Walls<2>>,
    ) -> Result<(), crate::plot::PlotError> {
        use crate::plot::{line_charts, particle_panels, Chart, ParticleView, Series, Snapshot};
        let mm = crate::reference::martin_moyce();
        let dev = |d: Option<f64>| d.map_or("–".to_string(), |d| format!("{:.1} %", 100.0 * d));
        line_charts(
            &dir.join("dam_break.png"),
            1200,
            520,
            &[
                (
                    Chart {
                        title: format!(
                            "surge front, n = {}: mean deviation {} (1 ≤ T ≤ 3)",
                            res.n,
                            dev(res.front_deviation)
                        ),
                        x_label: "T = t √(2g/a)".into(),
                        y_label: "Z = z/a".into(),
                        ..Default::default()
                    },
                    vec![
                        Series::line("gpm", res.front.clone()),
                        Series::points("Martin & Moyce 1952", mm.front.clone()),
                    ],
                ),
                (
                    Chart {
                        title: format!(
                            "column height: mean deviation {} (τ ≤ 2)",
                            dev(res.height_deviation)
                        ),
                        x_label: "τ = t √(g/a)".into(),
                        y_label: "H = η/(2a)".into(),
                        ..Default::default()
                    },
                    vec![
                        Series::line("gpm", res.height.clone()),
                        Series::points("Martin & Moyce 1952", mm.height.clone()),
                    ],
                ),
            ],
        )?;
        let mut shots = res.pressure.clone();
        let end = sim.time * (2.0 * cfg.scene.gravity).sqrt();
        if shots.last().is_none_or(|s| (s.0 - end).abs() > 1e-9) {
            shots.push(water_pressure(sim, end));
        }
        let shots: Vec<Snapshot> = shots
            .into_iter()
            .map(|(t, x, value)| Snapshot {
                title: format!("T = t √(2g/a) = {t:.2}"),
                x,
                value,
            })
            .collect();
        // a few particles' pressure spikes would leave the rest in one colour
        let note = "1–99 % quantiles\nover the panels\n(beyond: end colours)";
        let mut view = ParticleView::fit(&shots, "pressure p", note);
        view.quantile_scale(&shots, 0.01);
        view.include([0.0, 0.0], [cfg.scene.length, 2.0]);
        let title = format!("dam break, n = {}: pressure", res.n);
        particle_panels(&dir.join("pressure.png"), &title, &shots, 2, 560, &view)
    }
}

/// Runs a dam break to `t_end` through [`run_scene`].
pub fn run(cfg: &DamBreakConfig) -> Result<DamBreakResult, Error> {
    Ok(run_scene(cfg, |_| {}, |_, _| Ok(ControlFlow::Continue(())))?.result)
}
