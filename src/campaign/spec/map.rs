//! `[map]`: an XY workspace map campaign (both axes move to random points of the plane, the
//! camera measures x, y and θ at each). Validated here like the rest of the file: every error
//! names the file, the line and the key.
use super::*;
use crate::recon2d::{Grid2, Method2};
use crate::sampling2d::{Design2, Design2Kind, Polygon};

/// `[map]` as written.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MapSpec {
    /// Map grid along x and y: `[start, end]` µm.
    #[serde(deserialize_with = "exactly_two")]
    pub x_range_um: [f64; 2],
    #[serde(deserialize_with = "exactly_two")]
    pub y_range_um: [f64; 2],
    /// Grid steps `[x, y]`, µm.
    #[serde(deserialize_with = "exactly_two")]
    pub step_um: [f64; 2],
    /// Points measured per direction, or a fraction of the grid points (of those inside the
    /// polygon, if any).
    #[serde(default)]
    pub m: Option<usize>,
    #[serde(default)]
    pub fraction: Option<f64>,
    #[serde(default = "default_seed")]
    pub seed: u64,
    /// `random` | `stratified`.
    #[serde(default = "default_design")]
    pub design: Design2Kind,
    /// Approach side of every point, one map each: `forward` ends every move on both axes in +,
    /// `backward` in −.
    #[serde(default = "default_directions")]
    pub directions: Vec<Direction>,
    /// Only points inside this polygon (`[[x_um, y_um], ...]`).
    #[serde(default)]
    pub polygon: Option<Vec<[f64; 2]>>,
    /// Map reconstruction method of `csmetro::recon2d` (`auto` picks by cross-validation).
    #[serde(default = "default_method")]
    pub method: String,
    /// Step of the full grid scan the map campaign's time is compared against, µm.
    #[serde(default = "default_full_step")]
    pub full_scan_step_um: f64,
}

fn default_seed() -> u64 {
    1
}
fn default_design() -> Design2Kind {
    Design2Kind::Random
}
fn default_directions() -> Vec<Direction> {
    vec![Direction::Forward]
}
fn default_method() -> String {
    "auto".into()
}
fn default_full_step() -> f64 {
    5.0
}

/// `[map]`, resolved.
#[derive(Debug, Clone)]
pub struct MapPlan {
    pub grid: Grid2,
    pub design: Design2,
    /// The design's grid cells (ix, iy), drawn at validation: the plan measures these.
    pub points: Vec<(usize, usize)>,
    pub directions: Vec<Direction>,
    pub method: Method2,
    pub full_scan_step_um: f64,
}

/// Most map points measured per direction.
pub const MAX_MAP_M: usize = 200_000;

pub(super) fn validate_map(
    m: &MapSpec,
    approach_um: f64,
    limits_of: &dyn Fn(AxisId) -> Result<(f64, f64), SpecError>,
    fail: &dyn Fn(&str, String) -> SpecError,
) -> Result<MapPlan, SpecError> {
    let mut grids = Vec::new();
    for (axis, key, [start, end], step) in [
        (AxisId::X, "map.x_range_um", m.x_range_um, m.step_um[0]),
        (AxisId::Y, "map.y_range_um", m.y_range_um, m.step_um[1]),
    ] {
        if !(step.is_finite() && step > 0.0) {
            return Err(fail("map.step_um", "steps must be > 0 µm".into()));
        }
        let g = Grid::new(start, step, end).map_err(|e| fail(key, e))?;
        let (lo, hi) = limits_of(axis)?;
        let pre = approach_um;
        if start - pre < lo - 1e-9 || end + pre > hi + 1e-9 {
            return Err(fail(
                key,
                format!(
                    "[{start}, {end}] µm with {pre} µm approach travel leaves the soft limits [{lo}, {hi}] µm of axis {axis}"
                ),
            ));
        }
        grids.push(g);
    }
    let grid = Grid2::new(grids[0], grids[1]).map_err(|e| fail("map.step_um", e))?;
    let polygon = match &m.polygon {
        None => None,
        Some(v) => {
            let p = Polygon(v.clone());
            p.validate().map_err(|e| fail("map.polygon", e))?;
            Some(p)
        }
    };
    if m.directions.is_empty() {
        return Err(fail(
            "map.directions",
            "needs forward and/or backward".into(),
        ));
    }
    if m.directions.len() > 1 && m.directions[0] == m.directions[1] {
        return Err(fail("map.directions", "a direction is listed twice".into()));
    }
    let method: Method2 = m
        .method
        .parse()
        .map_err(|e: String| fail("map.method", e))?;
    if !(m.full_scan_step_um.is_finite() && m.full_scan_step_um > 0.0) {
        return Err(fail("map.full_scan_step_um", "must be > 0 µm".into()));
    }
    let (count, key) = match (m.m, m.fraction) {
        (Some(_), Some(_)) => {
            return Err(fail("map.fraction", "give m or fraction, not both".into()))
        }
        (Some(k), None) => (k, "map.m"),
        (None, Some(f)) => {
            if !(f > 0.0 && f <= 1.0) {
                return Err(fail("map.fraction", "must be in (0, 1]".into()));
            }
            ((f * grid.len() as f64).round() as usize, "map.fraction")
        }
        (None, None) => {
            return Err(fail(
                "map",
                format!(
                    "give m or fraction (the map grid has {} points)",
                    grid.len()
                ),
            ))
        }
    };
    if !(3..=MAX_MAP_M).contains(&count) || count > grid.len() {
        return Err(fail(
            key,
            format!(
                "m = {count} must be in 3..={} (grid points, at most {MAX_MAP_M})",
                grid.len().min(MAX_MAP_M)
            ),
        ));
    }
    let design = Design2 {
        kind: m.design,
        m: count,
        seed: m.seed,
        polygon,
    };
    // The points themselves: a polygon holding fewer than m grid points is refused here.
    let key = if m.polygon.is_some() {
        "map.polygon"
    } else {
        key
    };
    let points = design.points(&grid).map_err(|e| fail(key, e))?;
    Ok(MapPlan {
        grid,
        design,
        points,
        directions: m.directions.clone(),
        method,
        full_scan_step_um: m.full_scan_step_um,
    })
}
