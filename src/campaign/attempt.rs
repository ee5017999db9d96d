//! One attempt at a stored campaign, whatever it measures (a characterisation, a map, a
//! verification): its start, its failure, its result files and its end are recorded the same
//! way, here, once.
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

use serde::Serialize;
use serde_json::{json, Value};
use tokio::sync::broadcast;

use super::engine::Outcome;
use super::error::CampaignError;
use super::events::{emit, store_sample, Event, SharedStore};
use super::results::ResultsError;
use super::spec::Campaign;
use crate::store::{Store, StoreError};
use crate::types::{CampaignState, Origin, SampleRecord};

/// What a finished campaign reports.
#[derive(Debug, Clone, Serialize)]
pub struct Finished {
    pub id: i64,
    pub state: CampaignState,
    pub outcome: Outcome,
    pub summary: Option<Value>,
    pub table: Option<String>,
    pub out_dir: Option<PathBuf>,
}

/// Campaign `id` being run: where its state, events and results go. Clones share the writes
/// that failed (the reconstruction worker's thread writes too).
#[derive(Clone)]
pub struct Attempt {
    pub store: SharedStore,
    pub events: broadcast::Sender<Event>,
    pub id: i64,
    /// Writes the store refused that no caller got back (events, curves): they end in the
    /// campaign's `errors`, or in its state's message when it stops before its end.
    failed_writes: Arc<Mutex<Vec<String>>>,
}

impl Attempt {
    pub fn new(store: SharedStore, events: broadcast::Sender<Event>, id: i64) -> Attempt {
        Attempt {
            store,
            events,
            id,
            failed_writes: Arc::default(),
        }
    }

    /// Stores and streams event `kind`; one the store refuses is noted as a failed write.
    pub fn emit(&self, kind: &str, data: Value) {
        if let Err(e) = emit(&self.store, &self.events, self.id, kind, data) {
            tracing::warn!(campaign = self.id, error = %e, kind, "event not stored");
            self.write_failed(format!("event `{kind}` not stored: {e}"));
        }
    }

    /// Commits sample `s` and streams it (see [`store_sample`]): its failure is the caller's.
    pub fn store_sample(&self, s: &SampleRecord) -> Result<bool, StoreError> {
        store_sample(&self.store, &self.events, self.id, s)
    }

    /// Notes a write of this attempt that failed, for the campaign's `errors`.
    pub fn write_failed(&self, msg: String) {
        self.failed_writes
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .push(msg);
    }

    /// The writes that failed since the last call, each failure once (with its count).
    pub fn take_failed_writes(&self) -> Vec<String> {
        let all =
            std::mem::take(&mut *self.failed_writes.lock().unwrap_or_else(|e| e.into_inner()));
        let mut counted: Vec<(String, usize)> = Vec::new();
        for m in all {
            match counted.iter_mut().find(|(c, _)| *c == m) {
                Some((_, n)) => *n += 1,
                None => counted.push((m, 1)),
            }
        }
        counted
            .into_iter()
            .map(|(m, n)| {
                if n == 1 {
                    m
                } else {
                    format!("{m} ({n} times)")
                }
            })
            .collect()
    }

    /// `msg` with the writes that failed in this attempt, for a state that ends it early.
    fn with_failed_writes(&self, msg: &str) -> String {
        let failed = self.take_failed_writes();
        if failed.is_empty() {
            msg.to_string()
        } else {
            format!("{msg}; {}", failed.join("; "))
        }
    }

    /// An event after the campaign's final state is stored: nothing reads the failed writes
    /// any more, and the state (what clients and a restart read) is in place; only said.
    fn emit_after_state(&self, kind: &str, data: Value) {
        if let Err(e) = emit(&self.store, &self.events, self.id, kind, data) {
            tracing::error!(campaign = self.id, error = %e, kind, "event not stored after the final state");
        }
    }

