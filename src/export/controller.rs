//! Compensation tables a motion controller loads: `csmetro export ID --format
//! linuxcnc|twincat-lsec|csv --axis x|y --out FILE`.
//!
//! The source is the campaign's compensation (`compensation_x|y.csv`) with the semantics of
//! `csmetro move`: to reach the wanted w approached in direction d, command c_d(w) with
//! c + e_d(c) = w ([`AxisTable::command_um`]). A controller instead adds a correction that it
//! interpolates linearly in the *programmed* (nominal) position between table entries, one
//! column per direction of motion. c_d(w) is piecewise linear in w, with kinks where c crosses
//! a grid point p_i, that is at w = p_i + e_d(p_i) (e is linear between grid points). So the
//! table tabulates c_d(w) - w at those nominals, both directions' kinks on one nominal column:
//! the controller's linear interpolation then lands where `csmetro move` commands, exactly up
//! to the file's number format. When a controller takes fewer entries, they are chosen greedily
//! where the interpolation misses most; the largest miss is reported and bounded.
//!
//! Positions are the stage's own coordinates (as csmetro commands them): the controller's axis
//! must use the same zero.
use crate::compensation::{AxisTable, CommandError};
use crate::types::{AxisId, Direction};

/// A controller table format.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Controller {
    /// LinuxCNC screw compensation, `[JOINT_n] COMP_FILE` with `COMP_FILE_TYPE = 1`.
    LinuxCnc,
    /// Beckhoff TwinCAT CNC (ISG kernel) leadscrew error compensation list, bilateral.
    TwinCatLsec,
    /// csmetro's own bilateral CSV: `nominal_um,forward_correction_um,backward_correction_um`.
    Csv,
}

impl Controller {
    pub fn as_str(self) -> &'static str {
        match self {
            Controller::LinuxCnc => "linuxcnc",
            Controller::TwinCatLsec => "twincat-lsec",
            Controller::Csv => "csv",
        }
    }

    /// Most entries the controller takes.
    pub fn max_points(self) -> usize {
        match self {
            // EMCMOT_COMP_SIZE in src/emc/motion/motion.h: a 257th entry is refused with
            // "too many compensation entries" (command.c, EMCMOT_SET_JOINT_COMP).
            Controller::LinuxCnc => 256,
            // P-COMP-00020: kw_nr_max < P-COMP-00059 (kw.ssfk.max_points), whose default is
            // 1500 (and the fixed maximum before CNC Build V3.1.3079.06).
            Controller::TwinCatLsec => 1499,
            // Bounded by the compensation table itself (two nominals per grid point).
            Controller::Csv => usize::MAX,
        }
    }

    /// The default bound on |controller command - `csmetro move` command|, µm: the file's
    /// resolution (TwinCAT: integers of 0.1 µm, ±0.05 µm) plus 0.01 µm of interpolation.
    pub fn default_max_deviation_um(self) -> f64 {
        match self {
            Controller::TwinCatLsec => 0.06,
            Controller::LinuxCnc | Controller::Csv => 0.01,
        }
    }
}

/// The length unit of a TwinCAT list (P-COMP-00017 `kw.ssfk.unit`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum LsecUnit {
    /// `unit = 1`: integers of 0.1 µm (the default: it needs nothing of the machine).
    Metric,
    /// `unit = 0`: integers of the axis's encoder increment, this many µm (from the CNC's
    /// axis parameters): finer than 0.1 µm on a stage like the M-111.1DG.
    Increments(f64),
}

impl LsecUnit {
    /// Smallest and largest increment accepted, µm.
    pub const INCREMENT_RANGE_UM: (f64, f64) = (1e-4, 10.0);

    /// One unit of the list, µm.
    pub fn um(self) -> f64 {
        match self {
            LsecUnit::Metric => 0.1,
            LsecUnit::Increments(q) => q,
        }
    }

    /// The default deviation bound: half a unit of rounding plus 0.01 µm of interpolation.
    pub fn default_max_deviation_um(self) -> f64 {
        match self {
            LsecUnit::Metric => Controller::TwinCatLsec.default_max_deviation_um(),
            LsecUnit::Increments(q) => q / 2.0 + 0.01,
        }
    }
}

