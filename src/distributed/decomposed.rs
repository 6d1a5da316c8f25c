//! A [`Simulation`] whose particles are decomposed over the ranks (issue 18): each rank holds
//! its own fluid particles and a halo of copies of other ranks' particles near its box, runs
//! the ordinary step on them, and the two global solves of the step (the implicit viscous one
//! and the Poisson one) go through the distributed CG on the ranks' local systems
//! ([`DistributedPoisson::set_local`]).
//!
//! Why the step itself needs no change: an own particle's predictor reads its neighbours within
//! `h` (all in the halo), the global solves write the own and halo unknowns, and the correction
//! reads `φ` within `h` again. Everything computed *at* halo particles is discarded (their
//! neighbourhoods are cut at the halo's edge); the halo is deep enough that what the own rows
//! read of it is right ([`HALO_LAYERS_FIXED`], [`HALO_LAYERS_MOVING`]). Where the step reads a
//! value it has just computed at a halo particle beyond that (the pressure before its
//! smoothing), the projection refreshes the halo from the owners ([`HaloSync`]). `Δt` is the
//! minimum over the ranks; the guard's checks (energy growth, speed, correction ratio, the
//! Theorem 4.5 ratio) are taken over every rank's own particles.
//!
//! **Fixed particles** (Eulerian): the halo is planned once; before every step its velocity
//! and pressure are refreshed from the owners. **Moving particles** (Lagrangian): after every
//! step each rank sends its own particles to the ranks whose boxes hold their new positions
//! ([`migrate`]), with what the next step needs of them (velocity, pressure, number-density
//! volume, material acceleration: [`CarriedState`]); the cut of space is drawn again
//! ([`RcbTree::balance`]) when the largest rank holds more than [`DecomposedRun::imbalance_limit`]
//! times the mean; then the halo is planned and exchanged again and the rank's local
//! simulation built anew on its particles. The trapezoidal pressure term's gradient at the old
//! positions is taken when the next step starts, from the owners' pressures.
//!
//! **A free surface** (the Dirichlet band of a detected surface): each rank detects it on its
//! particles every step (own ones right: their neighbourhoods are whole), the band travels
//! with the particles' records, and where the projection extends the water's velocity into
//! the band it first takes the halo's `u*` and corrected velocity from their owners
//! ([`HaloSync`]); the step's surface and splash counts are summed over the own particles.
//!
//! Limits: the setup reads the whole scene on every rank (each keeps its share); the diagnostics in the step's report are the rank's own (the global
//! ones: [`DecomposedRun::global_diagnostics`]); the local simulation of a moving run is
//! rebuilt every step (neighbour search included), where the single-process run keeps its
//! candidates while the particles stay within the skin.

use super::comm::Comm;
use super::decomposition::{migrate, ParticleHalo, RcbTree};
use super::diagnostics::{step_diagnostics, GlobalDiagnostics};
use super::driver::Shared;
use super::solver::{DdPreconditioner, DistributedPoisson, Traffic};
use crate::boundary::Boundary;
use crate::diagnostics::connectivity;
use crate::error::{DtLimit, Error, InputError, StabilityError};
use crate::flow::{
    CarriedState, FlowParams, FlowReport, FreeSurface, Motion, Simulation, StabilityGuard,
    SurfaceCount,
};
use crate::neighbors::NeighborConfig;
use crate::particles::{Particles, Role};
use crate::projection::{HaloSync, ProjectionStep, ViscousRule};
use std::sync::{Arc, Mutex};

/// Depth of the particle halo in `h + skin` for fixed particles: what an own row reads at
/// a halo particle (its number-density volume, the explicit terms) is complete within one
/// `h` of it.
pub const HALO_LAYERS_FIXED: f64 = 2.0;

/// Depth of the particle halo in `h + skin` for moving particles. The longest chain of reads
/// within one step, counted from an own row: its Poisson and viscous rows read the volumes
/// `ωⱼ` at the moved positions of the particles within `h` (1), each volume the moved
/// positions within `h` of that particle (2), each moved position the state before the move
/// within `h` (the shift, the Taylor correction's gradients: 3) — the volumes before the move
/// travel with the particles, so the chain stops there. The second derivatives of the Taylor
/// correction reach one `h` further, but only into the velocity of an own particle. Measured
/// (`tests/distributed.rs`): 2 layers already reproduce the single-process run (the third
/// link's pairs near `h` weigh almost nothing, and the default shift reads only `Δx`), 1 does
/// not.
pub const HALO_LAYERS_MOVING: f64 = 3.0;

/// The numbers carried with a particle when it migrates or is copied into a halo, besides
/// its position: global id, velocity, pressure, volume, material acceleration, the Poisson
/// warm start's last two increments `φⁿ`, `φⁿ⁻¹`, whether it is in the Dirichlet band (a
/// free surface's particles shift only along the surface), and the viscous solve's last
/// change `u − r` (its warm start, [`crate::poisson::HelmholtzSolver::warm_change`]). (The
/// pressure gradient of the trapezoidal term is taken when the next step starts, from these.)
const fn record_width(d: usize) -> usize {
    6 + 3 * d
}

