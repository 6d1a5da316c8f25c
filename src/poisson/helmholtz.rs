//! Implicit viscous solves `(I − c Δh) u = r` for vector fields (componentwise), used by the
//! Crank–Nicolson / backward-Euler predictor.
//!
//! Multiplied by `ω_i` the system is symmetric positive definite: `H = W + c K_σ`
//! ([`Assembly::fill_helmholtz`]) with the no-slip images of the walls entering as `u_g = σ u_src
//! + b` (`σ = −1` across one wall, `+1` at a corner) and Dirichlet particles' given values moved
//! to the right side. The same factorisation serves every component; with fixed particles and a
//! fixed `Δt` it is computed once and reused for every step.

use super::amg::{AmgCache, AmgSetup};
use super::assembly::Assembly;
use super::direct::Direct;
use super::iterative::{pcg_in, pcg_multi_in, pcg_with_in, CgInfo, CgWork, Shifted};
use super::{SolveInfo, SolveParams, SolverKind};
use crate::diagnostics::alias;
use crate::error::SolveError;
use crate::neighbors::NeighborList;
use crate::particles::Role;
use rayon::prelude::*;
use std::time::Instant;

/// Reusable state of the implicit viscous solve.
#[derive(Debug, Default)]
pub struct HelmholtzSolver {
    /// The assembled matrix `H`.
    pub assembly: Assembly,
    /// Cholesky caches.
    pub direct: Direct,
    /// AMG hierarchy (used with [`SolverKind::Amg`]).
    pub amg: AmgCache,
    b: Vec<f64>,
    x: Vec<f64>,
    sigma: Vec<f64>,
    /// The ghosts' constants and the right side's constant part (`D` per particle, flat),
    /// and the CG vectors: kept between solves (no allocation in a moving run's step).
    consts: Vec<f64>,
    rhs_const: Vec<f64>,
    cg_work: CgWork,
    /// The last solve's change `u − r` at every particle (`D` per particle, flat) and its `c`:
    /// the next guess is `r + (c / c_last)(u − r)_last` (the change is `≈ c W⁻¹K u`, smooth
    /// in time; on moving particles it halves the iterations, see [`Self::solve`]).
    delta: Vec<f64>,
    c_last: f64,
    /// `ω` per unknown when the solve reads the Poisson matrix ([`Shifted`]).
    shift: Vec<f64>,
    /// `Auto`: numeric Cholesky factorisations caused by changed values.
    auto_factorisations: u32,
    /// Set by [`Self::assume_moving`].
    moving: bool,
    /// When set, every component's solve goes to this solver (the distributed CG on a rank's
    /// local system); the matrix is assembled here as always.
    pub external: Option<Box<dyn super::ExternalSolve>>,
}

impl HelmholtzSolver {
    /// An empty solver.
    pub fn new() -> Self {
        Self::default()
    }

    /// The warm start's history: the last solve's change `u − r` at every particle (`D` per
    /// particle, flat; entries of particles that were not unknowns are zero or stale) and
    /// the `c` it was solved with (0 before the first solve).
    pub fn warm_change(&self) -> (&[f64], f64) {
        (&self.delta, self.c_last)
    }

    /// Sets the warm start's history (see [`Self::warm_change`]): the particle decomposition
    /// hands it to a rank's rebuilt local simulation with the particles (indexed like them), so
    /// that its next solve starts from the guess the single process would take.
    pub fn set_warm_change(&mut self, delta: Vec<f64>, c_last: f64) {
        self.delta = delta;
        self.c_last = c_last;
    }

    /// Tells `Auto` that the matrix values will change at every solve (moving particles), so
    /// that it uses Jacobi-CG from the first solve instead of after two Cholesky
    /// refactorisations have shown it.
    pub fn assume_moving(&mut self) {
        self.auto_factorisations = self.auto_factorisations.max(2);
        self.moving = true;
    }

    /// True after [`Self::assume_moving`]: the matrix changes at every solve, so deriving it
    /// from the step's Poisson matrix ([`Assembly::helmholtz_from`]) pays.
    pub fn is_moving(&self) -> bool {
        self.moving
    }

