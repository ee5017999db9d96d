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
mod control;
mod error;
mod follow;
mod schedule;
mod submit;

use super::progress::Progress;
use std::collections::{BTreeMap, VecDeque};
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Duration;

use serde::{Deserialize, Serialize};
use serde_json::{json, Value};
use tokio::sync::{broadcast, watch};

use crate::campaign::engine::Control;
use crate::campaign::preflight;
use crate::campaign::session::{self, Event, SharedStore};
use crate::campaign::spec::Campaign;
use crate::campaign::stagelock::{self, StageLock, StageLockError};
use crate::store::{CampaignRow, EventRow, StoreError};
use crate::types::{CampaignState, Origin};
pub use error::ManagerError;

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

    /// The store, off the async runtime (see [`SharedStore::with`]).
    fn db<T>(&self, f: impl FnOnce(&crate::store::Store) -> T) -> T {
        self.store.with(f)
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

    /// Stores an event in the campaign's log and broadcasts it. The service's own events
    /// (queued, paused, requeued...) record a change already made and answered: one the store
    /// refuses goes to the service's log, as no campaign run collects it.
    fn emit(&self, id: i64, kind: &str, data: Value) {
        if let Err(e) = crate::campaign::events::emit(&self.store, &self.events, id, kind, data) {
            tracing::error!(campaign = id, kind, error = %e, "event not stored");
        }
    }

    /// Queues every campaign a previous service left unfinished (oldest first) and starts what
    /// can start. Returns their ids.
    pub fn start(self: &Arc<Self>) -> Result<Vec<i64>, StoreError> {
        let rows = self.db(|s| s.unfinished())?;
        let mut ids = Vec::new();
        let db_path = self.store.path().map(Path::to_path_buf);
        for row in rows {
            // Running or paused in a process that is still alive (a foreground `csmetro run` on
            // this store): that process owns it; do not drive the stage a second time.
            if row.state.is_in_progress() {
                if let Some(e) = db_path.as_deref().and_then(|p| {
                    let scope = stagelock::Scope::of_spec_toml(&row.spec_toml);
                    stagelock::held_elsewhere_scoped(p, &row.stage, scope)
                }) {
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
                self.db(|s| s.set_state(row.id, CampaignState::Queued, Some(&msg)))?;
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

    fn row(&self, id: i64) -> Result<CampaignRow, ManagerError> {
        self.db(|s| s.campaign(id))?
            .ok_or(ManagerError::NoCampaign(id))
    }

    fn status_of(
        &self,
        row: CampaignRow,
        queue: Option<usize>,
    ) -> Result<CampaignStatus, ManagerError> {
        let stored = self.db(|s| s.sample_count(row.id))?;
        let percent = if row.planned == 0 {
            0.0
        } else {
            (100.0 * stored as f64 / row.planned as f64).min(100.0)
        };
        // Only a running or paused campaign has an elapsed time: the session stores its end
        // before the manager takes it off its table, and a status read in between must not
        // report a done campaign as still counting (seen once in CI).
        let live = matches!(row.state, CampaignState::Running | CampaignState::Paused);
        let progress = live
            .then(|| self.inner().active(row.id).map(|a| a.progress))
            .flatten();
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
    pub fn status(&self, id: i64) -> Result<CampaignStatus, ManagerError> {
        let pos = self.inner().queue_position(id).map(|(_, p)| p);
        let row = self.row(id)?;
        self.status_of(row, pos)
    }

    /// Every campaign, newest first.
    pub fn list(&self) -> Result<Vec<CampaignStatus>, ManagerError> {
        let rows = self.db(|s| s.campaigns())?;
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

    /// A campaign's log after event `after` (0: all).
    pub fn events_after(&self, id: i64, after: i64) -> Result<Vec<EventRow>, ManagerError> {
        self.row(id)?;
        self.db(|s| s.events_after(id, after))
            .map_err(ManagerError::from)
    }

    /// Committed samples in commit order after cursor `after` (0: from the first), at most
    /// `limit`.
    pub fn samples_after(
        &self,
        id: i64,
        after: i64,
        limit: usize,
    ) -> Result<Vec<(i64, crate::types::SampleRecord)>, ManagerError> {
        self.row(id)?;
        self.db(|s| s.samples_after(id, after, limit))
            .map_err(ManagerError::from)
    }

    pub fn result_names(&self, id: i64) -> Result<Vec<String>, ManagerError> {
        self.row(id)?;
        self.db(|s| s.result_names(id)).map_err(ManagerError::from)
    }

    /// (content type, bytes) of a stored result.
    pub fn result(&self, id: i64, name: &str) -> Result<(String, Vec<u8>), ManagerError> {
        self.row(id)?;
        self.db(|s| s.result(id, name))?
            .ok_or_else(|| ManagerError::NoResult {
                id,
                name: name.to_string(),
            })
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
