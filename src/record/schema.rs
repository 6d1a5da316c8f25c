//! The messages of a gpm MCAP log: serde types whose JSON Schemas, stored in the file (MCAP
//! schema encoding `jsonschema`, message encoding `json`), are derived from the types themselves.
//!
//! | topic | schema name | type | when |
//! | --- | --- | --- | --- |
//! | `/config` | `gpm.RunConfig` | [`RunConfig`] | once, first message |
//! | `/diagnostics` | `gpm.StepDiagnostics` | [`StepDiagnostics`] | every step |
//! | `/particles` | `foxglove.PointCloud` | [`PointCloud`] | every `k` steps (level `full`) |
//! | `/projection_input` | `gpm.ProjectionInput` | [`ProjectionInput`] | every `k` steps (level `full`) |
//!
//! Floating-point values that are not finite (a diverging run) are written as JSON `null` and
//! read back as NaN; their schemas say `"type": ["number", "null"]`. Bulk arrays (particle
//! positions, velocities, …) are [`Array`]s: little-endian bytes in standard base64 with a
//! numpy-style `dtype` and a `shape`, so they are exact (bit for bit) and cheap to write; in
//! Python `numpy.frombuffer(base64.b64decode(a["data"]), a["dtype"]).reshape(a["shape"])`.
//!
//! **Where the schemas come from.** The gpm messages derive [`schemars::JsonSchema`]: property
//! names, types, enum values and descriptions (the doc comments) follow the serde types by
//! construction, so a type and its schema cannot drift apart. [`message_schema`] then makes
//! every property required and forbids others (the writer always writes every field). The
//! crate's enums that the messages embed (`DtLimit`, `SolverKind`, …) get their schemas here,
//! with the values taken from their serde names and an exhaustive `match` that stops the build
//! when a variant is added; [`SolveParams`]'s schema is read from the JSON of its default value.
//! Only `foxglove.PointCloud` is written out by hand: it is Foxglove's published schema, which
//! Foxglove Studio recognises by name.

use super::RecordError;
use crate::boundary::{Boundary, NoBoundary, PeriodicBox, VectorKind, Wall, Walls};
use crate::consistent::{GradientKind, LaplacianKind};
use crate::flow::{DtLimit, FlowReport};
use crate::kernel::Weight;
use crate::neighbors::{NeighborConfig, Periodicity};
use crate::particles::Role;
use crate::poisson::{AmgSetup, SolveInfo, SolveParams, SolverKind};
use crate::projection::{Disconnected, SourceKind};
use crate::projection::{ProjectionParams, Scheme, StepReport};
use base64::Engine as _;
use schemars::{json_schema, JsonSchema, Schema, SchemaGenerator};
use serde::{Deserialize, Deserializer, Serialize};
use serde_json::{json, Value};
use std::borrow::Cow;

/// Version of the message layout below; bumped on any incompatible change.
pub const FORMAT_VERSION: u32 = 1;

/// Topic of [`RunConfig`].
pub const TOPIC_CONFIG: &str = "/config";
/// Topic of [`StepDiagnostics`].
pub const TOPIC_DIAGNOSTICS: &str = "/diagnostics";
/// Topic of the particle snapshots ([`PointCloud`]).
pub const TOPIC_PARTICLES: &str = "/particles";
/// Topic of [`ProjectionInput`].
pub const TOPIC_PROJECTION: &str = "/projection_input";

/// Schema name of [`RunConfig`].
pub const SCHEMA_CONFIG: &str = "gpm.RunConfig";
/// Schema name of [`StepDiagnostics`].
pub const SCHEMA_DIAGNOSTICS: &str = "gpm.StepDiagnostics";
/// Schema name of [`PointCloud`] (Foxglove's, so Foxglove Studio's 3D panel shows it).
pub const SCHEMA_POINT_CLOUD: &str = "foxglove.PointCloud";
/// Schema name of [`ProjectionInput`].
pub const SCHEMA_PROJECTION: &str = "gpm.ProjectionInput";

/// Reads a number, or `null` as NaN (serde_json writes every non-finite `f64` as `null`).
fn nullable<'de, D: Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
    Ok(Option::<f64>::deserialize(d)?.unwrap_or(f64::NAN))
}

/// The value of a number absent from an older log.
fn nan() -> f64 {
    f64::NAN
}

// ---------------------------------------------------------------------------------------------
// Deriving the stored schemas

/// Every object schema lists all its properties as required and allows no other; the Rust
/// `format` annotations (`double`, `uint`, …), which no JSON Schema validator knows, are dropped.
fn strict(schema: &mut Schema) {
    let Some(obj) = schema.as_object_mut() else {
        return;
    };
    obj.remove("format");
    if let Some(Value::Object(props)) = obj.get("properties") {
        let required: Vec<Value> = props.keys().map(|k| json!(k)).collect();
        obj.insert("required".into(), Value::Array(required));
        obj.entry("additionalProperties").or_insert(json!(false));
    }
}

/// The JSON Schema (draft 2020-12) of message type `T`, titled with its schema name.
pub fn message_schema<T: JsonSchema>(title: &str) -> Value {
    let mut schema = schemars::generate::SchemaSettings::draft2020_12()
        .with_transform(schemars::transform::RecursiveTransform(strict))
        .into_generator()
        .into_root_schema_for::<T>();
    schema.insert("title".into(), json!(title));
    schema.to_value()
}

/// The schema of a unit-only enum from the serde names of its variants. The `match` is
/// exhaustive, so adding a variant stops the build here until it is listed.
macro_rules! unit_enum_schema {
    ($ty:ident, $description:literal, [$($v:ident),+ $(,)?]) => {
        impl JsonSchema for $ty {
            fn schema_name() -> Cow<'static, str> {
                stringify!($ty).into()
            }
            fn json_schema(_: &mut SchemaGenerator) -> Schema {
                const _: fn(&$ty) = |v| match v {
                    $($ty::$v)|+ => {}
                };
                let names: Vec<Value> = [$($ty::$v),+]
                    .iter()
                    .map(|v| serde_json::to_value(v).expect("a unit variant serialises"))
                    .collect();
                json_schema!({"type": "string", "enum": names, "description": $description})
            }
        }
    };
}

unit_enum_schema!(
    DtLimit,
    "limit that set the time step",
    [Cfl, Viscous, Force, Max, Fixed]
);
unit_enum_schema!(SolverKind, "linear solver", [Cholesky, Cg, Amg, Auto]);
unit_enum_schema!(
    AmgSetup,
    "what was done to the AMG hierarchy before the solve",
    [None, Reused, Lagged, Refreshed, Rebuilt]
);
unit_enum_schema!(
    Scheme,
    "pressure-correction scheme",
    [NonIncremental, Incremental, Rotational]
);
unit_enum_schema!(
    Disconnected,
    "policy for fluid cut off from the rest: fail, or float (each such component its own floating one)",
    [Fail, Float]
);
unit_enum_schema!(
    SourceKind,
    "divergence of the source: sum_form (∇̂h·), adjoint_bt (∇̂h·(Bᵀ·)) or renormalised (∇ᶜ·)",
    [SumForm, AdjointBt, Renormalised, LeastSquares]
);
unit_enum_schema!(
    GradientKind,
    "gradient of the predictor and the correction: difference (adjoint to the source) or renormalised",
    [Difference, Renormalised, LeastSquares]
);
unit_enum_schema!(
    LaplacianKind,
    "Laplacian of the viscous term: gpm (Δh) or least_squares (Δˡˢ)",
    [Gpm, LeastSquares]
);

