//! `csmetro soak --campaigns N --seed S`: short simulated campaigns with random controller faults,
//! killed (`kill -9`, sometimes SIGTERM) and resumed at random, each checked against the
//! simulator's truth and against one uninterrupted, fault-free run of the same plan. Prints one
//! JSON object; exits 1 when any check fails.
//!
//! Checks per campaign: every stored position within the sensor noise of the true position at
//! its trigger (the truth log the simulated rig writes), no target stored twice, none lost (a
//! done campaign has every planned target), the end state `done` or `failed`/`interrupted` with
//! a message, within the timeout, and the summary's counts equal to the reference run's, its
//! physical times within a tolerance (the exchanges' wall time is part of a simulated move's
//! time). Under faults a run may take longer than the fault-free reference (timeouts, retries
//! and resyncs cost stage time, as on the bench), never shorter: the time saved is never
//! inflated.
use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitCode, Stdio};
use std::time::{Duration, Instant};

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::Serialize;
use serde_json::{json, Value};

use super::{CliError, CliResult};
use crate::store::Store;
use crate::types::CampaignState;

#[derive(clap::Args)]
pub struct Args {
    /// Number of campaigns.
    #[arg(long, default_value_t = 200)]
    campaigns: usize,
    /// Seed of the faults, the kill times and the plans.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// At most this many kills (and restarts) per campaign.
    #[arg(long, default_value_t = 3)]
    kills: usize,
    /// Distinct plans (each gets one reference run).
    #[arg(long, default_value_t = 8)]
    plans: usize,
    /// Wall-time limit of one campaign, all attempts together, s.
    #[arg(long, default_value_t = 300.0)]
    timeout_s: f64,
    /// No random controller faults (kills only).
    #[arg(long)]
    no_faults: bool,
    /// Working directory (default: a new one under the system temp dir, removed at the end).
    #[arg(long)]
    dir: Option<PathBuf>,
}

/// The simulated stage: cyclic error, backlash, and 0.05 µm of white measurement noise.
const MODEL: &str = r#"[stage]
travel_x_um = [0.0, 9500.0]
travel_y_um = [0.0, 4200.0]

[[effect]]
kind = "leadscrew_cyclic"
axis = "x"
period_um = 400.0
cos_um = [0.4]
sin_um = [0.2]

[[effect]]
kind = "backlash"
axis = "x"
reversal_um = 1.5

[[effect]]
kind = "noise"
sigma_um = 0.05
"#;
const NOISE_SIGMA_UM: f64 = 0.05;
/// Decoder error on a noise-free frame is a few nm; 6 σ of the noise plus this is the bound.
const DECODE_TOL_UM: f64 = 0.02;
/// Relative tolerance on physical times against the reference run. A simulated move's time
/// includes the exchanges' wall time, which the host's load stretches: the plans settle 2 s and
/// dwell 0.5 s per point, as the paper's rig, so that those milliseconds stay within it.
const TIME_TOL: f64 = 0.03;

fn campaign_text(dir: &Path, plan: usize, faults: Option<&str>) -> String {
    let m = 5 + plan % 3;
    let design_seed = 100 + plan as u64;
    let lo = 200.0 + 100.0 * (plan % 4) as f64;
    let mut t = format!(
        r#"[campaign]
name = "soak"
stage = "soak-{plan}"

[hardware]
kind = "sim"
optics = {{ width = 640, height = 640 }}

[hardware.sim]
model = "{model}"
time_scale = 1000
transport = "pty"
frame_time_s = 0.1
seed = {design_seed}

[axes.x]
range_um = [{lo}, {hi}]
step_um = 25.0
other_at_um = 2100.0
m = {m}

[sampling]
design = "random"
seed = {design_seed}
full_scan = true

[acquisition]
directions = ["forward", "backward"]
settle_s = 2.0
dwell_s = 0.5

[reconstruction]
method = "pchip"

[outputs]
dir = "{out}/{{id}}"
"#,
        model = dir.join("model.toml").display(),
        hi = lo + 400.0,
        out = dir.join("out").display(),
    );
    if let Some(f) = faults {
        t.push_str(f);
    }
    t
}

fn faults_text(rng: &mut ChaCha8Rng) -> String {
    format!(
        "\n[hardware.sim.faults]\nseed = {}\ndelay_rate = 0.02\ndelay_ms = [1, 30]\ndrop_rate = 0.005\n\
         garbage_rate = 0.005\nerror_rate = 0.0\nvanish_rate = 0.002\nvanish_ms = 50\n",
        rng.random::<u32>()
    )
}

