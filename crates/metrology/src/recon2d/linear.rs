//! Baseline: linear interpolation on a Delaunay triangulation of the samples; grid points outside
//! the samples' convex hull take the nearest covered value along their row (or column).
use super::{folds, rms_xy, Grid2, Map, MapSamples, CV_FOLDS};

/// Every component interpolated at every grid point (x fastest), `vals[c][sample]`.
fn raster(g: &Grid2, ix: &[usize], iy: &[usize], vals: &[&[f64]]) -> Vec<Vec<f64>> {
    let (nx, ny) = (g.x.n, g.y.n);
    let nc = vals.len();
    let mut out = vec![vec![f64::NAN; nx * ny]; nc];
    // Grid index coordinates: integers, exact in f64, so the orientation tests are exact.
    let pts: Vec<delaunator::Point> = ix
        .iter()
        .zip(iy)
        .map(|(&i, &j)| delaunator::Point {
            x: i as f64,
            y: j as f64,
        })
        .collect();
    let tri = delaunator::triangulate(&pts);
    for t in tri.triangles.chunks_exact(3) {
        let [a, b, c] = [t[0], t[1], t[2]];
        let (pa, pb, pc) = (&pts[a], &pts[b], &pts[c]);
        let det = (pb.x - pa.x) * (pc.y - pa.y) - (pc.x - pa.x) * (pb.y - pa.y);
        if det == 0.0 {
            continue;
        }
        let i0 = pa.x.min(pb.x).min(pc.x) as usize;
        let i1 = pa.x.max(pb.x).max(pc.x) as usize;
        let j0 = pa.y.min(pb.y).min(pc.y) as usize;
        let j1 = pa.y.max(pb.y).max(pc.y) as usize;
        for j in j0..=j1 {
            let y = j as f64;
            for i in i0..=i1 {
                let x = i as f64;
                let la = ((pb.x - x) * (pc.y - y) - (pc.x - x) * (pb.y - y)) / det;
                let lb = ((pc.x - x) * (pa.y - y) - (pa.x - x) * (pc.y - y)) / det;
                let lc = 1.0 - la - lb;
                if la < -1e-12 || lb < -1e-12 || lc < -1e-12 {
                    continue;
                }
                let k = j * nx + i;
                for (o, v) in out.iter_mut().zip(vals) {
                    o[k] = la * v[a] + lb * v[b] + lc * v[c];
                }
            }
        }
    }
    // The samples themselves (a collinear set has no triangles at all).
    for (s, (&i, &j)) in ix.iter().zip(iy).enumerate() {
        for (o, v) in out.iter_mut().zip(vals) {
            o[j * nx + i] = v[s];
        }
    }
    for o in &mut out {
        fill_outside(o, nx, ny);
    }
    out
}

/// Constant extrapolation: each uncovered point takes the nearest covered one in its row; rows
/// with none take the nearest covered row.
fn fill_outside(v: &mut [f64], nx: usize, ny: usize) {
    let mut covered_rows = Vec::new();
    for j in 0..ny {
        let row = &mut v[j * nx..(j + 1) * nx];
        let known: Vec<usize> = (0..nx).filter(|&i| !row[i].is_nan()).collect();
        if known.is_empty() {
            continue;
        }
        covered_rows.push(j);
        let mut q = 0;
        for i in 0..nx {
            while q + 1 < known.len() && known[q + 1].abs_diff(i) <= known[q].abs_diff(i) {
                q += 1;
            }
            if row[i].is_nan() {
                row[i] = row[known[q]];
            }
        }
    }
    if covered_rows.is_empty() {
        return;
    }
    let mut q = 0;
    for j in 0..ny {
        while q + 1 < covered_rows.len()
            && covered_rows[q + 1].abs_diff(j) <= covered_rows[q].abs_diff(j)
        {
            q += 1;
        }
        let src = covered_rows[q];
        if src != j && v[j * nx].is_nan() {
            v.copy_within(src * nx..(src + 1) * nx, j * nx);
        }
    }
}

/// The whole map by linear interpolation.
pub fn interpolate(g: &Grid2, s: &MapSamples) -> Map {
    let mut out = raster(g, &s.ix, &s.iy, &s.components());
    let theta = (out.len() > 2).then(|| out.pop().expect("three components"));
    let ey = out.pop().expect("e_y");
    let ex = out.pop().expect("e_x");
    Map {
        ex,
        ey,
        theta,
        u_ex: Vec::new(),
        u_ey: Vec::new(),
    }
}

/// k-fold cross-validation error (RMS over e_x, e_y, µm) of the linear interpolation.
pub fn cv_error(g: &Grid2, s: &MapSamples) -> f64 {
    rms_xy(s, &cv_predictions(g, s))
}

/// Held-out predictions of e_x and e_y at every sample (`pred[c][k]`).
pub fn cv_predictions(g: &Grid2, s: &MapSamples) -> Vec<Vec<f64>> {
    let m = s.len();
    let fold = folds(m, CV_FOLDS);
    let mut pred = vec![vec![0.0; m]; 2];
    for f in 0..CV_FOLDS {
        let train: Vec<usize> = (0..m).filter(|&k| fold[k] != f).collect();
        let t = s.subset(&train);
        let r = raster(g, &t.ix, &t.iy, &[&t.ex, &t.ey]);
        for k in (0..m).filter(|&k| fold[k] == f) {
            let at = s.iy[k] * g.x.n + s.ix[k];
            pred[0][k] = r[0][at];
            pred[1][k] = r[1][at];
        }
    }
    pred
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_plane_is_reproduced_inside_the_hull_and_held_outside() {
        let g = Grid2::new("0:1:20".parse().unwrap(), "0:1:10".parse().unwrap()).unwrap();
        let plane = |i: usize, j: usize| 0.5 + 0.25 * i as f64 - 0.125 * j as f64;
        let pts = [(2, 1), (18, 2), (10, 9), (5, 5), (15, 6), (9, 3)];
        let s = MapSamples {
            ix: pts.iter().map(|p| p.0).collect(),
            iy: pts.iter().map(|p| p.1).collect(),
            ex: pts.iter().map(|p| plane(p.0, p.1)).collect(),
            ey: pts.iter().map(|p| -plane(p.0, p.1)).collect(),
            theta: None,
        };
        let m = interpolate(&g, &s);
        assert!((m.ex[5 * 21 + 10] - plane(10, 5)).abs() < 1e-12);
        assert!((m.ey[3 * 21 + 10] + plane(10, 3)).abs() < 1e-12);
        assert!(m.ex.iter().all(|v| v.is_finite()));
        // Row 0 has no covered point: it copies row 1, where only (2, 1) is covered.
        assert_eq!(m.ex[0], plane(2, 1));
    }
}
