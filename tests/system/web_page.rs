//! The operator's page in a real browser: Debian's `chromium` driven by `chromedriver` over
//! WebDriver (plain HTTP + JSON, spoken here with the crate's own HTTP client) against
//! `csmetro serve` with a token, 100 stored campaigns and a short simulated campaign.
//!
//! Skips with a message when chromium or chromedriver is missing, except with
//! `CSMETRO_REQUIRE_BROWSER=1` (CI), where that is a failure. The screenshot goes to
//! `$CSMETRO_TEST_OUTPUT/web_page.png`, by default `target/tmp/web_page/web_page.png`.
use crate::common;

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use common::{campaign, write_config, Server};
use serde_json::{json, Value};

const TOKEN: &str = "page-test-token-0123456789";

fn find(env: &str, candidates: &[&str]) -> Option<PathBuf> {
    std::env::var_os(env)
        .map(PathBuf::from)
        .into_iter()
        .chain(candidates.iter().map(PathBuf::from))
        .find(|p| p.is_file())
}

/// (chromium binary, chromedriver), or why the test cannot run.
fn browser() -> Result<(PathBuf, PathBuf), String> {
    let chrome = find(
        "CSMETRO_CHROMIUM",
        &["/usr/lib/chromium/chromium", "/usr/bin/chromium"],
    )
    .ok_or("chromium not found (apt-get install chromium)")?;
    let driver = find("CSMETRO_CHROMEDRIVER", &["/usr/bin/chromedriver"])
        .ok_or("chromedriver not found (apt-get install chromium-driver)")?;
    Ok((chrome, driver))
}

/// The browser pair, or `None` after saying why the test is skipped.
fn browser_or_skip() -> Option<(PathBuf, PathBuf)> {
    match browser() {
        Ok(b) => Some(b),
        Err(why) if std::env::var("CSMETRO_REQUIRE_BROWSER").as_deref() == Ok("1") => {
            panic!("CSMETRO_REQUIRE_BROWSER=1 but {why}")
        }
        Err(why) => {
            eprintln!("SKIPPED: browser test of the web page: {why}");
            None
        }
    }
}

