//! Per-step cost of the projection and the flow around it, stage by stage.
//!
//! ```text
//! cargo run --release --example bench -- --quick          # ≤ 2 minutes
//! cargo run --release --example bench -- --out results/bench
//! ```
//!
//! Each configuration runs in a child process (so that its peak memory, `VmHWM`, is its own):
//! a periodic Taylor–Green flow (2D: `u = −cos 2πx sin 2πy, v = sin 2πx cos 2πy`; 3D:
//! `u = sin 2πx cos 2πy cos 2πz, v = −cos 2πx sin 2πy cos 2πz, w = 0`) with N particles, in
//! three frames: `fixed` (particles do not move: everything that depends only on positions can be
//! reused), `moving` (Lagrangian: the neighbour pairs are re-measured, volumes and matrix
//! values change every step; the pure Lagrangian frame on the exact lattice, no shifting) and
//! `shifted` (Lagrangian as the Taylor–Green scene runs it: the lattice jittered by
//! [`LAGRANGIAN_JITTER`] Δx, seeded, and the default shifting — the pair repulsion with its
//! Taylor correction of `u` and `p`). The pure frame is the moving step's bare cost but not a
//! run anyone can make: on the exact lattice the vortex's strain closes the rows, and at 2D 10⁵
//! the Poisson source grows by ×1.3–1.5 a step from about step 70 on (`|b|` 1.4·10⁻³ at step 70,
//! 1.1·10⁻¹ at step 100, 2.5·10² at step 140; its AMG-CG iterations 3 → 9 → 18) — the
//! README's *pure Lagrangian frame fails early*. After warm-up steps, the mean time per step of
//! each stage is written to `steps.csv` (`d,n_particles,frame,solver,reuse,threads,stage,seconds_per_step`),
//! together with the peak memory, and a table is printed. The cavity reuse comparison runs the
//! n = 100 cavity with every reuse switched on and off. The SpMV bandwidth of each case's Poisson
//! matrix is compared with a stream copy measured in the same process (`spmv.csv`:
//! `d,n_particles,frame,solver,reuse,threads,matrix_mb,spmv_gbs,copy_gbs,ratio`). The growth of the time per step
//! with N (the exponent of a least-squares power law per dimension and frame) is written to
//! `scaling.csv`. The switch study (full run only) flips each reuse switch of a moving step
//! alone against the defaults on the moving and the shifted 2D 10⁵ cases (`switches.csv`).

use anyhow::{bail, Context, Result};
use clap::Parser;
use gpm::boundary::PeriodicBox;
use gpm::flow::{FlowParams, Integrator, Motion, Shifting, Simulation, TimeStepLimits, VolumeRule};
use gpm::geometry::{jitter, lattice};
use gpm::kernel::Weight;
use gpm::neighbors::{NeighborConfig, Periodicity};
use gpm::particles::{Particles, Role};
use gpm::poisson::{SolveParams, SolverKind};
use gpm::projection::{ProjectionParams, Scheme};
use gpm::record::{RecordLevel, Recorder};
use gpm::scene::cavity;
use gpm::scene::taylor_green::{TaylorGreen, LAGRANGIAN_JITTER};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::f64::consts::PI;
use std::io::Write;
use std::path::PathBuf;
use std::process::Command;
use std::time::Instant;

#[derive(Parser, Debug, Clone)]
#[command(about = "Stage-by-stage cost of a gpm step, solvers, reuse, threads and memory")]
struct Args {
    /// A CI-sized subset (≤ 2 minutes).
    #[arg(long)]
    quick: bool,
    /// Output directory for steps.csv.
    #[arg(long, default_value = "results/bench")]
    out: PathBuf,
    /// Steps run before the timed ones in every Taylor–Green case. The flow starts with
    /// `p = 0`: its first steps build the pressure up, and the warm start of the Poisson solve
    /// (the last increments extrapolated in time) settles only after about 15 steps; a larger
    /// value times the settled steps a long run is made of.
    #[arg(long, default_value_t = 3)]
    warmup: usize,
    /// Run only the reuse-switch study (`switches.csv`), with this many alternated pairs per
    /// switch (the full run takes two).
    #[arg(long)]
    switches: Option<usize>,
    /// Run one configuration and print its JSON (used by the parent process).
    #[arg(long, hide = true)]
    child: Option<String>,
}