impl JsonSchema for Weight {
    fn schema_name() -> Cow<'static, str> {
        "Weight".into()
    }
    fn json_schema(generator: &mut SchemaGenerator) -> Schema {
        const _: fn(&Weight) = |w| match w {
            Weight::CubicSpline | Weight::WendlandC2 | Weight::WendlandC4 | Weight::Poly { .. } => {
            }
        };
        let names: Vec<Value> = [Weight::CubicSpline, Weight::WendlandC2, Weight::WendlandC4]
            .iter()
            .map(|w| serde_json::to_value(w).expect("a unit variant serialises"))
            .collect();
        let power = generator.subschema_for::<u32>();
        json_schema!({
            "description": "reference weight: a named kernel or {\"poly\": {\"p\", \"m\"}} for r^p (1 - r)^m",
            "oneOf": [
                {"type": "string", "enum": names},
                {
                    "type": "object",
                    "properties": {"poly": {
                        "type": "object",
                        "properties": {"p": power.clone(), "m": power},
                    }},
                },
            ],
        })
    }
}

/// [`SolveParams`]' schema, read from the JSON of its default value so that it follows the
/// solver's options as they are added: each key typed by its default (boolean, non-negative
/// integer, number, or the solver name).
impl JsonSchema for SolveParams {
    fn schema_name() -> Cow<'static, str> {
        "SolveParams".into()
    }
    fn json_schema(generator: &mut SchemaGenerator) -> Schema {
        let default = serde_json::to_value(SolveParams::default()).expect("SolveParams serialises");
        let mut props = serde_json::Map::new();
        for (k, v) in default.as_object().expect("SolveParams is a struct") {
            let mut s = match v {
                _ if k == "solver" => generator.subschema_for::<SolverKind>(),
                Value::Bool(_) => generator.subschema_for::<bool>(),
                Value::Number(n) if n.is_u64() => generator.subschema_for::<u64>(),
                Value::Number(_) => generator.subschema_for::<f64>(),
                _ => Schema::default(),
            };
            if s.get("$ref").is_none() {
                s.insert(
                    "description".into(),
                    json!(format!("gpm::poisson::SolveParams::{k}")),
                );
            }
            props.insert(k.clone(), s.to_value());
        }
        json_schema!({
            "type": "object",
            "description": "gpm::poisson::SolveParams",
            "properties": props,
        })
    }
}
// ---------------------------------------------------------------------------------------------
// /diagnostics

/// Connectivity of the fluid graph at one step (Imoto 2019, Def. 3.1).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct ConnectivityDiagnostics {
    /// Components of the fluid neighbour graph.
    pub components: usize,
    /// Components touching a Dirichlet particle.
    pub anchored: usize,
    /// Floating (pure Neumann) components.
    pub floating: usize,
    /// Fluid particles without any neighbour.
    pub isolated: usize,
    /// Floating components the run allows (`ProjectionParams::allowed_floating`).
    pub allowed_floating: usize,
    /// `floating <= allowed_floating && isolated == 0`: the Poisson problem is uniquely solvable
    /// up to the fixed constants. A failing step stops the run before its solve, so a recorded
    /// step normally has `ok = true`.
    pub ok: bool,
}

/// The Poisson solve of one step.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct SolveDiagnostics {
    /// The solver that ran.
    pub solver: SolverKind,
    /// Unknowns.
    pub unknowns: usize,
    /// Stored entries of the matrix.
    pub nnz: usize,
    /// CG iterations (0 for Cholesky).
    pub iterations: usize,
    /// `‖ω∘b − K x‖₂`.
    #[serde(deserialize_with = "nullable")]
    #[schemars(with = "Option<f64>")]
    pub abs_residual: f64,
    /// `‖ω∘b − K x‖₂ / ‖ω∘b‖₂`.
    #[serde(deserialize_with = "nullable")]
    #[schemars(with = "Option<f64>")]
    pub rel_residual: f64,
    /// `‖ω∘b − K x₀‖₂ / ‖ω∘b‖₂` of the initial guess: how far the warm start was off (0 for a
    /// direct solve; absent in older logs: NaN).
    #[serde(default = "nan", deserialize_with = "nullable")]
    #[schemars(with = "Option<f64>")]
    pub initial_rel_residual: f64,
    /// The relative tolerance the iterative solve stopped at (the viscous solve's adapts,
    /// `SolveParams::viscous_adaptive`; 0 for a direct solve; absent in older logs: NaN).
    #[serde(default = "nan", deserialize_with = "nullable")]
    #[schemars(with = "Option<f64>")]
    pub rel_tol: f64,
    /// Largest relative compatibility defect of a floating component (discrete Gauss theorem).
    #[serde(deserialize_with = "nullable")]
    #[schemars(with = "Option<f64>")]
    pub compatibility_defect: f64,
    /// The matrix pattern was rebuilt.
    pub pattern_rebuilt: bool,
    /// Cholesky reused its symbolic analysis.
    pub reused_symbolic: bool,
    /// Cholesky reused its numeric factor.
    pub reused_numeric: bool,
    /// Seconds: assembly.
    #[serde(deserialize_with = "nullable")]
    #[schemars(with = "Option<f64>")]
    pub assemble_seconds: f64,
    /// Seconds: symbolic analysis.
    #[serde(deserialize_with = "nullable")]
    #[schemars(with = "Option<f64>")]
    pub symbolic_seconds: f64,
    /// Seconds: numeric factorisation.
    #[serde(deserialize_with = "nullable")]
    #[schemars(with = "Option<f64>")]
    pub numeric_seconds: f64,
    /// Seconds: triangular solves or CG iterations.
    #[serde(deserialize_with = "nullable")]
    #[schemars(with = "Option<f64>")]
    pub iterate_seconds: f64,
    /// AMG: what was done to the hierarchy before the solve (absent in older logs: `none`).
    #[serde(default)]
    pub amg_setup: AmgSetup,
    /// AMG: levels of the hierarchy (0 without AMG).
    #[serde(default)]
    pub amg_levels: usize,
    /// AMG: operator complexity (0 without AMG).
    #[serde(default, deserialize_with = "nullable")]
    #[schemars(with = "Option<f64>")]
    pub amg_operator_complexity: f64,
    /// Seconds: AMG setup (rebuild or refresh) in this solve.
    #[serde(default, deserialize_with = "nullable")]
    #[schemars(with = "Option<f64>")]
    pub amg_setup_seconds: f64,
}

