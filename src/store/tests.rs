use super::*;
use crate::types::{AxisId, Direction, Phase, RunKey, Target};
use rand::{Rng, SeedableRng};
use std::process::{Child, Command, Stdio};
use std::time::Instant;

/// Every field of a record as bits, so `-0.0 != 0.0` and NaN payloads count.
fn bits(s: &SampleRecord) -> Vec<u64> {
    let t = &s.target;
    let mut v = vec![
        t.seq,
        t.run.phase as u64,
        t.run.axis as u64,
        t.run.direction as u64,
        u64::from(t.run.cycle),
        t.grid_index as u64,
        u64::from(s.frames),
        u64::from(s.rejected),
    ];
    v.extend(reals(s).iter().map(|x| x.to_bits()));
    v
}

fn assert_bit_exact(got: &[SampleRecord], want: &[SampleRecord]) {
    assert_eq!(got.len(), want.len(), "sample count");
    for (g, w) in got.iter().zip(want) {
        assert_eq!(bits(g), bits(w), "seq {}: {g:?} != {w:?}", w.target.seq);
    }
}

/// A plain deterministic sample (finite values), the same in parent and child processes.
fn sample(seq: u64) -> SampleRecord {
    let k = seq as f64;
    SampleRecord {
        target: Target {
            seq,
            run: RunKey {
                phase: if seq.is_multiple_of(3) {
                    Phase::Full
                } else {
                    Phase::Cs
                },
                axis: if seq.is_multiple_of(2) {
                    AxisId::X
                } else {
                    AxisId::Y
                },
                direction: if seq % 4 < 2 {
                    Direction::Forward
                } else {
                    Direction::Backward
                },
                cycle: (seq / 7) as u32,
            },
            grid_index: (seq % 101 * 13) as usize,
            target_x_um: k * 0.1 - 50.0,
            target_y_um: -k / 3.0,
        },
        meas_x_um: k * 0.1 - 50.0 + 1e-3 / (k + 1.0),
        meas_y_um: (k * 0.7).sin() * 0.013,
        theta_mrad: 1.0 / (k + 3.0),
        encoder_um: k * 0.1 - 50.0 + 2e-4,
        time_s: k * 0.351,
        unix_s: 1.7e9 + k * 0.351 + 1.0 / 7.0,
        quality: 1.0 - 1.0 / (k + 11.0),
        frames: 1 + (seq % 5) as u32,
        rejected: (seq % 3) as u32,
        point_s: 0.3 + k * 1e-9,
        frame_sd_um: (!seq.is_multiple_of(5)).then(|| [1e-3 * (k + 1.0).sqrt(), 0.02 / (k + 1.0)]),
    }
}

/// A sample whose float fields are all replaced by `f` (index 0..10 in [`REAL_NAMES`] order).
fn with_reals(mut s: SampleRecord, mut f: impl FnMut(usize) -> f64) -> SampleRecord {
    s.target.target_x_um = f(0);
    s.target.target_y_um = f(1);
    s.meas_x_um = f(2);
    s.meas_y_um = f(3);
    s.theta_mrad = f(4);
    s.encoder_um = f(5);
    s.time_s = f(6);
    s.unix_s = f(7);
    s.quality = f(8);
    s.point_s = f(9);
    s
}

fn new_campaign(store: &Store, stage: &str) -> i64 {
    store
        .create_campaign("c", "[design]\nn = 1\n", "/tmp/c.toml", stage, 10)
        .unwrap()
}

#[test]
fn store_is_send() {
    fn send<T: Send + 'static>() {}
    send::<Store>();
    send::<StoreError>();
}