    /// Solves `u_i − c Δh u_i = r_i` at the fluid particles for each component. `ghost_rule(j)`
    /// gives `(σ, b)` of ghost `j`, per component (`u_g[d] = σ[d] u_src[d] + b[d]`); Dirichlet
    /// particles keep the values in `u`. Writes the fluid rows of `u` (other rows are left as
    /// they are). When every ghost has the same `σ` for all components (no-slip walls) one
    /// matrix serves them all; otherwise (a free-slip wall: `σ = −1` for the normal component,
    /// `+1` for the tangential ones) each component has its own matrix and is solved in turn.
    /// With `params.warm_start` an iterative solve starts from `r + (c / c_last)(u − r)_last`,
    /// the right side plus the last solve's change scaled to this `c` ([`Self::warm_change`]).
    #[allow(clippy::too_many_arguments)]
    pub fn solve<const D: usize>(
        &mut self,
        nl: &NeighborList<D>,
        vol: &[f64],
        role: &[Role],
        ghost_rule: &dyn Fn(usize) -> ([f64; D], [f64; D]),
        c: f64,
        r: &[[f64; D]],
        u: &mut [[f64; D]],
        params: &SolveParams,
    ) -> Result<SolveInfo, SolveError> {
        self.solve_with_poisson(None, nl, vol, role, ghost_rule, c, r, u, params)
    }

    /// [`Self::solve`] with `poisson`, the Poisson matrix assembled for the same pairs, volumes
    /// and roles: the matrix is then derived from it ([`Assembly::helmholtz_from`]) rather than
    /// from the pairs (`None`, or a `poisson` of another configuration: from the pairs).
    #[allow(clippy::too_many_arguments)]
    pub fn solve_with_poisson<const D: usize>(
        &mut self,
        poisson: Option<&Assembly>,
        nl: &NeighborList<D>,
        vol: &[f64],
        role: &[Role],
        ghost_rule: &dyn Fn(usize) -> ([f64; D], [f64; D]),
        c: f64,
        r: &[[f64; D]],
        u: &mut [[f64; D]],
        params: &SolveParams,
    ) -> Result<SolveInfo, SolveError> {
        let uniform = (0..role.len())
            .filter(|&j| matches!(role[j], Role::Ghost { .. }))
            .all(|j| {
                let (s, _) = ghost_rule(j);
                s.iter().all(|&v| v == s[0])
            });
        if uniform {
            return self.solve_group(poisson, nl, vol, role, ghost_rule, c, r, u, params, 0..D);
        }
        let mut total: Option<SolveInfo> = None;
        for d in 0..D {
            let info = self.solve_group(
                poisson,
                nl,
                vol,
                role,
                ghost_rule,
                c,
                r,
                u,
                params,
                d..d + 1,
            )?;
            total = Some(match total {
                None => info,
                Some(t) => SolveInfo {
                    iters: t.iters + info.iters,
                    abs_residual: t.abs_residual.max(info.abs_residual),
                    rel_residual: t.rel_residual.max(info.rel_residual),
                    initial_rel_residual: t.initial_rel_residual.max(info.initial_rel_residual),
                    pattern_rebuilt: t.pattern_rebuilt || info.pattern_rebuilt,
                    reused_symbolic: t.reused_symbolic && info.reused_symbolic,
                    reused_numeric: t.reused_numeric && info.reused_numeric,
                    assemble_seconds: t.assemble_seconds + info.assemble_seconds,
                    symbolic_seconds: t.symbolic_seconds + info.symbolic_seconds,
                    numeric_seconds: t.numeric_seconds + info.numeric_seconds,
                    solve_seconds: t.solve_seconds + info.solve_seconds,
                    amg_setup_seconds: t.amg_setup_seconds + info.amg_setup_seconds,
                    ..info
                },
            });
        }
        Ok(total.expect("D ≥ 1 components"))
    }

