//! The acquisition engine: reference the axes, then for each planned target move → on-target →
//! settle → trigger → decode → a sample, committed at once and streamed to the reconstruction
//! worker. Decoding (and the simulated camera's rendering) runs on blocking threads while the
//! stage moves on; a rejected frame is re-measured later, re-approached from its run's
//! direction, and never stored. Pause is checked between points. Abort and stop are watched
//! during every wait (identification, reference moves, moves, settling, the camera, decoding):
//! the axis command in progress is dropped and both axes get a stop at once, and no motion
//! command is sent once either is requested. An unrecoverable error and the end of the campaign
//! also stop motion.
use std::collections::{BTreeMap, VecDeque};
use std::time::{Duration, Instant};

use csmetro_hal::{AxisError, CameraError, Frame, PendingFrame};
use csmetro_ppp::Decoder;
use serde::Serialize;
use serde_json::json;
use tokio::sync::watch;
use tokio::task::JoinHandle;

use super::plan::{Batch, Plan};
use super::rig::Rig;
use super::spec::Campaign;
use super::worker::StopEstimate;
use crate::store::StoreError;
use crate::types::{AxisId, Phase, RunKey, SampleRecord, Target};

mod map;

/// What the operator (or the service) asks of a running campaign.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Control {
    Run,
    Pause,
    /// Stop motion and end the campaign for good (state aborted).
    Abort,
    /// Stop motion and end this attempt, leaving the campaign resumable (service shutdown).
    Stop,
}

impl Control {
    /// Abort or Stop: the engine halts at the next point.
    pub fn halts(self) -> bool {
        matches!(self, Control::Abort | Control::Stop)
    }
}

/// Where samples and events go: the store, the worker, the API. Called on the engine's task.
pub trait Recorder: Send {
    /// Commits one sample; `Ok(false)` when its target was stored already.
    fn sample(&mut self, s: &SampleRecord) -> Result<bool, StoreError>;
    fn event(&mut self, kind: &str, data: serde_json::Value);
    /// A run (one sweep) has all its samples.
    fn run_done(&mut self, run: RunKey);
    /// Cross-validated error estimate of a CS run from the samples so far (adaptive mode).
    fn cv_error_um(&mut self, run: RunKey) -> Option<f64>;
    /// The adaptive stop's error estimate of a CS run from the samples so far; by default the
    /// cross-validated one, taken as exact.
    fn stop_estimate(&mut self, run: RunKey) -> Option<StopEstimate> {
        let e = self.cv_error_um(run)?;
        Some(StopEstimate {
            error_um: e,
            scatter_um: 0.0,
            cv_error_um: Some(e),
            distance_exponent: 0.0,
            method: String::new(),
            m: 0,
            pooled_m: 0,
            u_mean_um: None,
            band_error_um: None,
            true_error_um: None,
            values_um: Vec::new(),
        })
    }
    /// Simulation: the true stage position (mean over the frames) of the sample about to be
    /// committed for target `seq`, µm. Called before [`Recorder::sample`].
    fn truth(&mut self, _seq: u64, _x_um: f64, _y_um: f64) {}
}

/// Adaptive stop rule: the curve's pointwise band says its mean |error| is within the target
/// ([`super::worker::band_mean_abs_um`]: mean over the grid of u·√(2/π), u at k = 1). The band
/// is calibrated on the chosen curve's own held-out residuals at their distances to the nearest
/// sample and evaluated at the distances the whole design leaves, so it knows a spread design's
/// short gaps and a pooled curve's other-direction samples without a discount factor (the
/// cross-validated error taken as it is overstated a spread design's error 1.2-1.8x, and the
/// rule before this one divided it by a tuned 1.2). A curve without a band (bp or bpdn asked
/// for directly) falls back to its cross-validated error, undiscounted.
pub fn meets(e: &StopEstimate, goal_um: f64) -> bool {
    match e.band_error_um.or(e.cv_error_um) {
        Some(err) => err.is_finite() && err <= goal_um,
        None => false,
    }
}

/// A line's static axis closer than this to its place (µm) is already there: not moved again.
const STATIC_AT_UM: f64 = 0.01;

/// A run's batches and the next one to measure.
struct Sweep {
    run: RunKey,
    batches: Vec<Batch>,
    next: usize,
}

