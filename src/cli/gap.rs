//! `csmetro gap`: where measured campaign data leave the stage model, which library effect explains
//! the gap, and how far the held-out gap shrinks once it is added.
use std::path::PathBuf;
use std::process::ExitCode;

use csmetro_sim::StageModel;
use serde_json::json;

use super::{CliError, CliResult};
use crate::gap::{self, data, selftest};

#[derive(clap::Args)]
#[command(args_conflicts_with_subcommands = true)]
pub struct Args {
    #[command(subcommand)]
    pub command: Option<Sub>,
    /// The simulator's stage model (TOML with [[effect]] tables).
    #[arg(long)]
    pub model: Option<PathBuf>,
    /// Measured data: a campaign CSV (run,axis,direction,target_x_um,target_y_um,time_s,meas_x_um,meas_y_um;
    /// an unmeasured component left empty), an ISO 230-2 export (cycle,direction,target_um,deviation_um
    /// [,axis,static_um,time_s]; told apart by its header), or the id of a campaign in the store
    /// (`--db`); its run = 2·cycle + 0 for CS, 1 for the full scan.
    #[arg(long)]
    pub data: Option<PathBuf>,
    /// Store that `--data ID` reads.
    #[arg(long, env = "CSMETRO_DB", default_value = "csmetro-data/csmetro.db")]
    pub db: PathBuf,
    /// Print one JSON object on stdout instead of the text report.
    #[arg(long)]
    pub json: bool,
    /// Output directory: model.toml (updated model with the fitted effects) and gap.json.
    #[arg(long, default_value = "gap-out")]
    pub out: PathBuf,
    /// Candidate kinds, comma separated (default: the whole library).
    #[arg(long, value_delimiter = ',')]
    pub kinds: Option<Vec<String>>,
    /// Motor/encoder period tried when the model has no motor_cyclic of that axis, µm.
    #[arg(long)]
    pub motor_period_um: Option<f64>,
}

#[derive(clap::Subcommand)]
pub enum Sub {
    /// Benchmark on simulated data whose effect the diagnosed model lacks.
    Selftest(SelftestArgs),
    /// Simulate a line campaign (X lines at static Y, Y lines at static X, forward+backward,
    /// repeated runs) from a "real" stage model and write DATA.csv.
    Simulate(SimulateArgs),
}

#[derive(clap::Args)]
pub struct SelftestArgs {
    #[arg(long)]
    pub json: bool,
    /// Small size for CI (6 cases per category).
    #[arg(long)]
    pub quick: bool,
    /// Cases per category (default 40; no-gap gets twice as many).
    #[arg(long)]
    pub cases: Option<usize>,
    #[arg(long, default_value_t = 2026)]
    pub seed: u64,
    /// Exit with code 1 when a target is not met.
    #[arg(long)]
    pub strict: bool,
}

#[derive(clap::Args)]
pub struct SimulateArgs {
    /// The "real" stage model (its `noise` effects give σ unless --noise-um).
    #[arg(long)]
    pub truth: PathBuf,
    /// Output DATA.csv.
    #[arg(long)]
    pub out: PathBuf,
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    #[arg(long, default_value_t = 5)]
    pub runs: usize,
    #[arg(long, default_value_t = 40)]
    pub targets: usize,
    /// Static positions of the other axis per moving axis.
    #[arg(long, default_value_t = 3)]
    pub statics: usize,
    #[arg(long)]
    pub noise_um: Option<f64>,
}

fn load_model(path: &std::path::Path) -> Result<StageModel, CliError> {
    StageModel::load(path).map_err(|e| CliError::input(e.to_string()))
}

