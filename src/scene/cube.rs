//! The lid-driven cube: the unit cube, the lid `y = 1` moving with speed `U = 1` along `+x`,
//! no-slip on the five other walls (mirror ghosts, Neumann pressure), `z` spanwise,
//! `Re = U L / ν` — the square cavity ([`super::cavity`]) in three dimensions, built by the
//! same [`build_box`].
//!
//! Observed like the square: the centre-line profiles `u(0.5, y, 0.5)` and `v(x, 0.5, 0.5)`,
//! sampled and judged for steadiness by the cavity's [`SteadyCriterion`], averaged at the end,
//! and compared at Re 1000 with Albensoeder & Kuhlmann (2005)
//! ([`crate::reference::albensoeder_cube`]). The flow is mirror-symmetric about the mid-plane
//! `z = 0.5` (`u`, `v` even, `w` odd): the result carries the largest departure from it
//! ([`symmetry_error`]).

use super::cavity::{
    build_box, profile_errors, profile_tables, sample_positions, sample_profiles,
    validate_lid_and_steady, CavityResult, CentrelineSamples, SourceGhosts, SteadyCriterion,
};
use super::{FlowConfig, MonitorRanges, Scene, SceneConfig, SceneParams, Table};
use crate::boundary::Walls;
use crate::error::{Error, InputError};
use crate::flow::{FlowReport, Simulation};
use crate::reference::albensoeder_cube;
use crate::sampling::Sampler;
use serde::{Deserialize, Serialize};
use std::ops::ControlFlow;
use std::time::Instant;

/// The cube's own configuration keys (beside the shared [`FlowConfig`]; defaults Re 100,
/// n = 16, `t_end` = 30): the cavity's.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Cube {
    /// Steadiness and averaging.
    pub steady: SteadyCriterion,
    /// Lid speed.
    pub lid: f64,
    /// Continuation of the Poisson source into the wall ghosts.
    pub source_ghosts: SourceGhosts,
}

super::config_fields!(Cube {
    steady,
    lid,
    source_ghosts
});

/// Configuration of a cube run (one flat object; unknown keys are rejected).
pub type CubeConfig = SceneConfig<Cube>;

impl Default for Cube {
    fn default() -> Self {
        Cube {
            steady: SteadyCriterion::default(),
            lid: 1.0,
            source_ghosts: SourceGhosts::Auto,
        }
    }
}

impl SceneParams for Cube {
    const NAME: &'static str = "cube";
    const MIN_N: usize = 6;

    fn default_flow() -> FlowConfig {
        FlowConfig {
            n: 16,
            t_end: 30.0,
            ..FlowConfig::default()
        }
    }

    fn validate(&self, _flow: &FlowConfig) -> Result<(), InputError> {
        validate_lid_and_steady(self.lid, &self.steady)
    }
}

/// Builds the cube: an `n³` cell-centred lattice at rest, ghosts, neighbours, volumes.
pub fn build(cfg: &CubeConfig) -> Result<Simulation<3, Walls<3>>, Error> {
    cfg.validate()?;
    build_box(cfg, cfg.scene.lid, cfg.scene.source_ghosts)
}

/// Largest departure of the velocity from the mirror symmetry about `z = 0.5`, in units of
/// `|lid|`: `|u(p) − u(p')|`, `|v(p) − v(p')|`, `|w(p) + w(p')|` over the points `p` of a
/// `7 × 7 × 3` grid in the half `z < 0.5` (`x, y = k/8`, `z = 1/8, 1/4, 3/8`) and their
/// images `p'` (`z → 1 − z`), sampled as the profiles are.
pub fn symmetry_error(sim: &Simulation<3, Walls<3>>, lid: f64) -> f64 {
    let s = Sampler::new(&sim.particles.x, *sim.nl.kernel(), sim.nl.config().periodic);
    let mut p = Vec::new();
    for i in 1..8 {
        for j in 1..8 {
            for k in 1..4 {
                p.push([i as f64 / 8.0, j as f64 / 8.0, k as f64 / 8.0]);
            }
        }
    }
    let images: Vec<[f64; 3]> = p.iter().map(|q| [q[0], q[1], 1.0 - q[2]]).collect();
    let a = s.sample(&sim.particles.u, &p);
    let b = s.sample(&sim.particles.u, &images);
    a.iter()
        .zip(&b)
        .map(|(a, b)| {
            (a[0] - b[0])
                .abs()
                .max((a[1] - b[1]).abs())
                .max((a[2] + b[2]).abs())
        })
        .fold(0.0, f64::max)
        / lid.abs()
}

