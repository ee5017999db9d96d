//! Statistical checks of renderer + decoder (used by `csmetro ppp bench` and the tests).
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use crate::decode::Decoder;
use crate::render::{render, Optics, Pose};

/// Stage range that must decode, µm (the paper's pattern: 9.5 mm x 4.2 mm), and angle range.
pub const RANGE_X_UM: f64 = 9500.0;
/// See `RANGE_X_UM`.
pub const RANGE_Y_UM: f64 = 4200.0;
/// Largest in-plane angle that must decode, mrad.
pub const MAX_THETA_MRAD: f64 = 20.0;

/// Median and 99th percentile of decode time over repeated decodes of one frame (this thread).
#[derive(Debug, Clone, Serialize)]
pub struct Timing {
    /// Decodes timed.
    pub frames: usize,
    /// Median decode time, ms.
    pub median_ms: f64,
    /// 99th percentile, ms.
    pub p99_ms: f64,
    /// Fastest, ms.
    pub min_ms: f64,
}

/// Times `repeats` decodes of one rendered frame.
pub fn timing(decoder: &Decoder, optics: &Optics, repeats: usize, seed: u64) -> Timing {
    let frame = render(
        decoder.pattern(),
        optics,
        Pose::new(4321.0, 2100.0, 7.0),
        seed,
    );
    let _ = decoder.decode(&frame); // warm caches
    let mut ms: Vec<f64> = (0..repeats.max(1))
        .map(|_| decoder.decode(&frame).decode_ms)
        .collect();
    ms.sort_by(f64::total_cmp);
    let pct = |p: f64| ms[((ms.len() - 1) as f64 * p).round() as usize];
    Timing {
        frames: ms.len(),
        median_ms: pct(0.5),
        p99_ms: pct(0.99),
        min_ms: ms[0],
    }
}

/// Standard deviation of decoded x, y over noise realisations at one pose, px.
#[derive(Debug, Clone, Serialize)]
pub struct Precision {
    /// Frames rendered.
    pub frames: usize,
    /// Frames the decoder rejected.
    pub rejected: usize,
    /// Std of decoded x, px.
    pub std_x_px: f64,
    /// Std of decoded y, px.
    pub std_y_px: f64,
    /// Std of decoded θ, mrad.
    pub std_theta_mrad: f64,
    /// Mean decoded minus true position, px (accuracy at this pose, not precision).
    pub bias_x_px: f64,
    /// See `bias_x_px`.
    pub bias_y_px: f64,
}

fn std_mean(v: &[f64]) -> (f64, f64) {
    let n = v.len().max(1) as f64;
    let m = v.iter().sum::<f64>() / n;
    let var = v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (n - 1.0).max(1.0);
    (var.sqrt(), m)
}

/// Precision over noise realisations of one pose.
pub fn precision(
    decoder: &Decoder,
    optics: &Optics,
    pose: Pose,
    frames: usize,
    seed: u64,
) -> Precision {
    let upx = optics.um_per_px();
    let (mut xs, mut ys, mut ts) = (Vec::new(), Vec::new(), Vec::new());
    let mut rejected = 0;
    for i in 0..frames {
        let r = decoder.decode(&render(
            decoder.pattern(),
            optics,
            pose,
            seed.wrapping_add(i as u64),
        ));
        if r.ok {
            xs.push((r.x_um - pose.x_um) / upx);
            ys.push((r.y_um - pose.y_um) / upx);
            ts.push(r.theta_mrad);
        } else {
            rejected += 1;
        }
    }
    let ((sx, mx), (sy, my), (st, _)) = (std_mean(&xs), std_mean(&ys), std_mean(&ts));
    Precision {
        frames,
        rejected,
        std_x_px: sx,
        std_y_px: sy,
        std_theta_mrad: st,
        bias_x_px: mx,
        bias_y_px: my,
    }
}

