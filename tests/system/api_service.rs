//! `csmetro serve` end to end on simulated stages: submit over HTTP, follow the events, results,
//! validation errors, one campaign per stage (the others queue), pause/resume, abort (motion
//! stops), authentication, and recovery after `kill -9` and after SIGTERM.
use crate::common;

use std::collections::BTreeSet;
use std::time::Duration;

use common::{bin, campaign, sse, stored_seqs, write_config, Server};
use serde_json::Value;

/// 40 targets, about 2 s in a debug build.
fn quick(name: &str, stage: &str) -> String {
    campaign(name, stage, 20, 1000.0)
}

/// 80 targets at a tenth of real time: several seconds, long enough to act on it mid-run.
fn slow(name: &str, stage: &str) -> String {
    campaign(name, stage, 40, 10.0)
}

fn state(v: &Value) -> &str {
    v["state"].as_str().unwrap_or("")
}

#[test]
fn submitted_campaign_runs_streams_its_events_and_serves_its_results() {
    let dir = tempfile::tempdir().unwrap();
    let srv = Server::start(dir.path(), None);
    let (s, h) = srv.get("/health");
    assert_eq!((s, h["status"].as_str()), (200, Some("ok")), "{h}");

    let id = srv.submit(&quick("quick", "s1"));
    let events = srv.events(id, 0);
    let kinds: Vec<&str> = events.iter().map(|e| e.0.as_str()).collect();
    assert_eq!(kinds.first(), Some(&"queued"), "{kinds:?}");
    assert!(kinds.contains(&"started"), "{kinds:?}");
    assert_eq!(kinds.last(), Some(&"finished"), "{kinds:?}");
    assert_eq!(events.last().unwrap().2["data"]["state"], "done");
    // Logged events carry increasing ids; every one belongs to this campaign.
    let ids: Vec<i64> = events.iter().filter_map(|e| e.1).collect();
    assert!(ids.windows(2).all(|w| w[0] < w[1]), "{ids:?}");
    assert!(events.iter().all(|e| e.2["campaign"] == id));

    let st = srv.status(id);
    assert_eq!(state(&st), "done", "{st}");
    assert_eq!(st["planned"], 40);
    assert_eq!(st["stored"], 40);
    assert_eq!(st["percent"], 100.0);
    assert_eq!(st["name"], "quick");
    assert_eq!(st["stage"], "s1");

    // A finished campaign's stream is its log, then the end; `after` skips what was seen.
    let again = srv.events(id, 0);
    assert_eq!(again.len(), events.iter().filter(|e| e.1.is_some()).count());
    let tail = srv.events(id, ids[ids.len() - 2]);
    assert_eq!(tail.len(), 1);
    assert_eq!(tail[0].0, "finished");

    let (s, list) = srv.get("/campaigns");
    assert_eq!(s, 200);
    assert_eq!(list.as_array().unwrap().len(), 1);
    assert_eq!(list[0]["id"], id);

    let (s, r) = srv.get(&format!("/campaigns/{id}/results"));
    assert_eq!(s, 200, "{r}");
    let names: Vec<String> = r["results"]
        .as_array()
        .unwrap()
        .iter()
        .map(|n| n.as_str().unwrap().to_string())
        .collect();
    // Curves (CSV) and the summary (JSON) always; plots (SVG/PNG) when the session makes them.
    assert!(
        names
            .iter()
            .any(|n| n.starts_with("curves/") && n.ends_with(".csv")),
        "{names:?}"
    );
    assert!(names.iter().any(|n| n == "summary.json"), "{names:?}");
    for name in &names {
        let (s, bytes, ctype) = srv.request(
            "GET",
            &format!("/campaigns/{id}/results/{name}"),
            None,
            None,
        );
        assert_eq!(s, 200, "{name}");
        assert!(!bytes.is_empty(), "{name}");
        let want = match name.rsplit('.').next().unwrap() {
            "svg" => "image/svg+xml",
            "png" => "image/png",
            "csv" => "text/csv",
            "json" => "application/json",
            "txt" => "text/plain",
            _ => continue,
        };
        assert!(ctype.starts_with(want), "{name}: {ctype}");
        if want == "image/png" {
            assert_eq!(&bytes[..4], b"\x89PNG");
        }
        if want == "application/json" {
            serde_json::from_slice::<Value>(&bytes).unwrap();
        }
    }
    let (s, e) = srv.get(&format!("/campaigns/{id}/results/nope.csv"));
    assert_eq!(s, 404, "{e}");

    // Every committed sample, in pages, each once: what a client that missed live `sample`
    // events reads back.
    let (mut after, mut seqs) = (0i64, Vec::new());
    loop {
        let (s, page) = srv.get(&format!("/campaigns/{id}/samples?after={after}&limit=15"));
        assert_eq!(s, 200, "{page}");
        let items = page["samples"].as_array().unwrap();
        if items.is_empty() {
            assert_eq!(page["next"], after);
            break;
        }
        assert!(items.len() <= 15);
        for it in items {
            assert!(it["n"].as_i64().unwrap() > after);
            seqs.push(it["sample"]["target"]["seq"].as_u64().unwrap());
        }
        after = page["next"].as_i64().unwrap();
    }
    assert_eq!(seqs.len(), 40);
    let distinct: BTreeSet<u64> = seqs.iter().copied().collect();
    assert_eq!(distinct.len(), 40);
    assert_eq!(
        distinct,
        stored_seqs(&srv.db(), id)
            .into_iter()
            .collect::<BTreeSet<u64>>()
    );
    let (s, e) = srv.get(&format!("/campaigns/{id}/samples?limit=0"));
    assert_eq!(s, 400, "{e}");
    let (s, e) = srv.get("/campaigns/999/samples");
    assert_eq!(s, 404, "{e}");
    // Result files also land under the configured results_dir.
    assert!(dir.path().join(format!("var/results/quick-{id}")).is_dir());
}

