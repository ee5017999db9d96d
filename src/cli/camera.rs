//! `csmetro camera list|snap`: the cameras this build can reach, and one frame from one of them
//! (written as PNG, optionally decoded into the stage position).
//!
//! Exit codes: 0 done, 1 no camera found / camera failure, 2 bad input (flags, files, a backend
//! this build lacks), 3 frame rejected by the decoder (as `csmetro ppp decode`).
use std::net::Ipv4Addr;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Duration;

use clap::Subcommand;
use csmetro_camera::{
    list_cameras, open_camera, parse_guid, CameraBackend, CameraConfig, CameraId, PixelFormat,
};
use csmetro_hal::{Frame, Pixels};
use csmetro_ppp::render;
use csmetro_ppp::{write_png, Pose, PppConfig};

use super::ppp::EXIT_REJECTED;
use super::{CliError, CliResult};
use crate::campaign::spec::{Campaign, HardwareKind};

#[derive(clap::Args)]
pub struct Args {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Cameras on every backend this build has (Aravis: GigE / USB3 Vision; FireWire: IIDC).
    List,
    /// Grab one frame: print its figures, write it as PNG, decode the pattern in it.
    Snap(SnapArgs),
}

#[derive(clap::Args)]
struct SnapArgs {
    /// Camera: `ip:192.168.1.20` (or a bare IPv4), `serial:40123456`, `device_id:Basler-4012`,
    /// `guid:0x000a47010e0a1b2c` (FireWire), or `sim` (the simulated camera). Default: the
    /// campaign's camera, else the first camera `csmetro camera list` finds.
    #[arg(long)]
    id: Option<String>,
    /// Campaign file whose [hardware.camera], pattern and optics to use.
    #[arg(long, conflicts_with = "config")]
    campaign: Option<PathBuf>,
    /// TOML file with [pattern], [optics] and optional [decode] tables (as `csmetro ppp`).
    #[arg(long)]
    config: Option<PathBuf>,
    /// Exposure, µs (default: the campaign's, else 1000).
    #[arg(long)]
    exposure_us: Option<f64>,
    /// Pixel format asked of the camera: mono8 or mono16 (default: the campaign's, else mono8).
    #[arg(long)]
    pixel_format: Option<String>,
    /// Write the frame here (8- or 16-bit grayscale PNG).
    #[arg(long)]
    out: Option<PathBuf>,
    /// Decode the pattern: print x, y (µm), θ (mrad) and the decode figures.
    #[arg(long)]
    decode: bool,
    /// `--id sim`: stage x the simulated camera looks at, µm.
    #[arg(long, default_value_t = 5000.0, allow_negative_numbers = true)]
    sim_x_um: f64,
    /// `--id sim`: stage y, µm.
    #[arg(long, default_value_t = 2000.0, allow_negative_numbers = true)]
    sim_y_um: f64,
}

pub fn run(args: Args) -> CliResult {
    match args.command {
        Command::List => run_list(),
        Command::Snap(a) => run_snap(a),
    }
}

fn run_list() -> CliResult {
    let mut found = 0;
    for (backend, cams) in list_cameras() {
        match cams {
            Ok(cams) if cams.is_empty() => {
                let what = match backend {
                    CameraBackend::Aravis => "no GigE Vision / USB3 Vision camera found",
                    CameraBackend::Firewire => "no IIDC camera found",
                };
                outln!("{backend}: {what}");
            }
            Ok(cams) => {
                for c in cams {
                    found += 1;
                    outln!(
                        "{backend}: {}  [hardware.camera] backend = \"{backend}\", id = {}",
                        c.description,
                        id_toml(&c.id)
                    );
                }
            }
            Err(_) if !backend.compiled() => {
                outln!("{backend}: not in this build (rebuild with --features {backend})")
            }
            Err(e) => outln!("{backend}: {}", e.to_string().replace('\n', " ")),
        }
    }
    outln!(
        "sim: the simulated camera of kind = \"sim\" campaigns (`csmetro camera snap --id sim`)"
    );
    if found == 0 {
        return Err(CliError::failure(
            "no camera found on the backends this csmetro was built with",
        ));
    }
    Ok(ExitCode::SUCCESS)
}

