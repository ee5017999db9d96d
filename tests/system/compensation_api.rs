//! `POST /stages/{name}/move` on the service: refused (409) while a campaign of the stage runs
//! or waits, then a (compensated) move on the stage's hardware; bad requests are 400/404 and
//! move nothing.
use crate::common;

use common::Server;

#[test]
fn a_move_waits_for_no_campaign_and_uses_the_stage_s_compensation() {
    let dir = tempfile::tempdir().unwrap();
    let mut srv = Server::start(dir.path(), None);
    let stage = "comp-api-xy";
    // Slow enough (simulated time 10x) to still run when the move is asked for.
    let id = srv.submit(&common::campaign("char", stage, 20, 10.0));
    let body = r#"{"x_um": 500.0, "compensation_from": 1, "measure": true}"#;
    let path = format!("/stages/{stage}/move");
    let (s, v) = srv.post(&path, Some(("application/json", body)));
    assert_eq!(s, 409, "{v}");
    assert!(v["error"].as_str().unwrap().contains("campaign"), "{v}");
    srv.wait_for(id, 120.0, |st| st["state"] == "done");
    // Compensated, both directions: the camera finds the stage where it was asked to go.
    for dir in ["forward", "backward"] {
        let b = format!(
            r#"{{"x_um": 512.5, "direction": "{dir}", "compensation_from": {id}, "measure": true}}"#
        );
        // "done" is stored before the session has released the hardware: the stage is busy
        // (409) for that moment.
        let t0 = std::time::Instant::now();
        let (s, v) = loop {
            let (s, v) = srv.post(&path, Some(("application/json", &b)));
            if s != 409 || t0.elapsed().as_secs() > 30 {
                break (s, v);
            }
            std::thread::sleep(std::time::Duration::from_millis(100));
        };
        assert_eq!(s, 200, "{v}");
        let ax = &v["axes"][0];
        assert_eq!(ax["axis"], "x");
        assert_eq!(ax["approach"], dir);
        assert_eq!(ax["wanted_um"], 512.5);
        let cmd = ax["command_um"].as_f64().unwrap();
        assert!((ax["correction_um"].as_f64().unwrap() - (cmd - 512.5)).abs() < 1e-9);
        assert!(
            (v["measured_x_um"].as_f64().unwrap() - 512.5).abs() < 0.2,
            "{v}"
        );
        assert_eq!(v["compensation"], format!("campaign {id}"));
    }
    // Outside the table ([0, 1000] µm): refused, nothing moved.
    let (s, v) = srv.post(
        &path,
        Some((
            "application/json",
            r#"{"x_um": 5000.0, "compensation_from": 1}"#,
        )),
    );
    assert_eq!(s, 400, "{v}");
    assert!(v["error"]
        .as_str()
        .unwrap()
        .contains("outside the compensated range"));
    // Another stage's characterisation, an unknown stage, a bad body.
    let (s, v) = srv.post(
        "/stages/other/move",
        Some((
            "application/json",
            r#"{"x_um": 1.0, "compensation_from": 1}"#,
        )),
    );
    assert_eq!(s, 400, "{v}");
    let (s, _) = srv.post(
        "/stages/other/move",
        Some(("application/json", r#"{"x_um": 1.0}"#)),
    );
    assert_eq!(s, 404);
    let (s, _) = srv.post(&path, Some(("application/json", r#"{"x_um": "far"}"#)));
    assert_eq!(s, 400);
    let (s, _) = srv.post(
        &path,
        Some(("application/json", r#"{"x_um": 1.0, "approach_um": -5}"#)),
    );
    assert_eq!(s, 400);
    srv.terminate();
}

/// A verification submitted as a campaign (`verify = ID`, no axes of its own) runs on the
/// service; its verdict is at `GET /campaigns/{id}/verification` (404 for a campaign without
/// one). An id not in this service's store, or of another stage, is refused at submit.
#[test]
fn a_verification_campaign_runs_on_the_service_and_its_verdict_is_served() {
    let dir = tempfile::tempdir().unwrap();
    let mut srv = Server::start(dir.path(), None);
    let stage = "verify-api-xy";
    let id = srv.submit(&common::campaign("char", stage, 20, 1000.0));
    srv.wait_for(id, 120.0, |st| st["state"] == "done");
    let (s, v) = srv.get(&format!("/campaigns/{id}/verification"));
    assert_eq!(s, 404, "{v}");
    // The characterisation's file less its axes and sampling, two cycles (R), `verify = ID`.
    let verify_file = |stage: &str, of: i64| {
        let t = common::campaign("ver", stage, 20, 1000.0);
        let (a, b) = (
            t.find("[axes.x]").unwrap(),
            t.find("[acquisition]").unwrap(),
        );
        format!("{}{}", &t[..a], &t[b..])
            .replacen("[acquisition]\n", "[acquisition]\ncycles = 2\n", 1)
            .replacen("stage = ", &format!("verify = {of}\nstage = "), 1)
    };
    let vid = srv.submit(&verify_file(stage, id));
    let st = srv.wait_for(vid, 120.0, |st| {
        st["state"] == "done" || st["state"] == "failed"
    });
    let (s, v) = srv.get(&format!("/campaigns/{vid}/verification"));
    assert_eq!(s, 200, "{v}");
    assert_eq!(v["campaign"], id);
    assert_eq!(v["passed"], st["state"] == "done", "{v} {st}");
    let x = &v["axes"][0];
    assert_eq!(x["axis"], "x");
    for k in ["a_um", "b_um", "e_um", "m_um", "r_um"] {
        assert!(
            x["before"][k].is_number() && x["after"][k].is_number(),
            "{k}: {x}"
        );
    }
    assert!(x["max_abs_after_um"].is_number() && x["expected_um"].is_number());
    // Both passes' samples are the campaign's (2 cycles x 2 directions x each target).
    let targets: usize = [
        "iso_targets_um",
        "unvisited_targets_um",
        "extrapolated_targets_um",
    ]
    .iter()
    .map(|k| x[*k].as_array().unwrap().len())
    .sum();
    assert_eq!(
        common::stored_seqs(&srv.db(), vid).len(),
        2 * 2 * 2 * targets
    );
    // Refused at submit: not in this store, another stage's characterisation.
    let body = verify_file(stage, 999);
    let (s, v) = srv.post("/campaigns", Some(("application/toml", body.as_str())));
    assert_eq!(s, 400, "{v}");
    assert!(
        v["error"].as_str().unwrap().contains("no campaign 999"),
        "{v}"
    );
    let body = verify_file("other-xy", id);
    let (s, v) = srv.post("/campaigns", Some(("application/toml", body.as_str())));
    assert_eq!(s, 400, "{v}");
    assert!(v["error"].as_str().unwrap().contains("ran on stage"), "{v}");
    let (s, _) = srv.get("/campaigns/999/verification");
    assert_eq!(s, 404);
    srv.terminate();
}
