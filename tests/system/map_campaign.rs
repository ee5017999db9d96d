//! A `[map]` campaign end to end on the simulated XY stage: both axes move to stratified random
//! points, the camera measures, the store commits, the worker reconstructs e_x(x, y), e_y(x, y)
//! and θ with csmetro::recon2d, and the report writes the map, heat maps, the 2D compensation
//! table and ISO 230-1 figures. The truth the map is judged against is computed here in closed
//! form from the model this test writes, not by the simulator's code.
use crate::common;

use std::f64::consts::TAU;
use std::path::{Path, PathBuf};
use std::process::Stdio;
use std::time::{Duration, Instant};

use common::{bin, json_of};
use csmetro::campaign::spec::Campaign;
use csmetro::store::Store;

const X0: f64 = 1000.0;
const Y0: f64 = 1000.0;
const STEP: f64 = 50.0;
const NX: usize = 40;
const NY: usize = 20;

/// The stage: both axes' errors, with couplings (straightness, squareness).
const MODEL: &str = r#"
[stage]
travel_x_um = [0.0, 9500.0]
travel_y_um = [0.0, 4200.0]

[[effect]]
kind = "scale"
axis = "x"
ppm = 150
ref_um = 0

[[effect]]
kind = "harmonic"
axis = "x"
component = "axis"
period_um = 800
cos_um = [0.3]

[[effect]]
kind = "backlash"
axis = "x"
reversal_um = 2.0

[[effect]]
kind = "straightness"
axis = "x"
legendre_um = [0.5]

[[effect]]
kind = "scale"
axis = "y"
ppm = -100
ref_um = 0

[[effect]]
kind = "squareness"
axis = "y"
angle_urad = 40

[[effect]]
kind = "harmonic"
axis = "y"
component = "axis"
period_um = 600
cos_um = [0.2]
"#;

/// The x carriage's yaw, appended to [`MODEL`] by the tests that check θ (a rotated pattern
/// costs the simulated camera and the decoder several times the CPU of an upright one).
const YAW: &str = r#"
[[effect]]
kind = "yaw_abbe"
axis = "x"
yaw_urad = [100, 60]
offset_um = 1500
"#;

/// The yaw of the x carriage at x, µrad: the carriage's rotation (counterclockwise +).
fn yaw_urad(x: f64) -> f64 {
    100.0 + 60.0 * (2.0 * x / 9500.0 - 1.0)
}

/// The model above at (x, y), both axes approached forward (`d` = 1) or backward (-1):
/// (e_x, e_y), µm.
fn truth(x: f64, y: f64, d: f64, yaw: bool) -> (f64, f64) {
    let s = 2.0 * x / 9500.0 - 1.0;
    let p2 = 0.5 * (3.0 * s * s - 1.0);
    let abbe = if yaw {
        -yaw_urad(x) * 1e-6 * (y - 1500.0)
    } else {
        0.0
    };
    let ex = 150e-6 * x + 0.3 * (TAU * x / 800.0).cos() + d + 40e-6 * y + abbe;
    let ey = 0.5 * p2 - 100e-6 * y + 0.2 * (TAU * y / 600.0).cos();
    (ex, ey)
}

fn campaign(dir: &Path, extra: &str, time_scale: f64, yaw: bool) -> PathBuf {
    let model = if yaw {
        format!("{MODEL}{YAW}")
    } else {
        MODEL.to_string()
    };
    std::fs::write(dir.join("model.toml"), model).unwrap();
    let text = format!(
        r#"[campaign]
name = "map"
stage = "sim-xy"

[hardware]
kind = "sim"
optics = {{ width = 640, height = 640 }}

[hardware.sim]
model = "model.toml"
time_scale = {time_scale}
transport = "pty"
frame_time_s = 0.1
seed = 3

[map]
x_range_um = [{X0}, {x1}]
y_range_um = [{Y0}, {y1}]
step_um = [{STEP}, {STEP}]
m = 200
design = "stratified"
seed = 9
{extra}
[acquisition]
settle_s = 2.0
dwell_s = 0.5
approach_um = 50.0

[outputs]
dir = "{out}/{{name}}-{{id}}"
"#,
        x1 = X0 + STEP * (NX - 1) as f64,
        y1 = Y0 + STEP * (NY - 1) as f64,
        out = dir.display(),
    );
    let p = dir.join("map.toml");
    std::fs::write(&p, text).unwrap();
    p
}

