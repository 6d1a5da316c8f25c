//! The neighbour list (cell grid and kiddo k-d tree searches) against brute force: the same pairs (strictly `r < h`, as
//! the paper's sums), the same cached pair data, with periodic boxes, pairs placed exactly at
//! `h`, the skin's reuse rule, and the input errors.

mod common;

use common::{dirichlet_box, random_cloud, Spec};
use gpm::error::InputError;
use gpm::kernel::{Kernel, Weight};
use gpm::neighbors::{NeighborConfig, NeighborList, Periodicity, Search};

const SEARCHES: [Search; 2] = [Search::CellGrid, Search::KdTree];

/// One pair of the independent reference list.
#[derive(Clone, Copy, Debug)]
struct Pair<const D: usize> {
    j: usize,
    dx: [f64; D],
    r2: f64,
    w: f64,
}

/// Every ordered pair `(i, j)`, `j ≠ i`, with `|x_j − x_i| < h` (minimum image on periodic
/// axes), written from the definition without any code of the crate except the kernel.
fn reference<const D: usize>(cfg: &NeighborConfig<D>, x: &[[f64; D]]) -> Vec<Vec<Pair<D>>> {
    let k = Kernel::<D>::new(cfg.weight, cfg.h);
    let per = cfg.periodic;
    (0..x.len())
        .map(|i| {
            let mut row = Vec::new();
            for (j, xj) in x.iter().enumerate() {
                if j == i {
                    continue;
                }
                let mut d = [0.0; D];
                for a in 0..D {
                    d[a] = xj[a] - x[i][a];
                    let l = per.len[a];
                    if l > 0.0 {
                        d[a] -= l * (d[a] / l).round();
                    }
                }
                let r2: f64 = d.iter().map(|v| v * v).sum();
                if r2 < cfg.h * cfg.h {
                    row.push(Pair {
                        j,
                        dx: d,
                        r2,
                        w: k.w_h(r2.sqrt()),
                    });
                }
            }
            row
        })
        .collect()
}

/// Asserts that `nl` holds exactly the pairs of `want`, in ascending order per row, with the
/// same displacement, `r²`, `w_h` and `w_h/r²` up to round-off.
fn assert_same<const D: usize>(nl: &NeighborList<D>, want: &[Vec<Pair<D>>], what: &str) {
    assert_eq!(nl.len(), want.len(), "{what}: rows");
    let h = nl.h();
    for (i, row) in want.iter().enumerate() {
        let got: Vec<usize> = nl.row(i).map(|k| nl.indices()[k] as usize).collect();
        let exp: Vec<usize> = row.iter().map(|p| p.j).collect();
        assert_eq!(got, exp, "{what}: neighbours of particle {i}");
        for (k, p) in nl.row(i).zip(row) {
            for a in 0..D {
                assert!(
                    (nl.dx()[k][a] - p.dx[a]).abs() <= 4.0 * f64::EPSILON * h,
                    "{what}: dx of pair ({i},{}) axis {a}: {} vs {}",
                    p.j,
                    nl.dx()[k][a],
                    p.dx[a]
                );
            }
            assert!(
                (nl.r2(k) - p.r2).abs() <= 8.0 * f64::EPSILON * h * h,
                "{what}: r2"
            );
            assert!(
                (nl.w()[k] - p.w).abs() <= 1e-13 * p.w.abs().max(nl.kernel().w_h(0.0) * 1e-3),
                "{what}: w of pair ({i},{}): {} vs {}",
                p.j,
                nl.w()[k],
                p.w
            );
            let wr2 = p.w / p.r2;
            assert!(
                (nl.wr2()[k] - wr2).abs() <= 1e-12 * wr2.abs().max(1e-300),
                "{what}: wr2"
            );
        }
    }
    assert_eq!(nl.n_pairs(), want.iter().map(|r| r.len()).sum::<usize>());
}

/// Each unordered pair is stored from both ends with opposite displacements and equal data.
fn assert_symmetric<const D: usize>(nl: &NeighborList<D>) {
    for i in 0..nl.len() {
        for k in nl.row(i) {
            let j = nl.indices()[k] as usize;
            let back = nl
                .row(j)
                .find(|&m| nl.indices()[m] as usize == i)
                .unwrap_or_else(|| panic!("pair ({i},{j}) stored one way only"));
            for a in 0..D {
                assert_eq!(nl.dx()[back][a], -nl.dx()[k][a]);
            }
            assert_eq!(nl.r2(back), nl.r2(k));
            assert_eq!(nl.w()[back], nl.w()[k]);
            assert_eq!(nl.wr2()[back], nl.wr2()[k]);
        }
    }
}

