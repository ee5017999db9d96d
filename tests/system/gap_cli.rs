//! `csmetro gap` through the binary: end to end on a simulated "real" stage (the updated model
//! shrinks the gap on a fresh campaign by the reported amount), bad input, and the selftest.
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use csmetro::gap::data::{read_csv, simulate_campaign, write_csv, CampaignSpec};
use csmetro::gap::residual_rms_um;
use csmetro_sim::StageModel;

fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_csmetro"))
}

fn config(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("config/sim")
        .join(name)
}

fn json_of(o: &Output) -> serde_json::Value {
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let stdout = String::from_utf8(o.stdout.clone()).unwrap();
    assert_eq!(stdout.trim().lines().count(), 1, "exactly one JSON object");
    serde_json::from_str(stdout.trim()).unwrap()
}

fn gap(model: &Path, data: &Path, out: &Path) -> Output {
    bin()
        .args(["gap", "--json", "--model"])
        .arg(model)
        .arg("--data")
        .arg(data)
        .arg("--out")
        .arg(out)
        .output()
        .unwrap()
}

/// Simulated campaign on the "real" stage → gap → updated model → a fresh campaign (new seed, not
/// used to fit) shows the gap shrunk by the reported amount.
#[test]
fn end_to_end_updated_model_shrinks_the_gap_on_a_fresh_campaign() {
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("campaign.csv");
    let st = bin()
        .args(["gap", "simulate", "--seed", "21", "--truth"])
        .arg(config("real_stage.toml"))
        .arg("--out")
        .arg(&data)
        .status()
        .unwrap();
    assert!(st.success());
    let out = dir.path().join("gap");
    let j = json_of(&gap(&config("ideal.toml"), &data, &out));
    for key in [
        "heldout_rms_before_um",
        "heldout_rms_after_um",
        "added",
        "where",
        "unexplained",
    ] {
        assert!(j.get(key).is_some(), "missing {key}");
    }
    let before = j["heldout_rms_before_um"].as_f64().unwrap();
    let after = j["heldout_rms_after_um"].as_f64().unwrap();
    let added: Vec<(String, String)> = j["added"]
        .as_array()
        .unwrap()
        .iter()
        .map(|a| {
            for key in [
                "kind",
                "axis",
                "params",
                "heldout_rms_um",
                "gap_closed",
                "ties",
            ] {
                assert!(a.get(key).is_some(), "added item lacks {key}");
            }
            (
                a["kind"].as_str().unwrap().to_string(),
                a["axis"].as_str().unwrap().to_string(),
            )
        })
        .collect();
    // The real stage has exactly three withheld effects (see config/sim/real_stage.toml).
    let mut sorted = added.clone();
    sorted.sort();
    let expect = [
        ("backlash", "y"),
        ("squareness", "y"),
        ("straightness", "x"),
    ];
    assert_eq!(
        sorted,
        expect
            .iter()
            .map(|(k, a)| (k.to_string(), a.to_string()))
            .collect::<Vec<_>>(),
        "{j:#}"
    );
    assert_eq!(j["unexplained"]["significant"], false);
    assert!(!j["where"].as_array().unwrap().is_empty());
    let sq = j["added"]
        .as_array()
        .unwrap()
        .iter()
        .find(|a| a["kind"] == "squareness")
        .unwrap();
    let angle = sq["params"]["angle_urad"].as_f64().unwrap();
    assert!((angle - 60.0).abs() < 3.0, "squareness {angle} µrad");

    // The written model loads and re-predicts a fresh campaign.
    let updated = StageModel::load(&out.join("model.toml")).unwrap();
    let truth = StageModel::load(&config("real_stage.toml")).unwrap();
    let ideal = StageModel::load(&config("ideal.toml")).unwrap();
    let fresh = simulate_campaign(
        &truth,
        &CampaignSpec {
            seed: 987,
            ..Default::default()
        },
        None,
    );
    let fresh_before = residual_rms_um(&ideal, &fresh);
    let fresh_after = residual_rms_um(&updated, &fresh);
    assert!(
        (fresh_before / before - 1.0).abs() < 0.1,
        "fresh {fresh_before} vs reported {before}"
    );
    assert!(
        (fresh_after / after - 1.0).abs() < 0.1,
        "fresh {fresh_after} vs reported {after}"
    );
    let (reported, seen) = (1.0 - after / before, 1.0 - fresh_after / fresh_before);
    assert!(
        (reported - seen).abs() < 0.05,
        "shrink reported {reported}, seen {seen}"
    );
    assert!(seen > 0.5, "the gap must shrink: {seen}");
    // At the noise floor: the fitted model is as good as the truth on fresh data.
    let floor = residual_rms_um(&truth, &fresh);
    assert!(fresh_after < 1.05 * floor, "{fresh_after} vs truth {floor}");

    // Running the diagnosis again with the updated model finds no gap left.
    let fresh_csv = dir.path().join("fresh.csv");
    write_csv(&fresh_csv, &fresh).unwrap();
    assert_eq!(read_csv(&fresh_csv).unwrap().len(), fresh.len());
    let j2 = json_of(&gap(
        &out.join("model.toml"),
        &fresh_csv,
        &dir.path().join("g2"),
    ));
    assert_eq!(j2["added"].as_array().unwrap().len(), 0, "{j2:#}");
    assert_eq!(j2["unexplained"]["significant"], false);
}

