//! Operator accuracy study: Imoto's truncation-error experiment (seed 003), Shobuzako et al.'s
//! comparison of classical SPH, GPM and least-squares operators (seed 004), and what a consistent
//! (renormalised) gradient changes inside the projection.
//!
//! ```text
//! cargo run --release --example operator_accuracy -- --quick   # CI-sized, a few seconds
//! cargo run --release --example operator_accuracy              # full study (a few minutes)
//! cargo run --release --example operator_accuracy -- --part imoto,sph
//! ```
//!
//! Parts (`--part`, comma-separated, default all):
//!
//! * `imoto` — unit square, a lattice of spacing `Δx` with every particle moved by a uniform
//!   random offset of up to `jitter·Δx` per axis, volumes `Δx²`, influence radius `h` with
//!   `Δx ∝ h^{1+σ}` (regularity order `σ ∈ {0, 2, 4}`), nine weights (Imoto's `w₁, w₂, w₃` for the
//!   interpolant, the gradient and the Laplacian); relative max-norm errors of `Πh`, `∇h`, `Δh` of
//!   `f = sin πx sin πy` at the particles nearest an `m × m` grid, against `h`, and the observed
//!   rates next to the paper's Table 1. Files: `imoto_errors.csv`, `imoto_rates.csv`,
//!   `imoto_{interp,grad,lap}.png`.
//! * `sph` — Franke's function on the unit square, a lattice jittered by up to `0.3Δx`, fixed
//!   `h/Δx`; E₂ errors of the classical SPH forms, the GPM operators and the least-squares ones,
//!   interior particles (support inside the square) and near-boundary particles separately.
//!   Files: `sph_errors.csv`, `sph_rates.csv`, `sph_{interp,grad,lap}.png`.
//! * `projection` — periodic box; for a lattice, a jittered lattice and a lattice advected by a
//!   Taylor–Green flow: the sum-form divergence of a uniform field, the accuracy of `∇h` and of
//!   the renormalised `∇ᶜ`, and projections of `u* = u_df + ∇q` with the source / correction
//!   pairs (A) `∇̂h·`/`∇h` (today), (B) `∇̂h·`/`∇ᶜ`, (C) `∇̂h·(Bᵀ ·)`/`∇ᶜ`, (D) `∇h·`/`∇h`,
//!   (E) `∇ᶜ·`/`∇ᶜ`: error against the exact projection, the kick given to a divergence-free
//!   field, divergence left, adjointness defect, growth under repeated projection, time.
//!   File: `projection.csv`.
//! * `flows` — `Simulation::advance` in the Lagrangian frame with the projection variants A, B,
//!   C, E (`ProjectionParams::source` and `::gradient`): Taylor–Green step by step and at a fixed time against the CFL number,
//!   and the lid-driven cavity (Re 100) against Ghia et al. Files: `tg_steps.csv`, `flows.csv`.
//! * `weights` — the product's setting (number-density volumes, fixed `h/Δx`): operator errors on
//!   a lattice and on a Taylor–Green-advected lattice for several weights and `h/Δx`, and the
//!   default (Eulerian) cavity at Re 100 against Ghia et al. with its run time. File: `weights.csv`.
//!
//! Timings are wall-clock on a shared 2-core machine: compare them within one run only.

use anyhow::{bail, Context, Result};
use clap::Parser;
use gpm::boundary::Boundary;
use gpm::consistent::*;
use gpm::diagnostics::connectivity;
use gpm::flow::{Motion, Simulation};
use gpm::geometry::{jitter, lattice, number_density_volumes};
use gpm::kernel::Weight;
use gpm::math::norm2;
use gpm::neighbors::{NeighborConfig, NeighborList, Periodicity};
use gpm::operators::*;
use gpm::particles::Role;
use gpm::plot::{line_charts, Chart, Series};
use gpm::poisson::{PoissonSolver, SolveParams};
use rayon::prelude::*;
use std::f64::consts::PI;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

#[derive(Parser, Debug)]
#[command(about = "Operator accuracy study (Imoto; Shobuzako et al.) and the consistent gradient")]
struct Args {
    /// CI-sized run (a few seconds).
    #[arg(long)]
    quick: bool,
    /// Parts to run: imoto, sph, projection, flows, weights, all (comma-separated).
    #[arg(long, default_value = "all")]
    part: String,
    /// Output directory (default results/operator_accuracy, or ..._quick with --quick).
    #[arg(long)]
    out: Option<PathBuf>,
    /// Imoto study: h/Δx at the largest h (0.5), shared by the three regularity orders.
    #[arg(long, default_value_t = 4.0)]
    kappa: f64,
    /// Imoto study: jitter amplitude as a fraction of Δx (per axis).
    #[arg(long, default_value_t = 0.3)]
    imoto_jitter: f64,
    /// Imoto study: evaluation points per side (the particles nearest an m × m grid).
    #[arg(long)]
    eval_points: Option<usize>,
    /// h/Δx of the Shobuzako comparison and of the projection experiment.
    #[arg(long, default_value_t = 3.0)]
    h_ratio: f64,
    /// Flows: cavity particles per side.
    #[arg(long)]
    cavity_n: Option<usize>,
    /// Flows: cavity end time (the run stops earlier once steady).
    #[arg(long)]
    cavity_t_end: Option<f64>,
}

fn main() -> Result<()> {
    let args = Args::parse();
    let out = args.out.clone().unwrap_or_else(|| {
        PathBuf::from(if args.quick {
            "results/operator_accuracy_quick"
        } else {
            "results/operator_accuracy"
        })
    });
    std::fs::create_dir_all(&out).with_context(|| format!("creating {}", out.display()))?;
    let parts: Vec<String> = args
        .part
        .split(',')
        .map(|s| s.trim().to_ascii_lowercase())
        .collect();
    let known = ["imoto", "sph", "projection", "flows", "weights", "all"];
    if let Some(p) = parts.iter().find(|p| !known.contains(&p.as_str())) {
        bail!("unknown part '{p}': expected one of {known:?}");
    }
    let has = |p: &str| parts.iter().any(|q| q == p || q == "all");
    let t0 = Instant::now();
    if has("imoto") {
        imoto::run(&args, &out)?;
    }
    if has("sph") {
        sph::run(&args, &out)?;
    }
    if has("projection") {
        projection::run(&args, &out)?;
    }
    if has("flows") {
        flows::run(&args, &out)?;
    }
    if has("weights") {
        weights::run(&args, &out)?;
    }

    println!(
        "\nwrote {} ({:.1} s in total)",
        out.display(),
        t0.elapsed().as_secs_f64()
    );
    Ok(())
}

/// Least-squares slope of `ln y` against `ln x`.
fn fit_slope(pts: &[(f64, f64)]) -> f64 {
    let p: Vec<(f64, f64)> = pts
        .iter()
        .filter(|(x, y)| *x > 0.0 && *y > 0.0 && y.is_finite())
        .map(|(x, y)| (x.ln(), y.ln()))
        .collect();
    if p.len() < 2 {
        return f64::NAN;
    }
    let m = p.len() as f64;
    let mx = p.iter().map(|v| v.0).sum::<f64>() / m;
    let my = p.iter().map(|v| v.1).sum::<f64>() / m;
    let num: f64 = p.iter().map(|v| (v.0 - mx) * (v.1 - my)).sum();
    let den: f64 = p.iter().map(|v| (v.0 - mx).powi(2)).sum();
    num / den
}

/// Slope between the last two points.
fn last_slope(pts: &[(f64, f64)]) -> f64 {
    let n = pts.len();
    if n < 2 {
        return f64::NAN;
    }
    let (a, b) = (pts[n - 2], pts[n - 1]);
    (b.1 / a.1).ln() / (b.0 / a.0).ln()
}

/// Least-squares slope over the last `k` points (the finest levels).
fn fine_slope(pts: &[(f64, f64)], k: usize) -> f64 {
    fit_slope(&pts[pts.len().saturating_sub(k)..])
}

fn write(path: &Path, text: &str) -> Result<()> {
    std::fs::write(path, text).with_context(|| format!("writing {}", path.display()))
}

fn fmt_rate(r: f64) -> String {
    if r.is_finite() {
        format!("{r:6.2}")
    } else {
        "   n/a".into()
    }
}

// =============================================================================================
// Imoto's experiment (seed 003, §5 and Table 1)
// =============================================================================================
mod imoto {
    use super::*;

    /// A reference weight normalised in 2D.
    #[derive(Clone, Copy, Debug)]
    pub enum Radial {
        /// One of the crate's weights.
        Lib(Weight),
        /// `w̃(s) = −s W'(s)/2` from the cubic B-spline `W`: with it, the GPM gradient and
        /// Laplacian are the classical SPH difference gradient and Brookshaw's Laplacian.
        SplineDerived,
        /// `r^p (1 − r)(c0 + c1 r)`, already normalised; with `∫ w |x|² dx = 0` (Hypothesis 5
        /// with order 4), so it changes sign.
        Fourth { p: i32, c0: f64, c1: f64 },
    }

    impl Radial {
        pub fn eval(&self, r: f64) -> f64 {
            if r >= 1.0 {
                return 0.0;
            }
            match *self {
                Radial::Lib(w) => w.normalisation(2) * w.shape(r),
                Radial::SplineDerived => {
                    let c = Weight::CubicSpline.normalisation(2);
                    -0.5 * r * c * Weight::CubicSpline.dshape(r)
                }
                Radial::Fourth { p, c0, c1 } => r.powi(p) * (1.0 - r) * (c0 + c1 * r),
            }
        }
        pub fn name(&self) -> String {
            match *self {
                Radial::Lib(w) => match w {
                    Weight::Poly { p, m } => format!("r^{p}(1-r)^{m}"),
                    Weight::CubicSpline => "cubic B-spline".into(),
                    other => other.to_string(),
                },
                Radial::SplineDerived => "-sW'(s)/2 (SPH cubic)".into(),
                Radial::Fourth { p, .. } => format!("r^{p}(1-r)(a+br) 4th-order"),
            }
        }
    }

