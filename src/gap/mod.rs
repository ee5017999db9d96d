//! Sim-to-real gap diagnosis (see the gap-diagnosis issue and shared/notes/gap-contract.md).
//!
//! Pipeline: residual = measured - baseline prediction; every line (run, moving axis, static
//! position) × component gets its own constant offset (nuisance), removed exactly by demeaning the
//! residual and every design column within the line (Frisch–Waugh). Candidate effect groups are
//! linear in their parameters once their structure is fixed (period, travel, offset, τ), so each
//! group's columns are `effect_deviation` of unit-parameter effects. Groups are added greedily,
//! scored by the held-out RMS of leave-one-run-out cross-validation (held-out line offsets refit
//! on the held-out line), accepted only by a paired t-test over held-out lines. Repeatability
//! (pure error over repeated runs) gives σ; lack of fit and time structure against σ say whether
//! something remains unexplained and where.
pub mod data;
pub mod selftest;

use std::collections::{BTreeMap, HashMap};

use csmetro_sim::model::{AxisId, Effect, EffectKind, SampleContext, StageModel};
use nalgebra::{DMatrix, DVector};
use serde_json::{json, Value as Json};

pub use data::Sample;

/// Knobs of the diagnosis (defaults are what the selftest calibrates).
#[derive(Debug, Clone)]
pub struct Options {
    /// Candidate kinds (None = the whole library).
    pub kinds: Option<Vec<String>>,
    /// Motor/encoder period when the model has no `motor_cyclic` of that axis, µm.
    pub motor_period_um: f64,
    /// Leadscrew harmonics fitted (at least those of the model's own effect).
    pub leadscrew_harmonics: usize,
    /// τ grid for `thermal_drift`, s.
    pub tau_grid_s: Vec<f64>,
    /// Paired t over held-out lines needed to accept a group.
    pub t_accept: f64,
    /// Paired t over (line, position block) units the position cross-validation must also show.
    pub t_block: f64,
    /// Paired t under which two candidates are a tie (not told apart by held-out data).
    pub t_tie: f64,
    /// Relative residual under which a candidate (or pair) reproduces the pick: a confound.
    pub span_tie: f64,
    pub max_steps: usize,
    /// Position bins per travel for `where`.
    pub bins: usize,
    /// Time bins over the campaign.
    pub time_bins: usize,
    /// z (Wilson–Hilferty on χ² against σ) for a significant bin.
    pub z_where: f64,
    /// z for significant unexplained structure (lack of fit or time structure).
    pub z_unexplained: f64,
}

impl Default for Options {
    fn default() -> Self {
        Self {
            kinds: None,
            motor_period_um: 400.0 / 28.4,
            leadscrew_harmonics: 3,
            tau_grid_s: vec![300.0, 600.0, 1200.0, 2400.0, 4800.0, 9600.0],
            t_accept: 3.0,
            t_block: 2.0,
            t_tie: 2.0,
            span_tie: 0.1,
            max_steps: 6,
            bins: 24,
            time_bins: 60,
            z_where: 3.7,
            z_unexplained: 3.5,
        }
    }
}

/// The fitted structure of a candidate group: everything but its linear coefficients.
#[derive(Debug, Clone, PartialEq)]
enum Spec {
    Scale {
        ref_um: f64,
    },
    Cyclic {
        motor: bool,
        period_um: f64,
        h: usize,
    },
    Backlash,
    Hysteresis,
    Straightness {
        k: usize,
    },
    Yaw {
        offset_um: f64,
    },
    Squareness,
    CamRot,
    CamScale,
    Thermal {
        component: AxisId,
        tau_s: f64,
    },
}

impl Spec {
    fn kind_name(&self) -> &'static str {
        match self {
            Spec::Scale { .. } => "scale",
            Spec::Cyclic { motor: false, .. } => "leadscrew_cyclic",
            Spec::Cyclic { motor: true, .. } => "motor_cyclic",
            Spec::Backlash => "backlash",
            Spec::Hysteresis => "hysteresis",
            Spec::Straightness { .. } => "straightness",
            Spec::Yaw { .. } => "yaw_abbe",
            Spec::Squareness => "squareness",
            Spec::CamRot => "camera_rotation",
            Spec::CamScale => "camera_scale",
            Spec::Thermal { .. } => "thermal_drift",
        }
    }
    fn n_params(&self) -> usize {
        match self {
            Spec::Cyclic { h, .. } => 2 * h,
            Spec::Hysteresis | Spec::Yaw { .. } | Spec::Thermal { .. } => 2,
            Spec::Straightness { k } => *k,
            _ => 1,
        }
    }
    /// The effect kind with these linear coefficients.
    fn kind(&self, c: &[f64]) -> EffectKind {
        match self {
            Spec::Scale { ref_um } => EffectKind::Scale {
                ppm: c[0],
                ref_um: *ref_um,
            },
            Spec::Cyclic {
                motor,
                period_um,
                h,
            } => {
                let cos_um = (0..*h).map(|i| c[2 * i]).collect();
                let sin_um = (0..*h).map(|i| c[2 * i + 1]).collect();
                if *motor {
                    EffectKind::MotorCyclic {
                        period_um: *period_um,
                        cos_um,
                        sin_um,
                    }
                } else {
                    EffectKind::LeadscrewCyclic {
                        period_um: *period_um,
                        cos_um,
                        sin_um,
                    }
                }
            }
            Spec::Backlash => EffectKind::Backlash { reversal_um: c[0] },
            Spec::Hysteresis => EffectKind::Hysteresis {
                b0_um: c[0],
                b1_um: c[1],
            },
            Spec::Straightness { .. } => EffectKind::Straightness {
                legendre_um: c.to_vec(),
            },
            Spec::Yaw { offset_um } => EffectKind::YawAbbe {
                yaw_urad: [c[0], c[1]],
                offset_um: *offset_um,
            },
            Spec::Squareness => EffectKind::Squareness { angle_urad: c[0] },
            Spec::CamRot => EffectKind::CameraRotation { angle_urad: c[0] },
            Spec::CamScale => EffectKind::CameraScale { ppm: c[0] },
            Spec::Thermal { component, tau_s } => EffectKind::ThermalDrift {
                component: *component,
                amp_um: c[0],
                tau_s: *tau_s,
                rate_um_per_h: c[1],
            },
        }
    }
}

/// A candidate group: one kind on one axis (global kinds once; thermal once per component and τ).
#[derive(Debug, Clone)]
struct Group {
    spec: Spec,
    axis: AxisId,
    travel_um: Option<[f64; 2]>,
    /// Column index per parameter (None = not identifiable from line data, e.g. a constant per line).
    cols: Vec<Option<usize>>,
}