/// A bilateral table as the controller reads it: at nominal (programmed) position w, µm, the
/// command is w + correction of the direction of motion, interpolated linearly between rows.
#[derive(Debug, Clone, PartialEq)]
pub struct Bilateral {
    /// Strictly increasing, µm.
    pub nominal_um: Vec<f64>,
    pub forward_um: Vec<f64>,
    pub backward_um: Vec<f64>,
}

impl Bilateral {
    /// The interpolated command for `w` in direction `d`, µm (ends held, as LinuxCNC does).
    pub fn command_um(&self, d: Direction, w: f64) -> f64 {
        let c = match d {
            Direction::Forward => &self.forward_um,
            Direction::Backward => &self.backward_um,
        };
        w + lerp(&self.nominal_um, c, w)
    }
}

/// Linear interpolation of (x, y) at `w`, ends held.
fn lerp(x: &[f64], y: &[f64], w: f64) -> f64 {
    let i = x.partition_point(|&q| q <= w).clamp(1, x.len() - 1);
    let t = ((w - x[i - 1]) / (x[i] - x[i - 1])).clamp(0.0, 1.0);
    y[i - 1] + t * (y[i] - y[i - 1])
}

/// Why no controller table was written.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ControllerError {
    #[error("{origin}: no {missing} correction: a controller table is bilateral (characterise with directions = [\"forward\", \"backward\"])")]
    OneDirection {
        origin: String,
        missing: &'static str,
    },
    #[error("{origin}: {source}")]
    Command {
        origin: String,
        source: CommandError,
    },
    #[error("{origin}: no wanted position of [{lo_um}, {hi_um}] µm has a command in both directions (corrections larger than the grid step at the ends)")]
    EmptyRange {
        origin: String,
        lo_um: f64,
        hi_um: f64,
    },
    #[error("{origin}: a setpoint in units of {unit_um} µm does not fit the list's 32-bit integers (a larger --increment-um)")]
    Unit { origin: String, unit_um: f64 },
    #[error("{format}: with at most {points} entries the controller would command up to {deviation_um:.4} µm away from `csmetro move` (allowed {allowed_um} µm; raise --max-deviation-um or characterise a shorter travel)")]
    TooCoarse {
        format: &'static str,
        points: usize,
        deviation_um: f64,
        allowed_um: f64,
    },
}

/// A written controller table.
#[derive(Debug, Clone)]
pub struct Written {
    pub text: String,
    pub axis: AxisId,
    pub format: Controller,
    /// The table as the controller reads it back, µm.
    pub table: Bilateral,
    /// Wanted positions the table serves, µm: where `csmetro move` has a command in both
    /// directions (beyond them the controller holds the end corrections; csmetro refuses).
    pub range_um: (f64, f64),
    /// Largest |controller command - `csmetro move` command| over both directions, µm.
    pub max_deviation_um: f64,
}

/// The exact tabulation: every kink of both directions' c_d(w) - w in the served range.
fn exact(t: &AxisTable) -> Result<(Bilateral, (f64, f64)), ControllerError> {
    let origin = t.origin.clone();
    for (d, v) in [
        (Direction::Forward, &t.forward_um),
        (Direction::Backward, &t.backward_um),
    ] {
        if v.is_none() {
            return Err(ControllerError::OneDirection {
                origin,
                missing: d.as_str(),
            });
        }
    }
    let x = &t.positions_um;
    let (lo, hi) = t.range_um();
    let (m_lo, m_hi) = (x[1] - x[0], x[x.len() - 1] - x[x.len() - 2]);
    // `csmetro move` refuses a command more than one grid step beyond the table; near the ends
    // e is held, so the served wanted range is where c = w - e(end) stays within that step.
    let mut a = lo;
    let mut b = hi;
    for d in [Direction::Forward, Direction::Backward] {
        a = a.max(lo - m_lo + t.error_at(d, lo));
        b = b.min(hi + m_hi + t.error_at(d, hi));
    }
    // Off the exact edge, where the fixed-point iteration's tolerance could tip it outside.
    if a > lo {
        a += 1e-6;
    }
    if b < hi {
        b -= 1e-6;
    }
    if a >= b {
        return Err(ControllerError::EmptyRange {
            origin,
            lo_um: lo,
            hi_um: hi,
        });
    }
    let mut w = vec![a, b];
    for d in [Direction::Forward, Direction::Backward] {
        w.extend(
            x.iter()
                .map(|&p| p + t.error_at(d, p))
                .filter(|&k| k > a && k < b),
        );
    }
    w.sort_by(f64::total_cmp);
    w.dedup_by(|p, q| (*p - *q).abs() < 1e-9);
    let corr = |d: Direction| -> Result<Vec<f64>, ControllerError> {
        w.iter()
            .map(|&k| {
                t.command_um(d, k)
                    .map(|c| c - k)
                    .map_err(|source| ControllerError::Command {
                        origin: origin.clone(),
                        source,
                    })
            })
            .collect()
    };
    let forward_um = corr(Direction::Forward)?;
    let backward_um = corr(Direction::Backward)?;
    Ok((
        Bilateral {
            nominal_um: w,
            forward_um,
            backward_um,
        },
        (a, b),
    ))
}