/// The limits that set `Δt`, by the code the ranks exchange.
const LIMITS: [DtLimit; 5] = [
    DtLimit::Cfl,
    DtLimit::Viscous,
    DtLimit::Force,
    DtLimit::Max,
    DtLimit::Fixed,
];

/// A rank's part of a decomposed simulation.
pub struct DecomposedRun<C: Comm + Clone + 'static, const D: usize, B: Boundary<D>> {
    ctx: Context<C, D, B>,
    /// The rank's simulation: its own fluid particles first, then the halo, then ghosts.
    pub sim: Simulation<D, B>,
    /// Global index (in the scene's particle order) of each local fluid particle.
    gid: Vec<u32>,
    n_own: usize,
    halo: ParticleHalo,
    /// The particles moved since the local simulation was built: migrate, re-balance and
    /// rebuild before the next step.
    moved: bool,
    /// Re-balance (a new cut of space) when the largest rank holds more than this times the
    /// mean number of particles (default 1.1).
    pub imbalance_limit: f64,
    /// The global kinetic energy after the last step (the guard's growth check).
    prev_energy: Option<f64>,
}

/// What a rank keeps to build its local simulation again.
struct Context<C: Comm + Clone + 'static, const D: usize, B: Boundary<D>> {
    comm: C,
    tree: RcbTree<D>,
    /// The scene's boundary, neighbour settings and parameters.
    boundary: B,
    config: NeighborConfig<D>,
    params: FlowParams<D>,
    free_surface: Option<FreeSurface>,
    /// Whether the global Poisson problem has the constants as null space.
    floating: bool,
    /// Depth of the particle halo (distance from the rank's box).
    reach: f64,
    counts: DecompositionCounts,
    /// The Poisson solver (shared with the projection, which calls it).
    poisson: Arc<Mutex<DistributedPoisson<C>>>,
    /// The implicit viscous solver (Jacobi-CG, no null space).
    viscous: Arc<Mutex<DistributedPoisson<C>>>,
}

/// A rank's local particles: the simulation, global ids, own count, halo plan.
type Local<const D: usize, B> = (Simulation<D, B>, Vec<u32>, usize, ParticleHalo);

/// What the decomposition of a moving run did so far (this rank's counts).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct DecompositionCounts {
    /// Local simulations built (one at the start, then one per step of a moving run).
    pub rebuilds: u64,
    /// New cuts of space after the first.
    pub rebalances: u64,
    /// Own particles sent to another rank (they left this rank's box).
    pub migrated: u64,
    /// Halo particles received, summed over the rebuilds.
    pub halo_received: u64,
    /// Particles sent to (or, on the root, received by) the gathered copy
    /// ([`DecomposedRun::gather_into`]).
    pub gathered: u64,
}

