//! `csmetro generate` → `csmetro reconstruct` through the binary: outputs, JSON, and bad input.
use std::path::{Path, PathBuf};
use std::process::Command;

fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_csmetro"))
}

fn read_curve(path: &Path) -> Vec<(f64, f64)> {
    read_curve_u(path).0
}

/// (position, error) rows and, when the file has the column, each row's u_um.
fn read_curve_u(path: &Path) -> (Vec<(f64, f64)>, Option<Vec<f64>>) {
    let text = std::fs::read_to_string(path).unwrap();
    let mut lines = text.lines();
    let header = lines.next().unwrap();
    assert!(
        header == "position_um,error_um" || header == "position_um,error_um,u_um",
        "{header}"
    );
    let with_u = header.ends_with(",u_um");
    let mut rows = Vec::new();
    let mut u = Vec::new();
    for l in lines {
        let f: Vec<f64> = l.split(',').map(|v| v.parse().unwrap()).collect();
        assert_eq!(f.len(), if with_u { 3 } else { 2 }, "{l}");
        rows.push((f[0], f[1]));
        if with_u {
            u.push(f[2]);
        }
    }
    (rows, with_u.then_some(u))
}

fn generate(dir: &Path, m: usize) -> (PathBuf, PathBuf) {
    let full = dir.join("full.csv");
    let samples = dir.join("samples.csv");
    let st = bin()
        .args([
            "generate",
            "--seed",
            "3",
            "--m",
            &m.to_string(),
            "--out-full",
        ])
        .arg(&full)
        .arg("--out-samples")
        .arg(&samples)
        .status()
        .unwrap();
    assert!(st.success());
    (full, samples)
}

#[test]
fn round_trip_every_method_writes_the_whole_grid_and_beats_a_lookup_table() {
    let dir = tempfile::tempdir().unwrap();
    let (full, samples) = generate(dir.path(), 300);
    let truth = read_curve(&full);
    assert_eq!(truth.len(), 1901);
    assert_eq!(read_curve(&samples).len(), 300);
    let mut mae = std::collections::HashMap::new();
    for method in ["auto", "bp", "pchip", "linear"] {
        let out = dir.path().join(format!("{method}.csv"));
        let o = bin()
            .args([
                "reconstruct",
                "--grid",
                "0:5:9500",
                "--method",
                method,
                "--json",
                "--samples",
            ])
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
        for key in [
            "method",
            "solver",
            "n",
            "m",
            "solve_ms",
            "iterations",
            "objective",
            "cv_error_um",
        ] {
            assert!(j.get(key).is_some(), "{method}: JSON lacks `{key}`: {j}");
        }
        assert_eq!(j["n"], 1901);
        assert_eq!(j["m"], 300);
        if method == "bp" {
            assert_eq!(j["status"], "optimal");
            assert!(j["objective"].as_f64().unwrap() > 0.0);
            // Optimal means certified: primal and dual objectives agree.
            assert!(j["relative_gap"].as_f64().unwrap() < 1e-9, "{j}");
        }
        if method == "auto" {
            assert!(j["cv_error_um"].as_f64().unwrap() > 0.0);
        }
        let (g, u) = read_curve_u(&out);
        assert_eq!(g.len(), 1901);
        // The pointwise u (k = 1) for every method (bp asked directly: from its own folds), and
        // its ±2u band holds this test's truth at most grid points.
        let u = u.unwrap_or_else(|| panic!("{method}: no u_um column"));
        assert!(u.iter().all(|v| v.is_finite() && *v > 0.0), "{method}");
        let inside = g
            .iter()
            .zip(&truth)
            .zip(&u)
            .filter(|((a, b), u)| (a.1 - b.1).abs() <= 2.0 * **u)
            .count() as f64
            / 1901.0;
        eprintln!("{method}: band coverage {inside:.3}");
        assert!(
            (0.85..=1.0).contains(&inside),
            "{method}: band coverage {inside}"
        );
        let e = g
            .iter()
            .zip(&truth)
            .map(|(a, b)| (a.1 - b.1).abs())
            .sum::<f64>()
            / 1901.0;
        mae.insert(method, e);
    }
    assert!(mae["auto"] < mae["pchip"], "{mae:?}");
    assert!(mae["auto"] < mae["bp"], "{mae:?}");
    assert!(
        mae["auto"] < 0.198,
        "auto must beat the paper's Table II at m = 300: {mae:?}"
    );
}