#[test]
fn invalid_campaigns_are_refused_with_file_line_and_key() {
    let dir = tempfile::tempdir().unwrap();
    let srv = Server::start(dir.path(), None);
    let bad = quick("bad", "s1").replace("step_um = 25.0", "step_um = 25.0\nstpe = 3");
    let line = bad.lines().position(|l| l.contains("stpe")).unwrap() + 1;

    let (s, v) = srv.post("/campaigns", Some(("application/toml", &bad)));
    assert_eq!(s, 400, "{v}");
    let msg = v["error"].as_str().unwrap();
    assert!(
        msg.starts_with(&format!("submitted.toml:{line}: axes.x.stpe:")),
        "{msg}"
    );

    let body = serde_json::json!({"toml": bad, "name": "/some/where/mine.toml"}).to_string();
    let (s, v) = srv.post("/campaigns", Some(("application/json", &body)));
    assert_eq!(s, 400, "{v}");
    let msg = v["error"].as_str().unwrap();
    assert!(
        msg.starts_with(&format!("mine.toml:{line}: axes.x.stpe:")),
        "{msg}"
    );

    let (s, v) = srv.post("/campaigns", Some(("application/json", "{\"nope\": 1}")));
    assert_eq!(s, 400, "{v}");
    // Nothing was stored.
    assert_eq!(srv.get("/campaigns").1.as_array().unwrap().len(), 0);

    let (s, v) = srv.get("/campaigns/99");
    assert_eq!(s, 404, "{v}");
    assert!(v["error"].as_str().unwrap().contains("99"));
    assert_eq!(srv.post("/campaigns/99/abort", None).0, 404);
    assert_eq!(srv.get("/nowhere").0, 404);
}

