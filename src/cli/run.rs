//! `csmetro run CAMPAIGN.toml` (foreground, progress bar, summary table) and
//! `csmetro resume ID` (continue an interrupted campaign from its last stored sample).
use std::path::PathBuf;
use std::process::ExitCode;

use indicatif::{ProgressBar, ProgressStyle};
use tokio::sync::{broadcast, watch};

use super::{CliError, CliResult};
use crate::campaign::engine::Control;
use crate::campaign::preflight::{self, Report};
use crate::campaign::session::{self, SharedStore};
use crate::campaign::spec::Campaign;
use crate::campaign::stagelock::{self, StageLock};
use crate::store::Store;
use crate::types::{check_operator, CampaignState, Origin};

/// Default store of foreground runs (the service's config names its own).
pub const DEFAULT_DB: &str = "csmetro-data/csmetro.db";

#[derive(clap::Args)]
pub struct Args {
    /// Campaign file (TOML).
    campaign: PathBuf,
    /// SQLite store; campaigns, samples and results are committed there as they happen.
    #[arg(long, env = "CSMETRO_DB", default_value = DEFAULT_DB)]
    db: PathBuf,
    /// Print the summary as one JSON object on stdout instead of the table.
    #[arg(long)]
    json: bool,
    /// No progress bar.
    #[arg(long)]
    quiet: bool,
    /// Simulation only (soaks): append each sample's true position to this file.
    #[arg(long, hide = true)]
    truth_log: Option<PathBuf>,
    /// Your name, for the campaign's event log (who started it).
    #[arg(long, env = "CSMETRO_OPERATOR")]
    operator: Option<String>,
}

#[derive(clap::Args)]
pub struct ResumeArgs {
    /// Campaign id (see `csmetro status` or the store).
    id: i64,
    #[arg(long, env = "CSMETRO_DB", default_value = DEFAULT_DB)]
    db: PathBuf,
    #[arg(long)]
    json: bool,
    #[arg(long)]
    quiet: bool,
    #[arg(long, hide = true)]
    truth_log: Option<PathBuf>,
    /// Your name, for the campaign's event log (who resumed it).
    #[arg(long, env = "CSMETRO_OPERATOR")]
    operator: Option<String>,
}

/// The event log's origin of a foreground run; a bad name is bad input (exit 2).
fn origin(operator: Option<&str>) -> Result<Origin, CliError> {
    let op = match operator {
        Some(o) => check_operator(o).map_err(|e| CliError::input(format!("--operator: {e}")))?,
        None => None,
    };
    Ok(Origin::cli(op))
}

fn open(db: &std::path::Path) -> Result<SharedStore, CliError> {
    Store::open(db)
        .map(SharedStore::new)
        .map_err(|e| CliError::failure(format!("store {}: {e}", db.display())))
}

/// The stage for the whole foreground run: refused, before anything is stored or moved, while
/// another process (the service, another `run`) drives it.
fn take_stage(
    db: &std::path::Path,
    stage: &str,
    scope: stagelock::Scope,
) -> Result<StageLock, CliError> {
    stagelock::try_lock_scoped(db, stage, scope).map_err(|e| CliError::failure(e.to_string()))
}

pub fn run(a: Args) -> CliResult {
    let origin = origin(a.operator.as_deref())?;
    let c = Campaign::load(&a.campaign).map_err(|e| CliError::input(e.to_string()))?;
    let store = open(&a.db)?;
    let c = store
        .with(|s| crate::campaign::verification::resolve(c, s))
        .map_err(|e| CliError::input(e.to_string()))?;
    let _stage = take_stage(
        &a.db,
        &c.spec().campaign.stage,
        stagelock::Scope::of(c.spec().hardware.kind),
    )?;
    preflight(&c, &a.db, "nothing was recorded or moved")?;
    let id = session::create(&store, &c).map_err(CliError::failure)?;
    // A resume is offered where it applies: at the end of a run that did not finish.
    eprintln!(
        "campaign {id} \"{}\" stored in {}",
        c.spec().campaign.name,
        a.db.display()
    );
    let opts = session::Options {
        truth_log: a.truth_log,
        origin: Some(origin),
    };
    foreground(store, id, c, a.json, a.quiet, opts, &a.db)
}

