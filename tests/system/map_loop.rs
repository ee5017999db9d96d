//! The loop closed on an XY map (issue 50 item 3): a small `[map]` campaign on the simulated demo
//! stage (a defect-free 3 x 1.5 mm sub-region, 350 points of a 25 µm grid), then `csmetro
//! verify` of the map at never-visited XY points, then compensated two-axis moves from the map
//! (a results directory and a `compensation_map_forward.csv`), landing within the
//! verification's expected residual where plain moves show the stage's error; a map fed a point
//! outside its span and a malformed map file are refused, nothing moves.
use crate::common;

use std::path::{Path, PathBuf};

use common::{bin, json_of, repo};
use rand::{Rng, SeedableRng};
use serde_json::Value;

const STAGE: &str = "map-loop-sim";
const X: (f64, f64) = (5000.0, 8000.0);
const Y: (f64, f64) = (2200.0, 3700.0);

fn campaign(dir: &Path) -> PathBuf {
    let text = format!(
        r#"[campaign]
name = "maploop"
stage = "{STAGE}"

[hardware]
kind = "sim"
optics = {{ width = 640, height = 640 }}

[hardware.sim]
model = "{model}"
time_scale = 10000
transport = "pty"
frame_time_s = 0.1
seed = 2026

[map]
x_range_um = [{x0}, {x1}]
y_range_um = [{y0}, {y1}]
step_um = [25.0, 25.0]
m = 350
design = "stratified"
seed = 2026
directions = ["forward"]
method = "auto"

[acquisition]
settle_s = 2.0
dwell_s = 0.5
approach_um = 50.0

[outputs]
dir = "{out}/{{name}}-{{id}}"
"#,
        model = repo("config/sim").join("demo_xy.toml").display(),
        x0 = X.0,
        x1 = X.1,
        y0 = Y.0,
        y1 = Y.1,
        out = dir.display(),
    );
    let p = dir.join("map.toml");
    std::fs::write(&p, text).unwrap();
    p
}

fn mv(db: &Path, args: &[String]) -> std::process::Output {
    bin()
        .args(["move", "--stage", STAGE, "--json", "--db"])
        .arg(db)
        .args(args)
        .output()
        .unwrap()
}

