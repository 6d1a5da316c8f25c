//! Moment-consistent pair weights: a symmetric positive correction of the GPM pair weight that
//! makes the operators consistent on disordered particles (issue 13).
//!
//! Every GPM operator multiplies pair `(i, j)` by `F_ij = w_h(r_ij)/r_ij²`. On a disordered set
//! the first moment `Σ_j ω_j F_ij x_ji` does not vanish, so `∇̂h·` is not zero on uniform fields
//! and an incremental pressure can exert a mean force (the stall of issue 13). This module
//! replaces `F` by
//!
//! `F̃_ij = F_ij exp(s_ij)`,  `s_ij = (λ_i − λ_j)·x̂_ji + (Λ_i + Λ_j) : x̂_ji x̂_jiᵀ`,
//!
//! `x̂_ji = (x_j − x_i)/h`, with multipliers `λ_i ∈ R^d` and symmetric `Λ_i ∈ R^{d×d}` per fluid
//! row chosen so that
//!
//! `Σ_j ω_j F̃_ij x_ji = 0` (first moment) and `d Σ_j ω_j F̃_ij x_ji x_jiᵀ = I` (second moment).
//!
//! `s` is antisymmetric in its `λ` part under `i ↔ j` together with `x_ji → x_ij`, so `F̃` is
//! symmetric and positive: `∇̂h·` and `∇h` stay adjoint (Lemma 4.3), the Poisson matrix stays
//! SPD under h-connectivity, and `c0` is computed from `w̃ = F̃ r²`. With both moments met,
//! `∇̂h·` equals the difference form (zero on uniform fields), `∇h` is exact on linear fields
//! and `Δh` exact on quadratics.
//!
//! **Dual problem.** With `z_i = (λ_i, Λ_i)` and the features `φ(x̂) = (x̂, x̂x̂ᵀ)` the moment
//! conditions are the stationarity conditions of the convex function
//!
//! `Φ(z) = ½ Σ_i Σ_j ω_i ω_j F_ij exp(s_ij) − Σ_i ω_i z_i·t + ½ Σ_i ω_i Σ_q ε_q z_iq²`
//!
//! (`t = (0, I/d)`; pairs with a Dirichlet particle count once, with its multipliers zero), the
//! dual of a maximum-entropy (Kullback–Leibler) problem. `∇_{z_i} Φ = ω_i (M_i − t + ε∘z_i)`
//! with the moments `M_i = Σ_j ω_j F̃_ij φ(x̂_ji)` (in units of `h`). It is minimised by Newton's
//! method with Armijo backtracking; each Newton system `H δ = −∇Φ` (SPD, `d + d(d+1)/2`
//! unknowns per row) is solved by preconditioned conjugate gradients to the relative residual
//! `η = clamp(0.1 r, cg_rel_tol, 10⁻²)` (`r` the current moment residual: inexact Newton).
//!
//! **Regularisation.** `ε_q` (the Tikhonov term, [`MomentParams::reg_first`] and
//! [`MomentParams::reg_second`]) relaxes the conditions to `M_i − t = −ε∘z_i`: a row whose
//! neighbourhood cannot meet the second moment with bounded factors keeps bounded multipliers
//! (`|Λ| ≲ |M − t|/ε`) instead of driving factors to 10⁸. The first moment (the one that
//! removes the stall) is unregularised by default (`reg_first = 0`), so it is met to the
//! tolerance.
//!
//! **Walls.** A ghost's multipliers are the mirror images of its source's (`λ_g = L λ_s`,
//! `Λ_g = L Λ_s L`, `L` the reflection's linear part): then the pair `(i, g)` has the factor of
//! the mirrored pair `(s, g')` (`g'` the image of `i`), so the folded Poisson matrix stays
//! symmetric.
//!
//! **Preconditioners** ([`MomentPreconditioner`]): the `λ` block of `H` is a graph Laplacian
//! (coupling `λ_i − λ_j`), whose condition number grows like `(L/h)²`; block Jacobi then needs
//! hundreds to thousands of iterations. [`MomentPreconditioner::Amg`] applies one
//! smoothed-aggregation V-cycle ([`crate::poisson::amg`]) of the scalar Laplacian
//! `A_ij = −Σ ω_i ω_j F̃_ij |x̂_ji|²/d` to each `λ` component and the inverse of the `Λ–Λ`
//! diagonal block to the rest (the hierarchy is built at the first Newton step of a call and
//! refreshed, same aggregates, at the later ones). This module sits in layer 3, beside
//! [`crate::poisson`], for that reason.
//!
//! **Warm start.** [`MomentWeights`] keeps the multipliers of the last call and starts from
//! them when the fluid particles are the same (moving particles change them slowly).

