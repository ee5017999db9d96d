//! Rows as SQLite holds them: the column lists, and samples and campaigns encoded to and
//! decoded from their columns (exact REALs, the bits of the values SQLite would not keep).
use rusqlite::Row;

use super::{CampaignRow, RowError};
use crate::types::{AxisId, CampaignState, Direction, Phase, RunKey, SampleRecord, Target};

pub(super) const CAMPAIGN_COLS: &str = "id, name, spec_toml, spec_path, stage, state, planned, \
     created_unix_s, updated_unix_s, message";

pub(super) const SAMPLE_COLS: &str =
    "seq, phase, axis, direction, cycle, grid_index, target_x_um, \
     target_y_um, meas_x_um, meas_y_um, theta_mrad, encoder_um, time_s, unix_s, quality, frames, \
     rejected, point_s, raw_bits, frame_sd_x_um, frame_sd_y_um";

/// The REAL columns of a sample, in [`SAMPLE_COLS`] order (indices 6..=14 and 17).
const REAL_NAMES: [&str; 10] = [
    "target_x_um",
    "target_y_um",
    "meas_x_um",
    "meas_y_um",
    "theta_mrad",
    "encoder_um",
    "time_s",
    "unix_s",
    "quality",
    "point_s",
];

pub(super) fn reals(s: &SampleRecord) -> [f64; 10] {
    [
        s.target.target_x_um,
        s.target.target_y_um,
        s.meas_x_um,
        s.meas_y_um,
        s.theta_mrad,
        s.encoder_um,
        s.time_s,
        s.unix_s,
        s.quality,
        s.point_s,
    ]
}

/// A value SQLite stores exactly as REAL (everything but NaN and -0.0).
fn real_is_exact(v: f64) -> bool {
    !(v.is_nan() || (v == 0.0 && v.is_sign_negative()))
}

/// `name:hex-bits` of the values SQLite would not keep exactly, comma-separated; None if none.
pub(super) fn raw_bits(vals: &[f64; 10]) -> Option<String> {
    let parts: Vec<String> = REAL_NAMES
        .iter()
        .zip(vals)
        .filter(|(_, v)| !real_is_exact(**v))
        .map(|(n, v)| format!("{n}:{:016x}", v.to_bits()))
        .collect();
    (!parts.is_empty()).then(|| parts.join(","))
}

pub(super) fn u64_from(value: i64, what: &'static str) -> Result<u64, RowError> {
    u64::try_from(value).map_err(|_| RowError::Negative { what, value })
}

fn u32_from(value: i64, what: &'static str) -> Result<u32, RowError> {
    u32::try_from(value).map_err(|_| RowError::NotU32 { what, value })
}

pub(super) fn i64_from(value: u64, what: &'static str) -> Result<i64, RowError> {
    i64::try_from(value).map_err(|_| RowError::NotI64 { what, value })
}

/// A raw sample row, decoded into a record (or what is wrong with it).
pub(super) fn sample_from_row(row: &Row<'_>) -> rusqlite::Result<Result<SampleRecord, RowError>> {
    sample_from_row_at(row, 0)
}

/// A sample whose [`SAMPLE_COLS`] start at column `o` of the row.
pub(super) fn sample_from_row_at(
    row: &Row<'_>,
    o: usize,
) -> rusqlite::Result<Result<SampleRecord, RowError>> {
    let seq: i64 = row.get(o)?;
    let phase: String = row.get(o + 1)?;
    let axis: String = row.get(o + 2)?;
    let direction: String = row.get(o + 3)?;
    let cycle: i64 = row.get(o + 4)?;
    let grid_index: i64 = row.get(o + 5)?;
    let mut vals = [0.0f64; 10];
    for (i, idx) in (6..=14).chain([17]).enumerate() {
        let v: Option<f64> = row.get(o + idx)?;
        vals[i] = v.unwrap_or(f64::NAN);
    }
    let frames: i64 = row.get(o + 15)?;
    let rejected: i64 = row.get(o + 16)?;
    let raw: Option<String> = row.get(o + 18)?;
    let sd_x: Option<f64> = row.get(o + 19)?;
    let sd_y: Option<f64> = row.get(o + 20)?;
    Ok((|| {
        if let Some(raw) = raw {
            for part in raw.split(',').filter(|p| !p.is_empty()) {
                let (name, hex) = part
                    .split_once(':')
                    .ok_or_else(|| RowError::RawBitsEntry(part.to_string()))?;
                let i = REAL_NAMES
                    .iter()
                    .position(|n| *n == name)
                    .ok_or_else(|| RowError::RawBitsColumn(name.to_string()))?;
                let bits = u64::from_str_radix(hex, 16).map_err(|source| RowError::RawBitsHex {
                    part: part.to_string(),
                    source,
                })?;
                vals[i] = f64::from_bits(bits);
            }
        }
        let seq = u64_from(seq, "seq")?;
        let unknown = |what, value: &str| RowError::Unknown {
            seq,
            what,
            value: value.to_string(),
        };
        let [target_x_um, target_y_um, meas_x_um, meas_y_um, theta_mrad, encoder_um, time_s, unix_s, quality, point_s] =
            vals;
        Ok(SampleRecord {
            target: Target {
                seq,
                run: RunKey {
                    phase: Phase::parse(&phase).ok_or_else(|| unknown("phase", &phase))?,
                    axis: AxisId::parse(&axis).ok_or_else(|| unknown("axis", &axis))?,
                    direction: parse_direction(&direction)
                        .ok_or_else(|| unknown("direction", &direction))?,
                    cycle: u32_from(cycle, "cycle")?,
                },
                grid_index: usize::try_from(grid_index).map_err(|_| {
                    RowError::NegativeGridIndex {
                        seq,
                        value: grid_index,
                    }
                })?,
                target_x_um,
                target_y_um,
            },
            meas_x_um,
            meas_y_um,
            theta_mrad,
            encoder_um,
            time_s,
            unix_s,
            quality,
            frames: u32_from(frames, "frames")?,
            rejected: u32_from(rejected, "rejected")?,
            point_s,
            frame_sd_um: sd_x.zip(sd_y).map(|(x, y)| [x, y]),
        })
    })())
}

fn parse_direction(s: &str) -> Option<Direction> {
    [Direction::Forward, Direction::Backward]
        .into_iter()
        .find(|d| d.as_str() == s)
}

/// A raw campaign row, decoded (or what is wrong with it).
pub(super) fn campaign_from_row(row: &Row<'_>) -> rusqlite::Result<Result<CampaignRow, RowError>> {
    let id: i64 = row.get(0)?;
    let state: String = row.get(5)?;
    let planned: i64 = row.get(6)?;
    let partial = CampaignRow {
        id,
        name: row.get(1)?,
        spec_toml: row.get(2)?,
        spec_path: row.get(3)?,
        stage: row.get(4)?,
        state: CampaignState::Queued,
        planned: 0,
        created_unix_s: row.get(7)?,
        updated_unix_s: row.get(8)?,
        message: row.get(9)?,
    };
    Ok((|| {
        Ok(CampaignRow {
            state: CampaignState::parse(&state).ok_or_else(|| RowError::State {
                id,
                value: state.clone(),
            })?,
            planned: u64_from(planned, "planned")?,
            ..partial
        })
    })())
}
