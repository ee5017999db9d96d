//! The effect library: kinds, parameters and the deviation each adds to a sample.
//!
//! `EffectKind` is the `[[effect]]` table of a model file as serde reads and writes it: `kind`
//! names the variant, the other keys are its fields (defaults below are the file format's).
use std::f64::consts::PI;

use serde::{Deserialize, Serialize};

use super::{AxisId, Deviation, SampleContext, StageModel};

/// Which component a simulator-only effect moves: the effect's own axis or the other one.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Component {
    /// The effect's own axis (the moving one).
    #[default]
    Axis,
    /// The other axis of the pair.
    Other,
}

fn leadscrew_period() -> f64 {
    400.0
}
fn thermal_tau() -> f64 {
    1800.0
}
fn envelope_period() -> f64 {
    4000.0
}

/// The kinds of effect and their parameters (µm, ppm, µrad, s).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum EffectKind {
    /// δ_axis = ppm·1e-6·(p - ref_um)
    Scale {
        /// Scale error, ppm (1 ppm = 1 µm per m of travel).
        ppm: f64,
        /// Position of zero error, µm (default 0).
        #[serde(default)]
        ref_um: f64,
    },
    /// δ_axis = Σ_h cos_h·cos(2πh p/period) + sin_h·sin(2πh p/period)
    LeadscrewCyclic {
        /// Leadscrew pitch, µm (default 400).
        #[serde(default = "leadscrew_period")]
        period_um: f64,
        /// Cosine amplitude of each harmonic h = 1, 2, ..., µm.
        #[serde(default)]
        cos_um: Vec<f64>,
        /// Sine amplitude of each harmonic, µm; see `cos_um`.
        #[serde(default)]
        sin_um: Vec<f64>,
    },
    /// Same form as the leadscrew, one short period (motor revolution / encoder).
    MotorCyclic {
        /// Period (motor revolution or encoder line), µm.
        period_um: f64,
        /// Cosine amplitude of each harmonic h = 1, 2, ..., µm.
        #[serde(default)]
        cos_um: Vec<f64>,
        /// Sine amplitude of each harmonic, µm; see `cos_um`.
        #[serde(default)]
        sin_um: Vec<f64>,
    },
    /// δ_axis = (b/2)·d
    Backlash {
        /// Reversal width `b`, µm.
        reversal_um: f64,
    },
    /// δ_axis = ((b0 + b1·s)/2)·d
    Hysteresis {
        /// Reversal width at mid-travel (`b0`), µm.
        b0_um: f64,
        /// Change of the reversal width from mid-travel to the travel end (`b1`), µm (default 0).
        #[serde(default)]
        b1_um: f64,
    },
    /// δ_other = Σ_k c_k P_k(s), k = 2, 3, ...
    Straightness {
        /// Coefficients `c_2, c_3, ...` of the Legendre profile, µm.
        #[serde(default)]
        legendre_um: Vec<f64>,
    },
    /// δ_axis = -(e0 + e1·s)·1e-6·(p_other - offset_um)
    YawAbbe {
        /// Angles e0, e1, µrad: written as `[e0, e1]`; read as `[e0]` or `[e0, e1]`.
        #[serde(deserialize_with = "one_or_two")]
        yaw_urad: [f64; 2],
        /// Abbe offset: the other axis' position of zero error, µm (default 0).
        #[serde(default)]
        offset_um: f64,
    },
    /// δ_other = angle·1e-6·p_axis (declared on y: δ_x = α·p_y)
    Squareness {
        /// Angle α, µrad.
        angle_urad: f64,
    },
    /// δ_x = -θ p_y, δ_y = θ p_x (every sample)
    CameraRotation {
        /// Angle θ, µrad.
        angle_urad: f64,
    },
    /// δ = ppm·1e-6·(p_x, p_y) (every sample)
    CameraScale {
        /// Scale error, ppm.
        ppm: f64,
    },
    /// δ_component = amp·(1 - e^(-t/τ)) + rate·t/3600 (every sample). In a file, a missing
    /// `component` is the effect's `axis`.
    ThermalDrift {
        /// Component that drifts (`x` or `y`).
        component: AxisId,
        /// Exponential amplitude, µm (default 0).
        #[serde(default)]
        amp_um: f64,
        /// Time constant τ, s (default 1800); ≤ 0: the full amplitude from the start.
        #[serde(default = "thermal_tau")]
        tau_s: f64,
        /// Linear drift rate, µm/h (default 0).
        #[serde(default)]
        rate_um_per_h: f64,
    },
    /// White measurement noise (simulator only).
    Noise {
        /// Standard deviation, µm.
        sigma_um: f64,
    },

    // ---- simulator-only kinds (the paper-like generator and "outside the library" cases) ----
    /// Leadscrew cyclic error with a slowly varying envelope and phase:
    /// Σ_h amp_h·E(s)·cos(2πh p/period + phase_h + drift·(s+1)/2),
    /// E(s) = 1 + env_linear·s + env_wave_amp·sin(2π p/env_wave_period_um + env_wave_phase_rad).
    LeadscrewModulated {
        /// Leadscrew pitch, µm (default 400).
        #[serde(default = "leadscrew_period")]
        period_um: f64,
        /// Amplitude `amp_h` of each harmonic h = 1, 2, ..., µm.
        #[serde(default)]
        amp_um: Vec<f64>,
        /// Phase `phase_h` of each harmonic, rad (missing ones 0).
        #[serde(default)]
        phase_rad: Vec<f64>,
        /// Linear envelope slope over `s` (dimensionless, default 0).
        #[serde(default)]
        env_linear: f64,
        /// Relative amplitude of the envelope's wave (dimensionless, default 0).
        #[serde(default)]
        env_wave_amp: f64,
        /// Period of the envelope's wave, µm (default 4000).
        #[serde(default = "envelope_period")]
        env_wave_period_um: f64,
        /// Phase of the envelope's wave, rad (default 0).
        #[serde(default)]
        env_wave_phase_rad: f64,
        /// Phase drift from one travel end to the other, rad (default 0).
        #[serde(default)]
        phase_drift_rad: f64,
    },
    /// A sinusoidal profile of any period on a chosen component.
    Harmonic {
        /// Component the profile moves (default the effect's axis).
        #[serde(default)]
        component: Component,
        /// Period of the fundamental, µm.
        period_um: f64,
        /// Cosine amplitude of each harmonic h = 1, 2, ..., µm.
        #[serde(default)]
        cos_um: Vec<f64>,
        /// Sine amplitude of each harmonic, µm; see `cos_um`.
        #[serde(default)]
        sin_um: Vec<f64>,
    },
    /// Legendre profile Σ_k c_k P_k(s), k = 1, 2, ... on a chosen component (bows, trends).
    Legendre {
        /// Component the profile moves (default the effect's axis).
        #[serde(default)]
        component: Component,
        /// Coefficients `c_1, c_2, ...` of the Legendre profile, µm.
        #[serde(default)]
        coef_um: Vec<f64>,
    },
    /// Localized Gaussian defect (a dent in the leadscrew or guide).
    Defect {
        /// Component the defect moves (default the effect's axis).
        #[serde(default)]
        component: Component,
        /// Position of the defect's centre on the moving axis, µm.
        center_um: f64,
        /// Peak deviation (signed), µm.
        height_um: f64,
        /// Gaussian width (standard deviation), µm.
        sigma_um: f64,
    },
    /// Correlated roughness: a seeded AR(1) profile with correlation length `corr_um`.
    Roughness {
        /// Component the profile moves (default the effect's axis).
        #[serde(default)]
        component: Component,
        /// RMS of the profile, µm.
        sigma_um: f64,
        /// Correlation length, µm.
        corr_um: f64,
        /// TOML integers are i64: written as its bit pattern, so any u64 seed reads back.
        #[serde(default, with = "seed_bits")]
        seed: u64,
    },
}

