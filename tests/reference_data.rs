//! The embedded Ghia, Ghia & Shin (1982) centre-line tables (`data/`, see `data/SOURCES.md`):
//! they parse, have the published 17 points with the wall values the boundary conditions force,
//! positions on Ghia's 129-point grid, and no value that breaks the smoothness of its profile
//! (the check that would have caught PySPH's Re = 3200 entry `−0.86636`).

use gpm::reference::{ghia, parse_two_columns, rms_max, CentrelineTable, GHIA_RE};

fn tables() -> Vec<CentrelineTable> {
    GHIA_RE
        .iter()
        .map(|&re| ghia(re).expect("embedded table"))
        .collect()
}

#[test]
fn tables_exist_for_100_and_1000_only() {
    assert_eq!(GHIA_RE, [100, 1000]);
    for re in [0, 400, 3200, 5000, 10000] {
        assert!(ghia(re).is_none(), "Re = {re}");
    }
    for t in tables() {
        assert!(GHIA_RE.contains(&t.re));
        assert_eq!(t.u_vertical.len(), 17, "Re {} u", t.re);
        assert_eq!(t.v_horizontal.len(), 17, "Re {} v", t.re);
    }
}

#[test]
fn wall_values_are_the_boundary_conditions() {
    for t in tables() {
        // table order: from the lid (y = 1) down to the bottom wall (y = 0)
        let u = &t.u_vertical;
        assert_eq!(u[0], (1.0, 1.0), "lid: u = 1 at y = 1");
        assert_eq!(u[16], (0.0, 0.0), "bottom wall: u = 0 at y = 0");
        // from the right wall (x = 1) to the left wall (x = 0)
        let v = &t.v_horizontal;
        assert_eq!(v[0], (1.0, 0.0), "v = 0 at x = 1");
        assert_eq!(v[16], (0.0, 0.0), "v = 0 at x = 0");
        // speeds bounded by the lid speed
        for &(_, s) in u.iter().chain(v) {
            assert!(s.abs() <= 1.0);
        }
    }
}

#[test]
fn positions_are_monotone_and_on_ghias_grid() {
    let round_half_up_4 = |x: f64| (x * 1e4 + 0.5).floor() / 1e4;
    for t in tables() {
        for (name, col) in [("y", &t.u_vertical), ("x", &t.v_horizontal)] {
            for w in col.windows(2) {
                assert!(
                    w[1].0 < w[0].0,
                    "Re {} {name}: {} then {}",
                    t.re,
                    w[0].0,
                    w[1].0
                );
            }
            // every position is a grid node (j − 1)/128 rounded half-up to 4 decimals
            for &(p, _) in col.iter() {
                let j = (p * 128.0).round();
                assert!((0.0..=128.0).contains(&j));
                assert!(
                    (p - round_half_up_4(j / 128.0)).abs() < 1e-12,
                    "Re {} {name} = {p} is not a 4-decimal grid node j/128",
                    t.re
                );
            }
        }
    }
    // the tables of both Reynolds numbers use the same positions (Ghia's Tables I and II list
    // one position column for all Re)
    let (a, b) = (ghia(100).unwrap(), ghia(1000).unwrap());
    let pos = |c: &[(f64, f64)]| c.iter().map(|p| p.0).collect::<Vec<_>>();
    assert_eq!(pos(&a.u_vertical), pos(&b.u_vertical));
    assert_eq!(pos(&a.v_horizontal), pos(&b.v_horizontal));
    // the centre of the cavity is a tabulated point of both lines
    assert!(pos(&a.u_vertical).contains(&0.5) && pos(&a.v_horizontal).contains(&0.5));
}

