//! The incremental pressure-Poisson projection step (MISSION §4), as a module a particle code can
//! call from its own loop.
//!
//! Given `xⁿ, uⁿ, pⁿ` and a neighbour list at `xⁿ`, one [`ProjectionStep::step`]:
//!
//! 1. checks its input ([`checks`]: lengths, finiteness, volumes, a neighbour list measured at
//!    these positions, ghosts placed and made with a reach of at least `h`, `h` above the
//!    spacing) and h-connectivity (before any solve, the viscous one included), and computes `c0`;
//! 2. predicts `u* − θΔtν Δh u* = uⁿ + Δt ((1−θ) ν Δh uⁿ + g + a_extra − ∇h pⁿ / ρ)` (the
//!    pressure term only in the incremental schemes; `θ = ½` is Crank–Nicolson, solved with a
//!    symmetric Helmholtz system, `θ = 0` is explicit);
//! 3. solves `−Δh φ = ∇̂h·f` with `f = −(ρ/Δt) u*` (sum-form divergence for the source by
//!    default; see [`SourceKind`] for the variants);
//! 4. corrects `uⁿ⁺¹ = u* − (Δt/ρ) ∇h φ` (difference gradient by default, see
//!    [`ProjectionParams::gradient`]) and sets `pⁿ⁺¹ = φ` (non-incremental), `pⁿ + φ` (standard
//!    incremental) or `pⁿ + φ − ρθν ∇̂h·u*` (rotational incremental, Timmermans et al. 1996, with
//!    `θ` the implicit weight of the viscous term);
//! 5. returns a [`StepReport`] with the diagnostics: connectivity, `c0`, the Theorem 4.5 ratio
//!    `‖φ‖_h01 / (√(d c0) ‖f‖_ℓ2)`, the solve, divergence before and after, energy and timings.
//!
//! The pair `∇̂h·` / `∇h` is discretely adjoint (Lemma 4.3), which is why the source uses one and
//! the correction the other. Advection and particle shifting are the caller's business (see
//! [`crate::flow`] for a complete solver). The step holds only scratch memory: the caller owns
//! the particles and the predictor velocity `u*`.
//!
//! **Stages.** [`ProjectionStep::predict`] and [`ProjectionStep::project`] are made of the public
//! stages of [`stages`] ([`stages::source_field`], [`stages::divergence_into`], the Poisson solve
//! [`crate::poisson::PoissonSolver::solve`], [`stages::correct`], [`stages::measure_divergence`]), which a
//! caller can also run one by one; [`ProjectionPlan`] decides which of them run.
//!
//! **A one-off `project`.** With an incremental scheme `project` returns `pⁿ⁺¹ = pⁿ + φ`, and
//! `φ ≈ (ρ/Δt)·(potential of u*)`: projecting a field that did not come from a predictor (an
//! initial condition, a random field) leaves a pressure of order `ρ/Δt` that the next incremental
//! `predict` re-applies as `−∇h p/ρ`. Use [`Scheme::NonIncremental`] for such a one-off projection
//! (`pⁿ⁺¹ = φ`), or reset the pressure afterwards ([`ProjectionStep::reset_pressure`]).

pub mod checks;
pub mod stages;
pub mod surface;

use crate::boundary::{Boundary, VectorKind};
use crate::consistent::{GradientKind, GradientOperator, LaplacianKind};
use crate::diagnostics::{
    min_spacing, norm_h01, norm_l2, norm_l2_vec, semi_regularity, stability_ratio, Components,
    ConnectivitySummary, Region,
};
use crate::error::{Error, InputError};
use crate::neighbors::NeighborList;
use crate::particles::{Particles, Role};
use crate::poisson::{HelmholtzSolver, PoissonSolver, SolveInfo, SolveParams};
use serde::{Deserialize, Serialize};
use std::time::Instant;

/// Pressure-correction scheme.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum Scheme {
    /// Chorin's projection: the predictor has no pressure gradient and `pⁿ⁺¹ = φ`.
    NonIncremental,
    /// Standard incremental (Goda/van Kan): `pⁿ⁺¹ = pⁿ + φ`.
    Incremental,
    /// Rotational incremental (Timmermans et al.): `pⁿ⁺¹ = pⁿ + φ − ρν ∇̂h·u*`.
    #[default]
    Rotational,
}

impl std::str::FromStr for Scheme {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s.trim().to_ascii_lowercase().replace('-', "_").as_str() {
            "non_incremental" | "nonincremental" | "chorin" => Ok(Scheme::NonIncremental),
            "incremental" | "standard" => Ok(Scheme::Incremental),
            "rotational" => Ok(Scheme::Rotational),
            _ => Err(format!(
                "unknown scheme '{s}': expected non-incremental, incremental or rotational"
            )),
        }
    }
}

impl std::fmt::Display for Scheme {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Scheme::NonIncremental => "non-incremental",
            Scheme::Incremental => "incremental",
            Scheme::Rotational => "rotational",
        })
    }
}

/// The divergence of the Poisson source `−Δh φ = D f`, `f = −(ρ/Δt) u*`, and of the reported
/// `div_before` / `div_after` (the operator-accuracy study, `examples/operator_accuracy.rs`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum SourceKind {
    /// The sum form `∇̂h·f` (default): exactly adjoint to the difference gradient `∇h`
    /// (Lemma 4.3), so with [`GradientKind::Difference`] Theorem 4.5 applies.
    #[default]
    SumForm,
    /// `∇̂h·(Bᵀ f)` (`B` the renormalisation matrices of
    /// [`crate::consistent::Renormalisation`]): the divergence adjoint to the renormalised
    /// gradient `∇ᶜ = B∇h`, `(∇̂h·(Bᵀψ), φ) = −(ψ, ∇ᶜφ)`; pairs with
    /// [`GradientKind::Renormalised`].
    AdjointBt,
    /// The consistent (renormalised) divergence `∇ᶜ·f_i = Σ_a (B_i ∇h f_a)_a`: exact for linear
    /// fields and zero for uniform ones, but adjoint to no gradient of the projection.
    Renormalised,
    /// The least-squares divergence `∇ˡˢ·f_i = Σ_a (∇ˡˢ f_a)_a`
    /// ([`crate::consistent::LsOperators`]): exact for quadratic fields; adjoint to no gradient.
    LeastSquares,
}

impl std::str::FromStr for SourceKind {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s.trim().to_ascii_lowercase().replace('-', "_").as_str() {
            "sum_form" | "sumform" | "sum" => Ok(SourceKind::SumForm),
            "adjoint_bt" | "adjointbt" | "adjoint" => Ok(SourceKind::AdjointBt),
            "renormalised" | "renormalized" | "consistent" => Ok(SourceKind::Renormalised),
            "least_squares" | "ls" => Ok(SourceKind::LeastSquares),
            _ => Err(format!(
                "unknown source divergence '{s}': expected sum-form, adjoint-bt, renormalised or \
                 least-squares"
            )),
        }
    }
}

impl std::fmt::Display for SourceKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            SourceKind::SumForm => "sum-form",
            SourceKind::AdjointBt => "adjoint-bt",
            SourceKind::Renormalised => "renormalised",
            SourceKind::LeastSquares => "least-squares",
        })
    }
}

/// The policy for fluid cut off from the rest: the components beyond
/// [`ProjectionParams::allowed_floating`] and the isolated particles (no neighbour within `h`).
///
/// The Poisson problem on such a component is a pure Neumann one: `φ` is fixed up to a constant
/// there, which [`crate::poisson::PoissonSolver`] sets to mean zero (an isolated particle gets
/// `φ = 0` and its source is dropped). The pressure gradient inside the component is then
/// unique; an isolated particle feels none, so it moves ballistically (body force and its own
/// velocity) until it rejoins.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Disconnected {
    /// An error naming the particles ([`crate::error::ConnectivityError`]): for fixed
    /// particles a disconnected set-up is a mistake.
    #[default]
    Fail,
    /// Each such component is its own floating component (see above); the step reports how
    /// many particles the policy acted on ([`StepReport::disconnected`]).
    Float,
}

/// Physical and numerical parameters of the projection.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ProjectionParams<const D: usize> {
    /// Density `ρ`.
    pub rho: f64,
    /// Kinematic viscosity `ν` (0 skips the viscous stage).
    pub nu: f64,
    /// Body force per unit mass `g` (all zero skips the stage).
    pub gravity: [f64; D],
    /// Pressure-correction scheme.
    pub scheme: Scheme,
    /// Implicit weight `θ ∈ [0, 1]` of the viscous term in the predictor:
    /// `u* − θΔtν Δh u* = uⁿ + Δt((1−θ) ν Δh uⁿ + …)`. 0 = explicit (no solve),
    /// ½ = Crank–Nicolson (second order), 1 = backward Euler. The rotational correction is
    /// `−ρ θν ∇̂h·u*` (the part of the implicit viscous term that the projection changes).
    pub viscous_theta: f64,
    /// Linear solve parameters.
    pub solve: SolveParams,
    /// How the source `f = −(ρ/Δt) u*` is continued into wall ghosts.
    /// [`VectorKind::Mirror`] (normal component flipped, tangential kept) keeps `∇̂h·` and `∇h`
    /// exactly adjoint, so Theorem 4.5 applies and its ratio is at most 1; the no-slip rule
    /// ([`VectorKind::Velocity`]) feeds the wall velocity into the source (the adjointness then
    /// holds only up to wall terms, and an impulsively started lid gives ratios above 1);
    /// [`VectorKind::RestWalls`] takes the no-slip images across walls at rest (the odd
    /// continuation, smooth where the velocity vanishes on the wall; the mirror's even one has
    /// a kink there), the mirror across moving ones and at their corners, and blends the two
    /// within a moving wall's [`crate::boundary::Wall::source_band`] (the odd images' net flux
    /// next to a lid whose speed jumps at its corners is a first-order mass source).
    pub source_ghosts: VectorKind,
    /// Reuse connectivity and `c0` while the pair data, roles and volumes are bit-identical
    /// (they are functions of those alone; default true).
    pub reuse_diagnostics: bool,
    /// Floating (pure Neumann) components the problem is expected to have: 1 for a box closed
    /// by walls, 0 when a Dirichlet band touches every part of the fluid. More are reported as a
    /// connectivity failure.
    pub allowed_floating: usize,
    /// What the projection does with fluid cut off from the rest beyond `allowed_floating`
    /// (an isolated particle, a cluster that lost its path to the Dirichlet band or drifted
    /// away from the bulk): fail naming the particles (default) or solve each such component
    /// as its own floating one ([`Disconnected`]). Either way the step's connectivity counts
    /// and [`StepReport::disconnected`] record it.
    pub disconnected: Disconnected,
    /// The gradient for `∇pⁿ` in the predictor and `∇φ` in the correction: the difference
    /// gradient `∇h` (default; exactly adjoint to the source's `∇̂h·`, so Theorem 4.5 applies)
    /// or the renormalised `∇ᶜ = B∇h` (first order on disordered particles; not adjoint; its
    /// matrices are cached while the pair data and volumes are unchanged).
    pub gradient: GradientKind,
    /// The divergence of the source and of the measured `div_before` / `div_after`: the sum
    /// form `∇̂h·` (default), the adjoint of `∇ᶜ` `∇̂h·(Bᵀ·)` (with `gradient = renormalised`) or
    /// the consistent divergence `∇ᶜ·`. The rotational pressure term uses the same divergence.
    pub source: SourceKind,
    /// The Laplacian of the viscous term: the GPM `Δh` (default) or the least-squares `Δˡˢ`
    /// (exact on quadratics on disordered particles; with `θ > 0` the predictor solves
    /// `(I − θΔtν Δh) u* = uⁿ + Δt(ν(Δˡˢ − θΔh) uⁿ + …)`, so the implicit solve keeps the SPD
    /// matrix and a steady state is the consistent one).
    pub laplacian: LaplacianKind,
    /// Weight `β ∈ [0, 1)` of one Jacobi smoothing sweep of the new pressure with the Poisson
    /// matrix, `p_i ← p_i + β (Δh p)_i / |(Δh)_ii|` (default 0: none). With a divergence and
    /// gradient that are not adjoint, `∇·∇` has near-null (checkerboard) modes of either sign
    /// on disordered particles; the incremental pressure `p ← p − (Δh)⁻¹∇·∇p + …` then grows
    /// slowly in the negative ones (measured: eigenvalues of `(Δh)⁻¹∇ᶜ·∇ᶜ` down to −0.022 at
    /// 0.3 Δx jitter). The sweep damps them; on smooth pressures it changes `p` by
    /// `O(β Δx² ∇²p)`, which the next projection restores.
    pub pressure_smoothing: f64,
    /// The Dirichlet band is a free surface (default false: the band's velocity is given
    /// data). Its particles are then predicted like fluid ones (body force and pressure terms;
    /// no viscous term: the surface is stress-free) and their velocity after the correction is
    /// the water's below them ([`stages::extend_to_band`]), while their pressure is held at the
    /// band's value (`φ = 0` there; zero, or what the driver sets:
    /// [`crate::flow::free_surface::set_band_pressure`]): the paper's Dirichlet problem on the
    /// fluid, and a band that moves with it.
    pub free_surface: bool,
}