fn one_or_two<'de, D: serde::Deserializer<'de>>(d: D) -> Result<[f64; 2], D::Error> {
    let v = Vec::<f64>::deserialize(d)?;
    match v[..] {
        [e0] => Ok([e0, 0.0]),
        [e0, e1] => Ok([e0, e1]),
        _ => Err(serde::de::Error::custom(
            "`yaw_urad` must be [e0] or [e0, e1]",
        )),
    }
}

mod seed_bits {
    use serde::{Deserialize, Deserializer, Serializer};

    pub(super) fn serialize<S: Serializer>(seed: &u64, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_i64(*seed as i64)
    }

    pub(super) fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<u64, D::Error> {
        Ok(i64::deserialize(d)? as u64)
    }
}

/// One effect of the model.
#[derive(Debug, Clone, PartialEq)]
pub struct Effect {
    /// The moving axis the effect belongs to.
    pub axis: AxisId,
    /// Travel over which `s` runs from -1 to 1; `None` = the model's axis range.
    pub travel_um: Option<[f64; 2]>,
    /// Kind and parameters.
    pub kind: EffectKind,
    /// Precomputed profile for `Roughness` (grid 1 µm over the travel).
    table: Option<RoughTable>,
}

#[derive(Debug, Clone, PartialEq)]
struct RoughTable {
    start_um: f64,
    step_um: f64,
    values: Vec<f64>,
}

