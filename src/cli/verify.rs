//! `csmetro verify ID`: measures a characterised stage again without and with its compensation
//! and reports before/after side by side; exit 1 ("passed": false) when the compensated residual
//! exceeds the expected one.
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::Arc;

use tokio::sync::watch;

use super::run::DEFAULT_DB;
use super::{CliError, CliResult};
use crate::campaign::engine::Control;
use crate::campaign::session::{self, SharedStore};
use crate::campaign::stagelock;
use crate::campaign::verify::map as verify_map;
use crate::campaign::verify::{self, prior_from_summary, Prior, VerifyOptions};
use crate::compensation::Compensation;
use crate::store::Store;
use crate::types::{AxisId, CampaignState};

#[derive(clap::Args)]
pub struct Args {
    /// The characterisation campaign (its hardware, grid and compensation tables).
    id: i64,
    #[arg(long, env = "CSMETRO_DB", default_value = DEFAULT_DB)]
    db: PathBuf,
    /// Print exactly one JSON object on stdout instead of the table.
    #[arg(long)]
    json: bool,
    /// Another compensation than the campaign's own: a results directory or a table file.
    #[arg(long)]
    compensation: Option<PathBuf>,
    /// Measurement cycles per direction (ISO 230-2: 5).
    #[arg(long, default_value_t = 5)]
    cycles: u32,
    /// Targets chosen from the characterisation's grid.
    #[arg(long, default_value_t = 11)]
    targets: usize,
    /// Random targets between grid points (never visited by the characterisation).
    #[arg(long, default_value_t = 10)]
    unvisited: usize,
    /// A map campaign: never-visited XY points measured (a lattice of random columns x rows
    /// with at least this many points).
    #[arg(long, default_value_t = 20)]
    points: usize,
    /// Seed of the target choice.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Largest |compensated error| that passes, µm (default per axis: 3 x the
    /// characterisation's CV error + the repeatability R).
    #[arg(long)]
    expected_um: Option<f64>,
    /// No progress on stderr.
    #[arg(long)]
    quiet: bool,
}

