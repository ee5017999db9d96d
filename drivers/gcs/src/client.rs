//! Async driver for a PI C-863 Mercury (one axis, id "1") over a serial line or TCP.
//!
//! Every wait is bounded: each reply has a timeout, a failed exchange is retried a bounded
//! number of times after re-synchronising the byte stream, and a vanished port is reopened a
//! bounded number of times. Every setter is followed by `ERR?`, so a refused command becomes a
//! typed error at once. Positions cross the [`Axis`] boundary in µm and the wire in mm.
//!
//! Replies are bound to their requests (the crate README states the rule): a reply is taken
//! only while the stream is *in sync*, only if it has the shape of the answer to the request
//! just sent, and only if nothing unsolicited arrived before the request. Any timeout, garbled
//! reply or I/O error puts the stream out of sync; before the next request the driver sends a
//! probe `SPA?` whose list of parameter ids is a fresh nonce and discards everything up to the
//! reply that echoes that list.
use std::time::{Duration, Instant};

use csmetro_hal::{Axis, AxisError, AxisInfo};
use futures::{FutureExt, SinkExt, StreamExt};
use serde::{Deserialize, Serialize};
use tokio::io::{AsyncRead, AsyncWrite};
use tokio::net::TcpStream;
use tokio_util::codec::Framed;
use tracing::{debug, warn};

use crate::codec::ClientCodec;
use crate::error::{error_message, E10_STOPPED, E5_INIT_NOT_DONE};
use crate::frame::{
    parse_param_id, AxisQuery, AxisSetter, Command, ControlByte, RefMode, Reply, BUSY, READY,
};

/// How to reach the controller.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "lowercase")]
pub enum Transport {
    /// A serial device (or a pty), 8N1.
    Serial {
        /// Device path, e.g. `/dev/ttyUSB0` or a pty.
        port: String,
        #[serde(default = "default_baud")]
        /// Baud rate, bit/s (default 115200).
        baud: u32,
        /// Hardware flow control (RTS/CTS).
        #[serde(default)]
        rts_cts: bool,
    },
    /// A terminal server or the simulator, `host:port`.
    Tcp {
        /// `host:port` to connect to.
        address: String,
    },
}

fn default_baud() -> u32 {
    115_200
}

/// Driver configuration (a TOML/JSON section; times in ms, positions in µm, GCS speeds in mm).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct C863Config {
    /// How to reach the controller.
    pub transport: Transport,
    /// GCS axis identifier (a C-863 has one axis, "1").
    pub axis: String,
    /// Daisy-chain address of the controller; `None` for a directly connected controller.
    pub address: Option<u8>,
    /// Soft limits (lo, hi) in µm; a target outside is refused before anything is sent.
    pub soft_limits_um: (f64, f64),
    /// Reference move: FRF (reference switch), FNL or FPL (limit switches).
    pub reference: RefMode,
    /// `VEL` to set when referencing, mm/s (`None` keeps the controller's).
    pub velocity_mm_s: Option<f64>,
    /// `ACC` to set, mm/s².
    pub acceleration_mm_s2: Option<f64>,
    /// `DEC` to set, mm/s².
    pub deceleration_mm_s2: Option<f64>,
    /// Longest wait for one reply.
    pub reply_timeout_ms: u64,
    /// Extra attempts of one exchange after a timeout or a garbled reply.
    pub retries: u32,
    /// Attempts to reopen a port that failed, per exchange.
    pub reconnect_attempts: u32,
    /// Pause between reopen attempts.
    pub reconnect_delay_ms: u64,
    /// Polling period while waiting for on-target or for the reference move.
    pub poll_interval_ms: u64,
}

impl Default for C863Config {
    fn default() -> Self {
        Self {
            transport: Transport::Serial {
                port: "/dev/ttyUSB0".into(),
                baud: 115_200,
                rts_cts: false,
            },
            axis: "1".into(),
            address: None,
            soft_limits_um: (0.0, 15_000.0),
            reference: RefMode::Frf,
            velocity_mm_s: None,
            acceleration_mm_s2: None,
            deceleration_mm_s2: None,
            reply_timeout_ms: 500,
            retries: 2,
            reconnect_attempts: 10,
            reconnect_delay_ms: 200,
            poll_interval_ms: 20,
        }
    }
}

