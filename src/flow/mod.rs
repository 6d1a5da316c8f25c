//! A complete incompressible particle-flow solver around [`ProjectionStep`]: time-step control,
//! neighbour maintenance, ghosts, volumes, advection and particle shifting.
//!
//! One [`Simulation::advance`]:
//! 1. moves ghosts with their sources; when the neighbour candidates have expired, regenerates
//!    the ghosts and searches again (otherwise only re-measures pairs);
//! 2. recomputes volumes (`ω_i = 1/Σ_{j≠i} w_h(r_ij)`) if asked;
//! 3. picks `Δt` from the CFL, viscous and body-force limits;
//! 4. predictor and projection on the current configuration (Eulerian frame: with the
//!    convective term `−(u·∇h)u`);
//! 5. Lagrangian frame: moves the particles with the projected velocity, `xⁿ⁺¹ = xⁿ + Δt uⁿ⁺¹ + δ`,
//!    where the shift `δ` is the Fickian one (`δx_i = −A h |u_i| Δt ∇C_i`, Skillen et al. 2013's
//!    scaling of Lind et al. 2012's law; none in a pure Lagrangian run) plus the wall margin
//!    ([`WALL_MARGIN`]), and corrects velocity and pressure to the shifted position by a
//!    first-order Taylor expansion (Xu et al. 2009), `u_i += (δ_i·∇h) u_i`. The particles thus
//!    move with a field that is divergence-free on the configuration it was projected on (the
//!    ISPH step of Lind et al. 2012), and the neighbours follow at the start of the next step.

//!
//! Time-step control and the stability guards are in [`crate::time`] (re-exported here), the
//! convective term in [`convection`], shifting in [`shifting`].

pub mod convection;
pub mod free_surface;
pub mod shifting;

use crate::boundary::Boundary;
use crate::consistent::GradientKind;
use crate::error::{Error, InputError};
use crate::geometry::number_density_volume;
use crate::neighbors::{closest_pair, NeighborConfig, NeighborList};
use crate::particles::{Particles, Role};
use crate::projection::{ProjectionParams, ProjectionStep, Scheme, StepReport};
use serde::{Deserialize, Serialize};
use std::time::Instant;

pub use crate::time::{DtLimit, StabilityGuard, TimeStepLimits};
pub use convection::{Convection, ConvectionForm, Integrator};
pub use free_surface::{FreeSurface, SurfaceCount};
pub use shifting::Shifting;

/// Frame of the particles.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Motion {
    /// Particles move with the flow (plus shifting).
    #[default]
    Lagrangian,
    /// Particles stay; the convective term `−(u·∇h)u` is added to the predictor.
    Eulerian,
}

impl std::str::FromStr for Motion {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s.trim().to_ascii_lowercase().as_str() {
            "lagrangian" => Ok(Motion::Lagrangian),
            "eulerian" => Ok(Motion::Eulerian),
            _ => Err(format!(
                "unknown motion '{s}': expected lagrangian or eulerian"
            )),
        }
    }
}

pub use crate::setup::VolumeRule;

/// Everything the flow solver needs besides the particles and the boundary.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FlowParams<const D: usize> {
    /// Projection parameters (ρ, ν, g, scheme, solver).
    pub projection: ProjectionParams<D>,
    /// Time-step limits.
    pub limits: TimeStepLimits,
    /// Frame.
    pub motion: Motion,
    /// Integrator of the explicit terms.
    pub integrator: Integrator,
    /// Discretisation of the convective term (Eulerian frame; [`ConvectionForm`]).
    pub convection: ConvectionForm,
    /// Shifting (Lagrangian only; `None` = pure Lagrangian).
    pub shifting: Option<Shifting>,
    /// Volumes.
    pub volumes: VolumeRule,
    /// Pair weights, applied after every volume update ([`crate::pair_weights`]).
    pub pair_weights: crate::pair_weights::PairWeights,
    /// Initial particle spacing `Δx` (for shift limits).
    pub dx: f64,
}

impl<const D: usize> FlowParams<D> {
    /// Checks every parameter, naming the first bad one by its key path in this struct:
    /// `projection.*` ([`ProjectionParams::validate`], e.g. `projection.solve.abs_tol`),
    /// `limits.*` ([`TimeStepLimits::validate`]), `shifting.*` ([`Shifting::validate`]) and
    /// `dx` (positive and finite).
    pub fn validate(&self) -> Result<(), InputError> {
        self.projection
            .validate()
            .map_err(|e| e.under("projection"))?;
        self.limits.validate()?;
        if let Some(s) = &self.shifting {
            s.validate()?;
        }
        if !(self.dx > 0.0 && self.dx.is_finite()) {
            return Err(InputError::parameter(
                "dx",
                self.dx,
                "the particle spacing must be positive and finite",
            ));
        }
        Ok(())
    }
}

