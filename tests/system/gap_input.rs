//! `csmetro gap` refuses input it cannot diagnose honestly — an empty model, negative run ids,
//! duplicated rows, targets beyond the model's travel, absurdly large models — with exit code 2
//! and one line naming the file and the line, before any diagnosis runs.
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use csmetro::gap::data::{simulate_campaign, to_csv_string, CampaignSpec};
use csmetro_sim::StageModel;

fn ideal() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("config/sim/ideal.toml")
}

fn gap(model: &Path, data: &Path, out: &Path) -> Output {
    Command::new(env!("CARGO_BIN_EXE_csmetro"))
        .args(["gap", "--json", "--model"])
        .arg(model)
        .arg("--data")
        .arg(data)
        .arg("--out")
        .arg(out)
        .output()
        .unwrap()
}

fn expect_input_error(o: &Output, needles: &[&str]) {
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert_eq!(err.trim().lines().count(), 1, "one-line message: {err}");
    for n in needles {
        assert!(err.contains(n), "{n:?} not in {err}");
    }
}

/// A valid two-run campaign CSV (header on line 1, data from line 2).
fn good_csv() -> String {
    let truth = StageModel::load(&ideal()).unwrap();
    let spec = CampaignSpec {
        runs: 2,
        targets_per_line: 6,
        ..Default::default()
    };
    to_csv_string(&simulate_campaign(&truth, &spec, None))
}

fn write(dir: &Path, name: &str, text: &str) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, text).unwrap();
    p
}

#[test]
fn an_empty_model_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let data = write(dir.path(), "d.csv", &good_csv());
    let out = dir.path().join("o");
    for (name, text) in [
        ("empty.toml", ""),
        ("comments.toml", "# nothing yet\n"),
        ("stage_only.toml", "[stage]\ntravel_x_um = [0.0, 9500.0]\n"),
    ] {
        let m = write(dir.path(), name, text);
        expect_input_error(
            &gap(&m, &data, &out),
            &[&format!("{name}:1:"), "empty model"],
        );
    }
    assert!(!out.exists(), "no output on bad input");
}

#[test]
fn negative_run_ids_are_refused_at_their_line() {
    let dir = tempfile::tempdir().unwrap();
    let text = good_csv();
    let mut lines: Vec<String> = text.lines().map(String::from).collect();
    // Data line 7 (file line 8) gets run -1.
    let (_, rest) = lines[7].split_once(',').unwrap();
    lines[7] = format!("-1,{rest}");
    let data = write(dir.path(), "neg.csv", &lines.join("\n"));
    expect_input_error(
        &gap(&ideal(), &data, &dir.path().join("o")),
        &["neg.csv:8:", "`run` = -1"],
    );
}

#[test]
fn duplicate_rows_are_refused_naming_both_lines() {
    let dir = tempfile::tempdir().unwrap();
    let text = good_csv();
    let mut lines: Vec<String> = text.lines().map(String::from).collect();
    let copy = lines[3].clone();
    lines.push(copy);
    let n = lines.len();
    let data = write(dir.path(), "dup.csv", &lines.join("\n"));
    expect_input_error(
        &gap(&ideal(), &data, &dir.path().join("o")),
        &[&format!("dup.csv:{n}:"), "duplicate", "line 4"],
    );
}

#[test]
fn targets_beyond_the_travel_are_refused_at_their_line() {
    let dir = tempfile::tempdir().unwrap();
    let text = good_csv();
    let mut lines: Vec<String> = text.lines().map(String::from).collect();
    // ideal.toml: x travel [0, 9500] µm; target_x_um is the 4th column.
    let mut f: Vec<String> = lines[5].split(',').map(String::from).collect();
    f[3] = "12000.000".into();
    lines[5] = f.join(",");
    let data = write(dir.path(), "far.csv", &lines.join("\n"));
    expect_input_error(
        &gap(&ideal(), &data, &dir.path().join("o")),
        &["far.csv:6:", "target_x_um", "travel"],
    );
}

/// 1,000 `cos_um` terms kept `gap` busy for over a minute; now refused at once, at its line.
#[test]
fn an_absurd_model_is_refused_quickly() {
    let dir = tempfile::tempdir().unwrap();
    let data = write(dir.path(), "d.csv", &good_csv());
    let terms: Vec<String> = (0..1000).map(|i| format!("{}e-3", i % 9)).collect();
    let m = write(
        dir.path(),
        "huge.toml",
        &format!(
            "[[effect]]\nkind = \"leadscrew_cyclic\"\naxis = \"x\"\nperiod_um = 400.0\ncos_um = [{}]\n",
            terms.join(", ")
        ),
    );
    // Refused at parse (the error names the term bound) before anything is fitted.
    let o = gap(&m, &data, &dir.path().join("o"));
    expect_input_error(&o, &["huge.toml:5:", "cos_um", "64"]);
}
