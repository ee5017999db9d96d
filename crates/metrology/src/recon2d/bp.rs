//! 2D DCT basis pursuit denoising, for comparison with the physics model:
//!     min ‖c‖₁  s.t.  ‖A c − b‖₂ ≤ ε,   A = the samples of the 2D orthonormal inverse DCT,
//! c the ny × nx coefficients (x fastest). The 2D DCT is separable: rows then columns through
//! the 1D transforms of `recon::dct`, never a matrix. A·Aᵀ = I, so the projection onto the
//! feasible set is closed form (one inverse and one forward 2D DCT), and Douglas–Rachford
//! splitting (ADMM on the same split) needs nothing else. A dual point comes from the splitting's
//! multiplier, scaled so that ‖Aᵀλ‖∞ ≤ 1: ‖c‖₁ − (bᵀλ − ε‖λ‖₂) bounds the distance to the
//! optimum (weak duality), and the solve stops when that certified gap is below the tolerance,
//! relative to ‖c‖₁, or at the iteration cap (the report says which).
use serde::Serialize;

use super::Grid2;
use crate::recon::dct::Dct;

/// Stop when the certified duality gap is below this fraction of ‖c‖₁.
pub const GAP_TOL: f64 = 1e-3;
/// Iterations between duality-gap checks (a check costs no extra transform, only O(n) sums).
const GAP_EVERY: usize = 10;
/// Soft threshold relative to ‖Aᵀb‖∞ (the 1D denoising solver's fraction).
const THRESHOLD_FRACTION: f64 = 1.0 / 40.0;

/// The separable 2D orthonormal DCT on an nx × ny grid (x fastest).
pub struct Dct2 {
    nx: usize,
    ny: usize,
    rows: Dct,
    cols: Dct,
    col: Vec<f64>,
}

impl Dct2 {
    pub fn new(nx: usize, ny: usize) -> Self {
        Self {
            nx,
            ny,
            rows: Dct::new(nx.max(2)),
            cols: Dct::new(ny.max(2)),
            col: vec![0.0; ny],
        }
    }
    fn pass(&mut self, v: &mut [f64], inverse: bool) {
        let (nx, ny) = (self.nx, self.ny);
        if nx >= 2 {
            for row in v.chunks_exact_mut(nx) {
                if inverse {
                    self.rows.inverse(row);
                } else {
                    self.rows.forward(row);
                }
            }
        }
        if ny >= 2 {
            for i in 0..nx {
                for j in 0..ny {
                    self.col[j] = v[j * nx + i];
                }
                if inverse {
                    self.cols.inverse(&mut self.col);
                } else {
                    self.cols.forward(&mut self.col);
                }
                for j in 0..ny {
                    v[j * nx + i] = self.col[j];
                }
            }
        }
    }
    /// Coefficients → map, in place.
    pub fn inverse(&mut self, v: &mut [f64]) {
        self.pass(v, true);
    }
    /// Map → coefficients, in place.
    pub fn forward(&mut self, v: &mut [f64]) {
        self.pass(v, false);
    }
}

/// One component's solve.
#[derive(Debug, Clone, Serialize)]
pub struct BpSolve {
    pub iterations: usize,
    /// ‖c‖₁ of the returned (feasible) coefficients and the dual bound below the optimum.
    pub l1: f64,
    pub dual: f64,
    /// (‖c‖₁ − dual) / ‖c‖₁: the certified relative distance to the optimum.
    pub rel_gap: f64,
    pub epsilon_um: f64,
    /// Whether the gap reached [`GAP_TOL`] before the iteration cap.
    pub converged: bool,
}