impl<const D: usize> ProjectionParams<D> {
    /// `ρ g`, the wall-normal pressure gradient of the fluid at rest
    /// ([`Boundary::fill_pressure`]).
    pub fn rho_g(&self) -> [f64; D] {
        self.gravity.map(|g| self.rho * g)
    }

    /// `ρ = 1`, viscosity `nu`, no body force, the rotational scheme, default solver, one
    /// floating component allowed (closed box), the difference gradient and the sum-form source.
    pub fn new(nu: f64) -> Self {
        ProjectionParams {
            rho: 1.0,
            nu,
            gravity: [0.0; D],
            scheme: Scheme::Rotational,
            viscous_theta: 0.5,
            source_ghosts: VectorKind::Mirror,
            reuse_diagnostics: true,
            solve: SolveParams::default(),
            allowed_floating: 1,
            disconnected: Disconnected::Fail,
            gradient: GradientKind::Difference,
            source: SourceKind::SumForm,
            laplacian: LaplacianKind::Gpm,
            pressure_smoothing: 0.0,
            free_surface: false,
        }
    }

    /// The operators for disordered and moving particles
    /// ([`crate::consistent::LsOperators`], exact on quadratic fields on any distribution):
    /// the least-squares divergence `∇ˡˢ·` for the source and the rotational term, the
    /// least-squares gradient `∇ˡˢ` for `∇pⁿ` and `∇φ`, the least-squares viscous Laplacian
    /// `Δˡˢ`, the no-slip ghost rule for the source (the divergence's wall points carry the wall
    /// velocity), and the pressure smoothing [`Self::pressure_smoothing`] = 0.1. The Poisson matrix
    /// stays the GPM one (SPD under h-connectivity: Theorem 4.1 and the connectivity and `c0`
    /// checks apply); `∇ˡˢ·` and `∇ˡˢ` are not adjoint, so Theorem 4.5 does not bound the
    /// correction (its ratio is still reported).
    pub fn with_consistent_operators(mut self) -> Self {
        self.source = SourceKind::LeastSquares;
        self.gradient = GradientKind::LeastSquares;
        self.laplacian = LaplacianKind::LeastSquares;
        self.pressure_smoothing = 0.1;
        // the divergence's wall points carry the wall velocity (the no-slip images)
        self.source_ghosts = VectorKind::Velocity;
        self
    }

    /// Checks `ρ > 0`, `ν ≥ 0`, `θ ∈ [0, 1]`, finite values, non-negative tolerances, and that
    /// the adjoint source [`SourceKind::AdjointBt`] comes with the renormalised gradient it is
    /// the adjoint of. The error names the offending key and its value.
    pub fn validate(&self) -> Result<(), InputError> {
        let bad = |name: &'static str, value: f64, reason: &str| {
            Err(InputError::Parameter {
                name: name.into(),
                value,
                reason: reason.into(),
            })
        };
        if !(self.rho > 0.0 && self.rho.is_finite()) {
            return bad("rho", self.rho, "the density must be positive and finite");
        }
        if !(self.nu >= 0.0 && self.nu.is_finite()) {
            return bad(
                "nu",
                self.nu,
                "the viscosity must be non-negative and finite",
            );
        }
        if !(0.0..=1.0).contains(&self.viscous_theta) {
            return bad(
                "viscous_theta",
                self.viscous_theta,
                "the implicit viscous weight must be in [0, 1]",
            );
        }
        if let Some(g) = self.gravity.iter().find(|g| !g.is_finite()) {
            return bad("gravity", *g, "the body force must be finite");
        }
        self.solve.validate()?;
        if !(0.0..1.0).contains(&self.pressure_smoothing) {
            return bad(
                "pressure_smoothing",
                self.pressure_smoothing,
                "the smoothing weight must be in [0, 1)",
            );
        }
        if self.source == SourceKind::AdjointBt && self.gradient != GradientKind::Renormalised {
            return Err(InputError::Config {
                key: "source".into(),
                reason: format!(
                    "the adjoint source {} is the adjoint of the renormalised gradient: it needs \
                     gradient = renormalised, not {}",
                    self.source, self.gradient
                ),
            });
        }
        Ok(())
    }
}

/// Which stages of the projection run, decided once from the parameters (MISSION §4: a step
/// skips every stage it does not need). [`ProjectionStep::predict`] and
/// [`ProjectionStep::project`] follow it, and [`crate::flow::StagePlan`] takes the projection's
/// stages from it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ProjectionPlan {
    /// `(1−θ) ν Δh uⁿ` in the predictor (`ν > 0`, `θ < 1`).
    pub viscous_explicit: bool,
    /// The Helmholtz solve `(I − θΔtν Δh) u* = r` (`ν > 0`, `θ > 0`).
    pub viscous_implicit: bool,
    /// The implicit weight actually used: `θ` when `ν > 0`, else 0.
    pub theta: f64,
    /// `−∇pⁿ/ρ` in the predictor (the incremental schemes).
    pub pressure_gradient: bool,
    /// The body force `g` (some component non-zero).
    pub body_force: bool,
    /// The rotational pressure term `−ρθν ∇̂h·u*` (rotational scheme, `θν > 0`).
    pub rotational: bool,
    /// The gradient of the predictor and the correction.
    pub gradient: GradientKind,
    /// The divergence of the source.
    pub source: SourceKind,
}

impl ProjectionPlan {
    /// The plan for `params`.
    pub fn new<const D: usize>(params: &ProjectionParams<D>) -> Self {
        let nu = params.nu;
        let theta = if nu > 0.0 { params.viscous_theta } else { 0.0 };
        ProjectionPlan {
            viscous_explicit: nu > 0.0 && theta < 1.0,
            viscous_implicit: theta > 0.0,
            theta,
            pressure_gradient: params.scheme != Scheme::NonIncremental,
            body_force: params.gravity.iter().any(|&v| v != 0.0),
            rotational: params.scheme == Scheme::Rotational && nu * params.viscous_theta > 0.0,
            gradient: params.gradient,
            source: params.source,
        }
    }
}

/// Wall-clock seconds per stage of one step.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct StageTimings {
    /// Connectivity, `c0` and the other checks.
    pub diagnostics: f64,
    /// Predictor (viscous term, pressure gradient, forces).
    pub predictor: f64,
    /// Sum-form divergence of the source.
    pub source: f64,
    /// Poisson solve (assembly + factorisation/iterations).
    pub solve: f64,
    /// Correction and pressure update.
    pub correction: f64,
}

/// What one projection step did and measured.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct StepReport {
    /// Time step used.
    pub dt: f64,
    /// Connectivity of the fluid graph (checked before the solve).
    pub connectivity: ConnectivitySummary,
    /// Fluid particles the [`Disconnected::Float`] policy acted on in this step: those of the
    /// floating components beyond `allowed_floating` and the isolated ones (0 when the problem
    /// is the expected one; with [`Disconnected::Fail`] such a step is an error instead).
    pub disconnected: usize,
    /// Semi-regularity constant `c0` over `Ω`.
    pub c0: f64,
    /// Smallest distance between a fluid particle and any neighbour (ghosts included; `∞` when
    /// no fluid particle has one). Falls when particles clump or approach a wall.
    pub min_spacing: f64,
    /// Theorem 4.5 ratio `‖φ‖_h01(Ω) / (√(d c0) ‖f‖_ℓ2(Ω))`, at most 1 by the theorem.
    pub stability_ratio: f64,
    /// The Poisson solve.
    pub solve: SolveInfo,
    /// The implicit viscous (Helmholtz) solve of the step's predictor, when one ran and
    /// [`Prediction::add_to`] brought it here (`None` with explicit or no viscosity).
    pub viscous: Option<SolveInfo>,
    /// `‖D u*‖_ℓ2(Ω)`, `D` the source's divergence ([`SourceKind`]), measured as the source
    /// sees `u*`: zero on the Dirichlet band, ghosts continued as for the source.
    pub div_before: f64,
    /// `‖D uⁿ⁺¹‖_ℓ2(Ω)`, measured exactly as `div_before` (band zeroed, same ghost rule), so the
    /// two compare what the projection removed.
    pub div_after: f64,
    /// `‖uⁿ⁺¹ − u*‖_ℓ2(Ω) / ‖u*‖_ℓ2(Ω)` (0 when `u* = 0`): the share of the predicted velocity
    /// the correction removes. Small (`O(Δt)`) in a healthy run; it approaches or exceeds 1 when
    /// the pressure feedback drives a blow-up, while the Theorem 4.5 ratio can stay below 1.
    pub correction_ratio: f64,
    /// `½ ρ Σ_Ω ω_i |u_i|²` after the step.
    pub kinetic_energy: f64,
    /// `max_Ω |u_i|` after the step.
    pub max_speed: f64,
    /// Seconds per stage.
    pub timings: StageTimings,
}

/// What [`ProjectionStep::predict`] did.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Prediction {
    /// Seconds spent on the predictor (viscous term, pressure gradient, forces, the solve).
    pub seconds: f64,
    /// Seconds spent on the input checks and the connectivity check before the viscous solve.
    pub diagnostics_seconds: f64,
    /// The implicit viscous (Helmholtz) solve, when it ran.
    pub viscous: Option<SolveInfo>,
}

impl Prediction {
    /// Adds the predictor's timings and its viscous solve to the report of the
    /// [`ProjectionStep::project`] that followed it (`timings.predictor`, its checks to
    /// `timings.diagnostics`, the solve to `viscous`).
    pub fn add_to(&self, report: &mut StepReport) {
        report.timings.predictor = self.seconds;
        report.timings.diagnostics += self.diagnostics_seconds;
        report.viscous = self.viscous;
    }
}

/// What connectivity and c0 were computed from.
#[derive(Clone, Debug, Default, PartialEq)]
struct DiagnosticsKey {
    valid: bool,
    epoch: u64,
    generation: u64,
    roles: u64,
    vol: Vec<f64>,
}

fn role_fingerprint(role: &[crate::particles::Role]) -> u64 {
    use std::hash::{Hash, Hasher};
    let mut h = std::collections::hash_map::DefaultHasher::new();
    role.len().hash(&mut h);
    for r in role {
        match *r {
            crate::particles::Role::Fluid => 0u64.hash(&mut h),
            crate::particles::Role::Dirichlet => 1u64.hash(&mut h),
            crate::particles::Role::Ghost { source, walls } => {
                (2u64, source, walls).hash(&mut h);
            }
        }
    }
    h.finish()
}

