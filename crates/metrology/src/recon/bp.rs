//! Basis pursuit (paper Eq. 5) and basis pursuit denoising in the orthonormal DCT basis.
//!
//! Two solvers for the same problems:
//! - [`solve_clarabel`]: the generic LP/SOCP through Clarabel with the dense sampled basis; the
//!   reference, slow (tens of seconds at n = 1901, m = 600).
//! - [`solve_fast`]: ADMM whose projection onto {Aθ = h} is one DCT pair (A·Aᵀ = I), followed by
//!   an exact finish: the BP optimum is a vertex with m non-zeros, so from ADMM's ranking of the
//!   columns a simplex restricted to the best-ranked ones ([`super::simplex`]) pivots to the
//!   optimal basis, where the square system A_S θ_S = h gives the exact primal, A_Sᵀ y = sign(θ_S)
//!   the dual, and ||Aᵀy||∞ ≤ 1 (one more DCT) certifies optimality with a zero duality gap. ADMM
//!   runs only long enough (max(50, m/6) iterations) for the optimal basis to lie within the top
//!   m + m/12 ranked columns but for a handful (measured at m = 600, n = 1901: after 100
//!   iterations 8-16 of its columns rank below m, none below ~680), and in f32, since only the
//!   ranking is used. Above `exact_max_m` samples ADMM (f64) stops at a certified duality gap.
//!   BPDN: 200 f32 ADMM iterations estimate the support, then an active set
//!   ([`super::simplex::denoise`]) solves the LASSO conditions on it at the λ whose residual is
//!   exactly ε, until ||θ||₁ and the dual bound hᵀy − ε||y|| agree to 1e-9; if it does not get
//!   there, f64 ADMM stops at the certified gap `gap_tol`.
use std::time::Instant;

use nalgebra::{DMatrix, DVector};

use rustfft::num_traits::Float;

use super::dct::Dct;

/// Which problem to solve.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Problem {
    /// min ||θ||₁ s.t. Aθ = h
    BasisPursuit,
    /// min ||θ||₁ s.t. ||Aθ - h||₂ ≤ epsilon (µm)
    Denoising { epsilon: f64 },
}

/// Settings of the fast solver.
#[derive(Debug, Clone)]
pub struct FastSettings {
    /// ADMM iteration cap (one DCT pair each).
    pub max_iter: usize,
    /// BP: the simplex finish starts once ADMM's support has not changed for this many iterations.
    pub stable_iter: usize,
    /// BP: ... or after this many ADMM iterations at the latest (later attempts at 2x, 4x, ...).
    /// `None`: max(50, m/6). Fewer iterations cost more pivots (measured at n = 1901, m = 600:
    /// ~100 pivots after 75 iterations, ~50 after 100, ~25 after 150).
    pub finish_iter: Option<usize>,
    /// BP: ADMM over-relaxation (1 = plain; 1.5-1.8 speeds up support discovery; 1.8 measured
    /// ~15 % faster than 1.6 at m = 600, equal at m = 100-300).
    pub relaxation: f64,
    /// Soft threshold 1/ρ as a fraction of the largest minimum-energy coefficient. `None`: for BP
    /// 0.0014·(n/m)² within [0.005, 0.5], for BPDN 1/40.
    pub threshold_fraction: Option<f64>,
    /// Dual feasibility slack accepted by the certificate (||Aᵀy||∞ ≤ 1 + tol).
    pub certificate_tol: f64,
    /// Relative primal/dual residual at which plain ADMM stops (BPDN, or when the finish fails).
    pub admm_tol: f64,
    /// BP: candidate columns beyond the m ranked first that the simplex starts with (more join
    /// by column generation). `None`: m/12 within [8, 31]. Measured on the bench curves (AMD
    /// EPYC, harness medians, m/12 → 32): m = 500 3.56-3.60 → 3.62; m = 600 4.76-4.78 → 4.70-4.75;
    /// m = 900 11.2-11.6 → 9.8-9.9 ms; m = 1200 24-26 → 21 ms. Beyond ~32 the first block solve
    /// costs more than the generation rounds it saves (a round adds at most 32 columns too).
    /// (Measured with the former hand-written kernels; 23, 31 and 39 were level there.)
    pub candidates: Option<usize>,
    /// Pivot budget of one simplex finish.
    pub max_pivots: usize,
    /// BP: largest m for the exact finish (its dense m x m factorization grows as m³: ~1.5 ms
    /// in f32 at 600, ~2 s at 6554). Above it ADMM stops at a certified relative duality gap.
    pub exact_max_m: usize,
    /// BP: from this many samples the simplex's first anchor is the f64 Cholesky of B₀ᵀB₀ instead
    /// of the f32 LU of B₀ (measured at n = 1901, 40 curves each, median / mean ms: m = 300 3.35 /
    /// 3.57 against 3.23 / 3.33; m = 400 3.83 / 3.89 against 3.84 / 4.17; m = 500 4.63 / 4.71
    /// against 5.12 / 5.71).
    pub gram_min_m: usize,
    /// BP without the exact finish: stop once (||θ||₁ - hᵀy) / ||θ||₁ ≤ this for a feasible θ
    /// and a dual-feasible y (both checked against the transforms). BPDN: the gap its ADMM
    /// fallback stops at (the active-set path goes on to `bpdn_exact_gap`).
    pub gap_tol: f64,
    /// BPDN: f32 ADMM iterations that estimate the support before the active-set finish
    /// (`None`: see [`bpdn_warm_iterations`]).
    pub bpdn_warm_iter: Option<usize>,
    /// BPDN: active-set rounds before the f64 ADMM fallback takes over.
    pub bpdn_max_rounds: usize,
    /// BPDN: the certified relative gap at which the active set stops and reports `optimal`.
    pub bpdn_exact_gap: f64,
}