impl C863Config {
    /// Defaults, reached over TCP at `host:port`.
    pub fn tcp(address: impl Into<String>) -> Self {
        Self {
            transport: Transport::Tcp {
                address: address.into(),
            },
            ..Self::default()
        }
    }
    /// Defaults, reached over the serial device `port` at 115200 baud, no flow control.
    pub fn serial(port: impl Into<String>) -> Self {
        Self {
            transport: Transport::Serial {
                port: port.into(),
                baud: 115_200,
                rts_cts: false,
            },
            ..Self::default()
        }
    }
    fn reply_timeout(&self) -> Duration {
        Duration::from_millis(self.reply_timeout_ms)
    }
}

trait Io: AsyncRead + AsyncWrite + Send + Sync + Unpin {}
impl<T: AsyncRead + AsyncWrite + Send + Sync + Unpin> Io for T {}

type Conn = Framed<Box<dyn Io>, ClientCodec>;

/// What went wrong in one exchange, before retries decide.
enum Fail {
    /// The port is gone: reopen.
    Io(String),
    /// No reply in time: resync, retry.
    Timeout,
    /// A reply that breaks the protocol: resync, retry.
    Garbled(String),
}

/// Counters of the link's recoveries since [`C863::connect`] (for soaks and diagnostics).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize)]
pub struct LinkStats {
    /// Frames written: commands, control bytes and resync probes, resent ones included.
    pub frames_sent: u64,
    /// Exchanges attempted again after a failed one.
    pub retries: u64,
    /// Resynchronisations started.
    pub resyncs: u64,
    /// Resynchronisations that did not reach sync (a timeout, or too much to discard).
    pub resyncs_failed: u64,
    /// Replies and garbled frames discarded because they could answer an earlier request.
    pub discarded: u64,
    /// Port reopened after an I/O error.
    pub reopens: u64,
}

/// Parameters the resync probe reads: every GCS 2.0 stage controller has them and reading
/// them changes nothing.
const PROBE_PARAMS: [u32; 4] = [0x0A, 0x15, 0x16, 0x30];
/// Items per probe: 4^8 = 65 536 different probes before a list repeats.
const PROBE_LEN: usize = 8;
/// Longest resync, in reply timeouts: a stream that keeps talking cannot hold the driver.
const RESYNC_TIMEOUTS: u32 = 4;
/// Most frames one resync discards before it gives up.
const RESYNC_MAX_DISCARD: usize = 64;

/// The parameter ids of probe `nonce`, in order (two bits of the nonce per item).
fn probe_ids(nonce: u16) -> [u32; PROBE_LEN] {
    std::array::from_fn(|i| PROBE_PARAMS[usize::from(nonce >> (2 * i)) & 3])
}

/// Whether `r` is the reply to the probe that asked for `ids` on `axis`: one
/// `axis id=value` line per id, in order (ids decimal or hex).
fn answers_probe(r: &Reply, axis: &str, ids: &[u32]) -> bool {
    r.lines.len() == ids.len()
        && r.lines.iter().zip(ids).all(|(l, &id)| {
            let Some((head, _)) = l.split_once('=') else {
                return false;
            };
            let mut t = head.split_ascii_whitespace();
            matches!(
                (t.next(), t.next().map(parse_param_id), t.next()),
                (Some(a), Some(Ok(got)), None) if a == axis && got == id
            )
        })
}

/// A starting nonce that differs between sessions, so that a probe reply left in flight by a
/// previous process is not taken for this one's.
fn session_nonce() -> u16 {
    use std::hash::{BuildHasher, Hasher};
    let mut h = std::collections::hash_map::RandomState::new().build_hasher();
    h.write_u32(std::process::id());
    h.finish() as u16
}

/// A connected (or reconnectable) C-863.
pub struct C863 {
    cfg: C863Config,
    conn: Option<Conn>,
    /// Every request since the last matched probe got its own reply in time: the next reply
    /// read answers the next request. False at start, after reopening and after any failure.
    in_sync: bool,
    /// Nonce of the last probe sent.
    nonce: u16,
    stats: LinkStats,
    /// A move or reference may be in progress: stop on drop.
    moving: bool,
}

fn mm(um: f64) -> f64 {
    um / 1000.0
}

impl C863 {
    /// Opens the port (bounded by the reconnect settings); sends nothing. The first request
    /// is preceded by a resync probe.
    pub async fn connect(cfg: C863Config) -> Result<Self, AxisError> {
        let mut me = Self {
            cfg,
            conn: None,
            in_sync: false,
            nonce: session_nonce(),
            stats: LinkStats::default(),
            moving: false,
        };
        me.reopen().await?;
        me.stats.reopens = 0;
        Ok(me)
    }

