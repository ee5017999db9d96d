//! `csmetro sim` (placeholder until its issue lands: it refuses to run).
use std::process::ExitCode;

use super::{CliError, CliResult};

#[derive(clap::Args)]
pub struct Args {}

pub fn run(_args: Args) -> CliResult {
    let _ = ExitCode::SUCCESS;
    Err(CliError::failure("not built yet"))
}