pub fn run(a: Args) -> CliResult {
    if let Some(e) = a.expected_um {
        if !(e.is_finite() && e > 0.0) {
            return Err(CliError::input("--expected-um must be a positive number"));
        }
    }
    if a.cycles == 0 || a.cycles > verify::MAX_CYCLES {
        return Err(CliError::input(format!(
            "--cycles must be 1..={}",
            verify::MAX_CYCLES
        )));
    }
    if a.targets < 2 || a.targets + a.unvisited > verify::MAX_TARGETS {
        return Err(CliError::input(format!(
            "--targets at least 2, --targets + --unvisited at most {}",
            verify::MAX_TARGETS
        )));
    }
    if !a.db.exists() {
        return Err(CliError::input(format!("no store at {}", a.db.display())));
    }
    let store = Store::open(&a.db)
        .map_err(|e| CliError::failure(format!("store {}: {e}", a.db.display())))?;
    let row = store
        .campaign(a.id)
        .map_err(|e| CliError::failure(e.to_string()))?
        .ok_or_else(|| CliError::input(format!("no campaign {} in {}", a.id, a.db.display())))?;
    if row.state != CampaignState::Done {
        return Err(CliError::input(format!(
            "campaign {} is {}: only a finished characterisation can be verified",
            a.id,
            row.state.as_str()
        )));
    }
    // A bad table is refused here, before any hardware is touched.
    let comp = match &a.compensation {
        Some(p) => Compensation::load(p),
        None => crate::campaign::compensate::stored(&store, a.id, &row.stage),
    }
    .map_err(|e| CliError::input(e.to_string()))?;
    comp.check_stage(&row.stage)
        .map_err(|e| CliError::input(e.to_string()))?;
    let summary: serde_json::Value = store
        .result(a.id, "summary.json")
        .ok()
        .flatten()
        .and_then(|(_, b)| serde_json::from_slice(&b).ok())
        .unwrap_or_default();
    let samples = store
        .samples(a.id)
        .map_err(|e| CliError::failure(e.to_string()))?;
    let measured = [AxisId::X, AxisId::Y].map(|ax| verify::measured_span(&samples, ax));
    let shared = SharedStore::new(store);
    let c = session::load_stored(&shared, a.id).map_err(CliError::failure)?;
    if c.map().is_some() {
        let opts = verify_map::MapVerifyOptions {
            points: a.points,
            cycles: a.cycles,
            seed: a.seed,
            expected_um: a.expected_um,
            measured_span_um: verify_map::measured_span(&samples),
        };
        return run_map(&a, &row.stage, &shared, &c, comp, &opts);
    }
    for ax in c.axes() {
        comp.check_covers(ax.axis, ax.grid.start_um, ax.grid.end_um())
            .map_err(|e| CliError::input(e.to_string()))?;
    }
    let _stage = stagelock::try_lock_scoped(
        &a.db,
        &row.stage,
        stagelock::Scope::of(c.spec().hardware.kind),
    )
    .map_err(|e| CliError::failure(e.to_string()))?;
    let opts = VerifyOptions {
        cycles: a.cycles,
        iso_targets: a.targets,
        unvisited_targets: a.unvisited,
        seed: a.seed,
        expected_um: a.expected_um,
        measured_span_um: measured,
    };
    let prior = move |axis: AxisId| -> Prior { prior_from_summary(&summary, axis) };
    let rt = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
        .map_err(|e| CliError::failure(e.to_string()))?;
    let quiet = a.quiet;
    let verdict = rt.block_on(async {
        let (tx, rx) = watch::channel(Control::Run);
        // Ctrl-C or SIGTERM: motion stops, the verification ends without a verdict.
        tokio::spawn(async move {
            let mut term =
                tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate()).ok();
            tokio::select! {
                _ = tokio::signal::ctrl_c() => {},
                _ = async { match term.as_mut() { Some(t) => { t.recv().await; } None => std::future::pending::<()>().await } } => {},
            }
            let _ = tx.send(Control::Abort);
        });
        let mut progress = verify::Progress(move |kind: &str, data: &serde_json::Value| {
            if !quiet && matches!(kind, "pass" | "frame_rejected" | "point_failed") {
                eprintln!("{kind}: {data}");
            }
        });
        let done = Default::default();
        verify::run(a.id, &c, Arc::new(comp), &prior, &opts, rx, &done, &mut progress).await
    });
    let v = verdict.map_err(|e| match e {
        verify::VerifyError::Refused(m) => CliError::input(m),
        e => CliError::failure(e.to_string()),
    })?;
    // Results next to the characterisation's: in the store (so `report` and the API serve
    // them) and in its output directory.
    let kept = keep_files(&shared, &c, a.id, &verify::files(&v));
    link_report(&shared, &kept.dir, a.id, verify::REPORT_FILE, v.passed);
    finish(&a, &kept, verify::json(&v), &verify::table(&v), v.passed)
}

/// The verdict on stdout (JSON or the table), where the files went; exit 1 when it failed or
/// when the store refused its files (a verdict printed but not kept is not a verification the
/// lab has: `report` and the API would still show the last one).
fn finish(a: &Args, kept: &Kept, json: serde_json::Value, table: &str, passed: bool) -> CliResult {
    if a.json {
        outln!("{json}");
    } else {
        out!("{table}");
    }
    if !kept.unstored.is_empty() {
        return Err(CliError::failure(format!(
            "the verification's results were not stored in campaign {}: {}",
            a.id,
            kept.unstored.join("; ")
        )));
    }
    if !kept.written {
        eprintln!(
            "warning: {} not written (the results are in the store, campaign {})",
            kept.dir.join("verify").display(),
            a.id
        );
    } else if !a.quiet {
        eprintln!(
            "results: {} (and in the store, campaign {})",
            kept.dir.join("verify").display(),
            a.id
        );
    }
    Ok(if passed {
        ExitCode::SUCCESS
    } else {
        ExitCode::FAILURE
    })
}

