//! The before/after report of `csmetro verify ID`: per target and direction the mean deviation
//! without and with the compensation, the largest |after| and the expected residual it is
//! checked against ([`per_target`]); one chart per axis, SVG and PNG, with that pass line drawn
//! ([`verify_chart_svg`], [`verify_chart_png`]); `verify/report.html` with the tables and
//! charts ([`verify_html`]); and the link the characterisation's `report.html` gets to it
//! ([`with_verification_link`]).
use std::collections::BTreeMap;

use base64::Engine as _;
use plotters::coord::Shift;
use plotters::prelude::*;
use serde::Serialize;

use super::html::esc;
use super::plot::{frame, padded_range, render_png, render_svg, xy_chart, DrawError, Mesh};
use super::PlotOptions;
use crate::types::{AxisId, Direction, SampleRecord};

/// One target and direction of a verification (µm).
#[derive(Debug, Clone, Serialize)]
pub struct TargetCheck {
    pub target_um: f64,
    /// `forward` or `backward`.
    pub direction: &'static str,
    /// `iso` (on the characterisation's grid) or `unvisited` (between its grid points).
    pub kind: &'static str,
    pub mean_before_um: f64,
    pub mean_after_um: f64,
    pub max_abs_after_um: f64,
    /// The pass line here: every compensated approach must stay within ±expected.
    pub expected_um: f64,
    pub passed: bool,
}

/// Targets within this distance are one (µm; the verification's targets are exact copies).
const SAME_TARGET_UM: f64 = 1e-6;

/// [`TargetCheck`] of every target of `axis` that `kind_of` names (`None`: not reported, e.g. a
/// grid end outside the measured span), ascending, forward before backward.
pub fn per_target(
    before: &[SampleRecord],
    after: &[SampleRecord],
    axis: AxisId,
    kind_of: &dyn Fn(f64) -> Option<&'static str>,
    expected: &dyn Fn(Direction, f64) -> f64,
) -> Vec<TargetCheck> {
    // (target key, backward) -> (target, kind, before sum, n, after sum, n, max |after|)
    type Acc = (f64, &'static str, f64, usize, f64, usize, f64);
    let mut per: BTreeMap<(i64, bool), Acc> = BTreeMap::new();
    for (is_after, list) in [(false, before), (true, after)] {
        for s in list.iter().filter(|s| s.target.run.axis == axis) {
            let t = s.target.target_um();
            let Some(kind) = kind_of(t) else { continue };
            let backward = s.target.run.direction == Direction::Backward;
            let key = ((t / SAME_TARGET_UM).round() as i64, backward);
            let e = per.entry(key).or_insert((t, kind, 0.0, 0, 0.0, 0, 0.0));
            let d = s.error_um(axis);
            if is_after {
                e.4 += d;
                e.5 += 1;
                e.6 = e.6.max(d.abs());
            } else {
                e.2 += d;
                e.3 += 1;
            }
        }
    }
    per.into_iter()
        .map(|((_, backward), (t, kind, sb, nb, sa, na, max_a))| {
            let dir = if backward {
                Direction::Backward
            } else {
                Direction::Forward
            };
            let mean = |s: f64, n: usize| if n > 0 { s / n as f64 } else { f64::NAN };
            let e = expected(dir, t);
            TargetCheck {
                target_um: t,
                direction: dir.as_str(),
                kind,
                mean_before_um: mean(sb, nb),
                mean_after_um: mean(sa, na),
                max_abs_after_um: if na > 0 { max_a } else { f64::NAN },
                expected_um: e,
                // NaN (no u at the target, no compensated approach) fails, as in the verdict.
                passed: na > 0 && max_a <= e,
            }
        })
        .collect()
}

/// What a verification chart of one axis shows.
#[derive(Debug, Clone)]
pub struct VerifyChart<'a> {
    pub axis: &'a str,
    pub checks: &'a [TargetCheck],
    /// Every compensated approach (target, deviation), µm: what the pass line checks.
    pub after_samples: &'a [(f64, f64)],
    pub passed: bool,
}

