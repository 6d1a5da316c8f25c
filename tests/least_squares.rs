//! The least-squares operators (`gpm::consistent::LsOperators`) on disordered particles: exact
//! on quadratic fields in the interior, and, in the wall variant, on quadratic velocities that
//! take the wall value (the no-slip images stand for wall points).

use gpm::boundary::{Boundary, VectorKind, Walls};
use gpm::consistent::LsOperators;
use gpm::geometry::{jitter, lattice};
use gpm::kernel::Weight;
use gpm::neighbors::{NeighborConfig, NeighborList};
use gpm::particles::{Particles, Role};
use gpm::setup::{prepare, VolumeRule};

/// A jittered channel `[0, 1) × [0, 1]`, periodic in x, walls at y = 0 and 1.
fn channel(n: usize, jit: f64) -> (Particles<2>, Walls<2>, NeighborList<2>) {
    let dx = 1.0 / n as f64;
    let mut x = lattice([0.0, 0.0], [1.0, 1.0], dx);
    jitter(&mut x, jit * dx, 11);
    let mut p = Particles::<2>::new();
    for x in x {
        p.push(x, [0.0, 0.0], 0.0, dx * dx, Role::Fluid);
    }
    let walls = Walls::channel([0.0, 0.0], [1.0, 1.0]);
    let nc = NeighborConfig::new_relative(Weight::WendlandC2, dx, 3.0, 0.3);
    let nl = prepare(&mut p, &walls, nc, VolumeRule::NumberDensity).unwrap();
    (p, walls, nl)
}

#[test]
fn wall_variant_is_exact_for_a_no_slip_quadratic_profile() {
    for jit in [0.1, 0.3] {
        let (mut p, walls, nl) = channel(24, jit);
        // Poiseuille profile u = (y (1 − y), 0): zero at both walls, Δu = (−2, 0), div u = 0
        for i in 0..p.len() {
            if p.role[i].is_fluid() {
                let y = p.x[i][1];
                p.u[i] = [y * (1.0 - y), 0.0];
            }
        }
        walls.fill_vector(&p.role, &mut p.u, VectorKind::Velocity);
        let fluid = p.role.iter().filter(|r| r.is_fluid()).count();
        let mut ls = LsOperators::at_walls();
        ls.update(&nl, &p.vol, nl.len(), Some((&p.x, &p.role)));
        let fell: Vec<_> = ls.fallback_rows.iter().filter(|&&i| i < fluid).collect();
        assert!(fell.is_empty(), "fluid rows fell back: {fell:?}");
        let mut lap = vec![[0.0; 2]; fluid];
        ls.laplacian_vec_into(&nl, &p.u, &mut lap);
        let mut div = vec![0.0; fluid];
        ls.div_into(&nl, &p.u, &mut div);
        for i in 0..fluid {
            assert!(
                (lap[i][0] + 2.0).abs() < 1e-8,
                "jitter {jit} row {i}: Δu = {:?}",
                lap[i]
            );
            assert!(
                lap[i][1].abs() < 1e-8,
                "jitter {jit} row {i}: Δu = {:?}",
                lap[i]
            );
            assert!(
                div[i].abs() < 1e-8,
                "jitter {jit} row {i}: div u = {}",
                div[i]
            );
        }
        // the plain variant (ghosts as fit points) sees the odd extension and is not exact
        // in the rows next to the walls
        let mut plain = LsOperators::new();
        plain.update(&nl, &p.vol, nl.len(), None);
        plain.laplacian_vec_into(&nl, &p.u, &mut lap);
        let worst = lap.iter().map(|l| (l[0] + 2.0).abs()).fold(0.0, f64::max);
        assert!(worst > 0.1, "jitter {jit}: plain variant error {worst}");
    }
}

#[test]
fn plain_variant_is_exact_for_quadratics_away_from_walls() {
    let (mut p, _walls, nl) = channel(24, 0.3);
    let f = |x: &[f64; 2]| 1.0 + 0.3 * x[0] - 2.0 * x[1] + 0.7 * x[0] * x[1] - 1.5 * x[1] * x[1];
    // quadratic in x is not periodic: use rows away from x = 0, 1 and the walls
    for i in 0..p.len() {
        p.p[i] = f(&p.x[i]);
    }
    let mut ls = LsOperators::new();
    ls.update(&nl, &p.vol, nl.len(), None);
    let n = p.role.iter().filter(|r| r.is_fluid()).count();
    let mut g = vec![[0.0; 2]; n];
    ls.grad_into(&nl, &p.p, &mut g);
    let mut lap = vec![0.0; n];
    ls.laplacian_into(&nl, &p.p, &mut lap);
    let h = nl.h();
    let mut checked = 0;
    for i in 0..n {
        let x = p.x[i];
        if x[0] < h || x[0] > 1.0 - h || x[1] < h || x[1] > 1.0 - h {
            continue;
        }
        let ge = [0.3 + 0.7 * x[1], -2.0 + 0.7 * x[0] - 3.0 * x[1]];
        assert!(
            (g[i][0] - ge[0]).abs() < 1e-8 && (g[i][1] - ge[1]).abs() < 1e-8,
            "row {i}: {:?}",
            g[i]
        );
        assert!((lap[i] + 3.0).abs() < 1e-7, "row {i}: Δf = {}", lap[i]);
        checked += 1;
    }
    assert!(checked > n / 3, "{checked} rows checked");
}

