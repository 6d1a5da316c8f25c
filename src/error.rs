//! Typed errors, one enum per stage, each carrying the evidence (particle ids, residuals, values).
//!
//! This module depends on nothing else in the crate (only on `std`, `thiserror` and the error
//! types of `mcap` and `serde_json`), so every module may use it. [`DtLimit`] lives here because
//! [`StabilityError::TimeStepTooLarge`] names it; it is re-exported by [`crate::time`] and
//! [`crate::flow`]. [`RecordError`] is re-exported by [`crate::record`].

use serde::{Deserialize, Serialize};
use std::borrow::Cow;
use std::path::PathBuf;
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
        /// The parameter's key path, dot-separated as in a configuration file
        /// (`solve.abs_tol`, `limits.guard.energy_growth`, `h`); see [`InputError::parameter`]
        /// and [`InputError::under`].
        name: Cow<'static, str>,
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
    /// The influence radius is at or below the smallest particle distance (`h ≤ min r_ij`), so
    /// no particle has a neighbour: the paper's standing assumption `min r_ij < h` fails.
    #[error(
        "influence radius h = {h} is at or below the minimum particle spacing {min_spacing} \
         (particles {i} and {j}): no particle has a neighbour; h must exceed the spacing \
         (typically h/dx = 2 to 4)"
    )]
    RadiusTooSmall {
        /// The influence radius.
        h: f64,
        /// The smallest distance between two particles.
        min_spacing: f64,
        /// One particle of the closest pair.
        i: usize,
        /// The other.
        j: usize,
    },
    /// A configuration file or message that cannot be read into the configuration type; `key`
    /// is the path of the offending entry (`limits.cfl`, `n`; empty for the document itself).
    #[error("configuration key '{key}': {reason}")]
    Config {
        /// Path of the entry, dot-separated.
        key: String,
        /// What is wrong (from the parser).
        reason: String,
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
    /// The neighbour list was not measured at the current positions (the particles moved, or
    /// the ghosts were placed, after its last update).
    #[error("neighbour list out of date at particle {particle}: {reason}")]
    StaleNeighbors {
        /// The first particle whose row does not match.
        particle: usize,
        /// What differs, and the fix.
        reason: String,
    },
    /// A ghost particle that is not where the boundary puts it, or stored out of order.
    #[error("ghost particle {particle}: {reason}")]
    Ghost {
        /// The particle.
        particle: usize,
        /// What is wrong, and the fix.
        reason: String,
    },
    /// A fluid particle closer than `h` to a wall (or a corner) without its mirror image: the
    /// ghosts were made with a reach below `h`.
    #[error(
        "fluid particle {particle} is {distance:e} from the wall(s) {walls:#b}, closer than \
         h = {h}, but has no ghost image there: make the ghosts with a reach of at least h \
         (h + skin for a moving list)"
    )]
    MissingGhost {
        /// The fluid particle.
        particle: usize,
        /// Bit mask of the walls of the missing image.
        walls: u8,
        /// Its largest distance to those walls.
        distance: f64,
        /// The influence radius.
        h: f64,
    },
}

impl InputError {
    /// A [`InputError::Parameter`] naming the key path `name` (a `&'static str` or a `String`).
    pub fn parameter(
        name: impl Into<Cow<'static, str>>,
        value: f64,
        reason: impl Into<String>,
    ) -> Self {
        InputError::Parameter {
            name: name.into(),
            value,
            reason: reason.into(),
        }
    }

    /// Puts a [`InputError::Parameter`]'s key path under `prefix`: `solve.abs_tol` becomes
    /// `projection.solve.abs_tol` with `prefix = "projection"`. Other errors are returned
    /// unchanged. A validator of a type held in a field of another calls this with the field's
    /// name, so the key names the entry from the outermost parameter set.
    pub fn under(self, prefix: &str) -> Self {
        match self {
            InputError::Parameter {
                name,
                value,
                reason,
            } if !prefix.is_empty() => InputError::Parameter {
                name: Cow::Owned(format!("{prefix}.{name}")),
                value,
                reason,
            },
            other => other,
        }
    }

    /// The key path of a [`InputError::Parameter`], `None` for the other variants.
    pub fn parameter_name(&self) -> Option<&str> {
        match self {
            InputError::Parameter { name, .. } => Some(name),
            _ => None,
        }
    }
}

