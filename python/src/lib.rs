//! Python bindings of gpm (`import gpm`): the checked GPM projection for a particle loop written
//! in Python, the neighbour list, the ready-made scenes and MCAP recording.
//!
//! The caller's particles live in a [`System`] (gpm's `Particles`, neighbour list, boundary,
//! projection parameters and the projection's scratch). Arrays cross the boundary as follows:
//!
//! - inputs (`accel`, `u_star`) are read in place when they are C-contiguous float64 arrays of
//!   shape `(n, dim)` (no copy; anything else is converted once);
//! - `predict` hands its `u*` buffer to numpy (no copy);
//! - the `x`, `u`, `p`, `vol` getters copy: the projection swaps its velocity and pressure
//!   buffers every step, so a view would go stale;
//! - setters copy into gpm's arrays.
//!
//! Every gpm error becomes an exception of the `gpm` package (`gpm.InputError`, …, all
//! subclasses of `gpm.GpmError`) carrying gpm's message and, where gpm knows them, the
//! offending `particle` and `parameter`. Nothing panics across the boundary: a panic inside gpm
//! surfaces as `pyo3_runtime.PanicException`, never an abort.

use gpm::boundary::{NoBoundary, PeriodicBox, Walls};
use gpm::error::{Error, InputError};
use gpm::kernel::Weight;
use gpm::neighbors::{NeighborConfig, NeighborList, Periodicity};
use gpm::particles::{Particles, Role};
use gpm::poisson::SolveParams;
use gpm::projection::{ProjectionParams, ProjectionStep, Scheme, StepReport};
use gpm::record::schema::{BoundarySpec, ToBoundarySpec};
use gpm::record::{
    ProjectionRecord, RecordLevel, Recorder as GpmRecorder, RecorderOptions, StepContext,
    StepRecord,
};
use gpm::scene::{Scene, SceneVisitor};
use gpm::setup::VolumeRule;
use numpy::{PyArray1, PyArrayMethods, PyReadonlyArray2, PyUntypedArrayMethods};
use pyo3::prelude::*;
use pyo3::sync::PyOnceLock;
use pyo3::types::{PyDict, PyList, PyType};
use std::ops::ControlFlow;
use std::path::PathBuf;

// ---------------------------------------------------------------------------------------------
// errors

/// The exception class `gpm.<name>` (defined in `gpm/_errors.py`).
fn error_class<'py>(py: Python<'py>, name: &'static str) -> PyResult<&'py Bound<'py, PyType>> {
    static INPUT: PyOnceLock<Py<PyType>> = PyOnceLock::new();
    static CONNECTIVITY: PyOnceLock<Py<PyType>> = PyOnceLock::new();
    static SOLVE: PyOnceLock<Py<PyType>> = PyOnceLock::new();
    static STABILITY: PyOnceLock<Py<PyType>> = PyOnceLock::new();
    static RECORD: PyOnceLock<Py<PyType>> = PyOnceLock::new();
    static PAIR: PyOnceLock<Py<PyType>> = PyOnceLock::new();
    let cell = match name {
        "InputError" => &INPUT,
        "ConnectivityError" => &CONNECTIVITY,
        "SolveError" => &SOLVE,
        "StabilityError" => &STABILITY,
        "RecordError" => &RECORD,
        _ => &PAIR,
    };
    cell.import(py, "gpm._errors", name)
}

/// The exception for a gpm error: its class by stage, gpm's message, and the attributes
/// `particle`, `parameter` and (connectivity) `offending`.
fn to_py_err(e: Error) -> PyErr {
    Python::attach(|py| match build_exception(py, &e) {
        Ok(err) => err,
        Err(err) => err,
    })
}

fn build_exception(py: Python<'_>, e: &Error) -> PyResult<PyErr> {
    let (class, particle, parameter): (&str, Option<usize>, Option<String>) = match e {
        Error::Input(i) => {
            let (particle, parameter) = input_location(i);
            ("InputError", particle, parameter)
        }
        Error::Connectivity(c) => ("ConnectivityError", c.offending.first().copied(), None),
        Error::Solve(s) => {
            let particle = match s {
                gpm::error::SolveError::NotPositiveDefinite { particle, .. }
                | gpm::error::SolveError::NonFinite { particle } => Some(*particle),
                _ => None,
            };
            ("SolveError", particle, None)
        }
        Error::Stability(s) => {
            let particle = match s {
                gpm::error::StabilityError::BlowUp { particle, .. } => Some(*particle),
                _ => None,
            };
            ("StabilityError", particle, None)
        }
        Error::Record(_) => ("RecordError", None, None),
        Error::PairWeights(p) => {
            let particle = match p {
                gpm::error::PairWeightError::NoConvergence { particle, .. }
                | gpm::error::PairWeightError::NonFinite { particle } => Some(*particle),
            };
            ("PairWeightError", particle, None)
        }
        // a decomposed run's step failed on another rank: not reachable from Python (one
        // process), classed with the solve
        Error::PeerFailed { .. } => ("SolveError", None, None),
    };
    let mut message = e.to_string();
    if let Error::Input(InputError::StaleNeighbors { .. }) = e {
        message.push_str(" (from Python: System.update_neighbors() after moving particles)");
    }
    let exc = error_class(py, class)?.call1((message,))?;
    exc.setattr("particle", particle)?;
    exc.setattr("parameter", parameter)?;
    if let Error::Connectivity(c) = e {
        exc.setattr("offending", c.offending.clone())?;
    }
    Ok(PyErr::from_value(exc))
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

/// A `gpm.InputError` about the binding's own argument `name` (shape, dtype, value).
fn arg_error(name: &str, reason: String) -> PyErr {
    let e: Error = InputError::Config {
        key: name.to_string(),
        reason,
    }
    .into();
    to_py_err(e)
}

fn param_error(name: &'static str, value: f64, reason: &str) -> PyErr {
    to_py_err(InputError::parameter(name, value, reason).into())
}

trait OrPy<T> {
    fn py(self) -> PyResult<T>;
}

impl<T, E: Into<Error>> OrPy<T> for Result<T, E> {
    fn py(self) -> PyResult<T> {
        self.map_err(|e| to_py_err(e.into()))
    }
}

// ---------------------------------------------------------------------------------------------
// arrays

/// `obj` as a float64 array of shape `(rows, D)` (`rows` checked when given), read in place when
/// it already is a C-contiguous float64 array.
fn read_rows<'py>(
    py: Python<'py>,
    name: &str,
    obj: &Bound<'py, PyAny>,
    dim: usize,
    rows: Option<usize>,
) -> PyResult<PyReadonlyArray2<'py, f64>> {
    let arr = match obj.extract::<PyReadonlyArray2<'py, f64>>() {
        Ok(a) if a.is_c_contiguous() => a,
        _ => {
            let np = py.import("numpy")?;
            let conv = np
                .call_method1("ascontiguousarray", (obj, "float64"))
                .map_err(|e| {
                    arg_error(
                        name,
                        format!("expected an array of floats of shape (n, {dim}): {e}"),
                    )
                })?;
            conv.extract::<PyReadonlyArray2<'py, f64>>().map_err(|_| {
                let shape: Option<Vec<usize>> =
                    conv.getattr("shape").and_then(|s| s.extract()).ok();
                arg_error(
                    name,
                    format!("expected an array of shape (n, {dim}), got shape {shape:?}"),
                )
            })?
        }
    };
    let shape = arr.shape();
    if shape[1] != dim || rows.is_some_and(|r| r != shape[0]) {
        let want = rows.map_or("n".to_string(), |r| r.to_string());
        return Err(arg_error(
            name,
            format!(
                "expected an array of shape ({want}, {dim}), got ({}, {})",
                shape[0], shape[1]
            ),
        ));
    }
    Ok(arr)
}