impl Default for FastSettings {
    fn default() -> Self {
        Self {
            max_iter: 20_000,
            stable_iter: 5,
            finish_iter: None,
            relaxation: 1.8,
            threshold_fraction: None,
            certificate_tol: 1e-9,
            admm_tol: 1e-10,
            candidates: None,
            max_pivots: 5000,
            exact_max_m: 2000,
            gram_min_m: 400,
            gap_tol: 1e-3,
            bpdn_warm_iter: None,
            bpdn_max_rounds: 60,
            bpdn_exact_gap: 1e-9,
        }
    }
}

/// How a solve ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum SolveStatus {
    /// Optimal, with a dual certificate (zero gap up to rounding).
    Optimal,
    /// Stopped by tolerance on residuals, no exact certificate (first-order accuracy).
    Solved,
    /// Iteration cap reached; the result is the best iterate.
    MaxIterations,
    /// The reference solver failed (numerical trouble, infeasible data).
    Failed,
}

#[derive(Debug, Clone)]
pub struct BpSolution {
    /// DCT coefficients θ (length n).
    pub theta: Vec<f64>,
    pub status: SolveStatus,
    pub iterations: usize,
    /// ||θ||₁
    pub objective: f64,
    /// hᵀy of the best dual point found (NaN when none).
    pub dual_objective: f64,
    /// Wall time of the solver only, ms.
    pub solve_ms: f64,
    /// Ψθ, the curve on the grid, when the solver formed it (the exact finish does, to check
    /// the samples): spares the caller an inverse transform.
    pub signal: Option<Vec<f64>>,
}

/// An exact finish's certified optimum.
struct Finish {
    theta: Vec<f64>,
    signal: Option<Vec<f64>>,
    /// hᵀy of the certificate.
    dual: f64,
    pivots: usize,
}

impl BpSolution {
    /// Stopped at a certified gap: objective `p` ≥ optimum ≥ dual bound `d`.
    fn solved(theta: Vec<f64>, iterations: usize, p: f64, d: f64, t0: Instant) -> Self {
        BpSolution {
            theta,
            status: SolveStatus::Solved,
            iterations,
            objective: p,
            dual_objective: d,
            solve_ms: t0.elapsed().as_secs_f64() * 1e3,
            signal: None,
        }
    }

    /// A certified optimum: ||θ||₁ = hᵀy = `f.dual`, after `iterations` ADMM iterations.
    fn optimal(f: Finish, iterations: usize, t0: Instant) -> Self {
        let Finish {
            theta,
            signal,
            dual: dual_objective,
            pivots,
        } = f;
        Self {
            objective: theta.iter().map(|v| v.abs()).sum(),
            theta,
            signal,
            status: SolveStatus::Optimal,
            iterations: iterations + pivots,
            dual_objective,
            solve_ms: t0.elapsed().as_secs_f64() * 1e3,
        }
    }
}

fn soft<F: Float>(v: F, t: F) -> F {
    if v > t {
        v - t
    } else if v < -t {
        v + t
    } else {
        F::zero()
    }
}

/// What one ADMM update reports: whether the support changed, its size and, when asked for,
/// ||x − z||², ||z − z_prev||² and ||z||².
struct Step<F> {
    changed: bool,
    nnz: usize,
    r2: F,
    s2: F,
    z2: F,
}

/// One relaxed ADMM update after the projection `x`: z = soft(x̂ + u, 1/ρ) with
/// x̂ = αx + (1 − α)z, u += x̂ − z, and v = z − u, the next projection's input. Shared by the f64
/// iterations and the f32 ranking run; `NORMS` adds the residual norms only the former reads.
#[inline(always)]
fn admm_update<F: Float, const NORMS: bool>(
    x: &[F],
    z: &mut [F],
    u: &mut [F],
    v: &mut [F],
    alpha: F,
    inv: F,
) -> Step<F> {
    let zero = F::zero();
    let mut st = Step {
        changed: false,
        nnz: 0,
        r2: zero,
        s2: zero,
        z2: zero,
    };
    let beta = F::one() - alpha;
    for (((&xi, zi), ui), vi) in x
        .iter()
        .zip(z.iter_mut())
        .zip(u.iter_mut())
        .zip(v.iter_mut())
    {
        let xh = alpha * xi + beta * *zi;
        let zn = soft(xh + *ui, inv);
        st.changed |= (zn != zero) != (*zi != zero);
        st.nnz += usize::from(zn != zero);
        if NORMS {
            st.s2 = st.s2 + (zn - *zi) * (zn - *zi);
            st.r2 = st.r2 + (xi - zn) * (xi - zn);
            st.z2 = st.z2 + zn * zn;
        }
        *zi = zn;
        *ui = *ui + (xh - zn);
        *vi = zn - *ui;
    }
    st
}

