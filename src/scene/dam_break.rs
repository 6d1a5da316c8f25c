//! The collapse of a water column (Martin & Moyce 1952, `n² = 2`): water of width `a` and
//! height `2a` at rest against the left wall of an open tank of length `L a` (walls at `x = 0`,
//! `x = L a` and the floor), released at `t = 0` under gravity `g`. Its top and its right side
//! are a free surface ([`crate::flow::free_surface`]).
//!
//! The walls are free-slip by default (`walls` key; `no_slip` selectable). At Martin & Moyce's
//! `Re ≈ 4·10⁴` the walls' boundary layers stay thinner than `√(ν t) ≈ 0.007 a` over the run,
//! below a particle spacing at every resolution run here, and the no-slip images put a layer a
//! spacing thick at rest: measured (2026-11-28), its band particles hang on the wall `x = 0` as
//! a film (column height 11–12 % off the experiment at n = 32–60, 2.0–2.2 % free-slip), and the
//! held-back particles at the floor are overrun by the water above, which the wall margin
//! pushes back (33–116 pushes a run; with the band held at zero that overrun stopped n = 24 on
//! the speed guard).
//!
//! Units: `a = 1`, `g` = the `gravity` key (default 1); the shared key `re` is `√(g a³)/ν`
//! (water at Martin & Moyce's `a = 5.7 cm`: about 4·10⁴) and `n` the particles across the
//! column's width (`Δx = a/n`). Observables, every step: the surge front `Z = z/a` against
//! `T = t√(2g/a)` (`z` the largest `x` of the water plus `Δx/2`, the edge of its particle) and
//! the residual column height `H = η/(2a)` against `τ = t√(g/a)` (`η` the largest `y` of the
//! water within `Δx` of the left wall, plus `Δx/2`), compared with the experiment
//! ([`crate::reference::martin_moyce`]) by the mean relative deviation over the measured points
//! with `1 ≤ T ≤ 3` (front) and `τ ≤ 2` (height). The summary also gives the front's fitted
//! start-up delay ([`crate::reference::best_delay`]): the experiment's release was not
//! instantaneous, and the simulated front delayed by `ΔT ≈ 0.24–0.29` lies within about 1 % of
//! it (free-slip, n = 24–60).
//!
//! The build, the observables and the report are generic over the dimension ([`ColumnScene`]:
//! [`build_column`], [`front_and_height`]; the vertical is the last axis), shared with the 3D
//! dam break ([`super::dam_break_3d`]): every [`ColumnScene<D>`] is a [`Scene<D>`]. Every run
//! reports its mean time per step and the water's volume `Σ ω` (kept: fixed volumes, no
//! particle lost).

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
    /// The walls: `free_slip` (default) or `no_slip` (module docs: why).
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
            walls: WallKind::FreeSlip,
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

/// The geometry and physics of a column collapse, whatever the dimension: what the 2D
/// [`DamBreak`] and the 3D [`super::dam_break_3d::DamBreak3d`] share.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ColumnSpec {
    /// Tank length over the column width `L`.
    pub length: f64,
    /// Depth of column and tank across the flow `b/a` (3D: along `y`; unused in 2D), rounded
    /// to whole particle spacings by [`column_extent`].
    pub depth: f64,
    /// Gravity `g`, along `−x_{D−1}`.
    pub gravity: f64,
    /// Free-surface detection.
    pub free_surface: FreeSurface,
    /// The walls.
    pub walls: WallKind,
}

/// A column-collapse scene in `D` dimensions: its keys give a [`ColumnSpec`]. Every such
/// scene is a [`Scene<D>`] through one generic implementation (build, observe, report).
pub trait ColumnScene<const D: usize>: SceneParams {
    /// What the plots call the scene (`"dam break"`).
    const TITLE: &'static str;
    /// The column and tank.
    fn spec(&self) -> ColumnSpec;
}

impl ColumnScene<2> for DamBreak {
    const TITLE: &'static str = "dam break";
    fn spec(&self) -> ColumnSpec {
        ColumnSpec {
            length: self.length,
            depth: 1.0,
            gravity: self.gravity,
            free_surface: self.free_surface,
            walls: self.walls,
        }
    }
}