#[test]
fn searches_equal_brute_force_on_random_sets_2d() {
    for (seed, n, h, weight) in [
        (1u64, 3000usize, 0.03, Weight::WendlandC2),
        (2, 1500, 0.05, Weight::CubicSpline),
        (3, 500, 0.2, Weight::Poly { p: 1, m: 3 }),
    ] {
        let x = random_cloud::<2>(n, seed);
        for (skin, search) in [0.0, 0.3 * h]
            .into_iter()
            .flat_map(|s| SEARCHES.map(|q| (s, q)))
        {
            let cfg = NeighborConfig::new(weight, h, skin).with_search(search);
            let nl = NeighborList::build(cfg, &x).unwrap();
            let want = reference(&cfg, &x);
            assert_same(&nl, &want, &format!("2D {search:?}"));
            assert_symmetric(&nl);
            let bf = NeighborList::brute_force(cfg, &x).unwrap();
            assert_same(&bf, &want, "2D brute_force");
        }
    }
}

#[test]
fn searches_equal_brute_force_on_random_sets_3d() {
    for (seed, n, h, weight) in [
        (4u64, 2000usize, 0.12, Weight::WendlandC4),
        (5, 800, 0.25, Weight::CubicSpline),
    ] {
        let x = random_cloud::<3>(n, seed);
        for (skin, search) in [0.0, 0.2 * h]
            .into_iter()
            .flat_map(|s| SEARCHES.map(|q| (s, q)))
        {
            let cfg = NeighborConfig::new(weight, h, skin).with_search(search);
            let nl = NeighborList::build(cfg, &x).unwrap();
            let want = reference(&cfg, &x);
            assert_same(&nl, &want, &format!("3D {search:?}"));
            assert_symmetric(&nl);
        }
    }
}

#[test]
fn the_list_equals_brute_force_on_lattice_families() {
    // lattices put many pairs at the same distance; jitter breaks ties
    for jit in [0.0, 0.3, 0.45] {
        let f = dirichlet_box::<2>(Spec::lattice(12, 2.5, Weight::WendlandC2).jittered(jit, 7));
        assert_same(&f.nl, &reference(f.nl.config(), &f.x), "2D box");
        let f = dirichlet_box::<3>(Spec::lattice(5, 1.7, Weight::CubicSpline).jittered(jit, 8));
        assert_same(&f.nl, &reference(f.nl.config(), &f.x), "3D box");
    }
}

#[test]
fn periodic_boxes_match_brute_force() {
    // 2D: unit period from the origin; and a box [−0.5, 0.5) × [2, 3.5) with unequal periods
    let x = random_cloud::<2>(1200, 11);
    let cfg = NeighborConfig::new(Weight::WendlandC2, 0.06, 0.01)
        .with_periodicity(Periodicity::all([0.0; 2], [1.0; 2]));
    let want = reference(&cfg, &x);
    for search in SEARCHES {
        let nl = NeighborList::build(cfg.with_search(search), &x).unwrap();
        assert_same(&nl, &want, &format!("2D periodic {search:?}"));
    }
    let nl = NeighborList::build(cfg, &x).unwrap();
    assert_symmetric(&nl);
    // some pairs really cross the faces
    let crossing = (0..nl.len())
        .flat_map(|i| nl.row(i).map(move |k| (i, k)))
        .filter(|&(i, k)| {
            let j = nl.indices()[k] as usize;
            (0..2).any(|a| (x[j][a] - x[i][a]).abs() > 0.5)
        })
        .count();
    assert!(
        crossing > 20,
        "only {crossing} pairs cross the periodic faces"
    );

    let lo = [-0.5, 2.0];
    let len = [1.0, 1.5];
    let y: Vec<[f64; 2]> = random_cloud::<2>(900, 12)
        .iter()
        .map(|p| [lo[0] + len[0] * p[0], lo[1] + len[1] * p[1]])
        .collect();
    let cfg = NeighborConfig::new(Weight::CubicSpline, 0.09, 0.0)
        .with_periodicity(Periodicity::all(lo, len));
    let nl = NeighborList::build(cfg, &y).unwrap();
    assert_same(&nl, &reference(&cfg, &y), "2D offset periodic");

    // only one axis periodic
    let cfg = NeighborConfig::new(Weight::CubicSpline, 0.09, 0.0).with_periodicity(Periodicity {
        lo: [0.0, 0.0],
        len: [1.0, 0.0],
    });
    let nl = NeighborList::build(cfg, &x).unwrap();
    assert_same(&nl, &reference(&cfg, &x), "2D half periodic");

    // 3D
    let z = random_cloud::<3>(1500, 13);
    let cfg = NeighborConfig::new(Weight::WendlandC4, 0.15, 0.02)
        .with_periodicity(Periodicity::all([0.0; 3], [1.0; 3]));
    let nl = NeighborList::build(cfg, &z).unwrap();
    assert_same(&nl, &reference(&cfg, &z), "3D periodic");
    assert_symmetric(&nl);
}

