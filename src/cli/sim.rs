//! `csmetro sim`: simulated devices.
//!
//! `csmetro sim controller --tcp 127.0.0.1:PORT | --pty` serves a simulated PI C-863 and prints
//! where it listens (address or tty path) as the first stdout line, then serves until SIGINT or
//! SIGTERM. `csmetro sim bench-gcs` times the GCS driver against it over a pty (JSON);
//! `csmetro sim soak-gcs` runs the driver under random faults and checks that every answer it
//! took was the controller's reply to the request it had just sent (JSON).
//! `csmetro sim rig --config RIG.toml` serves a whole simulated rig (two controllers and, with
//! the `aravis` feature, a GigE Vision camera) for `kind = "real"` campaigns.
use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::{Duration, Instant};

use clap::Subcommand;
use csmetro_gcs::{AxisQuery, Command};
use csmetro_gcs::{C863Config, RefMode, C863};
use csmetro_hal::Axis;
use csmetro_sim::SimStage;
use csmetro_sim::{soak_gcs, BindingCheck, SoakOptions};
use csmetro_sim::{AxisId, StageModel};
use csmetro_sim::{ControllerConfig, SimController};
use serde_json::json;

use super::{CliError, CliResult};

mod rig;

#[derive(clap::Args)]
pub struct Args {
    #[command(subcommand)]
    what: What,
}

#[derive(clap::Args)]
struct ControllerArgs {
    /// Serve over TCP at this address (port 0 picks a free one).
    #[arg(long, conflicts_with = "pty", required_unless_present = "pty")]
    tcp: Option<SocketAddr>,
    /// Serve over a pseudo-terminal; prints the tty path to open like a serial device.
    #[arg(long)]
    pty: bool,
    /// With --pty: the stable path (symlink to the pty) to create; default in the temp dir.
    #[arg(long, requires = "pty")]
    link: Option<PathBuf>,
    /// Stage model (TOML) whose errors make the true position; default: an ideal stage.
    #[arg(long)]
    model: Option<PathBuf>,
    /// Which stage axis this controller drives.
    #[arg(long, default_value = "x")]
    axis: String,
    /// Simulated physical seconds per real second (100 runs a campaign 100 times faster).
    #[arg(long)]
    time_scale: Option<f64>,
    /// Simulator config: `time_scale` and a `[controller]` section (ControllerConfig, faults,
    /// `[controller.random_faults]`).
    #[arg(long)]
    config: Option<PathBuf>,
    /// Seed of the config's `[controller.random_faults]` (overrides its `seed`).
    #[arg(long)]
    fault_seed: Option<u64>,
}

#[derive(Subcommand)]
enum What {
    /// Serve a whole simulated rig: two C-863s (TCP or pty) on one simulated XY stage and, with
    /// the `aravis` feature, a GigE Vision camera on 127.0.0.1 drawing the pattern at the
    /// stage's true position. Prints where each device is, then `ready`.
    Rig(rig::RigArgs),
    /// Serve a simulated PI C-863 (GCS 2.0) over TCP or a pty.
    Controller(ControllerArgs),
    /// Time the GCS driver against the simulated C-863 over a pty: round trip (median, p99)
    /// and a reference + N-move sequence. Prints JSON.
    BenchGcs {
        /// Round trips (`POS? 1`) to time.
        #[arg(long, default_value_t = 2000)]
        round_trips: usize,
        /// Moves after the reference move.
        #[arg(long, default_value_t = 100)]
        moves: usize,
        /// Step between moves, µm.
        #[arg(long, default_value_t = 100.0)]
        step_um: f64,
        /// Simulated seconds per real second (default: the --config file's, else 1).
        #[arg(long)]
        time_scale: Option<f64>,
        /// Use a simulator already serving at this tty path (another process, e.g.
        /// `csmetro sim controller --pty`) instead of one in this process.
        #[arg(long, conflicts_with = "config")]
        port: Option<PathBuf>,
        /// Simulator config for the in-process simulator (as `sim controller --config`:
        /// `[controller]`, its faults; its `time_scale` unless --time-scale is given).
        #[arg(long)]
        config: Option<PathBuf>,
    },
    /// Soak the GCS driver against the simulated C-863 (pty) under random delays (past the
    /// reply timeout too), dropped and garbled replies; checks every answer the driver took
    /// against the reply the simulator produced for that request. Prints JSON.
    SoakGcs {
        /// Driver calls (queries, and a move every tenth call on average).
        #[arg(long, default_value_t = 100_000)]
        commands: u64,
        /// Seeds both the command mix and the faults.
        #[arg(long, default_value_t = 1)]
        seed: u64,
        #[arg(long, default_value_t = 100.0)]
        time_scale: f64,
        /// The driver's reply timeout, ms.
        #[arg(long, default_value_t = 100)]
        reply_timeout_ms: u64,
        /// Fault rates and delays from this file's `[controller.random_faults]` instead of
        /// the built-in ones (its seed is replaced by --seed).
        #[arg(long)]
        config: Option<PathBuf>,
    },
}

