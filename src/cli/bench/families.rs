//! `bench families`: `auto` on error curves the stage simulator did not make.
//!
//! The curves come from the generator the tests share (crates/testcurves: not
//! `csmetro_sim`'s model, not the recon code): trend, cyclic terms of periods drawn anywhere in
//! 80–2,000 µm with harmonics and slowly varying envelopes, correlated roughness and white noise,
//! steps and defects, and two families shaped like real leadscrew and noisy axes (4,303 points at
//! 2.5 µm, ±20 µm). Per family and m it reports `auto` (no pitch) against `physics` told the
//! true period, `bp` and `pchip`, how often periods were detected, and how `auto`'s
//! `cv_error_um` compares with its true error.
use serde::Serialize;

use crate::grid::Grid;
use crate::recon::{self, Method, ReconSettings};
use crate::samples::GridSamples;

use csmetro_testcurves as curves;

pub(super) use curves::FAMILIES;

#[derive(Debug, Clone, Serialize)]
pub(super) struct FamilyRow {
    pub(super) family: String,
    /// Grid points of the family's curves (m is scaled from the 1,901-point figure asked).
    pub(super) n: usize,
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
    /// `auto`'s pointwise band: share of the grid with |g − f| ≤ 2u (mean over seeds, and the
    /// lowest seed), and sharpness mean(2u) / mean |g − f| (mean over seeds).
    pub(super) band_coverage: f64,
    pub(super) band_coverage_min: f64,
    pub(super) band_sharpness: f64,
}

fn mean_abs(g: &[f64], f: &[f64]) -> f64 {
    g.iter().zip(f).map(|(a, b)| (a - b).abs()).sum::<f64>() / f.len() as f64
}

pub(super) fn run(seeds: u64, ms: &[usize], families: &[String]) -> anyhow::Result<Vec<FamilyRow>> {
    let mut rows = Vec::new();
    for fam in families {
        if !FAMILIES.contains(&fam.as_str()) {
            anyhow::bail!("unknown family {fam:?} (one of {FAMILIES:?})");
        }
        for &m_ref in ms {
            let mut acc = [0.0f64; 5];
            let (mut ratios, mut times) = (Vec::new(), Vec::new());
            let (mut cover, mut sharp) = (Vec::new(), Vec::new());
            let (mut detected, mut dominant) = (0usize, 0usize);
            let mut picks = std::collections::BTreeMap::new();
            let mut n_fam = 0;
            for seed in 0..seeds {
                let c =
                    curves::family(fam, seed).ok_or_else(|| anyhow::anyhow!("unknown family"))?;
                let grid = Grid::new(0.0, c.step_um, c.step_um * (c.n - 1) as f64)
                    .map_err(anyhow::Error::msg)?;
                let m = curves::scaled_m(m_ref, c.n);
                n_fam = c.n;
                let idx = curves::pick(grid.n, m, 7919 * seed + m as u64);
                let samples = GridSamples {
                    values: curves::sample(&c, &idx, seed ^ m as u64),
                    idx,
                };
                let (truth, periods, sigma) = (&c.truth, &c.periods, c.noise_um);
                let run = |method: Method, pitch: Option<f64>| {
                    let s = ReconSettings {
                        method,
                        pitch_um: pitch,
                        noise_um: sigma,
                        ..Default::default()
                    };
                    recon::reconstruct(&grid, &samples, &s)
                };
                let auto = run(Method::Auto, None).map_err(anyhow::Error::msg)?;
                let e_auto = mean_abs(&auto.values, truth);
                if auto.u_um.len() == truth.len() {
                    let inside = auto
                        .values
                        .iter()
                        .zip(truth)
                        .zip(&auto.u_um)
                        .filter(|((g, f), u)| (*g - *f).abs() <= 2.0 * *u)
                        .count();
                    cover.push(inside as f64 / truth.len() as f64);
                    let mean_u = auto.u_um.iter().sum::<f64>() / truth.len() as f64;
                    sharp.push(2.0 * mean_u / e_auto);
                }
                // With no period to tell, physics is told nothing (its own search).
                let told =
                    run(Method::Physics, periods.first().copied()).map_err(anyhow::Error::msg)?;
                let bp = run(Method::Bp, None).map_err(anyhow::Error::msg)?;
                let pchip = run(Method::Pchip, None).map_err(anyhow::Error::msg)?;
                acc[0] += e_auto;
                acc[1] += mean_abs(&told.values, truth);
                acc[2] += mean_abs(&bp.values, truth);
                acc[3] += mean_abs(&pchip.values, truth);
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
                n: n_fam,
                m: curves::scaled_m(m_ref, n_fam),
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
                band_coverage: cover.iter().sum::<f64>() / cover.len().max(1) as f64,
                band_coverage_min: cover.iter().copied().fold(f64::NAN, f64::min),
                band_sharpness: sharp.iter().sum::<f64>() / sharp.len().max(1) as f64,
            });
        }
    }
    Ok(rows)
}

