//! The distributed preconditioned CG of the Poisson system.
//!
//! Each rank owns the rows of its unknowns ([`LocalRows`]); one iteration is
//!
//! 1. `z = M r` ([`DdPreconditioner`]): Jacobi, or the two-level
//!    `M = Q + (I − QA) B (I − AQ)` with `B` one V-cycle of the crate's AMG on the rank's
//!    own–own block (or, `Schwarz`, on its own and halo rows) and `Q = Z A_c⁻¹ Zᵀ` on
//!    piecewise-constant aggregates (`A_c = Zᵀ K Z`, replicated and factorised on every rank):
//!    one halo exchange (for `A w`) and reduction 1, `[r·w, Σ_C w, Zᵀ A w]`; `z` is projected
//!    to zero mean on each floating component;
//! 2. `p = z + β p`; halo exchange of `p` (one message to each neighbour rank); `q = K p`;
//!    reduction 2, `p·q`;
//! 3. `x += α p`, `r −= α q`; reduction 3, `[r·r, Σ_C r, Zᵀ r]`: `r` projected to zero mean
//!    on each floating component (the constants are the null space), `Zᵀ r` kept for step 1.
//!
//! Two neighbour exchanges (four with `Schwarz`) and three reductions per iteration. Every
//! reduction adds the ranks' partial sums in rank order ([`Comm::sum`]), so all ranks hold the
//! same bits and a run is reproducible. At the end the own parts of `x` are gathered to every
//! rank (the driver keeps the particle state on every rank, see [`super`]).

use super::comm::Comm;
use super::halo::LocalRows;
use super::partition::rcb;
use crate::error::SolveError;
use crate::poisson::amg::{Amg, AmgParams, CsrRef};
use crate::poisson::iterative::{stop_tol, CgInfo};
use crate::poisson::{ExternalSolve, ExternalSystem};
use nalgebra::{DMatrix, DVector};
use serde::{Deserialize, Serialize};

/// Messages of one exchange: `(rank, values)`.
type Messages = Vec<(usize, Vec<f64>)>;

/// The preconditioner of the distributed CG.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DdPreconditioner {
    /// The diagonal: the same iterations at any number of ranks, but many of them.
    Jacobi,
    /// Block Jacobi: one AMG V-cycle of the rank's own–own block.
    BlockAmg,
    /// Block AMG plus the coarse correction on per-rank aggregates (the fewest iterations at
    /// 1 rank on the cavity, but 1.6–1.9× as many at 4, see `docs/mpi.md`).
    BlockAmgCoarse,
    /// Additive Schwarz with overlap `h` (one V-cycle of the AMG of the own and halo rows,
    /// the overlap weighted `1/√k` for an unknown held by `k` ranks, the halo's results added
    /// back to their owners) plus the coarse correction.
    Schwarz,
    /// Two-level and independent of the partition: a Chebyshev polynomial of degree
    /// [`DistributedPoisson::chebyshev_degree`] in `D⁻¹K` over `[λ/30, λ]` (`λ` the global
    /// Gershgorin bound of `D⁻¹K`; one halo exchange per degree) as the smoother, and the
    /// coarse correction on aggregates cut from *all* unknowns by RCB, whatever their rank.
    /// The operator is then the same at any number of ranks, and so are the iterations (up to
    /// round-off); each iteration costs `degree` exchanges instead of one V-cycle. The
    /// default: Taylor–Green n = 128 9.5 iterations per solve at 1, 2 and 4 ranks (block AMG
    /// with coarse correction: 12.3 → 19.4), the cavity n = 64 24.3 (13.5 → 25.7).
    #[default]
    Chebyshev,
}

/// Message counts and volumes of one rank (cumulative; [`DistributedPoisson::traffic`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Traffic {
    /// Point-to-point messages sent (halo exchanges).
    pub messages: u64,
    /// Bytes in them.
    pub bytes: u64,
    /// Global reductions (each an allgather of the partial sums).
    pub reductions: u64,
    /// `f64` values contributed to reductions.
    pub reduced_values: u64,
    /// Bytes this rank contributed to gathers of the solution (allgather of own values).
    pub gathered_bytes: u64,
    /// Solves.
    pub solves: u64,
    /// CG iterations.
    pub iterations: u64,
}

