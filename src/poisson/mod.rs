//! The discrete Poisson problem `−Δh u_i = b_i` on the fluid particles (Imoto 2019, eq. (3)),
//! generalised to walls with a Neumann condition (MISSION §3).
//!
//! Unknowns are the fluid particles; Dirichlet particles hold zero; ghost images take the value
//! of their source. Each component of the fluid neighbour graph is *anchored* (touches a
//! Dirichlet particle: `K` is SPD on it, Theorem 4.1) or *floating* (pure Neumann: singular with
//! the constants as null space). For a floating component the right-hand side is projected to
//! zero sum (the sum-form source already sums to zero when the discrete Gauss theorem holds; the
//! removed defect is reported) and the solution is fixed to zero ω-weighted mean.
//!
//! Three solvers share [`PoissonSolver::solve`]: sparse Cholesky ([`direct`]) with symbolic reuse,
//! Jacobi-preconditioned CG ([`iterative`]) with warm start, and CG preconditioned by a
//! smoothed-aggregation AMG V-cycle ([`amg`]) whose hierarchy is reused across solves
//! (values-only refresh, lagged refresh: [`amg::AmgCache`]). [`SolverKind::Auto`] takes
//! Cholesky for 2D systems up to [`SolveParams::direct_limit`] unknowns while the factor is
//! reused, and AMG-CG otherwise (always in 3D, where the Cholesky factor fills in far more, and
//! once the matrix values change every step).

pub mod amg;
pub mod assembly;
pub mod direct;
pub mod helmholtz;
pub mod iterative;

use crate::diagnostics::{alias, Components};
use crate::error::{InputError, SolveError};
use crate::neighbors::NeighborList;
use crate::particles::Role;
use serde::{Deserialize, Serialize};
use std::time::Instant;

pub use amg::{Amg, AmgCache, AmgParams, AmgReuse, AmgSetup};
pub use assembly::Assembly;
pub use direct::Direct;
pub use helmholtz::HelmholtzSolver;

/// Which linear solver.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum SolverKind {
    /// Sparse Cholesky (faer) with symbolic reuse.
    Cholesky,
    /// Jacobi-preconditioned conjugate gradients with warm start.
    Cg,
    /// Conjugate gradients preconditioned by a smoothed-aggregation AMG V-cycle, with warm
    /// start and a reused hierarchy ([`amg`]).
    Amg,
    /// Cholesky in 2D up to [`SolveParams::direct_limit`] unknowns while its factor can be
    /// reused (fixed particles); AMG-CG in 3D, above the limit, and from the second numeric
    /// refactorisation on (the matrix values change every step: moving particles).
    #[default]
    Auto,
}

impl std::str::FromStr for SolverKind {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s.trim().to_ascii_lowercase().as_str() {
            "cholesky" | "direct" => Ok(SolverKind::Cholesky),
            "cg" | "pcg" | "jacobi" | "cg-jacobi" => Ok(SolverKind::Cg),
            "amg" | "cg-amg" | "amg-cg" => Ok(SolverKind::Amg),
            "auto" => Ok(SolverKind::Auto),
            _ => Err(format!(
                "unknown solver '{s}': expected cholesky, cg, amg or auto"
            )),
        }
    }
}

impl std::fmt::Display for SolverKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            SolverKind::Cholesky => "cholesky",
            SolverKind::Cg => "cg",
            SolverKind::Amg => "amg",
            SolverKind::Auto => "auto",
        })
    }
}