/// The rows of a C-contiguous `(n, D)` array as `[f64; D]` (no copy).
fn as_rows<'a, const D: usize>(arr: &'a PyReadonlyArray2<'_, f64>) -> &'a [[f64; D]] {
    let flat = arr
        .as_slice()
        .expect("read_rows returns C-contiguous arrays");
    // SAFETY: `[f64; D]` has the size of D f64 and the alignment of f64, no padding; the
    // slice holds `rows · D` values (checked by read_rows).
    unsafe { std::slice::from_raw_parts(flat.as_ptr().cast::<[f64; D]>(), flat.len() / D) }
}

/// A float vector of length `rows` (any sequence or array).
fn read_vec(py: Python<'_>, name: &str, obj: &Bound<'_, PyAny>, rows: usize) -> PyResult<Vec<f64>> {
    let np = py.import("numpy")?;
    let conv = np
        .call_method1("ascontiguousarray", (obj, "float64"))
        .and_then(|a| a.call_method1("reshape", (-1,)))
        .map_err(|e| arg_error(name, format!("expected {rows} floats: {e}")))?;
    let arr = conv.extract::<numpy::PyReadonlyArray1<'_, f64>>()?;
    if arr.len() != rows {
        return Err(arg_error(
            name,
            format!("expected {rows} values, got {}", arr.len()),
        ));
    }
    Ok(arr.as_slice()?.to_vec())
}

/// A point of dimension `dim` from any sequence.
fn read_point(name: &str, v: &[f64], dim: usize) -> PyResult<Vec<f64>> {
    if v.len() != dim {
        return Err(arg_error(
            name,
            format!("expected {dim} coordinates, got {}", v.len()),
        ));
    }
    Ok(v.to_vec())
}

/// `Vec<[f64; D]>` reinterpreted as its `len · D` values (no copy).
fn flatten<const D: usize>(v: Vec<[f64; D]>) -> Vec<f64> {
    let mut v = std::mem::ManuallyDrop::new(v);
    let (ptr, len, cap) = (v.as_mut_ptr(), v.len(), v.capacity());
    // SAFETY: same allocation, same alignment (f64), size cap · D · 8 bytes either way.
    unsafe { Vec::from_raw_parts(ptr.cast::<f64>(), len * D, cap * D) }
}

/// A numpy `(rows, D)` array owning `v` (no copy), `rows ≤ v.len()` (a view of the first rows).
fn to_numpy<const D: usize>(
    py: Python<'_>,
    v: Vec<[f64; D]>,
    rows: usize,
) -> PyResult<Bound<'_, PyAny>> {
    let n = v.len();
    let arr = PyArray1::from_vec(py, flatten(v)).reshape([n, D])?;
    if rows == n {
        Ok(arr.into_any())
    } else {
        arr.into_any()
            .get_item(pyo3::types::PySlice::new(py, 0, rows as isize, 1))
    }
}

// ---------------------------------------------------------------------------------------------
// JSON <-> Python

fn json_to_py(py: Python<'_>, v: &serde_json::Value) -> PyResult<Py<PyAny>> {
    use serde_json::Value;
    Ok(match v {
        Value::Null => py.None(),
        Value::Bool(b) => b.into_pyobject(py)?.to_owned().into_any().unbind(),
        Value::Number(n) => {
            if let Some(i) = n.as_i64() {
                i.into_pyobject(py)?.into_any().unbind()
            } else if let Some(u) = n.as_u64() {
                u.into_pyobject(py)?.into_any().unbind()
            } else {
                n.as_f64()
                    .unwrap_or(f64::NAN)
                    .into_pyobject(py)?
                    .into_any()
                    .unbind()
            }
        }
        Value::String(s) => s.into_pyobject(py)?.into_any().unbind(),
        Value::Array(a) => {
            let l = PyList::empty(py);
            for x in a {
                l.append(json_to_py(py, x)?)?;
            }
            l.into_any().unbind()
        }
        Value::Object(m) => {
            let d = PyDict::new(py);
            for (k, x) in m {
                d.set_item(k, json_to_py(py, x)?)?;
            }
            d.into_any().unbind()
        }
    })
}

