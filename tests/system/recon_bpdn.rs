//! `bpdn` (min ||θ||₁ s.t. ||Aθ − h||₂ ≤ ε, A = sampled orthonormal inverse DCT) on data from
//! generators written here, independent of the simulator and of the solver: the answer lies in the
//! noise ball, its reported duality gap brackets Clarabel's optimum, it recovers a known sparse
//! signal, and `reconstruct --json` reports the certified gap.
use std::process::Command;

use csmetro::recon::bp::{solve_clarabel, solve_fast, FastSettings, Problem, SolveStatus};
use csmetro::recon::dct::Dct;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

/// m distinct sorted grid indices out of n, drawn here (not by csmetro's sampling designs).
fn draw_indices(n: usize, m: usize, rng: &mut ChaCha8Rng) -> Vec<usize> {
    let mut all: Vec<usize> = (0..n).collect();
    for k in 0..m {
        let j = rng.random_range(k..n);
        all.swap(k, j);
    }
    let mut idx = all[..m].to_vec();
    idx.sort_unstable();
    idx
}

/// A stage-like error curve in µm on n points 5 µm apart: a linear scale error, a bow, a
/// leadscrew-like period with its second harmonic and a slow envelope, a local defect, plus
/// correlated roughness. Built from closed forms, not from csmetro's DCT or simulator.
fn stage_curve(n: usize, rng: &mut ChaCha8Rng) -> Vec<f64> {
    let len = 5.0 * (n - 1) as f64;
    let period = rng.random_range(150.0..900.0);
    let (p1, p2) = (
        rng.random_range(0.0..std::f64::consts::TAU),
        rng.random_range(0.0..std::f64::consts::TAU),
    );
    let scale = rng.random_range(-2.0..2.0);
    let bow = rng.random_range(-1.0..1.0);
    let amp = rng.random_range(0.3..1.0);
    let defect_at = rng.random_range(0.2..0.8) * len;
    let mut rough = 0.0;
    (0..n)
        .map(|i| {
            let x = 5.0 * i as f64;
            let t = x / len;
            let w = std::f64::consts::TAU * x / period;
            rough = 0.9 * rough + 0.01 * rng.random_range(-1.0..1.0);
            scale * t
                + bow * 4.0 * t * (1.0 - t)
                + amp * (1.0 + 0.3 * t) * (w + p1).sin()
                + 0.2 * amp * (2.0 * w + p2).sin()
                + 0.4 * (-((x - defect_at) / 60.0).powi(2)).exp()
                + rough
        })
        .collect()
}

/// Residual norm ||(Ψθ)[idx] − h||₂ through a plain O(n·m) sum of the DCT-III formula.
fn residual_norm(theta: &[f64], idx: &[usize], h: &[f64]) -> f64 {
    let n = theta.len() as f64;
    idx.iter()
        .zip(h)
        .map(|(&i, &hk)| {
            let g: f64 = theta
                .iter()
                .enumerate()
                .map(|(k, &t)| {
                    let c = if k == 0 {
                        (1.0 / n).sqrt()
                    } else {
                        (2.0 / n).sqrt()
                    };
                    t * c * (std::f64::consts::PI * k as f64 * (2 * i + 1) as f64 / (2.0 * n)).cos()
                })
                .sum();
            (g - hk).powi(2)
        })
        .sum::<f64>()
        .sqrt()
}

fn noisy_samples(f: &[f64], idx: &[usize], sigma: f64, rng: &mut ChaCha8Rng) -> Vec<f64> {
    let noise = Normal::new(0.0, sigma).unwrap();
    idx.iter().map(|&i| f[i] + noise.sample(rng)).collect()
}

/// On stage-like curves at several sizes the solution lies inside the noise ball, the solver
/// certifies it optimal by its own active set (status `optimal`, gap ≤ 1e-9), and the dual bound
/// it reports is below its objective.
#[test]
fn bpdn_stays_in_the_noise_ball_with_a_certified_gap() {
    for (seed, n, m) in [(1u64, 601usize, 150usize), (2, 601, 300), (3, 1024, 200)] {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let f = stage_curve(n, &mut rng);
        let idx = draw_indices(n, m, &mut rng);
        let sigma = 0.01;
        let h = noisy_samples(&f, &idx, sigma, &mut rng);
        let eps = sigma * (m as f64).sqrt();
        let mut dct = Dct::new(n);
        let sol = solve_fast(
            &mut dct,
            &idx,
            &h,
            Problem::Denoising { epsilon: eps },
            &FastSettings::default(),
        );
        let r = residual_norm(&sol.theta, &idx, &h);
        assert!(
            r <= eps * (1.0 + 1e-9),
            "seed {seed}: residual {r} > ε {eps}"
        );
        assert_eq!(sol.status, SolveStatus::Optimal, "seed {seed}");
        let l1: f64 = sol.theta.iter().map(|v| v.abs()).sum();
        assert!(
            (sol.objective - l1).abs() <= 1e-12 * l1,
            "objective is ||θ||₁"
        );
        let gap = (sol.objective - sol.dual_objective) / sol.objective;
        assert!(
            (-1e-12..=1e-9).contains(&gap),
            "seed {seed}: relative gap {gap:e}"
        );
        // The noise ball is not the whole story: the curve stays close to the truth.
        let mut g = sol.theta.clone();
        dct.inverse(&mut g);
        let mae = g.iter().zip(&f).map(|(a, b)| (a - b).abs()).sum::<f64>() / n as f64;
        assert!(mae < 0.15, "seed {seed}: mean error {mae} µm");
    }
}