/// Projection of coefficients `v` (in place) onto the constraint set of `problem`, done on the
/// signal g = Ψv: one DCT pair.
fn project(dct: &mut Dct, idx: &[usize], h: &[f64], problem: Problem, v: &mut [f64]) {
    dct.inverse(v);
    constrain(idx, h, problem, v);
    dct.forward(v);
}

/// The signal `g` projected onto the constraint set: the samples replaced (BP) or pulled into
/// the ε-ball around them (BPDN).
fn constrain(idx: &[usize], h: &[f64], problem: Problem, g: &mut [f64]) {
    match problem {
        Problem::BasisPursuit => {
            for (k, &i) in idx.iter().enumerate() {
                g[i] = h[k];
            }
        }
        Problem::Denoising { epsilon } => {
            let r2: f64 = idx.iter().zip(h).map(|(&i, &hk)| (g[i] - hk).powi(2)).sum();
            let r = r2.sqrt();
            if r > epsilon {
                let f = epsilon / r;
                for (k, &i) in idx.iter().enumerate() {
                    g[i] = h[k] + (g[i] - h[k]) * f;
                }
            }
        }
    }
}

/// ADMM's dual estimate y = A(ρu): the sampled signal of ρu.
fn admm_dual(dct: &mut Dct, idx: &[usize], u: &[f64], rho: f64) -> Vec<f64> {
    let mut yu: Vec<f64> = u.iter().map(|v| rho * v).collect();
    dct.sample(&mut yu, idx)
}

