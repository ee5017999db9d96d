//! ISO 230-2 figures per moving axis, by [`crate::iso230::evaluate`].
//!
//! Up to three sources, reported separately; [`AxisIso230::source`] names the one the axis's
//! figures are (charts, `summary.txt`, `report.html`), in this order of preference:
//! - `full_scan`: the full scan's measurements, every grid point a target approached once per
//!   direction and cycle (R and the ±2s bands only with two cycles or more).
//! - `reconstructed`: the forward (`ef_xx`) and backward (`eb_xx`) reconstructions, every grid
//!   point a target with one approach per direction. There is no repeatability information (s =
//!   0), so R is not reported and A = E; B, B̄, E and M are those of the systematic curves at
//!   grid resolution.
//! - `measured`: the CS samples of those components, when repeated cycles exist — targets
//!   measured at least twice in every direction present. Other targets are left out.
//!
//! Without a full scan or repeated cycles the figures are those of the reconstruction, labelled
//! "estimated from the reconstruction".
use std::collections::BTreeMap;

use serde::Serialize;

use super::{ComponentCurve, ReportError};
use crate::iso230::{evaluate, Approach, Iso230Summary, TargetRow};
use crate::iso_uncertainty::{
    curve_row_u, iso_uncertainty, measured_row_u, BudgetInputs, IsoUncertainty,
};
use crate::types::{AxisId, Component, Direction};

/// ISO 230-2 figures of one moving axis.
#[derive(Debug, Clone, Serialize)]
pub struct AxisIso230 {
    /// `x` or `y`.
    pub axis: String,
    /// The driving-direction components used (`ef_xx`, `eb_xx`), when present.
    pub forward_component: Option<String>,
    pub backward_component: Option<String>,
    /// From the reconstructed curves at every grid point.
    pub reconstructed: Iso230Summary,
    /// From the measured samples, when repeated cycles exist.
    pub measured: Option<Iso230Summary>,
    /// From the full scan's measurements, when a full scan was made.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub full_scan: Option<Iso230Summary>,
    /// Which of the above the axis's figures are.
    pub source: IsoSource,
    /// The source as a reader sees it, e.g. "measured full scan, 1 cycle".
    pub source_label: String,
    /// What was left out and why, and departures from ISO 230-2's test conditions.
    pub notes: Vec<String>,
    /// Expanded uncertainty of the reported figures and its budget
    /// ([`crate::iso_uncertainty`]); absent for a reconstruction without a band.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub uncertainty: Option<IsoUncertainty>,
    /// Per-target figures of `source` (the chart's points).
    #[serde(skip)]
    pub chart_rows: Vec<TargetRow>,
}

/// Where an axis's ISO 230-2 figures come from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum IsoSource {
    FullScan,
    Measured,
    Reconstructed,
}

impl AxisIso230 {
    /// The figures of [`AxisIso230::source`].
    pub fn reported(&self) -> &Iso230Summary {
        match self.source {
            IsoSource::FullScan => self.full_scan.as_ref().unwrap_or(&self.reconstructed),
            IsoSource::Measured => self.measured.as_ref().unwrap_or(&self.reconstructed),
            IsoSource::Reconstructed => &self.reconstructed,
        }
    }
}

fn fig(v: Option<f64>) -> String {
    match v {
        Some(v) if v.is_finite() => format!("{v:.3} µm"),
        _ => "n/a".into(),
    }
}

/// The figures of each axis as `summary.txt` and `csmetro run` print them, one block per axis:
/// the source, then A, B, E, M, R (n/a where the data cannot give them).
pub fn iso_text(figures: &[AxisIso230]) -> String {
    let mut t = String::new();
    for f in figures {
        let r = f.reported();
        t.push_str(&format!(
            "ISO 230-2 {} axis ({}, {} targets): A {}  B {}  E {}  M {}  R {}\n",
            f.axis.to_uppercase(),
            f.source_label,
            r.targets,
            fig(Some(r.a_um)),
            fig(r.b_um),
            fig(Some(r.e_um)),
            fig(r.m_um),
            fig(r.r_um),
        ));
        if r.r_um.is_none() {
            t.push_str("  R n/a: one approach per target and direction (no repeated cycles)\n");
        }
        if let Some(u) = &f.uncertainty {
            let figs: Vec<String> = [
                ("A", Some(&u.a)),
                ("B", u.b.as_ref()),
                ("E", Some(&u.e)),
                ("M", u.m.as_ref()),
                ("R", u.r.as_ref()),
            ]
            .into_iter()
            .filter_map(|(n, b)| b.map(|b| format!("{n} = {}", b.display())))
            .collect();
            t.push_str(&format!("  with U: {}\n", figs.join(", ")));
        }
    }
    t
}

