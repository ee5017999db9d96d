//! Results a user can act on: per-component plots (SVG and PNG), compensation lookup tables,
//! ISO 230-2 figures per moving axis and the paper's Table III as a plain-text summary.
//!
//! Input is one [`ComponentCurve`] per error component (`ef_xx`, `eb_xy`, ...; error =
//! measured - target, µm) as the campaign engine assembles it. [`build_report`] makes every file
//! in memory; [`write_report`] also writes them under a directory:
//!
//! | file | content |
//! |---|---|
//! | `plots/<comp>.svg`, `plots/<comp>.png` | samples, reconstruction, full scan; residual panel |
//! | `compensation_x.csv`, `compensation_y.csv` | lookup table at grid resolution, see [`compensation_csv`] |
//! | `iso230.json` | [`AxisIso230`] per moving axis |
//! | `plots/iso230_<axis>.svg`, `.png` | ISO 230-2 chart: x̄↑ x̄↓ per target, ±2s bands, A B E M R ([`iso_chart_files`]) |
//!
//! `csmetro verify ID` adds `verify/report.html` and `verify/verify_<axis>.svg|png` (before /
//! after with the pass line, [`verification`]) and links the first from `report.html`.
//!
//! The summary table ([`SummaryTable`], [`render_table`]) needs the campaign's timings, so the
//! engine renders it itself; so does `report.html` ([`html::report_html`]), which also needs
//! the campaign's log (the rig's identification, the attempts).
mod compensation;
pub mod heatmap;
pub mod html;
mod iso;
pub mod iso230_1;
mod isoplot;
mod plot;
pub use plot::DrawError;
mod table;
pub mod verification;

use std::path::Path;

use serde::Serialize;

use crate::types::{AxisId, Component};

pub use compensation::{compensation_columns, compensation_csv};
pub use iso::{iso230_axis, iso230_axis_with, iso_text, AxisIso230, IsoSource};
pub use isoplot::{iso_chart_png, iso_chart_svg};
pub use plot::{plot_png, plot_svg, register_fonts, PlotOptions, FONT_FAMILY};
pub use table::{
    format_hms, recovery_error, render_table, time_saved_pct, ErrorStats, SummaryRow, SummaryTable,
};

/// One error component as reconstructed by a campaign, with what it can be compared against.
/// All positions and errors in µm; error = measured - target.
#[derive(Debug, Clone, serde::Serialize)]
pub struct ComponentCurve {
    /// `ef_xx`, `eb_xy`, ... (see [`Component::name`]).
    pub component: String,
    /// Grid positions of the moving axis.
    pub grid_um: Vec<f64>,
    /// CS reconstruction at every grid point (error, µm).
    pub reconstructed_um: Vec<f64>,
    /// Reconstruction method, e.g. "physics", "bp", "pchip".
    pub method: String,
    /// Cross-validated error estimate, µm.
    pub cv_error_um: Option<f64>,
    /// CS measurements (position µm, error µm). Repeated positions are repeated approaches.
    pub samples: Vec<(f64, f64)>,
    /// Full scan on the same grid, when one was made.
    pub full_scan_um: Option<Vec<f64>>,
    /// The full scan's measurements (position µm, error µm), every cycle: ISO 230-2's
    /// measured figures come from these when they exist.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub full_scan_samples: Vec<(f64, f64)>,
    /// Simulator ground truth on the same grid, when known.
    pub truth_um: Option<Vec<f64>>,
    /// Pointwise standard uncertainty (k = 1) of `reconstructed_um`, µm, when computed.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub u_um: Vec<f64>,
}

impl ComponentCurve {
    /// The parsed component name, `None` when `component` is not one of the eight.
    pub fn parsed(&self) -> Option<Component> {
        Component::parse(&self.component)
    }

    /// Number of CS measurements (the paper's m).
    pub fn m(&self) -> usize {
        self.samples.len()
    }

    /// The curve the residual is taken against: the full scan, else the ground truth, with its
    /// label ("full scan" / "truth").
    pub fn reference(&self) -> Option<(&[f64], &'static str)> {
        self.full_scan_um
            .as_deref()
            .map(|f| (f, "full scan"))
            .or_else(|| self.truth_um.as_deref().map(|t| (t, "truth")))
    }

    /// Residual = reconstruction - reference (full scan, else truth) at every grid point.
    pub fn residual_um(&self) -> Option<(Vec<f64>, &'static str)> {
        self.reference().map(|(r, label)| {
            (
                self.reconstructed_um
                    .iter()
                    .zip(r)
                    .map(|(g, f)| g - f)
                    .collect(),
                label,
            )
        })
    }

