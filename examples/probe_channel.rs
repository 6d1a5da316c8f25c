//! Issue 13 probe: plane Poiseuille flow on fixed jittered particles.
//!
//! Periodic in x, mirror-ghost walls at y = 0 and 1, body force G = 1 along x, ν = 0.1, run to
//! t = 20 (steady), Eulerian frame, AB2, Crank–Nicolson viscosity, number-density volumes,
//! Wendland C2 with h = 3Δx, particles on the cell-centred n × n lattice jittered by F·Δx
//! (seed 7). Prints `max_i |u_x − G y(1−y)/(2ν)| / (G/(8ν))` over the fluid particles.
//!
//! ```text
//! cargo run --release --example probe_channel -- --jitter 0.1 --scheme rotational \
//!     --weights moment [--n 32] [--t 20] [--reg 1e-3] [--precond amg|block_jacobi]
//! ```
//!
//! `--speed` instead times the pair-weight computation alone on the channel's particles: cold,
//! then warm-started after moving every fluid particle by a random `0.05 Δx` (and cold on the
//! moved particles, for comparison).

use gpm::boundary::Walls;
use gpm::flow::{FlowParams, Integrator, Motion, Simulation, TimeStepLimits, VolumeRule};
use gpm::geometry::{jitter, lattice};
use gpm::kernel::Weight;
use gpm::neighbors::NeighborConfig;
use gpm::pair_weights::{MomentPreconditioner, MomentReport, MomentWeights, PairWeights};
use gpm::particles::{Particles, Role};
use gpm::projection::{ProjectionParams, Scheme};
use gpm::setup::{prepare_with, update_with};

fn arg<T: std::str::FromStr>(args: &[String], key: &str, default: T) -> T
where
    T::Err: std::fmt::Debug,
{
    args.iter()
        .position(|a| a == key)
        .and_then(|k| args.get(k + 1))
        .map(|v| v.parse().expect(key))
        .unwrap_or(default)
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    let jit: f64 = arg(&args, "--jitter", 0.1);
    let scheme: Scheme = arg(&args, "--scheme", Scheme::Rotational);
    let weights: PairWeights = arg(&args, "--weights", PairWeights::Plain);
    let n: usize = arg(&args, "--n", 32);
    let t_end: f64 = arg(&args, "--t", 20.0);
    let reg: f64 = arg(&args, "--reg", f64::NAN);
    let precond: String = arg(&args, "--precond", "amg".to_string());
    let dx = 1.0 / n as f64;
    let mut pts = lattice([0.0, 0.0], [1.0, 1.0], dx);
    jitter(&mut pts, jit * dx, 7);
    let mut p = Particles::<2>::new();
    for mut x in pts {
        x[0] = x[0].rem_euclid(1.0);
        x[1] = x[1].clamp(0.05 * dx, 1.0 - 0.05 * dx);
        p.push(x, [0.0, 0.0], 0.0, dx * dx, Role::Fluid);
    }
    let walls = Walls::channel([0.0, 0.0], [1.0, 1.0]);
    if args.iter().any(|a| a == "--speed") {
        return speed(p, walls, n, jit, reg, &precond);
    }
    let (nu, g) = (0.1, 1.0);
    let mut proj = ProjectionParams::<2>::new(nu);
    proj.gravity = [g, 0.0];
    proj.scheme = scheme;
    let limits = TimeStepLimits {
        u_ref: 1.25,
        ..Default::default()
    };
    let params = FlowParams {
        projection: proj,
        limits,
        motion: Motion::Eulerian,
        integrator: Integrator::Ab2,
        convection: Default::default(),
        shifting: None,
        volumes: VolumeRule::NumberDensity,
        pair_weights: PairWeights::Plain,
        dx,
    };
    let nc = NeighborConfig::new_relative(Weight::WendlandC2, dx, 3.0, 0.0);
    let t0 = std::time::Instant::now();
    let mut sim = Simulation::new(p, walls, nc, params)?;
    // the moment solver's parameters first, then the weights on the next refresh
    if reg.is_finite() {
        sim.pair_weights.params.reg_second = reg;
    }
    if precond == "block_jacobi" {
        sim.pair_weights.params.preconditioner = MomentPreconditioner::BlockJacobi;
    }
    sim.params.pair_weights = weights;
    sim.invalidate_neighbors();
    let mut failed = None;
    while sim.time < t_end {
        if let Err(e) = sim.advance() {
            failed = Some(format!("failed at t = {}: {e}", sim.time));
            break;
        }
    }
    let umax = g / (8.0 * nu);
    let mut err: f64 = 0.0;
    for i in 0..sim.particles.len() {
        if !sim.particles.role[i].is_fluid() {
            continue;
        }
        let y = sim.particles.x[i][1];
        let exact = g / (2.0 * nu) * y * (1.0 - y);
        err = err.max((sim.particles.u[i][0] - exact).abs());
    }
    let pw = sim
        .pair_weights
        .last_report()
        .map(|r| {
            format!(
                " | pair weights: newton {} cg {} {:.2}s, 1st {:.1e} 2nd {:.1e} (worst {}), \
                 {} relaxed rows, factors [{:.3}, {:.3}]",
                r.newton,
                r.cg_iters,
                r.seconds,
                r.first_moment,
                r.second_moment,
                r.worst_particle,
                r.regularised_rows,
                r.factor_min,
                r.factor_max
            )
        })
        .unwrap_or_default();
    println!(
        "jitter {jit} {scheme} {weights:?} n {n}: max err/umax {:.3e} steps {} wall {:.2}s{pw}{}",
        err / umax,
        sim.steps,
        t0.elapsed().as_secs_f64(),
        failed.map(|f| format!(" [{f}]")).unwrap_or_default()
    );
    Ok(())
}

