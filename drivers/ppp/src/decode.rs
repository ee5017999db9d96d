//! Absolute (x, y, θ) from one frame of the pattern.
//!
//! 1. Carriers: 2-D FFT of a centred 256² Hann-windowed crop; the two fundamental peaks are
//!    searched in a ring around the nominal period (one cone per lattice direction) and
//!    interpolated to sub-bin.
//! 2. Fine: quadrature demodulation of the whole frame at each carrier over 50 %-overlapping
//!    Hann blocks (separable complex exponentials, so 4 multiply-adds per pixel), then a
//!    weighted least-squares plane through the unwrapped block phases gives the carrier
//!    correction and the phase at the image centre; done twice (the second pass at the
//!    refined carrier: at the exact carrier every dot contributes with the same phase, so the
//!    missing coded dots do not bias the phase). The plane residual is a quality figure.
//! 3. Coarse: the two phase planes give every lattice site's pixel position; dot contrast is
//!    read at each site; the always-dark corner class fixes the mod-3 phase; each code line
//!    is read as the ratio of its dots to its always-present neighbours; the bit string is
//!    matched against the whole code, and accepted only with few errors and a clear margin
//!    over the second-best window.
//!
//! Every stage can reject the frame; a rejected frame carries the reason and no position.
use std::sync::Arc;
use std::time::Instant;

use csmetro_hal::{Frame, Pixels};
use rustfft::num_complex::Complex32;
use rustfft::{Fft, FftPlanner};
use serde::{Deserialize, Serialize};

use crate::pattern::Pattern;
use crate::render::Optics;

/// Decoder settings: the expected imaging scale and the rejection thresholds.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct DecodeConfig {
    /// Nominal imaged period, px (period_um · magnification / pixel pitch).
    pub period_px: f64,
    /// Accepted relative deviation of the measured period from the nominal one.
    pub period_tolerance: f64,
    /// Largest in-plane angle searched, rad.
    pub max_angle_rad: f64,
    /// Demodulation block size, px (blocks overlap by half).
    pub block_px: usize,
    /// Minimum carrier peak power over the mean power of its ring in the coarse spectrum.
    pub min_peak_snr: f64,
    /// Minimum fundamental amplitude, fraction of full scale.
    pub min_modulation: f64,
    /// Maximum weighted rms residual of the block phases around their plane, rad.
    pub max_phase_rms_rad: f64,
    /// Maximum non-orthogonality of the two carriers, mrad, and period anisotropy (relative).
    pub max_skew_mrad: f64,
    /// Maximum period anisotropy of the two carriers (relative).
    pub max_anisotropy: f64,
    /// Maximum corner-class level relative to the always-present dots.
    pub max_corner_level: f64,
    /// Per axis: minimum reliable code bits, maximum disagreeing bits, minimum margin (errors
    /// of the second-best window minus errors of the best). The ~29 code lines visible along
    /// y put the nearest other window only ~4 bits away, so at most 1 error is corrected and
    /// a wrong window needs ≥ 3 coincident misreads that all survive the erasure threshold.
    pub min_bits: usize,
    /// Maximum disagreeing bits (see `min_bits`).
    pub max_bit_errors: usize,
    /// Minimum margin (see `min_bits`).
    pub min_margin: usize,
    /// A bit whose line ratio is within this of 0.5 (times 2) is an erasure, not a vote.
    pub min_bit_confidence: f64,
}

impl Default for DecodeConfig {
    fn default() -> Self {
        Self {
            period_px: 4.0 * 10.0 / 4.65,
            period_tolerance: 0.2,
            max_angle_rad: 0.3,
            block_px: 128,
            min_peak_snr: 30.0,
            min_modulation: 0.003,
            max_phase_rms_rad: 0.15,
            max_skew_mrad: 10.0,
            max_anisotropy: 0.01,
            max_corner_level: 0.3,
            min_bits: 14,
            max_bit_errors: 1,
            min_margin: 3,
            min_bit_confidence: 0.3,
        }
    }
}

impl DecodeConfig {
    /// Thresholds as default, scale from the optics and pattern.
    pub fn for_optics(pattern: &Pattern, optics: &Optics) -> Self {
        Self {
            period_px: optics.period_px(pattern),
            ..Default::default()
        }
    }
}

/// Quality figures of a decode (also filled, as far as reached, for a rejected frame).
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct Quality {
    /// Weaker carrier's peak power over its ring's mean power (coarse spectrum).
    pub peak_snr: f64,
    /// Weaker carrier's fundamental amplitude, fraction of full scale.
    pub modulation: f64,
    /// Weighted rms residual of block phases around the fitted plane (worse carrier), rad.
    pub phase_rms_rad: f64,
    /// Angle between the carriers minus 90°, mrad.
    pub skew_mrad: f64,
    /// Level of the always-missing corner dots relative to always-present dots (ideal 0).
    pub corner_level: f64,
    /// Reliable code bits read, bits disagreeing with the matched window, and margin
    /// (second-best window's disagreements minus the best's), along x and y.
    pub bits_x: usize,
    /// See `bits_x`.
    pub bit_errors_x: usize,
    /// See `bits_x`.
    pub margin_x: usize,
    /// See `bits_x`.
    pub bits_y: usize,
    /// See `bits_x`.
    pub bit_errors_y: usize,
    /// See `bits_x`.
    pub margin_y: usize,
}