#[test]
fn one_campaign_per_stage_the_next_queues_and_other_stages_run_alongside() {
    let dir = tempfile::tempdir().unwrap();
    let srv = Server::start(dir.path(), None);
    let a = srv.submit(&slow("first", "shared"));
    let b = srv.submit(&quick("second", "shared"));
    let c = srv.submit(&quick("elsewhere", "other"));
    srv.wait_for(a, 30.0, |s| state(s) == "running");
    let sb = srv.status(b);
    assert_eq!(state(&sb), "queued", "{sb}");
    assert_eq!(sb["queue_position"], 0);
    assert_eq!(sb["stored"], 0);
    // The other stage is not held up by the first one.
    srv.wait_for(c, 60.0, |s| state(s) == "done");
    let sa = srv.status(a);
    assert_eq!(state(&sa), "running", "{sa}");
    assert_eq!(state(&srv.status(b)), "queued");
    let (_, h) = srv.get("/health");
    assert!(h["running"].as_array().unwrap().contains(&a.into()), "{h}");
    assert!(h["queued"].as_array().unwrap().contains(&b.into()), "{h}");

    srv.wait_for(a, 120.0, |s| state(s) == "done");
    let sb = srv.wait_for(b, 60.0, |s| state(s) == "done");
    assert_eq!(sb["stored"], sb["planned"]);
    // b started only after a had finished.
    let ev_a = srv.events(a, 0);
    let ev_b = srv.events(b, 0);
    let a_end = ev_a.iter().find(|e| e.0 == "finished").unwrap().1.unwrap();
    let b_start = ev_b.iter().find(|e| e.0 == "started").unwrap().1.unwrap();
    assert!(
        b_start > a_end,
        "b started (event {b_start}) before a ended ({a_end})"
    );
}

#[test]
fn pause_holds_the_campaign_and_resume_finishes_it() {
    let dir = tempfile::tempdir().unwrap();
    let srv = Server::start(dir.path(), None);
    let id = srv.submit(&slow("paused", "s1"));
    srv.wait_for(id, 30.0, |s| s["stored"].as_u64() > Some(3));
    let (s, v) = srv.post(&format!("/campaigns/{id}/pause"), None);
    assert_eq!((s, state(&v)), (200, "paused"), "{v}");
    std::thread::sleep(Duration::from_millis(500));
    let n = srv.status(id)["stored"].as_u64().unwrap();
    std::thread::sleep(Duration::from_millis(1500));
    let st = srv.status(id);
    assert_eq!(state(&st), "paused", "{st}");
    assert_eq!(st["stored"].as_u64().unwrap(), n, "samples while paused");
    // Resuming a running campaign or pausing a paused one's neighbour state is a conflict.
    let (s, v) = srv.post(&format!("/campaigns/{id}/resume"), None);
    assert_eq!((s, state(&v)), (200, "running"), "{v}");
    let (s, v) = srv.post(&format!("/campaigns/{id}/resume"), None);
    assert_eq!(s, 409, "{v}");
    let st = srv.wait_for(id, 120.0, |s| state(s) == "done");
    assert_eq!(st["stored"], st["planned"]);
    let kinds: Vec<String> = srv.events(id, 0).into_iter().map(|e| e.0).collect();
    assert!(kinds.contains(&"paused".to_string()), "{kinds:?}");
    assert!(kinds.contains(&"resumed".to_string()), "{kinds:?}");
    let (s, _) = srv.post(&format!("/campaigns/{id}/pause"), None);
    assert_eq!(s, 409);
}

