//! The lid-driven cavity: unit square, lid `y = 1` moving with speed `U = 1` along `+x`,
//! `Re = U L / ν`, no-slip walls by mirror ghosts (Neumann pressure), compared with
//! Ghia, Ghia & Shin (1982) along the centre lines.
//!
//! **Steadiness.** Every `steady.interval` time units the centre-line profiles are sampled (MLS,
//! see [`crate::sampling`]); the flow is judged steady when the largest change of any profile
//! value between two samples, divided by the interval, is below `steady.tol` (in units of
//! `U² / L`). The reported profiles are the mean of the samples taken over the last
//! `steady.average_window` time units (Lagrangian particles sample a steady field with noise).

use crate::boundary::Walls;
use crate::consistent::GradientKind;
use crate::error::{Error, InputError};
use crate::flow::{
    FlowParams, FlowReport, Integrator, Motion, Shifting, Simulation, TimeStepLimits, VolumeRule,
};
use crate::geometry::lattice;
use crate::kernel::Weight;
use crate::neighbors::NeighborConfig;
use crate::particles::{Particles, Role};
use crate::poisson::SolveParams;
use crate::projection::{ProjectionParams, Scheme};
use crate::reference::{ghia, rms_max};
use crate::sampling::Sampler;
use serde::{Deserialize, Serialize};
use std::time::Instant;

/// How steadiness is judged and profiles averaged.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SteadyCriterion {
    /// Time between profile samples (default 0.5).
    pub interval: f64,
    /// Steady when `max |Δprofile| / interval < tol` (default 1e-3).
    pub tol: f64,
    /// Average the samples of the last `average_window` time units (default 2).
    pub average_window: f64,
    /// Stop `average_window` after steadiness is first reached (default true).
    pub stop_when_steady: bool,
}

impl Default for SteadyCriterion {
    fn default() -> Self {
        SteadyCriterion {
            interval: 0.5,
            tol: 1e-3,
            average_window: 2.0,
            stop_when_steady: true,
        }
    }
}

/// Configuration of a cavity run (serialisable; unknown keys are rejected).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CavityConfig {
    /// Reynolds number `U L / ν`.
    pub re: f64,
    /// Fluid particles per side.
    pub n: usize,
    /// End time (the run may stop earlier when steady).
    pub t_end: f64,
    /// Influence radius over particle spacing.
    pub h_over_dx: f64,
    /// Neighbour skin over `h`.
    pub skin_over_h: f64,
    /// Reference weight.
    pub weight: Weight,
    /// Pressure-correction scheme.
    pub scheme: Scheme,
    /// Gradient of the predictor and the correction (difference `∇h` or renormalised `B∇h`).
    pub gradient: GradientKind,
    /// Frame of the particles.
    pub motion: Motion,
    /// Integrator of the explicit terms.
    pub integrator: Integrator,
    /// Implicit weight of the viscous term (½ = Crank–Nicolson, 0 = explicit).
    pub viscous_theta: f64,
    /// Particle shifting (Lagrangian).
    pub shifting: Option<Shifting>,
    /// Volumes.
    pub volumes: VolumeRule,
    /// Time-step limits.
    pub limits: TimeStepLimits,
    /// Linear solver.
    pub solve: SolveParams,
    /// Steadiness and averaging.
    pub steady: SteadyCriterion,
    /// Lid speed.
    pub lid: f64,
    /// Continuation of the Poisson source into the wall ghosts.
    pub source_ghosts: SourceGhosts,
}

/// Serialisable choice of [`crate::boundary::VectorKind`] for the Poisson source.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum SourceGhosts {
    /// Normal component flipped, tangential kept: exact adjointness, Theorem 4.5 applies.
    #[default]
    Mirror,
    /// The no-slip velocity images (wall velocity enters the source).
    NoSlip,
}

