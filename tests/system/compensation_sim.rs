//! Compensated motion and the verification run on the simulated demo stage (leadscrew cyclic
//! error, 2 µm backlash, scale error, straightness): characterise a short stretch of x once,
//! then `csmetro verify` and `csmetro move` with the compensation it wrote, and the bad tables
//! they must refuse before anything moves.
use crate::common;

use std::path::{Path, PathBuf};
use std::process::Output;
use std::sync::OnceLock;

use common::{bin, SimFile};
use serde_json::Value;

const STAGE: &str = "comp-sim-xy";

/// The tests share one store and stage: one at a time (the stage lock would refuse the others).
fn serial() -> std::sync::MutexGuard<'static, ()> {
    static M: std::sync::Mutex<()> = std::sync::Mutex::new(());
    M.lock().unwrap_or_else(|e| e.into_inner())
}

/// The characterisation: x over [1000, 3000] µm on a 5 µm grid with y at 0 µm (where a
/// move's simulated rig has it: the x table holds y's own error there), 120 random targets per
/// direction, two cycles. Run once for every test of this file.
fn characterised() -> &'static (PathBuf, PathBuf) {
    static ONCE: OnceLock<(PathBuf, PathBuf)> = OnceLock::new();
    ONCE.get_or_init(|| {
        let dir = tempfile::tempdir().unwrap().keep();
        let camp = sim_file(
            &dir,
            "char",
            "",
            "[axes.x]\nrange_um = [1000.0, 3000.0]\nstep_um = 5.0\nother_at_um = 0.0\nm = 120\n\n\
             [sampling]\ndesign = \"random\"\nseed = 11\n\n\
             [acquisition]\ndirections = [\"forward\", \"backward\"]\ncycles = 2\nsettle_s = 2.0\n\
             dwell_s = 0.5\n\n[reconstruction]\nnoise_um = 0.01",
            "",
        )
        .write(&dir.join("char.toml"));
        let db = dir.join("csmetro.db");
        let o = bin()
            .args(["run", "--quiet", "--db"])
            .arg(&db)
            .arg(&camp)
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        (db, dir.join("char-1"))
    })
}

fn verify(extra: &[&str]) -> Output {
    verify_in(&characterised().0, extra)
}

/// `csmetro verify 1` of the characterisation with the store at `db`.
fn verify_in(db: &Path, extra: &[&str]) -> Output {
    bin()
        .args(["verify", "1", "--quiet", "--cycles", "2", "--db"])
        .arg(db)
        .args(extra)
        .output()
        .unwrap()
}

/// The one JSON object on stdout, whatever the exit code.
fn only_json(o: &Output) -> Value {
    let s = String::from_utf8_lossy(&o.stdout);
    let v: Value =
        serde_json::from_str(s.trim()).unwrap_or_else(|e| panic!("not one JSON object ({e}): {s}"));
    v
}

fn figure(v: &Value, k: &str) -> f64 {
    v[k].as_f64()
        .unwrap_or_else(|| panic!("{k} missing in {v}"))
}