/// The distributed Poisson solver: plug it into [`crate::poisson::PoissonSolver::external`].
#[derive(Debug)]
pub struct DistributedPoisson<C: Comm> {
    comm: C,
    /// Preconditioner (default [`DdPreconditioner::Chebyshev`]).
    pub preconditioner: DdPreconditioner,
    /// Target unknowns per coarse aggregate (default 16: at 4 ranks 19 iterations against 23
    /// with 64 for Taylor–Green n = 128; the coarse problem has `N/16` unknowns, which suits
    /// this machine's sizes, not 10⁶ unknowns per rank, see `docs/mpi.md`).
    pub aggregate_size: usize,
    /// Degree of the Chebyshev smoother of [`DdPreconditioner::Chebyshev`] (default 2: measured, Taylor–Green n = 128 / cavity n = 64, 20 steps, mean iterations: degree 1 12.7 / 36.0, 2 9.5 / 24.3, 3 13.1 / 28.4, 4 13.1 / 29.6, 6 11.2 / 25.0).
    pub chebyshev_degree: usize,
    /// [`DdPreconditioner::Chebyshev`]: the global bound of `D⁻¹K`'s spectrum.
    lambda_max: f64,
    pattern: Option<u64>,
    owner: Vec<u32>,
    rows: LocalRows,
    amg: Option<Amg>,
    coarse: Option<Coarse>,
    /// Diagonal of the own rows (Jacobi).
    diag: Vec<f64>,
    /// Schwarz: `1/√k` for an unknown held by `k` ranks (own and halo), so that the overlap
    /// is not counted several times: `B = Σ_r R_rᵀ D_r A_r⁻¹ D_r R_r`.
    overlap_weight: Vec<f64>,
    /// The own rows' values the preconditioner was built for.
    built_for: Option<(DdPreconditioner, usize, Vec<f64>)>,
    null_key: Vec<Vec<u32>>,
    traffic: Traffic,
    /// Iterations of the last solve.
    pub last_iters: usize,
    /// Set by [`Self::set_local`]: the systems are local (particle decomposition).
    local: Option<LocalIds>,
    /// Local mode: the local unknown of each own row and of each halo entry (`u32::MAX` for a
    /// halo unknown the local system does not hold: none when the particle halo covers `h`).
    own_local: Vec<u32>,
    halo_local: Vec<u32>,
}

/// What a rank's local system does not say about itself: the global index and owner rank of
/// each of its particles, and whether the global problem is floating.
#[derive(Clone, Debug, PartialEq)]
struct LocalIds {
    gid: Vec<u32>,
    owner: Vec<u32>,
    floating: bool,
    /// Bumped by every [`DistributedPoisson::set_local`]: the rows are rebuilt.
    generation: u64,
}

#[derive(Debug)]
struct Coarse {
    /// Aggregate (global coarse index) of each own and halo unknown (local numbering).
    agg: Vec<u32>,
    n: usize,
    chol: nalgebra::Cholesky<f64, nalgebra::Dyn>,
    /// Per floating component: its members in each aggregate (`Zᵀ 1_C`).
    comp_counts: Vec<Vec<f64>>,
}

impl<C: Comm> DistributedPoisson<C> {
    /// A solver over `comm` with the default preconditioner.
    pub fn new(comm: C) -> Self {
        DistributedPoisson {
            comm,
            preconditioner: DdPreconditioner::default(),
            aggregate_size: 16,
            chebyshev_degree: 2,
            lambda_max: 0.0,
            pattern: None,
            owner: Vec::new(),
            rows: LocalRows::default(),
            amg: None,
            coarse: None,
            diag: Vec::new(),
            overlap_weight: Vec::new(),
            built_for: None,
            null_key: Vec::new(),
            traffic: Traffic::default(),
            last_iters: 0,
            local: None,
            own_local: Vec::new(),
            halo_local: Vec::new(),
        }
    }

    /// Switches to local systems (the particle decomposition, [`super::decomposition`]): each
    /// rank's system is the one it assembled over its own particles and the halo of particles
    /// it received, complete in the rows of its own fluid particles only. `gid[i]` is the global
    /// index of local particle `i` and `owner[i]` its rank (for the unknowns; ghosts and
    /// Dirichlet particles are not read); `floating` says whether the *global* problem has
    /// the constants as null space (no Dirichlet particle anywhere: the closed cavity, the
    /// periodic box) — a local system cannot tell. Call it again whenever the local particles
    /// change. The rows are then built from the local matrix ([`LocalRows::from_local`]), the
    /// coarse aggregates per rank, and the solution written back to the own and halo unknowns
    /// of the local system (others keep their value). Not with [`DdPreconditioner::Schwarz`]
    /// (it needs the halo's rows).
    pub fn set_local(&mut self, gid: Vec<u32>, owner: Vec<u32>, floating: bool) {
        assert_eq!(gid.len(), owner.len(), "an owner per particle");
        let generation = self.local.as_ref().map_or(0, |l| l.generation + 1);
        self.local = Some(LocalIds {
            gid,
            owner,
            floating,
            generation,
        });
        self.pattern = None;
    }

    /// The communicator.
    pub fn comm(&self) -> &C {
        &self.comm
    }

    /// Message counts and volumes so far.
    pub fn traffic(&self) -> Traffic {
        self.traffic
    }

    /// Owner rank of each unknown of the last solve.
    pub fn owner(&self) -> &[u32] {
        &self.owner
    }

    /// This rank's rows of the last solve.
    pub fn rows(&self) -> &LocalRows {
        &self.rows
    }

    /// The unknown (of the system the last solve saw) of each own row: the global index for
    /// the whole system, the local unknown for a rank's local system ([`Self::set_local`]).
    pub fn own_unknowns(&self) -> &[u32] {
        if self.local.is_some() {
            &self.own_local
        } else {
            &self.rows.own
        }
    }

