//! Periods of the cyclic error, found in the samples themselves (no pitch assumed).
//!
//! Generalized Lomb–Scargle periodogram (sinusoid plus floating mean, Zechmeister & Kürster 2009)
//! on the residual of a low-order polynomial trend, evaluated on a frequency grid oversampled at
//! least 5x against the span, from the longest period we trust (a quarter of the span: fewer
//! cycles are a bow or a drift, not a period) down to the grid's
//! Nyquist period. Random sampling resolves periods far below twice the mean sample spacing, which
//! is why the search goes down to the grid's Nyquist. Samples on a uniform grid (x = x0 + k·Δ) make
//! every sum of the periodogram one real FFT of the zero-filled, zero-padded sample sequence
//! (exact, O(N' log N') for all frequencies at once); off-grid positions fall back to the direct
//! sums. A peak counts when its false-alarm probability, a Bonferroni bound over the effective
//! number of independent frequencies, is below `FAP_MAX` twice over: against white noise, and
//! against the local spectral background of the residual (median powers in log-spaced bands,
//! interpolated in log-log), so that correlated roughness and drift, whose power piles up at low
//! frequencies, do not pass for a period. Its frequency is then refined off the
//! grid by golden-section search on the power, the fitted sinusoid is subtracted (prewhitening)
//! and the search repeats.
use std::sync::Arc;

use realfft::num_complex::Complex;
use realfft::{RealFftPlanner, RealToComplex};
use serde::Serialize;

/// Detection threshold on the false-alarm probability.
pub const FAP_MAX: f64 = 1e-3;
/// With none below [`FAP_MAX`], the strongest peak below this one is a candidate for the
/// cross-validation (reported only if the cross-validated model keeps it).
pub const FAP_CANDIDATE: f64 = 0.05;
/// At most this many distinct periods (harmonics of a found period do not count).
pub const MAX_PERIODS: usize = 4;
/// Degree of the polynomial trend removed before the search.
const TREND_DEG: usize = 4;
const OVERSAMPLE: f64 = 5.0;
/// Fewest cycles over the span for a period (the longest is span / MIN_CYCLES): fewer are
/// what a bow or a drift leaves after the trend is removed, and the model's trend carries them.
const MIN_CYCLES: f64 = 4.0;
/// Bins of the background's level: at least `BG_BIN_CELLS` resolution cells and `BG_BIN_REL` of
/// their frequency wide; the peak's own `BG_GAP` cells (and those of every frequency already
/// removed) are left out.
const BG_BIN_CELLS: f64 = 8.0;
const BG_BIN_REL: f64 = 0.25;
const BG_GAP: f64 = 3.0;

/// One detected period.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Period {
    pub period_um: f64,
    /// Amplitude of the fundamental sinusoid, µm.
    pub amplitude_um: f64,
    /// False-alarm probability of the detection (Bonferroni bound).
    pub fap: f64,
    /// Quadratic phase rate about the span's centre, rad/µm², that best fits the dominant
    /// period (0 for the others): a period drifting along the travel (chirp).
    pub chirp_rad_um2: f64,
    /// The drift it means: local period at the end of the travel over that at its start, - 1.
    pub drift: f64,
    /// With the chirp: the local period at `chirp_centre_um` (the samples' centre), µm.
    #[serde(skip)]
    pub chirp_period_um: f64,
    #[serde(skip)]
    pub chirp_centre_um: f64,
}

/// Mean and variance of `y`.
fn moments(y: &[f64]) -> (f64, f64) {
    let nf = y.len() as f64;
    let ym = y.iter().sum::<f64>() / nf;
    (ym, y.iter().map(|v| (v - ym) * (v - ym)).sum::<f64>() / nf)
}

