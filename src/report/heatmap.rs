//! Heat maps of a 2D field on the map grid (e_x, e_y, θ, residuals): one drawing routine, two
//! backends (SVG text, RGB bitmap encoded as PNG), like the component plots.
//!
//! A map of more cells than [`MAX_CELLS_DRAWN`] is drawn from block means (each drawn cell the
//! mean of the grid points under it), so a 1.6 M-point map gives a small SVG; the colour bar
//! spans the drawn values, symmetric about 0 when they change sign (diverging blue-white-red),
//! else a sequential ramp.
use plotters::coord::Shift;
use plotters::prelude::*;

use super::plot::{frame, render_png, render_svg, tick, DrawError, Fonts, PlotOptions};
use super::ReportError;
use crate::recon2d::Grid2;

/// Most cells drawn along x and along y.
pub const MAX_CELLS_DRAWN: (usize, usize) = (160, 80);

/// A field on a map grid, x fastest.
#[derive(Debug, Clone)]
pub struct HeatMap<'a> {
    /// Title, e.g. `e_x (forward)`.
    pub title: String,
    /// Colour bar label, e.g. `e_x / µm`.
    pub unit: String,
    pub grid: &'a Grid2,
    pub values: &'a [f64],
    /// Sample positions (µm) drawn as dots, if any.
    pub samples: &'a [(f64, f64)],
}

fn heat_error(h: &HeatMap<'_>, reason: DrawError) -> ReportError {
    ReportError::Plot {
        component: h.title.clone(),
        reason,
    }
}

/// Block means: (cells along x, along y, their values, x fastest). NaNs are skipped.
fn blocks(h: &HeatMap<'_>) -> (usize, usize, Vec<f64>) {
    let (nx, ny) = (h.grid.x.n, h.grid.y.n);
    let (bx, by) = (
        nx.div_ceil(MAX_CELLS_DRAWN.0).max(1),
        ny.div_ceil(MAX_CELLS_DRAWN.1).max(1),
    );
    let (cx, cy) = (nx.div_ceil(bx), ny.div_ceil(by));
    let mut sum = vec![0.0; cx * cy];
    let mut cnt = vec![0u32; cx * cy];
    for iy in 0..ny {
        for ix in 0..nx {
            let v = h.values[iy * nx + ix];
            if v.is_finite() {
                let k = (iy / by) * cx + ix / bx;
                sum[k] += v;
                cnt[k] += 1;
            }
        }
    }
    let v = sum
        .iter()
        .zip(&cnt)
        .map(|(s, &c)| if c > 0 { s / c as f64 } else { f64::NAN })
        .collect();
    (cx, cy, v)
}

/// Colour of `t` in [0, 1]: blue-white-red when diverging, else dark blue to yellow.
fn colour(t: f64, diverging: bool) -> RGBColor {
    let t = t.clamp(0.0, 1.0);
    let lerp = |a: u8, b: u8, s: f64| (a as f64 + (b as f64 - a as f64) * s).round() as u8;
    if diverging {
        if t < 0.5 {
            let s = t / 0.5;
            RGBColor(lerp(33, 255, s), lerp(102, 255, s), lerp(172, 255, s))
        } else {
            let s = (t - 0.5) / 0.5;
            RGBColor(lerp(255, 178, s), lerp(255, 24, s), lerp(255, 43, s))
        }
    } else {
        RGBColor(lerp(40, 250, t), lerp(30, 220, t), lerp(110, 40, t))
    }
}

/// The heat map as an SVG document.
pub fn heatmap_svg(h: &HeatMap<'_>, opts: &PlotOptions) -> Result<String, ReportError> {
    check(h)?;
    render_svg(opts, |root| draw(root, h)).map_err(|e| heat_error(h, e))
}

/// The heat map as a PNG file, drawn by the same code as [`heatmap_svg`].
pub fn heatmap_png(h: &HeatMap<'_>, opts: &PlotOptions) -> Result<Vec<u8>, ReportError> {
    check(h)?;
    render_png(opts, |root| draw(root, h)).map_err(|e| heat_error(h, e))
}

fn check(h: &HeatMap<'_>) -> Result<(), ReportError> {
    if h.values.len() != h.grid.len() || h.grid.is_empty() {
        return Err(heat_error(
            h,
            DrawError::GridSize {
                values: h.values.len(),
                nx: h.grid.x.n,
                ny: h.grid.y.n,
            },
        ));
    }
    Ok(())
}