use crate::boundary::{first_ghost, Boundary, VectorKind};
use crate::diagnostics::alias;
use crate::error::{Error, InputError, PairWeightError};
use crate::neighbors::NeighborList;
use crate::particles::{Particles, Role};
use crate::poisson::amg::{Amg, AmgParams, CsrRef};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::time::Instant;

/// Most unknowns per row (`d + d(d+1)/2` for `d = 3`).
const M: usize = 9;

/// Which pair weight the operators use.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum PairWeights {
    /// The GPM weight `F_ij = w_h(r_ij)/r_ij²`.
    #[default]
    Plain,
    /// The moment-consistent weight `F̃_ij = F_ij exp(s_ij)` of this module.
    Moment,
}

impl std::str::FromStr for PairWeights {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s.trim().to_ascii_lowercase().as_str() {
            "plain" => Ok(PairWeights::Plain),
            "moment" => Ok(PairWeights::Moment),
            _ => Err(format!(
                "unknown pair weights '{s}': expected plain or moment"
            )),
        }
    }
}

/// The preconditioner of the Newton systems.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum MomentPreconditioner {
    /// Inverse of each row's diagonal block.
    BlockJacobi,
    /// AMG V-cycle of the scalar Laplacian per `λ` component, block inverse for `Λ`.
    #[default]
    Amg,
}

/// Parameters of the Newton iteration.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MomentParams {
    /// Stop when every row's residual `max_q |M_iq − t_q + ε_q z_iq|` is below this (default
    /// 10⁻¹⁰).
    pub tol: f64,
    /// Tikhonov weight `ε` on `λ` (default 0: first moment exact).
    pub reg_first: f64,
    /// Tikhonov weight `ε` on `Λ` (default 10⁻³; see the module docs and
    /// `docs/research/consistent_pair_weights.md`).
    pub reg_second: f64,
    /// Most Newton steps (default 60).
    pub max_newton: usize,
    /// Most conjugate-gradient iterations per Newton step (default 2000).
    pub max_cg: usize,
    /// Tightest relative residual of the Newton systems (default 10⁻⁴; the loosest is 10⁻²).
    pub cg_rel_tol: f64,
    /// Preconditioner (default AMG).
    pub preconditioner: MomentPreconditioner,
    /// Start from the last call's multipliers when the fluid particles are the same (default
    /// true).
    pub warm_start: bool,
    /// Residual accepted when the Newton step limit is reached or the line search stalls
    /// (default 0: only `tol` is accepted). Moving particles track the multipliers from step to
    /// step with a few Newton steps and accept a small moment residual: the factors stay
    /// symmetric and positive whatever the residual, so the adjointness of Lemma 4.3 and the
    /// SPD Poisson matrix hold exactly and only the consistency is approximate.
    pub accept: f64,
}

impl Default for MomentParams {
    fn default() -> Self {
        MomentParams {
            tol: 1e-10,
            reg_first: 0.0,
            reg_second: 1e-3,
            max_newton: 60,
            max_cg: 2000,
            cg_rel_tol: 1e-4,
            preconditioner: MomentPreconditioner::Amg,
            warm_start: true,
            accept: 0.0,
        }
    }
}

impl MomentParams {
    /// Checks every field (positive tolerances, non-negative regularisation, at least one
    /// Newton and one CG step).
    pub fn validate(&self) -> Result<(), InputError> {
        for (name, v, ok) in [
            ("tol", self.tol, self.tol > 0.0),
            ("reg_first", self.reg_first, self.reg_first >= 0.0),
            ("reg_second", self.reg_second, self.reg_second >= 0.0),
            ("cg_rel_tol", self.cg_rel_tol, self.cg_rel_tol > 0.0),
            ("max_newton", self.max_newton as f64, self.max_newton > 0),
            ("max_cg", self.max_cg as f64, self.max_cg > 0),
            ("accept", self.accept, self.accept >= 0.0),
        ] {
            if !(ok && v.is_finite()) {
                return Err(InputError::parameter(
                    name,
                    v,
                    "must be finite and positive (non-negative for the regularisation)",
                ));
            }
        }
        Ok(())
    }
}