pub fn run(args: Args) -> CliResult {
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .map_err(|e| CliError::failure(format!("tokio runtime: {e}")))?;
    match args.what {
        What::Controller(a) => rt.block_on(controller(a)),
        What::Rig(a) => rt.block_on(rig::rig(a)),
        What::BenchGcs {
            round_trips,
            moves,
            step_um,
            time_scale,
            port,
            config,
        } => rt.block_on(bench_gcs(
            round_trips,
            moves,
            step_um,
            time_scale,
            port,
            config,
        )),
        What::SoakGcs {
            commands,
            seed,
            time_scale,
            reply_timeout_ms,
            config,
        } => rt.block_on(soak(commands, seed, time_scale, reply_timeout_ms, config)),
    }
}

/// Longest soak: a typo must not start a run of days.
const MAX_SOAK_COMMANDS: u64 = 10_000_000;

async fn soak(
    commands: u64,
    seed: u64,
    time_scale: f64,
    reply_timeout_ms: u64,
    config: Option<PathBuf>,
) -> CliResult {
    if commands == 0 || commands > MAX_SOAK_COMMANDS {
        return Err(CliError::input(format!(
            "--commands must be 1..={MAX_SOAK_COMMANDS}, not {commands}"
        )));
    }
    if let Err(m) = csmetro_sim::check_time_scale(time_scale) {
        return Err(CliError::input(format!("--time-scale: {m}")));
    }
    if !(1..=60_000).contains(&reply_timeout_ms) {
        return Err(CliError::input(format!(
            "--reply-timeout-ms must be 1..=60000, not {reply_timeout_ms}"
        )));
    }
    let mut opts = SoakOptions::new(commands, seed);
    opts.time_scale = time_scale;
    opts.reply_timeout_ms = reply_timeout_ms;
    if let Some(p) = &config {
        let (_, cfg) = load_config(p)?;
        opts.faults = cfg.random_faults.ok_or_else(|| {
            CliError::input(format!(
                "{}: no [controller.random_faults] section",
                p.display()
            ))
        })?;
        opts.faults.seed = seed;
    }
    let r = soak_gcs(&opts).await.map_err(CliError::failure)?;
    let out = json!({
        "commands": r.commands,
        "seed": seed,
        "time_scale": time_scale,
        "reply_timeout_ms": reply_timeout_ms,
        "fault_rates": {
            "delay": opts.faults.delay_rate,
            "delay_ms": opts.faults.delay_ms,
            "drop": opts.faults.drop_rate,
            "garbage": opts.faults.garbage_rate,
            "error": opts.faults.error_rate,
            "vanish": opts.faults.vanish_rate,
        },
        "faults_injected": r.faults,
        "retries": r.link.retries,
        "resyncs": r.link.resyncs,
        "resyncs_failed": r.link.resyncs_failed,
        "discarded_replies": r.link.discarded,
        "reopens": r.link.reopens,
        "errors_returned": r.errors_returned,
        "answers_checked": r.answers_checked,
        "stale_accepted": r.stale_accepted,
        "garbled_accepted": r.garbled_accepted,
        "misaligned": r.misaligned,
        "examples": r.examples,
        "unchecked": r.unchecked,
        "wall_s": r.wall_s,
    });
    outln!(
        "{}",
        serde_json::to_string_pretty(&out).map_err(|e| CliError::failure(e.to_string()))?
    );
    Ok(ExitCode::SUCCESS)
}

