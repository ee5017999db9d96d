//! Component plots: one drawing routine, two backends (SVG text, RGB bitmap encoded as PNG).
//!
//! Upper panel: CS samples (markers), reconstruction (line), full scan and ground truth (thin
//! lines) when present. Lower panel, when a full scan or the truth exists: residual =
//! reconstruction - full scan (or - truth without a full scan).
//!
//! Text: plotters is built with `ab_glyph` (no system fontconfig/freetype); DejaVu Sans, embedded
//! by the `dejavu` crate, is registered as [`FONT_FAMILY`] before the first drawing. SVG files
//! name the same family, so viewers use their own sans-serif font.
use std::sync::Once;

use plotters::coord::types::RangedCoordf64;
use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::register_font;

use super::{ComponentCurve, ReportError};

/// The font family the plots use; [`register_fonts`] maps it to the embedded DejaVu Sans.
pub const FONT_FAMILY: &str = "sans-serif";

/// Size of a plot, pixels (the SVG view box and the PNG bitmap).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PlotOptions {
    pub width: u32,
    pub height: u32,
}

impl Default for PlotOptions {
    fn default() -> Self {
        Self {
            width: 1200,
            height: 800,
        }
    }
}

/// Registers the embedded DejaVu Sans (regular, bold) as [`FONT_FAMILY`] for plotters' text
/// layout and rasterisation. Idempotent; the plot functions call it themselves.
pub fn register_fonts() {
    static ONCE: Once = Once::new();
    ONCE.call_once(|| {
        // The bytes are a valid TrueType file shipped by the `dejavu` crate: failure here is a
        // build problem, caught by the tests.
        let _ = register_font(FONT_FAMILY, FontStyle::Normal, dejavu::sans::regular());
        let _ = register_font(FONT_FAMILY, FontStyle::Bold, dejavu::sans::bold());
    });
}

/// The plot of `curve` as an SVG document.
pub fn plot_svg(curve: &ComponentCurve, opts: &PlotOptions) -> Result<String, ReportError> {
    curve.validate()?;
    render_svg(opts, |root| draw(root, curve)).map_err(|reason| plot_error(curve, reason))
}

/// The plot of `curve` as a PNG file (8-bit RGB), drawn by the same code as [`plot_svg`].
pub fn plot_png(curve: &ComponentCurve, opts: &PlotOptions) -> Result<Vec<u8>, ReportError> {
    curve.validate()?;
    render_png(opts, |root| draw(root, curve)).map_err(|reason| plot_error(curve, reason))
}

