//! What the manager follows while it runs: campaigns a dead foreground process left behind
//! (orphans), pauses and progress of the running campaigns.
#[allow(clippy::wildcard_imports)]
use super::*;

impl Manager {
    /// Campaigns that a foreground process (`csmetro run`/`resume` on this store) left
    /// `running` or `paused` when it died without finishing (kill -9, a crash): nobody holds
    /// their stage any more and nobody will finish them. Marked `interrupted` (checked every
    /// [`STAGE_RETRY`]), so that resume and abort take them through the API instead of refusing
    /// a campaign that looks alive until the next service start.
    pub(super) fn watch_orphans(self: &Arc<Self>) {
        let Some(db_path) = self.store.path().map(Path::to_path_buf) else {
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
    pub(super) fn sweep_orphans(&self, db_path: &Path) {
        for row in self.unfinished_rows("orphan check") {
            // Paused by the operator: held on purpose (possibly across a restart), not orphaned.
            if row.state != CampaignState::Running || self.inner().active(row.id).is_some() {
                continue;
            }
            // A held stage means its process is alive (or the service drives the stage and will
            // look again later). The lock is kept while the state is read again and changed: no
            // process can take the campaign up in between, and one that finished it released
            // the stage only after storing its final state.
            let scope = stagelock::Scope::of_spec_toml(&row.spec_toml);
            let Ok(_stage) = stagelock::try_lock_scoped(db_path, &row.stage, scope) else {
                continue;
            };
            self.mark_orphan(row.id);
        }
    }

    /// The store's unfinished campaigns; none (and a warning naming `what`) when it cannot be
    /// read: the check runs again later.
    pub(super) fn unfinished_rows(&self, what: &str) -> Vec<CampaignRow> {
        self.db(|s| s.unfinished()).unwrap_or_else(|e| {
            tracing::warn!(error = %e, "{what}: cannot read the store");
            Vec::new()
        })
    }

    /// Marks campaign `id` `interrupted` if the store still says `running`: the caller holds its
    /// stage's lock, so the process that ran it is gone.
    pub(super) fn mark_orphan(&self, id: i64) {
        let now = self.db(|s| s.campaign(id)).ok().flatten();
        let Some(now) = now.filter(|r| r.state == CampaignState::Running) else {
            return;
        };
        let stored = self.db(|s| s.sample_count(id)).unwrap_or(0);
        let msg = format!(
            "the process that ran it exited without finishing (was {}); {stored} of {} \
             samples are stored and a resume continues from there",
            now.state.as_str(),
            now.planned
        );
        tracing::warn!(campaign = id, stage = %now.stage, "{msg}");
        if let Err(e) = self.db(|s| s.set_state(id, CampaignState::Interrupted, Some(&msg))) {
            // Still `running` in the store: the next sweep finds it again.
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
    pub(super) fn reclaim_stage(&self, stage: &str, id: i64) {
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
    pub(super) fn follow_pauses(self: &Arc<Self>) {
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
                    if let Err(err) = m.db(|s| {
                        s.set_state(
                            e.campaign,
                            CampaignState::Paused,
                            Some("paused by the operator"),
                        )
                    }) {
                        // The engine holds anyway; only the stored state lags.
                        tracing::error!(campaign = e.campaign, error = %err, "paused state not stored");
                    }
                }
            }
        });
    }

    /// Notes each running campaign's first sample of its attempt: where its ETA's rate starts.
    pub(super) fn follow_progress(self: &Arc<Self>) {
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
}
