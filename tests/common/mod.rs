//! A `csmetro serve` process on 127.0.0.1:0 with its own configuration and store, tiny
//! simulated campaigns, and a small HTTP client for the tests.
// Each test binary uses some of these helpers, and `pub` is how they are shared between them.
#![allow(dead_code, unreachable_pub)]
use std::io::{BufRead, BufReader, Read};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use serde_json::Value;

/// The binary, with stage locks in a directory of this test only: tests run in parallel on the
/// same stage names, which machine-wide locks would otherwise serialize.
pub fn bin() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_csmetro"));
    c.env("CSMETRO_LOCK_DIR", test_lock_dir());
    c
}

/// A lock directory per test (libtest names each test's thread after it).
pub fn test_lock_dir() -> PathBuf {
    let t = std::thread::current();
    let name: String = t
        .name()
        .unwrap_or("main")
        .chars()
        .map(|c| if c.is_ascii_alphanumeric() { c } else { '_' })
        .collect();
    let d = std::env::temp_dir().join(format!("csmetro-test-locks-{}-{name}", std::process::id()));
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// The single JSON object a successful `--json` command printed on stdout.
pub fn json_of(o: &std::process::Output) -> Value {
    assert!(
        o.status.success(),
        "exit {:?}: {}",
        o.status.code(),
        String::from_utf8_lossy(&o.stderr)
    );
    serde_json::from_str(String::from_utf8_lossy(&o.stdout).trim()).unwrap()
}

pub fn repo(p: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join(p)
}

/// The `[campaign]` and `[hardware]` sections of a test campaign on a simulated stage: the
/// controllers on pseudo-terminals, a 640 × 640 camera whose frames take 0.1 s.
pub fn sim_header(name: &str, stage: &str, model: &str, time_scale: f64, seed: u64) -> String {
    format!(
        r#"[campaign]
name = "{name}"
stage = "{stage}"

[hardware]
kind = "sim"
optics = {{ width = 640, height = 640 }}

[hardware.sim]
model = "{model}"
time_scale = {time_scale}
transport = "pty"
frame_time_s = 0.1
seed = {seed}
"#
    )
}

/// `csmetro run --json --quiet --db DB CAMPAIGN`, to its end.
pub fn run_json(campaign: &Path, db: &Path) -> std::process::Output {
    bin()
        .args(["run", "--json", "--quiet", "--db"])
        .arg(db)
        .arg(campaign)
        .output()
        .unwrap()
}

/// `csmetro resume ID --db DB` with `flags` (e.g. `--json`, `--quiet`), to its end.
pub fn resume(id: i64, flags: &[&str], db: &Path) -> std::process::Output {
    bin()
        .arg("resume")
        .arg(id.to_string())
        .args(flags)
        .arg("--db")
        .arg(db)
        .output()
        .unwrap()
}

/// A campaign of `2 * m` targets on x (forward and backward) of a simulated stage.
/// `time_scale`: simulated physical time runs that many times faster than the wall clock.
pub fn campaign(name: &str, stage: &str, m: usize, time_scale: f64) -> String {
    let head = sim_header(name, stage, "ideal.toml", time_scale, 7);
    format!(
        r#"{head}
[axes.x]
range_um = [0.0, 1000.0]
step_um = 25.0
other_at_um = 2100.0
m = {m}

[sampling]
design = "random"
seed = 3

[acquisition]
directions = ["forward", "backward"]
settle_s = 0.2

[outputs]
dir = "{name}-{{id}}"
"#
    )
}

pub struct Server {
    pub child: Child,
    pub url: String,
    pub dir: PathBuf,
    pub config: PathBuf,
    pub token: Option<String>,
}

/// Writes `dir/csmetro.toml` (store and results under `dir/var`).
pub fn write_config(dir: &Path, bind: &str, token: Option<&str>) -> PathBuf {
    let mut t = format!("[server]\nbind = \"{bind}\"\n");
    if let Some(tok) = token {
        t.push_str(&format!("token = \"{tok}\"\n"));
    }
    t.push_str("\n[storage]\ndb = \"var/csmetro.db\"\nresults_dir = \"var/results\"\n\n[log]\nfilter = \"info,csmetro=debug\"\n");
    // Submitted campaigns name their stage model (`ideal.toml`) in the shipped models.
    t.push_str(&format!(
        "\n[campaigns]\nbase_dir = \"{}\"\n",
        repo("config/sim").display()
    ));
    let p = dir.join("csmetro.toml");
    std::fs::write(&p, t).unwrap();
    p
}

impl Server {
    /// Starts `csmetro serve` with the configuration in `dir` (written if absent).
    pub fn start(dir: &Path, token: Option<&str>) -> Server {
        Self::start_with_env(dir, token, &[])
    }

    /// [`Server::start`] with more variables in the service's environment.
    pub fn start_with_env(dir: &Path, token: Option<&str>, env: &[(&str, &Path)]) -> Server {
        let config = dir.join("csmetro.toml");
        if !config.exists() {
            write_config(dir, "127.0.0.1:0", token);
        }
        let log = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(dir.join("serve.log"))
            .unwrap();
        let mut child = bin()
            .arg("serve")
            .arg("--config")
            .arg(&config)
            .env_remove("RUST_LOG")
            .env_remove("NOTIFY_SOCKET")
            .envs(env.iter().copied())
            .stdout(Stdio::piped())
            .stderr(log)
            .spawn()
            .unwrap();
        let mut out = BufReader::new(child.stdout.take().unwrap());
        let mut url = String::new();
        out.read_line(&mut url).unwrap();
        let url = url.trim().to_string();
        assert!(
            url.starts_with("http://127.0.0.1:"),
            "first stdout line {url:?}; log:\n{}",
            std::fs::read_to_string(dir.join("serve.log")).unwrap_or_default()
        );
        // Keep draining stdout so the service never blocks on a full pipe.
        std::thread::spawn(move || {
            let mut sink = Vec::new();
            let _ = out.read_to_end(&mut sink);
        });
        Server {
            child,
            url,
            dir: dir.to_path_buf(),
            config,
            token: token.map(str::to_string),
        }
    }

    pub fn log(&self) -> String {
        std::fs::read_to_string(self.dir.join("serve.log")).unwrap_or_default()
    }

    pub fn db(&self) -> PathBuf {
        self.dir.join("var/csmetro.db")
    }

    /// SIGTERM, then wait for the exit; returns the exit status.
    pub fn terminate(&mut self) -> std::process::ExitStatus {
        let pid = self.child.id().to_string();
        Command::new("kill").args(["-TERM", &pid]).status().unwrap();
        let t0 = Instant::now();
        loop {
            if let Some(st) = self.child.try_wait().unwrap() {
                return st;
            }
            assert!(t0.elapsed() < Duration::from_secs(30), "serve did not stop");
            std::thread::sleep(Duration::from_millis(50));
        }
    }

    pub fn kill9(&mut self) {
        self.child.kill().unwrap();
        self.child.wait().unwrap();
    }

    fn agent() -> ureq::Agent {
        ureq::Agent::config_builder()
            .http_status_as_error(false)
            .build()
            .into()
    }

    /// (status, body) of a request; `token` overrides the server's.
    pub fn request(
        &self,
        method: &str,
        path: &str,
        body: Option<(&str, &str)>,
        token: Option<&str>,
    ) -> (u16, Vec<u8>, String) {
        let url = format!("{}{path}", self.url);
        let token = token.or(self.token.as_deref());
        let a = Self::agent();
        let r = match method {
            "GET" => {
                let mut r = a.get(&url);
                if let Some(t) = token {
                    r = r.header("Authorization", &format!("Bearer {t}"));
                }
                r.call()
            }
            "POST" => {
                let mut r = a.post(&url);
                if let Some(t) = token {
                    r = r.header("Authorization", &format!("Bearer {t}"));
                }
                match body {
                    Some((ctype, b)) => r.content_type(ctype).send(b),
                    None => r.send_empty(),
                }
            }
            _ => unreachable!(),
        };
        let mut r = r.unwrap();
        let status = r.status().as_u16();
        let ctype = r
            .headers()
            .get("content-type")
            .and_then(|v| v.to_str().ok())
            .unwrap_or("")
            .to_string();
        let bytes = r
            .body_mut()
            .with_config()
            .limit(1 << 30)
            .read_to_vec()
            .unwrap();
        (status, bytes, ctype)
    }

    pub fn get(&self, path: &str) -> (u16, Value) {
        let (s, b, _) = self.request("GET", path, None, None);
        (s, serde_json::from_slice(&b).unwrap_or(Value::Null))
    }

    pub fn post(&self, path: &str, body: Option<(&str, &str)>) -> (u16, Value) {
        let (s, b, _) = self.request("POST", path, body, None);
        (s, serde_json::from_slice(&b).unwrap_or(Value::Null))
    }

    /// Submits campaign text; returns its id.
    pub fn submit(&self, text: &str) -> i64 {
        let (s, v) = self.post("/campaigns", Some(("application/toml", text)));
        assert_eq!(s, 201, "{v}");
        v["id"].as_i64().unwrap()
    }

    pub fn status(&self, id: i64) -> Value {
        let (s, v) = self.get(&format!("/campaigns/{id}"));
        assert_eq!(s, 200, "{v}");
        v
    }

    /// Polls until `pred(status)` or the timeout; returns the last status.
    pub fn wait_for(&self, id: i64, timeout_s: f64, pred: impl Fn(&Value) -> bool) -> Value {
        let t0 = Instant::now();
        loop {
            let st = self.status(id);
            if pred(&st) {
                return st;
            }
            assert!(
                t0.elapsed().as_secs_f64() < timeout_s,
                "timeout waiting on campaign {id}: {st}\nlog:\n{}",
                self.log()
            );
            std::thread::sleep(Duration::from_millis(50));
        }
    }

    /// Every server-sent event of a campaign's stream until the service ends it.
    pub fn events(&self, id: i64, after: i64) -> Vec<(String, Option<i64>, Value)> {
        sse(&self.url, self.token.as_deref(), id, after)
    }
}

/// Every server-sent event of a campaign's stream until the service ends it:
/// (event name, id, parsed data).
pub fn sse(
    base: &str,
    token: Option<&str>,
    id: i64,
    after: i64,
) -> Vec<(String, Option<i64>, Value)> {
    let url = format!("{base}/campaigns/{id}/events?after={after}");
    let agent: ureq::Agent = ureq::Agent::config_builder()
        .http_status_as_error(false)
        .build()
        .into();
    let mut r = agent.get(&url);
    if let Some(t) = token {
        r = r.header("Authorization", &format!("Bearer {t}"));
    }
    let r = r.call().unwrap();
    assert_eq!(r.status().as_u16(), 200);
    let mut out = Vec::new();
    let (mut kind, mut eid, mut data) = (String::new(), None, String::new());
    for l in BufReader::new(r.into_body().into_reader()).lines() {
        let l = l.unwrap();
        if l.is_empty() {
            if !kind.is_empty() {
                out.push((
                    std::mem::take(&mut kind),
                    eid.take(),
                    serde_json::from_str(&data).unwrap(),
                ));
            }
            data.clear();
        } else if let Some(v) = l.strip_prefix("event: ") {
            kind = v.to_string();
        } else if let Some(v) = l.strip_prefix("id: ") {
            eid = v.parse().ok();
        } else if let Some(v) = l.strip_prefix("data: ") {
            data.push_str(v);
        }
    }
    out
}

impl Drop for Server {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// The store at `db` (created if new) with `trigger` added: a second connection's SQLite trigger
/// makes chosen writes fail, as a full disk or a lost file would.
pub fn fail_writes(db: &Path, trigger: &str) {
    drop(csmetro::store::Store::open(db).unwrap());
    let c = rusqlite::Connection::open(db).unwrap();
    c.execute_batch(trigger).unwrap();
}

/// The stored samples' seqs of a campaign, read from the store file directly.
pub fn stored_seqs(db: &Path, id: i64) -> Vec<u64> {
    let s = csmetro::store::Store::open(db).unwrap();
    s.samples(id)
        .unwrap()
        .iter()
        .map(|r| r.target.seq)
        .collect()
}

/// A campaign file on a simulated stage (stage model `config/sim/{model}`, a 640 x 640 camera,
/// simulated time 1000x): the tests that write their own files share this one fixture.
pub struct SimFile<'a> {
    pub name: &'a str,
    pub stage: &'a str,
    pub model: &'a str,
    /// More `[campaign]` keys (`verify = 1`).
    pub campaign: &'a str,
    /// More `[hardware.sim]` keys (`seed = 5`, `transport = "pty"`).
    pub sim: &'a str,
    /// The sections after `[hardware.sim]`: `[axes.*]`, `[sampling]`, `[acquisition]`, ...
    pub rest: &'a str,
    /// `[outputs] dir` (`{id}`, `{name}` expand).
    pub outputs: String,
    /// Sections after `[outputs]`.
    pub tail: &'a str,
}

impl SimFile<'_> {
    pub fn text(&self) -> String {
        format!(
            "[campaign]\nname = \"{}\"\nstage = \"{}\"\n{}\n\n[hardware]\nkind = \"sim\"\n\
             optics = {{ width = 640, height = 640 }}\n\n[hardware.sim]\nmodel = \"{}\"\n\
             time_scale = 1000\n{}\n\n{}\n\n[outputs]\ndir = \"{}\"\n\n{}",
            self.name,
            self.stage,
            self.campaign,
            repo("config/sim").join(self.model).display(),
            self.sim,
            self.rest,
            self.outputs,
            self.tail
        )
    }

    /// Writes the file to `path` and returns it.
    pub fn write(&self, path: &Path) -> PathBuf {
        std::fs::write(path, self.text()).unwrap();
        path.to_path_buf()
    }
}

/// A small `[map]` campaign named `name` on stage "s1": both axes to 40 random XY points of a
/// 950 × 450 µm region (the demo XY model, time scale 100), results in `<name>-<id>`.
pub fn map_campaign(name: &str) -> String {
    format!(
        r#"{}
[map]
x_range_um = [2000.0, 2950.0]
y_range_um = [1000.0, 1450.0]
step_um = [50.0, 50.0]
m = 40
design = "random"
seed = 5
method = "linear"

[acquisition]
settle_s = 2.0
dwell_s = 0.5

[outputs]
dir = "{name}-{{id}}"
"#,
        sim_header(name, "s1", "demo_xy.toml", 100.0, 4)
    )
}
