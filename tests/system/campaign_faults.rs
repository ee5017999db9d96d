//! `[hardware.sim.faults]`: random faults of the simulated controllers, injected into a campaign.
use crate::common;

use std::path::Path;
use std::process::Output;

use common::{bin, json_of, SimFile};
use csmetro::store::Store;

fn campaign(dir: &Path, faults: &str) -> std::path::PathBuf {
    let out = format!("{}/{{id}}", dir.join("out").display());
    SimFile {
        name: "faulty",
        stage: "sim-faults",
        model: "ideal.toml",
        campaign: "",
        sim: "transport = \"pty\"\nframe_time_s = 0.1\nseed = 3",
        rest:
            "[axes.x]\nrange_um = [1000.0, 1250.0]\nstep_um = 25.0\nother_at_um = 2100.0\nm = 5\n\n\
               [sampling]\ndesign = \"random\"\nseed = 4\n\n\
               [acquisition]\ndirections = [\"forward\", \"backward\"]\nsettle_s = 0.2",
        outputs: out,
        tail: faults,
    }
    .write(&dir.join("campaign.toml"))
}

fn run(c: &Path, db: &Path) -> Output {
    bin()
        .args(["run", "--json", "--quiet", "--db"])
        .arg(db)
        .arg(c)
        .output()
        .unwrap()
}

#[test]
fn faults_are_parsed_validated_and_given_to_both_controllers() {
    let dir = tempfile::tempdir().unwrap();
    let c = campaign(
        dir.path(),
        "[hardware.sim.faults]\nseed = 9\ndelay_rate = 0.0\ndrop_rate = 0.0\n",
    );
    let db = dir.path().join("c.db");
    let j = json_of(&run(&c, &db));
    assert_eq!(j["state"], "done", "{j}");
    let s = Store::open(&db).unwrap();
    let rig = s
        .events_after(1, 0)
        .unwrap()
        .into_iter()
        .find(|e| e.kind == "rig")
        .unwrap();
    let d = rig.data["describe"].as_str().unwrap();
    assert!(d.contains("random faults"), "{d}");

    // Out-of-range rates and unknown keys are refused, naming the file and the key.
    for bad in [
        "[hardware.sim.faults]\ndrop_rate = 1.5\n",
        "[hardware.sim.faults]\ndelay_ms = [900, 10]\n",
        "[hardware.sim.faults]\nexplode_rate = 0.1\n",
    ] {
        let d2 = tempfile::tempdir().unwrap();
        let c = campaign(d2.path(), bad);
        let o = run(&c, &d2.path().join("c.db"));
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{bad}: {err}");
        assert!(err.contains("campaign.toml"), "{err}");
        assert!(
            err.contains("faults") || err.contains("explode_rate"),
            "{err}"
        );
    }
}

/// With delays on every reply the run takes at least that long, and with dropped and garbled
/// replies besides, the campaign still ends done with every target once.
#[test]
fn faults_strike_and_the_campaign_still_completes() {
    let dir = tempfile::tempdir().unwrap();
    let c = campaign(
        dir.path(),
        "[hardware.sim.faults]\nseed = 9\ndelay_rate = 1.0\ndelay_ms = [20, 20]\n\
         garbage_rate = 0.02\ndrop_rate = 0.02\n",
    );
    let db = dir.path().join("c.db");
    let j = json_of(&run(&c, &db));
    assert_eq!(j["state"], "done", "{j}");
    // 10 targets, each at least a move, an on-target poll and a position query: 30 delayed
    // replies of 20 ms at the least.
    assert!(j["wall_s"].as_f64().unwrap() > 0.6, "{j}");
    let s = Store::open(&db).unwrap();
    assert_eq!(s.sample_count(1).unwrap(), 10);
}