fn check_dt(dt: f64) -> Result<(), InputError> {
    if !(dt > 0.0 && dt.is_finite()) {
        return Err(InputError::Parameter {
            name: "dt".into(),
            value: dt,
            reason: "the time step must be positive and finite".into(),
        });
    }
    Ok(())
}

/// Everything [`ProjectionStep::project`] read and wrote in one call: enough to re-run it.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ProjectionCapture<const D: usize> {
    /// Positions (all particles, ghosts included).
    pub x: Vec<[f64; D]>,
    /// Volumes.
    pub vol: Vec<f64>,
    /// Roles.
    pub role: Vec<crate::particles::Role>,
    /// Predictor velocity `u*` (ghosts filled).
    pub u_star: Vec<[f64; D]>,
    /// Pressure `pⁿ` before the update.
    pub p_in: Vec<f64>,
    /// The increment held before the solve (CG's warm start).
    pub phi_in: Vec<f64>,
    /// Time step.
    pub dt: f64,
    /// Velocity `uⁿ⁺¹` after the correction.
    pub u_out: Vec<[f64; D]>,
    /// Pressure `pⁿ⁺¹`.
    pub p_out: Vec<f64>,
    /// Increment `φ`.
    pub phi: Vec<f64>,
    /// The steady singular part the projection left out ([`ProjectionStep::singular`];
    /// `None`: none): a re-run without it would project a different field.
    pub singular: Option<SingularPart<D>>,
}

/// Brings the copies a rank holds of other ranks' particles up to date (the particle
/// decomposition, [`crate::distributed::decomposed`]): the projection calls it where a value it
/// just computed at a copy would read beyond the copies (the pressure before its smoothing:
/// the rotational term of a copy reads `u*` up to `2h` from the rank's own particles, where
/// the global solves do not write). Collective: every rank's projection calls it at the same
/// point of the step.
pub trait HaloSync: Send + Sync + std::fmt::Debug {
    /// Overwrites the entries of `values` (`width` numbers per particle) at the copies with
    /// their owners' values; the other entries are left as they are.
    fn sync(&mut self, values: &mut [f64], width: usize);

    /// [`Self::sync`] for one number per particle.
    fn scalar(&mut self, values: &mut [f64]) {
        self.sync(values, 1);
    }

    /// The particles this rank owns, when they are the first ones (the rest its copies):
    /// bounds over the rows, such as the adaptive viscous tolerance's divergence gain, are then
    /// taken over the own rows only, whose neighbourhoods are whole (`None`: over every row).
    fn own(&self) -> Option<usize> {
        None
    }
}

/// The warm start of the Poisson solve: the increments of the last steps extrapolated in time
/// to the new step, `φⁿ⁺¹ ≈ Σ_k ℓ_k(tⁿ⁺¹) φⁿ⁻ᵏ` (Lagrange weights on the steps' times), linear
/// through the last two, quadratic through the last three or cubic through the last four.
/// Along the trajectories of moving particles the increment carries the flow's `u·∇` terms and
/// each order leaves a smaller residual (2D Taylor–Green, 10⁵ particles: `‖r₀‖/‖b‖`
/// 9·10⁻⁵ linear, 1.4·10⁻⁶ quadratic: AMG-CG 9–10 iterations to 10⁻⁸ instead of 6; settled, the
/// quadratic guess 1.8·10⁻⁷ off the solution, the cubic 4.9·10⁻⁹); where the increments are
/// rough in time (impulsive starts, a band that changes, or a fixed point whose increment is
/// already predicted to the solver's noise) the larger weights amplify their noise. So every
/// guess the history allows is formed every step and, once the solve is done, the one nearest
/// to its solution (over the fluid) is the order of the next step's guess.
#[derive(Debug, Default)]
struct WarmStart {
    /// `φⁿ⁻²` and `Δtⁿ⁻¹` (empty / 0 until the history is three deep).
    prev2: Vec<f64>,
    dt_prev2: f64,
    /// `φⁿ⁻³` and `Δtⁿ⁻²` (empty / 0 until the history is four deep).
    prev3: Vec<f64>,
    dt_prev3: f64,
    /// The guesses of this step (empty when no quadratic / cubic one could be formed).
    linear: Vec<f64>,
    quadratic: Vec<f64>,
    cubic: Vec<f64>,
    /// The order the next guess takes: cubic when `use_cubic` and a cubic guess can be formed,
    /// else quadratic when `use_quadratic`, else linear.
    use_quadratic: bool,
    use_cubic: bool,
}

/// The Lagrange weights at `t` of the nodes `ts`.
fn lagrange_weights<const K: usize>(ts: [f64; K], t: f64) -> [f64; K] {
    std::array::from_fn(|k| {
        (0..K)
            .filter(|&m| m != k)
            .map(|m| (t - ts[m]) / (ts[k] - ts[m]))
            .product()
    })
}

impl WarmStart {
    /// Forgets the third and fourth levels (the history was reset or handed over).
    fn forget(&mut self) {
        self.prev2.clear();
        self.dt_prev2 = 0.0;
        self.prev3.clear();
        self.dt_prev3 = 0.0;
        self.linear.clear();
        self.quadratic.clear();
        self.cubic.clear();
        self.use_quadratic = false;
        self.use_cubic = false;
    }

    /// Overwrites `phi` (`φⁿ` on entry) with the guess for the step of length `dt`, and shifts
    /// the history: `prev` (`φⁿ⁻¹`, of the step `dt_prev` before) becomes `φⁿ`.
    fn extrapolate(&mut self, phi: &mut [f64], prev: &mut [f64], dt: f64, dt_prev: f64) {
        let n = phi.len();
        let quad = self.prev2.len() == n && self.dt_prev2 > 0.0;
        let cubic = quad && self.prev3.len() == n && self.dt_prev3 > 0.0;
        if quad {
            // Lagrange weights at tⁿ⁺¹ on tⁿ, tⁿ⁻¹ = tⁿ − a, tⁿ⁻² = tⁿ − a − b
            let (a, b) = (dt_prev, self.dt_prev2);
            let l0 = (dt + a) * (dt + a + b) / (a * (a + b));
            let l1 = -dt * (dt + a + b) / (a * b);
            let l2 = dt * (dt + a) / ((a + b) * b);
            let r = dt / a;
            // and on tⁿ⁻³ = tⁿ − a − b − c as well
            let c3 = if cubic {
                lagrange_weights([0.0, -a, -a - b, -a - b - self.dt_prev3], dt)
            } else {
                [0.0; 4]
            };
            self.linear.resize(n, 0.0);
            self.quadratic.resize(n, 0.0);
            if cubic {
                self.cubic.resize(n, 0.0);
            } else {
                // the history becomes four deep: φⁿ⁻² moves to the fourth level
                self.cubic.clear();
                self.prev3.clone_from(&self.prev2);
            }
            let use_cubic = cubic && self.use_cubic;
            for i in 0..n {
                let (p0, p1, p2) = (phi[i], prev[i], self.prev2[i]);
                self.linear[i] = p0 + r * (p0 - p1);
                self.quadratic[i] = l0 * p0 + l1 * p1 + l2 * p2;
                if cubic {
                    let p3 = self.prev3[i];
                    self.cubic[i] = c3[0] * p0 + c3[1] * p1 + c3[2] * p2 + c3[3] * p3;
                    self.prev3[i] = p2;
                }
                self.prev2[i] = p1;
                prev[i] = p0;
                phi[i] = if use_cubic {
                    self.cubic[i]
                } else if self.use_quadratic {
                    self.quadratic[i]
                } else {
                    self.linear[i]
                };
            }
            self.dt_prev3 = self.dt_prev2;
        } else {
            let r = dt / dt_prev;
            self.prev2.clear();
            self.prev2.extend_from_slice(prev);
            self.prev3.clear();
            self.dt_prev3 = 0.0;
            self.linear.clear();
            self.quadratic.clear();
            self.cubic.clear();
            for (p, q) in phi.iter_mut().zip(prev.iter_mut()) {
                let last = *p;
                *p = last + r * (last - *q);
                *q = last;
            }
        }
        self.dt_prev2 = dt_prev;
    }

    /// After the solve: the order whose guess was nearest to the solution `phi` over the fluid
    /// is the next step's.
    fn judge(&mut self, phi: &[f64], role: &[Role]) {
        if self.quadratic.len() != phi.len() || self.linear.len() != phi.len() {
            return;
        }
        let with_cubic = self.cubic.len() == phi.len();
        let (mut el, mut eq, mut ec) = (0.0, 0.0, 0.0);
        for i in 0..phi.len() {
            if role[i].is_fluid() {
                el += (phi[i] - self.linear[i]).powi(2);
                eq += (phi[i] - self.quadratic[i]).powi(2);
                if with_cubic {
                    ec += (phi[i] - self.cubic[i]).powi(2);
                }
            }
        }
        self.use_quadratic = eq < el;
        self.use_cubic = with_cubic && ec < el.min(eq);
    }
}

/// What a kept `∇p/ρ` was taken from ([`ProjectionStep::keep_pressure_gradient`]): the
/// neighbour list's epoch and generation (pairs, positions, ghosts), the bits of the pressure
/// (ghosts filled) and of the volumes, and `ρ`.
#[derive(Clone, Copy, Debug, PartialEq)]
struct KeptGradientKey {
    epoch: u64,
    generation: u64,
    pressure: u64,
    volumes: u64,
    len: usize,
    rho: u64,
    gradient: GradientKind,
}

impl KeptGradientKey {
    fn of<const D: usize>(
        nl: &NeighborList<D>,
        p: &[f64],
        vol: &[f64],
        rho: f64,
        gradient: GradientKind,
    ) -> Self {
        KeptGradientKey {
            gradient,
            epoch: nl.epoch(),
            generation: nl.generation(),
            pressure: crate::neighbors::values_hash(p),
            volumes: crate::neighbors::values_hash(vol),
            len: p.len(),
            rho: rho.to_bits(),
        }
    }
}

/// `g /= ρ`, every component (a pressure gradient into `∇p/ρ`).
fn divide<const D: usize>(g: &mut [[f64; D]], rho: f64) {
    for v in g.iter_mut().flatten() {
        *v /= rho;
    }
}

/// [`HaloSync::sync`] for a vector per particle.
fn sync_vector<const D: usize>(h: &mut dyn HaloSync, values: &mut [[f64; D]]) {
    let mut flat: Vec<f64> = values.iter().flatten().copied().collect();
    h.sync(&mut flat, D);
    for (v, f) in values.iter_mut().zip(flat.chunks_exact(D)) {
        v.copy_from_slice(f);
    }
}

/// A steady velocity field `u_s` that is part of the solution but not of what the particles'
/// discrete operators see (a singular part subtracted as in Botella & Peyret 1998, e.g.
/// [`crate::scene::corner`]): the projection makes the source's divergence of `u − u_s`
/// vanish, not that of `u`. `u_s` is given at every particle with two continuations into the
/// ghosts: `source` as the source's ghost rule continues the regular part `u − u_s`
/// (subtracted from the source and from the measured divergences), `no_slip` as the no-slip
/// rule does (subtracted from the rotational scheme's divergence). Only with the sum-form
/// source ([`SourceKind::SumForm`]), whose divergence reads the ghosts as given.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SingularPart<const D: usize> {
    /// `u_s`, ghosts continued like the source's.
    pub source: Vec<[f64; D]>,
    /// `u_s`, ghosts continued by the no-slip rule.
    pub no_slip: Vec<[f64; D]>,
}

