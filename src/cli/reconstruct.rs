//! `csmetro reconstruct`: samples CSV → full curve CSV (+ one JSON object with `--json`).
use std::path::PathBuf;
use std::process::ExitCode;

use super::{CliError, CliResult};
use crate::grid::Grid;
use crate::noise::NoiseFloor;
use crate::recon::{self, Method, ReconSettings, Solver};
use crate::samples;

#[derive(clap::Args)]
pub struct Args {
    /// Samples, CSV with header `position_um,error_um` (positions on the grid), or a results'
    /// `samples.csv` / `verify/samples.csv` (one curve: see --axis, --direction, --phase).
    #[arg(long)]
    samples: PathBuf,
    /// In a results' samples file: the moving axis of the curve (x or y).
    #[arg(long)]
    axis: Option<String>,
    /// In a results' samples file: the approach direction of the curve (forward or backward).
    #[arg(long)]
    direction: Option<String>,
    /// In a results' samples file: only the CS sample (cs) or the full scan (full); default both.
    #[arg(long)]
    phase: Option<String>,
    /// Grid START:STEP:END in µm, e.g. 0:5:9500.
    // A travel may start below zero: `--grid -20:5:20` is a grid, not a flag.
    #[arg(long, allow_hyphen_values = true)]
    grid: String,
    /// auto | bp | bpdn | pchip | linear | physics
    #[arg(long, default_value = "auto")]
    method: String,
    /// fast | clarabel (bp and bpdn only).
    #[arg(long, default_value = "fast")]
    solver: String,
    /// Sensor noise σ in µm (BPDN radius σ·√m; nugget of the physics model). Raised to what
    /// the file's repeated cycles or frames (`frame_sd_*_um`) show when clearly below it,
    /// lowered when the held-out residuals cannot hold it.
    #[arg(long, default_value_t = 0.01)]
    noise_um: f64,
    /// Leadscrew thread pitch in µm, if known: a hint for the physics model, which otherwise
    /// (and in addition) uses the periods it finds in the samples.
    #[arg(long)]
    pitch_um: Option<f64>,
    /// BP with more samples than the exact finish takes (m > 2000): stop at this certified
    /// relative duality gap (||θ||₁ - hᵀy) / ||θ||₁. Below 2000 samples BP is solved exactly.
    /// BPDN: its active set stops at a 1e-9 gap; its ADMM fallback (m > 2000, or when the active
    /// set fails) at this one. JSON `relative_gap` reports the gap reached.
    #[arg(long, default_value_t = 1e-3)]
    gap_tol: f64,
    /// Output CSV `position_um,error_um,u_um` at every grid point, u the pointwise standard
    /// uncertainty (k = 1; the column is left out for bp/bpdn, which have none) (default: stdout
    /// unless --json).
    #[arg(long)]
    out: Option<PathBuf>,
    /// Print exactly one JSON object with the solve figures on stdout.
    #[arg(long)]
    json: bool,
}

