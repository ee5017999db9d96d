//! The fault soak (`csmetro soak`) on a few campaigns: random controller faults, `kill -9` and
//! SIGTERM at random, resumes; every stored position against the simulator's truth, nothing
//! lost or stored twice, the summary against an uninterrupted run's. The full-size figure
//! (`csmetro soak --campaigns 200`) is measured in release and reported apart.
use crate::common;

use common::{bin, json_of};

#[test]
fn a_short_fault_soak_loses_nothing_and_reports_like_an_uninterrupted_run() {
    let dir = tempfile::tempdir().unwrap();
    let o = bin()
        .args([
            "soak",
            "--campaigns",
            "3",
            "--seed",
            "5",
            "--kills",
            "2",
            "--plans",
            "1",
            "--timeout-s",
            "120",
            "--dir",
        ])
        .arg(dir.path())
        .output()
        .unwrap();
    let j = json_of(&o);
    let s = &j["soak"];
    assert_eq!(j["ok"], true, "{j}");
    assert_eq!(s["campaigns"], 3, "{j}");
    assert!(
        s["kills"].as_u64().unwrap() + s["sigterms"].as_u64().unwrap() >= 1,
        "{j}"
    );
    assert!(s["samples_checked"].as_u64().unwrap() >= 3 * 44, "{j}");
    assert_eq!(s["positions_beyond_noise"], 0, "{j}");
    assert_eq!(s["lost"], 0, "{j}");
    assert_eq!(s["duplicated"], 0, "{j}");
    assert_eq!(s["summary_mismatches"], 0, "{j}");
}