    /// Records the start: `planned` targets, state running, then `started` (or
    /// `resumed_from_store` when `stored` targets were measured before). A verification names
    /// the characterisation it verifies.
    pub fn start(
        &self,
        planned: u64,
        stored: usize,
        name: &str,
        origin: &Origin,
        verify: Option<i64>,
    ) -> Result<(), CampaignError> {
        self.store.with(|s| {
            s.set_planned(self.id, planned)?;
            s.set_state(self.id, CampaignState::Running, None)
        })?;
        let mut data = json!({"planned": planned, "stored": stored, "name": name,
                              "by": origin.describe(), "origin": origin});
        if let Some(v) = verify {
            data["verify"] = json!(v);
        }
        let kind = if stored == 0 {
            "started"
        } else {
            "resumed_from_store"
        };
        self.emit(kind, data);
        Ok(())
    }

    /// An attempt that cannot go on: the error, then the state change (interrupted, so it can
    /// be resumed), both in the log. Returns the message, with the writes that failed before
    /// and the state's own failure.
    pub fn fail(&self, cause: &str, msg: String) -> String {
        let msg = self.with_failed_writes(&msg);
        // A state that cannot be stored is said too (the store keeps the campaign `running`,
        // which the service's next start resumes).
        let stored = self
            .store
            .with(|s| s.set_state(self.id, CampaignState::Interrupted, Some(&msg)));
        let msg = match stored {
            Ok(()) => msg,
            Err(e) => format!("{msg}; state not stored: {e}"),
        };
        self.emit_after_state(
            "error",
            json!({"cause": cause, "error": msg, "resumable": true}),
        );
        self.emit_after_state("finished", json!({"state": "interrupted", "error": msg}));
        msg
    }

    /// Motion halted before the end (stopped or aborted): the state with its reason (and the
    /// writes that failed), then `finished` with `data`.
    pub fn halted(
        &self,
        state: CampaignState,
        reason: &str,
        data: Value,
        outcome: Outcome,
    ) -> Result<Finished, CampaignError> {
        let id = self.id;
        let reason = self.with_failed_writes(reason);
        // Not stored, an aborted campaign would be left `running` and resumed by the
        // service's next start: an error, not a finished campaign.
        self.store
            .with(|s| s.set_state(id, state, Some(&reason)))
            .map_err(|source| CampaignError::HaltNotStored {
                id,
                state: state.as_str(),
                source: Box::new(source),
            })?;
        self.emit_after_state("finished", data);
        Ok(Finished {
            id,
            state,
            outcome,
            summary: None,
            table: None,
            out_dir: None,
        })
    }

    /// The store's id (results folders are marked with it).
    pub fn store_id(&self) -> String {
        self.store.with(Store::store_id).unwrap_or_else(|e| {
            tracing::warn!(error = %e, "store id not read");
            "unknown".into()
        })
    }

    /// Stores the result `files` and writes them to the campaign's output directory, claimed
    /// for it (a results folder belongs to one campaign of one store: never written over).
    /// Failures are added to `errors`; returns the directory written.
    pub fn put_files(
        &self,
        c: &Campaign,
        store_id: &str,
        files: &[(String, String, Vec<u8>)],
        errors: &mut Vec<String>,
    ) -> Result<PathBuf, ResultsError> {
        let id = self.id;
        let store_err = self.store.with(|s| {
            let mut last = None;
            for (name, ctype, bytes) in files {
                if let Err(e) = s.put_result(id, name, ctype, bytes) {
                    last = Some(e.to_string());
                }
            }
            last
        });
        if let Some(e) = store_err {
            errors.push(format!("results not stored: {e}"));
        }
        let wanted = super::results::out_dir(c, id);
        let written = super::results::claim_out_dir(&wanted, store_id, id, &c.spec().campaign.name)
            .and_then(|d| write_files(&d, files).map(|()| d));
        if let Err(e) = &written {
            tracing::warn!(error = %e, dir = %wanted.display(), "result files not written");
            self.emit(
                "error",
                json!({"cause": "results", "error": e.to_string(), "resumable": false}),
            );
            errors.push(e.to_string());
        }
        written
    }

