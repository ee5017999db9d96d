//! `csmetro reconstruct2d` against XY maps from a generator written here (not csmetro_sim, not the
//! code under test): each axis's error along its own travel (leadscrew sinusoid + slow trend), the
//! other axis's straightness, squareness, yaw times the Abbe offset, noise σ = 0.01 µm.
use std::path::Path;
use std::process::Command;

use csmetro::grid::Grid;
use csmetro::recon2d::{self, Grid2, MapSamples, Method2};
use rand::seq::index::sample;
use rand::SeedableRng;
use rand_distr::{Distribution, Normal};

const PI2: f64 = std::f64::consts::TAU;

/// The stage's true errors at (x, y) µm: (e_x µm, e_y µm, θ µrad).
fn truth(x: f64, y: f64) -> (f64, f64, f64) {
    // X axis along its travel: leadscrew (400 µm pitch, a 2nd harmonic) and a slow trend.
    let fx = 0.15 * (PI2 * x / 400.0 + 0.3).sin()
        + 0.04 * (PI2 * x / 200.0 + 1.0).sin()
        + 1.2e-4 * x
        + 0.3 * (x / 9500.0).powi(2);
    // Y axis along its travel: leadscrew of 500 µm and a trend.
    let fy = 0.12 * (PI2 * y / 500.0 + 1.1).sin() - 0.8e-4 * y + 0.1 * (y / 4200.0).powi(3);
    // Yaw of each carriage (µrad), varying slowly along its own travel.
    let yaw_x = 40.0 * (PI2 * x / 6000.0).sin() + 8.0 * x / 9500.0;
    let yaw_y = 30.0 * (PI2 * y / 5000.0).cos();
    // Straightness of each axis seen by the other, squareness 20 µrad.
    let sx = 0.1 * (PI2 * y / 3000.0).sin();
    let sy = 0.2 * (PI2 * x / 7000.0).sin() + 0.05 * (x / 9500.0).powi(2);
    let squareness = 20e-6;
    // Abbe: a yaw θ (µrad) moves the tool point at an offset d (µm) by d·θ·1e-6 across it.
    let ex = fx + sx + squareness * y - (y - 2100.0) * yaw_x * 1e-6;
    let ey = fy + sy + (x - 4750.0) * yaw_y * 1e-6;
    (ex, ey, yaw_x + yaw_y)
}

/// A fraction of the grid's points at random, with noise σ = 0.01 µm (and 0.2 µrad on θ).
fn draw(g: &Grid2, frac: f64, seed: u64) -> MapSamples {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let m = (frac * g.len() as f64).round() as usize;
    let noise = Normal::new(0.0, 0.01).unwrap();
    let noise_t = Normal::new(0.0, 0.2).unwrap();
    let mut s = MapSamples {
        theta: Some(Vec::new()),
        ..Default::default()
    };
    for k in sample(&mut rng, g.len(), m) {
        let (ix, iy) = (k % g.x.n, k / g.x.n);
        let (ex, ey, t) = truth(g.x.position(ix), g.y.position(iy));
        s.ix.push(ix);
        s.iy.push(iy);
        s.ex.push(ex + noise.sample(&mut rng));
        s.ey.push(ey + noise.sample(&mut rng));
        s.theta.as_mut().unwrap().push(t + noise_t.sample(&mut rng));
    }
    s
}

/// (mean, max) |error| of e_x and e_y over the whole grid.
fn errors(g: &Grid2, ex: &[f64], ey: &[f64]) -> (f64, f64) {
    let (mut sum, mut max) = (0.0, 0.0f64);
    for j in 0..g.y.n {
        for i in 0..g.x.n {
            let (tx, ty, _) = truth(g.x.position(i), g.y.position(j));
            let k = j * g.x.n + i;
            let (a, b) = ((ex[k] - tx).abs(), (ey[k] - ty).abs());
            sum += a + b;
            max = max.max(a).max(b);
        }
    }
    (sum / (2 * g.len()) as f64, max)
}

fn grid(x: &str, y: &str) -> Grid2 {
    Grid2::new(x.parse::<Grid>().unwrap(), y.parse::<Grid>().unwrap()).unwrap()
}

