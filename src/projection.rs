//! The incremental pressure-Poisson projection step (MISSION §4), as a module a particle code can
//! call from its own loop.
//!
//! Given `xⁿ, uⁿ, pⁿ` and a neighbour list at `xⁿ`, one [`ProjectionStep::step`]:
//!
//! 1. checks h-connectivity (before any solve) and computes `c0`;
//! 2. predicts `u* − θΔtν Δh u* = uⁿ + Δt ((1−θ) ν Δh uⁿ + g + a_extra − ∇h pⁿ / ρ)` (the
//!    pressure term only in the incremental schemes; `θ = ½` is Crank–Nicolson, solved with a
//!    symmetric Helmholtz system, `θ = 0` is explicit);
//! 3. solves `−Δh φ = ∇̂h·f` with `f = −(ρ/Δt) u*` (sum-form divergence for the source);
//! 4. corrects `uⁿ⁺¹ = u* − (Δt/ρ) ∇h φ` (difference gradient) and sets
//!    `pⁿ⁺¹ = φ` (non-incremental), `pⁿ + φ` (standard incremental) or
//!    `pⁿ + φ − ρθν ∇̂h·u*` (rotational incremental, Timmermans et al. 1996, with `θ` the
//!    implicit weight of the viscous term);
//! 5. returns a [`StepReport`] with the diagnostics: connectivity, `c0`, the Theorem 4.5 ratio
//!    `‖φ‖_h01 / (√(d c0) ‖f‖_ℓ2)`, the solve, divergence before and after, energy and timings.
//!
//! The pair `∇̂h·` / `∇h` is discretely adjoint (Lemma 4.3), which is why the source uses one and
//! the correction the other. Advection and particle shifting are the caller's business (see
//! [`crate::flow`] for a complete solver). The step holds only scratch memory: the caller owns
//! the particles.

use crate::boundary::{Boundary, VectorKind};
use crate::consistent::{GradientKind, GradientOperator};
use crate::diagnostics::{
    connectivity, norm_h01, norm_l2, norm_l2_vec, semi_regularity, stability_ratio,
    ConnectivitySummary, Region,
};
use crate::error::{Error, InputError};
use crate::math::norm2;
use crate::neighbors::NeighborList;
use crate::operators::{div_sum_into, laplacian_vec_into};
use crate::particles::Particles;
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
    /// holds only up to wall terms, and an impulsively started lid gives ratios above 1).
    pub source_ghosts: VectorKind,
    /// Reuse connectivity and `c0` while the pair data, roles and volumes are bit-identical
    /// (they are functions of those alone; default true).
    pub reuse_diagnostics: bool,
    /// Floating (pure Neumann) components the problem is expected to have: 1 for a box closed
    /// by walls, 0 when a Dirichlet band touches every part of the fluid. More are reported as a
    /// connectivity failure.
    pub allowed_floating: usize,
    /// The gradient for `∇pⁿ` in the predictor and `∇φ` in the correction: the difference
    /// gradient `∇h` (default; exactly adjoint to the source's `∇̂h·`, so Theorem 4.5 applies)
    /// or the renormalised `∇ᶜ = B∇h` (first order on disordered particles; not adjoint; its
    /// matrices are cached while the pair data and volumes are unchanged).
    pub gradient: GradientKind,
}

impl<const D: usize> ProjectionParams<D> {
    /// `ρ = 1`, viscosity `nu`, no body force, the rotational scheme, default solver, one
    /// floating component allowed (closed box).
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
            gradient: GradientKind::Difference,
        }
    }

    /// Checks `ρ > 0`, `ν ≥ 0` and finite values.
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
        self.solve.validate()
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
    /// Semi-regularity constant `c0` over `Ω`.
    pub c0: f64,
    /// Theorem 4.5 ratio `‖φ‖_h01(Ω) / (√(d c0) ‖f‖_ℓ2(Ω))`, at most 1 by the theorem.
    pub stability_ratio: f64,
    /// The Poisson solve.
    pub solve: SolveInfo,
    /// `‖∇̂h·u*‖_ℓ2(Ω)` (ghosts continued as for the source).
    pub div_before: f64,
    /// `‖∇̂h·uⁿ⁺¹‖_ℓ2(Ω)` (ghosts continued as for the source).
    pub div_after: f64,
    /// `½ ρ Σ_Ω ω_i |u_i|²` after the step.
    pub kinetic_energy: f64,
    /// `max_Ω |u_i|` after the step.
    pub max_speed: f64,
    /// Seconds per stage.
    pub timings: StageTimings,
}

