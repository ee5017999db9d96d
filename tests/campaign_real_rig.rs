//! A `kind = "real"` campaign through the hardware code path, with simulators behind the wires:
//! the C-863 driver talks GCS over TCP to simulated controllers (the way a terminal server or the
//! USB-serial link carries it), and the camera is opened by IP through Aravis, GigE Vision
//! discovery, GVCP and GVSP included, from a fake GV camera that draws the pattern at the
//! simulated stage's true position. Nothing in `csmetro run` knows it is not a lab.
//!
//! Needs the `aravis` feature (libaravis): `cargo test --features aravis --test campaign_real_rig`.
#![cfg(feature = "aravis")]
mod common;
mod rig;

use std::path::Path;

use common::{bin, json_of};
use csmetro::store::Store;

/// X carries a 1000 ppm scale error: the stage really stands 1 µm further per mm than commanded
/// (and than its encoder says), so a sample can only show it if it came from the camera.
const MODEL: &str = r#"
[stage]
travel_x_um = [0.0, 9500.0]
travel_y_um = [0.0, 4200.0]

[[effect]]
kind = "scale"
axis = "x"
ppm = 1000.0
ref_um = 0.0
"#;

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
    std::fs::write(
        &campaign,
        format!(
            r#"[campaign]
name = "real-rig"
stage = "lab-xy"
{hardware}
[axes.x]
range_um = [1000.0, 1200.0]
step_um = 10.0
other_at_um = 2100.0
m = 6

[sampling]
design = "random"
seed = 4
full_scan = true

[acquisition]
directions = ["forward", "backward"]
settle_s = 0.0
dwell_s = 0.0
approach_um = 20.0

[reconstruction]
method = "pchip"

[outputs]
dir = "{out}/{{name}}-{{id}}"
"#,
            hardware =
                rig::real_hardware(&r.x, &r.y, [500.0, 3000.0], [500.0, 4000.0], rig::CAMERA),
            out = dir.path().display(),
        ),
    )
    .unwrap();

    let o = bin()
        .args(["run", "--json", "--quiet", "--db"])
        .arg(&db)
        .arg(&campaign)
        .output()
        .unwrap();
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
        // What the camera saw: the true position, 1000 ppm beyond the target.
        let err = r.meas_x_um - target;
        assert!(
            (err - 1e-3 * target).abs() < 0.05,
            "seq {}: target {target} µm measured {} µm (error {err} µm, expected {} µm)",
            r.target.seq,
            r.meas_x_um,
            1e-3 * target
        );
        assert!((r.meas_y_um - 2100.0).abs() < 0.05, "y {}", r.meas_y_um);
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