    /// Checks that every per-grid-point vector has the grid's length and the grid is not empty.
    pub fn validate(&self) -> Result<(), ReportError> {
        let bad = |reason: String| {
            Err(ReportError::InvalidCurve {
                component: self.component.clone(),
                reason,
            })
        };
        let n = self.grid_um.len();
        if n == 0 {
            return bad("empty grid".into());
        }
        if self.reconstructed_um.len() != n {
            return bad(format!(
                "{} reconstructed values for {n} grid points",
                self.reconstructed_um.len()
            ));
        }
        for (what, v) in [("full scan", &self.full_scan_um), ("truth", &self.truth_um)] {
            if let Some(v) = v {
                if v.len() != n {
                    return bad(format!("{} {what} values for {n} grid points", v.len()));
                }
            }
        }
        Ok(())
    }
}

/// What can go wrong while making a report.
#[derive(Debug, thiserror::Error)]
pub enum ReportError {
    #[error("component {component}: {reason}")]
    InvalidCurve { component: String, reason: String },
    #[error("plot of {component}: {reason}")]
    Plot {
        component: String,
        reason: DrawError,
    },
    #[error("report i/o: {0}")]
    Io(#[from] std::io::Error),
    #[error("report json: {0}")]
    Json(#[from] serde_json::Error),
}

/// One report file: relative name (forward slashes), MIME type and content.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct ReportFile {
    pub name: String,
    pub content_type: &'static str,
    #[serde(skip)]
    pub bytes: Vec<u8>,
}

/// Settings of [`build_report`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ReportOptions {
    pub plot: PlotOptions,
    /// Targets closer than this are the same ISO 230-2 target, µm.
    pub iso_tol_um: f64,
    /// The ISO 230-2 uncertainty budget's inputs (campaign `[uncertainty]`).
    pub budget: crate::iso_uncertainty::BudgetInputs,
}

impl Default for ReportOptions {
    fn default() -> Self {
        Self {
            plot: PlotOptions::default(),
            iso_tol_um: 1e-3,
            budget: Default::default(),
        }
    }
}

/// A component name safe as a file name: anything but `[A-Za-z0-9_-]` becomes `_`.
/// `component` as a file or link name: `[A-Za-z0-9_-]`, others `_`.
pub(crate) fn file_stem(component: &str) -> String {
    let s: String = component
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '_' || c == '-' {
                c
            } else {
                '_'
            }
        })
        .collect();
    if s.is_empty() {
        "component".into()
    } else {
        s
    }
}

/// Every report file for `curves`, in memory: `plots/<comp>.svg` and `.png` per curve,
/// `compensation_x.csv` / `compensation_y.csv` for each axis that has a component, and
/// `iso230.json` (an object keyed by moving axis, `"x"` / `"y"`, of [`AxisIso230`]; axes without
/// a driving-direction component are absent).
pub fn build_report(
    curves: &[ComponentCurve],
    opts: &ReportOptions,
) -> Result<Vec<ReportFile>, ReportError> {
    report_files(curves, opts).map(|(files, _)| files)
}

/// [`build_report`] and the ISO 230-2 figures of each moving axis it wrote to `iso230.json`.
pub fn report_files(
    curves: &[ComponentCurve],
    opts: &ReportOptions,
) -> Result<(Vec<ReportFile>, Vec<AxisIso230>), ReportError> {
    let mut files = Vec::new();
    let mut figures = Vec::new();
    for c in curves {
        c.validate()?;
        let stem = file_stem(&c.component);
        files.push(ReportFile {
            name: format!("plots/{stem}.svg"),
            content_type: "image/svg+xml",
            bytes: plot_svg(c, &opts.plot)?.into_bytes(),
        });
        files.push(ReportFile {
            name: format!("plots/{stem}.png"),
            content_type: "image/png",
            bytes: plot_png(c, &opts.plot)?,
        });
    }
    let mut iso = serde_json::Map::new();
    for axis in [AxisId::X, AxisId::Y] {
        if let Some(csv) = compensation_csv(axis, curves)? {
            files.push(ReportFile {
                name: format!("compensation_{}.csv", axis.as_str()),
                content_type: "text/csv",
                bytes: csv.into_bytes(),
            });
        }
        if let Some(fig) = iso230_axis_with(axis, curves, opts.iso_tol_um, &opts.budget)? {
            iso.insert(axis.as_str().to_string(), serde_json::to_value(&fig)?);
            figures.push(fig);
        }
    }
    files.push(ReportFile {
        name: "iso230.json".into(),
        content_type: "application/json",
        bytes: serde_json::to_vec_pretty(&iso)?,
    });
    Ok((files, figures))
}

/// The ISO 230-2 chart of each axis in `figures`: `plots/iso230_<axis>.svg` and `.png`.
pub fn iso_chart_files(
    figures: &[AxisIso230],
    opts: &PlotOptions,
) -> Result<Vec<ReportFile>, ReportError> {
    let mut files = Vec::new();
    for f in figures {
        let stem = format!("plots/iso230_{}", file_stem(&f.axis));
        files.push(ReportFile {
            name: format!("{stem}.svg"),
            content_type: "image/svg+xml",
            bytes: iso_chart_svg(f, opts)?.into_bytes(),
        });
        files.push(ReportFile {
            name: format!("{stem}.png"),
            content_type: "image/png",
            bytes: iso_chart_png(f, opts)?,
        });
    }
    Ok(files)
}

