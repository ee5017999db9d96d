//! `csmetro export ID --format nexus`: a simulated campaign's results as a NeXus file, opened
//! by real readers (h5py, nexusformat) that compare every value with the CSV/JSON results
//! (`tests/nexus/check_nexus.py`). Without `--features nexus` the format is refused (exit 2).
//!
//! The reader part skips with a message when h5py or nexusformat is missing, except with
//! `CSMETRO_REQUIRE_NEXUS=1` (CI).
mod common;

use std::path::Path;
use std::process::Command;

use common::{bin, campaign, json_of};

/// h5py and nexusformat open `file` and find every value of the results in `results`.
fn read_back(file: &Path, results: &Path) {
    let check = Command::new("python3")
        .arg(common::repo("tests/nexus/check_nexus.py"))
        .arg(file)
        .arg(results)
        .output()
        .unwrap();
    let said = String::from_utf8_lossy(&check.stdout);
    assert!(
        check.status.success() && said.starts_with("ok: "),
        "{said}\n{}",
        String::from_utf8_lossy(&check.stderr)
    );
}

#[test]
fn a_campaign_exports_to_nexus_that_h5py_and_nexusformat_read_back() {
    let dir = tempfile::tempdir().unwrap();
    let db = dir.path().join("c.db");
    let file = dir.path().join("c.toml");
    let text = campaign("nx", "sim-nx", 8, 1000.0)
        .replace(
            "model = \"ideal.toml\"",
            &format!(
                "model = {:?}",
                common::repo("config/sim/demo_xy.toml")
                    .display()
                    .to_string()
            ),
        )
        .replace("seed = 3", "seed = 3\nfull_scan = true")
        .replace("dir = \"", &format!("dir = \"{}/", dir.path().display()));
    // `[outputs] nexus = true` writes the file with the results; a build without the feature
    // refuses the key at validation (exit 2), before anything runs.
    let with_nexus = text.replace("[outputs]\n", "[outputs]\nnexus = true\n");
    assert_ne!(with_nexus, text);
    std::fs::write(&file, &with_nexus).unwrap();
    let run = common::run_json(&file, &db);
    if !cfg!(feature = "nexus") {
        assert_eq!(run.status.code(), Some(2), "{run:?}");
        assert!(String::from_utf8_lossy(&run.stderr).contains("outputs.nexus"));
        std::fs::write(&file, text).unwrap();
        json_of(&common::run_json(&file, &db));
    } else {
        json_of(&run);
    }
    let results = dir.path().join("nx-1");
    let out = dir.path().join("c.nxs");
    let o = bin()
        .args(["export", "1", "--format", "nexus", "--json", "--db"])
        .arg(&db)
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    if !cfg!(feature = "nexus") {
        assert_eq!(o.status.code(), Some(2), "{o:?}");
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(err.contains("--features nexus"), "{err}");
        assert!(!out.exists());
        return;
    }
    let v = json_of(&o);
    assert!(v["bytes"].as_u64().unwrap() > 1000, "{v}");
    let readers = Command::new("python3")
        .args(["-c", "import h5py, nexusformat.nexus"])
        .status()
        .is_ok_and(|s| s.success());
    if !readers {
        assert!(
            std::env::var("CSMETRO_REQUIRE_NEXUS").as_deref() != Ok("1"),
            "CSMETRO_REQUIRE_NEXUS=1 but h5py/nexusformat are not installed"
        );
        eprintln!("SKIPPED: NeXus readers: pip install h5py nexusformat");
        return;
    }
    assert!(results.join("iso230.json").is_file(), "{results:?}");
    read_back(&out, &results);
    // The one written with the results reads the same.
    read_back(&results.join("nx-1.nxs"), &results);

    // An unknown campaign is the user's mistake (exit 2), and nothing is written.
    let missing = dir.path().join("none.nxs");
    let o = bin()
        .args(["export", "9", "--format", "nexus", "--db"])
        .arg(&db)
        .arg("--out")
        .arg(&missing)
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2), "{o:?}");
    assert!(!missing.exists());
}
