//! The shared simulated stage: both axes' motion state behind one lock, a clock with a time
//! scale, and the stage model that turns commanded (encoder) positions into where the carriage
//! really is. The simulated controllers write to it; the simulated camera reads
//! [`SimStage::true_position_um`].
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use csmetro_effects::{AxisId, StageModel};

/// Time scales a simulation accepts: [`MIN_TIME_SCALE`, `MAX_TIME_SCALE`]. Below 1e-3 one
/// physical second is over a quarter of an hour: a reference move would last days, a campaign
/// could not end, and `1e-300` makes every move's wall time overflow; above 1e6 one
/// nanosecond of wall time is a millisecond of motion and on-target is never seen.
pub const MIN_TIME_SCALE: f64 = 1e-3;
/// See [`MIN_TIME_SCALE`].
pub const MAX_TIME_SCALE: f64 = 1e6;

/// Checks a time scale against [`MIN_TIME_SCALE`] and [`MAX_TIME_SCALE`]; the error says the
/// range and the value.
pub fn check_time_scale(scale: f64) -> Result<(), String> {
    if scale.is_finite() && (MIN_TIME_SCALE..=MAX_TIME_SCALE).contains(&scale) {
        Ok(())
    } else {
        Err(format!(
            "must be in [{MIN_TIME_SCALE:e}, {MAX_TIME_SCALE:e}] (physical seconds per wall second), not {scale}"
        ))
    }
}

/// Physical time of the simulation: real time × `scale` (100 = a physical hour in 36 s).
#[derive(Debug, Clone, Copy)]
pub struct SimClock {
    start: Instant,
    scale: f64,
}

impl SimClock {
    /// A clock starting now; a non-finite or non-positive `scale` means 1 (real time).
    pub fn new(scale: f64) -> Self {
        let scale = if scale.is_finite() && scale > 0.0 {
            scale
        } else {
            1.0
        };
        Self {
            start: Instant::now(),
            scale,
        }
    }
    /// Physical seconds per real second.
    pub fn scale(&self) -> f64 {
        self.scale
    }
    /// Physical seconds since the simulation started.
    pub fn now_s(&self) -> f64 {
        self.start.elapsed().as_secs_f64() * self.scale
    }
    /// Real duration of `physical_s` physical seconds.
    pub fn real(&self, physical_s: f64) -> Duration {
        Duration::from_secs_f64((physical_s / self.scale).max(0.0))
    }
}

/// A trapezoidal (or triangular) move from `p0` to `p1`, mm and s.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Profile {
    /// Physical start time, s.
    pub t0: f64,
    /// Start position, mm.
    pub p0: f64,
    /// End position, mm.
    pub p1: f64,
    /// Cruise velocity, mm/s.
    pub vel: f64,
    /// Acceleration, mm/s².
    pub acc: f64,
    /// Deceleration, mm/s².
    pub dec: f64,
}

impl Profile {
    /// (peak velocity, accel time, cruise time, decel time)
    fn phases(&self) -> (f64, f64, f64, f64) {
        let d = (self.p1 - self.p0).abs();
        let (a, b) = (self.acc.max(1e-9), self.dec.max(1e-9));
        let mut v = self.vel.max(1e-9);
        // Not enough room to reach vel: triangular profile.
        let d_ramps = v * v / (2.0 * a) + v * v / (2.0 * b);
        if d_ramps > d {
            v = (2.0 * d * a * b / (a + b)).sqrt();
        }
        let ta = v / a;
        let tb = v / b;
        let tc = if v > 0.0 {
            ((d - v * v / (2.0 * a) - v * v / (2.0 * b)) / v).max(0.0)
        } else {
            0.0
        };
        (v, ta, tc, tb)
    }
    /// Length of the move, physical s (0 when it goes nowhere).
    pub fn duration(&self) -> f64 {
        if self.p0 == self.p1 {
            return 0.0;
        }
        let (_, ta, tc, tb) = self.phases();
        ta + tc + tb
    }
    /// Physical time the move ends, s.
    pub fn end(&self) -> f64 {
        self.t0 + self.duration()
    }
    /// Position at physical time `t`.
    pub fn pos(&self, t: f64) -> f64 {
        if self.p0 == self.p1 {
            return self.p1;
        }
        let (v, ta, tc, tb) = self.phases();
        let s = (t - self.t0).max(0.0);
        let dist = if s < ta {
            0.5 * self.acc * s * s
        } else if s < ta + tc {
            0.5 * v * ta + v * (s - ta)
        } else if s < ta + tc + tb {
            let r = ta + tc + tb - s;
            (self.p1 - self.p0).abs() - 0.5 * self.dec * r * r
        } else {
            return self.p1;
        };
        self.p0 + (self.p1 - self.p0).signum() * dist
    }
    /// Velocity (signed) at physical time `t`.
    pub fn velocity(&self, t: f64) -> f64 {
        if self.p0 == self.p1 {
            return 0.0;
        }
        let (v, ta, tc, tb) = self.phases();
        let s = t - self.t0;
        let mag = if s < 0.0 || s >= ta + tc + tb {
            0.0
        } else if s < ta {
            self.acc * s
        } else if s < ta + tc {
            v
        } else {
            self.dec * (ta + tc + tb - s)
        };
        (self.p1 - self.p0).signum() * mag
    }
}

