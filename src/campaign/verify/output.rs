//! What a verification writes: the before/after table, its JSON, the samples, the charts (SVG and
//! PNG with the pass line), verify/report.html and the files list.
#[allow(clippy::wildcard_imports)]
use super::*;
use crate::report::DrawError;

fn opt(v: Option<f64>) -> String {
    v.map_or("-".into(), |v| format!("{v:.3}"))
}

/// What an axis's expected residual is made of, in words.
fn basis(a: &AxisVerdict) -> String {
    match a.expected_from {
        "band" => format!(
            "expected 3 u + unidirectional R {} at each target, tightest at {} µm: {:.3} µm (mean u {})",
            opt(a.repeatability_um),
            opt(a.worst_target_um),
            a.expected_um,
            opt(a.u_mean_um)
        ),
        "given" => format!("expected {:.3} µm (given)", a.expected_um),
        _ => format!(
            "expected {:.3} µm (3 x CV error {} + unidirectional R {})",
            a.expected_um,
            opt(a.cv_error_um),
            opt(a.repeatability_um)
        ),
    }
}

/// The side-by-side table (`summary.txt` of the verification).
pub fn table(v: &Verdict) -> String {
    let mut s = format!(
        "verification of campaign {} on stage {} (compensation: {})\n",
        v.campaign, v.stage, v.compensation
    );
    s.push_str(&format!(
        "{:<5} {:<7} {:>8} {:>8} {:>8} {:>8} {:>8} {:>10} {:>10}\n",
        "axis", "", "A µm", "B µm", "E µm", "M µm", "R µm", "mean|e| µm", "max|e| µm"
    ));
    for a in &v.axes {
        for (name, f, mean, max) in [
            (
                "before",
                &a.before,
                a.mean_abs_before_um,
                a.max_abs_before_um,
            ),
            ("after", &a.after, a.mean_abs_after_um, a.max_abs_after_um),
        ] {
            s.push_str(&format!(
                "{:<5} {:<7} {:>8.3} {:>8} {:>8.3} {:>8} {:>8} {:>10.3} {:>10.3}\n",
                a.axis.to_uppercase(),
                name,
                f.a_um,
                opt(f.b_um),
                f.e_um,
                opt(f.m_um),
                opt(f.r_um),
                mean,
                max
            ));
        }
        let basis = basis(a);
        s.push_str(&format!(
            "{:<5} E reduced {:.1}x; max |after| {:.3} µm ({:.3} µm at never-visited targets) vs {}: {}\n",
            a.axis.to_uppercase(),
            a.e_reduction,
            a.max_abs_after_um,
            a.max_abs_after_unvisited_um,
            basis,
            if a.passed { "passed" } else { "FAILED" }
        ));
        let m = match (a.characterisation_m, a.grid_points) {
            (Some(m), Some(n)) if n > 0 => format!(
                "characterised with m = {m} of {n} grid points per run ({:.1} %); ",
                100.0 * m as f64 / n as f64
            ),
            _ => String::new(),
        };
        if let Some(cv) = a.cv_error_um.filter(|v| *v > 0.0) {
            s.push_str(&format!(
                "{:<5} {m}rms of the mean residual {:.3} µm vs its CV error estimate {cv:.3} µm ({:+.0} %)\n",
                a.axis.to_uppercase(),
                a.rms_after_um,
                100.0 * (a.rms_after_um / cv - 1.0)
            ));
        }
        if let (Some((lo, hi)), Some(after), Some(before)) = (
            a.measured_span_um,
            a.max_abs_after_extrapolated_um,
            a.max_abs_before_extrapolated_um,
        ) {
            s.push_str(&format!(
                "{:<5} grid ends outside the characterised span [{lo}, {hi}] µm ({}): max |error| {before:.3} before, {after:.3} µm after (extrapolated table, not in the figures or the verdict)\n",
                a.axis.to_uppercase(),
                a.extrapolated_targets_um
                    .iter()
                    .map(|p| format!("{p}"))
                    .collect::<Vec<_>>()
                    .join(", ")
            ));
        }
    }
    s.push_str(&format!(
        "{}\n",
        if v.passed {
            "verification passed"
        } else {
            "verification FAILED"
        }
    ));
    s
}

