//! The input checks of the plug-in path: what [`super::ProjectionStep::predict`] and
//! [`super::ProjectionStep::project`] verify before they compute anything, each failure a typed
//! [`InputError`] naming the particle (or key) and the cause. All are `O(N)` or `O(pairs)`.
//!
//! * lengths of `u`, `p`, `vol`, `role` (and `u*`, `accel`) against the positions, and of the
//!   neighbour list's rows;
//! * roles: ghosts stored after every other particle, each with a fluid source;
//! * finite positions, velocities, pressures (`u*` and `accel` where given), at the first
//!   particle that is not;
//! * positive finite volumes;
//! * a neighbour list measured at these positions: every stored pair's `x_j − x_i` equals the
//!   positions' (a list not updated after the particles moved fails here; a particle that moved
//!   without any neighbour is caught by the connectivity check), and the boundary's periodicity;
//! * `h` above the minimum particle spacing (else no particle has a neighbour);
//! * the boundary's own check ([`Boundary::check_ghosts`]): for walls, ghosts at the images of
//!   their sources (`place_ghosts` was called) and an image for every fluid particle closer than
//!   `h` to a wall (the ghosts were made with a reach of at least `h`).

use crate::boundary::{first_ghost, Boundary};
use crate::error::InputError;
use crate::math::{first_where, is_finite};
use crate::neighbors::{NeighborList, Periodicity};
use crate::particles::{Particles, Role};

/// Which per-particle values a stage reads (so that the checks cover exactly those).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Reads {
    /// The velocity `uⁿ` (the predictor reads it; the projection reads `u*` instead).
    pub velocity: bool,
}

/// Lengths, roles, finiteness and volumes of `particles` (values of ghosts are not checked:
/// they are refilled from their sources; their positions and volumes are).
pub fn check_particles<const D: usize>(
    particles: &Particles<D>,
    reads: Reads,
) -> Result<(), InputError> {
    let n = particles.x.len();
    for (field, len) in [
        ("u", particles.u.len()),
        ("p", particles.p.len()),
        ("vol", particles.vol.len()),
        ("role", particles.role.len()),
    ] {
        if len != n {
            return Err(InputError::LengthMismatch {
                field,
                len,
                expected: n,
            });
        }
    }
    check_roles(&particles.role)?;
    let bad = first_where(n, |i| {
        let ghost = matches!(particles.role[i], Role::Ghost { .. });
        !is_finite(&particles.x[i])
            || (!ghost && reads.velocity && !is_finite(&particles.u[i]))
            || (!ghost && !particles.p[i].is_finite())
            || !(particles.vol[i] > 0.0 && particles.vol[i].is_finite())
    });
    if let Some(i) = bad {
        let ghost = matches!(particles.role[i], Role::Ghost { .. });
        let field = if !is_finite(&particles.x[i]) {
            "position"
        } else if !ghost && reads.velocity && !is_finite(&particles.u[i]) {
            "velocity"
        } else if !ghost && !particles.p[i].is_finite() {
            "pressure"
        } else {
            return Err(InputError::BadVolume {
                particle: i,
                value: particles.vol[i],
            });
        };
        return Err(InputError::NonFinite { field, particle: i });
    }
    Ok(())
}

/// Ghosts after every other particle, each with a fluid source before the first ghost.
pub fn check_roles(role: &[Role]) -> Result<(), InputError> {
    let first = first_ghost(role);
    for (i, r) in role.iter().enumerate().skip(first) {
        match *r {
            Role::Ghost { source, .. } => {
                let s = source as usize;
                if s >= first || !role[s].is_real() {
                    return Err(InputError::BadGhostSource {
                        particle: i,
                        source_particle: s,
                    });
                }
            }
            _ => {
                return Err(InputError::Ghost {
                    particle: i,
                    reason: format!(
                        "a non-ghost particle after the first ghost {first}: ghosts must be \
                         stored after every other particle (Boundary::make_ghosts does so)"
                    ),
                })
            }
        }
    }
    Ok(())
}

/// A per-particle field (`u*`, `accel`) of the right length with finite values on every particle
/// that is not a ghost. With `ghosts_optional` the field may stop at the first ghost or extend
/// beyond the particles (ghost entries are refilled, extra ones ignored: the ghosts may have been
/// regenerated since the field was computed), else its length must be the particles'.
pub fn check_field<const D: usize>(
    field: &'static str,
    v: &[[f64; D]],
    role: &[Role],
    ghosts_optional: bool,
) -> Result<(), InputError> {
    let n = role.len();
    let first = first_ghost(role);
    let ok_len = if ghosts_optional {
        v.len() >= first
    } else {
        v.len() == n
    };
    if !ok_len {
        return Err(InputError::LengthMismatch {
            field,
            len: v.len(),
            expected: if ghosts_optional { first } else { n },
        });
    }
    if let Some(i) = first_where(first, |i| !is_finite(&v[i])) {
        return Err(InputError::NonFinite { field, particle: i });
    }
    Ok(())
}

