//! The convective term `−(u·∇h)u` of the Eulerian frame, integrated explicitly.
//!
//! `N = (u·∇h)u` with the difference gradient ([`grad_vec_into`]) or, with the consistent
//! operators, the least-squares gradient of the wall variant of
//! [`crate::consistent::LsOperators`] (exact on quadratic velocities that take the wall value;
//! the difference gradient is off by `O(1)` on disordered particles); forward Euler adds `−Nⁿ` to
//! the predictor, second-order Adams–Bashforth with variable steps adds
//! `−((1 + r/2) Nⁿ − (r/2) Nⁿ⁻¹)`, `r = Δtⁿ/Δtⁿ⁻¹` (forward Euler on the first step).

use crate::consistent::LsOperators;
use crate::neighbors::NeighborList;
use crate::operators::grad_vec_into;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Time integration of the explicit terms of the predictor (convection in the Eulerian frame).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Integrator {
    /// Forward Euler (first order).
    Euler,
    /// Second-order Adams–Bashforth with variable-step coefficients (forward Euler on the first
    /// step). With Crank–Nicolson viscosity (`viscous_theta = ½`) and an incremental pressure
    /// scheme the step is second order in time.
    #[default]
    Ab2,
}

impl std::str::FromStr for Integrator {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s.trim().to_ascii_lowercase().as_str() {
            "euler" => Ok(Integrator::Euler),
            "ab2" => Ok(Integrator::Ab2),
            _ => Err(format!("unknown integrator '{s}': expected euler or ab2")),
        }
    }
}

/// The convective term's state between steps: the previous `N` and its `Δt` (for AB2), and the
/// velocity-gradient scratch.
#[derive(Clone, Debug, Default)]
pub struct Convection<const D: usize> {
    prev: Option<(Vec<[f64; D]>, f64)>,
    grad: Vec<[[f64; D]; D]>,
}

impl<const D: usize> Convection<D> {
    /// No previous step (the first step is forward Euler).
    pub fn new() -> Self {
        Convection {
            prev: None,
            grad: Vec::new(),
        }
    }

    /// Writes the convective acceleration `−N` (Euler) or `−((1 + r/2) Nⁿ − (r/2) Nⁿ⁻¹)` (AB2)
    /// of velocities `u` (ghosts already filled) into `out`, and keeps `Nⁿ` and `dt` for the
    /// next step. AB2 falls back to Euler when there is no previous step or the particle count
    /// changed. With `least_squares` (coefficients for the configuration of `nl`, e.g.
    /// [`crate::projection::ProjectionStep::velocity_least_squares`]) the gradient is the
    /// least-squares one, otherwise the difference gradient.
    #[allow(clippy::too_many_arguments)]
    pub fn accel_into(
        &mut self,
        nl: &NeighborList<D>,
        vol: &[f64],
        least_squares: Option<&LsOperators<D>>,
        u: &[[f64; D]],
        integrator: Integrator,
        dt: f64,
        out: &mut Vec<[f64; D]>,
    ) {
        let n = u.len();
        self.grad.resize(n, [[0.0; D]; D]);
        if let Some(ls) = least_squares {
            ls.grad_vec_into(nl, u, &mut self.grad);
        } else {
            grad_vec_into(nl, vol, u, &mut self.grad);
        }
        let mut conv: Vec<[f64; D]> = vec![[0.0; D]; n];
        conv.par_iter_mut()
            .zip(self.grad.par_iter())
            .zip(u.par_iter())
            .for_each(|((a, g), ui)| {
                *a = std::array::from_fn(|k| (0..D).map(|b| g[k][b] * ui[b]).sum::<f64>());
            });
        out.resize(n, [0.0; D]);
        match (&self.prev, integrator) {
            (Some((prev, dt_prev)), Integrator::Ab2) if prev.len() == n => {
                let r = dt / dt_prev;
                let (c1, c0) = (1.0 + 0.5 * r, 0.5 * r);
                for i in 0..n {
                    out[i] = std::array::from_fn(|k| -(c1 * conv[i][k] - c0 * prev[i][k]));
                }
            }
            _ => {
                for i in 0..n {
                    out[i] = conv[i].map(|v| -v);
                }
            }
        }
        self.prev = Some((conv, dt));
    }
}
