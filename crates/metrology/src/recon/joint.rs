//! One direction's curve from its own samples and the opposite direction's.
//!
//! The position-dependent errors of a stage (the screw's cyclic error, trend, roughness of the
//! guide) are the same whichever way it moves; what differs is backlash and hysteresis, which
//! vary slowly along the travel. When the other direction measured other positions, its
//! samples, shifted by a smooth difference (a polynomial in the position, fitted to them), fill
//! this direction's gaps. The pooled curve is kept only when it cross-validates better than the
//! direction alone: a difference that is not smooth (a cyclic error that shifts with the
//! backlash) leaves the pooled samples inconsistent and their held-out error higher.
use super::physics::legendre;
use super::{reconstruct, ReconError, ReconSettings, Reconstruction};
use crate::grid::Grid;
use crate::samples::{nearest_steps, GridSamples};
use nalgebra::{DMatrix, DVector};

/// Degrees of the direction difference the cross-validation chooses among: a constant
/// backlash, one changing linearly along the travel, a cubic. Not the cubic alone: its ends
/// bend to follow the error of the direction's own curve where that curve has few samples
/// (a backward curve 0.5 µm off over the last 500 µm of the simulator's X on one seed).
pub const DIFF_DEGREES: [usize; 3] = [0, 1, 3];

/// `own`'s curve, with `other` (the opposite direction's samples) pooled in when that
/// cross-validates better. `pooled_with` of the result counts the other direction's samples
/// used, `difference_degree` is the degree of the difference the cross-validation chose.
pub fn reconstruct_joint(
    grid: &Grid,
    own: &GridSamples,
    other: &GridSamples,
    s: &ReconSettings,
) -> Result<Reconstruction, ReconError> {
    reconstruct_joint_among(grid, own, other, s, &DIFF_DEGREES)
}

/// [`reconstruct_joint`] with the difference's degree among `degrees` (a refit of a chosen
/// curve, e.g. in cross-validation folds, passes the one degree chosen).
pub fn reconstruct_joint_among(
    grid: &Grid,
    own: &GridSamples,
    other: &GridSamples,
    s: &ReconSettings,
    degrees: &[usize],
) -> Result<Reconstruction, ReconError> {
    let alone = reconstruct(grid, own, s)?;
    let new_positions = other
        .idx
        .iter()
        .filter(|i| own.idx.binary_search(i).is_err())
        .count();
    let near = backed_by(own, other);
    let mut best: Option<Reconstruction> = None;
    // Nothing to gain without new positions, and the difference needs a few to be fitted.
    'degree: for &deg in degrees.iter().filter(|&&d| new_positions >= 4 * (d + 1)) {
        let mut base = alone.values.clone();
        let mut pooled = None;
        // Two alternations: the first against the direction alone, where that curve is
        // backed by its own samples, the second against the pooled curve, everywhere.
        for fit_on in [&near, other] {
            // A singular fit (positions bunched together) leaves this degree out.
            let Some(diff) = fit_difference(grid, fit_on, &base, deg) else {
                continue 'degree;
            };
            let r = reconstruct(grid, &merge(grid, own, other, &diff), s)?;
            base = r.values.clone();
            pooled = Some(r);
        }
        let mut r = pooled.expect("two rounds ran");
        r.difference_degree = Some(deg);
        // Ties go to the lower degree (tried first).
        if lower_cv(&r, best.as_ref().unwrap_or(&alone)) {
            best = Some(r);
        }
    }
    match best {
        Some(mut r) if lower_cv(&r, &alone) => {
            r.pooled_with = Some(other.len());
            r.m = own.len();
            Ok(r)
        }
        _ => Ok(alone),
    }
}