/// Which limit set the time step.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DtLimit {
    /// Advective CFL.
    #[default]
    Cfl,
    /// Explicit viscous stability.
    Viscous,
    /// Body force.
    Force,
    /// `dt_max`.
    Max,
    /// A fixed step.
    Fixed,
}

impl std::fmt::Display for DtLimit {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            DtLimit::Cfl => "CFL",
            DtLimit::Viscous => "explicit viscous",
            DtLimit::Force => "body-force",
            DtLimit::Max => "dt_max",
            DtLimit::Fixed => "fixed",
        })
    }
}

/// Failure of the linear solve.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum SolveError {
    /// The iterative solver stopped at `max_iters` without meeting the tolerance.
    #[error(
        "conjugate gradients did not converge in {iters} iterations: \
         residual {abs_residual:e} (relative {rel_residual:e}); raise solve.max_iters or \
         loosen solve.rel_tol / solve.abs_tol"
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
    /// The band values extrapolated to a surface did not settle
    /// ([`crate::projection::ProjectionStep::project_to_surface`]).
    #[error(
        "the band's extrapolation to the surface did not converge: largest change {change:e} \
         after {solves} solves (raise max_solves, or check the surface's foot points)"
    )]
    BandNotConverged {
        /// Poisson solves done.
        solves: usize,
        /// The last change of the band values (largest, absolute).
        change: f64,
    },
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

/// A run going unstable, detected by the checks of [`crate::time::StabilityGuard`] (all off by
/// default) before it turns into a blow-up: each names the step, the quantity and where.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum StabilityError {
    /// The time step of step `step` exceeds `factor` times one of the stability limits of
    /// [`crate::time::TimeStepLimits`] (CFL, explicit viscous, body force).
    #[error(
        "step {step}: time step dt = {dt:e} exceeds the {limit} limit {bound:e} \
         ({:.3} times it, allowed {factor}); lower limits.dt_fixed / limits.dt_max",
        dt / bound
    )]
    TimeStepTooLarge {
        /// The step that would have been taken (1 for the first).
        step: u64,
        /// The time step.
        dt: f64,
        /// Which limit it exceeds (the smallest one).
        limit: DtLimit,
        /// The limit's value.
        bound: f64,
        /// The allowed multiple of the limit.
        factor: f64,
    },
    /// A monitored quantity left its admissible range after step `step`: kinetic-energy
    /// growth per step, maximum speed over the reference speed, or the Theorem 4.5 ratio.
    #[error(
        "step {step} (t = {time}): {quantity} = {value:e} exceeds {bound:e}; fastest particle \
         {particle} at {position:?} with |u| = {speed:e} (time step too large, or the flow under-resolved?)"
    )]
    BlowUp {
        /// The step after which the check failed.
        step: u64,
        /// Time after that step.
        time: f64,
        /// What was checked: `"kinetic energy growth"`, `"max speed / u_ref"` or
        /// `"Theorem 4.5 ratio"`.
        quantity: &'static str,
        /// Its value.
        value: f64,
        /// The bound it exceeds.
        bound: f64,
        /// The fastest fluid particle (where the blow-up is).
        particle: usize,
        /// Its position.
        position: Vec<f64>,
        /// Its speed.
        speed: f64,
    },
}

