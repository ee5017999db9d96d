//! The stage model: one effect library for the error-curve generator, the simulated controller
//! and camera, and `csmetro gap` (see `shared/notes/gap-contract.md`).
//!
//! A model is a list of effects, each an `[[effect]]` table in a TOML file:
//!
//! ```toml
//! [stage]
//! travel_x_um = [0.0, 9500.0]
//! travel_y_um = [0.0, 4200.0]
//!
//! [[effect]]
//! kind = "leadscrew_cyclic"
//! axis = "x"
//! period_um = 400.0
//! cos_um = [1.0]
//! sin_um = [0.0]
//! ```
//!
//! Measured position = target + Σ deviations of the effects that act on the sample (+ noise).
//! An effect acts on a sample when its `axis` is the moving axis, except the global kinds
//! (`camera_rotation`, `camera_scale`, `thermal_drift`), which act on every sample.
use std::collections::BTreeMap;
use std::f64::consts::PI;
use std::path::Path;

use toml::{Table, Value};

// The axis and direction types live in the hardware seam; re-exported where they always were.
pub use csmetro_hal::{AxisId, Direction};

/// Everything the model needs to predict one measured sample.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SampleContext {
    /// The moving axis of this line.
    pub moving: AxisId,
    /// Approach direction: +1 forward, -1 backward.
    pub direction: f64,
    pub target_x_um: f64,
    pub target_y_um: f64,
    /// Seconds since the start of the data (campaign).
    pub time_s: f64,
}

impl SampleContext {
    pub fn target(&self, axis: AxisId) -> f64 {
        match axis {
            AxisId::X => self.target_x_um,
            AxisId::Y => self.target_y_um,
        }
    }
}

/// A deviation vector (δx, δy) in µm.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Deviation {
    pub x_um: f64,
    pub y_um: f64,
}

impl Deviation {
    fn add(&mut self, axis: AxisId, v: f64) {
        match axis {
            AxisId::X => self.x_um += v,
            AxisId::Y => self.y_um += v,
        }
    }
    pub fn get(&self, axis: AxisId) -> f64 {
        match axis {
            AxisId::X => self.x_um,
            AxisId::Y => self.y_um,
        }
    }
}

/// Which component a simulator-only effect moves: the effect's own axis or the other one.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Component {
    Axis,
    Other,
}

/// The kinds of effect and their parameters (µm, ppm, µrad, s).
#[derive(Debug, Clone, PartialEq)]
pub enum EffectKind {
    /// δ_axis = ppm·1e-6·(p - ref_um)
    Scale { ppm: f64, ref_um: f64 },
    /// δ_axis = Σ_h cos_h·cos(2πh p/period) + sin_h·sin(2πh p/period)
    LeadscrewCyclic {
        period_um: f64,
        cos_um: Vec<f64>,
        sin_um: Vec<f64>,
    },
    /// Same form as the leadscrew, one short period (motor revolution / encoder).
    MotorCyclic {
        period_um: f64,
        cos_um: Vec<f64>,
        sin_um: Vec<f64>,
    },
    /// δ_axis = (b/2)·d
    Backlash { reversal_um: f64 },
    /// δ_axis = ((b0 + b1·s)/2)·d
    Hysteresis { b0_um: f64, b1_um: f64 },
    /// δ_other = Σ_k c_k P_k(s), k = 2, 3, ...
    Straightness { legendre_um: Vec<f64> },
    /// δ_axis = -(e0 + e1·s)·1e-6·(p_other - offset_um)
    YawAbbe { yaw_urad: [f64; 2], offset_um: f64 },
    /// δ_other = angle·1e-6·p_axis (declared on y: δ_x = α·p_y)
    Squareness { angle_urad: f64 },
    /// δ_x = -θ p_y, δ_y = θ p_x (every sample)
    CameraRotation { angle_urad: f64 },
    /// δ = ppm·1e-6·(p_x, p_y) (every sample)
    CameraScale { ppm: f64 },
    /// δ_component = amp·(1 - e^(-t/τ)) + rate·t/3600 (every sample)
    ThermalDrift {
        component: AxisId,
        amp_um: f64,
        tau_s: f64,
        rate_um_per_h: f64,
    },
    /// White measurement noise (simulator only).
    Noise { sigma_um: f64 },

