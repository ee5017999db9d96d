//! Sample files: CSV with header `position_um,error_um`, read with errors that name file and line.
use std::path::Path;

use crate::grid::Grid;
use crate::noise::Scatter;

// The reconstruction's input type lives with the mathematics; re-exported so the readers'
// callers keep their paths.
pub use csmetro_metrology::samples::{nearest_steps, GridSamples};

/// Largest samples file read: a full grid of [`crate::grid::MAX_GRID_POINTS`] rows of ~40
/// bytes fits.
pub const MAX_SAMPLES_BYTES: u64 = 64 << 20;

/// Why a samples file (a curve's, a map's) was refused: one line naming the file, and the line.
#[derive(Debug, thiserror::Error)]
pub enum SamplesFileError {
    #[error("{path}: cannot read: {source}")]
    Read {
        path: String,
        source: crate::tomlpos::ReadError,
    },
    /// A line the parser refused, with its reason (the parsers, the metrology crate's among
    /// them, say it in text).
    #[error("{path}:{line}: {message}")]
    Line {
        path: String,
        line: usize,
        message: String,
    },
}

impl SamplesFileError {
    /// A bounded read of `path` that failed.
    pub(crate) fn read(path: &Path) -> impl FnOnce(crate::tomlpos::ReadError) -> Self + '_ {
        move |source| SamplesFileError::Read {
            path: path.display().to_string(),
            source,
        }
    }
    /// A parser's `(line, reason)` for `path`.
    pub(crate) fn line(path: &Path) -> impl FnOnce((usize, String)) -> Self + '_ {
        move |(line, message)| SamplesFileError::Line {
            path: path.display().to_string(),
            line,
            message,
        }
    }
}

/// Reads the samples of one error curve; every error is one line naming the file and line.
pub fn read_samples_csv(
    path: &Path,
    grid: &Grid,
    sel: &Select,
) -> Result<(GridSamples, SampleScatter), SamplesFileError> {
    let text = crate::tomlpos::read_bounded(path, MAX_SAMPLES_BYTES)
        .map_err(SamplesFileError::read(path))?;
    parse_samples_repeats(&text, grid, sel).map_err(SamplesFileError::line(path))
}

/// At most 40 characters of a field for an error message (a field may be megabytes long).
fn clip(s: &str) -> String {
    match s.char_indices().nth(40) {
        Some((i, _)) => format!("{}…", &s[..i]),
        None => s.to_string(),
    }
}

/// The samples layout every csmetro result writes (the results' `samples.csv`,
/// `verify/samples.csv`) and the samples readers (`csmetro reconstruct --samples`, `csmetro gap
/// --data`) accept. The results' first fifteen columns keep their order; the others were added
/// so that one file feeds every command (verify's and gap's names are among them). Per row, one
/// measured target of a sweep of `axis` (the moving axis) in `direction`:
/// `seq` commit order; `phase` cs | full | map; `cycle`; `target_x_um`, `target_y_um` the
/// target; `meas_x_um`, `meas_y_um` the decoded position; `theta_mrad`; `encoder_um` what the
/// controller reported; `time_s` physical time since the campaign started; `quality`,
/// `frames`, `rejected` the decode; `pass` before | after in a verification (moved without /
/// with the compensation), empty elsewhere; `run` the sweep number (2·cycle, + 1 for the full
/// scan or the `after` pass); `target_um` = `position_um` the moving axis' target; `error_um` =
/// measured - target along the moving axis; `frame_sd_x_um`, `frame_sd_y_um` the standard
/// deviation of the point's single frames (empty with one frame). Positions and errors in µm.
pub const LAYOUT: [&str; 22] = [
    "seq",
    "phase",
    "axis",
    "direction",
    "cycle",
    "target_x_um",
    "target_y_um",
    "meas_x_um",
    "meas_y_um",
    "theta_mrad",
    "encoder_um",
    "time_s",
    "quality",
    "frames",
    "rejected",
    "pass",
    "run",
    "target_um",
    "position_um",
    "error_um",
    "frame_sd_x_um",
    "frame_sd_y_um",
];

/// The header line of [`LAYOUT`].
pub fn layout_header() -> String {
    let mut h = LAYOUT.join(",");
    h.push('\n');
    h
}

