//! The motor/encoder period when the model does not give it. One motor revolution moves the
//! carriage by the thread pitch over the gearhead ratio, and the ratio is not known well (the
//! catalogue's 28.4:1 is unverified; gearheads of one family differ by a few percent). Over a
//! travel of thousands of periods a 0.2 % error in the period turns the fitted sinusoid through
//! a whole cycle, so a fixed nominal period fits nothing of a real motor error. The period is
//! therefore read from the data: the line-demeaned baseline residual of the moving component,
//! least squares of one sinusoid (line offsets refit) over a band of periods around the nominal
//! one, at a step fine enough that no peak falls between two trials, then refined. The nominal
//! period is kept unless another one explains clearly more (so the search changes nothing when
//! the nominal period is right or there is no motor error). The search adds a few hundred
//! trial periods: the nested test the group must then pass (z 5, p < 1e-6 per trial) stays far
//! above what the largest of them reaches on noise.
use csmetro_effects::AxisId;

use super::design::Rows;
use super::Sample;

/// Band of periods searched, as factors of the nominal period (gearhead ratios about 24.7:1 to
/// 32.6:1 for the nominal 28.4:1).
pub(super) const BAND: [f64; 2] = [0.87, 1.15];
/// Trial frequencies per independent one (1 / span of the targets).
const OVERSAMPLE: f64 = 3.0;
/// Another period replaces the nominal one only when it explains this much more.
const KEEP_NOMINAL: f64 = 1.25;

/// Rows of the moving component of `axis`' lines: (position, residual, line group).
fn rows_of(samples: &[Sample], rows: &Rows, axis: AxisId) -> (Vec<f64>, Vec<f64>, Vec<usize>) {
    let mut p = Vec::new();
    let mut y = Vec::new();
    let mut g = Vec::new();
    for i in 0..rows.n {
        let s = &samples[rows.sample[i]];
        if s.moving == axis && rows.comp[i] == axis {
            p.push(s.target(axis));
            y.push(rows.y[i]);
            g.push(rows.lc[i]);
        }
    }
    (p, y, g)
}

/// Explained sum of squares of one sinusoid of frequency `f` (1/µm), offsets per group refit.
fn power(p: &[f64], y: &[f64], g: &[usize], n_groups: usize, f: f64) -> f64 {
    // Per group: n, Σc, Σs, Σcc, Σss, Σcs, Σyc, Σys, Σy.
    let mut acc = vec![[0.0f64; 9]; n_groups];
    let w = std::f64::consts::TAU * f;
    for ((&pi, &yi), &gi) in p.iter().zip(y).zip(g) {
        let (s, c) = (w * pi).sin_cos();
        let a = &mut acc[gi];
        a[0] += 1.0;
        a[1] += c;
        a[2] += s;
        a[3] += c * c;
        a[4] += s * s;
        a[5] += c * s;
        a[6] += yi * c;
        a[7] += yi * s;
        a[8] += yi;
    }
    let (mut gcc, mut gss, mut gcs, mut bc, mut bs) = (0.0, 0.0, 0.0, 0.0, 0.0);
    for a in acc.iter().filter(|a| a[0] > 0.0) {
        let n = a[0];
        gcc += a[3] - a[1] * a[1] / n;
        gss += a[4] - a[2] * a[2] / n;
        gcs += a[5] - a[1] * a[2] / n;
        bc += a[6] - a[8] * a[1] / n;
        bs += a[7] - a[8] * a[2] / n;
    }
    let det = gcc * gss - gcs * gcs;
    if det <= 1e-12 * (gcc * gss).max(1e-300) {
        return 0.0;
    }
    (gss * bc * bc - 2.0 * gcs * bc * bs + gcc * bs * bs) / det
}

/// Why the data cannot tell the motor period from its aliases.
#[derive(Debug, thiserror::Error)]
enum Unresolved {
    #[error("{have} distinct targets on {axis} lines, {need} needed")]
    TooFewTargets {
        have: usize,
        axis: AxisId,
        need: f64,
    },
    #[error("no two targets on a line")]
    NoGaps,
    #[error("the targets are evenly spaced (every period of the band has a long-period alias on them; spread the targets irregularly)")]
    Even,
}