/// Scratch memory of the projection, reusable across steps (and `Send + Sync`).
#[derive(Debug, Default)]
pub struct ProjectionStep<const D: usize> {
    /// The steady singular part of the velocity the projection leaves out ([`SingularPart`]);
    /// `None` (the default): none.
    pub singular: Option<SingularPart<D>>,
    /// Scratch of the singular part's divergence.
    work_scalar: Vec<f64>,
    /// When set, the halo of copies of other ranks' particles is refreshed where the step needs
    /// it (see [`HaloSync`]).
    pub halo: Option<Box<dyn HaloSync>>,
    /// When true, [`project`](Self::project) stores its inputs and outputs in
    /// [`captured`](Self::captured) (for recording and re-running).
    pub capture: bool,
    /// The last capture.
    pub captured: Option<ProjectionCapture<D>>,
    /// Pressure increment `φ` of the last step (warm start for CG).
    pub phi: Vec<f64>,
    /// The potential `χ` of the last volume shift ([`Self::volume_shift_into`]; its warm start).
    volume_chi: Vec<f64>,
    /// The relative volume error `e` of the last volume shift at every particle (0 off the
    /// fluid; [`Self::volume_error_sums`]).
    volume_e: Vec<f64>,
    /// [`predict`](Self::predict) also assembles and (Cholesky) factorises the Poisson matrix
    /// of its configuration, on one thread while the predictor runs on the others
    /// ([`crate::poisson::PoissonSolver::prepare`]), so that [`project`](Self::project) on the same
    /// configuration finds the factor ready. Set it when predict and project see the same
    /// particles (the [`crate::flow::Simulation`] driver does, and [`step`](Self::step) always
    /// does it; a Lagrangian loop that moves its particles between the two would waste the
    /// work). Default false.
    pub overlap_solve_setup: bool,
    /// [`project`](Self::project) also takes `∇pⁿ⁺¹/ρ` of the corrected (and smoothed)
    /// pressure on its configuration, in the same pass over the pairs as `∇φ` for the
    /// difference and least-squares gradients (not in a decomposed run, whose halo pressures
    /// are refreshed between steps), for
    /// [`take_pressure_gradient`](Self::take_pressure_gradient): a Lagrangian driver's next step
    /// needs exactly that field for the trapezoidal pressure term before it moves the
    /// particles. Bit for bit [`pressure_gradient_into`](Self::pressure_gradient_into) on the
    /// same state. Default false (the [`crate::flow::Simulation`] sets it on moving
    /// particles).
    pub keep_pressure_gradient: bool,
    /// That gradient and what it was taken from (`None`: nothing kept).
    kept_pressure_gradient: (Vec<[f64; D]>, Option<KeptGradientKey>),
    /// The increment of the step before and that step's `Δt`: the warm start is the linear
    /// extrapolation in time of the last two increments, or the quadratic one of the last
    /// three (`warm`).
    phi_prev: Vec<f64>,
    dt_prev: f64,
    /// The warm start's third level and its choice of order ([`WarmStart`]).
    warm: WarmStart,
    /// The Poisson solver and its caches.
    pub solver: PoissonSolver,
    /// The implicit viscous solver and its caches.
    pub viscous: HelmholtzSolver,
    /// `u*` of the last [`step`](Self::step) (a caller of `predict` owns its own).
    own_u_star: Vec<[f64; D]>,
    /// `u*` with its ghosts refilled (the projection's copy).
    u_star: Vec<[f64; D]>,
    u_new: Vec<[f64; D]>,
    p_new: Vec<f64>,
    work_vec: Vec<[f64; D]>,
    work_vec2: Vec<[f64; D]>,
    rhs: Vec<f64>,
    work: Vec<f64>,
    viscous_info: SolveInfo,
    /// The volumes and roles the overlapped Poisson setup reads (kept vectors).
    ahead_inputs: (Vec<f64>, Vec<Role>),
    /// What `comps`, `c0` and the spacing were last computed from (`valid` false: nothing).
    diagnostics_key: DiagnosticsKey,
    diagnostics_values: (f64, f64),
    /// The components of the last connectivity check (taken out while the predictor's
    /// overlapped Poisson setup reads them: the key is invalid then).
    comps: Components,
    connectivity_scratch: crate::diagnostics::ConnectivityScratch,
    /// With a [`HaloSync`] (a rank of a decomposed run): the source's divergence `D f` of the
    /// last projection at every particle, and the particles the last connectivity check
    /// found disconnected ([`Disconnected::Float`]), for the run's global diagnostics.
    source_divergence: Vec<f64>,
    disconnected: Vec<usize>,
    gradient: GradientOperator<D>,
    /// `∇p/ρ` of the current pressure on the current configuration, computed by the driver
    /// ([`Self::pressure_gradient_into`]) just before [`predict`](Self::predict), which then
    /// uses it rather than computing it again (valid for that one call: the flag).
    pressure_gradient_given: (Vec<[f64; D]>, bool),
    /// Dirichlet values of the increment on the band ([`Self::set_band_increment`]; empty:
    /// zero).
    band_phi: Vec<f64>,
    /// The moving walls' ghost partners of [`VectorKind::RestWallsLinear`].
    linear_ghosts: stages::LinearGhosts,
    /// The adaptive viscous tolerance's state ([`SolveParams::viscous_adaptive`]).
    viscous_rule: ViscousRule,
}

/// The adaptive viscous tolerance's state ([`SolveParams::viscous_adaptive`]), kept between
/// steps (and handed on when a decomposed run builds a rank's projection anew).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub(crate) struct ViscousRule {
    /// The next viscous solve's tolerance before its clamp (0: the rule does not apply).
    pub loosen: f64,
    /// The divergence's gain bound the candidate was computed with
    /// ([`stages::divergence_gain_into`]; 0: not measured yet). It is measured again in the
    /// source's pass whenever the last candidate lay above a tenth of the tight tolerance, and
    /// kept otherwise: below that it cannot matter. A rank of a decomposed run measures it over
    /// its own rows and takes the largest of the ranks'.
    pub gain: f64,
    /// The last Poisson solve's `initial_rel_residual`.
    pub rho_last: f64,
}

impl ViscousRule {
    /// The next viscous solve's candidate `θ ρ ‖∇̂h·u*‖ / (G ‖u*‖)` (`rho0` the Poisson
    /// solve's warm-start residual, `du` and `u` the norms over the fluid, `G` the kept gain
    /// bound, `θ = 0.1`), with `ρ` carried one step on while it falls (a warm start still
    /// settling: the viscous error stays in the history its next guesses extrapolate). 0 (the
    /// tight tolerance) without the rule or without one of its inputs.
    pub fn update(&mut self, adaptive: bool, rho0: f64, du: f64, u: f64) {
        let rho_next = match self.rho_last {
            last if last > 0.0 => rho0 * (rho0 / last).min(1.0),
            _ => rho0,
        };
        self.rho_last = rho0;
        self.loosen = if adaptive && rho0 > 0.0 && du > 0.0 && u > 0.0 && self.gain > 0.0 {
            0.1 * rho_next * du / (self.gain * u)
        } else {
            0.0
        };
    }
}

impl<const D: usize> ProjectionStep<D> {
    /// Empty scratch.
    pub fn new() -> Self {
        Self::default()
    }

    /// The predictor velocity `u*` of the last [`step`](Self::step) (ghosts filled).
    pub fn u_star(&self) -> &[[f64; D]] {
        &self.u_star
    }

    /// The divergences of the last projection at every particle, before (`D f`, the Poisson
    /// source with `f = −(ρ/Δt) u*`) and after (`D uⁿ⁺¹`), as `div_before` and `div_after`
    /// measure them (`‖·‖_ℓ2(Ω)`, the first scaled by `Δt/ρ`), and the particles the
    /// connectivity check found disconnected. Kept only with a [`HaloSync`]: a rank of a
    /// decomposed run sums them over its own particles (empty otherwise).
    pub(crate) fn rank_diagnostics(&self) -> (&[f64], &[f64], &[usize]) {
        if self.halo.is_none() {
            return (&[], &[], &[]);
        }
        (&self.source_divergence, &self.rhs, &self.disconnected)
    }

    /// The adaptive viscous tolerance's state.
    pub(crate) fn viscous_rule(&self) -> ViscousRule {
        self.viscous_rule
    }

    /// The adaptive viscous tolerance's state, for a decomposed run to set from the ranks'
    /// global values (so that every rank's distributed viscous CG stops at the same
    /// tolerance) and to hand on. That tolerance is a single process's up to the gain bound,
    /// which each rank takes with its own rows' volume spread: the largest of the ranks'
    /// bounds can lie below the bound over all rows when the extreme volumes and the largest
    /// row sum sit on different ranks.
    pub(crate) fn viscous_rule_mut(&mut self) -> &mut ViscousRule {
        &mut self.viscous_rule
    }

    /// The solve parameters of the implicit viscous solve: `params` with `viscous_rel_tol`
    /// loosened to the last projection's candidate within `[min(rel_tol, viscous_rel_tol),
    /// rel_tol]` ([`SolveParams::viscous_adaptive`]) — the upper end the tolerance the last
    /// Poisson solve stopped at, `max(rel_tol, warm_tol ρ)` with [`SolveParams::warm_tol`]:
    /// never looser than the pressure's solve — and `rel_tol` raised to match (the tolerance
    /// the viscous solve stops at is `min(rel_tol, viscous_rel_tol)`).
    fn viscous_params(&self, params: &SolveParams) -> SolveParams {
        let mut v = *params;
        if params.viscous_adaptive && self.viscous_rule.loosen > 0.0 {
            let ceiling = params.poisson_rel_tol(self.viscous_rule.rho_last);
            v.viscous_rel_tol = self
                .viscous_rule
                .loosen
                .clamp(params.viscous_tol(), ceiling);
            v.rel_tol = ceiling;
        }
        v
    }

    /// The last implicit viscous solve (default when none ran; a step's own is its report's
    /// [`StepReport::viscous`], `None` when that step ran none).
    pub fn viscous_info(&self) -> SolveInfo {
        self.viscous_info
    }

    /// The warm start's history: the last increment `φⁿ` (`phi`), the one before (`φⁿ⁻¹`,
    /// empty before the second step) and the last step's `Δt` (0 before the first).
    pub fn warm_start(&self) -> (&[f64], &[f64], f64) {
        (&self.phi, &self.phi_prev, self.dt_prev)
    }

    /// Sets the warm start's history (see [`Self::warm_start`]): the particle decomposition
    /// hands it to a rank's rebuilt local simulation with the particles. Both vectors are
    /// indexed like the particles; the next step extrapolates from them when both cover every
    /// particle.
    pub fn set_warm_start(&mut self, phi: Vec<f64>, phi_prev: Vec<f64>, dt_prev: f64) {
        self.phi = phi;
        self.phi_prev = phi_prev;
        self.dt_prev = dt_prev;
        // the third level is not handed over: the next steps extrapolate linearly until the
        // history is three deep again
        self.warm.forget();
    }

    /// Dirichlet values `g` of the increment `φ` on the band for the following projections
    /// (indexed like the particles; only the entries of Dirichlet particles are read, a ghost
    /// of one takes its source's): the Poisson problem becomes `−Δh φ = D f` on the fluid with
    /// `φ = g` on the band — the band's pairs move `Σ_band 2d ω_j w_h(r_ij)/r_ij² g_j` to
    /// the right side of row `i` — and the correction's gradient reads `g` there. An empty
    /// vector (the default) is the paper's homogeneous problem `φ = 0`. Values that continue
    /// the fluid's `φ` smoothly into the band (e.g. extrapolated to a surface beyond it)
    /// remove the kink that `φ = 0` on a band of finite width leaves at its inner edge. With a
    /// [`HaloSync`] (a decomposed run) the owners' values are what counts: the projection
    /// overwrites the halo copies' entries with them.
    pub fn set_band_increment(&mut self, values: Vec<f64>) {
        self.band_phi = values;
    }

    /// Takes the band's Dirichlet values of the increment out (leaving `φ = 0` on the band), to
    /// be refilled and handed back with [`Self::set_band_increment`] without an allocation.
    pub fn take_band_increment(&mut self) -> Vec<f64> {
        std::mem::take(&mut self.band_phi)
    }

    /// The band's Dirichlet values of the increment ([`Self::set_band_increment`]; empty:
    /// zero).
    pub fn band_increment(&self) -> &[f64] {
        &self.band_phi
    }

