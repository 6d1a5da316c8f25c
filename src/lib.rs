//! # gpm — incompressible particle fluids with the generalized particle method
//!
//! gpm's heart is an incremental pressure-Poisson projection built on the operators of the
//! generalized particle method (Imoto, *Stability of a generalized particle method for a Poisson
//! equation by discrete Sobolev norms*, Appl. Math. 64 (2019) 33–43):
//!
//! 1. a velocity predictor `u*` ([`projection::ProjectionStep::predict`]);
//! 2. the source `∇̂h·f`, `f = −(ρ/Δt) u*`, with the sum-form divergence ([`operators::div_sum`]);
//! 3. the discrete Poisson problem `−Δh φ = ∇̂h·f` ([`poisson::PoissonSolver`]);
//! 4. the correction `uⁿ⁺¹ = u* − (Δt/ρ) ∇h φ` with the difference gradient ([`operators::grad_diff`]).
//!
//! Before every solve it checks the two conditions of the theory
//! ([`diagnostics`]): **h-connectivity** (Def. 3.1 — exactly when the Poisson matrix is positive
//! definite, Thm 4.1; violations are reported with the offending particles) and the
//! **semi-regularity constant** `c0` (Def. 3.2), and it reports the Theorem 4.5 ratio
//! `‖φ‖_h01 / (√(d c0) ‖f‖_ℓ2)`, which the theory bounds by 1.
//!
//! ```
//! use gpm::prelude::*;
//!
//! // a lid-driven cavity at rest: 20 × 20 particles, walls by mirror ghosts
//! let dx = 1.0 / 20.0;
//! let mut p = Particles::<2>::new();
//! for x in lattice([0.0, 0.0], [1.0, 1.0], dx) {
//!     p.push(x, [0.0, 0.0], 0.0, dx * dx, Role::Fluid);
//! }
//! let walls = Walls::<2>::cavity(1.0, 1.0); // lid y = 1 moving at speed 1
//! let config = NeighborConfig::new_relative(Weight::WendlandC2, dx, 3.0, 0.0);
//! // ghosts → neighbour list → volumes ω_i = 1/Σw → ghost placement, in that order
//! let nl = prepare(&mut p, &walls, config, VolumeRule::NumberDensity)?;
//!
//! // one projection step at Re = 100
//! let params = ProjectionParams::<2>::new(0.01);
//! let mut step = ProjectionStep::new();
//! let report = step.step(&mut p, &nl, &walls, &params, 0.005, None)?;
//! assert_eq!(report.connectivity.floating, 1); // one pure-Neumann component: the fluid
//! assert!(report.stability_ratio <= 1.0); // Theorem 4.5
//! assert!(report.div_after < report.div_before);
//! # Ok::<(), gpm::Error>(())
//! ```
//!
//! A complete solver around the step (time-step control, ghosts, convection or advection and
//! shifting) is [`flow::Simulation`]; ready-made scenes are in [`scene`]; runs are recorded to
//! MCAP by [`record`].

#![warn(missing_docs)]
// `!(x > 0.0)` is deliberate: it rejects NaN, which `x <= 0.0` would let through
#![allow(clippy::neg_cmp_op_on_partial_ord)]
// numeric kernels index several parallel arrays with one loop variable
#![allow(clippy::needless_range_loop)]

pub mod boundary;
pub mod consistent;
pub mod diagnostics;
pub mod distributed;
pub mod error;
pub mod flow;
pub mod geometry;
pub mod kernel;
pub mod math;
pub mod neighbors;
pub mod operators;
pub mod pair_weights;
pub mod particles;
#[cfg(feature = "cli")]
pub mod plot;
pub mod poisson;
pub mod projection;
pub mod record;
pub mod reference;
pub mod sampling;
pub mod scene;
pub mod setup;
pub mod time;

pub use error::{Error, Result};

/// The types a particle code plugging in the projection needs, in one import:
/// `use gpm::prelude::*;`.
pub mod prelude {
    pub use crate::boundary::{Boundary, NoBoundary, PeriodicBox, Wall, Walls};
    pub use crate::consistent::GradientKind;
    pub use crate::diagnostics::{connectivity, semi_regularity, Components, Region};
    pub use crate::error::{Error, InputError, Result};
    pub use crate::geometry::{lattice, number_density_volumes};
    pub use crate::kernel::Weight;
    pub use crate::neighbors::{NeighborConfig, NeighborList, Periodicity};
    pub use crate::particles::{Particles, Role};
    pub use crate::poisson::{SolveParams, SolverKind};
    pub use crate::projection::{
        Prediction, ProjectionParams, ProjectionStep, Scheme, SourceKind, StepReport,
    };
    pub use crate::record::{RecordLevel, Recorder, StepContext, StepRecord};
    pub use crate::setup::{prepare, update, VolumeRule};
}
