//! The XY workspace error map e_x(x, y), e_y(x, y) (and θ(x, y)) from scattered samples on a 2D grid.
//!
//! Three methods: `physics`, a structured model of a stacked XY stage (each axis's own error along
//! its travel with the leadscrew periods found in the samples, the other axis's straightness, and
//! coupling terms linear in the other coordinate); `bp`, 2D DCT basis pursuit denoising with fast
//! operators (for comparison); and `linear`, linear interpolation on a Delaunay triangulation of
//! the samples (the baseline). `auto` picks the one with the smallest cross-validation error.
use std::str::FromStr;
use std::time::Instant;

use serde::Serialize;

use crate::grid::Grid;
use crate::recon::band::HeldOut;
use crate::recon::periods::Period;

pub mod bp;
pub mod linear;
pub mod physics;

/// Most points a map grid may have (nx·ny): 4 M, over twice the 1901 × 841 map.
pub const MAX_MAP_POINTS: usize = 4_000_000;
/// Folds of the cross-validation that picks the knot spacing and the method.
pub const CV_FOLDS: usize = 5;
/// Iteration cap of a basis-pursuit solve (each iteration is two 2D DCTs of the whole grid).
pub const BP_MAX_ITER: usize = 300;
/// Largest grid on which `auto` cross-validates basis pursuit: a held-out solve costs up to
/// [`BP_CV_MAX_ITER`] pairs of 2D DCTs of the whole grid, far over the 10 s budget on a 1.6 M-point
/// map, and minutes in a debug build at 64 k points.
pub const BP_AUTO_MAX_POINTS: usize = 50_000;
/// Iteration cap of the held-out basis-pursuit solve that `auto` compares.
pub const BP_CV_MAX_ITER: usize = 100;

/// The map grid: x fastest.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Grid2 {
    pub x: Grid,
    pub y: Grid,
}

impl Grid2 {
    /// Refuses grids of more than [`MAX_MAP_POINTS`] points before anything is allocated.
    pub fn new(x: Grid, y: Grid) -> Result<Self, String> {
        let n = x.n.saturating_mul(y.n);
        if n > MAX_MAP_POINTS {
            return Err(format!(
                "map grid {} x {} has {n} points, more than {MAX_MAP_POINTS}",
                x.n, y.n
            ));
        }
        Ok(Self { x, y })
    }
    pub fn len(&self) -> usize {
        self.x.n * self.y.n
    }
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

/// Samples of the map: grid indices and the measured errors (µm; θ in µrad).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct MapSamples {
    pub ix: Vec<usize>,
    pub iy: Vec<usize>,
    pub ex: Vec<f64>,
    pub ey: Vec<f64>,
    pub theta: Option<Vec<f64>>,
}

impl MapSamples {
    pub fn len(&self) -> usize {
        self.ix.len()
    }
    pub fn is_empty(&self) -> bool {
        self.ix.is_empty()
    }
    /// The measured components: e_x, e_y, then θ if present.
    pub fn components(&self) -> Vec<&[f64]> {
        let mut c = vec![self.ex.as_slice(), self.ey.as_slice()];
        if let Some(t) = &self.theta {
            c.push(t.as_slice());
        }
        c
    }
    /// The samples at the given positions (in that order).
    pub fn subset(&self, keep: &[usize]) -> Self {
        let pick = |v: &[f64]| keep.iter().map(|&k| v[k]).collect::<Vec<f64>>();
        Self {
            ix: keep.iter().map(|&k| self.ix[k]).collect(),
            iy: keep.iter().map(|&k| self.iy[k]).collect(),
            ex: pick(&self.ex),
            ey: pick(&self.ey),
            theta: self.theta.as_deref().map(pick),
        }
    }
}

/// A reconstructed map, every component at every grid point, x fastest.
#[derive(Debug, Clone, PartialEq)]
pub struct Map {
    pub ex: Vec<f64>,
    pub ey: Vec<f64>,
    pub theta: Option<Vec<f64>>,
    /// Pointwise standard uncertainty (k = 1, µm) of e_x and e_y at every grid point (see
    /// [`map_band`]); empty where not computed.
    pub u_ex: Vec<f64>,
    pub u_ey: Vec<f64>,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Method2 {
    Auto,
    Physics,
    Linear,
    Bp,
}

impl FromStr for Method2 {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "auto" => Ok(Self::Auto),
            "physics" => Ok(Self::Physics),
            "linear" => Ok(Self::Linear),
            "bp" => Ok(Self::Bp),
            _ => Err(format!(
                "unknown method {s:?} (auto | bp | physics | linear)"
            )),
        }
    }
}