    /// The singular part covers every particle (ghosts included), finite, with the sum-form
    /// source.
    pub(crate) fn check_singular(
        &self,
        role: &[Role],
        source: SourceKind,
    ) -> Result<(), InputError> {
        let Some(s) = &self.singular else {
            return Ok(());
        };
        if source != SourceKind::SumForm {
            return Err(InputError::Parameter {
                name: "singular part".into(),
                value: f64::NAN,
                reason: format!("needs the sum-form source, not {source:?}"),
            });
        }
        for (field, v) in [
            ("singular part (source)", &s.source),
            ("singular part (no-slip)", &s.no_slip),
        ] {
            if v.len() != role.len() {
                return Err(InputError::LengthMismatch {
                    field,
                    len: v.len(),
                    expected: role.len(),
                });
            }
            if let Some(i) = v.iter().position(|u| !u.iter().all(|c| c.is_finite())) {
                return Err(InputError::NonFinite { field, particle: i });
            }
        }
        Ok(())
    }

    /// Rejects band values that do not cover the particles or are not finite on the band.
    fn check_band_increment(&self, role: &[Role]) -> Result<(), InputError> {
        let g = &self.band_phi;
        if g.is_empty() {
            return Ok(());
        }
        let first = crate::boundary::first_ghost(role);
        if g.len() < first {
            return Err(InputError::LengthMismatch {
                field: "band increment",
                len: g.len(),
                expected: first,
            });
        }
        match (0..first).find(|&i| role[i] == Role::Dirichlet && !g[i].is_finite()) {
            Some(i) => Err(InputError::NonFinite {
                field: "band increment",
                particle: i,
            }),
            None => Ok(()),
        }
    }

    /// Sets the pressure of every particle and the held increment `φ` to zero: after a one-off
    /// [`project`](Self::project) of a field that did not come from a predictor, so that the next
    /// incremental [`predict`](Self::predict) does not re-apply its pressure (of order `ρ/Δt`).
    pub fn reset_pressure(&mut self, particles: &mut Particles<D>) {
        particles.p.iter_mut().for_each(|p| *p = 0.0);
        self.phi.iter_mut().for_each(|p| *p = 0.0);
        self.phi_prev.clear();
        self.warm.forget();
    }

    /// Predictor and projection on the same neighbour list: for particles that do not move
    /// during the step (Eulerian/ALE frames, or a caller that moves them afterwards). A
    /// Lagrangian loop calls [`predict`](Self::predict), moves the particles with `u*`, updates
    /// the list and then calls [`project`](Self::project), so that the divergence is removed on
    /// the configuration the particles will occupy.
    ///
    /// On return `particles.u` and `particles.p` hold `uⁿ⁺¹` and `pⁿ⁺¹` (ghosts refilled), and
    /// [`u_star`](Self::u_star) the predictor velocity. On error, `u` and `p` are unchanged
    /// (except their ghost values).
    pub fn step(
        &mut self,
        particles: &mut Particles<D>,
        nl: &NeighborList<D>,
        boundary: &dyn Boundary<D>,
        params: &ProjectionParams<D>,
        dt: f64,
        accel: Option<&[[f64; D]]>,
    ) -> Result<StepReport, Error> {
        let mut u_star = std::mem::take(&mut self.own_u_star);
        // predict and project see the same configuration here: the Poisson setup can always
        // run beside the predictor
        let overlap = std::mem::replace(&mut self.overlap_solve_setup, true);
        let pred = self.predict(particles, nl, boundary, params, dt, accel, &mut u_star);
        self.overlap_solve_setup = overlap;
        let r = pred.and_then(|pred| {
            let mut r = self.project(particles, nl, boundary, params, dt, &u_star)?;
            pred.add_to(&mut r);
            Ok(r)
        });
        self.own_u_star = u_star;
        r
    }

    /// `∇p/ρ` of the particles' pressure on the configuration of `nl`, with the predictor's
    /// gradient (`params.gradient`; pressure ghosts refilled first), into `out` (every
    /// particle). A Lagrangian driver evaluates it at both ends of a step to apply the pressure
    /// gradient with the trapezoidal rule along the trajectories.
    pub fn pressure_gradient_into(
        &mut self,
        particles: &mut Particles<D>,
        nl: &NeighborList<D>,
        boundary: &dyn Boundary<D>,
        params: &ProjectionParams<D>,
        out: &mut Vec<[f64; D]>,
    ) {
        let n = particles.len();
        if boundary.has_ghosts() {
            boundary.fill_pressure(
                &particles.x,
                &particles.role,
                &mut particles.p,
                params.rho_g(),
            );
        }
        out.clear();
        out.resize(n, [0.0; D]);
        self.gradient.kind = params.gradient;
        self.gradient.share_walls = !boundary.has_ghosts();
        self.gradient.prepare(nl, &particles.vol);
        self.gradient
            .apply_into(nl, &particles.vol, &particles.p, out);
        divide(out, params.rho);
    }

    /// The `∇p/ρ` the last [`project`](Self::project) kept
    /// ([`Self::keep_pressure_gradient`]), swapped into `out` when it is of this state — the
    /// configuration of `nl`, the pressures, volumes and `ρ` as they were then, and the same
    /// gradient in `params`; returns whether it was (`out` is left as it was otherwise, and
    /// [`Self::pressure_gradient_into`] gives the same). Served once.
    pub fn take_pressure_gradient(
        &mut self,
        particles: &Particles<D>,
        nl: &NeighborList<D>,
        params: &ProjectionParams<D>,
        out: &mut Vec<[f64; D]>,
    ) -> bool {
        let Some(key) = self.kept_pressure_gradient.1.take() else {
            return false;
        };
        if key
            != KeptGradientKey::of(
                nl,
                &particles.p,
                &particles.vol,
                params.rho,
                params.gradient,
            )
        {
            return false;
        }
        std::mem::swap(out, &mut self.kept_pressure_gradient.0);
        true
    }

    /// [`Self::pressure_gradient_into`] into a buffer of this step that the next
    /// [`predict`](Self::predict) call uses instead of computing the same `∇p/ρ` again: valid
    /// for that one call, which must see the same particles, configuration and parameters
    /// (the caller's guarantee). Returns the gradient.
    pub fn pressure_gradient_for_predictor(
        &mut self,
        particles: &mut Particles<D>,
        nl: &NeighborList<D>,
        boundary: &dyn Boundary<D>,
        params: &ProjectionParams<D>,
    ) -> &[[f64; D]] {
        let mut g = std::mem::take(&mut self.pressure_gradient_given.0);
        self.pressure_gradient_into(particles, nl, boundary, params, &mut g);
        self.pressure_gradient_given = (g, true);
        &self.pressure_gradient_given.0
    }

    /// The least-squares coefficients of the wall variant (velocities) for the configuration
    /// of `nl`, brought up to date here; the predictor's viscous Laplacian and the source read
    /// the same cache, so a driver's convective term computed from it costs no second build.
    pub fn velocity_least_squares(
        &mut self,
        nl: &NeighborList<D>,
        vol: &[f64],
        x: &[[f64; D]],
        role: &[crate::particles::Role],
    ) -> &crate::consistent::LsOperators<D> {
        self.gradient.update_walls(nl, vol, Some((x, role)));
        &self.gradient.ls_walls
    }

    /// The volume shift of the Lagrangian frame (`Shifting::volume` of `crate::flow`) into `out`
    /// (every particle; zero off the fluid): `δ_i = −β ∇h χ_i` with `−Δh χ = e` on the fluid
    /// rows, `e_i = ω̄/ω_i − 1` (`ω̄` the mean fluid volume: `mean_volume`, or this
    /// configuration's when `None`), solved with this step's Poisson solver to the relative
    /// tolerance `tol` (`Shifting::volume_tol` of `crate::flow`; no warm-start factor) on the
    /// configuration of `nl` (the matrix of the last projection when the configuration is the
    /// same), `χ` continued into the ghosts like a pressure without gravity (evenly: no shift
    /// through a wall). `Σ_i ω_i e_i = 0`, so the Neumann problem is compatible. The divergence
    /// of the displacement is `β e`: compressed regions (`ω_i < ω̄`) expand, emptied ones
    /// contract. Returns the root-mean-square of `e` over the fluid.
    ///
    /// A rank of a decomposed run (with a [`HaloSync`]) passes the mean over every rank's own
    /// particles; the solve is then the global one and `χ` of the copies is their owners'.
    /// Collective there: every rank calls it at the same point of the step.
    #[allow(clippy::too_many_arguments)]
    pub fn volume_shift_into(
        &mut self,
        particles: &Particles<D>,
        nl: &NeighborList<D>,
        boundary: &dyn Boundary<D>,
        params: &ProjectionParams<D>,
        beta: f64,
        tol: f64,
        mean_volume: Option<f64>,
        out: &mut Vec<[f64; D]>,
    ) -> Result<f64, Error> {
        let n = particles.len();
        self.diagnostics(particles, nl, params, None)?;
        let (role, vol) = (&particles.role, &particles.vol);
        let fluid = |i: usize| role[i] == Role::Fluid;
        let (sum_vol, count) = (0..n)
            .filter(|&i| fluid(i))
            .fold((0.0, 0usize), |(s, c), i| (s + vol[i], c + 1));
        out.clear();
        out.resize(n, [0.0; D]);
        let mut e = std::mem::take(&mut self.volume_e);
        e.clear();
        e.resize(n, 0.0);
        if count == 0 && self.halo.is_none() {
            self.volume_e = e;
            return Ok(0.0);
        }
        let mean_vol = mean_volume.unwrap_or(sum_vol / count.max(1) as f64);
        let mut sq = 0.0;
        for i in (0..n).filter(|&i| fluid(i)) {
            e[i] = mean_vol / vol[i] - 1.0;
            sq += e[i] * e[i];
        }
        let mut chi = std::mem::take(&mut self.volume_chi);
        chi.resize(n, 0.0);
        let solve = SolveParams {
            rel_tol: tol,
            warm_tol: 0.0,
            ..params.solve
        };
        let solved = self
            .solver
            .solve(nl, vol, role, &self.comps, &e, &mut chi, &solve);
        self.volume_e = e;
        if let Err(err) = solved {
            chi.clear();
            self.volume_chi = chi;
            return Err(err.into());
        }
        if let Some(h) = self.halo.as_mut() {
            h.scalar(&mut chi);
        }
        if boundary.has_ghosts() {
            boundary.fill_pressure(&particles.x, role, &mut chi, [0.0; D]);
        }
        crate::operators::grad_diff_into(nl, vol, &chi, out);
        self.volume_chi = chi;
        for (i, d) in out.iter_mut().enumerate() {
            *d = if fluid(i) {
                d.map(|g| -beta * g)
            } else {
                [0.0; D]
            };
        }
        Ok((sq / count.max(1) as f64).sqrt())
    }

    /// `(Σ e_i², count)` of the last volume shift's relative volume error over the fluid
    /// particles among the first `n` ([`Self::volume_shift_into`]; a rank of a decomposed run
    /// passes its own particles' count).
    pub fn volume_error_sums(&self, particles: &Particles<D>, n: usize) -> (f64, usize) {
        (0..n.min(self.volume_e.len()))
            .filter(|&i| particles.role[i] == Role::Fluid)
            .fold((0.0, 0), |(s, c), i| (s + self.volume_e[i].powi(2), c + 1))
    }

    /// The least-squares coefficients for the configuration of `nl`, brought up to date: the
    /// wall variant (velocities, as [`Self::velocity_least_squares`]) and the plain variant
    /// (pressures, whose ghosts carry the Neumann extension).
    pub fn least_squares(
        &mut self,
        nl: &NeighborList<D>,
        vol: &[f64],
        x: &[[f64; D]],
        role: &[crate::particles::Role],
        has_ghosts: bool,
    ) -> (
        &crate::consistent::LsOperators<D>,
        &crate::consistent::LsOperators<D>,
    ) {
        self.gradient.share_walls = !has_ghosts;
        self.gradient.update_walls(nl, vol, Some((x, role)));
        if has_ghosts {
            self.gradient.update_plain(nl, vol);
        }
        (&self.gradient.ls_walls, self.gradient.plain())
    }