/// Why a chart could not be drawn. plotters' errors are generic over the backend (SVG,
/// bitmap): their text is what both backends share.
#[derive(Debug, thiserror::Error)]
pub enum DrawError {
    #[error("{0}")]
    Backend(String),
    #[error("zero-sized plot")]
    ZeroSized,
    /// A heat map whose values do not fill its grid.
    #[error("{values} values for a {nx} x {ny} grid")]
    GridSize { values: usize, nx: usize, ny: usize },
    /// A verification chart without targets.
    #[error("no targets of axis {0}")]
    NoTargets(String),
    #[error(transparent)]
    Png(#[from] png::EncodingError),
}

impl DrawError {
    /// A plotters error of any backend.
    pub(super) fn of(e: impl std::fmt::Display) -> Self {
        DrawError::Backend(e.to_string())
    }
}

/// Runs a chart's drawing on an SVG document of `opts`' size (fonts registered first).
pub(super) fn render_svg(
    opts: &PlotOptions,
    draw: impl FnOnce(&DrawingArea<SVGBackend<'_>, Shift>) -> Result<(), DrawError>,
) -> Result<String, DrawError> {
    register_fonts();
    let mut out = String::new();
    {
        let root = SVGBackend::with_string(&mut out, (opts.width, opts.height)).into_drawing_area();
        draw(&root)?;
        root.present().map_err(DrawError::of)?;
    }
    Ok(out)
}

/// Runs the same drawing on an RGB bitmap and encodes it as PNG.
pub(super) fn render_png(
    opts: &PlotOptions,
    draw: impl FnOnce(&DrawingArea<BitMapBackend<'_>, Shift>) -> Result<(), DrawError>,
) -> Result<Vec<u8>, DrawError> {
    if opts.width == 0 || opts.height == 0 {
        return Err(DrawError::ZeroSized);
    }
    register_fonts();
    let mut rgb = vec![0u8; opts.width as usize * opts.height as usize * 3];
    {
        let root =
            BitMapBackend::with_buffer(&mut rgb, (opts.width, opts.height)).into_drawing_area();
        draw(&root)?;
        root.present().map_err(DrawError::of)?;
    }
    encode_png(&rgb, opts.width, opts.height)
}

/// Fonts of a chart, scaled to its height: tick labels, axis descriptions; `small` in px.
pub(super) struct Fonts {
    pub small: u32,
    pub label: FontDesc<'static>,
    pub desc: FontDesc<'static>,
}

/// The frame every chart shares: a white page, the title on top, fonts scaled to the height.
/// Returns the fonts and the area below the title.
pub(super) fn frame<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    title: &str,
) -> Result<(Fonts, DrawingArea<DB, Shift>), DrawError> {
    let (_, h) = root.dim_in_pixel();
    let small = (h / 50).clamp(11, 18);
    root.fill(&WHITE).map_err(DrawError::of)?;
    let body = root
        .titled(title, (FONT_FAMILY, small + 6).into_font())
        .map_err(DrawError::of)?;
    let fonts = Fonts {
        small,
        label: (FONT_FAMILY, small).into_font(),
        desc: (FONT_FAMILY, small + 2).into_font(),
    };
    Ok((fonts, body))
}

/// An 8-bit RGB buffer as a PNG file.
pub(super) fn encode_png(rgb: &[u8], width: u32, height: u32) -> Result<Vec<u8>, DrawError> {
    let mut png_bytes = Vec::new();
    {
        let mut enc = png::Encoder::new(&mut png_bytes, width, height);
        enc.set_color(png::ColorType::Rgb);
        enc.set_depth(png::BitDepth::Eight);
        // Plots are mostly flat white: per-row adaptive filtering shrinks them about 4-fold.
        enc.set_compression(png::Compression::Default);
        enc.set_adaptive_filter(png::AdaptiveFilterType::Adaptive);
        let mut w = enc.write_header()?;
        w.write_image_data(rgb)?;
    }
    Ok(png_bytes)
}

fn plot_error(curve: &ComponentCurve, reason: DrawError) -> ReportError {
    ReportError::Plot {
        component: curve.component.clone(),
        reason,
    }
}

/// `ef_xx — physics, m = 600, CV error 0.123 µm`.
pub(crate) fn title(curve: &ComponentCurve) -> String {
    let cv = match curve.cv_error_um {
        Some(e) if e.is_finite() => format!("{e:.3} µm"),
        _ => "n/a".into(),
    };
    format!(
        "{} — {}, m = {}, CV error {}",
        curve.component,
        curve.method,
        curve.m(),
        cv
    )
}

/// (min, max) of the finite values, `None` without any.
pub(super) fn value_range(values: impl Iterator<Item = f64>) -> Option<(f64, f64)> {
    let (lo, hi) = values
        .filter(|v| v.is_finite())
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| {
            (lo.min(v), hi.max(v))
        });
    (lo <= hi).then_some((lo, hi))
}

/// (min, max) of the finite values, padded by 5 % (at least 1e-3); (-1, 1) without any.
pub(super) fn padded_range(values: impl Iterator<Item = f64>) -> (f64, f64) {
    match value_range(values) {
        Some((lo, hi)) => {
            let pad = (0.05 * (hi - lo)).max(1e-3);
            (lo - pad, hi + pad)
        }
        None => (-1.0, 1.0),
    }
}

/// Tick label without float noise or trailing zeros: `200`, `0.02`, `-1.5`.
pub(super) fn tick(v: &f64) -> String {
    let s = format!("{v:.6}");
    let s = s.trim_end_matches('0').trim_end_matches('.');
    if s == "-0" {
        "0".into()
    } else {
        s.into()
    }
}

pub(super) fn finite_points<'a>(
    xs: &'a [f64],
    ys: &'a [f64],
) -> impl Iterator<Item = (f64, f64)> + 'a {
    xs.iter()
        .zip(ys)
        .map(|(&x, &y)| (x, y))
        .filter(|(x, y)| x.is_finite() && y.is_finite())
}

const RECON: RGBColor = RGBColor(31, 119, 180);
const FULL: RGBColor = RGBColor(60, 60, 60);
const TRUTH: RGBColor = RGBColor(44, 160, 44);
const SAMPLE: RGBColor = RGBColor(214, 39, 40);

