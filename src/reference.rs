//! Reference data shipped with the crate (embedded, so runs do not depend on files at run time).
//!
//! Ghia, Ghia & Shin (1982), *High-Re solutions for incompressible flow using the Navier–Stokes
//! equations and a multigrid method*, J. Comput. Phys. 48(3):387–411: Table I (u along the
//! vertical centre line x = 0.5) and Table II (v along the horizontal centre line y = 0.5) for
//! all seven Reynolds numbers of the paper, Re = 100, 400, 1000, 3200, 5000, 7500 and 10 000
//! ([`GHIA_RE`]). See `data/SOURCES.md` for the transcription, its cross-checks and the
//! paper's misprints: Re 10 000's `u(0.5)` carries the corrected sign, and the two printed
//! values that cannot be restored (Re 400 `v(0.9063)`, Re 3200 `u(0.4531)`) are left out of
//! their tables ([`GHIA_OMITTED`]), which then have 16 rows instead of 17.
//!
//! An extrapolated reference at the same points ([`extrapolated`], [`EXTRAPOLATED_RE`]): the
//! steady cavity by second-order finite differences of the stream-function/vorticity equations,
//! Richardson-extrapolated — Re 100 and 1000 from 256²…1024² grids, accurate to about 10⁻⁶
//! (validated against Botella & Peyret 1998 at Re 1000); Re 400, 3200 and 5000 from 128²…512²
//! grids by `tools/fd_cavity.py` (the same method), accurate to 10⁻⁵, 3.4·10⁻⁴ and 7.8·10⁻⁴
//! (the files' `uncertainty` column). Ghia's interior values are 0.14–1 % RMS off them up to
//! Re 1000 and 1.1–2.1 % at Re 3200 and 5000, so an error against Ghia of that size cannot
//! rank a method: report both. These tables have every one of Ghia's 17 positions, also the
//! two whose printed values are left out of Ghia's tables.
//!
//! The lid-driven cube at Re 1000 ([`albensoeder_cube`]): Albensoeder & Kuhlmann (2005)'s
//! centre-line tables, spectrally accurate.

/// A pair of cavity centre-line tables (Ghia et al.'s, or the extrapolated reference at the same
/// points).
#[derive(Clone, Debug, PartialEq)]
pub struct CentrelineTable {
    /// Reynolds number.
    pub re: u32,
    /// `(y, u)` along `x = 0.5`, walls included, in the table's order.
    pub u_vertical: Vec<(f64, f64)>,
    /// `(x, v)` along `y = 0.5`, walls included, in the table's order.
    pub v_horizontal: Vec<(f64, f64)>,
}

/// Ghia et al.'s tables: `(Re, Table I column, Table II column)`.
const GHIA_TABLES: [(u32, &str, &str); 7] = [
    (
        100,
        include_str!("../data/ghia1982_re100_u_vertical.csv"),
        include_str!("../data/ghia1982_re100_v_horizontal.csv"),
    ),
    (
        400,
        include_str!("../data/ghia1982_re400_u_vertical.csv"),
        include_str!("../data/ghia1982_re400_v_horizontal.csv"),
    ),
    (
        1000,
        include_str!("../data/ghia1982_re1000_u_vertical.csv"),
        include_str!("../data/ghia1982_re1000_v_horizontal.csv"),
    ),
    (
        3200,
        include_str!("../data/ghia1982_re3200_u_vertical.csv"),
        include_str!("../data/ghia1982_re3200_v_horizontal.csv"),
    ),
    (
        5000,
        include_str!("../data/ghia1982_re5000_u_vertical.csv"),
        include_str!("../data/ghia1982_re5000_v_horizontal.csv"),
    ),
    (
        7500,
        include_str!("../data/ghia1982_re7500_u_vertical.csv"),
        include_str!("../data/ghia1982_re7500_v_horizontal.csv"),
    ),
    (
        10000,
        include_str!("../data/ghia1982_re10000_u_vertical.csv"),
        include_str!("../data/ghia1982_re10000_v_horizontal.csv"),
    ),
];
const EX100_U: &str = include_str!("../data/extrapolated_re100_u_vertical.csv");
const EX100_V: &str = include_str!("../data/extrapolated_re100_v_horizontal.csv");
const EX1000_U: &str = include_str!("../data/extrapolated_re1000_u_vertical.csv");
const EX1000_V: &str = include_str!("../data/extrapolated_re1000_v_horizontal.csv");
const EX400_U: &str = include_str!("../data/extrapolated_re400_u_vertical.csv");
const EX400_V: &str = include_str!("../data/extrapolated_re400_v_horizontal.csv");
const EX3200_U: &str = include_str!("../data/extrapolated_re3200_u_vertical.csv");
const EX3200_V: &str = include_str!("../data/extrapolated_re3200_v_horizontal.csv");
const EX5000_U: &str = include_str!("../data/extrapolated_re5000_u_vertical.csv");
const EX5000_V: &str = include_str!("../data/extrapolated_re5000_v_horizontal.csv");