/// Parameters of a solve.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SolveParams {
    /// Solver choice.
    pub solver: SolverKind,
    /// CG: stop when `‖r‖₂ ≤ rel_tol ‖b‖₂` (default `1e-10`).
    pub rel_tol: f64,
    /// CG: or when `‖r‖₂ ≤ abs_tol` (default `0`).
    pub abs_tol: f64,
    /// The implicit viscous solve ([`HelmholtzSolver`]) by CG: stop when
    /// `‖r‖₂ ≤ min(rel_tol, viscous_rel_tol) ‖b‖₂` (default `1e-12`). Tighter than the pressure's:
    /// its error enters the Poisson source `∇̂h·u*`, a field a thousand times smaller than `u*`,
    /// and a warm-started solve that stops just under a loose tolerance leaves an error that
    /// changes from step to step — creeping up while two iterations suffice, falling when a
    /// third is needed. The pressure's warm start extrapolates that jump as if it were the
    /// flow: 2D Taylor–Green, 10⁵ moving particles, `rel_tol = 1e-8` for both: one such step
    /// put the guess 2.7·10⁻⁴ off (against 2·10⁻⁷) and the next three solves took 11–12 AMG-CG
    /// iterations instead of 6.
    pub viscous_rel_tol: f64,
    /// Loosen the viscous solve's tolerance, up to `rel_tol`, by as much as the pressure's
    /// warm start can bear (default true): the projection sets the next viscous solve's
    /// tolerance to `θ ρ ‖Du*‖ / (G ‖u*‖)` within `[min(rel_tol, viscous_rel_tol), rel_tol]`,
    /// with `D` the source's divergence, `ρ` the last Poisson solve's `‖b − K φ₀‖/‖b‖` by CG
    /// ([`SolveInfo::initial_rel_residual`]; while it falls from step to step — a warm start
    /// still settling — `ρ²/ρ_before`: the viscous error stays in the history the next guesses
    /// extrapolate from), `G` a bound of `D`'s gain on a velocity error
    /// ([`crate::projection::stages::divergence_gain_into`]) and `θ = 0.1`, so that the viscous
    /// error moves the Poisson source by at most a tenth of the warm start's own residual
    /// (`‖Du*‖` and `‖u*‖` as the step measures them). Where that residual is small (fixed
    /// particles, the pure Lagrangian frame: `ρ ≈ 10⁻⁷`) the tolerance stays at
    /// `viscous_rel_tol`; where the particles are shifted every step (`ρ ≈ 5·10⁻²` at 2D 10⁵)
    /// it rises to `rel_tol`. Only with a source other than the adjoint one (which has no bound
    /// `G`), a Poisson solve by CG or AMG-CG and a viscous solve by CG. In a decomposed run
    /// every rank takes the candidate from the global values (`G` the largest of the ranks'
    /// bounds over their own rows, the norms summed over them, `ρ` the distributed solve's),
    /// so that the ranks stop their global viscous CG at the same tolerance.
    pub viscous_adaptive: bool,
    /// CG, the Poisson solve: a solve started from a warm start that predicted at least 90 % of
    /// the right side (`ρ = ‖b − K φ₀‖₂/‖b‖₂ ≤ 0.1`) also stops once it has cut that residual
    /// by `warm_tol`, at `‖r‖₂ ≤ max(rel_tol, warm_tol ρ) ‖b‖₂` ([`iterative::stop_tol`];
    /// default 0: off, `rel_tol` alone). On shifted particles the next step's move puts
    /// configuration noise of `ρ ≈ 1–8·10⁻²` of the source back into the problem; solving each
    /// step to `rel_tol = 10⁻¹⁰` of a source that is a few per cent new noise at the next step
    /// is the moving step's largest cost. Measured (README, *Performance*): the Lagrangian
    /// Taylor–Green vortex n = 100 to t = 2 and the shifted 2D 10⁵ bench step with
    /// `warm_tol = 10⁻³`. The divergence left after the projection rises with the tolerance
    /// (`div_after`); a poor warm start (the Lagrangian cavity's: `ρ` 0.18–8), a cold start
    /// and fixed particles once settled (`ρ ≈ 10⁻⁷`: `warm_tol ρ` below `rel_tol`) are left
    /// alone. A direct solve ignores it (a one-process run that factorises and a decomposed
    /// one that iterates then differ by the looser tolerance). The reported
    /// [`SolveInfo::rel_tol`] is the tolerance the solve stopped at; the viscous solve's
    /// adaptive tolerance ([`Self::viscous_adaptive`]) is capped by it instead of `rel_tol`.
    pub warm_tol: f64,
    /// CG: iteration limit (default 10 000).
    pub max_iters: usize,
    /// CG: start from the previous solution held in `phi` (default true).
    pub warm_start: bool,
    /// Cholesky: reuse the symbolic analysis while the pattern is unchanged (default true).
    pub reuse_symbolic: bool,
    /// Cholesky: reuse the numeric factor while the matrix values are unchanged; AMG: keep the
    /// hierarchy as it is while the matrix values are unchanged (default true).
    pub reuse_numeric: bool,
    /// Skip refilling the matrix values while the pair data (neighbour-list generation),
    /// volumes and coefficients are unchanged (default true).
    pub reuse_values: bool,
    /// `Auto`: largest 2D system solved directly (default 50 000 unknowns: at 10⁴ a reused
    /// Cholesky factor beats AMG-CG in the cavity, 2.9 s vs 10.3 s per run; at 10⁵ AMG-CG is
    /// faster, 141 vs 227 ms per periodic step, and needs a third of the memory).
    pub direct_limit: usize,
    /// `Auto`, the Poisson solve: largest 2D system still solved directly once its values change from step to
    /// step (moving particles; default 4 000 unknowns). A numeric refactorisation per step
    /// against an AMG-CG solve, measured on the Lagrangian cavity and Taylor–Green vortex
    /// (2 threads): 3 334 unknowns 7.6 vs 10.9 ms, 10 000 unknowns 66 vs 30 ms.
    pub moving_direct_limit: usize,
    /// AMG: when only the matrix values changed (same pattern), or a lagged hierarchy asks for a
    /// refresh, recompute the Galerkin operators on the existing aggregates and prolongators
    /// instead of rebuilding (default false since 2026-11-28). On moving particles the refresh
    /// on stale aggregates costs more iterations than it saves in setup: Lagrangian
    /// Taylor–Green n = 100 to t = 2, 7 205 AMG-CG iterations with it against 6 061 without
    /// (10.4–13.8 s against 10.5–12.0 s), the Lagrangian Re 100 cavity n = 100 to t = 2,
    /// 13 142 against 11 034 (23.3–30.9 s against 21.7–23.4 s); the moving Taylor–Green bench
    /// never asks for a refresh in 40 steps (the same iterations either way). It pays where the
    /// values change and the pattern's geometry does not (a uniform rescaling of the volumes
    /// gives the fresh build's iterations, `tests/amg.rs`).
    pub amg_reuse_values: bool,
    /// AMG: when only the matrix values changed, keep the hierarchy (lagged) while CG's
    /// iterations per decade of residual reduction stay within `amg_lag_factor` times those
    /// right after the last refresh (default true).
    pub amg_lag: bool,
    /// AMG: the lag threshold (default 1.5); a values-only refresh that is itself this much
    /// slower than right after the last full rebuild triggers a full rebuild.
    pub amg_lag_factor: f64,
    /// AMG: when the pattern changed but the unknowns are the same particles (moving particles
    /// with a rebuilt neighbour list), treat the new matrix as new values: keep the hierarchy
    /// (`amg_lag`) or its aggregates with new Galerkin operators (`amg_reuse_values`) until the
    /// iteration rate asks for a refresh or a rebuild (default true).
    pub amg_reuse_aggregates: bool,
    /// Matrix pattern of the pairs within `h` only (default true). With a neighbour skin
    /// (moving particles) the candidate list also holds pairs between `h` and `h + skin`,
    /// whose matrix entries are zero: kept in the pattern (false) it can be reused until the
    /// list is searched again, at the cost of carrying those zeros through every product
    /// (1.5× the entries at skin 0.3h); left out (true) the pattern follows the pair set and
    /// is rebuilt whenever the pair data change. No effect without a skin.
    pub pattern_within_h: bool,
    /// With `pattern_within_h`: the pattern kept while the neighbour list's set of pairs
    /// within `h` is unchanged ([`crate::neighbors::NeighborList::pair_set`]), only its
    /// values refilled, so that the caches keyed on the pattern (Cholesky's symbolic
    /// analysis, the AMG hierarchy's pattern) hold (default true). Off: a new pattern at every
    /// measure.
    pub pattern_keep_pairs: bool,
}

