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
//! ```text
//! cargo run --release --example own_loop
//! ```

use gpm::boundary::PeriodicBox;
use gpm::geometry::{lattice, number_density_volumes};
use gpm::kernel::Weight;
use gpm::neighbors::{NeighborConfig, NeighborList, Periodicity};
use gpm::particles::{Particles, Role};
use gpm::projection::{ProjectionParams, ProjectionStep, Scheme, StepReport};
use std::f64::consts::PI;

/// Runs `steps` steps of the user loop and returns every report.
fn user_loop(n: usize, steps: usize) -> Result<Vec<StepReport>, gpm::Error> {
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
    let dt = 0.002;
    let drag = 0.1;
    let mut reports = Vec::new();
    let mut u_star = Vec::new();
    for _ in 0..steps {
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
        reports.push(report);
    }
    Ok(reports)
}

fn main() {
    match user_loop(40, 20) {
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
        let reports = super::user_loop(24, 10).unwrap();
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
