//! The maps' band on surfaces it was not tuned on: a third generator, written after the band's
//! settings were fixed (session 38 tuned them on reconstruct2d_rough.rs's six surfaces), with its
//! own RNG (xorshift64*) and structures neither of the other two generators has: a stitching
//! step across a line, an oblique ripple no separable model holds, small pits narrower than the
//! sample spacing at 0.5 %, squareness, and twice their sensor noise (0.02 µm).
use csmetro::grid::Grid;
use csmetro::recon2d::{self, Grid2, MapSamples, Method2};
use std::f64::consts::TAU;

/// xorshift64* (Vigna 2016): not the SplitMix64 of mapstage.rs nor the PCG of the second surface.
struct Xs(u64);
impl Xs {
    fn new(seed: u64) -> Self {
        Xs(seed.wrapping_mul(0x2545_F491_4F6C_DD1D) | 1)
    }
    fn unit(&mut self) -> f64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        (self.0.wrapping_mul(0x2545_F491_4F6C_DD1D) >> 11) as f64 / (1u64 << 53) as f64
    }
    fn range(&mut self, a: f64, b: f64) -> f64 {
        a + (b - a) * self.unit()
    }
    fn sign(&mut self) -> f64 {
        if self.unit() < 0.5 {
            -1.0
        } else {
            1.0
        }
    }
    /// Standard normal (Box–Muller, cosine branch).
    fn normal(&mut self) -> f64 {
        let u = self.unit().max(1e-300);
        (-2.0 * u.ln()).sqrt() * (TAU * self.unit()).cos()
    }
}

/// One component: own-axis leadscrew, quadratic bow, squareness, stitching step (e_x only, along
/// x = x0; e_y along y = y0), oblique ripple, pits.
struct Part {
    pitch: f64,
    amp: f64,
    phase: f64,
    bow: f64,
    square: f64,
    step_at: f64,
    step: f64,
    ripple: (f64, f64, f64, f64),
}

struct Third {
    lx: f64,
    ly: f64,
    parts: [Part; 2],
    /// Pits shared by both components: centre x, y, radius µm, depth µm (e_x), depth (e_y).
    pits: Vec<(f64, f64, f64, f64, f64)>,
    noise_um: f64,
}

impl Third {
    fn new(seed: u64, lx: f64, ly: f64) -> Self {
        let mut r = Xs::new(seed);
        let part = |span: f64, r: &mut Xs| Part {
            pitch: r.range(300.0, span / 4.5),
            amp: r.range(0.4, 1.5),
            phase: TAU * r.unit(),
            bow: r.range(-0.4, 0.4),
            square: r.range(-0.3, 0.3),
            step_at: r.range(0.25, 0.75) * span,
            step: r.sign() * r.range(0.05, 0.15),
            ripple: (
                r.range(80.0, 200.0),
                r.range(0.0, TAU / 2.0),
                r.range(0.02, 0.06),
                TAU * r.unit(),
            ),
        };
        let parts = [part(lx, &mut r), part(ly, &mut r)];
        let pits = (0..3)
            .map(|_| {
                (
                    r.range(0.1, 0.9) * lx,
                    r.range(0.1, 0.9) * ly,
                    r.range(30.0, 80.0),
                    r.sign() * r.range(0.05, 0.2),
                    r.sign() * r.range(0.05, 0.2),
                )
            })
            .collect();
        Self {
            lx,
            ly,
            parts,
            pits,
            noise_um: 0.02,
        }
    }

    fn truth(&self, x: f64, y: f64) -> (f64, f64, f64) {
        let mut out = [0.0; 2];
        for (c, (p, o)) in self.parts.iter().zip(&mut out).enumerate() {
            let (t, other, span, ospan) = if c == 0 {
                (x, y, self.lx, self.ly)
            } else {
                (y, x, self.ly, self.lx)
            };
            let s = 2.0 * t / span - 1.0;
            let (lambda, angle, amp, phase) = p.ripple;
            let along = x * angle.cos() + y * angle.sin();
            *o = p.amp * (TAU * t / p.pitch + p.phase).sin()
                + p.bow * s * s
                + p.square * (2.0 * other / ospan - 1.0)
                + if t >= p.step_at { p.step } else { 0.0 }
                + amp * (TAU * along / lambda + phase).sin();
            for &(px, py, rad, dx, dy) in &self.pits {
                let g = (-((x - px).powi(2) + (y - py).powi(2)) / (2.0 * rad * rad)).exp();
                *o += g * if c == 0 { dx } else { dy };
            }
        }
        (out[0], out[1], 0.0)
    }

    fn draw(&self, g: &Grid2, frac: f64, seed: u64) -> MapSamples {
        let mut r = Xs::new(seed ^ 0x7419_0d00);
        crate::reconstruct2d_rough::draw_map(
            &mut r,
            Xs::unit,
            Xs::normal,
            g,
            frac,
            self.noise_um,
            |x, y| self.truth(x, y),
        )
    }
}

#[test]
fn maps_band_holds_on_a_third_surface_it_was_not_tuned_on() {
    let g = Grid2::new(
        "0:5:4000".parse::<Grid>().unwrap(),
        "0:5:3000".parse::<Grid>().unwrap(),
    )
    .unwrap();
    let mut failed = Vec::new();
    for (frac, seed) in [(0.02, 1), (0.02, 2), (0.005, 3), (0.005, 4)] {
        let f = Third::new(seed, 4000.0, 3000.0);
        let s = f.draw(&g, frac, seed);
        let (map, r) = recon2d::reconstruct(&g, &s, Method2::Auto).unwrap();
        let figs = crate::reconstruct2d_rough::band_figures_of(
            |x, y| f.truth(x, y),
            &g,
            [&map.ex, &map.ey, &map.u_ex, &map.u_ey],
        );
        for (what, (cover, sharp, err)) in ["e_x", "e_y"].into_iter().zip(figs) {
            eprintln!(
                "third surface {:.1} % seed {seed} ({}, m {}): {what} mean error {err:.4} µm, \
                 coverage {cover:.3}, sharpness {sharp:.2}",
                100.0 * frac,
                r.method,
                r.m
            );
            // Measured (XEON-S33): 2 % 0.976–0.992, sharpness 1.96–2.09; 0.5 % 0.914–0.980,
            // 1.74–1.98. Before the close pairs checked the noise proxies, 0.5 % was covered
            // 0.29–0.56 (the ripple and pits taken for noise). Over 0.98 at 2 % with a band
            // about twice the mean error: the ripple's error is bounded (|A sin|), and a ±2u of
            // its rms covers nearly all of it; the upper bound is 0.995, not the curves' 0.98.
            if !((0.90..=0.995).contains(&cover) && sharp <= 3.0) {
                failed.push(format!(
                    "{frac} seed {seed} {what}: coverage {cover:.3} sharpness {sharp:.2}"
                ));
            }
        }
    }
    assert!(failed.is_empty(), "{failed:?}");
}
