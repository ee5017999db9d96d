//! Compensation from an XY error map: `compensation_map_<dir>.csv` of a `[map]` campaign
//! (`x_um,y_um,corr_x_um,corr_y_um` at every grid point, x fastest, corr = −error when the point
//! is approached in `<dir>` on both axes, see [`crate::campaign::map::compensation_map_csv`]).
//!
//! Both axes are corrected together: e(x, y) = (e_x, e_y) is interpolated between the grid
//! points (bicubic, see [`MapTable::error_at`]), and the commands c = (c_x, c_y) with c + e(c) = wanted are found by fixed-point
//! steps c ← wanted − e(c) (a contraction: the map's slopes are ≪ 1). A wanted point outside the
//! map's rectangle is refused, never clipped.
use std::path::Path;

use super::{parse_num, CommandError, TableError, MAX_CORRECTION_UM, MAX_TABLE_BYTES};
use crate::types::{AxisId, Direction};

/// The header of a map compensation table.
pub const MAP_HEADER: &str = "x_um,y_um,corr_x_um,corr_y_um";
const MAX_STEPS: usize = 30;
const CONVERGED_UM: f64 = 1e-7;

/// One direction's map: errors (not corrections) at every grid point, x fastest.
#[derive(Debug, Clone)]
pub struct MapTable {
    pub direction: Direction,
    /// Grid positions, µm, strictly increasing.
    pub xs: Vec<f64>,
    pub ys: Vec<f64>,
    /// e_x, e_y at (xs[i], ys[j]) as index j·nx + i, µm.
    pub ex: Vec<f64>,
    pub ey: Vec<f64>,
    pub origin: String,
}

fn increasing(v: &[f64]) -> bool {
    v.windows(2).all(|w| w[1] > w[0])
}