    /// Connectivity (checked against `params.allowed_floating`) and `c0`, reused while the pair
    /// data, roles and volumes are those of the last call (with `params.reuse_diagnostics`).
    /// Connectivity (into `self.comps`), `c0`, the smallest spacing and the particles a
    /// floating component may leave disconnected, recomputed only when the pair data, roles
    /// or volumes changed (and `params.reuse_diagnostics`); the key's and the components'
    /// vectors are overwritten in place. `c0_known`: `c0` of these pair data and volumes
    /// when the caller has it (summed by the Poisson assembly).
    fn diagnostics(
        &mut self,
        particles: &Particles<D>,
        nl: &NeighborList<D>,
        params: &ProjectionParams<D>,
        c0_known: Option<f64>,
    ) -> Result<(f64, f64, usize), Error> {
        let roles = role_fingerprint(&particles.role);
        let k = &mut self.diagnostics_key;
        let hit = params.reuse_diagnostics
            && k.valid
            && k.epoch == nl.epoch()
            && k.generation == nl.generation()
            && k.roles == roles
            && k.vol == particles.vol;
        if !hit {
            k.valid = false;
            crate::diagnostics::connectivity_into(
                nl,
                &particles.role,
                &mut self.comps,
                &mut self.connectivity_scratch,
            );
            // (summed by the Poisson assembly of these pair data and volumes when it ran
            // first: Assembly::c0_of)
            let c0 = c0_known.unwrap_or_else(|| {
                semi_regularity(nl, &particles.vol, &particles.role, Region::Omega)
            });
            let spacing = min_spacing(nl, &particles.role, Region::Omega);
            self.diagnostics_values = (c0, spacing);
            let k = &mut self.diagnostics_key;
            (k.valid, k.epoch, k.generation, k.roles) = (true, nl.epoch(), nl.generation(), roles);
            k.vol.clone_from(&particles.vol);
        }
        let (c0, spacing) = self.diagnostics_values;
        self.disconnected.clear();
        let disconnected = match (
            self.comps.check(params.allowed_floating),
            params.disconnected,
        ) {
            (Ok(()), _) => 0,
            (Err(e), Disconnected::Fail) => return Err(e.into()),
            (Err(e), Disconnected::Float) => {
                if self.halo.is_some() {
                    self.disconnected.clone_from(&e.offending);
                }
                e.offending.len()
            }
        };
        Ok((c0, spacing, disconnected))
    }

    /// Predictor into `u_star` (resized to the particles; ghosts filled by the no-slip rule):
    ///
    /// `u* − θΔtν Δh u* = uⁿ + Δt ((1−θ) ν Δh uⁿ + g + accel − G pⁿ/ρ)` on the fluid, `u* = uⁿ`
    /// elsewhere (the pressure term only in the incremental schemes, `G` the gradient of
    /// [`ProjectionParams::gradient`]); `accel` is an optional extra acceleration per particle
    /// (the caller's own forces, or a convective term). The [`ProjectionPlan`] of `params`
    /// decides which terms run.
    ///
    /// Checks its input first ([`checks`]: lengths, finite values naming the particle, positive
    /// volumes, a neighbour list measured at these positions, ghosts placed and reaching `h`,
    /// `h` above the spacing) and, before the implicit viscous solve, h-connectivity. Particles
    /// are not modified except their ghost values.
    ///
    /// A Lagrangian loop moves its particles with `u_star` and then calls
    /// [`project`](Self::project) with it:
    ///
    /// ```
    /// use gpm::boundary::PeriodicBox;
    /// use gpm::geometry::{lattice, number_density_volumes};
    /// use gpm::kernel::Weight;
    /// use gpm::neighbors::{NeighborConfig, NeighborList, Periodicity};
    /// use gpm::particles::{Particles, Role};
    /// use gpm::projection::{ProjectionParams, ProjectionStep};
    ///
    /// let dx = 1.0 / 16.0;
    /// let periodic = Periodicity::all([0.0, 0.0], [1.0, 1.0]);
    /// let boundary = PeriodicBox { periodic };
    /// let mut particles = Particles::<2>::new();
    /// for x in lattice([0.0, 0.0], [1.0, 1.0], dx) {
    ///     let u = [(6.283 * x[1]).sin(), 0.5 * (6.283 * x[0]).cos()];
    ///     particles.push(x, u, 0.0, dx * dx, Role::Fluid);
    /// }
    /// let config = NeighborConfig::new_relative(Weight::WendlandC2, dx, 3.0, 0.3)
    ///     .with_periodicity(periodic);
    /// let mut nl = NeighborList::build(config, &particles.x)?;
    /// particles.vol = number_density_volumes(&nl);
    /// let params = ProjectionParams::<2>::new(0.01);
    /// let mut step = ProjectionStep::<2>::new();
    /// let (dt, mut u_star) = (0.01, Vec::new());
    ///
    /// let pred = step.predict(&mut particles, &nl, &boundary, &params, dt, None, &mut u_star)?;
    /// assert_eq!(u_star.len(), particles.len());
    /// assert!(pred.viscous.is_some()); // Crank–Nicolson by default
    /// // move with u*, then bring the list and the volumes to the new positions
    /// for (x, u) in particles.x.iter_mut().zip(&u_star) {
    ///     x[0] += dt * u[0];
    ///     x[1] += dt * u[1];
    ///     periodic.wrap(x);
    /// }
    /// nl.update(&particles.x)?;
    /// particles.vol = number_density_volumes(&nl);
    /// let mut report = step.project(&mut particles, &nl, &boundary, &params, dt, &u_star)?;
    /// pred.add_to(&mut report);
    /// assert!(report.div_after < report.div_before);
    /// # Ok::<(), gpm::Error>(())
    /// ```
    #[allow(clippy::too_many_arguments)]
    pub fn predict(
        &mut self,
        particles: &mut Particles<D>,
        nl: &NeighborList<D>,
        boundary: &dyn Boundary<D>,
        params: &ProjectionParams<D>,
        dt: f64,
        accel: Option<&[[f64; D]]>,
        u_star: &mut Vec<[f64; D]>,
    ) -> Result<Prediction, Error> {
        crate::math::in_pool(|| {
            self.predict_inner(particles, nl, boundary, params, dt, accel, u_star)
        })
    }

    #[allow(clippy::too_many_arguments)]
    fn predict_inner(
        &mut self,
        particles: &mut Particles<D>,
        nl: &NeighborList<D>,
        boundary: &dyn Boundary<D>,
        params: &ProjectionParams<D>,
        dt: f64,
        accel: Option<&[[f64; D]]>,
        u_star: &mut Vec<[f64; D]>,
    ) -> Result<Prediction, Error> {
        let t = Instant::now();
        check_dt(dt)?;
        params.validate()?;
        checks::check_configuration(particles, nl, boundary, checks::Reads { velocity: true })?;
        if let Some(extra) = accel {
            checks::check_field("accel", extra, &particles.role, false)?;
        }
        let plan = ProjectionPlan::new(params);
        // moving particles with an implicit viscous term: the Poisson matrix is assembled
        // first and the viscous one derived from it (Assembly::helmholtz_from), then the
        // Poisson factor (if any) and the predictor run side by side, both reading it
        // (with or without `overlap_solve_setup`, so that both give the same bits). The
        // assembly sums c0's rows in the pass that writes the values: the diagnostics below
        // take it from there instead of a pass of their own.
        let mut solver = std::mem::take(&mut self.solver);
        let t_assembly = Instant::now();
        let mut k = None;
        if plan.viscous_implicit
            && self.viscous.is_moving()
            && solver
                .assemble_ahead(nl, &particles.vol, &particles.role, &params.solve)
                .is_ok()
        {
            k = Some(std::mem::take(&mut solver.assembly));
        }
        let c0 = k.as_ref().and_then(|k| k.c0_of(nl));
        let assembly_time = t_assembly.elapsed();
        let mut ahead = None;
        if plan.viscous_implicit || self.overlap_solve_setup {
            // connectivity before any solve, the viscous one included
            if let Err(e) = self.diagnostics(particles, nl, params, c0) {
                if let Some(k) = k {
                    solver.assembly = k;
                }
                self.solver = solver;
                return Err(e);
            }
            if self.overlap_solve_setup {
                // the components, volumes and roles out of `self` while the predictor runs
                // beside the setup (into kept vectors: no allocation)
                let (mut vol, mut role) = std::mem::take(&mut self.ahead_inputs);
                vol.clone_from(&particles.vol);
                role.clone_from(&particles.role);
                self.diagnostics_key.valid = false;
                ahead = Some((std::mem::take(&mut self.comps), vol, role));
            }
        }
        // the assembly above counts to the predictor, as when it ran after the diagnostics
        let diagnostics_seconds = (t.elapsed() - assembly_time).as_secs_f64();
        let t = Instant::now()
            .checked_sub(assembly_time)
            .unwrap_or_else(Instant::now);
        // with `ahead`, the Poisson matrix of this configuration is factorised on one thread
        // while the predictor runs on the others (without it that branch is empty); a failure
        // there is left to `project`'s own solve, which meets the same inputs and reports it
        let (_, res) = rayon::join(
            || {
                if let Some((comps, vol, role)) = &ahead {
                    let _ = match &k {
                        Some(k) => solver.factor_ahead_of::<D>(k, comps, &params.solve),
                        None => solver.prepare(nl, vol, role, comps, &params.solve),
                    };
                }
            },
            || {
                self.predict_body(
                    particles,
                    nl,
                    boundary,
                    params,
                    dt,
                    accel,
                    u_star,
                    t,
                    diagnostics_seconds,
                    k.as_ref(),
                )
            },
        );
        if let Some(k) = k {
            solver.assembly = k;
        }
        self.solver = solver;
        if let Some((comps, vol, role)) = ahead {
            // the components back, still those of the key (the predictor moves nothing)
            self.comps = comps;
            self.ahead_inputs = (vol, role);
            self.diagnostics_key.valid = true;
        }
        // a given pressure gradient serves one call, used or not (an early error)
        self.pressure_gradient_given.1 = false;
        // the predictor stage lasts until both are done
        res.map(|p| Prediction {
            seconds: t.elapsed().as_secs_f64(),
            ..p
        })
    }

