//! Localisation of what the model does not explain: repeatability (pure error), position and
//! time maps, the other-axis map and the periodogram of the residual.
use std::collections::BTreeMap;

use csmetro_effects::{AxisId, StageModel};

use super::design::{demean, key_um, Rows};
use super::findings::{OtherAxis, Peak, Where};
use super::{Options, Sample};

/// Wilson–Hilferty z of a χ² statistic with k degrees of freedom.
pub fn chi2_z(x: f64, k: f64) -> f64 {
    if k <= 0.0 {
        return 0.0;
    }
    let a = 2.0 / (9.0 * k);
    ((x / k).max(0.0).cbrt() - (1.0 - a)) / a.sqrt()
}

/// Cell means of a residual, and the pure-error σ² with its degrees of freedom.
pub(super) struct CellStats {
    pub(super) mean: Vec<f64>,
    pub(super) n: Vec<usize>,
    pub(super) ss_lof: f64,
    pub(super) df_lof: f64,
    pub(super) ss_pe: f64,
    pub(super) df_pe: f64,
}

pub(super) fn cell_stats(rows: &Rows, e: &[f64], p: usize) -> CellStats {
    let mut sum = vec![0.0; rows.n_cells];
    let mut n = vec![0usize; rows.n_cells];
    for i in 0..rows.n {
        sum[rows.cell[i]] += e[i];
        n[rows.cell[i]] += 1;
    }
    let mean: Vec<f64> = sum
        .iter()
        .zip(&n)
        .map(|(s, &k)| if k > 0 { s / k as f64 } else { 0.0 })
        .collect();
    let ss_pe: f64 = (0..rows.n)
        .map(|i| (e[i] - mean[rows.cell[i]]).powi(2))
        .sum();
    let ss_lof: f64 = mean.iter().zip(&n).map(|(m, &k)| k as f64 * m * m).sum();
    let extra_lines: usize = rows
        .runs_per_cell_group
        .iter()
        .map(|r| r.saturating_sub(1))
        .sum();
    let df_pe = rows.n as f64 - rows.n_cells as f64 - extra_lines as f64;
    let df_lof = rows.n_cells as f64 - rows.n_cell_groups as f64 - p as f64;
    CellStats {
        mean,
        n,
        ss_lof,
        df_lof,
        ss_pe,
        df_pe,
    }
}

/// One position bin: (Σ n·mean², cells, peak |mean|).
pub(super) type Bin = (f64, f64, f64);