/// What a computation of the factors did.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct MomentReport {
    /// Newton steps.
    pub newton: usize,
    /// Conjugate-gradient iterations, all Newton steps together.
    pub cg_iters: usize,
    /// Largest first-moment residual `max_i |Σ_j ω_j F̃_ij x̂_ji|_∞` over fluid rows.
    pub first_moment: f64,
    /// Largest second-moment residual `max_i |Σ_j ω_j F̃_ij x̂_ji x̂_jiᵀ − I/d|_∞`.
    pub second_moment: f64,
    /// The fluid particle with the largest second-moment residual.
    pub worst_particle: usize,
    /// Rows whose second-moment residual exceeds 10⁻⁶ (relaxed by the regularisation).
    pub regularised_rows: usize,
    /// Smallest factor `exp(s_ij)` over all stored pairs.
    pub factor_min: f64,
    /// Largest factor.
    pub factor_max: f64,
    /// The iteration started from the previous multipliers.
    pub warm: bool,
    /// Wall seconds.
    pub seconds: f64,
}

/// The multipliers and the solver state kept between calls (for warm starts).
#[derive(Clone, Debug, Default)]
pub struct MomentWeights<const D: usize> {
    /// Parameters.
    pub params: MomentParams,
    z: Vec<[f64; M]>,
    fluid_len: usize,
    last: Option<MomentReport>,
}

/// Per-row unknowns `d + d(d+1)/2`.
const fn unknowns(d: usize) -> usize {
    d + d * (d + 1) / 2
}

/// `φ(x̂) = (x̂_a; x̂_a x̂_b (a ≤ b), off-diagonal doubled)`: `z·φ = λ·x̂ + Λ:x̂x̂ᵀ`.
#[inline(always)]
fn feat<const D: usize>(d: &[f64; D]) -> [f64; M] {
    let mut f = [0.0; M];
    let mut q = D;
    for a in 0..D {
        f[a] = d[a];
        for b in a..D {
            f[q] = d[a] * d[b] * if a == b { 1.0 } else { 2.0 };
            q += 1;
        }
    }
    // keep the second-moment entries in the order (a ≤ b) row-major
    f
}

/// The mirror `L` (diagonal signs `sg`) acting on a coefficient vector `(λ, Λ)`.
#[inline(always)]
fn mirror<const D: usize>(f: &[f64; M], sg: &[f64; D]) -> [f64; M] {
    let mut g = *f;
    let mut q = D;
    for a in 0..D {
        g[a] *= sg[a];
        for b in a..D {
            g[q] *= sg[a] * sg[b];
            q += 1;
        }
    }
    g
}

#[inline(always)]
fn dot(a: &[f64; M], b: &[f64; M], m: usize) -> f64 {
    let mut s = 0.0;
    for q in 0..m {
        s += a[q] * b[q];
    }
    s
}

/// The pair data of the fluid rows, in compact row order.
struct Rows {
    /// Particle of each row.
    particle: Vec<usize>,
    /// `ω_i` of each row.
    vol: Vec<f64>,
    offsets: Vec<usize>,
    /// `φ(x̂_ji)` seen from row `i`.
    phi: Vec<[f64; M]>,
    /// The neighbour's feature in its source's frame: `L_j φ(x̂_ij)`.
    psi: Vec<[f64; M]>,
    /// Row of the neighbour's source (`u32::MAX` for a Dirichlet neighbour).
    other: Vec<u32>,
    /// `ω_i ω_j F_ij h²`.
    base: Vec<f64>,
    /// ½ for a pair counted from both ends, 1 for a Dirichlet neighbour.
    half: Vec<f64>,
    /// Row of each pair.
    row_of: Vec<u32>,
}

/// Linear part (diagonal signs) of each particle's mirror: 1 for non-ghosts.
fn mirror_signs<const D: usize>(role: &[Role], boundary: &dyn Boundary<D>) -> Vec<[f64; D]> {
    let mut sg = vec![[1.0; D]; role.len()];
    boundary.fill_vector(role, &mut sg, VectorKind::Mirror);
    sg
}

impl<const D: usize> MomentWeights<D> {
    /// A solver with `params` and no multipliers yet.
    pub fn new(params: MomentParams) -> Self {
        MomentWeights {
            params,
            ..Default::default()
        }
    }

    /// The report of the last successful computation.
    pub fn last_report(&self) -> Option<&MomentReport> {
        self.last.as_ref()
    }

    /// The multipliers `(λ_i, Λ_i)` of particle `i` from the last call (`λ` first, then
    /// `Λ_ab`, `a ≤ b`, row-major); zeros for rows not computed.
    pub fn multipliers(&self, i: usize) -> [f64; M] {
        self.z.get(i).copied().unwrap_or([0.0; M])
    }

    /// Forgets the multipliers (the next call starts cold).
    pub fn reset(&mut self) {
        self.z.clear();
        self.fluid_len = 0;
    }