/// Solves for one component: the map at every grid point (x fastest) and the solve figures.
/// `idx` are flat grid indices (distinct), `b` the samples there, `epsilon` the residual bound
/// (µm, or µrad for θ).
pub fn solve(
    dct: &mut Dct2,
    idx: &[usize],
    b: &[f64],
    epsilon: f64,
    max_iter: usize,
) -> (Vec<f64>, BpSolve) {
    let n = dct.nx * dct.ny;
    // Aᵀb: the minimum-energy solution, whose largest coefficient sets the threshold's scale.
    let mut z = vec![0.0; n];
    for (&i, &v) in idx.iter().zip(b) {
        z[i] = v;
    }
    dct.forward(&mut z);
    let scale = z.iter().fold(0.0f64, |a, v| a.max(v.abs()));
    if scale == 0.0 {
        let zero = BpSolve {
            iterations: 0,
            l1: 0.0,
            dual: 0.0,
            rel_gap: 0.0,
            epsilon_um: epsilon,
            converged: true,
        };
        return (vec![0.0; n], zero);
    }
    let t = THRESHOLD_FRACTION * scale;
    let mut x = vec![0.0; n];
    let mut work = vec![0.0; n];
    let mut report = BpSolve {
        iterations: 0,
        l1: f64::INFINITY,
        dual: f64::NEG_INFINITY,
        rel_gap: f64::INFINITY,
        epsilon_um: epsilon,
        converged: false,
    };
    let mut best: Option<Vec<f64>> = None;
    for it in 1..=max_iter.max(1) {
        report.iterations = it;
        // x = P_C(z): z − Aᵀ(r·(1 − ε/‖r‖)) when the residual r = Az − b is outside the ball.
        work.copy_from_slice(&z);
        dct.inverse(&mut work);
        let mut q: Vec<f64> = idx.iter().zip(b).map(|(&i, &v)| work[i] - v).collect();
        let rn = q.iter().map(|v| v * v).sum::<f64>().sqrt();
        let shrink = if rn > epsilon {
            1.0 - epsilon / rn
        } else {
            0.0
        };
        for v in &mut q {
            *v *= shrink;
        }
        work.fill(0.0);
        if shrink > 0.0 {
            for (&i, &v) in idx.iter().zip(&q) {
                work[i] = v;
            }
            dct.forward(&mut work);
        }
        // work = Aᵀq = z − x.
        for ((xv, &zv), &w) in x.iter_mut().zip(&z).zip(&work) {
            *xv = zv - w;
        }
        if it % GAP_EVERY == 0 || it == max_iter {
            // The subgradient (x − z)/t = −Aᵀq/t at the fixed point: λ = −q/t, scaled into
            // the dual's feasible set ‖Aᵀλ‖∞ ≤ 1.
            let inf = work.iter().fold(0.0f64, |a, v| a.max(v.abs())) / t;
            let s = -1.0 / (t * inf.max(1.0));
            let btl: f64 = b.iter().zip(&q).map(|(a, c)| a * c).sum::<f64>() * s;
            let ln = q.iter().map(|v| v * v).sum::<f64>().sqrt() * s.abs();
            let dual = btl - epsilon * ln;
            let l1: f64 = x.iter().map(|v| v.abs()).sum();
            let gap = ((l1 - dual) / l1.max(1e-300)).max(0.0);
            if gap < report.rel_gap {
                report.rel_gap = gap;
                report.l1 = l1;
                report.dual = dual;
                best = Some(x.clone());
            }
            if gap <= GAP_TOL {
                report.converged = true;
                break;
            }
        }
        // z += soft(2x − z, t) − x.
        for (zv, &xv) in z.iter_mut().zip(&x) {
            let v = 2.0 * xv - *zv;
            let y = v.signum() * (v.abs() - t).max(0.0);
            *zv += y - xv;
        }
    }
    let mut c = best.unwrap_or(x);
    dct.inverse(&mut c);
    (c, report)
}

/// The flat grid index (x fastest) of each sample.
pub fn flat_indices(g: &Grid2, ix: &[usize], iy: &[usize]) -> Vec<usize> {
    ix.iter().zip(iy).map(|(&i, &j)| j * g.x.n + i).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_2d_transform_is_orthonormal_and_inverts() {
        let mut d = Dct2::new(7, 5);
        let v: Vec<f64> = (0..35).map(|k| ((k * 37 % 11) as f64) - 5.0).collect();
        let mut c = v.clone();
        d.forward(&mut c);
        let e0: f64 = v.iter().map(|a| a * a).sum();
        let e1: f64 = c.iter().map(|a| a * a).sum();
        assert!((e0 - e1).abs() < 1e-9 * e0);
        d.inverse(&mut c);
        assert!(v.iter().zip(&c).all(|(a, b)| (a - b).abs() < 1e-12));
    }

    #[test]
    fn a_sparse_map_is_recovered_with_a_certified_gap() {
        // Three 2D cosines (a DCT-sparse map) from 30 % of a 40 × 24 grid, noise-free.
        let (nx, ny) = (40, 24);
        let mut d = Dct2::new(nx, ny);
        let mut coef = vec![0.0; nx * ny];
        coef[3] = 1.0;
        coef[5 * nx + 1] = -0.7;
        coef[2 * nx + 9] = 0.4;
        let mut map = coef.clone();
        d.inverse(&mut map);
        let idx: Vec<usize> = (0..nx * ny).filter(|k| (k * 7919) % 10 < 3).collect();
        let b: Vec<f64> = idx.iter().map(|&i| map[i]).collect();
        let (got, r) = solve(&mut d, &idx, &b, 1e-6, 5000);
        assert!(r.converged, "{r:?}");
        assert!(r.dual <= r.l1 && r.rel_gap <= GAP_TOL);
        let worst = got
            .iter()
            .zip(&map)
            .fold(0.0f64, |a, (g, t)| a.max((g - t).abs()));
        assert!(worst < 0.02, "max error {worst}");
    }
}
