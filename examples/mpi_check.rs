//! The distributed projection against the single-process one (issue 18), under MPI:
//!
//! ```text
//! cargo build --release --features mpi --example mpi_check
//! mpirun -n 4 --oversubscribe target/release/examples/mpi_check [--steps 20] [--tg-n 128]
//!     [--cavity-n 64] [--preconditioner jacobi|block_amg|block_amg_coarse|schwarz|chebyshev]
//!     [--aggregate-size 16] [--chebyshev-degree 2] [--decomposed true]
//!     [--motion eulerian|lagrangian]
//! ```
//!
//! `--motion lagrangian` (with `--decomposed true`) moves the particles: after every step they
//! migrate to the rank whose box holds them, with their carried state, and the halo is built
//! again; the positions are compared too.
//!
//! With `--decomposed true` every rank holds only its own particles and their halo
//! (`gpm::distributed::decomposed::DecomposedRun`: the particle decomposition, both global
//! solves on the ranks' local systems); the own particles' velocities are gathered to rank 0
//! and compared with the single-process run, and each step's global diagnostics with its.
//!
//! For the Taylor–Green vortex and the lid-driven cavity (Eulerian, CG tolerance 1e-12): rank 0
//! runs the scene on its own with the default solver (Cholesky), then every rank runs it with
//! the distributed solve; every step's global diagnostics (components joined through the
//! halo, `c0`, the Theorem 4.5 ratio) are checked against the step's own, and at the end the
//! largest velocity difference to the single-process run must be at most 1e-9 and the
//! connectivity and `c0` of every step identical. Prints one JSON line per scene with the
//! iterations and every rank's message counts and volumes per step. Exits non-zero on a
//! failed check.

use anyhow::{bail, Context, Result};
use gpm::boundary::Boundary;
use gpm::distributed::mpi::{init, MpiComm};
use gpm::distributed::{Comm, DdPreconditioner, DistributedRun};
use gpm::flow::{FlowReport, Motion, Simulation};
use gpm::scene::{cavity, taylor_green};

struct Args {
    steps: u64,
    tg_n: usize,
    cavity_n: usize,
    preconditioner: DdPreconditioner,
    aggregate_size: usize,
    chebyshev_degree: usize,
    /// Each rank holds only its own particles and their halo (`DecomposedRun`).
    decomposed: bool,
    /// The frame of both scenes (moving particles only with `decomposed`).
    motion: Motion,
}

fn args() -> Result<Args> {
    let mut a = Args {
        steps: 20,
        tg_n: 128,
        cavity_n: 64,
        preconditioner: DdPreconditioner::default(),
        aggregate_size: 16,
        chebyshev_degree: 2,
        decomposed: false,
        motion: Motion::Eulerian,
    };
    let v: Vec<String> = std::env::args().skip(1).collect();
    for pair in v.chunks(2) {
        let value = pair.get(1).context("every option takes a value")?;
        match pair[0].as_str() {
            "--steps" => a.steps = value.parse()?,
            "--tg-n" => a.tg_n = value.parse()?,
            "--cavity-n" => a.cavity_n = value.parse()?,
            "--aggregate-size" => a.aggregate_size = value.parse()?,
            "--chebyshev-degree" => a.chebyshev_degree = value.parse()?,
            "--decomposed" => a.decomposed = value.parse()?,
            "--motion" => a.motion = value.parse().map_err(anyhow::Error::msg)?,
            "--preconditioner" => {
                a.preconditioner = serde_json::from_value(serde_json::Value::String(value.clone()))?
            }
            o => bail!("unknown option {o}"),
        }
    }
    if a.motion != Motion::Eulerian && !a.decomposed {
        bail!(
            "--motion {:?} needs --decomposed true (the replicated run is for fixed particles)",
            a.motion
        );
    }
    Ok(a)
}

/// Steps `sim` `steps` times; returns the reports.
fn steps<B: Boundary<2>>(
    sim: &mut Simulation<2, B>,
    n: u64,
    mut each: impl FnMut(&FlowReport, &Simulation<2, B>) -> Result<()>,
) -> Result<Vec<FlowReport>> {
    (0..n)
        .map(|_| {
            let rep = sim.advance()?;
            each(&rep, sim)?;
            Ok(rep)
        })
        .collect()
}

