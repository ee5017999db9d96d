//! `csmetro move --stage NAME --x-um X [--y-um Y] [--compensation RESULTS_DIR|FILE]`: one
//! (compensated) move for a person at the bench.
//!
//! The hardware: `--campaign FILE` (a campaign file of that stage names its controllers and
//! camera, or its simulation), else the stored characterisation the compensation came from
//! (same store, same stage), else a simulated stage (`--sim-model` or an ideal one).
use std::path::{Path, PathBuf};
use std::process::ExitCode;

use serde_json::json;

use super::run::DEFAULT_DB;
use super::{CliError, CliResult};
use crate::campaign::motion::{self, MoveError, MoveRequest};
use crate::campaign::spec::Campaign;
use crate::campaign::{session, stagelock};
use crate::compensation::Compensation;
use crate::store::Store;
use crate::types::{AxisId, Direction};

#[derive(clap::Args)]
pub struct Args {
    /// The stage to move (as campaigns name it, `[campaign] stage`).
    #[arg(long)]
    stage: String,
    /// Wanted x position, µm.
    #[arg(long, allow_hyphen_values = true)]
    x_um: f64,
    /// Wanted y position, µm (y stays where it is without it).
    #[arg(long, allow_hyphen_values = true)]
    y_um: Option<f64>,
    /// Compensation: a results directory (compensation_x|y.csv) or one table file.
    #[arg(long)]
    compensation: Option<PathBuf>,
    /// Approach direction: the target is reached moving forward (increasing) or backward.
    /// With a table of one direction only, the move approaches from that table's side.
    #[arg(long, default_value = "forward")]
    direction: String,
    /// Pre-travel before the final approach, µm.
    #[arg(long, default_value_t = 50.0)]
    approach_um: f64,
    /// A campaign file of this stage: its hardware is used.
    #[arg(long)]
    campaign: Option<PathBuf>,
    /// Simulated stage without `--campaign`: the stage model (TOML); default an ideal stage.
    #[arg(long)]
    sim_model: Option<PathBuf>,
    /// Store (stage locks; the characterisation named by a results directory).
    #[arg(long, env = "CSMETRO_DB", default_value = DEFAULT_DB)]
    db: PathBuf,
    /// After the move, take a camera frame and report the measured position.
    #[arg(long)]
    measure: bool,
    /// Print one JSON object.
    #[arg(long)]
    json: bool,
}

fn sim_campaign(stage: &str, model: Option<&Path>) -> Result<Campaign, CliError> {
    let model = match model {
        Some(p) => {
            let abs = std::path::absolute(p)
                .map_err(|e| CliError::input(format!("{}: {e}", p.display())))?;
            format!(
                "model = {}\n",
                toml::Value::String(abs.display().to_string())
            )
        }
        None => String::new(),
    };
    let text = format!(
        "[campaign]\nname = \"move\"\nstage = {}\n[hardware]\nkind = \"sim\"\noptics = {{ width = 640, height = 640 }}\n[hardware.sim]\n{model}[axes.x]\nrange_um = [0.0, 100.0]\nstep_um = 5.0\nother_at_um = 0.0\n[sampling]\ndesign = \"full\"\n",
        toml::Value::String(stage.to_string())
    );
    Campaign::parse(&text, "(simulated stage)", Path::new("."))
        .map_err(|e| CliError::input(e.to_string()))
}

/// The campaign whose hardware this move uses, and how it was chosen.
fn hardware(a: &Args, comp: Option<&Compensation>) -> Result<(Campaign, String), CliError> {
    if let Some(p) = &a.campaign {
        let text = crate::tomlpos::read_bounded(p, crate::tomlpos::MAX_TOML_BYTES)
            .map_err(|e| CliError::input(format!("{}: cannot read: {e}", p.display())))?;
        let base = p.parent().map(Path::to_path_buf).unwrap_or_default();
        let c = Campaign::parse(&text, &p.display().to_string(), &base)
            .map_err(|e| CliError::input(e.to_string()))?;
        if c.spec().campaign.stage != a.stage {
            return Err(CliError::input(format!(
                "{} is a campaign of stage {:?}, not {:?}",
                p.display(),
                c.spec().campaign.stage,
                a.stage
            )));
        }
        return Ok((c, format!("campaign file {}", p.display())));
    }
    if let (Some(id), true) = (comp.and_then(|c| c.campaign), a.db.exists()) {
        if let Ok(store) = Store::open(&a.db) {
            if let Ok(Some(row)) = store.campaign(id) {
                if row.stage == a.stage {
                    let shared = crate::campaign::events::SharedStore::new(store);
                    let c = session::load_stored(&shared, id).map_err(CliError::failure)?;
                    return Ok((c, format!("campaign {id}'s hardware")));
                }
            }
        }
    }
    let c = sim_campaign(&a.stage, a.sim_model.as_deref())?;
    Ok((
        c,
        match &a.sim_model {
            Some(p) => format!("simulated stage ({})", p.display()),
            None => "simulated ideal stage".into(),
        },
    ))
}