    /// The nine weights: rows interpolant, gradient, Laplacian; columns Imoto's w₁, w₂, w₃.
    ///
    /// * `w₁`: the lowest-order polynomial weight (`(1−r)`), and for the gradient / Laplacian the
    ///   lowest-order one vanishing at 0 to first / second order (Hypothesis 6, Prop. 17):
    ///   `r(1−r)`, `r²(1−r)`;
    /// * `w₂`: the cubic B-spline, and for the derivatives the weight that turns the GPM
    ///   operators into the classical SPH ones with the cubic spline (Appendix A);
    /// * `w₃`: the lowest-order polynomial with `∫ w(|x|) |x|² dx = 0` (Hypothesis 5 with order
    ///   4) and the same vanishing order at 0: `r^p (1−r)(a + b r)` with `(a, b)` from the
    ///   normalisation and the moment condition (closed forms below, checked by quadrature).
    pub fn weights() -> [[Radial; 3]; 3] {
        // p = 0: ∫(1−r)(a+br) r³ = a/20 + b/30 = 0, 2π(a/6 + b/12) = 1
        let a0 = 12.0 / PI;
        // p = 1: a/30 + b/42 = 0, 2π(a/12 + b/20) = 1
        let a1 = 75.0 / (2.0 * PI);
        // p = 2: a/42 + b/56 = 0, 2π(a/20 + b/30) = 1
        let a2 = 90.0 / PI;
        [
            [
                Radial::Lib(Weight::Poly { p: 0, m: 1 }),
                Radial::Lib(Weight::CubicSpline),
                Radial::Fourth {
                    p: 0,
                    c0: a0,
                    c1: -1.5 * a0,
                },
            ],
            [
                Radial::Lib(Weight::Poly { p: 1, m: 1 }),
                Radial::SplineDerived,
                Radial::Fourth {
                    p: 1,
                    c0: a1,
                    c1: -1.4 * a1,
                },
            ],
            [
                Radial::Lib(Weight::Poly { p: 2, m: 1 }),
                Radial::SplineDerived,
                Radial::Fourth {
                    p: 2,
                    c0: a2,
                    c1: -4.0 / 3.0 * a2,
                },
            ],
        ]
    }

    /// `∫_{ℝ²} w(|x|) |x|^k dx` by composite Gauss–Legendre on `[0, 1]` (pieces of width 1/64,
    /// so the cubic spline's breakpoint at ½ is a piece boundary).
    pub fn moment(w: &Radial, k: i32) -> f64 {
        let g = [
            (-0.906_179_845_938_664, 0.236_926_885_056_189_1),
            (-0.538_469_310_105_683_1, 0.478_628_670_499_366_5),
            (0.0, 0.568_888_888_888_888_9),
            (0.538_469_310_105_683_1, 0.478_628_670_499_366_5),
            (0.906_179_845_938_664, 0.236_926_885_056_189_1),
        ];
        let pieces = 64;
        let mut s = 0.0;
        for p in 0..pieces {
            let (a, b) = (p as f64 / pieces as f64, (p + 1) as f64 / pieces as f64);
            for (t, wt) in g {
                let r = 0.5 * (a + b) + 0.5 * (b - a) * t;
                s += 0.5 * (b - a) * wt * w.eval(r) * r.powi(k) * 2.0 * PI * r;
            }
        }
        s
    }

    fn splitmix(mut z: u64) -> u64 {
        z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// The particle of lattice cell `k`: `Δx (k + ½ + ε_k)`, `ε_k` uniform in `[−a, a]²` from a
    /// hash of `(k, seed)`, so the infinite jittered lattice is generated lazily and
    /// reproducibly.
    #[inline]
    fn particle(k: [i64; 2], dx: f64, amp: f64, seed: u64) -> [f64; 2] {
        let h1 = splitmix(seed ^ splitmix((k[0] as u64) ^ splitmix(k[1] as u64).rotate_left(17)));
        let h2 = splitmix(h1);
        let u1 = (h1 >> 11) as f64 / (1u64 << 53) as f64;
        let u2 = (h2 >> 11) as f64 / (1u64 << 53) as f64;
        [
            dx * (k[0] as f64 + 0.5 + amp * (2.0 * u1 - 1.0)),
            dx * (k[1] as f64 + 0.5 + amp * (2.0 * u2 - 1.0)),
        ]
    }

    fn f(x: &[f64; 2]) -> f64 {
        (PI * x[0]).sin() * (PI * x[1]).sin()
    }
    fn grad_f(x: &[f64; 2]) -> [f64; 2] {
        let (s0, c0) = (PI * x[0]).sin_cos();
        let (s1, c1) = (PI * x[1]).sin_cos();
        [PI * c0 * s1, PI * s0 * c1]
    }
    fn lap_f(x: &[f64; 2]) -> f64 {
        -2.0 * PI * PI * f(x)
    }

    /// Errors at one evaluation particle: `[interp w1..w3, grad w1..w3, lap w1..w3]` (absolute)
    /// and the exact values' magnitudes `[|f|, |∇f|, |Δf|]`, and the neighbour count.
    fn at_point(
        g: [f64; 2],
        h: f64,
        dx: f64,
        amp: f64,
        seed: u64,
        ws: &[[Radial; 3]; 3],
    ) -> ([f64; 9], [f64; 3], usize) {
        let ki = [(g[0] / dx).floor() as i64, (g[1] / dx).floor() as i64];
        let xi = particle(ki, dx, amp, seed);
        let fi = f(&xi);
        let m = (h / dx).ceil() as i64 + 1;
        let hinv = 1.0 / h;
        let scale = hinv * hinv; // w_h = w(r/h)/h²
        let vol = dx * dx;
        let mut interp = [0.0; 3];
        let mut grad = [[0.0; 2]; 3];
        let mut lap = [0.0; 3];
        // self term of the interpolant
        for (c, w) in ws[0].iter().enumerate() {
            interp[c] += vol * fi * w.eval(0.0) * scale;
        }
        let mut count = 0;
        for a in -m..=m {
            for b in -m..=m {
                if a == 0 && b == 0 {
                    continue;
                }
                let xj = particle([ki[0] + a, ki[1] + b], dx, amp, seed);
                let d = [xj[0] - xi[0], xj[1] - xi[1]];
                let r2 = d[0] * d[0] + d[1] * d[1];
                if r2 >= h * h {
                    continue;
                }
                count += 1;
                let r = r2.sqrt();
                let q = r * hinv;
                let fj = f(&xj);
                let df = fj - fi;
                for c in 0..3 {
                    interp[c] += vol * fj * ws[0][c].eval(q) * scale;
                    let gw = 2.0 * vol * df / r2 * ws[1][c].eval(q) * scale;
                    grad[c][0] += gw * d[0];
                    grad[c][1] += gw * d[1];
                    lap[c] += 4.0 * vol * df / r2 * ws[2][c].eval(q) * scale;
                }
            }
        }
        let ge = grad_f(&xi);
        let mut e = [0.0; 9];
        for c in 0..3 {
            e[c] = (interp[c] - fi).abs();
            e[3 + c] = ((grad[c][0] - ge[0]).powi(2) + (grad[c][1] - ge[1]).powi(2)).sqrt();
            e[6 + c] = (lap[c] - lap_f(&xi)).abs();
        }
        (e, [fi.abs(), norm2(&ge).sqrt(), lap_f(&xi).abs()], count)
    }

    /// Table 1 of the paper: numerical and theoretical rates, `[operator][weight][σ index]`.
    const PAPER_NUM: [[[f64; 3]; 3]; 3] = [
        [[-0.10, 2.02, 2.00], [0.05, 2.13, 2.01], [0.00, 4.20, 7.41]],
        [
            [-0.05, 2.11, 2.02],
            [-0.02, 2.08, 2.03],
            [-0.06, 3.56, 7.69],
        ],
        [
            [-1.14, 2.91, 2.05],
            [-1.09, 2.39, 2.23],
            [-1.02, 2.76, 7.50],
        ],
    ];
    const PAPER_THEORY: [[[f64; 3]; 3]; 3] = [
        [
            [f64::NAN, 2.0, 2.0],
            [f64::NAN, 2.0, 2.0],
            [f64::NAN, 2.0, 4.0],
        ],
        [
            [f64::NAN, 2.0, 2.0],
            [f64::NAN, 2.0, 2.0],
            [f64::NAN, 2.0, 4.0],
        ],
        [
            [f64::NAN, 1.0, 2.0],
            [f64::NAN, 1.0, 2.0],
            [f64::NAN, 1.0, 3.0],
        ],
    ];
    const SIGMAS: [i32; 3] = [0, 2, 4];
    const OPS: [&str; 3] = ["interp", "grad", "lap"];

    pub fn run(args: &Args, out: &Path) -> Result<()> {
        let t0 = Instant::now();
        println!("== Imoto, truncation error estimates (seed 003): reconstruction of §5 ==");
        let ws = weights();
        for (o, row) in ws.iter().enumerate() {
            for w in row {
                let m0 = moment(w, 0);
                if (m0 - 1.0).abs() > 1e-9 {
                    bail!("{} ({}): ∫w = {m0}, not 1", w.name(), OPS[o]);
                }
                if let Radial::Fourth { .. } = w {
                    let m2 = moment(w, 2);
                    if m2.abs() > 1e-9 {
                        bail!("{}: ∫w|x|² = {m2}, not 0", w.name());
                    }
                }
            }
        }
        println!(
            "weights: ∫w = 1 for all nine, ∫w|x|² = 0 for the three 4th-order ones (quadrature)"
        );
        let h0 = 0.5;
        let m_eval = args.eval_points.unwrap_or(if args.quick { 4 } else { 8 });
        let levels: [usize; 3] = if args.quick { [5, 4, 2] } else { [9, 7, 5] };
        let amp = args.imoto_jitter;
        let seed = 2020;
        let mut csv =
            String::from("sigma,h,dx,h_over_dx,mean_neighbours,operator,weight,rel_max_error\n");
        // rel errors [sigma][op*3+w] -> points (h, e)
        let mut series: Vec<Vec<Vec<(f64, f64)>>> = vec![vec![Vec::new(); 9]; 3];
        for (s, &sigma) in SIGMAS.iter().enumerate() {
            for k in 0..levels[s] {
                let h = h0 * 2f64.powf(-(k as f64) / 2.0);
                let dx = h * (h / h0).powi(sigma) / args.kappa;
                let pts: Vec<[f64; 2]> = (0..m_eval * m_eval)
                    .map(|e| {
                        let (a, b) = (e / m_eval, e % m_eval);
                        [
                            (a as f64 + 0.5) / m_eval as f64,
                            (b as f64 + 0.5) / m_eval as f64,
                        ]
                    })
                    .collect();
                let res: Vec<([f64; 9], [f64; 3], usize)> = pts
                    .par_iter()
                    .map(|g| at_point(*g, h, dx, amp, seed + s as u64, &ws))
                    .collect();
                let mut emax = [0.0f64; 9];
                let mut vmax = [0.0f64; 3];
                let mut nb = 0usize;
                for (e, v, c) in &res {
                    for q in 0..9 {
                        emax[q] = emax[q].max(e[q]);
                    }
                    for q in 0..3 {
                        vmax[q] = vmax[q].max(v[q]);
                    }
                    nb += c;
                }
                let mean_nb = nb as f64 / res.len() as f64;
                for q in 0..9 {
                    let rel = emax[q] / vmax[q / 3];
                    series[s][q].push((h, rel));
                    let _ = writeln!(
                        csv,
                        "{sigma},{h:.6e},{dx:.6e},{:.3},{mean_nb:.1},{},{},{rel:.6e}",
                        h / dx,
                        OPS[q / 3],
                        ws[q / 3][q % 3].name()
                    );
                }
            }
        }
        write(&out.join("imoto_errors.csv"), &csv)?;
        // rates
        let mut rates = String::from(
            "operator,weight,sigma,rate_fit_all,rate_fit_finest4,paper_numerical,paper_theory\n",
        );
        println!(
            "\nrelative max-norm errors of f = sin πx sin πy, jitter ±{amp}Δx, Δx = h (h/{h0})^σ / {}, \
             {m_eval}×{m_eval} evaluation particles",
            args.kappa
        );
        println!(
            "rates: all = least-squares slope over every h, fine = over the 4 smallest h; paper = Table 1 (numerical / theoretical)\n"
        );
        println!(
            "{:<9} {:<28} | {:^27} | {:^27} | {:^27}",
            "operator", "weight", "σ = 0", "σ = 2", "σ = 4"
        );
        println!(
            "{:<9} {:<28} | {:>6} {:>6} {:>6} {:>6} | {:>6} {:>6} {:>6} {:>6} | {:>6} {:>6} {:>6} {:>6}",
            "", "", "all", "fine", "paper", "th.", "all", "fine", "paper", "th.", "all", "fine", "paper", "th."
        );
        for q in 0..9 {
            let (o, w) = (q / 3, q % 3);
            let mut line = format!("{:<9} {:<28} |", OPS[o], ws[o][w].name());
            for (s, ser) in series.iter().enumerate() {
                let fit = fit_slope(&ser[q]);
                let last = fine_slope(&ser[q], 4);
                let _ = write!(
                    line,
                    " {} {} {} {} |",
                    fmt_rate(fit),
                    fmt_rate(last),
                    fmt_rate(PAPER_NUM[o][w][s]),
                    fmt_rate(PAPER_THEORY[o][w][s])
                );
                let _ = writeln!(
                    rates,
                    "{},{},{},{fit:.4},{last:.4},{},{}",
                    OPS[o],
                    ws[o][w].name(),
                    SIGMAS[s],
                    PAPER_NUM[o][w][s],
                    PAPER_THEORY[o][w][s]
                );
            }
            println!("{line}");
        }
        write(&out.join("imoto_rates.csv"), &rates)?;
        // plots: one PNG per operator, one panel per σ
        for o in 0..3 {
            let charts: Vec<(Chart, Vec<Series>)> = (0..3)
                .map(|s| {
                    (
                        Chart {
                            title: format!("{} error, σ = {}", OPS[o], SIGMAS[s]),
                            x_label: "h".into(),
                            y_label: "relative max error".into(),
                            log_x: true,
                            log_y: true,
                        },
                        (0..3)
                            .map(|w| {
                                Series::line_points(
                                    format!("w{}: {}", w + 1, ws[o][w].name()),
                                    series[s][o * 3 + w].clone(),
                                )
                            })
                            .collect(),
                    )
                })
                .collect();
            line_charts(
                &out.join(format!("imoto_{}.png", OPS[o])),
                1800,
                600,
                &charts,
            )?;
        }
        println!("\nimoto part: {:.1} s", t0.elapsed().as_secs_f64());
        Ok(())
    }
}

// =============================================================================================
// Shobuzako et al. (seed 004): classical SPH vs GPM vs least squares, Franke's function
// =============================================================================================
mod sph {
    use super::*;

