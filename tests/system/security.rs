//! The browser is a client too: requests another web page can make a lab user's browser send
//! to `csmetro serve` on 127.0.0.1 (cross-site request forgery, DNS rebinding) change nothing.
//!
//! Raw HTTP first (every header an attacker controls: Origin, Host, content types, fetch
//! metadata), then a real headless chromium loading an attacker's page from another local
//! origin that tries `fetch(..., {mode: 'no-cors'})`, a CORS submission and form POSTs. A
//! legitimate client's move is the control: it works and leaves its trace, so "nothing moved"
//! is something the test can see fail.
//!
//! The browser part skips with a message when chromium is missing, except with
//! `CSMETRO_REQUIRE_BROWSER=1` (CI).
use crate::common;

use std::io::{Read, Write};
use std::net::TcpStream;
use std::path::PathBuf;
use std::time::Duration;

use common::{campaign, Server};
use serde_json::Value;

/// One raw HTTP/1.1 request (headers as given, `Host` included only if given); returns the
/// status code and body.
fn raw(url: &str, method: &str, path: &str, headers: &[(&str, &str)], body: &str) -> (u16, String) {
    let addr = url.trim_start_matches("http://");
    let mut s = TcpStream::connect(addr).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(20))).unwrap();
    let mut req = format!("{method} {path} HTTP/1.1\r\nConnection: close\r\n");
    for (k, v) in headers {
        req.push_str(&format!("{k}: {v}\r\n"));
    }
    req.push_str(&format!("Content-Length: {}\r\n\r\n{body}", body.len()));
    s.write_all(req.as_bytes()).unwrap();
    let mut out = String::new();
    let _ = s.read_to_string(&mut out);
    let status = out
        .split_whitespace()
        .nth(1)
        .and_then(|c| c.parse().ok())
        .unwrap_or(0);
    let body = out
        .split_once("\r\n\r\n")
        .map_or("", |(_, b)| b)
        .to_string();
    (status, body)
}

/// (method, path, headers, body, the status it must get).
type Attempt<'a> = (&'a str, &'a str, Vec<(&'a str, &'a str)>, &'a str, u16);

/// The stage's log of moves.
fn stage_events(srv: &Server, stage: &str) -> Vec<Value> {
    let (s, v) = srv.get(&format!("/stages/{stage}/events"));
    assert_eq!(s, 200, "{v}");
    v["events"].as_array().cloned().unwrap_or_default()
}

fn campaign_count(srv: &Server) -> usize {
    let (s, v) = srv.get("/campaigns");
    assert_eq!(s, 200, "{v}");
    v.as_array().map_or(0, Vec::len)
}

/// A finished campaign on stage `a` (a move takes its hardware from it) and one running slowly
/// on stage `b` (pause and abort have something to act on).
fn setup(srv: &Server) -> (i64, i64) {
    let done = srv.submit(&campaign("ref", "sec-a", 4, 1000.0));
    srv.wait_for(done, 120.0, |s| s["state"] == "done");
    let running = srv.submit(&campaign("long", "sec-b", 40, 1.0));
    srv.wait_for(running, 60.0, |s| s["state"] == "running");
    (done, running)
}

/// What every attack must leave as it was.
fn assert_untouched(srv: &Server, campaigns: usize, running: i64) {
    assert_eq!(campaign_count(srv), campaigns, "a campaign was submitted");
    assert_eq!(srv.status(running)["state"], "running", "paused or aborted");
    assert!(stage_events(srv, "sec-a").is_empty(), "the stage moved");
}