/// What connectivity and c0 were computed from.
#[derive(Clone, Debug, PartialEq)]
struct DiagnosticsKey {
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

fn check_rows<const D: usize>(nl: &NeighborList<D>, n: usize) -> Result<(), InputError> {
    if nl.len() != n {
        return Err(InputError::LengthMismatch {
            field: "neighbor list rows",
            len: nl.len(),
            expected: n,
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
}

/// Scratch memory of the projection, reusable across steps (and `Send + Sync`).
#[derive(Debug, Default)]
pub struct ProjectionStep<const D: usize> {
    /// When true, [`project`](Self::project) stores its inputs and outputs in
    /// [`captured`](Self::captured) (for recording and re-running).
    pub capture: bool,
    /// The last capture.
    pub captured: Option<ProjectionCapture<D>>,
    /// Predictor velocity `u*` of the last step (all particles, ghosts filled).
    pub u_star: Vec<[f64; D]>,
    /// Pressure increment `φ` of the last step (warm start for CG).
    pub phi: Vec<f64>,
    work_vec: Vec<[f64; D]>,
    work_vec2: Vec<[f64; D]>,
    rhs: Vec<f64>,
    work: Vec<f64>,
    /// The Poisson solver and its caches.
    pub solver: PoissonSolver,
    /// The implicit viscous solver and its caches.
    pub viscous: HelmholtzSolver,
    /// The last implicit viscous solve.
    pub viscous_info: SolveInfo,
    diagnostics_cache: Option<(DiagnosticsKey, crate::diagnostics::Components, f64)>,
    gradient: GradientOperator<D>,
}

impl<const D: usize> ProjectionStep<D> {
    /// Empty scratch.
    pub fn new() -> Self {
        Self::default()
    }

    /// Predictor and projection on the same neighbour list: for particles that do not move
    /// during the step (Eulerian/ALE frames, or a caller that moves them afterwards). A
    /// Lagrangian loop calls [`predict`](Self::predict), moves the particles, updates the list
    /// and then calls [`project`](Self::project), so that the divergence is removed on the
    /// configuration the particles will occupy.
    ///
    /// On return `particles.u` and `particles.p` hold `uⁿ⁺¹` and `pⁿ⁺¹` (ghosts refilled).
    pub fn step(
        &mut self,
        particles: &mut Particles<D>,
        nl: &NeighborList<D>,
        boundary: &dyn Boundary<D>,
        params: &ProjectionParams<D>,
        dt: f64,
        accel: Option<&[[f64; D]]>,
    ) -> Result<StepReport, Error> {
        let tp = self.predict(particles, nl, boundary, params, dt, accel)?;
        let mut r = self.project(particles, nl, boundary, params, dt)?;
        r.timings.predictor = tp;
        Ok(r)
    }

    /// Predictor `u* = uⁿ + Δt (ν Δh uⁿ + g + accel − ∇h pⁿ/ρ)` into [`Self::u_star`] (the
    /// pressure term only for the incremental schemes); `accel` is an optional extra
    /// acceleration per particle (the caller's own forces, or a convective term). Particles are
    /// not modified except their ghost values. Returns the seconds spent.
    pub fn predict(
        &mut self,
        particles: &mut Particles<D>,
        nl: &NeighborList<D>,
        boundary: &dyn Boundary<D>,
        params: &ProjectionParams<D>,
        dt: f64,
        accel: Option<&[[f64; D]]>,
    ) -> Result<f64, Error> {
        check_dt(dt)?;
        params.validate()?;
        let n = particles.len();
        check_rows(nl, n)?;
        if let Some(extra) = accel {
            if extra.len() != n {
                return Err(InputError::LengthMismatch {
                    field: "accel",
                    len: extra.len(),
                    expected: n,
                }
                .into());
            }
        }
        let t = Instant::now();
        let (rho, nu) = (params.rho, params.nu);
        if boundary.has_ghosts() {
            boundary.fill_vector(&particles.role, &mut particles.u, VectorKind::Velocity);
            boundary.fill_scalar(&particles.role, &mut particles.p);
        }
        let role = &particles.role;
        let vol = &particles.vol;
        self.u_star.clone_from(&particles.u);
        let acc = &mut self.work_vec;
        acc.clear();
        acc.resize(n, [0.0; D]);
        let theta = if nu > 0.0 { params.viscous_theta } else { 0.0 };
        if nu > 0.0 && theta < 1.0 {
            laplacian_vec_into(nl, vol, &particles.u, acc);
            let f = (1.0 - theta) * nu;
            for a in acc.iter_mut() {
                for v in a.iter_mut() {
                    *v *= f;
                }
            }
        }
        if params.scheme != Scheme::NonIncremental {
            let gp = &mut self.work_vec2;
            gp.resize(n, [0.0; D]);
            self.gradient.kind = params.gradient;
            self.gradient.prepare(nl, vol);
            self.gradient.apply_into(nl, vol, &particles.p, gp);
            for (a, g) in acc.iter_mut().zip(gp.iter()) {
                for k in 0..D {
                    a[k] -= g[k] / rho;
                }
            }
        }
        let g = params.gravity;
        let has_g = g.iter().any(|&v| v != 0.0);
        for i in 0..n {
            if !role[i].is_fluid() {
                continue;
            }
            let a = &acc[i];
            let us = &mut self.u_star[i];
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
        if theta > 0.0 {
            // (I − θΔtν Δh) u* = r, no-slip ghosts as matrix entries
            let mut r = std::mem::take(&mut self.work_vec2);
            r.clone_from(&self.u_star);
            let rule = |j: usize| match particles.role[j] {
                crate::particles::Role::Ghost { walls, .. } => boundary.velocity_affine(walls),
                _ => (1.0, [0.0; D]),
            };
            self.viscous_info = self.viscous.solve(
                nl,
                &particles.vol,
                &particles.role,
                &rule,
                theta * dt * nu,
                &r,
                &mut self.u_star,
                &params.solve,
            )?;
            self.work_vec2 = r;
        }
        Ok(t.elapsed().as_secs_f64())
    }

    /// Projection of the predictor held in [`Self::u_star`] on the configuration described by
    /// `nl` (which may differ from the predictor's, e.g. after the particles moved with `u*`;
    /// ghosts may have been regenerated in between: their `u*` is refilled from their sources).
    /// Checks connectivity before the solve, solves for `φ`, corrects velocity and pressure.
    ///
    /// On error in the checks or in the solve, `particles.u` and `particles.p` are unchanged.
    pub fn project(
        &mut self,
        particles: &mut Particles<D>,
        nl: &NeighborList<D>,
        boundary: &dyn Boundary<D>,
        params: &ProjectionParams<D>,
        dt: f64,
    ) -> Result<StepReport, Error> {
        check_dt(dt)?;
        params.validate()?;
        let n = particles.len();
        check_rows(nl, n)?;
        let mut report = StepReport {
            dt,
            ..Default::default()
        };
        let (rho, nu) = (params.rho, params.nu);
        let ghosts = boundary.has_ghosts();

        // 1. diagnostics that must pass before any solve (recomputed only when the pair graph,
        //    roles or volumes changed: they are functions of those alone)
        let t = Instant::now();
        let key = DiagnosticsKey {
            epoch: nl.epoch(),
            generation: nl.generation(),
            roles: role_fingerprint(&particles.role),
            vol: particles.vol.clone(),
        };
        let cached = match &self.diagnostics_cache {
            Some((k, comps, c0)) if params.reuse_diagnostics && *k == key => {
                Some((comps.clone(), *c0))
            }
            _ => None,
        };
        let (comps, c0) = match cached {
            Some(v) => v,
            None => {
                let comps = connectivity(nl, &particles.role);
                let c0 = semi_regularity(nl, &particles.vol, &particles.role, Region::Omega);
                (comps, c0)
            }
        };
        report.connectivity = comps.summary();
        comps.check(params.allowed_floating)?;
        report.c0 = c0;
        self.diagnostics_cache = Some((key, comps.clone(), c0));
        report.timings.diagnostics = t.elapsed().as_secs_f64();
        let role = &particles.role;
        let vol = &particles.vol;
        self.u_star.resize(n, [0.0; D]);
        if ghosts {
            boundary.fill_vector(role, &mut self.u_star, VectorKind::Velocity);
        }
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
            ..Default::default()
        });

        // 3. source ∇̂h·f with f = −(ρ/Δt) u* on Ω (zero on the Dirichlet band)
        let t = Instant::now();
        let c = -rho / dt;
        let f = &mut self.work_vec2;
        f.resize(n, [0.0; D]);
        for i in 0..n {
            f[i] = if matches!(role[i], crate::particles::Role::Dirichlet) {
                [0.0; D]
            } else {
                self.u_star[i].map(|v| c * v)
            };
        }
        if ghosts && params.source_ghosts == VectorKind::Mirror {
            boundary.fill_vector(role, f, VectorKind::Mirror);
        }
        self.rhs.resize(n, 0.0);
        div_sum_into(nl, vol, f, &mut self.rhs);
        report.div_before = norm_l2(vol, &self.rhs, role, Region::Omega) / rho * dt;
        let f_l2 = norm_l2_vec(vol, f, role, Region::Omega);
        report.timings.source = t.elapsed().as_secs_f64();

        // 4. Poisson solve for the increment
        let t = Instant::now();
        self.phi.resize(n, 0.0);
        report.solve = self.solver.solve(
            nl,
            vol,
            role,
            &comps,
            &self.rhs,
            &mut self.phi,
            &params.solve,
        )?;
        report.timings.solve = t.elapsed().as_secs_f64();

        // 5. correction and pressure update
        let t = Instant::now();
        let t_diag = Instant::now();
        let phi_h01 = norm_h01(nl, vol, &self.phi, role, Region::Omega);
        report.stability_ratio = stability_ratio(phi_h01, report.c0, f_l2, D);
        let diag_extra = t_diag.elapsed().as_secs_f64();
        let gphi = &mut self.work_vec;
        gphi.resize(n, [0.0; D]);
        self.gradient.kind = params.gradient;
        self.gradient.prepare(nl, vol);
        self.gradient.apply_into(nl, vol, &self.phi, gphi);
        let rot_nu = nu * params.viscous_theta;
        if params.scheme == Scheme::Rotational && rot_nu > 0.0 {
            self.work.resize(n, 0.0);
            div_sum_into(nl, vol, &self.u_star, &mut self.work);
        }
        let s = dt / rho;
        for i in 0..n {
            if !role[i].is_fluid() {
                continue;
            }
            let us = self.u_star[i];
            let gp = gphi[i];
            particles.u[i] = std::array::from_fn(|k| us[k] - s * gp[k]);
            particles.p[i] = match params.scheme {
                Scheme::NonIncremental => self.phi[i],
                Scheme::Incremental => particles.p[i] + self.phi[i],
                Scheme::Rotational => {
                    let rot = if rot_nu > 0.0 {
                        rho * rot_nu * self.work[i]
                    } else {
                        0.0
                    };
                    particles.p[i] + self.phi[i] - rot
                }
            };
        }
        if ghosts {
            boundary.fill_vector(role, &mut particles.u, VectorKind::Velocity);
            boundary.fill_scalar(role, &mut particles.p);
        }
        report.timings.correction = t.elapsed().as_secs_f64() - diag_extra;

        let t = Instant::now();
        self.rhs.resize(n, 0.0);
        if ghosts && params.source_ghosts == VectorKind::Mirror {
            // measure with the same continuation as the source
            self.work_vec.clone_from(&particles.u);
            boundary.fill_vector(role, &mut self.work_vec, VectorKind::Mirror);
            div_sum_into(nl, vol, &self.work_vec, &mut self.rhs);
        } else {
            div_sum_into(nl, vol, &particles.u, &mut self.rhs);
        }
        report.div_after = norm_l2(vol, &self.rhs, role, Region::Omega);
        let (mut ke, mut vmax) = (0.0, 0.0f64);
        for i in 0..n {
            if role[i].is_fluid() {
                let u2 = norm2(&particles.u[i]);
                ke += 0.5 * rho * vol[i] * u2;
                vmax = vmax.max(u2);
                if !u2.is_finite() {
                    return Err(crate::error::SolveError::NonFinite { particle: i }.into());
                }
            }
        }
        report.kinetic_energy = ke;
        report.max_speed = vmax.sqrt();
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