    // ---- simulator-only kinds (the paper-like generator and "outside the library" cases) ----
    /// Leadscrew cyclic error with a slowly varying envelope and phase:
    /// Σ_h amp_h·E(s)·cos(2πh p/period + phase_h + drift·(s+1)/2),
    /// E(s) = 1 + env_linear·s + env_wave_amp·sin(2π p/env_wave_period_um + env_wave_phase_rad).
    LeadscrewModulated {
        period_um: f64,
        amp_um: Vec<f64>,
        phase_rad: Vec<f64>,
        env_linear: f64,
        env_wave_amp: f64,
        env_wave_period_um: f64,
        env_wave_phase_rad: f64,
        phase_drift_rad: f64,
    },
    /// A sinusoidal profile of any period on a chosen component.
    Harmonic {
        component: Component,
        period_um: f64,
        cos_um: Vec<f64>,
        sin_um: Vec<f64>,
    },
    /// Legendre profile Σ_k c_k P_k(s), k = 1, 2, ... on a chosen component (bows, trends).
    Legendre {
        component: Component,
        coef_um: Vec<f64>,
    },
    /// Localized Gaussian defect (a dent in the leadscrew or guide).
    Defect {
        component: Component,
        center_um: f64,
        height_um: f64,
        sigma_um: f64,
    },
    /// Correlated roughness: a seeded AR(1) profile with correlation length `corr_um`.
    Roughness {
        component: Component,
        sigma_um: f64,
        corr_um: f64,
        seed: u64,
    },
}

/// One effect of the model.
#[derive(Debug, Clone, PartialEq)]
pub struct Effect {
    /// The moving axis the effect belongs to.
    pub axis: AxisId,
    /// Travel over which `s` runs from -1 to 1; `None` = the model's axis range.
    pub travel_um: Option<[f64; 2]>,
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

/// Model-file errors, each naming the effect and the key.
#[derive(Debug, thiserror::Error)]
pub enum ModelError {
    #[error("{path}: {message}")]
    File { path: String, message: String },
    #[error("{0}")]
    Invalid(String),
}

/// The stage model: axis ranges and effects.
#[derive(Debug, Clone, PartialEq)]
pub struct StageModel {
    pub travel_x_um: [f64; 2],
    pub travel_y_um: [f64; 2],
    pub effects: Vec<Effect>,
}

impl Default for StageModel {
    /// An ideal stage over the paper's pattern range (9.5 mm x 4.2 mm).
    fn default() -> Self {
        Self {
            travel_x_um: [0.0, 9500.0],
            travel_y_um: [0.0, 4200.0],
            effects: Vec::new(),
        }
    }
}

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

pub const SIM_ONLY_KINDS: &[&str] = &[
    "leadscrew_modulated",
    "harmonic",
    "legendre",
    "defect",
    "roughness",
];

impl EffectKind {
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

    pub fn with_travel(mut self, travel_um: [f64; 2]) -> Self {
        self.travel_um = Some(travel_um);
        self
    }

    /// Whether this effect acts on a sample whose moving axis is `moving`.
    pub fn acts_on(&self, moving: AxisId) -> bool {
        self.kind.is_global() || self.axis == moving
    }

