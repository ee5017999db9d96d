//! Driver soak: the C-863 client against the simulated controller under random faults,
//! checking that every answer the client returned is the reply the controller produced for
//! the very request the client sent last, never a late reply to an earlier one.
//!
//! Binding check: the simulator numbers the requests it handles and the client counts the
//! frames it writes ([`LinkStats::frames_sent`]); over one byte stream the n-th frame written
//! is the n-th request handled. A query call that returns `Ok(reply)` last wrote its command,
//! so `reply` must equal the reply the controller produced for request number `frames_sent`.
use std::collections::VecDeque;
use std::sync::Arc;
use std::time::{Duration, Instant};

use bytes::BytesMut;
use csmetro_effects::{AxisId, StageModel};
use csmetro_gcs::encode_reply;
use csmetro_gcs::{AxisQuery, Command, ControlByte};
use csmetro_gcs::{C863Config, LinkStats, RefMode, C863};
use csmetro_hal::Axis;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::Serialize;

use super::{Controller, ControllerConfig, Exchange, FaultCounts, RandomFaults, SimController};
use crate::stage::SimStage;

/// What to run.
#[derive(Debug, Clone)]
pub struct SoakOptions {
    /// Driver calls to make (queries and moves).
    pub commands: u64,
    /// Seeds the command mix (the faults have their own seed).
    pub seed: u64,
    /// Simulated seconds per real second (moves are part of the mix).
    pub time_scale: f64,
    /// Random faults of the simulated controller.
    pub faults: RandomFaults,
    /// The driver's reply timeout; delays longer than this are the dangerous ones.
    pub reply_timeout_ms: u64,
    /// The driver's extra attempts of one exchange after a timeout or a garbled reply.
    pub retries: u32,
}

impl SoakOptions {
    /// Delays beyond the 100 ms reply timeout included, drops and garbage (about one reply
    /// in 125 struck).
    pub fn new(commands: u64, seed: u64) -> Self {
        Self {
            commands,
            seed,
            time_scale: 100.0,
            faults: RandomFaults {
                seed,
                delay_rate: 0.004,
                delay_ms: [20, 400],
                drop_rate: 0.002,
                garbage_rate: 0.002,
                ..RandomFaults::default()
            },
            reply_timeout_ms: 100,
            retries: 2,
        }
    }
}

/// What happened.
#[derive(Debug, Clone, Serialize)]
pub struct SoakReport {
    /// Driver calls made.
    pub commands: u64,
    /// Faults that struck, by kind.
    pub faults: FaultCounts,
    /// The driver's recoveries (retries, resyncs, discarded replies, ...).
    pub link: LinkStats,
    /// Calls that returned an error (a timeout after all retries, ...): safe, not wrong.
    pub errors_returned: u64,
    /// Answers compared with the controller's reply to their request.
    pub answers_checked: u64,
    /// Answers that were not the controller's reply to the request sent last: the bug.
    pub stale_accepted: u64,
    /// Answers that were the garbage sent in place of their own reply. Must be 0.
    pub garbled_accepted: u64,
    /// Answers whose request number did not hold the command sent (the frame count and the
    /// simulator's request count disagree: the check itself failed). Must be 0.
    pub misaligned: u64,
    /// Answers not checked because the simulator never handled their request in time.
    pub unchecked: u64,
    /// The first few stale or misaligned answers, described.
    pub examples: Vec<String>,
    /// Real duration of the soak, s.
    pub wall_s: f64,
}

struct Check {
    seq: u64,
    cmd: String,
    reply: Vec<u8>,
}

/// Checks answers a client took against the replies the controller produced for their
/// requests (the controller must [`keep_exchanges`](Controller::keep_exchanges)).
#[derive(Default)]
pub struct BindingCheck {
    pending: VecDeque<Check>,
    exchanges: VecDeque<Exchange>,
    /// Answers compared so far.
    pub checked: u64,
    /// Answers that differ from the controller's reply to their request (a reply to an
    /// earlier request, or bytes of several).
    pub stale: u64,
    /// Answers that are the garbled bytes sent for their own request (bound, but wrong).
    pub garbled: u64,
    /// Answers whose request number did not hold their command.
    pub misaligned: u64,
    /// The first few stale or misaligned answers, described (for the report).
    pub examples: Vec<String>,
}

impl BindingCheck {
    /// Records that the client answered `cmd`, written as frame number `seq` (its
    /// [`LinkStats::frames_sent`] right after the call), with `reply`.
    pub fn expect(&mut self, seq: u64, cmd: &Command, reply: &csmetro_gcs::Reply) {
        let mut buf = BytesMut::new();
        encode_reply(reply, &mut buf);
        self.pending.push_back(Check {
            seq,
            cmd: cmd.to_string(),
            reply: buf.to_vec(),
        });
    }

    /// Answers not compared yet (their request not handled yet).
    pub fn unchecked(&self) -> u64 {
        self.pending.len() as u64
    }

