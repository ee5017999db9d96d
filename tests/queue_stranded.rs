//! A campaign queued behind a foreground `csmetro run` whose process dies (kill -9) is started
//! once the stage is free, whichever of the service's stage retry and orphan sweep comes first;
//! it was left `queued` for good (6/10 tries) when the retry won: the store still showed the
//! dead run `running`, and the start failed. Queued campaigns stay controllable meanwhile.
//!
//! The dead process is played by this test: it holds the stage lock with a campaign marked
//! `running` in the service's store, then lets the lock go without finishing it (what the
//! kernel does for a killed process). `CSMETRO_QUEUE_TRIALS` sets the number of tries (default 4;
//! the note's figure used 50).
mod common;

use std::time::{Duration, Instant};

use common::{campaign, test_lock_dir, Server};
use csmetro::campaign::stagelock;
use csmetro::store::Store;
use csmetro::types::CampaignState;

fn state(srv: &Server, id: i64) -> String {
    srv.status(id)["state"]
        .as_str()
        .unwrap_or_default()
        .to_string()
}

#[test]
fn a_campaign_queued_behind_a_killed_foreground_run_starts_when_the_stage_frees() {
    // The same lock directory as the service's (common::bin()).
    std::env::set_var("CSMETRO_LOCK_DIR", test_lock_dir());
    let dir = tempfile::tempdir().unwrap();
    let srv = Server::start(dir.path(), None);
    let db = srv.db();
    let trials: usize = std::env::var("CSMETRO_QUEUE_TRIALS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(4);
    let stage = "sim-q";
    for t in 0..trials {
        // The foreground run: holds the stage, its campaign `running` in the store.
        let lock = stagelock::try_lock(&db, stage).expect("stage free between trials");
        let dead = {
            let s = Store::open(&db).unwrap();
            let text = campaign(&format!("fg{t}"), stage, 4, 1000.0);
            let id = s
                .create_campaign(&format!("fg{t}"), &text, "fg.toml", stage, 8)
                .unwrap();
            s.set_state(id, CampaignState::Running, None).unwrap();
            id
        };
        let queued = srv.submit(&campaign(&format!("svc{t}"), stage, 4, 1000.0));
        assert_eq!(state(&srv, queued), "queued");
        // Spread the death over the service's 2 s retry period.
        std::thread::sleep(Duration::from_millis(300 + 450 * (t as u64 % 5)));
        drop(lock);
        let t0 = Instant::now();
        loop {
            let st = state(&srv, queued);
            if st == "done" {
                break;
            }
            assert!(
                t0.elapsed() < Duration::from_secs(60) && st != "failed",
                "trial {t}: campaign {queued} is {st}; log:\n{}",
                srv.log()
            );
            std::thread::sleep(Duration::from_millis(100));
        }
        assert_eq!(state(&srv, dead), "interrupted", "trial {t}");
        // Its resumable state is controllable: abort ends it.
        let (s, v) = srv.post(&format!("/campaigns/{dead}/abort"), None);
        assert_eq!(s, 200, "{v}");
    }
}

#[test]
fn a_queued_campaign_can_be_paused_resumed_and_aborted() {
    std::env::set_var("CSMETRO_LOCK_DIR", test_lock_dir());
    let dir = tempfile::tempdir().unwrap();
    let srv = Server::start(dir.path(), None);
    let db = srv.db();
    let stage = "sim-p";
    // Another process holds the stage: the submitted campaign waits in the queue.
    let lock = stagelock::try_lock(&db, stage).unwrap();
    let a = srv.submit(&campaign("a", stage, 4, 1000.0));
    let b = srv.submit(&campaign("b", stage, 4, 1000.0));
    assert_eq!(state(&srv, a), "queued");
    let (s, v) = srv.post(&format!("/campaigns/{a}/pause"), None);
    assert_eq!((s, v["state"].as_str()), (200, Some("paused")), "{v}");
    let (s, v) = srv.post(&format!("/campaigns/{b}/abort"), None);
    assert_eq!((s, v["state"].as_str()), (200, Some("aborted")), "{v}");
    drop(lock);
    // Paused before it started: it does not start on its own.
    std::thread::sleep(Duration::from_secs(3));
    assert_eq!(state(&srv, a), "paused");
    assert_eq!(state(&srv, b), "aborted");
    let (s, v) = srv.post(&format!("/campaigns/{a}/resume"), None);
    assert_eq!(s, 200, "{v}");
    srv.wait_for(a, 60.0, |st| st["state"] == "done");
    assert_eq!(state(&srv, b), "aborted", "an aborted campaign never runs");
}
