//! Preparing a particle configuration for the projection in the right order, so that a caller
//! of [`crate::projection::ProjectionStep`] cannot get it wrong:
//!
//! 1. positions confined to the domain (periodic wrap; a fluid particle outside a wall is an
//!    error);
//! 2. ghosts: the images of the fluid particles within `reach = h + skin` of a wall
//!    ([`Boundary::make_ghosts`]);
//! 3. the neighbour list at the positions, ghosts included, with the boundary's periodicity;
//! 4. volumes (`ω_i = 1/Σ_j w_h(r_ij)` on the fluid for [`VolumeRule::NumberDensity`], kept
//!    for [`VolumeRule::Fixed`]);
//! 5. [`Boundary::place_ghosts`], which copies the sources' volumes into the ghosts.
//!
//! 6. with [`PairWeights::Moment`], the moment-consistent pair weights
//!    ([`crate::pair_weights`]), after the volumes (which use the plain `w_h`): [`prepare_with`],
//!    [`update_with`].
//!
//! [`prepare`] does this once; [`update`] after the particles moved (re-making the ghosts when
//! the list has to search again). The projection's checks
//! ([`crate::projection::checks`]) report a configuration that skipped a step.

use crate::boundary::Boundary;
use crate::error::Error;
use crate::geometry::number_density_volume;
use crate::neighbors::{NeighborConfig, NeighborList};
use crate::pair_weights::{MomentWeights, PairWeights};
use crate::particles::{Particles, Role};
use crate::projection::checks::check_spacing;

/// How particle volumes are set.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum VolumeRule {
    /// `ω_i = 1 / Σ_{j≠i} w_h(r_ij)`, recomputed every step (MISSION §2's consistency fix).
    #[default]
    NumberDensity,
    /// Kept as given.
    Fixed,
}

/// Ghosts, neighbour list, volumes and ghost placement for `particles` (fluid and Dirichlet
/// particles; any ghosts present are dropped and made again). The list takes its periodicity
/// from `boundary`. Fails on invalid particles, a fluid particle outside the domain, and
/// `h` at or below the minimum spacing.
///
/// ```
/// use gpm::boundary::Walls;
/// use gpm::geometry::lattice;
/// use gpm::kernel::Weight;
/// use gpm::neighbors::NeighborConfig;
/// use gpm::particles::{Particles, Role};
/// use gpm::setup::{prepare, VolumeRule};
///
/// let dx = 0.05;
/// // a channel 0 ≤ y ≤ 0.5, periodic in x with period 1
/// let walls = Walls::channel([0.0, 0.0], [1.0, 0.5]);
/// let mut particles = Particles::<2>::new();
/// for x in lattice([0.0, 0.0], [1.0, 0.5], dx) {
///     particles.push(x, [1.0, 0.0], 0.0, dx * dx, Role::Fluid);
/// }
/// let fluid = particles.len();
/// let config = NeighborConfig::new_relative(Weight::WendlandC2, dx, 3.0, 0.2);
/// let nl = prepare(&mut particles, &walls, config, VolumeRule::NumberDensity)?;
/// assert!(particles.len() > fluid); // ghosts beyond both walls
/// assert_eq!(nl.len(), particles.len());
/// assert!(nl.config().periodic.len[0] == 1.0);
/// # Ok::<(), gpm::Error>(())
/// ```
pub fn prepare<const D: usize>(
    particles: &mut Particles<D>,
    boundary: &dyn Boundary<D>,
    config: NeighborConfig<D>,
    volumes: VolumeRule,
) -> Result<NeighborList<D>, Error> {
    particles.validate()?;
    boundary.confine(particles)?;
    let config = config.with_periodicity(boundary.periodicity());
    if boundary.has_ghosts() {
        boundary.make_ghosts(particles, config.h + config.skin);
    }
    let nl = NeighborList::build(config, &particles.x)?;
    check_spacing(&nl, &particles.x)?;
    set_volumes(particles, boundary, &nl, volumes);
    Ok(nl)
}

