//! A simulated PI C-863.11 Mercury controller (one axis, id "1") driving one axis of a
//! [`SimStage`]: the GCS 2.0 state machine ([`Controller`]), fault injection ([`Fault`]), and
//! servers over TCP and over a pseudo-terminal ([`SimController`]).
//!
//! `POS?` answers the encoder (the commanded motion); where the carriage really is comes from
//! [`SimStage::true_position_um`], which adds the stage model's errors, as on the real stage.
use std::collections::VecDeque;
use std::sync::Mutex;
use std::time::{Duration, Instant};

use csmetro_effects::AxisId;
use csmetro_gcs::error::*;
use csmetro_gcs::{encode_reply, Request, RequestBody};
use csmetro_gcs::{
    Address, AxisQuery, AxisSetter, Command, ControlByte, RefMode, Reply, BUSY, READY,
};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use crate::stage::{AxisState, MotionKind, SimStage};

// The FFI boundary with the pseudo-terminal: the only module of this crate allowed `unsafe`.
#[allow(unsafe_code)]
mod pty;
mod server;
pub(crate) mod soak;

pub use server::{remove_stale_links, Endpoint, SimController};

/// The C-863's one axis.
pub const AXIS: &str = "1";

/// Controller settings; the defaults model a C-863.11 with an M-111.1DG (15 mm, 1.5 mm/s).
///
/// As the `[controller]` section of a simulator config (`csmetro sim controller --config`):
///
/// ```toml
/// time_scale = 100
/// [controller]
/// max_velocity_mm_s = 1.5
/// velocity_mm_s = 1.0
/// [[controller.faults]]
/// kind = "delay_reply"   # drop_reply | delay_reply | garbage | error | vanish
/// ms = 300
/// after_commands = 20
/// [[controller.faults]]
/// kind = "error"
/// code = 1024
/// during_motion = true
/// ```
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ControllerConfig {
    /// `*IDN?` line; the model is its second field.
    pub idn: String,
    /// Stage name (`CST?`, parameter 0x3C).
    pub stage: String,
    /// Travel range [TMN, TMX], mm.
    pub travel_mm: [f64; 2],
    /// Upper limit of `VEL`, mm/s.
    pub max_velocity_mm_s: f64,
    /// Upper limit of `ACC`/`DEC`, mm/s².
    pub max_acceleration_mm_s2: f64,
    /// Power-up `VEL`, mm/s.
    pub velocity_mm_s: f64,
    /// Power-up `ACC` and `DEC`, mm/s².
    pub acceleration_mm_s2: f64,
    /// Velocity of reference moves, mm/s.
    pub reference_velocity_mm_s: f64,
    /// Position of the reference switch (FRF), mm.
    pub reference_switch_mm: f64,
    /// Where the carriage is at power-up, mm.
    pub start_mm: f64,
    /// On-target window, mm.
    pub settle_window_mm: f64,
    /// Time inside the window before on-target, s.
    pub settle_time_s: f64,
    /// Daisy-chain address (addressed frames for another address are ignored).
    pub address: u8,
    /// Faults to inject, each after a number of received commands.
    pub faults: Vec<FaultSpec>,
    /// Faults drawn at random per command (`[controller.random_faults]`), for soaks.
    pub random_faults: Option<RandomFaults>,
}

/// Faults that strike at random: before each reply, each kind strikes with its probability,
/// drawn from a generator seeded by `seed` (same seed, same commands: same faults).
///
/// ```toml
/// [controller.random_faults]
/// seed = 7
/// delay_rate = 0.01      # reply sent late, by a time drawn in delay_ms
/// delay_ms = [50, 800]
/// drop_rate = 0.005      # reply never sent
/// garbage_rate = 0.005   # reply replaced by garbage bytes
/// error_rate = 0.0       # controller latches error `error_code`
/// error_code = 1024
/// vanish_rate = 0.0      # the port vanishes for vanish_ms
/// vanish_ms = 200
/// ```
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RandomFaults {
    /// Seed of the fault generator.
    pub seed: u64,
    /// Probability per reply of a delay.
    pub delay_rate: f64,
    /// Range of the delay, real milliseconds.
    pub delay_ms: [u64; 2],
    /// Probability per reply of a drop.
    pub drop_rate: f64,
    /// Probability per reply of garbage in its place.
    pub garbage_rate: f64,
    /// Probability per reply of a latched error.
    pub error_rate: f64,
    /// GCS error code a random error latches.
    pub error_code: i32,
    /// Probability per reply of the port vanishing.
    pub vanish_rate: f64,
    /// How long the port stays away, real milliseconds.
    pub vanish_ms: u64,
}