#[test]
fn open_sets_pragmas_and_schema_version() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("deep/er/csmetro.db");
    for _ in 0..2 {
        // The second open finds the schema in place and leaves it alone.
        let store = Store::open(&path).unwrap();
        assert_eq!(store.path(), Some(path.as_path()));
        let q = |sql: &str| -> String {
            store
                .conn
                .query_row(sql, [], |r| r.get::<_, rusqlite::types::Value>(0))
                .map(|v| match v {
                    rusqlite::types::Value::Integer(i) => i.to_string(),
                    rusqlite::types::Value::Text(t) => t,
                    other => format!("{other:?}"),
                })
                .unwrap()
        };
        assert_eq!(q("PRAGMA journal_mode"), "wal");
        assert_eq!(q("PRAGMA synchronous"), "1", "NORMAL");
        assert_eq!(q("PRAGMA foreign_keys"), "1");
        assert_eq!(q("PRAGMA busy_timeout"), "5000");
        assert_eq!(q("PRAGMA user_version"), SCHEMA_VERSION.to_string());
        assert_eq!(q("PRAGMA application_id"), APPLICATION_ID.to_string());
        let tables = q(
            "SELECT group_concat(name, ',') FROM (SELECT name FROM sqlite_schema \
             WHERE type = 'table' AND name NOT LIKE 'sqlite_%' ORDER BY name)",
        );
        assert_eq!(
            tables,
            "campaigns,events,results,samples,stage_events,store_info"
        );
    }
    assert!(Store::open_in_memory().unwrap().path().is_none());
}

#[test]
fn campaign_round_trip_and_states() {
    let store = Store::open_in_memory().unwrap();
    let before = now_unix_s();
    let a = store
        .create_campaign(
            "xy sweep",
            "[grid]\nstep_um = 5.0\n",
            "/etc/csmetro/a.toml",
            "stage-1",
            420,
        )
        .unwrap();
    let b = store
        .create_campaign("second", "", "b.toml", "stage-2", 0)
        .unwrap();
    assert!(b > a);

    let row = store.campaign(a).unwrap().unwrap();
    assert_eq!(row.id, a);
    assert_eq!(row.name, "xy sweep");
    assert_eq!(row.spec_toml, "[grid]\nstep_um = 5.0\n");
    assert_eq!(row.spec_path, "/etc/csmetro/a.toml");
    assert_eq!(row.stage, "stage-1");
    assert_eq!(row.state, CampaignState::Queued);
    assert_eq!(row.planned, 420);
    assert_eq!(row.message, None);
    assert!(row.created_unix_s >= before && row.created_unix_s <= now_unix_s());
    assert_eq!(row.updated_unix_s, row.created_unix_s);

    let ids: Vec<i64> = store.campaigns().unwrap().iter().map(|c| c.id).collect();
    assert_eq!(ids, vec![b, a], "newest first");
    assert!(store.campaign(b + 100).unwrap().is_none());

    for state in [
        CampaignState::Running,
        CampaignState::Paused,
        CampaignState::Interrupted,
        CampaignState::Failed,
        CampaignState::Aborted,
        CampaignState::Done,
        CampaignState::Queued,
    ] {
        let msg = format!("now {}", state.as_str());
        store.set_state(a, state, Some(&msg)).unwrap();
        let row = store.campaign(a).unwrap().unwrap();
        assert_eq!(row.state, state);
        assert_eq!(row.message.as_deref(), Some(msg.as_str()));
        assert!(row.updated_unix_s >= row.created_unix_s);
    }
    store.set_state(a, CampaignState::Done, None).unwrap();
    assert_eq!(store.campaign(a).unwrap().unwrap().message, None);
    // The other campaign is untouched.
    assert_eq!(
        store.campaign(b).unwrap().unwrap().state,
        CampaignState::Queued
    );

    // A conditional change leaves a campaign that has moved on as it is.
    assert!(!store
        .set_state_from(a, CampaignState::Running, CampaignState::Paused, Some("p"))
        .unwrap());
    assert_eq!(
        store.campaign(a).unwrap().unwrap().state,
        CampaignState::Done
    );
    store.set_state(a, CampaignState::Running, None).unwrap();
    assert!(store
        .set_state_from(a, CampaignState::Running, CampaignState::Paused, Some("p"))
        .unwrap());
    assert_eq!(
        store.campaign(a).unwrap().unwrap().state,
        CampaignState::Paused
    );
    assert!(matches!(
        store
            .set_state_from(999, CampaignState::Running, CampaignState::Paused, None)
            .unwrap_err(),
        StoreError::UnknownCampaign { .. }
    ));
    store.set_state(a, CampaignState::Done, None).unwrap();

    store.set_planned(a, 1234).unwrap();
    assert_eq!(store.campaign(a).unwrap().unwrap().planned, 1234);

    let e = store
        .set_state(999, CampaignState::Running, None)
        .unwrap_err();
    assert!(
        matches!(e, StoreError::UnknownCampaign { id: 999, .. }),
        "{e}"
    );
    assert!(e.to_string().contains(":memory:"), "{e}");
    assert!(matches!(
        store.set_planned(999, 1).unwrap_err(),
        StoreError::UnknownCampaign { .. }
    ));
    assert!(matches!(
        store
            .create_campaign("big", "", "", "s", u64::MAX)
            .unwrap_err(),
        StoreError::OutOfRange { .. }
    ));
    // Serializes for the API with lowercase states.
    let json = serde_json::to_value(store.campaign(a).unwrap().unwrap()).unwrap();
    assert_eq!(json["state"], "done");
}