    /// Recoveries so far.
    pub fn stats(&self) -> LinkStats {
        self.stats
    }

    /// The configuration this driver was built with.
    pub fn config(&self) -> &C863Config {
        &self.cfg
    }

    async fn open_once(&self) -> Result<Conn, String> {
        let io: Box<dyn Io> = match &self.cfg.transport {
            Transport::Tcp { address } => {
                let s = tokio::time::timeout(self.cfg.reply_timeout(), TcpStream::connect(address))
                    .await
                    .map_err(|_| format!("connect to {address} timed out"))?
                    .map_err(|e| format!("connect to {address}: {e}"))?;
                s.set_nodelay(true).map_err(|e| e.to_string())?;
                Box::new(s)
            }
            Transport::Serial {
                port,
                baud,
                rts_cts,
            } => {
                use tokio_serial::SerialPortBuilderExt;
                let flow = if *rts_cts {
                    tokio_serial::FlowControl::Hardware
                } else {
                    tokio_serial::FlowControl::None
                };
                let s = tokio_serial::new(port, *baud)
                    .data_bits(tokio_serial::DataBits::Eight)
                    .parity(tokio_serial::Parity::None)
                    .stop_bits(tokio_serial::StopBits::One)
                    .flow_control(flow)
                    .open_native_async()
                    .map_err(|e| format!("open {port}: {e}"))?;
                Box::new(s)
            }
        };
        Ok(Framed::new(io, ClientCodec::new(self.cfg.address)))
    }

    /// Opens the port, trying `1 + reconnect_attempts` times.
    async fn reopen(&mut self) -> Result<(), AxisError> {
        self.conn = None;
        let mut last = String::new();
        for attempt in 0..=self.cfg.reconnect_attempts {
            if attempt > 0 {
                tokio::time::sleep(Duration::from_millis(self.cfg.reconnect_delay_ms)).await;
            }
            match self.open_once().await {
                Ok(c) => {
                    if attempt > 0 {
                        debug!(attempt, "C-863 port reopened");
                    }
                    self.conn = Some(c);
                    // A reopened serial port may still deliver replies to earlier requests.
                    self.in_sync = false;
                    self.stats.reopens += 1;
                    return Ok(());
                }
                Err(e) => last = e,
            }
        }
        Err(AxisError::Io(format!(
            "{last} (gave up after {} attempts)",
            self.cfg.reconnect_attempts + 1
        )))
    }

    /// Discards whatever has already arrived unasked (complete frames and partial bytes);
    /// returns how many frames and whether anything was there.
    fn drain_arrived(conn: &mut Conn) -> (u64, bool) {
        let mut frames = 0;
        while frames < RESYNC_MAX_DISCARD as u64 {
            match conn.next().now_or_never() {
                Some(Some(_)) => frames += 1,
                // Nothing more for now, or closed (the next send or read reports it).
                Some(None) | None => break,
            }
        }
        let partial = !conn.read_buffer().is_empty();
        if partial {
            conn.read_buffer_mut().clear();
            conn.codec_mut().reset();
        }
        (frames, frames > 0 || partial)
    }

    /// Brings the stream back in sync: discards what already arrived, sends a probe `SPA?`
    /// whose id list encodes a fresh nonce, and discards every frame up to the reply that
    /// echoes exactly that list. Replies are in request order, so whatever follows answers
    /// requests sent after the probe. Bounded by the reply timeout per read,
    /// [`RESYNC_TIMEOUTS`] timeouts in all and [`RESYNC_MAX_DISCARD`] frames.
    async fn resync(&mut self) -> Result<(), Fail> {
        self.stats.resyncs += 1;
        let r = self.resync_once().await;
        if r.is_err() {
            self.stats.resyncs_failed += 1;
        }
        r
    }