    /// The deviation this effect adds to a sample (noise excluded), assuming it acts on it.
    fn deviation(&self, model: &StageModel, c: &SampleContext) -> Deviation {
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

    fn prepare(&mut self, model_travel: [f64; 2]) {
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

impl StageModel {
    pub fn new(travel_x_um: [f64; 2], travel_y_um: [f64; 2]) -> Self {
        Self {
            travel_x_um,
            travel_y_um,
            effects: Vec::new(),
        }
    }

    pub fn travel(&self, axis: AxisId) -> [f64; 2] {
        match axis {
            AxisId::X => self.travel_x_um,
            AxisId::Y => self.travel_y_um,
        }
    }

    /// Adds an effect (and builds its lookup table if it needs one).
    pub fn push(&mut self, mut effect: Effect) {
        effect.prepare(self.travel(effect.axis));
        self.effects.push(effect);
    }

    pub fn with(mut self, effect: Effect) -> Self {
        self.push(effect);
        self
    }

    /// Sum of the deviations of the effects that act on this sample (no noise).
    pub fn deviation(&self, c: &SampleContext) -> Deviation {
        let mut total = Deviation::default();
        for e in self.effects.iter().filter(|e| e.acts_on(c.moving)) {
            let d = e.deviation(self, c);
            total.x_um += d.x_um;
            total.y_um += d.y_um;
        }
        total
    }

    /// Deviation of a single effect (index into `effects`), zero if it does not act on the sample.
    pub fn effect_deviation(&self, index: usize, c: &SampleContext) -> Deviation {
        let e = &self.effects[index];
        if e.acts_on(c.moving) {
            e.deviation(self, c)
        } else {
            Deviation::default()
        }
    }

    /// Noise-free predicted measurement (x, y) in µm: target + deviations.
    pub fn predict(&self, c: &SampleContext) -> (f64, f64) {
        let d = self.deviation(c);
        (c.target_x_um + d.x_um, c.target_y_um + d.y_um)
    }

    /// Total white measurement noise σ, µm (root sum of squares of `noise` effects).
    pub fn noise_sigma_um(&self) -> f64 {
        self.effects
            .iter()
            .filter_map(|e| match e.kind {
                EffectKind::Noise { sigma_um } => Some(sigma_um * sigma_um),
                _ => None,
            })
            .sum::<f64>()
            .sqrt()
    }

    /// Reads a model TOML file; errors name the file, the effect and the key.
    pub fn load(path: &Path) -> Result<Self, ModelError> {
        let text = std::fs::read_to_string(path).map_err(|e| ModelError::File {
            path: path.display().to_string(),
            message: e.to_string(),
        })?;
        Self::from_toml_str(&text).map_err(|e| ModelError::File {
            path: path.display().to_string(),
            message: e.to_string(),
        })
    }

    pub fn from_toml_str(text: &str) -> Result<Self, ModelError> {
        let table: Table = text
            .parse()
            .map_err(|e: toml::de::Error| ModelError::Invalid(e.to_string()))?;
        Self::from_table(&table)
    }

    pub fn from_table(table: &Table) -> Result<Self, ModelError> {
        let mut model = StageModel::default();
        for key in table.keys() {
            if key != "stage" && key != "effect" {
                return Err(ModelError::Invalid(format!(
                    "unknown top-level key `{key}` (expected [stage] and [[effect]])"
                )));
            }
        }
        if let Some(stage) = table.get("stage") {
            let stage = stage
                .as_table()
                .ok_or_else(|| ModelError::Invalid("`stage` must be a table".into()))?;
            let mut p = Params::new("[stage]", stage);
            if let Some(v) = p.opt_pair("travel_x_um")? {
                model.travel_x_um = v;
            }
            if let Some(v) = p.opt_pair("travel_y_um")? {
                model.travel_y_um = v;
            }
            p.finish()?;
        }
        if let Some(effects) = table.get("effect") {
            let arr = effects.as_array().ok_or_else(|| {
                ModelError::Invalid("`effect` must be an array of tables ([[effect]])".into())
            })?;
            for (i, e) in arr.iter().enumerate() {
                let t = e.as_table().ok_or_else(|| {
                    ModelError::Invalid(format!("effect #{}: must be a table", i + 1))
                })?;
                let effect = parse_effect(i + 1, t)?;
                model.push(effect);
            }
        }
        Ok(model)
    }

    /// The model as TOML, in the same format `load` reads.
    pub fn to_toml_string(&self) -> String {
        let mut root = Table::new();
        let mut stage = Table::new();
        stage.insert("travel_x_um".into(), pair(self.travel_x_um));
        stage.insert("travel_y_um".into(), pair(self.travel_y_um));
        root.insert("stage".into(), Value::Table(stage));
        let effects: Vec<Value> = self
            .effects
            .iter()
            .map(|e| Value::Table(e.to_table()))
            .collect();
        root.insert("effect".into(), Value::Array(effects));
        toml::to_string(&root).expect("a TOML table always serializes")
    }
}

fn pair(v: [f64; 2]) -> Value {
    Value::Array(vec![Value::Float(v[0]), Value::Float(v[1])])
}

fn floats(v: &[f64]) -> Value {
    Value::Array(v.iter().map(|&x| Value::Float(x)).collect())
}

fn component_str(c: Component) -> &'static str {
    match c {
        Component::Axis => "axis",
        Component::Other => "other",
    }
}

impl Effect {
    /// This effect's parameters as an ordered map (for reports and JSON).
    pub fn params(&self) -> BTreeMap<String, Value> {
        let mut t = self.to_table();
        t.remove("kind");
        t.remove("axis");
        t.into_iter().collect()
    }

    pub fn to_table(&self) -> Table {
        let mut t = Table::new();
        t.insert("kind".into(), Value::String(self.kind.name().into()));
        t.insert("axis".into(), Value::String(self.axis.as_str().into()));
        if let Some(tr) = self.travel_um {
            t.insert("travel_um".into(), pair(tr));
        }
        let mut put = |k: &str, v: Value| {
            t.insert(k.into(), v);
        };
        match &self.kind {
            EffectKind::Scale { ppm, ref_um } => {
                put("ppm", Value::Float(*ppm));
                put("ref_um", Value::Float(*ref_um));
            }
            EffectKind::LeadscrewCyclic {
                period_um,
                cos_um,
                sin_um,
            }
            | EffectKind::MotorCyclic {
                period_um,
                cos_um,
                sin_um,
            } => {
                put("period_um", Value::Float(*period_um));
                put("cos_um", floats(cos_um));
                put("sin_um", floats(sin_um));
            }
            EffectKind::Backlash { reversal_um } => put("reversal_um", Value::Float(*reversal_um)),
            EffectKind::Hysteresis { b0_um, b1_um } => {
                put("b0_um", Value::Float(*b0_um));
                put("b1_um", Value::Float(*b1_um));
            }
            EffectKind::Straightness { legendre_um } => put("legendre_um", floats(legendre_um)),
            EffectKind::YawAbbe {
                yaw_urad,
                offset_um,
            } => {
                put("yaw_urad", floats(yaw_urad));
                put("offset_um", Value::Float(*offset_um));
            }
            EffectKind::Squareness { angle_urad } | EffectKind::CameraRotation { angle_urad } => {
                put("angle_urad", Value::Float(*angle_urad))
            }
            EffectKind::CameraScale { ppm } => put("ppm", Value::Float(*ppm)),
            EffectKind::ThermalDrift {
                component,
                amp_um,
                tau_s,
                rate_um_per_h,
            } => {
                put("component", Value::String(component.as_str().into()));
                put("amp_um", Value::Float(*amp_um));
                put("tau_s", Value::Float(*tau_s));
                put("rate_um_per_h", Value::Float(*rate_um_per_h));
            }
            EffectKind::Noise { sigma_um } => put("sigma_um", Value::Float(*sigma_um)),
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
                put("period_um", Value::Float(*period_um));
                put("amp_um", floats(amp_um));
                put("phase_rad", floats(phase_rad));
                put("env_linear", Value::Float(*env_linear));
                put("env_wave_amp", Value::Float(*env_wave_amp));
                put("env_wave_period_um", Value::Float(*env_wave_period_um));
                put("env_wave_phase_rad", Value::Float(*env_wave_phase_rad));
                put("phase_drift_rad", Value::Float(*phase_drift_rad));
            }
            EffectKind::Harmonic {
                component,
                period_um,
                cos_um,
                sin_um,
            } => {
                put("component", Value::String(component_str(*component).into()));
                put("period_um", Value::Float(*period_um));
                put("cos_um", floats(cos_um));
                put("sin_um", floats(sin_um));
            }
            EffectKind::Legendre { component, coef_um } => {
                put("component", Value::String(component_str(*component).into()));
                put("coef_um", floats(coef_um));
            }
            EffectKind::Defect {
                component,
                center_um,
                height_um,
                sigma_um,
            } => {
                put("component", Value::String(component_str(*component).into()));
                put("center_um", Value::Float(*center_um));
                put("height_um", Value::Float(*height_um));
                put("sigma_um", Value::Float(*sigma_um));
            }
            EffectKind::Roughness {
                component,
                sigma_um,
                corr_um,
                seed,
            } => {
                put("component", Value::String(component_str(*component).into()));
                put("sigma_um", Value::Float(*sigma_um));
                put("corr_um", Value::Float(*corr_um));
                put("seed", Value::Integer(*seed as i64));
            }
        }
        t
    }
}

/// Reads one effect's parameters, tracking which keys were used so leftovers are errors.
struct Params<'a> {
    ctx: String,
    table: &'a Table,
    used: Vec<&'static str>,
}

impl<'a> Params<'a> {
    fn new(ctx: &str, table: &'a Table) -> Self {
        Self {
            ctx: ctx.to_string(),
            table,
            used: Vec::new(),
        }
    }