#[derive(Debug, Default, Serialize)]
struct Totals {
    campaigns: usize,
    kills: usize,
    sigterms: usize,
    attempts: usize,
    samples_checked: u64,
    positions_beyond_noise: u64,
    max_position_error_um: f64,
    position_bound_um: f64,
    samples_without_truth: u64,
    lost: u64,
    duplicated: u64,
    ended: BTreeMap<String, usize>,
    timeouts: usize,
    summary_mismatches: usize,
    max_time_rel_dev: f64,
    problems: Vec<String>,
}

fn bin() -> Result<PathBuf, CliError> {
    std::env::current_exe().map_err(|e| CliError::failure(format!("own executable: {e}")))
}

fn spawn(args: &[&str], db: &Path, truth: &Path, file: Option<&Path>) -> Result<Child, CliError> {
    Command::new(bin()?)
        .args(args)
        .arg("--db")
        .arg(db)
        .arg("--truth-log")
        .arg(truth)
        .args(file)
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .map_err(|e| CliError::failure(format!("cannot start csmetro: {e}")))
}

fn sample_count(db: &Path) -> u64 {
    Store::open(db)
        .ok()
        .and_then(|s| s.sample_count(1).ok())
        .unwrap_or(0)
}

/// Waits for the child to end, at most until `deadline`; None on timeout (child killed).
fn wait_until(child: &mut Child, deadline: Instant) -> Option<Value> {
    loop {
        match child.try_wait() {
            Ok(Some(_)) => {
                let mut out = String::new();
                if let Some(mut o) = child.stdout.take() {
                    let _ = std::io::Read::read_to_string(&mut o, &mut out);
                }
                return Some(serde_json::from_str(out.trim()).unwrap_or(Value::Null));
            }
            Ok(None) if Instant::now() < deadline => std::thread::sleep(Duration::from_millis(20)),
            _ => {
                let _ = child.kill();
                let _ = child.wait();
                return None;
            }
        }
    }
}

/// The figures two runs of one plan must share: counts exactly, physical times within
/// [`TIME_TOL`] (with `faults`, only below: recovering from a fault takes stage time).
/// Returns the mismatches and the largest relative time deviation that counts.
fn compare(got: &Value, want: &Value, faults: bool) -> (Vec<String>, f64) {
    let mut bad = Vec::new();
    let mut dev = 0.0f64;
    let (ga, wa) = (got["axes"].as_array(), want["axes"].as_array());
    let (Some(ga), Some(wa)) = (ga, wa) else {
        return (vec!["no axes in a summary".into()], 0.0);
    };
    if ga.len() != wa.len() {
        bad.push(format!("{} axes against {}", ga.len(), wa.len()));
    }
    for (g, w) in ga.iter().zip(wa) {
        for phase in ["cs", "full"] {
            let (gp, wp) = (&g["phases"][phase], &w["phases"][phase]);
            for k in ["measurements", "failed_points", "saved_by_adaptive"] {
                if gp[k] != wp[k] {
                    bad.push(format!(
                        "{}.{phase}.{k}: {} against {}",
                        w["axis"], gp[k], wp[k]
                    ));
                }
            }
            if let (Some(a), Some(b)) = (gp["acquisition_s"].as_f64(), wp["acquisition_s"].as_f64())
            {
                let signed = (a - b) / b.abs().max(1e-9);
                let d = if faults {
                    (-signed).max(0.0)
                } else {
                    signed.abs()
                };
                dev = dev.max(d);
                if d > TIME_TOL {
                    bad.push(format!(
                        "{}.{phase}.acquisition_s: {a:.3} against {b:.3}",
                        w["axis"]
                    ));
                }
            }
        }
    }
    for k in ["cs", "full"] {
        if got["total"][k]["measurements"] != want["total"][k]["measurements"] {
            bad.push(format!("total.{k}.measurements"));
        }
    }
    if let (Some(a), Some(b)) = (
        got["total"]["acquisition_saved_pct"].as_f64(),
        want["total"]["acquisition_saved_pct"].as_f64(),
    ) {
        let over = if faults { a - b } else { (a - b).abs() };
        if over > 100.0 * TIME_TOL {
            bad.push(format!("acquisition_saved_pct {a:.2} against {b:.2}"));
        }
    }
    (bad, dev)
}

