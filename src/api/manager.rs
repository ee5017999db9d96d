//! The campaign manager behind the API: a FIFO queue per stage (one campaign drives a stage at a
//! time, the others wait in state `queued`), the control channel of each running campaign, and
//! one broadcast of live events for every client.
//!
//! Crash safety comes from the store: every sample is committed as it is taken, so a campaign
//! left `running`/`interrupted`/`queued` by a killed service is queued again by
//! [`Manager::start`] and resumed by `session::execute`, which skips the stored targets. A
//! campaign the operator paused stays paused across a restart (killed or shut down) until the
//! operator resumes it.
//! Liveness comes from a lock file per stage ([`crate::campaign::stagelock`]): a campaign still
//! run by a live process (a foreground `csmetro run` on the same store) is left to it, a queued
//! campaign waits while another process holds its stage, and a campaign whose process died
//! without finishing is marked `interrupted` (resumable through the API) within seconds.
//!
//! Shutdown: [`Manager::shutdown`] sends `Control::Stop`: the engine stops motion and the session
//! ends the campaign `interrupted`, which the next start resumes. Only an operator's abort
//! leaves a campaign `aborted`.
use super::progress::Progress;
use std::collections::{BTreeMap, VecDeque};
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Duration;

use serde::{Deserialize, Serialize};
use serde_json::{json, Value};
use tokio::sync::{broadcast, watch};

use super::ApiError;
use crate::campaign::engine::Control;
use crate::campaign::preflight;
use crate::campaign::session::{self, Event, SharedStore};
use crate::campaign::spec::Campaign;
use crate::campaign::stagelock::{self, StageLock, StageLockError};
use crate::store::{CampaignRow, EventRow, StoreError};
use crate::types::{CampaignState, Origin};

/// How often a campaign waiting for a stage held by another process tries again.
const STAGE_RETRY: Duration = Duration::from_secs(2);

/// Failed starts of a queued campaign before it is left `interrupted`.
const MAX_START_TRIES: u32 = 5;

/// Live events buffered per subscriber before a slow one lags (it then catches up from the store).
const EVENT_BUFFER: usize = 4096;

/// A campaign as the API reports it.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct CampaignStatus {
    pub id: i64,
    pub name: String,
    pub stage: String,
    pub state: CampaignState,
    /// Targets in the plan.
    pub planned: u64,
    /// Samples committed to the store.
    pub stored: u64,
    /// stored / planned, %.
    pub percent: f64,
    /// Why it is in its state (error, who paused it...).
    pub message: Option<String>,
    /// Place in its stage's queue (0 = next), when queued.
    pub queue_position: Option<usize>,
    pub created_unix_s: f64,
    pub updated_unix_s: f64,
    /// Wall time of the attempt the service is running now (pauses included), s; `None` when
    /// the service is not running the campaign.
    #[serde(default)]
    pub elapsed_s: Option<f64>,
    /// Wall time until the last planned sample at this attempt's rate (paused time left out),
    /// s; `None` unless running with at least two samples taken in this attempt.
    #[serde(default)]
    pub eta_s: Option<f64>,
}

struct Active {
    id: i64,
    control: watch::Sender<Control>,
    /// An operator asked for the abort (as opposed to the service shutting down).
    operator_abort: bool,
    /// Keeps other processes off the stage while this campaign drives it.
    _stage_lock: Option<StageLock>,
    /// Progress of this attempt, for elapsed time and ETA.
    progress: Progress,
}

#[derive(Default)]
struct Inner {
    /// Waiting campaigns per stage, oldest first.
    queues: BTreeMap<String, VecDeque<i64>>,
    /// The campaign driving each stage.
    running: BTreeMap<String, Active>,
    /// Failed starts per queued campaign (see [`Manager::retry_start`]).
    start_failures: BTreeMap<i64, u32>,
}

impl Inner {
    fn queue_position(&self, id: i64) -> Option<(String, usize)> {
        self.queues
            .iter()
            .find_map(|(s, q)| q.iter().position(|&x| x == id).map(|p| (s.clone(), p)))
    }
    fn active(&mut self, id: i64) -> Option<&mut Active> {
        self.running.values_mut().find(|a| a.id == id)
    }
}

/// Owns the store, the queues and the running campaigns. Create with [`Manager::new`], then
/// [`Manager::start`] inside a tokio runtime.
pub struct Manager {
    limits: Limits,
    store: SharedStore,
    events: broadcast::Sender<Event>,
    results_dir: PathBuf,
    campaigns_dir: PathBuf,
    inner: Mutex<Inner>,
    shutdown: watch::Sender<bool>,
    /// Number of campaign tasks not yet finished (shutdown waits for 0).
    active: watch::Sender<usize>,
}

/// `data` with the service named as the origin of the change (`by`, `origin`).
fn by_service(mut data: Value) -> Value {
    if let (Some(d), Value::Object(o)) = (data.as_object_mut(), Origin::service().fields()) {
        d.extend(o);
    }
    data
}

