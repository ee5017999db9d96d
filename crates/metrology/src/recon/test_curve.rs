//! Paper-like error curves for recon's own tests, so that recon does not depend on the simulator:
//! a leadscrew error (harmonics of a 400 µm pitch with a linearly varying envelope), a secondary
//! periodicity, scale and bow, two local defects and AR(1) roughness, all seeded; and seeded
//! standard normal draws for the tests' noise.
use rand::{Rng, SeedableRng};

/// The curve at positions i·step_um, i < n, µm.
pub(crate) fn paper_like(n: usize, step_um: f64, seed: u64) -> Vec<f64> {
    use std::f64::consts::PI;
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let span = (step_um * (n.max(2) - 1) as f64).max(1e-300);
    let amps = [0.8, 0.25, 0.1];
    let phases: Vec<f64> = amps
        .iter()
        .map(|_| rng.random_range(0.0..2.0 * PI))
        .collect();
    let env = rng.random_range(-0.3..0.3);
    let (sec_period, sec_phase) = (
        rng.random_range(900.0..1500.0),
        rng.random_range(0.0..2.0 * PI),
    );
    let (scale_ppm, bow) = (rng.random_range(-20.0..20.0), rng.random_range(-0.8..0.8));
    let defects: Vec<(f64, f64, f64)> = (0..2)
        .map(|_| {
            (
                rng.random_range(0.0..span),
                rng.random_range(-0.3..0.3),
                rng.random_range(15.0..60.0),
            )
        })
        .collect();
    let (sigma, corr) = (0.03, 20.0);
    let phi = (-step_um / corr).exp();
    let mut rough = rng.random_range(-sigma..sigma);
    (0..n)
        .map(|i| {
            let x = i as f64 * step_um;
            let s = 2.0 * x / span - 1.0;
            let w = 2.0 * PI * x / 400.0;
            let lead: f64 = amps
                .iter()
                .zip(&phases)
                .enumerate()
                .map(|(h, (a, p))| a * ((h + 1) as f64 * w + p).cos())
                .sum();
            let defect: f64 = defects
                .iter()
                .map(|(c, a, sd)| a * (-0.5 * ((x - c) / sd).powi(2)).exp())
                .sum();
            if i > 0 {
                let e: f64 = rng.random_range(-1.0..1.0) * sigma * 3f64.sqrt();
                rough = phi * rough + (1.0 - phi * phi).sqrt() * e;
            }
            (1.0 + env * s) * lead
                + 0.15 * (2.0 * PI * x / sec_period + sec_phase).cos()
                + scale_ppm * 1e-6 * x
                + bow * (1.5 * s * s - 0.5)
                + defect
                + rough
        })
        .collect()
}

/// Standard normal draws (Box–Muller), seeded.
pub(crate) fn normals(seed: u64) -> impl FnMut() -> f64 {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    move || {
        let (u, v): (f64, f64) = (rng.random::<f64>().max(1e-300), rng.random());
        (-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos()
    }
}
