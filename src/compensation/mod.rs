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

use crate::types::{AxisId, Direction};

pub mod map;
mod table;

use table::parse_num;
pub use table::AxisTable;

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
    #[error(
        "a map compensation corrects x and y together: give both positions (--x-um and --y-um)"
    )]
    MapNeedsBoth,
}

/// Compensation of a stage: line tables or an XY map.
#[derive(Debug, Clone)]
pub struct Compensation {
    /// The stage the tables were measured on, when known (a results directory says).
    pub stage: Option<String>,
    /// The characterisation campaign, when known.
    pub campaign: Option<i64>,
    pub correction: Correction,
    /// Where it came from (a directory, a file, `campaign N`).
    pub source: String,
    /// Unidirectional repeatability of x and y (the larger of R↑ and R↓ of the
    /// characterisation's ISO 230-2 measured figures), µm, when its results give it.
    pub repeatability_um: [Option<f64>; 2],
}

/// What corrects the moves.
#[derive(Debug, Clone)]
pub enum Correction {
    /// A table per axis (either may be absent), each measured along a line.
    Lines {
        x: Option<AxisTable>,
        y: Option<AxisTable>,
        /// Where the other axis stood while each table's line was measured (x's table: y, µm;
        /// y's table: x), when the results say (`summary.json`'s `other_at_um`): a two-axis
        /// move needs it to take that axis's own error back out (see
        /// [`Compensation::command_xy`]).
        line_other_um: [Option<f64>; 2],
    },
    /// An XY map's compensation (a `[map]` campaign's `compensation_map_<dir>.csv`): every
    /// move corrects both axes from the map.
    Map(map::MapCompensation),
}

impl Correction {
    /// Line tables `x` and `y`, the lines' positions unknown; none at all: `None`.
    fn lines(x: Option<AxisTable>, y: Option<AxisTable>) -> Option<Correction> {
        (x.is_some() || y.is_some()).then_some(Correction::Lines {
            x,
            y,
            line_other_um: [None, None],
        })
    }
}

/// One axis's planned command in a two-axis compensated move.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AxisCommand {
    pub command_um: f64,
    /// The approach direction the correction was measured for.
    pub approach: Direction,
    /// The other axis's error on this one taken out (µm), `None` when the tables cannot say
    /// (one table, no cross column, no line position, or the other axis outside its table).
    pub cross_um: Option<f64>,
}

impl Compensation {
    /// The line table of `axis`; `None` for a map.
    pub fn table(&self, axis: AxisId) -> Option<&AxisTable> {
        match (&self.correction, axis) {
            (Correction::Lines { x, .. }, AxisId::X) => x.as_ref(),
            (Correction::Lines { y, .. }, AxisId::Y) => y.as_ref(),
            (Correction::Map(_), _) => None,
        }
    }

    /// Expected landing uncertainty (k = 1) of a compensated move of `axis` whose correction
    /// has standard uncertainty `u_um` (the table's u there): u combined in quadrature with the
    /// repeatability's standard deviation, R / 4 (ISO 230-2: R↑ = 4 s↑), when the results give
    /// R; else u alone. µm.
    pub fn landing_u_um(&self, axis: AxisId, u_um: f64) -> f64 {
        let s = self.repeatability_um[axis as usize].map_or(0.0, |r| r / 4.0);
        u_um.hypot(s)
    }

    /// The XY map; `None` for line tables.
    pub fn map(&self) -> Option<&map::MapCompensation> {
        match &self.correction {
            Correction::Map(m) => Some(m),
            Correction::Lines { .. } => None,
        }
    }

    /// Where the other axis stood while each line table was measured (x's, y's), when known.
    pub fn line_other_um(&self) -> [Option<f64>; 2] {
        match &self.correction {
            Correction::Lines { line_other_um, .. } => *line_other_um,
            Correction::Map(_) => [None, None],
        }
    }