#[test]
fn verification_shows_the_compensation_removing_the_systematic_error() {
    let _one = serial();
    let o = verify(&["--json"]);
    let v = only_json(&o);
    assert_eq!(v["campaign"], 1);
    let passed = v["passed"].as_bool().unwrap();
    // The exit code says the same as "passed".
    assert_eq!(o.status.code(), Some(if passed { 0 } else { 1 }));
    let axes = v["axes"].as_array().unwrap();
    assert_eq!(axes.len(), 1);
    let x = &axes[0];
    assert_eq!(x["axis"], "x");
    let (b, a) = (&x["before"], &x["after"]);
    for f in [b, a] {
        for k in ["a_um", "b_um", "e_um", "m_um", "r_um"] {
            assert!(f[k].is_number(), "{k} in {f}");
        }
    }
    // The stage's 2 µm backlash and its cyclic error dominate before; the compensation takes
    // out the systematic part (E) by close to 10x even at this small size (120 of 401 points).
    assert!(figure(b, "b_um") > 1.5, "{x}");
    assert!(figure(a, "b_um").abs() < 0.3, "{x}");
    let ratio = figure(b, "e_um") / figure(a, "e_um");
    assert!(ratio > 8.0, "E before/after {ratio}: {x}");
    // At never-visited targets (between grid points) too.
    let un = figure(x, "max_abs_after_unvisited_um");
    assert!(
        un < 0.6 && figure(x, "max_abs_before_unvisited_um") > 2.0,
        "{x}"
    );
    assert!(figure(x, "max_abs_after_um") >= un);
    assert!(figure(x, "expected_um") > 0.0);
    // Both verdicts are reachable: the expected residual decides.
    let lax = verify(&[
        "--json",
        "--expected-um",
        "1.0",
        "--targets",
        "3",
        "--unvisited",
        "1",
    ]);
    assert_eq!(lax.status.code(), Some(0));
    assert_eq!(only_json(&lax)["passed"], true);
    let strict = verify(&[
        "--json",
        "--expected-um",
        "0.05",
        "--targets",
        "3",
        "--unvisited",
        "1",
    ]);
    assert_eq!(strict.status.code(), Some(1));
    assert_eq!(only_json(&strict)["passed"], false);
    assert_eq!(only_json(&strict)["axes"][0]["expected_um"], 0.05);
    // Results beside the characterisation's: table with both sides, the plot, the JSON.
    let (_, results) = characterised();
    let txt = std::fs::read_to_string(results.join("verify/summary.txt")).unwrap();
    assert!(txt.contains("before") && txt.contains("after"), "{txt}");
    let svg = std::fs::read_to_string(results.join("verify/verify_x.svg")).unwrap();
    assert!(svg.starts_with("<svg") && svg.contains("after, backward"));
    let store = csmetro::store::Store::open(&characterised().0).unwrap();
    assert!(store.result(1, "verify/verify.json").unwrap().is_some());
    // The pass line on the chart (SVG and PNG), each target against it in the JSON and on the
    // page, and the characterisation's report linking to the page (file and store).
    assert!(svg.contains("pass line ±expected"), "no pass line");
    let png = std::fs::read(results.join("verify/verify_x.png")).unwrap();
    assert!(png.starts_with(b"\x89PNG"));
    let checks = only_json(&strict)["axes"][0]["per_target"].clone();
    let checks = checks.as_array().expect("per_target");
    assert!(!checks.is_empty() && checks.iter().any(|t| t["passed"] == false));
    assert!(checks.iter().all(|t| t["expected_um"] == 0.05));
    let page = std::fs::read_to_string(results.join("verify/report.html")).unwrap();
    assert!(
        page.contains("E before") && page.contains("max |after|"),
        "{page}"
    );
    assert!(page.contains("<td class=\"fail\">FAIL</td>") && page.contains("verify_x.svg"));
    assert!(page.contains("href=\"../report.html\""));
    let link = "href=\"verify/report.html\"";
    let report = std::fs::read_to_string(results.join("report.html")).unwrap();
    assert_eq!(
        report.matches(link).count(),
        1,
        "one link after three verifications"
    );
    let stored = store.result(1, "report.html").unwrap().unwrap().1;
    assert!(String::from_utf8(stored).unwrap().contains(link));
}

/// Copies the characterisation's results to a fresh directory, `edit` changes it.
fn results_copy(name: &str, edit: impl FnOnce(&Path)) -> PathBuf {
    let (_, results) = characterised();
    let d = tempfile::tempdir().unwrap().keep().join(name);
    std::fs::create_dir_all(&d).unwrap();
    for f in ["compensation_x.csv", "summary.json"] {
        std::fs::copy(results.join(f), d.join(f)).unwrap();
    }
    edit(&d);
    d
}

fn refused(o: &Output, needle: &str) {
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(err.contains(needle), "{needle:?} not in {err}");
    assert_eq!(err.trim().lines().count(), 1, "{err}");
    assert!(
        o.stdout.is_empty(),
        "{}",
        String::from_utf8_lossy(&o.stdout)
    );
}

