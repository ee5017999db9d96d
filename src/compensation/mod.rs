//! Compensated motion: the measured error curves turned into the commands that reach wanted
//! positions.
//!
//! A table (`compensation_x|y.csv`, see [`crate::report::compensation`]) gives, per grid
//! position p and approach direction, corr(p) = -e(p) where e(p) = measured - target when p was
//! commanded from that direction. To reach a wanted w the command c must satisfy c + e(c) = w;
//! c = w - e(c) is a contraction (|e'| ≪ 1 on a leadscrew stage), solved by fixed-point steps on
//! the linearly interpolated table. A command outside the table's grid or the soft limits is
//! refused, never clipped: clipping would move somewhere else than asked.
use std::fmt;
use std::path::Path;

use crate::report::compensation_columns;
use crate::types::{AxisId, Direction};

pub mod campaign;
pub mod motion;
pub mod verify;

/// Largest compensation table read, bytes (1 M grid points at ~60 bytes a row).
pub const MAX_TABLE_BYTES: u64 = 64 << 20;
/// Largest correction believed, µm: beyond it the table is not an error map of a
/// micropositioning stage (or is in the wrong unit).
pub const MAX_CORRECTION_UM: f64 = 1000.0;
/// Fixed-point steps at most, and the change in the command that ends them, µm.
const MAX_STEPS: usize = 20;
const CONVERGED_UM: f64 = 1e-7;

/// A table refused at load: the file, the line (1-based; 0: the file as a whole) and why.
#[derive(Debug, Clone, PartialEq)]
pub struct TableError {
    pub origin: String,
    pub line: usize,
    pub message: String,
}

impl fmt::Display for TableError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if self.line > 0 {
            write!(f, "{}:{}: {}", self.origin, self.line, self.message)
        } else {
            write!(f, "{}: {}", self.origin, self.message)
        }
    }
}

impl std::error::Error for TableError {}

/// Why a wanted position has no compensated command.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CommandError {
    #[error("axis {axis}: no compensation table for this axis")]
    NoTable { axis: AxisId },
    #[error("axis {axis}: {wanted_um} µm is outside the compensated range [{lo_um}, {hi_um}] µm")]
    OutsideTable {
        axis: AxisId,
        wanted_um: f64,
        lo_um: f64,
        hi_um: f64,
    },
    #[error("axis {axis}: the corrected command {command_um:.4} µm for {wanted_um} µm is outside the soft limits [{lo_um}, {hi_um}] µm; not moved")]
    OutsideLimits {
        axis: AxisId,
        wanted_um: f64,
        command_um: f64,
        lo_um: f64,
        hi_um: f64,
    },
    #[error("axis {axis}: the correction does not converge at {wanted_um} µm (table too steep)")]
    NoConvergence { axis: AxisId, wanted_um: f64 },
    #[error("axis {axis}: {wanted_um} is not a finite position")]
    NotFinite { axis: AxisId, wanted_um: f64 },
}

