//! The design: rows (two per sample, grouped by line, cell and position block), the candidate
//! groups' columns, and the per-line sufficient statistics that make cross-validation of any
//! column subset cheap.
use std::collections::HashMap;

use csmetro_effects::{AxisId, Effect, SampleContext, StageModel};
use nalgebra::{DMatrix, DVector};

use super::candidates::Group;
use super::Sample;

/// Row layout: one row per measured component (x, y) of each sample.
pub(super) struct Rows {
    pub(super) n: usize,
    /// Line-demeaned baseline residual.
    pub(super) y: Vec<f64>,
    pub(super) line: Vec<usize>,
    pub(super) comp: Vec<AxisId>,
    pub(super) sample: Vec<usize>,
    /// (line, component) group for demeaning.
    pub(super) lc: Vec<usize>,
    pub(super) n_lc: usize,
    /// (line, component) groups that hold rows: the offsets actually fitted.
    pub(super) n_lc_used: usize,
    /// Cell: (moving axis, static position, component, direction, target), repeated over runs.
    pub(super) cell: Vec<usize>,
    pub(super) n_cells: usize,
    /// (moving axis, static position, component) group of each cell.
    pub(super) cell_group: Vec<usize>,
    pub(super) n_cell_groups: usize,
    /// Runs of each line group (for pure-error degrees of freedom).
    pub(super) runs_per_cell_group: Vec<usize>,
    pub(super) line_run: Vec<usize>,
    pub(super) n_runs: usize,
    pub(super) n_lines: usize,
    /// Position block (quarter of the moving axis' travel) of each row, for the position CV.
    pub(super) block: Vec<usize>,
    /// Mean baseline residual of each (line, component) group before demeaning: the line offsets.
    pub(super) lc_mean: Vec<f64>,
}

/// Position blocks for the position cross-validation gate.
pub(super) const BLOCKS: usize = 4;

pub(super) fn key_um(v: f64) -> i64 {
    (v * 100.0).round() as i64
}

pub(super) fn demean(v: &mut [f64], lc: &[usize], n_lc: usize) {
    let mut s = vec![0.0; n_lc];
    let mut n = vec![0usize; n_lc];
    for (i, &g) in lc.iter().enumerate() {
        s[g] += v[i];
        n[g] += 1;
    }
    for (i, &g) in lc.iter().enumerate() {
        v[i] -= s[g] / n[g] as f64;
    }
}

