//! The physics model of a stacked XY stage, fitted by penalised least squares.
//!
//! Each component c ∈ {e_x, e_y, θ} is modelled as
//!     c(x, y) = F(x) + G(y) + ŷ·H(x) + x̂·K(y) + Σ_ω env_ω(x)·(cos, sin)(ωx) + ŷ·(…)
//!                                              + Σ_ω env_ω(y)·(cos, sin)(ωy) + x̂·(…),
//! F and G the errors along each axis's own travel (trends, the other axis's straightness),
//! ŷ·H(x) and x̂·K(y) the couplings linear in the other coordinate (squareness, yaw times an Abbe
//! offset that changes with the other axis), x̂, ŷ ∈ [-1, 1] the centred coordinates. The ω are the
//! leadscrew periods (and their 2nd and 3rd harmonics) found in the samples themselves: the
//! samples' mean at each x (resp. y) grid position, where the other axis's errors average out,
//! goes through the 1D period search of `recon::periods`. Each period's sine and cosine carry a
//! slowly varying cubic-spline envelope (the nut's cyclic amplitude drifts along the travel), and
//! the fundamental's also appears times the other coordinate (cyclic yaw times its Abbe arm).
//! F, G are uniform cubic B-splines at knot spacing h (chosen by cross-validation), H, K at 4h:
//! the smooth residual. The unknowns are O(nx + ny): the normal matrix is assembled from the
//! samples (4 basis values per family per sample) and factored once per candidate, and the map is
//! evaluated separably, so a 1901 × 841 grid never forms an nx·ny matrix.
use faer::linalg::solvers::SolveCore;
use faer::{Conj, Mat, Side};

use super::{folds, rms_xy, Candidate, Grid2, Map, MapSamples, CV_FOLDS};
use crate::recon::periods::{self, Period};

/// Most unknowns of one fit: a dense Cholesky of 1200 is ~0.6 GFLOP, and the cross-validation
/// factors ~6 per candidate within the 10 s budget of a 1.6 M-point map.
const MAX_UNKNOWNS: usize = 1200;
/// Knot spacings cross-validated: at most this many, spread over the feasible ones.
const MAX_KNOT_CANDIDATES: usize = 8;
/// Curvature penalty weights tried by cross-validation, relative to the mean diagonal of AᵀA.
const PENALTIES: [f64; 2] = [1e-4, 1e-1];
/// Ridge on every coefficient, relative to the mean diagonal: it only settles the constants and
/// linear terms the blocks share (F and G both hold a constant, for example).
const RIDGE: f64 = 1e-9;
/// Distinct periods kept per axis (the strongest), each with its harmonics.
const MAX_PERIODS_PER_AXIS: usize = 3;
/// Harmonics modelled per period (1 = the fundamental alone).
const HARMONICS: usize = 3;
/// A harmonic is modelled only if its period spans at least this many grid steps.
const MIN_STEPS_PER_PERIOD: f64 = 3.0;
/// Intervals of a cyclic term's envelope spline over the travel (a slow amplitude drift).
const ENV_INTERVALS: f64 = 6.0;

/// Uniform cubic B-spline basis on [a, a + k·h].
#[derive(Debug, Clone, Copy)]
struct Spline {
    a: f64,
    h: f64,
    k: usize,
}

impl Spline {
    fn new(a: f64, b: f64, h: f64) -> Self {
        let k = (((b - a) / h).ceil() as usize).max(1);
        Self { a, h, k }
    }
    fn count(&self) -> usize {
        self.k + 3
    }
    /// First basis index and the 4 nonzero basis values at x.
    fn eval(&self, x: f64) -> (usize, [f64; 4]) {
        let t = ((x - self.a) / self.h).clamp(0.0, self.k as f64);
        let i = (t.floor() as usize).min(self.k - 1);
        let f = t - i as f64;
        let g = 1.0 - f;
        (
            i,
            [
                g * g * g / 6.0,
                (3.0 * f * f * f - 6.0 * f * f + 4.0) / 6.0,
                (-3.0 * f * f * f + 3.0 * f * f + 3.0 * f + 1.0) / 6.0,
                f * f * f / 6.0,
            ],
        )
    }
}

/// One family of basis functions: a spline along one axis, optionally modulated by cos/sin(ω·t),
/// optionally times the other coordinate (centred, in [-1, 1]).
#[derive(Debug, Clone, Copy)]
struct Family {
    along_x: bool,
    coupled: bool,
    sp: Spline,
    /// (ω rad/µm, sine?)
    wave: Option<(f64, bool)>,
}

impl Family {
    /// The 4 (first index, values) of the family at coordinate t along its axis, before coupling.
    fn eval(&self, t: f64) -> (usize, [f64; 4]) {
        let (i, mut v) = self.sp.eval(t);
        if let Some((w, sine)) = self.wave {
            let m = if sine { (w * t).sin() } else { (w * t).cos() };
            for b in &mut v {
                *b *= m;
            }
        }
        (i, v)
    }
}

/// Angular frequencies (rad/µm) of the cyclic terms along each axis, fundamentals first.
#[derive(Debug, Clone, Default)]
struct Waves {
    x: Vec<(f64, bool)>,
    y: Vec<(f64, bool)>,
}