/// One cross-validated candidate: held-out RMS error over e_x and e_y (µm).
#[derive(Debug, Clone, Serialize)]
pub struct Candidate {
    pub method: &'static str,
    pub knot_um: Option<f64>,
    pub cv_error_um: f64,
    /// Folds held out in turn: [`CV_FOLDS`], or 1 for basis pursuit (one fold of the
    /// [`CV_FOLDS`] held out: a full solve per fold is too slow).
    pub folds: usize,
}

/// The solve figures printed by `--json`.
#[derive(Debug, Clone, Serialize)]
pub struct Report2 {
    pub method: &'static str,
    pub nx: usize,
    pub ny: usize,
    pub m: usize,
    pub solve_ms: f64,
    /// Held-out RMS error of e_x and e_y of the chosen method (µm; includes the sensor noise).
    pub cv_error_um: f64,
    /// Knot spacing of the physics model's per-axis splines (µm), when physics was chosen.
    pub knot_um: Option<f64>,
    pub folds: usize,
    pub candidates: Vec<Candidate>,
    /// Cyclic periods found along x and along y by the physics model (fundamentals, µm).
    pub periods_x: Vec<Period>,
    pub periods_y: Vec<Period>,
    /// Basis-pursuit solves of the returned map (e_x, e_y[, θ]), when bp was chosen.
    pub bp: Option<Vec<bp::BpSolve>>,
    /// Mean and largest pointwise u (k = 1, µm) of e_x and of e_y over the grid.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub u_ex_mean_um: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub u_ex_max_um: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub u_ey_mean_um: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub u_ey_max_um: Option<f64>,
}

/// Assigns each of m samples to one of k folds, at random but reproducibly.
pub(crate) fn folds(m: usize, k: usize) -> Vec<usize> {
    use rand::seq::SliceRandom;
    use rand::SeedableRng;
    let mut order: Vec<usize> = (0..m).collect();
    order.shuffle(&mut rand_chacha::ChaCha8Rng::seed_from_u64(0x2d_4d4150));
    let mut fold = vec![0; m];
    for (r, &s) in order.iter().enumerate() {
        fold[s] = r % k;
    }
    fold
}

/// RMS over e_x and e_y of held-out predictions `pred[c][s]` against the samples.
pub(crate) fn rms_xy(s: &MapSamples, pred: &[Vec<f64>]) -> f64 {
    let mut sum = 0.0;
    for (c, truth) in [&s.ex, &s.ey].into_iter().enumerate() {
        sum += truth
            .iter()
            .zip(&pred[c])
            .map(|(t, p)| (t - p) * (t - p))
            .sum::<f64>();
    }
    (sum / (2 * s.len()).max(1) as f64).sqrt()
}

/// Basis pursuit of every component from the samples `s`: the map and the solve reports.
/// `sigma[c]` is the noise level of component c; ε = σ·√m.
fn bp_map(
    g: &Grid2,
    s: &MapSamples,
    sigma: &[f64],
    max_iter: usize,
) -> (Vec<Vec<f64>>, Vec<bp::BpSolve>) {
    let idx = bp::flat_indices(g, &s.ix, &s.iy);
    let mut dct = bp::Dct2::new(g.x.n, g.y.n);
    let eps_scale = (s.len() as f64).sqrt();
    s.components()
        .into_iter()
        .zip(sigma)
        .map(|(b, &sg)| bp::solve(&mut dct, &idx, b, sg * eps_scale, max_iter))
        .unzip()
}

/// Held-out RMS over e_x and e_y of basis pursuit on one fold (trained on the others), and the
/// held-out predictions `pred[c][k]` (NaN for the samples of the other folds).
fn bp_cv_error(g: &Grid2, s: &MapSamples, sigma: &[f64]) -> (f64, Vec<Vec<f64>>) {
    let fold = folds(s.len(), CV_FOLDS);
    let train: Vec<usize> = (0..s.len()).filter(|&k| fold[k] != 0).collect();
    let test: Vec<usize> = (0..s.len()).filter(|&k| fold[k] == 0).collect();
    let mut t = s.subset(&train);
    t.theta = None;
    let (maps, _) = bp_map(g, &t, &sigma[..2], BP_CV_MAX_ITER);
    let held = s.subset(&test);
    let pred: Vec<Vec<f64>> = maps
        .iter()
        .map(|m| {
            held.ix
                .iter()
                .zip(&held.iy)
                .map(|(&i, &j)| m[j * g.x.n + i])
                .collect()
        })
        .collect();
    let mut all = vec![vec![f64::NAN; s.len()]; pred.len()];
    for (a, p) in all.iter_mut().zip(&pred) {
        for (&k, &v) in test.iter().zip(p) {
            a[k] = v;
        }
    }
    (rms_xy(&held, &pred), all)
}