/// Position map (cell means binned over the moving axis' travel, per axis, direction and
/// component; χ² over the static positions of a bin so cancelling structure still counts) and
/// time map (pure-error residuals binned over time). Returns significant intervals, the total
/// time-structure z, and the excess sum of squares.
pub(super) fn where_maps(
    samples: &[Sample],
    model: &StageModel,
    rows: &Rows,
    e: &[f64],
    cs: &CellStats,
    sigma2: f64,
    opts: &Options,
) -> (Vec<Where>, f64) {
    let nb = opts.bins.max(1);
    // Representative row of each cell.
    let mut cell_row = vec![usize::MAX; rows.n_cells];
    for i in 0..rows.n {
        if cell_row[rows.cell[i]] == usize::MAX {
            cell_row[rows.cell[i]] = i;
        }
    }
    // (axis, dir, comp) series → bins: (Σ n m², df, peak |m|).
    let mut series: BTreeMap<(AxisId, bool, AxisId), Vec<Bin>> = BTreeMap::new();
    for (c, &i) in cell_row.iter().enumerate() {
        if i == usize::MAX {
            continue;
        }
        let s = &samples[rows.sample[i]];
        let a = s.moving;
        let tr = model.travel(a);
        let u = ((s.target(a) - tr[0]) / (tr[1] - tr[0]) * nb as f64).floor();
        let b = (u.max(0.0) as usize).min(nb - 1);
        let bins = series
            .entry((a, s.direction > 0.0, rows.comp[i]))
            .or_insert_with(|| vec![(0.0, 0.0, 0.0); nb]);
        bins[b].0 += cs.n[c] as f64 * cs.mean[c] * cs.mean[c];
        bins[b].1 += 1.0;
        bins[b].2 = f64::max(bins[b].2, cs.mean[c].abs());
    }
    let mut items = Vec::new();
    let mut total_excess = 0.0;
    let mut cand = Vec::new();
    for ((a, fwd, comp), bins) in &series {
        let tr = model.travel(*a);
        let w = (tr[1] - tr[0]) / nb as f64;
        let mut run: Option<(usize, usize, f64, f64, f64)> = None;
        for (b, &(ss, df, peak)) in bins.iter().enumerate() {
            let excess = (ss - df * sigma2).max(0.0);
            total_excess += excess;
            let z = if df > 0.0 {
                chi2_z(ss / sigma2, df)
            } else {
                0.0
            };
            let sig = z > opts.z_where;
            match (&mut run, sig) {
                (Some(r), true) => {
                    r.1 = b;
                    r.2 += excess;
                    r.3 = r.3.max(z);
                    r.4 = r.4.max(peak);
                }
                (None, true) => run = Some((b, b, excess, z, peak)),
                (Some(_), false) => cand.push((*a, *fwd, *comp, run.take().unwrap(), w, tr[0])),
                (None, false) => {}
            }
        }
        if let Some(r) = run.take() {
            cand.push((*a, *fwd, *comp, r, w, tr[0]));
        }
    }
    for (a, fwd, comp, (b0, b1, ex, z, peak), w, lo) in cand {
        items.push(Where {
            map: "position",
            axis: Some(a),
            direction: Some(if fwd { "forward" } else { "backward" }),
            component: Some(comp),
            from: lo + b0 as f64 * w,
            to: lo + (b1 + 1) as f64 * w,
            share: ex,
            z,
            peak_um: peak,
        });
    }
    // Time map on pure-error residuals.
    let tmax = samples.iter().map(|s| s.time_s).fold(0.0f64, f64::max);
    let tmin = samples
        .iter()
        .map(|s| s.time_s)
        .fold(f64::INFINITY, f64::min);
    let ntb = opts.time_bins.max(1);
    let span = (tmax - tmin).max(1e-9);
    let mut tb = vec![(0.0f64, 0usize); ntb];
    for i in 0..rows.n {
        let t = samples[rows.sample[i]].time_s;
        let b = (((t - tmin) / span * ntb as f64).floor() as usize).min(ntb - 1);
        tb[b].0 += e[i] - cs.mean[rows.cell[i]];
        tb[b].1 += 1;
    }
    // Null expectation of each bin's squared sum: σ²·1ᵀM1 with M the pure-error residual maker
    // (line offsets and cell means removed), applied to the bin's indicator.
    let mut bin_rows: Vec<Vec<usize>> = vec![Vec::new(); ntb];
    for i in 0..rows.n {
        let t = samples[rows.sample[i]].time_s;
        let b = (((t - tmin) / span * ntb as f64).floor() as usize).min(ntb - 1);
        bin_rows[b].push(i);
    }
    let null_factor: Vec<f64> = bin_rows
        .iter()
        .map(|idx| {
            if idx.is_empty() {
                return 0.0;
            }
            let mut v = vec![0.0; rows.n];
            idx.iter().for_each(|&i| v[i] = 1.0);
            demean(&mut v, &rows.lc, rows.n_lc);
            demean(&mut v, &rows.cell, rows.n_cells);
            idx.iter().map(|&i| v[i]).sum::<f64>() / idx.len() as f64
        })
        .collect();
    let mut t_stat = 0.0;
    let mut t_df = 0.0;
    let mut trun: Option<(usize, usize, f64, f64, f64)> = None;
    let mut tcand = Vec::new();
    let mut t_excess_total = 0.0;
    for (b, &(s, n)) in tb.iter().enumerate() {
        if n == 0 {
            continue;
        }
        let f = null_factor[b];
        if f < 1e-3 {
            continue;
        }
        let x = s * s / (n as f64 * sigma2 * f);
        t_stat += x;
        t_df += 1.0;
        let ex = (s * s / n as f64 - sigma2 * f).max(0.0);
        t_excess_total += ex;
        let z = chi2_z(x, 1.0);
        let sig = z > opts.z_where;
        match (&mut trun, sig) {
            (Some(r), true) => {
                r.1 = b;
                r.2 += ex;
                r.3 = r.3.max(z);
                r.4 = r.4.max((s / n as f64).abs());
            }
            (None, true) => trun = Some((b, b, ex, z, (s / n as f64).abs())),
            (Some(_), false) => tcand.push(trun.take().unwrap()),
            (None, false) => {}
        }
    }
    if let Some(r) = trun.take() {
        tcand.push(r);
    }
    let tw = span / ntb as f64;
    let time_z = chi2_z(t_stat, t_df);
    let grand = total_excess + t_excess_total;
    for (b0, b1, ex, z, peak) in tcand {
        items.push(Where {
            map: "time",
            axis: None,
            direction: None,
            component: None,
            from: tmin + b0 as f64 * tw,
            to: tmin + (b1 + 1) as f64 * tw,
            share: ex,
            z,
            peak_um: peak,
        });
    }
    for it in items.iter_mut() {
        it.share = if grand > 0.0 { it.share / grand } else { 0.0 };
    }
    items.sort_by(|a, b| b.share.total_cmp(&a.share).then(b.z.total_cmp(&a.z)));
    items.truncate(16);
    (items, time_z)
}

