//! Every recorded message validates against the JSON Schema stored in its file, the stored
//! schemas are valid JSON Schema (2020-12) and equal the library's, and the schemas reject what
//! the serde types reject (missing fields, unknown fields, unknown enum values).

use gpm::flow::DtLimit;
use gpm::kernel::Weight;
use gpm::poisson::SolverKind;
use gpm::projection::Scheme;
use gpm::record::schema::{
    all_schemas, BoundarySpec, PeriodicSpec, ProjectionInput, RunConfig, StepDiagnostics,
    TOPIC_PROJECTION,
};
use gpm::record::{RecordLevel, Recorder};
use gpm::scene::cavity::{self, CavityConfig};
use gpm::scene::taylor_green::{self, TaylorGreenConfig};
use serde_json::{json, Value};
use std::collections::{BTreeMap, HashMap};
use std::path::Path;

fn validator(schema: &Value) -> jsonschema::Validator {
    jsonschema::meta::validate(schema).expect("a valid JSON Schema");
    jsonschema::validator_for(schema).expect("compiles")
}

fn assert_valid(v: &jsonschema::Validator, instance: &Value, what: &str) {
    let errors: Vec<String> = v.iter_errors(instance).map(|e| e.to_string()).collect();
    assert!(errors.is_empty(), "{what}: {errors:?}");
}

/// Validates every message of a complete file against its stored schema; returns the count per
/// topic and one decoded projection input (if any).
fn validate_file(path: &Path) -> (BTreeMap<String, usize>, Option<ProjectionInput>) {
    let bytes = std::fs::read(path).unwrap();
    let library: HashMap<&str, Value> = all_schemas()
        .into_iter()
        .map(|(_, name, s)| (name, s))
        .collect();
    let mut validators: HashMap<u16, jsonschema::Validator> = HashMap::new();
    let mut counts = BTreeMap::new();
    let mut input = None;
    for m in mcap::MessageStream::new(&bytes).unwrap() {
        let m = m.unwrap();
        let schema = m
            .channel
            .schema
            .as_ref()
            .expect("every channel has a schema");
        assert_eq!(schema.encoding, "jsonschema");
        assert_eq!(m.channel.message_encoding, "json");
        let v = validators.entry(schema.id).or_insert_with(|| {
            let s: Value = serde_json::from_slice(&schema.data).unwrap();
            assert_eq!(
                s,
                library[schema.name.as_str()],
                "stored schema {}",
                schema.name
            );
            assert_eq!(s["title"], schema.name.as_str());
            validator(&s)
        });
        let msg: Value = serde_json::from_slice(&m.data).unwrap();
        assert_valid(v, &msg, &format!("{} {}", m.channel.topic, m.sequence));
        *counts.entry(m.channel.topic.clone()).or_insert(0) += 1;
        if m.channel.topic == TOPIC_PROJECTION && input.is_none() {
            input = Some(serde_json::from_value(msg).unwrap());
        }
    }
    (counts, input)
}

#[test]
fn recorded_messages_validate() {
    let dir = tempfile::tempdir().unwrap();
    // cavity (walls, ghosts), Lagrangian so shifting and rebuilds show up
    let cfg = CavityConfig::default().with(|c| {
        c.n = 12;
        c.t_end = 1.0;
        c.motion = gpm::flow::Motion::Lagrangian;
    });
    let path = dir.path().join("cavity.mcap");
    let mut sim = cavity::build(&cfg).unwrap();
    sim.projection.capture = true;
    let mut rec = Recorder::create(
        &path,
        RecordLevel::Full,
        2,
        &json!({"scene": "cavity", "config": &cfg}),
    )
    .unwrap();
    for _ in 0..5 {
        let r = sim.advance().unwrap();
        rec.write_step(&r, &sim).unwrap();
    }
    rec.finish().unwrap();
    let (counts, input) = validate_file(&path);
    assert_eq!(counts["/config"], 1);
    assert_eq!(counts["/diagnostics"], 5);
    assert_eq!(counts["/particles"], 3);
    assert_eq!(counts["/projection_input"], 3);
    assert!(matches!(
        input.unwrap().boundary,
        BoundarySpec::Walls { .. }
    ));

    // Taylor–Green (periodic box), through the scene's run and observer
    let cfg = TaylorGreenConfig::default().with(|c| {
        c.n = 12;
        c.t_end = 0.02;
    });
    let path = dir.path().join("tg.mcap");
    let mut rec = Recorder::create(&path, RecordLevel::Full, 1, &json!(null)).unwrap();
    taylor_green::run(&cfg, |r, sim| Ok(rec.write_step(r, sim)?)).unwrap();
    let s = rec.finish().unwrap();
    let (counts, _) = validate_file(&path);
    assert_eq!(counts["/diagnostics"] as u64, s.steps);
    assert_eq!(counts["/particles"] as u64, s.steps);
}

