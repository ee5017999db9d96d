//! `[campaign] verify = ID`: the keys a verification campaign may and may not have (checked
//! before any store is at hand; the characterisation itself is resolved when it runs).
use super::CampaignSpec;

/// ISO 230-2's measurement cycles per direction, when the file does not set
/// `[acquisition] cycles`.
pub const DEFAULT_VERIFY_CYCLES: u32 = 5;
/// Most cycles a verification measures (a bound on what a file or a flag can ask).
pub const MAX_VERIFY_CYCLES: u32 = 50;

/// Checks a verification's own keys (before any store is at hand): an id, no `[axes]`, no
/// `[compensation]`. Errors: (key, message).
pub fn check_verification(spec: &CampaignSpec, id: i64) -> Result<(), (&'static str, String)> {
    if id <= 0 {
        return Err(("campaign.verify", "must be a campaign id (> 0)".into()));
    }
    if !spec.axes.is_empty() {
        return Err((
            "axes",
            format!("a verification measures the axes of characterisation {id}: leave out [axes]"),
        ));
    }
    if spec.map.is_some() {
        return Err((
            "map",
            format!("a verification measures the axes of characterisation {id}: leave out [map]"),
        ));
    }
    if spec.compensation.is_some() {
        return Err((
            "compensation",
            format!(
                "a verification applies the compensation of characterisation {id}: leave out [compensation]"
            ),
        ));
    }
    if spec.acquisition.cycles > MAX_VERIFY_CYCLES {
        return Err((
            "acquisition.cycles",
            format!(
                "a verification measures at most {} cycles",
                MAX_VERIFY_CYCLES
            ),
        ));
    }
    Ok(())
}