impl From<&SolveInfo> for SolveDiagnostics {
    fn from(s: &SolveInfo) -> Self {
        SolveDiagnostics {
            solver: s.solver,
            unknowns: s.unknowns,
            nnz: s.nnz,
            iterations: s.iters,
            abs_residual: s.abs_residual,
            rel_residual: s.rel_residual,
            initial_rel_residual: s.initial_rel_residual,
            rel_tol: s.rel_tol,
            compatibility_defect: s.compatibility_defect,
            pattern_rebuilt: s.pattern_rebuilt,
            reused_symbolic: s.reused_symbolic,
            reused_numeric: s.reused_numeric,
            assemble_seconds: s.assemble_seconds,
            symbolic_seconds: s.symbolic_seconds,
            numeric_seconds: s.numeric_seconds,
            iterate_seconds: s.solve_seconds,
            amg_setup: s.amg_setup,
            amg_levels: s.amg_levels,
            amg_operator_complexity: s.amg_operator_complexity,
            amg_setup_seconds: s.amg_setup_seconds,
        }
    }
}

/// Wall-clock seconds per stage of one step.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct TimingDiagnostics {
    /// Ghosts, neighbour list, volumes.
    #[serde(deserialize_with = "nullable")]
    #[schemars(with = "Option<f64>")]
    pub neighbors: f64,
    /// Predictor.
    #[serde(deserialize_with = "nullable")]
    #[schemars(with = "Option<f64>")]
    pub predictor: f64,
    /// Connectivity, `c0`, norms.
    #[serde(deserialize_with = "nullable")]
    #[schemars(with = "Option<f64>")]
    pub diagnostics: f64,
    /// Source `∇̂h·f`.
    #[serde(deserialize_with = "nullable")]
    #[schemars(with = "Option<f64>")]
    pub source: f64,
    /// Poisson solve (assembly, factorisation, iterations).
    #[serde(deserialize_with = "nullable")]
    #[schemars(with = "Option<f64>")]
    pub solve: f64,
    /// Correction and pressure update.
    #[serde(deserialize_with = "nullable")]
    #[schemars(with = "Option<f64>")]
    pub correction: f64,
    /// Advection, shifting, confinement.
    #[serde(deserialize_with = "nullable")]
    #[schemars(with = "Option<f64>")]
    pub advect: f64,
    /// Sum of the stages above.
    #[serde(deserialize_with = "nullable")]
    #[schemars(with = "Option<f64>")]
    pub total: f64,
    /// Seconds the recorder spent on the *previous* step (serialising, compressing, flushing):
    /// the recording overhead, comparable with `total`.
    #[serde(deserialize_with = "nullable")]
    #[schemars(with = "Option<f64>")]
    pub record: f64,
}

/// One `/diagnostics` message: what one flow step did and measured.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct StepDiagnostics {
    /// Step number (1 for the first step); also the MCAP sequence number.
    pub step: u64,
    /// Simulation time after the step; the MCAP log time is this in nanoseconds.
    #[serde(deserialize_with = "nullable")]
    #[schemars(with = "Option<f64>")]
    pub time: f64,
    /// Time step.
    #[serde(deserialize_with = "nullable")]
    #[schemars(with = "Option<f64>")]
    pub dt: f64,
    /// Which limit set `Δt`; `null` when the caller's own loop chose it.
    pub dt_limit: Option<DtLimit>,
    /// h-connectivity.
    pub connectivity: ConnectivityDiagnostics,
    /// Semi-regularity constant `c0` (Def. 3.2).
    #[serde(deserialize_with = "nullable")]
    #[schemars(with = "Option<f64>")]
    pub c0: f64,
    /// Theorem 4.5 ratio `‖φ‖_h01 / (√(d c0) ‖f‖_ℓ2)` (at most 1 by the theorem).
    #[serde(deserialize_with = "nullable")]
    #[schemars(with = "Option<f64>")]
    pub stability_ratio: f64,
    /// Smallest distance between a fluid particle and a neighbour (ghosts included; absent in
    /// older logs: NaN).
    #[serde(default = "nan", deserialize_with = "nullable")]
    #[schemars(with = "Option<f64>")]
    pub min_spacing: f64,
    /// `‖uⁿ⁺¹ − u*‖/‖u*‖`: the share of the predicted velocity the correction removed (absent
    /// in older logs: NaN).
    #[serde(default = "nan", deserialize_with = "nullable")]
    #[schemars(with = "Option<f64>")]
    pub correction_ratio: f64,
    /// Kinetic energy after the step over the energy before it; `null` on the first step, from
    /// rest, or when the loop did not say.
    #[serde(default)]
    pub energy_growth: Option<f64>,
    /// The Poisson solve.
    pub solve: SolveDiagnostics,
    /// The implicit viscous solve of the predictor; `null` when none ran (explicit or no
    /// viscosity, a loop that did not say) and in older logs.
    #[serde(default)]
    pub viscous: Option<SolveDiagnostics>,
    /// `‖∇̂h·u*‖_ℓ2(Ω)`.
    #[serde(deserialize_with = "nullable")]
    #[schemars(with = "Option<f64>")]
    pub div_before: f64,
    /// `‖∇̂h·uⁿ⁺¹‖_ℓ2(Ω)`.
    #[serde(deserialize_with = "nullable")]
    #[schemars(with = "Option<f64>")]
    pub div_after: f64,
    /// Kinetic energy after the step.
    #[serde(deserialize_with = "nullable")]
    #[schemars(with = "Option<f64>")]
    pub kinetic_energy: f64,
    /// Largest fluid speed after the step.
    #[serde(deserialize_with = "nullable")]
    #[schemars(with = "Option<f64>")]
    pub max_speed: f64,
    /// The neighbour candidates were rebuilt this step.
    pub neighbors_rebuilt: bool,
    /// Largest particle shift this step.
    #[serde(deserialize_with = "nullable")]
    #[schemars(with = "Option<f64>")]
    pub max_shift: f64,
    /// Moving particles with the volume shift: the RMS relative deviation of the fluid's
    /// number-density volumes from their mean before the move (`ω̄/ω_i − 1`); `null` without a
    /// volume shift (and in older logs).
    #[serde(default)]
    pub volume_error: Option<f64>,
    /// Moving particles: particles the wall margin stopped this step (a particle that would
    /// have come closer to a wall than the margin; 0 in older logs).
    #[serde(default)]
    pub wall_pushes: u64,
    /// Seconds per stage.
    pub timings: TimingDiagnostics,
    /// Free surfaces: particles of the band (surface particles) this step; `null` without a
    /// free surface (and in older logs).
    #[serde(default)]
    pub surface_particles: Option<u64>,
    /// Free surfaces: band particles without a fluid neighbour (splashes); `null` without one.
    #[serde(default)]
    pub splash_particles: Option<u64>,
}

impl StepDiagnostics {
    /// The diagnostics of a flow step. `allowed_floating` comes from the projection parameters;
    /// `record_seconds` is the recorder's time on the previous step.
    pub fn from_report(report: &FlowReport, allowed_floating: usize, record_seconds: f64) -> Self {
        Self::new(
            &super::StepContext::from_flow(report, allowed_floating),
            &report.projection,
            record_seconds,
        )
    }

