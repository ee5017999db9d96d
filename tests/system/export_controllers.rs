//! `csmetro export ID --format linuxcnc|twincat-lsec|csv --axis x`: a characterised simulated
//! campaign's compensation as controller tables, read back here by readers written from the
//! formats' documentation (not from csmetro's writer), which then drive a simulated axis: the
//! position each controller commands for a wanted position must be the one `csmetro move`
//! commands. Bad requests are refused with exit 2 and write nothing.
use crate::common;

use std::path::{Path, PathBuf};
use std::process::Output;
use std::sync::OnceLock;

use common::{bin, json_of, SimFile};
use csmetro::compensation::Compensation;
use csmetro::types::{AxisId, Direction};

const STAGE: &str = "export-sim-xy";

/// x over [1000, 1600] µm on a 5 µm grid of the demo stage (cyclic error, 2 µm backlash, scale
/// error), 60 random targets per direction: 121 grid points, so LinuxCNC's 256 entries hold
/// every kink of both directions.
fn characterised() -> &'static (PathBuf, PathBuf) {
    static ONCE: OnceLock<(PathBuf, PathBuf)> = OnceLock::new();
    ONCE.get_or_init(|| {
        let dir = tempfile::tempdir().unwrap().keep();
        let camp = SimFile {
            name: "char",
            stage: STAGE,
            model: "demo_xy.toml",
            campaign: "",
            sim: "seed = 5",
            rest: "[axes.x]\nrange_um = [1000.0, 1600.0]\nstep_um = 5.0\nother_at_um = 2100.0\nm = 60\n\n\
                   [sampling]\ndesign = \"random\"\nseed = 11\n\n\
                   [acquisition]\ndirections = [\"forward\", \"backward\"]\nsettle_s = 2.0\n\n\
                   [reconstruction]\nnoise_um = 0.01",
            outputs: format!("{}/{{name}}-{{id}}", dir.display()),
            tail: "",
        }
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

fn export(id: &str, args: &[&str], out: &Path) -> Output {
    let (db, _) = characterised();
    bin()
        .args(["export", id, "--db"])
        .arg(db)
        .args(args)
        .arg("--out")
        .arg(out)
        .output()
        .unwrap()
}

/// A bilateral table as a controller holds it: nominal (programmed) positions and, per
/// direction, what it adds to them, all in µm.
struct Table {
    nominal: Vec<f64>,
    forward: Vec<f64>,
    backward: Vec<f64>,
}

/// LinuxCNC, `COMP_FILE_TYPE = 1` (INI docs, `[JOINT_n] COMP_FILE`): lines `nominal
/// forward_trim reverse_trim` in machine units (mm), read as `usrmotLoadComp` does (stops at
/// the first line that is not three numbers), ascending nominals, at most 256 entries.
fn read_linuxcnc(text: &str) -> Table {
    let mut t = Table {
        nominal: vec![],
        forward: vec![],
        backward: vec![],
    };
    for line in text.lines() {
        let v: Vec<f64> = line
            .split_whitespace()
            .map_while(|s| s.parse().ok())
            .collect();
        if v.len() < 3 {
            break;
        }
        if let Some(&last) = t.nominal.last() {
            assert!(v[0] * 1000.0 > last, "nominals must increase: {line}");
        }
        t.nominal.push(v[0] * 1000.0);
        t.forward.push(v[1] * 1000.0);
        t.backward.push(v[2] * 1000.0);
    }
    assert!(
        !t.nominal.is_empty() && t.nominal.len() <= 256,
        "{}",
        t.nominal.len()
    );
    assert_eq!(
        t.nominal.len(),
        text.lines().count(),
        "lines the loader would skip"
    );
    t
}

/// LinuxCNC's motion module (`compute_screw_comp`, control.c): trims and slopes held as f32,
/// the trim of the direction the joint moves in, linear in the commanded position between
/// entries, the last one kept at rest; `motor_pos_cmd = pos_cmd + trim`. A move to `w` in `d`:
/// the joint comes from 50 µm on the approach side and stops at `w`.
fn linuxcnc_moves_to(t: &Table, d: Direction, w: f64) -> f64 {
    let mm = |v: f64| v / 1000.0;
    let trims = match d {
        Direction::Forward => &t.forward,
        Direction::Backward => &t.backward,
    };
    let n = t.nominal.len();
    let trim32: Vec<f32> = trims.iter().map(|&v| mm(v) as f32).collect();
    let slope32: Vec<f32> = (0..n)
        .map(|k| {
            if k + 1 < n {
                ((mm(trims[k + 1]) - mm(trims[k])) / (mm(t.nominal[k + 1]) - mm(t.nominal[k])))
                    as f32
            } else {
                0.0
            }
        })
        .collect();
    let mut corr = 0.0f64;
    for step in 0..=100 {
        let pos = mm(w - d.sign() * 50.0 * (1.0 - step as f64 / 100.0));
        // The entry at or below pos (before the first: the first entry's trim, slope 0).
        let k = t.nominal.partition_point(|&x| mm(x) <= pos);
        corr = if k == 0 {
            trim32[0] as f64
        } else {
            trim32[k - 1] as f64 + slope32[k - 1] as f64 * (pos - mm(t.nominal[k - 1]))
        };
    }
    (mm(w) + corr) * 1000.0
}

/// TwinCAT CNC leadscrew error compensation list (Beckhoff Information System, TF5200 axis
/// compensation, P-COMP-00017..00025): `name value` lines, `# ` comments; unit 1 = 0.1 µm;
/// bilateral; interval 0 = each setpoint listed; pos/neg the position error (actual - setpoint)
/// for motion in the positive/negative direction, which the CNC takes off the setpoint,
/// interpolating linearly between setpoints. Returned as nominal + what the CNC adds.
fn read_twincat(text: &str) -> Table {
    let mut kv = std::collections::HashMap::new();
    for line in text.lines() {
        let line = line.trim();
        if line.is_empty() || line.starts_with("# ") {
            continue;
        }
        let mut it = line.split_whitespace();
        let (k, v) = (it.next().unwrap(), it.next().unwrap());
        assert!(
            kv.insert(k.to_string(), v.to_string()).is_none(),
            "{k} twice"
        );
    }
    let int = |k: &str| -> i64 { kv[k].parse().unwrap_or_else(|_| panic!("{k} = {}", kv[k])) };
    assert_eq!(int("kw.ssfk.unit"), 1);
    assert_eq!(int("kw.ssfk.bilateral"), 1);
    assert_eq!(int("kw.ssfk.interval"), 0);
    assert_eq!(int("kopf.achs_nr"), 1);
    let n = int("kw.ssfk.kw_nr_max") as usize;
    assert!((2..1500).contains(&n), "{n}");
    let mut t = Table {
        nominal: vec![],
        forward: vec![],
        backward: vec![],
    };
    for i in 0..n {
        let s = int(&format!("kw.ssfk.table[{i}].setpoint")) as f64 / 10.0;
        if let Some(&last) = t.nominal.last() {
            assert!(s > last);
        }
        t.nominal.push(s);
        t.forward
            .push(-(int(&format!("kw.ssfk.table[{i}].pos")) as f64) / 10.0);
        t.backward
            .push(-(int(&format!("kw.ssfk.table[{i}].neg")) as f64) / 10.0);
    }
    assert_eq!(int("kw.ssfk.kw_startpos") as f64 / 10.0, t.nominal[0]);
    t
}

/// The bilateral CSV (README): `nominal_um,forward_correction_um,backward_correction_um`.
fn read_csv(text: &str) -> Table {
    let mut lines = text.lines();
    assert_eq!(
        lines.next(),
        Some("nominal_um,forward_correction_um,backward_correction_um")
    );
    let mut t = Table {
        nominal: vec![],
        forward: vec![],
        backward: vec![],
    };
    for l in lines {
        let v: Vec<f64> = l.split(',').map(|s| s.parse().unwrap()).collect();
        t.nominal.push(v[0]);
        t.forward.push(v[1]);
        t.backward.push(v[2]);
    }
    t
}

/// Linear interpolation of the table's correction in the nominal position (TwinCAT, CSV).
fn interpolated(t: &Table, d: Direction, w: f64) -> f64 {
    let c = match d {
        Direction::Forward => &t.forward,
        Direction::Backward => &t.backward,
    };
    let k = t
        .nominal
        .partition_point(|&x| x <= w)
        .clamp(1, t.nominal.len() - 1);
    let f = (w - t.nominal[k - 1]) / (t.nominal[k] - t.nominal[k - 1]);
    w + c[k - 1] + f * (c[k] - c[k - 1])
}

/// 24 wanted positions spread irregularly over `[lo, hi]`, both ends included.
fn wanted(lo: f64, hi: f64) -> Vec<f64> {
    let mut w: Vec<f64> = (0..22)
        .map(|k| lo + (hi - lo) * ((k as f64 * 0.618_034 + 0.05) % 1.0))
        .collect();
    w.push(lo);
    w.push(hi);
    w
}

#[test]
fn controllers_reading_the_exported_tables_command_what_csmetro_move_commands() {
    let (db, results) = characterised();
    let dir = tempfile::tempdir().unwrap();
    // What `csmetro move --compensation RESULTS` commands (its library function).
    let comp = Compensation::load(results).unwrap();
    let x = comp.table(AxisId::X).unwrap();
    for (format, tol) in [("linuxcnc", 0.01), ("csv", 0.01), ("twincat-lsec", 0.051)] {
        let out = dir.path().join(format!("x.{format}"));
        let t0 = std::time::Instant::now();
        let v = json_of(&export(
            "1",
            &["--format", format, "--axis", "x", "--json"],
            &out,
        ));
        eprintln!("{format}: {v} ({:.2} s)", t0.elapsed().as_secs_f64());
        assert_eq!(v["axis"], "x");
        let text = std::fs::read_to_string(&out).unwrap();
        assert_eq!(v["bytes"].as_u64(), Some(text.len() as u64));
        let table = match format {
            "linuxcnc" => read_linuxcnc(&text),
            "csv" => read_csv(&text),
            _ => read_twincat(&text),
        };
        assert_eq!(v["entries"].as_u64(), Some(table.nominal.len() as u64));
        let (lo, hi) = (
            v["range_um"][0].as_f64().unwrap(),
            v["range_um"][1].as_f64().unwrap(),
        );
        // The characterised travel, less at most a grid step at its ends.
        assert!(
            (1000.0..1005.0).contains(&lo) && hi <= 1600.0 && hi > 1595.0,
            "{v}"
        );
        let (mut worst, mut largest): (f64, f64) = (0.0, 0.0);
        for d in [Direction::Forward, Direction::Backward] {
            for w in wanted(lo, hi) {
                let want = x.command_um(d, w).unwrap();
                let got = match format {
                    "linuxcnc" => linuxcnc_moves_to(&table, d, w),
                    _ => interpolated(&table, d, w),
                };
                worst = worst.max((got - want).abs());
                assert!(
                    (got - want).abs() <= tol,
                    "{format} {d:?} {w}: controller {got}, csmetro move {want}"
                );
                largest = largest.max((want - w).abs());
            }
        }
        // A real correction: the demo stage is off by µm here.
        assert!(largest > 1.0, "{largest}");
        let reported = v["max_deviation_um"].as_f64().unwrap();
        assert!(worst <= reported + 1e-6, "{format}: {worst} > {reported}");
    }
    // The binary's own move commands the same as the library (two positions, both sides).
    let lc = read_linuxcnc(&std::fs::read_to_string(dir.path().join("x.linuxcnc")).unwrap());
    for (w, d) in [(1234.5, "forward"), (1432.1, "backward")] {
        let o = bin()
            .args(["move", "--stage", STAGE, "--json", "--db"])
            .arg(db)
            .args(["--x-um", &w.to_string(), "--direction", d, "--compensation"])
            .arg(results)
            .output()
            .unwrap();
        let m = json_of(&o);
        let cmd = m["axes"][0]["command_um"].as_f64().unwrap();
        let dir = if d == "forward" {
            Direction::Forward
        } else {
            Direction::Backward
        };
        assert!((linuxcnc_moves_to(&lc, dir, w) - cmd).abs() <= 0.01, "{m}");
    }
}

fn refused(o: &Output, needle: &str, out: &Path) {
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(err.contains(needle), "{needle:?} not in {err}");
    assert!(!out.exists(), "{} written", out.display());
}

#[test]
fn bad_requests_exit_2_and_write_nothing() {
    let (db, _) = characterised();
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("t.tbl");
    // A map campaign and a campaign with no results, stored beside the characterisation.
    let (map_id, empty_id) = {
        let s = csmetro::store::Store::open(db).unwrap();
        let map = std::fs::read_to_string(common::repo("config/campaigns/map-sim.toml")).unwrap();
        let line = std::fs::read_to_string(db.parent().unwrap().join("char.toml")).unwrap();
        (
            s.create_campaign("map", &map, "map.toml", STAGE, 10)
                .unwrap(),
            s.create_campaign("line", &line, "line.toml", STAGE, 10)
                .unwrap(),
        )
    };
    let (map_id, empty_id) = (map_id.to_string(), empty_id.to_string());
    let lc = ["--format", "linuxcnc"];
    refused(&export("1", &lc, &out), "needs --axis x|y", &out);
    refused(
        &export("1", &["--format", "csv", "--axis", "y"], &out),
        "axis y was not characterised",
        &out,
    );
    refused(
        &export("1", &["--format", "csv", "--axis", "z"], &out),
        "must be x or y",
        &out,
    );
    refused(
        &export(&map_id, &["--format", "twincat-lsec", "--axis", "x"], &out),
        "map campaign",
        &out,
    );
    refused(
        &export(&empty_id, &["--format", "linuxcnc", "--axis", "x"], &out),
        "has no compensation table",
        &out,
    );
    refused(
        &export("99", &["--format", "linuxcnc", "--axis", "x"], &out),
        "no campaign 99",
        &out,
    );
    refused(
        &export("1", &["--format", "nexus", "--axis", "x"], &out),
        "--axis",
        &out,
    );
    refused(
        &export(
            "1",
            &[
                "--format",
                "linuxcnc",
                "--axis",
                "x",
                "--max-deviation-um",
                "-1",
            ],
            &out,
        ),
        "--max-deviation-um",
        &out,
    );
    let nowhere = dir.path().join("missing/dir/x.tbl");
    refused(
        &export("1", &["--format", "linuxcnc", "--axis", "x"], &nowhere),
        "does not exist",
        &nowhere,
    );
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0);
}