impl Rows {
    pub(super) fn build(samples: &[Sample], model: &StageModel) -> Rows {
        let mut line_ids: HashMap<(i64, AxisId, i64), usize> = HashMap::new();
        let mut run_ids: HashMap<i64, usize> = HashMap::new();
        let mut cell_ids: HashMap<(AxisId, i64, AxisId, bool, i64), usize> = HashMap::new();
        let mut cg_ids: HashMap<(AxisId, i64, AxisId), usize> = HashMap::new();
        let mut cg_runs: Vec<std::collections::BTreeSet<i64>> = Vec::new();
        let mut line_run = Vec::new();
        let mut cell_group = Vec::new();
        let mut r = Rows {
            n: 0,
            y: Vec::new(),
            line: Vec::new(),
            comp: Vec::new(),
            sample: Vec::new(),
            lc: Vec::new(),
            n_lc: 0,
            n_lc_used: 0,
            cell: Vec::new(),
            n_cells: 0,
            cell_group: Vec::new(),
            n_cell_groups: 0,
            runs_per_cell_group: Vec::new(),
            line_run: Vec::new(),
            n_runs: 0,
            n_lines: 0,
            block: Vec::new(),
            lc_mean: Vec::new(),
        };
        for (i, s) in samples.iter().enumerate() {
            let st = key_um(s.target(s.moving.other()));
            let nr = run_ids.len();
            let run = *run_ids.entry(s.run).or_insert(nr);
            let nl = line_ids.len();
            let line = *line_ids.entry((s.run, s.moving, st)).or_insert(nl);
            if line == line_run.len() {
                line_run.push(run);
            }
            let (px, py) = model.predict(&s.context());
            let u = csmetro_effects::map_to_unit(s.target(s.moving), model.travel(s.moving));
            let block =
                (((u + 1.0) / 2.0 * BLOCKS as f64).floor().max(0.0) as usize).min(BLOCKS - 1);
            for comp in [AxisId::X, AxisId::Y] {
                // An unmeasured component (a one-axis sensor) is no data: it enters no fit,
                // no σ and no RMS.
                if !s.meas(comp).is_finite() {
                    continue;
                }
                r.block.push(block);
                let pred = match comp {
                    AxisId::X => px,
                    AxisId::Y => py,
                };
                let ng = cg_ids.len();
                let cg = *cg_ids.entry((s.moving, st, comp)).or_insert(ng);
                if cg == cg_runs.len() {
                    cg_runs.push(Default::default());
                }
                cg_runs[cg].insert(s.run);
                let nc = cell_ids.len();
                let key = (
                    s.moving,
                    st,
                    comp,
                    s.direction > 0.0,
                    key_um(s.target(s.moving)),
                );
                let cell = *cell_ids.entry(key).or_insert(nc);
                if cell == cell_group.len() {
                    cell_group.push(cg);
                }
                r.y.push(s.meas(comp) - pred);
                r.line.push(line);
                r.comp.push(comp);
                r.sample.push(i);
                r.lc.push(2 * line + usize::from(comp == AxisId::Y));
                r.cell.push(cell);
            }
        }
        r.n = r.y.len();
        r.n_lines = line_ids.len();
        r.n_lc = 2 * r.n_lines;
        let mut used = vec![false; r.n_lc];
        r.lc.iter().for_each(|&g| used[g] = true);
        r.n_lc_used = used.iter().filter(|u| **u).count();
        r.n_cells = cell_ids.len();
        r.cell_group = cell_group;
        r.n_cell_groups = cg_ids.len();
        r.runs_per_cell_group = cg_runs.iter().map(|s| s.len()).collect();
        r.line_run = line_run;
        r.n_runs = run_ids.len();
        let (lc, n_lc) = (r.lc.clone(), r.n_lc);
        let raw = r.y.clone();
        demean(&mut r.y, &lc, n_lc);
        let mut lc_mean = vec![0.0; n_lc];
        let mut cnt = vec![0usize; n_lc];
        for (i, &g) in lc.iter().enumerate() {
            lc_mean[g] += raw[i];
            cnt[g] += 1;
        }
        r.lc_mean = lc_mean
            .iter()
            .zip(&cnt)
            .map(|(s, &n)| if n > 0 { s / n as f64 } else { f64::NAN })
            .collect();
        r
    }
}

/// Per-line sufficient statistics over all columns: CV of any column subset is then cheap.
pub(super) struct Design {
    pub(super) p: usize,
    /// Per-line Gram (p×p, row-major), Xᵀy and yᵀy.
    pub(super) gl: Vec<Vec<f64>>,
    pub(super) bl: Vec<Vec<f64>>,
    pub(super) yyl: Vec<f64>,
    /// Per-run sums.
    pub(super) gr: Vec<Vec<f64>>,
    pub(super) br: Vec<Vec<f64>>,
    pub(super) gt: Vec<f64>,
    pub(super) bt: Vec<f64>,
    /// Per (line, position block) unit: Gram, Xᵀy, yᵀy, and per component the sums (Σx, Σy, n).
    pub(super) gu: Vec<Vec<f64>>,
    pub(super) bu: Vec<Vec<f64>>,
    pub(super) yyu: Vec<f64>,
    pub(super) su: Vec<[(Vec<f64>, f64, f64); 2]>,
    /// Per position block sums.
    pub(super) gk: Vec<Vec<f64>>,
    pub(super) bk: Vec<Vec<f64>>,
    /// Column scale: column used = raw / scale.
    pub(super) scale: Vec<f64>,
    /// Demeaned, scaled columns.
    pub(super) cols: Vec<Vec<f64>>,
    pub(super) dof: f64,
    /// Lines on which each column varies (a column constant on a line is its offset there).
    pub(super) col_lines: Vec<Vec<bool>>,
    /// Rows per (line, position block) unit.
    pub(super) unit_rows: Vec<usize>,
}

