//! The stages of the projection as public functions with explicit inputs and outputs.
//!
//! [`super::ProjectionStep::project`] runs, in order:
//!
//! | stage | function | computes |
//! | --- | --- | --- |
//! | ghosts of `u*` | [`crate::boundary::Boundary::fill_vector`] | `u*` on the ghosts from their sources (no-slip rule) |
//! | source field | [`source_field`] | `f = −(ρ/Δt) u*`, zero on the Dirichlet band, ghosts continued by `source_ghosts` |
//! | source | [`divergence_into`] | `b = D f` with `D` the chosen [`SourceKind`] |
//! | Poisson solve | [`crate::poisson::PoissonSolver::solve`] | `−Δh φ = b` |
//! | correction | [`correct`] | `uⁿ⁺¹ = u* − (Δt/ρ) G φ`, `pⁿ⁺¹` by the scheme |
//! | measurement | [`measure_divergence`], [`energy`], [`crate::diagnostics::stability_ratio`] | `div`, kinetic energy, max speed, the Theorem 4.5 ratio |
//!
//! A caller can run them one by one (e.g. to insert its own step between the solve and the
//! correction); the functions neither allocate more than their outputs nor check their input
//! (see [`super::checks`]).

use super::{ProjectionParams, Scheme, SourceKind};
use crate::boundary::{Boundary, VectorKind};
use crate::consistent::{div_renormalised_gain_into, div_renormalised_into, GradientOperator};
use crate::diagnostics::{norm_l2, Region};
use crate::error::{InputError, SolveError};
use crate::math::norm2;
use crate::neighbors::NeighborList;
use crate::operators::{div_sum_gain_into, div_sum_into};
use crate::particles::Role;
use rayon::prelude::*;

/// The source field `f_i = scale · v_i` (the projection uses `scale = −ρ/Δt`, `v = u*`) on the
/// fluid and the ghosts, and on the Dirichlet band `f_i = 0` (the paper's `f̂`, which the
/// adjointness of the sum-form pair needs) or, with a consistent divergence (`kind`
/// renormalised or least-squares), the band's own `scale · v_i`: a consistent divergence of the
/// field the particles carry (zeroing the band would make a divergence-free field look
/// divergent within `h` of it — at a free surface, the water flowing toward its moving surface
/// would look compressed); when the boundary has ghosts and
/// `ghost_rule` is [`VectorKind::Mirror`] or [`VectorKind::RestWalls`], the ghosts are refilled
/// by that rule (`x`: the positions, which [`VectorKind::RestWalls`]'s band reads; else they
/// keep `scale` times the ghost values of `v`, which the caller filled by the no-slip rule).
///
/// With [`VectorKind::RestWallsLinear`], `linear` (brought up to date for this configuration by
/// [`LinearGhosts::update`]) continues the moving walls' ghosts on top of the rest-walls fill;
/// without it they keep the rest-walls values.
#[allow(clippy::too_many_arguments)]
pub fn source_field<const D: usize>(
    x: &[[f64; D]],
    role: &[Role],
    boundary: &dyn Boundary<D>,
    ghost_rule: VectorKind,
    linear: Option<&LinearGhosts>,
    kind: SourceKind,
    scale: f64,
    v: &[[f64; D]],
    f: &mut Vec<[f64; D]>,
) {
    let n = role.len();
    f.resize(n, [0.0; D]);
    let keep_band = matches!(kind, SourceKind::LeastSquares | SourceKind::Renormalised);
    for i in 0..n {
        f[i] = if !keep_band && matches!(role[i], Role::Dirichlet) {
            [0.0; D]
        } else {
            v[i]
        };
    }
    // the rule continues the velocity (an affine rule would not commute with the scaling)
    if boundary.has_ghosts() && ghost_rule != VectorKind::Velocity {
        boundary.fill_vector_at(x, role, f, ghost_rule);
        if let Some(l) = linear.filter(|_| ghost_rule == VectorKind::RestWallsLinear) {
            l.apply(f);
        }
    }
    if scale != 1.0 {
        f.par_iter_mut().for_each(|fi| *fi = fi.map(|c| scale * c));
    }
}