#[test]
fn unfinished_returns_exactly_the_non_final_campaigns() {
    let store = Store::open_in_memory().unwrap();
    let states = [
        CampaignState::Done,
        CampaignState::Queued,
        CampaignState::Aborted,
        CampaignState::Running,
        CampaignState::Failed,
        CampaignState::Paused,
        CampaignState::Interrupted,
        CampaignState::Done,
        CampaignState::Queued,
    ];
    let mut want = Vec::new();
    for (i, &state) in states.iter().enumerate() {
        let id = new_campaign(&store, &format!("stage-{i}"));
        store.set_state(id, state, None).unwrap();
        if !state.is_final() {
            want.push(id);
        }
    }
    let got: Vec<i64> = store.unfinished().unwrap().iter().map(|c| c.id).collect();
    assert_eq!(got, want, "non-final campaigns, oldest first");
    assert_eq!(want.len(), 5);
    assert!(store
        .unfinished()
        .unwrap()
        .iter()
        .all(|c| !c.state.is_final()));
}

#[test]
fn samples_round_trip_bit_exact() {
    let store = Store::open_in_memory().unwrap();
    let c = new_campaign(&store, "s");
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(230);
    let awkward = [
        -0.0,
        0.0,
        f64::NAN,
        f64::from_bits(0xfff8_0000_dead_beef), // negative NaN with a payload
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::MIN_POSITIVE,
        5e-324, // smallest subnormal
        -f64::MAX,
        f64::MAX,
        0.1 + 0.2,
        1.0e-17,
        9_007_199_254_740_993.0, // 2^53 + 1 rounds: an integral REAL
        -3.0,
    ];
    let mut want = Vec::new();
    for seq in 0..200u64 {
        let s = match seq {
            // All awkward values in every column, rotated.
            0..=13 => with_reals(sample(seq), |i| awkward[(i + seq as usize) % awkward.len()]),
            // Random bit patterns: every double, NaNs included.
            14..=99 => with_reals(sample(seq), |_| f64::from_bits(rng.random::<u64>())),
            _ => sample(seq),
        };
        want.push(s);
    }
    let mut extreme = sample(200);
    extreme.target.run.cycle = u32::MAX;
    extreme.frames = u32::MAX;
    extreme.rejected = u32::MAX;
    extreme.target.grid_index = i64::MAX as usize;
    want.push(extreme);
    let mut big_seq = sample(i64::MAX as u64);
    big_seq.target.seq = i64::MAX as u64;
    want.push(big_seq);

    // Inserted out of order, read back ordered by seq.
    let mut order: Vec<usize> = (0..want.len()).collect();
    order.reverse();
    order.swap(3, 50);
    for &i in &order {
        assert!(store.insert_sample(c, &want[i]).unwrap());
    }
    assert_bit_exact(&store.samples(c).unwrap(), &want);
    assert_eq!(store.sample_count(c).unwrap(), want.len() as u64);
    let seqs: BTreeSet<u64> = want.iter().map(|s| s.target.seq).collect();
    assert_eq!(store.done_seqs(c).unwrap(), seqs);

    // A seq past i64 cannot be stored and says so.
    let mut too_big = sample(0);
    too_big.target.seq = u64::MAX;
    assert!(matches!(
        store.insert_sample(c, &too_big).unwrap_err(),
        StoreError::OutOfRange { .. }
    ));

    // What the lab sees in the sqlite3 shell: lowercase names and plain REALs.
    let (phase, axis, dir, ty, x, raw): (String, String, String, String, f64, Option<String>) =
        store
            .conn
            .query_row(
                "SELECT phase, axis, direction, typeof(meas_x_um), meas_x_um, raw_bits \
                 FROM samples WHERE campaign_id = ?1 AND seq = 102",
                [c],
                |r| {
                    Ok((
                        r.get(0)?,
                        r.get(1)?,
                        r.get(2)?,
                        r.get(3)?,
                        r.get(4)?,
                        r.get(5)?,
                    ))
                },
            )
            .unwrap();
    assert_eq!(
        (phase.as_str(), axis.as_str(), dir.as_str()),
        ("full", "x", "backward")
    );
    assert_eq!(ty, "real");
    assert_eq!(x.to_bits(), want[102].meas_x_um.to_bits());
    assert_eq!(raw, None, "plain values need no raw bits");
    // NaN is NULL and -0.0 reads 0.0 in SQL; the exact bits are in raw_bits.
    let (t0, raw0): (Option<f64>, Option<String>) = store
        .conn
        .query_row(
            "SELECT target_x_um, raw_bits FROM samples WHERE campaign_id = ?1 AND seq = 0",
            [c],
            |r| Ok((r.get(0)?, r.get(1)?)),
        )
        .unwrap();
    assert_eq!(t0, Some(0.0));
    assert!(raw0.unwrap().starts_with("target_x_um:8000000000000000,"));
}