impl SolveParams {
    /// The implicit viscous solve's tolerance, `min(rel_tol, viscous_rel_tol)`: its stopping
    /// test, and the tight end of the adaptive one ([`Self::viscous_adaptive`]).
    pub fn viscous_tol(&self) -> f64 {
        self.rel_tol.min(self.viscous_rel_tol)
    }

    /// The relative tolerance a Poisson solve by CG stops at when its initial guess leaves
    /// `rho = ‖b − K φ₀‖₂/‖b‖₂`: `rel_tol`, or `warm_tol rho` where that is larger and the
    /// warm start predicted most of the right side ([`iterative::stop_tol`]).
    pub fn poisson_rel_tol(&self, rho: f64) -> f64 {
        iterative::stop_tol(0.0, self.rel_tol, self.warm_tol, 1.0, rho)
    }

    /// Checks the tolerances `rel_tol`, `abs_tol` and `viscous_rel_tol` (non-negative and
    /// finite), `warm_tol` (in `[0, 1)`), `max_iters`
    /// (at least 1) and `amg_lag_factor` (positive and finite), naming the first bad one by its
    /// key under `solve` (`solve.abs_tol`) and its value.
    pub fn validate(&self) -> Result<(), InputError> {
        for (name, v) in [
            ("solve.rel_tol", self.rel_tol),
            ("solve.abs_tol", self.abs_tol),
            ("solve.viscous_rel_tol", self.viscous_rel_tol),
        ] {
            if !(v >= 0.0 && v.is_finite()) {
                return Err(InputError::parameter(
                    name,
                    v,
                    "a tolerance must be non-negative and finite",
                ));
            }
        }
        if !(0.0..1.0).contains(&self.warm_tol) {
            return Err(InputError::parameter(
                "solve.warm_tol",
                self.warm_tol,
                "the warm-start factor must lie in [0, 1) (0: off)",
            ));
        }
        if self.max_iters == 0 {
            return Err(InputError::parameter(
                "solve.max_iters",
                0.0,
                "at least one iteration is needed",
            ));
        }
        if !(self.amg_lag_factor > 0.0 && self.amg_lag_factor.is_finite()) {
            return Err(InputError::parameter(
                "solve.amg_lag_factor",
                self.amg_lag_factor,
                "the lag threshold must be positive and finite",
            ));
        }
        Ok(())
    }

    /// The AMG reuse switches of these parameters.
    pub fn amg_reuse(&self) -> AmgReuse {
        AmgReuse {
            unchanged: self.reuse_numeric,
            values: self.amg_reuse_values,
            lag: self.amg_lag,
            lag_factor: self.amg_lag_factor,
            aggregates: self.amg_reuse_aggregates,
        }
    }

    /// The solver `Auto` resolves to for `n` unknowns in dimension `d` (other kinds unchanged).
    pub fn resolve(&self, d: usize, n: usize) -> SolverKind {
        match self.solver {
            SolverKind::Auto => {
                if d == 2 && n <= self.direct_limit {
                    SolverKind::Cholesky
                } else {
                    SolverKind::Amg
                }
            }
            k => k,
        }
    }
}