    /// A summary's stage, campaign and lines' positions (`summary.json` beside the tables),
    /// and a map's figures from the summary `v`.
    fn read_identity(
        &mut self,
        (stage, campaign, lines): (Option<String>, Option<i64>, [Option<f64>; 2]),
        v: Option<&serde_json::Value>,
    ) {
        self.stage = stage;
        self.campaign = campaign;
        match &mut self.correction {
            Correction::Lines { line_other_um, .. } => *line_other_um = lines,
            Correction::Map(m) => {
                if let Some(v) = v {
                    m.read_summary(v);
                }
            }
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
            let table = |axis: AxisId| {
                let f = path.join(format!("compensation_{axis}.csv"));
                f.exists().then(|| AxisTable::load(axis, &f)).transpose()
            };
            let (x, y) = (table(AxisId::X)?, table(AxisId::Y)?);
            let correction = if let Some(lines) = Correction::lines(x, y) {
                lines
            } else {
                // A map campaign's results: its maps, one per measured direction.
                let mut m = map::MapCompensation::default();
                for d in [Direction::Forward, Direction::Backward] {
                    let f = path.join(format!("compensation_map_{}.csv", d.as_str()));
                    if f.exists() {
                        m.set(map::MapTable::load(d, &f)?);
                    }
                }
                if m.is_empty() {
                    return Err(TableError {
                        origin,
                        line: 0,
                        message: "no compensation_x.csv, compensation_y.csv or compensation_map_<direction>.csv in this directory".into(),
                    });
                }
                Correction::Map(m)
            };
            let mut c = Compensation {
                stage: None,
                campaign: None,
                correction,
                source: origin.clone(),
                repeatability_um: [None, None],
            };
            let summary = path.join("summary.json");
            if summary.exists() {
                let identity = summary_identity(&summary)?;
                let v = match c.correction {
                    Correction::Map(_) => Some(summary_json(&summary)?),
                    Correction::Lines { .. } => {
                        // Unreadable as JSON: summary_identity refused it already.
                        c.repeatability_um = repeatabilities(&summary_json(&summary)?);
                        None
                    }
                };
                c.read_identity(identity, v.as_ref());
            }
            return Ok(c);
        }
        if map::is_map_file(path) {
            let mut m = map::MapCompensation::default();
            m.set(map::MapTable::load(map::direction_of_file(path), path)?);
            let (stage, campaign) = match path.parent().map(|d| d.join("summary.json")) {
                Some(s) if s.is_file() => {
                    let (stage, id, _) = summary_identity(&s)?;
                    m.read_summary(&summary_json(&s)?);
                    (stage, id)
                }
                _ => (None, None),
            };
            return Ok(Compensation {
                stage,
                campaign,
                correction: Correction::Map(m),
                source: origin,
                repeatability_um: [None, None],
            });
        }
        let axis = table_axis(path)?;
        let t = AxisTable::load(axis, path)?;
        // A table inside a results directory: the directory's summary names its stage.
        let (stage, campaign, line_other_um, repeatability_um) =
            match path.parent().map(|d| d.join("summary.json")) {
                Some(s) if s.is_file() => {
                    let (stage, id, lines) = summary_identity(&s)?;
                    (stage, id, lines, repeatabilities(&summary_json(&s)?))
                }
                _ => (None, None, [None, None], [None, None]),
            };
        Ok(Compensation {
            stage,
            campaign,
            correction: Correction::Lines {
                x: (axis == AxisId::X).then(|| t.clone()),
                y: (axis == AxisId::Y).then_some(t),
                line_other_um,
            },
            source: origin,
            repeatability_um,
        })
    }

