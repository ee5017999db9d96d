//! Clients of the service: `csmetro submit|status|watch|pause|unpause|abort|report`.
//! (`csmetro resume ID` stays the foreground resume on a store; the service's resume of a paused
//! or interrupted campaign is `csmetro unpause ID`.)
//!
//! Exit codes: 0 fine; 1 failure (service unreachable, campaign not done, 409); 2 bad input
//! (campaign file, unknown id, missing or wrong token); `watch` exits 130 for an aborted campaign.
use std::io::{BufRead, BufReader};
use std::path::{Component, Path, PathBuf};
use std::process::ExitCode;
use std::time::{Duration, Instant};

use serde_json::{json, Value};

use super::{CliError, CliResult};
use crate::api::CampaignStatus;
use crate::types::CampaignState;

/// Default address of the service (`[server] bind` of the shipped configuration).
pub const DEFAULT_SERVER: &str = "http://127.0.0.1:8463";

/// How far `report` goes for one result file.
const MAX_RESULT_BYTES: u64 = 1 << 30;

#[derive(clap::Args, Clone)]
pub struct Conn {
    /// Service URL.
    #[arg(long, env = "CSMETRO_SERVER", default_value = DEFAULT_SERVER, global = true)]
    server: String,
    /// Bearer token, when the service requires one.
    #[arg(long, env = "CSMETRO_TOKEN", hide_env_values = true, global = true)]
    token: Option<String>,
    /// Print JSON (one object, or one event per line for `watch`).
    #[arg(long, global = true)]
    json: bool,
    /// Your name, sent as `X-Operator`: the campaign's event log says who submitted, paused,
    /// resumed or aborted it (ASCII, at most 64 bytes).
    #[arg(long, env = "CSMETRO_OPERATOR", global = true)]
    operator: Option<String>,
}

#[derive(clap::Args)]
pub struct SubmitArgs {
    /// Campaign file (TOML); relative paths in it resolve on the service's side
    /// (`[campaigns] base_dir` of its configuration).
    campaign: PathBuf,
    /// Follow the campaign's events after submitting (as `csmetro watch`).
    #[arg(long)]
    watch: bool,
    #[command(flatten)]
    conn: Conn,
}

#[derive(clap::Args)]
pub struct StatusArgs {
    /// Campaign id; without it, every campaign.
    id: Option<i64>,
    #[command(flatten)]
    conn: Conn,
}

#[derive(clap::Args)]
pub struct WatchArgs {
    id: i64,
    /// Also print every sample (many lines).
    #[arg(long)]
    samples: bool,
    /// Without `--samples`: seconds between progress lines (stored/planned, elapsed, ETA)
    /// while samples arrive.
    #[arg(long, default_value_t = 5.0, value_parser = progress_interval)]
    progress_s: f64,
    #[command(flatten)]
    conn: Conn,
}

// Stays a String error: clap's value parser prints it as the flag's error.
fn progress_interval(s: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(v) if v.is_finite() && (0.1..=86_400.0).contains(&v) => Ok(v),
        _ => Err("expected seconds between 0.1 and 86400".into()),
    }
}

#[derive(clap::Args)]
pub struct IdArgs {
    id: i64,
    #[command(flatten)]
    conn: Conn,
}

#[derive(clap::Args)]
pub struct AbortArgs {
    id: i64,
    /// Seconds to wait for a running campaign to stop motion and end (0: do not wait).
    #[arg(long, default_value_t = 60.0)]
    wait_s: f64,
    #[command(flatten)]
    conn: Conn,
}

#[derive(clap::Args)]
pub struct ReportArgs {
    id: i64,
    /// Directory the results are written to (default csmetro-report-ID).
    #[arg(long)]
    out: Option<PathBuf>,
    #[command(flatten)]
    conn: Conn,
}

struct Client {
    base: String,
    token: Option<String>,
    operator: Option<String>,
    agent: ureq::Agent,
}

struct Reply {
    status: u16,
    content_type: String,
    body: Vec<u8>,
}

impl Client {
    fn new(c: &Conn) -> Self {
        let agent: ureq::Agent = ureq::Agent::config_builder()
            .http_status_as_error(false)
            .timeout_connect(Some(Duration::from_secs(5)))
            .build()
            .into();
        Self {
            base: c.server.trim_end_matches('/').to_string(),
            token: c.token.clone().filter(|t| !t.is_empty()),
            operator: c.operator.clone().filter(|o| !o.trim().is_empty()),
            agent,
        }
    }

