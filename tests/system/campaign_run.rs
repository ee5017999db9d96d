//! `csmetro run` / `csmetro resume` end to end on simulated hardware: the C-863 driver talks GCS
//! to simulated controllers over pseudo-terminals, the simulated camera renders the pattern, the
//! decoder measures, the store commits, the worker reconstructs, the report is written.
use crate::common;

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::time::{Duration, Instant};

use common::{bin, json_of, repo, resume, run_json, sim_header};
use csmetro::store::Store;
use csmetro::types::CampaignState;

/// A small Y campaign: `points` grid points, `m` random targets per direction, full scan.
fn campaign(dir: &Path, range_um: f64, m: usize) -> PathBuf {
    campaign_at(dir, range_um, m, 1000.0)
}

/// [`campaign`] at the given simulated time scale.
fn campaign_at(dir: &Path, range_um: f64, m: usize, time_scale: f64) -> PathBuf {
    let head = sim_header(
        "it",
        "sim-xy",
        &repo("config/sim/demo_xy.toml").display().to_string(),
        time_scale,
        5,
    );
    let text = format!(
        r#"{head}
[axes.y]
range_um = [1000.0, {hi}]
step_um = 5.0
other_at_um = 4750.0
m = {m}

[sampling]
design = "random"
seed = 11
full_scan = true

[acquisition]
directions = ["forward", "backward"]
settle_s = 2.0
dwell_s = 0.5

[reconstruction]
method = "auto"
noise_um = 0.01

[outputs]
dir = "{out}/{{name}}-{{id}}"
"#,
        hi = 1000.0 + range_um,
        out = dir.display(),
    );
    let p = dir.join("campaign.toml");
    std::fs::write(&p, text).unwrap();
    p
}

fn store(db: &Path) -> Store {
    Store::open(db).unwrap()
}

/// `csmetro run` in the background (stderr kept for the exit message).
fn spawn_run(campaign: &Path, db: &Path) -> Child {
    bin()
        .args(["run", "--quiet", "--db"])
        .arg(db)
        .arg(campaign)
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap()
}

/// Sends `signal` (e.g. `-INT`) to a running campaign and waits for its exit.
fn signal(child: Child, signal: &str) -> Output {
    let st = Command::new("kill")
        .args([signal, &child.id().to_string()])
        .status()
        .unwrap();
    assert!(st.success());
    child.wait_with_output().unwrap()
}

/// Waits until campaign 1 has at least `n` committed samples (the child keeps running).
fn wait_for_samples(child: &mut Child, db: &Path, n: u64) -> u64 {
    let t0 = Instant::now();
    loop {
        if let Some(status) = child.try_wait().unwrap() {
            let mut err = String::new();
            if let Some(mut e) = child.stderr.take() {
                let _ = std::io::Read::read_to_string(&mut e, &mut err);
            }
            panic!("campaign ended ({status}) before {n} samples: {err}");
        }
        if db.exists() {
            if let Ok(k) = store(db).sample_count(1) {
                if k >= n {
                    return k;
                }
            }
        }
        assert!(t0.elapsed() < Duration::from_secs(120), "no progress");
        std::thread::sleep(Duration::from_millis(20));
    }
}

