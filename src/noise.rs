//! The noise σ a curve is reconstructed with: the σ told (`noise_um`, `--noise-um`), raised to
//! the samples' own scatter where they show one and the told σ is clearly below it.
//!
//! Why: the band at a sample point rests on σ, since a curve through its samples is off by the
//! sample's own noise there. Told half the samples' σ, it covers 0.78 of the sample points
//! (`tests/gp/noise_told.py`). Two scatters are measured:
//! - a campaign point's frames ([`frames_scatter`]): taken at a standing stage, they show the
//!   camera's scatter, not the stage's landing scatter, so they bound a sample's noise from below
//!   only, and a told σ above them is kept;
//! - a position's repeated cycles in a samples file (`crate::samples`): each re-approaches the
//!   target, so they include the landing scatter (and any drift between cycles).
//!
//! The other way, a told σ above what the held-out residuals allow, is lowered by the
//! reconstruction itself (`recon::noise_told_too_high`): every residual carries its sample's noise.
use serde::Serialize;

use crate::recon::band::chi2_quantile;
use crate::types::{AxisId, SampleRecord};

/// One-sided 95 % normal quantile: the told σ is raised only when it lies below the measured
/// scatter's 95 % lower confidence bound.
const Z95: f64 = 1.645;

/// A pooled scatter of repeated readings: Σ (k − 1)·s² over the samples that were repeated, its
/// degrees of freedom Σ (k − 1), and how much the samples average (each its k readings).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Scatter {
    pub sum_sq: f64,
    pub dof: u64,
    inv_k_sum: f64,
    samples: u64,
}

impl Scatter {
    /// One sample, the mean of `k` readings whose squares about their mean sum to `sum_sq`
    /// (`None`: not measured, as for one reading).
    pub fn add(&mut self, k: u32, sum_sq: Option<f64>) {
        let k = k.max(1);
        self.add_rows(&[(k, sum_sq)]);
    }

    /// One sample, the mean of several rows, row i the mean of `k_i` readings whose squares
    /// about that row's mean sum to `sum_sq_i` (as [`Scatter::add`]). The sample's variance is
    /// σ²·Σ(1/k_i)/r² for r rows.
    pub fn add_rows(&mut self, rows: &[(u32, Option<f64>)]) {
        if rows.is_empty() {
            return;
        }
        let r = rows.len() as f64;
        self.samples += 1;
        self.inv_k_sum += rows
            .iter()
            .map(|(k, _)| 1.0 / f64::from((*k).max(1)))
            .sum::<f64>()
            / (r * r);
        for &(k, sum_sq) in rows {
            if let Some(ss) = sum_sq.filter(|v| v.is_finite() && k >= 2) {
                self.sum_sq += ss;
                self.dof += u64::from(k - 1);
            }
        }
    }

    /// The mean of 1/k over the samples (1 without any).
    pub fn mean_inv_k(&self) -> f64 {
        if self.samples > 0 {
            self.inv_k_sum / self.samples as f64
        } else {
            1.0
        }
    }

    /// A sample's σ as the repeats show it, µm; `None` without a repeat.
    pub fn sample_sigma_um(&self) -> Option<f64> {
        (self.dof > 0 && self.sum_sq.is_finite())
            .then(|| (self.sum_sq / self.dof as f64 * self.mean_inv_k()).sqrt())
    }
}

/// The σ of one curve's samples: told, measured from their repeats, and used.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct NoiseFloor {
    /// σ told, µm.
    pub told_um: f64,
    /// A sample's noise as its repeats show it (σ of one reading over √readings), µm; `None`
    /// when no sample had two readings or more.
    pub measured_um: Option<f64>,
    /// Degrees of freedom of `measured_um`: Σ (readings − 1).
    pub dof: u64,
    /// σ the curve is reconstructed with, µm: `told_um`, or `measured_um` when the told σ is
    /// below its 95 % lower bound.
    pub used_um: f64,
}

impl NoiseFloor {
    /// The told σ against a measured scatter.
    pub fn from_scatter(told_um: f64, s: &Scatter) -> Self {
        let measured_um = s.sample_sigma_um();
        let mut used_um = told_um;
        if let Some(m) = measured_um {
            let lower = m * m * s.dof as f64 / chi2_quantile(s.dof as f64, Z95);
            if told_um * told_um < lower {
                used_um = m;
            }
        }
        NoiseFloor {
            told_um,
            measured_um,
            dof: s.dof,
            used_um,
        }
    }