/// One row of [`LAYOUT`]; `after`: `Some` in a verification (the pass), `None` elsewhere.
pub fn layout_row(r: &crate::types::SampleRecord, after: Option<bool>) -> String {
    let t = &r.target;
    let k = t.run;
    let extra = after.unwrap_or(k.phase == crate::types::Phase::Full);
    let sd = |i: usize| {
        r.frame_sd_um
            .map(|d| format!("{:.6}", d[i]))
            .unwrap_or_default()
    };
    format!(
        "{},{},{},{},{},{},{},{:.6},{:.6},{:.5},{:.6},{:.3},{:.4},{},{},{},{},{},{},{:.6},{},{}\n",
        t.seq,
        k.phase.as_str(),
        k.axis.as_str(),
        k.direction.as_str(),
        k.cycle,
        t.target_x_um,
        t.target_y_um,
        r.meas_x_um,
        r.meas_y_um,
        r.theta_mrad,
        r.encoder_um,
        r.time_s,
        r.quality,
        r.frames,
        r.rejected,
        match after {
            Some(true) => "after",
            Some(false) => "before",
            None => "",
        },
        2 * u64::from(k.cycle) + u64::from(extra),
        t.target_um(),
        t.target_um(),
        r.error_um(k.axis),
        sd(0),
        sd(1)
    )
}

/// Which curve of a samples file in [`LAYOUT`] to read (ignored for `position_um,error_um`).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Select {
    pub axis: Option<crate::types::AxisId>,
    pub direction: Option<crate::types::Direction>,
    pub phase: Option<crate::types::Phase>,
}

/// Parses `position_um,error_um` sample CSV text; errors carry the 1-based line number.
pub fn parse_samples_csv(text: &str, grid: &Grid) -> Result<GridSamples, (usize, String)> {
    parse_samples_with(text, grid, &Select::default())
}

/// Parses sample CSV text: `position_um,error_um` (one sample per position), or [`LAYOUT`]
/// (one curve picked by `sel`: the moving axis' error in one direction, `after` rows of a
/// verification left out since they were moved with the compensation; repeated cycles of a
/// position averaged). Errors carry the 1-based line number.
pub fn parse_samples_with(
    text: &str,
    grid: &Grid,
    sel: &Select,
) -> Result<GridSamples, (usize, String)> {
    parse_samples_repeats(text, grid, sel).map(|(s, _)| s)
}

/// What a samples file shows of its samples' noise ([`crate::noise`]).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct SampleScatter {
    /// The positions' repeated cycles about their mean.
    pub repeats: Scatter,
    /// The rows' frames (`frames`, `frame_sd_<axis>_um` of the moving axis in [`LAYOUT`]).
    pub frames: Scatter,
}