    /// Franke's (1979) test function and its `x` derivative and Laplacian.
    pub fn franke(x: &[f64; 2]) -> (f64, f64, f64) {
        let (x, y) = (x[0], x[1]);
        // terms A exp(g(x) + k(y)): (A, g, g', g'', k, k', k'')
        let gauss = |a: f64, b: f64, t: f64| {
            let u = 9.0 * t - b;
            (-a * u * u, -18.0 * a * u, -162.0 * a)
        };
        let mut f = 0.0;
        let mut fx = 0.0;
        let mut lap = 0.0;
        let terms = [
            (0.75, gauss(0.25, 2.0, x), gauss(0.25, 2.0, y)),
            (
                0.75,
                gauss(1.0 / 49.0, -1.0, x),
                (-(9.0 * y + 1.0) / 10.0, -0.9, 0.0),
            ),
            (0.5, gauss(0.25, 7.0, x), gauss(0.25, 3.0, y)),
            (-0.2, gauss(1.0, 4.0, x), gauss(1.0, 7.0, y)),
        ];
        for (a, (g, g1, g2), (k, k1, k2)) in terms {
            let e = a * (g + k).exp();
            f += e;
            fx += g1 * e;
            lap += (g2 + g1 * g1 + k2 + k1 * k1) * e;
        }
        (f, fx, lap)
    }

    #[derive(Clone, Copy, PartialEq, Eq, Debug)]
    pub enum Op {
        Interp,
        Grad,
        Lap,
    }

    impl Op {
        fn name(&self) -> &'static str {
            match self {
                Op::Interp => "interp",
                Op::Grad => "grad",
                Op::Lap => "lap",
            }
        }
    }

    /// Model name, operator, expected order (Shobuzako et al. Table 1 / least-squares theory).
    pub const MODELS: [(&str, Op, f64); 19] = [
        ("classical ΣfWV (cubic)", Op::Interp, 0.0),
        ("partition of unity ΣWV−1 (cubic)", Op::Interp, 0.0),
        ("Shepard / CSPH (cubic)", Op::Interp, 1.0),
        ("LS q=1 (cubic)", Op::Interp, 2.0),
        ("GPM Πh Wendland C2 ω=1/Σw", Op::Interp, 0.0),
        ("GPM Πh r²(1-r)⁴ ω=1/Σw", Op::Interp, 0.0),
        ("classical standard (cubic)", Op::Grad, -1.0),
        ("classical difference (cubic)", Op::Grad, 0.0),
        ("classical sum (cubic)", Op::Grad, -1.0),
        ("CSPH Bonet-Lok (cubic)", Op::Grad, 1.0),
        ("LS q=2 (cubic)", Op::Grad, 2.0),
        ("GPM ∇h Wendland C2 ω=1/Σw", Op::Grad, 0.0),
        ("GPM ∇h r²(1-r)⁴ ω=1/Σw", Op::Grad, 0.0),
        ("renormalised ∇ᶜ Wendland C2", Op::Grad, 1.0),
        ("renormalised ∇ᶜ r²(1-r)⁴", Op::Grad, 1.0),
        ("Brookshaw (cubic)", Op::Lap, -1.0),
        ("LS q=2 (cubic)", Op::Lap, 1.0),
        ("GPM Δh Wendland C2 ω=1/Σw", Op::Lap, -1.0),
        ("GPM Δh r²(1-r)⁴ ω=1/Σw", Op::Lap, -1.0),
    ];

    fn e2(approx: &[f64], exact: &[f64], set: &[usize]) -> f64 {
        let n: f64 = set.iter().map(|&i| (approx[i] - exact[i]).powi(2)).sum();
        let d: f64 = set.iter().map(|&i| exact[i].powi(2)).sum();
        (n / d).sqrt()
    }