/// The model's families and offsets for one knot spacing.
#[derive(Debug, Clone)]
struct Design {
    fams: Vec<Family>,
    offs: Vec<usize>,
    x_mid: f64,
    x_half: f64,
    y_mid: f64,
    y_half: f64,
}

impl Design {
    fn new(g: &Grid2, h: f64, waves: &Waves) -> Self {
        let (x0, x1) = (g.x.start_um, g.x.end_um());
        let (y0, y1) = (g.y.start_um, g.y.end_um());
        let fam = |along_x, coupled, sp, wave| Family {
            along_x,
            coupled,
            sp,
            wave,
        };
        let mut fams = vec![
            fam(true, false, Spline::new(x0, x1, h), None),
            fam(false, false, Spline::new(y0, y1, h), None),
            fam(true, true, Spline::new(x0, x1, 4.0 * h), None),
            fam(false, true, Spline::new(y0, y1, 4.0 * h), None),
        ];
        for (along_x, ws, a, b) in [(true, &waves.x, x0, x1), (false, &waves.y, y0, y1)] {
            let env = Spline::new(a, b, ((b - a) / ENV_INTERVALS).max(1e-9));
            // The coupled (yaw × Abbe) term: a cubic amplitude over the travel.
            let one = Spline::new(a, b, (b - a).max(1e-9));
            for &(w, fundamental) in ws {
                for sine in [false, true] {
                    fams.push(fam(along_x, false, env, Some((w, sine))));
                    if fundamental {
                        fams.push(fam(along_x, true, one, Some((w, sine))));
                    }
                }
            }
        }
        let mut offs = vec![0];
        for f in &fams {
            offs.push(offs[offs.len() - 1] + f.sp.count());
        }
        Self {
            fams,
            offs,
            x_mid: 0.5 * (x0 + x1),
            x_half: (0.5 * (x1 - x0)).max(1e-9),
            y_mid: 0.5 * (y0 + y1),
            y_half: (0.5 * (y1 - y0)).max(1e-9),
        }
    }
    fn unknowns(&self) -> usize {
        self.offs[self.offs.len() - 1]
    }
    /// Nonzeros of every design row.
    fn nnz(&self) -> usize {
        4 * self.fams.len()
    }
    /// The design row at (x, y): [`Design::nnz`] (column, value) entries written to `out`.
    fn row(&self, x: f64, y: f64, out: &mut [(usize, f64)]) {
        let xh = (x - self.x_mid) / self.x_half;
        let yh = (y - self.y_mid) / self.y_half;
        for (b, f) in self.fams.iter().enumerate() {
            let (at, other) = if f.along_x { (x, yh) } else { (y, xh) };
            let scale = if f.coupled { other } else { 1.0 };
            let (i, v) = f.eval(at);
            for q in 0..4 {
                out[4 * b + q] = (self.offs[b] + i + q, v[q] * scale);
            }
        }
    }
    /// Second-difference penalty DᵀD of every family (no penalty across families).
    fn add_penalty(&self, n: &mut Mat<f64>, mu: f64) {
        for b in 0..self.fams.len() {
            for s in self.offs[b]..self.offs[b + 1].saturating_sub(2) {
                let d = [(s, 1.0), (s + 1, -2.0), (s + 2, 1.0)];
                for &(i, a) in &d {
                    for &(j, c) in &d {
                        n[(i, j)] += mu * a * c;
                    }
                }
            }
        }
    }
}

/// Normal equations AᵀA (lower triangle, column-major p × p) and AᵀB (p × nc) of a set of samples.
#[derive(Clone)]
struct Normal {
    p: usize,
    ata: Vec<f64>,
    atb: Vec<f64>,
}

impl Normal {
    fn new(p: usize, nc: usize) -> Self {
        Self {
            p,
            ata: vec![0.0; p * p],
            atb: vec![0.0; p * nc],
        }
    }
    /// Adds one sample's row: 4 consecutive columns per family, so the outer product goes in
    /// 4 × 4 blocks (the lower triangle of AᵀA holds the block (b, b') for b' ≤ b by column).
    fn add(&mut self, row: &[(usize, f64)], vals: &[f64]) {
        let p = self.p;
        for (bi, bl) in row.chunks_exact(4).enumerate() {
            let i0 = bl[0].0;
            let a = [bl[0].1, bl[1].1, bl[2].1, bl[3].1];
            for br in row[..4 * (bi + 1)].chunks_exact(4) {
                let j0 = br[0].0;
                for (q, &(_, b)) in br.iter().enumerate() {
                    let col = &mut self.ata[(j0 + q) * p + i0..(j0 + q) * p + i0 + 4];
                    for (t, (c, &av)) in col.iter_mut().zip(&a).enumerate() {
                        // Within a family's own block, only the lower triangle (i ≥ j).
                        if i0 + t >= j0 + q {
                            *c += av * b;
                        }
                    }
                }
            }
            for (c, v) in vals.iter().enumerate() {
                for (t, &av) in a.iter().enumerate() {
                    self.atb[c * p + i0 + t] += av * v;
                }
            }
        }
    }
    fn add_all(&mut self, o: &Normal, sign: f64) {
        for (a, b) in self.ata.iter_mut().zip(&o.ata) {
            *a += sign * b;
        }
        for (a, b) in self.atb.iter_mut().zip(&o.atb) {
            *a += sign * b;
        }
    }
}

