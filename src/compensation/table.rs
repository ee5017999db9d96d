//! One axis's compensation table: its file layout, and the command that reaches a wanted
//! position with it.
use std::path::Path;

use super::{
    read_table_file, CommandError, TableError, CONVERGED_UM, MAX_CORRECTION_UM, MAX_STEPS,
};
use crate::report::compensation_columns;
use crate::types::{AxisId, Direction};

/// The compensation of one moving axis: error curves per approach direction on one grid.
#[derive(Debug, Clone)]
pub struct AxisTable {
    pub axis: AxisId,
    /// Grid, µm, strictly increasing.
    pub positions_um: Vec<f64>,
    /// Driving-direction error e(p) = measured - target, µm, per direction when measured.
    pub forward_um: Option<Vec<f64>>,
    pub backward_um: Option<Vec<f64>>,
    /// The other component's error while this axis moves (its straightness, µm), per
    /// direction, when the table has it: a two-axis compensation takes it into account on the
    /// other axis.
    pub cross_forward_um: Option<Vec<f64>>,
    pub cross_backward_um: Option<Vec<f64>>,
    /// Standard uncertainty (k = 1) of the correction per direction, µm, when the table has it.
    pub u_forward_um: Option<Vec<f64>>,
    pub u_backward_um: Option<Vec<f64>>,
    /// Where it was read from (errors name it).
    pub origin: String,
}