pub fn resume(a: ResumeArgs) -> CliResult {
    let origin = origin(a.operator.as_deref())?;
    let store = open(&a.db)?;
    let row = store
        .with(|s| s.campaign(a.id))
        .map_err(|e| CliError::failure(e.to_string()))?
        .ok_or_else(|| CliError::input(format!("no campaign {} in {}", a.id, a.db.display())))?;
    if row.state.is_final() {
        return Err(CliError::input(format!(
            "campaign {} is {}: nothing to resume",
            a.id,
            row.state.as_str()
        )));
    }
    let _stage = take_stage(
        &a.db,
        &row.stage,
        stagelock::Scope::of_spec_toml(&row.spec_toml),
    )?;
    let c = session::load_stored(&store, a.id).map_err(CliError::failure)?;
    preflight(
        &c,
        &a.db,
        &format!("campaign {} not resumed; nothing moved", a.id),
    )?;
    let opts = session::Options {
        truth_log: a.truth_log,
        origin: Some(origin),
    };
    foreground(store, a.id, c, a.json, a.quiet, opts, &a.db)
}

/// The pre-flight of `csmetro check` (the stage already taken), before the campaign is
/// recorded or started: the table on stderr, and an error naming the failed check (exit 2 when
/// the campaign file must change, 1 when the rig must).
fn preflight(c: &Campaign, db: &std::path::Path, not_done: &str) -> Result<(), CliError> {
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .map_err(|e| CliError::failure(e.to_string()))?;
    let mut report = Report::default();
    rt.block_on(preflight::check_devices(
        c,
        preflight::Options { store: Some(db) },
        &mut report,
    ));
    if !report.blocks() {
        for w in report.warnings() {
            eprintln!("warning: {w}");
        }
        return Ok(());
    }
    eprint!("{}", report.table());
    Err(CliError {
        code: report.exit_code(),
        message: format!("{}; {not_done}", report.error_message()),
    })
}

/// What an operator does with a finished characterisation: the commands to type (on stderr,
/// after the results line), for the axes that have a compensation table.
fn next_steps(id: i64, stage: &str, dir: &std::path::Path, db_arg: &str) -> String {
    let axes: Vec<&str> = ["x", "y"]
        .into_iter()
        .filter(|a| dir.join(format!("compensation_{a}.csv")).is_file())
        .collect();
    let Some(first) = axes.first() else {
        return String::new();
    };
    let target = if axes == ["x"] {
        "--x-um X"
    } else {
        "--x-um X --y-um Y"
    };
    format!(
        "next:\n  csmetro verify {id}{db_arg}    # the compensation proved: before/after at targets never visited\n  \
         csmetro move --stage {stage} {target} --compensation {}{db_arg}    # a compensated move\n  \
         csmetro export {id} --format csv --axis {first} --out compensation-{first}.csv{db_arg}    # the table for a controller (also linuxcnc, twincat-lsec)\n",
        dir.display()
    )
}