/// Least-squares fit of mean + a·cos(ωx) + b·sin(ωx) to `y`: (normalized power, a, b, mean).
fn gls(x: &[f64], y: &[f64], w: f64) -> (f64, f64, f64, f64) {
    let mut acc = [0.0f64; 7];
    for (&xi, &yi) in x.iter().zip(y) {
        let (s, c) = (w * xi).sin_cos();
        accumulate(&mut acc, yi, c, s);
    }
    let (ym, yy) = moments(y);
    power(&acc, ym, yy, y.len())
}

fn accumulate(acc: &mut [f64; 7], y: f64, c: f64, s: f64) {
    acc[0] += c;
    acc[1] += s;
    acc[2] += y * c;
    acc[3] += y * s;
    acc[4] += c * c;
    acc[5] += s * s;
    acc[6] += c * s;
}

/// Normalized GLS power in [0, 1] from the sums, with the sinusoid's coefficients and the mean.
fn power(acc: &[f64; 7], ym: f64, yy: f64, n: usize) -> (f64, f64, f64, f64) {
    let nf = n as f64;
    let (c, s) = (acc[0] / nf, acc[1] / nf);
    let yc = acc[2] / nf - ym * c;
    let ys = acc[3] / nf - ym * s;
    let cc = acc[4] / nf - c * c;
    let ss = acc[5] / nf - s * s;
    let csx = acc[6] / nf - c * s;
    let d = cc * ss - csx * csx;
    if !(d > 1e-14 && yy > 0.0) {
        return (0.0, 0.0, 0.0, ym);
    }
    let p = (ss * yc * yc + cc * ys * ys - 2.0 * csx * yc * ys) / (yy * d);
    let a = (yc * ss - ys * csx) / d;
    let b = (ys * cc - yc * csx) / d;
    (p.clamp(0.0, 1.0), a, b, ym - a * c - b * s)
}

/// Power on the angular-frequency grid w0 + k·dw, k < nw (sin/cos by rotation, re-anchored).
fn periodogram(x: &[f64], y: &[f64], w0: f64, dw: f64, nw: usize) -> Vec<f64> {
    let (ym, yy) = moments(y);
    let mut out = Vec::with_capacity(nw);
    let (mut c, mut s) = (vec![0.0; x.len()], vec![0.0; x.len()]);
    let rot: Vec<(f64, f64)> = x.iter().map(|&xi| (dw * xi).sin_cos()).collect();
    for k in 0..nw {
        if k % 128 == 0 {
            let w = w0 + k as f64 * dw;
            for (j, &xi) in x.iter().enumerate() {
                (s[j], c[j]) = (w * xi).sin_cos();
            }
        }
        let mut acc = [0.0f64; 7];
        for j in 0..x.len() {
            accumulate(&mut acc, y[j], c[j], s[j]);
            let (sd, cd) = rot[j];
            let (cn, sn) = (c[j] * cd - s[j] * sd, s[j] * cd + c[j] * sd);
            c[j] = cn;
            s[j] = sn;
        }
        out.push(power(&acc, ym, yy, x.len()).0);
    }
    out
}

/// Periodogram of samples on a uniform grid, x_j = x0 + k_j·Δ: on the frequencies
/// ω_l = 2π·l/(N'·Δ) every sum of [`accumulate`] is a DFT bin of a zero-filled length-N' sequence
/// (Σ y·e^{-iωkΔ} of the values, Σ e^{-iωkΔ} and Σ e^{-2iωkΔ} of the sampling pattern; cos², sin²
/// and cos·sin through the double angle). The power does not depend on x0, so k_j alone serves.
struct GridPeriodogram {
    k: Vec<usize>,
    len: usize,
    fft: Arc<dyn RealToComplex<f64>>,
    /// DFT of the sampling pattern (bins 0..=len/2).
    pattern: Vec<Complex<f64>>,
    scratch: Vec<Complex<f64>>,
    /// Bin spacing, rad/µm.
    dw: f64,
}