/// Outcome of decoding one frame. Positions are NaN (JSON null) when `ok` is false.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct DecodeResult {
    /// Whether the frame gave a position that can be trusted.
    pub ok: bool,
    /// Why the frame was rejected.
    pub reason: Option<String>,
    /// Stage position (pattern point at the image centre minus the pattern origin), µm.
    pub x_um: f64,
    /// See `x_um`.
    pub y_um: f64,
    /// In-plane angle, mrad (same sign convention as the renderer).
    pub theta_mrad: f64,
    /// Imaged period, px.
    pub period_px: f64,
    /// Wall time of the decode, ms.
    pub decode_ms: f64,
    #[serde(flatten)]
    /// Quality figures of the decode.
    pub quality: Quality,
}

/// Fine result for one carrier.
#[derive(Debug, Clone, Copy)]
struct PlaneFit {
    /// Carrier, rad/px.
    k: [f64; 2],
    /// Phase at the image centre, rad, wrapped to (-π, π].
    phase: f64,
    rms: f64,
    /// Mean fundamental amplitude, grey levels.
    amplitude: f64,
}

/// Reusable decoder (FFT plan and thresholds). `Send + Sync`: share it across threads.
pub struct Decoder {
    pattern: Pattern,
    cfg: DecodeConfig,
    fft_n: usize,
    fft: Arc<dyn Fft<f32>>,
}

fn wrap(a: f64) -> f64 {
    let t = std::f64::consts::TAU;
    a - t * ((a + std::f64::consts::PI) / t).floor()
}

/// Four dot products of `x` with `a..d`, in independent lanes so that LLVM vectorises them.
#[inline]
fn dot4(x: &[f32], a: &[f32], b: &[f32], c: &[f32], d: &[f32]) -> [f32; 4] {
    let mut acc = [[0f32; 8]; 4];
    let n = x.len() / 8 * 8;
    for i in (0..n).step_by(8) {
        let xs = &x[i..i + 8];
        let (a8, b8, c8, d8) = (&a[i..i + 8], &b[i..i + 8], &c[i..i + 8], &d[i..i + 8]);
        for l in 0..8 {
            acc[0][l] += xs[l] * a8[l];
            acc[1][l] += xs[l] * b8[l];
            acc[2][l] += xs[l] * c8[l];
            acc[3][l] += xs[l] * d8[l];
        }
    }
    let mut out = [0f32; 4];
    for (o, lane) in out.iter_mut().zip(acc.iter()) {
        *o = lane.iter().sum();
    }
    for i in n..x.len() {
        out[0] += x[i] * a[i];
        out[1] += x[i] * b[i];
        out[2] += x[i] * c[i];
        out[3] += x[i] * d[i];
    }
    out
}

fn hann(t: usize, n: usize) -> f64 {
    let s = (std::f64::consts::PI * (t as f64 + 0.5) / n as f64).sin();
    s * s
}

fn bilinear(img: &[f32], w: usize, h: usize, u: f64, v: f64) -> Option<f32> {
    if !(u >= 0.0 && v >= 0.0 && u < (w - 1) as f64 && v < (h - 1) as f64) {
        return None;
    }
    let (iu, iv) = (u as usize, v as usize);
    let (fu, fv) = ((u - iu as f64) as f32, (v - iv as f64) as f32);
    let p = iv * w + iu;
    let top = img[p] + fu * (img[p + 1] - img[p]);
    let bot = img[p + w] + fu * (img[p + w + 1] - img[p + w]);
    Some(top + fv * (bot - top))
}

/// Result of matching a bit string (with erasures) against the code.
struct Match {
    offset: i64,
    reliable: usize,
    errors: usize,
    margin: usize,
}

fn match_code(code: &[u8], bits: &[Option<u8>]) -> Match {
    let l = bits.len() as i64;
    let n = code.len() as i64;
    let reliable = bits.iter().flatten().count();
    let (mut best, mut second, mut best_off) = (usize::MAX, usize::MAX, 0i64);
    for m in -(l - 1)..n {
        let mut errors = 0usize;
        for (k, b) in bits.iter().enumerate() {
            if let Some(b) = b {
                let idx = m + k as i64;
                if idx < 0 || idx >= n || code[idx as usize] != *b {
                    errors += 1;
                }
            }
        }
        if errors < best {
            second = best;
            best = errors;
            best_off = m;
        } else if errors < second {
            second = errors;
        }
    }
    Match {
        offset: best_off,
        reliable,
        errors: best,
        margin: second.saturating_sub(best),
    }
}

