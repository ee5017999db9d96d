//! Pointwise standard uncertainty of a reconstructed curve, from its own cross-validation.
//!
//! A curve's error at a grid point grows with the distance to the nearest sample: where
//! samples are dense the curve is pinned, across a gap it interpolates (a rough or local
//! feature between two samples is invisible). The cross-validation already predicts every
//! sample from folds that did not see it; each held-out residual comes with the distance from
//! its position to the nearest training sample of its fold. Those pairs calibrate u(d): the
//! residuals are binned by distance (equal counts), each bin's u is half a 95 % quantile of
//! |residual| (a ±2u band covers 95 % of them even when the errors are heavy-tailed, which a
//! Gaussian σ does not), u is made non-decreasing in d (pool adjacent violators), the sensor
//! noise each held-out residual carries is taken out, and every grid point gets u at its own
//! distance to the nearest sample of the whole design. Neighbouring bins that hold more noise
//! than curve error are read as one: taking σ out of a bin's quantile amplifies its sampling
//! error, and where the curve's error is about σ a bin of 33 reads below the noise by chance.
//!
//! Two regimes are told apart:
//! - off the samples (d > 0), the calibrated u(d) above. The bin's quantile is split-conformal
//!   with its finite-sample correction: of k exchangeable residuals the level is
//!   (k + ½)(1 − α)/k, not 1 − α (a bin of 33 residuals at m = 100 reads its 96.4 % point):
//!   the plain 95 % quantile of a few dozen residuals under-covered at small m (0.87–0.92 per
//!   family at m = 100 of 1,901 on the independent generator). The conservative rank
//!   ⌈(k + 1)(1 − α)⌉ guarantees ≥ 1 − α; its mid-point (k + ½) is the randomised conformal
//!   level, 1 − α on average, which the target (coverage 0.93–0.97 on average) asks
//!   for: (k + 1) widened the band on step-and-defect curves to 3.4 times their mean error;
//! - at the samples themselves (d = 0: half the grid at m = 900 of 1,901) the curve is not
//!   predicted but fitted, and no held-out residual is that close. Its error there is the
//!   noise the fit kept and its bias, √(rms(g − y)² − σ² + 2σ² df/m) (Stein's unbiased risk
//!   estimate; σ for a curve through its samples), at least the nearest bin's u and at most
//!   √(σ² + (q₉₅|g − y|/2)²) (see `at_samples`). Before, the
//!   grid's sample points took the first bin's u (held-out residuals
//!   1–2 steps away, noise and all): 2–300 times the curve's actual miss there, which made the
//!   band 3–4.5 times the mean error at m = 900 and on rough curves.
//!
//! Where along the travel matters as well: a step or a narrow defect the model cannot hold
//! makes the held-out residuals about it large, and a band of the distance alone spreads that
//! error over the whole curve (too wide away from it, too narrow on it: 0.64 of one stretch of
//! tests/gp/compare_gp.py's step-and-defect curve covered, seed 0). Off the samples u is scaled
//! by [`LocalScale`], the held-out residuals' mean square about the position (the nearest 25th
//! of them, each over the distance curve's u at its own distance, shrunk towards 1 by as much as
//! the windows vary beyond their own sampling error, see [`prior_weight`]) — normalised
//! split-conformal: the distance curve is calibrated on the residuals divided by their scale
//! from the others about them, so the whole still covers at its level. That curve: 0.880 → 0.939.
//! The scale multiplies the residuals' size, noise included, and the noise, the same all along,
//! is taken out after it: a bias on part of the travel under noise is then read there at its
//! size, not as a share of the travel's rms (see [`DistanceCurve::local`]); a window's largest
//! square counts at most χ²₁'s 99 % point times the others' mean there, so one impulse or step
//! does not widen its whole window.
//!
//! A step or a sharp flank between two samples is the extreme of this: the interpolant's error
//! is up to the step's height in that one gap and small beside it, but a window of held-out
//! residuals holds the step and widens the band around it on both sides (the sawtooth and
//! square wave of tests/gp/band_variants.py: 2u 4–6 times their mean error). The samples tell
//! which gap: its jump departs from both neighbouring gaps' slopes ([`gap_departure`]) by far
//! more than a typical gap's. Held-out residuals in such gaps of their fold are left out of the
//! calibration and the band in such a gap of the design is at least half its departure for an
//! interpolant (its transition spans the gap wherever the step is in it; the held-out
//! residuals, at samples, read it only part way), and the held-out residuals' share of the
//! departure for a fit that places the step by its model (a period's flank); that band is used
//! when it scores better on the held-out residuals (interval score) than the one of all
//! residuals (square wave m = 600, pchip: sharpness 4.97 → 2.71; sawtooth m = 300, physics:
//! 4.18 → 2.89; coverage 0.951 → 0.970 and 0.941 → 0.962).
//! Off the samples u is also at least 1/√2 of u at the samples: a curve carries the noise it
//! kept at its samples between them too.
//!
//! Where the curve is linear in its samples and that map is known (the physics model: ridge
//! least squares and the residual's smoother, g = S y), the sensor noise's part of its error is not
//! estimated but computed, σ²‖S_x‖² at every grid point
//! ([`crate::recon::physics::Fitted::noise_variance`]), and the held-out residuals are read for
//! the bias alone (see [`FitNoise`]): u² = σ²‖S_x‖² + b².
//! The floors that guarded the ill-conditioned noise subtraction (a third of the quantile, 1/√2
//! of u at the samples) then go: where the model fits they held the band at about twice its
//! error.
//!
//! Which candidate `auto` picked is itself uncertain when the candidates' cross-validated errors
//! are close: [`choice_weight`] and [`choice_variance`] add the spread between the chosen curve
//! and the close candidates' curves, weighted by how likely each is the better predictor.

/// Smallest residual count per distance bin (a 95 % quantile of fewer is mostly noise).
const PER_BIN: usize = 30;
/// Most bins.
const MAX_BINS: usize = 6;
/// The bin quantile whose half is u (so 2u covers it): 1 − α before the finite-sample
/// correction.
const QUANTILE: f64 = 0.95;
/// Alternatives of `auto` weighing less than this in the model-choice term are left out (their
/// curve is not computed).
pub const MIN_CHOICE_WEIGHT: f64 = 0.01;

/// One held-out sample of a curve's cross-validation.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Residual {
    /// Distance to the nearest training sample of its fold (µm).
    pub d: f64,
    /// The prediction by the fold that left it out − the sample (µm).
    pub r: f64,
    /// Its position (µm).
    pub x: f64,
    /// [`gap_departure`] of the gap of its fold's training samples it sits in (µm; NaN: not
    /// known).
    pub gap: f64,
}

/// χ² quantile with `dof` degrees of freedom at the normal quantile `z` (Wilson–Hilferty: within
/// 1 % of the exact value from 3 degrees of freedom up; `z` = 1.645 is the 95 % point, −1.645
/// the 5 %).
pub fn chi2_quantile(dof: f64, z: f64) -> f64 {
    let a = 2.0 / (9.0 * dof);
    dof * (1.0 - a + z * a.sqrt()).max(0.0).powi(3)
}

/// u (µm, k = 1) at every grid point: `sample_pos` the design's positions (µm, ascending),
/// `grid_pos` the grid's, `sample_val` the samples' values (µm; empty: the step gaps below are
/// not looked for), `misfit` the curve's |g − y| at the samples (empty: not known, the
/// sample points then take the off-sample u at distance 0), `cv` the held-out residuals,
/// `noise_um` the sensor noise σ the residuals carry, `noise_var` the variance that noise alone
/// gives the curve at each grid point (µm², a method linear in its samples; empty: not known,
/// see [`FitNoise`]). Empty without residuals.
pub fn pointwise_u(
    grid_pos: &[f64],
    sample_pos: &[f64],
    sample_val: &[f64],
    misfit: &[f64],
    cv: &[Residual],
    noise_um: f64,
    noise_var: &[f64],
) -> Vec<f64> {
    if sample_pos.is_empty() {
        return Vec::new();
    }
    let cv: Vec<Residual> = cv
        .iter()
        .copied()
        .filter(|c| c.d.is_finite() && c.r.is_finite() && c.x.is_finite())
        .collect();
    let dist: Vec<f64> = grid_pos
        .iter()
        .map(|&p| nearest_distance(sample_pos, p))
        .collect();
    let fit_noise = FitNoise::new(noise_var, &dist);
    let band = |steps| band_with_gaps(&dist, grid_pos, misfit, &cv, noise_um, &fit_noise, steps);
    let (all, all_score) = band(None);
    // A gap whose jump departs from its neighbours' slopes by more than STEP_GAP times the
    // held-out residuals' median departure holds a step or a flank the samples bracket.
    let mut typical: Vec<f64> = cv.iter().map(|c| c.gap).filter(|g| g.is_finite()).collect();
    typical.sort_by(f64::total_cmp);
    if sample_val.len() != sample_pos.len() || typical.len() < 2 * LOCAL_K_MIN {
        return all;
    }
    let threshold = STEP_GAP * quantile(&typical, 0.5);
    let gaps: Vec<f64> = grid_pos
        .iter()
        .map(|&p| gap_feature(sample_pos, sample_val, p))
        .collect();
    // Without a step gap among the residuals or on the grid the step band is this one.
    if threshold <= 0.0 || !typical.iter().chain(&gaps).any(|&g| g > threshold) {
        return all;
    }
    let ms = misfit.iter().map(|v| v * v).sum::<f64>() / misfit.len().max(1) as f64;
    let steps = Steps {
        through: misfit.is_empty() || ms.sqrt() <= THROUGH * noise_um,
        threshold,
        grid_gap: &gaps,
    };
    let (stepped, score) = band(Some(&steps));
    if score < GAP_GAIN * all_score {
        stepped
    } else {
        all
    }
}