/// The upper corner of the column, `[1, b, 2]` in 3D (`[1, 2]` in 2D): width `a = 1` along
/// `x_0`, height `2a` along `x_{D−1}` (up), the depth `b` rounded to a whole number (at least
/// one) of spacings `dx` on the axes between.
pub fn column_extent<const D: usize>(spec: &ColumnSpec, dx: f64) -> [f64; D] {
    let depth = (spec.depth / dx).round().max(1.0) * dx;
    std::array::from_fn(|a| match a {
        0 => 1.0,
        a if a == D - 1 => 2.0,
        _ => depth,
    })
}

/// Builds a column collapse in `D` dimensions: the column `[0, a] × [0, b] × [0, 2a]` (2D:
/// `[0, a] × [0, 2a]`) at rest against the wall `x = 0` of the tank `[0, L a] × [0, b] × [0,
/// 2a]`, walls on every side but the top, gravity along `−x_{D−1}`, a free surface.
pub fn build_column<const D: usize>(
    flow: &FlowConfig,
    spec: &ColumnSpec,
) -> Result<Simulation<D, Walls<D>>, Error> {
    let dx = flow.dx();
    let hi = column_extent::<D>(spec, dx);
    let mut p = Particles::<D>::new();
    for x in lattice([0.0; D], hi, dx) {
        p.push(x, [0.0; D], 0.0, dx.powi(D as i32), Role::Fluid);
    }
    let mut tank = hi;
    tank[0] = spec.length;
    let walls = spec.walls.apply(Walls::tank([0.0; D], tank));
    let g = spec.gravity;
    // the front's speed approaches 2√(g h) ≈ 2√(2 g a)
    let u_ref = 2.0 * (2.0 * g).sqrt();
    let mut params = flow.flow_params(u_ref);
    params.projection.nu = g.sqrt() / flow.re;
    params.projection.gravity[D - 1] = -g;
    params.projection.allowed_floating = 0;
    super::hydrostatic::free_surface_operators(&mut params.projection, flow.operators);
    if params.limits.guard.energy_floor == 0.0 {
        // from rest the energy grows by large factors in the first steps
        let volume: f64 = hi.iter().product();
        params.limits.guard.energy_floor = 1e-3 * 0.5 * u_ref * u_ref * volume;
    }
    Simulation::new(p, walls, flow.neighbor_config(), params)?.with_free_surface(spec.free_surface)
}

/// Builds the dam break: the column `[0, a] × [0, 2a]` at rest in the tank `[0, L a]`, walls on
/// three sides, gravity, a free surface ([`build_column`] in 2D).
pub fn build(cfg: &DamBreakConfig) -> Result<Simulation<2, Walls<2>>, Error> {
    cfg.validate()?;
    build_column(cfg, &cfg.scene.spec())
}

/// The front `z` (largest `x_0` of the water plus `Δx/2`) and the column height `η` at the
/// left wall (largest `x_{D−1}` of the water within `Δx` of it, plus `Δx/2`), in any
/// dimension (3D: over the whole depth). Splash particles — band particles without a fluid
/// neighbour within `h`, drops that left the bulk — are not the water's front or top.
pub fn front_and_height<const D: usize>(sim: &Simulation<D, Walls<D>>) -> (f64, f64) {
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
                eta = eta.max(p.x[i][D - 1]);
            }
        }
    }
    (z + 0.5 * dx, eta + 0.5 * dx)
}

/// The water's volume `Σ ω_i` over the fluid and band particles.
fn water_volume<const D: usize>(sim: &Simulation<D, Walls<D>>) -> f64 {
    let p = &sim.particles;
    (0..p.len())
        .filter(|&i| p.role[i].is_real())
        .map(|i| p.vol[i])
        .sum()
}

