//! The paper's Table III as a report: measurements, time and recovery error per stage and
//! design (full scan / CS), as a serializable table and an aligned plain-text rendering.
use serde::Serialize;

use crate::types::Phase;

/// Recovery error of a curve g against a reference f, µm.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct ErrorStats {
    /// Points compared.
    pub n: usize,
    /// mean |g - f|
    pub mean_abs_um: f64,
    /// max |g - f|
    pub max_abs_um: f64,
    /// Standard deviation of g - f (n - 1 denominator; 0 for one point).
    pub std_um: f64,
    /// Root mean square of g - f.
    pub rms_um: f64,
}

/// Recovery error of `recovered` (g) against `reference` (f), point by point. `None` when the
/// lengths differ or there is nothing to compare; pairs with a non-finite value are skipped.
pub fn recovery_error(recovered: &[f64], reference: &[f64]) -> Option<ErrorStats> {
    if recovered.len() != reference.len() {
        return None;
    }
    let d: Vec<f64> = recovered
        .iter()
        .zip(reference)
        .map(|(g, f)| g - f)
        .filter(|d| d.is_finite())
        .collect();
    if d.is_empty() {
        return None;
    }
    let n = d.len() as f64;
    let mean = d.iter().sum::<f64>() / n;
    let var = if d.len() > 1 {
        d.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0)
    } else {
        0.0
    };
    Some(ErrorStats {
        n: d.len(),
        mean_abs_um: d.iter().map(|x| x.abs()).sum::<f64>() / n,
        max_abs_um: d.iter().fold(0.0, |m, x| m.max(x.abs())),
        std_um: var.sqrt(),
        rms_um: (d.iter().map(|x| x * x).sum::<f64>() / n).sqrt(),
    })
}

/// Time saved by `new_s` against `full_s`, %; `None` unless `full_s > 0`.
pub fn time_saved_pct(full_s: f64, new_s: f64) -> Option<f64> {
    (full_s > 0.0 && new_s.is_finite()).then(|| 100.0 * (1.0 - new_s / full_s))
}

/// `h:mm:ss`, rounded to the second (`3:10:01`); `-` for a negative or non-finite time.
pub fn format_hms(s: f64) -> String {
    if !(s.is_finite() && s >= 0.0) {
        return "-".into();
    }
    let t = s.round() as u64;
    format!("{}:{:02}:{:02}", t / 3600, t / 60 % 60, t % 60)
}

/// One line of the summary: one stage (moving axis) and one design.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SummaryRow {
    /// e.g. "X stage".
    pub stage: String,
    /// Full scan or CS sample.
    pub phase: Phase,
    /// Reconstruction method of a CS row, shown as `CS (physics)`.
    pub method: Option<String>,
    /// Measurements taken (the paper's "meas.").
    pub measurements: usize,
    /// Physical acquisition time (moves, settling, frames), s.
    pub acquisition_s: f64,
    /// Processing (reconstruction) time, s.
    pub processing_s: f64,
    /// Recovery error against the full scan, when one exists.
    pub vs_full_scan: Option<ErrorStats>,
    /// Recovery error against the simulator's ground truth, when known.
    pub vs_truth: Option<ErrorStats>,
    /// Time saved against the stage's full scan, % of acquisition + processing.
    pub time_saved_pct: Option<f64>,
}

impl SummaryRow {
    /// `full scan`, `CS` or `CS (method)`.
    pub fn design(&self) -> String {
        match (self.phase, &self.method) {
            (Phase::Full, _) => "full scan".into(),
            (Phase::Cs, Some(m)) if !m.is_empty() => format!("CS ({m})"),
            (Phase::Cs, _) => "CS".into(),
            (Phase::Map, _) => "map".into(),
        }
    }

    /// Acquisition + processing, s.
    pub fn total_s(&self) -> f64 {
        self.acquisition_s + self.processing_s
    }
}

/// The summary table (the paper's Table III).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SummaryTable {
    pub title: String,
    pub rows: Vec<SummaryRow>,
}

