//! Boundaries: planar walls by mirror-image ghosts, periodic boxes, and none.
//!
//! **Walls.** A wall is an axis-aligned plane. Every fluid particle within `reach` of a wall has
//! a ghost: its mirror image across the wall (and across each pair of walls at a corner, and each
//! triple at a 3D corner). Ghosts are stored after all other particles and carry
//! [`Role::Ghost`]. Their values follow the source:
//!
//! * scalars (pressure, increments) are copied: a homogeneous Neumann condition, and a symmetric
//!   Poisson matrix (the image distance is the same seen from either end of a pair);
//! * velocities follow the no-slip rule `u_g = 2 U_wall − u_src` across one wall (so the wall
//!   velocity is reached half-way between source and image); at a corner the images across two
//!   walls are applied in turn, and their mean is taken when the two orders disagree (a lid
//!   corner), which gives `u_g = u_src`;
//! * gradients and other "mirror" vectors follow `v_g = L v_src` (`L` flips the normal
//!   components): the rule under which the pair `∇̂h·` / `∇h` stays exactly adjoint.

use crate::error::InputError;
use crate::neighbors::Periodicity;
use crate::particles::{Particles, Role};
use rayon::prelude::*;

/// How a vector field is continued into the ghosts.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum VectorKind {
    /// No-slip: `u_g = 2 U_wall − u_src` per wall.
    Velocity,
    /// Mirror: normal components flipped, tangential kept (`v_g = L v_src`).
    Mirror,
    /// The no-slip image across walls at rest, the mirror across a moving wall and at its
    /// corners, the two blended next to a moving wall: a ghost of a source at `x` crossing
    /// only walls at rest takes `β v_noslip + (1 − β) L v_src`, `β = Π_k S(d_k/δ_k)` over the
    /// moving walls `k` with a band `δ_k = `[`Wall::source_band`] (`d_k` the source's distance
    /// from wall `k`, `S` the quintic step of [`Wall::ramp`]; no band: `β = 1`); a ghost that
    /// crosses a moving wall takes the mirror `L v_src`. Why: the odd continuation (no-slip,
    /// `−v_src` across a wall at rest) is smooth to first derivatives where the velocity
    /// vanishes on the wall, the mirror's even one has a kink there; but only the mirror keeps
    /// the sum-form divergence conservative (`Σ_i ω_i ∇̂h·v_i = 0` for every `v`: the fluid–ghost
    /// pairs cancel in twos exactly when the continuation's signs are the reflection's). The
    /// odd rule's net flux through a wall at rest sums `∂v_t/∂t` along it to its ends, which
    /// is zero at a corner of walls at rest but `O(U Δx)` next to a moving lid, whose speed
    /// jumps at its corners: a mass source of first order there, and a first-order error in
    /// the whole cavity. Blending into the mirror over a band of fixed width `δ` removes it
    /// (measured with `δ = ¼` side: Re 100 second order, Re 1000 errors 2–6× below the
    /// mirror's, but an order falling to 1.4 at n = 128 — a first-order term of another
    /// origin is left). Without positions ([`Boundary::fill_vector`]) no band applies.
    RestWalls,
    /// [`VectorKind::RestWalls`], except that a ghost crossing one moving wall alone takes
    /// its source's tangential components continued *linearly* along the wall's normal, from
    /// the source `s` and the fluid particle `k` straight inward from it (`u_g = u_s + (u_s −
    /// u_k) 2d_s/r_k`, `d_s` the source's distance from the wall, `r_k` the distance from `s`
    /// to `k`; the normal component flipped as by the mirror). Exact for fields linear along
    /// the normal, where the mirror's even continuation errs by `2 d_s ∂u_t/∂n`, and it does
    /// not read the wall's speed, so nothing jumps at the wall's corners. Measured on the
    /// cavity (README): it changes the error's amplitude term only at second order — order 2
    /// at Re 1000 up to n = 128, not beyond; at Re 100 up to twice the rest-walls rule's
    /// error at n ≤ 64 — so it is an option, not a default. The wall-normal partners need
    /// the neighbour list: the boundary fills this rule like [`VectorKind::RestWalls`], and
    /// the projection's source stage (`LinearGhosts` in `gpm::projection::stages`) continues
    /// the moving wall's ghosts of the source field on top (an adjoint-`Bᵀ` source's `Bᵀv`
    /// keeps the rest-walls fill); it refuses a source without a partner straight inward
    /// (particles not on a lattice aligned with the wall).
    RestWallsLinear,
}

