//! Plane Poiseuille flow: a channel of height `H = 1` between stationary no-slip walls at
//! `y = 0` and `y = 1`, periodic in `x` with period `L`, driven from rest by a uniform body
//! force `G` along `x`. The steady solution is
//!
//! `u(y) = G y (H − y) / (2ν)`, `v = 0`, `p` constant, centre speed `U_c = G H² / (8ν)`.
//!
//! The shared key `re` is the Reynolds number of the steady flow, `Re = U_c H / ν`, so
//! `ν = √(G H³ / (8 Re))`; the defaults (`re` = 12.5, `body_force` = 1) give `ν = 0.1` and
//! `U_c = 1.25`. The flow approaches steadiness as `e^{−π²νt/H²}` (time scale ≈ 1 at `ν = 0.1`),
//! so the default `t_end` = 20 is steady to round-off.
//!
//! The particles start on a cell-centred lattice (`n` across the channel, `round(L n)` along
//! it), optionally jittered by `jitter · Δx` (uniform in each coordinate, seeded): fixed jittered
//! particles are the disorder a moving-particle run produces, without the motion — the test of
//! whether the projection is consistent on disordered particles (a body force must be balanced
//! by viscous stress, not by a spurious pressure force).

use super::{run_scene, FlowConfig, MonitorRanges, Scene, SceneConfig, SceneParams, Table};
use crate::boundary::Walls;
use crate::error::{Error, InputError};
use crate::flow::{FlowReport, Simulation};
use crate::geometry::{jitter, lattice};
use crate::particles::{Particles, Role};
use serde::{Deserialize, Serialize};
use std::ops::ControlFlow;
use std::time::Instant;

/// The channel's own configuration keys (beside the shared [`FlowConfig`]).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Channel {
    /// Body force per unit mass `G` along `x` (default 1).
    pub body_force: f64,
    /// Length `L` of the periodic direction over the channel height (default 1).
    pub length: f64,
    /// Jitter of the initial positions as a fraction of `Δx` (each coordinate uniform in
    /// `[−jitter Δx, jitter Δx]`; default 0, at most 0.45 so that no particle leaves its cell).
    pub jitter: f64,
    /// Seed of the jitter (ChaCha8; default 7).
    pub seed: u64,
}

super::config_fields!(Channel {
    body_force,
    length,
    jitter,
    seed
});

impl Default for Channel {
    fn default() -> Self {
        Channel {
            body_force: 1.0,
            length: 1.0,
            jitter: 0.0,
            seed: 7,
        }
    }
}

/// Configuration of a channel run (one flat object; unknown keys are rejected).
pub type ChannelConfig = SceneConfig<Channel>;

impl SceneParams for Channel {
    const NAME: &'static str = "channel";
    const MIN_N: usize = 6;

    fn default_flow() -> FlowConfig {
        FlowConfig {
            re: 12.5,
            n: 32,
            t_end: 20.0,
            ..FlowConfig::default()
        }
    }

    fn validate(&self, _flow: &FlowConfig) -> Result<(), InputError> {
        if !(self.body_force.is_finite() && self.body_force > 0.0) {
            return Err(InputError::parameter(
                "body_force",
                self.body_force,
                "the body force must be positive and finite",
            ));
        }
        if !(self.length.is_finite() && (0.25..=64.0).contains(&self.length)) {
            return Err(InputError::parameter(
                "length",
                self.length,
                "the channel length over its height must be in [0.25, 64]",
            ));
        }
        if !(0.0..=0.45).contains(&self.jitter) {
            return Err(InputError::parameter(
                "jitter",
                self.jitter,
                "the jitter must be in [0, 0.45] particle spacings",
            ));
        }
        Ok(())
    }
}

impl Channel {
    /// Kinematic viscosity `ν = √(G H³ / (8 Re))` (H = 1).
    pub fn nu(&self, re: f64) -> f64 {
        (self.body_force / (8.0 * re)).sqrt()
    }

    /// Steady centre speed `U_c = G H² / (8ν)`.
    pub fn centre_speed(&self, re: f64) -> f64 {
        self.body_force / (8.0 * self.nu(re))
    }

    /// The steady velocity `u(y) = G y (1 − y) / (2ν)`.
    pub fn exact(&self, re: f64, y: f64) -> f64 {
        self.body_force * y * (1.0 - y) / (2.0 * self.nu(re))
    }
}