    fn url(&self, path: &str) -> String {
        format!("{}{path}", self.base)
    }

    fn unreachable(&self, e: ureq::Error) -> CliError {
        CliError::failure(format!("cannot reach the service at {}: {e}", self.base))
    }

    fn auth<B>(&self, r: ureq::RequestBuilder<B>) -> ureq::RequestBuilder<B> {
        let r = match &self.operator {
            Some(o) => r.header("X-Operator", o),
            None => r,
        };
        match &self.token {
            Some(t) => r.header("Authorization", &format!("Bearer {t}")),
            None => r,
        }
    }

    fn reply(
        &self,
        r: Result<ureq::http::Response<ureq::Body>, ureq::Error>,
    ) -> Result<Reply, CliError> {
        let mut r = r.map_err(|e| self.unreachable(e))?;
        let status = r.status().as_u16();
        let content_type = r
            .headers()
            .get("content-type")
            .and_then(|v| v.to_str().ok())
            .unwrap_or("")
            .to_string();
        let body = r
            .body_mut()
            .with_config()
            .limit(MAX_RESULT_BYTES)
            .read_to_vec()
            .map_err(|e| self.unreachable(e))?;
        let reply = Reply {
            status,
            content_type,
            body,
        };
        if (200..300).contains(&status) {
            Ok(reply)
        } else {
            Err(http_error(&reply))
        }
    }

    fn get(&self, path: &str) -> Result<Reply, CliError> {
        self.reply(self.auth(self.agent.get(&self.url(path))).call())
    }

    fn post_json(&self, path: &str, body: &Value) -> Result<Reply, CliError> {
        self.reply(self.auth(self.agent.post(&self.url(path))).send_json(body))
    }

    fn post_empty(&self, path: &str) -> Result<Reply, CliError> {
        self.reply(self.auth(self.agent.post(&self.url(path))).send_empty())
    }

    fn status(&self, id: i64) -> Result<CampaignStatus, CliError> {
        json_of(&self.get(&format!("/campaigns/{id}"))?)
    }
}

/// The service's `{"error": ...}` as a CLI error: its fault or the user's, by status code.
fn http_error(r: &Reply) -> CliError {
    let msg = serde_json::from_slice::<Value>(&r.body)
        .ok()
        .and_then(|v| v["error"].as_str().map(str::to_string))
        .unwrap_or_else(|| String::from_utf8_lossy(&r.body).trim().to_string());
    let msg = format!("service answered {}: {msg}", r.status);
    match r.status {
        400 | 401 | 403 | 404 => CliError::input(msg),
        _ => CliError::failure(msg),
    }
}

fn json_of<T: serde::de::DeserializeOwned>(r: &Reply) -> Result<T, CliError> {
    serde_json::from_slice(&r.body)
        .map_err(|e| CliError::failure(format!("unexpected answer from the service: {e}")))
}

fn print_json(v: &impl serde::Serialize) {
    outln!("{}", serde_json::to_string(v).unwrap_or_default());
}

fn line(s: &CampaignStatus) -> String {
    let mut l = format!(
        "campaign {} \"{}\" on {}: {} {}/{} ({:.1} %)",
        s.id,
        s.name,
        s.stage,
        s.state.as_str(),
        s.stored,
        s.planned,
        s.percent
    );
    if let Some(p) = s.queue_position {
        l.push_str(&format!(", queue position {p}"));
    }
    if let Some(e) = s.eta_s {
        l.push_str(&format!(", ETA {}", crate::report::format_hms(e)));
    }
    if let Some(m) = &s.message {
        l.push_str(&format!(" — {m}"));
    }
    l
}

pub fn submit(a: SubmitArgs) -> CliResult {
    let text = std::fs::read_to_string(&a.campaign)
        .map_err(|e| CliError::input(format!("{}: cannot read: {e}", a.campaign.display())))?;
    let name = a
        .campaign
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let c = Client::new(&a.conn);
    let st: CampaignStatus =
        json_of(&c.post_json("/campaigns", &json!({"toml": text, "name": name}))?)?;
    if a.conn.json && !a.watch {
        print_json(&st);
    } else {
        eprintln!("{}", line(&st));
    }
    if a.watch {
        return follow(&c, st.id, false, a.conn.json, DEFAULT_PROGRESS_S);
    }
    if !a.conn.json {
        outln!("{}", st.id);
    }
    Ok(ExitCode::SUCCESS)
}