#[test]
fn a_campaign_runs_end_to_end_and_reports_against_the_truth() {
    let dir = tempfile::tempdir().unwrap();
    let db = dir.path().join("c.db");
    let c = campaign(dir.path(), 400.0, 20);
    let j = json_of(&run_json(&c, &db));
    assert_eq!(j["state"], "done");
    let y = &j["axes"][0];
    assert_eq!(y["axis"], "y");
    assert_eq!(y["grid_points"], 81);
    assert_eq!(y["phases"]["cs"]["measurements"], 40);
    assert_eq!(y["phases"]["full"]["measurements"], 162);
    let saved = y["acquisition_saved_pct"].as_f64().unwrap();
    assert!(
        saved > 60.0 && saved < 100.0 * (1.0 - 40.0 / 162.0),
        "{saved}"
    );
    // Time per measured point: a CS point (20 µm moves) costs about what a full-scan point (5 µm)
    // does, as on the paper's rig; getting to a run's start is reported apart (CS runs first and
    // pays the trip from the reference switches).
    let phase = |p: &str, k: &str| y["phases"][p][k].as_f64().unwrap();
    let per_point =
        (phase("cs", "acquisition_s") / 40.0) / (phase("full", "acquisition_s") / 162.0);
    assert!(
        (1.0..1.02).contains(&per_point),
        "CS/full time per point {per_point}"
    );
    assert!(phase("cs", "positioning_s") > 1.0, "{}", y["phases"]);
    assert!(phase("full", "positioning_s") < phase("cs", "positioning_s"));
    let comps: Vec<&str> = y["components"]
        .as_array()
        .unwrap()
        .iter()
        .map(|c| c["component"].as_str().unwrap())
        .collect();
    for k in ["ef_yy", "eb_yy", "ef_yx", "eb_yx"] {
        assert!(comps.contains(&k), "{k} in {comps:?}");
    }
    for c in y["components"].as_array().unwrap() {
        // One frame per point: the σ told is the σ used, and the frames measure nothing.
        assert_eq!(c["cs"]["noise_um"], 0.01, "{c}");
        assert!(c["cs"]["frame_noise_um"].is_null(), "{c}");
        // The camera measures the truth to ~10 nm; 20 random points recover 400 µm of curve.
        let full = c["full_vs_truth"]["max_abs_um"].as_f64().unwrap();
        let cs = c["cs_vs_truth"]["mean_abs_um"].as_f64().unwrap();
        assert!(full < 0.1, "{}: full scan vs truth {full}", c["component"]);
        assert!(cs < 0.3, "{}: CS vs truth {cs}", c["component"]);
    }
    assert!(j["iso230"]["y"]["reconstructed"]["b_um"].as_f64().unwrap() > 0.5);
    // Every reported figure with its expanded uncertainty and budget (issue 51).
    let u = &j["iso230"]["y"]["uncertainty"];
    assert_eq!(u["e"]["k"], 2.0, "{u}");
    let (e, big_e) = (
        u["e"]["value_um"].as_f64().unwrap(),
        u["e"]["expanded_um"].as_f64().unwrap(),
    );
    assert!(big_e > 0.0 && big_e < 0.5 * e, "E {e} ± {big_e}");
    let sources: Vec<&str> = u["e"]["contributions"]
        .as_array()
        .unwrap()
        .iter()
        .map(|c| c["source"].as_str().unwrap())
        .collect();
    assert_eq!(sources, ["data", "pitch", "misalignment"], "{u}");

    let out = dir.path().join("it-1");
    for f in [
        "summary.json",
        "summary.txt",
        "samples.csv",
        "ef_yy.csv",
        "compensation_y.csv",
        "iso230.json",
        "plots/ef_yy.svg",
        "plots/eb_yx.png",
    ] {
        assert!(out.join(f).is_file(), "{f} written");
    }
    let summary = std::fs::read_to_string(out.join("summary.txt")).unwrap();
    assert!(
        summary.contains("with U: A = ") && summary.contains("µm (k = 2)"),
        "{summary}"
    );
    let png = std::fs::read(out.join("plots/eb_yx.png")).unwrap();
    assert_eq!(&png[1..4], b"PNG");
    let comp = std::fs::read_to_string(out.join("compensation_y.csv")).unwrap();
    assert!(comp.starts_with("position_um,"), "{comp:.80}");
    assert_eq!(comp.lines().count(), 1 + 81);

    // Everything is in the store too, each target once.
    let s = store(&db);
    let row = s.campaign(1).unwrap().unwrap();
    assert_eq!(row.state, CampaignState::Done);
    let samples = s.samples(1).unwrap();
    assert_eq!(samples.len(), 202);
    let mut seqs: Vec<u64> = samples.iter().map(|r| r.target.seq).collect();
    seqs.dedup();
    assert_eq!(seqs.len(), 202);
    for r in &samples {
        assert!((r.meas_x_um - 4750.0).abs() < 20.0, "x stands still");
        assert!((r.meas_y_um - r.target.target_y_um).abs() < 20.0);
    }
    let names = s.result_names(1).unwrap();
    assert!(names.iter().any(|n| n == "plots/ef_yy.svg"), "{names:?}");

    // The stored campaign is gap data as it is: CS and full scan are two runs of one Y line.
    let ideal = Path::new(env!("CARGO_MANIFEST_DIR")).join("config/sim/ideal.toml");
    let g = json_of(
        &bin()
            .args(["gap", "--json", "--data", "1", "--db"])
            .arg(&db)
            .arg("--model")
            .arg(&ideal)
            .arg("--out")
            .arg(dir.path().join("gap"))
            .output()
            .unwrap(),
    );
    assert_eq!(g["n_samples"], 202);
    assert_eq!(g["n_runs"], 2);
    assert_eq!(g["n_lines"], 2);
    // The demo stage is far from ideal: the gap is there and located.
    assert!(g["heldout_rms_before_um"].as_f64().unwrap() > 0.2, "{g}");
    assert!(!g["where"].as_array().unwrap().is_empty());
}