fn speed(
    mut p: Particles<2>,
    walls: Walls<2>,
    n: usize,
    jit: f64,
    reg: f64,
    precond: &str,
) -> Result<(), Box<dyn std::error::Error>> {
    let dx = 1.0 / n as f64;
    let mut state = MomentWeights::<2>::default();
    if reg.is_finite() {
        state.params.reg_second = reg;
    }
    if precond == "block_jacobi" {
        state.params.preconditioner = MomentPreconditioner::BlockJacobi;
    }
    let nc = NeighborConfig::new_relative(Weight::WendlandC2, dx, 3.0, 0.3);
    let (vr, mw) = (VolumeRule::NumberDensity, PairWeights::Moment);
    let mut nl = prepare_with(&mut p, &walls, nc, vr, mw, &mut state)?;
    let show = |what: &str, r: &MomentReport| {
        println!(
            "n {n} jitter {jit} {precond} {what}: newton {} cg {} {:.3}s, 1st {:.1e} 2nd {:.1e}, \
             factors [{:.2e}, {:.2e}]",
            r.newton,
            r.cg_iters,
            r.seconds,
            r.first_moment,
            r.second_moment,
            r.factor_min,
            r.factor_max
        )
    };
    show("cold", state.last_report().unwrap());
    let fluid = p.role.iter().filter(|r| r.is_fluid()).count();
    let mut shift = vec![[0.0; 2]; fluid];
    jitter(&mut shift, 0.05 * dx, 99);
    for (x, s) in p.x.iter_mut().zip(&shift) {
        x[0] += s[0];
        x[1] = (x[1] + s[1]).clamp(0.01 * dx, 1.0 - 0.01 * dx);
    }
    update_with(&mut p, &walls, &mut nl, vr, mw, &mut state)?;
    show("warm after 0.05 dx move", state.last_report().unwrap());
    state.reset();
    update_with(&mut p, &walls, &mut nl, vr, mw, &mut state)?;
    show("cold after the move", state.last_report().unwrap());
    Ok(())
}