#[test]
fn duplicate_seq_is_refused() {
    let store = Store::open_in_memory().unwrap();
    let c = new_campaign(&store, "s");
    let other = new_campaign(&store, "t");
    for seq in 0..10 {
        assert!(store.insert_sample(c, &sample(seq)).unwrap());
    }
    let mut again = sample(4);
    again.meas_x_um = 12345.0;
    again.frames = 99;
    assert!(!store.insert_sample(c, &again).unwrap());
    assert!(!store.insert_sample(c, &sample(9)).unwrap());
    assert_eq!(store.sample_count(c).unwrap(), 10);
    // The first sample stays as it was.
    let stored = store.samples(c).unwrap();
    assert_bit_exact(&stored[4..5], &[sample(4)]);
    // The same seq in another campaign is another target.
    assert!(store.insert_sample(other, &again).unwrap());
    assert_eq!(store.sample_count(other).unwrap(), 1);
    assert_eq!(store.sample_count(c).unwrap(), 10);
}

#[test]
fn writes_for_an_unknown_campaign_are_refused() {
    let store = Store::open_in_memory().unwrap();
    let c = new_campaign(&store, "s");
    let e = store.insert_sample(c + 1, &sample(0)).unwrap_err();
    assert!(matches!(e, StoreError::UnknownCampaign { .. }), "{e}");
    assert!(matches!(
        store
            .add_event(c + 1, "x", &serde_json::json!(null))
            .unwrap_err(),
        StoreError::UnknownCampaign { .. }
    ));
    assert!(matches!(
        store.put_result(c + 1, "a", "text/csv", b"").unwrap_err(),
        StoreError::UnknownCampaign { .. }
    ));
    assert_eq!(store.sample_count(c + 1).unwrap(), 0);
}

#[test]
fn events_are_ordered_and_filtered() {
    let store = Store::open_in_memory().unwrap();
    let a = new_campaign(&store, "s");
    let b = new_campaign(&store, "t");
    let mut ids_a = Vec::new();
    let mut last = 0;
    for i in 0..20 {
        let (c, kind) = if i % 3 == 0 {
            (b, "log")
        } else {
            (a, "sample")
        };
        let data = serde_json::json!({ "i": i, "msg": format!("event {i}"), "x": [1.5, -0.25] });
        let id = store.add_event(c, kind, &data).unwrap();
        assert!(id > last, "ids grow");
        last = id;
        if c == a {
            ids_a.push((id, data));
        }
    }
    let all = store.events_after(a, 0).unwrap();
    assert_eq!(all.len(), ids_a.len());
    for (ev, (id, data)) in all.iter().zip(&ids_a) {
        assert_eq!(ev.id, *id);
        assert_eq!(ev.campaign, a);
        assert_eq!(ev.kind, "sample");
        assert_eq!(&ev.data, data);
        assert!(ev.unix_s > 1.6e9);
    }
    let cut = ids_a[5].0;
    let tail: Vec<i64> = store
        .events_after(a, cut)
        .unwrap()
        .iter()
        .map(|e| e.id)
        .collect();
    let want: Vec<i64> = ids_a[6..].iter().map(|(id, _)| *id).collect();
    assert_eq!(tail, want);
    assert!(store.events_after(a, last).unwrap().is_empty());
    assert_eq!(store.events_after(b, 0).unwrap().len(), 7);
}

