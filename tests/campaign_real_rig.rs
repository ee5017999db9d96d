//! A `kind = "real"` campaign through the hardware code path, with simulators behind the wires:
//! the C-863 driver talks GCS over TCP to simulated controllers (the way a terminal server or the
//! USB-serial link carries it), and the camera is opened by IP through Aravis, GigE Vision
//! discovery, GVCP and GVSP included, from a fake GV camera that draws the pattern at the
//! simulated stage's true position. Nothing in `csmetro run` knows it is not a lab.
//!
//! Needs the `aravis` feature (libaravis): `cargo test --features aravis --test campaign_real_rig`.
#![cfg(feature = "aravis")]
mod common;

use std::sync::Arc;

use common::{bin, json_of};
use csmetro::store::Store;
use csmetro_camera::{FakeGvCamera, FrameSource};
use csmetro_hal::Pixels;
use csmetro_ppp::render;
use csmetro_ppp::{Optics, Pattern, PatternConfig, Pose};
use csmetro_sim::SimStage;
use csmetro_sim::{AxisId, StageModel};
use csmetro_sim::{ControllerConfig, Endpoint, SimController};

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

fn tcp_port(sim: &SimController) -> u16 {
    match sim.endpoint() {
        Endpoint::Tcp(a) => a.port(),
        other => panic!("expected TCP, got {other:?}"),
    }
}

#[test]
fn a_real_rig_campaign_runs_over_gcs_tcp_and_gige_vision() {
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .unwrap();
    let model = StageModel::from_toml_str(MODEL).unwrap();
    let stage = SimStage::new(model, 1000.0, [1.0, 2.0], 1.5, 5.0);
    let cfg = ControllerConfig {
        travel_mm: [-1.0, 14.0],
        reference_switch_mm: 6.5,
        ..ControllerConfig::default()
    };
    let sims: Vec<SimController> = rt.block_on(async {
        let mut v = Vec::new();
        for (a, start_mm) in [(AxisId::X, 1.0), (AxisId::Y, 2.0)] {
            let c = ControllerConfig {
                start_mm,
                ..cfg.clone()
            };
            v.push(
                SimController::start_tcp(stage.clone(), a, c, "127.0.0.1:0".parse().unwrap())
                    .await
                    .unwrap(),
            );
        }
        v
    });
    let (px, py) = (tcp_port(&sims[0]), tcp_port(&sims[1]));

    let pattern = Pattern::new(PatternConfig::default()).unwrap();
    let seen = stage.clone();
    let drawn = Arc::new(std::sync::atomic::AtomicU64::new(0));
    let drawn2 = drawn.clone();
    let source: FrameSource = Arc::new(move |buf: &mut [u8], w: usize, h: usize| {
        let (x, y) = seen.true_position_um();
        let optics = Optics {
            width: w,
            height: h,
            ..Optics::default()
        };
        let k = drawn2.fetch_add(1, std::sync::atomic::Ordering::SeqCst);
        let f = render(&pattern, &optics, Pose::new(x, y, 0.0), k);
        if let Pixels::Mono8(p) = f.pixels {
            buf[..p.len()].copy_from_slice(&p);
        }
    });
    let fake = FakeGvCamera::start(source).expect("fake GV camera on 127.0.0.1");

    let dir = tempfile::tempdir().unwrap();
    let db = dir.path().join("real.db");
    let campaign = dir.path().join("real.toml");
    std::fs::write(
        &campaign,
        format!(
            r#"[campaign]
name = "real-rig"
stage = "lab-xy"

[hardware]
kind = "real"
# The decoder's optics: the fake sensor's full 1024 x 768 frame.
optics = {{ width = 1024, height = 768 }}

[hardware.controllers.x]
transport = {{ kind = "tcp", address = "127.0.0.1:{px}" }}
soft_limits_um = [500.0, 3000.0]
poll_interval_ms = 2

[hardware.controllers.y]
transport = {{ kind = "tcp", address = "127.0.0.1:{py}" }}
soft_limits_um = [500.0, 4000.0]
poll_interval_ms = 2

[hardware.camera]
id = {{ ip = "{ip}" }}
exposure_us = 1000.0

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
            ip = fake.ip(),
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
    assert!(drawn.load(std::sync::atomic::Ordering::SeqCst) >= row.planned);
    let events = s.events_after(1, 0).unwrap();
    let rig = events.iter().find(|e| e.kind == "rig").expect("rig event");
    let describe = rig.data["describe"]
        .as_str()
        .unwrap_or_default()
        .to_string();
    assert!(
        describe.contains("C-863") && describe.contains(fake.serial()),
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
    // Motion stopped and both axes at rest at the end.
    rt.block_on(async {
        for (sim, a) in sims.into_iter().zip([AxisId::X, AxisId::Y]) {
            assert!(
                !sim.stage().with_axis(a, |s, _| s.is_moving()),
                "{a} at rest"
            );
            assert!(sim.controller().command_count() > 0);
            sim.shutdown().await;
        }
    });
}
