//! The C ABI of gpm (`include/gpm.h`, generated from this file by cbindgen).
//!
//! A C or C++ particle code keeps its particles and its loop; it hands positions and velocities
//! to a `GpmSystem` (gpm's particles, neighbour list, boundary, parameters and projection
//! scratch) and calls `gpm_system_update_neighbors`, `gpm_system_predict`,
//! `gpm_system_project` (or `gpm_system_step`). Recording goes through `GpmRecorder`
//! (gpm's `Recorder::record`).
//!
//! Rules of the boundary: handles are opaque and freed by their `_free` function; every
//! pointer is checked for null; every array comes with its row count, checked against the
//! system; every call runs under `catch_unwind`, so a panic inside gpm becomes
//! `GPM_STATUS_PANIC` with its message, never an unwind into C. Errors are a status code plus
//! a thread-local message, particle and parameter.

// The functions check every pointer for null before they dereference it; which is what the
// safety sections of unsafe functions would say, on every function.
#![allow(clippy::missing_safety_doc)]

use gpm::boundary::{NoBoundary, PeriodicBox, Walls};
use gpm::error::{Error, InputError};
use gpm::kernel::Weight;
use gpm::neighbors::{NeighborConfig, NeighborList, Periodicity};
use gpm::particles::{Particles, Role};
use gpm::projection::{ProjectionParams, ProjectionStep, Scheme, StepReport};
use gpm::record::schema::{BoundarySpec, ToBoundarySpec};
use gpm::record::{
    ProjectionRecord, RecordLevel, Recorder, RecorderOptions, StepContext, StepRecord,
};
use gpm::setup::VolumeRule;
use std::cell::RefCell;
use std::ffi::{c_char, c_int, CStr, CString};
use std::panic::{catch_unwind, AssertUnwindSafe};

/// What a call returned.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum GpmStatus {
    /// Success.
    Ok = 0,
    /// A required pointer was NULL (the message names the argument).
    NullPointer = 1,
    /// Bad particle data or parameters (gpm's InputError; particle/parameter named).
    Input = 2,
    /// h-connectivity fails (particle = the first offending one).
    Connectivity = 3,
    /// The linear solve failed.
    Solve = 4,
    /// A run became unstable.
    Stability = 5,
    /// Recording failed (the message names the file).
    Record = 6,
    /// The moment-consistent pair weights failed.
    PairWeights = 7,
    /// A panic inside gpm, caught at the boundary (a bug: please report the message).
    Panic = 8,
}

/// The reference weight of the kernel.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum GpmWeight {
    /// Wendland C2 `(1 − r)⁴ (1 + 4r)` (the default).
    WendlandC2 = 0,
    /// Wendland C4.
    WendlandC4 = 1,
    /// Cubic B-spline.
    CubicSpline = 2,
}

/// What surrounds the particles.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum GpmBoundaryKind {
    /// Free space.
    None = 0,
    /// Every axis periodic on `[lo, hi)`.
    Periodic = 1,
    /// No-slip walls on every face of `[lo, hi]` (mirror ghosts).
    ClosedBox = 2,
    /// Walls at both ends of the last axis, periodic along the others.
    Channel = 3,
    /// The lid-driven cavity `[0, hi[0]]^dim`, the top wall moving with `lid` along x.
    Cavity = 4,
}

/// Pressure-correction scheme.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum GpmScheme {
    /// Rotational incremental (Timmermans et al.; the default).
    Rotational = 0,
    /// Standard incremental (Goda / van Kan).
    Incremental = 1,
    /// Chorin's non-incremental projection (one-off projections).
    NonIncremental = 2,
}

/// What a recorder writes.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum GpmRecordLevel {
    /// Nothing (no file).
    None = 0,
    /// `/config` and `/diagnostics`.
    Diagnostics = 1,
    /// Also particle snapshots and projection inputs every `every` steps.
    Full = 2,
}

/// Everything a system is made with besides the arrays; `gpm_settings_default` fills it.
/// The enumerations are passed as `uint32_t` (values of GpmWeight, GpmBoundaryKind, GpmScheme)
/// and checked.
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct GpmSettings {
    /// 2 or 3.
    pub dim: u32,
    /// Influence radius h.
    pub h: f64,
    /// Neighbour-search skin (0: search at every update).
    pub skin: f64,
    /// A GpmWeight.
    pub weight: u32,
    /// A GpmBoundaryKind.
    pub boundary: u32,
    /// Lower corner of the box (first `dim` entries used).
    pub lo: [f64; 3],
    /// Upper corner of the box.
    pub hi: [f64; 3],
    /// Lid speed (GPM_BOUNDARY_KIND_CAVITY).
    pub lid: f64,
    /// Density.
    pub rho: f64,
    /// Kinematic viscosity (0 skips the viscous stage).
    pub nu: f64,
    /// Body force per unit mass.
    pub gravity: [f64; 3],
    /// A GpmScheme.
    pub scheme: u32,
    /// Implicit weight of the viscous term (0 explicit, 0.5 Crank–Nicolson).
    pub viscous_theta: f64,
    /// Floating (pure Neumann) components allowed (1: closed or periodic box).
    pub allowed_floating: u32,
    /// Non-zero: keep the volumes given to gpm_system_new; zero: number density, recomputed
    /// by every gpm_system_update_neighbors.
    pub fixed_volumes: c_int,
}