/// Fast BP / BPDN solver on the sampled orthonormal DCT.
pub fn solve_fast(
    dct: &mut Dct,
    idx: &[usize],
    h: &[f64],
    problem: Problem,
    s: &FastSettings,
) -> BpSolution {
    let t0 = Instant::now();
    let n = dct.len();
    let m = idx.len();

    let project = |dct: &mut Dct, v: &mut [f64]| project(dct, idx, h, problem, v);
    if let Problem::Denoising { epsilon } = problem {
        let hn = h.iter().map(|v| v * v).sum::<f64>().sqrt();
        if epsilon <= 0.0 {
            // A ball of radius 0 is the equality: basis pursuit, with its exact finish.
            let mut sol = solve_fast(dct, idx, h, Problem::BasisPursuit, s);
            sol.solve_ms = t0.elapsed().as_secs_f64() * 1e3;
            return sol;
        }
        if hn <= epsilon {
            // θ = 0 is inside the ball, and y = 0 bounds the optimum from below by 0.
            let zero = Finish {
                theta: vec![0.0; n],
                signal: Some(vec![0.0; n]),
                dual: 0.0,
                pivots: 0,
            };
            return BpSolution::optimal(zero, 0, t0);
        }
    }
    if h.iter().all(|&v| v == 0.0) {
        // θ = 0 is feasible with ||θ||₁ = 0, and y = 0 certifies it for BP and BPDN alike.
        let zero = Finish {
            theta: vec![0.0; n],
            signal: Some(vec![0.0; n]),
            dual: 0.0,
            pivots: 0,
        };
        return BpSolution::optimal(zero, 0, t0);
    }

    // The minimum-energy solution x0 = Aᵀh (the projection of θ = 0, whose signal is 0: one
    // forward transform) sets ρ's scale, and starts ADMM unless the exact finish follows (then
    // [`interpolated_start`]).
    let mut x = vec![0.0; n];
    constrain(idx, h, problem, &mut x);
    dct.forward(&mut x);
    let scale = x.iter().map(|v| v.abs()).fold(0.0, f64::max).max(1e-300);
    let bp = matches!(problem, Problem::BasisPursuit);
    // Aᵀh again is the exact finish's right-hand side (one DCT fewer per solve); only BP up to
    // `exact_max_m` samples has an exact finish.
    let exact = bp && m <= s.exact_max_m;
    let ath = if exact { x.clone() } else { Vec::new() };
    // For BP ρ stays fixed (residual balancing was measured to scramble the support and cost
    // pivots).
    let fraction = s.threshold_fraction.unwrap_or(if bp && !exact {
        // Gap-certified path (measured at n = 65 536, m = 6554: 0.01 reaches a 1e-3 gap in
        // ~10 % fewer iterations than 0.005, as fast as 0.02).
        0.01
    } else if bp {
        // Fit of the fastest fraction at n = 1901 (0.5 at m = 100, 0.05 at 300, 0.0125 at 600):
        // a high threshold leaves few coefficients for small m, a low one lets ADMM find the
        // ~m non-zeros at large m (a fixed 1/40 cost up to 3x in time at m = 100).
        (0.0014 * (n as f64 / m.max(1) as f64).powi(2)).clamp(0.005, 0.5)
    } else {
        1.0 / 40.0
    });
    let mut rho = 1.0 / (fraction * scale);
    let alpha = if bp { s.relaxation } else { 1.0 };
    if exact && 8 * m >= n {
        x = interpolated_start(dct, idx, h);
    }
    let mut z: Vec<f64> = x.iter().map(|&v| soft(v, 1.0 / rho)).collect();
    let mut u = vec![0.0; n];
    let mut v = vec![0.0; n];
    let mut iterations = 0;
    let mut status = SolveStatus::MaxIterations;
    let mut stable = 0;
    let mut prev_nnz = 0;
    let mut next_stable = s.stable_iter;
    let mut next_finish = s.finish_iter.unwrap_or((m / 6).max(50)).max(1);
    let mut simplex_failed = false;

    if exact {
        // The ADMM run before the exact finish only ranks columns, so it runs in f32 (the
        // transforms' cost ~1.5x lower at n = 1901); if the finish fails, the f64 iterations
        // below take over and retry it at twice the budget.
        let (zs, us, its) = admm_single(dct, idx, h, &z, rho, alpha, next_finish, next_stable);
        if let Some(f) = exact_finish(dct, idx, h, &ath, &zs, &us, rho, s, false) {
            return BpSolution::optimal(f, its, t0);
        }
        simplex_failed = true;
        next_stable *= 2;
        next_finish *= 2;
    }
    if let (Problem::Denoising { epsilon }, true) = (problem, m <= s.exact_max_m) {
        let mut ath = vec![0.0; n];
        dct.adjoint(idx, |r| h[r], &mut ath);
        let tol = s.bpdn_exact_gap;
        let homotopy = (m <= HOMOTOPY_MAX_M && s.bpdn_max_rounds > 0)
            .then(|| super::simplex::denoise::homotopy(dct, idx, h, &ath, epsilon, 4 * m))
            .flatten()
            .filter(|d| d.primal - d.dual <= tol * d.primal.max(1e-300));
        let (found, its) = match homotopy {
            Some(d) => (Some(d), 0),
            None => {
                let warm = s.bpdn_warm_iter.unwrap_or_else(|| bpdn_warm_iterations(m));
                let (zs, its) = admm_single_ball(dct, idx, h, epsilon, &z, rho, warm);
                // The start: ADMM's largest coefficients, fewer than m (G must stay
                // non-singular, and the optimum has fewer non-zeros than samples).
                let cap = (m * 15 / 16).max(1);
                let mut start: Vec<(usize, f64)> = (0..n)
                    .filter(|&k| zs[k] != 0.0)
                    .map(|k| (k, zs[k]))
                    .collect();
                if start.len() > cap {
                    start.select_nth_unstable_by(cap - 1, |a, b| b.1.abs().total_cmp(&a.1.abs()));
                    start.truncate(cap);
                }
                for e in &mut start {
                    e.1 = e.1.signum();
                }
                let rounds = s.bpdn_max_rounds;
                let d = super::simplex::denoise::denoise(
                    dct, idx, h, &ath, epsilon, &start, rounds, tol,
                );
                (d, its)
            }
        };
        if let Some(d) = found {
            let gap = d.primal - d.dual;
            let rel = gap / d.primal.max(1e-300);
            if rel <= s.gap_tol.max(tol) {
                return BpSolution {
                    objective: d.primal,
                    dual_objective: d.dual,
                    theta: d.theta,
                    signal: Some(d.signal),
                    status: if rel <= tol {
                        SolveStatus::Optimal
                    } else {
                        SolveStatus::Solved
                    },
                    iterations: its + d.rounds,
                    solve_ms: t0.elapsed().as_secs_f64() * 1e3,
                };
            }
        }
        iterations = its;
    }
    for i in 0..n {
        v[i] = z[i] - u[i];
    }
    for it in iterations + 1..=s.max_iter {
        iterations = it;
        project(dct, &mut v);
        std::mem::swap(&mut x, &mut v);
        // The next projection's input goes to v, the buffer that held the previous x.
        let Step {
            changed,
            nnz,
            r2,
            s2,
            z2,
        } = admm_update::<f64, true>(&x, &mut z, &mut u, &mut v, alpha, 1.0 / rho);
        let zn = z2.sqrt().max(1e-300);
        let (r, sd) = (r2.sqrt() / zn, rho * s2.sqrt() / zn);
        if bp && !exact {
            if it % GAP_EVERY == 0 {
                let (theta, p, d) = certified_gap(dct, idx, h, &z, &u, rho);
                if p - d <= s.gap_tol * p.max(1e-300) {
                    return BpSolution::solved(theta, it, p, d, t0);
                }
            }
        } else if bp {
            stable = if changed || nnz != prev_nnz {
                0
            } else {
                stable + 1
            };
            prev_nnz = nnz;
            // Exact finish once the support has settled or the iteration budget is spent; if it
            // fails, wait twice as long.
            if stable >= next_stable || it >= next_finish {
                if let Some(f) = exact_finish(dct, idx, h, &ath, &z, &u, rho, s, simplex_failed) {
                    return BpSolution::optimal(f, it, t0);
                }
                simplex_failed = true;
                next_stable *= 2;
                next_finish = 2 * it;
            }
        } else if let (Problem::Denoising { epsilon }, 0) = (problem, it % GAP_EVERY) {
            let (theta, p, d) = denoise_gap(dct, idx, h, epsilon, &z);
            if p - d <= s.gap_tol * p.max(1e-300) {
                return BpSolution::solved(theta, it, p, d, t0);
            }
        }
        if !bp && it % 10 == 0 {
            // BPDN: residual balancing keeps primal and dual progress in step.
            let f = if r > 10.0 * sd {
                2.0
            } else if sd > 10.0 * r {
                0.5
            } else {
                1.0
            };
            if f != 1.0 {
                rho *= f;
                for i in 0..n {
                    u[i] /= f;
                    v[i] = z[i] - u[i];
                }
            }
        }
        if r < s.admm_tol && sd < s.admm_tol {
            status = SolveStatus::Solved;
            break;
        }
    }
    let mut dual = f64::NAN;
    let theta = match problem {
        // Return a feasible point: the projection of z.
        Problem::BasisPursuit => {
            let mut t = z.clone();
            project(dct, &mut t);
            t
        }
        Problem::Denoising { epsilon } => {
            // A point inside the ball with its certified bound, whatever ended the iterations.
            let (theta, _, d) = denoise_gap(dct, idx, h, epsilon, &z);
            dual = d;
            theta
        }
    };
    let objective = theta.iter().map(|v| v.abs()).sum();
    BpSolution {
        theta,
        status,
        iterations,
        objective,
        dual_objective: dual,
        solve_ms: t0.elapsed().as_secs_f64() * 1e3,
        signal: None,
    }
}