/// The outcome of a cube run: the centre-line profiles and their errors (as for the square;
/// `reference` holds the errors against Albensoeder & Kuhlmann, `ghia` is `None`), and the
/// symmetry about the mid-plane.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct CubeResult {
    /// Profiles, steadiness, errors, monitor ranges.
    #[serde(flatten)]
    pub profiles: CavityResult,
    /// [`symmetry_error`] at the end.
    pub symmetry: f64,
}

/// The cube's observables during a run.
pub struct CubeState {
    profiles: CentrelineSamples,
    res: CavityResult,
}

impl Scene<3> for Cube {
    type Boundary = Walls<3>;
    type State = CubeState;
    type Result = CubeResult;
    type Summary = CubeSummary;

    fn build(cfg: &CubeConfig) -> Result<Simulation<3, Walls<3>>, Error> {
        build(cfg)
    }

    fn start(cfg: &CubeConfig, _sim: &Simulation<3, Walls<3>>) -> CubeState {
        let (ys, xs) = sample_positions(albensoeder_cube(cfg.re.round() as u32).as_ref());
        CubeState {
            profiles: CentrelineSamples::new(ys, xs, &cfg.scene.steady),
            res: CavityResult {
                re: cfg.re,
                n: cfg.n,
                ..Default::default()
            },
        }
    }

    fn observe(
        s: &mut CubeState,
        cfg: &CubeConfig,
        rep: &FlowReport,
        sim: &Simulation<3, Walls<3>>,
    ) -> ControlFlow<()> {
        s.res.monitor.observe(rep);
        let sample = |ys: &[f64], xs: &[f64]| sample_profiles(sim, ys, xs);
        s.profiles
            .observe(&cfg.scene.steady, cfg.motion, sim.time, sample)
    }

    fn finish(
        s: CubeState,
        cfg: &CubeConfig,
        sim: &Simulation<3, Walls<3>>,
        started: Instant,
    ) -> CubeResult {
        let CubeState { profiles, mut res } = s;
        let sample = |ys: &[f64], xs: &[f64]| sample_profiles(sim, ys, xs);
        profiles.finish(&cfg.scene.steady, cfg.motion, sim.time, sample, &mut res);
        res.reference = albensoeder_cube(cfg.re.round() as u32)
            .map(|t| profile_errors(&t, &res.ys, &res.u, &res.xs, &res.v));
        res.particles = sim.particles.n_fluid();
        res.ghosts = sim.particles.len() - res.particles;
        res.steps = sim.steps;
        res.t_end = sim.time;
        let symmetry = symmetry_error(sim, cfg.scene.lid);
        res.wall_seconds = started.elapsed().as_secs_f64();
        CubeResult {
            profiles: res,
            symmetry,
        }
    }

    fn summary(cfg: &CubeConfig, res: &CubeResult) -> CubeSummary {
        CubeSummary::new(res, cfg)
    }

    /// `profile_u.csv` (`y,u` along x = z = 0.5) and `profile_v.csv` (`x,v` along
    /// y = z = 0.5).
    fn tables(_cfg: &CubeConfig, res: &CubeResult) -> Vec<Table> {
        profile_tables(&res.profiles)
    }

    #[cfg(feature = "cli")]
    fn write_plots(
        dir: &std::path::Path,
        _cfg: &CubeConfig,
        res: &CubeResult,
        sim: &Simulation<3, Walls<3>>,
    ) -> Result<(), crate::plot::PlotError> {
        write_plots(dir, res, sim)
    }
}