/// A stage of a flow step. A [`StagePlan`] lists the stages a scene needs; the others never run.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Stage {
    /// Ghost images of fluid particles across walls (placement and value fills).
    Ghosts,
    /// Periodic wrap of positions and minimum-image pairs.
    Periodic,
    /// Neighbour re-measurement after particles move (Lagrangian frame).
    MovingNeighbors,
    /// Volumes `ω = 1/Σw` recomputed.
    Volumes,
    /// Convective term `−(u·∇h)u` (Eulerian frame).
    Convection,
    /// Explicit part of the viscous term.
    ViscousExplicit,
    /// Implicit (Helmholtz) part of the viscous term.
    ViscousImplicit,
    /// Body force.
    BodyForce,
    /// `−∇h pⁿ/ρ` in the predictor (incremental schemes).
    PressureGradient,
    /// Advection with `u*` (Lagrangian frame).
    Advection,
    /// Source, Poisson solve and correction.
    Projection,
    /// Rotational pressure correction `−ρθν ∇̂h·u*`.
    RotationalCorrection,
    /// Particle shifting.
    Shifting,
    /// A Dirichlet band (free surface / open boundary) anchors the pressure.
    DirichletBand,
    /// Free-surface detection: the band is chosen again every step ([`free_surface`]).
    FreeSurface,
}

/// What a scene has, and so which stages run (MISSION §4: "a scene skips every stage it does not
/// need"). Built once by [`Simulation::new`] from the boundary, the particles and the parameters.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct StagePlan {
    /// The stages, in execution order.
    pub stages: Vec<Stage>,
}

impl StagePlan {
    /// The plan for a boundary with/without ghosts and periodic axes, the roles present, and the
    /// parameters.
    pub fn new<const D: usize>(
        has_ghosts: bool,
        periodic: bool,
        has_dirichlet: bool,
        params: &FlowParams<D>,
    ) -> Self {
        // the projection's own stages are decided once, by its plan
        let pr = crate::projection::ProjectionPlan::new(&params.projection);
        let lagrangian = params.motion == Motion::Lagrangian;
        let mut s = Vec::new();
        let mut add = |c: bool, st: Stage| {
            if c {
                s.push(st)
            }
        };
        add(has_ghosts, Stage::Ghosts);
        add(periodic, Stage::Periodic);
        add(has_dirichlet, Stage::DirichletBand);
        add(params.volumes == VolumeRule::NumberDensity, Stage::Volumes);
        add(!lagrangian, Stage::Convection);
        add(pr.viscous_explicit, Stage::ViscousExplicit);
        add(pr.body_force, Stage::BodyForce);
        add(pr.pressure_gradient, Stage::PressureGradient);
        add(pr.viscous_implicit, Stage::ViscousImplicit);
        add(lagrangian, Stage::Advection);
        add(lagrangian, Stage::MovingNeighbors);
        add(true, Stage::Projection);
        add(pr.rotational, Stage::RotationalCorrection);
        add(lagrangian && params.shifting.is_some(), Stage::Shifting);
        StagePlan { stages: s }
    }
    /// True when the plan has `stage`.
    pub fn has(&self, stage: Stage) -> bool {
        self.stages.contains(&stage)
    }
}

/// A flow step's report: the projection's plus what the flow solver did around it.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct FlowReport {
    /// Step number (1 for the first step).
    pub step: u64,
    /// Time after the step.
    pub time: f64,
    /// Which limit set `Δt`.
    pub dt_limit: DtLimit,
    /// The neighbour candidates were rebuilt this step.
    pub neighbors_rebuilt: bool,
    /// Largest shift this step (distance units).
    pub max_shift: f64,
    /// Seconds: ghosts + neighbour list + volumes.
    pub neighbors_seconds: f64,
    /// Seconds: advection, shifting, confinement.
    pub advect_seconds: f64,
    /// The projection's report.
    pub projection: StepReport,
    /// `Δt` over the smallest of the CFL, explicit viscous and body-force limits at the start
    /// of the step ([`Simulation::dt_bound`]): above 1 the step exceeds a stability limit.
    pub dt_ratio: f64,
    /// Kinetic energy after the step over the energy before it (`None` on the first step or
    /// from rest). Above 1 without a forcing that explains it, the run is blowing up.
    pub energy_growth: Option<f64>,
    /// Fluid particles the wall margin moved back this step (Lagrangian frame; see
    /// [`WALL_MARGIN`]).
    pub wall_pushes: usize,
    /// Free surfaces: the band the detection chose for this step (`None` without one).
    pub surface: Option<SurfaceCount>,
    /// The volume shift's RMS relative volume error `e` before the move ([`Shifting::volume`];
    /// `None` when no volume shift was computed this step).
    pub volume_error: Option<f64>,
}

/// Moving particles are kept at least this fraction of the spacing `Δx` inside the walls: a
/// particle the flow carries closer is moved back along the wall normal and its velocity and
/// pressure re-interpolated there (a shift, counted in [`FlowReport::wall_pushes`]). A fluid
/// particle's mirror image is then never closer than `Δx/2`, and no particle crosses a wall
/// within a step whose normal displacement is below the margin.
pub const WALL_MARGIN: f64 = 0.25;

/// A step of [`Simulation::advance_to`] that falls short of the end time by at most this
/// fraction of itself is stretched to land on it, rather than leave a sliver of a step.
const LAND_TOLERANCE: f64 = 1e-9;

