//! The compensation a campaign runs with, read from the store (the compensation module itself
//! knows no store).
use std::sync::Arc;

use super::spec::Campaign;
use crate::compensation::{Compensation, TableError};
use crate::store::{Store, StoreError};

/// Compensation of stored campaign `id` of `stage`: its result tables or maps.
pub fn stored(store: &Store, id: i64, stage: &str) -> Result<Compensation, TableError> {
    Compensation::from_results(id, stage, |name| {
        store.result(id, name).map(|r| r.map(|(_, bytes)| bytes))
    })
}

/// Why a campaign's `[compensation]` cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum CompensateError {
    #[error(transparent)]
    Store(#[from] StoreError),
    #[error("compensation: no campaign {0} in the store")]
    NoCampaign(i64),
    #[error(transparent)]
    Table(#[from] TableError),
    /// The table does not fit the campaign (stage, range, direction).
    #[error("compensation: {0}")]
    Misfit(#[from] super::spec::Misfit),
}

/// The compensation campaign `c` runs with, resolved against `store` (`from = ID`) or its file.
pub fn for_campaign(
    c: &Campaign,
    store: &Store,
) -> Result<Option<Arc<Compensation>>, CompensateError> {
    let Some(s) = &c.spec().compensation else {
        return Ok(None);
    };
    let comp = match (s.from, &s.file) {
        (Some(id), _) => {
            let row = store.campaign(id)?.ok_or(CompensateError::NoCampaign(id))?;
            stored(store, id, &row.stage)?
        }
        (None, Some(f)) => Compensation::load(&c.resolve(f))?,
        (None, None) => return Ok(None),
    };
    super::spec::fits(&comp, c)?;
    Ok(Some(Arc::new(comp)))
}
