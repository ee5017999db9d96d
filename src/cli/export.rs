//! `csmetro export ID --format nexus --out F.nxs`: a stored campaign in a form a facility
//! loads (NeXus/HDF5; built with `--features nexus`). `--format linuxcnc|twincat-lsec|csv
//! --axis x|y --out F`: one axis's compensation as a bilateral table a motion controller loads.
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Instant;

use super::run::DEFAULT_DB;
use super::{CliError, CliResult};
use crate::export::controller::{self, Controller, LsecUnit};
use crate::export::Export;
use crate::store::Store;
use crate::types::AxisId;

#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Format {
    /// One NeXus (HDF5) file: samples, curves, ISO 230-2 figures, compensation, the campaign
    /// file and the rig's identity.
    Nexus,
    /// LinuxCNC screw compensation (`[JOINT_n] COMP_FILE`, `COMP_FILE_TYPE = 1`), mm.
    Linuxcnc,
    /// Beckhoff TwinCAT CNC leadscrew error compensation list (`kw.ssfk.*`), bilateral, 0.1 µm.
    TwincatLsec,
    /// `nominal_um,forward_correction_um,backward_correction_um`.
    Csv,
}

impl Format {
    fn controller(self) -> Option<Controller> {
        match self {
            Format::Nexus => None,
            Format::Linuxcnc => Some(Controller::LinuxCnc),
            Format::TwincatLsec => Some(Controller::TwinCatLsec),
            Format::Csv => Some(Controller::Csv),
        }
    }
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
    /// The axis whose compensation a controller table holds (linuxcnc, twincat-lsec, csv).
    #[arg(long)]
    axis: Option<String>,
    /// Largest allowed |controller command - `csmetro move` command| in the table's range, µm
    /// (default 0.01; twincat-lsec 0.06: its values are integers of 0.1 µm).
    #[arg(long, allow_hyphen_values = true)]
    max_deviation_um: Option<f64>,
    /// twincat-lsec only: lengths in encoder increments of this many µm (`kw.ssfk.unit = 0`,
    /// the axis's increment from its CNC parameters) instead of 0.1 µm; default deviation
    /// bound half an increment + 0.01 µm.
    #[arg(long, allow_hyphen_values = true)]
    increment_um: Option<f64>,
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
    if let Some(f) = a.format.controller() {
        return controller_table(&a, &store, f, t0);
    }
    if a.axis.is_some() || a.max_deviation_um.is_some() || a.increment_um.is_some() {
        return Err(CliError::input(
            "--axis, --max-deviation-um and --increment-um apply to --format linuxcnc, twincat-lsec and csv",
        ));
    }
    let e = Export::gather(&store, a.id).map_err(|e| match e {
        crate::export::ExportError::NoCampaign(_) => CliError::input(e.to_string()),
        _ => CliError::failure(e.to_string()),
    })?;
    drop(store);
    write_nexus(&e, &a.out)?;
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

/// One axis's compensation of campaign `a.id` as a controller table in `a.out`; every refusal
/// (no such axis, no table, a map campaign, a table the format cannot hold) is exit 2 and
/// writes nothing.
fn controller_table(a: &Args, store: &Store, f: Controller, t0: Instant) -> CliResult {
    let format = f.as_str();
    let axis = match a.axis.as_deref() {
        Some(s) => AxisId::parse(s)
            .ok_or_else(|| CliError::input(format!("--axis {s:?}: must be x or y")))?,
        None => {
            return Err(CliError::input(format!(
                "--format {format} needs --axis x|y: its table holds one axis (both directions)"
            )))
        }
    };
    let unit = match a.increment_um {
        None => LsecUnit::Metric,
        Some(_) if f != Controller::TwinCatLsec => {
            return Err(CliError::input(
                "--increment-um applies to --format twincat-lsec (its kw.ssfk.unit = 0)",
            ))
        }
        Some(q) => {
            let (lo, hi) = LsecUnit::INCREMENT_RANGE_UM;
            if !(q.is_finite() && (lo..=hi).contains(&q)) {
                return Err(CliError::input(format!(
                    "--increment-um must be a number of µm in [{lo}, {hi}]"
                )));
            }
            LsecUnit::Increments(q)
        }
    };
    let max_dev = a.max_deviation_um.unwrap_or_else(|| match f {
        Controller::TwinCatLsec => unit.default_max_deviation_um(),
        _ => f.default_max_deviation_um(),
    });
    if !(max_dev.is_finite() && max_dev > 0.0) {
        return Err(CliError::input(
            "--max-deviation-um must be a positive number of µm",
        ));
    }
    let id = a.id;
    let row = store
        .campaign(id)
        .map_err(|e| CliError::failure(e.to_string()))?
        .ok_or_else(|| CliError::input(format!("no campaign {id} in the store")))?;
    let is_map = row
        .spec_toml
        .parse::<toml::Table>()
        .is_ok_and(|t| t.contains_key("map"));
    if is_map {
        return Err(CliError::input(format!(
            "campaign {id} is an XY map campaign: its compensation_map_*.csv corrects both axes over the plane, not one axis a controller table holds"
        )));
    }
    let comp = crate::campaign::compensate::stored(store, id, &row.stage)
        .map_err(|e| CliError::input(e.to_string()))?;
    let table = comp.table(axis).ok_or_else(|| {
        let have: Vec<&str> = [AxisId::X, AxisId::Y]
            .into_iter()
            .filter(|&x| comp.table(x).is_some())
            .map(AxisId::as_str)
            .collect();
        CliError::input(format!(
            "campaign {id}: axis {axis} was not characterised (its compensation has axis {})",
            have.join(", ")
        ))
    })?;
    let w = controller::write_in(table, f, unit, id, max_dev)
        .map_err(|e| CliError::input(e.to_string()))?;
    write_new(&a.out, w.text.as_bytes())?;
    let secs = t0.elapsed().as_secs_f64();
    let entries = w.table.nominal_um.len();
    let (lo, hi) = w.range_um;
    if a.json {
        outln!(
            "{}",
            serde_json::json!({"id": id, "format": format, "axis": axis.as_str(),
                "out": a.out.display().to_string(), "bytes": w.text.len(), "entries": entries,
                "range_um": [lo, hi], "max_deviation_um": w.max_deviation_um,
                "units": match (f, unit) {
                    (Controller::LinuxCnc, _) => "mm".to_string(),
                    (Controller::TwinCatLsec, LsecUnit::Metric) => "0.1 µm".to_string(),
                    (Controller::TwinCatLsec, LsecUnit::Increments(q)) => format!("{q} µm (encoder increments)"),
                    (Controller::Csv, _) => "µm".to_string(),
                },
                "export_s": secs})
        );
    } else {
        outln!(
            "campaign {id} axis {axis} → {} ({format}: {entries} entries over [{lo:.4}, {hi:.4}] µm, within {:.4} µm of csmetro move)",
            a.out.display(),
            w.max_deviation_um
        );
        if f == Controller::LinuxCnc {
            outln!(
                "load: [JOINT_n] COMP_FILE = {}, COMP_FILE_TYPE = 1 (mm: LINEAR_UNITS = mm)",
                a.out.display()
            );
        }
    }
    Ok(ExitCode::SUCCESS)
}

/// Writes `bytes` to `out` whole or not at all (a temporary file beside it, renamed).
fn write_new(out: &Path, bytes: &[u8]) -> Result<(), CliError> {
    let dir = match out.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    if !dir.is_dir() {
        return Err(CliError::input(format!(
            "{}: cannot write: directory {} does not exist",
            out.display(),
            dir.display()
        )));
    }
    let name = out
        .file_name()
        .ok_or_else(|| CliError::input(format!("{}: not a file name", out.display())))?;
    let tmp = dir.join(format!(
        ".{}.tmp-{}",
        name.to_string_lossy(),
        std::process::id()
    ));
    let done = std::fs::write(&tmp, bytes).and_then(|()| std::fs::rename(&tmp, out));
    done.map_err(|e| {
        let _ = std::fs::remove_file(&tmp);
        CliError::failure(format!(
            "{}: cannot write: {}",
            out.display(),
            crate::tomlpos::io_reason(&e)
        ))
    })
}