/// The Reynolds numbers with an extrapolated reference ([`extrapolated`]).
pub const EXTRAPOLATED_RE: [u32; 5] = [100, 400, 1000, 3200, 5000];

/// Parses the first two columns of a CSV with `#` comments and one header line (further columns,
/// such as the extrapolated reference's `uncertainty`, are ignored).
pub fn parse_two_columns(text: &str) -> Result<Vec<(f64, f64)>, String> {
    let mut rows = Vec::new();
    let mut header = false;
    for (ln, line) in text.lines().enumerate() {
        let l = line.trim();
        if l.is_empty() || l.starts_with('#') {
            continue;
        }
        if !header {
            header = true;
            continue;
        }
        let mut it = l.split(',');
        let parse = |s: Option<&str>| -> Result<f64, String> {
            s.ok_or_else(|| format!("line {}: missing column", ln + 1))?
                .trim()
                .parse::<f64>()
                .map_err(|e| format!("line {}: {e}", ln + 1))
        };
        rows.push((parse(it.next())?, parse(it.next())?));
    }
    Ok(rows)
}

/// Ghia et al.'s tables for `re` (one of [`GHIA_RE`]).
pub fn ghia(re: u32) -> Option<CentrelineTable> {
    let &(_, u, v) = GHIA_TABLES.iter().find(|t| t.0 == re)?;
    Some(table(re, u, v))
}

/// The extrapolated reference for `re` (one of [`EXTRAPOLATED_RE`]), at Ghia's printed
/// positions (all 17 of each table).
pub fn extrapolated(re: u32) -> Option<CentrelineTable> {
    let (u, v) = match re {
        100 => (EX100_U, EX100_V),
        400 => (EX400_U, EX400_V),
        1000 => (EX1000_U, EX1000_V),
        3200 => (EX3200_U, EX3200_V),
        5000 => (EX5000_U, EX5000_V),
        _ => return None,
    };
    Some(table(re, u, v))
}

fn table(re: u32, u: &str, v: &str) -> CentrelineTable {
    // the embedded files are checked by tests/reference_data.rs
    CentrelineTable {
        re,
        u_vertical: parse_two_columns(u).expect("embedded reference table parses"),
        v_horizontal: parse_two_columns(v).expect("embedded reference table parses"),
    }
}

const AK1000_U: &str = include_str!("../data/albensoeder2005_cube_re1000_u_vertical.csv");
const AK1000_V: &str = include_str!("../data/albensoeder2005_cube_re1000_v_horizontal.csv");

/// The lid-driven **cube** (3D, rigid end walls) at `re` = 1000: Albensoeder & Kuhlmann (2005),
/// *Accurate three-dimensional lid-driven cavity flow*, J. Comput. Phys. 206, 536–558, Tables 5
/// and 6 (Chebyshev collocation), mapped to gpm's frame (unit cube, lid `y = 1` moving in `+x`,
/// `z` spanwise): `u_vertical` is `u(0.5, y, 0.5)`, `v_horizontal` is `v(x, 0.5, 0.5)`, at
/// Ghia et al.'s positions. See `data/SOURCES.md`.
pub fn albensoeder_cube(re: u32) -> Option<CentrelineTable> {
    (re == 1000).then(|| table(re, AK1000_U, AK1000_V))
}

/// The key of the embedded tables for a run at Reynolds number `re`: `re` itself when it is a
/// whole number, `None` otherwise (a table at a nearby Reynolds number is no reference for it).
pub fn table_key(re: f64) -> Option<u32> {
    let r = re.round();
    let whole =
        re.is_finite() && r >= 1.0 && r <= f64::from(u32::MAX) && (re - r).abs() <= 1e-9 * r;
    whole.then_some(r as u32)
}

/// Reynolds numbers with embedded tables of Ghia et al.
pub const GHIA_RE: [u32; 7] = [100, 400, 1000, 3200, 5000, 7500, 10000];

/// Rows of Ghia et al.'s tables left out because the printed value is a misprint whose digits
/// cannot be restored with confidence (`data/SOURCES.md`): `(Re, 'u' or 'v', position,
/// printed value)`.
pub const GHIA_OMITTED: [(u32, char, f64, f64); 2] =
    [(400, 'v', 0.9063, -0.23827), (3200, 'u', 0.4531, -0.86636)];