#[test]
fn results_are_replaced() {
    let store = Store::open_in_memory().unwrap();
    let a = new_campaign(&store, "s");
    let b = new_campaign(&store, "t");
    let png: Vec<u8> = (0..=255u8).cycle().take(70_000).collect();
    store
        .put_result(a, "summary.json", "application/json", b"{\"v\":1}")
        .unwrap();
    store.put_result(a, "ef_xx.png", "image/png", &png).unwrap();
    store
        .put_result(b, "summary.json", "application/json", b"{\"v\":\"b\"}")
        .unwrap();
    assert_eq!(
        store.result(a, "ef_xx.png").unwrap(),
        Some(("image/png".to_string(), png.clone()))
    );
    store
        .put_result(a, "summary.json", "text/plain", b"replaced")
        .unwrap();
    assert_eq!(
        store.result(a, "summary.json").unwrap(),
        Some(("text/plain".to_string(), b"replaced".to_vec()))
    );
    assert_eq!(
        store.result(b, "summary.json").unwrap().unwrap().1,
        b"{\"v\":\"b\"}".to_vec()
    );
    assert_eq!(store.result(a, "missing.csv").unwrap(), None);
    assert_eq!(
        store.result_names(a).unwrap(),
        vec!["ef_xx.png".to_string(), "summary.json".to_string()]
    );
    store.put_result(a, "empty.csv", "text/csv", b"").unwrap();
    assert_eq!(
        store.result(a, "empty.csv").unwrap(),
        Some(("text/csv".to_string(), Vec::new()))
    );
    assert_eq!(store.result_names(a).unwrap().len(), 3);
}

#[test]
fn a_stage_runs_one_campaign_at_a_time() {
    let store = Store::open_in_memory().unwrap();
    let a = new_campaign(&store, "stage-1");
    let b = new_campaign(&store, "stage-1");
    let c = new_campaign(&store, "stage-2");
    store.set_state(a, CampaignState::Running, None).unwrap();
    store
        .set_state(a, CampaignState::Running, Some("again"))
        .unwrap();
    store.set_state(c, CampaignState::Running, None).unwrap();
    let e = store
        .set_state(b, CampaignState::Running, None)
        .unwrap_err();
    match &e {
        StoreError::StageBusy { stage, running, .. } => {
            assert_eq!(stage, "stage-1");
            assert_eq!(*running, a);
        }
        other => panic!("{other}"),
    }
    assert_eq!(
        store.campaign(b).unwrap().unwrap().state,
        CampaignState::Queued
    );
    store.set_state(a, CampaignState::Paused, None).unwrap();
    store.set_state(b, CampaignState::Running, None).unwrap();
}

#[test]
fn newer_schema_and_foreign_files_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("future.db");
    drop(Store::open(&path).unwrap());
    Connection::open(&path)
        .unwrap()
        .pragma_update(None, "user_version", SCHEMA_VERSION + 1)
        .unwrap();
    let e = Store::open(&path).unwrap_err();
    assert!(matches!(e, StoreError::SchemaTooNew { .. }), "{e}");
    assert!(e.to_string().contains(&path.display().to_string()), "{e}");

    let other = dir.path().join("other.db");
    Connection::open(&other)
        .unwrap()
        .execute_batch("CREATE TABLE notes (t TEXT)")
        .unwrap();
    let e = Store::open(&other).unwrap_err();
    assert!(matches!(e, StoreError::NotAStore { .. }), "{e}");
}

#[test]
fn open_errors_name_the_path() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("plain-file");
    std::fs::write(&file, b"x").unwrap();
    let path = file.join("sub/csmetro.db");
    let e = Store::open(&path).unwrap_err();
    assert!(matches!(e, StoreError::CreateDir { .. }), "{e}");
    assert!(e.to_string().contains(&path.display().to_string()), "{e}");

    let garbage = dir.path().join("garbage.db");
    std::fs::write(&garbage, vec![0x5a; 8192]).unwrap();
    let e = Store::open(&garbage).unwrap_err();
    assert!(e.to_string().contains("garbage.db"), "{e}");
}

