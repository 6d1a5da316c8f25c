//! A [`Simulation`] whose Poisson solve is distributed: [`DistributedRun::install`] plugs the
//! solver in, [`DistributedRun::check_step`] computes the step's global diagnostics and checks
//! them against the step's own report.

use super::comm::Comm;
use super::diagnostics::{step_diagnostics, GlobalDiagnostics};
use super::solver::{DistributedPoisson, Traffic};
use crate::boundary::Boundary;
use crate::error::SolveError;
use crate::flow::{FlowReport, Simulation};
use crate::poisson::{ExternalSolve, ExternalSystem};
use std::sync::{Arc, Mutex, MutexGuard};

/// What a distributed run can report besides the crate's errors.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum DistributedError {
    /// A global diagnostic differs from the one the step computed on the whole configuration.
    #[error("step {step}: the global {quantity} is {global} but the step's own is {local}")]
    Mismatch {
        /// Step number.
        step: u64,
        /// Which diagnostic.
        quantity: &'static str,
        /// From the ranks' rows.
        global: f64,
        /// From the step's report.
        local: f64,
    },
}

/// The solver shared between the Poisson solver (which calls it) and the driver (which reads
/// its partition and traffic).
#[derive(Debug)]
pub(crate) struct Shared<C: Comm>(pub(crate) Arc<Mutex<DistributedPoisson<C>>>);

impl<C: Comm> ExternalSolve for Shared<C> {
    fn solve(
        &mut self,
        sys: ExternalSystem<'_>,
    ) -> Result<crate::poisson::iterative::CgInfo, SolveError> {
        self.0.lock().expect("distributed solver lock").solve(sys)
    }
    fn handles_null_space(&self) -> bool {
        self.0
            .lock()
            .expect("distributed solver lock")
            .handles_null_space()
    }
}

/// A distributed run's solver and its per-step checks.
#[derive(Debug)]
pub struct DistributedRun<C: Comm + 'static> {
    solver: Arc<Mutex<DistributedPoisson<C>>>,
    time: f64,
}

impl<C: Comm + 'static> DistributedRun<C> {
    /// A run over `comm` (the solver's settings through [`Self::solver`]).
    pub fn new(comm: C) -> Self {
        DistributedRun {
            solver: Arc::new(Mutex::new(DistributedPoisson::new(comm))),
            time: 0.0,
        }
    }

    /// The solver (its settings, partition, traffic).
    pub fn solver(&self) -> MutexGuard<'_, DistributedPoisson<C>> {
        self.solver.lock().expect("distributed solver lock")
    }

    /// Message counts and volumes of this rank so far.
    pub fn traffic(&self) -> Traffic {
        self.solver().traffic()
    }

    /// Makes `sim`'s Poisson solves go through the distributed solver.
    pub fn install<const D: usize, B: Boundary<D>>(&mut self, sim: &mut Simulation<D, B>) {
        sim.projection.solver.external = Some(Box::new(Shared(self.solver.clone())));
        self.time = sim.time;
    }

    /// The global diagnostics of the step just taken (`rep`), checked against the report: the
    /// connectivity summary and `c0` must be identical, the Theorem 4.5 ratio equal to
    /// `1e-9` relative (the sums are added in another order).
    pub fn check_step<const D: usize, B: Boundary<D>>(
        &mut self,
        rep: &FlowReport,
        sim: &Simulation<D, B>,
    ) -> Result<GlobalDiagnostics, DistributedError> {
        let dt = rep.time - self.time;
        self.time = rep.time;
        let g = step_diagnostics(&mut self.solver(), sim, dt);
        let pr = &rep.projection;
        let mismatch = |quantity, global: f64, local: f64| DistributedError::Mismatch {
            step: rep.step,
            quantity,
            global,
            local,
        };
        let (gc, lc) = (g.connectivity, pr.connectivity);
        for (q, a, b) in [
            ("component count", gc.components, lc.components),
            ("floating component count", gc.floating, lc.floating),
            ("isolated particle count", gc.isolated, lc.isolated),
        ] {
            if a != b {
                return Err(mismatch(q, a as f64, b as f64));
            }
        }
        if g.c0 != pr.c0 {
            return Err(mismatch("c0", g.c0, pr.c0));
        }
        let tol = 1e-9 * pr.stability_ratio.abs().max(1e-300);
        if (g.stability_ratio - pr.stability_ratio).abs() > tol {
            return Err(mismatch(
                "Theorem 4.5 ratio",
                g.stability_ratio,
                pr.stability_ratio,
            ));
        }
        Ok(g)
    }
}