/// Boundary handling the projection step and the flow solver call into.
pub trait Boundary<const D: usize>: Send + Sync {
    /// True when the boundary keeps ghost particles (so the fill stages are needed).
    fn has_ghosts(&self) -> bool;
    /// Periodic axes (for the neighbour search and position wrapping).
    fn periodicity(&self) -> Periodicity<D>;
    /// Copies scalar values into the ghosts.
    fn fill_scalar(&self, role: &[Role], v: &mut [f64]);
    /// Continues the pressure into the ghosts with the wall's Neumann condition
    /// `∂p/∂n = ρ g·n` (a wall at rest under the body force `g`; `rho_g = ρ g`): the image of
    /// `x_src` gets `p_g = p_src + ρ g·(x_g − x_src)`, which continues a hydrostatic pressure
    /// exactly. The default (and `rho_g = 0`) is [`fill_scalar`](Self::fill_scalar).
    fn fill_pressure(&self, x: &[[f64; D]], role: &[Role], p: &mut [f64], rho_g: [f64; D]) {
        let _ = (x, rho_g);
        self.fill_scalar(role, p);
    }
    /// Continues a vector field into the ghosts. [`VectorKind::Velocity`] takes every wall's
    /// velocity as uniform; a wall whose velocity varies along it ([`Wall::ramp`]) needs the
    /// positions: [`fill_velocity`](Self::fill_velocity).
    fn fill_vector(&self, role: &[Role], v: &mut [[f64; D]], kind: VectorKind);
    /// [`fill_vector`](Self::fill_vector) with the particles' positions `x`, for a rule that
    /// depends on where the source is ([`VectorKind::RestWalls`] with a
    /// [`Wall::source_band`]); the default ignores them.
    fn fill_vector_at(&self, x: &[[f64; D]], role: &[Role], v: &mut [[f64; D]], kind: VectorKind) {
        let _ = x;
        self.fill_vector(role, v, kind)
    }
    /// Continues a velocity field into the ghosts by the walls' velocity rule, each wall's
    /// velocity taken at the foot of the source particle `x` on it (the same as
    /// `fill_vector(role, v, VectorKind::Velocity)` for uniform wall velocities, the default).
    fn fill_velocity(&self, x: &[[f64; D]], role: &[Role], v: &mut [[f64; D]]) {
        let _ = x;
        self.fill_vector(role, v, VectorKind::Velocity)
    }
    /// Continues a velocity-gradient field `G[a][b] = ∂u_a/∂x_b` into the ghosts as the
    /// gradient of the velocity images: `G_g = Σ G_src R`, `Σ` the diagonal signs of the
    /// velocity rule (all −1 per no-slip wall crossed, −1 on the normal component per free-slip
    /// one) and `R` the reflection (column `b` negated for each crossed wall normal to axis `b`),
    /// plus `2 ∂U/∂x_b` across one wall whose velocity `U` varies along it ([`Wall::ramp`]; `x`
    /// the particles' positions). The default (no ghosts) does nothing.
    fn fill_velocity_gradient(&self, x: &[[f64; D]], role: &[Role], g: &mut [[[f64; D]; D]]) {
        let _ = (x, role, g);
    }
    /// Moves ghosts to the images of their sources (after the sources moved).
    fn place_ghosts(&self, p: &mut Particles<D>);
    /// Drops every ghost and creates images of the fluid particles within `reach` of a wall.
    /// `reach` must be at least the search radius of the neighbour list (`h + skin`): the
    /// symmetry of the Poisson matrix and the adjointness of the operators rely on every image
    /// within `h` of a fluid particle existing.
    fn make_ghosts(&self, p: &mut Particles<D>, reach: f64);
    /// [`make_ghosts`](Self::make_ghosts), with images of the Dirichlet particles too when
    /// `band` is true (a free surface that touches a wall: its particles' images hold the band's
    /// values, and the band moves, so its images must follow it). The default ignores `band`.
    fn make_ghosts_with_band(&self, p: &mut Particles<D>, reach: f64, band: bool) {
        let _ = band;
        self.make_ghosts(p, reach)
    }
    /// Maps positions back into the domain where the boundary allows it (periodic wrap) and
    /// reports a fluid particle that has left the domain.
    fn confine(&self, p: &mut Particles<D>) -> Result<(), InputError>;
    /// [`confine`](Self::confine), with the Dirichlet particles too when `band` is true (a
    /// free surface, whose band moves with the fluid). The default ignores `band`.
    fn confine_with_band(&self, p: &mut Particles<D>, band: bool) -> Result<(), InputError> {
        let _ = band;
        self.confine(p)
    }
    /// The displacement that brings a point `x` back to at least `margin` inside every wall: a
    /// point at distance `s < margin` from a wall (or beyond it by less than `margin`, `s > −margin`)
    /// is reflected about the margin plane, to `2 margin − s` (zero when it already is inside
    /// the margin, when it is beyond a wall by `margin` or more — a step too large, which
    /// [`confine`](Self::confine) reports — and for boundaries without walls). A reflection
    /// rather than a stop at the margin: two particles stopped at the margin plane land on the
    /// same line, and at a corner on the same point. Moving particles use it as the wall part
    /// of their shift, before the projection of the step (which therefore acts on the
    /// corrected positions); their velocity into the wall is dropped (see
    /// `flow::shifting`).
    fn wall_margin_push(&self, x: &[f64; D], margin: f64) -> [f64; D] {
        let _ = (x, margin);
        [0.0; D]
    }
    /// The velocity rule of a ghost reflected across the walls in `walls` from a source at
    /// `x_src` as an affine map `u_g[d] = σ[d] u_src[d] + b[d]` (`σ[d] = ±1`: all −1 across one
    /// no-slip wall, −1 only for the normal component across a free-slip one; `b` from the walls'
    /// velocities at the source's foot), for implicit solves that need it as matrix entries.
    fn velocity_affine(&self, walls: u8, x_src: &[f64; D]) -> ([f64; D], [f64; D]) {
        let _ = (walls, x_src);
        ([1.0; D], [0.0; D])
    }
    /// The axis of the wall and its inward sign (`+1`: the fluid at larger coordinates) when a
    /// ghost crossing the walls in `walls` crossed exactly one wall and that wall moves
    /// ([`VectorKind::RestWallsLinear`] continues those ghosts); `None` otherwise (and for
    /// boundaries without walls).
    fn single_moving_wall(&self, walls: u8) -> Option<(usize, f64)> {
        let _ = walls;
        None
    }
    /// Checks that the ghosts of `p` are those this boundary would make and place for an
    /// influence radius `h`: for [`Walls`], every ghost at the image of its source with its
    /// source's volume (so [`place_ghosts`](Self::place_ghosts) ran after the last move), and an
    /// image for every fluid particle closer than `h` to a wall or a corner (so
    /// [`make_ghosts`](Self::make_ghosts) ran with a reach of at least `h`). `O(N)`. The default
    /// (no ghosts) accepts anything.
    fn check_ghosts(&self, p: &Particles<D>, h: f64) -> Result<(), InputError> {
        let _ = (p, h);
        Ok(())
    }
}

