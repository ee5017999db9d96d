//! Exact BPDN finish: min ||θ||₁ s.t. ||Aθ − h||₂ ≤ ε on the sampled orthonormal DCT, by a
//! primal-dual active set on the support, from a first-order estimate of it.
//!
//! BPDN's optimum is the LASSO optimum min ½||Aθ − h||² + λ||θ||₁ at the λ where the residual
//! reaches ε. On a support S with signs s the LASSO's optimality conditions A_Sᵀr = λs (r = h − Aθ)
//! give θ_S = G⁻¹(A_Sᵀh − λs) with G = A_SᵀA_S, and r = (I − P_S)h + λA_SG⁻¹s, two orthogonal
//! parts: ||r||² = ||(I − P_S)h||² + λ²·sᵀG⁻¹s, so the λ of the noise ball has a closed form.
//! That point is optimal when the signs agree (θ_j s_j > 0) and no other column correlates more
//! (|A_jᵀr| ≤ λ): one DCT checks every column. Otherwise sign violators leave S and the columns
//! correlating most join it, and the round repeats (measured at n = 1901 on paper-like curves:
//! a few rounds at m = 600 from ~100 ADMM iterations, ten or so at m = 300).
//!
//! G comes from the Gram table (one DCT, `super::gram`) and is Cholesky-factored by faer at each
//! round. Nothing is taken from the factorization on trust: every round's θ is checked against
//! the transforms (its residual norm by an inverse DCT), and its dual point y = r / ||Aᵀr||∞ (dual
//! feasible by construction) gives the bound hᵀy − ε||y|| ≤ optimum ≤ ||θ||₁ that the caller
//! stops on.
use faer::dyn_stack::{MemBuffer, MemStack};
use faer::linalg::cholesky::llt::factor::{cholesky_in_place, cholesky_in_place_scratch};
use faer::linalg::triangular_solve::{
    solve_lower_triangular_in_place, solve_upper_triangular_in_place,
};
use faer::{MatMut, MatRef, Par};

use super::gram::{gram_lower, half_gram};
use crate::recon::dct::Dct;

/// A primal point inside the noise ball and the best dual bound found.
pub struct Denoised {
    /// θ (length n) with ||Aθ − h|| ≤ ε, checked through the transforms.
    pub theta: Vec<f64>,
    /// Ψθ on the whole grid.
    pub signal: Vec<f64>,
    /// ||θ||₁
    pub primal: f64,
    /// hᵀy − ε||y|| of a dual-feasible y (||Aᵀy||∞ ≤ 1): a lower bound on the optimum.
    pub dual: f64,
    /// Active-set rounds (one factorization and one DCT pair each).
    pub rounds: usize,
}

/// The dual bound of the residual r (dual direction) and its correlations w = Aᵀr: y = r / ||w||∞
/// is dual feasible, and the bound hᵀy − ε||y|| is maximised over the scale t·y, t ∈ [0, 1] (at
/// 0 or 1: it is linear in t).
pub fn dual_bound(h: &[f64], r: &[f64], w: &[f64], epsilon: f64) -> f64 {
    let inf = w.iter().map(|v| v.abs()).fold(0.0, f64::max);
    if inf <= 0.0 || !inf.is_finite() {
        return 0.0;
    }
    let hr: f64 = h.iter().zip(r).map(|(a, b)| a * b).sum();
    let rn = r.iter().map(|v| v * v).sum::<f64>().sqrt();
    ((hr - epsilon * rn) / inf).max(0.0)
}

