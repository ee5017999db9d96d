//! `csmetro gap` on a fourth, independently written generator (tests/common/othergen.rs): other
//! stage travel, other campaign designs (two x and two y lines with jittered targets, ISO-like
//! few targets on three x lines, dense random targets on six cycles, uniform steps with paused
//! cycles; line after line or cycle after cycle; time stamps from a feed and a dwell), effects
//! in physical units (a motor revolution from a drawn gearhead ratio, yaw times an Abbe arm
//! measured from a line that is not at zero, warm-up drifts of 10-90 min). Every library effect
//! alone on each design, pairs, nulls and effects outside the library.
//!
//! `issue_effects_are_named` (debug, about a minute on 2 shared cores) runs eight singles on
//! every design, the issue's pair, nulls and out-of-library cases; `full_sweep` (ignored; run
//! `cargo test --release --test system gap_othergen:: -- --ignored --nocapture`, GAP_OTHERGEN_SEEDS
//! seeds per design, default 3) prints the rates per effect over every kind.
#[path = "../common/othergen.rs"]
mod othergen;

// For othergen (it takes them from its includer).
use csmetro::gap::data::Sample;
use csmetro::gap::{diagnose, Diagnosis, Options};
use csmetro_sim::AxisId;
use othergen::*;

/// The rates the issue asks for: every kind named in at least 3 of 4 cases but one kind at
/// most, pairs both named in 80 %, nulls named in at most 5 %, outside effects not named as a
/// library effect in more than 1 of 8 (a wave on evenly spaced targets is a motor error's
/// alias: see `period`).
fn check(t: &Tally) {
    let rates = t.single_rates();
    let low: Vec<&(String, f64)> = rates.iter().filter(|(_, r)| *r < 0.75).collect();
    assert!(
        low.len() <= 1,
        "effects named in < 75 % of their cases: {low:?}\n{}\n{}",
        t.summary(),
        t.log.join("\n")
    );
    let (n, h) = t.singles_total();
    assert!(
        h as f64 >= 0.875 * n as f64,
        "singles {h}/{n}\n{}\n{}",
        t.summary(),
        t.log.join("\n")
    );
    assert!(
        t.pairs.1 as f64 >= 0.8 * t.pairs.0 as f64,
        "pairs: {}\n{}",
        t.summary(),
        t.log.join("\n")
    );
    assert!(
        t.nulls.1 as f64 <= 0.05 * t.nulls.0 as f64,
        "nulls: {}\n{}",
        t.summary(),
        t.log.join("\n")
    );
    assert!(
        t.outside.1 as f64 <= 0.125 * t.outside.0 as f64,
        "outside: {}\n{}",
        t.summary(),
        t.log.join("\n")
    );
}

/// The issue's misses (motor cyclic, yaw × Abbe, thermal drift, straightness + thermal drift)
/// and five more kinds, one case each on the four designs.
#[test]
fn issue_effects_are_named() {
    let kinds: &[(&str, usize)] = &[
        ("motor_cyclic", 0),
        ("yaw_abbe", 0),
        ("thermal_drift", 1),
        ("straightness", 0),
        ("backlash", 1),
        ("leadscrew_cyclic", 1),
        ("squareness", 1),
        ("camera_rotation", 0),
    ];
    let t = sweep(0..1, &[0, 1, 2, 3], kinds, 1);
    println!("{}", t.summary());
    for l in &t.log {
        println!("  {l}");
    }
    check(&t);
    // The three effects the issue saw missed, each on at least 3 of the 4 designs.
    for k in ["motor_cyclic", "yaw_abbe", "thermal_drift"] {
        let (n, h) = t.single[k];
        assert!(h + 1 >= n, "{k} named {h}/{n}: {}", t.summary());
    }
}

/// Every kind, every pair, on every design over several seeds (release: a few minutes).
#[test]
#[ignore]
fn full_sweep() {
    let seeds: u64 = std::env::var("GAP_OTHERGEN_SEEDS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(3);
    let t = sweep(0..seeds, &[0, 1, 2, 3], KINDS, PAIRS.len());
    for l in &t.log {
        println!("  {l}");
    }
    println!("{}", t.summary());
    check(&t);
}
