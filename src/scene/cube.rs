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
    build_box, profile_errors, profile_tables, validate_lid_and_steady, BoxSummary, CavityResult,
    CavityState, SourceGhosts, SteadyCriterion, SOURCE_BAND,
};
use super::{FlowConfig, Scene, SceneConfig, SceneParams, Table};
use crate::boundary::Walls;
use crate::error::{Error, InputError};
use crate::flow::{FlowReport, Simulation};
use crate::reference::{albensoeder_cube, table_key};
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
    /// Width of the lid's corner ramp ([`crate::boundary::Wall::ramp`]), in side lengths:
    /// the lid's speed falls smoothly to zero within `lid_ramp` of the walls that meet it
    /// (`0`, the default: the classic cavity, a speed discontinuous at the lid corners;
    /// `0.5`: a regularised lid, zero only at the corners).
    pub lid_ramp: f64,
    /// Continuation of the Poisson source into the wall ghosts.
    pub source_ghosts: SourceGhosts,
    /// Width, in side lengths, of the band next to the lid within which the `rest_walls`
    /// source continuation blends the walls at rest's no-slip images into the mirror
    /// ([`crate::boundary::Wall::source_band`]; default ¼; `0`: none — a first-order mass
    /// source at the lid corners).
    pub source_band: f64,
}

super::config_fields!(Cube {
    steady,
    lid,
    lid_ramp,
    source_ghosts,
    source_band
});

/// Configuration of a cube run (one flat object; unknown keys are rejected).
pub type CubeConfig = SceneConfig<Cube>;

impl Default for Cube {
    fn default() -> Self {
        Cube {
            steady: SteadyCriterion::default(),
            lid: 1.0,
            lid_ramp: 0.0,
            source_ghosts: SourceGhosts::Auto,
            source_band: SOURCE_BAND,
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
            laplacian: Some(super::cavity::WALL_LAPLACIAN),
            shifting: Some(super::cavity::wall_shifting()),
            ..FlowConfig::default()
        }
    }

    fn validate(&self, flow: &FlowConfig) -> Result<(), InputError> {
        validate_lid_and_steady(self.lid, self.lid_ramp, self.source_band, &self.steady)?;
        super::cavity::validate_source_ghosts(self.source_ghosts, flow)
    }
}

/// Builds the cube: an `n³` cell-centred lattice at rest, ghosts, neighbours, volumes.
pub fn build(cfg: &CubeConfig) -> Result<Simulation<3, Walls<3>>, Error> {
    cfg.validate()?;
    build_box(
        cfg,
        cfg.scene.lid,
        cfg.scene.lid_ramp,
        cfg.scene.source_ghosts,
        cfg.scene.source_band,
    )
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

impl Scene<3> for Cube {
    type Boundary = Walls<3>;
    type State = CavityState;
    type Result = CubeResult;
    type Summary = CubeSummary;

    fn build(cfg: &CubeConfig) -> Result<Simulation<3, Walls<3>>, Error> {
        build(cfg)
    }

    fn start(cfg: &CubeConfig, _sim: &Simulation<3, Walls<3>>) -> CavityState {
        let table = table_key(cfg.re).and_then(albensoeder_cube);
        CavityState::new(cfg, &cfg.scene.steady, table.as_ref())
    }

    fn observe(
        s: &mut CavityState,
        cfg: &CubeConfig,
        rep: &FlowReport,
        sim: &Simulation<3, Walls<3>>,
    ) -> ControlFlow<()> {
        s.observe(cfg, &cfg.scene.steady, rep, sim)
    }

    fn finish(
        s: CavityState,
        cfg: &CubeConfig,
        sim: &Simulation<3, Walls<3>>,
        started: Instant,
    ) -> CubeResult {
        let symmetry = symmetry_error(sim, cfg.scene.lid);
        let mut res = s.finish(cfg, &cfg.scene.steady, sim, started);
        res.reference = table_key(cfg.re)
            .and_then(albensoeder_cube)
            .map(|t| profile_errors(&t, &res.ys, &res.u, &res.xs, &res.v));
        CubeResult {
            profiles: res,
            symmetry,
        }
    }

    fn summary(cfg: &CubeConfig, res: &CubeResult) -> CubeSummary {
        BoxSummary {
            symmetry: Some(res.symmetry),
            ..BoxSummary::new(&res.profiles, cfg)
        }
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

/// The cube's `summary.json`: the cavity's layout ([`BoxSummary`]), the errors against
/// Albensoeder & Kuhlmann in `rms_u_ref`, `max_u_ref`, `rms_v_ref`, `max_v_ref` (`null` without a
/// reference for this Re; Ghia's `rms_u` … are `null`), and `symmetry`.
pub type CubeSummary = BoxSummary<Cube>;

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
    let re = table_key(r.re);
    let mut refs = Vec::new();
    if let Some(t) = re.and_then(albensoeder_cube) {
        refs.push(ReferenceCurve {
            label: "Albensoeder & Kuhlmann 2005 (cube)",
            table: t,
            points: true,
        });
    }
    if let Some(t) = re.and_then(crate::reference::ghia) {
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
