//! Submission: a client's campaign file validated, checked against the quota and the preflight,
//! stored and queued.
#[allow(clippy::wildcard_imports)]
use super::*;

impl Manager {
    /// Validates and stores a campaign file sent by a client, and queues it. `name` is the
    /// file name the client gave (errors name it; relative paths resolve in `campaigns_dir`).
    pub fn submit(
        self: &Arc<Self>,
        text: &str,
        name: &str,
    ) -> Result<CampaignStatus, ManagerError> {
        self.submit_by(text, name, &Origin::api(None, None))
    }

    /// [`Manager::submit`], the `queued` event naming who submitted it.
    pub fn submit_by(
        self: &Arc<Self>,
        text: &str,
        name: &str,
        origin: &Origin,
    ) -> Result<CampaignStatus, ManagerError> {
        if self.shutting_down() {
            return Err(ManagerError::ShuttingDown);
        }
        let file = Path::new(name)
            .file_name()
            .map(|f| f.to_string_lossy().into_owned())
            .filter(|f| !f.is_empty())
            .unwrap_or_else(|| "submitted.toml".into());
        self.check_quota()?;
        let c = Campaign::parse(text, &file, &self.campaigns_dir)?;
        // `verify = ID`: a characterisation in this service's store only.
        let c = self.db(|s| crate::campaign::verification::resolve(c, s))?;
        // load_stored resolves relative paths from the stored path's directory.
        let c = c.stored_as(self.campaigns_dir.join(&file).display().to_string());
        self.preflight_at_submit(&c)?;
        let stage = c.spec().campaign.stage.clone();
        let waiting = self.inner().queues.get(&stage).map_or(0, VecDeque::len);
        if waiting >= self.limits.max_queued_per_stage {
            return Err(ManagerError::QueueFull { waiting, stage });
        }
        let id = session::create(&self.store, &c).map_err(|e| {
            tracing::error!(error = %e, "campaign not recorded");
            ManagerError::NotRecorded
        })?;
        let position = {
            let mut inner = self.inner();
            let q = inner.queues.entry(stage.clone()).or_default();
            q.push_back(id);
            q.len() - 1
        };
        tracing::info!(campaign = id, name = %c.spec().campaign.name, stage = %stage, "submitted");
        self.emit(
            id,
            "queued",
            json!({"stage": stage, "position": position, "name": c.spec().campaign.name,
                   "by": origin.describe(), "origin": origin}),
        );
        self.schedule(&stage);
        self.status(id)
    }

    /// 507 while the store file (and its write-ahead log) is over [`Limits::max_store_bytes`]:
    /// clients cannot fill the disk one campaign at a time.
    pub(super) fn check_quota(&self) -> Result<(), ManagerError> {
        let Some(db) = self.store.path().map(Path::to_path_buf) else {
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
            return Err(ManagerError::OverQuota {
                used_mb: used >> 20,
                max_mb: self.limits.max_store_bytes >> 20,
            });
        }
        Ok(())
    }

    /// The pre-flight of `csmetro check`, before the campaign is recorded, when its stage is
    /// free now (held for the check). A campaign queued behind another, or whose stage another
    /// process drives, is checked when it starts. 409 when the file must change, 503 when the
    /// rig must; the message names the failed check.
    pub(super) fn preflight_at_submit(&self, c: &Campaign) -> Result<(), ManagerError> {
        let stage = &c.spec().campaign.stage;
        {
            let inner = self.inner();
            if inner.running.contains_key(stage)
                || inner.queues.get(stage).is_some_and(|q| !q.is_empty())
            {
                return Ok(());
            }
        }
        let db_path = self.store.path().map(Path::to_path_buf);
        let scope = stagelock::Scope::of(c.spec().hardware.kind);
        let _lock = match db_path
            .as_deref()
            .map(|p| stagelock::try_lock_scoped(p, stage, scope))
        {
            Some(Err(_)) => return Ok(()),
            Some(Ok(l)) => Some(l),
            None => None,
        };
        // Called on a blocking thread of the service's runtime (routes::submit).
        let report = tokio::runtime::Handle::current().block_on(preflight_report(c));
        if !report.blocks() {
            for w in report.warnings() {
                tracing::warn!(campaign = %c.spec().campaign.name, "{w}");
            }
            return Ok(());
        }
        tracing::warn!(campaign = %c.spec().campaign.name, "{}; not queued", report.error_message());
        Err(ManagerError::Preflight {
            class: report.failure_class(),
            message: report.client_message(),
        })
    }
}