    fn reduce(&mut self, v: &[f64]) -> Vec<f64> {
        self.traffic.reductions += 1;
        self.traffic.reduced_values += v.len() as u64;
        self.comm.sum(v)
    }

    /// Fills the halo part of `v` (own values first, then the halo of [`Self::rows`]) from
    /// the neighbour ranks: one message to and from each.
    pub fn exchange_values(&mut self, v: &mut [f64]) {
        self.halo_exchange(v, false);
    }

    /// The reverse of [`Self::exchange_values`]: the halo part of `v` is sent to its owners,
    /// which add what they receive to their own entries.
    fn exchange_add(&mut self, v: &mut [f64]) {
        self.halo_exchange(v, true);
    }

    fn halo_exchange(&mut self, v: &mut [f64], reverse: bool) {
        let m = self.rows.n_own();
        let (own, halo) = (&self.rows.sends, &self.rows.recvs);
        let pack_own = || {
            own.iter()
                .map(|(q, l)| (*q, l.iter().map(|&i| v[i as usize]).collect::<Vec<f64>>()))
        };
        let pack_halo = || {
            halo.iter()
                .map(|(q, r)| (*q, v[m + r.start..m + r.end].to_vec()))
        };
        let (sends, mut recvs): (Messages, Messages) = if reverse {
            (
                pack_halo().collect(),
                pack_own().map(|(q, l)| (q, vec![0.0; l.len()])).collect(),
            )
        } else {
            (
                pack_own().collect(),
                pack_halo().map(|(q, l)| (q, vec![0.0; l.len()])).collect(),
            )
        };
        self.count_messages(&sends);
        self.comm.exchange(&sends, &mut recvs);
        for (k, (_, data)) in recvs.iter().enumerate() {
            if reverse {
                for (&i, d) in self.rows.sends[k].1.iter().zip(data) {
                    v[i as usize] += d;
                }
            } else {
                let r = &self.rows.recvs[k].1;
                v[m + r.start..m + r.end].copy_from_slice(data);
            }
        }
    }

    fn count_messages(&mut self, sends: &[(usize, Vec<f64>)]) {
        self.traffic.messages += sends.len() as u64;
        self.traffic.bytes += 8 * sends.iter().map(|s| s.1.len() as u64).sum::<u64>();
    }

    /// Partition, rows, halo plan and preconditioner for a new pattern; new values only
    /// refill the rows and rebuild the preconditioner.
    fn setup(&mut self, sys: &ExternalSystem<'_>, null: &[Vec<u32>]) {
        let a = CsrRef::from(sys.a);
        let pattern = sys.a.pattern_id();
        if self.pattern != Some(pattern) || self.owner.len() != sys.a.n() {
            match &self.local {
                Some(l) => {
                    let n = sys.a.n();
                    let gid: Vec<u32> = (0..n).map(|u| l.gid[sys.a.particle[u] as usize]).collect();
                    self.owner = (0..n)
                        .map(|u| l.owner[sys.a.particle[u] as usize])
                        .collect();
                    self.rows = LocalRows::from_local(a, &gid, &self.owner, &self.comm);
                    let me = self.comm.rank() as u32;
                    let mut own_local: Vec<u32> = (0..n as u32)
                        .filter(|&u| self.owner[u as usize] == me)
                        .collect();
                    own_local.sort_unstable_by_key(|&u| gid[u as usize]);
                    let mut at = std::collections::HashMap::new();
                    for u in (0..n as u32).filter(|&u| self.owner[u as usize] != me) {
                        at.insert((self.owner[u as usize], gid[u as usize]), u);
                    }
                    // the halo's owners, in the order of `rows.halo` (by owner, then index)
                    let mut halo_owner = Vec::with_capacity(self.rows.halo.len());
                    for (q, range) in &self.rows.recvs {
                        halo_owner.extend(std::iter::repeat_n(*q as u32, range.len()));
                    }
                    self.halo_local = self
                        .rows
                        .halo
                        .iter()
                        .zip(&halo_owner)
                        .map(|(&g, &q)| at.get(&(q, g)).copied().unwrap_or(u32::MAX))
                        .collect();
                    self.own_local = own_local;
                }
                None => {
                    self.owner = rcb(sys.positions, sys.dim, self.comm.size());
                    self.rows = LocalRows::new(a, &self.owner, self.comm.rank());
                }
            }
            self.pattern = Some(pattern);
            self.built_for = None;
        } else {
            self.rows.refill(&sys.a.values);
        }
        // the same matrix and settings (fixed particles): keep the preconditioner
        let key = (
            self.preconditioner,
            self.aggregate_size,
            self.rows.values.clone(),
        );
        if self.built_for.as_ref() == Some(&key) && self.null_key == null {
            return;
        }
        self.built_for = Some(key);
        self.null_key = null.to_vec();
        self.diag = self.rows.block.view().diagonal();
        if self.preconditioner == DdPreconditioner::Schwarz {
            let m = self.rows.n_own();
            let mut k = vec![1.0; m + self.rows.halo.len()];
            for (_, list) in &self.rows.sends {
                for &i in list {
                    k[i as usize] += 1.0;
                }
            }
            self.exchange_values(&mut k);
            self.overlap_weight = k.iter().map(|k| 1.0 / k.sqrt()).collect();
        }
        if self.preconditioner == DdPreconditioner::Chebyshev {
            // Gershgorin: λ(D⁻¹K) ≤ max_i Σ_j |K_ij| / K_ii, the max over the ranks
            let local = (0..self.rows.n_own())
                .map(|i| {
                    let (a, b) = (self.rows.offsets[i], self.rows.offsets[i + 1]);
                    self.rows.values[a..b].iter().map(|v| v.abs()).sum::<f64>() / self.diag[i]
                })
                .fold(0.0f64, f64::max);
            let mut slots = vec![0.0; self.comm.size()];
            slots[self.comm.rank()] = local;
            self.lambda_max = self.reduce(&slots).into_iter().fold(0.0, f64::max);
        }
        self.amg = match self.preconditioner {
            DdPreconditioner::Jacobi | DdPreconditioner::Chebyshev => None,
            DdPreconditioner::Schwarz => {
                Some(Amg::build(self.rows.ext.view(), AmgParams::default()))
            }
            _ => Some(Amg::build(self.rows.block.view(), AmgParams::default())),
        };
        self.coarse = match self.preconditioner {
            DdPreconditioner::BlockAmgCoarse
            | DdPreconditioner::Schwarz
            | DdPreconditioner::Chebyshev => Some(self.coarse_space(sys, null)),
            _ => None,
        };
    }