fn legend_line(color: RGBColor, width: u32) -> impl Fn((i32, i32)) -> PathElement<(i32, i32)> {
    move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], color.stroke_width(width))
}

/// What a line chart's axes say: descriptions, label counts (`None`: plotters' default) and a
/// caption above the plot.
pub(super) struct Mesh<'s> {
    pub x_desc: &'s str,
    pub y_desc: &'s str,
    pub x_labels: Option<usize>,
    pub y_labels: Option<usize>,
    pub caption: Option<String>,
}

/// The cartesian chart every line chart shares (margins from the font size, a light grid, ticks
/// without trailing zeros), its mesh drawn.
pub(super) fn xy_chart<'a, DB: DrawingBackend>(
    area: &'a DrawingArea<DB, Shift>,
    fonts: &Fonts,
    x: std::ops::Range<f64>,
    y: std::ops::Range<f64>,
    mesh: Mesh<'_>,
) -> Result<ChartContext<'a, DB, Cartesian2d<RangedCoordf64, RangedCoordf64>>, DrawError> {
    let err = |e: &dyn std::fmt::Display| DrawError::of(e);
    let small = fonts.small;
    let mut builder = ChartBuilder::on(area);
    builder
        .margin(12)
        .margin_right(small * 2)
        .x_label_area_size(small * 3)
        .y_label_area_size(small * 5);
    if let Some(c) = mesh.caption {
        builder.caption(c, fonts.desc.clone());
    }
    let mut chart = builder.build_cartesian_2d(x, y).map_err(|e| err(&e))?;
    let mut m = chart.configure_mesh();
    m.x_desc(mesh.x_desc)
        .y_desc(mesh.y_desc)
        .x_label_formatter(&tick)
        .y_label_formatter(&tick)
        .label_style(fonts.label.clone())
        .axis_desc_style(fonts.desc.clone())
        .light_line_style(RGBColor(235, 235, 235))
        .bold_line_style(RGBColor(205, 205, 205));
    if let Some(n) = mesh.x_labels {
        m.x_labels(n);
    }
    if let Some(n) = mesh.y_labels {
        m.y_labels(n);
    }
    m.draw().map_err(|e| err(&e))?;
    Ok(chart)
}