const BEFORE_F: RGBColor = RGBColor(214, 39, 40);
const BEFORE_B: RGBColor = RGBColor(227, 119, 194);
const AFTER_F: RGBColor = RGBColor(31, 119, 180);
const AFTER_B: RGBColor = RGBColor(23, 190, 207);
const PASS: RGBColor = RGBColor(44, 140, 44);
const SAMPLE: RGBColor = RGBColor(150, 150, 150);

/// The chart as an SVG document.
pub fn verify_chart_svg(c: &VerifyChart<'_>, opts: &PlotOptions) -> Result<String, DrawError> {
    render_svg(opts, |root| draw(root, c))
}

/// The chart as a PNG file, drawn by the same code as [`verify_chart_svg`].
pub fn verify_chart_png(c: &VerifyChart<'_>, opts: &PlotOptions) -> Result<Vec<u8>, DrawError> {
    render_png(opts, |root| draw(root, c))
}

/// The pass line: per target the tightest expected residual of its directions (finite only).
fn pass_line(checks: &[TargetCheck]) -> Vec<(f64, f64)> {
    let mut per: BTreeMap<i64, (f64, f64)> = BTreeMap::new();
    for c in checks.iter().filter(|c| c.expected_um.is_finite()) {
        let e = per
            .entry((c.target_um / SAME_TARGET_UM).round() as i64)
            .or_insert((c.target_um, f64::INFINITY));
        e.1 = e.1.min(c.expected_um);
    }
    per.into_values().collect()
}

fn draw<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    c: &VerifyChart<'_>,
) -> Result<(), DrawError> {
    let err = |e: &dyn std::fmt::Display| DrawError::of(e);
    let title = format!(
        "axis {}: deviation before / after compensation — {}",
        c.axis,
        if c.passed { "passed" } else { "FAILED" }
    );
    let (fonts, body) = frame(root, &title)?;
    if c.checks.is_empty() {
        return Err(DrawError::NoTargets(c.axis.to_string()));
    }
    let line = pass_line(c.checks);
    let xs = c.checks.iter().map(|t| t.target_um);
    let (x0, x1) = padded_range(xs);
    let ys = c
        .checks
        .iter()
        .flat_map(|t| [t.mean_before_um, t.mean_after_um])
        .chain(c.after_samples.iter().map(|s| s.1))
        .chain(line.iter().flat_map(|(_, e)| [*e, -*e]));
    let (y0, y1) = padded_range(ys);
    // Head-room for the legend (six rows).
    let y1 = y1 + (y1 - y0) * 0.35;
    let mut chart = xy_chart(
        &body,
        &fonts,
        x0..x1,
        y0..y1,
        Mesh {
            x_desc: "target / µm",
            y_desc: "deviation / µm",
            x_labels: None,
            y_labels: None,
            caption: None,
        },
    )?;
    chart
        .draw_series(LineSeries::new(
            [(x0, 0.0), (x1, 0.0)],
            RGBColor(120, 120, 120).stroke_width(1),
        ))
        .map_err(|e| err(&e))?;
    if !line.is_empty() {
        for sign in [1.0, -1.0] {
            let s = chart
                .draw_series(LineSeries::new(
                    line.iter().map(|&(t, e)| (t, sign * e)),
                    PASS.stroke_width(2),
                ))
                .map_err(|e| err(&e))?;
            if sign > 0.0 {
                s.label("pass line ±expected").legend(move |(x, y)| {
                    PathElement::new(vec![(x, y), (x + 20, y)], PASS.stroke_width(2))
                });
            }
        }
    }
    chart
        .draw_series(
            c.after_samples
                .iter()
                .filter(|(x, y)| x.is_finite() && y.is_finite())
                .map(|&p| Circle::new(p, 2, SAMPLE.filled())),
        )
        .map_err(|e| err(&e))?
        .label("after, every approach")
        .legend(|(x, y)| Circle::new((x + 10, y), 2, SAMPLE.filled()));
    for (after, dir, color, label) in [
        (false, "forward", BEFORE_F, "before, forward (mean)"),
        (false, "backward", BEFORE_B, "before, backward (mean)"),
        (true, "forward", AFTER_F, "after, forward (mean)"),
        (true, "backward", AFTER_B, "after, backward (mean)"),
    ] {
        let pts: Vec<(f64, f64)> = c
            .checks
            .iter()
            .filter(|t| t.direction == dir)
            .map(|t| {
                (
                    t.target_um,
                    if after {
                        t.mean_after_um
                    } else {
                        t.mean_before_um
                    },
                )
            })
            .filter(|(x, y)| x.is_finite() && y.is_finite())
            .collect();
        chart
            .draw_series(LineSeries::new(pts.clone(), color.stroke_width(2)))
            .map_err(|e| err(&e))?
            .label(label)
            .legend(move |(x, y)| {
                PathElement::new(vec![(x, y), (x + 20, y)], color.stroke_width(2))
            });
        chart
            .draw_series(pts.into_iter().map(|p| Circle::new(p, 3, color.filled())))
            .map_err(|e| err(&e))?;
    }
    // A failing target is marked where its worst approach lies, on the side it failed.
    chart
        .draw_series(
            c.checks
                .iter()
                .filter(|t| !t.passed && t.max_abs_after_um.is_finite())
                .map(|t| {
                    let y = t.max_abs_after_um.copysign(t.mean_after_um);
                    Cross::new((t.target_um, y), 6, BLACK.stroke_width(2))
                }),
        )
        .map_err(|e| err(&e))?;
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperRight)
        .background_style(WHITE.mix(0.85))
        .border_style(RGBColor(150, 150, 150))
        .label_font(fonts.label)
        .draw()
        .map_err(|e| err(&e))?;
    Ok(())
}