/// The flat summary written to `summary.json`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CubeSummary {
    /// Reynolds number.
    pub re: f64,
    /// Fluid particles per side.
    pub n: usize,
    /// Fluid particles (`n³`).
    pub particles: usize,
    /// Ghost particles at the end.
    pub ghosts: usize,
    /// Steps.
    pub steps: u64,
    /// Time reached.
    pub t_end: f64,
    /// Wall-clock seconds of the run.
    pub wall_seconds: f64,
    /// The reference the errors are measured against (`null`: none for this Re).
    pub reference: Option<String>,
    /// RMS of `u − u_ref` along x = z = 0.5 (lid-speed units, interior points).
    pub rms_u: Option<f64>,
    /// Max of `|u − u_ref|`.
    pub max_u: Option<f64>,
    /// RMS of `v − v_ref` along y = z = 0.5.
    pub rms_v: Option<f64>,
    /// Max of `|v − v_ref|`.
    pub max_v: Option<f64>,
    /// Largest departure from the mirror symmetry about z = 0.5 ([`symmetry_error`]).
    pub symmetry: f64,
    /// Steadiness reached.
    pub steady: bool,
    /// Time it was first reached.
    pub steady_time: Option<f64>,
    /// Last `max|Δprofile|/Δt`.
    pub steady_rate: f64,
    /// How steadiness was judged.
    pub steadiness: String,
    /// Ranges of the per-step monitor.
    #[serde(flatten)]
    pub monitor: MonitorRanges,
    /// The configuration of the run.
    pub config: CubeConfig,
}

impl CubeSummary {
    /// Flattens a result and its configuration.
    pub fn new(res: &CubeResult, cfg: &CubeConfig) -> Self {
        let r = &res.profiles;
        let e = r.reference;
        CubeSummary {
            re: r.re,
            n: r.n,
            particles: r.particles,
            ghosts: r.ghosts,
            steps: r.steps,
            t_end: r.t_end,
            wall_seconds: r.wall_seconds,
            reference: e.map(|_| "Albensoeder & Kuhlmann (2005), Tables 5 and 6".into()),
            rms_u: e.map(|g| g.rms_u),
            max_u: e.map(|g| g.max_u),
            rms_v: e.map(|g| g.rms_v),
            max_v: e.map(|g| g.max_v),
            symmetry: res.symmetry,
            steady: r.steady,
            steady_time: r.steady_time,
            steady_rate: r.steady_rate,
            steadiness: r.steady_rule.clone(),
            monitor: r.monitor.clone(),
            config: cfg.clone(),
        }
    }
}

/// Writes `profiles.png` (both centre-line profiles against Albensoeder & Kuhlmann at Re 1000,
/// with Ghia et al.'s square at the same Re for comparison) and `particles.png` (the fluid
/// particles of the mid-plane layers `|z − 0.5| < Δx`, coloured by speed) into `dir`.
#[cfg(feature = "cli")]
pub fn write_plots(
    dir: &std::path::Path,
    res: &CubeResult,
    sim: &Simulation<3, Walls<3>>,
) -> Result<(), crate::plot::PlotError> {
    use super::cavity::{write_profile_plot, ReferenceCurve};
    let r = &res.profiles;
    let re = r.re.round() as u32;
    let mut refs = Vec::new();
    if let Some(t) = albensoeder_cube(re) {
        refs.push(ReferenceCurve {
            label: "Albensoeder & Kuhlmann 2005 (cube)",
            table: t,
            points: true,
        });
    }
    if let Some(t) = crate::reference::ghia(re) {
        refs.push(ReferenceCurve {
            label: "Ghia et al. 1982 (square, 2D)",
            table: t,
            points: false,
        });
    }
    write_profile_plot(
        &dir.join("profiles.png"),
        r,
        ", z = 0.5",
        &refs,
        &[r.reference.map(|g| ("RMS A&K", g))],
    )?;
    let p = &sim.particles;
    let dx = 1.0 / r.n.max(1) as f64;
    let (xs, speed): (Vec<[f64; 2]>, Vec<f64>) = (0..p.len())
        .filter(|&i| p.role[i].is_fluid() && (p.x[i][2] - 0.5).abs() < dx)
        .map(|i| ([p.x[i][0], p.x[i][1]], crate::math::norm2(&p.u[i]).sqrt()))
        .unzip();
    crate::plot::particles(
        &dir.join("particles.png"),
        &format!(
            "Cube Re {} t = {:.1}: speed, mid-plane z = 0.5",
            r.re, r.t_end
        ),
        &xs,
        &speed,
        [0.0, 0.0],
        [1.0, 1.0],
        "|u| / U",
        800,
    )
}