    /// The diagnostics of one projection step `p` in its context `ctx` (from any loop);
    /// `record_seconds` is the recorder's time on the previous step. The total time is
    /// `neighbors + predictor + diagnostics + source + solve + correction + advect`.
    pub fn new(ctx: &super::StepContext, p: &StepReport, record_seconds: f64) -> Self {
        let c = &p.connectivity;
        let t = &p.timings;
        let allowed_floating = ctx.allowed_floating;
        let total = ctx.neighbors_seconds
            + t.predictor
            + t.diagnostics
            + t.source
            + t.solve
            + t.correction
            + ctx.advect_seconds;
        StepDiagnostics {
            step: ctx.step,
            time: ctx.time,
            dt: p.dt,
            dt_limit: ctx.dt_limit,
            connectivity: ConnectivityDiagnostics {
                components: c.components,
                anchored: c.anchored,
                floating: c.floating,
                isolated: c.isolated,
                allowed_floating,
                ok: c.floating <= allowed_floating && c.isolated == 0,
            },
            c0: p.c0,
            stability_ratio: p.stability_ratio,
            min_spacing: p.min_spacing,
            correction_ratio: p.correction_ratio,
            energy_growth: ctx.energy_growth,
            solve: SolveDiagnostics::from(&p.solve),
            viscous: p.viscous.as_ref().map(SolveDiagnostics::from),
            div_before: p.div_before,
            div_after: p.div_after,
            kinetic_energy: p.kinetic_energy,
            max_speed: p.max_speed,
            neighbors_rebuilt: ctx.neighbors_rebuilt,
            max_shift: ctx.max_shift,
            volume_error: ctx.volume_error,
            wall_pushes: ctx.wall_pushes as u64,
            timings: TimingDiagnostics {
                neighbors: ctx.neighbors_seconds,
                predictor: t.predictor,
                diagnostics: t.diagnostics,
                source: t.source,
                solve: t.solve,
                correction: t.correction,
                advect: ctx.advect_seconds,
                total,
                record: record_seconds,
            },
            surface_particles: ctx.surface.map(|s| s.surface as u64),
            splash_particles: ctx.surface.map(|s| s.splash as u64),
        }
    }
}

// ---------------------------------------------------------------------------------------------
// /config

/// The `/config` message: the run's complete configuration, written once before the first step.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct RunConfig {
    /// Always `"gpm-mcap"`.
    #[schemars(extend("const" = "gpm-mcap"))]
    pub format: String,
    /// [`FORMAT_VERSION`] of the writer.
    pub format_version: u32,
    /// Version of the gpm crate that wrote the file.
    pub gpm_version: String,
    /// Recording level.
    pub level: super::RecordLevel,
    /// `k`: snapshots and projection inputs every `k` steps (level `full`).
    pub particles_every: u64,
    /// The file is flushed (a chunk closed) every this many steps.
    pub flush_every: u64,
    /// Chunk compression (`zstd` or `none`).
    #[schemars(extend("enum" = ["zstd", "none"]))]
    pub compression: String,
    /// Rayon worker threads of the run (results of parallel reductions may depend on it).
    pub threads: usize,
    /// The caller's configuration, verbatim (for `gpm run`: `{"scene": ..., "config": {...}}`
    /// with the scene's serde configuration, enough to reproduce the run).
    pub config: Value,
}

impl RunConfig {}

// ---------------------------------------------------------------------------------------------
// /particles: foxglove.PointCloud

/// `foxglove.Time`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Time {
    /// Seconds.
    pub sec: u32,
    /// Nanoseconds, `0..1e9`.
    pub nsec: u32,
}

impl Time {
    /// From nanoseconds.
    pub fn from_nanos(ns: u64) -> Self {
        Time {
            sec: (ns / 1_000_000_000).min(u32::MAX as u64) as u32,
            nsec: (ns % 1_000_000_000) as u32,
        }
    }
}

/// `foxglove.Vector3`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Vector3 {
    /// x.
    pub x: f64,
    /// y.
    pub y: f64,
    /// z.
    pub z: f64,
}

/// `foxglove.Quaternion`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Quaternion {
    /// x.
    pub x: f64,
    /// y.
    pub y: f64,
    /// z.
    pub z: f64,
    /// w.
    pub w: f64,
}

/// `foxglove.Pose`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Pose {
    /// Origin.
    pub position: Vector3,
    /// Orientation.
    pub orientation: Quaternion,
}

impl Default for Pose {
    fn default() -> Self {
        Pose {
            position: Vector3::default(),
            orientation: Quaternion {
                x: 0.0,
                y: 0.0,
                z: 0.0,
                w: 1.0,
            },
        }
    }
}

/// `foxglove.NumericType` code of 32-bit floats.
pub const FLOAT32: u8 = 7;
/// `foxglove.NumericType` code of 64-bit floats.
pub const FLOAT64: u8 = 8;

/// `foxglove.PackedElementField`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PackedElementField {
    /// Field name (`x`, `y`, `z` are the position).
    pub name: String,
    /// Byte offset within a point.
    pub offset: u32,
    /// `foxglove.NumericType` (1 UINT8 … 7 FLOAT32, 8 FLOAT64).
    #[serde(rename = "type")]
    pub numeric_type: u8,
}

/// `foxglove.PointCloud`: the `/particles` snapshot. gpm writes, per particle (ghosts
/// included), little-endian FLOAT32 fields `x y z vx vy vz speed p role` (`z = vz = 0` in 2D;
/// `role`: 0 fluid, 1 Dirichlet, 2 ghost), `frame_id = "world"`, identity pose.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PointCloud {
    /// Simulation time.
    pub timestamp: Time,
    /// Frame of reference.
    pub frame_id: String,
    /// Origin of the cloud in the frame.
    pub pose: Pose,
    /// Bytes per point.
    pub point_stride: u32,
    /// Fields of a point.
    pub fields: Vec<PackedElementField>,
    /// Points, standard base64.
    pub data: String,
}

/// Field names of gpm's point clouds, in order.
pub const POINT_FIELDS: [&str; 9] = ["x", "y", "z", "vx", "vy", "vz", "speed", "p", "role"];

/// Role code of the point cloud and of [`ProjectionInput::role_kind`].
pub fn role_code(r: &Role) -> u8 {
    match r {
        Role::Fluid => 0,
        Role::Dirichlet => 1,
        Role::Ghost { .. } => 2,
    }
}

impl PointCloud {
    /// A snapshot of particles at `time` (seconds): one point per position; the slices should
    /// have one entry per position (a shorter `u`, `p` or `role` ends the cloud early; the
    /// [`Recorder`](super::Recorder) checks the lengths first and reports a mismatch).
    pub fn from_particles<const D: usize>(
        time: f64,
        x: &[[f64; D]],
        u: &[[f64; D]],
        p: &[f64],
        role: &[Role],
    ) -> Self {
        let stride = 4 * POINT_FIELDS.len();
        let mut bytes = Vec::with_capacity(stride * x.len());
        for (((x, u), p), role) in x.iter().zip(u).zip(p).zip(role) {
            let mut put = |v: f64| bytes.extend_from_slice(&(v as f32).to_le_bytes());
            let c = |a: &[f64; D], k: usize| if k < D { a[k] } else { 0.0 };
            for k in 0..3 {
                put(c(x, k));
            }
            for k in 0..3 {
                put(c(u, k));
            }
            put(u.iter().map(|v| v * v).sum::<f64>().sqrt());
            put(*p);
            put(role_code(role) as f64);
        }
        PointCloud {
            timestamp: Time::from_nanos(super::time_to_nanos(time)),
            frame_id: "world".into(),
            pose: Pose::default(),
            point_stride: stride as u32,
            fields: POINT_FIELDS
                .iter()
                .enumerate()
                .map(|(k, n)| PackedElementField {
                    name: (*n).into(),
                    offset: 4 * k as u32,
                    numeric_type: FLOAT32,
                })
                .collect(),
            data: base64::engine::general_purpose::STANDARD.encode(&bytes),
        }
    }