/// Builds the simulation: the (jittered) lattice at rest, the channel walls, the body force.
pub fn build(cfg: &ChannelConfig) -> Result<Simulation<2, Walls<2>>, Error> {
    cfg.validate()?;
    let dx = cfg.dx();
    let len = (cfg.scene.length * cfg.n as f64).round().max(1.0) * dx;
    let mut x: Vec<[f64; 2]> = lattice([0.0, 0.0], [len, 1.0], dx);
    jitter(&mut x, cfg.scene.jitter * dx, cfg.scene.seed);
    let mut p = Particles::<2>::new();
    for x in x {
        p.push(x, [0.0, 0.0], 0.0, dx * dx, Role::Fluid);
    }
    let walls = Walls::channel([0.0, 0.0], [len, 1.0]);
    let uc = cfg.scene.centre_speed(cfg.re);
    let mut params = cfg.flow_params(uc);
    if cfg.operators.consistent(cfg.scene.jitter > 0.0) {
        // disordered fixed particles
        params.projection = params.projection.with_consistent_operators();
    }
    params.projection.gravity = [cfg.scene.body_force, 0.0];
    Simulation::new(p, walls, cfg.neighbor_config(), params)
}

/// The errors of the velocity field against the steady solution, in units of `U_c`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ChannelErrors {
    /// `max_i |u_i − u_exact(y_i)| / U_c` over the fluid particles.
    pub max_rel_error: f64,
    /// RMS of `(u_i − u_exact(y_i)) / U_c` over the fluid particles.
    pub rms_rel_error: f64,
    /// `max_i |v_i| / U_c`.
    pub max_rel_v: f64,
    /// Mean `u` of the fluid particles within `Δx` of the centre line, over `U_c`.
    pub centre_speed_ratio: f64,
}

/// Errors of the current state against the steady solution.
pub fn errors(sim: &Simulation<2, Walls<2>>, cfg: &ChannelConfig) -> ChannelErrors {
    let p = &sim.particles;
    let uc = cfg.scene.centre_speed(cfg.re);
    let (mut emax, mut e2, mut vmax, mut k) = (0.0f64, 0.0, 0.0f64, 0usize);
    let (mut centre, mut kc) = (0.0, 0usize);
    for i in 0..p.len() {
        if !p.role[i].is_fluid() {
            continue;
        }
        let e = (p.u[i][0] - cfg.scene.exact(cfg.re, p.x[i][1])) / uc;
        emax = emax.max(e.abs());
        e2 += e * e;
        vmax = vmax.max(p.u[i][1].abs() / uc);
        k += 1;
        if (p.x[i][1] - 0.5).abs() < cfg.dx() {
            centre += p.u[i][0] / uc;
            kc += 1;
        }
    }
    ChannelErrors {
        max_rel_error: emax,
        rms_rel_error: (e2 / k.max(1) as f64).sqrt(),
        max_rel_v: vmax,
        centre_speed_ratio: centre / kc.max(1) as f64,
    }
}

/// The outcome of a channel run.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ChannelResult {
    /// Body force.
    pub g: f64,
    /// Kinematic viscosity.
    pub nu: f64,
    /// Steady centre speed `G/(8ν)`.
    pub u_centre_exact: f64,
    /// Particles across the channel.
    pub n: usize,
    /// Fluid particles.
    pub particles: usize,
    /// Jitter (fraction of Δx).
    pub jitter: f64,
    /// Steps.
    pub steps: u64,
    /// Final time.
    pub t_end: f64,
    /// Wall seconds.
    pub wall_seconds: f64,
    /// Errors at the final time.
    pub errors: ChannelErrors,
    /// Ranges of the per-step monitor.
    pub monitor: MonitorRanges,
    /// `(y, u)` of every fluid particle at the end, sorted by `y`.
    pub profile: Vec<(f64, f64)>,
}

/// The flat summary written to `summary.json`.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ChannelSummary {
    /// Body force `G`.
    #[serde(rename = "G")]
    pub g: f64,
    /// Kinematic viscosity `ν`.
    pub nu: f64,
    /// Reynolds number `U_c H / ν`.
    pub re: f64,
    /// Steady centre speed `U_c = G/(8ν)`.
    pub u_max: f64,
    /// Particles across the channel.
    pub n: usize,
    /// Fluid particles.
    pub particles: usize,
    /// Jitter of the initial positions (fraction of Δx).
    pub jitter: f64,
    /// Steps.
    pub steps: u64,
    /// Final time.
    pub t_end: f64,
    /// Wall seconds of the run.
    pub wall_seconds: f64,
    /// `max |u − u_exact| / U_c` over the fluid particles.
    pub max_rel_error: f64,
    /// RMS of `(u − u_exact) / U_c`.
    pub rms_rel_error: f64,
    /// `max |v| / U_c`.
    pub max_rel_v: f64,
    /// Mean `u / U_c` within `Δx` of the centre line (1 when right; 0 when the flow stalls).
    pub centre_speed_ratio: f64,
    /// Ranges of the per-step monitor (c0, connectivity, spacing, stability ratio, …).
    #[serde(flatten)]
    pub monitor: MonitorRanges,
    /// The configuration of the run.
    pub config: ChannelConfig,
}

