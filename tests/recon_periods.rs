//! Period detection and `auto` on curves the simulator did not make: a small generator of its
//! own (trend + cyclic terms with envelopes and harmonics + correlated roughness + white noise).
use csmetro::grid::Grid;
use csmetro::recon::{periods, reconstruct, Method, ReconSettings};
use csmetro::samples::GridSamples;
use std::f64::consts::TAU;

/// SplitMix64: independent of the project's generators.
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
}

/// A curve on n points of `step` µm: bow and tilt, cyclic terms (period, amplitude) each with
/// a second harmonic and a linear envelope, roughness (moving average) and white noise.
fn curve(n: usize, step: f64, cyclic: &[(f64, f64)], noise: f64, seed: u64) -> Vec<f64> {
    let mut r = Rng(seed);
    let span = step * (n - 1) as f64;
    let (bow, tilt) = (2.0 * r.gauss(), r.gauss());
    let phases: Vec<(f64, f64)> = cyclic
        .iter()
        .map(|_| (TAU * r.next(), TAU * r.next()))
        .collect();
    let white: Vec<f64> = (0..n + 8).map(|_| r.gauss()).collect();
    (0..n)
        .map(|i| {
            let x = i as f64 * step;
            let s = 2.0 * x / span - 1.0;
            let mut v = bow * s * s + tilt * s;
            for (&(p, a), &(f1, f2)) in cyclic.iter().zip(&phases) {
                let w = TAU * x / p;
                v += a * (1.0 + 0.2 * s) * ((w + f1).sin() + 0.3 * (2.0 * w + f2).sin());
            }
            v + 0.02 * white[i..i + 8].iter().sum::<f64>() / 8f64.sqrt() + noise * r.gauss()
        })
        .collect()
}

/// m distinct random grid indices, ascending.
fn pick(n: usize, m: usize, seed: u64) -> Vec<usize> {
    let mut r = Rng(seed ^ 0xABCD);
    let mut all: Vec<usize> = (0..n).collect();
    for i in 0..m {
        let j = i + (r.next() * (n - i) as f64) as usize;
        all.swap(i, j.min(n - 1));
    }
    let mut idx = all[..m].to_vec();
    idx.sort_unstable();
    idx
}

fn detect_on(n: usize, step: f64, truth: &[f64], m: usize, seed: u64) -> Vec<periods::Period> {
    let idx = pick(n, m, seed);
    let x: Vec<f64> = idx.iter().map(|&i| i as f64 * step).collect();
    let y: Vec<f64> = idx.iter().map(|&i| truth[i]).collect();
    periods::detect(&x, &y, 2.0 * step)
}

fn near(found: &[periods::Period], p: f64, rel: f64) -> bool {
    found.iter().any(|f| (f.period_um / p - 1.0).abs() <= rel)
}

#[test]
fn periods_anywhere_from_80_to_2000_um_are_found_within_1_percent() {
    for (k, &p) in [83.0, 250.0, 517.0, 1210.0, 1990.0].iter().enumerate() {
        for m in [100, 300] {
            let truth = curve(1901, 5.0, &[(p, 1.0)], 0.01, 10 + k as u64);
            let found = detect_on(1901, 5.0, &truth, m, k as u64);
            assert!(near(&found, p, 0.01), "period {p} at m = {m}: {found:?}");
            assert!(found.len() <= 2, "period {p} at m = {m}: {found:?}");
        }
    }
}

#[test]
fn two_incommensurate_periods_are_both_found() {
    let truth = curve(1901, 5.0, &[(250.0, 1.0), (613.0, 0.5)], 0.01, 3);
    let found = detect_on(1901, 5.0, &truth, 300, 4);
    assert!(
        near(&found, 250.0, 0.01) && near(&found, 613.0, 0.01),
        "{found:?}"
    );
}

#[test]
fn a_period_near_the_grid_resolution_limit_is_found() {
    // 11.3 µm on a 5 µm grid: just above the grid's Nyquist period of 10 µm.
    let truth = curve(1901, 5.0, &[(11.3, 1.0)], 0.01, 5);
    let found = detect_on(1901, 5.0, &truth, 300, 6);
    assert!(near(&found, 11.3, 0.01), "{found:?}");
}

