//! The volume shift of moving particles (`Shifting::volume`, issue 13): zero on a lattice, a
//! displacement that evens out a compressed patch, and the Lagrangian cavity at Re 1000 that it
//! (with the mirror source rule of moving particles) keeps running where it failed at t ≈ 0.2.

use gpm::boundary::Walls;
use gpm::flow::{Motion, Simulation};
use gpm::geometry::lattice;
use gpm::particles::{Particles, Role};
use gpm::scene::cavity::{self, CavityConfig};
use gpm::scene::run_scene;
use std::ops::ControlFlow;

fn config(n: usize) -> CavityConfig {
    CavityConfig::default().with(|c| {
        c.n = n;
        c.motion = Motion::Lagrangian;
    })
}

/// The cavity's particles at `x`, with its walls, neighbours and number-density volumes.
fn cavity_at(cfg: &CavityConfig, x: &[[f64; 2]]) -> Simulation<2, Walls<2>> {
    let dx = cfg.dx();
    let mut p = Particles::<2>::new();
    for &xi in x {
        p.push(xi, [0.0; 2], 0.0, dx * dx, Role::Fluid);
    }
    Simulation::new(
        p,
        Walls::cavity(1.0, 1.0),
        cfg.neighbor_config(),
        cfg.flow_params(1.0),
    )
    .expect("a valid cavity")
}

/// The volume shift of `sim` with `β` and the RMS relative volume error it was computed from.
fn volume_shift(sim: &mut Simulation<2, Walls<2>>, beta: f64) -> (Vec<[f64; 2]>, f64) {
    let mut out = Vec::new();
    let e = sim
        .projection
        .volume_shift_into(
            &sim.particles,
            &sim.nl,
            &sim.boundary,
            &sim.params.projection,
            beta,
            None,
            &mut out,
        )
        .expect("the volume shift's solve");
    (out, e)
}

/// On the cell-centred lattice with its mirror ghosts every number-density volume is the same:
/// the volume error and the shift are zero (round-off). A patch compressed towards its centre
/// (by up to 12 % of the distance) has a volume error; moving the particles by the shift and
/// measuring again (new neighbours, new volumes) leaves a fraction of it, the particles move
/// outwards from the centre, and nobody crosses a wall.
#[test]
fn the_volume_shift_leaves_the_lattice_alone_and_evens_out_a_compressed_patch() {
    let cfg = config(24);
    let x0 = lattice([0.0; 2], [1.0; 2], cfg.dx());
    let mut sim = cavity_at(&cfg, &x0);
    let (shift, e) = volume_shift(&mut sim, 1.0);
    let largest = shift.iter().map(|d| d[0].hypot(d[1])).fold(0.0, f64::max);
    assert!(e < 1e-12, "lattice volume error {e:e}");
    assert!(largest < 1e-12 * cfg.dx(), "lattice shift {largest:e}");

    let (c, r) = ([0.45, 0.55], 0.25);
    let x: Vec<[f64; 2]> = x0
        .iter()
        .map(|p| {
            let d = [p[0] - c[0], p[1] - c[1]];
            let s = d[0].hypot(d[1]) / r;
            let f = if s < 1.0 { 1.0 - 0.12 * (1.0 - s) } else { 1.0 };
            [c[0] + f * d[0], c[1] + f * d[1]]
        })
        .collect();
    let mut sim = cavity_at(&cfg, &x);
    let (shift, e1) = volume_shift(&mut sim, 1.0);
    assert!(e1 > 1e-3, "the compressed patch has a volume error: {e1:e}");
    // outwards: the shift of the particles around the centre points away from it
    let mut outward = 0.0;
    for (p, d) in x.iter().zip(&shift) {
        let rel = [p[0] - c[0], p[1] - c[1]];
        let s = rel[0].hypot(rel[1]);
        if s > 0.05 && s < r {
            outward += (rel[0] * d[0] + rel[1] * d[1]) / s;
        }
    }
    assert!(
        outward > 0.0,
        "the patch's shift points inwards ({outward:e})"
    );
    let moved: Vec<[f64; 2]> = x
        .iter()
        .zip(&shift)
        .map(|(p, d)| [p[0] + d[0], p[1] + d[1]])
        .collect();
    assert!(moved.iter().all(|p| p.iter().all(|&v| v > 0.0 && v < 1.0)));
    let mut sim = cavity_at(&cfg, &moved);
    let (_, e2) = volume_shift(&mut sim, 1.0);
    assert!(
        e2 < 0.6 * e1,
        "one shift left {e2:e} of the volume error {e1:e}"
    );
}

/// The Lagrangian cavity at Re 1000 with the cavity's defaults (the walls' shifting with the
/// volume shift, the mirror source rule of moving particles) holds to t = 3 at n = 40, its
/// particles inside the walls and no speed above the lid's by more than a quarter; without the
/// volume shift and with the no-slip source rule (the defaults before) it stops at t < 1.
#[test]
fn the_volume_shift_holds_the_lagrangian_cavity_at_re_1000() {
    let cfg = config(40).with(|c| {
        c.re = 1000.0;
        c.t_end = 3.0;
        c.limits.cfl = cavity::LAGRANGIAN_CFL;
        c.scene.steady.stop_when_steady = false;
    });
    let mut vmax = 0.0f64;
    let run = run_scene(
        &cfg,
        |_| {},
        |rep, _| {
            vmax = vmax.max(rep.projection.max_speed);
            Ok(ControlFlow::Continue(()))
        },
    )
    .expect("the Lagrangian cavity at Re 1000 to t = 3");
    assert!(
        run.sim.time >= 3.0 - 1e-9,
        "stopped at t = {}",
        run.sim.time
    );
    assert!(vmax <= 1.25, "a velocity reached {vmax} U");
    assert!(run.result.monitor.c0_max > run.result.monitor.c0_min);

    let before = cfg.clone().with(|c| {
        if let Some(s) = c.shifting.as_mut() {
            s.volume = 0.0;
            s.max_fraction = 0.2;
        }
        c.scene.source_ghosts = cavity::SourceGhosts::NoSlip;
    });
    let failed = run_scene(&before, |_| {}, |_, _| Ok(ControlFlow::Continue(())));
    match failed {
        Err(e) => eprintln!("the old defaults: {e}"),
        Ok(run) => panic!("the old defaults held to t = {}", run.sim.time),
    }
}
