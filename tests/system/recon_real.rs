//! Reconstruction judged on error curves of real axes (tests/data/real, measured by others):
//! a resolver's 250 µm cyclic error, where the stage's period must be found in the samples (nothing
//! may assume the simulator's 400 µm pitch), and a noisy laser-triangulation axis without a period,
//! where `auto` must do about as well as the better of `bp` and `pchip`.
use crate::common;

use std::path::Path;

use common::{bin, repo};
use serde_json::Value;

/// A measured curve on its uniform grid: first position, step (µm), values (µm).
struct Curve {
    x0: f64,
    step: f64,
    f: Vec<f64>,
}

fn curve(name: &str) -> Curve {
    let text = std::fs::read_to_string(repo(&format!("tests/data/real/{name}"))).unwrap();
    let rows: Vec<(f64, f64)> = text
        .lines()
        .skip(1)
        .map(|l| {
            let (a, b) = l.split_once(',').unwrap();
            (a.parse().unwrap(), b.parse().unwrap())
        })
        .collect();
    let n = rows.len();
    let step = ((rows[n - 1].0 - rows[0].0) / (n - 1) as f64 * 1000.0).round() / 1000.0;
    Curve {
        x0: rows[0].0,
        step,
        f: rows.into_iter().map(|r| r.1).collect(),
    }
}

/// `m` distinct grid indices drawn by a seeded xorshift (a design this test owns).
fn design(n: usize, m: usize, seed: u64) -> Vec<usize> {
    let mut s = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
    let mut taken = vec![false; n];
    let mut idx = Vec::with_capacity(m);
    while idx.len() < m {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        let i = (s % n as u64) as usize;
        if !taken[i] {
            taken[i] = true;
            idx.push(i);
        }
    }
    idx.sort_unstable();
    idx
}

/// Reconstructs from the samples at `idx` with `method` (and `extra` flags); returns the mean
/// |g − f| over the whole curve (µm) and the JSON figures.
fn score(dir: &Path, c: &Curve, idx: &[usize], method: &str, extra: &[&str]) -> (f64, Value) {
    let samples = dir.join("samples.csv");
    let mut t = String::from("position_um,error_um\n");
    for &i in idx {
        t.push_str(&format!("{},{}\n", c.x0 + c.step * i as f64, c.f[i]));
    }
    std::fs::write(&samples, t).unwrap();
    let out = dir.join("curve.csv");
    let end = c.x0 + c.step * (c.f.len() - 1) as f64;
    let o = bin()
        .args(["reconstruct", "--method", method, "--json", "--samples"])
        .arg(&samples)
        // A grid that starts below zero is given as written, not as `--grid=...`.
        .args(["--grid", &format!("{}:{}:{end}", c.x0, c.step), "--out"])
        .arg(&out)
        .args(extra)
        .output()
        .unwrap();
    assert!(
        o.status.success(),
        "{method}: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    let j: Value = serde_json::from_slice(&o.stdout).unwrap();
    let g: Vec<f64> = std::fs::read_to_string(&out)
        .unwrap()
        .lines()
        .skip(1)
        // position_um,error_um,u_um: the error is the second column.
        .map(|l| l.split(',').nth(1).unwrap().parse().unwrap())
        .collect();
    assert_eq!(g.len(), c.f.len());
    let e = g.iter().zip(&c.f).map(|(a, b)| (a - b).abs()).sum::<f64>() / g.len() as f64;
    (e, j)
}

#[test]
fn auto_finds_the_resolvers_250_um_period_and_does_as_well_as_being_told_it() {
    let c = curve("resolver_250um.csv");
    assert_eq!(c.f.len(), 4303);
    let dir = tempfile::tempdir().unwrap();
    // 5 % of the points, as a characterisation would take them.
    let idx = design(c.f.len(), 215, 7);
    let (auto, j) = score(dir.path(), &c, &idx, "auto", &[]);
    let (told, _) = score(dir.path(), &c, &idx, "physics", &["--pitch-um", "250"]);
    let (pchip, _) = score(dir.path(), &c, &idx, "pchip", &[]);
    eprintln!(
        "resolver 5 %: auto {auto:.3} µm ({}), physics told 250 µm {told:.3}, pchip {pchip:.3}",
        j["method"]
    );
    let periods: Vec<f64> = j["periods_um"]
        .as_array()
        .unwrap()
        .iter()
        .map(|p| p["period_um"].as_f64().unwrap())
        .collect();
    assert!(
        periods.iter().any(|p| (p - 250.0).abs() < 2.5),
        "the 250 µm period is found: {periods:?}"
    );
    assert!(
        auto <= 1.10 * told,
        "auto {auto} µm vs told the period {told} µm"
    );
    assert!(
        auto < 0.2 * pchip,
        "auto {auto} µm vs a lookup table {pchip} µm"
    );
}

#[test]
fn on_a_noisy_axis_without_a_period_auto_does_about_as_well_as_the_better_of_bp_and_pchip() {
    let c = curve("ild2300_yscan.csv");
    assert_eq!(c.f.len(), 415);
    assert!(c.x0 < 0.0, "the grid starts below zero");
    let dir = tempfile::tempdir().unwrap();
    for frac in [0.16, 0.32, 0.47] {
        let m = (frac * c.f.len() as f64).round() as usize;
        let (mut auto, mut bp, mut pchip) = (0.0, 0.0, 0.0);
        let seeds = 4;
        for seed in 0..seeds {
            let idx = design(c.f.len(), m, 100 + seed);
            auto += score(dir.path(), &c, &idx, "auto", &[]).0 / seeds as f64;
            bp += score(dir.path(), &c, &idx, "bp", &[]).0 / seeds as f64;
            pchip += score(dir.path(), &c, &idx, "pchip", &[]).0 / seeds as f64;
        }
        eprintln!("ILD2300 m = {m}: auto {auto:.2} µm, bp {bp:.2}, pchip {pchip:.2}");
        let best = bp.min(pchip);
        assert!(
            auto <= 1.10 * best,
            "m = {m}: auto {auto:.2} µm vs the better of bp/pchip {best:.2} µm"
        );
    }
}