    /// Aggregates: every rank's own unknowns cut by RCB into parts of about
    /// `aggregate_size` (computed alike on every rank from the replicated positions);
    /// `A_c = Zᵀ K Z` summed over the ranks' rows, plus `σ 1 1ᵀ` on each floating component's
    /// aggregates (its constants are the null space), factorised by dense Cholesky.
    fn coarse_space(&mut self, sys: &ExternalSystem<'_>, null: &[Vec<u32>]) -> Coarse {
        if let Some(floating) = self.local.as_ref().map(|l| l.floating) {
            return self.coarse_space_local(sys, floating);
        }
        let p = self.comm.size();
        let d = sys.dim;
        let mut global_agg = vec![0u32; self.owner.len()];
        let mut first = 0usize;
        // Chebyshev: one cut of all unknowns, the same at any number of ranks
        let groups = if self.preconditioner == DdPreconditioner::Chebyshev {
            1
        } else {
            p
        };
        for r in 0..groups {
            let members: Vec<u32> = (0..self.owner.len() as u32)
                .filter(|&u| groups == 1 || self.owner[u as usize] as usize == r)
                .collect();
            let parts = members.len().div_ceil(self.aggregate_size.max(1)).max(1);
            let pts: Vec<f64> = members
                .iter()
                .flat_map(|&u| sys.positions[u as usize * d..(u as usize + 1) * d].to_vec())
                .collect();
            for (k, part) in rcb(&pts, d, parts).into_iter().enumerate() {
                global_agg[members[k] as usize] = (first + part as usize) as u32;
            }
            first += parts;
        }
        let nc = first;
        let agg: Vec<u32> = self
            .rows
            .own
            .iter()
            .chain(&self.rows.halo)
            .map(|&g| global_agg[g as usize])
            .collect();
        let comp_counts: Vec<Vec<f64>> = null
            .iter()
            .map(|comp| {
                let mut count = vec![0.0; nc];
                for &u in comp {
                    count[global_agg[u as usize] as usize] += 1.0;
                }
                count
            })
            .collect();
        self.coarse_factor(agg, nc, comp_counts)
    }

    /// The coarse space of local systems: each rank cuts its own unknowns into aggregates of
    /// about `aggregate_size` (numbered after those of the ranks before it), the halo learns
    /// its aggregates from the owners; the floating component, when the global problem has
    /// one, is every unknown.
    fn coarse_space_local(&mut self, sys: &ExternalSystem<'_>, floating: bool) -> Coarse {
        let d = sys.dim;
        let m = self.rows.n_own();
        let parts = m.div_ceil(self.aggregate_size.max(1)).max(1);
        let all = self.comm.all_gather(&[parts as f64]);
        let first: usize = all[..self.comm.rank()].iter().map(|v| v[0] as usize).sum();
        let nc: usize = all.iter().map(|v| v[0] as usize).sum();
        let mut pts: Vec<f64> = self
            .own_local
            .iter()
            .flat_map(|&u| sys.positions[u as usize * d..(u as usize + 1) * d].to_vec())
            .collect();
        unwrap_periodic(&mut pts, d, sys.periods);
        let mut aggf = vec![0.0; m + self.rows.halo.len()];
        if m > 0 {
            for (k, part) in rcb(&pts, d, parts).into_iter().enumerate() {
                aggf[k] = (first + part as usize) as f64;
            }
        }
        self.exchange_values(&mut aggf);
        let agg: Vec<u32> = aggf.iter().map(|&a| a as u32).collect();
        let mut comp_counts = Vec::new();
        if floating {
            let mut count = vec![0.0; nc];
            for &a in &agg[..m] {
                count[a as usize] += 1.0;
            }
            comp_counts.push(self.reduce(&count));
        }
        self.coarse_factor(agg, nc, comp_counts)
    }

