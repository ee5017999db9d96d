//! A campaign that could not do its job says so: points whose every frame was rejected and
//! reconstructions that failed end the campaign `failed` (exit 1, reasons in the summary, the
//! status and the events), and so do results that cannot be written.
use crate::common;

use std::path::Path;
use std::process::Output;

use common::{fail_writes, repo, resume, run_json, sim_header};
use csmetro::store::Store;
use csmetro::types::CampaignState;
use serde_json::Value;

/// `m` random targets per direction on x from `lo_um` over 250 µm (step 25 µm), results to `out`.
fn campaign(dir: &Path, lo_um: f64, out: &Path, extra: &str) -> std::path::PathBuf {
    campaign_at(dir, lo_um, out, extra, 1000.0)
}

/// [`campaign`] at the given simulated time scale.
fn campaign_at(
    dir: &Path,
    lo_um: f64,
    out: &Path,
    extra: &str,
    time_scale: f64,
) -> std::path::PathBuf {
    let head = sim_header(
        "fails",
        "sim-fail",
        &repo("config/sim/ideal.toml").display().to_string(),
        time_scale,
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
    let errors = errors_of(&j);
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

/// Makes the store refuse one kind of write, as a full disk or a read-only store would: the
/// schema is created first, then a trigger fails the writes `when` selects.
/// `csmetro run` of the failing-stage campaign at time scale 1 (physical time is wall time, so a
/// signal or abort lands mid-run), stderr piped.
fn run_at_time_scale_1(dir: &Path, db: &Path) -> std::process::Child {
    let c = campaign_at(dir, 1000.0, &dir.join("out"), "", 1.0);
    common::bin()
        .args(["run", "--quiet", "--db"])
        .arg(db)
        .arg(&c)
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap()
}

/// Sends `signal` to `child` 300 ms after `ready` (a count) first reads 1 in the store at `db`
/// (within 30 s), and waits for it.
fn signal_when(
    db: &Path,
    child: std::process::Child,
    ready: &str,
    signal: &str,
) -> std::process::Output {
    let t0 = std::time::Instant::now();
    while !rusqlite::Connection::open(db)
        .and_then(|c| c.query_row(ready, [], |r| r.get::<_, i64>(0)))
        .is_ok_and(|n| n == 1)
    {
        assert!(t0.elapsed().as_secs() < 30, "never ready: {ready}");
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    std::thread::sleep(std::time::Duration::from_millis(300));
    let pid = child.id().to_string();
    assert!(std::process::Command::new("kill")
        .args([signal, &pid])
        .status()
        .unwrap()
        .success());
    child.wait_with_output().unwrap()
}

/// A summary's `errors`.
fn errors_of(j: &Value) -> Vec<&str> {
    j["errors"]
        .as_array()
        .unwrap()
        .iter()
        .filter_map(Value::as_str)
        .collect()
}

#[test]
fn a_curve_that_cannot_be_stored_fails_the_campaign() {
    let dir = tempfile::tempdir().unwrap();
    let db = dir.path().join("c.db");
    fail_writes(
        &db,
        "CREATE TRIGGER no_curves BEFORE INSERT ON results WHEN NEW.name LIKE 'curves/%' \
         BEGIN SELECT RAISE(FAIL, 'disk full (test)'); END;",
    );
    let c = campaign(dir.path(), 1000.0, &dir.path().join("out"), "");
    let o = run_json(&c, &db);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    let j = summary(&o);
    assert_eq!(j["state"], "failed", "{j}");
    let errors = j["errors"].to_string();
    assert!(
        errors.contains("curves/") && errors.contains("not stored") && errors.contains("disk full"),
        "{errors}"
    );
    let s = Store::open(&db).unwrap();
    let row = s.campaign(1).unwrap().unwrap();
    assert_eq!(row.state, CampaignState::Failed);
    assert!(row.message.unwrap_or_default().contains("not stored"));
    let log = s.events_after(1, 0).unwrap();
    assert!(
        !log.iter().any(|e| e.kind == "reconstructed"),
        "a curve not stored is not announced as reconstructed"
    );
    assert!(log
        .iter()
        .any(|e| e.kind == "error" && e.data["cause"] == "storage"));
}

#[test]
fn an_abort_whose_state_cannot_be_stored_is_an_error() {
    // Left `running` in the store, an aborted campaign would be resumed by the service's next
    // start: the abort must not be reported as done.
    let dir = tempfile::tempdir().unwrap();
    let db = dir.path().join("c.db");
    fail_writes(
        &db,
        "CREATE TRIGGER no_abort BEFORE UPDATE OF state ON campaigns \
         WHEN NEW.state = 'aborted' BEGIN SELECT RAISE(FAIL, 'disk full (test)'); END;",
    );
    // Time scale 1: still referencing when the abort comes.
    let child = run_at_time_scale_1(dir.path(), &db);
    let o = signal_when(
        &db,
        child,
        "SELECT count(*) FROM campaigns WHERE id = 1 AND state = 'running'",
        "-INT",
    );
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(
        err.contains("motion stopped, but its state (aborted) was not stored"),
        "{err}"
    );
    assert!(!err.contains("aborted; motion stopped"), "{err}");
}

#[test]
fn an_event_that_cannot_be_stored_fails_the_campaign_and_loses_no_sample() {
    let dir = tempfile::tempdir().unwrap();
    let db = dir.path().join("c.db");
    fail_writes(
        &db,
        "CREATE TRIGGER no_reconstructed BEFORE INSERT ON events \
         WHEN NEW.kind = 'reconstructed' BEGIN SELECT RAISE(ABORT, 'injected (test)'); END;",
    );
    let c = campaign(dir.path(), 1000.0, &dir.path().join("out"), "");
    let o = run_json(&c, &db);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(err.contains("event `reconstructed` not stored"), "{err}");
    let j = summary(&o);
    assert_eq!(j["state"], "failed", "{j}");
    let errors = errors_of(&j);
    assert!(
        errors.iter().any(
            |e| e.contains("event `reconstructed` not stored") && e.contains("injected (test)")
        ),
        "{errors:?}"
    );
    // Only the event is lost: every sample, the curve and the figures are there.
    assert_eq!(j["axes"][0]["phases"]["cs"]["measurements"], 5, "{j}");
    let s = Store::open(&db).unwrap();
    assert_eq!(s.samples(1).unwrap().len(), 5);
    let names = s.result_names(1).unwrap();
    assert!(names.iter().any(|n| n.starts_with("curves/")), "{names:?}");
    let row = s.campaign(1).unwrap().unwrap();
    assert_eq!(row.state, CampaignState::Failed);
    assert!(
        row.message.unwrap_or_default().contains("not stored"),
        "the state's message says it"
    );
    // summary.json as stored and as written say the same.
    let (_, stored) = s.result(1, "summary.json").unwrap().unwrap();
    let stored: Value = serde_json::from_slice(&stored).unwrap();
    assert_eq!(stored["state"], "failed");
    assert_eq!(stored["errors"], j["errors"]);
    let written: Value = serde_json::from_slice(
        &std::fs::read(dir.path().join("out").join("summary.json")).unwrap(),
    )
    .unwrap();
    assert_eq!(written["errors"], j["errors"]);
    let log = s.events_after(1, 0).unwrap();
    assert!(!log.iter().any(|e| e.kind == "reconstructed"));
    let fin = log.iter().rfind(|e| e.kind == "finished").unwrap();
    assert_eq!(fin.data["state"], "failed", "{}", fin.data);
}

#[test]
fn events_not_stored_before_a_stop_are_in_the_interrupted_state() {
    let dir = tempfile::tempdir().unwrap();
    let db = dir.path().join("c.db");
    fail_writes(
        &db,
        "CREATE TRIGGER no_rig BEFORE INSERT ON events WHEN NEW.kind = 'rig' \
         BEGIN SELECT RAISE(ABORT, 'injected (test)'); END;",
    );
    // Time scale 1: still measuring when the stop comes.
    let child = run_at_time_scale_1(dir.path(), &db);
    // The `rig` event is written (and refused) before anything moves.
    let o = signal_when(
        &db,
        child,
        "SELECT count(*) FROM events WHERE campaign_id = 1 AND kind = 'started'",
        "-TERM",
    );
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(143), "{err}");
    let row = Store::open(&db).unwrap().campaign(1).unwrap().unwrap();
    assert_eq!(row.state, CampaignState::Interrupted);
    let msg = row.message.unwrap_or_default();
    assert!(
        msg.contains("event `rig` not stored") && msg.contains("injected (test)"),
        "{msg}"
    );
}
