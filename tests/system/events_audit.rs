//! The event stream is the campaign's audit trail: every state change is an event with its
//! cause and its origin (the command line, the API client's address, the operator's name when
//! given), errors included, and a campaign's `updated_unix_s` moves with every sample.
use crate::common;
#[path = "../rig/mod.rs"]
mod rig;

use std::time::Duration;

use common::{bin, campaign, Server};
use csmetro::store::{EventRow, Store};
use csmetro::types::CampaignState;
use serde_json::Value;

fn state(v: &Value) -> &str {
    v["state"].as_str().unwrap_or("")
}

/// POST as an operator (`X-Operator`), or anonymously.
fn post_as(srv: &Server, path: &str, operator: Option<&str>, body: Option<&str>) -> (u16, Value) {
    let agent: ureq::Agent = ureq::Agent::config_builder()
        .http_status_as_error(false)
        .build()
        .into();
    let mut r = agent.post(&format!("{}{path}", srv.url));
    if let Some(o) = operator {
        r = r.header("X-Operator", o);
    }
    let mut resp = match body {
        Some(b) => r.content_type("application/toml").send(b),
        None => r.send_empty(),
    }
    .unwrap();
    let status = resp.status().as_u16();
    let v = resp.body_mut().read_json().unwrap_or(Value::Null);
    (status, v)
}

fn kinds(events: &[EventRow]) -> Vec<&str> {
    events.iter().map(|e| e.kind.as_str()).collect()
}

#[test]
fn pause_and_resume_over_http_are_events_that_say_who_and_from_where() {
    let dir = tempfile::tempdir().unwrap();
    let srv = Server::start(dir.path(), None);
    let (s, v) = post_as(
        &srv,
        "/campaigns",
        Some("ana"),
        Some(&campaign("audited", "s1", 40, 10.0)),
    );
    assert_eq!(s, 201, "{v}");
    let id = v["id"].as_i64().unwrap();
    // updated_unix_s moves with the samples while nothing else changes.
    let a = srv.wait_for(id, 30.0, |s| s["stored"].as_u64() > Some(2));
    let b = srv.wait_for(id, 30.0, |s| s["stored"].as_u64() > a["stored"].as_u64());
    assert_eq!((state(&a), state(&b)), ("running", "running"));
    assert!(
        b["updated_unix_s"].as_f64() > a["updated_unix_s"].as_f64(),
        "updated_unix_s did not move with the samples: {a} {b}"
    );
    // A bad operator name is bad input.
    let (s, v) = post_as(
        &srv,
        &format!("/campaigns/{id}/pause"),
        Some(&"x".repeat(65)),
        None,
    );
    assert_eq!(s, 400, "{v}");
    let (s, v) = post_as(&srv, &format!("/campaigns/{id}/pause"), Some("ana"), None);
    assert_eq!((s, state(&v)), (200, "paused"), "{v}");
    assert!(v["message"].as_str().unwrap().contains("\"ana\""), "{v}");
    // Resumed at once, by `csmetro unpause --operator`: both changes are in the log even if
    // the engine never held between them.
    let o = bin()
        .args(["unpause", &id.to_string(), "--json", "--operator", "cy"])
        .env("CSMETRO_SERVER", &srv.url)
        .env_remove("CSMETRO_TOKEN")
        .output()
        .unwrap();
    let v: Value = serde_json::from_slice(&o.stdout).unwrap_or(Value::Null);
    assert_eq!(
        state(&v),
        "running",
        "{v} {}",
        String::from_utf8_lossy(&o.stderr)
    );
    srv.wait_for(id, 120.0, |s| state(s) == "done");

    let ev = Store::open(&srv.db()).unwrap().events_after(id, 0).unwrap();
    let k = kinds(&ev);
    let find = |kind: &str| {
        ev.iter()
            .find(|e| e.kind == kind)
            .unwrap_or_else(|| panic!("no {kind} event in {k:?}"))
    };
    let queued = find("queued");
    assert_eq!(queued.data["origin"]["operator"], "ana", "{}", queued.data);
    let paused = find("paused");
    let o = &paused.data["origin"];
    assert_eq!(
        (o["via"].as_str(), o["operator"].as_str()),
        (Some("api"), Some("ana")),
        "{}",
        paused.data
    );
    assert!(
        o["client"].as_str().unwrap().starts_with("127.0.0.1:"),
        "{}",
        paused.data
    );
    assert!(paused.data["by"].as_str().unwrap().contains("ana"));
    let resumed = find("resumed");
    assert_eq!(resumed.data["origin"]["via"], "api", "{}", resumed.data);
    assert_eq!(resumed.data["origin"]["operator"], "cy", "{}", resumed.data);
    assert!(resumed.data["origin"]["client"].is_string());
    let pos = |kind: &str| k.iter().position(|x| *x == kind).unwrap();
    assert!(
        pos("paused") < pos("resumed") && pos("resumed") < pos("finished"),
        "{k:?}"
    );
}

