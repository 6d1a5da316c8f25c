//! The step's diagnostics as global quantities over the ranks' own rows (MISSION §3): the
//! h-connectivity components joined through the halo, `c0`, the norms and the Theorem 4.5 ratio.
//!
//! Components: every rank joins its own unknowns along the matrix pattern (a union-find over
//! its own rows); then each component carries the smallest global unknown index of its members
//! as its label and whether one of its members touches the Dirichlet band, and both travel
//! through the halo (one exchange each per round) until no rank changes a label (one reduction
//! per round): a distributed union-find by label propagation, `≤ P + 1` rounds when every
//! rank's part of a component is connected in itself. A component is counted once, by the rank
//! owning its smallest member.

use super::comm::Comm;
use super::solver::DistributedPoisson;
use crate::diagnostics::{
    alias, norm_h01, norm_l2_vec, semi_regularity, stability_ratio, ConnectivitySummary, Region,
};
use crate::neighbors::NeighborList;
use crate::particles::Role;
use crate::poisson::Assembly;
use serde::{Deserialize, Serialize};

/// Global diagnostics of one step, identical on every rank.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct GlobalDiagnostics {
    /// Components of the fluid graph (anchored, floating, isolated particles).
    pub connectivity: ConnectivitySummary,
    /// Semi-regularity constant `c0` over the fluid rows.
    pub c0: f64,
    /// `‖φ‖_h01(Ω)`.
    pub phi_h01: f64,
    /// `‖f‖_ℓ2(Ω)`.
    pub f_l2: f64,
    /// The Theorem 4.5 ratio `‖φ‖_h01 / (√(d c0) ‖f‖_ℓ2)`.
    pub stability_ratio: f64,
    /// Rounds of the label propagation.
    pub rounds: usize,
}

/// [`global_diagnostics`] of the step `sim` just took (`dt` its `Δt`): its assembly,
/// neighbours, roles, volumes and increment, and the source field `−(ρ/Δt) u*`.
pub fn step_diagnostics<C: Comm, const D: usize, B: crate::boundary::Boundary<D>>(
    dd: &mut DistributedPoisson<C>,
    sim: &crate::flow::Simulation<D, B>,
    dt: f64,
) -> GlobalDiagnostics {
    let scale = -sim.params.projection.rho / dt;
    let f: Vec<[f64; D]> = sim
        .projection
        .u_star()
        .iter()
        .map(|u| u.map(|c| scale * c))
        .collect();
    global_diagnostics(
        dd,
        &sim.projection.solver.assembly,
        &sim.nl,
        &sim.particles.role,
        &sim.particles.vol,
        &sim.projection.phi,
        &f,
    )
}

/// The diagnostics of the configuration the last solve of `dd` saw (`a` its assembly), from
/// the ranks' own rows: `phi` the increment at every particle, `f` the Poisson source field
/// `−(ρ/Δt) u*`.
pub fn global_diagnostics<C: Comm, const D: usize>(
    dd: &mut DistributedPoisson<C>,
    a: &Assembly,
    nl: &NeighborList<D>,
    role: &[Role],
    vol: &[f64],
    phi: &[f64],
    f: &[[f64; D]],
) -> GlobalDiagnostics {
    let rank = dd.comm().rank() as u32;
    // the roles seen by this rank's sums: fluid only where the particle is an own unknown
    let own_role: Vec<Role> = role
        .iter()
        .enumerate()
        .map(|(i, &r)| {
            let u = a.unknown.get(i).copied().unwrap_or(u32::MAX);
            if r.is_fluid() && (u == u32::MAX || dd.owner().get(u as usize) != Some(&rank)) {
                Role::Dirichlet
            } else {
                r
            }
        })
        .collect();
    let c0 = semi_regularity(nl, vol, &own_role, Region::Omega);
    let h01 = norm_h01(nl, vol, phi, &own_role, Region::Omega);
    let fl2 = norm_l2_vec(vol, f, &own_role, Region::Omega);
    let (connectivity, rounds) = components(dd, a, nl, role);
    let c0 = dd.comm().max(&[c0])[0];
    let s = dd.comm().sum(&[h01 * h01, fl2 * fl2]);
    let (phi_h01, f_l2) = (s[0].sqrt(), s[1].sqrt());
    GlobalDiagnostics {
        connectivity,
        c0,
        phi_h01,
        f_l2,
        stability_ratio: stability_ratio(phi_h01, c0, f_l2, D),
        rounds,
    }
}

