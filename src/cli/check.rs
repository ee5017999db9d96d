//! `csmetro check CAMPAIGN.toml`: pre-flight without motion. Prints a table of checks (or
//! JSON); exit 0 only if every check passed, 2 when the campaign file must change, 1 when the
//! rig must. Nothing moves and nothing is recorded in the store.
use std::path::{Path, PathBuf};
use std::process::ExitCode;

use super::run::DEFAULT_DB;
use super::{CliError, CliResult};
use crate::campaign::preflight::{self, Class, Options, Report};
use crate::campaign::spec::Campaign;
use crate::campaign::stagelock;

#[derive(clap::Args)]
pub struct Args {
    /// Campaign file (TOML).
    campaign: PathBuf,
    /// The store the campaign would be recorded in: checked writable, left untouched.
    #[arg(long, env = "CSMETRO_DB", default_value = DEFAULT_DB)]
    db: PathBuf,
    /// Print the checks as one JSON object on stdout instead of the table.
    #[arg(long)]
    json: bool,
}

pub fn run(a: Args) -> CliResult {
    let mut report = Report::default();
    if let Some(c) = config_checks(&a.campaign, &mut report) {
        let rt = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(2)
            .enable_all()
            .build()
            .map_err(|e| CliError::failure(format!("tokio runtime: {e}")))?;
        // The stage must be free: the check talks to the same controllers a running campaign
        // drives.
        match stage_lock(
            &a.db,
            &c.spec().campaign.stage,
            stagelock::Scope::of(c.spec().hardware.kind),
        ) {
            Ok(lock) => {
                report.push(
                    "stage",
                    Class::Device,
                    Ok(format!(
                        "`{}` not driven by another process",
                        &c.spec().campaign.stage
                    )),
                );
                rt.block_on(preflight::check_devices(
                    &c,
                    Options { store: Some(&a.db) },
                    &mut report,
                ));
                drop(lock);
            }
            Err(e) => {
                report.push("stage", Class::Device, Err(e.to_string()));
                report.skip("devices", Class::Device, "the stage is busy");
            }
        }
    }
    if a.json {
        outln!("{}", report.json());
    } else {
        out!("{}", report.table());
    }
    let code = report.exit_code();
    if code != 0 {
        eprintln!("error: {}", report.error_message().replace('\n', " "));
    }
    Ok(ExitCode::from(code))
}

/// `config` (the file validates) and `outputs` (its output directory takes files); the
/// campaign when both pass.
fn config_checks(path: &Path, report: &mut Report) -> Option<Campaign> {
    let origin = path.display().to_string();
    let text = match crate::tomlpos::read_bounded(path, crate::tomlpos::MAX_TOML_BYTES) {
        Ok(t) => t,
        Err(e) => {
            report.push(
                "config",
                Class::Config,
                Err(format!("{origin}: cannot read: {e}")),
            );
            return None;
        }
    };
    let base = path.parent().map(Path::to_path_buf).unwrap_or_default();
    match Campaign::parse(&text, &origin, &base) {
        Ok(c) => report.push(
            "config",
            Class::Config,
            Ok(format!(
                "{origin}: valid, kind = \"{}\", {} planned measurements",
                match c.spec().hardware.kind {
                    crate::campaign::spec::HardwareKind::Sim => "sim",
                    crate::campaign::spec::HardwareKind::Real => "real",
                },
                crate::campaign::plan::plan(&c).total()
            )),
        ),
        Err(e) => {
            report.push("config", Class::Config, Err(e.to_string()));
            return None;
        }
    }
    // `load` is `parse` plus the probe of the output directory.
    match Campaign::load(path) {
        Ok(c) => {
            report.push(
                "outputs",
                Class::Config,
                Ok(format!("{} writable", c.spec().outputs.dir)),
            );
            Some(c)
        }
        Err(e) => {
            report.push("outputs", Class::Config, Err(e.to_string()));
            None
        }
    }
}

/// Takes the stage as `run` would; a store whose directory does not exist yet is used by no
/// process, so only the machine-wide lock matters (taken next to a temporary store path).
fn stage_lock(
    db: &Path,
    stage: &str,
    scope: stagelock::Scope,
) -> Result<stagelock::StageLock, stagelock::StageLockError> {
    let dir_exists = db
        .parent()
        .is_none_or(|d| d.as_os_str().is_empty() || d.is_dir());
    let store = if dir_exists {
        db.to_path_buf()
    } else {
        std::env::temp_dir().join("csmetro-check.db")
    };
    stagelock::try_lock_scoped(&store, stage, scope)
}