/// The band on the measured curves of tests/data/real (when the bench runs from the repository:
/// a resolver's cyclic error on a leadscrew axis, 4,303 points at 2.5 µm, and a noisy
/// laser-triangulation scan, 415 points): `auto` with the default noise setting from `seeds`
/// random designs of each m (scaled to the curve's length), coverage of the measured curve itself
/// (its own noise included) by ±2u.
#[derive(Debug, Clone, Serialize)]
pub(super) struct RealBand {
    pub(super) curve: String,
    pub(super) n: usize,
    pub(super) m: usize,
    pub(super) seeds: u64,
    pub(super) auto_um: f64,
    pub(super) band_coverage: f64,
    pub(super) band_coverage_min: f64,
    pub(super) band_sharpness: f64,
}

pub(super) fn real(seeds: u64, ms: &[usize]) -> anyhow::Result<Vec<RealBand>> {
    let mut rows = Vec::new();
    for name in ["resolver_250um", "ild2300_yscan"] {
        let Ok(text) = std::fs::read_to_string(format!("tests/data/real/{name}.csv")) else {
            continue;
        };
        let pts: Vec<(f64, f64)> = text
            .lines()
            .skip(1)
            .filter_map(|l| {
                let (a, b) = l.split_once(',')?;
                Some((a.trim().parse().ok()?, b.trim().parse().ok()?))
            })
            .collect();
        let n = pts.len();
        if n < 10 {
            continue;
        }
        let step = ((pts[n - 1].0 - pts[0].0) / (n - 1) as f64 * 1000.0).round() / 1000.0;
        let grid = Grid::new(0.0, step, step * (n - 1) as f64).map_err(anyhow::Error::msg)?;
        let truth: Vec<f64> = pts.iter().map(|p| p.1).collect();
        for &m_ref in ms {
            let m = curves::scaled_m(m_ref, n);
            let (mut err, mut cover, mut sharp) = (Vec::new(), Vec::new(), Vec::new());
            for seed in 0..seeds {
                let idx = curves::pick(grid.n, m, 7919 * seed + m as u64);
                let samples = GridSamples {
                    values: idx.iter().map(|&i| truth[i]).collect(),
                    idx,
                };
                let r = recon::reconstruct(&grid, &samples, &ReconSettings::default())?;
                let e = mean_abs(&r.values, &truth);
                err.push(e);
                if r.u_um.len() == n {
                    let inside = r
                        .values
                        .iter()
                        .zip(&truth)
                        .zip(&r.u_um)
                        .filter(|((g, f), u)| (*g - *f).abs() <= 2.0 * *u)
                        .count();
                    cover.push(inside as f64 / n as f64);
                    sharp.push(2.0 * r.u_um.iter().sum::<f64>() / n as f64 / e);
                }
            }
            let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len().max(1) as f64;
            rows.push(RealBand {
                curve: name.into(),
                n,
                m,
                seeds,
                auto_um: mean(&err),
                band_coverage: mean(&cover),
                band_coverage_min: cover.iter().copied().fold(f64::NAN, f64::min),
                band_sharpness: mean(&sharp),
            });
        }
    }
    Ok(rows)
}