impl MapTable {
    /// Parses a map compensation table measured approaching in `direction`.
    pub fn parse(direction: Direction, text: &str, origin: &str) -> Result<MapTable, TableError> {
        let err = |line: usize, message: String| TableError {
            origin: origin.to_string(),
            line,
            message,
        };
        let mut lines = text.lines().enumerate().map(|(i, l)| (i + 1, l));
        let (hl, header) = lines
            .next()
            .ok_or_else(|| err(0, "empty file: no header".into()))?;
        if header.trim_end_matches('\r').trim() != MAP_HEADER {
            return Err(err(
                hl,
                format!("not a map compensation table: the header must be {MAP_HEADER}"),
            ));
        }
        let mut rows: Vec<(usize, [f64; 4])> = Vec::new();
        for (ln, line) in lines {
            let line = line.trim_end_matches('\r');
            if line.trim().is_empty() {
                continue;
            }
            let cells: Vec<&str> = line.split(',').collect();
            if cells.len() != 4 {
                return Err(err(ln, format!("{} fields, the header has 4", cells.len())));
            }
            let mut v = [0.0; 4];
            for (k, cell) in cells.iter().enumerate() {
                let name = ["x_um", "y_um", "corr_x_um", "corr_y_um"][k];
                v[k] = parse_num(cell).map_err(|m| err(ln, format!("{name}: {m}")))?;
                if k >= 2 && v[k].abs() > MAX_CORRECTION_UM {
                    return Err(err(
                        ln,
                        format!("{name} {} µm is larger than {MAX_CORRECTION_UM} µm: not an error map of this stage", v[k]),
                    ));
                }
            }
            rows.push((ln, v));
        }
        if rows.is_empty() {
            return Err(err(0, "no grid points".into()));
        }
        // The first row of the grid: every point at the first y.
        let y0 = rows[0].1[1];
        let nx = rows.iter().take_while(|(_, r)| r[1] == y0).count();
        let xs: Vec<f64> = rows[..nx].iter().map(|(_, r)| r[0]).collect();
        if let Some(w) = (1..nx).find(|&i| xs[i] <= xs[i - 1]) {
            return Err(err(
                rows[w].0,
                format!(
                    "x_um {} does not increase along the row (previous {}): the table is x fastest",
                    xs[w],
                    xs[w - 1]
                ),
            ));
        }
        if !rows.len().is_multiple_of(nx) {
            let (ln, _) = rows[rows.len() - 1];
            return Err(err(
                ln,
                format!(
                    "{} grid points are not whole rows of {nx} points",
                    rows.len()
                ),
            ));
        }
        let ny = rows.len() / nx;
        if nx < 2 || ny < 2 {
            return Err(err(
                0,
                format!("a {nx} x {ny} grid: a map needs at least 2 x 2 points"),
            ));
        }
        let mut ys = Vec::with_capacity(ny);
        let (mut ex, mut ey) = (
            Vec::with_capacity(rows.len()),
            Vec::with_capacity(rows.len()),
        );
        for (k, (ln, r)) in rows.iter().enumerate() {
            let (i, j) = (k % nx, k / nx);
            if i == 0 {
                if let Some(&prev) = ys.last() {
                    if r[1] <= prev {
                        return Err(err(
                            *ln,
                            format!(
                                "y_um {} does not increase from row to row (previous {prev})",
                                r[1]
                            ),
                        ));
                    }
                }
                ys.push(r[1]);
            }
            if r[0] != xs[i] || r[1] != ys[j] {
                return Err(err(
                    *ln,
                    format!(
                        "({}, {}) is not grid point ({}, {}): the table must hold every point of a rectangular grid, x fastest",
                        r[0], r[1], xs[i], ys[j]
                    ),
                ));
            }
            ex.push(-r[2]);
            ey.push(-r[3]);
        }
        debug_assert!(increasing(&ys));
        // Evenly spaced (the cubic interpolation's weights assume it), as a map grid is.
        for (name, v, row_of) in [("x_um", &xs, 0usize), ("y_um", &ys, 1)] {
            let h = v[1] - v[0];
            if let Some(k) =
                (2..v.len()).find(|&k| ((v[k] - v[k - 1]) - h).abs() > 1e-6 * h.abs().max(1.0))
            {
                let r = if row_of == 0 { k } else { k * nx };
                return Err(err(
                    rows[r].0,
                    format!("{name} {} breaks the grid's even spacing of {h} µm", v[k]),
                ));
            }
        }
        Ok(MapTable {
            direction,
            xs,
            ys,
            ex,
            ey,
            origin: origin.to_string(),
        })
    }

    /// Reads and parses a table file (regular file, bounded size).
    pub fn load(direction: Direction, path: &Path) -> Result<MapTable, TableError> {
        let (origin, text) = super::read_table_file(path)?;
        MapTable::parse(direction, &text, &origin)
    }

    /// The map's rectangle: ((x_lo, x_hi), (y_lo, y_hi)), µm.
    pub fn span_um(&self) -> [(f64, f64); 2] {
        [
            (self.xs[0], self.xs[self.xs.len() - 1]),
            (self.ys[0], self.ys[self.ys.len() - 1]),
        ]
    }