impl AxisTable {
    /// Parses a compensation table of moving axis `axis` (header as written by
    /// [`crate::report::compensation::compensation_csv`]).
    pub fn parse(axis: AxisId, text: &str, origin: &str) -> Result<AxisTable, TableError> {
        let err = |line: usize, message: String| TableError {
            origin: origin.to_string(),
            line,
            message,
        };
        let mut lines = text.lines().enumerate().map(|(i, l)| (i + 1, l));
        let (hl, header) = lines
            .next()
            .ok_or_else(|| err(0, "empty file: no header".into()))?;
        let cols: Vec<&str> = header.trim_end_matches('\r').split(',').collect();
        let allowed: Vec<String> = compensation_columns(axis)
            .iter()
            .map(|c| format!("{}_um", c.name()))
            .collect();
        let n = cols.len();
        // Optional last: the corrections' uncertainty (tables written since it exists).
        let with_u = n >= 6 && cols[n - 2] == "u_forward_um" && cols[n - 1] == "u_backward_um";
        // `k`: the first correction column.
        let k = if with_u { n - 4 } else { n.saturating_sub(2) };
        let well_formed = n >= 4
            && cols[0] == "position_um"
            && cols[k] == "corr_forward_um"
            && cols[k + 1] == "corr_backward_um";
        if !well_formed {
            return Err(err(
                hl,
                format!(
                    "not a compensation table: the header must be position_um, then some of {}, then corr_forward_um,corr_backward_um (and optionally u_forward_um,u_backward_um)",
                    allowed.join(",")
                ),
            ));
        }
        // The error columns, in the documented order: a table of the other axis names its
        // components with the other axis first (ef_yy for y) and is refused here.
        let mut last = None;
        // Which of the documented columns each error column is (2, 3: the cross component).
        let mut kinds = Vec::new();
        for c in &cols[1..k] {
            let Some(k) = allowed.iter().position(|a| a == c) else {
                return Err(err(
                    hl,
                    format!(
                        "column {c:?} does not belong to a compensation table of axis {axis} (expected some of {})",
                        allowed.join(",")
                    ),
                ));
            };
            if last.is_some_and(|l| k <= l) {
                return Err(err(hl, format!("column {c:?} out of order or repeated")));
            }
            last = Some(k);
            kinds.push(k);
        }
        let mut cross: [Vec<Option<f64>>; 2] = [Vec::new(), Vec::new()];
        let mut positions = Vec::new();
        let mut corr: [Vec<Option<f64>>; 2] = [Vec::new(), Vec::new()];
        let mut unc: [Vec<Option<f64>>; 2] = [Vec::new(), Vec::new()];
        for (ln, line) in lines {
            let line = line.trim_end_matches('\r');
            if line.trim().is_empty() {
                continue;
            }
            let cells: Vec<&str> = line.split(',').collect();
            if cells.len() != n {
                return Err(err(
                    ln,
                    format!("{} fields, the header has {n}", cells.len()),
                ));
            }
            let p = parse_num(cells[0]).map_err(|m| err(ln, format!("position_um: {m}")))?;
            if let Some(&prev) = positions.last() {
                if p <= prev {
                    return Err(err(
                        ln,
                        format!("position_um {p} does not increase (previous {prev})"),
                    ));
                }
            }
            // The own error columns are not used (corr is), but a table with a bad cell anywhere
            // is not one to trust; the cross columns serve two-axis moves.
            let mut row_cross = [None, None];
            for (j, cell) in cells[1..k].iter().enumerate() {
                if !cell.trim().is_empty() {
                    let v =
                        parse_num(cell).map_err(|m| err(ln, format!("{}: {m}", cols[j + 1])))?;
                    if kinds[j] >= 2 && v.abs() <= MAX_CORRECTION_UM {
                        row_cross[kinds[j] - 2] = Some(v);
                    }
                }
            }
            if with_u {
                for (d, cell) in [cells[k + 2], cells[k + 3]].into_iter().enumerate() {
                    let name = ["u_forward_um", "u_backward_um"][d];
                    let v = if cell.trim().is_empty() {
                        None
                    } else {
                        let v = parse_num(cell).map_err(|m| err(ln, format!("{name}: {m}")))?;
                        if !(0.0..=MAX_CORRECTION_UM).contains(&v) {
                            return Err(err(ln, format!("{name} {v} µm is not an uncertainty (0 to {MAX_CORRECTION_UM} µm)")));
                        }
                        Some(v)
                    };
                    unc[d].push(v);
                }
            }
            for (d, v) in row_cross.into_iter().enumerate() {
                cross[d].push(v);
            }
            positions.push(p);
            for (d, cell) in [cells[k], cells[k + 1]].into_iter().enumerate() {
                let name = ["corr_forward_um", "corr_backward_um"][d];
                let v = if cell.trim().is_empty() {
                    None
                } else {
                    let v = parse_num(cell).map_err(|m| err(ln, format!("{name}: {m}")))?;
                    if v.abs() > MAX_CORRECTION_UM {
                        return Err(err(
                            ln,
                            format!("{name} {v} µm is larger than {MAX_CORRECTION_UM} µm: not an error map of this stage"),
                        ));
                    }
                    Some(v)
                };
                corr[d].push(v);
            }
        }
        if positions.len() < 2 {
            return Err(err(0, "fewer than 2 grid points".into()));
        }
        // A direction is present in every row or in none: a hole would be interpolated over.
        let mut dirs: [Option<Vec<f64>>; 2] = [None, None];
        for d in 0..2 {
            let present = corr[d].iter().filter(|v| v.is_some()).count();
            if present == 0 {
                continue;
            }
            if let Some(i) = corr[d].iter().position(Option::is_none) {
                // Line of that row: header + blank lines are rare; find it by position.
                let ln = line_of_row(text, i);
                return Err(err(
                    ln,
                    format!(
                        "{} is empty here but not in other rows",
                        ["corr_forward_um", "corr_backward_um"][d]
                    ),
                ));
            }
            dirs[d] = Some(corr[d].iter().map(|v| -v.unwrap_or(0.0)).collect());
        }
        let [forward_um, backward_um] = dirs;
        // A cross column with a hole is not used (never interpolated over).
        let [cross_forward_um, cross_backward_um] =
            cross.map(|c| c.iter().copied().collect::<Option<Vec<f64>>>());
        let [u_forward_um, u_backward_um] = unc.map(|c| {
            (c.len() == positions.len())
                .then(|| c.iter().copied().collect::<Option<Vec<f64>>>())
                .flatten()
        });
        if forward_um.is_none() && backward_um.is_none() {
            return Err(err(
                0,
                "no correction in either direction (both corr columns empty)".into(),
            ));
        }
        Ok(AxisTable {
            axis,
            positions_um: positions,
            forward_um,
            backward_um,
            cross_forward_um,
            cross_backward_um,
            u_forward_um,
            u_backward_um,
            origin: origin.to_string(),
        })
    }

    /// Reads and parses a table file (regular file, bounded size).
    pub fn load(axis: AxisId, path: &Path) -> Result<AxisTable, TableError> {
        let (origin, text) = read_table_file(path)?;
        AxisTable::parse(axis, &text, &origin)
    }

    /// Grid range, µm.
    pub fn range_um(&self) -> (f64, f64) {
        (
            self.positions_um[0],
            *self.positions_um.last().expect("≥ 2 points"),
        )
    }

    /// The direction whose column serves an approach in `d`: `d`'s own when measured, else the
    /// other one — then the move must approach from that side (see [`Compensation::command`]).
    pub fn served_direction(&self, d: Direction) -> Direction {
        match (d, &self.forward_um, &self.backward_um) {
            (Direction::Forward, None, Some(_)) => Direction::Backward,
            (Direction::Backward, Some(_), None) => Direction::Forward,
            _ => d,
        }
    }

    /// Error at commanded `p` approached in `d` (linear interpolation), µm; `p` within the grid.
    pub fn error_at(&self, d: Direction, p: f64) -> f64 {
        let e = match self.served_direction(d) {
            Direction::Forward => self.forward_um.as_deref(),
            Direction::Backward => self.backward_um.as_deref(),
        }
        .expect("a table has at least one direction");
        self.interpolate(e, p)
    }

