//! A `[map]` campaign through the service: submitted, paused (no sample while paused), resumed
//! (re-approached from the run's side), finished with its map files in the store.
use crate::common;

use std::time::Duration;

use common::Server;
use serde_json::Value;

fn state(v: &Value) -> &str {
    v["state"].as_str().unwrap_or("?")
}

#[test]
fn a_map_campaign_pauses_resumes_and_reports_through_the_service() {
    let dir = tempfile::tempdir().unwrap();
    let srv = Server::start(dir.path(), None);
    let id = srv.submit(&common::map_campaign("svc-map"));
    assert_eq!(srv.status(id)["planned"], 40);
    srv.wait_for(id, 60.0, |s| s["stored"].as_u64() > Some(3));
    let (s, v) = srv.post(&format!("/campaigns/{id}/pause"), None);
    assert_eq!((s, state(&v)), (200, "paused"), "{v}");
    std::thread::sleep(Duration::from_millis(500));
    let n = srv.status(id)["stored"].as_u64().unwrap();
    std::thread::sleep(Duration::from_millis(1000));
    assert_eq!(srv.status(id)["stored"].as_u64().unwrap(), n, "paused");
    assert!(n < 40, "paused mid-map ({n} stored)");
    let (s, v) = srv.post(&format!("/campaigns/{id}/resume"), None);
    assert_eq!((s, state(&v)), (200, "running"), "{v}");
    let st = srv.wait_for(id, 120.0, |s| state(s) == "done" || state(s) == "failed");
    assert_eq!(state(&st), "done", "{st}");
    assert_eq!(st["stored"], 40);
    let (s, files) = srv.get(&format!("/campaigns/{id}/results"));
    assert_eq!(s, 200);
    let text = files.to_string();
    for f in [
        "map_forward.csv",
        "compensation_map_forward.csv",
        "plots/map_forward_ex.png",
        "plots/map_forward_residual_ey.svg",
    ] {
        assert!(text.contains(f), "{f} in {text}");
    }
    let (s, summary) = srv.get(&format!("/campaigns/{id}/results/summary.json"));
    assert_eq!(s, 200);
    assert_eq!(summary["map"]["measurements"], 40, "{summary}");
    assert_eq!(summary["map"]["runs"][0]["method"], "linear");
    // The service's report has the residual against the simulator's truth too.
    let vs = &summary["map"]["runs"][0]["vs_truth"];
    assert!(vs["ex"]["mean_abs_um"].as_f64().is_some(), "{summary}");
}