/// Runs `a` and `b` (next to each other in the plan) alternate batches: adaptive runs (several
/// batches each) of the same phase, axis and cycle.
fn takes_turns(plan: &Plan, a: RunKey, b: RunKey) -> bool {
    let adaptive = |r: RunKey| plan.run_batches(r).nth(1).is_some();
    a.phase == b.phase && a.axis == b.axis && a.cycle == b.cycle && adaptive(a) && adaptive(b)
}

/// Time and counts of one (phase, axis).
#[derive(Debug, Clone, Default, Serialize)]
pub struct PhaseStats {
    pub measurements: u64,
    /// Physical time measuring the run's targets: moves between them, settling, dwell, frames,
    /// and the re-approaches of retried points, s.
    pub acquisition_s: f64,
    /// Physical time getting to a run's start (the other axis into place, the approach
    /// pre-travel), and back after a pause, s. Kept apart: it depends on where the previous run
    /// or the reference move left the stage, i.e. on the plan order, not on the phase (the
    /// first phase after referencing pays the trip from the reference switch).
    pub positioning_s: f64,
    /// Wall time decoding frames, s.
    pub decode_s: f64,
    pub frames: u64,
    pub rejected_frames: u64,
    pub failed_points: u64,
    /// Targets not measured because the adaptive mode met its error target.
    pub saved_by_adaptive: u64,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum EndState {
    Done,
    Aborted,
    /// Halted by [`Control::Stop`]: resumable from the last stored sample.
    Stopped,
}

fn end_of(c: Control) -> EndState {
    if c == Control::Stop {
        EndState::Stopped
    } else {
        EndState::Aborted
    }
}

#[derive(Debug, Clone, Serialize)]
pub struct Outcome {
    pub end: EndState,
    pub stats: BTreeMap<String, PhaseStats>,
    pub wall_s: f64,
}

pub fn stats_key(phase: Phase, axis: AxisId) -> String {
    format!("{}-{}", phase.as_str(), axis.as_str())
}

#[derive(Debug, thiserror::Error)]
pub enum EngineError {
    #[error("axis {axis}: {source}")]
    Axis { axis: AxisId, source: AxisError },
    #[error("camera: {0}")]
    Camera(#[from] CameraError),
    #[error("storage: {0}")]
    Store(#[from] StoreError),
    #[error("{0}")]
    Other(String),
    /// Abort or stop requested while the engine waited; [`Engine::run`] turns it into its end
    /// state, it never leaves the engine.
    #[error("halted ({0:?})")]
    Halted(Control),
}

/// The halt (Abort or Stop) requested, if any.
fn requested(control: &watch::Receiver<Control>) -> Option<Control> {
    let c = *control.borrow();
    c.halts().then_some(c)
}

/// Resolves once Abort or Stop is requested; never when nobody can request one any more.
async fn halt_requested(control: &mut watch::Receiver<Control>) -> Control {
    // The guard is dropped before any other await (it is not Send).
    let c = control.wait_for(|c| c.halts()).await.map(|c| *c);
    match c {
        Ok(c) => c,
        Err(_) => std::future::pending().await,
    }
}

/// Runs `op` (an axis command) unless a halt is requested before or while it runs; a halt
/// drops it at once (the GCS driver's exchanges are cancel-safe), and the caller's `?` takes
/// [`EngineError::Halted`] up to [`Engine::run`], which stops both axes.
async fn guarded<T>(
    control: &mut watch::Receiver<Control>,
    op: impl std::future::Future<Output = Result<T, EngineError>>,
) -> Result<T, EngineError> {
    if let Some(c) = requested(control) {
        return Err(EngineError::Halted(c));
    }
    tokio::select! {
        biased;
        c = halt_requested(control) => Err(EngineError::Halted(c)),
        r = op => r,
    }
}

fn ax(axis: AxisId) -> impl FnOnce(AxisError) -> EngineError {
    move |source| EngineError::Axis { axis, source }
}

/// A frame set in flight: the target, when it was taken, and its decode job.
struct InFlight {
    target: Target,
    encoder_um: f64,
    time_s: f64,
    unix_s: f64,
    point_s: f64,
    /// Simulation: the true position at the triggers of this point.
    truth: Option<(f64, f64)>,
    job: JoinHandle<Decoded>,
}

struct Decoded {
    ok: Option<(f64, f64, f64, f64)>,
    /// The frames' scatter (x, y) about their mean, µm; with two frames or more.
    frame_sd_um: Option<[f64; 2]>,
    reason: Option<String>,
    frames: u32,
    wall_s: f64,
}

fn unix_now() -> f64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_secs_f64())
        .unwrap_or(0.0)
}

/// Decodes and averages the frames of one point; any rejected frame rejects the point.
fn decode_all(decoder: &Decoder, jobs: Vec<PendingFrame>) -> Decoded {
    // Decoding only: a simulated camera's rendering is not processing.
    let mut wall = 0.0;
    let n = jobs.len() as u32;
    let (mut xs, mut ys, mut st, mut q) = (Vec::new(), Vec::new(), 0.0, f64::INFINITY);
    for job in jobs {
        let frame: Frame = match job() {
            Ok(f) => f,
            Err(e) => {
                return Decoded {
                    ok: None,
                    frame_sd_um: None,
                    reason: Some(format!("camera: {e}")),
                    frames: n,
                    wall_s: wall,
                }
            }
        };
        let t = Instant::now();
        let r = decoder.decode(&frame);
        wall += t.elapsed().as_secs_f64();
        if !r.ok {
            return Decoded {
                ok: None,
                frame_sd_um: None,
                reason: r.reason.or(Some("rejected".into())),
                frames: n,
                wall_s: wall,
            };
        }
        xs.push(r.x_um);
        ys.push(r.y_um);
        st += r.theta_mrad;
        let bits = (r.quality.bits_x + r.quality.bits_y).max(1) as f64;
        let agree = 1.0 - (r.quality.bit_errors_x + r.quality.bit_errors_y) as f64 / bits;
        q = q.min(agree);
    }
    let k = n as f64;
    let mean = |v: &[f64]| v.iter().sum::<f64>() / k;
    let sd = |v: &[f64]| {
        let c = mean(v);
        (v.iter().map(|x| (x - c).powi(2)).sum::<f64>() / (k - 1.0)).sqrt()
    };
    let frame_sd_um =
        Some([sd(&xs), sd(&ys)]).filter(|s| n >= 2 && s.iter().all(|v| v.is_finite()));
    Decoded {
        ok: Some((mean(&xs), mean(&ys), st / k, q)),
        frame_sd_um,
        reason: None,
        frames: n,
        wall_s: wall,
    }
}

pub struct Engine<'a> {
    pub campaign: &'a Campaign,
    pub rig: &'a mut Rig,
    pub recorder: &'a mut dyn Recorder,
    pub control: watch::Receiver<Control>,
    /// Targets stored by an earlier attempt (resume): skipped, never measured twice.
    pub done: BTreeMap<u64, SampleRecord>,
    /// Physical time already spent by earlier attempts, s.
    pub start_time_s: f64,
    stats: BTreeMap<String, PhaseStats>,
    /// Physical time spent on a target before the attempt that is stored (rejected attempts,
    /// re-approaches), s: it goes into that sample's `point_s`, so the stored samples alone
    /// give the acquisition time.
    extra_s: BTreeMap<u64, f64>,
    /// Where the sweep came from before a re-approach (a resume mid-run, after a pause): the
    /// next point's move is timed from there, as an uninterrupted sweep moves (simulation; on
    /// hardware a move's time is the wall time).
    planned_from_um: Option<f64>,
    /// Decode jobs in flight at most (2 cores: keep both busy while the stage moves).
    pub depth: usize,
    /// Applied to every commanded target of the moving axis (verification runs,
    /// `[compensation]`); samples keep the wanted target, so their error is the residual.
    pub compensation: Option<std::sync::Arc<crate::compensation::Compensation>>,
    /// Points measured whose frames are still being decoded, oldest first.
    flight: VecDeque<InFlight>,
    /// Both axes were sent a stop after a halt request (sent once).
    stopped: bool,
}