#[test]
fn periodic_positions_outside_the_box_give_the_same_pairs() {
    // shifting particles by whole periods changes nothing (minimum image)
    let x = random_cloud::<2>(600, 21);
    let cfg = NeighborConfig::new(Weight::WendlandC2, 0.08, 0.0)
        .with_periodicity(Periodicity::all([0.0; 2], [1.0; 2]));
    let shifted: Vec<[f64; 2]> = x
        .iter()
        .enumerate()
        .map(|(i, p)| {
            let s = (i % 5) as f64 - 2.0;
            [p[0] + s, p[1] - 2.0 * s]
        })
        .collect();
    let a = NeighborList::build(cfg, &x).unwrap();
    let b = NeighborList::build(cfg, &shifted).unwrap();
    assert_same(&b, &reference(&cfg, &shifted), "shifted by periods");
    assert_eq!(a.n_pairs(), b.n_pairs());
    for i in 0..a.len() {
        let (ra, rb) = (a.row(i), b.row(i));
        assert_eq!(a.indices()[ra.clone()], b.indices()[rb.clone()], "row {i}");
        for (ka, kb) in ra.zip(rb) {
            for c in 0..2 {
                // equal up to the round-off of coordinates of size ≤ 5
                assert!((a.dx()[ka][c] - b.dx()[kb][c]).abs() < 1e-14);
            }
        }
    }
}

#[test]
fn pairs_exactly_at_h_are_excluded_and_just_inside_included() {
    // dyadic coordinates make |x_j − x_i| = h exactly in floating point:
    // 2D: the 3-4-5 triangle, h = 5/16; 3D: the 2-3-6-7 quadruple, h = 7/8
    let h2d = 5.0 / 16.0;
    let x2: Vec<[f64; 2]> = vec![
        [0.0, 0.0],
        [3.0 / 16.0, 4.0 / 16.0],        // exactly h from 0
        [-h2d * (1.0 - 1e-9), 0.0],      // just inside from 0
        [0.0, -h2d],                     // exactly h from 0
        [3.0 / 16.0, 4.0 / 16.0 + h2d],  // exactly h from 1, 2h·… from 0
        [0.6 + h2d * (1.0 - 1e-9), 0.6], // just inside from 6
        [0.6, 0.6],
    ];
    for skin in [0.0, 0.1] {
        let cfg = NeighborConfig::new(Weight::WendlandC2, h2d, skin);
        for nl in [
            NeighborList::build(cfg, &x2).unwrap(),
            NeighborList::brute_force(cfg, &x2).unwrap(),
        ] {
            let row = |i: usize| -> Vec<u32> { nl.row(i).map(|k| nl.indices()[k]).collect() };
            assert_eq!(row(0), vec![2], "skin {skin}");
            assert_eq!(row(1), Vec::<u32>::new());
            assert_eq!(row(2), vec![0]);
            assert_eq!(row(3), Vec::<u32>::new());
            assert_eq!(row(5), vec![6]);
            assert_eq!(row(6), vec![5]);
            // the included pair at h(1 − 1e-9) has a tiny but positive weight
            let k = nl.row(0).next().unwrap();
            assert!(nl.w()[k] > 0.0);
        }
    }
    let h3d = 7.0 / 8.0;
    let x3: Vec<[f64; 3]> = vec![
        [0.0, 0.0, 0.0],
        [2.0 / 8.0, 3.0 / 8.0, 6.0 / 8.0],      // exactly h
        [-h3d * (1.0 - 1e-9) / 3f64.sqrt(); 3], // |.| = h (1 − 1e-9) up to round-off
    ];
    let cfg = NeighborConfig::new(Weight::CubicSpline, h3d, 0.0);
    let nl = NeighborList::build(cfg, &x3).unwrap();
    let row0: Vec<u32> = nl.row(0).map(|k| nl.indices()[k]).collect();
    assert_eq!(row0, vec![2]);
    assert_eq!(nl.row(1).len(), 0);

    // across a periodic face: 1/8 and 7/8 with period 1 are 1/4 apart
    let xp: Vec<[f64; 2]> = vec![[0.125, 0.5], [0.875, 0.5], [0.875, 0.4]];
    let cfg = NeighborConfig::new(Weight::WendlandC2, 0.25, 0.0)
        .with_periodicity(Periodicity::all([0.0; 2], [1.0; 2]));
    for nl in [
        NeighborList::build(cfg, &xp).unwrap(),
        NeighborList::brute_force(cfg, &xp).unwrap(),
    ] {
        assert_eq!(nl.row(0).len(), 0, "pair at exactly h across the face");
        assert_eq!(nl.row(1).len(), 1, "1 sees only 2");
        assert_eq!(nl.indices()[nl.row(1).start], 2);
    }
    let xq: Vec<[f64; 2]> = vec![[0.125, 0.5], [0.875 + 1e-9, 0.5]];
    let nl = NeighborList::build(cfg, &xq).unwrap();
    assert_eq!(nl.row(0).len(), 1, "pair just inside h across the face");
    assert!((nl.dx()[nl.row(0).start][0] + (0.25 - 1e-9)).abs() < 1e-15);
}