/// The partners of [`VectorKind::RestWallsLinear`]: for every ghost `g` that crossed one
/// moving wall alone (normal axis `a`), its source `s`, the fluid particle `k` straight inward
/// from `s` (the nearest neighbour of `s` whose offset is along the normal, to `10⁻⁹ h`) and
/// the ratio `2 d_s / r_k` of the ghost's and the partner's normal distances from `s`; the
/// ghost's tangential components are `u_s + (u_s − u_k) 2d_s/r_k`, its normal one `−u_s`.
/// Computed once per neighbour-list configuration (the epoch and the generation).
#[derive(Clone, Debug, Default)]
pub struct LinearGhosts {
    key: Option<(u64, u64, usize)>,
    /// `(ghost, source, partner, ratio, normal axis)`.
    entries: Vec<(u32, u32, u32, f64, u8)>,
}

impl LinearGhosts {
    /// Finds the partners for the configuration of `nl` (nothing to do when it is the last
    /// one's). Errors naming the first source without a fluid neighbour straight inward.
    pub fn update<const D: usize>(
        &mut self,
        nl: &NeighborList<D>,
        x: &[[f64; D]],
        role: &[Role],
        boundary: &dyn Boundary<D>,
    ) -> Result<(), InputError> {
        let key = (nl.epoch(), nl.generation(), role.len());
        if self.key == Some(key) {
            return Ok(());
        }
        self.key = None;
        self.entries.clear();
        for (g, r) in role.iter().enumerate() {
            let Role::Ghost { source, walls } = *r else {
                continue;
            };
            let Some((axis, inward)) = boundary.single_moving_wall(walls) else {
                continue;
            };
            let s = source as usize;
            if s >= nl.len() {
                continue;
            }
            // the nearest fluid neighbour of s along the inward normal
            let mut best: Option<(usize, f64)> = None;
            for k in nl.row(s) {
                let j = nl.neighbor(k);
                if !role[j].is_fluid() {
                    continue;
                }
                let d = nl.dx()[k];
                let along = inward * d[axis];
                let lateral: f64 = (0..D).filter(|&b| b != axis).map(|b| d[b] * d[b]).sum();
                let tol = 1e-9 * nl.h();
                if along > tol && lateral.sqrt() <= tol && best.is_none_or(|(_, r)| along < r) {
                    best = Some((j, along));
                }
            }
            let Some((k, along)) = best else {
                return Err(InputError::Ghost {
                    particle: g,
                    reason: format!(
                        "the rest_walls_linear source rule continues it from its source {s} \
                         and the fluid particle straight inward from {s} along the wall's \
                         normal, and {s} has no such neighbour (the rule needs particles on \
                         a lattice aligned with the moving wall; use rest_walls otherwise)"
                    ),
                });
            };
            let out = (x[g][axis] - x[s][axis]).abs();
            self.entries
                .push((g as u32, source, k as u32, out / along, axis as u8));
        }
        self.key = Some(key);
        Ok(())
    }

    /// Continues the listed ghosts of `f` (filled by the rest-walls rule before).
    pub fn apply<const D: usize>(&self, f: &mut [[f64; D]]) {
        for &(g, s, k, ratio, axis) in &self.entries {
            let (fs, fk) = (f[s as usize], f[k as usize]);
            f[g as usize] = std::array::from_fn(|a| {
                if a == axis as usize {
                    -fs[a]
                } else {
                    fs[a] + (fs[a] - fk[a]) * ratio
                }
            });
        }
    }
}