/// The noise's own part of the curve's error, where it is known. The held-out residuals'
/// quantile less the noise's share is an ill-conditioned difference where the curve's error is
/// below the noise: without more, the band keeps at least a third of the quantile there
/// ([`DENOISE_FLOOR`]; a σ set too high must not zero it), and off the samples at least 1/√2 of
/// u at them. Where a model fits, that was up to twice its error (tests/gp/band_fifth.py's two
/// periods at m = 300, seed 1, σ = 0.01 µm: u 0.0048 µm off the samples against an rms error of
/// 0.0028, 0.998 covered; σ‖S_x‖ there 0.0024).
/// A curve linear in its samples (g = S y, the physics model) carries the noise's variance
/// σ²‖S_x‖² at x, and its mean square error is that plus its bias². There u² = σ²‖S_x‖² + b²,
/// and the held-out residuals are read for the bias alone: their quantile less the sensor's
/// share and less their folds' own noise variance (the grid's at the same distance to the
/// nearest sample; a fold's, from fewer samples, is a little more, so b is if anything
/// overstated), at least 0 — σ²‖S_x‖² scales with σ, so a σ set too high does not zero the band.
/// A bias below the residuals' sampling error can read 0 (a sine of half σ the model misses:
/// tests/gp/band_fifth.py's faint sine at m = 100, one seed of five 0.69 covered); reading it
/// as its flat-prior posterior mean or as at least one standard error kept more such seeds
/// (lowest 0.83) but widened the curves a model fits by as much as the old floors (13–18 of 72
/// family-m cells of the third to fifth generators over 0.98, against 8 with the floors and 1
/// with this).
struct FitNoise {
    /// σ²‖S_x‖² at each grid point (µm²); empty: not known.
    var: Vec<f64>,
    /// The grid's mean of it by distance to the nearest sample (None: not known).
    by_distance: Option<DistanceCurve>,
}

/// Distance bins of the grid's noise variance (see [`FitNoise`]).
const VAR_BINS: usize = 20;

impl FitNoise {
    fn new(noise_var: &[f64], dist: &[f64]) -> Self {
        let known = !noise_var.is_empty()
            && noise_var.len() == dist.len()
            && noise_var.iter().all(|v| v.is_finite() && *v >= 0.0);
        if !known {
            return Self {
                var: Vec::new(),
                by_distance: None,
            };
        }
        let mut off: Vec<(f64, f64)> = dist
            .iter()
            .zip(noise_var)
            .filter(|(d, _)| **d > 0.0)
            .map(|(&d, &v)| (d, v))
            .collect();
        off.sort_by(|a, b| a.0.total_cmp(&b.0));
        let (mut d, mut u) = (Vec::new(), Vec::new());
        for part in equal_parts(&off, VAR_BINS.min(off.len())) {
            d.push(part.iter().map(|p| p.0).sum::<f64>() / part.len() as f64);
            u.push(part.iter().map(|p| p.1).sum::<f64>() / part.len() as f64);
        }
        Self {
            var: noise_var.to_vec(),
            by_distance: (!d.is_empty()).then(|| DistanceCurve::bare(d, u)),
        }
    }

    fn known(&self) -> bool {
        !self.var.is_empty()
    }

    /// The share of a bin's quantile its denoised u keeps at least.
    fn floor_share(&self) -> f64 {
        if self.known() {
            0.0
        } else {
            DENOISE_FLOOR
        }
    }

    /// A held-out residual's own noise variance from its fold's fit at distance `d` (µm²).
    fn fold_var(&self, d: f64) -> f64 {
        self.by_distance.as_ref().map_or(0.0, |c| c.at(d).max(0.0))
    }

    /// u at grid point `i` from its bias part `b` (µm).
    fn at(&self, i: usize, b: f64) -> f64 {
        self.var.get(i).map_or(b, |&v| (b * b + v).sqrt())
    }
}

/// The least share of a bin's quantile its denoised u keeps when the noise's variance along the
/// curve is not known (see [`FitNoise`]).
const DENOISE_FLOOR: f64 = 1.0 / 3.0;

/// Where the steps are (see [`band_with_gaps`]).
struct Steps<'a> {
    /// A gap whose departure is above this (µm) holds a step.
    threshold: f64,
    /// The departure of each grid point's gap (µm).
    grid_gap: &'a [f64],
    /// The curve passes through its samples (an interpolant): its transition spans the step's
    /// gap whatever the step's place in it.
    through: bool,
}

/// A gap holds a step when its departure is this many times the held-out residuals' median
/// one (well beyond the noise's own spread in it; chosen once, not tuned).
const STEP_GAP: f64 = 10.0;
/// A curve that misses its samples by at most this share of the noise σ (rms) passes through
/// them.
const THROUGH: f64 = 0.1;
/// Fewest held-out residuals in step gaps whose ratio to the departure calibrates the band
/// there (a fit that is not an interpolant).
const STEP_RESIDUALS: usize = 10;
/// The step gaps' band is taken only when its interval score is lower by more than this
/// factor's complement.
const GAP_GAIN: f64 = 0.95;

/// [`pointwise_u`]'s band and its interval score on the held-out residuals (mean of
/// 2·2u + (2/α)·miss, each residual against the band from the others about it). With `steps`,
/// the residuals in step gaps are left out of the calibration and 2u in a step gap of the grid
/// is at least its departure for an interpolant — it covers a step anywhere in the gap, where
/// the held-out residuals, at samples, read the transition only part way (95 % of them within
/// 0.70 of the departure against 1.0 for the grid's points, square wave m = 300) — and the
/// step residuals' conformal share of it for a model fit.
fn band_with_gaps(
    dist: &[f64],
    grid_pos: &[f64],
    misfit: &[f64],
    cv: &[Residual],
    noise_um: f64,
    fit_noise: &FitNoise,
    steps: Option<&Steps<'_>>,
) -> (Vec<f64>, f64) {
    let is_step = |c: &Residual| steps.is_some_and(|s| c.gap > s.threshold);
    let kept: Vec<Residual> = cv.iter().filter(|c| !is_step(c)).copied().collect();
    let local = LocalScale::new(&kept);
    // Each residual over its local scale, with the noise it carries on the same scale: the
    // sensor's and, where known, its fold's own (taking σ itself out of r/l left the noise's
    // E[1/l²] share in: ~7 % of σ² with windows of 12 noise-dominated residuals, which read as
    // a curve error of a quarter of σ where a model fits).
    // Each kept residual's scale from the others about it (a window walk each: once, for the
    // calibration and the score below).
    let scales: Vec<f64> = (0..kept.len())
        .map(|k| local.as_ref().map_or(1.0, |l| l.left_out(k)))
        .collect();
    let scaled: Vec<(f64, f64, f64, f64)> = kept
        .iter()
        .zip(&scales)
        .map(|(c, &l)| {
            let noise = noise_um * noise_um + fit_noise.fold_var(c.d);
            (c.d, c.r / l, noise / (l * l), noise)
        })
        .collect();
    let pairs: Vec<(f64, f64)> = scaled.iter().map(|&(d, r, _, _)| (d, r)).collect();
    let Some(curve) = DistanceCurve::calibrate_with(scaled, fit_noise.floor_share()) else {
        return (Vec::new(), f64::INFINITY);
    };
    // A fit that is not an interpolant places a step where its model does (a period's
    // flank): its held-out residuals in step gaps tell how much of the departure it misses.
    let step_ratio = match steps {
        Some(s) if !s.through => {
            let mut ratio: Vec<f64> = cv
                .iter()
                .filter(|c| is_step(c))
                .map(|c| c.r.abs() / c.gap)
                .collect();
            ratio.sort_by(f64::total_cmp);
            if ratio.len() >= STEP_RESIDUALS {
                quantile(&ratio, conformal_level(ratio.len() as f64)).min(1.0)
            } else {
                1.0
            }
        }
        _ => 1.0,
    };
    let score = DistanceCurve::calibrate(&pairs, 0.0, DENOISE_FLOOR).map_or(f64::INFINITY, |raw| {
        let mut k = 0;
        let total: f64 = cv
            .iter()
            .map(|c| {
                let half = if is_step(c) {
                    let l = local.as_ref().map_or(1.0, |l| l.at(c.x));
                    (2.0 * raw.at(c.d) * l).hypot(step_ratio * c.gap)
                } else {
                    k += 1;
                    2.0 * raw.at(c.d) * scales[k - 1]
                };
                2.0 * half + 2.0 / (1.0 - QUANTILE) * (c.r.abs() - half).max(0.0)
            })
            .sum();
        total / cv.len().max(1) as f64
    });
    let rms_r = (kept.iter().map(|c| c.r * c.r).sum::<f64>() / kept.len().max(1) as f64).sqrt();
    let at_sample = at_samples(misfit, noise_um, curve.u[0], rms_r);
    // The noise the curve kept at its samples is between them too: with the weights (1 − t, t)
    // of two samples at least half its variance (below it, 0.899 of the third generator's
    // 0.02 µm cycle under 0.01 µm noise was covered at m = 100, 0.949 with it).
    // (Where the noise's variance along the curve is known, it is that part exactly.)
    let between = if fit_noise.known() {
        0.0
    } else {
        at_sample.unwrap_or(0.0) * std::f64::consts::FRAC_1_SQRT_2
    };
    // The scale multiplies the residuals' size, noise and all, and the noise is taken out after
    // it (see `DistanceCurve::local`). Tried before the windows' prior weight came from the
    // data, that made chance dips of the scale zero the band (tests/gp/compare_gp.py's step
    // and defect curve, seed 0, 0.872 off its samples); with it and the capped squares, 0.952.
    let u = grid_pos
        .iter()
        .zip(dist)
        .enumerate()
        .map(|(i, (&p, &d))| {
            let base = match (at_sample, &local) {
                (Some(u0), _) if d == 0.0 => return u0.max(fit_noise.at(i, 0.0)),
                (_, Some(l)) => curve.local(d, l.capped(p), fit_noise.floor_share()),
                _ => curve.at(d),
            }
            .max(between);
            let base = fit_noise.at(i, base);
            match steps {
                Some(s) if s.grid_gap[i] > s.threshold => {
                    base.hypot(step_ratio * s.grid_gap[i] / 2.0)
                }
                _ => base,
            }
        })
        .collect();
    (u, score)
}

/// How far the jump across a gap (`l1` to `r1`, each (position µm, value µm)) departs from what
/// the neighbouring gap's slope predicts, the smaller of the two sides' (`l2`, `r2` the next
/// samples out; NaN with neither). A step or a sharp flank the samples bracket makes it the
/// step's height in that gap alone (its neighbours each have one side that agrees); on a smooth
/// curve it is about the curvature times the gap squared, as an interpolant's error.
pub fn gap_departure(
    l2: Option<(f64, f64)>,
    l1: (f64, f64),
    r1: (f64, f64),
    r2: Option<(f64, f64)>,
) -> f64 {
    let h = r1.0 - l1.0;
    let jump = r1.1 - l1.1;
    let side = |a: (f64, f64), b: (f64, f64)| {
        let w = b.0 - a.0;
        (w > 0.0).then(|| (jump - (b.1 - a.1) / w * h).abs())
    };
    match (l2.and_then(|a| side(a, l1)), r2.and_then(|b| side(r1, b))) {
        (Some(a), Some(b)) => a.min(b),
        (Some(a), None) | (None, Some(a)) => a,
        (None, None) => f64::NAN,
    }
}