    fn err(&self, msg: String) -> ModelError {
        ModelError::Invalid(format!("{}: {}", self.ctx, msg))
    }

    fn num(&self, key: &str, v: &Value) -> Result<f64, ModelError> {
        let x = match v {
            Value::Float(f) => *f,
            Value::Integer(i) => *i as f64,
            _ => return Err(self.err(format!("`{key}` must be a number"))),
        };
        if !x.is_finite() {
            return Err(self.err(format!("`{key}` must be finite")));
        }
        Ok(x)
    }

    fn opt_f64(&mut self, key: &'static str) -> Result<Option<f64>, ModelError> {
        self.used.push(key);
        match self.table.get(key) {
            None => Ok(None),
            Some(v) => self.num(key, v).map(Some),
        }
    }

    fn f64_or(&mut self, key: &'static str, default: f64) -> Result<f64, ModelError> {
        Ok(self.opt_f64(key)?.unwrap_or(default))
    }

    fn req_f64(&mut self, key: &'static str) -> Result<f64, ModelError> {
        self.opt_f64(key)?
            .ok_or_else(|| self.err(format!("missing parameter `{key}`")))
    }

    fn vec_or_empty(&mut self, key: &'static str) -> Result<Vec<f64>, ModelError> {
        self.used.push(key);
        match self.table.get(key) {
            None => Ok(Vec::new()),
            Some(Value::Array(a)) => a.iter().map(|v| self.num(key, v)).collect(),
            Some(_) => Err(self.err(format!("`{key}` must be an array of numbers"))),
        }
    }