impl std::str::FromStr for SourceGhosts {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s.trim().to_ascii_lowercase().replace('-', "_").as_str() {
            "mirror" => Ok(SourceGhosts::Mirror),
            "no_slip" | "noslip" => Ok(SourceGhosts::NoSlip),
            _ => Err(format!(
                "unknown source ghost rule '{s}': expected mirror or no-slip"
            )),
        }
    }
}

impl From<SourceGhosts> for crate::boundary::VectorKind {
    fn from(s: SourceGhosts) -> Self {
        match s {
            SourceGhosts::Mirror => crate::boundary::VectorKind::Mirror,
            SourceGhosts::NoSlip => crate::boundary::VectorKind::Velocity,
        }
    }
}

impl Default for CavityConfig {
    fn default() -> Self {
        CavityConfig {
            re: 100.0,
            n: 50,
            t_end: 40.0,
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
            steady: SteadyCriterion::default(),
            lid: 1.0,
            source_ghosts: SourceGhosts::Mirror,
        }
    }
}

impl CavityConfig {
    /// Checks every parameter and names the first bad one.
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
        if self.n < 4 || self.n > 20_000 {
            return bad(
                "n",
                self.n as f64,
                "particles per side must be in 4..=20000",
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
            return bad(
                "h_over_dx",
                self.h_over_dx,
                "h must exceed the particle spacing (h/dx > 1) and h/dx ≤ 8",
            );
        }
        if !(self.skin_over_h >= 0.0 && self.skin_over_h <= 2.0) {
            return bad(
                "skin_over_h",
                self.skin_over_h,
                "the skin must be in [0, 2] h",
            );
        }
        if !(self.lid.is_finite() && self.lid != 0.0) {
            return bad("lid", self.lid, "the lid speed must be finite and non-zero");
        }
        if let Err(reason) = self.weight.validate() {
            return bad("weight", f64::NAN, &reason);
        }
        let s = &self.steady;
        if !(s.interval > 0.0 && s.interval.is_finite()) {
            return bad("steady.interval", s.interval, "must be positive and finite");
        }
        if s.tol.is_nan() || s.tol <= 0.0 {
            return bad("steady.tol", s.tol, "must be positive");
        }
        if !(s.average_window >= 0.0 && s.average_window.is_finite()) {
            return bad(
                "steady.average_window",
                s.average_window,
                "must be non-negative and finite",
            );
        }
        if !(0.0..=1.0).contains(&self.viscous_theta) {
            return bad("viscous_theta", self.viscous_theta, "must be in [0, 1]");
        }
        self.limits.validate()?;
        super::validate_common(&self.solve, self.shifting.as_ref())
    }

    /// Particle spacing `1/n`.
    pub fn dx(&self) -> f64 {
        1.0 / self.n as f64
    }
}

/// Builds the simulation: an `n × n` cell-centred lattice at rest, ghosts, neighbours, volumes.
pub fn build(cfg: &CavityConfig) -> Result<Simulation<2, Walls<2>>, Error> {
    cfg.validate()?;
    let dx = cfg.dx();
    let mut p = Particles::<2>::new();
    for x in lattice([0.0, 0.0], [1.0, 1.0], dx) {
        p.push(x, [0.0, 0.0], 0.0, dx * dx, Role::Fluid);
    }
    let walls = Walls::cavity(1.0, cfg.lid);
    let nc = NeighborConfig::new_relative(cfg.weight, dx, cfg.h_over_dx, cfg.skin_over_h);
    let mut projection = ProjectionParams::new(cfg.lid.abs() / cfg.re);
    projection.scheme = cfg.scheme;
    projection.gradient = cfg.gradient;
    projection.viscous_theta = cfg.viscous_theta;
    projection.source_ghosts = cfg.source_ghosts.into();
    projection.solve = cfg.solve;
    projection.allowed_floating = 1;
    let mut limits = cfg.limits;
    limits.u_ref = limits.u_ref.max(cfg.lid.abs());
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
    Simulation::new(p, walls, nc, params)
}