    /// `A_c = Zᵀ K Z` summed over the ranks' rows, plus `σ 1 1ᵀ` on the aggregates of each
    /// floating component (`comp_counts[k][a]`: its members in aggregate `a`), factorised.
    fn coarse_factor(&mut self, agg: Vec<u32>, nc: usize, comp_counts: Vec<Vec<f64>>) -> Coarse {
        let mut ac = vec![0.0; nc * nc];
        for i in 0..self.rows.n_own() {
            let ai = agg[i] as usize;
            for k in self.rows.offsets[i]..self.rows.offsets[i + 1] {
                ac[ai * nc + agg[self.rows.cols[k] as usize] as usize] += self.rows.values[k];
            }
        }
        let mut ac = self.reduce(&ac);
        let sigma = (0..nc).map(|a| ac[a * nc + a]).sum::<f64>() / nc as f64;
        for count in &comp_counts {
            let on: Vec<usize> = (0..nc).filter(|&a| count[a] > 0.0).collect();
            for &a in &on {
                for &b in &on {
                    ac[a * nc + b] += sigma;
                }
            }
        }
        let chol = DMatrix::from_row_slice(nc, nc, &ac)
            .cholesky()
            .expect("the coarse matrix is positive definite once its null space is fixed");
        Coarse {
            agg,
            n: nc,
            chol,
            comp_counts,
        }
    }

    /// `w = B s` on the own rows: one V-cycle of the own–own block, or the diagonal; for
    /// Schwarz, `s`'s halo is exchanged, the V-cycle runs over own and halo rows, and the
    /// halo's part goes back to its owners (two exchanges).
    fn local(&mut self, s: &[f64], w: &mut [f64]) {
        let m = self.rows.n_own();
        if self.preconditioner == DdPreconditioner::Chebyshev {
            self.chebyshev(s, w);
            return;
        }
        if self.preconditioner == DdPreconditioner::Schwarz {
            let nh = self.rows.halo.len();
            let mut se = vec![0.0; m + nh];
            se[..m].copy_from_slice(&s[..m]);
            self.exchange_values(&mut se);
            for (v, d) in se.iter_mut().zip(&self.overlap_weight) {
                *v *= d;
            }
            let mut we = vec![0.0; m + nh];
            if let Some(amg) = &mut self.amg {
                amg.vcycle(self.rows.ext.view(), &se, &mut we);
            }
            for (v, d) in we.iter_mut().zip(&self.overlap_weight) {
                *v *= d;
            }
            self.exchange_add(&mut we);
            w[..m].copy_from_slice(&we[..m]);
            return;
        }
        match &mut self.amg {
            Some(amg) => amg.vcycle(self.rows.block.view(), &s[..m], &mut w[..m]),
            None => {
                for i in 0..m {
                    w[i] = s[i] / self.diag[i];
                }
            }
        }
    }

    /// `w = p(D⁻¹K) D⁻¹ s` on the own rows: `degree` steps of the Chebyshev iteration for
    /// `K w = s` from `w = 0`, preconditioned by the diagonal, over `[λ/30, λ]` (Saad,
    /// *Iterative Methods*, Alg. 12.1). A fixed polynomial, so `B` is linear and symmetric
    /// (`D^{−½} p(D^{−½}KD^{−½}) D^{−½}`) and positive on the spectrum; every step but the
    /// first exchanges the halo of the update.
    fn chebyshev(&mut self, s: &[f64], w: &mut [f64]) {
        let m = self.rows.n_own();
        let nh = self.rows.halo.len();
        let (hi, lo) = (self.lambda_max, self.lambda_max / 30.0);
        let (theta, delta) = (0.5 * (hi + lo), 0.5 * (hi - lo));
        let sigma = theta / delta;
        let mut rho = 1.0 / sigma;
        let mut r = s[..m].to_vec();
        let mut d = vec![0.0; m + nh];
        for i in 0..m {
            d[i] = r[i] / (theta * self.diag[i]);
            w[i] = d[i];
        }
        let mut t = vec![0.0; m];
        for _ in 1..self.chebyshev_degree.max(1) {
            self.exchange_values(&mut d);
            self.rows.spmv(&d, &mut t);
            for i in 0..m {
                r[i] -= t[i];
            }
            let rho_new = 1.0 / (2.0 * sigma - rho);
            for i in 0..m {
                d[i] = rho_new * rho * d[i] + 2.0 * rho_new / delta * r[i] / self.diag[i];
                w[i] += d[i];
            }
            rho = rho_new;
        }
    }

