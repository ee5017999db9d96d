//! Sim-to-real gap diagnosis: where measured line data leave the stage model, which effect of the
//! candidate library explains the difference, and how far the held-out gap shrinks once it is
//! added. A sample is predicted as its target plus the deviations of the effects acting on it
//! (those of its moving axis, and the camera and thermal effects) plus a constant offset per line:
//! one run, one moving axis, one static position, both directions (the static axis' own error and
//! the sensor's zero are not known).
//!
//! Pipeline: residual = measured - baseline prediction; every line (run, moving axis, static
//! position) × component gets its own constant offset (nuisance), removed exactly by demeaning the
//! residual and every design column within the line (Frisch–Waugh). Candidate effect groups are
//! linear in their parameters once their structure is fixed (period, travel, offset, τ), so each
//! group's columns are `effect_deviation` of unit-parameter effects. Groups are added greedily,
//! scored by the held-out RMS of leave-one-run-out cross-validation (held-out line offsets refit
//! on the held-out line). A group is accepted when the nested model comparison (F test against
//! the larger model's residual) is significant, the held-out runs improve, held-out parts of
//! the travel improve too, and it explains a fair share of the structure left beyond the
//! within-run noise (a partial fit of something outside the library does not). Repeatability
//! (pure error over repeated runs, or what a drift in time leaves of it) gives σ; lack of fit and
//! time structure against σ say whether something remains unexplained and where. A component
//! left unmeasured (NaN) on a sample gives no row at all.
mod candidates;
pub mod data;
mod design;
pub mod drift;
mod findings;
mod localise;
mod period;
mod report;
pub mod saturated;
mod search;
pub mod selftest;
mod stats;

use csmetro_effects::{AxisId, StageModel};

pub use data::Sample;
use design::Rows;
pub use localise::chi2_z;
pub use report::{Added, Diagnosis, OtherAxis, Peak, Tie, Unexplained, Where};
pub use search::diagnose;

/// Knobs of the diagnosis (defaults are what the selftest calibrates).
#[derive(Debug, Clone)]
pub struct Options {
    /// Candidate kinds (None = the whole library).
    pub kinds: Option<Vec<String>>,
    /// Motor/encoder period when the model has no `motor_cyclic` of that axis, µm.
    pub motor_period_um: f64,
    /// Leadscrew harmonics fitted (at least those of the model's own effect).
    pub leadscrew_harmonics: usize,
    /// τ grid for `thermal_drift`, s.
    pub tau_grid_s: Vec<f64>,
    /// Paired t over held-out lines needed to accept a group (no longer a gate: reported only).
    pub t_accept: f64,
    /// z of the nested-model F test a group needs.
    pub z_accept: f64,
    /// Share of its held-out-run gain a group must keep on held-out parts of the travel.
    pub block_share: f64,
    /// Share of the remaining structure (in-sample, beyond repeatability) a group must explain.
    pub min_share: f64,
    /// Paired t over (line, position block) units the position cross-validation must also show.
    pub t_block: f64,
    /// Paired t under which two candidates are a tie (not told apart by held-out data).
    pub t_tie: f64,
    /// Relative residual under which a candidate (or pair) reproduces the pick: a confound.
    pub span_tie: f64,
    pub max_steps: usize,
    /// Position bins per travel for `where`.
    pub bins: usize,
    /// Time bins over the campaign.
    pub time_bins: usize,
    /// z (Wilson–Hilferty on χ² against σ) for a significant bin.
    pub z_where: f64,
    /// z for significant unexplained structure (lack of fit or time structure).
    pub z_unexplained: f64,
    /// ISO 230-2 decomposition (saturated model, pure-error tests, leave-one-cycle-out) for
    /// data that are ISO 230-2 tables (the CLI sets it for an ISO 230-2 export): each cycle's
    /// zero is then a finding (drift), not a per-line nuisance as in line campaigns.
    pub iso230: bool,
    /// Whether `time_s` came from the data (false: row order, so no rates per hour).
    pub time_from_column: bool,
}