/// The divergence `out = D v` of the source (rows `0..nl.len()`), `D` by `kind`:
///
/// * [`SourceKind::SumForm`]: `∇̂h·v_i = d Σ_j ω_j (v_j + v_i)·x_ji w_h/r²`;
/// * [`SourceKind::AdjointBt`]: `∇̂h·(Bᵀv)`, with `Bᵀv` continued into the ghosts by the mirror
///   rule `ghost_rule` unless it is the no-slip one (as `v` was);
/// * [`SourceKind::Renormalised`]: `∇ᶜ·v_i = Σ_a (B_i ∇h v_a)_a`;
/// * [`SourceKind::LeastSquares`]: `∇ˡˢ·v_i = Σ_a (∇ˡˢ v_a)_a`.
///
/// `ops` holds the matrices `B` and the least-squares coefficients (brought up to date here
/// when the kind needs them);
/// `work` is scratch.
#[allow(clippy::too_many_arguments)]
pub fn divergence_into<const D: usize>(
    nl: &NeighborList<D>,
    vol: &[f64],
    x: &[[f64; D]],
    role: &[Role],
    boundary: &dyn Boundary<D>,
    ghost_rule: VectorKind,
    kind: SourceKind,
    ops: &mut GradientOperator<D>,
    v: &[[f64; D]],
    work: &mut Vec<[f64; D]>,
    out: &mut Vec<f64>,
) {
    divergence_gain_into(
        nl, vol, x, role, boundary, ghost_rule, kind, ops, v, work, out, None,
    );
}

/// [`divergence_into`] and, from the same pass over the pairs, a bound `G` of the divergence's
/// gain on a velocity error `e` at the fluid particles: `‖D e‖ ≤ G ‖e‖` in the `ω`-weighted
/// norms, with `G = g · (max ω / min ω)` and `g` the largest row sum of `|D|` over the fluid
/// rows, bounded pair by pair: `2d Σ_j ω_j w_h(r_ij)/r_ij` for [`SourceKind::SumForm`], `‖B_i‖_F`
/// times that for [`SourceKind::Renormalised`], `2 Σ_k |c_k|` (the pairs' least-squares
/// coefficients) for [`SourceKind::LeastSquares`] (the row sums bound `D`'s `∞`-norm, the pairs'
/// near-symmetry its `1`-norm, the volumes' spread the weighting). The projection compares it
/// with the divergence's gain on `u*` to know how much of a viscous solve's error reaches the
/// Poisson source ([`crate::poisson::SolveParams::viscous_adaptive`]). `G` is 0 for
/// [`SourceKind::AdjointBt`] (no bound is taken), when there is no fluid particle and without
/// `measure` (the divergence alone, [`divergence_into`]). `measure = Some(k)` takes the bound
/// over the fluid among the first `k` particles (`nl.len()` for all; a rank of a decomposed
/// run its own, whose neighbourhoods are whole, and not its halo's copies).
#[allow(clippy::too_many_arguments)]
pub fn divergence_gain_into<const D: usize>(
    nl: &NeighborList<D>,
    vol: &[f64],
    x: &[[f64; D]],
    role: &[Role],
    boundary: &dyn Boundary<D>,
    ghost_rule: VectorKind,
    kind: SourceKind,
    ops: &mut GradientOperator<D>,
    v: &[[f64; D]],
    work: &mut Vec<[f64; D]>,
    out: &mut Vec<f64>,
    measure: Option<usize>,
) -> f64 {
    let (n, d) = (nl.len(), D as f64);
    let counted = measure.unwrap_or(0).min(n);
    let measure = measure.is_some();
    let fluid = |i: usize| i < counted && role[i].is_fluid();
    out.resize(n, 0.0);
    let renorm = &mut ops.renorm;
    let row_sum = match kind {
        SourceKind::SumForm if measure => 2.0 * d * div_sum_gain_into(nl, vol, v, out, fluid),
        SourceKind::SumForm => {
            div_sum_into(nl, vol, v, out);
            0.0
        }
        SourceKind::AdjointBt => {
            renorm.update(nl, vol, n);
            work.resize(n, [0.0; D]);
            renorm.apply_transpose_into(v, work);
            if boundary.has_ghosts() && ghost_rule != VectorKind::Velocity {
                boundary.fill_vector_at(x, role, work, ghost_rule);
            }
            div_sum_into(nl, vol, work, out);
            0.0
        }
        SourceKind::Renormalised => {
            renorm.update(nl, vol, n);
            if measure {
                2.0 * d * div_renormalised_gain_into(nl, vol, renorm, v, out, fluid)
            } else {
                div_renormalised_into(nl, vol, renorm, v, out);
                0.0
            }
        }
        SourceKind::LeastSquares => {
            ops.update_walls(nl, vol, Some((x, role)));
            if measure {
                2.0 * ops.ls_walls.div_gain_into(nl, v, out, fluid)
            } else {
                ops.ls_walls.div_into(nl, v, out);
                0.0
            }
        }
    };
    if row_sum == 0.0 {
        return 0.0;
    }
    let (lo, hi) = (0..counted)
        .into_par_iter()
        .with_min_len(4096)
        .filter(|&i| fluid(i))
        .map(|i| (vol[i], vol[i]))
        .reduce(|| (f64::INFINITY, 0.0), |a, b| (a.0.min(b.0), a.1.max(b.1)));
    if lo > 0.0 && hi > 0.0 {
        row_sum * hi / lo
    } else {
        0.0
    }
}