/// What a dam-break run accumulates and reports (2D and 3D).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct DamBreakResult {
    /// Particles across the column width.
    pub n: usize,
    /// Water particles.
    pub particles: usize,
    /// Particle spacing `Δx/a`.
    pub dx: f64,
    /// 3D: the depth `b/a` of column and tank, rounded to whole spacings (absent in 2D).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub depth: Option<f64>,
    /// Steps.
    pub steps: u64,
    /// Final time `t √(g/a)`.
    pub t_end: f64,
    /// Final `T = t√(2g/a)`.
    pub t_end_scaled: f64,
    /// Wall seconds (set-up included).
    pub wall_seconds: f64,
    /// Mean wall seconds per step (set-up excluded).
    #[serde(default)]
    pub seconds_per_step: f64,
    /// Mean relative deviation of the front from Martin & Moyce over `1 ≤ T ≤ 3`
    /// (`null` when the run did not reach a measured point).
    pub front_deviation: Option<f64>,
    /// Measured points it was taken over.
    pub front_points: usize,
    /// The delay `ΔT` of the simulated front (in `[0, 1]`) nearest to the experiment over
    /// `1 ≤ T ≤ 3` ([`crate::reference::best_delay`]): a diagnostic of the experiment's
    /// start-up (its gate's removal is not modelled), fitted to the measurements — not part of
    /// `front_deviation`.
    #[serde(default)]
    pub front_delay: Option<f64>,
    /// The front's mean relative deviation with that delay.
    #[serde(default)]
    pub front_delayed_deviation: Option<f64>,
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
    /// The water's volume `Σ ω` (fluid and band particles) at the start.
    #[serde(default)]
    pub volume: f64,
    /// Largest relative change of the water's volume from the start over the steps (the
    /// particles keep their volumes `Δx^D` and none is lost: 0 up to round-off).
    #[serde(default)]
    pub volume_change: f64,
    /// Ranges of the per-step monitor.
    pub monitor: MonitorRanges,
    /// `(T, Z)` per step (and at `t = 0`).
    #[serde(skip)]
    pub front: Vec<(f64, f64)>,
    /// `(τ, H)` per step (and at `t = 0`).
    #[serde(skip)]
    pub height: Vec<(f64, f64)>,
    /// `(T, positions, pressures)` of the water (fluid and band particles; 3D: those of the
    /// mid-plane slab `|y − b/2| ≤ Δx/2`, positions `(x, z)`) after the first step at or past
    /// each `T` of [`PRESSURE_AT`] (drawn into `pressure.png` with the final state).
    #[serde(skip)]
    pub pressure: Vec<(f64, Vec<[f64; 2]>, Vec<f64>)>,
    /// When the first step began (after the set-up).
    #[serde(skip)]
    pub stepping_from: Option<Instant>,
}

/// `T = t√(2g/a)` at which the water's pressure is kept for `pressure.png` (the final state is
/// drawn as well).
pub const PRESSURE_AT: [f64; 3] = [0.0, 1.0, 2.0];

/// `(T, positions, pressures)` of the water now, positions `(x_0, x_{D−1})`; in 3D only the
/// particles of the mid-plane slab `|x_1 − depth/2| ≤ Δx/2`.
fn water_pressure<const D: usize>(
    sim: &Simulation<D, Walls<D>>,
    depth: f64,
    big_t: f64,
) -> (f64, Vec<[f64; 2]>, Vec<f64>) {
    let p = &sim.particles;
    let slab = 0.5 * sim.params.dx + 1e-9;
    let water = (0..p.len()).filter(|&i| {
        p.role[i].is_real() && (1..D - 1).all(|a| (p.x[i][a] - 0.5 * depth).abs() <= slab)
    });
    let (x, pressure) = water.map(|i| ([p.x[i][0], p.x[i][D - 1]], p.p[i])).unzip();
    (big_t, x, pressure)
}

/// The flat summary written to `summary.json`.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ColumnSummary<S> {
    /// The result.
    #[serde(flatten)]
    pub result: DamBreakResult,
    /// The configuration of the run.
    pub config: SceneConfig<S>,
}

/// The 2D dam break's `summary.json`.
pub type DamBreakSummary = ColumnSummary<DamBreak>;