/// A running flow.
pub struct Simulation<const D: usize, B: Boundary<D>> {
    /// Particle state (fluid, Dirichlet band, then ghosts).
    pub particles: Particles<D>,
    /// The neighbour list at the current positions.
    pub nl: NeighborList<D>,
    /// The boundary.
    pub boundary: B,
    /// Parameters.
    pub params: FlowParams<D>,
    /// Projection scratch.
    pub projection: ProjectionStep<D>,
    /// Current time.
    pub time: f64,
    /// Steps taken.
    pub steps: u64,
    plan: StagePlan,
    /// The convective acceleration of the current step (Eulerian frame).
    work: Vec<[f64; D]>,
    shift_scratch: shifting::ShiftScratch<D>,
    stale: bool,
    /// The advection velocity of a Lagrangian step (scratch).
    advect_u: Vec<[f64; D]>,
    /// Lagrangian frame: each fluid particle's material acceleration over the last step,
    /// `(uⁿ⁺¹ − ũⁿ)/Δt` with `ũⁿ` the velocity carried to the moved position (empty before the
    /// first step); the next move adds `Δt²/2 a`.
    material_accel: Vec<[f64; D]>,
    /// Lagrangian frame, incremental schemes: `∇pⁿ/ρ` on the configuration `xⁿ` the last
    /// step ended with (empty before the first step). Computed at the start of the next step,
    /// before the particles move (`pressure_grad_due`): the same positions, neighbours and
    /// pressure as at the end of the last one, but a caller can still bring the pressure of
    /// particles it holds copies of up to date between the steps (the particle decomposition:
    /// a halo particle's pressure update reads beyond the halo).
    old_pressure_grad: Vec<[f64; D]>,
    pressure_grad_due: bool,
    /// The explicit acceleration handed to the predictor (scratch).
    extra_accel: Vec<[f64; D]>,
    /// The predicted velocity `u*` (scratch).
    u_star: Vec<[f64; D]>,
    convection: Convection<D>,
    /// Kinetic energy after the last step (for `guard.energy_growth`).
    prev_energy: Option<f64>,
    /// Moment pair-weight state: parameters, warm-start multipliers, last report.
    pub pair_weights: crate::pair_weights::MomentWeights<D>,
    /// Lagrangian frame with shifting and the difference gradients: the shift's Taylor
    /// correction takes its gradients `∇h u`, `∇h p` and the velocity's range in the shift's
    /// own pass over the pairs, not in three passes of their own — the same bits (default true;
    /// off only to measure the saving).
    pub fused_shift: bool,
    /// Free-surface detection and the full-lattice number density `n₀` it compares with.
    free_surface: Option<(FreeSurface, f64)>,
    /// The largest speed of the moving particles for the Fickian shift's global speed, when
    /// the caller knows it beyond this simulation's particles (the particle decomposition: the
    /// maximum over every rank); `None`: the maximum over this simulation's particles.
    pub(crate) shift_speed: Option<f64>,
    /// Scratch of the volume shift ([`Shifting::volume`]).
    volume_shift: Vec<[f64; D]>,
    /// The mean fluid volume of the volume shift when the caller knows it beyond this
    /// simulation's particles (the particle decomposition: over every rank's own particles);
    /// `None`: the mean over this simulation's fluid particles.
    pub(crate) volume_mean: Option<f64>,
    /// The steady acceleration of a singular part (`set_singular_part`), empty without one.
    singular_accel: Vec<[f64; D]>,
}

/// What a Lagrangian step hands to the next for each particle besides its position,
/// velocity, pressure and volume: the particle decomposition moves it with the particle to its
/// new rank ([`Simulation::carried_state`], [`Simulation::set_carried_state`]). Indexed like
/// the particles that are not ghosts (fluid, then a Dirichlet band); empty before the first
/// step.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct CarriedState<const D: usize> {
    /// The material acceleration over the last step, `(uⁿ⁺¹ − ũⁿ)/Δt`: the next move adds
    /// `Δt²/2 a`.
    pub material_accel: Vec<[f64; D]>,
    /// Whether the next step takes the pressure gradient at the configuration before its move
    /// for the trapezoidal pressure term (incremental schemes after the first step).
    pub pressure_grad_due: bool,
}

impl<const D: usize, B: Boundary<D>> Simulation<D, B> {
    /// Sets up ghosts, the neighbour list and volumes for `particles` (fluid and Dirichlet
    /// particles, no ghosts yet). The neighbour configuration's periodicity is taken from the
    /// boundary.
    pub fn new(
        mut particles: Particles<D>,
        boundary: B,
        neighbors: NeighborConfig<D>,
        params: FlowParams<D>,
    ) -> Result<Self, Error> {
        params.validate()?;
        particles.validate()?;
        // a fluid particle outside the domain is an input error, not a later blow-up
        boundary.confine(&mut particles)?;
        let mut config = neighbors.with_periodicity(boundary.periodicity());
        if params.motion == Motion::Eulerian {
            // fixed particles never outgrow a skin; without it the matrix pattern holds only
            // the pairs within h (1.7x fewer entries at skin 0.3h, and less Cholesky fill)
            config.skin = 0.0;
        }
        let plan = StagePlan::new(
            boundary.has_ghosts(),
            config.periodic.any(),
            particles.role.contains(&crate::particles::Role::Dirichlet),
            &params,
        );
        let reach = config.h + config.skin;
        if plan.has(Stage::Ghosts) {
            boundary.make_ghosts(&mut particles, reach);
        }
        let nl = NeighborList::build(config, &particles.x)?;
        if nl.n_pairs() == 0 && particles.len() >= 2 {
            // h ≤ min r_ij: name h and the spacing rather than report every particle isolated
            if let Some((min_spacing, i, j)) = closest_pair(&particles.x, &config.periodic) {
                return Err(InputError::RadiusTooSmall {
                    h: config.h,
                    min_spacing,
                    i,
                    j,
                }
                .into());
            }
        }
        let mut sim = Simulation {
            particles,
            nl,
            boundary,
            params,
            projection: ProjectionStep::new(),
            time: 0.0,
            steps: 0,
            plan,
            work: Vec::new(),
            shift_scratch: Default::default(),
            fused_shift: true,
            stale: false,
            advect_u: Vec::new(),
            material_accel: Vec::new(),
            old_pressure_grad: Vec::new(),
            pressure_grad_due: false,
            extra_accel: Vec::new(),
            u_star: Vec::new(),
            convection: Convection::new(),
            prev_energy: None,
            pair_weights: Default::default(),
            free_surface: None,
            shift_speed: None,
            volume_shift: Vec::new(),
            volume_mean: None,
            singular_accel: Vec::new(),
        };
        // predict and project act on the same configuration in every step of the driver
        sim.projection.overlap_solve_setup = true;
        if sim.params.motion == Motion::Lagrangian {
            sim.projection.solver.assume_moving();
            sim.projection.viscous.assume_moving();
            // the next step's trapezoidal term reads ∇pⁿ⁺¹ of this configuration
            sim.projection.keep_pressure_gradient = true;
        }
        sim.update_volumes()?;
        Ok(sim)
    }

