//! The Taylor–Green vortex on the periodic unit square (MISSION §5), an exact Navier–Stokes
//! solution:
//!
//! `u = −U e^{−8π²t/Re} cos 2πx sin 2πy`, `v = U e^{−8π²t/Re} sin 2πx cos 2πy`,
//! `p = −ρU² e^{−16π²t/Re} (cos 4πx + cos 4πy)/4`.

use super::{run_scene, FlowConfig, MonitorRanges, Scene, SceneConfig, SceneParams};
use crate::boundary::PeriodicBox;
use crate::error::{Error, InputError};
use crate::flow::{FlowReport, Simulation};
use crate::geometry::{jitter, lattice};
use crate::neighbors::Periodicity;
use crate::particles::{Particles, Role};
use serde::{Deserialize, Serialize};
use std::f64::consts::PI;
use std::ops::ControlFlow;
use std::time::Instant;

/// The Taylor–Green vortex's own configuration key (beside the shared [`FlowConfig`];
/// defaults Re 100, n = 50, `t_end` = 2).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TaylorGreen {
    /// Velocity amplitude `U`.
    pub amplitude: f64,
    /// Initial displacement of each particle from its lattice site, uniform in
    /// `[−jitter Δx, jitter Δx]` per coordinate (at most 0.45). Default (`null`):
    /// [`LAGRANGIAN_JITTER`] for Lagrangian runs, 0 for Eulerian ones. The lattice is
    /// symmetric about the vortex's stagnation points, so without it a Lagrangian run deforms
    /// the rows there symmetrically (they close up along the compressive axis and open along
    /// the stretching one) and no shifting law that is itself symmetric can undo that: the
    /// pair repulsion cancels on every particle of a symmetrically compressed row.
    pub jitter: Option<f64>,
    /// Seed of the jitter (ChaCha8; default 7).
    pub seed: u64,
}

super::config_fields!(TaylorGreen {
    amplitude,
    jitter,
    seed
});

impl Default for TaylorGreen {
    fn default() -> Self {
        TaylorGreen {
            amplitude: 1.0,
            jitter: None,
            seed: 7,
        }
    }
}

/// The initial jitter of a Lagrangian run when none is given, in particle spacings.
pub const LAGRANGIAN_JITTER: f64 = 0.05;

impl TaylorGreen {
    /// The jitter a run in `motion` uses: the given one, or [`LAGRANGIAN_JITTER`] for
    /// Lagrangian runs and 0 for Eulerian ones.
    pub fn jitter_for(&self, motion: crate::flow::Motion) -> f64 {
        self.jitter.unwrap_or(match motion {
            crate::flow::Motion::Lagrangian => LAGRANGIAN_JITTER,
            crate::flow::Motion::Eulerian => 0.0,
        })
    }
}

/// Configuration of a Taylor–Green run (one flat object; unknown keys are rejected).
pub type TaylorGreenConfig = SceneConfig<TaylorGreen>;

impl SceneParams for TaylorGreen {
    const NAME: &'static str = "taylor_green";
    const MIN_N: usize = 8;

    fn default_flow() -> FlowConfig {
        FlowConfig {
            t_end: 2.0,
            ..FlowConfig::default()
        }
    }

