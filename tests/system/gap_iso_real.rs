//! `csmetro gap` on real ISO 230-2 tests nobody on the project made (the ESS target-MUTS axes,
//! tests/data/iso230/README.md) and on ISO tables of an independent generator
//! (tests/common/isogen.rs): it names the reversal and the drift a metrologist reads off the
//! table, with values and standard errors, names nothing in noise, and says what the layout
//! cannot see.
#[path = "../common/isogen.rs"]
mod isogen;

use std::path::{Path, PathBuf};
use std::process::Command;

use csmetro::gap::data::Sample;
use csmetro::gap::{diagnose, Diagnosis, Options};
use csmetro_sim::{AxisId, StageModel};
use isogen::*;
use serde_json::Value;

fn data(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data/iso230")
        .join(name)
}

/// An ideal stage (noise only) whose travel covers the targets.
fn ideal_model(lo: f64, hi: f64) -> String {
    format!(
        "[stage]\ntravel_x_um = [{lo:.1}, {hi:.1}]\ntravel_y_um = [0.0, 1000.0]\n\n[[effect]]\nkind = \"noise\"\naxis = \"x\"\nsigma_um = 1.0\n"
    )
}

fn run_cli(file: &Path, lo: f64, hi: f64, json: bool) -> (Value, String) {
    let dir = tempfile::tempdir().unwrap();
    let model = dir.path().join("model.toml");
    std::fs::write(&model, ideal_model(lo, hi)).unwrap();
    let mut args = vec!["gap"];
    if json {
        args.push("--json");
    }
    let o = Command::new(env!("CARGO_BIN_EXE_csmetro"))
        .args(&args)
        .arg("--model")
        .arg(&model)
        .arg("--data")
        .arg(file)
        .arg("--out")
        .arg(dir.path().join("out"))
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr).to_string();
    assert_eq!(o.status.code(), Some(0), "{err}");
    let out = String::from_utf8_lossy(&o.stdout).to_string();
    if json {
        (serde_json::from_str(&out).expect("one JSON object"), out)
    } else {
        (Value::Null, out)
    }
}

fn named<'a>(j: &'a Value, kind: &str) -> Option<&'a Value> {
    j["findings"]
        .as_array()?
        .iter()
        .find(|f| f["kind"] == kind && f["named"] == true)
}

#[test]
fn muts_x_names_the_backlash_and_the_drift_and_says_what_it_cannot_see() {
    let f = data("muts_b02_x.csv");
    let (j, _) = run_cli(&f, -21000.0, 21000.0, true);
    let ctx = format!("{j:#}");
    // The ISO figures as before.
    let fig = &j["iso230"][0]["figures"];
    for (k, v) in [
        ("a_um", 135.27),
        ("b_um", 33.58),
        ("e_um", 122.85),
        ("m_um", 93.65),
        ("r_um", 55.16),
    ] {
        assert!((fig[k].as_f64().unwrap() - v).abs() < 0.01, "{k}: {fig}");
    }
    // Backlash: −25.4 µm by hand (± 1.9 over targets); drift-corrected it may move by half
    // a cycle's drift (0.7 µm).
    let b = named(&j, "backlash").unwrap_or_else(|| panic!("backlash not named: {ctx}"));
    let v = b["value_um"].as_f64().unwrap();
    assert!((v / -25.4 - 1.0).abs() < 0.15, "backlash {v}");
    let se = b["se_um"].as_f64().unwrap();
    assert!((1.0..3.0).contains(&se), "se {se}");
    // In `added` too, with the library's parameter.
    let added = j["added"].as_array().unwrap();
    let rev = added
        .iter()
        .find(|a| a["kind"] == "backlash")
        .and_then(|a| a["params"]["reversal_um"].as_f64())
        .unwrap();
    assert!((rev - v).abs() < 1e-9);
    // Drift: −1.42 µm per cycle by hand.
    let d = named(&j, "thermal_drift").unwrap_or_else(|| panic!("drift not named: {ctx}"));
    let r = d["rate_um_per_cycle"].as_f64().unwrap();
    assert!((-2.0..-0.9).contains(&r), "drift {r} µm/cycle");
    assert!(d["shape"].is_string() && d["rate_se_um_per_cycle"].as_f64().unwrap() > 0.0);
    assert_eq!(j["drift"]["significant"], true, "{}", j["drift"]);
    assert_eq!(j["drift"]["between_cycles"][0]["named"], true);
    // No time column: no rate per hour is made up.
    assert!(d["rate_um_per_h"].is_null(), "{d}");
    let (rb, ra) = (
        d["r_before_um"].as_f64().unwrap(),
        d["r_after_um"].as_f64().unwrap(),
    );
    assert!(ra < rb, "R {rb} -> {ra}");
    let before = j["heldout_rms_before_um"].as_f64().unwrap();
    let after = j["heldout_rms_after_um"].as_f64().unwrap();
    assert!(after < before, "held-out {before} -> {after}");
    assert!(
        before > 30.0 && after > 25.0,
        "the position error stays: {after}"
    );
    // Nothing else is named (no scale: the table has no linear part).
    for f in j["findings"].as_array().unwrap() {
        if f["named"] == true {
            assert!(
                ["backlash", "thermal_drift", "hysteresis"].contains(&f["kind"].as_str().unwrap()),
                "{f}"
            );
        }
    }
    // What it cannot see: the ~30 µm position error, why, and what to measure.
    let cannot = j["cannot_see"].as_array().unwrap();
    let text: Vec<&str> = cannot.iter().map(|c| c.as_str().unwrap()).collect();
    assert!(
        text.iter().any(|t| t.contains("position-dependent error")
            && t.contains("resolve no period below 10000 µm")
            && t.contains("400 µm")),
        "{text:?}"
    );
    let pe = &j["iso_decomposition"]["tables"][0]["cannot_see"]["position_error"];
    let rms = pe["rms_um"].as_f64().unwrap();
    assert!((20.0..40.0).contains(&rms), "{pe}");
    // The text report says the same.
    let (_, txt) = run_cli(&f, -21000.0, 21000.0, false);
    assert!(txt.contains("backlash (reversal"), "{txt}");
    assert!(txt.contains("drift between cycles"), "{txt}");
    assert!(txt.contains("cannot see:"), "{txt}");
    assert!(!txt.contains("which: no effect improves"), "{txt}");
}