/// A configuration given as a dict (or any JSON-serialisable value), a JSON string, or `None`.
fn config_text(py: Python<'_>, name: &str, config: Option<&Bound<'_, PyAny>>) -> PyResult<String> {
    match config {
        None => Ok("{}".into()),
        Some(c) if c.is_none() => Ok("{}".into()),
        Some(c) => {
            if let Ok(s) = c.extract::<String>() {
                return Ok(s);
            }
            py.import("json")?
                .call_method1("dumps", (c,))
                .and_then(|s| s.extract::<String>())
                .map_err(|e| arg_error(name, format!("not JSON-serialisable: {e}")))
        }
    }
}

fn to_json_value<T: serde::Serialize>(v: &T) -> serde_json::Value {
    serde_json::to_value(v).unwrap_or(serde_json::Value::Null)
}

// ---------------------------------------------------------------------------------------------
// boundary

/// The boundary of a [`System`]: built by the static constructors.
#[pyclass(module = "gpm._gpm", frozen, from_py_object)]
#[derive(Clone, Debug)]
struct Boundary {
    kind: BoundaryKind,
}

#[derive(Clone, Debug)]
enum BoundaryKind {
    None,
    Periodic { lo: Vec<f64>, hi: Vec<f64> },
    ClosedBox { lo: Vec<f64>, hi: Vec<f64> },
    Channel { lo: Vec<f64>, hi: Vec<f64> },
    Cavity { dim: usize, side: f64, lid: f64 },
}

#[pymethods]
impl Boundary {
    /// No boundary: free space (the caller handles what surrounds the particles).
    #[staticmethod]
    fn none() -> Self {
        Boundary {
            kind: BoundaryKind::None,
        }
    }
    /// Every axis periodic on the box `[lo, hi)`.
    #[staticmethod]
    fn periodic(lo: Vec<f64>, hi: Vec<f64>) -> PyResult<Self> {
        let lo = read_point("lo", &lo, lo.len())?;
        let hi = read_point("hi", &hi, lo.len())?;
        Ok(Boundary {
            kind: BoundaryKind::Periodic { lo, hi },
        })
    }
    /// Stationary walls on every face of the box `[lo, hi]` (mirror ghosts, no-slip).
    #[staticmethod]
    fn closed_box(lo: Vec<f64>, hi: Vec<f64>) -> PyResult<Self> {
        let hi = read_point("hi", &hi, lo.len())?;
        Ok(Boundary {
            kind: BoundaryKind::ClosedBox { lo, hi },
        })
    }
    /// Walls at the lowest and highest value of the last axis, periodic along the others.
    #[staticmethod]
    fn channel(lo: Vec<f64>, hi: Vec<f64>) -> PyResult<Self> {
        let hi = read_point("hi", &hi, lo.len())?;
        Ok(Boundary {
            kind: BoundaryKind::Channel { lo, hi },
        })
    }
    /// The lid-driven cavity `[0, side]^dim`, the top wall moving with speed `lid` along x.
    #[staticmethod]
    #[pyo3(signature = (side = 1.0, lid = 1.0, dim = 2))]
    fn cavity(side: f64, lid: f64, dim: usize) -> Self {
        Boundary {
            kind: BoundaryKind::Cavity { dim, side, lid },
        }
    }
    /// The dimension the boundary is made for (`None` for `Boundary.none()`).
    #[getter]
    fn dim(&self) -> Option<usize> {
        match &self.kind {
            BoundaryKind::None => None,
            BoundaryKind::Periodic { lo, .. }
            | BoundaryKind::ClosedBox { lo, .. }
            | BoundaryKind::Channel { lo, .. } => Some(lo.len()),
            BoundaryKind::Cavity { dim, .. } => Some(*dim),
        }
    }
    fn __repr__(&self) -> String {
        format!("gpm.Boundary({:?})", self.kind)
    }
}

/// A boundary of dimension `D`.
enum Bnd<const D: usize> {
    None(NoBoundary),
    Periodic(PeriodicBox<D>),
    Walls(Walls<D>),
}