    /// The particles that are not ghosts (fluid, then a Dirichlet band): they come first.
    fn n_real(&self) -> usize {
        let role = &self.particles.role;
        role.iter().take_while(|r| r.is_real()).count()
    }

    /// The per-particle state a Lagrangian step carries to the next (see [`CarriedState`]).
    pub fn carried_state(&self) -> CarriedState<D> {
        let n = self.n_real();
        let v = &self.material_accel;
        CarriedState {
            material_accel: v[..v.len().min(n)].to_vec(),
            pressure_grad_due: self.pressure_grad_due,
        }
    }

    /// Sets the per-particle state the next Lagrangian step starts from (the particle
    /// decomposition: a rank's new particles with the state their last step left). The
    /// material acceleration is empty (as before the first step) or has one entry per particle
    /// that is not a ghost; fails naming it when it has not.
    pub fn set_carried_state(&mut self, state: CarriedState<D>) -> Result<(), InputError> {
        let n = self.n_real();
        let v = &state.material_accel;
        if !v.is_empty() && v.len() != n {
            return Err(InputError::LengthMismatch {
                field: "material_accel",
                len: v.len(),
                expected: n,
            });
        }
        self.material_accel = state.material_accel;
        if !self.material_accel.is_empty() {
            // ghosts do not move
            self.material_accel.resize(self.particles.len(), [0.0; D]);
        }
        self.pressure_grad_due = state.pressure_grad_due;
        Ok(())
    }

    /// The kinetic energy after the last step (`None` before the first).
    pub(crate) fn prev_energy(&self) -> Option<f64> {
        self.prev_energy
    }

    /// The stages this simulation runs.
    pub fn plan(&self) -> &StagePlan {
        &self.plan
    }

    /// Makes the water's boundary a free surface ([`free_surface`]): from now on every step
    /// first chooses the surface particles (the Dirichlet band, `p = 0`) by their number
    /// density, the band moves and is corrected with the fluid
    /// ([`ProjectionParams::free_surface`]), walls mirror the band too, and a fluid cluster
    /// without a path to the band is handled by `params.projection.disconnected`. The first
    /// detection runs here. Fails on a bad threshold.
    pub fn with_free_surface(mut self, fs: FreeSurface) -> Result<Self, Error> {
        fs.validate()?;
        let n0 = free_surface::lattice_number_density(self.nl.kernel(), self.params.dx);
        self.free_surface = Some((fs, n0));
        self.params.projection.free_surface = true;
        if !self.plan.has(Stage::DirichletBand) {
            let i = self.plan.stages.len().min(3);
            self.plan.stages.insert(i, Stage::DirichletBand);
        }
        self.plan.stages.push(Stage::FreeSurface);
        // images of every real particle near a wall, whatever its role will be
        if self.plan.has(Stage::Ghosts) {
            let c = self.nl.config();
            self.boundary
                .make_ghosts_with_band(&mut self.particles, c.h + c.skin, true);
            self.nl.invalidate();
            self.nl.update(&self.particles.x)?;
            self.update_volumes()?;
        }
        free_surface::detect(&mut self.particles, &self.nl, n0, fs.threshold, true);
        Ok(self)
    }

    /// The free-surface detection, when the run has one.
    pub fn free_surface(&self) -> Option<FreeSurface> {
        self.free_surface.map(|(fs, _)| fs)
    }

    fn update_volumes(&mut self) -> Result<(), Error> {
        if self.plan.has(Stage::Volumes) {
            // `number_density_volumes` from the sums the measure took, in place
            let p = &mut self.particles;
            for ((vol, r), &s) in p.vol.iter_mut().zip(&p.role).zip(self.nl.w_sums()) {
                // a particle without neighbours (number density 0) keeps the volume it had: it
                // carries its mass ballistically until it rejoins (`Disconnected::Float`)
                let v = number_density_volume(s);
                if r.is_fluid() && v.is_finite() {
                    *vol = v;
                }
            }
            // ghosts copy their source's volume
            if self.plan.has(Stage::Ghosts) {
                self.boundary.place_ghosts(&mut self.particles);
            }
        }
        let (kind, p) = (self.params.pair_weights, &self.particles);
        self.pair_weights
            .apply(kind, &mut self.nl, p, &self.boundary)?;
        Ok(())
    }