/// The other MUTS tables: reversals and drifts of their own, checked against the hand
/// decomposition in tests/data/iso230/README.md.
#[test]
fn other_real_tables_name_what_the_hand_decomposition_shows() {
    // (file, travel, backlash by hand (None: not significant by hand), drift per cycle by hand
    // (None: no trend by hand)).
    struct Case {
        file: &'static str,
        travel: [f64; 2],
        backlash: Option<f64>,
        drift: Option<f64>,
    }
    let cases = [
        Case {
            file: "muts_b02_y.csv",
            travel: [-21000.0, 21000.0],
            backlash: Some(-12.77),
            drift: Some(-3.20),
        },
        Case {
            file: "muts_b02_z.csv",
            travel: [-16000.0, 6000.0],
            backlash: Some(-1.61),
            drift: None,
        },
        Case {
            file: "muts_w42_x_ild50.csv",
            travel: [-5000.0, 5000.0],
            backlash: None,
            drift: None,
        },
        // x̄↑ − x̄↓ −10.55 ± 2.84 µm by hand, its per-target values tilted (−2.6 … −18.6 µm) the
        // way a drift of −10.6 µm per cycle acting between the two passes tilts them.
        Case {
            file: "muts_w42_y_ild50.csv",
            travel: [-5000.0, 5000.0],
            backlash: Some(-10.55),
            drift: Some(-10.59),
        },
    ];
    for c in cases {
        let (j, _) = run_cli(&data(c.file), c.travel[0], c.travel[1], true);
        let summary: Vec<String> = j["findings"]
            .as_array()
            .unwrap()
            .iter()
            .map(|f| {
                format!(
                    "{} named={} {} ± {} p {}",
                    f["kind"], f["named"], f["value"], f["se"], f["p"]
                )
            })
            .collect();
        let ctx = format!("{}: {summary:#?}", c.file);
        match c.backlash {
            Some(b) => {
                let f = named(&j, "backlash").unwrap_or_else(|| panic!("{ctx}"));
                let v = f["value_um"].as_f64().unwrap();
                let se = f["se_um"].as_f64().unwrap();
                let raw = f["iso_reversal_um"].as_f64().unwrap();
                assert!((raw - b).abs() < 0.01, "{ctx}");
                // A drift correction moves it by at most one cycle's drift.
                let per_cycle = c.drift.unwrap_or(0.0).abs();
                assert!(
                    (v - b).abs() < 0.15 * b.abs() + 2.0 * se + per_cycle,
                    "{ctx}"
                );
            }
            None => assert!(named(&j, "backlash").is_none(), "{ctx}"),
        }
        match c.drift {
            Some(d) => {
                let f = named(&j, "thermal_drift").unwrap_or_else(|| panic!("{ctx}"));
                let r = f["rate_um_per_cycle"].as_f64().unwrap();
                assert!((r / d - 1.0).abs() < 0.35, "{ctx}");
            }
            None => assert!(named(&j, "thermal_drift").is_none(), "{ctx}"),
        }
        if c.backlash.is_none() && c.drift.is_none() {
            // The null: nothing named, nothing left beyond the pure error, no drift.
            assert!(j["added"].as_array().unwrap().is_empty(), "{ctx}");
            assert_eq!(j["unexplained"]["significant"], false, "{ctx}");
            assert_eq!(j["drift"]["significant"], false, "{ctx}");
            let text = j["cannot_see"].as_array().unwrap();
            assert!(
                text.iter()
                    .any(|t| t.as_str().unwrap().contains("cannot show a reversal below")),
                "{ctx}"
            );
        }
    }
}