/// Solves (AᵀA + penalty) X = AᵀB; None if the matrix is not positive definite.
fn solve(d: &Design, nm: &Normal, mu_rel: f64) -> Option<Mat<f64>> {
    let p = nm.p;
    let nc = nm.atb.len() / p.max(1);
    let mean_diag = (0..p).map(|i| nm.ata[i * p + i]).sum::<f64>() / p as f64;
    let scale = if mean_diag > 0.0 { mean_diag } else { 1.0 };
    let mut n = Mat::from_fn(p, p, |i, j| if i >= j { nm.ata[j * p + i] } else { 0.0 });
    d.add_penalty(&mut n, mu_rel * scale);
    for i in 0..p {
        n[(i, i)] += RIDGE * scale;
    }
    let llt = n.llt(Side::Lower).ok()?;
    let mut x = Mat::from_fn(p, nc, |i, c| nm.atb[c * p + i]);
    llt.solve_in_place_with_conj(Conj::No, x.as_mut());
    let finite = (0..x.ncols()).all(|c| (0..x.nrows()).all(|i| x[(i, c)].is_finite()));
    finite.then_some(x)
}

/// Random probes of the Hutchinson estimates in [`PhysicsFit::noise_reference`]: a bin of the
/// band sums a few hundred samples' diagonals, whose estimation error then is well under 1 %.
const HAT_PROBES: usize = 32;
/// Nearest other samples whose in-sample residuals a sample's noise proxy is taken against.
const NOISE_NEIGHBOURS: usize = 4;
/// Fewest close pairs the noise proxies are checked against (see [`PhysicsFit::noise_reference`]).
const PAIRS_MIN: usize = 30;
/// Their largest distance, in grid steps (the 5, 7.1 and 10 µm neighbours on a 5 µm grid: ~70
/// pairs at 0.5 % of 801 × 601, ~1,100 at 2 %). Within 1.5 steps (5 and 7.1 µm) the pairs were
/// two thirds as many, and a chance deficit of 0.39 on 37 of them widened one component of the
/// second surface of reconstruct2d_rough.rs to sharpness 3.08.
const PAIR_LAG_STEPS: f64 = 2.05;

/// What the fit knows about the sensor noise at each sample, for the pointwise band. With
/// y = f + ε (noise variance σ²) and H the fit's hat matrix, the in-sample residual is
/// (I − H)ε plus the fit's bias, and the bias is where the map is wrong: taken as noise it
/// removes the very error the band is for (a bump the model cannot hold, 0.1 µm high, zeroed
/// the band there: coverage 0.48 on tests/system/reconstruct2d_rough.rs's second surface). The
/// bias is smooth over the few tens of µm between neighbouring samples, the noise is not: each
/// sample's proxy is its residual less the mean residual of its nearest samples, which keeps its
/// own noise draw (the held-out residual carries the same one) and cancels most of the bias.
#[derive(Debug, Clone)]
pub struct NoiseReference {
    /// The noise proxy of e_x and e_y per sample (µm), `noise[c][k]`: r_k − mean of r_j over its
    /// [`NOISE_NEIGHBOURS`] nearest samples j, r the in-sample residual.
    pub noise: Vec<Vec<f64>>,
    /// The proxy's expected square over σ² (from M = (I − H)²: M_kk − 2 mean_j M_kj +
    /// mean_jl M_jl).
    pub noise_var: Vec<f64>,
    /// (H²)_kk per sample: the fit's noise-induced variance over σ².
    pub fit_var: Vec<f64>,
}