impl Default for Options {
    fn default() -> Self {
        Self {
            kinds: None,
            motor_period_um: 400.0 / 28.4,
            leadscrew_harmonics: 3,
            tau_grid_s: vec![300.0, 600.0, 1200.0, 2400.0, 4800.0, 9600.0],
            t_accept: 3.0,
            z_accept: 5.0,
            block_share: 0.5,
            min_share: 0.5,
            t_block: 2.0,
            t_tie: 2.0,
            span_tie: 0.1,
            max_steps: 6,
            bins: 24,
            time_bins: 60,
            z_where: 3.7,
            z_unexplained: 3.5,
            iso230: false,
            time_from_column: true,
        }
    }
}

/// Input problems of the diagnosis (exit code 2 at the CLI).
#[derive(Debug)]
pub struct GapError(pub String);

impl std::fmt::Display for GapError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

/// RMS of data - model with every line's constant offsets refit (the contract's nuisance), over
/// the same degrees of freedom as the held-out RMS: how far a model is from a campaign it was not
/// fitted on.
pub fn residual_rms_um(model: &StageModel, samples: &[Sample]) -> f64 {
    let rows = Rows::build(samples, model);
    let ss: f64 = rows.y.iter().map(|v| v * v).sum();
    (ss / rows.n.saturating_sub(rows.n_lc_used).max(1) as f64).sqrt()
}

/// ISO 230-2 figures of every measured line group (moving axis, static position) from the
/// deviations of the moving axis' component (measured - target), µm. Groups whose moving
/// component is never measured are left out.
pub fn iso230_figures(samples: &[Sample]) -> Vec<(AxisId, f64, crate::iso230::Iso230Summary)> {
    use std::collections::BTreeMap;
    let mut groups: BTreeMap<(AxisId, i64), (f64, Vec<crate::iso230::Approach>)> = BTreeMap::new();
    for s in samples {
        let a = s.moving;
        let dev = s.meas(a) - s.target(a);
        if !dev.is_finite() {
            continue;
        }
        let st = s.target(a.other());
        groups
            .entry((a, design::key_um(st)))
            .or_insert((st, Vec::new()))
            .1
            .push(crate::iso230::Approach {
                target_um: s.target(a),
                forward: s.direction > 0.0,
                deviation_um: dev,
            });
    }
    groups
        .into_iter()
        .filter_map(|((a, _), (st, ap))| {
            crate::iso230::evaluate(&ap, 0.01).map(|mut f| {
                f.rows.clear();
                (a, st, f)
            })
        })
        .collect()
}

/// One text line of ISO 230-2 figures, µm.
pub fn describe_iso230(axis: AxisId, static_um: f64, f: &crate::iso230::Iso230Summary) -> String {
    let o = |v: Option<f64>| v.map_or("-".to_string(), |v| format!("{v:.3}"));
    format!(
        "ISO 230-2, {axis} axis at {} = {static_um:.0} µm ({} targets, ≥ {} approaches): A {:.3} (↑ {}, ↓ {}), B {} (B̄ {}), E {:.3} (↑ {}, ↓ {}), M {}, R {} (↑ {}, ↓ {}) µm",
        axis.other(),
        f.targets,
        f.min_approaches,
        f.a_um,
        o(f.a_up_um),
        o(f.a_down_um),
        o(f.b_um),
        o(f.b_mean_um),
        f.e_um,
        o(f.e_up_um),
        o(f.e_down_um),
        o(f.m_um),
        o(f.r_um),
        o(f.r_up_um),
        o(f.r_down_um),
    )
}

#[cfg(test)]
mod tests {
    use super::data::{simulate_campaign, CampaignSpec};
    use super::*;
    use csmetro_effects::{AxisId, Component, Effect, EffectKind};