    /// With `kind = Moment`: computes the factors for the current list (plain weights, as
    /// after [`NeighborList::update`]), volumes and ghosts of `particles`, and multiplies the
    /// list's pair weights by them ([`NeighborList::scale_pair_weights`]). `Plain` does nothing
    /// and returns `None`. Call it after the volumes are set and the ghosts placed.
    pub fn apply(
        &mut self,
        kind: PairWeights,
        nl: &mut NeighborList<D>,
        particles: &Particles<D>,
        boundary: &dyn Boundary<D>,
    ) -> Result<Option<MomentReport>, Error> {
        if kind == PairWeights::Plain {
            return Ok(None);
        }
        let (factors, report) = self.factors(nl, &particles.vol, &particles.role, boundary)?;
        nl.scale_pair_weights(&factors)?;
        Ok(Some(report))
    }

    /// The factors `exp(s_k)` of every stored pair `k` of `nl` (plain weights), and the report.
    /// Does not change `nl`.
    pub fn factors(
        &mut self,
        nl: &NeighborList<D>,
        vol: &[f64],
        role: &[Role],
        boundary: &dyn Boundary<D>,
    ) -> Result<(Vec<f64>, MomentReport), Error> {
        let t0 = Instant::now();
        self.params
            .validate()
            .map_err(|e| e.under("pair_weights"))?;
        let n = nl.len();
        if vol.len() != n || role.len() != n {
            return Err(InputError::LengthMismatch {
                field: "vol/role",
                len: vol.len().min(role.len()),
                expected: n,
            }
            .into());
        }
        let m = unknowns(D);
        let sg = mirror_signs(role, boundary);
        let rows = build_rows(nl, vol, role, &sg);
        let nf = rows.particle.len();
        let fl = first_ghost(role);
        let warm = self.params.warm_start && self.fluid_len == fl && self.z.len() == n.max(fl);
        let mut z: Vec<[f64; M]> = if warm {
            rows.particle.iter().map(|&i| self.z[i]).collect()
        } else {
            vec![[0.0; M]; nf]
        };
        let (newton, cg_iters) = newton(&rows, &mut z, &self.params, m, D)?;
        // multipliers of every particle: fluid own, ghost mirrored, Dirichlet zero
        let mut zall = vec![[0.0; M]; n];
        for (u, &i) in rows.particle.iter().enumerate() {
            zall[i] = z[u];
        }
        for i in 0..n {
            if let Role::Ghost { source, .. } = role[i] {
                zall[i] = mirror(&zall[source as usize], &sg[i]);
            }
        }
        let h = nl.h();
        let factors: Vec<f64> = (0..n)
            .into_par_iter()
            .flat_map_iter(|i| {
                let zall = &zall;
                nl.row(i).map(move |k| {
                    let j = nl.neighbor(k);
                    let d: [f64; D] = std::array::from_fn(|a| nl.dx()[k][a] / h);
                    let nd: [f64; D] = std::array::from_fn(|a| -d[a]);
                    // f_ij = f_ji bit for bit: x_ij = −x_ji exactly and + commutes
                    let (si, sj) = (dot(&zall[i], &feat(&d), m), dot(&zall[j], &feat(&nd), m));
                    (si + sj).exp()
                })
            })
            .collect();
        // report
        let mut rep = MomentReport {
            newton,
            cg_iters,
            warm,
            factor_min: f64::INFINITY,
            factor_max: 0.0,
            ..Default::default()
        };
        for f in &factors {
            rep.factor_min = rep.factor_min.min(*f);
            rep.factor_max = rep.factor_max.max(*f);
        }
        if let Some(k) = factors.iter().position(|f| !f.is_finite()) {
            let i = nl
                .pair_offsets()
                .partition_point(|&o| o <= k)
                .saturating_sub(1);
            return Err(PairWeightError::NonFinite { particle: i }.into());
        }
        let t = target(m, D);
        for u in 0..nf {
            let mut mom = [0.0; M];
            for k in rows.offsets[u]..rows.offsets[u + 1] {
                let s = dot(&z[u], &rows.phi[k], m) + other_s(&rows, &z, k, m);
                let w = rows.base[k] * s.exp() / rows.vol[u];
                for q in 0..m {
                    mom[q] += w * rows.phi[k][q];
                }
            }
            let r1 = (0..D).map(|q| mom[q].abs()).fold(0.0, f64::max);
            let r2 = (D..m).map(|q| (mom[q] - t[q]).abs()).fold(0.0, f64::max);
            rep.first_moment = rep.first_moment.max(r1);
            if r2 > rep.second_moment {
                rep.second_moment = r2;
                rep.worst_particle = rows.particle[u];
            }
            rep.regularised_rows += (r2 > 1e-6) as usize;
        }
        self.z = zall;
        self.fluid_len = fl;
        rep.seconds = t0.elapsed().as_secs_f64();
        self.last = Some(rep);
        Ok((factors, rep))
    }
}

