//! `reconstruct2d` on rough maps (tests/common/mapstage.rs: leadscrew cyclic errors of a few µm,
//! straightness, squareness, yaw × Abbe), the kind the targets are stated for.
#[path = "../common/mapstage.rs"]
mod mapstage;

use csmetro::grid::Grid;
use csmetro::recon2d::{self, Grid2, MapSamples, Method2};
use mapstage::{Rng, Stage};

fn grid(x: &str, y: &str) -> Grid2 {
    Grid2::new(x.parse::<Grid>().unwrap(), y.parse::<Grid>().unwrap()).unwrap()
}

/// m = frac · grid points, distinct, at random (partial Fisher–Yates), noise σ = 0.01 µm
/// (0.2 µrad on θ).
fn draw(stage: &Stage, g: &Grid2, frac: f64, seed: u64) -> MapSamples {
    let mut r = Rng(seed ^ 0x5eed);
    let n = g.len();
    let m = (frac * n as f64).round() as usize;
    let mut idx: Vec<usize> = (0..n).collect();
    let mut s = MapSamples {
        theta: Some(Vec::with_capacity(m)),
        ..Default::default()
    };
    for i in 0..m {
        let j = (i + (r.next() * (n - i) as f64) as usize).min(n - 1);
        idx.swap(i, j);
        let k = idx[i];
        let (ix, iy) = (k % g.x.n, k / g.x.n);
        let (ex, ey, t) = stage.truth(g.x.position(ix), g.y.position(iy));
        s.ix.push(ix);
        s.iy.push(iy);
        s.ex.push(ex + 0.01 * r.gauss());
        s.ey.push(ey + 0.01 * r.gauss());
        s.theta.as_mut().unwrap().push(t + 0.2 * r.gauss());
    }
    s
}

/// Mean and max |error| of e_x and of e_y over the whole grid: [(mean_x, max_x), (mean_y, max_y)].
fn errors(stage: &Stage, g: &Grid2, ex: &[f64], ey: &[f64]) -> [(f64, f64); 2] {
    let mut out = [(0.0, 0.0f64); 2];
    for j in 0..g.y.n {
        for i in 0..g.x.n {
            let (tx, ty, _) = stage.truth(g.x.position(i), g.y.position(j));
            let k = j * g.x.n + i;
            for (o, e) in out.iter_mut().zip([(ex[k] - tx).abs(), (ey[k] - ty).abs()]) {
                o.0 += e;
                o.1 = o.1.max(e);
            }
        }
    }
    for o in &mut out {
        o.0 /= g.len() as f64;
    }
    out
}

/// The target size, every method side by side, one JSON line each (release, by hand):
/// `cargo test --release --test system reconstruct2d_rough:: -- --ignored --nocapture`
fn bench(frac: f64, seed: u64, methods: &[Method2]) {
    let g = grid("0:5:9500", "0:5:4200");
    let stage = Stage::new(seed);
    let s = draw(&stage, &g, frac, seed);
    for &method in methods {
        let t0 = std::time::Instant::now();
        let (map, r) = recon2d::reconstruct(&g, &s, method).unwrap();
        let wall = t0.elapsed().as_secs_f64();
        let [(mx, xx), (my, xy)] = errors(&stage, &g, &map.ex, &map.ey);
        println!(
            "{}",
            serde_json::json!({
                "fraction": frac, "seed": seed, "nx": g.x.n, "ny": g.y.n, "m": s.len(),
                "method": r.method, "cv_error_um": r.cv_error_um, "solve_ms": r.solve_ms,
                "wall_s": wall,
                "ex_mean_um": mx, "ex_max_um": xx, "ey_mean_um": my, "ey_max_um": xy,
                "report": r,
            })
        );
    }
}

#[test]
#[ignore = "issue 39 target size (1901 x 841): run in release by hand"]
fn bench_rough_2_percent() {
    for seed in [1, 2, 3] {
        bench(0.02, seed, &[Method2::Physics, Method2::Linear]);
    }
}

#[test]
#[ignore = "issue 39 target size (1901 x 841): run in release by hand"]
fn bench_rough_half_percent() {
    for seed in [1, 2, 3] {
        bench(0.005, seed, &[Method2::Physics, Method2::Linear]);
    }
}

/// 2D DCT basis pursuit at the target size, for comparison (slow: up to 300 iterations of two
/// 1.6 M-point 2D DCTs per component).
#[test]
#[ignore = "issue 39 target size (1901 x 841): run in release by hand"]
fn bench_rough_bp() {
    bench(0.02, 1, &[Method2::Bp]);
}