#[test]
fn frames_measure_the_cameras_noise_and_raise_a_sigma_told_too_low() {
    let dir = tempfile::tempdir().unwrap();
    let db = dir.path().join("c.db");
    let c = campaign(dir.path(), 300.0, 30);
    // Four frames a point, σ told a tenth of the simulated camera's (0.01 µm a frame).
    let text = std::fs::read_to_string(&c)
        .unwrap()
        .replace("dwell_s = 0.5\n", "dwell_s = 0.5\nframes_per_point = 4\n")
        .replace("noise_um = 0.01", "noise_um = 0.001")
        .replace(
            "[outputs]",
            "[uncertainty]\nsensor_u_um = 0.001\n\n[outputs]",
        );
    std::fs::write(&c, text).unwrap();
    let j = json_of(&run_json(&c, &db));
    assert_eq!(j["state"], "done", "{j}");
    let comps = j["axes"][0]["components"].as_array().unwrap();
    assert_eq!(comps.len(), 4, "{j}");
    for k in comps {
        let cs = &k["cs"];
        // A sample averages four frames: 0.01 / √4 = 0.005 µm, with the decoder's own scatter.
        let frames = cs["frame_noise_um"].as_f64().unwrap();
        assert!((0.004..0.008).contains(&frames), "{k}");
        assert_eq!(cs["frame_noise_dof"], 90, "30 points of 4 frames: {k}");
        assert_eq!(cs["noise_told_um"], 0.001, "{k}");
        assert_eq!(cs["noise_um"], frames, "the curve uses the frames' σ: {k}");
    }
    // ISO 230-2 from the measured full scan (one approach a target): each mean is worth the
    // sensor's repeatability, told 0.001 µm and raised to what the frames show.
    let m = &j["iso230"]["y"]["uncertainty"]["m"]["contributions"][0];
    assert_eq!(m["source"], "data", "{m}");
    let data = m["u_um"].as_f64().unwrap();
    assert!(
        (0.004..0.008).contains(&data),
        "{}",
        j["iso230"]["y"]["uncertainty"]
    );
    // The store keeps each point's scatter: a resumed campaign measures the same σ.
    let samples = store(&db).samples(1).unwrap();
    assert_eq!(samples.len(), 60 + 2 * 61);
    for s in &samples {
        assert_eq!(s.frames, 4);
        let [x, y] = s.frame_sd_um.expect("scatter of 4 frames");
        assert!(x > 0.0 && y > 0.0 && x < 0.05 && y < 0.05, "{s:?}");
    }
    // samples.csv keeps the scatter too: `reconstruct` on it measures the campaign's σ.
    let csv = dir.path().join("it-1/samples.csv");
    let o = bin()
        .args(["reconstruct", "--grid", "1000:5:1300", "--json"])
        .args([
            "--noise-um",
            "0.001",
            "--axis",
            "y",
            "--direction",
            "forward",
        ])
        .args(["--phase", "cs", "--samples"])
        .arg(&csv)
        .output()
        .unwrap();
    let r = json_of(&o);
    let ef_yy = comps
        .iter()
        .find(|k| k["component"] == "ef_yy")
        .expect("ef_yy");
    let campaign = ef_yy["cs"]["frame_noise_um"].as_f64().unwrap();
    let read = r["frame_noise_um"].as_f64().unwrap();
    // The file rounds each σ to 1e-6 µm.
    assert!((read - campaign).abs() < 1e-5, "{read} vs {campaign}: {r}");
    assert_eq!(r["frame_noise_dof"], 90, "{r}");
    assert_eq!(r["noise_um"], r["frame_noise_um"], "{r}");
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("frames' scatter"), "{err}");
}