/// What one projection step measured (gpm's StepReport, flattened).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default)]
pub struct GpmReport {
    /// Time step.
    pub dt: f64,
    /// Semi-regularity constant over the fluid.
    pub c0: f64,
    /// Smallest distance between a fluid particle and any neighbour.
    pub min_spacing: f64,
    /// Theorem 4.5 ratio (the theory bounds it by 1).
    pub stability_ratio: f64,
    /// Discrete divergence of u* (l2 norm).
    pub div_before: f64,
    /// Discrete divergence after the projection.
    pub div_after: f64,
    /// |u(n+1) − u*| / |u*|.
    pub correction_ratio: f64,
    /// ½ ρ Σ ω |u|² after the step.
    pub kinetic_energy: f64,
    /// Largest fluid speed after the step.
    pub max_speed: f64,
    /// Connected components of the fluid graph.
    pub components: usize,
    /// Floating components.
    pub floating: usize,
    /// Isolated particles.
    pub isolated: usize,
    /// Iterations of the Poisson solve (0 for Cholesky).
    pub solve_iters: usize,
    /// Relative residual of the Poisson solve.
    pub solve_rel_residual: f64,
    /// Wall-clock seconds of the projection (diagnostics, source, solve, correction).
    pub seconds: f64,
    /// Unknowns of the implicit viscous solve of `gpm_system_step`'s predictor (0 when none
    /// ran: `gpm_system_project`, explicit or no viscosity; then the next two are 0 too).
    pub viscous_unknowns: usize,
    /// Iterations of the implicit viscous solve, its components summed (0 for Cholesky).
    pub viscous_iters: usize,
    /// Relative residual of the implicit viscous solve (the largest over its components).
    pub viscous_rel_residual: f64,
}

impl From<&StepReport> for GpmReport {
    fn from(r: &StepReport) -> Self {
        let t = &r.timings;
        GpmReport {
            dt: r.dt,
            c0: r.c0,
            min_spacing: r.min_spacing,
            stability_ratio: r.stability_ratio,
            div_before: r.div_before,
            div_after: r.div_after,
            correction_ratio: r.correction_ratio,
            kinetic_energy: r.kinetic_energy,
            max_speed: r.max_speed,
            components: r.connectivity.components,
            floating: r.connectivity.floating,
            isolated: r.connectivity.isolated,
            solve_iters: r.solve.iters,
            solve_rel_residual: r.solve.rel_residual,
            seconds: t.diagnostics + t.predictor + t.source + t.solve + t.correction,
            viscous_unknowns: r.viscous.map_or(0, |v| v.unknowns),
            viscous_iters: r.viscous.map_or(0, |v| v.iters),
            viscous_rel_residual: r.viscous.map_or(0.0, |v| v.rel_residual),
        }
    }
}

// ---------------------------------------------------------------------------------------------
// errors

struct LastError {
    message: CString,
    particle: i64,
    parameter: Option<CString>,
}

thread_local! {
    static LAST: RefCell<Option<LastError>> = const { RefCell::new(None) };
}

/// An error of this layer: the status, the message, the particle and the parameter.
struct Fail {
    status: GpmStatus,
    message: String,
    particle: Option<usize>,
    parameter: Option<String>,
}

impl Fail {
    fn null(arg: &str) -> Self {
        Fail {
            status: GpmStatus::NullPointer,
            message: format!("argument '{arg}' is NULL"),
            particle: None,
            parameter: Some(arg.into()),
        }
    }
    fn arg(name: &str, reason: String) -> Self {
        Fail {
            status: GpmStatus::Input,
            message: format!("argument '{name}': {reason}"),
            particle: None,
            parameter: Some(name.into()),
        }
    }
}

impl From<Error> for Fail {
    fn from(e: Error) -> Self {
        let message = e.to_string();
        let (status, particle, parameter) = match &e {
            Error::Input(i) => {
                let (p, q) = input_location(i);
                (GpmStatus::Input, p, q)
            }
            Error::Connectivity(c) => (GpmStatus::Connectivity, c.offending.first().copied(), None),
            Error::Solve(s) => (
                GpmStatus::Solve,
                match s {
                    gpm::error::SolveError::NotPositiveDefinite { particle, .. }
                    | gpm::error::SolveError::NonFinite { particle } => Some(*particle),
                    _ => None,
                },
                None,
            ),
            Error::Stability(s) => (
                GpmStatus::Stability,
                match s {
                    gpm::error::StabilityError::BlowUp { particle, .. } => Some(*particle),
                    _ => None,
                },
                None,
            ),
            Error::Record(_) => (GpmStatus::Record, None, None),
            Error::PairWeights(p) => (
                GpmStatus::PairWeights,
                match p {
                    gpm::error::PairWeightError::NoConvergence { particle, .. }
                    | gpm::error::PairWeightError::NonFinite { particle } => Some(*particle),
                },
                None,
            ),
            // a decomposed run's step failed on another rank: not reachable through the C
            // ABI (one process), classed with the solve
            Error::PeerFailed { .. } => (GpmStatus::Solve, None, None),
        };
        Fail {
            status,
            message,
            particle,
            parameter,
        }
    }
}

impl From<InputError> for Fail {
    fn from(e: InputError) -> Self {
        Error::from(e).into()
    }
}

impl From<gpm::error::RecordError> for Fail {
    fn from(e: gpm::error::RecordError) -> Self {
        Error::from(e).into()
    }
}

/// The argument that carries gpm's particle field `field` (`"velocity"` is `u`).
fn argument(field: &str) -> String {
    match field {
        "position" => "x",
        "velocity" => "u",
        "pressure" => "p",
        "volume" => "vol",
        other => other,
    }
    .to_string()
}

/// The particle and the parameter an input error names.
fn input_location(e: &InputError) -> (Option<usize>, Option<String>) {
    match e {
        InputError::LengthMismatch { field, .. } => (None, Some(argument(field))),
        InputError::NonFinite { field, particle } => (Some(*particle), Some(argument(field))),
        InputError::BadVolume { particle, .. } => (Some(*particle), Some("vol".into())),
        InputError::BadGhostSource { particle, .. } => (Some(*particle), None),
        InputError::Coincident { i, .. } => (Some(*i), Some("x".into())),
        InputError::Parameter { name, .. } => (None, Some(name.to_string())),
        InputError::PeriodTooShort { .. } => (None, Some("boundary".into())),
        InputError::RadiusTooSmall { i, .. } => (Some(*i), Some("h".into())),
        InputError::Config { key, .. } => (None, Some(key.clone())),
        InputError::OutsideDomain { particle, .. } => (Some(*particle), Some("x".into())),
        InputError::StaleNeighbors { particle, .. } => (Some(*particle), None),
        InputError::Ghost { particle, .. } => (Some(*particle), None),
        InputError::MissingGhost { particle, .. } => (Some(*particle), None),
    }
}

