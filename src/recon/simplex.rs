//! Exact finish for basis pursuit: a primal simplex for min ||θ||₁ s.t. Aθ = h on the sampled
//! orthonormal DCT, started from the support a short ADMM run found.
//!
//! The basis B = A_S is square (m columns). Pricing needs w = Aᵀy for all n columns, which is one
//! DCT instead of an m x n product; the ratio test is the long-step rule of l1 simplex methods
//! (pass breakpoints while the objective still decreases), which cuts the number of pivots.
//! Basis changes are kept as an eta file on top of one dense LU and refactored periodically.
use faer::linalg::solvers::{PartialPivLu, Solve};
use faer::{Col, Mat};

use super::dct::Dct;

/// Result of a certified simplex finish.
pub struct SimplexResult {
    pub theta: Vec<f64>,
    /// hᵀy of the certifying dual point (equals ||θ||₁ up to rounding).
    pub dual_objective: f64,
    pub pivots: usize,
    /// max |Aᵀy| of the certificate (≤ 1 + tol).
    pub dual_inf_norm: f64,
}

/// Basis B = A_S as one dense LU (faer: ~2x nalgebra's speed here, and a transpose solve)
/// plus an eta file of the pivots since.
struct Basis {
    lu: PartialPivLu<f64>,
    /// Eta file: (position r, column d) for each pivot since the last factorization.
    etas: Vec<(usize, Col<f64>)>,
}

impl Basis {
    fn factor(dct: &Dct, idx: &[usize], support: &[usize]) -> Option<Self> {
        let m = idx.len();
        let b = Mat::<f64>::from_fn(m, m, |r, c| dct.basis(idx[r], support[c]));
        let lu = b.partial_piv_lu();
        // Reject (near-)singular bases: a tiny pivot in U means a column nearly dependent.
        let u = lu.U();
        let (mut dmax, mut dmin) = (0.0f64, f64::INFINITY);
        for i in 0..m {
            dmax = dmax.max(u[(i, i)].abs());
            dmin = dmin.min(u[(i, i)].abs());
        }
        if dmin.is_nan() || dmin <= 1e-12 * dmax {
            return None;
        }
        Some(Self {
            lu,
            etas: Vec::new(),
        })
    }

    /// x = B⁻¹ b
    fn ftran(&self, b: &Col<f64>) -> Col<f64> {
        let mut x = self.lu.solve(b);
        for (r, d) in &self.etas {
            let xr = x[*r] / d[*r];
            for i in 0..x.nrows() {
                x[i] -= d[i] * xr;
            }
            x[*r] = xr;
        }
        x
    }

    /// y = B⁻ᵀ c
    fn btran(&self, c: &Col<f64>) -> Col<f64> {
        let mut c = c.clone();
        for (r, d) in self.etas.iter().rev() {
            let mut dot = 0.0;
            for i in 0..c.nrows() {
                if i != *r {
                    dot += d[i] * c[i];
                }
            }
            c[*r] = (c[*r] - dot) / d[*r];
        }
        self.lu.solve_transpose(&c)
    }
}

fn finite(v: &Col<f64>) -> bool {
    (0..v.nrows()).all(|i| v[i].is_finite())
}

fn amax(v: &Col<f64>) -> f64 {
    (0..v.nrows()).map(|i| v[i].abs()).fold(0.0, f64::max)
}

fn sign(v: f64) -> f64 {
    if v >= 0.0 {
        1.0
    } else {
        -1.0
    }
}