fn foreground(
    store: SharedStore,
    id: i64,
    c: Campaign,
    json: bool,
    quiet: bool,
    opts: session::Options,
    db: &std::path::Path,
) -> CliResult {
    let stage = c.spec().campaign.stage.clone();
    let db_arg = if db == std::path::Path::new(DEFAULT_DB) {
        String::new()
    } else {
        format!(" --db {}", db.display())
    };
    let rt = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
        .map_err(|e| CliError::failure(e.to_string()))?;
    rt.block_on(async move {
        let planned = crate::campaign::verification::planned(&c)
            .unwrap_or(crate::campaign::plan::plan(&c).total() as u64);
        let stored = store.with(|s| s.sample_count(id)).unwrap_or(0);
        let bar = if quiet {
            ProgressBar::hidden()
        } else {
            ProgressBar::new(planned)
        };
        bar.set_style(
            ProgressStyle::with_template(
                "{spinner} [{elapsed_precise}] {bar:40} {pos}/{len} targets  {msg}",
            )
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
        );
        bar.set_position(stored);
        let (ctl_tx, ctl_rx) = watch::channel(Control::Run);
        let (ev_tx, mut ev_rx) = broadcast::channel::<session::Event>(1024);
        // Ctrl-C: the operator aborts. SIGTERM (shutdown, a supervisor): stop, resumable.
        // Either way motion stops before anything else.
        tokio::spawn(async move {
            let mut term =
                tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate()).ok();
            let c = tokio::select! {
                _ = tokio::signal::ctrl_c() => Control::Abort,
                _ = async { match term.as_mut() { Some(t) => { t.recv().await; } None => std::future::pending::<()>().await } } => Control::Stop,
            };
            let _ = ctl_tx.send(c);
        });
        let b2 = bar.clone();
        tokio::spawn(async move {
            while let Ok(e) = ev_rx.recv().await {
                match e.kind.as_str() {
                    "run_start" => b2.set_message(e.data["run"].as_str().unwrap_or("").to_string()),
                    "reconstructed" => b2.println(format!(
                        "reconstructed {} {}: {} (CV error {} µm, {:.0} ms)",
                        e.data["run"].as_str().unwrap_or(""),
                        e.data["component"].as_str().unwrap_or(""),
                        e.data["method"].as_str().unwrap_or(""),
                        e.data["cv_error_um"].as_f64().map_or("-".into(), |v| format!("{v:.3}")),
                        e.data["solve_ms"].as_f64().unwrap_or(0.0)
                    )),
                    "frame_rejected" | "point_failed" | "adaptive" | "reconstruction_failed" => {
                        b2.println(format!("{}: {}", e.kind, e.data))
                    }
                    _ => {}
                }
            }
        });
        let b3 = bar.clone();
        let on_sample = Box::new(move |_: &crate::types::SampleRecord| b3.inc(1));
        let r = session::execute_with(store, id, c, ctl_rx, ev_tx, on_sample, opts).await;
        bar.finish_and_clear();
        let fin = r.map_err(CliError::failure)?;
        if json {
            outln!(
                "{}",
                serde_json::to_string(&fin.summary.clone().unwrap_or(serde_json::json!({
                    "id": id, "state": fin.state.as_str()
                })))
                .unwrap_or_default()
            );
        } else if let Some(t) = &fin.table {
            outln!("{t}");
        }
        if let Some(d) = &fin.out_dir {
            eprintln!(
                "results: {} (report.html and the files; also in the store, campaign {id})",
                d.display()
            );
            if fin.state == CampaignState::Done {
                eprint!("{}", next_steps(id, &stage, d, &db_arg));
            }
        }
        Ok(match fin.state {
            CampaignState::Done => ExitCode::SUCCESS,
            CampaignState::Failed => {
                let errors = fin.summary.as_ref().and_then(|s| s["errors"].as_array().cloned());
                for e in errors.unwrap_or_default() {
                    eprintln!("error: {}", e.as_str().unwrap_or_default());
                }
                eprintln!("campaign {id} failed; motion stopped");
                ExitCode::FAILURE
            }
            CampaignState::Paused => {
                eprintln!("campaign {id} is paused; `csmetro resume {id}` continues it");
                ExitCode::from(143)
            }
            CampaignState::Aborted => {
                eprintln!("campaign {id} aborted; motion stopped");
                ExitCode::from(130)
            }
            CampaignState::Interrupted => {
                eprintln!(
                    "campaign {id} stopped; motion stopped; `csmetro resume {id}` continues from the last stored sample"
                );
                ExitCode::from(143)
            }
            _ => ExitCode::FAILURE,
        })
    })
}
