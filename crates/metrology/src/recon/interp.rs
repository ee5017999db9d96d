//! Lookup-table style baselines: linear and PCHIP interpolation between samples, ends held.
//!
//! Hand-written because they are a few lines each and no maintained crate covers PCHIP on an
//! arbitrary grid; both are tested on exact cases below.

/// Evaluates `segment(k, t)` on the interval [xs[k], xs[k+1]] holding x at relative place t;
/// outside the samples the end values are held. Positions in ascending order (the usual case: a
/// whole grid) find their interval by a cursor moving forward; any other order falls back to a
/// binary search (measured at n = 1901 from 600 samples: 29 µs by binary search alone).
fn held_ends(xs: &[f64], ys: &[f64], at: &[f64], segment: impl Fn(usize, f64) -> f64) -> Vec<f64> {
    let n = xs.len();
    let mut k = 0;
    let mut last = f64::NEG_INFINITY;
    at.iter()
        .map(|&x| {
            if x <= xs[0] {
                ys[0]
            } else if x >= xs[n - 1] {
                ys[n - 1]
            } else {
                // The last k ≤ n − 2 with xs[k] ≤ x.
                if x < last {
                    k = xs.partition_point(|&v| v <= x).clamp(1, n - 1) - 1;
                } else {
                    while k + 2 < n && xs[k + 1] <= x {
                        k += 1;
                    }
                }
                last = x;
                segment(k, (x - xs[k]) / (xs[k + 1] - xs[k]))
            }
        })
        .collect()
}

/// Linear interpolation of (xs, ys) at every position; constant beyond the end samples.
pub fn linear(xs: &[f64], ys: &[f64], at: &[f64]) -> Vec<f64> {
    held_ends(xs, ys, at, |k, t| ys[k] + t * (ys[k + 1] - ys[k]))
}

/// Fritsch–Carlson monotone cubic (PCHIP) slopes, with the usual one-sided end formula.
fn pchip_slopes(xs: &[f64], ys: &[f64]) -> Vec<f64> {
    let n = xs.len();
    let h: Vec<f64> = xs.windows(2).map(|w| w[1] - w[0]).collect();
    let delta: Vec<f64> = (0..n - 1).map(|i| (ys[i + 1] - ys[i]) / h[i]).collect();
    let mut d = vec![0.0; n];
    if n == 2 {
        d[0] = delta[0];
        d[1] = delta[0];
        return d;
    }
    for k in 1..n - 1 {
        if delta[k - 1] * delta[k] > 0.0 {
            let w1 = 2.0 * h[k] + h[k - 1];
            let w2 = h[k] + 2.0 * h[k - 1];
            d[k] = (w1 + w2) / (w1 / delta[k - 1] + w2 / delta[k]);
        }
    }
    let end = |h0: f64, h1: f64, d0: f64, d1: f64| {
        let mut s = ((2.0 * h0 + h1) * d0 - h0 * d1) / (h0 + h1);
        if s * d0 <= 0.0 {
            s = 0.0;
        } else if d0 * d1 <= 0.0 && s.abs() > 3.0 * d0.abs() {
            s = 3.0 * d0;
        }
        s
    };
    d[0] = end(h[0], h[1], delta[0], delta[1]);
    d[n - 1] = end(h[n - 2], h[n - 3], delta[n - 2], delta[n - 3]);
    d
}

/// PCHIP interpolation at every position; constant beyond the end samples.
pub fn pchip(xs: &[f64], ys: &[f64], at: &[f64]) -> Vec<f64> {
    let d = pchip_slopes(xs, ys);
    held_ends(xs, ys, at, |k, t| {
        let h = xs[k + 1] - xs[k];
        let (t2, t3) = (t * t, t * t * t);
        let h00 = 2.0 * t3 - 3.0 * t2 + 1.0;
        let h10 = t3 - 2.0 * t2 + t;
        let h01 = -2.0 * t3 + 3.0 * t2;
        let h11 = t3 - t2;
        h00 * ys[k] + h10 * h * d[k] + h01 * ys[k + 1] + h11 * h * d[k + 1]
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn linear_is_exact_on_lines_and_holds_ends() {
        let xs = [0.0, 10.0, 25.0];
        let ys = [1.0, 3.0, 6.0];
        let v = linear(&xs, &ys, &[-5.0, 0.0, 5.0, 10.0, 20.0, 25.0, 30.0]);
        assert_eq!(v, vec![1.0, 1.0, 2.0, 3.0, 5.0, 6.0, 6.0]);
    }

    /// Positions in any order get the values they get in a sorted sweep (the cursor and the
    /// binary search find the same interval, repeated positions and sample positions included).
    #[test]
    fn order_of_positions_does_not_change_values() {
        let xs = [0.0, 2.0, 3.0, 7.0, 8.0, 12.0];
        let ys = [0.5, -1.0, 2.0, 0.0, 4.0, 1.0];
        let sorted: Vec<f64> = (-4..=56).map(|i| i as f64 * 0.25).collect();
        let mut shuffled = sorted.clone();
        shuffled.reverse();
        shuffled.swap(3, 40);
        shuffled.push(7.0);
        shuffled.push(7.0);
        for f in [linear, pchip] {
            let a = f(&xs, &ys, &sorted);
            let b = f(&xs, &ys, &shuffled);
            for (x, v) in shuffled.iter().zip(&b) {
                let i = sorted.iter().position(|s| s == x).unwrap();
                assert_eq!(*v, a[i], "at {x}");
            }
            // Each sample is hit exactly.
            assert_eq!(f(&xs, &ys, &xs), ys.to_vec());
        }
    }

    #[test]
    fn pchip_reproduces_samples_lines_and_stays_monotone() {
        let xs = [0.0, 1.0, 3.0, 4.0, 7.0];
        let ys: Vec<f64> = xs.iter().map(|x| 2.0 * x - 1.0).collect();
        let at: Vec<f64> = (0..=70).map(|i| i as f64 * 0.1).collect();
        for (x, v) in at.iter().zip(pchip(&xs, &ys, &at)) {
            assert!((v - (2.0 * x - 1.0)).abs() < 1e-12);
        }
        // Monotone data with a flat step: no overshoot.
        let ys = [0.0, 0.0, 1.0, 1.0, 1.0];
        let v = pchip(&xs, &ys, &at);
        assert!(v.windows(2).all(|w| w[1] >= w[0] - 1e-12));
        assert!(v.iter().all(|&x| (-1e-12..=1.0 + 1e-12).contains(&x)));
        for (x, y) in xs.iter().zip(ys) {
            assert!((pchip(&xs, &ys, &[*x])[0] - y).abs() < 1e-12);
        }
    }
}