/// `time_scale` and the `[controller]` section of a simulator config file.
fn load_config(path: &Path) -> Result<(Option<f64>, ControllerConfig), CliError> {
    let text = std::fs::read_to_string(path)
        .map_err(|e| CliError::input(format!("{}: {e}", path.display())))?;
    let mut table: toml::Table =
        toml::from_str(&text).map_err(|e| CliError::input(format!("{}: {e}", path.display())))?;
    let scale = match table.get("time_scale") {
        None => None,
        Some(v) => Some(
            v.as_float()
                .or(v.as_integer().map(|i| i as f64))
                .ok_or_else(|| {
                    CliError::input(format!("{}: `time_scale` must be a number", path.display()))
                })?,
        ),
    };
    if let Some(Err(m)) = scale.map(csmetro_sim::check_time_scale) {
        let line = crate::tomlpos::span_of(&text, "time_scale").map_or(String::new(), |r| {
            format!(":{}", crate::tomlpos::line_of(&text, r.start))
        });
        return Err(CliError::input(format!(
            "{}{line}: time_scale: {m}",
            path.display()
        )));
    }
    let cfg: ControllerConfig = match table.remove("controller") {
        None => ControllerConfig::default(),
        Some(v) => v
            .try_into()
            .map_err(|e| CliError::input(format!("{}: [controller]: {e}", path.display())))?,
    };
    if let Some(rf) = &cfg.random_faults {
        rf.validate().map_err(|e| {
            CliError::input(format!(
                "{}: [controller.random_faults]: {e}",
                path.display()
            ))
        })?;
    }
    Ok((scale, cfg))
}

async fn controller(a: ControllerArgs) -> CliResult {
    let mut signals = Signals::register()?;
    let axis = AxisId::parse(&a.axis)
        .ok_or_else(|| CliError::input(format!("--axis must be x or y, not {:?}", a.axis)))?;
    let (file_scale, mut cfg) = match &a.config {
        Some(p) => load_config(p)?,
        None => (None, ControllerConfig::default()),
    };
    if let Some(seed) = a.fault_seed {
        cfg.random_faults
            .as_mut()
            .ok_or_else(|| {
                CliError::input(
                    "--fault-seed needs a [controller.random_faults] section in --config",
                )
            })?
            .seed = seed;
    }
    let scale = a.time_scale.or(file_scale).unwrap_or(1.0);
    if let Err(m) = csmetro_sim::check_time_scale(scale) {
        return Err(CliError::input(format!("--time-scale: {m}")));
    }
    let model = match &a.model {
        Some(p) => StageModel::load(p).map_err(|e| CliError::input(e.to_string()))?,
        None => StageModel::default(),
    };
    let start = [cfg.start_mm; 2];
    let stage = SimStage::new(
        model,
        scale,
        start,
        cfg.velocity_mm_s,
        cfg.acceleration_mm_s2,
    );
    let sim = match (a.tcp, a.pty) {
        (Some(addr), _) => SimController::start_tcp(stage, axis, cfg, addr).await,
        (None, true) => SimController::start_pty(stage, axis, cfg, a.link.clone()).await,
        (None, false) => return Err(CliError::input("give --tcp ADDR or --pty")),
    }
    .map_err(|e| CliError::failure(format!("cannot serve: {e}")))?;
    outln!("{}", sim.endpoint());
    eprintln!(
        "simulated C-863.11 (axis {axis}, time scale {scale}) serving at {}",
        sim.endpoint()
    );
    signals.wait().await;
    sim.shutdown().await;
    Ok(ExitCode::SUCCESS)
}

/// SIGINT or SIGTERM, registered before the first line is printed so that a signal sent as
/// soon as the address is known is never missed.
struct Signals {
    term: tokio::signal::unix::Signal,
    int: tokio::signal::unix::Signal,
}

impl Signals {
    fn register() -> Result<Self, CliError> {
        use tokio::signal::unix::{signal, SignalKind};
        let e = |e: std::io::Error| CliError::failure(format!("signal handler: {e}"));
        Ok(Self {
            term: signal(SignalKind::terminate()).map_err(e)?,
            int: signal(SignalKind::interrupt()).map_err(e)?,
        })
    }
    async fn wait(&mut self) {
        tokio::select! {
            _ = self.term.recv() => {}
            _ = self.int.recv() => {}
        }
    }
}

fn percentile(sorted: &[f64], q: f64) -> f64 {
    let i = ((sorted.len() as f64 - 1.0) * q).round() as usize;
    sorted[i.min(sorted.len() - 1)]
}