    /// [`solve`](Self::solve) for the components `comps`, which share their ghosts' `σ`.
    // `d` runs over the components of each `u[p]`
    #[allow(clippy::too_many_arguments, clippy::needless_range_loop)]
    fn solve_group<const D: usize>(
        &mut self,
        poisson: Option<&Assembly>,
        nl: &NeighborList<D>,
        vol: &[f64],
        role: &[Role],
        ghost_rule: &dyn Fn(usize) -> ([f64; D], [f64; D]),
        c: f64,
        r: &[[f64; D]],
        u: &mut [[f64; D]],
        params: &SolveParams,
        comps: std::ops::Range<usize>,
    ) -> Result<SolveInfo, SolveError> {
        let t0 = Instant::now();
        let n = role.len();
        self.sigma.resize(n, 1.0);
        self.consts.clear();
        self.consts.resize(n * D, 0.0);
        let (consts, _) = self.consts.as_chunks_mut::<D>();
        for j in 0..n {
            if let Role::Ghost { source, .. } = role[j] {
                let (s, b) = ghost_rule(j);
                self.sigma[j] = s[comps.start];
                consts[j] = b;
                if role[source as usize] == Role::Dirichlet {
                    // the image of a band particle: a given value, σ u_src + b
                    let us = u[source as usize];
                    consts[j] = std::array::from_fn(|d| s[d] * us[d] + b[d]);
                }
            } else {
                self.sigma[j] = 1.0;
                if role[j] == Role::Dirichlet {
                    consts[j] = u[j];
                }
            }
        }
        self.assembly.within_h = params.pattern_within_h;
        self.assembly.keep_pairs = params.pattern_keep_pairs;
        self.assembly.reuse_values = params.reuse_values;
        // every component by one Jacobi-CG on `W + c K` read from the step's Poisson matrix
        // `K` without forming it, when the images add nothing to it (all `σ = 1`: no walls)
        let read_k = match poisson {
            Some(k)
                if self.external.is_none()
                    && comps.len() == D
                    && D > 1
                    && solver_kind::<D>(k.n(), params, self.auto_factorisations)
                        == SolverKind::Cg
                    && self.sigma.iter().all(|&s| s == 1.0)
                    && k.is_current(nl, role) =>
            {
                Some(k)
            }
            _ => None,
        };
        let pattern_rebuilt = match read_k {
            Some(_) => {
                self.assembly.discard_values();
                false
            }
            None => {
                let derived = poisson.and_then(|k| {
                    self.assembly
                        .helmholtz_from(k, nl, vol, role, 1.0, c, &self.sigma)
                });
                match derived {
                    Some(rebuilt) => rebuilt,
                    None => self
                        .assembly
                        .update_helmholtz(nl, vol, role, c, &self.sigma)?,
                }
            }
        };
        let a = read_k.unwrap_or(&self.assembly);
        let m = a.n();
        let two_d = 2.0 * D as f64;
        // constant parts: c ω_i ω_j a_ij b_j over ghost and Dirichlet neighbours (none in a
        // periodic box: the pass is skipped)
        let has_const = role.iter().any(|r| !r.is_fluid());
        self.rhs_const.clear();
        self.rhs_const.resize(m * D, 0.0);
        let (rhs_const, _) = self.rhs_const.as_chunks_mut::<D>();
        if has_const {
            rhs_const
                .par_iter_mut()
                .zip(a.particle.par_iter())
                .with_min_len(1024)
                .for_each(|(out, &p)| {
                    let p = p as usize;
                    for k in nl.row(p) {
                        let j = nl.indices()[k] as usize;
                        if !role[j].is_fluid() {
                            let w = c * two_d * vol[p] * vol[j] * nl.wr2()[k];
                            for d in comps.clone() {
                                out[d] += w * consts[j][d];
                            }
                        }
                    }
                });
        }
        let assemble_seconds = t0.elapsed().as_secs_f64();
        // the warm start: the right side plus the last change, scaled to this `c`
        self.delta.resize(n * D, 0.0);
        let scale = if self.c_last > 0.0 {
            c / self.c_last
        } else {
            0.0
        };
        let delta = std::mem::take(&mut self.delta);
        let guess = |u: &[[f64; D]], p: usize, d: usize| -> f64 {
            if params.warm_start {
                u[p][d] + scale * delta[p * D + d]
            } else {
                0.0
            }
        };
        // Auto: as for the Poisson problem, Cholesky in 2D up to the limit while its factor is
        // reused (fixed particles: two triangular solves; cavity n = 50 runs in 3.4 s against
        // 5.3 s with Jacobi-CG), Jacobi-CG with warm start otherwise — H = W + cK is dominated
        // by the mass term W, so Jacobi converges in a few iterations, while a factor recomputed
        // every step (moving particles) costs far more (examples/bench). AMG-CG on request.
        // tighter than the pressure's (see `SolveParams::viscous_rel_tol`), also for an
        // external solver, which stops at its system's `rel_tol` (and not at the pressure's
        // warm-start factor: the viscous tolerance has its own rule)
        let viscous_tol = params.viscous_tol();
        if let Some(ext) = self.external.as_mut() {
            let t = Instant::now();
            let params = &SolveParams {
                rel_tol: viscous_tol,
                warm_tol: 0.0,
                ..*params
            };
            self.b.resize(m * D, 0.0);
            self.x.resize(m * D, 0.0);
            let xs = nl.search_positions();
            let positions: Vec<f64> = a.particle.iter().flat_map(|&p| xs[p as usize]).collect();
            let weights: Vec<f64> = a.particle.iter().map(|&p| vol[p as usize]).collect();
            let mut info = SolveInfo {
                solver: SolverKind::Cg,
                unknowns: m,
                nnz: a.nnz(),
                pattern_rebuilt,
                assemble_seconds,
                rel_tol: viscous_tol,
                ..Default::default()
            };
            for d in comps.clone() {
                let (b, x) = (
                    &mut self.b[d * m..(d + 1) * m],
                    &mut self.x[d * m..(d + 1) * m],
                );
                for (uix, &p) in a.particle.iter().enumerate() {
                    let p = p as usize;
                    b[uix] = vol[p] * r[p][d] + rhs_const[uix][d];
                    x[uix] = guess(u, p, d);
                }
                let ri = ext.solve(super::ExternalSystem {
                    a,
                    b,
                    x,
                    null: &[],
                    positions: &positions,
                    dim: D,
                    params,
                    weights: &weights,
                    periods: &nl.config().periodic.len,
                })?;
                info.add_component(&ri);
                for (uix, &p) in a.particle.iter().enumerate() {
                    u[p as usize][d] = x[uix];
                }
            }
            info.solve_seconds = t.elapsed().as_secs_f64();
            self.delta = delta;
            remember(&mut self.delta, &a.particle, comps, r, u);
            self.c_last = c;
            return Ok(info);
        }
        let kind = solver_kind::<D>(m, params, self.auto_factorisations);
        let mut info = SolveInfo {
            solver: kind,
            unknowns: m,
            nnz: a.nnz(),
            pattern_rebuilt,
            assemble_seconds,
            ..Default::default()
        };
        self.b.resize(m * D, 0.0);
        self.x.resize(m * D, 0.0);
        for d in comps.clone() {
            for (uix, &p) in a.particle.iter().enumerate() {
                let p = p as usize;
                let v = vol[p] * r[p][d] + rhs_const[uix][d];
                if !v.is_finite() {
                    return Err(SolveError::NonFinite { particle: p });
                }
                self.b[d * m + uix] = v;
            }
        }
        if !matches!(kind, SolverKind::Cholesky | SolverKind::Auto) {
            info.rel_tol = viscous_tol;
        }
        match kind {
            SolverKind::Cholesky | SolverKind::Auto => {
                // one solve per component: faer's multi-column triangular solve measured
                // slower here (15 ms for two columns against 2 × 3.5 ms at 10⁴ unknowns)
                for d in comps.clone() {
                    let ri = self.direct.solve(
                        a,
                        &[],
                        &self.b[d * m..(d + 1) * m],
                        &mut self.x[d * m..(d + 1) * m],
                        params.reuse_symbolic,
                        params.reuse_numeric,
                    )?;
                    info.reused_symbolic = ri.symbolic;
                    info.reused_numeric = ri.numeric;
                    if d == comps.start
                        && params.solver == SolverKind::Auto
                        && params.reuse_numeric
                        && !ri.numeric
                    {
                        self.auto_factorisations += 1;
                    }
                    info.symbolic_seconds += ri.symbolic_seconds;
                    info.numeric_seconds += ri.numeric_seconds;
                    info.solve_seconds += ri.solve_seconds;
                }
            }
            SolverKind::Cg if comps.len() == D && D > 1 => {
                // every component at once: one pass over the matrix per product for all
                let t = Instant::now();
                for d in comps.clone() {
                    let x = &mut self.x[d * m..(d + 1) * m];
                    for (uix, &p) in a.particle.iter().enumerate() {
                        x[uix] = guess(u, p as usize, d);
                    }
                }
                let mut xs = self.x.chunks_mut(m);
                let xs: [&mut [f64]; D] =
                    std::array::from_fn(|_| xs.next().expect("one column per component"));
                let bs: [&[f64]; D] = std::array::from_fn(|d| &self.b[d * m..(d + 1) * m]);
                let op = if read_k.is_some() {
                    self.shift.clear();
                    self.shift
                        .extend(a.particle.iter().map(|&p| vol[p as usize]));
                    Shifted {
                        a,
                        scale: c,
                        shift: &self.shift,
                    }
                } else {
                    Shifted::plain(a)
                };
                let infos = pcg_multi_in(
                    &mut self.cg_work,
                    op,
                    bs,
                    xs,
                    viscous_tol,
                    params.abs_tol,
                    params.max_iters,
                )?;
                for ri in infos {
                    info.add_component(&ri);
                }
                info.solve_seconds = t.elapsed().as_secs_f64();
            }
            SolverKind::Cg | SolverKind::Amg => {
                let reuse = params.amg_reuse();
                if kind == SolverKind::Amg {
                    info.amg_setup = self.amg.prepare(a, reuse);
                    let h = self.amg.hierarchy().expect("prepared hierarchy");
                    info.amg_levels = h.stats().levels();
                    info.amg_operator_complexity = h.stats().operator_complexity();
                    if matches!(info.amg_setup, AmgSetup::Rebuilt | AmgSetup::Refreshed) {
                        info.amg_setup_seconds = h.stats().setup_seconds;
                    }
                }
                let t = Instant::now();
                let mut first: Option<CgInfo> = None;
                for d in comps.clone() {
                    let x = &mut self.x[d * m..(d + 1) * m];
                    for (uix, &p) in a.particle.iter().enumerate() {
                        x[uix] = guess(u, p as usize, d);
                    }
                    let b = &self.b[d * m..(d + 1) * m];
                    let ri = if kind == SolverKind::Amg {
                        pcg_with_in(
                            a,
                            b,
                            x,
                            viscous_tol,
                            params.abs_tol,
                            params.max_iters,
                            &mut self.amg.preconditioner(a),
                            &mut self.cg_work,
                        )?
                    } else {
                        pcg_in(
                            a,
                            b,
                            x,
                            viscous_tol,
                            params.abs_tol,
                            params.max_iters,
                            &mut self.cg_work,
                        )?
                    };
                    first.get_or_insert(ri);
                    info.add_component(&ri);
                }
                info.solve_seconds = t.elapsed().as_secs_f64();
                if let (SolverKind::Amg, Some(ri)) = (kind, first) {
                    self.amg.record(&ri, reuse);
                }
            }
        }
        self.delta = delta;
        for d in comps.clone() {
            for (uix, &p) in a.particle.iter().enumerate() {
                let v = self.x[d * m + uix];
                if !v.is_finite() {
                    return Err(SolveError::NonFinite {
                        particle: p as usize,
                    });
                }
                u[p as usize][d] = v;
            }
        }
        remember(&mut self.delta, &a.particle, comps.clone(), r, u);
        self.c_last = c;
        // ghosts alias fluid particles; keep the unused import honest
        debug_assert!(role
            .iter()
            .enumerate()
            .all(|(j, r)| !matches!(r, Role::Ghost { .. }) || alias(role, j).is_some()));
        Ok(info)
    }
}

/// The solver of `m` unknowns: `Auto` takes Cholesky in 2D up to the limit while its factor
/// is reused (fewer than two refactorisations so far), Jacobi-CG otherwise.
fn solver_kind<const D: usize>(m: usize, params: &SolveParams, factorisations: u32) -> SolverKind {
    match params.solver {
        SolverKind::Auto => {
            if D == 2 && m <= params.direct_limit && factorisations < 2 {
                SolverKind::Cholesky
            } else {
                SolverKind::Cg
            }
        }
        k => k,
    }
}

/// Stores the solve's change `u − r` of the components `comps` at the unknowns' particles in
/// `delta` (`D` per particle), the next solve's warm start.
fn remember<const D: usize>(
    delta: &mut [f64],
    particle: &[u32],
    comps: std::ops::Range<usize>,
    r: &[[f64; D]],
    u: &[[f64; D]],
) {
    for &p in particle {
        let p = p as usize;
        for d in comps.clone() {
            delta[p * D + d] = u[p][d] - r[p][d];
        }
    }
}
