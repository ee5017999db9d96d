//! `csmetro sim`: simulated devices.
//!
//! `csmetro sim controller --tcp 127.0.0.1:PORT | --pty` serves a simulated PI C-863 and prints
//! where it listens (address or tty path) as the first stdout line, then serves until SIGINT or
//! SIGTERM. `csmetro sim bench-gcs` times the GCS driver against it over a pty (JSON).
use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::{Duration, Instant};

use clap::Subcommand;
use csmetro_gcs::{C863Config, RefMode, C863};
use csmetro_hal::Axis;
use csmetro_sim::controller::{ControllerConfig, SimController};
use csmetro_sim::stage::SimStage;
use csmetro_sim::{AxisId, StageModel};
use serde_json::json;

use super::{CliError, CliResult};

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
    /// Simulator config: `time_scale` and a `[controller]` section (ControllerConfig, faults).
    #[arg(long)]
    config: Option<PathBuf>,
}

#[derive(Subcommand)]
enum What {
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
        #[arg(long, default_value_t = 1.0)]
        time_scale: f64,
        /// Use a simulator already serving at this tty path (another process, e.g.
        /// `csmetro sim controller --pty`) instead of one in this process.
        #[arg(long)]
        port: Option<PathBuf>,
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
        What::BenchGcs {
            round_trips,
            moves,
            step_um,
            time_scale,
            port,
        } => rt.block_on(bench_gcs(round_trips, moves, step_um, time_scale, port)),
    }
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
    let cfg = match table.remove("controller") {
        None => ControllerConfig::default(),
        Some(v) => v
            .try_into()
            .map_err(|e| CliError::input(format!("{}: [controller]: {e}", path.display())))?,
    };
    Ok((scale, cfg))
}

async fn controller(a: ControllerArgs) -> CliResult {
    let mut signals = Signals::register()?;
    let axis = AxisId::parse(&a.axis)
        .ok_or_else(|| CliError::input(format!("--axis must be x or y, not {:?}", a.axis)))?;
    let (file_scale, cfg) = match &a.config {
        Some(p) => load_config(p)?,
        None => (None, ControllerConfig::default()),
    };
    let scale = a.time_scale.or(file_scale).unwrap_or(1.0);
    if !(scale.is_finite() && scale > 0.0) {
        return Err(CliError::input(format!(
            "--time-scale must be > 0, not {scale}"
        )));
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
    println!("{}", sim.endpoint());
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
    scale: f64,
    port: Option<PathBuf>,
) -> CliResult {
    let fail = |e: csmetro_hal::AxisError| CliError::failure(e.to_string());
    let (sim, clock, path) = match port {
        Some(p) => (None, None, p.display().to_string()),
        None => {
            let cfg = ControllerConfig::default();
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
    for _ in 0..round_trips.max(1) {
        let t = Instant::now();
        drv.position_um().await.map_err(fail)?;
        rt.push(t.elapsed().as_secs_f64() * 1e6);
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
    let out = json!({
        "transport": "pty",
        "round_trip_us": { "n": rt.len(), "median": percentile(&rt, 0.5), "p99": percentile(&rt, 0.99) },
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
    println!(
        "{}",
        serde_json::to_string_pretty(&out).map_err(|e| CliError::failure(e.to_string()))?
    );
    drop(drv);
    if let Some(sim) = sim {
        sim.shutdown().await;
    }
    Ok(ExitCode::SUCCESS)
}