#[test]
fn kill_9_then_resume_loses_nothing_and_measures_nothing_twice() {
    let dir = tempfile::tempdir().unwrap();
    let db = dir.path().join("c.db");
    let c = campaign(dir.path(), 2000.0, 60);
    let mut child = spawn_run(&c, &db);
    wait_for_samples(&mut child, &db, 150);
    child.kill().unwrap(); // SIGKILL
    child.wait().unwrap();
    let before = store(&db).samples(1).unwrap();
    assert!(before.len() >= 150);
    let planned = store(&db).campaign(1).unwrap().unwrap().planned;
    assert!((before.len() as u64) < planned, "killed mid-run");

    let j = json_of(&resume(1, &["--json", "--quiet"], &db));
    assert_eq!(j["state"], "done");
    let s = store(&db);
    let after = s.samples(1).unwrap();
    assert_eq!(after.len() as u64, planned, "every planned target, once");
    let mut seqs: Vec<u64> = after.iter().map(|r| r.target.seq).collect();
    seqs.sort();
    seqs.dedup();
    assert_eq!(seqs.len() as u64, planned, "no target twice");
    // What was committed before the kill is kept as it was.
    for b in &before {
        let a = after.iter().find(|a| a.target.seq == b.target.seq).unwrap();
        assert_eq!((a.meas_y_um, a.unix_s), (b.meas_y_um, b.unix_s));
    }
    let events = s.events_after(1, 0).unwrap();
    assert!(events.iter().any(|e| e.kind == "resumed_from_store"));
    assert_eq!(s.campaign(1).unwrap().unwrap().state, CampaignState::Done);
    // A finished campaign cannot be resumed again.
    let o = resume(1, &[], &db);
    assert_eq!(o.status.code(), Some(2));
}