/// At most `max` rows of `full` (its first and last kept), inserted greedily where linear
/// interpolation between the kept rows misses `full` most (both directions). `full` is
/// piecewise linear between its rows, so the miss is largest at one of them.
fn reduce(full: &Bilateral, max: usize) -> Bilateral {
    let n = full.nominal_um.len();
    if n <= max {
        return full.clone();
    }
    let miss = |i: usize, j: usize| -> (f64, usize) {
        let (x, f, b) = (&full.nominal_um, &full.forward_um, &full.backward_um);
        let mut worst = (0.0, i);
        for k in i + 1..j {
            let t = (x[k] - x[i]) / (x[j] - x[i]);
            let e = (f[i] + t * (f[j] - f[i]) - f[k])
                .abs()
                .max((b[i] + t * (b[j] - b[i]) - b[k]).abs());
            if e > worst.0 {
                worst = (e, k);
            }
        }
        worst
    };
    let mut kept = vec![0, n - 1];
    // (start, end, miss, where) per interval between kept rows.
    let mut segs = vec![{
        let (e, k) = miss(0, n - 1);
        (0, n - 1, e, k)
    }];
    while kept.len() < max.max(2) {
        let (s, &(i, j, e, k)) = segs
            .iter()
            .enumerate()
            .max_by(|p, q| p.1 .2.total_cmp(&q.1 .2))
            .expect("one interval at least");
        if e <= 1e-7 {
            break;
        }
        let (e1, k1) = miss(i, k);
        let (e2, k2) = miss(k, j);
        segs[s] = (i, k, e1, k1);
        segs.push((k, j, e2, k2));
        kept.push(k);
    }
    kept.sort_unstable();
    let pick = |v: &[f64]| kept.iter().map(|&i| v[i]).collect::<Vec<f64>>();
    Bilateral {
        nominal_um: pick(&full.nominal_um),
        forward_um: pick(&full.forward_um),
        backward_um: pick(&full.backward_um),
    }
}

/// A number as written and as read back (the file's own rounding is part of the table).
fn fixed(v: f64, decimals: usize) -> (String, f64) {
    let s = format!("{v:.decimals$}");
    // A formatted finite f64 always parses back.
    let back = s.parse().unwrap_or(v);
    (s, back)
}

/// Writes the table of `t` in `format`; `max_deviation_um` bounds the difference between the
/// controller's command and `csmetro move`'s at any wanted position of the served range.
pub fn write(
    t: &AxisTable,
    format: Controller,
    campaign: i64,
    max_deviation_um: f64,
) -> Result<Written, ControllerError> {
    write_in(t, format, LsecUnit::Metric, campaign, max_deviation_um)
}

