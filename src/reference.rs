//! Reference data shipped with the crate (embedded, so runs do not depend on files at run time).
//!
//! Ghia, Ghia & Shin (1982), *High-Re solutions for incompressible flow using the Navier–Stokes
//! equations and a multigrid method*, J. Comput. Phys. 48(3):387–411: Table I (u along the
//! vertical centre line x = 0.5) and Table II (v along the horizontal centre line y = 0.5) for
//! Re = 100 and 1000. See `data/SOURCES.md` for the transcription and its cross-checks.
//!
//! An extrapolated reference at the same points ([`extrapolated`]): the steady cavity by
//! second-order finite differences of the stream-function/vorticity equations on 128²…1024²
//! grids, Richardson-extrapolated, accurate to about 10⁻⁶ (validated against Botella & Peyret
//! 1998 at Re 1000). Ghia's interior values are 0.25–1 % RMS off it, so an error against Ghia
//! below about 0.5 % cannot rank a method: report both.

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

const RE100_U: &str = include_str!("../data/ghia1982_re100_u_vertical.csv");
const RE100_V: &str = include_str!("../data/ghia1982_re100_v_horizontal.csv");
const RE1000_U: &str = include_str!("../data/ghia1982_re1000_u_vertical.csv");
const RE1000_V: &str = include_str!("../data/ghia1982_re1000_v_horizontal.csv");
const EX100_U: &str = include_str!("../data/extrapolated_re100_u_vertical.csv");
const EX100_V: &str = include_str!("../data/extrapolated_re100_v_horizontal.csv");
const EX1000_U: &str = include_str!("../data/extrapolated_re1000_u_vertical.csv");
const EX1000_V: &str = include_str!("../data/extrapolated_re1000_v_horizontal.csv");

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

/// Ghia et al.'s tables for `re` = 100 or 1000.
pub fn ghia(re: u32) -> Option<CentrelineTable> {
    let (u, v) = match re {
        100 => (RE100_U, RE100_V),
        1000 => (RE1000_U, RE1000_V),
        _ => return None,
    };
    Some(table(re, u, v))
}

/// The extrapolated reference for `re` = 100 or 1000, at Ghia's printed positions.
pub fn extrapolated(re: u32) -> Option<CentrelineTable> {
    let (u, v) = match re {
        100 => (EX100_U, EX100_V),
        1000 => (EX1000_U, EX1000_V),
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

/// Reynolds numbers with embedded tables.
pub const GHIA_RE: [u32; 2] = [100, 1000];

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

/// Mean of `|y_sim(T) − y_exp| / y_exp` over the measured points with `lo ≤ T ≤ hi` that the
/// simulated curve covers, and how many there were (`None` without any).
pub fn mean_relative_deviation(
    sim: &[(f64, f64)],
    measured: &[(f64, f64)],
    lo: f64,
    hi: f64,
) -> Option<(f64, usize)> {
    let d: Vec<f64> = measured
        .iter()
        .filter(|&&(t, _)| t >= lo && t <= hi)
        .filter_map(|&(t, y)| interpolate(sim, t).map(|s| ((s - y) / y).abs()))
        .collect();
    (!d.is_empty()).then(|| (d.iter().sum::<f64>() / d.len() as f64, d.len()))
}
