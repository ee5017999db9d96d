//! Simulated camera frames of the pattern.
//!
//! Geometry (the convention the decoder inverts): a pixel offset `d = (du, dv)` from the image
//! centre, in px (columns right, rows down, pixel `u` covering `[u, u + 1)`, centre at `W/2`),
//! sees the pattern point
//!
//! `P = origin + (x, y) + s · R(θ) · d`,  `s = pixel_pitch_um / magnification` (µm/px),
//!
//! so the stage position (x, y) is the pattern point imaged at the image centre; moving the
//! stage by +x brings pattern points of larger X to the centre, i.e. the pattern image moves
//! towards -u. θ > 0 rotates the image axes counter-clockwise in pattern coordinates.
//!
//! Radiometry: each pixel integrates `ss x ss` sub-samples, each of which is the exact box
//! average of the dot profile over its sub-pixel extent along X and along Y (exact at θ = 0,
//! so the image is a continuous function of position and sub-pixel steps are not quantised
//! by the sub-sample grid). Then, in this order: dust (occluding discs on the pattern),
//! illumination gradient, Gaussian PSF, defocus (pillbox), exposure gain, Poisson shot noise,
//! Gaussian read noise, clipping and quantisation to 8 or 12 bits.
use csmetro_hal::{Frame, Pixels};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Poisson, StandardNormal};
use serde::{Deserialize, Serialize};

use crate::pattern::Pattern;

/// Camera, optics and image-quality settings. Defaults: the paper's setup (1024 x 768 px,
/// 4.65 µm pixels, 10x objective), 1 px PSF, 1 % read noise, 8-bit output.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Optics {
    /// Frame width, px.
    pub width: usize,
    /// Frame height, px.
    pub height: usize,
    /// Sensor pixel pitch, µm.
    pub pixel_pitch_um: f64,
    /// Objective magnification.
    pub magnification: f64,
    /// Sub-samples per pixel along each axis (≥ 1; 4 or more for metrology).
    pub supersample: usize,
    /// Gaussian PSF standard deviation, px.
    pub psf_sigma_px: f64,
    /// Defocus as a pillbox (disc) blur of this radius, px (0 = in focus).
    pub defocus_radius_px: f64,
    /// Level of the background and of a dot, fractions of full scale (their difference is the contrast).
    pub background: f64,
    /// See `background`.
    pub foreground: f64,
    /// Relative illumination change across the full width and height (e.g. 0.2 = ±10 %).
    pub gradient: [f64; 2],
    /// Number of dust particles (dark discs) and their radius range, px.
    pub dust_count: usize,
    /// See `dust_count`.
    pub dust_radius_px: [f64; 2],
    /// Exposure gain applied before clipping (> 1 saturates the dots).
    pub exposure: f64,
    /// Full-well capacity in electrons at full scale; 0 disables shot noise.
    pub full_well_e: f64,
    /// Gaussian read noise, standard deviation as a fraction of full scale.
    pub read_noise: f64,
    /// Output bit depth: 8 (Mono8) or 12 (Mono16 words, values 0..4095).
    pub bit_depth: u8,
}

impl Default for Optics {
    fn default() -> Self {
        Self {
            width: 1024,
            height: 768,
            pixel_pitch_um: 4.65,
            magnification: 10.0,
            supersample: 4,
            psf_sigma_px: 1.0,
            defocus_radius_px: 0.0,
            background: 0.15,
            foreground: 0.75,
            gradient: [0.0, 0.0],
            dust_count: 0,
            dust_radius_px: [3.0, 15.0],
            exposure: 1.0,
            full_well_e: 0.0,
            read_noise: 0.01,
            bit_depth: 8,
        }
    }
}