    fn opt_pair(&mut self, key: &'static str) -> Result<Option<[f64; 2]>, ModelError> {
        self.used.push(key);
        match self.table.get(key) {
            None => Ok(None),
            Some(Value::Array(a)) if a.len() == 2 => {
                let lo = self.num(key, &a[0])?;
                let hi = self.num(key, &a[1])?;
                if hi <= lo {
                    return Err(self.err(format!("`{key}` must be [lo, hi] with lo < hi")));
                }
                Ok(Some([lo, hi]))
            }
            Some(_) => Err(self.err(format!("`{key}` must be [lo, hi] in µm"))),
        }
    }

    fn string(&mut self, key: &'static str) -> Result<Option<String>, ModelError> {
        self.used.push(key);
        match self.table.get(key) {
            None => Ok(None),
            Some(Value::String(s)) => Ok(Some(s.clone())),
            Some(_) => Err(self.err(format!("`{key}` must be a string"))),
        }
    }

    fn component(&mut self, default: Component) -> Result<Component, ModelError> {
        match self.string("component")?.as_deref() {
            None => Ok(default),
            Some("axis") => Ok(Component::Axis),
            Some("other") => Ok(Component::Other),
            Some(s) => Err(self.err(format!(
                "`component` must be \"axis\" or \"other\", not {s:?}"
            ))),
        }
    }

    fn positive(&self, key: &str, v: f64) -> Result<f64, ModelError> {
        if v > 0.0 {
            Ok(v)
        } else {
            Err(self.err(format!("`{key}` must be > 0")))
        }
    }