/// How the particles move (module docs).
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
enum Frame {
    /// Particles do not move.
    Fixed,
    /// The pure Lagrangian frame on the exact lattice, no shifting.
    Moving,
    /// The Lagrangian Taylor–Green's particles as its scene moves them (jitter and the default
    /// shifting), with the GPM operators of the other frames (the scene's own moving runs take
    /// the consistent ones, which cost more: README, Performance).
    Shifted,
}

impl std::fmt::Display for Frame {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.pad(match self {
            Frame::Fixed => "fixed",
            Frame::Moving => "moving",
            Frame::Shifted => "shifted",
        })
    }
}

/// One configuration.
#[derive(Clone, Debug, Serialize, Deserialize)]
struct Case {
    d: usize,
    n_particles: usize,
    frame: Frame,
    solver: SolverKind,
    reuse: bool,
    threads: usize,
    steps: usize,
    warmup: usize,
    /// One reuse switch set against its default ([`SWITCHES`]; none: the defaults).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    flip: Option<String>,
}

/// The reuse switches of a moving step, each flipped alone against the defaults by the switch
/// study (`switches.csv`): name, whether it is on by default, what it saves.
const SWITCHES: [(&str, bool, &str); 13] = [
    (
        "skin",
        true,
        "neighbour candidates kept between searches (skin 0.3h; off: 0)",
    ),
    (
        "warm_start",
        true,
        "Poisson and viscous CG start from extrapolated solutions",
    ),
    (
        "amg_lag",
        true,
        "AMG hierarchy kept while the iteration rate holds",
    ),
    (
        "amg_reuse_values",
        false,
        "AMG refresh by Galerkin products on the kept aggregates",
    ),
    (
        "amg_reuse_aggregates",
        true,
        "AMG aggregates kept when the pattern changes",
    ),
    (
        "reuse_diagnostics",
        true,
        "connectivity and c0 kept while the pair set holds",
    ),
    (
        "pattern_keep_pairs",
        true,
        "Poisson pattern (and its id) kept while the pairs within h hold",
    ),
    (
        "keep_pressure_gradient",
        true,
        "trapezoidal term's ∇pⁿ⁺¹ taken with ∇φ in the correction's pass",
    ),
    (
        "fused_shift",
        true,
        "shift's Taylor gradients and velocity range taken in the shift's own pass",
    ),
    (
        "pattern_reuse",
        false,
        "Poisson pattern of the candidate pairs, kept until the next search",
    ),
    (
        "amg_single_precision",
        true,
        "AMG V-cycle reads f32 copies of its matrices' values",
    ),
    (
        "viscous_adaptive",
        true,
        "viscous tolerance loosened up to rel_tol where the pressure's warm start is poor",
    ),
    (
        "warm_tol",
        false,
        "Poisson CG stops at 10⁻³ of its warm start's residual (solve.warm_tol; off: rel_tol alone)",
    ),
];

/// The warm-start factor the switch study sets ([`SolveParams::warm_tol`]).
const WARM_TOL: f64 = 1e-3;

impl Case {
    /// The columns that name the case in the CSV files: `d,n_particles,frame,solver,reuse,threads`.
    fn csv_key(&self) -> String {
        format!(
            "{},{},{},{},{},{}",
            self.d, self.n_particles, self.frame, self.solver, self.reuse, self.threads
        )
    }
}