    /// `z = M r` projected to zero mean on each floating component, returning `r·z` (one
    /// reduction). Without the coarse space `M = B`; with it the symmetric two-level
    /// `M = Q + (I − QA) B (I − AQ)`, `Q = Z A_c⁻¹ Zᵀ`: `y₁ = A_c⁻¹ Zᵀr` (`zr`, reduced with
    /// the residual), `w = B (r − A Z y₁)` (`Z y₁` is known on the halo: no exchange),
    /// one halo exchange of `w` for `t = A w`, one reduction of `[r·w, Σ_C w, Zᵀ t]`,
    /// `y₂ = A_c⁻¹ Zᵀ t`, and `z = w + Z (y₁ − y₂)`.
    fn precondition(
        &mut self,
        r: &[f64],
        zr: &[f64],
        comps: &[(Vec<usize>, f64)],
        z: &mut [f64],
    ) -> f64 {
        let m = self.rows.n_own();
        let Some(c) = self.coarse.take() else {
            self.local(r, z);
            let mut v = vec![dot(r, &z[..m])];
            v.extend(comp_sums(&z[..m], comps));
            let s = self.reduce(&v);
            project_means(&mut z[..m], comps, &s[1..]);
            // r·(z − μ) = r·z: r sums to zero on each component
            return s[0];
        };
        let y1 = c.chol.solve(&DVector::from_column_slice(zr));
        let mut s = vec![0.0; m];
        for i in 0..m {
            let mut az = 0.0;
            for k in self.rows.offsets[i]..self.rows.offsets[i + 1] {
                az += self.rows.values[k] * y1[c.agg[self.rows.cols[k] as usize] as usize];
            }
            s[i] = r[i] - az;
        }
        let mut w = vec![0.0; m + self.rows.halo.len()];
        self.local(&s, &mut w);
        self.exchange_values(&mut w);
        let mut t = vec![0.0; m];
        self.rows.spmv(&w, &mut t);
        let mut v = vec![dot(r, &w[..m])];
        v.extend(comp_sums(&w[..m], comps));
        let split = v.len();
        let mut zt = vec![0.0; c.n];
        for i in 0..m {
            zt[c.agg[i] as usize] += t[i];
        }
        v.extend_from_slice(&zt);
        let red = self.reduce(&v);
        let y2 = c.chol.solve(&DVector::from_column_slice(&red[split..]));
        let dy: Vec<f64> = (0..c.n).map(|a| y1[a] - y2[a]).collect();
        for i in 0..m {
            z[i] = w[i] + dy[c.agg[i] as usize];
        }
        let zr_dy: f64 = zr.iter().zip(&dy).map(|(a, b)| a * b).sum();
        let sums: Vec<f64> = c
            .comp_counts
            .iter()
            .zip(&red[1..split])
            .map(|(count, sw)| sw + count.iter().zip(&dy).map(|(n, d)| n * d).sum::<f64>())
            .collect();
        project_means(&mut z[..m], comps, &sums);
        self.coarse = Some(c);
        red[0] + zr_dy
    }

    fn coarse_restrict(&self, r: &[f64], out: &mut Vec<f64>) {
        if let Some(c) = &self.coarse {
            out.clear();
            out.resize(c.n, 0.0);
            for i in 0..self.rows.n_own() {
                out[c.agg[i] as usize] += r[i];
            }
        }
    }
}

/// Per floating component: own members (local indices) and the global member count.
fn local_null(rows: &LocalRows, null: &[&[u32]]) -> Vec<(Vec<usize>, f64)> {
    null.iter()
        .map(|comp| {
            let own: Vec<usize> = comp
                .iter()
                .filter_map(|g| rows.own.binary_search(g).ok())
                .collect();
            (own, comp.len() as f64)
        })
        .collect()
}

impl<C: Comm> ExternalSolve for DistributedPoisson<C> {
    fn handles_null_space(&self) -> bool {
        self.local.is_some()
    }

