//! The lid corners' singularity subtracted from the square cavity (Botella & Peyret 1998).
//!
//! At a corner where a wall slides along itself at speed `U` and meets a wall at rest, the
//! velocity jumps and no discretisation resolves the flow at the grid scale. The leading term
//! of the flow there is Stokes flow in the corner (Taylor's scraping flow; Batchelor 1967,
//! *An Introduction to Fluid Dynamics*): with `ξ` along the lid away from the corner, `η`
//! along the wall at rest and `(r, θ)` their polar coordinates (`θ = 0` the lid, `θ = π/2` the
//! wall at rest), `ψ = r f(θ)`,
//!
//! `f(θ) = A sin θ + C θ sin θ + D θ cos θ`, `D = U/(1 − π²/4)`, `C = Dπ/2`, `A = −Dπ²/4`,
//!
//! `u_r = f'(θ)`, `u_θ = −f(θ)`: `u = U` along the lid, `0` along the wall, divergence-free,
//! a function of `θ` alone (a jump at `r = 0`, gradient `∝ 1/r`). The square cavity's
//! singular part `u_s` is the sum of both lid corners' (each extended over the whole box; on
//! the lid each gives `U`, so the regular part `u − u_s` is `−U` there and takes the other walls'
//! values minus `u_s` — continuous, without the jump).
//!
//! The particles still carry `u`; what changes is what the discrete operators act on
//! ([`crate::flow::Simulation::set_singular_part`]):
//!
//! * the viscous term and the pressure: `u_s` is Stokes flow, `ν Δu_s = ∇p_s/ρ`, so the momentum
//!   equation of `u − u_s` keeps the regular pressure `p − p_s` and drops both — the predictor
//!   gets `−ν L_h u_s` added (`L_h` the predictor's own viscous operator, `u_s` continued into
//!   the ghosts by the no-slip rule with the walls' `u_s`), and the pressure the run reports is
//!   the **regular part** `p − p_s` (`p_s ∝ 1/r` has no finite value at the corner);
//! * convection: of `(u·∇)u = (u·∇)(u − u_s) + ((u − u_s)·∇)u_s + (u_s·∇)u_s` only the last,
//!   the singular `∝ 1/r` self-advection of `u_s`, is taken exactly — the predictor gets
//!   `N_h(u_s) − (u_s·∇)u_s` added, `N_h` the run's own convective form (the other two terms
//!   are bounded and stay discrete; taking the cross term exactly too puts an explicit
//!   `∝ 1/r` rate on the corner particles, which blew up at Re 1000, n = 32);
//! * the projection makes the source's divergence of `u − u_s` vanish
//!   ([`crate::projection::SingularPart`]; `u_s` continued into the ghosts as the source's
//!   rule continues the regular part, i.e. about the walls' `u_s` where the rule uses the
//!   walls' velocity).
//!
//! Fixed particles of the 2D square cavity `[0, 1]²` (lid `y = 1` moving in `+x`) only, with
//! the sum-form source; [`install`] checks.

use crate::boundary::{VectorKind, Walls};
use crate::error::{Error, InputError};
use crate::flow::convection::{Convection, ConvectionForm, Integrator};
use crate::flow::Simulation;
use crate::particles::Role;
use crate::projection::{SingularPart, SourceKind};
use std::f64::consts::PI;