/// [`gap_departure`] of the gap of the ascending `xs` (values `ys`) that holds `p` (the end gap
/// beyond the ends; NaN with fewer than three samples).
pub fn gap_feature(xs: &[f64], ys: &[f64], p: f64) -> f64 {
    if ys.len() != xs.len() {
        return f64::NAN;
    }
    gap_at(xs.len(), xs.partition_point(|&q| q < p), |k| (xs[k], ys[k]))
}

/// [`gap_departure`] of the gap before index `insert` (where a position would insert; the end
/// gap beyond the ends) of `n` ascending samples, `at(k)` sample k's (position µm, value µm);
/// NaN with fewer than three.
pub fn gap_at(n: usize, insert: usize, at: impl Fn(usize) -> (f64, f64)) -> f64 {
    if n < 3 {
        return f64::NAN;
    }
    let i = insert.clamp(1, n - 1);
    gap_departure(
        (i >= 2).then(|| at(i - 2)),
        at(i - 1),
        at(i),
        (i + 1 < n).then(|| at(i + 1)),
    )
}

/// Held-out residuals per window of [`LocalScale`]: a 25th of them, between these. At m = 600
/// on the GP script's curves windows of 16–40 gave the same coverage (0.960–0.962 over its 12
/// curves) and 12 lost the step-and-defect curve's gain; at m = 300 on `bench families`' steps
/// 24 widened the band (sharpness 3.29 on the system test's two seeds against 3.14 with 12).
const LOCAL_K_MIN: usize = 12;
const LOCAL_K_MAX: usize = 48;
/// The share of the residuals in a window.
const LOCAL_SHARE: usize = 25;

/// How much larger or smaller the held-out residuals are about a position than over the whole
/// travel, at the same distance to the nearest sample (see the module's notes). Below 48
/// residuals there is none (a window would be a quarter of the travel or more).
struct LocalScale {
    /// Held-out positions, ascending, and the square of each residual over the distance curve's
    /// raw u at its distance (the global mean of these is 1).
    x: Vec<f64>,
    s2: Vec<f64>,
    /// Index into `x` of each residual of the input order.
    rank: Vec<usize>,
    /// Residuals per window.
    k: usize,
    /// The prior's weight at the mean square 1, in residuals (see [`prior_weight`]).
    kappa: f64,
}

impl LocalScale {
    fn new(cv: &[Residual]) -> Option<Self> {
        let k = (cv.len() / LOCAL_SHARE).clamp(LOCAL_K_MIN, LOCAL_K_MAX);
        if cv.len() < 4 * k {
            return None;
        }
        let pairs: Vec<(f64, f64)> = cv.iter().map(|c| (c.d, c.r)).collect();
        let raw = DistanceCurve::calibrate(&pairs, 0.0, DENOISE_FLOOR)?;
        let mut order: Vec<usize> = (0..cv.len()).collect();
        order.sort_by(|&a, &b| cv[a].x.total_cmp(&cv[b].x));
        let mut rank = vec![0; cv.len()];
        for (i, &o) in order.iter().enumerate() {
            rank[o] = i;
        }
        let mut s2: Vec<f64> = order
            .iter()
            .map(|&o| {
                let q = raw.at(cv[o].d);
                if q > 0.0 {
                    (cv[o].r / q).powi(2)
                } else {
                    0.0
                }
            })
            .collect();
        let mean = s2.iter().sum::<f64>() / s2.len() as f64;
        if !(mean > 0.0 && mean.is_finite()) {
            return None;
        }
        s2.iter_mut().for_each(|v| *v /= mean);
        let kappa = prior_weight(&s2, k);
        Some(Self {
            x: order.iter().map(|&o| cv[o].x).collect(),
            s2,
            rank,
            k,
            kappa,
        })
    }

    /// The scale at position `p`: the root of the mean square of the `k` nearest residuals,
    /// shrunk towards 1 with the weight of `kappa` residuals (none at all: 1).
    fn at(&self, p: f64) -> f64 {
        self.window(self.x.partition_point(|&q| q < p), p, None).0
    }

    /// [`Self::at`] with each square in the window at most [`CAPPED`]: the scale of the band
    /// off the samples (see [`DistanceCurve::local`]).
    fn capped(&self, p: f64) -> f64 {
        self.window(self.x.partition_point(|&q| q < p), p, None).1
    }

    /// The scale at residual `k`'s position from the others (its own square would pull the
    /// scale towards itself, and the calibration would read the band as covering it).
    fn left_out(&self, k: usize) -> f64 {
        let i = self.rank[k];
        self.window(i, self.x[i], Some(i)).0
    }

    /// [`Self::at`] and [`Self::capped`] from the residuals nearest to `p` (`i`: where `p`
    /// would insert in `x`), `skip` left out.
    fn window(&self, i: usize, p: f64, skip: Option<usize>) -> (f64, f64) {
        if self.kappa.is_infinite() {
            return (1.0, 1.0);
        }
        let n = self.x.len();
        let (mut lo, mut hi) = (i, i); // the window is [lo, hi)
        let (mut sum, mut taken) = (0.0, 0usize);
        let mut largest = 0.0f64;
        while taken < self.k {
            if lo > 0 && Some(lo - 1) == skip {
                lo -= 1;
                continue;
            }
            if hi < n && Some(hi) == skip {
                hi += 1;
                continue;
            }
            let left = if lo > 0 {
                p - self.x[lo - 1]
            } else {
                f64::INFINITY
            };
            let right = if hi < n {
                self.x[hi] - p
            } else {
                f64::INFINITY
            };
            let j = if lo > 0 && left <= right {
                lo -= 1;
                lo
            } else if hi < n {
                hi += 1;
                hi - 1
            } else {
                break;
            };
            sum += self.s2[j];
            largest = largest.max(self.s2[j]);
            taken += 1;
        }
        let shrunk = |s: f64| ((s + self.kappa) / (taken as f64 + self.kappa)).sqrt();
        let others = (sum - largest) / (taken.max(2) - 1) as f64;
        let capped = sum - largest + largest.min(CAPPED * others);
        (shrunk(sum), shrunk(capped))
    }
}

/// The largest square of a window counts at most this many times the others' mean in the
/// capped scale: χ²₁'s 99 % point, so one residual far beyond the rest (a step, an impulse
/// narrower than the samples' spacing) does not read as an error all over its window.
const CAPPED: f64 = 6.63;

/// The local scale's prior weight (in residuals at the mean square 1) from how much the
/// windows' mean squares `s2` (along the travel, global mean 1) vary beyond their own sampling
/// error: empirical Bayes, a window's mean of k Gaussian residuals' squares has variance 2/k
/// about its true scale, which varies as τ² = var(window means) − 2/k; the window then weighs
/// τ²/(τ² + 2/k) and the prior 2/τ² residuals, at least `k`/2 (the fixed weight before). Where
/// the residuals are exchangeable (noise, or a bias the same all along) τ² is about 0 and the
/// scale stays near 1: with the fixed weight its windows' chance clusters moved the band's
/// bias part by ±40 % between arrangements of the same residuals.
fn prior_weight(s2: &[f64], k: usize) -> f64 {
    let means: Vec<f64> = s2
        .chunks_exact(k)
        .map(|w| w.iter().sum::<f64>() / k as f64)
        .collect();
    let floor = k as f64 / 2.0;
    if means.len() < 2 {
        return floor;
    }
    let var = means.iter().map(|m| (m - 1.0).powi(2)).sum::<f64>() / (means.len() - 1) as f64;
    let chance = 2.0 / k as f64;
    let tau2 = var - chance;
    // Only a spread chance would rarely give counts (one-sided 95 %, var ~ chance·χ²/dof):
    // the band takes the noise out after the scale, which multiplies a chance scale's error
    // by the noise-to-bias ratio (5 of 12 orders of the same exchangeable residuals read a
    // bias from half to 1.5 times its size along the travel without this).
    let dof = (means.len() - 1) as f64;
    if var > chance * (1.0 + 1.645 * (2.0 / dof).sqrt()) {
        (2.0 / tau2).max(floor)
    } else {
        f64::INFINITY
    }
}

/// u (µm, k = 1) at the given distances to the nearest sample from the `cv` pairs (the 2D maps'
/// band: no sample regime apart, the map's miss at its samples is not kept). Empty without
/// residuals.
pub fn u_at_distances(dist: &[f64], cv: &[(f64, f64)], noise_um: f64) -> Vec<f64> {
    match DistanceCurve::calibrate(cv, noise_um, DENOISE_FLOOR) {
        Some(curve) => dist.iter().map(|&d| curve.at(d)).collect(),
        None => Vec::new(),
    }
}

/// One held-out sample of a 2D map with the fitted model's noise reference at it (see
/// [`u_at_distances_denoised`]).
#[derive(Debug, Clone, Copy)]
pub struct HeldOut {
    /// Distance to the nearest training sample of its fold (µm).
    pub d: f64,
    /// Held-out residual: the prediction by the fold that left it out − the sample (µm).
    pub r: f64,
    /// A noise proxy there (µm) that shares the sample's noise draw: for the physics model its
    /// in-sample residual less its neighbours' (recon2d::physics::NoiseReference).
    pub noise: f64,
    /// The proxy's expected square over the noise variance.
    pub noise_var: f64,
    /// The fit's own noise-induced variance there over the noise variance, (H²)_kk.
    pub fit_var: f64,
    /// Its cell of the plane (see [`Cells`]).
    pub cell: usize,
}

/// A coarse partition of the map's plane for the band's local excess: `nx` × `ny` cells, the cell
/// of every grid point (`grid`, the same order as the distances asked for).
pub struct Cells<'a> {
    pub nx: usize,
    pub ny: usize,
    pub grid: &'a [usize],
}