#[test]
fn sigint_aborts_stops_and_records_the_abort() {
    let dir = tempfile::tempdir().unwrap();
    let db = dir.path().join("c.db");
    let c = campaign(dir.path(), 2000.0, 60);
    let mut child = spawn_run(&c, &db);
    wait_for_samples(&mut child, &db, 30);
    let o = signal(child, "-INT");
    assert_eq!(
        o.status.code(),
        Some(130),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    assert!(String::from_utf8_lossy(&o.stderr).contains("motion stopped"));
    let s = store(&db);
    let row = s.campaign(1).unwrap().unwrap();
    assert_eq!(row.state, CampaignState::Aborted);
    assert!(s.sample_count(1).unwrap() < row.planned);
    let events = s.events_after(1, 0).unwrap();
    let last = events.last().unwrap();
    assert_eq!(last.kind, "finished");
}

#[test]
fn bad_campaign_files_name_file_line_and_key_and_nothing_is_stored() {
    let dir = tempfile::tempdir().unwrap();
    let db = dir.path().join("c.db");
    let good = std::fs::read_to_string(campaign(dir.path(), 400.0, 20)).unwrap();
    let cases = [
        ("step_um = 5.0", "step_um = 5.0\nstpe = 1", "axes.y.stpe"),
        ("m = 20", "m = \"twenty\"", "axes.y.m"),
        ("settle_s = 2.0", "settle_s = -1.0", "acquisition.settle_s"),
        (
            "range_um = [1000.0, 1400]",
            "range_um = [1000.0, 99000.0]",
            "axes.y.range_um",
        ),
        (
            "time_scale = 1000",
            "time_scale = 1000\ntime_scale = 10",
            "hardware.sim.time_scale",
        ),
        // A reference move of days that no abort could cut short before issue 47.
        (
            "time_scale = 1000",
            "time_scale = 1e-300",
            "hardware.sim.time_scale: must be in [1e-3, 1e6]",
        ),
    ];
    for (from, to, key) in cases {
        assert!(good.contains(from), "{from}");
        let text = good.replacen(from, to, 1);
        let changed = to.lines().last().unwrap();
        let line = text.lines().position(|l| l.trim() == changed).unwrap() + 1;
        let f = dir.path().join("bad.toml");
        std::fs::write(&f, &text).unwrap();
        let o = run_json(&f, &db);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{to}: {err}");
        assert!(
            err.contains(&format!("bad.toml:{line}: {key}")),
            "{to}: want bad.toml:{line}: {key}, got {err}"
        );
        assert!(!db.exists(), "{to}: nothing stored before validation");
    }
    let o = run_json(&dir.path().join("missing.toml"), &db);
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("missing.toml"));
}

#[test]
fn sigterm_stops_motion_and_leaves_the_campaign_resumable() {
    let dir = tempfile::tempdir().unwrap();
    let db = dir.path().join("c.db");
    let c = campaign(dir.path(), 1000.0, 30);
    let mut child = spawn_run(&c, &db);
    wait_for_samples(&mut child, &db, 30);
    let o = signal(child, "-TERM");
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(143), "{err}");
    assert!(err.contains("motion stopped"), "{err}");
    let row = store(&db).campaign(1).unwrap().unwrap();
    assert_eq!(row.state, CampaignState::Interrupted);
    let j = json_of(&resume(1, &["--json", "--quiet"], &db));
    assert_eq!(j["state"], "done");
    assert_eq!(store(&db).sample_count(1).unwrap(), row.planned);
}

/// Adaptive mode: a reachable error target ends each sweep early and the summary says how many
/// measurements that saved; an unreachable one measures the whole design.
#[test]
fn adaptive_mode_stops_at_the_error_target_and_reports_the_saving() {
    let dir = tempfile::tempdir().unwrap();
    let c = campaign(dir.path(), 1000.0, 120);
    let text = std::fs::read_to_string(&c).unwrap();
    let text = text.replace("full_scan = true", "full_scan = false");
    let mut summaries = Vec::new();
    for (k, goal) in [(0, 0.5), (1, 1e-4)] {
        let f = dir.path().join(format!("adaptive{k}.toml"));
        std::fs::write(
            &f,
            text.replace(
                "seed = 11",
                &format!("seed = 11\ntarget_error_um = {goal}\nbatch = 30"),
            ),
        )
        .unwrap();
        let j = json_of(&run_json(&f, &dir.path().join(format!("a{k}.db"))));
        assert_eq!(j["state"], "done");
        summaries.push(j["axes"][0]["phases"]["cs"].clone());
    }
    let (easy, hard) = (&summaries[0], &summaries[1]);
    let saved = easy["saved_by_adaptive"].as_u64().unwrap();
    let measured = easy["measurements"].as_u64().unwrap();
    assert!(saved >= 60, "{easy}");
    assert_eq!(measured + saved, 240, "{easy}");
    assert_eq!(hard["saved_by_adaptive"], 0, "{hard}");
    assert_eq!(hard["measurements"], 240, "{hard}");
}