pub(super) fn other_axis_map(
    samples: &[Sample],
    rows: &Rows,
    cs: &CellStats,
    sigma2: f64,
) -> Vec<OtherAxis> {
    // (axis, static key, comp) → (Σ n m², cells, rows, static position)
    type Acc = (f64, f64, f64, f64);
    let mut acc: BTreeMap<(AxisId, i64, AxisId), Acc> = BTreeMap::new();
    let mut seen = vec![false; rows.n_cells];
    for i in 0..rows.n {
        let s = &samples[rows.sample[i]];
        let st = s.target(s.moving.other());
        let e = acc
            .entry((s.moving, key_um(st), rows.comp[i]))
            .or_insert((0.0, 0.0, 0.0, st));
        e.2 += 1.0;
        let c = rows.cell[i];
        if !seen[c] {
            seen[c] = true;
            e.0 += cs.n[c] as f64 * cs.mean[c] * cs.mean[c];
            e.1 += 1.0;
        }
    }
    acc.into_iter()
        .map(|((axis, _, component), (ss, df, n, st))| OtherAxis {
            axis,
            component,
            static_um: st,
            rms_um: ((ss - df * sigma2).max(0.0) / n.max(1.0)).sqrt(),
            z: chi2_z(ss / sigma2, df),
        })
        .collect()
}

/// Median spacing of the distinct target positions, µm (the sampling the design has).
pub(super) fn typical_spacing(mut pos: Vec<f64>) -> Option<f64> {
    pos.sort_by(f64::total_cmp);
    pos.dedup_by(|a, b| (*a - *b).abs() < 1e-3);
    let mut gaps: Vec<f64> = pos.windows(2).map(|w| w[1] - w[0]).collect();
    if gaps.is_empty() {
        return None;
    }
    gaps.sort_by(f64::total_cmp);
    Some(gaps[gaps.len() / 2])
}

/// Frequency map: Lomb–Scargle-style least-squares periodogram of the cell means (non-uniform
/// targets) per moving axis and component, both directions together; peaks with a false-alarm
/// probability under 1 %. Only periods the sampling resolves are searched: at least two periods
/// over the measured span (a longer one is a trend, not a cycle) and more than twice the typical
/// target spacing (a shorter one aliases); a near-singular sine/cosine pair is skipped. Returns
/// the peaks and what could not be searched.
pub(super) fn frequency_map(
    samples: &[Sample],
    rows: &Rows,
    cs: &CellStats,
    sigma2: f64,
) -> (Vec<Peak>, Vec<String>) {
    let mut cell_row = vec![usize::MAX; rows.n_cells];
    for i in 0..rows.n {
        if cell_row[rows.cell[i]] == usize::MAX {
            cell_row[rows.cell[i]] = i;
        }
    }
    let mut out = Vec::new();
    let mut notes = Vec::new();
    for a in [AxisId::X, AxisId::Y] {
        for comp in [AxisId::X, AxisId::Y] {
            // (position, mean, n, cell group)
            let pts: Vec<(f64, f64, f64, usize)> = cell_row
                .iter()
                .enumerate()
                .filter(|(_, &i)| i != usize::MAX)
                .filter(|(_, &i)| samples[rows.sample[i]].moving == a && rows.comp[i] == comp)
                .map(|(c, &i)| {
                    (
                        samples[rows.sample[i]].target(a),
                        cs.mean[c],
                        cs.n[c] as f64,
                        rows.cell_group[c],
                    )
                })
                .collect();
            // A trend over the line is not a cycle: remove each line group's straight line
            // first, so a scale or squareness does not show as a period as long as the travel.
            let pts = detrend(pts);
            if pts.is_empty() {
                continue;
            }
            let Some(spacing) = typical_spacing(pts.iter().map(|p| p.0).collect()) else {
                continue;
            };
            let lo = pts.iter().map(|p| p.0).fold(f64::INFINITY, f64::min);
            let hi = pts.iter().map(|p| p.0).fold(f64::NEG_INFINITY, f64::max);
            let span = hi - lo;
            // Oversampled grid (a peak falls between independent frequencies); the false-alarm
            // probability counts the independent ones.
            let (f0, df, fmax) = (2.0 / span, 0.05 / span, (1.0 / 12.0f64).min(0.5 / spacing));
            if pts.len() < 8 || fmax.partial_cmp(&f0) != Some(std::cmp::Ordering::Greater) {
                notes.push(format!(
                    "{a} lines, {comp} component: targets {spacing:.0} µm apart over {span:.0} µm cannot resolve a periodic error (no period between {:.0} and {:.0} µm): cyclic error is not searched",
                    2.0 * spacing,
                    span / 2.0
                ));
                continue;
            }
            let m = ((fmax - f0) / df).floor() as usize;
            let ymax = pts.iter().map(|p| p.1.abs()).fold(0.0f64, f64::max);
            let mut best = (0.0, 0.0, 0.0);
            for k in 0..=m {
                let f = f0 + k as f64 * df;
                let w = 2.0 * std::f64::consts::PI * f;
                let (mut cc, mut ss, mut cs_, mut yc, mut ys) = (0.0, 0.0, 0.0, 0.0, 0.0);
                for &(p, y, n, _) in &pts {
                    let (sn, cn) = (w * p).sin_cos();
                    cc += n * cn * cn;
                    ss += n * sn * sn;
                    cs_ += n * cn * sn;
                    yc += n * y * cn;
                    ys += n * y * sn;
                }
                let det = cc * ss - cs_ * cs_;
                // Sine and cosine nearly parallel on these targets: the fit is singular.
                if det <= 0.05 * cc * ss {
                    continue;
                }
                let ca = (ss * yc - cs_ * ys) / det;
                let sa = (cc * ys - cs_ * yc) / det;
                // An amplitude beyond the data's own is an ill-conditioned fit, not a cycle.
                if ca.hypot(sa) > 2.0 * ymax {
                    continue;
                }
                let red = (ca * yc + sa * ys) / sigma2;
                if red > best.0 {
                    best = (red, 1.0 / f, ca.hypot(sa));
                }
            }
            let independent = ((fmax - f0) * span).max(1.0);
            let fap = (independent * (-best.0 / 2.0).exp()).min(1.0);
            if fap < 0.01 {
                out.push(Peak {
                    axis: a,
                    component: comp,
                    period_um: best.1,
                    amplitude_um: best.2,
                    fap,
                });
            }
        }
    }
    (out, notes)
}