impl Decoder {
    /// A decoder of `pattern` with these thresholds.
    pub fn new(pattern: Pattern, cfg: DecodeConfig) -> Self {
        let fft_n = 256;
        let fft = FftPlanner::<f32>::new().plan_fft_forward(fft_n);
        Self {
            pattern,
            cfg,
            fft_n,
            fft,
        }
    }

    /// Its thresholds.
    pub fn config(&self) -> &DecodeConfig {
        &self.cfg
    }

    /// The pattern it decodes.
    pub fn pattern(&self) -> &Pattern {
        &self.pattern
    }

    /// Decodes a camera frame (Mono8 or Mono16 with its bit depth).
    pub fn decode(&self, frame: &Frame) -> DecodeResult {
        let t0 = Instant::now();
        let n = frame.width * frame.height;
        let (img, full): (Vec<f32>, f32) = match &frame.pixels {
            Pixels::Mono8(p) => (p.iter().map(|&v| v as f32).collect(), 255.0),
            Pixels::Mono16(p) => (
                p.iter().map(|&v| v as f32).collect(),
                ((1u32 << frame.bit_depth.clamp(1, 16)) - 1) as f32,
            ),
        };
        let mut r = if img.len() != n {
            self.reject(
                format!(
                    "frame holds {} pixels, expected {}x{}",
                    img.len(),
                    frame.width,
                    frame.height
                ),
                Quality::default(),
            )
        } else {
            self.decode_inner(&img, frame.width, frame.height, full)
        };
        r.decode_ms = t0.elapsed().as_secs_f64() * 1e3;
        r
    }

    /// Decodes row-major f32 pixels whose full scale is `full_scale` grey levels.
    pub fn decode_pixels(
        &self,
        img: &[f32],
        width: usize,
        height: usize,
        full_scale: f32,
    ) -> DecodeResult {
        let t0 = Instant::now();
        let mut r = if img.len() != width * height {
            self.reject(
                format!("{} pixels, expected {width}x{height}", img.len()),
                Quality::default(),
            )
        } else {
            self.decode_inner(img, width, height, full_scale)
        };
        r.decode_ms = t0.elapsed().as_secs_f64() * 1e3;
        r
    }

    fn reject(&self, reason: String, quality: Quality) -> DecodeResult {
        DecodeResult {
            ok: false,
            reason: Some(reason),
            x_um: f64::NAN,
            y_um: f64::NAN,
            theta_mrad: f64::NAN,
            period_px: f64::NAN,
            decode_ms: 0.0,
            quality,
        }
    }

    fn decode_inner(&self, img: &[f32], w: usize, h: usize, full: f32) -> DecodeResult {
        let mut q = Quality::default();
        let cfg = &self.cfg;
        if w < self.fft_n || h < self.fft_n || w < 2 * cfg.block_px || h < 2 * cfg.block_px {
            return self.reject(
                format!(
                    "frame {w}x{h} too small (min {0}x{0} px)",
                    self.fft_n.max(2 * cfg.block_px)
                ),
                q,
            );
        }
        // 1. Carriers from the coarse spectrum.
        let (kc, snr) = self.coarse_carriers(img, w, h);
        q.peak_snr = snr;
        let Some(kc) = kc else {
            return self.reject("no carrier peak in the expected period ring".into(), q);
        };
        if snr < cfg.min_peak_snr {
            return self.reject(
                format!(
                    "carrier peak power {snr:.1} below {:.1} (no pattern or too blurred)",
                    cfg.min_peak_snr
                ),
                q,
            );
        }
        // 2. Fine phase: two demodulation passes (the first, only for the carrier, on every 4th row).
        let first = self.demodulate(img, w, h, kc, 4);
        let k1 = [first[0].k, first[1].k];
        let fine = self.demodulate(img, w, h, k1, 1);
        let [f1, f2] = fine;
        q.phase_rms_rad = f1.rms.max(f2.rms);
        q.modulation = f1.amplitude.min(f2.amplitude) / full as f64;
        let th1 = (-f1.k[1]).atan2(f1.k[0]);
        let th2 = f2.k[0].atan2(f2.k[1]);
        q.skew_mrad = (th2 - th1) * 1e3;
        let (p1, p2) = (
            std::f64::consts::TAU / f1.k[0].hypot(f1.k[1]),
            std::f64::consts::TAU / f2.k[0].hypot(f2.k[1]),
        );
        let period_px = 0.5 * (p1 + p2);
        let theta = 0.5 * (th1 + th2);
        if q.modulation < cfg.min_modulation {
            return self.reject(
                format!(
                    "fundamental amplitude {:.4} of full scale below {}",
                    q.modulation, cfg.min_modulation
                ),
                q,
            );
        }
        if q.phase_rms_rad.is_nan() || q.phase_rms_rad > cfg.max_phase_rms_rad {
            return self.reject(
                format!(
                    "phase plane residual {:.3} rad above {}",
                    q.phase_rms_rad, cfg.max_phase_rms_rad
                ),
                q,
            );
        }
        if q.skew_mrad.abs() > cfg.max_skew_mrad
            || ((p1 - p2) / period_px).abs() > cfg.max_anisotropy
        {
            return self.reject(
                format!(
                    "lattice not square: skew {:.2} mrad, periods {p1:.4}/{p2:.4} px",
                    q.skew_mrad
                ),
                q,
            );
        }
        if ((period_px - cfg.period_px) / cfg.period_px).abs() > cfg.period_tolerance {
            return self.reject(
                format!(
                    "period {period_px:.3} px far from the nominal {:.3} px",
                    cfg.period_px
                ),
                q,
            );
        }
        // 3. Coarse: lattice indices from the code.
        match self.coarse(img, w, h, &f1, &f2, &mut q) {
            Ok((c_ref, r_ref)) => {
                let p = self.pattern.config.period_um;
                let tau = std::f64::consts::TAU;
                let xc = p * (c_ref as f64 + f1.phase / tau);
                let yc = p * (r_ref as f64 + f2.phase / tau);
                let [ox, oy] = self.pattern.config.origin_um;
                DecodeResult {
                    ok: true,
                    reason: None,
                    x_um: xc - ox,
                    y_um: yc - oy,
                    theta_mrad: theta * 1e3,
                    period_px,
                    decode_ms: 0.0,
                    quality: q,
                }
            }
            Err(reason) => {
                let mut r = self.reject(reason, q);
                r.period_px = period_px;
                r.theta_mrad = theta * 1e3;
                r
            }
        }
    }