/// Sub-pixel steps over one period along x and y together: residual of decoded vs commanded
/// displacement after removing an offset and a scale (linear fit), px.
#[derive(Debug, Clone, Serialize)]
pub struct Linearity {
    /// Steps taken.
    pub steps: usize,
    /// Step size, px.
    pub step_px: f64,
    /// Frames rejected.
    pub rejected: usize,
    /// Largest x residual, px.
    pub max_residual_x_px: f64,
    /// Largest y residual, px.
    pub max_residual_y_px: f64,
    /// RMS x residual, px.
    pub rms_residual_x_px: f64,
    /// RMS y residual, px.
    pub rms_residual_y_px: f64,
    /// Fitted scale minus 1 (the decoder is self-calibrated by the known period).
    pub scale_error_x: f64,
    /// See `scale_error_x`.
    pub scale_error_y: f64,
}

fn line_residuals(t: &[f64], m: &[f64]) -> (Vec<f64>, f64) {
    let n = t.len() as f64;
    let (mt, mm) = (t.iter().sum::<f64>() / n, m.iter().sum::<f64>() / n);
    let sxx: f64 = t.iter().map(|a| (a - mt).powi(2)).sum();
    let sxy: f64 = t.iter().zip(m).map(|(a, b)| (a - mt) * (b - mm)).sum();
    let slope = if sxx > 0.0 { sxy / sxx } else { 1.0 };
    (
        t.iter()
            .zip(m)
            .map(|(a, b)| b - (mm + slope * (a - mt)))
            .collect(),
        slope,
    )
}

/// Linearity of sub-pixel steps over one period.
pub fn linearity(
    decoder: &Decoder,
    optics: &Optics,
    start: Pose,
    step_px: f64,
    seed: u64,
) -> Linearity {
    let upx = optics.um_per_px();
    let period_px = optics.period_px(decoder.pattern());
    let steps = (period_px / step_px).ceil() as usize + 1;
    let (mut t, mut mx, mut my) = (Vec::new(), Vec::new(), Vec::new());
    let mut rejected = 0;
    for i in 0..steps {
        let d = i as f64 * step_px;
        let pose = Pose::new(start.x_um + d * upx, start.y_um + d * upx, start.theta_mrad);
        let r = decoder.decode(&render(
            decoder.pattern(),
            optics,
            pose,
            seed.wrapping_add(i as u64),
        ));
        if r.ok {
            t.push(d);
            mx.push((r.x_um - start.x_um) / upx);
            my.push((r.y_um - start.y_um) / upx);
        } else {
            rejected += 1;
        }
    }
    let (rx, sx) = line_residuals(&t, &mx);
    let (ry, sy) = line_residuals(&t, &my);
    let max = |v: &[f64]| v.iter().fold(0f64, |a, b| a.max(b.abs()));
    let rms = |v: &[f64]| (v.iter().map(|x| x * x).sum::<f64>() / v.len().max(1) as f64).sqrt();
    Linearity {
        steps,
        step_px,
        rejected,
        max_residual_x_px: max(&rx),
        max_residual_y_px: max(&ry),
        rms_residual_x_px: rms(&rx),
        rms_residual_y_px: rms(&ry),
        scale_error_x: sx - 1.0,
        scale_error_y: sy - 1.0,
    }
}

/// Outcome counts of a sweep. "right" = decoded within `tolerance_period` of a period of the
/// truth on both axes; "wrong" = accepted but farther: the count that must be zero.
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
pub struct Sweep {
    /// Frames decoded.
    pub frames: usize,
    /// Decoded right.
    pub right: usize,
    /// Rejected.
    pub rejected: usize,
    /// Accepted but wrong (must be zero).
    pub wrong: usize,
    /// `right / frames`.
    pub success_rate: f64,
    /// Largest error among accepted frames, px.
    pub max_error_px: f64,
    /// First few wrong frames (pose, seed) for reproduction.
    pub wrong_examples: Vec<(Pose, u64)>,
    /// Rejection reasons (first words) with counts.
    pub reasons: Vec<(String, usize)>,
}