#[test]
fn committed_samples_survive_drop_and_reopen() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("csmetro.db");
    let (c, want) = {
        let store = Store::open(&path).unwrap();
        let c = new_campaign(&store, "s");
        let want: Vec<SampleRecord> = (0..300).map(sample).collect();
        for s in &want {
            assert!(store.insert_sample(c, s).unwrap());
        }
        store.add_event(c, "done", &serde_json::json!(1)).unwrap();
        // A second connection sees every commit while the first is open (from the WAL).
        let reader = Store::open(&path).unwrap();
        assert_eq!(reader.sample_count(c).unwrap(), 300);
        (c, want)
        // Both dropped here: no explicit close or checkpoint.
    };
    let store = Store::open(&path).unwrap();
    assert_bit_exact(&store.samples(c).unwrap(), &want);
    assert_eq!(store.events_after(c, 0).unwrap().len(), 1);
    assert_eq!(store.unfinished().unwrap()[0].id, c);
}

const CHILD_DB: &str = "CSMETRO_STORE_TEST_CHILD_DB";
const CHILD_CAMPAIGN: &str = "CSMETRO_STORE_TEST_CHILD_CAMPAIGN";

/// Not a test on its own: the child process of
/// `insert_survives_sigkill_mid_write`, which inserts samples until it is killed.
#[test]
#[ignore = "child process of insert_survives_sigkill_mid_write; does nothing without its env"]
fn child_inserts_until_killed() {
    let (Ok(db), Ok(campaign)) = (std::env::var(CHILD_DB), std::env::var(CHILD_CAMPAIGN)) else {
        return;
    };
    let campaign: i64 = campaign.parse().unwrap();
    let store = Store::open(Path::new(&db)).unwrap();
    let start = store.sample_count(campaign).unwrap();
    // A safety net should the parent die without killing us.
    let deadline = Instant::now() + Duration::from_secs(120);
    let mut seq = start;
    while Instant::now() < deadline {
        assert!(store.insert_sample(campaign, &sample(seq)).unwrap());
        if seq.is_multiple_of(16) {
            store
                .add_event(campaign, "progress", &serde_json::json!({ "seq": seq }))
                .unwrap();
        }
        seq += 1;
    }
    panic!("child writer was not killed within 120 s");
}

/// Kills the child (SIGKILL) if the test fails before it does.
struct KillOnDrop(Child);

impl Drop for KillOnDrop {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

#[test]
fn insert_survives_sigkill_mid_write() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("killed.db");
    let store = Store::open(&path).unwrap();
    let c = new_campaign(&store, "s");
    store.set_state(c, CampaignState::Running, None).unwrap();

    let exe = std::env::current_exe().unwrap();
    let mut child = KillOnDrop(
        Command::new(exe)
            .args([
                "--exact",
                "store::tests::child_inserts_until_killed",
                "--ignored",
                "--test-threads=1",
                "--nocapture",
            ])
            .env(CHILD_DB, &path)
            .env(CHILD_CAMPAIGN, c.to_string())
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap(),
    );
    let t0 = Instant::now();
    loop {
        if let Some(status) = child.0.try_wait().unwrap() {
            let mut err = String::new();
            use std::io::Read;
            child
                .0
                .stderr
                .take()
                .unwrap()
                .read_to_string(&mut err)
                .unwrap();
            panic!("child exited early ({status}): {err}");
        }
        if store.sample_count(c).unwrap() >= 50 {
            break;
        }
        assert!(
            t0.elapsed() < Duration::from_secs(60),
            "child stored no 50 samples in 60 s"
        );
        std::thread::sleep(Duration::from_millis(2));
    }
    // Close our connection first, so nobody checkpoints or removes the WAL: the reopen below
    // has to recover from what the killed writer left.
    drop(store);
    std::thread::sleep(Duration::from_millis(20));
    child.0.kill().unwrap(); // SIGKILL
    let status = child.0.wait().unwrap();
    assert!(!status.success(), "child was killed: {status}");
    let wal = dir.path().join("killed.db-wal");
    assert!(
        std::fs::metadata(&wal)
            .map(|m| m.len() > 0)
            .unwrap_or(false),
        "the killed writer left its WAL behind"
    );