/// u (µm, k = 1) at the given distances to the nearest sample, for a map whose model is a linear
/// smoother: its held-out residuals are mostly the sensor noise (the fit averages the noise of
/// thousands of samples down to a fraction of it), so the band is the excess of their mean square
/// over the noise, with the noise estimated from the same samples' in-sample residuals.
///
/// Per distance bin (equal counts, as [`pointwise_u`]): σ² = Σ r_in² / Σ ((I − H)²)_kk (the
/// residual variance with the fit's degrees of freedom taken out, E r_in² = σ²((I − H)²)_kk
/// without bias), the map's squared error e² = mean r² − σ² (E r² = e² + σ², the held-out
/// prediction being independent of the held-out sample's noise). Both sums run over the same
/// samples, so their noise draws largely cancel (a bin's mean square carries ~3 % sampling noise,
/// the size of e² itself at 2 % sampled). The held-out fits' extra noise-induced variance
/// (trained on (folds − 1)/folds of the samples) is taken out as well. e² is at least the fit's
/// own noise-induced variance σ²·mean (H²)_kk, which the map carries whatever its bias (this floor
/// keeps a bias in the in-sample residuals, which inflates σ², from zeroing the band), and the
/// excess over that floor is shrunk by its sampling error ([`shrunk_mean`]). u is e
/// times the bin's tail shape, its split-conformal quantile of |r| at level (k + ½)·0.95/k over
/// 2·rms(r) (≈ 1 for Gaussian residuals, more for heavy tails; the curves' band reads the same
/// quantile). Then non-decreasing in d. Empty without residuals.
///
/// With `cells`, the excess over the noise floor varies over the plane: each
/// held-out sample's excess (r² less its bin's noise share, refit and floor) is summed per cell;
/// a cell's excess is its 3 × 3 block's mean, shrunk by its sampling error as the bins' are,
/// over the whole map's (shrunk alike); at a grid point u² = u_floor(d)² + (u(d)² − u_floor(d)²)
/// × that ratio of its cell. A map whose excess is within the noise as a whole (the rough stage)
/// keeps the band of the distance alone.
pub fn u_at_distances_denoised(
    dist: &[f64],
    held: &[HeldOut],
    folds: usize,
    cells: Option<&Cells<'_>>,
) -> Vec<f64> {
    let mut h: Vec<HeldOut> = held
        .iter()
        .copied()
        .filter(|h| {
            [h.d, h.r, h.noise, h.noise_var, h.fit_var]
                .iter()
                .all(|v| v.is_finite())
        })
        .collect();
    if h.len() < 2 {
        return Vec::new();
    }
    h.sort_by(|a, b| a.d.total_cmp(&b.d));
    let (mut d, mut u, mut w) = (Vec::new(), Vec::new(), Vec::new());
    let (mut u_floor, mut per_sample) = (Vec::new(), Vec::new());
    for part in equal_bins(&h) {
        let k = part.len() as f64;
        let ms = part.iter().map(|p| p.r * p.r).sum::<f64>() / k;
        let dof = part.iter().map(|p| p.noise_var).sum::<f64>();
        let sigma2 = if dof > 0.0 {
            part.iter().map(|p| p.noise * p.noise).sum::<f64>() / dof
        } else {
            0.0
        };
        let floor = sigma2 * part.iter().map(|p| p.fit_var.max(0.0)).sum::<f64>() / k;
        // The held-out fit saw (folds − 1)/folds of the samples: its noise-induced variance is
        // the map's times folds/(folds − 1) (a fixed basis: variance ∝ 1/m); the excess is not
        // the map's.
        let refit = floor / (folds.max(2) - 1) as f64;
        // The excess over the floor is a difference of two mean squares of ~σ² each: its sampling
        // error (se, from the per-sample terms r² − noise²·k/dof) can be larger than the excess
        // itself, ~2·10⁻⁶ µm² on a 1,600-residual bin of the rough stage against an error of
        // ~10⁻⁶. Taken as it came, the bins' upward excursions set the band (coverage 0.987,
        // sharpness 3.15 at 2 % sampled): it is shrunk by its positive-part James–Stein factor
        // (1 − se²/excess²)₊, which keeps an excess many se wide (a bump the model cannot hold:
        // 10⁻⁴ against se 10⁻⁵) and drops one within the noise.
        let scale = if dof > 0.0 { k / dof } else { 0.0 };
        // Per sample: r² less its share of the noise, the refit and the floor (their mean is
        // ms − σ² − refit − floor).
        let excess: Vec<f64> = part
            .iter()
            .map(|p| p.r * p.r - p.noise * p.noise * scale - refit - floor)
            .collect();
        let e2 = floor
            + shrunk_mean(
                excess.iter().sum(),
                excess.iter().map(|v| v * v).sum(),
                part.len(),
            );
        per_sample.extend(part.iter().map(|p| p.cell).zip(excess));
        let shape = if ms > 0.0 {
            half_quantile(part.iter().map(|p| p.r)).0 / ms.sqrt()
        } else {
            1.0
        };
        u_floor.push(shape * floor.sqrt());
        d.push(part.iter().map(|p| p.d).sum::<f64>() / k);
        u.push(shape * e2.sqrt());
        w.push(k);
    }
    let floor_curve = DistanceCurve::bare(d.clone(), non_decreasing(&u_floor, &w));
    let curve = DistanceCurve::bare(d, non_decreasing(&u, &w));
    let factor = cells.and_then(|c| local_excess(c, &per_sample));
    dist.iter()
        .enumerate()
        .map(|(i, &x)| {
            let u = curve.at(x);
            match (&factor, cells) {
                (Some(f), Some(c)) => {
                    let uf = floor_curve.at(x).min(u);
                    (uf * uf + (u * u - uf * uf) * f[c.grid[i]]).sqrt()
                }
                _ => u,
            }
        })
        .collect()
}

/// The mean of k values from their sum and sum of squares, shrunk by its sampling error: its
/// positive-part James–Stein factor (1 − se²/mean²)₊, se² their variance over k. A mean many se
/// above zero is kept, one within its noise is dropped; a negative one is 0.
fn shrunk_mean(sum: f64, sum_sq: f64, k: usize) -> f64 {
    if k < 2 {
        return 0.0;
    }
    let kf = k as f64;
    let mean = sum / kf;
    let se2 = ((sum_sq / kf - mean * mean) * kf / (kf - 1.0)).max(0.0) / kf;
    shrunk(mean, se2)
}

/// A positive estimate with sampling variance `se2`, shrunk by its positive-part James–Stein
/// factor (1 − se²/value²)₊; 0 when not positive.
pub(crate) fn shrunk(value: f64, se2: f64) -> f64 {
    if value > 0.0 {
        value * (1.0 - se2 / (value * value)).max(0.0)
    } else {
        0.0
    }
}

/// The least share of the whole map's excess a cell keeps: a block's shrunk excess reads nothing
/// where the error is small but not zero (free, one of six second surfaces in
/// tests/system/reconstruct2d_rough.rs had e_y 0.884 covered; at 0.1 all six 0.947–0.968, sharpness
/// 2.60–2.92; at 0.25 up to 3.04).
const MIN_CELL_SHARE: f64 = 0.1;

/// Per cell, the excess over the noise floor of the held-out samples in its 3 × 3 block of cells
/// over the whole map's, each shrunk by its sampling error; None when the whole map's is nothing.
fn local_excess(c: &Cells<'_>, per_sample: &[(usize, f64)]) -> Option<Vec<f64>> {
    let n = c.nx * c.ny;
    let (mut sum, mut sq, mut cnt) = (vec![0.0; n], vec![0.0; n], vec![0usize; n]);
    for &(cell, t) in per_sample {
        if cell < n {
            sum[cell] += t;
            sq[cell] += t * t;
            cnt[cell] += 1;
        }
    }
    let all = shrunk_mean(sum.iter().sum(), sq.iter().sum(), cnt.iter().sum());
    if all <= 0.0 {
        return None;
    }
    Some(
        (0..n)
            .map(|cell| {
                // The 3 × 3 block: the cell alone (~200 samples) read the second surface's bump
                // too sharply (coverage 0.911–0.931, sharpness 2.2–2.5): its error spills over.
                let (cx, cy) = (cell % c.nx, cell / c.nx);
                let (mut s, mut q, mut k) = (0.0, 0.0, 0);
                for y in cy.saturating_sub(1)..(cy + 2).min(c.ny) {
                    for x in cx.saturating_sub(1)..(cx + 2).min(c.nx) {
                        let j = y * c.nx + x;
                        s += sum[j];
                        q += sq[j];
                        k += cnt[j];
                    }
                }
                (shrunk_mean(s, q, k) / all).max(MIN_CELL_SHARE)
            })
            .collect(),
    )
}

/// u at the samples themselves. The curve's error there is its miss plus the sample's noise,
/// g − f = (g − y) + n. For a linear smoother g = Hy of bias b = (H − I)f, E |g − y|²/m = b² +
/// σ² tr((I − H)²)/m and E |g − f|²/m = b² + σ² tr(H²)/m, so E (g − f)² = E (g − y)² − σ² +
/// 2σ² tr(H)/m whatever the bias (Stein's unbiased risk estimate, Mallows' Cp): σ for a curve
/// through its samples (tr H = m), σ √(df/m) for a projection on df terms. The share h =
/// tr(H)/m is read from the held-out residuals: a held-out residual is its in-sample miss over
/// (1 − H_ii), so h ≈ 1 − rms(g − y)/rms(r) (`rms_r` of the held-out residuals; folds that
/// leave out more than one sample read it a little high, which widens u). Before, u₀ was
/// σ − rms(g − y), exact only without bias: a physics fit that misses a modulation keeps its
/// miss at its samples too (the fourth generator's envelope at m = 300, seed 3: u₀ 0.0026 µm
/// against an error of 0.0078 µm there, 0.70 of the samples covered; now 0.0079 µm, 0.97).
/// Kept between `near`, the nearest distance bin's u (capped there the sample points were
/// covered 0.76–0.83 of the time on physics fits, whose error at a sample is up to twice its
/// error one step away), and the miss and the noise in quadrature, √(σ² + (q₉₅|g − y|/2)²),
/// which bounds it whatever the fit.
fn at_samples(misfit: &[f64], noise_um: f64, near: f64, rms_r: f64) -> Option<f64> {
    let mut r: Vec<f64> = misfit
        .iter()
        .map(|v| v.abs())
        .filter(|v| v.is_finite())
        .collect();
    if r.is_empty() {
        return None;
    }
    let ms = r.iter().map(|v| v * v).sum::<f64>() / r.len() as f64;
    r.sort_by(f64::total_cmp);
    let sigma = noise_um.max(0.0);
    let s2 = sigma * sigma;
    let hi = (quantile(&r, QUANTILE) / 2.0).hypot(sigma);
    let lo = near.min(hi);
    let h = if rms_r > 0.0 {
        (1.0 - ms.sqrt() / rms_r).clamp(0.0, 1.0)
    } else {
        1.0
    };
    Some((ms - s2 + 2.0 * s2 * h).max(0.0).sqrt().clamp(lo, hi))
}