impl Optics {
    /// Object-side pixel size, µm/px.
    pub fn um_per_px(&self) -> f64 {
        self.pixel_pitch_um / self.magnification
    }
    /// Pattern period as imaged, px.
    pub fn period_px(&self, pattern: &Pattern) -> f64 {
        pattern.config.period_um / self.um_per_px()
    }
    /// Checks the settings a render cannot work with.
    pub fn validate(&self) -> Result<(), String> {
        if self.width < 64 || self.height < 64 || self.width > 16384 || self.height > 16384 {
            return Err(format!(
                "frame size {}x{} outside 64..16384 px",
                self.width, self.height
            ));
        }
        if !(self.pixel_pitch_um > 0.0 && self.magnification > 0.0) {
            return Err("pixel pitch and magnification must be positive".into());
        }
        if !(1..=16).contains(&self.supersample) {
            return Err(format!("supersample {} outside 1..16", self.supersample));
        }
        if self.bit_depth != 8 && self.bit_depth != 12 {
            return Err(format!("bit depth {} (8 or 12)", self.bit_depth));
        }
        let finite_nonneg = [
            self.psf_sigma_px,
            self.defocus_radius_px,
            self.full_well_e,
            self.read_noise,
            self.exposure,
        ];
        if finite_nonneg.iter().any(|v| !(v.is_finite() && *v >= 0.0)) {
            return Err(
                "blur, defocus, full well, noise and exposure must be finite and ≥ 0".into(),
            );
        }
        if self.psf_sigma_px > 20.0 || self.defocus_radius_px > 30.0 {
            return Err("blur above 20 px sigma or defocus above 30 px radius".into());
        }
        Ok(())
    }
}

/// Stage pose: position of the image centre on the pattern (µm, relative to `origin_um`) and
/// in-plane rotation (mrad).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Pose {
    /// Stage x, µm.
    pub x_um: f64,
    /// Stage y, µm.
    pub y_um: f64,
    /// In-plane angle, mrad.
    pub theta_mrad: f64,
}

impl Pose {
    /// A pose at (x, y) µm and θ mrad.
    pub fn new(x_um: f64, y_um: f64, theta_mrad: f64) -> Self {
        Self {
            x_um,
            y_um,
            theta_mrad,
        }
    }
}

/// Offset that makes lattice coordinates positive before truncating casts (fast floor).
const FLOOR_OFFSET: f64 = 1_048_576.0;
/// Zero lines padded on each side of the line table, so that any lattice index within the
/// padding needs no bounds branch (frames far outside the pattern are clamped to blank).
const PAD: i64 = 8192;

/// Per lattice line: (line on, line on and corner line c ≡ 0 mod 3), padded with zeros.
fn line_table(pattern: &Pattern) -> Vec<[f32; 2]> {
    let lines = pattern.line_flags();
    let mut t = vec![[0f32; 2]; lines.len() + 2 * PAD as usize];
    for (c, &on) in lines.iter().enumerate() {
        let on = on as f32;
        let corner = pattern.has_corner_marks() && c % 3 == 0;
        t[c + PAD as usize] = [on, if corner { on } else { 0.0 }];
    }
    t
}

/// Box-averaged dot profile at lattice coordinate `t` (periods) over a sample `wp` periods wide:
/// (line profile, corner-line profile). Exact while the box spans at most one dot edge pair.
#[inline(always)]
fn profile(t: f64, tab: &[[f32; 2]], half: f64, wp: f64) -> (f32, f32) {
    let ci = (t + 0.5 + FLOOR_OFFSET) as i64 - FLOOR_OFFSET as i64;
    let d = (t - ci as f64).abs();
    let cov = ((half + 0.5 * wp - d) / wp).clamp(0.0, 1.0) as f32;
    let e = tab[(ci + PAD).clamp(0, tab.len() as i64 - 1) as usize];
    (cov * e[0], cov * e[1])
}

/// Noise-free pattern coverage in [0, 1] per pixel (row-major), before any optics.
pub fn render_coverage(pattern: &Pattern, optics: &Optics, pose: Pose) -> Vec<f32> {
    if pose.theta_mrad == 0.0 {
        coverage_separable(pattern, optics, pose)
    } else {
        coverage_general(pattern, optics, pose)
    }
}

