//! `csmetro sim rig --config SIM.toml`: a whole simulated rig in one process. Two simulated
//! C-863s (TCP or pty) drive one simulated XY stage, and with the `aravis` feature a GigE
//! Vision camera on a loopback address (Aravis's fake camera) draws the pattern at the stage's
//! true position. A `kind = "real"` campaign pointed at it runs unchanged; `arv-tool-0.8` and
//! other GigE Vision clients see an ordinary camera.
//!
//! The first stdout lines say where each device is, then `ready`:
//! ```text
//! x: tcp 127.0.0.1:50863
//! y: tcp 127.0.0.1:50864
//! camera: gige 127.0.0.1 serial CSMRIG01 device Aravis-Fake-CSMRIG01
//! ready
//! ```
use std::net::{Ipv4Addr, SocketAddr};
use std::path::{Path, PathBuf};
use std::process::ExitCode;

use csmetro_ppp::{Optics, PatternConfig};
use csmetro_sim::SimStage;
use csmetro_sim::{AxisId, StageModel};
use csmetro_sim::{ControllerConfig, SimController};
use serde::Deserialize;

use super::{CliError, CliResult, Signals};

#[derive(clap::Args)]
pub(super) struct RigArgs {
    /// Rig file (TOML): `time_scale`, `model`, `[x]` and `[y]` (where each controller serves,
    /// its `[x.controller]` settings), `[camera]`.
    #[arg(long)]
    config: PathBuf,
    /// At shutdown, write every command each controller received to this file
    /// (`x<TAB>command` per line): what the rig was asked to do.
    #[arg(long)]
    command_log: Option<PathBuf>,
}

/// Longest rig file.
const MAX_RIG_BYTES: u64 = 1 << 20;

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RigFile {
    /// Simulated physical seconds per real second (the stage moves this many times faster).
    #[serde(default = "one")]
    time_scale: f64,
    /// Stage model TOML (relative to the rig file); default: an ideal stage.
    model: Option<String>,
    x: RigAxis,
    y: RigAxis,
    camera: Option<RigCamera>,
}