#[test]
fn bad_tables_are_refused_at_load_with_file_and_line_and_nothing_moves() {
    let _one = serial();
    let nan = results_copy("nan", |d| {
        let p = d.join("compensation_x.csv");
        let t = std::fs::read_to_string(&p).unwrap();
        let mut lines: Vec<String> = t.lines().map(String::from).collect();
        let cells: Vec<&str> = lines[10].split(',').collect();
        let n = cells.len();
        lines[10] = format!("{},NaN,{}", cells[..n - 2].join(","), cells[n - 1]);
        std::fs::write(&p, lines.join("\n")).unwrap();
    });
    let header = results_copy("header", |d| {
        let p = d.join("compensation_x.csv");
        let t = std::fs::read_to_string(&p).unwrap();
        std::fs::write(&p, t.replacen("corr_forward_um", "corr_fwd", 1)).unwrap();
    });
    let other_stage = results_copy("stage", |d| {
        let p = d.join("summary.json");
        let t = std::fs::read_to_string(&p).unwrap();
        std::fs::write(&p, t.replace(STAGE, "lab-xy")).unwrap();
    });
    let short = results_copy("short", |d| {
        // Only the grid up to 2000 µm: the characterised travel is [1000, 3000].
        let p = d.join("compensation_x.csv");
        let t = std::fs::read_to_string(&p).unwrap();
        let kept: Vec<&str> = t.lines().take(202).collect();
        std::fs::write(&p, kept.join("\n")).unwrap();
    });
    let nan_file = nan.join("compensation_x.csv");
    let cases: Vec<(PathBuf, String)> = vec![
        (nan.clone(), format!("{}:11:", nan_file.display())),
        (
            header.clone(),
            format!("{}:1:", header.join("compensation_x.csv").display()),
        ),
        (other_stage, "not on \"comp-sim-xy\"".into()),
        (short, "does not cover the travel [1000, 3000]".into()),
    ];
    for (path, needle) in &cases {
        let o = verify(&["--json", "--compensation", path.to_str().unwrap()]);
        refused(&o, needle);
    }
    // The same tables through `move`, except coverage (a move needs its target only).
    for (path, needle) in &cases[..3] {
        let o = mv(&["--x-um", "2000", "--compensation", path.to_str().unwrap()]);
        refused(&o, needle);
    }
}

fn mv(extra: &[&str]) -> Output {
    let (db, _) = characterised();
    bin()
        .args(["move", "--stage", STAGE, "--json", "--db"])
        .arg(db)
        .args(extra)
        .output()
        .unwrap()
}

#[test]
fn a_compensated_move_lands_where_asked_and_refuses_rather_than_clips() {
    let _one = serial();
    let (_, results) = characterised();
    let res = results.to_str().unwrap();
    // Off the grid, in both approach directions: on the characterisation's hardware (found
    // through the results' campaign id in the store), measured by the camera.
    for dir in ["forward", "backward"] {
        let camp = results.parent().unwrap().join("char.toml");
        let plain = mv(&[
            "--x-um",
            "2500.3",
            "--direction",
            dir,
            "--measure",
            "--campaign",
            camp.to_str().unwrap(),
        ]);
        let comp = mv(&[
            "--x-um",
            "2500.3",
            "--direction",
            dir,
            "--measure",
            "--compensation",
            res,
        ]);
        let (p, c) = (common::json_of(&plain), common::json_of(&comp));
        assert!(
            c["hardware"].as_str().unwrap().contains("campaign 1"),
            "{c}"
        );
        let err = |v: &Value| v["measured_x_um"].as_f64().unwrap() - 2500.3;
        assert!(err(&p).abs() > 0.5, "{dir}: uncompensated {p}");
        assert!(err(&c).abs() < 0.3, "{dir}: compensated {c}");
        // y stands where x's line was measured (0 µm, where a move's simulated rig starts):
        // the x table holds y's error there, nothing to note.
        assert!(c["notes"].is_null(), "{c}");
        let ax = &c["axes"][0];
        assert_eq!(ax["approach"], dir);
        assert!(ax["correction_um"].as_f64().unwrap().abs() > 0.5, "{ax}");
        // The computation of a compensated command: well under 1 ms.
        assert!(ax["compute_us"].as_f64().unwrap() < 1000.0, "{ax}");
    }
    // Outside the compensated range: refused, not clipped to the edge.
    let o = mv(&["--x-um", "3100", "--compensation", res]);
    refused(&o, "outside the compensated range");
    // Outside the soft limits of the simulated axis ([-500, 13500] µm), with or without.
    let o = mv(&["--x-um", "20000"]);
    refused(&o, "soft limits");
}

/// The campaign files of this test: the demo stage model, results under `dir`.
fn sim_file<'a>(
    dir: &Path,
    name: &'a str,
    campaign: &'a str,
    rest: &'a str,
    tail: &'a str,
) -> SimFile<'a> {
    let outputs = format!("{}/{{name}}-{{id}}", dir.display());
    SimFile {
        name,
        stage: STAGE,
        model: "demo_xy.toml",
        campaign,
        sim: "seed = 5",
        rest,
        outputs,
        tail,
    }
}

/// A campaign file that runs compensated: x over [1500, 2500] µm every 25 µm, both directions.
fn compensated_campaign(section: &str) -> PathBuf {
    let (_, results) = characterised();
    let dir = results.parent().unwrap();
    sim_file(
        dir,
        "comp",
        "",
        "[axes.x]\nrange_um = [1500.0, 2500.0]\nstep_um = 25.0\nother_at_um = 0.0\n\n\
         [sampling]\ndesign = \"full\"\n\n\
         [acquisition]\ndirections = [\"forward\", \"backward\"]\nsettle_s = 2.0",
        section,
    )
    .write(&dir.join(format!("comp-{}.toml", section.len())))
}