/// One configuration's result.
#[derive(Clone, Debug, Serialize, Deserialize)]
struct Outcome {
    case: Case,
    stages: Vec<(String, f64)>,
    total: f64,
    peak_mb: f64,
    poisson_iters: f64,
    spmv_gbs: f64,
    /// Bytes one SpMV reads and writes (MB): matrix entries, column indices, three vectors.
    spmv_mb: f64,
    copy_gbs: f64,
}

fn peak_mb() -> f64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines().find(|l| l.starts_with("VmHWM:")).and_then(|l| {
                l.split_whitespace()
                    .nth(1)
                    .and_then(|v| v.parse::<f64>().ok())
            })
        })
        .map(|kb| kb / 1024.0)
        .unwrap_or(f64::NAN)
}

fn solve_params(solver: SolverKind, reuse: bool) -> SolveParams {
    SolveParams {
        solver,
        rel_tol: 1e-8,
        warm_start: reuse,
        reuse_symbolic: reuse,
        reuse_numeric: reuse,
        reuse_values: reuse,
        ..Default::default()
    }
}

fn periodic_sim<const D: usize>(c: &Case) -> Result<Simulation<D, PeriodicBox<D>>> {
    let side = (c.n_particles as f64).powf(1.0 / D as f64).round() as usize;
    let dx = 1.0 / side as f64;
    let shifted = c.frame == Frame::Shifted;
    let mut xs = lattice([0.0; D], [1.0; D], dx);
    if shifted {
        jitter(&mut xs, LAGRANGIAN_JITTER * dx, TaylorGreen::default().seed);
    }
    let mut p = Particles::<D>::new();
    for x in xs {
        let (s0, c0) = (2.0 * PI * x[0]).sin_cos();
        let (s1, c1) = (2.0 * PI * x[1]).sin_cos();
        let u: [f64; D] = if D == 2 {
            std::array::from_fn(|a| if a == 0 { -c0 * s1 } else { s0 * c1 })
        } else {
            let c2 = (2.0 * PI * x[2]).cos();
            std::array::from_fn(|a| match a {
                0 => s0 * c1 * c2,
                1 => -c0 * s1 * c2,
                _ => 0.0,
            })
        };
        p.push(x, u, 0.0, dx.powi(D as i32), Role::Fluid);
    }
    let periodic = Periodicity::all([0.0; D], [1.0; D]);
    let mut projection = ProjectionParams::<D>::new(0.01);
    projection.scheme = Scheme::Rotational;
    projection.solve = solve_params(c.solver, c.reuse);
    projection.reuse_diagnostics = c.reuse;
    let mut skin = if c.reuse { 0.3 } else { 0.0 };
    match c.flip.as_deref() {
        None => {}
        Some("skin") => skin = 0.0,
        Some("warm_start") => projection.solve.warm_start = false,
        Some("amg_lag") => projection.solve.amg_lag = false,
        Some("amg_reuse_values") => projection.solve.amg_reuse_values = true,
        Some("amg_reuse_aggregates") => projection.solve.amg_reuse_aggregates = false,
        Some("reuse_diagnostics") => projection.reuse_diagnostics = false,
        Some("pattern_reuse") => projection.solve.pattern_within_h = false,
        Some("pattern_keep_pairs") => projection.solve.pattern_keep_pairs = false,
        Some("viscous_adaptive") => projection.solve.viscous_adaptive = false,
        Some("warm_tol") => projection.solve.warm_tol = WARM_TOL,
        Some("keep_pressure_gradient" | "amg_single_precision" | "fused_shift") => {}
        Some(other) => bail!("unknown switch {other:?}"),
    }
    let moving = c.frame != Frame::Fixed;
    let params = FlowParams {
        projection,
        limits: TimeStepLimits {
            dt_fixed: Some(0.1 * dx),
            ..Default::default()
        },
        motion: if moving {
            Motion::Lagrangian
        } else {
            Motion::Eulerian
        },
        integrator: Integrator::Ab2,
        convection: Default::default(),
        shifting: shifted.then(Shifting::default),
        volumes: VolumeRule::NumberDensity,
        pair_weights: Default::default(),
        dx,
    };
    let config = NeighborConfig::new_relative(Weight::WendlandC2, dx, 3.0, skin);
    let mut sim = Simulation::new(p, PeriodicBox { periodic }, config, params)?;
    match c.flip.as_deref() {
        Some("keep_pressure_gradient") => sim.projection.keep_pressure_gradient = false,
        Some("fused_shift") => sim.fused_shift = false,
        Some("amg_single_precision") => sim.projection.solver.amg.params.single_precision = false,
        _ => {}
    }
    Ok(sim)
}

