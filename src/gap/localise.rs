//! Localisation of what the model does not explain: repeatability (pure error), position and
//! time maps, the other-axis map and the periodogram of the residual.
use std::collections::BTreeMap;

use csmetro_sim::{AxisId, StageModel};

use super::design::{demean, key_um, Rows};
use super::report::{OtherAxis, Peak, Where};
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

/// Frequency map: Lomb–Scargle-style least-squares periodogram of the cell means (non-uniform
/// targets) per moving axis and component, both directions together; peaks with a false-alarm
/// probability under 1 %.
pub(super) fn frequency_map(
    samples: &[Sample],
    model: &StageModel,
    rows: &Rows,
    cs: &CellStats,
    sigma2: f64,
) -> Vec<Peak> {
    let mut cell_row = vec![usize::MAX; rows.n_cells];
    for i in 0..rows.n {
        if cell_row[rows.cell[i]] == usize::MAX {
            cell_row[rows.cell[i]] = i;
        }
    }
    let mut out = Vec::new();
    for a in [AxisId::X, AxisId::Y] {
        for comp in [AxisId::X, AxisId::Y] {
            // (position, mean, n)
            let pts: Vec<(f64, f64, f64)> = cell_row
                .iter()
                .enumerate()
                .filter(|(_, &i)| i != usize::MAX)
                .filter(|(_, &i)| samples[rows.sample[i]].moving == a && rows.comp[i] == comp)
                .map(|(c, &i)| {
                    (
                        samples[rows.sample[i]].target(a),
                        cs.mean[c],
                        cs.n[c] as f64,
                    )
                })
                .collect();
            if pts.len() < 8 {
                continue;
            }
            let tr = model.travel(a);
            let span = tr[1] - tr[0];
            let (f0, df, fmax) = (1.0 / span, 0.5 / span, 1.0 / 12.0);
            let m = ((fmax - f0) / df).floor() as usize;
            let mut best = (0.0, 0.0, 0.0);
            for k in 0..=m {
                let f = f0 + k as f64 * df;
                let w = 2.0 * std::f64::consts::PI * f;
                let (mut cc, mut ss, mut cs_, mut yc, mut ys) = (0.0, 0.0, 0.0, 0.0, 0.0);
                for &(p, y, n) in &pts {
                    let (sn, cn) = (w * p).sin_cos();
                    cc += n * cn * cn;
                    ss += n * sn * sn;
                    cs_ += n * cn * sn;
                    yc += n * y * cn;
                    ys += n * y * sn;
                }
                let det = cc * ss - cs_ * cs_;
                if det <= 1e-9 * cc * ss {
                    continue;
                }
                let ca = (ss * yc - cs_ * ys) / det;
                let sa = (cc * ys - cs_ * yc) / det;
                let red = (ca * yc + sa * ys) / sigma2;
                if red > best.0 {
                    best = (red, 1.0 / f, ca.hypot(sa));
                }
            }
            let fap = ((m + 1) as f64 * (-best.0 / 2.0).exp()).min(1.0);
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
    out
}