pub fn status(a: StatusArgs) -> CliResult {
    let c = Client::new(&a.conn);
    match a.id {
        Some(id) => {
            let st = c.status(id)?;
            if a.conn.json {
                print_json(&st);
            } else {
                outln!("{}", line(&st));
            }
        }
        None => {
            let all: Vec<CampaignStatus> = json_of(&c.get("/campaigns")?)?;
            if a.conn.json {
                print_json(&all);
            } else {
                outln!(
                    "{:>5}  {:<11}  {:>15}  {:>6}  {:<12}  {:>8}  name",
                    "id",
                    "state",
                    "stored/planned",
                    "%",
                    "stage",
                    "ETA"
                );
                for s in &all {
                    outln!(
                        "{:>5}  {:<11}  {:>15}  {:>6.1}  {:<12}  {:>8}  {}",
                        s.id,
                        s.state.as_str(),
                        format!("{}/{}", s.stored, s.planned),
                        s.percent,
                        s.stage,
                        s.eta_s.map_or("-".into(), crate::report::format_hms),
                        s.name
                    );
                }
            }
        }
    }
    Ok(ExitCode::SUCCESS)
}

pub fn watch(a: WatchArgs) -> CliResult {
    let c = Client::new(&a.conn);
    follow(&c, a.id, a.samples, a.conn.json, a.progress_s)
}

/// Seconds between `watch`'s progress lines unless `--progress-s` says otherwise.
const DEFAULT_PROGRESS_S: f64 = 5.0;

/// `progress 12/80 samples (15.0 %), elapsed 0:00:03, ETA 0:00:17`.
fn progress_line(s: &CampaignStatus) -> String {
    let hms = |v: Option<f64>| v.map_or("-".to_string(), crate::report::format_hms);
    format!(
        "progress {}/{} samples ({:.1} %), elapsed {}, ETA {}",
        s.stored,
        s.planned,
        s.percent,
        hms(s.elapsed_s),
        hms(s.eta_s)
    )
}

/// One server-sent event as received.
#[derive(Default)]
struct Sse {
    id: Option<i64>,
    kind: String,
    data: String,
}

/// Reads server-sent events from `r`, calling `each` per event; returns the last event id.
fn read_sse(
    r: impl std::io::Read,
    mut each: impl FnMut(&Sse),
) -> (Option<i64>, std::io::Result<()>) {
    let mut last = None;
    let mut cur = Sse::default();
    for l in BufReader::new(r).lines() {
        let l = match l {
            Ok(l) => l,
            Err(e) => return (last, Err(e)),
        };
        if l.is_empty() {
            if !cur.data.is_empty() || !cur.kind.is_empty() {
                if cur.id.is_some() {
                    last = cur.id;
                }
                each(&cur);
            }
            cur = Sse::default();
            continue;
        }
        if l.starts_with(':') {
            continue; // keep-alive comment
        }
        let (field, value) = l.split_once(':').unwrap_or((&l, ""));
        let value = value.strip_prefix(' ').unwrap_or(value);
        match field {
            "event" => cur.kind = value.to_string(),
            "id" => cur.id = value.parse().ok(),
            "data" => {
                if !cur.data.is_empty() {
                    cur.data.push('\n');
                }
                cur.data.push_str(value);
            }
            _ => {}
        }
    }
    (last, Ok(()))
}

fn describe(e: &Value) -> String {
    let kind = e["kind"].as_str().unwrap_or("");
    let d = &e["data"];
    match kind {
        "sample" => {
            let t = &d["target"];
            let f = |v: &Value| v.as_f64().unwrap_or(f64::NAN);
            format!(
                "sample seq {} at ({:.3}, {:.3}) µm: error x {:+.3} µm, y {:+.3} µm",
                t["seq"],
                f(&t["target_x_um"]),
                f(&t["target_y_um"]),
                f(&d["meas_x_um"]) - f(&t["target_x_um"]),
                f(&d["meas_y_um"]) - f(&t["target_y_um"]),
            )
        }
        // The summary rides on the final event; one line of it here, all of it in `report`.
        "finished" if d.get("summary").is_some() => {
            let t = &d["summary"]["total"];
            let pct = |v: &Value| v.as_f64().map_or("-".to_string(), |p| format!("{p:.2} %"));
            format!(
                "finished {}: {} samples; acquisition saved {} (full scan {} measurements, CS {}); `csmetro report` for the files",
                d["state"].as_str().unwrap_or("?"),
                d["summary"]["samples"],
                pct(&t["acquisition_saved_pct"]),
                t["full"]["measurements"],
                t["cs"]["measurements"],
            )
        }
        _ => format!("{kind} {d}"),
    }
}