/// The scraper flow of one corner: origin `o`, axis signs `s` (`ξ = s₀ (x − o₀)`,
/// `η = s₁ (y − o₁)`, both `≥ 0` in the box), the lid along `ξ` moving at `u_lid` (in `ξ`).
/// Returns `u` and `∇u` (`g[a][b] = ∂u_a/∂x_b`) at `x ≠ o`.
fn scraper(x: &[f64; 2], o: [f64; 2], s: [f64; 2], u_lid: f64) -> ([f64; 2], [[f64; 2]; 2]) {
    let (xi, eta) = (s[0] * (x[0] - o[0]), s[1] * (x[1] - o[1]));
    let r2 = xi * xi + eta * eta;
    let th = eta.atan2(xi);
    let d = u_lid / (1.0 - PI * PI / 4.0);
    let (c, a) = (d * PI / 2.0, -d * PI * PI / 4.0);
    let (sn, cs) = th.sin_cos();
    let f = a * sn + c * th * sn + d * th * cs;
    let fp = a * cs + c * sn + c * th * cs + d * cs - d * th * sn;
    // u_ξ = u_r cos θ − u_θ sin θ, u_η = u_r sin θ + u_θ cos θ
    let (u_xi, u_eta) = (fp * cs + f * sn, fp * sn - f * cs);
    // d/dθ (u_ξ, u_η) = (f'' + f)(cos θ, sin θ), f'' + f = 2C cos θ − 2D sin θ
    let ff = 2.0 * c * cs - 2.0 * d * sn;
    let (dxi, deta) = (ff * cs, ff * sn);
    let (th_xi, th_eta) = (-eta / r2, xi / r2);
    let u = [s[0] * u_xi, s[1] * u_eta];
    let g = [
        [dxi * th_xi, s[0] * s[1] * dxi * th_eta],
        [s[0] * s[1] * deta * th_xi, deta * th_eta],
    ];
    (u, g)
}

/// `u_s` and `∇u_s` of the square cavity `[0, 1]²` with the lid `y = 1` moving at `lid` in
/// `+x`: both lid corners' scraper flows summed (module docs). Undefined at the two corners.
pub fn singular_velocity(x: &[f64; 2], lid: f64) -> ([f64; 2], [[f64; 2]; 2]) {
    let (u1, g1) = scraper(x, [0.0, 1.0], [1.0, -1.0], lid);
    let (u2, g2) = scraper(x, [1.0, 1.0], [-1.0, -1.0], -lid);
    (
        [u1[0] + u2[0], u1[1] + u2[1]],
        std::array::from_fn(|a| std::array::from_fn(|b| g1[a][b] + g2[a][b])),
    )
}

/// The walls of `Walls::cavity` / `closed_box([0, 0], [1, 1])` in their order: bit `k` of a
/// ghost's mask is the wall on axis `k / 2` at `k % 2`.
fn foot(x: &[f64; 2], k: usize) -> [f64; 2] {
    let mut y = *x;
    y[k / 2] = (k % 2) as f64;
    y
}