fn draw<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    h: &HeatMap<'_>,
) -> Result<(), DrawError> {
    let err = |e: &dyn std::fmt::Display| DrawError::of(e);
    let (w, _) = root.dim_in_pixel();
    let (
        Fonts {
            small,
            label: label_font,
            desc: desc_font,
        },
        body,
    ) = frame(root, &h.title)?;
    let (plot, bar) = body.split_horizontally(w.saturating_sub(small * 13));
    let (cx, cy, v) = blocks(h);
    let (lo, hi) = v
        .iter()
        .filter(|x| x.is_finite())
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &x| {
            (a.min(x), b.max(x))
        });
    let (lo, hi) = if lo.is_finite() { (lo, hi) } else { (0.0, 1.0) };
    let diverging = lo < 0.0 && hi > 0.0;
    let (lo, hi) = if diverging {
        let a = lo.abs().max(hi.abs());
        (-a, a)
    } else if hi > lo {
        (lo, hi)
    } else {
        (lo - 0.5, hi + 0.5)
    };
    let t = |x: f64| (x - lo) / (hi - lo);
    let (gx, gy) = (&h.grid.x, &h.grid.y);
    let (x0, x1) = (gx.start_um, gx.end_um().max(gx.start_um + gx.step_um));
    let (y0, y1) = (gy.start_um, gy.end_um().max(gy.start_um + gy.step_um));
    let mut chart = ChartBuilder::on(&plot)
        .margin(12)
        .x_label_area_size(small * 3)
        .y_label_area_size(small * 5)
        .build_cartesian_2d(x0..x1, y0..y1)
        .map_err(|e| err(&e))?;
    chart
        .configure_mesh()
        .disable_mesh()
        .x_desc("x / µm")
        .y_desc("y / µm")
        .x_label_formatter(&tick)
        .y_label_formatter(&tick)
        .label_style(label_font.clone())
        .axis_desc_style(desc_font.clone())
        .draw()
        .map_err(|e| err(&e))?;
    let (wx, wy) = ((x1 - x0) / cx as f64, (y1 - y0) / cy as f64);
    chart
        .draw_series((0..cy).flat_map(|j| {
            let v = &v;
            (0..cx).filter_map(move |i| {
                let val = v[j * cx + i];
                val.is_finite().then(|| {
                    let (a, b) = (x0 + i as f64 * wx, y0 + j as f64 * wy);
                    Rectangle::new(
                        [(a, b), (a + wx, b + wy)],
                        colour(t(val), diverging).filled(),
                    )
                })
            })
        }))
        .map_err(|e| err(&e))?;
    if !h.samples.is_empty() && h.samples.len() <= 20_000 {
        chart
            .draw_series(
                h.samples
                    .iter()
                    .map(|&(x, y)| Circle::new((x, y), 1, BLACK.filled())),
            )
            .map_err(|e| err(&e))?;
    }
    // Colour bar.
    let mut cb = ChartBuilder::on(&bar)
        .margin(12)
        .margin_top(small * 2)
        .y_label_area_size(small * 8)
        .x_label_area_size(small * 3)
        .build_cartesian_2d(0.0..1.0, lo..hi)
        .map_err(|e| err(&e))?;
    cb.configure_mesh()
        .disable_mesh()
        .disable_x_axis()
        .y_desc(h.unit.as_str())
        .y_label_formatter(&tick)
        .label_style(label_font)
        .axis_desc_style(desc_font)
        .draw()
        .map_err(|e| err(&e))?;
    let steps = 64;
    cb.draw_series((0..steps).map(|k| {
        let a = lo + (hi - lo) * k as f64 / steps as f64;
        let b = lo + (hi - lo) * (k + 1) as f64 / steps as f64;
        Rectangle::new(
            [(0.0, a), (1.0, b)],
            colour(t((a + b) / 2.0), diverging).filled(),
        )
    }))
    .map_err(|e| err(&e))?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::grid::Grid;

    fn grid(nx: usize, ny: usize) -> Grid2 {
        Grid2::new(
            Grid::new(0.0, 5.0, 5.0 * (nx - 1) as f64).unwrap(),
            Grid::new(0.0, 5.0, 5.0 * (ny - 1) as f64).unwrap(),
        )
        .unwrap()
    }

    #[test]
    fn large_maps_are_drawn_from_block_means() {
        let g = grid(1901, 841);
        // v = ix: each drawn cell holds the mean of its block's ix.
        let v: Vec<f64> = (0..g.len()).map(|k| (k % 1901) as f64).collect();
        let h = HeatMap {
            title: "heat test".into(),
            unit: "µm".into(),
            grid: &g,
            values: &v,
            samples: &[],
        };
        let (cx, cy, b) = blocks(&h);
        assert!(
            cx <= MAX_CELLS_DRAWN.0 && cy <= MAX_CELLS_DRAWN.1,
            "{cx} {cy}"
        );
        let bx = 1901usize.div_ceil(MAX_CELLS_DRAWN.0);
        assert_eq!(b[0], (bx as f64 - 1.0) / 2.0);
        let svg = heatmap_svg(&h, &PlotOptions::default()).unwrap();
        assert!(svg.len() < 3 << 20, "{} bytes", svg.len());
        assert!(svg.contains("x / µm") && svg.contains("heat test"));
    }

    #[test]
    fn png_has_the_size_and_the_colours_of_both_signs() {
        let g = grid(30, 20);
        let v: Vec<f64> = (0..g.len()).map(|k| (k % 30) as f64 - 14.5).collect();
        let h = HeatMap {
            title: "e_x".into(),
            unit: "e_x / µm".into(),
            grid: &g,
            values: &v,
            samples: &[(10.0, 10.0)],
        };
        let png = heatmap_png(&h, &PlotOptions::default()).unwrap();
        let dec = png::Decoder::new(std::io::Cursor::new(png));
        let mut r = dec.read_info().unwrap();
        let mut buf = vec![0; r.output_buffer_size()];
        let info = r.next_frame(&mut buf).unwrap();
        assert_eq!((info.width, info.height), (1200, 800));
        let px: Vec<&[u8]> = buf.chunks(3).collect();
        let reddish = px.iter().any(|p| p[0] > 150 && p[1] < 80 && p[2] < 80);
        let bluish = px.iter().any(|p| p[2] > 140 && p[0] < 80);
        assert!(reddish && bluish, "both ends of the diverging scale drawn");
        let bad = HeatMap {
            values: &v[..10],
            ..h.clone()
        };
        assert!(heatmap_svg(&bad, &PlotOptions::default()).is_err());
    }
}