pub fn run(a: Args) -> CliResult {
    let direction = match a.direction.as_str() {
        "forward" => Direction::Forward,
        "backward" => Direction::Backward,
        _ => return Err(CliError::input("--direction must be forward or backward")),
    };
    if a.stage.is_empty() || a.stage.len() > crate::campaign::spec::MAX_NAME_LEN {
        return Err(CliError::input("--stage: a stage name of 1 to 64 bytes"));
    }
    let mut wanted = vec![(AxisId::X, a.x_um)];
    if let Some(y) = a.y_um {
        wanted.push((AxisId::Y, y));
    }
    let req = MoveRequest {
        wanted,
        direction,
        approach_um: a.approach_um,
        measure: a.measure,
    };
    req.check()
        .map_err(|e| CliError::input(format!("--{}", e.to_string().replace('_', "-"))))?;
    // A bad table is refused here: nothing is built, nothing moves.
    let comp = match &a.compensation {
        Some(p) => {
            let c = Compensation::load(p).map_err(|e| CliError::input(e.to_string()))?;
            c.check_stage(&a.stage)
                .map_err(|e| CliError::input(e.to_string()))?;
            Some(c)
        }
        None => None,
    };
    let (c, hw) = hardware(&a, comp.as_ref())?;
    if let Some(d) = a.db.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(d)
            .map_err(|e| CliError::failure(format!("{}: {e}", d.display())))?;
    }
    let _lock = stagelock::try_lock_scoped(
        &a.db,
        &a.stage,
        stagelock::Scope::of(c.spec().hardware.kind),
    )
    .map_err(|e| CliError::failure(e.to_string()))?;
    let rt = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
        .map_err(|e| CliError::failure(e.to_string()))?;
    let cancel = async {
        let _ = tokio::signal::ctrl_c().await;
    };
    let mut out = rt
        .block_on(motion::execute(&c, comp.as_ref(), &req, cancel))
        .map_err(|e| match e {
            MoveError::Refused(m) => CliError::input(m),
            MoveError::Failed(m) => CliError::failure(m),
        })?;
    out["stage"] = json!(a.stage);
    out["hardware"] = json!(hw);
    if a.json {
        outln!("{out}");
    } else {
        outln!("stage {} ({hw})", a.stage);
        for p in out["axes"].as_array().into_iter().flatten() {
            outln!(
                "{}: wanted {:.4} µm, commanded {:.4} µm (correction {:+.4} µm, approach {}, {:.1} µs)",
                p["axis"].as_str().unwrap_or(""),
                p["wanted_um"].as_f64().unwrap_or(f64::NAN),
                p["command_um"].as_f64().unwrap_or(f64::NAN),
                p["correction_um"].as_f64().unwrap_or(f64::NAN),
                p["approach"].as_str().unwrap_or(""),
                p["compute_us"].as_f64().unwrap_or(f64::NAN)
            );
            if let Some(u) = p["landing_u_um"].as_f64() {
                let from = if p["repeatability_um"].is_number() {
                    "table u and repeatability"
                } else {
                    "table u; no repeatability measured"
                };
                outln!(
                    "{}: expected landing ±{:.4} µm (k = 2; {from})",
                    p["axis"].as_str().unwrap_or(""),
                    2.0 * u
                );
            }
        }
        if let (Some(x), Some(y)) = (out["measured_x_um"].as_f64(), out["measured_y_um"].as_f64()) {
            outln!("measured: x {x:.4} µm, y {y:.4} µm");
        } else if let Some(e) = out["measure_error"].as_str() {
            outln!("measured: no position ({e})");
        }
        for n in out["notes"].as_array().into_iter().flatten() {
            outln!("note: {}", n.as_str().unwrap_or_default());
        }
    }
    Ok(ExitCode::SUCCESS)
}