/// Weight of an alternative of `auto` in the model-choice term: the probability that it predicts
/// held-out samples better than the chosen one, from the paired differences of their absolute
/// held-out residuals (`chosen` and `alternative` fold by fold in the same order; an alternative
/// scored on fewer folds is compared on those): Φ(−z) with z the mean difference over its
/// standard error (a normal approximation of the cross-validation's own sampling noise, as
/// pseudo-BMA+ weights, Yao et al. 2018). 0.5 for a tie, ~0 for one clearly worse.
pub fn choice_weight(chosen: &[Residual], alternative: &[Residual]) -> f64 {
    let k = chosen.len().min(alternative.len());
    if k < 2 {
        return 0.0;
    }
    let d: Vec<f64> = chosen[..k]
        .iter()
        .zip(&alternative[..k])
        .map(|(c, a)| a.r.abs() - c.r.abs())
        .filter(|v| v.is_finite())
        .collect();
    let k = d.len() as f64;
    if k < 2.0 {
        return 0.0;
    }
    let mean = d.iter().sum::<f64>() / k;
    let var = d.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (k - 1.0);
    let se = (var / k).sqrt();
    if se <= 0.0 {
        // Identical predictions: the same curve, no spread to add.
        return 0.0;
    }
    normal_cdf(-mean / se)
}

/// The model-choice variance at every grid point (µm²): with the chosen curve weighing 1 and each
/// alternative `(w, curve)` its [`choice_weight`], the weighted mean of (g_alt − g)² over the
/// normalised weights: the mean squared distance from the chosen curve to a curve drawn from
/// that mixture of the candidates. Added to u² in quadrature. Empty without alternatives.
pub fn choice_variance(chosen: &[f64], alternatives: &[(f64, Vec<f64>)]) -> Vec<f64> {
    let alts: Vec<&(f64, Vec<f64>)> = alternatives
        .iter()
        .filter(|(w, g)| *w > 0.0 && g.len() == chosen.len())
        .collect();
    if alts.is_empty() {
        return Vec::new();
    }
    let total = 1.0 + alts.iter().map(|a| a.0).sum::<f64>();
    (0..chosen.len())
        .map(|i| {
            alts.iter()
                .map(|(w, g)| w * (g[i] - chosen[i]).powi(2))
                .sum::<f64>()
                / total
        })
        .collect()
}

/// Φ(x), the standard normal CDF (erfc by Numerical Recipes' Chebyshev fit, |ε| < 1.2e-7).
fn normal_cdf(x: f64) -> f64 {
    let z = (x / std::f64::consts::SQRT_2).abs();
    let t = 1.0 / (1.0 + 0.5 * z);
    let erfc = t
        * (-z * z - 1.265_512_23
            + t * (1.000_023_68
                + t * (0.374_091_96
                    + t * (0.096_784_18
                        + t * (-0.186_288_06
                            + t * (0.278_868_07
                                + t * (-1.135_203_98
                                    + t * (1.488_515_87
                                        + t * (-0.822_152_23 + t * 0.170_872_77)))))))))
            .exp();
    if x >= 0.0 {
        1.0 - 0.5 * erfc
    } else {
        0.5 * erfc
    }
}

/// Distance from `p` to the nearest of the ascending `xs`.
pub fn nearest_distance(xs: &[f64], p: f64) -> f64 {
    let i = xs.partition_point(|&q| q < p);
    let mut d = f64::INFINITY;
    if i < xs.len() {
        d = d.min(xs[i] - p);
    }
    if i > 0 {
        d = d.min(p - xs[i - 1]);
    }
    d
}

/// u as a function of the distance to the nearest sample: bin centres and values.
struct DistanceCurve {
    d: Vec<f64>,
    u: Vec<f64>,
    /// Per bin, the noise variance taken out of its quantile on the residuals' scale
    /// (`scaled`) and on the µm scale (`plain`), µm² (empty: not kept; see [`Self::local`]).
    scaled: Vec<f64>,
    plain: Vec<f64>,
}

impl DistanceCurve {
    /// A curve of u alone (no noise shares kept: [`Self::local`] then scales u).
    fn bare(d: Vec<f64>, u: Vec<f64>) -> Self {
        Self {
            d,
            u,
            scaled: Vec::new(),
            plain: Vec::new(),
        }
    }

    /// Linear between bin centres; the first bin's value below; beyond the last centre the
    /// last two bins' growth continues (a wide gap of a random design, where a local defect
    /// can hide, is where the curve is least known; held-out samples rarely sit that far).
    fn at(&self, d: f64) -> f64 {
        let (x, u) = (&self.d, &self.u);
        let k = x.len() - 1;
        // At the first centre its own value even where the next bin shares its centre
        // (distances are whole grid steps).
        if d <= x[0] {
            return u[0];
        }
        if d <= x[k] {
            return interpolate(x, u, d);
        }
        let slope = if k > 0 && x[k] > x[k - 1] {
            ((u[k] - u[k - 1]) / (x[k] - x[k - 1])).max(0.0)
        } else {
            0.0
        };
        u[k] + slope * (d - x[k])
    }

    /// u at distance `d` where the held-out residuals are `scale` times their size over the
    /// travel ([`LocalScale::capped`]): the scale multiplies what the residuals read, bias and
    /// noise together, and the noise, the same all along, is taken out after it. Scaling the
    /// band with the noise already out (before) read a bias that lives on part of the travel
    /// under noise too low there and too high elsewhere: a bias of 2σ on a fifth of the travel
    /// read 0.64σ there (see `a_bias_on_part_of_the_travel_is_read_there_not_spread`).
    /// `floor`: the least share of the scaled u kept (see [`FitNoise`]).
    fn local(&self, d: f64, scale: f64, floor: f64) -> f64 {
        let u = self.at(d);
        if self.scaled.len() != self.d.len() || self.plain.len() != self.d.len() {
            return u * scale;
        }
        let (ns, np) = (
            interpolate(&self.d, &self.scaled, d),
            interpolate(&self.d, &self.plain, d),
        );
        let b2 = scale * scale * (u * u + ns) - np;
        b2.max((floor * scale * u).powi(2)).max(0.0).sqrt()
    }
}

/// `v` (one per ascending `x`) at `d`: linear between, the end values beyond.
fn interpolate(x: &[f64], v: &[f64], d: f64) -> f64 {
    let i = x.partition_point(|&q| q <= d);
    if i == 0 {
        return v[0];
    }
    if i >= x.len() {
        return v[x.len() - 1];
    }
    let t = (d - x[i - 1]) / (x[i] - x[i - 1]);
    v[i - 1] + t * (v[i] - v[i - 1])
}

impl DistanceCurve {
    /// From the finite (distance, residual) pairs; None with fewer than 2.
    /// `floor`: the least share of a bin's quantile kept when the noise is taken out.
    fn calibrate(cv: &[(f64, f64)], noise_um: f64, floor: f64) -> Option<Self> {
        let noise2 = noise_um.max(0.0).powi(2);
        Self::calibrate_with(
            cv.iter().map(|&(d, r)| (d, r, noise2, noise2)).collect(),
            floor,
        )
    }

    /// [`Self::calibrate`] from (distance, residual, the noise variance it carries, µm², the
    /// same before the residual was scaled): the sensor's, and its fold's own where known (the
    /// curve is then the bias part alone, at least 0 with `floor` 0, see [`FitNoise`]).
    fn calibrate_with(mut cv: Vec<(f64, f64, f64, f64)>, floor: f64) -> Option<Self> {
        cv.retain(|&(d, r, v, p)| {
            d.is_finite() && r.is_finite() && v.is_finite() && v >= 0.0 && p.is_finite() && p >= 0.0
        });
        (cv.len() >= 2).then(|| distance_curve(cv, floor))
    }
}

fn distance_curve(mut cv: Vec<(f64, f64, f64, f64)>, floor: f64) -> DistanceCurve {
    cv.sort_by(|a, b| a.0.total_cmp(&b.0));
    let bins: Vec<&[(f64, f64, f64, f64)]> = equal_bins(&cv).collect();
    let raw: Vec<(f64, usize)> = bins
        .iter()
        .map(|b| half_quantile(b.iter().map(|p| p.1)))
        .collect();
    // A bin whose raw u is below √2 σ holds more noise than curve error: taking σ out more than
    // doubles its quantile's sampling error (a bin of 33 reading 0.0095 µm under σ = 0.01 µm
    // where the curve's error was 0.008: the band was its floor, a third). Such neighbours are
    // pooled, one quantile from all their residuals.
    // Each bin's summed noise variance (µm²).
    let noise: Vec<f64> = bins
        .iter()
        .map(|b| b.iter().map(|p| p.2).sum::<f64>())
        .collect();
    let noisy = |b: usize| raw[b].0 * raw[b].0 < 2.0 * noise[b] / bins[b].len().max(1) as f64;
    let plain: Vec<f64> = bins
        .iter()
        .map(|b| b.iter().map(|p| p.3).sum::<f64>())
        .collect();
    let order: Vec<usize> = (0..bins.len()).collect();
    let (mut d, mut u, mut w) = (Vec::new(), Vec::new(), Vec::new());
    let (mut taken_scaled, mut taken_plain) = (Vec::new(), Vec::new());
    for group in order.chunk_by(|&a, &b| noisy(a) && noisy(b)) {
        let (q, k) = match group {
            [b] => raw[*b],
            _ => half_quantile(group.iter().flat_map(|&b| bins[b].iter().map(|p| p.1))),
        };
        // The held-out residual is (curve error − the noise it carries); with its fold's own
        // noise known, the curve error's bias part.
        let v = group.iter().map(|&b| noise[b]).sum::<f64>();
        let sd = (v / k.max(1) as f64).sqrt();
        let level = conformal_level(k as f64);
        let clean = denoise(q, sd, level, floor);
        // The noise's share `denoise` takes out, on both scales (see `DistanceCurve::local`).
        let share = (noise_quantile(level) / 2.0).powi(2) / k.max(1) as f64;
        let vp = group.iter().map(|&b| plain[b]).sum::<f64>();
        for part in group.iter().map(|&b| bins[b]) {
            d.push(part.iter().map(|p| p.0).sum::<f64>() / part.len() as f64);
            u.push(clean);
            w.push(part.len() as f64);
            taken_scaled.push(share * v);
            taken_plain.push(share * vp);
        }
    }
    let u = non_decreasing(&u, &w);
    DistanceCurve {
        d,
        u,
        scaled: taken_scaled,
        plain: taken_plain,
    }
}