/// The compensation of one moving axis: error curves per approach direction on one grid.
#[derive(Debug, Clone)]
pub struct AxisTable {
    pub axis: AxisId,
    /// Grid, µm, strictly increasing.
    pub positions_um: Vec<f64>,
    /// Driving-direction error e(p) = measured - target, µm, per direction when measured.
    pub forward_um: Option<Vec<f64>>,
    pub backward_um: Option<Vec<f64>>,
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
        let well_formed = n >= 4
            && cols[0] == "position_um"
            && cols[n - 2] == "corr_forward_um"
            && cols[n - 1] == "corr_backward_um";
        if !well_formed {
            return Err(err(
                hl,
                format!(
                    "not a compensation table: the header must be position_um, then some of {}, then corr_forward_um,corr_backward_um",
                    allowed.join(",")
                ),
            ));
        }
        // The error columns, in the documented order: a table of the other axis names its
        // components with the other axis first (ef_yy for y) and is refused here.
        let mut last = None;
        for c in &cols[1..n - 2] {
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
        }
        let mut positions = Vec::new();
        let mut corr: [Vec<Option<f64>>; 2] = [Vec::new(), Vec::new()];
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
            // The error columns are not used (corr is), but a table with a bad cell anywhere is
            // not one to trust.
            for (k, cell) in cells[1..n - 2].iter().enumerate() {
                if !cell.trim().is_empty() {
                    parse_num(cell).map_err(|m| err(ln, format!("{}: {m}", cols[k + 1])))?;
                }
            }
            positions.push(p);
            for (d, cell) in [cells[n - 2], cells[n - 1]].into_iter().enumerate() {
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
            origin: origin.to_string(),
        })
    }

    /// Reads and parses a table file (regular file, bounded size).
    pub fn load(axis: AxisId, path: &Path) -> Result<AxisTable, TableError> {
        let origin = path.display().to_string();
        let text = crate::tomlpos::read_bounded(path, MAX_TABLE_BYTES).map_err(|m| TableError {
            origin: origin.clone(),
            line: 0,
            message: format!("cannot read: {m}"),
        })?;
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
        let x = &self.positions_um;
        let i = x.partition_point(|&q| q <= p).clamp(1, x.len() - 1);
        let (x0, x1) = (x[i - 1], x[i]);
        let t = ((p - x0) / (x1 - x0)).clamp(0.0, 1.0);
        e[i - 1] + t * (e[i] - e[i - 1])
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
        // A wanted position at the table's edge may need a command just beyond it: the edge
        // value holds there for up to one grid step (the table's resolution), no further.
        let x = &self.positions_um;
        let (m_lo, m_hi) = (x[1] - x[0], x[x.len() - 1] - x[x.len() - 2]);
        let mut c = wanted_um;
        for _ in 0..MAX_STEPS {
            let next = wanted_um - self.error_at(d, c.clamp(lo, hi));
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

fn parse_num(s: &str) -> Result<f64, String> {
    let v: f64 = s
        .trim()
        .parse()
        .map_err(|_| format!("{:?} is not a number", truncate(s)))?;
    if !v.is_finite() {
        return Err(format!("{:?} is not a finite number", truncate(s)));
    }
    Ok(v)
}

/// Cell text in messages: short, so an error line never carries a whole file.
fn truncate(s: &str) -> String {
    s.trim().chars().take(24).collect()
}

/// Compensation of a stage: a table per axis (either may be absent).
#[derive(Debug, Clone)]
pub struct Compensation {
    /// The stage the tables were measured on, when known (a results directory says).
    pub stage: Option<String>,
    /// The characterisation campaign, when known.
    pub campaign: Option<i64>,
    pub x: Option<AxisTable>,
    pub y: Option<AxisTable>,
    /// Where it came from (a directory, a file, `campaign N`).
    pub source: String,
}

impl Compensation {
    pub fn table(&self, axis: AxisId) -> Option<&AxisTable> {
        match axis {
            AxisId::X => self.x.as_ref(),
            AxisId::Y => self.y.as_ref(),
        }
    }

    /// Loads `path`: a results directory (`compensation_x.csv`, `compensation_y.csv`, and
    /// `summary.json` naming the stage and campaign) or one table file, whose axis is read from
    /// its name (`..._x.csv`) or else its header.
    pub fn load(path: &Path) -> Result<Compensation, TableError> {
        let origin = path.display().to_string();
        let meta = std::fs::metadata(path).map_err(|e| TableError {
            origin: origin.clone(),
            line: 0,
            message: format!("cannot read: {}", crate::tomlpos::io_reason(&e)),
        })?;
        if meta.is_dir() {
            let mut c = Compensation {
                stage: None,
                campaign: None,
                x: None,
                y: None,
                source: origin.clone(),
            };
            for axis in [AxisId::X, AxisId::Y] {
                let f = path.join(format!("compensation_{axis}.csv"));
                if f.exists() {
                    let t = AxisTable::load(axis, &f)?;
                    match axis {
                        AxisId::X => c.x = Some(t),
                        AxisId::Y => c.y = Some(t),
                    }
                }
            }
            if c.x.is_none() && c.y.is_none() {
                return Err(TableError {
                    origin,
                    line: 0,
                    message: "no compensation_x.csv or compensation_y.csv in this directory".into(),
                });
            }
            let summary = path.join("summary.json");
            if summary.exists() {
                let (stage, id) = summary_identity(&summary)?;
                c.stage = stage;
                c.campaign = id;
            }
            return Ok(c);
        }
        let axis = table_axis(path)?;
        let t = AxisTable::load(axis, path)?;
        // A table inside a results directory: the directory's summary names its stage.
        let (stage, campaign) = match path.parent().map(|d| d.join("summary.json")) {
            Some(s) if s.is_file() => summary_identity(&s)?,
            _ => (None, None),
        };
        Ok(Compensation {
            stage,
            campaign,
            x: (axis == AxisId::X).then(|| t.clone()),
            y: (axis == AxisId::Y).then_some(t),
            source: origin,
        })
    }

    /// Compensation of a stored campaign: its `compensation_x|y.csv` results.
    pub fn from_store(
        store: &crate::store::Store,
        id: i64,
        stage: &str,
    ) -> Result<Compensation, TableError> {
        let origin = format!("campaign {id}");
        let mut c = Compensation {
            stage: Some(stage.to_string()),
            campaign: Some(id),
            x: None,
            y: None,
            source: origin.clone(),
        };
        for axis in [AxisId::X, AxisId::Y] {
            let name = format!("compensation_{axis}.csv");
            let r = store.result(id, &name).map_err(|e| TableError {
                origin: origin.clone(),
                line: 0,
                message: e.to_string(),
            })?;
            if let Some((_, bytes)) = r {
                let text = String::from_utf8(bytes).map_err(|_| TableError {
                    origin: format!("{origin}/{name}"),
                    line: 0,
                    message: "not UTF-8 text".into(),
                })?;
                let t = AxisTable::parse(axis, &text, &format!("{origin}/{name}"))?;
                match axis {
                    AxisId::X => c.x = Some(t),
                    AxisId::Y => c.y = Some(t),
                }
            }
        }
        if c.x.is_none() && c.y.is_none() {
            return Err(TableError {
                origin,
                line: 0,
                message: "has no compensation table (a finished characterisation writes compensation_x|y.csv)".into(),
            });
        }
        Ok(c)
    }

    /// Refuses a compensation measured on another stage than `stage`.
    pub fn check_stage(&self, stage: &str) -> Result<(), TableError> {
        match &self.stage {
            Some(s) if s != stage => Err(TableError {
                origin: self.source.clone(),
                line: 0,
                message: format!("measured on stage {s:?}, not on {stage:?}"),
            }),
            _ => Ok(()),
        }
    }

    /// Refuses a compensation whose table of `axis` does not cover `[lo, hi]` µm.
    pub fn check_covers(&self, axis: AxisId, lo_um: f64, hi_um: f64) -> Result<(), TableError> {
        let t = self.table(axis).ok_or_else(|| TableError {
            origin: self.source.clone(),
            line: 0,
            message: format!("no compensation table of axis {axis}"),
        })?;
        let (a, b) = t.range_um();
        if lo_um < a - 1e-9 || hi_um > b + 1e-9 {
            return Err(TableError {
                origin: t.origin.clone(),
                line: 0,
                message: format!(
                    "its grid [{a}, {b}] µm does not cover the travel [{lo_um}, {hi_um}] µm"
                ),
            });
        }
        Ok(())
    }

    /// The command for `wanted_um` on `axis` approached in `d`, inside `soft_limits_um`.
    pub fn command(
        &self,
        axis: AxisId,
        d: Direction,
        wanted_um: f64,
        soft_limits_um: (f64, f64),
    ) -> Result<f64, CommandError> {
        let t = self.table(axis).ok_or(CommandError::NoTable { axis })?;
        let c = t.command_um(d, wanted_um)?;
        let (lo, hi) = soft_limits_um;
        if c < lo || c > hi {
            return Err(CommandError::OutsideLimits {
                axis,
                wanted_um,
                command_um: c,
                lo_um: lo,
                hi_um: hi,
            });
        }
        Ok(c)
    }
}

/// The axis of a single table file: `..._x.csv` / `..._y.csv`, else the header's components.
fn table_axis(path: &Path) -> Result<AxisId, TableError> {
    let name = path
        .file_stem()
        .and_then(|s| s.to_str())
        .unwrap_or_default();
    if name.ends_with("_x") {
        return Ok(AxisId::X);
    }
    if name.ends_with("_y") {
        return Ok(AxisId::Y);
    }
    let origin = path.display().to_string();
    let text = crate::tomlpos::read_bounded(path, MAX_TABLE_BYTES).map_err(|m| TableError {
        origin: origin.clone(),
        line: 0,
        message: format!("cannot read: {m}"),
    })?;
    let header = text.lines().next().unwrap_or_default();
    for axis in [AxisId::X, AxisId::Y] {
        let own = format!("_{axis}{axis}_um");
        if header.split(',').any(|c| c.ends_with(&own)) {
            return Ok(axis);
        }
    }
    Err(TableError {
        origin,
        line: 1,
        message: "cannot tell the axis: name the file compensation_x.csv or compensation_y.csv"
            .into(),
    })
}

/// `stage` and `id` from a results directory's summary.json.
fn summary_identity(path: &Path) -> Result<(Option<String>, Option<i64>), TableError> {
    let origin = path.display().to_string();
    let text = crate::tomlpos::read_bounded(path, 16 << 20).map_err(|m| TableError {
        origin: origin.clone(),
        line: 0,
        message: format!("cannot read: {m}"),
    })?;
    let v: serde_json::Value = serde_json::from_str(&text).map_err(|e| TableError {
        origin,
        line: e.line(),
        message: "not a results summary (JSON)".into(),
    })?;
    Ok((v["stage"].as_str().map(str::to_string), v["id"].as_i64()))
}

/// `[compensation]` of a campaign file: `from = ID` (a characterisation in the same store) or
/// `file = "..."` (a results directory or a table, relative to the campaign file).
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CompensationSpec {
    #[serde(default)]
    pub from: Option<i64>,
    #[serde(default)]
    pub file: Option<String>,
}

/// Checks `[compensation]` of a parsed campaign: one source; a `file` is loaded now (a bad table
/// refuses the campaign before anything is stored or moved) and must fit the campaign's stage,
/// axes and directions. `from = ID` is resolved when the campaign runs (it needs the store).
/// Errors: (key, message). Submitted campaigns may only name a stored characterisation.
pub fn check_spec(
    c: &crate::campaign::spec::Campaign,
    submitted: bool,
) -> Result<(), (&'static str, String)> {
    let Some(s) = &c.spec.compensation else {
        return Ok(());
    };
    match (s.from, &s.file) {
        (Some(id), None) if id > 0 => Ok(()),
        (Some(_), None) => Err(("compensation.from", "must be a campaign id (> 0)".into())),
        (None, Some(_)) if submitted => Err((
            "compensation.file",
            "a submitted campaign names its compensation by the characterisation's id: from = ID".into(),
        )),
        (None, Some(f)) => {
            if f.is_empty() || f.len() > 1024 || f.contains('\0') {
                return Err(("compensation.file", "must be a path of 1..=1024 bytes".into()));
            }
            let comp = Compensation::load(&c.resolve(f)).map_err(|e| ("compensation.file", e.to_string()))?;
            fits(&comp, c).map_err(|e| ("compensation.file", e))
        }
        _ => Err((
            "compensation",
            "give one of from = ID (a stored characterisation) or file = \"...\" (results directory or table)".into(),
        )),
    }
}

/// Refuses a compensation that does not fit campaign `c`: another stage, an axis without a
/// table or a grid short of the axis's range, a direction the table cannot serve.
pub fn fits(comp: &Compensation, c: &crate::campaign::spec::Campaign) -> Result<(), String> {
    comp.check_stage(&c.spec.campaign.stage)
        .map_err(|e| e.to_string())?;
    for ax in &c.axes {
        comp.check_covers(ax.axis, ax.grid.start_um, ax.grid.end_um())
            .map_err(|e| e.to_string())?;
        let t = comp.table(ax.axis).expect("checked by check_covers");
        for &d in &c.spec.acquisition.directions {
            if t.served_direction(d) != d {
                return Err(format!(
                    "{}: no {} correction, and the campaign measures {} (approached from the other side, backlash would stay)",
                    t.origin,
                    d.as_str(),
                    d.as_str()
                ));
            }
        }
    }
    Ok(())
}

/// The compensation campaign `c` runs with, resolved against `store` (`from = ID`) or its file.
pub fn for_campaign(
    c: &crate::campaign::spec::Campaign,
    store: &crate::store::Store,
) -> Result<Option<std::sync::Arc<Compensation>>, String> {
    let Some(s) = &c.spec.compensation else {
        return Ok(None);
    };
    let comp = match (s.from, &s.file) {
        (Some(id), _) => {
            let row = store
                .campaign(id)
                .map_err(|e| e.to_string())?
                .ok_or_else(|| format!("compensation: no campaign {id} in the store"))?;
            Compensation::from_store(store, id, &row.stage).map_err(|e| e.to_string())?
        }
        (None, Some(f)) => Compensation::load(&c.resolve(f)).map_err(|e| e.to_string())?,
        (None, None) => return Ok(None),
    };
    fits(&comp, c).map_err(|e| format!("compensation: {e}"))?;
    Ok(Some(std::sync::Arc::new(comp)))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An error map written here, independent of the report writer: a 400 µm cyclic error, a
    /// scale error and a 2 µm reversal, on a 10 µm grid over [0, 2000] µm.
    fn e_true(d: Direction, p: f64) -> f64 {
        let cyc = 1.5 * (2.0 * std::f64::consts::PI * p / 400.0 + 0.7).sin();
        let scale = 80e-6 * p;
        cyc + scale
            + match d {
                Direction::Forward => 1.0,
                Direction::Backward => -1.0,
            }
    }

    fn table_text(step: f64, both: bool) -> String {
        let mut s =
            String::from("position_um,ef_xx_um,eb_xx_um,corr_forward_um,corr_backward_um\n");
        let n = (2000.0 / step) as usize;
        for i in 0..=n {
            let p = i as f64 * step;
            let (f, b) = (
                e_true(Direction::Forward, p),
                e_true(Direction::Backward, p),
            );
            if both {
                s.push_str(&format!("{p},{f:.6},{b:.6},{:.6},{:.6}\n", -f, -b));
            } else {
                s.push_str(&format!("{p},{f:.6},,{:.6},\n", -f));
            }
        }
        s
    }

    #[test]
    fn the_command_reaches_the_wanted_position_in_both_directions() {
        let t = AxisTable::parse(AxisId::X, &table_text(1.0, true), "t.csv").unwrap();
        for d in [Direction::Forward, Direction::Backward] {
            // Off-grid positions the table never held.
            for k in 0..97 {
                let w = 20.0 + k as f64 * 19.37;
                let c = t.command_um(d, w).unwrap();
                // Where the stage ends up commanded to c, by the independent map.
                let reached = c + e_true(d, c);
                assert!(
                    (reached - w).abs() < 2e-3,
                    "{d:?} {w}: reached {reached}, command {c}"
                );
            }
        }
    }

    #[test]
    fn a_one_direction_table_serves_the_other_direction_from_its_side() {
        let t = AxisTable::parse(AxisId::X, &table_text(5.0, false), "t.csv").unwrap();
        assert!(t.backward_um.is_none());
        assert_eq!(t.served_direction(Direction::Backward), Direction::Forward);
        let c = t.command_um(Direction::Backward, 1000.0).unwrap();
        assert!((c + e_true(Direction::Forward, c) - 1000.0).abs() < 0.02);
    }

    #[test]
    fn commands_outside_the_table_or_the_soft_limits_are_refused_not_clipped() {
        let t = AxisTable::parse(AxisId::X, &table_text(5.0, true), "t.csv").unwrap();
        let c = Compensation {
            stage: None,
            campaign: None,
            x: Some(t),
            y: None,
            source: "t".into(),
        };
        assert!(matches!(
            c.command(AxisId::X, Direction::Forward, 2500.0, (-500.0, 13_500.0)),
            Err(CommandError::OutsideTable { .. })
        ));
        // At 0 the forward error is ~ +1 + 1.5 sin(0.7) ≈ +1.97 µm: the command is ≈ -1.97 µm.
        let ok = c
            .command(AxisId::X, Direction::Forward, 3.0, (-500.0, 13_500.0))
            .unwrap();
        assert!(ok < 3.0);
        assert!(matches!(
            c.command(AxisId::X, Direction::Forward, 3.0, (ok + 0.5, 13_500.0)),
            Err(CommandError::OutsideLimits { .. })
        ));
        assert!(matches!(
            c.command(AxisId::Y, Direction::Forward, 3.0, (-500.0, 13_500.0)),
            Err(CommandError::NoTable { .. })
        ));
        assert!(c
            .command(AxisId::X, Direction::Forward, f64::NAN, (-500.0, 13_500.0))
            .is_err());
    }

    #[test]
    fn bad_tables_are_refused_with_the_line() {
        let good = table_text(100.0, true);
        let bad = |text: &str, axis: AxisId| AxisTable::parse(axis, text, "bad.csv").unwrap_err();
        // Wrong header.
        let e = bad(&good.replacen("position_um", "pos", 1), AxisId::X);
        assert_eq!(e.line, 1);
        // Another axis's table.
        assert_eq!(bad(&good, AxisId::Y).line, 1);
        // NaN on the 4th data row (line 5).
        let mut lines: Vec<String> = good.lines().map(String::from).collect();
        lines[4] = "300,nan,0,NaN,0".into();
        let e = bad(&lines.join("\n"), AxisId::X);
        assert_eq!(e.line, 5, "{e}");
        assert!(e.to_string().starts_with("bad.csv:5:"), "{e}");
        // A position that goes back.
        let mut l2: Vec<String> = good.lines().map(String::from).collect();
        l2[3] = "50,0,0,0,0".into();
        assert_eq!(bad(&l2.join("\n"), AxisId::X).line, 4);
        // A hole in one direction.
        let mut l3: Vec<String> = good.lines().map(String::from).collect();
        l3[6] = "500,0,0,,0".into();
        assert_eq!(bad(&l3.join("\n"), AxisId::X).line, 7);
        // Missing fields, absurd values.
        let mut l4: Vec<String> = good.lines().map(String::from).collect();
        l4[2] = "100,0,0".into();
        assert_eq!(bad(&l4.join("\n"), AxisId::X).line, 3);
        let mut l5: Vec<String> = good.lines().map(String::from).collect();
        l5[2] = "100,0,0,5e6,0".into();
        assert_eq!(bad(&l5.join("\n"), AxisId::X).line, 3);
        assert!(AxisTable::parse(AxisId::X, "", "e.csv").is_err());
    }

    #[test]
    fn coverage_and_stage_are_checked() {
        let t = AxisTable::parse(AxisId::X, &table_text(5.0, true), "t.csv").unwrap();
        let c = Compensation {
            stage: Some("sim-xy".into()),
            campaign: Some(3),
            x: Some(t),
            y: None,
            source: "t".into(),
        };
        assert!(c.check_covers(AxisId::X, 0.0, 2000.0).is_ok());
        assert!(c.check_covers(AxisId::X, 0.0, 9500.0).is_err());
        assert!(c.check_covers(AxisId::Y, 0.0, 100.0).is_err());
        assert!(c.check_stage("sim-xy").is_ok());
        assert!(c.check_stage("lab-xy").is_err());
    }
}