/// One planar wall `x_axis = position`, with the fluid on the `inward` side.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Wall<const D: usize> {
    /// Normal axis.
    pub axis: usize,
    /// Coordinate of the plane.
    pub position: f64,
    /// +1 when the fluid is at larger coordinates (a lower wall), −1 otherwise.
    pub inward: f64,
    /// Wall velocity (tangential for a moving lid).
    pub velocity: [f64; D],
    /// Free-slip (`true`: no penetration, no friction — the image keeps the tangential velocity
    /// and reverses the normal one) or no-slip (`false`, the default: the image's velocity is
    /// `2U − u`).
    pub slip: bool,
    /// Width `δ` over which the wall's velocity falls to zero towards every wall that meets it
    /// (`0`, the default: uniform). At a foot point at distances `d_j` from the other walls
    /// (those normal to another axis) the wall moves with `U Π_j S(d_j/δ)`, `S(t) = 6t⁵ − 15t⁴ +
    /// 10t³` for `t < 1` (else 1): a lid whose speed is continuous at its corners, the
    /// regularised lid-driven cavity for `δ = ½` side, a corner treatment that vanishes with `δ`.
    pub ramp: f64,
    /// Width of the band next to this wall, when it moves, within which the
    /// [`VectorKind::RestWalls`] continuation blends the walls at rest's no-slip images into
    /// the mirror (`0`, the default: no band).
    pub source_band: f64,
}

impl<const D: usize> Wall<D> {
    /// A wall at rest, no-slip, uniform: the plane `x_axis = position` with the fluid on the
    /// `inward` side (`+1`: at larger coordinates).
    pub fn at_rest(axis: usize, position: f64, inward: f64) -> Self {
        Wall {
            axis,
            position,
            inward,
            velocity: [0.0; D],
            slip: false,
            ramp: 0.0,
            source_band: 0.0,
        }
    }