fn output_dir() -> PathBuf {
    let d = std::env::var_os("CSMETRO_TEST_OUTPUT")
        .map(PathBuf::from)
        .unwrap_or_else(|| Path::new(env!("CARGO_TARGET_TMPDIR")).join("web_page"));
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// A chromedriver process and one headless chromium session in it.
struct Browser {
    driver: Child,
    base: String,
    session: String,
    agent: ureq::Agent,
}

impl Browser {
    fn start(chrome: &Path, driver: &Path, profile: &Path) -> Browser {
        let mut child = Command::new(driver)
            .arg("--port=0")
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .expect("chromedriver starts");
        // "ChromeDriver was started successfully on port N."
        let mut out = BufReader::new(child.stdout.take().unwrap());
        let mut port = None;
        let mut line = String::new();
        while port.is_none() && out.read_line(&mut line).unwrap_or(0) > 0 {
            port = Some(line.as_str())
                .filter(|l| l.contains("started successfully"))
                .and_then(|l| l.split("on port ").nth(1))
                .and_then(|r| r.trim().trim_end_matches('.').parse::<u16>().ok());
            line.clear();
        }
        std::thread::spawn(move || {
            let mut sink = String::new();
            while out.read_line(&mut sink).unwrap_or(0) > 0 {
                sink.clear();
            }
        });
        let port = port.expect("chromedriver printed its port");
        let agent: ureq::Agent = ureq::Agent::config_builder()
            .http_status_as_error(false)
            .timeout_global(Some(Duration::from_secs(60)))
            .build()
            .into();
        let mut b = Browser {
            driver: child,
            base: format!("http://127.0.0.1:{port}"),
            session: String::new(),
            agent,
        };
        let caps = json!({"capabilities": {"alwaysMatch": {
            "browserName": "chrome",
            "goog:chromeOptions": {
                "binary": chrome,
                "args": ["--headless=new", "--no-sandbox", "--disable-gpu",
                         "--disable-dev-shm-usage", "--window-size=1400,2400",
                         "--no-first-run", "--no-default-browser-check",
                         format!("--user-data-dir={}", profile.display())],
            },
            "goog:loggingPrefs": {"browser": "ALL"},
        }}});
        let t0 = Instant::now();
        let v = loop {
            match b
                .agent
                .post(&format!("{}/session", b.base))
                .send_json(&caps)
            {
                Ok(mut r) => break r.body_mut().read_json::<Value>().unwrap(),
                Err(e) if t0.elapsed() < Duration::from_secs(20) => {
                    let _ = e;
                    std::thread::sleep(Duration::from_millis(200));
                }
                Err(e) => panic!("chromedriver: {e}"),
            }
        };
        b.session = v["value"]["sessionId"]
            .as_str()
            .unwrap_or_else(|| panic!("no session: {v}"))
            .to_string();
        b
    }

    fn call(&self, method: &str, path: &str, body: Value) -> Value {
        let url = format!("{}/session/{}{path}", self.base, self.session);
        let r = match method {
            "GET" => self.agent.get(&url).call(),
            "DELETE" => self.agent.delete(&url).call(),
            _ => self.agent.post(&url).send_json(&body),
        };
        let mut r = r.unwrap_or_else(|e| panic!("{method} {path}: {e}"));
        let ok = r.status().is_success();
        let v: Value = r.body_mut().read_json().unwrap_or(Value::Null);
        assert!(ok, "{method} {path}: {v}");
        v["value"].clone()
    }

    fn goto(&self, url: &str) {
        self.call("POST", "/url", json!({ "url": url }));
    }

    /// Runs `script` (a function body) in the page; its return value.
    fn js(&self, script: &str) -> Value {
        self.call(
            "POST",
            "/execute/sync",
            json!({"script": script, "args": []}),
        )
    }

    fn element(&self, css: &str) -> String {
        let v = self.call(
            "POST",
            "/element",
            json!({"using": "css selector", "value": css}),
        );
        v.as_object()
            .and_then(|o| o.values().next())
            .and_then(Value::as_str)
            .unwrap_or_else(|| panic!("no element {css}: {v}"))
            .to_string()
    }

    fn click(&self, css: &str) {
        let e = self.element(css);
        self.call("POST", &format!("/element/{e}/click"), json!({}));
    }

    fn type_into(&self, css: &str, text: &str) {
        let e = self.element(css);
        self.call(
            "POST",
            &format!("/element/{e}/value"),
            json!({ "text": text }),
        );
    }

    /// Polls `script` until it returns something truthy; that value.
    fn wait(&self, what: &str, timeout_s: f64, script: &str) -> Value {
        let t0 = Instant::now();
        loop {
            let v = self.js(script);
            if !(v.is_null() || v == false || v == 0 || v == "") {
                return v;
            }
            assert!(
                t0.elapsed().as_secs_f64() < timeout_s,
                "timeout waiting for {what}; console: {:?}",
                self.console()
            );
            std::thread::sleep(Duration::from_millis(100));
        }
    }

    /// The browser console's messages since the last call: (level, text).
    fn console(&self) -> Vec<(String, String)> {
        let v = self.call("POST", "/se/log", json!({"type": "browser"}));
        v.as_array()
            .into_iter()
            .flatten()
            .map(|e| {
                (
                    e["level"].as_str().unwrap_or("").to_string(),
                    e["message"].as_str().unwrap_or("").to_string(),
                )
            })
            .collect()
    }

    /// Errors on the console. The browser logs every 4xx reply: the 401s of the first,
    /// tokenless load (the page then asks for the token) and the 400 of the refused campaign
    /// file are answers the page handles, not errors of the page.
    /// Returns (errors, how many handled 4xx replies were logged).
    fn console_errors(&self) -> (Vec<String>, usize) {
        let handled = |m: &str| {
            m.contains("Failed to load resource")
                && (m.contains("status of 401") || m.contains("status of 400"))
        };
        let log = self.console();
        let n = log.iter().filter(|(_, m)| handled(m)).count();
        let errors = log
            .into_iter()
            .filter(|(l, m)| l == "SEVERE" && !handled(m))
            .map(|(_, m)| m)
            .collect();
        (errors, n)
    }

    fn screenshot(&self, path: &Path) {
        let b64 = self.call("GET", "/screenshot", Value::Null);
        let bytes = base64_decode(b64.as_str().unwrap());
        // A real image of the page's size.
        let dec = png::Decoder::new(std::io::Cursor::new(&bytes));
        let info = dec.read_info().unwrap().info().clone();
        assert!(info.width >= 1000 && info.height >= 1000, "{info:?}");
        std::fs::write(path, bytes).unwrap();
    }
}

impl Drop for Browser {
    fn drop(&mut self) {
        if !self.session.is_empty() {
            let url = format!("{}/session/{}", self.base, self.session);
            let _ = self.agent.delete(&url).call();
        }
        let _ = self.driver.kill();
        let _ = self.driver.wait();
    }
}

fn base64_decode(s: &str) -> Vec<u8> {
    let val = |c: u8| -> u32 {
        match c {
            b'A'..=b'Z' => (c - b'A') as u32,
            b'a'..=b'z' => (c - b'a' + 26) as u32,
            b'0'..=b'9' => (c - b'0' + 52) as u32,
            b'+' => 62,
            b'/' => 63,
            _ => panic!("not base64: {c}"),
        }
    };
    let clean: Vec<u8> = s.bytes().filter(|c| !c.is_ascii_whitespace()).collect();
    let mut out = Vec::with_capacity(clean.len() / 4 * 3);
    for chunk in clean.chunks(4) {
        let n = chunk.iter().take_while(|&&c| c != b'=').count();
        let mut acc = 0u32;
        for (i, &c) in chunk[..n].iter().enumerate() {
            acc |= val(c) << (18 - 6 * i);
        }
        out.extend_from_slice(&acc.to_be_bytes()[1..n.max(1)]);
    }
    out
}

/// 100 finished campaigns in the store before the service starts: the history the page lists.
fn stored_history(dir: &Path, n: usize) {
    write_config(dir, "127.0.0.1:0", Some(TOKEN));
    std::fs::create_dir_all(dir.join("var")).unwrap();
    let store = csmetro::store::Store::open(&dir.join("var/csmetro.db")).unwrap();
    for i in 0..n {
        let text = campaign(&format!("old{i}"), "s9", 20, 1000.0);
        let id = store
            .create_campaign(&format!("old{i}"), &text, "old.toml", "s9", 40)
            .unwrap();
        store
            .set_state(id, csmetro::types::CampaignState::Done, None)
            .unwrap();
    }
}

fn api_state(srv: &Server, id: i64) -> String {
    srv.status(id)["state"].as_str().unwrap_or("").to_string()
}

#[test]
fn the_page_follows_a_campaign_live_pauses_it_and_shows_its_results() {
    let Some((chrome, driver)) = browser_or_skip() else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    stored_history(dir.path(), 100);
    let srv = Server::start(dir.path(), Some(TOKEN));
    let b = Browser::start(&chrome, &driver, &dir.path().join("chromium-profile"));

    // Without the token the page asks for it (and shows no data).
    b.goto(&format!("{}/", srv.url));
    b.wait(
        "the token form",
        20.0,
        "return !document.getElementById('token-form').hidden",
    );
    b.type_into("#token", TOKEN);
    b.click("#token-form button");
    b.wait(
        "the list",
        20.0,
        "return document.querySelectorAll('#campaigns tbody tr').length >= 100",
    );
    // The token stays out of every URL the page asked for.
    let urls = b.js("return performance.getEntriesByType('resource').map(e => e.name)");
    assert!(!urls.to_string().contains(TOKEN), "{urls}");

    // First paint with 100 stored campaigns: a fresh load (the token kept in the tab).
    b.goto(&format!("{}/", srv.url));
    let paint = b.wait(
        "the list painted",
        20.0,
        "const s = window.csmetroStats; return s && s.listPaintMs !== null && \
         document.querySelectorAll('#campaigns tbody tr').length >= 100 && \
         {list_ms: s.listPaintMs, fcp_ms: (performance.getEntriesByType('paint').find(e => e.name === 'first-contentful-paint') || {}).startTime}",
    );
    let list_ms = paint["list_ms"].as_f64().unwrap();
    eprintln!(
        "web page: first paint {:.0} ms, campaign list of 100 painted at {list_ms:.0} ms after navigation",
        paint["fcp_ms"].as_f64().unwrap_or(f64::NAN)
    );
    // Target 1 s; the bound leaves room for a loaded CI machine.
    assert!(list_ms < 3000.0, "{paint}");

    // A campaign file with a typo: refused, the error shown at its line. The good one, at 5×
    // real time, runs long enough to see it move and pause it on a loaded machine.
    let good = campaign("live", "s1", 40, 5.0);
    let bad = good.replace("step_um = 25.0", "step_um = 25.0\nstpe = 3");
    let bad_line = bad.lines().position(|l| l.contains("stpe")).unwrap() + 1;
    let set_text = |t: &str| {
        b.js(&format!(
            "document.getElementById('submit-text').value = {}; \
             document.getElementById('submit-name').value = 'live.toml'; return true",
            serde_json::to_string(t).unwrap()
        ));
    };
    set_text(&bad);
    b.click("#submit-form button");
    let at = b.wait(
        "the validation error",
        20.0,
        "const e = document.getElementById('submit-error-line'); return e && e.dataset.line",
    );
    assert_eq!(at, Value::from(bad_line.to_string()));
    let msg = b.js("return document.getElementById('submit-error-msg').textContent");
    assert!(
        msg.as_str()
            .unwrap()
            .starts_with(&format!("live.toml:{bad_line}: axes.x.stpe")),
        "{msg}"
    );

    // The good one: submitted from the page, which then follows it.
    set_text(&good);
    b.click("#submit-form button");
    let id = b
        .wait(
            "the new campaign selected",
            20.0,
            "const t = document.getElementById('detail-title').textContent; \
             return t.includes('live') && Number(location.hash.slice(1))",
        )
        .as_i64()
        .unwrap();
    assert_eq!(srv.status(id)["name"], "live");

    // Progress advances and the live plot gains points.
    let first = b.wait(
        "samples on the plot",
        60.0,
        "const n = Number(document.getElementById('plots').dataset.samples || 0); return n >= 3 && n",
    );
    let first = first.as_u64().unwrap();
    let stored0 = b.js("return Number(document.getElementById('detail-state').dataset.stored)");
    b.wait(
        "more samples on the plot",
        60.0,
        &format!(
            "return Number(document.getElementById('plots').dataset.samples || 0) > {first} + 3"
        ),
    );
    b.wait(
        "progress to advance",
        20.0,
        &format!(
            "return Number(document.getElementById('detail-state').dataset.stored) > {stored0}"
        ),
    );
    let canvases = b.js(
        "return [...document.querySelectorAll('#plots canvas')].map(c => [c.dataset.component, Number(c.dataset.points)])",
    );
    let comps: Vec<&str> = canvases
        .as_array()
        .unwrap()
        .iter()
        .map(|c| c[0].as_str().unwrap())
        .collect();
    assert!(
        comps.contains(&"ef_xx") && comps.contains(&"ef_xy"),
        "{canvases}"
    );

    // The pause button pauses: the API agrees, and nothing is measured while paused.
    b.wait(
        "the pause button",
        20.0,
        "return !document.getElementById('btn-pause').disabled",
    );
    b.click("#btn-pause");
    let t0 = Instant::now();
    while api_state(&srv, id) != "paused" {
        assert!(t0.elapsed() < Duration::from_secs(10), "{}", srv.status(id));
        std::thread::sleep(Duration::from_millis(50));
    }
    b.wait(
        "the page to show the pause",
        10.0,
        "return document.getElementById('detail-state').dataset.state === 'paused'",
    );
    std::thread::sleep(Duration::from_millis(500));
    let held = srv.status(id)["stored"].as_u64().unwrap();
    std::thread::sleep(Duration::from_millis(1500));
    assert_eq!(srv.status(id)["stored"].as_u64().unwrap(), held);
    assert_eq!(api_state(&srv, id), "paused");
    b.click("#btn-resume");
    srv.wait_for(id, 10.0, |s| {
        s["state"] == "running" || s["state"] == "done"
    });

    // At the end: every sample on the plot, the reconstructions drawn, the ISO 230-2 figures
    // and the result files listed.
    srv.wait_for(id, 180.0, |s| s["state"] == "done");
    let planned = srv.status(id)["planned"].as_u64().unwrap();
    b.wait(
        "every sample on the plot",
        20.0,
        &format!("return Number(document.getElementById('plots').dataset.samples) === {planned}"),
    );
    b.wait(
        "the reconstructions",
        20.0,
        "return [...document.querySelectorAll('#plots canvas')].every(c => Number(c.dataset.curves) > 0)",
    );
    b.wait(
        "the ISO 230-2 figures",
        20.0,
        "return !document.getElementById('iso').hidden && \
         document.querySelector('#iso .iso-table[data-axis=x] tr[data-figure=A]') !== null",
    );
    let links = b.wait(
        "the result files",
        20.0,
        "const a = [...document.querySelectorAll('#results a')].map(a => a.dataset.name); \
         return a.includes('summary.json') && a",
    );
    let (s, served) = srv.get(&format!("/campaigns/{id}/results"));
    assert_eq!(s, 200);
    assert_eq!(links, served["results"], "every result file is linked");
    // A campaign whose report draws the ISO 230-2 chart: the page shows it, loaded.
    let iso_charts = served["results"]
        .as_array()
        .unwrap()
        .iter()
        .filter_map(Value::as_str)
        .filter(|n| n.starts_with("plots/iso230_") && n.ends_with(".svg"))
        .count();
    if iso_charts > 0 {
        b.wait(
            "the ISO 230-2 chart",
            20.0,
            &format!(
                "const i = [...document.querySelectorAll('#iso-body img')]; \
                 return i.length === {iso_charts} && i.every(x => x.complete && x.naturalWidth > 0)"
            ),
        );
    }

    let stats = b.js("return window.csmetroStats");
    let live = stats["liveSamples"].as_f64().unwrap();
    let max_lat = stats["maxLatencyS"].as_f64().unwrap();
    eprintln!(
        "web page: {live} live samples, commit-to-plot latency mean {:.3} s, max {max_lat:.3} s",
        stats["sumLatencyS"].as_f64().unwrap() / live.max(1.0)
    );
    assert!(live > 0.0, "{stats}");
    // Target 1 s; the bound leaves room for a loaded CI machine.
    assert!(max_lat < 3.0, "{stats}");

    b.js("document.getElementById('detail').scrollIntoView(); return true");
    let shot = output_dir().join("web_page.png");
    b.screenshot(&shot);
    eprintln!("web page: screenshot in {}", shot.display());

    // Its verification (`[campaign] verify = ID`): the page shows the before/after table and
    // the charts with the pass line.
    let ver = common::sim_header("ver", "s1", "ideal.toml", 100.0, 7).replace(
        "stage = \"s1\"\n",
        &format!("stage = \"s1\"\nverify = {id}\n"),
    ) + "\n[acquisition]\ncycles = 2\nsettle_s = 0.2\n";
    let vid = srv.submit(&ver);
    srv.wait_for(vid, 180.0, |s| {
        s["state"] == "done" || s["state"] == "failed"
    });
    b.js(&format!("select({vid}); return true"));
    let row = b.wait(
        "the verification's before/after table",
        30.0,
        "const r = document.querySelector('#verification-body .verify-table tr[data-axis=x]'); \
         return !document.getElementById('verification').hidden && r && r.children.length",
    );
    assert_eq!(row, 8, "axis, E, E, mean, mean, max, expected, verdict");
    b.wait(
        "the verification chart",
        20.0,
        "const i = [...document.querySelectorAll('#verification-body img')]; \
         return i.length === 1 && i.every(x => x.complete && x.naturalWidth > 0)",
    );
    let (errors, handled) = b.console_errors();
    assert!(errors.is_empty(), "console errors: {errors:?}");
    // The log was really read: the tokenless first load's 401s and the refused file's 400 are in it.
    assert!(
        handled >= 2,
        "{handled} handled 4xx replies in the console log"
    );
}

/// The campaign's `wall_s` from its summary, s.
fn wall_s(srv: &Server, id: i64) -> f64 {
    let (s, b, _) = srv.request(
        "GET",
        &format!("/campaigns/{id}/results/summary.json"),
        None,
        None,
    );
    assert_eq!(s, 200);
    serde_json::from_slice::<Value>(&b).unwrap()["wall_s"]
        .as_f64()
        .unwrap()
}

/// The page's cost: the same campaign alternately with no page open and with the page following
/// it live (plot, list refresh every 2 s). Target: ≤ 5 % more wall time.
#[test]
#[ignore = "measurement, a few minutes: cargo test --test system web_page:: -- --ignored --nocapture"]
fn the_page_adds_little_to_a_campaigns_wall_time() {
    let Some((chrome, driver)) = browser_or_skip() else {
        return;
    };
    let rounds: usize = std::env::var("CSMETRO_PAGE_ROUNDS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(3);
    let dir = tempfile::tempdir().unwrap();
    let srv = Server::start(dir.path(), None);
    let b = Browser::start(&chrome, &driver, &dir.path().join("chromium-profile"));
    let text = campaign("overhead", "s1", 40, 4.0);
    let (mut without, mut with) = (Vec::new(), Vec::new());
    for round in 0..2 * rounds {
        let watched = round % 2 == 1;
        b.goto("about:blank");
        let id = srv.submit(&text);
        if watched {
            b.goto(&format!("{}/#{id}", srv.url));
            b.wait(
                "the page following the campaign",
                20.0,
                &format!("return document.getElementById('detail-title').textContent.includes('Campaign {id} ')"),
            );
        }
        srv.wait_for(id, 600.0, |s| s["state"] == "done");
        let w = wall_s(&srv, id);
        eprintln!(
            "round {round}: page {}: wall {w:.2} s",
            if watched { "open" } else { "closed" }
        );
        if watched {
            with.push(w)
        } else {
            without.push(w)
        }
    }
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
    let median = |v: &[f64]| {
        let mut v = v.to_vec();
        v.sort_by(f64::total_cmp);
        let n = v.len();
        (v[(n - 1) / 2] + v[n / 2]) / 2.0
    };
    let (a, p) = (mean(&without), mean(&with));
    let (ma, mp) = (median(&without), median(&with));
    eprintln!(
        "web page overhead: mean wall {a:.2} s without the page, {p:.2} s with it: {:+.1} %; \
         medians {ma:.2} s, {mp:.2} s: {:+.1} %",
        100.0 * (p / a - 1.0),
        100.0 * (mp / ma - 1.0)
    );
    // The target is 5 %; a shared machine's noise gets twice that before this fails.
    assert!(p / a - 1.0 < 0.10, "{without:?} {with:?}");
}

/// A map campaign is drawn over XY, not as 1-D scatter against one axis: heat maps of e_x and
/// e_y (the samples while it runs, the reconstructed grid at its end) and the ISO 230-1
/// figures of the map.
#[test]
fn a_map_campaign_shows_heat_maps_and_its_iso230_1_figures() {
    let Some((chrome, driver)) = browser_or_skip() else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let srv = Server::start(dir.path(), None);
    let b = Browser::start(&chrome, &driver, &dir.path().join("chromium-profile"));
    let id = srv.submit(&common::map_campaign("page-map"));
    b.goto(&format!("{}/#{id}", srv.url));
    b.wait(
        "the samples over XY",
        60.0,
        "const c = document.querySelector('#map-body canvas[data-map=\"forward-ex\"]'); \
         return c !== null && Number(c.dataset.samples) > 0",
    );
    let st = srv.wait_for(id, 180.0, |s| {
        s["state"] == "done" || s["state"] == "failed"
    });
    assert_eq!(st["state"], "done", "{st}");
    let maps = b.wait(
        "the reconstructed heat maps",
        30.0,
        "const c = [...document.querySelectorAll('#map-body canvas')]; \
         return c.length >= 2 && c.every(x => Number(x.dataset.cells) > 0 && Number(x.dataset.samples) === 40) && \
         c.map(x => [x.dataset.map, Number(x.dataset.cells)])",
    );
    let names: Vec<&str> = maps
        .as_array()
        .unwrap()
        .iter()
        .map(|m| m[0].as_str().unwrap())
        .collect();
    assert!(
        names.contains(&"forward-ex") && names.contains(&"forward-ey"),
        "{maps}"
    );
    // 20 x 10 grid points of the [map] (950 x 450 µm at 50 µm).
    assert!(maps[0][1].as_u64() >= Some(200), "{maps}");
    // Non-trivial content: many colours (the cells' scale and the colour bar), not a blank.
    for key in ["forward-ex", "forward-ey"] {
        let colours = b.js(&format!(
            "const c = document.querySelector('#map-body canvas[data-map=\"{key}\"]'); \
             const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data; \
             const s = new Set(); for (let i = 0; i < d.length; i += 4) s.add((d[i] << 16) | (d[i + 1] << 8) | d[i + 2]); \
             return s.size"
        ));
        assert!(colours.as_u64() > Some(30), "{key}: {colours} colours");
    }
    // No 1-D scatter of a map against one axis.
    let lines = b.js(
        "return [document.querySelectorAll('#plots canvas').length, document.getElementById('lines').hidden]",
    );
    assert_eq!(lines, json!([0, true]), "{lines}");
    let sq = b.wait(
        "the ISO 230-1 figures",
        20.0,
        "const t = document.querySelector('#iso2301-body tr[data-figure=squareness_urad] td.num'); \
         return !document.getElementById('iso2301').hidden && t && t.textContent",
    );
    assert!(
        sq.as_str()
            .unwrap()
            .parse::<f64>()
            .is_ok_and(f64::is_finite),
        "{sq}"
    );
    b.js("document.getElementById('maps').scrollIntoView(); return true");
    b.screenshot(&output_dir().join("web_page_map.png"));
    let (errors, _) = b.console_errors();
    assert!(errors.is_empty(), "console errors: {errors:?}");
}