/// The device checks of the pre-flight (the service's own store is open, and a submitted
/// file's output directory was probed when it was parsed).
async fn preflight_report(c: &Campaign) -> preflight::Report {
    let mut report = preflight::Report::default();
    preflight::check_devices(c, preflight::Options::default(), &mut report).await;
    report
}

/// A store failure as the client sees it: the details (with the store's server path) go to the
/// log only.
fn store_err(e: StoreError) -> ApiError {
    tracing::error!(error = %e, "store");
    ApiError::internal("the service's store failed (its log has the details)")
}

/// What one service lets clients fill.
#[derive(Debug, Clone, Copy)]
pub struct Limits {
    /// Submissions are refused (507) while the store (with its WAL) is larger, bytes.
    pub max_store_bytes: u64,
    /// Campaigns waiting per stage; one more is refused (409).
    pub max_queued_per_stage: usize,
}

impl Default for Limits {
    fn default() -> Self {
        Limits {
            max_store_bytes: 4 << 30,
            max_queued_per_stage: 100,
        }
    }
}

impl Manager {
    /// `results_dir`: where relative `[outputs] dir` of campaigns go; `campaigns_dir`: where
    /// relative paths in submitted campaign files resolve.
    pub fn new(
        store: SharedStore,
        results_dir: &Path,
        campaigns_dir: &Path,
        limits: Limits,
    ) -> Arc<Manager> {
        Arc::new(Manager {
            limits,
            store,
            events: broadcast::channel(EVENT_BUFFER).0,
            results_dir: results_dir.to_path_buf(),
            campaigns_dir: campaigns_dir.to_path_buf(),
            inner: Mutex::new(Inner::default()),
            shutdown: watch::channel(false).0,
            active: watch::channel(0).0,
        })
    }