/// ISO 230-2 figures of moving axis `axis` from its driving-direction curves in `curves`
/// (coupling components are not positioning errors and are ignored). Targets closer than
/// `tol_um` are one target. `Ok(None)` without a driving component of that axis; an error when
/// a used curve is invalid or forward and backward curves are not on one grid.
pub fn iso230_axis(
    axis: AxisId,
    curves: &[ComponentCurve],
    tol_um: f64,
) -> Result<Option<AxisIso230>, ReportError> {
    iso230_axis_with(axis, curves, tol_um, &BudgetInputs::default())
}

/// [`iso230_axis`] with the uncertainty budget's inputs (sensor, pitch, temperature, alignment).
pub fn iso230_axis_with(
    axis: AxisId,
    curves: &[ComponentCurve],
    tol_um: f64,
    budget: &BudgetInputs,
) -> Result<Option<AxisIso230>, ReportError> {
    let find = |direction| {
        let comp = Component {
            moving: axis,
            direction,
            measured: axis,
        };
        curves.iter().find(|c| c.parsed() == Some(comp))
    };
    let fwd = find(Direction::Forward);
    let bwd = find(Direction::Backward);
    let used: Vec<(&ComponentCurve, bool)> = [(fwd, true), (bwd, false)]
        .into_iter()
        .filter_map(|(c, f)| c.map(|c| (c, f)))
        .collect();
    if used.is_empty() {
        return Ok(None);
    }
    for (c, _) in &used {
        c.validate()?;
    }
    if let (Some(f), Some(b)) = (fwd, bwd) {
        let same = f.grid_um.len() == b.grid_um.len()
            && f.grid_um
                .iter()
                .zip(&b.grid_um)
                .all(|(p, q)| (p - q).abs() <= tol_um.max(crate::grid::ON_GRID_TOL_UM));
        if !same {
            return Err(ReportError::InvalidCurve {
                component: b.component.clone(),
                reason: format!("grid differs from {}'s", f.component),
            });
        }
    }
    let mut notes = Vec::new();

    let recon: Vec<Approach> = used
        .iter()
        .flat_map(|&(c, forward)| {
            c.grid_um
                .iter()
                .zip(&c.reconstructed_um)
                .filter(|(p, e)| p.is_finite() && e.is_finite())
                .map(move |(&p, &e)| Approach {
                    target_um: p,
                    forward,
                    deviation_um: e,
                })
        })
        .collect();
    let Some(recon_iso) = evaluate(&recon, tol_um) else {
        return Err(ReportError::InvalidCurve {
            component: used[0].0.component.clone(),
            reason: "no finite reconstructed value".into(),
        });
    };
    let mut reconstructed = recon_iso;
    let recon_rows = std::mem::take(&mut reconstructed.rows);
    notes.push(
        "reconstructed: one approach per target and direction (s = 0): R not reported, A = E"
            .into(),
    );
    if used.len() == 1 {
        notes.push(format!(
            "only the {} direction was characterized: B, B̄ and M need both",
            if used[0].1 { "forward" } else { "backward" }
        ));
    }

    let measured = measured_figures(&used, tol_um, &mut notes);
    let mut full_scan = full_scan_figures(&used, tol_um, &mut notes);
    let (source, source_label, chart_rows) = if let Some(f) = &mut full_scan {
        let cycles = f.min_approaches;
        let label = format!(
            "measured full scan, {cycles} cycle{}",
            if cycles == 1 { "" } else { "s" }
        );
        (IsoSource::FullScan, label, std::mem::take(&mut f.rows))
    } else if let Some(m) = &measured {
        let label = format!(
            "repeated cycles, at least {} approaches per target and direction",
            m.min_approaches
        );
        (IsoSource::Measured, label, m.rows.clone())
    } else {
        (
            IsoSource::Reconstructed,
            "estimated from the reconstruction".to_string(),
            recon_rows,
        )
    };
    let row_u = match source {
        IsoSource::Reconstructed => {
            let band = |forward: bool| {
                let c = if forward { fwd } else { bwd }?;
                (c.u_um.len() == c.grid_um.len()).then_some(c)
            };
            let banded = used.iter().all(|&(_, f)| band(f).is_some());
            banded.then(|| {
                curve_row_u(&chart_rows, |forward, p| {
                    let c = band(forward)?;
                    let i = c
                        .grid_um
                        .iter()
                        .position(|&q| (q - p).abs() <= tol_um.max(crate::grid::ON_GRID_TOL_UM))?;
                    Some(c.u_um[i].hypot(local_misfit(c, p)))
                })
            })
        }
        _ => Some(measured_row_u(&chart_rows, budget.sensor_u_um)),
    };
    let mut fig = AxisIso230 {
        axis: axis.as_str().into(),
        forward_component: fwd.map(|c| c.component.clone()),
        backward_component: bwd.map(|c| c.component.clone()),
        reconstructed,
        measured,
        full_scan,
        source,
        source_label,
        notes,
        uncertainty: None,
        chart_rows,
    };
    match row_u {
        Some(ru) => {
            fig.uncertainty = Some(iso_uncertainty(
                fig.reported(),
                &fig.chart_rows,
                &ru,
                budget,
            ));
        }
        None => fig
            .notes
            .push("no pointwise band for the reconstruction: U not computed".into()),
    }
    Ok(Some(fig))
}