#[test]
fn widely_quoted_centre_values() {
    // centre values quoted throughout the cavity literature (Ghia Table I/II, row y or x = 0.5)
    let at = |c: &[(f64, f64)], p: f64| c.iter().find(|q| q.0 == p).unwrap().1;
    let a = ghia(100).unwrap();
    let b = ghia(1000).unwrap();
    assert_eq!(at(&a.u_vertical, 0.5), -0.20581);
    assert_eq!(at(&a.v_horizontal, 0.5), 0.05454);
    assert_eq!(at(&b.u_vertical, 0.5), -0.06080);
    assert_eq!(at(&b.v_horizontal, 0.5), 0.02526);
    // the extremes: Re 1000 u minimum −0.38289 at y = 0.1719, v extremes 0.37095 / −0.51550
    assert_eq!(at(&b.u_vertical, 0.1719), -0.38289);
    assert_eq!(at(&b.v_horizontal, 0.1563), 0.37095);
    assert_eq!(at(&b.v_horizontal, 0.9063), -0.51550);
}

/// Largest deviation of a tabulated value from the cubic through four other points of the same
/// profile (the two nearest on each side where they exist, otherwise the four nearest on one
/// side and the other), in units of the lid speed, and where it occurs.
fn worst_deviation(col: &[(f64, f64)]) -> (f64, f64) {
    let mut pts = col.to_vec();
    pts.sort_by(|a, b| a.0.total_cmp(&b.0));
    let mut worst = (0.0, f64::NAN);
    for k in 1..pts.len() - 1 {
        let others: Vec<(f64, f64)> = pts
            .iter()
            .enumerate()
            .filter(|&(i, _)| i != k)
            .map(|(_, p)| *p)
            .collect();
        let lo = k.saturating_sub(2).min(others.len() - 4);
        let stencil = &others[lo..lo + 4];
        let x = pts[k].0;
        let mut p = 0.0;
        for (i, &(xi, yi)) in stencil.iter().enumerate() {
            let mut l = yi;
            for (j, &(xj, _)) in stencil.iter().enumerate() {
                if j != i {
                    l *= (x - xj) / (xi - xj);
                }
            }
            p += l;
        }
        let d = (pts[k].1 - p).abs();
        if d > worst.0 {
            worst = (d, x);
        }
    }
    worst
}

/// A quarter of the lid speed: a smooth profile sampled this densely departs from a local cubic
/// by far less (the steepest genuine stretch, Re 1000 near the lid, bends by about 0.16 across
/// the widest gap of the table), while a slip of a sign, a leading digit or a row shows up as a
/// deviation of the size of the values themselves (0.3 – 0.8).
const SMOOTHNESS_BOUND: f64 = 0.25;

#[test]
fn profiles_are_smooth() {
    for t in tables() {
        for (name, col) in [("u(y)", &t.u_vertical), ("v(x)", &t.v_horizontal)] {
            let (d, at) = worst_deviation(col);
            assert!(
                d < SMOOTHNESS_BOUND,
                "Re {} {name}: value at {at} departs {d:.3} from the cubic of its neighbours",
                t.re
            );
        }
    }
}

#[test]
fn smoothness_check_catches_transcription_slips() {
    // the PySPH slip (Re 3200, y = 0.4531: −0.86636 between −0.04272 and −0.24427) planted at
    // the same position in our tables, a sign slip at an extremum, a leading-digit swap, and a
    // value moved one row
    let b = ghia(1000).unwrap();
    let a = ghia(100).unwrap();
    let set = |col: &[(f64, f64)], p: f64, v: f64| -> Vec<(f64, f64)> {
        col.iter()
            .map(|&(q, w)| if q == p { (q, v) } else { (q, w) })
            .collect()
    };
    let slips: Vec<(&str, Vec<(f64, f64)>)> = vec![
        ("Re1000 u pysph", set(&b.u_vertical, 0.4531, -0.86636)),
        ("Re100 u pysph", set(&a.u_vertical, 0.4531, -0.86636)),
        ("Re1000 v sign", set(&b.v_horizontal, 0.1563, -0.37095)),
        ("Re1000 v digits", set(&b.v_horizontal, 0.9063, -0.15550)),
        ("Re100 v sign", set(&a.v_horizontal, 0.2344, -0.17527)),
        ("Re100 u row", set(&a.u_vertical, 0.9609, 0.84123)),
    ];
    for (what, col) in slips {
        let (d, _) = worst_deviation(&col);
        assert!(
            d > SMOOTHNESS_BOUND,
            "{what}: slip not detected (deviation {d:.3})"
        );
    }
}

