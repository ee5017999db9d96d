//! The loop closed on both axes of the simulated demo stage: characterise x and y (each line
//! with the other axis standing still), verify, then compensated two-axis moves to random XY
//! points. The simulator keeps both axes' errors at every position (one planar truth), so a
//! move's landing carries the x error, y's straightness on x, y's own error and x's
//! straightness on y: the compensation must take out all four.
use crate::common;

use std::path::PathBuf;
use std::sync::OnceLock;

use common::{bin, SimFile};
use rand::{Rng, SeedableRng};
use serde_json::Value;

const STAGE: &str = "comp-xy-sim";

/// The README demo's characterisation (x over [0, 9500] µm at y = 2100, y over [0, 4200] µm
/// at x = 4750, 5 µm grids, 300 and 150 random targets per direction, the demo's seeds),
/// without its full scan.
fn characterised() -> &'static (PathBuf, PathBuf, PathBuf) {
    static ONCE: OnceLock<(PathBuf, PathBuf, PathBuf)> = OnceLock::new();
    ONCE.get_or_init(|| {
        let dir = tempfile::tempdir().unwrap().keep();
        let outputs = format!("{}/{{name}}-{{id}}", dir.display());
        let camp = SimFile {
            name: "xy",
            stage: STAGE,
            model: "demo_xy.toml",
            campaign: "",
            sim: "seed = 2026",
            rest: "[axes.x]\nrange_um = [0.0, 9500.0]\nstep_um = 5.0\nother_at_um = 2100.0\nm = 300\n\n\
                   [axes.y]\nrange_um = [0.0, 4200.0]\nstep_um = 5.0\nother_at_um = 4750.0\nm = 150\n\n\
                   [sampling]\ndesign = \"random\"\nseed = 2026\n\n\
                   [acquisition]\ndirections = [\"forward\", \"backward\"]\ncycles = 1\nsettle_s = 2.0\n\
                   dwell_s = 0.5\napproach_um = 50.0\n\n[reconstruction]\nmethod = \"auto\"\nnoise_um = 0.01",
            outputs,
            tail: "",
        }
        .write(&dir.join("xy.toml"));
        let db = dir.join("csmetro.db");
        let o = bin()
            .args(["run", "--quiet", "--db"])
            .arg(&db)
            .arg(&camp)
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        (db, dir.join("xy-1"), camp)
    })
}

fn mv(args: &[String]) -> Value {
    let (db, _, _) = characterised();
    let o = bin()
        .args(["move", "--stage", STAGE, "--json", "--measure", "--db"])
        .arg(db)
        .args(args)
        .output()
        .unwrap();
    assert!(
        o.status.success(),
        "{args:?}: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    common::json_of(&o)
}

#[test]
fn compensated_two_axis_moves_land_within_the_verified_residual_on_both_axes() {
    let (db, results, camp) = characterised();
    // The verification first: both axes, E reduced ≥ 10×, every target within its expected.
    let o = bin()
        .args(["verify", "1", "--json", "--quiet", "--cycles", "2", "--db"])
        .arg(db)
        .output()
        .unwrap();
    let v = common::json_of(&o);
    assert_eq!(v["passed"], true, "{v}");
    // Each landing is held to what the verification holds each target to: 3 u (the table's
    // uncertainty there, which `move` reports) + the axis's unidirectional repeatability.
    let mut repeat = [0.0f64; 2];
    for (i, a) in v["axes"].as_array().unwrap().iter().enumerate() {
        assert!(a["e_reduction"].as_f64().unwrap() >= 10.0, "{a}");
        assert_eq!(a["expected_from"], "band", "{a}");
        repeat[i] = a["repeatability_um"].as_f64().unwrap();
    }
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(2026);
    let (mut before, mut after) = ([0.0f64; 2], [0.0f64; 2]);
    let n = 20;
    for k in 0..n {
        let x = 9500.0 * rng.random::<f64>();
        let y = 4200.0 * rng.random::<f64>();
        let dir = if k % 2 == 0 { "forward" } else { "backward" };
        let to = |extra: [&str; 2]| {
            let mut a: Vec<String> = ["--x-um", &format!("{x:.3}"), "--y-um", &format!("{y:.3}")]
                .into_iter()
                .map(String::from)
                .collect();
            a.extend(["--direction", dir].map(String::from));
            a.extend(extra.map(String::from));
            a
        };
        let plain = mv(&to(["--campaign", camp.to_str().unwrap()]));
        let comp = mv(&to(["--compensation", results.to_str().unwrap()]));
        for (i, (axis, want)) in [("x", x), ("y", y)].into_iter().enumerate() {
            let key = format!("measured_{axis}_um");
            let u = comp["axes"][i]["u_um"].as_f64().unwrap();
            let expected = [3.0 * u + repeat[i]; 2];
            let e0 = plain[&key].as_f64().unwrap() - want;
            let e1 = comp[&key].as_f64().unwrap() - want;
            before[i] += e0.abs() / n as f64;
            after[i] += e1.abs() / n as f64;
            assert!(
                e1.abs() <= expected[i],
                "move {k} to ({x:.1}, {y:.1}) {dir}: {axis} lands {e1:.3} µm off, expected ≤ {:.3} µm ({comp})",
                expected[i]
            );
        }
        // Both axes moved, and each took the other's error on it into account.
        let axes = comp["axes"].as_array().unwrap();
        assert!(axes.iter().all(|a| a["cross_um"].is_number()), "{comp}");
    }
    // The stage's error shows without the compensation (both axes), and is taken out with it.
    for i in 0..2 {
        assert!(
            before[i] > 0.5 && after[i] < before[i] / 5.0,
            "axis {i}: mean |error| {:.3} µm without, {:.3} µm with",
            before[i],
            after[i]
        );
    }
}