/// How far the curve misses the samples on either side of `p` (the larger of the two
/// residuals, µm; 0 without samples). The band is calibrated over the whole curve; at a peak a
/// smooth model rounds off, the samples there show the miss the band averages away, and a
/// range figure (E, M) is made of peaks.
fn local_misfit(c: &ComponentCurve, p: f64) -> f64 {
    let at = |x: f64| {
        let i = c
            .grid_um
            .partition_point(|&q| q < x)
            .min(c.grid_um.len() - 1);
        let j = i.saturating_sub(1);
        let nearest = if (c.grid_um[j] - x).abs() < (c.grid_um[i] - x).abs() {
            j
        } else {
            i
        };
        c.reconstructed_um[nearest]
    };
    let residual = |s: Option<&(f64, f64)>| s.map_or(0.0, |&(x, e)| (e - at(x)).abs());
    let left = c
        .samples
        .iter()
        .filter(|s| s.0 <= p && s.1.is_finite())
        .max_by(|a, b| a.0.total_cmp(&b.0));
    let right = c
        .samples
        .iter()
        .filter(|s| s.0 >= p && s.1.is_finite())
        .min_by(|a, b| a.0.total_cmp(&b.0));
    residual(left).max(residual(right))
}

/// Figures from the full scan's measurements of every direction present; `None` without a full
/// scan of each direction used. Every target counts (a scan visits each once per cycle).
fn full_scan_figures(
    used: &[(&ComponentCurve, bool)],
    tol_um: f64,
    notes: &mut Vec<String>,
) -> Option<Iso230Summary> {
    if used.iter().any(|(c, _)| c.full_scan_samples.is_empty()) {
        return None;
    }
    let all: Vec<Approach> = used
        .iter()
        .flat_map(|&(c, forward)| {
            c.full_scan_samples
                .iter()
                .filter(|(p, e)| p.is_finite() && e.is_finite())
                .map(move |&(p, e)| Approach {
                    target_um: p,
                    forward,
                    deviation_um: e,
                })
        })
        .collect();
    let fig = evaluate(&all, tol_um)?;
    if fig.min_approaches < 2 {
        notes.push(
            "full scan: one approach per target and direction (one cycle, s = 0): R not \
             reported, A = E"
                .into(),
        );
    } else if fig.min_approaches < 5 {
        notes.push(format!(
            "full scan: at least {} approaches per target and direction; ISO 230-2 asks for 5",
            fig.min_approaches
        ));
    }
    Some(fig)
}