#[test]
fn skin_keeps_the_pattern_for_small_moves_and_rebuilds_for_large() {
    let h = 0.05;
    let skin = 0.02;
    let cfg = NeighborConfig::new(Weight::WendlandC2, h, skin)
        .with_periodicity(Periodicity::all([0.0; 2], [1.0; 2]));
    let mut x = random_cloud::<2>(1000, 31);
    x[0] = [0.9995, 0.5];
    let mut nl = NeighborList::new(cfg).unwrap();
    assert!(nl.update(&x).unwrap().rebuilt);
    let e1 = nl.epoch();
    let pattern0 = nl.pattern().1.to_vec();
    let x_ref = x.clone();

    // every particle moves less than skin/2 (random directions; some leave [0,1)² and are seen
    // through the periodic faces), one crosses a face: no rebuild, and the list is exact
    let dirs = random_cloud::<2>(1000, 32);
    for (xi, di) in x.iter_mut().zip(&dirs) {
        for a in 0..2 {
            xi[a] += 0.49 * skin * (2.0 * di[a] - 1.0) / 2f64.sqrt();
        }
    }
    x[0] = [0.0005, 0.5]; // 0.001 away from [0.9995, 0.5] through the face
    let up = nl.update(&x).unwrap();
    assert!(!up.rebuilt, "small moves rebuilt the candidates");
    assert_eq!(nl.epoch(), e1);
    assert_eq!(nl.pattern().1, &pattern0[..]);
    assert_same(&nl, &reference(&cfg, &x), "after small moves");

    // the reference is the last rebuild, not the last update: 0.3 skin twice rebuilds
    let mut z = x.clone();
    z[5] = [x_ref[5][0] + 0.3 * skin, x_ref[5][1]];
    assert!(!nl.update(&z).unwrap().rebuilt);
    z[5][0] += 0.3 * skin;
    let up = nl.update(&z).unwrap();
    assert!(up.rebuilt, "accumulated drift beyond skin/2 must rebuild");
    let e2 = nl.epoch();
    assert!(e2 > e1, "a rebuild changes the epoch");
    assert_same(&nl, &reference(&cfg, &z), "after rebuild");

    // one large move rebuilds
    let mut w = z.clone();
    w[7] = [0.5, 0.123];
    assert!(nl.update(&w).unwrap().rebuilt);
    assert!(nl.epoch() > e2, "a rebuild changes the epoch");
    // epochs are unique in the process: a second list never shares one
    let other = NeighborList::build(cfg, &w).unwrap();
    assert_ne!(other.epoch(), nl.epoch());
    assert_same(&nl, &reference(&cfg, &w), "after a large move");

    // a different particle count rebuilds
    let mut v = w.clone();
    v.push([0.3141, 0.2718]);
    assert!(nl.update(&v).unwrap().rebuilt);
    assert_same(&nl, &reference(&cfg, &v), "after adding a particle");
}

