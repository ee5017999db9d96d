//! One samples layout (`csmetro::samples::LAYOUT`): a real simulated campaign's `samples.csv`
//! and its verification's `verify/samples.csv` have the same header and feed `csmetro
//! reconstruct --samples` and `csmetro gap --data` as they are.
use crate::common;

use std::path::Path;
use std::process::Output;

use common::{bin, json_of, repo, SimFile};

fn run(args: &[&str], files: &[&Path]) -> Output {
    let mut c = bin();
    c.args(args);
    for f in files {
        c.arg(f);
    }
    c.output().unwrap()
}

#[test]
fn a_campaigns_samples_and_its_verification_feed_reconstruct_and_gap() {
    let dir = tempfile::tempdir().unwrap();
    let camp = SimFile {
        name: "lay",
        stage: "layout-sim-xy",
        model: "demo_xy.toml",
        campaign: "",
        sim: "seed = 5",
        rest:
            "[axes.x]\nrange_um = [1000.0, 1300.0]\nstep_um = 5.0\nother_at_um = 2100.0\nm = 30\n\n\
               [sampling]\ndesign = \"random\"\nseed = 11\nfull_scan = true\n\n\
               [acquisition]\ndirections = [\"forward\", \"backward\"]\ncycles = 2\nsettle_s = 2.0",
        outputs: format!("{}/{{name}}-{{id}}", dir.path().display()),
        tail: "",
    }
    .write(&dir.path().join("lay.toml"));
    let db = dir.path().join("c.db");
    let o = run(&["run", "--quiet", "--db"], &[&db, &camp]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    // The verification: its exit says pass or fail, both leave verify/samples.csv.
    let o = run(
        &[
            "verify",
            "1",
            "--quiet",
            "--json",
            "--cycles",
            "2",
            "--targets",
            "5",
            "--unvisited",
            "2",
            "--db",
        ],
        &[&db],
    );
    assert!(matches!(o.status.code(), Some(0 | 1)), "{o:?}");
    let results = dir.path().join("lay-1");
    let samples = results.join("samples.csv");
    let verify = results.join("verify/samples.csv");
    let header = |p: &Path| {
        std::fs::read_to_string(p)
            .unwrap()
            .lines()
            .next()
            .unwrap()
            .to_string()
    };
    assert_eq!(header(&samples), header(&verify));
    assert_eq!(header(&samples), csmetro::samples::LAYOUT.join(","));
    // The results' first columns keep their place (scripts index them).
    assert!(header(&samples).starts_with(
        "seq,phase,axis,direction,cycle,target_x_um,target_y_um,meas_x_um,meas_y_um,theta_mrad,encoder_um,time_s,quality,frames,rejected,"
    ));

    // reconstruct: one curve of the file; two cycles and the full scan averaged per position.
    let o = run(
        &[
            "reconstruct",
            "--grid",
            "1000:5:1300",
            "--method",
            "linear",
            "--samples",
        ],
        &[&samples],
    );
    assert_eq!(o.status.code(), Some(2), "{o:?}");
    assert!(String::from_utf8_lossy(&o.stderr).contains("choose one with --axis and --direction"));
    let curve = dir.path().join("ef_xx.csv");
    let o = run(
        &[
            "reconstruct",
            "--grid",
            "1000:5:1300",
            "--method",
            "linear",
            "--axis",
            "x",
            "--direction",
            "forward",
            "--json",
            "--samples",
        ],
        &[&samples, Path::new("--out"), &curve],
    );
    let v = json_of(&o);
    // The full scan visits all 61 points: every one is a sample, so linear returns the means.
    let text = std::fs::read_to_string(&curve).unwrap();
    let rows: Vec<(f64, f64)> = text
        .lines()
        .skip(1)
        .map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            (f[0].parse().unwrap(), f[1].parse().unwrap())
        })
        .collect();
    assert_eq!(rows.len(), 61, "{v}");
    // Against the rows of the file itself: the mean of x forward errors at 1150 µm.
    let store = csmetro::store::Store::open(&db).unwrap();
    let at: Vec<f64> = store
        .samples(1)
        .unwrap()
        .iter()
        .filter(|s| {
            s.target.run.direction == csmetro::types::Direction::Forward
                && (s.target.target_x_um - 1150.0).abs() < 1e-9
        })
        .map(|s| s.error_um(csmetro::types::AxisId::X))
        .collect();
    assert!(at.len() >= 2, "{at:?}");
    let mean = at.iter().sum::<f64>() / at.len() as f64;
    let got = rows.iter().find(|r| (r.0 - 1150.0).abs() < 1e-9).unwrap().1;
    assert!((got - mean).abs() < 1e-5, "{got} vs {mean}");

    // gap: the results' samples and the verification's (its `before` pass) as data.
    let model = repo("config/sim/demo_xy.toml");
    for data in [&samples, &verify] {
        let out = dir.path().join(format!(
            "gap-{}",
            data.parent().unwrap().ends_with("verify")
        ));
        let o = run(
            &["gap", "--json", "--model"],
            &[&model, Path::new("--data"), data, Path::new("--out"), &out],
        );
        let v = json_of(&o);
        assert!(v.is_object(), "{v}");
    }
}