fn schema_of(name: &str) -> jsonschema::Validator {
    let s = all_schemas()
        .into_iter()
        .find(|(_, n, _)| *n == name)
        .unwrap()
        .2;
    validator(&s)
}

#[test]
fn every_variant_validates_and_round_trips() {
    let v = schema_of("gpm.StepDiagnostics");
    let dt_limits = [
        DtLimit::Cfl,
        DtLimit::Viscous,
        DtLimit::Force,
        DtLimit::Max,
        DtLimit::Fixed,
    ];
    let solvers = [SolverKind::Cholesky, SolverKind::Cg, SolverKind::Auto];
    for (k, dt_limit) in dt_limits.into_iter().enumerate() {
        let mut d = StepDiagnostics {
            step: k as u64 + 1,
            time: 0.5,
            dt: 0.01,
            dt_limit: Some(dt_limit),
            ..Default::default()
        };
        d.solve.solver = solvers[k % 3];
        // a diverging run: non-finite values are written as null and read back as NaN
        d.stability_ratio = f64::NAN;
        d.kinetic_energy = f64::INFINITY;
        let j = serde_json::to_value(d).unwrap();
        assert!(j["stability_ratio"].is_null() && j["kinetic_energy"].is_null());
        assert_valid(&v, &j, "diagnostics");
        let back: StepDiagnostics = serde_json::from_value(j).unwrap();
        assert!(back.stability_ratio.is_nan() && back.kinetic_energy.is_nan());
        assert_eq!(back.dt_limit, Some(dt_limit));
        assert_eq!(back.solve.solver, solvers[k % 3]);
    }
    // a loop of its own chose Δt: no limit, written as null
    let d = StepDiagnostics {
        dt_limit: None,
        ..Default::default()
    };
    let j = serde_json::to_value(d).unwrap();
    assert!(j["dt_limit"].is_null());
    assert_valid(&v, &j, "diagnostics without a dt limit");
    assert_eq!(serde_json::from_value::<StepDiagnostics>(j).unwrap(), d);

    let v = schema_of("gpm.RunConfig");
    for level in [
        RecordLevel::None,
        RecordLevel::Diagnostics,
        RecordLevel::Full,
    ] {
        let c = RunConfig {
            format: "gpm-mcap".into(),
            format_version: 1,
            gpm_version: "0".into(),
            level,
            particles_every: 10,
            flush_every: 1,
            compression: "none".into(),
            threads: 2,
            config: json!({"anything": [1, 2]}),
        };
        let j = serde_json::to_value(&c).unwrap();
        assert_valid(&v, &j, "config");
        assert_eq!(serde_json::from_value::<RunConfig>(j).unwrap(), c);
    }

    // projection inputs: every boundary kind, every weight form, every scheme and solver
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("one.mcap");
    let cfg = CavityConfig::default().with(|c| c.n = 8);
    let mut sim = cavity::build(&cfg).unwrap();
    sim.projection.capture = true;
    let mut rec = Recorder::create(&path, RecordLevel::Full, 1, &json!({})).unwrap();
    let r = sim.advance().unwrap();
    rec.write_step(&r, &sim).unwrap();
    rec.finish().unwrap();
    let (_, input) = validate_file(&path);
    let base = input.unwrap();
    let v = schema_of("gpm.ProjectionInput");
    let boundaries = [
        BoundarySpec::None,
        BoundarySpec::Periodic {
            periodic: PeriodicSpec {
                lo: vec![0.0, 0.0],
                len: vec![1.0, 1.0],
            },
        },
        base.boundary.clone(),
        BoundarySpec::Custom {
            description: "a user's circular wall".into(),
        },
    ];
    let weights = [
        Weight::CubicSpline,
        Weight::WendlandC2,
        Weight::WendlandC4,
        Weight::Poly { p: 2, m: 3 },
    ];
    let schemes = [
        Scheme::NonIncremental,
        Scheme::Incremental,
        Scheme::Rotational,
    ];
    for (k, b) in boundaries.iter().enumerate() {
        for (l, w) in weights.iter().enumerate() {
            let mut m = base.clone();
            m.boundary = b.clone();
            m.neighbors.weight = *w;
            m.params.scheme = schemes[(k + l) % 3];
            m.params.solve.solver = solvers[l % 3];
            m.params.source_ghosts = [
                gpm::record::schema::GhostContinuation::Mirror,
                gpm::record::schema::GhostContinuation::Velocity,
                gpm::record::schema::GhostContinuation::RestWalls,
            ][(k + l) % 3];
            let j = serde_json::to_value(&m).unwrap();
            assert_valid(&v, &j, &format!("projection input {k} {l}"));
            assert_eq!(serde_json::from_value::<ProjectionInput>(j).unwrap(), m);
        }
    }
    // a custom boundary is recorded but cannot be rebuilt: a typed error names it
    let err = boundaries[3]
        .build::<2>()
        .err()
        .expect("a custom boundary is not rebuilt");
    assert!(err.to_string().contains("a user's circular wall"), "{err}");
}