#[test]
fn skin_rule_holds_when_pairs_come_into_range() {
    // two particles at h + 0.9 skin move towards each other by 0.45 skin each: the candidate
    // list found them, so the new pair (distance h − 0… ) is seen without a rebuild
    let h = 0.1;
    let skin = 0.04;
    let cfg = NeighborConfig::new(Weight::CubicSpline, h, skin);
    let x = vec![[0.3, 0.3], [0.3 + h + 0.9 * skin, 0.3]];
    let mut nl = NeighborList::build(cfg, &x).unwrap();
    assert_eq!(nl.n_pairs(), 0);
    let y = vec![
        [0.3 + 0.49 * skin, 0.3],
        [0.3 + h + 0.9 * skin - 0.49 * skin, 0.3],
    ];
    assert!(!nl.update(&y).unwrap().rebuilt);
    assert_eq!(nl.n_pairs(), 2, "pair within h after the move");
    assert_same(&nl, &reference(&cfg, &y), "pair coming into range");
}

#[test]
fn a_measure_whose_rows_outgrow_their_room_lays_the_pairs_out_again() {
    // the pair arrays leave room for a sixteenth more pairs per region of 512 rows: a cloud
    // of 1500 particles squeezed by 7 % towards its centre (within the skin: no search) gains
    // about 16 % more pairs — past the room — then is let go again, then a third of it is
    // squeezed alone; every state the brute-force pairs, bit-symmetric, without a search
    let h = 0.05;
    let cfg = NeighborConfig::new(Weight::WendlandC2, h, 0.1);
    let x = random_cloud::<2>(1500, 33);
    let mut nl = NeighborList::build(cfg, &x).unwrap();
    let squeeze = |x: &[[f64; 2]], s: f64, which: &dyn Fn(usize) -> bool| -> Vec<[f64; 2]> {
        x.iter()
            .enumerate()
            .map(|(i, p)| {
                let s = if which(i) { s } else { 1.0 };
                [0.5 + s * (p[0] - 0.5), 0.5 + s * (p[1] - 0.5)]
            })
            .collect()
    };
    let before = nl.n_pairs();
    let mut sets = nl.pair_set();
    for (what, y) in [
        ("squeezed", squeeze(&x, 0.93, &|_| true)),
        ("let go", x.clone()),
        ("a third squeezed", squeeze(&x, 0.93, &|i| i % 3 == 0)),
        ("let go again", x.clone()),
    ] {
        assert!(!nl.update(&y).unwrap().rebuilt, "{what}: within the skin");
        assert_same(&nl, &reference(&cfg, &y), what);
        assert_symmetric(&nl);
        assert_ne!(nl.pair_set(), sets, "{what}: other pairs");
        sets = nl.pair_set();
        if what == "squeezed" {
            assert!(
                nl.n_pairs() as f64 > 1.12 * before as f64,
                "{what}: {} pairs against {before}: not past the room",
                nl.n_pairs()
            );
        }
    }
    assert_eq!(nl.n_pairs(), before);
}

#[test]
fn coincident_particles_are_rejected() {
    let mut x = random_cloud::<2>(200, 41);
    x[57] = x[123];
    let cfg = NeighborConfig::new(Weight::WendlandC2, 0.1, 0.0);
    for r in [
        NeighborList::build(cfg, &x),
        NeighborList::brute_force(cfg, &x),
    ] {
        match r {
            Err(InputError::Coincident { i, j, distance }) => {
                let mut p = [i, j];
                p.sort_unstable();
                assert_eq!(p, [57, 123]);
                assert_eq!(distance, 0.0);
            }
            other => panic!("expected Coincident, got {other:?}"),
        }
    }
    // 3D, and periodic images that coincide
    let mut z = random_cloud::<3>(100, 42);
    z[3] = z[99];
    assert!(matches!(
        NeighborList::build(NeighborConfig::new(Weight::CubicSpline, 0.2, 0.0), &z),
        Err(InputError::Coincident { .. })
    ));
    let y = vec![[0.25, 0.5], [1.25, 0.5], [0.5, 0.5]];
    let cfg = NeighborConfig::new(Weight::CubicSpline, 0.3, 0.0)
        .with_periodicity(Periodicity::all([0.0; 2], [1.0; 2]));
    match NeighborList::build(cfg, &y) {
        Err(InputError::Coincident { i, j, .. }) => {
            let mut p = [i, j];
            p.sort_unstable();
            assert_eq!(p, [0, 1]);
        }
        other => panic!("expected Coincident for periodic images, got {other:?}"),
    }
}

