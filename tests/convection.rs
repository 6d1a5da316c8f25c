//! The convective term (`flow::convection`, issue 15): every form exact on linear fields, the
//! ghost gradients those of the no-slip images, and the Re 1000 cavity at the CFL limit, which
//! the central form blows up and the skew-symmetric form keeps bounded.

use gpm::boundary::{first_ghost, Boundary, NoBoundary, VectorKind, Walls};
use gpm::flow::{Convection, ConvectionForm, Integrator};
use gpm::geometry::{lattice, number_density_volumes};
use gpm::kernel::Weight;
use gpm::neighbors::{NeighborConfig, NeighborList};
use gpm::particles::{Particles, Role};
use gpm::scene::cavity::{self, CavityConfig};

const FORMS: [ConvectionForm; 5] = [
    ConvectionForm::Central,
    ConvectionForm::SkewSymmetric,
    ConvectionForm::Upwind,
    ConvectionForm::Muscl,
    ConvectionForm::MusclVanLeer,
];

/// A linear field `u = A x + b` (not divergence-free: the forms must not rely on it).
fn linear(x: &[f64; 2]) -> [f64; 2] {
    [
        0.3 + 1.2 * x[0] - 0.7 * x[1],
        -0.4 + 0.5 * x[0] + 0.9 * x[1],
    ]
}
const A: [[f64; 2]; 2] = [[1.2, -0.7], [0.5, 0.9]];

#[test]
fn every_form_is_exact_on_linear_fields_away_from_the_boundary() {
    let (n, h_over_dx) = (24usize, 3.0);
    let dx = 1.0 / n as f64;
    let h = h_over_dx * dx;
    let mut p = Particles::<2>::new();
    for x in lattice([0.0, 0.0], [1.0, 1.0], dx) {
        let u = linear(&x);
        p.push(x, u, 0.0, dx * dx, Role::Fluid);
    }
    let nl = NeighborList::build(NeighborConfig::new(Weight::WendlandC2, h, 0.0), &p.x).unwrap();
    // ω = 1/Σw: the difference gradient is exact on linear fields on the symmetric lattice
    p.vol = number_density_volumes(&nl);
    // the MUSCL forms read the gradients of the neighbours too: rows 2h inside the edge
    let interior: Vec<usize> = (0..p.len())
        .filter(|&i| p.x[i].iter().all(|&c| c > 2.0 * h && c < 1.0 - 2.0 * h))
        .collect();
    assert!(interior.len() > 20);
    for form in FORMS {
        let mut conv = Convection::<2>::new();
        let mut out = Vec::new();
        conv.accel_into(
            &nl,
            &p.vol,
            &p.x,
            &p.role,
            &NoBoundary,
            None,
            &p.u,
            form,
            Integrator::Euler,
            1e-3,
            &mut out,
        );
        let mut worst = 0.0f64;
        for &i in &interior {
            let u = p.u[i];
            // −(u·∇)u with the exact gradient A
            let exact: [f64; 2] = std::array::from_fn(|a| -(A[a][0] * u[0] + A[a][1] * u[1]));
            for a in 0..2 {
                worst = worst.max((out[i][a] - exact[a]).abs());
            }
        }
        assert!(worst < 1e-11, "{form:?}: error {worst:e}");
    }
}

#[test]
fn ghost_gradients_are_those_of_the_no_slip_images() {
    // every ghost's velocity is an affine function of its position within each group of
    // ghosts reflected across the same walls (the lid corners included): the filled gradient
    // must be that function's gradient
    let n = 12usize;
    let dx = 1.0 / n as f64;
    let walls = Walls::<2>::cavity(1.0, 1.0);
    let mut p = Particles::<2>::new();
    for x in lattice([0.0, 0.0], [1.0, 1.0], dx) {
        let u = linear(&x);
        p.push(x, u, 0.0, dx * dx, Role::Fluid);
    }
    walls.make_ghosts(&mut p, 3.0 * dx);
    walls.fill_vector(&p.role, &mut p.u, VectorKind::Velocity);
    let mut g = vec![A; p.len()];
    let first = first_ghost(&p.role);
    for gg in &mut g[first..] {
        *gg = [[f64::NAN; 2]; 2];
    }
    walls.fill_velocity_gradient(&p.x, &p.role, &mut g);
    let mask = |i: usize| match p.role[i] {
        Role::Ghost { walls, .. } => walls,
        _ => unreachable!(),
    };
    let mut pairs = 0;
    for (i, gi) in g.iter().enumerate().skip(first) {
        for j in first..p.len() {
            if i == j || mask(i) != mask(j) {
                continue;
            }
            let dxij = [p.x[j][0] - p.x[i][0], p.x[j][1] - p.x[i][1]];
            for (a, row) in gi.iter().enumerate() {
                let predicted = row[0] * dxij[0] + row[1] * dxij[1];
                let actual = p.u[j][a] - p.u[i][a];
                assert!(
                    (predicted - actual).abs() < 1e-12,
                    "ghosts {i}, {j} (walls {:#b}): {predicted} vs {actual}",
                    mask(i)
                );
            }
            pairs += 1;
        }
    }
    assert!(pairs > 100);
    // a lid corner is among the groups
    assert!((first..p.len()).any(|i| mask(i).count_ones() == 2));
}

fn cavity_re1000(form: ConvectionForm) -> CavityConfig {
    // n = 48, Δt at the default CFL limit 0.2 h/U: cell Reynolds number U Δx/ν ≈ 21
    CavityConfig::default().with(|c| {
        c.re = 1000.0;
        c.n = 48;
        c.t_end = 2.0;
        c.convection = form;
    })
}

#[test]
fn re1000_cavity_at_the_cfl_limit_blows_up_with_central_convection_only() {
    // central: the speed guard (3 U) trips near the top-right lid corner before t = 1
    match cavity::run(&cavity_re1000(ConvectionForm::Central), |_, _| Ok(())) {
        Err(gpm::error::Error::Stability(gpm::error::StabilityError::BlowUp {
            time,
            position,
            ..
        })) => {
            assert!(time < 2.0);
            assert!(position[0] > 0.9 && position[1] > 0.9, "{position:?}");
        }
        other => panic!(
            "expected the central form to blow up: {:?}",
            other.map(|r| r.steps)
        ),
    }
    // skew-symmetric: bounded through the spin-up, every step within the theory's bound
    let mut max_speed = 0.0f64;
    let res = cavity::run(&cavity_re1000(ConvectionForm::SkewSymmetric), |rep, _| {
        assert!(rep.projection.stability_ratio <= 1.0);
        assert!(
            rep.dt_ratio <= 1.0 + 1e-12,
            "dt at the CFL limit, not above"
        );
        max_speed = max_speed.max(rep.projection.max_speed);
        Ok(())
    })
    .unwrap();
    assert!((res.t_end - 2.0).abs() < 1e-9, "ran to t = {}", res.t_end);
    // the lid speed bounds the flow (no overshoot beyond a few per cent)
    assert!(max_speed < 1.1, "max speed {max_speed}");
}