/// Pointwise standard uncertainty (k = 1, µm) of e_x and e_y at every grid point, as the 1D
/// curve's ([`crate::recon::band`]): the chosen method's held-out residuals `pred[c][k] − value`
/// paired with each held-out sample's distance to the nearest training sample of its fold (in
/// the plane), calibrated into u(d), read at every grid point's distance to the nearest sample.
/// Samples without a prediction (NaN: basis pursuit holds one fold out) are left out.
///
/// The held-out residuals carry the sensor noise, which a map has no setting for. With the physics
/// model's `reference` (its in-sample residuals and hat-matrix diagonals) the noise is estimated
/// per distance bin from the same samples and taken out of their mean square
/// ([`crate::recon::band::u_at_distances_denoised`]); before, its in-sample residual RMS was
/// taken out of the bin's quantile down to a floor of a third of it, and the band was 4–7 times
/// the mean error of a map the model smooths the 0.01 µm noise out of, and 0.75 covering on a
/// map whose error is a bump the model cannot hold (tests/system/reconstruct2d_rough.rs).
/// The excess over the fit's noise floor (its error beyond the noise it propagates) varies over
/// the plane: a bump the model cannot hold is the map's error where it is and nowhere else. Its
/// share per cell of ~200 held-out samples (with the 8 around it, shrunk by its sampling error,
/// at least a tenth) scales the band's excess there; before, the band depended on the distance
/// to the samples only and spread the bump over the whole map
/// (tests/system/reconstruct2d_rough.rs's second surface: coverage 0.935 / 0.934, sharpness 3.11 / 3.07 at 2 %; now 0.957 / 0.954,
/// 2.65 / 2.63). For the other methods (linear interpolation passes through its samples, basis
/// pursuit within ε of them: no in-sample residual tells the noise) `noise[c]` is taken out of
/// the quantile as the curves' band does.
fn map_band(
    g: &Grid2,
    s: &MapSamples,
    pred: &[Vec<f64>],
    noise: &[f64],
    reference: Option<&physics::NoiseReference>,
) -> (Vec<f64>, Vec<f64>) {
    let m = s.len();
    let fold = folds(m, CV_FOLDS);
    let mut dist = vec![f64::NAN; m];
    for f in 0..CV_FOLDS {
        let held: Vec<usize> = (0..m)
            .filter(|&k| fold[k] == f && pred.iter().take(2).all(|p| p[k].is_finite()))
            .collect();
        if held.is_empty() {
            continue;
        }
        let train: Vec<usize> = (0..m).filter(|&k| fold[k] != f).collect();
        let t = s.subset(&train);
        let d = nearest_sample_distance(g, &t.ix, &t.iy);
        for k in held {
            dist[k] = d[s.iy[k] * g.x.n + s.ix[k]];
        }
    }
    let all = nearest_sample_distance(g, &s.ix, &s.iy);
    // Cells of ~200 held-out samples over the plane, square-ish in µm, for the excess over the
    // noise floor varying over it (`band::u_at_distances_denoised`; the physics model's only).
    let (wx, wy) = (g.x.step_um * g.x.n as f64, g.y.step_um * g.y.n as f64);
    let want = (m / 200).max(1) as f64;
    let cx = ((want * wx / wy).sqrt().round() as usize).clamp(1, g.x.n);
    let cy = ((want / cx as f64).round() as usize).clamp(1, g.y.n);
    let cell_of = |i: usize, j: usize| (j * cy / g.y.n) * cx + i * cx / g.x.n;
    let grid_cell: Vec<usize> = match reference {
        Some(_) => (0..g.y.n)
            .flat_map(|j| (0..g.x.n).map(move |i| cell_of(i, j)))
            .collect(),
        None => Vec::new(),
    };
    let cells = crate::recon::band::Cells {
        nx: cx,
        ny: cy,
        grid: &grid_cell,
    };
    let comp = |c: usize, value: &[f64]| {
        let held = (0..m).filter(|&k| dist[k].is_finite());
        match reference {
            Some(nr) => {
                let h: Vec<HeldOut> = held
                    .map(|k| HeldOut {
                        d: dist[k],
                        r: pred[c][k] - value[k],
                        noise: nr.noise[c][k],
                        noise_var: nr.noise_var[k],
                        fit_var: nr.fit_var[k],
                        cell: cell_of(s.ix[k], s.iy[k]),
                    })
                    .collect();
                crate::recon::band::u_at_distances_denoised(&all, &h, CV_FOLDS, Some(&cells))
            }
            None => {
                let cv: Vec<(f64, f64)> = held.map(|k| (dist[k], pred[c][k] - value[k])).collect();
                crate::recon::band::u_at_distances(&all, &cv, noise.get(c).copied().unwrap_or(0.0))
            }
        }
    };
    (comp(0, &s.ex), comp(1, &s.ey))
}