pub fn run(args: Args) -> CliResult {
    match args.command {
        Some(Sub::Selftest(a)) => return run_selftest(a),
        Some(Sub::Simulate(a)) => return run_simulate(a),
        None => {}
    }
    let model_path = args
        .model
        .ok_or_else(|| CliError::input("gap: --model MODEL.toml is required"))?;
    let data_path = args
        .data
        .ok_or_else(|| CliError::input("gap: --data DATA.csv is required"))?;
    let model = load_model(&model_path)?;
    if model.effects.is_empty() {
        // An empty (or truncated) file would silently stand for an ideal 9.5 x 4.2 mm stage.
        return Err(CliError::input(format!(
            "{}:1: empty model: no [[effect]] tables (give the stage's model; an ideal stage is one `noise` effect)",
            model_path.display()
        )));
    }
    let stored_id = data_path
        .to_str()
        .and_then(|t| t.parse::<i64>().ok())
        .filter(|_| !data_path.exists());
    let (samples, format) = match stored_id {
        Some(id) => {
            let s = stored_samples(&args.db, id)?;
            data::check_travel(&format!("campaign {id}"), &s, None, &model)
                .map_err(CliError::input)?;
            (s, data::Format::Campaign)
        }
        None => {
            let (s, lines, format) = data::read_any(&data_path).map_err(CliError::input)?;
            data::check_travel(&data_path.display().to_string(), &s, Some(&lines), &model)
                .map_err(CliError::input)?;
            (s, format)
        }
    };
    let mut opts = gap::Options {
        kinds: args.kinds,
        time_from_column: format != (data::Format::Iso230 { timed: false }),
        ..Default::default()
    };
    if matches!(format, data::Format::Iso230 { .. }) {
        opts.iso230 = true;
    }
    if let Some(p) = args.motor_period_um {
        if !(p.is_finite() && p > 0.0) {
            return Err(CliError::input("gap: --motor-period-um must be > 0"));
        }
        opts.motor_period_um = p;
    }
    let d = gap::diagnose(&model, &samples, &opts)
        .map_err(|e| CliError::input(format!("{}: {e}", data_path.display())))?;
    if d.n_runs < 5 {
        // Measured on campaign data: 3 runs x 2 lines found nothing that 6 runs found at once.
        eprintln!(
            "note: {} runs only: whole-run hold-out has little power; measure ≥ 5 cycles (runs) to attribute effects",
            d.n_runs
        );
    }
    std::fs::create_dir_all(&args.out)
        .map_err(|e| CliError::failure(format!("{}: {e}", args.out.display())))?;
    let model_out = args.out.join("model.toml");
    let header = format!(
        "# Updated by `csmetro gap` from {} on {}: {} effect(s) added.\n",
        model_path.display(),
        data_path.display(),
        d.added.len()
    );
    std::fs::write(&model_out, header + &d.model.to_toml_string())
        .map_err(|e| CliError::failure(format!("{}: {e}", model_out.display())))?;
    let iso = gap::iso230_figures(&samples);
    let mut j = d.to_json();
    j["model_out"] = json!(model_out.display().to_string());
    j["data_format"] = json!(match format {
        data::Format::Campaign => "campaign",
        data::Format::Iso230 { .. } => "iso230",
    });
    if format == (data::Format::Iso230 { timed: false }) {
        let note = "no `time_s` column: time is the row order, 1 s per row (drift rates are per 3600 rows)";
        if let Some(n) = j["notes"].as_array_mut() {
            n.push(json!(note));
        }
        if !args.json {
            outln!("note: {note}");
        }
    }
    j["iso230"] = json!(iso
        .iter()
        .map(|(a, st, f)| json!({"axis": a.as_str(), "static_um": st, "figures": f}))
        .collect::<Vec<_>>());
    let json_out = args.out.join("gap.json");
    std::fs::write(&json_out, format!("{j:#}\n"))
        .map_err(|e| CliError::failure(format!("{}: {e}", json_out.display())))?;
    if args.json {
        outln!("{j}");
    } else {
        if matches!(format, data::Format::Iso230 { .. }) {
            for (a, st, f) in &iso {
                outln!("{}", gap::describe_iso230(*a, *st, f));
            }
        }
        out!("{}", d.summary());
        outln!("updated model: {}", model_out.display());
    }
    Ok(ExitCode::SUCCESS)
}