#[test]
fn a_campaign_with_a_compensation_section_runs_compensated() {
    let _one = serial();
    let (db, results) = characterised();
    let run = |camp: &Path| {
        bin()
            .args(["run", "--quiet", "--json", "--db"])
            .arg(db)
            .arg(camp)
            .output()
            .unwrap()
    };
    // A bad table in the file: refused before anything is stored or moved.
    let bad = results.parent().unwrap().join("bad_x.csv");
    std::fs::write(
        &bad,
        "position_um,ef_xx_um,corr_forward_um,corr_backward_um\n1000,0.1,-0.1,\n2000,inf,1,\n3000,0.1,-0.1,\n",
    )
    .unwrap();
    let before = csmetro::store::Store::open(db)
        .unwrap()
        .campaigns()
        .unwrap()
        .len();
    let o = run(&compensated_campaign(&format!(
        "[compensation]\nfile = \"{}\"",
        bad.display()
    )));
    refused(&o, &format!("{}:3:", bad.display()));
    let o = run(&compensated_campaign(
        "[compensation]\nfrom = 1\nfile = \"x.csv\"",
    ));
    refused(&o, "compensation");
    assert_eq!(
        csmetro::store::Store::open(db)
            .unwrap()
            .campaigns()
            .unwrap()
            .len(),
        before
    );
    // From the stored characterisation: every target lands within a few tenths of a µm.
    let o = run(&compensated_campaign("[compensation]\nfrom = 1"));
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let id = common::json_of(&o)["id"].as_i64().unwrap();
    let store = csmetro::store::Store::open(db).unwrap();
    let errs: Vec<f64> = store
        .samples(id)
        .unwrap()
        .iter()
        .map(|s| s.error_um(csmetro::types::AxisId::X))
        .collect();
    assert_eq!(errs.len(), 2 * 41);
    let max = errs.iter().fold(0.0f64, |m, e| m.max(e.abs()));
    assert!(max < 0.5, "compensated max |error| {max}");
    // The same targets uncompensated, in the characterisation: errors of µm.
    let raw: Vec<f64> = store
        .samples(1)
        .unwrap()
        .iter()
        .filter(|s| (1500.0..=2500.0).contains(&s.target.target_x_um))
        .map(|s| s.error_um(csmetro::types::AxisId::X).abs())
        .collect();
    assert!(raw.iter().fold(0.0f64, |m, e| m.max(*e)) > 2.0);
}