/// Smallest share of the grid's area the samples' convex hull may cover: below it most of the
/// map would be extrapolated from a corner or a band, and the cross-validation (held-out
/// points from the same corner) would not see it. A uniform random design of 10 points covers
/// about 40 % on average, of 30 points 70 %.
pub const MIN_HULL_FRACTION: f64 = 0.25;

/// Whether the samples span the grid: refuses samples on one line (the map's x and y
/// dependences cannot be told apart: every model fits them, and the cross-validation, on the
/// same line, reports a falsely small error) and samples whose convex hull covers less than
/// [`MIN_HULL_FRACTION`] of the grid. Returns the share covered.
pub fn coverage(g: &Grid2, s: &MapSamples) -> Result<f64, String> {
    let m = s.len();
    let pts: Vec<(i64, i64)> = (0..m).map(|k| (s.ix[k] as i64, s.iy[k] as i64)).collect();
    let um = |ix: i64, iy: i64| {
        (
            g.x.start_um + ix as f64 * g.x.step_um,
            g.y.start_um + iy as f64 * g.y.step_um,
        )
    };
    let (wx, wy) = (
        g.x.n.saturating_sub(1) as i64,
        g.y.n.saturating_sub(1) as i64,
    );
    let span = |v: &mut dyn Iterator<Item = i64>| {
        let (lo, hi) = v.fold((i64::MAX, i64::MIN), |(a, b), x| (a.min(x), b.max(x)));
        (lo, hi)
    };
    let (x0, x1) = span(&mut pts.iter().map(|p| p.0));
    let (y0, y1) = span(&mut pts.iter().map(|p| p.1));
    let fraction = if wx == 0 || wy == 0 {
        // A grid one point wide is a line: the samples need only span it.
        match (wx, wy) {
            (0, 0) => 1.0,
            (0, _) => (y1 - y0) as f64 / wy as f64,
            _ => (x1 - x0) as f64 / wx as f64,
        }
    } else {
        let area2 = hull_area2(&pts);
        if area2 == 0 {
            // One line: the two samples farthest apart name it.
            let (a, b) = if x1 > x0 {
                let a = pts.iter().filter(|p| p.0 == x0).min_by_key(|p| p.1);
                let b = pts.iter().filter(|p| p.0 == x1).max_by_key(|p| p.1);
                (a, b)
            } else {
                let a = pts.iter().filter(|p| p.1 == y0).min_by_key(|p| p.0);
                let b = pts.iter().filter(|p| p.1 == y1).max_by_key(|p| p.0);
                (a, b)
            };
            let (a, b) = (
                a.copied().unwrap_or_default(),
                b.copied().unwrap_or_default(),
            );
            let (pa, pb) = (um(a.0, a.1), um(b.0, b.1));
            return Err(format!(
                "all {m} samples lie on one line, from ({}, {}) to ({}, {}) µm: the map's \
                 dependence on x cannot be told from its dependence on y there, and off the \
                 line it would be made up (its cross-validation error, from the same line, \
                 would be falsely small); measure points spread over the plane, e.g. a random \
                 design over the whole grid",
                pa.0, pa.1, pb.0, pb.1
            ));
        }
        area2 as f64 / (2.0 * wx as f64 * wy as f64)
    };
    if fraction < MIN_HULL_FRACTION {
        let (lo, hi) = (um(x0, y0), um(x1, y1));
        return Err(format!(
            "the samples cover {:.1} % of the grid (their convex hull; x {}..{} µm, y {}..{} \
             µm), less than the {:.0} % needed: the rest of the map would be extrapolated and \
             its error is not known; measure points spread over the whole grid, or give \
             --grid-x/--grid-y only the part measured",
            100.0 * fraction,
            lo.0,
            hi.0,
            lo.1,
            hi.1,
            100.0 * MIN_HULL_FRACTION
        ));
    }
    Ok(fraction)
}

/// Twice the area of the convex hull of `pts` (monotone chain, exact in integers).
fn hull_area2(pts: &[(i64, i64)]) -> i128 {
    let mut p: Vec<(i64, i64)> = pts.to_vec();
    p.sort_unstable();
    p.dedup();
    if p.len() < 3 {
        return 0;
    }
    let cross = |o: (i64, i64), a: (i64, i64), b: (i64, i64)| {
        (a.0 - o.0) as i128 * (b.1 - o.1) as i128 - (a.1 - o.1) as i128 * (b.0 - o.0) as i128
    };
    let mut hull: Vec<(i64, i64)> = Vec::with_capacity(2 * p.len());
    for pass in 0..2 {
        let start = hull.len();
        let iter: Box<dyn Iterator<Item = &(i64, i64)>> = if pass == 0 {
            Box::new(p.iter())
        } else {
            Box::new(p.iter().rev())
        };
        for &q in iter {
            while hull.len() >= start + 2
                && cross(hull[hull.len() - 2], hull[hull.len() - 1], q) <= 0
            {
                hull.pop();
            }
            hull.push(q);
        }
        hull.pop();
    }
    let n = hull.len();
    (0..n)
        .map(|i| {
            let (a, b) = (hull[i], hull[(i + 1) % n]);
            a.0 as i128 * b.1 as i128 - b.0 as i128 * a.1 as i128
        })
        .sum::<i128>()
        .abs()
}

