//! Plugging the GPM projection into your own particle loop.
//!
//! The caller owns the particles and the time loop; gpm supplies the neighbour list and the
//! projection. This loop advects the particles itself (Lagrangian, forward Euler) and asks gpm only
//! to predict, to project on the moved configuration and to report:
//!
//! ```text
//! for each step:
//!     nl.update(&x)                                  // neighbours at xⁿ
//!     step.predict(&mut particles, &nl, .., dt, Some(&my_forces), &mut u_star)
//!     x += dt · u*                                   // your advection
//!     nl.update(&x)                                  // neighbours at x*
//!     report = step.project(&mut particles, &nl, .., dt, &u_star)
//! ```
//!
//! The flow is a Taylor–Green vortex in a periodic box with a user-supplied drag force, run for a
//! short time; each step prints the projection's diagnostics.
//!
//! With `--out DIR` the loop also records `DIR/run.mcap` through [`Recorder::record`]: the
//! diagnostics of every step, and every 5 steps a particle snapshot and the projection's inputs
//! (the loop turns the projection's capture on at those steps). `gpm replay DIR/run.mcap`
//! summarises it, `gpm replay --rerun` re-runs the recorded projections; nothing of this needs
//! gpm's own driver.
//!
//! ```text
//! cargo run --release --example own_loop
//! cargo run --release --example own_loop -- --out DIR
//! ```

use gpm::boundary::PeriodicBox;
use gpm::geometry::{lattice, number_density_volumes};
use gpm::kernel::Weight;
use gpm::neighbors::{NeighborConfig, NeighborList, Periodicity};
use gpm::particles::{Particles, Role};
use gpm::projection::{ProjectionParams, ProjectionStep, Scheme, StepReport};
use gpm::record::schema::ToBoundarySpec;
use gpm::record::{
    ProjectionRecord, RecordLevel, RecordSummary, Recorder, StepContext, StepRecord,
};
use std::f64::consts::PI;
use std::path::Path;

/// The loop's settings: recorded verbatim as the file's `/config`.
#[derive(Clone, Copy, Debug, serde::Serialize, serde::Deserialize, PartialEq)]
pub struct LoopConfig {
    /// Particles per side.
    pub n: usize,
    /// Steps.
    pub steps: usize,
    /// Time step.
    pub dt: f64,
    /// Linear drag coefficient of the user's force `-drag u`.
    pub drag: f64,
}

impl LoopConfig {
    /// `n` particles per side, `steps` steps of `Δt = 0.002`, drag 0.1.
    pub fn new(n: usize, steps: usize) -> Self {
        LoopConfig {
            n,
            steps,
            dt: 0.002,
            drag: 0.1,
        }
    }
}

/// Runs the user loop for `cfg` and records it to `path` (level `full`, a snapshot and a
/// projection input every `every` steps); returns every report and what the recorder wrote.
pub fn recorded_loop(
    cfg: &LoopConfig,
    path: &Path,
    every: u64,
) -> Result<(Vec<StepReport>, RecordSummary), gpm::Error> {
    let mut rec = Recorder::create(path, RecordLevel::Full, every, cfg)?;
    let reports = user_loop(cfg, Some(&mut rec))?;
    Ok((reports, rec.finish()?))
}

