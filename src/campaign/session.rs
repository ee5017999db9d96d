//! One campaign from file to results: stored, run (or resumed) on its rig, reconstructed,
//! reported. Used by `csmetro run`, `csmetro resume` and the service alike.
use std::collections::BTreeMap;
use std::path::PathBuf;
use std::sync::{Arc, Mutex};

use serde_json::{json, Value};
use tokio::sync::{broadcast, watch};

use super::attempt::Attempt;
pub use super::attempt::Finished;
use super::engine::{Control, EndState, Engine, EngineError, Recorder};
pub use super::error::CampaignError;
/// Where they lived before: the log and stream have their own module.
pub use super::events::{Event, SharedStore};
use super::plan::{plan, Plan};
/// Where it lived before: results no longer imports session.
pub use super::results::TruthSource;
use super::results::{problems, tally};
use super::rig::{self, Rig};
use super::spec::Campaign;
use super::worker::{reconstruct_run, settings, Worker};
use crate::store::StoreError;
use crate::types::{CampaignState, Origin, RunKey, SampleRecord};

/// Stores a new campaign (state queued) and returns its id.
pub fn create(store: &SharedStore, c: &Campaign) -> Result<i64, CampaignError> {
    let planned = super::verification::planned(c).unwrap_or(plan(c).total() as u64);
    let id = store.with(|s| -> Result<i64, StoreError> {
        let id = s.create_campaign(
            &c.spec().campaign.name,
            c.text(),
            c.origin(),
            &c.spec().campaign.stage,
            planned,
        )?;
        // The model it was validated with runs it, at every resume too.
        if let Some(m) = c.model() {
            s.set_model_snapshot(id, &m.text)?;
        }
        Ok(id)
    })?;
    Ok(id)
}

/// Reloads a stored campaign's file (its text was stored with it).
pub fn load_stored(store: &SharedStore, id: i64) -> Result<Campaign, CampaignError> {
    store.with(|s| {
        let row = s.campaign(id)?.ok_or(CampaignError::NotStored(id))?;
        let base = PathBuf::from(&row.spec_path)
            .parent()
            .map(|p| p.to_path_buf())
            .unwrap_or_default();
        let snapshot = s.model_snapshot(id)?;
        let c = Campaign::parse_stored(&row.spec_toml, &row.spec_path, &base, snapshot)?;
        // `verify = ID`: the characterisation's axes.
        Ok(super::verification::resolve(c, s)?)
    })
}

struct StoreRecorder {
    run: Attempt,
    worker: Worker,
    samples: Vec<SampleRecord>,
    campaign: Campaign,
    on_sample: Box<dyn FnMut(&SampleRecord) + Send>,
    truth_log: Option<std::fs::File>,
    /// Simulation: the stage's truth, so each adaptive decision records the true error of the
    /// curve it judged (how far the stop is from the best one in hindsight).
    truth: TruthSource,
}

