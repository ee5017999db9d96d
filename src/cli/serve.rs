//! `csmetro serve --config config/csmetro.toml`: the HTTP/JSON service (see `csmetro::api`).
use std::io::IsTerminal;
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

use super::{CliError, CliResult};
use crate::api::{self, ServiceConfig};

#[derive(clap::Args)]
pub struct Args {
    /// Service configuration (TOML): [server] bind/token, [storage] db/results_dir, [log] filter.
    #[arg(long, env = "CSMETRO_CONFIG", default_value = "config/csmetro.toml")]
    config: PathBuf,
}

/// Logs to stderr: the journal captures it under systemd, and stamps it itself.
fn init_tracing(filter: &str) {
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new(filter));
    let journal = std::env::var_os("JOURNAL_STREAM").is_some();
    let b = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .with_ansi(!journal && std::io::stderr().is_terminal());
    let r = if journal {
        b.without_time().try_init()
    } else {
        b.try_init()
    };
    if let Err(e) = r {
        eprintln!("warning: logging not set up: {e}");
    }
}

pub fn run(a: Args) -> CliResult {
    let cfg = ServiceConfig::load(&a.config).map_err(|e| CliError::input(e.to_string()))?;
    init_tracing(&cfg.log_filter);
    let rt = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
        .map_err(|e| CliError::failure(e.to_string()))?;
    let r = rt.block_on(api::run(cfg));
    // A reconstruction still running on a blocking thread must not hold the exit.
    rt.shutdown_timeout(Duration::from_secs(2));
    r.map(|()| ExitCode::SUCCESS).map_err(CliError::failure)
}