    /// (e_x, e_y) at commanded (x, y): bicubic (Catmull-Rom, separable, on the 4 × 4 grid
    /// points around (x, y); beyond an edge the grid is continued linearly); positions outside
    /// the grid take the edge. Bilinear interpolation would lose up to 30 % of a leadscrew
    /// harmonic of 4 grid steps' period between the grid points; the cubic loses about 12 %
    /// (and under 1 % of one of 8 steps).
    pub fn error_at(&self, x: f64, y: f64) -> (f64, f64) {
        let cell = |v: &[f64], p: f64| {
            let i = v.partition_point(|&q| q <= p).clamp(1, v.len() - 1);
            let t = ((p - v[i - 1]) / (v[i] - v[i - 1])).clamp(0.0, 1.0);
            (i - 1, t)
        };
        // Catmull-Rom weights of points i-1, i, i+1, i+2 at fraction t of cell [i, i+1].
        let w = |t: f64| {
            let (t2, t3) = (t * t, t * t * t);
            [
                0.5 * (-t3 + 2.0 * t2 - t),
                0.5 * (3.0 * t3 - 5.0 * t2 + 2.0),
                0.5 * (-3.0 * t3 + 4.0 * t2 + t),
                0.5 * (t3 - t2),
            ]
        };
        let (i, tx) = cell(&self.xs, x);
        let (j, ty) = cell(&self.ys, y);
        let (wx, wy) = (w(tx), w(ty));
        let (nx, ny) = (self.xs.len() as isize, self.ys.len() as isize);
        let at = |f: &[f64]| {
            // f at grid (a, b), continued linearly beyond the edges.
            let row = |a: isize, b: usize| -> f64 {
                let g = |a: isize| f[b * nx as usize + a as usize];
                if a < 0 {
                    2.0 * g(0) - g(1)
                } else if a >= nx {
                    2.0 * g(nx - 1) - g(nx - 2)
                } else {
                    g(a)
                }
            };
            let along_x = |b: usize| {
                (0..4)
                    .map(|k| wx[k] * row(i as isize - 1 + k as isize, b))
                    .sum::<f64>()
            };
            let col = |b: isize| -> f64 {
                if b < 0 {
                    2.0 * along_x(0) - along_x(1)
                } else if b >= ny {
                    2.0 * along_x(ny as usize - 1) - along_x(ny as usize - 2)
                } else {
                    along_x(b as usize)
                }
            };
            (0..4)
                .map(|k| wy[k] * col(j as isize - 1 + k as isize))
                .sum::<f64>()
        };
        (at(&self.ex), at(&self.ey))
    }

    /// The commands (c_x, c_y) with c + e(c) = `wanted` (both axes approached in the map's
    /// direction). A wanted point outside the map is refused; a command just beyond its edge
    /// (up to one grid step, the edge value held) is accepted, as for the line tables.
    pub fn command(&self, wanted: [f64; 2]) -> Result<[f64; 2], CommandError> {
        let span = self.span_um();
        for (k, axis) in [AxisId::X, AxisId::Y].into_iter().enumerate() {
            let w = wanted[k];
            if !w.is_finite() {
                return Err(CommandError::NotFinite { axis, wanted_um: w });
            }
            let (lo, hi) = span[k];
            if w < lo - 1e-9 || w > hi + 1e-9 {
                return Err(CommandError::OutsideTable {
                    axis,
                    wanted_um: w,
                    lo_um: lo,
                    hi_um: hi,
                });
            }
        }
        let mut c = wanted;
        for _ in 0..MAX_STEPS {
            let (ex, ey) = self.error_at(c[0], c[1]);
            let next = [wanted[0] - ex, wanted[1] - ey];
            let change = (next[0] - c[0]).abs().max((next[1] - c[1]).abs());
            c = next;
            if change <= CONVERGED_UM {
                for (k, (axis, g)) in [(AxisId::X, &self.xs), (AxisId::Y, &self.ys)]
                    .into_iter()
                    .enumerate()
                {
                    let (lo, hi) = span[k];
                    let (m_lo, m_hi) = (g[1] - g[0], g[g.len() - 1] - g[g.len() - 2]);
                    if c[k] < lo - m_lo || c[k] > hi + m_hi {
                        return Err(CommandError::OutsideTable {
                            axis,
                            wanted_um: wanted[k],
                            lo_um: lo,
                            hi_um: hi,
                        });
                    }
                }
                return Ok(c);
            }
        }
        Err(CommandError::NoConvergence {
            axis: AxisId::X,
            wanted_um: wanted[0],
        })
    }