/// [`build_report`], and writes every file under `dir` (created, with `plots/`, if missing).
/// Returns the same files so the caller can also store them.
pub fn write_report(
    dir: &Path,
    curves: &[ComponentCurve],
    opts: &ReportOptions,
) -> Result<Vec<ReportFile>, ReportError> {
    let files = build_report(curves, opts)?;
    for f in &files {
        let path = dir.join(&f.name);
        if let Some(parent) = path.parent() {
            std::fs::create_dir_all(parent)?;
        }
        std::fs::write(path, &f.bytes)?;
    }
    Ok(files)
}

#[cfg(test)]
pub(crate) mod testdata {
    use super::ComponentCurve;

    /// A paper-like curve on 0:5:1000: slow trend + 400 µm leadscrew cycle, direction offset
    /// `offset_um`; samples every 7th grid point, the full scan slightly noisy.
    pub(crate) fn curve(component: &str, offset_um: f64) -> ComponentCurve {
        let grid: Vec<f64> = (0..=200).map(|i| i as f64 * 5.0).collect();
        let f = |x: f64| {
            offset_um
                + 2e-3 * x
                + 0.8 * (2.0 * std::f64::consts::PI * x / 400.0).sin()
                + 0.1 * (x / 37.0).cos()
        };
        let truth: Vec<f64> = grid.iter().map(|&x| f(x)).collect();
        let full: Vec<f64> = truth
            .iter()
            .enumerate()
            .map(|(i, t)| t + 0.02 * ((i * 7919 % 13) as f64 - 6.0) / 6.0)
            .collect();
        let samples = grid.iter().step_by(7).map(|&x| (x, f(x))).collect();
        let reconstructed = grid
            .iter()
            .map(|&x| f(x) + 0.01 * (x / 50.0).sin())
            .collect();
        ComponentCurve {
            component: component.into(),
            grid_um: grid,
            reconstructed_um: reconstructed,
            method: "physics".into(),
            cv_error_um: Some(0.0123),
            samples,
            full_scan_um: Some(full),
            full_scan_samples: Vec::new(),
            truth_um: Some(truth),
            u_um: Vec::new(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::testdata::curve;
    use super::*;

    /// Set `CSMETRO_REPORT_TEST_OUT=DIR` to keep the files for a look.
    #[test]
    fn write_report_writes_every_file_it_returns() {
        let tmp = tempfile::tempdir().unwrap();
        let keep = std::env::var_os("CSMETRO_REPORT_TEST_OUT").map(std::path::PathBuf::from);
        let dir = keep.as_deref().unwrap_or(tmp.path());
        let curves = vec![
            curve("ef_xx", 1.0),
            curve("eb_xx", -1.0),
            curve("ef_xy", 0.0),
            curve("ef_yy", 0.5),
        ];
        let files = write_report(dir, &curves, &ReportOptions::default()).unwrap();
        let names: Vec<&str> = files.iter().map(|f| f.name.as_str()).collect();
        for want in [
            "plots/ef_xx.svg",
            "plots/ef_xx.png",
            "plots/eb_xx.png",
            "plots/ef_xy.svg",
            "plots/ef_yy.png",
            "compensation_x.csv",
            "compensation_y.csv",
            "iso230.json",
        ] {
            assert!(names.contains(&want), "{want} missing from {names:?}");
        }
        assert_eq!(files.len(), 4 * 2 + 3);
        for f in &files {
            let on_disk = std::fs::read(dir.join(&f.name)).unwrap();
            assert_eq!(on_disk, f.bytes, "{}", f.name);
            assert!(!f.bytes.is_empty());
        }
        let iso: serde_json::Value = serde_json::from_slice(
            &files
                .iter()
                .find(|f| f.name == "iso230.json")
                .unwrap()
                .bytes,
        )
        .unwrap();
        // x has both directions: reversal 2 µm; y only forward: no reversal.
        let bx = iso["x"]["reconstructed"]["b_um"].as_f64().unwrap();
        assert!((bx - 2.0).abs() < 1e-9, "{bx}");
        assert!(iso["y"]["reconstructed"]["b_um"].is_null());
    }

    #[test]
    fn mismatched_lengths_are_refused() {
        let mut c = curve("ef_xx", 0.0);
        c.full_scan_um.as_mut().unwrap().pop();
        assert!(matches!(
            build_report(&[c], &ReportOptions::default()),
            Err(ReportError::InvalidCurve { .. })
        ));
    }

    #[test]
    fn file_stems_cannot_escape_the_directory() {
        assert_eq!(file_stem("../etc/x"), "___etc_x");
        assert_eq!(file_stem("ef_xx"), "ef_xx");
    }
}