fn expect_input_error(dir: &Path, content: Option<&str>, extra: &[&str], needle: &str) {
    let path = dir.join("bad.csv");
    if let Some(c) = content {
        std::fs::write(&path, c).unwrap();
    } else {
        let _ = std::fs::remove_file(&path);
    }
    let o = bin()
        .args(["reconstruct", "--grid", "0:5:100", "--samples"])
        .arg(&path)
        .args(extra)
        .output()
        .unwrap();
    assert_eq!(
        o.status.code(),
        Some(2),
        "content {content:?}: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    let err = String::from_utf8(o.stderr).unwrap();
    assert_eq!(err.trim().lines().count(), 1, "one-line error: {err}");
    if !extra.iter().any(|a| a.starts_with("--method")) {
        assert!(err.contains("bad.csv"), "names the file: {err}");
    }
    assert!(err.contains(needle), "expected {needle:?} in {err}");
    assert!(!err.contains("panicked"));
}

#[test]
fn bad_input_gives_one_line_exit_2() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    expect_input_error(d, None, &[], "cannot read");
    expect_input_error(d, Some("0,1\n5,2\n"), &[], "header");
    expect_input_error(d, Some("position_um,error_um\n0,1\n5,NaN\n"), &[], ":3:");
    expect_input_error(
        d,
        Some("position_um,error_um\n0,1\n5,2\n5,3\n"),
        &[],
        "duplicate",
    );
    expect_input_error(
        d,
        Some("position_um,error_um\n0,1\n7,2\n"),
        &[],
        "not on the grid",
    );
    expect_input_error(d, Some("position_um,error_um\n0,1\n"), &[], "at least 2");
    let many: String = std::iter::once("position_um,error_um\n".to_string())
        .chain((0..=21).map(|i| format!("{},{}\n", i * 5, i)))
        .collect();
    expect_input_error(d, Some(&many), &[], "not on the grid");
    expect_input_error(
        d,
        Some("position_um,error_um\n0,1\n5,2\n"),
        &["--method", "magic"],
        "unknown method",
    );
    expect_input_error(
        d,
        Some("position_um,error_um\n0,1\n5,2\n"),
        &["--method", "bp", "--gap-tol", "0"],
        "--gap-tol",
    );
}

#[test]
fn reconstruct_with_clarabel_matches_fast_solver() {
    let dir = tempfile::tempdir().unwrap();
    let full = dir.path().join("full.csv");
    let samples = dir.path().join("s.csv");
    assert!(bin()
        .args(["generate", "--grid", "0:50:9500", "--m", "50", "--out-full"])
        .arg(&full)
        .arg("--out-samples")
        .arg(&samples)
        .status()
        .unwrap()
        .success());
    let mut curves = Vec::new();
    for solver in ["fast", "clarabel"] {
        let out = dir.path().join(format!("{solver}.csv"));
        let o = bin()
            .args([
                "reconstruct",
                "--grid",
                "0:50:9500",
                "--method",
                "bp",
                "--solver",
                solver,
                "--json",
                "--samples",
            ])
            .arg(&samples)
            .arg("--out")
            .arg(&out)
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        curves.push(read_curve(&out));
    }
    let d = curves[0]
        .iter()
        .zip(&curves[1])
        .map(|(a, b)| (a.1 - b.1).abs())
        .fold(0.0, f64::max);
    assert!(d < 1e-6, "max difference {d} µm");
}

/// `bench families` refuses an unknown family or an m the 1,901-point grid cannot hold with one
/// line and exit 2, before any reconstruction runs.
#[test]
fn bench_families_bad_arguments_give_one_line_exit_2() {
    for (args, needle) in [
        (
            &["--families", "single,bogus"][..],
            "unknown family \"bogus\"",
        ),
        (&["--m", "100,5000"][..], "--m"),
        (&["--seeds", "0"][..], "--seeds"),
    ] {
        let o = bin()
            .args(["bench", "families"])
            .args(args)
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{args:?}: {err}");
        assert_eq!(err.trim().lines().count(), 1, "{args:?}: {err}");
        assert!(err.contains(needle), "{args:?}: {err}");
        assert!(o.stdout.is_empty(), "{args:?}");
    }
}

