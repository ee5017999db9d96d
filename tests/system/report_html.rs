//! `report.html` from the service: listed with the results, served as HTML, fetched by
//! `csmetro report`; and the service writes every campaign's results below its own
//! `results_dir`, also a foreground campaign with an absolute `[outputs] dir` that it finishes.
use crate::common;

use std::process::Command;
use std::time::{Duration, Instant};

use common::{bin, campaign, repo, Server};
use csmetro::store::Store;

fn state(v: &serde_json::Value) -> &str {
    v["state"].as_str().unwrap_or("")
}

#[test]
fn the_service_lists_serves_and_csmetro_report_fetches_report_html() {
    let dir = tempfile::tempdir().unwrap();
    let srv = Server::start(dir.path(), None);
    let id = srv.submit(&campaign("html", "s1", 5, 1000.0));
    srv.wait_for(id, 60.0, |s| state(s) == "done");
    let (_, list) = srv.get(&format!("/campaigns/{id}/results"));
    let names: Vec<&str> = list["results"]
        .as_array()
        .unwrap()
        .iter()
        .filter_map(|v| v.as_str())
        .collect();
    for want in ["report.html", "plots/iso230_x.svg", "plots/iso230_x.png"] {
        assert!(names.contains(&want), "{want} not in {names:?}");
    }
    let (s, body, ctype) = srv.request(
        "GET",
        &format!("/campaigns/{id}/results/report.html"),
        None,
        None,
    );
    assert_eq!(s, 200);
    assert!(ctype.starts_with("text/html"), "{ctype}");
    let html = String::from_utf8(body).unwrap();
    assert!(html.contains(&format!("csmetro campaign {id} — html")));
    // Written below the service's results_dir too, in a folder marked as this campaign's.
    let folder = dir.path().join(format!("var/results/html-{id}"));
    assert_eq!(
        std::fs::read_to_string(folder.join("report.html")).unwrap(),
        html
    );
    assert!(folder.join(".csmetro-results.json").is_file());

    let out = dir.path().join("fetched");
    let o = bin()
        .args(["report", &id.to_string(), "--out", out.to_str().unwrap()])
        .env("CSMETRO_SERVER", &srv.url)
        .env_remove("CSMETRO_TOKEN")
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    assert_eq!(
        std::fs::read_to_string(out.join("report.html")).unwrap(),
        html
    );
    assert!(
        err.contains(&format!("report: {}", out.join("report.html").display())),
        "{err}"
    );
}

#[test]
fn a_foreground_campaign_the_service_finishes_writes_below_its_results_dir() {
    let dir = tempfile::tempdir().unwrap();
    let db = dir.path().join("var/csmetro.db");
    let elsewhere = dir.path().join("elsewhere");
    let text = campaign("fg", "s1", 20, 10.0)
        .replace(
            "model = \"ideal.toml\"",
            &format!("model = \"{}\"", repo("config/sim/ideal.toml").display()),
        )
        .replace(
            "dir = \"fg-{id}\"",
            &format!("dir = \"{}/fg-{{id}}\"", elsewhere.display()),
        );
    let file = dir.path().join("fg.toml");
    std::fs::write(&file, text).unwrap();
    let mut child = bin()
        .args(["run", "--quiet", "--db"])
        .arg(&db)
        .arg(&file)
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let t0 = Instant::now();
    while !(db.exists() && Store::open(&db).unwrap().sample_count(1).unwrap_or(0) >= 3) {
        assert!(
            child.try_wait().unwrap().is_none(),
            "ended before 3 samples"
        );
        assert!(t0.elapsed() < Duration::from_secs(60), "no progress");
        std::thread::sleep(Duration::from_millis(20));
    }
    // SIGTERM: motion stops, the campaign stays resumable; the service takes it up at start.
    assert!(Command::new("kill")
        .args(["-TERM", &child.id().to_string()])
        .status()
        .unwrap()
        .success());
    child.wait().unwrap();
    let srv = Server::start(dir.path(), None);
    srv.wait_for(1, 120.0, |s| state(s) == "done");
    let mine = dir.path().join("var/results/fg-1");
    assert!(mine.join("summary.json").is_file(), "{}", srv.log());
    assert!(
        !elsewhere.join("fg-1").exists(),
        "the service wrote outside its results_dir"
    );
}
