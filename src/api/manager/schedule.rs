//! Scheduling: the FIFO queue of each stage, its stage lock, the launch of a campaign's session
//! and what its end leaves (a retry, the next campaign).
#[allow(clippy::wildcard_imports)]
use super::*;
use crate::campaign::error::CampaignError;

impl Manager {
    /// Starts the next queued campaign of `stage` unless one drives it already.
    pub(super) fn schedule(self: &Arc<Self>, stage: &str) {
        loop {
            if self.shutting_down() {
                return;
            }
            let db_path = self.store.path().map(Path::to_path_buf);
            // The head's lock scope (its hardware kind), read before `inner` is taken: the store
            // is never locked inside it. A head that changed meanwhile locks machine-wide.
            let head = self
                .inner()
                .queues
                .get(stage)
                .and_then(|q| q.front().copied());
            let head_scope = head
                .and_then(|id| self.db(|s| s.campaign(id)).ok().flatten())
                .map_or(stagelock::Scope::Machine, |r| {
                    stagelock::Scope::of_spec_toml(&r.spec_toml)
                });
            let (id, rx, locked) = {
                let mut inner = self.inner();
                if inner.running.contains_key(stage) {
                    return;
                }
                let Some(&id) = inner.queues.get(stage).and_then(|q| q.front()) else {
                    return;
                };
                let scope = if head == Some(id) {
                    head_scope
                } else {
                    stagelock::Scope::Machine
                };
                let lock = match db_path
                    .as_deref()
                    .map(|p| stagelock::try_lock_scoped(p, stage, scope))
                {
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
                .db(|s| s.campaign(id))
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
    pub(super) fn wait_for_stage(self: &Arc<Self>, id: i64, stage: &str, e: StageLockError) {
        let msg = e.to_string();
        let first = self
            .db(|s| s.campaign(id))
            .ok()
            .flatten()
            .is_none_or(|r| r.message.as_deref() != Some(msg.as_str()));
        if first {
            tracing::warn!(campaign = id, error = %msg, "waiting for the stage");
            if let Err(e) = self.db(|s| s.set_state(id, CampaignState::Queued, Some(&msg))) {
                // It is `queued` already and waits all the same; only the reason is not stored.
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
    pub(super) fn schedule_later(self: &Arc<Self>, stage: &str) {
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
    pub(super) fn interrupt(&self, id: i64, msg: String) {
        if let Err(e) = self.db(|s| s.set_state(id, CampaignState::Interrupted, Some(&msg))) {
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

    pub(super) fn launch(
        self: &Arc<Self>,
        id: i64,
        stage: String,
        c: Campaign,
        control: watch::Receiver<Control>,
    ) {
        // Below the service's results_dir whatever the template (absolute ones included).
        let dir =
            crate::campaign::results::service_outputs(&self.results_dir, &c.spec().outputs.dir);
        let c = c.with_outputs_dir(dir);
        tracing::info!(campaign = id, name = %c.spec().campaign.name, stage = %stage, "starting");
        // Nothing is measured before `execute` runs: this is what earlier attempts stored.
        let stored = self.db(|s| s.sample_count(id)).unwrap_or(0);
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
                me.finished(id, &stage, Ok(Err(CampaignError::Recorded(msg))));
                return;
            }
            let run = session::execute(store, id, c, control, events, Box::new(|_| {}));
            // A panic in the session must still free the stage and count down.
            let r = tokio::spawn(run).await;
            me.finished(id, &stage, r);
        });
    }

    pub(super) fn finished(
        self: &Arc<Self>,
        id: i64,
        stage: &str,
        r: Result<Result<session::Finished, CampaignError>, tokio::task::JoinError>,
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
                if self.retry_start(id, stage, &e.to_string()) {
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
    pub(super) fn retry_start(self: &Arc<Self>, id: i64, stage: &str, error: &str) -> bool {
        let queued = self
            .db(|s| s.campaign(id))
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
}