/// `u_s` at every particle: exact on the real particles, continued into each ghost by `rule`
/// with the walls' own `u_s` at the source's feet — the continuation the rule gives the regular
/// part `u − u_s` (whose walls move at `U − u_s`), subtracted from the one it gives `u`:
///
/// * [`VectorKind::Velocity`] (no-slip): across one wall `2 u_s(foot) − u_s`; across two,
///   the mean of both orders, `u_s`;
/// * [`VectorKind::Mirror`]: each crossed wall's normal component odd about the wall's
///   `u_s`, the tangential ones even;
/// * [`VectorKind::RestWalls`]: the mirror across the lid (alone or with another wall);
///   across walls at rest the no-slip images blended into the mirror within `band` of the
///   lid (as [`crate::boundary::Wall::source_band`]).
fn continued(
    x: &[[f64; 2]],
    role: &[Role],
    lid: f64,
    rule: VectorKind,
    band: f64,
) -> Vec<[f64; 2]> {
    let at = |p: &[f64; 2]| singular_velocity(p, lid).0;
    let mut out: Vec<[f64; 2]> = (0..x.len())
        .map(|i| {
            if role[i].is_real() {
                at(&x[i])
            } else {
                [0.0; 2]
            }
        })
        .collect();
    let walls_of = |m: u8| (0..4).filter(move |k| m & (1 << k) != 0);
    let mirror = |xs: &[f64; 2], v: [f64; 2], m: u8| {
        let mut y = v;
        for k in walls_of(m) {
            y[k / 2] = 2.0 * at(&foot(xs, k))[k / 2] - y[k / 2];
        }
        y
    };
    let no_slip = |xs: &[f64; 2], v: [f64; 2], m: u8| match m.count_ones() {
        1 => {
            let w = at(&foot(xs, m.trailing_zeros() as usize));
            [2.0 * w[0] - v[0], 2.0 * w[1] - v[1]]
        }
        _ => v,
    };
    for i in 0..x.len() {
        let Role::Ghost { source, walls } = role[i] else {
            continue;
        };
        let xs = &x[source as usize];
        let v = at(xs);
        out[i] = match rule {
            VectorKind::Velocity => no_slip(xs, v, walls),
            VectorKind::Mirror => mirror(xs, v, walls),
            // (install refuses the linear rule: its lid ghosts need the neighbour list)
            VectorKind::RestWalls | VectorKind::RestWallsLinear => {
                if walls & 0b1000 != 0 {
                    mirror(xs, v, walls)
                } else {
                    let odd = no_slip(xs, v, walls);
                    let even = mirror(xs, v, walls);
                    // the boundary's own blend (no band: the no-slip images alone)
                    let beta = if band > 0.0 {
                        crate::boundary::smooth_step((1.0 - xs[1]) / band)
                    } else {
                        1.0
                    };
                    [0, 1].map(|a| beta * odd[a] + (1.0 - beta) * even[a])
                }
            }
        };
    }
    out
}

