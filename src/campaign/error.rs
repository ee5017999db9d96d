//! Why a campaign (stored, run or resumed) ended in an error rather than a final state: the
//! callers (the CLI's exit code, the service's retries) decide on the kind, the operator reads
//! the text.
use crate::store::StoreError;

use super::spec::SpecError;

#[derive(Debug, thiserror::Error)]
pub enum CampaignError {
    /// Boxed: a store error is large, and every campaign call returns this.
    #[error(transparent)]
    Store(Box<StoreError>),
    /// The stored file (or the characterisation a verification names) no longer validates.
    #[error(transparent)]
    Spec(#[from] SpecError),
    /// The compensation tables of the characterisation a verification names.
    #[error(transparent)]
    Table(#[from] crate::compensation::TableError),
    #[error("no campaign {0} in the store")]
    NotStored(i64),
    #[error("not a verification campaign")]
    NotVerification,
    #[error("truth log {path}: {source}")]
    TruthLog {
        path: String,
        source: std::io::Error,
    },
    /// The attempt failed before it measured (or without losing anything): the message is the
    /// one recorded in the campaign's state and log.
    #[error("campaign {id} interrupted ({msg}); `csmetro resume {id}` tries again")]
    NotStarted { id: i64, msg: String },
    /// The attempt stopped while measuring; every sample taken is stored.
    #[error("campaign {id} interrupted ({msg}); `csmetro resume {id}` continues from the last stored sample")]
    Stopped { id: i64, msg: String },
    /// The attempt failed before it started (a `[compensation]` that cannot be used, the
    /// service's pre-flight), as recorded in its state and log.
    #[error("{0}")]
    Recorded(String),
    /// Motion stopped but the final state was not stored: the service's next start would
    /// resume the campaign.
    #[error("campaign {id}: motion stopped, but its state ({state}) was not stored: {source}")]
    HaltNotStored {
        id: i64,
        state: &'static str,
        source: Box<StoreError>,
    },
}

impl From<StoreError> for CampaignError {
    fn from(e: StoreError) -> Self {
        CampaignError::Store(Box::new(e))
    }
}
