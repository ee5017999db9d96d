//! `csmetro gap` on ISO 230-2 data as users have it: the export of a bidirectional positioning
//! test (one row per cycle, direction and target, with the deviation), one measured component,
//! a coarse fixed-target grid, a large scale error, tens of µm of backlash, a sensor
//! nonlinearity outside the library and a slow drift. Data from the independent generator
//! (tests/common/gapgen.rs), run through the binary.
use crate::gapgen;

use std::fmt::Write as _;
use std::path::Path;
use std::process::Command;

use csmetro_sim::AxisId;
use gapgen::*;
use serde_json::Value;

const MODEL: &str = "# An ideal 40 mm axis measured by a triangulation sensor.
[stage]
travel_x_um = [0.0, 40000.0]
travel_y_um = [0.0, 1000.0]

[[effect]]
kind = \"noise\"
axis = \"x\"
sigma_um = 0.5
";

const BACKLASH_UM: f64 = -25.46;
const SCALE_PPM: f64 = -3570.0;

/// The ISO export of a 5-cycle bidirectional test with `n` targets.
fn iso_export(n: usize, seed: u64, with_time: bool) -> String {
    let mut rng = Rng::new(seed);
    let travel = [0.0, 40000.0];
    let lines = vec![Line {
        moving: AxisId::X,
        static_um: 0.0,
        targets: iso_targets(n, travel, &mut rng),
    }];
    let truth = vec![
        Eff::Backlash {
            axis: AxisId::X,
            reversal_um: BACKLASH_UM,
        },
        Eff::Scale {
            axis: AxisId::X,
            ppm: SCALE_PPM,
        },
        Eff::Nonlin {
            axis: AxisId::X,
            amp_um: 15.0,
        },
        // About 10 µm over the five cycles.
        Eff::Thermal {
            comp: AxisId::X,
            amp_um: 0.0,
            tau_s: 1.0,
            rate_um_per_h: 10.0 / (5.0 * (2 * n + 20) as f64 * 15.0 / 3600.0),
        },
    ];
    let camp = Campaign {
        runs: 5,
        noise_um: 0.5,
        offset_um: 0.3,
        measure: [true, false],
        dt_s: 15.0,
        travel: [travel, [0.0, 1000.0]],
    };
    let samples = generate(&truth, &lines, &camp, rng.u64());
    let mut s = String::from(if with_time {
        "cycle,direction,target_um,deviation_um,time_s\n"
    } else {
        "cycle,direction,target_um,deviation_um\n"
    });
    for x in samples {
        let dir = if x.direction > 0.0 { "up" } else { "down" };
        let _ = write!(
            s,
            "{},{dir},{:.3},{:.4}",
            x.run,
            x.target_x_um,
            x.meas_x_um - x.target_x_um
        );
        if with_time {
            let _ = write!(s, ",{:.1}", x.time_s);
        }
        s.push('\n');
    }
    s
}

fn run_gap(dir: &Path, data: &str) -> (Value, String) {
    let model = dir.join("model.toml");
    std::fs::write(&model, MODEL).unwrap();
    let d = dir.join("iso.csv");
    std::fs::write(&d, data).unwrap();
    let o = Command::new(env!("CARGO_BIN_EXE_csmetro"))
        .args(["gap", "--json", "--model"])
        .arg(&model)
        .arg("--data")
        .arg(&d)
        .arg("--out")
        .arg(dir.join("out"))
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr).to_string();
    assert_eq!(o.status.code(), Some(0), "{err}");
    (
        serde_json::from_slice(&o.stdout).expect("one JSON object"),
        err,
    )
}

fn param(j: &Value, kind: &str, key: &str) -> Option<f64> {
    j["added"]
        .as_array()?
        .iter()
        .find(|a| a["kind"] == kind && a["axis"] == "x")
        .and_then(|a| a["params"][key].as_f64())
}

