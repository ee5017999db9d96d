//! `csmetro demo`: reconstruction of a generated paper-like curve by every method, against the truth.
use std::process::ExitCode;

use super::bench::{accuracy, PAPER_TABLE_II};
use super::{CliError, CliResult};
use crate::recon::Method;

#[derive(clap::Args)]
pub struct Args {
    /// Number of curve seeds averaged.
    #[arg(long, default_value_t = 3)]
    seeds: u64,
    /// Print the rows as one JSON object instead of a table.
    #[arg(long)]
    json: bool,
}

pub fn run(a: Args) -> CliResult {
    let methods = [Method::Bp, Method::Linear, Method::Pchip, Method::Auto];
    let rows = accuracy(a.seeds, &[100, 300, 600, 900], &methods).map_err(CliError::failure)?;
    if a.json {
        outln!("{}", serde_json::json!({ "rows": rows }));
        return Ok(ExitCode::SUCCESS);
    }
    outln!("Reconstruction of a paper-like X-forward error curve (n = 1901, 0..9500 µm step 5 µm, noise 0.01 µm),");
    outln!(
        "mean over {} seeds; errors g - f against the simulator's ground truth, µm.\n",
        a.seeds
    );
    outln!(
        "{:>5} {:>8} {:>10} {:>10} {:>9} {:>11}",
        "m",
        "method",
        "mean|g-f|",
        "max|g-f|",
        "std",
        "solve ms"
    );
    for &(m, mean, max, std) in &PAPER_TABLE_II {
        for r in rows.iter().filter(|r| r.m == m) {
            outln!(
                "{:>5} {:>8} {:>10.4} {:>10.3} {:>9.4} {:>11.1}",
                r.m,
                r.method,
                r.mean_abs_um,
                r.max_abs_um,
                r.std_um,
                r.median_solve_ms
            );
        }
        outln!(
            "{:>5} {:>8} {:>10.4} {:>10.3} {:>9.4} {:>11}",
            m,
            "paper",
            mean,
            max,
            std,
            "-"
        );
    }
    Ok(ExitCode::SUCCESS)
}
