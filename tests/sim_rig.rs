//! `csmetro sim rig` + `csmetro run` of a `kind = "real"` campaign: GCS over TCP to the rig's
//! controllers, the camera through Aravis (GigE Vision discovery by serial number) from the
//! rig's fake camera. The campaign completes and recovers the stage's error curve as well as
//! the same campaign on `kind = "sim"` (within 10 %), both judged against the curve computed
//! here from the model's formulas, not by csmetro.
//!
//! A first test follows one small campaign sample by sample: each measured x is the target plus
//! the model's error (so it came from the camera), the encoder says the target, the rig's event
//! names the controllers and the camera, and the driver asked on-target after its last move.
//!
//! Needs the `aravis` feature: `cargo test --features aravis --test sim_rig`.
#![cfg(feature = "aravis")]
mod common;
mod rig;

use std::f64::consts::PI;
use std::path::Path;

use common::{json_of, run_json};
use csmetro::store::Store;

/// Scale error of 120 ppm and a 1450 µm wave on x; no noise, no backlash.
const MODEL: &str = r#"
[stage]
travel_x_um = [0.0, 9500.0]
travel_y_um = [0.0, 4200.0]

[[effect]]
kind = "scale"
axis = "x"
ppm = 120.0
ref_um = 1000.0

[[effect]]
kind = "harmonic"
axis = "x"
period_um = 1450.0
cos_um = [0.6]
sin_um = [-0.3]
"#;

/// The x error the model describes at x = `p` µm (its documented formulas).
fn truth_um(p: f64) -> f64 {
    let w = 2.0 * PI * p / 1450.0;
    120e-6 * (p - 1000.0) + 0.6 * w.cos() - 0.3 * w.sin()
}

/// A campaign of x over `range_um` at 10 µm, `m` random targets each way (`tail`: more of its
/// `[sampling]` and its `[reconstruction]`), on the `hardware` given, results below `out`.
fn x_campaign(
    name: &str,
    hardware: &str,
    range_um: [f64; 2],
    m: usize,
    tail: &str,
    out: &Path,
) -> String {
    let [lo, hi] = range_um;
    format!(
        r#"[campaign]
name = "{name}"
stage = "sim-rig-{name}"
{hardware}
[axes.x]
range_um = [{lo:?}, {hi:?}]
step_um = 10.0
other_at_um = 2000.0
m = {m}

[sampling]
design = "random"
seed = 11
{tail}
[acquisition]
directions = ["forward", "backward"]
settle_s = 0.0
dwell_s = 0.0
approach_um = 20.0

[outputs]
dir = "{out}/{{name}}-{{id}}"
"#,
        out = out.display()
    )
}

/// The reconstruction both kinds share: basis pursuit with denoising.
const BPDN: &str = "[reconstruction]\nmethod = \"bpdn\"\nnoise_um = 0.01\n";

/// RMS of (reconstructed - truth) over every CS curve of the x component, µm, and how many
/// curves there were.
fn recovery_rms_um(db: &Path) -> (f64, usize) {
    let s = Store::open(db).unwrap();
    let (mut sum, mut n, mut curves) = (0.0, 0usize, 0usize);
    for name in s.result_names(1).unwrap() {
        // ef_xx / eb_xx: x moving forward / backward, x measured.
        if !(name == "ef_xx.csv" || name == "eb_xx.csv") {
            continue;
        }
        let (_, bytes) = s.result(1, &name).unwrap().unwrap();
        let text = String::from_utf8(bytes).unwrap();
        let mut lines = text.lines();
        let head: Vec<&str> = lines.next().unwrap().split(',').collect();
        let Some(cs) = head.iter().position(|h| *h == "cs_um") else {
            continue;
        };
        curves += 1;
        for l in lines {
            let v: Vec<f64> = l.split(',').map(|x| x.parse().unwrap()).collect();
            sum += (v[cs] - truth_um(v[0])).powi(2);
            n += 1;
        }
    }
    assert!(n > 0, "no CS curve of x in the store");
    ((sum / n as f64).sqrt(), curves)
}