/// The Dirichlet band's volumes continued from the fluid: each band particle with fluid
/// neighbours within `h` (wall images of fluid particles included) takes the Shepard mean
/// `Σ w_ij ω_j / Σ w_ij` of their volumes; the others and the fluid keep theirs, and ghosts of
/// band particles take their source's. The number-density volume `1/Σ_j w_ij` of a particle
/// whose support the edge of the particle set cuts (the outer rows of a band) is too large,
/// and the band's volumes enter the fluid's Poisson rows (`2d ω_j w_ij/r_ij²`): on a
/// Vogel-spiral disk with a band of width `h` they distort the Laplacian of the fluid
/// particles next to the band (see [`crate::projection::surface`]).
pub fn band_volumes_from_fluid<const D: usize>(p: &mut Particles<D>, nl: &NeighborList<D>) {
    let new: Vec<(usize, f64)> = (0..p.len().min(nl.len()))
        .filter(|&i| p.role[i] == Role::Dirichlet)
        .filter_map(|i| {
            crate::projection::stages::fluid_shepard(nl, &p.role, i, |j| [p.vol[j]])
                .map(|[v]| (i, v))
        })
        .collect();
    for (i, v) in new {
        p.vol[i] = v;
    }
    for g in 0..p.len() {
        if let Role::Ghost { source, .. } = p.role[g] {
            p.vol[g] = p.vol[source as usize];
        }
    }
}

/// [`prepare`], then the pair weights `weights` (for [`PairWeights::Moment`], computed by
/// `state`, which keeps the multipliers for warm starts in [`update_with`]).
pub fn prepare_with<const D: usize>(
    particles: &mut Particles<D>,
    boundary: &dyn Boundary<D>,
    config: NeighborConfig<D>,
    volumes: VolumeRule,
    weights: PairWeights,
    state: &mut MomentWeights<D>,
) -> Result<NeighborList<D>, Error> {
    let mut nl = prepare(particles, boundary, config, volumes)?;
    state.apply(weights, &mut nl, particles, boundary)?;
    Ok(nl)
}

/// [`update`], then the pair weights (see [`prepare_with`]).
pub fn update_with<const D: usize>(
    particles: &mut Particles<D>,
    boundary: &dyn Boundary<D>,
    nl: &mut NeighborList<D>,
    volumes: VolumeRule,
    weights: PairWeights,
    state: &mut MomentWeights<D>,
) -> Result<bool, Error> {
    let rebuilt = update(particles, boundary, nl, volumes)?;
    state.apply(weights, nl, particles, boundary)?;
    Ok(rebuilt)
}

/// After the particles moved: confines them, places the ghosts, updates `nl` (re-making the
/// ghosts first when the list has to search again, so that they cover `h + skin`), the volumes
/// and the ghosts' volumes. Returns true when the candidates were rebuilt.
pub fn update<const D: usize>(
    particles: &mut Particles<D>,
    boundary: &dyn Boundary<D>,
    nl: &mut NeighborList<D>,
    volumes: VolumeRule,
) -> Result<bool, Error> {
    boundary.confine(particles)?;
    let ghosts = boundary.has_ghosts();
    if ghosts {
        boundary.place_ghosts(particles);
    }
    let mut rebuilt = false;
    if nl.needs_rebuild(&particles.x) {
        if ghosts {
            let c = nl.config();
            let reach = c.h + c.skin;
            boundary.make_ghosts(particles, reach);
        }
        nl.invalidate();
        rebuilt = true;
    }
    nl.update(&particles.x)?;
    set_volumes(particles, boundary, nl, volumes);
    Ok(rebuilt)
}

fn set_volumes<const D: usize>(
    particles: &mut Particles<D>,
    boundary: &dyn Boundary<D>,
    nl: &NeighborList<D>,
    volumes: VolumeRule,
) {
    if volumes == VolumeRule::NumberDensity {
        let p = &mut *particles;
        for ((vol, r), &s) in p.vol.iter_mut().zip(&p.role).zip(nl.w_sums()) {
            if r.is_fluid() {
                *vol = number_density_volume(s);
            }
        }
    }
    if boundary.has_ghosts() {
        boundary.place_ghosts(particles);
    }
}