    /// Takes the real particles' state from elsewhere — the copy of a decomposed run
    /// gathered from its ranks, which scenes and recordings observe — as a step would leave
    /// it: for each row `(particle, x, u, p, volume, in the band)` the particle's values (the
    /// band only with a free surface), then, when `moved`, the ghosts and neighbours brought
    /// to the new positions (the given volumes kept), the ghosts' velocity and pressure by
    /// the boundary's rules, and the clock `(time, steps)`.
    #[allow(clippy::type_complexity)]
    pub(crate) fn load_real_state(
        &mut self,
        rows: impl Iterator<Item = (usize, [f64; D], [f64; D], f64, f64, bool)>,
        moved: bool,
        clock: (f64, u64),
    ) -> Result<(), Error> {
        let band = self.free_surface.is_some();
        let p = &mut self.particles;
        for (i, x, u, pr, vol, in_band) in rows {
            p.x[i] = x;
            p.u[i] = u;
            p.p[i] = pr;
            p.vol[i] = vol;
            if band {
                p.role[i] = if in_band {
                    Role::Dirichlet
                } else {
                    Role::Fluid
                };
            }
        }
        let ghosts = self.plan.has(Stage::Ghosts);
        if moved {
            let real: Vec<(usize, f64)> = (0..self.particles.len())
                .filter(|&i| self.particles.role[i].is_real())
                .map(|i| (i, self.particles.vol[i]))
                .collect();
            self.refresh()?;
            for (i, v) in real {
                self.particles.vol[i] = v;
            }
            if ghosts {
                self.boundary.place_ghosts(&mut self.particles);
            }
        }
        if ghosts {
            let rho_g = self.params.projection.rho_g();
            let p = &mut self.particles;
            self.boundary.fill_velocity(&p.x, &p.role, &mut p.u);
            self.boundary.fill_pressure(&p.x, &p.role, &mut p.p, rho_g);
        }
        (self.time, self.steps) = clock;
        Ok(())
    }

    /// Particle `i`'s last move beyond the advection: the length of its shift and whether the
    /// wall margin pushed it (`None` before the first Lagrangian step).
    pub(crate) fn last_move(&self, i: usize) -> Option<(f64, bool)> {
        self.shift_scratch.last_move(i)
    }

    /// Forces the next [`advance`](Self::advance) to search neighbours again, re-create the
    /// ghosts and recompute volumes, as if the particles had moved (benchmarks of reuse: a
    /// fixed-particle run otherwise builds its neighbour list once).
    pub fn invalidate_neighbors(&mut self) {
        self.nl.invalidate();
        self.stale = true;
    }

    /// `∇p/ρ` of the current pressure on the current configuration, into `out`
    /// ([`ProjectionStep::pressure_gradient_into`]).
    fn pressure_gradient_into(&mut self, out: &mut Vec<[f64; D]>) {
        self.projection.pressure_gradient_into(
            &mut self.particles,
            &self.nl,
            &self.boundary,
            &self.params.projection,
            out,
        );
    }

    /// Brings ghosts, neighbours and volumes up to date with the positions.
    fn refresh(&mut self) -> Result<bool, Error> {
        let ghosts = self.plan.has(Stage::Ghosts);
        if ghosts {
            self.boundary.place_ghosts(&mut self.particles);
        }
        let mut rebuilt = false;
        if self.nl.needs_rebuild(&self.particles.x) {
            if ghosts {
                let c = self.nl.config();
                let reach = c.h + c.skin;
                let band = self.free_surface.is_some();
                self.boundary
                    .make_ghosts_with_band(&mut self.particles, reach, band);
            }
            self.nl.invalidate();
            rebuilt = true;
        }
        self.nl.update(&self.particles.x)?;
        self.update_volumes()?;
        Ok(rebuilt)
    }

    /// Adds a steady singular part `u_s` to the solution (Botella & Peyret 1998: the particles
    /// carry `u`, their discrete operators act on the regular part `u − u_s`): `accel` is the
    /// steady acceleration `u_s` contributes to every fluid particle's momentum beyond what the
    /// operators make of it (the exact terms minus the discrete ones), added in every
    /// predictor; `part` is what the projection leaves out of the divergence
    /// ([`SingularPart`](crate::projection::SingularPart)). Fixed particles only (the fields
    /// are of this configuration); `None` removes it. [`crate::scene::corner`] makes the lid
    /// corners' one.
    pub fn set_singular_part(
        &mut self,
        part: Option<(Vec<[f64; D]>, crate::projection::SingularPart<D>)>,
    ) -> Result<(), InputError> {
        let Some((accel, part)) = part else {
            self.singular_accel.clear();
            self.projection.singular = None;
            return Ok(());
        };
        if self.plan.has(Stage::Advection) {
            return Err(InputError::Parameter {
                name: "singular part".into(),
                value: f64::NAN,
                reason: "a steady singular part needs fixed particles (the Eulerian frame)".into(),
            });
        }
        let n = self.particles.len();
        if accel.len() != n {
            return Err(InputError::LengthMismatch {
                field: "singular acceleration",
                len: accel.len(),
                expected: n,
            });
        }
        if let Some(i) = accel.iter().position(|a| !a.iter().all(|c| c.is_finite())) {
            return Err(InputError::NonFinite {
                field: "singular acceleration",
                particle: i,
            });
        }
        let before = self.projection.singular.replace(part);
        let checked = self
            .projection
            .check_singular(&self.particles.role, self.params.projection.source);
        match checked {
            Ok(()) => self.singular_accel = accel,
            Err(_) => self.projection.singular = before,
        }
        checked
    }