fn one() -> f64 {
    1.0
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RigAxis {
    /// Serve over TCP at this address (port 0 picks a free one).
    tcp: Option<SocketAddr>,
    /// Serve over a pseudo-terminal instead.
    #[serde(default)]
    pty: bool,
    /// With `pty`: the stable path (symlink to the pty) to create.
    link: Option<PathBuf>,
    /// The controller's settings (`travel_mm`, `start_mm`, velocities, faults, ...).
    #[serde(default)]
    controller: ControllerConfig,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
#[cfg_attr(not(feature = "aravis"), allow(dead_code))]
struct RigCamera {
    /// Loopback address the GigE Vision camera serves on (GVCP port 3956).
    #[serde(default = "localhost")]
    ip: Ipv4Addr,
    /// Serial number (1 to 15 characters).
    #[serde(default = "default_serial")]
    serial: String,
    /// Sensor size, pixels.
    #[serde(default = "default_width")]
    width: u32,
    #[serde(default = "default_height")]
    height: u32,
    /// The pattern on the stage.
    #[serde(default)]
    pattern: PatternConfig,
    /// How frames are drawn (pixel pitch, magnification, blur, noise); the sensor size wins.
    #[serde(default)]
    optics: Optics,
    /// Seed of the per-frame rendering noise and of the stage model's white noise.
    #[serde(default = "one_u64")]
    seed: u64,
}

fn localhost() -> Ipv4Addr {
    Ipv4Addr::LOCALHOST
}
fn default_serial() -> String {
    "CSMRIG01".into()
}
fn default_width() -> u32 {
    1024
}
fn default_height() -> u32 {
    768
}
fn one_u64() -> u64 {
    1
}

fn load(path: &Path) -> Result<RigFile, CliError> {
    let shown = path.display();
    let text = crate::tomlpos::read_bounded(path, MAX_RIG_BYTES)
        .map_err(|e| CliError::input(format!("{shown}: {e}")))?;
    let rig: RigFile = toml::from_str(&text).map_err(|e| {
        let t = crate::tomlpos::TomlError::from_toml(&text, &shown.to_string(), &e);
        CliError::input(t.to_string())
    })?;
    if let Err(m) = csmetro_sim::check_time_scale(rig.time_scale) {
        let line = crate::tomlpos::span_of(&text, "time_scale").map_or(String::new(), |r| {
            format!(":{}", crate::tomlpos::line_of(&text, r.start))
        });
        return Err(CliError::input(format!("{shown}{line}: time_scale: {m}")));
    }
    for (name, a) in [("x", &rig.x), ("y", &rig.y)] {
        if a.tcp.is_some() == a.pty {
            return Err(CliError::input(format!(
                "{shown}: [{name}] needs exactly one of `tcp = \"127.0.0.1:PORT\"` or `pty = true`"
            )));
        }
        if a.link.is_some() && !a.pty {
            return Err(CliError::input(format!(
                "{shown}: [{name}] `link` needs `pty = true`"
            )));
        }
        let c = &a.controller;
        let [lo, hi] = c.travel_mm;
        if !(lo.is_finite() && hi.is_finite() && lo < hi && (lo..=hi).contains(&c.start_mm)) {
            return Err(CliError::input(format!(
                "{shown}: [{name}.controller] travel_mm = [lo, hi] with lo < hi and start_mm inside"
            )));
        }
        if let Some(rf) = &c.random_faults {
            rf.validate().map_err(|e| {
                CliError::input(format!("{shown}: [{name}.controller.random_faults]: {e}"))
            })?;
        }
    }
    if let Some(cam) = &rig.camera {
        let mut o = cam.optics.clone();
        o.width = cam.width as usize;
        o.height = cam.height as usize;
        o.validate()
            .map_err(|e| CliError::input(format!("{shown}: [camera.optics]: {e}")))?;
        csmetro_ppp::Pattern::new(cam.pattern.clone())
            .map_err(|e| CliError::input(format!("{shown}: [camera.pattern]: {e}")))?;
    }
    Ok(rig)
}

pub(super) async fn rig(a: RigArgs) -> CliResult {
    let mut signals = Signals::register()?;
    let file = load(&a.config)?;
    let model = match &file.model {
        Some(p) => {
            let base = a.config.parent().unwrap_or(Path::new(""));
            let path = base.join(p);
            StageModel::load(&path).map_err(|e| CliError::input(e.to_string()))?
        }
        None => StageModel::default(),
    };
    let stage = SimStage::new(
        model,
        file.time_scale,
        [file.x.controller.start_mm, file.y.controller.start_mm],
        file.x.controller.velocity_mm_s,
        file.x.controller.acceleration_mm_s2,
    );
    let mut sims = Vec::new();
    for (axis, ax) in [(AxisId::X, &file.x), (AxisId::Y, &file.y)] {
        let cfg = ax.controller.clone();
        let sim = match ax.tcp {
            Some(addr) => SimController::start_tcp(stage.clone(), axis, cfg, addr).await,
            None => SimController::start_pty(stage.clone(), axis, cfg, ax.link.clone()).await,
        }
        .map_err(|e| CliError::failure(format!("cannot serve the {axis} controller: {e}")))?;
        sims.push((axis, sim));
    }
    let camera = start_camera(&file, &stage)?;
    for (axis, sim) in &sims {
        let at = match sim.endpoint() {
            csmetro_sim::Endpoint::Tcp(a) => format!("tcp {a}"),
            csmetro_sim::Endpoint::Pty(p) => format!("pty {}", p.display()),
        };
        outln!("{axis}: {at}");
    }
    outln!("camera: {}", camera.line);
    outln!("ready");
    eprintln!(
        "simulated rig: 2 x C-863.11 (time scale {}), camera {}; SIGINT or SIGTERM stops it",
        file.time_scale, camera.line
    );
    signals.wait().await;
    drop(camera);
    let mut log = String::new();
    for (axis, sim) in sims {
        for cmd in sim.controller().command_log() {
            log.push_str(&format!("{axis}\t{cmd}\n"));
        }
        sim.shutdown().await;
    }
    if let Some(p) = &a.command_log {
        std::fs::write(p, log).map_err(|e| CliError::failure(format!("{}: {e}", p.display())))?;
    }
    Ok(ExitCode::SUCCESS)
}

/// The rig's camera, kept alive while it serves, and the line that says where it is.
struct RigCameraHandle {
    line: String,
    #[cfg(feature = "aravis")]
    _fake: Option<csmetro_camera::FakeGvCamera>,
}

#[cfg(feature = "aravis")]
fn start_camera(file: &RigFile, stage: &SimStage) -> Result<RigCameraHandle, CliError> {
    use std::sync::atomic::{AtomicU64, Ordering};
    use std::sync::{Arc, Mutex};

    use csmetro_camera::{FakeGvCamera, FakeGvOptions, FrameSource};
    use csmetro_hal::Pixels;
    use csmetro_ppp::render;
    use csmetro_ppp::{Pattern, Pose};
    use rand::SeedableRng;
    use rand_distr::Distribution;

    let Some(cam) = &file.camera else {
        return Ok(RigCameraHandle {
            line: "none (no [camera] in the rig file)".into(),
            _fake: None,
        });
    };
    let pattern = Pattern::new(cam.pattern.clone()).map_err(|e| CliError::input(e.to_string()))?;
    let base = cam.optics.clone();
    let seen = stage.clone();
    let noise = stage.model().noise_sigma_um().max(0.0);
    let normal = rand_distr::Normal::new(0.0, noise).map_err(|e| CliError::input(e.to_string()))?;
    let rng = Mutex::new(rand_chacha::ChaCha8Rng::seed_from_u64(cam.seed));
    let frames = AtomicU64::new(0);
    let seed = cam.seed;
    // The true position at the moment the frame is drawn, plus the model's white noise (as
    // the simulated camera of a `kind = "sim"` campaign sees it).
    let source: FrameSource = Arc::new(move |buf: &mut [u8], w: usize, h: usize| {
        let (mut x, mut y) = seen.true_position_um();
        if noise > 0.0 {
            let mut r = rng.lock().unwrap_or_else(|e| e.into_inner());
            x += normal.sample(&mut *r);
            y += normal.sample(&mut *r);
        }
        let optics = Optics {
            width: w,
            height: h,
            bit_depth: 8,
            ..base.clone()
        };
        let k = frames.fetch_add(1, Ordering::SeqCst);
        let f = render(
            &pattern,
            &optics,
            Pose::new(x, y, 0.0),
            seed.wrapping_add(k),
        );
        if let Pixels::Mono8(p) = f.pixels {
            let n = p.len().min(buf.len());
            buf[..n].copy_from_slice(&p[..n]);
        }
    });
    let fake = FakeGvCamera::start_with(
        FakeGvOptions {
            ip: cam.ip,
            serial: cam.serial.clone(),
            sensor_width: cam.width,
            sensor_height: cam.height,
            ..FakeGvOptions::default()
        },
        source,
    )
    .map_err(|e| CliError::failure(format!("camera: {e}")))?;
    Ok(RigCameraHandle {
        line: format!(
            "gige {} serial {} device {}",
            fake.ip(),
            fake.serial(),
            fake.device_id()
        ),
        _fake: Some(fake),
    })
}

#[cfg(not(feature = "aravis"))]
fn start_camera(file: &RigFile, _: &SimStage) -> Result<RigCameraHandle, CliError> {
    Ok(RigCameraHandle {
        line: if file.camera.is_some() {
            "none (this csmetro was built without the `aravis` feature: rebuild with \
             `--features aravis` to serve the GigE Vision camera)"
                .into()
        } else {
            "none (no [camera] in the rig file)".into()
        },
    })
}
