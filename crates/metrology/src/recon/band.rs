//! Pointwise standard uncertainty of a reconstructed curve, from its own cross-validation.
//!
//! A curve's error at a grid point grows with the distance to the nearest sample: where
//! samples are dense the curve is pinned, across a gap it interpolates (a rough or local
//! feature between two samples is invisible). The cross-validation already predicts every
//! sample from folds that did not see it; each held-out residual comes with the distance from
//! its position to the nearest training sample of its fold. Those pairs calibrate u(d): the
//! residuals are binned by distance (equal counts), each bin's u is half its 95 % quantile of
//! |residual| (a ±2u band covers 95 % of them even when the errors are heavy-tailed, which a
//! Gaussian σ does not), u is made non-decreasing in d (pool adjacent violators), the sensor
//! noise each held-out residual carries is taken out, and every grid point gets u at its own
//! distance to the nearest sample of the whole design. The method's own error structure is in
//! the residuals, whichever method `auto` picked; the uncertainty of that choice is not
//! modelled separately (the residuals are the chosen method's).

/// Smallest residual count per distance bin (a 95 % quantile of fewer is mostly noise).
const PER_BIN: usize = 30;
/// Most bins.
const MAX_BINS: usize = 6;
/// The bin quantile whose half is u (so 2u covers it).
const QUANTILE: f64 = 0.95;

/// u (µm, k = 1) at every grid point: `sample_pos` the design's positions (µm, ascending),
/// `grid_pos` the grid's, `cv` (distance to the nearest training sample µm, held-out residual
/// µm) pairs, `noise_um` the sensor noise σ the residuals carry. Empty without residuals.
pub fn pointwise_u(
    grid_pos: &[f64],
    sample_pos: &[f64],
    cv: &[(f64, f64)],
    noise_um: f64,
) -> Vec<f64> {
    let cv: Vec<(f64, f64)> = cv
        .iter()
        .copied()
        .filter(|(d, r)| d.is_finite() && r.is_finite())
        .collect();
    if cv.len() < 2 || sample_pos.is_empty() {
        return Vec::new();
    }
    let curve = distance_curve(cv, noise_um.max(0.0));
    grid_pos
        .iter()
        .map(|&p| curve.at(nearest_distance(sample_pos, p)))
        .collect()
}

/// Distance from `p` to the nearest of the ascending `xs`.
pub fn nearest_distance(xs: &[f64], p: f64) -> f64 {
    let i = xs.partition_point(|&q| q < p);
    let mut d = f64::INFINITY;
    if i < xs.len() {
        d = d.min(xs[i] - p);
    }
    if i > 0 {
        d = d.min(p - xs[i - 1]);
    }
    d
}

/// u as a function of the distance to the nearest sample: bin centres and values.
struct DistanceCurve {
    d: Vec<f64>,
    u: Vec<f64>,
}

impl DistanceCurve {
    /// Linear between bin centres; the first bin's value below; beyond the last centre the
    /// last two bins' growth continues (a wide gap of a random design, where a local defect
    /// can hide, is where the curve is least known; held-out samples rarely sit that far).
    fn at(&self, d: f64) -> f64 {
        let (x, u) = (&self.d, &self.u);
        if d <= x[0] {
            return u[0];
        }
        let i = x.partition_point(|&q| q <= d);
        if i >= x.len() {
            let k = x.len() - 1;
            let slope = if k > 0 && x[k] > x[k - 1] {
                ((u[k] - u[k - 1]) / (x[k] - x[k - 1])).max(0.0)
            } else {
                0.0
            };
            return u[k] + slope * (d - x[k]);
        }
        let t = (d - x[i - 1]) / (x[i] - x[i - 1]);
        u[i - 1] + t * (u[i] - u[i - 1])
    }
}

