//! The operator's controls of a campaign: pause, resume, abort.
#[allow(clippy::wildcard_imports)]
use super::*;

impl Manager {
    pub(super) fn refuse(&self, id: i64, what: &'static str) -> ManagerError {
        match self.row(id) {
            Ok(row) => ManagerError::Refused {
                id,
                state: row.state.as_str(),
                what,
            },
            Err(e) => e,
        }
    }

    /// Holds a running campaign between two points (motion ends on target, nothing is lost).
    pub fn pause(&self, id: i64) -> Result<CampaignStatus, ManagerError> {
        self.pause_by(id, &Origin::api(None, None))
    }

    /// [`Manager::pause`]; the `paused` event and the status message say who paused it.
    pub fn pause_by(&self, id: i64, origin: &Origin) -> Result<CampaignStatus, ManagerError> {
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
                self.db(|s| s.set_state(id, CampaignState::Paused, Some(&msg)))?;
                self.emit_by_operator(id, "paused", origin);
                return self.status(id);
            };
            if a.control.borrow().halts() {
                drop(inner);
                return Err(self.refuse(id, "pause"));
            }
            // Its session may have stored its end already (it leaves `active` after that).
            if !self.db(|s| {
                s.set_state_from(
                    id,
                    CampaignState::Running,
                    CampaignState::Paused,
                    Some(&msg),
                )
            })? {
                drop(inner);
                return Err(self.refuse(id, "pause"));
            }
            a.control.send_replace(Control::Pause);
            a.progress.pause(crate::store::now_unix_s());
        }
        self.emit_by_operator(id, "paused", origin);
        self.status(id)
    }

    /// An operator's pause or resume as an event (and a log line) saying who.
    pub(super) fn emit_by_operator(&self, id: i64, kind: &str, origin: &Origin) {
        let mut data = origin.fields();
        data["cause"] = json!("operator");
        self.emit(id, kind, data);
        tracing::info!(campaign = id, by = %origin.describe(), "{kind}");
    }

    /// Continues a paused campaign, or queues an interrupted one again (it resumes from its
    /// last stored sample).
    pub fn resume(self: &Arc<Self>, id: i64) -> Result<CampaignStatus, ManagerError> {
        self.resume_by(id, &Origin::api(None, None))
    }

    /// [`Manager::resume`]; the `resumed` (running again) or `requeued` event says who.
    pub fn resume_by(
        self: &Arc<Self>,
        id: i64,
        origin: &Origin,
    ) -> Result<CampaignStatus, ManagerError> {
        if self.shutting_down() {
            return Err(ManagerError::ShuttingDown);
        }
        let requeue_stage = {
            let mut inner = self.inner();
            if let Some(a) = inner.active(id) {
                if *a.control.borrow() != Control::Pause
                    || !self.db(|s| {
                        s.set_state_from(id, CampaignState::Paused, CampaignState::Running, None)
                    })?
                {
                    drop(inner);
                    return Err(self.refuse(id, "resume"));
                }
                a.control.send_replace(Control::Run);
                a.progress.resume(crate::store::now_unix_s());
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
                self.db(|s| {
                    s.set_state(
                        id,
                        CampaignState::Queued,
                        Some(&format!("resumed by {}", origin.describe())),
                    )
                })?;
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
    pub fn abort(self: &Arc<Self>, id: i64) -> Result<CampaignStatus, ManagerError> {
        self.abort_by(id, &Origin::api(None, None))
    }

    /// [`Manager::abort`]; the `abort_requested` (running) or `finished` event says who.
    pub fn abort_by(
        self: &Arc<Self>,
        id: i64,
        origin: &Origin,
    ) -> Result<CampaignStatus, ManagerError> {
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
        self.db(|s| {
            s.set_state(
                id,
                CampaignState::Aborted,
                Some(&format!(
                    "aborted by {} before it ran again",
                    origin.describe()
                )),
            )
        })?;
        let mut data = origin.fields();
        data["state"] = json!("aborted");
        self.emit(id, "finished", data);
        tracing::info!(campaign = id, "aborted while not running");
        self.status(id)
    }
}
