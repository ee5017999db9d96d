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

/// e_x, e_y and their u (k = 1) columns of a map CSV written by the CLI (x fastest, checked).
type MapColumns = (Vec<f64>, Vec<f64>, Vec<f64>, Vec<f64>);
fn read_map(path: &std::path::Path, g: &Grid2) -> MapColumns {
    let text = std::fs::read_to_string(path).unwrap();
    let mut lines = text.lines();
    assert_eq!(
        lines.next(),
        Some("x_um,y_um,ex_um,ey_um,theta_urad,u_ex_um,u_ey_um")
    );
    let (mut ex, mut ey, mut ux, mut uy) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    for (k, l) in lines.enumerate() {
        let v: Vec<f64> = l.split(',').map(|f| f.parse().unwrap()).collect();
        assert_eq!(
            (v[0], v[1]),
            (g.x.position(k % g.x.n), g.y.position(k / g.x.n))
        );
        ex.push(v[2]);
        ey.push(v[3]);
        ux.push(v[5]);
        uy.push(v[6]);
    }
    assert_eq!(ex.len(), g.len());
    (ex, ey, ux, uy)
}

/// Share of the grid with |map − truth| ≤ 2u, and mean(2u) / mean |map − truth|, of e_x and e_y.
fn band_figures(stage: &Stage, g: &Grid2, map: [&[f64]; 4]) -> [(f64, f64); 2] {
    band_figures_of(|x, y| stage.truth(x, y), g, map).map(|(cover, sharp, _)| (cover, sharp))
}