/// Sample positions along the centre lines: 101 evenly spaced points plus Ghia's.
pub fn sample_positions(re: u32) -> (Vec<f64>, Vec<f64>) {
    let mut ys: Vec<f64> = (0..=100).map(|k| k as f64 / 100.0).collect();
    let mut xs = ys.clone();
    if let Some(t) = ghia(re) {
        ys.extend(t.u_vertical.iter().map(|p| p.0));
        xs.extend(t.v_horizontal.iter().map(|p| p.0));
    }
    for v in [&mut ys, &mut xs] {
        v.sort_by(|a, b| a.partial_cmp(b).unwrap());
        v.dedup_by(|a, b| (*a - *b).abs() < 1e-12);
    }
    (ys, xs)
}

/// `u(0.5, y)` at `ys` and `v(x, 0.5)` at `xs` from the current particles (ghosts included).
pub fn sample_profiles(
    sim: &Simulation<2, Walls<2>>,
    ys: &[f64],
    xs: &[f64],
) -> (Vec<f64>, Vec<f64>) {
    let s = Sampler::new(&sim.particles.x, *sim.nl.kernel(), sim.nl.config().periodic);
    let pu: Vec<[f64; 2]> = ys.iter().map(|&y| [0.5, y]).collect();
    let pv: Vec<[f64; 2]> = xs.iter().map(|&x| [x, 0.5]).collect();
    let u = s
        .sample(&sim.particles.u, &pu)
        .iter()
        .map(|v| v[0])
        .collect();
    let v = s
        .sample(&sim.particles.u, &pv)
        .iter()
        .map(|v| v[1])
        .collect();
    (u, v)
}

/// Errors against Ghia et al. in units of the lid speed (interior points only).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct GhiaErrors {
    /// RMS of `u − u_Ghia` along `x = 0.5`.
    pub rms_u: f64,
    /// Max of `|u − u_Ghia|`.
    pub max_u: f64,
    /// RMS of `v − v_Ghia` along `y = 0.5`.
    pub rms_v: f64,
    /// Max of `|v − v_Ghia|`.
    pub max_v: f64,
}

/// The outcome of [`run`].
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct CavityResult {
    /// Reynolds number.
    pub re: f64,
    /// Fluid particles per side.
    pub n: usize,
    /// Fluid particles.
    pub particles: usize,
    /// Ghost particles at the end.
    pub ghosts: usize,
    /// Steps taken.
    pub steps: u64,
    /// Time reached.
    pub t_end: f64,
    /// Wall-clock seconds of the whole run.
    pub wall_seconds: f64,
    /// Steadiness reached.
    pub steady: bool,
    /// Time at which it was first reached.
    pub steady_time: Option<f64>,
    /// Last measured `max |Δprofile| / interval`.
    pub steady_rate: f64,
    /// How steadiness was judged (text for the summary).
    pub steady_rule: String,
    /// Profile samples averaged.
    pub averaged_samples: usize,
    /// Positions of the u profile (x = 0.5).
    pub ys: Vec<f64>,
    /// Averaged `u(0.5, y)`.
    pub u: Vec<f64>,
    /// Positions of the v profile (y = 0.5).
    pub xs: Vec<f64>,
    /// Averaged `v(x, 0.5)`.
    pub v: Vec<f64>,
    /// Errors against Ghia et al. when a table exists for this Re.
    pub ghia: Option<GhiaErrors>,
    /// Largest Theorem 4.5 ratio over all steps.
    pub max_stability_ratio: f64,
    /// Range of c0 over all steps.
    pub c0_min: f64,
    /// Range of c0 over all steps.
    pub c0_max: f64,
    /// Largest `‖∇̂h·u‖` after projection over `‖∇̂h·u*‖` before, over all steps.
    pub max_div_ratio: f64,
}

/// Interpolates a profile given at sorted positions `pos` to `q` (linear).
pub fn interp(pos: &[f64], val: &[f64], q: f64) -> f64 {
    match pos.iter().position(|&p| p >= q) {
        Some(0) => val[0],
        Some(k) => {
            let (p0, p1) = (pos[k - 1], pos[k]);
            let t = if p1 > p0 { (q - p0) / (p1 - p0) } else { 0.0 };
            val[k - 1] * (1.0 - t) + val[k] * t
        }
        None => *val.last().unwrap(),
    }
}