/// The characterisation's `report.html`, in the store and in its output directory, links to
/// the verification (`href`, relative to the results). A report that cannot be updated keeps
/// its old content: the verification's own files are written already.
fn link_report(shared: &SharedStore, dir: &Path, id: i64, href: &str, passed: bool) {
    let note = "(before / after figures and charts of the last `csmetro verify`)";
    let warnings = shared.with(|s| {
        crate::campaign::verification::link_report(s, id, Some((dir, href)), href, passed, note)
    });
    for w in warnings {
        eprintln!("warning: {w}");
    }
}

/// Runs `body` on a runtime with Ctrl-C / SIGTERM turned into an abort of the verification.
fn with_abort<T>(
    body: impl FnOnce(
        watch::Receiver<Control>,
    ) -> std::pin::Pin<Box<dyn std::future::Future<Output = T>>>,
) -> Result<T, CliError> {
    let rt = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
        .map_err(|e| CliError::failure(e.to_string()))?;
    Ok(rt.block_on(async {
        let (tx, rx) = watch::channel(Control::Run);
        tokio::spawn(async move {
            let mut term =
                tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate()).ok();
            tokio::select! {
                _ = tokio::signal::ctrl_c() => {},
                _ = async { match term.as_mut() { Some(t) => { t.recv().await; } None => std::future::pending::<()>().await } } => {},
            }
            let _ = tx.send(Control::Abort);
        });
        body(rx).await
    }))
}

/// What became of the verification's files: the store's refusals (name: error) and whether
/// the output directory was written.
struct Kept {
    unstored: Vec<String>,
    written: bool,
    dir: PathBuf,
}

/// Stores the verification's files with the campaign's results (store and output directory).
fn keep_files(
    shared: &SharedStore,
    c: &crate::campaign::spec::Campaign,
    id: i64,
    files: &[(String, String, Vec<u8>)],
) -> Kept {
    let unstored = shared.with(|s| {
        files
            .iter()
            .filter_map(|(name, ctype, bytes)| {
                s.put_result(id, name, ctype, bytes)
                    .err()
                    .map(|e| format!("{name}: {e}"))
            })
            .collect()
    });
    let dir = crate::campaign::results::out_dir(c, id);
    let mut written = true;
    for (name, _, bytes) in files {
        let p = dir.join(name);
        let ok = p
            .parent()
            .map_or(Ok(()), std::fs::create_dir_all)
            .and_then(|()| std::fs::write(&p, bytes));
        written &= ok.is_ok();
    }
    Kept {
        unstored,
        written,
        dir,
    }
}

/// `csmetro verify ID` of a map campaign (see [`verify_map`]).
fn run_map(
    a: &Args,
    stage: &str,
    shared: &SharedStore,
    c: &crate::campaign::spec::Campaign,
    comp: Compensation,
    opts: &verify_map::MapVerifyOptions,
) -> CliResult {
    if comp.map().is_none() {
        return Err(CliError::input(format!(
            "{}: campaign {} is a map campaign: verify it with its map (compensation_map_<direction>.csv)",
            comp.source, a.id
        )));
    }
    let _stage =
        stagelock::try_lock_scoped(&a.db, stage, stagelock::Scope::of(c.spec().hardware.kind))
            .map_err(|e| CliError::failure(e.to_string()))?;
    let quiet = a.quiet;
    let id = a.id;
    let comp = Arc::new(comp);
    let c2 = c.clone();
    let opts2 = opts.clone();
    let verdict = with_abort(move |rx| {
        Box::pin(async move {
            let mut progress = verify::Progress(move |kind: &str, data: &serde_json::Value| {
                if !quiet && matches!(kind, "pass" | "frame_rejected" | "point_failed") {
                    eprintln!("{kind}: {data}");
                }
            });
            verify_map::run(id, &c2, comp, &opts2, rx, &mut progress).await
        })
    })?;
    let v = verdict.map_err(|e| match e {
        verify::VerifyError::Refused(m) => CliError::input(m),
        e => CliError::failure(e.to_string()),
    })?;
    let kept = keep_files(shared, c, a.id, &verify_map::files(&v));
    link_report(shared, &kept.dir, a.id, verify::REPORT_FILE, v.passed);
    finish(
        a,
        &kept,
        verify_map::json(&v),
        &verify_map::table(&v),
        v.passed,
    )
}
