//! `csmetro move --stage NAME --x-um X [--y-um Y] [--compensation RESULTS_DIR|FILE]`: one
//! (compensated) move for a person at the bench.
//!
//! The hardware: `--campaign FILE` (a campaign file of that stage names its controllers and
//! camera, or its simulation), else the stored characterisation the compensation came from
//! (same store, same stage), else a simulated stage (`--sim-model` or an ideal one).
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use serde_json::json;

use super::run::DEFAULT_DB;
use super::{CliError, CliResult};
use crate::campaign::rig::{self, Rig};
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

/// One axis's move, decided before anything moves.
struct Planned {
    axis: AxisId,
    wanted_um: f64,
    command_um: f64,
    approach: Direction,
    compute_us: f64,
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
        if c.spec.campaign.stage != a.stage {
            return Err(CliError::input(format!(
                "{} is a campaign of stage {:?}, not {:?}",
                p.display(),
                c.spec.campaign.stage,
                a.stage
            )));
        }
        return Ok((c, format!("campaign file {}", p.display())));
    }
    if let (Some(id), true) = (comp.and_then(|c| c.campaign), a.db.exists()) {
        if let Ok(store) = Store::open(&a.db) {
            if let Ok(Some(row)) = store.campaign(id) {
                if row.stage == a.stage {
                    let shared = Arc::new(Mutex::new(store));
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

async fn go(rig: &mut Rig, c: &Campaign, p: &Planned, pre_um: f64) -> Result<f64, String> {
    let timeout = Duration::from_secs_f64(c.spec.hardware.move_timeout_s);
    let rtimeout = Duration::from_secs_f64(c.spec.hardware.reference_timeout_s);
    let a = rig.axis(p.axis);
    let (lo, hi) = a.soft_limits_um();
    let start = (p.command_um - p.approach.sign() * pre_um).clamp(lo, hi);
    for (k, target) in [start, p.command_um].into_iter().enumerate() {
        match a.move_to(target).await {
            Err(csmetro_hal::AxisError::NotReferenced) if k == 0 => {
                a.reference(rtimeout)
                    .await
                    .map_err(|e| format!("axis {}: reference: {e}", p.axis))?;
                a.move_to(target)
                    .await
                    .map_err(|e| format!("axis {}: {e}", p.axis))?;
            }
            r => r.map_err(|e| format!("axis {}: {e}", p.axis))?,
        }
        a.wait_on_target(timeout)
            .await
            .map_err(|e| format!("axis {}: {e}", p.axis))?;
    }
    a.position_um()
        .await
        .map_err(|e| format!("axis {}: {e}", p.axis))
}

async fn measure(rig: &mut Rig) -> Result<(f64, f64), String> {
    let mut cam = rig.camera.take().ok_or("no camera")?;
    let decoder = rig.decoder.clone();
    let (cam, r) = tokio::task::spawn_blocking(move || {
        let r = cam
            .trigger(Duration::from_secs(5))
            .map_err(|e| e.to_string())
            .and_then(|job| job().map_err(|e| e.to_string()))
            .and_then(|frame| {
                let d = decoder.decode(&frame);
                if d.ok {
                    Ok((d.x_um, d.y_um))
                } else {
                    Err(d.reason.unwrap_or_else(|| "frame rejected".into()))
                }
            });
        (cam, r)
    })
    .await
    .map_err(|e| e.to_string())?;
    rig.camera = Some(cam);
    r
}

pub fn run(a: Args) -> CliResult {
    let direction = match a.direction.as_str() {
        "forward" => Direction::Forward,
        "backward" => Direction::Backward,
        _ => return Err(CliError::input("--direction must be forward or backward")),
    };
    if !(a.approach_um.is_finite() && (0.0..=10_000.0).contains(&a.approach_um)) {
        return Err(CliError::input("--approach-um must be 0..=10000"));
    }
    if a.stage.is_empty() || a.stage.len() > crate::campaign::spec::MAX_NAME_LEN {
        return Err(CliError::input("--stage: a stage name of 1 to 64 bytes"));
    }
    let mut wanted = vec![(AxisId::X, a.x_um)];
    if let Some(y) = a.y_um {
        wanted.push((AxisId::Y, y));
    }
    if let Some((axis, _)) = wanted.iter().find(|(_, w)| !w.is_finite()) {
        return Err(CliError::input(format!(
            "--{axis}-um must be a finite number"
        )));
    }
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
    let _lock =
        stagelock::try_lock(&a.db, &a.stage).map_err(|e| CliError::failure(e.to_string()))?;
    let rt = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
        .map_err(|e| CliError::failure(e.to_string()))?;
    rt.block_on(async {
        let mut rig = rig::build(&c)
            .await
            .map_err(|e| CliError::failure(format!("hardware: {e}")))?;
        // Every command first (soft limits, table range): a refused one moves nothing.
        let mut planned = Vec::new();
        for &(axis, w) in &wanted {
            let limits = rig.axis(axis).soft_limits_um();
            let t0 = Instant::now();
            let r = match &comp {
                Some(cmp) => {
                    let approach = cmp
                        .table(axis)
                        .map_or(direction, |t| t.served_direction(direction));
                    cmp.command(axis, approach, w, limits).map(|c| (c, approach))
                }
                None if w < limits.0 || w > limits.1 => Err(
                    crate::compensation::CommandError::OutsideLimits {
                        axis,
                        wanted_um: w,
                        command_um: w,
                        lo_um: limits.0,
                        hi_um: limits.1,
                    },
                ),
                None => Ok((w, direction)),
            };
            let compute_us = t0.elapsed().as_secs_f64() * 1e6;
            match r {
                Ok((command_um, approach)) => planned.push(Planned {
                    axis,
                    wanted_um: w,
                    command_um,
                    approach,
                    compute_us,
                }),
                Err(e) => {
                    rig.close().await;
                    return Err(CliError::input(e.to_string()));
                }
            }
        }
        let moves = async {
            let mut enc = Vec::new();
            for p in &planned {
                enc.push(go(&mut rig, &c, p, a.approach_um).await?);
            }
            Ok::<_, String>(enc)
        };
        let r = tokio::select! {
            r = moves => r,
            _ = tokio::signal::ctrl_c() => Err("interrupted".to_string()),
        };
        let encoders = match r {
            Ok(e) => e,
            Err(e) => {
                rig.stop_all().await;
                rig.close().await;
                return Err(CliError::failure(format!("{e}; motion stopped")));
            }
        };
        let measured = if a.measure {
            Some(measure(&mut rig).await)
        } else {
            None
        };
        rig.close().await;
        let axes: Vec<_> = planned
            .iter()
            .zip(&encoders)
            .map(|(p, e)| {
                json!({"axis": p.axis.as_str(), "wanted_um": p.wanted_um, "command_um": p.command_um,
                       "correction_um": p.command_um - p.wanted_um, "approach": p.approach.as_str(),
                       "encoder_um": e, "compute_us": p.compute_us})
            })
            .collect();
        let mut out = json!({"stage": a.stage, "hardware": hw,
            "compensation": comp.as_ref().map(|c| c.source.clone()), "axes": axes});
        match &measured {
            Some(Ok((x, y))) => {
                out["measured_x_um"] = json!(x);
                out["measured_y_um"] = json!(y);
            }
            Some(Err(e)) => out["measure_error"] = json!(e),
            None => {}
        }
        if a.json {
            println!("{out}");
        } else {
            println!("stage {} ({hw})", a.stage);
            for p in &planned {
                println!(
                    "{}: wanted {:.4} µm, commanded {:.4} µm (correction {:+.4} µm, approach {}, {:.1} µs)",
                    p.axis,
                    p.wanted_um,
                    p.command_um,
                    p.command_um - p.wanted_um,
                    p.approach.as_str(),
                    p.compute_us
                );
            }
            match &measured {
                Some(Ok((x, y))) => println!("measured: x {x:.4} µm, y {y:.4} µm"),
                Some(Err(e)) => println!("measured: no position ({e})"),
                None => {}
            }
        }
        Ok(ExitCode::SUCCESS)
    })
}