impl<'a> Engine<'a> {
    pub fn new(
        campaign: &'a Campaign,
        rig: &'a mut Rig,
        recorder: &'a mut dyn Recorder,
        control: watch::Receiver<Control>,
        done: BTreeMap<u64, SampleRecord>,
    ) -> Self {
        let start_time_s = done
            .values()
            .map(|s| s.time_s + s.point_s)
            .fold(0.0, f64::max);
        Self {
            campaign,
            rig,
            recorder,
            control,
            done,
            start_time_s,
            stats: BTreeMap::new(),
            extra_s: BTreeMap::new(),
            planned_from_um: None,
            depth: std::thread::available_parallelism()
                .map_or(2, |n| n.get())
                .clamp(2, 8),
            compensation: None,
            flight: VecDeque::new(),
            stopped: false,
        }
    }

    /// A halt was requested: stops both axes (once) before anything else is done.
    async fn stop_for_halt(&mut self) {
        if !self.stopped {
            self.stopped = true;
            self.rig.stop_all().await;
        }
    }

    /// The command for target `t`: the target itself, or its compensated command. A command the
    /// compensation refuses (outside its table or the soft limits) ends the run; nothing moves.
    fn commanded_um(&mut self, t: &Target) -> Result<f64, EngineError> {
        let Some(c) = self.compensation.clone() else {
            return Ok(t.target_um());
        };
        let limits = self.rig.axis(t.run.axis).soft_limits_um();
        c.command(t.run.axis, t.run.direction, t.target_um(), limits)
            .map_err(|e| EngineError::Other(format!("compensation: {e}")))
    }