/// The samples as the CLI reads them.
fn write_samples(path: &std::path::Path, g: &Grid2, s: &MapSamples) {
    let mut t = String::from("x_um,y_um,ex_um,ey_um,theta_urad\n");
    for (k, th) in s.theta.as_ref().unwrap().iter().enumerate() {
        t += &format!(
            "{},{},{},{},{th}\n",
            g.x.position(s.ix[k]),
            g.y.position(s.iy[k]),
            s.ex[k],
            s.ey[k]
        );
    }
    std::fs::write(path, t).unwrap();
}

/// e_x and e_y columns of a map CSV written by the CLI (x fastest, checked).
fn read_map(path: &std::path::Path, g: &Grid2) -> (Vec<f64>, Vec<f64>) {
    let text = std::fs::read_to_string(path).unwrap();
    let mut lines = text.lines();
    assert_eq!(lines.next(), Some("x_um,y_um,ex_um,ey_um,theta_urad"));
    let (mut ex, mut ey) = (Vec::new(), Vec::new());
    for (k, l) in lines.enumerate() {
        let v: Vec<f64> = l.split(',').map(|f| f.parse().unwrap()).collect();
        assert_eq!(
            (v[0], v[1]),
            (g.x.position(k % g.x.n), g.y.position(k / g.x.n))
        );
        ex.push(v[2]);
        ey.push(v[3]);
    }
    assert_eq!(ex.len(), g.len());
    (ex, ey)
}

/// Whether `periods` (JSON array of {period_um}) holds `want` within 1 %.
fn has_period(periods: &serde_json::Value, want: f64) -> bool {
    periods
        .as_array()
        .unwrap()
        .iter()
        .any(|p| (p["period_um"].as_f64().unwrap() / want - 1.0).abs() < 0.01)
}

/// A 4 × 3 mm corner of the workspace on the 5 µm grid (801 × 601; the Y pitch, up to 500 µm, needs
/// its ≥ 4 cycles in the span to count as a period): the sample density
/// and roughness at a fifth of the points, small enough for a debug build.
fn small() -> (Stage, Grid2) {
    (
        Stage::with_travel(5, 4000.0, 3000.0),
        grid("0:5:4000", "0:5:3000"),
    )
}

#[test]
fn rough_maps_meet_the_2_percent_targets_through_the_binary() {
    let (stage, g) = small();
    let s = draw(&stage, &g, 0.02, 5);
    let dir = tempfile::tempdir().unwrap();
    let samples = dir.path().join("samples.csv");
    write_samples(&samples, &g, &s);
    let out = dir.path().join("map.csv");
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_csmetro"))
        .args([
            "reconstruct2d",
            "--grid-x",
            "0:5:4000",
            "--grid-y",
            "0:5:3000",
        ])
        .args(["--method", "auto", "--json", "--samples"])
        .arg(&samples)
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let j: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let (ex, ey) = read_map(&out, &g);
    let [(mx, xx), (my, xy)] = errors(&stage, &g, &ex, &ey);
    let lin = recon2d::reconstruct(&g, &s, Method2::Linear).unwrap().0;
    let [(lmx, lxx), (lmy, lxy)] = errors(&stage, &g, &lin.ex, &lin.ey);
    eprintln!(
        "2 %: {} e_x {mx:.4}/{xx:.4} e_y {my:.4}/{xy:.4} µm; linear e_x {lmx:.4}/{lxx:.3} e_y {lmy:.4}/{lxy:.3}; periods x {} y {}",
        j["method"], j["periods_x"], j["periods_y"]
    );
    assert_eq!(j["method"], "physics", "{j}");
    // The 2 % targets: mean |error| ≤ 0.02 µm and max ≤ 0.2 µm, each component.
    for (what, mean, max) in [("e_x", mx, xx), ("e_y", my, xy)] {
        assert!(
            mean <= 0.02 && max <= 0.2,
            "{what}: mean {mean} max {max} µm"
        );
    }
    // Linear interpolation cannot follow the leadscrew between samples ~35 µm apart.
    assert!(lmx > 5.0 * mx && lmy > 5.0 * my && lxx.max(lxy) > 5.0 * xx.max(xy));
    // The leadscrew pitches are found from the samples.
    assert!(has_period(&j["periods_x"], stage.x.pitch), "{j}");
    assert!(has_period(&j["periods_y"], stage.y.pitch), "{j}");
    let names: Vec<&str> = j["candidates"]
        .as_array()
        .unwrap()
        .iter()
        .map(|c| c["method"].as_str().unwrap())
        .collect();
    assert!(
        names.contains(&"physics") && names.contains(&"linear"),
        "{names:?}"
    );
}