/// Half the split-conformal 95 % quantile of the residuals' magnitudes, and their count.
fn half_quantile(residuals: impl Iterator<Item = f64>) -> (f64, usize) {
    let mut r: Vec<f64> = residuals.map(f64::abs).collect();
    r.sort_by(f64::total_cmp);
    (quantile(&r, conformal_level(r.len() as f64)) / 2.0, r.len())
}

/// A held-out residuals' u `q` (µm, half their quantile at `level`) with the sensor noise's
/// share taken out in quadrature, at least `floor` of it (see [`FitNoise`]). The noise's share
/// is half its own quantile at that level, not σ: for a Gaussian
/// error and noise the halves add in quadrature (0.98 σ at 95 %, 1.05 σ at a bin of 33's
/// 96.4 %). Taking σ instead took 4 % of σ² too much from a pooled bin, a quarter of the
/// curve's share where its error is 0.4 σ (tests/gp/compare_gp.py's "two" at σ = 0.02 µm).
fn denoise(q: f64, noise_um: f64, level: f64, floor: f64) -> f64 {
    let n = noise_um * noise_quantile(level) / 2.0;
    (q * q - n * n).max((q * floor).powi(2)).sqrt()
}

/// z with P(|N(0, 1)| ≤ z) = `level` (bisection on [`normal_cdf`]).
fn noise_quantile(level: f64) -> f64 {
    let (mut lo, mut hi) = (0.0, 10.0);
    for _ in 0..60 {
        let z = 0.5 * (lo + hi);
        if 2.0 * normal_cdf(z) - 1.0 < level {
            lo = z;
        } else {
            hi = z;
        }
    }
    0.5 * (lo + hi)
}

/// Equal-count bins of `v` (sorted by distance): about [`PER_BIN`] each, at most [`MAX_BINS`].
fn equal_bins<T>(v: &[T]) -> impl Iterator<Item = &[T]> {
    equal_parts(v, (v.len() / PER_BIN).clamp(1, MAX_BINS))
}

/// `v` in `bins` consecutive parts of equal count (±1).
fn equal_parts<T>(v: &[T], bins: usize) -> impl Iterator<Item = &[T]> {
    (0..bins).map(move |b| &v[b * v.len() / bins..(b + 1) * v.len() / bins])
}

/// The quantile level read from a bin of k residuals. Split-conformal finite-sample level: the
/// ⌈(k + 1)(1 − α)⌉-th of k residuals bounds a new one with probability ≥ 1 − α; the randomised
/// version (a new residual's rank uniform, ties split) is exact on average at (k + ½)(1 − α)/k,
/// read between order statistics (a bin of 33 reads 96.4 %; see the module's notes).
fn conformal_level(k: f64) -> f64 {
    ((k + 0.5) * QUANTILE / k).min(1.0)
}

/// The q-quantile of ascending `v` (linear between order statistics).
fn quantile(v: &[f64], q: f64) -> f64 {
    let h = q * (v.len() - 1) as f64;
    let i = h.floor() as usize;
    let j = (i + 1).min(v.len() - 1);
    v[i] + (h - i as f64) * (v[j] - v[i])
}