/// The correction: on every fluid particle `u_i = u*_i − (Δt/ρ) gφ_i` and
///
/// * `p_i = φ_i` ([`Scheme::NonIncremental`]),
/// * `p_i = p_i + φ_i` ([`Scheme::Incremental`]),
/// * `p_i = p_i + φ_i − ρθν (∇̂h·u*)_i` ([`Scheme::Rotational`]; `rot_div` holds `∇̂h·u*` and is
///   read only when `θν > 0`).
///
/// `gphi` is the gradient of `φ` (the projection's [`crate::consistent::GradientOperator`]);
/// `u` and `p` hold `uⁿ`, `pⁿ` on entry (non-fluid entries are left as they are: the caller
/// refills the ghosts afterwards).
#[allow(clippy::too_many_arguments)]
pub fn correct<const D: usize>(
    role: &[Role],
    params: &ProjectionParams<D>,
    dt: f64,
    u_star: &[[f64; D]],
    phi: &[f64],
    gphi: &[[f64; D]],
    rot_div: &[f64],
    u: &mut [[f64; D]],
    p: &mut [f64],
) {
    correct_velocity(role, params, dt, u_star, gphi, u);
    update_pressure(role, params, phi, rot_div, p);
}

/// The velocity half of [`correct`]: `u = u* − (Δt/ρ) ∇φ` at the fluid (and, with a free
/// surface, the band's) particles.
pub fn correct_velocity<const D: usize>(
    role: &[Role],
    params: &ProjectionParams<D>,
    dt: f64,
    u_star: &[[f64; D]],
    gphi: &[[f64; D]],
    u: &mut [[f64; D]],
) {
    let s = dt / params.rho;
    for i in 0..role.len() {
        // a free-surface particle is corrected like the fluid; its pressure is the band's
        // value (φ = 0 there), which the driver sets
        if role[i].is_fluid() || params.free_surface && role[i] == Role::Dirichlet {
            let (us, gp) = (u_star[i], gphi[i]);
            u[i] = std::array::from_fn(|k| us[k] - s * gp[k]);
        }
    }
}

/// The pressure half of [`correct`] (it needs no gradient): `p` of the fluid particles
/// updated by the scheme.
pub fn update_pressure<const D: usize>(
    role: &[Role],
    params: &ProjectionParams<D>,
    phi: &[f64],
    rot_div: &[f64],
    p: &mut [f64],
) {
    let rho = params.rho;
    let rot_nu = params.nu * params.viscous_theta;
    for i in 0..role.len() {
        if !role[i].is_fluid() {
            continue;
        }
        p[i] = match params.scheme {
            Scheme::NonIncremental => phi[i],
            Scheme::Incremental => p[i] + phi[i],
            Scheme::Rotational => {
                let rot = if rot_nu > 0.0 {
                    rho * rot_nu * rot_div[i]
                } else {
                    0.0
                };
                p[i] + phi[i] - rot
            }
        };
    }
}