/// θ = 0: X and Y lattice coordinates depend on the column and the row alone, so a pixel's
/// sub-sample sum factorises, Σ(fx·fy − hx·hy) = Σfx·Σfy − Σhx·Σhy — the same image as the
/// general path from (w + h)·ss profile evaluations instead of 2·w·h·ss² (the campaign
/// simulator renders thousands of frames; this is most of its CPU).
fn coverage_separable(pattern: &Pattern, optics: &Optics, pose: Pose) -> Vec<f32> {
    let (w, h, ss) = (optics.width, optics.height, optics.supersample.max(1));
    let p = pattern.config.period_um;
    let s = optics.um_per_px();
    let inv_p = 1.0 / p;
    let sub = 1.0 / ss as f64;
    let wp = s * sub * inv_p;
    let half = 0.5 * pattern.config.dot_fraction;
    let lines = line_table(pattern);
    // Per column (or row): sums over its sub-samples of the line and corner-line profiles.
    let sums = |origin: f64, n: usize| -> Vec<(f32, f32)> {
        (0..n)
            .map(|k| {
                let (mut f, mut c) = (0f32, 0f32);
                for sk in 0..ss {
                    let d = k as f64 + (sk as f64 + 0.5) * sub - 0.5 * n as f64;
                    let (a, b) = profile((origin + s * d) * inv_p, &lines, half, wp);
                    f += a;
                    c += b;
                }
                (f, c)
            })
            .collect()
    };
    let cols = sums(pattern.config.origin_um[0] + pose.x_um, w);
    let rows = sums(pattern.config.origin_um[1] + pose.y_um, h);
    let norm = (sub * sub) as f32;
    let mut out = vec![0f32; w * h];
    for (row, &(fy, hy)) in out.chunks_exact_mut(w).zip(&rows) {
        for (px, &(fx, hx)) in row.iter_mut().zip(&cols) {
            *px = (fx * fy - hx * hy) * norm;
        }
    }
    out
}

fn coverage_general(pattern: &Pattern, optics: &Optics, pose: Pose) -> Vec<f32> {
    let (w, h, ss) = (optics.width, optics.height, optics.supersample.max(1));
    let p = pattern.config.period_um;
    let s = optics.um_per_px();
    let (sn, cs) = (pose.theta_mrad * 1e-3).sin_cos();
    let inv_p = 1.0 / p;
    let sub = 1.0 / ss as f64;
    let wp = s * sub * inv_p;
    let half = 0.5 * pattern.config.dot_fraction;
    let lines = line_table(pattern);
    let x0 = pattern.config.origin_um[0] + pose.x_um;
    let y0 = pattern.config.origin_um[1] + pose.y_um;
    let (dtx, dty) = (s * cs * sub * inv_p, s * sn * sub * inv_p);
    let norm = (sub * sub) as f32;
    let mut out = vec![0f32; w * h];
    for v in 0..h {
        let row = &mut out[v * w..(v + 1) * w];
        for sv in 0..ss {
            let dv = v as f64 + (sv as f64 + 0.5) * sub - 0.5 * h as f64;
            let du0 = 0.5 * sub - 0.5 * w as f64;
            let tx0 = (x0 + s * (cs * du0 - sn * dv)) * inv_p;
            let ty0 = (y0 + s * (sn * du0 + cs * dv)) * inv_p;
            for (u, px) in row.iter_mut().enumerate() {
                let mut acc = 0f32;
                for su in 0..ss {
                    let j = (u * ss + su) as f64;
                    let (fx, hx) = profile(tx0 + j * dtx, &lines, half, wp);
                    if fx == 0.0 {
                        continue;
                    }
                    let (fy, hy) = profile(ty0 + j * dty, &lines, half, wp);
                    acc += fx * fy - hx * hy;
                }
                *px += acc * norm;
            }
        }
    }
    out
}