/// Recording and replay failures; each names the file.
#[derive(Debug, thiserror::Error)]
pub enum RecordError {
    /// Creating, writing or reading the file failed.
    #[error("{}: {source}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// The I/O error.
        source: std::io::Error,
    },
    /// The MCAP writer or a record parser failed.
    #[error("{}: MCAP: {source}", path.display())]
    Mcap {
        /// The file.
        path: PathBuf,
        /// The mcap crate's error.
        source: mcap::McapError,
    },
    /// A message could not be encoded or decoded.
    #[error("{}: {what}: {source}", path.display())]
    Json {
        /// The file.
        path: PathBuf,
        /// Which message (topic and step).
        what: String,
        /// The serde error.
        source: serde_json::Error,
    },
    /// The file is not an MCAP file at all.
    #[error("{}: not an MCAP file: {reason}", path.display())]
    NotMcap {
        /// The file.
        path: PathBuf,
        /// Why.
        reason: String,
    },
    /// The file is MCAP but its content is not what gpm writes (or a later format).
    #[error("{}: {message}", path.display())]
    Format {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// A recorded description (boundary, parameters, arrays) cannot be turned back into the
    /// crate's types.
    #[error("recorded {what}: {reason}")]
    Spec {
        /// Which part.
        what: &'static str,
        /// What is wrong.
        reason: String,
    },
    /// Another process holds the output directory's lock ([`crate::record::OutputLock`]): two
    /// runs into one directory would overwrite each other's files.
    #[error(
        "{}: the output directory is in use by another gpm run{}; choose another --out or wait \
         for it to finish",
        path.display(),
        holder.map(|p| format!(" (process {p})")).unwrap_or_default()
    )]
    Locked {
        /// The lock file.
        path: PathBuf,
        /// The holder's process id, when it could be read from the lock file.
        holder: Option<u32>,
    },
    /// A path that is not a regular file where one is read or written (a FIFO, a device, a
    /// directory), or an output that would overwrite an input.
    #[error("{}: {reason}", path.display())]
    NotAFile {
        /// The path.
        path: PathBuf,
        /// What it is, and why it is refused.
        reason: String,
    },
    /// The file has no particle snapshots to draw.
    #[error(
        "{}: no /particles snapshots to draw (record the run with --record full)",
        path.display()
    )]
    NoSnapshots {
        /// The file.
        path: PathBuf,
    },
    /// A field asked for by name that the snapshots do not have.
    #[error(
        "{}: the particle snapshots have no field '{field}'; available: {}",
        path.display(),
        available.join(", ")
    )]
    UnknownField {
        /// The file.
        path: PathBuf,
        /// The name asked for.
        field: String,
        /// The names that would have worked.
        available: Vec<String>,
    },
    /// Drawing or encoding an image (PNG, GIF) failed.
    #[error("{}: drawing failed: {message}", path.display())]
    Render {
        /// The image file.
        path: PathBuf,
        /// What went wrong.
        message: String,
    },
    /// Re-running a recorded projection failed.
    #[error("{}: re-running the projection of step {step} failed: {source}", path.display())]
    Rerun {
        /// The file.
        path: PathBuf,
        /// The recorded step.
        step: u64,
        /// The projection's error.
        source: Box<Error>,
    },
}

/// Failure of the moment-consistent pair weights ([`crate::pair_weights`]): the Newton
/// iteration on the dual problem did not bring every fluid row's moments to the tolerance.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum PairWeightError {
    /// Newton stopped at its step limit (or its line search found no decrease) with the
    /// (regularised) moment residual `max_q |M_iq − t_q + ε_q z_iq|` still above the tolerance.
    #[error(
        "moment pair weights did not converge in {newton} Newton steps: moment residual \
         {residual:e} at particle {particle} ({reason}); raise the regularisation or max_newton"
    )]
    NoConvergence {
        /// Newton steps run.
        newton: usize,
        /// Largest residual left.
        residual: f64,
        /// The worst fluid particle.
        particle: usize,
        /// Step limit or line search.
        reason: &'static str,
    },
    /// A multiplier or factor became NaN or infinite.
    #[error("moment pair weights: non-finite value at particle {particle}")]
    NonFinite {
        /// The particle.
        particle: usize,
    },
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
    /// A run became unstable (see [`crate::time::StabilityGuard`]).
    #[error(transparent)]
    Stability(#[from] StabilityError),
    /// Recording or replaying a run failed (or the run was interrupted on request).
    #[error(transparent)]
    Record(#[from] RecordError),
    /// The moment-consistent pair weights could not be computed.
    #[error(transparent)]
    PairWeights(#[from] PairWeightError),
    /// A run decomposed over ranks: the step failed on other ranks (each reports its own
    /// error); this rank stops with them.
    #[error("step {step}: the step failed on {ranks} other rank(s), which report the cause")]
    PeerFailed {
        /// The step (1 for the first).
        step: u64,
        /// How many ranks failed.
        ranks: usize,
    },
}

/// `Result` with the crate's [`Error`](enum@Error).
pub type Result<T, E = Error> = std::result::Result<T, E>;
