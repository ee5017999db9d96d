//! Period detection and `auto` on curves the simulator did not make: the generator shared with
//! `bench families` (crates/testcurves: trend + cyclic terms with envelopes and harmonics +
//! correlated roughness + white noise + defects), independent of csmetro's own models.
use csmetro::grid::Grid;
use csmetro::recon::{periods, reconstruct, Method, ReconSettings};
use csmetro::samples::GridSamples;

use csmetro_testcurves as curves;
use curves::{pick, Rng, Spec};

/// A curve on n points of `step` µm: bow and tilt, cyclic terms (period, amplitude) each with
/// a second harmonic and a linear envelope, correlated roughness and white scatter `noise`.
fn curve(n: usize, step: f64, cyclic: &[(f64, f64)], noise: f64, seed: u64) -> Vec<f64> {
    let mut sp = Spec::new(n, step);
    sp.cyclic = cyclic.to_vec();
    sp.harmonics = [0.3, 0.0];
    sp.envelope = 0.2;
    (sp.rough_um, sp.rough_corr_um) = (0.02, 20.0);
    sp.white_um = noise;
    sp.render(seed)
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

/// Correlated roughness is not a period: with many samples its power piles up at low
/// frequencies far above the white-noise level, and a white-noise false-alarm test "found" a
/// period in 85 % of such curves at m = 900.
#[test]
fn correlated_roughness_has_no_period_even_with_many_samples() {
    let mut false_alarms = Vec::new();
    for seed in 0..20 {
        // The bench's noise family: trend, 0.3 µm roughness over 15 µm, 0.1 µm sensor noise.
        let c = curves::family("noise", seed).unwrap();
        let idx = pick(c.n, 900, seed);
        let x: Vec<f64> = idx.iter().map(|&i| i as f64 * c.step_um).collect();
        let found = periods::detect(&x, &curves::sample(&c, &idx, seed), 2.0 * c.step_um);
        if !found.is_empty() {
            false_alarms.push((seed, found));
        }
    }
    // The target: none in >= 95 % of them.
    assert!(false_alarms.len() <= 1, "{false_alarms:?}");
}

/// A reconstruction of curve `c` from the samples at `idx` (sensor noise drawn with `noise_seed`,
/// the settings' σ `noise_um`) by `method`, told `pitch`, with its mean |g − f| over the grid.
fn on_curve(
    c: &curves::Curve,
    idx: Vec<usize>,
    noise_seed: u64,
    noise_um: f64,
) -> impl Fn(Method, Option<f64>) -> (csmetro::recon::Reconstruction, f64) + '_ {
    let grid = Grid::new(0.0, c.step_um, c.step_um * (c.n - 1) as f64).unwrap();
    let samples = GridSamples {
        values: curves::sample(c, &idx, noise_seed),
        idx,
    };
    move |method, pitch| {
        let s = ReconSettings {
            method,
            pitch_um: pitch,
            noise_um,
            ..Default::default()
        };
        let r = reconstruct(&grid, &samples, &s).unwrap();
        let err = r
            .values
            .iter()
            .zip(&c.truth)
            .map(|(a, b)| (a - b).abs())
            .sum::<f64>()
            / c.n as f64;
        (r, err)
    }
}

fn auto_and_baselines(c: &curves::Curve, m: usize, seed: u64) -> (f64, f64, f64, f64, Vec<f64>) {
    let run = on_curve(
        c,
        pick(c.n, m, seed),
        seed,
        ReconSettings::default().noise_um,
    );
    let (auto, e_auto) = run(Method::Auto, None);
    let found = auto.periods_um.iter().map(|p| p.period_um).collect();
    let told = c
        .periods
        .first()
        .map_or(f64::NAN, |&p| run(Method::Physics, Some(p)).1);
    (
        e_auto,
        told,
        run(Method::Bp, None).1,
        run(Method::Pchip, None).1,
        found,
    )
}

