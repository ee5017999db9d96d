//! The gap diagnosis end to end through real campaigns: the simulated rig (GCS over pty, camera,
//! decoder) runs on a "real" stage model with effects the simulator's ideal model lacks;
//! `csmetro gap --data ID` finds them from the store, and the updated model shrinks the gap on a
//! fresh campaign (new noise, not used to fit) by the amount it reported.
use crate::common;

use std::path::{Path, PathBuf};

use common::{bin, json_of, repo};

fn config(name: &str) -> PathBuf {
    repo("config/sim").join(name)
}

/// Full-scan lines on both axes, six cycles each way (six runs to hold out: with three the held-out test has too little power to accept anything).
fn line_campaign(dir: &Path, seed: u64) -> PathBuf {
    let text = format!(
        r#"[campaign]
name = "lines{seed}"
[hardware]
kind = "sim"
optics = {{ width = 640, height = 640 }}
[hardware.sim]
model = "{model}"
time_scale = 1000
seed = {seed}
[axes.x]
range_um = [0.0, 9500.0]
step_um = 100.0
other_at_um = 2100.0
[axes.y]
range_um = [0.0, 4200.0]
step_um = 100.0
other_at_um = 4750.0
[sampling]
design = "full"
[acquisition]
cycles = 6
settle_s = 1.0
dwell_s = 0.2
[outputs]
dir = "{out}/{{name}}"
"#,
        model = config("real_stage.toml").display(),
        out = dir.display()
    );
    let p = dir.join(format!("lines{seed}.toml"));
    std::fs::write(&p, text).unwrap();
    p
}

fn gap(model: &Path, id: u32, db: &Path, out: &Path) -> serde_json::Value {
    json_of(
        &bin()
            .args(["gap", "--json", "--data", &id.to_string(), "--db"])
            .arg(db)
            .arg("--model")
            .arg(model)
            .arg("--out")
            .arg(out)
            .output()
            .unwrap(),
    )
}

#[test]
fn campaign_gap_finds_the_withheld_effects_and_the_shrink_holds_on_a_fresh_campaign() {
    let dir = tempfile::tempdir().unwrap();
    let db = dir.path().join("c.db");
    for seed in [1, 2] {
        let o = bin()
            .args(["run", "--quiet", "--json", "--db"])
            .arg(&db)
            .arg(line_campaign(dir.path(), seed))
            .output()
            .unwrap();
        let j = json_of(&o);
        assert_eq!(j["state"], "done");
        // Six approaches per target and direction: ISO 230-2 figures from the measurements.
        // Unidirectional repeatability R↑ = max 4 s↑ of the 0.05 µm sensor noise; reversal B
        // near the stage's 1.5 µm; bidirectional R = max(2s↑ + 2s↓ + |B_i|, ...) holds B.
        let m = &j["iso230"]["x"]["measured"];
        let r_up = m["r_up_um"]
            .as_f64()
            .unwrap_or_else(|| panic!("{:#}", j["iso230"]));
        assert!(r_up > 0.1 && r_up < 0.5, "R↑ {r_up} µm");
        let b = m["b_um"].as_f64().unwrap();
        assert!((b - 1.5).abs() < 0.3, "B {b} µm");
        let r = m["r_um"].as_f64().unwrap();
        assert!(r > b && r < b + 0.8, "R {r} µm");
    }
    let fit = dir.path().join("fit");
    let j = gap(&config("ideal.toml"), 1, &db, &fit);
    assert_eq!(j["n_runs"], 6);
    let mut added: Vec<(String, String)> = j["added"]
        .as_array()
        .unwrap()
        .iter()
        .map(|a| {
            (
                a["kind"].as_str().unwrap().to_string(),
                a["axis"].as_str().unwrap().to_string(),
            )
        })
        .collect();
    added.sort();
    // real_stage.toml has exactly these three effects more than ideal.toml.
    for want in [
        ("backlash", "y"),
        ("squareness", "y"),
        ("straightness", "x"),
    ] {
        assert!(
            added.contains(&(want.0.to_string(), want.1.to_string())),
            "{want:?} not found in {added:?}: {j:#}"
        );
    }
    let (before, after) = (
        j["heldout_rms_before_um"].as_f64().unwrap(),
        j["heldout_rms_after_um"].as_f64().unwrap(),
    );
    assert!(after < 0.5 * before, "{before} -> {after}");

    // Fresh campaign 2: the ideal model's gap and the updated model's gap, neither fitted on it.
    let fresh_before = gap(&config("ideal.toml"), 2, &db, &dir.path().join("b"))
        ["heldout_rms_before_um"]
        .as_f64()
        .unwrap();
    let fresh_after = gap(&fit.join("model.toml"), 2, &db, &dir.path().join("a"))
        ["heldout_rms_before_um"]
        .as_f64()
        .unwrap();
    let (reported, seen) = (1.0 - after / before, 1.0 - fresh_after / fresh_before);
    assert!(
        (reported - seen).abs() < 0.05,
        "shrink reported {reported:.3} ({before:.4} -> {after:.4} µm), seen on the fresh campaign {seen:.3} ({fresh_before:.4} -> {fresh_after:.4} µm)"
    );
}
