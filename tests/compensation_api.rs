//! `POST /stages/{name}/move` on the service: refused (409) while a campaign of the stage runs
//! or waits, then a (compensated) move on the stage's hardware; bad requests are 400/404 and
//! move nothing.
mod common;

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
        let (s, v) = srv.post(&path, Some(("application/json", &b)));
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