/// The drawing shared by both backends.
fn draw<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    c: &ComponentCurve,
) -> Result<(), DrawError> {
    let err = |e: &dyn std::fmt::Display| DrawError::of(e);
    let (fonts, body) = frame(root, &title(c))?;
    let residual = c.residual_um();
    let (upper, lower) = match residual {
        Some(_) => {
            let (_, bh) = body.dim_in_pixel();
            let (u, l) = body.split_vertically((bh as f64 * 0.64) as u32);
            (u, Some(l))
        }
        None => (body, None),
    };

    let grid = &c.grid_um;
    // The moving axis spans exactly the grid (and samples); padding only if degenerate.
    let (x0, x1) = value_range(grid.iter().chain(c.samples.iter().map(|s| &s.0)).copied())
        .filter(|(lo, hi)| hi > lo)
        .unwrap_or_else(|| padded_range(grid.iter().copied()));
    let ys = c
        .reconstructed_um
        .iter()
        .chain(c.samples.iter().map(|s| &s.1))
        .chain(c.full_scan_um.iter().flatten())
        .chain(c.truth_um.iter().flatten())
        .copied();
    let (y0, y1) = padded_range(ys);
    // Head-room for the legend box (upper right) so it does not hide the curves.
    let legend_rows = 2
        + usize::from(c.full_scan_um.is_some())
        + usize::from(c.truth_um.is_some())
        + usize::from(c.u_um.len() == c.grid_um.len());
    let y1 = y1 + (y1 - y0) * 0.08 * legend_rows as f64;
    let x_labels = ((root.dim_in_pixel().0 / 110) as usize).max(3);

    let mut chart = xy_chart(
        &upper,
        &fonts,
        x0..x1,
        y0..y1,
        Mesh {
            x_desc: "position / µm",
            y_desc: "error / µm",
            x_labels: Some(x_labels),
            y_labels: None,
            caption: None,
        },
    )?;
    if let Some(full) = &c.full_scan_um {
        chart
            .draw_series(LineSeries::new(
                finite_points(grid, full),
                FULL.stroke_width(1),
            ))
            .map_err(|e| err(&e))?
            .label("full scan")
            .legend(legend_line(FULL, 1));
    }
    if let Some(truth) = &c.truth_um {
        chart
            .draw_series(LineSeries::new(
                finite_points(grid, truth),
                TRUTH.stroke_width(1),
            ))
            .map_err(|e| err(&e))?
            .label("truth")
            .legend(legend_line(TRUTH, 1));
    }
    if let Some(band) = band_polygon(grid, &c.reconstructed_um, &c.u_um) {
        chart
            .draw_series(std::iter::once(Polygon::new(
                band,
                RECON.mix(0.22).filled(),
            )))
            .map_err(|e| err(&e))?
            .label("±2u (k = 2)")
            .legend(|(x, y)| {
                Rectangle::new([(x, y - 4), (x + 20, y + 4)], RECON.mix(0.22).filled())
            });
    }
    chart
        .draw_series(LineSeries::new(
            finite_points(grid, &c.reconstructed_um),
            RECON.stroke_width(2),
        ))
        .map_err(|e| err(&e))?
        .label(format!("reconstruction ({})", c.method))
        .legend(legend_line(RECON, 2));
    let marker = if c.m() > 300 { 2 } else { 3 };
    chart
        .draw_series(
            c.samples
                .iter()
                .filter(|(x, y)| x.is_finite() && y.is_finite())
                .map(|&p| Circle::new(p, marker, SAMPLE.filled())),
        )
        .map_err(|e| err(&e))?
        .label(format!("samples (m = {})", c.m()))
        .legend(|(x, y)| Circle::new((x + 10, y), 3, SAMPLE.filled()));
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperRight)
        .background_style(WHITE.mix(0.85))
        .border_style(RGBColor(150, 150, 150))
        .label_font(fonts.label.clone())
        .draw()
        .map_err(|e| err(&e))?;

    if let (Some(lower), Some((res, against))) = (lower, residual) {
        let zeros = vec![0.0; grid.len()];
        let band = band_polygon(grid, &zeros, &c.u_um);
        let (r0, r1) = padded_range(
            res.iter()
                .copied()
                .chain([0.0])
                .chain(band.iter().flatten().map(|p| p.1)),
        );
        let mut chart = xy_chart(
            &lower,
            &fonts,
            x0..x1,
            r0..r1,
            Mesh {
                x_desc: "position / µm",
                y_desc: "residual / µm",
                x_labels: Some(x_labels),
                y_labels: Some(5),
                caption: Some(format!("residual: reconstruction − {against}")),
            },
        )?;
        chart
            .draw_series(LineSeries::new(
                [(x0, 0.0), (x1, 0.0)],
                RGBColor(120, 120, 120).stroke_width(1),
            ))
            .map_err(|e| err(&e))?;
        if let Some(band) = band {
            chart
                .draw_series(std::iter::once(Polygon::new(
                    band,
                    RECON.mix(0.22).filled(),
                )))
                .map_err(|e| err(&e))?;
        }
        chart
            .draw_series(LineSeries::new(
                finite_points(grid, &res),
                RECON.stroke_width(1),
            ))
            .map_err(|e| err(&e))?;
    }
    Ok(())
}

/// The outline of `center ± 2u` (upper edge forward, lower edge back), finite points only;
/// `None` without a band of the grid's length.
fn band_polygon(grid: &[f64], center: &[f64], u: &[f64]) -> Option<Vec<(f64, f64)>> {
    if u.len() != grid.len() || center.len() != grid.len() {
        return None;
    }
    let ok: Vec<usize> = (0..grid.len())
        .filter(|&i| grid[i].is_finite() && center[i].is_finite() && u[i].is_finite())
        .collect();
    if ok.len() < 2 {
        return None;
    }
    let upper = ok.iter().map(|&i| (grid[i], center[i] + 2.0 * u[i]));
    let lower = ok.iter().rev().map(|&i| (grid[i], center[i] - 2.0 * u[i]));
    Some(upper.chain(lower).collect())
}

#[cfg(test)]
mod tests {
    use super::super::testdata::curve;
    use super::*;

