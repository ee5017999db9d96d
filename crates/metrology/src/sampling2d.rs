//! 2D sampling designs for the XY workspace map: which points of the map grid to measure, and in
//! which order the stage visits them.
//!
//! A design and its seed fully determine the points, so a resumed map campaign regenerates the
//! same plan. The visiting order runs through horizontal bands (as many as the design has rows of
//! strata), each band in ascending x and the bands in ascending y: every x move inside a band is
//! forward, so the approach-direction rule (the engine ends every move on each axis in the run's
//! direction, with an overshoot pre-position when needed) costs a pre-position only at a band's
//! start in x and where y steps back inside a band.
use rand::seq::{index, SliceRandom};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use crate::recon2d::Grid2;

/// How the map's points are drawn.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Design2Kind {
    /// m distinct grid points drawn uniformly (inside the polygon, if any).
    Random,
    /// The map cut into about m equal rectangular strata, one random grid point in each: random,
    /// but no large holes.
    Stratified,
}

/// A polygon in the map's plane, vertices in µm; a grid point is inside by the even-odd rule.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Polygon(pub Vec<[f64; 2]>);

impl Polygon {
    /// At least 3 finite vertices.
    pub fn validate(&self) -> Result<(), String> {
        if self.0.len() < 3 {
            return Err(format!(
                "needs at least 3 vertices [x_um, y_um], got {}",
                self.0.len()
            ));
        }
        if self.0.len() > MAX_POLYGON_VERTICES {
            return Err(format!("at most {MAX_POLYGON_VERTICES} vertices"));
        }
        if self.0.iter().flatten().any(|v| !v.is_finite()) {
            return Err("vertices must be finite numbers (µm)".into());
        }
        Ok(())
    }

    pub fn contains(&self, x: f64, y: f64) -> bool {
        let v = &self.0;
        let mut inside = false;
        let mut j = v.len() - 1;
        for i in 0..v.len() {
            let ([xi, yi], [xj, yj]) = (v[i], v[j]);
            if (yi > y) != (yj > y) && x < (xj - xi) * (y - yi) / (yj - yi) + xi {
                inside = !inside;
            }
            j = i;
        }
        inside
    }
}

/// Most vertices a polygon may have.
pub const MAX_POLYGON_VERTICES: usize = 64;

/// A reproducible 2D design.
#[derive(Debug, Clone, PartialEq)]
pub struct Design2 {
    pub kind: Design2Kind,
    pub m: usize,
    pub seed: u64,
    pub polygon: Option<Polygon>,
}

/// A map point: grid indices (ix, iy).
pub type Cell = (usize, usize);

/// Rows of strata for about `m` points on an `nx` × `ny` grid: strata about square in index
/// units, so the points spread evenly in both directions.
pub fn strata_rows(m: usize, nx: usize, ny: usize) -> usize {
    let r = ((m as f64) * ny as f64 / nx.max(1) as f64).sqrt().round() as usize;
    r.clamp(1, ny.max(1))
}

impl Design2 {
    /// Grid points inside the polygon (all of them without one), x fastest.
    fn inside(&self, g: &Grid2) -> Vec<usize> {
        let (nx, ny) = (g.x.n, g.y.n);
        match &self.polygon {
            None => (0..nx * ny).collect(),
            Some(p) => (0..nx * ny)
                .filter(|&k| p.contains(g.x.position(k % nx), g.y.position(k / nx)))
                .collect(),
        }
    }

    /// The design's m distinct points in visiting order (see the module doc).
    pub fn points(&self, g: &Grid2) -> Result<Vec<Cell>, String> {
        let (nx, ny) = (g.x.n, g.y.n);
        let inside = self.inside(g);
        if self.m < 3 || self.m > inside.len() {
            return Err(format!(
                "a map needs 3 <= m <= {} (the grid points{}), got m = {}",
                inside.len(),
                if self.polygon.is_some() {
                    " inside the polygon"
                } else {
                    ""
                },
                self.m
            ));
        }
        let mut rng = ChaCha8Rng::seed_from_u64(self.seed);
        let rows = strata_rows(self.m, nx, ny);
        let mut chosen: Vec<usize> = match self.kind {
            Design2Kind::Random => index::sample(&mut rng, inside.len(), self.m)
                .into_iter()
                .map(|i| inside[i])
                .collect(),
            Design2Kind::Stratified => {
                let cols = self.m.div_ceil(rows).clamp(1, nx);
                // Grid points of each stratum (row-major strata), then one from each of m
                // strata picked at random (all of them when there are exactly m).
                let mut strata: Vec<Vec<usize>> = vec![Vec::new(); rows * cols];
                for &k in &inside {
                    let (ix, iy) = (k % nx, k / nx);
                    strata[(iy * rows / ny) * cols + ix * cols / nx].push(k);
                }
                let mut order: Vec<usize> = (0..strata.len())
                    .filter(|&s| !strata[s].is_empty())
                    .collect();
                order.shuffle(&mut rng);
                let mut v: Vec<usize> = order
                    .iter()
                    .take(self.m)
                    .map(|&s| strata[s][rng.random_range(0..strata[s].len())])
                    .collect();
                // A polygon can leave fewer non-empty strata than m: top up at random.
                if v.len() < self.m {
                    let taken: std::collections::HashSet<usize> = v.iter().copied().collect();
                    let mut rest: Vec<usize> = inside
                        .iter()
                        .copied()
                        .filter(|k| !taken.contains(k))
                        .collect();
                    rest.shuffle(&mut rng);
                    v.extend(rest.into_iter().take(self.m - v.len()));
                }
                v
            }
        };
        // Visiting order: bands in ascending y, ascending x within a band.
        chosen.sort_unstable_by_key(|&k| {
            let (ix, iy) = (k % nx, k / nx);
            (iy * rows / ny, ix, iy)
        });
        Ok(chosen.into_iter().map(|k| (k % nx, k / nx)).collect())
    }
}