// ---- Independent generator ---------------------------------------------------------------

fn samples_of(t: &IsoTable) -> Vec<Sample> {
    t.readings
        .iter()
        .map(|r| Sample {
            run: r.cycle as i64,
            moving: AxisId::X,
            direction: if r.up { 1.0 } else { -1.0 },
            target_x_um: r.target_um,
            target_y_um: 0.0,
            time_s: r.time_s,
            meas_x_um: r.target_um + r.deviation_um,
            meas_y_um: f64::NAN,
        })
        .collect()
}

fn diagnose_table(t: &IsoTable) -> Diagnosis {
    let lo = t.spec.start_um - 1000.0;
    let hi = t.spec.start_um + t.spec.span_um + 1000.0;
    let model = StageModel::new([lo, hi], [0.0, 1000.0]);
    let opts = Options {
        iso230: true,
        ..Options::default()
    };
    diagnose(&model, &samples_of(t), &opts).unwrap()
}

fn named_kinds(d: &Diagnosis) -> Vec<String> {
    d.iso
        .as_ref()
        .map(|i| {
            i.findings()
                .filter(|f| f.named)
                .map(|f| format!("{} {:.3}", f.kind, f.value))
                .collect()
        })
        .unwrap_or_default()
}

fn random_layout(g: &mut Pcg) -> IsoSpec {
    IsoSpec {
        targets: g.int(5, 9),
        cycles: 5,
        start_um: g.between(-20000.0, 0.0),
        span_um: g.between(8000.0, 40000.0),
        ..IsoSpec::default()
    }
}

/// Null tables: noise only, or noise and a large repeatable position-dependent error.
fn null_sweep(n: usize, seed: u64) -> (usize, Vec<String>) {
    let mut g = Pcg::new(seed);
    let mut alarms = 0;
    let mut log = Vec::new();
    for i in 0..n {
        let mut s = random_layout(&mut g);
        s.noise_um = g.between(0.2, 3.0);
        s.position = match i % 4 {
            0 => PositionError::None,
            1 => PositionError::SmoothNoLine(g.between(10.0, 50.0) * s.noise_um),
            2 => PositionError::Irregular(g.between(10.0, 50.0) * s.noise_um),
            _ => PositionError::Smooth(g.between(10.0, 50.0) * s.noise_um),
        };
        let t = make(s, g.uniform().to_bits());
        let d = diagnose_table(&t);
        let k = named_kinds(&d);
        if !k.is_empty() || !d.added.is_empty() {
            alarms += 1;
            log.push(format!("null #{i} {:?}: {k:?}", s.position));
        }
    }
    (alarms, log)
}