#[test]
fn rough_maps_meet_the_half_percent_targets() {
    let (stage, g) = small();
    let s = draw(&stage, &g, 0.005, 6);
    let (map, r) = recon2d::reconstruct(&g, &s, Method2::Physics).unwrap();
    let [(mx, xx), (my, xy)] = errors(&stage, &g, &map.ex, &map.ey);
    eprintln!(
        "0.5 %: m {} knot {:?} e_x {mx:.4}/{xx:.4} e_y {my:.4}/{xy:.4} µm",
        r.m, r.knot_um
    );
    // The 0.5 % targets: mean ≤ 0.05 µm, max ≤ 0.5 µm.
    for (what, mean, max) in [("e_x", mx, xx), ("e_y", my, xy)] {
        assert!(
            mean <= 0.05 && max <= 0.5,
            "{what}: mean {mean} max {max} µm"
        );
    }
    assert!(r
        .periods_x
        .iter()
        .any(|p| (p.period_um / stage.x.pitch - 1.0).abs() < 0.01));
    assert!(r
        .periods_y
        .iter()
        .any(|p| (p.period_um / stage.y.pitch - 1.0).abs() < 0.01));
}

#[test]
fn bp_through_the_binary_is_feasible_with_a_certified_gap() {
    // 0.6 × 0.3 mm at 10 µm (61 × 31): small enough for auto to cross-validate bp too, and for
    // a debug build's DCTs.
    let stage = Stage::with_travel(9, 600.0, 300.0);
    let g = grid("0:10:600", "0:10:300");
    let s = draw(&stage, &g, 0.15, 9);
    let dir = tempfile::tempdir().unwrap();
    let samples = dir.path().join("samples.csv");
    write_samples(&samples, &g, &s);
    let run = |method: &str, out: &std::path::Path| -> serde_json::Value {
        let o = std::process::Command::new(env!("CARGO_BIN_EXE_csmetro"))
            .args([
                "reconstruct2d",
                "--grid-x",
                "0:10:600",
                "--grid-y",
                "0:10:300",
            ])
            .args(["--method", method, "--json", "--samples"])
            .arg(&samples)
            .arg("--out")
            .arg(out)
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        serde_json::from_slice(&o.stdout).unwrap()
    };
    let out = dir.path().join("bp.csv");
    let j = run("bp", &out);
    assert_eq!(j["method"], "bp", "{j}");
    let solves = j["bp"].as_array().unwrap();
    assert_eq!(solves.len(), 3, "e_x, e_y and θ: {j}");
    let (ex, ey) = read_map(&out, &g);
    for (c, (solve, map)) in solves.iter().zip([&ex, &ey]).enumerate() {
        // Weak duality: the dual bound lies below ‖c‖₁, and the reported gap is theirs.
        let (l1, dual) = (
            solve["l1"].as_f64().unwrap(),
            solve["dual"].as_f64().unwrap(),
        );
        let gap = solve["rel_gap"].as_f64().unwrap();
        assert!(dual <= l1 * (1.0 + 1e-9), "{solve}");
        assert!(((l1 - dual) / l1 - gap).abs() < 1e-9, "{solve}");
        // The returned map is feasible: within ε of the samples.
        let b = if c == 0 { &s.ex } else { &s.ey };
        let r2: f64 = (0..s.len())
            .map(|k| (map[s.iy[k] * g.x.n + s.ix[k]] - b[k]).powi(2))
            .sum();
        let eps = solve["epsilon_um"].as_f64().unwrap();
        assert!(
            r2.sqrt() <= eps * (1.0 + 1e-6),
            "residual {} > ε {eps}",
            r2.sqrt()
        );
    }
    let [(mx, xx), (my, xy)] = errors(&stage, &g, &ex, &ey);
    eprintln!("bp: e_x {mx:.4}/{xx:.4} e_y {my:.4}/{xy:.4} µm; {j}");
    // Auto compares bp by its held-out error on a grid this size.
    let j = run("auto", &dir.path().join("auto.csv"));
    let bp = j["candidates"]
        .as_array()
        .unwrap()
        .iter()
        .find(|c| c["method"] == "bp")
        .unwrap_or_else(|| panic!("no bp candidate: {j}"));
    assert!(
        bp["cv_error_um"].as_f64().unwrap() > 0.0 && bp["folds"] == 1,
        "{j}"
    );
}