    /// Values of every model at every particle, in [`MODELS`] order.
    fn evaluate(x: &[[f64; 2]], dx: f64, h_ratio: f64) -> Result<Vec<Vec<f64>>> {
        let phi: Vec<f64> = x.iter().map(|p| franke(p).0).collect();
        let build = |w: Weight| {
            NeighborList::build(NeighborConfig::new_relative(w, dx, h_ratio, 0.0), x)
                .context("neighbour list")
        };
        let nlc = build(Weight::CubicSpline)?;
        let v = vec![dx * dx; x.len()];
        let gx = |g: Vec<[f64; 2]>| g.into_iter().map(|v| v[0]).collect::<Vec<f64>>();
        let mut vals: Vec<Vec<f64>> = vec![
            interpolate_at_particles(&nlc, &v, &phi),
            interpolate_at_particles(&nlc, &v, &vec![1.0; x.len()]),
            shepard_interpolate(&nlc, &v, &phi),
            ls_interpolate(&nlc, &v, &phi),
        ];
        let gpm: Vec<(NeighborList<2>, Vec<f64>)> =
            [Weight::WendlandC2, Weight::Poly { p: 2, m: 4 }]
                .into_iter()
                .map(|w| {
                    let nl = build(w)?;
                    let vol = number_density_volumes(&nl);
                    Ok((nl, vol))
                })
                .collect::<Result<_>>()?;
        for (nl, vol) in &gpm {
            vals.push(interpolate_at_particles(nl, vol, &phi));
        }
        vals.push(gx(sph_gradient(&nlc, &v, &phi, SphGradient::Standard)));
        vals.push(gx(sph_gradient(&nlc, &v, &phi, SphGradient::Difference)));
        vals.push(gx(sph_gradient(&nlc, &v, &phi, SphGradient::Sum)));
        vals.push(gx(csph_gradient(&nlc, &v, &phi)));
        let (lsg, lsl) = ls_gradient_laplacian(&nlc, &v, &phi);
        vals.push(gx(lsg));
        for (nl, vol) in &gpm {
            vals.push(gx(grad_diff(nl, vol, &phi)));
        }
        for (nl, vol) in &gpm {
            let r = Renormalisation::compute(nl, vol, nl.len());
            vals.push(gx(grad_renormalised(nl, vol, &r, &phi)));
        }
        vals.push(sph_laplacian_brookshaw(&nlc, &v, &phi));
        vals.push(lsl);
        for (nl, vol) in &gpm {
            vals.push(laplacian(nl, vol, &phi));
        }
        assert_eq!(vals.len(), MODELS.len());
        Ok(vals)
    }

    pub fn run(args: &Args, out: &Path) -> Result<()> {
        let t0 = Instant::now();
        println!("\n== Shobuzako et al. (seed 004): classical SPH, GPM and least squares on Franke's function ==");
        // check the analytic derivatives of Franke's function by central differences
        for p in [[0.3, 0.7], [0.61, 0.2], [0.9, 0.45]] {
            let e = 1e-4;
            let (f0, fx, lap) = franke(&p);
            let fxp = franke(&[p[0] + e, p[1]]).0;
            let fxm = franke(&[p[0] - e, p[1]]).0;
            let fyp = franke(&[p[0], p[1] + e]).0;
            let fym = franke(&[p[0], p[1] - e]).0;
            let fx_fd = (fxp - fxm) / (2.0 * e);
            let lap_fd = (fxp + fxm + fyp + fym - 4.0 * f0) / (e * e);
            if (fx - fx_fd).abs() > 1e-6 * (1.0 + fx.abs())
                || (lap - lap_fd).abs() > 1e-3 * (1.0 + lap.abs())
            {
                bail!("Franke derivatives disagree with finite differences at {p:?}");
            }
        }
        let ns: Vec<usize> = if args.quick {
            vec![16, 32, 64]
        } else {
            vec![16, 32, 64, 128, 256]
        };
        let amp = 0.3;
        let mut csv = String::from("n,dx,h,model,operator,set,e2,particles_in_set\n");
        // [model][set] -> (dx, e)
        let mut series: Vec<[Vec<(f64, f64)>; 2]> = vec![[Vec::new(), Vec::new()]; MODELS.len()];
        for &n in &ns {
            let dx = 1.0 / n as f64;
            let h = args.h_ratio * dx;
            let mut x = lattice([0.0, 0.0], [1.0, 1.0], dx);
            jitter(&mut x, amp * dx, 4000 + n as u64);
            let interior: Vec<usize> = (0..x.len())
                .filter(|&i| x[i].iter().all(|&c| c >= h && c <= 1.0 - h))
                .collect();
            let boundary: Vec<usize> = (0..x.len())
                .filter(|&i| !x[i].iter().all(|&c| c >= h && c <= 1.0 - h))
                .collect();
            let exact: Vec<(f64, f64, f64)> = x.iter().map(franke).collect();
            let ef: Vec<f64> = exact.iter().map(|e| e.0).collect();
            let ex: Vec<f64> = exact.iter().map(|e| e.1).collect();
            let el: Vec<f64> = exact.iter().map(|e| e.2).collect();
            let vals = evaluate(&x, dx, args.h_ratio)?;
            for (m, (name, op, _)) in MODELS.iter().enumerate() {
                for (s, set) in [&interior, &boundary].iter().enumerate() {
                    let e = if m == 1 {
                        // the defect of the partition of unity: E₂ with φ = 1
                        let ones = vec![1.0; x.len()];
                        e2(&vals[m], &ones, set)
                    } else {
                        let exact = match op {
                            Op::Interp => &ef,
                            Op::Grad => &ex,
                            Op::Lap => &el,
                        };
                        e2(&vals[m], exact, set)
                    };
                    series[m][s].push((dx, e));
                    let _ = writeln!(
                        csv,
                        "{n},{dx:.6e},{h:.6e},{name},{},{},{e:.6e},{}",
                        op.name(),
                        ["interior", "near_boundary"][s],
                        set.len()
                    );
                }
            }
        }
        write(&out.join("sph_errors.csv"), &csv)?;
        let mut rates =
            String::from("model,operator,set,order_fit,order_last_pair,order_expected\n");
        println!(
            "E₂ errors (their eq. 49), jitter ±{amp}Δx, h = {}Δx, n = {:?}; order = slope of ln E₂ vs ln Δx\n",
            args.h_ratio, ns
        );
        println!(
            "{:<6} {:<34} | {:>9} {:>6} {:>6} | {:>9} {:>6} {:>6} | {:>5}",
            "op", "model", "E₂ int.", "fit", "last", "E₂ bdry", "fit", "last", "theory"
        );
        for (m, (name, op, theory)) in MODELS.iter().enumerate() {
            let mut line = format!("{:<6} {:<34} |", op.name(), name);
            for s in 0..2 {
                let fit = fit_slope(&series[m][s]);
                let last = last_slope(&series[m][s]);
                let e_fin = series[m][s].last().map(|p| p.1).unwrap_or(f64::NAN);
                let _ = write!(line, " {e_fin:9.2e} {} {} |", fmt_rate(fit), fmt_rate(last));
                let _ = writeln!(
                    rates,
                    "{name},{},{},{fit:.4},{last:.4},{theory}",
                    op.name(),
                    ["interior", "near_boundary"][s]
                );
            }
            let _ = write!(line, " {theory:5.1}");
            println!("{line}");
        }
        write(&out.join("sph_rates.csv"), &rates)?;
        for op in [Op::Interp, Op::Grad, Op::Lap] {
            let charts: Vec<(Chart, Vec<Series>)> = (0..2)
                .map(|s| {
                    (
                        Chart {
                            title: format!(
                                "{} E₂, {} particles",
                                op.name(),
                                ["interior", "near-boundary"][s]
                            ),
                            x_label: "Δx".into(),
                            y_label: "E₂".into(),
                            log_x: true,
                            log_y: true,
                        },
                        MODELS
                            .iter()
                            .enumerate()
                            .filter(|(_, m)| m.1 == op)
                            .map(|(k, m)| Series::line_points(m.0, series[k][s].clone()))
                            .collect(),
                    )
                })
                .collect();
            line_charts(
                &out.join(format!("sph_{}.png", op.name())),
                1800,
                700,
                &charts,
            )?;
        }
        println!("\nsph part: {:.1} s", t0.elapsed().as_secs_f64());
        Ok(())
    }
}

// =============================================================================================
// The consistent gradient inside the projection: a standalone experiment (periodic box)
// =============================================================================================
mod projection {
    use super::*;

    const TWO_PI: f64 = 2.0 * PI;

    /// Divergence-free Taylor–Green field.
    pub fn u_df(x: &[f64; 2]) -> [f64; 2] {
        let (s0, c0) = (TWO_PI * x[0]).sin_cos();
        let (s1, c1) = (TWO_PI * x[1]).sin_cos();
        [-c0 * s1, s0 * c1]
    }
    /// The gradient part's potential `q = sin 2πx sin 4πy / (2π)`, its gradient and Laplacian.
    pub fn q(x: &[f64; 2]) -> (f64, [f64; 2], f64) {
        let (s0, c0) = (TWO_PI * x[0]).sin_cos();
        let (s1, c1) = (2.0 * TWO_PI * x[1]).sin_cos();
        let v = s0 * s1 / TWO_PI;
        (
            v,
            [c0 * s1, 2.0 * s0 * c1],
            -(TWO_PI * TWO_PI + 4.0 * TWO_PI * TWO_PI) * v,
        )
    }

