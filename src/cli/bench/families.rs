//! `bench families`: `auto` on error curves the stage simulator did not make.
//!
//! A generator of its own (not `csmetro_sim`'s model, not the recon code): trend, cyclic terms of
//! periods drawn anywhere in 80–2,000 µm with harmonics and slowly varying envelopes, correlated
//! roughness and white noise, in six families. Per family and m it reports `auto` (no pitch)
//! against `physics` told the true period, `bp` and `pchip`, how often periods were detected, and
//! how `auto`'s `cv_error_um` compares with its true error.
use std::f64::consts::TAU;

use serde::Serialize;

use crate::grid::Grid;
use crate::recon::{self, Method, ReconSettings};
use crate::samples::GridSamples;

pub(super) const FAMILIES: [&str; 6] = ["single", "two", "limit", "chirp", "noise", "steps"];

/// SplitMix64 (independent of the project's generators).
struct Rng(u64);
impl Rng {
    fn next(&mut self) -> f64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64
    }
    fn gauss(&mut self) -> f64 {
        let (u, v) = (self.next().max(1e-300), self.next());
        (-2.0 * u.ln()).sqrt() * (TAU * v).cos()
    }
    /// Log-uniform in [lo, hi].
    fn log_uniform(&mut self, lo: f64, hi: f64) -> f64 {
        (lo.ln() + self.next() * (hi / lo).ln()).exp()
    }
}

/// One curve of `family` on `grid` (µm) and its true periods (the first is the dominant one).
pub(super) fn curve(family: &str, grid: &Grid, seed: u64) -> (Vec<f64>, Vec<f64>) {
    let mut r = Rng(seed.wrapping_mul(0x2545_F491_4F6C_DD1D) ^ family.len() as u64);
    let n = grid.n;
    let span = grid.step_um * (n - 1) as f64;
    let periods: Vec<f64> = match family {
        "single" | "chirp" | "steps" => vec![r.log_uniform(80.0, 2000.0)],
        "two" => {
            let p1 = r.log_uniform(80.0, 2000.0);
            // A second period at an irrational-looking ratio 1.3–2.7 away, inside 80–2,000 µm.
            let ratio = 1.3 + 1.4 * r.next();
            let p2 = if p1 * ratio <= 2000.0 {
                p1 * ratio
            } else {
                p1 / ratio
            };
            vec![p1, p2.clamp(80.0, 2000.0)]
        }
        "limit" => vec![grid.step_um * (2.1 + 0.8 * r.next())],
        _ => Vec::new(),
    };
    let amps: Vec<f64> = periods
        .iter()
        .enumerate()
        .map(|(k, _)| (0.5 + r.next()) / (1 + k) as f64)
        .collect();
    let (bow, tilt, cubic) = (2.0 * r.gauss(), r.gauss(), 0.5 * r.gauss());
    let phases: Vec<[f64; 3]> = periods
        .iter()
        .map(|_| [TAU * r.next(), TAU * r.next(), TAU * r.next()])
        .collect();
    let env: Vec<f64> = periods.iter().map(|_| 0.3 * (r.next() - 0.5)).collect();
    // Chirp: the period drifts linearly by up to ±4 % over the travel.
    let drift = if family == "chirp" {
        0.08 * (r.next() - 0.5)
    } else {
        0.0
    };
    let rough_amp = if family == "noise" { 0.3 } else { 0.03 };
    // Steps and local defects: a few jumps and Gaussian bumps.
    let steps: Vec<(f64, f64)> = if family == "steps" {
        (0..3).map(|_| (span * r.next(), 0.3 * r.gauss())).collect()
    } else {
        Vec::new()
    };
    let bumps: Vec<(f64, f64, f64)> = if family == "steps" {
        (0..3)
            .map(|_| (span * r.next(), 0.5 * r.gauss(), 20.0 + 60.0 * r.next()))
            .collect()
    } else {
        Vec::new()
    };
    // Roughness: exponentially correlated (AR(1) along the grid, 15 µm correlation length).
    let phi = (-grid.step_um / 15.0f64).exp();
    let mut ar = r.gauss();
    let mut out = Vec::with_capacity(n);
    for i in 0..n {
        let x = i as f64 * grid.step_um;
        let s = 2.0 * x / span - 1.0;
        let mut v = bow * s * s + tilt * s + cubic * s * s * s;
        for (k, &p) in periods.iter().enumerate() {
            // Phase of a period drifting as p·(1 + drift·s): ∫ 2π/p(x) dx.
            let ph = if drift != 0.0 {
                TAU * span / (2.0 * p * drift) * ((1.0 + drift * s) / (1.0 - drift)).ln()
            } else {
                TAU * x / p
            };
            let [f1, f2, f3] = phases[k];
            let e = 1.0 + env[k] * s;
            v += amps[k]
                * e
                * ((ph + f1).sin() + 0.3 * (2.0 * ph + f2).sin() + 0.1 * (3.0 * ph + f3).sin());
        }
        for &(at, h) in &steps {
            if x >= at {
                v += h;
            }
        }
        for &(at, h, w) in &bumps {
            v += h * (-((x - at) / w).powi(2)).exp();
        }
        ar = phi * ar + (1.0 - phi * phi).sqrt() * r.gauss();
        out.push(v + rough_amp * ar);
    }
    // Noise-free: sensor noise ([`noise_of`]) is added when sampling.
    (out, periods)
}

