//! Abort and stop reach the stage within 0.5 s in every phase, at time scale 1 (physical time is
//! wall time): Ctrl-C (SIGINT) and SIGTERM to `csmetro run`, the API's abort and the service's
//! shutdown, each sent while an axis references, while it moves, and while the engine settles.
//! The simulated controllers write every command they handle to a trace
//! (`CSMETRO_SIM_TRACE`, with the axis state after it), so the latency is the controller's: the
//! time from the request to the stop command's arrival, where the axis must be at rest; no
//! motion command may come after the request, and the campaign ends as the request says.
//!
//! `CSMETRO_STOP_TRIALS=20 cargo test --test stop_latency -- --nocapture` prints the median
//! and the largest latency over 20 trials per path and phase (default 2 trials).
mod common;

use std::path::{Path, PathBuf};
use std::process::Stdio;
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use common::{bin, repo, Server};

/// The bound: from the request to both axes' stop at the controller.
const MAX_LATENCY_S: f64 = 0.5;

fn unix_now() -> f64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .unwrap()
        .as_secs_f64()
}

fn trials() -> usize {
    std::env::var("CSMETRO_STOP_TRIALS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(2)
}

/// One X campaign at time scale 1 whose phases last long enough to be hit: the reference
/// switch at 1 mm (travel [-1, 3] mm), Y referenced from 0 mm (1 s at 1 mm/s), Y then moved to
/// 2 mm for the run (0.7 s at 1.5 mm/s), and 3 s of settling at each target.
fn campaign(name: &str, model: &str) -> String {
    format!(
        r#"[campaign]
name = "{name}"
stage = "latency"

[hardware]
kind = "sim"
optics = {{ width = 640, height = 640 }}

[hardware.sim]
model = "{model}"
time_scale = 1
transport = "pty"
frame_time_s = 0.1
seed = 3
travel_mm = [-1.0, 3.0]
soft_limits_x_um = [-500.0, 2500.0]
soft_limits_y_um = [-500.0, 2500.0]

[axes.x]
range_um = [800.0, 1600.0]
step_um = 50.0
other_at_um = 2000.0
m = 4

[sampling]
design = "random"
seed = 3

[acquisition]
directions = ["forward"]
settle_s = 3.0

[outputs]
dir = "{name}-{{id}}"
"#
    )
}

#[derive(Debug, Clone, Copy, PartialEq)]
enum Phase {
    Referencing,
    Move,
    Settle,
}

const PHASES: [Phase; 3] = [Phase::Referencing, Phase::Move, Phase::Settle];

/// One command as the simulated controller handled it.
#[derive(Debug, Clone)]
struct Line {
    t: f64,
    axis: String,
    moving: bool,
    on_target: bool,
    cmd: String,
}

fn read_trace(path: &Path, from: f64) -> Vec<Line> {
    let text = std::fs::read_to_string(path).unwrap_or_default();
    text.lines()
        .filter_map(|l| {
            let mut f = l.splitn(5, ' ');
            let t: f64 = f.next()?.parse().ok()?;
            let axis = f.next()?.to_string();
            let moving = f.next()? == "1";
            let on_target = f.next()? == "1";
            let cmd = f.next().unwrap_or("").to_string();
            (t >= from).then_some(Line {
                t,
                axis,
                moving,
                on_target,
                cmd,
            })
        })
        .collect()
}

/// The command's word: `MOV` of `MOV 1 0.8`, `MOV?` of a query.
fn word(cmd: &str) -> &str {
    cmd.split_whitespace().next().unwrap_or("")
}

fn is_motion(cmd: &str) -> bool {
    ["MOV", "MVR", "FRF", "FNL", "FPL"].contains(&word(cmd))
}

fn is_stop(cmd: &str) -> bool {
    ["#24", "STP", "HLT"].contains(&word(cmd))
}

/// When `phase` is under way in the trace (lines from `from` on): the wall time to request
/// the halt at, well inside the phase.
fn phase_time(lines: &[Line], phase: Phase) -> Option<f64> {
    let on = |a: &'static str| move |l: &&Line| l.axis == a;
    match phase {
        // Y's reference move, 1 s long.
        Phase::Referencing => lines
            .iter()
            .filter(on("y"))
            .find(|l| word(&l.cmd) == "FRF")
            .map(|l| l.t + 0.3),
        // Y to the run's other_at, 0.7 s.
        Phase::Move => lines
            .iter()
            .filter(on("y"))
            .find(|l| word(&l.cmd) == "MOV")
            .map(|l| l.t + 0.25),
        // X's second move (the approach, then the first target) on target: 3 s of settling.
        Phase::Settle => {
            let second = lines
                .iter()
                .filter(on("x"))
                .filter(|l| word(&l.cmd) == "MOV")
                .nth(1)?;
            lines
                .iter()
                .filter(on("x"))
                .find(|l| l.t > second.t && l.on_target)
                .map(|l| l.t + 0.8)
        }
    }
}

/// Waits until `phase` shows in the trace, then until its request time; returns the wall time
/// of the request to come (just before the caller sends it).
fn wait_phase(trace: &Path, from: f64, phase: Phase, what: &str) {
    let t0 = Instant::now();
    loop {
        if let Some(at) = phase_time(&read_trace(trace, from), phase) {
            let wait = at - unix_now();
            if wait > 0.0 {
                std::thread::sleep(Duration::from_secs_f64(wait));
            }
            return;
        }
        assert!(
            t0.elapsed() < Duration::from_secs(60),
            "{what}: {phase:?} never came; trace:\n{}",
            std::fs::read_to_string(trace).unwrap_or_default()
        );
        std::thread::sleep(Duration::from_millis(10));
    }
}

/// Checks the trace after a request at `t_req`; returns the latency (the later of the two
/// axes' stops).
fn check_stop(trace: &Path, from: f64, t_req: f64, what: &str) -> f64 {
    let lines = read_trace(trace, from);
    let dump = || {
        lines
            .iter()
            .filter(|l| l.t > t_req - 1.0)
            .map(|l| {
                format!(
                    "{:+.3} {} m{} {}",
                    l.t - t_req,
                    l.axis,
                    l.moving as u8,
                    l.cmd
                )
            })
            .collect::<Vec<_>>()
            .join("\n")
    };
    let mut worst: f64 = 0.0;
    for axis in ["x", "y"] {
        let stop = lines
            .iter()
            .find(|l| l.axis == axis && l.t >= t_req && is_stop(&l.cmd))
            .unwrap_or_else(|| panic!("{what}: axis {axis} got no stop\n{}", dump()));
        let latency = stop.t - t_req;
        assert!(
            latency <= MAX_LATENCY_S,
            "{what}: axis {axis} stopped {latency:.3} s after the request\n{}",
            dump()
        );
        assert!(
            !stop.moving,
            "{what}: axis {axis} still moving after its stop"
        );
        // No motion command after the request (one already on its way when it was made
        // arrives within microseconds), and none at all after the stop.
        for l in lines.iter().filter(|l| l.axis == axis && is_motion(&l.cmd)) {
            assert!(
                l.t < t_req + 0.05 && l.t < stop.t,
                "{what}: {} sent to axis {axis} {:.3} s after the request\n{}",
                l.cmd,
                l.t - t_req,
                dump()
            );
        }
        // At rest from the stop on, in everything the controller answered afterwards.
        assert!(
            lines
                .iter()
                .filter(|l| l.axis == axis && l.t >= stop.t)
                .all(|l| !l.moving),
            "{what}: axis {axis} moving again after its stop\n{}",
            dump()
        );
        worst = worst.max(latency);
    }
    worst
}

fn summary(what: &str, v: &mut [f64]) {
    v.sort_by(|a, b| a.partial_cmp(b).unwrap());
    let median = v[v.len() / 2];
    let max = v[v.len() - 1];
    println!(
        "{what}: {} trials, latency median {:.0} ms, max {:.0} ms",
        v.len(),
        median * 1e3,
        max * 1e3
    );
}

/// `csmetro run` on the campaign, halted by `signal` in `phase`: (latency, exit code, wall
/// time from the signal to the exit).
fn run_and_signal(dir: &Path, k: usize, signal: &str, phase: Phase) -> (f64, i32, f64) {
    let trace = dir.join(format!("trace-{k}.log"));
    let file = dir.join(format!("c{k}.toml"));
    let model = repo("config/sim/ideal.toml");
    std::fs::write(
        &file,
        campaign(&format!("lat{k}"), &model.display().to_string()),
    )
    .unwrap();
    let db = dir.join(format!("db{k}.db"));
    let from = unix_now();
    let child = bin()
        .args(["run", "--quiet", "--db"])
        .arg(&db)
        .arg(&file)
        .current_dir(dir)
        .env("CSMETRO_SIM_TRACE", &trace)
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let what = format!("run, {signal} in {phase:?} (trial {k})");
    wait_phase(&trace, from, phase, &what);
    let t_req = unix_now();
    let sent = std::process::Command::new("kill")
        .args([&format!("-{signal}"), &child.id().to_string()])
        .status()
        .unwrap();
    assert!(sent.success());
    let t0 = Instant::now();
    let out = child.wait_with_output().unwrap();
    let exit_s = t0.elapsed().as_secs_f64();
    let code = out.status.code().unwrap_or(-1);
    let latency = check_stop(&trace, from, t_req, &what);
    let err = String::from_utf8_lossy(&out.stderr).to_string();
    match signal {
        "INT" => {
            assert_eq!(code, 130, "{what}: {err}");
            assert!(err.contains("aborted; motion stopped"), "{what}: {err}");
        }
        _ => {
            assert_eq!(code, 143, "{what}: {err}");
            assert!(err.contains("csmetro resume"), "{what}: {err}");
        }
    }
    (latency, code, exit_s)
}

fn cli(signal: &str) {
    let dir = tempfile::tempdir().unwrap();
    let mut k = 0;
    for phase in PHASES {
        let mut lat = Vec::new();
        for _ in 0..trials() {
            k += 1;
            let (l, _, exit_s) = run_and_signal(dir.path(), k, signal, phase);
            assert!(exit_s < 10.0, "exit {exit_s:.1} s after SIG{signal}");
            lat.push(l);
        }
        summary(&format!("csmetro run, SIG{signal}, {phase:?}"), &mut lat);
    }
}

#[test]
fn ctrl_c_stops_motion_within_half_a_second_in_every_phase() {
    cli("INT");
}

#[test]
fn sigterm_stops_motion_within_half_a_second_in_every_phase() {
    cli("TERM");
}

fn start_server(dir: &Path, trace: &Path) -> Server {
    Server::start_with_env(dir, None, &[("CSMETRO_SIM_TRACE", trace)])
}

#[test]
fn api_abort_and_shutdown_stop_motion_within_half_a_second_in_every_phase() {
    let dir = tempfile::tempdir().unwrap();
    let trace: PathBuf = dir.path().join("trace.log");
    let server = start_server(dir.path(), &trace);
    let mut k = 0;
    for phase in PHASES {
        let mut lat = Vec::new();
        for _ in 0..trials() {
            k += 1;
            let what = format!("API abort in {phase:?} (trial {k})");
            let from = unix_now();
            let id = server.submit(&campaign(&format!("api{k}"), "ideal.toml"));
            wait_phase(&trace, from, phase, &what);
            let t_req = unix_now();
            let (s, v) = server.post(&format!("/campaigns/{id}/abort"), None);
            assert_eq!(s, 200, "{what}: {v}");
            let st = server.wait_for(id, 10.0, |v| {
                !matches!(v["state"].as_str(), Some("running" | "queued"))
            });
            assert_eq!(st["state"], "aborted", "{what}: {st}");
            lat.push(check_stop(&trace, from, t_req, &what));
        }
        summary(&format!("API abort, {phase:?}"), &mut lat);
    }
    drop(server);
    // Shutdown (SIGTERM to the service): the campaign stops resumable, within the grace.
    let mut lat = Vec::new();
    for phase in PHASES {
        k += 1;
        let what = format!("service shutdown in {phase:?} (trial {k})");
        let sdir = dir.path().join(format!("svc{k}"));
        std::fs::create_dir_all(&sdir).unwrap();
        let strace = sdir.join("trace.log");
        let mut server = start_server(&sdir, &strace);
        let from = unix_now();
        let id = server.submit(&campaign(&format!("svc{k}"), "ideal.toml"));
        wait_phase(&strace, from, phase, &what);
        let t_req = unix_now();
        let t0 = Instant::now();
        let st = server.terminate();
        let exit_s = t0.elapsed().as_secs_f64();
        assert!(st.success(), "{what}: {st:?}\n{}", server.log());
        assert!(exit_s < 10.0, "{what}: exit {exit_s:.1} s after SIGTERM");
        lat.push(check_stop(&strace, from, t_req, &what));
        let conn = rusqlite::Connection::open(server.db()).unwrap();
        let state: String = conn
            .query_row("SELECT state FROM campaigns WHERE id = ?1", [id], |r| {
                r.get(0)
            })
            .unwrap();
        assert_eq!(state, "interrupted", "{what}");
    }
    summary("service shutdown (one trial per phase)", &mut lat);
}