/// Active-set rounds from the support `start` (columns with their signs ±1; at most m − 1 of
/// them), for at most `max_rounds`, until the relative gap (primal − dual) / primal ≤ `gap_tol`.
/// `ath` = Aᵀh on all n frequencies. `None` when no round produced a point inside the ball (a
/// singular Gram matrix, or a round budget spent before any).
#[allow(clippy::too_many_arguments)]
pub fn denoise(
    dct: &mut Dct,
    idx: &[usize],
    h: &[f64],
    ath: &[f64],
    epsilon: f64,
    start: &[(usize, f64)],
    max_rounds: usize,
    gap_tol: f64,
) -> Option<Denoised> {
    let n = dct.len();
    let m = idx.len();
    let (hg, r0) = half_gram(dct, idx);
    let hh: f64 = h.iter().map(|v| v * v).sum();
    // Aim a hair inside the ball so that rounding cannot put the checked residual outside it.
    let target2 = (epsilon * (1.0 - 1e-10)).powi(2);
    let mut support: Vec<(usize, f64)> = start.to_vec();
    let mut best: Option<Denoised> = None;
    let mut best_dual = 0.0f64;
    let mut l_buf: Vec<f64> = Vec::new();
    let mut rhs: Vec<f64> = Vec::new();
    let mut g = vec![0.0; n];
    let mut w = vec![0.0; n];
    let mut in_s = vec![false; n];
    for round in 1..=max_rounds {
        support.sort_unstable_by_key(|&(k, _)| k);
        support.dedup_by_key(|&mut (k, _)| k);
        let k = support.len();
        if k == 0 || k >= m {
            break;
        }
        let cols: Vec<u32> = support.iter().map(|&(c, _)| c as u32).collect();
        l_buf.clear();
        l_buf.resize(k * k, 0.0);
        gram_lower(&hg, &cols, &mut l_buf, k);
        if cols[0] == 0 {
            // Frequency 0's own weight (its column of the lower triangle, the diagonal twice).
            l_buf[..k].iter_mut().for_each(|v| *v *= r0);
            l_buf[0] *= r0;
        }
        let mut scratch = MemBuffer::new(cholesky_in_place_scratch::<f64>(
            k,
            Par::Seq,
            Default::default(),
        ));
        if cholesky_in_place(
            MatMut::from_column_major_slice_mut(&mut l_buf, k, k),
            Default::default(),
            Par::Seq,
            MemStack::new(&mut scratch),
            Default::default(),
        )
        .is_err()
        {
            break;
        }
        // [d q] = G⁻¹[s, A_Sᵀh].
        rhs.clear();
        rhs.extend(support.iter().map(|&(_, s)| s));
        rhs.extend(support.iter().map(|&(c, _)| ath[c]));
        {
            let l = MatRef::from_column_major_slice(&l_buf, k, k);
            let mut v = MatMut::from_column_major_slice_mut(&mut rhs, k, 2);
            solve_lower_triangular_in_place(l, v.as_mut(), Par::Seq);
            solve_upper_triangular_in_place(l.transpose(), v, Par::Seq);
        }
        let (d, q) = rhs.split_at(k);
        let std_: f64 = support.iter().zip(d).map(|(&(_, s), &dj)| s * dj).sum();
        let proj: f64 = support
            .iter()
            .zip(q)
            .map(|(&(c, _), &qj)| ath[c] * qj)
            .sum();
        let outside2 = (hh - proj).max(0.0);
        if !(std_ > 0.0 && std_.is_finite()) {
            break;
        }
        let lam2 = (target2 - outside2) / std_;
        if lam2 <= 0.0 {
            // S fits the samples closer than ε by least squares alone: too many columns. Drop
            // the eighth with the smallest least-squares coefficients and try again.
            let mut order: Vec<usize> = (0..k).collect();
            order.sort_unstable_by(|&a, &b| q[a].abs().total_cmp(&q[b].abs()));
            let drop = (k / 8).max(1);
            let gone: Vec<usize> = order[..drop].iter().map(|&j| support[j].0).collect();
            support.retain(|(c, _)| !gone.contains(c));
            continue;
        }
        let lam = lam2.sqrt();
        // θ and its residual through the transforms, not through G.
        g.fill(0.0);
        for (j, &(c, _)) in support.iter().enumerate() {
            g[c] = q[j] - lam * d[j];
        }
        let theta_s: Vec<f64> = support.iter().map(|&(c, _)| g[c]).collect();
        dct.inverse(&mut g);
        let r: Vec<f64> = idx.iter().zip(h).map(|(&i, &hk)| hk - g[i]).collect();
        dct.adjoint(idx, |j| r[j], &mut w);
        let rn2: f64 = r.iter().map(|v| v * v).sum();
        if !rn2.is_finite() {
            break;
        }
        let dual = dual_bound(h, &r, &w, epsilon);
        best_dual = best_dual.max(dual);
        let primal: f64 = theta_s.iter().map(|v| v.abs()).sum();
        if rn2 <= epsilon * epsilon && best.as_ref().is_none_or(|b| primal < b.primal) {
            let mut theta = vec![0.0; n];
            for (&(c, _), &t) in support.iter().zip(&theta_s) {
                theta[c] = t;
            }
            best = Some(Denoised {
                theta,
                signal: g.clone(),
                primal,
                dual: 0.0,
                rounds: round,
            });
        }
        if let Some(b) = best.as_mut() {
            b.dual = best_dual;
            b.rounds = round;
            if b.primal - best_dual <= gap_tol * b.primal.max(1e-300) {
                return best;
            }
        }
        // Next support: sign violators leave, the columns correlating most beyond λ join (a
        // limited number per round: adding every violator of a poor start overshoots).
        for &(c, _) in &support {
            in_s[c] = true;
        }
        let mut join: Vec<(f64, usize)> = w
            .iter()
            .enumerate()
            .filter(|&(c, v)| !in_s[c] && v.abs() > lam * (1.0 + 1e-9))
            .map(|(c, v)| (v.abs(), c))
            .collect();
        for &(c, _) in &support {
            in_s[c] = false;
        }
        let limit = (k / 32).max(8);
        if join.len() > limit {
            join.select_nth_unstable_by(limit - 1, |a, b| b.0.total_cmp(&a.0));
            join.truncate(limit);
        }
        let before = support.len();
        let mut j = 0;
        support.retain(|&(_, s)| {
            j += 1;
            theta_s[j - 1] * s > 0.0
        });
        if join.is_empty() && support.len() == before {
            // Consistent signs, no violator, and still a gap: rounding; nothing left to change.
            break;
        }
        support.extend(join.into_iter().map(|(_, c)| (c, w[c].signum())));
    }
    best
}