async fn bench_gcs(
    round_trips: usize,
    moves: usize,
    step_um: f64,
    scale: Option<f64>,
    port: Option<PathBuf>,
    config: Option<PathBuf>,
) -> CliResult {
    let fail = |e: csmetro_hal::AxisError| CliError::failure(e.to_string());
    let (file_scale, cfg) = match &config {
        Some(p) => load_config(p)?,
        None => (None, ControllerConfig::default()),
    };
    let scale = scale.or(file_scale).unwrap_or(1.0);
    if let Err(m) = csmetro_sim::check_time_scale(scale) {
        return Err(CliError::input(format!("--time-scale: {m}")));
    }
    let (sim, clock, path) = match port {
        Some(p) => (None, None, p.display().to_string()),
        None => {
            let stage = SimStage::new(
                StageModel::default(),
                scale,
                [cfg.start_mm; 2],
                cfg.velocity_mm_s,
                cfg.acceleration_mm_s2,
            );
            let clock = stage.clock();
            let sim = SimController::start_pty(stage, AxisId::X, cfg, None)
                .await
                .map_err(|e| CliError::failure(format!("pty: {e}")))?;
            sim.controller().keep_exchanges(1 << 16);
            let path = sim.endpoint().to_string();
            (Some(sim), Some(clock), path)
        }
    };
    let mut drv = C863::connect(C863Config {
        reference: RefMode::Fnl,
        poll_interval_ms: 5,
        ..C863Config::serial(path)
    })
    .await
    .map_err(fail)?;
    drv.identify().await.map_err(fail)?;
    let mut rt = Vec::with_capacity(round_trips);
    // With an in-process simulator every answer is checked against the reply produced for
    // its request; a round trip that fails after the driver's retries is counted, not fatal.
    let mut chk = BindingCheck::default();
    let mut rt_errors = 0u64;
    let pos = Command::Query {
        query: AxisQuery::Pos,
        axes: vec![drv.config().axis.clone()],
    };
    for _ in 0..round_trips.max(1) {
        let t = Instant::now();
        match drv.query(&pos).await {
            Ok(r) => {
                rt.push(t.elapsed().as_secs_f64() * 1e6);
                chk.expect(drv.stats().frames_sent, &pos, &r);
            }
            Err(_) => rt_errors += 1,
        }
        if let Some(s) = &sim {
            chk.absorb(s.controller());
        }
    }
    if rt.is_empty() {
        return Err(CliError::failure("no round trip succeeded"));
    }
    rt.sort_by(f64::total_cmp);
    let t0 = Instant::now();
    let phys0 = clock.map(|c| c.now_s());
    drv.reference(Duration::from_secs(120))
        .await
        .map_err(fail)?;
    let t_ref = t0.elapsed().as_secs_f64();
    for i in 0..moves {
        drv.move_to(1000.0 + (i % 100) as f64 * step_um)
            .await
            .map_err(fail)?;
        drv.wait_on_target(Duration::from_secs(60))
            .await
            .map_err(fail)?;
    }
    let wall = t0.elapsed().as_secs_f64();
    let binding = match &sim {
        Some(s) => {
            chk.settle(s.controller(), Duration::from_secs(10)).await;
            json!({
                "answers_checked": chk.checked,
                "stale_accepted": chk.stale,
                "garbled_accepted": chk.garbled,
                "misaligned": chk.misaligned,
                "unchecked": chk.unchecked(),
                "faults_injected": s.controller().fault_counts(),
            })
        }
        None => serde_json::Value::Null,
    };
    let out = json!({
        "transport": "pty",
        "round_trip_us": { "n": rt.len(), "median": percentile(&rt, 0.5), "p99": percentile(&rt, 0.99) },
        "round_trip_errors": rt_errors,
        "link": drv.stats(),
        "binding": binding,
        "sequence": {
            "reference": "FNL",
            "moves": moves,
            "step_um": step_um,
            "time_scale": scale,
            "reference_wall_s": t_ref,
            "wall_s": wall,
            "physical_s": clock.zip(phys0).map(|(c, p0)| c.now_s() - p0),
            "simulator": if sim.is_some() { "in-process" } else { "external" },
        }
    });
    outln!(
        "{}",
        serde_json::to_string_pretty(&out).map_err(|e| CliError::failure(e.to_string()))?
    );
    drop(drv);
    if let Some(sim) = sim {
        sim.shutdown().await;
    }
    Ok(ExitCode::SUCCESS)
}
