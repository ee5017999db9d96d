//! Measured line-campaign data: the CSV format `csmetro gap` reads, and a seeded generator that
//! simulates the paper's line campaigns from a "real" stage model (for the benchmark and tests).
use std::collections::HashMap;
use std::fmt::Write as _;
use std::path::Path;

use csmetro_effects::{AxisId, Deviation, SampleContext, StageModel};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

/// The CSV header, in this order when written (any column order is accepted when read).
pub const HEADER: [&str; 8] = [
    "run",
    "axis",
    "direction",
    "target_x_um",
    "target_y_um",
    "time_s",
    "meas_x_um",
    "meas_y_um",
];

/// One measured sample of a line.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sample {
    /// Repeated cycle number.
    pub run: i64,
    /// The moving axis of the line.
    pub moving: AxisId,
    /// +1 forward, -1 backward.
    pub direction: f64,
    pub target_x_um: f64,
    pub target_y_um: f64,
    /// Seconds since the start of the data.
    pub time_s: f64,
    /// Measured position, µm; NaN when that component was not measured (an empty CSV field).
    pub meas_x_um: f64,
    pub meas_y_um: f64,
}

/// A campaign's stored samples as gap data: one run per cycle and phase (run = 2·cycle, +1
/// for the full scan), so the diagnosis can hold a whole sweep out; time is the campaign's
/// physical time.
pub fn from_campaign(records: &[crate::types::SampleRecord]) -> Vec<Sample> {
    use crate::types::{AxisId as A, Phase};
    records
        .iter()
        .map(|r| {
            let k = r.target.run;
            Sample {
                run: 2 * k.cycle as i64 + (k.phase == Phase::Full) as i64,
                moving: match k.axis {
                    A::X => AxisId::X,
                    A::Y => AxisId::Y,
                },
                direction: k.direction.sign(),
                target_x_um: r.target.target_x_um,
                target_y_um: r.target.target_y_um,
                time_s: r.time_s,
                meas_x_um: r.meas_x_um,
                meas_y_um: r.meas_y_um,
            }
        })
        .collect()
}

impl Sample {
    pub fn context(&self) -> SampleContext {
        SampleContext {
            moving: self.moving,
            direction: self.direction,
            target_x_um: self.target_x_um,
            target_y_um: self.target_y_um,
            time_s: self.time_s,
        }
    }
    pub fn target(&self, a: AxisId) -> f64 {
        match a {
            AxisId::X => self.target_x_um,
            AxisId::Y => self.target_y_um,
        }
    }
    pub fn meas(&self, a: AxisId) -> f64 {
        match a {
            AxisId::X => self.meas_x_um,
            AxisId::Y => self.meas_y_um,
        }
    }
}

/// The ISO 230-2 export header: one row per (cycle, direction, target) with the deviation, as a
/// laser interferometer or a one-axis sensor run gives it. Required columns (any order):
/// `cycle` (the repeated cycle, >= 0; each cycle is one run and one line), `direction`
/// (forward/backward, up/down or +1/-1), `target_um` and `deviation_um` (measured - target).
/// Optional: `axis` (x or y, default x), `static_um` (position of the other axis, default 0) and
/// `time_s` (default: the row order, 1 s apart).
pub const ISO_HEADER: [&str; 4] = ["cycle", "direction", "target_um", "deviation_um"];
pub const ISO_OPTIONAL: [&str; 3] = ["axis", "static_um", "time_s"];

/// Which of the two accepted CSV formats a file is in.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Format {
    /// The line-campaign format ([`HEADER`]).
    Campaign,
    /// The ISO 230-2 export ([`ISO_HEADER`]); `timed`: it has a `time_s` column.
    Iso230 { timed: bool },
}

fn header_names(header: &str) -> Vec<String> {
    header
        .split(',')
        .map(|s| s.trim().trim_start_matches('\u{feff}').to_ascii_lowercase())
        .collect()
}