#[test]
fn an_iso_230_2_export_names_backlash_and_scale_and_reports_drift() {
    for (n, seed) in [(9, 1), (11, 2), (21, 3)] {
        let dir = tempfile::tempdir().unwrap();
        let (j, _) = run_gap(dir.path(), &iso_export(n, seed, seed != 2));
        let ctx = format!("{n} targets: {j:#}");
        assert_eq!(j["data_format"], "iso230", "{ctx}");
        let b = param(&j, "backlash", "reversal_um").or_else(|| param(&j, "hysteresis", "b0_um"));
        let b = b.unwrap_or_else(|| panic!("backlash not named; {ctx}"));
        assert!((b / BACKLASH_UM - 1.0).abs() < 0.10, "backlash {b}; {ctx}");
        let ppm = param(&j, "scale", "ppm").unwrap_or_else(|| panic!("scale not named; {ctx}"));
        assert!((ppm / SCALE_PPM - 1.0).abs() < 0.15, "scale {ppm}; {ctx}");
        let before = j["heldout_rms_before_um"].as_f64().unwrap();
        let after = j["heldout_rms_after_um"].as_f64().unwrap();
        assert!(
            after <= 0.4 * before,
            "held-out RMS {before} -> {after}; {ctx}"
        );
        let notes = j["notes"].as_array().unwrap();
        let drift_noted = notes.iter().any(|n| n.as_str().unwrap().contains("drift"));
        let drift_added = j["added"]
            .as_array()
            .unwrap()
            .iter()
            .any(|a| a["kind"] == "thermal_drift");
        assert!(drift_noted || drift_added, "drift not reported; {ctx}");
        // The ISO 230-2 figures beside the diagnosis: B̄ is the reversal the data show.
        let f = &j["iso230"][0]["figures"];
        assert!(
            (f["b_mean_um"].as_f64().unwrap() / BACKLASH_UM - 1.0).abs() < 0.15,
            "{f}"
        );
        for k in [
            "a_um",
            "a_up_um",
            "a_down_um",
            "e_up_um",
            "e_down_um",
            "m_um",
            "r_up_um",
            "r_down_um",
        ] {
            assert!(f[k].as_f64().is_some(), "{k} missing: {f}");
        }
        // Targets 1.8-4 mm apart: a 400 µm leadscrew period cannot be resolved (said so), and
        // no "frequency" is made up from them: none shorter than twice the target spacing, none
        // with an amplitude beyond the data's.
        assert!(
            notes.iter().any(|n| {
                let n = n.as_str().unwrap();
                n.contains("leadscrew_cyclic x") && n.contains("cannot be resolved")
            }),
            "{ctx}"
        );
        let spacing = 40000.0 / (n as f64 + 1.0);
        for p in j["frequency"]
            .as_array()
            .unwrap()
            .iter()
            .chain(j["unexplained"]["frequency"].as_array().unwrap())
        {
            assert!(
                p["period_um"].as_f64().unwrap() >= 1.5 * spacing,
                "{p}; {ctx}"
            );
            assert!(p["amplitude_um"].as_f64().unwrap() < 200.0, "{p}; {ctx}");
        }
    }
}

#[test]
fn only_the_measured_component_counts() {
    // Campaign format with `meas_y_um` empty: σ is the sensor's, not √2 too small.
    let mut rng = Rng::new(5);
    let lines = contract_layout(60, 0, &mut rng)
        .into_iter()
        .filter(|l| l.moving == AxisId::X)
        .collect::<Vec<_>>();
    let camp = Campaign {
        measure: [true, false],
        runs: 4,
        ..Campaign::default()
    };
    let truth = vec![
        Eff::Cyclic {
            axis: AxisId::X,
            period_um: 400.0,
            cos_um: vec![0.4],
            sin_um: vec![0.2],
        },
        Eff::Backlash {
            axis: AxisId::X,
            reversal_um: 1.5,
        },
    ];
    let samples = generate(&truth, &lines, &camp, 9);
    let text = csmetro::gap::data::to_csv_string(&samples);
    assert!(
        text.lines().nth(1).unwrap().ends_with(','),
        "empty meas_y_um field"
    );
    let dir = tempfile::tempdir().unwrap();
    let model = Path::new(env!("CARGO_MANIFEST_DIR")).join("config/sim/ideal.toml");
    let d = dir.path().join("d.csv");
    std::fs::write(&d, text).unwrap();
    let o = Command::new(env!("CARGO_BIN_EXE_csmetro"))
        .args(["gap", "--json", "--model"])
        .arg(&model)
        .arg("--data")
        .arg(&d)
        .arg("--out")
        .arg(dir.path().join("out"))
        .output()
        .unwrap();
    assert_eq!(
        o.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    let j: Value = serde_json::from_slice(&o.stdout).unwrap();
    let sigma = j["sigma_um"].as_f64().unwrap();
    assert!((sigma / 0.05 - 1.0).abs() < 0.1, "σ {sigma}");
    let before = j["heldout_rms_before_um"].as_f64().unwrap();
    assert!((before / 0.05 - 1.0).abs() < 0.1, "held-out RMS {before}");
    assert!(j["added"].as_array().unwrap().is_empty(), "{j:#}");
    assert!(
        j["notes"]
            .as_array()
            .unwrap()
            .iter()
            .any(|n| n.as_str().unwrap().contains("meas_y_um")),
        "{j:#}"
    );
}

#[test]
fn iso_export_errors_name_file_and_line() {
    let dir = tempfile::tempdir().unwrap();
    let model = dir.path().join("model.toml");
    std::fs::write(&model, MODEL).unwrap();
    for (text, needle) in [
        (
            "cycle,direction,target_um,deviation_um\n1,up,100,0.5\n1,sideways,200,0.1\n",
            ":3: `direction`",
        ),
        (
            "cycle,direction,target_um,deviation_um\n1,up,100,0.5\n1,up,100,0.7\n",
            ":3: duplicate row",
        ),
        (
            "cycle,direction,deviation_um\n1,up,0.5\n",
            ":1: missing column(s) target_um",
        ),
        (
            "cycle,direction,target_um,deviation_um\n1,up,100,NaN\n",
            ":2: `deviation_um`",
        ),
    ] {
        let d = dir.path().join("bad.csv");
        std::fs::write(&d, text).unwrap();
        let o = Command::new(env!("CARGO_BIN_EXE_csmetro"))
            .args(["gap", "--model"])
            .arg(&model)
            .arg("--data")
            .arg(&d)
            .arg("--out")
            .arg(dir.path().join("out"))
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{err}");
        assert_eq!(err.trim().lines().count(), 1, "{err}");
        assert!(
            err.contains(needle) && err.contains("bad.csv"),
            "{needle}: {err}"
        );
    }
}
