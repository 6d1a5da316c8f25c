//! A [`Simulation`] whose particles are decomposed over the ranks (issue 18, the full
//! decomposition for fixed particles): each rank holds its own fluid particles and a halo of
//! copies of other ranks' particles within `2(h + skin)` of its box, runs the ordinary step on
//! them, and the two global solves of the step (the implicit viscous one and the Poisson one)
//! go through the distributed CG on the ranks' local systems
//! ([`DistributedPoisson::set_local`]).
//!
//! Why the step itself needs no change: before every step the halo's velocity and pressure are
//! refreshed from their owners; an own particle's predictor reads its neighbours within `h`
//! (all in the halo), the global solves write the own and halo unknowns, and the correction
//! reads `φ` within `h` again. Everything computed *at* halo particles is discarded (their
//! neighbourhoods are cut at the halo's edge); the `2(h + skin)` reach keeps the halo's first
//! layer right for what the own rows read of it (number-density volumes, the explicit terms).
//! `Δt` is the minimum over the ranks.
//!
//! Limits of this first stage: fixed particles (Eulerian frame), no Dirichlet band; the setup
//! reads the whole scene on every rank (each keeps its share); the diagnostics in the step's
//! report are the rank's own (the global ones: [`super::global_diagnostics`]).

use super::comm::Comm;
use super::decomposition::{migrate, ParticleHalo, RcbTree};
use super::diagnostics::{global_diagnostics, GlobalDiagnostics};
use super::driver::Shared;
use super::solver::{DdPreconditioner, DistributedPoisson};
use crate::boundary::Boundary;
use crate::diagnostics::connectivity;
use crate::error::{Error, InputError};
use crate::flow::{FlowReport, Motion, Simulation};
use crate::particles::{Particles, Role};
use std::sync::{Arc, Mutex};

/// A rank's part of a decomposed simulation.
pub struct DecomposedRun<C: Comm + Clone + 'static, const D: usize, B: Boundary<D>> {
    comm: C,
    /// The rank's simulation: its own fluid particles first, then the halo, then ghosts.
    pub sim: Simulation<D, B>,
    /// Global index (in the scene's particle order) of each local fluid particle.
    gid: Vec<u32>,
    n_own: usize,
    halo: ParticleHalo,
    tree: RcbTree<D>,
    /// The scene's time-step limits (the step's own `Δt` is set from the global minimum).
    limits: crate::flow::TimeStepLimits,
    /// The Poisson solver (shared with the projection, which calls it).
    poisson: Arc<Mutex<DistributedPoisson<C>>>,
}

impl<C: Comm + Clone + 'static, const D: usize, B: Boundary<D> + Clone> DecomposedRun<C, D, B> {
    /// This rank's part of the scene `global` (every rank passes the same one): the particles
    /// cut by a parallel RCB, the halo exchanged, a local simulation with the scene's boundary,
    /// neighbour settings and parameters, and the distributed solvers installed. Fails for a
    /// moving frame or a Dirichlet band (not supported yet).
    pub fn new(comm: C, global: &Simulation<D, B>) -> Result<Self, Error> {
        let (p, me) = (comm.size(), comm.rank());
        let gp = &global.particles;
        if global.params.motion != Motion::Eulerian {
            return Err(InputError::parameter(
                "motion",
                0.0,
                "the particle decomposition runs fixed particles (Eulerian) only so far",
            )
            .into());
        }
        if gp.role.contains(&Role::Dirichlet) {
            return Err(InputError::parameter(
                "role",
                0.0,
                "the particle decomposition does not run a Dirichlet band yet",
            )
            .into());
        }
        let fluid: Vec<usize> = (0..gp.len()).filter(|&i| gp.role[i].is_fluid()).collect();
        let share: Vec<usize> = fluid.iter().copied().filter(|i| i % p == me).collect();
        let x: Vec<[f64; D]> = share.iter().map(|&i| gp.x[i]).collect();
        let tree = RcbTree::balance(&comm, &x);
        let ids: Vec<f64> = share.iter().map(|&i| i as f64).collect();
        let (own_x, own_ids) = migrate(&comm, &tree, &x, &ids, 1);
        let config = *global.nl.config();
        let reach = 2.0 * (config.h + config.skin);
        let halo = ParticleHalo::new(&comm, &tree, &own_x, reach, &config.periodic);
        let halo_ids = halo.exchange(&comm, &own_ids, 1);
        let gid: Vec<u32> = own_ids.iter().chain(&halo_ids).map(|&v| v as u32).collect();
        let mut local = Particles::new();
        for &g in &gid {
            let g = g as usize;
            local.push(gp.x[g], gp.u[g], gp.p[g], gp.vol[g], Role::Fluid);
        }
        let mut sim = Simulation::new(local, global.boundary.clone(), config, global.params)?;
        let comps = connectivity(&global.nl, &gp.role);
        let floating = !comps.floating().is_empty();
        let poisson = install(&comm, &mut sim, &gid, own_ids.len(), &halo, floating);
        let limits = sim.params.limits;
        Ok(DecomposedRun {
            comm,
            sim,
            gid,
            n_own: own_ids.len(),
            halo,
            tree,
            limits,
            poisson,
        })
    }
}