fn distance_curve(mut cv: Vec<(f64, f64)>, noise_um: f64) -> DistanceCurve {
    cv.sort_by(|a, b| a.0.total_cmp(&b.0));
    let bins = (cv.len() / PER_BIN).clamp(1, MAX_BINS);
    let mut d = Vec::with_capacity(bins);
    let mut u = Vec::with_capacity(bins);
    let mut w = Vec::with_capacity(bins);
    for b in 0..bins {
        let part = &cv[b * cv.len() / bins..(b + 1) * cv.len() / bins];
        let mut r: Vec<f64> = part.iter().map(|p| p.1.abs()).collect();
        r.sort_by(f64::total_cmp);
        // The held-out residual is (curve error − sensor noise): take the noise out in quadrature,
        // keeping at least a third of the figure (a noise σ set too high must not zero the band).
        let q = quantile(&r, QUANTILE) / 2.0;
        let clean = (q * q - noise_um * noise_um).max(q * q / 9.0).sqrt();
        d.push(part.iter().map(|p| p.0).sum::<f64>() / part.len() as f64);
        u.push(clean);
        w.push(part.len() as f64);
    }
    let u = non_decreasing(&u, &w);
    DistanceCurve { d, u }
}

/// The q-quantile of ascending `v` (linear between order statistics).
fn quantile(v: &[f64], q: f64) -> f64 {
    let h = q * (v.len() - 1) as f64;
    let i = h.floor() as usize;
    let j = (i + 1).min(v.len() - 1);
    v[i] + (h - i as f64) * (v[j] - v[i])
}

/// Weighted pool-adjacent-violators: the non-decreasing sequence nearest to `v`.
fn non_decreasing(v: &[f64], w: &[f64]) -> Vec<f64> {
    // Blocks of (mean, weight, count).
    let mut blocks: Vec<(f64, f64, usize)> = Vec::new();
    for (&x, &wx) in v.iter().zip(w) {
        blocks.push((x, wx, 1));
        while blocks.len() > 1 && blocks[blocks.len() - 2].0 > blocks[blocks.len() - 1].0 {
            let (b, wb, nb) = blocks.pop().expect("two blocks");
            let (a, wa, na) = blocks.pop().expect("two blocks");
            blocks.push(((a * wa + b * wb) / (wa + wb), wa + wb, na + nb));
        }
    }
    blocks
        .into_iter()
        .flat_map(|(m, _, n)| std::iter::repeat_n(m, n))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_band_widens_with_the_distance_to_the_nearest_sample() {
        // Residuals growing with the distance: |r| ≈ 0.01 d.
        let cv: Vec<(f64, f64)> = (0..300)
            .map(|i| {
                let d = (i % 100) as f64;
                (d, 0.01 * d * if i % 2 == 0 { 1.0 } else { -1.0 })
            })
            .collect();
        let samples = [0.0, 200.0];
        let grid: Vec<f64> = (0..=20).map(|k| 10.0 * k as f64).collect();
        let u = pointwise_u(&grid, &samples, &cv, 0.0);
        assert_eq!(u.len(), grid.len());
        // At a sample the smallest, mid-gap (100 µm away) the largest.
        assert!(u[0] < 0.1 && u[10] > 0.35 && u[10] < 0.6, "{u:?}");
        assert!(u.windows(2).take(10).all(|w| w[1] >= w[0] - 1e-12));
    }

    #[test]
    fn violators_are_pooled_and_noise_is_taken_out() {
        assert_eq!(
            non_decreasing(&[1.0, 3.0, 2.0, 4.0], &[1.0; 4]),
            vec![1.0, 2.5, 2.5, 4.0]
        );
        let cv: Vec<(f64, f64)> = (0..100).map(|i| (i as f64, 0.2)).collect();
        let u = pointwise_u(&[0.0], &[0.0], &cv, 0.06);
        // q95 = 0.2 → 0.1, less 0.06 in quadrature: 0.08.
        assert!((u[0] - 0.08).abs() < 1e-9, "{u:?}");
        assert!(pointwise_u(&[0.0], &[0.0], &[], 0.0).is_empty());
    }
}