/// One process drives a stage: while a foreground run measures, a second `run` or a `resume` on
/// the same stage is refused before anything is stored or moved, and a service starting on the
/// same store neither re-runs that campaign nor starts its own on the stage until it is free.
#[test]
fn one_process_per_stage_a_second_run_and_a_starting_service_keep_off() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::create_dir_all(dir.path().join("var")).unwrap();
    let db = dir.path().join("var/csmetro.db");
    // Time scale 250, not 1000: the run (~10 s) must outlast the second run, the resume and the
    // service's start while six test threads share two cores.
    let c = campaign_at(dir.path(), 2000.0, 60, 250.0);
    let mut child = spawn_run(&c, &db);
    wait_for_samples(&mut child, &db, 20);

    let o = run_json(&c, &db);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(
        err.contains("driven by another csmetro process")
            && err.contains(&format!("pid {}", child.id())),
        "{err}"
    );
    assert_eq!(store(&db).campaigns().unwrap().len(), 1, "nothing stored");
    let o = resume(1, &[], &db);
    assert_eq!(o.status.code(), Some(1));

    common::write_config(dir.path(), "127.0.0.1:0", None);
    let mut server = common::Server::start(dir.path(), None);
    assert_eq!(server.db(), db);
    assert_eq!(server.status(1)["state"], "running");
    let queued = server.submit(&common::campaign("queued", "sim-xy", 5, 1000.0));
    let st = server.wait_for(queued, 10.0, |s| {
        s["message"]
            .as_str()
            .is_some_and(|m| m.contains("another csmetro process"))
    });
    assert_eq!(st["state"], "queued", "{st}");

    let out = child.wait_with_output().unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let st = server.wait_for(queued, 60.0, |s| s["state"] == "done");
    assert_eq!(st["stored"], st["planned"]);
    let s = store(&db);
    let row = s.campaign(1).unwrap().unwrap();
    assert_eq!(row.state, CampaignState::Done);
    let mut seqs = common::stored_seqs(&db, 1);
    let n = seqs.len();
    seqs.sort();
    seqs.dedup();
    assert_eq!((n as u64, seqs.len() as u64), (row.planned, row.planned));
    let events = s.events_after(1, 0).unwrap();
    assert!(
        !events
            .iter()
            .any(|e| e.kind == "requeued" || e.kind == "resumed_from_store"),
        "the service left campaign 1 alone"
    );
    assert!(server.log().contains("left to the process that runs it"));
    assert!(server.terminate().success());
}

/// A foreground run killed (-9) while the service runs on the same store: within seconds the
/// service shows the campaign `interrupted` (not `running` forever, with resume and abort
/// refused), and a resume through the API finishes it without measuring a target twice.
#[test]
fn a_foreground_run_killed_beside_the_service_becomes_resumable_through_it() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::create_dir_all(dir.path().join("var")).unwrap();
    let db = dir.path().join("var/csmetro.db");
    common::write_config(dir.path(), "127.0.0.1:0", None);
    let mut server = common::Server::start(dir.path(), None);
    assert_eq!(server.db(), db);
    // Long enough (~1700 targets) that it is still running after the wait below on a fast machine.
    let c = campaign(dir.path(), 4000.0, 60);
    let mut child = spawn_run(&c, &db);
    wait_for_samples(&mut child, &db, 20);
    // Alive: the service leaves it alone through a check (one every 2 s).
    std::thread::sleep(Duration::from_secs(3));
    assert_eq!(server.status(1)["state"], "running");
    child.kill().unwrap(); // SIGKILL: the run cannot store an end state
    child.wait().unwrap();
    let stored = store(&db).sample_count(1).unwrap();
    let planned = store(&db).campaign(1).unwrap().unwrap().planned;
    assert!(stored < planned, "killed mid-run");

    let st = server.wait_for(1, 15.0, |s| s["state"] == "interrupted");
    let msg = st["message"].as_str().unwrap_or("");
    assert!(msg.contains("exited without finishing"), "{st}");
    assert!(
        msg.contains(&format!("{stored} of {planned} samples")),
        "{st}"
    );
    let (code, v) = server.post("/campaigns/1/resume", None);
    assert_eq!(code, 200, "{v}");
    let st = server.wait_for(1, 180.0, |s| s["state"] == "done");
    assert_eq!(st["stored"], st["planned"]);
    let mut seqs = common::stored_seqs(&db, 1);
    let n = seqs.len();
    seqs.sort();
    seqs.dedup();
    assert_eq!(
        (n as u64, seqs.len() as u64),
        (planned, planned),
        "no target twice"
    );
    let events = store(&db).events_after(1, 0).unwrap();
    assert!(events
        .iter()
        .any(|e| e.kind == "interrupted"
            && e.data["reason"] == "its process exited without finishing"));
    assert!(server.terminate().success());
}

