//! Expanded uncertainty U (k = 2 by default) of the ISO 230-2 figures A, B, E, M, R, in the
//! spirit of ISO 230-9 and the GUM: a budget of standard uncertainties combined in quadrature.
//!
//! The contributions (each a standard uncertainty, µm):
//! - `data`: the figure's own statistics. From measured cycles: each mean x̄ has u = s/√n, each s
//!   has u(s) = s/√(2(n − 1)) (one approach per target: the sensor's repeatability stands in for
//!   s, since the data cannot show it). From a reconstruction: each x̄ is a point of a curve and
//!   its u is the curve's pointwise band (`u_um`, which already holds the sensor noise's effect on
//!   the curve). A range (E, M, A) takes the u of its two extremes in quadrature; B the two
//!   directions' u at the target where |B_i| is largest; R that of the s (and B_i) defining it.
//! - `pitch`: the pattern's pitch calibration, a scale error δ: deviation error δ·(P − P₀),
//!   so a range over a travel L moves by up to δ·L (u = u(δ)·L). Cancels in B and R.
//! - `thermal` (only when a temperature is given): the pattern's expansion from 20 °C, not
//!   corrected by csmetro, a rectangular bound α·|ΔT|·L (u = α|ΔT|L/√3) with the uncertainties of
//!   ΔT and α: u² = (α|ΔT|L)²/3 + (α·u(T)·L)² + (ΔT·u(α)·L)². Cancels in B and R.
//! - `misalignment`: the cosine error of an angle up to θ between the measuring direction and the
//!   motion, L(1 − cos θ) ≈ Lθ²/2, one-sided rectangular: u = Lθ²/(2·2√3). Cancels in B and R.
//!
//! Not in the budget (say so where it matters): drift during the test (ISO 230-2's
//! environmental variation error needs a drift test), the choice among reconstruction models
//! (the band is that of the model `auto` kept), correlations between the extremes' u.
use serde::Serialize;

use crate::iso230::{Iso230Summary, TargetRow};

/// What the budget needs beyond the data: campaign `[uncertainty]` or report settings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BudgetInputs {
    /// Repeatability of one position reading (PPP decoding), standard uncertainty, µm.
    pub sensor_u_um: f64,
    /// Relative standard uncertainty of the pattern pitch (scale), parts per million.
    pub pitch_u_ppm: f64,
    /// Largest angle between the measuring direction and the motion, mrad.
    pub misalignment_mrad: f64,
    /// The pattern's temperature during the test and its expansion, when known.
    pub thermal: Option<Thermal>,
    /// Coverage factor of the expanded uncertainty U = k·u.
    pub k: f64,
}

impl Default for BudgetInputs {
    fn default() -> Self {
        Self {
            sensor_u_um: 0.01,
            pitch_u_ppm: 2.0,
            misalignment_mrad: 1.0,
            thermal: None,
            k: 2.0,
        }
    }
}

/// The pattern's temperature and expansion coefficient (both with standard uncertainties).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Thermal {
    pub temperature_c: f64,
    pub temperature_u_c: f64,
    pub expansion_ppm_per_k: f64,
    pub expansion_u_ppm_per_k: f64,
}

/// One line of a budget.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct Contribution {
    /// `data`, `pitch`, `thermal`, `misalignment`.
    pub source: String,
    /// Standard uncertainty (k = 1), µm.
    pub u_um: f64,
}

/// A figure with its combined and expanded uncertainty and the budget behind them.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct Budget {
    pub value_um: f64,
    /// Combined standard uncertainty, µm.
    pub u_um: f64,
    /// Expanded uncertainty U = k·u, µm.
    pub expanded_um: f64,
    pub k: f64,
    pub contributions: Vec<Contribution>,
}

impl Budget {
    fn new(value_um: f64, k: f64, contributions: Vec<Contribution>) -> Self {
        let u = contributions
            .iter()
            .map(|c| c.u_um * c.u_um)
            .sum::<f64>()
            .sqrt();
        Self {
            value_um,
            u_um: u,
            expanded_um: k * u,
            k,
            contributions,
        }
    }

    /// `9.450 ± 0.120 µm (k = 2)`.
    pub fn display(&self) -> String {
        format!(
            "{:.3} ± {:.3} µm (k = {})",
            self.value_um, self.expanded_um, self.k
        )
    }
}

/// U of each ISO 230-2 figure present in the summary (`None` where the figure is).
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct IsoUncertainty {
    /// Travel the systematic contributions act over (span of the targets), µm.
    pub length_um: f64,
    pub a: Budget,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub b: Option<Budget>,
    pub e: Budget,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub m: Option<Budget>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub r: Option<Budget>,
    /// What the budget assumed or left out.
    pub notes: Vec<String>,
}