impl SummaryTable {
    /// Fills `time_saved_pct` of every CS row that has none from the full-scan row of the same
    /// stage (acquisition + processing times).
    pub fn fill_time_saved(&mut self) {
        let full: Vec<(String, f64)> = self
            .rows
            .iter()
            .filter(|r| r.phase == Phase::Full)
            .map(|r| (r.stage.clone(), r.total_s()))
            .collect();
        for r in self.rows.iter_mut().filter(|r| r.phase == Phase::Cs) {
            if r.time_saved_pct.is_none() {
                if let Some((_, t)) = full.iter().find(|(s, _)| *s == r.stage) {
                    r.time_saved_pct = time_saved_pct(*t, r.total_s());
                }
            }
        }
    }
}

fn mean_max(e: &Option<ErrorStats>) -> String {
    match e {
        Some(e) => format!("{:.3} / {:.3}", e.mean_abs_um, e.max_abs_um),
        None => "-".into(),
    }
}

/// The table as aligned plain text: a title line, a header, a rule and one line per row;
/// columns separated by ` | `, text left-aligned and numbers right-aligned. Missing values
/// are `-`. Recovery errors are `mean / max` |g - f| in µm.
pub fn render_table(table: &SummaryTable) -> String {
    const HEADER: [&str; 9] = [
        "stage",
        "design",
        "meas.",
        "acquisition",
        "acq. (s)",
        "processing (s)",
        "vs full scan mean/max (µm)",
        "vs truth mean/max (µm)",
        "time saved (%)",
    ];
    const LEFT: [bool; 9] = [true, true, false, false, false, false, false, false, false];
    let cells: Vec<[String; 9]> = table
        .rows
        .iter()
        .map(|r| {
            [
                r.stage.clone(),
                r.design(),
                r.measurements.to_string(),
                format_hms(r.acquisition_s),
                format!("{:.1}", r.acquisition_s),
                format!("{:.2}", r.processing_s),
                mean_max(&r.vs_full_scan),
                mean_max(&r.vs_truth),
                r.time_saved_pct
                    .map_or_else(|| "-".into(), |p| format!("{p:.2}")),
            ]
        })
        .collect();
    let width = |i: usize| {
        cells
            .iter()
            .map(|c| c[i].chars().count())
            .chain([HEADER[i].chars().count()])
            .max()
            .unwrap_or(0)
    };
    let widths: Vec<usize> = (0..9).map(width).collect();
    let line = |cols: &[&str]| {
        cols.iter()
            .enumerate()
            .map(|(i, s)| {
                let pad = " ".repeat(widths[i] - s.chars().count());
                if LEFT[i] {
                    format!("{s}{pad}")
                } else {
                    format!("{pad}{s}")
                }
            })
            .collect::<Vec<_>>()
            .join(" | ")
    };
    let mut out = String::new();
    if !table.title.is_empty() {
        out.push_str(&table.title);
        out.push('\n');
    }
    out.push_str(&line(&HEADER));
    out.push('\n');
    out.push_str(
        &widths
            .iter()
            .map(|&w| "-".repeat(w))
            .collect::<Vec<_>>()
            .join("-+-"),
    );
    out.push('\n');
    for c in &cells {
        let refs: Vec<&str> = c.iter().map(String::as_str).collect();
        out.push_str(&line(&refs));
        out.push('\n');
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn row(stage: &str, phase: Phase, m: usize, acq: f64, proc_s: f64) -> SummaryRow {
        SummaryRow {
            stage: stage.into(),
            phase,
            method: (phase == Phase::Cs).then(|| "physics".into()),
            measurements: m,
            acquisition_s: acq,
            processing_s: proc_s,
            vs_full_scan: None,
            vs_truth: None,
            time_saved_pct: None,
        }
    }

    #[test]
    fn recovery_error_stats() {
        let g = [1.0, 2.0, 3.0, 4.0];
        let f = [1.5, 2.0, 2.0, 4.0];
        let e = recovery_error(&g, &f).unwrap();
        // d = -0.5, 0, 1, 0
        assert_eq!(e.n, 4);
        assert!((e.mean_abs_um - 0.375).abs() < 1e-12);
        assert_eq!(e.max_abs_um, 1.0);
        let mean = 0.125;
        let var = ((-0.5f64 - mean).powi(2) + 2.0 * mean * mean + (1.0f64 - mean).powi(2)) / 3.0;
        assert!((e.std_um - var.sqrt()).abs() < 1e-12);
        assert!((e.rms_um - (1.25f64 / 4.0).sqrt()).abs() < 1e-12);
        assert!(recovery_error(&g, &f[..3]).is_none());
        assert!(recovery_error(&[], &[]).is_none());
    }

    #[test]
    fn hms_formatting() {
        assert_eq!(format_hms(0.0), "0:00:00");
        assert_eq!(format_hms(3.17 * 3600.0), "3:10:12");
        assert_eq!(format_hms(59.6), "0:01:00");
        assert_eq!(format_hms(36000.0 + 61.0), "10:01:01");
        assert_eq!(format_hms(f64::NAN), "-");
    }

    #[test]
    fn table_is_aligned_and_shows_the_numbers() {
        let mut t = SummaryTable {
            title: "Time and recovery, one cycle".into(),
            rows: vec![
                row("X stage", Phase::Full, 3801, 11412.0, 30492.0),
                row("X stage", Phase::Cs, 600, 1800.0, 4824.0),
                row("Y stage", Phase::Full, 1681, 5040.0, 13464.0),
                row("Y stage", Phase::Cs, 300, 900.0, 2412.0),
            ],
        };
        t.rows[1].vs_full_scan = Some(ErrorStats {
            n: 1901,
            mean_abs_um: 0.1234,
            max_abs_um: 0.98765,
            std_um: 0.1,
            rms_um: 0.15,
        });
        t.rows[1].vs_truth = recovery_error(&[0.0, 0.5], &[0.0, 0.0]);
        t.fill_time_saved();
        // (1800 + 4824) / (11412 + 30492) = 0.15807...
        let saved = t.rows[1].time_saved_pct.unwrap();
        assert!((saved - 100.0 * (1.0 - 6624.0 / 41904.0)).abs() < 1e-9);
        assert!(t.rows[0].time_saved_pct.is_none());

        let s = render_table(&t);
        let lines: Vec<&str> = s.lines().collect();
        assert_eq!(lines.len(), 1 + 2 + 4, "{s}");
        assert_eq!(lines[0], "Time and recovery, one cycle");
        // Every line after the title has the same width and its separators at the same places.
        let bars = |l: &str| -> Vec<usize> {
            l.chars()
                .enumerate()
                .filter(|(_, c)| *c == '|' || *c == '+')
                .map(|(i, _)| i)
                .collect()
        };
        let w = lines[1].chars().count();
        for l in &lines[1..] {
            assert_eq!(l.chars().count(), w, "{s}");
            assert_eq!(bars(l), bars(lines[1]), "{s}");
            assert_eq!(bars(l).len(), 8);
        }
        let x_cs = lines[4];
        for want in [
            "X stage",
            "CS (physics)",
            " 600 ",
            "0:30:00",
            "1800.0",
            "4824.00",
            "0.123 / 0.988",
            "0.250 / 0.500",
            &format!("{saved:.2}"),
        ] {
            assert!(x_cs.contains(want), "{want:?} not in {x_cs:?}");
        }
        assert!(lines[3].contains("full scan") && lines[3].contains("3801"));
        assert!(lines[3].contains("3:10:12"));
        // Numbers right-aligned: the measurement column ends at the same place.
        let meas_end = |l: &str| l.split(" | ").nth(2).unwrap().to_string();
        assert_eq!(meas_end(lines[4]), "  600");
        assert_eq!(meas_end(lines[3]), " 3801");
        // (900 + 2412) / (5040 + 13464) = 0.178988...
        assert!(
            lines[6].contains("Y stage") && lines[6].ends_with(" 82.10"),
            "{s}"
        );
    }
}
