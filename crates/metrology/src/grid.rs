//! The characterization grid `START:STEP:END` (µm) and mapping positions onto it.
use std::fmt;
use std::str::FromStr;

use serde::{Deserialize, Serialize};

/// Positions `start + i·step`, i = 0..n-1, in µm.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Grid {
    pub start_um: f64,
    pub step_um: f64,
    pub n: usize,
}

/// Positions closer than this to a grid point (µm) are on it.
pub const ON_GRID_TOL_UM: f64 = 1e-6;

/// Most points a grid may have. The paper's grid has 1901; a mistyped step (1e-7 µm) would
/// otherwise ask for ~10^11 points and abort on the allocation.
pub const MAX_GRID_POINTS: usize = 1_000_000;

impl Grid {
    /// A grid from start to end inclusive; `end - start` must be a whole number of steps.
    pub fn new(start_um: f64, step_um: f64, end_um: f64) -> Result<Self, String> {
        if !(start_um.is_finite() && step_um.is_finite() && end_um.is_finite()) {
            return Err("grid values must be finite numbers".into());
        }
        if step_um <= 0.0 {
            return Err(format!("grid step must be > 0 µm, got {step_um}"));
        }
        if end_um <= start_um {
            return Err(format!(
                "grid end ({end_um} µm) must be greater than start ({start_um} µm)"
            ));
        }
        let steps = (end_um - start_um) / step_um;
        if steps.is_nan() || steps >= MAX_GRID_POINTS as f64 {
            return Err(format!(
                "grid {start_um}:{step_um}:{end_um} has more than {MAX_GRID_POINTS} points"
            ));
        }
        let rounded = steps.round();
        if (steps - rounded).abs() * step_um > ON_GRID_TOL_UM {
            return Err(format!(
                "grid end {end_um} µm is not a whole number of {step_um} µm steps from {start_um} µm"
            ));
        }
        Ok(Self {
            start_um,
            step_um,
            n: rounded as usize + 1,
        })
    }

    pub fn end_um(&self) -> f64 {
        self.position(self.n - 1)
    }

    pub fn position(&self, i: usize) -> f64 {
        self.start_um + i as f64 * self.step_um
    }

    pub fn positions(&self) -> Vec<f64> {
        (0..self.n).map(|i| self.position(i)).collect()
    }

    /// Index of the grid point at `p`, if `p` lies within 1e-6 µm of one.
    pub fn index_of(&self, p: f64) -> Option<usize> {
        let u = (p - self.start_um) / self.step_um;
        let i = u.round();
        if i < 0.0 || i >= self.n as f64 {
            return None;
        }
        ((u - i).abs() * self.step_um <= ON_GRID_TOL_UM).then_some(i as usize)
    }
}

impl FromStr for Grid {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        let parts: Vec<&str> = s.split(':').collect();
        if parts.len() != 3 {
            return Err(format!(
                "grid must be START:STEP:END in µm (e.g. 0:5:9500), got {s:?}"
            ));
        }
        let num = |t: &str| {
            t.trim()
                .parse::<f64>()
                .map_err(|_| format!("grid value {t:?} is not a number"))
        };
        Grid::new(num(parts[0])?, num(parts[1])?, num(parts[2])?)
    }
}

impl fmt::Display for Grid {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}:{}:{}", self.start_um, self.step_um, self.end_um())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn paper_grid_has_1901_points() {
        let g: Grid = "0:5:9500".parse().unwrap();
        assert_eq!(g.n, 1901);
        assert_eq!(g.index_of(4750.0), Some(950));
        assert_eq!(g.index_of(4750.0 + 5e-7), Some(950));
        assert_eq!(g.index_of(4752.0), None);
        assert_eq!(g.index_of(-5.0), None);
        assert_eq!(g.index_of(9505.0), None);
    }

    #[test]
    fn bad_grids_are_refused() {
        assert!("0:5".parse::<Grid>().is_err());
        assert!("0:0:10".parse::<Grid>().is_err());
        assert!("10:1:0".parse::<Grid>().is_err());
        assert!("0:3:10".parse::<Grid>().is_err());
        assert!("a:1:2".parse::<Grid>().is_err());
    }

    #[test]
    fn huge_grids_are_refused_before_allocating() {
        let e = "0:1e-7:9500".parse::<Grid>().unwrap_err();
        assert!(e.contains("more than 1000000 points"), "{e}");
        assert!("0:1e-300:1".parse::<Grid>().is_err());
        assert!("0:5e-324:1e300".parse::<Grid>().is_err());
        // The largest allowed grid is still a grid.
        let g: Grid = "0:1:999999".parse().unwrap();
        assert_eq!(g.n, MAX_GRID_POINTS);
        assert!("0:1:1000000".parse::<Grid>().is_err());
    }
}
