//! The adaptive mode end to end on simulated hardware: each sweep measures its design in batches
//! and stops at the first batch boundary where its error estimate meets the target; the stored
//! summary says how many targets that saved, and the curve it delivers honours the target
//! against the simulator's truth.
use crate::common;

use std::path::Path;

use common::{bin, json_of, repo};
use csmetro::campaign::engine::CV_PLAUSIBLE;
use csmetro::store::Store;

const BUDGET: u64 = 160;
const BATCH: u64 = 40;

/// X from 1000 to 3000 µm (401 points): a budget of 160 targets per direction in batches of
/// 40, with the full scan that the saving is judged by.
fn campaign(dir: &Path, goal_um: f64) -> std::path::PathBuf {
    let text = format!(
        r#"[campaign]
name = "adaptive"
stage = "sim-xy"

[hardware]
kind = "sim"
optics = {{ width = 640, height = 640 }}

[hardware.sim]
model = "{model}"
time_scale = 1000
transport = "pty"
frame_time_s = 0.1
seed = 7

[axes.x]
range_um = [1000.0, 3000.0]
step_um = 5.0
other_at_um = 2100.0
m = {BUDGET}

[sampling]
design = "random"
seed = 3
full_scan = true
target_error_um = {goal_um}
batch = {BATCH}

[acquisition]
directions = ["forward", "backward"]
settle_s = 2.0
dwell_s = 0.5

[reconstruction]
method = "auto"
noise_um = 0.01

[outputs]
dir = "{out}/{{name}}-{{id}}"
"#,
        model = repo("config/sim/demo_xy.toml").display(),
        out = dir.display(),
    );
    let p = dir.join(format!("adaptive-{goal_um}.toml"));
    std::fs::write(&p, text).unwrap();
    p
}