/// Standard uncertainties of one target's statistics, µm (NaN where a direction is absent).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RowU {
    /// Of x̄↑ and x̄↓.
    pub mean_up: f64,
    pub mean_down: f64,
    /// Of s↑ and s↓ (0: s is not estimated, as for a reconstruction).
    pub s_up: f64,
    pub s_down: f64,
    /// The two directions' errors move together (two curves of one reconstruction round off
    /// the same peaks): their mean's u is then (u↑ + u↓)/2, not √(u↑² + u↓²)/2.
    pub correlated: bool,
}

/// The u of measured rows' statistics: s/√n and s/√(2(n − 1)); with one approach, the
/// sensor's repeatability for the mean and nothing for s (s = 0 is not reported as R).
pub fn measured_row_u(rows: &[TargetRow], sensor_u_um: f64) -> Vec<RowU> {
    let one = |n: usize, s: f64| -> (f64, f64) {
        match n {
            0 => (f64::NAN, f64::NAN),
            1 => (sensor_u_um, 0.0),
            n => {
                let nf = n as f64;
                // s from few approaches can be near 0 by chance: never below the sensor's u/√n.
                let s_eff = s.max(sensor_u_um);
                (s_eff / nf.sqrt(), s_eff / (2.0 * (nf - 1.0)).sqrt())
            }
        }
    };
    rows.iter()
        .map(|r| {
            let (mu, su) = one(r.n_up, r.s_up_um);
            let (md, sd) = one(r.n_down, r.s_down_um);
            RowU {
                mean_up: mu,
                mean_down: md,
                s_up: su,
                s_down: sd,
                correlated: false,
            }
        })
        .collect()
}

/// The u of reconstructed rows: the forward and backward curves' pointwise u at each target
/// (`u_at(forward, target_um)`), nothing for s.
pub fn curve_row_u(rows: &[TargetRow], u_at: impl Fn(bool, f64) -> Option<f64>) -> Vec<RowU> {
    rows.iter()
        .map(|r| RowU {
            mean_up: u_at(true, r.target_um).unwrap_or(f64::NAN),
            mean_down: u_at(false, r.target_um).unwrap_or(f64::NAN),
            s_up: 0.0,
            s_down: 0.0,
            correlated: true,
        })
        .collect()
}

/// The u of an extreme (the largest or smallest value) of a set of (value, u) candidates: the
/// largest u among the candidates that could be the true extreme, those whose ±2u reaches the
/// estimated one. Taking only the estimated extreme's own u ignores that the true extreme may
/// sit elsewhere (a peak the estimate rounds off, two near-equal maxima).
fn extreme_u(cands: &[(f64, f64)], largest: bool) -> f64 {
    let ok = |c: &&(f64, f64)| c.0.is_finite() && c.1.is_finite();
    let sign = if largest { 1.0 } else { -1.0 };
    let Some(top) = cands
        .iter()
        .filter(ok)
        .map(|c| sign * c.0)
        .max_by(f64::total_cmp)
    else {
        return 0.0;
    };
    cands
        .iter()
        .filter(ok)
        .filter(|c| sign * c.0 + 2.0 * c.1 >= top)
        .map(|c| c.1)
        .fold(0.0, f64::max)
}

fn hyp(a: f64, b: f64) -> f64 {
    (a * a + b * b).sqrt()
}

fn data(u: f64) -> Contribution {
    Contribution {
        source: "data".into(),
        u_um: u,
    }
}