pub(super) fn add_to(a: &mut [f64], b: &[f64]) {
    a.iter_mut().zip(b).for_each(|(x, y)| *x += y);
}

impl Design {
    pub(super) fn new(rows: &Rows, cols: Vec<Vec<f64>>, scale: Vec<f64>) -> Design {
        let p = cols.len();
        let nu = rows.n_lines * BLOCKS;
        let mut gu = vec![vec![0.0; p * p]; nu];
        let mut bu = vec![vec![0.0; p]; nu];
        let mut yyu = vec![0.0; nu];
        let mut su: Vec<[(Vec<f64>, f64, f64); 2]> =
            vec![[(vec![0.0; p], 0.0, 0.0), (vec![0.0; p], 0.0, 0.0)]; nu];
        let mut xi = vec![0.0; p];
        for i in 0..rows.n {
            let u = rows.line[i] * BLOCKS + rows.block[i];
            for j in 0..p {
                xi[j] = cols[j][i];
            }
            let g = &mut gu[u];
            for a in 0..p {
                if xi[a] == 0.0 {
                    continue;
                }
                for b in a..p {
                    g[a * p + b] += xi[a] * xi[b];
                }
                bu[u][a] += xi[a] * rows.y[i];
            }
            yyu[u] += rows.y[i] * rows.y[i];
            let c = &mut su[u][usize::from(rows.comp[i] == AxisId::Y)];
            add_to(&mut c.0, &xi);
            c.1 += rows.y[i];
            c.2 += 1.0;
        }
        for g in gu.iter_mut() {
            for a in 0..p {
                for b in 0..a {
                    g[a * p + b] = g[b * p + a];
                }
            }
        }
        let mut gl = vec![vec![0.0; p * p]; rows.n_lines];
        let mut bl = vec![vec![0.0; p]; rows.n_lines];
        let mut yyl = vec![0.0; rows.n_lines];
        let mut gk = vec![vec![0.0; p * p]; BLOCKS];
        let mut bk = vec![vec![0.0; p]; BLOCKS];
        for u in 0..nu {
            let (l, k) = (u / BLOCKS, u % BLOCKS);
            add_to(&mut gl[l], &gu[u]);
            add_to(&mut bl[l], &bu[u]);
            yyl[l] += yyu[u];
            add_to(&mut gk[k], &gu[u]);
            add_to(&mut bk[k], &bu[u]);
        }
        let mut gr = vec![vec![0.0; p * p]; rows.n_runs];
        let mut br = vec![vec![0.0; p]; rows.n_runs];
        for l in 0..rows.n_lines {
            let r = rows.line_run[l];
            add_to(&mut gr[r], &gl[l]);
            add_to(&mut br[r], &bl[l]);
        }
        let mut gt = vec![0.0; p * p];
        let mut bt = vec![0.0; p];
        for r in 0..rows.n_runs {
            add_to(&mut gt, &gr[r]);
            add_to(&mut bt, &br[r]);
        }
        let mut col_lines = vec![vec![false; rows.n_lines]; p];
        for (j, c) in cols.iter().enumerate() {
            for (i, v) in c.iter().enumerate() {
                if v.abs() > 1e-9 {
                    col_lines[j][rows.line[i]] = true;
                }
            }
        }
        let mut unit_rows = vec![0usize; nu];
        for i in 0..rows.n {
            unit_rows[rows.line[i] * BLOCKS + rows.block[i]] += 1;
        }
        Design {
            unit_rows,
            col_lines,
            p,
            gl,
            bl,
            yyl,
            gr,
            br,
            gt,
            bt,
            gu,
            bu,
            yyu,
            su,
            gk,
            bk,
            scale,
            cols,
            dof: rows.n.saturating_sub(rows.n_lc_used) as f64,
        }
    }