/// Kinds of the effect library, as named in a model file.
pub const LIBRARY_KINDS: &[&str] = &[
    "scale",
    "leadscrew_cyclic",
    "motor_cyclic",
    "backlash",
    "hysteresis",
    "straightness",
    "yaw_abbe",
    "squareness",
    "camera_rotation",
    "camera_scale",
    "thermal_drift",
    "noise",
];

/// Kinds only the simulator knows (ground-truth error outside the library), as named in a model file.
pub const SIM_ONLY_KINDS: &[&str] = &[
    "leadscrew_modulated",
    "harmonic",
    "legendre",
    "defect",
    "roughness",
];

impl EffectKind {
    /// The `kind` name of a model file.
    pub fn name(&self) -> &'static str {
        match self {
            EffectKind::Scale { .. } => "scale",
            EffectKind::LeadscrewCyclic { .. } => "leadscrew_cyclic",
            EffectKind::MotorCyclic { .. } => "motor_cyclic",
            EffectKind::Backlash { .. } => "backlash",
            EffectKind::Hysteresis { .. } => "hysteresis",
            EffectKind::Straightness { .. } => "straightness",
            EffectKind::YawAbbe { .. } => "yaw_abbe",
            EffectKind::Squareness { .. } => "squareness",
            EffectKind::CameraRotation { .. } => "camera_rotation",
            EffectKind::CameraScale { .. } => "camera_scale",
            EffectKind::ThermalDrift { .. } => "thermal_drift",
            EffectKind::Noise { .. } => "noise",
            EffectKind::LeadscrewModulated { .. } => "leadscrew_modulated",
            EffectKind::Harmonic { .. } => "harmonic",
            EffectKind::Legendre { .. } => "legendre",
            EffectKind::Defect { .. } => "defect",
            EffectKind::Roughness { .. } => "roughness",
        }
    }

    /// Global kinds act on every sample, whatever axis moves.
    pub fn is_global(&self) -> bool {
        matches!(
            self,
            EffectKind::CameraRotation { .. }
                | EffectKind::CameraScale { .. }
                | EffectKind::ThermalDrift { .. }
        )
    }
}

/// Legendre polynomial P_k(s) by the three-term recurrence.
pub fn legendre(k: usize, s: f64) -> f64 {
    match k {
        0 => 1.0,
        1 => s,
        _ => {
            let (mut p0, mut p1) = (1.0, s);
            for n in 1..k {
                let nf = n as f64;
                let p2 = ((2.0 * nf + 1.0) * s * p1 - nf * p0) / (nf + 1.0);
                p0 = p1;
                p1 = p2;
            }
            p1
        }
    }
}

fn fourier(p: f64, period: f64, cos: &[f64], sin: &[f64]) -> f64 {
    let w = 2.0 * PI * p / period;
    let n = cos.len().max(sin.len());
    (0..n)
        .map(|i| {
            let h = (i + 1) as f64;
            cos.get(i).copied().unwrap_or(0.0) * (h * w).cos()
                + sin.get(i).copied().unwrap_or(0.0) * (h * w).sin()
        })
        .sum()
}

