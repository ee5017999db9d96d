//! `csmetro generate`: a seeded paper-like error curve (full, noise-free) and a noisy sampled subset.
use std::path::PathBuf;
use std::process::ExitCode;

use csmetro_sim::ReferenceCurveParams;

use super::{CliError, CliResult};
use crate::grid::Grid;
use crate::samples::write_curve_csv;
use crate::sampling::{Design, DesignKind};
use crate::synth;

#[derive(clap::Args)]
pub struct Args {
    /// Seed of the curve (leadscrew phases, defects, roughness).
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Grid START:STEP:END in µm.
    #[arg(long, default_value = "0:5:9500", allow_hyphen_values = true)]
    grid: String,
    /// Number of samples m (random design unless --design says otherwise).
    #[arg(long, default_value_t = 600)]
    m: usize,
    /// random | jittered | full
    #[arg(long, default_value = "random")]
    design: String,
    /// Seed of the sampling design (default: the curve seed).
    #[arg(long)]
    design_seed: Option<u64>,
    /// White measurement noise σ added to the samples, µm.
    #[arg(long, default_value_t = 0.01)]
    noise_um: f64,
    /// Curve recipe overrides (TOML with fields of the reference recipe, e.g. `scale_ppm = 50`).
    #[arg(long)]
    params: Option<PathBuf>,
    /// Output: the full noise-free curve, `position_um,error_um`.
    #[arg(long)]
    out_full: PathBuf,
    /// Output: the sampled noisy subset, `position_um,error_um`.
    #[arg(long)]
    out_samples: PathBuf,
    /// Output: the stage model (TOML) that produced the curve.
    #[arg(long)]
    out_model: Option<PathBuf>,
}

pub fn run(a: Args) -> CliResult {
    let grid: Grid = a
        .grid
        .parse()
        .map_err(|e: String| CliError::input(format!("--grid: {e}")))?;
    let kind = match a.design.as_str() {
        "random" => DesignKind::Random,
        "jittered" => DesignKind::Jittered,
        "full" => DesignKind::Full,
        d => {
            return Err(CliError::input(format!(
                "--design: unknown design {d:?} (random, jittered, full)"
            )))
        }
    };
    let mut params = ReferenceCurveParams {
        travel_um: [grid.start_um, grid.end_um()],
        ..Default::default()
    };
    if let Some(path) = &a.params {
        let text = std::fs::read_to_string(path)
            .map_err(|e| CliError::input(format!("{}: {e}", path.display())))?;
        params = toml::from_str(&text)
            .map_err(|e| CliError::input(format!("{}: {e}", path.display())))?;
    }
    if !(a.noise_um.is_finite() && a.noise_um >= 0.0) {
        return Err(CliError::input("--noise-um must be a finite number >= 0"));
    }
    let design = Design::new(kind, a.m, a.design_seed.unwrap_or(a.seed));
    let p = synth::problem(&grid, a.seed, &params, &design, a.noise_um).map_err(CliError::input)?;
    let io = |path: &PathBuf, e: std::io::Error| {
        CliError::failure(format!("{}: cannot write: {e}", path.display()))
    };
    write_curve_csv(&a.out_full, &grid.positions(), &p.truth).map_err(|e| io(&a.out_full, e))?;
    let pos: Vec<f64> = p.samples.idx.iter().map(|&i| grid.position(i)).collect();
    write_curve_csv(&a.out_samples, &pos, &p.samples.values).map_err(|e| io(&a.out_samples, e))?;
    if let Some(path) = &a.out_model {
        std::fs::write(path, p.model.to_toml_string()).map_err(|e| io(path, e))?;
    }
    eprintln!(
        "wrote {} grid points to {} and {} samples ({:?}, seed {}) to {}",
        grid.n,
        a.out_full.display(),
        p.samples.len(),
        design.kind,
        design.seed,
        a.out_samples.display()
    );
    Ok(ExitCode::SUCCESS)
}
