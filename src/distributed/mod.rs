//! The projection's Poisson solve and its diagnostics domain-decomposed over ranks (MPI with
//! the `mpi` feature; threads of one process in the tests).
//!
//! **What is distributed.** The unknowns are split by recursive coordinate bisection of their
//! positions ([`partition::rcb`]); a rank owns the matrix rows of its unknowns and keeps a halo
//! of the unknowns of other ranks within `h` of them (the columns of its rows, [`halo`]). The
//! CG ([`solver`]) works on the own rows: the product needs one halo exchange per iteration,
//! the dot products three global reductions; the preconditioner is local (block Jacobi by the
//! crate's AMG on the own–own block) plus a small replicated coarse problem on aggregates, so
//! that its iterations stay nearly flat as ranks are added. Floating components (the closed
//! cavity, the periodic box: pure Neumann, constants as null space) are projected by global
//! sums. The diagnostics ([`diagnostics`]) are global: components joined through the halo,
//! `c0` by a maximum, the norms and the Theorem 4.5 ratio by sums.
//!
//! **What is not (yet).** The particle state, the neighbour search and the rest of the step
//! (predictor, correction) run on every rank alike (replicated), and each rank assembles the
//! whole matrix before taking its rows; the solution is gathered to every rank after the
//! solve. So memory does not shrink with the ranks and only the solve's work is divided; the
//! message counts of a fully distributed step (particle halo within `h` + skin) are modelled
//! in `docs/mpi.md`. Recording: rank 0 writes the one MCAP file; it holds every particle, so
//! the snapshots need no gather. The full decomposition exists for fixed and moving particles
//! ([`decomposed::DecomposedRun`], tested on thread ranks and under MPI by
//! `examples/mpi_check`, not yet behind `gpm run`): the
//! particles cut, migrated and given a halo ([`decomposition`]), a rank's rows taken from its
//! local matrix ([`halo::LocalRows::from_local`]) and both global solves of the step on the
//! local systems ([`DistributedPoisson::set_local`]).
//!
//! Every reduction adds the ranks' partial sums in rank order ([`comm::Comm::sum`]): all
//! ranks hold the same bits, so the replicated state stays identical across ranks.

pub mod comm;
pub mod decomposed;
pub mod decomposition;
pub mod diagnostics;
pub mod driver;
pub mod halo;
#[cfg(feature = "mpi")]
pub mod mpi;
pub mod partition;
pub mod solver;

pub use comm::{Comm, SelfComm, ThreadComm};
pub use diagnostics::{global_diagnostics, GlobalDiagnostics};
pub use driver::{DistributedError, DistributedRun};
pub use solver::{DdPreconditioner, DistributedPoisson, Traffic};