fn target(m: usize, d: usize) -> [f64; M] {
    let mut t = [0.0; M];
    let mut q = d;
    for a in 0..d {
        for b in a..d {
            if a == b {
                t[q] = 1.0 / d as f64;
            }
            q += 1;
        }
    }
    debug_assert_eq!(q, m);
    t
}

#[inline(always)]
fn other_s(rows: &Rows, z: &[[f64; M]], k: usize, m: usize) -> f64 {
    let o = rows.other[k];
    if o == u32::MAX {
        0.0
    } else {
        dot(&z[o as usize], &rows.psi[k], m)
    }
}

fn build_rows<const D: usize>(
    nl: &NeighborList<D>,
    vol: &[f64],
    role: &[Role],
    sg: &[[f64; D]],
) -> Rows {
    let n = nl.len();
    let mut unknown = vec![u32::MAX; n];
    let mut particle = Vec::new();
    for i in 0..n {
        if role[i].is_fluid() {
            unknown[i] = particle.len() as u32;
            particle.push(i);
        }
    }
    let h = nl.h();
    let mut offsets = vec![0usize];
    let (mut phi, mut psi, mut other, mut base, mut half) =
        (Vec::new(), Vec::new(), Vec::new(), Vec::new(), Vec::new());
    for &i in &particle {
        for k in nl.row(i) {
            let j = nl.neighbor(k);
            let d: [f64; D] = std::array::from_fn(|a| nl.dx()[k][a] / h);
            let nd: [f64; D] = std::array::from_fn(|a| -d[a]);
            phi.push(feat(&d));
            psi.push(mirror(&feat(&nd), &sg[j]));
            let a = alias(role, j).map(|s| unknown[s]).unwrap_or(u32::MAX);
            other.push(a);
            half.push(if a == u32::MAX { 1.0 } else { 0.5 });
            base.push(vol[i] * vol[j] * nl.wr2()[k] * h * h);
        }
        offsets.push(phi.len());
    }
    let vol = particle.iter().map(|&i| vol[i]).collect();
    let mut row_of = vec![0u32; phi.len()];
    for u in 0..particle.len() {
        row_of[offsets[u]..offsets[u + 1]].fill(u as u32);
    }
    Rows {
        row_of,
        particle,
        vol,
        offsets,
        phi,
        psi,
        other,
        base,
        half,
    }
}

/// Pair weights `w_k = base_k exp(s_k)` at `z`.
fn weights(rows: &Rows, z: &[[f64; M]], m: usize, w: &mut Vec<f64>) {
    w.resize(rows.phi.len(), 0.0);
    w.par_iter_mut().enumerate().for_each(|(k, wk)| {
        let u = rows.row_of[k] as usize;
        let s = dot(&z[u], &rows.phi[k], m) + other_s(rows, z, k, m);
        *wk = rows.base[k] * s.exp();
    });
}

/// `Φ(z)` for weights `w` at `z`.
fn objective(
    rows: &Rows,
    z: &[[f64; M]],
    w: &[f64],
    eps: &[f64; M],
    t: &[f64; M],
    m: usize,
) -> f64 {
    // fixed split lengths (here and in `vdot`): the same sums every run
    let pairs: f64 = w
        .par_iter()
        .zip(&rows.half)
        .with_min_len(2048)
        .with_max_len(2048)
        .map(|(w, h)| w * h)
        .sum();
    let lin: f64 = (0..z.len())
        .into_par_iter()
        .with_min_len(2048)
        .with_max_len(2048)
        .map(|u| {
            let mut s = 0.0;
            for q in 0..m {
                s += rows.vol[u] * (0.5 * eps[q] * z[u][q] * z[u][q] - z[u][q] * t[q]);
            }
            s
        })
        .sum();
    pairs + lin
}

/// `g_i = Σ_k w_k φ_k − ω_i t + ω_i ε∘z_i`.
fn gradient(
    rows: &Rows,
    z: &[[f64; M]],
    w: &[f64],
    eps: &[f64; M],
    t: &[f64; M],
    m: usize,
) -> Vec<[f64; M]> {
    (0..z.len())
        .into_par_iter()
        .map(|u| {
            let mut g = [0.0; M];
            for k in rows.offsets[u]..rows.offsets[u + 1] {
                for q in 0..m {
                    g[q] += w[k] * rows.phi[k][q];
                }
            }
            for q in 0..m {
                g[q] += rows.vol[u] * (eps[q] * z[u][q] - t[q]);
            }
            g
        })
        .collect()
}