fn cstring(s: String) -> CString {
    CString::new(s.replace('\0', " ")).unwrap_or_default()
}

/// Runs `f`, catching panics; records the error of a failure for the getters.
fn guard(f: impl FnOnce() -> Result<(), Fail>) -> GpmStatus {
    let result = catch_unwind(AssertUnwindSafe(f)).unwrap_or_else(|panic| {
        let what = panic
            .downcast_ref::<&str>()
            .map(|s| s.to_string())
            .or_else(|| panic.downcast_ref::<String>().cloned())
            .unwrap_or_else(|| "unknown panic".into());
        Err(Fail {
            status: GpmStatus::Panic,
            message: format!("internal error (panic) in gpm: {what}"),
            particle: None,
            parameter: None,
        })
    });
    match result {
        Ok(()) => {
            LAST.with(|l| *l.borrow_mut() = None);
            GpmStatus::Ok
        }
        Err(f) => {
            let status = f.status;
            LAST.with(|l| {
                *l.borrow_mut() = Some(LastError {
                    message: cstring(f.message),
                    particle: f.particle.map_or(-1, |p| p as i64),
                    parameter: f.parameter.map(cstring),
                })
            });
            status
        }
    }
}

/// The message of the last failed call on this thread ("" after a success). Valid until the
/// next call into gpm on this thread.
#[no_mangle]
pub extern "C" fn gpm_last_error_message() -> *const c_char {
    static EMPTY: &CStr = c"";
    LAST.with(|l| {
        l.borrow()
            .as_ref()
            .map_or(EMPTY.as_ptr(), |e| e.message.as_ptr())
    })
}

/// The particle the last error names (an index into the arrays passed), or -1.
#[no_mangle]
pub extern "C" fn gpm_last_error_particle() -> i64 {
    LAST.with(|l| l.borrow().as_ref().map_or(-1, |e| e.particle))
}

/// The parameter or argument the last error names (`"dt"`, `"u"`, `"h"`, …), or NULL.
#[no_mangle]
pub extern "C" fn gpm_last_error_parameter() -> *const c_char {
    LAST.with(|l| {
        l.borrow()
            .as_ref()
            .and_then(|e| e.parameter.as_ref())
            .map_or(std::ptr::null(), |p| p.as_ptr())
    })
}

/// The name of a status (`"GPM_STATUS_INPUT"`, …); a static string.
#[no_mangle]
pub extern "C" fn gpm_status_name(status: GpmStatus) -> *const c_char {
    let s: &'static CStr = match status {
        GpmStatus::Ok => c"GPM_STATUS_OK",
        GpmStatus::NullPointer => c"GPM_STATUS_NULL_POINTER",
        GpmStatus::Input => c"GPM_STATUS_INPUT",
        GpmStatus::Connectivity => c"GPM_STATUS_CONNECTIVITY",
        GpmStatus::Solve => c"GPM_STATUS_SOLVE",
        GpmStatus::Stability => c"GPM_STATUS_STABILITY",
        GpmStatus::Record => c"GPM_STATUS_RECORD",
        GpmStatus::PairWeights => c"GPM_STATUS_PAIR_WEIGHTS",
        GpmStatus::Panic => c"GPM_STATUS_PANIC",
    };
    s.as_ptr()
}

/// gpm's version ("0.1.0"); a static string.
#[no_mangle]
pub extern "C" fn gpm_version() -> *const c_char {
    static V: &CStr = c"0.1.0";
    V.as_ptr()
}

// ---------------------------------------------------------------------------------------------
// the system

enum Bnd<const D: usize> {
    None(NoBoundary),
    Periodic(PeriodicBox<D>),
    Walls(Walls<D>),
}

impl<const D: usize> Bnd<D> {
    fn new(s: &GpmSettings) -> Result<Self, Fail> {
        let lo: [f64; D] = std::array::from_fn(|k| s.lo[k]);
        let hi: [f64; D] = std::array::from_fn(|k| s.hi[k]);
        Ok(match s.boundary {
            0 => Bnd::None(NoBoundary),
            1 => Bnd::Periodic(PeriodicBox {
                periodic: Periodicity::all(lo, std::array::from_fn(|k| hi[k] - lo[k])),
            }),
            2 => Bnd::Walls(Walls::closed_box(lo, hi)),
            3 => Bnd::Walls(Walls::channel(lo, hi)),
            4 => Bnd::Walls(Walls::cavity(hi[0] - lo[0], s.lid)),
            other => {
                return Err(Fail::arg(
                    "settings.boundary",
                    format!("{other} is not a GpmBoundaryKind (0 to 4)"),
                ))
            }
        })
    }
    fn get(&self) -> &dyn gpm::boundary::Boundary<D> {
        match self {
            Bnd::None(b) => b,
            Bnd::Periodic(b) => b,
            Bnd::Walls(b) => b,
        }
    }
    fn spec(&self) -> BoundarySpec {
        match self {
            Bnd::None(b) => ToBoundarySpec::<D>::to_spec(b),
            Bnd::Periodic(b) => b.to_spec(),
            Bnd::Walls(b) => b.to_spec(),
        }
    }
}

struct Inner<const D: usize> {
    particles: Particles<D>,
    n_user: usize,
    nl: NeighborList<D>,
    boundary: Bnd<D>,
    params: ProjectionParams<D>,
    step: ProjectionStep<D>,
    volumes: VolumeRule,
    last: Option<StepReport>,
}