/// The one JSON object of `csmetro verify --json` (and `verify.json`).
pub fn json(v: &Verdict) -> Value {
    serde_json::to_value(v).unwrap_or(Value::Null)
}

/// Raw samples of both passes as CSV, in the layout of every samples file
/// ([`crate::samples::LAYOUT`]; `pass` before | after).
pub fn samples_csv(v: &Verdict) -> String {
    let mut s = crate::samples::layout_header();
    for (after, r) in &v.raw {
        s.push_str(&crate::samples::layout_row(r, Some(*after)));
    }
    s
}

/// The compensated approaches of an axis the verdict checks: (target, deviation), µm.
fn after_samples(v: &Verdict, a: &AxisVerdict) -> Vec<(f64, f64)> {
    v.raw
        .iter()
        .filter(|(after, r)| {
            *after
                && r.target.run.axis.as_str() == a.axis
                && !a
                    .extrapolated_targets_um
                    .iter()
                    .any(|q| (q - r.target.target_um()).abs() < 1e-9)
        })
        .map(|(_, r)| (r.target.target_um(), r.error_um(r.target.run.axis)))
        .collect()
}

/// Size of the verification charts.
pub(super) const CHART: crate::report::PlotOptions = crate::report::PlotOptions {
    width: 1200,
    height: 700,
};