/// What a motion is for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MotionKind {
    /// An ordinary move to a target.
    Move,
    /// A reference move; on arrival the axis is referenced.
    Reference,
}

/// One motion under way on an axis.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Motion {
    /// Its trajectory.
    pub profile: Profile,
    /// Plain move or reference move.
    pub kind: MotionKind,
    /// Injected motion error: at this physical time, servo off and this error code.
    pub fail_at: Option<(f64, i32)>,
}

/// One axis as its controller sees it (mm, s).
#[derive(Debug, Clone, PartialEq)]
pub struct AxisState {
    /// Servo on (SVO 1).
    pub servo: bool,
    /// Referenced (FRF? answers 1).
    pub referenced: bool,
    /// Reference mode on (RON 1): absolute moves need a reference first.
    pub ron: bool,
    /// Encoder position at rest (valid when `motion` is None).
    pub pos_mm: f64,
    /// Commanded position, mm.
    pub target_mm: f64,
    /// The motion under way, if any.
    pub motion: Option<Motion>,
    /// Physical time when the last motion ended (settling starts there).
    pub settled_from_s: f64,
    /// Last approach direction: +1 forward, -1 backward.
    pub last_dir: f64,
    /// Velocity for the next move, mm/s.
    pub vel: f64,
    /// Acceleration for the next move, mm/s².
    pub acc: f64,
    /// Deceleration for the next move, mm/s².
    pub dec: f64,
    /// Latched GCS error (ERR? reads and clears).
    pub error: i32,
}

impl AxisState {
    /// An axis at rest at `pos_mm`, servo off, not referenced, RON 1, deceleration = `acc` (mm, mm/s, mm/s²).
    pub fn new(pos_mm: f64, vel: f64, acc: f64) -> Self {
        Self {
            servo: false,
            referenced: false,
            ron: true,
            pos_mm,
            target_mm: pos_mm,
            motion: None,
            settled_from_s: 0.0,
            last_dir: 1.0,
            vel,
            acc,
            dec: acc,
            error: 0,
        }
    }

    /// Advances the state to physical time `now`: finished moves end, injected faults fire.
    pub fn update(&mut self, now: f64) {
        let Some(m) = self.motion else { return };
        if let Some((t, code)) = m.fail_at {
            if now >= t {
                self.pos_mm = m.profile.pos(t);
                self.motion = None;
                self.servo = false;
                self.error = code;
                self.settled_from_s = t;
                return;
            }
        }
        if now >= m.profile.end() {
            self.pos_mm = m.profile.p1;
            self.motion = None;
            self.settled_from_s = m.profile.end();
            if m.kind == MotionKind::Reference {
                self.referenced = true;
            }
        }
    }

    /// Encoder position at `now` (call [`update`](Self::update) first).
    pub fn position(&self, now: f64) -> f64 {
        match &self.motion {
            Some(m) => m.profile.pos(now),
            None => self.pos_mm,
        }
    }

    /// A motion is under way.
    pub fn is_moving(&self) -> bool {
        self.motion.is_some()
    }

    /// The motion under way is a reference move.
    pub fn is_referencing(&self) -> bool {
        matches!(
            self.motion,
            Some(Motion {
                kind: MotionKind::Reference,
                ..
            })
        )
    }

    /// Stops at once where the axis is (HLT/STP/#24; a reference move stays unfinished).
    pub fn stop(&mut self, now: f64) {
        if let Some(m) = self.motion.take() {
            self.pos_mm = m.profile.pos(now);
            self.target_mm = self.pos_mm;
            self.settled_from_s = now;
        }
    }

