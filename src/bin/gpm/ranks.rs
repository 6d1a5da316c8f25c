//! `gpm run` under `mpirun` (feature `mpi`): the scene's particles decomposed over the ranks
//! ([`gpm::scene::ranks::Decomposed`]: each rank steps its own particles with a halo, the
//! Poisson and viscous solves distributed); rank 0 gathers the particles after every step into
//! its copy of the scene, which the scene observes, the recording writes and the tables and
//! summary are made from. Stops (a signal, the scene's end) and failures are agreed by all
//! ranks, so that none is left waiting in a collective.

use anyhow::Result;
use gpm::boundary::Boundary;
use gpm::error::Error;
use gpm::flow::{FlowReport, Simulation};
use gpm::scene::{OneProcess, Stepper, Votes};

/// How this process takes the steps: alone, or as one rank of a decomposed run.
pub enum Steps<const D: usize, B: Boundary<D> + Clone> {
    /// One process.
    One(OneProcess),
    /// A rank under `mpirun`.
    #[cfg(feature = "mpi")]
    Ranks(Box<imp::Ranks<D, B>>),
    /// (Without the `mpi` feature: never made.)
    #[cfg(not(feature = "mpi"))]
    #[allow(dead_code)]
    Never(std::convert::Infallible, std::marker::PhantomData<B>),
}

impl<const D: usize, B: Boundary<D> + Clone> Steps<D, B> {
    /// This process's rank (0 alone).
    pub fn rank(&self) -> usize {
        match self {
            #[cfg(feature = "mpi")]
            Steps::Ranks(r) => r.rank(),
            _ => 0,
        }
    }

    /// Whether the steps are a rank's of a decomposed run.
    pub fn is_decomposed(&self) -> bool {
        !matches!(self, Steps::One(_))
    }

    /// Every rank's particles, halo and message counts (a collective: all ranks call it);
    /// `None` for one process.
    pub fn summary(&self) -> Option<serde_json::Value> {
        match self {
            #[cfg(feature = "mpi")]
            Steps::Ranks(r) => Some(r.summary()),
            _ => None,
        }
    }
}

impl<const D: usize, B: Boundary<D> + Clone> Stepper<D, B> for Steps<D, B> {
    fn start(&mut self, sim: &mut Simulation<D, B>) -> Result<(), Error> {
        match self {
            Steps::One(s) => Stepper::<D, B>::start(s, sim),
            #[cfg(feature = "mpi")]
            Steps::Ranks(r) => r.stepper.start(sim),
            #[cfg(not(feature = "mpi"))]
            Steps::Never(never, _) => match *never {},
        }
    }
    fn step(
        &mut self,
        sim: &mut Simulation<D, B>,
        until: Option<f64>,
    ) -> Result<FlowReport, Error> {
        match self {
            Steps::One(s) => s.step(sim, until),
            #[cfg(feature = "mpi")]
            Steps::Ranks(r) => r.stepper.step(sim, until),
            #[cfg(not(feature = "mpi"))]
            Steps::Never(never, _) => match *never {},
        }
    }
    fn agree(&mut self, votes: Votes) -> Votes {
        match self {
            Steps::One(s) => Stepper::<D, B>::agree(s, votes),
            #[cfg(feature = "mpi")]
            Steps::Ranks(r) => r.stepper.agree(votes),
            #[cfg(not(feature = "mpi"))]
            Steps::Never(never, _) => match *never {},
        }
    }
}

/// True when started by `mpirun` / `mpiexec` (Open MPI, or a PMI launcher).
fn launched() -> bool {
    ["OMPI_COMM_WORLD_SIZE", "PMIX_RANK", "PMI_RANK"]
        .iter()
        .any(|v| std::env::var_os(v).is_some())
}

/// The steps of this process: under `mpirun` (feature `mpi`) a rank of the decomposed run,
/// even with one rank; otherwise one process. Refuses `mpirun` without the `mpi` feature.
pub fn start<const D: usize, B: Boundary<D> + Clone + 'static>() -> Result<Steps<D, B>> {
    if !launched() {
        return Ok(Steps::One(OneProcess));
    }
    #[cfg(feature = "mpi")]
    {
        Ok(Steps::Ranks(Box::new(imp::Ranks::start()?)))
    }
    #[cfg(not(feature = "mpi"))]
    {
        let size = std::env::var("OMPI_COMM_WORLD_SIZE").unwrap_or_default();
        if size.is_empty() || size == "1" {
            return Ok(Steps::One(OneProcess));
        }
        anyhow::bail!(
            "started by mpirun with {size} ranks, but this gpm was built without the `mpi` \
             feature: every rank would run the whole scene alone (build with `cargo build \
             --release --features mpi`)"
        )
    }
}

#[cfg(feature = "mpi")]
mod imp {
    use super::*;
    use anyhow::Context;
    use gpm::distributed::mpi::{init, MpiComm};
    use gpm::distributed::Comm;
    use gpm::scene::ranks::Decomposed;

    /// A rank of the decomposed run.
    pub struct Ranks<const D: usize, B: Boundary<D> + Clone> {
        pub stepper: Decomposed<MpiComm, D, B>,
        _universe: mpi::environment::Universe,
    }

    impl<const D: usize, B: Boundary<D> + Clone + 'static> Ranks<D, B> {
        pub fn start() -> Result<Self> {
            let universe = init().context("MPI could not be initialised")?;
            Ok(Ranks {
                stepper: Decomposed::new(MpiComm, 0),
                _universe: universe,
            })
        }
    }

    impl<const D: usize, B: Boundary<D> + Clone> Ranks<D, B> {
        pub fn rank(&self) -> usize {
            MpiComm.rank()
        }

        /// Every rank's own and halo particles, the decomposition's counts and the solves'
        /// messages (a collective: all ranks call it).
        pub fn summary(&self) -> serde_json::Value {
            let mut mine = vec![0.0; 13];
            if let Some(run) = self.stepper.run() {
                let (c, t) = (run.counts(), run.traffic());
                mine = vec![
                    run.n_own() as f64,
                    run.n_halo() as f64,
                    c.rebuilds as f64,
                    c.rebalances as f64,
                    c.migrated as f64,
                    c.halo_received as f64,
                    c.gathered as f64,
                    t.messages as f64,
                    t.bytes as f64,
                    t.reductions as f64,
                    t.solves as f64,
                    t.iterations as f64,
                    run.particle_bytes() as f64,
                ];
            }
            let all = MpiComm.all_gather(&mine);
            let per_rank: Vec<_> = all
                .iter()
                .map(|v| {
                    serde_json::json!({
                        "own_particles": v[0], "halo_particles": v[1], "rebuilds": v[2],
                        "rebalances": v[3], "migrated": v[4], "halo_received": v[5],
                        "gathered_particles": v[6], "solve_messages": v[7],
                        "solve_bytes": v[8], "reductions": v[9], "solves": v[10],
                        "cg_iterations": v[11], "particle_record_bytes": v[12],
                    })
                })
                .collect();
            serde_json::json!({
                "ranks": all.len(),
                "decomposition": "particles (recursive coordinate bisection), gathered on rank 0",
                "per_rank": per_rank,
            })
        }
    }
}
