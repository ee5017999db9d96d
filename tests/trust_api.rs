//! A submitted campaign is untrusted: it names files only inside the service's campaign and
//! model directories, writes only below its results directory, and its errors show neither a
//! file's content nor a server path.
mod common;

use std::path::Path;
use std::time::{Duration, Instant};

use common::{campaign, repo, Server};

const SECRET: &str = "hunter2-do-not-show";

/// A service whose submitted campaigns resolve in `dir/campaigns` (with `ideal.toml` in it), and
/// secrets beside it: `dir/token`, `dir/secret.toml` (valid TOML), `dir/campaigns/bad.toml`
/// (not TOML), links out of the directory.
fn service(dir: &Path) -> Server {
    let camp = dir.join("campaigns");
    std::fs::create_dir_all(&camp).unwrap();
    std::fs::copy(repo("config/sim/ideal.toml"), camp.join("ideal.toml")).unwrap();
    std::fs::write(dir.join("token"), format!("{SECRET}\n")).unwrap();
    std::fs::write(
        dir.join("secret.toml"),
        format!("password = \"{SECRET}\"\n"),
    )
    .unwrap();
    std::fs::write(camp.join("bad.toml"), format!("{SECRET} root:x:0:0\n")).unwrap();
    std::os::unix::fs::symlink(dir.join("secret.toml"), camp.join("link.toml")).unwrap();
    std::os::unix::fs::symlink("/dev/zero", camp.join("zero.toml")).unwrap();
    std::fs::write(
        dir.join("csmetro.toml"),
        "[server]\nbind = \"127.0.0.1:0\"\n\n[storage]\ndb = \"var/csmetro.db\"\n\
         results_dir = \"var/results\"\n\n[campaigns]\nbase_dir = \"campaigns\"\n",
    )
    .unwrap();
    Server::start(dir, None)
}

fn with_model(model: &str) -> String {
    campaign("t", "s1", 5, 1000.0).replace("model = \"ideal.toml\"", &format!("model = {model:?}"))
}

/// Submits `text`; asserts a 400 that names the key and shows no secret and no server path.
fn refused(srv: &Server, dir: &Path, text: &str, key: &str) -> String {
    let (status, body, _) =
        srv.request("POST", "/campaigns", Some(("application/toml", text)), None);
    let body = String::from_utf8_lossy(&body).into_owned();
    assert_eq!(status, 400, "{body}");
    assert!(body.contains(key), "{body}");
    assert!(!body.contains(SECRET) && !body.contains("root:"), "{body}");
    for leak in [
        dir.display().to_string(),
        "/etc/".into(),
        "/dev/".into(),
        "/proc".into(),
    ] {
        assert!(!body.contains(&leak), "server path {leak} in {body}");
    }
    body
}

/// Peak resident memory of a process, kB.
fn peak_rss_kb(pid: u32) -> u64 {
    let s = std::fs::read_to_string(format!("/proc/{pid}/status")).unwrap();
    s.lines()
        .find_map(|l| l.strip_prefix("VmHWM:"))
        .and_then(|v| v.trim().trim_end_matches("kB").trim().parse().ok())
        .unwrap()
}

#[test]
fn submitted_models_stay_inside_the_allowed_directories() {
    let dir = tempfile::tempdir().unwrap();
    let srv = service(dir.path());
    let m = "hardware.sim.model";
    for model in [
        "/etc/passwd",
        "/etc/shadow",
        "/proc/self/environ",
        "../token",
        "../secret.toml",
        "./../secret.toml",
        "sub/../../secret.toml",
        "link.toml",
        "bad.toml",
        "missing.toml",
        "campaigns",
    ] {
        let b = refused(&srv, dir.path(), &with_model(model), m);
        assert!(!b.contains("password"), "{model}: {b}");
    }
    let abs = dir.path().join("secret.toml").display().to_string();
    refused(&srv, dir.path(), &with_model(&abs), m);

    // A model inside the directory is fine.
    let (status, v) = srv.post(
        "/campaigns",
        Some(("application/toml", &with_model("ideal.toml"))),
    );
    assert_eq!(status, 201, "{v}");
}

#[test]
fn dev_zero_is_refused_at_once_without_growing_the_service() {
    let dir = tempfile::tempdir().unwrap();
    let srv = service(dir.path());
    for model in ["/dev/zero", "zero.toml"] {
        let t0 = Instant::now();
        refused(&srv, dir.path(), &with_model(model), "hardware.sim.model");
        assert!(
            t0.elapsed() < Duration::from_secs(5),
            "{model}: {:?}",
            t0.elapsed()
        );
    }
    let kb = peak_rss_kb(srv.child.id());
    assert!(kb < 300_000, "service peak RSS {kb} kB");
}