/// Figures from the samples at targets approached at least twice in every direction present.
fn measured_figures(
    used: &[(&ComponentCurve, bool)],
    tol_um: f64,
    notes: &mut Vec<String>,
) -> Option<Iso230Summary> {
    let key = |p: f64| (p / tol_um.max(1e-12)).round() as i64;
    // target key -> (approaches forward, approaches backward)
    let mut counts: BTreeMap<i64, [usize; 2]> = BTreeMap::new();
    let mut all = Vec::new();
    for &(c, forward) in used {
        for &(p, e) in c
            .samples
            .iter()
            .filter(|(p, e)| p.is_finite() && e.is_finite())
        {
            counts.entry(key(p)).or_default()[usize::from(!forward)] += 1;
            all.push(Approach {
                target_um: p,
                forward,
                deviation_um: e,
            });
        }
    }
    let dirs: Vec<usize> = used.iter().map(|&(_, f)| usize::from(!f)).collect();
    let repeated = |k: &i64| {
        counts
            .get(k)
            .is_some_and(|n| dirs.iter().all(|&d| n[d] >= 2))
    };
    let kept: Vec<Approach> = all
        .into_iter()
        .filter(|a| repeated(&key(a.target_um)))
        .collect();
    let n_targets = counts.keys().filter(|k| repeated(k)).count();
    if n_targets < 2 {
        notes.push(format!(
            "measured: {n_targets} target(s) with repeated approaches in every direction \
             (at least 2 needed): no figures from the samples"
        ));
        return None;
    }
    let fig = evaluate(&kept, tol_um)?;
    if counts.len() > n_targets {
        notes.push(format!(
            "measured: {} of {} sampled targets left out (fewer than 2 approaches in a direction)",
            counts.len() - n_targets,
            counts.len()
        ));
    }
    if n_targets < 5 || fig.min_approaches < 5 {
        notes.push(format!(
            "measured: {n_targets} targets, at least {} approaches per direction; ISO 230-2 asks \
             for at least 5 targets and 5 approaches per direction",
            fig.min_approaches
        ));
    }
    Some(fig)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn line_curve(name: &str, f: impl Fn(f64) -> f64) -> ComponentCurve {
        let grid: Vec<f64> = (0..=100).map(|i| i as f64 * 10.0).collect();
        ComponentCurve {
            component: name.into(),
            reconstructed_um: grid.iter().map(|&x| f(x)).collect(),
            grid_um: grid,
            method: "physics".into(),
            cv_error_um: None,
            samples: Vec::new(),
            full_scan_um: None,
            full_scan_samples: Vec::new(),
            truth_um: None,
            u_um: Vec::new(),
        }
    }

    #[test]
    fn constant_backlash_and_trend_give_known_b_e_m() {
        // f(x) = x/1000 (0..1 µm); forward +1, backward -1: reversal 2 µm everywhere.
        let curves = [
            line_curve("ef_xx", |x| x / 1000.0 + 1.0),
            line_curve("eb_xx", |x| x / 1000.0 - 1.0),
            line_curve("ef_xy", |_| 50.0), // coupling: must not count
        ];
        let r = iso230_axis(AxisId::X, &curves, 1e-3).unwrap().unwrap();
        let s = &r.reconstructed;
        assert_eq!(s.targets, 101);
        assert!((s.b_um.unwrap() - 2.0).abs() < 1e-12);
        assert!((s.b_mean_um.unwrap() - 2.0).abs() < 1e-12);
        assert!((s.e_um - 3.0).abs() < 1e-12, "E from -1 to 2: {}", s.e_um);
        assert!((s.e_up_um.unwrap() - 1.0).abs() < 1e-12);
        assert!((s.m_um.unwrap() - 1.0).abs() < 1e-12);
        assert!((s.a_um - s.e_um).abs() < 1e-12);
        assert!(s.r_um.is_none() && s.r_up_um.is_none());
        assert!(r.measured.is_none());
        assert_eq!(r.forward_component.as_deref(), Some("ef_xx"));
        assert!(iso230_axis(AxisId::Y, &curves, 1e-3).unwrap().is_none());
    }

    #[test]
    fn position_dependent_hysteresis_gives_max_and_mean_reversal() {
        // b(x) = 1 + x/1000: B = max = 2 at x = 1000, B̄ = 1.5.
        let b = |x: f64| 1.0 + x / 1000.0;
        let curves = [
            line_curve("eb_yy", move |x| -b(x) / 2.0),
            line_curve("ef_yy", move |x| b(x) / 2.0),
        ];
        let s = iso230_axis(AxisId::Y, &curves, 1e-3)
            .unwrap()
            .unwrap()
            .reconstructed;
        assert!((s.b_um.unwrap() - 2.0).abs() < 1e-12);
        assert!((s.b_mean_um.unwrap() - 1.5).abs() < 1e-12);
        assert!(s.m_um.unwrap().abs() < 1e-12);
        assert!((s.e_um - 2.0).abs() < 1e-12); // from -1 to +1
    }

    #[test]
    fn repeated_cycles_give_measured_figures_with_repeatability() {
        // 6 targets, 3 cycles each direction, deviations ±1 µm backlash, scatter -0.1/0/+0.1
        // (s = 0.1); plus one target measured once, which must be left out.
        let mut f = line_curve("ef_xx", |_| 1.0);
        let mut b = line_curve("eb_xx", |_| -1.0);
        for t in 0..6 {
            let p = 100.0 + 150.0 * t as f64;
            for j in 0..3 {
                let noise = 0.1 * (j as f64 - 1.0);
                f.samples.push((p, 1.0 + noise));
                b.samples.push((p, -1.0 + noise));
            }
        }
        f.samples.push((55.0, 9.0));
        b.samples.push((55.0, -9.0));
        let r = iso230_axis(AxisId::X, &[f, b], 1e-3).unwrap().unwrap();
        let m = r.measured.as_ref().expect("measured figures");
        assert_eq!((m.targets, m.min_approaches), (6, 3));
        assert_eq!(m.rows.len(), 6);
        assert!((m.b_um.unwrap() - 2.0).abs() < 1e-12);
        assert!((m.r_up_um.unwrap() - 0.4).abs() < 1e-12);
        // R_i = 2s↑ + 2s↓ + |B_i| = 0.2 + 0.2 + 2.
        assert!((m.r_um.unwrap() - 2.4).abs() < 1e-12);
        // A = (1 + 0.2) - (-1 - 0.2); E = 2.
        assert!((m.a_um - 2.4).abs() < 1e-12);
        assert!((m.e_um - 2.0).abs() < 1e-12);
        assert!(r.notes.iter().any(|n| n.contains("1 of 7 sampled targets")));
        assert!(r.notes.iter().any(|n| n.contains("5 approaches")));
    }

    #[test]
    fn the_measured_full_scan_is_the_source_when_there_is_one() {
        // Reconstruction says reversal 2 µm; the full scan measured 3 µm (±1.5) at 4 targets.
        let mut f = line_curve("ef_xx", |_| 1.0);
        let mut b = line_curve("eb_xx", |_| -1.0);
        for p in [0.0, 10.0, 20.0, 30.0] {
            f.full_scan_samples.push((p, 1.5));
            b.full_scan_samples.push((p, -1.5));
        }
        let r = iso230_axis(AxisId::X, &[f.clone(), b.clone()], 1e-3)
            .unwrap()
            .unwrap();
        assert_eq!(r.source, IsoSource::FullScan);
        assert_eq!(r.source_label, "measured full scan, 1 cycle");
        assert!((r.reported().b_um.unwrap() - 3.0).abs() < 1e-12);
        assert!((r.reconstructed.b_um.unwrap() - 2.0).abs() < 1e-12);
        assert!(r.reported().r_um.is_none(), "one cycle: no repeatability");
        assert_eq!(r.chart_rows.len(), 4);
        let text = iso_text(std::slice::from_ref(&r));
        assert!(text.contains("ISO 230-2 X axis (measured full scan, 1 cycle, 4 targets)"));
        assert!(
            text.contains("B 3.000 µm") && text.contains("R n/a"),
            "{text}"
        );
        // A second cycle with 0.1 µm scatter: s = 0.0707 µm, R reported.
        for p in [0.0, 10.0, 20.0, 30.0] {
            f.full_scan_samples.push((p, 1.6));
            b.full_scan_samples.push((p, -1.4));
        }
        let r = iso230_axis(AxisId::X, &[f, b], 1e-3).unwrap().unwrap();
        assert_eq!(r.source_label, "measured full scan, 2 cycles");
        let s = 0.1 / 2f64.sqrt();
        assert!((r.reported().r_up_um.unwrap() - 4.0 * s).abs() < 1e-9);
        // Without any measured figures the reconstruction's are labelled as estimates.
        let r = iso230_axis(AxisId::X, &[line_curve("ef_xx", |_| 0.0)], 1e-3)
            .unwrap()
            .unwrap();
        assert_eq!(r.source, IsoSource::Reconstructed);
        assert!(iso_text(&[r]).contains("estimated from the reconstruction"));
    }

    #[test]
    fn single_cycle_samples_give_no_measured_figures() {
        let mut f = line_curve("ef_xx", |_| 0.0);
        f.samples = (0..50).map(|i| (i as f64 * 10.0, 0.1)).collect();
        let r = iso230_axis(AxisId::X, &[f], 1e-3).unwrap().unwrap();
        assert!(r.measured.is_none());
        assert!(r.reconstructed.b_um.is_none());
        assert!(r
            .notes
            .iter()
            .any(|n| n.contains("no figures from the samples")));
    }
}
