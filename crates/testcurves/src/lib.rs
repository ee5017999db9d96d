#![doc = include_str!("../README.md")]
use std::f64::consts::TAU;

/// Family names, in the bench's default order.
pub const FAMILIES: [&str; 8] = [
    "single",
    "two",
    "limit",
    "chirp",
    "noise",
    "steps",
    "leadscrew",
    "rough",
];

/// SplitMix64 (independent of the project's generators).
pub struct Rng(pub u64);
impl Rng {
    /// A uniform draw in [0, 1): an endless stream, not an `Iterator`.
    #[allow(clippy::should_implement_trait)]
    pub fn next(&mut self) -> f64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64
    }
    pub fn gauss(&mut self) -> f64 {
        let (u, v) = (self.next().max(1e-300), self.next());
        (-2.0 * u.ln()).sqrt() * (TAU * v).cos()
    }
    /// Log-uniform in [lo, hi].
    pub fn log_uniform(&mut self, lo: f64, hi: f64) -> f64 {
        (lo.ln() + self.next() * (hi / lo).ln()).exp()
    }
}

/// What a curve is made of.
#[derive(Debug, Clone)]
pub struct Spec {
    pub n: usize,
    pub step_um: f64,
    /// (period, amplitude of the fundamental), the dominant first.
    pub cyclic: Vec<(f64, f64)>,
    /// Amplitudes of harmonics 2 and 3 relative to the fundamental.
    pub harmonics: [f64; 2],
    /// Largest relative change of the cyclic amplitude over the travel (linear envelope).
    pub envelope: f64,
    /// Relative drift of every period over the travel (chirp): p·(1 + drift·s), s in [-1, 1].
    pub drift: f64,
    /// Scale of the polynomial trend (bow, tilt, cubic), µm.
    pub trend_um: f64,
    /// Exponentially correlated roughness: σ and correlation length.
    pub rough_um: f64,
    pub rough_corr_um: f64,
    /// White scatter that is part of the curve itself (a real measured curve carries it), σ.
    pub white_um: f64,
    /// Count and scale of steps, and of Gaussian bumps (local defects).
    pub steps: usize,
    pub bumps: usize,
    pub defect_um: f64,
}

impl Spec {
    pub fn new(n: usize, step_um: f64) -> Self {
        Self {
            n,
            step_um,
            cyclic: Vec::new(),
            harmonics: [0.3, 0.1],
            envelope: 0.0,
            drift: 0.0,
            trend_um: 1.0,
            rough_um: 0.03,
            rough_corr_um: 15.0,
            white_um: 0.0,
            steps: 0,
            bumps: 0,
            defect_um: 0.0,
        }
    }

    pub fn span_um(&self) -> f64 {
        self.step_um * (self.n.max(2) - 1) as f64
    }

    /// The curve at positions i·step, i < n, drawn with `seed`.
    pub fn render(&self, seed: u64) -> Vec<f64> {
        let mut r = Rng(seed.wrapping_mul(0x2545_F491_4F6C_DD1D) ^ 0x1234_5678);
        let (n, span) = (self.n, self.span_um());
        let t = self.trend_um;
        let (bow, tilt, cubic) = (2.0 * t * r.gauss(), t * r.gauss(), 0.5 * t * r.gauss());
        let phases: Vec<[f64; 3]> = self
            .cyclic
            .iter()
            .map(|_| [TAU * r.next(), TAU * r.next(), TAU * r.next()])
            .collect();
        let env: Vec<f64> = self
            .cyclic
            .iter()
            .map(|_| self.envelope * (2.0 * r.next() - 1.0))
            .collect();
        let steps: Vec<(f64, f64)> = (0..self.steps)
            .map(|_| (span * r.next(), self.defect_um * r.gauss()))
            .collect();
        let bumps: Vec<(f64, f64, f64)> = (0..self.bumps)
            .map(|_| {
                let (at, h) = (span * r.next(), self.defect_um * r.gauss());
                (at, h, 20.0 + 60.0 * r.next())
            })
            .collect();
        let phi = (-self.step_um / self.rough_corr_um.max(1e-9)).exp();
        let mut ar = r.gauss();
        let mut out = Vec::with_capacity(n);
        for i in 0..n {
            let x = i as f64 * self.step_um;
            let s = 2.0 * x / span - 1.0;
            let mut v = bow * s * s + tilt * s + cubic * s * s * s;
            for (k, &(p, a)) in self.cyclic.iter().enumerate() {
                let d = self.drift;
                // Phase of a period drifting as p·(1 + d·s): the integral of 2π/p(x) dx.
                let ph = if d != 0.0 {
                    TAU * span / (2.0 * p * d) * ((1.0 + d * s) / (1.0 - d)).ln()
                } else {
                    TAU * x / p
                };
                let [f1, f2, f3] = phases[k];
                let [h2, h3] = self.harmonics;
                v += a
                    * (1.0 + env[k] * s)
                    * ((ph + f1).sin() + h2 * (2.0 * ph + f2).sin() + h3 * (3.0 * ph + f3).sin());
            }
            for &(at, h) in &steps {
                if x >= at {
                    v += h;
                }
            }
            for &(at, h, w) in &bumps {
                v += h * (-((x - at) / w).powi(2)).exp();
            }
            ar = phi * ar + (1.0 - phi * phi).sqrt() * r.gauss();
            out.push(v + self.rough_um * ar + self.white_um * r.gauss());
        }
        out
    }
}