    fn stat(&mut self, run: RunKey) -> &mut PhaseStats {
        self.stats
            .entry(stats_key(run.phase, run.axis))
            .or_default()
    }

    fn advance(&mut self, run: RunKey, physical_s: f64) {
        self.stat(run).acquisition_s += physical_s;
        self.tick(physical_s);
    }

    fn tick(&mut self, physical_s: f64) {
        let t = self.rig.clock.get() + physical_s;
        self.rig.clock.set(t);
    }

    /// Runs the plan; on error, abort or stop the axes are stopped before returning. An error
    /// met after a halt was requested (a command cut short by it) ends the campaign as the
    /// halt says: the operator's abort stays an abort.
    pub async fn run(&mut self, plan: &Plan) -> Result<Outcome, EngineError> {
        let t0 = Instant::now();
        self.rig.clock.set(self.start_time_s);
        let r = self.run_inner(plan).await;
        let r = match r {
            Ok(EndState::Done) => Ok(EndState::Done),
            Ok(end) => {
                self.stop_for_halt().await;
                Ok(end)
            }
            Err(EngineError::Halted(c)) => {
                self.stop_for_halt().await;
                Ok(end_of(c))
            }
            Err(e) => {
                self.rig.stop_all().await;
                match requested(&self.control) {
                    Some(c) => {
                        self.recorder.event(
                            "error",
                            json!({"cause": "after_halt", "error": e.to_string(), "resumable": c == Control::Stop}),
                        );
                        Ok(end_of(c))
                    }
                    None => Err(e),
                }
            }
        };
        if r.as_ref().is_ok_and(|e| *e != EndState::Done) {
            // Motion is stopped: points already measured are decoded and stored (a resume
            // does not measure them again).
            while let Some(f) = self.flight.pop_front() {
                if let Err(e) = self.land(f, 0).await {
                    tracing::warn!(error = %e, "a point measured before the halt was not stored");
                }
            }
        }
        let end = r?;
        Ok(Outcome {
            end,
            stats: self.stats.clone(),
            wall_s: t0.elapsed().as_secs_f64(),
        })
    }