#[test]
fn non_finite_positions_name_the_particle() {
    let cfg = NeighborConfig::new(Weight::WendlandC2, 0.1, 0.0);
    for bad in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY] {
        let mut x = random_cloud::<2>(300, 51);
        x[211][1] = bad;
        for r in [
            NeighborList::build(cfg, &x),
            NeighborList::brute_force(cfg, &x),
        ] {
            assert_eq!(
                r.err(),
                Some(InputError::NonFinite {
                    field: "position",
                    particle: 211
                })
            );
        }
        // also on update of a list that was fine before
        let y = random_cloud::<2>(300, 51);
        let mut nl = NeighborList::build(cfg, &y).unwrap();
        assert!(matches!(
            nl.update(&x),
            Err(InputError::NonFinite { particle: 211, .. })
        ));
        let mut z = random_cloud::<3>(50, 52);
        z[0][2] = bad;
        assert!(matches!(
            NeighborList::build(NeighborConfig::new(Weight::CubicSpline, 0.3, 0.0), &z),
            Err(InputError::NonFinite { particle: 0, .. })
        ));
    }
}

#[test]
fn periods_too_short_and_bad_parameters_are_rejected() {
    let h = 0.2;
    let skin = 0.05;
    // period must be at least 2 (h + skin) = 0.5
    let ok = NeighborConfig::<2>::new(Weight::WendlandC2, h, skin).with_periodicity(Periodicity {
        lo: [0.0; 2],
        len: [0.5, 1.0],
    });
    assert!(ok.validate().is_ok());
    let bad = NeighborConfig::<2>::new(Weight::WendlandC2, h, skin).with_periodicity(Periodicity {
        lo: [0.0; 2],
        len: [1.0, 0.49],
    });
    match NeighborList::new(bad) {
        Err(InputError::PeriodTooShort {
            axis,
            period,
            needed,
        }) => {
            assert_eq!(axis, 1);
            assert_eq!(period, 0.49);
            assert!((needed - 0.5).abs() < 1e-15);
        }
        other => panic!("expected PeriodTooShort, got {other:?}"),
    }
    let x = random_cloud::<2>(10, 1);
    assert!(matches!(
        NeighborList::build(bad, &x),
        Err(InputError::PeriodTooShort { axis: 1, .. })
    ));
    assert!(matches!(
        NeighborList::brute_force(bad, &x),
        Err(InputError::PeriodTooShort { axis: 1, .. })
    ));
    let bad3 = NeighborConfig::<3>::new(Weight::CubicSpline, 0.3, 0.0)
        .with_periodicity(Periodicity::all([0.0; 3], [1.0, 1.0, 0.5]));
    assert!(matches!(
        NeighborList::new(bad3),
        Err(InputError::PeriodTooShort { axis: 2, .. })
    ));
    for l in [-1.0, f64::NAN] {
        let c =
            NeighborConfig::<2>::new(Weight::CubicSpline, 0.1, 0.0).with_periodicity(Periodicity {
                lo: [0.0; 2],
                len: [l, 0.0],
            });
        assert!(matches!(
            c.validate(),
            Err(InputError::PeriodTooShort { axis: 0, .. })
        ));
    }
    for (h, s) in [
        (0.0, 0.0),
        (-0.1, 0.0),
        (f64::NAN, 0.0),
        (f64::INFINITY, 0.0),
    ] {
        assert!(matches!(
            NeighborConfig::<2>::new(Weight::CubicSpline, h, s).validate(),
            Err(InputError::Parameter { name, .. }) if name == "h"
        ));
    }
    assert!(matches!(
        NeighborConfig::<2>::new(Weight::CubicSpline, 0.1, -0.01).validate(),
        Err(InputError::Parameter { name, .. }) if name == "skin"
    ));
    assert!(matches!(
        NeighborConfig::<2>::new(Weight::Poly { p: 1, m: 0 }, 0.1, 0.0).validate(),
        Err(InputError::Parameter { name, .. }) if name == "weight"
    ));
    // relative constructor: h = 3 Δx, skin = 0.1 h
    let c = NeighborConfig::<2>::new_relative(Weight::CubicSpline, 0.01, 3.0, 0.1);
    assert!((c.h - 0.03).abs() < 1e-15 && (c.skin - 0.003).abs() < 1e-15);
}