    fn solve(&mut self, sys: ExternalSystem<'_>) -> Result<CgInfo, SolveError> {
        // local systems: the floating component is the global problem's (set_local)
        let null_owned: Vec<Vec<u32>> = match self.local {
            Some(_) => Vec::new(),
            None => sys.null.iter().map(|c| c.to_vec()).collect(),
        };
        self.setup(&sys, &null_owned);
        let params = sys.params;
        let m = self.rows.n_own();
        let nh = self.rows.halo.len();
        let (comps, b, mut x) = match self.local.as_ref().map(|l| l.floating) {
            Some(floating) => {
                let count = self.reduce(&[m as f64])[0];
                let comps = if floating {
                    vec![((0..m).collect::<Vec<usize>>(), count)]
                } else {
                    Vec::new()
                };
                let own_local = std::mem::take(&mut self.own_local);
                let pick =
                    |v: &[f64]| -> Vec<f64> { own_local.iter().map(|&u| v[u as usize]).collect() };
                let mut b = pick(sys.b);
                let (w, x0) = (pick(sys.weights), pick(sys.x));
                self.own_local = own_local;
                if floating {
                    // the right side made compatible: zero sum, ω-weighted over all ranks
                    let s = self.reduce(&[b.iter().sum::<f64>(), w.iter().sum::<f64>()]);
                    let mean = s[0] / s[1];
                    for (bi, wi) in b.iter_mut().zip(&w) {
                        *bi -= wi * mean;
                    }
                }
                (comps, b, x0)
            }
            None => (
                local_null(&self.rows, sys.null),
                self.rows.own.iter().map(|&g| sys.b[g as usize]).collect(),
                self.rows.own.iter().map(|&g| sys.x[g as usize]).collect(),
            ),
        };
        x.resize(m + nh, 0.0);
        self.traffic.solves += 1;

        // r = b − K x (x's halo first), projected; ‖b‖, ‖r‖ and Zᵀ r in one reduction
        self.exchange_values(&mut x);
        let mut r = vec![0.0; m];
        self.rows.spmv(&x, &mut r);
        for i in 0..m {
            r[i] = b[i] - r[i];
        }
        let mut zr = Vec::new();
        let (bb, rr) = self.reduce_residual(&mut r, &comps, &mut zr, Some(dot(&b, &b)));
        let (bnorm, mut rnorm) = (bb.sqrt(), rr.sqrt());
        if bnorm == 0.0 {
            for g in sys.x.iter_mut() {
                *g = 0.0;
            }
            return Ok(CgInfo::default());
        }
        let r0 = rnorm;
        let tol = stop_tol(params.abs_tol, params.rel_tol, params.warm_tol, bnorm, r0);
        let mut z = vec![0.0; m];
        let mut p = vec![0.0; m + nh];
        let mut q = vec![0.0; m];
        let mut rz = 0.0;
        let mut iters = 0;
        while rnorm > tol {
            if iters >= params.max_iters {
                self.gather(&x[..m], sys.x);
                return Err(SolveError::NoConvergence {
                    iters,
                    abs_residual: rnorm,
                    rel_residual: rnorm / bnorm,
                });
            }
            let rz_new = self.precondition(&r, &zr, &comps, &mut z);
            if rz_new.is_nan() || rz_new <= 0.0 {
                return Err(SolveError::Backend(format!(
                    "distributed CG: r·Br = {rz_new:e} ≤ 0 at iteration {iters}"
                )));
            }
            let beta = if iters == 0 { 0.0 } else { rz_new / rz };
            rz = rz_new;
            for i in 0..m {
                p[i] = z[i] + beta * p[i];
            }
            self.exchange_values(&mut p);
            self.rows.spmv(&p, &mut q);
            let pq = self.reduce(&[dot(&p[..m], &q)])[0];
            if pq.is_nan() || pq <= 0.0 {
                return Err(SolveError::Backend(format!(
                    "distributed CG: p·Kp = {pq:e} ≤ 0 at iteration {iters}"
                )));
            }
            let alpha = rz / pq;
            for i in 0..m {
                x[i] += alpha * p[i];
                r[i] -= alpha * q[i];
            }
            rnorm = self.reduce_residual(&mut r, &comps, &mut zr, None).1.sqrt();
            iters += 1;
            if !rnorm.is_finite() {
                return Err(SolveError::Backend(format!(
                    "distributed CG: residual became {rnorm} at iteration {iters}"
                )));
            }
        }
        self.traffic.iterations += iters as u64;
        self.last_iters = iters;
        // true residual ‖b − K x‖ (its halo exchange and reduction are counted too)
        self.exchange_values(&mut x);
        self.rows.spmv(&x, &mut q);
        let tr: f64 = (0..m).map(|i| (b[i] - q[i]).powi(2)).sum();
        let true_r = self.reduce(&[tr])[0].sqrt();
        if self.local.as_ref().is_some_and(|l| l.floating) {
            // the constant fixed: zero ω-weighted mean over all ranks
            let w: Vec<f64> = self
                .own_local
                .iter()
                .map(|&u| sys.weights[u as usize])
                .collect();
            let s = self.reduce(&[
                w.iter().zip(&x).map(|(w, x)| w * x).sum::<f64>(),
                w.iter().sum::<f64>(),
            ]);
            let mean = s[0] / s[1];
            for xi in x[..m].iter_mut() {
                *xi -= mean;
            }
        }
        self.gather(&x[..m], sys.x);
        Ok(CgInfo {
            iters,
            abs_residual: true_r,
            rel_residual: true_r / bnorm,
            initial_residual: r0,
            final_residual: rnorm,
            b_norm: bnorm,
        })
    }
}