    async fn run_inner(&mut self, plan: &Plan) -> Result<EndState, EngineError> {
        // Earlier samples first, so the worker reconstructs from everything.
        // A store that fails here would fail the next sample too: stop now, nothing lost.
        for s in self.done.values() {
            self.recorder.sample(s)?;
        }
        let timeout = Duration::from_secs_f64(self.campaign.spec().hardware.reference_timeout_s);
        for a in [AxisId::X, AxisId::Y] {
            let rig = &mut *self.rig;
            let info = guarded(&mut self.control, async {
                rig.axis(a).identify().await.map_err(ax(a))
            })
            .await?;
            self.recorder.event(
                "axis",
                json!({"axis": a.as_str(), "idn": info.idn, "stage": info.stage, "travel_um": [info.travel_um.0, info.travel_um.1]}),
            );
            let t = Instant::now();
            // A reference move runs for seconds (tens at a slow reference velocity): a halt
            // cuts it short, and the next axis's is never started.
            let rig = &mut *self.rig;
            guarded(&mut self.control, async {
                rig.axis(a).reference(timeout).await.map_err(ax(a))
            })
            .await?;
            let phys = self.rig.time.physical_since(t);
            let t = self.rig.clock.get() + phys;
            self.rig.clock.set(t);
            self.recorder.event(
                "referenced",
                json!({"axis": a.as_str(), "physical_s": phys}),
            );
        }
        let runs = plan.runs();
        let mut i = 0;
        while i < runs.len() {
            // Adaptive runs of one axis and cycle take turns batch by batch: a forward batch
            // ends at the top of the stroke where the backward one starts, and the backward one
            // ends where the next forward one starts, so no batch pays a trip back across the
            // stroke (9.5 mm, 6 s on the demo's X for every batch of a run on its own).
            let mut j = i + 1;
            while j < runs.len() && takes_turns(plan, runs[i], runs[j]) {
                j += 1;
            }
            let mut sweeps: Vec<Sweep> = runs[i..j]
                .iter()
                .map(|&run| Sweep {
                    run,
                    batches: plan.run_batches(run).cloned().collect(),
                    next: 0,
                })
                .collect();
            i = j;
            while sweeps.iter().any(|w| w.next < w.batches.len()) {
                for w in sweeps.iter_mut().filter(|w| w.next < w.batches.len()) {
                    let c = self.control_point().await;
                    if c.halts() {
                        return Ok(end_of(c));
                    }
                    if let Some(c) = self.sweep_batch(w).await? {
                        return Ok(end_of(c));
                    }
                }
            }
        }
        self.rig.stop_all().await;
        Ok(EndState::Done)
    }

    /// Decides whether an adaptive sweep goes on (after its first batch), then measures its next
    /// batch (announcing the run before the first); a stopped or finished sweep is done. The
    /// decision waits until the sweep's turn comes again: when two directions take turns, the
    /// other direction's batch measured in between is in the estimate (a pooled curve uses it).
    /// `Some` when halted.
    async fn sweep_batch(&mut self, w: &mut Sweep) -> Result<Option<Control>, EngineError> {
        let run = w.run;
        let bi = w.next;
        if self.stops(w) {
            let n: usize = w.batches[bi..].iter().map(|b| b.targets.len()).sum();
            self.stat(run).saved_by_adaptive += n as u64;
            w.next = w.batches.len();
        } else {
            if bi == 0 {
                let todo = w
                    .batches
                    .iter()
                    .flat_map(|b| &b.targets)
                    .filter(|t| !self.done.contains_key(&t.seq))
                    .count();
                self.recorder.event(
                    "run_start",
                    json!({"run": run.label(), "targets": w.batches.iter().map(|b| b.targets.len()).sum::<usize>(), "to_measure": todo}),
                );
            }
            let c = self.batch(&w.batches[bi]).await?;
            if c.halts() {
                return Ok(Some(c));
            }
            w.next += 1;
        }
        if w.next == w.batches.len() {
            self.recorder.run_done(run);
            self.recorder.event("run_done", json!({"run": run.label()}));
        }
        Ok(None)
    }

    /// The adaptive decision before a sweep's next batch (none before its first, or when the
    /// batch measured last has no target): whether the estimate from everything measured so
    /// far meets the target. Recorded as an `adaptive` event either way.
    fn stops(&mut self, w: &Sweep) -> bool {
        let Some(last) = w.next.checked_sub(1) else {
            return false;
        };
        let Some(goal) = w.batches[last].target_error_um else {
            return false;
        };
        let run = w.run;
        let est = self.recorder.stop_estimate(run);
        let stop = est.as_ref().is_some_and(|e| meets(e, goal));
        let cv = est.as_ref().and_then(|e| e.cv_error_um);
        self.recorder.event(
            "adaptive",
            json!({"run": run.label(), "batch": last, "cv_error_um": cv, "target_error_um": goal, "stop": stop,
                   "error_estimate_um": est.as_ref().map(|e| e.error_um),
                   "scatter_um": est.as_ref().map(|e| e.scatter_um),
                   "m": est.as_ref().map(|e| e.m), "pooled_m": est.as_ref().map(|e| e.pooled_m), "method": est.as_ref().map(|e| e.method.clone()),
                   "band_error_um": est.as_ref().and_then(|e| e.band_error_um),
                   "u_mean_um": est.as_ref().and_then(|e| e.u_mean_um),
                   "true_error_um": est.as_ref().and_then(|e| e.true_error_um)}),
        );
        stop
    }