    /// A lattice advected for time `t` by the steady Taylor–Green field (RK4, 50 steps), wrapped
    /// into the unit box: a Lagrangian-deformed configuration.
    pub fn advected(n: usize, t: f64) -> Vec<[f64; 2]> {
        let dx = 1.0 / n as f64;
        let per = Periodicity::all([0.0, 0.0], [1.0, 1.0]);
        let steps = 50;
        let dt = t / steps as f64;
        lattice([0.0, 0.0], [1.0, 1.0], dx)
            .into_iter()
            .map(|mut p| {
                for _ in 0..steps {
                    let k1 = u_df(&p);
                    let k2 = u_df(&[p[0] + 0.5 * dt * k1[0], p[1] + 0.5 * dt * k1[1]]);
                    let k3 = u_df(&[p[0] + 0.5 * dt * k2[0], p[1] + 0.5 * dt * k2[1]]);
                    let k4 = u_df(&[p[0] + dt * k3[0], p[1] + dt * k3[1]]);
                    for a in 0..2 {
                        p[a] += dt / 6.0 * (k1[a] + 2.0 * k2[a] + 2.0 * k3[a] + k4[a]);
                    }
                }
                per.wrap(&mut p);
                p
            })
            .collect()
    }

    fn l2v(vol: &[f64], v: &[[f64; 2]]) -> f64 {
        vol.iter()
            .zip(v)
            .map(|(w, a)| w * norm2(a))
            .sum::<f64>()
            .sqrt()
    }
    fn l2s(vol: &[f64], v: &[f64]) -> f64 {
        vol.iter()
            .zip(v)
            .map(|(w, a)| w * a * a)
            .sum::<f64>()
            .sqrt()
    }

    #[derive(Clone, Copy, PartialEq, Eq, Debug)]
    enum Variant {
        /// `∇̂h·` source, `∇h` correction (today's projection).
        A,
        /// `∇̂h·` source, `∇ᶜ` correction.
        B,
        /// `∇̂h·(Bᵀ ·)` source, `∇ᶜ` correction (the adjoint pair).
        C,
        /// Difference-form divergence `∇h·` source (Galilean invariant), `∇h` correction.
        D,
        /// Renormalised divergence `∇ᶜ·` source, `∇ᶜ` correction (both first-order consistent).
        E,
    }

    const VARIANTS: [Variant; 5] = [Variant::A, Variant::B, Variant::C, Variant::D, Variant::E];

    struct Setup<'a> {
        nl: &'a NeighborList<2>,
        vol: &'a [f64],
        role: &'a [Role],
        comps: &'a gpm::diagnostics::Components,
        renorm: &'a Renormalisation<2>,
    }

    /// Velocity, increment and the seconds of source, solve and correction.
    type Projected = (Vec<[f64; 2]>, Vec<f64>, [f64; 3]);

    /// One projection of `v` (`Δt/ρ = 1`): `−Δh φ = −D v`, `v − G φ`. Returns `(u, φ)` and the
    /// seconds spent in source, solve and correction.
    fn project(
        s: &Setup,
        solver: &mut PoissonSolver,
        variant: Variant,
        v: &[[f64; 2]],
    ) -> Result<Projected> {
        let n = v.len();
        let t = Instant::now();
        let minus: Vec<[f64; 2]> = v.iter().map(|a| [-a[0], -a[1]]).collect();
        let rhs = match variant {
            Variant::A | Variant::B => div_sum(s.nl, s.vol, &minus),
            Variant::C => {
                let mut bt = vec![[0.0; 2]; n];
                s.renorm.apply_transpose_into(&minus, &mut bt);
                div_sum(s.nl, s.vol, &bt)
            }
            Variant::D => {
                let mut d = vec![0.0; n];
                div_diff_into(s.nl, s.vol, &minus, &mut d);
                d
            }
            Variant::E => div_renormalised(s.nl, s.vol, s.renorm, &minus),
        };
        let t_src = t.elapsed().as_secs_f64();
        let t = Instant::now();
        let mut phi = vec![0.0; n];
        let params = SolveParams {
            warm_start: false,
            ..Default::default()
        };
        solver.solve(s.nl, s.vol, s.role, s.comps, &rhs, &mut phi, &params)?;
        let t_solve = t.elapsed().as_secs_f64();
        let t = Instant::now();
        let g = match variant {
            Variant::A | Variant::D => grad_diff(s.nl, s.vol, &phi),
            Variant::B | Variant::C | Variant::E => grad_renormalised(s.nl, s.vol, s.renorm, &phi),
        };
        let u: Vec<[f64; 2]> = v
            .iter()
            .zip(&g)
            .map(|(a, b)| [a[0] - b[0], a[1] - b[1]])
            .collect();
        let t_corr = t.elapsed().as_secs_f64();
        Ok((u, phi, [t_src, t_solve, t_corr]))
    }

    fn median(mut v: Vec<f64>) -> f64 {
        v.sort_by(|a, b| a.partial_cmp(b).unwrap());
        v[v.len() / 2]
    }

    pub fn run(args: &Args, out: &Path) -> Result<()> {
        let t0 = Instant::now();
        println!("\n== The consistent gradient in the projection (periodic box, u* = u_TG + ∇q, Δt/ρ = 1) ==");
        let n = if args.quick { 32 } else { 64 };
        let dx = 1.0 / n as f64;
        let per = Periodicity::all([0.0, 0.0], [1.0, 1.0]);
        let mut jit = lattice([0.0, 0.0], [1.0, 1.0], dx);
        jitter(&mut jit, 0.3 * dx, 77);
        for p in jit.iter_mut() {
            per.wrap(p);
        }
        let configs: Vec<(&str, Vec<[f64; 2]>)> = vec![
            ("lattice", lattice([0.0, 0.0], [1.0, 1.0], dx)),
            ("jitter 0.3dx", jit),
            ("TG-advected t=0.02", advected(n, 0.02)),
            ("TG-advected t=0.1", advected(n, 0.1)),
        ];
        let weights = [
            Weight::CubicSpline,
            Weight::WendlandC2,
            Weight::Poly { p: 2, m: 4 },
        ];
        let reps = if args.quick { 3 } else { 7 };
        let mut csv = String::from(
            "config,weight,n,h_over_dx,uniform_div_max,uniform_div_rms,moment_defect_max,c0,\
             grad_diff_err,grad_renorm_err,lap_err,variant,u_err,phi_err,div_after_over_before,\
             adjoint_defect,growth_per_projection,first_projection_energy_ratio,kick,\
             t_source_s,t_solve_s,t_correction_s,t_renorm_s,t_grad_diff_s,t_grad_renorm_s\n",
        );
        println!(
            "n = {n}, h = {}Δx, number-density volumes; errors are relative ω-weighted ℓ2 norms\n",
            args.h_ratio
        );
        println!(
            "{:<19} {:<12} | {:>8} {:>8} {:>6} | {:>8} {:>8} {:>8} | {:>3} {:>8} {:>8} {:>8} {:>9} {:>9} {:>7}",
            "configuration",
            "weight",
            "∇̂h·1 max",
            "‖M−I‖max",
            "c0",
            "∇h q err",
            "∇ᶜ q err",
            "Δh q err",
            "var",
            "u err",
            "kick",
            "φ err",
            "div left",
            "adj.defect",
            "growth"
        );
        for (cname, x) in &configs {
            for &w in &weights {
                let cfg =
                    NeighborConfig::new_relative(w, dx, args.h_ratio, 0.0).with_periodicity(per);
                let nl = NeighborList::build(cfg, x)?;
                let vol = number_density_volumes(&nl);
                let role = vec![Role::Fluid; x.len()];
                let comps = connectivity(&nl, &role);
                // the uniform field (1, 0)
                let ones = vec![[1.0, 0.0]; x.len()];
                let du = div_sum(&nl, &vol, &ones);
                let du_max = du.iter().map(|v| v.abs()).fold(0.0, f64::max);
                let du_rms = (du.iter().map(|v| v * v).sum::<f64>() / du.len() as f64).sqrt();
                let mdef = (0..nl.len())
                    .map(|i| {
                        let m = moment_matrix(&nl, &vol, i);
                        ((m[0][0] - 1.0).powi(2)
                            + (m[1][1] - 1.0).powi(2)
                            + m[0][1].powi(2)
                            + m[1][0].powi(2))
                        .sqrt()
                    })
                    .fold(0.0, f64::max);
                let c0 = gpm::diagnostics::semi_regularity(
                    &nl,
                    &vol,
                    &role,
                    gpm::diagnostics::Region::Omega,
                );
                // timings of the renormalisation and of the two gradients
                let mut tr = Vec::new();
                let mut renorm = Renormalisation::new();
                for _ in 0..reps {
                    let t = Instant::now();
                    renorm = Renormalisation::compute(&nl, &vol, nl.len());
                    tr.push(t.elapsed().as_secs_f64());
                }
                if !renorm.fallback_rows.is_empty() {
                    println!(
                        "  ({} rows fell back to scalar renormalisation)",
                        renorm.fallback_rows.len()
                    );
                }
                let qv: Vec<(f64, [f64; 2], f64)> = x.iter().map(q).collect();
                let qs: Vec<f64> = qv.iter().map(|e| e.0).collect();
                let gq: Vec<[f64; 2]> = qv.iter().map(|e| e.1).collect();
                let lq: Vec<f64> = qv.iter().map(|e| e.2).collect();
                let mut tgd = Vec::new();
                let mut tgc = Vec::new();
                let mut gd = Vec::new();
                let mut gc = Vec::new();
                for _ in 0..reps {
                    let t = Instant::now();
                    gd = grad_diff(&nl, &vol, &qs);
                    tgd.push(t.elapsed().as_secs_f64());
                    let t = Instant::now();
                    gc = grad_renormalised(&nl, &vol, &renorm, &qs);
                    tgc.push(t.elapsed().as_secs_f64());
                }
                let diff = |a: &[[f64; 2]], b: &[[f64; 2]]| -> Vec<[f64; 2]> {
                    a.iter()
                        .zip(b)
                        .map(|(u, v)| [u[0] - v[0], u[1] - v[1]])
                        .collect()
                };
                let e_gd = l2v(&vol, &diff(&gd, &gq)) / l2v(&vol, &gq);
                let e_gc = l2v(&vol, &diff(&gc, &gq)) / l2v(&vol, &gq);
                let lh = laplacian(&nl, &vol, &qs);
                let e_l = l2s(
                    &vol,
                    &lh.iter().zip(&lq).map(|(a, b)| a - b).collect::<Vec<_>>(),
                ) / l2s(&vol, &lq);
                let setup = Setup {
                    nl: &nl,
                    vol: &vol,
                    role: &role,
                    comps: &comps,
                    renorm: &renorm,
                };
                let mut solver = PoissonSolver::new();
                let udf: Vec<[f64; 2]> = x.iter().map(u_df).collect();
                let ustar: Vec<[f64; 2]> = udf
                    .iter()
                    .zip(&gq)
                    .map(|(a, b)| [a[0] + b[0], a[1] + b[1]])
                    .collect();
                // a rough random field for the repeated projection (seeded)
                let mut s = 12345u64;
                let rnd: Vec<[f64; 2]> = (0..x.len())
                    .map(|_| {
                        std::array::from_fn(|_| {
                            s = s
                                .wrapping_mul(6364136223846793005)
                                .wrapping_add(1442695040888963407);
                            (s >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
                        })
                    })
                    .collect();
                // warm-up: assembly and factorisation happen once per configuration
                project(&setup, &mut solver, Variant::A, &ustar)?;
                for variant in VARIANTS {
                    let mut times = [Vec::new(), Vec::new(), Vec::new()];
                    let mut res = None;
                    for _ in 0..reps {
                        let (u, phi, t) = project(&setup, &mut solver, variant, &ustar)?;
                        for k in 0..3 {
                            times[k].push(t[k]);
                        }
                        res = Some((u, phi));
                    }
                    let (u, phi) = res.unwrap();
                    let e_u = l2v(&vol, &diff(&u, &udf)) / l2v(&vol, &udf);
                    let wsum: f64 = vol.iter().sum();
                    let mean_d: f64 = vol
                        .iter()
                        .zip(phi.iter().zip(&qs))
                        .map(|(w, (a, b))| w * (a - b))
                        .sum::<f64>()
                        / wsum;
                    let dphi: Vec<f64> = phi.iter().zip(&qs).map(|(a, b)| a - b - mean_d).collect();
                    let e_phi = l2s(&vol, &dphi) / l2s(&vol, &qs);
                    let div_after =
                        l2s(&vol, &div_sum(&nl, &vol, &u)) / l2s(&vol, &div_sum(&nl, &vol, &ustar));
                    // adjointness of the variant's (D, G) on (ψ, φ) = (u*, q)
                    let (dpsi, gphi) = match variant {
                        Variant::A => (div_sum(&nl, &vol, &ustar), gd.clone()),
                        Variant::B => (div_sum(&nl, &vol, &ustar), gc.clone()),
                        Variant::C => {
                            let mut bt = vec![[0.0; 2]; x.len()];
                            renorm.apply_transpose_into(&ustar, &mut bt);
                            (div_sum(&nl, &vol, &bt), gc.clone())
                        }
                        Variant::D => {
                            let mut d = vec![0.0; x.len()];
                            div_diff_into(&nl, &vol, &ustar, &mut d);
                            (d, gd.clone())
                        }
                        Variant::E => (div_renormalised(&nl, &vol, &renorm, &ustar), gc.clone()),
                    };
                    // the kick: what one projection does to an exactly divergence-free field
                    let kick = {
                        let (pu, _, _) = project(&setup, &mut solver, variant, &udf)?;
                        l2v(&vol, &diff(&pu, &udf)) / l2v(&vol, &udf)
                    };
                    let a1: f64 = vol
                        .iter()
                        .zip(dpsi.iter().zip(&qs))
                        .map(|(w, (d, p))| w * d * p)
                        .sum();
                    let a2: f64 = vol
                        .iter()
                        .zip(ustar.iter().zip(&gphi))
                        .map(|(w, (u, g))| w * (u[0] * g[0] + u[1] * g[1]))
                        .sum();
                    let adj = (a1 + a2).abs() / a2.abs();
                    // repeated projection of a rough field
                    let (mut v, _, _) = project(&setup, &mut solver, variant, &rnd)?;
                    let first = l2v(&vol, &v) / l2v(&vol, &rnd);
                    let n1 = l2v(&vol, &v);
                    let k_rep = 10;
                    for _ in 0..k_rep {
                        v = project(&setup, &mut solver, variant, &v)?.0;
                    }
                    let growth = (l2v(&vol, &v) / n1).powf(1.0 / k_rep as f64);
                    let [ts, tsv, tc] = times.map(median);
                    let _ = writeln!(
                        csv,
                        "{cname},{w},{n},{},{du_max:.6e},{du_rms:.6e},{mdef:.6e},{c0:.6},{e_gd:.6e},{e_gc:.6e},{e_l:.6e},{variant:?},{e_u:.6e},{e_phi:.6e},{div_after:.6e},{adj:.6e},{growth:.6},{first:.6},{kick:.6e},{ts:.6e},{tsv:.6e},{tc:.6e},{:.6e},{:.6e},{:.6e}",
                        args.h_ratio,
                        median(tr.clone()),
                        median(tgd.clone()),
                        median(tgc.clone())
                    );
                    if variant == Variant::A {
                        print!(
                            "{:<19} {:<12} | {:>8.3} {:>8.3} {:>6.3} | {:>8.2e} {:>8.2e} {:>8.2e} |",
                            cname,
                            w.to_string(),
                            du_max,
                            mdef,
                            c0,
                            e_gd,
                            e_gc,
                            e_l
                        );
                    } else {
                        print!(
                            "{:<19} {:<12} | {:>8} {:>8} {:>6} | {:>8} {:>8} {:>8} |",
                            "", "", "", "", "", "", "", ""
                        );
                    }
                    println!(
                        " {:>3} {:>8.2e} {:>8.2e} {:>8.2e} {:>9.2e} {:>9.2e} {:>7.4}",
                        format!("{variant:?}"),
                        e_u,
                        kick,
                        e_phi,
                        div_after,
                        adj,
                        growth
                    );
                }
                println!(
                    "{:<19} {:<12} | time per call: B matrices {:.2} ms, ∇h {:.2} ms, ∇ᶜ {:.2} ms ({} particles)",
                    "",
                    "",
                    1e3 * median(tr),
                    1e3 * median(tgd),
                    1e3 * median(tgc),
                    x.len()
                );
            }
        }
        write(&out.join("projection.csv"), &csv)?;
        println!(
            "\nvariants (source / correction): A = ∇̂h· / ∇h (today); B = ∇̂h· / ∇ᶜ; C = ∇̂h·(Bᵀ·) / ∇ᶜ (adjoint pair);\n\
             D = ∇h· (difference form) / ∇h; E = ∇ᶜ· / ∇ᶜ. u err = ‖u − u_TG‖/‖u_TG‖ after one projection of u_TG + ∇q;\n\
             kick = ‖P u_TG − u_TG‖/‖u_TG‖ (one projection of the divergence-free field alone; Δt-independent);\n\
             div left = ‖∇̂h·u‖/‖∇̂h·u*‖; adj.defect =\n\
             |(Du*, q) + (u*, Gq)| / |(u*, Gq)|; growth = per-application norm factor of repeated projections of a rough field."
        );
        println!("\nprojection part: {:.1} s", t0.elapsed().as_secs_f64());
        Ok(())
    }
}