/// Reconstructs the whole map with `method` (`auto`: the smallest cross-validation error).
pub fn reconstruct(g: &Grid2, s: &MapSamples, method: Method2) -> Result<(Map, Report2), String> {
    if s.len() < 3 {
        return Err(format!("need at least 3 samples, found {}", s.len()));
    }
    let t0 = Instant::now();
    let mut candidates = Vec::new();
    let phys = match method {
        Method2::Linear => None,
        Method2::Physics => {
            let (fit, mut cands) = physics::select(g, s)?;
            candidates.append(&mut cands);
            Some(fit)
        }
        // Too few samples for the model: auto is left with the others; bp only needs it for
        // the noise level.
        Method2::Auto | Method2::Bp => physics::select(g, s).ok().map(|(fit, mut cands)| {
            if method == Method2::Auto {
                candidates.append(&mut cands);
            }
            fit
        }),
    };
    let mut lin_pred = None;
    let lin_cv = if matches!(method, Method2::Auto | Method2::Linear)
        || (method == Method2::Bp && phys.is_none())
    {
        let pred = linear::cv_predictions(g, s);
        let e = rms_xy(s, &pred);
        lin_pred = Some(pred);
        candidates.push(Candidate {
            method: "linear",
            knot_um: None,
            cv_error_um: e,
            folds: CV_FOLDS,
        });
        Some(e)
    } else {
        None
    };
    // The noise level basis pursuit's ε assumes: the physics model's in-sample residual per
    // component (noise plus misfit), else the linear interpolation's held-out error.
    let sigma: Vec<f64> = match &phys {
        Some(p) => p.residual_rms(g, s),
        None => vec![lin_cv.unwrap_or(0.0); s.components().len()],
    };
    let mut bp_pred = None;
    let bp_cv = match method {
        Method2::Auto if g.len() <= BP_AUTO_MAX_POINTS => {
            let (e, pred) = bp_cv_error(g, s, &sigma);
            bp_pred = Some(pred);
            Some(e)
        }
        _ => None,
    };
    if let Some(e) = bp_cv {
        candidates.push(Candidate {
            method: "bp",
            knot_um: None,
            cv_error_um: e,
            folds: 1,
        });
    }
    let finite = |v: Option<f64>| v.filter(|e| e.is_finite());
    let choice = match method {
        Method2::Physics => "physics",
        Method2::Linear => "linear",
        Method2::Bp => "bp",
        Method2::Auto => {
            let mut best = ("linear", f64::INFINITY);
            for (name, e) in [
                ("physics", finite(phys.as_ref().map(|p| p.cv_error_um))),
                ("bp", finite(bp_cv)),
                ("linear", finite(lin_cv)),
            ] {
                if let Some(e) = e {
                    if e < best.1 {
                        best = (name, e);
                    }
                }
            }
            best.0
        }
    };
    let mut bp_report = None;
    let (mut map, cv, knot) = match choice {
        "physics" => {
            let p = phys.as_ref().expect("physics fitted");
            (p.evaluate(g), p.cv_error_um, Some(p.knot_um))
        }
        "bp" => {
            let (mut out, rep) = bp_map(g, s, &sigma, BP_MAX_ITER);
            bp_report = Some(rep);
            let theta = (out.len() > 2).then(|| out.pop().expect("three components"));
            let ey = out.pop().expect("e_y");
            let ex = out.pop().expect("e_x");
            let map = Map {
                ex,
                ey,
                theta,
                u_ex: Vec::new(),
                u_ey: Vec::new(),
            };
            (map, bp_cv.unwrap_or(f64::NAN), None)
        }
        _ => (linear::interpolate(g, s), lin_cv.unwrap_or(f64::NAN), None),
    };
    // The band from the chosen method's held-out predictions (basis pursuit asked for directly
    // had none: one held-out fold, as `auto` scores it).
    let held = match choice {
        "physics" => phys.as_ref().and_then(|p| p.held_out(g, s)),
        "bp" => bp_pred.or_else(|| Some(bp_cv_error(g, s, &sigma).1)),
        _ => lin_pred.or_else(|| Some(linear::cv_predictions(g, s))),
    };
    if let Some(pred) = held {
        // The physics model's noise reference: its own held-out residuals are denoised with it;
        // for the other methods its noise estimate with the fit's degrees of freedom taken out,
        // σ² = Σ r_in² / Σ((I − H)²)_kk (the in-sample RMS reads low by the fit's share).
        let reference = phys.as_ref().and_then(|p| p.noise_reference(g, s));
        let noise: Vec<f64> = match (&reference, &phys) {
            (Some(nr), _) => {
                let dof = nr.noise_var.iter().sum::<f64>();
                nr.noise
                    .iter()
                    .map(|r| (r.iter().map(|v| v * v).sum::<f64>() / dof.max(1.0)).sqrt())
                    .collect()
            }
            (None, Some(_)) => sigma.clone(),
            (None, None) => vec![0.0; 2],
        };
        let denoise = if choice == "physics" {
            reference.as_ref()
        } else {
            None
        };
        (map.u_ex, map.u_ey) = map_band(g, s, &pred, &noise, denoise);
    }
    let stats = |u: &[f64]| {
        (!u.is_empty()).then(|| {
            (
                u.iter().sum::<f64>() / u.len() as f64,
                u.iter().copied().fold(0.0, f64::max),
            )
        })
    };
    let (ux, uy) = (stats(&map.u_ex), stats(&map.u_ey));
    let (periods_x, periods_y) = match &phys {
        Some(p) => (p.periods_x.clone(), p.periods_y.clone()),
        None => (Vec::new(), Vec::new()),
    };
    let report = Report2 {
        method: choice,
        nx: g.x.n,
        ny: g.y.n,
        m: s.len(),
        solve_ms: t0.elapsed().as_secs_f64() * 1e3,
        cv_error_um: cv,
        knot_um: knot,
        folds: CV_FOLDS,
        candidates,
        periods_x,
        periods_y,
        bp: bp_report,
        u_ex_mean_um: ux.map(|v| v.0),
        u_ex_max_um: ux.map(|v| v.1),
        u_ey_mean_um: uy.map(|v| v.0),
        u_ey_max_um: uy.map(|v| v.1),
    };
    Ok((map, report))
}