enum Dim {
    D2(Box<Inner<2>>),
    D3(Box<Inner<3>>),
}

/// An opaque handle: the caller's particles (copied in), gpm's neighbour list, boundary,
/// parameters and projection scratch. Made by gpm_system_new, freed by gpm_system_free.
pub struct GpmSystem {
    dim: Dim,
}

/// An opaque handle on an MCAP recording. Made by gpm_recorder_new, finished and freed by
/// gpm_recorder_finish (or freed unfinished by gpm_recorder_free).
pub struct GpmRecorder {
    inner: Option<Recorder>,
}

macro_rules! with_dim {
    ($dim:expr, $s:ident, $body:expr) => {
        match $dim {
            Dim::D2($s) => {
                #[allow(dead_code)]
                const D: usize = 2;
                $body
            }
            Dim::D3($s) => {
                #[allow(dead_code)]
                const D: usize = 3;
                $body
            }
        }
    };
}

/// `ptr` as `rows` rows of `D` values (no copy), or the error naming `name`.
unsafe fn rows<'a, const D: usize>(
    name: &str,
    ptr: *const f64,
    rows: usize,
) -> Result<&'a [[f64; D]], Fail> {
    if ptr.is_null() {
        return Err(Fail::null(name));
    }
    // SAFETY: the caller passes `rows · D` doubles; `[f64; D]` has f64's alignment.
    Ok(unsafe { std::slice::from_raw_parts(ptr.cast::<[f64; D]>(), rows) })
}

unsafe fn rows_mut<'a, const D: usize>(
    name: &str,
    ptr: *mut f64,
    rows: usize,
) -> Result<&'a mut [[f64; D]], Fail> {
    if ptr.is_null() {
        return Err(Fail::null(name));
    }
    // SAFETY: as `rows`.
    Ok(unsafe { std::slice::from_raw_parts_mut(ptr.cast::<[f64; D]>(), rows) })
}

fn check_n(name: &str, n: usize, expected: usize) -> Result<(), Fail> {
    if n != expected {
        return Err(Fail::arg(
            name,
            format!("{n} rows given, the system has {expected} particles"),
        ));
    }
    Ok(())
}

impl<const D: usize> Inner<D> {
    unsafe fn new(
        s: &GpmSettings,
        n: usize,
        x: *const f64,
        u: *const f64,
        p: *const f64,
        vol: *const f64,
    ) -> Result<Self, Fail> {
        let x = unsafe { rows::<D>("x", x, n)? };
        let u = unsafe { rows::<D>("u", u, n)? };
        let boundary = Bnd::<D>::new(s)?;
        let mut particles = Particles::<D>::new();
        particles.x = x.to_vec();
        particles.u = u.to_vec();
        particles.p = if p.is_null() {
            vec![0.0; n]
        } else {
            unsafe { std::slice::from_raw_parts(p, n) }.to_vec()
        };
        let volumes = if s.fixed_volumes != 0 {
            VolumeRule::Fixed
        } else {
            VolumeRule::NumberDensity
        };
        particles.vol = if vol.is_null() {
            if volumes == VolumeRule::Fixed {
                return Err(Fail::null("vol"));
            }
            vec![1.0; n]
        } else {
            unsafe { std::slice::from_raw_parts(vol, n) }.to_vec()
        };
        particles.role = vec![Role::Fluid; n];
        let weight = match s.weight {
            0 => Weight::WendlandC2,
            1 => Weight::WendlandC4,
            2 => Weight::CubicSpline,
            other => {
                return Err(Fail::arg(
                    "settings.weight",
                    format!("{other} is not a GpmWeight (0 to 2)"),
                ))
            }
        };
        let mut params = ProjectionParams::<D>::new(s.nu);
        params.rho = s.rho;
        params.scheme = match s.scheme {
            0 => Scheme::Rotational,
            1 => Scheme::Incremental,
            2 => Scheme::NonIncremental,
            other => {
                return Err(Fail::arg(
                    "settings.scheme",
                    format!("{other} is not a GpmScheme (0 to 2)"),
                ))
            }
        };
        params.viscous_theta = s.viscous_theta;
        params.gravity = std::array::from_fn(|k| s.gravity[k]);
        params.allowed_floating = s.allowed_floating as usize;
        params.validate()?;
        let config = NeighborConfig::new(weight, s.h, s.skin);
        let nl = gpm::setup::prepare(&mut particles, boundary.get(), config, volumes)?;
        Ok(Inner {
            particles,
            n_user: n,
            nl,
            boundary,
            params,
            step: ProjectionStep::new(),
            volumes,
            last: None,
        })
    }

    fn record(&self, rec: &mut Recorder, step: u64, time: f64) -> Result<(), Fail> {
        let report = self.last.as_ref().ok_or_else(|| {
            Fail::arg(
                "system",
                "no step to record: call gpm_system_project or gpm_system_step first".into(),
            )
        })?;
        let snapshot = rec.wants_snapshot(step);
        let spec = self.boundary.spec();
        let projection = self
            .step
            .captured
            .as_ref()
            .filter(|_| snapshot)
            .map(|capture| ProjectionRecord {
                capture,
                neighbors: self.nl.config(),
                boundary: &spec,
                params: &self.params,
            });
        rec.record(&StepRecord {
            context: StepContext::new(step, time, self.params.allowed_floating),
            report,
            particles: snapshot.then(|| (&self.particles).into()),
            projection,
        })?;
        Ok(())
    }
}