impl Recorder for StoreRecorder {
    fn truth(&mut self, seq: u64, x_um: f64, y_um: f64) {
        use std::io::Write;
        // Written before the sample is committed: a sample stored is a sample whose truth is
        // on file, whenever the process dies.
        if let Some(f) = &mut self.truth_log {
            if let Err(e) = writeln!(f, "{seq},{x_um:?},{y_um:?}") {
                tracing::warn!(error = %e, "truth log not written");
            }
        }
    }
    fn sample(&mut self, s: &SampleRecord) -> Result<bool, StoreError> {
        let fresh = self.run.store_sample(s)?;
        self.samples.push(*s);
        self.worker.sample(s);
        (self.on_sample)(s);
        Ok(fresh)
    }
    fn event(&mut self, kind: &str, data: Value) {
        self.run.emit(kind, data);
    }
    fn run_done(&mut self, run: RunKey) {
        self.worker.run_done(run);
    }
    fn cv_error_um(&mut self, run: RunKey) -> Option<f64> {
        let grid = self.campaign.axis(run.axis)?.grid;
        let st = settings(&self.campaign);
        let curves =
            tokio::task::block_in_place(|| reconstruct_run(&grid, &st, run, &self.samples));
        curves
            .into_iter()
            .filter_map(|c| c.ok())
            .filter(|c| c.component.measured == run.axis)
            .filter_map(|c| c.cv_error_um)
            .next()
    }
    fn stop_estimate(&mut self, run: RunKey) -> Option<super::worker::StopEstimate> {
        let grid = self.campaign.axis(run.axis)?.grid;
        let st = settings(&self.campaign);
        let mut e = tokio::task::block_in_place(|| {
            super::worker::stop_estimate(&grid, &st, run, &self.samples)
        })
        .ok()?;
        let other_at = self.campaign.axis(run.axis)?.other_at_um;
        let component = run
            .components()
            .into_iter()
            .find(|c| c.measured == run.axis)?;
        e.true_error_um = self
            .truth
            .line(run, component, &grid.positions(), other_at)
            .filter(|t| t.len() == e.values_um.len() && !t.is_empty())
            .map(|t| {
                let n = t.len() as f64;
                t.iter()
                    .zip(&e.values_um)
                    .map(|(t, v)| (v - t).abs())
                    .sum::<f64>()
                    / n
            });
        Some(e)
    }
}

const STOPPED: &str = "stopped (service shutdown); resumes from the last stored sample";
const PAUSED_AT_STOP: &str =
    "paused by the operator; the service stopped meanwhile and keeps it paused until resumed";

/// Options of [`execute_with`] that only tests and soaks use.
#[derive(Debug, Clone, Default)]
pub struct Options {
    /// Simulation: append `seq,true_x_um,true_y_um` of each sample to this file (before the
    /// sample is committed), so a soak can check every stored position against the truth.
    pub truth_log: Option<PathBuf>,
    /// Who runs it (events name them); `None`: the service.
    pub origin: Option<Origin>,
}

/// Runs (or resumes) stored campaign `id`: skips targets already stored, stops motion on
/// abort and on error, reconstructs, reports, and records the final state.
pub async fn execute(
    store: SharedStore,
    id: i64,
    c: Campaign,
    control: watch::Receiver<Control>,
    events: broadcast::Sender<Event>,
    on_sample: Box<dyn FnMut(&SampleRecord) + Send>,
) -> Result<Finished, CampaignError> {
    execute_with(store, id, c, control, events, on_sample, Options::default()).await
}