/// Distance (µm) from every grid point (x fastest) to the nearest of the grid points
/// `(ix[k], iy[k])`: an exact Euclidean distance transform (squared distances along each row,
/// then the lower envelope of parabolas down each column; Felzenszwalb & Huttenlocher 2012),
/// linear in the grid's size whatever the number of samples. Empty `ix`: every distance infinite.
pub fn nearest_sample_distance(g: &Grid2, ix: &[usize], iy: &[usize]) -> Vec<f64> {
    let (nx, ny) = (g.x.n, g.y.n);
    let mut f = vec![f64::INFINITY; nx * ny];
    for (&i, &j) in ix.iter().zip(iy) {
        if i < nx && j < ny {
            f[j * nx + i] = 0.0;
        }
    }
    let mut buf = Vec::new();
    for row in f.chunks_exact_mut(nx) {
        buf.clear();
        buf.extend_from_slice(row);
        squared_distance_1d(&buf, g.x.step_um, row);
    }
    let mut col = vec![0.0; ny];
    let mut out = vec![0.0; ny];
    for i in 0..nx {
        for j in 0..ny {
            col[j] = f[j * nx + i];
        }
        squared_distance_1d(&col, g.y.step_um, &mut out);
        for j in 0..ny {
            f[j * nx + i] = out[j];
        }
    }
    for v in &mut f {
        *v = v.sqrt();
    }
    f
}

/// `out[q] = min_p f[p] + (step·(q − p))²` (the lower envelope of the parabolas rooted at the
/// finite `f[p]`); all infinite if none is.
fn squared_distance_1d(f: &[f64], step: f64, out: &mut [f64]) {
    let n = f.len();
    // Parabola roots (grid indices) and the boundaries between them, in index units scaled by
    // the step.
    let mut v: Vec<usize> = Vec::with_capacity(n);
    let mut z: Vec<f64> = Vec::with_capacity(n + 1);
    let s2 = step * step;
    // Intersection (in index units) of the parabolas rooted at p and q (p < q).
    let cross = |p: usize, q: usize| {
        ((f[q] + s2 * (q * q) as f64) - (f[p] + s2 * (p * p) as f64)) / (2.0 * s2 * (q - p) as f64)
    };
    for q in (0..n).filter(|&q| f[q].is_finite()) {
        loop {
            match v.last() {
                None => {
                    v.push(q);
                    z.clear();
                    z.push(f64::NEG_INFINITY);
                    break;
                }
                Some(&p) => {
                    let x = cross(p, q);
                    if x <= *z.last().expect("one boundary per parabola") {
                        v.pop();
                        z.pop();
                        if v.is_empty() {
                            continue;
                        }
                    } else {
                        v.push(q);
                        z.push(x);
                        break;
                    }
                }
            }
        }
    }
    if v.is_empty() {
        out.iter_mut().for_each(|o| *o = f64::INFINITY);
        return;
    }
    let mut k = 0;
    for (q, o) in out.iter_mut().enumerate() {
        while k + 1 < v.len() && z[k + 1] < q as f64 {
            k += 1;
        }
        let d = q as f64 - v[k] as f64;
        *o = f[v[k]] + s2 * d * d;
    }
}

