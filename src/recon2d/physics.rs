//! The physics model of a stacked XY stage, fitted by penalised least squares.
//!
//! Each component c ∈ {e_x, e_y, θ} is modelled as
//!     c(x, y) = F(x) + G(y) + ŷ·H(x) + x̂·K(y),
//! F and G the errors along each axis's own travel (leadscrew periods, trends, the other axis's
//! straightness), ŷ·H(x) and x̂·K(y) the couplings linear in the other coordinate (squareness,
//! yaw times an Abbe offset that changes with the other axis), x̂, ŷ ∈ [-1, 1] the centred
//! coordinates. F, G are uniform cubic B-splines at knot spacing h (chosen by cross-validation),
//! H, K at 4h (yaw varies slowly). The unknowns are O(nx + ny): the normal matrix is assembled
//! from the samples (16 basis values per sample) and factored once per candidate, and the map is
//! evaluated separably, so a 1901 × 841 grid never forms an nx·ny matrix.
use faer::linalg::solvers::SolveCore;
use faer::{Conj, Mat, Side};

use super::{folds, rms_xy, Candidate, Grid2, Map, MapSamples, CV_FOLDS};

/// Most unknowns of one fit: a dense Cholesky of 1200 is ~0.6 GFLOP, and the cross-validation
/// factors ~6 per candidate within the 10 s budget of a 1.6 M-point map.
const MAX_UNKNOWNS: usize = 1200;
/// Knot spacings cross-validated: the finest ones the samples allow.
const MAX_KNOT_CANDIDATES: usize = 8;
/// Curvature penalty weights tried by cross-validation, relative to the mean diagonal of AᵀA.
const PENALTIES: [f64; 2] = [1e-4, 1e-1];
/// Ridge on every coefficient, relative to the mean diagonal: it only settles the constants and
/// linear terms the four blocks share (F and G both hold a constant, for example).
const RIDGE: f64 = 1e-9;

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

/// The four blocks' bases and offsets for one knot spacing.
#[derive(Debug, Clone, Copy)]
struct Design {
    fx: Spline,
    gy: Spline,
    hx: Spline,
    ky: Spline,
    x_mid: f64,
    x_half: f64,
    y_mid: f64,
    y_half: f64,
}