/// Smallest 2^a·3^b·5^c >= `n` (sizes the FFT runs fast on).
fn smooth_len(n: usize) -> usize {
    let mut best = n.next_power_of_two();
    let mut p5 = 1usize;
    while p5 < best {
        let mut p35 = p5;
        while p35 < best {
            let mut v = p35;
            while v < n {
                v *= 2;
            }
            best = best.min(v);
            p35 *= 3;
        }
        p5 *= 5;
    }
    best
}

impl GridPeriodogram {
    /// `None` unless every position is x0 + k·`step` (to 1e-6 of a step).
    fn new(x: &[f64], step: f64, oversample: f64) -> Option<Self> {
        let x0 = *x.first()?;
        let mut k = Vec::with_capacity(x.len());
        for &xi in x {
            let f = (xi - x0) / step;
            let r = f.round();
            if !(r >= 0.0 && (f - r).abs() <= 1e-6 && r < 1e9) {
                return None;
            }
            k.push(r as usize);
        }
        let span_k = *k.last()?;
        let len = smooth_len(((oversample * (span_k + 1) as f64).ceil() as usize).max(16));
        let fft = RealFftPlanner::<f64>::new().plan_fft_forward(len);
        let scratch = fft.make_scratch_vec();
        let mut g = Self {
            k,
            len,
            fft,
            pattern: Vec::new(),
            scratch,
            dw: std::f64::consts::TAU / (len as f64 * step),
        };
        g.pattern = g.transform(&vec![1.0; x.len()]);
        Some(g)
    }

    fn transform(&mut self, y: &[f64]) -> Vec<Complex<f64>> {
        let mut input = vec![0.0; self.len];
        for (&k, &v) in self.k.iter().zip(y) {
            input[k] = v;
        }
        let mut out = self.fft.make_output_vec();
        // Lengths come from the plan itself, so the transform cannot fail.
        let _ = self
            .fft
            .process_with_scratch(&mut input, &mut out, &mut self.scratch);
        out
    }

    /// Bin `l` of the full-length DFT of the pattern (Hermitian beyond len/2).
    fn pattern_bin(&self, l: usize) -> Complex<f64> {
        let l = l % self.len;
        if l <= self.len / 2 {
            self.pattern[l]
        } else {
            self.pattern[self.len - l].conj()
        }
    }

    /// Power at bins lo..=hi (hi <= len/2).
    fn power(&mut self, y: &[f64], lo: usize, hi: usize) -> Vec<f64> {
        let (ym, yy) = moments(y);
        let m = y.len() as f64;
        let ft = self.transform(y);
        (lo..=hi)
            .map(|l| {
                let (p1, p2, f) = (self.pattern_bin(l), self.pattern_bin(2 * l), ft[l]);
                let acc = [
                    p1.re,
                    -p1.im,
                    f.re,
                    -f.im,
                    (m + p2.re) / 2.0,
                    (m - p2.re) / 2.0,
                    -p2.im / 2.0,
                ];
                power(&acc, ym, yy, y.len()).0
            })
            .collect()
    }
}

/// Residual of a least-squares polynomial of degree `deg` (Legendre basis on the span).
pub fn detrend(x: &[f64], y: &[f64], deg: usize) -> Vec<f64> {
    let m = x.len();
    let deg = deg.min(m.saturating_sub(2));
    let (lo, hi) = (x[0], x[m - 1]);
    let half = ((hi - lo) / 2.0).max(f64::MIN_POSITIVE);
    let a = nalgebra::DMatrix::from_fn(m, deg + 1, |r, k| {
        super::physics::legendre(k, (x[r] - lo) / half - 1.0)
    });
    let yv = nalgebra::DVector::from_column_slice(y);
    let mut ata = a.transpose() * &a;
    for k in 0..=deg {
        ata[(k, k)] += 1e-12 * m as f64;
    }
    match ata.cholesky() {
        Some(ch) => {
            let beta = ch.solve(&(a.transpose() * &yv));
            (yv - a * beta).iter().copied().collect()
        }
        None => y.to_vec(),
    }
}