/// Runs the simplex from `support` (m distinct columns). `None` when the start basis is singular
/// or the pivot budget runs out without a certificate.
pub fn finish(
    dct: &mut Dct,
    idx: &[usize],
    h: &[f64],
    mut support: Vec<usize>,
    max_pivots: usize,
    tol: f64,
) -> Option<SimplexResult> {
    let n = dct.len();
    let m = idx.len();
    let hv = Col::<f64>::from_fn(m, |r| h[r]);
    let scale = amax(&hv).max(1e-300);
    let mut basis = Basis::factor(dct, idx, &support)?;
    let mut theta_s = basis.ftran(&hv);
    let mut in_basis = vec![false; n];
    for &k in &support {
        in_basis[k] = true;
    }
    let mut w = vec![0.0; n];
    let mut col = Col::<f64>::zeros(m);
    let zero_tol = 1e-13 * scale;
    for pivots in 0..=max_pivots {
        let signs = Col::<f64>::from_fn(m, |r| sign(theta_s[r]));
        let y = basis.btran(&signs);
        if !finite(&y) {
            return None;
        }
        w.iter_mut().for_each(|v| *v = 0.0);
        for (r, &i) in idx.iter().enumerate() {
            w[i] = y[r];
        }
        dct.forward(&mut w);
        // Dantzig pricing over the non-basic columns.
        let (mut j, mut best) = (usize::MAX, 1.0 + tol);
        for (k, &wk) in w.iter().enumerate() {
            if !in_basis[k] && wk.abs() > best {
                best = wk.abs();
                j = k;
            }
        }
        if j == usize::MAX {
            return certify(dct, idx, &hv, &support, pivots, tol);
        }
        if pivots == max_pivots {
            return None;
        }
        let sj = sign(w[j]);
        for (r, &i) in idx.iter().enumerate() {
            col[r] = dct.basis(i, j);
        }
        let d = basis.ftran(&col);
        // θ_S(t) = θ_S - t·sj·d for the entering θ_j = sj·t; f'(0+) = 1 - |w_j| on a non-degenerate basis.
        let mut slope = 1.0;
        let mut breaks: Vec<(f64, usize)> = Vec::new();
        let mut zero_basic: Option<usize> = None;
        for r in 0..m {
            let dir = sj * d[r];
            if theta_s[r].abs() <= zero_tol {
                // A zero basic variable only adds |dir| to the slope; it may leave at t = 0.
                slope += dir.abs();
                if zero_basic.is_none_or(|q| dir.abs() > d[q].abs()) && dir.abs() > 1e-12 {
                    zero_basic = Some(r);
                }
            } else {
                slope -= sign(theta_s[r]) * dir;
                let t = theta_s[r] / dir;
                if t > 0.0 {
                    breaks.push((t, r));
                }
            }
        }
        let leave = if slope >= 0.0 {
            // Degenerate: no descent along this edge; swap a zero basic variable out at t = 0.
            zero_basic.map(|r| (0.0, r))
        } else {
            breaks.sort_unstable_by(|a, b| {
                a.0.partial_cmp(&b.0).unwrap_or(std::cmp::Ordering::Equal)
            });
            let mut found = None;
            for &(t, r) in &breaks {
                slope += 2.0 * d[r].abs();
                if slope >= 0.0 {
                    found = Some((t, r));
                    break;
                }
            }
            found
        };
        let (t, r) = leave?;
        if d[r].abs() < 1e-10 * amax(&d) {
            return None;
        }
        for q in 0..m {
            theta_s[q] -= t * sj * d[q];
        }
        theta_s[r] = sj * t;
        in_basis[support[r]] = false;
        in_basis[j] = true;
        support[r] = j;
        basis.etas.push((r, d));
        if basis.etas.len() >= 64 {
            basis = Basis::factor(dct, idx, &support)?;
            theta_s = basis.ftran(&hv);
        }
    }
    None
}

/// Recomputes θ and y from a fresh factorization and checks the certificate.
fn certify(
    dct: &mut Dct,
    idx: &[usize],
    hv: &Col<f64>,
    support: &[usize],
    pivots: usize,
    tol: f64,
) -> Option<SimplexResult> {
    let n = dct.len();
    let m = idx.len();
    let basis = Basis::factor(dct, idx, support)?;
    let theta_s = basis.ftran(hv);
    let y = basis.btran(&Col::<f64>::from_fn(m, |r| sign(theta_s[r])));
    if !finite(&theta_s) || !finite(&y) {
        return None;
    }
    let mut w = vec![0.0; n];
    for (r, &i) in idx.iter().enumerate() {
        w[i] = y[r];
    }
    dct.forward(&mut w);
    let inf = w.iter().map(|v| v.abs()).fold(0.0, f64::max);
    if inf > 1.0 + tol {
        return None;
    }
    let mut theta = vec![0.0; n];
    for (c, &k) in support.iter().enumerate() {
        theta[k] = theta_s[c];
    }
    let dual_objective = (0..m).map(|r| hv[r] * y[r]).sum();
    Some(SimplexResult {
        theta,
        dual_objective,
        pivots,
        dual_inf_norm: inf,
    })
}