/// Whether the targets of `axis` can tell the periods of the band apart from anything smooth.
/// Two ways they cannot: too few distinct targets (among M independent trial periods one
/// sinusoid then fits a good part of any smooth error at T targets by chance, about
/// 1 - M^(-2/(T-2)); at least a fifth is refused), or evenly spaced targets (every period of the
/// band then has an alias of long period on them: a motor error looks like a long wave, and a
/// long wave like a motor error).
fn resolves(
    samples: &[Sample],
    axis: AxisId,
    f_lo: f64,
    f_hi: f64,
    span: f64,
) -> Result<(), Unresolved> {
    let mut lines: std::collections::BTreeMap<(i64, i64), Vec<i64>> = Default::default();
    for s in samples.iter().filter(|s| s.moving == axis) {
        lines
            .entry((s.run, super::design::key_um(s.target(axis.other()))))
            .or_default()
            .push(super::design::key_um(s.target(axis)));
    }
    let mut all: Vec<i64> = lines.values().flatten().copied().collect();
    all.sort_unstable();
    all.dedup();
    let m = ((f_hi - f_lo) * span).max(1.0);
    let need = (9.0 * m.ln() + 2.0).ceil();
    if (all.len() as f64) < need {
        return Err(Unresolved::TooFewTargets {
            have: all.len(),
            axis,
            need,
        });
    }
    // Gaps between neighbouring targets of a line, µm.
    let mut gaps = Vec::new();
    for v in lines.values_mut() {
        v.sort_unstable();
        v.dedup();
        gaps.extend(v.windows(2).map(|w| (w[1] - w[0]) as f64 / 100.0));
    }
    if gaps.is_empty() {
        return Err(Unresolved::NoGaps);
    }
    // Mean resultant length of the gaps' phases over the band: 1 for even spacing, near 0 when
    // the gaps vary by more than a period.
    let trials = 16;
    let r: f64 = (0..trials)
        .map(|k| {
            let f = f_lo + (f_hi - f_lo) * (k as f64 + 0.5) / trials as f64;
            let (mut c, mut s) = (0.0, 0.0);
            for d in &gaps {
                let (si, co) = (std::f64::consts::TAU * f * d).sin_cos();
                c += co;
                s += si;
            }
            (c * c + s * s).sqrt() / gaps.len() as f64
        })
        .sum::<f64>()
        / trials as f64;
    if r < 0.5 {
        Ok(())
    } else {
        Err(Unresolved::Even)
    }
}

/// The motor period of `axis` that the data support, near `nominal_um`; `nominal_um` itself when
/// no other period in the band explains clearly more, or (with why) when the targets cannot
/// tell the periods of the band apart.
pub(super) fn motor_period(
    samples: &[Sample],
    rows: &Rows,
    axis: AxisId,
    nominal_um: f64,
) -> (f64, Option<String>) {
    let (p, y, g) = rows_of(samples, rows, axis);
    if p.len() < 24 || nominal_um.is_nan() || nominal_um <= 0.0 {
        return (nominal_um, None);
    }
    let n_groups = rows.n_lc;
    let lo = p.iter().copied().fold(f64::INFINITY, f64::min);
    let hi = p.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    let span = (hi - lo).max(nominal_um);
    let (f_lo, f_hi) = (1.0 / (BAND[1] * nominal_um), 1.0 / (BAND[0] * nominal_um));
    if let Err(why) = resolves(samples, axis, f_lo, f_hi, span) {
        let note = format!(
            "motor_cyclic {axis}: only the nominal period {nominal_um:.3} µm is tried; a period {:.2}-{:.2} µm (another gearhead ratio) cannot be read from these data: {why}",
            BAND[0] * nominal_um,
            BAND[1] * nominal_um
        );
        return (nominal_um, Some(note));
    }
    let df = 1.0 / (OVERSAMPLE * span);
    let n = ((f_hi - f_lo) / df).ceil() as usize + 1;
    let mut best = (0.0, 1.0 / nominal_um);
    for k in 0..n {
        let f = f_lo + k as f64 * df;
        let pw = power(&p, &y, &g, n_groups, f);
        if pw > best.0 {
            best = (pw, f);
        }
    }
    // Golden-section refinement within one trial step either side.
    let (mut a, mut b) = (best.1 - df, best.1 + df);
    let gr = 0.5 * (5f64.sqrt() - 1.0);
    let mut c = b - gr * (b - a);
    let mut d = a + gr * (b - a);
    let (mut pc, mut pd) = (
        power(&p, &y, &g, n_groups, c),
        power(&p, &y, &g, n_groups, d),
    );
    for _ in 0..30 {
        if pc > pd {
            b = d;
            d = c;
            pd = pc;
            c = b - gr * (b - a);
            pc = power(&p, &y, &g, n_groups, c);
        } else {
            a = c;
            c = d;
            pc = pd;
            d = a + gr * (b - a);
            pd = power(&p, &y, &g, n_groups, d);
        }
    }
    let (pw, f) = if pc > pd { (pc, c) } else { (pd, d) };
    let best = if pw > best.0 { (pw, f) } else { best };
    let nominal = power(&p, &y, &g, n_groups, 1.0 / nominal_um);
    if best.0 > KEEP_NOMINAL * nominal {
        (1.0 / best.1, None)
    } else {
        (nominal_um, None)
    }
}