/// Finds the periods in samples `y` at ascending positions `x` (µm). `min_period_um` is the
/// shortest period the data can carry (twice the grid step).
pub fn detect(x: &[f64], y: &[f64], min_period_um: f64) -> Vec<Period> {
    detect_below(x, y, min_period_um, FAP_MAX)
}

/// [`detect`] with another false-alarm threshold.
pub fn detect_below(x: &[f64], y: &[f64], min_period_um: f64, fap_max: f64) -> Vec<Period> {
    let m = x.len();
    if m < 12 || x.len() != y.len() {
        return Vec::new();
    }
    let span = x[m - 1] - x[0];
    let max_period = span / MIN_CYCLES;
    if !(span > 0.0 && min_period_um > 0.0 && max_period > min_period_um) {
        return Vec::new();
    }
    let tau = 2.0 * std::f64::consts::PI;
    let (wmin, wmax) = (tau / max_period, tau / min_period_um);
    // Samples on the grid whose Nyquist period is `min_period_um`: the FFT periodogram.
    let mut fast = GridPeriodogram::new(x, min_period_um / 2.0, OVERSAMPLE);
    let dw = fast.as_ref().map_or(tau / (OVERSAMPLE * span), |g| g.dw);
    // Effective number of independent frequencies: the span-resolution cells in the band.
    let m_eff = ((wmax - wmin) * span / tau).max(1.0);
    let mut r = detrend(x, y, TREND_DEG);
    let rms = moments(&r).1.sqrt();
    let mut found: Vec<Period> = Vec::new();
    // Every removed frequency, harmonics included: all are refitted jointly after each round.
    let mut ws: Vec<f64> = Vec::new();
    // Index in `ws` of each found period.
    let mut fund: Vec<usize> = Vec::new();
    let mut lock: Vec<(usize, f64)> = Vec::new();
    // Harmonics are removed too, so allow a few more rounds than distinct periods.
    for _ in 0..2 * MAX_PERIODS {
        let (w0, pw) = match fast.as_mut() {
            Some(g) => {
                let lo = (wmin / dw).ceil() as usize;
                let hi = ((wmax / dw).floor() as usize).min(g.len / 2);
                (lo as f64 * dw, g.power(&r, lo, hi))
            }
            None => {
                let nw = ((wmax - wmin) / dw).ceil() as usize + 1;
                (wmin, periodogram(x, &r, wmin, dw, nw))
            }
        };
        let (k, _) = pw
            .iter()
            .enumerate()
            .fold((0, -1.0), |b, (k, &p)| if p > b.1 { (k, p) } else { b });
        let w = refine(x, &r, w0 + k as f64 * dw, dw, wmin, wmax);
        let (p, a, b, off) = gls(x, &r, w);
        // The background is measured with the candidate's sinusoid removed: with few random
        // samples its own leakage spreads over every frequency and would hide it.
        let r2: Vec<f64> = x
            .iter()
            .zip(&r)
            .map(|(&xi, &ri)| {
                let (sn, cs) = (w * xi).sin_cos();
                ri - off - a * cs - b * sn
            })
            .collect();
        let pw2 = match fast.as_mut() {
            Some(g) => {
                let lo = (wmin / dw).ceil() as usize;
                let hi = ((wmax / dw).floor() as usize).min(g.len / 2);
                g.power(&r2, lo, hi)
            }
            None => periodogram(x, &r2, w0, dw, pw.len()),
        };
        // In units of the residual's variance, as `p` is.
        let scale = moments(&r2).1 / moments(&r).1.max(f64::MIN_POSITIVE);
        // Single-frequency tail of the normalized power with m - 3 degrees of freedom.
        let fap_white = (m_eff * (1.0 - p).powf((m as f64 - 3.0) / 2.0)).min(1.0);
        // Against the local background: the power at one frequency is exponential about its
        // local mean (two degrees of freedom), so exp(-p / mean) is its single-frequency tail.
        let bg = scale * background(&pw2, w0, dw, w, &ws, tau / span);
        let fap_local = (m_eff * (-p / bg).exp()).min(1.0);
        let fap = fap_white.max(fap_local);
        // Below 1e-3 of the data's spread a "period" is rounding left by the previous fits.
        if fap.is_nan() || fap >= fap_max || a.hypot(b) < 1e-3 * rms {
            break;
        }
        let period = tau / w;
        // A harmonic of a found period belongs to it (locked to it from now on).
        let owner = fund
            .iter()
            .map(|&j| (j, (ws[j] / w).recip()))
            .find(|&(j, _)| harmonic_of(period, tau / ws[j]));
        // Within 1.5 resolution cells of a removed frequency: a sideband of its envelope, which the
        // model's envelope terms carry; removed, but not a new period.
        let sideband = owner.is_none() && ws.iter().any(|&wj| (w - wj).abs() < 1.5 * tau / span);
        let is_harmonic = owner.is_some();
        let (j, k) = owner.map_or((ws.len(), 1.0), |(j, k)| (j, k.round()));
        ws.push(if is_harmonic { k * ws[j] } else { w });
        lock.push((j, k));
        match backfit(x, y, &mut ws, &lock, dw, wmin, wmax) {
            Some(res) => r = res,
            None => break,
        }
        for (f, &wj) in found.iter_mut().zip(&fund) {
            f.period_um = tau / ws[wj];
        }
        if is_harmonic || sideband {
            continue;
        }
        let period = tau / ws[ws.len() - 1];
        fund.push(ws.len() - 1);
        found.push(Period {
            period_um: period,
            amplitude_um: a.hypot(b),
            fap,
            chirp_rad_um2: 0.0,
            drift: 0.0,
            chirp_period_um: period,
            chirp_centre_um: (x[0] + x[m - 1]) / 2.0,
        });
        if found.len() == MAX_PERIODS {
            break;
        }
    }
    if let Some(f) = found.first_mut() {
        let r0 = detrend(x, y, TREND_DEG);
        let (w, c) = chirp_rate(x, &r0, tau / f.period_um, span);
        f.chirp_rad_um2 = c;
        f.chirp_period_um = tau / w;
        f.drift = (w - c * span) / (w + c * span) - 1.0;
    }
    found
}