    /// The time step for the current state, and the limit that set it.
    pub fn time_step(&self) -> (f64, DtLimit) {
        crate::time::time_step(
            &self.particles,
            &self.nl,
            &self.params.projection,
            &self.params.limits,
        )
    }

    /// `max_i 2d Σ_j ω_j w_h/r²` over fluid rows: half the Gershgorin bound on the spectrum of
    /// `−Δh` (so forward Euler on `ν Δh u` is stable for `ν Δt λ ≤ 1`).
    pub fn viscous_eigen_bound(&self) -> f64 {
        crate::time::viscous_eigen_bound(&self.particles, &self.nl)
    }

    /// The smallest of the stability limits on `Δt` for the current state (CFL, explicit
    /// viscous, body force, as in [`time_step`](Self::time_step) but without `dt_max` and a fixed
    /// step) and which one it is; `∞` (with [`DtLimit::Max`]) when none applies.
    pub fn dt_bound(&self) -> (DtLimit, f64) {
        crate::time::dt_bound(
            &self.particles,
            &self.nl,
            &self.params.projection,
            &self.params.limits,
        )
    }

    /// Advances one step.
    ///
    /// Eulerian: predictor (with `−(u·∇h)u`) and projection on the fixed configuration.
    /// Lagrangian: predictor and projection at `xⁿ`, then the particles move with `uⁿ⁺¹` plus
    /// their shift (Fickian and wall margin, with the Taylor correction of `u` and `p`).
    pub fn advance(&mut self) -> Result<FlowReport, Error> {
        crate::math::in_pool(|| self.advance_inner(None))
    }

    /// Advances one step that ends at time `t` at the latest: the step of
    /// [`advance`](Self::advance), shortened to `t − time` when its `Δt` would pass `t` (or fall
    /// short of it by at most 10⁻⁹ `Δt`, so that no sliver of a step is left), in which case the
    /// time after the step is exactly `t` and the report names [`DtLimit::Fixed`].
    /// `params.limits` is not changed. Fails when `t` is not finite or not after the current time.
    ///
    /// A loop that looks at every step: `while sim.time < t { let r = sim.advance_toward(t)?; … }`.
    pub fn advance_toward(&mut self, t: f64) -> Result<FlowReport, Error> {
        if !(t.is_finite() && t > self.time) {
            return Err(InputError::parameter(
                "t",
                t,
                format!(
                    "the end time must be finite and after the current time {}",
                    self.time
                ),
            )
            .into());
        }
        crate::math::in_pool(|| self.advance_inner(Some(t)))
    }

    /// Advances until the time is exactly `t` (the last step shortened as in
    /// [`advance_toward`](Self::advance_toward); a fixed `Δt` that divides the interval lands
    /// too) and returns the last step's report, `None` when the time already is `t`. Fails when
    /// `t` is not finite or before the current time, and with the first failing step's error.
    pub fn advance_to(&mut self, t: f64) -> Result<Option<FlowReport>, Error> {
        if !(t.is_finite() && t >= self.time) {
            return Err(InputError::parameter(
                "t",
                t,
                format!(
                    "the end time must be finite and not before the current time {}",
                    self.time
                ),
            )
            .into());
        }
        let mut last = None;
        while self.time < t {
            last = Some(crate::math::in_pool(|| self.advance_inner(Some(t)))?);
        }
        Ok(last)
    }

