//! Basis pursuit (paper Eq. 5) and basis pursuit denoising in the orthonormal DCT basis.
//!
//! Two solvers for the same problems:
//! - [`solve_clarabel`]: the generic LP/SOCP through Clarabel with the dense sampled basis; the
//!   reference, slow (tens of seconds at n = 1901, m = 600).
//! - [`solve_fast`]: ADMM whose projection onto {Aθ = h} is one DCT pair (A·Aᵀ = I), followed by
//!   an exact *polish*: the BP optimum is a vertex with m non-zeros, so once ADMM has found the
//!   support S the square system A_S θ_S = h gives the exact primal, A_Sᵀ y = sign(θ_S) the dual,
//!   and ||Aᵀy||∞ ≤ 1 (one more DCT) certifies optimality with a zero duality gap.
use std::time::Instant;

use nalgebra::{DMatrix, DVector};

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
    /// First ADMM iteration at which a polish is tried; then every `polish_growth`x further.
    pub first_polish: usize,
    pub polish_growth: f64,
    /// Dual feasibility slack accepted by the certificate (||Aᵀy||∞ ≤ 1 + tol).
    pub certificate_tol: f64,
    /// Relative primal/dual residual at which plain ADMM stops (BPDN, or when polishing fails).
    pub admm_tol: f64,
    /// BP: ADMM iterations before the exact simplex finish, and its pivot budget.
    pub warm_iter: usize,
    pub max_pivots: usize,
}