/// Longest delay or vanish a random fault may ask for (a typo must not hang a soak for hours).
pub const MAX_RANDOM_FAULT_MS: u64 = 60_000;

impl RandomFaults {
    /// Checks rates (in [0, 1]) and durations (ordered, at most [`MAX_RANDOM_FAULT_MS`]).
    pub fn validate(&self) -> Result<(), String> {
        for (name, r) in [
            ("delay_rate", self.delay_rate),
            ("drop_rate", self.drop_rate),
            ("garbage_rate", self.garbage_rate),
            ("error_rate", self.error_rate),
            ("vanish_rate", self.vanish_rate),
        ] {
            if !(0.0..=1.0).contains(&r) {
                return Err(format!("{name} must be in [0, 1], not {r}"));
            }
        }
        let [lo, hi] = self.delay_ms;
        if lo > hi || hi > MAX_RANDOM_FAULT_MS {
            return Err(format!(
                "delay_ms must be [lo, hi] with lo <= hi <= {MAX_RANDOM_FAULT_MS}, not [{lo}, {hi}]"
            ));
        }
        if self.vanish_ms > MAX_RANDOM_FAULT_MS {
            return Err(format!(
                "vanish_ms must be at most {MAX_RANDOM_FAULT_MS}, not {}",
                self.vanish_ms
            ));
        }
        Ok(())
    }
}

/// A probability usable by the generator whatever the config said (NaN strikes never).
fn rate(p: f64) -> f64 {
    if p.is_nan() {
        0.0
    } else {
        p.clamp(0.0, 1.0)
    }
}

impl Default for RandomFaults {
    fn default() -> Self {
        Self {
            seed: 0,
            delay_rate: 0.0,
            delay_ms: [50, 800],
            drop_rate: 0.0,
            garbage_rate: 0.0,
            error_rate: 0.0,
            error_code: 1024,
            vanish_rate: 0.0,
            vanish_ms: 200,
        }
    }
}

impl Default for ControllerConfig {
    fn default() -> Self {
        Self {
            idn: "(c)2015 Physik Instrumente (PI) GmbH & Co. KG, C-863.11, 0115000001, 01.003"
                .into(),
            stage: "M-111.1DG".into(),
            travel_mm: [0.0, 15.0],
            max_velocity_mm_s: 1.5,
            // Acceleration: see `hardware.sim.acceleration_mm_s2` (calibrated on the paper's
            // Table III timings; the datasheet does not give it).
            max_acceleration_mm_s2: 200.0,
            velocity_mm_s: 1.5,
            acceleration_mm_s2: 50.0,
            reference_velocity_mm_s: 1.0,
            reference_switch_mm: 7.5,
            start_mm: 3.0,
            settle_window_mm: 0.0001,
            settle_time_s: 0.01,
            address: 1,
            faults: Vec::new(),
            random_faults: None,
        }
    }
}

/// A fault of the line or of the controller, for tests (`[[controller.faults]]` in TOML).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum Fault {
    /// The next `count` replies are never sent.
    DropReply {
        /// How many replies.
        #[serde(default = "one")]
        count: u32,
    },
    /// The next `count` replies are sent `ms` real milliseconds late.
    DelayReply {
        /// Delay, real milliseconds.
        ms: u64,
        /// How many replies.
        #[serde(default = "one")]
        count: u32,
    },
    /// The next `count` replies are replaced by garbage bytes.
    Garbage {
        /// How many replies.
        #[serde(default = "one")]
        count: u32,
    },
    /// The controller latches `code` (1024 also switches the servo off). With `during_motion`,
    /// the error strikes halfway through the next move instead, stopping it.
    Error {
        /// GCS error code to latch.
        code: i32,
        /// Strike halfway through the next move instead of now.
        #[serde(default)]
        during_motion: bool,
    },
    /// The port disappears (TCP listener and connections closed, pty removed) for `ms` real
    /// milliseconds, then comes back at the same address or path. The reply to the command
    /// that triggers it is lost.
    Vanish {
        /// How long the port stays away, real milliseconds.
        ms: u64,
    },
}

fn one() -> u32 {
    1
}