/// Separable Gaussian blur, edges clamped. Written tap-major over whole rows so the inner
/// loops are branch-free and vectorise (this blur was most of a simulated frame's time).
fn gaussian_blur(img: &mut [f32], w: usize, h: usize, sigma: f64) {
    if sigma < 0.05 {
        return;
    }
    let r = (3.5 * sigma).ceil() as usize;
    let mut k: Vec<f32> = (0..=2 * r)
        .map(|i| {
            let d = i as f64 - r as f64;
            (-(d * d) / (2.0 * sigma * sigma)).exp() as f32
        })
        .collect();
    let sum: f32 = k.iter().sum();
    k.iter_mut().for_each(|v| *v /= sum);
    // Rows: each padded with its clamped edge values, then one pass per tap.
    let mut pad = vec![0f32; w + 2 * r];
    for row in img.chunks_exact_mut(w) {
        pad[..r].fill(row[0]);
        pad[r..r + w].copy_from_slice(row);
        pad[r + w..].fill(row[w - 1]);
        row.fill(0.0);
        for (i, &kv) in k.iter().enumerate() {
            for (o, &v) in row.iter_mut().zip(&pad[i..i + w]) {
                *o += kv * v;
            }
        }
    }
    // Columns: each output row is a weighted sum of whole (clamped) input rows.
    let src = img.to_vec();
    for (y, out) in img.chunks_exact_mut(w).enumerate() {
        out.fill(0.0);
        for (i, &kv) in k.iter().enumerate() {
            let yy = (y + i).saturating_sub(r).min(h - 1);
            for (o, &v) in out.iter_mut().zip(&src[yy * w..(yy + 1) * w]) {
                *o += kv * v;
            }
        }
    }
}

/// Pillbox (defocus) blur of radius `radius` px; kernel weights are the disc's area per pixel.
fn disc_blur(img: &mut [f32], w: usize, h: usize, radius: f64) {
    if radius < 0.3 {
        return;
    }
    let r = radius.ceil() as isize + 1;
    let mut taps = Vec::new();
    for dy in -r..=r {
        for dx in -r..=r {
            let mut inside = 0;
            for sy in 0..4 {
                for sx in 0..4 {
                    let (fx, fy) = (
                        dx as f64 + (sx as f64 + 0.5) / 4.0 - 0.5,
                        dy as f64 + (sy as f64 + 0.5) / 4.0 - 0.5,
                    );
                    if fx * fx + fy * fy <= radius * radius {
                        inside += 1;
                    }
                }
            }
            if inside > 0 {
                taps.push((dx, dy, inside as f32));
            }
        }
    }
    let sum: f32 = taps.iter().map(|t| t.2).sum();
    let src = img.to_vec();
    for y in 0..h as isize {
        for x in 0..w as isize {
            let mut acc = 0f32;
            for &(dx, dy, wgt) in &taps {
                let xx = (x + dx).clamp(0, w as isize - 1) as usize;
                let yy = (y + dy).clamp(0, h as isize - 1) as usize;
                acc += wgt * src[yy * w + xx];
            }
            img[y as usize * w + x as usize] = acc / sum;
        }
    }
}