    async fn resync_once(&mut self) -> Result<(), Fail> {
        let t = self.cfg.reply_timeout();
        let axis = self.cfg.axis.clone();
        self.nonce = self.nonce.wrapping_add(1);
        let ids = probe_ids(self.nonce);
        let probe = Command::QueryParam {
            items: ids.iter().map(|&id| (axis.clone(), id)).collect(),
        };
        let conn = self
            .conn
            .as_mut()
            .ok_or_else(|| Fail::Io("not connected".into()))?;
        let (frames, _) = Self::drain_arrived(conn);
        self.stats.discarded += frames;
        self.stats.frames_sent += 1;
        match tokio::time::timeout(t, conn.send(&probe)).await {
            Err(_) => return Err(Fail::Timeout),
            Ok(Err(e)) => return Err(Fail::Io(e.to_string())),
            Ok(Ok(())) => {}
        }
        let deadline = tokio::time::Instant::now() + t * RESYNC_TIMEOUTS;
        let mut last_discarded = None;
        for _ in 0..RESYNC_MAX_DISCARD {
            let until = deadline.min(tokio::time::Instant::now() + t);
            match tokio::time::timeout_at(until, conn.next()).await {
                Err(_) => break,
                Ok(None) => return Err(Fail::Io("port closed".into())),
                Ok(Some(Err(e))) => return Err(Fail::Io(e.to_string())),
                Ok(Some(Ok(Ok(r)))) if answers_probe(&r, &axis, &ids) => {
                    self.in_sync = true;
                    return Ok(());
                }
                Ok(Some(Ok(r))) => {
                    self.stats.discarded += 1;
                    debug!(frame = ?r, "discarded a frame that is not the probe's reply");
                    last_discarded = Some(match r {
                        Ok(r) => format!("{:?}", r.lines),
                        Err(e) => e.to_string(),
                    });
                }
            }
        }
        // The probe's reply did not come. If something else did, the last frame may have
        // been the probe's reply garbled: report the stream as garbled, not as silent.
        Err(match last_discarded {
            Some(f) => Fail::Garbled(format!(
                "resync probe unanswered; last frame discarded: {f}"
            )),
            None => Fail::Timeout,
        })
    }

    /// One attempt: send `cmd` and, if it has one, read its reply. Out of sync, or with
    /// anything unsolicited already received, a resync comes first.
    async fn exchange(&mut self, cmd: &Command) -> Result<Option<Reply>, Fail> {
        if self.in_sync {
            let conn = self
                .conn
                .as_mut()
                .ok_or_else(|| Fail::Io("not connected".into()))?;
            let (frames, any) = Self::drain_arrived(conn);
            if any {
                // Bytes nobody asked for: some earlier reply came after all, or noise.
                warn!(frames, "C-863 sent unsolicited bytes; resynchronising");
                self.stats.discarded += frames;
                self.in_sync = false;
            }
        }
        if !self.in_sync {
            self.resync().await?;
        }
        let t = self.cfg.reply_timeout();
        let conn = self
            .conn
            .as_mut()
            .ok_or_else(|| Fail::Io("not connected".into()))?;
        self.stats.frames_sent += 1;
        // Cancel safety: a caller may drop this future (an abort cuts a move short) after the
        // request went out and before its reply came; out of sync until the exchange is
        // complete, the next request resyncs first instead of taking that reply for its own.
        self.in_sync = false;
        match tokio::time::timeout(t, conn.send(cmd)).await {
            Err(_) => return Err(Fail::Timeout),
            Ok(Err(e)) => return Err(Fail::Io(e.to_string())),
            Ok(Ok(())) => {}
        }
        if !cmd.expects_reply() {
            self.in_sync = true;
            return Ok(None);
        }
        let r = match tokio::time::timeout(t, conn.next()).await {
            Err(_) => return Err(Fail::Timeout),
            Ok(None) => return Err(Fail::Io("port closed".into())),
            Ok(Some(Err(e))) => return Err(Fail::Io(e.to_string())),
            Ok(Some(Ok(Err(e)))) => Err(Fail::Garbled(e.to_string())),
            Ok(Some(Ok(Ok(r)))) => match cmd.check_reply_shape(&r) {
                Ok(()) => Ok(Some(r)),
                Err(e) => Err(Fail::Garbled(e)),
            },
        };
        // A whole reply was read (garbled or not): the stream is where it was before.
        self.in_sync = true;
        r
    }

