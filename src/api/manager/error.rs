//! What the manager refuses or fails with, as types: the HTTP layer (`api::routes`) maps each
//! to its status code, the text stays the client's message.
use crate::campaign::preflight;
use crate::store::StoreError;

#[derive(Debug, thiserror::Error)]
pub enum ManagerError {
    /// 404.
    #[error("no campaign {0}")]
    NoCampaign(i64),
    /// 404.
    #[error("campaign {id} has no result {name:?}")]
    NoResult { id: i64, name: String },
    /// 409: the control does not apply to the campaign's state.
    #[error("campaign {id} is {state}: cannot {what} it")]
    Refused {
        id: i64,
        state: &'static str,
        what: &'static str,
    },
    /// 409.
    #[error("the service is shutting down")]
    ShuttingDown,
    /// 409: the stage's queue is full.
    #[error(
        "{waiting} campaigns already wait for stage {stage} (the service's \
         [campaigns] max_queued): submit again when some have run"
    )]
    QueueFull { waiting: usize, stage: String },
    /// 507.
    #[error(
        "the store holds {used_mb} MB, over the service's quota ([storage] max_store_mb = \
         {max_mb}): nothing new is recorded until an operator frees space"
    )]
    OverQuota { used_mb: u64, max_mb: u64 },
    /// 400: the campaign file (errors name the client's file name only).
    #[error(transparent)]
    Invalid(#[from] crate::campaign::spec::SpecError),
    /// 409 (the file must change) or 503 (the rig must): the failed pre-flight check.
    #[error("{message}; the campaign was not queued")]
    Preflight {
        class: preflight::Class,
        message: String,
    },
    /// 500; the details are in the service's log only.
    #[error("the campaign could not be recorded (the service's log has the details)")]
    NotRecorded,
    /// 500; the details (with the store's server path) are in the service's log only.
    #[error("the service's store failed (its log has the details)")]
    Store,
}

impl From<StoreError> for ManagerError {
    /// Logged here, so that the client's message carries no server path.
    fn from(e: StoreError) -> Self {
        tracing::error!(error = %e, "store");
        ManagerError::Store
    }
}