/// The summary after `kill -9`, a resume stopped by SIGTERM and a last resume reports what one
/// uninterrupted run of the same campaign reports: every measurement of every attempt, the
/// same physical acquisition time and the same saving (the exchanges' wall time aside).
#[test]
fn the_summary_after_kill_9_sigterm_and_resume_equals_an_uninterrupted_runs() {
    let dir = tempfile::tempdir().unwrap();
    let c = campaign(dir.path(), 400.0, 20);
    let whole = json_of(&run_json(&c, &dir.path().join("whole.db")));
    let db = dir.path().join("c.db");
    let mut child = spawn_run(&c, &db);
    wait_for_samples(&mut child, &db, 30);
    child.kill().unwrap(); // SIGKILL
    child.wait().unwrap();
    let mut child = bin()
        .args(["resume", "1", "--quiet", "--db"])
        .arg(&db)
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    wait_for_samples(&mut child, &db, 100);
    let o = signal(child, "-TERM");
    assert_eq!(o.status.code(), Some(143));
    assert!(
        (store(&db).sample_count(1).unwrap()) < 202,
        "stopped mid-run"
    );
    let j = json_of(&resume(1, &["--json", "--quiet"], &db));
    assert_eq!(j["state"], "done");
    assert_eq!(j["samples"], 202);
    let (y, w) = (&j["axes"][0], &whole["axes"][0]);
    for phase in ["cs", "full"] {
        let (p, q) = (&y["phases"][phase], &w["phases"][phase]);
        assert_eq!(p["measurements"], q["measurements"], "{phase}: {p} vs {q}");
        assert_eq!(p["failed_points"], 0);
        let (a, b) = (
            p["acquisition_s"].as_f64().unwrap(),
            q["acquisition_s"].as_f64().unwrap(),
        );
        assert!((a / b - 1.0).abs() < 0.01, "{phase} acquisition {a} vs {b}");
    }
    assert_eq!(y["phases"]["cs"]["measurements"], 40);
    assert_eq!(y["phases"]["full"]["measurements"], 162);
    let saved = |v: &serde_json::Value| v["total"]["acquisition_saved_pct"].as_f64().unwrap();
    assert!(
        (saved(&j) - saved(&whole)).abs() < 0.5,
        "{} vs {}",
        saved(&j),
        saved(&whole)
    );
    assert_eq!(j["total"]["cs"]["measurements"], 40);
    assert_eq!(j["total"]["full"]["measurements"], 162);
    // The table prints both rows of the axis with every measurement.
    let txt = std::fs::read_to_string(dir.path().join("it-1/summary.txt")).unwrap();
    let row = |k: &str| {
        txt.lines()
            .find(|l| l.starts_with('Y') && l.contains(k))
            .unwrap_or_else(|| panic!("no Y {k} row in\n{txt}"))
            .to_string()
    };
    assert!(row("full scan").contains(" 162 "), "{txt}");
    assert!(row("CS ").contains(" 40 "), "{txt}");
}

