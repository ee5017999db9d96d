//! `csmetro reconstruct2d` on bad input: one line naming file and line, exit 2, nothing written.
use std::process::Command;

fn run(samples: &str, grid_x: &str, extra: &[&str]) -> (i32, String, bool) {
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
            "0:5:20",
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
