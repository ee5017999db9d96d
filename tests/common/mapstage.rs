//! A rough stacked XY stage for the 2D map tests, written from the physics of the stage (not from
//! csmetro_sim, not from recon2d): X carries Y; each axis has a scale error, a leadscrew cyclic
//! error (pitch 200–1000 µm, 2nd and 3rd harmonics, an amplitude that varies slowly along the
//! travel), a bow; each axis's straightness shows in the other component; squareness; and each
//! carriage's yaw (slow + a cyclic part at its leadscrew pitch) times its Abbe offset.
//!
//! The amplitudes are set so that linear interpolation on a Delaunay triangulation of random
//! samples of the 1901 × 841 (5 µm) grid gives about the figures for "such maps"
//! (~0.09 µm mean / ~4 µm max from 2 %, ~0.27 / ~4 from 0.5 %); the bench prints them.
#![allow(dead_code, unreachable_pub)]
use std::f64::consts::TAU;

/// SplitMix64: independent of the project's generators.
pub struct Rng(pub u64);
impl Rng {
    pub fn next(&mut self) -> f64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64
    }
    pub fn uniform(&mut self, a: f64, b: f64) -> f64 {
        a + (b - a) * self.next()
    }
    pub fn gauss(&mut self) -> f64 {
        let (u, v) = (self.next().max(1e-300), self.next());
        (-2.0 * u.ln()).sqrt() * (TAU * v).cos()
    }
}

/// One axis of the stage along its own travel [0, len] µm.
#[derive(Debug, Clone)]
pub struct Axis {
    pub len: f64,
    /// Scale error, µm/µm.
    pub scale: f64,
    /// Bow of the positioning error, µm at the ends relative to the middle.
    pub bow: f64,
    /// Leadscrew pitch (µm) and fundamental amplitude (µm).
    pub pitch: f64,
    pub amp: f64,
    /// Relative amplitudes of the 2nd and 3rd harmonics, and all phases (rad).
    pub harm: [f64; 2],
    pub phase: [f64; 3],
    /// Slow envelope of the cyclic amplitude: 1 + e1·s + e2·sin(π s), s ∈ [-1, 1].
    pub env: [f64; 2],
    /// Straightness seen by the other component: bow (µm) and a leadscrew wobble (µm).
    pub str_bow: f64,
    pub str_cubic: f64,
    pub str_wobble: f64,
    /// Yaw of the carriage (µrad): slow (amplitude, wavelength µm) and cyclic at the pitch.
    pub yaw_slow: f64,
    pub yaw_wave: f64,
    pub yaw_cyc: f64,
    pub yaw_phase: f64,
    /// Abbe offset of the drive line across the travel (µm, in the other coordinate).
    pub abbe_at: f64,
}

impl Axis {
    fn random(r: &mut Rng, len: f64, pitch: f64, amp: f64, other_len: f64) -> Self {
        Self {
            len,
            scale: r.uniform(-20e-6, 20e-6),
            bow: r.uniform(-1.0, 1.0),
            pitch,
            amp,
            harm: [r.uniform(0.25, 0.4), r.uniform(0.08, 0.15)],
            phase: [TAU * r.next(), TAU * r.next(), TAU * r.next()],
            env: [r.uniform(-0.3, 0.3), r.uniform(0.1, 0.25)],
            str_bow: r.uniform(-0.8, 0.8),
            str_cubic: r.uniform(-0.3, 0.3),
            str_wobble: r.uniform(0.05, 0.15),
            yaw_slow: r.uniform(20.0, 50.0),
            yaw_wave: r.uniform(0.8, 1.6) * len,
            yaw_cyc: r.uniform(2.0, 6.0),
            yaw_phase: TAU * r.next(),
            abbe_at: r.uniform(0.3, 0.7) * other_len,
        }
    }
    fn s(&self, t: f64) -> f64 {
        2.0 * t / self.len - 1.0
    }
    /// The leadscrew's cyclic error at t (µm).
    pub fn cyclic(&self, t: f64) -> f64 {
        let s = self.s(t);
        let w = TAU * t / self.pitch;
        let e = 1.0 + self.env[0] * s + self.env[1] * (std::f64::consts::PI * s).sin();
        self.amp
            * e
            * ((w + self.phase[0]).sin()
                + self.harm[0] * (2.0 * w + self.phase[1]).sin()
                + self.harm[1] * (3.0 * w + self.phase[2]).sin())
    }
    /// Positioning error along the axis's own travel (µm).
    pub fn positioning(&self, t: f64) -> f64 {
        let s = self.s(t);
        self.scale * t + self.bow * (s * s - 1.0 / 3.0) + self.cyclic(t)
    }
    /// Straightness: the error across the travel (µm).
    pub fn straightness(&self, t: f64) -> f64 {
        let s = self.s(t);
        self.str_bow * (s * s - 1.0 / 3.0)
            + self.str_cubic * s * s * s
            + self.str_wobble * (TAU * t / self.pitch + self.phase[0] + 0.7).sin()
    }
    /// Yaw of the carriage (µrad).
    pub fn yaw(&self, t: f64) -> f64 {
        self.yaw_slow * (TAU * t / self.yaw_wave + self.yaw_phase).sin()
            + self.yaw_cyc * (TAU * t / self.pitch + self.phase[0] + 1.9).sin()
    }
}

/// The stacked XY stage: X below, Y on top.
#[derive(Debug, Clone)]
pub struct Stage {
    pub x: Axis,
    pub y: Axis,
    /// Squareness of Y to X (µrad).
    pub squareness: f64,
}

impl Stage {
    /// A stage over 9500 × 4200 µm (the demo's travels) with pitches and amplitudes drawn from
    /// `seed`: X pitch 300–700 µm, Y pitch 200–500 µm, cyclic amplitudes ~1.5–2.5 µm.
    pub fn new(seed: u64) -> Self {
        Self::with_travel(seed, 9500.0, 4200.0)
    }
    pub fn with_travel(seed: u64, lx: f64, ly: f64) -> Self {
        let mut r = Rng(seed);
        let (px, py) = (r.uniform(300.0, 700.0), r.uniform(200.0, 500.0));
        let (ax, ay) = (r.uniform(1.8, 2.5), r.uniform(1.3, 2.0));
        Self {
            x: Axis::random(&mut r, lx, px, ax, ly),
            y: Axis::random(&mut r, ly, py, ay, lx),
            squareness: r.uniform(-30.0, 30.0),
        }
    }
    /// The true errors at (x, y) µm: (e_x µm, e_y µm, θ µrad).
    pub fn truth(&self, x: f64, y: f64) -> (f64, f64, f64) {
        let (tx, ty) = (self.x.yaw(x), self.y.yaw(y));
        // X carriage's yaw swings the whole Y axis: the point at y is (y - drive line) from the
        // X drive, an Abbe arm in e_x; Y's yaw acts with the arm (x - Y's drive line) in e_y.
        let ex = self.x.positioning(x) + self.y.straightness(y) + self.squareness * 1e-6 * y
            - (y - self.x.abbe_at) * tx * 1e-6;
        let ey = self.y.positioning(y)
            + self.x.straightness(x)
            + (x - self.y.abbe_at) * (tx + ty) * 1e-6;
        (ex, ey, tx + ty)
    }
}