    /// Returns the two carriers (rad/px; k1 along +u, k2 along +v) and the weaker peak's SNR.
    fn coarse_carriers(&self, img: &[f32], w: usize, h: usize) -> (Option<[[f64; 2]; 2]>, f64) {
        let n = self.fft_n;
        let (x0, y0) = ((w - n) / 2, (h - n) / 2);
        let mut mean = 0f64;
        for y in 0..n {
            mean += img[(y0 + y) * w + x0..(y0 + y) * w + x0 + n]
                .iter()
                .map(|&v| v as f64)
                .sum::<f64>();
        }
        let mean = (mean / (n * n) as f64) as f32;
        let win: Vec<f32> = (0..n).map(|t| hann(t, n) as f32).collect();
        let mut buf = vec![Complex32::new(0.0, 0.0); n * n];
        for y in 0..n {
            let row = &img[(y0 + y) * w + x0..(y0 + y) * w + x0 + n];
            for x in 0..n {
                buf[y * n + x] = Complex32::new((row[x] - mean) * win[x] * win[y], 0.0);
            }
        }
        let mut scratch = vec![Complex32::new(0.0, 0.0); self.fft.get_inplace_scratch_len()];
        self.fft.process_with_scratch(&mut buf, &mut scratch);
        // Only the low-frequency columns are needed: transpose those and transform along y.
        let rmax = n as f64 / (self.cfg.period_px * (1.0 - self.cfg.period_tolerance));
        let rmin = n as f64 / (self.cfg.period_px * (1.0 + self.cfg.period_tolerance));
        let fmax = (rmax.ceil() as i64 + 2).min(n as i64 / 2 - 1);
        let idx = |f: i64| f.rem_euclid(n as i64) as usize;
        let cols: Vec<i64> = (-fmax..=fmax).collect();
        let mut spec = vec![Complex32::new(0.0, 0.0); cols.len() * n];
        for (ci, &fx) in cols.iter().enumerate() {
            let col = &mut spec[ci * n..(ci + 1) * n];
            for y in 0..n {
                col[y] = buf[y * n + idx(fx)];
            }
            self.fft.process_with_scratch(col, &mut scratch);
        }
        let pow = |fx: i64, fy: i64| -> f64 {
            let ci = (fx + fmax) as usize;
            spec[ci * n + idx(fy)].norm_sqr() as f64
        };
        let tan = self.cfg.max_angle_rad.tan();
        let mut peaks = [(0f64, 0i64, 0i64); 2];
        let mut ring_sum = 0f64;
        let mut ring_n = 0usize;
        for fx in -fmax..=fmax {
            for fy in -fmax..=fmax {
                let r = ((fx * fx + fy * fy) as f64).sqrt();
                if r < rmin || r > rmax {
                    continue;
                }
                let pw = pow(fx, fy);
                ring_sum += pw;
                ring_n += 1;
                let (fxf, fyf) = (fx as f64, fy as f64);
                if fx > 0 && fyf.abs() <= fxf * tan && pw > peaks[0].0 {
                    peaks[0] = (pw, fx, fy);
                }
                if fy > 0 && fxf.abs() <= fyf * tan && pw > peaks[1].0 {
                    peaks[1] = (pw, fx, fy);
                }
            }
        }
        if ring_n == 0 || peaks.iter().any(|p| p.0 <= 0.0) {
            return (None, 0.0);
        }
        // Ring power without the four peaks' neighbourhoods (the two carriers and their mirrors).
        let mut excl = 0f64;
        let mut excl_n = 0usize;
        for &(_, px, py) in &peaks {
            for s in [1i64, -1] {
                for dx in -1..=1 {
                    for dy in -1..=1 {
                        let (fx, fy) = (s * px + dx, s * py + dy);
                        let r = ((fx * fx + fy * fy) as f64).sqrt();
                        if fx.abs() <= fmax && fy.abs() <= fmax && r >= rmin && r <= rmax {
                            excl += pow(fx, fy);
                            excl_n += 1;
                        }
                    }
                }
            }
        }
        let bg = (ring_sum - excl) / (ring_n.saturating_sub(excl_n)).max(1) as f64;
        let snr =
            peaks.iter().map(|p| p.0).fold(f64::INFINITY, f64::min) / bg.max(f64::MIN_POSITIVE);
        let mut ks = [[0f64; 2]; 2];
        for (k, &(_, px, py)) in ks.iter_mut().zip(peaks.iter()) {
            // Gaussian interpolation of the Hann-windowed peak, per axis.
            let interp = |m: f64, c: f64, p: f64| {
                let (lm, lc, lp) = (m.max(1e-30).ln(), c.max(1e-30).ln(), p.max(1e-30).ln());
                let den = lm - 2.0 * lc + lp;
                if den < 0.0 {
                    (0.5 * (lm - lp) / den).clamp(-0.5, 0.5)
                } else {
                    0.0
                }
            };
            let c = pow(px, py);
            let dx = if (px + 1).abs() <= fmax && (px - 1).abs() <= fmax {
                interp(pow(px - 1, py), c, pow(px + 1, py))
            } else {
                0.0
            };
            let dy = interp(pow(px, py - 1), c, pow(px, py + 1));
            let s = std::f64::consts::TAU / n as f64;
            *k = [s * (px as f64 + dx), s * (py as f64 + dy)];
        }
        (Some(ks), snr)
    }