/// [`band_figures`] against any truth (x, y) ↦ (e_x, e_y, …), with the mean |map − truth| (µm).
pub(crate) fn band_figures_of(
    truth: impl Fn(f64, f64) -> (f64, f64, f64),
    g: &Grid2,
    map: [&[f64]; 4],
) -> [(f64, f64, f64); 2] {
    let [ex, ey, ux, uy] = map;
    let mut out = [(0.0, 0.0, 0.0); 2];
    for (c, (v, u)) in [(ex, ux), (ey, uy)].into_iter().enumerate() {
        let (mut inside, mut err, mut band) = (0usize, 0.0, 0.0);
        for j in 0..g.y.n {
            for i in 0..g.x.n {
                let t = truth(g.x.position(i), g.y.position(j));
                let k = j * g.x.n + i;
                let e = (v[k] - if c == 0 { t.0 } else { t.1 }).abs();
                inside += usize::from(e <= 2.0 * u[k]);
                err += e;
                band += 2.0 * u[k];
            }
        }
        let n = g.len() as f64;
        out[c] = (inside as f64 / n, band / err, err / n);
    }
    out
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
    let (ex, ey, ux, uy) = read_map(&out, &g);
    let [(mx, xx), (my, xy)] = errors(&stage, &g, &ex, &ey);
    // The pointwise band (u_ex_um, u_ey_um) against this test's own truth.
    let [(cx, sx), (cy, sy)] = band_figures(&stage, &g, [&ex, &ey, &ux, &uy]);
    eprintln!("band: e_x coverage {cx:.3} sharpness {sx:.2}, e_y {cy:.3} / {sy:.2}");
    // Measured (XEON-S33): coverage 0.965 / 0.969, sharpness 2.54 / 2.69 (the targets
    // for curves, 0.90–0.98 and ≤ 3); with each distance bin's excess over the floor taken as
    // it came instead of shrunk by its sampling error: 0.981 / 0.987, 2.79 / 3.15; with the
    // in-sample residual RMS taken out down to a third of the quantile: 1.000, 6.63 / 7.00.
    for (what, cover, sharp) in [("e_x", cx, sx), ("e_y", cy, sy)] {
        assert!(
            (0.90..=0.98).contains(&cover) && sharp <= 3.0,
            "{what}: band coverage {cover} sharpness {sharp}"
        );
    }
    assert!(j["u_ex_mean_um"].as_f64().unwrap() > 0.0, "{j}");
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
    let [(cx, sx), (cy, sy)] = band_figures(&stage, &g, [&map.ex, &map.ey, &map.u_ex, &map.u_ey]);
    eprintln!("band 0.5 %: e_x coverage {cx:.3} sharpness {sx:.2}, e_y {cy:.3} / {sy:.2}");
    // Measured (XEON-S33): coverage 0.966 / 0.963, sharpness 2.72 / 2.78 (the excess taken as
    // it came: 0.978 / 0.967, 3.02 / 2.92; before the noise reference: 0.997 / 0.996, 4.01 /
    // 4.28).
    for (what, cover, sharp) in [("e_x", cx, sx), ("e_y", cy, sy)] {
        assert!(
            (0.90..=0.98).contains(&cover) && sharp <= 3.0,
            "{what}: band coverage {cover} sharpness {sharp}"
        );
    }
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
    let (ex, ey, _, _) = read_map(&out, &g);
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

/// A second map family for the band, independent of tests/common/mapstage.rs (its own generator
/// and RNG, another structure): per component a cubic polynomial in both coordinates, a
/// leadscrew-like periodic term along its own axis (fundamental and 2nd harmonic, amplitude
/// drifting linearly over the travel), the other axis's leadscrew seen weakly across, and one
/// local Gaussian bump (a guideway defect) that no separable model holds.
mod surface {
    use std::f64::consts::TAU;

    /// PCG-XSH-RR 32 (O'Neill 2014): not the SplitMix64 of mapstage.rs.
    pub(super) struct Pcg(u64);
    impl Pcg {
        pub(super) fn new(seed: u64) -> Self {
            let mut p = Pcg(seed.wrapping_mul(2_862_933_555_777_941_757).wrapping_add(7));
            p.u32();
            p
        }
        fn u32(&mut self) -> u32 {
            let old = self.0;
            self.0 = old
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1_442_695_040_888_963_407);
            let xorshifted = (((old >> 18) ^ old) >> 27) as u32;
            xorshifted.rotate_right((old >> 59) as u32)
        }
        /// Uniform in [0, 1).
        pub(super) fn unit(&mut self) -> f64 {
            let hi = u64::from(self.u32()) << 21;
            let lo = u64::from(self.u32()) >> 11;
            (hi | lo) as f64 / (1u64 << 53) as f64
        }
        pub(super) fn range(&mut self, a: f64, b: f64) -> f64 {
            a + (b - a) * self.unit()
        }
        /// Standard normal (Marsaglia's polar method).
        pub(super) fn normal(&mut self) -> f64 {
            loop {
                let (u, v) = (self.range(-1.0, 1.0), self.range(-1.0, 1.0));
                let s = u * u + v * v;
                if s > 0.0 && s < 1.0 {
                    return u * (-2.0 * s.ln() / s).sqrt();
                }
            }
        }
    }

    /// One component over [0, lx] × [0, ly].
    struct Component {
        /// Coefficients of x̂^i ŷ^j, i + j ≤ 3 (µm), x̂, ŷ ∈ [-1, 1].
        poly: Vec<(i32, i32, f64)>,
        /// Own axis's leadscrew: pitch µm, amplitude µm, drift per unit x̂, 2nd harmonic, phases.
        pitch: f64,
        amp: f64,
        drift: f64,
        second: f64,
        phase: [f64; 2],
        /// The other axis's leadscrew seen across (amplitude µm, phase).
        across: (f64, f64),
        /// Bump amplitude (µm).
        bump: f64,
    }

    pub(super) struct Surface {
        lx: f64,
        ly: f64,
        c: [Component; 2],
        /// Bump centre and radius (µm), shared by both components.
        bump_at: (f64, f64, f64),
    }

    impl Surface {
        pub(super) fn new(seed: u64, lx: f64, ly: f64) -> Self {
            let mut r = Pcg::new(seed);
            let bump_at = (
                r.range(0.2, 0.8) * lx,
                r.range(0.2, 0.8) * ly,
                r.range(150.0, 400.0),
            );
            // Pitches with at least 4 cycles over the travel (the period search needs them).
            let pitch = [r.range(250.0, lx / 5.0), r.range(200.0, ly / 5.0)];
            let comp = |pitch: f64, r: &mut Pcg| {
                let mut poly = Vec::new();
                for i in 0..=3 {
                    for j in 0..=(3 - i) {
                        poly.push((i, j, r.range(-0.5, 0.5) / f64::from(1 + i + j)));
                    }
                }
                Component {
                    poly,
                    pitch,
                    amp: r.range(0.8, 2.0),
                    drift: r.range(-0.2, 0.2),
                    second: r.range(0.1, 0.4),
                    phase: [TAU * r.unit(), TAU * r.unit()],
                    across: (r.range(0.05, 0.2), TAU * r.unit()),
                    bump: r.range(0.05, 0.15) * if r.unit() < 0.5 { -1.0 } else { 1.0 },
                }
            };
            let c = [comp(pitch[0], &mut r), comp(pitch[1], &mut r)];
            Self { lx, ly, c, bump_at }
        }

        /// (e_x, e_y, 0) µm at (x, y) µm.
        pub(super) fn truth(&self, x: f64, y: f64) -> (f64, f64, f64) {
            let (xh, yh) = (2.0 * x / self.lx - 1.0, 2.0 * y / self.ly - 1.0);
            let (bx, by, br) = self.bump_at;
            let bump = (-((x - bx).powi(2) + (y - by).powi(2)) / (2.0 * br * br)).exp();
            let pitches = [self.c[0].pitch, self.c[1].pitch];
            let mut out = [0.0; 2];
            for (own, (c, o)) in self.c.iter().zip(&mut out).enumerate() {
                let (t, s, other) = if own == 0 { (x, xh, y) } else { (y, yh, x) };
                let w = TAU * t / c.pitch;
                let poly: f64 = c
                    .poly
                    .iter()
                    .map(|&(i, j, a)| a * xh.powi(i) * yh.powi(j))
                    .sum();
                let lead = c.amp
                    * (1.0 + c.drift * s)
                    * ((w + c.phase[0]).sin() + c.second * (2.0 * w + c.phase[1]).sin());
                let across = c.across.0 * (TAU * other / pitches[1 - own] + c.across.1).sin();
                *o = poly + lead + across + c.bump * bump;
            }
            (out[0], out[1], 0.0)
        }
    }
}