/// Length of the path through `cells` (µm, Euclidean), from the first to the last.
pub fn path_length_um(g: &Grid2, cells: &[Cell]) -> f64 {
    cells
        .windows(2)
        .map(|w| {
            let dx = (w[1].0 as f64 - w[0].0 as f64) * g.x.step_um;
            let dy = (w[1].1 as f64 - w[0].1 as f64) * g.y.step_um;
            dx.hypot(dy)
        })
        .sum()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::grid::Grid;

    fn grid(nx: usize, ny: usize) -> Grid2 {
        Grid2::new(
            Grid::new(0.0, 50.0, 50.0 * (nx - 1) as f64).unwrap(),
            Grid::new(0.0, 50.0, 50.0 * (ny - 1) as f64).unwrap(),
        )
        .unwrap()
    }

    fn design(kind: Design2Kind, m: usize) -> Design2 {
        Design2 {
            kind,
            m,
            seed: 7,
            polygon: None,
        }
    }

    #[test]
    fn designs_are_distinct_seeded_and_on_the_grid() {
        let g = grid(40, 20);
        for kind in [Design2Kind::Random, Design2Kind::Stratified] {
            let p = design(kind, 120).points(&g).unwrap();
            assert_eq!(p.len(), 120);
            let mut u = p.clone();
            u.sort_unstable();
            u.dedup();
            assert_eq!(u.len(), 120, "{kind:?}: distinct points");
            assert!(p.iter().all(|&(x, y)| x < 40 && y < 20));
            assert_eq!(p, design(kind, 120).points(&g).unwrap(), "same seed");
            let other = Design2 {
                seed: 8,
                ..design(kind, 120)
            };
            assert_ne!(p, other.points(&g).unwrap(), "another seed");
        }
        assert!(design(Design2Kind::Random, 801).points(&g).is_err());
        assert!(design(Design2Kind::Random, 2).points(&g).is_err());
    }

    #[test]
    fn stratified_points_leave_no_large_hole() {
        // 200 points on 80 x 40 (strata of 4 x 4 grid points): each of the 50 blocks of 8 x 8
        // holds four strata, so at least one point.
        let g = grid(80, 40);
        let p = design(Design2Kind::Stratified, 200).points(&g).unwrap();
        for bx in 0..10 {
            for by in 0..5 {
                assert!(
                    p.iter().any(|&(x, y)| x / 8 == bx && y / 8 == by),
                    "block ({bx}, {by}) empty"
                );
            }
        }
    }

    #[test]
    fn the_visiting_order_is_banded_and_much_shorter_than_a_random_order() {
        let g = grid(80, 40);
        for kind in [Design2Kind::Random, Design2Kind::Stratified] {
            let p = design(kind, 200).points(&g).unwrap();
            let rows = strata_rows(200, 80, 40);
            let band = |c: &Cell| c.1 * rows / 40;
            // Ascending bands, ascending x inside a band: x moves forward but at band starts.
            for w in p.windows(2) {
                assert!(band(&w[0]) <= band(&w[1]));
                if band(&w[0]) == band(&w[1]) {
                    assert!(w[0].0 <= w[1].0);
                }
            }
            let mut shuffled = p.clone();
            shuffled.shuffle(&mut ChaCha8Rng::seed_from_u64(1));
            let (ours, random) = (path_length_um(&g, &p), path_length_um(&g, &shuffled));
            assert!(ours < 0.25 * random, "{kind:?}: {ours} vs {random}");
        }
    }

    #[test]
    fn a_polygon_keeps_every_point_inside() {
        let g = grid(40, 20);
        // A triangle over the lower-left half of the 1950 x 950 µm rectangle.
        let tri = Polygon(vec![[0.0, 0.0], [1950.0, 0.0], [0.0, 950.0]]);
        tri.validate().unwrap();
        for kind in [Design2Kind::Random, Design2Kind::Stratified] {
            let d = Design2 {
                polygon: Some(tri.clone()),
                ..design(kind, 100)
            };
            let p = d.points(&g).unwrap();
            assert_eq!(p.len(), 100);
            for &(ix, iy) in &p {
                let (x, y) = (ix as f64 * 50.0, iy as f64 * 50.0);
                assert!(x / 1950.0 + y / 950.0 <= 1.0 + 1e-9, "({x}, {y}) outside");
            }
        }
        assert!(Polygon(vec![[0.0, 0.0], [1.0, 1.0]]).validate().is_err());
        assert!(Polygon(vec![[0.0, 0.0], [1.0, f64::NAN], [2.0, 0.0]])
            .validate()
            .is_err());
    }
}