    /// Waits while paused; returns Run, Abort or Stop.
    async fn control_point(&mut self) -> Control {
        loop {
            let c = *self.control.borrow_and_update();
            match c {
                Control::Run | Control::Abort | Control::Stop => return c,
                Control::Pause => {
                    // The pause itself (who, when) is the manager's `paused` event; this one
                    // says motion is held, between two points.
                    self.recorder.event("held", json!({"reason": "paused"}));
                    if self.control.changed().await.is_err() {
                        // Nobody left to resume us: end resumable, not aborted.
                        return Control::Stop;
                    }
                    if *self.control.borrow() == Control::Run {
                        self.recorder.event("released", json!({}));
                    }
                }
            }
        }
    }

    /// Moves `axis` to `target_um` and waits for on-target; returns the physical time taken,
    /// timed from `timed_from_um` instead of where the axis was when given.
    async fn move_axis(
        &mut self,
        axis: AxisId,
        target_um: f64,
        timed_from_um: Option<f64>,
    ) -> Result<f64, EngineError> {
        let timeout = Duration::from_secs_f64(self.campaign.spec().hardware.move_timeout_s);
        let t = Instant::now();
        // Every motion command goes through here: none is sent once a halt is requested.
        let a = self.rig.axis(axis);
        let from = guarded(&mut self.control, async {
            let from = a.position_um().await.map_err(ax(axis))?;
            a.move_to(target_um).await.map_err(ax(axis))?;
            a.wait_on_target(timeout).await.map_err(ax(axis))?;
            Ok(from)
        })
        .await?;
        let from = timed_from_um.unwrap_or(from);
        Ok(self.rig.motion_s(axis, (target_um - from).abs(), t))
    }

    /// Puts the stage where a sweep to `first` in `direction` approaches it from the right side.
    /// `positioning`: the time counts as [`PhaseStats::positioning_s`] (a run's start, a resume
    /// after a pause), otherwise as acquisition (a retried point, an adaptive batch's sweep).
    async fn approach(
        &mut self,
        run: RunKey,
        first: &Target,
        positioning: bool,
    ) -> Result<(), EngineError> {
        if run.phase == Phase::Map {
            return self.map_approach(run, first, positioning).await;
        }
        let other = run.axis.other();
        let other_at = match other {
            AxisId::X => first.target_x_um,
            AxisId::Y => first.target_y_um,
        };
        let pre = &self.campaign.spec().acquisition.approach_um;
        let (lo, hi) = self.rig.axis(run.axis).soft_limits_um();
        let start = (first.target_um() - run.direction.sign() * pre).clamp(lo, hi);
        let mut phys = 0.0;
        // The other axis stands still during a run: put it in place first, always approached
        // from below, so its own direction-dependent error (its backlash) is one known constant
        // of the line, the same for every run of the axis and for the truth it is compared with.
        let a = self.rig.axis(other);
        let at = guarded(&mut self.control, async {
            a.position_um().await.map_err(ax(other))
        })
        .await?;
        if at > other_at + STATIC_AT_UM {
            let (olo, _) = self.rig.axis(other).soft_limits_um();
            let below = (other_at - pre).max(olo);
            if below < other_at {
                phys += self.move_axis(other, below, None).await?;
            }
        }
        phys += self.move_axis(other, other_at, None).await?;
        phys += self.move_axis(run.axis, start, None).await?;
        self.book_approach(run, first, phys, positioning);
        Ok(())
    }

    /// Books `phys` s of approach to `first`: as positioning (a `positioned` event) or as the
    /// acquisition time of the target it leads to.
    fn book_approach(&mut self, run: RunKey, first: &Target, phys: f64, positioning: bool) {
        if positioning {
            self.stat(run).positioning_s += phys;
            self.tick(phys);
            // The approach to a run's start is stored once per run (the last one counts): a
            // re-approach after a pause or a restart is time an uninterrupted run never spends.
            let run_start = !self.done.values().any(|s| s.target.run == run);
            self.recorder.event(
                "positioned",
                json!({"run": run.label(), "phase": run.phase.as_str(), "axis": run.axis.as_str(),
                       "physical_s": phys, "run_start": run_start}),
            );
        } else {
            self.advance(run, phys);
            *self.extra_s.entry(first.seq).or_default() += phys;
        }
    }