/// Removes a weighted straight line per group from (position, value, weight, group) points.
fn detrend(mut pts: Vec<(f64, f64, f64, usize)>) -> Vec<(f64, f64, f64, usize)> {
    let ng = pts.iter().map(|p| p.3 + 1).max().unwrap_or(0);
    // Σw, Σw·p, Σw·y, Σw·p², Σw·p·y
    let mut acc = vec![[0.0f64; 5]; ng];
    for &(p, y, w, g) in &pts {
        let a = &mut acc[g];
        a[0] += w;
        a[1] += w * p;
        a[2] += w * y;
        a[3] += w * p * p;
        a[4] += w * p * y;
    }
    for pt in pts.iter_mut() {
        let a = acc[pt.3];
        if a[0] <= 0.0 {
            continue;
        }
        let (mp, my) = (a[1] / a[0], a[2] / a[0]);
        let spp = a[3] - a[0] * mp * mp;
        let spy = a[4] - a[0] * mp * my;
        let slope = if spp > 1e-9 * a[3].max(1e-300) {
            spy / spp
        } else {
            0.0
        };
        pt.1 -= my + slope * (pt.0 - mp);
    }
    pts
}

/// Within-run noise σ² from successive differences in time (von Neumann) of the pure-error
/// residual within each line and component: a drift or any slow change in time cancels in the
/// difference of neighbours seconds apart, so this is the noise even when repeats drift.
/// `None` with fewer than 10 neighbour pairs.
pub(super) fn within_run_sigma2(
    samples: &[Sample],
    rows: &Rows,
    e: &[f64],
    cs: &CellStats,
) -> Option<f64> {
    let mut idx: Vec<usize> = (0..rows.n).collect();
    idx.sort_by(|&a, &b| {
        rows.lc[a].cmp(&rows.lc[b]).then(
            samples[rows.sample[a]]
                .time_s
                .total_cmp(&samples[rows.sample[b]].time_s),
        )
    });
    let (mut ss, mut m) = (0.0, 0usize);
    for w in idx.windows(2) {
        let (a, b) = (w[0], w[1]);
        if rows.lc[a] != rows.lc[b] {
            continue;
        }
        let ra = e[a] - cs.mean[rows.cell[a]];
        let rb = e[b] - cs.mean[rows.cell[b]];
        ss += (rb - ra).powi(2);
        m += 1;
    }
    (m >= 10).then(|| ss / (2.0 * m as f64))
}