/// One axis of `verify/report.html`.
#[derive(Debug, Clone)]
pub struct AxisPage<'a> {
    pub axis: &'a str,
    pub e_before_um: f64,
    pub e_after_um: f64,
    pub mean_abs_before_um: f64,
    pub mean_abs_after_um: f64,
    pub max_abs_after_um: f64,
    pub expected_um: f64,
    /// How the expected residual was obtained, in words.
    pub expected_basis: String,
    pub passed: bool,
    pub checks: &'a [TargetCheck],
    /// The chart as PNG (embedded) and the SVG's file name next to the page.
    pub png: Option<&'a [u8]>,
    pub svg_name: Option<String>,
}

fn num(v: f64) -> String {
    if v.is_finite() {
        format!("{v:.3}")
    } else {
        "n/a".into()
    }
}

fn verdict(passed: bool) -> &'static str {
    if passed {
        "<td class=\"pass\">pass</td>"
    } else {
        "<td class=\"fail\">FAIL</td>"
    }
}

const STYLE: &str = "body{font-family:sans-serif;max-width:1250px;margin:1.5em auto;padding:0 1em;color:#222}\
h1{font-size:1.5em}h2{font-size:1.2em;border-bottom:1px solid #ccc;margin-top:1.6em}\
table{border-collapse:collapse;margin:.5em 0}td,th{border:1px solid #ccc;padding:.2em .6em;text-align:left}\
th{background:#f3f3f3}td.num{text-align:right;font-variant-numeric:tabular-nums}\
td.pass{color:#1a7f37}td.fail{color:#b00020;font-weight:bold}\
pre{background:#f7f7f7;padding:.6em;overflow-x:auto;font-size:.85em;white-space:pre-wrap}\
img{max-width:100%;height:auto;display:block;margin:.5em 0}.note{color:#555;font-size:.9em}\
@media print{body{max-width:none;margin:0}}";