    /// Signed distance of `x` from the plane, positive on the fluid side.
    #[inline]
    pub fn distance(&self, x: &[f64; D]) -> f64 {
        self.inward * (x[self.axis] - self.position)
    }
    /// The velocity of the image of a particle moving with `v`: `2U − v` (no-slip), or `v` with
    /// its normal component `2U_n − v_n` (free-slip).
    #[inline]
    pub fn velocity_image(&self, v: &[f64; D]) -> [f64; D] {
        self.velocity_image_with(v, &self.velocity)
    }

    /// [`velocity_image`](Self::velocity_image) with the wall moving at `u` (a wall whose
    /// velocity varies along it, at the source's foot).
    #[inline]
    pub fn velocity_image_with(&self, v: &[f64; D], u: &[f64; D]) -> [f64; D] {
        if self.slip {
            let mut y = *v;
            y[self.axis] = 2.0 * u[self.axis] - v[self.axis];
            y
        } else {
            std::array::from_fn(|a| 2.0 * u[a] - v[a])
        }
    }

    /// The signs of [`velocity_image`](Self::velocity_image)'s linear part, per component.
    #[inline]
    pub fn velocity_signs(&self) -> [f64; D] {
        if self.slip {
            std::array::from_fn(|a| if a == self.axis { -1.0 } else { 1.0 })
        } else {
            [-1.0; D]
        }
    }

    /// True when the wall moves (a velocity other than zero).
    #[inline]
    pub fn moves(&self) -> bool {
        self.velocity.iter().any(|&u| u != 0.0)
    }

    /// Mirror image of `x`.
    #[inline]
    pub fn reflect(&self, x: &[f64; D]) -> [f64; D] {
        let mut y = *x;
        y[self.axis] = 2.0 * self.position - x[self.axis];
        y
    }
}

/// A set of planar walls (at most 8) with mirror-image ghosts; optionally periodic on other axes.
#[derive(Clone, Debug, PartialEq)]
pub struct Walls<const D: usize> {
    /// The walls; bit `k` of a ghost's `walls` field refers to `walls[k]`.
    pub walls: Vec<Wall<D>>,
    /// Periodic axes (must not carry walls).
    pub periodic: Periodicity<D>,
}

impl<const D: usize> Walls<D> {
    /// Stationary walls on every face of the box `[lo, hi]`.
    pub fn closed_box(lo: [f64; D], hi: [f64; D]) -> Self {
        let mut walls = Vec::new();
        for a in 0..D {
            walls.push(Wall::at_rest(a, lo[a], 1.0));
            walls.push(Wall::at_rest(a, hi[a], -1.0));
        }
        Walls {
            walls,
            periodic: Periodicity::none(),
        }
    }

    /// An open tank: stationary walls on every face of the box `[lo, hi]` except the top
    /// `x_{D−1} = hi[D−1]` (free-surface scenes: the water's top is a free surface, and nothing
    /// stops a splash from rising above `hi`).
    pub fn tank(lo: [f64; D], hi: [f64; D]) -> Self {
        let mut w = Self::closed_box(lo, hi);
        w.walls
            .retain(|wall| !(wall.axis == D - 1 && wall.inward < 0.0));
        w
    }

    /// A channel: stationary walls at `x_{D−1} = lo[D−1]` and `x_{D−1} = hi[D−1]` (for `D = 2`,
    /// `y = lo` and `y = hi`), periodic along every other axis `a` with period `hi[a] − lo[a]`
    /// (a plane Poiseuille or Couette set-up; set a wall's `velocity` for Couette).
    pub fn channel(lo: [f64; D], hi: [f64; D]) -> Self {
        let a = D - 1;
        let mut len = [0.0; D];
        for k in 0..a {
            len[k] = hi[k] - lo[k];
        }
        let mut plo = lo;
        plo[a] = 0.0;
        Walls {
            walls: vec![Wall::at_rest(a, lo[a], 1.0), Wall::at_rest(a, hi[a], -1.0)],
            periodic: Periodicity { lo: plo, len },
        }
    }

    /// The lid-driven cavity `[0, L]^D`: the wall at `x_{D−1} = L` moves with `lid` along axis 0.
    pub fn cavity(side: f64, lid: f64) -> Self {
        let mut w = Self::closed_box([0.0; D], [side; D]);
        for wall in &mut w.walls {
            if wall.axis == D - 1 && wall.inward < 0.0 {
                wall.velocity[0] = lid;
            }
        }
        w
    }

    fn image(&self, x: &[f64; D], mask: u8) -> [f64; D] {
        let mut y = *x;
        for (k, w) in self.walls.iter().enumerate() {
            if mask & (1 << k) != 0 {
                y = w.reflect(&y);
            }
        }
        y
    }