impl Default for SolveParams {
    fn default() -> Self {
        SolveParams {
            solver: SolverKind::Auto,
            rel_tol: 1e-10,
            abs_tol: 0.0,
            viscous_rel_tol: 1e-12,
            viscous_adaptive: true,
            warm_tol: 0.0,
            max_iters: 10_000,
            warm_start: true,
            reuse_symbolic: true,
            reuse_numeric: true,
            reuse_values: true,
            direct_limit: 50_000,
            moving_direct_limit: 4_000,
            amg_reuse_values: false,
            amg_lag: true,
            amg_lag_factor: 1.5,
            amg_reuse_aggregates: true,
            pattern_within_h: true,
            pattern_keep_pairs: true,
        }
    }
}

/// What a solve did.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct SolveInfo {
    /// The solver that ran.
    pub solver: SolverKind,
    /// Unknowns.
    pub unknowns: usize,
    /// Stored entries of the symmetric matrix.
    pub nnz: usize,
    /// CG iterations (0 for Cholesky).
    pub iters: usize,
    /// `‖ω∘b − K x‖₂` after the solve.
    pub abs_residual: f64,
    /// `‖ω∘b − K x‖₂ / ‖ω∘b‖₂`.
    pub rel_residual: f64,
    /// `‖ω∘b − K x₀‖₂ / ‖ω∘b‖₂` of the initial guess `x₀` (CG and AMG-CG, in one process or
    /// decomposed; the largest over the components of a viscous solve; 0 for a direct
    /// solve): how far the warm start was off.
    pub initial_rel_residual: f64,
    /// The relative tolerance the iterative solve stopped at, `‖r‖₂ ≤ rel_tol ‖b‖₂` (the
    /// Poisson solve's [`SolveParams::rel_tol`], or `warm_tol ρ` where [`SolveParams::warm_tol`]
    /// loosened it; the viscous solve's, adaptive or not, [`SolveParams::viscous_tol`]); 0 for
    /// a direct solve.
    pub rel_tol: f64,
    /// Floating components (each had its right side projected and its mean fixed).
    pub floating: usize,
    /// Largest `|Σ_C ω_i b_i| / Σ_C |ω_i b_i|` over floating components `C` before projection:
    /// zero when the discrete Gauss theorem holds exactly.
    pub compatibility_defect: f64,
    /// The pattern was rebuilt this solve.
    pub pattern_rebuilt: bool,
    /// Cholesky: the symbolic analysis was reused.
    pub reused_symbolic: bool,
    /// Cholesky: the numeric factor was reused.
    pub reused_numeric: bool,
    /// Seconds: pattern + values.
    pub assemble_seconds: f64,
    /// Seconds: symbolic analysis.
    pub symbolic_seconds: f64,
    /// Seconds: numeric factorisation.
    pub numeric_seconds: f64,
    /// Seconds: triangular solves or CG iterations.
    pub solve_seconds: f64,
    /// AMG: what was done to the hierarchy before this solve ([`AmgSetup::None`] without AMG).
    pub amg_setup: AmgSetup,
    /// AMG: levels of the hierarchy, the finest and the coarsest included.
    pub amg_levels: usize,
    /// AMG: operator complexity `Σ_l nnz(A_l) / nnz(A_0)`.
    pub amg_operator_complexity: f64,
    /// Seconds: AMG setup of this solve (rebuild or refresh; 0 when reused or lagged).
    pub amg_setup_seconds: f64,
}

impl SolveInfo {
    /// Takes the counts of the CG run of a scalar solve and the relative tolerance it stopped
    /// at ([`SolveParams::poisson_rel_tol`]).
    pub(crate) fn set_cg(&mut self, r: &iterative::CgInfo, params: &SolveParams) {
        self.iters = r.iters;
        self.abs_residual = r.abs_residual;
        self.rel_residual = r.rel_residual;
        self.initial_rel_residual = r.initial_rel_residual();
        self.rel_tol = params.poisson_rel_tol(self.initial_rel_residual);
    }

    /// Adds one CG run over a component of a vector solve: iterations summed, residuals the
    /// largest.
    pub(crate) fn add_component(&mut self, r: &iterative::CgInfo) {
        self.iters += r.iters;
        self.abs_residual = self.abs_residual.max(r.abs_residual);
        self.rel_residual = self.rel_residual.max(r.rel_residual);
        self.initial_rel_residual = self.initial_rel_residual.max(r.initial_rel_residual());
    }
}

/// The assembled system handed to an [`ExternalSolve`]: `K x = b` over the unknowns of `a`,
/// singular with the constants on each set of `null` (floating components, right side already
/// projected), `positions` the unknowns' coordinates (`dim` per unknown).
#[derive(Debug)]
pub struct ExternalSystem<'a> {
    /// The assembled matrix (full symmetric CSR).
    pub a: &'a Assembly,
    /// Right side `ω∘b`.
    pub b: &'a [f64],
    /// Initial guess on entry (warm start or zero), solution on return.
    pub x: &'a mut [f64],
    /// Unknowns of each floating component.
    pub null: &'a [&'a [u32]],
    /// Coordinates of the unknowns, `dim` numbers each.
    pub positions: &'a [f64],
    /// Dimension.
    pub dim: usize,
    /// Tolerances and iteration limit.
    pub params: &'a SolveParams,
    /// Volume `ω` of each unknown's particle (the weights of the floating components' means).
    pub weights: &'a [f64],
    /// Period of each axis (`dim` numbers; `0`: not periodic). A solver that groups unknowns
    /// by position (coarse aggregates) must unwrap periodic coordinates: a set of moving
    /// particles can straddle the periodic boundary.
    pub periods: &'a [f64],
}