/// Follows a campaign's events until the service ends the stream, reconnecting (from the last
/// event id) while the campaign is still live, e.g. across a service restart. The exit code
/// comes from the final state: done 0, aborted 130, anything else 1.
fn follow(c: &Client, id: i64, samples: bool, json: bool, progress_s: f64) -> CliResult {
    let mut after: i64 = 0;
    // Samples not printed one by one are summed up in a progress line now and then.
    let progress = !samples && !json;
    let mut last_progress = Instant::now();
    let mut down_since: Option<Instant> = None;
    loop {
        let url = c.url(&format!("/campaigns/{id}/events?after={after}"));
        let r = c
            .auth(c.agent.get(&url))
            .header("Accept", "text/event-stream")
            .call();
        match r {
            Ok(resp) if resp.status().is_success() => {
                down_since = None;
                let (last, _) = read_sse(resp.into_body().into_reader(), |e| {
                    if e.kind == "sample" && progress {
                        if last_progress.elapsed().as_secs_f64() >= progress_s {
                            last_progress = Instant::now();
                            // A missed line is no reason to stop following.
                            if let Ok(st) = c.status(id) {
                                outln!("{}", progress_line(&st));
                            }
                        }
                        return;
                    }
                    // stdout is line-buffered: each event reaches a pipe as it comes.
                    if json {
                        outln!("{}", e.data);
                    } else {
                        let v: Value = serde_json::from_str(&e.data).unwrap_or(Value::Null);
                        outln!("{}", describe(&v));
                    }
                });
                if let Some(l) = last {
                    after = after.max(l);
                }
            }
            Ok(resp) => {
                let reply = c.reply(Ok(resp));
                return Err(match reply {
                    Err(e) => e,
                    Ok(_) => CliError::failure("unexpected answer from the service"),
                });
            }
            Err(e) => {
                // The service may be restarting: it resumes the campaign, we follow it again.
                let since = *down_since.get_or_insert_with(Instant::now);
                if since.elapsed() > Duration::from_secs(60) {
                    return Err(c.unreachable(e));
                }
                std::thread::sleep(Duration::from_millis(500));
                continue;
            }
        }
        let st = match c.status(id) {
            Ok(st) => st,
            Err(e) if e.code == 1 => {
                std::thread::sleep(Duration::from_millis(500));
                down_since.get_or_insert_with(Instant::now);
                continue;
            }
            Err(e) => return Err(e),
        };
        if matches!(
            st.state,
            CampaignState::Queued | CampaignState::Running | CampaignState::Paused
        ) {
            continue;
        }
        eprintln!("{}", line(&st));
        return Ok(match st.state {
            CampaignState::Done => ExitCode::SUCCESS,
            CampaignState::Aborted => ExitCode::from(130),
            _ => ExitCode::FAILURE,
        });
    }
}

fn control(a: IdArgs, action: &str) -> CliResult {
    let c = Client::new(&a.conn);
    let st: CampaignStatus = json_of(&c.post_empty(&format!("/campaigns/{}/{action}", a.id))?)?;
    if a.conn.json {
        print_json(&st);
    } else {
        outln!("{}", line(&st));
    }
    Ok(ExitCode::SUCCESS)
}

/// Holds a running campaign between two points.
pub fn pause(a: IdArgs) -> CliResult {
    control(a, "pause")
}

/// Continues a paused campaign, or queues an interrupted one again on the service.
pub fn unpause(a: IdArgs) -> CliResult {
    control(a, "resume")
}