/// A leadscrew axis like a real one: 4,303 points at 2.5 µm, a cyclic error of several µm
/// within ±20 µm, sampled at 5 % (m = 226). `auto`, told no pitch, finds the period and comes
/// near `physics` told it, far ahead of the lookup table and basis pursuit.
#[test]
fn auto_finds_a_leadscrew_period_at_5_percent_sampling() {
    for seed in [0, 1] {
        let c = curves::family("leadscrew", seed).unwrap();
        let (auto, told, bp, pchip, found) = auto_and_baselines(&c, 226, seed);
        let p = c.periods[0];
        assert!(
            found.iter().any(|f| (f / p - 1.0).abs() < 0.01),
            "seed {seed}: period {p} µm, found {found:?}"
        );
        assert!(
            auto <= 1.1 * told && auto <= 0.7 * bp.min(pchip),
            "seed {seed}: auto {auto}, physics told {told}, bp {bp}, pchip {pchip}"
        );
    }
}

/// A noisy axis with no dominant period (scatter of up to 26 µm in the curve itself): no period
/// is reported and `auto` does about as well as the better of bp and pchip.
#[test]
fn auto_on_a_noisy_axis_without_period_matches_the_best_baseline() {
    // One curve: each costs four reconstructions of 4,303 points in a debug build.
    let c = curves::family("rough", 0).unwrap();
    let (auto, _, bp, pchip, found) = auto_and_baselines(&c, 226, 0);
    assert!(found.is_empty(), "{found:?}");
    assert!(
        auto <= 1.05 * bp.min(pchip),
        "auto {auto}, bp {bp}, pchip {pchip}"
    );
}

/// Few samples per cycle (the demo's Y at 5 %: 42 samples over 10.5 cycles of 400 µm): the
/// default structure of a period set has more columns than a training set has rows, and the
/// period used to be dropped for it (no period kept, mean error 2.4× that with it).
#[test]
fn a_period_is_kept_with_four_samples_per_cycle() {
    let grid = Grid::new(0.0, 5.0, 4200.0).unwrap();
    for seed in 0..2 {
        let truth = curve(grid.n, 5.0, &[(400.0, 1.0)], 0.01, 120 + seed);
        let idx = pick(grid.n, 42, 130 + seed);
        let samples = GridSamples {
            values: idx.iter().map(|&i| truth[i]).collect(),
            idx: idx.clone(),
        };
        let r = reconstruct(&grid, &samples, &ReconSettings::default()).unwrap();
        assert!(
            r.periods_um
                .iter()
                .any(|p| (p.period_um / 400.0 - 1.0).abs() < 0.01),
            "seed {seed}: {:?}",
            r.periods_um
        );
        let auto = mean_abs(&grid, &truth, &idx, Method::Auto, None);
        let pchip = mean_abs(&grid, &truth, &idx, Method::Pchip, None);
        assert!(
            auto <= 0.5 * pchip,
            "seed {seed}: auto {auto}, pchip {pchip}"
        );
    }
}

/// A long drifting period seen by few samples can miss the false-alarm test (bench `chirp`
/// family, seed 13, m = 100: FAP 0.006 for a 1,661 µm period over 5.7 cycles). The near miss is
/// still a candidate of the cross-validation, which keeps it: `auto` had 3.5× the error of
/// `physics` told the period (it fell back to pchip). It is not reported as a found period.
#[test]
fn a_near_miss_of_the_false_alarm_test_still_enters_the_model() {
    let c = curves::family("chirp", 13).unwrap();
    let m = 100;
    let run = on_curve(
        &c,
        pick(c.n, m, 7919 * 13 + m as u64),
        13 ^ m as u64,
        c.noise_um,
    );
    let (auto, e_auto) = run(Method::Auto, None);
    let e_told = run(Method::Physics, Some(c.periods[0])).1;
    assert!(
        e_auto <= 1.1 * e_told,
        "auto ({}) {e_auto} vs physics told {} µm {e_told}",
        auto.method,
        c.periods[0],
    );
    assert!(auto.periods_um.is_empty(), "{:?}", auto.periods_um);
}