    /// One step; with `until = Some(t)` shortened to end at `t` (see
    /// [`advance_toward`](Self::advance_toward)).
    fn advance_inner(&mut self, until: Option<f64>) -> Result<FlowReport, Error> {
        let t0 = Instant::now();
        let mut rebuilt = false;
        if self.stale {
            rebuilt |= self.refresh()?;
            self.stale = false;
        }
        let mut neighbors_seconds = t0.elapsed().as_secs_f64();
        check_state(&self.particles, &self.nl)?;
        let (mut dt, mut dt_limit) = self.time_step();
        // the last step of advance_to(t): shortened (or stretched by a rounding sliver) to land
        let land = until.filter(|&t| {
            let remaining = t - self.time;
            dt > remaining || remaining - dt <= LAND_TOLERANCE * dt
        });
        if let Some(t) = land {
            dt = t - self.time;
            dt_limit = DtLimit::Fixed;
        }
        let (bound_limit, bound) = self.dt_bound();
        let dt_ratio = if bound.is_finite() { dt / bound } else { 0.0 };
        self.params
            .limits
            .guard
            .check_dt(self.steps + 1, dt, bound_limit, bound)?;
        let lagrangian = self.plan.has(Stage::Advection);
        let trapezoid = lagrangian && self.params.projection.scheme != Scheme::NonIncremental;
        let mut grad_seconds = 0.0;
        if std::mem::take(&mut self.pressure_grad_due) && trapezoid {
            // ∇pⁿ at xⁿ for the trapezoidal term (the correction's operators): kept by the
            // last projection when it can, else taken here
            let t = Instant::now();
            let mut g = std::mem::take(&mut self.old_pressure_grad);
            let (p, nl, params) = (&self.particles, &self.nl, &self.params.projection);
            if !self
                .projection
                .take_pressure_gradient(p, nl, params, &mut g)
            {
                self.pressure_gradient_into(&mut g);
            }
            self.old_pressure_grad = g;
            grad_seconds = t.elapsed().as_secs_f64();
        } else {
            self.old_pressure_grad.clear();
        }
        let mut advect_seconds = 0.0;
        let mut moved = shifting::Moved::default();
        let mut volume_error = None;
        if lagrangian {
            // move with uⁿ (divergence-free and tangent to the walls after the last
            // projection) plus the shift (uⁿ and pⁿ Taylor-corrected to the shifted positions),
            // keep off the walls, and bring the neighbours and volumes to the moved
            // configuration: predictor and projection then act where the particles are at
            // tⁿ⁺¹, so uⁿ⁺¹ is divergence-free there (Cummins & Rudman 1999)
            let t1 = Instant::now();
            let sh = self
                .params
                .shifting
                .filter(|_| self.plan.has(Stage::Shifting));
            // the volume shift: one solve with this configuration's Poisson matrix (not with
            // a free surface, nor before the first projection has set the solver up)
            let mut volume_shift = std::mem::take(&mut self.volume_shift);
            volume_shift.clear();
            if let Some((beta, tol)) = sh
                .map(|s| (s.volume, s.volume_tol))
                .filter(|&(b, _)| b > 0.0 && self.free_surface.is_none() && self.steps > 0)
            {
                volume_error = Some(self.projection.volume_shift_into(
                    &self.particles,
                    &self.nl,
                    &self.boundary,
                    &self.params.projection,
                    beta,
                    tol,
                    self.volume_mean,
                    &mut volume_shift,
                )?);
            }
            let mut u = std::mem::take(&mut self.advect_u);
            u.clone_from(&self.particles.u);
            let ls = (self.params.projection.gradient == GradientKind::LeastSquares).then(|| {
                let p = &self.particles;
                let ghosts = self.boundary.has_ghosts();
                self.projection
                    .least_squares(&self.nl, &p.vol, &p.x, &p.role, ghosts)
            });
            self.shift_scratch.separate_passes = !self.fused_shift;
            let res = shifting::advance_particles(
                sh.as_ref(),
                self.free_surface.is_some(),
                self.params.dx,
                dt,
                self.shift_speed,
                WALL_MARGIN * self.params.dx,
                &mut self.particles,
                &mut u,
                &self.material_accel,
                self.params.projection.rho_g(),
                &self.nl,
                ls,
                &self.boundary,
                &mut self.shift_scratch,
                &volume_shift,
            );
            self.volume_shift = volume_shift;
            std::mem::swap(&mut self.particles.u, &mut u);
            self.advect_u = u;
            moved = res?;
            advect_seconds += t1.elapsed().as_secs_f64();
            let t2 = Instant::now();
            rebuilt |= self.refresh()?;
            neighbors_seconds += t2.elapsed().as_secs_f64();
            // ũⁿ, for the material acceleration after the projection
            self.material_accel.clone_from(&self.particles.u);
        }
        // the free surface of the configuration the projection acts on
        let surface = match self.free_surface {
            Some((fs, n0)) => {
                let t = Instant::now();
                let offset = fs.surface_offset * self.params.dx;
                let p = &mut self.particles;
                let count = free_surface::detect(p, &self.nl, n0, fs.threshold, offset == 0.0);
                if offset > 0.0 {
                    let mut g = Vec::new();
                    self.pressure_gradient_into(&mut g);
                    let rho = self.params.projection.rho;
                    free_surface::set_band_pressure(&mut self.particles, &self.nl, &g, rho, offset);
                }
                // the non-incremental solve's unknown is the pressure itself: the band's
                // values are its pressures (`p_b` with an offset, zero without); the
                // incremental schemes hold `φ = 0` there and keep `p_b` through `pⁿ + φ`
                if self.params.projection.scheme == Scheme::NonIncremental && offset > 0.0 {
                    let mut g = self.projection.take_band_increment();
                    g.clone_from(&self.particles.p);
                    self.projection.set_band_increment(g);
                }
                neighbors_seconds += t.elapsed().as_secs_f64();
                Some(count)
            }
            None => None,
        };
        // the predictor's right side computed here (convection, the trapezoidal pressure term)
        // is counted in the predictor stage's time
        let t_rhs = Instant::now();
        let accel = if self.plan.has(Stage::Convection) {
            // N = (u·∇h)u (convection::ConvectionForm); AB2: −((1 + r/2) Nⁿ − (r/2) Nⁿ⁻¹)
            if self.plan.has(Stage::Ghosts) {
                let p = &mut self.particles;
                self.boundary.fill_velocity(&p.x, &p.role, &mut p.u);
            }
            let ls = (self.params.projection.gradient == GradientKind::LeastSquares).then(|| {
                let p = &self.particles;
                self.projection
                    .velocity_least_squares(&self.nl, &p.vol, &p.x, &p.role)
            });
            self.convection.accel_into(
                &self.nl,
                &self.particles.vol,
                &self.particles.x,
                &self.particles.role,
                &self.boundary,
                ls,
                &self.particles.u,
                self.params.convection,
                self.params.integrator,
                dt,
                &mut self.work,
            );
            for (a, s) in self.work.iter_mut().zip(&self.singular_accel) {
                for k in 0..D {
                    a[k] += s[k];
                }
            }
            Some(&self.work[..])
        } else if trapezoid && !self.old_pressure_grad.is_empty() {
            // the pressure gradient along the trajectory by the trapezoidal rule,
            // −½(∇pⁿ|xⁿ + ∇pⁿ|xⁿ⁺¹)/ρ: the predictor applies the second term in full, this
            // adds ½(∇pⁿ|xⁿ⁺¹ − ∇pⁿ|xⁿ)/ρ (with −∇p at the new positions alone, the velocity
            // of a particle that crosses the pressure field is first order in time)
            // (∇pⁿ|xⁿ⁺¹ is also the predictor's own pressure term: it is handed over, not
            // computed twice)
            let gnew = self.projection.pressure_gradient_for_predictor(
                &mut self.particles,
                &self.nl,
                &self.boundary,
                &self.params.projection,
            );
            let mut g = std::mem::take(&mut self.extra_accel);
            g.clear();
            g.extend(gnew.iter().enumerate().map(|(i, gi)| {
                // fluid particles keep their index; ghosts are regenerated
                let old = match self.old_pressure_grad.get(i) {
                    Some(o) if self.particles.role[i].is_fluid() => *o,
                    _ => *gi,
                };
                std::array::from_fn(|k| 0.5 * (gi[k] - old[k]))
            }));
            self.extra_accel = g;
            Some(&self.extra_accel[..])
        } else if !self.singular_accel.is_empty() {
            Some(&self.singular_accel[..])
        } else {
            None
        };
        let rhs_seconds = t_rhs.elapsed().as_secs_f64() + grad_seconds;
        let proj = &self.params.projection;
        let mut u_star = std::mem::take(&mut self.u_star);
        let pred = self.projection.predict(
            &mut self.particles,
            &self.nl,
            &self.boundary,
            proj,
            dt,
            accel,
            &mut u_star,
        )?;
        let mut report = self.projection.project(
            &mut self.particles,
            &self.nl,
            &self.boundary,
            &self.params.projection,
            dt,
            &u_star,
        )?;
        self.u_star = u_star;
        pred.add_to(&mut report);
        report.timings.predictor += rhs_seconds;
        // ∇pⁿ⁺¹ at xⁿ⁺¹ for the next step's trapezoidal term: taken when that step starts
        self.pressure_grad_due = trapezoid;
        if lagrangian {
            let p = &self.particles;
            let band = self.free_surface.is_some();
            for (i, a) in self.material_accel.iter_mut().enumerate() {
                let moves = p.role[i].is_fluid() || band && p.role[i] == Role::Dirichlet;
                *a = if moves {
                    std::array::from_fn(|k| (p.u[i][k] - a[k]) / dt)
                } else {
                    [0.0; D]
                };
            }
        }
        let max_shift = moved.max_shift;
        self.time += dt;
        if let Some(t) = land {
            self.time = t;
        }
        self.steps += 1;
        let energy_growth = self
            .prev_energy
            .filter(|&e0| e0 > 0.0)
            .map(|e0| report.kinetic_energy / e0);
        self.params.limits.guard.check_report(
            &report,
            self.params.limits.u_ref,
            &mut self.prev_energy,
            &self.particles,
            self.steps,
            self.time,
        )?;
        Ok(FlowReport {
            step: self.steps,
            time: self.time,
            dt_limit,
            neighbors_rebuilt: rebuilt,
            max_shift,
            neighbors_seconds,
            advect_seconds,
            projection: report,
            dt_ratio,
            energy_growth,
            wall_pushes: moved.wall_pushes,
            surface,
            volume_error,
        })
    }
}

