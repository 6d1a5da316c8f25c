//! Re-running recorded projections through the current build (`gpm replay --rerun`).
//!
//! For each `/projection_input` message: check the recorded particles as the library checks a
//! caller's (lengths, roles and ghost sources, finite positions, positive volumes; a corrupt file
//! is a typed error, never a panic), rebuild the neighbour list from the recorded positions
//! and [`NeighborSpec`](super::schema::NeighborSpec), the boundary from its
//! [`BoundarySpec`](super::schema::BoundarySpec), set the particles (positions, volumes, roles,
//! `p = pⁿ`) and `u*`, give a fresh step the recorded singular part when there is one (the
//! lid corners' subtracted flow, [`ProjectionStep::singular`]), call
//! [`ProjectionStep::project`], and compare `u`, `p` and `φ` with the recorded outputs.
//!
//! **When the results are identical, and when not.** With the Cholesky solver (the default in
//! 2D) every stage is deterministic and independent of the thread count: operators sum each row
//! sequentially in neighbour order, and the factorisation runs sequentially. The rerun is then
//! bit-identical as long as the Poisson matrix has the same sparsity pattern, which is built from
//! the neighbour *candidates* (pairs within `h + skin` at the last neighbour search): a fresh list
//! finds the candidates at the recorded positions. Particles that never move (Eulerian frame)
//! give the same candidates; in a Lagrangian run the original candidates were found some steps
//! earlier, the pattern has other explicit zeros, the fill-reducing ordering differs and so does
//! the round-off (differences at the level of the solve's residual). With conjugate gradients the
//! re-run starts from the recorded warm start (`phi_in`), but the dot products are rayon
//! reductions whose association depends on the thread count and on work stealing, so the
//! difference is bounded by the solver tolerance instead.

use super::replay::{scan, Scan};
use super::schema::{decode_roles, ProjectionInput, TOPIC_PROJECTION};
use super::RecordError;
use crate::neighbors::NeighborList;
use crate::particles::Particles;
use crate::projection::{checks, ProjectionStep, SingularPart};
use serde::{Deserialize, Serialize};
use std::path::Path;
use std::time::Instant;

/// The comparison for one recorded projection.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct RerunStep {
    /// Step.
    pub step: u64,
    /// Particles (ghosts included).
    pub particles: usize,
    /// `max_i |u_i − u_i^rec|` (all components).
    pub max_du: f64,
    /// `max_i |p_i − p_i^rec|`.
    pub max_dp: f64,
    /// `max_i |φ_i − φ_i^rec|`.
    pub max_dphi: f64,
    /// `max_du / max_i |u_i^rec|` (0 when the recorded field is zero).
    pub rel_du: f64,
    /// `max_dp / max_i |p_i^rec|`.
    pub rel_dp: f64,
    /// `max_dphi / max_i |φ_i^rec|`.
    pub rel_dphi: f64,
    /// Every value is bit-identical.
    pub identical: bool,
    /// Seconds of the re-run (neighbour list + projection).
    pub seconds: f64,
}

/// The comparison over a file.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RerunReport {
    /// Per recorded projection.
    pub steps: Vec<RerunStep>,
    /// Thread counts of the recording run (distinct values seen).
    pub recorded_threads: Vec<usize>,
    /// Rayon threads of this re-run.
    pub threads: usize,
    /// What the scan found (damage included).
    pub scan: Scan,
}

impl RerunReport {
    /// Largest of each difference over all steps: `(du, dp, dphi)`.
    pub fn max_differences(&self) -> (f64, f64, f64) {
        self.steps.iter().fold((0.0, 0.0, 0.0), |m, s| {
            (m.0.max(s.max_du), m.1.max(s.max_dp), m.2.max(s.max_dphi))
        })
    }
    /// Largest relative differences `(du, dp, dphi)`.
    pub fn max_relative_differences(&self) -> (f64, f64, f64) {
        self.steps.iter().fold((0.0, 0.0, 0.0), |m, s| {
            (m.0.max(s.rel_du), m.1.max(s.rel_dp), m.2.max(s.rel_dphi))
        })
    }
    /// Steps reproduced bit for bit.
    pub fn identical(&self) -> usize {
        self.steps.iter().filter(|s| s.identical).count()
    }
}

fn diff(a: &[f64], b: &[f64]) -> (f64, f64, bool) {
    let mut d = 0.0f64;
    let mut m = 0.0f64;
    let mut same = a.len() == b.len();
    for (x, y) in a.iter().zip(b) {
        if x.to_bits() != y.to_bits() {
            same = false;
        }
        let e = (x - y).abs();
        d = if e.is_nan() { f64::INFINITY } else { d.max(e) };
        m = m.max(y.abs());
    }
    (d, if m > 0.0 { d / m } else { d }, same)
}