    async fn trigger(&mut self, frames: u32) -> Result<Vec<PendingFrame>, EngineError> {
        let mut cam = self
            .rig
            .camera
            .take()
            .ok_or_else(|| EngineError::Other("camera lost".into()))?;
        let timeout = Duration::from_secs(5);
        // A real camera blocks for its exposure: keep the runtime's threads free.
        let mut task = tokio::task::spawn_blocking(move || {
            let mut jobs = Vec::new();
            for _ in 0..frames {
                match cam.trigger(timeout) {
                    Ok(j) => jobs.push(j),
                    Err(e) => return (cam, Err(e)),
                }
            }
            (cam, Ok(jobs))
        });
        // The stage stands still meanwhile, but a halt still stops the axes now; the trigger
        // (bounded by its timeout) then ends, and the halt is taken at the next point.
        let done = tokio::select! {
            biased;
            _ = halt_requested(&mut self.control) => None,
            r = &mut task => Some(r),
        };
        let done = match done {
            Some(r) => r,
            None => {
                self.stop_for_halt().await;
                task.await
            }
        };
        let (cam, jobs) = done.map_err(|e| EngineError::Other(format!("camera task: {e}")))?;
        self.rig.camera = Some(cam);
        Ok(jobs?)
    }

    /// Measures at one target: move, settle, trigger; returns the decode job in flight.
    async fn measure(&mut self, t: &Target) -> Result<InFlight, EngineError> {
        let acq = &self.campaign.spec().acquisition;
        let (settle, dwell, frames) = (acq.settle_s, acq.dwell_s, acq.frames_per_point);
        let from = self.planned_from_um.take();
        let move_s = if t.run.phase == Phase::Map {
            self.map_move(t).await?
        } else {
            let command_um = self.commanded_um(t)?;
            self.move_axis(t.run.axis, command_um, from).await?
        };
        let wait = settle + dwell;
        let pause = self.rig.time.wall(wait);
        guarded(&mut self.control, async {
            tokio::time::sleep(pause).await;
            Ok(())
        })
        .await?;
        let a = self.rig.axis(t.run.axis);
        let encoder_um = guarded(&mut self.control, async {
            a.position_um().await.map_err(ax(t.run.axis))
        })
        .await?;
        let time_s = self.rig.clock.get() + move_s + wait;
        self.rig.clock.set(time_s);
        let trig = Instant::now();
        let mark = self.rig.triggers.as_ref().map(|l| l.len());
        let jobs = self.trigger(frames).await?;
        let truth = match (&self.rig.triggers, mark) {
            (Some(l), Some(m)) => l.mean_since(m),
            _ => None,
        };
        let frame_s = match self.rig.frame_time_s {
            Some(f) => f * frames as f64,
            None => self.rig.time.physical_since(trig),
        };
        let point_s = move_s + wait + frame_s;
        self.advance(t.run, frame_s);
        self.stat(t.run).acquisition_s += move_s + wait;
        let decoder = self.rig.decoder.clone();
        let job = tokio::task::spawn_blocking(move || decode_all(&decoder, jobs));
        Ok(InFlight {
            target: *t,
            encoder_um,
            time_s,
            unix_s: unix_now(),
            point_s,
            truth,
            job,
        })
    }