    /// The velocity of wall `k` at the foot of a point `x` (inside the walls): its velocity
    /// times the ramp factor `Π_j S(d_j/δ)` ([`Wall::ramp`]), and the factor's gradient.
    fn wall_velocity_at(&self, k: usize, x: &[f64; D]) -> ([f64; D], [f64; D]) {
        let w = &self.walls[k];
        if w.ramp <= 0.0 || !w.moves() {
            return (w.velocity, [0.0; D]);
        }
        let (mut f, mut df) = (1.0, [0.0; D]);
        for (j, o) in self.walls.iter().enumerate() {
            if j == k || o.axis == w.axis {
                continue;
            }
            let t = (o.distance(x) / w.ramp).clamp(0.0, 1.0);
            let s = smooth_step(t);
            let ds = if t < 1.0 && t > 0.0 {
                30.0 * t * t * (1.0 - t) * (1.0 - t) / w.ramp * o.inward
            } else {
                0.0
            };
            // product rule: d(f s) = df s + f ds
            for d in df.iter_mut() {
                *d *= s;
            }
            df[o.axis] += f * ds;
            f *= s;
        }
        (w.velocity.map(|u| u * f), df)
    }

    /// [`VectorKind::RestWalls`] across the walls in `mask` for a source with velocity `v` at
    /// `x` (`None`: no band applies).
    fn rest_walls_image(&self, v: &[f64; D], mask: u8, x: Option<&[f64; D]>) -> [f64; D] {
        let crossed = |k: usize| mask & (1 << k) != 0;
        if (0..self.walls.len()).any(|k| crossed(k) && self.walls[k].moves()) {
            return self.mirror_image(v, mask);
        }
        let odd = self.velocity_image(v, mask);
        let Some(x) = x else { return odd };
        let beta: f64 = self
            .walls
            .iter()
            .filter(|w| w.moves() && w.source_band > 0.0)
            .map(|w| smooth_step(w.distance(x) / w.source_band))
            .product();
        if beta == 1.0 {
            return odd;
        }
        let even = self.mirror_image(v, mask);
        std::array::from_fn(|a| beta * odd[a] + (1.0 - beta) * even[a])
    }

    /// True when some wall's velocity varies along it.
    fn ramped(&self) -> bool {
        self.walls.iter().any(|w| w.ramp > 0.0 && w.moves())
    }

    fn velocity_image(&self, v: &[f64; D], mask: u8) -> [f64; D] {
        self.velocity_image_at(v, mask, None)
    }

    /// The velocity rule across the walls in `mask` for a source with velocity `v` at `x`
    /// (`None`: every wall's velocity uniform).
    fn velocity_image_at(&self, v: &[f64; D], mask: u8, x: Option<&[f64; D]>) -> [f64; D] {
        // the walls crossed (a mask of eight bits: at most eight), without an allocation
        let mut walls = [0usize; 8];
        let mut n = 0;
        for k in (0..self.walls.len().min(8)).filter(|k| mask & (1 << k) != 0) {
            walls[n] = k;
            n += 1;
        }
        let ks = &walls[..n];
        let image = |k: usize, y: &[f64; D]| match x {
            Some(x) => self.walls[k].velocity_image_with(y, &self.wall_velocity_at(k, x).0),
            None => self.walls[k].velocity_image(y),
        };
        match ks.len() {
            1 => image(ks[0], v),
            _ => {
                // apply the walls in turn, in both (all) cyclic orders, and average
                let mut acc = [0.0; D];
                for start in 0..ks.len() {
                    let mut y = *v;
                    for m in 0..ks.len() {
                        y = image(ks[(start + m) % ks.len()], &y);
                    }
                    for a in 0..D {
                        acc[a] += y[a];
                    }
                }
                acc.map(|s| s / ks.len() as f64)
            }
        }
    }

    /// The signs of the linear part of the velocity rule across the walls in `mask`.
    fn velocity_signs(&self, mask: u8) -> [f64; D] {
        let mut sigma = [1.0; D];
        for (k, w) in self.walls.iter().enumerate() {
            if mask & (1 << k) != 0 {
                let s = w.velocity_signs();
                for a in 0..D {
                    sigma[a] *= s[a];
                }
            }
        }
        sigma
    }

    /// Every wall free-slip ([`Wall::slip`]).
    pub fn free_slip(mut self) -> Self {
        for w in &mut self.walls {
            w.slip = true;
        }
        self
    }

