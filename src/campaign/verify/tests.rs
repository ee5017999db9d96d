//! The verification's pure parts: targets, figures, priors.
use super::*;
use std::path::Path;

fn campaign() -> Campaign {
    let t = r#"
[campaign]
name = "v"
[hardware]
kind = "sim"
[axes.x]
range_um = [100.0, 1100.0]
step_um = 5.0
other_at_um = 100.0
m = 40
"#;
    Campaign::parse(t, "v.toml", Path::new(".")).unwrap()
}

#[test]
fn iso_targets_are_on_the_grid_and_the_others_never_are() {
    let c = campaign();
    let ax = &c.axes()[0];
    let (iso, un, ext) = targets(ax, &VerifyOptions::default());
    assert!(ext.is_empty());
    assert_eq!(iso.len(), 11);
    assert_eq!(iso[0], 100.0);
    assert_eq!(*iso.last().unwrap(), 1100.0);
    for p in &iso {
        assert!(ax.grid.index_of(*p).is_some());
    }
    // Uneven spacing: not all gaps equal.
    let gaps: Vec<f64> = iso.windows(2).map(|w| w[1] - w[0]).collect();
    assert!(gaps.iter().any(|g| (g - gaps[0]).abs() > 1.0));
    assert_eq!(un.len(), 10);
    for p in &un {
        let off = (p - 100.0).rem_euclid(5.0);
        assert!((1.0 - 1e-9..=4.0 + 1e-9).contains(&off), "{p}");
        assert!((100.0..=1100.0).contains(p));
    }
    let (p, _) = plan_of(&c, &VerifyOptions::default(), 0);
    // 5 cycles x 2 directions of 21 targets.
    assert_eq!(p.total(), 5 * 2 * 21);
}

/// A characterisation that measured [123, 1041] µm forward and [118, 1060] µm backward:
/// the figures' targets stay inside [123, 1041], the grid's ends are measured apart.
#[test]
fn targets_stay_inside_the_measured_span_and_the_ends_are_apart() {
    let c = campaign();
    let ax = &c.axes()[0];
    let sample = |p: f64, d: Direction| {
        let run = RunKey {
            phase: Phase::Cs,
            axis: AxisId::X,
            direction: d,
            cycle: 0,
        };
        SampleRecord::at(Target {
            seq: 0,
            run,
            grid_index: 0,
            target_x_um: p,
            target_y_um: 100.0,
        })
    };
    let f = Direction::Forward;
    let b = Direction::Backward;
    let s: Vec<SampleRecord> = [(123.0, f), (600.0, f), (1041.0, f), (118.0, b), (1060.0, b)]
        .into_iter()
        .map(|(p, d)| sample(p, d))
        .collect();
    let span = measured_span(&s, AxisId::X).unwrap();
    assert_eq!(span, (123.0, 1041.0));
    assert!(measured_span(&s, AxisId::Y).is_none());
    let opts = VerifyOptions {
        measured_span_um: [Some(span), None],
        ..VerifyOptions::default()
    };
    let (iso, un, ext) = targets(ax, &opts);
    assert_eq!(ext, vec![100.0, 1100.0]);
    // On the grid inside the span: 125 and 1040 the outermost.
    assert_eq!(iso[0], 125.0);
    assert_eq!(*iso.last().unwrap(), 1040.0);
    assert!(un.iter().all(|p| (125.0..1040.0).contains(p)), "{un:?}");
    assert_eq!(iso.len(), 11);
}

#[test]
fn prior_reads_the_driving_components_and_r() {
    let s = json!({"axes": [{"axis": "x", "grid_points": 1901, "components": [
        {"component": "ef_xx", "cs": {"cv_error_um": 0.05, "m": 100}},
        {"component": "eb_xx", "cs": {"cv_error_um": 0.07, "m": 100}},
        {"component": "ef_xy", "cs": {"cv_error_um": 0.9, "m": 300}}]}],
        "iso230": {"x": {"measured": {"r_um": 2.5, "r_up_um": 0.04, "r_down_um": 0.03}}}});
    let p = prior_from_summary(&s, AxisId::X);
    assert_eq!(p.cv_error_um, Some(0.07));
    assert_eq!(p.repeatability_um, Some(0.04));
    assert_eq!((p.m, p.grid_points), (Some(100), Some(1901)));
    let q = prior_from_summary(&s, AxisId::Y);
    assert!(q.cv_error_um.is_none() && q.repeatability_um.is_none());
}
