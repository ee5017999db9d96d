//! `csmetro reconstruct2d` on bad input: one line naming file and line, exit 2, nothing written.
use std::process::Command;

fn run(samples: &str, grid_x: &str, extra: &[&str]) -> (i32, String, bool) {
    run_xy(samples, grid_x, "0:5:20", extra)
}

/// `csmetro reconstruct2d` of `samples` (written to `s.csv`) on the grid `grid_x` × `grid_y`:
/// (exit code, stderr, whether the map file was written).
fn run_xy(samples: &str, grid_x: &str, grid_y: &str, extra: &[&str]) -> (i32, String, bool) {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("s.csv");
    std::fs::write(&path, samples).unwrap();
    let out = dir.path().join("map.csv");
    let o = Command::new(env!("CARGO_BIN_EXE_csmetro"))
        .args([
            "reconstruct2d",
            "--grid-x",
            grid_x,
            "--grid-y",
            grid_y,
            "--samples",
        ])
        .arg(&path)
        .arg("--out")
        .arg(&out)
        .args(extra)
        .output()
        .unwrap();
    let err = String::from_utf8(o.stderr).unwrap();
    (o.status.code().unwrap(), err, out.exists())
}

const GOOD: &str =
    "x_um,y_um,ex_um,ey_um\n0,0,0.1,0.2\n10,5,0.2,0.1\n20,20,0.3,0.0\n45,10,0.1,0.1\n";

#[test]
fn bad_rows_exit_2_naming_file_and_line() {
    for (row, want) in [
        ("12,0,0,0", "s.csv:6: x 12 µm is not on the grid"),
        ("10,25,0,0", "s.csv:6: y 25 µm is not on the grid"),
        (
            "15,0,NaN,0",
            "s.csv:6: ex_um is NaN (must be a finite number)",
        ),
        (
            "15,0,0,inf",
            "s.csv:6: ey_um is inf (must be a finite number)",
        ),
        ("15,0,0", "s.csv:6: expected 4 fields, found 3"),
        (
            "10,5,1,1",
            "s.csv:6: duplicate point (10, 5) µm (first at line 3)",
        ),
    ] {
        let (code, err, wrote) = run(&format!("{GOOD}{row}\n"), "0:5:50", &[]);
        assert_eq!(code, 2, "{row}: {err}");
        assert!(err.contains(want), "{row}: {err}");
        assert_eq!(err.trim().lines().count(), 1, "{err}");
        assert!(!wrote);
    }
}

#[test]
fn bad_header_grid_and_method_exit_2() {
    let (code, err, _) = run("position_um,error_um\n0,0\n", "0:5:50", &[]);
    assert_eq!(code, 2);
    assert!(
        err.contains("s.csv:1: missing header `x_um,y_um,ex_um,ey_um"),
        "{err}"
    );
    // 900 001 x 5 points: over the 4 M bound, refused before the samples are read.
    let (code, err, _) = run(GOOD, "0:1:900000", &[]);
    assert_eq!(code, 2);
    assert!(err.contains("more than 4000000"), "{err}");
    let (code, err, _) = run(GOOD, "0:3:50", &[]);
    assert_eq!(code, 2);
    assert!(err.contains("--grid-x"), "{err}");
    // (`bp` was the unknown method here until issue 39's basis pursuit made it a method.)
    let (code, err, _) = run(GOOD, "0:5:50", &["--method", "spline"]);
    assert_eq!(code, 2);
    assert!(err.contains("--method"), "{err}");
    let (code, err, _) = run("x_um,y_um,ex_um,ey_um\n0,0,0,0\n5,5,0,0\n", "0:5:50", &[]);
    assert_eq!(code, 2);
    assert!(err.contains("need at least 3 samples"), "{err}");
}

#[test]
fn a_few_samples_still_give_a_linear_map() {
    // Too few samples for the physics model: auto falls back to linear, physics says why.
    let (code, err, wrote) = run(GOOD, "0:5:50", &["--method", "linear"]);
    assert_eq!(code, 0, "{err}");
    assert!(wrote);
    let (code, err, _) = run(GOOD, "0:5:50", &["--method", "physics"]);
    assert_eq!(code, 2);
    assert!(err.contains("the physics model needs at least"), "{err}");
    let (code, err, _) = run(GOOD, "0:5:50", &["--method", "auto"]);
    assert_eq!(code, 0, "{err}");
}

/// Samples at (x, y) on a grid 0:50:2000 in both directions, with errors of a plausible
/// stage (a cyclic error along x, a bow along y, squareness).
fn samples_at(points: &[(f64, f64)]) -> String {
    let mut t = String::from("x_um,y_um,ex_um,ey_um\n");
    for &(x, y) in points {
        let ex = 0.3 * (x / 400.0 * std::f64::consts::TAU).sin() + 1e-4 * y;
        let ey = 2e-7 * (y - 1000.0) * (y - 1000.0) - 5e-5 * x;
        t.push_str(&format!("{x},{y},{ex:.5},{ey:.5}\n"));
    }
    t
}

#[test]
fn samples_that_do_not_span_the_plane_are_refused() {
    // Every sample on the diagonal x = y: any map fits them, and the cross-validation on the
    // same line reported a tiny error for a made-up map (exit 0 before).
    let diag: Vec<(f64, f64)> = (0..41)
        .map(|k| (50.0 * k as f64, 50.0 * k as f64))
        .collect();
    for method in ["auto", "physics", "linear"] {
        let (code, err, wrote) = run_xy(
            &samples_at(&diag),
            "0:50:2000",
            "0:50:2000",
            &["--method", method],
        );
        assert_eq!(code, 2, "{method}: {err}");
        assert!(
            err.contains("s.csv: all 41 samples lie on one line, from (0, 0) to (2000, 2000) µm"),
            "{method}: {err}"
        );
        assert!(
            err.contains("measure points spread over the plane"),
            "{err}"
        );
        assert_eq!(err.trim().lines().count(), 1, "{err}");
        assert!(!wrote, "{method}: nothing written");
    }
    // A band along the bottom edge, 100 µm of 2000: the rest would be extrapolated.
    let band: Vec<(f64, f64)> = (0..41)
        .flat_map(|i| [0.0, 50.0, 100.0].map(|y| (50.0 * i as f64, y)))
        .collect();
    let (code, err, wrote) = run_xy(&samples_at(&band), "0:50:2000", "0:50:2000", &["--json"]);
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("the samples cover 5.0 % of the grid"), "{err}");
    assert!(!wrote);
    // The same number of points spread over the plane is a map.
    let spread: Vec<(f64, f64)> = (0..123)
        .map(|k| {
            let i = k % 41;
            (50.0 * i as f64, 50.0 * ((k / 41 * 13 + i * 7) % 41) as f64)
        })
        .collect();
    let (code, err, wrote) = run_xy(&samples_at(&spread), "0:50:2000", "0:50:2000", &["--json"]);
    assert_eq!(code, 0, "{err}");
    assert!(wrote);
}