/// The single-process run on rank 0 (its reports and final state), `None` on the others.
fn serial_run<B: Boundary<2>>(
    build: &impl Fn() -> gpm::Result<Simulation<2, B>>,
    a: &Args,
) -> Result<Option<(Vec<FlowReport>, Simulation<2, B>)>> {
    if MpiComm.rank() != 0 {
        return Ok(None);
    }
    let mut sim = build()?;
    let reps = steps(&mut sim, a.steps, |_, _| Ok(()))?;
    Ok(Some((reps, sim)))
}

fn compare<B: Boundary<2>>(
    name: &str,
    build: impl Fn() -> gpm::Result<Simulation<2, B>>,
    a: &Args,
) -> Result<bool> {
    let comm = MpiComm;
    let serial = serial_run(&build, a)?;
    let mut sim = build()?;
    let mut run = DistributedRun::new(comm);
    run.solver().preconditioner = a.preconditioner;
    run.solver().aggregate_size = a.aggregate_size;
    run.solver().chebyshev_degree = a.chebyshev_degree;
    run.install(&mut sim);
    let started = std::time::Instant::now();
    let mut rounds = 0;
    let reps = steps(&mut sim, a.steps, |rep, sim| {
        rounds = rounds.max(run.check_step(rep, sim)?.rounds);
        Ok(())
    })?;
    let seconds = started.elapsed().as_secs_f64();
    let t = run.traffic();
    let per_step = |v: u64| v as f64 / a.steps as f64;
    let (own, halo) = {
        let s = run.solver();
        (s.rows().n_own() as f64, s.rows().halo.len() as f64)
    };
    let mine = [
        per_step(t.messages),
        per_step(t.bytes),
        per_step(t.reductions),
        per_step(t.reduced_values),
        per_step(t.gathered_bytes),
        own,
        halo,
    ];
    let all = comm.all_gather(&mine);
    let Some((sreps, ssim)) = serial else {
        return Ok(true);
    };
    let su = &ssim.particles.u;
    let diff = sim
        .particles
        .u
        .iter()
        .zip(su)
        .flat_map(|(a, b)| [(a[0] - b[0]).abs(), (a[1] - b[1]).abs()])
        .fold(0.0f64, f64::max);
    let same_diagnostics = reps.iter().zip(&sreps).all(|(d, s)| {
        d.projection.connectivity == s.projection.connectivity && d.projection.c0 == s.projection.c0
    });
    let iters: Vec<usize> = reps.iter().map(|r| r.projection.solve.iters).collect();
    let ranks: Vec<serde_json::Value> = all
        .iter()
        .map(|v| {
            serde_json::json!({
                "own": v[5], "halo": v[6], "messages_per_step": v[0], "bytes_per_step": v[1],
                "reductions_per_step": v[2], "reduced_values_per_step": v[3],
                "gathered_bytes_per_step": v[4],
            })
        })
        .collect();
    let ok = diff <= 1e-9 && same_diagnostics;
    println!(
        "{}",
        serde_json::json!({
            "scene": name, "ranks": comm.size(), "steps": a.steps,
            "preconditioner": a.preconditioner, "max_velocity_difference": diff,
            "connectivity_and_c0_identical": same_diagnostics,
            "iterations": iters, "mean_iterations": iters.iter().sum::<usize>() as f64 / iters.len() as f64,
            "label_rounds": rounds, "distributed_seconds": seconds, "per_rank": ranks, "ok": ok,
        })
    );
    Ok(ok)
}