/// Why a data file was refused; every message names the file (and the line, when one is to
/// blame).
#[derive(Debug, thiserror::Error)]
pub enum DataError {
    #[error("{origin}:{line}: {problem}")]
    Line {
        origin: String,
        line: usize,
        problem: LineError,
    },
    #[error("{0}: empty file")]
    Empty(String),
    #[error("{0}: empty file (expected header {header})", header = HEADER.join(","))]
    EmptyCampaign(String),
    #[error("{0}: no data rows")]
    NoRows(String),
    /// `place`: `file:line`, or `file: sample N` without lines.
    #[error("{place}: `{key}` = {value} lies outside the model's travel [{lo}, {hi}] µm")]
    OutsideTravel {
        place: String,
        key: &'static str,
        value: f64,
        lo: f64,
        hi: f64,
    },
    #[error("{0}: not a file (only DATA.csv files are accepted for now: campaign storage does not exist yet, so campaign ids cannot be resolved)")]
    NotAFile(String),
    #[error("{path}: cannot read: {source}")]
    Read {
        path: String,
        source: crate::tomlpos::ReadError,
    },
}

/// What is wrong with one line of a data file.
#[derive(Debug, thiserror::Error)]
pub enum LineError {
    #[error("missing column(s) {0} (an ISO 230-2 export needs {iso}; optional {opt})", iso = ISO_HEADER.join(","), opt = ISO_OPTIONAL.join(","))]
    MissingIsoColumns(String),
    #[error("missing column(s) {0} (header must have {header})", header = HEADER.join(","))]
    MissingColumns(String),
    #[error("{got} fields, header has {want}")]
    FieldCount { got: usize, want: usize },
    #[error("`{name}` = {value:?} is not a number")]
    NotANumber { name: &'static str, value: String },
    #[error("`{name}` is {value} (must be finite)")]
    NotFinite { name: &'static str, value: String },
    #[error("`{name}` = {value:?} is not an integer")]
    NotAnInteger { name: &'static str, value: String },
    #[error("`cycle` = {0} is negative")]
    NegativeCycle(i64),
    #[error("`run` = {0} is negative (runs are cycle numbers, >= 0)")]
    NegativeRun(i64),
    #[error("`axis` = {0:?} must be x or y")]
    Axis(String),
    #[error("`direction` = {0:?} must be forward or backward")]
    Direction(String),
    #[error(
        "`meas_x_um` and `meas_y_um` are both empty (a row needs at least one measured component)"
    )]
    NoMeasurement,
    #[error("duplicate row: same cycle, axis, direction and target as line {0}")]
    DuplicateIsoRow(usize),
    #[error("duplicate row: same run, axis, direction, targets and time as line {0}")]
    DuplicateRow(usize),
}

/// Parses either format, told apart by the header (`deviation_um` makes it an ISO 230-2 export).
pub fn parse_any(origin: &str, text: &str) -> Result<(Vec<Sample>, Vec<usize>, Format), DataError> {
    let first = text.lines().find(|l| !l.trim().is_empty()).unwrap_or("");
    if header_names(first).iter().any(|n| n == "deviation_um") {
        let timed = header_names(first).iter().any(|n| n == "time_s");
        parse_iso_lines(origin, text).map(|(s, l)| (s, l, Format::Iso230 { timed }))
    } else {
        parse_csv_lines(origin, text).map(|(s, l)| (s, l, Format::Campaign))
    }
}

fn parse_direction(v: &str) -> Result<f64, LineError> {
    match v.to_ascii_lowercase().as_str() {
        "forward" | "+1" | "1" | "up" => Ok(1.0),
        "backward" | "-1" | "down" => Ok(-1.0),
        s => Err(LineError::Direction(s.to_string())),
    }
}

/// A finite number in field `s` of column `name`.
fn number(name: &'static str, s: &str) -> Result<f64, LineError> {
    let v: f64 = s.parse().map_err(|_| LineError::NotANumber {
        name,
        value: s.to_string(),
    })?;
    if v.is_finite() {
        Ok(v)
    } else {
        Err(LineError::NotFinite {
            name,
            value: s.to_string(),
        })
    }
}

/// Parses an ISO 230-2 export ([`ISO_HEADER`]): the moving axis' measured position is target +
/// deviation, the other component is unmeasured.
pub fn parse_iso_lines(origin: &str, text: &str) -> Result<(Vec<Sample>, Vec<usize>), DataError> {
    let at_line = |line: usize| {
        move |problem: LineError| DataError::Line {
            origin: origin.to_string(),
            line,
            problem,
        }
    };
    let mut lines = text
        .lines()
        .enumerate()
        .filter(|(_, l)| !l.trim().is_empty());
    let (_, header) = lines
        .next()
        .ok_or_else(|| DataError::Empty(origin.to_string()))?;
    let names = header_names(header);
    let col = |h: &str| names.iter().position(|n| n == h);
    let missing: Vec<&str> = ISO_HEADER
        .iter()
        .filter(|h| col(h).is_none())
        .copied()
        .collect();
    if !missing.is_empty() {
        return Err(at_line(1)(LineError::MissingIsoColumns(missing.join(", "))));
    }
    let [c_cycle, c_dir, c_target, c_dev] = ISO_HEADER.map(|h| col(h).unwrap_or(0));
    let (c_axis, c_static, c_time) = (col("axis"), col("static_um"), col("time_s"));
    let mut out = Vec::new();
    let mut at = Vec::new();
    let mut seen: HashMap<(i64, AxisId, bool, [u64; 3]), usize> = HashMap::new();
    for (k, (i, line)) in lines.enumerate() {
        let ln = i + 1;
        let err = at_line(ln);
        let f: Vec<&str> = line.split(',').map(str::trim).collect();
        if f.len() != names.len() {
            return Err(err(LineError::FieldCount {
                got: f.len(),
                want: names.len(),
            }));
        }
        let num = |c: usize, name: &'static str| number(name, f[c]).map_err(err);
        let cycle: i64 = f[c_cycle].parse().map_err(|_| {
            err(LineError::NotAnInteger {
                name: "cycle",
                value: f[c_cycle].to_string(),
            })
        })?;
        if cycle < 0 {
            return Err(err(LineError::NegativeCycle(cycle)));
        }
        let moving = match c_axis {
            Some(c) => AxisId::parse(f[c]).ok_or_else(|| err(LineError::Axis(f[c].to_string())))?,
            None => AxisId::X,
        };
        let direction = parse_direction(f[c_dir]).map_err(err)?;
        let target = num(c_target, "target_um")?;
        let dev = num(c_dev, "deviation_um")?;
        let stat = match c_static {
            Some(c) => num(c, "static_um")?,
            None => 0.0,
        };
        let time_s = match c_time {
            Some(c) => num(c, "time_s")?,
            None => k as f64,
        };
        let (tx, ty) = match moving {
            AxisId::X => (target, stat),
            AxisId::Y => (stat, target),
        };
        let meas = target + dev;
        let sample = Sample {
            run: cycle,
            moving,
            direction,
            target_x_um: tx,
            target_y_um: ty,
            time_s,
            meas_x_um: if moving == AxisId::X { meas } else { f64::NAN },
            meas_y_um: if moving == AxisId::Y { meas } else { f64::NAN },
        };
        let bits = |v: f64| (v + 0.0).to_bits();
        // Without a time column one row per (cycle, axis, direction, target) is all there is.
        let t_key = if c_time.is_some() { bits(time_s) } else { 0 };
        let key = (cycle, moving, direction > 0.0, [bits(tx), bits(ty), t_key]);
        if let Some(first) = seen.insert(key, ln) {
            return Err(err(LineError::DuplicateIsoRow(first)));
        }
        out.push(sample);
        at.push(ln);
    }
    if out.is_empty() {
        return Err(DataError::NoRows(origin.to_string()));
    }
    Ok((out, at))
}

/// Parses campaign CSV text; errors are one line and name `origin` and the line number.
pub fn parse_csv(origin: &str, text: &str) -> Result<Vec<Sample>, DataError> {
    parse_csv_lines(origin, text).map(|(samples, _)| samples)
}

/// Same as [`parse_csv`], with the 1-based file line of every sample (for later checks).
pub fn parse_csv_lines(origin: &str, text: &str) -> Result<(Vec<Sample>, Vec<usize>), DataError> {
    let at_line = |line: usize| {
        move |problem: LineError| DataError::Line {
            origin: origin.to_string(),
            line,
            problem,
        }
    };
    let mut lines = text
        .lines()
        .enumerate()
        .filter(|(_, l)| !l.trim().is_empty());
    let (_, header) = lines
        .next()
        .ok_or_else(|| DataError::EmptyCampaign(origin.to_string()))?;
    let names: Vec<String> = header
        .split(',')
        .map(|s| s.trim().trim_start_matches('\u{feff}').to_ascii_lowercase())
        .collect();
    let mut idx = [0usize; 8];
    let missing: Vec<&str> = HEADER
        .iter()
        .enumerate()
        .filter_map(|(k, h)| match names.iter().position(|n| n == h) {
            Some(i) => {
                idx[k] = i;
                None
            }
            None => Some(*h),
        })
        .collect();
    if !missing.is_empty() {
        return Err(at_line(1)(LineError::MissingColumns(missing.join(", "))));
    }
    let mut out = Vec::new();
    let mut at = Vec::new();
    // One sample per (run, axis, direction, targets, time): a second is a copied row, which
    // would pass for a repeat and shrink the repeatability σ.
    let mut seen: HashMap<(i64, AxisId, bool, [u64; 3]), usize> = HashMap::new();
    // csmetro's samples layout (crate::samples::LAYOUT): a verification's `after` rows were
    // moved with the compensation, so their targets are not what the stage was commanded.
    let pass = names.iter().position(|n| n == "pass");
    for (i, line) in lines {
        let ln = i + 1;
        let err = at_line(ln);
        let f: Vec<&str> = line.split(',').map(str::trim).collect();
        if f.len() != names.len() {
            return Err(err(LineError::FieldCount {
                got: f.len(),
                want: names.len(),
            }));
        }
        if pass.is_some_and(|c| f[c].eq_ignore_ascii_case("after")) {
            continue;
        }
        let num = |k: usize| number(HEADER[k], f[idx[k]]).map_err(err);
        // A component the sensor does not measure is left empty.
        let meas = |k: usize| -> Result<f64, DataError> {
            if f[idx[k]].is_empty() {
                Ok(f64::NAN)
            } else {
                num(k)
            }
        };
        let run_s = f[idx[0]];
        let run: i64 = run_s.parse().map_err(|_| {
            err(LineError::NotAnInteger {
                name: "run",
                value: run_s.to_string(),
            })
        })?;
        if run < 0 {
            return Err(err(LineError::NegativeRun(run)));
        }
        let moving =
            AxisId::parse(f[idx[1]]).ok_or_else(|| err(LineError::Axis(f[idx[1]].to_string())))?;
        let direction = match f[idx[2]].to_ascii_lowercase().as_str() {
            "forward" | "+1" | "1" => 1.0,
            "backward" | "-1" => -1.0,
            s => return Err(err(LineError::Direction(s.to_string()))),
        };
        let sample = Sample {
            run,
            moving,
            direction,
            target_x_um: num(3)?,
            target_y_um: num(4)?,
            time_s: num(5)?,
            meas_x_um: meas(6)?,
            meas_y_um: meas(7)?,
        };
        if sample.meas_x_um.is_nan() && sample.meas_y_um.is_nan() {
            return Err(err(LineError::NoMeasurement));
        }
        // `+ 0.0` makes -0 and 0 one key.
        let bits = |v: f64| (v + 0.0).to_bits();
        let key = (
            run,
            moving,
            direction > 0.0,
            [
                bits(sample.target_x_um),
                bits(sample.target_y_um),
                bits(sample.time_s),
            ],
        );
        if let Some(first) = seen.insert(key, ln) {
            return Err(err(LineError::DuplicateRow(first)));
        }
        out.push(sample);
        at.push(ln);
    }
    if out.is_empty() {
        return Err(DataError::NoRows(origin.to_string()));
    }
    Ok((out, at))
}

/// Refuses samples whose targets lie outside the model's travel: the model's effects (and the
/// maps of the diagnosis) say nothing there. `lines` are the file lines of the samples (CSV);
/// without them a sample is named by its index. Tolerance: the CSV's 0.001 µm resolution.
pub fn check_travel(
    origin: &str,
    samples: &[Sample],
    lines: Option<&[usize]>,
    model: &StageModel,
) -> Result<(), DataError> {
    const TOL_UM: f64 = 1e-3;
    for (i, s) in samples.iter().enumerate() {
        for (axis, key) in [(AxisId::X, "target_x_um"), (AxisId::Y, "target_y_um")] {
            let [lo, hi] = model.travel(axis);
            let v = s.target(axis);
            if v < lo - TOL_UM || v > hi + TOL_UM {
                let place = match lines.and_then(|l| l.get(i)) {
                    Some(ln) => format!("{origin}:{ln}"),
                    None => format!("{origin}: sample {}", i + 1),
                };
                return Err(DataError::OutsideTravel {
                    place,
                    key,
                    value: v,
                    lo,
                    hi,
                });
            }
        }
    }
    Ok(())
}

/// Reads a campaign CSV file (campaign ids are not supported yet: there is no campaign storage).
pub fn read_csv(path: &Path) -> Result<Vec<Sample>, DataError> {
    read_csv_lines(path).map(|(samples, _)| samples)
}

/// Same as [`read_csv`], with the file line of every sample.
pub fn read_csv_lines(path: &Path) -> Result<(Vec<Sample>, Vec<usize>), DataError> {
    read_any(path).map(|(s, l, _)| (s, l))
}

/// Reads a data file in either format (auto-detected from the header).
pub fn read_any(path: &Path) -> Result<(Vec<Sample>, Vec<usize>, Format), DataError> {
    if !path.is_file() {
        return Err(DataError::NotAFile(path.display().to_string()));
    }
    // Bounded like every samples file: a huge file is refused, not read into memory.
    let text = crate::tomlpos::read_bounded(path, crate::samples::MAX_SAMPLES_BYTES).map_err(
        |source| DataError::Read {
            path: path.display().to_string(),
            source,
        },
    )?;
    parse_any(&path.display().to_string(), &text)
}

pub fn to_csv_string(samples: &[Sample]) -> String {
    let mut s = HEADER.join(",");
    s.push('\n');
    let m = |v: f64| {
        if v.is_finite() {
            format!("{v:.6}")
        } else {
            String::new()
        }
    };
    for x in samples {
        let _ = writeln!(
            s,
            "{},{},{},{:.3},{:.3},{:.3},{},{}",
            x.run,
            x.moving,
            if x.direction > 0.0 {
                "forward"
            } else {
                "backward"
            },
            x.target_x_um,
            x.target_y_um,
            x.time_s,
            m(x.meas_x_um),
            m(x.meas_y_um)
        );
    }
    s
}

pub fn write_csv(path: &Path, samples: &[Sample]) -> std::io::Result<()> {
    std::fs::write(path, to_csv_string(samples))
}

/// A line campaign like the paper's 1-DoF characterisation lines: X lines at a few static Y,
/// Y lines at a few static X, each forward then backward over the same targets, repeated `runs`
/// times, time monotone.
#[derive(Debug, Clone)]
pub struct CampaignSpec {
    pub runs: usize,
    pub targets_per_line: usize,
    pub static_positions: usize,
    /// Seconds per sample (move, settle, image).
    pub dt_s: f64,
    /// White measurement noise σ (µm); `None` = the truth model's `noise` effects.
    pub noise_um: Option<f64>,
    /// σ of the per-line unknown constant offsets (static axis error, sensor zero), µm.
    pub line_offset_um: f64,
    pub seed: u64,
}

impl Default for CampaignSpec {
    fn default() -> Self {
        Self {
            runs: 5,
            targets_per_line: 40,
            static_positions: 3,
            dt_s: 2.0,
            noise_um: None,
            line_offset_um: 2.0,
            seed: 1,
        }
    }
}

/// An extra deviation outside the model (e.g. a drift of a shape the library does not have).
pub type Extra<'a> = &'a dyn Fn(&SampleContext) -> Deviation;

/// Target positions of the lines of one moving axis: one random point per cell of a regular
/// partition of the travel (ISO 230-2 style, so periodic errors are sampled), the same every run.
fn line_targets(travel: [f64; 2], n: usize, rng: &mut ChaCha8Rng) -> Vec<f64> {
    let span = travel[1] - travel[0];
    let (lo, span) = (travel[0] + 0.01 * span, 0.98 * span);
    (0..n)
        .map(|i| lo + (i as f64 + rng.random_range(0.1..0.9)) * span / n as f64)
        .collect()
}

/// Simulates a campaign on `truth` (+ `extra`), with noise and per-line offsets.
pub fn simulate_campaign(
    truth: &StageModel,
    spec: &CampaignSpec,
    extra: Option<Extra<'_>>,
) -> Vec<Sample> {
    let mut rng = ChaCha8Rng::seed_from_u64(spec.seed);
    let sigma = spec.noise_um.unwrap_or_else(|| truth.noise_sigma_um());
    let noise = Normal::new(0.0, sigma.max(0.0)).expect("finite sigma");
    let offs = Normal::new(0.0, spec.line_offset_um.max(0.0)).expect("finite sigma");
    let tx = line_targets(truth.travel_x_um, spec.targets_per_line, &mut rng);
    let ty = line_targets(truth.travel_y_um, spec.targets_per_line, &mut rng);
    let statics = |tr: [f64; 2]| -> Vec<f64> {
        let k = spec.static_positions.max(1);
        (0..k)
            .map(|i| tr[0] + (tr[1] - tr[0]) * (i as f64 + 1.0) / (k as f64 + 1.0))
            .collect()
    };
    let sy = statics(truth.travel_y_um);
    let sx = statics(truth.travel_x_um);
    let mut t = 0.0;
    let mut out = Vec::new();
    for run in 1..=spec.runs as i64 {
        for (moving, targets, stat) in [(AxisId::X, &tx, &sy), (AxisId::Y, &ty, &sx)] {
            for &st in stat.iter() {
                let (ox, oy) = (offs.sample(&mut rng), offs.sample(&mut rng));
                let fwd = targets.iter().map(|&p| (p, 1.0));
                let bwd = targets.iter().rev().map(|&p| (p, -1.0));
                for (p, d) in fwd.chain(bwd) {
                    let (x, y) = match moving {
                        AxisId::X => (p, st),
                        AxisId::Y => (st, p),
                    };
                    let c = SampleContext {
                        moving,
                        direction: d,
                        target_x_um: x,
                        target_y_um: y,
                        time_s: t,
                    };
                    let (mut mx, mut my) = truth.predict(&c);
                    if let Some(f) = extra {
                        let e = f(&c);
                        mx += e.x_um;
                        my += e.y_um;
                    }
                    out.push(Sample {
                        run,
                        moving,
                        direction: d,
                        target_x_um: x,
                        target_y_um: y,
                        time_s: t,
                        meas_x_um: mx + ox + noise.sample(&mut rng),
                        meas_y_um: my + oy + noise.sample(&mut rng),
                    });
                    t += spec.dt_s;
                }
                t += 10.0 * spec.dt_s;
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn csv_round_trip_and_errors_name_the_line() {
        let m = StageModel::default();
        let spec = CampaignSpec {
            runs: 2,
            targets_per_line: 5,
            noise_um: Some(0.05),
            ..Default::default()
        };
        let s = simulate_campaign(&m, &spec, None);
        assert_eq!(s.len(), 2 * 6 * 10);
        assert!(s.windows(2).all(|w| w[1].time_s > w[0].time_s));
        let text = to_csv_string(&s);
        let back = parse_csv("d.csv", &text).unwrap();
        assert_eq!(back.len(), s.len());
        assert!((back[7].meas_x_um - s[7].meas_x_um).abs() < 1e-5);
        let bad = text.replacen("forward", "sideways", 1);
        let e = parse_csv("d.csv", &bad).unwrap_err();
        assert!(
            matches!(
                e,
                DataError::Line {
                    line: 2,
                    problem: LineError::Direction(_),
                    ..
                }
            ),
            "{e}"
        );
        let e = e.to_string();
        assert!(e.starts_with("d.csv:2:") && e.contains("direction"), "{e}");
        let mut rows: Vec<&str> = text.lines().collect();
        let nan_row = rows[3].rsplit_once(',').unwrap().0.to_string() + ",NaN";
        rows[3] = &nan_row;
        let e = parse_csv("d.csv", &rows.join("\n"))
            .unwrap_err()
            .to_string();
        assert!(e.starts_with("d.csv:4:") && e.contains("meas_y_um"), "{e}");
        let e = parse_csv("d.csv", "run,axis,direction,target_x_um\n1,x,forward,3\n")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("missing column") && e.contains("meas_x_um"),
            "{e}"
        );
    }
}