#[test]
fn a_real_campaign_on_the_simulated_rig_recovers_the_curve_as_the_sim_kind_does() {
    let _turn = rig::camera_turn();
    let dir = tempfile::tempdir().unwrap();
    let model = dir.path().join("model.toml");
    std::fs::write(&model, MODEL).unwrap();
    let exe = Path::new(env!("CARGO_BIN_EXE_csmetro"));
    let r = rig::Rig::start(
        exe,
        &rig::rig_file(dir.path(), Some(&model), 1.0, 2.0, true),
    );

    let real = dir.path().join("real.toml");
    let hardware = rig::real_hardware(&r.x, &r.y, [0.0, 9000.0], [0.0, 4000.0], rig::CAMERA);
    let text = x_campaign("real", &hardware, [500.0, 2500.0], 24, BPDN, dir.path());
    std::fs::write(&real, text).unwrap();
    let db_real = dir.path().join("real.db");
    let o = run_json(&real, &db_real);
    let j = json_of(&o);
    assert_eq!(j["state"], "done", "{j}");
    let log = r.stop();
    assert!(log.iter().any(|(a, c)| a == "x" && c.starts_with("MOV")));

    let sim = dir.path().join("sim.toml");
    let hardware = "[hardware]\nkind = \"sim\"\noptics = { width = 640, height = 640 }\n\n\
                    [hardware.sim]\nmodel = \"model.toml\"\ntime_scale = 1000\ntransport = \"tcp\"\nseed = 5\n";
    let text = x_campaign("sim", hardware, [500.0, 2500.0], 24, BPDN, dir.path());
    std::fs::write(&sim, text).unwrap();
    let db_sim = dir.path().join("sim.db");
    let o = run_json(&sim, &db_sim);
    assert_eq!(json_of(&o)["state"], "done");

    let (e_real, n_real) = recovery_rms_um(&db_real);
    let (e_sim, n_sim) = recovery_rms_um(&db_sim);
    assert_eq!((n_real, n_sim), (2, 2), "forward and backward curves");
    eprintln!("recovery error (RMS): real on the rig {e_real:.4} µm, sim {e_sim:.4} µm");
    // The curve is recovered at all (its own amplitude is ~0.7 µm)...
    assert!(e_sim < 0.3, "sim recovery error {e_sim} µm");
    // ...and the real path through the rig does as well as the simulation.
    assert!(
        (e_real - e_sim).abs() <= 0.10 * e_sim,
        "recovery error: real on the rig {e_real:.4} µm, sim {e_sim:.4} µm"
    );
}

#[test]
fn a_real_rig_campaign_runs_over_gcs_tcp_and_gige_vision() {
    let _turn = rig::camera_turn();
    let dir = tempfile::tempdir().unwrap();
    let model = dir.path().join("model.toml");
    std::fs::write(&model, MODEL).unwrap();
    let r = rig::Rig::start(
        Path::new(env!("CARGO_BIN_EXE_csmetro")),
        &rig::rig_file(dir.path(), Some(&model), 1.0, 2.0, true),
    );
    let db = dir.path().join("real.db");
    let campaign = dir.path().join("real.toml");
    // 21 grid points each way in a full scan, then 6 random targets each way.
    let hardware = rig::real_hardware(&r.x, &r.y, [500.0, 3000.0], [500.0, 4000.0], rig::CAMERA);
    let tail = "full_scan = true\n[reconstruction]\nmethod = \"pchip\"\n";
    let text = x_campaign("real-rig", &hardware, [1000.0, 1200.0], 6, tail, dir.path());
    std::fs::write(&campaign, text).unwrap();

    let o = run_json(&campaign, &db);
    let j = json_of(&o);
    assert_eq!(j["state"], "done", "{j}");

    let s = Store::open(&db).unwrap();
    let row = s.campaign(1).unwrap().unwrap();
    // 21 grid points each way for the full scan, 6 random targets each way for CS.
    assert_eq!(row.planned, 2 * 21 + 2 * 6);
    let samples = s.samples(1).unwrap();
    assert_eq!(samples.len() as u64, row.planned);
    let events = s.events_after(1, 0).unwrap();
    let rig = events.iter().find(|e| e.kind == "rig").expect("rig event");
    let describe = rig.data["describe"]
        .as_str()
        .unwrap_or_default()
        .to_string();
    assert!(
        describe.contains("C-863") && describe.contains("CSMTEST01"),
        "{describe}"
    );
    for r in &samples {
        let target = r.target.target_x_um;
        // What the camera saw: the true position, the model's error away from the target.
        let err = r.meas_x_um - target;
        assert!(
            (err - truth_um(target)).abs() < 0.05,
            "seq {}: target {target} µm measured {} µm (error {err} µm, expected {} µm)",
            r.target.seq,
            r.meas_x_um,
            truth_um(target)
        );
        assert!((r.meas_y_um - 2000.0).abs() < 0.05, "y {}", r.meas_y_um);
        // The encoder reports the commanded position, not the truth.
        assert!(
            (r.encoder_um - target).abs() < 0.05,
            "encoder {}",
            r.encoder_um
        );
    }
    // Every move was followed by the driver's motion queries: the campaign did not end with an
    // axis still moving.
    let log = r.stop();
    for axis in ["x", "y"] {
        let sent: Vec<&str> = log
            .iter()
            .filter(|(a, _)| a == axis)
            .map(|(_, c)| c.as_str())
            .collect();
        let last_move = sent.iter().rposition(|c| c.starts_with("MOV "));
        let last_move = last_move.unwrap_or_else(|| panic!("{axis}: no MOV in {sent:?}"));
        assert!(
            sent[last_move + 1..].iter().any(|c| c.starts_with("ONT?")),
            "{axis}: on-target never asked after the last move: {:?}",
            &sent[last_move..]
        );
    }
}