    fn base() -> StageModel {
        StageModel::default()
            .with(Effect::new(
                AxisId::X,
                EffectKind::LeadscrewCyclic {
                    period_um: 400.0,
                    cos_um: vec![0.4],
                    sin_um: vec![0.2],
                },
            ))
            .with(Effect::new(
                AxisId::X,
                EffectKind::Backlash { reversal_um: 1.5 },
            ))
    }

    fn spec(seed: u64) -> CampaignSpec {
        CampaignSpec {
            runs: 4,
            targets_per_line: 30,
            noise_um: Some(0.05),
            seed,
            ..Default::default()
        }
    }

    #[test]
    fn withheld_backlash_is_found_with_its_reversal_and_the_model_merges_it() {
        // The real stage's y backlash is 1.6 µm; the simulator's model says 1.0 µm.
        let mut diagnosed = base();
        diagnosed.push(Effect::new(
            AxisId::Y,
            EffectKind::Backlash { reversal_um: 1.0 },
        ));
        let truth_total = {
            let mut t = base();
            t.push(Effect::new(
                AxisId::Y,
                EffectKind::Backlash { reversal_um: 1.6 },
            ));
            t
        };
        let data = simulate_campaign(&truth_total, &spec(11), None);
        let d = diagnose(&diagnosed, &data, &Options::default()).unwrap();
        assert_eq!(d.added.len(), 1, "{}", d.summary());
        let a = &d.added[0];
        assert_eq!((a.kind.as_str(), a.axis.as_str()), ("backlash", "y"));
        let EffectKind::Backlash { reversal_um } = a.effect.kind else {
            panic!("not a backlash")
        };
        assert!((reversal_um - 0.6).abs() < 0.02, "reversal {reversal_um}");
        // Merged into the model's own backlash of y: 1.0 + 0.6.
        let merged: Vec<f64> = d
            .model
            .effects
            .iter()
            .filter_map(|e| match e.kind {
                EffectKind::Backlash { reversal_um } if e.axis == AxisId::Y => Some(reversal_um),
                _ => None,
            })
            .collect();
        assert_eq!(merged.len(), 1);
        assert!((merged[0] - 1.6).abs() < 0.02, "{merged:?}");
        assert!(d.heldout_rms_after_um < 0.6 * d.heldout_rms_before_um);
        assert!(
            (d.heldout_rms_after_um - 0.05).abs() < 0.01,
            "{}",
            d.heldout_rms_after_um
        );
        assert!((d.sigma_um - 0.05).abs() < 0.005, "σ {}", d.sigma_um);
        assert!(a.gap_closed.unwrap() > 0.9);
        assert!(!d.unexplained.significant);
        // Where: the y lines, y component, both directions.
        assert!(d
            .where_
            .iter()
            .take(2)
            .all(|w| w.axis == Some(AxisId::Y) && w.component == Some(AxisId::Y)));
    }

    #[test]
    fn no_gap_adds_nothing_even_with_large_line_offsets() {
        for seed in 0..4 {
            let data = simulate_campaign(
                &base(),
                &CampaignSpec {
                    line_offset_um: 50.0,
                    ..spec(100 + seed)
                },
                None,
            );
            let d = diagnose(&base(), &data, &Options::default()).unwrap();
            assert!(d.added.is_empty(), "seed {seed}: {}", d.summary());
            assert!(!d.unexplained.significant, "seed {seed}: {}", d.summary());
            assert!(d.where_.is_empty(), "seed {seed}: {:?}", d.where_);
            assert!(d.frequency.is_empty(), "seed {seed}: {:?}", d.frequency);
            assert!((d.heldout_rms_before_um / 0.05 - 1.0).abs() < 0.1);
        }
    }

    #[test]
    fn camera_scale_is_a_tie_with_the_two_axis_scales() {
        let truth = base().with(Effect::new(
            AxisId::X,
            EffectKind::CameraScale { ppm: 30.0 },
        ));
        let d = diagnose(
            &base(),
            &simulate_campaign(&truth, &spec(5), None),
            &Options::default(),
        )
        .unwrap();
        let a = &d.added[0];
        assert_eq!(a.kind, "camera_scale", "{}", d.summary());
        assert!(
            a.ties.iter().any(|t| t.label() == "scale x + scale y"),
            "{}",
            d.summary()
        );
        let EffectKind::CameraScale { ppm } = a.effect.kind else {
            panic!()
        };
        assert!((ppm - 30.0).abs() < 1.0, "{ppm}");
    }