impl<C: Comm + Clone + 'static, const D: usize, B: Boundary<D> + Clone> DecomposedRun<C, D, B> {
    /// This rank's part of the scene `global` (every rank passes the same one): the particles
    /// cut by a parallel RCB, the halo exchanged, a local simulation with the scene's boundary,
    /// neighbour settings and parameters, and the distributed solvers installed. Fixed
    /// particles (Eulerian) and moving ones (Lagrangian: after every step the particles
    /// migrate to the rank whose box holds them, with their carried state, the cut is
    /// re-balanced when needed, and the halo and local simulation are built again). A free
    /// surface (the Dirichlet band) is detected by each rank on its particles; a Dirichlet
    /// band without a free-surface detection is refused.
    pub fn new(comm: C, global: &Simulation<D, B>) -> Result<Self, Error> {
        let (p, me) = (comm.size(), comm.rank());
        let gp = &global.particles;
        let free_surface = global.free_surface();
        if gp.role.contains(&Role::Dirichlet) && free_surface.is_none() {
            return Err(InputError::parameter(
                "role",
                0.0,
                "the particle decomposition runs a Dirichlet band only as a detected free \
                 surface",
            )
            .into());
        }
        if global.projection.singular.is_some() {
            return Err(InputError::parameter(
                "corner_subtraction",
                1.0,
                "the particle decomposition does not carry a singular part (run it on one \
                 process)",
            )
            .into());
        }
        if global.params.projection.source_ghosts == crate::boundary::VectorKind::RestWallsLinear {
            return Err(InputError::parameter(
                "source_ghosts",
                0.0,
                "the particle decomposition does not carry the rest_walls_linear rule's \
                 wall-normal partners across ranks (run it on one process, or use rest_walls)",
            )
            .into());
        }
        let moving = global.params.motion != Motion::Eulerian;
        let config = *global.nl.config();
        let layers = if moving {
            HALO_LAYERS_MOVING
        } else {
            HALO_LAYERS_FIXED
        };
        let fluid: Vec<usize> = (0..gp.len()).filter(|&i| gp.role[i].is_real()).collect();
        let share: Vec<usize> = fluid.iter().copied().filter(|i| i % p == me).collect();
        let x: Vec<[f64; D]> = share.iter().map(|&i| gp.x[i]).collect();
        let tree = RcbTree::balance(&comm, &x);
        let carried = global.carried_state();
        let records = pack(
            gp,
            &carried,
            &global.projection,
            share.iter().map(|&i| (i, i as u32)),
        );
        let comps = connectivity(&global.nl, &gp.role);
        // a free surface anchors the pressure (its band is detected every step)
        let floating = free_surface.is_none() && !comps.floating().is_empty();
        let new_solver = |pre: Option<DdPreconditioner>| {
            let mut s = DistributedPoisson::new(comm.clone());
            if let Some(pre) = pre {
                s.preconditioner = pre;
            }
            Arc::new(Mutex::new(s))
        };
        let poisson = new_solver(None);
        let viscous = new_solver(Some(DdPreconditioner::Jacobi));
        let (own_x, own_recs) = migrate(&comm, &tree, &x, &records, record_width(D));
        let mut ctx = Context {
            comm,
            tree,
            boundary: global.boundary.clone(),
            config,
            params: global.params,
            free_surface,
            floating,
            reach: layers * (config.h + config.skin),
            counts: DecompositionCounts::default(),
            poisson,
            viscous,
        };
        let (sim, gid, n_own, halo) = ctx.build(
            own_x,
            own_recs,
            !carried.material_accel.is_empty(),
            carried.pressure_grad_due,
            (global.time, global.steps),
            WarmHistory::of(&global.projection),
        )?;
        Ok(DecomposedRun {
            ctx,
            sim,
            gid,
            n_own,
            halo,
            moved: false,
            imbalance_limit: 1.1,
            prev_energy: global.prev_energy(),
        })
    }

    /// After a moving step: every own particle to the rank whose box holds it (a new cut of
    /// space first when the ranks' counts drift apart), with its record, and the local
    /// simulation built again.
    fn redistribute(&mut self) -> Result<(), Error> {
        let n_own = self.n_own;
        let p = &self.sim.particles;
        let carried = self.sim.carried_state();
        let warm = WarmHistory::of(&self.sim.projection);
        let records = pack(
            p,
            &carried,
            &self.sim.projection,
            (0..n_own).map(|i| (i, self.gid[i])),
        );
        let x: Vec<[f64; D]> = p.x[..n_own].to_vec();
        let ctx = &mut self.ctx;
        let largest = ctx.comm.max(&[n_own as f64])[0];
        let mean = ctx.comm.sum(&[n_own as f64])[0] / ctx.comm.size() as f64;
        if largest > self.imbalance_limit * mean {
            ctx.tree = RcbTree::balance(&ctx.comm, &x);
            ctx.counts.rebalances += 1;
        }
        let me = ctx.comm.rank();
        ctx.counts.migrated += x.iter().filter(|xi| ctx.tree.owner(xi) != me).count() as u64;
        let (x, records) = migrate(&ctx.comm, &ctx.tree, &x, &records, record_width(D));
        let clock = (self.sim.time, self.sim.steps);
        let (accel, grad) = (
            !carried.material_accel.is_empty(),
            carried.pressure_grad_due,
        );
        (self.sim, self.gid, self.n_own, self.halo) =
            ctx.build(x, records, accel, grad, clock, warm)?;
        self.moved = false;
        Ok(())
    }
}