/// One uninterrupted, fault-free run of `plan`: its summary.
fn reference(dir: &Path, plan: usize, timeout: Duration) -> anyhow::Result<Value> {
    let d = dir.join(format!("ref-{plan}"));
    std::fs::create_dir_all(&d)?;
    let c = d.join("campaign.toml");
    std::fs::write(&c, campaign_text(dir, plan, None))?;
    let mut ch = spawn(
        &["run", "--json", "--quiet"],
        &d.join("c.db"),
        &d.join("truth.csv"),
        Some(&c),
    )
    .map_err(|e| anyhow::anyhow!(e.message))?;
    let j = wait_until(&mut ch, Instant::now() + timeout)
        .ok_or_else(|| anyhow::anyhow!("reference run of plan {plan} timed out"))?;
    if j["state"] != "done" {
        anyhow::bail!("reference run of plan {plan} ended {}", j["state"]);
    }
    Ok(j)
}

fn truth_log(p: &Path) -> BTreeMap<u64, (f64, f64)> {
    let text = std::fs::read_to_string(p).unwrap_or_default();
    let mut m = BTreeMap::new();
    for line in text.lines() {
        let f: Vec<&str> = line.split(',').collect();
        if let [s, x, y] = f[..] {
            if let (Ok(s), Ok(x), Ok(y)) = (s.parse(), x.parse(), y.parse()) {
                // The last trigger of a target is the attempt that was stored.
                m.insert(s, (x, y));
            }
        }
    }
    m
}

#[allow(clippy::too_many_arguments)]
fn one(
    i: usize,
    a: &Args,
    dir: &Path,
    rng: &mut ChaCha8Rng,
    refs: &mut BTreeMap<usize, Value>,
    tot: &mut Totals,
) -> Result<(), CliError> {
    let plan = i % a.plans.max(1);
    let timeout = Duration::from_secs_f64(a.timeout_s);
    if let std::collections::btree_map::Entry::Vacant(v) = refs.entry(plan) {
        v.insert(reference(dir, plan, timeout).map_err(CliError::failure)?);
    }
    let d = dir.join(format!("c{i}"));
    std::fs::create_dir_all(&d).map_err(|e| CliError::failure(e.to_string()))?;
    let c = d.join("campaign.toml");
    let faults = (!a.no_faults).then(|| faults_text(rng));
    std::fs::write(&c, campaign_text(dir, plan, faults.as_deref()))
        .map_err(|e| CliError::failure(e.to_string()))?;
    let (db, truth) = (d.join("c.db"), d.join("truth.csv"));
    let deadline = Instant::now() + timeout;
    let planned = 2 * (5 + plan % 3) + 2 * 17;
    let kills = if a.kills == 0 {
        0
    } else {
        rng.random_range(1..=a.kills)
    };
    let mut summary = Value::Null;
    let mut timed_out = false;
    for attempt in 0.. {
        tot.attempts += 1;
        // Killed before it stored the campaign: run it again, as an operator would.
        let stored = Store::open(&db)
            .ok()
            .and_then(|s| s.campaign(1).ok().flatten())
            .is_some();
        let mut ch = if !stored {
            spawn(&["run", "--json", "--quiet"], &db, &truth, Some(&c))?
        } else {
            spawn(&["resume", "1", "--json", "--quiet"], &db, &truth, None)?
        };
        if attempt < kills {
            // Kill once a random share of what is left is stored (or at once: before the
            // first sample, during referencing).
            let at = sample_count(&db) + rng.random_range(0..=(planned as u64 / 3));
            while sample_count(&db) < at && Instant::now() < deadline {
                if ch.try_wait().ok().flatten().is_some() {
                    break;
                }
                std::thread::sleep(Duration::from_millis(5));
            }
            if ch.try_wait().ok().flatten().is_none() {
                if rng.random_bool(0.8) {
                    let _ = ch.kill(); // SIGKILL
                    tot.kills += 1;
                } else {
                    let _ = Command::new("kill")
                        .args(["-TERM", &ch.id().to_string()])
                        .status();
                    tot.sigterms += 1;
                }
                let _ = ch.wait();
                continue;
            }
        }
        match wait_until(&mut ch, deadline) {
            None => {
                timed_out = true;
                break;
            }
            Some(j) => summary = j,
        }
        let state = Store::open(&db)
            .ok()
            .and_then(|s| s.campaign(1).ok().flatten())
            .map(|r| r.state);
        // An unrecoverable device error leaves it interrupted: resume, as an operator would,
        // a bounded number of times.
        if state == Some(CampaignState::Interrupted) && attempt < kills + 3 {
            continue;
        }
        break;
    }
    tot.campaigns += 1;
    if timed_out {
        tot.timeouts += 1;
        tot.problems
            .push(format!("campaign {i}: not ended within {}s", a.timeout_s));
    }
    let s = Store::open(&db).map_err(|e| CliError::failure(e.to_string()))?;
    let Some(row) = s
        .campaign(1)
        .map_err(|e| CliError::failure(e.to_string()))?
    else {
        tot.problems.push(format!("campaign {i}: not in its store"));
        return Ok(());
    };
    *tot.ended.entry(row.state.as_str().to_string()).or_default() += 1;
    let samples = s.samples(1).map_err(|e| CliError::failure(e.to_string()))?;
    let seqs: BTreeSet<u64> = samples.iter().map(|r| r.target.seq).collect();
    tot.duplicated += (samples.len() - seqs.len()) as u64;
    match row.state {
        CampaignState::Done => {
            let lost = row.planned.saturating_sub(seqs.len() as u64);
            tot.lost += lost;
            if lost > 0 {
                tot.problems
                    .push(format!("campaign {i}: {lost} planned target(s) missing"));
            }
        }
        CampaignState::Failed | CampaignState::Interrupted if row.message.is_some() => {}
        other => tot.problems.push(format!(
            "campaign {i}: ended {} without a reason",
            other.as_str()
        )),
    }
    let t = truth_log(&truth);
    let bound = 6.0 * NOISE_SIGMA_UM + DECODE_TOL_UM;
    tot.position_bound_um = bound;
    for r in &samples {
        let Some(&(x, y)) = t.get(&r.target.seq) else {
            tot.samples_without_truth += 1;
            continue;
        };
        let e = (r.meas_x_um - x).abs().max((r.meas_y_um - y).abs());
        tot.samples_checked += 1;
        tot.max_position_error_um = tot.max_position_error_um.max(e);
        if e > bound {
            tot.positions_beyond_noise += 1;
        }
    }
    if row.state == CampaignState::Done {
        let (bad, dev) = compare(&summary, &refs[&plan], faults.is_some());
        tot.max_time_rel_dev = tot.max_time_rel_dev.max(dev);
        if !bad.is_empty() {
            tot.summary_mismatches += 1;
            tot.problems
                .push(format!("campaign {i}: summary differs: {}", bad.join("; ")));
        }
    }
    Ok(())
}

