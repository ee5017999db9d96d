//! One (compensated) move of a stage: every command decided before anything moves, each target
//! approached from the side its correction was measured from, motion stopped on any error.
//! Used by `csmetro move` and `POST /stages/{name}/move`.
use std::time::{Duration, Instant};

use csmetro_hal::{AxisError, CameraError};
use serde_json::{json, Value};

use super::rig::{self, Rig};
use super::spec::Campaign;
use crate::compensation::{CommandError, Compensation};
use crate::types::{AxisId, Direction};

/// What to move where.
#[derive(Debug, Clone)]
pub struct MoveRequest {
    /// Wanted positions, µm, moved in this order.
    pub wanted: Vec<(AxisId, f64)>,
    /// The side each target is approached from (a one-direction table imposes its own).
    pub direction: Direction,
    /// Pre-travel before the final approach, µm.
    pub approach_um: f64,
    /// Take a camera frame at the end and report the decoded position.
    pub measure: bool,
}

/// Largest pre-travel accepted, µm.
pub const MAX_APPROACH_UM: f64 = 10_000.0;

#[derive(Debug, Clone)]
pub enum MoveError {
    /// The request cannot be served (outside the table or the soft limits): nothing moved.
    Refused(String),
    /// The hardware failed (motion stopped).
    Failed(String),
}

/// A move request whose numbers cannot be served (named by their JSON field).
#[derive(Debug, Clone, thiserror::Error)]
pub enum RequestError {
    #[error("approach_um must be 0..={MAX_APPROACH_UM}")]
    Approach,
    #[error("{0}_um must be a finite number")]
    NotFinite(AxisId),
}

impl MoveRequest {
    /// Checks the numbers themselves (before any hardware).
    pub fn check(&self) -> Result<(), RequestError> {
        if !(self.approach_um.is_finite() && (0.0..=MAX_APPROACH_UM).contains(&self.approach_um)) {
            return Err(RequestError::Approach);
        }
        if let Some((axis, _)) = self.wanted.iter().find(|(_, w)| !w.is_finite()) {
            return Err(RequestError::NotFinite(*axis));
        }
        Ok(())
    }
}