    /// Block demodulation at carriers `k` and plane fit per carrier; `row_step` > 1 skips rows.
    fn demodulate(
        &self,
        img: &[f32],
        w: usize,
        h: usize,
        k: [[f64; 2]; 2],
        row_step: usize,
    ) -> [PlaneFit; 2] {
        let l = self.cfg.block_px;
        let step = l / 2;
        let (nu, nv) = ((w - l) / step + 1, (h - l) / step + 1);
        let (u_start, v_start) = (
            (w - ((nu - 1) * step + l)) / 2,
            (h - ((nv - 1) * step + l)) / 2,
        );
        let (wc, hc) = (0.5 * w as f64, 0.5 * h as f64);
        let win: Vec<f64> = (0..l).map(|t| hann(t, l)).collect();
        // exp(-i·k_u·du) along a row, by complex rotation (f64, no per-pixel sin/cos).
        let row_phasor: Vec<Vec<(f64, f64)>> = (0..2)
            .map(|c| {
                let (s0, c0) = (k[c][0] * (0.5 - wc)).sin_cos();
                let (sr, cr) = k[c][0].sin_cos();
                let (mut re, mut im) = (c0, -s0);
                (0..w)
                    .map(|_| {
                        let out = (re, im);
                        (re, im) = (re * cr + im * sr, im * cr - re * sr);
                        out
                    })
                    .collect()
            })
            .collect();
        // Windowed row tables per block column: carrier 1 (re, im), carrier 2 (re, im).
        let mut tabs = vec![[Vec::new(), Vec::new(), Vec::new(), Vec::new()]; nu];
        for (j, t) in tabs.iter_mut().enumerate() {
            let u0 = u_start + j * step;
            for c in 0..2 {
                let (re, im): (Vec<f32>, Vec<f32>) = (0..l)
                    .map(|tt| {
                        let (co, si) = row_phasor[c][u0 + tt];
                        ((win[tt] * co) as f32, (win[tt] * si) as f32)
                    })
                    .unzip();
                t[2 * c] = re;
                t[2 * c + 1] = im;
            }
        }
        let mut sums = vec![[Complex32::new(0.0, 0.0); 2]; nu * nv];
        let mut rowsum = vec![[Complex32::new(0.0, 0.0); 2]; nu];
        let v_end = v_start + (nv - 1) * step + l;
        for v in (v_start..v_end).step_by(row_step) {
            let row = &img[v * w..(v + 1) * w];
            for (j, t) in tabs.iter().enumerate() {
                let u0 = u_start + j * step;
                let d = dot4(&row[u0..u0 + l], &t[0], &t[1], &t[2], &t[3]);
                rowsum[j] = [Complex32::new(d[0], d[1]), Complex32::new(d[2], d[3])];
            }
            let dv = v as f64 + 0.5 - hc;
            let ev: [Complex32; 2] = std::array::from_fn(|c| {
                let (s, co) = (k[c][1] * dv).sin_cos();
                Complex32::new(co as f32, -s as f32)
            });
            // Block rows whose window covers v.
            let rel = v - v_start;
            let i_hi = (rel / step).min(nv - 1);
            let i_lo = if rel >= l { (rel - l) / step + 1 } else { 0 };
            for i in i_lo..=i_hi {
                let wv = win[rel - i * step] as f32;
                for (j, rs) in rowsum.iter().enumerate() {
                    let s = &mut sums[i * nu + j];
                    s[0] += rs[0] * ev[0] * wv;
                    s[1] += rs[1] * ev[1] * wv;
                }
            }
        }
        let centre = |i: usize, j: usize| {
            (
                (u_start + j * step) as f64 + 0.5 * l as f64 - wc,
                (v_start + i * step) as f64 + 0.5 * l as f64 - hc,
            )
        };
        let wsum = win.iter().sum::<f64>().powi(2) / row_step as f64;
        std::array::from_fn(|c| {
            let s = |i: usize, j: usize| {
                let z = sums[i * nu + j][c];
                (z.re as f64, z.im as f64)
            };
            // Wrap-free carrier correction from neighbouring blocks.
            let (mut gu, mut gv) = ((0f64, 0f64), (0f64, 0f64));
            for i in 0..nv {
                for j in 0..nu {
                    let a = s(i, j);
                    if j + 1 < nu {
                        let b = s(i, j + 1);
                        gu.0 += b.0 * a.0 + b.1 * a.1;
                        gu.1 += b.1 * a.0 - b.0 * a.1;
                    }
                    if i + 1 < nv {
                        let b = s(i + 1, j);
                        gv.0 += b.0 * a.0 + b.1 * a.1;
                        gv.1 += b.1 * a.0 - b.0 * a.1;
                    }
                }
            }
            let gu = gu.1.atan2(gu.0) / step as f64;
            let gv = gv.1.atan2(gv.0) / step as f64;
            let (mut zr, mut zi) = (0f64, 0f64);
            let mut amp = 0f64;
            for i in 0..nv {
                for j in 0..nu {
                    let (cu, cv) = centre(i, j);
                    let (a, b) = s(i, j);
                    let (sn, co) = (-(gu * cu + gv * cv)).sin_cos();
                    zr += a * co - b * sn;
                    zi += a * sn + b * co;
                    amp += a.hypot(b);
                }
            }
            let phi0 = zi.atan2(zr);
            // Weighted LS plane phi = c0 + a·cu + b·cv through the unwrapped block phases.
            let mut m = [[0f64; 3]; 3];
            let mut rhs = [0f64; 3];
            let mut pts = Vec::with_capacity(nu * nv);
            for i in 0..nv {
                for j in 0..nu {
                    let (cu, cv) = centre(i, j);
                    let (a, b) = s(i, j);
                    let wgt = a * a + b * b;
                    let pred = phi0 + gu * cu + gv * cv;
                    let ph = pred + wrap(b.atan2(a) - pred);
                    let x = [1.0, cu, cv];
                    for r in 0..3 {
                        for cc in 0..3 {
                            m[r][cc] += wgt * x[r] * x[cc];
                        }
                        rhs[r] += wgt * x[r] * ph;
                    }
                    pts.push((wgt, cu, cv, ph));
                }
            }
            let sol = solve3(m, rhs).unwrap_or([phi0, gu, gv]);
            let (mut rss, mut ws) = (0f64, 0f64);
            for &(wgt, cu, cv, ph) in &pts {
                let r = ph - (sol[0] + sol[1] * cu + sol[2] * cv);
                rss += wgt * r * r;
                ws += wgt;
            }
            let rms = if ws > 0.0 {
                (rss / ws).sqrt()
            } else {
                f64::INFINITY
            };
            PlaneFit {
                k: [k[c][0] + sol[1], k[c][1] + sol[2]],
                phase: wrap(sol[0]),
                rms,
                amplitude: 2.0 * amp / (nu * nv) as f64 / wsum,
            }
        })
    }