impl Design {
    fn new(g: &Grid2, h: f64) -> Self {
        let (x0, x1) = (g.x.start_um, g.x.end_um());
        let (y0, y1) = (g.y.start_um, g.y.end_um());
        Self {
            fx: Spline::new(x0, x1, h),
            gy: Spline::new(y0, y1, h),
            hx: Spline::new(x0, x1, 4.0 * h),
            ky: Spline::new(y0, y1, 4.0 * h),
            x_mid: 0.5 * (x0 + x1),
            x_half: 0.5 * (x1 - x0),
            y_mid: 0.5 * (y0 + y1),
            y_half: 0.5 * (y1 - y0),
        }
    }
    fn offsets(&self) -> [usize; 5] {
        let o1 = self.fx.count();
        let o2 = o1 + self.gy.count();
        let o3 = o2 + self.hx.count();
        [0, o1, o2, o3, o3 + self.ky.count()]
    }
    fn unknowns(&self) -> usize {
        self.offsets()[4]
    }
    /// The 16 (column, value) entries of the design row at (x, y).
    fn row(&self, x: f64, y: f64) -> [(usize, f64); 16] {
        let o = self.offsets();
        let xh = (x - self.x_mid) / self.x_half;
        let yh = (y - self.y_mid) / self.y_half;
        let mut r = [(0, 0.0); 16];
        for (b, (sp, at, scale)) in [
            (self.fx, x, 1.0),
            (self.gy, y, 1.0),
            (self.hx, x, yh),
            (self.ky, y, xh),
        ]
        .into_iter()
        .enumerate()
        {
            let (i, v) = sp.eval(at);
            for q in 0..4 {
                r[4 * b + q] = (o[b] + i + q, v[q] * scale);
            }
        }
        r
    }
    /// Second-difference penalty DᵀD of every block (no penalty across blocks).
    fn add_penalty(&self, n: &mut Mat<f64>, mu: f64) {
        let o = self.offsets();
        for b in 0..4 {
            for s in o[b]..o[b + 1].saturating_sub(2) {
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

/// Normal equations AᵀA (lower triangle) and AᵀB of a set of samples.
struct Normal {
    ata: Mat<f64>,
    atb: Mat<f64>,
}

impl Normal {
    fn new(p: usize, nc: usize) -> Self {
        Self {
            ata: Mat::zeros(p, p),
            atb: Mat::zeros(p, nc),
        }
    }
    fn add(&mut self, row: &[(usize, f64); 16], vals: &[f64]) {
        for &(i, a) in row {
            for &(j, b) in row {
                if i >= j {
                    self.ata[(i, j)] += a * b;
                }
            }
            for (c, v) in vals.iter().enumerate() {
                self.atb[(i, c)] += a * v;
            }
        }
    }
}

/// Solves (AᵀA + penalty) X = AᵀB; None if the matrix is not positive definite.
fn solve(d: &Design, ata: &Mat<f64>, atb: &Mat<f64>, mu_rel: f64) -> Option<Mat<f64>> {
    let p = ata.nrows();
    let mean_diag = (0..p).map(|i| ata[(i, i)]).sum::<f64>() / p as f64;
    let scale = if mean_diag > 0.0 { mean_diag } else { 1.0 };
    let mut n = ata.clone();
    d.add_penalty(&mut n, mu_rel * scale);
    for i in 0..p {
        n[(i, i)] += RIDGE * scale;
    }
    let llt = n.llt(Side::Lower).ok()?;
    let mut x = atb.clone();
    llt.solve_in_place_with_conj(Conj::No, x.as_mut());
    let finite = (0..x.ncols()).all(|c| (0..x.nrows()).all(|i| x[(i, c)].is_finite()));
    finite.then_some(x)
}

/// A fitted physics model.
#[derive(Debug, Clone)]
pub struct PhysicsFit {
    design: Design,
    coef: Mat<f64>,
    pub knot_um: f64,
    pub penalty: f64,
    pub cv_error_um: f64,
}

fn positions(g: &Grid2, s: &MapSamples, k: usize) -> (f64, f64) {
    (g.x.position(s.ix[k]), g.y.position(s.iy[k]))
}

/// Knot spacings tried: multiples of the coarser grid step, each with fewer unknowns than
/// a third of the samples (and at most [`MAX_UNKNOWNS`]).
fn knot_candidates(g: &Grid2, m: usize) -> Vec<f64> {
    let step = g.x.step_um.max(g.y.step_um);
    [
        1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 8.0, 10.0, 12.0, 16.0, 24.0, 32.0, 48.0, 64.0,
    ]
    .iter()
    .map(|k| k * step)
    .filter(|&h| {
        let p = Design::new(g, h).unknowns();
        3 * p <= m && p <= MAX_UNKNOWNS
    })
    .take(MAX_KNOT_CANDIDATES)
    .collect()
}

/// Held-out RMS error of e_x and e_y at knot spacing h and penalty mu; None if singular.
fn cv_error(
    g: &Grid2,
    s: &MapSamples,
    comps: &[&[f64]],
    fold: &[usize],
    h: f64,
    mu: f64,
) -> Option<f64> {
    let m = s.len();
    let nc = comps.len();
    let d = Design::new(g, h);
    let p = d.unknowns();
    let mut parts: Vec<Normal> = (0..CV_FOLDS).map(|_| Normal::new(p, nc)).collect();
    let rows: Vec<[(usize, f64); 16]> = (0..m)
        .map(|k| {
            let (x, y) = positions(g, s, k);
            d.row(x, y)
        })
        .collect();
    let mut vals = vec![0.0; nc];
    for k in 0..m {
        for (c, comp) in comps.iter().enumerate() {
            vals[c] = comp[k];
        }
        parts[fold[k]].add(&rows[k], &vals);
    }
    let mut all = Normal::new(p, nc);
    for part in &parts {
        all.ata += &part.ata;
        all.atb += &part.atb;
    }
    let mut pred = vec![vec![0.0; m]; 2];
    for (f, part) in parts.iter().enumerate() {
        let ata = &all.ata - &part.ata;
        let atb = &all.atb - &part.atb;
        let x = solve(&d, &ata, &atb, mu)?;
        for k in (0..m).filter(|&k| fold[k] == f) {
            for (c, pc) in pred.iter_mut().enumerate() {
                pc[k] = rows[k].iter().map(|&(i, a)| a * x[(i, c)]).sum();
            }
        }
    }
    Some(rms_xy(s, &pred))
}

/// Fits every knot spacing and penalty, keeps the smallest k-fold CV error, refits on all samples.
pub fn select(g: &Grid2, s: &MapSamples) -> Result<(PhysicsFit, Vec<Candidate>), String> {
    let m = s.len();
    let mut knots = knot_candidates(g, m);
    if knots.is_empty() {
        // Too few samples for any spline at the grid's scale: the coarsest one (one interval per
        // axis, 4 + 4 + 4 + 4 unknowns) still needs a few times that many samples.
        let h = (g.x.end_um() - g.x.start_um).max(g.y.end_um() - g.y.start_um);
        if 3 * Design::new(g, h).unknowns() > m {
            return Err(format!(
                "the physics model needs at least {} samples, found {m}",
                3 * Design::new(g, h).unknowns()
            ));
        }
        knots.push(h);
    }
    let comps = s.components();
    let nc = comps.len();
    let fold = folds(m, CV_FOLDS);
    // Every knot spacing at the lightest penalty, then the other penalties at the best spacing.
    let mut best: Option<(f64, f64, f64)> = None; // (cv, h, mu)
    let mut candidates = Vec::new();
    for &h in &knots {
        let cv = cv_error(g, s, &comps, &fold, h, PENALTIES[0]);
        candidates.push(Candidate {
            method: "physics",
            knot_um: Some(h),
            cv_error_um: cv.unwrap_or(f64::NAN),
        });
        if let Some(cv) = cv {
            if best.is_none_or(|b| cv < b.0) {
                best = Some((cv, h, PENALTIES[0]));
            }
        }
    }
    if let Some((_, h, _)) = best {
        for &mu in &PENALTIES[1..] {
            if let Some(cv) = cv_error(g, s, &comps, &fold, h, mu) {
                if best.is_none_or(|b| cv < b.0) {
                    best = Some((cv, h, mu));
                }
            }
        }
    }
    let (cv, h, mu) = best.ok_or("the physics model's normal equations are singular")?;
    let d = Design::new(g, h);
    let mut all = Normal::new(d.unknowns(), nc);
    let mut vals = vec![0.0; nc];
    for k in 0..m {
        let (x, y) = positions(g, s, k);
        for (c, comp) in comps.iter().enumerate() {
            vals[c] = comp[k];
        }
        all.add(&d.row(x, y), &vals);
    }
    let coef = solve(&d, &all.ata, &all.atb, mu)
        .ok_or("the physics model's normal equations are singular")?;
    Ok((
        PhysicsFit {
            design: d,
            coef,
            knot_um: h,
            penalty: mu,
            cv_error_um: cv,
        },
        candidates,
    ))
}

impl PhysicsFit {
    /// The model at every grid point, x fastest, separably: F, H on the x grid, G, K on the y grid.
    pub fn evaluate(&self, g: &Grid2) -> Map {
        let d = self.design;
        let o = d.offsets();
        let block = |sp: Spline, off: usize, at: f64, c: usize| -> f64 {
            let (i, v) = sp.eval(at);
            (0..4).map(|q| v[q] * self.coef[(off + i + q, c)]).sum()
        };
        let nc = self.coef.ncols();
        let mut out: Vec<Vec<f64>> = Vec::with_capacity(nc);
        for c in 0..nc {
            let xs: Vec<(f64, f64, f64)> = (0..g.x.n)
                .map(|i| {
                    let x = g.x.position(i);
                    (
                        block(d.fx, o[0], x, c),
                        block(d.hx, o[2], x, c),
                        (x - d.x_mid) / d.x_half,
                    )
                })
                .collect();
            let mut v = Vec::with_capacity(g.len());
            for j in 0..g.y.n {
                let y = g.y.position(j);
                let gy = block(d.gy, o[1], y, c);
                let ky = block(d.ky, o[3], y, c);
                let yh = (y - d.y_mid) / d.y_half;
                v.extend(xs.iter().map(|&(f, h, xh)| f + gy + yh * h + xh * ky));
            }
            out.push(v);
        }
        let theta = (nc > 2).then(|| out.pop().expect("three components"));
        let ey = out.pop().expect("e_y");
        let ex = out.pop().expect("e_x");
        Map { ex, ey, theta }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_cubic_b_spline_basis_is_a_nonnegative_partition_of_unity() {
        let sp = Spline::new(-3.0, 17.0, 1.7);
        for k in 0..200 {
            let x = -3.0 + 20.0 * k as f64 / 199.0;
            let (_, v) = sp.eval(x);
            assert!((v.iter().sum::<f64>() - 1.0).abs() < 1e-12);
            assert!(v.iter().all(|&b| b >= 0.0));
        }
    }

    #[test]
    fn an_exact_model_is_recovered_from_noise_free_samples() {
        // A map that lies in the model's span up to spline error: smooth F, G, H, K.
        let g = Grid2::new("0:10:2000".parse().unwrap(), "0:10:1000".parse().unwrap()).unwrap();
        let truth = |x: f64, y: f64| {
            0.3 * (x / 700.0).sin() + 0.2 * (y / 300.0).cos() + 1e-4 * y * (x / 900.0).cos()
                - 2e-5 * x * y / 1000.0
        };
        let mut s = MapSamples::default();
        let mut state = 12345u64;
        let mut seen = std::collections::HashSet::new();
        while s.len() < 1500 {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            let (ix, iy) = (
                (state >> 33) as usize % g.x.n,
                (state >> 13) as usize % g.y.n,
            );
            if seen.insert((ix, iy)) {
                let (x, y) = (g.x.position(ix), g.y.position(iy));
                s.ix.push(ix);
                s.iy.push(iy);
                s.ex.push(truth(x, y));
                s.ey.push(-truth(y * 2.0, x / 2.0));
            }
        }
        let (fit, _) = select(&g, &s).unwrap();
        let map = fit.evaluate(&g);
        let mut worst: f64 = 0.0;
        for j in 0..g.y.n {
            for i in 0..g.x.n {
                let (x, y) = (g.x.position(i), g.y.position(j));
                worst = worst.max((map.ex[j * g.x.n + i] - truth(x, y)).abs());
            }
        }
        assert!(worst < 2e-3, "max |error| {worst} µm");
    }
}