/// Plugs the distributed solvers (local mode) into `sim`'s Poisson and viscous solves: `gid`
/// of the local fluid particles (own first, `n_own` of them, then the halo in `halo`'s
/// receive order).
fn install<C: Comm + Clone + 'static, const D: usize, B: Boundary<D>>(
    comm: &C,
    sim: &mut Simulation<D, B>,
    gid: &[u32],
    n_own: usize,
    halo: &ParticleHalo,
    floating: bool,
) -> Arc<Mutex<DistributedPoisson<C>>> {
    let n = sim.particles.len();
    let me = comm.rank() as u32;
    let mut gid = gid.to_vec();
    gid.resize(n, u32::MAX);
    let mut owner = vec![me; n];
    let mut k = n_own;
    for &(q, count) in &halo.recvs {
        for o in &mut owner[k..k + count] {
            *o = q as u32;
        }
        k += count;
    }
    let mut poisson = DistributedPoisson::new(comm.clone());
    poisson.set_local(gid.clone(), owner.clone(), floating);
    let poisson = Arc::new(Mutex::new(poisson));
    sim.projection.solver.external = Some(Box::new(Shared(poisson.clone())));
    let mut viscous = DistributedPoisson::new(comm.clone());
    viscous.preconditioner = DdPreconditioner::Jacobi;
    viscous.set_local(gid, owner, false);
    sim.projection.viscous.external = Some(Box::new(viscous));
    poisson
}

impl<C: Comm + Clone + 'static, const D: usize, B: Boundary<D>> DecomposedRun<C, D, B> {
    /// Own fluid particles of this rank.
    pub fn n_own(&self) -> usize {
        self.n_own
    }

    /// The scene index of each own particle (the first [`Self::n_own`] of [`Self::sim`]).
    pub fn own_ids(&self) -> &[u32] {
        &self.gid[..self.n_own]
    }

    /// The cut of space.
    pub fn tree(&self) -> &RcbTree<D> {
        &self.tree
    }

    /// One step of every rank (collective): the halo's velocity and pressure from their
    /// owners, `Δt` the minimum over the ranks, then the rank's step.
    pub fn advance(&mut self) -> Result<FlowReport, Error> {
        let w = D + 1;
        let p = &self.sim.particles;
        let mut own = Vec::with_capacity(self.n_own * w);
        for i in 0..self.n_own {
            own.extend_from_slice(&p.u[i]);
            own.push(p.p[i]);
        }
        let got = self.halo.exchange(&self.comm, &own, w);
        let p = &mut self.sim.particles;
        for (k, rec) in got.chunks_exact(w).enumerate() {
            let i = self.n_own + k;
            p.u[i] = std::array::from_fn(|a| rec[a]);
            p.p[i] = rec[D];
        }
        self.sim.params.limits = self.limits;
        let (dt, _) = self.sim.time_step();
        let dt = -self.comm.max(&[-dt])[0];
        self.sim.params.limits.dt_fixed = Some(dt);
        self.sim.advance()
    }

    /// The global diagnostics of the step just taken (collective): components joined through
    /// the halo, `c0` over every rank's own rows, the norms and the Theorem 4.5 ratio by sums
    /// (`dt` the step's `Δt`).
    pub fn global_diagnostics(&mut self, dt: f64) -> GlobalDiagnostics {
        let sim = &self.sim;
        let scale = -sim.params.projection.rho / dt;
        let f: Vec<[f64; D]> = sim
            .projection
            .u_star()
            .iter()
            .map(|u| u.map(|c| scale * c))
            .collect();
        let mut dd = self.poisson.lock().expect("distributed solver lock");
        global_diagnostics(
            &mut dd,
            &sim.projection.solver.assembly,
            &sim.nl,
            &sim.particles.role,
            &sim.particles.vol,
            &sim.projection.phi,
            &f,
        )
    }
}