    /// Compensation of stored campaign `id` of `stage`, from its result files
    /// (`compensation_x|y.csv`, else `compensation_map_<direction>.csv`, and `summary.json`):
    /// `read(name)` gives a result's bytes, `None` when the campaign has no such file. The store
    /// stays above: the caller reads it.
    pub fn from_results<E: std::fmt::Display>(
        id: i64,
        stage: &str,
        read: impl Fn(&str) -> Result<Option<Vec<u8>>, E>,
    ) -> Result<Compensation, TableError> {
        let origin = format!("campaign {id}");
        // A summary that cannot be read leaves the lines' positions unknown, as before.
        let summary: Option<serde_json::Value> = read("summary.json")
            .ok()
            .flatten()
            .and_then(|b| serde_json::from_slice(&b).ok());
        let text = |name: &str| stored_text(&read, &origin, name);
        let table = |axis: AxisId| -> Result<Option<AxisTable>, TableError> {
            let name = format!("compensation_{axis}.csv");
            text(&name)?
                .map(|(text, at)| AxisTable::parse(axis, &text, &at))
                .transpose()
        };
        let (x, y) = (table(AxisId::X)?, table(AxisId::Y)?);
        let correction = if x.is_some() || y.is_some() {
            Correction::Lines {
                x,
                y,
                line_other_um: summary.as_ref().map_or([None, None], line_positions),
            }
        } else {
            // A map campaign: its maps.
            let mut m = map::MapCompensation::default();
            for d in [Direction::Forward, Direction::Backward] {
                let name = format!("compensation_map_{}.csv", d.as_str());
                if let Some((text, at)) = text(&name)? {
                    m.set(map::MapTable::parse(d, &text, &at)?);
                }
            }
            if m.is_empty() {
                return Err(TableError {
                    origin,
                    line: 0,
                    message: "has no compensation table (a finished characterisation writes compensation_x|y.csv, a map campaign compensation_map_<direction>.csv)".into(),
                });
            }
            if let Some(v) = &summary {
                m.read_summary(v);
            }
            Correction::Map(m)
        };
        Ok(Compensation {
            stage: Some(stage.to_string()),
            campaign: Some(id),
            correction,
            source: origin,
            repeatability_um: summary.as_ref().map_or([None, None], repeatabilities),
        })
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
        within_limits(axis, wanted_um, c, soft_limits_um)?;
        Ok(c)
    }

    /// The other axis's error on `axis` at that axis's command `other_um` approached in `d`,
    /// relative to where it stood while `axis`'s line was measured (that part is already in
    /// `axis`'s own table), µm. Additive errors: true_x = x + A(x) + B(y), where x's line at y₀
    /// measured A(x) + B(y₀) and y's line measured (on x) A(x₀) + B(y); so
    /// B(y) − B(y₀) = cross_y(y) − cross_y(y₀). `None` when the tables cannot say.
    pub fn cross_um(&self, axis: AxisId, other_um: f64, d: Direction) -> Option<f64> {
        let o = self.table(axis.other())?;
        self.table(axis)?;
        let line_at = self.line_other_um()[match axis {
            AxisId::X => 0,
            AxisId::Y => 1,
        }]?;
        // The line's static axis is always approached from below (the engine's rule).
        Some(o.cross_at(d, other_um)? - o.cross_at(Direction::Forward, line_at)?)
    }

    /// Commands (x, y) for a point `wanted` of an XY map's compensation, both axes approached
    /// in the returned direction (`dir`, or the side the map was measured from), inside the
    /// soft limits. [`CommandError::NoTable`] without a map.
    pub fn command_point(
        &self,
        dir: Direction,
        wanted: [f64; 2],
        soft_limits_um: [(f64, f64); 2],
    ) -> Result<([f64; 2], Direction), CommandError> {
        let m = self
            .map()
            .ok_or(CommandError::NoTable { axis: AxisId::X })?;
        let t = m.served(dir);
        let c = t.command(wanted)?;
        within_limits(AxisId::X, wanted[0], c[0], soft_limits_um[0])?;
        within_limits(AxisId::Y, wanted[1], c[1], soft_limits_um[1])?;
        Ok((c, t.direction))
    }