    /// Number of points (decodes nothing).
    pub fn len(&self) -> usize {
        let bytes = self.data.len() / 4 * 3;
        let pad = self.data.bytes().rev().take_while(|&b| b == b'=').count();
        (bytes - pad.min(bytes)) / (self.point_stride.max(1) as usize)
    }

    /// True when the cloud has no point.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Decodes the named fields (any FLOAT32/FLOAT64/integer field) into one `Vec<f64>` each;
    /// `None` for a field the cloud does not have.
    pub fn decode(&self, names: &[&str]) -> Result<Vec<Option<Vec<f64>>>, String> {
        let bytes = base64::engine::general_purpose::STANDARD
            .decode(self.data.as_bytes())
            .map_err(|e| format!("point cloud data is not base64: {e}"))?;
        let stride = self.point_stride as usize;
        if stride == 0 || !bytes.len().is_multiple_of(stride) {
            return Err(format!(
                "point cloud data has {} bytes, not a multiple of the stride {stride}",
                bytes.len()
            ));
        }
        let n = bytes.len() / stride;
        let mut out = Vec::new();
        for name in names {
            let Some(f) = self.fields.iter().find(|f| f.name == *name) else {
                out.push(None);
                continue;
            };
            let size = match f.numeric_type {
                1 | 2 => 1,
                3 | 4 => 2,
                5..=7 => 4,
                8 => 8,
                t => return Err(format!("field '{name}' has unknown numeric type {t}")),
            };
            let off = f.offset as usize;
            if off + size > stride {
                return Err(format!("field '{name}' lies outside the point stride"));
            }
            let mut v = Vec::with_capacity(n);
            for i in 0..n {
                let b = &bytes[i * stride + off..i * stride + off + size];
                v.push(match f.numeric_type {
                    1 => b[0] as f64,
                    2 => b[0] as i8 as f64,
                    3 => u16::from_le_bytes([b[0], b[1]]) as f64,
                    4 => i16::from_le_bytes([b[0], b[1]]) as f64,
                    5 => u32::from_le_bytes(b.try_into().unwrap()) as f64,
                    6 => i32::from_le_bytes(b.try_into().unwrap()) as f64,
                    7 => f32::from_le_bytes(b.try_into().unwrap()) as f64,
                    _ => f64::from_le_bytes(b.try_into().unwrap()),
                });
            }
            out.push(Some(v));
        }
        Ok(out)
    }

    /// JSON Schema of `foxglove.PointCloud` (the structure Foxglove publishes for this schema
    /// name; written here with every property required).
    pub fn schema() -> Value {
        let number = json!({"type": "number"});
        let vector3 = json!({
            "title": "foxglove.Vector3",
            "type": "object",
            "properties": {"x": number, "y": number, "z": number},
            "required": ["x", "y", "z"],
        });
        let quaternion = json!({
            "title": "foxglove.Quaternion",
            "type": "object",
            "properties": {"x": number, "y": number, "z": number, "w": number},
            "required": ["x", "y", "z", "w"],
        });
        let numeric_types = [
            "UNKNOWN", "UINT8", "INT8", "UINT16", "INT16", "UINT32", "INT32", "FLOAT32", "FLOAT64",
        ]
        .iter()
        .enumerate()
        .map(|(k, t)| json!({"title": t, "const": k}))
        .collect::<Vec<_>>();
        json!({
            "$schema": "https://json-schema.org/draft/2020-12/schema",
            "title": SCHEMA_POINT_CLOUD,
            "description": "A collection of N-dimensional points with extra fields per point (gpm: x y z vx vy vz speed p role)",
            "type": "object",
            "properties": {
                "timestamp": {
                    "title": "time",
                    "type": "object",
                    "properties": {
                        "sec": {"type": "integer", "minimum": 0},
                        "nsec": {"type": "integer", "minimum": 0, "maximum": 999_999_999},
                    },
                    "required": ["sec", "nsec"],
                },
                "frame_id": {"type": "string", "description": "frame of reference"},
                "pose": {
                    "title": "foxglove.Pose",
                    "description": "origin of the cloud in the frame",
                    "type": "object",
                    "properties": {"position": vector3, "orientation": quaternion},
                    "required": ["position", "orientation"],
                },
                "point_stride": {"type": "integer", "minimum": 0, "description": "bytes between points in data"},
                "fields": {
                    "type": "array",
                    "description": "fields of each point in data",
                    "items": {
                        "title": "foxglove.PackedElementField",
                        "type": "object",
                        "properties": {
                            "name": {"type": "string"},
                            "offset": {"type": "integer", "minimum": 0, "description": "byte offset within a point"},
                            "type": {
                                "title": "foxglove.NumericType",
                                "description": "little-endian element type",
                                "oneOf": numeric_types,
                            },
                        },
                        "required": ["name", "offset", "type"],
                    },
                },
                "data": {"type": "string", "contentEncoding": "base64", "description": "points, interpreted with fields"},
            },
            "required": ["timestamp", "frame_id", "pose", "point_stride", "fields", "data"],
        })
    }
}

// ---------------------------------------------------------------------------------------------
// Bulk arrays

/// Element type of an [`Array`] (numpy spelling).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, JsonSchema)]
pub enum Dtype {
    /// Little-endian `f64`.
    #[serde(rename = "<f8")]
    F64,
    /// Little-endian `u32`.
    #[serde(rename = "<u4")]
    U32,
    /// `u8`.
    #[serde(rename = "|u1")]
    U8,
}

impl Dtype {
    fn size(self) -> usize {
        match self {
            Dtype::F64 => 8,
            Dtype::U32 => 4,
            Dtype::U8 => 1,
        }
    }
}

/// A typed array, exact: little-endian bytes in standard base64, numpy `dtype` and `shape`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct Array {
    /// Element type.
    pub dtype: Dtype,
    /// Shape (row-major): `[n]` or `[n, D]`.
    pub shape: Vec<usize>,
    /// The bytes, standard base64.
    #[schemars(extend("contentEncoding" = "base64"))]
    pub data: String,
}

fn b64(bytes: &[u8]) -> String {
    base64::engine::general_purpose::STANDARD.encode(bytes)
}