impl<const D: usize> Bnd<D> {
    fn new(b: &BoundaryKind) -> PyResult<Self> {
        let arr = |name: &str, v: &[f64]| -> PyResult<[f64; D]> {
            <[f64; D]>::try_from(v).map_err(|_| {
                arg_error(
                    &format!("boundary.{name}"),
                    format!(
                        "a {}-dimensional boundary for {D}-dimensional particles",
                        v.len()
                    ),
                )
            })
        };
        Ok(match b {
            BoundaryKind::None => Bnd::None(NoBoundary),
            BoundaryKind::Periodic { lo, hi } => {
                let (lo, hi) = (arr("lo", lo)?, arr("hi", hi)?);
                Bnd::Periodic(PeriodicBox {
                    periodic: Periodicity::all(lo, std::array::from_fn(|k| hi[k] - lo[k])),
                })
            }
            BoundaryKind::ClosedBox { lo, hi } => {
                Bnd::Walls(Walls::closed_box(arr("lo", lo)?, arr("hi", hi)?))
            }
            BoundaryKind::Channel { lo, hi } => {
                Bnd::Walls(Walls::channel(arr("lo", lo)?, arr("hi", hi)?))
            }
            BoundaryKind::Cavity { dim, side, lid } => {
                if *dim != D {
                    return Err(arg_error(
                        "boundary",
                        format!("a {dim}-dimensional cavity for {D}-dimensional particles"),
                    ));
                }
                Bnd::Walls(Walls::cavity(*side, *lid))
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

// ---------------------------------------------------------------------------------------------
// the system

/// One dimension's state.
struct Inner<const D: usize> {
    particles: Particles<D>,
    /// The caller's particles (fluid and Dirichlet); ghosts, if any, follow them.
    n_user: usize,
    nl: NeighborList<D>,
    boundary: Bnd<D>,
    params: ProjectionParams<D>,
    step: ProjectionStep<D>,
    volumes: VolumeRule,
}

enum Dim {
    D2(Box<Inner<2>>),
    D3(Box<Inner<3>>),
}

/// Runs `$body` with `$s` bound to the dimension's `Inner<D>` and `D` as a const.
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

/// Everything `System(...)` takes besides the arrays.
struct Settings {
    h: f64,
    skin: f64,
    weight: Weight,
    boundary: BoundaryKind,
    volumes: VolumeRule,
    nu: f64,
    rho: f64,
    scheme: Scheme,
    viscous_theta: f64,
    gravity: Option<Vec<f64>>,
    allowed_floating: usize,
    solve: SolveParams,
}

impl<const D: usize> Inner<D> {
    #[allow(clippy::too_many_arguments)]
    fn new(
        x: &[[f64; D]],
        u: &[[f64; D]],
        p: Option<Vec<f64>>,
        vol: Option<Vec<f64>>,
        dirichlet: Option<Vec<bool>>,
        s: &Settings,
    ) -> PyResult<Self> {
        let n = x.len();
        let boundary = Bnd::<D>::new(&s.boundary)?;
        let mut particles = Particles::<D>::new();
        particles.x = x.to_vec();
        particles.u = u.to_vec();
        particles.p = p.unwrap_or_else(|| vec![0.0; n]);
        let fixed = vol.is_some();
        particles.vol = vol.unwrap_or_else(|| vec![1.0; n]);
        particles.role = match dirichlet {
            Some(d) => d
                .iter()
                .map(|&b| if b { Role::Dirichlet } else { Role::Fluid })
                .collect(),
            None => vec![Role::Fluid; n],
        };
        if s.volumes == VolumeRule::Fixed && !fixed {
            return Err(arg_error(
                "vol",
                "volumes='fixed' needs the volumes (vol=...)".into(),
            ));
        }
        let mut params = ProjectionParams::<D>::new(s.nu);
        params.rho = s.rho;
        params.scheme = s.scheme;
        params.viscous_theta = s.viscous_theta;
        params.allowed_floating = s.allowed_floating;
        params.solve = s.solve;
        if let Some(g) = &s.gravity {
            params.gravity = <[f64; D]>::try_from(g.as_slice()).map_err(|_| {
                arg_error(
                    "gravity",
                    format!("expected {D} components, got {}", g.len()),
                )
            })?;
        }
        params.validate().py()?;
        let config = NeighborConfig::new(s.weight, s.h, s.skin);
        let nl = gpm::setup::prepare(&mut particles, boundary.get(), config, s.volumes).py()?;
        Ok(Inner {
            particles,
            n_user: n,
            nl,
            boundary,
            params,
            step: ProjectionStep::new(),
            volumes: s.volumes,
        })
    }

    fn update_neighbors(&mut self) -> Result<bool, Error> {
        gpm::setup::update(
            &mut self.particles,
            self.boundary.get(),
            &mut self.nl,
            self.volumes,
        )
    }

    fn predict(&mut self, dt: f64, accel: Option<&[[f64; D]]>) -> Result<Vec<[f64; D]>, Error> {
        let mut u_star = Vec::with_capacity(self.particles.len());
        self.step.predict(
            &mut self.particles,
            &self.nl,
            self.boundary.get(),
            &self.params,
            dt,
            accel,
            &mut u_star,
        )?;
        Ok(u_star)
    }

    fn project(&mut self, dt: f64, u_star: &[[f64; D]]) -> Result<StepReport, Error> {
        self.step.project(
            &mut self.particles,
            &self.nl,
            self.boundary.get(),
            &self.params,
            dt,
            u_star,
        )
    }

    fn step(&mut self, dt: f64, accel: Option<&[[f64; D]]>) -> Result<StepReport, Error> {
        self.step.step(
            &mut self.particles,
            &self.nl,
            self.boundary.get(),
            &self.params,
            dt,
            accel,
        )
    }

    fn user_rows(&self, v: &[[f64; D]]) -> Vec<[f64; D]> {
        v[..self.n_user].to_vec()
    }

    fn set_rows(field: &mut [[f64; D]], rows: &[[f64; D]]) {
        field[..rows.len()].copy_from_slice(rows);
    }

    fn record(
        &self,
        rec: &mut GpmRecorder,
        report: &StepReport,
        step: u64,
        time: f64,
    ) -> Result<(), Error> {
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

/// Particles, neighbour list, boundary and projection of a particle loop written in Python.
///
/// See the stub (`gpm/_gpm.pyi`) for the documentation of every method.
#[pyclass(module = "gpm._gpm")]
struct System {
    dim: Dim,
}

fn parse<T: std::str::FromStr<Err = String>>(name: &str, s: &str) -> PyResult<T> {
    s.parse::<T>().map_err(|e| arg_error(name, e))
}

#[pymethods]
impl System {
    #[new]
    #[pyo3(signature = (
        x, u, *, h, skin = 0.0, weight = "wendland2", boundary = None, p = None, vol = None,
        dirichlet = None, volumes = "number_density", nu = 0.0, rho = 1.0,
        scheme = "rotational", viscous_theta = 0.5, gravity = None, allowed_floating = 1,
        solve = None
    ))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        py: Python<'_>,
        x: &Bound<'_, PyAny>,
        u: &Bound<'_, PyAny>,
        h: f64,
        skin: f64,
        weight: &str,
        boundary: Option<Boundary>,
        p: Option<&Bound<'_, PyAny>>,
        vol: Option<&Bound<'_, PyAny>>,
        dirichlet: Option<Vec<bool>>,
        volumes: &str,
        nu: f64,
        rho: f64,
        scheme: &str,
        viscous_theta: f64,
        gravity: Option<Vec<f64>>,
        allowed_floating: usize,
        solve: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<Self> {
        let dim = {
            let shape: Vec<usize> = py
                .import("numpy")?
                .call_method1("shape", (x,))?
                .extract()
                .map_err(|e| arg_error("x", format!("expected an array of positions: {e}")))?;
            match shape.as_slice() {
                [_, d @ (2 | 3)] => *d,
                _ => {
                    return Err(arg_error(
                        "x",
                        format!("expected an array of shape (n, 2) or (n, 3), got {shape:?}"),
                    ))
                }
            }
        };
        let volumes = match volumes
            .trim()
            .to_ascii_lowercase()
            .replace('-', "_")
            .as_str()
        {
            "number_density" => VolumeRule::NumberDensity,
            "fixed" => VolumeRule::Fixed,
            other => {
                return Err(arg_error(
                    "volumes",
                    format!("unknown volume rule '{other}': expected number_density or fixed"),
                ))
            }
        };
        let solve = match solve {
            None => SolveParams::default(),
            Some(s) => {
                let text = config_text(py, "solve", Some(s))?;
                gpm::scene::config_from_json::<SolveParams>(&text)
                    .map_err(|e| match e {
                        InputError::Config { key, reason } => InputError::Config {
                            key: format!("solve.{key}"),
                            reason,
                        },
                        e => e,
                    })
                    .py()?
            }
        };
        let settings = Settings {
            h,
            skin,
            weight: parse("weight", weight)?,
            boundary: boundary.map_or(BoundaryKind::None, |b| b.kind),
            volumes,
            nu,
            rho,
            scheme: parse("scheme", scheme)?,
            viscous_theta,
            gravity,
            allowed_floating,
            solve,
        };
        let xa = read_rows(py, "x", x, dim, None)?;
        let n = xa.shape()[0];
        let ua = read_rows(py, "u", u, dim, Some(n))?;
        let p = p.map(|p| read_vec(py, "p", p, n)).transpose()?;
        let vol = vol.map(|v| read_vec(py, "vol", v, n)).transpose()?;
        if let Some(d) = &dirichlet {
            if d.len() != n {
                return Err(arg_error(
                    "dirichlet",
                    format!("expected {n} flags, got {}", d.len()),
                ));
            }
        }
        let dim = match dim {
            2 => Dim::D2(Box::new(Inner::new(
                as_rows::<2>(&xa),
                as_rows::<2>(&ua),
                p,
                vol,
                dirichlet,
                &settings,
            )?)),
            _ => Dim::D3(Box::new(Inner::new(
                as_rows::<3>(&xa),
                as_rows::<3>(&ua),
                p,
                vol,
                dirichlet,
                &settings,
            )?)),
        };
        Ok(System { dim })
    }

    /// Spatial dimension (2 or 3).
    #[getter]
    fn dim(&self) -> usize {
        match self.dim {
            Dim::D2(_) => 2,
            Dim::D3(_) => 3,
        }
    }

    fn __len__(&self) -> usize {
        with_dim!(&self.dim, s, s.n_user)
    }

    /// Ghost particles currently held (mirror images across walls).
    #[getter]
    fn n_ghosts(&self) -> usize {
        with_dim!(&self.dim, s, s.particles.len() - s.n_user)
    }

    /// Influence radius h.
    #[getter]
    fn h(&self) -> f64 {
        with_dim!(&self.dim, s, s.nl.h())
    }

    /// Stored neighbour pairs (each unordered pair twice).
    #[getter]
    fn n_pairs(&self) -> usize {
        with_dim!(&self.dim, s, s.nl.n_pairs())
    }

    /// Times the neighbour candidates were searched.
    #[getter]
    fn rebuilds(&self) -> u64 {
        with_dim!(&self.dim, s, s.nl.rebuilds())
    }

    #[getter]
    fn get_x<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        with_dim!(&self.dim, s, {
            let v = s.user_rows(&s.particles.x);
            to_numpy::<D>(py, v, s.n_user)
        })
    }

    #[setter]
    fn set_x(&mut self, py: Python<'_>, value: &Bound<'_, PyAny>) -> PyResult<()> {
        let dim = self.dim();
        with_dim!(&mut self.dim, s, {
            let a = read_rows(py, "x", value, dim, Some(s.n_user))?;
            Inner::<D>::set_rows(&mut s.particles.x, as_rows::<D>(&a));
            Ok(())
        })
    }

    #[getter]
    fn get_u<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        with_dim!(&self.dim, s, {
            let v = s.user_rows(&s.particles.u);
            to_numpy::<D>(py, v, s.n_user)
        })
    }

    #[setter]
    fn set_u(&mut self, py: Python<'_>, value: &Bound<'_, PyAny>) -> PyResult<()> {
        let dim = self.dim();
        with_dim!(&mut self.dim, s, {
            let a = read_rows(py, "u", value, dim, Some(s.n_user))?;
            Inner::<D>::set_rows(&mut s.particles.u, as_rows::<D>(&a));
            Ok(())
        })
    }

    #[getter]
    fn get_p<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        with_dim!(&self.dim, s, {
            PyArray1::from_slice(py, &s.particles.p[..s.n_user])
        })
    }

    #[setter]
    fn set_p(&mut self, py: Python<'_>, value: &Bound<'_, PyAny>) -> PyResult<()> {
        with_dim!(&mut self.dim, s, {
            let v = read_vec(py, "p", value, s.n_user)?;
            s.particles.p[..s.n_user].copy_from_slice(&v);
            Ok(())
        })
    }

    #[getter]
    fn get_vol<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        with_dim!(&self.dim, s, {
            PyArray1::from_slice(py, &s.particles.vol[..s.n_user])
        })
    }

    #[setter]
    fn set_vol(&mut self, py: Python<'_>, value: &Bound<'_, PyAny>) -> PyResult<()> {
        with_dim!(&mut self.dim, s, {
            let v = read_vec(py, "vol", value, s.n_user)?;
            s.particles.vol[..s.n_user].copy_from_slice(&v);
            Ok(())
        })
    }

    /// When true, `project` keeps its inputs and outputs, so that `Recorder.record` can write
    /// a re-runnable `/projection_input`.
    #[getter]
    fn get_capture(&self) -> bool {
        with_dim!(&self.dim, s, s.step.capture)
    }

    #[setter]
    fn set_capture(&mut self, on: bool) {
        with_dim!(&mut self.dim, s, s.step.capture = on)
    }

    fn update_neighbors(&mut self, py: Python<'_>) -> PyResult<bool> {
        with_dim!(&mut self.dim, s, {
            let s: &mut Inner<D> = s;
            py.detach(|| s.update_neighbors()).py()
        })
    }

    #[pyo3(signature = (dt, accel = None))]
    fn predict<'py>(
        &mut self,
        py: Python<'py>,
        dt: f64,
        accel: Option<&Bound<'py, PyAny>>,
    ) -> PyResult<Bound<'py, PyAny>> {
        let dim = self.dim();
        with_dim!(&mut self.dim, s, {
            let s: &mut Inner<D> = s;
            let n = s.n_user;
            let acc = accel
                .filter(|a| !a.is_none())
                .map(|a| read_rows(py, "accel", a, dim, Some(n)))
                .transpose()?;
            let acc_rows = acc.as_ref().map(as_rows::<D>);
            let u_star = py.detach(|| s.predict(dt, acc_rows)).py()?;
            to_numpy::<D>(py, u_star, n)
        })
    }

    fn project(
        &mut self,
        py: Python<'_>,
        dt: f64,
        u_star: &Bound<'_, PyAny>,
    ) -> PyResult<PyStepReport> {
        let dim = self.dim();
        with_dim!(&mut self.dim, s, {
            let s: &mut Inner<D> = s;
            let a = read_rows(py, "u_star", u_star, dim, Some(s.n_user))?;
            let rows = as_rows::<D>(&a);
            let report = py.detach(|| s.project(dt, rows)).py()?;
            Ok(PyStepReport { report })
        })
    }

    #[pyo3(signature = (dt, accel = None))]
    fn step(
        &mut self,
        py: Python<'_>,
        dt: f64,
        accel: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<PyStepReport> {
        let dim = self.dim();
        with_dim!(&mut self.dim, s, {
            let s: &mut Inner<D> = s;
            let acc = accel
                .filter(|a| !a.is_none())
                .map(|a| read_rows(py, "accel", a, dim, Some(s.n_user)))
                .transpose()?;
            let acc_rows = acc.as_ref().map(as_rows::<D>);
            let report = py.detach(|| s.step(dt, acc_rows)).py()?;
            Ok(PyStepReport { report })
        })
    }

    fn reset_pressure(&mut self) {
        with_dim!(&mut self.dim, s, {
            let s: &mut Inner<D> = s;
            s.step.reset_pressure(&mut s.particles)
        })
    }

    /// Maps positions into the periodic box in place (`x` an `(n, dim)` float64 array), as
    /// gpm's own loop does; no-op for a boundary without periodic axes.
    fn wrap(&self, py: Python<'_>, x: &Bound<'_, PyAny>) -> PyResult<()> {
        let dim = self.dim();
        let arr = x
            .extract::<numpy::PyReadwriteArray2<'_, f64>>()
            .map_err(|_| arg_error("x", format!("expected a float64 array of shape (n, {dim})")))?;
        let mut arr = arr;
        if arr.shape()[1] != dim {
            return Err(arg_error(
                "x",
                format!("expected shape (n, {dim}), got {:?}", arr.shape()),
            ));
        }
        let _ = py;
        with_dim!(&self.dim, s, {
            let per = s.boundary.get().periodicity();
            let mut view = arr.as_array_mut();
            for mut row in view.rows_mut() {
                let mut p: [f64; D] = std::array::from_fn(|k| row[k]);
                per.wrap(&mut p);
                for k in 0..D {
                    row[k] = p[k];
                }
            }
            Ok(())
        })
    }

    fn __repr__(&self) -> String {
        with_dim!(&self.dim, s, {
            format!(
                "gpm.System(dim={}, particles={}, ghosts={}, h={})",
                D,
                s.n_user,
                s.particles.len() - s.n_user,
                s.nl.h()
            )
        })
    }
}