// =============================================================================================
// Lagrangian flows with the projection variants (ProjectionParams::source / ::gradient)
// =============================================================================================
mod flows {
    use super::*;
    use gpm::flow::VolumeRule;
    use gpm::projection::SourceKind;
    use gpm::scene::cavity::{build, ghia_errors, sample_positions, sample_profiles, CavityConfig};
    use gpm::scene::taylor_green::{self, TaylorGreenConfig};

    type Sim<B> = Simulation<2, B>;

    /// A projection variant of the flow runs: name, source divergence, gradient.
    pub type FlowVariant = (&'static str, SourceKind, GradientKind);

    /// A: today; B: renormalised gradient; C: the adjoint pair ∇̂h·(Bᵀ·)/∇ᶜ; E: renormalised
    /// divergence and gradient.
    pub const FLOW_VARIANTS: [FlowVariant; 4] = [
        ("A", SourceKind::SumForm, GradientKind::Difference),
        ("B", SourceKind::SumForm, GradientKind::Renormalised),
        ("C", SourceKind::AdjointBt, GradientKind::Renormalised),
        ("E", SourceKind::Renormalised, GradientKind::Renormalised),
    ];

    /// `sim` with the variant's source divergence and gradient in its projection parameters.
    fn with_variant<B: Boundary<2>>(mut sim: Sim<B>, v: FlowVariant) -> Sim<B> {
        sim.params.projection.source = v.1;
        sim.params.projection.gradient = v.2;
        sim
    }

    pub struct Outcome {
        pub rms_u: f64,
        pub max_u: f64,
        pub rms_v: f64,
        pub max_v: f64,
        pub steps: u64,
        pub t_end: f64,
        pub steady: bool,
        pub wall: f64,
        /// Seconds in the projection's source and correction stages (where the variants differ).
        pub extra: f64,
        /// The error that stopped the run early, if any.
        pub failed: Option<String>,
    }

    /// A cavity run to steadiness with the example's loop (steadiness and averaging as in
    /// `gpm::scene::cavity::run`). A step that fails ends the run; the failure is reported.
    fn run_one(cfg: &CavityConfig, v: FlowVariant) -> Result<Outcome> {
        let start = Instant::now();
        let mut sim = with_variant(build(cfg)?, v);
        let mut extra = 0.0;
        let re_key = cfg.re.round() as u32;
        let (ys, xs) = sample_positions(gpm::reference::ghia(re_key).as_ref());
        let s = cfg.scene.steady;
        let mut samples: Vec<(f64, Vec<f64>, Vec<f64>)> = Vec::new();
        let mut next = s.interval;
        let mut steady_time = None;
        let mut failed = None;
        while sim.time < cfg.t_end - 1e-12 {
            match sim.advance() {
                Ok(r) => extra += r.projection.timings.source + r.projection.timings.correction,
                Err(e) => {
                    failed = Some(e.to_string());
                    break;
                }
            }
            if sim.time + 1e-12 >= next {
                let (u, v) = sample_profiles(&sim, &ys, &xs);
                if let Some(last) = samples.last() {
                    let du = u
                        .iter()
                        .zip(&last.1)
                        .chain(v.iter().zip(&last.2))
                        .map(|(a, b)| (a - b).abs())
                        .fold(0.0, f64::max);
                    if du / (sim.time - last.0) < s.tol && steady_time.is_none() {
                        steady_time = Some(sim.time);
                    }
                }
                samples.push((sim.time, u, v));
                next += s.interval;
                if let Some(ts) = steady_time {
                    if s.stop_when_steady && sim.time + 1e-12 >= ts + s.average_window {
                        break;
                    }
                }
            }
        }
        let (mut rms_u, mut max_u, mut rms_v, mut max_v) = (f64::NAN, f64::NAN, f64::NAN, f64::NAN);
        if failed.is_none() {
            if samples.is_empty() {
                let (u, v) = sample_profiles(&sim, &ys, &xs);
                samples.push((sim.time, u, v));
            }
            let t_last = samples.last().unwrap().0;
            let win: Vec<&(f64, Vec<f64>, Vec<f64>)> = samples
                .iter()
                .filter(|q| q.0 >= t_last - s.average_window - 1e-9)
                .collect();
            let m = win.len() as f64;
            let u: Vec<f64> = (0..ys.len())
                .map(|k| win.iter().map(|q| q.1[k]).sum::<f64>() / m)
                .collect();
            let v: Vec<f64> = (0..xs.len())
                .map(|k| win.iter().map(|q| q.2[k]).sum::<f64>() / m)
                .collect();
            let g = ghia_errors(re_key, &ys, &u, &xs, &v).context("no Ghia table for this Re")?;
            (rms_u, max_u, rms_v, max_v) = (g.rms_u, g.max_u, g.rms_v, g.max_v);
        }
        Ok(Outcome {
            rms_u,
            max_u,
            rms_v,
            max_v,
            steps: sim.steps,
            t_end: sim.time,
            steady: steady_time.is_some(),
            wall: start.elapsed().as_secs_f64(),
            extra,
            failed,
        })
    }

    /// `(t, L1 velocity error, L1 pressure error)` after each step.
    type Steps = Vec<(f64, f64, f64)>;

    /// L1 velocity and pressure errors of a Taylor–Green run after each of `steps` steps.
    fn tg_steps(cfg: &TaylorGreenConfig, v: Option<FlowVariant>, steps: usize) -> Result<Steps> {
        let mut sim = taylor_green::build(cfg)?;
        if let Some(v) = v {
            sim = with_variant(sim, v);
        }
        let mut out = Vec::new();
        for _ in 0..steps {
            if sim.advance().is_err() {
                break;
            }
            let e = taylor_green::errors(&sim, cfg.re, cfg.scene.amplitude);
            out.push((sim.time, e.l1_velocity_error, e.l1_pressure_error));
        }
        Ok(out)
    }

    pub fn run(args: &Args, out: &Path) -> Result<()> {
        let t0 = Instant::now();
        println!(
            "\n== Flows: the projection variants in the Lagrangian frame (and the Eulerian default) =="
        );
        // the Eulerian cavity (the product default): a lattice completed by mirror ghosts, so
        // M_i = I and ∇ᶜ = ∇h at every fluid particle
        let euler = build(&CavityConfig::default())?;
        let mdef = (0..euler.particles.len())
            .filter(|&i| euler.particles.role[i].is_fluid())
            .map(|i| {
                let m = moment_matrix(&euler.nl, &euler.particles.vol, i);
                (m[0][0] - 1.0)
                    .abs()
                    .max((m[1][1] - 1.0).abs())
                    .max(m[0][1].abs())
            })
            .fold(0.0, f64::max);
        println!(
            "Eulerian cavity (default, n = {}): max_i |M_i − I| over fluid particles = {mdef:.2e}: the renormalised \
             gradient is the difference gradient there",
            CavityConfig::default().n
        );
        let mut csv = String::from(
            "flow,weight,variant,n,t_end,steps,wall_s,source_correction_s,rms_u,max_u,rms_v,max_v,steady,failed\n",
        );
        // Taylor–Green, step by step: the Lagrangian frame against the Eulerian one
        let ns = if args.quick { 24 } else { 48 };
        let nsteps = 12;
        let tg = |motion| {
            TaylorGreenConfig::default().with(|c| {
                c.n = ns;
                c.motion = motion;
            })
        };
        let mut steps_csv = String::from("frame,variant,n,cfl,step,t,u_l1,p_l1\n");
        let mut rows: Vec<(String, Steps)> = Vec::new();
        rows.push((
            "Eulerian".into(),
            tg_steps(&tg(Motion::Eulerian), None, nsteps)?,
        ));
        for v in FLOW_VARIANTS {
            rows.push((
                format!("Lagrangian {}", v.0),
                tg_steps(&tg(Motion::Lagrangian), Some(v), nsteps)?,
            ));
        }
        println!(
            "\nTaylor–Green, Re 100, n = {ns}, Wendland C2, CFL 0.2: L1 velocity error after each step \
             (A today, B ∇ᶜ, C ∇̂h·(Bᵀ·)/∇ᶜ, E ∇ᶜ·/∇ᶜ)\n"
        );
        let mut head = format!("{:<14}", "step");
        for k in (0..nsteps).step_by(2) {
            let _ = write!(head, " {:>9}", k + 1);
        }
        println!("{head}");
        for (name, e) in &rows {
            let mut line = format!("{name:<14}");
            for k in (0..nsteps).step_by(2) {
                match e.get(k) {
                    Some(v) => {
                        let _ = write!(line, " {:>9.2e}", v.1);
                    }
                    None => line.push_str("    failed"),
                }
            }
            println!("{line}");
            for (k, v) in e.iter().enumerate() {
                let (frame, var) = name.split_once(' ').unwrap_or((name.as_str(), "-"));
                let _ = writeln!(
                    steps_csv,
                    "{frame},{var},{ns},0.2,{},{:.5},{:.6e},{:.6e}",
                    k + 1,
                    v.0,
                    v.1,
                    v.2
                );
            }
        }
        // how long each variant survives (t ≤ 0.5)
        let long = (0.5 / (0.2 * 3.0 / ns as f64)).round() as usize;
        println!("\nLagrangian Taylor–Green, n = {ns}, CFL 0.2, up to {long} steps (t = 0.5):\n");
        for v in FLOW_VARIANTS {
            let e = tg_steps(&tg(Motion::Lagrangian), Some(v), long)?;
            let (t, eu) = e.last().map(|l| (l.0, l.1)).unwrap_or((0.0, f64::NAN));
            let status = if e.len() < long {
                format!("failed in step {}", e.len() + 1)
            } else if eu.is_nan() || eu >= 1.0 {
                "diverged: error above 1".to_string()
            } else {
                "completed".to_string()
            };
            println!(
                "  {}: {} steps, t = {t:.3}, L1 velocity error {eu:.2e} ({status})",
                v.0,
                e.len()
            );
            let _ = writeln!(
                steps_csv,
                "Lagrangian-long,{},{ns},0.2,{},{t:.5},{eu:.6e},",
                v.0,
                e.len()
            );
        }
        // the same time with smaller steps: a per-projection error accumulates with the steps
        println!("\nLagrangian Taylor–Green, n = {ns}: L1 velocity error at t ≈ 0.1 against the CFL number\n");
        println!(
            "{:<10} {:>10} {:>10} {:>10}",
            "variant", "CFL 0.2", "CFL 0.1", "CFL 0.05"
        );
        for v in [FLOW_VARIANTS[0], FLOW_VARIANTS[3]] {
            let mut line = format!("{:<10}", v.0);
            for cfl in [0.2, 0.1, 0.05] {
                let mut c = tg(Motion::Lagrangian);
                c.limits.cfl = cfl;
                let k = (0.1 / (cfl * c.h_over_dx / ns as f64)).round() as usize;
                let e = tg_steps(&c, Some(v), k)?;
                match e.last() {
                    Some(last) if e.len() == k => {
                        let _ = write!(line, " {:>10.2e}", last.1);
                        let _ = writeln!(
                            steps_csv,
                            "Lagrangian,{},{ns},{cfl},{k},{:.5},{:.6e},{:.6e}",
                            v.0, last.0, last.1, last.2
                        );
                    }
                    _ => line.push_str("     failed"),
                }
            }
            println!("{line}");
        }
        write(&out.join("tg_steps.csv"), &steps_csv)?;
        // Lagrangian cavity against Ghia
        let mut base = CavityConfig::default().with(|c| {
            c.motion = Motion::Lagrangian;
            c.volumes = VolumeRule::NumberDensity;
        });
        base.n = args.cavity_n.unwrap_or(if args.quick { 24 } else { 50 });
        base.t_end = args
            .cavity_t_end
            .unwrap_or(if args.quick { 1.0 } else { 15.0 });
        println!(
            "\nLagrangian cavity, Re 100, n = {}, t_end ≤ {}: errors against Ghia et al. (lid-speed units)\n",
            base.n, base.t_end
        );
        println!(
            "{:<12} {:<13} | {:>8} {:>8} {:>8} {:>8} | {:>6} {:>6} {:>6} | {:>7} {:>7}",
            "weight",
            "gradient",
            "rms u",
            "max u",
            "rms v",
            "max v",
            "steps",
            "t",
            "steady",
            "wall s",
            "extra s"
        );
        for w in [Weight::WendlandC2, Weight::Poly { p: 2, m: 4 }] {
            for v in FLOW_VARIANTS {
                let mut cfg = base.clone();
                cfg.weight = w;
                let o = run_one(&cfg, v)?;
                println!(
                    "{:<12} {:<7} | {:>8.5} {:>8.5} {:>8.5} {:>8.5} | {:>6} {:>6.2} {:>6} | {:>7.1} {:>7.2}{}",
                    w.to_string(),
                    v.0,
                    o.rms_u,
                    o.max_u,
                    o.rms_v,
                    o.max_v,
                    o.steps,
                    o.t_end,
                    o.steady,
                    o.wall,
                    o.extra,
                    o.failed.as_ref().map(|m| format!("  FAILED: {m}")).unwrap_or_default()
                );
                let _ = writeln!(
                    csv,
                    "cavity,{w},{},{},{:.4},{},{:.3},{:.3},{:.6e},{:.6e},{:.6e},{:.6e},{},{}",
                    v.0,
                    cfg.n,
                    o.t_end,
                    o.steps,
                    o.wall,
                    o.extra,
                    o.rms_u,
                    o.max_u,
                    o.rms_v,
                    o.max_v,
                    o.steady,
                    o.failed.unwrap_or_default().replace(',', ";")
                );
            }
        }
        write(&out.join("flows.csv"), &csv)?;
        println!(
            "\nflows.csv: errors rms u, max u, rms v, max v against Ghia (NaN when the run failed)"
        );
        println!("\nflow part: {:.1} s", t0.elapsed().as_secs_f64());
        Ok(())
    }
}

// =============================================================================================
// Choosing the weight and h: the product's setting
// =============================================================================================
mod weights {
    use super::*;
    use gpm::scene::cavity::{self, CavityConfig};

