//! Sample files: CSV with header `position_um,error_um`, read with errors that name file and line.
use std::path::Path;

use crate::grid::Grid;

/// Samples of an error curve on a grid: grid indices (ascending) and errors (µm).
#[derive(Debug, Clone, PartialEq)]
pub struct GridSamples {
    pub idx: Vec<usize>,
    pub values: Vec<f64>,
}

impl GridSamples {
    pub fn len(&self) -> usize {
        self.idx.len()
    }
    pub fn is_empty(&self) -> bool {
        self.idx.is_empty()
    }
}

/// Grid steps from `i` to the nearest of the ascending indices `idx` (`usize::MAX` when empty).
pub fn nearest_steps(idx: &[usize], i: usize) -> usize {
    let j = idx.partition_point(|&x| x < i);
    let above = idx.get(j).map(|&x| x - i);
    let below = j.checked_sub(1).map(|j| i - idx[j]);
    above.into_iter().chain(below).min().unwrap_or(usize::MAX)
}

/// Largest samples file read: a full grid of [`crate::grid::MAX_GRID_POINTS`] rows of ~40
/// bytes fits.
pub const MAX_SAMPLES_BYTES: u64 = 64 << 20;

/// Reads `position_um,error_um` rows; every error is one line naming the file and line.
pub fn read_samples_csv(path: &Path, grid: &Grid) -> Result<GridSamples, String> {
    let name = path.display();
    let text = crate::tomlpos::read_bounded(path, MAX_SAMPLES_BYTES)
        .map_err(|e| format!("{name}: cannot read: {e}"))?;
    parse_samples_csv(&text, grid).map_err(|(line, msg)| format!("{name}:{line}: {msg}"))
}

/// At most 40 characters of a field for an error message (a field may be megabytes long).
fn clip(s: &str) -> String {
    match s.char_indices().nth(40) {
        Some((i, _)) => format!("{}…", &s[..i]),
        None => s.to_string(),
    }
}

/// Parses sample CSV text; errors carry the 1-based line number.
pub fn parse_samples_csv(text: &str, grid: &Grid) -> Result<GridSamples, (usize, String)> {
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
    let pos_col = cols.iter().position(|c| c == "position_um");
    let err_col = cols.iter().position(|c| c == "error_um");
    let (pc, ec) = match (pos_col, err_col) {
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
    let mut rows: Vec<(usize, f64, usize)> = Vec::new();
    let mut seen = vec![0usize; grid.n];
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
        let p = num(fields[pc], "position_um")?;
        let e = num(fields[ec], "error_um")?;
        let k = grid.index_of(p).ok_or_else(|| {
            (
                lineno,
                format!("position {p} µm is not on the grid {grid} (tolerance 1e-6 µm)"),
            )
        })?;
        if seen[k] != 0 {
            return Err((
                lineno,
                format!("duplicate position {p} µm (first at line {})", seen[k]),
            ));
        }
        seen[k] = lineno;
        rows.push((k, e, lineno));
    }
    rows.sort_by_key(|r| r.0);
    let m = rows.len();
    if m < 2 {
        return Err((
            text.lines().count().max(1),
            format!("need at least 2 samples, found {m}"),
        ));
    }
    Ok(GridSamples {
        idx: rows.iter().map(|r| r.0).collect(),
        values: rows.iter().map(|r| r.1).collect(),
    })
}

/// Writes `position_um,error_um` at each position.
pub fn write_curve_csv(path: &Path, positions: &[f64], values: &[f64]) -> std::io::Result<()> {
    use std::io::Write;
    let mut out = std::io::BufWriter::new(std::fs::File::create(path)?);
    writeln!(out, "position_um,error_um")?;
    for (p, v) in positions.iter().zip(values) {
        writeln!(out, "{p},{v}")?;
    }
    out.flush()
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
}
