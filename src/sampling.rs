//! Sampling particle fields at arbitrary points: moving least squares with a linear basis.
//!
//! At a point `y`, the values `f_j` of the particles within `h` are fitted by
//! `a + b·(x_j − y)` in the weighted least-squares sense (weights `w_h(|x_j − y|)`); `a` is the
//! sample. The fit reproduces linear fields exactly, unlike the Shepard average; where fewer
//! than `D + 1` particles are in range, or they are degenerate, the Shepard average is used.

use crate::kernel::Kernel;
use crate::neighbors::Periodicity;
use kiddo::{ImmutableKdTree, SquaredEuclidean};
use nalgebra::{DMatrix, DVector};
use rayon::prelude::*;

/// A sampler over fixed particle positions.
pub struct Sampler<'a, const D: usize> {
    x: &'a [[f64; D]],
    tree: ImmutableKdTree<f64, D>,
    kernel: Kernel<D>,
    periodic: Periodicity<D>,
}

impl<'a, const D: usize> Sampler<'a, D> {
    /// A sampler over the positions `x` (all roles: include ghosts so walls are seen), with
    /// support radius `kernel.h()`.
    pub fn new(x: &'a [[f64; D]], kernel: Kernel<D>, periodic: Periodicity<D>) -> Self {
        let wrapped: Vec<[f64; D]> = x
            .iter()
            .map(|p| {
                let mut q = *p;
                periodic.wrap(&mut q);
                q
            })
            .collect();
        let tree = ImmutableKdTree::new_from_slice(&wrapped).expect("finite positions");
        Sampler {
            x,
            tree,
            kernel,
            periodic,
        }
    }

    fn neighbours(&self, y: &[f64; D]) -> Vec<(usize, [f64; D], f64)> {
        let h = self.kernel.h();
        let mut out = Vec::new();
        let mut shifts = vec![[0.0; D]];
        for a in 0..D {
            let l = self.periodic.len[a];
            if l > 0.0 {
                let base = shifts.clone();
                for s in base {
                    for e in [-l, l] {
                        let mut t = s;
                        t[a] = e;
                        shifts.push(t);
                    }
                }
            }
        }
        let mut yw = *y;
        self.periodic.wrap(&mut yw);
        for s in shifts {
            let q: [f64; D] = std::array::from_fn(|a| yw[a] + s[a]);
            self.tree
                .query(&q)
                .within::<SquaredEuclidean<f64>>(h * h)
                .unsorted()
                .visit(|nb| {
                    if nb.distance < h * h {
                        let j = nb.item as usize;
                        let mut d: [f64; D] = std::array::from_fn(|a| self.x[j][a] - y[a]);
                        self.periodic.min_image(&mut d);
                        out.push((j, d, self.kernel.w_h(nb.distance.sqrt())));
                    }
                });
        }
        out.sort_by_key(|e| e.0);
        out.dedup_by_key(|e| e.0);
        out
    }

    /// Samples the `C`-component field `f` at the points `ys`.
    pub fn sample<const C: usize>(&self, f: &[[f64; C]], ys: &[[f64; D]]) -> Vec<[f64; C]> {
        ys.par_iter()
            .map(|y| {
                let nb = self.neighbours(y);
                let wsum: f64 = nb.iter().map(|e| e.2).sum();
                let shepard = || -> [f64; C] {
                    if wsum > 0.0 {
                        std::array::from_fn(|c| {
                            nb.iter().map(|e| e.2 * f[e.0][c]).sum::<f64>() / wsum
                        })
                    } else {
                        [f64::NAN; C]
                    }
                };
                if nb.len() < 2 * (D + 1) {
                    return shepard();
                }
                let m = D + 1;
                let mut a = DMatrix::<f64>::zeros(m, m);
                let mut rhs = DMatrix::<f64>::zeros(m, C);
                let hinv = 1.0 / self.kernel.h();
                for (j, d, w) in &nb {
                    let mut p = DVector::<f64>::zeros(m);
                    p[0] = 1.0;
                    for k in 0..D {
                        p[k + 1] = d[k] * hinv;
                    }
                    a += *w * &p * p.transpose();
                    for c in 0..C {
                        for r in 0..m {
                            rhs[(r, c)] += w * p[r] * f[*j][c];
                        }
                    }
                }
                match a.clone().cholesky() {
                    Some(ch) => {
                        let sol = ch.solve(&rhs);
                        let out: [f64; C] = std::array::from_fn(|c| sol[(0, c)]);
                        if out.iter().all(|v| v.is_finite()) {
                            out
                        } else {
                            shepard()
                        }
                    }
                    None => shepard(),
                }
            })
            .collect()
    }
}