/// The samples of `other` where a curve from `own` alone is backed by samples: inside `own`'s
/// span and no farther from one of its samples than its median spacing. Beyond the ends and in
/// wide gaps that curve extrapolates; differences fitted there follow its error (a backward
/// curve 0.5 µm off over the last 500 µm of the simulator's X, one seed). All of `other` when
/// too few are left to fit a cubic.
fn backed_by(own: &GridSamples, other: &GridSamples) -> GridSamples {
    let mut gaps: Vec<usize> = own.idx.windows(2).map(|w| w[1] - w[0]).collect();
    if gaps.is_empty() {
        return other.clone();
    }
    gaps.sort_unstable();
    let reach = gaps[gaps.len() / 2];
    let (lo, hi) = (own.idx[0], own.idx[own.idx.len() - 1]);
    let keep: Vec<usize> = (0..other.len())
        .filter(|&r| {
            let i = other.idx[r];
            (lo..=hi).contains(&i) && nearest_steps(&own.idx, i) <= reach
        })
        .collect();
    if keep.len() < 4 * (DIFF_DEGREES[DIFF_DEGREES.len() - 1] + 1) {
        return other.clone();
    }
    GridSamples {
        idx: keep.iter().map(|&r| other.idx[r]).collect(),
        values: keep.iter().map(|&r| other.values[r]).collect(),
    }
}

fn lower_cv(a: &Reconstruction, b: &Reconstruction) -> bool {
    match (a.cv_error_um, b.cv_error_um) {
        (Some(p), Some(q)) => p < q,
        _ => false,
    }
}

/// Coefficients of the difference other − curve at the other direction's positions, a
/// Legendre polynomial of degree `deg` in the position.
fn fit_difference(grid: &Grid, other: &GridSamples, curve: &[f64], deg: usize) -> Option<Vec<f64>> {
    let m = other.len();
    let a = DMatrix::from_fn(m, deg + 1, |r, k| legendre(k, unit(grid, other.idx[r])));
    let y = DVector::from_iterator(m, (0..m).map(|r| other.values[r] - curve[other.idx[r]]));
    let beta = (a.transpose() * &a).cholesky()?.solve(&(a.transpose() * y));
    Some(beta.iter().copied().collect())
}

/// Position of grid index i on [-1, 1].
fn unit(grid: &Grid, i: usize) -> f64 {
    if grid.n < 2 {
        0.0
    } else {
        2.0 * i as f64 / (grid.n - 1) as f64 - 1.0
    }
}

fn difference_at(grid: &Grid, diff: &[f64], i: usize) -> f64 {
    let s = unit(grid, i);
    diff.iter()
        .enumerate()
        .map(|(k, c)| c * legendre(k, s))
        .sum()
}