/// A solver that replaces the built-in ones for the Poisson system (the domain-decomposed CG
/// of [`crate::distributed`]). It reports as [`SolverKind::Cg`] with its iterations.
pub trait ExternalSolve: Send + Sync + std::fmt::Debug {
    /// Solves the system in place.
    fn solve(&mut self, sys: ExternalSystem<'_>) -> Result<iterative::CgInfo, SolveError>;

    /// True when the solver itself makes the right side compatible and fixes the constant
    /// (zero `ω`-weighted mean) of the floating components, globally: a rank's local system
    /// cannot (its component is a piece of the global one). Then [`PoissonSolver::solve`]
    /// leaves `b` and the solution as they are. Default false.
    fn handles_null_space(&self) -> bool {
        false
    }
}

/// Reusable solver state: matrix pattern and values, Cholesky caches, AMG hierarchy, scratch.
#[derive(Debug, Default)]
pub struct PoissonSolver {
    /// When set, every [`Self::solve`] goes to this solver instead of the built-in ones.
    pub external: Option<Box<dyn ExternalSolve>>,
    /// The assembled matrix.
    pub assembly: Assembly,
    /// The direct solver's caches.
    pub direct: Direct,
    /// The AMG hierarchy and its reuse state (its `params` set the next rebuild).
    pub amg: AmgCache,
    b: Vec<f64>,
    x: Vec<f64>,
    /// `Auto`: numeric Cholesky factorisations so far (the first one is always needed).
    auto_factorisations: u32,
    /// The factorisation [`Self::prepare`] did for the next solve (reported by that solve).
    ahead: Option<direct::DirectReuse>,
    /// Set by [`Self::assume_moving`]: the Cholesky ordering is a nested dissection of the
    /// particles' positions ([`direct::nested_dissection`]) instead of AMD.
    moving: bool,
    /// The CG vectors, kept between solves.
    cg: iterative::CgWork,
    /// The floating components and their member unknowns, kept between solves.
    floating: Vec<usize>,
    members: Vec<Vec<u32>>,
}

impl PoissonSolver {
    /// A solver with empty caches.
    pub fn new() -> Self {
        Self::default()
    }

    /// Tells `Auto` that the matrix values will change at every solve (moving particles), so
    /// that it applies its moving-particle rule from the first solve instead of after two
    /// refactorisations have shown it (two Cholesky factorisations saved: 0.3 s of a
    /// Lagrangian Taylor–Green run at n = 100), and that the Cholesky ordering should be cheap
    /// to recompute (nested dissection, see [`direct::nested_dissection`]).
    pub fn assume_moving(&mut self) {
        self.auto_factorisations = self.auto_factorisations.max(2);
        self.moving = true;
    }

    /// Sets up the solve of [`Self::solve`] for these inputs ahead of the right side: the matrix
    /// assembled and, when the solver resolves to Cholesky, factorised. The next `solve` with
    /// the same matrix inputs then finds the factor current (and reports the work done here).
    /// [`crate::flow::Simulation`] runs it concurrently with the predictor, which does not
    /// touch the Poisson matrix.
    pub fn prepare<const D: usize>(
        &mut self,
        nl: &NeighborList<D>,
        vol: &[f64],
        role: &[Role],
        components: &Components,
        params: &SolveParams,
    ) -> Result<(), SolveError> {
        self.ahead = None;
        self.assemble(nl, vol, role, params)?;
        self.factor_ahead::<D>(components, params)
    }

    /// The part of [`Self::prepare`] after the assembly, for a matrix already assembled by
    /// [`Self::assemble_ahead`]: the Cholesky factor when that is the solver that will run.
    pub fn factor_ahead<const D: usize>(
        &mut self,
        components: &Components,
        params: &SolveParams,
    ) -> Result<(), SolveError> {
        let a = std::mem::take(&mut self.assembly);
        let r = self.factor_ahead_of::<D>(&a, components, params);
        self.assembly = a;
        r
    }

    /// [`Self::factor_ahead`] of the matrix `a` taken out of this solver (so that it can be read
    /// elsewhere meanwhile); the caller puts it back into [`Self::assembly`].
    pub(crate) fn factor_ahead_of<const D: usize>(
        &mut self,
        a: &Assembly,
        components: &Components,
        params: &SolveParams,
    ) -> Result<(), SolveError> {
        self.ahead = None;
        if self.external.is_none() && self.kind_for::<D>(a.n(), params) == SolverKind::Cholesky {
            let (mut floating, mut members) = (
                std::mem::take(&mut self.floating),
                std::mem::take(&mut self.members),
            );
            floating_members(a, components, &mut floating, &mut members);
            let pinned = pinned_unknowns(&members, &floating);
            let r = self
                .direct
                .factor(a, &pinned, params.reuse_symbolic, params.reuse_numeric)?;
            count_refactorisation(&mut self.auto_factorisations, params, &r);
            self.ahead = Some(r);
        }
        Ok(())
    }

