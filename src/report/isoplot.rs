//! The ISO 230-2 chart of one axis, as the standard presents it: the forward (x̄↑) and backward
//! (x̄↓) mean positional deviation at each target with their ±2s bands and the mean
//! bidirectional deviation x̄, with A, B, E, M and R written on the chart and the figures'
//! source (measured full scan, repeated cycles, or estimated from the reconstruction) in the
//! title. Same drawing for SVG and PNG, like the component plots.
use plotters::coord::Shift;
use plotters::prelude::*;

use super::plot::{
    finite_points, frame, padded_range, render_png, render_svg, value_range, xy_chart, Mesh,
};
use super::{AxisIso230, DrawError, PlotOptions, ReportError, FONT_FAMILY};

const UP: RGBColor = RGBColor(31, 119, 180);
const DOWN: RGBColor = RGBColor(214, 39, 40);
const BIDIR: RGBColor = RGBColor(90, 90, 90);

fn chart_error(f: &AxisIso230, reason: DrawError) -> ReportError {
    ReportError::Plot {
        component: format!("iso230_{}", f.axis),
        reason,
    }
}

/// The chart's title: `ISO 230-2 — X axis, measured full scan, 1 cycle`.
pub(crate) fn chart_title(f: &AxisIso230) -> String {
    format!(
        "ISO 230-2 — {} axis, {}",
        f.axis.to_uppercase(),
        f.source_label
    )
}

/// The figures line written on the chart: `A 1.234 µm   B ...   R n/a`.
pub(crate) fn figures_line(f: &AxisIso230) -> String {
    let r = f.reported();
    let v = |x: Option<f64>| match x {
        Some(x) if x.is_finite() => format!("{x:.3} µm"),
        _ => "n/a".into(),
    };
    format!(
        "A {}    B {}    E {}    M {}    R {}",
        v(Some(r.a_um)),
        v(r.b_um),
        v(Some(r.e_um)),
        v(r.m_um),
        v(r.r_um)
    )
}

/// The chart of `f` as an SVG document.
pub fn iso_chart_svg(f: &AxisIso230, opts: &PlotOptions) -> Result<String, ReportError> {
    render_svg(opts, |root| draw(root, f)).map_err(|e| chart_error(f, e))
}

/// The chart of `f` as a PNG file, drawn by the same code as [`iso_chart_svg`].
pub fn iso_chart_png(f: &AxisIso230, opts: &PlotOptions) -> Result<Vec<u8>, ReportError> {
    render_png(opts, |root| draw(root, f)).map_err(|e| chart_error(f, e))
}

