//! Typed errors, one enum per stage, each carrying the evidence (particle ids, residuals, values).

use thiserror::Error;

/// Bad particle data or parameters, found before any computation uses them.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum InputError {
    /// Particle arrays of different lengths.
    #[error("particle field '{field}' has {len} entries, expected {expected}")]
    LengthMismatch {
        /// Field name.
        field: &'static str,
        /// Its length.
        len: usize,
        /// The number of positions.
        expected: usize,
    },
    /// A NaN or infinite value.
    #[error("particle {particle}: {field} is not finite (NaN or Inf)")]
    NonFinite {
        /// Which field.
        field: &'static str,
        /// The particle.
        particle: usize,
    },
    /// A volume that is not positive.
    #[error("particle {particle}: volume {value} is not positive")]
    BadVolume {
        /// The particle.
        particle: usize,
        /// Its volume.
        value: f64,
    },
    /// A ghost whose source is not a fluid particle.
    #[error("particle {particle}: ghost source {source_particle} is not a fluid particle")]
    BadGhostSource {
        /// The ghost.
        particle: usize,
        /// Its claimed source.
        source_particle: usize,
    },
    /// Two particles at the same position (`r_ij = 0` makes every operator divide by zero).
    #[error("particles {i} and {j} coincide (distance {distance:e})")]
    Coincident {
        /// First particle.
        i: usize,
        /// Second particle.
        j: usize,
        /// Their distance.
        distance: f64,
    },
    /// A parameter outside its valid range.
    #[error("parameter '{name}' = {value}: {reason}")]
    Parameter {
        /// Parameter name.
        name: &'static str,
        /// Its value.
        value: f64,
        /// What is wrong.
        reason: String,
    },
    /// A periodic box too short for the search radius (images would be counted twice).
    #[error("periodic axis {axis}: period {period} is shorter than 2 (h + skin) = {needed}")]
    PeriodTooShort {
        /// Axis.
        axis: usize,
        /// Period.
        period: f64,
        /// Minimum admissible period.
        needed: f64,
    },
    /// A particle outside the domain (escaped through a wall).
    #[error("particle {particle} at {position:?} is outside the domain: {reason}")]
    OutsideDomain {
        /// The particle.
        particle: usize,
        /// Its position.
        position: Vec<f64>,
        /// Which bound it violates.
        reason: String,
    },
}

/// Failure of the linear solve.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum SolveError {
    /// The iterative solver stopped at `max_iters` without meeting the tolerance.
    #[error(
        "conjugate gradients did not converge in {iters} iterations: \
         residual {abs_residual:e} (relative {rel_residual:e})"
    )]
    NoConvergence {
        /// Iterations run.
        iters: usize,
        /// `‖b − Kx‖₂` reached.
        abs_residual: f64,
        /// `‖b − Kx‖₂ / ‖b‖₂` reached.
        rel_residual: f64,
    },
    /// The matrix is not numerically positive definite (Cholesky pivot at `unknown`).
    #[error("Poisson matrix is not positive definite: pivot {unknown} (particle {particle})")]
    NotPositiveDefinite {
        /// Unknown index (after any pinning).
        unknown: usize,
        /// Particle index.
        particle: usize,
    },
    /// The solve produced a non-finite value.
    #[error("the solve produced a non-finite value at particle {particle}")]
    NonFinite {
        /// Particle index.
        particle: usize,
    },
    /// Any other failure reported by the linear-algebra backend.
    #[error("linear algebra backend: {0}")]
    Backend(String),
}

/// h-connectivity (Imoto 2019, Def. 3.1) fails: some particles are cut off.
#[derive(Debug, Error, Clone, PartialEq)]
#[error(
    "h-connectivity fails: {} particle(s) in {components} unexpected component(s) \
     ({isolated} isolated); first offending particles: {:?}",
    offending.len(),
    &offending[..offending.len().min(12)]
)]
pub struct ConnectivityError {
    /// Every particle of the unexpected components.
    pub offending: Vec<usize>,
    /// How many unexpected components.
    pub components: usize,
    /// How many of the offending particles have no neighbour at all.
    pub isolated: usize,
}

/// The crate's error: one variant per stage.
#[derive(Debug, Error)]
pub enum Error {
    /// Bad particle data or parameters.
    #[error(transparent)]
    Input(#[from] InputError),
    /// The particles violate h-connectivity; reported before any solve.
    #[error(transparent)]
    Connectivity(#[from] ConnectivityError),
    /// The Poisson solve failed.
    #[error(transparent)]
    Solve(#[from] SolveError),
    /// Recording or replaying a run failed (or the run was interrupted on request).
    #[error(transparent)]
    Record(#[from] crate::record::RecordError),
}

/// `Result` with the crate's [`Error`].
pub type Result<T, E = Error> = std::result::Result<T, E>;