/// [`parse_samples_with`], and the scatter of the positions' repeated cycles and of their
/// frames (a sample's noise as the file shows it: [`crate::noise`]).
pub fn parse_samples_repeats(
    text: &str,
    grid: &Grid,
    sel: &Select,
) -> Result<(GridSamples, SampleScatter), (usize, String)> {
    use crate::types::{AxisId, Direction, Phase};
    let mut lines = text
        .lines()
        .enumerate()
        .filter(|(_, l)| !l.trim().is_empty());
    let (hline, header) = lines.next().ok_or((
        1,
        "empty file: expected header `position_um,error_um`".to_string(),
    ))?;
    let cols: Vec<String> = header
        .split(',')
        .map(|c| c.trim().trim_start_matches('\u{feff}').to_string())
        .collect();
    let col = |n: &str| cols.iter().position(|c| c == n);
    let (pc, ec) = match (col("position_um"), col("error_um")) {
        (Some(p), Some(e)) => (p, e),
        _ => {
            return Err((
                hline + 1,
                format!(
                    "missing header `position_um,error_um` (found {:?})",
                    clip(header.trim())
                ),
            ))
        }
    };
    // The full layout: rows of several curves and cycles.
    let layout = match (col("axis"), col("direction"), col("cycle")) {
        (Some(a), Some(d), Some(c)) => Some((a, d, c, col("phase"), col("pass"))),
        _ => None,
    };
    let frames_col = col("frames");
    let sd_col = [col("frame_sd_x_um"), col("frame_sd_y_um")];
    // Per grid position: (errors, first line, cycles seen, each row's frames and their sum of
    // squares about the row's mean).
    type Slot = (Vec<f64>, usize, Vec<u64>, Vec<(u32, Option<f64>)>);
    let mut at: Vec<Option<Slot>> = vec![None; grid.n];
    let mut curves: Vec<(AxisId, Direction)> = Vec::new();
    for (i, line) in lines {
        let lineno = i + 1;
        let fields: Vec<&str> = line.split(',').map(str::trim).collect();
        if fields.len() != cols.len() {
            return Err((
                lineno,
                format!("expected {} fields, found {}", cols.len(), fields.len()),
            ));
        }
        let num = |s: &str, what: &str| -> Result<f64, (usize, String)> {
            let v: f64 = s
                .parse()
                .map_err(|_| (lineno, format!("{what} {:?} is not a number", clip(s))))?;
            if !v.is_finite() {
                return Err((
                    lineno,
                    format!("{what} is {} (must be a finite number)", clip(s)),
                ));
            }
            Ok(v)
        };
        let mut cycle = None;
        let mut frames = (1, None);
        if let Some((ac, dc, cc, phc, pac)) = layout {
            if pac.is_some_and(|c| fields[c] == "after") {
                continue;
            }
            let axis = AxisId::parse(fields[ac]).ok_or_else(|| {
                (
                    lineno,
                    format!("axis {:?}: must be x or y", clip(fields[ac])),
                )
            })?;
            let dir = match fields[dc] {
                "forward" => Direction::Forward,
                "backward" => Direction::Backward,
                s => {
                    return Err((
                        lineno,
                        format!("direction {:?}: must be forward or backward", clip(s)),
                    ))
                }
            };
            let phase = match phc {
                Some(c) => Some(Phase::parse(fields[c]).ok_or_else(|| {
                    (
                        lineno,
                        format!("phase {:?}: must be cs, full or map", clip(fields[c])),
                    )
                })?),
                None => None,
            };
            if phase == Some(Phase::Map) {
                return Err((
                    lineno,
                    "samples of an XY map campaign: use csmetro reconstruct2d".into(),
                ));
            }
            if sel.axis.is_some_and(|a| a != axis)
                || sel.direction.is_some_and(|d| d != dir)
                || (sel.phase.is_some() && phase != sel.phase)
            {
                continue;
            }
            if !curves.contains(&(axis, dir)) {
                curves.push((axis, dir));
                if curves.len() > 1 {
                    let names: Vec<String> = curves
                        .iter()
                        .map(|(a, d)| format!("{} {}", a.as_str(), d.as_str()))
                        .collect();
                    return Err((
                        lineno,
                        format!(
                            "a second curve ({}): choose one with --axis and --direction",
                            names.join(", ")
                        ),
                    ));
                }
            }
            let c: u64 = fields[cc].parse().map_err(|_| {
                (
                    lineno,
                    format!("cycle {:?} is not a whole number", clip(fields[cc])),
                )
            })?;
            // A full scan repeats the CS targets in the same cycle: its own sweep.
            cycle = Some(2 * c + u64::from(phase == Some(Phase::Full)));
            if let (Some(fc), Some(sc)) = (frames_col, sd_col[axis as usize]) {
                let k: u32 = fields[fc].parse().map_err(|_| {
                    (
                        lineno,
                        format!("frames {:?} is not a whole number", clip(fields[fc])),
                    )
                })?;
                let sd = match fields[sc] {
                    "" => None,
                    f => {
                        let sd = num(f, cols[sc].as_str())?;
                        if sd < 0.0 {
                            return Err((lineno, format!("{} is negative", cols[sc])));
                        }
                        Some(f64::from(k.saturating_sub(1)) * sd * sd)
                    }
                };
                frames = (k.max(1), sd);
            }
        }
        let p = num(fields[pc], "position_um")?;
        let e = num(fields[ec], "error_um")?;
        let k = grid.index_of(p).ok_or_else(|| {
            (
                lineno,
                format!("position {p} µm is not on the grid {grid} (tolerance 1e-6 µm)"),
            )
        })?;
        match (&mut at[k], cycle) {
            (slot @ None, _) => {
                *slot = Some((vec![e], lineno, cycle.into_iter().collect(), vec![frames]))
            }
            // Another cycle of the same target: a repeat, averaged.
            (Some((errors, _, seen, rows)), Some(c)) if !seen.contains(&c) => {
                errors.push(e);
                seen.push(c);
                rows.push(frames);
            }
            (Some((_, first, _, _)), _) => {
                return Err((
                    lineno,
                    format!("duplicate position {p} µm (first at line {first})"),
                ))
            }
        }
    }
    let mut scatter = SampleScatter::default();
    let rows: Vec<(usize, f64)> = at
        .iter()
        .enumerate()
        .filter_map(|(k, s)| {
            let (errors, _, _, frames) = s.as_ref()?;
            let mean = errors.iter().sum::<f64>() / errors.len() as f64;
            let sum_sq = errors.iter().map(|e| (e - mean).powi(2)).sum::<f64>();
            scatter.repeats.add(
                u32::try_from(errors.len()).unwrap_or(u32::MAX),
                Some(sum_sq),
            );
            scatter.frames.add_rows(frames);
            Some((k, mean))
        })
        .collect();
    let m = rows.len();
    if m < 2 {
        return Err((
            text.lines().count().max(1),
            format!("need at least 2 samples, found {m}"),
        ));
    }
    Ok((
        GridSamples {
            idx: rows.iter().map(|r| r.0).collect(),
            values: rows.iter().map(|r| r.1).collect(),
        },
        scatter,
    ))
}