    #[test]
    fn svg_has_title_axis_labels_and_residual_panel() {
        let c = curve("ef_xx", 0.5);
        let svg = plot_svg(&c, &PlotOptions::default()).unwrap();
        assert!(svg.starts_with("<svg"), "{}", &svg[..80.min(svg.len())]);
        assert!(svg.contains(&title(&c)), "title missing");
        assert!(svg.contains("ef_xx — physics, m = 29, CV error 0.012 µm"));
        assert!(svg.contains("position / µm"));
        assert!(svg.contains("error / µm"));
        assert!(svg.contains("residual / µm"));
        assert!(svg.contains("residual: reconstruction − full scan"));
        assert!(svg.contains("<circle"), "sample markers missing");
        assert!(svg.contains("<polyline"), "lines missing");
    }

    #[test]
    fn the_band_is_drawn_when_the_curve_has_one() {
        let mut c = curve("ef_xx", 0.5);
        let plain = plot_svg(&c, &PlotOptions::default()).unwrap();
        assert!(!plain.contains("±2u"));
        c.u_um = vec![0.05; c.grid_um.len()];
        let svg = plot_svg(&c, &PlotOptions::default()).unwrap();
        assert!(svg.contains("±2u (k = 2)"), "legend entry missing");
        // Two filled outlines: around the curve and around the residual's zero.
        assert!(
            svg.matches("<polygon").count() >= 2,
            "band outlines missing"
        );
        assert!(!plot_png(&c, &PlotOptions::default()).unwrap().is_empty());
    }

    #[test]
    fn svg_without_references_has_no_residual_panel() {
        let mut c = curve("eb_yx", 0.0);
        c.full_scan_um = None;
        c.truth_um = None;
        c.cv_error_um = None;
        let svg = plot_svg(&c, &PlotOptions::default()).unwrap();
        assert!(!svg.contains("residual"));
        assert!(svg.contains("CV error n/a"));
        // Residual against truth when there is no full scan.
        let mut c = curve("eb_yx", 0.0);
        c.full_scan_um = None;
        let svg = plot_svg(&c, &PlotOptions::default()).unwrap();
        assert!(svg.contains("residual: reconstruction − truth"));
    }

    #[test]
    fn png_decodes_at_the_requested_size_with_text_and_drawing() {
        let c = curve("ef_xy", 0.0);
        let opts = PlotOptions {
            width: 900,
            height: 640,
        };
        let bytes = plot_png(&c, &opts).unwrap();
        let dec = png::Decoder::new(std::io::Cursor::new(bytes));
        let mut reader = dec.read_info().unwrap();
        let mut buf = vec![0; reader.output_buffer_size()];
        let info = reader.next_frame(&mut buf).unwrap();
        assert_eq!((info.width, info.height), (900, 640));
        assert_eq!(info.color_type, png::ColorType::Rgb);
        let px = |x: usize, y: usize| {
            let i = (y * 900 + x) * 3;
            [buf[i], buf[i + 1], buf[i + 2]]
        };
        let mut colours = std::collections::HashSet::new();
        for y in 0..640 {
            for x in 0..900 {
                colours.insert(px(x, y));
            }
        }
        assert!(colours.len() > 10, "flat image: {} colours", colours.len());
        // The title band (top 30 px) holds dark, antialiased glyph pixels: text was rasterised.
        let dark_in_title = (0..30)
            .flat_map(|y| (0..900).map(move |x| (x, y)))
            .filter(|&(x, y)| px(x, y).iter().all(|&v| v < 100))
            .count();
        assert!(
            dark_in_title > 200,
            "title not drawn: {dark_in_title} dark pixels"
        );
        // Reconstruction colour and sample colour both appear.
        assert!(colours.contains(&[RECON.0, RECON.1, RECON.2]));
        assert!(colours.contains(&[SAMPLE.0, SAMPLE.1, SAMPLE.2]));
    }

    #[test]
    fn tick_labels_have_no_float_noise() {
        assert_eq!(tick(&200.0), "200");
        assert_eq!(tick(&(0.1 + 0.2)), "0.3");
        assert_eq!(tick(&-0.02), "-0.02");
        assert_eq!(tick(&-0.0), "0");
    }

    #[test]
    fn non_finite_values_do_not_break_the_plot() {
        let mut c = curve("ef_xx", 0.0);
        c.reconstructed_um[3] = f64::NAN;
        c.samples.push((f64::INFINITY, 1.0));
        assert!(plot_png(&c, &PlotOptions::default()).is_ok());
        assert!(plot_svg(&c, &PlotOptions::default()).is_ok());
    }
}