fn rerun_d<const D: usize>(m: &ProjectionInput) -> Result<RerunStep, crate::Error> {
    let t0 = Instant::now();
    let x = m.x.to_vectors::<D>("x")?;
    let n = x.len();
    let vol = m.vol.to_f64("vol")?;
    let role = decode_roles(&m.role_kind, &m.ghost_source, &m.ghost_walls)?;
    let u_star = m.u_star.to_vectors::<D>("u_star")?;
    let p_in = m.p_in.to_f64("p_in")?;
    let phi_in = m.phi_in.to_f64("phi_in")?;
    let u_out = m.u_out.to_vectors::<D>("u_out")?;
    let p_out = m.p_out.to_f64("p_out")?;
    let phi = m.phi.to_f64("phi")?;
    let singular = match (&m.singular_source, &m.singular_no_slip) {
        (None, None) => None,
        (Some(source), Some(no_slip)) => Some(SingularPart {
            source: source.to_vectors::<D>("singular_source")?,
            no_slip: no_slip.to_vectors::<D>("singular_no_slip")?,
        }),
        (source, _) => {
            return Err(RecordError::Spec {
                what: if source.is_some() {
                    "singular_no_slip"
                } else {
                    "singular_source"
                },
                reason: "missing: the singular part is recorded in both continuations or in \
                         neither"
                    .into(),
            }
            .into())
        }
    };
    let (source_len, no_slip_len) = singular
        .as_ref()
        .map_or((n, n), |s| (s.source.len(), s.no_slip.len()));
    for (what, len) in [
        ("vol", vol.len()),
        ("roles", role.len()),
        ("u_star", u_star.len()),
        ("p_in", p_in.len()),
        ("phi_in", phi_in.len()),
        ("u_out", u_out.len()),
        ("p_out", p_out.len()),
        ("phi", phi.len()),
        ("singular_source", source_len),
        ("singular_no_slip", no_slip_len),
    ] {
        if len != n {
            return Err(RecordError::Spec {
                what,
                reason: format!("{len} entries for {n} positions"),
            }
            .into());
        }
    }
    let config = m.neighbors.to_config::<D>()?;
    let boundary = m.boundary.build::<D>()?;
    let params = m.params.to_params::<D>()?;
    let mut particles = Particles::<D>::new();
    for i in 0..n {
        particles.push(x[i], u_star[i], p_in[i], vol[i], role[i]);
    }
    // the recorded bookkeeping is checked as the library checks a caller's particles (roles in
    // order, every ghost's source a fluid particle before the ghosts, finite positions and
    // volumes) before anything is built from it; `project` checks the rest (ghost placement,
    // the list against the positions, h)
    checks::check_particles(&particles, checks::Reads { velocity: false })?;
    let nl = NeighborList::build(config, &x)?;
    let mut step = ProjectionStep::<D>::new();
    step.phi = phi_in;
    step.singular = singular;
    step.project(
        &mut particles,
        &nl,
        boundary.as_ref(),
        &params,
        m.dt,
        &u_star,
    )?;
    let flat = |v: &[[f64; D]]| v.iter().flatten().copied().collect::<Vec<f64>>();
    let (max_du, rel_du, su) = diff(&flat(&particles.u), &flat(&u_out));
    let (max_dp, rel_dp, sp) = diff(&particles.p, &p_out);
    let (max_dphi, rel_dphi, sf) = diff(&step.phi, &phi);
    Ok(RerunStep {
        step: m.step,
        particles: n,
        max_du,
        max_dp,
        max_dphi,
        rel_du,
        rel_dp,
        rel_dphi,
        identical: su && sp && sf,
        seconds: t0.elapsed().as_secs_f64(),
    })
}

/// Re-runs one recorded projection and compares it with the recorded output.
pub fn rerun_input(m: &ProjectionInput) -> Result<RerunStep, crate::Error> {
    match m.dimension {
        2 => rerun_d::<2>(m),
        3 => rerun_d::<3>(m),
        d => Err(RecordError::Spec {
            what: "dimension",
            reason: format!("{d} (gpm runs in 2 or 3 dimensions)"),
        }
        .into()),
    }
}

/// Re-runs every `/projection_input` of the file at `path` (a damaged file up to its last
/// complete chunk); `progress` gets `(bytes read, file size)`.
pub fn rerun_file(path: &Path, progress: impl FnMut(u64, u64)) -> Result<RerunReport, RecordError> {
    let mut steps = Vec::new();
    let mut recorded_threads = Vec::new();
    let scan = scan(
        path,
        |msg| {
            if msg.topic != TOPIC_PROJECTION {
                return Ok(());
            }
            let m: ProjectionInput = msg.decode()?;
            if !recorded_threads.contains(&m.threads) {
                recorded_threads.push(m.threads);
            }
            let r = rerun_input(&m).map_err(|e| RecordError::Rerun {
                path: path.to_path_buf(),
                step: m.step,
                source: Box::new(e),
            })?;
            steps.push(r);
            Ok(())
        },
        progress,
    )?;
    Ok(RerunReport {
        steps,
        recorded_threads,
        threads: rayon::current_num_threads(),
        scan,
    })
}