/// Least-squares slope of v against p.
fn slope(p: &[f64], v: &[f64]) -> f64 {
    let n = p.len() as f64;
    let (mp, mv) = (p.iter().sum::<f64>() / n, v.iter().sum::<f64>() / n);
    let sxy: f64 = p.iter().zip(v).map(|(a, b)| (a - mp) * (b - mv)).sum();
    let sxx: f64 = p.iter().map(|a| (a - mp) * (a - mp)).sum();
    sxy / sxx
}

/// Reads `map_<dir>.csv` of a results folder: every grid point, x fastest, close to the truth.
fn check_map(out: &Path, dir: &str, yaw: bool) -> Vec<Vec<f64>> {
    let d = if dir == "forward" { 1.0 } else { -1.0 };
    let csv = std::fs::read_to_string(out.join(format!("map_{dir}.csv"))).unwrap();
    let mut lines = csv.lines();
    assert_eq!(lines.next(), Some("x_um,y_um,ex_um,ey_um,theta_urad"));
    let rows: Vec<Vec<f64>> = lines
        .map(|l| l.split(',').map(|v| v.parse().unwrap()).collect())
        .collect();
    assert_eq!(rows.len(), NX * NY);
    let (mut sum, mut max, mut n) = (0.0f64, 0.0f64, 0.0);
    for (k, r) in rows.iter().enumerate() {
        let (x, y) = (X0 + STEP * (k % NX) as f64, Y0 + STEP * (k / NX) as f64);
        assert_eq!((r[0], r[1]), (x, y), "row {k}: x fastest");
        let (tx, ty) = truth(x, y, d, yaw);
        for d in [r[2] - tx, r[3] - ty] {
            sum += d.abs();
            max = max.max(d.abs());
            n += 1.0;
        }
    }
    let mean = sum / n;
    // θ: the carriage's yaw as the camera sees it, µrad (the decoder's angle noise is ~1 µrad).
    let (mut t_sum, mut t_max) = (0.0f64, 0.0f64);
    for (k, r) in rows.iter().enumerate() {
        let want = if yaw {
            yaw_urad(X0 + STEP * (k % NX) as f64)
        } else {
            0.0
        };
        let d = (r[4] - want).abs();
        t_sum += d;
        t_max = t_max.max(d);
    }
    let t_mean = t_sum / rows.len() as f64;
    eprintln!(
        "map {dir} vs closed-form truth: mean {mean:.4} µm, max {max:.4} µm; θ mean {t_mean:.2} µrad, max {t_max:.2} µrad"
    );
    assert!(t_mean < 2.0 && t_max < 10.0, "θ mean {t_mean} max {t_max}");
    // A point approached from the wrong side in x would be 2 µm off (the backlash).
    assert!(mean < 0.05 && max < 0.3, "mean {mean} max {max}");
    rows
}