/// Errors of profiles `(ys, u)`, `(xs, v)` against Ghia's table for `re`.
pub fn ghia_errors(re: u32, ys: &[f64], u: &[f64], xs: &[f64], v: &[f64]) -> Option<GhiaErrors> {
    let t = ghia(re)?;
    let su: Vec<f64> = t.u_vertical.iter().map(|p| interp(ys, u, p.0)).collect();
    let sv: Vec<f64> = t.v_horizontal.iter().map(|p| interp(xs, v, p.0)).collect();
    let (rms_u, max_u) = rms_max(&t.u_vertical, &su);
    let (rms_v, max_v) = rms_max(&t.v_horizontal, &sv);
    Some(GhiaErrors {
        rms_u,
        max_u,
        rms_v,
        max_v,
    })
}

/// Runs a cavity to steadiness (or `t_end`); `observer` sees every step (for recording,
/// progress) and may stop the run by returning an error.
pub fn run(
    cfg: &CavityConfig,
    observer: impl FnMut(&FlowReport, &Simulation<2, Walls<2>>) -> Result<(), Error>,
) -> Result<CavityResult, Error> {
    run_full(cfg, observer).map(|(r, _)| r)
}

/// [`run`], also returning the final simulation state (for plots of the particles).
pub fn run_full(
    cfg: &CavityConfig,
    observer: impl FnMut(&FlowReport, &Simulation<2, Walls<2>>) -> Result<(), Error>,
) -> Result<(CavityResult, Simulation<2, Walls<2>>), Error> {
    run_with(cfg, |_| {}, observer)
}

/// [`run_full`] with a `setup` hook that may adjust the simulation after it is built and before
/// the first step (e.g. `sim.projection.capture = true` to record projection inputs).
pub fn run_with(
    cfg: &CavityConfig,
    setup: impl FnOnce(&mut Simulation<2, Walls<2>>),
    mut observer: impl FnMut(&FlowReport, &Simulation<2, Walls<2>>) -> Result<(), Error>,
) -> Result<(CavityResult, Simulation<2, Walls<2>>), Error> {
    let start = Instant::now();
    let mut sim = build(cfg)?;
    setup(&mut sim);
    let re_key = cfg.re.round() as u32;
    let (ys, xs) = sample_positions(re_key);
    let st = cfg.steady;
    let mut samples: Vec<(f64, Vec<f64>, Vec<f64>)> = Vec::new();
    let mut next_sample = st.interval;
    let mut steady_time = None;
    let mut rate = f64::INFINITY;
    let mut res = CavityResult {
        re: cfg.re,
        n: cfg.n,
        c0_min: f64::INFINITY,
        ..Default::default()
    };
    while sim.time < cfg.t_end - 1e-12 {
        let rep = sim.advance()?;
        let pr = &rep.projection;
        res.max_stability_ratio = res.max_stability_ratio.max(pr.stability_ratio);
        res.c0_min = res.c0_min.min(pr.c0);
        res.c0_max = res.c0_max.max(pr.c0);
        if pr.div_before > 0.0 {
            res.max_div_ratio = res.max_div_ratio.max(pr.div_after / pr.div_before);
        }
        observer(&rep, &sim)?;
        if sim.time + 1e-12 >= next_sample {
            let (u, v) = sample_profiles(&sim, &ys, &xs);
            if let Some(last) = samples.last() {
                let dt = sim.time - last.0;
                let du = u
                    .iter()
                    .zip(&last.1)
                    .chain(v.iter().zip(&last.2))
                    .map(|(a, b)| (a - b).abs())
                    .fold(0.0, f64::max);
                rate = du / dt;
                if rate < st.tol && steady_time.is_none() {
                    steady_time = Some(sim.time);
                }
            }
            samples.push((sim.time, u, v));
            next_sample += st.interval;
            if let Some(ts) = steady_time {
                if st.stop_when_steady && sim.time + 1e-12 >= ts + st.average_window {
                    break;
                }
            }
        }
    }
    if samples.is_empty() {
        let (u, v) = sample_profiles(&sim, &ys, &xs);
        samples.push((sim.time, u, v));
    }
    // average the samples of the last window
    let t_last = samples.last().unwrap().0;
    let window: Vec<&(f64, Vec<f64>, Vec<f64>)> = samples
        .iter()
        .filter(|s| s.0 >= t_last - st.average_window - 1e-9)
        .collect();
    let m = window.len() as f64;
    let u: Vec<f64> = (0..ys.len())
        .map(|k| window.iter().map(|s| s.1[k]).sum::<f64>() / m)
        .collect();
    let v: Vec<f64> = (0..xs.len())
        .map(|k| window.iter().map(|s| s.2[k]).sum::<f64>() / m)
        .collect();
    res.ghia = ghia_errors(re_key, &ys, &u, &xs, &v);
    res.averaged_samples = window.len();
    res.particles = sim.particles.n_fluid();
    res.ghosts = sim.particles.len() - res.particles;
    res.steps = sim.steps;
    res.t_end = sim.time;
    res.steady = steady_time.is_some();
    res.steady_time = steady_time;
    res.steady_rate = rate;
    res.steady_rule = format!(
        "centre-line profiles sampled every {} time units; steady when max|Δprofile|/Δt < {} U²/L; \
         profiles averaged over the last {} time units",
        st.interval, st.tol, st.average_window
    );
    res.ys = ys;
    res.u = u;
    res.xs = xs;
    res.v = v;
    res.wall_seconds = start.elapsed().as_secs_f64();
    Ok((res, sim))
}