/// The SpMV bandwidth of `a`, the bytes one SpMV moves (entries, column indices, three vectors)
/// and the memory bandwidth of a parallel copy of `len` doubles (GB/s, read + write), measured
/// in alternation (five rounds, the best of each), so that both see the same state of a machine
/// whose bandwidth drifts. Both run inside the thread pool, the SpMV ten times back to back as
/// CG runs it: a product started from outside the pool would also time the wake-up of its
/// sleeping workers (tens of µs against the 1.2 ms of a 2D 10⁵ product).
fn spmv_and_copy(a: &gpm::poisson::Assembly, len: usize) -> (f64, f64, f64) {
    let x = vec![1.0; a.n()];
    let mut y = vec![0.0; a.n()];
    let src = vec![1.0f64; len];
    let mut dst = vec![0.0f64; len];
    let (mut best_spmv, mut best_copy) = (f64::INFINITY, f64::INFINITY);
    gpm::math::in_pool(|| {
        a.spmv(&x, &mut y);
        for _ in 0..5 {
            let t = Instant::now();
            for _ in 0..10 {
                a.spmv(&x, &mut y);
            }
            best_spmv = best_spmv.min(t.elapsed().as_secs_f64() / 10.0);
            let t = Instant::now();
            dst.par_iter_mut()
                .zip(src.par_iter())
                .with_min_len(1 << 14)
                .for_each(|(d, s)| *d = *s);
            best_copy = best_copy.min(t.elapsed().as_secs_f64());
        }
    });
    std::hint::black_box((&y, &dst));
    let bytes = a.nnz() as f64 * 12.0 + a.n() as f64 * 24.0;
    (
        bytes / best_spmv / 1e9,
        bytes,
        16.0 * len as f64 / best_copy / 1e9,
    )
}