fn sample<const D: usize>(
    res: &mut DamBreakResult,
    spec: &ColumnSpec,
    t: f64,
    sim: &Simulation<D, Walls<D>>,
) {
    let g = spec.gravity;
    let (z, eta) = front_and_height(sim);
    let big_t = t * (2.0 * g).sqrt();
    res.front.push((big_t, z));
    res.height.push((t * g.sqrt(), eta / 2.0));
    // not at t = 0, where no step has set the pressure yet
    if t > 0.0
        && PRESSURE_AT
            .get(res.pressure.len())
            .is_some_and(|&at| big_t >= at)
    {
        let depth = res.depth.unwrap_or(0.0);
        res.pressure.push(water_pressure(sim, depth, big_t));
    }
}

impl<const D: usize, S: ColumnScene<D>> Scene<D> for S {
    type Boundary = Walls<D>;
    type State = DamBreakResult;
    type Result = DamBreakResult;
    type Summary = ColumnSummary<S>;
    const LAND_ON_T_END: bool = true;

    fn build(cfg: &SceneConfig<S>) -> Result<Simulation<D, Walls<D>>, Error> {
        cfg.validate()?;
        build_column(cfg, &cfg.scene.spec())
    }

    fn start(cfg: &SceneConfig<S>, sim: &Simulation<D, Walls<D>>) -> DamBreakResult {
        let spec = cfg.scene.spec();
        let mut res = DamBreakResult {
            n: cfg.n,
            particles: sim.particles.role.iter().filter(|r| r.is_real()).count(),
            dx: sim.params.dx,
            depth: (D > 2).then(|| column_extent::<D>(&spec, sim.params.dx)[1]),
            surface_min: usize::MAX,
            volume: water_volume(sim),
            monitor: MonitorRanges::new(),
            stepping_from: Some(Instant::now()),
            ..Default::default()
        };
        sample(&mut res, &spec, 0.0, sim);
        res
    }

    fn observe(
        res: &mut DamBreakResult,
        cfg: &SceneConfig<S>,
        rep: &FlowReport,
        sim: &Simulation<D, Walls<D>>,
    ) -> ControlFlow<()> {
        res.monitor.observe(rep);
        if let Some(s) = rep.surface {
            res.surface_min = res.surface_min.min(s.surface);
            res.surface_max = res.surface_max.max(s.surface);
            res.splash_max = res.splash_max.max(s.splash);
        }
        let change = (water_volume(sim) / res.volume - 1.0).abs();
        // a NaN volume is the largest change
        res.volume_change = if change.is_nan() {
            f64::INFINITY
        } else {
            res.volume_change.max(change)
        };
        sample(res, &cfg.scene.spec(), rep.time, sim);
        ControlFlow::Continue(())
    }

    fn finish(
        mut res: DamBreakResult,
        cfg: &SceneConfig<S>,
        sim: &Simulation<D, Walls<D>>,
        started: Instant,
    ) -> DamBreakResult {
        let g = cfg.scene.spec().gravity;
        res.steps = sim.steps;
        res.t_end = sim.time * g.sqrt();
        res.t_end_scaled = sim.time * (2.0 * g).sqrt();
        if res.surface_min == usize::MAX {
            res.surface_min = 0;
        }
        let mm = crate::reference::martin_moyce();
        let front = crate::reference::mean_relative_deviation(&res.front, &mm.front, 1.0, 3.0);
        let height = crate::reference::mean_relative_deviation(&res.height, &mm.height, 0.0, 2.0);
        (res.front_deviation, res.front_points) = front.map_or((None, 0), |(d, k)| (Some(d), k));
        let delay = crate::reference::best_delay(&res.front, &mm.front, 1.0, 3.0, 1.0);
        (res.front_delay, res.front_delayed_deviation) = delay.unzip();
        (res.height_deviation, res.height_points) = height.map_or((None, 0), |(d, k)| (Some(d), k));
        res.wall_seconds = started.elapsed().as_secs_f64();
        if let (Some(from), true) = (res.stepping_from, sim.steps > 0) {
            res.seconds_per_step = from.elapsed().as_secs_f64() / sim.steps as f64;
        }
        res
    }

