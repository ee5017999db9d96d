//! ISO 230-1 geometric figures of an XY stage from its workspace map: the straightness of each
//! axis and the squareness of X to Y.
//!
//! On a map, the X axis's straightness is e_y along x and the Y axis's is e_x along y. Each is
//! taken against its least-squares reference straight line (ISO 230-1 allows least squares or
//! minimum zone; least squares here) and given as the peak-to-valley of the deviations from it:
//! for the profile averaged over the other axis's positions, and for the worst single line. The
//! squareness is the angle between the two reference lines' directions minus 90°: with slopes
//! a_x = d e_y / d x and a_y = d e_x / d y, the X trajectory points at angle a_x from +x and the Y
//! trajectory at 90° − a_y, so the angle between them is 90° − (a_x + a_y). A rotation of the
//! measuring frame (the camera) adds +r to a_x and −r to a_y and drops out.
use serde::Serialize;

use crate::recon2d::Grid2;

#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Iso2301 {
    /// Angle between the X and Y trajectories minus 90°, µrad (> 0: more than 90°).
    pub squareness_urad: f64,
    /// Straightness of X (e_y along x), µm: profile averaged over y, and the worst row.
    pub straightness_x_um: f64,
    pub straightness_x_worst_um: f64,
    /// Straightness of Y (e_x along y), µm: profile averaged over x, and the worst column.
    pub straightness_y_um: f64,
    pub straightness_y_worst_um: f64,
    /// Slopes of the reference lines, µrad: d e_y / d x and d e_x / d y.
    pub slope_x_urad: f64,
    pub slope_y_urad: f64,
}

/// Slope of the least-squares line through (p, v) and the peak-to-valley of the deviations
/// from that line.
pub fn ls_straightness(p: &[f64], v: &[f64]) -> (f64, f64) {
    let n = p.len() as f64;
    if p.len() < 2 {
        return (0.0, 0.0);
    }
    let (mp, mv) = (p.iter().sum::<f64>() / n, v.iter().sum::<f64>() / n);
    let sxx: f64 = p.iter().map(|x| (x - mp) * (x - mp)).sum();
    let sxy: f64 = p.iter().zip(v).map(|(x, y)| (x - mp) * (y - mv)).sum();
    let slope = if sxx > 0.0 { sxy / sxx } else { 0.0 };
    let (lo, hi) = p
        .iter()
        .zip(v)
        .map(|(x, y)| y - (mv + slope * (x - mp)))
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), r| {
            (a.min(r), b.max(r))
        });
    (slope, hi - lo)
}

/// The figures of the map (`ex`, `ey` in µm at every grid point, x fastest).
pub fn iso230_1(g: &Grid2, ex: &[f64], ey: &[f64]) -> Iso2301 {
    let (nx, ny) = (g.x.n, g.y.n);
    let xs: Vec<f64> = (0..nx).map(|i| g.x.position(i)).collect();
    let ys: Vec<f64> = (0..ny).map(|j| g.y.position(j)).collect();
    // X: e_y along each row, and its mean over the rows.
    let mut mean_row = vec![0.0; nx];
    let mut worst_x: f64 = 0.0;
    for j in 0..ny {
        let row = &ey[j * nx..(j + 1) * nx];
        worst_x = worst_x.max(ls_straightness(&xs, row).1);
        for (m, v) in mean_row.iter_mut().zip(row) {
            *m += v / ny as f64;
        }
    }
    let (slope_x, str_x) = ls_straightness(&xs, &mean_row);
    let mut mean_col = vec![0.0; ny];
    let mut worst_y: f64 = 0.0;
    let mut col = vec![0.0; ny];
    for i in 0..nx {
        for j in 0..ny {
            col[j] = ex[j * nx + i];
            mean_col[j] += col[j] / nx as f64;
        }
        worst_y = worst_y.max(ls_straightness(&ys, &col).1);
    }
    let (slope_y, str_y) = ls_straightness(&ys, &mean_col);
    Iso2301 {
        squareness_urad: -(slope_x + slope_y) * 1e6,
        straightness_x_um: str_x,
        straightness_x_worst_um: worst_x,
        straightness_y_um: str_y,
        straightness_y_worst_um: worst_y,
        slope_x_urad: slope_x * 1e6,
        slope_y_urad: slope_y * 1e6,
    }
}

/// One line per figure for summary.txt.
pub fn iso230_1_text(label: &str, f: &Iso2301) -> String {
    format!(
        "ISO 230-1 ({label}, least-squares reference lines): squareness X to Y {:+.1} µrad; \
         straightness X {:.3} µm (worst row {:.3}), Y {:.3} µm (worst column {:.3})\n",
        f.squareness_urad,
        f.straightness_x_um,
        f.straightness_x_worst_um,
        f.straightness_y_um,
        f.straightness_y_worst_um
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::grid::Grid;

    #[test]
    fn figures_of_a_known_geometry() {
        let g = Grid2::new(
            Grid::new(0.0, 10.0, 2000.0).unwrap(),
            Grid::new(0.0, 10.0, 1000.0).unwrap(),
        )
        .unwrap();
        // Out-of-square by 30 µrad (Y leans toward +x: e_x = 30e-6 y), a frame rotation of
        // 12 µrad (e_x -= r y, e_y += r x), a bow of 0.4 µm peak-to-valley on X's e_y
        // (a parabola about the LS line) and a cosine of one period, 1 µm peak-to-valley, on Y's e_x
        // (symmetric about the middle: no LS slope).
        let (sq, r) = (30e-6, 12e-6);
        let (nx, ny) = (g.x.n, g.y.n);
        let mut ex = vec![0.0; g.len()];
        let mut ey = vec![0.0; g.len()];
        for j in 0..ny {
            for i in 0..nx {
                let (x, y) = (g.x.position(i), g.y.position(j));
                let u = x / 1000.0 - 1.0; // -1..1
                ex[j * nx + i] = sq * y - r * y + 0.5 * (std::f64::consts::TAU * y / 1000.0).cos();
                ey[j * nx + i] = r * x + 0.4 * u * u;
            }
        }
        let f = iso230_1(&g, &ex, &ey);
        // The angle between the axes is 90° - (a_x + a_y) = 90° - (12 + 18) µrad.
        assert!((f.squareness_urad + 30.0).abs() < 0.5, "{f:?}");
        // Parabola u² on [-1, 1] minus its LS line (slope 0): peak-to-valley 1 → 0.4 µm.
        assert!((f.straightness_x_um - 0.4).abs() < 1e-3, "{f:?}");
        assert!((f.straightness_x_worst_um - 0.4).abs() < 1e-3, "{f:?}");
        assert!((f.straightness_y_um - 1.0).abs() < 1e-6, "{f:?}");
        assert!(
            (f.slope_x_urad - 12.0).abs() < 1e-6
                && (f.straightness_y_worst_um - f.straightness_y_um).abs() < 1e-9
        );
    }
}
