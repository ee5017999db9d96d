//! `csmetro submit|status|watch|pause|unpause|abort|report` against a running `csmetro serve`.
use crate::common;

use std::path::Path;
use std::process::Output;

use common::{bin, campaign, Server};
use serde_json::Value;

fn cli(srv: &Server, args: &[&str]) -> Output {
    let mut c = bin();
    c.args(args)
        .env("CSMETRO_SERVER", &srv.url)
        .env_remove("CSMETRO_TOKEN");
    if let Some(t) = &srv.token {
        c.env("CSMETRO_TOKEN", t);
    }
    c.output().unwrap()
}

fn ok(o: &Output) -> String {
    assert!(
        o.status.success(),
        "exit {:?}\nstdout: {}\nstderr: {}",
        o.status.code(),
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    );
    String::from_utf8(o.stdout.clone()).unwrap()
}

fn write(dir: &Path, name: &str, text: &str) -> String {
    let p = dir.join(name);
    std::fs::write(&p, text).unwrap();
    p.display().to_string()
}

#[test]
fn submit_watch_status_and_report_a_campaign() {
    let dir = tempfile::tempdir().unwrap();
    let srv = Server::start(dir.path(), None);
    let file = write(
        dir.path(),
        "quick.toml",
        &campaign("quick", "s1", 20, 1000.0),
    );
    let out = ok(&cli(&srv, &["submit", &file]));
    let id: i64 = out.trim().parse().expect("submit prints the id");

    let w = cli(&srv, &["watch", &id.to_string()]);
    let text = ok(&w);
    assert!(text.lines().any(|l| l.starts_with("started ")), "{text}");
    assert!(
        text.lines().last().unwrap().starts_with("finished "),
        "{text}"
    );
    assert!(!text.contains("sample seq"), "samples only with --samples");
    assert!(String::from_utf8_lossy(&w.stderr).contains("done 40/40"));

    let st: Value =
        serde_json::from_str(&ok(&cli(&srv, &["status", &id.to_string(), "--json"]))).unwrap();
    assert_eq!(
        (st["state"].as_str(), st["stored"].as_u64()),
        (Some("done"), Some(40))
    );
    let line = ok(&cli(&srv, &["status", &id.to_string()]));
    assert!(line.contains("done 40/40 (100.0 %)"), "{line}");
    let table = ok(&cli(&srv, &["status"]));
    assert!(table.lines().nth(1).unwrap().contains("quick"), "{table}");

    // Every result, byte for byte as the API serves it.
    let out_dir = dir.path().join("report");
    let rep: Value = serde_json::from_str(&ok(&cli(
        &srv,
        &[
            "report",
            &id.to_string(),
            "--out",
            out_dir.to_str().unwrap(),
            "--json",
        ],
    )))
    .unwrap();
    let files = rep["files"].as_array().unwrap();
    let (_, list) = srv.get(&format!("/campaigns/{id}/results"));
    assert_eq!(files.len(), list["results"].as_array().unwrap().len());
    for f in files {
        let name = f["name"].as_str().unwrap();
        let on_disk = std::fs::read(out_dir.join(name)).unwrap();
        let (_, served, _) = srv.request(
            "GET",
            &format!("/campaigns/{id}/results/{name}"),
            None,
            None,
        );
        assert_eq!(on_disk, served, "{name}");
    }
    assert!(out_dir.join("summary.json").is_file());

    // JSON watch: one event object per line, samples included.
    let j = ok(&cli(&srv, &["watch", &id.to_string(), "--json"]));
    let evs: Vec<Value> = j
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    assert_eq!(evs.last().unwrap()["kind"], "finished");
}

#[test]
fn submit_watch_pause_unpause_and_abort() {
    let dir = tempfile::tempdir().unwrap();
    let srv = Server::start(dir.path(), None);
    let file = write(dir.path(), "slow.toml", &campaign("slow", "s1", 40, 10.0));
    let id: i64 = ok(&cli(&srv, &["submit", &file])).trim().parse().unwrap();
    let ids = id.to_string();
    srv.wait_for(id, 30.0, |s| s["stored"].as_u64() > Some(2));
    assert!(ok(&cli(&srv, &["pause", &ids])).contains(": paused"));
    assert!(ok(&cli(&srv, &["unpause", &ids])).contains(": running"));
    // Unpausing a running campaign is refused by the service (409 → exit 1).
    assert_eq!(cli(&srv, &["unpause", &ids]).status.code(), Some(1));

    let watcher = bin()
        .args(["watch", &ids])
        .env("CSMETRO_SERVER", &srv.url)
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let out = ok(&cli(&srv, &["abort", &ids]));
    assert!(
        out.contains(": aborted"),
        "abort waits until the campaign ended: {out}"
    );
    let w = watcher.wait_with_output().unwrap();
    assert_eq!(
        w.status.code(),
        Some(130),
        "{}",
        String::from_utf8_lossy(&w.stderr)
    );
    // Watching it afterwards gives the same verdict.
    assert_eq!(cli(&srv, &["watch", &ids]).status.code(), Some(130));
    // Report of an aborted campaign: no results, a failure.
    let r = cli(
        &srv,
        &[
            "report",
            &ids,
            "--out",
            dir.path().join("r").to_str().unwrap(),
        ],
    );
    assert_eq!(r.status.code(), Some(1));
}

#[test]
fn submit_with_watch_follows_to_the_end() {
    let dir = tempfile::tempdir().unwrap();
    let srv = Server::start(dir.path(), None);
    let file = write(dir.path(), "w.toml", &campaign("w", "s1", 20, 1000.0));
    let text = ok(&cli(&srv, &["submit", &file, "--watch", "--json"]));
    let evs: Vec<Value> = text
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    // Live samples are not in the log: those taken before the stream opened are not shown.
    let samples = evs.iter().filter(|e| e["kind"] == "sample").count();
    assert!((1..=40).contains(&samples), "{text}");
    assert_eq!(evs.last().unwrap()["kind"], "finished");
    assert_eq!(evs.last().unwrap()["data"]["state"], "done");
}

#[test]
fn errors_map_to_exit_codes_with_a_message() {
    let dir = tempfile::tempdir().unwrap();
    let srv = Server::start(dir.path(), Some("cli-token-0123456789abc"));
    let good = campaign("t", "s1", 20, 1000.0);
    let bad = good.replace("m = 20", "m = \"many\"");
    let line = bad.lines().position(|l| l.contains("many")).unwrap() + 1;
    let file = write(dir.path(), "bad.toml", &bad);

    let o = cli(&srv, &["submit", &file]);
    assert_eq!(o.status.code(), Some(2));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains(&format!("bad.toml:{line}: axes.x.m:")),
        "{err}"
    );

    // Missing or wrong token: refused by the service, reported as bad input.
    let good_file = write(dir.path(), "good.toml", &good);
    let o = bin()
        .args(["submit", &good_file, "--server", &srv.url])
        .env_remove("CSMETRO_TOKEN")
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("401"));
    let o = bin()
        .args([
            "status",
            "--server",
            &srv.url,
            "--token",
            "wrong-token-0123456789",
        ])
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2));

    assert_eq!(cli(&srv, &["status", "42"]).status.code(), Some(2));
    assert_eq!(
        cli(&srv, &["submit", "/no/such/file.toml"]).status.code(),
        Some(2)
    );

    // Nobody listening: a failure naming the address.
    let o = bin()
        .args(["status", "--server", "http://127.0.0.1:9"])
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&o.stderr)
        .contains("cannot reach the service at http://127.0.0.1:9"));
}
