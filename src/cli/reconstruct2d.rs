//! `csmetro reconstruct2d`: map samples CSV → the whole XY error map (+ one JSON object with `--json`).
use std::path::PathBuf;
use std::process::ExitCode;

use super::{CliError, CliResult};
use crate::grid::Grid;
use crate::recon2d::{self, Grid2, Method2};

#[derive(clap::Args)]
pub struct Args {
    /// Samples, CSV with header `x_um,y_um,ex_um,ey_um[,theta_urad]` (positions on the grids).
    #[arg(long)]
    samples: PathBuf,
    /// X grid START:STEP:END in µm, e.g. 0:5:9500.
    // A travel may start below zero: `--grid -20:5:20` is a grid, not a flag.
    #[arg(long, allow_hyphen_values = true)]
    grid_x: String,
    /// Y grid START:STEP:END in µm, e.g. 0:5:4200.
    // A travel may start below zero: `--grid -20:5:20` is a grid, not a flag.
    #[arg(long, allow_hyphen_values = true)]
    grid_y: String,
    /// auto | bp | physics | linear (auto: the smallest cross-validation error)
    #[arg(long, default_value = "auto")]
    method: String,
    /// Output CSV with the samples' header at every grid point, x fastest, then `u_ex_um,u_ey_um`
    /// (pointwise standard uncertainty, k = 1) (default: stdout unless --json).
    #[arg(long)]
    out: Option<PathBuf>,
    /// Print exactly one JSON object with the solve figures on stdout.
    #[arg(long)]
    json: bool,
}

pub fn run(a: Args) -> CliResult {
    let gx: Grid = a
        .grid_x
        .parse()
        .map_err(|e: String| CliError::input(format!("--grid-x: {e}")))?;
    let gy: Grid = a
        .grid_y
        .parse()
        .map_err(|e: String| CliError::input(format!("--grid-y: {e}")))?;
    let method: Method2 = a
        .method
        .parse()
        .map_err(|e: String| CliError::input(format!("--method: {e}")))?;
    // Before reading the samples: a grid too large is refused at once.
    let g = Grid2::new(gx, gy).map_err(|e| CliError::input(format!("--grid-x/--grid-y: {e}")))?;
    let s = recon2d::read_map_samples_csv(&a.samples, &g).map_err(CliError::input)?;
    // Samples that do not span the plane give a map and an error estimate that both look
    // fine and are not: refused, saying what to measure.
    if s.len() >= 3 {
        recon2d::coverage(&g, &s)
            .map_err(|e| CliError::input(format!("{}: {e}", a.samples.display())))?;
    }
    let (map, report) = recon2d::reconstruct(&g, &s, method)
        .map_err(|e| CliError::input(format!("{}: {e}", a.samples.display())))?;
    match &a.out {
        Some(path) => recon2d::write_map_csv(path, &g, &map)
            .map_err(|e| CliError::failure(format!("{}: cannot write: {e}", path.display())))?,
        None if !a.json => {
            let stdout = std::io::stdout();
            let mut w = std::io::BufWriter::new(stdout.lock());
            // A reader that stopped early (`| head`) got what it wanted.
            recon2d::write_map(&mut w, &g, &map)
                .or_else(|e| match e.kind() {
                    std::io::ErrorKind::BrokenPipe => Ok(()),
                    _ => Err(e),
                })
                .map_err(|e| CliError::failure(format!("stdout: {e}")))?;
        }
        None => {}
    }
    if a.json {
        let v = serde_json::to_value(&report).map_err(|e| CliError::failure(e.to_string()))?;
        outln!("{v}");
    }
    Ok(ExitCode::SUCCESS)
}
