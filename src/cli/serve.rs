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
    use tracing_subscriber::{layer::SubscriberExt, util::SubscriberInitExt, Layer};
    // RUST_LOG wins over the config file when it parses; a bad config value was refused at load.
    let targets = |s: &str| crate::api::config::parse_log_filter(s).ok();
    let filter = std::env::var("RUST_LOG")
        .ok()
        .and_then(|s| targets(&s))
        .or_else(|| targets(filter))
        .unwrap_or_else(|| {
            tracing_subscriber::filter::Targets::new().with_default(tracing::Level::INFO)
        });
    let journal = std::env::var_os("JOURNAL_STREAM").is_some();
    let fmt = tracing_subscriber::fmt::layer()
        .with_writer(std::io::stderr)
        .with_ansi(!journal && std::io::stderr().is_terminal());
    let registry = tracing_subscriber::registry();
    let r = if journal {
        registry
            .with(fmt.without_time().with_filter(filter))
            .try_init()
    } else {
        registry.with(fmt.with_filter(filter)).try_init()
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