/// The DCT of the samples' linear interpolation (ends held): the ranking ADMM's start before the
/// exact finish. Like the minimum-energy point Aᵀh it reproduces every sample, but it already
/// holds the curve's smooth part where Aᵀh holds the samples as spikes. Measured at n = 1901
/// (8 sets of 20 bench curves at m = 600, 4 sets at 300): median solve 6.71 → 6.45 ms at
/// m = 600 and 4.73 → 3.27 ms at 300, with ~10 and ~90 fewer ADMM iterations plus pivots per
/// curve. Used from m ≥ n/8: at m = 100 the gaps are too long for a useful curve (median equal,
/// mean 1.93 → 2.06 ms). PCHIP's curve did no better; ρ keeps its scale from Aᵀh, for which the
/// threshold fraction was fitted.
fn interpolated_start(dct: &mut Dct, idx: &[usize], h: &[f64]) -> Vec<f64> {
    let xs: Vec<f64> = idx.iter().map(|&i| i as f64).collect();
    let at: Vec<f64> = (0..dct.len()).map(|i| i as f64).collect();
    let mut x = super::interp::linear(&xs, h, &at);
    dct.forward(&mut x);
    x
}

/// BP's ADMM in f32 from the thresholded start `z0`, for at most `iters`
/// iterations or until the support has not changed for `stable_iter`: returns (z, u, iterations)
/// for [`rank_columns`].
#[allow(clippy::too_many_arguments)]
fn admm_single(
    dct: &mut Dct,
    idx: &[usize],
    h: &[f64],
    z0: &[f64],
    rho: f64,
    alpha: f64,
    iters: usize,
    stable_iter: usize,
) -> (Vec<f64>, Vec<f64>, usize) {
    let hs: Vec<f32> = h.iter().map(|&v| v as f32).collect();
    let (inv, a) = ((1.0 / rho) as f32, alpha as f32);
    let t = dct.single();
    let z = z0.iter().map(|&v| v as f32).collect();
    let (z, u, done) = ranking_loop(z, a, inv, iters, stable_iter, |v, x| {
        x.copy_from_slice(v);
        t.inverse(x);
        for (k, &i) in idx.iter().enumerate() {
            x[i] = hs[k];
        }
        t.forward(x);
    });
    let wide = |w: Vec<f32>| w.into_iter().map(f64::from).collect();
    (wide(z), wide(u), done)
}

