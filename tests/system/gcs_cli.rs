//! `csmetro sim` commands around the GCS driver: the soak and the bench report bound replies,
//! and a killed simulator's pty link is cleaned up by the next one.
use std::io::{BufRead, BufReader};
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

const BIN: &str = env!("CARGO_BIN_EXE_csmetro");

fn run_json(args: &[&str]) -> serde_json::Value {
    let out = Command::new(BIN).args(args).output().unwrap();
    assert!(
        out.status.success(),
        "{args:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).unwrap()
}

#[test]
fn soak_gcs_reports_faults_recoveries_and_no_stale_answer() {
    let v = run_json(&["sim", "soak-gcs", "--commands", "300", "--seed", "5"]);
    assert_eq!(v["commands"], 300);
    assert_eq!(v["stale_accepted"], 0, "{v}");
    assert_eq!(v["misaligned"], 0, "{v}");
    for k in ["delay", "drop", "garbage", "error", "vanish"] {
        assert!(v["faults_injected"][k].is_u64(), "{k}: {v}");
    }
    for k in [
        "retries",
        "resyncs",
        "errors_returned",
        "answers_checked",
        "wall_s",
    ] {
        assert!(v[k].is_number(), "{k}: {v}");
    }
    let bad = Command::new(BIN)
        .args(["sim", "soak-gcs", "--commands", "0"])
        .output()
        .unwrap();
    assert!(!bad.status.success());
}

#[test]
fn bench_gcs_with_three_late_replies_takes_no_stale_answer() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = dir.path().join("sim.toml");
    std::fs::write(
        &cfg,
        "time_scale = 100\n[[controller.faults]]\nkind = \"delay_reply\"\nms = 800\ncount = 3\nafter_commands = 20\n",
    )
    .unwrap();
    let v = run_json(&[
        "sim",
        "bench-gcs",
        "--config",
        cfg.to_str().unwrap(),
        "--round-trips",
        "40",
        "--moves",
        "2",
    ]);
    let b = &v["binding"];
    assert_eq!(b["faults_injected"]["delay"], 3, "{v}");
    assert_eq!(b["stale_accepted"], 0, "{v}");
    assert_eq!(b["misaligned"], 0, "{v}");
    assert!(v["link"]["resyncs"].as_u64().unwrap() >= 2, "{v}");
    assert_eq!(v["sequence"]["time_scale"], 100.0, "the file's time scale");
}

fn start_pty_sim() -> (std::process::Child, String) {
    let mut child = Command::new(BIN)
        .args(["sim", "controller", "--pty"])
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let mut line = String::new();
    BufReader::new(child.stdout.take().unwrap())
        .read_line(&mut line)
        .unwrap();
    (child, line.trim().to_string())
}

fn wait_gone(path: &str) -> bool {
    let t = Instant::now();
    while t.elapsed() < Duration::from_secs(5) {
        if Path::new(path).symlink_metadata().is_err() {
            return true;
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    false
}

#[test]
fn a_killed_simulators_pty_link_is_removed_by_the_next_one() {
    let (mut first, link1) = start_pty_sim();
    assert!(Path::new(&link1).symlink_metadata().is_ok(), "{link1}");
    first.kill().unwrap(); // SIGKILL: no chance to clean up
    first.wait().unwrap();
    assert!(
        Path::new(&link1).symlink_metadata().is_ok(),
        "kill -9 leaves the link"
    );
    let (mut second, link2) = start_pty_sim();
    assert_ne!(link1, link2);
    assert!(wait_gone(&link1), "stale link {link1} removed at start");
    assert!(Path::new(&link2).symlink_metadata().is_ok());
    Command::new("kill")
        .args(["-TERM", &second.id().to_string()])
        .status()
        .unwrap();
    second.wait().unwrap();
    assert!(wait_gone(&link2), "its own link removed on shutdown");
}

#[test]
fn sim_controller_refuses_bad_random_faults_naming_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = dir.path().join("sim.toml");
    std::fs::write(
        &cfg,
        "[controller.random_faults]\nseed = 1\ndrop_rate = 2.0\n",
    )
    .unwrap();
    let out = Command::new(BIN)
        .args([
            "sim",
            "controller",
            "--pty",
            "--config",
            cfg.to_str().unwrap(),
        ])
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("sim.toml") && err.contains("drop_rate"),
        "{err}"
    );
    let out = Command::new(BIN)
        .args(["sim", "controller", "--pty", "--fault-seed", "3"])
        .output()
        .unwrap();
    assert!(!out.status.success(), "--fault-seed without random faults");
    assert!(String::from_utf8_lossy(&out.stderr).contains("random_faults"));
}

#[test]
fn sim_time_scales_outside_the_sane_range_are_refused() {
    // 1e-300 passed before: a simulator whose reference move never ends.
    for scale in ["1e-300", "0.0001", "1e7", "NaN"] {
        let out = Command::new(BIN)
            .args(["sim", "controller", "--pty", "--time-scale", scale])
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "--time-scale {scale}: {err}");
        assert!(
            err.contains("--time-scale: must be in [1e-3, 1e6]"),
            "--time-scale {scale}: {err}"
        );
    }
    let dir = tempfile::tempdir().unwrap();
    let cfg = dir.path().join("sim.toml");
    std::fs::write(&cfg, "# simulator\ntime_scale = 1e-300\n").unwrap();
    let out = Command::new(BIN)
        .args(["sim", "controller", "--pty", "--config"])
        .arg(&cfg)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(
        err.contains("sim.toml:2: time_scale: must be in [1e-3, 1e6]"),
        "{err}"
    );
    let rig = dir.path().join("rig.toml");
    std::fs::write(
        &rig,
        "time_scale = 1e-300\n[x]\ntcp = \"127.0.0.1:0\"\n[y]\ntcp = \"127.0.0.1:0\"\n",
    )
    .unwrap();
    let out = Command::new(BIN)
        .args(["sim", "rig", "--config"])
        .arg(&rig)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(
        err.contains("rig.toml:1: time_scale: must be in [1e-3, 1e6]"),
        "{err}"
    );
}