/// Largest relative drift of a period over the travel that [`chirp_rate`] looks for.
const MAX_DRIFT: f64 = 0.08;

/// Quadratic phase rate c (rad/µm²) for which w·x + c·(x - centre)² best fits `y` (the GLS power
/// of that chirp, its frequency re-fitted within two resolution cells of `w`), with that
/// frequency: (w, 0) when no drift fits clearly better. The local angular frequency is
/// w + 2c·(x - centre), centre the samples' middle.
fn chirp_rate(x: &[f64], y: &[f64], w: f64, span: f64) -> (f64, f64) {
    let xm = (x[0] + x[x.len() - 1]) / 2.0;
    let power = |w: f64, c: f64| gls_phase(x, y, |xi| w * xi + c * (xi - xm) * (xi - xm));
    let cell = std::f64::consts::TAU / span;
    // Drift d over the travel: c = d·w / (2·span).
    let cmax = MAX_DRIFT * w / (2.0 * span);
    let best_w = |c: f64| {
        (-8..=8)
            .map(|j| w + j as f64 * cell / 4.0)
            .map(|v| (v, power(v, c)))
            .fold((w, -1.0), |b, t| if t.1 > b.1 { t } else { b })
    };
    let base = power(w, 0.0);
    let (mut best, mut bp) = ((w, 0.0), base);
    for j in -16..=16 {
        let c = cmax * j as f64 / 16.0;
        let (v, p) = best_w(c);
        if p > bp {
            (best, bp) = ((v, c), p);
        }
    }
    // Only a clear gain: a chirp fitted to noise would just bend the model.
    if bp > base + 0.02 * (1.0 - base) {
        best
    } else {
        (w, 0.0)
    }
}

