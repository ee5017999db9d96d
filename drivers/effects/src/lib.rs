#![doc = include_str!("../README.md")]
// Lints: the workspace wall (Cargo.toml `[workspace.lints]`), plus docs on everything public.
#![warn(missing_docs)]
mod effect;
mod file;

pub use effect::{
    legendre, map_to_unit, Component, Effect, EffectKind, LIBRARY_KINDS, SIM_ONLY_KINDS,
};
pub use file::{MAX_EFFECTS, MAX_TERMS, MAX_TRAVEL_UM};

// The axis and direction types live in the hardware seam; re-exported where they always were.
pub use csmetro_hal::{AxisId, Direction};

/// Everything the model needs to predict one measured sample.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SampleContext {
    /// The moving axis of this line.
    pub moving: AxisId,
    /// Approach direction: +1 forward, -1 backward.
    pub direction: f64,
    /// Target position on x, µm.
    pub target_x_um: f64,
    /// Target position on y, µm.
    pub target_y_um: f64,
    /// Seconds since the start of the data (campaign).
    pub time_s: f64,
}

impl SampleContext {
    /// Target position on `axis`, µm.
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
    /// Deviation along x, µm.
    pub x_um: f64,
    /// Deviation along y, µm.
    pub y_um: f64,
}

impl Deviation {
    pub(crate) fn add(&mut self, axis: AxisId, v: f64) {
        match axis {
            AxisId::X => self.x_um += v,
            AxisId::Y => self.y_um += v,
        }
    }
    /// Deviation along `axis`, µm.
    pub fn get(&self, axis: AxisId) -> f64 {
        match axis {
            AxisId::X => self.x_um,
            AxisId::Y => self.y_um,
        }
    }
}

/// Model-file errors, one line each, naming the line (and the file when read from one).
#[derive(Debug, thiserror::Error)]
pub enum ModelError {
    /// A problem in a model file.
    #[error("{path}: {message}")]
    File {
        /// Where: `FILE` or `FILE:LINE`.
        path: String,
        /// What is wrong.
        message: String,
    },
    /// A model that cannot be written out as TOML text (no line to name).
    #[error("{0}")]
    Invalid(String),
    /// A problem at a line of the TOML text.
    #[error("line {line}: {message}")]
    Line {
        /// Line number, 1-based.
        line: usize,
        /// What is wrong.
        message: String,
    },
}

/// The stage model: axis ranges and effects.
#[derive(Debug, Clone, PartialEq)]
pub struct StageModel {
    /// Travel range of x `[lo, hi]`, µm; an effect's `s` runs from -1 to 1 over it.
    pub travel_x_um: [f64; 2],
    /// Travel range of y `[lo, hi]`, µm.
    pub travel_y_um: [f64; 2],
    /// The effects, in file order.
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

impl StageModel {
    /// An ideal stage (no effects) over the given travel ranges, µm.
    pub fn new(travel_x_um: [f64; 2], travel_y_um: [f64; 2]) -> Self {
        Self {
            travel_x_um,
            travel_y_um,
            effects: Vec::new(),
        }
    }

    /// Travel range `[lo, hi]` of `axis`, µm.
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

    /// This model with `effect` added (builder form of `push`).
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

    /// Planar truth of an XY stage at (x, y), both axes having come to rest: each axis's own
    /// effects with that axis's approach direction (+1/-1), the global effects once. The line
    /// rule of [`deviation`](Self::deviation) (only the moving axis acts) measures one axis at a
    /// time; a point of a 2D map carries the errors of both axes at once.
    pub fn deviation_2d(
        &self,
        x_um: f64,
        y_um: f64,
        direction_x: f64,
        direction_y: f64,
        time_s: f64,
    ) -> Deviation {
        let ctx = |moving: AxisId, direction: f64| SampleContext {
            moving,
            direction,
            target_x_um: x_um,
            target_y_um: y_um,
            time_s,
        };
        let (cx, cy) = (ctx(AxisId::X, direction_x), ctx(AxisId::Y, direction_y));
        let mut total = Deviation::default();
        for e in &self.effects {
            let c = if e.kind.is_global() || e.axis == AxisId::X {
                &cx
            } else {
                &cy
            };
            let d = e.deviation(self, c);
            total.x_um += d.x_um;
            total.y_um += d.y_um;
        }
        total
    }

    /// Planar truth of the carriage's in-plane rotation θ(x, y), µrad (counterclockwise +): the
    /// yaw of both axes (see [`Effect::rotation_urad`]).
    pub fn rotation_urad_2d(&self, x_um: f64, y_um: f64) -> f64 {
        self.effects
            .iter()
            .map(|e| e.rotation_urad(self, x_um, y_um))
            .sum()
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
    fn planar_truth_adds_both_axes_each_with_its_own_direction() {
        let m = StageModel::from_toml_str(
            r#"
            [[effect]]
            kind = "backlash"
            axis = "x"
            reversal_um = 2.0
            [[effect]]
            kind = "scale"
            axis = "y"
            ppm = 100
            ref_um = 0
            [[effect]]
            kind = "squareness"
            axis = "y"
            angle_urad = 50
            [[effect]]
            kind = "camera_rotation"
            axis = "x"
            angle_urad = 10
            "#,
        )
        .unwrap();
        // x approached backward: -1 µm of backlash; y at 2000 µm: +0.2 µm of scale, and its
        // squareness puts 0.1 µm on x; the camera rotation acts once.
        let d = m.deviation_2d(1000.0, 2000.0, -1.0, 1.0, 0.0);
        let x = -1.0 + 50e-6 * 2000.0 - 10e-6 * 2000.0;
        let y = 100e-6 * 2000.0 + 10e-6 * 1000.0;
        assert!((d.x_um - x).abs() < 1e-12, "{} vs {x}", d.x_um);
        assert!((d.y_um - y).abs() < 1e-12, "{} vs {y}", d.y_um);
        let f = m.deviation_2d(1000.0, 2000.0, 1.0, 1.0, 0.0);
        assert!((f.x_um - d.x_um - 2.0).abs() < 1e-12);
    }

    #[test]
    fn the_rotation_is_the_one_whose_abbe_error_the_yaw_effects_give() {
        let m = StageModel::from_toml_str(
            r#"
            [[effect]]
            kind = "yaw_abbe"
            axis = "x"
            yaw_urad = [50, 10]
            [[effect]]
            kind = "yaw_abbe"
            axis = "y"
            yaw_urad = [20]
            "#,
        )
        .unwrap();
        // x at mid-travel (s = 0): ψx = 50; y's yaw turns the carriage the other way: −20.
        let th = m.rotation_urad_2d(4750.0, 1000.0) * 1e-6;
        assert!((th - 30e-6).abs() < 1e-15, "{th}");
        // A rotation by θ moves a point at offset (dx, dy) by (−θ·dy, θ·dx): the model's Abbe
        // deviations, each axis's yaw with its own sign.
        let (x, y) = (4750.0, 1000.0);
        let d = m.deviation_2d(x, y, 1.0, 1.0, 0.0);
        assert!((d.x_um - (-50e-6 * y)).abs() < 1e-12 && (d.y_um - (-20e-6 * x)).abs() < 1e-12);
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