    /// Compares what can be compared with the exchanges the controller logged so far.
    pub fn absorb(&mut self, ctl: &Controller) {
        self.exchanges.extend(ctl.drain_exchanges());
        while let Some(c) = self.pending.front() {
            while self.exchanges.front().is_some_and(|e| e.seq < c.seq) {
                self.exchanges.pop_front();
            }
            let Some(e) = self.exchanges.front() else {
                break; // the controller has not handled that request yet
            };
            self.checked += 1;
            let wrong = if e.seq != c.seq || e.request != c.cmd {
                self.misaligned += 1;
                true
            } else if e.reply != c.reply && e.sent == c.reply {
                self.garbled += 1;
                true
            } else if e.reply != c.reply {
                self.stale += 1;
                true
            } else {
                false
            };
            if wrong && self.examples.len() < 5 {
                let text = |b: &[u8]| b.iter().map(|&b| b as char).collect::<String>();
                self.examples.push(format!(
                    "request {} `{}` answered {:?}; the controller replied {:?} to request {} `{}`",
                    c.seq,
                    c.cmd,
                    text(&c.reply),
                    text(&e.reply),
                    e.seq,
                    e.request
                ));
            }
            self.pending.pop_front();
        }
    }

    /// Waits (at most `wait`) until every answer is compared.
    pub async fn settle(&mut self, ctl: &Controller, wait: Duration) {
        let end = Instant::now() + wait;
        self.absorb(ctl);
        while !self.pending.is_empty() && Instant::now() < end {
            tokio::time::sleep(Duration::from_millis(20)).await;
            self.absorb(ctl);
        }
    }
}

/// A checked query: one of the driver's own or a raw one, varied so that answers differ.
fn pick_query(rng: &mut ChaCha8Rng) -> Command {
    const QUERIES: [AxisQuery; 9] = [
        AxisQuery::Pos,
        AxisQuery::Pos,
        AxisQuery::Pos,
        AxisQuery::Ont,
        AxisQuery::Mov,
        AxisQuery::Svo,
        AxisQuery::Frf,
        AxisQuery::Vel,
        AxisQuery::Tmx,
    ];
    const PARAMS: [u32; 6] = [0x0A, 0x15, 0x16, 0x30, 0x3C, 0x50];
    match rng.random_range(0..10) {
        0..=4 => Command::Query {
            query: QUERIES[rng.random_range(0..QUERIES.len())],
            axes: vec!["1".into()],
        },
        5 => Command::QueryParam {
            items: (0..rng.random_range(1..=3))
                .map(|_| ("1".to_string(), PARAMS[rng.random_range(0..PARAMS.len())]))
                .collect(),
        },
        6 => Command::Err,
        7 => Command::Control(
            [
                ControlByte::Ready,
                ControlByte::MotionStatus,
                ControlByte::Status,
            ][rng.random_range(0..3)],
        ),
        _ => [Command::Csv, Command::Idn, Command::Sai { all: false }][rng.random_range(0..3)]
            .clone(),
    }
}

/// Runs the soak over a pty (the serial path), in this runtime.
pub async fn soak_gcs(opts: &SoakOptions) -> Result<SoakReport, String> {
    opts.faults.validate()?;
    let cfg = ControllerConfig::default();
    let stage = SimStage::new(
        StageModel::default(),
        opts.time_scale,
        [cfg.start_mm; 2],
        cfg.velocity_mm_s,
        cfg.acceleration_mm_s2,
    );
    let sim = SimController::start_pty(stage, AxisId::X, cfg, None)
        .await
        .map_err(|e| format!("pty: {e}"))?;
    let ctl: Arc<Controller> = sim.controller().clone();
    let soft = (500.0, 14_500.0);
    let mut drv = C863::connect(C863Config {
        reference: RefMode::Fnl,
        soft_limits_um: soft,
        reply_timeout_ms: opts.reply_timeout_ms,
        retries: opts.retries,
        poll_interval_ms: 2,
        ..C863Config::serial(sim.endpoint().to_string())
    })
    .await
    .map_err(|e| e.to_string())?;
    drv.reference(Duration::from_secs(60))
        .await
        .map_err(|e| format!("reference before the soak: {e}"))?;
    ctl.keep_exchanges(1 << 16);
    ctl.set_random_faults(Some(opts.faults.clone()));
    let mut rng = ChaCha8Rng::seed_from_u64(opts.seed ^ 0x5eed_c0de);
    let mut chk = BindingCheck::default();
    let mut errors = 0u64;
    let t0 = Instant::now();
    for _ in 0..opts.commands {
        if rng.random_range(0..10) == 0 {
            let target = rng.random_range(soft.0..=soft.1);
            if drv.move_to(target).await.is_err() {
                errors += 1;
            }
        } else {
            let cmd = pick_query(&mut rng);
            match drv.query(&cmd).await {
                Ok(r) => chk.expect(drv.stats().frames_sent, &cmd, &r),
                Err(_) => errors += 1,
            }
        }
        chk.absorb(&ctl);
    }
    let wall_s = t0.elapsed().as_secs_f64();
    // Requests still queued behind a delay are handled within a few of the longest delays.
    let wait = Duration::from_millis(opts.faults.delay_ms[1].saturating_mul(4) + 1000);
    chk.settle(&ctl, wait).await;
    ctl.set_random_faults(None);
    let _ = drv.stop().await;
    let report = SoakReport {
        commands: opts.commands,
        faults: ctl.fault_counts(),
        link: drv.stats(),
        errors_returned: errors,
        answers_checked: chk.checked,
        stale_accepted: chk.stale,
        garbled_accepted: chk.garbled,
        misaligned: chk.misaligned,
        unchecked: chk.unchecked(),
        examples: chk.examples.clone(),
        wall_s,
    };
    drop(drv);
    sim.shutdown().await;
    Ok(report)
}
