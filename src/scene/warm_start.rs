//! A run's initial fluid state from another run's final particles (a warm start): the velocity
//! and pressure of the file's fluid particles, sampled at the new run's fluid particles.
//!
//! The file is what [`crate::particles::Particles::fluid_csv`] writes (the examples'
//! `--particles-csv`): a header `x,y,u,v,p` (2D) or `x,y,z,u,v,w,p` (3D), then one row per
//! fluid particle. The new run's particles keep their own positions; at each fluid particle the
//! file's `u` and `p` are fitted by the [`Sampler`]'s quadratic moving least squares over the
//! file's fluid particles within [`SUPPORT`] `Δx_file` (`Δx_file` the median nearest-neighbour
//! distance of the file's particles) — one-sided at the walls, where the file has no ghosts; the
//! radius is wide enough for the quadratic fit at a lattice's corner (about 16 particles in a
//! quarter disk in 2D, 48 in an eighth of a ball in 3D, against the 12 and 20 it needs), so a
//! quadratic field is carried exactly everywhere. Everything else starts as in a cold start
//! (the ghosts take their values from the boundary's rules at the first step; the explicit
//! terms' history is empty, so the first step is Euler's).
//!
//! This is grid sequencing: a steady state reached at a coarse resolution carried to a fine one,
//! which then only has to settle the difference (the steady state of the fine run does not
//! depend on where it started). Scenes take it from the configuration key `initial` (a path).

use crate::boundary::Boundary;
use crate::error::{Error, InputError};
use crate::flow::Simulation;
use crate::kernel::Kernel;
use crate::sampling::Sampler;
use kiddo::{ImmutableKdTree, SquaredEuclidean};
use std::path::Path;

/// Radius of the sampling fit, in spacings of the snapshot's particles.
pub const SUPPORT: f64 = 4.5;

/// The fluid particles of a finished run: positions, velocities, pressures.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct FluidSnapshot<const D: usize> {
    /// Positions.
    pub x: Vec<[f64; D]>,
    /// Velocities.
    pub u: Vec<[f64; D]>,
    /// Pressures.
    pub p: Vec<f64>,
}

/// The error of a bad snapshot file: the configuration key `initial`, the file and what is wrong.
fn bad(source: &str, reason: impl std::fmt::Display) -> InputError {
    InputError::Config {
        key: "initial".into(),
        reason: format!("{source}: {reason}"),
    }
}

impl<const D: usize> FluidSnapshot<D> {
    /// Parses the CSV text of [`crate::particles::Particles::fluid_csv`]; `source` names it in
    /// errors (a path). Fails naming the line on a header for another dimension, a row with the
    /// wrong number of fields, a field that is not a finite number, and on a file without rows.
    pub fn from_csv(text: &str, source: &str) -> Result<Self, InputError> {
        let want = crate::particles::Particles::<D>::fluid_csv_columns();
        let mut lines = text
            .lines()
            .enumerate()
            .filter(|(_, l)| !l.trim().is_empty());
        let Some((_, header)) = lines.next() else {
            return Err(bad(source, "empty file"));
        };
        let got: Vec<&str> = header.split(',').map(str::trim).collect();
        if got != want {
            return Err(bad(
                source,
                format!(
                    "line 1: header '{}', expected '{}' (the fluid particles of a {D}D run)",
                    header.trim(),
                    want.join(",")
                ),
            ));
        }
        let mut snap = FluidSnapshot::default();
        for (k, line) in lines {
            let fields: Vec<&str> = line.split(',').map(str::trim).collect();
            if fields.len() != want.len() {
                return Err(bad(
                    source,
                    format!(
                        "line {}: {} fields, expected {}",
                        k + 1,
                        fields.len(),
                        want.len()
                    ),
                ));
            }
            let mut v = [0.0; 7];
            for (c, f) in fields.iter().enumerate() {
                v[c] = match f.parse::<f64>() {
                    Ok(a) if a.is_finite() => a,
                    _ => {
                        return Err(bad(
                            source,
                            format!("line {}: {} = '{f}' is not a finite number", k + 1, want[c]),
                        ))
                    }
                };
            }
            snap.x.push(std::array::from_fn(|a| v[a]));
            snap.u.push(std::array::from_fn(|a| v[D + a]));
            snap.p.push(v[2 * D]);
        }
        if snap.x.is_empty() {
            return Err(bad(source, "no particles (a header only)"));
        }
        Ok(snap)
    }

    /// Reads and parses the file at `path` ([`FluidSnapshot::from_csv`]); an unreadable file is
    /// named too.
    pub fn read(path: &Path) -> Result<Self, InputError> {
        let name = path.display().to_string();
        let text = std::fs::read_to_string(path).map_err(|e| bad(&name, e))?;
        Self::from_csv(&text, &name)
    }

    /// The snapshot's particle spacing: the median distance of a particle to its nearest other
    /// particle (`None` with fewer than two particles, or when all coincide).
    pub fn spacing(&self) -> Option<f64> {
        if self.x.len() < 2 {
            return None;
        }
        let tree = ImmutableKdTree::<f64, D>::new_from_slice(&self.x).ok()?;
        let mut d: Vec<f64> = self
            .x
            .iter()
            .map(|q| {
                tree.query(q)
                    .nearest_n::<SquaredEuclidean<f64>>(std::num::NonZero::new(2).unwrap())
                    .execute()
                    .iter()
                    .map(|nb| nb.distance)
                    .fold(0.0, f64::max)
                    .sqrt()
            })
            .collect();
        d.sort_by(f64::total_cmp);
        let m = d[d.len() / 2];
        (m > 0.0).then_some(m)
    }
}

/// Sets the velocity and pressure of `sim`'s fluid particles from `snap` (module doc): moving
/// least squares over the snapshot's particles within [`SUPPORT`] times its spacing, with
/// `sim`'s weight and periodicity. Fails naming the key `initial` when the snapshot has no
/// spacing, and naming the first fluid particle the snapshot does not reach (no snapshot
/// particle within `h`: the file is of another domain).
pub fn apply<const D: usize, B: Boundary<D>>(
    sim: &mut Simulation<D, B>,
    snap: &FluidSnapshot<D>,
) -> Result<(), Error> {
    let spacing = snap
        .spacing()
        .ok_or_else(|| bad("the snapshot", "fewer than two distinct particles"))?;
    let kernel = Kernel::<D>::new(sim.nl.kernel().weight(), SUPPORT * spacing);
    let sampler = Sampler::new(&snap.x, kernel, sim.nl.config().periodic);
    let p = &mut sim.particles;
    let fluid: Vec<usize> = (0..p.len()).filter(|&i| p.role[i].is_fluid()).collect();
    let at: Vec<[f64; D]> = fluid.iter().map(|&i| p.x[i]).collect();
    let u = sampler.sample(&snap.u, &at);
    let pr: Vec<[f64; 1]> = snap.p.iter().map(|&v| [v]).collect();
    let pr = sampler.sample(&pr, &at);
    for (k, &i) in fluid.iter().enumerate() {
        if !(u[k].iter().all(|v| v.is_finite()) && pr[k][0].is_finite()) {
            return Err(InputError::OutsideDomain {
                particle: i,
                position: p.x[i].to_vec(),
                reason: format!(
                    "no particle of the initial state (key 'initial') within {:.3e} of it",
                    kernel.h()
                ),
            }
            .into());
        }
        p.u[i] = u[k];
        p.p[i] = pr[k][0];
    }
    Ok(())
}