impl Effect {
    /// An effect on `axis` over the model's axis range.
    pub fn new(axis: AxisId, kind: EffectKind) -> Self {
        let mut e = Self {
            axis,
            travel_um: None,
            kind,
            table: None,
        };
        e.table = None;
        e
    }

    /// The same effect with its own travel `[lo, hi]`, µm, over which `s` runs from -1 to 1.
    pub fn with_travel(mut self, travel_um: [f64; 2]) -> Self {
        self.travel_um = Some(travel_um);
        self
    }

    /// The in-plane rotation of the carriage this effect implies at (x, y), µrad
    /// (counterclockwise +): the rotation whose Abbe error is the `yaw_abbe` deviation (x's yaw
    /// ψ moves x by −ψ·Δy: +ψ; y's moves y by −ψ·Δx: −ψ); 0 for every other kind.
    pub fn rotation_urad(&self, model: &StageModel, x_um: f64, y_um: f64) -> f64 {
        let EffectKind::YawAbbe { yaw_urad, .. } = &self.kind else {
            return 0.0;
        };
        let a = self.axis;
        let p = if a == AxisId::X { x_um } else { y_um };
        let travel = self.travel_um.unwrap_or_else(|| model.travel(a));
        let psi = yaw_urad[0] + yaw_urad[1] * map_to_unit(p, travel);
        match a {
            AxisId::X => psi,
            AxisId::Y => -psi,
        }
    }

    /// Whether this effect acts on a sample whose moving axis is `moving`.
    pub fn acts_on(&self, moving: AxisId) -> bool {
        self.kind.is_global() || self.axis == moving
    }

    /// The deviation this effect adds to a sample (noise excluded), assuming it acts on it.
    pub(super) fn deviation(&self, model: &StageModel, c: &SampleContext) -> Deviation {
        let a = self.axis;
        let o = a.other();
        let p = c.target(a);
        let travel = self.travel_um.unwrap_or_else(|| model.travel(a));
        let s = map_to_unit(p, travel);
        let d = c.direction;
        let mut dev = Deviation::default();
        let comp = |component: Component| match component {
            Component::Axis => a,
            Component::Other => o,
        };
        match &self.kind {
            EffectKind::Scale { ppm, ref_um } => dev.add(a, ppm * 1e-6 * (p - ref_um)),
            EffectKind::LeadscrewCyclic {
                period_um,
                cos_um,
                sin_um,
            }
            | EffectKind::MotorCyclic {
                period_um,
                cos_um,
                sin_um,
            } => dev.add(a, fourier(p, *period_um, cos_um, sin_um)),
            EffectKind::Backlash { reversal_um } => dev.add(a, reversal_um / 2.0 * d),
            EffectKind::Hysteresis { b0_um, b1_um } => dev.add(a, (b0_um + b1_um * s) / 2.0 * d),
            EffectKind::Straightness { legendre_um } => {
                let v = legendre_um
                    .iter()
                    .enumerate()
                    .map(|(i, c)| c * legendre(i + 2, s))
                    .sum();
                dev.add(o, v)
            }
            EffectKind::YawAbbe {
                yaw_urad,
                offset_um,
            } => {
                let other = c.target(o);
                dev.add(
                    a,
                    -(yaw_urad[0] + yaw_urad[1] * s) * 1e-6 * (other - offset_um),
                )
            }
            EffectKind::Squareness { angle_urad } => dev.add(o, angle_urad * 1e-6 * p),
            EffectKind::CameraRotation { angle_urad } => {
                let th = angle_urad * 1e-6;
                dev.x_um += -th * c.target_y_um;
                dev.y_um += th * c.target_x_um;
            }
            EffectKind::CameraScale { ppm } => {
                dev.x_um += ppm * 1e-6 * c.target_x_um;
                dev.y_um += ppm * 1e-6 * c.target_y_um;
            }
            EffectKind::ThermalDrift {
                component,
                amp_um,
                tau_s,
                rate_um_per_h,
            } => {
                let t = c.time_s;
                let expo = if *tau_s > 0.0 {
                    1.0 - (-t / tau_s).exp()
                } else {
                    1.0
                };
                dev.add(*component, amp_um * expo + rate_um_per_h * t / 3600.0)
            }
            EffectKind::Noise { .. } => {}
            EffectKind::LeadscrewModulated {
                period_um,
                amp_um,
                phase_rad,
                env_linear,
                env_wave_amp,
                env_wave_period_um,
                env_wave_phase_rad,
                phase_drift_rad,
            } => {
                let env = 1.0
                    + env_linear * s
                    + env_wave_amp * (2.0 * PI * p / env_wave_period_um + env_wave_phase_rad).sin();
                let drift = phase_drift_rad * (s + 1.0) / 2.0;
                let w = 2.0 * PI * p / period_um;
                let v: f64 = amp_um
                    .iter()
                    .enumerate()
                    .map(|(i, amp)| {
                        let h = (i + 1) as f64;
                        let ph = phase_rad.get(i).copied().unwrap_or(0.0);
                        amp * (h * w + ph + drift).cos()
                    })
                    .sum();
                dev.add(a, env * v)
            }
            EffectKind::Harmonic {
                component,
                period_um,
                cos_um,
                sin_um,
            } => dev.add(comp(*component), fourier(p, *period_um, cos_um, sin_um)),
            EffectKind::Legendre { component, coef_um } => {
                let v = coef_um
                    .iter()
                    .enumerate()
                    .map(|(i, c)| c * legendre(i + 1, s))
                    .sum();
                dev.add(comp(*component), v)
            }
            EffectKind::Defect {
                component,
                center_um,
                height_um,
                sigma_um,
            } => {
                let z = (p - center_um) / sigma_um;
                dev.add(comp(*component), height_um * (-0.5 * z * z).exp())
            }
            EffectKind::Roughness { component, .. } => {
                let v = self.table.as_ref().map(|t| t.eval(p)).unwrap_or(0.0);
                dev.add(comp(*component), v)
            }
        }
        dev
    }