    #[test]
    fn a_local_defect_is_unexplained_and_located_not_misattributed() {
        let truth = base().with(Effect::new(
            AxisId::X,
            EffectKind::Defect {
                component: Component::Axis,
                center_um: 6000.0,
                height_um: 0.4,
                sigma_um: 120.0,
            },
        ));
        let d = diagnose(
            &base(),
            &simulate_campaign(&truth, &spec(8), None),
            &Options::default(),
        )
        .unwrap();
        assert!(d.added.is_empty(), "{}", d.summary());
        assert!(d.unexplained.significant);
        let w = &d.unexplained.where_[0];
        assert_eq!((w.axis, w.component), (Some(AxisId::X), Some(AxisId::X)));
        // Located to within one position bin (9500/24 µm) of the defect's centre.
        let bin = 9500.0 / 24.0;
        assert!(
            w.from - bin <= 6000.0 && 6000.0 <= w.to + bin,
            "{:#?}",
            d.unexplained.where_
        );
        assert!(w.to - w.from < 2000.0, "{w:?}");
    }

    #[test]
    fn restricted_kinds_leave_position_dependent_backlash_unexplained() {
        let truth = base().with(Effect::new(
            AxisId::Y,
            EffectKind::Hysteresis {
                b0_um: 0.5,
                b1_um: 0.5,
            },
        ));
        let data = simulate_campaign(&truth, &spec(9), None);
        let all = diagnose(&base(), &data, &Options::default()).unwrap();
        assert_eq!(all.added[0].kind, "hysteresis", "{}", all.summary());
        assert!(!all.unexplained.significant, "{}", all.summary());
        let only_backlash = Options {
            kinds: Some(vec!["backlash".into()]),
            ..Default::default()
        };
        let d = diagnose(&base(), &data, &only_backlash).unwrap();
        assert_eq!(d.added.len(), 1);
        assert_eq!(
            (d.added[0].kind.as_str(), d.added[0].axis.as_str()),
            ("backlash", "y")
        );
        assert!(d.unexplained.significant, "{}", d.summary());
        assert!(d.unexplained.rms_um > 0.05);
    }

    #[test]
    fn a_periodic_error_of_unknown_period_is_unexplained_with_its_period() {
        let truth = base().with(Effect::new(
            AxisId::Y,
            EffectKind::Harmonic {
                component: Component::Axis,
                period_um: 700.0,
                cos_um: vec![0.12],
                sin_um: vec![0.05],
            },
        ));
        let d = diagnose(
            &base(),
            &simulate_campaign(&truth, &spec(12), None),
            &Options::default(),
        )
        .unwrap();
        assert!(d.added.is_empty(), "{}", d.summary());
        assert!(d.unexplained.significant);
        let p = &d.unexplained.frequency[0];
        assert_eq!((p.axis, p.component), (AxisId::Y, AxisId::Y));
        assert!((p.period_um - 700.0).abs() < 5.0, "{p:?}");
        assert!((p.amplitude_um - 0.13).abs() < 0.02, "{p:?}");
    }

    #[test]
    fn bad_inputs_are_refused() {
        let one_run = simulate_campaign(&base(), &CampaignSpec { runs: 1, ..spec(1) }, None);
        let e = diagnose(&base(), &one_run, &Options::default()).unwrap_err();
        assert!(e.0.contains("single run"), "{e}");
        let two = simulate_campaign(&base(), &spec(1), None);
        let o = Options {
            kinds: Some(vec!["warp".into()]),
            ..Default::default()
        };
        let e = diagnose(&base(), &two, &o).unwrap_err();
        assert!(e.0.contains("unknown candidate kind `warp`"), "{e}");
    }
}