    let store = Store::open(&path).unwrap();
    let got = store.samples(c).unwrap();
    let k = got.len() as u64;
    assert!(k >= 50, "{k} samples");
    let want: Vec<SampleRecord> = (0..k).map(sample).collect();
    assert_bit_exact(&got, &want); // contiguous 0..k, every one readable and exact
    assert_eq!(
        store.done_seqs(c).unwrap(),
        (0..k).collect::<BTreeSet<u64>>()
    );
    let events = store.events_after(c, 0).unwrap();
    assert!(events.windows(2).all(|w| w[0].id < w[1].id));
    assert_eq!(
        store.campaign(c).unwrap().unwrap().state,
        CampaignState::Running,
        "the service finds it unfinished and resumes it"
    );
    // Resuming continues at k, never stores a target twice.
    assert!(!store.insert_sample(c, &sample(k - 1)).unwrap());
    assert!(store.insert_sample(c, &sample(k)).unwrap());
    assert!(!store.insert_sample(c, &sample(k)).unwrap());
    assert_eq!(store.sample_count(c).unwrap(), k + 1);
    let integrity: String = store
        .conn
        .query_row("PRAGMA integrity_check", [], |r| r.get(0))
        .unwrap();
    assert_eq!(integrity, "ok");
    eprintln!(
        "child stored {k} samples in {:.0} ms before SIGKILL",
        t0.elapsed().as_secs_f64() * 1e3
    );
}

/// `cargo test -p csmetro --lib store::tests::insert_rate -- --ignored --nocapture`
#[test]
#[ignore = "timing, not a check: prints inserts per second"]
fn insert_rate() {
    let dir = tempfile::tempdir().unwrap();
    let store = Store::open(&dir.path().join("rate.db")).unwrap();
    let c = new_campaign(&store, "s");
    let n = 20_000u64;
    let t0 = Instant::now();
    for seq in 0..n {
        store.insert_sample(c, &sample(seq)).unwrap();
    }
    let dt = t0.elapsed().as_secs_f64();
    let t1 = Instant::now();
    let back = store.samples(c).unwrap();
    let dt_read = t1.elapsed().as_secs_f64();
    assert_eq!(back.len() as u64, n);
    println!(
        "store: {n} samples, one transaction each: {:.0} inserts/s ({:.1} us each); \
         read back all in {:.1} ms",
        n as f64 / dt,
        dt / n as f64 * 1e6,
        dt_read * 1e3
    );
}

#[test]
fn a_store_keeps_its_identity_and_another_store_has_another() {
    let dir = tempfile::tempdir().unwrap();
    let a = dir.path().join("a.db");
    let id = Store::open(&a).unwrap().store_id().unwrap();
    assert_eq!(id.len(), 16, "{id}");
    assert!(id.chars().all(|c| c.is_ascii_hexdigit()), "{id}");
    assert_eq!(Store::open(&a).unwrap().store_id().unwrap(), id, "reopened");
    let other = Store::open(&dir.path().join("b.db")).unwrap();
    assert_ne!(other.store_id().unwrap(), id);
}

#[test]
fn a_schema_1_store_is_migrated_and_gets_an_identity() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("v1.db");
    {
        let conn = Connection::open(&path).unwrap();
        conn.execute_batch(MIGRATIONS[0]).unwrap();
        conn.pragma_update(None, "application_id", APPLICATION_ID)
            .unwrap();
        conn.pragma_update(None, "user_version", 1).unwrap();
        conn.execute(
            "INSERT INTO campaigns (name, spec_toml, spec_path, stage, state, planned, \
             created_unix_s, updated_unix_s) VALUES ('old', '', 'a.toml', 's', 'done', 0, 1.0, 1.0)",
            [],
        )
        .unwrap();
    }
    let store = Store::open(&path).unwrap();
    assert_eq!(store.store_id().unwrap().len(), 16);
    assert_eq!(store.campaign(1).unwrap().unwrap().name, "old");
}