fn write_samples(path: &Path, g: &Grid2, s: &MapSamples) {
    let mut t = String::from("x_um,y_um,ex_um,ey_um,theta_urad\n");
    let th = s.theta.as_ref().unwrap();
    for (k, theta) in th.iter().enumerate() {
        t += &format!(
            "{},{},{},{},{theta}\n",
            g.x.position(s.ix[k]),
            g.y.position(s.iy[k]),
            s.ex[k],
            s.ey[k],
        );
    }
    std::fs::write(path, t).unwrap();
}

/// Reads a map CSV: checks header and x-fastest order, returns (e_x, e_y, θ).
fn read_map(path: &Path, g: &Grid2) -> (Vec<f64>, Vec<f64>, Vec<f64>) {
    let text = std::fs::read_to_string(path).unwrap();
    let mut lines = text.lines();
    assert_eq!(lines.next(), Some("x_um,y_um,ex_um,ey_um,theta_urad"));
    let (mut ex, mut ey, mut th) = (vec![], vec![], vec![]);
    for (k, l) in lines.enumerate() {
        let v: Vec<f64> = l.split(',').map(|f| f.parse().unwrap()).collect();
        assert_eq!(v.len(), 5);
        assert_eq!(v[0], g.x.position(k % g.x.n), "line {}", k + 2);
        assert_eq!(v[1], g.y.position(k / g.x.n), "line {}", k + 2);
        ex.push(v[2]);
        ey.push(v[3]);
        th.push(v[4]);
    }
    assert_eq!(ex.len(), g.len());
    (ex, ey, th)
}

#[test]
fn physics_beats_linear_from_2_percent_through_the_binary() {
    let g = grid("0:25:9500", "0:25:4200");
    assert_eq!((g.x.n, g.y.n), (381, 169));
    let s = draw(&g, 0.02, 7);
    let dir = tempfile::tempdir().unwrap();
    let samples = dir.path().join("samples.csv");
    write_samples(&samples, &g, &s);
    let mut got = std::collections::HashMap::new();
    for method in ["physics", "linear", "auto"] {
        let out = dir.path().join(format!("{method}.csv"));
        let o = Command::new(env!("CARGO_BIN_EXE_csmetro"))
            .args([
                "reconstruct2d",
                "--grid-x",
                "0:25:9500",
                "--grid-y",
                "0:25:4200",
            ])
            .args(["--method", method, "--json", "--samples"])
            .arg(&samples)
            .arg("--out")
            .arg(&out)
            .output()
            .unwrap();
        assert!(
            o.status.success(),
            "{method}: {}",
            String::from_utf8_lossy(&o.stderr)
        );
        let stdout = String::from_utf8(o.stdout).unwrap();
        assert_eq!(stdout.trim().lines().count(), 1, "exactly one JSON object");
        let j: serde_json::Value = serde_json::from_str(stdout.trim()).unwrap();
        assert_eq!(j["nx"], 381);
        assert_eq!(j["ny"], 169);
        assert_eq!(j["m"], s.len());
        assert!(j["solve_ms"].as_f64().unwrap() >= 0.0);
        let cv = j["cv_error_um"].as_f64().unwrap();
        let (ex, ey, th) = read_map(&out, &g);
        let (mean, max) = errors(&g, &ex, &ey);
        eprintln!(
            "2 %, {method} ({}): cv {cv:.4} µm, mean {mean:.4} µm, max {max:.4} µm",
            j["method"]
        );
        got.insert(
            method,
            (j["method"].as_str().unwrap().to_string(), cv, mean, max, th),
        );
    }
    let (_, cv_p, mean_p, max_p, th_p) = &got["physics"];
    let (_, cv_l, mean_l, max_l, _) = &got["linear"];
    // The model averages the noise of ~3 samples per unknown: its mean error stays below σ
    // (0.01 µm) and its max below half the 2 % target (0.2 µm) with room to spare.
    assert!(*mean_p < 0.01, "physics mean {mean_p} µm");
    assert!(*max_p < 0.1, "physics max {max_p} µm");
    // Linear interpolation cannot follow a 200 µm harmonic between samples ~220 µm apart.
    assert!(
        *mean_p * 3.0 < *mean_l,
        "physics {mean_p} vs linear {mean_l}"
    );
    assert!(*max_p * 2.0 < *max_l, "physics {max_p} vs linear {max_l}");
    // The cross-validation sees the same ranking, and auto follows it.
    assert!(cv_p < cv_l);
    assert_eq!(got["auto"].0, "physics");
    assert_eq!(got["auto"].2, *mean_p);
    // θ is reconstructed too: yaw_x + yaw_y is within the model (F + G); noise 0.2 µrad, so
    // the max over 64 k points of the fit's error stays within 5σ of one sample.
    let mut worst = 0.0f64;
    for j in 0..g.y.n {
        for i in 0..g.x.n {
            let (_, _, t) = truth(g.x.position(i), g.y.position(j));
            worst = worst.max((th_p[j * g.x.n + i] - t).abs());
        }
    }
    assert!(worst < 1.0, "θ max error {worst} µrad");
}