    /// Writes `summary.json` (store and output directory `dir`) with the campaign's final
    /// `state` and `errors`, the writes that failed so far and its own write's failure
    /// included: a failed write fails the campaign and the summary is written again where it
    /// could be. `written`: the bytes stored with the other result files; when the final
    /// summary reads the same, nothing is written.
    pub fn write_summary(
        &self,
        summary: &mut Value,
        state: &mut CampaignState,
        errors: &mut Vec<String>,
        dir: Option<&Path>,
        written: Option<&[u8]>,
    ) -> Result<(), serde_json::Error> {
        let failed = self.take_failed_writes();
        if !failed.is_empty() {
            errors.extend(failed);
            *state = CampaignState::Failed;
        }
        let mut failed_before = false;
        loop {
            summary["state"] = json!(state.as_str());
            summary["errors"] = json!(errors);
            let bytes = serde_json::to_vec_pretty(summary)?;
            if !failed_before && written == Some(bytes.as_slice()) {
                return Ok(());
            }
            let mut failed = Vec::new();
            let stored = self
                .store
                .with(|s| s.put_result(self.id, "summary.json", "application/json", &bytes));
            if let Err(e) = stored {
                failed.push(format!("results not stored (summary.json): {e}"));
            }
            if let Some(d) = dir {
                if let Err(e) = std::fs::write(d.join("summary.json"), &bytes) {
                    failed.push(format!("results not written (summary.json: {})", e.kind()));
                }
            }
            if failed.is_empty() {
                return Ok(());
            }
            // Said once: a second failure of the same write fails nothing more.
            if failed_before {
                for f in failed {
                    tracing::warn!(campaign = self.id, error = %f, "summary.json not rewritten");
                }
                return Ok(());
            }
            failed_before = true;
            errors.extend(failed);
            *state = CampaignState::Failed;
        }
    }

    /// The end of a campaign that measured to its end: its state (failed with `errors`) and
    /// `finished` with the summary.
    pub fn finish(
        &self,
        state: CampaignState,
        errors: Vec<String>,
        mut summary: Value,
        table: String,
        outcome: Outcome,
        out_dir: Option<PathBuf>,
    ) -> Result<Finished, CampaignError> {
        let message = (!errors.is_empty()).then(|| errors.join("; "));
        self.store
            .with(|s| s.set_state(self.id, state, message.as_deref()))?;
        summary["state"] = json!(state.as_str());
        summary["errors"] = json!(errors);
        // `out_dir`: where the results folder went, so a later verification campaign can link
        // the report in it to its own.
        self.emit_after_state(
            "finished",
            json!({"state": state.as_str(), "errors": errors, "summary": summary,
                   "out_dir": out_dir.as_ref().map(|d| d.display().to_string())}),
        );
        Ok(Finished {
            id: self.id,
            state,
            outcome,
            summary: Some(summary),
            table: Some(table),
            out_dir,
        })
    }
}

/// Writes the result files under `dir`; the first failure names the file (relative to `dir`).
pub fn write_files(dir: &Path, files: &[(String, String, Vec<u8>)]) -> Result<(), ResultsError> {
    let mut first = None;
    for (name, _, bytes) in files {
        let p = dir.join(name);
        let r = match p.parent() {
            Some(d) => std::fs::create_dir_all(d).and_then(|()| std::fs::write(&p, bytes)),
            None => std::fs::write(&p, bytes),
        };
        if let Err(e) = r {
            first.get_or_insert_with(|| ResultsError::Write {
                name: name.clone(),
                kind: e.kind(),
            });
        }
    }
    first.map_or(Ok(()), Err)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn refused_events_are_noted_once_each_with_their_count_and_taken_once() {
        let store = SharedStore::new(crate::store::Store::open_in_memory().unwrap());
        // No campaign 9: the store refuses its events (foreign key).
        let run = Attempt::new(store, broadcast::channel(4).0, 9);
        let worker = run.clone();
        for _ in 0..3 {
            worker.emit("reconstructed", json!({}));
        }
        run.emit("rig", json!({}));
        let failed = run.take_failed_writes();
        assert_eq!(failed.len(), 2, "{failed:?}");
        assert!(
            failed[0].starts_with("event `reconstructed` not stored: ")
                && failed[0].ends_with(" (3 times)"),
            "{failed:?}"
        );
        assert!(
            failed[1].starts_with("event `rig` not stored: "),
            "{failed:?}"
        );
        assert!(run.take_failed_writes().is_empty());
    }
}