#[test]
fn abort_stops_a_running_campaign_and_ends_its_stream() {
    let dir = tempfile::tempdir().unwrap();
    let srv = Server::start(dir.path(), None);
    let id = srv.submit(&slow("aborted", "s1"));
    let queued = srv.submit(&quick("never", "s1"));
    srv.wait_for(id, 30.0, |s| s["stored"].as_u64() > Some(2));
    // Follow the live stream while aborting.
    let url = srv.url.clone();
    let watcher = std::thread::spawn(move || sse(&url, None, id, 0));
    std::thread::sleep(Duration::from_millis(300));
    let (s, v) = srv.post(&format!("/campaigns/{id}/abort"), None);
    assert_eq!(s, 200, "{v}");
    let st = srv.wait_for(id, 30.0, |s| state(s) == "aborted");
    let events = watcher.join().unwrap();
    let last = events.last().unwrap();
    assert_eq!(
        (last.0.as_str(), &last.2["data"]["state"]),
        ("finished", &Value::from("aborted"))
    );
    // Motion and measurement stopped: nothing is stored after the abort.
    let n = st["stored"].as_u64().unwrap();
    assert!(n < 80, "{st}");
    std::thread::sleep(Duration::from_millis(800));
    assert_eq!(srv.status(id)["stored"].as_u64().unwrap(), n);
    assert_eq!(stored_seqs(&srv.db(), id).len() as u64, n);
    // The stage is free again: the queued campaign runs; an aborted one cannot be resumed.
    srv.wait_for(queued, 60.0, |s| state(s) == "done");
    assert_eq!(srv.post(&format!("/campaigns/{id}/resume"), None).0, 409);
    assert_eq!(srv.post(&format!("/campaigns/{id}/abort"), None).0, 409);
}

#[test]
fn a_queued_campaign_aborts_at_once() {
    let dir = tempfile::tempdir().unwrap();
    let srv = Server::start(dir.path(), None);
    let a = srv.submit(&slow("holder", "s1"));
    let b = srv.submit(&quick("waiting", "s1"));
    let (s, v) = srv.post(&format!("/campaigns/{b}/abort"), None);
    assert_eq!((s, state(&v)), (200, "aborted"), "{v}");
    let ev = srv.events(b, 0);
    assert_eq!(ev.last().unwrap().0, "finished");
    assert_eq!(srv.status(b)["stored"], 0);
    srv.post(&format!("/campaigns/{a}/abort"), None);
    srv.wait_for(a, 30.0, |s| state(s) == "aborted");
}

#[test]
fn a_token_is_required_on_every_route_when_configured() {
    let dir = tempfile::tempdir().unwrap();
    let token = "s3cret-token-0123456789";
    let srv = Server::start(dir.path(), Some(token));
    let routes = [
        ("GET", "/health"),
        ("GET", "/campaigns"),
        ("POST", "/campaigns"),
        ("GET", "/campaigns/1"),
        ("GET", "/campaigns/1/events"),
        ("POST", "/campaigns/1/pause"),
        ("POST", "/campaigns/1/resume"),
        ("POST", "/campaigns/1/abort"),
        ("GET", "/campaigns/1/samples"),
        ("GET", "/campaigns/1/results"),
        ("GET", "/campaigns/1/results/summary.json"),
        ("GET", "/nowhere"),
    ];
    for (m, p) in routes {
        for wrong in [
            Some(""),
            Some("s3cret-token-012345678"),
            Some("s3cret-token-0123456789x"),
        ] {
            let (s, b, _) = srv.request(m, p, None, wrong);
            assert_eq!(
                s,
                401,
                "{m} {p} with {wrong:?}: {}",
                String::from_utf8_lossy(&b)
            );
        }
        // No header at all.
        let a: ureq::Agent = ureq::Agent::config_builder()
            .http_status_as_error(false)
            .build()
            .into();
        let url = format!("{}{p}", srv.url);
        let r = if m == "GET" {
            a.get(&url).call()
        } else {
            a.post(&url).send_empty()
        };
        assert_eq!(r.unwrap().status().as_u16(), 401, "{m} {p} without a token");
    }
    let (s, v) = srv.get("/health");
    assert_eq!(s, 200, "{v}");
    let id = srv.submit(&quick("authorized", "s1"));
    assert_eq!(srv.status(id)["id"], id);
    let ev = srv.events(id, 0);
    assert_eq!(ev.last().unwrap().0, "finished");
}