/// Weighted pool-adjacent-violators: the non-decreasing sequence nearest to `v`.
fn non_decreasing(v: &[f64], w: &[f64]) -> Vec<f64> {
    // Blocks of (mean, weight, count).
    let mut blocks: Vec<(f64, f64, usize)> = Vec::new();
    for (&x, &wx) in v.iter().zip(w) {
        blocks.push((x, wx, 1));
        while blocks.len() > 1 && blocks[blocks.len() - 2].0 > blocks[blocks.len() - 1].0 {
            let (b, wb, nb) = blocks.pop().expect("two blocks");
            let (a, wa, na) = blocks.pop().expect("two blocks");
            blocks.push(((a * wa + b * wb) / (wa + wb), wa + wb, na + nb));
        }
    }
    blocks
        .into_iter()
        .flat_map(|(m, _, n)| std::iter::repeat_n(m, n))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::recon::test_curve::normals;

    #[test]
    fn a_step_departs_in_its_own_gap_only() {
        // Flat at 0 up to 20 µm, 1 µm from 30 µm on: the step is in the gap (20, 30).
        let xs = [0.0, 10.0, 20.0, 30.0, 40.0, 50.0];
        let ys = [0.0, 0.0, 0.0, 1.0, 1.0, 1.0];
        assert!((gap_feature(&xs, &ys, 25.0) - 1.0).abs() < 1e-12);
        // Its neighbours each have one side that agrees; a slope is no departure.
        assert!(gap_feature(&xs, &ys, 15.0).abs() < 1e-12);
        assert!(gap_feature(&xs, &ys, 35.0).abs() < 1e-12);
        let ramp: Vec<f64> = xs.iter().map(|x| 0.02 * x).collect();
        assert!(gap_feature(&xs, &ramp, 25.0).abs() < 1e-12);
        assert!(gap_feature(&xs[..2], &ys[..2], 5.0).is_nan());
    }

    #[test]
    fn a_step_widens_the_band_in_its_gap_and_leaves_the_rest_alone() {
        let mut normal = normals(3);
        // A flat curve sampled every 10 µm under σ = 0.01 µm with a 1 µm step in (2005, 2015):
        // held-out residuals are noise (departures ~0.02) but for the two whose training gap
        // holds the step (departure 1, residual half of it).
        let sample_pos: Vec<f64> = (0..400).map(|i| 5.0 + 10.0 * i as f64).collect();
        let sample_val: Vec<f64> = sample_pos
            .iter()
            .map(|&x| if x > 2010.0 { 1.0 } else { 0.0 } + 0.01 * normal())
            .collect();
        let cv: Vec<Residual> = sample_pos
            .iter()
            .map(|&x| {
                let step = x == 2005.0 || x == 2015.0;
                Residual {
                    d: 10.0,
                    r: if step { 0.5 } else { 0.014 * normal() },
                    x,
                    gap: if step { 1.0 } else { 0.02 * normal().abs() },
                }
            })
            .collect();
        let grid = [1000.0, 2010.0, 3000.0];
        let misfit = vec![0.0; sample_pos.len()];
        let u = pointwise_u(&grid, &sample_pos, &sample_val, &misfit, &cv, 0.01, &[]);
        // 2u covers the step anywhere in its gap; away from it the band is the noise's.
        assert!(2.0 * u[1] >= 1.0 - 0.03, "{u:?}");
        assert!(u[0] < 0.02 && u[2] < 0.02, "{u:?}");
        // Without the samples' values (no departure known) the two residuals widen the band
        // about the step by the local window instead, and it does not cover the step.
        let plain = pointwise_u(&grid, &sample_pos, &[], &misfit, &cv, 0.01, &[]);
        assert!(2.0 * plain[1] < 0.9, "{plain:?}");
    }

    #[test]
    fn a_fit_that_places_its_steps_takes_the_share_of_the_step_it_misses() {
        let mut normal = normals(5);
        // Ten 1 µm steps (a flank every 400 µm) a periodic model places: the two held-out
        // residuals of each step gap miss a fifth of it, and the fit misses its samples by
        // about the noise (not an interpolant).
        let sample_pos: Vec<f64> = (0..400).map(|i| 5.0 + 10.0 * i as f64).collect();
        let level = |x: f64| ((x + 190.0) / 400.0).floor();
        let sample_val: Vec<f64> = sample_pos
            .iter()
            .map(|&x| level(x) + 0.01 * normal())
            .collect();
        let cv: Vec<Residual> = sample_pos
            .iter()
            .map(|&x| {
                let step = level(x - 10.0) != level(x) || level(x + 10.0) != level(x);
                Residual {
                    d: 10.0,
                    r: if step { 0.2 } else { 0.014 * normal() },
                    x,
                    gap: if step { 1.0 } else { 0.02 * normal().abs() },
                }
            })
            .collect();
        let misfit: Vec<f64> = (0..400).map(|_| 0.008 * normal()).collect();
        let grid = [1200.0, 1010.0];
        let u = pointwise_u(&grid, &sample_pos, &sample_val, &misfit, &cv, 0.01, &[]);
        assert!((0.18..0.3).contains(&(2.0 * u[1])), "{u:?}");
        assert!(u[0] < 0.02, "{u:?}");
    }

    #[test]
    fn between_the_samples_of_a_curve_through_them_the_band_keeps_half_the_noise() {
        // Held-out residuals within the noise (σ = 0.03): the calibrated band is the floor of
        // a third; a curve through its samples carries σ/√2 of their noise mid-gap.
        let cv = flat_cv(0.03);
        let u = pointwise_u(&[0.0, 50.0], &[0.0, 100.0], &[], &[0.0; 20], &cv, 0.03, &[]);
        assert!((u[1] - 0.03 / 2f64.sqrt()).abs() < 1e-12, "{u:?}");
    }

    #[test]
    fn the_band_widens_with_the_distance_to_the_nearest_sample() {
        // Residuals growing with the distance: |r| ≈ 0.01 d (held out beyond the grid: the
        // same local scale at every grid point).
        let cv: Vec<Residual> = (0..300)
            .map(|i| {
                let d = (i % 100) as f64;
                let x = 1000.0 + i as f64;
                res(d, 0.01 * d * if i % 2 == 0 { 1.0 } else { -1.0 }, x)
            })
            .collect();
        let samples = [0.0, 200.0];
        let grid: Vec<f64> = (0..=20).map(|k| 10.0 * k as f64).collect();
        let u = pointwise_u(&grid, &samples, &[], &[], &cv, 0.0, &[]);
        assert_eq!(u.len(), grid.len());
        // At a sample the smallest, mid-gap (100 µm away) the largest.
        assert!(u[0] < 0.1 && u[10] > 0.35 && u[10] < 0.6, "{u:?}");
        assert!(u.windows(2).take(10).all(|w| w[1] >= w[0] - 1e-12));
    }

    /// 100 held-out residuals `r` (µm) at 5–104 µm from their fold's training samples.
    fn flat_cv(r: f64) -> Vec<Residual> {
        (0..100).map(|i| res(5.0 + i as f64, r, i as f64)).collect()
    }

    /// 40 misses of a curve at its samples, ±`v` (µm) alternately.
    fn alternating(v: f64) -> Vec<f64> {
        (0..40).map(|i| if i % 2 == 0 { v } else { -v }).collect()
    }

    fn res(d: f64, r: f64, x: f64) -> Residual {
        Residual {
            d,
            r,
            x,
            gap: f64::NAN,
        }
    }

    /// 600 held-out residuals spread as N(0, s²) exactly (normal quantiles), in the order
    /// `seed` shuffles them into along the travel, 1–10 µm from their folds' samples.
    fn gaussian_cv(s: f64, seed: u64) -> Vec<Residual> {
        use rand::seq::SliceRandom;
        use rand::SeedableRng;
        let n = 600;
        let mut order: Vec<usize> = (0..n).collect();
        order.shuffle(&mut rand_chacha::ChaCha8Rng::seed_from_u64(seed));
        order
            .iter()
            .enumerate()
            .map(|(i, &o)| {
                let z = noise_quantile(((o / 2) as f64 + 0.5) / (n / 2) as f64);
                let r = if o % 2 == 0 { s * z } else { -s * z };
                res(1.0 + (i % 10) as f64, r, 5.0 * i as f64)
            })
            .collect()
    }

    #[test]
    fn a_linear_fit_s_band_is_its_noise_variance_plus_the_bias_the_residuals_read() {
        let (sigma, fit) = (0.01f64, 0.0015f64);
        let samples: Vec<f64> = (0..300).map(|k| 10.0 * k as f64).collect();
        let grid: Vec<f64> = samples.iter().map(|x| x + 2.5).collect();
        let var = vec![fit * fit; grid.len()];
        let want = fit.hypot(0.005);
        // The same residuals in 12 orders along the travel: the band must not depend on
        // where chance puts the large ones (with the fixed local-scale prior it did: over 16
        // orders the noise-only band read up to 0.0033 µm, the biased one 0.0015–0.0061 µm).
        for seed in 0..12 {
            // Residuals of noise alone (their folds' noise variance included): the band is
            // the fit's own noise, where the floors held it at a third of the quantile
            // (~0.0033 µm).
            let noise_only = gaussian_cv((sigma * sigma + fit * fit).sqrt(), seed);
            let u = pointwise_u(&grid, &samples, &[], &[], &noise_only, sigma, &var);
            let mean = u.iter().sum::<f64>() / u.len() as f64;
            assert!(mean < 1.5 * fit, "seed {seed}: {mean}");
            let floored = pointwise_u(&grid, &samples, &[], &[], &noise_only, sigma, &[]);
            let mean = floored.iter().sum::<f64>() / floored.len() as f64;
            assert!(mean > 2.0 * fit, "seed {seed}: {mean}");
            // A bias of 0.005 µm beside it: u² = fit² + 0.005².
            let biased = gaussian_cv((sigma * sigma + fit * fit + 0.005f64.powi(2)).sqrt(), seed);
            let u = pointwise_u(&grid, &samples, &[], &[], &biased, sigma, &var);
            let mean = u.iter().sum::<f64>() / u.len() as f64;
            assert!(
                (mean / want - 1.0).abs() < 0.1,
                "seed {seed}: {mean} against {want}"
            );
            // Pointwise the bias part is the same all along, up to the local scale's doubt.
            for v in &u {
                assert!(
                    (v / want - 1.0).abs() < 0.25,
                    "seed {seed}: {v} against {want}"
                );
            }
        }
        let noise_only = gaussian_cv((sigma * sigma + fit * fit).sqrt(), 0);
        // The noise variance scales with σ: a σ told twice too high does not zero the band.
        let var4 = vec![4.0 * fit * fit; grid.len()];
        let u = pointwise_u(&grid, &samples, &[], &[], &noise_only, 2.0 * sigma, &var4);
        assert!(u.iter().all(|v| *v >= 2.0 * fit - 1e-12), "{u:?}");
    }

    #[test]
    fn a_bias_on_part_of_the_travel_is_read_there_not_spread() {
        // 600 held-out residuals along 3,000 µm under σ = 0.01 µm, with a bias of 0.02 µm (2σ)
        // on the first fifth: the band there should read the bias, and little elsewhere.
        let (sigma, fit, bias) = (0.01f64, 0.0015f64, 0.02f64);
        let samples: Vec<f64> = (0..300).map(|k| 10.0 * k as f64).collect();
        let grid: Vec<f64> = samples.iter().map(|x| x + 2.5).collect();
        let var = vec![fit * fit; grid.len()];
        let biased = |x: f64| x < 600.0;
        for seed in 0..6 {
            let cv: Vec<Residual> = gaussian_cv((sigma * sigma + fit * fit).sqrt(), seed)
                .into_iter()
                .map(|mut c| {
                    if biased(c.x) {
                        c.r += bias;
                    }
                    c
                })
                .collect();
            let u = pointwise_u(&grid, &samples, &[], &[], &cv, sigma, &var);
            let mean = |inside: bool| {
                let v: Vec<f64> = grid
                    .iter()
                    .zip(&u)
                    .filter(|(x, _)| biased(**x) == inside && (**x - 600.0).abs() > 150.0)
                    .map(|(_, u)| *u)
                    .collect();
                v.iter().sum::<f64>() / v.len() as f64
            };
            let (on, off) = (mean(true), mean(false));
            // Scaling the band with the noise already out read 0.0064 µm on it (seed 0): 2u
            // of 0.013 µm under a bias of 0.02, none of it covered. Now 0.014–0.016 µm.
            assert!(on > 0.6 * bias && on < 1.25 * bias, "seed {seed}: {on}");
            assert!(off < 0.3 * bias, "seed {seed}: {off}");
        }
    }

    #[test]
    fn the_local_scale_weighs_its_windows_by_how_much_they_vary_beyond_chance() {
        // Alike all along: no local scale at all.
        assert!(prior_weight(&[1.0; 600], 24).is_infinite());
        // Half the travel at 0.2, half at 1.8 (a defect region): the windows weigh as much as
        // they ever do, the prior k/2 residuals.
        let halves = |lo: f64, hi: f64| -> Vec<f64> {
            (0..576).map(|i| if i < 288 { lo } else { hi }).collect()
        };
        assert_eq!(prior_weight(&halves(0.2, 1.8), 24), 12.0);
        // A spread of 0.3² between chunk means: beyond windows of 48 (sampling variance
        // 2/48) it is structure, with weight 2/τ²; within windows of 12 (2/12) it is chance.
        let mild = prior_weight(&halves(0.7, 1.3), 48);
        let tau2 = 0.09 * 12.0 / 11.0 - 2.0 / 48.0;
        assert!((mild - 2.0 / tau2).abs() < 1e-9, "{mild}");
        assert!(prior_weight(&halves(0.7, 1.3), 12).is_infinite());
    }

    #[test]
    fn the_band_widens_where_the_held_out_residuals_are_large() {
        // 400 held-out residuals 1–10 µm from their fold's samples, 10 µm apart: ±0.01 µm, but
        // ±0.05 µm over 2,000–2,400 µm (a defect the model cannot hold).
        let cv: Vec<Residual> = (0..400)
            .map(|i| {
                let x = 10.0 * i as f64;
                let r = if (2000.0..2400.0).contains(&x) {
                    0.05
                } else {
                    0.01
                };
                res((1 + i * 37 % 10) as f64, if i % 2 == 0 { r } else { -r }, x)
            })
            .collect();
        let u = pointwise_u(&[500.0, 2200.0], &[495.0, 2195.0], &[], &[], &cv, 0.0, &[]);
        // By the distance alone both would read the 96 % point of all of them, 0.05 / 2; the
        // scale (shrunk towards 1) reads 0.005 and 0.016.
        assert!(u[0] < 0.01 && u[1] > 3.0 * u[0], "{u:?}");
        // The held-out residuals stay covered as a whole (each against the band read from the
        // others about it).
        let l = LocalScale::new(&cv).expect("enough residuals");
        let pairs: Vec<(f64, f64)> = cv
            .iter()
            .enumerate()
            .map(|(k, c)| (c.d, c.r / l.left_out(k)))
            .collect();
        let curve = DistanceCurve::calibrate(&pairs, 0.0, DENOISE_FLOOR).expect("a curve");
        let inside = (0..cv.len())
            .filter(|&k| cv[k].r.abs() <= 2.0 * curve.at(cv[k].d) * l.left_out(k))
            .count();
        assert!(inside as f64 / cv.len() as f64 >= 0.93, "{inside}");
    }

    #[test]
    fn violators_are_pooled_and_noise_is_taken_out() {
        assert_eq!(
            non_decreasing(&[1.0, 3.0, 2.0, 4.0], &[1.0; 4]),
            vec![1.0, 2.5, 2.5, 4.0]
        );
        let cv: Vec<Residual> = (0..100).map(|i| res(i as f64, 0.2, i as f64)).collect();
        let u = pointwise_u(&[0.0], &[0.0], &[], &[], &cv, 0.06, &[]);
        // Three bins of 33 (not noisy: 0.1 > √2 · 0.06): q95 = 0.2 → 0.1, less the noise's
        // half quantile at a bin's level (96.4 %, z = 2.10: 1.05 σ) in quadrature: 0.0776.
        let n = 0.06 * noise_quantile(conformal_level(33.0)) / 2.0;
        assert!((n / 0.06 - 1.05).abs() < 0.01, "{n}");
        assert!((u[0] - (0.01 - n * n).sqrt()).abs() < 1e-9, "{u:?}");
        // At 95 % the noise's share is 0.98 σ.
        assert!((noise_quantile(0.95) - 1.96).abs() < 1e-3);
        assert!(pointwise_u(&[0.0], &[0.0], &[], &[], &[], 0.0, &[]).is_empty());
    }

    #[test]
    fn bins_with_more_noise_than_error_are_read_together() {
        // Three bins of 33 under σ = 0.01 µm: the nearest reads 0.009 µm (below the noise, as a
        // bin of a curve whose error is near σ can by chance), the next 0.013 (also below √2 σ),
        // the farthest 0.03.
        let bin = |d: f64, r: f64| (0..33).map(move |i| res(d, r, d + i as f64));
        let cv: Vec<Residual> = bin(10.0, 0.018)
            .chain(bin(50.0, 0.026))
            .chain(bin(120.0, 0.06))
            .collect();
        let u = pointwise_u(&[10.0, 50.0, 120.0], &[0.0], &[], &[], &cv, 0.01, &[]);
        // The first two are one quantile (0.013 µm of 66 residuals) less the noise's share at
        // its level: 0.0082 µm, not the nearest bin's floor alone (a third of 0.009, 0.003 µm).
        let less = |q: f64, k: f64| {
            let n = 0.01 * noise_quantile(conformal_level(k)) / 2.0;
            (q * q - n * n).sqrt()
        };
        let pooled = less(0.013, 66.0);
        assert!((pooled - 0.0082).abs() < 1e-4, "{pooled}");
        assert!(
            (u[0] - pooled).abs() < 1e-9 && (u[1] - pooled).abs() < 1e-9,
            "{u:?}"
        );
        assert!((u[2] - less(0.03, 33.0)).abs() < 1e-9, "{u:?}");
        // Without noise to take out each bin is its own.
        let u = pointwise_u(&[10.0, 50.0], &[0.0], &[], &[], &cv, 0.0, &[]);
        assert!(
            (u[0] - 0.009).abs() < 1e-9 && (u[1] - 0.013).abs() < 1e-9,
            "{u:?}"
        );
    }

    #[test]
    fn sample_points_take_the_curves_miss_and_the_noise() {
        let cv = flat_cv(0.5);
        let misfit = vec![0.0; 20];
        let u = pointwise_u(&[0.0, 5.0], &[0.0, 100.0], &[], &misfit, &cv, 0.03, &[]);
        // At the sample: σ (a curve through its samples); 5 µm off it the calibrated band.
        assert!((u[0] - 0.03).abs() < 1e-12, "{u:?}");
        assert!(u[1] > 0.2, "{u:?}");
    }

    #[test]
    fn a_smoothing_fit_keeps_part_of_the_noise_at_its_samples() {
        // A smoother of weight ½ on its own sample under σ = 0.03 µm: it misses its samples by
        // half the noise, and a held-out sample (its miss over 1 − ½) by the whole of it. Those
        // residuals are within the noise: the nearest bin's u is a third of its quantile.
        let cv = flat_cv(0.03);
        let misfit = alternating(0.015);
        let u = pointwise_u(&[0.0, 5.0], &[0.0, 100.0], &[], &misfit, &cv, 0.03, &[]);
        // The other half of the noise is in the curve: √(0.015² − σ² + 2σ² · ½) = 0.015.
        assert!((u[0] - 0.015).abs() < 1e-12, "{u:?}");
        // Off them the calibrated band (a third of 0.015) is below the noise the curve kept:
        // that noise, at least half its variance, is the band.
        assert!((u[1] - 0.015 / 2f64.sqrt()).abs() < 1e-12, "{u:?}");
    }

    #[test]
    fn a_fit_that_misses_its_samples_by_more_than_the_noise_keeps_its_bias_there() {
        // A fit of few terms (held-out residuals hardly above its misses: df/m ≈ 0.06) misses
        // its samples by 0.0125 µm under σ = 0.01: 0.0075 of that is its bias, which it carries
        // at the samples too. σ − rms(miss) would have read 0.
        let cv = flat_cv(0.0133);
        let misfit = alternating(0.0125);
        let u = pointwise_u(&[0.0], &[0.0, 100.0], &[], &misfit, &cv, 0.01, &[]);
        let h = 1.0 - 0.0125 / 0.0133;
        let sure = (0.0125f64.powi(2) - 1e-4 + 2e-4 * h).sqrt();
        assert!((sure - 0.0083).abs() < 1e-4, "{sure}");
        assert!((u[0] - sure).abs() < 1e-12, "{u:?}");
    }

    #[test]
    fn a_maps_band_is_its_error_beyond_the_noise_the_samples_share() {
        let mut normal = normals(7);
        // Held-out error of scale s under noise σ = 0.01 (the map's case: s ≪ σ); the in-sample
        // residual is the same noise shrunk by the fit, ((I − H)²)_kk = 0.9, (H²)_kk = 0.1.
        let held = |s: f64, normal: &mut dyn FnMut() -> f64| -> Vec<HeldOut> {
            (0..6000)
                .map(|k| {
                    let eps = 0.01 * normal();
                    HeldOut {
                        d: (k % 100) as f64,
                        r: s * normal() - eps,
                        noise: 0.9f64.sqrt() * eps,
                        noise_var: 0.9,
                        fit_var: 0.1,
                        cell: 0,
                    }
                })
                .collect()
        };
        let u = u_at_distances_denoised(&[0.0, 50.0, 99.0], &held(0.004, &mut normal), 5, None);
        // 0.004 (times the Gaussian tail shape, 0.98) in every bin.
        assert!(u.iter().all(|&u| (u / 0.004 - 1.0).abs() < 0.15), "{u:?}");
        // Noise only: the fit's own noise-induced variance, 0.01·√0.1, not zero.
        let u = u_at_distances_denoised(&[0.0, 99.0], &held(0.0, &mut normal), 5, None);
        let floor = 0.01 * 0.1f64.sqrt();
        assert!(u.iter().all(|&u| (u / floor - 1.0).abs() < 0.15), "{u:?}");
        assert!(u_at_distances_denoised(&[0.0], &[], 5, None).is_empty());
    }

    #[test]
    fn a_maps_band_does_not_take_the_noise_of_its_noise_estimate_for_error() {
        let mut normal = normals(11);
        // Noise only (σ = 0.01), 600 held-out samples whose noise proxy shares 70 % of their
        // draw (a fit's proxy also carries its neighbours'): each bin's excess over the floor is
        // sampling noise of ~10⁻⁵ µm², the floor's own size. Twenty designs, every distance.
        let floor = 0.01 * 0.1f64.sqrt();
        let dist: Vec<f64> = (0..100).map(f64::from).collect();
        let mut widest: f64 = 0.0;
        for _ in 0..20 {
            let held: Vec<HeldOut> = (0..600)
                .map(|k| {
                    let eps = 0.01 * normal();
                    let other = 0.01 * normal();
                    HeldOut {
                        d: (k % 100) as f64,
                        r: -eps,
                        noise: 0.9f64.sqrt() * (0.7 * eps + 0.51f64.sqrt() * other),
                        noise_var: 0.9,
                        fit_var: 0.1,
                        cell: 0,
                    }
                })
                .collect();
            let u = u_at_distances_denoised(&dist, &held, 5, None);
            widest = u.iter().copied().fold(widest, f64::max);
        }
        // Widest 1.15 floors; 1.38 with the excess taken as it came.
        assert!(widest < 1.25 * floor, "{widest} against {floor}");
    }

    #[test]
    fn a_maps_excess_stays_in_the_cells_it_is_in() {
        let mut normal = normals(5);
        // 4 × 4 cells, 400 held-out samples each; the map's error (0.03 µm, three times the
        // noise) only in cell 5; the noise proxy shares the sample's draw.
        let held: Vec<HeldOut> = (0..6400)
            .map(|k| {
                let cell = k % 16;
                let eps = 0.01 * normal();
                let e = if cell == 5 { 0.03 * normal() } else { 0.0 };
                HeldOut {
                    d: (k % 97) as f64,
                    r: e - eps,
                    noise: 0.9f64.sqrt() * eps,
                    noise_var: 0.9,
                    fit_var: 0.01,
                    cell,
                }
            })
            .collect();
        let grid = [5, 15, 0];
        let cells = Cells {
            nx: 4,
            ny: 4,
            grid: &grid,
        };
        let u = u_at_distances_denoised(&[50.0; 3], &held, 5, Some(&cells));
        let flat = u_at_distances_denoised(&[50.0], &held, 5, None)[0];
        // By the distance alone: 0.03/4 (a sixteenth of the squared error) everywhere.
        assert!((flat / 0.0075 - 1.0).abs() < 0.2, "{flat}");
        // Cell 5 and the blocks it is in carry it (cell 0's block of 4 more than cell 5's of 9);
        // cell 15, two cells away, is near the noise floor.
        assert!(
            u[0] > 1.2 * flat && u[2] > flat && u[1] < 0.5 * flat,
            "{u:?} {flat}"
        );
        // There: the floor (0.01·√0.01 times the bins' tail shape, ~0.92) and a tenth of the whole
        // map's excess.
        let floor = 0.001 * 0.92;
        let far = (floor * floor + MIN_CELL_SHARE * (flat * flat - floor * floor)).sqrt();
        assert!((u[1] / far - 1.0).abs() < 0.1, "{u:?} against {far}");
    }

    #[test]
    fn close_candidates_weigh_about_half_and_clear_losers_nothing() {
        let chosen: Vec<Residual> = (0..200)
            .map(|i| res(1.0, if i % 2 == 0 { 0.1 } else { -0.12 }, i as f64))
            .collect();
        // As good on average: |residual| 0.11 throughout against 0.10 / 0.12 alternately.
        let twin: Vec<Residual> = (0..200)
            .map(|i| res(1.0, if i % 4 < 2 { 0.11 } else { -0.11 }, i as f64))
            .collect();
        let worse: Vec<Residual> = chosen.iter().map(|c| res(c.d, 2.0 * c.r, c.x)).collect();
        let w = choice_weight(&chosen, &twin);
        assert!(w > 0.2 && w < 0.8, "{w}");
        assert!(choice_weight(&chosen, &worse) < 1e-6);
        assert!((normal_cdf(0.0) - 0.5).abs() < 1e-7);
        assert!((normal_cdf(1.959_964) - 0.975).abs() < 1e-6);
        let v = choice_variance(&[0.0, 1.0], &[(1.0, vec![0.2, 1.0])]);
        // Two curves weighing 1 each: half of 0.2².
        assert!((v[0] - 0.02).abs() < 1e-12 && v[1] == 0.0, "{v:?}");
    }
}