impl Array {
    /// `[n]` f64.
    pub fn from_f64(v: &[f64]) -> Self {
        let mut b = Vec::with_capacity(8 * v.len());
        for x in v {
            b.extend_from_slice(&x.to_le_bytes());
        }
        Array {
            dtype: Dtype::F64,
            shape: vec![v.len()],
            data: b64(&b),
        }
    }
    /// `[n, D]` f64.
    pub fn from_vectors<const D: usize>(v: &[[f64; D]]) -> Self {
        let mut b = Vec::with_capacity(8 * D * v.len());
        for x in v {
            for c in x {
                b.extend_from_slice(&c.to_le_bytes());
            }
        }
        Array {
            dtype: Dtype::F64,
            shape: vec![v.len(), D],
            data: b64(&b),
        }
    }
    /// `[n]` u32.
    pub fn from_u32(v: &[u32]) -> Self {
        let mut b = Vec::with_capacity(4 * v.len());
        for x in v {
            b.extend_from_slice(&x.to_le_bytes());
        }
        Array {
            dtype: Dtype::U32,
            shape: vec![v.len()],
            data: b64(&b),
        }
    }
    /// `[n]` u8.
    pub fn from_u8(v: &[u8]) -> Self {
        Array {
            dtype: Dtype::U8,
            shape: vec![v.len()],
            data: b64(v),
        }
    }

    fn bytes(&self, what: &'static str, dtype: Dtype) -> Result<Vec<u8>, RecordError> {
        let spec = |reason: String| RecordError::Spec { what, reason };
        if self.dtype != dtype {
            return Err(spec(format!(
                "dtype {:?}, expected {:?}",
                self.dtype, dtype
            )));
        }
        let b = base64::engine::general_purpose::STANDARD
            .decode(self.data.as_bytes())
            .map_err(|e| spec(format!("data is not base64: {e}")))?;
        let n: usize = self.shape.iter().product();
        if b.len() != n * dtype.size() {
            return Err(spec(format!(
                "shape {:?} needs {} bytes, data has {}",
                self.shape,
                n * dtype.size(),
                b.len()
            )));
        }
        Ok(b)
    }

    /// Decodes a `[n]` f64 array.
    pub fn to_f64(&self, what: &'static str) -> Result<Vec<f64>, RecordError> {
        let b = self.bytes(what, Dtype::F64)?;
        Ok(b.chunks_exact(8)
            .map(|c| f64::from_le_bytes(c.try_into().unwrap()))
            .collect())
    }
    /// Decodes a `[n, D]` f64 array.
    pub fn to_vectors<const D: usize>(
        &self,
        what: &'static str,
    ) -> Result<Vec<[f64; D]>, RecordError> {
        if self.shape.len() != 2 || self.shape[1] != D {
            return Err(RecordError::Spec {
                what,
                reason: format!("shape {:?}, expected [n, {D}]", self.shape),
            });
        }
        let v = self.to_f64(what)?;
        Ok(v.chunks_exact(D)
            .map(|c| std::array::from_fn(|k| c[k]))
            .collect())
    }
    /// Decodes a `[n]` u32 array.
    pub fn to_u32(&self, what: &'static str) -> Result<Vec<u32>, RecordError> {
        let b = self.bytes(what, Dtype::U32)?;
        Ok(b.chunks_exact(4)
            .map(|c| u32::from_le_bytes(c.try_into().unwrap()))
            .collect())
    }
    /// Decodes a `[n]` u8 array.
    pub fn to_u8(&self, what: &'static str) -> Result<Vec<u8>, RecordError> {
        self.bytes(what, Dtype::U8)
    }

    /// Number of elements the shape declares.
    pub fn len(&self) -> usize {
        self.shape.iter().product()
    }

    /// True when the array has no element.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

// ---------------------------------------------------------------------------------------------
// What a projection needs besides the particles

fn dim_check(what: &'static str, len: usize, d: usize) -> Result<(), RecordError> {
    if len != d {
        return Err(RecordError::Spec {
            what,
            reason: format!("has {len} components, the run is {d}-dimensional"),
        });
    }
    Ok(())
}

fn to_array<const D: usize>(what: &'static str, v: &[f64]) -> Result<[f64; D], RecordError> {
    dim_check(what, v.len(), D)?;
    Ok(std::array::from_fn(|k| v[k]))
}

/// Periodic axes ([`Periodicity`]): axis `k` has period `len[k]` when it is positive.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct PeriodicSpec {
    /// Lower corner of the periodic box.
    pub lo: Vec<f64>,
    /// Period per axis; 0 = not periodic.
    pub len: Vec<f64>,
}

impl<const D: usize> From<&Periodicity<D>> for PeriodicSpec {
    fn from(p: &Periodicity<D>) -> Self {
        let Periodicity { lo, len } = *p;
        PeriodicSpec {
            lo: lo.to_vec(),
            len: len.to_vec(),
        }
    }
}

impl PeriodicSpec {
    /// Back to a [`Periodicity`] (checks the dimension).
    pub fn to_periodicity<const D: usize>(&self) -> Result<Periodicity<D>, RecordError> {
        Ok(Periodicity {
            lo: to_array("periodic.lo", &self.lo)?,
            len: to_array("periodic.len", &self.len)?,
        })
    }
}

/// Everything [`crate::neighbors::NeighborList::build`] needs besides the positions.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct NeighborSpec {
    /// Influence radius `h`.
    pub h: f64,
    /// Skin.
    pub skin: f64,
    /// Reference weight.
    pub weight: Weight,
    /// Periodic axes.
    pub periodic: PeriodicSpec,
}

impl<const D: usize> From<&NeighborConfig<D>> for NeighborSpec {
    fn from(c: &NeighborConfig<D>) -> Self {
        // exhaustive on purpose (see ProjectionSpec)
        let NeighborConfig {
            h,
            skin,
            weight,
            periodic,
            // the candidates, and so every result, are the same with either structure
            search: _,
        } = *c;
        NeighborSpec {
            h,
            skin,
            weight,
            periodic: (&periodic).into(),
        }
    }
}

impl NeighborSpec {
    /// Back to a [`NeighborConfig`] (checks the dimension).
    pub fn to_config<const D: usize>(&self) -> Result<NeighborConfig<D>, RecordError> {
        Ok(NeighborConfig::new(self.weight, self.h, self.skin)
            .with_periodicity(self.periodic.to_periodicity()?))
    }
}

/// One planar wall ([`Wall`]).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct WallSpec {
    /// Normal axis.
    pub axis: usize,
    /// Coordinate of the plane.
    pub position: f64,
    /// +1 when the fluid is at larger coordinates, −1 otherwise.
    pub inward: f64,
    /// Wall velocity.
    pub velocity: Vec<f64>,
    /// Free-slip (absent in files written before free-slip walls existed: no-slip).
    #[serde(default)]
    pub slip: bool,
    /// Width of the velocity's ramp towards the walls that meet it ([`Wall::ramp`]; absent in
    /// files written before ramped walls existed: `0`, a uniform wall velocity).
    #[serde(default)]
    pub ramp: f64,
    /// Width of the source continuation's band next to the wall ([`Wall::source_band`]; absent
    /// in files written before it existed: `0`, no band).
    #[serde(default)]
    pub source_band: f64,
}