/// The flat summary written to `summary.json`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CavitySummary {
    /// Reynolds number.
    pub re: f64,
    /// Fluid particles per side.
    pub n: usize,
    /// Fluid particles.
    pub particles: usize,
    /// Ghost particles at the end.
    pub ghosts: usize,
    /// Steps.
    pub steps: u64,
    /// Time reached.
    pub t_end: f64,
    /// Wall-clock seconds of the run.
    pub wall_seconds: f64,
    /// RMS of `u − u_Ghia` (lid-speed units, interior points); `null` without a table.
    pub rms_u: Option<f64>,
    /// Max of `|u − u_Ghia|`.
    pub max_u: Option<f64>,
    /// RMS of `v − v_Ghia`.
    pub rms_v: Option<f64>,
    /// Max of `|v − v_Ghia|`.
    pub max_v: Option<f64>,
    /// Steadiness reached.
    pub steady: bool,
    /// Time it was first reached.
    pub steady_time: Option<f64>,
    /// Last `max|Δprofile|/Δt`.
    pub steady_rate: f64,
    /// How steadiness was judged.
    pub steadiness: String,
    /// Largest Theorem 4.5 ratio over all steps.
    pub max_stability_ratio: f64,
    /// Smallest c0 over all steps.
    pub c0_min: f64,
    /// Largest c0 over all steps.
    pub c0_max: f64,
    /// The configuration of the run.
    pub config: CavityConfig,
}

impl CavitySummary {
    /// Flattens a result and its configuration.
    pub fn new(res: &CavityResult, cfg: &CavityConfig) -> Self {
        CavitySummary {
            re: res.re,
            n: res.n,
            particles: res.particles,
            ghosts: res.ghosts,
            steps: res.steps,
            t_end: res.t_end,
            wall_seconds: res.wall_seconds,
            rms_u: res.ghia.map(|g| g.rms_u),
            max_u: res.ghia.map(|g| g.max_u),
            rms_v: res.ghia.map(|g| g.rms_v),
            max_v: res.ghia.map(|g| g.max_v),
            steady: res.steady,
            steady_time: res.steady_time,
            steady_rate: res.steady_rate,
            steadiness: res.steady_rule.clone(),
            max_stability_ratio: res.max_stability_ratio,
            c0_min: res.c0_min,
            c0_max: res.c0_max,
            config: cfg.clone(),
        }
    }
}