/// A fault and when it strikes.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FaultSpec {
    /// The fault.
    #[serde(flatten)]
    pub fault: Fault,
    /// Strikes once this many commands have been received (0 = from the start).
    #[serde(default)]
    pub after_commands: u64,
}

#[derive(Debug, Default)]
struct FaultState {
    pending: Vec<FaultSpec>,
    drop: u32,
    delay: VecDeque<u64>,
    garbage: u32,
    motion_error: Option<i32>,
    vanish: Option<u64>,
    random: Option<(RandomFaults, ChaCha8Rng)>,
    counts: FaultCounts,
}

/// Faults that struck so far (scripted and random), by kind. A delayed reply that was also
/// dropped counts as a drop only.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize)]
pub struct FaultCounts {
    /// Replies delayed.
    pub delay: u64,
    /// Replies dropped.
    pub drop: u64,
    /// Replies replaced by garbage.
    pub garbage: u64,
    /// Errors latched.
    pub error: u64,
    /// Times the port vanished.
    pub vanish: u64,
}

/// One request as the controller handled it, for tests that check which reply a client took
/// for which request (see [`Controller::keep_exchanges`]).
#[derive(Debug, Clone, PartialEq)]
pub struct Exchange {
    /// 1-based number of the request among all requests to this controller.
    pub seq: u64,
    /// The request as text (control bytes as `#7`).
    pub request: String,
    /// The reply the controller produced, encoded (empty: none), before faults.
    pub reply: Vec<u8>,
    /// The bytes it sent back (differs from `reply` under a fault).
    pub sent: Vec<u8>,
    /// When the bytes are written (handling time plus any delay).
    pub sent_at: Instant,
}

/// The bytes sent instead of a reply by [`Fault::Garbage`]: neither a value nor a GCS reply shape.
pub const GARBAGE: &[u8] = b"\xfe#~garbled\x01@\n";

/// Random faults drawn for one reply.
#[derive(Debug, Default)]
struct Strike {
    delay_ms: Option<u64>,
    drop: bool,
    garbage: bool,
    vanish_ms: Option<u64>,
}

/// What a request produced.
#[derive(Debug, Default, PartialEq)]
pub struct Outcome {
    /// Bytes to write back (empty: no reply).
    pub bytes: Vec<u8>,
    /// Real delay before writing them.
    pub delay: Duration,
    /// After this request the port vanishes for this long.
    pub vanish: Option<Duration>,
}

struct Inner {
    cfg: ControllerConfig,
    faults: FaultState,
    commands: u64,
    log: Vec<String>,
    /// `Some(cap)`: exchanges are kept (the oldest dropped beyond `cap`).
    exchanges: Option<(usize, VecDeque<Exchange>)>,
    /// [`TRACE_ENV`]: where each command is written as it is handled.
    trace: Option<std::fs::File>,
}

/// Environment variable naming a file to which every simulated controller of the process
/// appends one line per command it handles, `UNIX_S AXIS MOVING ON_TARGET COMMAND` (the axis
/// state after the command): the simulator's own record of when a stop arrived and whether the
/// stage was still moving, for the stop-latency tests (`tests/stop_latency.rs`).
pub const TRACE_ENV: &str = "CSMETRO_SIM_TRACE";

/// The C-863 state machine for one axis of a [`SimStage`].
pub struct Controller {
    stage: SimStage,
    axis: AxisId,
    inner: Mutex<Inner>,
}

const LOG_CAP: usize = 100_000;

impl Controller {
    /// Sets the stage axis to the configured power-up state.
    pub fn new(stage: SimStage, axis: AxisId, cfg: ControllerConfig) -> Self {
        stage.with_axis(axis, |a, _| {
            *a = AxisState::new(cfg.start_mm, cfg.velocity_mm_s, cfg.acceleration_mm_s2);
        });
        let faults = FaultState {
            pending: cfg.faults.clone(),
            random: cfg
                .random_faults
                .clone()
                .map(|r| (r.clone(), ChaCha8Rng::seed_from_u64(r.seed))),
            ..Default::default()
        };
        Self {
            stage,
            axis,
            inner: Mutex::new(Inner {
                cfg,
                faults,
                commands: 0,
                log: Vec::new(),
                exchanges: None,
                trace: std::env::var_os(TRACE_ENV).and_then(|p| {
                    std::fs::OpenOptions::new()
                        .create(true)
                        .append(true)
                        .open(p)
                        .ok()
                }),
            }),
        }
    }