/// The particle arrays agree in length with each other and the neighbour list, positions,
/// velocities and pressures of the fluid particles are finite, and their volumes positive and
/// finite (except particles without neighbours, whose number-density volume is infinite unless
/// the flow kept their last one, and which the connectivity check reports). Checked before every step, so that a bad value set
/// by the caller is named at its particle rather than surfacing later as a failed solve.
fn check_state<const D: usize>(p: &Particles<D>, nl: &NeighborList<D>) -> Result<(), InputError> {
    let n = p.x.len();
    for (field, len) in [
        ("neighbor list rows", nl.len()),
        ("u", p.u.len()),
        ("p", p.p.len()),
        ("vol", p.vol.len()),
        ("role", p.role.len()),
    ] {
        if len != n {
            return Err(InputError::LengthMismatch {
                field,
                len,
                expected: n,
            });
        }
    }
    for i in 0..p.len() {
        if !p.role[i].is_fluid() {
            continue;
        }
        let field = if !crate::math::is_finite(&p.x[i]) {
            "position"
        } else if !crate::math::is_finite(&p.u[i]) {
            "velocity"
        } else if !p.p[i].is_finite() {
            "pressure"
        } else if !nl.row(i).is_empty()
            && (p.vol[i].is_nan() || p.vol[i] <= 0.0 || p.vol[i].is_infinite())
        {
            return Err(InputError::BadVolume {
                particle: i,
                value: p.vol[i],
            });
        } else {
            continue;
        };
        return Err(InputError::NonFinite { field, particle: i });
    }
    Ok(())
}