/// [`write`] with the TwinCAT list's length unit (ignored by the other formats).
pub fn write_in(
    t: &AxisTable,
    format: Controller,
    unit: LsecUnit,
    campaign: i64,
    max_deviation_um: f64,
) -> Result<Written, ControllerError> {
    let (full, range) = exact(t)?;
    let reduced = reduce(&full, format.max_points());
    let (text, table) = match format {
        Controller::LinuxCnc => linuxcnc(&reduced),
        Controller::Csv => csv(&reduced),
        Controller::TwinCatLsec => twincat(t, &reduced, unit, campaign)?,
    };
    // Every kink of the exact commands and every row of the table: both sides are linear in
    // between, so the largest difference is at one of them.
    let mut deviation: f64 = 0.0;
    for (k, &w) in full.nominal_um.iter().enumerate() {
        deviation = deviation
            .max((table.command_um(Direction::Forward, w) - (w + full.forward_um[k])).abs())
            .max((table.command_um(Direction::Backward, w) - (w + full.backward_um[k])).abs());
    }
    for (k, &w) in table.nominal_um.iter().enumerate() {
        for (d, c) in [
            (Direction::Forward, table.forward_um[k]),
            (Direction::Backward, table.backward_um[k]),
        ] {
            let exact = t
                .command_um(d, w)
                .map_err(|source| ControllerError::Command {
                    origin: t.origin.clone(),
                    source,
                })?;
            deviation = deviation.max((w + c - exact).abs());
        }
    }
    if deviation > max_deviation_um {
        return Err(ControllerError::TooCoarse {
            format: format.as_str(),
            points: table.nominal_um.len(),
            deviation_um: deviation,
            allowed_um: max_deviation_um,
        });
    }
    Ok(Written {
        text,
        axis: t.axis,
        format,
        table,
        range_um: range,
        max_deviation_um: deviation,
    })
}

/// LinuxCNC `COMP_FILE_TYPE = 1`: one line per entry, `nominal forward_trim reverse_trim`,
/// whitespace separated, nominal strictly ascending, in machine units (mm here: write
/// `LINEAR_UNITS = mm` for the joint). Sources: LinuxCNC INI configuration docs, `[JOINT_n]`
/// `COMP_FILE` / `COMP_FILE_TYPE` (linuxcnc.org/docs/stable/html/config/ini-config.html); the loader
/// `usrmotLoadComp` (src/emc/motion/usrmotintf.cc: type 0 holds actual positions and is turned
/// into trims as nominal - actual, type 1 holds the trims); `compute_screw_comp`
/// (src/emc/motion/control.c: the trim of the direction of `vel_cmd`, linear in `pos_cmd`
/// between entries, the last one kept at rest, ends held) and `motor_pos_cmd = pos_cmd +
/// backlash_filt + motor_offset` (the trim is added to the commanded position). The loader
/// stops at the first line that is not three numbers, so the file has no comment or header.
fn linuxcnc(b: &Bilateral) -> (String, Bilateral) {
    let mut text = String::new();
    let mut back = Bilateral {
        nominal_um: Vec::new(),
        forward_um: Vec::new(),
        backward_um: Vec::new(),
    };
    for k in 0..b.nominal_um.len() {
        // mm with 9 decimals: 1e-6 µm steps.
        let (n, nb) = fixed(b.nominal_um[k] / 1000.0, 9);
        let (f, fb) = fixed(b.forward_um[k] / 1000.0, 9);
        let (r, rb) = fixed(b.backward_um[k] / 1000.0, 9);
        text.push_str(&format!("{n} {f} {r}\n"));
        back.nominal_um.push(nb * 1000.0);
        back.forward_um.push(fb * 1000.0);
        back.backward_um.push(rb * 1000.0);
    }
    (text, back)
}

/// csmetro's bilateral CSV: command = nominal_um + the correction of the approach direction,
/// linear between rows, rows ascending; wanted positions outside the first and last row are
/// outside the compensation.
fn csv(b: &Bilateral) -> (String, Bilateral) {
    let mut text = String::from("nominal_um,forward_correction_um,backward_correction_um\n");
    let mut back = Bilateral {
        nominal_um: Vec::new(),
        forward_um: Vec::new(),
        backward_um: Vec::new(),
    };
    for k in 0..b.nominal_um.len() {
        let (n, nb) = fixed(b.nominal_um[k], 6);
        let (f, fb) = fixed(b.forward_um[k], 6);
        let (r, rb) = fixed(b.backward_um[k], 6);
        text.push_str(&format!("{n},{f},{r}\n"));
        back.nominal_um.push(nb);
        back.forward_um.push(fb);
        back.backward_um.push(rb);
    }
    (text, back)
}