#[test]
fn non_loopback_bind_without_a_token_refuses_to_start() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = write_config(dir.path(), "0.0.0.0:0", None);
    let out = bin()
        .arg("serve")
        .arg("--config")
        .arg(&cfg)
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("csmetro.toml:2: server.bind:"), "{err}");
    assert!(err.contains("token"), "{err}");
    assert!(out.stdout.is_empty());
    assert!(
        !dir.path().join("var").exists(),
        "nothing created before refusing"
    );
}

#[test]
fn kill_9_mid_campaign_then_restart_resumes_it_with_nothing_lost_or_measured_twice() {
    let dir = tempfile::tempdir().unwrap();
    let mut srv = Server::start(dir.path(), None);
    let id = srv.submit(&slow("crash", "s1"));
    let queued = srv.submit(&quick("after-crash", "s1"));
    srv.wait_for(id, 30.0, |s| s["stored"].as_u64() > Some(10));
    srv.kill9();
    let before = stored_seqs(&srv.db(), id);
    assert!(!before.is_empty() && before.len() < 80, "{}", before.len());
    drop(srv);

    let srv = Server::start(dir.path(), None);
    let st = srv.wait_for(id, 120.0, |s| state(s) == "done");
    assert_eq!(st["planned"], 80);
    assert_eq!(st["stored"], 80, "{st}");
    let seqs = stored_seqs(&srv.db(), id);
    let unique: BTreeSet<u64> = seqs.iter().copied().collect();
    assert_eq!(unique.len(), seqs.len(), "a target stored twice");
    assert_eq!(unique, (0..80).collect::<BTreeSet<u64>>());
    // The samples committed before the crash are kept as they were.
    let s2 = csmetro::store::Store::open(&srv.db()).unwrap();
    let after: Vec<_> = s2.samples(id).unwrap();
    for seq in &before {
        assert!(after.iter().any(|r| r.target.seq == *seq));
    }
    let kinds: Vec<String> = srv.events(id, 0).into_iter().map(|e| e.0).collect();
    assert!(kinds.contains(&"requeued".to_string()), "{kinds:?}");
    assert!(
        kinds.contains(&"resumed_from_store".to_string()),
        "{kinds:?}"
    );
    // The campaign queued behind it survives the crash too.
    srv.wait_for(queued, 60.0, |s| state(s) == "done");
}

#[test]
fn sigterm_stops_motion_and_leaves_the_campaign_resumable() {
    let dir = tempfile::tempdir().unwrap();
    let mut srv = Server::start(dir.path(), None);
    let id = srv.submit(&slow("stopped", "s1"));
    srv.wait_for(id, 30.0, |s| s["stored"].as_u64() > Some(5));
    let code = srv.terminate();
    assert!(code.success(), "{code:?}\n{}", srv.log());
    let store = csmetro::store::Store::open(&srv.db()).unwrap();
    let row = store.campaign(id).unwrap().unwrap();
    assert_eq!(row.state.as_str(), "interrupted", "{:?}", row.message);
    let n = store.sample_count(id).unwrap();
    assert!(n < 80);
    drop(store);
    drop(srv);

    let srv = Server::start(dir.path(), None);
    let st = srv.wait_for(id, 120.0, |s| state(s) == "done");
    assert_eq!(st["stored"], 80, "{st}");
    let seqs = stored_seqs(&srv.db(), id);
    assert_eq!(seqs.iter().copied().collect::<BTreeSet<u64>>().len(), 80);
}