    /// Commands for a move to `wanted` (x, y; `None`: that axis stays at its command
    /// `now_um`), each axis approached in `dir` (or the side its table was measured from):
    /// each axis's own error and the other axis's error on it corrected together (fixed point:
    /// the cross terms depend on the other axis's command). Axes without a table are refused
    /// ([`CommandError::NoTable`]) if they are to move.
    pub fn command_xy(
        &self,
        wanted: [Option<f64>; 2],
        now_um: [f64; 2],
        dir: Direction,
        soft_limits_um: [(f64, f64); 2],
    ) -> Result<[Option<AxisCommand>; 2], CommandError> {
        if self.map().is_some() {
            let (Some(x), Some(y)) = (wanted[0], wanted[1]) else {
                return Err(CommandError::MapNeedsBoth);
            };
            let (c, approach) = self.command_point(dir, [x, y], soft_limits_um)?;
            return Ok(c.map(|command_um| {
                Some(AxisCommand {
                    command_um,
                    approach,
                    cross_um: None,
                })
            }));
        }
        let axes = [AxisId::X, AxisId::Y];
        let mut plan: [Option<AxisCommand>; 2] = [None, None];
        for (i, &axis) in axes.iter().enumerate() {
            if let Some(w) = wanted[i] {
                let t = self.table(axis).ok_or(CommandError::NoTable { axis })?;
                let approach = t.served_direction(dir);
                plan[i] = Some(AxisCommand {
                    command_um: t.command_um(approach, w)?,
                    approach,
                    cross_um: None,
                });
            }
        }
        for _ in 0..MAX_STEPS {
            let cmd = |i: usize| plan[i].map_or(now_um[i], |p| p.command_um);
            let dir_of = |i: usize| plan[i].map_or(dir, |p| p.approach);
            let mut changed = 0.0f64;
            let mut next = plan;
            for (i, &axis) in axes.iter().enumerate() {
                let (Some(p), Some(w)) = (plan[i], wanted[i]) else {
                    continue;
                };
                let cross = self.cross_um(axis, cmd(1 - i), dir_of(1 - i));
                let t = self.table(axis).ok_or(CommandError::NoTable { axis })?;
                let c = t.solve(p.approach, w, w - cross.unwrap_or(0.0))?;
                changed = changed.max((c - p.command_um).abs());
                next[i] = Some(AxisCommand {
                    command_um: c,
                    approach: p.approach,
                    cross_um: cross,
                });
            }
            plan = next;
            if changed <= CONVERGED_UM {
                for (i, &axis) in axes.iter().enumerate() {
                    if let (Some(p), Some(w)) = (plan[i], wanted[i]) {
                        within_limits(axis, w, p.command_um, soft_limits_um[i])?;
                    }
                }
                return Ok(plan);
            }
        }
        let i = usize::from(wanted[0].is_none());
        Err(CommandError::NoConvergence {
            axis: axes[i],
            wanted_um: wanted[i].unwrap_or(f64::NAN),
        })
    }
}