impl Default for FastSettings {
    fn default() -> Self {
        Self {
            max_iter: 20_000,
            first_polish: 40,
            polish_growth: 1.6,
            certificate_tol: 1e-9,
            admm_tol: 1e-10,
            warm_iter: 60,
            max_pivots: 5000,
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
}

fn soft(v: f64, t: f64) -> f64 {
    if v > t {
        v - t
    } else if v < -t {
        v + t
    } else {
        0.0
    }
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

    // Projection onto the constraint set, done on the signal g = Ψv.
    let project = |dct: &mut Dct, v: &mut [f64]| {
        dct.inverse(v);
        match problem {
            Problem::BasisPursuit => {
                for (k, &i) in idx.iter().enumerate() {
                    v[i] = h[k];
                }
            }
            Problem::Denoising { epsilon } => {
                let r2: f64 = idx.iter().zip(h).map(|(&i, &hk)| (v[i] - hk).powi(2)).sum();
                let r = r2.sqrt();
                if r > epsilon {
                    let f = epsilon / r;
                    for (k, &i) in idx.iter().enumerate() {
                        v[i] = h[k] + (v[i] - h[k]) * f;
                    }
                }
            }
        }
        dct.forward(v);
    };

    // Warm start at the minimum-energy solution x0 = Aᵀh.
    let mut x = vec![0.0; n];
    project(dct, &mut x);
    let scale = x.iter().map(|v| v.abs()).fold(0.0, f64::max).max(1e-300);
    // Threshold 1/ρ a few percent of the largest coefficient: fast support discovery.
    let mut rho = 20.0 / scale;
    let mut z: Vec<f64> = x.iter().map(|&v| soft(v, 1.0 / rho)).collect();
    let mut u = vec![0.0; n];
    let mut v = vec![0.0; n];
    let mut next_polish = s.first_polish as f64;
    let mut iterations = 0;
    let mut status = SolveStatus::MaxIterations;

    for it in 1..=s.max_iter {
        iterations = it;
        for i in 0..n {
            v[i] = z[i] - u[i];
        }
        project(dct, &mut v);
        std::mem::swap(&mut x, &mut v);
        let mut r2 = 0.0;
        let mut s2 = 0.0;
        let inv = 1.0 / rho;
        for i in 0..n {
            let zi = soft(x[i] + u[i], inv);
            s2 += (zi - z[i]).powi(2);
            z[i] = zi;
            let ri = x[i] - zi;
            r2 += ri * ri;
            u[i] += ri;
        }
        let zn = z.iter().map(|v| v * v).sum::<f64>().sqrt().max(1e-300);
        let (r, sd) = (r2.sqrt() / zn, rho * s2.sqrt() / zn);
        // Residual balancing keeps primal and dual progress in step.
        if it % 10 == 0 {
            let f = if r > 10.0 * sd {
                2.0
            } else if sd > 10.0 * r {
                0.5
            } else {
                1.0
            };
            if f != 1.0 {
                rho *= f;
                for ui in u.iter_mut() {
                    *ui /= f;
                }
            }
        }
        if matches!(problem, Problem::BasisPursuit) && it == s.warm_iter {
            let support = rank_support(&z, &u, rho, m);
            if let Some(r) =
                super::simplex::finish(dct, idx, h, support, s.max_pivots, s.certificate_tol)
            {
                let obj = r.theta.iter().map(|v| v.abs()).sum();
                return BpSolution {
                    theta: r.theta,
                    status: SolveStatus::Optimal,
                    iterations: it + r.pivots,
                    objective: obj,
                    dual_objective: r.dual_objective,
                    solve_ms: t0.elapsed().as_secs_f64() * 1e3,
                };
            }
        }
        if matches!(problem, Problem::BasisPursuit) && it as f64 >= next_polish {
            next_polish *= s.polish_growth;
            if let Some((theta, dual)) = polish(dct, idx, h, &z, &u, rho, s.certificate_tol) {
                let obj = theta.iter().map(|v| v.abs()).sum();
                return BpSolution {
                    theta,
                    status: SolveStatus::Optimal,
                    iterations,
                    objective: obj,
                    dual_objective: dual,
                    solve_ms: t0.elapsed().as_secs_f64() * 1e3,
                };
            }
        }
        if r < s.admm_tol && sd < s.admm_tol {
            status = SolveStatus::Solved;
            break;
        }
    }
    let theta = match problem {
        // Return a feasible point: the projection of z.
        Problem::BasisPursuit => {
            let mut t = z.clone();
            project(dct, &mut t);
            t
        }
        Problem::Denoising { .. } => z,
    };
    let objective = theta.iter().map(|v| v.abs()).sum();
    BpSolution {
        theta,
        status,
        iterations,
        objective,
        dual_objective: f64::NAN,
        solve_ms: t0.elapsed().as_secs_f64() * 1e3,
    }
}

/// The m columns most likely in the optimal basis: ADMM's non-zeros by magnitude, then the
/// columns whose dual ρu is closest to ±1.
fn rank_support(z: &[f64], u: &[f64], rho: f64, m: usize) -> Vec<usize> {
    let key = |k: usize| {
        if z[k] != 0.0 {
            2.0 + z[k].abs()
        } else {
            (rho * u[k]).abs().min(1.0)
        }
    };
    let mut order: Vec<usize> = (0..z.len()).collect();
    order.sort_unstable_by(|&a, &b| {
        key(b)
            .partial_cmp(&key(a))
            .unwrap_or(std::cmp::Ordering::Equal)
    });
    order.truncate(m);
    order
}

/// Exact solve on the support ADMM found, and its dual certificate. Returns (θ, hᵀy) when certified.
///
/// Non-degenerate BP optima have exactly m non-zeros (a square, invertible A_S); sparse signals
/// give fewer (a tall A_S, least squares that must fit exactly). The dual starts from ADMM's
/// estimate y₀ = A(ρu) and is corrected minimally so that A_Sᵀy = sign(θ_S); the point is optimal
/// when ||Aᵀy||∞ ≤ 1, since then hᵀy = ||θ||₁.
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
    let mut support: Vec<usize> = (0..n).filter(|&k| z[k] != 0.0).collect();
    if support.is_empty() {
        return None;
    }
    if support.len() > m {
        support.sort_unstable_by(|&a, &b| {
            z[b].abs()
                .partial_cmp(&z[a].abs())
                .unwrap_or(std::cmp::Ordering::Equal)
        });
        support.truncate(m);
    }
    let k = support.len();
    let a_s = DMatrix::from_fn(m, k, |r, c| dct.basis(idx[r], support[c]));
    let hv = DVector::from_column_slice(h);
    // Dual estimate from ADMM: y0 = A·(ρu), i.e. the sampled signal of ρu.
    let mut yu: Vec<f64> = u.iter().map(|v| rho * v).collect();
    dct.inverse(&mut yu);
    let y0 = DVector::from_iterator(m, idx.iter().map(|&i| yu[i]));
    let (theta_s, y) = if k == m {
        let lu = a_s.clone().lu();
        let theta_s = lu.solve(&hv)?;
        let sign = theta_s.map(|v| if v >= 0.0 { 1.0 } else { -1.0 });
        (theta_s, lu_transpose_solve(&lu, &sign)?)
    } else {
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
        (theta_s, y0 + q * c)
    };
    if theta_s.iter().chain(y.iter()).any(|v| !v.is_finite()) {
        return None;
    }
    // w = Aᵀy = Ψᵀ(scatter y): the certificate needs |w| ≤ 1 everywhere.
    let mut w = vec![0.0; n];
    for (r, &i) in idx.iter().enumerate() {
        w[i] = y[r];
    }
    dct.forward(&mut w);
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

/// Solves Aᵀx = b with the LU of A (nalgebra has no transpose solve): P A = L U, so
/// Aᵀ = Uᵀ Lᵀ P⁻ᵀ and x = Pᵀ (Lᵀ)⁻¹ (Uᵀ)⁻¹ b.
fn lu_transpose_solve(
    lu: &nalgebra::linalg::LU<f64, nalgebra::Dyn, nalgebra::Dyn>,
    b: &DVector<f64>,
) -> Option<DVector<f64>> {
    let w = lu.u().transpose().solve_lower_triangular(b)?;
    let mut x = lu.l().transpose().solve_upper_triangular(&w)?;
    lu.p().inv_permute_rows(&mut x);
    Some(x)
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
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    fn sparse_problem(n: usize, s: usize, m: usize, seed: u64) -> (Vec<f64>, Vec<usize>, Vec<f64>) {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        let mut theta = vec![0.0; n];
        for _ in 0..s {
            let k = rng.random_range(0..n);
            theta[k] = rng.random_range(0.5..2.0) * if rng.random::<bool>() { 1.0 } else { -1.0 };
        }
        let mut g = theta.clone();
        Dct::new(n).inverse(&mut g);
        let idx = crate::sampling::Design::new(crate::sampling::DesignKind::Random, m, seed)
            .indices(n)
            .unwrap();
        let h = idx.iter().map(|&i| g[i]).collect();
        (theta, idx, h)
    }

    /// Exact recovery of an s-sparse DCT signal from m ≈ 4 s ln n samples.
    #[test]
    fn lu_transpose_solve_solves_the_transpose() {
        let a = DMatrix::from_fn(5, 5, |r, c| {
            ((r * 7 + c * 3) % 11) as f64 - 5.0 + if r == c { 9.0 } else { 0.0 }
        });
        let b = DVector::from_fn(5, |r, _| r as f64 - 1.5);
        let x = lu_transpose_solve(&a.clone().lu(), &b).unwrap();
        assert!((a.transpose() * x - b).norm() < 1e-12);
    }

    #[test]
    fn exact_recovery_of_sparse_signal() {
        let (n, s) = (1024, 8);
        let m = (4.0 * s as f64 * (n as f64).ln()).ceil() as usize;
        for seed in 0..3 {
            let (theta, idx, h) = sparse_problem(n, s, m, seed);
            let mut dct = Dct::new(n);
            let sol = solve_fast(
                &mut dct,
                &idx,
                &h,
                Problem::BasisPursuit,
                &FastSettings::default(),
            );
            assert_eq!(sol.status, SolveStatus::Optimal, "seed {seed}");
            let err = theta
                .iter()
                .zip(&sol.theta)
                .map(|(a, b)| (a - b).abs())
                .fold(0.0, f64::max);
            assert!(err < 1e-8, "seed {seed}: max coefficient error {err}");
        }
    }

    /// The fast solver and Clarabel agree on a paper-like curve: objective within 1e-6 relative,
    /// recovered curve within 1e-6 µm.
    #[test]
    fn fast_solver_agrees_with_clarabel() {
        use csmetro_sim::reference::{error_curve, paper_like_model, ReferenceCurveParams};
        let n = 381;
        let grid: Vec<f64> = (0..n).map(|i| i as f64 * 25.0).collect();
        let params = ReferenceCurveParams {
            travel_um: [0.0, 9500.0],
            ..Default::default()
        };
        for (seed, m) in [(1u64, 60usize), (2, 120)] {
            let f = error_curve(
                &paper_like_model(seed, &params),
                csmetro_sim::AxisId::X,
                &grid,
                0.0,
            );
            let idx = crate::sampling::Design::new(crate::sampling::DesignKind::Random, m, seed)
                .indices(n)
                .unwrap();
            let h: Vec<f64> = idx.iter().map(|&i| f[i]).collect();
            let mut dct = Dct::new(n);
            let fast = solve_fast(
                &mut dct,
                &idx,
                &h,
                Problem::BasisPursuit,
                &FastSettings::default(),
            );
            let refr = solve_clarabel(&dct, &idx, &h, Problem::BasisPursuit);
            assert_eq!(fast.status, SolveStatus::Optimal);
            assert_eq!(refr.status, SolveStatus::Optimal);
            let rel = (fast.objective - refr.objective).abs() / refr.objective;
            assert!(
                rel < 1e-6,
                "seed {seed}: objective {} vs {} (rel {rel:e})",
                fast.objective,
                refr.objective
            );
            assert!(
                (fast.dual_objective - fast.objective).abs() < 1e-9 * fast.objective,
                "certificate gap"
            );
            let (mut g1, mut g2) = (fast.theta.clone(), refr.theta.clone());
            dct.inverse(&mut g1);
            dct.inverse(&mut g2);
            let d = g1
                .iter()
                .zip(&g2)
                .map(|(a, b)| (a - b).abs())
                .fold(0.0, f64::max);
            assert!(d < 1e-6, "seed {seed}: max curve difference {d:e} µm");
            for (k, &i) in idx.iter().enumerate() {
                assert!(
                    (g1[i] - h[k]).abs() < 1e-9,
                    "fast BP must interpolate the samples"
                );
            }
        }
    }

    /// BPDN keeps the residual inside the noise ball and agrees with Clarabel's objective.
    #[test]
    fn bpdn_respects_the_noise_ball() {
        let (n, s, m) = (256, 6, 80);
        let (_, idx, h) = sparse_problem(n, s, m, 9);
        let eps = 0.05;
        let mut dct = Dct::new(n);
        let fast = solve_fast(
            &mut dct,
            &idx,
            &h,
            Problem::Denoising { epsilon: eps },
            &FastSettings::default(),
        );
        let mut g = fast.theta.clone();
        dct.inverse(&mut g);
        let r = idx
            .iter()
            .zip(&h)
            .map(|(&i, hk)| (g[i] - hk).powi(2))
            .sum::<f64>()
            .sqrt();
        assert!(r <= eps * (1.0 + 1e-6), "residual {r} > {eps}");
        let refr = solve_clarabel(&dct, &idx, &h, Problem::Denoising { epsilon: eps });
        let rel = (fast.objective - refr.objective).abs() / refr.objective;
        assert!(
            rel < 1e-4,
            "objective {} vs {} (rel {rel:e})",
            fast.objective,
            refr.objective
        );
    }
}
