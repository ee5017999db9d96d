//! The ratio test: the long-step rule of l1 simplex methods (pass breakpoints while the objective
//! still decreases).

/// Long-step ratio test over the breakpoints `tb` (t per basic variable, ∞ for none) with slope
/// increases `inc(b)`: pass them in increasing t (equal t: lower index first) while the objective
/// still decreases; returns (b, t) where the slope turns non-negative. Usually it turns within
/// the first few, which [`smallest_breaks`] finds in one pass; only otherwise are all of them
/// collected into `breaks` and passed by [`pass_in_order`].
pub(super) fn long_step(
    tb: &[f64],
    inc: impl Fn(usize) -> f64,
    slope: f64,
    breaks: &mut Vec<(f64, usize, f64)>,
) -> Option<(usize, f64)> {
    let (near, count) = smallest_breaks(tb);
    let mut s = slope;
    for &(t, b) in &near[..count] {
        s += inc(b);
        if s >= 0.0 {
            return Some((b, t));
        }
    }
    if count < NEAR_BREAKS {
        return None;
    }
    // Breakpoints at t = ∞ (d = 0) change no slope: left out.
    breaks.clear();
    breaks.extend(
        tb.iter()
            .enumerate()
            .filter(|&(_, &t)| t < f64::INFINITY)
            .map(|(b, &t)| (t, b, inc(b))),
    );
    pass_in_order(breaks, slope)
}

/// Passes the breakpoints (t, basic variable, slope increase) in increasing t from `slope` until
/// it turns non-negative; returns that one. For the long steps that pass more than
/// [`smallest_breaks`] holds (measured at m = 600: about two per solve, ~34 of ~340 breakpoints
/// passed), in sorted chunks cut off by selection: a full sort of them all, after eight minimum
/// scans, was ~25 µs each.
fn pass_in_order(breaks: &mut [(f64, usize, f64)], mut slope: f64) -> Option<(usize, f64)> {
    let by = |a: &(f64, usize, f64), b: &(f64, usize, f64)| a.0.total_cmp(&b.0);
    let mut rest = breaks;
    let mut chunk = 4 * NEAR_BREAKS;
    while !rest.is_empty() {
        let k = chunk.min(rest.len());
        if k < rest.len() {
            rest.select_nth_unstable_by(k - 1, by);
        }
        let (head, tail) = rest.split_at_mut(k);
        head.sort_unstable_by(by);
        for &(t, b, inc) in head.iter() {
            slope += inc;
            if slope >= 0.0 {
                return Some((b, t));
            }
        }
        rest = tail;
        chunk *= 4;
    }
    None
}

/// Breakpoints [`smallest_breaks`] collects for the long step's first try.
const NEAR_BREAKS: usize = 8;

/// The (t, index) of the [`NEAR_BREAKS`] smallest finite breakpoints of `tb` in increasing t
/// (equal t: lower index first), and how many there are. One pass with a short insertion list:
/// collecting every breakpoint and scanning for the minimum repeatedly cost ~8 µs per long step
/// at m = 600 (about one pivot in four).
fn smallest_breaks(tb: &[f64]) -> ([(f64, usize); NEAR_BREAKS], usize) {
    let mut near = [(f64::INFINITY, usize::MAX); NEAR_BREAKS];
    let mut count = 0;
    for (b, &t) in tb.iter().enumerate() {
        // The list's last entry is ∞ until it is full: one comparison rejects the rest.
        if t < near[NEAR_BREAKS - 1].0 {
            let mut p = count.min(NEAR_BREAKS - 1);
            while p > 0 && near[p - 1].0 > t {
                near[p] = near[p - 1];
                p -= 1;
            }
            near[p] = (t, b);
            count = (count + 1).min(NEAR_BREAKS);
        }
    }
    (near, count)
}

