//! Paper-like reference error curves (the shape of the paper's Fig. 6 X-forward driving error:
//! slow trend, leadscrew cyclic error with harmonics, roughness and noise), built from the stage
//! model's effects so that the generator, the simulated devices and the gap diagnosis share one model.
use std::f64::consts::PI;

use csmetro_effects::{AxisId, Component, Effect, EffectKind, SampleContext, StageModel};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

/// Recipe of a paper-like X-forward driving error; every amplitude in µm. The defaults give curves
/// of the paper's Fig. 6 scale (a few µm peak-to-peak, 400 µm leadscrew period).
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ReferenceCurveParams {
    /// Axis travel, µm.
    pub travel_um: [f64; 2],
    /// Leadscrew pitch, µm.
    pub leadscrew_period_um: f64,
    /// Harmonic amplitudes of the leadscrew error (h = 1..), µm.
    pub leadscrew_amp_um: Vec<f64>,
    /// Linear envelope variation over the stroke (±, fraction).
    pub envelope_linear: f64,
    /// Slow envelope wave amplitude (fraction).
    pub envelope_wave: f64,
    /// Range `[lo, hi]` the envelope wave's period is drawn from, µm.
    pub envelope_wave_period_um: [f64; 2],
    /// Maximum phase drift over the stroke, rad.
    pub phase_drift_rad: f64,
    /// Secondary periodicity: amplitude, µm.
    pub secondary_amp_um: f64,
    /// Secondary periodicity: period, µm.
    pub secondary_period_um: f64,
    /// Slow trend: scale error, ppm.
    pub scale_ppm: f64,
    /// Slow trend: bow (parabola peak-to-chord height), µm.
    pub bow_um: f64,
    /// Slow trend: amplitude of one stroke-long sine, µm.
    pub stroke_sine_um: f64,
    /// Number of localized defects.
    pub defects: usize,
    /// Range `[lo, hi]` of the defects' heights (random sign), µm.
    pub defect_height_um: [f64; 2],
    /// Range `[lo, hi]` of the defects' widths (Gaussian sigma), µm.
    pub defect_sigma_um: [f64; 2],
    /// Correlated roughness (AR(1)): RMS, µm.
    pub roughness_sigma_um: f64,
    /// Correlated roughness: correlation length, µm.
    pub roughness_corr_um: f64,
    /// White measurement noise: standard deviation, µm.
    pub noise_sigma_um: f64,
}

impl Default for ReferenceCurveParams {
    fn default() -> Self {
        Self {
            travel_um: [0.0, 9500.0],
            leadscrew_period_um: 400.0,
            leadscrew_amp_um: vec![1.7, 0.5, 0.18, 0.05],
            envelope_linear: 0.125,
            envelope_wave: 0.15,
            envelope_wave_period_um: [3000.0, 6000.0],
            phase_drift_rad: 0.4,
            secondary_amp_um: 0.25,
            secondary_period_um: 1450.0,
            scale_ppm: 80.0,
            bow_um: 1.2,
            stroke_sine_um: 0.5,
            defects: 4,
            defect_height_um: [0.3, 1.0],
            defect_sigma_um: [10.0, 30.0],
            roughness_sigma_um: 0.085,
            roughness_corr_um: 12.0,
            noise_sigma_um: 0.01,
        }
    }
}