/// Normalized GLS power of a sinusoid in the phase `phase(x)` (plus a mean) fitted to `y`.
fn gls_phase(x: &[f64], y: &[f64], phase: impl Fn(f64) -> f64) -> f64 {
    let mut acc = [0.0f64; 7];
    for (&xi, &yi) in x.iter().zip(y) {
        let (s, c) = phase(xi).sin_cos();
        accumulate(&mut acc, yi, c, s);
    }
    let (ym, yy) = moments(y);
    power(&acc, ym, yy, y.len()).0
}

/// Mean power of the background at angular frequency `w`, from the periodogram `pw` on the grid
/// w0 + k·dw. The band is cut into log-spaced bins (at least `BG_BIN_CELLS` resolution cells of
/// `cell` and `BG_BIN_REL` of their frequency wide); each bin's median power (over ln 2, the
/// median of an exponential over its mean), leaving out `w` and every frequency in `removed`, is
/// its level, and the background at `w` is interpolated between bin centres in log-log. Below
/// the first centre it is extrapolated along the first two bins' slope when that rises toward
/// low frequencies: the power of correlated roughness and drift grows there like a power law,
/// and a flat estimate made a peak there look far stronger than it is. Never below the median
/// over the whole band.
fn background(pw: &[f64], w0: f64, dw: f64, w: f64, removed: &[f64], cell: f64) -> f64 {
    let at = |k: usize| w0 + k as f64 * dw;
    let clear = |v: f64| {
        (v - w).abs() >= BG_GAP * cell && removed.iter().all(|&r| (v - r).abs() >= BG_GAP * cell)
    };
    let median = |v: &mut Vec<f64>| {
        let mid = v.len() / 2;
        *v.select_nth_unstable_by(mid, f64::total_cmp).1
    };
    // (ln of the bin's centre frequency, ln of its median power)
    let mut levels: Vec<(f64, f64)> = Vec::new();
    let mut all: Vec<f64> = Vec::with_capacity(pw.len());
    let mut k = 0;
    while k < pw.len() {
        let (k0, start) = (k, at(k));
        let end = start + (BG_BIN_CELLS * cell).max(BG_BIN_REL * start);
        let mut vals = Vec::new();
        while k < pw.len() && at(k) < end {
            if clear(at(k)) {
                vals.push(pw[k]);
            }
            k += 1;
        }
        all.extend_from_slice(&vals);
        if vals.len() >= 8 {
            let centre = (at(k0).max(f64::MIN_POSITIVE) * at(k - 1)).sqrt();
            levels.push((centre.ln(), median(&mut vals).max(f64::MIN_POSITIVE).ln()));
        }
    }
    if all.is_empty() {
        return f64::MIN_POSITIVE;
    }
    let global = median(&mut all);
    let lw = w.max(f64::MIN_POSITIVE).ln();
    let local = match levels.len() {
        0 => global,
        1 => levels[0].1.exp(),
        len => {
            let j = levels.partition_point(|c| c.0 < lw);
            let (i0, i1) = match j {
                0 => (0, 1),
                j if j >= len => (len - 2, len - 1),
                j => (j - 1, j),
            };
            let ((x0, y0), (x1, y1)) = (levels[i0], levels[i1]);
            let v = y0 + (lw - x0) / (x1 - x0) * (y1 - y0);
            // Beyond the ends only a level that rises outward is extrapolated.
            match j {
                0 => v.max(y0),
                j if j >= len => y1,
                _ => v,
            }
            .exp()
        }
    };
    (local.max(global) / std::f64::consts::LN_2).max(f64::MIN_POSITIVE)
}