    /// Bound on the interpolation's own error between grid points, per axis (e_x, e_y), µm:
    /// the bilinear one, |f − bilinear| ≤ (h_x² max|f_xx| + h_y² max|f_yy|) / 8 per cell, with
    /// the second derivatives taken from the map's second differences (the largest over the
    /// map). The cubic interpolation used does better on every period the grid resolves (see
    /// [`MapTable::error_at`]): a conservative bound.
    pub fn interpolation_bound_um(&self) -> [f64; 2] {
        let (nx, ny) = (self.xs.len(), self.ys.len());
        [&self.ex, &self.ey].map(|f| {
            let mut dx: f64 = 0.0;
            let mut dy: f64 = 0.0;
            for j in 0..ny {
                for i in 0..nx {
                    let k = j * nx + i;
                    if i > 0 && i + 1 < nx {
                        // Second difference scaled to the local step: h² f'' ≈ this.
                        let (h0, h1) = (self.xs[i] - self.xs[i - 1], self.xs[i + 1] - self.xs[i]);
                        let d2 = 2.0 * (h0 * f[k + 1] - (h0 + h1) * f[k] + h1 * f[k - 1])
                            / (h0 * h1 * (h0 + h1));
                        dx = dx.max(d2.abs() * h0.max(h1).powi(2));
                    }
                    if j > 0 && j + 1 < ny {
                        let (h0, h1) = (self.ys[j] - self.ys[j - 1], self.ys[j + 1] - self.ys[j]);
                        let d2 = 2.0 * (h0 * f[k + nx] - (h0 + h1) * f[k] + h1 * f[k - nx])
                            / (h0 * h1 * (h0 + h1));
                        dy = dy.max(d2.abs() * h0.max(h1).powi(2));
                    }
                }
            }
            (dx + dy) / 8.0
        })
    }
}

/// A map campaign's compensation: one map per measured direction, and the reconstruction's
/// cross-validation error per direction when the results say (`summary.json`'s
/// `map.runs[].cv_error_um`: held-out RMS over e_x and e_y, sensor noise included).
#[derive(Debug, Clone, Default)]
pub struct MapCompensation {
    pub forward: Option<MapTable>,
    pub backward: Option<MapTable>,
    pub cv_error_um: [Option<f64>; 2],
    /// The map's own ISO 230-1 squareness per direction (whole grid, `map.runs[].iso230_1`),
    /// µrad, when the results say.
    pub squareness_urad: [Option<f64>; 2],
}

impl MapCompensation {
    /// The direction whose map serves an approach in `d`: its own when measured, else the other.
    pub fn served_direction(&self, d: Direction) -> Direction {
        match (d, &self.forward, &self.backward) {
            (Direction::Forward, None, Some(_)) => Direction::Backward,
            (Direction::Backward, Some(_), None) => Direction::Forward,
            _ => d,
        }
    }

    pub fn table(&self, d: Direction) -> Option<&MapTable> {
        match self.served_direction(d) {
            Direction::Forward => self.forward.as_ref(),
            Direction::Backward => self.backward.as_ref(),
        }
    }

    /// The map of the served direction (there is at least one).
    pub fn served(&self, d: Direction) -> &MapTable {
        self.table(d)
            .or(self.forward.as_ref())
            .or(self.backward.as_ref())
            .expect("a map compensation has at least one direction")
    }

    pub fn set(&mut self, t: MapTable) {
        match t.direction {
            Direction::Forward => self.forward = Some(t),
            Direction::Backward => self.backward = Some(t),
        }
    }

    pub fn is_empty(&self) -> bool {
        self.forward.is_none() && self.backward.is_none()
    }

    /// Reads `map.runs[].cv_error_um` of a results summary.
    pub fn read_summary(&mut self, v: &serde_json::Value) {
        for r in v["map"]["runs"].as_array().into_iter().flatten() {
            let cv = r["cv_error_um"].as_f64().filter(|c| c.is_finite());
            let sq = r["iso230_1"]["squareness_urad"]
                .as_f64()
                .filter(|c| c.is_finite());
            let k = match r["direction"].as_str() {
                Some("forward") => 0,
                Some("backward") => 1,
                _ => continue,
            };
            self.cv_error_um[k] = cv;
            self.squareness_urad[k] = sq;
        }
    }

    pub fn cv_of(&self, d: Direction) -> Option<f64> {
        self.cv_error_um[usize::from(self.served_direction(d) == Direction::Backward)]
    }
}