/// The band's Dirichlet values `g` of the increment moved to the right side of the Poisson
/// rows ([`super::ProjectionStep::set_band_increment`]): `rhs_i += Σ_{j ∈ band} 2d ω_j
/// w_h(r_ij)/r_ij² g_j` for every fluid `i` (the matrix row is `ω_i` times that of `−Δh`; a
/// ghost of a band particle carries its source's value).
pub fn add_band_values<const D: usize>(
    nl: &NeighborList<D>,
    vol: &[f64],
    role: &[Role],
    g: &[f64],
    rhs: &mut [f64],
) {
    let two_d = 2.0 * D as f64;
    rhs.par_iter_mut().enumerate().for_each(|(i, r)| {
        if !role[i].is_fluid() {
            return;
        }
        let mut add = 0.0;
        for k in nl.row(i) {
            let j = nl.indices()[k] as usize;
            if let Some(b) = band_source(role, j) {
                add += two_d * vol[j] * nl.wr2()[k] * g[b];
            }
        }
        *r += add;
    });
}

/// Writes the band's Dirichlet values `g` into `φ` (band particles and their ghosts).
pub fn set_band_values(role: &[Role], g: &[f64], phi: &mut [f64]) {
    for (i, v) in phi.iter_mut().enumerate() {
        if let Some(b) = band_source(role, i) {
            *v = g[b];
        }
    }
}

/// The band particle a particle stands for: itself, or a ghost's band source.
fn band_source(role: &[Role], j: usize) -> Option<usize> {
    match role[j] {
        Role::Dirichlet => Some(j),
        Role::Ghost { source, .. } if role[source as usize] == Role::Dirichlet => {
            Some(source as usize)
        }
        _ => None,
    }
}

/// A free surface's velocity: each band particle takes the Shepard mean `Σ w_ij u_j / Σ w_ij`
/// of the corrected velocities of its fluid neighbours within `h` (wall images of fluid
/// particles included, with their no-slip values); a band particle without one — a splash —
/// keeps the velocity it has (its ballistic prediction). The band's own correction
/// `u* − (Δt/ρ)∇φ` is an integrator that nothing in the Poisson problem constrains (the band
/// carries no divergence row): measured on a tank at rest, its velocity grows without bound;
/// taken from the fluid, the surface moves with the water below it.
pub fn extend_to_band<const D: usize>(nl: &NeighborList<D>, role: &[Role], u: &mut [[f64; D]]) {
    let ext: Vec<(usize, [f64; D])> = (0..role.len())
        .into_par_iter()
        .filter(|&i| role[i] == Role::Dirichlet)
        .filter_map(|i| fluid_shepard(nl, role, i, |j| u[j]).map(|v| (i, v)))
        .collect();
    for (i, v) in ext {
        u[i] = v;
    }
}

/// The Shepard mean `Σ w_ij v_j / Σ w_ij` of `value` over the fluid neighbours of particle `i`
/// within `h` (wall images of fluid particles included, with their own values); `None`
/// without one.
pub(crate) fn fluid_shepard<const D: usize, const K: usize>(
    nl: &NeighborList<D>,
    role: &[Role],
    i: usize,
    value: impl Fn(usize) -> [f64; K],
) -> Option<[f64; K]> {
    let (mut sw, mut sv) = (0.0, [0.0; K]);
    for k in nl.row(i) {
        let j = nl.indices()[k] as usize;
        let w = nl.w()[k];
        if w > 0.0 && crate::diagnostics::alias(role, j).is_some() {
            sw += w;
            let v = value(j);
            for a in 0..K {
                sv[a] += w * v[a];
            }
        }
    }
    (sw > 0.0).then(|| sv.map(|v| v / sw))
}