/// Why motion (or the measurement after it) failed.
#[derive(Debug, thiserror::Error)]
enum MotionError {
    #[error("axis {axis}: reference: {source}")]
    Reference { axis: AxisId, source: AxisError },
    #[error("axis {axis}: {source}")]
    Axis { axis: AxisId, source: AxisError },
    #[error("interrupted")]
    Interrupted,
    #[error("no camera")]
    NoCamera,
    #[error(transparent)]
    Camera(#[from] CameraError),
    /// The decoder's reason for rejecting the frame.
    #[error("{0}")]
    Rejected(String),
    #[error(transparent)]
    Task(#[from] tokio::task::JoinError),
}

/// One axis's move, decided before anything moves.
struct Planned {
    axis: AxisId,
    wanted_um: f64,
    command_um: f64,
    approach: Direction,
    /// The other axis's error on this one taken out, µm (compensated two-axis moves).
    cross_um: Option<f64>,
    /// The correction's standard uncertainty (k = 1) at the target, µm, when the table has one.
    u_um: Option<f64>,
    compute_us: f64,
}

/// Notes, the computation's time (µs, per axis; the hardware queries before it excluded),
/// then (axis, wanted, command, approach, cross term, u) per wanted axis, in the request's
/// order.
type Commands = (
    Vec<String>,
    f64,
    Vec<(AxisId, f64, f64, Direction, Option<f64>, Option<f64>)>,
);

fn p_dir(p: &Option<crate::compensation::AxisCommand>) -> Direction {
    p.map_or(Direction::Forward, |p| p.approach)
}

/// The compensated commands of `req`: an axis that does not move stands at its present command.
async fn plan_compensated(
    rig: &mut Rig,
    cmp: &Compensation,
    req: &MoveRequest,
) -> Result<Commands, CommandError> {
    let mut wanted = [None, None];
    let mut now_um = [0.0; 2];
    let mut limits = [(0.0, 0.0); 2];
    for (i, axis) in [AxisId::X, AxisId::Y].into_iter().enumerate() {
        let a = rig.axis(axis);
        limits[i] = a.soft_limits_um();
        wanted[i] = req.wanted.iter().find(|(w, _)| *w == axis).map(|p| p.1);
        if wanted[i].is_none() {
            // Unknown (a failed query): the cross term is left out for this axis.
            now_um[i] = a.position_um().await.unwrap_or(f64::NAN);
        }
    }
    let t0 = Instant::now();
    let plan = cmp.command_xy(wanted, now_um, req.direction, limits)?;
    let compute_us = t0.elapsed().as_secs_f64() * 1e6 / req.wanted.len().max(1) as f64;
    Ok((
        notes(cmp, &plan, wanted, now_um),
        compute_us,
        req.wanted
            .iter()
            .filter_map(|&(axis, w)| {
                let i = usize::from(axis == AxisId::Y);
                let u = cmp.table(axis).and_then(|t| t.u_at(p_dir(&plan[i]), w));
                plan[i].map(|p| (axis, w, p.command_um, p.approach, p.cross_um, u))
            })
            .collect(),
    ))
}

/// What the operator should know about a compensated move the tables cannot fully correct: an
/// axis's table holds the other axis's error where that axis stood during its line, so away
/// from there, without the other axis's table to give its straightness, the landing carries
/// the difference.
fn notes(
    cmp: &Compensation,
    plan: &[Option<crate::compensation::AxisCommand>; 2],
    wanted: [Option<f64>; 2],
    now_um: [f64; 2],
) -> Vec<String> {
    let mut out = Vec::new();
    for (i, axis) in [AxisId::X, AxisId::Y].into_iter().enumerate() {
        let (Some(p), Some(line_at)) = (plan[i], cmp.line_other_um()[i]) else {
            continue;
        };
        let other_at = plan[1 - i].map_or(now_um[1 - i], |q| q.command_um);
        let far = (other_at - line_at).abs() > 1.0 || other_at.is_nan();
        if p.cross_um.is_none() && far && wanted[i].is_some() {
            out.push(format!(
                "{axis} corrected as measured with {o} at {line_at} µm; {o} is at {other_at:.3} µm, where the tables do not give {o}'s straightness (no {o} table covering it): the landing may be off by it",
                o = axis.other()
            ));
        }
    }
    out
}

async fn go(rig: &mut Rig, c: &Campaign, p: &Planned, pre_um: f64) -> Result<f64, MotionError> {
    let axis = p.axis;
    let fail = |source| MotionError::Axis { axis, source };
    let timeout = Duration::from_secs_f64(c.spec().hardware.move_timeout_s);
    let rtimeout = Duration::from_secs_f64(c.spec().hardware.reference_timeout_s);
    let a = rig.axis(p.axis);
    let (lo, hi) = a.soft_limits_um();
    let start = (p.command_um - p.approach.sign() * pre_um).clamp(lo, hi);
    for (k, target) in [start, p.command_um].into_iter().enumerate() {
        match a.move_to(target).await {
            Err(csmetro_hal::AxisError::NotReferenced) if k == 0 => {
                a.reference(rtimeout)
                    .await
                    .map_err(|source| MotionError::Reference { axis, source })?;
                a.move_to(target).await.map_err(fail)?;
            }
            r => r.map_err(fail)?,
        }
        a.wait_on_target(timeout).await.map_err(fail)?;
    }
    a.position_um().await.map_err(fail)
}

async fn measure(rig: &mut Rig) -> Result<(f64, f64), MotionError> {
    let mut cam = rig.camera.take().ok_or(MotionError::NoCamera)?;
    let decoder = rig.decoder.clone();
    let (cam, r) = tokio::task::spawn_blocking(move || {
        let r = cam
            .trigger(Duration::from_secs(5))
            .and_then(|job| job())
            .map_err(MotionError::Camera)
            .and_then(|frame| {
                let d = decoder.decode(&frame);
                if d.ok {
                    Ok((d.x_um, d.y_um))
                } else {
                    Err(MotionError::Rejected(
                        d.reason.unwrap_or_else(|| "frame rejected".into()),
                    ))
                }
            });
        (cam, r)
    })
    .await?;
    rig.camera = Some(cam);
    r
}

/// Moves the stage of campaign `c`'s hardware as `req` asks; `cancel` resolving stops motion.
/// The answer: per axis wanted, commanded, correction, approach, encoder, computation time (µs),
/// and the measured position when asked.
pub async fn execute(
    c: &Campaign,
    comp: Option<&Compensation>,
    req: &MoveRequest,
    cancel: impl std::future::Future<Output = ()>,
) -> Result<Value, MoveError> {
    req.check().map_err(|e| MoveError::Refused(e.to_string()))?;
    let mut rig = rig::build(c)
        .await
        .map_err(|e| MoveError::Failed(format!("hardware: {e}")))?;
    // Every command first (soft limits, table range): a refused one moves nothing. Both axes
    // together: the one that does not move still bends the other's path (its straightness).
    let mut planned = Vec::new();
    let move_notes;
    let t0 = Instant::now();
    let r = match comp {
        Some(cmp) => plan_compensated(&mut rig, cmp, req).await,
        None => req
            .wanted
            .iter()
            .map(|&(axis, w)| {
                let limits = rig.axis(axis).soft_limits_um();
                if w < limits.0 || w > limits.1 {
                    Err(CommandError::OutsideLimits {
                        axis,
                        wanted_um: w,
                        command_um: w,
                        lo_um: limits.0,
                        hi_um: limits.1,
                    })
                } else {
                    Ok((axis, w, w, req.direction, None, None))
                }
            })
            .collect::<Result<Vec<_>, _>>()
            .map(|c| {
                let us = t0.elapsed().as_secs_f64() * 1e6 / req.wanted.len().max(1) as f64;
                (Vec::new(), us, c)
            }),
    };
    match r {
        Ok((n, compute_us, cmds)) => {
            move_notes = n;
            for (axis, wanted_um, command_um, approach, cross_um, u_um) in cmds {
                planned.push(Planned {
                    axis,
                    wanted_um,
                    command_um,
                    approach,
                    cross_um,
                    u_um,
                    compute_us,
                });
            }
        }
        Err(e) => {
            rig.close().await;
            return Err(MoveError::Refused(e.to_string()));
        }
    }
    let moves = async {
        let mut enc = Vec::new();
        for p in &planned {
            enc.push(go(&mut rig, c, p, req.approach_um).await?);
        }
        Ok::<_, MotionError>(enc)
    };
    let r = tokio::select! {
        r = moves => r,
        _ = cancel => Err(MotionError::Interrupted),
    };
    let encoders = match r {
        Ok(e) => e,
        Err(e) => {
            rig.stop_all().await;
            rig.close().await;
            return Err(MoveError::Failed(format!("{e}; motion stopped")));
        }
    };
    let measured = if req.measure {
        Some(measure(&mut rig).await)
    } else {
        None
    };
    rig.close().await;
    let axes: Vec<_> = planned
        .iter()
        .zip(&encoders)
        .map(|(p, e)| {
            // Where the compensated move is expected to land around the wanted position (k = 1):
            // the table's u there with the characterisation's repeatability.
            let landing = comp.zip(p.u_um).map(|(c, u)| c.landing_u_um(p.axis, u));
            let repeat = comp.and_then(|c| c.repeatability_um[p.axis as usize]);
            json!({"axis": p.axis.as_str(), "wanted_um": p.wanted_um, "command_um": p.command_um,
                   "correction_um": p.command_um - p.wanted_um, "approach": p.approach.as_str(),
                   "cross_um": p.cross_um, "u_um": p.u_um, "encoder_um": e, "compute_us": p.compute_us,
                   "landing_u_um": landing, "repeatability_um": repeat})
        })
        .collect();
    let mut out = json!({"compensation": comp.map(|c| c.source.clone()), "axes": axes});
    if !move_notes.is_empty() {
        out["notes"] = json!(move_notes);
    }
    match &measured {
        Some(Ok((x, y))) => {
            out["measured_x_um"] = json!(x);
            out["measured_y_um"] = json!(y);
        }
        Some(Err(e)) => out["measure_error"] = json!(e.to_string()),
        None => {}
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::compensation::{AxisCommand, AxisTable, Correction};

    #[test]
    fn a_move_away_from_the_line_without_the_other_table_is_noted() {
        let text = "position_um,ef_xx_um,corr_forward_um,corr_backward_um\n0,1,-1,\n100,1,-1,\n";
        let t = AxisTable::parse(AxisId::X, text, "x.csv").unwrap();
        let cmp = Compensation {
            stage: None,
            campaign: None,
            correction: Correction::Lines {
                x: Some(t),
                y: None,
                line_other_um: [Some(2100.0), None],
            },
            source: "test".into(),
            repeatability_um: [None, None],
        };
        let plan = [
            Some(AxisCommand {
                command_um: 49.0,
                approach: Direction::Forward,
                cross_um: None,
            }),
            None,
        ];
        let n = notes(&cmp, &plan, [Some(50.0), None], [0.0, 0.0]);
        assert_eq!(n.len(), 1, "{n:?}");
        assert!(
            n[0].contains("y at 2100 µm") && n[0].contains("0.000 µm"),
            "{n:?}"
        );
        // At the line's y: nothing to say.
        assert!(notes(&cmp, &plan, [Some(50.0), None], [0.0, 2100.0]).is_empty());
    }
}