/// `(H v)_i = Σ_k w_k φ_k (φ_k·v_i + ψ_k·v_{o(k)}) + ω_i ε∘v_i`.
fn hess_apply(
    rows: &Rows,
    w: &[f64],
    eps: &[f64; M],
    m: usize,
    v: &[[f64; M]],
    out: &mut [[f64; M]],
) {
    out.par_iter_mut().enumerate().for_each(|(u, o)| {
        let mut acc = [0.0; M];
        for k in rows.offsets[u]..rows.offsets[u + 1] {
            let s = dot(&rows.phi[k], &v[u], m) + other_s(rows, v, k, m);
            let f = w[k] * s;
            for q in 0..m {
                acc[q] += f * rows.phi[k][q];
            }
        }
        for q in 0..m {
            acc[q] += rows.vol[u] * eps[q] * v[u][q];
        }
        *o = acc;
    });
}

/// Cholesky inverse of the leading `m × m` block of `a` (shifted when not positive definite).
fn spd_inverse(a: &[[f64; M]; M], lo: usize, hi: usize) -> [[f64; M]; M] {
    let n = hi - lo;
    let tr: f64 = (lo..hi)
        .map(|q| a[q][q].abs())
        .sum::<f64>()
        .max(f64::MIN_POSITIVE);
    let mut shift = 0.0;
    for _ in 0..40 {
        let mut l = [[0.0; M]; M];
        let mut ok = true;
        'outer: for r in 0..n {
            for c in 0..=r {
                let mut s = a[lo + r][lo + c] + if r == c { shift } else { 0.0 };
                for p in 0..c {
                    s -= l[r][p] * l[c][p];
                }
                if r == c {
                    if !(s > 1e-14 * tr) {
                        ok = false;
                        break 'outer;
                    }
                    l[r][r] = s.sqrt();
                } else {
                    l[r][c] = s / l[c][c];
                }
            }
        }
        if ok {
            // inverse column by column
            let mut inv = [[0.0; M]; M];
            for col in 0..n {
                let mut y = [0.0; M];
                for r in 0..n {
                    let mut s = if r == col { 1.0 } else { 0.0 };
                    for p in 0..r {
                        s -= l[r][p] * y[p];
                    }
                    y[r] = s / l[r][r];
                }
                let mut x = [0.0; M];
                for r in (0..n).rev() {
                    let mut s = y[r];
                    for p in r + 1..n {
                        s -= l[p][r] * x[p];
                    }
                    x[r] = s / l[r][r];
                }
                for r in 0..n {
                    inv[lo + r][lo + col] = x[r];
                }
            }
            return inv;
        }
        shift = if shift == 0.0 {
            1e-10 * tr
        } else {
            shift * 10.0
        };
    }
    // not finite: the identity (the Newton iteration reports the non-finite row)
    let mut id = [[0.0; M]; M];
    for (q, row) in id.iter_mut().enumerate().take(hi).skip(lo) {
        row[q] = 1.0;
    }
    id
}

/// The preconditioner of one Newton step.
struct Precond {
    blocks: Vec<[[f64; M]; M]>,
    amg: Option<(Amg, ScalarCsr)>,
    d: usize,
    m: usize,
}

struct ScalarCsr {
    offsets: Vec<usize>,
    cols: Vec<u32>,
    values: Vec<f64>,
}

impl ScalarCsr {
    fn view(&self) -> CsrRef<'_> {
        CsrRef {
            offsets: &self.offsets,
            cols: &self.cols,
            values: &self.values,
        }
    }
}