/// RMS and maximum of `sim − ref` over the interior points (walls at 0 and 1 excluded).
pub fn rms_max(reference: &[(f64, f64)], simulated: &[f64]) -> (f64, f64) {
    let mut s2 = 0.0;
    let mut m = 0.0f64;
    let mut k = 0;
    for ((pos, r), s) in reference.iter().zip(simulated) {
        if *pos <= 0.0 || *pos >= 1.0 {
            continue;
        }
        let e = s - r;
        s2 += e * e;
        m = m.max(e.abs());
        k += 1;
    }
    ((s2 / k.max(1) as f64).sqrt(), m)
}

const MM_FRONT: &str = include_str!("../data/martin_moyce1952_surge_front.csv");
const MM_HEIGHT: &str = include_str!("../data/martin_moyce1952_column_height.csv");

/// Martin & Moyce (1952)'s collapse of a water column of width `a` and height `2a`
/// (`n² = 2`; Phil. Trans. R. Soc. A 244, 312–324, Tables 2 and 6; see `data/SOURCES.md`):
/// the surge front `Z = z/a` against `T = t√(2g/a)`, and the residual column height
/// `H = η/(2a)` against `τ = t√(g/a)`.
#[derive(Clone, Debug, PartialEq)]
pub struct DamBreakTable {
    /// `(T, Z)`.
    pub front: Vec<(f64, f64)>,
    /// `(τ, H)`.
    pub height: Vec<(f64, f64)>,
}

/// Martin & Moyce's dam-break measurements.
pub fn martin_moyce() -> DamBreakTable {
    DamBreakTable {
        front: parse_two_columns(MM_FRONT).expect("embedded Martin & Moyce front table"),
        height: parse_two_columns(MM_HEIGHT).expect("embedded Martin & Moyce height table"),
    }
}

/// Linear interpolation of the sampled curve `(t, y)` (ascending `t`) at `t`; `None` outside it.
pub fn interpolate(curve: &[(f64, f64)], t: f64) -> Option<f64> {
    let k = curve.iter().position(|&(s, _)| s >= t)?;
    if k == 0 {
        return (curve[0].0 == t).then_some(curve[0].1);
    }
    let (t0, y0) = curve[k - 1];
    let (t1, y1) = curve[k];
    Some(y0 + (y1 - y0) * (t - t0) / (t1 - t0))
}

/// The delay `ΔT ∈ [0, max_lag]` (steps of 0.001) of the simulated curve that brings it nearest
/// to the measured points over `lo ≤ T ≤ hi`: the one that minimises the mean relative
/// deviation of `y_sim(T − ΔT)` from `y_exp(T)` (over the points whose `T − ΔT` the simulated
/// curve covers), with that deviation; `None` when no delay covers a point. A diagnostic of a
/// start-up delay (an experiment's release that is not instantaneous), not an error measure:
/// it is fitted to the measurements.
pub fn best_delay(
    sim: &[(f64, f64)],
    measured: &[(f64, f64)],
    lo: f64,
    hi: f64,
    max_lag: f64,
) -> Option<(f64, f64)> {
    let steps = (max_lag / 1e-3).round() as usize;
    (0..=steps)
        .map(|k| k as f64 * 1e-3)
        .filter_map(|lag| delayed_deviation(sim, measured, lo, hi, lag).map(|(d, _)| (lag, d)))
        .fold(None, |best: Option<(f64, f64)>, (lag, d)| match best {
            Some((_, b)) if b <= d => best,
            _ => Some((lag, d)),
        })
}

/// Mean of `|y_sim(T) − y_exp| / y_exp` over the measured points with `lo ≤ T ≤ hi` that the
/// simulated curve covers, and how many there were (`None` without any).
pub fn mean_relative_deviation(
    sim: &[(f64, f64)],
    measured: &[(f64, f64)],
    lo: f64,
    hi: f64,
) -> Option<(f64, usize)> {
    delayed_deviation(sim, measured, lo, hi, 0.0)
}

/// [`mean_relative_deviation`] of the simulated curve delayed by `lag`: `y_sim(T − lag)`.
fn delayed_deviation(
    sim: &[(f64, f64)],
    measured: &[(f64, f64)],
    lo: f64,
    hi: f64,
    lag: f64,
) -> Option<(f64, usize)> {
    let (mut sum, mut count) = (0.0, 0);
    for &(t, y) in measured.iter().filter(|&&(t, _)| t >= lo && t <= hi) {
        if let Some(s) = interpolate(sim, t - lag) {
            sum += ((s - y) / y).abs();
            count += 1;
        }
    }
    (count > 0).then(|| (sum / count as f64, count))
}