    /// Reads the code and returns the absolute lattice indices (column, row) of the site
    /// nearest the image centre (the one at phase 0 of both carriers).
    fn coarse(
        &self,
        img: &[f32],
        w: usize,
        h: usize,
        f1: &PlaneFit,
        f2: &PlaneFit,
        q: &mut Quality,
    ) -> Result<(i64, i64), String> {
        let tau = std::f64::consts::TAU;
        let (a, b, c, d) = (f1.k[0], f1.k[1], f2.k[0], f2.k[1]);
        let det = a * d - b * c;
        let (wc, hc) = (0.5 * w as f64, 0.5 * h as f64);
        // Pixel (index) coordinates of lattice point (i, j) in relative site units.
        let site = |i: f64, j: f64| {
            let (p1, p2) = (tau * i - f1.phase, tau * j - f2.phase);
            let du = (d * p1 - b * p2) / det;
            let dv = (-c * p1 + a * p2) / det;
            (du + wc - 0.5, dv + hc - 0.5)
        };
        let (mut imin, mut imax, mut jmin, mut jmax) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
        for (u, v) in [
            (0.0, 0.0),
            (w as f64, 0.0),
            (0.0, h as f64),
            (w as f64, h as f64),
        ] {
            let (du, dv) = (u - wc, v - hc);
            let i = (a * du + b * dv + f1.phase) / tau;
            let j = (c * du + d * dv + f2.phase) / tau;
            imin = imin.min(i);
            imax = imax.max(i);
            jmin = jmin.min(j);
            jmax = jmax.max(j);
        }
        let (i0, j0) = (imin.floor() as i64, jmin.floor() as i64);
        let (ni, nj) = (
            (imax.ceil() as i64 - i0 + 1) as usize,
            (jmax.ceil() as i64 - j0 + 1) as usize,
        );
        // Background between dots (cell centres) and dot levels; contrast = dot - mean of 4 cells.
        let bg: Vec<Option<f32>> = (0..=nj)
            .flat_map(|jj| (0..=ni).map(move |ii| (ii, jj)))
            .map(|(ii, jj)| {
                let (u, v) = site((i0 + ii as i64) as f64 - 0.5, (j0 + jj as i64) as f64 - 0.5);
                bilinear(img, w, h, u, v)
            })
            .collect();
        let mut dots = vec![f32::NAN; ni * nj];
        for jj in 0..nj {
            for ii in 0..ni {
                let (u, v) = site((i0 + ii as i64) as f64, (j0 + jj as i64) as f64);
                let g = |x: usize, y: usize| bg[y * (ni + 1) + x];
                if let (Some(val), Some(b00), Some(b10), Some(b01), Some(b11)) = (
                    bilinear(img, w, h, u, v),
                    g(ii, jj),
                    g(ii + 1, jj),
                    g(ii, jj + 1),
                    g(ii + 1, jj + 1),
                ) {
                    dots[jj * ni + ii] = val - 0.25 * (b00 + b10 + b01 + b11);
                }
            }
        }
        let at = |i: i64, j: i64| -> f32 {
            let (ii, jj) = (i - i0, j - j0);
            if ii < 0 || jj < 0 || ii >= ni as i64 || jj >= nj as i64 {
                f32::NAN
            } else {
                dots[jj as usize * ni + ii as usize]
            }
        };
        // Class means by (i mod 3, j mod 3): the corner class is the darkest.
        let mut cls = [[(0f64, 0usize); 3]; 3];
        // Sums of squares per class too: the noise of a class mean, for the orientation test.
        let mut sq = [[0f64; 3]; 3];
        for jj in 0..nj {
            for ii in 0..ni {
                let v = dots[jj * ni + ii];
                if v.is_finite() {
                    let (ci, cj) = (
                        (i0 + ii as i64).rem_euclid(3) as usize,
                        (j0 + jj as i64).rem_euclid(3) as usize,
                    );
                    cls[ci][cj].0 += v as f64;
                    cls[ci][cj].1 += 1;
                    sq[ci][cj] += (v as f64).powi(2);
                }
            }
        }
        let mean = |x: usize, y: usize| cls[x % 3][y % 3].0 / cls[x % 3][y % 3].1.max(1) as f64;
        if cls.iter().flatten().any(|c| c.1 < 20) {
            return Err("too few lattice sites in the frame".into());
        }
        let (mut ac, mut bc) = (0usize, 0usize);
        for x in 0..3 {
            for y in 0..3 {
                if mean(x, y) < mean(ac, bc) {
                    (ac, bc) = (x, y);
                }
            }
        }
        // Always-present classes: columns and rows not ≡ code lines, minus the corner.
        let full = [(ac, bc + 2), (ac + 2, bc), (ac + 2, bc + 2)].map(|(x, y)| mean(x, y));
        let full_mean = full.iter().sum::<f64>() / 3.0;
        if full_mean <= 0.0 {
            return Err("no dot contrast at the lattice sites".into());
        }
        q.corner_level = mean(ac, bc) / full_mean;
        let others_min = (0..9)
            .map(|t| (t / 3, t % 3))
            .filter(|&(x, y)| (x, y) != (ac, bc))
            .map(|(x, y)| mean(x, y))
            .fold(f64::INFINITY, f64::min);
        // The darkest other class is code column x code row, whose level is the product of the
        // visible code densities: ~0.09 where a frame sees long runs of zero bits. So the corner
        // must stand out from it by more than the noise of a class mean (and 2 % of a dot),
        // not by a fixed 10 %; a wrong pick still fails the code match downstream.
        let (ss, n) = [(ac, bc + 2), (ac + 2, bc), (ac + 2, bc + 2)]
            .iter()
            .map(|&(x, y)| {
                let (sum, k) = cls[x % 3][y % 3];
                (sq[x % 3][y % 3] - sum * sum / k.max(1) as f64, k)
            })
            .fold((0.0, 0usize), |(a, m), (s, k)| (a + s, m + k));
        let min_count = cls.iter().flatten().map(|c| c.1).min().unwrap_or(1).max(1);
        let se = (ss.max(0.0) / n.max(1) as f64).sqrt() / (min_count as f64).sqrt();
        let needed = (8.0 * se / full_mean).max(0.02);
        if q.corner_level > self.cfg.max_corner_level
            || (others_min - mean(ac, bc)) / full_mean < needed
        {
            return Err(format!(
                "orientation cells not found (corner level {:.2})",
                q.corner_level
            ));
        }
        // Relative index residues of code lines: c ≡ 1 (mod 3) where the corner class has c ≡ 0.
        let code_i = (ac + 1) % 3;
        let code_j = (bc + 1) % 3;
        let probe_j = (bc + 2) % 3;
        let probe_i = (ac + 2) % 3;
        let min_conf = self.cfg.min_bit_confidence;
        let read_bit = |num: f64, den: f64, cnt: usize| -> Option<u8> {
            if cnt < 4 || den < 0.3 * full_mean * cnt as f64 {
                return None;
            }
            let r = num / den;
            if (2.0 * (r - 0.5)).abs() < min_conf {
                None
            } else {
                Some((r > 0.5) as u8)
            }
        };
        let first_i = i0 + ((code_i as i64 - i0).rem_euclid(3));
        let mut bits_x = Vec::new();
        let mut i = first_i;
        while i < i0 + ni as i64 {
            let (mut num, mut den, mut cnt) = (0f64, 0f64, 0usize);
            for j in j0..j0 + nj as i64 {
                if j.rem_euclid(3) as usize != probe_j {
                    continue;
                }
                let (x, l, r) = (at(i, j), at(i - 1, j), at(i + 1, j));
                if x.is_finite() && l.is_finite() && r.is_finite() {
                    num += x as f64;
                    den += 0.5 * (l + r) as f64;
                    cnt += 1;
                }
            }
            bits_x.push(read_bit(num, den, cnt));
            i += 3;
        }
        let first_j = j0 + ((code_j as i64 - j0).rem_euclid(3));
        let mut bits_y = Vec::new();
        let mut j = first_j;
        while j < j0 + nj as i64 {
            let (mut num, mut den, mut cnt) = (0f64, 0f64, 0usize);
            for i in i0..i0 + ni as i64 {
                if i.rem_euclid(3) as usize != probe_i {
                    continue;
                }
                let (x, t, bt) = (at(i, j), at(i, j - 1), at(i, j + 1));
                if x.is_finite() && t.is_finite() && bt.is_finite() {
                    num += x as f64;
                    den += 0.5 * (t + bt) as f64;
                    cnt += 1;
                }
            }
            bits_y.push(read_bit(num, den, cnt));
            j += 3;
        }
        let code = &self.pattern.code;
        let mx = match_code(code, &bits_x);
        let my = match_code(code, &bits_y);
        (q.bits_x, q.bit_errors_x, q.margin_x) = (mx.reliable, mx.errors, mx.margin);
        (q.bits_y, q.bit_errors_y, q.margin_y) = (my.reliable, my.errors, my.margin);
        let cfg = &self.cfg;
        for (axis, m) in [("x", &mx), ("y", &my)] {
            if m.reliable < cfg.min_bits {
                return Err(format!(
                    "only {} reliable code bits along {axis} (need {})",
                    m.reliable, cfg.min_bits
                ));
            }
            if m.errors > cfg.max_bit_errors {
                return Err(format!(
                    "code along {axis}: best window disagrees on {} of {} bits",
                    m.errors, m.reliable
                ));
            }
            if m.margin < cfg.min_margin {
                return Err(format!(
                    "code along {axis} ambiguous: margin {} < {}",
                    m.margin, cfg.min_margin
                ));
            }
        }
        // Column of code bit `offset` is 3·offset + 1; it is relative index first_i.
        let c_ref = 3 * mx.offset + 1 - first_i;
        let r_ref = 3 * my.offset + 1 - first_j;
        let lines = self.pattern.lines() as i64;
        if c_ref < 0 || c_ref >= lines || r_ref < 0 || r_ref >= lines {
            return Err("decoded position outside the pattern".into());
        }
        Ok((c_ref, r_ref))
    }
}

fn solve3(mut m: [[f64; 3]; 3], mut r: [f64; 3]) -> Option<[f64; 3]> {
    for col in 0..3 {
        let piv = (col..3).max_by(|&x, &y| m[x][col].abs().total_cmp(&m[y][col].abs()))?;
        if m[piv][col].abs() < 1e-300 {
            return None;
        }
        m.swap(col, piv);
        r.swap(col, piv);
        for row in 0..3 {
            if row != col {
                let f = m[row][col] / m[col][col];
                let pivot = m[col];
                for (mk, pk) in m[row].iter_mut().zip(pivot.iter()).skip(col) {
                    *mk -= f * pk;
                }
                r[row] -= f * r[col];
            }
        }
    }
    Some([r[0] / m[0][0], r[1] / m[1][1], r[2] / m[2][2]])
}

#[cfg(test)]
mod tests;
