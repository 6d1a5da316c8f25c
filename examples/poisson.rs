//! Manufactured Poisson problems in 2D and 3D: the paper's Dirichlet-band problem
//! `−Δh u = ∇̂h·f̂` on the unit square/cube with `u = Π_a sin²(π x_a)` and `f = −∇u`, on lattice
//! and 0.3Δx-jittered particles, for fixed `h/Δx` (2, 3, 4) and for `h` shrinking like `√Δx`
//! (the regime in which the truncation-error paper proves convergence).
//!
//! ```text
//! cargo run --release --example poisson -- --out results/poisson
//! ```
//! writes `error_vs_n.csv` and prints the observed orders (least-squares slope of log error
//! against log n, sign flipped so that a positive order means convergence).
#![allow(clippy::type_complexity, clippy::needless_range_loop)]

use anyhow::{Context, Result};
use clap::Parser;
use gpm::kernel::Weight;
use gpm::poisson::{PoissonSolver, SolveParams, SolverKind};
use gpm::scene::manufactured::{BandProblem, BandSpec};
use std::io::Write;
use std::path::PathBuf;
use std::time::Instant;

#[derive(Parser, Debug)]
#[command(about = "GPM Poisson solver against manufactured solutions (2D and 3D)")]
struct Args {
    /// Output directory for error_vs_n.csv.
    #[arg(long, default_value = "results/poisson")]
    out: PathBuf,
    /// Reference weight (cubic, wendland2, wendland4, polyP-M).
    #[arg(long, default_value = "wendland2")]
    weight: Weight,
    /// Linear solver (cholesky, cg, auto).
    #[arg(long, default_value = "auto")]
    solver: SolverKind,
    /// Small sizes only (a CI-sized check).
    #[arg(long)]
    quick: bool,
    /// Jitter amplitude as a fraction of Δx for the jittered distribution.
    #[arg(long, default_value_t = 0.3)]
    jitter: f64,
    /// Seed of the jitter.
    #[arg(long, default_value_t = 2024)]
    seed: u64,
}

struct Row {
    d: usize,
    distribution: &'static str,
    regime: String,
    h_over_dx: f64,
    n: usize,
    particles: usize,
    l2_error: f64,
    h01_error: f64,
    seconds: f64,
}

fn solve<const D: usize>(
    n: usize,
    h_over_dx: f64,
    jit: f64,
    args: &Args,
) -> Result<(usize, f64, f64, f64)> {
    let t = Instant::now();
    let spec = BandSpec::new(n, h_over_dx)
        .with_weight(args.weight)
        .jittered(jit, args.seed ^ (n as u64) << 8 ^ D as u64);
    let prob = BandProblem::<D>::build(&spec)?;
    prob.comps.check(0)?;
    let mut phi = vec![0.0; prob.x.len()];
    let mut solver = PoissonSolver::new();
    let params = SolveParams {
        solver: args.solver,
        ..Default::default()
    };
    solver
        .solve(
            &prob.nl,
            &prob.vol,
            &prob.role,
            &prob.comps,
            &prob.rhs,
            &mut phi,
            &params,
        )
        .context("Poisson solve")?;
    let seconds = t.elapsed().as_secs_f64();
    let (l2, h01) = prob.errors(&phi);
    Ok((prob.n_fluid(), l2, h01, seconds))
}

fn order(rows: &[&Row], f: impl Fn(&Row) -> f64) -> f64 {
    // least-squares slope of log(err) against log(n)
    let pts: Vec<(f64, f64)> = rows
        .iter()
        .map(|r| ((r.n as f64).ln(), f(r).ln()))
        .collect();
    let m = pts.len() as f64;
    let mx = pts.iter().map(|p| p.0).sum::<f64>() / m;
    let my = pts.iter().map(|p| p.1).sum::<f64>() / m;
    let sxy: f64 = pts.iter().map(|p| (p.0 - mx) * (p.1 - my)).sum();
    let sxx: f64 = pts.iter().map(|p| (p.0 - mx).powi(2)).sum();
    -sxy / sxx
}

fn main() -> Result<()> {
    let args = Args::parse();
    std::fs::create_dir_all(&args.out).with_context(|| format!("creating {:?}", args.out))?;
    let (ns2, ns3): (Vec<usize>, Vec<usize>) = if args.quick {
        (vec![16, 24, 32], vec![8, 10, 12])
    } else {
        (vec![16, 32, 64, 128, 256], vec![8, 12, 16, 24, 32])
    };
    let mut rows: Vec<Row> = Vec::new();
    for d in [2usize, 3] {
        let ns = if d == 2 { &ns2 } else { &ns3 };
        for (distribution, jit) in [("lattice", 0.0), ("jittered", args.jitter)] {
            let mut regimes: Vec<(String, Box<dyn Fn(usize) -> f64>)> = vec![];
            for r in [2.0, 3.0, 4.0] {
                regimes.push((format!("fixed{r}"), Box::new(move |_n| r)));
            }
            let n0 = ns[0] as f64;
            regimes.push((
                "sqrt".to_string(),
                Box::new(move |n| 2.0 * (n as f64 / n0).sqrt()),
            ));
            for (regime, hr) in &regimes {
                for &n in ns {
                    let h_over_dx = hr(n);
                    let (particles, l2, h01, s) = if d == 2 {
                        solve::<2>(n, h_over_dx, jit, &args)?
                    } else {
                        solve::<3>(n, h_over_dx, jit, &args)?
                    };
                    println!(
                        "d={d} {distribution:8} {regime:8} h/dx={h_over_dx:5.2} n={n:4} N={particles:8} l2={l2:.3e} h01={h01:.3e} {s:.3}s"
                    );
                    rows.push(Row {
                        d,
                        distribution,
                        regime: regime.clone(),
                        h_over_dx,
                        n,
                        particles,
                        l2_error: l2,
                        h01_error: h01,
                        seconds: s,
                    });
                }
            }
        }
    }
    let path = args.out.join("error_vs_n.csv");
    let mut f = std::fs::File::create(&path).with_context(|| format!("creating {path:?}"))?;
    writeln!(
        f,
        "d,distribution,regime,h_over_dx,n,particles,l2_error,h01_error,seconds"
    )?;
    for r in &rows {
        writeln!(
            f,
            "{},{},{},{:.6},{},{},{:.6e},{:.6e},{:.6}",
            r.d,
            r.distribution,
            r.regime,
            r.h_over_dx,
            r.n,
            r.particles,
            r.l2_error,
            r.h01_error,
            r.seconds
        )?;
    }
    println!("\nobserved orders (slope of -log error vs log n):");
    println!(
        "{:>2} {:>9} {:>8} {:>8} {:>8}",
        "d", "dist", "regime", "l2", "h01"
    );
    let mut keys: Vec<(usize, &str, String)> = rows
        .iter()
        .map(|r| (r.d, r.distribution, r.regime.clone()))
        .collect();
    keys.dedup();
    for (d, dist, regime) in keys {
        let sel: Vec<&Row> = rows
            .iter()
            .filter(|r| r.d == d && r.distribution == dist && r.regime == regime)
            .collect();
        println!(
            "{d:>2} {dist:>9} {regime:>8} {:>8.2} {:>8.2}",
            order(&sel, |r| r.l2_error),
            order(&sel, |r| r.h01_error)
        );
    }
    println!("wrote {}", path.display());
    Ok(())
}