/// Aborts a campaign and waits (up to `--wait-s`) until it has stopped motion and ended.
pub fn abort(a: AbortArgs) -> CliResult {
    let c = Client::new(&a.conn);
    let mut st: CampaignStatus = json_of(&c.post_empty(&format!("/campaigns/{}/abort", a.id))?)?;
    let t0 = Instant::now();
    while !st.state.is_final() && t0.elapsed().as_secs_f64() < a.wait_s {
        std::thread::sleep(Duration::from_millis(200));
        st = c.status(a.id)?;
    }
    if a.conn.json {
        print_json(&st);
    } else {
        outln!("{}", line(&st));
    }
    if a.wait_s > 0.0 && !st.state.is_final() {
        return Err(CliError::failure(format!(
            "campaign {} did not stop within {} s",
            a.id, a.wait_s
        )));
    }
    Ok(ExitCode::SUCCESS)
}

/// A result name as a relative path inside the report directory (no `..`, not absolute).
fn safe_relative(name: &str) -> Option<PathBuf> {
    let p = Path::new(name);
    let ok = !name.is_empty() && p.components().all(|c| matches!(c, Component::Normal(_)));
    ok.then(|| p.to_path_buf())
}

/// Downloads every result of a campaign into a directory.
pub fn report(a: ReportArgs) -> CliResult {
    let c = Client::new(&a.conn);
    let st = c.status(a.id)?;
    let list: Value = json_of(&c.get(&format!("/campaigns/{}/results", a.id))?)?;
    let names: Vec<String> = list["results"]
        .as_array()
        .map(|v| {
            v.iter()
                .filter_map(|n| n.as_str().map(str::to_string))
                .collect()
        })
        .unwrap_or_default();
    let dir = a
        .out
        .unwrap_or_else(|| PathBuf::from(format!("csmetro-report-{}", a.id)));
    let mut written = Vec::new();
    for name in &names {
        let Some(rel) = safe_relative(name) else {
            eprintln!("warning: skipped result {name:?}: not a plain relative file name");
            continue;
        };
        let r = c.get(&format!("/campaigns/{}/results/{name}", a.id))?;
        let path = dir.join(rel);
        if let Some(d) = path.parent() {
            std::fs::create_dir_all(d)
                .map_err(|e| CliError::failure(format!("{}: {e}", d.display())))?;
        }
        std::fs::write(&path, &r.body)
            .map_err(|e| CliError::failure(format!("{}: {e}", path.display())))?;
        written.push(json!({"name": name, "path": path, "bytes": r.body.len(), "content_type": r.content_type}));
    }
    if a.conn.json {
        print_json(&json!({"id": a.id, "state": st.state.as_str(), "dir": dir, "files": written}));
    } else {
        for w in &written {
            outln!("{}", w["path"].as_str().unwrap_or(""));
        }
        eprintln!(
            "{} result(s) of campaign {} ({}) in {}",
            written.len(),
            a.id,
            st.state.as_str(),
            dir.display()
        );
        if names.iter().any(|n| n == "report.html") {
            eprintln!("report: {}", dir.join("report.html").display());
        }
    }
    if names.is_empty() && st.state != CampaignState::Done {
        return Err(CliError::failure(format!(
            "campaign {} is {}: no results yet",
            a.id,
            st.state.as_str()
        )));
    }
    Ok(ExitCode::SUCCESS)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sse_frames_are_split_on_blank_lines_and_keep_their_id() {
        let text = ": keep-alive\n\nevent: started\nid: 7\ndata: {\"a\":1}\n\nevent: sample\ndata: {\"b\":2}\n\n";
        let mut got = Vec::new();
        let (last, r) = read_sse(text.as_bytes(), |e| {
            got.push((e.kind.clone(), e.id, e.data.clone()))
        });
        assert!(r.is_ok());
        assert_eq!(last, Some(7));
        assert_eq!(
            got,
            vec![
                ("started".to_string(), Some(7), "{\"a\":1}".to_string()),
                ("sample".to_string(), None, "{\"b\":2}".to_string()),
            ]
        );
    }

    #[test]
    fn result_names_cannot_escape_the_report_directory() {
        assert_eq!(
            safe_relative("curves/a.csv"),
            Some(PathBuf::from("curves/a.csv"))
        );
        assert_eq!(safe_relative("../etc/passwd"), None);
        assert_eq!(safe_relative("/etc/passwd"), None);
        assert_eq!(safe_relative("a/./b"), Some(PathBuf::from("a/b")));
        assert_eq!(safe_relative(""), None);
    }
}