    /// Column `col` (one value per grid point) at `p`, linear between grid points, the end
    /// values held beyond them.
    fn interpolate(&self, col: &[f64], p: f64) -> f64 {
        let x = &self.positions_um;
        let i = x.partition_point(|&q| q <= p).clamp(1, x.len() - 1);
        let t = ((p - x[i - 1]) / (x[i] - x[i - 1])).clamp(0.0, 1.0);
        col[i - 1] + t * (col[i] - col[i - 1])
    }

    /// `col` at `p` when `p` is on the grid (to rounding), else `None`.
    fn on_grid(&self, col: &[f64], p: f64) -> Option<f64> {
        let (lo, hi) = self.range_um();
        (lo - 1e-9..=hi + 1e-9)
            .contains(&p)
            .then(|| self.interpolate(col, p))
    }

    /// The other component's error while this axis moves, at commanded `p` approached in `d`
    /// (interpolated as [`error_at`](Self::error_at)), µm; `None` without that column or
    /// outside the grid.
    pub fn cross_at(&self, d: Direction, p: f64) -> Option<f64> {
        let col = match d {
            Direction::Forward => self.cross_forward_um.as_deref(),
            Direction::Backward => self.cross_backward_um.as_deref(),
        }
        .or(self.cross_forward_um.as_deref())
        .or(self.cross_backward_um.as_deref())?;
        self.on_grid(col, p)
    }

    /// Standard uncertainty (k = 1, µm) of the correction at `p` approached in `d` (the column
    /// the correction is served from), `None` when the table has none or `p` is off the grid.
    pub fn u_at(&self, d: Direction, p: f64) -> Option<f64> {
        let col = match self.served_direction(d) {
            Direction::Forward => self.u_forward_um.as_deref(),
            Direction::Backward => self.u_backward_um.as_deref(),
        }?;
        self.on_grid(col, p)
    }

    /// The command that reaches `wanted_um` when approached in `d`: c with c + e(c) = wanted.
    pub fn command_um(&self, d: Direction, wanted_um: f64) -> Result<f64, CommandError> {
        let axis = self.axis;
        if !wanted_um.is_finite() {
            return Err(CommandError::NotFinite { axis, wanted_um });
        }
        let (lo, hi) = self.range_um();
        if wanted_um < lo - 1e-9 || wanted_um > hi + 1e-9 {
            return Err(CommandError::OutsideTable {
                axis,
                wanted_um,
                lo_um: lo,
                hi_um: hi,
            });
        }
        self.solve(d, wanted_um, wanted_um)
    }

    /// c with c + e(c) = `aim_um` (the wanted position less any other axis's error on this
    /// one); errors name `wanted_um`.
    pub(super) fn solve(
        &self,
        d: Direction,
        wanted_um: f64,
        aim_um: f64,
    ) -> Result<f64, CommandError> {
        let axis = self.axis;
        let (lo, hi) = self.range_um();
        // A wanted position at the table's edge may need a command just beyond it: the edge
        // value holds there for up to one grid step (the table's resolution), no further.
        let x = &self.positions_um;
        let (m_lo, m_hi) = (x[1] - x[0], x[x.len() - 1] - x[x.len() - 2]);
        let mut c = aim_um;
        for _ in 0..MAX_STEPS {
            let next = aim_um - self.error_at(d, c.clamp(lo, hi));
            let done = (next - c).abs() <= CONVERGED_UM;
            c = next;
            if done {
                if c < lo - m_lo || c > hi + m_hi {
                    return Err(CommandError::OutsideTable {
                        axis,
                        wanted_um,
                        lo_um: lo,
                        hi_um: hi,
                    });
                }
                return Ok(c);
            }
        }
        Err(CommandError::NoConvergence { axis, wanted_um })
    }
}

/// 1-based file line of data row `i` (0-based, blank lines skipped), for error messages.
fn line_of_row(text: &str, i: usize) -> usize {
    text.lines()
        .enumerate()
        .skip(1)
        .filter(|(_, l)| !l.trim().is_empty())
        .nth(i)
        .map_or(0, |(k, _)| k + 1)
}

pub(super) fn parse_num(s: &str) -> Result<f64, NumError> {
    let v: f64 = s
        .trim()
        .parse()
        .map_err(|_| NumError::NotANumber(truncate(s)))?;
    if !v.is_finite() {
        return Err(NumError::NotFinite(truncate(s)));
    }
    Ok(v)
}

/// A table cell that is not a finite number (its text shortened).
#[derive(Debug, thiserror::Error)]
pub(super) enum NumError {
    #[error("{0:?} is not a number")]
    NotANumber(String),
    #[error("{0:?} is not a finite number")]
    NotFinite(String),
}

/// Cell text in messages: short, so an error line never carries a whole file.
fn truncate(s: &str) -> String {
    s.trim().chars().take(24).collect()
}