/// At most 40 characters of a field for an error message.
fn clip(s: &str) -> String {
    match s.char_indices().nth(40) {
        Some((i, _)) => format!("{}…", &s[..i]),
        None => s.to_string(),
    }
}

/// Parses map sample CSV text; errors carry the 1-based line number.
pub fn parse_map_samples_csv(text: &str, g: &Grid2) -> Result<MapSamples, (usize, String)> {
    const HEADER: &str = "x_um,y_um,ex_um,ey_um[,theta_urad]";
    let mut lines = text
        .lines()
        .enumerate()
        .filter(|(_, l)| !l.trim().is_empty());
    let (hline, header) = lines
        .next()
        .ok_or((1, format!("empty file: expected header `{HEADER}`")))?;
    let cols: Vec<String> = header
        .split(',')
        .map(|c| c.trim().trim_start_matches('\u{feff}').to_string())
        .collect();
    let col = |name: &str| cols.iter().position(|c| c == name);
    let (cx, cy, cex, cey) = match (col("x_um"), col("y_um"), col("ex_um"), col("ey_um")) {
        (Some(a), Some(b), Some(c), Some(d)) => (a, b, c, d),
        _ => {
            return Err((
                hline + 1,
                format!(
                    "missing header `{HEADER}` (found {:?})",
                    clip(header.trim())
                ),
            ))
        }
    };
    let ct = col("theta_urad");
    let mut s = MapSamples {
        theta: ct.map(|_| Vec::new()),
        ..Default::default()
    };
    let mut seen = std::collections::HashMap::new();
    for (i, line) in lines {
        let lineno = i + 1;
        let fields: Vec<&str> = line.split(',').map(str::trim).collect();
        if fields.len() != cols.len() {
            return Err((
                lineno,
                format!("expected {} fields, found {}", cols.len(), fields.len()),
            ));
        }
        let num = |c: usize, what: &str| -> Result<f64, (usize, String)> {
            let f = fields[c];
            let v: f64 = f
                .parse()
                .map_err(|_| (lineno, format!("{what} {:?} is not a number", clip(f))))?;
            if !v.is_finite() {
                return Err((
                    lineno,
                    format!("{what} is {} (must be a finite number)", clip(f)),
                ));
            }
            Ok(v)
        };
        let (x, y) = (num(cx, "x_um")?, num(cy, "y_um")?);
        let ix = g.x.index_of(x).ok_or_else(|| {
            (
                lineno,
                format!("x {x} µm is not on the grid {} (tolerance 1e-6 µm)", g.x),
            )
        })?;
        let iy = g.y.index_of(y).ok_or_else(|| {
            (
                lineno,
                format!("y {y} µm is not on the grid {} (tolerance 1e-6 µm)", g.y),
            )
        })?;
        if let Some(first) = seen.insert((ix, iy), lineno) {
            return Err((
                lineno,
                format!("duplicate point ({x}, {y}) µm (first at line {first})"),
            ));
        }
        s.ix.push(ix);
        s.iy.push(iy);
        s.ex.push(num(cex, "ex_um")?);
        s.ey.push(num(cey, "ey_um")?);
        if let (Some(c), Some(t)) = (ct, s.theta.as_mut()) {
            t.push(num(c, "theta_urad")?);
        }
    }
    if s.len() < 3 {
        return Err((
            text.lines().count().max(1),
            format!("need at least 3 samples, found {}", s.len()),
        ));
    }
    Ok(s)
}