/// The direction a map table file is for: `compensation_map_forward.csv` /
/// `..._backward.csv`; any other name: forward (the map campaign's default direction).
pub fn direction_of_file(path: &Path) -> Direction {
    let stem = path
        .file_stem()
        .and_then(|s| s.to_str())
        .unwrap_or_default();
    if stem.ends_with("_backward") {
        Direction::Backward
    } else {
        Direction::Forward
    }
}

/// Whether a file is a map table: its name or its header says so.
pub fn is_map_file(path: &Path) -> bool {
    let name = path
        .file_name()
        .and_then(|s| s.to_str())
        .unwrap_or_default();
    if name.starts_with("compensation_map_") {
        return true;
    }
    crate::tomlpos::read_bounded(path, MAX_TABLE_BYTES)
        .ok()
        .and_then(|t| {
            t.lines()
                .next()
                .map(|h| h.trim_end_matches('\r').trim() == MAP_HEADER)
        })
        .unwrap_or(false)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A smooth planar error field, written here, on a 50 µm grid.
    fn e(x: f64, y: f64) -> (f64, f64) {
        let tau = std::f64::consts::TAU;
        (
            1.0 + 80e-6 * x + 0.3 * (tau * x / 800.0).sin() + 30e-6 * y,
            -0.5 + 0.4 * (tau * y / 1200.0).cos() - 20e-6 * x,
        )
    }

    fn text() -> String {
        let mut s = format!("{MAP_HEADER}\n");
        for j in 0..=20 {
            for i in 0..=40 {
                let (x, y) = (1000.0 + 50.0 * i as f64, 500.0 + 50.0 * j as f64);
                let (ex, ey) = e(x, y);
                s.push_str(&format!("{x},{y},{:.6},{:.6}\n", -ex, -ey));
            }
        }
        s
    }

    #[test]
    fn the_commands_reach_off_grid_points_on_both_axes() {
        let t = MapTable::parse(Direction::Forward, &text(), "m.csv").unwrap();
        assert_eq!(t.span_um(), [(1000.0, 3000.0), (500.0, 1500.0)]);
        let bound = t.interpolation_bound_um();
        for k in 0..50 {
            let w = [1010.0 + 39.3 * k as f64, 510.0 + 19.7 * k as f64];
            let c = t.command(w).unwrap();
            let (ex, ey) = e(c[0], c[1]);
            let reached = [c[0] + ex, c[1] + ey];
            for a in 0..2 {
                assert!(
                    (reached[a] - w[a]).abs() <= bound[a] + 1e-4,
                    "{w:?}: reached {reached:?}, bound {bound:?}"
                );
            }
        }
        assert!(bound[0] < 0.02 && bound[1] < 0.01, "{bound:?}");
        assert!(matches!(
            t.command([3100.0, 700.0]),
            Err(CommandError::OutsideTable {
                axis: AxisId::X,
                ..
            })
        ));
        assert!(matches!(
            t.command([2000.0, 400.0]),
            Err(CommandError::OutsideTable {
                axis: AxisId::Y,
                ..
            })
        ));
    }

    #[test]
    fn bad_map_tables_name_the_line() {
        let good = text();
        let bad = |s: &str| MapTable::parse(Direction::Forward, s, "bad.csv").unwrap_err();
        assert_eq!(bad(&good.replacen("x_um", "pos", 1)).line, 1);
        let mut l: Vec<String> = good.lines().map(String::from).collect();
        l[5] = "1200,500,nan,0".into();
        let e = bad(&l.join("\n"));
        assert!(e.to_string().starts_with("bad.csv:6:"), "{e}");
        let mut l: Vec<String> = good.lines().map(String::from).collect();
        l[50] = "1000,550,0".into();
        assert_eq!(bad(&l.join("\n")).line, 51);
        let mut l: Vec<String> = good.lines().map(String::from).collect();
        l[45] = "1250,550,0,0".into();
        assert_eq!(bad(&l.join("\n")).line, 46);
        let mut l: Vec<String> = good.lines().map(String::from).collect();
        l.pop();
        assert!(bad(&l.join("\n")).message.contains("whole rows"));
    }
}