    /// Refuses motion the soft limits do not allow, before anything is sent: a `MOV` target
    /// outside them, and any `MVR` (a relative target cannot be checked here, and a relative
    /// move resent after a lost reply would move twice).
    fn guard_motion(&self, cmd: &Command) -> Result<(), AxisError> {
        let (lo, hi) = self.cfg.soft_limits_um;
        match cmd {
            Command::Set {
                setter: AxisSetter::Mov,
                args,
            } => {
                for (_, v) in args {
                    // In mm, as `move_to` converts: a target on a limit stays on it.
                    if !(*v >= mm(lo) && *v <= mm(hi)) {
                        return Err(AxisError::OutsideSoftLimits {
                            target_um: v * 1000.0,
                            lo_um: lo,
                            hi_um: hi,
                        });
                    }
                }
                Ok(())
            }
            Command::Set {
                setter: AxisSetter::Mvr,
                ..
            } => Err(AxisError::Protocol(
                "MVR is not sent: a relative move can be neither checked against the soft \
                 limits nor resent safely; use MOV"
                    .into(),
            )),
            _ => Ok(()),
        }
    }

    /// Sends `cmd` and checks its reply with `check`; retries timeouts, garbled replies and
    /// port failures `retries` times (reopening a failed port as configured), each retry
    /// after a resync. Retrying is safe because every command that gets here may be sent
    /// twice: queries only read (except that a lost `ERR?` reply loses its code), setters are
    /// absolute (`MOV`, `SVO`, `VEL`, ...), a reference move restarts towards the same switch,
    /// stops stop again, and `MVR` never gets here ([`guard_motion`](Self::guard_motion)).
    async fn request<T>(
        &mut self,
        cmd: &Command,
        check: impl Fn(&Reply) -> Result<T, String>,
    ) -> Result<T, AxisError> {
        self.guard_motion(cmd)?;
        let mut last = AxisError::Protocol("no attempt".into());
        for attempt in 0..=self.cfg.retries {
            if attempt > 0 {
                self.stats.retries += 1;
            }
            if self.conn.is_none() {
                self.reopen().await?;
            }
            let r = match self.exchange(cmd).await {
                Ok(Some(reply)) => check(&reply).map_err(Fail::Garbled),
                Ok(None) => check(&Reply::default()).map_err(Fail::Garbled),
                Err(f) => Err(f),
            };
            match r {
                Ok(v) => return Ok(v),
                Err(Fail::Io(e)) => {
                    warn!(%cmd, error = %e, attempt, "C-863 port failed; reopening");
                    self.conn = None;
                    self.in_sync = false;
                    last = AxisError::Io(e);
                }
                Err(Fail::Timeout) => {
                    warn!(%cmd, attempt, "C-863 reply timeout");
                    self.in_sync = false;
                    last = AxisError::Timeout {
                        what: format!("reply to `{cmd}`"),
                        after: self.cfg.reply_timeout(),
                    };
                }
                Err(Fail::Garbled(e)) => {
                    warn!(%cmd, error = %e, attempt, "C-863 garbled reply");
                    self.in_sync = false;
                    last = AxisError::Protocol(format!("reply to `{cmd}`: {e}"));
                }
            }
        }
        Err(last)
    }

    /// A query with a reply.
    pub async fn query(&mut self, cmd: &Command) -> Result<Reply, AxisError> {
        self.request(cmd, |r| Ok(r.clone())).await
    }

    /// `ERR?`: the latched error code (reading clears it).
    pub async fn error_code(&mut self) -> Result<i32, AxisError> {
        self.request(&Command::Err, |r| {
            let l = r.single()?;
            l.trim()
                .parse::<i32>()
                .map_err(|_| format!("ERR? reply is not an integer: {l:?}"))
        })
        .await
    }

    /// Sends a setter, then `ERR?`; a non-zero code becomes [`AxisError::Controller`]
    /// (5 becomes [`AxisError::NotReferenced`]).
    pub async fn set(&mut self, cmd: &Command) -> Result<(), AxisError> {
        let mut last = None;
        for _ in 0..=self.cfg.retries {
            self.request(cmd, |_| Ok(())).await?;
            match self.error_code().await {
                Ok(0) => return Ok(()),
                Ok(E5_INIT_NOT_DONE)
                    if matches!(
                        cmd,
                        Command::Set {
                            setter: AxisSetter::Mov | AxisSetter::Mvr,
                            ..
                        }
                    ) =>
                {
                    return Err(AxisError::NotReferenced)
                }
                Ok(code) => return Err(controller_error(code)),
                // ERR? itself failed after its own retries: resend the (idempotent) setter.
                Err(e) => last = Some(e),
            }
        }
        Err(last.unwrap_or_else(|| AxisError::Protocol("no attempt".into())))
    }

    fn axes(&self) -> Vec<String> {
        vec![self.cfg.axis.clone()]
    }