fn run_selftest(a: SelftestArgs) -> CliResult {
    let cases = a.cases.unwrap_or(if a.quick { 6 } else { 40 });
    if cases == 0 {
        return Err(CliError::input("gap selftest: --cases must be >= 1"));
    }
    let o = selftest::SelftestOptions {
        cases,
        seed: a.seed,
        ..Default::default()
    };
    let report = selftest::run(&o);
    if a.json {
        outln!("{report}");
    } else {
        outln!("{report:#}");
    }
    let met = report["all_targets_met"] == json!(true);
    Ok(if a.strict && !met {
        ExitCode::from(1)
    } else {
        ExitCode::SUCCESS
    })
}

fn run_simulate(a: SimulateArgs) -> CliResult {
    if let Some(n) = a.noise_um {
        if !(n.is_finite() && n >= 0.0) {
            return Err(CliError::input(format!(
                "gap simulate: --noise-um = {n} must be a finite number >= 0"
            )));
        }
    }
    // Bounded like every data file the diagnosis reads back.
    const MAX_RUNS: usize = 1000;
    const MAX_TARGETS: usize = 100_000;
    const MAX_STATICS: usize = 100;
    if a.runs == 0 || a.targets == 0 {
        return Err(CliError::input(
            "gap simulate: --runs and --targets must be >= 1",
        ));
    }
    if a.runs > MAX_RUNS || a.targets > MAX_TARGETS || a.statics > MAX_STATICS {
        return Err(CliError::input(format!(
            "gap simulate: at most --runs {MAX_RUNS}, --targets {MAX_TARGETS}, --statics {MAX_STATICS}"
        )));
    }
    if a.runs * a.targets * a.statics.max(1) > 2_000_000 {
        return Err(CliError::input(
            "gap simulate: --runs x --targets x --statics must stay <= 2,000,000 samples per axis",
        ));
    }
    let truth = load_model(&a.truth)?;
    let sigma = a.noise_um.unwrap_or_else(|| truth.noise_sigma_um());
    if !(sigma.is_finite() && sigma >= 0.0) {
        return Err(CliError::input(format!(
            "{}: the noise σ of the truth model is {sigma} (must be finite, >= 0)",
            a.truth.display()
        )));
    }
    let spec = data::CampaignSpec {
        runs: a.runs,
        targets_per_line: a.targets,
        static_positions: a.statics,
        noise_um: a.noise_um,
        seed: a.seed,
        ..Default::default()
    };
    let s = data::simulate_campaign(&truth, &spec, None);
    data::write_csv(&a.out, &s)
        .map_err(|e| CliError::failure(format!("{}: {e}", a.out.display())))?;
    eprintln!("wrote {} samples to {}", s.len(), a.out.display());
    Ok(ExitCode::SUCCESS)
}

/// Samples of stored campaign `id`, as gap data.
fn stored_samples(db: &std::path::Path, id: i64) -> Result<Vec<data::Sample>, CliError> {
    if !db.exists() {
        return Err(CliError::input(format!(
            "gap: --data {id}: no store at {} (give --db)",
            db.display()
        )));
    }
    let store = crate::store::Store::open(db)
        .map_err(|e| CliError::failure(format!("store {}: {e}", db.display())))?;
    if store
        .campaign(id)
        .map_err(|e| CliError::failure(e.to_string()))?
        .is_none()
    {
        return Err(CliError::input(format!(
            "gap: no campaign {id} in {}",
            db.display()
        )));
    }
    let records = store
        .samples(id)
        .map_err(|e| CliError::failure(e.to_string()))?;
    if records.is_empty() {
        return Err(CliError::input(format!(
            "gap: campaign {id} has no samples yet"
        )));
    }
    Ok(data::from_campaign(&records))
}