/// The f32 ADMM iterations from z (u = 0) with the projection `project(v, x)`: x = P(v).
fn ranking_loop(
    mut z: Vec<f32>,
    alpha: f32,
    inv: f32,
    iters: usize,
    stable_iter: usize,
    mut project: impl FnMut(&[f32], &mut [f32]),
) -> (Vec<f32>, Vec<f32>, usize) {
    let n = z.len();
    let mut u = vec![0.0f32; n];
    let mut v = z.clone();
    let mut x = vec![0.0f32; n];
    let (mut stable, mut prev_nnz, mut done) = (0, 0, 0);
    for it in 1..=iters {
        done = it;
        project(&v, &mut x);
        let Step { changed, nnz, .. } =
            admm_update::<f32, false>(&x, &mut z, &mut u, &mut v, alpha, inv);
        stable = if changed || nnz != prev_nnz {
            0
        } else {
            stable + 1
        };
        prev_nnz = nnz;
        if stable >= stable_iter {
            break;
        }
    }
    (z, u, done)
}

/// Exact BP finish from ADMM's state: for a sparse optimum (far fewer non-zeros than samples,
/// where a square basis is degenerate) a least-squares polish on the support with a corrected
/// dual; otherwise the restricted simplex from ADMM's ranking. Noisy curves have m non-zeros at
/// the optimum and ADMM reports slightly fewer, so near m the dense least squares (tens of ms at
/// m = 600) is only tried once the simplex has failed.
#[allow(clippy::too_many_arguments)]
fn exact_finish(
    dct: &mut Dct,
    idx: &[usize],
    h: &[f64],
    ath: &[f64],
    z: &[f64],
    u: &[f64],
    rho: f64,
    s: &FastSettings,
    simplex_failed: bool,
) -> Option<Finish> {
    let m = idx.len();
    let nnz = z.iter().filter(|v| **v != 0.0).count();
    if nnz < m && (2 * nnz <= m || simplex_failed) {
        if let Some((theta, dual)) = polish(dct, idx, h, z, u, rho, s.certificate_tol) {
            return Some(Finish {
                theta,
                signal: None,
                dual,
                pivots: 0,
            });
        }
    }
    let k0 = s.candidates.unwrap_or((m / 12).clamp(8, 31));
    let order = rank_columns(z, u, rho, m + k0);
    super::simplex::finish(
        dct,
        idx,
        h,
        ath,
        &order,
        k0,
        s.max_pivots,
        s.certificate_tol,
        s.gram_min_m,
    )
    .map(|r| Finish {
        theta: r.theta,
        signal: Some(r.signal),
        dual: r.dual_objective,
        pivots: r.pivots,
    })
}

/// ADMM iterations between duality-gap checks (a check costs two DCT pairs).
const GAP_EVERY: usize = 20;

/// A feasible primal (z projected onto {Aθ = h}) and a feasible dual (ADMM's y = A(ρu), scaled so
/// that ||Aᵀy||∞ ≤ 1): returns (θ, ||θ||₁, hᵀy), a certified bound on the distance to the optimum.
fn certified_gap(
    dct: &mut Dct,
    idx: &[usize],
    h: &[f64],
    z: &[f64],
    u: &[f64],
    rho: f64,
) -> (Vec<f64>, f64, f64) {
    let mut theta = z.to_vec();
    project(dct, idx, h, Problem::BasisPursuit, &mut theta);
    let primal = theta.iter().map(|v| v.abs()).sum();
    let y = admm_dual(dct, idx, u, rho);
    let mut w = vec![0.0; z.len()];
    dct.adjoint(idx, |r| y[r], &mut w);
    // (Measured: a few alternating clip/project passes on y tightened the dual bound by ~15 %
    // at twice the cost per check; not worth it.)
    let inf = w.iter().map(|v| v.abs()).fold(0.0, f64::max).max(1.0);
    let dual = h.iter().zip(&y).map(|(a, b)| a * b).sum::<f64>() / inf;
    (theta, primal, dual)
}

/// BPDN up to this many samples tries the exact homotopy first (the active set from an ADMM
/// start did not converge at m = 100, n = 1901: the optimum has ~m non-zeros there).
const HOMOTOPY_MAX_M: usize = 160;

/// f32 ADMM iterations that estimate BPDN's support for the active set. Measured at n = 1901 on
/// paper-like curves (σ = 0.01 µm): 100 leave 3-5 rounds at m = 600, 200 leave 2-3; at m = 300
/// 100 iterations left the active set far off (hundreds of violators, 20-40 rounds), 200 some
/// ten rounds.
pub fn bpdn_warm_iterations(_m: usize) -> usize {
    200
}