/// The LASSO homotopy (LARS with drops) from λ = ||Aᵀh||∞ down to the λ whose residual is ε:
/// exact and start-free, one Cholesky of the active Gram matrix and one DCT pair per event, so
/// for few samples only (at n = 1901, m = 100: ~150 events). `None` when it does not end within
/// `max_steps` or G turns singular; the caller checks the returned bounds like any other.
pub fn homotopy(
    dct: &mut Dct,
    idx: &[usize],
    h: &[f64],
    ath: &[f64],
    epsilon: f64,
    max_steps: usize,
) -> Option<Denoised> {
    let n = dct.len();
    let m = idx.len();
    let (hg, r0) = half_gram(dct, idx);
    let target2 = (epsilon * (1.0 - 1e-10)).powi(2);
    let mut c = ath.to_vec();
    let mut r = h.to_vec();
    let (j0, c0) = c
        .iter()
        .enumerate()
        .max_by(|a, b| a.1.abs().total_cmp(&b.1.abs()))?;
    let mut lam = c0.abs();
    // (column, sign, θ), in increasing column order.
    let mut act: Vec<(usize, f64, f64)> = vec![(j0, c0.signum(), 0.0)];
    let mut in_s = vec![false; n];
    in_s[j0] = true;
    let mut u = vec![0.0; n];
    let mut a = vec![0.0; n];
    let mut l_buf = Vec::new();
    // A column that just left sits on the boundary |c_j| = λ: rounding would let it rejoin at
    // once, so it waits one event.
    let mut dropped = usize::MAX;
    for _ in 0..max_steps {
        let k = act.len();
        if k == 0 || k > m {
            return None;
        }
        let cols: Vec<u32> = act.iter().map(|e| e.0 as u32).collect();
        l_buf.clear();
        l_buf.resize(k * k, 0.0);
        gram_lower(&hg, &cols, &mut l_buf, k);
        if cols[0] == 0 {
            l_buf[..k].iter_mut().for_each(|v| *v *= r0);
            l_buf[0] *= r0;
        }
        let mut scratch = MemBuffer::new(cholesky_in_place_scratch::<f64>(
            k,
            Par::Seq,
            Default::default(),
        ));
        cholesky_in_place(
            MatMut::from_column_major_slice_mut(&mut l_buf, k, k),
            Default::default(),
            Par::Seq,
            MemStack::new(&mut scratch),
            Default::default(),
        )
        .ok()?;
        let mut d: Vec<f64> = act.iter().map(|e| e.1).collect();
        {
            let l = MatRef::from_column_major_slice(&l_buf, k, k);
            let mut v = MatMut::from_column_major_slice_mut(&mut d, k, 1);
            solve_lower_triangular_in_place(l, v.as_mut(), Par::Seq);
            solve_upper_triangular_in_place(l.transpose(), v, Par::Seq);
        }
        // v = A_S d on the samples, a = Aᵀv on every column.
        u.fill(0.0);
        for (e, &dj) in act.iter().zip(&d) {
            u[e.0] = dj;
        }
        dct.inverse(&mut u);
        let v: Vec<f64> = idx.iter().map(|&i| u[i]).collect();
        dct.adjoint(idx, |j| v[j], &mut a);
        let std_: f64 = act.iter().zip(&d).map(|(e, dj)| e.1 * dj).sum();
        if !(std_ > 0.0 && std_.is_finite()) {
            return None;
        }
        let rn2: f64 = r.iter().map(|x| x * x).sum();
        let outside2 = (rn2 - lam * lam * std_).max(0.0);
        let lam_end = ((target2 - outside2) / std_).max(0.0).sqrt();
        // Next event: a column joins (|c_j − γa_j| = λ − γ) or a coefficient reaches zero.
        let mut best = (f64::INFINITY, usize::MAX, false);
        for j in 0..n {
            if in_s[j] || j == dropped {
                continue;
            }
            for g in [(lam - c[j]) / (1.0 - a[j]), (lam + c[j]) / (1.0 + a[j])] {
                if g > 1e-11 * lam && g < best.0 {
                    best = (g, j, true);
                }
            }
        }
        for (p, (e, &dj)) in act.iter().zip(&d).enumerate() {
            let g = -e.2 / dj;
            if g > 1e-11 * lam && g < best.0 {
                best = (g, p, false);
            }
        }
        let (mut gamma, at, join) = best;
        let last = lam - gamma <= lam_end;
        if last {
            gamma = lam - lam_end;
        }
        for (e, &dj) in act.iter_mut().zip(&d) {
            e.2 += gamma * dj;
        }
        for (ri, vi) in r.iter_mut().zip(&v) {
            *ri -= gamma * vi;
        }
        for (cj, aj) in c.iter_mut().zip(&a) {
            *cj -= gamma * aj;
        }
        lam -= gamma;
        if last {
            break;
        }
        dropped = usize::MAX;
        if join {
            let pos = act.partition_point(|e| e.0 < at);
            act.insert(pos, (at, c[at].signum(), 0.0));
            in_s[at] = true;
        } else {
            dropped = act[at].0;
            in_s[dropped] = false;
            act.remove(at);
        }
        if lam <= 0.0 {
            return None;
        }
    }
    if lam.is_nan() {
        return None;
    }
    // The end point through the transforms: its residual and the dual bound of that residual.
    let mut g = vec![0.0; n];
    for e in &act {
        g[e.0] = e.2;
    }
    let theta = g.clone();
    dct.inverse(&mut g);
    let res: Vec<f64> = idx.iter().zip(h).map(|(&i, &hk)| hk - g[i]).collect();
    let rn2: f64 = res.iter().map(|x| x * x).sum();
    if rn2.is_nan() || rn2 > epsilon * epsilon {
        return None;
    }
    let mut w = vec![0.0; n];
    dct.adjoint(idx, |j| res[j], &mut w);
    Some(Denoised {
        primal: theta.iter().map(|x| x.abs()).sum(),
        dual: dual_bound(h, &res, &w, epsilon),
        theta,
        signal: g,
        rounds: act.len(),
    })
}