fn draw<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    f: &AxisIso230,
) -> Result<(), DrawError> {
    let err = |e: &dyn std::fmt::Display| DrawError::of(e);
    let (fonts, body) = frame(root, &chart_title(f))?;
    let small = fonts.small;
    // The figures, in bold, on a strip of their own above the plot: never hidden by a curve.
    let (strip, plot) = body.split_vertically(small * 2 + 8);
    strip
        .draw_text(
            &figures_line(f),
            &(FONT_FAMILY, small + 4)
                .into_font()
                .style(FontStyle::Bold)
                .color(&BLACK),
            (small as i32 * 6, 4),
        )
        .map_err(|e| err(&e))?;

    let rows = &f.chart_rows;
    let col =
        |g: fn(&crate::iso230::TargetRow) -> f64| -> Vec<f64> { rows.iter().map(g).collect() };
    let p = col(|r| r.target_um);
    let up = col(|r| r.mean_up_um);
    let down = col(|r| r.mean_down_um);
    let s_up = col(|r| r.s_up_um);
    let s_down = col(|r| r.s_down_um);
    let bidir = col(|r| r.mean_bidir_um);
    let band = |m: &[f64], s: &[f64], k: f64| -> Vec<f64> {
        m.iter().zip(s).map(|(m, s)| m + k * s).collect()
    };
    let (up_hi, up_lo) = (band(&up, &s_up, 2.0), band(&up, &s_up, -2.0));
    let (down_hi, down_lo) = (band(&down, &s_down, 2.0), band(&down, &s_down, -2.0));
    let has_bands = s_up
        .iter()
        .chain(&s_down)
        .any(|s| s.is_finite() && *s > 0.0);

    let (x0, x1) = value_range(p.iter().copied())
        .filter(|(lo, hi)| hi > lo)
        .unwrap_or_else(|| padded_range(p.iter().copied()));
    let (y0, y1) = padded_range(
        up_hi
            .iter()
            .chain(&up_lo)
            .chain(&down_hi)
            .chain(&down_lo)
            .copied(),
    );
    let y1 = y1 + (y1 - y0) * 0.3; // head-room for the legend
    let mut chart = xy_chart(
        &plot,
        &fonts,
        x0..x1,
        y0..y1,
        Mesh {
            x_desc: "target position / µm",
            y_desc: "positional deviation / µm",
            x_labels: Some(((root.dim_in_pixel().0 / 110) as usize).max(3)),
            y_labels: None,
            caption: None,
        },
    )?;
    let line = |c: RGBColor, w: u32| {
        move |(x, y): (i32, i32)| PathElement::new(vec![(x, y), (x + 20, y)], c.stroke_width(w))
    };
    let markers = rows.len() <= 60;
    for (mean, hi, lo, color, name) in [
        (&up, &up_hi, &up_lo, UP, "x̄↑ forward"),
        (&down, &down_hi, &down_lo, DOWN, "x̄↓ backward"),
    ] {
        if mean.iter().all(|v| !v.is_finite()) {
            continue;
        }
        if has_bands {
            for (k, b) in [hi, lo].into_iter().enumerate() {
                let s = chart
                    .draw_series(LineSeries::new(
                        finite_points(&p, b),
                        color.mix(0.45).stroke_width(1),
                    ))
                    .map_err(|e| err(&e))?;
                if k == 0 {
                    s.label(format!("{name} ± 2s"))
                        .legend(line(RGBColor(color.0, color.1, color.2), 1));
                }
            }
        }
        chart
            .draw_series(LineSeries::new(
                finite_points(&p, mean),
                color.stroke_width(2),
            ))
            .map_err(|e| err(&e))?
            .label(name)
            .legend(line(color, 2));
        if markers {
            chart
                .draw_series(finite_points(&p, mean).map(|q| Circle::new(q, 3, color.filled())))
                .map_err(|e| err(&e))?;
        }
    }
    if bidir.iter().any(|v| v.is_finite()) {
        chart
            .draw_series(LineSeries::new(
                finite_points(&p, &bidir),
                BIDIR.stroke_width(1),
            ))
            .map_err(|e| err(&e))?
            .label("x̄ bidirectional")
            .legend(line(BIDIR, 1));
    }
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::report::{iso230_axis, ComponentCurve};
    use crate::types::AxisId;

    fn axis() -> AxisIso230 {
        let grid: Vec<f64> = (0..=20).map(|i| i as f64 * 50.0).collect();
        let curve = |name: &str, off: f64| ComponentCurve {
            component: name.into(),
            reconstructed_um: grid.iter().map(|x| off + x / 1000.0).collect(),
            grid_um: grid.clone(),
            method: "physics".into(),
            cv_error_um: None,
            samples: Vec::new(),
            full_scan_um: None,
            // Two cycles, 0.2 µm apart: s = 0.1414 µm.
            full_scan_samples: grid
                .iter()
                .flat_map(|&x| [(x, off + 0.1), (x, off - 0.1)])
                .collect(),
            truth_um: None,
            u_um: Vec::new(),
        };
        iso230_axis(
            AxisId::X,
            &[curve("ef_xx", 1.0), curve("eb_xx", -1.0)],
            1e-3,
        )
        .unwrap()
        .unwrap()
    }

    #[test]
    fn the_chart_shows_the_means_bands_and_figures_with_their_source() {
        let f = axis();
        let svg = iso_chart_svg(&f, &PlotOptions::default()).unwrap();
        assert!(svg.contains("ISO 230-2 — X axis, measured full scan, 2 cycles"));
        // Means ±1 µm: B = 2 µm; s = 0.1414 µm: R = 2s↑ + 2s↓ + B = 2.566 µm.
        let r = f.reported();
        assert!((r.b_um.unwrap() - 2.0).abs() < 1e-9);
        assert!(svg.contains(&figures_line(&f)), "figures not on the chart");
        assert!(svg.contains("B 2.000 µm"));
        assert!(svg.contains("R 2.566 µm"), "{}", figures_line(&f));
        assert!(svg.contains("x̄↑ forward ± 2s") && svg.contains("x̄↓ backward"));
        // Two means, four band lines, one bidirectional line (and the legend's marks).
        assert!(svg.matches("<polyline").count() >= 7);
        let png = iso_chart_png(&f, &PlotOptions::default()).unwrap();
        assert_eq!(&png[1..4], b"PNG");
    }
}