impl<C: Comm + Clone + 'static, const D: usize, B: Boundary<D> + Clone> Context<C, D, B> {
    /// The local simulation for the own particles at `x` with their `records`: the halo
    /// planned and exchanged, the simulation built from the scene's settings with the owners'
    /// volumes and carried state, and the distributed solvers set to the new local systems.
    fn build(
        &mut self,
        x: Vec<[f64; D]>,
        records: Vec<f64>,
        accel: bool,
        grad: bool,
        clock: (f64, u64),
        warm: WarmHistory,
    ) -> Result<Local<D, B>, Error> {
        let w = record_width(D);
        let n_own = x.len();
        let halo = ParticleHalo::new(
            &self.comm,
            &self.tree,
            &x,
            self.reach,
            &self.config.periodic,
        );
        let mut own = Vec::with_capacity(n_own * (D + w));
        for (xi, rec) in x.iter().zip(records.chunks_exact(w)) {
            own.extend_from_slice(xi);
            own.extend_from_slice(rec);
        }
        let got = halo.exchange(&self.comm, &own, D + w);
        let all: Vec<&[f64]> = own
            .chunks_exact(D + w)
            .chain(got.chunks_exact(D + w))
            .collect();
        let mut local = Particles::new();
        let mut carried = CarriedState {
            pressure_grad_due: grad,
            ..Default::default()
        };
        let mut gid = Vec::with_capacity(all.len());
        let (mut phi, mut phi_prev) = (Vec::new(), Vec::new());
        let mut change = Vec::with_capacity(all.len() * D);
        for rec in &all {
            let xi: [f64; D] = std::array::from_fn(|a| rec[a]);
            let r = &rec[D..];
            let u: [f64; D] = std::array::from_fn(|a| r[1 + a]);
            let role = if r[5 + 2 * D] != 0.0 {
                Role::Dirichlet
            } else {
                Role::Fluid
            };
            local.push(xi, u, r[1 + D], r[2 + D], role);
            gid.push(r[0] as u32);
            phi.push(r[3 + 2 * D]);
            phi_prev.push(r[4 + 2 * D]);
            change.extend_from_slice(&r[6 + 2 * D..6 + 3 * D]);
            if accel {
                carried
                    .material_accel
                    .push(std::array::from_fn(|a| r[3 + D + a]));
            }
        }
        let (vol, role, pressure) = (local.vol.clone(), local.role.clone(), local.p.clone());
        let mut sim = Simulation::new(local, self.boundary.clone(), self.config, self.params)?;
        if let Some(fs) = self.free_surface {
            sim = sim.with_free_surface(fs)?;
        }
        // the owners' volumes, band and pressures: a halo particle's neighbourhood is cut at
        // the halo's edge (and the detection at construction resets the band's pressure)
        let n_real = vol.len();
        sim.particles.vol[..n_real].copy_from_slice(&vol);
        sim.particles.role[..n_real].copy_from_slice(&role);
        sim.particles.p[..n_real].copy_from_slice(&pressure);
        sim.boundary.place_ghosts(&mut sim.particles);
        sim.set_carried_state(carried)?;
        // the ghosts' entries are not unknowns: zero
        let n = sim.particles.len();
        if let Some((dt_prev, before)) = warm.poisson {
            phi.resize(n, 0.0);
            phi_prev.resize(if before { n } else { 0 }, 0.0);
            sim.projection.set_warm_start(phi, phi_prev, dt_prev);
        }
        if warm.viscous_c > 0.0 {
            change.resize(n * D, 0.0);
            sim.projection
                .viscous
                .set_warm_change(change, warm.viscous_c);
        }
        *sim.projection.viscous_rule_mut() = warm.viscous_rule;
        (sim.time, sim.steps) = (clock.0, clock.1);
        sim.projection.solver.external = Some(Box::new(Shared(self.poisson.clone())));
        sim.projection.viscous.external = Some(Box::new(Shared(self.viscous.clone())));
        sim.projection.halo = Some(Box::new(Sync {
            comm: self.comm.clone(),
            halo: halo.clone(),
            n_own,
        }));
        let n = sim.particles.len();
        let me = self.comm.rank() as u32;
        let mut owner = vec![me; n];
        let mut k = n_own;
        for &(q, count) in &halo.recvs {
            owner[k..k + count].fill(q as u32);
            k += count;
        }
        let mut full_gid = gid.clone();
        full_gid.resize(n, u32::MAX);
        for (s, floating) in [(&self.poisson, self.floating), (&self.viscous, false)] {
            let mut s = s.lock().expect("distributed solver lock");
            s.set_local(full_gid.clone(), owner.clone(), floating);
        }
        self.counts.rebuilds += 1;
        self.counts.halo_received += halo.n_halo() as u64;
        Ok((sim, gid, n_own, halo))
    }
}

/// The solvers' warm-start histories to hand on besides the per-particle values of the
/// records: the Poisson problem's last `Δt` once a step was taken and whether the increment
/// before the last one is there too, the `c` of the viscous solve's last change (0:
/// none), and the adaptive viscous tolerance's state.
#[derive(Clone, Copy, Debug)]
struct WarmHistory {
    poisson: Option<(f64, bool)>,
    viscous_c: f64,
    viscous_rule: ViscousRule,
}

impl WarmHistory {
    fn of<const D: usize>(projection: &ProjectionStep<D>) -> Self {
        let (phi, phi_prev, dt_prev) = projection.warm_start();
        WarmHistory {
            poisson: (dt_prev > 0.0 && !phi.is_empty()).then_some((dt_prev, !phi_prev.is_empty())),
            viscous_c: projection.viscous.warm_change().1,
            viscous_rule: projection.viscous_rule(),
        }
    }
}

/// The copies of other ranks' particles refreshed from their owners, for the projection.
#[derive(Debug)]
struct Sync<C: Comm> {
    comm: C,
    halo: ParticleHalo,
    n_own: usize,
}

impl<C: Comm> HaloSync for Sync<C> {
    fn sync(&mut self, values: &mut [f64], width: usize) {
        let (own, halo) = (self.n_own * width, self.halo.n_halo() * width);
        let got = self.halo.exchange(&self.comm, &values[..own], width);
        values[own..own + halo].copy_from_slice(&got);
    }