    /// Halts smoothly (HLT): decelerates at `dec` from the current velocity to a stop. The
    /// ramp is the second half of a triangular profile peaking now, so [`Profile`] serves.
    /// A reference move so halted stays unfinished.
    pub fn halt(&mut self, now: f64) {
        let Some(m) = self.motion else { return };
        let v = m.profile.velocity(now);
        let d = self.dec.max(1e-9);
        if v == 0.0 {
            self.stop(now);
            return;
        }
        let p = m.profile.pos(now);
        let half = v * v / (2.0 * d) * v.signum();
        let profile = Profile {
            t0: now - v.abs() / d,
            p0: p - half,
            p1: p + half,
            vel: v.abs(),
            acc: d,
            dec: d,
        };
        self.target_mm = profile.p1;
        self.motion = Some(Motion {
            profile,
            kind: MotionKind::Move,
            fail_at: None,
        });
    }

    /// Starts a motion from the current position.
    pub fn start(&mut self, now: f64, target: f64, vel: f64, kind: MotionKind) {
        let p0 = self.position(now);
        self.stop(now);
        if target != p0 {
            self.last_dir = (target - p0).signum();
        }
        self.target_mm = target;
        let profile = Profile {
            t0: now,
            p0,
            p1: target,
            vel,
            acc: self.acc,
            dec: self.dec,
        };
        self.motion = Some(Motion {
            profile,
            kind,
            fail_at: None,
        });
        self.update(now);
    }
}

struct Inner {
    axes: [AxisState; 2],
}

/// The two-axis simulated stage (cheap to clone; clones share state).
#[derive(Clone)]
pub struct SimStage {
    inner: Arc<Mutex<Inner>>,
    model: Arc<StageModel>,
    clock: SimClock,
}

fn idx(a: AxisId) -> usize {
    match a {
        AxisId::X => 0,
        AxisId::Y => 1,
    }
}

impl SimStage {
    /// Both axes at `start_mm`, servo off, unreferenced, with the given default speed.
    pub fn new(model: StageModel, time_scale: f64, start_mm: [f64; 2], vel: f64, acc: f64) -> Self {
        let axes = [
            AxisState::new(start_mm[0], vel, acc),
            AxisState::new(start_mm[1], vel, acc),
        ];
        Self {
            inner: Arc::new(Mutex::new(Inner { axes })),
            model: Arc::new(model),
            clock: SimClock::new(time_scale),
        }
    }

    /// The stage's clock.
    pub fn clock(&self) -> SimClock {
        self.clock
    }

    /// The stage model that turns encoder positions into true ones.
    pub fn model(&self) -> &StageModel {
        &self.model
    }

    fn lock(&self) -> MutexGuard<'_, Inner> {
        // A panic elsewhere must not take the simulator down with poisoned state.
        self.inner.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Runs `f` on one axis, brought up to date with the clock; `f` gets the physical time.
    pub fn with_axis<R>(&self, axis: AxisId, f: impl FnOnce(&mut AxisState, f64) -> R) -> R {
        let now = self.clock.now_s();
        let mut g = self.lock();
        let a = &mut g.axes[idx(axis)];
        a.update(now);
        f(a, now)
    }

    /// The carriage's in-plane rotation now, µrad: the yaw of both axes at their positions
    /// ([`StageModel::rotation_urad_2d`]).
    pub fn rotation_urad(&self) -> f64 {
        let (x, y) = self.encoder_um();
        self.model.rotation_urad_2d(x, y)
    }

    /// Encoder positions (x, y) in µm now: what `POS?` reports.
    pub fn encoder_um(&self) -> (f64, f64) {
        let now = self.clock.now_s();
        let mut g = self.lock();
        let mut p = [0.0; 2];
        for (i, a) in g.axes.iter_mut().enumerate() {
            a.update(now);
            p[i] = a.position(now) * 1000.0;
        }
        (p[0], p[1])
    }

    /// Where the carriage really is (x, y) in µm now: encoder positions plus the stage
    /// model's planar deviation, both axes' errors each from its own last approach direction
    /// ([`StageModel::deviation_2d`]). One truth for line moves and map points alike: a line
    /// campaign's static axis adds its own error at its position (a constant of the line, as the
    /// gap contract's line offsets have it), and a two-axis move keeps the first axis's error
    /// while the second moves. Noise is not included (the camera adds it).
    pub fn true_position_um(&self) -> (f64, f64) {
        self.true_position_at_um(None)
    }

