//! Refinement of a basis's primal and dual against the f64 transforms, and the optimality
//! certificate that every result must pass.
use faer::Col;

use super::basis::Anchor;
use super::restricted::{finite, sign, Restricted};
use crate::recon::dct::Dct;

/// Result of a certified simplex finish.
pub struct SimplexResult {
    pub theta: Vec<f64>,
    /// Ψθ, the curve on the whole grid (formed to check the samples).
    pub signal: Vec<f64>,
    /// hᵀy of the certifying dual point (equals ||θ||₁ up to rounding).
    pub dual_objective: f64,
    pub pivots: usize,
    /// max |Aᵀy| of the certificate (≤ 1 + tol).
    pub dual_inf_norm: f64,
}

/// Iterative refinement of a basis's primal and dual in f64: residuals through the transforms,
/// corrections through the anchor B₀ (any [`Anchor`]) and the restricted basis (A_S = B₀·B_r).
pub(super) struct Refine<'a, B: Anchor> {
    pub(super) basis: &'a B,
    pub(super) lp: &'a Restricted,
}

/// Refinement rounds (each gains ~4 digits at the anchor's κ·ε ≈ 1e-4).
const REFINE_MAX: usize = 6;

/// Residual (relative to max |h| for the primal, absolute on sign θ for the dual) at which
/// refinement stops: 100x inside [`verify`]'s 1e-10. The f64 Gram anchor's basic solutions start at
/// 1e-14 to 1e-12 (measured at m = 600), so they are certified as they are instead of paying a
/// correction (a Gram solve and two transforms per side) for digits no check or curve uses.
const REFINED: f64 = 1e-12;

impl<B: Anchor> Refine<'_, B> {
    /// θ_S with A_S θ_S = h to rounding: θ_S += B_r⁻¹B₀⁻¹(h − A_S θ_S). Returns the signal Ψθ of
    /// the final θ_S (the last residual's transform, for [`verify`] and the caller's curve) and
    /// its largest sample residual.
    pub(super) fn primal(
        &self,
        dct: &mut Dct,
        idx: &[usize],
        h: &[f64],
        support: &[usize],
        theta_s: &mut Col<f64>,
    ) -> (Vec<f64>, f64) {
        let (n, m) = (dct.len(), idx.len());
        let scale = h.iter().map(|v| v.abs()).fold(0.0, f64::max).max(1e-300);
        let (mut di, mut dc) = (Col::<f64>::zeros(m), Col::<f64>::zeros(0));
        let mut signal = vec![0.0; n];
        for round in 0..=REFINE_MAX {
            signal_of(dct, support, theta_s, &mut signal);
            let mut r = Col::<f64>::from_fn(m, |i| h[i] - signal[idx[i]]);
            let worst = (0..m).map(|i| r[i].abs()).fold(0.0, f64::max);
            if worst <= REFINED * scale || round == REFINE_MAX || worst.is_nan() {
                return (signal, worst);
            }
            self.basis.solve(dct, idx, &mut r);
            self.lp.ftran(r.as_ref(), &mut di, &mut dc);
            self.apply(&di, &dc, theta_s);
        }
        unreachable!("the last round returns")
    }

    /// y with A_Sᵀ y = sign(θ_S) to rounding: y += B₀⁻ᵀB_r⁻ᵀ(sign − A_Sᵀy). `w` holds Aᵀy on entry
    /// (the caller has just priced with it) and on return.
    pub(super) fn dual(
        &self,
        dct: &mut Dct,
        idx: &[usize],
        support: &[usize],
        theta_s: &Col<f64>,
        y: &mut Col<f64>,
        w: &mut [f64],
    ) {
        let m = idx.len();
        let lp = self.lp;
        for round in 0..=REFINE_MAX {
            if round > 0 {
                dct.adjoint(idx, |r| y[r], w);
            }
            if round == REFINE_MAX {
                break;
            }
            // Residuals on the basic variables, in the restricted basis's layout.
            let mut ci = Col::<f64>::zeros(m);
            let mut cc = Col::<f64>::zeros(lp.c.len());
            let mut worst = 0.0f64;
            for (q, b) in lp.basics().enumerate() {
                let r = sign(theta_s[q]) - w[support[q]];
                if b < m {
                    ci[b] = r;
                } else {
                    cc[b - m] = r;
                }
                worst = worst.max(r.abs());
            }
            if worst <= REFINED {
                break;
            }
            let mut d = Col::<f64>::zeros(m);
            lp.btran(&ci, &cc, &mut d);
            self.basis.solve_transpose(dct, idx, &mut d);
            for i in 0..m {
                y[i] += d[i];
            }
        }
    }

    /// θ_S += the correction (di on identity rows, dc on C), in basis order.
    fn apply(&self, di: &Col<f64>, dc: &Col<f64>, theta_s: &mut Col<f64>) {
        let m = self.lp.m;
        for (q, b) in self.lp.basics().enumerate() {
            theta_s[q] += if b < m { di[b] } else { dc[b - m] };
        }
    }
}

/// `signal` ← Ψθ for θ = θ_S on the support, zero elsewhere.
pub(super) fn signal_of(dct: &mut Dct, support: &[usize], theta_s: &Col<f64>, signal: &mut [f64]) {
    signal.fill(0.0);
    for (c, &k) in support.iter().enumerate() {
        signal[k] = theta_s[c];
    }
    dct.inverse(signal);
}

/// A basis's refined primal and dual, as [`verify`] checks them.
pub(super) struct Candidate<'a> {
    pub(super) support: &'a [usize],
    pub(super) theta_s: &'a Col<f64>,
    /// Ψθ for θ = θ_S on the support, zero elsewhere.
    pub(super) signal: Vec<f64>,
    /// max |h − (Ψθ)_idx|.
    pub(super) resid: f64,
    pub(super) y: &'a Col<f64>,
    /// Aᵀy.
    pub(super) w: &'a [f64],
}

/// Checks a candidate optimum against the transforms: θ (zero off the support) must reproduce the
/// samples (its signal and residual come from the transform in [`Refine::primal`]), w = Aᵀy must
/// satisfy |w| ≤ 1 + tol everywhere (w on the support equal to sign θ), and the gap ||θ||₁ - hᵀy
/// must vanish up to rounding.
pub(super) fn verify(
    n: usize,
    h: &[f64],
    c: Candidate<'_>,
    pivots: usize,
    tol: f64,
) -> Option<SimplexResult> {
    if !finite(c.theta_s) {
        return None;
    }
    let inf = c.w.iter().map(|v| v.abs()).fold(0.0, f64::max);
    if inf.is_nan() || inf > 1.0 + tol {
        return None;
    }
    let mut theta = vec![0.0; n];
    for (q, &k) in c.support.iter().enumerate() {
        theta[k] = c.theta_s[q];
    }
    let scale = h.iter().map(|v| v.abs()).fold(0.0, f64::max).max(1e-300);
    if c.resid.is_nan() || c.resid > 1e-10 * scale {
        return None;
    }
    let objective: f64 = theta.iter().map(|v| v.abs()).sum();
    let dual_objective: f64 = h.iter().enumerate().map(|(r, hr)| hr * c.y[r]).sum();
    if (objective - dual_objective).abs() > 1e-10 * objective.max(1e-300) {
        return None;
    }
    Some(SimplexResult {
        theta,
        signal: c.signal,
        dual_objective,
        pivots,
        dual_inf_norm: inf,
    })
}