/// `own` with `other` minus the difference at the positions `own` lacks (ascending).
fn merge(grid: &Grid, own: &GridSamples, other: &GridSamples, diff: &[f64]) -> GridSamples {
    let mut all: Vec<(usize, f64)> = own
        .idx
        .iter()
        .copied()
        .zip(own.values.iter().copied())
        .collect();
    for (&i, &v) in other.idx.iter().zip(&other.values) {
        if own.idx.binary_search(&i).is_err() {
            all.push((i, v - difference_at(grid, diff, i)));
        }
    }
    all.sort_by_key(|p| p.0);
    GridSamples {
        idx: all.iter().map(|p| p.0).collect(),
        values: all.iter().map(|p| p.1).collect(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::recon::Method;

    /// A stage curve written here (not the simulator's): two cyclic terms, a bow and a rough part
    /// drawn per position, the same in both directions; backward = forward + a sloped backlash.
    fn curves(n: usize) -> (Vec<f64>, Vec<f64>) {
        let mut state = 0x1234_5678_9abc_def0u64;
        let mut rough = 0.0;
        let mut f = Vec::with_capacity(n);
        for i in 0..n {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            let u = (state >> 11) as f64 / (1u64 << 53) as f64 - 0.5;
            rough = 0.7 * rough + 0.03 * u;
            let x = i as f64 * 5.0;
            let s = x / 4750.0 - 1.0;
            f.push(
                1.3 * (1.0 + 0.3 * s)
                    * (std::f64::consts::TAU * x / 350.0 + 0.4 + 0.6 * s * s).sin()
                    + 0.3 * (2.0 * std::f64::consts::TAU * x / 350.0 + 1.1 * s).cos()
                    + 0.4 * (std::f64::consts::TAU * x / 1230.0).cos()
                    + 0.8 * s * s
                    + rough,
            );
        }
        let b = f
            .iter()
            .enumerate()
            .map(|(i, v)| v - 1.7 + 0.3 * (i as f64 / n as f64))
            .collect();
        (f, b)
    }

    fn mean_abs(g: &[f64], t: &[f64]) -> f64 {
        g.iter().zip(t).map(|(a, b)| (a - b).abs()).sum::<f64>() / t.len() as f64
    }

    fn design(m: usize, seed: u64, n: usize) -> Vec<usize> {
        crate::sampling::Design::new(crate::sampling::DesignKind::Random, m, seed)
            .indices(n)
            .unwrap()
    }

    /// Every other point of `idx` from `first` (dealt as the adaptive plan deals two
    /// directions), those below `end`, valued from curve `t`.
    fn every_other(idx: &[usize], first: usize, t: &[f64], end: usize) -> GridSamples {
        let idx: Vec<usize> = idx
            .iter()
            .copied()
            .skip(first)
            .step_by(2)
            .filter(|&i| i < end)
            .collect();
        let values = idx.iter().map(|&i| t[i]).collect();
        GridSamples { idx, values }
    }

    #[test]
    fn the_other_directions_samples_at_other_positions_sharpen_the_curve() {
        let grid = Grid::new(0.0, 5.0, 9500.0).unwrap();
        let (f, b) = curves(grid.n);
        let idx = design(200, 3, grid.n);
        // Interleaved: forward takes every other design point, backward the rest.
        let (fw, bw) = (
            every_other(&idx, 0, &f, grid.n),
            every_other(&idx, 1, &b, grid.n),
        );
        let s = ReconSettings {
            method: Method::Auto,
            ..Default::default()
        };
        let alone = reconstruct(&grid, &fw, &s).unwrap();
        let joint = reconstruct_joint(&grid, &fw, &bw, &s).unwrap();
        assert_eq!(joint.pooled_with, Some(bw.len()));
        let (ea, ej) = (mean_abs(&alone.values, &f), mean_abs(&joint.values, &f));
        assert!(ej < 0.9 * ea, "joint {ej} vs alone {ea}");
    }

    #[test]
    fn samples_at_the_same_positions_or_an_unrelated_curve_leave_the_direction_alone() {
        let grid = Grid::new(0.0, 5.0, 9500.0).unwrap();
        let (f, _) = curves(grid.n);
        let idx = design(120, 4, grid.n);
        let fw = GridSamples {
            idx: idx.clone(),
            values: idx.iter().map(|&i| f[i]).collect(),
        };
        let s = ReconSettings::default();
        let same = GridSamples {
            idx: idx.clone(),
            values: idx.iter().map(|&i| f[i] - 2.0).collect(),
        };
        assert_eq!(
            reconstruct_joint(&grid, &fw, &same, &s)
                .unwrap()
                .pooled_with,
            None
        );
        // The other direction sees a different cyclic error: pooling would corrupt the curve.
        let other_idx = design(120, 5, grid.n);
        let unrelated = GridSamples {
            values: other_idx
                .iter()
                .map(|&i| 1.5 * (i as f64 * 5.0 / 97.0).sin())
                .collect(),
            idx: other_idx,
        };
        let r = reconstruct_joint(&grid, &fw, &unrelated, &s).unwrap();
        assert_eq!(r.pooled_with, None);
    }

    #[test]
    fn a_gap_at_the_end_of_the_own_samples_is_filled_by_the_other_direction() {
        // Forward measured nothing in the last 8 % of the stroke, backward did: the forward
        // curve there comes from the backward samples, not from extrapolating its own (the
        // difference fitted where the forward curve alone is backed by samples).
        let grid = Grid::new(0.0, 5.0, 9500.0).unwrap();
        let (f, _) = curves(grid.n);
        let b: Vec<f64> = f.iter().map(|v| v - 2.0).collect();
        let cut = grid.n * 92 / 100;
        let s = ReconSettings::default();
        // Designs on which a cubic difference fitted everywhere did not pool at all.
        for seed in [1, 2] {
            let idx = design(300, seed, grid.n);
            let (fw, bw) = (
                every_other(&idx, 0, &f, cut),
                every_other(&idx, 1, &b, grid.n),
            );
            let alone = reconstruct(&grid, &fw, &s).unwrap();
            let joint = reconstruct_joint(&grid, &fw, &bw, &s).unwrap();
            assert_eq!(joint.pooled_with, Some(bw.len()), "seed {seed}");
            let end = |g: &[f64]| mean_abs(&g[cut..], &f[cut..]);
            let (ea, ej) = (end(&alone.values), end(&joint.values));
            assert!(ej < 0.3 * ea, "seed {seed}: end {ej} µm vs alone {ea} µm");
        }
    }
}
