//! Tests of the BP / BPDN solvers on known problems.
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

/// Basis pursuit with the default settings.
fn bp_default(dct: &mut Dct, idx: &[usize], h: &[f64]) -> BpSolution {
    solve_fast(dct, idx, h, Problem::BasisPursuit, &FastSettings::default())
}

/// A paper-like curve on n points `step_um` apart, sampled at m random grid points.
fn paper_problem(n: usize, step_um: f64, m: usize, seed: u64) -> (Vec<usize>, Vec<f64>) {
    let f = crate::recon::test_curve::paper_like(n, step_um, seed);
    let idx = crate::sampling::Design::new(crate::sampling::DesignKind::Random, m, seed)
        .indices(n)
        .unwrap();
    let h = idx.iter().map(|&i| f[i]).collect();
    (idx, h)
}

/// Exact recovery of an s-sparse DCT signal from m ≈ 4 s ln n samples.
#[test]
fn exact_recovery_of_sparse_signal() {
    let (n, s) = (1024, 8);
    let m = (4.0 * s as f64 * (n as f64).ln()).ceil() as usize;
    for seed in 0..3 {
        let (theta, idx, h) = sparse_problem(n, s, m, seed);
        let mut dct = Dct::new(n);
        let sol = bp_default(&mut dct, &idx, &h);
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
    // 381 = 3·127 and the prime 383 (odd lengths: rustdct, realfft in the f32 ranking). Each
    // problem is solved from both first anchors (the f32 LU, and the Gram matrix's Cholesky
    // that serves from `gram_min_m` samples).
    let gram = FastSettings {
        gram_min_m: 0,
        ..Default::default()
    };
    for (n, seed, m) in [(381, 1u64, 60usize), (381, 2, 120), (383, 3, 120)] {
        let (idx, h) = paper_problem(n, 25.0, m, seed);
        let mut dct = Dct::new(n);
        let refr = solve_clarabel(&dct, &idx, &h, Problem::BasisPursuit);
        assert_eq!(refr.status, SolveStatus::Optimal);
        let lu = bp_default(&mut dct, &idx, &h);
        let gr = solve_fast(&mut dct, &idx, &h, Problem::BasisPursuit, &gram);
        for fast in [lu, gr] {
            assert_eq!(fast.status, SolveStatus::Optimal);
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
}

/// The f64 update's norms are the real sums of squares, and the update itself soft-thresholds
/// x̂ + u: here (α = 1, u = 0, z = 0) z = soft(x, 1/4), u = x − z, v = z − u.
#[test]
fn double_update_reports_the_residual_norms() {
    let x = [1.0, -2.0, 0.5, 3.0, 0.1];
    let (mut z, mut u, mut v) = ([0.0; 5], [0.0; 5], [0.0; 5]);
    let st = admm_update::<f64, true>(&x, &mut z, &mut u, &mut v, 1.0, 0.25);
    assert_eq!(z, [0.75, -1.75, 0.25, 2.75, 0.0]);
    assert_eq!((st.changed, st.nnz), (true, 4));
    for k in 0..5 {
        assert_eq!(u[k], x[k] - z[k]);
        assert_eq!(v[k], z[k] - u[k]);
    }
    assert!(
        (st.z2 - (0.75f64.powi(2) + 1.75f64.powi(2) + 0.25f64.powi(2) + 2.75f64.powi(2))).abs()
            < 1e-12
    );
    assert!((st.r2 - 4.0 * 0.25f64.powi(2) - 0.1f64.powi(2)).abs() < 1e-12);
    assert!((st.s2 - st.z2).abs() < 1e-12);
    // The same support again (x = z, u = 0, no threshold) is no change; f32 without norms
    // leaves them zero.
    let xs: Vec<f32> = z.iter().map(|&v| v as f32).collect();
    let (mut zs, mut us, mut vs) = (xs.clone(), vec![0.0f32; 5], vec![0.0f32; 5]);
    let again = admm_update::<f32, false>(&xs, &mut zs, &mut us, &mut vs, 1.0, 0.0);
    assert_eq!((again.changed, again.nnz), (false, 4));
    assert_eq!((again.r2, again.s2, again.z2), (0.0, 0.0, 0.0));
}

#[test]
fn zero_samples_give_the_zero_curve() {
    let mut dct = Dct::new(1901);
    let idx: Vec<usize> = (0..1901).step_by(7).collect();
    let h = vec![0.0; idx.len()];
    for problem in [Problem::BasisPursuit, Problem::Denoising { epsilon: 0.1 }] {
        let sol = solve_fast(&mut dct, &idx, &h, problem, &FastSettings::default());
        assert_eq!(sol.status, SolveStatus::Optimal);
        assert!(sol.theta.iter().all(|&v| v == 0.0));
        assert_eq!((sol.objective, sol.dual_objective), (0.0, 0.0));
    }
}

/// Above the exact finish's size BP stops at a certified gap: the returned θ reproduces the
/// samples, and [hᵀy, ||θ||₁] brackets the true optimum (taken from the exact finish).
#[test]
fn gap_certified_path_brackets_the_optimum() {
    let n = 2048;
    let (idx, h) = paper_problem(n, 4.0, 300, 3);
    let mut dct = Dct::new(n);
    let exact = bp_default(&mut dct, &idx, &h);
    assert_eq!(exact.status, SolveStatus::Optimal);
    for tol in [1e-2, 1e-3] {
        let s = FastSettings {
            exact_max_m: 0,
            gap_tol: tol,
            ..Default::default()
        };
        let r = solve_fast(&mut dct, &idx, &h, Problem::BasisPursuit, &s);
        assert_eq!(r.status, SolveStatus::Solved);
        assert!(r.objective - r.dual_objective <= tol * r.objective);
        assert!(
            r.dual_objective <= exact.objective * (1.0 + 1e-12)
                && exact.objective <= r.objective * (1.0 + 1e-12),
            "tol {tol}: optimum {} outside [{}, {}]",
            exact.objective,
            r.dual_objective,
            r.objective
        );
        let mut g = r.theta.clone();
        dct.inverse(&mut g);
        for (k, &i) in idx.iter().enumerate() {
            assert!((g[i] - h[k]).abs() < 1e-9, "samples reproduced");
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