/// m = frac · grid points of the second surface, distinct, at random, noise σ = 0.01 µm, all from
/// the surface module's own RNG.
fn draw_surface(f: &surface::Surface, g: &Grid2, frac: f64, seed: u64) -> MapSamples {
    let mut r = surface::Pcg::new(seed ^ 0xd1ce);
    draw_map(
        &mut r,
        surface::Pcg::unit,
        surface::Pcg::normal,
        g,
        frac,
        0.01,
        |x, y| f.truth(x, y),
    )
}

/// m = frac · grid points, distinct, at random (partial Fisher–Yates), each component of
/// `truth` with Gaussian noise `noise_um`: every draw from `unit` and `normal` of the one
/// generator `r` (each test surface brings its own).
pub(crate) fn draw_map<R>(
    r: &mut R,
    unit: fn(&mut R) -> f64,
    normal: fn(&mut R) -> f64,
    g: &Grid2,
    frac: f64,
    noise_um: f64,
    truth: impl Fn(f64, f64) -> (f64, f64, f64),
) -> MapSamples {
    let n = g.len();
    let m = (frac * n as f64).round() as usize;
    let mut idx: Vec<usize> = (0..n).collect();
    let mut s = MapSamples::default();
    for i in 0..m {
        let j = (i + (unit(r) * (n - i) as f64) as usize).min(n - 1);
        idx.swap(i, j);
        let (ix, iy) = (idx[i] % g.x.n, idx[i] / g.x.n);
        let (ex, ey, _) = truth(g.x.position(ix), g.y.position(iy));
        s.ix.push(ix);
        s.iy.push(iy);
        s.ex.push(ex + noise_um * normal(r));
        s.ey.push(ey + noise_um * normal(r));
    }
    s
}

#[test]
fn rough_maps_band_holds_on_a_second_surface() {
    let g = grid("0:5:4000", "0:5:3000");
    let mut failed = Vec::new();
    for (frac, seed) in [
        (0.02, 21),
        (0.005, 22),
        (0.02, 31),
        (0.02, 41),
        (0.005, 32),
        (0.005, 42),
    ] {
        let f = surface::Surface::new(seed, 4000.0, 3000.0);
        let s = draw_surface(&f, &g, frac, seed);
        let (map, r) = recon2d::reconstruct(&g, &s, Method2::Auto).unwrap();
        let [(cx, sx, mx), (cy, sy, my)] = band_figures_of(
            |x, y| f.truth(x, y),
            &g,
            [&map.ex, &map.ey, &map.u_ex, &map.u_ey],
        );
        eprintln!(
            "second surface {:.1} %: m {} {} e_x mean {mx:.4} µm coverage {cx:.3} sharpness {sx:.2}, \
             e_y mean {my:.4} µm {cy:.3} / {sy:.2}",
            100.0 * frac,
            r.m,
            r.method,
        );
        // Measured (XEON-S33), six surfaces: coverage 0.947–0.968, sharpness 2.60–2.92 (seeds
        // 21 / 22: 0.957 / 0.954, 2.65 / 2.63; 0.954 / 0.958, 2.91 / 2.82). The bump is the
        // map's error: a band of the distance to the samples only spread it over the whole map
        // (0.934–0.955, sharpness 2.86–3.42); its excess over the noise floor now varies over
        // the plane.
        for (what, cover, sharp) in [("e_x", cx, sx), ("e_y", cy, sy)] {
            if !((0.90..=0.98).contains(&cover) && sharp <= 3.0) {
                failed.push(format!("{frac} {what}: coverage {cover} sharpness {sharp}"));
            }
        }
    }
    assert!(failed.is_empty(), "{failed:?}");
}
