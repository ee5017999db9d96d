//! The compensation a campaign runs with, read from the store (the compensation module itself
//! knows no store).
use std::sync::Arc;

use super::spec::Campaign;
use crate::compensation::{Compensation, TableError};
use crate::store::Store;

/// Compensation of stored campaign `id` of `stage`: its result tables or maps.
pub fn stored(store: &Store, id: i64, stage: &str) -> Result<Compensation, TableError> {
    Compensation::from_results(id, stage, |name| {
        store
            .result(id, name)
            .map(|r| r.map(|(_, bytes)| bytes))
            .map_err(|e| e.to_string())
    })
}

/// The compensation campaign `c` runs with, resolved against `store` (`from = ID`) or its file.
pub fn for_campaign(c: &Campaign, store: &Store) -> Result<Option<Arc<Compensation>>, String> {
    let Some(s) = &c.spec().compensation else {
        return Ok(None);
    };
    let comp = match (s.from, &s.file) {
        (Some(id), _) => {
            let row = store
                .campaign(id)
                .map_err(|e| e.to_string())?
                .ok_or_else(|| format!("compensation: no campaign {id} in the store"))?;
            stored(store, id, &row.stage).map_err(|e| e.to_string())?
        }
        (None, Some(f)) => Compensation::load(&c.resolve(f)).map_err(|e| e.to_string())?,
        (None, None) => return Ok(None),
    };
    super::spec::fits(&comp, c).map_err(|e| format!("compensation: {e}"))?;
    Ok(Some(Arc::new(comp)))
}