/// Writes `position_um,error_um` at each position.
pub fn write_curve_csv(path: &Path, positions: &[f64], values: &[f64]) -> std::io::Result<()> {
    write_curve_u_csv(path, positions, values, &[])
}

/// Writes `position_um,error_um,u_um` (the curve's pointwise standard uncertainty, k = 1) at
/// each position; without a `u` of the positions' length, `position_um,error_um` only.
pub fn write_curve_u_csv(
    path: &Path,
    positions: &[f64],
    values: &[f64],
    u: &[f64],
) -> std::io::Result<()> {
    use std::io::Write;
    let mut out = std::io::BufWriter::new(std::fs::File::create(path)?);
    out.write_all(curve_csv(positions, values, u).as_bytes())?;
    out.flush()
}

/// The text of [`write_curve_u_csv`].
pub fn curve_csv(positions: &[f64], values: &[f64], u: &[f64]) -> String {
    let with_u = u.len() == positions.len();
    let mut s = String::from(if with_u {
        "position_um,error_um,u_um\n"
    } else {
        "position_um,error_um\n"
    });
    for (i, (p, v)) in positions.iter().zip(values).enumerate() {
        if with_u {
            s.push_str(&format!("{p},{v},{}\n", u[i]));
        } else {
            s.push_str(&format!("{p},{v}\n"));
        }
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    fn grid() -> Grid {
        "0:5:100".parse().unwrap()
    }

    #[test]
    fn parses_and_sorts() {
        let s = parse_samples_csv("position_um,error_um\n10,0.5\n0,-1\n", &grid()).unwrap();
        assert_eq!(s.idx, vec![0, 2]);
        assert_eq!(s.values, vec![-1.0, 0.5]);
    }

    #[test]
    fn errors_name_the_line() {
        let g = grid();
        let e = parse_samples_csv("position_um,error_um\n0,1\n5,NaN\n", &g).unwrap_err();
        assert_eq!(e.0, 3);
        let e = parse_samples_csv("position_um,error_um\n0,1\n0,2\n", &g).unwrap_err();
        assert_eq!(e.0, 3);
        assert!(e.1.contains("duplicate"));
        let e = parse_samples_csv("position_um,error_um\n0,1\n7,2\n", &g).unwrap_err();
        assert!(e.1.contains("not on the grid"), "{}", e.1);
        let e = parse_samples_csv("0,1\n5,2\n", &g).unwrap_err();
        assert!(e.1.contains("header"));
        let e = parse_samples_csv("position_um,error_um\n0,1\n", &g).unwrap_err();
        assert!(e.1.contains("at least 2"));
    }

    #[test]
    fn the_layout_picks_one_curve_and_averages_repeated_cycles() {
        use crate::types::{AxisId, Direction};
        let g = grid();
        let h = layout_header();
        let row = |phase: &str, dir: &str, cycle: u32, pass: &str, p: f64, e: f64| {
            format!(
                "0,{phase},x,{dir},{cycle},{p},0,{},0,0,{p},0,1,1,0,{pass},0,{p},{p},{e},,\n",
                p + e
            )
        };
        let text = format!(
            "{h}{}{}{}{}{}",
            row("cs", "forward", 0, "", 10.0, 1.0),
            row("cs", "forward", 1, "", 10.0, 2.0),
            row("cs", "forward", 0, "", 20.0, 3.0),
            row("cs", "backward", 0, "", 10.0, 9.0),
            row("full", "forward", 0, "after", 5.0, 7.0),
        );
        // Two curves: one must be chosen.
        let e = parse_samples_csv(&text, &g).unwrap_err();
        assert!(e.1.contains("x forward, x backward") && e.0 == 5, "{e:?}");
        let fwd = Select {
            axis: Some(AxisId::X),
            direction: Some(Direction::Forward),
            phase: None,
        };
        let (s, rep) = parse_samples_repeats(&text, &g, &fwd).unwrap();
        // 10 µm: cycles 0 and 1 averaged; the `after` row is left out.
        assert_eq!(s.idx, vec![2, 4]);
        assert_eq!(s.values, vec![1.5, 3.0]);
        // Their scatter: (1 − 1.5)² + (2 − 1.5)² on one degree of freedom; the samples average
        // 2 and 1 readings. A sample's σ: √(0.5 · (1/2 + 1)/2).
        let rep = rep.repeats;
        assert_eq!((rep.sum_sq, rep.dof, rep.mean_inv_k()), (0.5, 1, 0.75));
        assert!((rep.sample_sigma_um().unwrap() - 0.375f64.sqrt()).abs() < 1e-12);
        // The same cycle twice is a copied row.
        let dup = format!("{text}{}", row("cs", "forward", 1, "", 10.0, 2.0));
        let e = parse_samples_with(&dup, &g, &fwd).unwrap_err();
        assert!(e.1.contains("duplicate") && e.0 == 7, "{e:?}");
        // Each row's frames: `frames` and the moving axis's `frame_sd_x_um` (y's is another
        // coordinate). 10 µm: 4 and 2 frames over two cycles, 20 µm: one frame (no scatter).
        let framed = |cycle: u32, p: f64, k: u32, sd: &str| {
            format!("0,cs,x,forward,{cycle},{p},0,{p},0,0,{p},0,1,{k},0,,0,{p},{p},0,{sd},9\n")
        };
        let text = format!(
            "{h}{}{}{}",
            framed(0, 10.0, 4, "0.1"),
            framed(1, 10.0, 2, "0.2"),
            framed(0, 20.0, 1, "")
        );
        let (_, sc) = parse_samples_repeats(&text, &g, &fwd).unwrap();
        let f = sc.frames;
        // Σ (k − 1)·s² = 3 · 0.01 + 1 · 0.04 on 4 degrees of freedom; a position's variance
        // σ²·Σ(1/k)/r²: (1/4 + 1/2)/4 at 10 µm and 1 at 20 µm.
        assert!((f.sum_sq - 0.07).abs() < 1e-12 && f.dof == 4, "{f:?}");
        assert!(
            (f.mean_inv_k() - (0.1875 + 1.0) / 2.0).abs() < 1e-12,
            "{f:?}"
        );
        let neg = format!("{h}{}", framed(0, 10.0, 4, "-0.1"));
        let e = parse_samples_with(&neg, &g, &fwd).unwrap_err();
        assert!(
            e.1.contains("frame_sd_x_um is negative") && e.0 == 2,
            "{e:?}"
        );
        let bad = format!("{h}{}", row("cs", "sideways", 0, "", 10.0, 1.0));
        assert!(parse_samples_with(&bad, &g, &fwd)
            .unwrap_err()
            .1
            .contains("direction"));
    }
}