/// The id as TOML, to paste into `[hardware.camera]`.
fn id_toml(id: &CameraId) -> String {
    let q = |s: &str| toml::Value::String(s.to_string()).to_string();
    match id {
        CameraId::Ip(ip) => format!("{{ ip = \"{ip}\" }}"),
        CameraId::Serial(s) => format!("{{ serial = {} }}", q(s)),
        CameraId::DeviceId(s) => format!("{{ device_id = {} }}", q(s)),
        CameraId::Guid(s) => format!("{{ guid = {} }}", q(s)),
    }
}

/// What `--id` names: the simulated camera, or a real one on a backend.
enum Target {
    Sim,
    Real(CameraBackend, CameraId),
}

fn parse_id(s: &str) -> Result<Target, CliError> {
    let bad = |m: String| CliError::input(format!("--id {s:?}: {m}"));
    let s = s.trim();
    if s == "sim" {
        return Ok(Target::Sim);
    }
    if let Ok(ip) = s.parse::<Ipv4Addr>() {
        return Ok(Target::Real(CameraBackend::Aravis, CameraId::Ip(ip)));
    }
    let Some((kind, v)) = s.split_once(':') else {
        return Ok(Target::Real(
            CameraBackend::Aravis,
            CameraId::DeviceId(s.to_string()),
        ));
    };
    let v = v.trim();
    Ok(match kind {
        "ip" => Target::Real(
            CameraBackend::Aravis,
            CameraId::Ip(
                v.parse()
                    .map_err(|_| bad(format!("{v:?} is not an IPv4 address")))?,
            ),
        ),
        "serial" => Target::Real(CameraBackend::Aravis, CameraId::Serial(v.to_string())),
        "device_id" => Target::Real(CameraBackend::Aravis, CameraId::DeviceId(v.to_string())),
        "guid" => {
            parse_guid(v).map_err(|e| bad(e.0))?;
            Target::Real(CameraBackend::Firewire, CameraId::Guid(v.to_string()))
        }
        // A GigE device id may itself contain colons (rare): keep the whole text.
        _ => Target::Real(CameraBackend::Aravis, CameraId::DeviceId(s.to_string())),
    })
}

fn load_ppp(path: &Path) -> Result<PppConfig, CliError> {
    let text = crate::tomlpos::read_bounded(path, crate::tomlpos::MAX_TOML_BYTES)
        .map_err(|e| CliError::input(format!("{}: {e}", path.display())))?;
    toml::from_str(&text).map_err(|e| CliError::input(format!("{}: {e}", path.display())))
}

