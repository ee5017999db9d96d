//! `POST /stages/{name}/move` on the service's side: the body checked, the stage free, the
//! hardware and compensation resolved from the store (the move itself is
//! [`crate::campaign::motion`]).
use super::{ApiError, Manager};
use crate::campaign::motion::MoveRequest;
use crate::campaign::spec::Campaign;
use crate::compensation::Compensation;
use crate::types::{AxisId, Direction};

/// Body of `POST /stages/{name}/move`.
#[derive(Debug, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MoveBody {
    pub x_um: f64,
    #[serde(default)]
    pub y_um: Option<f64>,
    /// `forward` (default) or `backward`.
    #[serde(default)]
    pub direction: Option<String>,
    #[serde(default)]
    pub approach_um: Option<f64>,
    /// A stored characterisation of this stage whose compensation to apply.
    #[serde(default)]
    pub compensation_from: Option<i64>,
    /// A stored campaign of this stage whose hardware to use; default the compensation's
    /// campaign, else the stage's most recent campaign.
    #[serde(default)]
    pub hardware_from: Option<i64>,
    #[serde(default)]
    pub measure: bool,
}

/// What [`api_prepare`] resolved: the hardware's campaign, the compensation, the request and
/// the stage lock held while the move runs.
pub type Prepared = (
    Campaign,
    Option<Compensation>,
    MoveRequest,
    Option<crate::campaign::stagelock::StageLock>,
);

/// A server-side failure as a client sees it: what failed, not the message (it may hold server
/// paths); the whole of it goes to the log.
fn hidden(what: &str, e: &dyn std::fmt::Display) -> ApiError {
    tracing::error!(error = %e, "move: {what}");
    ApiError::internal(format!(
        "{what} could not be read (the service's log has the details)"
    ))
}

/// The service's side of a move: the body checked, the stage free (409 while a campaign of it
/// runs or waits), its lock taken (campaigns submitted meanwhile wait for it), the hardware and
/// compensation resolved from the store. Blocking (store).
pub fn api_prepare(m: &Manager, stage: &str, body: &[u8]) -> Result<Prepared, ApiError> {
    if stage.is_empty() || stage.len() > crate::campaign::spec::MAX_NAME_LEN {
        return Err(ApiError::bad_request("stage: a name of 1 to 64 bytes"));
    }
    let b: MoveBody = serde_json::from_slice(body).map_err(|e| {
        ApiError::bad_request(format!(
            "body: expected {{\"x_um\": .., \"y_um\"?, \"direction\"?, \"approach_um\"?, \"compensation_from\"?, \"hardware_from\"?, \"measure\"?}}: {e}"
        ))
    })?;
    let direction = match b.direction.as_deref().unwrap_or("forward") {
        "forward" => Direction::Forward,
        "backward" => Direction::Backward,
        _ => return Err(ApiError::bad_request("direction: forward or backward")),
    };
    let mut wanted = vec![(AxisId::X, b.x_um)];
    if let Some(y) = b.y_um {
        wanted.push((AxisId::Y, y));
    }
    let req = MoveRequest {
        wanted,
        direction,
        approach_um: b.approach_um.unwrap_or(50.0),
        measure: b.measure,
    };
    req.check()
        .map_err(|e| ApiError::bad_request(e.to_string()))?;
    if m.shutting_down() {
        return Err(ApiError::conflict("the service is shutting down"));
    }
    if m.stage_busy(stage) {
        return Err(ApiError::conflict(format!(
            "a campaign runs or waits on stage {stage}: the move would cut in"
        )));
    }
    let store = m.store().clone();
    let (comp, hw) = store.with(|s| {
        let of_stage = |id: i64| -> Result<crate::store::CampaignRow, ApiError> {
            let row = s
                .campaign(id)
                .map_err(|e| hidden("store", &e))?
                .ok_or_else(|| ApiError::not_found(format!("no campaign {id}")))?;
            if row.stage != stage {
                return Err(ApiError::bad_request(format!(
                    "campaign {id} ran on stage {}, not {stage}",
                    row.stage
                )));
            }
            Ok(row)
        };
        let comp = match b.compensation_from {
            Some(id) => {
                let row = of_stage(id)?;
                Some(
                    crate::campaign::compensate::stored(s, id, &row.stage)
                        .map_err(|e| ApiError::bad_request(e.to_string()))?,
                )
            }
            None => None,
        };
        let hw = match b.hardware_from.or(b.compensation_from) {
            Some(id) => of_stage(id)?.id,
            None => s
                .campaigns()
                .map_err(|e| hidden("store", &e))?
                .into_iter()
                .find(|r| r.stage == stage)
                .map(|r| r.id)
                .ok_or_else(|| {
                    ApiError::not_found(format!(
                        "no campaign of stage {stage} in the store to take the hardware from"
                    ))
                })?,
        };
        Ok::<_, ApiError>((comp, hw))
    })?;
    let db_path = store.path().map(std::path::Path::to_path_buf);
    let c = crate::campaign::session::load_stored(&store, hw)
        .map_err(|e| hidden(&format!("campaign {hw}'s hardware"), &e))?;
    let lock = match db_path {
        Some(p) => Some(
            crate::campaign::stagelock::try_lock_scoped(
                &p,
                stage,
                crate::campaign::stagelock::Scope::of(c.spec().hardware.kind),
            )
            .map_err(|e| ApiError::conflict(e.to_string()))?,
        ),
        None => None,
    };
    Ok((c, comp, req, lock))
}