/// Fills `settings` with the defaults: 2-D, h = 0 (to be set), no skin, Wendland C2, no
/// boundary, ρ = 1, ν = 0, no gravity, the rotational scheme, θ = ½, one floating component,
/// number-density volumes.
#[no_mangle]
pub unsafe extern "C" fn gpm_settings_default(settings: *mut GpmSettings) -> GpmStatus {
    guard(|| {
        let s = unsafe { settings.as_mut() }.ok_or_else(|| Fail::null("settings"))?;
        *s = GpmSettings {
            dim: 2,
            h: 0.0,
            skin: 0.0,
            weight: GpmWeight::WendlandC2 as u32,
            boundary: GpmBoundaryKind::None as u32,
            lo: [0.0; 3],
            hi: [1.0; 3],
            lid: 1.0,
            rho: 1.0,
            nu: 0.0,
            gravity: [0.0; 3],
            scheme: GpmScheme::Rotational as u32,
            viscous_theta: 0.5,
            allowed_floating: 1,
            fixed_volumes: 0,
        };
        Ok(())
    })
}

/// Makes a system of `n` particles: `x` and `u` are `n × dim` doubles (row-major), `p` and
/// `vol` `n` doubles or NULL (zero pressure; volumes from the number density). Sets up the
/// ghosts, the neighbour list and the volumes. On success `*out` holds the handle.
#[no_mangle]
pub unsafe extern "C" fn gpm_system_new(
    settings: *const GpmSettings,
    n: usize,
    x: *const f64,
    u: *const f64,
    p: *const f64,
    vol: *const f64,
    out: *mut *mut GpmSystem,
) -> GpmStatus {
    guard(|| {
        let out = unsafe { out.as_mut() }.ok_or_else(|| Fail::null("out"))?;
        *out = std::ptr::null_mut();
        let s = unsafe { settings.as_ref() }.ok_or_else(|| Fail::null("settings"))?;
        let dim = match s.dim {
            2 => Dim::D2(Box::new(unsafe { Inner::<2>::new(s, n, x, u, p, vol)? })),
            3 => Dim::D3(Box::new(unsafe { Inner::<3>::new(s, n, x, u, p, vol)? })),
            d => {
                return Err(Fail::arg(
                    "settings.dim",
                    format!("{d}: the dimension must be 2 or 3"),
                ))
            }
        };
        *out = Box::into_raw(Box::new(GpmSystem { dim }));
        Ok(())
    })
}

/// Frees a system (NULL is ignored).
#[no_mangle]
pub unsafe extern "C" fn gpm_system_free(system: *mut GpmSystem) {
    if !system.is_null() {
        let _ = catch_unwind(AssertUnwindSafe(|| drop(unsafe { Box::from_raw(system) })));
    }
}

/// The number of the caller's particles (ghosts excluded); 0 for NULL.
#[no_mangle]
pub unsafe extern "C" fn gpm_system_len(system: *const GpmSystem) -> usize {
    unsafe { system.as_ref() }.map_or(0, |s| with_dim!(&s.dim, s, s.n_user))
}

/// The dimension (2 or 3); 0 for NULL.
#[no_mangle]
pub unsafe extern "C" fn gpm_system_dim(system: *const GpmSystem) -> u32 {
    unsafe { system.as_ref() }.map_or(0, |s| match s.dim {
        Dim::D2(_) => 2,
        Dim::D3(_) => 3,
    })
}

fn system_mut<'a>(system: *mut GpmSystem) -> Result<&'a mut GpmSystem, Fail> {
    unsafe { system.as_mut() }.ok_or_else(|| Fail::null("system"))
}

fn system_ref<'a>(system: *const GpmSystem) -> Result<&'a GpmSystem, Fail> {
    unsafe { system.as_ref() }.ok_or_else(|| Fail::null("system"))
}

/// After the particles moved (gpm_system_set_positions): confines them, places the ghosts,
/// updates the neighbour list and the volumes. `*rebuilt` (may be NULL) is set to 1 when the
/// neighbour candidates were searched again.
#[no_mangle]
pub unsafe extern "C" fn gpm_system_update_neighbors(
    system: *mut GpmSystem,
    rebuilt: *mut c_int,
) -> GpmStatus {
    guard(|| {
        let s = system_mut(system)?;
        let r = with_dim!(&mut s.dim, s, {
            let s: &mut Inner<D> = s;
            gpm::setup::update(&mut s.particles, s.boundary.get(), &mut s.nl, s.volumes)
        })?;
        if let Some(out) = unsafe { rebuilt.as_mut() } {
            *out = r as c_int;
        }
        Ok(())
    })
}

/// Which array a get/set call addresses.
#[derive(Clone, Copy)]
enum Field {
    X,
    U,
}

unsafe fn get_rows(system: *const GpmSystem, f: Field, out: *mut f64, n: usize) -> GpmStatus {
    guard(|| {
        let s = system_ref(system)?;
        with_dim!(&s.dim, s, {
            let s: &Inner<D> = s;
            check_n("n", n, s.n_user)?;
            let dst = unsafe { rows_mut::<D>("out", out, n)? };
            let src = match f {
                Field::X => &s.particles.x,
                Field::U => &s.particles.u,
            };
            dst.copy_from_slice(&src[..n]);
            Ok(())
        })
    })
}

unsafe fn set_rows(system: *mut GpmSystem, f: Field, v: *const f64, n: usize) -> GpmStatus {
    guard(|| {
        let s = system_mut(system)?;
        with_dim!(&mut s.dim, s, {
            let s: &mut Inner<D> = s;
            check_n("n", n, s.n_user)?;
            let src = unsafe { rows::<D>(if let Field::X = f { "x" } else { "u" }, v, n)? };
            let dst = match f {
                Field::X => &mut s.particles.x,
                Field::U => &mut s.particles.u,
            };
            dst[..n].copy_from_slice(src);
            Ok(())
        })
    })
}

/// Copies the positions (n × dim) into `out`; `n` must be gpm_system_len.
#[no_mangle]
pub unsafe extern "C" fn gpm_system_get_positions(
    system: *const GpmSystem,
    out: *mut f64,
    n: usize,
) -> GpmStatus {
    unsafe { get_rows(system, Field::X, out, n) }
}

