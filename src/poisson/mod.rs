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
//! Two solvers share [`PoissonSolver::solve`]: sparse Cholesky ([`direct`]) with symbolic reuse,
//! and Jacobi-preconditioned CG ([`iterative`]) with warm start.

pub mod assembly;
pub mod direct;
pub mod helmholtz;
pub mod iterative;

use crate::diagnostics::{alias, Components};
use crate::error::SolveError;
use crate::neighbors::NeighborList;
use crate::particles::Role;
use serde::{Deserialize, Serialize};
use std::time::Instant;

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
    /// Cholesky in 2D up to [`SolveParams::direct_limit`] unknowns, CG otherwise.
    #[default]
    Auto,
}

impl std::str::FromStr for SolverKind {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s.trim().to_ascii_lowercase().as_str() {
            "cholesky" | "direct" => Ok(SolverKind::Cholesky),
            "cg" | "pcg" => Ok(SolverKind::Cg),
            "auto" => Ok(SolverKind::Auto),
            _ => Err(format!(
                "unknown solver '{s}': expected cholesky, cg or auto"
            )),
        }
    }
}

impl std::fmt::Display for SolverKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            SolverKind::Cholesky => "cholesky",
            SolverKind::Cg => "cg",
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
    /// CG: iteration limit (default 10 000).
    pub max_iters: usize,
    /// CG: start from the previous solution held in `phi` (default true).
    pub warm_start: bool,
    /// Cholesky: reuse the symbolic analysis while the pattern is unchanged (default true).
    pub reuse_symbolic: bool,
    /// Cholesky: reuse the numeric factor while the matrix values are unchanged (default true).
    pub reuse_numeric: bool,
    /// Skip refilling the matrix values while the pair data (neighbour-list generation),
    /// volumes and coefficients are unchanged (default true).
    pub reuse_values: bool,
    /// `Auto`: largest 2D system solved directly (default 200 000 unknowns).
    pub direct_limit: usize,
}

impl Default for SolveParams {
    fn default() -> Self {
        SolveParams {
            solver: SolverKind::Auto,
            rel_tol: 1e-10,
            abs_tol: 0.0,
            max_iters: 10_000,
            warm_start: true,
            reuse_symbolic: true,
            reuse_numeric: true,
            reuse_values: true,
            direct_limit: 200_000,
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
}

/// Reusable solver state: matrix pattern and values, Cholesky caches, scratch.
#[derive(Debug, Default)]
pub struct PoissonSolver {
    /// The assembled matrix.
    pub assembly: Assembly,
    /// The direct solver's caches.
    pub direct: Direct,
    b: Vec<f64>,
    x: Vec<f64>,
}

impl PoissonSolver {
    /// A solver with empty caches.
    pub fn new() -> Self {
        Self::default()
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
        let pattern_rebuilt = self.assembly.update_pattern(nl, role);
        self.assembly.reuse_values = params.reuse_values;
        self.assembly.fill_values(nl, vol, role)?;
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
        let floating = components.floating();
        info.floating = floating.len();
        let mut members: Vec<Vec<u32>> = vec![Vec::new(); components.len()];
        if !floating.is_empty() {
            for (u, &p) in a.particle.iter().enumerate() {
                let c = components.label[p as usize];
                if c != u32::MAX && !components.anchored[c as usize] {
                    members[c as usize].push(u as u32);
                }
            }
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

        let kind = match params.solver {
            SolverKind::Auto => {
                if D == 2 && n <= params.direct_limit {
                    SolverKind::Cholesky
                } else {
                    SolverKind::Cg
                }
            }
            k => k,
        };
        info.solver = kind;
        self.x.resize(n, 0.0);
        match kind {
            SolverKind::Cholesky => {
                let pinned: Vec<u32> = floating
                    .iter()
                    .filter_map(|&c| members[c].first().copied())
                    .collect();
                let r = self.direct.solve(
                    a,
                    &pinned,
                    &self.b,
                    &mut self.x,
                    params.reuse_symbolic,
                    params.reuse_numeric,
                )?;
                info.reused_symbolic = r.symbolic;
                info.reused_numeric = r.numeric;
                info.symbolic_seconds = r.symbolic_seconds;
                info.numeric_seconds = r.numeric_seconds;
                info.solve_seconds = r.solve_seconds;
                let (abs, rel) = residual(a, &self.b, &self.x);
                info.abs_residual = abs;
                info.rel_residual = rel;
            }
            SolverKind::Cg | SolverKind::Auto => {
                let t = Instant::now();
                for (u, &p) in a.particle.iter().enumerate() {
                    self.x[u] = if params.warm_start && phi[p as usize].is_finite() {
                        phi[p as usize]
                    } else {
                        0.0
                    };
                }
                let r = iterative::pcg(
                    a,
                    &self.b,
                    &mut self.x,
                    params.rel_tol,
                    params.abs_tol,
                    params.max_iters,
                )?;
                info.iters = r.iters;
                info.abs_residual = r.abs_residual;
                info.rel_residual = r.rel_residual;
                info.solve_seconds = t.elapsed().as_secs_f64();
            }
        }
        // fix the constant of each floating component: zero ω-weighted mean
        for &c in &floating {
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
        Ok(info)
    }
}

fn residual(a: &Assembly, b: &[f64], x: &[f64]) -> (f64, f64) {
    let mut kx = vec![0.0; a.n()];
    a.spmv(x, &mut kx);
    let r = kx
        .iter()
        .zip(b)
        .map(|(k, b)| (b - k) * (b - k))
        .sum::<f64>()
        .sqrt();
    let bn = b.iter().map(|v| v * v).sum::<f64>().sqrt();
    (r, if bn > 0.0 { r / bn } else { 0.0 })
}