/// Runs the user loop for `cfg`, recording each step when a recorder is given, and returns
/// every report.
pub fn user_loop(
    cfg: &LoopConfig,
    mut rec: Option<&mut Recorder>,
) -> Result<Vec<StepReport>, gpm::Error> {
    let n = cfg.n;
    let dx = 1.0 / n as f64;
    let periodic = Periodicity::all([0.0, 0.0], [1.0, 1.0]);
    let boundary = PeriodicBox { periodic };
    // the user's particles
    let mut particles = Particles::<2>::new();
    for x in lattice([0.0, 0.0], [1.0, 1.0], dx) {
        let (s2x, c2x) = (2.0 * PI * x[0]).sin_cos();
        let (s2y, c2y) = (2.0 * PI * x[1]).sin_cos();
        particles.push(x, [-c2x * s2y, s2x * c2y], 0.0, dx * dx, Role::Fluid);
    }
    // gpm's neighbour list, with a skin so that most updates only re-measure pairs
    let mut nl = NeighborList::build(
        NeighborConfig::new_relative(Weight::WendlandC2, dx, 3.0, 0.3).with_periodicity(periodic),
        &particles.x,
    )?;
    let mut params = ProjectionParams::<2>::new(0.01);
    params.scheme = Scheme::Incremental;
    let mut step = ProjectionStep::<2>::new();
    let (dt, drag) = (cfg.dt, cfg.drag);
    let mut reports = Vec::new();
    let mut u_star = Vec::new();
    for k in 1..=cfg.steps as u64 {
        // capture the projection's inputs only where the recorder takes a snapshot
        let snapshot = rec.as_ref().is_some_and(|r| r.wants_snapshot(k));
        step.capture = snapshot;
        nl.update(&particles.x)?;
        particles.vol = number_density_volumes(&nl);
        // the user's own force: linear drag
        let forces: Vec<[f64; 2]> = particles
            .u
            .iter()
            .map(|u| [-drag * u[0], -drag * u[1]])
            .collect();
        let prediction = step.predict(
            &mut particles,
            &nl,
            &boundary,
            &params,
            dt,
            Some(&forces),
            &mut u_star,
        )?;
        // the user's own advection with the predictor velocity, then periodic wrap
        for (x, u) in particles.x.iter_mut().zip(&u_star) {
            x[0] += dt * u[0];
            x[1] += dt * u[1];
            periodic.wrap(x);
        }
        nl.update(&particles.x)?;
        particles.vol = number_density_volumes(&nl);
        let mut report = step.project(&mut particles, &nl, &boundary, &params, dt, &u_star)?;
        prediction.add_to(&mut report);
        if let Some(rec) = rec.as_mut() {
            let boundary = boundary.to_spec();
            let projection =
                step.captured
                    .as_ref()
                    .filter(|_| snapshot)
                    .map(|capture| ProjectionRecord {
                        capture,
                        neighbors: nl.config(),
                        boundary: &boundary,
                        params: &params,
                    });
            rec.record(&StepRecord {
                context: StepContext::new(k, k as f64 * dt, params.allowed_floating),
                report: &report,
                particles: snapshot.then(|| (&particles).into()),
                projection,
            })?;
        }
        reports.push(report);
    }
    Ok(reports)
}

/// `--out DIR` from the command line, if given.
fn out_dir() -> Result<Option<std::path::PathBuf>, String> {
    let mut args = std::env::args().skip(1);
    let mut out = None;
    while let Some(a) = args.next() {
        match a.as_str() {
            "--out" => out = Some(args.next().ok_or("--out needs a directory")?.into()),
            _ => {
                return Err(format!(
                    "unknown argument '{a}' (usage: own_loop [--out DIR])"
                ))
            }
        }
    }
    Ok(out)
}

fn main() {
    let out = match out_dir() {
        Ok(out) => out,
        Err(e) => {
            eprintln!("error: {e}");
            std::process::exit(2);
        }
    };
    let cfg = LoopConfig::new(40, 20);
    let result = match &out {
        None => user_loop(&cfg, None),
        Some(dir) => std::fs::create_dir_all(dir)
            .map_err(|e| gpm::record::RecordError::Io {
                path: dir.clone(),
                source: e,
            })
            .map_err(gpm::Error::from)
            .and_then(|()| recorded_loop(&cfg, &dir.join("run.mcap"), 5))
            .map(|(reports, summary)| {
                println!(
                    "recorded {} steps to {} ({} bytes)",
                    summary.steps,
                    dir.join("run.mcap").display(),
                    summary.bytes
                );
                for note in &summary.notes {
                    println!("note: {note}");
                }
                reports
            }),
    };
    match result {
        Ok(reports) => {
            println!(
                "{:>4} {:>12} {:>12} {:>8} {:>10} {:>10}",
                "step", "div before", "div after", "c0", "ratio", "KE"
            );
            for (k, r) in reports.iter().enumerate() {
                println!(
                    "{:>4} {:>12.3e} {:>12.3e} {:>8.4} {:>10.3e} {:>10.5}",
                    k + 1,
                    r.div_before,
                    r.div_after,
                    r.c0,
                    r.stability_ratio,
                    r.kinetic_energy
                );
            }
        }
        Err(e) => {
            eprintln!("error: {e}");
            std::process::exit(1);
        }
    }
}

#[cfg(test)]
mod tests {
    #[test]
    fn the_user_loop_runs_and_projects() {
        let reports = super::user_loop(&super::LoopConfig::new(24, 10), None).unwrap();
        assert_eq!(reports.len(), 10);
        let ke0 = reports[0].kinetic_energy;
        for r in &reports {
            assert!(
                r.stability_ratio <= 1.0,
                "Theorem 4.5 ratio {}",
                r.stability_ratio
            );
            assert!(r.div_after < r.div_before, "{r:?}");
            assert_eq!(r.connectivity.floating, 1);
            // viscosity and drag only dissipate
            assert!(r.kinetic_energy <= ke0 * 1.0001);
        }
    }
}