/// A serialisable boundary: enough to rebuild [`Walls`], [`PeriodicBox`] or [`NoBoundary`]; a
/// boundary of your own is recorded as [`BoundarySpec::Custom`] (or as an equivalent crate
/// boundary, if it has one).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum BoundarySpec {
    /// [`NoBoundary`].
    None,
    /// [`PeriodicBox`].
    Periodic {
        /// The periodic axes.
        periodic: PeriodicSpec,
    },
    /// [`Walls`] with mirror ghosts (bit `k` of a ghost's `walls` is `walls[k]`).
    Walls {
        /// The walls, in order (at most 8: a ghost's wall set is one byte).
        #[schemars(length(max = 8))]
        walls: Vec<WallSpec>,
        /// Periodic axes.
        periodic: PeriodicSpec,
    },
    /// A boundary of the caller's own, described in words: its projection inputs are recorded
    /// (arrays, parameters, neighbour settings) but cannot be re-run, because gpm cannot
    /// rebuild the boundary ([`BoundarySpec::build`] fails with [`RecordError::Spec`]).
    Custom {
        /// What the boundary is (free text).
        description: String,
    },
}

/// Boundaries that can describe themselves as a [`BoundarySpec`] (needed to record projection
/// inputs). Implemented for the crate's boundaries; implement it for your own to record them
/// (returning a spec that [`BoundarySpec::build`] turns into an equivalent boundary).
pub trait ToBoundarySpec<const D: usize> {
    /// The spec of this boundary.
    fn to_spec(&self) -> BoundarySpec;
}

impl<const D: usize> ToBoundarySpec<D> for Walls<D> {
    fn to_spec(&self) -> BoundarySpec {
        let Walls { walls, periodic } = self;
        BoundarySpec::Walls {
            walls: walls
                .iter()
                .map(|w| {
                    let Wall {
                        axis,
                        position,
                        inward,
                        velocity,
                        slip,
                        ramp,
                        source_band,
                    } = *w;
                    WallSpec {
                        axis,
                        position,
                        inward,
                        velocity: velocity.to_vec(),
                        slip,
                        ramp,
                        source_band,
                    }
                })
                .collect(),
            periodic: periodic.into(),
        }
    }
}

impl<const D: usize> ToBoundarySpec<D> for PeriodicBox<D> {
    fn to_spec(&self) -> BoundarySpec {
        BoundarySpec::Periodic {
            periodic: (&self.periodic).into(),
        }
    }
}

impl<const D: usize> ToBoundarySpec<D> for NoBoundary {
    fn to_spec(&self) -> BoundarySpec {
        BoundarySpec::None
    }
}

impl<const D: usize> From<&Walls<D>> for BoundarySpec {
    fn from(w: &Walls<D>) -> Self {
        w.to_spec()
    }
}

impl<const D: usize> From<&PeriodicBox<D>> for BoundarySpec {
    fn from(b: &PeriodicBox<D>) -> Self {
        b.to_spec()
    }
}

impl BoundarySpec {
    /// [`Walls`] from a `walls` spec.
    pub fn to_walls<const D: usize>(&self) -> Result<Walls<D>, RecordError> {
        match self {
            BoundarySpec::Walls { walls, periodic } => {
                let mut out = Vec::with_capacity(walls.len());
                for w in walls {
                    if w.axis >= D {
                        return Err(RecordError::Spec {
                            what: "wall",
                            reason: format!("axis {} in a {D}-dimensional run", w.axis),
                        });
                    }
                    out.push(Wall {
                        axis: w.axis,
                        position: w.position,
                        inward: w.inward,
                        velocity: to_array("wall velocity", &w.velocity)?,
                        slip: w.slip,
                        ramp: w.ramp,
                        source_band: w.source_band,
                    });
                }
                if out.len() > 8 {
                    return Err(RecordError::Spec {
                        what: "walls",
                        reason: format!("{} walls; at most 8 are supported", out.len()),
                    });
                }
                Ok(Walls {
                    walls: out,
                    periodic: periodic.to_periodicity()?,
                })
            }
            _ => Err(RecordError::Spec {
                what: "boundary",
                reason: "not a walls boundary".into(),
            }),
        }
    }

    /// The boundary this spec describes.
    pub fn build<const D: usize>(&self) -> Result<Box<dyn Boundary<D>>, RecordError> {
        Ok(match self {
            BoundarySpec::None => Box::new(NoBoundary),
            BoundarySpec::Periodic { periodic } => Box::new(PeriodicBox {
                periodic: periodic.to_periodicity()?,
            }),
            BoundarySpec::Walls { .. } => Box::new(self.to_walls::<D>()?),
            BoundarySpec::Custom { description } => {
                return Err(RecordError::Spec {
                    what: "boundary",
                    reason: format!(
                        "a custom boundary ({description}) cannot be rebuilt from the recording"
                    ),
                })
            }
        })
    }
}

/// [`ProjectionParams`] in serialisable form.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct ProjectionSpec {
    /// Density.
    pub rho: f64,
    /// Kinematic viscosity.
    pub nu: f64,
    /// Body force.
    pub gravity: Vec<f64>,
    /// Pressure scheme.
    pub scheme: Scheme,
    /// Implicit weight of the viscous term.
    pub viscous_theta: f64,
    /// Linear solve.
    pub solve: SolveParams,
    /// How the source is continued into wall ghosts.
    pub source_ghosts: GhostContinuation,
    /// Floating components allowed.
    pub allowed_floating: usize,
    /// Policy for components beyond them (files before it was recorded: fail).
    #[serde(default)]
    pub disconnected: Disconnected,
    /// Connectivity and c0 reused while their inputs are unchanged.
    pub reuse_diagnostics: bool,
    /// Gradient of the predictor and the correction (files before it was recorded: difference).
    #[serde(default)]
    pub gradient: crate::consistent::GradientKind,
    /// Divergence of the source (files before it was recorded: sum form).
    #[serde(default)]
    pub source: crate::projection::SourceKind,
    /// Laplacian of the viscous term (files before it was recorded: gpm).
    #[serde(default)]
    pub laplacian: LaplacianKind,
    /// Weight of the pressure smoothing sweep (files before it was recorded: 0).
    #[serde(default)]
    pub pressure_smoothing: f64,
    /// The Dirichlet band is a free surface that moves with the fluid (files before it was
    /// recorded: false).
    #[serde(default)]
    pub free_surface: bool,
}

/// [`VectorKind`] in serialisable form.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum GhostContinuation {
    /// [`VectorKind::Velocity`]: no-slip images.
    Velocity,
    /// [`VectorKind::Mirror`]: normal components flipped.
    Mirror,
    /// [`VectorKind::RestWalls`]: no-slip images across walls at rest, mirror across moving
    /// ones and at their corners, blended within a moving wall's [`WallSpec::source_band`].
    /// (Files written before 2026-11-28 evening had the no-slip rule's mean at a moving wall's
    /// corners, and no band; they re-run with this rule.)
    RestWalls,
    /// [`VectorKind::RestWallsLinear`]: [`GhostContinuation::RestWalls`] with the tangential
    /// components across a moving wall continued linearly from the source and the particle
    /// straight inward from it.
    RestWallsLinear,
}

impl From<VectorKind> for GhostContinuation {
    fn from(k: VectorKind) -> Self {
        match k {
            VectorKind::Velocity => GhostContinuation::Velocity,
            VectorKind::Mirror => GhostContinuation::Mirror,
            VectorKind::RestWalls => GhostContinuation::RestWalls,
            VectorKind::RestWallsLinear => GhostContinuation::RestWallsLinear,
        }
    }
}