#[test]
fn schemas_reject_what_the_types_reject() {
    let v = schema_of("gpm.StepDiagnostics");
    let good = serde_json::to_value(StepDiagnostics::default()).unwrap();
    assert_valid(&v, &good, "default diagnostics");

    let mut missing = good.clone();
    missing.as_object_mut().unwrap().remove("c0");
    assert!(!v.is_valid(&missing));
    assert!(serde_json::from_value::<StepDiagnostics>(missing).is_err());

    let mut extra = good.clone();
    extra["timings"]["bogus"] = json!(1.0);
    assert!(!v.is_valid(&extra));
    assert!(serde_json::from_value::<StepDiagnostics>(extra).is_err());

    let mut bad_enum = good.clone();
    bad_enum["dt_limit"] = json!("sometimes");
    assert!(!v.is_valid(&bad_enum));
    assert!(serde_json::from_value::<StepDiagnostics>(bad_enum).is_err());

    let mut bad_type = good;
    bad_type["step"] = json!(-1);
    assert!(!v.is_valid(&bad_type));
    assert!(serde_json::from_value::<StepDiagnostics>(bad_type).is_err());

    // a point cloud needs its base64 data and typed fields
    let v = schema_of("foxglove.PointCloud");
    let cloud = serde_json::to_value(gpm::record::schema::PointCloud::from_particles::<2>(
        1.5,
        &[[0.0, 1.0]],
        &[[2.0, 3.0]],
        &[4.0],
        &[gpm::particles::Role::Fluid],
    ))
    .unwrap();
    assert_valid(&v, &cloud, "point cloud");
    assert_eq!(cloud["timestamp"], json!({"sec": 1, "nsec": 500_000_000}));
    let mut bad = cloud;
    bad["fields"][0]["type"] = json!(9);
    assert!(!v.is_valid(&bad));
}

/// Writes sample recordings for the Python interoperability check in `.ci/run`:
/// `GPM_INTEROP_OUT=DIR cargo test --release --test record_schema -- --ignored write_interop_samples`
/// (a full-level cavity with projection inputs, and a Taylor–Green run with uncompressed chunks).
#[test]
#[ignore]
fn write_interop_samples() {
    let dir = std::path::PathBuf::from(
        std::env::var_os("GPM_INTEROP_OUT").expect("set GPM_INTEROP_OUT to a directory"),
    );
    std::fs::create_dir_all(&dir).unwrap();
    let cfg = CavityConfig::default().with(|c| {
        c.n = 12;
        c.t_end = 1.0;
    });
    let mut sim = cavity::build(&cfg).unwrap();
    sim.projection.capture = true;
    let mut rec = Recorder::create(
        dir.join("cavity_full.mcap"),
        RecordLevel::Full,
        2,
        &json!({"scene": "cavity", "config": &cfg}),
    )
    .unwrap();
    for _ in 0..6 {
        let r = sim.advance().unwrap();
        rec.write_step(&r, &sim).unwrap();
    }
    rec.finish().unwrap();
    let cfg = TaylorGreenConfig::default().with(|c| {
        c.n = 12;
        c.t_end = 0.3;
    });
    let options = gpm::record::RecorderOptions {
        compression: gpm::record::ChunkCompression::None,
        ..gpm::record::RecorderOptions::new(RecordLevel::Diagnostics, 10)
    };
    let mut rec =
        Recorder::create_with(dir.join("tg_uncompressed.mcap"), options, &json!({})).unwrap();
    taylor_green::run(&cfg, |r, sim| Ok(rec.write_step(r, sim)?)).unwrap();
    rec.finish().unwrap();
}