/// One curve of a family with what a bench needs to judge a reconstruction of it.
pub struct Curve {
    pub n: usize,
    pub step_um: f64,
    /// The true curve (without sensor noise).
    pub truth: Vec<f64>,
    /// True periods, the dominant first (empty: none).
    pub periods: Vec<f64>,
    /// Sensor noise σ added to each sample.
    pub noise_um: f64,
}

/// The families on 1,901 points at 5 µm, each amplitude of order 1 µm:
/// - single: one period anywhere in 80–2,000 µm; two: a second at a ratio 1.3–2.7 away;
///   limit: a period of 2.1–2.9 grid steps; chirp: the period drifts up to ±4 % over the travel;
///   noise: trend and correlated roughness, no period; steps: a period, steps and bumps.
///
/// and two on 4,303 points at 2.5 µm, as a real leadscrew axis measured over ±20 µm:
/// - leadscrew: a 120–600 µm period of 2–8 µm with harmonics and envelope, sometimes a weaker
///   second period (motor step or gear), 5–15 µm of bow and tilt, defects, 0.05–0.5 µm
///   roughness and 0.01–0.3 µm sensor noise;
/// - rough: no period, 10–20 µm of drift and 2–26 µm of scatter in the curve itself (a noisy
///   laser-triangulation axis).
pub fn family(name: &str, seed: u64) -> Option<Curve> {
    let mut r =
        Rng(seed.wrapping_mul(0x9E37_79B9) ^ (name.len() as u64) << 40 ^ name.as_bytes()[0] as u64);
    let mut sp = Spec::new(1901, 5.0);
    let mut noise = 0.01;
    let amp = |r: &mut Rng, k: usize| (0.5 + r.next()) / (1 + k) as f64;
    match name {
        "single" | "chirp" | "steps" => {
            let p = r.log_uniform(80.0, 2000.0);
            sp.cyclic = vec![(p, amp(&mut r, 0))];
            sp.envelope = 0.15;
            if name == "chirp" {
                sp.drift = 0.08 * (r.next() - 0.5);
            }
            if name == "steps" {
                (sp.steps, sp.bumps, sp.defect_um) = (3, 3, 0.4);
            }
        }
        "two" => {
            let p1 = r.log_uniform(80.0, 2000.0);
            let ratio = 1.3 + 1.4 * r.next();
            let p2 = if p1 * ratio <= 2000.0 {
                p1 * ratio
            } else {
                p1 / ratio
            };
            sp.cyclic = vec![
                (p1, amp(&mut r, 0)),
                (p2.clamp(80.0, 2000.0), amp(&mut r, 1)),
            ];
            sp.envelope = 0.15;
        }
        "limit" => {
            sp.cyclic = vec![(sp.step_um * (2.1 + 0.8 * r.next()), amp(&mut r, 0))];
            sp.envelope = 0.15;
        }
        "noise" => {
            sp.rough_um = 0.3;
            noise = 0.1;
        }
        "leadscrew" => {
            sp = Spec::new(4303, 2.5);
            let p = r.log_uniform(120.0, 600.0);
            sp.cyclic = vec![(p, r.log_uniform(2.0, 8.0))];
            if r.next() < 0.4 {
                let q = p * (0.2 + 0.6 * r.next());
                sp.cyclic
                    .push((q.max(4.0 * sp.step_um), r.log_uniform(0.2, 1.5)));
            }
            sp.harmonics = [0.2 + 0.3 * r.next(), 0.1 * r.next()];
            sp.envelope = 0.3;
            sp.trend_um = r.log_uniform(2.5, 7.5);
            sp.rough_um = r.log_uniform(0.05, 0.5);
            sp.rough_corr_um = r.log_uniform(5.0, 40.0);
            (sp.steps, sp.bumps, sp.defect_um) = (1, 2, 1.0);
            noise = r.log_uniform(0.01, 0.3);
        }
        "rough" => {
            sp = Spec::new(4303, 2.5);
            sp.trend_um = r.log_uniform(5.0, 10.0);
            sp.rough_um = r.log_uniform(2.0, 10.0);
            sp.rough_corr_um = r.log_uniform(20.0, 200.0);
            sp.white_um = r.log_uniform(2.0, 26.0);
        }
        _ => return None,
    }
    let periods = sp.cyclic.iter().map(|c| c.0).collect();
    Some(Curve {
        n: sp.n,
        step_um: sp.step_um,
        truth: sp.render(seed),
        periods,
        noise_um: noise,
    })
}

/// m distinct random grid indices below n, ascending (partial Fisher–Yates).
pub fn pick(n: usize, m: usize, seed: u64) -> Vec<usize> {
    let mut r = Rng(seed ^ 0x5DEE_CE66);
    let mut all: Vec<usize> = (0..n).collect();
    for i in 0..m.min(n) {
        let j = i + (r.next() * (n - i) as f64) as usize;
        all.swap(i, j.min(n - 1));
    }
    let mut idx = all[..m.min(n)].to_vec();
    idx.sort_unstable();
    idx
}

/// The samples of `c` at `idx` with its sensor noise (seeded apart from the curve).
pub fn sample(c: &Curve, idx: &[usize], seed: u64) -> Vec<f64> {
    let mut r = Rng(seed ^ 0xA5A5_0000);
    idx.iter()
        .map(|&i| c.truth[i] + c.noise_um * r.gauss())
        .collect()
}

/// m for a curve of n points at the sampling fraction m_ref of 1,901 (m = 100 of 1,901 is
/// 226 of 4,303: 5 %).
pub fn scaled_m(m_ref: usize, n: usize) -> usize {
    ((m_ref as f64 * n as f64 / 1901.0).round() as usize).clamp(2, n)
}