// ---------------------------------------------------------------------------------------------
// the report

/// What one projection step did and measured (gpm's `StepReport`).
#[pyclass(module = "gpm._gpm", name = "StepReport", frozen)]
#[derive(Clone)]
struct PyStepReport {
    report: StepReport,
}

#[pymethods]
impl PyStepReport {
    #[getter]
    fn dt(&self) -> f64 {
        self.report.dt
    }
    #[getter]
    fn c0(&self) -> f64 {
        self.report.c0
    }
    #[getter]
    fn min_spacing(&self) -> f64 {
        self.report.min_spacing
    }
    #[getter]
    fn stability_ratio(&self) -> f64 {
        self.report.stability_ratio
    }
    #[getter]
    fn div_before(&self) -> f64 {
        self.report.div_before
    }
    #[getter]
    fn div_after(&self) -> f64 {
        self.report.div_after
    }
    #[getter]
    fn correction_ratio(&self) -> f64 {
        self.report.correction_ratio
    }
    #[getter]
    fn kinetic_energy(&self) -> f64 {
        self.report.kinetic_energy
    }
    #[getter]
    fn max_speed(&self) -> f64 {
        self.report.max_speed
    }
    #[getter]
    fn connectivity(&self, py: Python<'_>) -> PyResult<Py<PyAny>> {
        json_to_py(py, &to_json_value(&self.report.connectivity))
    }
    #[getter]
    fn solve(&self, py: Python<'_>) -> PyResult<Py<PyAny>> {
        json_to_py(py, &to_json_value(&self.report.solve))
    }
    #[getter]
    fn viscous(&self, py: Python<'_>) -> PyResult<Py<PyAny>> {
        match &self.report.viscous {
            Some(v) => json_to_py(py, &to_json_value(v)),
            None => Ok(py.None()),
        }
    }
    #[getter]
    fn timings(&self, py: Python<'_>) -> PyResult<Py<PyAny>> {
        json_to_py(py, &to_json_value(&self.report.timings))
    }
    fn to_dict(&self, py: Python<'_>) -> PyResult<Py<PyAny>> {
        json_to_py(py, &to_json_value(&self.report))
    }
    fn __repr__(&self) -> String {
        let r = &self.report;
        format!(
            "gpm.StepReport(div_before={:e}, div_after={:e}, c0={}, stability_ratio={:e}, \
             kinetic_energy={}, floating={})",
            r.div_before,
            r.div_after,
            r.c0,
            r.stability_ratio,
            r.kinetic_energy,
            r.connectivity.floating
        )
    }
}