    pub(super) fn prepare(&mut self, model_travel: [f64; 2]) {
        if let EffectKind::Roughness {
            sigma_um,
            corr_um,
            seed,
            ..
        } = &self.kind
        {
            let travel = self.travel_um.unwrap_or(model_travel);
            self.table = Some(RoughTable::ar1(travel, *sigma_um, *corr_um, *seed));
        }
    }
}

impl RoughTable {
    /// Stationary AR(1) on a 1 µm grid (with 1 mm margin each side): correlation e^(-Δ/corr).
    fn ar1(travel: [f64; 2], sigma: f64, corr: f64, seed: u64) -> Self {
        use rand::SeedableRng;
        use rand_distr::{Distribution, StandardNormal};
        let step = 1.0;
        let start = travel[0].min(travel[1]) - 1000.0;
        let n = ((travel[1] - travel[0]).abs() + 2000.0).ceil() as usize + 1;
        let rho = (-step / corr.max(1e-9)).exp();
        let innov = sigma * (1.0 - rho * rho).sqrt();
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        let mut values = Vec::with_capacity(n);
        let z0: f64 = StandardNormal.sample(&mut rng);
        let mut v = sigma * z0;
        for _ in 0..n {
            values.push(v);
            let z: f64 = StandardNormal.sample(&mut rng);
            v = rho * v + innov * z;
        }
        Self {
            start_um: start,
            step_um: step,
            values,
        }
    }

    fn eval(&self, p: f64) -> f64 {
        let u = ((p - self.start_um) / self.step_um).clamp(0.0, (self.values.len() - 1) as f64);
        let i = (u.floor() as usize).min(self.values.len() - 2);
        let f = u - i as f64;
        self.values[i] * (1.0 - f) + self.values[i + 1] * f
    }
}

/// Maps p to [-1, 1] over `travel`.
pub fn map_to_unit(p: f64, travel: [f64; 2]) -> f64 {
    let span = travel[1] - travel[0];
    if span.abs() < f64::EPSILON {
        0.0
    } else {
        2.0 * (p - travel[0]) / span - 1.0
    }
}