fn run_snap(a: SnapArgs) -> CliResult {
    // Pattern, optics and (from a campaign) the camera.
    let (ppp, campaign_camera) = match &a.campaign {
        Some(p) => {
            let text = crate::tomlpos::read_bounded(p, crate::tomlpos::MAX_TOML_BYTES)
                .map_err(|e| CliError::input(format!("{}: {e}", p.display())))?;
            let base = p.parent().map(PathBuf::from).unwrap_or_default();
            // Validated as `csmetro run` would (a backend this build lacks is refused here).
            let c = Campaign::parse(&text, &p.display().to_string(), &base)
                .map_err(|e| CliError::input(e.to_string()))?;
            let h = &c.spec().hardware;
            let cam = match h.kind {
                HardwareKind::Real => h.camera.clone(),
                HardwareKind::Sim => None,
            };
            (
                PppConfig {
                    pattern: h.pattern.clone(),
                    optics: h.optics.clone(),
                    decode: None,
                },
                cam,
            )
        }
        None => (
            match &a.config {
                Some(p) => load_ppp(p)?,
                None => PppConfig::default(),
            },
            None,
        ),
    };
    ppp.optics.validate().map_err(CliError::input)?;
    if let Some(e) = a.exposure_us {
        if !(e.is_finite() && e > 0.0) {
            return Err(CliError::input("--exposure-us must be a positive number"));
        }
    }
    let format = match a.pixel_format.as_deref() {
        None => None,
        Some("mono8") => Some(PixelFormat::Mono8),
        Some("mono16") => Some(PixelFormat::Mono16),
        Some(other) => {
            return Err(CliError::input(format!(
                "--pixel-format {other:?}: mono8 or mono16"
            )))
        }
    };

    let target = match &a.id {
        Some(s) => Some(parse_id(s)?),
        None => None,
    };
    let frame = match (target, campaign_camera) {
        (Some(Target::Sim), _) => {
            let (x, y) = (a.sim_x_um, a.sim_y_um);
            if !(x.is_finite() && y.is_finite()) {
                return Err(CliError::input("--sim-x-um and --sim-y-um must be finite"));
            }
            let pattern = ppp.pattern().map_err(|e| CliError::input(e.to_string()))?;
            outln!(
                "camera: simulated ({}x{}, stage at x {x} µm, y {y} µm)",
                ppp.optics.width,
                ppp.optics.height
            );
            render(&pattern, &ppp.optics, Pose::new(x, y, 0.0), 1)
        }
        (Some(Target::Real(backend, id)), base) => {
            let mut cfg = base.unwrap_or_else(|| CameraConfig::new(id.clone(), 1000.0));
            cfg.backend = backend;
            cfg.id = id;
            grab_real(cfg, a.exposure_us, format)?
        }
        (None, Some(cfg)) => grab_real(cfg, a.exposure_us, format)?,
        (None, None) => {
            let first = list_cameras()
                .into_iter()
                .filter_map(|(_, r)| r.ok())
                .flatten()
                .next()
                .ok_or_else(|| {
                    CliError::failure(
                        "no camera found on the backends this csmetro was built with \
                         (`csmetro camera list`; `--id sim` for the simulated camera)",
                    )
                })?;
            let mut cfg = CameraConfig::new(first.id, 1000.0);
            cfg.backend = first.backend;
            grab_real(cfg, a.exposure_us, format)?
        }
    };
    print_frame(&frame);
    if let Some(out) = &a.out {
        write_png(out, &frame).map_err(|e| CliError::input(e.to_string()))?;
        outln!("wrote {}", out.display());
    }
    if !a.decode {
        return Ok(ExitCode::SUCCESS);
    }
    let decoder = ppp.decoder().map_err(|e| CliError::input(e.to_string()))?;
    let r = decoder.decode(&frame);
    if r.ok {
        outln!(
            "x_um {:.4} y_um {:.4} theta_mrad {:.4} period_px {:.5} decode_ms {:.2}",
            r.x_um,
            r.y_um,
            r.theta_mrad,
            r.period_px,
            r.decode_ms
        );
        Ok(ExitCode::SUCCESS)
    } else {
        outln!("rejected: {}", r.reason.as_deref().unwrap_or("unknown"));
        Ok(ExitCode::from(EXIT_REJECTED))
    }
}

fn grab_real(
    mut cfg: CameraConfig,
    exposure_us: Option<f64>,
    format: Option<PixelFormat>,
) -> Result<Frame, CliError> {
    if let Some(e) = exposure_us {
        cfg.exposure_us = e;
    }
    if let Some(f) = format {
        cfg.pixel_format = f;
    }
    // Settings that belong to the other backend go with the id's backend switch.
    cfg.validate()
        .map_err(|e| CliError::input(format!("camera: {e}")))?;
    if !cfg.backend.compiled() {
        return Err(CliError::input(format!(
            "{} needs the {b} camera backend: rebuild csmetro with --features {b}",
            cfg.id,
            b = cfg.backend.name()
        )));
    }
    let timeout = cfg.frame_timeout();
    let mut cam = open_camera(cfg).map_err(|e| CliError::failure(e.to_string()))?;
    outln!("camera: {}", cam.describe());
    cam.grab(timeout.max(Duration::from_millis(1)))
        .map_err(|e| CliError::failure(e.to_string()))
}

fn print_frame(f: &Frame) {
    let v = f.to_f32();
    let n = v.len().max(1) as f64;
    let (lo, hi, sum) = v
        .iter()
        .fold((f32::MAX, f32::MIN, 0.0f64), |(lo, hi, s), &p| {
            (lo.min(p), hi.max(p), s + f64::from(p))
        });
    let kind = match f.pixels {
        Pixels::Mono8(_) => "Mono8",
        Pixels::Mono16(_) => "Mono16",
    };
    outln!(
        "frame: {}x{} {kind} bit_depth {} timestamp_s {:.6} min {} max {} mean {:.2}",
        f.width,
        f.height,
        f.bit_depth,
        f.timestamp_s,
        if v.is_empty() { 0.0 } else { lo },
        if v.is_empty() { 0.0 } else { hi },
        sum / n
    );
}
