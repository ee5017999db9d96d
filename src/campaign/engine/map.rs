//! Motion of a map run: both axes move to each point, and every move ends on each axis in the
//! run's direction (forward: +x and +y) by at least `approach_um`, so the backlash state of every
//! point is known. Where the path goes the other way on an axis (a band's start in x, y stepping
//! back inside a band), that axis first goes to the overshoot pre-position `target − sign ·
//! approach_um`. Moves are sequential (y, then x); their time is the sum. With a map's
//! compensation (a map verification) the commands are the compensated ones.

use super::{Engine, EngineError};
use crate::types::{AxisId, RunKey, Target};

impl Engine<'_> {
    /// Moves one axis to `target_um`, ending in `sign`'s direction by at least the approach
    /// travel; returns the physical time.
    async fn map_axis(
        &mut self,
        axis: AxisId,
        target_um: f64,
        sign: f64,
    ) -> Result<f64, EngineError> {
        let pre = self.campaign.spec().acquisition.approach_um;
        let now = self
            .rig
            .axis(axis)
            .position_um()
            .await
            .map_err(super::ax(axis))?;
        let mut phys = 0.0;
        if (target_um - now) * sign < pre || pre == 0.0 && (target_um - now) * sign < 0.0 {
            let (lo, hi) = self.rig.axis(axis).soft_limits_um();
            let start = (target_um - sign * pre).clamp(lo, hi);
            phys += self.move_axis(axis, start, None).await?;
        }
        phys += self.move_axis(axis, target_um, None).await?;
        Ok(phys)
    }

    /// Moves the stage onto map target `t` (see the module doc); physical time, s.
    pub(super) async fn map_move(&mut self, t: &Target) -> Result<f64, EngineError> {
        let sign = t.run.direction.sign();
        // With an XY map's compensation (a map verification's compensated pass): the commands
        // reaching the wanted point, both axes approached in the run's direction (the map's).
        let (cx, cy) = match self.compensation.clone() {
            None => (t.target_x_um, t.target_y_um),
            Some(c) => {
                let limits = [AxisId::X, AxisId::Y].map(|a| self.rig.axis(a).soft_limits_um());
                let (cmd, approach) = c
                    .command_point(t.run.direction, [t.target_x_um, t.target_y_um], limits)
                    .map_err(|e| EngineError::Other(format!("compensation: {e}")))?;
                if approach != t.run.direction {
                    return Err(EngineError::Other(format!(
                        "compensation: no {} map",
                        t.run.direction.as_str()
                    )));
                }
                (cmd[0], cmd[1])
            }
        };
        let y = self.map_axis(AxisId::Y, cy, sign).await?;
        let x = self.map_axis(AxisId::X, cx, sign).await?;
        Ok(x + y)
    }

    /// A map run's start (or a re-approach): both axes to the overshoot pre-position of `first`.
    pub(super) async fn map_approach(
        &mut self,
        run: RunKey,
        first: &Target,
        positioning: bool,
    ) -> Result<(), EngineError> {
        let pre = self.campaign.spec().acquisition.approach_um * run.direction.sign();
        let mut phys = 0.0;
        for (axis, p) in [
            (AxisId::Y, first.target_y_um),
            (AxisId::X, first.target_x_um),
        ] {
            let (lo, hi) = self.rig.axis(axis).soft_limits_um();
            phys += self.move_axis(axis, (p - pre).clamp(lo, hi), None).await?;
        }
        self.book_approach(run, first, phys, positioning);
        Ok(())
    }
}
