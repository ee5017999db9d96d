//! `csmetro export ID --format nexus --out F.nxs`: a stored campaign in a form a facility
//! loads (NeXus/HDF5; built with `--features nexus`).
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Instant;

use super::run::DEFAULT_DB;
use super::{CliError, CliResult};
use crate::export::Export;
use crate::store::Store;

#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Format {
    /// One NeXus (HDF5) file: samples, curves, ISO 230-2 figures, compensation, the campaign
    /// file and the rig's identity.
    Nexus,
}

#[derive(clap::Args)]
pub struct Args {
    /// The stored campaign.
    id: i64,
    #[arg(long, value_enum)]
    format: Format,
    /// The file to write (replaced if it exists).
    #[arg(long)]
    out: PathBuf,
    #[arg(long, env = "CSMETRO_DB", default_value = DEFAULT_DB)]
    db: PathBuf,
    /// One JSON object on stdout: the file, its size and the time taken.
    #[arg(long)]
    json: bool,
}

pub fn run(a: Args) -> CliResult {
    if !a.db.is_file() {
        return Err(CliError::input(format!(
            "{}: no store there (--db)",
            a.db.display()
        )));
    }
    let t0 = Instant::now();
    let store = Store::open(&a.db).map_err(|e| CliError::failure(e.to_string()))?;
    let e = Export::gather(&store, a.id).map_err(|e| match e {
        crate::export::ExportError::NoCampaign(_) => CliError::input(e.to_string()),
        _ => CliError::failure(e.to_string()),
    })?;
    drop(store);
    match a.format {
        Format::Nexus => write_nexus(&e, &a.out)?,
    }
    let bytes = std::fs::metadata(&a.out).map_or(0, |m| m.len());
    let secs = t0.elapsed().as_secs_f64();
    if a.json {
        outln!(
            "{}",
            serde_json::json!({"id": a.id, "format": "nexus", "out": a.out.display().to_string(),
                "bytes": bytes, "export_s": secs})
        );
    } else {
        outln!(
            "campaign {} → {} ({:.1} kB, {:.2} s)",
            a.id,
            a.out.display(),
            bytes as f64 / 1000.0,
            secs
        );
    }
    Ok(ExitCode::SUCCESS)
}

#[cfg(feature = "nexus")]
fn write_nexus(e: &Export, out: &std::path::Path) -> Result<(), CliError> {
    crate::export::nexus::write(e, out).map_err(|e| CliError::failure(e.to_string()))
}

#[cfg(not(feature = "nexus"))]
fn write_nexus(_: &Export, _: &std::path::Path) -> Result<(), CliError> {
    Err(CliError::input(
        "--format nexus needs a csmetro built with --features nexus (and Debian's libhdf5-dev)",
    ))
}