/// The reported bounds bracket the true optimum (Clarabel's interior point on the same SOCP):
/// dual ≤ optimum ≤ objective, for the active-set path and for the ADMM fallback alike.
#[test]
fn bpdn_gap_brackets_clarabels_optimum() {
    let (n, m) = (160usize, 56usize);
    for seed in [11u64, 12] {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let f = stage_curve(n, &mut rng);
        let idx = draw_indices(n, m, &mut rng);
        let h = noisy_samples(&f, &idx, 0.02, &mut rng);
        let eps = 0.02 * (m as f64).sqrt();
        let problem = Problem::Denoising { epsilon: eps };
        let mut dct = Dct::new(n);
        let reference = solve_clarabel(&dct, &idx, &h, problem);
        assert_eq!(reference.status, SolveStatus::Optimal);
        let opt = reference.objective;
        let fallback = FastSettings {
            bpdn_max_rounds: 0,
            gap_tol: 1e-3,
            ..Default::default()
        };
        for (name, s) in [("active set", FastSettings::default()), ("admm", fallback)] {
            let sol = solve_fast(&mut dct, &idx, &h, problem, &s);
            let (lo, hi) = (sol.dual_objective, sol.objective);
            assert!(lo.is_finite(), "{name}: a dual bound is reported");
            assert!(
                lo <= opt * (1.0 + 1e-7) && opt <= hi * (1.0 + 1e-7),
                "seed {seed} {name}: optimum {opt} outside [{lo}, {hi}]"
            );
            assert!(
                hi - lo <= s.gap_tol.max(1e-9) * hi,
                "{name}: gap {}",
                (hi - lo) / hi
            );
            assert!(residual_norm(&sol.theta, &idx, &h) <= eps * (1.0 + 1e-9));
        }
    }
}

/// An s-sparse DCT signal (coefficients well above the noise) sampled with noise: BPDN finds
/// its support and its coefficients to within a few σ.
#[test]
fn bpdn_recovers_a_sparse_signal() {
    let (n, s, m) = (1024usize, 10usize, 200usize);
    let sigma = 0.005;
    for seed in [21u64, 22, 23] {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut theta = vec![0.0; n];
        let mut support = Vec::new();
        while support.len() < s {
            let k = rng.random_range(0..n);
            if theta[k] == 0.0 {
                theta[k] =
                    rng.random_range(1.0..3.0) * if rng.random::<bool>() { 1.0 } else { -1.0 };
                support.push(k);
            }
        }
        // The signal from the DCT-III formula directly.
        let nf = n as f64;
        let f: Vec<f64> = (0..n)
            .map(|i| {
                support
                    .iter()
                    .map(|&k| {
                        let c = if k == 0 {
                            (1.0 / nf).sqrt()
                        } else {
                            (2.0 / nf).sqrt()
                        };
                        theta[k]
                            * c
                            * (std::f64::consts::PI * k as f64 * (2 * i + 1) as f64 / (2.0 * nf))
                                .cos()
                    })
                    .sum()
            })
            .collect();
        let idx = draw_indices(n, m, &mut rng);
        let h = noisy_samples(&f, &idx, sigma, &mut rng);
        let eps = sigma * (m as f64).sqrt();
        let mut dct = Dct::new(n);
        let sol = solve_fast(
            &mut dct,
            &idx,
            &h,
            Problem::Denoising { epsilon: eps },
            &FastSettings::default(),
        );
        assert_eq!(sol.status, SolveStatus::Optimal, "seed {seed}");
        let err = theta
            .iter()
            .zip(&sol.theta)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max);
        // The l1 bias shrinks each coefficient by about λ (~σ·√(m/n) scale): a few σ·√(n/m).
        assert!(err < 0.1, "seed {seed}: max coefficient error {err}");
        for &k in &support {
            assert!(
                sol.theta[k] * theta[k] > 0.0,
                "seed {seed}: coefficient {k} found"
            );
        }
    }
}

/// `csmetro reconstruct --method bpdn --json` reports the certified relative gap, status optimal.
#[test]
fn reconstruct_json_reports_the_bpdn_gap() {
    let dir = tempfile::tempdir().unwrap();
    let n = 401;
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let f = stage_curve(n, &mut rng);
    let idx = draw_indices(n, 120, &mut rng);
    let h = noisy_samples(&f, &idx, 0.01, &mut rng);
    let mut csv = String::from("position_um,error_um\n");
    for (&i, v) in idx.iter().zip(&h) {
        csv.push_str(&format!("{},{v}\n", 5 * i));
    }
    let path = dir.path().join("samples.csv");
    std::fs::write(&path, csv).unwrap();
    let o = Command::new(env!("CARGO_BIN_EXE_csmetro"))
        .args([
            "reconstruct",
            "--method",
            "bpdn",
            "--grid",
            "0:5:2000",
            "--json",
        ])
        .arg("--samples")
        .arg(&path)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(v["status"], "optimal", "{v}");
    let gap = v["relative_gap"].as_f64().expect("relative_gap reported");
    assert!((0.0..=1e-9).contains(&gap), "{v}");
    let (p, d) = (
        v["objective"].as_f64().unwrap(),
        v["dual_objective"].as_f64().unwrap(),
    );
    assert!(d <= p && (p - d) / p <= 1e-9, "{v}");
}