/// The neighbour list belongs to these positions: as many rows as particles, the boundary's
/// periodicity, and every stored pair's displacement `x_j − x_i` (minimum image) bit-identical
/// to the one the list would measure now. Names the first particle whose row does not match.
pub fn check_neighbors<const D: usize>(
    nl: &NeighborList<D>,
    x: &[[f64; D]],
    periodic: &Periodicity<D>,
) -> Result<(), InputError> {
    if nl.len() != x.len() {
        return Err(InputError::LengthMismatch {
            field: "neighbor list rows",
            len: nl.len(),
            expected: x.len(),
        });
    }
    let per = nl.config().periodic;
    if per != *periodic {
        return Err(InputError::Config {
            key: "neighbors.periodic".into(),
            reason: format!(
                "the neighbour list's periodic axes {:?} differ from the boundary's {:?}: build \
                 the list with NeighborConfig::with_periodicity(boundary.periodicity())",
                per.len, periodic.len
            ),
        });
    }
    // the list recorded the positions it measured: equal fingerprints, nothing to compare
    if nl.measured_at() != 0 && nl.measured_at() == crate::neighbors::positions_hash(x) {
        return Ok(());
    }
    let bad = first_where(x.len(), |i| {
        nl.row(i).any(|k| {
            let j = nl.indices()[k] as usize;
            let mut d: [f64; D] = std::array::from_fn(|a| x[j][a] - x[i][a]);
            per.min_image(&mut d);
            d != nl.dx()[k]
        })
    });
    if let Some(i) = bad {
        let k = nl.row(i).start;
        let j = nl.indices()[k] as usize;
        return Err(InputError::StaleNeighbors {
            particle: i,
            reason: format!(
                "its pair with particle {j} was measured at a different position; call \
                 NeighborList::update(&x) after moving particles (and after place_ghosts)"
            ),
        });
    }
    Ok(())
}

/// `h` above the minimum spacing: a list without a single pair for two or more particles means
/// `h ≤ min r_ij` ([`InputError::RadiusTooSmall`], naming the closest pair).
pub fn check_spacing<const D: usize>(
    nl: &NeighborList<D>,
    x: &[[f64; D]],
) -> Result<(), InputError> {
    if nl.n_pairs() > 0 || x.len() < 2 {
        return Ok(());
    }
    let per = nl.config().periodic;
    let (min_spacing, i, j) = closest_pair(x, &per);
    Err(InputError::RadiusTooSmall {
        h: nl.h(),
        min_spacing,
        i,
        j,
    })
}

/// The closest pair `(distance, i, j)` (`i < j`, minimum image), by a sweep along axis 0
/// (`O(N log N)` for spread-out points); only called on the error path.
fn closest_pair<const D: usize>(x: &[[f64; D]], per: &Periodicity<D>) -> (f64, usize, usize) {
    let dist = |i: usize, j: usize| {
        let mut d: [f64; D] = std::array::from_fn(|a| x[j][a] - x[i][a]);
        per.min_image(&mut d);
        d.iter().map(|v| v * v).sum::<f64>().sqrt()
    };
    let mut best = (f64::INFINITY, 0, 1);
    if per.any() {
        // images make the sweep order invalid: the error path may afford O(N²)
        for i in 0..x.len() {
            for j in i + 1..x.len() {
                let r = dist(i, j);
                if r < best.0 {
                    best = (r, i, j);
                }
            }
        }
        return best;
    }
    let mut order: Vec<usize> = (0..x.len()).collect();
    order.sort_by(|&a, &b| x[a][0].total_cmp(&x[b][0]));
    for (a, &i) in order.iter().enumerate() {
        for &j in &order[a + 1..] {
            if x[j][0] - x[i][0] > best.0 {
                break;
            }
            let r = dist(i, j);
            let (lo, hi) = (i.min(j), i.max(j));
            if r < best.0 || (r == best.0 && (lo, hi) < (best.1, best.2)) {
                best = (r, lo, hi);
            }
        }
    }
    best
}

/// Every check of the plug-in path on the particles, the list and the boundary (see the module
/// documentation).
pub fn check_configuration<const D: usize>(
    particles: &Particles<D>,
    nl: &NeighborList<D>,
    boundary: &dyn Boundary<D>,
    reads: Reads,
) -> Result<(), InputError> {
    check_particles(particles, reads)?;
    check_neighbors(nl, &particles.x, &boundary.periodicity())?;
    check_spacing(nl, &particles.x)?;
    boundary.check_ghosts(particles, nl.h())
}