/// One pass of the ratio test over basic values `x` with directions `d` (times `sj`): the
/// slope's change (−sign(x)·d for a live variable, |d| for a degenerate one, which any step
/// drives from zero), the largest |d|, and each variable's breakpoint t = x/d into `t` (∞ unless
/// live and t > 0). Separate accumulators and no index-carrying state let it vectorise: the
/// single pass that also tracked the first breakpoint ran ~2.8 µs per pivot at m = 600.
pub(super) fn ratio_pass(
    x: &[f64],
    d: &[f64],
    sj: f64,
    zero_tol: f64,
    t: &mut [f64],
) -> (f64, f64) {
    const L: usize = 4;
    let (mut slope, mut dmax) = ([0.0f64; L], [0.0f64; L]);
    let lane = |x: f64, d: f64, slope: &mut f64, dmax: &mut f64| {
        let d = sj * d;
        let ad = d.abs();
        *dmax = dmax.max(ad);
        let live = x.abs() > zero_tol;
        *slope += if live { -(1f64.copysign(x) * d) } else { ad };
        let q = x / d;
        if live & (q > 0.0) {
            q
        } else {
            f64::INFINITY
        }
    };
    let n = x.len().min(d.len()).min(t.len());
    let (xs, ds, ts) = (&x[..n], &d[..n], &mut t[..n]);
    let mut xc = xs.chunks_exact(L);
    let mut dc = ds.chunks_exact(L);
    let mut tc = ts.chunks_exact_mut(L);
    for ((xa, da), ta) in (&mut xc).zip(&mut dc).zip(&mut tc) {
        for k in 0..L {
            ta[k] = lane(xa[k], da[k], &mut slope[k], &mut dmax[k]);
        }
    }
    for ((&xv, &dv), tv) in xc
        .remainder()
        .iter()
        .zip(dc.remainder())
        .zip(tc.into_remainder())
    {
        *tv = lane(xv, dv, &mut slope[0], &mut dmax[0]);
    }
    (
        slope.iter().sum(),
        dmax.iter().fold(0.0, |a: f64, &b| a.max(b)),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    /// its sorted chunks, and reports none when the slope never turns.
    #[test]
    fn long_step_passes_breakpoints_in_order() {
        let n = 700;
        let breaks: Vec<(f64, usize, f64)> = (0..n)
            .map(|b| (((b * 389) % n) as f64 + 0.5, b, 1.0 + (b % 3) as f64))
            .collect();
        let mut sorted = breaks.clone();
        sorted.sort_by(|a, b| a.0.total_cmp(&b.0));
        let total: f64 = breaks.iter().map(|b| b.2).sum();
        for passed in [0usize, 1, 7, 31, 32, 33, 200, 699] {
            // A slope that turns exactly at the `passed`-th breakpoint (0-based).
            let before: f64 = sorted[..passed].iter().map(|b| b.2).sum();
            let slope = -(before + 0.5 * sorted[passed].2);
            let mut work = breaks.clone();
            let want = (sorted[passed].1, sorted[passed].0);
            assert_eq!(
                pass_in_order(&mut work, slope),
                Some(want),
                "passed {passed}"
            );
        }
        let mut work = breaks.clone();
        assert_eq!(pass_in_order(&mut work, -total - 1.0), None);
    }

    /// by lower index, however many (or few) there are.
    #[test]
    fn smallest_breaks_are_the_sorted_head() {
        let inf = f64::INFINITY;
        for len in [0usize, 1, 5, 8, 9, 40, 611] {
            let tb: Vec<f64> = (0..len)
                .map(|b| match (b * 37) % 11 {
                    0..=2 => inf,
                    k => ((b * 13) % 7) as f64 * 0.25 + k as f64 * 1e-3 * ((b % 3) as f64),
                })
                .collect();
            let mut want: Vec<(f64, usize)> = tb
                .iter()
                .enumerate()
                .filter(|(_, t)| t.is_finite())
                .map(|(b, &t)| (t, b))
                .collect();
            want.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
            want.truncate(NEAR_BREAKS);
            let (near, count) = smallest_breaks(&tb);
            assert_eq!(&near[..count], &want[..], "len {len}");
        }
    }
}