    fn validate(&self, _flow: &FlowConfig) -> Result<(), InputError> {
        if !(self.amplitude.is_finite() && self.amplitude != 0.0) {
            return Err(InputError::Parameter {
                name: "amplitude".into(),
                value: self.amplitude,
                reason: "must be finite and non-zero".into(),
            });
        }
        if let Some(j) = self.jitter.filter(|j| !(0.0..=0.45).contains(j)) {
            return Err(InputError::parameter(
                "jitter",
                j,
                "the jitter must be in [0, 0.45] particle spacings",
            ));
        }
        Ok(())
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

/// Builds the simulation at `t = 0` with the exact fields.
pub fn build(cfg: &TaylorGreenConfig) -> Result<Simulation<2, PeriodicBox<2>>, Error> {
    cfg.validate()?;
    let dx = 1.0 / cfg.n as f64;
    let amplitude = cfg.scene.amplitude;
    let mut p = Particles::<2>::new();
    let mut xs = lattice([0.0, 0.0], [1.0, 1.0], dx);
    jitter(
        &mut xs,
        cfg.scene.jitter_for(cfg.motion) * dx,
        cfg.scene.seed,
    );
    for x in xs {
        let (u, pr) = exact(cfg.re, amplitude, &x, 0.0);
        p.push(x, u, pr, dx * dx, Role::Fluid);
    }
    let bc = PeriodicBox {
        periodic: Periodicity::all([0.0, 0.0], [1.0, 1.0]),
    };
    Simulation::new(p, bc, cfg.neighbor_config(), cfg.flow_params(amplitude))
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

/// The outcome of a Taylor–Green run.
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
    /// Ranges of the per-step monitor.
    pub monitor: MonitorRanges,
}

/// Runs to `t_end` (the last step is shortened to land on it) through [`run_scene`];
/// `observer` sees every step and cannot stop the run (use [`run_scene`] for that).
pub fn run(
    cfg: &TaylorGreenConfig,
    mut observer: impl FnMut(&FlowReport, &Simulation<2, PeriodicBox<2>>) -> Result<(), Error>,
) -> Result<TaylorGreenResult, Error> {
    let run = run_scene(
        cfg,
        |_| {},
        |rep, sim| {
            observer(rep, sim)?;
            Ok(ControlFlow::Continue(()))
        },
    )?;
    Ok(run.result)
}

/// The flat summary written to `summary.json`.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct TaylorGreenSummary {
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
    /// `Σ|u − u_ex| / Σ|u_ex|`.
    pub l1_velocity_error: f64,
    /// Relative error of the maximum speed against `U e^{−8π²t/Re}`.
    pub linf_decay_error: f64,
    /// Mean-free relative L1 pressure error.
    pub l1_pressure_error: f64,
    /// Ranges of the per-step monitor (`c0_min`, `c0_max`, `min_spacing`,
    /// `max_stability_ratio`, …).
    #[serde(flatten)]
    pub monitor: MonitorRanges,
    /// The configuration of the run.
    pub config: TaylorGreenConfig,
}

impl Scene<2> for TaylorGreen {
    type Boundary = PeriodicBox<2>;
    type State = TaylorGreenResult;
    type Result = TaylorGreenResult;
    type Summary = TaylorGreenSummary;
    const LAND_ON_T_END: bool = true;

    fn build(cfg: &TaylorGreenConfig) -> Result<Simulation<2, PeriodicBox<2>>, Error> {
        build(cfg)
    }

    fn start(cfg: &TaylorGreenConfig, _sim: &Simulation<2, PeriodicBox<2>>) -> TaylorGreenResult {
        TaylorGreenResult {
            re: cfg.re,
            n: cfg.n,
            ..Default::default()
        }
    }

    fn observe(
        res: &mut TaylorGreenResult,
        _cfg: &TaylorGreenConfig,
        rep: &FlowReport,
        _sim: &Simulation<2, PeriodicBox<2>>,
    ) -> ControlFlow<()> {
        res.monitor.observe(rep);
        ControlFlow::Continue(())
    }

    fn finish(
        mut res: TaylorGreenResult,
        cfg: &TaylorGreenConfig,
        sim: &Simulation<2, PeriodicBox<2>>,
        started: Instant,
    ) -> TaylorGreenResult {
        res.steps = sim.steps;
        res.t_end = sim.time;
        res.errors = errors(sim, cfg.re, cfg.scene.amplitude);
        res.wall_seconds = started.elapsed().as_secs_f64();
        res
    }

    fn summary(cfg: &TaylorGreenConfig, res: &TaylorGreenResult) -> TaylorGreenSummary {
        TaylorGreenSummary {
            re: res.re,
            n: res.n,
            steps: res.steps,
            t_end: res.t_end,
            wall_seconds: res.wall_seconds,
            l1_velocity_error: res.errors.l1_velocity_error,
            linf_decay_error: res.errors.linf_decay_error,
            l1_pressure_error: res.errors.l1_pressure_error,
            monitor: res.monitor.clone(),
            config: cfg.clone(),
        }
    }
}