#[test]
fn requests_from_other_origins_hosts_and_simple_content_types_change_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let srv = Server::start(dir.path(), None);
    let (done, running) = setup(&srv);
    let n = campaign_count(&srv);
    let host = srv.url.trim_start_matches("http://").to_string();
    let toml = campaign("evil", "sec-c", 4, 1000.0);
    let mv = r#"{"x_um": 500}"#;
    let evil = [("Host", host.as_str()), ("Origin", "http://evil.example")];
    let pause = format!("/campaigns/{running}/pause");
    let abort = format!("/campaigns/{running}/abort");
    let attempts: Vec<Attempt<'_>> = vec![
        // A foreign Origin, whatever the content type.
        (
            "POST",
            "/campaigns",
            [&evil[..], &[("Content-Type", "text/plain")]].concat(),
            &toml,
            403,
        ),
        (
            "POST",
            "/campaigns",
            [&evil[..], &[("Content-Type", "application/toml")]].concat(),
            &toml,
            403,
        ),
        (
            "POST",
            "/campaigns",
            [
                &evil[..],
                &[("Content-Type", "application/x-www-form-urlencoded")],
            ]
            .concat(),
            &toml,
            403,
        ),
        ("POST", "/campaigns", evil.to_vec(), &toml, 403),
        (
            "POST",
            "/stages/sec-a/move",
            [&evil[..], &[("Content-Type", "text/plain")]].concat(),
            mv,
            403,
        ),
        (
            "POST",
            "/stages/sec-a/move",
            [&evil[..], &[("Content-Type", "application/json")]].concat(),
            mv,
            403,
        ),
        ("POST", &pause, evil.to_vec(), "", 403),
        ("POST", &abort, evil.to_vec(), "", 403),
        (
            "POST",
            &abort,
            vec![("Host", &host), ("Origin", "null")],
            "",
            403,
        ),
        // No Origin but a simple content type (what a browser may send without asking).
        (
            "POST",
            "/campaigns",
            vec![("Host", &host), ("Content-Type", "text/plain")],
            &toml,
            415,
        ),
        (
            "POST",
            "/campaigns",
            vec![
                ("Host", &host),
                ("Content-Type", "multipart/form-data; boundary=x"),
            ],
            &toml,
            415,
        ),
        ("POST", "/campaigns", vec![("Host", &host)], &toml, 415),
        (
            "POST",
            "/stages/sec-a/move",
            vec![("Host", &host), ("Content-Type", "text/plain")],
            mv,
            415,
        ),
        ("POST", "/stages/sec-a/move", vec![("Host", &host)], mv, 415),
        (
            "POST",
            &pause,
            vec![
                ("Host", &host),
                ("Content-Type", "application/x-www-form-urlencoded"),
            ],
            "a=1",
            415,
        ),
        // The browser's own word that it is a cross-site or form request.
        (
            "POST",
            &abort,
            vec![("Host", &host), ("Sec-Fetch-Site", "cross-site")],
            "",
            403,
        ),
        (
            "POST",
            &abort,
            vec![("Host", &host), ("Sec-Fetch-Mode", "no-cors")],
            "",
            403,
        ),
        (
            "POST",
            "/stages/sec-a/move",
            vec![
                ("Host", &host),
                ("Sec-Fetch-Site", "same-site"),
                ("Content-Type", "application/json"),
            ],
            mv,
            403,
        ),
        // DNS rebinding: the right address under another name, reads included.
        (
            "POST",
            "/stages/sec-a/move",
            vec![
                ("Host", "evil.example:80"),
                ("Content-Type", "application/json"),
            ],
            mv,
            421,
        ),
        ("POST", &abort, vec![("Host", "evil.example")], "", 421),
        ("GET", "/campaigns", vec![("Host", "evil.example")], "", 421),
        (
            "GET",
            "/health",
            vec![("Host", &host), ("Origin", "http://evil.example")],
            "",
            403,
        ),
    ];
    for (method, path, headers, body, want) in &attempts {
        let (status, answer) = raw(&srv.url, method, path, headers, body);
        assert_eq!(status, *want, "{method} {path} {headers:?}: {answer}");
        assert!(!answer.contains("Access-Control-Allow"), "{answer}");
    }
    assert_untouched(&srv, n, running);

    // The answers carry no CORS and say nosniff; result files are sandboxed.
    let (s, _, _) = srv.request("GET", "/health", None, None);
    assert_eq!(s, 200);
    let r = ureq::get(&format!(
        "{}/campaigns/{done}/results/summary.json",
        srv.url
    ))
    .call()
    .unwrap();
    let h = r.headers();
    assert_eq!(h.get("x-content-type-options").unwrap(), "nosniff");
    assert!(h
        .get("content-security-policy")
        .unwrap()
        .to_str()
        .unwrap()
        .starts_with("sandbox"));
    assert!(h.get("access-control-allow-origin").is_none());

    // The control: the same move from a legitimate client works and is logged with its origin.
    let (s, v) = raw(
        &srv.url,
        "POST",
        "/stages/sec-a/move",
        &[
            ("Host", &host),
            ("Content-Type", "application/json"),
            ("X-Operator", "ada"),
        ],
        mv,
    );
    assert_eq!(s, 200, "{v}");
    let log = stage_events(&srv, "sec-a");
    let kinds: Vec<&str> = log.iter().filter_map(|e| e["kind"].as_str()).collect();
    assert_eq!(kinds, ["move", "moved"], "{log:?}");
    assert_eq!(log[0]["data"]["origin"]["operator"], "ada", "{log:?}");
    assert_eq!(log[0]["data"]["wanted"]["x_um"], 500.0, "{log:?}");
    // The page's own requests (same origin, JSON) still control campaigns.
    let (s, v) = raw(
        &srv.url,
        "POST",
        &pause,
        &[
            ("Host", &host),
            ("Origin", &srv.url),
            ("Sec-Fetch-Site", "same-origin"),
            ("Content-Type", "application/json"),
        ],
        "{}",
    );
    assert_eq!(s, 200, "{v}");
    // And curl's bare POST.
    let (s, v) = raw(&srv.url, "POST", &abort, &[("Host", &host)], "");
    assert_eq!(s, 200, "{v}");
}