impl Group {
    fn kind(&self) -> &'static str {
        self.spec.kind_name()
    }
    /// `x`, `y` or `-` (global); thermal drift by component.
    fn axis_label(&self) -> String {
        match &self.spec {
            Spec::CamRot | Spec::CamScale => "-".into(),
            Spec::Thermal { component, .. } => component.as_str().into(),
            _ => self.axis.as_str().into(),
        }
    }
    fn label(&self) -> String {
        match &self.spec {
            Spec::CamRot | Spec::CamScale => self.kind().into(),
            _ => format!("{} {}", self.kind(), self.axis_label()),
        }
    }
    /// Family key: thermal groups of one component with different τ are alternatives.
    fn family(&self) -> String {
        self.label()
    }
    fn col_set(&self) -> Vec<usize> {
        self.cols.iter().flatten().copied().collect()
    }
}

/// Row layout: two rows (x, y components) per sample.
struct Rows {
    n: usize,
    /// Line-demeaned baseline residual.
    y: Vec<f64>,
    line: Vec<usize>,
    comp: Vec<AxisId>,
    sample: Vec<usize>,
    /// (line, component) group for demeaning.
    lc: Vec<usize>,
    n_lc: usize,
    /// Cell: (moving axis, static position, component, direction, target), repeated over runs.
    cell: Vec<usize>,
    n_cells: usize,
    /// (moving axis, static position, component) group of each cell.
    cell_group: Vec<usize>,
    n_cell_groups: usize,
    /// Runs of each line group (for pure-error degrees of freedom).
    runs_per_cell_group: Vec<usize>,
    line_run: Vec<usize>,
    n_runs: usize,
    n_lines: usize,
    /// Position block (quarter of the moving axis' travel) of each row, for the position CV.
    block: Vec<usize>,
}

/// Position blocks for the position cross-validation gate.
const BLOCKS: usize = 4;

fn key_um(v: f64) -> i64 {
    (v * 100.0).round() as i64
}