/// Sets the positions (n × dim); call gpm_system_update_neighbors before the next projection.
#[no_mangle]
pub unsafe extern "C" fn gpm_system_set_positions(
    system: *mut GpmSystem,
    x: *const f64,
    n: usize,
) -> GpmStatus {
    unsafe { set_rows(system, Field::X, x, n) }
}

/// Copies the velocities (n × dim) into `out`.
#[no_mangle]
pub unsafe extern "C" fn gpm_system_get_velocities(
    system: *const GpmSystem,
    out: *mut f64,
    n: usize,
) -> GpmStatus {
    unsafe { get_rows(system, Field::U, out, n) }
}

/// Sets the velocities (n × dim).
#[no_mangle]
pub unsafe extern "C" fn gpm_system_set_velocities(
    system: *mut GpmSystem,
    u: *const f64,
    n: usize,
) -> GpmStatus {
    unsafe { set_rows(system, Field::U, u, n) }
}

/// Copies the pressures (n) into `out`.
#[no_mangle]
pub unsafe extern "C" fn gpm_system_get_pressures(
    system: *const GpmSystem,
    out: *mut f64,
    n: usize,
) -> GpmStatus {
    guard(|| {
        let s = system_ref(system)?;
        with_dim!(&s.dim, s, {
            check_n("n", n, s.n_user)?;
            if out.is_null() {
                return Err(Fail::null("out"));
            }
            let dst = unsafe { std::slice::from_raw_parts_mut(out, n) };
            dst.copy_from_slice(&s.particles.p[..n]);
            Ok(())
        })
    })
}

/// Copies the volumes (n) into `out`.
#[no_mangle]
pub unsafe extern "C" fn gpm_system_get_volumes(
    system: *const GpmSystem,
    out: *mut f64,
    n: usize,
) -> GpmStatus {
    guard(|| {
        let s = system_ref(system)?;
        with_dim!(&s.dim, s, {
            check_n("n", n, s.n_user)?;
            if out.is_null() {
                return Err(Fail::null("out"));
            }
            let dst = unsafe { std::slice::from_raw_parts_mut(out, n) };
            dst.copy_from_slice(&s.particles.vol[..n]);
            Ok(())
        })
    })
}

/// Keep (non-zero) the projection's inputs for gpm_recorder_record's re-runnable
/// `/projection_input` at snapshot steps.
#[no_mangle]
pub unsafe extern "C" fn gpm_system_set_capture(system: *mut GpmSystem, on: c_int) -> GpmStatus {
    guard(|| {
        let s = system_mut(system)?;
        with_dim!(&mut s.dim, s, s.step.capture = on != 0);
        Ok(())
    })
}

/// Maps `n` positions (n × dim, any array of the caller's) into the periodic box in place,
/// exactly as gpm does; leaves them unchanged without periodic axes.
#[no_mangle]
pub unsafe extern "C" fn gpm_system_wrap(
    system: *const GpmSystem,
    x: *mut f64,
    n: usize,
) -> GpmStatus {
    guard(|| {
        let s = system_ref(system)?;
        with_dim!(&s.dim, s, {
            let per = s.boundary.get().periodicity();
            for p in unsafe { rows_mut::<D>("x", x, n)? } {
                per.wrap(p);
            }
            Ok(())
        })
    })
}

/// The predictor: writes u* (n × dim) into `u_star` from the velocities, the viscous term,
/// −∇p/ρ (incremental schemes), gravity and `accel` (n × dim, or NULL). The particles are not
/// changed. Move them with u*, set the positions, update the neighbours, then project.
#[no_mangle]
pub unsafe extern "C" fn gpm_system_predict(
    system: *mut GpmSystem,
    dt: f64,
    accel: *const f64,
    u_star: *mut f64,
    n: usize,
) -> GpmStatus {
    guard(|| {
        let s = system_mut(system)?;
        with_dim!(&mut s.dim, s, {
            let s: &mut Inner<D> = s;
            check_n("n", n, s.n_user)?;
            let out = unsafe { rows_mut::<D>("u_star", u_star, n)? };
            let acc = if accel.is_null() {
                None
            } else {
                Some(unsafe { rows::<D>("accel", accel, n)? })
            };
            let mut buf = Vec::with_capacity(s.particles.len());
            s.step.predict(
                &mut s.particles,
                &s.nl,
                s.boundary.get(),
                &s.params,
                dt,
                acc,
                &mut buf,
            )?;
            out.copy_from_slice(&buf[..n]);
            Ok(())
        })
    })
}

/// Projects `u_star` (n × dim) on the current configuration: connectivity and c0 checked
/// first, the Poisson solve, u and p corrected (unchanged on error). `report` may be NULL.
#[no_mangle]
pub unsafe extern "C" fn gpm_system_project(
    system: *mut GpmSystem,
    dt: f64,
    u_star: *const f64,
    n: usize,
    report: *mut GpmReport,
) -> GpmStatus {
    guard(|| {
        let s = system_mut(system)?;
        with_dim!(&mut s.dim, s, {
            let s: &mut Inner<D> = s;
            check_n("n", n, s.n_user)?;
            let us = unsafe { rows::<D>("u_star", u_star, n)? };
            let r = s
                .step
                .project(&mut s.particles, &s.nl, s.boundary.get(), &s.params, dt, us)?;
            if let Some(out) = unsafe { report.as_mut() } {
                *out = GpmReport::from(&r);
            }
            s.last = Some(r);
            Ok(())
        })
    })
}