fn run_case<const D: usize>(c: &Case) -> Result<Outcome> {
    let mut sim = periodic_sim::<D>(c)?;
    let dir = std::env::temp_dir().join(format!("gpm_bench_{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    let mut rec = Recorder::create(
        dir.join("bench.mcap"),
        RecordLevel::Diagnostics,
        10,
        &serde_json::json!({"bench": c}),
    )?;
    let names = [
        "neighbors",
        "operators",
        "assembly",
        "solve",
        "correction",
        "diagnostics",
        "recording",
        "other",
    ];
    let mut acc = [0.0f64; 8];
    let mut total = 0.0;
    let mut iters = 0.0;
    for k in 0..c.warmup + c.steps {
        if !c.reuse {
            sim.invalidate_neighbors();
        }
        let t0 = Instant::now();
        let r = sim.advance()?;
        let tr = Instant::now();
        rec.write_step(&r, &sim)?;
        let rec_s = tr.elapsed().as_secs_f64();
        let wall = t0.elapsed().as_secs_f64();
        if k < c.warmup {
            continue;
        }
        let p = &r.projection;
        let v = &p.viscous.unwrap_or_default();
        let assembly = p.solve.assemble_seconds + v.assemble_seconds;
        let solve = p.solve.symbolic_seconds
            + p.solve.numeric_seconds
            + p.solve.solve_seconds
            + v.symbolic_seconds
            + v.numeric_seconds
            + v.solve_seconds;
        let viscous_total =
            v.assemble_seconds + v.symbolic_seconds + v.numeric_seconds + v.solve_seconds;
        let operators = (p.timings.predictor - viscous_total).max(0.0) + p.timings.source;
        let stages = [
            r.neighbors_seconds,
            operators,
            assembly,
            solve,
            p.timings.correction,
            p.timings.diagnostics,
            rec_s,
            0.0,
        ];
        let known: f64 = stages.iter().sum();
        for i in 0..7 {
            acc[i] += stages[i];
        }
        acc[7] += (wall - known).max(0.0);
        total += wall;
        iters += p.solve.iters as f64;
    }
    rec.finish()?;
    let _ = std::fs::remove_dir_all(&dir);
    let m = c.steps as f64;
    // peak memory of the run, before the bandwidth measurement allocates its arrays
    let peak = peak_mb();
    // SpMV bandwidth on the Poisson matrix just used, against a copy of 2 × 256 MB (far larger
    // than the caches, so the memory bandwidth)
    let a = &sim.projection.solver.assembly;
    let (spmv_gbs, bytes, copy_gbs) = spmv_and_copy(a, 1 << 25);
    Ok(Outcome {
        case: c.clone(),
        stages: names
            .iter()
            .zip(acc)
            .map(|(n, s)| (n.to_string(), s / m))
            .collect(),
        total: total / m,
        peak_mb: peak,
        poisson_iters: iters / m,
        spmv_gbs,
        spmv_mb: bytes / 1e6,
        copy_gbs,
    })
}

fn child(spec: &str) -> Result<()> {
    // (an unknown frame is refused by name: "unknown variant")
    let c: Case = serde_json::from_str(spec).context("child spec")?;
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(c.threads)
        .build()
        .context("thread pool")?;
    let o = pool.install(|| match c.d {
        2 => run_case::<2>(&c),
        3 => run_case::<3>(&c),
        d => bail!("dimension {d}"),
    })?;
    println!("{}", serde_json::to_string(&o)?);
    Ok(())
}

fn spawn(c: &Case) -> Result<Outcome> {
    let exe = std::env::current_exe()?;
    let out = Command::new(exe)
        .arg("--child")
        .arg(serde_json::to_string(c)?)
        .output()
        .context("spawning a benchmark child")?;
    if !out.status.success() {
        bail!(
            "case {:?} failed: {}",
            c,
            String::from_utf8_lossy(&out.stderr).trim()
        );
    }
    let line = String::from_utf8_lossy(&out.stdout);
    serde_json::from_str(line.trim()).context("child output")
}

fn main_inner(a: Args) -> Result<()> {
    if let Some(spec) = &a.child {
        return child(spec);
    }
    std::fs::create_dir_all(&a.out)?;
    if a.switches.is_some() {
        return switches(&a);
    }
    let mut cases = Vec::new();
    let case = |d, n, frame, solver, reuse, threads, steps| Case {
        d,
        n_particles: n,
        frame,
        solver,
        reuse,
        threads,
        steps,
        warmup: a.warmup,
        flip: None,
    };
    if a.quick {
        for frame in [Frame::Fixed, Frame::Moving] {
            cases.push(case(2, 10_000, frame, SolverKind::Auto, true, 2, 10));
            cases.push(case(2, 10_000, frame, SolverKind::Auto, false, 2, 5));
        }
        cases.push(case(
            2,
            10_000,
            Frame::Shifted,
            SolverKind::Auto,
            true,
            2,
            10,
        ));
        cases.push(case(2, 10_000, Frame::Moving, SolverKind::Cg, true, 2, 10));
        cases.push(case(2, 10_000, Frame::Fixed, SolverKind::Auto, true, 1, 10));
        cases.push(case(3, 10_000, Frame::Fixed, SolverKind::Auto, true, 2, 5));
    } else {
        for (d, n, steps) in [
            (2, 10_000, 20),
            (2, 100_000, 10),
            (2, 1_000_000, 4),
            (3, 10_000, 10),
            (3, 100_000, 4),
        ] {
            for frame in [Frame::Fixed, Frame::Moving, Frame::Shifted] {
                cases.push(case(d, n, frame, SolverKind::Auto, true, 2, steps));
            }
        }
        // solver comparison (the AMG iteration counts at 10⁴ and 10⁶ give the scaling),
        // reuse and threads at 10⁵ (2D) and 10⁴ (3D)
        for solver in [SolverKind::Cholesky, SolverKind::Cg, SolverKind::Amg] {
            cases.push(case(2, 100_000, Frame::Moving, solver, true, 2, 6));
        }
        cases.push(case(2, 10_000, Frame::Fixed, SolverKind::Amg, true, 2, 10));
        cases.push(case(2, 10_000, Frame::Moving, SolverKind::Amg, true, 2, 10));
        for solver in [SolverKind::Cg, SolverKind::Cholesky] {
            cases.push(case(3, 10_000, Frame::Moving, solver, true, 2, 6));
        }
        for frame in [Frame::Fixed, Frame::Moving] {
            cases.push(case(2, 100_000, frame, SolverKind::Auto, false, 2, 4));
            cases.push(case(2, 100_000, frame, SolverKind::Auto, true, 1, 6));
        }
    }
    let mut csv = std::fs::File::create(a.out.join("steps.csv"))?;
    writeln!(
        csv,
        "d,n_particles,frame,solver,reuse,threads,stage,seconds_per_step,peak_mb"
    )?;
    println!(
        "Taylor–Green cases: {} warm-up steps, then the timed steps",
        a.warmup
    );
    println!(
        "{:>2} {:>9} {:>7} {:>9} {:>5} {:>3} | {:>8} {:>8} {:>8} {:>8} {:>8} {:>8} {:>8} {:>8} | {:>9} {:>7} {:>6} {:>6} {:>6} {:>5}",
        "d", "N", "frame", "solver", "reuse", "thr", "neigh", "ops", "assem", "solve", "corr", "diag", "rec", "other", "total ms", "MB", "iters", "GB/s", "copy", "%"
    );
    // the SpMV of each case's Poisson matrix against the stream copy of the same process
    let mut spmv_csv = std::fs::File::create(a.out.join("spmv.csv"))?;
    writeln!(
        spmv_csv,
        "d,n_particles,frame,solver,reuse,threads,matrix_mb,spmv_gbs,copy_gbs,ratio"
    )?;
    // (d, frame, N, seconds per step) of the main rows (auto solver, reuse, 2 threads)
    let mut sizes: Vec<(usize, Frame, f64, f64)> = Vec::new();
    for c in &cases {
        match spawn(c) {
            Ok(o) => {
                if c.solver == SolverKind::Auto && c.reuse && c.threads == 2 {
                    sizes.push((c.d, c.frame, c.n_particles as f64, o.total));
                }
                let ms = |k: usize| o.stages[k].1 * 1e3;
                println!(
                    "{:>2} {:>9} {:>7} {:>9} {:>5} {:>3} | {:>8.2} {:>8.2} {:>8.2} {:>8.2} {:>8.2} {:>8.2} {:>8.2} {:>8.2} | {:>9.2} {:>7.0} {:>6.1} {:>6.1} {:>6.1} {:>5.0}",
                    c.d, c.n_particles, c.frame, c.solver.to_string(), c.reuse, c.threads,
                    ms(0), ms(1), ms(2), ms(3), ms(4), ms(5), ms(6), ms(7),
                    o.total * 1e3, o.peak_mb, o.poisson_iters, o.spmv_gbs, o.copy_gbs,
                    100.0 * o.spmv_gbs / o.copy_gbs
                );
                let key = c.csv_key();
                writeln!(
                    spmv_csv,
                    "{key},{:.1},{:.2},{:.2},{:.3}",
                    o.spmv_mb,
                    o.spmv_gbs,
                    o.copy_gbs,
                    o.spmv_gbs / o.copy_gbs
                )?;
                for (stage, s) in &o.stages {
                    writeln!(csv, "{key},{stage},{s:.6e},{:.1}", o.peak_mb)?;
                }
                writeln!(csv, "{key},total,{:.6e},{:.1}", o.total, o.peak_mb)?;
            }
            Err(e) => println!("{:?}: {e:#}", c),
        }
    }
    println!("wrote {}", a.out.join("steps.csv").display());
    scaling(&a, &sizes)?;
    if !a.quick {
        switches(&a)?;
    }
    cavity_reuse(&a)?;
    Ok(())
}

/// Each reuse switch of [`SWITCHES`] flipped alone against the defaults on the moving and the
/// shifted 2D 10⁵ Taylor–Green steps (issue 17: every reuse switch pays on moving particles):
/// the defaults and the flipped run alternated, two of each (`--switches K`: K), the fastest of
/// each kept; printed and written to `switches.csv`
/// (`d,n_particles,frame,switch,default_on,on_ms,off_ms,off_over_on`).
fn switches(a: &Args) -> Result<()> {
    let mut csv = std::fs::File::create(a.out.join("switches.csv"))?;
    writeln!(
        csv,
        "d,n_particles,frame,switch,default_on,on_ms,off_ms,off_over_on"
    )?;
    let rounds = a.switches.unwrap_or(2).max(1);
    // the pure moving step, and the Lagrangian step a user runs (jitter and shifting)
    for frame in [Frame::Moving, Frame::Shifted] {
        let base = Case {
            d: 2,
            n_particles: 100_000,
            frame,
            solver: SolverKind::Auto,
            reuse: true,
            threads: 2,
            steps: 10,
            warmup: a.warmup,
            flip: None,
        };
        println!(
            "reuse switches, each flipped alone (2D 10⁵ {frame}, ms per step, best of {rounds}):"
        );
        for (name, default_on, what) in SWITCHES {
            let flipped = Case {
                flip: Some(name.to_string()),
                ..base.clone()
            };
            let (mut t_default, mut t_flipped) = (f64::INFINITY, f64::INFINITY);
            for _ in 0..rounds {
                t_default = t_default.min(spawn(&base)?.total);
                t_flipped = t_flipped.min(spawn(&flipped)?.total);
            }
            let (on, off) = if default_on {
                (t_default, t_flipped)
            } else {
                (t_flipped, t_default)
            };
            writeln!(
                csv,
                "2,100000,{frame},{name},{default_on},{:.2},{:.2},{:.3}",
                on * 1e3,
                off * 1e3,
                off / on
            )?;
            println!(
                "  {name:<21} on {:7.1}  off {:7.1}  off/on {:5.2}  (default {}; {what})",
                on * 1e3,
                off * 1e3,
                off / on,
                if default_on { "on" } else { "off" }
            );
        }
    }
    println!("wrote {}", a.out.join("switches.csv").display());
    Ok(())
}

/// The exponent `b` of `time per step ∝ N^b` fitted by least squares to `ln t` against `ln N`
/// over the sizes of each dimension and frame (main rows: auto solver, reuse, 2 threads),
/// printed and written to `scaling.csv` (`d,frame,n_min,n_max,sizes,exponent`); issue 17 asks
/// for `b ≤ 1.1` from 10⁴ to 10⁶ in 2D. Nothing with fewer than two sizes (`--quick`).
fn scaling(a: &Args, sizes: &[(usize, Frame, f64, f64)]) -> Result<()> {
    let mut csv = std::fs::File::create(a.out.join("scaling.csv"))?;
    writeln!(csv, "d,frame,n_min,n_max,sizes,exponent")?;
    let mut groups: Vec<(usize, Frame)> = sizes.iter().map(|s| (s.0, s.1)).collect();
    groups.sort();
    groups.dedup();
    for (d, frame) in groups {
        let pts: Vec<(f64, f64)> = sizes
            .iter()
            .filter(|s| s.0 == d && s.1 == frame)
            .map(|s| (s.2.ln(), s.3.ln()))
            .collect();
        if pts.len() < 2 {
            continue;
        }
        let m = pts.len() as f64;
        let (mx, my) = (
            pts.iter().map(|p| p.0).sum::<f64>() / m,
            pts.iter().map(|p| p.1).sum::<f64>() / m,
        );
        let sxx: f64 = pts.iter().map(|p| (p.0 - mx).powi(2)).sum();
        let sxy: f64 = pts.iter().map(|p| (p.0 - mx) * (p.1 - my)).sum();
        if sxx <= 0.0 {
            continue;
        }
        let b = sxy / sxx;
        let n_min = pts.iter().map(|p| p.0.exp()).fold(f64::INFINITY, f64::min);
        let n_max = pts.iter().map(|p| p.0.exp()).fold(0.0, f64::max);
        println!(
            "{d}D {frame}: time per step ∝ N^{b:.3} (least squares over {} sizes, {n_min:.0} to {n_max:.0})",
            pts.len()
        );
        writeln!(
            csv,
            "{d},{frame},{n_min:.0},{n_max:.0},{},{b:.4}",
            pts.len()
        )?;
    }
    println!("wrote {}", a.out.join("scaling.csv").display());
    Ok(())
}

/// Cavity step cost with every reuse switch on and off (neighbour list, matrix values,
/// symbolic and numeric factorisations, warm start, diagnostics cache).
fn cavity_reuse(a: &Args) -> Result<()> {
    let n = if a.quick { 50 } else { 100 };
    let (warmup, steps) = (3, if a.quick { 10 } else { 30 });
    let mut csv = std::fs::File::create(a.out.join("cavity_reuse.csv"))?;
    writeln!(csv, "n,reuse,seconds_per_step,neighbors,assembly,solve")?;
    let mut per_step = [0.0; 2];
    for (k, reuse) in [true, false].into_iter().enumerate() {
        let mut cfg = cavity::CavityConfig::default().with(|c| c.n = n);
        cfg.solve.warm_start = reuse;
        cfg.solve.reuse_symbolic = reuse;
        cfg.solve.reuse_numeric = reuse;
        cfg.solve.reuse_values = reuse;
        let mut sim = cavity::build(&cfg)?;
        sim.params.projection.reuse_diagnostics = reuse;
        let (mut wall, mut neigh, mut assem, mut solve) = (0.0, 0.0, 0.0, 0.0);
        for s in 0..warmup + steps {
            if !reuse {
                sim.invalidate_neighbors();
            }
            let t = Instant::now();
            let r = sim.advance()?;
            let w = t.elapsed().as_secs_f64();
            if s >= warmup {
                let (p, v) = (
                    &r.projection.solve,
                    &r.projection.viscous.unwrap_or_default(),
                );
                wall += w;
                neigh += r.neighbors_seconds;
                assem += p.assemble_seconds + v.assemble_seconds;
                solve += p.symbolic_seconds
                    + p.numeric_seconds
                    + p.solve_seconds
                    + v.symbolic_seconds
                    + v.numeric_seconds
                    + v.solve_seconds;
            }
        }
        let m = steps as f64;
        per_step[k] = wall / m;
        writeln!(
            csv,
            "{n},{reuse},{:.6e},{:.6e},{:.6e},{:.6e}",
            wall / m,
            neigh / m,
            assem / m,
            solve / m
        )?;
        println!(
            "cavity n = {n}, reuse {:>5}: {:7.2} ms/step (neighbours {:.2}, assembly {:.2}, factor+solve {:.2} ms)",
            reuse,
            1e3 * wall / m,
            1e3 * neigh / m,
            1e3 * assem / m,
            1e3 * solve / m
        );
    }
    println!(
        "cavity n = {n}: every reuse off / on = {:.2}x",
        per_step[1] / per_step[0]
    );
    Ok(())
}

fn main() -> std::process::ExitCode {
    match main_inner(Args::parse()) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            std::process::ExitCode::FAILURE
        }
    }
}