fn find(p: &mut [usize], mut a: usize) -> usize {
    while p[a] != a {
        p[a] = p[p[a]];
        a = p[a];
    }
    a
}

fn components<C: Comm, const D: usize>(
    dd: &mut DistributedPoisson<C>,
    a: &Assembly,
    nl: &NeighborList<D>,
    role: &[Role],
) -> (ConnectivitySummary, usize) {
    let rows = dd.rows().clone();
    let own_unknowns = dd.own_unknowns().to_vec();
    let m = rows.n_own();
    let nh = rows.halo.len();
    // local union-find along own–own entries
    let mut parent: Vec<usize> = (0..m).collect();
    for i in 0..m {
        for &c in &rows.cols[rows.offsets[i]..rows.offsets[i + 1]] {
            let c = c as usize;
            if c < m {
                let (x, y) = (find(&mut parent, i), find(&mut parent, c));
                if x != y {
                    parent[x.max(y)] = x.min(y);
                }
            }
        }
    }
    let root: Vec<usize> = (0..m).map(|i| find(&mut parent, i)).collect();
    // touches the band / has a neighbour at all (the serial rule of diagnostics::connectivity)
    let mut touches = vec![false; m];
    let mut isolated = 0.0;
    for (li, &u) in own_unknowns.iter().enumerate() {
        let i = a.particle[u as usize] as usize;
        let mut has_nb = false;
        for k in nl.row(i) {
            match alias(role, nl.indices()[k] as usize) {
                None => {
                    touches[li] = true;
                    has_nb = true;
                }
                Some(s) if s != i => has_nb = true,
                Some(_) => {}
            }
        }
        if !has_nb {
            isolated += 1.0;
        }
    }
    let mut label: Vec<f64> = rows.own.iter().map(|&g| g as f64).collect();
    let mut anchored: Vec<f64> = touches.iter().map(|&t| t as u8 as f64).collect();
    label.resize(m + nh, f64::INFINITY);
    anchored.resize(m + nh, 0.0);
    let mut rounds = 0;
    loop {
        // within the rank: the component's smallest label and any anchor
        let mut best = vec![(f64::INFINITY, 0.0f64); m];
        for i in 0..m {
            let mut l = label[i];
            let mut an = anchored[i];
            for &c in &rows.cols[rows.offsets[i]..rows.offsets[i + 1]] {
                l = l.min(label[c as usize]);
                an = an.max(anchored[c as usize]);
            }
            let b = &mut best[root[i]];
            b.0 = b.0.min(l);
            b.1 = b.1.max(an);
        }
        let mut changed = 0.0;
        for i in 0..m {
            let (l, an) = best[root[i]];
            if l != label[i] || an != anchored[i] {
                changed = 1.0;
                label[i] = l;
                anchored[i] = an;
            }
        }
        rounds += 1;
        if dd.comm().sum(&[changed])[0] == 0.0 && rounds > 1 {
            break;
        }
        dd.exchange_values(&mut label);
        dd.exchange_values(&mut anchored);
    }
    let (mut comps, mut anch) = (0.0, 0.0);
    for (i, &g) in rows.own.iter().enumerate() {
        if label[i] == g as f64 {
            comps += 1.0;
            anch += anchored[i];
        }
    }
    let s = dd.comm().sum(&[comps, anch, isolated]);
    (
        ConnectivitySummary {
            components: s[0] as usize,
            anchored: s[1] as usize,
            floating: (s[0] - s[1]) as usize,
            isolated: s[2] as usize,
        },
        rounds,
    )
}