/// [`compare`] for the decomposed run: rank 0 compares the gathered own velocities and every
/// step's global diagnostics with the single-process run.
fn compare_decomposed<B: Boundary<2> + Clone>(
    name: &str,
    build: impl Fn() -> gpm::Result<Simulation<2, B>>,
    a: &Args,
) -> Result<bool> {
    use gpm::distributed::decomposed::DecomposedRun;
    let comm = MpiComm;
    let serial = serial_run(&build, a)?;
    let global = build()?;
    let started = std::time::Instant::now();
    let mut run = DecomposedRun::new(comm, &global)?;
    run.set_preconditioner(a.preconditioner, a.aggregate_size);
    drop(global);
    let (mut t, mut diags, mut iters) = (0.0, Vec::new(), Vec::new());
    for _ in 0..a.steps {
        let rep = run.advance()?;
        diags.push(run.global_diagnostics(rep.time - t));
        iters.push(rep.projection.solve.iters);
        t = rep.time;
    }
    let seconds = started.elapsed().as_secs_f64();
    let p = &run.sim.particles;
    let mine: Vec<f64> = run
        .own_ids()
        .iter()
        .enumerate()
        .flat_map(|(i, &g)| [g as f64, p.u[i][0], p.u[i][1], p.x[i][0], p.x[i][1]])
        .collect();
    let all = comm.all_gather(&mine);
    let counts = run.counts();
    let migrated = comm.sum(&[counts.migrated as f64, counts.rebalances as f64]);
    // the particle decomposition's own traffic (besides the solves'): halo copies received
    // and particles migrated, per rank and step
    let per_step = |v: u64| v as f64 / a.steps as f64;
    let particle_traffic = comm.all_gather(&[
        run.n_halo() as f64,
        per_step(counts.halo_received),
        per_step(counts.migrated),
        (per_step(counts.halo_received) + per_step(counts.migrated)) * run.particle_bytes() as f64,
    ]);
    let Some((sreps, ssim)) = serial else {
        return Ok(true);
    };
    let (su, sx) = (&ssim.particles.u, &ssim.particles.x);
    let fluid = ssim.particles.role.iter().filter(|r| r.is_fluid()).count();
    let mut seen = 0usize;
    let (mut diff, mut dx) = (0.0f64, 0.0f64);
    for rec in all.iter().flat_map(|v| v.chunks_exact(5)) {
        let g = rec[0] as usize;
        diff = diff.max((rec[1] - su[g][0]).abs().max((rec[2] - su[g][1]).abs()));
        dx = dx.max((rec[3] - sx[g][0]).abs().max((rec[4] - sx[g][1]).abs()));
        seen += 1;
    }
    let same_diagnostics = diags.iter().zip(&sreps).all(|(d, s)| {
        d.connectivity == s.projection.connectivity
            && (d.c0 - s.projection.c0).abs() <= 1e-12 * s.projection.c0
    });
    let owned: Vec<f64> = all.iter().map(|v| (v.len() / 5) as f64).collect();
    let ok = diff <= 1e-9 && dx <= 1e-9 && same_diagnostics && seen == fluid;
    println!(
        "{}",
        serde_json::json!({
            "scene": name, "ranks": comm.size(), "steps": a.steps, "decomposed": true,
            "motion": format!("{:?}", a.motion), "max_velocity_difference": diff,
            "max_position_difference": dx, "migrations": migrated[0], "rebalances": migrated[1],
            "particle_traffic_per_rank": particle_traffic.iter().map(|v| serde_json::json!({
                "halo_particles": v[0], "halo_received_per_step": v[1],
                "migrated_per_step": v[2], "particle_bytes_per_step": v[3],
            })).collect::<Vec<_>>(), "particles_compared": seen, "fluid_particles": fluid,
            "connectivity_equal_and_c0_to_1e-12": same_diagnostics,
            "own_particles_per_rank": owned, "distributed_seconds": seconds,
            "mean_iterations": iters.iter().sum::<usize>() as f64 / iters.len().max(1) as f64,
            "iterations": iters, "ok": ok,
        })
    );
    Ok(ok)
}

fn main() -> Result<()> {
    let _universe = init().context("MPI could not be initialised")?;
    let a = args()?;
    let tg = taylor_green::TaylorGreenConfig::default().with(|c| {
        c.n = a.tg_n;
        c.motion = a.motion;
        c.solve.rel_tol = 1e-12;
    });
    let cav = cavity::CavityConfig::default().with(|c| {
        c.n = a.cavity_n;
        c.motion = a.motion;
        c.solve.rel_tol = 1e-12;
        // the moving cavity's volume shift too (its own tolerance, 1e-6 by default)
        if let Some(sh) = c.shifting.as_mut() {
            sh.volume_tol = 1e-12;
        }
    });
    let (ok_tg, ok_cav) = if a.decomposed {
        (
            compare_decomposed("taylor_green", || taylor_green::build(&tg), &a)?,
            compare_decomposed("cavity", || cavity::build(&cav), &a)?,
        )
    } else {
        (
            compare("taylor_green", || taylor_green::build(&tg), &a)?,
            compare("cavity", || cavity::build(&cav), &a)?,
        )
    };
    if !(ok_tg && ok_cav) {
        bail!("the distributed run differs from the single-process one");
    }
    Ok(())
}