pub fn run(a: Args) -> CliResult {
    if a.campaigns == 0 || a.campaigns > 100_000 {
        return Err(CliError::input("--campaigns: 1 to 100000"));
    }
    if !(a.timeout_s.is_finite() && a.timeout_s > 0.0) {
        return Err(CliError::input("--timeout-s: a positive number of seconds"));
    }
    let (dir, remove) = match &a.dir {
        Some(d) => (d.clone(), false),
        None => (
            std::env::temp_dir().join(format!("csmetro-soak-{}", std::process::id())),
            true,
        ),
    };
    std::fs::create_dir_all(&dir)
        .and_then(|()| std::fs::write(dir.join("model.toml"), MODEL))
        .map_err(|e| CliError::failure(format!("{}: {e}", dir.display())))?;
    let t0 = Instant::now();
    let mut rng = ChaCha8Rng::seed_from_u64(a.seed);
    let mut refs = BTreeMap::new();
    let mut tot = Totals::default();
    let mut err = None;
    for i in 0..a.campaigns {
        if let Err(e) = one(i, &a, &dir, &mut rng, &mut refs, &mut tot) {
            err = Some(e);
            break;
        }
    }
    if remove {
        let _ = std::fs::remove_dir_all(&dir);
    }
    if let Some(e) = err {
        return Err(e);
    }
    let ok = tot.positions_beyond_noise == 0
        && tot.samples_without_truth == 0
        && tot.lost == 0
        && tot.duplicated == 0
        && tot.timeouts == 0
        && tot.summary_mismatches == 0
        && tot.problems.is_empty();
    tot.problems.truncate(20);
    outln!(
        "{}",
        json!({"soak": tot, "seed": a.seed, "faults": !a.no_faults, "ok": ok,
               "wall_s": t0.elapsed().as_secs_f64(), "time_tolerance": TIME_TOL})
    );
    Ok(if ok {
        ExitCode::SUCCESS
    } else {
        ExitCode::FAILURE
    })
}