/// Predictor and projection on the same configuration (particles that do not move during the
/// step); `accel` (n × dim) and `report` may be NULL.
#[no_mangle]
pub unsafe extern "C" fn gpm_system_step(
    system: *mut GpmSystem,
    dt: f64,
    accel: *const f64,
    n: usize,
    report: *mut GpmReport,
) -> GpmStatus {
    guard(|| {
        let s = system_mut(system)?;
        with_dim!(&mut s.dim, s, {
            let s: &mut Inner<D> = s;
            check_n("n", n, s.n_user)?;
            let acc = if accel.is_null() {
                None
            } else {
                Some(unsafe { rows::<D>("accel", accel, n)? })
            };
            let r = s.step.step(
                &mut s.particles,
                &s.nl,
                s.boundary.get(),
                &s.params,
                dt,
                acc,
            )?;
            if let Some(out) = unsafe { report.as_mut() } {
                *out = GpmReport::from(&r);
            }
            s.last = Some(r);
            Ok(())
        })
    })
}

// ---------------------------------------------------------------------------------------------
// recording

/// Starts an MCAP recording at `path` (written as `path.partial`, renamed by
/// gpm_recorder_finish): `level` a GpmRecordLevel, snapshots every `every` steps at level full,
/// `config_json` the loop's settings as JSON text (recorded as `/config`; NULL for none).
#[no_mangle]
pub unsafe extern "C" fn gpm_recorder_new(
    path: *const c_char,
    level: u32,
    every: u64,
    config_json: *const c_char,
    out: *mut *mut GpmRecorder,
) -> GpmStatus {
    guard(|| {
        let out = unsafe { out.as_mut() }.ok_or_else(|| Fail::null("out"))?;
        *out = std::ptr::null_mut();
        if path.is_null() {
            return Err(Fail::null("path"));
        }
        let path = unsafe { CStr::from_ptr(path) }
            .to_str()
            .map_err(|e| Fail::arg("path", format!("not UTF-8: {e}")))?;
        let level = match level {
            0 => RecordLevel::None,
            1 => RecordLevel::Diagnostics,
            2 => RecordLevel::Full,
            other => {
                return Err(Fail::arg(
                    "level",
                    format!("{other} is not a GpmRecordLevel (0 to 2)"),
                ))
            }
        };
        if every == 0 {
            return Err(InputError::parameter("every", 0.0, "snapshots every 0 steps").into());
        }
        let config = if config_json.is_null() {
            serde_json::Value::Null
        } else {
            let text = unsafe { CStr::from_ptr(config_json) }
                .to_str()
                .map_err(|e| Fail::arg("config_json", format!("not UTF-8: {e}")))?;
            gpm::scene::strict_json(text)?
        };
        let rec = Recorder::create_with(path, RecorderOptions::new(level, every), &config)?;
        *out = Box::into_raw(Box::new(GpmRecorder { inner: Some(rec) }));
        Ok(())
    })
}

/// Whether step `step` gets a snapshot (`*wants` = 1): steps 1, k+1, 2k+1, … at level full.
#[no_mangle]
pub unsafe extern "C" fn gpm_recorder_wants_snapshot(
    recorder: *const GpmRecorder,
    step: u64,
    wants: *mut c_int,
) -> GpmStatus {
    guard(|| {
        let r = unsafe { recorder.as_ref() }.ok_or_else(|| Fail::null("recorder"))?;
        let w = unsafe { wants.as_mut() }.ok_or_else(|| Fail::null("wants"))?;
        *w = r.inner.as_ref().is_some_and(|r| r.wants_snapshot(step)) as c_int;
        Ok(())
    })
}

/// Records the system's last step (its last gpm_system_project or gpm_system_step) as step
/// `step` (from 1) ending at `time`; at snapshot steps also the particles and, with capture
/// on, the projection's inputs.
#[no_mangle]
pub unsafe extern "C" fn gpm_recorder_record(
    recorder: *mut GpmRecorder,
    system: *const GpmSystem,
    step: u64,
    time: f64,
) -> GpmStatus {
    guard(|| {
        let r = unsafe { recorder.as_mut() }.ok_or_else(|| Fail::null("recorder"))?;
        let s = system_ref(system)?;
        if step == 0 {
            return Err(InputError::parameter("step", 0.0, "steps are numbered from 1").into());
        }
        let rec = r
            .inner
            .as_mut()
            .ok_or_else(|| Fail::arg("recorder", "the recording is finished".into()))?;
        with_dim!(&s.dim, s, s.record(rec, step, time))
    })
}

/// Finishes the file (summary, footer, rename to `path`) and frees the recorder, whatever the
/// outcome. `*steps` (may be NULL) receives the steps recorded.
#[no_mangle]
pub unsafe extern "C" fn gpm_recorder_finish(
    recorder: *mut GpmRecorder,
    steps: *mut u64,
) -> GpmStatus {
    guard(|| {
        if recorder.is_null() {
            return Err(Fail::null("recorder"));
        }
        let mut r = unsafe { Box::from_raw(recorder) };
        let rec = r
            .inner
            .take()
            .ok_or_else(|| Fail::arg("recorder", "the recording is finished".into()))?;
        let summary = rec.finish()?;
        if let Some(out) = unsafe { steps.as_mut() } {
            *out = summary.steps;
        }
        Ok(())
    })
}