    async fn axis_query<T>(
        &mut self,
        q: AxisQuery,
        parse: impl Fn(&Reply, &str) -> Result<T, String>,
    ) -> Result<T, AxisError> {
        let axis = self.cfg.axis.clone();
        self.request(
            &Command::Query {
                query: q,
                axes: self.axes(),
            },
            |r| parse(r, &axis),
        )
        .await
    }

    async fn axis_f64(&mut self, q: AxisQuery) -> Result<f64, AxisError> {
        self.axis_query(q, |r, a| r.axis_f64(a)).await
    }

    async fn axis_bool(&mut self, q: AxisQuery) -> Result<bool, AxisError> {
        self.axis_query(q, |r, a| r.axis_bool(a)).await
    }

    fn setter(&self, setter: AxisSetter, v: f64) -> Command {
        Command::Set {
            setter,
            args: vec![(self.cfg.axis.clone(), v)],
        }
    }

    /// Servo on/off (`SVO`).
    pub async fn set_servo(&mut self, on: bool) -> Result<(), AxisError> {
        self.set(&self.setter(AxisSetter::Svo, if on { 1.0 } else { 0.0 }))
            .await
    }

    /// Applies the configured velocity, acceleration and deceleration.
    pub async fn configure(&mut self) -> Result<(), AxisError> {
        let c = self.cfg.clone();
        for (s, v) in [
            (AxisSetter::Vel, c.velocity_mm_s),
            (AxisSetter::Acc, c.acceleration_mm_s2),
            (AxisSetter::Dec, c.deceleration_mm_s2),
        ] {
            if let Some(v) = v {
                self.set(&self.setter(s, v)).await?;
            }
        }
        Ok(())
    }

    /// `ONT?`
    pub async fn on_target(&mut self) -> Result<bool, AxisError> {
        self.axis_bool(AxisQuery::Ont).await
    }

    /// `FRF?`: whether the axis is referenced.
    pub async fn is_referenced(&mut self) -> Result<bool, AxisError> {
        self.axis_bool(AxisQuery::Frf).await
    }

    /// `#5`: whether the axis is moving.
    pub async fn is_moving(&mut self) -> Result<bool, AxisError> {
        let mask = self
            .request(&Command::Control(ControlByte::MotionStatus), |r| {
                let l = r.single()?.trim();
                let l = l.strip_prefix("0x").unwrap_or(l);
                u32::from_str_radix(l, 16).map_err(|_| format!("#5 reply is not hex: {l:?}"))
            })
            .await?;
        Ok(mask & 1 != 0)
    }

    /// Waits until `#5` reports no motion, at most `timeout` (the stage is stopped on timeout).
    /// Unlike [`Axis::wait_on_target`] this also ends for a halted or failed move.
    pub async fn wait_motion_done(&mut self, timeout: Duration) -> Result<(), AxisError> {
        let deadline = Instant::now() + timeout;
        let poll = Duration::from_millis(self.cfg.poll_interval_ms);
        while self.is_moving().await? {
            if Instant::now() >= deadline {
                self.stop_quietly().await;
                return Err(AxisError::Timeout {
                    what: "end of motion (#5)".into(),
                    after: timeout,
                });
            }
            tokio::time::sleep(poll).await;
        }
        self.moving = false;
        Ok(())
    }

    /// `#7`: whether the controller is ready (not busy referencing).
    pub async fn is_ready(&mut self) -> Result<bool, AxisError> {
        self.request(&Command::Control(ControlByte::Ready), |r| {
            match r.single()? {
                l if l == READY.to_string() => Ok(true),
                l if l == BUSY.to_string() => Ok(false),
                l => Err(format!("#7 reply is neither 0xB1 nor 0xB0: {l:?}")),
            }
        })
        .await
    }

    /// `HLT`: smooth stop; the controller latches error 10, which is read and cleared here.
    pub async fn halt(&mut self) -> Result<(), AxisError> {
        self.request(&Command::Halt { axes: self.axes() }, |_| Ok(()))
            .await?;
        self.after_stop().await
    }

    /// `STP`: abrupt stop of all axes (error 10 read and cleared).
    pub async fn stop_all(&mut self) -> Result<(), AxisError> {
        self.request(&Command::Stop, |_| Ok(())).await?;
        self.after_stop().await
    }

    async fn after_stop(&mut self) -> Result<(), AxisError> {
        self.moving = false;
        match self.error_code().await? {
            0 | E10_STOPPED => Ok(()),
            code => Err(controller_error(code)),
        }
    }

