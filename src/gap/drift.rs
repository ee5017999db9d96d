//! Drift in time, tested against the noise that remains once the drift is taken out, not
//! against repeats that contain it: the pure-error residual (line offsets and target means
//! removed) is regressed, per measured component, on the time since the mean visit of each
//! target, uniformly and growing along the moving axis' travel (thermal expansion). A steady
//! drift of the line offsets themselves is reported beside it (a per-line constant is not a gap).
use csmetro_effects::{map_to_unit, AxisId, StageModel};
use nalgebra::{DMatrix, DVector};

use super::design::Rows;
use super::localise::{chi2_z, CellStats};
use super::Sample;

#[derive(Debug, Clone)]
pub struct Drift {
    /// Nested F test (drift terms vs none, against the pure error left without them) as z.
    pub z: f64,
    pub significant: bool,
    /// Per component (x, y): drift rate at mid-travel and at the start and end of the travel, µm/h
    /// (NaN: component unmeasured).
    pub rate_mid_um_per_h: [f64; 2],
    pub rate_ends_um_per_h: [[f64; 2]; 2],
    /// Pure-error σ² once the drift is removed, µm².
    pub sigma2_rest: f64,
    pub df_rest: f64,
    /// Trend of the line offsets over time, µm/h, and its z against their own scatter.
    pub offset_rate_um_per_h: f64,
    pub offset_z: f64,
}

pub(super) fn drift_test(
    samples: &[Sample],
    model: &StageModel,
    rows: &Rows,
    e: &[f64],
    cs: &CellStats,
    z_thr: f64,
) -> Drift {
    // Mean time of each cell.
    let mut tsum = vec![0.0; rows.n_cells];
    for i in 0..rows.n {
        tsum[rows.cell[i]] += samples[rows.sample[i]].time_s;
    }
    let tmean: Vec<f64> = tsum
        .iter()
        .zip(&cs.n)
        .map(|(s, &n)| if n > 0 { s / n as f64 } else { 0.0 })
        .collect();
    // Columns: (comp, uniform | along travel), hours.
    let comp_idx = |c: AxisId| usize::from(c == AxisId::Y);
    let mut g = DMatrix::<f64>::zeros(4, 4);
    let mut b = DVector::<f64>::zeros(4);
    let mut ss_pe = 0.0;
    for i in 0..rows.n {
        let s = &samples[rows.sample[i]];
        let r = e[i] - cs.mean[rows.cell[i]];
        ss_pe += r * r;
        let dt = (s.time_s - tmean[rows.cell[i]]) / 3600.0;
        let u = map_to_unit(s.target(s.moving), model.travel(s.moving));
        let k = 2 * comp_idx(rows.comp[i]);
        let x = [dt, dt * u];
        for a in 0..2 {
            b[k + a] += x[a] * r;
            for c in 0..2 {
                g[(k + a, k + c)] += x[a] * x[c];
            }
        }
    }
    // Keep the identifiable columns only (a component unmeasured, or one target per line).
    let keep: Vec<usize> = (0..4).filter(|&j| g[(j, j)] > 1e-12).collect();
    let gk = DMatrix::from_fn(keep.len(), keep.len(), |a, c| g[(keep[a], keep[c])]);
    let bk = DVector::from_fn(keep.len(), |a, _| b[keep[a]]);
    let beta = super::design::solve(gk, bk.clone());
    let ss_drift = bk.dot(&beta).max(0.0);
    let p = keep.len() as f64;
    let df_rest = (cs.df_pe - p).max(1.0);
    let sigma2_rest = ((ss_pe - ss_drift) / df_rest).max(1e-300);
    let z = if p > 0.0 && cs.df_pe > p + 2.0 {
        chi2_z(ss_drift / sigma2_rest, p)
    } else {
        0.0
    };
    let mut coef = [f64::NAN; 4];
    for (a, &j) in keep.iter().enumerate() {
        coef[j] = beta[a];
    }
    let mut rate_mid = [f64::NAN; 2];
    let mut rate_ends = [[f64::NAN; 2]; 2];
    for c in 0..2 {
        if coef[2 * c].is_finite() {
            let slope = if coef[2 * c + 1].is_finite() {
                coef[2 * c + 1]
            } else {
                0.0
            };
            rate_mid[c] = coef[2 * c];
            rate_ends[c] = [coef[2 * c] - slope, coef[2 * c] + slope];
        }
    }
    // Line offsets over time: one intercept per (moving axis, static position, component)
    // group, one common slope.
    let (offset_rate_um_per_h, offset_z) = offset_trend(samples, rows);
    Drift {
        z,
        significant: z > z_thr,
        rate_mid_um_per_h: rate_mid,
        rate_ends_um_per_h: rate_ends,
        sigma2_rest,
        df_rest,
        offset_rate_um_per_h,
        offset_z,
    }
}

fn offset_trend(samples: &[Sample], rows: &Rows) -> (f64, f64) {
    // Per lc group: mean time, its cell group.
    let mut t = vec![0.0; rows.n_lc];
    let mut n = vec![0usize; rows.n_lc];
    let mut grp = vec![usize::MAX; rows.n_lc];
    for i in 0..rows.n {
        let g = rows.lc[i];
        t[g] += samples[rows.sample[i]].time_s;
        n[g] += 1;
        grp[g] = rows.cell_group[rows.cell[i]];
    }
    let pts: Vec<(usize, f64, f64)> = (0..rows.n_lc)
        .filter(|&g| n[g] > 0 && rows.lc_mean[g].is_finite())
        .map(|g| (grp[g], t[g] / n[g] as f64 / 3600.0, rows.lc_mean[g]))
        .collect();
    // Demean time and offset within each group, then one slope.
    let ng = rows.n_cell_groups;
    let (mut st, mut so, mut cnt) = (vec![0.0; ng], vec![0.0; ng], vec![0usize; ng]);
    for &(g, tt, o) in &pts {
        st[g] += tt;
        so[g] += o;
        cnt[g] += 1;
    }
    let (mut sxx, mut sxy, mut m) = (0.0, 0.0, 0usize);
    let groups_used = cnt.iter().filter(|&&c| c > 0).count();
    let centred: Vec<(f64, f64)> = pts
        .iter()
        .map(|&(g, tt, o)| (tt - st[g] / cnt[g] as f64, o - so[g] / cnt[g] as f64))
        .collect();
    for &(x, y) in &centred {
        sxx += x * x;
        sxy += x * y;
        m += 1;
    }
    let df = m as f64 - groups_used as f64 - 1.0;
    if sxx <= 0.0 || df < 1.0 {
        return (f64::NAN, 0.0);
    }
    let slope = sxy / sxx;
    let rss: f64 = centred.iter().map(|&(x, y)| (y - slope * x).powi(2)).sum();
    let se = (rss / df / sxx).sqrt();
    let z = if se > 0.0 { slope / se } else { 0.0 };
    (slope, z)
}