fn expect_input_error(o: &Output, needles: &[&str]) {
    assert_eq!(
        o.status.code(),
        Some(2),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(err.trim().lines().count(), 1, "one-line message: {err}");
    for n in needles {
        assert!(err.contains(n), "{n:?} not in {err}");
    }
}

#[test]
fn bad_input_exits_2_with_a_one_line_message() {
    let dir = tempfile::tempdir().unwrap();
    let good = dir.path().join("good.csv");
    let truth = StageModel::load(&config("ideal.toml")).unwrap();
    let spec = CampaignSpec {
        runs: 2,
        targets_per_line: 6,
        ..Default::default()
    };
    write_csv(&good, &simulate_campaign(&truth, &spec, None)).unwrap();
    let text = std::fs::read_to_string(&good).unwrap();
    let ideal = config("ideal.toml");
    let out = dir.path().join("o");

    // Unknown kind and unknown parameter in the model.
    let m = dir.path().join("bad_kind.toml");
    std::fs::write(&m, "[[effect]]\nkind = \"warp\"\naxis = \"x\"\n").unwrap();
    expect_input_error(
        &gap(&m, &good, &out),
        &["bad_kind.toml", "unknown kind `warp`"],
    );
    let m = dir.path().join("bad_param.toml");
    std::fs::write(
        &m,
        "[[effect]]\nkind = \"backlash\"\naxis = \"x\"\nreversal_um = 1\nslope = 2\n",
    )
    .unwrap();
    expect_input_error(&gap(&m, &good, &out), &["unknown parameter `slope`"]);

    // Missing column.
    let d = dir.path().join("nocol.csv");
    let no_time: String = text
        .lines()
        .map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            [&f[..5], &f[6..]].concat().join(",")
        })
        .collect::<Vec<_>>()
        .join("\n");
    std::fs::write(&d, no_time).unwrap();
    expect_input_error(&gap(&ideal, &d, &out), &["nocol.csv:1", "time_s"]);

    // NaN on data line 5 (file line 6).
    let d = dir.path().join("nan.csv");
    let mut lines: Vec<String> = text.lines().map(String::from).collect();
    let (head, _) = lines[5].rsplit_once(',').unwrap();
    lines[5] = format!("{head},NaN");
    std::fs::write(&d, lines.join("\n")).unwrap();
    expect_input_error(&gap(&ideal, &d, &out), &["nan.csv:6", "meas_y_um"]);

    // A single run: nothing can be held out.
    let d = dir.path().join("one.csv");
    let one: Vec<&str> = text
        .lines()
        .enumerate()
        .filter(|(i, l)| *i == 0 || l.starts_with("1,"))
        .map(|(_, l)| l)
        .collect();
    std::fs::write(&d, one.join("\n")).unwrap();
    expect_input_error(&gap(&ideal, &d, &out), &["one.csv", "single run"]);

    // A campaign id (not a file): no campaign storage yet.
    expect_input_error(
        &gap(&ideal, Path::new("campaign-2026-11-22"), &out),
        &["campaign-2026-11-22", "campaign storage"],
    );
    assert!(!out.exists(), "no output on bad input");
}

/// The CI-size benchmark: rates measured on fresh seeded cases, loose bounds at this size.
#[test]
fn selftest_quick_reports_rates_and_meets_loose_bounds() {
    let o = bin()
        .args(["gap", "selftest", "--json", "--cases", "8", "--seed", "7"])
        .output()
        .unwrap();
    let j = json_of(&o);
    let rate = |v: &serde_json::Value| v["rate"].as_f64().unwrap();
    assert!(j["targets"].as_array().unwrap().len() == 5);
    assert!(rate(&j["single"]["ge_3_sigma"]) >= 0.8, "{j:#}");
    assert!(rate(&j["no_gap"]["false_attributions"]) <= 0.125, "{j:#}");
    assert!(rate(&j["pairs"]) >= 0.6, "{j:#}");
    assert!(
        j["median_heldout_gap_closed"].as_f64().unwrap() >= 0.7,
        "{j:#}"
    );
    assert!(
        rate(&j["outside_library"]["unexplained_not_misattributed"]) >= 0.6,
        "{j:#}"
    );
}