#[test]
fn rms_and_max_exclude_the_walls() {
    let t = ghia(100).unwrap();
    let r = &t.u_vertical;
    let exact: Vec<f64> = r.iter().map(|p| p.1).collect();
    assert_eq!(rms_max(r, &exact), (0.0, 0.0));
    // +0.01 at interior points, +1 at the walls (ignored)
    let sim: Vec<f64> = r
        .iter()
        .map(|&(p, v)| {
            if p == 0.0 || p == 1.0 {
                v + 1.0
            } else {
                v + 0.01
            }
        })
        .collect();
    let (rms, max) = rms_max(r, &sim);
    assert!((rms - 0.01).abs() < 1e-12 && (max - 0.01).abs() < 1e-12);
    // one interior point off by 0.15: rms = 0.15/√15 over the 15 interior points
    let mut sim = exact.clone();
    sim[8] -= 0.15;
    let (rms, max) = rms_max(r, &sim);
    assert!((rms - 0.15 / 15f64.sqrt()).abs() < 1e-12);
    assert!((max - 0.15).abs() < 1e-12);
}

#[test]
fn parser_reports_bad_lines() {
    let ok = "# comment\nx,v\n\n1.0, 0.0\n0.5,-0.25\n";
    assert_eq!(
        parse_two_columns(ok).unwrap(),
        vec![(1.0, 0.0), (0.5, -0.25)]
    );
    let bad = "x,v\n1.0,0.0\n0.5,abc\n";
    let e = parse_two_columns(bad).unwrap_err();
    assert!(e.contains("line 3"), "{e}");
    let missing = "x,v\n1.0\n";
    let e = parse_two_columns(missing).unwrap_err();
    assert!(e.contains("line 2") && e.contains("missing"), "{e}");
}

/// The extrapolated reference sits at Ghia's printed positions, carries the same wall values, and
/// Ghia's interior values differ from it by the RMS amounts its source note states
/// (Re 100: 0.25 % u, 0.51 % v; Re 1000: 0.37 % u, 1.0 % v, to the printed two digits).
#[test]
fn extrapolated_reference_matches_its_source_note() {
    use gpm::reference::extrapolated;
    let stated = [(100, 0.0025, 0.0051), (1000, 0.0037, 0.010)];
    for (re, su, sv) in stated {
        let g = ghia(re).unwrap();
        let e = extrapolated(re).expect("embedded extrapolated table");
        for (a, b) in [
            (&g.u_vertical, &e.u_vertical),
            (&g.v_horizontal, &e.v_horizontal),
        ] {
            assert_eq!(a.len(), b.len());
            for (p, q) in a.iter().zip(b.iter()) {
                assert_eq!(p.0, q.0, "Re {re}: positions differ");
                if p.0 == 0.0 || p.0 == 1.0 {
                    assert_eq!(p.1, q.1, "Re {re}: wall value at {}", p.0);
                }
            }
        }
        let gu: Vec<f64> = g.u_vertical.iter().map(|p| p.1).collect();
        let gv: Vec<f64> = g.v_horizontal.iter().map(|p| p.1).collect();
        let (ru, _) = rms_max(&e.u_vertical, &gu);
        let (rv, _) = rms_max(&e.v_horizontal, &gv);
        // the note rounds to two significant digits
        assert!((ru - su).abs() < 0.06 * su, "Re {re}: u RMS {ru}");
        assert!((rv - sv).abs() < 0.06 * sv, "Re {re}: v RMS {rv}");
    }
    assert!(extrapolated(400).is_none());
}