#[test]
fn noise_plus_trend_has_no_period_in_at_least_95_percent_of_seeds() {
    let mut false_alarms = Vec::new();
    for seed in 0..40 {
        let truth = curve(1901, 5.0, &[], 0.05, 100 + seed);
        let found = detect_on(1901, 5.0, &truth, 300, seed);
        if !found.is_empty() {
            false_alarms.push(found);
        }
    }
    assert!(false_alarms.len() <= 2, "{false_alarms:?}");
}

fn mean_abs(grid: &Grid, truth: &[f64], idx: &[usize], method: Method, pitch: Option<f64>) -> f64 {
    let samples = GridSamples {
        idx: idx.to_vec(),
        values: idx.iter().map(|&i| truth[i]).collect(),
    };
    let s = ReconSettings {
        method,
        pitch_um: pitch,
        ..Default::default()
    };
    let r = reconstruct(grid, &samples, &s).unwrap();
    r.values
        .iter()
        .zip(truth)
        .map(|(a, b)| (a - b).abs())
        .sum::<f64>()
        / truth.len() as f64
}

#[test]
fn auto_without_a_pitch_nearly_matches_physics_told_the_true_period() {
    let grid = Grid::new(0.0, 5.0, 9500.0).unwrap();
    for m in [100, 300] {
        let (mut auto, mut told, mut bp, mut pchip) = (0.0, 0.0, 0.0, 0.0);
        // One seed per m here (debug build); more seeds in the release run reported.
        for seed in 0..1 {
            let truth = curve(grid.n, 5.0, &[(250.0, 1.0)], 0.01, 40 + seed);
            let idx = pick(grid.n, m, 50 + seed);
            auto += mean_abs(&grid, &truth, &idx, Method::Auto, None);
            told += mean_abs(&grid, &truth, &idx, Method::Physics, Some(250.0));
            bp += mean_abs(&grid, &truth, &idx, Method::Bp, None);
            pchip += mean_abs(&grid, &truth, &idx, Method::Pchip, None);
        }
        assert!(
            auto <= 1.2 * told,
            "m = {m}: auto {auto} vs physics told 250 µm {told}"
        );
        assert!(
            auto <= bp.min(pchip),
            "m = {m}: auto {auto}, bp {bp}, pchip {pchip}"
        );
    }
}

/// `cv_error_um` is an estimate one can stop on: on curves of this file's generator, sampled with
/// 0.01 µm sensor noise, its mean over seeds is within 15 % of the true mean |g − f| over the grid
/// (the raw cross-validated error overstated it ~50 % at m = 600 of 1,901).
#[test]
fn cv_error_estimates_the_true_error_within_15_percent() {
    let grid = Grid::new(0.0, 5.0, 9500.0).unwrap();
    let (mut est, mut err) = (0.0, 0.0);
    for seed in 0..3 {
        let truth = curve(grid.n, 5.0, &[(317.0, 1.0), (1130.0, 0.4)], 0.0, 70 + seed);
        let idx = pick(grid.n, 600, 80 + seed);
        let mut noise = Rng(90 + seed);
        let samples = GridSamples {
            values: idx
                .iter()
                .map(|&i| truth[i] + 0.01 * noise.gauss())
                .collect(),
            idx,
        };
        let s = ReconSettings {
            method: Method::Auto,
            noise_um: 0.01,
            ..Default::default()
        };
        let r = reconstruct(&grid, &samples, &s).unwrap();
        est += r.cv_error_um.unwrap();
        err += r
            .values
            .iter()
            .zip(&truth)
            .map(|(a, b)| (a - b).abs())
            .sum::<f64>()
            / grid.n as f64;
    }
    let ratio = est / err;
    assert!(
        (0.85..=1.15).contains(&ratio),
        "cv_error_um {est} against true {err} (sums over 3 seeds): ratio {ratio}"
    );
}