/// Why a verification chart is missing.
#[derive(Debug, thiserror::Error)]
pub enum ChartError {
    #[error("no axis {0}")]
    NoAxis(String),
    #[error(transparent)]
    Draw(#[from] DrawError),
}

fn chart<T>(
    v: &Verdict,
    axis: &str,
    draw: impl FnOnce(&crate::report::verification::VerifyChart<'_>) -> Result<T, DrawError>,
) -> Result<T, ChartError> {
    let a = v
        .axes
        .iter()
        .find(|a| a.axis == axis)
        .ok_or_else(|| ChartError::NoAxis(axis.to_string()))?;
    let samples = after_samples(v, a);
    Ok(draw(&crate::report::verification::VerifyChart {
        axis,
        checks: &a.per_target,
        after_samples: &samples,
        passed: a.passed,
    })?)
}

/// One axis before / after (mean deviation per target and direction, every compensated
/// approach, the pass line ±expected) as SVG.
pub fn plot_svg(v: &Verdict, axis: &str) -> Result<String, ChartError> {
    chart(v, axis, |c| {
        crate::report::verification::verify_chart_svg(c, &CHART)
    })
}

/// [`plot_svg`] as PNG.
pub fn plot_png(v: &Verdict, axis: &str) -> Result<Vec<u8>, ChartError> {
    chart(v, axis, |c| {
        crate::report::verification::verify_chart_png(c, &CHART)
    })
}

/// `verify/report.html`: the before/after tables and charts (`pngs`: per axis).
pub fn page_html(v: &Verdict, pngs: &[(String, Vec<u8>)]) -> String {
    use crate::report::verification::{verify_html, AxisPage};
    let axes: Vec<AxisPage<'_>> = v
        .axes
        .iter()
        .map(|a| AxisPage {
            axis: &a.axis,
            e_before_um: a.before.e_um,
            e_after_um: a.after.e_um,
            mean_abs_before_um: a.mean_abs_before_um,
            mean_abs_after_um: a.mean_abs_after_um,
            max_abs_after_um: a.max_abs_after_um,
            expected_um: a.expected_um,
            expected_basis: basis(a),
            passed: a.passed,
            checks: &a.per_target,
            png: pngs
                .iter()
                .find(|(n, _)| *n == a.axis)
                .map(|(_, b)| b.as_slice()),
            svg_name: Some(format!("verify_{}.svg", a.axis)),
        })
        .collect();
    verify_html(
        &format!(
            "Verification of campaign {} on stage {}",
            v.campaign, v.stage
        ),
        &format!("Compensation: {}.", v.compensation),
        v.passed,
        &axes,
        &table(v),
        "",
    )
}

/// The stored verdict (the JSON of `csmetro verify --json`), among a campaign's results.
pub const VERDICT_FILE: &str = "verify/verify.json";

/// `report.html` of a verification campaign: verdict, the side-by-side table, the plots of both
/// curves (embedded), the campaign file.
pub fn report_html(v: &Verdict, id: i64, name: &str, text: &str, origin: &str) -> String {
    use crate::report::html::esc;
    use base64::Engine as _;
    let title = format!(
        "csmetro campaign {id} — {name}: verification of campaign {}",
        v.campaign
    );
    let mut h = format!(
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>{t}</title>\
         <style>body{{font-family:sans-serif;max-width:1250px;margin:1em auto}}pre{{background:#f4f4f4;padding:.5em;overflow-x:auto}}\
         img{{max-width:100%}}.bad{{color:#b00020}}</style></head><body>\n<h1>{t}</h1>\n",
        t = esc(&title)
    );
    h.push_str(&format!(
        "<p>Verdict: <b{}>{}</b>. Stage {}, compensation {}. Units: µm (error = measured − wanted position).</p>\n",
        if v.passed { "" } else { " class=\"bad\"" },
        if v.passed { "passed" } else { "FAILED" },
        esc(&v.stage),
        esc(&v.compensation)
    ));
    h.push_str(&format!(
        "<h2>Before / after (ISO 230-2)</h2>\n<p><a href=\"{REPORT_FILE}\">Each target against its pass line</a>.</p>\n<pre>{}</pre>\n",
        esc(&table(v))
    ));
    for a in &v.axes {
        if let Ok(svg) = plot_svg(v, &a.axis) {
            h.push_str(&format!(
                "<figure><img alt=\"axis {ax}\" src=\"data:image/svg+xml;base64,{}\"></figure>\n",
                base64::engine::general_purpose::STANDARD.encode(svg),
                ax = esc(&a.axis)
            ));
        }
    }
    h.push_str(&format!(
        "<h2>Campaign file</h2>\n<p>{}</p>\n<pre>{}</pre>\n</body></html>\n",
        esc(origin),
        esc(text)
    ));
    h
}

/// The verification's result files (name relative to the characterisation's results, content
/// type, bytes).
pub fn files(v: &Verdict) -> Vec<(String, String, Vec<u8>)> {
    let mut f = vec![
        (
            "verify/summary.txt".to_string(),
            "text/plain".to_string(),
            table(v).into_bytes(),
        ),
        (
            VERDICT_FILE.into(),
            "application/json".into(),
            serde_json::to_vec_pretty(&json(v)).unwrap_or_default(),
        ),
        (
            "verify/samples.csv".into(),
            "text/csv".into(),
            samples_csv(v).into_bytes(),
        ),
    ];
    let mut pngs = Vec::new();
    for a in &v.axes {
        if let Ok(svg) = plot_svg(v, &a.axis) {
            f.push((
                format!("verify/verify_{}.svg", a.axis),
                "image/svg+xml".into(),
                svg.into_bytes(),
            ));
        }
        if let Ok(png) = plot_png(v, &a.axis) {
            f.push((
                format!("verify/verify_{}.png", a.axis),
                "image/png".into(),
                png.clone(),
            ));
            pngs.push((a.axis.clone(), png));
        }
    }
    f.push((
        REPORT_FILE.into(),
        "text/html; charset=utf-8".into(),
        page_html(v, &pngs).into_bytes(),
    ));
    f
}

/// The verification's page among the characterisation's results (linked from its report.html).
pub const REPORT_FILE: &str = "verify/report.html";