/// Writes `profile_u.csv` (`y,u`), `profile_v.csv` (`x,v`) and `summary.json` into `dir`.
pub fn write_tables(
    dir: &std::path::Path,
    res: &CavityResult,
    cfg: &CavityConfig,
) -> std::io::Result<()> {
    use std::io::Write;
    std::fs::create_dir_all(dir)?;
    let mut f = std::io::BufWriter::new(std::fs::File::create(dir.join("profile_u.csv"))?);
    writeln!(f, "y,u")?;
    for (y, u) in res.ys.iter().zip(&res.u) {
        writeln!(f, "{y:.6},{u:.8}")?;
    }
    f.flush()?;
    let mut f = std::io::BufWriter::new(std::fs::File::create(dir.join("profile_v.csv"))?);
    writeln!(f, "x,v")?;
    for (x, v) in res.xs.iter().zip(&res.v) {
        writeln!(f, "{x:.6},{v:.8}")?;
    }
    f.flush()?;
    let summary = CavitySummary::new(res, cfg);
    std::fs::write(
        dir.join("summary.json"),
        serde_json::to_string_pretty(&summary).map_err(std::io::Error::other)?,
    )?;
    Ok(())
}

/// Writes `profiles.png` (both centre-line profiles against Ghia et al.) and `particles.png`
/// (fluid particles coloured by speed) into `dir`.
#[cfg(feature = "cli")]
pub fn write_plots(
    dir: &std::path::Path,
    res: &CavityResult,
    sim: &Simulation<2, Walls<2>>,
) -> Result<(), crate::plot::PlotError> {
    use crate::plot::{line_charts, particles, Chart, Series};
    let mut su = vec![Series::line(
        "gpm",
        res.u.iter().zip(&res.ys).map(|(u, y)| (*u, *y)).collect(),
    )];
    let mut sv = vec![Series::line(
        "gpm",
        res.xs.iter().zip(&res.v).map(|(x, v)| (*x, *v)).collect(),
    )];
    if let Some(t) = ghia(res.re.round() as u32) {
        su.push(Series::points(
            "Ghia et al. 1982",
            t.u_vertical.iter().map(|(y, u)| (*u, *y)).collect(),
        ));
        sv.push(Series::points("Ghia et al. 1982", t.v_horizontal.clone()));
    }
    let err = res
        .ghia
        .map(|g| format!(" (RMS {:.2}%)", 100.0 * g.rms_u))
        .unwrap_or_default();
    let errv = res
        .ghia
        .map(|g| format!(" (RMS {:.2}%)", 100.0 * g.rms_v))
        .unwrap_or_default();
    line_charts(
        &dir.join("profiles.png"),
        1400,
        650,
        &[
            (
                Chart {
                    title: format!("u along x = 0.5, Re {} n {}{err}", res.re, res.n),
                    x_label: "u / U".into(),
                    y_label: "y".into(),
                    ..Default::default()
                },
                su,
            ),
            (
                Chart {
                    title: format!("v along y = 0.5, Re {} n {}{errv}", res.re, res.n),
                    x_label: "x".into(),
                    y_label: "v / U".into(),
                    ..Default::default()
                },
                sv,
            ),
        ],
    )?;
    let p = &sim.particles;
    let (xs, speed): (Vec<[f64; 2]>, Vec<f64>) = (0..p.len())
        .filter(|&i| p.role[i].is_fluid())
        .map(|i| (p.x[i], crate::math::norm2(&p.u[i]).sqrt()))
        .unzip();
    particles(
        &dir.join("particles.png"),
        &format!("Cavity Re {} t = {:.1}: speed", res.re, res.t_end),
        &xs,
        &speed,
        [0.0, 0.0],
        [1.0, 1.0],
        "|u| / U",
        800,
    )
}