/// Residual of the joint least-squares fit of the polynomial trend and sinusoids at `ws`: a
/// first estimate's leakage would otherwise show up as a spurious period in the next round.
fn joint_residual(x: &[f64], y: &[f64], ws: &[f64]) -> Option<(Vec<f64>, Vec<f64>)> {
    let m = x.len();
    let cols = TREND_DEG + 1 + 2 * ws.len();
    if cols + 2 > m {
        return None;
    }
    let (lo, half) = (x[0], ((x[m - 1] - x[0]) / 2.0).max(f64::MIN_POSITIVE));
    let a = nalgebra::DMatrix::from_fn(m, cols, |r, k| {
        if k <= TREND_DEG {
            super::physics::legendre(k, (x[r] - lo) / half - 1.0)
        } else {
            let j = k - TREND_DEG - 1;
            let (s, c) = (ws[j / 2] * x[r]).sin_cos();
            if j.is_multiple_of(2) {
                c
            } else {
                s
            }
        }
    });
    let yv = nalgebra::DVector::from_column_slice(y);
    let mut ata = a.transpose() * &a;
    for k in 0..cols {
        ata[(k, k)] += 1e-10 * m as f64;
    }
    let beta = ata.cholesky()?.solve(&(a.transpose() * &yv));
    let r = (yv - &a * &beta).iter().copied().collect();
    Some((r, beta.iter().skip(TREND_DEG + 1).copied().collect()))
}

/// Backfitting: each frequency is refined again on the residual plus its own fitted sinusoid
/// (the others removed), then all are refitted jointly.
/// `lock[j] = (i, k)`: frequency j is the k-th harmonic of frequency i (k = 1: its own).
fn backfit(
    x: &[f64],
    y: &[f64],
    ws: &mut [f64],
    lock: &[(usize, f64)],
    dw: f64,
    wmin: f64,
    wmax: f64,
) -> Option<Vec<f64>> {
    let (mut r, mut coef) = joint_residual(x, y, ws)?;
    for _ in 0..2 {
        for j in 0..ws.len() {
            if lock[j].1 != 1.0 {
                continue;
            }
            let own: Vec<f64> = x
                .iter()
                .zip(&r)
                .map(|(&xi, &ri)| {
                    let (s, c) = (ws[j] * xi).sin_cos();
                    ri + coef[2 * j] * c + coef[2 * j + 1] * s
                })
                .collect();
            ws[j] = refine(x, &own, ws[j], dw / 2.0, wmin, wmax);
        }
        for j in 0..ws.len() {
            ws[j] = lock[j].1 * ws[lock[j].0];
        }
        (r, coef) = joint_residual(x, y, ws)?;
    }
    Some(r)
}

/// Whether `p` is within 1 % of fundamental/k for an integer k >= 2.
fn harmonic_of(p: f64, fundamental: f64) -> bool {
    let k = (fundamental / p).round();
    k >= 2.0 && (fundamental / k - p).abs() <= 0.01 * p
}

