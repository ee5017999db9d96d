//! `[uncertainty]`: what the ISO 230-2 uncertainty budget needs beyond the data
//! ([`crate::iso_uncertainty`]). Every key is optional; the defaults are stated in the report.
use serde::{Deserialize, Serialize};

use crate::iso_uncertainty::{BudgetInputs, Thermal};

/// `[uncertainty]` as written.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct UncertaintySpec {
    /// Repeatability of one position reading (PPP decoding), standard uncertainty, µm.
    pub sensor_u_um: f64,
    /// Relative standard uncertainty of the pattern's pitch calibration, ppm.
    pub pitch_u_ppm: f64,
    /// Largest angle between the measuring direction and the motion (cosine error), mrad.
    pub misalignment_mrad: f64,
    /// The pattern's mean temperature during the test, °C, and its standard uncertainty: with
    /// `expansion_ppm_per_k`, the thermal contribution (none without a temperature).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub temperature_c: Option<f64>,
    pub temperature_u_c: f64,
    /// The pattern substrate's expansion coefficient and its standard uncertainty, ppm/K.
    pub expansion_ppm_per_k: f64,
    pub expansion_u_ppm_per_k: f64,
    /// Coverage factor of U.
    pub k: f64,
}

impl Default for UncertaintySpec {
    fn default() -> Self {
        let d = BudgetInputs::default();
        Self {
            sensor_u_um: d.sensor_u_um,
            pitch_u_ppm: d.pitch_u_ppm,
            misalignment_mrad: d.misalignment_mrad,
            temperature_c: None,
            temperature_u_c: 0.5,
            // Soda-lime glass, a common pattern substrate.
            expansion_ppm_per_k: 9.0,
            expansion_u_ppm_per_k: 1.0,
            k: d.k,
        }
    }
}

impl UncertaintySpec {
    /// The budget's inputs, or the first bad key (`uncertainty.<key>`) and why.
    pub fn inputs(&self) -> Result<BudgetInputs, (&'static str, String)> {
        let in_range = |v: f64, lo: f64, hi: f64| v.is_finite() && (lo..=hi).contains(&v);
        let checks: [(&'static str, f64, f64, f64, &str); 7] = [
            (
                "uncertainty.sensor_u_um",
                self.sensor_u_um,
                0.0,
                100.0,
                "µm",
            ),
            ("uncertainty.pitch_u_ppm", self.pitch_u_ppm, 0.0, 1e4, "ppm"),
            (
                "uncertainty.misalignment_mrad",
                self.misalignment_mrad,
                0.0,
                100.0,
                "mrad",
            ),
            (
                "uncertainty.temperature_u_c",
                self.temperature_u_c,
                0.0,
                50.0,
                "K",
            ),
            (
                "uncertainty.expansion_ppm_per_k",
                self.expansion_ppm_per_k,
                -100.0,
                100.0,
                "ppm/K",
            ),
            (
                "uncertainty.expansion_u_ppm_per_k",
                self.expansion_u_ppm_per_k,
                0.0,
                100.0,
                "ppm/K",
            ),
            ("uncertainty.k", self.k, 1.0, 5.0, ""),
        ];
        for (key, v, lo, hi, unit) in checks {
            if !in_range(v, lo, hi) {
                return Err((
                    key,
                    format!("must be in [{lo}, {hi}] {unit}")
                        .trim_end()
                        .to_string(),
                ));
            }
        }
        if let Some(t) = self.temperature_c {
            if !in_range(t, -50.0, 100.0) {
                return Err((
                    "uncertainty.temperature_c",
                    "must be in [-50, 100] °C".into(),
                ));
            }
        }
        Ok(BudgetInputs {
            sensor_u_um: self.sensor_u_um,
            pitch_u_ppm: self.pitch_u_ppm,
            misalignment_mrad: self.misalignment_mrad,
            thermal: self.temperature_c.map(|t| Thermal {
                temperature_c: t,
                temperature_u_c: self.temperature_u_c,
                expansion_ppm_per_k: self.expansion_ppm_per_k,
                expansion_u_ppm_per_k: self.expansion_u_ppm_per_k,
            }),
            k: self.k,
        })
    }
}