/// [`execute`] with [`Options`].
pub async fn execute_with(
    store: SharedStore,
    id: i64,
    c: Campaign,
    control: watch::Receiver<Control>,
    events: broadcast::Sender<Event>,
    on_sample: Box<dyn FnMut(&SampleRecord) + Send>,
    opts: Options,
) -> Result<Finished, CampaignError> {
    let run = Attempt::new(store.clone(), events, id);
    let origin = opts.origin.clone().unwrap_or_else(Origin::service);
    if c.spec().campaign.verify.is_some() {
        return super::verification::execute(&run, c, control, on_sample, origin).await;
    }
    let truth_log = match &opts.truth_log {
        Some(p) => Some(
            std::fs::OpenOptions::new()
                .create(true)
                .append(true)
                .open(p)
                .map_err(|source| CampaignError::TruthLog {
                    path: p.display().to_string(),
                    source,
                })?,
        ),
        None => None,
    };
    let p: Plan = plan(&c);
    let done: BTreeMap<u64, SampleRecord> = store
        .with(|s| s.samples(id))?
        .into_iter()
        .map(|s| (s.target.seq, s))
        .collect();
    run.start(
        p.total() as u64,
        done.len(),
        &c.spec().campaign.name,
        &origin,
        None,
    )?;
    let fail = |cause: &str, msg: String| run.fail(cause, msg);
    // `[compensation]`: resolved (and a bad table refused) before the hardware is touched.
    let compensation = store
        .with(|s| super::compensate::for_campaign(&c, s))
        .map_err(|e| CampaignError::Recorded(fail("compensation", format!("stopped: {e}"))))?;
    let mut rig: Rig = rig::build(&c)
        .await
        .map_err(|e| CampaignError::NotStarted {
            id,
            msg: fail("hardware", format!("hardware: {e}")),
        })?;
    run.emit("rig", json!({"describe": rig.describe}));

    let recon_failures: Arc<Mutex<Vec<String>>> = Arc::default();
    let rf2 = recon_failures.clone();
    // Writes of the worker that failed go with the attempt's: the campaign ends `failed`.
    let run2 = run.clone();
    let worker = Worker::start(&c, move |r| match r {
        Ok(curve) => {
            let name = format!(
                "curves/{}-{}.csv",
                curve.run.label(),
                curve.component.name()
            );
            let stored = run2
                .store
                .with(|s| s.put_result(id, &name, "text/csv", curve.csv().as_bytes()));
            if let Err(e) = stored {
                let msg = format!("{name} not stored: {e}");
                run2.emit(
                    "error",
                    json!({"cause": "storage", "error": msg, "resumable": false}),
                );
                run2.write_failed(msg);
                return;
            }
            run2.emit(
                "reconstructed",
                json!({"run": curve.run.label(), "component": curve.component.name(), "method": curve.method,
                       "cv_error_um": curve.cv_error_um, "solve_ms": curve.solve_ms, "m": curve.samples.len()}),
            );
        }
        Err(e) => {
            let e = e.to_string();
            run2.emit("reconstruction_failed", json!({"error": e}));
            rf2.lock().unwrap_or_else(|p| p.into_inner()).push(e);
        }
    });
    let mut rec = StoreRecorder {
        run: run.clone(),
        worker,
        samples: Vec::new(),
        campaign: c.clone(),
        on_sample,
        truth_log,
        truth: TruthSource::new(&rig, &c),
    };
    let outcome = {
        let mut engine = Engine::new(&c, &mut rig, &mut rec, control, done);
        engine.compensation = compensation;
        engine.run(&p).await
    };
    let StoreRecorder { worker, .. } = rec;
    let maps = worker.maps();
    // Wall time decoding in this attempt (the physical figures are in the samples).
    let decode_s: BTreeMap<String, f64> = match &outcome {
        Ok(o) => o
            .stats
            .iter()
            .map(|(k, v)| (k.clone(), v.decode_s))
            .collect(),
        Err(_) => BTreeMap::new(),
    };
    run.emit("attempt", json!({"decode_s": decode_s}));
    let outcome = match outcome {
        Ok(o) => o,
        Err(e) => {
            rig.stop_all().await;
            rig.close().await;
            drop(worker.finish());
            let cause = match &e {
                EngineError::Axis { .. } => "axis",
                EngineError::Camera(_) => "camera",
                EngineError::Store(_) => "storage",
                EngineError::Other(_) => "acquisition",
                EngineError::Halted(_) => "halted",
            };
            let msg = fail(cause, format!("stopped: {e}"));
            return Err(CampaignError::Stopped { id, msg });
        }
    };
    let curves = tokio::task::spawn_blocking(move || worker.finish())
        .await
        .unwrap_or_default();
    let truth = TruthSource::new(&rig, &c);
    let motion_settle_s = rig.motion.map_or(0.0, |m| m.settle_s);
    rig.close().await;
    // Halted before the end: stopped (resumable) or aborted, motion already stopped.
    let halted = match outcome.end {
        EndState::Done => None,
        EndState::Stopped => Some((
            CampaignState::Interrupted,
            STOPPED,
            json!({"state": "interrupted", "reason": STOPPED}),
        )),
        EndState::Aborted => Some((
            CampaignState::Aborted,
            "aborted by the operator",
            json!({"state": "aborted", "cause": "operator"}),
        )),
    };
    if let Some((mut state, mut msg, mut data)) = halted {
        // Stopped (shutdown) while the operator held it paused: it stays paused.
        let paused = store
            .with(|s| s.campaign(id))
            .ok()
            .flatten()
            .is_some_and(|r| r.state == CampaignState::Paused);
        if state == CampaignState::Interrupted && paused {
            state = CampaignState::Paused;
            msg = PAUSED_AT_STOP;
            data = json!({"state": "paused", "reason": PAUSED_AT_STOP});
        }
        return run.halted(state, msg, data, outcome);
    }
    // Every figure from the store: the same whatever attempts it took.
    let (samples, log) =
        store.with(|s| Ok::<_, StoreError>((s.samples(id)?, s.events_after(id, 0)?)))?;
    let t = tally(&p, &samples, &log);
    let failures = recon_failures
        .lock()
        .unwrap_or_else(|e| e.into_inner())
        .clone();
    let mut errors = problems(&t, &failures);
    // The report says them too; those after it are added by `write_summary`.
    errors.extend(run.take_failed_writes());
    let mut rep = super::results::build(
        &c,
        id,
        &t,
        outcome.wall_s,
        &errors,
        &curves,
        &samples,
        &truth,
    );
    let maps = std::mem::take(&mut *maps.lock().unwrap_or_else(|p| p.into_inner()));
    errors.extend(super::map::add_to_report(
        &c,
        &maps,
        &t,
        &truth,
        motion_settle_s,
        &mut rep,
    ));
    let store_id = run.store_id();
    let created = store
        .with(|s| s.campaign(id))
        .ok()
        .flatten()
        .map(|r| r.created_unix_s);
    let html = report_html(
        &c,
        id,
        &store_id,
        created,
        &errors,
        &rep,
        &log,
        outcome.wall_s,
    );
    rep.files.push((
        "report.html".into(),
        "text/html; charset=utf-8".into(),
        html.into_bytes(),
    ));
    let written = run.put_files(&c, &store_id, &rep.files, &mut errors);
    #[cfg(feature = "nexus")]
    if let (true, Ok(d)) = (c.spec().outputs.nexus, &written) {
        if let Err(e) = write_nexus(&store, id, d, &c.spec().campaign.name, errors.is_empty()) {
            errors.push(format!("NeXus file not written: {e}"));
        }
    }
    let mut state = if errors.is_empty() {
        CampaignState::Done
    } else {
        CampaignState::Failed
    };
    // summary.json as stored says the state before the maps, the files and the NeXus file were
    // written: their failures (and its own write's) go into it too.
    let stored_summary = rep
        .files
        .iter()
        .find(|(n, _, _)| n == "summary.json")
        .map(|(_, _, b)| b.as_slice());
    let mut summary = rep.summary.clone();
    if let Err(e) = run.write_summary(
        &mut summary,
        &mut state,
        &mut errors,
        written.as_deref().ok(),
        stored_summary,
    ) {
        errors.push(format!("summary.json: {e}"));
        state = CampaignState::Failed;
    }
    run.finish(state, errors, summary, rep.table, outcome, written.ok())
}

