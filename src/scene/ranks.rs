//! A scene run decomposed over ranks ([`Decomposed`], a [`Stepper`]): every rank builds the
//! scene, the particles are cut between the ranks ([`DecomposedRun`]), each rank steps its own
//! ones, and after every step rank `root` gathers them into its copy of the scene's
//! simulation — the copy the scene observes, its result is computed from and a recording
//! writes. The other ranks' copies keep the initial particles (only their clocks advance):
//! their scene results are not the run's. Stops and failures are agreed by all ranks, so no
//! rank is left waiting in a collective.

use super::{Stepper, Votes};
use crate::boundary::Boundary;
use crate::distributed::decomposed::DecomposedRun;
use crate::distributed::Comm;
use crate::error::{Error, InputError};
use crate::flow::{FlowReport, Simulation};

/// Settings applied to the decomposed run once it is made.
type Configure<C, const D: usize, B> = Box<dyn FnOnce(&mut DecomposedRun<C, D, B>)>;

/// The steps of a scene taken by a [`DecomposedRun`] over `comm`, gathered on `root`.
pub struct Decomposed<C: Comm + Clone + 'static, const D: usize, B: Boundary<D> + Clone> {
    comm: C,
    root: usize,
    run: Option<DecomposedRun<C, D, B>>,
    configure: Option<Configure<C, D, B>>,
}

impl<C: Comm + Clone + 'static, const D: usize, B: Boundary<D> + Clone> Decomposed<C, D, B> {
    /// A run over `comm` whose gathered copy lives on rank `root`.
    pub fn new(comm: C, root: usize) -> Self {
        Decomposed {
            comm,
            root,
            run: None,
            configure: None,
        }
    }

    /// Settings for the decomposed run once it is made (e.g. its preconditioner), before
    /// the first step.
    pub fn configure(mut self, f: impl FnOnce(&mut DecomposedRun<C, D, B>) + 'static) -> Self {
        self.configure = Some(Box::new(f));
        self
    }

    /// The decomposed run (after the run started).
    pub fn run(&self) -> Option<&DecomposedRun<C, D, B>> {
        self.run.as_ref()
    }

    /// The rank that holds the gathered copy.
    pub fn root(&self) -> usize {
        self.root
    }

    /// Whether this rank holds the gathered copy (observes, records).
    pub fn is_root(&self) -> bool {
        self.comm.rank() == self.root
    }
}

impl<C: Comm + Clone + 'static, const D: usize, B: Boundary<D> + Clone> Stepper<D, B>
    for Decomposed<C, D, B>
{
    fn start(&mut self, sim: &mut Simulation<D, B>) -> Result<(), Error> {
        let mut run = DecomposedRun::new(self.comm.clone(), sim)?;
        if let Some(f) = self.configure.take() {
            f(&mut run);
        }
        self.run = Some(run);
        Ok(())
    }

    fn step(
        &mut self,
        sim: &mut Simulation<D, B>,
        until: Option<f64>,
    ) -> Result<FlowReport, Error> {
        let Some(run) = self.run.as_mut() else {
            return Err(InputError::parameter(
                "step",
                (sim.steps + 1) as f64,
                "the decomposed run was not started (Stepper::start)",
            )
            .into());
        };
        let report = match until {
            Some(t) => run.advance_toward(t)?,
            None => run.advance()?,
        };
        // the root's update of its copy can fail (a neighbour search): all ranks learn it
        let gathered = run.gather_into(sim, self.root);
        let failed = self.comm.max(&[gathered.is_err() as u8 as f64])[0] > 0.0;
        gathered?;
        if failed {
            return Err(Error::PeerFailed {
                step: report.step,
                ranks: 1,
            });
        }
        Ok(report)
    }

    fn agree(&mut self, votes: Votes) -> Votes {
        let root = self.is_root();
        let v = self.comm.max(&[
            (root && votes.scene_stop) as u8 as f64,
            votes.caller_stop as u8 as f64,
            votes.failed as u8 as f64,
        ]);
        Votes {
            scene_stop: v[0] > 0.0,
            caller_stop: v[1] > 0.0,
            failed: v[2] > 0.0,
        }
    }
}