/// One projection on a Vogel-spiral disk (nowhere a lattice) with a Dirichlet band of width
/// `h`: the consistent set leaves the rigid rotation `(−y, x)` as it is (its least-squares
/// divergence is zero to round-off, the band's velocities included), while the GPM pair changes
/// it by several per cent (the sum-form divergence of a linear field on a disordered set, and
/// the paper's zero source on the band).
#[test]
fn consistent_projection_keeps_a_rigid_rotation_on_a_spiral_disk() {
    use gpm::boundary::NoBoundary;
    use gpm::geometry::vogel_disk;
    use gpm::projection::{ProjectionParams, ProjectionStep, Scheme};
    let n = 1500;
    let dx = (std::f64::consts::PI / n as f64).sqrt();
    let h = 3.0 * dx;
    let mut gpm = ProjectionParams::<2>::new(0.0);
    gpm.scheme = Scheme::NonIncremental;
    gpm.allowed_floating = 0;
    let consistent = gpm.with_consistent_operators();
    let change = |params: &ProjectionParams<2>| {
        let mut p = Particles::<2>::new();
        for x in vogel_disk(n, [0.0, 0.0], 1.0) {
            let role = if x[0].hypot(x[1]) > 1.0 - h {
                Role::Dirichlet
            } else {
                Role::Fluid
            };
            p.push(x, [-x[1], x[0]], 0.0, dx * dx, role);
        }
        let config = NeighborConfig::new(Weight::WendlandC2, h, 0.0);
        let nl = prepare(&mut p, &NoBoundary, config, VolumeRule::NumberDensity).unwrap();
        let u_star = p.u.clone();
        ProjectionStep::new()
            .project(&mut p, &nl, &NoBoundary, params, 1.0, &u_star)
            .unwrap();
        (0..p.len())
            .filter(|&i| p.role[i] == Role::Fluid)
            .map(|i| (p.u[i][0] + p.x[i][1]).hypot(p.u[i][1] - p.x[i][0]))
            .fold(0.0, f64::max)
    };
    let c = change(&consistent);
    let g = change(&gpm);
    assert!(c < 1e-9, "consistent set changed the rotation by {c}");
    assert!(g > 1e-2, "GPM set changed it by only {g}");
}

/// The wall variant on a lattice in a closed 3D box (many pairs exactly at `r = h`, where
/// `w_h = 0` only up to rounding) gives mirror images the mirrored Laplacian: its fit points
/// must not depend on which far ghosts the neighbour search returned.
#[test]
fn wall_variant_keeps_the_mirror_symmetry_of_a_lattice() {
    let n = 12;
    let dx = 1.0 / n as f64;
    let mut p = Particles::<3>::new();
    for x in lattice([0.0; 3], [1.0; 3], dx) {
        p.push(x, [0.0; 3], 0.0, dx * dx * dx, Role::Fluid);
    }
    // the lid at z = 1 moves along x: the box is symmetric about y = 1/2
    let walls = Walls::<3>::cavity(1.0, 1.0);
    let nc = NeighborConfig::new_relative(Weight::WendlandC2, dx, 3.0, 0.3);
    let nl = prepare(&mut p, &walls, nc, VolumeRule::NumberDensity).unwrap();
    let fluid = p.role.iter().filter(|r| r.is_fluid()).count();
    // u_x, u_z even and u_y odd about y = 1/2
    for i in 0..fluid {
        let [a, b, c] = p.x[i];
        let s =
            (std::f64::consts::PI * a).sin() * (std::f64::consts::PI * b).sin() * (3.0 * c).sin();
        p.u[i] = [s, s * (b - 0.5), 0.5 * s * c];
    }
    walls.fill_vector(&p.role, &mut p.u, VectorKind::Velocity);
    let mut ls = LsOperators::at_walls();
    ls.update(&nl, &p.vol, nl.len(), Some((&p.x, &p.role)));
    let mut lap = vec![[0.0; 3]; fluid];
    ls.laplacian_vec_into(&nl, &p.u, &mut lap);
    let scale = lap.iter().flatten().fold(0.0f64, |m, v| m.max(v.abs()));
    for i in 0..fluid {
        let [a, b, c] = p.x[i];
        let j = (0..fluid)
            .find(|&j| {
                (p.x[j][0] - a).abs() < 1e-9
                    && (p.x[j][1] - (1.0 - b)).abs() < 1e-9
                    && (p.x[j][2] - c).abs() < 1e-9
            })
            .expect("the mirror image is a lattice point");
        let d = (lap[i][0] - lap[j][0])
            .abs()
            .max((lap[i][1] + lap[j][1]).abs())
            .max((lap[i][2] - lap[j][2]).abs());
        assert!(
            d < 1e-10 * scale,
            "rows {i} at {:?} and {j}: Δu {:?} vs {:?}",
            p.x[i],
            lap[i],
            lap[j]
        );
    }
}