#[test]
fn a_schema_2_store_keeps_its_samples_and_takes_map_samples() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("v2.db");
    let id;
    {
        let store = Store::open(&path).unwrap();
        id = new_campaign(&store, "s");
        assert!(store.insert_sample(id, &sample(0)).unwrap());
    }
    {
        // Back to schema 2 as an older csmetro wrote it: the samples table without 'map'.
        let conn = Connection::open(&path).unwrap();
        conn.execute_batch(
            "CREATE TABLE s2 AS SELECT * FROM samples; DROP TABLE samples; \
             ALTER TABLE s2 DROP COLUMN frame_sd_x_um; ALTER TABLE s2 DROP COLUMN frame_sd_y_um; \
             DROP TABLE stage_events; ALTER TABLE campaigns DROP COLUMN model_toml;",
        )
        .unwrap();
        let create = MIGRATIONS[0]
            .split("CREATE TABLE samples (")
            .nth(1)
            .and_then(|t| t.split(");").next())
            .unwrap();
        conn.execute_batch(&format!(
            "CREATE TABLE samples ({create}); INSERT INTO samples SELECT * FROM s2; DROP TABLE s2;"
        ))
        .unwrap();
        conn.pragma_update(None, "user_version", 2).unwrap();
    }
    let store = Store::open(&path).unwrap();
    assert_eq!(store.samples(id).unwrap(), vec![sample(0)]);
    let mut m = sample(1);
    m.target.run.phase = Phase::Map;
    assert!(store.insert_sample(id, &m).unwrap());
    assert_eq!(store.samples(id).unwrap()[1].target.run.phase, Phase::Map);
}

#[test]
fn updated_unix_s_moves_with_every_committed_sample() {
    let store = Store::open_in_memory().unwrap();
    let id = new_campaign(&store, "s");
    let mut last = store.campaign(id).unwrap().unwrap().updated_unix_s;
    for seq in 0..3 {
        std::thread::sleep(std::time::Duration::from_millis(20));
        assert!(store.insert_sample(id, &sample(seq)).unwrap());
        let now = store.campaign(id).unwrap().unwrap().updated_unix_s;
        assert!(
            now > last,
            "sample {seq}: updated_unix_s {now} did not move from {last}"
        );
        assert!((now - now_unix_s()).abs() < 5.0, "{now} is wall-clock time");
        last = now;
    }
    // A duplicate is not a new sample: nothing moves.
    std::thread::sleep(std::time::Duration::from_millis(20));
    assert!(!store.insert_sample(id, &sample(0)).unwrap());
    assert_eq!(store.campaign(id).unwrap().unwrap().updated_unix_s, last);
}

#[test]
fn stage_events_are_logged_per_stage_in_order() {
    let store = Store::open_in_memory().unwrap();
    let a = store
        .add_stage_event(
            "sim-xy",
            "move_requested",
            &serde_json::json!({"x_um": 1.0}),
        )
        .unwrap();
    store
        .add_stage_event("other", "move_requested", &serde_json::json!({}))
        .unwrap();
    let b = store
        .add_stage_event("sim-xy", "moved", &serde_json::json!({"x_um": 1.0}))
        .unwrap();
    let all = store.stage_events_after("sim-xy", 0, 10).unwrap();
    assert_eq!(all.iter().map(|e| e.id).collect::<Vec<_>>(), [a, b]);
    assert_eq!(all[1].kind, "moved");
    assert_eq!(store.stage_events_after("sim-xy", a, 10).unwrap().len(), 1);
    assert_eq!(store.stage_events_after("sim-xy", 0, 1).unwrap().len(), 1);
}

/// Two processes (here threads, each its own connection) opening the same new store at once
/// both get it: entering WAL mode answers busy without SQLite's busy handler, and is retried.
#[test]
fn two_openers_of_a_new_store_at_once_both_succeed() {
    let dir = tempfile::tempdir().unwrap();
    for k in 0..40 {
        let path = dir.path().join(format!("s{k}.db"));
        let gate = std::sync::Arc::new(std::sync::Barrier::new(2));
        let open = |path: std::path::PathBuf, gate: std::sync::Arc<std::sync::Barrier>| {
            std::thread::spawn(move || {
                gate.wait();
                Store::open(&path).map(|_| ())
            })
        };
        let a = open(path.clone(), gate.clone());
        let b = open(path, gate);
        a.join().unwrap().unwrap();
        b.join().unwrap().unwrap();
    }
}