fn demean(v: &mut [f64], lc: &[usize], n_lc: usize) {
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
    fn build(samples: &[Sample], model: &StageModel) -> Rows {
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
            cell: Vec::new(),
            n_cells: 0,
            cell_group: Vec::new(),
            n_cell_groups: 0,
            runs_per_cell_group: Vec::new(),
            line_run: Vec::new(),
            n_runs: 0,
            n_lines: 0,
            block: Vec::new(),
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
            let u = csmetro_sim::model::map_to_unit(s.target(s.moving), model.travel(s.moving));
            let block =
                (((u + 1.0) / 2.0 * BLOCKS as f64).floor().max(0.0) as usize).min(BLOCKS - 1);
            for comp in [AxisId::X, AxisId::Y] {
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
        r.n_cells = cell_ids.len();
        r.cell_group = cell_group;
        r.n_cell_groups = cg_ids.len();
        r.runs_per_cell_group = cg_runs.iter().map(|s| s.len()).collect();
        r.line_run = line_run;
        r.n_runs = run_ids.len();
        let (lc, n_lc) = (r.lc.clone(), r.n_lc);
        demean(&mut r.y, &lc, n_lc);
        r
    }
}

/// Per-line sufficient statistics over all columns: CV of any column subset is then cheap.
struct Design {
    p: usize,
    /// Per-line Gram (p×p, row-major), Xᵀy and yᵀy.
    gl: Vec<Vec<f64>>,
    bl: Vec<Vec<f64>>,
    yyl: Vec<f64>,
    /// Per-run sums.
    gr: Vec<Vec<f64>>,
    br: Vec<Vec<f64>>,
    gt: Vec<f64>,
    bt: Vec<f64>,
    /// Per (line, position block) unit: Gram, Xᵀy, yᵀy, and per component the sums (Σx, Σy, n).
    gu: Vec<Vec<f64>>,
    bu: Vec<Vec<f64>>,
    yyu: Vec<f64>,
    su: Vec<[(Vec<f64>, f64, f64); 2]>,
    /// Per position block sums.
    gk: Vec<Vec<f64>>,
    bk: Vec<Vec<f64>>,
    /// Column scale: column used = raw / scale.
    scale: Vec<f64>,
    /// Demeaned, scaled columns.
    cols: Vec<Vec<f64>>,
    dof: f64,
}

fn add_to(a: &mut [f64], b: &[f64]) {
    a.iter_mut().zip(b).for_each(|(x, y)| *x += y);
}

impl Design {
    fn new(rows: &Rows, cols: Vec<Vec<f64>>, scale: Vec<f64>) -> Design {
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
        Design {
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
            dof: (rows.n - rows.n_lc) as f64,
        }
    }

    /// Position cross-validation: hold out each quarter of the travel (all runs), fit on the rest,
    /// predict the held-out quarter (line offsets refit on it). Per (line, block) SSE.
    /// A fit to a local defect does not carry over to other parts of the travel; a real effect does.
    fn block_cv(&self, s: &[usize]) -> Cv {
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

    fn sub(&self, g: &[f64], b: &[f64], s: &[usize]) -> (DMatrix<f64>, DVector<f64>) {
        let p = self.p;
        let a = DMatrix::from_fn(s.len(), s.len(), |i, j| g[s[i] * p + s[j]]);
        let v = DVector::from_fn(s.len(), |i, _| b[s[i]]);
        (a, v)
    }

    /// Cross-validation holding out whole runs: per-line held-out SSE (line offsets refit).
    fn cv(&self, rows: &Rows, s: &[usize]) -> Cv {
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
    fn fit(&self, s: &[usize]) -> DVector<f64> {
        let (a, v) = self.sub(&self.gt, &self.bt, s);
        solve(a, v)
    }

    fn residual(&self, rows: &Rows, s: &[usize], beta: &DVector<f64>) -> Vec<f64> {
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
fn solve(mut a: DMatrix<f64>, v: DVector<f64>) -> DVector<f64> {
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
struct Cv {
    rms: f64,
    sse: Vec<f64>,
}

/// Paired t of (a - b) over held-out lines: > 0 when b is better.
fn paired_t(a: &Cv, b: &Cv) -> f64 {
    let d: Vec<f64> = a.sse.iter().zip(&b.sse).map(|(x, y)| x - y).collect();
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

/// Wilson–Hilferty z of a χ² statistic with k degrees of freedom.
pub fn chi2_z(x: f64, k: f64) -> f64 {
    if k <= 0.0 {
        return 0.0;
    }
    let a = 2.0 / (9.0 * k);
    ((x / k).max(0.0).cbrt() - (1.0 - a)) / a.sqrt()
}

/// Input problems of the diagnosis (exit code 2 at the CLI).
#[derive(Debug)]
pub struct GapError(pub String);

impl std::fmt::Display for GapError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

/// One tie: a candidate (or set) the data cannot tell apart from the pick.
#[derive(Debug, Clone)]
pub struct Tie {
    pub members: Vec<(String, String)>,
    pub heldout_rms_um: Option<f64>,
    /// "score" (held-out score within noise) or "span" (reproduces the pick's fitted deviation).
    pub reason: &'static str,
}

impl Tie {
    pub fn label(&self) -> String {
        self.members
            .iter()
            .map(|(k, a)| {
                if a == "-" {
                    k.clone()
                } else {
                    format!("{k} {a}")
                }
            })
            .collect::<Vec<_>>()
            .join(" + ")
    }
}

/// One accepted effect group.
#[derive(Debug, Clone)]
pub struct Added {
    pub kind: String,
    /// x, y, or "-" for camera kinds (thermal drift: its component).
    pub axis: String,
    /// The fitted effect (what the data say the missing effect is), final joint fit.
    pub effect: Effect,
    pub heldout_rms_um: f64,
    pub gap_closed: Option<f64>,
    pub t_stat: f64,
    pub ties: Vec<Tie>,
}

/// One significant interval of the residual.
#[derive(Debug, Clone)]
pub struct Where {
    pub map: &'static str,
    pub axis: Option<AxisId>,
    pub direction: Option<&'static str>,
    pub component: Option<AxisId>,
    pub from: f64,
    pub to: f64,
    pub share: f64,
    pub z: f64,
    pub peak_um: f64,
}

#[derive(Debug, Clone)]
pub struct Unexplained {
    pub significant: bool,
    pub rms_um: f64,
    pub lack_of_fit_z: f64,
    pub time_z: f64,
    pub where_: Vec<Where>,
    pub frequency: Vec<Peak>,
}

/// A significant periodogram peak of the residual over position.
#[derive(Debug, Clone)]
pub struct Peak {
    pub axis: AxisId,
    pub component: AxisId,
    pub period_um: f64,
    pub amplitude_um: f64,
    /// False-alarm probability (Bonferroni over the frequency grid).
    pub fap: f64,
}

impl Peak {
    pub fn describe(&self) -> String {
        format!(
            "periodic: {} lines, {} component, period {:.2} µm, amplitude {:.3} µm (false-alarm p {:.1e})",
            self.axis, self.component, self.period_um, self.amplitude_um, self.fap
        )
    }

    pub fn to_json(&self) -> Json {
        json!({
            "axis": self.axis.as_str(),
            "component": self.component.as_str(),
            "period_um": self.period_um,
            "amplitude_um": self.amplitude_um,
            "fap": self.fap,
        })
    }
}

/// Other-axis map: systematic residual per line group (moving axis, static position, component).
#[derive(Debug, Clone)]
pub struct OtherAxis {
    pub axis: AxisId,
    pub component: AxisId,
    /// Position of the static (other) axis, µm.
    pub static_um: f64,
    /// RMS of the systematic part (cell means in excess of the repeatability), µm.
    pub rms_um: f64,
    pub z: f64,
}

impl OtherAxis {
    pub fn to_json(&self) -> Json {
        json!({
            "axis": self.axis.as_str(),
            "component": self.component.as_str(),
            "static_um": self.static_um,
            "rms_um": self.rms_um,
            "z": self.z,
        })
    }
}

fn other_axis_map(samples: &[Sample], rows: &Rows, cs: &CellStats, sigma2: f64) -> Vec<OtherAxis> {
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
fn frequency_map(
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

#[derive(Debug, Clone)]
pub struct Diagnosis {
    pub n_samples: usize,
    pub n_runs: usize,
    pub n_lines: usize,
    pub sigma_um: f64,
    pub sigma_from_repeats: bool,
    pub heldout_rms_before_um: f64,
    pub heldout_rms_after_um: f64,
    pub lack_of_fit_before_z: f64,
    pub added: Vec<Added>,
    pub where_: Vec<Where>,
    pub frequency: Vec<Peak>,
    pub other_axis: Vec<OtherAxis>,
    pub unexplained: Unexplained,
    pub model: StageModel,
    pub candidates: Vec<String>,
}

fn candidate_groups(model: &StageModel, rows_have: &[AxisId], opts: &Options) -> Vec<Group> {
    let allowed = |k: &str| {
        opts.kinds
            .as_ref()
            .is_none_or(|ks| ks.iter().any(|x| x == k))
    };
    let existing = |kind: &str, axis: AxisId| -> Option<&Effect> {
        model
            .effects
            .iter()
            .find(|e| e.kind.name() == kind && (e.kind.is_global() || e.axis == axis))
    };
    let mut out = Vec::new();
    let mut push = |spec: Spec, axis: AxisId, travel: Option<[f64; 2]>| {
        if allowed(spec.kind_name()) {
            out.push(Group {
                spec,
                axis,
                travel_um: travel,
                cols: Vec::new(),
            });
        }
    };
    for &a in &[AxisId::X, AxisId::Y] {
        if !rows_have.contains(&a) {
            continue;
        }
        let tr = |k: &str| existing(k, a).and_then(|e| e.travel_um);
        let ref_um = match existing("scale", a).map(|e| &e.kind) {
            Some(EffectKind::Scale { ref_um, .. }) => *ref_um,
            _ => 0.0,
        };
        push(Spec::Scale { ref_um }, a, tr("scale"));
        for motor in [false, true] {
            let name = if motor {
                "motor_cyclic"
            } else {
                "leadscrew_cyclic"
            };
            let (period_um, h0) = match existing(name, a).map(|e| &e.kind) {
                Some(EffectKind::LeadscrewCyclic {
                    period_um,
                    cos_um,
                    sin_um,
                })
                | Some(EffectKind::MotorCyclic {
                    period_um,
                    cos_um,
                    sin_um,
                }) => (*period_um, cos_um.len().max(sin_um.len())),
                _ => (if motor { opts.motor_period_um } else { 400.0 }, 0),
            };
            let h = if motor {
                h0.max(1)
            } else {
                h0.max(opts.leadscrew_harmonics)
            };
            push(
                Spec::Cyclic {
                    motor,
                    period_um,
                    h,
                },
                a,
                tr(name),
            );
        }
        push(Spec::Backlash, a, None);
        push(Spec::Hysteresis, a, tr("hysteresis"));
        let k = match existing("straightness", a).map(|e| &e.kind) {
            Some(EffectKind::Straightness { legendre_um }) => legendre_um.len().max(3),
            _ => 3,
        };
        push(Spec::Straightness { k }, a, tr("straightness"));
        let offset_um = match existing("yaw_abbe", a).map(|e| &e.kind) {
            Some(EffectKind::YawAbbe { offset_um, .. }) => *offset_um,
            _ => 0.0,
        };
        push(Spec::Yaw { offset_um }, a, tr("yaw_abbe"));
        if a == AxisId::Y {
            push(Spec::Squareness, a, None);
        }
    }
    push(Spec::CamRot, AxisId::X, None);
    push(Spec::CamScale, AxisId::X, None);
    for c in [AxisId::X, AxisId::Y] {
        let mut taus = opts.tau_grid_s.clone();
        for e in &model.effects {
            if let EffectKind::ThermalDrift {
                component, tau_s, ..
            } = e.kind
            {
                if component == c && !taus.contains(&tau_s) {
                    taus.push(tau_s);
                }
            }
        }
        for tau_s in taus {
            push(
                Spec::Thermal {
                    component: c,
                    tau_s,
                },
                AxisId::X,
                None,
            );
        }
    }
    out
}

/// Builds the design columns of every group (deduplicated, demeaned per line, unit RMS).
fn build_columns(
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

fn union(a: &[usize], b: &[usize]) -> Vec<usize> {
    let mut s: Vec<usize> = a.iter().chain(b).copied().collect();
    s.sort_unstable();
    s.dedup();
    s
}

/// `big` generalises `small` (same axis): a tie between them is not a confound.
fn generalises(big: &Group, small: &Group) -> bool {
    big.axis == small.axis && matches!((&big.spec, &small.spec), (Spec::Hysteresis, Spec::Backlash))
}

/// Cell means of a residual, and the pure-error σ² with its degrees of freedom.
struct CellStats {
    mean: Vec<f64>,
    n: Vec<usize>,
    ss_lof: f64,
    df_lof: f64,
    ss_pe: f64,
    df_pe: f64,
}

fn cell_stats(rows: &Rows, e: &[f64], p: usize) -> CellStats {
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
type Bin = (f64, f64, f64);

/// Position map (cell means binned over the moving axis' travel, per axis, direction and
/// component; χ² over the static positions of a bin so cancelling structure still counts) and
/// time map (pure-error residuals binned over time). Returns significant intervals, the total
/// time-structure z, and the excess sum of squares.
fn where_maps(
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

/// Diagnoses the gap between `samples` and `model`.
pub fn diagnose(
    model: &StageModel,
    samples: &[Sample],
    opts: &Options,
) -> Result<Diagnosis, GapError> {
    if let Some(ks) = &opts.kinds {
        for k in ks {
            if k == "noise" || !csmetro_sim::model::LIBRARY_KINDS.contains(&k.as_str()) {
                return Err(GapError(format!(
                    "unknown candidate kind `{k}` (library: {})",
                    csmetro_sim::model::LIBRARY_KINDS
                        .iter()
                        .filter(|k| **k != "noise")
                        .copied()
                        .collect::<Vec<_>>()
                        .join(", ")
                )));
            }
        }
    }
    let mut runs: Vec<i64> = samples.iter().map(|s| s.run).collect();
    runs.sort_unstable();
    runs.dedup();
    if runs.len() < 2 {
        return Err(GapError(format!(
            "the data hold a single run ({}): nothing can be held out; at least 2 repeated runs are needed",
            runs.first().copied().unwrap_or(0)
        )));
    }
    let rows = Rows::build(samples, model);
    let mut have: Vec<AxisId> = samples.iter().map(|s| s.moving).collect();
    have.sort();
    have.dedup();
    let mut groups = candidate_groups(model, &have, opts);
    let (cols, scale) = build_columns(samples, model, &rows, &mut groups);
    groups.retain(|g| g.cols.iter().any(Option::is_some));
    let design = Design::new(&rows, cols, scale);

    // σ from repeats on the baseline residual, refined on the final residual below.
    let cs0 = cell_stats(&rows, &rows.y, 0);
    let mut current: Vec<usize> = Vec::new();
    let base_cv = design.cv(&rows, &current);
    let mut cur_cv = base_cv.clone();
    let mut chosen: Vec<usize> = Vec::new();
    let mut steps: Vec<(f64, f64, Vec<Tie>)> = Vec::new();
    let mut used_families: Vec<String> = Vec::new();
    for _ in 0..opts.max_steps {
        let cur_block = design.block_cv(&current);
        let mut evals: Vec<(usize, Vec<usize>, Cv, f64)> = Vec::new();
        let mut gated: Vec<(usize, Cv, f64)> = Vec::new();
        for (gi, g) in groups.iter().enumerate() {
            if chosen.contains(&gi) || used_families.contains(&g.family()) {
                continue;
            }
            let s = union(&current, &g.col_set());
            if s.len() == current.len() {
                continue;
            }
            let cv = design.cv(&rows, &s);
            let t = paired_t(&cur_cv, &cv);
            // Gate: the group must also predict parts of the travel it was not fitted on.
            if t > opts.t_accept && paired_t(&cur_block, &design.block_cv(&s)) <= opts.t_block {
                gated.push((gi, cv, t));
                continue;
            }
            evals.push((gi, s, cv, t));
        }
        let sig: Vec<&(usize, Vec<usize>, Cv, f64)> =
            evals.iter().filter(|e| e.3 > opts.t_accept).collect();
        let Some(best) = sig.iter().min_by(|a, b| a.2.rms.total_cmp(&b.2.rms)) else {
            // Two effects on the same lines can each fail the position gate alone (neither
            // extrapolates without the other): try pairs of the best gated candidates jointly.
            gated.sort_by(|a, b| a.1.rms.total_cmp(&b.1.rms));
            gated.truncate(6);
            let mut best_pair: Option<(usize, usize, Vec<usize>, Cv, f64)> = None;
            for (x, (ga, _, _)) in gated.iter().enumerate() {
                for (gb, _, _) in &gated[x + 1..] {
                    if groups[*ga].family() == groups[*gb].family() {
                        continue;
                    }
                    let s2 = union(
                        &union(&current, &groups[*ga].col_set()),
                        &groups[*gb].col_set(),
                    );
                    let cv = design.cv(&rows, &s2);
                    let t = paired_t(&cur_cv, &cv);
                    if t > opts.t_accept
                        && paired_t(&cur_block, &design.block_cv(&s2)) > opts.t_block
                        && best_pair.as_ref().is_none_or(|b| cv.rms < b.3.rms)
                    {
                        best_pair = Some((*ga, *gb, s2, cv, t));
                    }
                }
            }
            let Some((ga, gb, s2, cv, t)) = best_pair else {
                break;
            };
            let first = gated.iter().find(|g| g.0 == ga).expect("from gated");
            steps.push((first.1.rms, first.2, Vec::new()));
            steps.push((cv.rms, t, Vec::new()));
            for g in [ga, gb] {
                used_families.push(groups[g].family());
                chosen.push(g);
            }
            current = s2;
            cur_cv = cv;
            continue;
        };
        // Parsimony among the candidates the held-out data cannot tell from the best.
        let near: Vec<&&(usize, Vec<usize>, Cv, f64)> = sig
            .iter()
            .filter(|e| e.0 == best.0 || paired_t(&e.2, &best.2) < opts.t_tie)
            .collect();
        let pick = *near
            .iter()
            .min_by(|a, b| {
                (a.1.len(), a.2.rms)
                    .partial_cmp(&(b.1.len(), b.2.rms))
                    .unwrap_or(std::cmp::Ordering::Equal)
            })
            .expect("best is near itself");
        let pg = &groups[pick.0];
        let mut ties: Vec<Tie> = near
            .iter()
            .filter(|e| e.0 != pick.0)
            .filter(|e| {
                let g = &groups[e.0];
                !generalises(g, pg) && !generalises(pg, g) && g.family() != pg.family()
            })
            .map(|e| Tie {
                members: vec![(groups[e.0].kind().into(), groups[e.0].axis_label())],
                heldout_rms_um: Some(e.2.rms),
                reason: "score",
            })
            .collect();
        ties.sort_by_key(|a| a.label());
        ties.dedup_by(|a, b| a.label() == b.label());
        // Span ties: a group or pair of groups that reproduces the pick's fitted deviation.
        let beta = design.fit(&pick.1);
        let pcols = pg.col_set();
        let bvec: Vec<(usize, f64)> = pick
            .1
            .iter()
            .enumerate()
            .filter(|(_, j)| pcols.contains(j) && !current.contains(j))
            .map(|(k, &j)| (j, beta[k]))
            .collect();
        let p = design.p;
        let ff: f64 = bvec
            .iter()
            .flat_map(|&(i, bi)| bvec.iter().map(move |&(j, bj)| (i, j, bi * bj)))
            .map(|(i, j, w)| w * design.gt[i * p + j])
            .sum();
        let reproduces = |extra: &[usize]| -> bool {
            let s = union(&current, extra);
            if ff <= 0.0 || s.is_empty() {
                return false;
            }
            let a = DMatrix::from_fn(s.len(), s.len(), |i, j| design.gt[s[i] * p + s[j]]);
            let c = DVector::from_fn(s.len(), |i, _| {
                bvec.iter()
                    .map(|&(j, bj)| bj * design.gt[s[i] * p + j])
                    .sum()
            });
            let x = solve(a, c.clone());
            let resid = (ff - c.dot(&x)).max(0.0);
            (resid / ff).sqrt() < opts.span_tie
        };
        let others: Vec<usize> = (0..groups.len())
            .filter(|&gi| {
                gi != pick.0
                    && !chosen.contains(&gi)
                    && groups[gi].family() != pg.family()
                    && !generalises(&groups[gi], pg)
                    && !generalises(pg, &groups[gi])
                    && !groups[gi].col_set().iter().all(|j| current.contains(j))
            })
            .collect();
        let mut single_ties = Vec::new();
        for &gi in &others {
            if reproduces(&groups[gi].col_set()) {
                single_ties.push(gi);
            }
        }
        let label_of = |gi: usize| (groups[gi].kind().to_string(), groups[gi].axis_label());
        for &gi in &single_ties {
            let m = vec![label_of(gi)];
            if !ties.iter().any(|t| t.members == m) {
                ties.push(Tie {
                    members: m,
                    heldout_rms_um: None,
                    reason: "span",
                });
            }
        }
        for (x, &gi) in others.iter().enumerate() {
            for &gj in &others[x + 1..] {
                if single_ties.contains(&gi)
                    || single_ties.contains(&gj)
                    || groups[gi].family() == groups[gj].family()
                {
                    continue;
                }
                if reproduces(&union(&groups[gi].col_set(), &groups[gj].col_set())) {
                    ties.push(Tie {
                        members: vec![label_of(gi), label_of(gj)],
                        heldout_rms_um: None,
                        reason: "span",
                    });
                }
            }
        }
        used_families.push(pg.family());
        chosen.push(pick.0);
        current = pick.1.clone();
        cur_cv = pick.2.clone();
        steps.push((pick.2.rms, pick.3, ties));
    }

    // Final joint fit, residual, repeatability and lack of fit.
    let beta = design.fit(&current);
    let e = design.residual(&rows, &current, &beta);
    let cs = cell_stats(&rows, &e, current.len());
    let (sigma2, from_repeats) = if cs.df_pe >= 5.0 && cs.ss_pe > 0.0 {
        (cs.ss_pe / cs.df_pe, true)
    } else {
        (cur_cv.rms.powi(2).max(1e-18), false)
    };
    let sigma = sigma2.sqrt();
    let lof_before_z = chi2_z(cs0.ss_lof / sigma2, cs0.df_lof);
    let lof_z = chi2_z(cs.ss_lof / sigma2, cs.df_lof);
    let (where_before, _) = where_maps(samples, model, &rows, &rows.y, &cs0, sigma2, opts);
    let (where_after, time_z) = where_maps(samples, model, &rows, &e, &cs, sigma2, opts);
    let unexpl_rms = ((cs.ss_lof - cs.df_lof.max(0.0) * sigma2).max(0.0) / rows.n as f64).sqrt();
    let significant = lof_z > opts.z_unexplained || time_z > opts.z_unexplained;

    // Parameters: each column belongs to the first chosen group that has it.
    let mut owner: HashMap<usize, usize> = HashMap::new();
    for &gi in &chosen {
        for j in groups[gi].col_set() {
            owner.entry(j).or_insert(gi);
        }
    }
    let coef_of = |j: usize| -> f64 {
        current
            .iter()
            .position(|&c| c == j)
            .map(|k| beta[k] / design.scale[j])
            .unwrap_or(0.0)
    };
    let before = base_cv.rms;
    let mut updated = model.clone();
    let mut added = Vec::new();
    for (step, &gi) in chosen.iter().enumerate() {
        let g = &groups[gi];
        let c: Vec<f64> = g
            .cols
            .iter()
            .map(|cj| match cj {
                Some(j) if owner.get(j) == Some(&gi) => coef_of(*j),
                _ => 0.0,
            })
            .collect();
        let mut eff = Effect::new(g.axis, g.spec.kind(&c));
        eff.travel_um = g.travel_um;
        merge_into(&mut updated, &eff);
        let (rms, t, ties) = steps[step].clone();
        let denom = before * before - sigma2;
        let gap_closed = if denom > 1e-12 * before * before && denom > 0.0 {
            Some(((before * before - rms * rms) / denom).clamp(0.0, 1.0))
        } else {
            None
        };
        added.push(Added {
            kind: g.kind().into(),
            axis: g.axis_label(),
            effect: eff,
            heldout_rms_um: rms,
            gap_closed,
            t_stat: t,
            ties,
        });
    }
    Ok(Diagnosis {
        n_samples: samples.len(),
        n_runs: rows.n_runs,
        n_lines: rows.n_lines,
        sigma_um: sigma,
        sigma_from_repeats: from_repeats,
        heldout_rms_before_um: before,
        heldout_rms_after_um: cur_cv.rms,
        lack_of_fit_before_z: lof_before_z,
        added,
        where_: where_before,
        frequency: frequency_map(samples, model, &rows, &cs0, sigma2),
        other_axis: other_axis_map(samples, &rows, &cs0, sigma2),
        unexplained: Unexplained {
            significant,
            rms_um: if significant { unexpl_rms } else { 0.0 },
            lack_of_fit_z: lof_z,
            time_z,
            where_: if significant { where_after } else { Vec::new() },
            frequency: if significant {
                frequency_map(samples, model, &rows, &cs, sigma2)
            } else {
                Vec::new()
            },
        },
        model: updated,
        candidates: groups.iter().map(Group::label).collect::<Vec<_>>(),
    })
}

/// Adds a fitted effect to the model: into the existing effect of the same kind and axis (same
/// structure) when there is one, else as a new effect.
fn merge_into(model: &mut StageModel, add: &Effect) {
    use EffectKind as K;
    for e in model.effects.iter_mut() {
        if e.kind.name() != add.kind.name()
            || (!e.kind.is_global() && e.axis != add.axis)
            || e.travel_um != add.travel_um
        {
            continue;
        }
        let sum_vec = |a: &mut Vec<f64>, b: &[f64]| {
            if a.len() < b.len() {
                a.resize(b.len(), 0.0);
            }
            a.iter_mut().zip(b).for_each(|(x, y)| *x += y);
        };
        match (&mut e.kind, &add.kind) {
            (
                K::Scale { ppm, ref_um },
                K::Scale {
                    ppm: p2,
                    ref_um: r2,
                },
            ) if ref_um == r2 => {
                *ppm += p2;
                return;
            }
            (
                K::LeadscrewCyclic {
                    period_um,
                    cos_um,
                    sin_um,
                },
                K::LeadscrewCyclic {
                    period_um: p2,
                    cos_um: c2,
                    sin_um: s2,
                },
            )
            | (
                K::MotorCyclic {
                    period_um,
                    cos_um,
                    sin_um,
                },
                K::MotorCyclic {
                    period_um: p2,
                    cos_um: c2,
                    sin_um: s2,
                },
            ) if period_um == p2 => {
                sum_vec(cos_um, c2);
                sum_vec(sin_um, s2);
                return;
            }
            (K::Backlash { reversal_um }, K::Backlash { reversal_um: r2 }) => {
                *reversal_um += r2;
                return;
            }
            (K::Hysteresis { b0_um, b1_um }, K::Hysteresis { b0_um: a, b1_um: b }) => {
                *b0_um += a;
                *b1_um += b;
                return;
            }
            (K::Straightness { legendre_um }, K::Straightness { legendre_um: l2 }) => {
                sum_vec(legendre_um, l2);
                return;
            }
            (
                K::YawAbbe {
                    yaw_urad,
                    offset_um,
                },
                K::YawAbbe {
                    yaw_urad: y2,
                    offset_um: o2,
                },
            ) if offset_um == o2 => {
                yaw_urad[0] += y2[0];
                yaw_urad[1] += y2[1];
                return;
            }
            (K::Squareness { angle_urad }, K::Squareness { angle_urad: a })
            | (K::CameraRotation { angle_urad }, K::CameraRotation { angle_urad: a }) => {
                *angle_urad += a;
                return;
            }
            (K::CameraScale { ppm }, K::CameraScale { ppm: p2 }) => {
                *ppm += p2;
                return;
            }
            (
                K::ThermalDrift {
                    component,
                    amp_um,
                    tau_s,
                    rate_um_per_h,
                },
                K::ThermalDrift {
                    component: c2,
                    amp_um: a2,
                    tau_s: t2,
                    rate_um_per_h: r2,
                },
            ) if component == c2 && tau_s == t2 => {
                *amp_um += a2;
                *rate_um_per_h += r2;
                return;
            }
            _ => {}
        }
    }
    model.push(add.clone());
}

fn toml_to_json(v: &toml::Value) -> Json {
    match v {
        toml::Value::Float(f) => json!(f),
        toml::Value::Integer(i) => json!(i),
        toml::Value::String(s) => json!(s),
        toml::Value::Boolean(b) => json!(b),
        toml::Value::Array(a) => Json::Array(a.iter().map(toml_to_json).collect()),
        other => json!(other.to_string()),
    }
}

impl Where {
    pub fn to_json(&self) -> Json {
        let (from_um, to_um, from_s, to_s) = match self.map {
            "time" => (None, None, Some(self.from), Some(self.to)),
            _ => (Some(self.from), Some(self.to), None, None),
        };
        json!({
            "map": self.map,
            "axis": self.axis.map(|a| a.as_str()),
            "direction": self.direction,
            "component": self.component.map(|a| a.as_str()),
            "from_um": from_um,
            "to_um": to_um,
            "from_s": from_s,
            "to_s": to_s,
            "share": self.share,
            "z": self.z,
            "peak_um": self.peak_um,
        })
    }

    pub fn describe(&self) -> String {
        match self.map {
            "time" => format!(
                "time {:.0}..{:.0} s (share {:.0} %, peak {:.3} µm)",
                self.from,
                self.to,
                100.0 * self.share,
                self.peak_um
            ),
            _ => format!(
                "{} lines, {}, {} component, {:.0}..{:.0} µm (share {:.0} %, peak {:.3} µm)",
                self.axis.map(|a| a.as_str()).unwrap_or("-"),
                self.direction.unwrap_or("-"),
                self.component.map(|a| a.as_str()).unwrap_or("-"),
                self.from,
                self.to,
                100.0 * self.share,
                self.peak_um
            ),
        }
    }
}

impl Diagnosis {
    pub fn to_json(&self) -> Json {
        let added: Vec<Json> = self
            .added
            .iter()
            .map(|a| {
                let params: serde_json::Map<String, Json> = a
                    .effect
                    .params()
                    .iter()
                    .map(|(k, v)| (k.clone(), toml_to_json(v)))
                    .collect();
                json!({
                    "kind": a.kind,
                    "axis": a.axis,
                    "params": params,
                    "heldout_rms_um": a.heldout_rms_um,
                    "gap_closed": a.gap_closed,
                    "t_stat": if a.t_stat.is_finite() { a.t_stat } else { 1e9 },
                    "ties": a.ties.iter().map(|t| json!({
                        "label": t.label(),
                        "members": t.members.iter().map(|(k, ax)| json!({"kind": k, "axis": ax})).collect::<Vec<_>>(),
                        "heldout_rms_um": t.heldout_rms_um,
                        "reason": t.reason,
                    })).collect::<Vec<_>>(),
                })
            })
            .collect();
        json!({
            "n_samples": self.n_samples,
            "n_runs": self.n_runs,
            "n_lines": self.n_lines,
            "sigma_um": self.sigma_um,
            "sigma_from_repeats": self.sigma_from_repeats,
            "heldout_rms_before_um": self.heldout_rms_before_um,
            "heldout_rms_after_um": self.heldout_rms_after_um,
            "lack_of_fit_before_z": self.lack_of_fit_before_z,
            "added": added,
            "where": self.where_.iter().map(Where::to_json).collect::<Vec<_>>(),
            "frequency": self.frequency.iter().map(Peak::to_json).collect::<Vec<_>>(),
            "other_axis": self.other_axis.iter().map(OtherAxis::to_json).collect::<Vec<_>>(),
            "unexplained": {
                "significant": self.unexplained.significant,
                "rms_um": self.unexplained.rms_um,
                "lack_of_fit_z": self.unexplained.lack_of_fit_z,
                "time_z": self.unexplained.time_z,
                "where": self.unexplained.where_.iter().map(Where::to_json).collect::<Vec<_>>(),
                "frequency": self.unexplained.frequency.iter().map(Peak::to_json).collect::<Vec<_>>(),
            },
            "candidates": self.candidates,
        })
    }

    /// Human-readable report.
    pub fn summary(&self) -> String {
        use std::fmt::Write as _;
        let mut s = String::new();
        let _ = writeln!(
            s,
            "data: {} samples, {} runs, {} lines; repeatability σ = {:.4} µm{}",
            self.n_samples,
            self.n_runs,
            self.n_lines,
            self.sigma_um,
            if self.sigma_from_repeats {
                " (pure error over repeated runs)"
            } else {
                " (no repeats: from the held-out residual)"
            }
        );
        let _ = writeln!(
            s,
            "held-out RMS gap (leave-one-run-out): before {:.4} µm, after {:.4} µm",
            self.heldout_rms_before_um, self.heldout_rms_after_um
        );
        if self.where_.is_empty() {
            let _ = writeln!(
                s,
                "where: no interval significant against the repeatability"
            );
        } else {
            let _ = writeln!(
                s,
                "where (data - model, significant against repeatability):"
            );
            for w in &self.where_ {
                let _ = writeln!(s, "  {}", w.describe());
            }
        }
        for p in &self.frequency {
            let _ = writeln!(s, "  {}", p.describe());
        }
        if self.added.is_empty() {
            let _ = writeln!(
                s,
                "which: no effect improves the held-out fit significantly"
            );
        }
        for (i, a) in self.added.iter().enumerate() {
            let params: Vec<String> = a
                .effect
                .params()
                .iter()
                .map(|(k, v)| format!("{k} = {v}"))
                .collect();
            let _ = writeln!(
                s,
                "{}. {} {}: held-out RMS {:.4} µm, gap closed {} ({})",
                i + 1,
                a.kind,
                a.axis,
                a.heldout_rms_um,
                a.gap_closed
                    .map(|g| format!("{:.0} %", 100.0 * g))
                    .unwrap_or_else(|| "n/a".into()),
                params.join(", ")
            );
            if !a.ties.is_empty() {
                let t: Vec<String> = a
                    .ties
                    .iter()
                    .map(|t| format!("{} ({})", t.label(), t.reason))
                    .collect();
                let _ = writeln!(s, "   tie, the data cannot tell apart: {}", t.join("; "));
            }
        }
        if self.unexplained.significant {
            let _ = writeln!(
                s,
                "unexplained: structure remains that no library effect explains (RMS {:.4} µm, lack-of-fit z {:.1}, time z {:.1})",
                self.unexplained.rms_um, self.unexplained.lack_of_fit_z, self.unexplained.time_z
            );
            for w in &self.unexplained.where_ {
                let _ = writeln!(s, "  {}", w.describe());
            }
            for p in &self.unexplained.frequency {
                let _ = writeln!(s, "  {}", p.describe());
            }
        } else {
            let _ = writeln!(
                s,
                "unexplained: nothing significant remains (lack-of-fit z {:.1}, time z {:.1})",
                self.unexplained.lack_of_fit_z, self.unexplained.time_z
            );
        }
        s
    }
}

/// RMS of data - model with every line's constant offsets refit (the contract's nuisance), over
/// the same degrees of freedom as the held-out RMS: how far a model is from a campaign it was not
/// fitted on.
pub fn residual_rms_um(model: &StageModel, samples: &[Sample]) -> f64 {
    let rows = Rows::build(samples, model);
    let ss: f64 = rows.y.iter().map(|v| v * v).sum();
    (ss / (rows.n - rows.n_lc).max(1) as f64).sqrt()
}

#[cfg(test)]
mod tests {
    use super::data::{simulate_campaign, CampaignSpec};
    use super::*;
    use csmetro_sim::model::Component;

    fn base() -> StageModel {
        StageModel::default()
            .with(Effect::new(
                AxisId::X,
                EffectKind::LeadscrewCyclic {
                    period_um: 400.0,
                    cos_um: vec![0.4],
                    sin_um: vec![0.2],
                },
            ))
            .with(Effect::new(
                AxisId::X,
                EffectKind::Backlash { reversal_um: 1.5 },
            ))
    }

    fn spec(seed: u64) -> CampaignSpec {
        CampaignSpec {
            runs: 4,
            targets_per_line: 30,
            noise_um: Some(0.05),
            seed,
            ..Default::default()
        }
    }

    #[test]
    fn withheld_backlash_is_found_with_its_reversal_and_the_model_merges_it() {
        // The real stage's y backlash is 1.6 µm; the simulator's model says 1.0 µm.
        let mut diagnosed = base();
        diagnosed.push(Effect::new(
            AxisId::Y,
            EffectKind::Backlash { reversal_um: 1.0 },
        ));
        let truth_total = {
            let mut t = base();
            t.push(Effect::new(
                AxisId::Y,
                EffectKind::Backlash { reversal_um: 1.6 },
            ));
            t
        };
        let data = simulate_campaign(&truth_total, &spec(11), None);
        let d = diagnose(&diagnosed, &data, &Options::default()).unwrap();
        assert_eq!(d.added.len(), 1, "{}", d.summary());
        let a = &d.added[0];
        assert_eq!((a.kind.as_str(), a.axis.as_str()), ("backlash", "y"));
        let EffectKind::Backlash { reversal_um } = a.effect.kind else {
            panic!("not a backlash")
        };
        assert!((reversal_um - 0.6).abs() < 0.02, "reversal {reversal_um}");
        // Merged into the model's own backlash of y: 1.0 + 0.6.
        let merged: Vec<f64> = d
            .model
            .effects
            .iter()
            .filter_map(|e| match e.kind {
                EffectKind::Backlash { reversal_um } if e.axis == AxisId::Y => Some(reversal_um),
                _ => None,
            })
            .collect();
        assert_eq!(merged.len(), 1);
        assert!((merged[0] - 1.6).abs() < 0.02, "{merged:?}");
        assert!(d.heldout_rms_after_um < 0.6 * d.heldout_rms_before_um);
        assert!(
            (d.heldout_rms_after_um - 0.05).abs() < 0.01,
            "{}",
            d.heldout_rms_after_um
        );
        assert!((d.sigma_um - 0.05).abs() < 0.005, "σ {}", d.sigma_um);
        assert!(a.gap_closed.unwrap() > 0.9);
        assert!(!d.unexplained.significant);
        // Where: the y lines, y component, both directions.
        assert!(d
            .where_
            .iter()
            .take(2)
            .all(|w| w.axis == Some(AxisId::Y) && w.component == Some(AxisId::Y)));
    }

    #[test]
    fn no_gap_adds_nothing_even_with_large_line_offsets() {
        for seed in 0..4 {
            let data = simulate_campaign(
                &base(),
                &CampaignSpec {
                    line_offset_um: 50.0,
                    ..spec(100 + seed)
                },
                None,
            );
            let d = diagnose(&base(), &data, &Options::default()).unwrap();
            assert!(d.added.is_empty(), "seed {seed}: {}", d.summary());
            assert!(!d.unexplained.significant, "seed {seed}: {}", d.summary());
            assert!(d.where_.is_empty(), "seed {seed}: {:?}", d.where_);
            assert!(d.frequency.is_empty(), "seed {seed}: {:?}", d.frequency);
            assert!((d.heldout_rms_before_um / 0.05 - 1.0).abs() < 0.1);
        }
    }

    #[test]
    fn camera_scale_is_a_tie_with_the_two_axis_scales() {
        let truth = base().with(Effect::new(
            AxisId::X,
            EffectKind::CameraScale { ppm: 30.0 },
        ));
        let d = diagnose(
            &base(),
            &simulate_campaign(&truth, &spec(5), None),
            &Options::default(),
        )
        .unwrap();
        let a = &d.added[0];
        assert_eq!(a.kind, "camera_scale", "{}", d.summary());
        assert!(
            a.ties.iter().any(|t| t.label() == "scale x + scale y"),
            "{}",
            d.summary()
        );
        let EffectKind::CameraScale { ppm } = a.effect.kind else {
            panic!()
        };
        assert!((ppm - 30.0).abs() < 1.0, "{ppm}");
    }

    #[test]
    fn a_local_defect_is_unexplained_and_located_not_misattributed() {
        let truth = base().with(Effect::new(
            AxisId::X,
            EffectKind::Defect {
                component: Component::Axis,
                center_um: 6000.0,
                height_um: 0.4,
                sigma_um: 120.0,
            },
        ));
        let d = diagnose(
            &base(),
            &simulate_campaign(&truth, &spec(8), None),
            &Options::default(),
        )
        .unwrap();
        assert!(d.added.is_empty(), "{}", d.summary());
        assert!(d.unexplained.significant);
        let w = &d.unexplained.where_[0];
        assert_eq!((w.axis, w.component), (Some(AxisId::X), Some(AxisId::X)));
        // Located to within one position bin (9500/24 µm) of the defect's centre.
        let bin = 9500.0 / 24.0;
        assert!(
            w.from - bin <= 6000.0 && 6000.0 <= w.to + bin,
            "{:#?}",
            d.unexplained.where_
        );
        assert!(w.to - w.from < 2000.0, "{w:?}");
    }

    #[test]
    fn restricted_kinds_leave_position_dependent_backlash_unexplained() {
        let truth = base().with(Effect::new(
            AxisId::Y,
            EffectKind::Hysteresis {
                b0_um: 0.5,
                b1_um: 0.5,
            },
        ));
        let data = simulate_campaign(&truth, &spec(9), None);
        let all = diagnose(&base(), &data, &Options::default()).unwrap();
        assert_eq!(all.added[0].kind, "hysteresis", "{}", all.summary());
        assert!(!all.unexplained.significant, "{}", all.summary());
        let only_backlash = Options {
            kinds: Some(vec!["backlash".into()]),
            ..Default::default()
        };
        let d = diagnose(&base(), &data, &only_backlash).unwrap();
        assert_eq!(d.added.len(), 1);
        assert_eq!(
            (d.added[0].kind.as_str(), d.added[0].axis.as_str()),
            ("backlash", "y")
        );
        assert!(d.unexplained.significant, "{}", d.summary());
        assert!(d.unexplained.rms_um > 0.05);
    }

    #[test]
    fn a_periodic_error_of_unknown_period_is_unexplained_with_its_period() {
        let truth = base().with(Effect::new(
            AxisId::Y,
            EffectKind::Harmonic {
                component: Component::Axis,
                period_um: 700.0,
                cos_um: vec![0.12],
                sin_um: vec![0.05],
            },
        ));
        let d = diagnose(
            &base(),
            &simulate_campaign(&truth, &spec(12), None),
            &Options::default(),
        )
        .unwrap();
        assert!(d.added.is_empty(), "{}", d.summary());
        assert!(d.unexplained.significant);
        let p = &d.unexplained.frequency[0];
        assert_eq!((p.axis, p.component), (AxisId::Y, AxisId::Y));
        assert!((p.period_um - 700.0).abs() < 5.0, "{p:?}");
        assert!((p.amplitude_um - 0.13).abs() < 0.02, "{p:?}");
    }

    #[test]
    fn bad_inputs_are_refused() {
        let one_run = simulate_campaign(&base(), &CampaignSpec { runs: 1, ..spec(1) }, None);
        let e = diagnose(&base(), &one_run, &Options::default()).unwrap_err();
        assert!(e.0.contains("single run"), "{e}");
        let two = simulate_campaign(&base(), &spec(1), None);
        let o = Options {
            kinds: Some(vec!["warp".into()]),
            ..Default::default()
        };
        let e = diagnose(&base(), &two, &o).unwrap_err();
        assert!(e.0.contains("unknown candidate kind `warp`"), "{e}");
    }
}