    /// Position cross-validation: hold out each quarter of the travel (all runs), fit on the rest,
    /// predict the held-out quarter (line offsets refit on it). Per (line, block) SSE.
    /// A fit to a local defect does not carry over to other parts of the travel; a real effect does.
    pub(super) fn block_cv(&self, s: &[usize]) -> Cv {
        let p = self.p;
        let mut sse = Vec::with_capacity(self.yyu.len());
        let betas: Vec<DVector<f64>> = (0..BLOCKS)
            .map(|k| {
                let g: Vec<f64> = (0..p * p).map(|j| self.gt[j] - self.gk[k][j]).collect();
                let b: Vec<f64> = (0..p).map(|j| self.bt[j] - self.bk[k][j]).collect();
                let (a, v) = self.sub(&g, &b, s);
                solve(a, v)
            })
            .collect();
        for u in 0..self.yyu.len() {
            let beta = &betas[u % BLOCKS];
            let (a, v) = self.sub(&self.gu[u], &self.bu[u], s);
            let mut e = self.yyu[u];
            if !s.is_empty() {
                e += -2.0 * beta.dot(&v) + beta.dot(&(a * beta));
            }
            for (sx, sy, n) in &self.su[u] {
                if *n > 0.0 {
                    let m = sy
                        - s.iter()
                            .zip(beta.iter())
                            .map(|(&j, b)| sx[j] * b)
                            .sum::<f64>();
                    e -= m * m / n;
                }
            }
            sse.push(e);
        }
        let total: f64 = sse.iter().sum();
        Cv {
            rms: (total.max(0.0) / self.dof.max(1.0)).sqrt(),
            sse,
        }
    }

    /// Lines on which any of `new` columns varies.
    pub(super) fn line_mask(&self, new: &[usize]) -> Vec<bool> {
        let n = self.col_lines.first().map_or(0, Vec::len);
        (0..n)
            .map(|l| new.iter().any(|&j| self.col_lines[j][l]))
            .collect()
    }

    /// (line, block) units with rows on lines in `lines`.
    pub(super) fn unit_mask(&self, lines: &[bool]) -> Vec<bool> {
        (0..self.unit_rows.len())
            .map(|u| self.unit_rows[u] > 0 && lines[u / BLOCKS])
            .collect()
    }

    pub(super) fn sub(&self, g: &[f64], b: &[f64], s: &[usize]) -> (DMatrix<f64>, DVector<f64>) {
        let p = self.p;
        let a = DMatrix::from_fn(s.len(), s.len(), |i, j| g[s[i] * p + s[j]]);
        let v = DVector::from_fn(s.len(), |i, _| b[s[i]]);
        (a, v)
    }

    /// Cross-validation holding out whole runs: per-line held-out SSE (line offsets refit).
    pub(super) fn cv(&self, rows: &Rows, s: &[usize]) -> Cv {
        let p = self.p;
        let mut sse = self.yyl.clone();
        if !s.is_empty() {
            let mut betas = Vec::with_capacity(rows.n_runs);
            for r in 0..rows.n_runs {
                let g: Vec<f64> = (0..p * p).map(|k| self.gt[k] - self.gr[r][k]).collect();
                let b: Vec<f64> = (0..p).map(|k| self.bt[k] - self.br[r][k]).collect();
                let (a, v) = self.sub(&g, &b, s);
                betas.push(solve(a, v));
            }
            for (l, e) in sse.iter_mut().enumerate() {
                let beta = &betas[rows.line_run[l]];
                let (a, v) = self.sub(&self.gl[l], &self.bl[l], s);
                *e += -2.0 * beta.dot(&v) + beta.dot(&(a * beta));
            }
        }
        let total: f64 = sse.iter().sum();
        Cv {
            rms: (total.max(0.0) / self.dof.max(1.0)).sqrt(),
            sse,
        }
    }

    /// In-sample least squares on all data.
    pub(super) fn fit(&self, s: &[usize]) -> DVector<f64> {
        let (a, v) = self.sub(&self.gt, &self.bt, s);
        solve(a, v)
    }

    pub(super) fn residual(&self, rows: &Rows, s: &[usize], beta: &DVector<f64>) -> Vec<f64> {
        let mut e = rows.y.clone();
        for (k, &j) in s.iter().enumerate() {
            for (i, v) in e.iter_mut().enumerate() {
                *v -= beta[k] * self.cols[j][i];
            }
        }
        e
    }
}