/// Sensor noise σ of a family, µm.
pub(super) fn noise_of(family: &str) -> f64 {
    if family == "noise" {
        0.1
    } else {
        0.01
    }
}

/// m distinct random grid indices, ascending (partial Fisher–Yates).
pub(super) fn pick(n: usize, m: usize, seed: u64) -> Vec<usize> {
    let mut r = Rng(seed ^ 0x5DEE_CE66);
    let mut all: Vec<usize> = (0..n).collect();
    for i in 0..m.min(n) {
        let j = i + (r.next() * (n - i) as f64) as usize;
        all.swap(i, j.min(n - 1));
    }
    let mut idx = all[..m.min(n)].to_vec();
    idx.sort_unstable();
    idx
}

#[derive(Debug, Clone, Serialize)]
pub(super) struct FamilyRow {
    pub(super) family: String,
    pub(super) m: usize,
    pub(super) seeds: u64,
    /// Mean over seeds of the mean |g − f| over the grid, µm.
    pub(super) auto_um: f64,
    pub(super) physics_told_um: f64,
    pub(super) bp_um: f64,
    pub(super) pchip_um: f64,
    /// auto / physics told the true period.
    pub(super) auto_over_told: f64,
    /// auto / min(bp, pchip) (means over seeds).
    pub(super) auto_over_best_baseline: f64,
    pub(super) mean_cv_error_um: f64,
    /// Mean over seeds of cv_error_um / true error, and its extremes.
    pub(super) cv_ratio_mean: f64,
    pub(super) cv_ratio_min: f64,
    pub(super) cv_ratio_max: f64,
    /// Fraction of curves with at least one period detected.
    pub(super) detected: f64,
    /// Fraction of curves whose dominant true period was found within 1 %.
    pub(super) dominant_found: f64,
    pub(super) picks: std::collections::BTreeMap<String, usize>,
    pub(super) median_auto_ms: f64,
}

fn mean_abs(g: &[f64], f: &[f64]) -> f64 {
    g.iter().zip(f).map(|(a, b)| (a - b).abs()).sum::<f64>() / f.len() as f64
}

pub(super) fn run(seeds: u64, ms: &[usize], families: &[String]) -> Result<Vec<FamilyRow>, String> {
    let grid: Grid = "0:5:9500".parse()?;
    let mut rows = Vec::new();
    for fam in families {
        if !FAMILIES.contains(&fam.as_str()) {
            return Err(format!("unknown family {fam:?} (one of {FAMILIES:?})"));
        }
        for &m in ms {
            let mut acc = [0.0f64; 5];
            let (mut ratios, mut times) = (Vec::new(), Vec::new());
            let (mut detected, mut dominant) = (0usize, 0usize);
            let mut picks = std::collections::BTreeMap::new();
            for seed in 0..seeds {
                let (truth, periods) = curve(fam, &grid, seed);
                let idx = pick(grid.n, m, 7919 * seed + m as u64);
                let sigma = noise_of(fam);
                let mut r = Rng(seed ^ 0xA5A5_0000 ^ m as u64);
                let samples = GridSamples {
                    values: idx.iter().map(|&i| truth[i] + sigma * r.gauss()).collect(),
                    idx,
                };
                let run = |method: Method, pitch: Option<f64>| {
                    let s = ReconSettings {
                        method,
                        pitch_um: pitch,
                        noise_um: sigma,
                        ..Default::default()
                    };
                    recon::reconstruct(&grid, &samples, &s)
                };
                let auto = run(Method::Auto, None)?;
                let e_auto = mean_abs(&auto.values, &truth);
                let told = run(Method::Physics, periods.first().copied())?;
                let bp = run(Method::Bp, None)?;
                let pchip = run(Method::Pchip, None)?;
                acc[0] += e_auto;
                acc[1] += mean_abs(&told.values, &truth);
                acc[2] += mean_abs(&bp.values, &truth);
                acc[3] += mean_abs(&pchip.values, &truth);
                let cv = auto.cv_error_um.unwrap_or(f64::NAN);
                acc[4] += cv;
                ratios.push(cv / e_auto);
                times.push(auto.solve_ms);
                detected += usize::from(!auto.periods_um.is_empty());
                dominant += usize::from(periods.first().is_some_and(|&p| {
                    auto.periods_um
                        .iter()
                        .any(|q| (q.period_um / p - 1.0).abs() <= 0.01)
                }));
                *picks.entry(auto.method.clone()).or_insert(0) += 1;
            }
            let k = seeds as f64;
            let [a, t, b, p, c] = acc.map(|v| v / k);
            rows.push(FamilyRow {
                family: fam.clone(),
                m,
                seeds,
                auto_um: a,
                physics_told_um: t,
                bp_um: b,
                pchip_um: p,
                auto_over_told: a / t,
                auto_over_best_baseline: a / b.min(p),
                mean_cv_error_um: c,
                cv_ratio_mean: ratios.iter().sum::<f64>() / k,
                cv_ratio_min: ratios.iter().cloned().fold(f64::INFINITY, f64::min),
                cv_ratio_max: ratios.iter().cloned().fold(0.0, f64::max),
                detected: detected as f64 / k,
                dominant_found: dominant as f64 / k,
                picks,
                median_auto_ms: super::median(&mut times),
            });
        }
    }
    Ok(rows)
}
