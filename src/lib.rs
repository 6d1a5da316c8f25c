//! # gpm — incompressible particle fluids with the generalized particle method
//!
//! (crate documentation is completed with the projection step)

#![warn(missing_docs)]

pub mod boundary;
pub mod diagnostics;
pub mod error;
pub mod flow;
pub mod geometry;
pub mod kernel;
pub mod math;
pub mod neighbors;
pub mod operators;
pub mod particles;
#[cfg(feature = "cli")]
pub mod plot;
pub mod poisson;
pub mod projection;
pub mod record;
pub mod reference;
pub mod sampling;
pub mod scene;

pub use error::{Error, Result};