/// `[campaign] verify = 1`: the verification as a campaign through `csmetro run` — stored,
/// reported, its verdict kept — and refused at load, with file and line, when its id cannot be
/// verified.
#[test]
fn a_verify_campaign_runs_the_verification_and_refuses_what_it_cannot_verify() {
    let _one = serial();
    let (db, results) = characterised();
    let dir = results.parent().unwrap();
    let run = |camp: &Path| {
        bin()
            .args(["run", "--quiet", "--json", "--db"])
            .arg(db)
            .arg(camp)
            .output()
            .unwrap()
    };
    let acq = "[acquisition]\ncycles = 2\nsettle_s = 2.0";
    let camp = sim_file(dir, "ver", "verify = 1", acq, "").write(&dir.join("ver.toml"));
    let o = run(&camp);
    let v = only_json(&o);
    let id = v["id"].as_i64().unwrap();
    assert_eq!(v["campaign"], 1, "{v}");
    assert_eq!(v["verify"], 1, "{v}");
    let passed = v["passed"].as_bool().unwrap();
    assert_eq!(v["state"], if passed { "done" } else { "failed" }, "{v}");
    assert_eq!(o.status.code(), Some(if passed { 0 } else { 1 }));
    let x = &v["axes"][0];
    assert_eq!(x["axis"], "x");
    for f in [&x["before"], &x["after"]] {
        for k in ["a_um", "b_um", "e_um", "m_um", "r_um"] {
            assert!(f[k].is_number(), "{k} in {f}");
        }
    }
    assert!(figure(&x["before"], "b_um") > 1.5, "{x}");
    assert!(figure(&x["after"], "b_um").abs() < 0.3, "{x}");
    let ratio = figure(&x["before"], "e_um") / figure(&x["after"], "e_um");
    assert!(ratio > 8.0, "E before/after {ratio}: {x}");
    // Both passes stored as the campaign's samples (2 cycles x 2 directions x each target),
    // the verdict, table, plot and report among its results.
    let targets: usize = [
        "iso_targets_um",
        "unvisited_targets_um",
        "extrapolated_targets_um",
    ]
    .iter()
    .map(|k| x[*k].as_array().unwrap().len())
    .sum();
    assert!(targets >= 21, "{x}");
    let store = csmetro::store::Store::open(db).unwrap();
    assert_eq!(store.samples(id).unwrap().len(), 2 * 2 * 2 * targets);
    let verdict = store.result(id, "verify/verify.json").unwrap().unwrap().1;
    let verdict: Value = serde_json::from_slice(&verdict).unwrap();
    assert_eq!(verdict["axes"][0]["after"], x["after"]);
    let out = dir.join(format!("ver-{id}"));
    let txt = std::fs::read_to_string(out.join("summary.txt")).unwrap();
    assert!(
        txt.contains("verification of campaign 1") && txt.contains("after"),
        "{txt}"
    );
    let html = std::fs::read_to_string(out.join("report.html")).unwrap();
    assert!(
        html.contains("data:image/svg+xml;base64,"),
        "no plot in the report"
    );
    assert!(out.join("verify/verify_x.svg").exists());
    drop(store);

    // Refused at load (exit 2, the file and the line of `verify`), nothing stored or moved.
    let count = || {
        csmetro::store::Store::open(db)
            .unwrap()
            .campaigns()
            .unwrap()
            .len()
    };
    // A finished campaign of this stage without compensation tables.
    let bare = {
        let s = csmetro::store::Store::open(db).unwrap();
        let row = s.campaign(1).unwrap().unwrap();
        let bare = s
            .create_campaign("bare", &row.spec_toml, &row.spec_path, STAGE, 0)
            .unwrap();
        s.set_state(bare, csmetro::types::CampaignState::Done, None)
            .unwrap();
        bare
    };
    let before = count();
    let (of_verification, of_bare) = (format!("verify = {id}"), format!("verify = {bare}"));
    let other_stage = SimFile {
        stage: "lab-xy",
        ..sim_file(dir, "ver", "verify = 1", acq, "")
    };
    let cases = [
        (
            sim_file(dir, "ver", "verify = 99", acq, ""),
            "no campaign 99".to_string(),
        ),
        (other_stage, "ran on stage \"comp-sim-xy\"".into()),
        (
            sim_file(dir, "ver", &of_verification, acq, ""),
            "is a verification".into(),
        ),
        (
            sim_file(dir, "ver", &of_bare, acq, ""),
            "no compensation table".into(),
        ),
    ];
    for (k, (f, needle)) in cases.iter().enumerate() {
        let p = f.write(&dir.join(format!("bad-ver-{k}.toml")));
        let o = run(&p);
        refused(&o, needle);
        // `verify` is on line 4 of the file.
        refused(&o, &format!("{}:4:", p.display()));
    }
    // Axes of its own: the verification measures the characterisation's.
    let p = sim_file(
        dir,
        "ver",
        "verify = 1",
        "[axes.x]\nrange_um = [1500.0, 2500.0]\nstep_um = 25.0\nother_at_um = 2100.0\nm = 10",
        "",
    )
    .write(&dir.join("bad-ver-axes.toml"));
    refused(&run(&p), "leave out [axes]");
    assert_eq!(count(), before);
}

#[test]
fn a_verification_the_store_refuses_is_an_error_not_a_verdict_kept() {
    let _one = serial();
    let (db, _) = characterised();
    // A copy of the characterisation's store whose results table refuses the verification.
    let dir = tempfile::tempdir().unwrap();
    let copy = dir.path().join("copy.db");
    rusqlite::Connection::open(db)
        .unwrap()
        .execute("VACUUM INTO ?1", [copy.to_str().unwrap()])
        .unwrap();
    common::fail_writes(
        &copy,
        "CREATE TRIGGER no_verify BEFORE INSERT ON results WHEN NEW.name LIKE 'verify/%' \
         BEGIN SELECT RAISE(FAIL, 'disk full (test)'); END;",
    );
    let o = verify_in(&copy, &["--json"]);
    let err = String::from_utf8_lossy(&o.stderr);
    // The verdict is shown, and the exit says it was not kept.
    assert!(only_json(&o)["passed"].is_boolean());
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(
        err.contains("results were not stored")
            && err.contains("verify/")
            && err.contains("disk full"),
        "{err}"
    );
}