/// Backlash 1–30 µm and a drift (linear or settling, continuous or per cycle), buried in a
/// large position-dependent error: (backlash named within 15 %, drift named, cases, log).
fn buried_sweep(n: usize, seed: u64) -> (usize, usize, usize, Vec<String>) {
    let mut g = Pcg::new(seed);
    let (mut hit_b, mut hit_d) = (0, 0);
    let mut log = Vec::new();
    for i in 0..n {
        let mut s = random_layout(&mut g);
        let b = g.between(1.0, 30.0) * if g.coin() { 1.0 } else { -1.0 };
        s.backlash_um = b;
        s.noise_um = b.abs() / g.between(8.0, 15.0);
        let rate = g.between(1.5, 4.0) * s.noise_um * if g.coin() { 1.0 } else { -1.0 };
        s.drift = if i % 2 == 0 {
            DriftShape::Linear(rate)
        } else {
            DriftShape::Settling(rate * 5.0, g.between(1.0, 3.0))
        };
        s.drift_continuous = (i / 2) % 2 == 0;
        s.position = if i % 3 == 0 {
            PositionError::Irregular(g.between(10.0, 40.0) * b.abs())
        } else {
            PositionError::SmoothNoLine(g.between(10.0, 40.0) * b.abs())
        };
        let t = make(s, g.uniform().to_bits());
        let d = diagnose_table(&t);
        let iso = d.iso.as_ref().expect("ISO decomposition");
        let fb = iso.findings().find(|f| f.kind == "backlash" && f.named);
        let ok_b = fb.is_some_and(|f| (f.value / b - 1.0).abs() <= 0.15);
        let ok_d = iso.findings().any(|f| f.kind == "thermal_drift" && f.named);
        hit_b += usize::from(ok_b);
        hit_d += usize::from(ok_d);
        if std::env::var("GAP_ISO_SHOW")
            .ok()
            .and_then(|v| v.parse::<usize>().ok())
            == Some(i)
        {
            println!("{}", d.summary());
        }
        if !ok_b || !ok_d {
            let fd = iso.findings().find(|f| f.kind == "thermal_drift");
            log.push(format!(
                "buried #{i}: backlash {b:.2} -> {:?}, drift {:?} continuous {} -> {ok_d} (p {:?}, {:?}); named {:?}",
                fb.map(|f| f.value),
                s.drift,
                s.drift_continuous,
                fd.map(|f| f.p),
                fd.and_then(|f| f.refused.clone()),
                named_kinds(&d)
            ));
        }
    }
    (hit_b, hit_d, n, log)
}

#[test]
fn generated_nulls_name_nothing() {
    let n = 60;
    let (alarms, log) = null_sweep(n, 7);
    assert!(
        alarms * 20 <= n,
        "{alarms}/{n} nulls named something: {log:#?}"
    );
}

#[test]
fn generated_buried_backlash_and_drift_are_named() {
    let n = 40;
    let (b, d, n, log) = buried_sweep(n, 11);
    assert!(b * 10 >= 9 * n, "backlash {b}/{n}: {log:#?}");
    assert!(d * 10 >= 9 * n, "drift {d}/{n}: {log:#?}");
}