#[test]
fn a_map_campaign_runs_end_to_end_and_recovers_the_truth() {
    let dir = tempfile::tempdir().unwrap();
    let db = dir.path().join("c.db");
    let c = campaign(
        dir.path(),
        "directions = [\"forward\", \"backward\"]\n",
        10000.0,
        true,
    );
    let o = bin()
        .args(["run", "--json", "--quiet", "--db"])
        .arg(&db)
        .arg(&c)
        .output()
        .unwrap();
    let j = json_of(&o);
    assert_eq!(j["state"], "done", "{j}");

    // Every point stored, each with both axes on target.
    let samples = Store::open(&db).unwrap().samples(1).unwrap();
    assert_eq!(samples.len(), 400);
    assert!(samples.iter().all(|s| s.target.run.phase.as_str() == "map"));
    let m = &j["map"];
    assert_eq!(m["measurements"], 400);
    assert_eq!((m["nx"].as_u64(), m["ny"].as_u64()), (Some(40), Some(20)));
    // The campaign's time against the full 5 µm scan of the same rectangle (391 x 191 points).
    assert_eq!(m["full_scan_estimate"]["points"], 391 * 191);
    let saved = m["acquisition_saved_pct"].as_f64().unwrap();
    assert!(saved > 99.0 && saved < 100.0, "{saved}");

    // The map file: every grid point, x fastest, close to the truth.
    let out = dir.path().join("map-1");
    let rows = check_map(&out, "forward", true);
    // Backward: every point approached from +x and +y, the x backlash the other way.
    check_map(&out, "backward", true);

    // ISO 230-1: squareness from the reference lines' slopes, computed here from the truth.
    let xs: Vec<f64> = (0..NX).map(|i| X0 + STEP * i as f64).collect();
    let ys: Vec<f64> = (0..NY).map(|i| Y0 + STEP * i as f64).collect();
    // Each axis's profile is averaged over the other axis's positions (x's yaw makes e_x's
    // slope along y depend on x).
    let mean_over = |n: usize, f: &dyn Fn(usize) -> f64| (0..n).map(f).sum::<f64>() / n as f64;
    let ey_of_x: Vec<f64> = xs
        .iter()
        .map(|&x| mean_over(NY, &|j| truth(x, ys[j], 1.0, true).1))
        .collect();
    let ex_of_y: Vec<f64> = ys
        .iter()
        .map(|&y| mean_over(NX, &|i| truth(xs[i], y, 1.0, true).0))
        .collect();
    let (a_x, a_y) = (slope(&xs, &ey_of_x), slope(&ys, &ex_of_y));
    let want = -(a_x + a_y) * 1e6;
    let iso = &m["runs"][0]["iso230_1"];
    let got = iso["squareness_urad"].as_f64().unwrap();
    assert!((got - want).abs() < 5.0, "squareness {got} vs {want} µrad");
    assert!(iso["straightness_x_um"].as_f64().unwrap() >= 0.0);
    let text = std::fs::read_to_string(out.join("summary.txt")).unwrap();
    assert!(
        text.contains("ISO 230-1") && text.contains("squareness X to Y"),
        "{text}"
    );
    assert!(text.contains("full 5 µm grid scan"), "{text}");
    assert!(text.contains("map forward vs truth"), "{text}");

    for f in [
        "compensation_map_forward.csv",
        "samples.csv",
        "report.html",
        "plots/map_forward_ex.png",
        "plots/map_forward_ey.svg",
        "plots/map_forward_theta.png",
        "plots/map_forward_residual_ex.svg",
        "plots/map_forward_residual_ey.png",
        "plots/map_forward_residual_theta.png",
    ] {
        let p = out.join(f);
        assert!(p.is_file() && p.metadata().unwrap().len() > 100, "{f}");
    }
    // report.html: the heat maps embedded, the ISO 230-1 figures in its summary.
    let html = std::fs::read_to_string(out.join("report.html")).unwrap();
    assert!(html.contains("alt=\"plots/map_forward_ey.png\""));
    assert!(html.contains("squareness X to Y"));
    let comp = std::fs::read_to_string(out.join("compensation_map_forward.csv")).unwrap();
    let mut comp = comp.lines();
    assert_eq!(comp.next(), Some("x_um,y_um,corr_x_um,corr_y_um"));
    let first: Vec<f64> = comp
        .next()
        .unwrap()
        .split(',')
        .map(|v| v.parse().unwrap())
        .collect();
    assert!((first[2] + rows[0][2]).abs() < 1e-5 && (first[3] + rows[0][3]).abs() < 1e-5);
}

