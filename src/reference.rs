//! Reference data shipped with the crate (embedded, so runs do not depend on files at run time).
//!
//! Ghia, Ghia & Shin (1982), *High-Re solutions for incompressible flow using the Navier–Stokes
//! equations and a multigrid method*, J. Comput. Phys. 48(3):387–411: Table I (u along the
//! vertical centre line x = 0.5) and Table II (v along the horizontal centre line y = 0.5) for
//! Re = 100 and 1000. See `data/SOURCES.md` for the transcription and its cross-checks.

/// A Ghia et al. centre-line table pair.
#[derive(Clone, Debug, PartialEq)]
pub struct GhiaTable {
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

/// Parses a two-column CSV with `#` comments and one header line.
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

/// The tables for `re` = 100 or 1000.
pub fn ghia(re: u32) -> Option<GhiaTable> {
    let (u, v) = match re {
        100 => (RE100_U, RE100_V),
        1000 => (RE1000_U, RE1000_V),
        _ => return None,
    };
    Some(GhiaTable {
        re,
        u_vertical: parse_two_columns(u).expect("embedded Ghia table parses"),
        v_horizontal: parse_two_columns(v).expect("embedded Ghia table parses"),
    })
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