impl From<GhostContinuation> for VectorKind {
    fn from(k: GhostContinuation) -> Self {
        match k {
            GhostContinuation::Velocity => VectorKind::Velocity,
            GhostContinuation::Mirror => VectorKind::Mirror,
            GhostContinuation::RestWalls => VectorKind::RestWalls,
            GhostContinuation::RestWallsLinear => VectorKind::RestWallsLinear,
        }
    }
}

impl<const D: usize> From<&ProjectionParams<D>> for ProjectionSpec {
    fn from(p: &ProjectionParams<D>) -> Self {
        // exhaustive on purpose: a new parameter must be recorded, or a re-run silently
        // differs from the run
        let ProjectionParams {
            rho,
            nu,
            gravity,
            scheme,
            viscous_theta,
            solve,
            source_ghosts,
            allowed_floating,
            disconnected,
            reuse_diagnostics,
            gradient,
            source,
            laplacian,
            pressure_smoothing,
            free_surface,
        } = *p;
        ProjectionSpec {
            rho,
            nu,
            gravity: gravity.to_vec(),
            scheme,
            viscous_theta,
            solve,
            source_ghosts: source_ghosts.into(),
            allowed_floating,
            disconnected,
            reuse_diagnostics,
            gradient,
            source,
            laplacian,
            pressure_smoothing,
            free_surface,
        }
    }
}

impl ProjectionSpec {
    /// Back to [`ProjectionParams`] (checks the dimension).
    pub fn to_params<const D: usize>(&self) -> Result<ProjectionParams<D>, RecordError> {
        Ok(ProjectionParams {
            rho: self.rho,
            nu: self.nu,
            gravity: to_array("gravity", &self.gravity)?,
            scheme: self.scheme,
            viscous_theta: self.viscous_theta,
            solve: self.solve,
            source_ghosts: self.source_ghosts.into(),
            allowed_floating: self.allowed_floating,
            disconnected: self.disconnected,
            reuse_diagnostics: self.reuse_diagnostics,
            gradient: self.gradient,
            source: self.source,
            laplacian: self.laplacian,
            pressure_smoothing: self.pressure_smoothing,
            free_surface: self.free_surface,
        })
    }
}

// ---------------------------------------------------------------------------------------------
// /projection_input

/// One `/projection_input` message: everything one [`crate::projection::ProjectionStep::project`]
/// call read, and what it wrote, so that `gpm replay --rerun` can run it again and compare.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct ProjectionInput {
    /// Step.
    pub step: u64,
    /// Simulation time after the step.
    pub time: f64,
    /// Time step passed to the projection.
    pub dt: f64,
    /// Dimension `D`.
    #[schemars(extend("enum" = [2, 3]))]
    pub dimension: usize,
    /// Particles (ghosts included).
    pub particles: usize,
    /// Rayon worker threads of the recording run.
    pub threads: usize,
    /// Neighbour list configuration.
    pub neighbors: NeighborSpec,
    /// Boundary.
    pub boundary: BoundarySpec,
    /// Projection parameters.
    pub params: ProjectionSpec,
    /// Positions `[n, D]`.
    pub x: Array,
    /// Volumes `[n]`.
    pub vol: Array,
    /// Role per particle `[n]` u8: 0 fluid, 1 Dirichlet, 2 ghost.
    pub role_kind: Array,
    /// Ghost source per particle `[n]` u32 (0 for non-ghosts).
    pub ghost_source: Array,
    /// Ghost wall bit set per particle `[n]` u8 (0 for non-ghosts).
    pub ghost_walls: Array,
    /// Predictor velocity `u*` `[n, D]`.
    pub u_star: Array,
    /// Pressure `pⁿ` before the projection `[n]`.
    pub p_in: Array,
    /// Increment held before the solve (CG's warm start) `[n]`.
    pub phi_in: Array,
    /// Velocity after the projection `[n, D]`.
    pub u_out: Array,
    /// Pressure after the projection `[n]`.
    pub p_out: Array,
    /// Increment `φ` `[n]`.
    pub phi: Array,
    /// The steady singular part the projection left out (the lid corners' subtracted flow,
    /// `gpm::scene::corner`), continued into the ghosts like the source `[n, D]`; `null` when
    /// there is none (missing in files written before 2026-11-30).
    #[serde(default)]
    pub singular_source: Option<Array>,
    /// The same singular part continued into the ghosts by the no-slip rule `[n, D]`; present
    /// exactly when `singular_source` is.
    #[serde(default)]
    pub singular_no_slip: Option<Array>,
}

/// Roles to the three arrays of [`ProjectionInput`].
pub fn encode_roles(role: &[Role]) -> (Array, Array, Array) {
    let kind: Vec<u8> = role.iter().map(role_code).collect();
    let source: Vec<u32> = role
        .iter()
        .map(|r| match r {
            Role::Ghost { source, .. } => *source,
            _ => 0,
        })
        .collect();
    let walls: Vec<u8> = role
        .iter()
        .map(|r| match r {
            Role::Ghost { walls, .. } => *walls,
            _ => 0,
        })
        .collect();
    (
        Array::from_u8(&kind),
        Array::from_u32(&source),
        Array::from_u8(&walls),
    )
}

/// The three role arrays back to roles.
pub fn decode_roles(kind: &Array, source: &Array, walls: &Array) -> Result<Vec<Role>, RecordError> {
    let k = kind.to_u8("role_kind")?;
    let s = source.to_u32("ghost_source")?;
    let w = walls.to_u8("ghost_walls")?;
    if s.len() != k.len() || w.len() != k.len() {
        return Err(RecordError::Spec {
            what: "roles",
            reason: format!(
                "role_kind has {}, ghost_source {}, ghost_walls {} entries",
                k.len(),
                s.len(),
                w.len()
            ),
        });
    }
    k.iter()
        .enumerate()
        .map(|(i, &c)| match c {
            0 => Ok(Role::Fluid),
            1 => Ok(Role::Dirichlet),
            2 => Ok(Role::Ghost {
                source: s[i],
                walls: w[i],
            }),
            c => Err(RecordError::Spec {
                what: "role_kind",
                reason: format!("particle {i}: unknown role code {c}"),
            }),
        })
        .collect()
}

/// The schema of every topic: `(topic, schema name, JSON Schema)`.
pub fn all_schemas() -> Vec<(&'static str, &'static str, Value)> {
    vec![
        (
            TOPIC_CONFIG,
            SCHEMA_CONFIG,
            message_schema::<RunConfig>(SCHEMA_CONFIG),
        ),
        (
            TOPIC_DIAGNOSTICS,
            SCHEMA_DIAGNOSTICS,
            message_schema::<StepDiagnostics>(SCHEMA_DIAGNOSTICS),
        ),
        (TOPIC_PARTICLES, SCHEMA_POINT_CLOUD, PointCloud::schema()),
        (
            TOPIC_PROJECTION,
            SCHEMA_PROJECTION,
            message_schema::<ProjectionInput>(SCHEMA_PROJECTION),
        ),
    ]
}