#[test]
fn bad_map_sections_name_the_line_and_the_key() {
    let dir = tempfile::tempdir().unwrap();
    let c = campaign(dir.path(), "", 10000.0, false);
    let text = std::fs::read_to_string(&c).unwrap();
    let line_of = |needle: &str| text.lines().position(|l| l.starts_with(needle)).unwrap() + 1;
    for (from, to, key) in [
        ("m = 200", "m = 801", "map.m"),
        ("m = 200", "m = 2", "map.m"),
        ("step_um = [50, 50]", "step_um = [50, 0]", "map.step_um"),
        ("design = \"stratified\"", "design = \"grid\"", "map.design"),
        (
            "x_range_um = [1000, 2950]",
            "x_range_um = [-480, 2950]",
            "map.x_range_um",
        ),
    ] {
        let bad = text.replace(from, to);
        assert_ne!(bad, text, "{from}");
        let e = Campaign::parse(&bad, "map.toml", dir.path()).unwrap_err();
        let msg = e.to_string();
        let want_line = line_of(from);
        assert!(msg.starts_with(&format!("map.toml:{want_line}")), "{msg}");
        if !key.ends_with("design") {
            assert!(msg.contains(key), "{msg}");
        }
    }
    // Lines and a map are separate campaigns.
    let bad = text.replace(
        "[acquisition]",
        "[axes.y]\nrange_um = [0.0, 500.0]\nstep_um = 5.0\nother_at_um = 100.0\nm = 20\n\n[acquisition]",
    );
    let e = Campaign::parse(&bad, "map.toml", dir.path()).unwrap_err();
    let msg = e.to_string();
    assert!(
        msg.starts_with(&format!("map.toml:{}: map", line_of("[map]"))) && msg.contains("[axes.*]"),
        "{msg}"
    );
    // A polygon too small for m points.
    let bad = text.replace(
        "seed = 9\n",
        "seed = 9\npolygon = [[1000, 1000], [1100, 1000], [1000, 1100]]\n",
    );
    let e = Campaign::parse(&bad, "map.toml", dir.path()).unwrap_err();
    assert!(e.to_string().contains("map.polygon"), "{e}");
}

#[test]
fn a_map_campaign_killed_mid_run_resumes_without_losing_or_repeating_a_point() {
    let dir = tempfile::tempdir().unwrap();
    let db = dir.path().join("c.db");
    let c = campaign(dir.path(), "", 1000.0, false);
    let mut child = bin()
        .args(["run", "--quiet", "--db"])
        .arg(&db)
        .arg(&c)
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let t0 = Instant::now();
    loop {
        assert!(child.try_wait().unwrap().is_none(), "ended before the kill");
        let n = Store::open(&db).ok().and_then(|s| s.sample_count(1).ok());
        if n.is_some_and(|n| n >= 60) {
            break;
        }
        assert!(t0.elapsed() < Duration::from_secs(120), "no progress");
        std::thread::sleep(Duration::from_millis(20));
    }
    child.kill().unwrap(); // SIGKILL
    child.wait().unwrap();
    let before = Store::open(&db).unwrap().samples(1).unwrap();
    assert!(before.len() >= 60 && before.len() < 200, "{}", before.len());
    let j = json_of(
        &bin()
            .args(["resume", "1", "--json", "--quiet", "--db"])
            .arg(&db)
            .output()
            .unwrap(),
    );
    assert_eq!(j["state"], "done", "{j}");
    let after = Store::open(&db).unwrap().samples(1).unwrap();
    let mut seqs: Vec<u64> = after.iter().map(|s| s.target.seq).collect();
    seqs.sort_unstable();
    seqs.dedup();
    assert_eq!((after.len(), seqs.len()), (200, 200), "every point once");
    for b in &before {
        let a = after.iter().find(|a| a.target.seq == b.target.seq).unwrap();
        assert_eq!((a.meas_x_um, a.unix_s), (b.meas_x_um, b.unix_s));
    }
    // The points measured after the resume were approached as the first ones were.
    check_map(&dir.path().join("map-1"), "forward", false);
}