    /// Stops motion without reporting failures (used on error paths).
    async fn stop_quietly(&mut self) {
        if let Err(e) = self.stop().await {
            warn!(error = %e, "C-863 stop after an error failed");
        }
    }
}

fn controller_error(code: i32) -> AxisError {
    AxisError::Controller {
        code,
        message: error_message(code).to_string(),
    }
}

#[async_trait::async_trait]
impl Axis for C863 {
    async fn identify(&mut self) -> Result<AxisInfo, AxisError> {
        self.request(&Command::Csv, |r| {
            let v = r.single()?.trim();
            if v.starts_with("2.") {
                Ok(())
            } else {
                Err(format!("GCS syntax version {v:?}, expected 2.x"))
            }
        })
        .await?;
        let idn = self
            .request(&Command::Idn, |r| {
                let l = r.single()?.trim().to_string();
                if l.split(',').count() < 3 {
                    return Err(format!(
                        "*IDN? reply is not `vendor, model, serial, fw`: {l:?}"
                    ));
                }
                Ok(l)
            })
            .await?;
        let axis = self.cfg.axis.clone();
        self.request(&Command::Sai { all: false }, |r| {
            if r.lines.iter().any(|l| l.trim() == axis) {
                Ok(())
            } else {
                Err(format!("axis {axis:?} not among SAI? {:?}", r.lines))
            }
        })
        .await?;
        let lo = self.axis_f64(AxisQuery::Tmn).await?;
        let hi = self.axis_f64(AxisQuery::Tmx).await?;
        let stage = self
            .axis_query(AxisQuery::Cst, |r, a| r.axis_value(a).map(str::to_string))
            .await?;
        let (slo, shi) = self.cfg.soft_limits_um;
        if slo < lo * 1000.0 || shi > hi * 1000.0 {
            warn!(
                slo,
                shi, lo, hi, "soft limits reach beyond the controller's travel range"
            );
        }
        Ok(AxisInfo {
            idn,
            stage,
            travel_um: (lo * 1000.0, hi * 1000.0),
        })
    }

    async fn reference(&mut self, timeout: Duration) -> Result<(), AxisError> {
        let deadline = Instant::now() + timeout;
        self.set_servo(true).await?;
        self.configure().await?;
        let cmd = Command::Reference {
            mode: self.cfg.reference,
            axes: self.axes(),
        };
        self.moving = true;
        if let Err(e) = self.set(&cmd).await {
            // Refused by the controller: nothing moves. Otherwise it may: keep the stop-on-drop.
            if matches!(e, AxisError::Controller { .. }) {
                self.moving = false;
            }
            return Err(e);
        }
        let poll = Duration::from_millis(self.cfg.poll_interval_ms);
        loop {
            if self.is_ready().await? {
                break;
            }
            if Instant::now() >= deadline {
                self.stop_quietly().await;
                return Err(AxisError::Timeout {
                    what: format!("reference move ({cmd})"),
                    after: timeout,
                });
            }
            tokio::time::sleep(poll).await;
        }
        self.moving = false;
        let code = self.error_code().await?;
        if code != 0 {
            return Err(controller_error(code));
        }
        if !self.is_referenced().await? {
            return Err(AxisError::Protocol(format!(
                "{cmd} finished but FRF? reports unreferenced"
            )));
        }
        Ok(())
    }

    async fn move_to(&mut self, target_um: f64) -> Result<(), AxisError> {
        let (lo, hi) = self.cfg.soft_limits_um;
        // Checked before anything is sent (NaN fails both comparisons, hence the negation).
        if !(target_um >= lo && target_um <= hi) {
            return Err(AxisError::OutsideSoftLimits {
                target_um,
                lo_um: lo,
                hi_um: hi,
            });
        }
        self.moving = true;
        let r = self.set(&self.setter(AxisSetter::Mov, mm(target_um))).await;
        if let Err(e) = &r {
            if !matches!(e, AxisError::NotReferenced | AxisError::Controller { .. }) {
                self.stop_quietly().await;
            } else {
                self.moving = false;
            }
        }
        r
    }

