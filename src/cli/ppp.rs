//! `csmetro ppp`: render a simulated camera frame of the pseudo-periodic pattern, decode a
//! frame into the absolute stage position, and benchmark the decoder.
//!
//! Exit codes: 0 decoded, 2 bad input (flags, file), 3 frame rejected by the decoder
//! (JSON `"ok": false` with the reason), 1 anything else.
use std::path::PathBuf;
use std::process::ExitCode;

use clap::Subcommand;
use csmetro_ppp::render;
use csmetro_ppp::{png_from_bytes, selftest, write_png, DecodeResult, Pose, PppConfig};
use serde_json::json;

use super::{CliError, CliResult};

/// Largest PNG frame file read: a 2^24 px 16-bit frame stored uncompressed, with room.
const MAX_PNG_BYTES: u64 = 64 << 20;

/// Exit code of a frame the decoder rejected.
pub const EXIT_REJECTED: u8 = 3;

#[derive(clap::Args)]
pub struct Args {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Render a simulated camera frame of the pattern at a stage pose (PNG).
    Render(RenderArgs),
    /// Decode a frame (PNG, 8- or 16-bit grayscale) into x, y (µm) and θ (mrad).
    Decode(DecodeArgs),
    /// Decoder benchmark: timing, precision, step linearity, random-pose and degraded sweeps (one JSON object).
    Bench(BenchArgs),
}

#[derive(clap::Args)]
struct ConfigArg {
    /// TOML file with [pattern], [optics] and optional [decode] tables (defaults: the paper's setup).
    #[arg(long)]
    config: Option<PathBuf>,
}

impl ConfigArg {
    fn load(&self) -> Result<PppConfig, CliError> {
        let Some(path) = &self.config else {
            return Ok(PppConfig::default());
        };
        let text = crate::tomlpos::read_bounded(path, crate::tomlpos::MAX_TOML_BYTES)
            .map_err(|e| CliError::input(format!("{}: {e}", path.display())))?;
        toml::from_str(&text).map_err(|e| CliError::input(format!("{}: {e}", path.display())))
    }
}

#[derive(clap::Args)]
struct RenderArgs {
    /// Stage x, µm (pattern point at the image centre, relative to the pattern origin).
    #[arg(long, allow_negative_numbers = true)]
    x_um: f64,
    /// Stage y, µm.
    #[arg(long, allow_negative_numbers = true)]
    y_um: f64,
    /// In-plane rotation, mrad.
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true)]
    theta_mrad: f64,
    /// Gaussian PSF sigma, px (default: the config's, 1 px).
    #[arg(long)]
    blur_px: Option<f64>,
    /// Read noise, fraction of full scale (default: the config's, 0.01).
    #[arg(long)]
    noise: Option<f64>,
    /// Defocus pillbox radius, px.
    #[arg(long)]
    defocus_px: Option<f64>,
    /// Number of dust particles.
    #[arg(long)]
    dust: Option<usize>,
    /// Exposure gain (> 1 saturates).
    #[arg(long)]
    exposure: Option<f64>,
    /// Output bit depth, 8 or 12.
    #[arg(long)]
    bit_depth: Option<u8>,
    /// Noise and dust seed.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Output PNG.
    #[arg(long)]
    out: PathBuf,
    #[command(flatten)]
    config: ConfigArg,
}

#[derive(clap::Args)]
struct DecodeArgs {
    /// Frame to decode (PNG).
    frame: PathBuf,
    /// Print the full result as one JSON object.
    #[arg(long)]
    json: bool,
    #[command(flatten)]
    config: ConfigArg,
}

#[derive(clap::Args)]
struct BenchArgs {
    /// Decodes of one frame for the timing figures.
    #[arg(long, default_value_t = 300)]
    repeats: usize,
    /// Noise realisations at a fixed pose for the precision figure.
    #[arg(long, default_value_t = 50)]
    precision_frames: usize,
    /// Sub-pixel step for the linearity sweep over one period, px (0 skips it).
    #[arg(long, default_value_t = 0.05)]
    step_px: f64,
    /// Random poses at nominal image quality (absolute decode success rate).
    #[arg(long, default_value_t = 200)]
    poses: usize,
    /// Random degraded frames (blur, defocus, dust, saturation, low contrast, noise).
    #[arg(long, default_value_t = 200)]
    degraded: usize,
    /// Worker threads for the two sweeps (timing always runs on this one thread).
    #[arg(long, default_value_t = 1)]
    threads: usize,
    #[arg(long, default_value_t = 7)]
    seed: u64,
    #[command(flatten)]
    config: ConfigArg,
}