    /// The images of a point at `x`: one mask (bit `k` = wall `k`) per non-empty subset of the
    /// walls closer than `reach` whose axes are distinct, with the walls of the subset.
    fn image_masks(&self, x: &[f64; D], reach: f64) -> Vec<(u8, Vec<usize>)> {
        let near: Vec<usize> = (0..self.walls.len())
            .filter(|&k| self.walls[k].distance(x) < reach)
            .collect();
        let mut out = Vec::new();
        for subset in 1u32..(1 << near.len()) {
            let ks: Vec<usize> = (0..near.len())
                .filter(|b| subset & (1 << b) != 0)
                .map(|b| near[b])
                .collect();
            let mut axes: Vec<usize> = ks.iter().map(|&k| self.walls[k].axis).collect();
            axes.sort_unstable();
            axes.dedup();
            if axes.len() == ks.len() {
                let mask = ks.iter().fold(0u8, |m, &k| m | (1 << k));
                out.push((mask, ks));
            }
        }
        out
    }

    fn mirror_image(&self, v: &[f64; D], mask: u8) -> [f64; D] {
        let mut y = *v;
        for (k, w) in self.walls.iter().enumerate() {
            if mask & (1 << k) != 0 {
                y[w.axis] = -y[w.axis];
            }
        }
        y
    }
}

impl<const D: usize> Boundary<D> for Walls<D> {
    fn has_ghosts(&self) -> bool {
        !self.walls.is_empty()
    }

    fn velocity_affine(&self, walls: u8, x_src: &[f64; D]) -> ([f64; D], [f64; D]) {
        (
            self.velocity_signs(walls),
            self.velocity_image_at(&[0.0; D], walls, Some(x_src)),
        )
    }

    fn single_moving_wall(&self, walls: u8) -> Option<(usize, f64)> {
        if walls.count_ones() != 1 {
            return None;
        }
        let w = self.walls.get(walls.trailing_zeros() as usize)?;
        w.moves().then_some((w.axis, w.inward))
    }

    fn periodicity(&self) -> Periodicity<D> {
        self.periodic
    }

    fn fill_scalar(&self, role: &[Role], v: &mut [f64]) {
        fill_from_sources(role, v, |s, _| *s);
    }

    fn fill_pressure(&self, x: &[[f64; D]], role: &[Role], p: &mut [f64], rho_g: [f64; D]) {
        self.fill_scalar(role, p);
        if rho_g.iter().all(|&g| g == 0.0) {
            return;
        }
        let first = first_ghost(role).min(p.len());
        p[first..]
            .par_iter_mut()
            .zip(role[first..].par_iter())
            .for_each(|(g, r)| {
                if let Role::Ghost { source, walls } = r {
                    let xs = &x[*source as usize];
                    let xg = self.image(xs, *walls);
                    *g += (0..D).map(|k| rho_g[k] * (xg[k] - xs[k])).sum::<f64>();
                }
            });
    }

    fn fill_vector(&self, role: &[Role], v: &mut [[f64; D]], kind: VectorKind) {
        fill_from_sources(role, v, |s, walls| match kind {
            VectorKind::Velocity => self.velocity_image(s, walls),
            VectorKind::Mirror => self.mirror_image(s, walls),
            VectorKind::RestWalls | VectorKind::RestWallsLinear => {
                self.rest_walls_image(s, walls, None)
            }
        });
    }

    fn fill_vector_at(&self, x: &[[f64; D]], role: &[Role], v: &mut [[f64; D]], kind: VectorKind) {
        if !matches!(kind, VectorKind::RestWalls | VectorKind::RestWallsLinear) {
            return self.fill_vector(role, v, kind);
        }
        fill_from_sources_at(role, v, |s, src, walls| {
            self.rest_walls_image(s, walls, Some(&x[src]))
        });
    }

    fn fill_velocity(&self, x: &[[f64; D]], role: &[Role], v: &mut [[f64; D]]) {
        if !self.ramped() {
            return self.fill_vector(role, v, VectorKind::Velocity);
        }
        fill_from_sources_at(role, v, |s, src, walls| {
            self.velocity_image_at(s, walls, Some(&x[src]))
        });
    }

