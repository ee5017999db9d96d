//! A map campaign's (`[map]`) plan: one batch per direction over the design's points.
//!
//! A map run visits the design's points (see [`crate::sampling2d`]) with both axes moving; the
//! engine ends every move on each axis in the run's direction (forward: +x and +y) by at least
//! `[acquisition] approach_um`, pre-positioning where the path goes the other way, so every
//! point has a known backlash state.
use super::Batch;
use crate::campaign::spec::MapPlan;
use crate::types::{AxisId, Direction, Phase, RunKey, Target};

/// The run of a map direction: phase `map`, axis x by convention, cycle 0.
pub fn run_key(direction: Direction) -> RunKey {
    RunKey {
        phase: Phase::Map,
        axis: AxisId::X,
        direction,
        cycle: 0,
    }
}

/// One batch per map direction: the same points, forward in the design's order, backward in
/// the reverse order (bands from the top, descending x).
pub fn batches(mp: &MapPlan, seq: &mut u64) -> Vec<Batch> {
    let nx = mp.grid.x.n;
    let cells = &mp.points;
    mp.directions
        .iter()
        .map(|&direction| {
            let run = run_key(direction);
            let mut order = cells.clone();
            if direction == Direction::Backward {
                order.reverse();
            }
            let targets = order
                .into_iter()
                .map(|(ix, iy)| {
                    let t = Target {
                        seq: *seq,
                        run,
                        grid_index: iy * nx + ix,
                        target_x_um: mp.grid.x.position(ix),
                        target_y_um: mp.grid.y.position(iy),
                    };
                    *seq += 1;
                    t
                })
                .collect();
            Batch {
                run,
                index: 0,
                targets,
                target_error_um: None,
            }
        })
        .collect()
}