/// The `k` nearest other points of every point (µm), by a bucket grid of about 2 points per cell
/// searched ring by ring (linear in the points, where all pairs would be 10⁹ at 2 % of a 1.6 M
/// map).
fn nearest_neighbours(pts: &[(f64, f64)], k: usize) -> Vec<Vec<usize>> {
    let m = pts.len();
    let k = k.min(m.saturating_sub(1));
    if k == 0 {
        return vec![Vec::new(); m];
    }
    let (mut x0, mut x1, mut y0, mut y1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    for &(x, y) in pts {
        (x0, x1, y0, y1) = (x0.min(x), x1.max(x), y0.min(y), y1.max(y));
    }
    // At most 4096 cells a side (samples on a line would otherwise ask for millions); the cells
    // stay square, which the search's distance bound needs.
    let cell = ((x1 - x0).max(1e-9) * (y1 - y0).max(1e-9) * 2.0 / m as f64)
        .sqrt()
        .max((x1 - x0).max(y1 - y0) / 4096.0)
        .max(1e-9);
    let nx = ((x1 - x0) / cell) as usize + 1;
    let ny = ((y1 - y0) / cell) as usize + 1;
    let cx = |x: f64| (((x - x0) / cell) as usize).min(nx - 1);
    let cy = |y: f64| (((y - y0) / cell) as usize).min(ny - 1);
    let mut bucket = vec![Vec::new(); nx * ny];
    for (i, &(x, y)) in pts.iter().enumerate() {
        bucket[cy(y) * nx + cx(x)].push(i);
    }
    pts.iter()
        .enumerate()
        .map(|(i, &(x, y))| {
            let (ci, cj) = (cx(x) as i64, cy(y) as i64);
            let mut best: Vec<(f64, usize)> = Vec::with_capacity(k + 1);
            for ring in 0i64.. {
                // Every point of ring r + 1 or beyond is at least r cells away.
                if best.len() == k
                    && best[k - 1].0 <= (ring as f64 - 1.0).max(0.0).powi(2) * cell * cell
                {
                    break;
                }
                if ring > nx.max(ny) as i64 {
                    break;
                }
                for dj in -ring..=ring {
                    for di in -ring..=ring {
                        if di.abs() != ring && dj.abs() != ring {
                            continue;
                        }
                        let (a, b) = (ci + di, cj + dj);
                        if a < 0 || b < 0 || a >= nx as i64 || b >= ny as i64 {
                            continue;
                        }
                        for &j in &bucket[b as usize * nx + a as usize] {
                            if j == i {
                                continue;
                            }
                            let d2 = (pts[j].0 - x).powi(2) + (pts[j].1 - y).powi(2);
                            if best.len() < k || d2 < best[k - 1].0 {
                                let at = best.partition_point(|b| b.0 <= d2);
                                best.insert(at, (d2, j));
                                best.truncate(k);
                            }
                        }
                    }
                }
            }
            best.into_iter().map(|b| b.1).collect()
        })
        .collect()
}

/// A fitted physics model.
#[derive(Debug, Clone)]
pub struct PhysicsFit {
    design: Design,
    coef: Mat<f64>,
    pub knot_um: f64,
    pub penalty: f64,
    pub cv_error_um: f64,
    /// The cyclic periods found along x and along y (fundamentals; their harmonics are modelled).
    pub periods_x: Vec<Period>,
    pub periods_y: Vec<Period>,
    /// Each axis's roughness below the knot spacing: a shrunk per-column (x) offset of e_x and
    /// per-row (y) offset of e_y, µm (see [`axis_roughness`]).
    rough_x: Vec<f64>,
    rough_y: Vec<f64>,
}

/// The residual's part that depends on one grid coordinate only (an axis's roughness, correlated
/// over a few µm: finer than any knot spacing the samples carry): per grid line `i` of `idx`, the
/// mean residual shrunk by empirical Bayes, n·τ² / (n·τ² + σ²), with σ² the within-line variance
/// and τ² the between-line variance beyond it. Without such structure τ² ≈ 0 and nothing is
/// added; with a few samples per line (a map samples 0.5–2 % of 1.6 M points: ~4–17 per column)
/// it recovers what a spline at 10 µm knots cannot.
fn axis_roughness(n: usize, idx: &[usize], resid: &[f64]) -> Vec<f64> {
    let mut sum = vec![0.0; n];
    let mut cnt = vec![0usize; n];
    for (&i, &r) in idx.iter().zip(resid) {
        sum[i] += r;
        cnt[i] += 1;
    }
    let mean: Vec<f64> = (0..n)
        .map(|i| {
            if cnt[i] > 0 {
                sum[i] / cnt[i] as f64
            } else {
                0.0
            }
        })
        .collect();
    let (mut ss, mut dof) = (0.0, 0usize);
    for (&i, &r) in idx.iter().zip(resid) {
        ss += (r - mean[i]).powi(2);
    }
    for &c in &cnt {
        dof += c.saturating_sub(1);
    }
    let lines: Vec<usize> = (0..n).filter(|&i| cnt[i] > 0).collect();
    if dof == 0 || lines.is_empty() {
        return vec![0.0; n];
    }
    let sigma2 = ss / dof as f64;
    let tau2 = (lines
        .iter()
        .map(|&i| mean[i].powi(2) - sigma2 / cnt[i] as f64)
        .sum::<f64>()
        / lines.len() as f64)
        .max(0.0);
    if tau2 <= 0.0 || !tau2.is_finite() {
        return vec![0.0; n];
    }
    (0..n)
        .map(|i| {
            let nt = cnt[i] as f64 * tau2;
            if cnt[i] == 0 {
                0.0
            } else {
                nt / (nt + sigma2) * mean[i]
            }
        })
        .collect()
}

fn positions(g: &Grid2, s: &MapSamples, k: usize) -> (f64, f64) {
    (g.x.position(s.ix[k]), g.y.position(s.iy[k]))
}

/// Knot spacings tried: multiples of the coarser grid step with fewer unknowns than a third of
/// the samples (and at most [`MAX_UNKNOWNS`]); at most [`MAX_KNOT_CANDIDATES`], the finest and
/// the coarsest among them.
fn knot_candidates(g: &Grid2, m: usize, waves: &Waves) -> Vec<f64> {
    let step = g.x.step_um.max(g.y.step_um);
    let feasible: Vec<f64> = [
        1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 8.0, 10.0, 12.0, 16.0, 24.0, 32.0, 48.0, 64.0, 96.0, 128.0,
        192.0, 256.0,
    ]
    .iter()
    .map(|k| k * step)
    .filter(|&h| {
        let p = Design::new(g, h, waves).unknowns();
        3 * p <= m && p <= MAX_UNKNOWNS
    })
    .collect();
    let n = feasible.len();
    if n <= MAX_KNOT_CANDIDATES {
        return feasible;
    }
    let last = MAX_KNOT_CANDIDATES - 1;
    let mut out: Vec<f64> = (0..MAX_KNOT_CANDIDATES)
        .map(|k| feasible[(k * (n - 1) + last / 2) / last])
        .collect();
    out.dedup();
    out
}

/// Held-out RMS error of e_x and e_y at knot spacing h and penalty mu; None if singular.
fn cv_error(
    g: &Grid2,
    s: &MapSamples,
    comps: &[&[f64]],
    fold: &[usize],
    d: &Design,
    mu: f64,
) -> Option<f64> {
    cv_predictions(g, s, comps, fold, d, mu).map(|pred| rms_xy(s, &pred))
}

/// Held-out predictions of e_x and e_y at every sample (`pred[c][k]`, sample k predicted by the
/// fold that left it out); None if singular.
fn cv_predictions(
    g: &Grid2,
    s: &MapSamples,
    comps: &[&[f64]],
    fold: &[usize],
    d: &Design,
    mu: f64,
) -> Option<Vec<Vec<f64>>> {
    let m = s.len();
    let nc = comps.len();
    let p = d.unknowns();
    let r = d.nnz();
    let mut parts: Vec<Normal> = (0..CV_FOLDS).map(|_| Normal::new(p, nc)).collect();
    let mut rows = vec![(0usize, 0.0f64); m * r];
    let mut vals = vec![0.0; nc];
    for (k, row) in rows.chunks_exact_mut(r).enumerate() {
        let (x, y) = positions(g, s, k);
        d.row(x, y, row);
        for (c, comp) in comps.iter().enumerate() {
            vals[c] = comp[k];
        }
        parts[fold[k]].add(row, &vals);
    }
    let mut all = Normal::new(p, nc);
    for part in &parts {
        all.add_all(part, 1.0);
    }
    let mut pred = vec![vec![0.0; m]; 2];
    for (f, part) in parts.iter().enumerate() {
        let mut train = all.clone();
        train.add_all(part, -1.0);
        let x = solve(d, &train, mu)?;
        for k in (0..m).filter(|&k| fold[k] == f) {
            for (c, pc) in pred.iter_mut().enumerate() {
                pc[k] = rows[k * r..(k + 1) * r]
                    .iter()
                    .map(|&(i, a)| a * x[(i, c)])
                    .sum();
            }
        }
    }
    Some(pred)
}

/// `f` over `items` on up to 2 threads (the target machine's cores), results in order.
fn par_map<T: Sync, R: Send>(items: &[T], f: impl Fn(&T) -> R + Sync) -> Vec<R> {
    let threads = std::thread::available_parallelism()
        .map_or(1, |n| n.get())
        .clamp(1, 2)
        .min(items.len().max(1));
    if threads <= 1 {
        return items.iter().map(&f).collect();
    }
    let f = &f;
    let mut out: Vec<Option<R>> = (0..items.len()).map(|_| None).collect();
    std::thread::scope(|sc| {
        let handles: Vec<_> = (0..threads)
            .map(|t| {
                sc.spawn(move || {
                    (t..items.len())
                        .step_by(threads)
                        .map(|k| (k, f(&items[k])))
                        .collect::<Vec<_>>()
                })
            })
            .collect();
        for h in handles {
            for (k, r) in h.join().expect("a cross-validation thread panicked") {
                out[k] = Some(r);
            }
        }
    });
    out.into_iter()
        .map(|r| r.expect("every item mapped"))
        .collect()
}

/// The cyclic periods along one axis: per grid position along it, the mean of the samples there
/// (the other axis's errors average out), e_x and e_y each through the 1D period search; the
/// strongest distinct ones, at most [`MAX_PERIODS_PER_AXIS`].
fn axis_periods(
    n: usize,
    pos: impl Fn(usize) -> f64,
    step: f64,
    idx: &[usize],
    comps: &[&[f64]],
) -> Vec<Period> {
    let span = (pos(n - 1) - pos(0)).abs().max(step);
    let mut all: Vec<Period> = Vec::new();
    for comp in comps.iter().take(2) {
        let mut sum = vec![0.0; n];
        let mut cnt = vec![0u32; n];
        for (&i, &v) in idx.iter().zip(comp.iter()) {
            sum[i] += v;
            cnt[i] += 1;
        }
        let (mut x, mut y) = (Vec::new(), Vec::new());
        for i in (0..n).filter(|&i| cnt[i] > 0) {
            x.push(pos(i));
            y.push(sum[i] / cnt[i] as f64);
        }
        all.extend(periods::detect(&x, &y, 2.0 * step));
    }
    all.sort_by(|a, b| b.amplitude_um.total_cmp(&a.amplitude_um));
    let mut kept: Vec<Period> = Vec::new();
    for p in all {
        // The same period seen in both components, or a harmonic of a kept one: already modelled.
        // Within 2 resolution cells (1/span) of a kept frequency or its harmonics: the same
        // period seen in the other component, a harmonic, or a sidelobe of the finite span
        // (±1.4 cells) or of the envelope, which the envelope splines carry (ENV_INTERVALS = 6:
        // 3 intervals per cycle of a 2-cell beat).
        let dup = kept.iter().any(|k| {
            (1..=HARMONICS).any(|h| (h as f64 / k.period_um - 1.0 / p.period_um).abs() < 2.0 / span)
        });
        if !dup && kept.len() < MAX_PERIODS_PER_AXIS {
            kept.push(p);
        }
    }
    kept
}

/// The angular frequencies of the periods and their harmonics that the grid resolves.
fn frequencies(ps: &[Period], step: f64) -> Vec<(f64, bool)> {
    let mut out = Vec::new();
    for p in ps {
        for k in 1..=HARMONICS {
            if p.period_um / k as f64 >= MIN_STEPS_PER_PERIOD * step {
                out.push((std::f64::consts::TAU * k as f64 / p.period_um, k == 1));
            }
        }
    }
    out
}

/// Finds the periods, fits every knot spacing and penalty, keeps the smallest k-fold CV error,
/// refits on all samples.
pub fn select(g: &Grid2, s: &MapSamples) -> Result<(PhysicsFit, Vec<Candidate>), String> {
    let m = s.len();
    let comps = s.components();
    let nc = comps.len();
    let periods_x = axis_periods(g.x.n, |i| g.x.position(i), g.x.step_um, &s.ix, &comps);
    let periods_y = axis_periods(g.y.n, |i| g.y.position(i), g.y.step_um, &s.iy, &comps);
    let mut waves = Waves {
        x: frequencies(&periods_x, g.x.step_um),
        y: frequencies(&periods_y, g.y.step_um),
    };
    let mut knots = knot_candidates(g, m, &waves);
    if knots.is_empty() {
        // Too few samples for the cyclic terms: the smooth model alone.
        waves = Waves::default();
        knots = knot_candidates(g, m, &waves);
    }
    if knots.is_empty() {
        // Too few samples for any spline at the grid's scale: the coarsest one (one interval per
        // axis, 4 + 4 + 4 + 4 unknowns) still needs a few times that many samples.
        let h = (g.x.end_um() - g.x.start_um).max(g.y.end_um() - g.y.start_um);
        let need = 3 * Design::new(g, h, &waves).unknowns();
        if need > m {
            return Err(format!(
                "the physics model needs at least {need} samples, found {m}"
            ));
        }
        knots.push(h);
    }
    let fold = folds(m, CV_FOLDS);
    // Every knot spacing at the lightest penalty, then the other penalties at the best spacing.
    let mut best: Option<(f64, f64, f64)> = None; // (cv, h, mu)
    let mut candidates = Vec::new();
    let cvs = par_map(&knots, |&h| {
        cv_error(
            g,
            s,
            &comps,
            &fold,
            &Design::new(g, h, &waves),
            PENALTIES[0],
        )
    });
    for (&h, cv) in knots.iter().zip(cvs) {
        candidates.push(Candidate {
            method: "physics",
            knot_um: Some(h),
            cv_error_um: cv.unwrap_or(f64::NAN),
            folds: CV_FOLDS,
        });
        if let Some(cv) = cv {
            if best.is_none_or(|b| cv < b.0) {
                best = Some((cv, h, PENALTIES[0]));
            }
        }
    }
    if let Some((_, h, _)) = best {
        let d = Design::new(g, h, &waves);
        for &mu in &PENALTIES[1..] {
            if let Some(cv) = cv_error(g, s, &comps, &fold, &d, mu) {
                if best.is_none_or(|b| cv < b.0) {
                    best = Some((cv, h, mu));
                }
            }
        }
    }
    let (cv, h, mu) = best.ok_or("the physics model's normal equations are singular")?;
    let d = Design::new(g, h, &waves);
    let mut all = Normal::new(d.unknowns(), nc);
    let mut vals = vec![0.0; nc];
    let mut row = vec![(0usize, 0.0f64); d.nnz()];
    for k in 0..m {
        let (x, y) = positions(g, s, k);
        for (c, comp) in comps.iter().enumerate() {
            vals[c] = comp[k];
        }
        d.row(x, y, &mut row);
        all.add(&row, &vals);
    }
    let coef = solve(&d, &all, mu).ok_or("the physics model's normal equations are singular")?;
    // The residual at the samples, for each axis's roughness along its own travel.
    let (mut res_x, mut res_y) = (Vec::with_capacity(m), Vec::with_capacity(m));
    for (k, (&ex, &ey)) in comps[0].iter().zip(comps[1]).enumerate() {
        let (x, y) = positions(g, s, k);
        d.row(x, y, &mut row);
        let fit = |c: usize| -> f64 { row.iter().map(|&(i, a)| a * coef[(i, c)]).sum() };
        res_x.push(ex - fit(0));
        res_y.push(ey - fit(1));
    }
    let rough_x = axis_roughness(g.x.n, &s.ix, &res_x);
    let rough_y = axis_roughness(g.y.n, &s.iy, &res_y);
    let (periods_x, periods_y) = if waves.x.is_empty() && waves.y.is_empty() {
        (Vec::new(), Vec::new())
    } else {
        (periods_x, periods_y)
    };
    Ok((
        PhysicsFit {
            design: d,
            coef,
            knot_um: h,
            penalty: mu,
            cv_error_um: cv,
            periods_x,
            periods_y,
            rough_x,
            rough_y,
        },
        candidates,
    ))
}

impl PhysicsFit {
    /// RMS of the fit's residual at the samples, per component (e_x, e_y[, θ]).
    pub fn residual_rms(&self, g: &Grid2, s: &MapSamples) -> Vec<f64> {
        let d = &self.design;
        let comps = s.components();
        let mut sum = vec![0.0; comps.len()];
        let mut row = vec![(0usize, 0.0f64); d.nnz()];
        for k in 0..s.len() {
            let (x, y) = positions(g, s, k);
            d.row(x, y, &mut row);
            for (c, comp) in comps.iter().enumerate() {
                let fit: f64 = row.iter().map(|&(i, a)| a * self.coef[(i, c)]).sum();
                sum[c] += (comp[k] - fit).powi(2);
            }
        }
        sum.iter()
            .map(|v| (v / s.len().max(1) as f64).sqrt())
            .collect()
    }

    /// The noise reference of the pointwise band (see [`NoiseReference`]): per sample the noise
    /// proxies of e_x and e_y, their variance factors and (H²)_kk, with M = (I − H)² and H² by
    /// Hutchinson's estimator (E[z_a (Mz)_b] = M_ab for random ±1 probes z; [`HAT_PROBES`] of
    /// them, seeded: the band is reproducible); None if singular.
    pub fn noise_reference(&self, g: &Grid2, s: &MapSamples) -> Option<NoiseReference> {
        use rand::{Rng, SeedableRng};
        const P: usize = HAT_PROBES;
        let d = &self.design;
        let (m, p, r) = (s.len(), d.unknowns(), d.nnz());
        let mut rows = vec![(0usize, 0.0f64); m * r];
        for (k, row) in rows.chunks_exact_mut(r).enumerate() {
            let (x, y) = positions(g, s, k);
            d.row(x, y, row);
        }
        let at = |x: &Mat<f64>, k: usize, c: usize| -> f64 {
            rows[k * r..(k + 1) * r]
                .iter()
                .map(|&(i, a)| a * x[(i, c)])
                .sum()
        };
        // H applied to P columns at once (sample-major, k · P + j).
        let hat = |v: &[f64]| -> Option<Vec<f64>> {
            let mut nm = Normal::new(p, P);
            for (k, row) in rows.chunks_exact(r).enumerate() {
                nm.add(row, &v[k * P..(k + 1) * P]);
            }
            let x = solve(d, &nm, self.penalty)?;
            Some((0..m * P).map(|t| at(&x, t / P, t % P)).collect())
        };
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(0x4841_5431);
        let z: Vec<f64> = (0..m * P)
            .map(|_| if rng.random::<bool>() { 1.0 } else { -1.0 })
            .collect();
        let hz = hat(&z)?;
        let w: Vec<f64> = z.iter().zip(&hz).map(|(a, b)| a - b).collect();
        let hw = hat(&w)?;
        // (I − H)²z = w − Hw and H²z = Hz − Hw.
        let mz: Vec<f64> = w.iter().zip(&hw).map(|(a, b)| a - b).collect();
        let entry = |v: &[f64], a: usize, b: usize| -> f64 {
            let (za, zb) = (&z[a * P..(a + 1) * P], &z[b * P..(b + 1) * P]);
            let (va, vb) = (&v[a * P..(a + 1) * P], &v[b * P..(b + 1) * P]);
            let ab: f64 = za.iter().zip(vb).map(|(x, y)| x * y).sum();
            let ba: f64 = zb.iter().zip(va).map(|(x, y)| x * y).sum();
            (ab + ba) / (2 * P) as f64
        };
        let h2z: Vec<f64> = hz.iter().zip(&hw).map(|(a, b)| a - b).collect();
        let comps = s.components();
        let resid: Vec<Vec<f64>> = (0..2)
            .map(|c| (0..m).map(|k| comps[c][k] - at(&self.coef, k, c)).collect())
            .collect();
        let pts: Vec<(f64, f64)> = (0..m).map(|k| positions(g, s, k)).collect();
        let nb = nearest_neighbours(&pts, NOISE_NEIGHBOURS);
        let mut noise = vec![vec![0.0; m]; 2];
        let (mut noise_var, mut fit_var) = (vec![0.0; m], vec![0.0; m]);
        for k in 0..m {
            fit_var[k] = entry(&h2z, k, k);
            let n = &nb[k];
            if n.is_empty() {
                (noise[0][k], noise[1][k]) = (resid[0][k], resid[1][k]);
                noise_var[k] = entry(&mz, k, k);
                continue;
            }
            let q = n.len() as f64;
            for c in 0..2 {
                noise[c][k] = resid[c][k] - n.iter().map(|&j| resid[c][j]).sum::<f64>() / q;
            }
            let cross: f64 = n.iter().map(|&j| entry(&mz, k, j)).sum();
            let among: f64 = n
                .iter()
                .flat_map(|&a| n.iter().map(move |&b| (a, b)))
                .map(|(a, b)| entry(&mz, a, b))
                .sum();
            noise_var[k] = entry(&mz, k, k) - 2.0 * cross / q + among / (q * q);
        }
        // Structure finer than the spacing of the samples (a ripple, a pit) is not smooth
        // between neighbours a sample spacing apart: the proxy takes it for noise, and the band
        // took it out of the error (tests/system/reconstruct2d_band_variants.rs: an oblique
        // ripple of 0.02–0.06 µm at 80–200 µm and pits of 30–80 µm, 0.5 % sampled: coverage
        // 0.29–0.56). Pairs of samples within two grid steps tell the noise alone (the
        // residual's structure barely changes over 10 µm); where their σ² is clearly below the
        // proxies', the proxies are scaled down to it.
        let lag = PAIR_LAG_STEPS * g.x.step_um.max(g.y.step_um);
        let mut pairs = Vec::new();
        for (k, n) in nb.iter().enumerate() {
            for &j in n {
                let (a, b) = (pts[k], pts[j]);
                let mutual_first = j > k || !nb[j].contains(&k);
                if mutual_first && (a.0 - b.0).hypot(a.1 - b.1) <= lag {
                    pairs.push((k, j));
                }
            }
        }
        let var_pair: f64 = pairs
            .iter()
            .map(|&(k, j)| entry(&mz, k, k) + entry(&mz, j, j) - 2.0 * entry(&mz, k, j))
            .sum();
        let all_var: f64 = noise_var.iter().sum();
        if pairs.len() >= PAIRS_MIN && var_pair > 0.0 && all_var > 0.0 {
            for c in 0..2 {
                let pair = pairs
                    .iter()
                    .map(|&(k, j)| (resid[c][k] - resid[c][j]).powi(2))
                    .sum::<f64>()
                    / var_pair;
                let proxy = noise[c].iter().map(|v| v * v).sum::<f64>() / all_var;
                if !(proxy > 0.0 && pair.is_finite()) {
                    continue;
                }
                // The pairs' σ² is a mean of chi-square terms (relative se √(2/pairs)): its
                // deficit is shrunk by 1.5 se, (1 − (1.5 se)²/deficit²)₊, so a structure-free
                // map keeps its proxies. The band is sensitive to it where the map's error is
                // far below the noise: the rough stage at 0.5 % had a chance deficit of 0.20 on
                // 89 pairs (1.3 se), and the 9 % of σ² a 1-se shrink kept took its e_x band from
                // sharpness 2.72 to 3.77.
                let kept =
                    crate::recon::band::shrunk(1.0 - pair / proxy, 2.25 * 2.0 / pairs.len() as f64);
                let f = (1.0 - kept).sqrt();
                noise[c].iter_mut().for_each(|v| *v *= f);
            }
        }
        Some(NoiseReference {
            noise,
            noise_var,
            fit_var,
        })
    }

    /// Held-out predictions of e_x and e_y at every sample by the chosen structure and penalty
    /// (the selection's folds), for the pointwise band; None if singular.
    pub fn held_out(&self, g: &Grid2, s: &MapSamples) -> Option<Vec<Vec<f64>>> {
        let fold = folds(s.len(), CV_FOLDS);
        cv_predictions(g, s, &s.components(), &fold, &self.design, self.penalty)
    }

    /// The model at every grid point, x fastest, separably: the x families on the x grid, the y
    /// families on the y grid.
    pub fn evaluate(&self, g: &Grid2) -> Map {
        let d = &self.design;
        let nc = self.coef.ncols();
        let mut out: Vec<Vec<f64>> = Vec::with_capacity(nc);
        // (plain, coupled) sums of one axis's families at coordinate t.
        let sums = |along_x: bool, t: f64, c: usize| -> (f64, f64) {
            let mut acc = (0.0, 0.0);
            for (b, f) in d
                .fams
                .iter()
                .enumerate()
                .filter(|(_, f)| f.along_x == along_x)
            {
                let (i, v) = f.eval(t);
                let s: f64 = (0..4)
                    .map(|q| v[q] * self.coef[(d.offs[b] + i + q, c)])
                    .sum();
                if f.coupled {
                    acc.1 += s;
                } else {
                    acc.0 += s;
                }
            }
            acc
        };
        for c in 0..nc {
            let xs: Vec<(f64, f64, f64)> = (0..g.x.n)
                .map(|i| {
                    let x = g.x.position(i);
                    let (f, h) = sums(true, x, c);
                    (f, h, (x - d.x_mid) / d.x_half)
                })
                .collect();
            let mut v = Vec::with_capacity(g.len());
            for j in 0..g.y.n {
                let y = g.y.position(j);
                let (gy, ky) = sums(false, y, c);
                let yh = (y - d.y_mid) / d.y_half;
                v.extend(xs.iter().map(|&(f, h, xh)| f + gy + yh * h + xh * ky));
            }
            out.push(v);
        }
        let theta = (nc > 2).then(|| out.pop().expect("three components"));
        let mut ey = out.pop().expect("e_y");
        let mut ex = out.pop().expect("e_x");
        let nx = g.x.n;
        for (k, (ex, ey)) in ex.iter_mut().zip(ey.iter_mut()).enumerate() {
            *ex += self.rough_x.get(k % nx).copied().unwrap_or(0.0);
            *ey += self.rough_y.get(k / nx).copied().unwrap_or(0.0);
        }
        Map {
            ex,
            ey,
            theta,
            u_ex: Vec::new(),
            u_ey: Vec::new(),
        }
    }
}

#[cfg(test)]
mod tests;