    /// The predictor after its checks: explicit terms, then the implicit viscous solve.
    #[allow(clippy::too_many_arguments)]
    fn predict_body(
        &mut self,
        particles: &mut Particles<D>,
        nl: &NeighborList<D>,
        boundary: &dyn Boundary<D>,
        params: &ProjectionParams<D>,
        dt: f64,
        accel: Option<&[[f64; D]]>,
        u_star: &mut Vec<[f64; D]>,
        t: Instant,
        diagnostics_seconds: f64,
        poisson: Option<&crate::poisson::Assembly>,
    ) -> Result<Prediction, Error> {
        let plan = ProjectionPlan::new(params);
        let n = particles.len();
        let rho = params.rho;
        if boundary.has_ghosts() {
            boundary.fill_velocity(&particles.x, &particles.role, &mut particles.u);
            boundary.fill_pressure(
                &particles.x,
                &particles.role,
                &mut particles.p,
                params.rho_g(),
            );
        }
        let role = &particles.role;
        let vol = &particles.vol;
        u_star.clone_from(&particles.u);
        let acc = &mut self.work_vec;
        acc.clear();
        acc.resize(n, [0.0; D]);
        let theta = plan.theta;
        if params.laplacian == LaplacianKind::LeastSquares && params.nu > 0.0 {
            // ν(Δˡˢ − θΔh) uⁿ explicit, θΔh implicit below
            let geometry = Some((&particles.x[..], &particles.role[..]));
            self.gradient.update_walls(nl, vol, geometry);
            self.gradient
                .ls_walls
                .laplacian_vec_into(nl, &particles.u, acc);
            if theta > 0.0 {
                let gp = &mut self.work_vec2;
                gp.resize(n, [0.0; D]);
                crate::operators::laplacian_vec_into(nl, vol, &particles.u, gp);
                for (a, g) in acc.iter_mut().zip(gp.iter()) {
                    for k in 0..D {
                        a[k] -= theta * g[k];
                    }
                }
            }
            for a in acc.iter_mut() {
                for v in a.iter_mut() {
                    *v *= params.nu;
                }
            }
        } else if plan.viscous_explicit {
            crate::operators::laplacian_vec_into(nl, vol, &particles.u, acc);
            let f = (1.0 - theta) * params.nu;
            for a in acc.iter_mut() {
                for v in a.iter_mut() {
                    *v *= f;
                }
            }
        }
        if params.free_surface {
            // a free surface is stress-free: its particles get no viscous term (their one-sided
            // Laplacian, explicit while the fluid's is implicit, is what would make them
            // unstable)
            for (a, r) in acc.iter_mut().zip(particles.role.iter()) {
                if *r == crate::particles::Role::Dirichlet {
                    *a = [0.0; D];
                }
            }
        }
        let (given, valid) = &mut self.pressure_gradient_given;
        let use_given = std::mem::take(valid) && given.len() == n && plan.pressure_gradient;
        if use_given {
            for (a, g) in acc.iter_mut().zip(given.iter()) {
                for k in 0..D {
                    a[k] -= g[k];
                }
            }
        } else if plan.pressure_gradient {
            let gp = &mut self.work_vec2;
            gp.resize(n, [0.0; D]);
            self.gradient.kind = params.gradient;
            self.gradient.share_walls = !boundary.has_ghosts();
            self.gradient.prepare(nl, vol);
            self.gradient.apply_into(nl, vol, &particles.p, gp);
            for (a, g) in acc.iter_mut().zip(gp.iter()) {
                for k in 0..D {
                    a[k] -= g[k] / rho;
                }
            }
        }
        let g = params.gravity;
        let has_g = plan.body_force;
        let band_moves = params.free_surface;
        for i in 0..n {
            if !(role[i].is_fluid() || band_moves && role[i] == crate::particles::Role::Dirichlet) {
                continue;
            }
            let a = &acc[i];
            let us = &mut u_star[i];
            for k in 0..D {
                let mut ak = a[k];
                if has_g {
                    ak += g[k];
                }
                if let Some(extra) = accel {
                    ak += extra[i][k];
                }
                us[k] += dt * ak;
            }
        }
        let mut viscous = None;
        if plan.viscous_implicit {
            // (I − θΔtν Δh) u* = r, no-slip ghosts as matrix entries
            let mut r = std::mem::take(&mut self.work_vec2);
            r.clone_from(u_star);
            let rule = |j: usize| match particles.role[j] {
                crate::particles::Role::Ghost { source, walls } => {
                    boundary.velocity_affine(walls, &particles.x[source as usize])
                }
                _ => ([1.0; D], [0.0; D]),
            };
            let solve = self.viscous_params(&params.solve);
            let info = self.viscous.solve_with_poisson(
                poisson,
                nl,
                &particles.vol,
                &particles.role,
                &rule,
                theta * dt * params.nu,
                &r,
                u_star,
                &solve,
            );
            self.work_vec2 = r;
            self.viscous_info = info?;
            viscous = Some(self.viscous_info);
        }
        if params.free_surface {
            // the band's u* is the water's below it (see stages::extend_to_band)
            if boundary.has_ghosts() {
                boundary.fill_velocity(&particles.x, &particles.role, u_star);
            }
            stages::extend_to_band(nl, &particles.role, u_star);
            // a copy's extension reads u* beyond the global solves: its owner's
            if let Some(h) = self.halo.as_mut() {
                sync_vector(h.as_mut(), u_star);
            }
        }
        Ok(Prediction {
            seconds: t.elapsed().as_secs_f64(),
            diagnostics_seconds,
            viscous,
        })
    }

    /// Projection of the predictor velocity `u_star` on the configuration described by `nl`
    /// (which may differ from the predictor's, e.g. after the particles moved with `u*`;
    /// ghosts may have been regenerated in between: `u_star` must cover every particle before
    /// the first ghost, and the ghosts' `u*` is refilled from their sources).
    /// Checks its input ([`checks`]) and connectivity before the solve, solves for `φ`, corrects
    /// velocity and pressure, and measures the divergence before and after the same way.
    ///
    /// On error in the checks, in the solve or in the result (a non-finite velocity),
    /// `particles.u` and `particles.p` are unchanged.
    ///
    /// With an incremental scheme the pressure is updated incrementally: a one-off projection
    /// of a field that did not come from [`predict`](Self::predict) leaves `p ~ ρ/Δt` that the
    /// next incremental predictor re-applies — use [`Scheme::NonIncremental`] for it, or
    /// [`reset_pressure`](Self::reset_pressure) afterwards:
    ///
    /// ```
    /// use gpm::boundary::Walls;
    /// use gpm::geometry::lattice;
    /// use gpm::kernel::Weight;
    /// use gpm::neighbors::NeighborConfig;
    /// use gpm::particles::{Particles, Role};
    /// use gpm::projection::{ProjectionParams, ProjectionStep, Scheme};
    /// use gpm::setup::{prepare, VolumeRule};
    ///
    /// let dx = 1.0 / 20.0;
    /// let walls = Walls::closed_box([0.0, 0.0], [1.0, 1.0]);
    /// let mut particles = Particles::<2>::new();
    /// for x in lattice([0.0, 0.0], [1.0, 1.0], dx) {
    ///     particles.push(x, [x[0], 0.0], 0.0, dx * dx, Role::Fluid); // div u = 1
    /// }
    /// let config = NeighborConfig::new_relative(Weight::WendlandC2, dx, 3.0, 0.0);
    /// let nl = prepare(&mut particles, &walls, config, VolumeRule::NumberDensity)?;
    /// let mut params = ProjectionParams::<2>::new(0.0);
    /// params.scheme = Scheme::NonIncremental; // a one-off projection: p = φ
    /// let u_star = particles.u.clone();
    /// let report = ProjectionStep::new().project(&mut particles, &nl, &walls, &params, 0.1, &u_star)?;
    /// assert!(report.div_after < report.div_before);
    /// assert!(report.stability_ratio <= 1.0);
    /// # Ok::<(), gpm::Error>(())
    /// ```
    pub fn project(
        &mut self,
        particles: &mut Particles<D>,
        nl: &NeighborList<D>,
        boundary: &dyn Boundary<D>,
        params: &ProjectionParams<D>,
        dt: f64,
        u_star: &[[f64; D]],
    ) -> Result<StepReport, Error> {
        crate::math::in_pool(|| self.project_inner(particles, nl, boundary, params, dt, u_star))
    }

