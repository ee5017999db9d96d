//! An operator's pause survives a service restart, whether the service was killed (`kill -9`)
//! or shut down (SIGTERM): the campaign stays paused, the stage does not move, and only the
//! operator's resume continues it.
use crate::common;

use std::collections::BTreeSet;
use std::time::Duration;

use common::{campaign, stored_seqs, Server};
use serde_json::Value;

fn state(v: &Value) -> &str {
    v["state"].as_str().unwrap_or("")
}

fn pause_then_restart(kill9: bool) {
    let dir = tempfile::tempdir().unwrap();
    let mut srv = Server::start(dir.path(), None);
    let id = srv.submit(&campaign("held", "s1", 40, 10.0));
    srv.wait_for(id, 30.0, |s| s["stored"].as_u64() > Some(3));
    let (s, v) = srv.post(&format!("/campaigns/{id}/pause"), None);
    assert_eq!((s, state(&v)), (200, "paused"), "{v}");
    std::thread::sleep(Duration::from_millis(300));
    if kill9 {
        srv.kill9();
    } else {
        assert!(srv.terminate().success(), "{}", srv.log());
    }
    let n = stored_seqs(&srv.db(), id).len();
    drop(srv);

    let srv = Server::start(dir.path(), None);
    // Longer than the orphan sweep's period: nothing turns the pause into a run.
    std::thread::sleep(Duration::from_millis(3000));
    let st = srv.status(id);
    assert_eq!(state(&st), "paused", "{st}\n{}", srv.log());
    assert_eq!(stored_seqs(&srv.db(), id).len(), n, "measured while paused");
    let (s, v) = srv.post(&format!("/campaigns/{id}/resume"), None);
    assert_eq!(s, 200, "{v}");
    let st = srv.wait_for(id, 120.0, |s| state(s) == "done");
    assert_eq!(st["stored"], 80, "{st}");
    let seqs = stored_seqs(&srv.db(), id);
    assert_eq!(seqs.iter().copied().collect::<BTreeSet<u64>>().len(), 80);
}

#[test]
fn a_pause_survives_kill_9_and_restart() {
    pause_then_restart(true);
}

#[test]
fn a_pause_survives_a_shutdown_and_restart() {
    pause_then_restart(false);
}