/// The budget of every figure of `summary` from its per-target rows and their u (`row_u`, one
/// per row, same order).
pub fn iso_uncertainty(
    summary: &Iso230Summary,
    rows: &[TargetRow],
    row_u: &[RowU],
    inputs: &BudgetInputs,
) -> IsoUncertainty {
    let k = inputs.k;
    let targets = rows.iter().map(|r| r.target_um);
    let lo = targets.clone().fold(f64::INFINITY, f64::min);
    let hi = targets.fold(f64::NEG_INFINITY, f64::max);
    let length = if hi > lo { hi - lo } else { 0.0 };
    let mut notes = Vec::new();

    // Scale-like contributions of a range over the travel.
    let mut scale = vec![Contribution {
        source: "pitch".into(),
        u_um: inputs.pitch_u_ppm * 1e-6 * length,
    }];
    if let Some(t) = inputs.thermal {
        let dt = t.temperature_c - 20.0;
        let (a, ua) = (t.expansion_ppm_per_k * 1e-6, t.expansion_u_ppm_per_k * 1e-6);
        let u = ((a * dt.abs() * length).powi(2) / 3.0
            + (a * t.temperature_u_c * length).powi(2)
            + (dt * ua * length).powi(2))
        .sqrt();
        scale.push(Contribution {
            source: "thermal".into(),
            u_um: u,
        });
        if dt.abs() > 0.0 {
            notes.push(format!(
                "the pattern's expansion at {:.2} °C (ΔT = {dt:+.2} K, {:.2} ppm/K) is not \
                 corrected: within the thermal contribution",
                t.temperature_c, t.expansion_ppm_per_k
            ));
        }
    } else {
        notes.push("no temperature given: thermal expansion is not in the budget".into());
    }
    let theta = inputs.misalignment_mrad * 1e-3;
    scale.push(Contribution {
        source: "misalignment".into(),
        u_um: length * theta * theta / 2.0 / (2.0 * 3f64.sqrt()),
    });
    notes.push(
        "drift during the test (ISO 230-2's environmental variation error) is not in the budget"
            .into(),
    );
    let with_scale = |u_data: f64| {
        let mut c = vec![data(u_data)];
        c.extend(scale.iter().cloned());
        c
    };

    let has = |n: usize| n > 0;
    let mut means = Vec::new(); // (x̄, u) both directions
    let mut plus = Vec::new(); // (x̄ + 2s, u)
    let mut minus = Vec::new(); // (x̄ − 2s, u)
    for (r, u) in rows.iter().zip(row_u) {
        for (n, m, s, um, us) in [
            (r.n_up, r.mean_up_um, r.s_up_um, u.mean_up, u.s_up),
            (r.n_down, r.mean_down_um, r.s_down_um, u.mean_down, u.s_down),
        ] {
            if has(n) {
                means.push((m, um));
                let uu = hyp(um, 2.0 * us);
                plus.push((m + 2.0 * s, uu));
                minus.push((m - 2.0 * s, uu));
            }
        }
    }
    let e = Budget::new(
        summary.e_um,
        k,
        with_scale(hyp(extreme_u(&means, true), extreme_u(&means, false))),
    );
    let a = Budget::new(
        summary.a_um,
        k,
        with_scale(hyp(extreme_u(&plus, true), extreme_u(&minus, false))),
    );
    let b = summary.b_um.map(|b| {
        let cands: Vec<(f64, f64)> = rows
            .iter()
            .zip(row_u)
            .map(|(r, u)| (r.reversal_um.abs(), hyp(u.mean_up, u.mean_down)))
            .collect();
        Budget::new(b, k, vec![data(extreme_u(&cands, true))])
    });
    let m = summary.m_um.map(|m| {
        let bidir: Vec<(f64, f64)> = rows
            .iter()
            .zip(row_u)
            .map(|(r, u)| {
                let u_mean = if u.correlated {
                    (u.mean_up + u.mean_down) / 2.0
                } else {
                    hyp(u.mean_up, u.mean_down) / 2.0
                };
                (r.mean_bidir_um, u_mean)
            })
            .collect();
        Budget::new(
            m,
            k,
            with_scale(hyp(extreme_u(&bidir, true), extreme_u(&bidir, false))),
        )
    });
    let r = summary.r_um.map(|r| {
        let both = summary.b_um.is_some();
        // The u of the row's R as ISO 230-2 forms it: 4s, or 2s↑ + 2s↓ + |B_i|.
        let cands: Vec<(f64, f64)> = rows
            .iter()
            .zip(row_u)
            .flat_map(|(row, u)| {
                let bidir = (
                    row.r_bidir_um,
                    if row.r_bidir_um > row.r_up_um.max(row.r_down_um) {
                        hyp(
                            hyp(2.0 * u.s_up, 2.0 * u.s_down),
                            hyp(u.mean_up, u.mean_down),
                        )
                    } else if row.r_up_um >= row.r_down_um {
                        4.0 * u.s_up
                    } else {
                        4.0 * u.s_down
                    },
                );
                let uni = [(row.r_up_um, 4.0 * u.s_up), (row.r_down_um, 4.0 * u.s_down)];
                if both {
                    vec![bidir]
                } else {
                    uni.into_iter().filter(|(v, _)| v.is_finite()).collect()
                }
            })
            .collect();
        Budget::new(r, k, vec![data(extreme_u(&cands, true))])
    });
    IsoUncertainty {
        length_um: length,
        a,
        b,
        e,
        m,
        r,
        notes,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::iso230::evaluate;
    use crate::iso230::tests::ap;

    /// The budget of a small test worked by hand (published here so a reader can check it).
    ///
    /// Targets 0 and 1000 µm, three approaches per direction:
    /// - 0 µm ↑ {1.0, 1.2, 1.4}: x̄ = 1.2, s = 0.2;  ↓ {0.0, 0.0, 0.0}: x̄ = 0.0, s = 0 (→ sensor 0.01)
    /// - 1000 µm ↑ {3.0, 3.0, 3.0}: x̄ = 3.0, s = 0 (→ 0.01); ↓ {2.0, 2.1, 2.2}: x̄ = 2.1, s = 0.1
    ///
    /// E = 3.0 − 0.0 = 3.0. Data: u(x̄ = 3.0) = 0.01/√3, u(x̄ = 0.0) = 0.01/√3, so
    /// u_data = 0.01·√(2/3) = 0.008165. Pitch 2 ppm over L = 1000 µm: 0.002. Misalignment 1 mrad:
    /// 1000·1e-6/2/(2√3) = 1.4434e-4. Thermal 23 °C ± 0.5, 8 ± 1 ppm/K: (8e-6·3·1000)²/3 +
    /// (8e-6·0.5·1000)² + (3·1e-6·1000)² = 1.92e-4 + 1.6e-5 + 9e-6 → 0.014731.
    /// u(E) = √(0.008165² + 0.002² + 1.4434e-4² + 0.014731²) = 0.016963, U = 0.033926.
    /// B = max(|1.2 − 0|, |3.0 − 2.1|) = 1.2 at 0 µm: u = √((0.2/√3)² + (0.01/√3)²) = 0.115614,
    /// U = 0.231228 (no scale terms).
    #[test]
    fn budget_matches_a_hand_computation() {
        let data = [
            ap(0.0, true, 1.0),
            ap(0.0, true, 1.2),
            ap(0.0, true, 1.4),
            ap(0.0, false, 0.0),
            ap(0.0, false, 0.0),
            ap(0.0, false, 0.0),
            ap(1000.0, true, 3.0),
            ap(1000.0, true, 3.0),
            ap(1000.0, true, 3.0),
            ap(1000.0, false, 2.0),
            ap(1000.0, false, 2.1),
            ap(1000.0, false, 2.2),
        ];
        let s = evaluate(&data, 1e-3).unwrap();
        let inputs = BudgetInputs {
            thermal: Some(Thermal {
                temperature_c: 23.0,
                temperature_u_c: 0.5,
                expansion_ppm_per_k: 8.0,
                expansion_u_ppm_per_k: 1.0,
            }),
            ..BudgetInputs::default()
        };
        let u = iso_uncertainty(&s, &s.rows, &measured_row_u(&s.rows, 0.01), &inputs);
        assert!((u.e.value_um - 3.0).abs() < 1e-12);
        assert!((u.e.u_um - 0.016963).abs() < 2e-6, "{:?}", u.e);
        assert!((u.e.expanded_um - 0.033926).abs() < 4e-6, "{:?}", u.e);
        let b = u.b.as_ref().unwrap();
        assert!((b.value_um - 1.2).abs() < 1e-12);
        assert!((b.expanded_um - 0.231228).abs() < 2e-6, "{b:?}");
        assert_eq!(u.e.display(), "3.000 ± 0.034 µm (k = 2)");
        // Every figure present has a budget; R from three approaches per direction.
        assert!(u.m.is_some() && u.r.is_some());
        let thermal = u.e.contributions.iter().find(|c| c.source == "thermal");
        assert!((thermal.unwrap().u_um - 0.014731).abs() < 2e-6);
    }

    #[test]
    fn without_temperature_the_budget_says_so_and_has_no_thermal_line() {
        let data = [ap(0.0, true, 0.0), ap(500.0, true, 1.0)];
        let s = evaluate(&data, 1e-3).unwrap();
        let u = iso_uncertainty(
            &s,
            &s.rows,
            &measured_row_u(&s.rows, 0.01),
            &BudgetInputs::default(),
        );
        assert!(u.e.contributions.iter().all(|c| c.source != "thermal"));
        assert!(u.notes.iter().any(|n| n.contains("no temperature")));
        // One approach: u of each mean is the sensor's; no B, M (one direction), no R.
        assert!(u.b.is_none() && u.m.is_none() && u.r.is_none());
        let d = u.e.contributions[0].u_um;
        assert!((d - 0.01 * 2f64.sqrt()).abs() < 1e-12, "{d}");
    }

    #[test]
    fn curve_u_is_taken_at_the_extremes() {
        let data = [ap(0.0, true, 0.0), ap(10.0, true, 5.0), ap(20.0, true, 2.0)];
        let s = evaluate(&data, 1e-3).unwrap();
        let ru = curve_row_u(&s.rows, |_, p| Some(0.1 + p / 100.0));
        let inputs = BudgetInputs {
            pitch_u_ppm: 0.0,
            misalignment_mrad: 0.0,
            ..BudgetInputs::default()
        };
        let u = iso_uncertainty(&s, &s.rows, &ru, &inputs);
        // max at 10 µm (u 0.2), min at 0 µm (u 0.1).
        assert!((u.e.u_um - hyp(0.2, 0.1)).abs() < 1e-12, "{:?}", u.e);
    }
}