fn within_limits(
    axis: AxisId,
    wanted_um: f64,
    c: f64,
    (lo, hi): (f64, f64),
) -> Result<(), CommandError> {
    if c < lo || c > hi {
        return Err(CommandError::OutsideLimits {
            axis,
            wanted_um,
            command_um: c,
            lo_um: lo,
            hi_um: hi,
        });
    }
    Ok(())
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
    let (origin, text) = read_table_file(path)?;
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

/// A table file's text (regular file, at most [`MAX_TABLE_BYTES`]) and its origin for messages.
fn read_table_file(path: &Path) -> Result<(String, String), TableError> {
    let origin = path.display().to_string();
    let text = crate::tomlpos::read_bounded(path, MAX_TABLE_BYTES).map_err(|m| TableError {
        origin: origin.clone(),
        line: 0,
        message: format!("cannot read: {m}"),
    })?;
    Ok((origin, text))
}

/// Result file `name` as text (`read` gives its bytes), with its origin for messages
/// (`campaign N/name`); `None` when there is no such file.
fn stored_text<E: std::fmt::Display>(
    read: &impl Fn(&str) -> Result<Option<Vec<u8>>, E>,
    origin: &str,
    name: &str,
) -> Result<Option<(String, String)>, TableError> {
    let at = format!("{origin}/{name}");
    let Some(bytes) = read(name).map_err(|e| TableError {
        origin: origin.to_string(),
        line: 0,
        message: e.to_string(),
    })?
    else {
        return Ok(None);
    };
    let text = String::from_utf8(bytes).map_err(|_| TableError {
        origin: at.clone(),
        line: 0,
        message: "not UTF-8 text".into(),
    })?;
    Ok(Some((text, at)))
}

/// Where each axis's line had the other axis standing (`axes[].other_at_um`).
fn line_positions(v: &serde_json::Value) -> [Option<f64>; 2] {
    let mut out = [None, None];
    for a in v["axes"].as_array().into_iter().flatten() {
        let at = a["other_at_um"].as_f64().filter(|p| p.is_finite());
        match a["axis"].as_str() {
            Some("x") => out[0] = at,
            Some("y") => out[1] = at,
            _ => {}
        }
    }
    out
}

/// Unidirectional repeatability of x and y from a results summary: the larger of R↑ and R↓ of
/// `iso230.<axis>.measured` (the bidirectional R holds the reversal, which the compensation
/// corrects per direction), µm; `None` where the characterisation did not measure it.
fn repeatabilities(v: &serde_json::Value) -> [Option<f64>; 2] {
    [AxisId::X, AxisId::Y].map(|a| unidirectional_repeatability_um(v, a))
}

/// One axis's unidirectional repeatability from a results summary (see [`repeatabilities`]).
pub fn unidirectional_repeatability_um(summary: &serde_json::Value, a: AxisId) -> Option<f64> {
    let m = &summary["iso230"][a.as_str()]["measured"];
    [m["r_up_um"].as_f64(), m["r_down_um"].as_f64()]
        .into_iter()
        .flatten()
        .filter(|r| r.is_finite() && *r >= 0.0)
        .reduce(f64::max)
}

/// A results directory's summary.json as JSON.
fn summary_json(path: &Path) -> Result<serde_json::Value, TableError> {
    let origin = path.display().to_string();
    let text = crate::tomlpos::read_bounded(path, 16 << 20).map_err(|m| TableError {
        origin: origin.clone(),
        line: 0,
        message: format!("cannot read: {m}"),
    })?;
    serde_json::from_str(&text).map_err(|e| TableError {
        origin,
        line: e.line(),
        message: "not a results summary (JSON)".into(),
    })
}

/// `stage`, `id` and the lines' static positions from a results directory's summary.json.
#[allow(clippy::type_complexity)]
fn summary_identity(
    path: &Path,
) -> Result<(Option<String>, Option<i64>, [Option<f64>; 2]), TableError> {
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
    Ok((
        v["stage"].as_str().map(str::to_string),
        v["id"].as_i64(),
        line_positions(&v),
    ))
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
            correction: Correction::Lines {
                x: Some(t),
                y: None,
                line_other_um: [None, None],
            },
            source: "t".into(),
            repeatability_um: [None, None],
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
            correction: Correction::Lines {
                x: Some(t),
                y: None,
                line_other_um: [None, None],
            },
            source: "t".into(),
            repeatability_um: [None, None],
        };
        assert!(c.check_covers(AxisId::X, 0.0, 2000.0).is_ok());
        assert!(c.check_covers(AxisId::X, 0.0, 9500.0).is_err());
        assert!(c.check_covers(AxisId::Y, 0.0, 100.0).is_err());
        assert!(c.check_stage("sim-xy").is_ok());
        assert!(c.check_stage("lab-xy").is_err());
    }

    #[test]
    fn the_landing_uncertainty_adds_the_repeatability_from_the_results() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(dir.path().join("compensation_x.csv"), table_text(5.0, true)).unwrap();
        // x measured R↑ 0.08, R↓ 0.12 µm (cycles ≥ 2); y not measured.
        let summary = serde_json::json!({"stage": "sim-xy", "id": 4,
            "axes": [{"axis": "x", "other_at_um": 2100.0}],
            "iso230": {"x": {"measured": {"r_um": 2.1, "r_up_um": 0.08, "r_down_um": 0.12}}}});
        std::fs::write(dir.path().join("summary.json"), summary.to_string()).unwrap();
        let from_dir = Compensation::load(dir.path()).unwrap();
        let from_file = Compensation::load(&dir.path().join("compensation_x.csv")).unwrap();
        let read = |name: &str| Ok::<_, String>(std::fs::read(dir.path().join(name)).ok());
        let stored = Compensation::from_results(4, "sim-xy", read).unwrap();
        for c in [&from_dir, &from_file, &stored] {
            // The unidirectional R (the larger), not the bidirectional one.
            assert_eq!(c.repeatability_um, [Some(0.12), None], "{}", c.source);
            // s = R / 4 in quadrature with the table's u.
            let l = c.landing_u_um(AxisId::X, 0.04);
            assert!(
                (l - (0.04f64.powi(2) + 0.03f64.powi(2)).sqrt()).abs() < 1e-12,
                "{l}"
            );
            // Without R: the table's u alone.
            assert_eq!(c.landing_u_um(AxisId::Y, 0.04), 0.04);
        }
    }
}
