//! Particle state owned by the caller: positions, velocities, pressures, volumes and roles.
//!
//! Structure of arrays over `[f64; D]`. Nothing here is solver scratch: the projection step keeps
//! its own working memory ([`crate::projection::ProjectionStep`]), so the same `Particles` can be
//! handed to the projection from any particle loop.

use crate::error::InputError;
use crate::math::is_finite;

/// What a particle is for the discrete Poisson problem and the operators.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Role {
    /// A particle of `Ω`: its velocity evolves and its pressure is an unknown of the Poisson problem.
    Fluid,
    /// A particle of the band `Γ_H` with prescribed pressure (increment) zero: the paper's
    /// Dirichlet band, used for free surfaces and open boundaries. Its velocity is given data.
    Dirichlet,
    /// A mirror image of the fluid particle `source` across the walls in the bit set `walls`
    /// (bit `k` = wall `k` of [`crate::boundary::Walls`]). All its fields are derived from the
    /// source: scalars are copied (Neumann), vectors follow the wall rule.
    Ghost {
        /// Index of the fluid particle this ghost mirrors.
        source: u32,
        /// Bit set of the walls it is reflected across (one bit: a wall image; two: a corner).
        walls: u8,
    },
}

impl Role {
    /// True for [`Role::Fluid`].
    #[inline]
    pub fn is_fluid(&self) -> bool {
        matches!(self, Role::Fluid)
    }

    /// True for a particle of `Ω_H` — [`Role::Fluid`] or [`Role::Dirichlet`] — rather than a
    /// ghost image: what a ghost may mirror.
    #[inline]
    pub fn is_real(&self) -> bool {
        !matches!(self, Role::Ghost { .. })
    }
}

/// The particle state of a run.
#[derive(Clone, Debug, Default)]
pub struct Particles<const D: usize> {
    /// Positions `x_i`.
    pub x: Vec<[f64; D]>,
    /// Velocities `u_i`.
    pub u: Vec<[f64; D]>,
    /// Pressures `p_i`.
    pub p: Vec<f64>,
    /// Volumes `ω_i > 0`.
    pub vol: Vec<f64>,
    /// Roles.
    pub role: Vec<Role>,
}

impl<const D: usize> Particles<D> {
    /// No particles.
    pub fn new() -> Self {
        Particles {
            x: Vec::new(),
            u: Vec::new(),
            p: Vec::new(),
            vol: Vec::new(),
            role: Vec::new(),
        }
    }

    /// Number of particles (all roles).
    pub fn len(&self) -> usize {
        self.x.len()
    }

    /// True when there are no particles.
    pub fn is_empty(&self) -> bool {
        self.x.is_empty()
    }

    /// Appends one particle.
    pub fn push(&mut self, x: [f64; D], u: [f64; D], p: f64, vol: f64, role: Role) {
        self.x.push(x);
        self.u.push(u);
        self.p.push(p);
        self.vol.push(vol);
        self.role.push(role);
    }

    /// Removes every particle from index `n` on (used to drop and regenerate ghosts).
    pub fn truncate(&mut self, n: usize) {
        self.x.truncate(n);
        self.u.truncate(n);
        self.p.truncate(n);
        self.vol.truncate(n);
        self.role.truncate(n);
    }

    /// Number of fluid particles.
    pub fn n_fluid(&self) -> usize {
        self.role.iter().filter(|r| r.is_fluid()).count()
    }

    /// The columns of [`Self::fluid_csv`]: `x, y, u, v, p` in 2D, `x, y, z, u, v, w, p` in 3D.
    pub fn fluid_csv_columns() -> Vec<&'static str> {
        const AXES: [&str; 3] = ["x", "y", "z"];
        const VELS: [&str; 3] = ["u", "v", "w"];
        AXES[..D]
            .iter()
            .chain(&VELS[..D])
            .copied()
            .chain(["p"])
            .collect()
    }

    /// The fluid particles as CSV text: a header line (`x,y,u,v,p` in 2D, `x,y,z,u,v,w,p` in
    /// 3D), then one row per fluid particle in index order, numbers in their shortest exact
    /// form (what the examples' `--particles-csv` writes, for scripts outside gpm).
    pub fn fluid_csv(&self) -> String {
        use std::fmt::Write;
        let mut text = Self::fluid_csv_columns().join(",");
        text.push('\n');
        for i in (0..self.len()).filter(|&i| self.role[i].is_fluid()) {
            for v in self.x[i].iter().chain(&self.u[i]) {
                let _ = write!(text, "{v},");
            }
            let _ = writeln!(text, "{}", self.p[i]);
        }
        text
    }

    /// Largest speed `max |u_i|` over the fluid particles (0 without any).
    pub fn max_fluid_speed(&self) -> f64 {
        self.u
            .iter()
            .zip(&self.role)
            .filter(|(_, r)| r.is_fluid())
            .map(|(u, _)| u.iter().map(|v| v * v).sum::<f64>())
            .fold(0.0f64, f64::max)
            .sqrt()
    }

    /// Largest speed `max |u_i|` over the fluid and band particles (0 without any): the speed
    /// the time step must resolve when the band moves (a free surface).
    pub fn max_speed(&self) -> f64 {
        self.u
            .iter()
            .zip(&self.role)
            .filter(|(_, r)| r.is_real())
            .map(|(u, _)| u.iter().map(|v| v * v).sum::<f64>())
            .fold(0.0f64, f64::max)
            .sqrt()
    }

    /// Checks that the arrays agree in length, that positions, velocities, pressures and volumes
    /// are finite, that volumes are positive and that every ghost mirrors a fluid particle.
    /// The error names the first offending particle.
    pub fn validate(&self) -> Result<(), InputError> {
        let n = self.x.len();
        for (name, len) in [
            ("u", self.u.len()),
            ("p", self.p.len()),
            ("vol", self.vol.len()),
            ("role", self.role.len()),
        ] {
            if len != n {
                return Err(InputError::LengthMismatch {
                    field: name,
                    len,
                    expected: n,
                });
            }
        }
        for i in 0..n {
            if !is_finite(&self.x[i]) {
                return Err(InputError::NonFinite {
                    field: "position",
                    particle: i,
                });
            }
            if !is_finite(&self.u[i]) {
                return Err(InputError::NonFinite {
                    field: "velocity",
                    particle: i,
                });
            }
            if !self.p[i].is_finite() {
                return Err(InputError::NonFinite {
                    field: "pressure",
                    particle: i,
                });
            }
            if !(self.vol[i] > 0.0) || !self.vol[i].is_finite() {
                return Err(InputError::BadVolume {
                    particle: i,
                    value: self.vol[i],
                });
            }
            if let Role::Ghost { source, .. } = self.role[i] {
                let s = source as usize;
                if s >= n || !self.role[s].is_real() {
                    return Err(InputError::BadGhostSource {
                        particle: i,
                        source_particle: s,
                    });
                }
            }
        }
        Ok(())
    }
}