#[test]
fn physics_beats_linear_from_half_a_percent() {
    // 0.5 % of a 381 x 169 grid is only 322 points, too few for a 400 µm leadscrew period on a
    // 9.5 mm travel; a 10 µm grid gives 2000 samples, as the 5 µm target grid's 0.5 % gives 8000.
    let g = grid("0:10:9500", "0:10:4200");
    let s = draw(&g, 0.005, 11);
    let (pm, pr) = recon2d::reconstruct(&g, &s, Method2::Physics).unwrap();
    let (lm, lr) = recon2d::reconstruct(&g, &s, Method2::Linear).unwrap();
    let (mean_p, max_p) = errors(&g, &pm.ex, &pm.ey);
    let (mean_l, max_l) = errors(&g, &lm.ex, &lm.ey);
    eprintln!(
        "0.5 %: physics (knot {:?} µm, cv {:.4}) mean {mean_p:.4} max {max_p:.4}; linear (cv {:.4}) mean {mean_l:.4} max {max_l:.4}",
        pr.knot_um, pr.cv_error_um, lr.cv_error_um
    );
    assert_eq!(pr.m, s.len());
    // As at 2 %: below σ on average, below half the 0.5 % max target (0.5 µm) / 5.
    assert!(mean_p < 0.01, "physics mean {mean_p} µm");
    assert!(max_p < 0.1, "physics max {max_p} µm");
    assert!(mean_p * 3.0 < mean_l, "physics {mean_p} vs linear {mean_l}");
    assert!(max_p * 2.0 < max_l, "physics {max_p} vs linear {max_l}");
    assert!(pr.cv_error_um < lr.cv_error_um);
}

/// The target size, physics and linear side by side (release build, run by hand):
/// `cargo test --release --test system reconstruct2d_maps:: -- --ignored --nocapture bench_map2d_2`
fn bench(frac: f64, seed: u64) {
    let g = grid("0:5:9500", "0:5:4200");
    let s = draw(&g, frac, seed);
    for method in [Method2::Physics, Method2::Linear, Method2::Auto] {
        let (map, r) = recon2d::reconstruct(&g, &s, method).unwrap();
        let (mean, max) = errors(&g, &map.ex, &map.ey);
        let mut ex_mean = 0.0;
        let mut ey_mean = 0.0;
        let (mut ex_max, mut ey_max) = (0.0f64, 0.0f64);
        for j in 0..g.y.n {
            for i in 0..g.x.n {
                let (tx, ty, _) = truth(g.x.position(i), g.y.position(j));
                let k = j * g.x.n + i;
                let (a, b) = ((map.ex[k] - tx).abs(), (map.ey[k] - ty).abs());
                ex_mean += a;
                ey_mean += b;
                ex_max = ex_max.max(a);
                ey_max = ey_max.max(b);
            }
        }
        let n = g.len() as f64;
        println!(
            "{}",
            serde_json::json!({
                "fraction": frac, "nx": g.x.n, "ny": g.y.n, "m": s.len(),
                "method": format!("{method:?}").to_lowercase(), "chosen": r.method,
                "knot_um": r.knot_um, "cv_error_um": r.cv_error_um, "solve_ms": r.solve_ms,
                "mean_um": mean, "max_um": max,
                "ex_mean_um": ex_mean / n, "ex_max_um": ex_max,
                "ey_mean_um": ey_mean / n, "ey_max_um": ey_max,
            })
        );
    }
}

#[test]
#[ignore = "issue 39 target size (1901 x 841): run in release by hand"]
fn bench_map2d_2_percent() {
    bench(0.02, 21);
}

#[test]
#[ignore = "issue 39 target size (1901 x 841): run in release by hand"]
fn bench_map2d_half_percent() {
    bench(0.005, 22);
}