    fn project_inner(
        &mut self,
        particles: &mut Particles<D>,
        nl: &NeighborList<D>,
        boundary: &dyn Boundary<D>,
        params: &ProjectionParams<D>,
        dt: f64,
        u_star: &[[f64; D]],
    ) -> Result<StepReport, Error> {
        let t = Instant::now();
        check_dt(dt)?;
        params.validate()?;
        checks::check_configuration(particles, nl, boundary, checks::Reads { velocity: false })?;
        checks::check_field("u_star", u_star, &particles.role, true)?;
        let n = particles.len();
        self.check_band_increment(&particles.role)?;
        self.check_singular(&particles.role, params.source)?;
        let mut report = StepReport {
            dt,
            ..Default::default()
        };
        let plan = ProjectionPlan::new(params);
        let rho = params.rho;
        let ghosts = boundary.has_ghosts();

        // 1. diagnostics that must pass before any solve (recomputed only when the pair graph,
        //    roles or volumes changed: they are functions of those alone)
        let (c0, spacing, disconnected) = self.diagnostics(particles, nl, params, None)?;
        report.connectivity = self.comps.summary();
        report.disconnected = disconnected;
        report.c0 = c0;
        report.min_spacing = spacing;
        report.timings.diagnostics = t.elapsed().as_secs_f64();
        let role = &particles.role;
        let vol = &particles.vol;
        // 2. u* on every particle, ghosts refilled from their sources
        self.u_star.clear();
        self.u_star
            .extend_from_slice(&u_star[..u_star.len().min(n)]);
        self.u_star.resize(n, [0.0; D]);
        if ghosts {
            boundary.fill_velocity(&particles.x, role, &mut self.u_star);
        }
        // warm start: the last increments extrapolated to this step's time (WarmStart)
        if self.phi.len() == n && self.phi_prev.len() == n && self.dt_prev > 0.0 {
            self.warm
                .extrapolate(&mut self.phi, &mut self.phi_prev, dt, self.dt_prev);
        } else {
            self.warm.forget();
            self.phi_prev.clone_from(&self.phi);
        }
        self.dt_prev = dt;
        let mut capture = self.capture.then(|| ProjectionCapture {
            x: particles.x.clone(),
            vol: vol.clone(),
            role: role.clone(),
            u_star: self.u_star.clone(),
            p_in: particles.p.clone(),
            phi_in: {
                let mut v = self.phi.clone();
                v.resize(n, 0.0);
                v
            },
            dt,
            singular: self.singular.clone(),
            ..Default::default()
        });

        // 3. source D f with f = −(ρ/Δt) u* on Ω (zero on the Dirichlet band, except for the
        //    least-squares divergence)
        let t = Instant::now();
        if ghosts && params.source_ghosts == VectorKind::RestWallsLinear {
            self.linear_ghosts
                .update(nl, &particles.x, role, boundary)?;
        }
        let f = &mut self.work_vec2;
        // (source_field reads the partners only under the rest-walls-linear rule)
        stages::source_field(
            &particles.x,
            role,
            boundary,
            params.source_ghosts,
            Some(&self.linear_ghosts),
            plan.source,
            -rho / dt,
            &self.u_star,
            f,
        );
        // the adaptive viscous tolerance's divergence gain, measured in the source's pass while
        // the last step's candidate could matter (see `ViscousRule::gain`)
        let adaptive = params.solve.viscous_adaptive;
        let measure = adaptive
            && (self.viscous_rule.gain == 0.0
                || self.viscous_rule.loosen > 0.1 * params.solve.viscous_tol());
        let gain = stages::divergence_gain_into(
            nl,
            vol,
            &particles.x,
            role,
            boundary,
            params.source_ghosts,
            plan.source,
            &mut self.gradient,
            f,
            &mut self.work_vec,
            &mut self.rhs,
            measure.then(|| self.halo.as_ref().and_then(|h| h.own()).unwrap_or(n)),
        );
        if measure {
            self.viscous_rule.gain = gain;
        }
        if let Some(s) = &self.singular {
            // the regular part's source: the divergence of −(ρ/Δt) u_s subtracted
            subtract_divergence(
                nl,
                vol,
                &s.source,
                -rho / dt,
                &mut self.work_scalar,
                &mut self.rhs,
            );
        }
        report.div_before = norm_l2(vol, &self.rhs, role, Region::Omega) / rho * dt;
        if self.halo.is_some() {
            self.source_divergence.clone_from(&self.rhs);
        }
        let f_l2 = norm_l2_vec(vol, f, role, Region::Omega);
        report.timings.source = t.elapsed().as_secs_f64();

        // 4. Poisson solve for the increment (φ = g on the band: its pairs move to the right side)
        let t = Instant::now();
        self.phi.resize(n, 0.0);
        let inhomogeneous = !self.band_phi.is_empty();
        if inhomogeneous {
            // a rank's halo copies take their owners' values (a copy's neighbourhood is cut)
            if let Some(h) = self.halo.as_mut() {
                h.scalar(&mut self.band_phi);
            }
            stages::add_band_values(nl, vol, role, &self.band_phi, &mut self.rhs);
        }
        report.solve = self.solver.solve(
            nl,
            vol,
            role,
            &self.comps,
            &self.rhs,
            &mut self.phi,
            &params.solve,
        )?;
        if inhomogeneous {
            stages::set_band_values(role, &self.band_phi, &mut self.phi);
        }
        self.warm.judge(&self.phi, role);
        // a rank of a decomposed run takes the candidate from the global sums instead
        if self.halo.is_none() {
            self.viscous_rule.update(
                adaptive,
                report.solve.initial_rel_residual,
                report.div_before,
                f_l2 * dt / rho,
            );
        }
        report.timings.solve = t.elapsed().as_secs_f64();

        // 5. correction and pressure update, into scratch (u and p untouched until it is checked)
        let t = Instant::now();
        let t_diag = Instant::now();
        let phi_h01 = norm_h01(nl, vol, &self.phi, role, Region::Omega);
        report.stability_ratio = stability_ratio(phi_h01, report.c0, f_l2, D);
        let diag_extra = t_diag.elapsed().as_secs_f64();
        let gphi = &mut self.work_vec;
        gphi.resize(n, [0.0; D]);
        self.gradient.kind = params.gradient;
        self.gradient.share_walls = !boundary.has_ghosts();
        self.gradient.prepare(nl, vol);
        if plan.rotational {
            // the rotational term with the source's divergence (∇̂h· by default)
            let mut rot = std::mem::take(&mut self.work);
            stages::divergence_into(
                nl,
                vol,
                &particles.x,
                role,
                boundary,
                VectorKind::Velocity,
                plan.source,
                &mut self.gradient,
                &self.u_star,
                &mut self.work_vec2,
                &mut rot,
            );
            if let Some(s) = &self.singular {
                subtract_divergence(nl, vol, &s.no_slip, 1.0, &mut self.work_scalar, &mut rot);
            }
            self.work = rot;
        }
        self.u_new.clone_from(&particles.u);
        self.p_new.clone_from(&particles.p);
        // the pressure first (it reads no gradient; smoothed), then ∇φ — with ∇pⁿ⁺¹ in the
        // same pass, as `pressure_gradient_into` takes it, when it is kept for the driver's
        // next step — and the velocity
        stages::update_pressure(role, params, &self.phi, &self.work, &mut self.p_new);
        if params.pressure_smoothing > 0.0 && plan.pressure_gradient {
            if let Some(h) = self.halo.as_mut() {
                h.scalar(&mut self.p_new);
            }
            if ghosts {
                boundary.fill_pressure(&particles.x, role, &mut self.p_new, params.rho_g());
            }
            stages::smooth_pressure(nl, vol, role, params.pressure_smoothing, &mut self.p_new);
        }
        self.kept_pressure_gradient.1 = None;
        if self.keep_pressure_gradient && self.halo.is_none() {
            if ghosts {
                boundary.fill_pressure(&particles.x, role, &mut self.p_new, params.rho_g());
            }
            let mut g = std::mem::take(&mut self.kept_pressure_gradient.0);
            g.resize(n, [0.0; D]);
            self.gradient
                .apply2_into(nl, vol, &self.phi, &self.p_new, gphi, &mut g);
            divide(&mut g, rho);
            let key = KeptGradientKey::of(nl, &self.p_new, vol, rho, params.gradient);
            self.kept_pressure_gradient = (g, Some(key));
        } else {
            self.gradient.apply_into(nl, vol, &self.phi, gphi);
        }
        stages::correct_velocity(role, params, dt, &self.u_star, gphi, &mut self.u_new);
        if ghosts {
            boundary.fill_velocity(&particles.x, role, &mut self.u_new);
            boundary.fill_pressure(&particles.x, role, &mut self.p_new, params.rho_g());
        }
        // a copy's corrected velocity reads φ beyond the global solve: its owner's (the
        // extension into the band and the measured divergence read it)
        // (the ghosts again from their sources, which the extension reads)
        if let Some(h) = self.halo.as_mut() {
            sync_vector(h.as_mut(), &mut self.u_new);
            if ghosts {
                boundary.fill_velocity(&particles.x, role, &mut self.u_new);
            }
        }
        if params.free_surface {
            stages::extend_to_band(nl, role, &mut self.u_new);
            if ghosts {
                boundary.fill_velocity(&particles.x, role, &mut self.u_new);
            }
        }
        report.timings.correction = t.elapsed().as_secs_f64() - diag_extra;

        // 6. measurement, the same way as div_before
        let t = Instant::now();
        report.div_after = stages::measure_divergence(
            nl,
            vol,
            &particles.x,
            role,
            boundary,
            params.source_ghosts,
            Some(&self.linear_ghosts),
            plan.source,
            &mut self.gradient,
            &self.u_new,
            &mut self.work_vec,
            &mut self.work_vec2,
            &mut self.rhs,
        );
        if let Some(s) = &self.singular {
            subtract_divergence(
                nl,
                vol,
                &s.source,
                1.0,
                &mut self.work_scalar,
                &mut self.rhs,
            );
            report.div_after = norm_l2(vol, &self.rhs, role, Region::Omega);
        }
        let (ke, vmax) = stages::energy(vol, role, rho, &self.u_new)?;
        report.correction_ratio = stages::correction_ratio(vol, role, &self.u_star, &self.u_new);
        report.kinetic_energy = ke;
        report.max_speed = vmax;
        std::mem::swap(&mut particles.u, &mut self.u_new);
        std::mem::swap(&mut particles.p, &mut self.p_new);
        if let Some(c) = capture.as_mut() {
            c.u_out = particles.u.clone();
            c.p_out = particles.p.clone();
            c.phi = self.phi.clone();
        }
        if capture.is_some() {
            self.captured = capture;
        }
        report.timings.diagnostics += diag_extra + t.elapsed().as_secs_f64();
        Ok(report)
    }
}

/// `out −= scale · ∇̂h·v` (the sum form, `v`'s ghosts as given); `work` is scratch.
fn subtract_divergence<const D: usize>(
    nl: &NeighborList<D>,
    vol: &[f64],
    v: &[[f64; D]],
    scale: f64,
    work: &mut Vec<f64>,
    out: &mut [f64],
) {
    work.resize(nl.len(), 0.0);
    crate::operators::div_sum_into(nl, vol, v, work);
    for (o, d) in out.iter_mut().zip(work.iter()) {
        *o -= scale * d;
    }
}

#[cfg(test)]
mod tests {
    use super::WarmStart;
    use crate::particles::Role;

    /// `φ(t)` at the particles: a quadratic in time (different per particle).
    fn phi_at(t: f64) -> Vec<f64> {
        (0..5)
            .map(|i| 1.0 + i as f64 - (0.5 + i as f64) * t + (2.0 - 0.3 * i as f64) * t * t)
            .collect()
    }

    /// The largest `|a_i − b_i|`.
    fn max_diff(a: &[f64], b: &[f64]) -> f64 {
        a.iter()
            .zip(b)
            .map(|(x, y)| (x - y).abs())
            .fold(0.0, f64::max)
    }

    /// Runs the history a projection keeps (`phi` = the last solution, `prev` = the one
    /// before; the first step has none to extrapolate from and copies) through the solutions
    /// `at(times[k])`: for each step `k ≥ 2` the guess, then `visit(k, w, guess)`, then the
    /// judge on the solution.
    fn replay(
        w: &mut WarmStart,
        times: &[f64],
        at: impl Fn(f64) -> Vec<f64>,
        role: &[Role],
        mut visit: impl FnMut(usize, &WarmStart, &[f64]),
    ) {
        let mut phi = at(times[0]);
        let mut prev = phi.clone();
        for k in 1..times.len() {
            let (dt, dt_prev) = (times[k] - times[k - 1], times[k - 1] - times[k.max(2) - 2]);
            if k == 1 {
                w.forget();
                prev.clone_from(&phi);
                phi = at(times[k]);
                continue;
            }
            w.extrapolate(&mut phi, &mut prev, dt, dt_prev);
            visit(k, w, &phi);
            phi = at(times[k]);
            w.judge(&phi, role);
        }
    }

    /// The quadratic guess through three unequal steps is exact for a quadratic in time, the
    /// linear one is not; the solve's judge then picks the quadratic order for the next step,
    /// and a history shorter than three levels gives the linear guess.
    #[test]
    fn the_warm_start_extrapolates_quadratics_exactly_and_keeps_the_nearer_order() {
        let role = vec![Role::Fluid; 5];
        let times = [0.0, 0.1, 0.25, 0.3, 0.42];
        let mut w = WarmStart::default();
        let mut guesses = Vec::new();
        replay(&mut w, &times, phi_at, &role, |k, w, guess| {
            guesses.push((k, guess.to_vec(), w.use_quadratic))
        });
        let exact = |k: usize| phi_at(times[k]);
        let err = |g: &[f64], k: usize| max_diff(g, &exact(k));
        // k = 2: two levels only, a linear guess (not exact for a quadratic)
        assert!(!guesses[0].2 && err(&guesses[0].1, 2) > 1e-3);
        // k = 3: three levels, but the order was not judged yet: linear, and the judge then
        // finds the quadratic guess nearer
        assert!(!guesses[1].2 && err(&guesses[1].1, 3) > 1e-3);
        // k = 4: quadratic, exact to round-off through the unequal steps
        assert!(guesses[2].2, "the judge kept the linear order");
        assert!(err(&guesses[2].1, 4) < 1e-13, "{}", err(&guesses[2].1, 4));
        // a reset history starts linear again
        w.forget();
        assert!(!w.use_quadratic && w.prev2.is_empty());
    }

    /// A cubic in time: once the history is four deep the cubic guess through unequal steps is
    /// exact, the judge picks it over the quadratic, and `forget` drops the fourth level.
    #[test]
    fn the_warm_start_extrapolates_cubics_exactly_once_four_levels_deep() {
        let role = vec![Role::Fluid; 4];
        let at = |t: f64| -> Vec<f64> {
            (0..4)
                .map(|i| 0.5 + i as f64 * t - 0.7 * t * t + (1.0 + 0.4 * i as f64) * t * t * t)
                .collect()
        };
        let times = [0.0, 0.1, 0.25, 0.3, 0.42, 0.5, 0.61];
        let mut w = WarmStart::default();
        let mut last = (Vec::new(), false);
        replay(&mut w, &times, at, &role, |k, w, guess| {
            last = (guess.to_vec(), w.use_cubic && w.cubic.len() == guess.len());
            if k >= 4 {
                // four levels: the cubic guess is formed, exact to round-off
                let e = max_diff(&w.cubic, &at(times[k]));
                assert!(e < 1e-13, "step {k}: cubic guess off by {e}");
            }
        });
        // the last guess was the cubic one, exact
        assert!(last.1, "the judge did not choose the cubic order");
        let e = max_diff(&last.0, &at(times[times.len() - 1]));
        assert!(e < 1e-13, "{e}");
        w.forget();
        assert!(!w.use_cubic && w.prev3.is_empty() && w.dt_prev3 == 0.0);
    }

    /// Increments that are rough in time (alternating): the linear guess is nearer, and the
    /// judge keeps the linear order.
    #[test]
    fn the_warm_start_keeps_the_linear_order_for_rough_increments() {
        let role = vec![Role::Fluid; 3];
        let mut w = WarmStart::default();
        let seq = |k: usize| -> Vec<f64> {
            let s = if k.is_multiple_of(2) { 1.0 } else { -1.0 };
            vec![1.0 + 0.01 * s, 2.0 - 0.01 * s, 3.0 + 0.01 * s]
        };
        let mut phi = seq(0);
        let mut prev = phi.clone();
        w.use_quadratic = true;
        for k in 1..8 {
            w.extrapolate(&mut phi, &mut prev, 0.1, 0.1);
            phi = seq(k);
            w.judge(&phi, &role);
        }
        assert!(!w.use_quadratic);
    }
}