    /// True when the σ used is not the σ told.
    pub fn changed(&self) -> bool {
        self.used_um != self.told_um
    }
}

/// The frames' scatter of the coordinate `measured` over `samples` (campaign points).
pub fn frames_scatter<'a>(
    samples: impl IntoIterator<Item = &'a SampleRecord>,
    measured: AxisId,
) -> Scatter {
    let axis = measured as usize;
    let mut scatter = Scatter::default();
    for s in samples {
        let k = s.frames.max(1);
        let sd = s.frame_sd_um.map(|d| d[axis]);
        scatter.add(k, sd.map(|sd| f64::from(k - 1) * sd * sd));
    }
    scatter
}

/// The σ to reconstruct the coordinate `measured` of campaign `samples` with, given the σ told.
pub fn noise_floor<'a>(
    told_um: f64,
    samples: impl IntoIterator<Item = &'a SampleRecord>,
    measured: AxisId,
) -> NoiseFloor {
    NoiseFloor::from_scatter(told_um, &frames_scatter(samples, measured))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::types::{Direction, Phase, RunKey, Target};

    /// A point of `k` frames whose single frames scatter by `sd` µm along x.
    fn point(k: u32, sd: Option<f64>) -> SampleRecord {
        let run = RunKey {
            phase: Phase::Cs,
            axis: AxisId::X,
            direction: Direction::Forward,
            cycle: 0,
        };
        SampleRecord {
            frames: k,
            frame_sd_um: sd.map(|s| [s, 10.0 * s]),
            ..SampleRecord::at(Target {
                seq: 0,
                run,
                grid_index: 0,
                target_x_um: 0.0,
                target_y_um: 0.0,
            })
        }
    }

    #[test]
    fn a_sigma_told_below_the_frames_scatter_is_raised_to_it() {
        // 200 points of 4 frames, each frame σ 0.01 µm: a sample's σ is 0.005 µm.
        let pts: Vec<_> = (0..200).map(|_| point(4, Some(0.01))).collect();
        let f = noise_floor(0.002, &pts, AxisId::X);
        assert!((f.measured_um.unwrap() - 0.005).abs() < 1e-12, "{f:?}");
        assert_eq!(f.dof, 600);
        assert!(f.changed() && f.used_um == f.measured_um.unwrap(), "{f:?}");
        // The y coordinate reads its own scatter (ten times x's here).
        let fy = noise_floor(0.002, &pts, AxisId::Y);
        assert!((fy.used_um - 0.05).abs() < 1e-12, "{fy:?}");
    }

    #[test]
    fn a_told_sigma_within_or_above_the_frames_reach_is_kept() {
        let pts: Vec<_> = (0..200).map(|_| point(4, Some(0.01))).collect();
        // Above the frames: the stage's landing scatter the frames do not see.
        let above = noise_floor(0.02, &pts, AxisId::X);
        assert!(!above.changed() && above.used_um == 0.02, "{above:?}");
        // Just below the estimate but within its 95 % chance (600 dof: the bound is ~0.92 of it).
        let near = noise_floor(0.0048, &pts, AxisId::X);
        assert!(!near.changed(), "{near:?}");
        // Few frames: 3 points of 2 frames cannot tell 0.004 from 0.005.
        let few: Vec<_> = (0..3)
            .map(|_| point(2, Some(0.005 * 2f64.sqrt())))
            .collect();
        assert!(!noise_floor(0.004, &few, AxisId::X).changed());
    }

    #[test]
    fn single_frames_measure_nothing() {
        let pts: Vec<_> = (0..50).map(|_| point(1, None)).collect();
        let f = noise_floor(0.01, &pts, AxisId::X);
        assert_eq!((f.measured_um, f.dof, f.used_um), (None, 0, 0.01));
        // Points of one frame count in how much a sample averages, not in the scatter.
        let mut mixed: Vec<_> = (0..100).map(|_| point(4, Some(0.01))).collect();
        mixed.extend((0..100).map(|_| point(1, None)));
        let m = noise_floor(0.0, &mixed, AxisId::X).measured_um.unwrap();
        let want = (1e-4 * (0.25 + 1.0) / 2.0f64).sqrt();
        assert!((m - want).abs() < 1e-12, "{m} against {want}");
    }

    #[test]
    fn the_chi2_quantile_is_near_the_tables() {
        // χ²(0.95): 10 dof 18.307, 100 dof 124.342.
        assert!((chi2_quantile(10.0, Z95) - 18.307).abs() < 0.05);
        assert!((chi2_quantile(100.0, Z95) - 124.342).abs() < 0.1);
    }
}