    fn own(&self) -> Option<usize> {
        Some(self.n_own)
    }
}

/// The records (see [`record_width`]) of the particles `(i, global id)` of `p`.
fn pack<const D: usize>(
    p: &Particles<D>,
    carried: &CarriedState<D>,
    projection: &ProjectionStep<D>,
    which: impl Iterator<Item = (usize, u32)>,
) -> Vec<f64> {
    let (phi, phi_prev, _) = projection.warm_start();
    let change = projection.viscous.warm_change().0;
    let mut out = Vec::new();
    for (i, g) in which {
        out.push(g as f64);
        out.extend_from_slice(&p.u[i]);
        out.push(p.p[i]);
        out.push(p.vol[i]);
        out.extend_from_slice(&carried.material_accel.get(i).copied().unwrap_or([0.0; D]));
        out.push(phi.get(i).copied().unwrap_or(0.0));
        out.push(phi_prev.get(i).copied().unwrap_or(0.0));
        out.push((p.role[i] == Role::Dirichlet) as u8 as f64);
        let c = change.get(i * D..(i + 1) * D).unwrap_or(&[0.0; D]);
        out.extend_from_slice(c);
    }
    out
}

impl<C: Comm + Clone + 'static, const D: usize, B: Boundary<D> + Clone> DecomposedRun<C, D, B> {
    /// Own fluid particles of this rank.
    pub fn n_own(&self) -> usize {
        self.n_own
    }

    /// The scene index of each own particle (the first [`Self::n_own`] of [`Self::sim`]).
    pub fn own_ids(&self) -> &[u32] {
        &self.gid[..self.n_own]
    }

    /// The scene index of each local fluid particle (own, then halo).
    pub fn local_ids(&self) -> &[u32] {
        &self.gid
    }

    /// The cut of space.
    pub fn tree(&self) -> &RcbTree<D> {
        &self.ctx.tree
    }

    /// The preconditioner of the distributed Poisson CG (default: [`DdPreconditioner`]'s)
    /// and its coarse aggregates' target size (collective in effect: every rank must set the
    /// same before the next step).
    pub fn set_preconditioner(&mut self, pre: DdPreconditioner, aggregate_size: usize) {
        let mut p = self.ctx.poisson.lock().expect("distributed solver lock");
        p.preconditioner = pre;
        p.aggregate_size = aggregate_size;
    }

    /// Bytes of one particle's message (position and record) in a migration or halo exchange.
    pub fn particle_bytes(&self) -> usize {
        8 * (D + record_width(D))
    }

    /// What the decomposition did so far on this rank.
    pub fn counts(&self) -> DecompositionCounts {
        self.ctx.counts
    }

    /// Messages and volumes of this rank's global solves so far (the Poisson and the implicit
    /// viscous ones, added).
    pub fn traffic(&self) -> Traffic {
        let a = self
            .ctx
            .poisson
            .lock()
            .expect("distributed solver lock")
            .traffic();
        let b = self
            .ctx
            .viscous
            .lock()
            .expect("distributed solver lock")
            .traffic();
        Traffic {
            messages: a.messages + b.messages,
            bytes: a.bytes + b.bytes,
            reductions: a.reductions + b.reductions,
            reduced_values: a.reduced_values + b.reduced_values,
            gathered_bytes: a.gathered_bytes + b.gathered_bytes,
            solves: a.solves + b.solves,
            iterations: a.iterations + b.iterations,
        }
    }

    /// Halo particles of this rank now.
    pub fn n_halo(&self) -> usize {
        self.halo.n_halo()
    }

    /// One step of every rank (collective). Moving particles: the own particles migrate
    /// after the last step and the local simulation is built again (halo included);
    /// fixed ones: the halo's velocity and pressure from their owners. `Δt` (and the speed
    /// of a Fickian shift with a global speed) the extreme over the ranks, then the rank's
    /// step. The report is the step's over every rank's own particles: its diagnostics
    /// (connectivity, `c0`, minimum spacing, the divergences, the Theorem 4.5 ratio, energy,
    /// speed, correction ratio, shifts, wall pushes, surface counts, the limit that set `Δt`)
    /// are global and the same on every rank; its timings are this rank's.
    pub fn advance(&mut self) -> Result<FlowReport, Error> {
        self.advance_inner(None)
    }

    /// [`Self::advance`] ending at time `t` at the latest, as
    /// [`Simulation::advance_toward`] (the same shortened last step on every rank).
    pub fn advance_toward(&mut self, t: f64) -> Result<FlowReport, Error> {
        self.advance_inner(Some(t))
    }

    fn advance_inner(&mut self, until: Option<f64>) -> Result<FlowReport, Error> {
        if self.moved {
            self.redistribute()?;
        } else {
            let w = D + 1;
            let p = &self.sim.particles;
            let mut own = Vec::with_capacity(self.n_own * w);
            for i in 0..self.n_own {
                own.extend_from_slice(&p.u[i]);
                own.push(p.p[i]);
            }
            let got = self.halo.exchange(&self.ctx.comm, &own, w);
            let p = &mut self.sim.particles;
            for (k, rec) in got.chunks_exact(w).enumerate() {
                let i = self.n_own + k;
                p.u[i] = std::array::from_fn(|a| rec[a]);
                p.p[i] = rec[D];
            }
        }
        self.sim.params.limits = self.ctx.params.limits;
        let (dt, limit) = self.sim.time_step();
        let p = &self.sim.particles;
        let speed = (0..self.n_own)
            .map(|i| p.u[i].iter().map(|c| c * c).sum::<f64>().sqrt())
            .fold(0.0, f64::max);
        let m = self.ctx.comm.max(&[-dt, speed]);
        // the limit that set Δt: the one of the first rank whose Δt is the smallest
        let code = |l: DtLimit| LIMITS.iter().position(|&k| k == l).unwrap_or(0) as f64;
        let limit = self
            .ctx
            .comm
            .all_gather(&[dt, code(limit)])
            .iter()
            .find(|v| v[0] == -m[0])
            .and_then(|v| LIMITS.get(v[1] as usize).copied())
            .unwrap_or(limit);
        self.sim.params.limits.dt_fixed = Some(-m[0]);
        self.sim.shift_speed = Some(m[1]);
        // the volume shift's mean fluid volume: over every rank's own particles
        let volume_shift = self.sim.params.motion != Motion::Eulerian
            && self.sim.params.shifting.is_some_and(|s| s.volume > 0.0);
        if volume_shift {
            let p = &self.sim.particles;
            let (sum, count) = (0..self.n_own)
                .filter(|&i| p.role[i] == Role::Fluid)
                .fold((0.0, 0.0), |(s, c), i| (s + p.vol[i], c + 1.0));
            let g = self.ctx.comm.sum(&[sum, count]);
            self.sim.volume_mean = (g[1] > 0.0).then(|| g[0] / g[1]);
        }
        // the report's guard checks over every rank's own particles (the local sums hold the
        // halo, whose values after the step are not all right, and a rank's energy can grow
        // faster than the whole's): only the time-step check stays local (a rank's bound
        // covers its own particles, and the halo's are not smaller)
        let guard = self.ctx.params.limits.guard;
        self.sim.params.limits.guard = StabilityGuard {
            dt_over_limit: guard.dt_over_limit,
            ..Default::default()
        };
        let report = match until {
            Some(t) => self.sim.advance_toward(t),
            None => self.sim.advance(),
        };
        self.moved = self.sim.params.motion != Motion::Eulerian;
        // every rank takes part in the global sums, also one whose step failed
        let mut report = match report {
            Ok(r) => r,
            Err(e) => {
                let _ = self.globalize(&guard, None);
                return Err(e);
            }
        };
        self.globalize(&guard, Some(&mut report))?;
        // Δt was fixed on every rank: name the limit that set it, unless the step was
        // shortened to land on `until`
        if until.is_none_or(|t| report.time != t) {
            report.dt_limit = limit;
        }
        if report.surface.is_some() {
            report.surface = Some(self.surface_count());
        }
        Ok(report)
    }

    /// The free surface's particles and splashes over every rank's own particles (the local
    /// detection also flags the halo's outer edge, whose neighbourhoods are cut).
    fn surface_count(&self) -> SurfaceCount {
        let (p, nl) = (&self.sim.particles, &self.sim.nl);
        let band = |i: &usize| p.role[*i] == Role::Dirichlet;
        let surface = (0..self.n_own).filter(band).count();
        let splash = (0..self.n_own)
            .filter(band)
            .filter(|&i| {
                !nl.row(i).any(|k| {
                    nl.w()[k] > 0.0
                        && crate::diagnostics::alias(&p.role, nl.indices()[k] as usize).is_some()
                })
            })
            .count();
        let s = self.ctx.comm.sum(&[surface as f64, splash as f64]);
        SurfaceCount {
            surface: s[0] as usize,
            splash: s[1] as usize,
        }
    }

    /// The step's report over the own particles of every rank, and the scene's guard on it
    /// (collective): energy, speed, correction ratio, divergences, minimum spacing, shifts
    /// and wall pushes from global sums and extremes, connectivity, `c0` and the Theorem 4.5
    /// ratio from [`Self::global_diagnostics`]. A rank whose step failed passes `None`; the
    /// others then fail with [`Error::PeerFailed`].
    fn globalize(
        &mut self,
        guard: &StabilityGuard,
        report: Option<&mut FlowReport>,
    ) -> Result<(), Error> {
        let failed = report.is_none() as u8 as f64;
        let p = &self.sim.particles;
        let (u_star, vol, rho) = (
            self.sim.projection.u_star(),
            &p.vol,
            self.sim.params.projection.rho,
        );
        let (src, div, disconnected) = self.sim.projection.rank_diagnostics();
        // sums: energy, ‖u − u*‖², ‖u*‖², failed ranks, ‖D f‖², ‖D u‖², disconnected, pushes,
        // the Poisson system's unknowns and entries, the volume shift's Σe² and count
        let mut sums = [0.0; 12];
        // maxima: −(smallest squared spacing), largest shift, Δt over its bound, the
        // divergence's gain bound over the own rows (the adaptive viscous tolerance's `G`)
        let mut extremes = [f64::NEG_INFINITY; 4];
        let mut fastest = (0usize, -1.0f64);
        if let Some(report) = report.as_deref() {
            let nl = &self.sim.nl;
            for i in (0..self.n_own).filter(|&i| p.role[i].is_fluid()) {
                let u2: f64 = p.u[i].iter().map(|c| c * c).sum();
                sums[0] += 0.5 * rho * vol[i] * u2;
                let d2: f64 = (0..D).map(|a| (p.u[i][a] - u_star[i][a]).powi(2)).sum();
                sums[1] += vol[i] * d2;
                sums[2] += vol[i] * u_star[i].iter().map(|c| c * c).sum::<f64>();
                sums[4] += vol[i] * src.get(i).map_or(0.0, |v| v * v);
                sums[5] += vol[i] * div.get(i).map_or(0.0, |v| v * v);
                if u2 > fastest.1 {
                    fastest = (i, u2);
                }
                let r2 = nl.row(i).map(|k| nl.r2(k)).fold(f64::INFINITY, f64::min);
                extremes[0] = extremes[0].max(-r2);
            }
            sums[6] = disconnected.iter().filter(|&&i| i < self.n_own).count() as f64;
            // the shifts and wall pushes of the own particles (the halo's are counted by
            // their owners, and the outer ones' are not right)
            extremes[1] = 0.0;
            if self.sim.params.motion != Motion::Eulerian {
                for i in 0..self.n_own {
                    if let Some((shift, pushed)) = self.sim.last_move(i) {
                        extremes[1] = extremes[1].max(shift);
                        sums[7] += pushed as u8 as f64;
                    }
                }
            }
            extremes[2] = report.dt_ratio;
            extremes[3] = self.sim.projection.viscous_rule().gain;
            if report.volume_error.is_some() {
                let (sq, count) = self.sim.projection.volume_error_sums(p, self.n_own);
                (sums[10], sums[11]) = (sq, count as f64);
            }
        }
        sums[3] = failed;
        // the Poisson system's unknowns and entries: the own rows'
        let (unknowns, nnz) = {
            let dd = self.ctx.poisson.lock().expect("distributed solver lock");
            let rows = dd.rows();
            let m = rows.n_own();
            (m as f64, rows.offsets.get(m).copied().unwrap_or(0) as f64)
        };
        (sums[8], sums[9]) = (unknowns, nnz);
        let s = self.ctx.comm.sum(&sums);
        let e = self.ctx.comm.max(&extremes);
        // the fastest particle of all: speed, global id and position from every rank
        let mut mine = vec![fastest.1.max(0.0).sqrt(), -1.0];
        mine.extend_from_slice(&[0.0; D]);
        if fastest.1 >= 0.0 {
            mine[1] = self.gid[fastest.0] as f64;
            mine[2..].copy_from_slice(&p.x[fastest.0]);
        }
        let best = self
            .ctx
            .comm
            .all_gather(&mine)
            .into_iter()
            .fold(mine.clone(), |a, b| if b[0] > a[0] { b } else { a });
        if s[3] > failed {
            return Err(Error::PeerFailed {
                step: self.sim.steps + 1,
                ranks: (s[3] - failed) as usize,
            });
        }
        let Some(report) = report else {
            return Ok(());
        };
        // the step's own Δt (a step landing on an end time is shorter than the limits')
        let dt = report.projection.dt;
        let g = self.global_diagnostics(dt);
        let global = &mut report.projection;
        global.connectivity = g.connectivity;
        global.c0 = g.c0;
        global.stability_ratio = g.stability_ratio;
        global.kinetic_energy = s[0];
        global.max_speed = best[0];
        global.correction_ratio = if s[2] > 0.0 {
            (s[1] / s[2]).sqrt()
        } else {
            0.0
        };
        global.solve.unknowns = s[8] as usize;
        global.solve.nnz = s[9] as usize;
        global.div_before = s[4].sqrt() / rho * dt;
        global.div_after = s[5].sqrt();
        // the next viscous solve's tolerance, alike on every rank
        let rule = self.sim.projection.viscous_rule_mut();
        rule.gain = e[3];
        rule.update(
            self.ctx.params.projection.solve.viscous_adaptive,
            global.solve.initial_rel_residual,
            global.div_before,
            s[2].sqrt(),
        );
        global.min_spacing = (-e[0]).sqrt();
        let allowed = self.ctx.params.projection.allowed_floating;
        let c = g.connectivity;
        global.disconnected = if c.isolated == 0 && c.floating <= allowed {
            0
        } else {
            s[6] as usize
        };
        report.wall_pushes = s[7] as usize;
        if report.volume_error.is_some() {
            report.volume_error = Some((s[10] / s[11].max(1.0)).sqrt());
        }
        report.max_shift = e[1];
        report.dt_ratio = e[2];
        report.energy_growth = self.prev_energy.filter(|&e0| e0 > 0.0).map(|e0| s[0] / e0);
        // the fastest particle, as the guard names it
        let mut one = Particles::new();
        let x: [f64; D] = std::array::from_fn(|a| best[2 + a]);
        let u: [f64; D] = std::array::from_fn(|a| if a == 0 { best[0] } else { 0.0 });
        one.push(x, u, 0.0, 1.0, Role::Fluid);
        let mut prev = self.prev_energy;
        let out = guard.check_report(
            &report.projection,
            self.ctx.params.limits.u_ref,
            &mut prev,
            &one,
            report.step,
            report.time,
        );
        self.prev_energy = prev;
        out.map_err(|e| match e {
            StabilityError::BlowUp {
                step,
                time,
                quantity,
                value,
                bound,
                position,
                speed,
                ..
            } => StabilityError::BlowUp {
                step,
                time,
                quantity,
                value,
                bound,
                particle: best[1].max(0.0) as usize,
                position,
                speed,
            },
            e => e,
        })?;
        Ok(())
    }

    /// Every rank's own particles into `view` on rank `root` (collective): the copy of the
    /// whole scene that scenes observe and recordings write (`view` is the simulation the
    /// run was made from, every rank's). On `root` the real particles' positions,
    /// velocities, pressures, volumes and band are the ranks' and, for moving particles, the
    /// ghosts and neighbours are brought to the new positions
    /// (`Simulation::load_real_state`); on every rank the clock is the run's. Costs a
    /// message of `8 (4 + 2d)` bytes per own particle to `root`, and on `root` a neighbour
    /// update of the whole scene per call.
    pub fn gather_into(&mut self, view: &mut Simulation<D, B>, root: usize) -> Result<(), Error> {
        let comm = &self.ctx.comm;
        let (me, w) = (comm.rank(), 4 + 2 * D);
        let p = &self.sim.particles;
        let mut mine = Vec::with_capacity(self.n_own * w);
        for i in 0..self.n_own {
            mine.push(self.gid[i] as f64);
            mine.extend_from_slice(&p.x[i]);
            mine.extend_from_slice(&p.u[i]);
            mine.extend_from_slice(&[p.p[i], p.vol[i]]);
            mine.push((p.role[i] == Role::Dirichlet) as u8 as f64);
        }
        let counts = comm.all_gather(&[self.n_own as f64]);
        let sends: Vec<(usize, Vec<f64>)> = if me == root {
            Vec::new()
        } else {
            vec![(root, mine.clone())]
        };
        let mut recvs: Vec<(usize, Vec<f64>)> = if me == root {
            (0..comm.size())
                .filter(|&q| q != root)
                .map(|q| (q, vec![0.0; counts[q][0] as usize * w]))
                .collect()
        } else {
            Vec::new()
        };
        comm.exchange(&sends, &mut recvs);
        let clock = (self.sim.time, self.sim.steps);
        if me != root {
            self.ctx.counts.gathered += self.n_own as u64;
            (view.time, view.steps) = clock;
            return Ok(());
        }
        let n = view.particles.len();
        let rows = std::iter::once(&mine)
            .chain(recvs.iter().map(|(_, v)| v))
            .flat_map(|v| v.chunks_exact(w));
        let mut checked = Vec::with_capacity(n);
        for r in rows {
            let i = r[0] as usize;
            if i >= n || !view.particles.role[i].is_real() {
                return Err(InputError::parameter(
                    "view",
                    i as f64,
                    "the gathered copy is not the simulation the decomposed run was made from",
                )
                .into());
            }
            checked.push((
                i,
                std::array::from_fn(|a| r[1 + a]),
                std::array::from_fn(|a| r[1 + D + a]),
                r[1 + 2 * D],
                r[2 + 2 * D],
                r[3 + 2 * D] != 0.0,
            ));
        }
        self.ctx.counts.gathered += (checked.len() - self.n_own) as u64;
        let moved = self.ctx.params.motion != Motion::Eulerian;
        view.load_real_state(checked.into_iter(), moved, clock)
    }

    /// The global diagnostics of the step just taken (collective): components joined through
    /// the halo, `c0` over every rank's own rows, the norms and the Theorem 4.5 ratio by sums
    /// (`dt` the step's `Δt`).
    pub fn global_diagnostics(&mut self, dt: f64) -> GlobalDiagnostics {
        let mut dd = self.ctx.poisson.lock().expect("distributed solver lock");
        step_diagnostics(&mut dd, &self.sim, dt)
    }
}