    fn inner(&self) -> MutexGuard<'_, Inner> {
        self.inner.lock().unwrap_or_else(|e| e.into_inner())
    }

    fn db(&self) -> MutexGuard<'_, crate::store::Store> {
        self.store.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// A campaign of `stage` runs or waits in its queue: a move would cut in (409).
    pub fn stage_busy(&self, stage: &str) -> bool {
        let i = self.inner();
        i.running.contains_key(stage) || i.queues.get(stage).is_some_and(|q| !q.is_empty())
    }

    pub fn store(&self) -> &SharedStore {
        &self.store
    }

    /// Live events of every campaign (samples included, with id 0: they are not in the log).
    pub fn subscribe(&self) -> broadcast::Receiver<Event> {
        self.events.subscribe()
    }

    /// Becomes true when the service starts shutting down.
    pub fn shutdown_signal(&self) -> watch::Receiver<bool> {
        self.shutdown.subscribe()
    }

    pub fn shutting_down(&self) -> bool {
        *self.shutdown.borrow()
    }

    /// Stores an event in the campaign's log and broadcasts it.
    fn emit(&self, id: i64, kind: &str, data: Value) {
        let r = self.db().add_event(id, kind, &data);
        match r {
            Ok(eid) => {
                let _ = self.events.send(Event {
                    id: eid,
                    campaign: id,
                    unix_s: crate::store::now_unix_s(),
                    kind: kind.into(),
                    data,
                });
            }
            Err(e) => tracing::warn!(campaign = id, kind, error = %e, "event not stored"),
        }
    }

    /// Queues every campaign a previous service left unfinished (oldest first) and starts what
    /// can start. Returns their ids.
    pub fn start(self: &Arc<Self>) -> Result<Vec<i64>, String> {
        let rows = self.db().unfinished().map_err(|e| e.to_string())?;
        let mut ids = Vec::new();
        let db_path = self.db().path().map(Path::to_path_buf);
        for row in rows {
            // Running or paused in a process that is still alive (a foreground `csmetro run` on
            // this store): that process owns it; do not drive the stage a second time.
            if row.state.is_in_progress() {
                if let Some(e) = db_path
                    .as_deref()
                    .and_then(|p| stagelock::held_elsewhere(p, &row.stage))
                {
                    tracing::warn!(campaign = row.id, error = %e, "left to the process that runs it");
                    continue;
                }
            }
            if row.state == CampaignState::Paused {
                // The operator's pause holds: the stage stays where it is until they resume.
                tracing::info!(campaign = row.id, name = %row.name, "paused by the operator; left paused at start");
                continue;
            }
            if row.state != CampaignState::Queued {
                let msg = format!("resumed at service start (was {})", row.state.as_str());
                self.db()
                    .set_state(row.id, CampaignState::Queued, Some(&msg))
                    .map_err(|e| e.to_string())?;
                self.emit(
                    row.id,
                    "requeued",
                    by_service(
                        json!({"reason": "service start", "previous_state": row.state.as_str()}),
                    ),
                );
            }
            tracing::info!(campaign = row.id, name = %row.name, stage = %row.stage, previous_state = row.state.as_str(), "queued again at start");
            self.inner()
                .queues
                .entry(row.stage.clone())
                .or_default()
                .push_back(row.id);
            ids.push(row.id);
        }
        self.follow_pauses();
        self.follow_progress();
        self.watch_orphans();
        let stages: Vec<String> = self.inner().queues.keys().cloned().collect();
        for s in stages {
            self.schedule(&s);
        }
        Ok(ids)
    }

    /// Campaigns that a foreground process (`csmetro run`/`resume` on this store) left
    /// `running` or `paused` when it died without finishing (kill -9, a crash): nobody holds
    /// their stage any more and nobody will finish them. Marked `interrupted` (checked every
    /// [`STAGE_RETRY`]), so that resume and abort take them through the API instead of refusing
    /// a campaign that looks alive until the next service start.
    fn watch_orphans(self: &Arc<Self>) {
        let Some(db_path) = self.db().path().map(Path::to_path_buf) else {
            return;
        };
        let me = Arc::downgrade(self);
        let mut stop = self.shutdown_signal();
        tokio::spawn(async move {
            loop {
                tokio::select! {
                    _ = tokio::time::sleep(STAGE_RETRY) => {}
                    _ = stop.changed() => return,
                }
                let Some(m) = me.upgrade() else { return };
                if m.shutting_down() {
                    return;
                }
                m.sweep_orphans(&db_path);
            }
        });
    }

    /// One pass of [`Manager::watch_orphans`].
    fn sweep_orphans(&self, db_path: &Path) {
        for row in self.unfinished_rows("orphan check") {
            // Paused by the operator: held on purpose (possibly across a restart), not orphaned.
            if row.state != CampaignState::Running || self.inner().active(row.id).is_some() {
                continue;
            }
            // A held stage means its process is alive (or the service drives the stage and will
            // look again later). The lock is kept while the state is read again and changed: no
            // process can take the campaign up in between, and one that finished it released
            // the stage only after storing its final state.
            let Ok(_stage) = stagelock::try_lock(db_path, &row.stage) else {
                continue;
            };
            self.mark_orphan(row.id);
        }
    }

    /// The store's unfinished campaigns; none (and a warning naming `what`) when it cannot be
    /// read: the check runs again later.
    fn unfinished_rows(&self, what: &str) -> Vec<CampaignRow> {
        self.db().unfinished().unwrap_or_else(|e| {
            tracing::warn!(error = %e, "{what}: cannot read the store");
            Vec::new()
        })
    }

    /// Marks campaign `id` `interrupted` if the store still says `running`: the caller holds its
    /// stage's lock, so the process that ran it is gone.
    fn mark_orphan(&self, id: i64) {
        let now = self.db().campaign(id).ok().flatten();
        let Some(now) = now.filter(|r| r.state == CampaignState::Running) else {
            return;
        };
        let stored = self.db().sample_count(id).unwrap_or(0);
        let msg = format!(
            "the process that ran it exited without finishing (was {}); {stored} of {} \
             samples are stored and a resume continues from there",
            now.state.as_str(),
            now.planned
        );
        tracing::warn!(campaign = id, stage = %now.stage, "{msg}");
        if let Err(e) = self
            .db()
            .set_state(id, CampaignState::Interrupted, Some(&msg))
        {
            tracing::warn!(campaign = id, error = %e, "orphan check: state not stored");
            return;
        }
        self.emit(
            id,
            "interrupted",
            by_service(json!({"reason": "its process exited without finishing",
                   "previous_state": now.state.as_str(), "stored": stored, "resumable": true})),
        );
    }

    /// With `stage`'s lock held: campaigns the store still shows `running` on it that this
    /// service does not run are orphans of a dead process. Marked `interrupted` before `id`
    /// starts, so the store's one-running-campaign-per-stage rule does not refuse `id` (a
    /// campaign submitted just as a foreground `csmetro run` died was stranded `queued`).
    fn reclaim_stage(&self, stage: &str, id: i64) {
        for row in self.unfinished_rows("stage reclaim") {
            if row.stage == stage
                && row.id != id
                && row.state == CampaignState::Running
                && self.inner().active(row.id).is_none()
            {
                self.mark_orphan(row.id);
            }
        }
    }

    /// A pause asked for while a campaign was starting is overwritten by the session's
    /// `running`: put `paused` back once it has started (the engine holds at its first point).
    fn follow_pauses(self: &Arc<Self>) {
        let mut rx = self.events.subscribe();
        let me = Arc::downgrade(self);
        tokio::spawn(async move {
            loop {
                let e = match rx.recv().await {
                    Ok(e) => e,
                    Err(broadcast::error::RecvError::Lagged(_)) => continue,
                    Err(broadcast::error::RecvError::Closed) => return,
                };
                if e.kind != "started" && e.kind != "resumed_from_store" {
                    continue;
                }
                let Some(m) = me.upgrade() else { return };
                let mut inner = m.inner();
                let paused = inner
                    .active(e.campaign)
                    .is_some_and(|a| *a.control.borrow() == Control::Pause);
                if paused {
                    if let Err(err) = m.db().set_state(
                        e.campaign,
                        CampaignState::Paused,
                        Some("paused by the operator"),
                    ) {
                        // The engine holds anyway; only the stored state lags.
                        tracing::error!(campaign = e.campaign, error = %err, "paused state not stored");
                    }
                }
            }
        });
    }

    /// Notes each running campaign's first sample of its attempt: where its ETA's rate starts.
    fn follow_progress(self: &Arc<Self>) {
        let mut rx = self.events.subscribe();
        let me = Arc::downgrade(self);
        tokio::spawn(async move {
            loop {
                let e = match rx.recv().await {
                    Ok(e) => e,
                    Err(broadcast::error::RecvError::Lagged(_)) => continue,
                    Err(broadcast::error::RecvError::Closed) => return,
                };
                if e.kind != "sample" {
                    continue;
                }
                let Some(m) = me.upgrade() else { return };
                let mut inner = m.inner();
                if let Some(a) = inner.active(e.campaign) {
                    if a.progress.first_sample.is_none() {
                        // Counted from the start so a missed (lagged) first event costs nothing.
                        let n = a.progress.stored_at_start + 1;
                        a.progress.first_sample = Some((e.unix_s, n));
                    }
                }
            }
        });
    }

    /// Validates and stores a campaign file sent by a client, and queues it. `name` is the
    /// file name the client gave (errors name it; relative paths resolve in `campaigns_dir`).
    pub fn submit(self: &Arc<Self>, text: &str, name: &str) -> Result<CampaignStatus, ApiError> {
        self.submit_by(text, name, &Origin::api(None, None))
    }

    /// [`Manager::submit`], the `queued` event naming who submitted it.
    pub fn submit_by(
        self: &Arc<Self>,
        text: &str,
        name: &str,
        origin: &Origin,
    ) -> Result<CampaignStatus, ApiError> {
        if self.shutting_down() {
            return Err(ApiError::conflict("the service is shutting down"));
        }
        let file = Path::new(name)
            .file_name()
            .map(|f| f.to_string_lossy().into_owned())
            .filter(|f| !f.is_empty())
            .unwrap_or_else(|| "submitted.toml".into());
        self.check_quota()?;
        let mut c = Campaign::parse(text, &file, &self.campaigns_dir)
            .map_err(|e| ApiError::bad_request(e.to_string()))?;
        // `verify = ID`: a characterisation in this service's store only.
        crate::campaign::verification::resolve(&mut c, &self.db())
            .map_err(|e| ApiError::bad_request(e.to_string()))?;
        // load_stored resolves relative paths from the stored path's directory.
        c.origin = self.campaigns_dir.join(&file).display().to_string();
        self.preflight_at_submit(&c)?;
        let stage = c.spec.campaign.stage.clone();
        let waiting = self.inner().queues.get(&stage).map_or(0, VecDeque::len);
        if waiting >= self.limits.max_queued_per_stage {
            return Err(ApiError::conflict(format!(
                "{waiting} campaigns already wait for stage {stage} (the service's \
                 [campaigns] max_queued): submit again when some have run"
            )));
        }
        let id = session::create(&self.store, &c).map_err(|e| {
            tracing::error!(error = %e, "campaign not recorded");
            ApiError::internal(
                "the campaign could not be recorded (the service's log has the details)",
            )
        })?;
        let position = {
            let mut inner = self.inner();
            let q = inner.queues.entry(stage.clone()).or_default();
            q.push_back(id);
            q.len() - 1
        };
        tracing::info!(campaign = id, name = %c.spec.campaign.name, stage = %stage, "submitted");
        self.emit(
            id,
            "queued",
            json!({"stage": stage, "position": position, "name": c.spec.campaign.name,
                   "by": origin.describe(), "origin": origin}),
        );
        self.schedule(&stage);
        self.status(id)
    }

    /// 507 while the store file (and its write-ahead log) is over [`Limits::max_store_bytes`]:
    /// clients cannot fill the disk one campaign at a time.
    fn check_quota(&self) -> Result<(), ApiError> {
        let Some(db) = self.db().path().map(Path::to_path_buf) else {
            return Ok(());
        };
        let size = |p: &Path| std::fs::metadata(p).map_or(0, |m| m.len());
        let mut wal = db.clone().into_os_string();
        wal.push("-wal");
        let used = size(&db) + size(Path::new(&wal));
        if used > self.limits.max_store_bytes {
            tracing::warn!(
                used,
                max = self.limits.max_store_bytes,
                "store over its quota"
            );
            return Err(ApiError::new(
                axum::http::StatusCode::INSUFFICIENT_STORAGE,
                format!(
                    "the store holds {} MB, over the service's quota ([storage] max_store_mb = \
                     {}): nothing new is recorded until an operator frees space",
                    used >> 20,
                    self.limits.max_store_bytes >> 20
                ),
            ));
        }
        Ok(())
    }

    /// The pre-flight of `csmetro check`, before the campaign is recorded, when its stage is
    /// free now (held for the check). A campaign queued behind another, or whose stage another
    /// process drives, is checked when it starts. 409 when the file must change, 503 when the
    /// rig must; the message names the failed check.
    fn preflight_at_submit(&self, c: &Campaign) -> Result<(), ApiError> {
        let stage = &c.spec.campaign.stage;
        {
            let inner = self.inner();
            if inner.running.contains_key(stage)
                || inner.queues.get(stage).is_some_and(|q| !q.is_empty())
            {
                return Ok(());
            }
        }
        let db_path = self.db().path().map(Path::to_path_buf);
        let _lock = match db_path.as_deref().map(|p| stagelock::try_lock(p, stage)) {
            Some(Err(_)) => return Ok(()),
            Some(Ok(l)) => Some(l),
            None => None,
        };
        // Called on a blocking thread of the service's runtime (routes::submit).
        let report = tokio::runtime::Handle::current().block_on(preflight_report(c));
        if !report.blocks() {
            for w in report.warnings() {
                tracing::warn!(campaign = %c.spec.campaign.name, "{w}");
            }
            return Ok(());
        }
        let status = match report.failure_class() {
            preflight::Class::Config => axum::http::StatusCode::CONFLICT,
            preflight::Class::Device | preflight::Class::View => {
                axum::http::StatusCode::SERVICE_UNAVAILABLE
            }
        };
        tracing::warn!(campaign = %c.spec.campaign.name, "{}; not queued", report.error_message());
        Err(ApiError::new(
            status,
            format!("{}; the campaign was not queued", report.client_message()),
        ))
    }

    /// Starts the next queued campaign of `stage` unless one drives it already.
    fn schedule(self: &Arc<Self>, stage: &str) {
        loop {
            if self.shutting_down() {
                return;
            }
            let db_path = self.db().path().map(Path::to_path_buf);
            let (id, rx, locked) = {
                let mut inner = self.inner();
                if inner.running.contains_key(stage) {
                    return;
                }
                let Some(&id) = inner.queues.get(stage).and_then(|q| q.front()) else {
                    return;
                };
                let lock = match db_path.as_deref().map(|p| stagelock::try_lock(p, stage)) {
                    None => None,
                    Some(Ok(l)) => Some(l),
                    Some(Err(StageLockError::Io { path, source })) => {
                        // Not "busy": waiting would never end. The reason, not the server
                        // path, goes to the campaign (its status is served by the API).
                        inner.queues.get_mut(stage).and_then(|q| q.pop_front());
                        drop(inner);
                        tracing::error!(campaign = id, lock = %path.display(), error = %source,
                            "cannot take the stage lock");
                        self.interrupt(
                            id,
                            format!(
                                "cannot take the lock of stage `{stage}`: {}; fix the lock \
                                 directory (CSMETRO_LOCK_DIR) and resume",
                                crate::tomlpos::io_reason(&source)
                            ),
                        );
                        continue;
                    }
                    Some(Err(e)) => {
                        drop(inner);
                        self.wait_for_stage(id, stage, e);
                        return;
                    }
                };
                inner.queues.get_mut(stage).and_then(|q| q.pop_front());
                let locked = lock.is_some();
                let (tx, rx) = watch::channel(Control::Run);
                inner.running.insert(
                    stage.to_string(),
                    Active {
                        id,
                        control: tx,
                        operator_abort: false,
                        _stage_lock: lock,
                        progress: Progress::default(),
                    },
                );
                (id, rx, locked)
            };
            if locked {
                self.reclaim_stage(stage, id);
            }
            // Another process may have finished it while it waited for the stage.
            if self
                .db()
                .campaign(id)
                .ok()
                .flatten()
                .is_some_and(|r| r.state.is_final())
            {
                self.inner().running.remove(stage);
                continue;
            }
            match session::load_stored(&self.store, id) {
                Ok(c) => {
                    self.launch(id, stage.to_string(), c, rx);
                    return;
                }
                Err(e) => {
                    // E.g. its stage model file is gone: keep it resumable once fixed.
                    tracing::error!(campaign = id, error = %e, "cannot load the stored campaign");
                    self.inner().running.remove(stage);
                    self.interrupt(id, format!("cannot load: {e}"));
                }
            }
        }
    }

    /// The head of `stage`'s queue stays queued while another process holds the stage; the
    /// scheduler tries again every [`STAGE_RETRY`].
    fn wait_for_stage(self: &Arc<Self>, id: i64, stage: &str, e: StageLockError) {
        let msg = e.to_string();
        let first = self
            .db()
            .campaign(id)
            .ok()
            .flatten()
            .is_none_or(|r| r.message.as_deref() != Some(msg.as_str()));
        if first {
            tracing::warn!(campaign = id, error = %msg, "waiting for the stage");
            if let Err(e) = self.db().set_state(id, CampaignState::Queued, Some(&msg)) {
                tracing::error!(campaign = id, error = %e, "waiting state not stored");
            }
            self.emit(
                id,
                "waiting_for_stage",
                by_service(json!({"stage": stage, "reason": msg})),
            );
        }
        self.schedule_later(stage);
    }

    /// Runs [`Manager::schedule`] for `stage` again after [`STAGE_RETRY`] (unless the service
    /// stops first).
    fn schedule_later(self: &Arc<Self>, stage: &str) {
        let (me, stage) = (Arc::clone(self), stage.to_string());
        let mut stop = self.shutdown_signal();
        tokio::spawn(async move {
            tokio::select! {
                _ = tokio::time::sleep(STAGE_RETRY) => me.schedule(&stage),
                _ = stop.changed() => {}
            }
        });
    }

    /// Ends a campaign's attempt as resumable (state interrupted) and closes its event stream.
    fn interrupt(&self, id: i64, msg: String) {
        if let Err(e) = self
            .db()
            .set_state(id, CampaignState::Interrupted, Some(&msg))
        {
            // The event below still tells clients; the store is what a restart reads.
            tracing::error!(campaign = id, error = %e, "interrupted state not stored");
        }
        self.emit(
            id,
            "error",
            by_service(json!({"cause": "service", "error": msg, "resumable": true})),
        );
        self.emit(
            id,
            "finished",
            json!({"state": "interrupted", "error": msg}),
        );
    }

    fn launch(
        self: &Arc<Self>,
        id: i64,
        stage: String,
        mut c: Campaign,
        control: watch::Receiver<Control>,
    ) {
        // Below the service's results_dir whatever the template (absolute ones included).
        c.spec.outputs.dir =
            crate::campaign::results::service_outputs(&self.results_dir, &c.spec.outputs.dir);
        tracing::info!(campaign = id, name = %c.spec.campaign.name, stage = %stage, "starting");
        // Nothing is measured before `execute` runs: this is what earlier attempts stored.
        let stored = self.db().sample_count(id).unwrap_or(0);
        if let Some(a) = self.inner().active(id) {
            a.progress = Progress::new(stored);
        }
        self.active.send_modify(|n| *n += 1);
        let me = Arc::clone(self);
        let (store, events) = (self.store.clone(), self.events.clone());
        tokio::spawn(async move {
            // Checked again on the stage it now holds, before it is recorded as started: the
            // rig may have changed since it was queued. A failure leaves it resumable.
            let report = preflight_report(&c).await;
            if report.blocks() {
                tracing::warn!(campaign = id, "{}; not started", report.error_message());
                let msg = format!("{}; not started", report.client_message());
                me.interrupt(id, msg.clone());
                me.finished(id, &stage, Ok(Err(msg)));
                return;
            }
            let run = session::execute(store, id, c, control, events, Box::new(|_| {}));
            // A panic in the session must still free the stage and count down.
            let r = tokio::spawn(run).await;
            me.finished(id, &stage, r);
        });
    }

    fn finished(
        self: &Arc<Self>,
        id: i64,
        stage: &str,
        r: Result<Result<session::Finished, String>, tokio::task::JoinError>,
    ) {
        let operator_abort = {
            let mut inner = self.inner();
            match inner.running.get(stage) {
                Some(a) if a.id == id => {
                    let o = a.operator_abort;
                    inner.running.remove(stage);
                    o
                }
                _ => false,
            }
        };
        match r {
            Ok(Ok(fin)) => {
                self.inner().start_failures.remove(&id);
                tracing::info!(campaign = id, state = fin.state.as_str(), "campaign ended");
                if fin.state == CampaignState::Interrupted && !operator_abort {
                    self.emit(
                        id,
                        "interrupted",
                        by_service(json!({"reason": "service shutdown", "resumable": true})),
                    );
                }
            }
            Ok(Err(e)) => {
                tracing::warn!(campaign = id, error = %e, "campaign stopped");
                if self.retry_start(id, stage, &e) {
                    self.active.send_modify(|n| *n = n.saturating_sub(1));
                    return;
                }
            }
            Err(e) => {
                let msg = format!("campaign task failed: {e}");
                tracing::error!(campaign = id, error = %msg);
                self.interrupt(id, msg);
            }
        }
        self.active.send_modify(|n| *n = n.saturating_sub(1));
        self.schedule(stage);
    }

    /// A campaign whose attempt failed before it started (the store still says `queued`)
    /// goes back to the head of its stage's queue and is tried again after [`STAGE_RETRY`];
    /// after [`MAX_START_TRIES`] failures it is `interrupted` with the reason (resumable).
    /// Either way it stays controllable. Returns whether it was queued again.
    fn retry_start(self: &Arc<Self>, id: i64, stage: &str, error: &str) -> bool {
        let queued = self
            .db()
            .campaign(id)
            .ok()
            .flatten()
            .is_some_and(|r| r.state == CampaignState::Queued);
        if !queued {
            return false;
        }
        let tries = {
            let mut inner = self.inner();
            let n = inner.start_failures.entry(id).or_insert(0);
            *n += 1;
            *n
        };
        if tries >= MAX_START_TRIES {
            self.inner().start_failures.remove(&id);
            self.interrupt(
                id,
                format!("could not start after {tries} tries: {error}; resume once fixed"),
            );
            return false;
        }
        tracing::warn!(campaign = id, tries, error = %error, "could not start; queued again");
        self.inner()
            .queues
            .entry(stage.to_string())
            .or_default()
            .push_front(id);
        self.schedule_later(stage);
        true
    }

    fn row(&self, id: i64) -> Result<CampaignRow, ApiError> {
        self.db()
            .campaign(id)
            .map_err(store_err)?
            .ok_or_else(|| ApiError::not_found(format!("no campaign {id}")))
    }

    fn status_of(
        &self,
        row: CampaignRow,
        queue: Option<usize>,
    ) -> Result<CampaignStatus, ApiError> {
        let stored = self.db().sample_count(row.id).map_err(store_err)?;
        let percent = if row.planned == 0 {
            0.0
        } else {
            (100.0 * stored as f64 / row.planned as f64).min(100.0)
        };
        let progress = self.inner().active(row.id).map(|a| a.progress);
        let (elapsed_s, eta_s) = match progress {
            Some(p) => {
                let running = row.state == CampaignState::Running;
                let (e, eta) = p.estimate(crate::store::now_unix_s(), stored, row.planned, running);
                (Some(e), eta)
            }
            None => (None, None),
        };
        Ok(CampaignStatus {
            id: row.id,
            name: row.name,
            stage: row.stage,
            state: row.state,
            planned: row.planned,
            stored,
            percent,
            message: row.message,
            queue_position: queue,
            created_unix_s: row.created_unix_s,
            updated_unix_s: row.updated_unix_s,
            elapsed_s,
            eta_s,
        })
    }

    /// State and progress of one campaign.
    pub fn status(&self, id: i64) -> Result<CampaignStatus, ApiError> {
        let pos = self.inner().queue_position(id).map(|(_, p)| p);
        let row = self.row(id)?;
        self.status_of(row, pos)
    }

    /// Every campaign, newest first.
    pub fn list(&self) -> Result<Vec<CampaignStatus>, ApiError> {
        let rows = self.db().campaigns().map_err(store_err)?;
        rows.into_iter()
            .map(|r| {
                let pos = self.inner().queue_position(r.id).map(|(_, p)| p);
                self.status_of(r, pos)
            })
            .collect()
    }

    /// Ids of the running campaigns and of the queued ones.
    pub fn overview(&self) -> (Vec<i64>, Vec<i64>) {
        let inner = self.inner();
        (
            inner.running.values().map(|a| a.id).collect(),
            inner.queues.values().flatten().copied().collect(),
        )
    }

    fn refuse(&self, id: i64, what: &str) -> ApiError {
        match self.row(id) {
            Ok(row) => ApiError::conflict(format!(
                "campaign {id} is {}: cannot {what} it",
                row.state.as_str()
            )),
            Err(e) => e,
        }
    }

    /// Holds a running campaign between two points (motion ends on target, nothing is lost).
    pub fn pause(&self, id: i64) -> Result<CampaignStatus, ApiError> {
        self.pause_by(id, &Origin::api(None, None))
    }

    /// [`Manager::pause`]; the `paused` event and the status message say who paused it.
    pub fn pause_by(&self, id: i64, origin: &Origin) -> Result<CampaignStatus, ApiError> {
        let msg = format!("paused by {}", origin.describe());
        {
            let mut inner = self.inner();
            let Some(a) = inner.active(id) else {
                // Queued (in the queue, or left `queued` by a failed start): held before it
                // starts; resume queues it again.
                let in_queue = inner.queue_position(id);
                if let Some((stage, _)) = &in_queue {
                    if let Some(q) = inner.queues.get_mut(stage) {
                        q.retain(|&x| x != id);
                    }
                }
                drop(inner);
                let row = self.row(id)?;
                if in_queue.is_none() && row.state != CampaignState::Queued {
                    return Err(self.refuse(id, "pause"));
                }
                self.db()
                    .set_state(id, CampaignState::Paused, Some(&msg))
                    .map_err(store_err)?;
                self.emit_by_operator(id, "paused", origin);
                return self.status(id);
            };
            if a.control.borrow().halts() {
                drop(inner);
                return Err(self.refuse(id, "pause"));
            }
            a.control.send_replace(Control::Pause);
            a.progress.pause(crate::store::now_unix_s());
            self.db()
                .set_state(id, CampaignState::Paused, Some(&msg))
                .map_err(store_err)?;
        }
        self.emit_by_operator(id, "paused", origin);
        self.status(id)
    }

    /// An operator's pause or resume as an event (and a log line) saying who.
    fn emit_by_operator(&self, id: i64, kind: &str, origin: &Origin) {
        let mut data = origin.fields();
        data["cause"] = json!("operator");
        self.emit(id, kind, data);
        tracing::info!(campaign = id, by = %origin.describe(), "{kind}");
    }

    /// Continues a paused campaign, or queues an interrupted one again (it resumes from its
    /// last stored sample).
    pub fn resume(self: &Arc<Self>, id: i64) -> Result<CampaignStatus, ApiError> {
        self.resume_by(id, &Origin::api(None, None))
    }

    /// [`Manager::resume`]; the `resumed` (running again) or `requeued` event says who.
    pub fn resume_by(
        self: &Arc<Self>,
        id: i64,
        origin: &Origin,
    ) -> Result<CampaignStatus, ApiError> {
        if self.shutting_down() {
            return Err(ApiError::conflict("the service is shutting down"));
        }
        let requeue_stage = {
            let mut inner = self.inner();
            if let Some(a) = inner.active(id) {
                if *a.control.borrow() != Control::Pause {
                    drop(inner);
                    return Err(self.refuse(id, "resume"));
                }
                a.control.send_replace(Control::Run);
                a.progress.resume(crate::store::now_unix_s());
                self.db()
                    .set_state(id, CampaignState::Running, None)
                    .map_err(store_err)?;
                drop(inner);
                self.emit_by_operator(id, "resumed", origin);
                return self.status(id);
            } else if inner.queue_position(id).is_some() {
                drop(inner);
                return Err(self.refuse(id, "resume"));
            } else {
                let row = self.row(id)?;
                // Interrupted, or paused by the operator before a service restart.
                if !matches!(
                    row.state,
                    CampaignState::Interrupted | CampaignState::Paused
                ) {
                    drop(inner);
                    return Err(self.refuse(id, "resume"));
                }
                self.db()
                    .set_state(
                        id,
                        CampaignState::Queued,
                        Some(&format!("resumed by {}", origin.describe())),
                    )
                    .map_err(store_err)?;
                inner
                    .queues
                    .entry(row.stage.clone())
                    .or_default()
                    .push_back(id);
                Some(row.stage)
            }
        };
        tracing::info!(campaign = id, by = %origin.describe(), "resumed");
        if let Some(stage) = requeue_stage {
            let mut data = origin.fields();
            data["reason"] = json!("operator");
            self.emit(id, "requeued", data);
            self.schedule(&stage);
        }
        self.status(id)
    }

    /// Aborts a campaign: a running one stops motion and ends `aborted`; a queued or
    /// interrupted one is marked aborted at once.
    pub fn abort(self: &Arc<Self>, id: i64) -> Result<CampaignStatus, ApiError> {
        self.abort_by(id, &Origin::api(None, None))
    }

    /// [`Manager::abort`]; the `abort_requested` (running) or `finished` event says who.
    pub fn abort_by(
        self: &Arc<Self>,
        id: i64,
        origin: &Origin,
    ) -> Result<CampaignStatus, ApiError> {
        let mut inner = self.inner();
        if let Some(a) = inner.active(id) {
            a.operator_abort = true;
            a.control.send_replace(Control::Abort);
            drop(inner);
            self.emit(id, "abort_requested", origin.fields());
            tracing::info!(campaign = id, by = %origin.describe(), "abort requested");
            return self.status(id);
        }
        let queued = inner.queue_position(id);
        if let Some((stage, _)) = &queued {
            if let Some(q) = inner.queues.get_mut(stage) {
                q.retain(|&x| x != id);
            }
        }
        drop(inner);
        let row = self.row(id)?;
        let resting = matches!(
            row.state,
            CampaignState::Interrupted | CampaignState::Paused | CampaignState::Queued
        );
        if queued.is_none() && !resting {
            return Err(self.refuse(id, "abort"));
        }
        self.db()
            .set_state(
                id,
                CampaignState::Aborted,
                Some(&format!(
                    "aborted by {} before it ran again",
                    origin.describe()
                )),
            )
            .map_err(store_err)?;
        let mut data = origin.fields();
        data["state"] = json!("aborted");
        self.emit(id, "finished", data);
        tracing::info!(campaign = id, "aborted while not running");
        self.status(id)
    }

    /// A campaign's log after event `after` (0: all).
    pub fn events_after(&self, id: i64, after: i64) -> Result<Vec<EventRow>, ApiError> {
        self.row(id)?;
        self.db().events_after(id, after).map_err(store_err)
    }

    /// Committed samples in commit order after cursor `after` (0: from the first), at most
    /// `limit`.
    pub fn samples_after(
        &self,
        id: i64,
        after: i64,
        limit: usize,
    ) -> Result<Vec<(i64, crate::types::SampleRecord)>, ApiError> {
        self.row(id)?;
        self.db().samples_after(id, after, limit).map_err(store_err)
    }

    pub fn result_names(&self, id: i64) -> Result<Vec<String>, ApiError> {
        self.row(id)?;
        self.db().result_names(id).map_err(store_err)
    }

    /// (content type, bytes) of a stored result.
    pub fn result(&self, id: i64, name: &str) -> Result<(String, Vec<u8>), ApiError> {
        self.row(id)?;
        self.db()
            .result(id, name)
            .map_err(store_err)?
            .ok_or_else(|| ApiError::not_found(format!("campaign {id} has no result {name:?}")))
    }

    /// Stops every running campaign (motion first) and leaves them, and the queued ones,
    /// to be resumed at the next start; waits up to `grace` for them. Returns how many were
    /// still running when the wait ended.
    pub async fn shutdown(&self, grace: Duration) -> usize {
        self.shutdown.send_replace(true);
        for a in self.inner().running.values() {
            tracing::info!(campaign = a.id, "stopping for shutdown");
            // An abort already requested stays an abort: turned into a resumable stop, the
            // campaign would end `interrupted` and run again at the next start.
            a.control.send_if_modified(|c| {
                let stop = *c != Control::Abort;
                if stop {
                    *c = Control::Stop;
                }
                stop
            });
        }
        let mut rx = self.active.subscribe();
        let _ = tokio::time::timeout(grace, rx.wait_for(|n| *n == 0)).await;
        let left = *rx.borrow();
        left
    }
}
