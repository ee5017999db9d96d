//! Command-line front ends. Each subcommand module exposes `Args` and `run`.
use std::process::ExitCode;
use std::sync::atomic::{AtomicBool, Ordering};

/// `println!` for command output that never panics: when the reader goes away
/// (`csmetro reconstruct | head`) the output ends, not the command; a campaign must still stop
/// its motion and store its results, and nothing else needs a backtrace.
macro_rules! outln {
    () => {
        $crate::cli::write_out(format_args!("\n"))
    };
    ($($t:tt)*) => {
        $crate::cli::write_out(format_args!("{}\n", format_args!($($t)*)))
    };
}

/// `print!` counterpart of [`outln!`].
macro_rules! out {
    ($($t:tt)*) => {
        $crate::cli::write_out(format_args!($($t)*))
    };
}

pub mod bench;
pub mod camera;
pub mod check;
pub mod client;
pub mod demo;
pub mod export;
pub mod gap;
pub mod generate;
pub mod move_cmd;
pub mod ppp;
pub mod reconstruct;
pub mod reconstruct2d;
pub mod run;
pub mod serve;
pub mod sim;
pub mod soak;
pub mod verify;

static STDOUT_CLOSED: AtomicBool = AtomicBool::new(false);

/// Writes command output to stdout; after the first failed write the rest is dropped (a closed
/// pipe silently, anything else with one warning on stderr).
pub fn write_out(args: std::fmt::Arguments<'_>) {
    use std::io::Write;
    if STDOUT_CLOSED.load(Ordering::Relaxed) {
        return;
    }
    if let Err(e) = std::io::stdout().lock().write_fmt(args) {
        STDOUT_CLOSED.store(true, Ordering::Relaxed);
        if e.kind() != std::io::ErrorKind::BrokenPipe {
            eprintln!("warning: standard output: {e}; further output dropped");
        }
    }
}

/// An error that ends a command: a one-line message and the process exit code.
#[derive(Debug)]
pub struct CliError {
    pub code: u8,
    pub message: String,
}

impl CliError {
    /// Bad input from the user (file, flag, data): exit code 2.
    pub fn input(message: impl std::fmt::Display) -> Self {
        Self {
            code: 2,
            message: message.to_string(),
        }
    }
    /// Anything else that failed: exit code 1.
    pub fn failure(message: impl std::fmt::Display) -> Self {
        Self {
            code: 1,
            message: message.to_string(),
        }
    }
}

impl From<anyhow::Error> for CliError {
    fn from(e: anyhow::Error) -> Self {
        Self::failure(format!("{e:#}"))
    }
}

pub type CliResult = Result<ExitCode, CliError>;

/// Prints the error on one line of stderr and maps it to the exit code.
pub fn finish(result: CliResult) -> ExitCode {
    match result {
        Ok(code) => code,
        Err(e) => {
            eprintln!(
                "error: {}",
                crate::types::shorten_numbers(&e.message.replace('\n', " "))
            );
            ExitCode::from(e.code)
        }
    }
}