    /// As [`true_position_um`](Self::true_position_um), with the model's time-dependent
    /// effects (drift) evaluated at `time_s` instead of the simulator clock: a campaign passes
    /// its own physical time, which excludes the wall time the simulation itself spends.
    pub fn true_position_at_um(&self, time_s: Option<f64>) -> (f64, f64) {
        let now = self.clock.now_s();
        // One lock for a consistent snapshot of both axes.
        let (x, y, dx, dy) = {
            let mut g = self.lock();
            for a in g.axes.iter_mut() {
                a.update(now);
            }
            let p = |i: usize| g.axes[i].position(now) * 1000.0;
            (p(0), p(1), g.axes[0].last_dir, g.axes[1].last_dir)
        };
        let d = self.model.deviation_2d(x, y, dx, dy, time_s.unwrap_or(now));
        (x + d.x_um, y + d.y_um)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use csmetro_effects::{Effect, EffectKind};

    #[test]
    fn trapezoid_reaches_target_in_the_textbook_time() {
        // 10 mm at 2 mm/s with 4 mm/s²: 0.5 s up, 4.5 s cruise, 0.5 s down.
        let p = Profile {
            t0: 1.0,
            p0: 0.0,
            p1: 10.0,
            vel: 2.0,
            acc: 4.0,
            dec: 4.0,
        };
        assert!((p.duration() - 5.5).abs() < 1e-12);
        assert!((p.pos(1.5) - 0.5).abs() < 1e-12);
        assert!((p.pos(6.5) - 10.0).abs() < 1e-12);
        assert!((p.velocity(3.0) - 2.0).abs() < 1e-12);
        // Short move: triangular, never reaches vel.
        let q = Profile {
            t0: 0.0,
            p0: 5.0,
            p1: 4.0,
            vel: 10.0,
            acc: 4.0,
            dec: 4.0,
        };
        assert!((q.duration() - 1.0).abs() < 1e-12);
        assert!((q.pos(0.5) - 4.5).abs() < 1e-12);
    }

    #[test]
    fn halt_decelerates_smoothly_from_the_current_velocity() {
        let mut a = AxisState::new(0.0, 2.0, 4.0);
        a.servo = true;
        a.start(0.0, 10.0, 2.0, MotionKind::Move);
        a.update(2.0); // cruising at 2 mm/s, at 0.5 + 2*1.5 = 3.5 mm
        a.halt(2.0);
        // Stops 0.5 s later, v²/2d = 0.5 mm further, without a jump in position or velocity.
        let m = a.motion.unwrap();
        assert!((m.profile.pos(2.0) - 3.5).abs() < 1e-12);
        assert!((m.profile.velocity(2.0 + 1e-9) - 2.0).abs() < 1e-6);
        assert!((m.profile.end() - 2.5).abs() < 1e-12);
        a.update(3.0);
        assert!(!a.is_moving());
        assert!((a.position(3.0) - 4.0).abs() < 1e-12 && a.target_mm == a.pos_mm);
    }

    /// Both axes at 1 mm, x with 2 µm of backlash and y with 6 µm; time runs 10⁶ × faster.
    fn backlash_stage() -> SimStage {
        let model = StageModel::default()
            .with(Effect::new(
                AxisId::X,
                EffectKind::Backlash { reversal_um: 2.0 },
            ))
            .with(Effect::new(
                AxisId::Y,
                EffectKind::Backlash { reversal_um: 6.0 },
            ));
        SimStage::new(model, 1e6, [1.0, 1.0], 1.0, 10.0)
    }

    #[test]
    fn planar_truth_keeps_the_error_of_the_axis_that_moved_first() {
        let stage = backlash_stage();
        assert_eq!(
            stage.true_position_um(),
            (1001.0, 1003.0),
            "both forward at rest"
        );
        stage.with_axis(AxisId::X, |a, now| a.start(now, 0.5, 1.0, MotionKind::Move));
        std::thread::sleep(Duration::from_millis(5));
        stage.with_axis(AxisId::Y, |a, now| a.start(now, 2.0, 1.0, MotionKind::Move));
        std::thread::sleep(Duration::from_millis(5));
        // x came backward (-1 µm) and keeps it while y moves forward (+3 µm).
        let (x, y) = stage.true_position_um();
        assert!(
            (x - 499.0).abs() < 1e-9 && (y - 2003.0).abs() < 1e-9,
            "{x} {y}"
        );
    }
}