/// Builds a seeded stage model whose X axis carries a paper-like error curve.
pub fn paper_like_model(seed: u64, p: &ReferenceCurveParams) -> StageModel {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let [lo, hi] = p.travel_um;
    let span = hi - lo;
    let mut m = StageModel::new(p.travel_um, [0.0, 4200.0]);
    let x = AxisId::X;
    let sign = |rng: &mut ChaCha8Rng| if rng.random::<bool>() { 1.0 } else { -1.0 };

    let phases: Vec<f64> = p
        .leadscrew_amp_um
        .iter()
        .map(|_| rng.random_range(0.0..2.0 * PI))
        .collect();
    let [wlo, whi] = p.envelope_wave_period_um;
    m.push(Effect::new(
        x,
        EffectKind::LeadscrewModulated {
            period_um: p.leadscrew_period_um,
            amp_um: p.leadscrew_amp_um.clone(),
            phase_rad: phases,
            env_linear: p.envelope_linear * sign(&mut rng),
            env_wave_amp: p.envelope_wave,
            env_wave_period_um: if whi > wlo {
                rng.random_range(wlo..whi)
            } else {
                wlo
            },
            env_wave_phase_rad: rng.random_range(0.0..2.0 * PI),
            phase_drift_rad: rng.random_range(-p.phase_drift_rad..=p.phase_drift_rad),
        },
    ));
    let ph: f64 = rng.random_range(0.0..2.0 * PI);
    m.push(Effect::new(
        x,
        EffectKind::Harmonic {
            component: Component::Axis,
            period_um: p.secondary_period_um,
            cos_um: vec![p.secondary_amp_um * ph.cos()],
            sin_um: vec![p.secondary_amp_um * ph.sin()],
        },
    ));
    m.push(Effect::new(
        x,
        EffectKind::Scale {
            ppm: p.scale_ppm,
            ref_um: lo,
        },
    ));
    // Bow: peak-to-chord height `bow_um` is (3/2)·c2 for P2 over [-1, 1] (P2 runs -1/2..1).
    let ph: f64 = rng.random_range(0.0..2.0 * PI);
    m.push(Effect::new(
        x,
        EffectKind::Legendre {
            component: Component::Axis,
            coef_um: vec![0.0, -p.bow_um / 1.5 * sign(&mut rng)],
        },
    ));
    m.push(Effect::new(
        x,
        EffectKind::Harmonic {
            component: Component::Axis,
            period_um: span,
            cos_um: vec![p.stroke_sine_um * ph.cos()],
            sin_um: vec![p.stroke_sine_um * ph.sin()],
        },
    ));
    for _ in 0..p.defects {
        let [h0, h1] = p.defect_height_um;
        let [s0, s1] = p.defect_sigma_um;
        m.push(Effect::new(
            x,
            EffectKind::Defect {
                component: Component::Axis,
                center_um: rng.random_range(lo + 0.05 * span..hi - 0.05 * span),
                height_um: rng.random_range(h0..=h1) * sign(&mut rng),
                sigma_um: rng.random_range(s0..=s1),
            },
        ));
    }
    if p.roughness_sigma_um > 0.0 {
        m.push(Effect::new(
            x,
            EffectKind::Roughness {
                component: Component::Axis,
                sigma_um: p.roughness_sigma_um,
                corr_um: p.roughness_corr_um,
                seed: rng.random(),
            },
        ));
    }
    if p.noise_sigma_um > 0.0 {
        m.push(Effect::new(
            x,
            EffectKind::Noise {
                sigma_um: p.noise_sigma_um,
            },
        ));
    }
    m
}

/// The noise-free error (measured - target) of `axis` moving forward, at each position (µm),
/// with the other axis held at `other_um`.
pub fn error_curve(
    model: &StageModel,
    axis: AxisId,
    positions_um: &[f64],
    other_um: f64,
) -> Vec<f64> {
    positions_um
        .iter()
        .map(|&p| {
            let (tx, ty) = match axis {
                AxisId::X => (p, other_um),
                AxisId::Y => (other_um, p),
            };
            let c = SampleContext {
                moving: axis,
                direction: 1.0,
                target_x_um: tx,
                target_y_um: ty,
                time_s: 0.0,
            };
            model.deviation(&c).get(axis)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn paper_like_curve_has_paper_like_size_and_is_seeded() {
        let p = ReferenceCurveParams::default();
        let grid: Vec<f64> = (0..1901).map(|i| i as f64 * 5.0).collect();
        let a = error_curve(&paper_like_model(1, &p), AxisId::X, &grid, 0.0);
        let b = error_curve(&paper_like_model(1, &p), AxisId::X, &grid, 0.0);
        let c = error_curve(&paper_like_model(2, &p), AxisId::X, &grid, 0.0);
        assert_eq!(a, b);
        assert_ne!(a, c);
        let (mn, mx) = a
            .iter()
            .fold((f64::MAX, f64::MIN), |(l, h), &v| (l.min(v), h.max(v)));
        // Leadscrew ±1.7..2.4 µm on top of a ~1 µm trend: a few µm peak to peak, as in the paper's Fig. 4.
        assert!(mx - mn > 3.0 && mx - mn < 12.0, "peak-to-peak {}", mx - mn);
    }
}