/// BPDN's ADMM in f32 (projection onto the ε-ball around the samples, in the signal domain) from
/// the thresholded start `z0`, for `iters` iterations: returns (z, iterations).
fn admm_single_ball(
    dct: &mut Dct,
    idx: &[usize],
    h: &[f64],
    epsilon: f64,
    z0: &[f64],
    rho: f64,
    iters: usize,
) -> (Vec<f64>, usize) {
    let hs: Vec<f32> = h.iter().map(|&v| v as f32).collect();
    let inv = (1.0 / rho) as f32;
    let eps = epsilon as f32;
    let t = dct.single();
    let z = z0.iter().map(|&v| v as f32).collect();
    let (z, _, done) = ranking_loop(z, 1.0, inv, iters, usize::MAX, |v, x| {
        x.copy_from_slice(v);
        t.inverse(x);
        let r2: f32 = idx
            .iter()
            .zip(&hs)
            .map(|(&i, &hk)| (x[i] - hk).powi(2))
            .sum();
        let r = r2.sqrt();
        if r > eps {
            let f = eps / r;
            for (k, &i) in idx.iter().enumerate() {
                x[i] = hs[k] + (x[i] - hs[k]) * f;
            }
        }
        t.forward(x);
    });
    (z.into_iter().map(f64::from).collect(), done)
}

/// BPDN's certified bound from any iterate z: the projection of z's signal onto the ball is a
/// feasible θ, and z's residual r = h − Az gives the dual-feasible y = r / ||Aᵀr||∞. Returns
/// (θ, ||θ||₁, hᵀy − ε||y||). Three transforms.
fn denoise_gap(
    dct: &mut Dct,
    idx: &[usize],
    h: &[f64],
    epsilon: f64,
    z: &[f64],
) -> (Vec<f64>, f64, f64) {
    let mut g = z.to_vec();
    dct.inverse(&mut g);
    let r: Vec<f64> = idx.iter().zip(h).map(|(&i, &hk)| hk - g[i]).collect();
    let mut w = vec![0.0; z.len()];
    dct.adjoint(idx, |k| r[k], &mut w);
    let dual = super::simplex::denoise::dual_bound(h, &r, &w, epsilon);
    constrain(idx, h, Problem::Denoising { epsilon }, &mut g);
    dct.forward(&mut g);
    let primal = g.iter().map(|v| v.abs()).sum();
    (g, primal, dual)
}

/// The `keep` columns most likely in the optimal basis, most likely first: ADMM's non-zeros by
/// magnitude, then the columns whose dual ρu is closest to ±1. Keys are computed once and only
/// the kept ones sorted (a full sort of all n with the key in the comparator was ~80 µs of an
/// m = 600 solve).
fn rank_columns(z: &[f64], u: &[f64], rho: f64, keep: usize) -> Vec<usize> {
    let key = |k: usize| {
        if z[k] != 0.0 {
            2.0 + z[k].abs()
        } else {
            (rho * u[k]).abs().min(1.0)
        }
    };
    // Descending key, then ascending column: a total order, so the result does not depend on
    // how the selection splits ties.
    let by = |a: &(f64, usize), b: &(f64, usize)| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1));
    let mut keyed: Vec<(f64, usize)> = (0..z.len()).map(|k| (key(k), k)).collect();
    let keep = keep.min(keyed.len());
    if keep < keyed.len() && keep > 0 {
        keyed.select_nth_unstable_by(keep - 1, by);
    }
    keyed.truncate(keep);
    keyed.sort_unstable_by(by);
    keyed.into_iter().map(|(_, k)| k).collect()
}

/// Exact finish for a degenerate (sparse) optimum with fewer non-zeros than samples: least squares
/// on ADMM's support, which must fit the samples exactly, and a dual certificate. The dual starts
/// from ADMM's estimate y₀ = A(ρu) and is corrected minimally so that A_Sᵀy = sign(θ_S); the point
/// is optimal when ||Aᵀy||∞ ≤ 1, since then hᵀy = ||θ||₁. Returns (θ, hᵀy) when certified.
fn polish(
    dct: &mut Dct,
    idx: &[usize],
    h: &[f64],
    z: &[f64],
    u: &[f64],
    rho: f64,
    tol: f64,
) -> Option<(Vec<f64>, f64)> {
    let n = dct.len();
    let m = idx.len();
    let support: Vec<usize> = (0..n).filter(|&k| z[k] != 0.0).collect();
    if support.is_empty() || support.len() >= m {
        return None;
    }
    let k = support.len();
    let a_s = DMatrix::from_fn(m, k, |r, c| dct.basis(idx[r], support[c]));
    let hv = DVector::from_column_slice(h);
    let y0 = DVector::from_vec(admm_dual(dct, idx, u, rho));
    let qr = a_s.clone().qr();
    let (q, r) = (qr.q(), qr.r());
    let theta_s = r.solve_upper_triangular(&(q.transpose() * &hv))?;
    let resid = (&a_s * &theta_s - &hv).norm();
    if resid > 1e-9 * hv.norm().max(1e-300) {
        return None;
    }
    let sign = theta_s.map(|v| if v >= 0.0 { 1.0 } else { -1.0 });
    let defect = sign - a_s.transpose() * &y0;
    let c = r.transpose().solve_lower_triangular(&defect)?;
    let y = y0 + q * c;
    if theta_s.iter().chain(y.iter()).any(|v| !v.is_finite()) {
        return None;
    }
    // w = Aᵀy = Ψᵀ(scatter y): the certificate needs |w| ≤ 1 everywhere.
    let mut w = vec![0.0; n];
    dct.adjoint(idx, |r| y[r], &mut w);
    let worst = w.iter().map(|v| v.abs()).fold(0.0, f64::max);
    if worst > 1.0 + tol {
        return None;
    }
    let mut theta = vec![0.0; n];
    for (c, &k) in support.iter().enumerate() {
        theta[k] = theta_s[c];
    }
    let dual = h.iter().zip(y.iter()).map(|(a, b)| a * b).sum();
    Some((theta, dual))
}