/// Frees a recorder without renaming its file (it stays `path.partial`); NULL is ignored.
#[no_mangle]
pub unsafe extern "C" fn gpm_recorder_free(recorder: *mut GpmRecorder) {
    if !recorder.is_null() {
        let _ = catch_unwind(AssertUnwindSafe(|| {
            drop(unsafe { Box::from_raw(recorder) })
        }));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn settings() -> GpmSettings {
        let mut s = std::mem::MaybeUninit::<GpmSettings>::uninit();
        assert_eq!(
            unsafe { gpm_settings_default(s.as_mut_ptr()) },
            GpmStatus::Ok
        );
        unsafe { s.assume_init() }
    }

    fn lattice(n: usize) -> Vec<f64> {
        let dx = 1.0 / n as f64;
        gpm::geometry::lattice([0.0, 0.0], [1.0, 1.0], dx)
            .into_iter()
            .flatten()
            .collect()
    }

    /// The defaults on the periodic unit square with `h = 3 Δx` for an `n × n` lattice.
    fn periodic_settings(n: usize) -> GpmSettings {
        let mut s = settings();
        s.h = 3.0 / n as f64;
        s.boundary = GpmBoundaryKind::Periodic as u32;
        s
    }

    /// A system of the 2D particles at `x` with velocities `u` (no pressures or volumes given).
    fn new_system(s: &GpmSettings, x: &[f64], u: &[f64]) -> *mut GpmSystem {
        let mut sys = std::ptr::null_mut();
        let st = unsafe {
            gpm_system_new(
                s,
                x.len() / 2,
                x.as_ptr(),
                u.as_ptr(),
                std::ptr::null(),
                std::ptr::null(),
                &mut sys,
            )
        };
        assert_eq!(st, GpmStatus::Ok, "{}", message());
        sys
    }

    fn message() -> String {
        unsafe { CStr::from_ptr(gpm_last_error_message()) }
            .to_string_lossy()
            .into_owned()
    }

    fn parameter() -> Option<String> {
        let p = gpm_last_error_parameter();
        (!p.is_null()).then(|| unsafe { CStr::from_ptr(p) }.to_string_lossy().into_owned())
    }

    #[test]
    fn null_pointers_are_errors_not_crashes() {
        let mut sys = std::ptr::null_mut();
        let st = unsafe {
            gpm_system_new(
                std::ptr::null(),
                0,
                std::ptr::null(),
                std::ptr::null(),
                std::ptr::null(),
                std::ptr::null(),
                &mut sys,
            )
        };
        assert_eq!(st, GpmStatus::NullPointer);
        assert_eq!(parameter().as_deref(), Some("settings"));
        let s = settings();
        let st = unsafe {
            gpm_system_new(
                &s,
                4,
                std::ptr::null(),
                std::ptr::null(),
                std::ptr::null(),
                std::ptr::null(),
                &mut sys,
            )
        };
        assert_eq!(st, GpmStatus::NullPointer);
        assert!(message().contains("'x'"), "{}", message());
        assert!(sys.is_null());
        assert_eq!(
            unsafe {
                gpm_system_step(
                    std::ptr::null_mut(),
                    0.1,
                    std::ptr::null(),
                    0,
                    std::ptr::null_mut(),
                )
            },
            GpmStatus::NullPointer
        );
        unsafe { gpm_system_free(std::ptr::null_mut()) };
    }

    #[test]
    fn the_report_carries_the_viscous_solve_of_a_step() {
        let n = 12;
        let x = lattice(n);
        // a shear wave: the implicit viscous solve has something to do
        let u: Vec<f64> = x
            .chunks_exact(2)
            .flat_map(|p| [(2.0 * std::f64::consts::PI * p[1]).sin(), 0.0])
            .collect();
        let mut s = periodic_settings(n);
        s.nu = 0.01;
        assert_eq!(s.viscous_theta, 0.5, "implicit by default");
        let sys = new_system(&s, &x, &u);
        let mut r = GpmReport::default();
        let st = unsafe { gpm_system_step(sys, 0.01, std::ptr::null(), n * n, &mut r) };
        assert_eq!(st, GpmStatus::Ok, "{}", message());
        assert_eq!(r.viscous_unknowns, n * n);
        assert!(r.viscous_rel_residual < 1e-10, "{}", r.viscous_rel_residual);
        // a projection alone runs no viscous solve
        let mut q = GpmReport::default();
        let st = unsafe { gpm_system_project(sys, 0.01, u.as_ptr(), n * n, &mut q) };
        assert_eq!(st, GpmStatus::Ok, "{}", message());
        assert_eq!((q.viscous_unknowns, q.viscous_iters), (0, 0));
        unsafe { gpm_system_free(sys) };
    }

    #[test]
    fn errors_name_the_particle_and_the_parameter() {
        let n = 12;
        let x = lattice(n);
        let mut u = vec![0.0; x.len()];
        let mut s = periodic_settings(n);
        let sys = new_system(&s, &x, &u);
        // dt
        let st =
            unsafe { gpm_system_step(sys, -1.0, std::ptr::null(), n * n, std::ptr::null_mut()) };
        assert_eq!(st, GpmStatus::Input);
        assert_eq!(parameter().as_deref(), Some("dt"));
        // NaN velocity at particle 9
        u[2 * 9 + 1] = f64::NAN;
        assert_eq!(
            unsafe { gpm_system_set_velocities(sys, u.as_ptr(), n * n) },
            GpmStatus::Ok
        );
        let mut us = vec![0.0; x.len()];
        let st = unsafe { gpm_system_predict(sys, 0.01, std::ptr::null(), us.as_mut_ptr(), n * n) };
        assert_eq!(st, GpmStatus::Input);
        assert_eq!(gpm_last_error_particle(), 9);
        assert!(message().contains("particle 9"), "{}", message());
        // wrong row count
        let st = unsafe { gpm_system_set_velocities(sys, u.as_ptr(), 3) };
        assert_eq!(st, GpmStatus::Input);
        assert_eq!(parameter().as_deref(), Some("n"));
        // a bad enumeration value
        s.scheme = 99;
        let mut other = std::ptr::null_mut();
        let st = unsafe {
            gpm_system_new(
                &s,
                n * n,
                x.as_ptr(),
                u.as_ptr(),
                std::ptr::null(),
                std::ptr::null(),
                &mut other,
            )
        };
        assert_eq!(st, GpmStatus::Input);
        assert_eq!(parameter().as_deref(), Some("settings.scheme"));
        unsafe { gpm_system_free(sys) };
    }
}
