//! A campaign that could not do its job says so: points whose every frame was rejected and
//! reconstructions that failed end the campaign `failed` (exit 1, reasons in the summary, the
//! status and the events), and so do results that cannot be written.
mod common;

use std::path::Path;
use std::process::Output;

use common::{repo, resume, run_json, sim_header};
use csmetro::store::Store;
use csmetro::types::CampaignState;
use serde_json::Value;

/// `m` random targets per direction on x from `lo_um` over 250 µm (step 25 µm), results to `out`.
fn campaign(dir: &Path, lo_um: f64, out: &Path, extra: &str) -> std::path::PathBuf {
    let head = sim_header(
        "fails",
        "sim-fail",
        &repo("config/sim/ideal.toml").display().to_string(),
        1000.0,
        3,
    );
    let text = format!(
        r#"{head}
[axes.x]
range_um = [{lo_um}, {hi}]
step_um = 25.0
other_at_um = 2100.0
m = 5

[sampling]
design = "random"
seed = 4

[acquisition]
directions = ["forward"]
settle_s = 0.2
max_retries = 1

[outputs]
dir = "{out}"
{extra}"#,
        hi = lo_um + 250.0,
        out = out.display(),
    );
    let p = dir.join("campaign.toml");
    std::fs::write(&p, text).unwrap();
    p
}

fn summary(o: &Output) -> Value {
    serde_json::from_str(String::from_utf8_lossy(&o.stdout).trim()).unwrap()
}

#[test]
fn points_rejected_beyond_the_pattern_fail_the_campaign() {
    let dir = tempfile::tempdir().unwrap();
    let db = dir.path().join("c.db");
    // Past the end of the pattern (and of the stage model's travel): no frame decodes.
    let c = campaign(dir.path(), 12_500.0, &dir.path().join("out"), "");
    let o = run_json(&c, &db);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    let j = summary(&o);
    assert_eq!(j["state"], "failed", "{j}");
    let errors: Vec<&str> = j["errors"]
        .as_array()
        .unwrap()
        .iter()
        .filter_map(Value::as_str)
        .collect();
    assert!(
        errors
            .iter()
            .any(|e| e.contains("5 planned point(s) failed")),
        "{errors:?}"
    );
    assert!(
        errors.iter().any(|e| e.contains("reconstruction failed")),
        "{errors:?}"
    );
    assert!(err.contains("failed"), "{err}");
    assert_eq!(j["axes"][0]["phases"].as_object().map(|p| p.len()), Some(1));
    assert_eq!(j["axes"][0]["phases"]["cs"]["failed_points"], 5, "{j}");
    let s = Store::open(&db).unwrap();
    let row = s.campaign(1).unwrap().unwrap();
    assert_eq!(row.state, CampaignState::Failed);
    assert!(
        row.message
            .as_deref()
            .unwrap_or("")
            .contains("point(s) failed"),
        "{:?}",
        row.message
    );
    let fin = s
        .events_after(1, 0)
        .unwrap()
        .into_iter()
        .rfind(|e| e.kind == "finished")
        .unwrap();
    assert_eq!(fin.data["state"], "failed", "{}", fin.data);
    assert!(!fin.data["errors"].as_array().unwrap().is_empty());
    // Failed for good: nothing to resume.
    let o = resume(1, &[], &db);
    assert_eq!(o.status.code(), Some(2));
}

#[test]
fn results_that_cannot_be_written_are_an_error() {
    let dir = tempfile::tempdir().unwrap();
    let db = dir.path().join("c.db");
    // The directory passes the writability check at validation (exit 2 before anything runs
    // is `an_unwritable_output_directory_is_refused_before_anything_runs`); writing the
    // summary into it fails at the end: a directory stands where `summary.json` goes.
    let out = dir.path().join("results");
    std::fs::create_dir_all(out.join("summary.json")).unwrap();
    let c = campaign(dir.path(), 1000.0, &out, "");
    let o = run_json(&c, &db);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(
        !err.contains("results: "),
        "claims results were written: {err}"
    );
    assert!(err.contains("results not written"), "{err}");
    let j = summary(&o);
    assert_eq!(j["state"], "failed", "{j}");
    // The measurement itself is complete, and its results are in the store.
    assert_eq!(j["axes"][0]["phases"]["cs"]["measurements"], 5, "{j}");
    let s = Store::open(&db).unwrap();
    assert_eq!(s.campaign(1).unwrap().unwrap().state, CampaignState::Failed);
    assert!(s.result(1, "summary.json").unwrap().is_some());
}