/// Renders one camera frame of `pattern` at `pose`; `seed` fixes dust and noise.
pub fn render(pattern: &Pattern, optics: &Optics, pose: Pose, seed: u64) -> Frame {
    let (w, h) = (optics.width, optics.height);
    let mut img = render_coverage(pattern, optics, pose);
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let (bg, fg) = (optics.background as f32, optics.foreground as f32);
    img.iter_mut().for_each(|v| *v = bg + (fg - bg) * *v);
    for _ in 0..optics.dust_count {
        let (cx, cy) = (
            rng.random::<f64>() * w as f64,
            rng.random::<f64>() * h as f64,
        );
        let [rlo, rhi] = optics.dust_radius_px;
        let rad = rlo + (rhi - rlo).max(0.0) * rng.random::<f64>();
        let opacity = 0.7 + 0.3 * rng.random::<f64>();
        let (x0, x1) = (
            (cx - rad - 1.0).max(0.0) as usize,
            ((cx + rad + 1.0) as usize).min(w - 1),
        );
        let (y0, y1) = (
            (cy - rad - 1.0).max(0.0) as usize,
            ((cy + rad + 1.0) as usize).min(h - 1),
        );
        for y in y0..=y1 {
            for x in x0..=x1 {
                let dist = ((x as f64 + 0.5 - cx).powi(2) + (y as f64 + 0.5 - cy).powi(2)).sqrt();
                let m = (rad + 0.5 - dist).clamp(0.0, 1.0);
                img[y * w + x] *= (1.0 - opacity * m) as f32;
            }
        }
    }
    let [gx, gy] = optics.gradient;
    if gx != 0.0 || gy != 0.0 {
        for y in 0..h {
            for x in 0..w {
                let g = 1.0
                    + gx * ((x as f64 + 0.5) / w as f64 - 0.5)
                    + gy * ((y as f64 + 0.5) / h as f64 - 0.5);
                img[y * w + x] *= g.max(0.0) as f32;
            }
        }
    }
    gaussian_blur(&mut img, w, h, optics.psf_sigma_px);
    disc_blur(&mut img, w, h, optics.defocus_radius_px);
    let maxv = ((1u32 << optics.bit_depth) - 1) as f32;
    let fw = optics.full_well_e;
    let (gain, rn) = (optics.exposure as f32, optics.read_noise as f32);
    let mut out = Vec::with_capacity(w * h);
    for &v in &img {
        let mut s = (v * gain).max(0.0);
        if fw > 0.0 {
            let lambda = s as f64 * fw;
            let e = if lambda > 50.0 {
                lambda + lambda.sqrt() * rng.sample::<f64, _>(StandardNormal)
            } else if lambda > 0.0 {
                Poisson::new(lambda)
                    .map(|d| d.sample(&mut rng))
                    .unwrap_or(lambda)
            } else {
                0.0
            };
            s = (e / fw) as f32;
        }
        if rn > 0.0 {
            s += rn * rng.sample::<f32, _>(StandardNormal);
        }
        // Values are ≥ 0 here: adding ½ and casting rounds (libm's roundf was 5 % of a frame).
        out.push((s.clamp(0.0, 1.0) * maxv + 0.5) as u16);
    }
    let pixels = if optics.bit_depth == 8 {
        Pixels::Mono8(out.iter().map(|&v| v as u8).collect())
    } else {
        Pixels::Mono16(out)
    };
    Frame {
        width: w,
        height: h,
        bit_depth: optics.bit_depth,
        pixels,
        timestamp_s: 0.0,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pattern::PatternConfig;

    /// The fast θ = 0 path must draw the same image as the general one, sub-pixel poses included.
    #[test]
    fn separable_coverage_equals_the_general_render_at_zero_rotation() {
        let pattern = Pattern::new(PatternConfig::default()).unwrap();
        let optics = Optics {
            width: 200,
            height: 150,
            ..Optics::default()
        };
        for (x, y) in [(0.0, 0.0), (1234.567, 4321.01), (9499.999, 13.37)] {
            let pose = Pose::new(x, y, 0.0);
            let a = coverage_separable(&pattern, &optics, pose);
            let b = coverage_general(&pattern, &optics, pose);
            let max = a
                .iter()
                .zip(&b)
                .map(|(p, q)| (p - q).abs())
                .fold(0f32, f32::max);
            assert!(max < 1e-5, "pose ({x}, {y}): max difference {max}");
            assert!(a.iter().any(|&v| v > 0.5), "pattern visible");
        }
    }

    /// The blur keeps a flat field flat up to the clamped edges and spreads an impulse into
    /// the normalised, symmetric Gaussian it should.
    #[test]
    fn gaussian_blur_is_normalised_symmetric_and_edge_clamped() {
        let (w, h) = (31, 23);
        let mut flat = vec![0.4f32; w * h];
        gaussian_blur(&mut flat, w, h, 1.3);
        assert!(flat.iter().all(|v| (v - 0.4).abs() < 1e-6));
        let mut img = vec![0f32; w * h];
        img[11 * w + 15] = 1.0;
        gaussian_blur(&mut img, w, h, 1.0);
        let total: f32 = img.iter().sum();
        assert!((total - 1.0).abs() < 1e-5, "mass {total}");
        assert!((img[11 * w + 14] - img[11 * w + 16]).abs() < 1e-7);
        assert!((img[10 * w + 15] - img[12 * w + 15]).abs() < 1e-7);
        let ratio = img[11 * w + 16] / img[11 * w + 15];
        assert!((ratio - (-0.5f32).exp()).abs() < 1e-4, "ratio {ratio}");
    }
}