    /// The simulated stage this controller drives.
    pub fn stage(&self) -> &SimStage {
        &self.stage
    }

    /// The stage axis this controller drives.
    pub fn axis(&self) -> AxisId {
        self.axis
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, Inner> {
        self.inner.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Injects a fault now.
    pub fn inject(&self, fault: Fault) {
        let mut g = self.lock();
        let after_commands = g.commands;
        g.faults.pending.push(FaultSpec {
            fault,
            after_commands,
        });
    }

    /// Number of commands received so far (every line and control byte).
    pub fn command_count(&self) -> u64 {
        self.lock().commands
    }

    /// The commands received so far, as text (control bytes as `#5` etc.).
    pub fn command_log(&self) -> Vec<String> {
        self.lock().log.clone()
    }

    /// Replaces the random faults (the generator seeded afresh); `None` stops them.
    pub fn set_random_faults(&self, rf: Option<RandomFaults>) {
        let mut g = self.lock();
        g.faults.random = rf
            .clone()
            .map(|r| (r.clone(), ChaCha8Rng::seed_from_u64(r.seed)));
        g.cfg.random_faults = rf;
    }

    /// Faults that struck so far, by kind.
    pub fn fault_counts(&self) -> FaultCounts {
        self.lock().faults.counts
    }

    /// Starts keeping every [`Exchange`] (at most `cap`, the oldest dropped first), for
    /// [`drain_exchanges`](Self::drain_exchanges). Off by default: a long-running simulator
    /// keeps nothing.
    pub fn keep_exchanges(&self, cap: usize) {
        self.lock().exchanges = Some((cap.max(1), VecDeque::new()));
    }

    /// The exchanges kept since the last call, oldest first.
    pub fn drain_exchanges(&self) -> Vec<Exchange> {
        match &mut self.lock().exchanges {
            Some((_, q)) => q.drain(..).collect(),
            None => Vec::new(),
        }
    }

    /// Handles one request: state change, reply bytes and injected faults.
    pub fn handle(&self, req: &Request) -> Outcome {
        let mut g = self.lock();
        if let Some(a) = req.address {
            if a.target != g.cfg.address {
                return Outcome::default(); // for another controller on the chain
            }
        }
        g.commands += 1;
        let text = match &req.body {
            RequestBody::Control(c) => format!("#{}", c.byte()),
            RequestBody::Line(l) => l.clone(),
            RequestBody::Invalid { text, .. } => text.clone(),
        };
        if g.log.len() < LOG_CAP {
            g.log.push(text.clone());
        }
        self.activate_faults(&mut g);
        let reply = match &req.body {
            RequestBody::Invalid { code, .. } => {
                self.latch(*code);
                None
            }
            RequestBody::Line(l) => match Command::parse(l) {
                Ok(cmd) => self.exec(&mut g, &cmd),
                Err(code) => {
                    self.latch(code);
                    None
                }
            },
            RequestBody::Control(c) => self.exec(&mut g, &Command::Control(*c)),
        };
        if g.trace.is_some() {
            self.trace(&mut g, &text);
        }
        let mut out = Outcome::default();
        let mut produced = Vec::new();
        if let Some(mut reply) = reply {
            reply.address = req.address.map(|a| Address {
                target: a.sender,
                sender: a.target,
            });
            let mut buf = bytes::BytesMut::new();
            encode_reply(&reply, &mut buf);
            produced = buf.to_vec();
            let strike = self.draw_random(&mut g);
            let f = &mut g.faults;
            if f.drop > 0 || strike.drop {
                f.drop = f.drop.saturating_sub(u32::from(!strike.drop));
                f.counts.drop += 1;
            } else if f.garbage > 0 || strike.garbage {
                f.garbage = f.garbage.saturating_sub(u32::from(!strike.garbage));
                f.counts.garbage += 1;
                out.bytes = GARBAGE.to_vec();
            } else {
                out.bytes = produced.clone();
            }
            if let Some(ms) = f.delay.pop_front().or(strike.delay_ms) {
                out.delay = Duration::from_millis(ms);
                if !out.bytes.is_empty() {
                    f.counts.delay += 1;
                }
            }
            if let Some(ms) = strike.vanish_ms {
                f.vanish.get_or_insert(ms);
            }
        }
        out.vanish = g.faults.vanish.take().map(Duration::from_millis);
        if out.vanish.is_some() {
            // The port goes away while this command is in flight: its reply is lost.
            out.bytes.clear();
            g.faults.counts.vanish += 1;
        }
        let (delay, seq) = (out.delay, g.commands);
        if let Some((cap, q)) = &mut g.exchanges {
            if q.len() >= *cap {
                q.pop_front();
            }
            q.push_back(Exchange {
                seq,
                request: text,
                reply: produced,
                sent: out.bytes.clone(),
                sent_at: Instant::now() + delay,
            });
        }
        out
    }

    /// One line of the [`TRACE_ENV`] file, written whole by one `write` (both controllers
    /// append to the same file).
    fn trace(&self, g: &mut Inner, text: &str) {
        use std::io::Write;
        let cfg = &g.cfg;
        let (moving, ont) = self
            .stage
            .with_axis(self.axis, |a, now| (a.is_moving(), on_target(a, cfg, now)));
        let unix_s = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0.0, |d| d.as_secs_f64());
        let line = format!(
            "{unix_s:.6} {} {} {} {}\n",
            self.axis.as_str(),
            moving as u8,
            ont as u8,
            text.trim()
        );
        if let Some(f) = &mut g.trace {
            // Best effort: a trace that cannot be written must not fail the controller.
            let _ = f.write_all(line.as_bytes());
        }
    }

    /// Draws the random faults for one reply: every kind is drawn every time, so the same
    /// seed and the same commands give the same faults whatever the rates. An error strikes
    /// at once (latched as by [`Fault::Error`]).
    fn draw_random(&self, g: &mut Inner) -> Strike {
        let Some((rf, rng)) = &mut g.faults.random else {
            return Strike::default();
        };
        let u: [f64; 5] = std::array::from_fn(|_| rng.random::<f64>());
        let [a, b] = rf.delay_ms;
        let delay_ms = rng.random_range(a.min(b)..=a.max(b));
        let strike = Strike {
            delay_ms: (u[0] < rate(rf.delay_rate)).then_some(delay_ms),
            drop: u[1] < rate(rf.drop_rate),
            garbage: u[2] < rate(rf.garbage_rate),
            vanish_ms: (u[4] < rate(rf.vanish_rate)).then_some(rf.vanish_ms),
        };
        if u[3] < rate(rf.error_rate) {
            let code = rf.error_code;
            g.faults.counts.error += 1;
            self.latch_fault(code);
        }
        strike
    }

    /// The controller latches `code`; 1024 (motion error) also stops and switches the servo off.
    fn latch_fault(&self, code: i32) {
        self.stage.with_axis(self.axis, |a, now| {
            if code == E1024_MOTION_ERROR {
                a.stop(now);
                a.servo = false;
            }
            a.error = code;
        });
    }

    fn activate_faults(&self, g: &mut Inner) {
        let n = g.commands;
        let (due, later): (Vec<_>, Vec<_>) = std::mem::take(&mut g.faults.pending)
            .into_iter()
            .partition(|s| s.after_commands < n);
        g.faults.pending = later;
        for s in due {
            let f = &mut g.faults;
            match s.fault {
                Fault::DropReply { count } => f.drop += count,
                Fault::DelayReply { ms, count } => f.delay.extend((0..count).map(|_| ms)),
                Fault::Garbage { count } => f.garbage += count,
                Fault::Error {
                    code,
                    during_motion: true,
                } => {
                    f.counts.error += 1;
                    f.motion_error = Some(code);
                }
                Fault::Error {
                    code,
                    during_motion: false,
                } => {
                    f.counts.error += 1;
                    self.latch_fault(code);
                }
                Fault::Vanish { ms } => f.vanish = Some(ms),
            }
        }
    }

    fn latch(&self, code: i32) {
        self.stage.with_axis(self.axis, |a, _| a.error = code);
    }

    fn check_axes(axes: &[String]) -> Result<(), i32> {
        if axes.iter().all(|a| a == AXIS) {
            Ok(())
        } else {
            Err(E15_INVALID_AXIS)
        }
    }

    fn exec(&self, g: &mut Inner, cmd: &Command) -> Option<Reply> {
        match self.exec_inner(g, cmd) {
            Ok(r) => r,
            Err(code) => {
                self.latch(code);
                None
            }
        }
    }

    fn exec_inner(&self, g: &mut Inner, cmd: &Command) -> Result<Option<Reply>, i32> {
        let cfg = &mut g.cfg;
        let axis = self.axis;
        let st = &self.stage;
        let one = |s: String| Ok(Some(Reply::line(s)));
        match cmd {
            Command::Control(ControlByte::Status) => {
                let w = st.with_axis(axis, |a, now| {
                    let p = a.position(now);
                    let mut w = 0u32;
                    if on_target(a, cfg, now) {
                        w |= 1 << 15;
                    }
                    if a.is_referencing() {
                        w |= 1 << 14;
                    }
                    if a.is_moving() {
                        w |= 1 << 13;
                    }
                    if a.servo {
                        w |= 1 << 12;
                    }
                    if a.error != 0 {
                        w |= 1 << 8;
                    }
                    if p >= cfg.travel_mm[1] {
                        w |= 1 << 2;
                    }
                    if (p - cfg.reference_switch_mm).abs() < 1e-6 {
                        w |= 1 << 1;
                    }
                    if p <= cfg.travel_mm[0] {
                        w |= 1;
                    }
                    w
                });
                one(format!("0x{w:X}"))
            }
            Command::Control(ControlByte::MotionStatus) => one(format!(
                "{:X}",
                st.with_axis(axis, |a, _| a.is_moving() as u8)
            )),
            Command::Control(ControlByte::Ready) => {
                let busy = st.with_axis(axis, |a, _| a.is_referencing());
                one(if busy { BUSY } else { READY }.to_string())
            }
            Command::Control(ControlByte::MacroRunning) => one("0".into()),
            Command::Control(ControlByte::StopAll) | Command::Stop => {
                st.with_axis(axis, |a, now| {
                    a.stop(now);
                    a.error = E10_STOPPED;
                });
                Ok(None)
            }
            Command::Halt { axes } => {
                Self::check_axes(axes)?;
                // HLT decelerates; STP and #24 stop at once.
                st.with_axis(axis, |a, now| {
                    a.halt(now);
                    a.error = E10_STOPPED;
                });
                Ok(None)
            }
            Command::Idn => one(cfg.idn.clone()),
            Command::Csv => one("2.0".into()),
            Command::Sai { .. } => one(AXIS.into()),
            Command::Err => one(st
                .with_axis(axis, |a, _| std::mem::take(&mut a.error))
                .to_string()),
            Command::Hlp => Ok(Some(Reply::lines(
                HELP.iter().map(|s| s.to_string()).collect(),
            ))),
            Command::Query { query, axes } => {
                Self::check_axes(axes)?;
                let v = st.with_axis(axis, |a, now| match query {
                    AxisQuery::Pos => format!("{:.9}", a.position(now)),
                    AxisQuery::Mov => format!("{:.9}", a.target_mm),
                    AxisQuery::Ont => (on_target(a, cfg, now) as u8).to_string(),
                    AxisQuery::Svo => (a.servo as u8).to_string(),
                    AxisQuery::Frf => (a.referenced as u8).to_string(),
                    AxisQuery::Vel => format!("{:.6}", a.vel),
                    AxisQuery::Acc => format!("{:.6}", a.acc),
                    AxisQuery::Dec => format!("{:.6}", a.dec),
                    AxisQuery::Tmn => format!("{:.6}", cfg.travel_mm[0]),
                    AxisQuery::Tmx => format!("{:.6}", cfg.travel_mm[1]),
                    AxisQuery::Lim | AxisQuery::Trs => "1".into(),
                    AxisQuery::Ron => (a.ron as u8).to_string(),
                    AxisQuery::Cst => cfg.stage.clone(),
                });
                one(format!("{AXIS}={v}"))
            }
            Command::Set { setter, args } => {
                Self::check_axes(&args.iter().map(|(a, _)| a.clone()).collect::<Vec<_>>())?;
                let motion_error = &mut g.faults.motion_error;
                st.with_axis(axis, |a, now| {
                    for (_, v) in args {
                        set_one(a, cfg, *setter, *v, now, motion_error)?;
                    }
                    Ok(None)
                })
            }
            Command::Reference { mode, axes } => {
                Self::check_axes(axes)?;
                st.with_axis(axis, |a, now| {
                    if !a.servo || !a.ron {
                        return Err(E5_INIT_NOT_DONE);
                    }
                    let to = match mode {
                        RefMode::Frf => cfg.reference_switch_mm,
                        RefMode::Fnl => cfg.travel_mm[0],
                        RefMode::Fpl => cfg.travel_mm[1],
                    };
                    a.referenced = false;
                    a.start(now, to, cfg.reference_velocity_mm_s, MotionKind::Reference);
                    Ok(None)
                })
            }
            Command::SetParam { items } => {
                Self::check_axes(&items.iter().map(|(a, _, _)| a.clone()).collect::<Vec<_>>())?;
                // All or nothing: validate on a copy first.
                let mut c = cfg.clone();
                for (_, id, v) in items {
                    set_param(&mut c, *id, v)?;
                }
                *cfg = c;
                Ok(None)
            }
            Command::QueryParam { items } => {
                let items: Vec<(String, u32)> = if items.is_empty() {
                    PARAMS.iter().map(|p| (AXIS.to_string(), p.0)).collect()
                } else {
                    items.clone()
                };
                Self::check_axes(&items.iter().map(|(a, _)| a.clone()).collect::<Vec<_>>())?;
                let mut lines = Vec::new();
                for (ax, id) in items {
                    let v = get_param(cfg, id).ok_or(E54_UNKNOWN_PARAM)?;
                    lines.push(format!("{ax} 0x{id:X}={v}"));
                }
                Ok(Some(Reply::lines(lines)))
            }
        }
    }
}

fn on_target(a: &AxisState, cfg: &ControllerConfig, now: f64) -> bool {
    a.servo
        && !a.is_moving()
        && (a.position(now) - a.target_mm).abs() <= cfg.settle_window_mm
        && now - a.settled_from_s >= cfg.settle_time_s
}

fn set_one(
    a: &mut AxisState,
    cfg: &ControllerConfig,
    setter: AxisSetter,
    v: f64,
    now: f64,
    motion_error: &mut Option<i32>,
) -> Result<(), i32> {
    match setter {
        AxisSetter::Svo => {
            if v == 0.0 {
                a.stop(now);
                a.servo = false;
            } else {
                a.servo = true;
                a.target_mm = a.position(now);
                a.settled_from_s = now;
            }
        }
        AxisSetter::Mov | AxisSetter::Mvr => {
            let target = if setter == AxisSetter::Mvr {
                a.target_mm + v
            } else {
                v
            };
            if !a.servo || a.is_referencing() || (a.ron && !a.referenced) {
                return Err(E5_INIT_NOT_DONE);
            }
            if target < cfg.travel_mm[0] || target > cfg.travel_mm[1] {
                return Err(E7_POS_OUT_OF_LIMITS);
            }
            let vel = a.vel;
            a.start(now, target, vel, MotionKind::Move);
            if let (Some(code), Some(m)) = (motion_error.take(), a.motion.as_mut()) {
                // The following error strikes halfway through the move.
                m.fail_at = Some((m.profile.t0 + m.profile.duration() / 2.0, code));
            }
        }
        AxisSetter::Vel => {
            if v <= 0.0 {
                return Err(E17_PARAM_OUT_OF_RANGE);
            }
            if v > cfg.max_velocity_mm_s {
                return Err(E8_VEL_OUT_OF_LIMITS);
            }
            a.vel = v;
        }
        AxisSetter::Acc | AxisSetter::Dec => {
            if v <= 0.0 || v > cfg.max_acceleration_mm_s2 {
                return Err(E17_PARAM_OUT_OF_RANGE);
            }
            if setter == AxisSetter::Acc {
                a.acc = v;
            } else {
                a.dec = v;
            }
        }
        AxisSetter::Ron => a.ron = v != 0.0,
        AxisSetter::Pos => {
            if a.ron || a.is_moving() {
                return Err(E5_INIT_NOT_DONE);
            }
            a.pos_mm = v;
            a.target_mm = v;
        }
    }
    Ok(())
}

/// Parameters served by SPA/SPA? (id, name).
const PARAMS: &[(u32, &str)] = &[
    (0x0A, "maximum velocity (mm/s)"),
    (0x15, "maximum travel in positive direction (mm)"),
    (0x16, "value at reference position (mm)"),
    (0x30, "maximum travel in negative direction (mm)"),
    (0x36, "settling window (mm)"),
    (0x3C, "stage name"),
    (0x3F, "settling time (s)"),
    (0x4A, "maximum acceleration (mm/s²)"),
    (0x50, "velocity for reference moves (mm/s)"),
];

fn get_param(c: &ControllerConfig, id: u32) -> Option<String> {
    Some(match id {
        0x0A => c.max_velocity_mm_s.to_string(),
        0x15 => c.travel_mm[1].to_string(),
        0x16 => c.reference_switch_mm.to_string(),
        // GCS stores the negative travel as a positive distance.
        0x30 => (-c.travel_mm[0]).to_string(),
        0x36 => c.settle_window_mm.to_string(),
        0x3C => c.stage.clone(),
        0x3F => c.settle_time_s.to_string(),
        0x4A => c.max_acceleration_mm_s2.to_string(),
        0x50 => c.reference_velocity_mm_s.to_string(),
        _ => return None,
    })
}

fn set_param(c: &mut ControllerConfig, id: u32, v: &str) -> Result<(), i32> {
    if id == 0x3C {
        c.stage = v.to_string();
        return Ok(());
    }
    if !PARAMS.iter().any(|p| p.0 == id) {
        return Err(E54_UNKNOWN_PARAM);
    }
    let x = csmetro_gcs::parse_float(v)?;
    let positive = |x: f64| {
        if x > 0.0 {
            Ok(x)
        } else {
            Err(E17_PARAM_OUT_OF_RANGE)
        }
    };
    match id {
        0x0A => c.max_velocity_mm_s = positive(x)?,
        0x15 => c.travel_mm[1] = x,
        0x16 => c.reference_switch_mm = x,
        0x30 => c.travel_mm[0] = -x,
        0x36 => c.settle_window_mm = positive(x)?,
        0x3F => {
            c.settle_time_s = if x >= 0.0 {
                x
            } else {
                return Err(E17_PARAM_OUT_OF_RANGE);
            }
        }
        0x4A => c.max_acceleration_mm_s2 = positive(x)?,
        0x50 => c.reference_velocity_mm_s = positive(x)?,
        _ => unreachable!("checked above"),
    }
    if c.travel_mm[0] >= c.travel_mm[1] {
        return Err(E17_PARAM_OUT_OF_RANGE);
    }
    Ok(())
}

const HELP: &[&str] = &[
    "The following commands are valid:",
    "#4 Request Status Register",
    "#5 Request Motion Status",
    "#7 Request Controller Ready Status",
    "#8 Query If Macro Is Running",
    "#24 Stop All Axes",
    "*IDN? Get Device Identification",
    "ACC <AxisID> <Acceleration> Set Closed-Loop Acceleration",
    "ACC? [{<AxisID>}] Get Closed-Loop Acceleration",
    "CST? [{<AxisID>}] Get Assignment Of Stages To Axes",
    "CSV? Get Current Syntax Version",
    "DEC <AxisID> <Deceleration> Set Closed-Loop Deceleration",
    "DEC? [{<AxisID>}] Get Closed-Loop Deceleration",
    "ERR? Get Error Number",
    "FNL [{<AxisID>}] Fast Reference Move To Negative Limit",
    "FPL [{<AxisID>}] Fast Reference Move To Positive Limit",
    "FRF [{<AxisID>}] Fast Reference Move To Reference Switch",
    "FRF? [{<AxisID>}] Get Referencing Result",
    "HLP? Get List Of Available Commands",
    "HLT [{<AxisID>}] Halt Motion Smoothly",
    "LIM? [{<AxisID>}] Indicate Limit Switches",
    "MOV {<AxisID> <Position>} Set Target Position",
    "MOV? [{<AxisID>}] Get Target Position",
    "MVR {<AxisID> <Distance>} Set Target Relative To Current Target",
    "ONT? [{<AxisID>}] Get On-Target State",
    "POS {<AxisID> <Position>} Set Real Position",
    "POS? [{<AxisID>}] Get Real Position",
    "RON {<AxisID> <ReferenceOn>} Set Reference Mode",
    "RON? [{<AxisID>}] Get Reference Mode",
    "SAI? [ALL] Get List Of Current Axis Identifiers",
    "SPA {<AxisID> <ParamID> <Value>} Set Volatile Memory Parameters",
    "SPA? [{<AxisID> <ParamID>}] Get Volatile Memory Parameters",
    "STP Stop All Axes",
    "SVO {<AxisID> <ServoState>} Set Servo Mode",
    "SVO? [{<AxisID>}] Get Servo Mode",
    "TMN? [{<AxisID>}] Get Minimum Commandable Position",
    "TMX? [{<AxisID>}] Get Maximum Commandable Position",
    "TRS? [{<AxisID>}] Indicate Reference Switch",
    "VEL {<AxisID> <Velocity>} Set Closed-Loop Velocity",
    "VEL? [{<AxisID>}] Get Closed-Loop Velocity",
    "end of help",
];

#[cfg(test)]
mod tests;
