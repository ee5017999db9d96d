//! A campaign's log and stream: events stored in its store and sent to whoever watches, and
//! samples committed and streamed (`csmetro watch`, server-sent events); and the one way into
//! the store from async code, [`SharedStore::with`].
use std::path::{Path, PathBuf};
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

/// The store shared by a campaign's runner, the service's manager and its routes. Its only
/// door is [`SharedStore::with`], so no SQLite call (the mutex, then a commit waiting on
/// fsync) runs where it would stall the async runtime.
#[derive(Clone)]
pub struct SharedStore {
    store: Arc<Mutex<Store>>,
    /// Read once: asking the store would take its mutex for a value that never changes.
    path: Option<PathBuf>,
}

impl SharedStore {
    pub fn new(store: Store) -> SharedStore {
        let path = store.path().map(Path::to_path_buf);
        SharedStore {
            store: Arc::new(Mutex::new(store)),
            path,
        }
    }

    /// Runs `f` on the store, off the async runtime (see [`off_runtime`]): the mutex is taken
    /// there too, since waiting for it blocks as much as the disk does. `f` must not call
    /// `with` again (the mutex is not reentrant).
    pub fn with<T>(&self, f: impl FnOnce(&Store) -> T) -> T {
        off_runtime(|| f(&self.store.lock().unwrap_or_else(|e| e.into_inner())))
    }

    /// The store's file (`None` in memory).
    pub fn path(&self) -> Option<&Path> {
        self.path.as_deref()
    }
}

/// Runs blocking work without stalling the async runtime: on a multi-threaded runtime's worker
/// the worker hands its other tasks (the API, the other stage's campaign) to another thread for
/// the duration; elsewhere (a plain or blocking thread, a current-thread runtime, where
/// `block_in_place` is not allowed) it runs as it is.
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
    let fresh = store.with(|st| st.insert_sample(id, s))?;
    if fresh {
        // No subscriber is no error: the sample is stored.
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

/// Stores event `kind` in campaign `id`'s log, then streams it; returns its id. An event the
/// store refused is not streamed (a client would see what the log does not keep).
pub(crate) fn emit(
    store: &SharedStore,
    events: &broadcast::Sender<Event>,
    id: i64,
    kind: &str,
    data: Value,
) -> Result<i64, StoreError> {
    let unix_s = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_secs_f64())
        .unwrap_or(0.0);
    let eid = store.with(|s| s.add_event(id, kind, &data))?;
    // No subscriber is no error: the event is stored.
    let _ = events.send(Event {
        id: eid,
        campaign: id,
        unix_s,
        kind: kind.into(),
        data,
    });
    Ok(eid)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn store() -> SharedStore {
        SharedStore::new(Store::open_in_memory().unwrap())
    }

    /// `block_in_place` is only allowed on a multi-threaded runtime: called from each place a
    /// store call happens (a worker, a blocking thread, a current-thread runtime, no runtime),
    /// `with` runs the call instead of panicking, and nested in itself on a worker too.
    #[test]
    fn with_runs_on_every_kind_of_thread() {
        let s = store();
        assert_eq!(s.with(|st| st.campaigns().unwrap().len()), 0);
        let mt = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(2)
            .build()
            .unwrap();
        let s2 = s.clone();
        let on_worker = mt.block_on(async move {
            tokio::spawn(async move { off_runtime(|| s2.with(|st| st.campaigns().is_ok())) })
                .await
                .unwrap()
        });
        assert!(on_worker);
        let s3 = s.clone();
        let on_blocking =
            mt.block_on(mt.spawn_blocking(move || s3.with(|st| st.campaigns().is_ok())));
        assert!(on_blocking.unwrap());
        let ct = tokio::runtime::Builder::new_current_thread()
            .build()
            .unwrap();
        assert!(ct.block_on(async { s.with(|st| st.campaigns().is_ok()) }));
    }

    /// A store call that waits for another task of the runtime: on its only worker, that task
    /// runs only if the call handed the worker over (without it, the wait times out).
    #[test]
    fn a_store_call_leaves_the_worker_to_the_other_tasks() {
        let rt = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(1)
            .build()
            .unwrap();
        let s = store();
        let released = rt.block_on(async move {
            let (inside_tx, inside_rx) = tokio::sync::oneshot::channel::<()>();
            let (release_tx, release_rx) = std::sync::mpsc::channel::<()>();
            let other = tokio::spawn(async move {
                if inside_rx.await.is_ok() {
                    let _ = release_tx.send(());
                }
            });
            let call = tokio::spawn(async move {
                s.with(|_| {
                    let _ = inside_tx.send(());
                    release_rx.recv_timeout(std::time::Duration::from_secs(10))
                })
            });
            let r = call.await.unwrap();
            other.await.unwrap();
            r
        });
        assert!(released.is_ok(), "the other task never ran: {released:?}");
    }

    #[test]
    fn an_event_the_store_refuses_is_returned_and_not_streamed() {
        let s = store();
        let (tx, mut rx) = broadcast::channel(4);
        // No campaign 1: the foreign key refuses the event.
        let r = emit(&s, &tx, 1, "started", json!({}));
        assert!(r.is_err(), "{r:?}");
        assert!(rx.try_recv().is_err());
    }
}