impl Precond {
    fn new(
        rows: &Rows,
        w: &[f64],
        eps: &[f64; M],
        m: usize,
        d: usize,
        kind: MomentPreconditioner,
        prev: Option<Amg>,
    ) -> Self {
        let nf = rows.particle.len();
        let amg_on = kind == MomentPreconditioner::Amg;
        let blocks: Vec<[[f64; M]; M]> = (0..nf)
            .into_par_iter()
            .map(|u| {
                let mut b = [[0.0; M]; M];
                for k in rows.offsets[u]..rows.offsets[u + 1] {
                    let own = rows.other[k] == u as u32;
                    for p in 0..m {
                        let fp = w[k] * rows.phi[k][p];
                        for q in 0..m {
                            let c = rows.phi[k][q] + if own { rows.psi[k][q] } else { 0.0 };
                            b[p][q] += fp * c;
                        }
                    }
                }
                for q in 0..m {
                    b[q][q] += rows.vol[u] * eps[q];
                }
                if amg_on {
                    spd_inverse(&b, d, m)
                } else {
                    spd_inverse(&b, 0, m)
                }
            })
            .collect();
        let amg = amg_on.then(|| {
            let mut offsets = vec![0usize];
            let mut cols = Vec::new();
            let mut values = Vec::new();
            let mut row: Vec<(u32, f64)> = Vec::new();
            for u in 0..nf {
                row.clear();
                let mut diag = 0.0;
                for k in rows.offsets[u]..rows.offsets[u + 1] {
                    let r2: f64 = (0..d).map(|a| rows.phi[k][a] * rows.phi[k][a]).sum();
                    let a = w[k] * r2 / d as f64;
                    let o = rows.other[k];
                    diag += a;
                    if o == u as u32 {
                        diag += a;
                    } else if o != u32::MAX {
                        row.push((o, -a));
                    }
                }
                // (shifted: the λ block is singular in a periodic box, and the V-cycle of a
                // singular matrix is not a usable SPD preconditioner)
                row.push((u as u32, diag * (1.0 + 1e-3) + rows.vol[u] * eps[0]));
                row.sort_unstable_by_key(|e| e.0);
                let mut last = u32::MAX;
                for &(c, v) in &row {
                    if c == last {
                        *values.last_mut().unwrap() += v;
                    } else {
                        cols.push(c);
                        values.push(v);
                        last = c;
                    }
                }
                offsets.push(cols.len());
            }
            let csr = ScalarCsr {
                offsets,
                cols,
                values,
            };
            // the pattern is the same at every Newton step: refresh the values only
            let amg = match prev {
                Some(mut a) if a.n() == nf && a.stats().nnz.first() == Some(&csr.cols.len()) => {
                    a.refresh(csr.view());
                    a
                }
                _ => Amg::build(csr.view(), AmgParams::default()),
            };
            (amg, csr)
        });
        Precond { blocks, amg, d, m }
    }

    fn apply(&mut self, r: &[[f64; M]], out: &mut [[f64; M]]) {
        let (d, m) = (self.d, self.m);
        let lo = if self.amg.is_some() { d } else { 0 };
        out.par_iter_mut().enumerate().for_each(|(u, o)| {
            let b = &self.blocks[u];
            let mut x = [0.0; M];
            for p in lo..m {
                let mut s = 0.0;
                for q in lo..m {
                    s += b[p][q] * r[u][q];
                }
                x[p] = s;
            }
            *o = x;
        });
        if let Some((amg, csr)) = &mut self.amg {
            let nf = r.len();
            let mut rb = vec![0.0; nf];
            let mut xb = vec![0.0; nf];
            for c in 0..d {
                for u in 0..nf {
                    rb[u] = r[u][c];
                }
                amg.vcycle(csr.view(), &rb, &mut xb);
                for u in 0..nf {
                    out[u][c] = xb[u];
                }
            }
        }
    }
}

fn vdot(a: &[[f64; M]], b: &[[f64; M]], m: usize) -> f64 {
    a.par_iter()
        .zip(b)
        .with_min_len(2048)
        .with_max_len(2048)
        .map(|(x, y)| dot(x, y, m))
        .sum()
}