/// Installs the lid corners' singular part in a square-cavity simulation built by
/// [`super::cavity::build`] (lid speed `lid`, the rest-walls rule's band `band`): the
/// predictor's steady acceleration and the projection's [`SingularPart`] (module docs).
/// Errors for moving particles, a ramped lid, walls other than the cavity's, a source other
/// than the sum form, or a MUSCL convective form (whose ghost gradients are the walls' own).
pub fn install(sim: &mut Simulation<2, Walls<2>>, lid: f64, band: f64) -> Result<(), Error> {
    let bad = |reason: String| -> Error {
        InputError::Parameter {
            name: "corner_subtraction".into(),
            value: f64::NAN,
            reason,
        }
        .into()
    };
    let cavity = Walls::<2>::cavity(1.0, lid);
    let walls = &sim.boundary.walls;
    if walls.len() != 4
        || walls.iter().zip(&cavity.walls).any(|(w, c)| {
            (w.axis, w.position, w.inward, w.velocity, w.slip)
                != (c.axis, c.position, c.inward, c.velocity, c.slip)
                || w.ramp > 0.0
        })
    {
        return Err(bad(
            "needs the square cavity's walls, the lid at y = 1 without a ramp".into(),
        ));
    }
    let params = &sim.params;
    if params.projection.source != SourceKind::SumForm {
        return Err(bad(format!(
            "needs the sum-form source, not {:?}",
            params.projection.source
        )));
    }
    if params.projection.source_ghosts == VectorKind::RestWallsLinear {
        return Err(bad(
            "not with the rest_walls_linear source rule (the subtraction continues the \
             singular part's ghosts without the neighbour list)"
                .into(),
        ));
    }
    if matches!(
        params.convection,
        ConvectionForm::Muscl | ConvectionForm::MusclVanLeer
    ) {
        return Err(bad(format!(
            "not with the {:?} convective form",
            params.convection
        )));
    }
    let (x, role, vol) = (&sim.particles.x, &sim.particles.role, &sim.particles.vol);
    let n = x.len();
    let nl = &sim.nl;
    let no_slip = continued(x, role, lid, VectorKind::Velocity, band);
    let source = continued(x, role, lid, params.projection.source_ghosts, band);
    // ν L_h u_s with the predictor's viscous operator
    let nu = params.projection.nu;
    let mut lap = vec![[0.0; 2]; n];
    if params.projection.laplacian == crate::consistent::LaplacianKind::LeastSquares {
        sim.projection
            .velocity_least_squares(nl, vol, x, role)
            .laplacian_vec_into(nl, &no_slip, &mut lap);
    } else {
        crate::operators::laplacian_vec_into(nl, vol, &no_slip, &mut lap);
    }
    // −N_h(u_s) with the run's convective form (one forward-Euler evaluation)
    let ls = (params.projection.gradient == crate::consistent::GradientKind::LeastSquares)
        .then(|| sim.projection.velocity_least_squares(nl, vol, x, role));
    let mut minus_n = Vec::new();
    Convection::new().accel_into(
        nl,
        vol,
        x,
        role,
        &sim.boundary,
        ls,
        &no_slip,
        params.convection,
        Integrator::Euler,
        1.0,
        &mut minus_n,
    );
    let convects = sim.plan().has(crate::flow::Stage::Convection);
    let accel: Vec<[f64; 2]> = (0..n)
        .map(|i| {
            if !role[i].is_fluid() {
                return [0.0; 2];
            }
            let (u, g) = singular_velocity(&x[i], lid);
            std::array::from_fn(|a| {
                let exact = u[0] * g[a][0] + u[1] * g[a][1];
                let conv = if convects {
                    -exact - minus_n[i][a]
                } else {
                    0.0
                };
                conv - nu * lap[i][a]
            })
        })
        .collect();
    sim.set_singular_part(Some((accel, SingularPart { source, no_slip })))?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    const TL: ([f64; 2], [f64; 2], f64) = ([0.0, 1.0], [1.0, -1.0], 1.0);
    const TR: ([f64; 2], [f64; 2], f64) = ([1.0, 1.0], [-1.0, -1.0], -1.0);

    #[test]
    fn each_corner_flow_takes_its_walls_velocities() {
        // (corner, a point on the lid at distance t from it, a point on its wall at rest)
        let on_lid = |c: &([f64; 2], [f64; 2], f64), t: f64| [c.0[0] + c.1[0] * t, 1.0];
        let on_wall = |c: &([f64; 2], [f64; 2], f64), t: f64| [c.0[0], 1.0 - t];
        for c in [TL, TR] {
            for t in [0.05, 0.4, 0.9] {
                // along the lid (y = 1): the lid's velocity (1, 0)
                let (u, _) = scraper(&on_lid(&c, t), c.0, c.1, c.2);
                assert!((u[0] - 1.0).abs() < 1e-14 && u[1].abs() < 1e-14, "{u:?}");
                // along the wall at rest (x = 0 or 1): at rest
                let (u, _) = scraper(&on_wall(&c, t), c.0, c.1, c.2);
                assert!(u[0].abs() < 1e-14 && u[1].abs() < 1e-14, "{u:?}");
            }
        }
    }

    /// `∇u_s` against central differences, divergence-free, and each corner's vorticity
    /// harmonic (the Stokes equations: `ω = −(f'' + f)/r` with `f'' + f` a sum of `cos θ` and
    /// `sin θ`).
    #[test]
    fn the_singular_part_is_divergence_free_stokes_flow_with_its_gradient() {
        let lid = 1.3;
        for p in [
            [0.3, 0.6],
            [0.1, 0.9],
            [0.8, 0.95],
            [0.5, 0.1],
            [0.02, 0.97],
        ] {
            let (_, g) = singular_velocity(&p, lid);
            assert!((g[0][0] + g[1][1]).abs() < 1e-12 * (1.0 + g[0][0].abs()));
            let e = 1e-6;
            for b in 0..2 {
                let (mut a, mut c) = (p, p);
                a[b] += e;
                c[b] -= e;
                let (ua, uc) = (singular_velocity(&a, lid).0, singular_velocity(&c, lid).0);
                for k in 0..2 {
                    let fd = (ua[k] - uc[k]) / (2.0 * e);
                    assert!(
                        (fd - g[k][b]).abs() < 1e-6 * (1.0 + g[k][b].abs()),
                        "{p:?} {k} {b}: {fd} {}",
                        g[k][b]
                    );
                }
            }
            for (o, s, u) in [TL, TR] {
                let omega = |q: [f64; 2]| {
                    let g = scraper(&q, o, s, u * lid).1;
                    g[1][0] - g[0][1]
                };
                let r = (p[0] - o[0]).hypot(p[1] - o[1]);
                // central differences at a step well below the distance to the corner
                let h = 1e-3 * r;
                let lap = (omega([p[0] + h, p[1]])
                    + omega([p[0] - h, p[1]])
                    + omega([p[0], p[1] + h])
                    + omega([p[0], p[1] - h])
                    - 4.0 * omega(p))
                    / (h * h);
                let w = omega(p).abs();
                assert!(
                    w > 0.0 && lap.abs() < 1e-3 * w / (r * r),
                    "{p:?}: Δω = {lap}, ω = {w}"
                );
            }
        }
    }

    /// Re 1000 at n = 24 to t = 2 (the impulsive start, where the corners' forcing is largest):
    /// bounded, the projection cuts the regular part's divergence every step, the stability ratio
    /// stays ≤ 1.
    #[test]
    fn a_cavity_with_the_corners_subtracted_runs_and_cuts_the_regular_divergence() {
        use crate::scene::cavity::{build, Cavity, CavityConfig};
        let cfg = CavityConfig {
            flow: crate::scene::FlowConfig {
                n: 24,
                re: 1000.0,
                ..CavityConfig::default().flow
            },
            scene: Cavity {
                corner_subtraction: true,
                ..Default::default()
            },
        };
        let mut sim = build(&cfg).expect("the classic cavity takes the subtraction");
        assert!(sim.projection.singular.is_some());
        let mut steps = 0;
        while sim.time < 2.0 {
            let r = sim.advance().expect("the step runs");
            let p = &r.projection;
            assert!(
                p.div_after < p.div_before,
                "step {}: {} after {}",
                r.step,
                p.div_after,
                p.div_before
            );
            assert!(
                p.stability_ratio <= 1.0,
                "step {}: {}",
                r.step,
                p.stability_ratio
            );
            steps += 1;
        }
        assert!(steps > 20);
        let vmax = sim
            .particles
            .u
            .iter()
            .zip(&sim.particles.role)
            .filter(|(_, r)| r.is_fluid())
            .map(|(u, _)| u[0].hypot(u[1]))
            .fold(0.0, f64::max);
        // (1.77 at t = 2: the corners' forcing at this coarse resolution overshoots the lid
        // speed near them for a while)
        assert!(vmax.is_finite() && vmax < 2.0, "max speed {vmax}");
    }

    #[test]
    fn the_subtraction_is_refused_where_it_does_not_apply() {
        use crate::scene::cavity::{build, Cavity, CavityConfig};
        let mut cfg = CavityConfig {
            flow: crate::scene::FlowConfig {
                n: 16,
                ..CavityConfig::default().flow
            },
            scene: Cavity {
                corner_subtraction: true,
                lid_ramp: 0.25,
                ..Default::default()
            },
        };
        let e = build(&cfg)
            .err()
            .expect("a ramped lid is refused")
            .to_string();
        assert!(e.contains("corner_subtraction"), "{e}");
        cfg.scene.lid_ramp = 0.0;
        cfg.motion = crate::flow::Motion::Lagrangian;
        let e = build(&cfg)
            .err()
            .expect("moving particles are refused")
            .to_string();
        assert!(e.contains("corner_subtraction"), "{e}");
        cfg.motion = crate::flow::Motion::Eulerian;
        cfg.convection = ConvectionForm::Muscl;
        let e = build(&cfg).err().expect("MUSCL is refused").to_string();
        assert!(e.contains("corner_subtraction"), "{e}");
    }
}