/// Random degradation of the nominal optics, for the never-silently-wrong sweep: blur,
/// defocus, dust, saturation, low contrast, noise, illumination gradient, 8/12 bit.
pub fn degrade(base: &Optics, rng: &mut impl Rng) -> Optics {
    let mut o = base.clone();
    o.psf_sigma_px = rng.random_range(0.5..4.0);
    o.defocus_radius_px = if rng.random_bool(0.3) {
        rng.random_range(0.0..5.0)
    } else {
        0.0
    };
    o.dust_count = if rng.random_bool(0.5) {
        rng.random_range(0..60)
    } else {
        0
    };
    o.dust_radius_px = [3.0, rng.random_range(5.0..40.0)];
    o.exposure = if rng.random_bool(0.3) {
        rng.random_range(1.0..3.0)
    } else {
        1.0
    };
    o.background = rng.random_range(0.05..0.4);
    o.foreground = o.background + rng.random_range(0.02..0.6);
    o.read_noise = rng.random_range(0.002..0.05);
    o.full_well_e = if rng.random_bool(0.5) {
        rng.random_range(2000.0..20000.0)
    } else {
        0.0
    };
    o.gradient = [rng.random_range(-0.8..0.8), rng.random_range(-0.8..0.8)];
    o.bit_depth = if rng.random_bool(0.3) { 12 } else { 8 };
    o
}

/// Random poses over the whole stage range (edges included: 10 % of the draws sit exactly on
/// a range edge) and ±20 mrad. `degraded` draws random image degradations per frame.
pub fn sweep(
    decoder: &Decoder,
    optics: &Optics,
    frames: usize,
    degraded: bool,
    seed: u64,
    threads: usize,
) -> Sweep {
    let threads = threads.max(1);
    let upx = optics.um_per_px();
    let period_um = decoder.pattern().config.period_um;
    let parts: Vec<Sweep> = std::thread::scope(|s| {
        let handles: Vec<_> = (0..threads)
            .map(|t| {
                s.spawn(move || {
                    let mut out = Sweep::default();
                    let mut reasons = std::collections::BTreeMap::<String, usize>::new();
                    for i in (t..frames).step_by(threads) {
                        let fseed = seed.wrapping_mul(1_000_003).wrapping_add(i as u64);
                        let mut rng = ChaCha8Rng::seed_from_u64(fseed);
                        let mut coord = |range: f64| match rng.random_range(0..20) {
                            0 => 0.0,
                            1 => range,
                            _ => rng.random_range(0.0..range),
                        };
                        let (x, y) = (coord(RANGE_X_UM), coord(RANGE_Y_UM));
                        let pose =
                            Pose::new(x, y, rng.random_range(-MAX_THETA_MRAD..=MAX_THETA_MRAD));
                        let o = if degraded {
                            degrade(optics, &mut rng)
                        } else {
                            optics.clone()
                        };
                        let r = decoder.decode(&render(decoder.pattern(), &o, pose, fseed));
                        out.frames += 1;
                        if !r.ok {
                            out.rejected += 1;
                            // Group by the reason's wording before its first number.
                            let reason = r.reason.unwrap_or_default();
                            let key = reason
                                .split_whitespace()
                                .take_while(|w| !w.chars().any(|c| c.is_ascii_digit()))
                                .collect::<Vec<_>>()
                                .join(" ");
                            *reasons.entry(key).or_default() += 1;
                            continue;
                        }
                        let err = (r.x_um - pose.x_um).abs().max((r.y_um - pose.y_um).abs());
                        if err <= 0.1 * period_um {
                            out.right += 1;
                            out.max_error_px = out.max_error_px.max(err / upx);
                        } else {
                            out.wrong += 1;
                            if out.wrong_examples.len() < 10 {
                                out.wrong_examples.push((pose, fseed));
                            }
                        }
                    }
                    out.reasons = reasons.into_iter().collect();
                    out
                })
            })
            .collect();
        handles
            .into_iter()
            .map(|h| h.join().expect("sweep thread panicked"))
            .collect()
    });
    let mut total = Sweep::default();
    let mut reasons = std::collections::BTreeMap::<String, usize>::new();
    for p in parts {
        total.frames += p.frames;
        total.right += p.right;
        total.rejected += p.rejected;
        total.wrong += p.wrong;
        total.max_error_px = total.max_error_px.max(p.max_error_px);
        total.wrong_examples.extend(p.wrong_examples);
        for (k, v) in p.reasons {
            *reasons.entry(k).or_default() += v;
        }
    }
    total.reasons = reasons.into_iter().collect();
    total.success_rate = total.right as f64 / total.frames.max(1) as f64;
    total
}