/// Two stores, one absolute `[outputs] dir` with `{id}`: both stores' campaign 1 would write
/// `it-1`. The folder belongs to the first; the second's results go to a folder with its
/// store's identity in the name. Each has its `report.html`, self-contained, with the ISO
/// 230-2 figures from the measured full scan; a finished run offers no resume.
#[test]
fn results_are_never_overwritten_and_each_campaign_has_its_report() {
    let dir = tempfile::tempdir().unwrap();
    let c = campaign(dir.path(), 100.0, 5);
    let (db_a, db_b) = (dir.path().join("a.db"), dir.path().join("b.db"));
    let oa = run_json(&c, &db_a);
    let ja = json_of(&oa);
    assert_eq!(ja["state"], "done");
    let err = String::from_utf8_lossy(&oa.stderr);
    // The results line, then what to type next: the verification, a compensated move, the
    // controller export (this campaign has compensation tables).
    let results_line = err.lines().position(|l| l.starts_with("results: "));
    assert!(results_line.is_some(), "{err}");
    let next: Vec<&str> = err.lines().skip(results_line.unwrap() + 1).collect();
    assert!(
        next.first() == Some(&"next:")
            && next.iter().any(|l| l.contains("csmetro verify 1"))
            && next.iter().any(|l| l.contains("--compensation"))
            && next.iter().any(|l| l.contains("csmetro export 1")),
        "{err}"
    );
    assert!(
        !err.contains("resume"),
        "a finished run offers no resume: {err}"
    );

    let out = dir.path().join("it-1");
    let marker = |d: &Path| -> serde_json::Value {
        serde_json::from_slice(&std::fs::read(d.join(".csmetro-results.json")).unwrap()).unwrap()
    };
    let id_a = store(&db_a).store_id().unwrap();
    assert_eq!(marker(&out)["store_id"], id_a.as_str());
    let summary_a = std::fs::read(out.join("summary.json")).unwrap();

    let jb = json_of(&run_json(&c, &db_b));
    assert_eq!(
        (jb["id"].as_i64(), jb["state"].as_str()),
        (Some(1), Some("done"))
    );
    let id_b = store(&db_b).store_id().unwrap();
    assert_ne!(id_a, id_b);
    assert_eq!(
        std::fs::read(out.join("summary.json")).unwrap(),
        summary_a,
        "store b's campaign 1 wrote over store a's results"
    );
    assert_eq!(marker(&out)["store_id"], id_a.as_str());
    let out_b = dir.path().join(format!("it-1.store-{id_b}-c1"));
    assert_eq!(marker(&out_b)["store_id"], id_b.as_str());
    assert!(out_b.join("summary.json").is_file());

    // ISO 230-2 from the measured full scan, on the chart, in summary.txt and the run table.
    let txt = std::fs::read_to_string(out.join("summary.txt")).unwrap();
    assert!(
        txt.contains("ISO 230-2 Y axis (measured full scan, 1 cycle, 21 targets): A "),
        "{txt}"
    );
    assert_eq!(ja["iso230"]["y"]["source"], "full_scan", "{}", ja["iso230"]);
    let b_full = ja["iso230"]["y"]["full_scan"]["b_um"].as_f64().unwrap();
    assert!(txt.contains(&format!("B {b_full:.3} µm")), "{txt}");
    let svg = std::fs::read_to_string(out.join("plots/iso230_y.svg")).unwrap();
    assert!(
        svg.contains("measured full scan, 1 cycle") && svg.contains(&format!("B {b_full:.3} µm"))
    );
    assert_eq!(
        &std::fs::read(out.join("plots/iso230_y.png")).unwrap()[1..4],
        b"PNG"
    );

    // report.html: one file, plots embedded, the campaign file, the rig's *IDN? replies.
    let html = std::fs::read_to_string(out.join("report.html")).unwrap();
    assert!(html.starts_with("<!DOCTYPE html>"));
    assert!(
        html.contains("data:image/png;base64,iVBORw0KGgo"),
        "PNG data URIs"
    );
    assert!(!html.contains("src=\"http") && !html.contains("src=\"plots/"));
    assert!(html.contains("measured full scan, 1 cycle"));
    assert!(html.contains("name = &quot;it&quot;"), "the campaign file");
    assert!(html.contains("(*IDN?)"), "the rig's identification");
    assert!(html.contains(&id_a), "the store");
    let stored = store(&db_a).result(1, "report.html").unwrap().unwrap();
    assert_eq!(stored.1, html.as_bytes());
}