#[test]
fn a_camera_failure_is_an_error_event_before_the_campaign_is_requeued() {
    let dir = tempfile::tempdir().unwrap();
    // Two simulated C-863 controllers on TCP (the hardware path of a `kind = "real"` campaign).
    let rig = rig::Rig::start(
        std::path::Path::new(env!("CARGO_BIN_EXE_csmetro")),
        &rig::rig_file(dir.path(), None, 1.0, 2.0, false),
    );
    // No camera answers at 127.0.0.1 (and without the `aravis` feature there is no GigE
    // camera support at all): the rig cannot open its camera.
    let hardware = rig::real_hardware(
        &rig.x,
        &rig.y,
        [500.0, 3000.0],
        [500.0, 4000.0],
        r#"{ ip = "127.0.0.1" }"#,
    );
    // The service's store (common::write_config): the foreground run uses the same file.
    let db = dir.path().join("var/csmetro.db");
    let file = dir.path().join("real.toml");
    std::fs::write(
        &file,
        format!(
            r#"[campaign]
name = "no-camera"
stage = "lab-xy"
{hardware}
[axes.x]
range_um = [1000.0, 1200.0]
step_um = 10.0
other_at_um = 2100.0
m = 5

[outputs]
dir = "out-{{id}}"
"#
        ),
    )
    .unwrap();
    let o = bin()
        .args(["run", "--quiet", "--operator", "bo", "--db"])
        .arg(&db)
        .arg(&file)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success(), "{err}");
    assert!(err.contains("camera"), "{err}");
    // The pre-flight (or, in a build without the camera's backend, validation) refuses it before
    // anything is recorded: no campaign, no events.
    std::fs::create_dir_all(db.parent().unwrap()).unwrap();
    let recorded = Store::open(&db).unwrap().campaigns().unwrap().len();
    assert_eq!(recorded, 0, "nothing recorded: {err}");

    // A campaign recorded before its camera went away (an earlier attempt left it interrupted).
    let s = Store::open(&db).unwrap();
    let toml = std::fs::read_to_string(&file).unwrap();
    let id = s
        .create_campaign("no-camera", &toml, &file.display().to_string(), "lab-xy", 0)
        .unwrap();
    assert_eq!(id, 1);
    s.set_state(id, CampaignState::Interrupted, Some("earlier attempt"))
        .unwrap();
    drop(s);

    // The service takes the interrupted campaign up again at its start: requeued, then the
    // failure as an error event before the attempt ends.
    let srv = Server::start(dir.path(), None);
    let t0 = std::time::Instant::now();
    let ev = loop {
        let ev = Store::open(&db).unwrap().events_after(1, 0).unwrap();
        if ev.iter().any(|e| e.kind == "error") {
            break ev;
        }
        assert!(
            t0.elapsed() < Duration::from_secs(60),
            "{:?}\n{}",
            kinds(&ev),
            srv.log()
        );
        std::thread::sleep(Duration::from_millis(100));
    };
    let k = kinds(&ev);
    let requeued = k.iter().position(|x| *x == "requeued").expect("requeued");
    assert!(k[requeued..].contains(&"error"), "{k:?}");
    assert_eq!(ev[requeued].data["previous_state"], "interrupted");
    assert_eq!(
        ev[requeued].data["by"], "the service",
        "{}",
        ev[requeued].data
    );
}