#[test]
fn empty_and_single_particle_sets() {
    let cfg = NeighborConfig::<2>::new(Weight::CubicSpline, 0.1, 0.0);
    let nl = NeighborList::build(cfg, &[]).unwrap();
    assert_eq!(nl.len(), 0);
    assert_eq!(nl.n_pairs(), 0);
    let nl = NeighborList::build(cfg, &[[0.5, 0.5]]).unwrap();
    assert_eq!(nl.len(), 1);
    assert_eq!(nl.row(0).len(), 0);
}

#[test]
fn neighbor_stats_match_brute_force() {
    use gpm::diagnostics::neighbor_stats;
    use gpm::particles::Role;
    let f = dirichlet_box::<2>(Spec::lattice(10, 2.3, Weight::CubicSpline).jittered(0.45, 71));
    let s = neighbor_stats(&f.nl, &f.role);
    let want = reference(f.nl.config(), &f.x);
    let fluid: Vec<usize> = (0..f.x.len())
        .filter(|&i| f.role[i] == Role::Fluid)
        .collect();
    let counts: Vec<usize> = fluid.iter().map(|&i| want[i].len()).collect();
    assert_eq!(s.min_neighbors, *counts.iter().min().unwrap());
    assert_eq!(s.max_neighbors, *counts.iter().max().unwrap());
    let mean = counts.iter().sum::<usize>() as f64 / counts.len() as f64;
    assert!((s.mean_neighbors - mean).abs() < 1e-12);
    // closest pair with a fluid end, by brute force over all pairs
    let mut best = (f64::INFINITY, 0, 0);
    for &i in &fluid {
        for (j, xj) in f.x.iter().enumerate() {
            if j != i {
                let r = ((xj[0] - f.x[i][0]).powi(2) + (xj[1] - f.x[i][1]).powi(2)).sqrt();
                if r < best.0 {
                    best = (r, i, j);
                }
            }
        }
    }
    assert!((s.min_distance - best.0).abs() <= 1e-15);
    let (a, b) = s.closest_pair.unwrap();
    let mut got = [a, b];
    got.sort_unstable();
    let mut exp = [best.1, best.2];
    exp.sort_unstable();
    assert_eq!(got, exp);
}

#[test]
fn a_far_outlier_does_not_blow_the_cell_grid_up() {
    // one particle 10⁶ radii away: the grid coarsens its cells instead of allocating 10¹² of them
    let mut x = random_cloud::<2>(800, 21);
    x.push([1.0e4, -3.0e4]);
    x.push([1.0e4 + 0.01, -3.0e4]);
    for search in SEARCHES {
        let cfg = NeighborConfig::new(Weight::WendlandC2, 0.05, 0.01).with_search(search);
        let nl = NeighborList::build(cfg, &x).unwrap();
        assert_same(&nl, &reference(&cfg, &x), &format!("outlier {search:?}"));
        // the far pair found each other
        assert_eq!(nl.row(800).len(), 1, "{search:?}");
    }
}

/// The list records the fingerprint of the positions it measured (what the projection's check
/// compares instead of every pair): equal for the same positions, different after a one-ulp move
/// of one coordinate, and current again after `update`.
#[test]
fn the_list_records_the_positions_it_measured() {
    use gpm::neighbors::positions_hash;
    let x = random_cloud::<2>(20_000, 7);
    let cfg = NeighborConfig::new(Weight::WendlandC2, 0.03, 0.01);
    let mut nl = NeighborList::build(cfg, &x).unwrap();
    assert_eq!(nl.measured_at(), positions_hash(&x));
    assert_ne!(nl.measured_at(), 0);
    let mut y = x.clone();
    y[12_345][1] = f64::from_bits(y[12_345][1].to_bits() + 1);
    assert_ne!(positions_hash(&y), positions_hash(&x));
    nl.update(&y).unwrap();
    assert_eq!(nl.measured_at(), positions_hash(&y));
}

