//! A campaign's log and stream: events stored in its store and sent to whoever watches, and
//! samples committed and streamed (`csmetro watch`, server-sent events).
use std::sync::{Arc, Mutex};

use serde::Serialize;
use serde_json::{json, Value};
use tokio::sync::broadcast;

use crate::store::{Store, StoreError};
use crate::types::SampleRecord;

/// A campaign event as stored and streamed (server-sent events, `csmetro watch`).
#[derive(Debug, Clone, Serialize, serde::Deserialize)]
pub struct Event {
    pub id: i64,
    pub campaign: i64,
    pub unix_s: f64,
    pub kind: String,
    pub data: Value,
}

pub type SharedStore = Arc<Mutex<Store>>;

pub(crate) fn lock(s: &SharedStore) -> std::sync::MutexGuard<'_, Store> {
    s.lock().unwrap_or_else(|e| e.into_inner())
}

/// Runs a store write (the lock, then an SQLite commit that waits on fsync) without stalling the
/// async runtime: on a multi-threaded runtime's worker the worker hands its other tasks (the API,
/// the other stage's campaign) to another thread for the duration; elsewhere (a plain or blocking
/// thread, a current-thread runtime, where `block_in_place` is not allowed) it runs as it is.
fn off_runtime<T>(f: impl FnOnce() -> T) -> T {
    use tokio::runtime::{Handle, RuntimeFlavor};
    match Handle::try_current() {
        Ok(h) if h.runtime_flavor() == RuntimeFlavor::MultiThread => tokio::task::block_in_place(f),
        _ => f(),
    }
}

/// Commits sample `s` of campaign `id` and, when it is new (a resumed run may measure a stored
/// target again), streams it as a live `sample` event (id 0: samples are not in the event log).
pub(crate) fn store_sample(
    store: &SharedStore,
    events: &broadcast::Sender<Event>,
    id: i64,
    s: &SampleRecord,
) -> Result<bool, StoreError> {
    let fresh = off_runtime(|| lock(store).insert_sample(id, s))?;
    if fresh {
        let _ = events.send(Event {
            id: 0,
            campaign: id,
            unix_s: s.unix_s,
            kind: "sample".into(),
            data: json!(s),
        });
    }
    Ok(fresh)
}

pub(crate) fn emit(
    store: &SharedStore,
    events: &broadcast::Sender<Event>,
    id: i64,
    kind: &str,
    data: Value,
) {
    let unix_s = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_secs_f64())
        .unwrap_or(0.0);
    match off_runtime(|| lock(store).add_event(id, kind, &data)) {
        Ok(eid) => {
            let _ = events.send(Event {
                id: eid,
                campaign: id,
                unix_s,
                kind: kind.into(),
                data,
            });
        }
        Err(e) => tracing::warn!(error = %e, kind, "event not stored"),
    }
}