    fn summary(cfg: &SceneConfig<S>, res: &DamBreakResult) -> ColumnSummary<S> {
        ColumnSummary {
            result: res.clone(),
            config: cfg.clone(),
        }
    }

    fn tables(_cfg: &SceneConfig<S>, res: &DamBreakResult) -> Vec<Table> {
        vec![
            Table::pairs("front.csv", "T,Z", &res.front),
            Table::pairs("height.csv", "tau,H", &res.height),
        ]
    }

    #[cfg(feature = "cli")]
    fn write_plots(
        dir: &std::path::Path,
        cfg: &SceneConfig<S>,
        res: &DamBreakResult,
        sim: &Simulation<D, Walls<D>>,
    ) -> Result<(), crate::plot::PlotError> {
        write_plots::<D, S>(dir, cfg, res, sim)
    }
}

/// Writes `dam_break.png` (front and column height against Martin & Moyce) and `pressure.png`
/// (the water coloured by pressure at T ≈ 0, 1, 2 and at the end; 3D: the mid-plane slab).
#[cfg(feature = "cli")]
fn write_plots<const D: usize, S: ColumnScene<D>>(
    dir: &std::path::Path,
    cfg: &SceneConfig<S>,
    res: &DamBreakResult,
    sim: &Simulation<D, Walls<D>>,
) -> Result<(), crate::plot::PlotError> {
    use crate::plot::{line_charts, particle_panels, Chart, ParticleView, Series, Snapshot};
    let spec = cfg.scene.spec();
    let mm = crate::reference::martin_moyce();
    let dev = |d: Option<f64>| d.map_or("–".to_string(), |d| format!("{:.1} %", 100.0 * d));
    let chart = |title: String, x: &str, y: &str, sim: &[(f64, f64)], exp: &[(f64, f64)]| {
        let chart = Chart {
            title,
            x_label: x.into(),
            y_label: y.into(),
            ..Default::default()
        };
        let series = vec![
            Series::line("gpm", sim.to_vec()),
            Series::points("Martin & Moyce 1952", exp.to_vec()),
        ];
        (chart, series)
    };
    let front = format!(
        "surge front, n = {}: mean deviation {} (1 ≤ T ≤ 3)",
        res.n,
        dev(res.front_deviation)
    );
    let height = format!(
        "column height: mean deviation {} (τ ≤ 2)",
        dev(res.height_deviation)
    );
    let mut front_chart = chart(front, "T = t √(2g/a)", "Z = z/a", &res.front, &mm.front);
    if let (Some(lag), Some(d)) = (res.front_delay, res.front_delayed_deviation) {
        // the fitted start-up delay (a diagnostic: see `best_delay`), drawn beside the run
        let delayed = res.front.iter().map(|&(t, z)| (t + lag, z)).collect();
        let name = format!("gpm delayed by ΔT = {lag:.2} (fitted): {:.1} %", 100.0 * d);
        front_chart.1.insert(1, Series::line(name, delayed));
    }
    line_charts(
        &dir.join("dam_break.png"),
        1200,
        520,
        &[
            front_chart,
            chart(
                height,
                "τ = t √(g/a)",
                "H = η/(2a)",
                &res.height,
                &mm.height,
            ),
        ],
    )?;
    let mut shots = res.pressure.clone();
    let end = sim.time * (2.0 * spec.gravity).sqrt();
    if shots.last().is_none_or(|s| (s.0 - end).abs() > 1e-9) {
        shots.push(water_pressure(sim, res.depth.unwrap_or(0.0), end));
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
    view.include([0.0, 0.0], [spec.length, 2.0]);
    let plane = if D > 2 { ", mid-plane" } else { "" };
    let title = format!("{}, n = {}: pressure{plane}", S::TITLE, res.n);
    particle_panels(&dir.join("pressure.png"), &title, &shots, 2, 560, &view)
}

/// Runs a dam break to `t_end` through [`run_scene`].
pub fn run(cfg: &DamBreakConfig) -> Result<DamBreakResult, Error> {
    Ok(run_scene(cfg, |_| {}, |_, _| Ok(ControlFlow::Continue(())))?.result)
}