/// Writes the map with the samples' header at every grid point, x fastest.
/// With the band, `u_ex_um,u_ey_um` (k = 1) are appended as the last columns.
pub fn write_map(w: &mut impl std::io::Write, g: &Grid2, map: &Map) -> std::io::Result<()> {
    let band = map.u_ex.len() == map.ex.len() && map.u_ey.len() == map.ey.len();
    write!(w, "x_um,y_um,ex_um,ey_um")?;
    if map.theta.is_some() {
        write!(w, ",theta_urad")?;
    }
    if band {
        write!(w, ",u_ex_um,u_ey_um")?;
    }
    writeln!(w)?;
    for j in 0..g.y.n {
        let y = g.y.position(j);
        for i in 0..g.x.n {
            let k = j * g.x.n + i;
            let x = g.x.position(i);
            write!(w, "{x},{y},{},{}", map.ex[k], map.ey[k])?;
            if let Some(t) = &map.theta {
                write!(w, ",{}", t[k])?;
            }
            if band {
                write!(w, ",{},{}", map.u_ex[k], map.u_ey[k])?;
            }
            writeln!(w)?;
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn grid() -> Grid2 {
        Grid2::new("0:5:50".parse().unwrap(), "0:5:20".parse().unwrap()).unwrap()
    }

    #[test]
    fn parses_columns_in_any_order_with_theta() {
        let t = "y_um,x_um,ex_um,ey_um,theta_urad\n5,10,0.1,0.2,3\n20,50,1,2,4\n0,0,0,0,0\n";
        let s = parse_map_samples_csv(t, &grid()).unwrap();
        assert_eq!(s.ix, vec![2, 10, 0]);
        assert_eq!(s.iy, vec![1, 4, 0]);
        assert_eq!(s.ey, vec![0.2, 2.0, 0.0]);
        assert_eq!(s.theta, Some(vec![3.0, 4.0, 0.0]));
    }

    #[test]
    fn bad_rows_name_their_line() {
        let head = "x_um,y_um,ex_um,ey_um\n0,0,0,0\n5,5,0,0\n";
        for (row, want) in [
            ("7,0,0,0", "not on the grid"),
            ("0,25,0,0", "not on the grid"),
            ("10,0,NaN,0", "finite"),
            ("10,0,abc,0", "not a number"),
            ("10,0,0", "expected 4 fields"),
            ("5,5,1,1", "duplicate point (5, 5) µm (first at line 3)"),
        ] {
            let (line, msg) =
                parse_map_samples_csv(&format!("{head}{row}\n"), &grid()).unwrap_err();
            assert_eq!(line, 4, "{row}: {msg}");
            assert!(msg.contains(want), "{row}: {msg}");
        }
        let (line, msg) =
            parse_map_samples_csv("position_um,error_um\n0,0\n", &grid()).unwrap_err();
        assert_eq!(line, 1);
        assert!(msg.contains("missing header"), "{msg}");
    }

    #[test]
    fn samples_on_a_line_or_in_a_corner_do_not_span_the_grid() {
        let g = Grid2::new(
            Grid {
                start_um: 0.0,
                step_um: 10.0,
                n: 101,
            },
            Grid {
                start_um: 0.0,
                step_um: 10.0,
                n: 51,
            },
        )
        .unwrap();
        let at = |pts: &[(usize, usize)]| MapSamples {
            ix: pts.iter().map(|p| p.0).collect(),
            iy: pts.iter().map(|p| p.1).collect(),
            ex: vec![0.0; pts.len()],
            ey: vec![0.0; pts.len()],
            theta: None,
        };
        let diag: Vec<(usize, usize)> = (0..50).map(|k| (k, k)).collect();
        let e = coverage(&g, &at(&diag)).unwrap_err();
        assert!(
            e.contains("on one line, from (0, 0) to (490, 490) µm"),
            "{e}"
        );
        let corner: Vec<(usize, usize)> =
            (0..20).flat_map(|i| (0..10).map(move |j| (i, j))).collect();
        let e = coverage(&g, &at(&corner)).unwrap_err();
        assert!(e.contains("cover 3.4 % of the grid"), "{e}");
        // The four corners and the centre: the whole grid.
        let f = coverage(&g, &at(&[(0, 0), (100, 0), (0, 50), (100, 50), (50, 25)])).unwrap();
        assert!((f - 1.0).abs() < 1e-12, "{f}");
        // A triangle over half of it.
        let f = coverage(&g, &at(&[(0, 0), (100, 0), (0, 50)])).unwrap();
        assert!((f - 0.5).abs() < 1e-12, "{f}");
    }

    #[test]
    fn the_distance_transform_matches_brute_force() {
        let g = Grid2::new("0:5:60".parse().unwrap(), "0:2:30".parse().unwrap()).unwrap();
        let (ix, iy) = (vec![0, 7, 12, 3], vec![2, 15, 0, 9]);
        let d = nearest_sample_distance(&g, &ix, &iy);
        for j in 0..g.y.n {
            for i in 0..g.x.n {
                let want = ix
                    .iter()
                    .zip(&iy)
                    .map(|(&a, &b)| {
                        (5.0 * (i as f64 - a as f64)).hypot(2.0 * (j as f64 - b as f64))
                    })
                    .fold(f64::INFINITY, f64::min);
                assert!((d[j * g.x.n + i] - want).abs() < 1e-9, "({i}, {j})");
            }
        }
        assert!(nearest_sample_distance(&g, &[], &[])[0].is_infinite());
    }

    #[test]
    fn map_grids_are_bounded() {
        let x: Grid = "0:1:99999".parse().unwrap();
        let y: Grid = "0:1:99".parse().unwrap();
        assert!(Grid2::new(x, y).unwrap_err().contains("more than 4000000"));
        let y: Grid = "0:1:39".parse().unwrap();
        assert_eq!(Grid2::new(x, y).unwrap().len(), 4_000_000);
    }
}