/// `verify/report.html`: the verdict, the before/after table per axis (E, mean |e|, max |after|
/// vs expected, pass/fail), the per-target table, the charts (PNG embedded, SVG linked) and
/// the side-by-side text table. Self-contained but for the links next to it. `extra_html`
/// (already escaped) goes under the before/after table: a map's ISO 230-1 figures and points.
pub fn verify_html(
    title: &str,
    lead: &str,
    passed: bool,
    axes: &[AxisPage<'_>],
    table: &str,
    extra_html: &str,
) -> String {
    let mut h = format!(
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>{t}</title><style>{STYLE}</style></head><body>\n<h1>{t}</h1>\n",
        t = esc(title)
    );
    h.push_str(&format!(
        "<p>Verdict: <b class=\"{}\">{}</b>. {} <a href=\"../report.html\">The characterisation's report</a>.</p>\n\
         <p class=\"note\">Units: µm; deviation = measured − wanted position. The pass line is the expected residual at each target: every compensated approach must stay within ±expected.</p>\n",
        if passed { "pass" } else { "fail" },
        if passed { "passed" } else { "FAILED" },
        esc(lead)
    ));
    h.push_str(
        "<h2>Before / after</h2>\n<table><tr><th>axis</th><th>E before</th><th>E after</th>\
         <th>mean |e| before</th><th>mean |e| after</th><th>max |after|</th><th>expected</th>\
         <th>verdict</th></tr>\n",
    );
    for a in axes {
        h.push_str(&format!(
            "<tr data-axis=\"{}\"><td>{}</td><td class=\"num\">{}</td><td class=\"num\">{}</td><td class=\"num\">{}</td><td class=\"num\">{}</td><td class=\"num\">{}</td><td class=\"num\">{}</td>{}</tr>\n",
            esc(a.axis),
            esc(&a.axis.to_uppercase()),
            num(a.e_before_um),
            num(a.e_after_um),
            num(a.mean_abs_before_um),
            num(a.mean_abs_after_um),
            num(a.max_abs_after_um),
            num(a.expected_um),
            verdict(a.passed)
        ));
    }
    h.push_str("</table>\n");
    h.push_str(extra_html);
    for a in axes {
        h.push_str(&format!(
            "<h2>Axis {}</h2>\n<p class=\"note\">{}</p>\n",
            esc(&a.axis.to_uppercase()),
            esc(&a.expected_basis)
        ));
        if let Some(png) = a.png {
            h.push_str(&format!(
                "<figure><img alt=\"axis {} before / after\" src=\"data:image/png;base64,{}\">",
                esc(a.axis),
                base64::engine::general_purpose::STANDARD.encode(png)
            ));
            if let Some(svg) = &a.svg_name {
                h.push_str(&format!(
                    "<figcaption><a href=\"{n}\">{n}</a></figcaption>",
                    n = esc(svg)
                ));
            }
            h.push_str("</figure>\n");
        }
        h.push_str(
            "<table><tr><th>target</th><th>direction</th><th>kind</th><th>mean before</th>\
             <th>mean after</th><th>max |after|</th><th>expected</th><th></th></tr>\n",
        );
        for t in a.checks {
            h.push_str(&format!(
                "<tr><td class=\"num\">{}</td><td>{}</td><td>{}</td><td class=\"num\">{}</td><td class=\"num\">{}</td><td class=\"num\">{}</td><td class=\"num\">{}</td>{}</tr>\n",
                num(t.target_um),
                t.direction,
                t.kind,
                num(t.mean_before_um),
                num(t.mean_after_um),
                num(t.max_abs_after_um),
                num(t.expected_um),
                verdict(t.passed)
            ));
        }
        h.push_str("</table>\n");
    }
    h.push_str(&format!(
        "<h2>Summary</h2>\n<pre>{}</pre>\n</body></html>\n",
        esc(table)
    ));
    h
}

const LINK_START: &str = "<!-- csmetro:verification -->";
const LINK_END: &str = "<!-- /csmetro:verification -->";

/// `report` (a characterisation's `report.html`) with a paragraph under its title linking to
/// its verification at `href` (relative), one paragraph per verification: the one an earlier
/// verification at the same `href` left is replaced (`csmetro verify` writes one place), the
/// others (verification campaigns, each its own results) are kept. `None` when the document
/// has no title to put it under.
pub fn with_verification_link(
    report: &str,
    href: &str,
    passed: bool,
    note: &str,
) -> Option<String> {
    let target = format!("href=\"{}\"", esc(href));
    let entry = format!(
        "<p>Verification: <a {target}>{}</a> {}</p>",
        if passed { "passed" } else { "FAILED" },
        esc(note)
    );
    if let (Some(a), Some(b)) = (report.find(LINK_START), report.find(LINK_END)) {
        if a < b {
            let mut entries: Vec<&str> = report[a + LINK_START.len()..b]
                .split_inclusive("</p>")
                .map(str::trim)
                .filter(|p| !p.is_empty() && !p.contains(&target))
                .collect();
            entries.push(&entry);
            let end = b + LINK_END.len();
            let end = end + usize::from(report[end..].starts_with('\n'));
            return Some(format!(
                "{}{LINK_START}{}{LINK_END}\n{}",
                &report[..a],
                entries.concat(),
                &report[end..]
            ));
        }
    }
    let at = report.find("</h1>\n")? + "</h1>\n".len();
    Some(format!(
        "{}{LINK_START}{entry}{LINK_END}\n{}",
        &report[..at],
        &report[at..]
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::types::{Phase, RunKey, Target};

    fn sample(axis: AxisId, dir: Direction, t: f64, e: f64) -> SampleRecord {
        let target = Target {
            seq: 0,
            run: RunKey {
                phase: Phase::Cs,
                axis,
                direction: dir,
                cycle: 0,
            },
            grid_index: 0,
            target_x_um: if axis == AxisId::X { t } else { 0.0 },
            target_y_um: if axis == AxisId::Y { t } else { 0.0 },
        };
        SampleRecord {
            meas_x_um: target.target_x_um + if axis == AxisId::X { e } else { 0.0 },
            meas_y_um: target.target_y_um + if axis == AxisId::Y { e } else { 0.0 },
            ..SampleRecord::at(target)
        }
    }

    fn checks() -> Vec<TargetCheck> {
        use Direction::{Backward as B, Forward as F};
        let x = AxisId::X;
        let before = [
            sample(x, F, 0.0, 2.0),
            sample(x, F, 100.0, 3.0),
            sample(x, B, 100.0, 4.0),
        ];
        let after = [
            sample(x, F, 0.0, 0.1),
            sample(x, F, 0.0, -0.3),
            sample(x, F, 100.0, 0.6),
            sample(x, B, 100.0, 0.2),
            sample(x, F, 500.0, 9.0),
        ];
        let kind = |t: f64| (t < 200.0).then_some(if t == 0.0 { "iso" } else { "unvisited" });
        per_target(&before, &after, x, &kind, &|d, _| {
            if d == F {
                0.5
            } else {
                0.25
            }
        })
    }

    #[test]
    fn each_target_and_direction_is_checked_against_its_pass_line() {
        let c = checks();
        assert_eq!(c.len(), 3, "{c:?}");
        let (a, b, d) = (&c[0], &c[1], &c[2]);
        assert_eq!((a.target_um, a.direction, a.kind), (0.0, "forward", "iso"));
        assert!((a.mean_after_um + 0.1).abs() < 1e-9 && (a.max_abs_after_um - 0.3).abs() < 1e-9);
        assert!(a.passed && (a.mean_before_um - 2.0).abs() < 1e-9);
        assert_eq!((b.target_um, b.direction), (100.0, "forward"));
        assert!(!b.passed, "0.6 > 0.5");
        assert_eq!((d.direction, d.kind), ("backward", "unvisited"));
        assert!(d.passed && d.expected_um == 0.25);
        assert_eq!(pass_line(&c), vec![(0.0, 0.5), (100.0, 0.25)]);
    }

    #[test]
    fn the_chart_draws_the_pass_line_in_both_formats() {
        let c = checks();
        let ch = VerifyChart {
            axis: "x",
            checks: &c,
            after_samples: &[(0.0, 0.1), (100.0, 0.6)],
            passed: false,
        };
        let svg = verify_chart_svg(&ch, &PlotOptions::default()).unwrap();
        assert!(svg.contains("pass line ±expected") && svg.contains("FAILED"));
        assert!(svg.contains("<polyline"));
        let png = verify_chart_png(
            &ch,
            &PlotOptions {
                width: 600,
                height: 400,
            },
        )
        .unwrap();
        let mut r = png::Decoder::new(std::io::Cursor::new(png))
            .read_info()
            .unwrap();
        let mut buf = vec![0; r.output_buffer_size()];
        r.next_frame(&mut buf).unwrap();
        let green = buf
            .chunks(3)
            .filter(|p| *p == [PASS.0, PASS.1, PASS.2])
            .count();
        assert!(green > 100, "pass line not drawn: {green} pixels");
        let empty = VerifyChart { checks: &[], ..ch };
        assert!(verify_chart_svg(&empty, &PlotOptions::default()).is_err());
    }

    #[test]
    fn the_page_has_both_tables_and_the_link_goes_under_the_title_once() {
        let c = checks();
        let a = AxisPage {
            axis: "x",
            e_before_um: 4.0,
            e_after_um: 0.9,
            mean_abs_before_um: 3.0,
            mean_abs_after_um: 0.3,
            max_abs_after_um: 0.6,
            expected_um: 0.25,
            expected_basis: "expected <given>".into(),
            passed: false,
            checks: &c,
            png: Some(&[1, 2, 3]),
            svg_name: Some("verify_x.svg".into()),
        };
        let h = verify_html(
            "verification <1>",
            "Stage s",
            false,
            &[a],
            "table & text",
            "",
        );
        assert!(h.contains("verification &lt;1&gt;") && h.contains("expected &lt;given&gt;"));
        assert!(
            h.contains("<td class=\"fail\">FAIL</td>")
                && h.contains("<td class=\"pass\">pass</td>")
        );
        assert!(h.contains("href=\"verify_x.svg\"") && h.contains("data:image/png;base64,AQID"));
        assert!(h.contains("href=\"../report.html\"") && h.contains("table &amp; text"));

        let rep = "<html><body>\n<h1>campaign 1</h1>\n<p>State</p>\n";
        let one = with_verification_link(rep, "verify/report.html", false, "(run 1)").unwrap();
        assert!(one.contains("<h1>campaign 1</h1>\n<!-- csmetro:verification --><p>Verification: <a href=\"verify/report.html\">FAILED</a>"));
        let two = with_verification_link(&one, "verify/report.html", true, "(run 2)").unwrap();
        assert_eq!(two.matches(LINK_START).count(), 1, "{two}");
        assert!(two.contains("passed</a> (run 2)") && !two.contains("run 1"));
        assert!(two.ends_with("<p>State</p>\n"));
        // A verification campaign's link is added beside it, and replaced by its own again.
        let three =
            with_verification_link(&two, "../../2/results/report.html", true, "(c 2)").unwrap();
        let four =
            with_verification_link(&three, "../../2/results/report.html", false, "(c 2)").unwrap();
        assert_eq!(four.matches(LINK_START).count(), 1, "{four}");
        assert_eq!(four.matches("<p>Verification: ").count(), 2, "{four}");
        assert!(
            four.contains("href=\"verify/report.html\">passed</a> (run 2)"),
            "{four}"
        );
        assert!(
            four.contains("href=\"../../2/results/report.html\">FAILED</a> (c 2)</p>"),
            "{four}"
        );
        assert!(four.ends_with("<p>State</p>\n"));
        assert!(with_verification_link("<p>no title</p>", "x", true, "").is_none());
    }
}