pub fn run(args: Args) -> CliResult {
    match args.command {
        Command::Render(a) => run_render(a),
        Command::Decode(a) => run_decode(a),
        Command::Bench(a) => run_bench(a),
    }
}

fn finite(name: &str, v: f64) -> Result<f64, CliError> {
    if v.is_finite() {
        Ok(v)
    } else {
        Err(CliError::input(format!("--{name} must be a finite number")))
    }
}

fn run_render(a: RenderArgs) -> CliResult {
    let mut cfg = a.config.load()?;
    let o = &mut cfg.optics;
    if let Some(v) = a.blur_px {
        o.psf_sigma_px = v;
    }
    if let Some(v) = a.noise {
        o.read_noise = v;
    }
    if let Some(v) = a.defocus_px {
        o.defocus_radius_px = v;
    }
    if let Some(v) = a.dust {
        o.dust_count = v;
    }
    if let Some(v) = a.exposure {
        o.exposure = v;
    }
    if let Some(v) = a.bit_depth {
        o.bit_depth = v;
    }
    o.validate().map_err(CliError::input)?;
    let pattern = cfg.pattern().map_err(|e| CliError::input(e.to_string()))?;
    let pose = Pose::new(
        finite("x-um", a.x_um)?,
        finite("y-um", a.y_um)?,
        finite("theta-mrad", a.theta_mrad)?,
    );
    let frame = render(&pattern, &cfg.optics, pose, a.seed);
    write_png(&a.out, &frame).map_err(|e| CliError::input(e.to_string()))?;
    Ok(ExitCode::SUCCESS)
}

fn run_decode(a: DecodeArgs) -> CliResult {
    let cfg = a.config.load()?;
    let decoder = cfg.decoder().map_err(|e| CliError::input(e.to_string()))?;
    // Through the shared bounded reader, as every other input file: a fifo or a device is
    // refused before it is opened (opening a fifo blocks until a writer comes).
    let shown = a.frame.display().to_string();
    let bytes = crate::tomlpos::read_bounded_bytes(&a.frame, MAX_PNG_BYTES)
        .map_err(|e| CliError::input(format!("{shown}: {e}")))?;
    let frame = png_from_bytes(&bytes, &shown).map_err(|e| CliError::input(e.to_string()))?;
    let r: DecodeResult = decoder.decode(&frame);
    if a.json {
        let mut v = serde_json::to_value(&r).map_err(|e| CliError::failure(e.to_string()))?;
        // Which frame this is about, for a rejection read among many.
        v["frame"] = json!(a.frame.display().to_string());
        outln!("{v}");
    } else if r.ok {
        outln!(
            "x_um {:.4} y_um {:.4} theta_mrad {:.4} period_px {:.5} decode_ms {:.2}",
            r.x_um,
            r.y_um,
            r.theta_mrad,
            r.period_px,
            r.decode_ms
        );
    } else {
        outln!(
            "rejected: {}: {}",
            a.frame.display(),
            r.reason.as_deref().unwrap_or("unknown")
        );
    }
    Ok(if r.ok {
        ExitCode::SUCCESS
    } else {
        ExitCode::from(EXIT_REJECTED)
    })
}

fn run_bench(a: BenchArgs) -> CliResult {
    let cfg = a.config.load()?;
    cfg.optics.validate().map_err(CliError::input)?;
    let decoder = cfg.decoder().map_err(|e| CliError::input(e.to_string()))?;
    let o = &cfg.optics;
    let timing = selftest::timing(&decoder, o, a.repeats, a.seed);
    let precision = selftest::precision(
        &decoder,
        o,
        Pose::new(3210.7, 1234.3, 3.0),
        a.precision_frames,
        a.seed,
    );
    let linearity = if a.step_px > 0.0 {
        let mut quiet = o.clone();
        quiet.read_noise = 0.0;
        Some(selftest::linearity(
            &decoder,
            &quiet,
            Pose::new(5000.0, 2000.0, 0.0),
            a.step_px,
            a.seed,
        ))
    } else {
        None
    };
    let poses = selftest::sweep(&decoder, o, a.poses, false, a.seed, a.threads);
    let degraded = selftest::sweep(
        &decoder,
        o,
        a.degraded,
        true,
        a.seed.wrapping_add(1),
        a.threads,
    );
    let out = json!({
        "frame": format!("{}x{} Mono{}", o.width, o.height, o.bit_depth),
        "decode_ms": timing,
        "precision_1px_psf": precision,
        "step_linearity_noise_free": linearity,
        "random_poses_nominal": poses,
        "degraded_sweep": degraded,
    });
    outln!("{out}");
    Ok(ExitCode::SUCCESS)
}
