//! Inputs that used to crash or hang the command line: each is now a one-line error, exit 2,
//! in bounded time, and nothing moves or is stored.
use crate::common;

use std::path::Path;
use std::process::Output;
use std::time::{Duration, Instant};

use common::{bin, repo};

fn run(args: &[&str], dir: &Path) -> (Output, Duration) {
    let t0 = Instant::now();
    let o = bin().args(args).current_dir(dir).output().unwrap();
    (o, t0.elapsed())
}

fn input_error(o: &Output, needle: &str) -> String {
    let err = String::from_utf8_lossy(&o.stderr).into_owned();
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(err.contains(needle), "expected {needle:?} in {err}");
    assert!(!err.contains("panicked"), "{err}");
    err
}

fn campaign_file(dir: &Path, edit: impl Fn(String) -> String) -> String {
    let t = std::fs::read_to_string(repo("config/campaigns/demo-sim.toml")).unwrap();
    let t = t.replace(
        "../sim/demo_xy.toml",
        &repo("config/sim/demo_xy.toml").display().to_string(),
    );
    let p = dir.join("c.toml");
    std::fs::write(&p, edit(t)).unwrap();
    p.display().to_string()
}

#[test]
fn a_campaign_with_a_tiny_step_is_refused_not_aborted() {
    let dir = tempfile::tempdir().unwrap();
    let db = dir.path().join("c.db").display().to_string();
    let f = campaign_file(dir.path(), |t| {
        t.replacen("step_um = 5.0", "step_um = 1e-7", 1)
    });
    let (o, took) = run(&["run", &f, "--db", &db, "--quiet"], dir.path());
    let err = input_error(&o, "axes.x.range_um");
    assert!(err.contains("c.toml:"), "{err}");
    assert!(took < Duration::from_secs(20), "{took:?}");
}

#[test]
fn an_unwritable_output_directory_is_refused_before_anything_runs() {
    let dir = tempfile::tempdir().unwrap();
    let db = dir.path().join("c.db").display().to_string();
    let f = campaign_file(dir.path(), |t| {
        t.replace(
            "dir = \"csmetro-results/{name}-{id}\"",
            "dir = \"/proc/csmetro/{name}-{id}\"",
        )
    });
    let (o, _) = run(&["run", &f, "--db", &db, "--quiet"], dir.path());
    input_error(&o, "outputs.dir");
    assert!(!Path::new(&db).exists(), "nothing stored");
}

#[test]
fn a_model_that_is_a_device_is_refused_at_once() {
    let dir = tempfile::tempdir().unwrap();
    let db = dir.path().join("c.db").display().to_string();
    let f = campaign_file(dir.path(), |t| {
        t.replace(
            &repo("config/sim/demo_xy.toml").display().to_string(),
            "/dev/zero",
        )
    });
    let (o, took) = run(&["run", &f, "--db", &db, "--quiet"], dir.path());
    input_error(&o, "hardware.sim.model");
    assert!(took < Duration::from_secs(20), "{took:?}");
}

#[test]
fn reconstruct_refuses_grids_too_large_to_solve() {
    let dir = tempfile::tempdir().unwrap();
    let s = dir.path().join("s.csv");
    std::fs::write(&s, "position_um,error_um\n0,1\n5,2\n10,0\n").unwrap();
    let s = s.display().to_string();
    for (grid, method) in [
        ("0:1e-7:9500", "auto"),
        ("0:0.001:9500", "bp"),
        // Below the grid limit but too large to solve in bounded time.
        ("0:0.1:9500", "bp"),
        ("0:0.01:9500", "auto"),
    ] {
        let (o, took) = run(
            &[
                "reconstruct",
                "--grid",
                grid,
                "--method",
                method,
                "--samples",
                &s,
            ],
            dir.path(),
        );
        input_error(&o, "--grid");
        assert!(took < Duration::from_secs(10), "{grid}: {took:?}");
    }
}

/// A simulated stage is locked in its store only: while a run on store a drives `sim-xy`, a
/// move of `sim-xy` on store b (another user's demo on the same machine) goes ahead, and one
/// on store a is still refused. Real ports keep the machine-wide lock (stagelock's tests).
#[test]
fn two_stores_each_drive_their_simulated_stage_at_once() {
    use std::io::{BufRead, BufReader};
    let dir = tempfile::tempdir().unwrap();
    let f = campaign_file(dir.path(), |t| t);
    let db = |n: &str| dir.path().join(n).display().to_string();
    // Both processes share this test's lock directory (bin() sets it), as two processes on one
    // machine share /run/lock.
    let mut a = bin()
        .args(["run", &f, "--db", &db("a.db"), "--quiet"])
        .current_dir(dir.path())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    // Its first line: the campaign is stored, so the stage is taken.
    let mut line = String::new();
    BufReader::new(a.stderr.take().unwrap())
        .read_line(&mut line)
        .unwrap();
    assert!(line.contains("stored in"), "{line}");
    let mv = |store: &str| {
        run(
            &[
                "move",
                "--stage",
                "sim-xy",
                "--x-um",
                "100",
                "--json",
                "--db",
                &db(store),
            ],
            dir.path(),
        )
        .0
    };
    let other = mv("b.db");
    let same = mv("a.db");
    a.kill().unwrap();
    a.wait().unwrap();
    let err = String::from_utf8_lossy(&other.stderr);
    assert_eq!(other.status.code(), Some(0), "{err}");
    let err = String::from_utf8_lossy(&same.stderr);
    assert_eq!(same.status.code(), Some(1), "{err}");
    assert!(err.contains("driven by another csmetro process"), "{err}");
}