/// The figures for BENCHMARKS.md:
/// `GAP_ISO_CASES=400 cargo test --release --test system gap_iso_real::iso_sweep -- --ignored --nocapture`
#[test]
#[ignore]
fn iso_sweep() {
    let n: usize = std::env::var("GAP_ISO_CASES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(200);
    let (alarms, log) = null_sweep(n, 2026);
    for l in &log {
        println!("  {l}");
    }
    println!("nulls: {alarms}/{n} with a named effect");
    let (b, d, n, log) = buried_sweep(n, 2027);
    for l in &log {
        println!("  {l}");
    }
    println!("buried: backlash within 15 % {b}/{n}, drift named {d}/{n}");
}

/// With `time_s` the drift has a rate per hour; a per-cycle step drift leaves the reversal as
/// measured, a continuous one is corrected for what it does between the two passes.
#[test]
fn time_column_gives_the_rate_per_hour() {
    let spec = IsoSpec {
        targets: 7,
        noise_um: 0.5,
        backlash_um: 8.0,
        drift: DriftShape::Linear(2.0),
        position: PositionError::Irregular(20.0),
        ..IsoSpec::default()
    };
    let t = make(spec, 99);
    let dir = tempfile::tempdir().unwrap();
    let f = dir.path().join("iso.csv");
    std::fs::write(&f, t.csv(true)).unwrap();
    let (j, _) = run_cli(&f, -21000.0, 21000.0, true);
    let d = named(&j, "thermal_drift").unwrap_or_else(|| panic!("{j:#}"));
    let cycle_s = 2.0 * 7.0 * spec.dwell_s + 2.0 * spec.reversal_s;
    let per_h = d["rate_um_per_h"].as_f64().unwrap();
    let want = 2.0 / cycle_s * 3600.0;
    assert!((per_h / want - 1.0).abs() < 0.15, "{per_h} vs {want}");
    let per_cycle = d["rate_um_per_cycle"].as_f64().unwrap();
    assert!((per_cycle / 2.0 - 1.0).abs() < 0.15, "{per_cycle}");
    let b = named(&j, "backlash").unwrap()["value_um"].as_f64().unwrap();
    assert!((b / 8.0 - 1.0).abs() < 0.15, "backlash {b}");
    assert_eq!(d["timing"], "continuous in time", "{d}");
}

#[test]
fn simulate_refuses_non_finite_noise_and_huge_sizes() {
    let dir = tempfile::tempdir().unwrap();
    let truth = Path::new(env!("CARGO_MANIFEST_DIR")).join("config/sim/ideal.toml");
    for extra in [
        vec!["--noise-um", "inf"],
        vec!["--noise-um", "NaN"],
        vec!["--noise-um=-1"],
        vec!["--targets", "100000000"],
        vec!["--runs", "1000", "--targets", "100000"],
    ] {
        let o = Command::new(env!("CARGO_BIN_EXE_csmetro"))
            .args(["gap", "simulate", "--truth"])
            .arg(&truth)
            .arg("--out")
            .arg(dir.path().join("d.csv"))
            .args(&extra)
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{extra:?}: {err}");
        assert_eq!(err.trim().lines().count(), 1, "{extra:?}: {err}");
        assert!(!err.contains("panicked"), "{err}");
    }
}

/// Odd tables never panic and never name anything they cannot support: one direction only, too
/// few cycles, one target, missing readings, a constant (quantised) table, huge values.
#[test]
fn odd_tables_are_handled() {
    let base = make(
        IsoSpec {
            targets: 6,
            backlash_um: 5.0,
            position: PositionError::Irregular(10.0),
            ..IsoSpec::default()
        },
        3,
    );
    let opts = Options {
        iso230: true,
        ..Options::default()
    };
    let model = StageModel::new([-21000.0, 21000.0], [0.0, 1000.0]);
    let all = samples_of(&base);
    let variants: Vec<(&str, Vec<Sample>)> = vec![
        (
            "forward only",
            all.iter().filter(|s| s.direction > 0.0).copied().collect(),
        ),
        (
            "two cycles",
            all.iter().filter(|s| s.run <= 2).copied().collect(),
        ),
        (
            "one target",
            all.iter()
                .filter(|s| (s.target_x_um - base.targets[2]).abs() < 1e-6)
                .copied()
                .collect(),
        ),
        (
            "missing readings",
            all.iter()
                .enumerate()
                .filter(|(i, _)| i % 7 != 3)
                .map(|(_, s)| *s)
                .collect(),
        ),
        (
            "constant",
            all.iter()
                .map(|s| Sample {
                    meas_x_um: s.target_x_um,
                    ..*s
                })
                .collect(),
        ),
        (
            "huge",
            all.iter()
                .map(|s| Sample {
                    meas_x_um: s.target_x_um + 1e12 * (s.run as f64),
                    ..*s
                })
                .collect(),
        ),
    ];
    for (name, s) in variants {
        match diagnose(&model, &s, &opts) {
            Ok(d) => {
                let j = d.to_json();
                assert!(j.is_object(), "{name}");
                let _ = d.summary();
                if name == "constant" {
                    assert!(d.added.is_empty(), "{name}: {}", d.summary());
                }
                if name == "forward only" {
                    assert!(
                        !d.added.iter().any(|a| a.kind == "backlash"),
                        "{name}: {}",
                        d.summary()
                    );
                }
            }
            Err(e) => assert!(!e.0.is_empty(), "{name}"),
        }
    }
}

/// Where the targets resolve a library period (here 41 targets ~150 µm apart and the 400 µm
/// leadscrew pitch), the cyclic error is tested and named with the rest; where they do not (the
/// 5 mm grids above) it is only said that they cannot.
#[test]
fn a_resolved_leadscrew_period_is_named_on_a_dense_table() {
    let spec = IsoSpec {
        targets: 41,
        start_um: 1000.0,
        span_um: 6000.0,
        noise_um: 0.2,
        backlash_um: 3.0,
        periodic: Some((400.0, 1.5, 0.7)),
        position: PositionError::SmoothNoLine(5.0),
        ..IsoSpec::default()
    };
    let t = make(spec, 5);
    let d = diagnose_table(&t);
    let iso = d.iso.as_ref().unwrap();
    let c = iso
        .findings()
        .find(|f| f.kind == "leadscrew_cyclic" && f.named)
        .unwrap_or_else(|| panic!("{}", d.summary()));
    assert!((c.value / 1.5 - 1.0).abs() < 0.15, "{}", d.summary());
    assert!(d.added.iter().any(|a| a.kind == "leadscrew_cyclic"));
    let b = iso
        .findings()
        .find(|f| f.kind == "backlash" && f.named)
        .unwrap();
    assert!((b.value / 3.0 - 1.0).abs() < 0.15, "{}", d.summary());
    // Without the periodic error nothing cyclic is named.
    let t = make(
        IsoSpec {
            periodic: None,
            ..spec
        },
        6,
    );
    let d = diagnose_table(&t);
    assert!(
        !d.added.iter().any(|a| a.kind.ends_with("cyclic")),
        "{}",
        d.summary()
    );
}