/// systemd's side of Type=notify: READY=1 once listening, WATCHDOG=1 at half of WATCHDOG_USEC,
/// STOPPING=1 on SIGTERM, on the datagram socket NOTIFY_SOCKET names.
#[test]
fn notifies_systemd_ready_watchdog_and_stopping() {
    use std::os::unix::net::UnixDatagram;
    let dir = tempfile::tempdir().unwrap();
    let cfg = write_config(dir.path(), "127.0.0.1:0", None);
    let sock_path = dir.path().join("notify.sock");
    let sock = UnixDatagram::bind(&sock_path).unwrap();
    sock.set_read_timeout(Some(Duration::from_secs(20)))
        .unwrap();
    // WATCHDOG_PID must be the service's own pid, as systemd sets it: exec keeps the shell's.
    let mut child = std::process::Command::new("sh")
        .arg("-c")
        .arg("WATCHDOG_PID=$$ exec \"$0\" serve --config \"$1\"")
        .arg(env!("CARGO_BIN_EXE_csmetro"))
        .arg(&cfg)
        .env("NOTIFY_SOCKET", &sock_path)
        .env("WATCHDOG_USEC", "300000")
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let mut buf = [0u8; 512];
    let mut recv = || {
        let n = sock.recv(&mut buf).expect("a notification");
        String::from_utf8_lossy(&buf[..n]).into_owned()
    };
    let first = recv();
    assert!(first.lines().any(|l| l == "READY=1"), "{first:?}");
    assert!(
        first.contains("STATUS=listening on 127.0.0.1:"),
        "{first:?}"
    );
    // Pings keep coming (their period is WATCHDOG_USEC / 2, not something a loaded host's
    // clock can check).
    for _ in 0..3 {
        assert_eq!(recv().trim(), "WATCHDOG=1");
    }
    std::process::Command::new("kill")
        .args(["-TERM", &child.id().to_string()])
        .status()
        .unwrap();
    let stopping = loop {
        let m = recv();
        if m.trim() != "WATCHDOG=1" {
            break m;
        }
    };
    assert_eq!(stopping.trim(), "STOPPING=1");
    assert!(child.wait().unwrap().success());
}

/// (status, content type, CSP header, body) of a GET without any token.
fn get_plain(url: &str) -> (u16, String, String, String) {
    let a: ureq::Agent = ureq::Agent::config_builder()
        .http_status_as_error(false)
        .build()
        .into();
    let mut r = a.get(url).call().unwrap();
    let h = |n: &str| {
        r.headers()
            .get(n)
            .and_then(|v| v.to_str().ok())
            .unwrap_or("")
            .to_string()
    };
    let (ctype, csp) = (h("content-type"), h("content-security-policy"));
    let status = r.status().as_u16();
    let body = r.body_mut().read_to_string().unwrap_or_default();
    (status, ctype, csp, body)
}

#[test]
fn the_page_and_its_assets_load_without_a_token_and_nothing_else_does() {
    let dir = tempfile::tempdir().unwrap();
    let srv = Server::start(dir.path(), Some("s3cret-token-0123456789"));
    let (s, ctype, csp, body) = get_plain(&format!("{}/", srv.url));
    assert_eq!(s, 200, "{body}");
    assert!(ctype.starts_with("text/html"), "{ctype}");
    assert!(body.contains("<title>csmetro</title>"), "{body}");
    // Scripts from this origin only: the page works offline and runs no injected code.
    assert!(csp.contains("script-src 'self'"), "{csp}");
    for (path, want) in [
        ("/ui/app.js", "text/javascript"),
        ("/ui/style.css", "text/css"),
    ] {
        assert!(body.contains(path), "the page loads {path}");
        let (s, ctype, _, text) = get_plain(&format!("{}{path}", srv.url));
        assert_eq!(s, 200, "{path}");
        assert!(ctype.starts_with(want), "{path}: {ctype}");
        assert!(!text.is_empty());
    }
    // The data stay behind the token, as do unknown assets.
    for path in ["/health", "/campaigns", "/ui/other.js", "/ui/"] {
        assert_eq!(
            get_plain(&format!("{}{path}", srv.url)).0,
            401,
            "{path} without a token"
        );
    }
    let (s, b, _) = srv.request("POST", "/", None, Some(""));
    assert_eq!(s, 401, "{}", String::from_utf8_lossy(&b));
}