    fn fill_velocity_gradient(&self, x: &[[f64; D]], role: &[Role], g: &mut [[[f64; D]; D]]) {
        let ramped = self.ramped();
        fill_from_sources_at(role, g, |s, src, walls| {
            let sigma = self.velocity_signs(walls);
            let mut flip = [1.0; D];
            for (k, w) in self.walls.iter().enumerate() {
                if walls & (1 << k) != 0 {
                    flip[w.axis] = -flip[w.axis];
                }
            }
            let mut out: [[f64; D]; D] =
                std::array::from_fn(|a| std::array::from_fn(|b| sigma[a] * flip[b] * s[a][b]));
            // one wall crossed: u_g(y) = 2 U(foot) − L u(R y) gains 2 ∂U/∂y (the foot moves with
            // y along the wall); across several the orders' mean does not depend on U's ramp
            if ramped && walls.count_ones() == 1 {
                let k = walls.trailing_zeros() as usize;
                let w = &self.walls[k];
                if !w.slip {
                    let (_, df) = self.wall_velocity_at(k, &x[src]);
                    for a in 0..D {
                        for b in 0..D {
                            out[a][b] += 2.0 * w.velocity[a] * df[b];
                        }
                    }
                }
            }
            out
        });
    }

    fn place_ghosts(&self, p: &mut Particles<D>) {
        let first = first_ghost(&p.role);
        let (src, ghosts) = p.x.split_at_mut(first);
        ghosts
            .par_iter_mut()
            .zip(p.role[first..].par_iter())
            .for_each(|(g, r)| {
                if let Role::Ghost { source, walls } = r {
                    *g = self.image(&src[*source as usize], *walls);
                }
            });
        let (vs, vg) = p.vol.split_at_mut(first);
        for (g, r) in vg.iter_mut().zip(&p.role[first..]) {
            if let Role::Ghost { source, .. } = r {
                *g = vs[*source as usize];
            }
        }
    }

    fn make_ghosts(&self, p: &mut Particles<D>, reach: f64) {
        self.make_ghosts_with_band(p, reach, false)
    }

    fn make_ghosts_with_band(&self, p: &mut Particles<D>, reach: f64, band: bool) {
        let first = first_ghost(&p.role);
        p.truncate(first);
        let nw = self.walls.len();
        assert!(nw <= 8, "at most 8 walls");
        for i in 0..first {
            let mirrored = match p.role[i] {
                Role::Fluid => true,
                Role::Dirichlet => band,
                Role::Ghost { .. } => false,
            };
            if !mirrored {
                continue;
            }
            let x = p.x[i];
            for (mask, _) in self.image_masks(&x, reach) {
                let y = self.image(&x, mask);
                let u = self.velocity_image_at(&p.u[i], mask, Some(&x));
                let (pi, vi) = (p.p[i], p.vol[i]);
                p.push(
                    y,
                    u,
                    pi,
                    vi,
                    Role::Ghost {
                        source: i as u32,
                        walls: mask,
                    },
                );
            }
        }
    }

    fn check_ghosts(&self, p: &Particles<D>, h: f64) -> Result<(), InputError> {
        let first = first_ghost(&p.role);
        let tol = 1e-9 * h;
        let mut present = std::collections::HashSet::new();
        for g in first..p.len() {
            let Role::Ghost { source, walls } = p.role[g] else {
                continue; // order checked by the caller
            };
            let s = source as usize;
            if s >= first {
                return Err(InputError::BadGhostSource {
                    particle: g,
                    source_particle: s,
                });
            }
            let y = self.image(&p.x[s], walls);
            let off = (0..D)
                .map(|a| (p.x[g][a] - y[a]).abs())
                .fold(0.0f64, f64::max);
            if !(off <= tol) {
                return Err(InputError::Ghost {
                    particle: g,
                    reason: format!(
                        "it is {off:e} away from the image of its source {s} across the walls \
                         {walls:#b}: call Boundary::place_ghosts after moving particles"
                    ),
                });
            }
            if p.vol[g] != p.vol[s] {
                return Err(InputError::Ghost {
                    particle: g,
                    reason: format!(
                        "its volume {} differs from its source {s}'s {}: call \
                         Boundary::place_ghosts after computing volumes",
                        p.vol[g], p.vol[s]
                    ),
                });
            }
            present.insert((source, walls));
        }
        for i in 0..first {
            if !p.role[i].is_fluid() {
                continue;
            }
            let x = p.x[i];
            for (mask, ks) in self.image_masks(&x, h) {
                if !present.contains(&(i as u32, mask)) {
                    let distance = ks
                        .iter()
                        .map(|&k| self.walls[k].distance(&x))
                        .fold(f64::NEG_INFINITY, f64::max);
                    return Err(InputError::MissingGhost {
                        particle: i,
                        walls: mask,
                        distance,
                        h,
                    });
                }
            }
        }
        Ok(())
    }

