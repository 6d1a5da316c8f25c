//! `gpm run` under `mpirun` (feature `mpi`): every rank runs the scene with the Poisson solve
//! distributed over the ranks ([`gpm::distributed`]); rank 0 alone writes the output. Each
//! step's global diagnostics are checked against the step's own, and a stop (signal, failed
//! check) is agreed by all ranks so that none is left waiting in a collective.

use anyhow::Result;
use gpm::boundary::Boundary;
use gpm::flow::{FlowReport, Simulation};
use std::ops::ControlFlow;

#[cfg(feature = "mpi")]
mod imp {
    use super::*;
    use anyhow::{bail, Context};
    use gpm::distributed::driver::SCENES;
    use gpm::distributed::mpi::{init, MpiComm};
    use gpm::distributed::{Comm, DistributedError, DistributedRun};

    /// The distributed run of this rank.
    pub struct Ranks {
        run: DistributedRun<MpiComm>,
        mismatch: Option<DistributedError>,
        _universe: mpi::environment::Universe,
    }

    /// True when started by `mpirun` / `mpiexec` (Open MPI, or a PMI launcher).
    fn launched() -> bool {
        ["OMPI_COMM_WORLD_SIZE", "PMIX_RANK", "PMI_RANK"]
            .iter()
            .any(|v| std::env::var_os(v).is_some())
    }

    /// `Some` under `mpirun` (even with one rank: the distributed solver runs), `None` otherwise.
    pub fn start(scene: &str) -> Result<Option<Ranks>> {
        if !launched() {
            return Ok(None);
        }
        if !SCENES.contains(&scene) {
            bail!(DistributedError::Unsupported {
                scene: scene.into()
            });
        }
        let universe = init().context("MPI could not be initialised")?;
        Ok(Some(Ranks {
            run: DistributedRun::new(MpiComm),
            mismatch: None,
            _universe: universe,
        }))
    }

    impl Ranks {
        pub fn rank(&self) -> usize {
            MpiComm.rank()
        }
        pub fn install<const D: usize, B: Boundary<D>>(&mut self, sim: &mut Simulation<D, B>) {
            self.run.install(sim);
        }
        /// The step's check, and the stop agreed by every rank.
        pub fn observe<const D: usize, B: Boundary<D>>(
            &mut self,
            rep: &FlowReport,
            sim: &Simulation<D, B>,
            flow: ControlFlow<()>,
        ) -> ControlFlow<()> {
            if let Err(e) = self.run.check_step(rep, sim) {
                self.mismatch.get_or_insert(e);
            }
            let stop = flow.is_break() || self.mismatch.is_some();
            if MpiComm.max(&[stop as u8 as f64])[0] > 0.0 {
                ControlFlow::Break(())
            } else {
                ControlFlow::Continue(())
            }
        }
        /// Every rank's message counts (a collective: all ranks call it), or the failed check.
        pub fn finish(&mut self) -> Result<serde_json::Value> {
            let t = self.run.traffic();
            let (own, halo) = {
                let s = self.run.solver();
                (s.rows().n_own(), s.rows().halo.len())
            };
            let mine = [
                own as f64,
                halo as f64,
                t.messages as f64,
                t.bytes as f64,
                t.reductions as f64,
                t.reduced_values as f64,
                t.gathered_bytes as f64,
                t.solves as f64,
                t.iterations as f64,
            ];
            let all = MpiComm.all_gather(&mine);
            if let Some(e) = self.mismatch.take() {
                return Err(e.into());
            }
            let per_rank: Vec<_> = all
                .iter()
                .map(|v| {
                    serde_json::json!({
                        "own_unknowns": v[0], "halo_unknowns": v[1], "messages": v[2],
                        "bytes": v[3], "reductions": v[4], "reduced_values": v[5],
                        "gathered_bytes": v[6], "solves": v[7], "iterations": v[8],
                    })
                })
                .collect();
            Ok(serde_json::json!({ "ranks": all.len(), "per_rank": per_rank }))
        }
    }
}

#[cfg(not(feature = "mpi"))]
mod imp {
    use super::*;

    /// Without the `mpi` feature there is one process and nothing to distribute.
    pub enum Ranks {}

    pub fn start(_scene: &str) -> Result<Option<Ranks>> {
        Ok(None)
    }

    impl Ranks {
        pub fn rank(&self) -> usize {
            match *self {}
        }
        pub fn install<const D: usize, B: Boundary<D>>(&mut self, _sim: &mut Simulation<D, B>) {
            match *self {}
        }
        pub fn observe<const D: usize, B: Boundary<D>>(
            &mut self,
            _rep: &FlowReport,
            _sim: &Simulation<D, B>,
            _flow: ControlFlow<()>,
        ) -> ControlFlow<()> {
            match *self {}
        }
        pub fn finish(&mut self) -> Result<serde_json::Value> {
            match *self {}
        }
    }
}

pub use imp::start;