    fn finish(self) -> Result<(), ModelError> {
        for key in self.table.keys() {
            if !self.used.contains(&key.as_str()) {
                return Err(self.err(format!(
                    "unknown parameter `{key}` (allowed: {})",
                    self.used.join(", ")
                )));
            }
        }
        Ok(())
    }
}

fn parse_effect(index: usize, t: &Table) -> Result<Effect, ModelError> {
    let kind_name = match t.get("kind") {
        Some(Value::String(s)) => s.clone(),
        _ => {
            return Err(ModelError::Invalid(format!(
                "effect #{index}: missing `kind` (one of {})",
                LIBRARY_KINDS.join(", ")
            )))
        }
    };
    let mut p = Params::new(&format!("effect #{index} ({kind_name})"), t);
    p.used.push("kind");
    let axis = match p.string("axis")? {
        Some(s) => {
            AxisId::parse(&s).ok_or_else(|| p.err(format!("`axis` must be x or y, not {s:?}")))?
        }
        None => {
            // Global kinds belong to no axis; others must name theirs.
            if matches!(
                kind_name.as_str(),
                "camera_rotation" | "camera_scale" | "thermal_drift" | "noise"
            ) {
                AxisId::X
            } else {
                return Err(p.err("missing `axis` (x or y)".into()));
            }
        }
    };
    let travel = p.opt_pair("travel_um")?;
    let kind = match kind_name.as_str() {
        "scale" => EffectKind::Scale {
            ppm: p.req_f64("ppm")?,
            ref_um: p.f64_or("ref_um", 0.0)?,
        },
        "leadscrew_cyclic" | "motor_cyclic" => {
            let period = p.f64_or(
                "period_um",
                if kind_name == "leadscrew_cyclic" {
                    400.0
                } else {
                    f64::NAN
                },
            )?;
            if period.is_nan() {
                return Err(p.err("missing parameter `period_um`".into()));
            }
            let period_um = p.positive("period_um", period)?;
            let cos_um = p.vec_or_empty("cos_um")?;
            let sin_um = p.vec_or_empty("sin_um")?;
            if cos_um.is_empty() && sin_um.is_empty() {
                return Err(p.err("needs `cos_um` and/or `sin_um` (one value per harmonic)".into()));
            }
            if kind_name == "leadscrew_cyclic" {
                EffectKind::LeadscrewCyclic {
                    period_um,
                    cos_um,
                    sin_um,
                }
            } else {
                EffectKind::MotorCyclic {
                    period_um,
                    cos_um,
                    sin_um,
                }
            }
        }
        "backlash" => EffectKind::Backlash {
            reversal_um: p.req_f64("reversal_um")?,
        },
        "hysteresis" => EffectKind::Hysteresis {
            b0_um: p.req_f64("b0_um")?,
            b1_um: p.f64_or("b1_um", 0.0)?,
        },
        "straightness" => {
            let legendre_um = p.vec_or_empty("legendre_um")?;
            if legendre_um.is_empty() {
                return Err(p.err("needs `legendre_um` = [c2, c3, ..]".into()));
            }
            EffectKind::Straightness { legendre_um }
        }
        "yaw_abbe" => {
            let v = p.vec_or_empty("yaw_urad")?;
            if v.is_empty() || v.len() > 2 {
                return Err(p.err("`yaw_urad` must be [e0] or [e0, e1]".into()));
            }
            EffectKind::YawAbbe {
                yaw_urad: [v[0], v.get(1).copied().unwrap_or(0.0)],
                offset_um: p.f64_or("offset_um", 0.0)?,
            }
        }
        "squareness" => EffectKind::Squareness {
            angle_urad: p.req_f64("angle_urad")?,
        },
        "camera_rotation" => EffectKind::CameraRotation {
            angle_urad: p.req_f64("angle_urad")?,
        },
        "camera_scale" => EffectKind::CameraScale {
            ppm: p.req_f64("ppm")?,
        },
        "thermal_drift" => {
            let component = match p.string("component")?.as_deref() {
                None => axis,
                Some(s) => AxisId::parse(s)
                    .ok_or_else(|| p.err(format!("`component` must be x or y, not {s:?}")))?,
            };
            EffectKind::ThermalDrift {
                component,
                amp_um: p.f64_or("amp_um", 0.0)?,
                tau_s: p.f64_or("tau_s", 1800.0)?,
                rate_um_per_h: p.f64_or("rate_um_per_h", 0.0)?,
            }
        }
        "noise" => {
            let s = p.req_f64("sigma_um")?;
            if s < 0.0 {
                return Err(p.err("`sigma_um` must be >= 0".into()));
            }
            EffectKind::Noise { sigma_um: s }
        }
        "leadscrew_modulated" => {
            let period = p.f64_or("period_um", 400.0)?;
            EffectKind::LeadscrewModulated {
                period_um: p.positive("period_um", period)?,
                amp_um: p.vec_or_empty("amp_um")?,
                phase_rad: p.vec_or_empty("phase_rad")?,
                env_linear: p.f64_or("env_linear", 0.0)?,
                env_wave_amp: p.f64_or("env_wave_amp", 0.0)?,
                env_wave_period_um: {
                    let v = p.f64_or("env_wave_period_um", 4000.0)?;
                    p.positive("env_wave_period_um", v)?
                },
                env_wave_phase_rad: p.f64_or("env_wave_phase_rad", 0.0)?,
                phase_drift_rad: p.f64_or("phase_drift_rad", 0.0)?,
            }
        }
        "harmonic" => {
            let component = p.component(Component::Axis)?;
            let period = p.req_f64("period_um")?;
            EffectKind::Harmonic {
                component,
                period_um: p.positive("period_um", period)?,
                cos_um: p.vec_or_empty("cos_um")?,
                sin_um: p.vec_or_empty("sin_um")?,
            }
        }
        "legendre" => EffectKind::Legendre {
            component: p.component(Component::Axis)?,
            coef_um: p.vec_or_empty("coef_um")?,
        },
        "defect" => {
            let component = p.component(Component::Axis)?;
            let sigma = p.req_f64("sigma_um")?;
            EffectKind::Defect {
                component,
                center_um: p.req_f64("center_um")?,
                height_um: p.req_f64("height_um")?,
                sigma_um: p.positive("sigma_um", sigma)?,
            }
        }
        "roughness" => {
            let component = p.component(Component::Axis)?;
            let corr = p.req_f64("corr_um")?;
            let seed = match t.get("seed") {
                None => 0,
                Some(Value::Integer(i)) if *i >= 0 => *i as u64,
                Some(_) => return Err(p.err("`seed` must be a non-negative integer".into())),
            };
            p.used.push("seed");
            EffectKind::Roughness {
                component,
                sigma_um: p.req_f64("sigma_um")?,
                corr_um: p.positive("corr_um", corr)?,
                seed,
            }
        }
        other => {
            return Err(ModelError::Invalid(format!(
                "effect #{index}: unknown kind `{other}` (library: {}; simulator-only: {})",
                LIBRARY_KINDS.join(", "),
                SIM_ONLY_KINDS.join(", ")
            )))
        }
    };
    p.finish()?;
    let mut e = Effect::new(axis, kind);
    e.travel_um = travel;
    Ok(e)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ctx(moving: AxisId, d: f64, x: f64, y: f64) -> SampleContext {
        SampleContext {
            moving,
            direction: d,
            target_x_um: x,
            target_y_um: y,
            time_s: 0.0,
        }
    }

    /// The worked example of the gap contract, to the digit.
    #[test]
    fn gap_contract_worked_example() {
        let m = StageModel::from_toml_str(
            r#"
            [[effect]]
            kind = "leadscrew_cyclic"
            axis = "x"
            period_um = 400
            cos_um = [1.0]
            sin_um = [0.0]
            [[effect]]
            kind = "backlash"
            axis = "x"
            reversal_um = 2.0
            [[effect]]
            kind = "squareness"
            axis = "y"
            angle_urad = 100
            "#,
        )
        .unwrap();
        let (x, y) = m.predict(&ctx(AxisId::X, 1.0, 100.0, 2000.0));
        assert!(
            (x - 101.0).abs() < 1e-12 && (y - 2000.0).abs() < 1e-12,
            "{x} {y}"
        );
        let (x, y) = m.predict(&ctx(AxisId::X, -1.0, 200.0, 2000.0));
        assert!(
            (x - 198.0).abs() < 1e-12 && (y - 2000.0).abs() < 1e-12,
            "{x} {y}"
        );
        let (x, y) = m.predict(&ctx(AxisId::Y, 1.0, 4750.0, 1000.0));
        assert!(
            (x - 4750.1).abs() < 1e-9 && (y - 1000.0).abs() < 1e-12,
            "{x} {y}"
        );
    }

    #[test]
    fn effects_of_static_axis_do_not_act_but_global_ones_do() {
        let m = StageModel::default()
            .with(Effect::new(
                AxisId::Y,
                EffectKind::Scale {
                    ppm: 100.0,
                    ref_um: 0.0,
                },
            ))
            .with(Effect::new(
                AxisId::X,
                EffectKind::CameraRotation { angle_urad: 10.0 },
            ));
        let d = m.deviation(&ctx(AxisId::X, 1.0, 1000.0, 2000.0));
        assert!((d.x_um - (-10e-6 * 2000.0)).abs() < 1e-12);
        assert!((d.y_um - 10e-6 * 1000.0).abs() < 1e-12);
    }

    #[test]
    fn toml_round_trip_keeps_every_parameter() {
        let text = r#"
            [stage]
            travel_x_um = [0.0, 9500.0]
            travel_y_um = [0.0, 4200.0]
            [[effect]]
            kind = "yaw_abbe"
            axis = "x"
            yaw_urad = [20.0, -5.0]
            offset_um = 2100.0
            [[effect]]
            kind = "thermal_drift"
            component = "y"
            amp_um = 0.5
            tau_s = 900
            rate_um_per_h = 0.1
            [[effect]]
            kind = "roughness"
            axis = "x"
            sigma_um = 0.085
            corr_um = 12
            seed = 7
        "#;
        let m = StageModel::from_toml_str(text).unwrap();
        let again = StageModel::from_toml_str(&m.to_toml_string()).unwrap();
        assert_eq!(m, again);
        let c = SampleContext {
            time_s: 600.0,
            ..ctx(AxisId::X, 1.0, 4321.0, 1234.0)
        };
        assert_eq!(m.deviation(&c), again.deviation(&c));
    }

    #[test]
    fn bad_files_are_refused_with_the_key_named() {
        let e =
            StageModel::from_toml_str("[[effect]]\nkind = \"warp\"\naxis = \"x\"\n").unwrap_err();
        assert!(e.to_string().contains("unknown kind `warp`"), "{e}");
        let e = StageModel::from_toml_str(
            "[[effect]]\nkind = \"scale\"\naxis = \"x\"\nppm = 1\nfoo = 2\n",
        )
        .unwrap_err();
        assert!(e.to_string().contains("unknown parameter `foo`"), "{e}");
        let e = StageModel::from_toml_str("[[effect]]\nkind = \"backlash\"\naxis = \"x\"\n")
            .unwrap_err();
        assert!(e.to_string().contains("reversal_um"), "{e}");
    }

    #[test]
    fn legendre_matches_closed_forms() {
        for &s in &[-1.0, -0.3, 0.0, 0.7, 1.0] {
            assert!((legendre(2, s) - 0.5 * (3.0 * s * s - 1.0)).abs() < 1e-14);
            assert!((legendre(3, s) - 0.5 * (5.0 * s * s * s - 3.0 * s)).abs() < 1e-14);
        }
    }

    #[test]
    fn roughness_has_the_requested_sigma() {
        let m = StageModel::default().with(Effect::new(
            AxisId::X,
            EffectKind::Roughness {
                component: Component::Axis,
                sigma_um: 0.1,
                corr_um: 12.0,
                seed: 3,
            },
        ));
        let v: Vec<f64> = (0..1900)
            .map(|i| m.deviation(&ctx(AxisId::X, 1.0, i as f64 * 5.0, 0.0)).x_um)
            .collect();
        let mean = v.iter().sum::<f64>() / v.len() as f64;
        let sd = (v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / v.len() as f64).sqrt();
        assert!((sd - 0.1).abs() < 0.02, "sd {sd}");
    }
}