/// TwinCAT CNC leadscrew error compensation list (`kw.ssfk.*`), bilateral, non-equidistant.
/// Sources: Beckhoff Information System, TF5200 TwinCAT 3 CNC "Axis compensation":
/// "Leadscrew error compensation" (the position setpoint is changed by a compensation value,
/// interpolated linearly between interpolation points; bilateral = one table per direction of
/// motion), "Compensation value lists" and "Comments in the ASCII file" (`# ` comment lines),
/// the parameters P-COMP-00017 `unit` (1: metric, 0.1 µm; 0: encoder increments), P-COMP-00018 `interval` (0: each
/// interpolation point given), P-COMP-00019 `kw_startpos`, P-COMP-00020 `kw_nr_max` (<
/// P-COMP-00059, default 1500), P-COMP-00021 `bilateral`, P-COMP-00023/24 `table[i].pos|neg`
/// (SGN32, "specified as absolute position errors": in the documented example
/// Δs = s_actual - s_setpoint), P-COMP-00025 `table[i].setpoint`, and the example list.
///
/// Doubtful, not stated there: that the CNC *subtracts* the interpolated error from the
/// setpoint (the only reading under which a table of measured errors compensates) and indexes
/// it by the uncompensated setpoint. So the value at setpoint s is s - c(s): what the stage
/// would be off by if commanded s without correction, to the extent that the CNC's output
/// s - Δ(s) is csmetro's command c(s). Setpoints and values are written as integers of
/// the unit, 0.1 µm or the given encoder increment (SGN32 before CNC Build V3.1.3132.0); the
/// logical axis number is 1 for x, 2 for y (edit `kopf.achs_nr` if the CNC numbers them
/// otherwise).
fn twincat(
    t: &AxisTable,
    b: &Bilateral,
    unit: LsecUnit,
    campaign: i64,
) -> Result<(String, Bilateral), ControllerError> {
    let n = b.nominal_um.len();
    let q_um = unit.um();
    // Units per µm: exactly 10 for the metric list (as written before increments existed).
    let per_um = match unit {
        LsecUnit::Metric => 10.0,
        LsecUnit::Increments(q) => 1.0 / q,
    };
    // Setpoints on the unit's lattice, inside the served range (ceil the first, floor the last).
    let mut s: Vec<i64> = b
        .nominal_um
        .iter()
        .enumerate()
        .map(|(k, &w)| {
            let q = w * per_um;
            (if k == 0 {
                q.ceil()
            } else if k == n - 1 {
                q.floor()
            } else {
                q.round()
            }) as i64
        })
        .collect();
    s.dedup();
    if s.len() < 2 || s.windows(2).any(|p| p[0] >= p[1]) {
        // A served range shorter than the unit's lattice.
        let (lo_um, hi_um) = t.range_um();
        return Err(ControllerError::EmptyRange {
            origin: t.origin.clone(),
            lo_um,
            hi_um,
        });
    }
    let mut back = Bilateral {
        nominal_um: Vec::new(),
        forward_um: Vec::new(),
        backward_um: Vec::new(),
    };
    let mut pos = Vec::new();
    let mut neg = Vec::new();
    if s.iter().any(|v| i32::try_from(*v).is_err()) {
        return Err(ControllerError::Unit {
            origin: t.origin.clone(),
            unit_um: q_um,
        });
    }
    for &si in &s {
        let w = si as f64 / per_um;
        let err = |d: Direction| -> Result<i64, ControllerError> {
            let c = t
                .command_um(d, w)
                .map_err(|source| ControllerError::Command {
                    origin: t.origin.clone(),
                    source,
                })?;
            Ok(((w - c) * per_um).round() as i64)
        };
        let (p, q) = (err(Direction::Forward)?, err(Direction::Backward)?);
        pos.push(p);
        neg.push(q);
        back.nominal_um.push(w);
        back.forward_um.push(-(p as f64) / per_um);
        back.backward_um.push(-(q as f64) / per_um);
    }
    let (unit_flag, unit_line) = match unit {
        LsecUnit::Metric => (1, "Lengths in 0.1 um (kw.ssfk.unit = 1).".to_string()),
        LsecUnit::Increments(q) => (
            0,
            format!(
                "Lengths in encoder increments of {q} um (kw.ssfk.unit = 0): valid only on an axis whose increment is {q} um."
            ),
        ),
    };
    let name = t.axis.as_str().to_ascii_uppercase();
    let nr = match t.axis {
        AxisId::X => 1,
        AxisId::Y => 2,
    };
    let mut text = format!(
        "# csmetro campaign {campaign}, axis {name}: bilateral leadscrew error compensation (LSEC)\n\
         # {unit_line}\n\
         # pos/neg: the position error at the setpoint for motion in the positive/negative\n\
         # direction, taken off the setpoint (linear in between).\n\
         # Served setpoints {} to {} (list units); positions in the stage's own coordinates.\n\
         kopf.achs_nr                 {nr}\n\
         kopf.log_achs_name           {name}\n\
         kw.ssfk.unit                 {unit_flag}\n\
         kw.ssfk.bilateral            1\n\
         kw.ssfk.modulo               0\n\
         kw.ssfk.interval             0\n\
         kw.ssfk.kw_startpos          {}\n\
         kw.ssfk.kw_nr_max            {}\n",
        s[0],
        s[s.len() - 1],
        s[0],
        s.len()
    );
    for (i, v) in s.iter().enumerate() {
        text.push_str(&format!("kw.ssfk.table[{i}].setpoint {v}\n"));
    }
    for (i, v) in pos.iter().enumerate() {
        text.push_str(&format!("kw.ssfk.table[{i}].pos {v}\n"));
    }
    for (i, v) in neg.iter().enumerate() {
        text.push_str(&format!("kw.ssfk.table[{i}].neg {v}\n"));
    }
    Ok((text, back))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A stage written here: 400 µm cyclic error, scale error, a 2 µm reversal.
    fn e(d: Direction, p: f64) -> f64 {
        1.5 * (2.0 * std::f64::consts::PI * p / 400.0 + 0.7).sin() + 80e-6 * p + d.sign()
    }

    fn table(step: f64, end: f64, both: bool) -> AxisTable {
        let mut s =
            String::from("position_um,ef_xx_um,eb_xx_um,corr_forward_um,corr_backward_um\n");
        let n = (end / step).round() as usize;
        for i in 0..=n {
            let p = i as f64 * step;
            let (f, b) = (e(Direction::Forward, p), e(Direction::Backward, p));
            if both {
                s.push_str(&format!("{p},{f},{b},{},{}\n", -f, -b));
            } else {
                s.push_str(&format!("{p},{f},,{},\n", -f));
            }
        }
        AxisTable::parse(AxisId::X, &s, "t.csv").unwrap()
    }

    #[test]
    fn a_table_within_the_limit_reproduces_the_move_command_between_its_rows() {
        let t = table(5.0, 600.0, true);
        for f in [Controller::LinuxCnc, Controller::Csv] {
            let w = write(&t, f, 1, 0.01).unwrap();
            assert!(w.table.nominal_um.len() <= f.max_points());
            assert!(w.max_deviation_um < 1e-5, "{f:?}: {}", w.max_deviation_um);
            // Off every row: 0.37 µm steps through the range.
            let (a, b) = w.range_um;
            let mut x = a;
            while x < b {
                for d in [Direction::Forward, Direction::Backward] {
                    let c = t.command_um(d, x).unwrap();
                    assert!((w.table.command_um(d, x) - c).abs() < 1e-5, "{f:?} {x}");
                }
                x += 0.37;
            }
        }
        let w = write(&t, Controller::TwinCatLsec, 1, 0.06).unwrap();
        assert!(w.max_deviation_um <= 0.0501, "{}", w.max_deviation_um);
    }

    #[test]
    fn a_long_table_is_reduced_to_the_limit_and_its_miss_is_bounded() {
        // 9500 µm every 5 µm: 1901 grid points, ~3800 kinks, LinuxCNC takes 256.
        let t = table(5.0, 9500.0, true);
        let w = write(&t, Controller::LinuxCnc, 1, 1.0).unwrap();
        assert_eq!(w.table.nominal_um.len(), 256);
        assert!(
            w.max_deviation_um > 0.01 && w.max_deviation_um < 0.2,
            "{}",
            w.max_deviation_um
        );
        let e = write(&t, Controller::LinuxCnc, 1, 0.01).unwrap_err();
        assert!(
            matches!(e, ControllerError::TooCoarse { points: 256, .. }),
            "{e}"
        );
        assert!(e.to_string().contains("--max-deviation-um"), "{e}");
        // Nominals strictly ascending, as LinuxCNC requires.
        assert!(w.table.nominal_um.windows(2).all(|p| p[0] < p[1]));
    }

    #[test]
    fn a_one_direction_table_is_refused() {
        let t = table(5.0, 600.0, false);
        let e = write(&t, Controller::Csv, 1, 0.01).unwrap_err();
        assert!(e.to_string().contains("no backward correction"), "{e}");
    }

    #[test]
    fn corrections_beyond_the_grid_step_at_both_ends_leave_nothing_to_serve() {
        let t = AxisTable::parse(
            AxisId::X,
            "position_um,ef_xx_um,eb_xx_um,corr_forward_um,corr_backward_um\n0,5,5,-5,-5\n1,5,5,-5,-5\n",
            "steep.csv",
        )
        .unwrap();
        let e = write(&t, Controller::LinuxCnc, 1, 0.01).unwrap_err();
        assert!(matches!(e, ControllerError::EmptyRange { .. }), "{e}");
        assert!(e.to_string().starts_with("steep.csv: "), "{e}");
    }

    #[test]
    fn the_files_have_the_documented_shape() {
        let t = table(10.0, 200.0, true);
        let l = write(&t, Controller::LinuxCnc, 1, 0.01).unwrap();
        for line in l.text.lines() {
            let v: Vec<f64> = line
                .split_whitespace()
                .map(|s| s.parse().unwrap())
                .collect();
            assert_eq!(v.len(), 3, "{line}");
        }
        let tw = write(&t, Controller::TwinCatLsec, 7, 0.06).unwrap();
        let n = tw.table.nominal_um.len();
        assert!(tw
            .text
            .contains(&format!("kw.ssfk.kw_nr_max            {n}\n")));
        assert!(tw.text.contains("kw.ssfk.bilateral            1\n"));
        assert!(tw.text.contains(&format!("kw.ssfk.table[{}].neg ", n - 1)));
        assert!(tw.text.lines().all(|l| l.is_ascii()));
        let c = write(&t, Controller::Csv, 1, 0.01).unwrap();
        assert!(c
            .text
            .starts_with("nominal_um,forward_correction_um,backward_correction_um\n"));
    }

    #[test]
    fn encoder_increments_are_unit_0_and_round_to_half_an_increment() {
        let t = table(10.0, 200.0, true);
        let unit = LsecUnit::Increments(0.0035);
        let tw = write_in(&t, Controller::TwinCatLsec, unit, 7, 0.01).unwrap();
        assert!(tw.text.contains("kw.ssfk.unit                 0\n"));
        assert!(tw.text.contains("increments of 0.0035 um"));
        // Rounding to 0.0035 µm: at most half of it off (the metric list: 0.05 µm).
        assert!(
            tw.max_deviation_um <= 0.0035 / 2.0 + 1e-9,
            "{}",
            tw.max_deviation_um
        );
        let m = write(&t, Controller::TwinCatLsec, 7, 0.06).unwrap();
        assert!(m.max_deviation_um > tw.max_deviation_um);
        // A setpoint past the list's 32-bit integers is refused, not wrapped.
        let far = write_in(
            &t,
            Controller::TwinCatLsec,
            LsecUnit::Increments(1e-8),
            7,
            1.0,
        );
        assert!(matches!(far, Err(ControllerError::Unit { .. })), "{far:?}");
    }
}