    fn wall_margin_push(&self, x: &[f64; D], margin: f64) -> [f64; D] {
        let mut d = [0.0; D];
        for w in &self.walls {
            let s = w.distance(x);
            // a point beyond the wall by `margin` or more: not moved (confine reports it)
            if s > -margin && s < margin {
                d[w.axis] += 2.0 * (margin - s) * w.inward;
            }
        }
        d
    }

    fn confine(&self, p: &mut Particles<D>) -> Result<(), InputError> {
        self.confine_with_band(p, false)
    }

    fn confine_with_band(&self, p: &mut Particles<D>, band: bool) -> Result<(), InputError> {
        let per = self.periodic;
        for i in 0..p.len() {
            if !(p.role[i].is_fluid() || band && p.role[i] == Role::Dirichlet) {
                continue;
            }
            if per.any() {
                per.wrap(&mut p.x[i]);
            }
            for w in &self.walls {
                if !(w.distance(&p.x[i]) > 0.0) {
                    return Err(InputError::OutsideDomain {
                        particle: i,
                        position: p.x[i].to_vec(),
                        reason: format!(
                            "crossed the wall x[{}] = {} (time step too large for the flow?)",
                            w.axis, w.position
                        ),
                    });
                }
            }
        }
        Ok(())
    }
}

/// A periodic box without walls.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PeriodicBox<const D: usize> {
    /// The periodic axes.
    pub periodic: Periodicity<D>,
}

impl<const D: usize> Boundary<D> for PeriodicBox<D> {
    fn has_ghosts(&self) -> bool {
        false
    }
    fn periodicity(&self) -> Periodicity<D> {
        self.periodic
    }
    fn fill_scalar(&self, _: &[Role], _: &mut [f64]) {}
    fn fill_vector(&self, _: &[Role], _: &mut [[f64; D]], _: VectorKind) {}
    fn place_ghosts(&self, _: &mut Particles<D>) {}
    fn make_ghosts(&self, _: &mut Particles<D>, _: f64) {}
    fn confine(&self, p: &mut Particles<D>) -> Result<(), InputError> {
        for (x, r) in p.x.iter_mut().zip(&p.role) {
            if r.is_fluid() {
                self.periodic.wrap(x);
            }
        }
        Ok(())
    }
}

/// No boundary handling at all (free space, or a Dirichlet band the caller placed).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct NoBoundary;

impl<const D: usize> Boundary<D> for NoBoundary {
    fn has_ghosts(&self) -> bool {
        false
    }
    fn periodicity(&self) -> Periodicity<D> {
        Periodicity::none()
    }
    fn fill_scalar(&self, _: &[Role], _: &mut [f64]) {}
    fn fill_vector(&self, _: &[Role], _: &mut [[f64; D]], _: VectorKind) {}
    fn place_ghosts(&self, _: &mut Particles<D>) {}
    fn make_ghosts(&self, _: &mut Particles<D>, _: f64) {}
    fn confine(&self, _: &mut Particles<D>) -> Result<(), InputError> {
        Ok(())
    }
}

/// Every ghost's value from its source's, `v_g = f(v_src, walls)` (entries past the end of `v`
/// are left alone).
fn fill_from_sources<T: Copy + Send + Sync>(
    role: &[Role],
    v: &mut [T],
    f: impl Fn(&T, u8) -> T + Sync,
) {
    fill_from_sources_at(role, v, |s, _, walls| f(s, walls))
}

/// [`fill_from_sources`] with the source's index passed on.
fn fill_from_sources_at<T: Copy + Send + Sync>(
    role: &[Role],
    v: &mut [T],
    f: impl Fn(&T, usize, u8) -> T + Sync,
) {
    let first = first_ghost(role).min(v.len());
    let (src, ghosts) = v.split_at_mut(first);
    ghosts
        .par_iter_mut()
        .zip(role[first..].par_iter())
        .for_each(|(g, r)| {
            if let Role::Ghost { source, walls } = r {
                *g = f(&src[*source as usize], *source as usize, *walls);
            }
        });
}

/// The quintic step `S(t) = 6t⁵ − 15t⁴ + 10t³` on `t` clamped to `[0, 1]`.
pub(crate) fn smooth_step(t: f64) -> f64 {
    let t = t.clamp(0.0, 1.0);
    t * t * t * (10.0 + t * (6.0 * t - 15.0))
}

/// Index of the first ghost (ghosts are kept after every other particle).
pub fn first_ghost(role: &[Role]) -> usize {
    role.iter()
        .position(|r| matches!(r, Role::Ghost { .. }))
        .unwrap_or(role.len())
}