// ---------------------------------------------------------------------------------------------
// recording

/// An MCAP recording of a loop of the caller's own (gpm's `Recorder::record`).
#[pyclass(module = "gpm._gpm")]
struct Recorder {
    inner: Option<GpmRecorder>,
    path: PathBuf,
}

#[pymethods]
impl Recorder {
    #[new]
    #[pyo3(signature = (path, level = "diagnostics", every = 1, config = None))]
    fn new(
        py: Python<'_>,
        path: PathBuf,
        level: &str,
        every: u64,
        config: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<Self> {
        let level: RecordLevel = parse("level", level)?;
        if every == 0 {
            return Err(param_error(
                "every",
                0.0,
                "snapshots every 0 steps: give at least 1",
            ));
        }
        let text = config_text(py, "config", config)?;
        let value: serde_json::Value = if config.is_none_or(|c| c.is_none()) {
            serde_json::Value::Null
        } else {
            gpm::scene::strict_json(&text).py()?
        };
        let rec =
            GpmRecorder::create_with(&path, RecorderOptions::new(level, every), &value).py()?;
        Ok(Recorder {
            inner: Some(rec),
            path,
        })
    }

    /// Whether step `step` gets a particle snapshot (level "full", steps 1, k+1, 2k+1, …).
    fn wants_snapshot(&self, step: u64) -> bool {
        self.inner.as_ref().is_some_and(|r| r.wants_snapshot(step))
    }

    fn record(
        &mut self,
        system: PyRef<'_, System>,
        report: PyRef<'_, PyStepReport>,
        step: u64,
        time: f64,
    ) -> PyResult<()> {
        let rec = self.inner.as_mut().ok_or_else(|| {
            to_py_err(Error::Record(gpm::error::RecordError::Spec {
                what: "recorder",
                reason: "the recording is already finished".into(),
            }))
        })?;
        if step == 0 {
            return Err(param_error("step", 0.0, "steps are numbered from 1"));
        }
        with_dim!(&system.dim, s, s.record(rec, &report.report, step, time)).py()
    }

    /// Writes the summary and footer, renames `path.partial` to `path`, and returns what was
    /// written (`steps`, `messages`, `bytes`, `path`, …).
    fn finish(&mut self, py: Python<'_>) -> PyResult<Py<PyAny>> {
        let rec = self.inner.take().ok_or_else(|| {
            to_py_err(Error::Record(gpm::error::RecordError::Spec {
                what: "recorder",
                reason: "the recording is already finished".into(),
            }))
        })?;
        let summary = rec.finish().py()?;
        json_to_py(py, &to_json_value(&summary))
    }

    #[getter]
    fn path(&self) -> PathBuf {
        self.path.clone()
    }

    fn __enter__(slf: Py<Self>) -> Py<Self> {
        slf
    }

    /// Leaving a `with` block finishes the file; when the block raised, the file is kept as
    /// `run.failed.mcap` (gpm's `finish_failed`) and the exception propagates.
    #[pyo3(signature = (exc_type, _exc, _tb))]
    fn __exit__(
        &mut self,
        exc_type: &Bound<'_, PyAny>,
        _exc: &Bound<'_, PyAny>,
        _tb: &Bound<'_, PyAny>,
    ) -> PyResult<bool> {
        if let Some(rec) = self.inner.take() {
            if exc_type.is_none() {
                rec.finish().py()?;
            } else {
                rec.finish_failed().py()?;
            }
        }
        Ok(false)
    }
}

// ---------------------------------------------------------------------------------------------
// scenes

struct RunScene {
    config: String,
    record: Option<(PathBuf, RecordLevel, u64)>,
}

/// What a scene run returns to Python (JSON, converted with the GIL held).
struct SceneOutput {
    name: &'static str,
    summary: serde_json::Value,
    result: serde_json::Value,
    tables: Vec<(String, String)>,
    steps: u64,
    end: serde_json::Value,
    record: Option<serde_json::Value>,
    interrupted: Option<PyErr>,
}

impl SceneVisitor for RunScene {
    type Output = Result<SceneOutput, Error>;
    fn visit<const D: usize, S: Scene<D>>(self) -> Self::Output {
        let cfg = gpm::scene::scene_config_from_json::<S>(&self.config)?;
        cfg.validate()?;
        let mut interrupted = None;
        let mut steps = 0u64;
        let observer = |rep: &gpm::flow::FlowReport, _: &_| {
            steps = rep.step;
            // Ctrl-C in the interpreter stops the run after this step
            match Python::attach(|py| py.check_signals()) {
                Ok(()) => Ok(ControlFlow::Continue(())),
                Err(e) => {
                    interrupted = Some(e);
                    Ok(ControlFlow::Break(()))
                }
            }
        };
        let (run, record) = match &self.record {
            None => (gpm::scene::run_scene(&cfg, |_| {}, observer)?, None),
            Some((path, level, every)) => {
                let rr = gpm::scene::run_recorded(
                    &cfg,
                    path,
                    RecorderOptions::new(*level, *every),
                    &cfg.record_header(),
                    |_| {},
                    observer,
                )?;
                let summary = rr.record?;
                (rr.run?, Some(to_json_value(&summary)))
            }
        };
        Ok(SceneOutput {
            name: S::NAME,
            summary: to_json_value(&run.summary(&cfg)),
            result: to_json_value(&run.result),
            tables: S::tables(&cfg, &run.result)
                .into_iter()
                .map(|t| (t.name, t.text))
                .collect(),
            steps,
            end: to_json_value(&run.end),
            record,
            interrupted,
        })
    }
}

/// Runs a registered scene (`gpm.SCENES`) with a configuration (dict, JSON text or None for
/// the defaults; the keys of `gpm run <scene> --config`).
#[pyfunction]
#[pyo3(signature = (name, config = None, *, record = None, level = "diagnostics", every = 10))]
fn run_scene(
    py: Python<'_>,
    name: &str,
    config: Option<&Bound<'_, PyAny>>,
    record: Option<PathBuf>,
    level: &str,
    every: u64,
) -> PyResult<Py<PyAny>> {
    let config = config_text(py, "config", config)?;
    let level: RecordLevel = parse("level", level)?;
    let visitor = RunScene {
        config,
        record: record.map(|p| (p, level, every.max(1))),
    };
    let out = py
        .detach(|| gpm::scene::visit_scene(name, visitor).map_err(Error::from))
        .py()?
        .py()?;
    if let Some(e) = out.interrupted {
        return Err(e);
    }
    let d = PyDict::new(py);
    d.set_item("scene", out.name)?;
    d.set_item("summary", json_to_py(py, &out.summary)?)?;
    d.set_item("result", json_to_py(py, &out.result)?)?;
    let tables = PyDict::new(py);
    for (name, text) in out.tables {
        tables.set_item(name, text)?;
    }
    d.set_item("tables", tables)?;
    d.set_item("steps", out.steps)?;
    d.set_item("end", json_to_py(py, &out.end)?)?;
    d.set_item(
        "record",
        match &out.record {
            Some(r) => json_to_py(py, r)?,
            None => py.None(),
        },
    )?;
    Ok(d.into_any().unbind())
}

/// The cell-centred lattice of spacing `dx` in the box `[lo, hi]` (gpm's `lattice`).
#[pyfunction]
fn lattice<'py>(
    py: Python<'py>,
    lo: Vec<f64>,
    hi: Vec<f64>,
    dx: f64,
) -> PyResult<Bound<'py, PyAny>> {
    if !(dx > 0.0 && dx.is_finite()) {
        return Err(param_error(
            "dx",
            dx,
            "the spacing must be positive and finite",
        ));
    }
    let hi = read_point("hi", &hi, lo.len())?;
    match lo.len() {
        2 => {
            let v = gpm::geometry::lattice([lo[0], lo[1]], [hi[0], hi[1]], dx);
            let n = v.len();
            to_numpy::<2>(py, v, n)
        }
        3 => {
            let v = gpm::geometry::lattice([lo[0], lo[1], lo[2]], [hi[0], hi[1], hi[2]], dx);
            let n = v.len();
            to_numpy::<3>(py, v, n)
        }
        d => Err(arg_error("lo", format!("2 or 3 coordinates, got {d}"))),
    }
}