fn chromium() -> Option<PathBuf> {
    let found = std::env::var_os("CSMETRO_CHROMIUM")
        .map(PathBuf::from)
        .into_iter()
        .chain(["/usr/lib/chromium/chromium", "/usr/bin/chromium"].map(PathBuf::from))
        .find(|p| p.is_file());
    if found.is_none() {
        if std::env::var("CSMETRO_REQUIRE_BROWSER").as_deref() == Ok("1") {
            panic!("CSMETRO_REQUIRE_BROWSER=1 but chromium is not installed");
        }
        eprintln!("SKIPPED: browser CSRF test: chromium not found (apt-get install chromium)");
    }
    found
}

/// Serves `page` at `/` of 127.0.0.1 on another port (the attacker's origin) until dropped;
/// returns its URL.
fn attacker_site(page: String) -> String {
    let l = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let url = format!("http://localhost:{}/", l.local_addr().unwrap().port());
    std::thread::spawn(move || {
        for s in l.incoming() {
            let Ok(mut s) = s else { return };
            let mut buf = [0u8; 4096];
            let _ = s.read(&mut buf);
            let r = format!(
                "HTTP/1.1 200 OK\r\nContent-Type: text/html\r\nContent-Length: {}\r\nConnection: close\r\n\r\n{page}",
                page.len()
            );
            let _ = s.write_all(r.as_bytes());
        }
    });
    url
}

/// The attacker's page: no-cors fetches, a CORS submission and form POSTs (into frames, so
/// every one is sent) against the service; it writes `done` into the page when all were tried.
fn attack_page(service: &str, running: i64, toml: &str) -> String {
    let js_toml = serde_json::to_string(toml).unwrap();
    let html_toml = toml.replace('&', "&amp;").replace('"', "&quot;");
    format!(
        r#"<!doctype html><html><body>
<iframe name="f1"></iframe><iframe name="f2"></iframe><iframe name="f3"></iframe>
<form id="a" method="POST" target="f1" enctype="text/plain" action="{service}/campaigns"><input name="x" value="{html_toml}"></form>
<form id="b" method="POST" target="f2" action="{service}/stages/sec-a/move"><input name="x_um" value="500"></form>
<form id="c" method="POST" target="f3" action="{service}/campaigns/{running}/abort"></form>
<pre id="out"></pre>
<script>
const T = {service:?};
const toml = {js_toml};
const nc = (path, init) => fetch(T + path, Object.assign({{method: 'POST', mode: 'no-cors'}}, init));
(async () => {{
  const tries = [
    nc('/campaigns', {{headers: {{'Content-Type': 'text/plain'}}, body: toml}}),
    nc('/campaigns', {{body: toml}}),
    nc('/campaigns', {{headers: {{'Content-Type': 'application/x-www-form-urlencoded'}}, body: toml}}),
    nc('/stages/sec-a/move', {{headers: {{'Content-Type': 'text/plain'}}, body: '{{"x_um": 500}}'}}),
    nc('/stages/sec-a/move', {{body: '{{"x_um": 500}}'}}),
    nc('/campaigns/{running}/pause', {{}}),
    nc('/campaigns/{running}/abort', {{}}),
    fetch(T + '/campaigns', {{method: 'POST', headers: {{'Content-Type': 'application/json'}}, body: JSON.stringify({{toml}})}}),
    fetch(T + '/campaigns').then(r => r.text()),
  ];
  const r = await Promise.allSettled(tries);
  document.getElementById('out').textContent = r.map(x => x.status).join(',');
  for (const f of ['a', 'b', 'c']) document.getElementById(f).submit();
  await new Promise(res => setTimeout(res, 1500));
  document.getElementById('out').textContent += ' done';
}})();
</script></body></html>"#
    )
}

#[test]
fn a_page_on_another_origin_cannot_submit_move_pause_or_abort_through_the_browser() {
    let Some(chrome) = chromium() else { return };
    let dir = tempfile::tempdir().unwrap();
    let srv = Server::start(dir.path(), None);
    let (_, running) = setup(&srv);
    let n = campaign_count(&srv);
    let page = attack_page(&srv.url, running, &campaign("evil", "sec-c", 4, 1000.0));
    let site = attacker_site(page);
    let profile = dir.path().join("profile");
    let out = std::process::Command::new(&chrome)
        .args([
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--no-first-run",
            "--virtual-time-budget=15000",
            "--dump-dom",
        ])
        .arg(format!("--user-data-dir={}", profile.display()))
        .arg(&site)
        .output()
        .expect("chromium runs");
    let dom = String::from_utf8_lossy(&out.stdout);
    assert!(
        dom.contains(" done"),
        "the attack page did not finish: {dom}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert_untouched(&srv, n, running);
    // The browser did send them: the service refused them (not the browser on its own).
    let refused = srv.log().matches("refused by the browser policy").count();
    assert!(
        refused >= 7,
        "{refused} refused requests in the log:\n{}",
        srv.log()
    );
    std::thread::sleep(Duration::from_millis(500));
    assert_untouched(&srv, n, running);
    srv_abort(&srv, running);
}

fn srv_abort(srv: &Server, id: i64) {
    let (s, v) = srv.post(&format!("/campaigns/{id}/abort"), None);
    assert_eq!(s, 200, "{v}");
}