#[test]
fn status_has_elapsed_time_and_an_eta_that_matches_the_time_left() {
    let dir = tempfile::tempdir().unwrap();
    let srv = Server::start(dir.path(), None);
    let id = srv.submit(&slow("eta", "s1"));
    let st = srv.wait_for(id, 60.0, |s| {
        state(s) == "running" && s["stored"].as_u64() >= Some(20) && s["eta_s"].is_f64()
    });
    let eta = st["eta_s"].as_f64().unwrap();
    let elapsed = st["elapsed_s"].as_f64().unwrap();
    assert!(eta > 0.0 && elapsed > 0.0, "{st}");
    // The CLI shows it: `status ID` on its line, `status` in a column.
    let cli = |args: &[&str]| {
        let o = bin()
            .args(args)
            .env("CSMETRO_SERVER", &srv.url)
            .env_remove("CSMETRO_TOKEN")
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        String::from_utf8(o.stdout).unwrap()
    };
    let line = cli(&["status", &id.to_string()]);
    assert!(
        line.contains(": running ") && line.contains(", ETA 0:"),
        "{line}"
    );
    let table = cli(&["status"]);
    assert!(table.lines().next().unwrap().contains("ETA"), "{table}");
    assert!(
        table
            .lines()
            .nth(1)
            .is_some_and(|l| l.contains("running") && l.contains(" 0:0")),
        "{table}"
    );
    // Paused: no ETA (the rate is unknown until it runs again); the elapsed time goes on.
    let (s, v) = srv.post(&format!("/campaigns/{id}/pause"), None);
    assert_eq!(s, 200, "{v}");
    let p = srv.status(id);
    assert!(p["eta_s"].is_null(), "{p}");
    assert!(p["elapsed_s"].as_f64().unwrap() >= elapsed, "{p}");
    // Resumed: an ETA again, from the rate with the pause left out (the arithmetic against a
    // fake clock is api::progress's unit tests: a loaded host's rate is no test of it).
    let (s, v) = srv.post(&format!("/campaigns/{id}/resume"), None);
    assert_eq!(s, 200, "{v}");
    let again = srv.wait_for(id, 60.0, |s| {
        state(s) == "running" && s["eta_s"].is_f64() || s["stored"] == s["planned"]
    });
    if again["stored"] != again["planned"] {
        assert!(again["eta_s"].as_f64().unwrap() >= 0.0, "{again}");
    }
    srv.wait_for(id, 120.0, |s| s["stored"] == s["planned"]);
    let done = srv.wait_for(id, 120.0, |s| state(s) == "done");
    assert!(
        done["eta_s"].is_null() && done["elapsed_s"].is_null(),
        "{done}"
    );
}

#[test]
fn watch_without_samples_prints_progress_lines_with_an_eta() {
    let dir = tempfile::tempdir().unwrap();
    let srv = Server::start(dir.path(), None);
    let id = srv.submit(&slow("watched", "s1"));
    let out = bin()
        .args(["watch", &id.to_string(), "--progress-s", "0.5"])
        .env("CSMETRO_SERVER", &srv.url)
        .env_remove("CSMETRO_TOKEN")
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{text}");
    let progress: Vec<&str> = text
        .lines()
        .filter(|l| l.starts_with("progress "))
        .collect();
    assert!(progress.len() >= 2, "{text}");
    assert!(
        progress
            .iter()
            .any(|l| l.contains("/80 samples") && l.contains(", ETA 0:")),
        "{text}"
    );
    assert!(!text.contains("sample seq"), "{text}");
    assert!(
        text.lines().last().unwrap().starts_with("finished "),
        "{text}"
    );
    let bad = bin()
        .args(["watch", &id.to_string(), "--progress-s", "0"])
        .env("CSMETRO_SERVER", &srv.url)
        .output()
        .unwrap();
    assert_eq!(bad.status.code(), Some(2));
}