impl Scene<2> for Channel {
    type Boundary = Walls<2>;
    type State = ChannelResult;
    type Result = ChannelResult;
    type Summary = ChannelSummary;
    const LAND_ON_T_END: bool = true;

    fn build(cfg: &ChannelConfig) -> Result<Simulation<2, Walls<2>>, Error> {
        build(cfg)
    }

    fn start(cfg: &ChannelConfig, sim: &Simulation<2, Walls<2>>) -> ChannelResult {
        ChannelResult {
            g: cfg.scene.body_force,
            nu: cfg.scene.nu(cfg.re),
            u_centre_exact: cfg.scene.centre_speed(cfg.re),
            n: cfg.n,
            particles: sim.particles.role.iter().filter(|r| r.is_fluid()).count(),
            jitter: cfg.scene.jitter,
            monitor: MonitorRanges::new(),
            ..Default::default()
        }
    }

    fn observe(
        res: &mut ChannelResult,
        _cfg: &ChannelConfig,
        rep: &FlowReport,
        _sim: &Simulation<2, Walls<2>>,
    ) -> ControlFlow<()> {
        res.monitor.observe(rep);
        ControlFlow::Continue(())
    }

    fn finish(
        mut res: ChannelResult,
        cfg: &ChannelConfig,
        sim: &Simulation<2, Walls<2>>,
        started: Instant,
    ) -> ChannelResult {
        res.steps = sim.steps;
        res.t_end = sim.time;
        res.errors = errors(sim, cfg);
        let p = &sim.particles;
        res.profile = (0..p.len())
            .filter(|&i| p.role[i].is_fluid())
            .map(|i| (p.x[i][1], p.u[i][0]))
            .collect();
        res.profile.sort_by(|a, b| a.0.total_cmp(&b.0));
        res.wall_seconds = started.elapsed().as_secs_f64();
        res
    }

    fn summary(cfg: &ChannelConfig, res: &ChannelResult) -> ChannelSummary {
        ChannelSummary {
            g: res.g,
            nu: res.nu,
            re: cfg.re,
            u_max: res.u_centre_exact,
            n: res.n,
            particles: res.particles,
            jitter: res.jitter,
            steps: res.steps,
            t_end: res.t_end,
            wall_seconds: res.wall_seconds,
            max_rel_error: res.errors.max_rel_error,
            rms_rel_error: res.errors.rms_rel_error,
            max_rel_v: res.errors.max_rel_v,
            centre_speed_ratio: res.errors.centre_speed_ratio,
            monitor: res.monitor.clone(),
            config: cfg.clone(),
        }
    }

    fn tables(_cfg: &ChannelConfig, res: &ChannelResult) -> Vec<Table> {
        use std::fmt::Write;
        let mut t = String::from("y,u\n");
        for (y, u) in &res.profile {
            let _ = writeln!(t, "{y:.8},{u:.10}");
        }
        vec![Table {
            name: "profile.csv".into(),
            text: t,
        }]
    }

    #[cfg(feature = "cli")]
    fn write_plots(
        dir: &std::path::Path,
        cfg: &ChannelConfig,
        res: &ChannelResult,
        _sim: &Simulation<2, Walls<2>>,
    ) -> Result<(), crate::plot::PlotError> {
        use crate::plot::{line_charts, Chart, Series};
        let exact: Vec<(f64, f64)> = (0..=100)
            .map(|k| {
                let y = k as f64 / 100.0;
                (cfg.scene.exact(cfg.re, y), y)
            })
            .collect();
        line_charts(
            &dir.join("profile.png"),
            800,
            650,
            &[(
                Chart {
                    title: format!(
                        "channel n {} jitter {} Δx: max error {:.2e} U_c",
                        res.n, res.jitter, res.errors.max_rel_error
                    ),
                    x_label: "u".into(),
                    y_label: "y".into(),
                    ..Default::default()
                },
                vec![
                    Series::points("gpm (every particle)", {
                        res.profile.iter().map(|(y, u)| (*u, *y)).collect()
                    }),
                    Series::line("G y (1 − y) / 2ν", exact),
                ],
            )],
        )
    }
}

/// Runs a channel to `t_end` through [`run_scene`].
pub fn run(cfg: &ChannelConfig) -> Result<ChannelResult, Error> {
    Ok(run_scene(cfg, |_| {}, |_, _| Ok(ControlFlow::Continue(())))?.result)
}