#[test]
fn a_map_compensates_two_axis_moves_and_its_verification_passes() {
    let dir = tempfile::tempdir().unwrap();
    let db = dir.path().join("c.db");
    let camp = campaign(dir.path());
    let o = bin()
        .args(["run", "--quiet", "--json", "--db"])
        .arg(&db)
        .arg(&camp)
        .output()
        .unwrap();
    assert_eq!(json_of(&o)["state"], "done");
    let results = dir.path().join("maploop-1");

    // The verification: never-visited points, before and after, both axes.
    let o = bin()
        .args(["verify", "1", "--json", "--quiet", "--cycles", "2", "--db"])
        .arg(&db)
        .output()
        .unwrap();
    let v: Value = serde_json::from_slice(&o.stdout).unwrap_or_default();
    eprintln!("{}", serde_json::to_string_pretty(&v).unwrap());
    assert_eq!(o.status.code(), Some(0), "{v}");
    assert_eq!(
        (v["kind"].as_str(), v["passed"].as_bool()),
        (Some("map"), Some(true))
    );
    let mut expected = [0.0f64; 2];
    for (i, a) in v["axes"].as_array().unwrap().iter().enumerate() {
        let (b, f) = (
            a["mean_abs_before_um"].as_f64().unwrap(),
            a["mean_abs_after_um"].as_f64().unwrap(),
        );
        assert!(f <= b / 10.0, "{a}");
        assert!(a["max_abs_after_um"].as_f64().unwrap() <= a["expected_um"].as_f64().unwrap());
        expected[i] = a["expected_um"].as_f64().unwrap();
    }
    // Points between grid lines, inside the map.
    for p in v["points_um"].as_array().unwrap() {
        let (x, y) = (p[0].as_f64().unwrap(), p[1].as_f64().unwrap());
        assert!(X.0 < x && x < X.1 && Y.0 < y && y < Y.1, "{p}");
        for q in [x - X.0, y - Y.0] {
            let off = q.rem_euclid(25.0);
            assert!((4.9..=20.1).contains(&off), "{p} on a grid line");
        }
    }
    assert!(v["iso230_1_before"]["squareness_urad"].is_number());
    assert!(v["iso230_1_after"]["squareness_urad"].is_number());
    for f in [
        "verify/verify.json",
        "verify/summary.txt",
        "verify/samples.csv",
        "verify/verify_x.svg",
        "verify/verify_y.png",
    ] {
        assert!(results.join(f).is_file(), "{f}");
    }
    // The chart: before/after per point and the pass line.
    let svg = std::fs::read_to_string(results.join("verify/verify_x.svg")).unwrap();
    assert!(
        svg.contains("pass line") && svg.contains("after, forward"),
        "{svg:.300}"
    );

    // Random compensated moves (results directory, then the table file on every other one).
    let table = results.join("compensation_map_forward.csv");
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(50);
    let n = 10;
    let (mut before, mut after) = ([0.0f64; 2], [0.0f64; 2]);
    for k in 0..n {
        let x = X.0 + 100.0 + (X.1 - X.0 - 200.0) * rng.random::<f64>();
        let y = Y.0 + 100.0 + (Y.1 - Y.0 - 200.0) * rng.random::<f64>();
        let to = |extra: [&str; 2]| -> Vec<String> {
            let mut a: Vec<String> = ["--x-um", &format!("{x:.3}"), "--y-um", &format!("{y:.3}")]
                .into_iter()
                .map(String::from)
                .collect();
            a.push("--measure".into());
            a.extend(extra.map(String::from));
            a
        };
        let source = if k % 2 == 0 { &results } else { &table };
        let plain = json_of(&mv(&db, &to(["--campaign", camp.to_str().unwrap()])));
        let comp = json_of(&mv(&db, &to(["--compensation", source.to_str().unwrap()])));
        for (i, (axis, want)) in [("x", x), ("y", y)].into_iter().enumerate() {
            let key = format!("measured_{axis}_um");
            let e0 = plain[&key].as_f64().unwrap() - want;
            let e1 = comp[&key].as_f64().unwrap() - want;
            before[i] += e0.abs() / n as f64;
            after[i] += e1.abs() / n as f64;
            assert!(
                e1.abs() <= expected[i],
                "move {k} to ({x:.1}, {y:.1}): {axis} lands {e1:.3} µm off, expected ≤ {:.3} ({comp})",
                expected[i]
            );
            assert_eq!(comp["axes"][i]["approach"], "forward");
        }
    }
    eprintln!("moves: mean |error| without {before:?}, with {after:?} µm");
    for i in 0..2 {
        assert!(
            before[i] > 0.3 && after[i] < before[i] / 5.0,
            "axis {i}: {} → {} µm",
            before[i],
            after[i]
        );
    }

    // Outside the map: refused (exit 2), not clipped.
    let o = mv(
        &db,
        &["--x-um", "8200", "--y-um", "3000", "--compensation"]
            .map(String::from)
            .into_iter()
            .chain([results.display().to_string()])
            .collect::<Vec<_>>(),
    );
    assert_eq!(o.status.code(), Some(2));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("outside the compensated range"), "{err}");

    // A malformed map file: exit 2 naming file:line, nothing moves.
    let text = std::fs::read_to_string(&table).unwrap();
    let mut lines: Vec<String> = text.lines().map(String::from).collect();
    lines[4] = "5075,2200,abc,0.1".into();
    let bad = dir.path().join("compensation_map_forward.csv");
    std::fs::write(&bad, lines.join("\n")).unwrap();
    let o = mv(
        &db,
        &["--x-um", "6000", "--y-um", "3000", "--compensation"]
            .map(String::from)
            .into_iter()
            .chain([bad.display().to_string()])
            .collect::<Vec<_>>(),
    );
    assert_eq!(o.status.code(), Some(2));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains(&format!("{}:5:", bad.display())), "{err}");
}