/// The loop of `examples/own_loop.rs` (and `examples/own_loop.py`) run entirely in Rust, for
/// `examples/bench_overhead.py`: the same particles, forces, advection and calls, no recording.
/// Returns the wall seconds of each step and the kinetic energy after each step (so that the
/// benchmark can check that both loops did the same work).
#[pyfunction]
fn _rust_own_loop(
    py: Python<'_>,
    n: usize,
    steps: usize,
    dt: f64,
    drag: f64,
) -> PyResult<(Vec<f64>, Vec<f64>)> {
    use gpm::geometry::number_density_volumes;
    use std::f64::consts::PI;
    py.detach(|| -> Result<(Vec<f64>, Vec<f64>), Error> {
        let dx = 1.0 / n as f64;
        let periodic = Periodicity::all([0.0, 0.0], [1.0, 1.0]);
        let boundary = PeriodicBox { periodic };
        let mut particles = Particles::<2>::new();
        for x in gpm::geometry::lattice([0.0, 0.0], [1.0, 1.0], dx) {
            let (s2x, c2x) = (2.0 * PI * x[0]).sin_cos();
            let (s2y, c2y) = (2.0 * PI * x[1]).sin_cos();
            particles.push(x, [-c2x * s2y, s2x * c2y], 0.0, dx * dx, Role::Fluid);
        }
        let mut nl = NeighborList::build(
            NeighborConfig::new_relative(Weight::WendlandC2, dx, 3.0, 0.3)
                .with_periodicity(periodic),
            &particles.x,
        )?;
        let mut params = ProjectionParams::<2>::new(0.01);
        params.scheme = Scheme::Incremental;
        let mut step = ProjectionStep::<2>::new();
        let mut u_star = Vec::new();
        let (mut seconds, mut energy) = (Vec::new(), Vec::new());
        for _ in 0..steps {
            let t = std::time::Instant::now();
            nl.update(&particles.x)?;
            particles.vol = number_density_volumes(&nl);
            let forces: Vec<[f64; 2]> = particles
                .u
                .iter()
                .map(|u| [-drag * u[0], -drag * u[1]])
                .collect();
            step.predict(
                &mut particles,
                &nl,
                &boundary,
                &params,
                dt,
                Some(&forces),
                &mut u_star,
            )?;
            for (x, u) in particles.x.iter_mut().zip(&u_star) {
                x[0] += dt * u[0];
                x[1] += dt * u[1];
                periodic.wrap(x);
            }
            nl.update(&particles.x)?;
            particles.vol = number_density_volumes(&nl);
            let report = step.project(&mut particles, &nl, &boundary, &params, dt, &u_star)?;
            seconds.push(t.elapsed().as_secs_f64());
            energy.push(report.kinetic_energy);
        }
        Ok((seconds, energy))
    })
    .py()
}

#[pymodule]
fn _gpm(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<System>()?;
    m.add_class::<Boundary>()?;
    m.add_class::<PyStepReport>()?;
    m.add_class::<Recorder>()?;
    m.add_function(wrap_pyfunction!(run_scene, m)?)?;
    m.add_function(wrap_pyfunction!(lattice, m)?)?;
    m.add_function(wrap_pyfunction!(_rust_own_loop, m)?)?;
    m.add("SCENES", gpm::scene::SCENES.to_vec())?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    Ok(())
}