/// Reference solver: the LP (BP) or SOCP (BPDN) through Clarabel with the dense sampled basis.
pub fn solve_clarabel(dct: &Dct, idx: &[usize], h: &[f64], problem: Problem) -> BpSolution {
    use clarabel::algebra::CscMatrix;
    use clarabel::solver::{
        DefaultSettingsBuilder, DefaultSolver, IPSolver, SolverStatus, SupportedConeT,
    };
    let t0 = Instant::now();
    let n = dct.len();
    let m = idx.len();
    // Variables [θ; t], minimize Σt with -t ≤ θ ≤ t.
    let nv = 2 * n;
    let mut q = vec![0.0; nv];
    for qi in q.iter_mut().skip(n) {
        *qi = 1.0;
    }
    let p = CscMatrix::<f64>::zeros((nv, nv));
    // Rows: [A θ (= h) | SOC block | θ - t ≤ 0 | -θ - t ≤ 0]
    let (eq_rows, soc_rows) = match problem {
        Problem::BasisPursuit => (m, 0),
        Problem::Denoising { .. } => (0, m + 1),
    };
    let nrows = eq_rows + soc_rows + 2 * n;
    let off_a = match problem {
        Problem::BasisPursuit => 0,
        Problem::Denoising { .. } => 1,
    };
    let mut colptr = Vec::with_capacity(nv + 1);
    let mut rowval = Vec::new();
    let mut nzval = Vec::new();
    let lin0 = eq_rows + soc_rows;
    colptr.push(0);
    for k in 0..n {
        for (r, &i) in idx.iter().enumerate() {
            rowval.push(off_a + r);
            // SOC: s = b - A x = (ε, h - Aθ) so the A block enters with +Ψ as for equality.
            nzval.push(dct.basis(i, k));
        }
        rowval.push(lin0 + k);
        nzval.push(1.0);
        rowval.push(lin0 + n + k);
        nzval.push(-1.0);
        colptr.push(rowval.len());
    }
    for k in 0..n {
        rowval.push(lin0 + k);
        nzval.push(-1.0);
        rowval.push(lin0 + n + k);
        nzval.push(-1.0);
        colptr.push(rowval.len());
    }
    let a = CscMatrix::new(nrows, nv, colptr, rowval, nzval);
    let mut b = vec![0.0; nrows];
    let mut cones = Vec::new();
    match problem {
        Problem::BasisPursuit => {
            b[..m].copy_from_slice(h);
            cones.push(SupportedConeT::ZeroConeT(m));
        }
        Problem::Denoising { epsilon } => {
            b[0] = epsilon;
            b[1..=m].copy_from_slice(h);
            cones.push(SupportedConeT::SecondOrderConeT(m + 1));
        }
    }
    cones.push(SupportedConeT::NonnegativeConeT(2 * n));
    let settings = DefaultSettingsBuilder::default()
        .verbose(false)
        .tol_gap_abs(1e-10)
        .tol_gap_rel(1e-10)
        .tol_feas(1e-10)
        .max_iter(400)
        .build()
        .expect("valid Clarabel settings");
    let mut solver = match DefaultSolver::new(&p, &q, &a, &b, &cones, settings) {
        Ok(s) => s,
        Err(_) => {
            return BpSolution {
                theta: vec![0.0; n],
                status: SolveStatus::Failed,
                iterations: 0,
                objective: f64::NAN,
                dual_objective: f64::NAN,
                solve_ms: t0.elapsed().as_secs_f64() * 1e3,
                signal: None,
            }
        }
    };
    solver.solve();
    let sol = &solver.solution;
    let status = match sol.status {
        SolverStatus::Solved => SolveStatus::Optimal,
        SolverStatus::AlmostSolved => SolveStatus::Solved,
        SolverStatus::MaxIterations => SolveStatus::MaxIterations,
        _ => SolveStatus::Failed,
    };
    let theta = sol.x[..n].to_vec();
    BpSolution {
        objective: theta.iter().map(|v| v.abs()).sum(),
        dual_objective: sol.obj_val_dual,
        theta,
        status,
        iterations: sol.iterations as usize,
        solve_ms: t0.elapsed().as_secs_f64() * 1e3,
        signal: None,
    }
}

#[cfg(test)]
mod tests;