/// Newton with Armijo backtracking on `Φ`; returns (Newton steps, CG iterations).
fn newton(
    rows: &Rows,
    z: &mut [[f64; M]],
    p: &MomentParams,
    m: usize,
    d: usize,
) -> Result<(usize, usize), PairWeightError> {
    let nf = z.len();
    let t = target(m, d);
    let mut eps = [0.0; M];
    for q in 0..m {
        eps[q] = if q < d { p.reg_first } else { p.reg_second };
    }
    let mut w = Vec::new();
    weights(rows, z, m, &mut w);
    let mut phi0 = objective(rows, z, &w, &eps, &t, m);
    let mut cg_total = 0;
    let worst = |g: &[[f64; M]]| -> (f64, usize) {
        let mut best = (0.0f64, 0usize);
        for (u, gu) in g.iter().enumerate() {
            let r = (0..m).map(|q| gu[q].abs()).fold(0.0, f64::max) / rows.vol[u];
            if !(r <= best.0) {
                best = (r, u);
            }
        }
        best
    };
    let mut hierarchy: Option<Amg> = None;
    for step in 0..=p.max_newton {
        let g = gradient(rows, z, &w, &eps, &t, m);
        let (res, wu) = worst(&g);
        if !res.is_finite() {
            return Err(PairWeightError::NonFinite {
                particle: rows.particle[wu],
            });
        }
        if res <= p.tol || nf == 0 {
            return Ok((step, cg_total));
        }
        if step == p.max_newton && res <= p.accept {
            return Ok((step, cg_total));
        }
        if step == p.max_newton {
            return Err(PairWeightError::NoConvergence {
                newton: step,
                residual: res,
                particle: rows.particle[wu],
                reason: "Newton step limit",
            });
        }
        // PCG on H δ = −g to the relative residual η (inexact Newton: loose while the moment
        // residual is large, cg_rel_tol near the solution)
        let eta = (0.1 * res).clamp(p.cg_rel_tol, 1e-2);
        let mut pre = Precond::new(rows, &w, &eps, m, d, p.preconditioner, hierarchy.take());
        let mut dz = vec![[0.0; M]; nf];
        let mut r: Vec<[f64; M]> = g.iter().map(|x| x.map(|v| -v)).collect();
        let mut y = vec![[0.0; M]; nf];
        pre.apply(&r, &mut y);
        let mut dir = y.clone();
        let mut ry = vdot(&r, &y, m);
        let r0 = vdot(&r, &r, m).sqrt();
        let mut hp = vec![[0.0; M]; nf];
        for _ in 0..p.max_cg {
            hess_apply(rows, &w, &eps, m, &dir, &mut hp);
            let php = vdot(&dir, &hp, m);
            if !(php > 0.0) {
                break;
            }
            let alpha = ry / php;
            dz.par_iter_mut()
                .zip(r.par_iter_mut())
                .zip(dir.par_iter().zip(hp.par_iter()))
                .for_each(|((x, rr), (pp, hh))| {
                    for q in 0..m {
                        x[q] += alpha * pp[q];
                        rr[q] -= alpha * hh[q];
                    }
                });
            cg_total += 1;
            if vdot(&r, &r, m).sqrt() <= eta * r0 {
                break;
            }
            pre.apply(&r, &mut y);
            let ry2 = vdot(&r, &y, m);
            let beta = ry2 / ry;
            ry = ry2;
            dir.par_iter_mut().zip(y.par_iter()).for_each(|(pp, yy)| {
                for q in 0..m {
                    pp[q] = yy[q] + beta * pp[q];
                }
            });
        }
        // Armijo backtracking along the Newton direction, then (when that finds no decrease,
        // e.g. a CG direction spoilt by rounding) along the preconditioned gradient
        let mut zt = z.to_vec();
        let mut accepted = line_search(rows, z, &dz, &g, &eps, &t, m, &mut w, &mut zt, &mut phi0);
        if !accepted {
            pre.apply(&g, &mut dz);
            dz.iter_mut().for_each(|x| *x = x.map(|v| -v));
            accepted = line_search(rows, z, &dz, &g, &eps, &t, m, &mut w, &mut zt, &mut phi0);
        }
        if !accepted && res <= p.accept {
            return Ok((step, cg_total));
        }
        if !accepted {
            return Err(PairWeightError::NoConvergence {
                newton: step,
                residual: res,
                particle: rows.particle[wu],
                reason: "line search found no decrease",
            });
        }
        hierarchy = pre.amg.take().map(|(a, _)| a);
        z.copy_from_slice(&zt);
    }
    Err(PairWeightError::NoConvergence {
        newton: p.max_newton,
        residual: f64::NAN,
        particle: 0,
        reason: "Newton step limit",
    })
}

/// Armijo backtracking from `z` along `dz`: on success `zt = z + α dz`, `w` its weights, `phi0`
/// its objective.
#[allow(clippy::too_many_arguments)]
fn line_search(
    rows: &Rows,
    z: &[[f64; M]],
    dz: &[[f64; M]],
    g: &[[f64; M]],
    eps: &[f64; M],
    t: &[f64; M],
    m: usize,
    w: &mut Vec<f64>,
    zt: &mut [[f64; M]],
    phi0: &mut f64,
) -> bool {
    let nf = z.len();
    let slope = vdot(g, dz, m);
    if !(slope < 0.0) {
        return false;
    }
    let mut alpha = 1.0;
    for _ in 0..40 {
        for u in 0..nf {
            for q in 0..m {
                zt[u][q] = z[u][q] + alpha * dz[u][q];
            }
        }
        weights(rows, zt, m, w);
        let phi = objective(rows, zt, w, eps, t, m);
        // (with a rounding allowance: near the minimum Φ changes by less than its ulp)
        if phi.is_finite() && phi <= *phi0 + 1e-4 * alpha * slope + 1e-14 * phi0.abs() {
            *phi0 = phi;
            return true;
        }
        alpha *= 0.5;
    }
    weights(rows, z, m, w);
    false
}