pub fn run(a: Args) -> CliResult {
    let grid: Grid = a
        .grid
        .parse()
        .map_err(|e: String| CliError::input(format!("--grid: {e}")))?;
    let method: Method = a
        .method
        .parse()
        .map_err(|e: String| CliError::input(format!("--method: {e}")))?;
    let solver: Solver = a
        .solver
        .parse()
        .map_err(|e: String| CliError::input(format!("--solver: {e}")))?;
    if !(a.noise_um.is_finite() && a.noise_um >= 0.0) {
        return Err(CliError::input("--noise-um must be a finite number >= 0"));
    }
    if a.pitch_um.is_some_and(|p| !(p.is_finite() && p > 0.0)) {
        return Err(CliError::input("--pitch-um must be a positive number"));
    }
    if !(a.gap_tol.is_finite() && a.gap_tol > 0.0 && a.gap_tol < 1.0) {
        return Err(CliError::input("--gap-tol must be a number in (0, 1)"));
    }
    // Before reading the samples: a grid too large for the method is refused at once.
    crate::recon::limits::check_solve_size(method, solver, grid.n, 2)
        .map_err(|e| CliError::input(format!("--grid: {e}")))?;
    let sel = select(&a)?;
    let (s, scatter) =
        samples::read_samples_csv(&a.samples, &grid, &sel).map_err(CliError::input)?;
    // Repeated cycles of a position show a sample's own noise: a told σ below it is raised.
    let noise = NoiseFloor::from_scatter(a.noise_um, &scatter.repeats);
    warn_raised(&a.samples, &noise, "repeated cycles'", "repeats'");
    // A campaign's frames show the camera's share: a σ still below it is raised to it.
    let frames = NoiseFloor::from_scatter(noise.used_um, &scatter.frames);
    warn_raised(&a.samples, &frames, "frames'", "frames'");
    crate::recon::limits::check_solve_size(method, solver, grid.n, s.len())
        .map_err(|e| CliError::input(format!("{}: {e}", a.samples.display())))?;
    if s.len() > grid.n {
        return Err(CliError::input(format!(
            "{}: {} samples but the grid has only {} points",
            a.samples.display(),
            s.len(),
            grid.n
        )));
    }
    let mut settings = ReconSettings {
        method,
        solver,
        noise_um: frames.used_um,
        pitch_um: a.pitch_um,
        ..Default::default()
    };
    settings.fast.gap_tol = a.gap_tol;
    let r = recon::reconstruct(&grid, &s, &settings)
        .map_err(|e| CliError::input(format!("{}: {e}", a.samples.display())))?;
    if r.noise_um < settings.noise_um {
        eprintln!(
            "warning: {}: --noise-um {} µm is more than the held-out residuals allow; the curve \
             uses {:.4} µm",
            a.samples.display(),
            settings.noise_um,
            r.noise_um
        );
    }
    let positions = grid.positions();
    match &a.out {
        Some(path) => samples::write_curve_u_csv(path, &positions, &r.values, &r.u_um)
            .map_err(|e| CliError::failure(format!("{}: cannot write: {e}", path.display())))?,
        None if !a.json => {
            out!("{}", samples::curve_csv(&positions, &r.values, &r.u_um));
        }
        None => {}
    }
    if a.json {
        let mut v = serde_json::to_value(&r).map_err(|e| CliError::failure(e.to_string()))?;
        v["noise_told_um"] = noise.told_um.into();
        v["repeat_noise_um"] = noise.measured_um.into();
        v["repeat_noise_dof"] = noise.dof.into();
        v["frame_noise_um"] = frames.measured_um.into();
        v["frame_noise_dof"] = frames.dof.into();
        outln!("{v}");
    }
    Ok(ExitCode::SUCCESS)
}

/// The warning that a σ told below the `scatter` of the file's `source` was raised to it.
fn warn_raised(path: &std::path::Path, f: &NoiseFloor, scatter: &str, source: &str) {
    if f.changed() {
        eprintln!(
            "warning: {}: --noise-um {} µm is below the {scatter} scatter ({:.4} µm, {} degrees of \
             freedom); the curve uses the {source}",
            path.display(),
            f.told_um,
            f.used_um,
            f.dof
        );
    }
}

/// `--axis`, `--direction`, `--phase` as a selection of one curve.
fn select(a: &Args) -> Result<samples::Select, CliError> {
    use crate::types::{AxisId, Direction, Phase};
    let axis = match a.axis.as_deref() {
        Some(s) => {
            Some(AxisId::parse(s).ok_or_else(|| CliError::input(format!("--axis {s:?}: x or y")))?)
        }
        None => None,
    };
    let direction = match a.direction.as_deref() {
        None => None,
        Some("forward") => Some(Direction::Forward),
        Some("backward") => Some(Direction::Backward),
        Some(s) => {
            return Err(CliError::input(format!(
                "--direction {s:?}: forward or backward"
            )))
        }
    };
    let phase = match a.phase.as_deref() {
        None => None,
        Some(s) => match Phase::parse(s) {
            Some(p @ (Phase::Cs | Phase::Full)) => Some(p),
            _ => return Err(CliError::input(format!("--phase {s:?}: cs or full"))),
        },
    };
    Ok(samples::Select {
        axis,
        direction,
        phase,
    })
}
