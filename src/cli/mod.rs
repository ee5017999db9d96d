//! Command-line front ends. Each subcommand module exposes `Args` and `run`.
use std::process::ExitCode;

pub mod bench;
pub mod camera;
pub mod check;
pub mod client;
pub mod demo;
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

/// An error that ends a command: a one-line message and the process exit code.
#[derive(Debug)]
pub struct CliError {
    pub code: u8,
    pub message: String,
}

impl CliError {
    /// Bad input from the user (file, flag, data): exit code 2.
    pub fn input(message: impl Into<String>) -> Self {
        Self {
            code: 2,
            message: message.into(),
        }
    }
    /// Anything else that failed: exit code 1.
    pub fn failure(message: impl Into<String>) -> Self {
        Self {
            code: 1,
            message: message.into(),
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
            eprintln!("error: {}", e.message.replace('\n', " "));
            ExitCode::from(e.code)
        }
    }
}