impl<C: Comm> DistributedPoisson<C> {
    /// One reduction of `[extra?, r·r, Σ_C r per floating component, Zᵀ r]`; then `r` loses
    /// each component's mean (the constants are the null space), `zr` receives the projected
    /// `Zᵀ r`, and the projected `|r|²` follows from `|r − μ1|² = |r|² − n μ²` per component.
    /// Returns `(extra, |r|²)`.
    fn reduce_residual(
        &mut self,
        r: &mut [f64],
        comps: &[(Vec<usize>, f64)],
        zr: &mut Vec<f64>,
        extra: Option<f64>,
    ) -> (f64, f64) {
        let mut v: Vec<f64> = extra.into_iter().collect();
        let e = v.len();
        v.push(dot(r, r));
        v.extend(comp_sums(r, comps));
        let split = v.len();
        self.coarse_restrict(r, zr);
        v.extend_from_slice(zr);
        let s = self.reduce(&v);
        zr.copy_from_slice(&s[split..]);
        let mut rr = s[e];
        for (k, (own, count)) in comps.iter().enumerate() {
            let mean = s[e + 1 + k] / count;
            rr -= count * mean * mean;
            for &i in own {
                r[i] -= mean;
            }
            if let Some(c) = &self.coarse {
                for (z, n) in zr.iter_mut().zip(&c.comp_counts[k]) {
                    *z -= mean * n;
                }
            }
        }
        (if e > 0 { s[0] } else { 0.0 }, rr.max(0.0))
    }

    /// Every rank's own values into the global vector `x` (allgather); local systems: the own
    /// values and the halo's (one exchange) into the local unknowns.
    fn gather(&mut self, own: &[f64], x: &mut [f64]) {
        if self.local.is_some() {
            let m = own.len();
            let mut full = own.to_vec();
            full.resize(m + self.rows.halo.len(), 0.0);
            self.exchange_values(&mut full);
            for (&u, &v) in self.own_local.iter().zip(&full[..m]) {
                x[u as usize] = v;
            }
            for (&u, &v) in self.halo_local.iter().zip(&full[m..]) {
                if u != u32::MAX {
                    x[u as usize] = v;
                }
            }
            return;
        }
        self.traffic.gathered_bytes += 8 * own.len() as u64;
        let all = self.comm.all_gather(own);
        let mut next = vec![0usize; all.len()];
        for (g, &o) in self.owner.iter().enumerate() {
            let o = o as usize;
            x[g] = all[o][next[o]];
            next[o] += 1;
        }
    }
}

/// Sums of `v` over each floating component's own members.
fn comp_sums<'a>(v: &'a [f64], comps: &'a [(Vec<usize>, f64)]) -> impl Iterator<Item = f64> + 'a {
    comps
        .iter()
        .map(move |(own, _)| own.iter().map(|&i| v[i]).sum::<f64>())
}

/// Subtracts each component's mean (`sums` global, over the component's global count).
fn project_means(v: &mut [f64], comps: &[(Vec<usize>, f64)], sums: &[f64]) {
    for ((own, count), s) in comps.iter().zip(sums) {
        let mean = s / count;
        for &i in own {
            v[i] -= mean;
        }
    }
}

fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

/// Shifts the periodic coordinates of `pts` (`d` numbers each) by whole periods to within
/// half a period of their circular mean, so that a set that straddles the periodic boundary
/// (a rank's moving particles, some just wrapped to the far side) is one compact set for
/// the RCB of the coarse aggregates. `periods[a] = 0`: axis `a` is not periodic.
fn unwrap_periodic(pts: &mut [f64], d: usize, periods: &[f64]) {
    for (a, &len) in periods.iter().enumerate().take(d) {
        if !(len > 0.0) || pts.is_empty() {
            continue;
        }
        let (s, c) = pts.chunks_exact(d).fold((0.0, 0.0), |(s, c), p| {
            let t = std::f64::consts::TAU * p[a] / len;
            (s + t.sin(), c + t.cos())
        });
        let centre = s.atan2(c) / std::f64::consts::TAU * len;
        for p in pts.chunks_exact_mut(d) {
            p[a] -= len * ((p[a] - centre) / len).round();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::unwrap_periodic;

    #[test]
    fn a_set_across_the_periodic_boundary_is_unwrapped_into_one_compact_set() {
        // x periodic with period 1, y not: points near x = 0 and x = 1 (one set, wrapped)
        let mut pts = vec![0.02, 0.5, 0.97, 0.4, 0.05, 0.6, 0.99, 0.1];
        unwrap_periodic(&mut pts, 2, &[1.0, 0.0]);
        let xs: Vec<f64> = pts.chunks(2).map(|p| p[0]).collect();
        let (lo, hi) = xs
            .iter()
            .fold((f64::MAX, f64::MIN), |(l, h), &x| (l.min(x), h.max(x)));
        assert!(hi - lo < 0.1, "compact after unwrapping: {xs:?}");
        // whole periods only, and y untouched
        for (p, q) in pts.chunks(2).zip([0.02, 0.97, 0.05, 0.99]) {
            assert!(((p[0] - q) - (p[0] - q).round()).abs() < 1e-12);
        }
        assert_eq!([pts[1], pts[3], pts[5], pts[7]], [0.5, 0.4, 0.6, 0.1]);
    }
}