#[test]
fn a_reader_that_closes_the_pipe_early_ends_the_output_not_in_a_panic() {
    use std::process::Stdio;
    let dir = tempfile::tempdir().unwrap();
    let (_, samples) = generate(dir.path(), 100);
    // `csmetro reconstruct ... | head -c 0`: the curve goes to stdout, whose reader is gone
    // before the first line is written.
    let mut child = bin()
        .args(["reconstruct", "--grid", "0:5:9500", "--samples"])
        .arg(&samples)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    drop(child.stdout.take());
    let o = child.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!err.contains("panicked"), "{err}");
    assert!(o.status.success(), "{:?}: {err}", o.status);
}

/// Three cycles of each position, each reading with its own noise (σ = 0.02 µm), told a tenth
/// of it: the repeats' scatter is the samples' σ, and the band at the samples rests on it.
#[test]
fn repeated_cycles_measure_the_noise_and_raise_a_sigma_told_too_low() {
    let dir = tempfile::tempdir().unwrap();
    // The test's own curve, and noise from the tests' generator (SplitMix64, Box–Muller), written
    // apart from csmetro's.
    let mut rng = crate::gapgen::Rng::new(45);
    let truth = |x: f64| {
        (2.0 * std::f64::consts::PI * x / 400.0).sin()
            + 0.2 * (2.0 * std::f64::consts::PI * x / 85.0).cos()
    };
    let n = 801; // 0:5:4000
    let mut picked = vec![false; n];
    let mut idx = Vec::new();
    while idx.len() < 150 {
        let i = rng.pick(n);
        if !picked[i] {
            picked[i] = true;
            idx.push(i);
        }
    }
    let mut text = csmetro::samples::layout_header();
    for cycle in 0..3 {
        for &i in &idx {
            let p = 5.0 * i as f64;
            let e = truth(p) + 0.02 * rng.normal();
            text.push_str(&format!(
                "0,cs,x,forward,{cycle},{p},0,{},0,0,{p},0,1,1,0,,{},{p},{p},{e},,\n",
                p + e,
                2 * cycle
            ));
        }
    }
    let samples = dir.path().join("cycles.csv");
    std::fs::write(&samples, text).unwrap();
    let run = |told: &str, out: &Path| {
        let o = bin()
            .args([
                "reconstruct",
                "--grid",
                "0:5:4000",
                "--json",
                "--noise-um",
                told,
            ])
            .arg("--samples")
            .arg(&samples)
            .arg("--out")
            .arg(out)
            .output()
            .unwrap();
        let j = crate::common::json_of(&o);
        (j, String::from_utf8_lossy(&o.stderr).into_owned())
    };
    let low = dir.path().join("low.csv");
    let (j, err) = run("0.002", &low);
    // A sample averages 3 readings: 0.02 / √3 = 0.0115 µm, on 150 × 2 degrees of freedom.
    let rep = j["repeat_noise_um"].as_f64().unwrap();
    assert!((0.0095..0.0140).contains(&rep), "{j}");
    assert_eq!(j["repeat_noise_dof"], 300, "{j}");
    assert_eq!(j["noise_told_um"], 0.002, "{j}");
    assert_eq!(j["noise_um"], rep, "{j}");
    assert!(err.contains("warning") && err.contains("repeat"), "{err}");
    // The band at the samples covers their truth as a band should.
    let (rows, u) = read_curve_u(&low);
    let u = u.unwrap();
    let inside = idx
        .iter()
        .filter(|&&i| (rows[i].1 - truth(rows[i].0)).abs() <= 2.0 * u[i])
        .count();
    assert!(inside as f64 / idx.len() as f64 >= 0.85, "{inside} of 150");
    // A σ told a little above the repeats' is kept: they may not hold every source of noise.
    let (j, err) = run("0.012", &dir.path().join("near.csv"));
    assert_eq!(j["noise_um"], 0.012, "{j}");
    assert!(!err.contains("warning"), "{err}");
    // Four times theirs is more than the held-out residuals allow: the curve takes their level.
    let (j, err) = run("0.05", &dir.path().join("high.csv"));
    let used = j["noise_um"].as_f64().unwrap();
    assert!((0.009..0.016).contains(&used), "{j}");
    assert!(err.contains("held-out residuals"), "{err}");
}
