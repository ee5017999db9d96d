//! `[compensation]` of a campaign file: which compensation a campaign runs with, and whether it
//! fits the campaign (stage, axes, directions).
use super::Campaign;
use crate::compensation::{Compensation, TableError};

/// `[compensation]` of a campaign file: `from = ID` (a characterisation in the same store) or
/// `file = "..."` (a results directory or a table, relative to the campaign file).
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CompensationSpec {
    #[serde(default)]
    pub from: Option<i64>,
    #[serde(default)]
    pub file: Option<String>,
}

/// Checks `[compensation]` of a parsed campaign: one source; a `file` is loaded now (a bad table
/// refuses the campaign before anything is stored or moved) and must fit the campaign's stage,
/// axes and directions. `from = ID` is resolved when the campaign runs (it needs the store).
/// Errors: (key, message). Submitted campaigns may only name a stored characterisation.
pub fn check_spec(c: &Campaign, submitted: bool) -> Result<(), (&'static str, String)> {
    let Some(s) = &c.spec.compensation else {
        return Ok(());
    };
    match (s.from, &s.file) {
        (Some(id), None) if id > 0 => Ok(()),
        (Some(_), None) => Err(("compensation.from", "must be a campaign id (> 0)".into())),
        (None, Some(_)) if submitted => Err((
            "compensation.file",
            "a submitted campaign names its compensation by the characterisation's id: from = ID".into(),
        )),
        (None, Some(f)) => {
            if f.is_empty() || f.len() > 1024 || f.contains('\0') {
                return Err(("compensation.file", "must be a path of 1..=1024 bytes".into()));
            }
            let comp = Compensation::load(&c.resolve(f)).map_err(|e| ("compensation.file", e.to_string()))?;
            fits(&comp, c).map_err(|e| ("compensation.file", e.to_string()))
        }
        _ => Err((
            "compensation",
            "give one of from = ID (a stored characterisation) or file = \"...\" (results directory or table)".into(),
        )),
    }
}

/// Refuses a compensation that does not fit campaign `c`: another stage, an axis without a
/// table or a grid short of the axis's range, a direction the table cannot serve.
pub fn fits(comp: &Compensation, c: &Campaign) -> Result<(), Misfit> {
    comp.check_stage(&c.spec.campaign.stage)?;
    for ax in &c.axes {
        comp.check_covers(ax.axis, ax.grid.start_um, ax.grid.end_um())?;
        let t = comp.table(ax.axis).expect("checked by check_covers");
        for &d in &c.spec.acquisition.directions {
            if t.served_direction(d) != d {
                return Err(Misfit::Direction {
                    origin: t.origin.clone(),
                    direction: d.as_str(),
                });
            }
        }
    }
    Ok(())
}

/// Why a compensation does not fit a campaign.
#[derive(Debug, thiserror::Error)]
pub enum Misfit {
    /// Another stage, or an axis without a table or with a grid short of the range.
    #[error(transparent)]
    Table(#[from] TableError),
    #[error("{origin}: no {direction} correction, and the campaign measures {direction} (approached from the other side, backlash would stay)")]
    Direction {
        origin: String,
        direction: &'static str,
    },
}