/// `‖D v‖_ℓ2(Ω)` measured as the source sees a velocity: `v` zeroed on the Dirichlet band, its
/// ghosts continued by `ghost_rule` ([`source_field`] with scale 1), then the divergence of
/// `kind` ([`divergence_into`]). `work`, `work2` and `div` are scratch (`div` holds `D v` on
/// return).
#[allow(clippy::too_many_arguments)]
pub fn measure_divergence<const D: usize>(
    nl: &NeighborList<D>,
    vol: &[f64],
    x: &[[f64; D]],
    role: &[Role],
    boundary: &dyn Boundary<D>,
    ghost_rule: VectorKind,
    linear: Option<&LinearGhosts>,
    kind: SourceKind,
    ops: &mut GradientOperator<D>,
    v: &[[f64; D]],
    work: &mut Vec<[f64; D]>,
    work2: &mut Vec<[f64; D]>,
    div: &mut Vec<f64>,
) -> f64 {
    source_field(x, role, boundary, ghost_rule, linear, kind, 1.0, v, work);
    divergence_into(
        nl, vol, x, role, boundary, ghost_rule, kind, ops, work, work2, div,
    );
    norm_l2(vol, div, role, Region::Omega)
}

/// `‖u_new − u*‖_ℓ2(Ω) / ‖u*‖_ℓ2(Ω)` (ω-weighted over the fluid; 0 when `u* = 0`): the
/// share of the predicted velocity the correction removed.
pub fn correction_ratio<const D: usize>(
    vol: &[f64],
    role: &[Role],
    u_star: &[[f64; D]],
    u_new: &[[f64; D]],
) -> f64 {
    let (mut num, mut den) = (0.0, 0.0);
    for i in 0..role.len() {
        if role[i].is_fluid() {
            let d: [f64; D] = std::array::from_fn(|a| u_new[i][a] - u_star[i][a]);
            num += vol[i] * norm2(&d);
            den += vol[i] * norm2(&u_star[i]);
        }
    }
    if den > 0.0 {
        (num / den).sqrt()
    } else {
        0.0
    }
}

/// Kinetic energy `½ ρ Σ_Ω ω_i |u_i|²` and the maximum speed `max_Ω |u_i|`; a non-finite
/// velocity is reported at the first fluid particle that has one.
pub fn energy<const D: usize>(
    vol: &[f64],
    role: &[Role],
    rho: f64,
    u: &[[f64; D]],
) -> Result<(f64, f64), SolveError> {
    let (mut ke, mut vmax) = (0.0, 0.0f64);
    for i in 0..role.len() {
        if role[i].is_fluid() {
            let u2 = norm2(&u[i]);
            ke += 0.5 * rho * vol[i] * u2;
            vmax = vmax.max(u2);
            if !u2.is_finite() {
                return Err(SolveError::NonFinite { particle: i });
            }
        }
    }
    Ok((ke, vmax.sqrt()))
}

/// One damped Jacobi sweep with the Poisson matrix on the fluid rows:
/// `p_i ← p_i + β (Δh p)_i / |(Δh)_ii|`, `(Δh)_ii = −2d Σ_j ω_j w_h/r²` (ghost values read as
/// they are: the caller fills them first). A sweep is stable for `β ∈ [0, 1)` whatever the
/// distribution; see [`ProjectionParams::pressure_smoothing`].
pub fn smooth_pressure<const D: usize>(
    nl: &NeighborList<D>,
    vol: &[f64],
    role: &[Role],
    beta: f64,
    p: &mut [f64],
) {
    let old = p.to_vec();
    p.par_iter_mut().enumerate().for_each(|(i, pi)| {
        if !role[i].is_fluid() {
            return;
        }
        let (mut num, mut den) = (0.0, 0.0);
        for k in nl.row(i) {
            let j = nl.indices()[k] as usize;
            let c = vol[j] * nl.wr2()[k];
            num += c * (old[j] - old[i]);
            den += c;
        }
        if den > 0.0 {
            *pi = old[i] + beta * num / den;
        }
    });
}