/// Ridge-stabilised normal equations (columns are scaled to unit RMS, so the ridge is tiny).
pub(super) fn solve(mut a: DMatrix<f64>, v: DVector<f64>) -> DVector<f64> {
    let n = a.nrows();
    if n == 0 {
        return v;
    }
    let dmax = (0..n).map(|i| a[(i, i)]).fold(0.0f64, f64::max).max(1e-300);
    for i in 0..n {
        a[(i, i)] += 1e-9 * dmax;
    }
    match a.clone().cholesky() {
        Some(c) => c.solve(&v),
        None => a
            .svd(true, true)
            .solve(&v, 1e-12 * dmax)
            .unwrap_or_else(|_| DVector::zeros(n)),
    }
}

#[derive(Debug, Clone)]
pub(super) struct Cv {
    pub(super) rms: f64,
    pub(super) sse: Vec<f64>,
}

/// Paired t of (a - b) over held-out lines: > 0 when b is better.
pub(super) fn paired_t(a: &Cv, b: &Cv) -> f64 {
    paired_t_on(a, b, None)
}

/// Paired t over the held-out units in `mask` only: the units a candidate cannot change (lines
/// its columns are constant on) would only dilute the mean (an effect seen on the one y line of
/// four lines per run could never reach t = 3 however strong).
pub(super) fn paired_t_on(a: &Cv, b: &Cv, mask: Option<&[bool]>) -> f64 {
    let d: Vec<f64> = a
        .sse
        .iter()
        .zip(&b.sse)
        .enumerate()
        .filter(|(i, _)| mask.is_none_or(|m| m[*i]))
        .map(|(_, (x, y))| x - y)
        .collect();
    let n = d.len() as f64;
    if n < 2.0 {
        return 0.0;
    }
    let m = d.iter().sum::<f64>() / n;
    let v = d.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (n - 1.0);
    if v <= 0.0 {
        return if m > 0.0 { f64::INFINITY } else { 0.0 };
    }
    m / (v / n).sqrt()
}

/// Builds the design columns of every group (deduplicated, demeaned per line, unit RMS).
pub(super) fn build_columns(
    samples: &[Sample],
    model: &StageModel,
    rows: &Rows,
    groups: &mut [Group],
) -> (Vec<Vec<f64>>, Vec<f64>) {
    let mut cols: Vec<Vec<f64>> = Vec::new();
    let mut scale: Vec<f64> = Vec::new();
    let ctx: Vec<SampleContext> = samples.iter().map(Sample::context).collect();
    for g in groups.iter_mut() {
        let np = g.spec.n_params();
        for j in 0..np {
            let mut c = vec![0.0; np];
            c[j] = 1.0;
            let mut e = Effect::new(g.axis, g.spec.kind(&c));
            e.travel_um = g.travel_um;
            let unit = StageModel::new(model.travel_x_um, model.travel_y_um).with(e);
            let mut v: Vec<f64> = (0..rows.n)
                .map(|i| {
                    let d = unit.effect_deviation(0, &ctx[rows.sample[i]]);
                    d.get(rows.comp[i])
                })
                .collect();
            demean(&mut v, &rows.lc, rows.n_lc);
            let norm = (v.iter().map(|x| x * x).sum::<f64>() / rows.n as f64).sqrt();
            if norm < 1e-9 {
                g.cols.push(None);
                continue;
            }
            v.iter_mut().for_each(|x| *x /= norm);
            let dup = cols
                .iter()
                .position(|c: &Vec<f64>| c.iter().zip(&v).all(|(a, b)| (a - b).abs() < 1e-12));
            match dup {
                Some(k) if (scale[k] - norm).abs() <= 1e-12 * norm => g.cols.push(Some(k)),
                _ => {
                    cols.push(v);
                    scale.push(norm);
                    g.cols.push(Some(cols.len() - 1));
                }
            }
        }
    }
    (cols, scale)
}

pub(super) fn union(a: &[usize], b: &[usize]) -> Vec<usize> {
    let mut s: Vec<usize> = a.iter().chain(b).copied().collect();
    s.sort_unstable();
    s.dedup();
    s
}