    async fn wait_on_target(&mut self, timeout: Duration) -> Result<(), AxisError> {
        let deadline = Instant::now() + timeout;
        let poll = Duration::from_millis(self.cfg.poll_interval_ms);
        loop {
            if self.on_target().await? {
                self.moving = false;
                return Ok(());
            }
            // A motion error (1024: servo switched off) never reaches on-target: report it now.
            let code = self.error_code().await?;
            if code != 0 {
                self.stop_quietly().await;
                return Err(controller_error(code));
            }
            if Instant::now() >= deadline {
                self.stop_quietly().await;
                return Err(AxisError::Timeout {
                    what: "on-target (ONT?)".into(),
                    after: timeout,
                });
            }
            tokio::time::sleep(poll).await;
        }
    }

    async fn position_um(&mut self) -> Result<f64, AxisError> {
        Ok(self.axis_f64(AxisQuery::Pos).await? * 1000.0)
    }

    async fn stop(&mut self) -> Result<(), AxisError> {
        // #24 goes out first, before any resync: after a cancelled exchange or on a noisy
        // line a resync costs a probe's round trip or its timeouts, and #24 has no reply to
        // take out of order. Through `request` (reopen, retries) only if that send fails.
        let stop = Command::Control(ControlByte::StopAll);
        let t = self.cfg.reply_timeout();
        let sent = match self.conn.as_mut() {
            Some(conn) => matches!(tokio::time::timeout(t, conn.send(&stop)).await, Ok(Ok(()))),
            None => false,
        };
        if sent {
            self.stats.frames_sent += 1;
        } else {
            self.request(&stop, |_| Ok(())).await?;
        }
        self.after_stop().await
    }

    fn soft_limits_um(&self) -> (f64, f64) {
        self.cfg.soft_limits_um
    }
}

impl Drop for C863 {
    /// Hardware safety: a driver dropped while the stage may move sends #24 (stop all).
    fn drop(&mut self) {
        if !self.moving {
            return;
        }
        let Some(mut conn) = self.conn.take() else {
            return;
        };
        match tokio::runtime::Handle::try_current() {
            Ok(h) => {
                h.spawn(async move {
                    let stop = Command::Control(ControlByte::StopAll);
                    let _ = tokio::time::timeout(Duration::from_secs(1), conn.send(&stop)).await;
                });
            }
            Err(_) => {
                warn!("C-863 dropped outside a tokio runtime while moving; could not send #24")
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_probe_is_answered_only_by_its_own_reply() {
        let all: std::collections::HashSet<_> = (0..=u16::MAX).map(probe_ids).collect();
        assert_eq!(all.len(), 1 << 16, "no two nonces share an id list");
        let reply =
            |ids: &[u32]| Reply::lines(ids.iter().map(|id| format!("1 0x{id:X}=1.5")).collect());
        let (a, b) = (probe_ids(41), probe_ids(42));
        assert!(answers_probe(&reply(&a), "1", &a));
        assert!(
            !answers_probe(&reply(&a), "1", &b),
            "an earlier probe's reply"
        );
        assert!(!answers_probe(&reply(&a[..7]), "1", &a), "a line short");
        assert!(!answers_probe(&reply(&a), "2", &a), "another axis");
        let decimal = Reply::lines(a.iter().map(|id| format!("1 {id}=0")).collect());
        assert!(
            answers_probe(&decimal, "1", &a),
            "decimal ids are the same ids"
        );
        for stale in ["1=7.5", "0", "\u{B1}", "2.0"] {
            assert!(!answers_probe(&Reply::line(stale), "1", &a), "{stale:?}");
        }
    }

    #[test]
    fn config_reads_from_toml_with_safe_defaults() {
        let c: C863Config = toml::from_str(
            r#"
            soft_limits_um = [100.0, 14900.0]
            reference = "FNL"
            velocity_mm_s = 1.0
            [transport]
            kind = "serial"
            port = "/dev/ttyUSB1"
            rts_cts = true
            "#,
        )
        .unwrap();
        assert_eq!(
            c.transport,
            Transport::Serial {
                port: "/dev/ttyUSB1".into(),
                baud: 115_200,
                rts_cts: true
            }
        );
        assert_eq!((c.reference, c.axis.as_str()), (RefMode::Fnl, "1"));
        assert_eq!(c.soft_limits_um, (100.0, 14_900.0));
        assert!(
            c.reply_timeout_ms > 0 && c.reconnect_attempts > 0,
            "every wait is bounded"
        );
        let t: C863Config =
            toml::from_str("[transport]\nkind = \"tcp\"\naddress = \"10.0.0.5:4001\"\n").unwrap();
        assert_eq!(
            t.transport,
            Transport::Tcp {
                address: "10.0.0.5:4001".into()
            }
        );
    }
}