    /// The first half of [`Self::prepare`]: the matrix brought up to date with the pair data,
    /// volumes and roles (so that the implicit viscous matrix can be derived from it, see
    /// [`Assembly::helmholtz_from`]); [`Self::factor_ahead`] is the second.
    pub fn assemble_ahead<const D: usize>(
        &mut self,
        nl: &NeighborList<D>,
        vol: &[f64],
        role: &[Role],
        params: &SolveParams,
    ) -> Result<(), SolveError> {
        self.ahead = None;
        self.assemble(nl, vol, role, params).map(|_| ())
    }

    /// The matrix brought up to date with the pair data, volumes and roles; true when the
    /// pattern was rebuilt.
    fn assemble<const D: usize>(
        &mut self,
        nl: &NeighborList<D>,
        vol: &[f64],
        role: &[Role],
        params: &SolveParams,
    ) -> Result<bool, SolveError> {
        self.assembly.within_h = params.pattern_within_h;
        self.assembly.keep_pairs = params.pattern_keep_pairs;
        self.assembly.reuse_values = params.reuse_values;
        let pattern_rebuilt = self.assembly.update_poisson(nl, vol, role)?;
        // moving particles: a new pattern every step, so the ordering's cost counts; nested
        // dissection on the particles' positions costs half of AMD's analysis for ~4 % more
        // fill (Lagrangian cavity n = 50: symbolic 2.8 -> 1.4 ms, numeric 2.9 -> 2.6 ms).
        // Fixed particles keep AMD (one analysis per run, and the same bits as before).
        let xs = nl.search_positions();
        if self.moving && pattern_rebuilt && xs.len() == role.len() {
            // (into the last step's vector: a moving step allocates nothing)
            let mut coords = self
                .direct
                .coordinates
                .take()
                .map(|(c, _)| c)
                .unwrap_or_default();
            coords.clear();
            coords.extend(self.assembly.particle.iter().flat_map(|&p| xs[p as usize]));
            self.direct.coordinates = Some((coords, D));
        }
        Ok(pattern_rebuilt)
    }

    /// The solver for the assembled matrix: `params.resolve`, except that `Auto` leaves
    /// Cholesky for AMG once refactorisations show the values change from step to step.
    fn kind<const D: usize>(&self, params: &SolveParams) -> SolverKind {
        self.kind_for::<D>(self.assembly.n(), params)
    }

    /// [`Self::kind`] for a matrix of `n` unknowns.
    fn kind_for<const D: usize>(&self, n: usize, params: &SolveParams) -> SolverKind {
        let kind = params.resolve(D, n);
        if params.solver == SolverKind::Auto
            && kind == SolverKind::Cholesky
            && self.auto_factorisations >= 2
            && n > params.moving_direct_limit
        {
            // the matrix values change from step to step (moving particles): refactorising
            // costs 2–12x an AMG-CG solve (examples/bench, 2D 10⁴ and 10⁵ moving)
            return SolverKind::Amg;
        }
        kind
    }