    /// Finishes a point: a stored sample, or the target back for a retry.
    async fn land(
        &mut self,
        f: InFlight,
        rejected_before: u32,
    ) -> Result<Option<Target>, EngineError> {
        let mut f = f;
        // No motion while decoding, but a halt stops the axes now, not after the decode.
        let d = tokio::select! {
            biased;
            _ = halt_requested(&mut self.control), if !self.stopped => None,
            d = &mut f.job => Some(d),
        };
        let d = match d {
            Some(d) => d,
            None => {
                self.stop_for_halt().await;
                (&mut f.job).await
            }
        };
        let d = d.map_err(|e| EngineError::Other(format!("decode task: {e}")))?;
        let run = f.target.run;
        {
            let st = self.stat(run);
            st.decode_s += d.wall_s;
            st.frames += d.frames as u64;
        }
        match d.ok {
            Some((x, y, theta, quality)) => {
                let rec = SampleRecord {
                    target: f.target,
                    meas_x_um: x,
                    meas_y_um: y,
                    theta_mrad: theta,
                    encoder_um: f.encoder_um,
                    time_s: f.time_s,
                    unix_s: f.unix_s,
                    quality,
                    frames: d.frames,
                    rejected: rejected_before,
                    point_s: f.point_s + self.extra_s.get(&f.target.seq).copied().unwrap_or(0.0),
                    frame_sd_um: d.frame_sd_um,
                };
                if let Some((x, y)) = f.truth {
                    self.recorder.truth(rec.target.seq, x, y);
                }
                let fresh = self.recorder.sample(&rec)?;
                if fresh {
                    self.stat(run).measurements += 1;
                }
                self.extra_s.remove(&rec.target.seq);
                self.done.insert(rec.target.seq, rec);
                Ok(None)
            }
            None => {
                self.stat(run).rejected_frames += 1;
                *self.extra_s.entry(f.target.seq).or_default() += f.point_s;
                self.recorder.event(
                    "frame_rejected",
                    json!({"seq": f.target.seq, "target_um": f.target.target_um(), "reason": d.reason,
                           "phase": run.phase.as_str(), "axis": run.axis.as_str(), "frames": d.frames}),
                );
                Ok(Some(f.target))
            }
        }
    }

    /// One sweep: pipelined over the targets, then bounded retries of rejected frames.
    async fn batch(&mut self, b: &Batch) -> Result<Control, EngineError> {
        let todo: Vec<Target> = b
            .targets
            .iter()
            .filter(|t| !self.done.contains_key(&t.seq))
            .copied()
            .collect();
        if todo.is_empty() {
            return Ok(Control::Run);
        }
        // The target before `t` in this sweep, if any.
        let before = |t: &Target| {
            let i = b.targets.iter().position(|x| x.seq == t.seq)?;
            i.checked_sub(1).map(|i| b.targets[i].target_um())
        };
        self.approach(b.run, &todo[0], b.index == 0).await?;
        self.planned_from_um = before(&todo[0]);
        let mut retry: Vec<Target> = Vec::new();
        for t in &todo {
            if let Some(c) = requested(&self.control) {
                // `run` stops the axes, then lands what is in flight.
                return Ok(c);
            }
            if *self.control.borrow() == Control::Pause {
                // Land what is in flight before pausing.
                while let Some(f) = self.flight.pop_front() {
                    retry.extend(self.land(f, 0).await?);
                }
                let c = self.control_point().await;
                if c.halts() {
                    return Ok(c);
                }
                // Resumed: approach again from the run's side.
                self.approach(b.run, t, true).await?;
                self.planned_from_um = before(t);
            }
            let f = self.measure(t).await?;
            self.flight.push_back(f);
            if self.flight.len() >= self.depth {
                let f = self.flight.pop_front().expect("non-empty");
                retry.extend(self.land(f, 0).await?);
            }
        }
        while let Some(f) = self.flight.pop_front() {
            retry.extend(self.land(f, 0).await?);
        }
        if let Some(c) = requested(&self.control) {
            return Ok(c);
        }
        // Rejected frames: re-approach each target from the run's side, measure again.
        let max = &self.campaign.spec().acquisition.max_retries;
        for t in retry {
            let c = *self.control.borrow();
            if c.halts() {
                return Ok(c);
            }
            let mut attempt = 1;
            loop {
                if attempt > *max {
                    self.stat(b.run).failed_points += 1;
                    let physical_s = self.extra_s.remove(&t.seq).unwrap_or(0.0);
                    self.recorder.event(
                        "point_failed",
                        json!({"seq": t.seq, "target_um": t.target_um(), "attempts": attempt,
                               "phase": b.run.phase.as_str(), "axis": b.run.axis.as_str(),
                               "physical_s": physical_s}),
                    );
                    break;
                }
                self.approach(b.run, &t, false).await?;
                let f = self.measure(&t).await?;
                if self.land(f, attempt).await?.is_none() {
                    break;
                }
                attempt += 1;
            }
        }
        Ok(Control::Run)
    }
}