/// Formats a Unix time as UTC, `2026-11-27 09:50:00 UTC` (civil date from days since the epoch,
/// H. Hinnant's algorithm).
fn utc(unix_s: f64) -> String {
    let [y, m, d, hh, mm, ss] = crate::types::utc_parts(unix_s);
    format!("{y:04}-{m:02}-{d:02} {hh:02}:{mm:02}:{ss:02} UTC")
}

/// `[outputs] nexus = true`: the campaign as `<dir>/<name>-<id>.nxs`, in the state it is about
/// to end in.
#[cfg(feature = "nexus")]
fn write_nexus(
    store: &SharedStore,
    id: i64,
    dir: &std::path::Path,
    name: &str,
    ok: bool,
) -> Result<(), crate::export::ExportError> {
    let mut e = store.with(|s| crate::export::Export::gather(s, id))?;
    e.state = if ok { "done" } else { "failed" }.into();
    crate::export::nexus::write(&e, &dir.join(format!("{name}-{id}.nxs")))
}

/// `report.html` of a campaign that measured to its end, from its results and its log.
#[allow(clippy::too_many_arguments)]
fn report_html(
    c: &Campaign,
    id: i64,
    store_id: &str,
    created_unix_s: Option<f64>,
    errors: &[String],
    rep: &super::results::Report,
    log: &[crate::store::EventRow],
    wall_s: f64,
) -> String {
    use crate::report::{format_hms, html};
    let mut timings = Vec::new();
    if let Some(t) = created_unix_s {
        timings.push(("submitted".to_string(), utc(t)));
    }
    let starts: Vec<&crate::store::EventRow> = log
        .iter()
        .filter(|e| e.kind == "started" || e.kind == "resumed_from_store")
        .collect();
    if let Some(e) = starts.first() {
        timings.push(("started".into(), utc(e.unix_s)));
    }
    timings.push(("finished".into(), utc(crate::store::now_unix_s())));
    timings.push(("attempts".into(), starts.len().max(1).to_string()));
    timings.push(("wall time of the last attempt".into(), format_hms(wall_s)));
    for ax in rep.summary["axes"].as_array().into_iter().flatten() {
        let a = ax["axis"].as_str().unwrap_or("?").to_uppercase();
        for phase in ["cs", "full"] {
            let p = &ax["phases"][phase];
            if p.is_null() {
                continue;
            }
            let f = |k: &str| p[k].as_f64().unwrap_or(0.0);
            timings.push((
                format!("{a} {phase}: acquisition / positioning / processing"),
                format!(
                    "{} / {} / {:.2} s ({} measurements)",
                    format_hms(f("acquisition_s")),
                    format_hms(f("positioning_s")),
                    f("processing_s"),
                    p["measurements"]
                ),
            ));
        }
    }
    // The rig as it identified itself (the last attempt's replies).
    let mut rig = Vec::new();
    if let Some(e) = log.iter().rev().find(|e| e.kind == "rig") {
        rig.push((
            "rig".to_string(),
            e.data["describe"].as_str().unwrap_or("").to_string(),
        ));
    }
    for axis in ["x", "y"] {
        if let Some(e) = log
            .iter()
            .rev()
            .find(|e| e.kind == "axis" && e.data["axis"] == axis)
        {
            rig.push((
                format!("axis {axis} (*IDN?)"),
                format!(
                    "{} — stage {}, travel {} µm",
                    e.data["idn"].as_str().unwrap_or("?"),
                    e.data["stage"].as_str().unwrap_or("?"),
                    e.data["travel_um"]
                ),
            ));
        }
    }
    rig.push(("stage name".into(), c.spec().campaign.stage.clone()));
    let state = if errors.is_empty() { "done" } else { "failed" };
    html::report_html(&html::HtmlReport {
        id,
        name: &c.spec().campaign.name,
        state,
        errors,
        store_id,
        timings,
        table: &rep.table,
        iso: &rep.iso,
        files: &rep.files,
        rig,
        campaign_text: c.text(),
        campaign_origin: c.origin(),
    })
}

#[cfg(test)]
mod tests {
    #[test]
    fn utc_dates_are_civil_dates() {
        assert_eq!(super::utc(0.0), "1970-01-01 00:00:00 UTC");
        // 2024-02-29 12:34:56 UTC (a leap day).
        assert_eq!(super::utc(1_709_210_096.0), "2024-02-29 12:34:56 UTC");
        assert_eq!(super::utc(1_798_761_599.0), "2026-12-31 23:59:59 UTC");
    }
}