#[test]
fn periodic_lattices_with_pairs_at_exactly_h_give_a_symmetric_list() {
    // h a whole number of spacings puts pairs at exactly h (up to rounding) across the periodic
    // faces: whichever way the rounding decides, both ends of a pair must agree, for every
    // search, with and without a skin (a search that pruned cells by a rounded chord once
    // dropped such a pair from one end: `scale_pair_weights` then found no reverse pair)
    fn check<const D: usize>(n: usize, h_over_dx: f64, skin: f64) {
        let dx = 1.0 / n as f64;
        let x = gpm::geometry::lattice([0.0; D], [1.0; D], dx);
        let cfg = NeighborConfig::new_relative(Weight::WendlandC2, dx, h_over_dx, skin)
            .with_periodicity(Periodicity::all([0.0; D], [1.0; D]));
        let want = reference(&cfg, &x);
        for search in SEARCHES {
            let nl = NeighborList::build(cfg.with_search(search), &x).unwrap();
            let what = format!("{D}D n={n} h={h_over_dx}Δx skin={skin} {search:?}");
            assert_same(&nl, &want, &what);
            assert_symmetric(&nl);
        }
    }
    for n in [10, 11, 13, 16] {
        for h in [2.0, 2.5, 3.0] {
            for skin in [0.0, 0.3] {
                check::<2>(n, h, skin);
            }
        }
    }
    check::<3>(7, 2.0, 0.0);
    check::<3>(9, 2.0, 0.3);
    check::<3>(9, 3.0, 0.3);
    check::<3>(10, 3.0, 0.0);
}

/// Moves every particle of a periodic cloud by less than `skin / 2` and wraps it back into the
/// box (some cross a face), re-measures without a search, and checks every pair's displacement
/// and `r²` bit for bit against the minimum image of `x_j − x_i` — a row skips `min_image` on
/// the axes whose faces its particle is far from, and must give the same bits.
fn moved_and_wrapped<const D: usize>(n: usize, h: f64, skin: f64, seed: u64) {
    let cfg = NeighborConfig::new(Weight::WendlandC2, h, skin)
        .with_periodicity(Periodicity::all([0.0; D], [1.0; D]));
    let mut x = random_cloud::<D>(n, seed);
    let mut nl = NeighborList::new(cfg).unwrap();
    assert!(nl.update(&x).unwrap().rebuilt);
    let dirs = random_cloud::<D>(n, seed + 1);
    let mut crossed = 0;
    for (xi, di) in x.iter_mut().zip(&dirs) {
        for a in 0..D {
            let moved = xi[a] + 0.49 * skin * (2.0 * di[a] - 1.0) / (D as f64).sqrt();
            let wrapped = moved.rem_euclid(1.0);
            crossed += (wrapped != moved) as usize;
            xi[a] = wrapped;
        }
    }
    assert!(crossed > 0, "no particle crossed a face");
    assert!(
        !nl.update(&x).unwrap().rebuilt,
        "the moves rebuilt the candidates"
    );
    assert_same(
        &nl,
        &reference(&cfg, &x),
        &format!("{D}D moved and wrapped"),
    );
    let per = cfg.periodic;
    let (mut deep, mut crossing) = (0, 0);
    for i in 0..nl.len() {
        if x[i].iter().all(|&c| c > 0.25 && c < 0.75) {
            deep += 1;
        }
        for k in nl.row(i) {
            let j = nl.indices()[k] as usize;
            let mut d: [f64; D] = std::array::from_fn(|a| x[j][a] - x[i][a]);
            crossing += d.iter().any(|v| v.abs() > 0.5) as usize;
            per.min_image(&mut d);
            for (a, (got, want)) in nl.dx()[k].iter().zip(&d).enumerate() {
                assert_eq!(
                    got.to_bits(),
                    want.to_bits(),
                    "{D}D: dx of pair ({i},{j}) axis {a}"
                );
            }
            assert_eq!(nl.r2(k).to_bits(), gpm::math::norm2(&d).to_bits());
        }
        // the row sums the measure takes beside the pairs: the number density and the
        // closest pair, as summed over the row afterwards
        let ws: f64 = nl.row(i).map(|k| nl.w()[k]).sum();
        assert_eq!(nl.w_sums()[i].to_bits(), ws.to_bits(), "{D}D: w sum of {i}");
        let rm = nl.row(i).map(|k| nl.r2(k)).fold(f64::INFINITY, f64::min);
        assert_eq!(
            nl.r2_mins()[i].to_bits(),
            rm.to_bits(),
            "{D}D: min r² of {i}"
        );
    }
    assert!(
        deep > 0 && crossing > 0,
        "{deep} deep rows, {crossing} crossing pairs"
    );
}

#[test]
fn moved_and_wrapped_particles_measure_the_minimum_image_bit_for_bit() {
    // (and the row sums taken with the pairs: `w_sums`, `r2_mins`)
    moved_and_wrapped::<2>(3000, 0.05, 0.015, 41);
    moved_and_wrapped::<3>(4000, 0.12, 0.03, 43);
}