/// Golden-section maximum of the power within one grid cell either side of `w`.
fn refine(x: &[f64], y: &[f64], w: f64, dw: f64, wmin: f64, wmax: f64) -> f64 {
    let g = (5f64.sqrt() - 1.0) / 2.0;
    let (mut a, mut b) = ((w - dw).max(wmin), (w + dw).min(wmax));
    let f = |w: f64| gls(x, y, w).0;
    let (mut c, mut d) = (b - g * (b - a), a + g * (b - a));
    let (mut fc, mut fd) = (f(c), f(d));
    // 24 steps narrow the two cells to 2e-5 of a cell, far below what the fits can tell apart.
    for _ in 0..24 {
        if fc > fd {
            b = d;
            d = c;
            fd = fc;
            c = b - g * (b - a);
            fc = f(c);
        } else {
            a = c;
            c = d;
            fc = fd;
            d = a + g * (b - a);
            fd = f(d);
        }
    }
    let best = (a + b) / 2.0;
    if f(best) >= f(w) {
        best
    } else {
        w
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lcg(seed: u64) -> impl FnMut() -> f64 {
        let mut s = seed
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        move || {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (s >> 11) as f64 / (1u64 << 53) as f64
        }
    }

    fn positions(m: usize, seed: u64) -> Vec<f64> {
        let mut u = lcg(seed);
        let mut x: Vec<f64> = (0..m).map(|_| (u() * 1900.0).floor() * 5.0).collect();
        x.sort_by(f64::total_cmp);
        x.dedup();
        x
    }

    #[test]
    fn finds_two_incommensurate_periods_and_refines_them_off_grid() {
        let x = positions(200, 7);
        let y: Vec<f64> = x
            .iter()
            .map(|&v| {
                1.5 * (v / 251.3 * std::f64::consts::TAU).sin()
                    + 0.6 * (v / 1187.0 * std::f64::consts::TAU + 1.0).cos()
                    + 2e-8 * v * v
            })
            .collect();
        let p = detect(&x, &y, 10.0);
        assert_eq!(p.len(), 2, "{p:?}");
        assert!((p[0].period_um / 251.3 - 1.0).abs() < 1e-3, "{p:?}");
        assert!((p[1].period_um / 1187.0 - 1.0).abs() < 5e-3, "{p:?}");
        assert!((p[0].amplitude_um - 1.5).abs() < 0.05, "{p:?}");
        assert!(p.iter().all(|q| q.fap < FAP_MAX));
    }

    #[test]
    fn harmonics_are_not_new_periods() {
        let x = positions(150, 3);
        let y: Vec<f64> = x
            .iter()
            .map(|&v| {
                let w = v / 400.0 * std::f64::consts::TAU;
                w.sin() + 0.5 * (2.0 * w + 0.4).sin() + 0.3 * (3.0 * w).cos()
            })
            .collect();
        let p = detect(&x, &y, 10.0);
        assert_eq!(p.len(), 1, "{p:?}");
        assert!((p[0].period_um / 400.0 - 1.0).abs() < 1e-3, "{p:?}");
    }

    /// The FFT periodogram is the direct one, bin for bin (exact, not an approximation).
    #[test]
    fn grid_periodogram_equals_the_direct_sums() {
        let x: Vec<f64> = positions(120, 11).iter().map(|v| v + 37.5).collect();
        let mut u = lcg(5);
        let y: Vec<f64> = x
            .iter()
            .map(|&v| (v / 333.0 * std::f64::consts::TAU).sin() + u() - 0.5)
            .collect();
        let mut g = GridPeriodogram::new(&x, 5.0, 5.0).expect("positions on a 5 µm grid");
        // Oversampled 5x against the span (positions on a 5 µm grid).
        assert!(g.len as f64 * 5.0 >= 5.0 * (x[x.len() - 1] - x[0]));
        let (lo, hi) = (3, g.len / 2);
        let fast = g.power(&y, lo, hi);
        let direct = periodogram(&x, &y, lo as f64 * g.dw, g.dw, hi - lo + 1);
        assert_eq!(fast.len(), direct.len());
        let worst = fast
            .iter()
            .zip(&direct)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max);
        assert!(worst < 1e-9, "largest difference {worst}");
        assert!(fast.iter().cloned().fold(0.0, f64::max) > 0.5);
        // Off the grid: no FFT.
        assert!(GridPeriodogram::new(&[0.0, 5.0, 7.3], 5.0, 5.0).is_none());
        assert_eq!(smooth_len(9501), 9600);
    }

    #[test]
    fn white_noise_has_no_period() {
        let mut hits = 0;
        for seed in 0..10 {
            let x = positions(150, seed);
            let mut u = lcg(100 + seed);
            let y: Vec<f64> = x.iter().map(|_| u() - 0.5).collect();
            hits += usize::from(!detect(&x, &y, 10.0).is_empty());
        }
        assert!(hits <= 1, "{hits} false detections in 10");
    }
}