    /// Solves `−Δh φ_i = rhs_i` for the fluid particles `i`.
    ///
    /// * `rhs` holds the right side at each particle row (only fluid rows are read);
    /// * `phi` receives the solution at fluid particles, the source's value at ghosts and zero
    ///   at Dirichlet particles; with `warm_start` its fluid values are CG's initial guess;
    /// * `components` must come from [`crate::diagnostics::connectivity`] for the same list.
    ///
    /// Connectivity is the caller's check ([`Components::check`], which the projection runs
    /// before every solve). The solver itself treats every floating component alike: an isolated
    /// particle (no neighbour) is a floating component of one particle, gets `φ = 0`, and its
    /// source is dropped — visible only as a `compatibility_defect` of 1.
    ///
    /// ```
    /// use gpm::diagnostics::connectivity;
    /// use gpm::geometry::lattice;
    /// use gpm::kernel::Weight;
    /// use gpm::neighbors::{NeighborConfig, NeighborList};
    /// use gpm::operators::laplacian;
    /// use gpm::particles::Role;
    /// use gpm::poisson::{PoissonSolver, SolveParams, SolverKind};
    ///
    /// // the paper's problem: a Dirichlet band of width ≥ h around the fluid of the unit square
    /// let dx = 1.0 / 16.0;
    /// let h = 3.0 * dx;
    /// let x = lattice([-h, -h], [1.0 + h, 1.0 + h], dx);
    /// let inside = |p: &[f64; 2]| p.iter().all(|&c| c > 0.0 && c < 1.0);
    /// let role: Vec<Role> =
    ///     x.iter().map(|p| if inside(p) { Role::Fluid } else { Role::Dirichlet }).collect();
    /// let nl = NeighborList::build(NeighborConfig::new(Weight::WendlandC2, h, 0.0), &x)?;
    /// let vol = vec![dx * dx; x.len()];
    /// let comps = connectivity(&nl, &role);
    /// comps.check(0)?; // h-connected to the band: K is SPD (Theorem 4.1)
    ///
    /// // right side −Δh u of a known u that vanishes on the band: the solve recovers u
    /// let u: Vec<f64> = x.iter().zip(&role).map(|(p, r)| {
    ///     if r.is_fluid() { (std::f64::consts::PI * p[0]).sin() * p[1] * (1.0 - p[1]) } else { 0.0 }
    /// }).collect();
    /// let rhs: Vec<f64> = laplacian(&nl, &vol, &u).iter().map(|v| -v).collect();
    /// let mut phi = vec![0.0; x.len()];
    /// let mut params = SolveParams::default();
    /// for solver in [SolverKind::Cholesky, SolverKind::Cg, SolverKind::Amg] {
    ///     params.solver = solver;
    ///     params.rel_tol = 1e-12;
    ///     let info = PoissonSolver::new().solve(&nl, &vol, &role, &comps, &rhs, &mut phi, &params)?;
    ///     let err = (0..x.len()).map(|i| (phi[i] - u[i]).abs()).fold(0.0, f64::max);
    ///     assert!(err < 1e-8, "{solver:?}: error {err:e} after {} iterations", info.iters);
    /// }
    /// # Ok::<(), gpm::Error>(())
    /// ```
    #[allow(clippy::too_many_arguments)]
    pub fn solve<const D: usize>(
        &mut self,
        nl: &NeighborList<D>,
        vol: &[f64],
        role: &[Role],
        components: &Components,
        rhs: &[f64],
        phi: &mut [f64],
        params: &SolveParams,
    ) -> Result<SolveInfo, SolveError> {
        let t0 = Instant::now();
        let ahead = self.ahead.take();
        let pattern_rebuilt = self.assemble(nl, vol, role, params)?;
        let a = &self.assembly;
        let n = a.n();
        let mut info = SolveInfo {
            unknowns: n,
            nnz: a.nnz(),
            pattern_rebuilt,
            ..Default::default()
        };
        self.b.resize(n, 0.0);
        for (u, &p) in a.particle.iter().enumerate() {
            let p = p as usize;
            self.b[u] = vol[p] * rhs[p];
            if !self.b[u].is_finite() {
                return Err(SolveError::NonFinite { particle: p });
            }
        }
        // floating components: members (as unknowns), right side projected to zero sum
        let (mut floating, mut members) = (
            std::mem::take(&mut self.floating),
            std::mem::take(&mut self.members),
        );
        floating_members(a, components, &mut floating, &mut members);
        info.floating = floating.len();
        let global_null = self
            .external
            .as_ref()
            .is_some_and(|e| e.handles_null_space());
        if !floating.is_empty() && !global_null {
            for &c in &floating {
                let m = &members[c];
                let sum_b: f64 = m.iter().map(|&u| self.b[u as usize]).sum();
                let abs_b: f64 = m.iter().map(|&u| self.b[u as usize].abs()).sum();
                let sum_w: f64 = m
                    .iter()
                    .map(|&u| vol[a.particle[u as usize] as usize])
                    .sum();
                if abs_b > 0.0 {
                    info.compatibility_defect = info.compatibility_defect.max(sum_b.abs() / abs_b);
                }
                let mean = sum_b / sum_w;
                for &u in m {
                    self.b[u as usize] -= vol[a.particle[u as usize] as usize] * mean;
                }
            }
        }
        info.assemble_seconds = t0.elapsed().as_secs_f64();

        let kind = match self.external {
            Some(_) => SolverKind::Cg,
            None => self.kind::<D>(params),
        };
        info.solver = kind;
        self.x.resize(n, 0.0);
        if let Some(ext) = self.external.as_mut() {
            for (u, &p) in a.particle.iter().enumerate() {
                let v = phi[p as usize];
                self.x[u] = if params.warm_start && v.is_finite() {
                    v
                } else {
                    0.0
                };
            }
            let xs = nl.search_positions();
            let positions: Vec<f64> = a.particle.iter().flat_map(|&p| xs[p as usize]).collect();
            let null: Vec<&[u32]> = floating.iter().map(|&c| members[c].as_slice()).collect();
            let weights: Vec<f64> = a.particle.iter().map(|&p| vol[p as usize]).collect();
            let t = Instant::now();
            let r = ext.solve(ExternalSystem {
                a,
                b: &self.b,
                x: &mut self.x,
                null: &null,
                positions: &positions,
                dim: D,
                params,
                weights: &weights,
                periods: &nl.config().periodic.len,
            })?;
            info.solve_seconds = t.elapsed().as_secs_f64();
            info.set_cg(&r, params);
        } else {
            match kind {
                SolverKind::Cholesky => {
                    let pinned = pinned_unknowns(&members, &floating);
                    let mut r = self.direct.solve(
                        a,
                        &pinned,
                        &self.b,
                        &mut self.x,
                        params.reuse_symbolic,
                        params.reuse_numeric,
                    )?;
                    match ahead {
                        // the factor prepared ahead was the one used: report its work
                        Some(f) if r.symbolic && r.numeric => {
                            r.symbolic = f.symbolic;
                            r.numeric = f.numeric;
                            r.symbolic_seconds = f.symbolic_seconds;
                            r.numeric_seconds = f.numeric_seconds;
                        }
                        _ => count_refactorisation(&mut self.auto_factorisations, params, &r),
                    }
                    info.reused_symbolic = r.symbolic;
                    info.reused_numeric = r.numeric;
                    info.symbolic_seconds = r.symbolic_seconds;
                    info.numeric_seconds = r.numeric_seconds;
                    info.solve_seconds = r.solve_seconds;
                    let (abs, rel) = residual(a, &self.b, &self.x);
                    info.abs_residual = abs;
                    info.rel_residual = rel;
                }
                SolverKind::Cg | SolverKind::Amg | SolverKind::Auto => {
                    self.cg.set_warm_tol(params.warm_tol);
                    for (u, &p) in a.particle.iter().enumerate() {
                        self.x[u] = if params.warm_start && phi[p as usize].is_finite() {
                            phi[p as usize]
                        } else {
                            0.0
                        };
                    }
                    let r = if kind == SolverKind::Amg {
                        let reuse = params.amg_reuse();
                        info.amg_setup = self.amg.prepare(a, reuse);
                        let h = self.amg.hierarchy().expect("prepared hierarchy");
                        info.amg_levels = h.stats().levels();
                        info.amg_operator_complexity = h.stats().operator_complexity();
                        if matches!(info.amg_setup, AmgSetup::Rebuilt | AmgSetup::Refreshed) {
                            info.amg_setup_seconds = h.stats().setup_seconds;
                        }
                        let t = Instant::now();
                        // the null sets on the stack for up to four floating components
                        let mut few: [&[u32]; 4] = [&[]; 4];
                        let many: Vec<&[u32]>;
                        let null: &[&[u32]] = if floating.len() <= few.len() {
                            for (slot, &c) in few.iter_mut().zip(&floating) {
                                *slot = &members[c];
                            }
                            &few[..floating.len()]
                        } else {
                            many = floating.iter().map(|&c| members[c].as_slice()).collect();
                            &many
                        };
                        let r = iterative::pcg_with_null_in(
                            a,
                            &self.b,
                            &mut self.x,
                            params.rel_tol,
                            params.abs_tol,
                            params.max_iters,
                            &mut self.amg.preconditioner(a),
                            null,
                            &mut self.cg,
                        )?;
                        info.solve_seconds = t.elapsed().as_secs_f64();
                        self.amg.record(&r, reuse);
                        r
                    } else {
                        let t = Instant::now();
                        let r = iterative::pcg_in(
                            a,
                            &self.b,
                            &mut self.x,
                            params.rel_tol,
                            params.abs_tol,
                            params.max_iters,
                            &mut self.cg,
                        )?;
                        info.solve_seconds = t.elapsed().as_secs_f64();
                        r
                    };
                    info.set_cg(&r, params);
                }
            }
        }
        // fix the constant of each floating component: zero ω-weighted mean
        for &c in floating.iter().filter(|_| !global_null) {
            let m = &members[c];
            let sw: f64 = m
                .iter()
                .map(|&u| vol[a.particle[u as usize] as usize])
                .sum();
            let sx: f64 = m
                .iter()
                .map(|&u| vol[a.particle[u as usize] as usize] * self.x[u as usize])
                .sum();
            let mean = sx / sw;
            for &u in m {
                self.x[u as usize] -= mean;
            }
        }
        // scatter: fluid values, ghosts from their source, Dirichlet zero
        for (i, v) in phi.iter_mut().enumerate() {
            *v = match alias(role, i) {
                Some(s) => self.x[a.unknown[s] as usize],
                None => 0.0,
            };
        }
        if let Some(u) = self.x.iter().position(|v| !v.is_finite()) {
            return Err(SolveError::NonFinite {
                particle: a.particle[u] as usize,
            });
        }
        (self.floating, self.members) = (floating, members);
        Ok(info)
    }
}

/// The floating components of `components` and, per component, its member unknowns (filled
/// for the floating ones only).
fn floating_members(
    a: &Assembly,
    components: &Components,
    floating: &mut Vec<usize>,
    members: &mut Vec<Vec<u32>>,
) {
    floating.clear();
    floating.extend((0..components.len()).filter(|&c| !components.anchored[c]));
    members.resize_with(components.len(), Vec::new);
    members.iter_mut().for_each(Vec::clear);
    if !floating.is_empty() {
        for (u, &p) in a.particle.iter().enumerate() {
            let c = components.label[p as usize];
            if c != u32::MAX && !components.anchored[c as usize] {
                members[c as usize].push(u as u32);
            }
        }
    }
}

/// One unknown fixed to zero per floating component (its first member): the SPD system the
/// direct solver factorises.
fn pinned_unknowns(members: &[Vec<u32>], floating: &[usize]) -> Vec<u32> {
    floating
        .iter()
        .filter_map(|&c| members[c].first().copied())
        .collect()
}

/// Counts a refactorisation caused by changed values (not by reuse switched off) for `Auto`.
fn count_refactorisation(count: &mut u32, params: &SolveParams, r: &direct::DirectReuse) {
    if params.solver == SolverKind::Auto && params.reuse_numeric && !r.numeric {
        *count += 1;
    }
}

fn residual(a: &Assembly, b: &[f64], x: &[f64]) -> (f64, f64) {
    let r = iterative::true_residual(a, b, x);
    let bn = b.iter().map(|v| v * v).sum::<f64>().sqrt();
    (r, if bn > 0.0 { r / bn } else { 0.0 })
}