#[test]
fn submitted_outputs_stay_below_the_results_directory() {
    let dir = tempfile::tempdir().unwrap();
    let srv = service(dir.path());
    let good = with_model("ideal.toml");
    let outside = dir.path().join("elsewhere");
    for out in [
        "../../x/{name}-{id}".to_string(),
        "/tmp/x-{id}".into(),
        format!("{}/{{id}}", outside.display()),
        "a/../../b".into(),
        "/proc/x".into(),
    ] {
        let t = good.replace("dir = \"t-{id}\"", &format!("dir = {out:?}"));
        assert_ne!(t, good);
        refused(&srv, dir.path(), &t, "outputs.dir");
    }
    assert!(!outside.exists());
    assert!(!dir.path().join("x").exists());
}

#[test]
fn submitted_names_are_bounded_and_plain() {
    let dir = tempfile::tempdir().unwrap();
    let srv = service(dir.path());
    let good = with_model("ideal.toml");
    let long = "s".repeat(300);
    let t = good.replace("stage = \"s1\"", &format!("stage = {long:?}"));
    refused(&srv, dir.path(), &t, "campaign.stage");
    // `{name}` expands in the output directory: it may not climb out of it.
    let t = good.replace("name = \"t\"", "name = \"..\"");
    refused(&srv, dir.path(), &t, "campaign.name");
    let t = good.replace("name = \"t\"", "name = \"a/../../x\"");
    refused(&srv, dir.path(), &t, "campaign.name");
}

/// A stage lock that cannot be taken for an I/O reason (here a directory stands where the lock
/// file goes) is not "another process drives the stage": the campaign ends interrupted with the
/// reason at once, no server path in it, instead of waiting in the queue for ever.
#[test]
fn a_stage_lock_io_error_interrupts_instead_of_waiting_forever() {
    let dir = tempfile::tempdir().unwrap();
    let s = service(dir.path());
    // A simulated stage is locked in its store only (see stagelock): its lock file there is
    // made unusable.
    let lock = csmetro::campaign::stagelock::lock_path(&s.db(), "s1");
    std::fs::create_dir_all(&lock).unwrap();
    let id = s.submit(&campaign("t", "s1", 5, 1000.0));
    let st = s.wait_for(id, 20.0, |st| st["state"] == "interrupted");
    let msg = st["message"].as_str().unwrap_or_default().to_string();
    assert!(msg.contains("cannot take the lock of stage"), "{st}");
    assert!(!msg.contains("stage-s1.lock"), "server path shown: {msg}");
    std::fs::remove_dir(&lock).unwrap();
}

/// What was validated is what runs: the stage model is read once, at submission, and stored
/// with the campaign. A file swapped in while the campaign waits (here: a link to a secret
/// outside the allowed directories) is never read; the campaign runs the model it was
/// validated with. It used to be read again at start by a loader without the confinement.
#[test]
fn a_model_swapped_after_submission_is_not_what_runs() {
    std::env::set_var("CSMETRO_LOCK_DIR", common::test_lock_dir());
    let dir = tempfile::tempdir().unwrap();
    let srv = service(dir.path());
    let camp = dir.path().join("campaigns");
    std::fs::copy(camp.join("ideal.toml"), camp.join("mine.toml")).unwrap();
    // Another process drives the stage: the campaign waits in the queue after validation.
    let lock = csmetro::campaign::stagelock::try_lock(&srv.db(), "s1").unwrap();
    let id = srv.submit(&with_model("mine.toml"));
    std::fs::remove_file(camp.join("mine.toml")).unwrap();
    std::os::unix::fs::symlink(dir.path().join("secret.toml"), camp.join("mine.toml")).unwrap();
    drop(lock);
    let st = srv.wait_for(id, 60.0, |s| {
        matches!(s["state"].as_str(), Some("done" | "interrupted" | "failed"))
    });
    assert_eq!(st["state"], "done", "{st}\n{}", srv.log());
    let stored = csmetro::store::Store::open(&srv.db())
        .unwrap()
        .model_snapshot(id)
        .unwrap()
        .unwrap();
    assert_eq!(
        stored,
        std::fs::read_to_string(repo("config/sim/ideal.toml")).unwrap()
    );
    assert!(!srv.log().contains(SECRET));
}