#[test]
fn an_adaptive_sweep_stops_at_the_first_batch_whose_estimate_meets_the_target() {
    let dir = tempfile::tempdir().unwrap();
    let goal = 0.1;
    let db = dir.path().join("a.db");
    let o = bin()
        .args(["run", "--json", "--quiet", "--db"])
        .arg(&db)
        .arg(campaign(dir.path(), goal))
        .output()
        .unwrap();
    let j = json_of(&o);
    assert_eq!(j["state"], "done", "{j}");
    let x = &j["axes"][0];
    let cs = &x["phases"]["cs"];
    let measured = cs["measurements"].as_u64().unwrap();
    let saved = cs["saved_by_adaptive"].as_u64().unwrap();
    // Every planned target of both sweeps was measured or saved, and some were saved.
    assert_eq!(measured + saved, 2 * BUDGET, "{cs}");
    assert!(saved >= BATCH, "nothing saved: {cs}");
    assert_eq!(cs["failed_points"], 0, "{cs}");

    // The decisions as stored: each one follows the rule, and a sweep ends at its first stop.
    let events = Store::open(&db).unwrap().events_after(1, 0).unwrap();
    let mut total = 0;
    let mut pooled_curves = Vec::new();
    let mut ms = std::collections::HashMap::new();
    for run in ["cs-x-forward-0", "cs-x-backward-0"] {
        let decisions: Vec<&serde_json::Value> = events
            .iter()
            .filter(|e| e.kind == "adaptive" && e.data["run"] == run)
            .map(|e| &e.data)
            .collect();
        assert!(!decisions.is_empty(), "{run}: no decision");
        for (k, d) in decisions.iter().enumerate() {
            assert_eq!(d["batch"].as_u64(), Some(k as u64), "{d}");
            assert_eq!(d["m"].as_u64(), Some((k as u64 + 1) * BATCH), "{d}");
            let est = d["error_estimate_um"].as_f64().unwrap();
            let scatter = d["scatter_um"].as_f64().unwrap();
            let cv = d["cv_error_um"].as_f64().unwrap();
            assert!(est > 0.0 && scatter >= 0.0 && cv > 0.0, "{d}");
            // A pooled curve's cross-validated error is taken as it is.
            let plausible = if d["pooled_m"].as_u64() > Some(0) {
                1.0
            } else {
                CV_PLAUSIBLE
            };
            let meets = (est + scatter).max(cv / plausible) <= goal;
            assert_eq!(d["stop"].as_bool(), Some(meets), "{d}");
            // Only the last decision of a sweep may stop it.
            assert_eq!(meets, k + 1 == decisions.len(), "{run}: {d}");
        }
        let last = decisions.last().unwrap();
        let m_run = if last["stop"] == true {
            last["m"].as_u64().unwrap()
        } else {
            BUDGET
        };
        total += m_run;
        ms.insert(run, m_run);
        // The curve of a stopped sweep honours the target against the simulator's truth.
        let comp = if run.contains("forward") {
            "ef_xx"
        } else {
            "eb_xx"
        };
        let c = x["components"]
            .as_array()
            .unwrap()
            .iter()
            .find(|c| c["component"] == comp)
            .unwrap();
        assert_eq!(c["cs"]["m"].as_u64(), Some(m_run), "{c}");
        // The directions measured other positions: a curve that pools the other's samples
        // says how many, and the degree of the difference the cross-validation chose.
        if let Some(p) = c["cs"]["pooled_with"].as_u64() {
            pooled_curves.push((run, p));
            assert!(
                [0, 1, 3].contains(&c["cs"]["difference_degree"].as_u64().unwrap()),
                "{c}"
            );
        }
        let truth = c["cs_vs_truth"]["mean_abs_um"].as_f64().unwrap();
        if last["stop"] == true {
            assert!(
                truth <= goal,
                "{run} stopped at {m_run}: true error {truth} µm"
            );
        }
    }
    assert_eq!(total, measured);
    // Each pooled curve holds all the other direction measured.
    assert!(!pooled_curves.is_empty(), "no curve pooled");
    for (run, p) in &pooled_curves {
        assert_eq!(p + ms[run], total, "{run}: {pooled_curves:?}");
    }
    // The two sweeps take turns batch by batch (no trip back across the stroke between two
    // batches of one direction): forward k, backward k, forward k + 1, ...
    let order: Vec<(String, u64)> = events
        .iter()
        .filter(|e| e.kind == "adaptive")
        .map(|e| {
            (
                e.data["run"].as_str().unwrap().to_string(),
                e.data["batch"].as_u64().unwrap(),
            )
        })
        .collect();
    let both = order
        .iter()
        .filter(|(r, _)| r == "cs-x-backward-0")
        .count()
        .min(order.iter().filter(|(r, _)| r == "cs-x-forward-0").count());
    for k in 0..both {
        assert_eq!(
            order[2 * k],
            ("cs-x-forward-0".to_string(), k as u64),
            "{order:?}"
        );
        assert_eq!(
            order[2 * k + 1],
            ("cs-x-backward-0".to_string(), k as u64),
            "{order:?}"
        );
    }
    // A decision waits for the sweep's next turn, so it sees the other direction's batch
    // measured in between: a pooled estimate holds all the other run had measured by then
    // (forward's decision k follows backward's batch k; backward's follows forward's k + 1).
    let batches_of = |run: &str| -> u64 {
        let last = events
            .iter()
            .rev()
            .find(|e| e.kind == "adaptive" && e.data["run"] == run)
            .map(|e| &e.data);
        match last {
            Some(d) if d["stop"] == true => d["batch"].as_u64().unwrap() + 1,
            _ => BUDGET / BATCH,
        }
    };
    let (nf, nb) = (batches_of("cs-x-forward-0"), batches_of("cs-x-backward-0"));
    let mut pooled = 0;
    for d in events
        .iter()
        .filter(|e| e.kind == "adaptive")
        .map(|e| &e.data)
    {
        let k = d["batch"].as_u64().unwrap();
        let other = if d["run"] == "cs-x-forward-0" {
            BATCH * (k + 1).min(nb)
        } else {
            BATCH * (k + 2).min(nf)
        };
        let p = d["pooled_m"].as_u64().unwrap();
        assert!(p == 0 || p == other, "expected {other} pooled: {d}");
        pooled += usize::from(p > 0);
    }
    assert!(pooled > 0, "no decision pooled the other direction");
    // The summary says where each sweep stopped and what that saved.
    let runs = x["adaptive"].as_array().expect("summary: adaptive");
    assert_eq!(runs.len(), 2, "{runs:?}");
    let saved_targets: u64 = runs
        .iter()
        .map(|r| r["saved_targets"].as_u64().unwrap())
        .sum();
    assert_eq!(saved_targets, saved);
    assert!(runs
        .iter()
        .all(|r| r["planned"] == BUDGET && r["target_error_um"] == goal));
    // The time saved is what the summary reports against the full scan.
    let pct = x["acquisition_saved_pct"].as_f64().unwrap();
    assert!(
        pct > 100.0 * (1.0 - (measured as f64 + 10.0) / 802.0),
        "{pct}"
    );
}