    fn rel_l2(vol: &[f64], a: &[f64], b: &[f64]) -> f64 {
        let n: f64 = vol
            .iter()
            .zip(a.iter().zip(b))
            .map(|(w, (x, y))| w * (x - y).powi(2))
            .sum();
        let d: f64 = vol.iter().zip(b).map(|(w, y)| w * y * y).sum();
        (n / d).sqrt()
    }

    pub fn run(args: &Args, out: &Path) -> Result<()> {
        let t0 = Instant::now();
        println!("\n== Choosing the weight and h: number-density volumes, fixed h/Δx ==");
        let ws: Vec<Weight> = vec![
            Weight::CubicSpline,
            Weight::WendlandC2,
            Weight::WendlandC4,
            Weight::Poly { p: 1, m: 3 },
            Weight::Poly { p: 2, m: 3 },
            Weight::Poly { p: 2, m: 4 },
        ];
        let ratios = [2.5, 3.0, 4.0];
        let n = if args.quick { 32 } else { 50 };
        let dx = 1.0 / n as f64;
        let per = Periodicity::all([0.0, 0.0], [1.0, 1.0]);
        let configs = [
            ("lattice", lattice([0.0, 0.0], [1.0, 1.0], dx)),
            ("TG-advected t=0.05", projection::advected(n, 0.05)),
        ];
        let mut csv = String::from(
            "kind,config,weight,h_over_dx,neighbours,grad_err,lap_err,uniform_div_max,kick,rms_u,max_u,rms_v,max_v,steps,wall_s\n",
        );
        println!(
            "\noperators on a periodic box, n = {n}: relative ℓ2 errors of ∇h q and Δh q (q = sin 2πx sin 4πy / 2π), \
             max |∇̂h·(1,0)|, and the kick ‖P u_TG − u_TG‖/‖u_TG‖ of today's projection\n"
        );
        println!(
            "{:<19} {:<10} {:>5} | {:>5} {:>9} {:>9} {:>9} {:>9}",
            "configuration", "weight", "h/Δx", "nbrs", "∇h err", "Δh err", "∇̂h·1 max", "kick"
        );
        for (cname, x) in &configs {
            for &w in &ws {
                for &r in &ratios {
                    let nl = NeighborList::build(
                        NeighborConfig::new_relative(w, dx, r, 0.0).with_periodicity(per),
                        x,
                    )?;
                    let vol = number_density_volumes(&nl);
                    let qv: Vec<(f64, [f64; 2], f64)> = x.iter().map(projection::q).collect();
                    let qs: Vec<f64> = qv.iter().map(|e| e.0).collect();
                    let g = grad_diff(&nl, &vol, &qs);
                    let gx: Vec<f64> = g.iter().flat_map(|v| [v[0], v[1]]).collect();
                    let gex: Vec<f64> = qv.iter().flat_map(|e| [e.1[0], e.1[1]]).collect();
                    let vol2: Vec<f64> = vol.iter().flat_map(|&v| [v, v]).collect();
                    let e_g = rel_l2(&vol2, &gx, &gex);
                    let lq: Vec<f64> = qv.iter().map(|e| e.2).collect();
                    let e_l = rel_l2(&vol, &laplacian(&nl, &vol, &qs), &lq);
                    let du = div_sum(&nl, &vol, &vec![[1.0, 0.0]; x.len()]);
                    let du_max = du.iter().map(|v| v.abs()).fold(0.0, f64::max);
                    // one projection of the divergence-free field (Δt/ρ = 1)
                    let role = vec![Role::Fluid; x.len()];
                    let comps = connectivity(&nl, &role);
                    let udf: Vec<[f64; 2]> = x.iter().map(projection::u_df).collect();
                    let minus: Vec<[f64; 2]> = udf.iter().map(|a| [-a[0], -a[1]]).collect();
                    let rhs = div_sum(&nl, &vol, &minus);
                    let mut phi = vec![0.0; x.len()];
                    PoissonSolver::new().solve(
                        &nl,
                        &vol,
                        &role,
                        &comps,
                        &rhs,
                        &mut phi,
                        &SolveParams::default(),
                    )?;
                    let gp = grad_diff(&nl, &vol, &phi);
                    let kick = (vol.iter().zip(&gp).map(|(w, g)| w * norm2(g)).sum::<f64>()
                        / vol.iter().zip(&udf).map(|(w, u)| w * norm2(u)).sum::<f64>())
                    .sqrt();
                    let nb = nl.n_pairs() as f64 / x.len() as f64;
                    println!(
                        "{:<19} {:<10} {:>5.1} | {:>5.1} {:>9.2e} {:>9.2e} {:>9.3} {:>9.2e}",
                        cname,
                        w.to_string(),
                        r,
                        nb,
                        e_g,
                        e_l,
                        du_max,
                        kick
                    );
                    let _ = writeln!(
                        csv,
                        "operators,{cname},{w},{r},{nb:.1},{e_g:.6e},{e_l:.6e},{du_max:.6e},{kick:.6e},,,,,,"
                    );
                }
            }
        }
        // the default cavity (Eulerian, mirror ghosts) against Ghia
        let cn = if args.quick { 20 } else { 50 };
        let ct = if args.quick { 2.0 } else { 40.0 };
        let (cw, cr): (Vec<Weight>, Vec<f64>) = if args.quick {
            (
                vec![Weight::WendlandC2, Weight::Poly { p: 2, m: 4 }],
                vec![3.0],
            )
        } else {
            (ws.clone(), ratios.to_vec())
        };
        println!(
            "\ndefault cavity (Eulerian, mirror ghosts), Re 100, n = {cn}, to steadiness (t ≤ {ct}): errors against Ghia et al.\n"
        );
        println!(
            "{:<10} {:>5} | {:>8} {:>8} {:>8} {:>8} | {:>6} {:>7}",
            "weight", "h/Δx", "rms u", "max u", "rms v", "max v", "steps", "wall s"
        );
        for &w in &cw {
            for &r in &cr {
                let cfg = CavityConfig::default().with(|c| {
                    c.n = cn;
                    c.t_end = ct;
                    c.weight = w;
                    c.h_over_dx = r;
                });
                let res = cavity::run(&cfg, |_, _| Ok(()));
                match res {
                    Ok(res) => {
                        let g = res.ghia.unwrap_or_default();
                        println!(
                            "{:<10} {:>5.1} | {:>8.5} {:>8.5} {:>8.5} {:>8.5} | {:>6} {:>7.1}",
                            w.to_string(),
                            r,
                            g.rms_u,
                            g.max_u,
                            g.rms_v,
                            g.max_v,
                            res.steps,
                            res.wall_seconds
                        );
                        let _ = writeln!(
                            csv,
                            "cavity,eulerian,{w},{r},,,,,,{:.6e},{:.6e},{:.6e},{:.6e},{},{:.3}",
                            g.rms_u, g.max_u, g.rms_v, g.max_v, res.steps, res.wall_seconds
                        );
                    }
                    Err(e) => {
                        println!("{:<10} {:>5.1} | failed: {e}", w.to_string(), r);
                        let _ = writeln!(csv, "cavity,eulerian,{w},{r},,,,,,,,,,,");
                    }
                }
            }
        }
        write(&out.join("weights.csv"), &csv)?;
        println!("\nweights part: {:.1} s", t0.elapsed().as_secs_f64());
        Ok(())
    }
}
