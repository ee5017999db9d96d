//! `bench gap`: the gap diagnosis' figures. The real ISO 230-2 table of the ESS target-MUTS X
//! axis (tests/data/iso230/muts_b02_x.csv: backlash and drift between cycles named, value ±
//! SE), and the independent generator the tests share (tests/common/othergen.rs: not
//! `csmetro_sim`'s model code): every library kind alone on its four designs, pairs, nulls and
//! effects outside the library, with the rates named.
use std::time::Instant;

use serde_json::{json, Value};

// AxisId, Diagnosis and Sample are for othergen (it takes them from its includer).
use crate::gap::data::{self, Sample};
use crate::gap::{diagnose, Diagnosis, Options};
use csmetro_sim::{AxisId, StageModel};

// Included, not a crate: othergen calls `diagnose` and builds `gap::data::Sample`, both of
// this crate; a crate of its own would depend on csmetro (a cycle) or copy the code under test.
#[path = "../../../tests/common/othergen.rs"]
mod othergen;

const MUTS_X: &str = include_str!("../../../tests/data/iso230/muts_b02_x.csv");

fn muts_x() -> anyhow::Result<Value> {
    let (samples, _, format) = data::parse_any("muts_b02_x.csv", MUTS_X)?;
    let opts = Options {
        iso230: true,
        time_from_column: format != (data::Format::Iso230 { timed: false }),
        ..Default::default()
    };
    let model = StageModel::new([-21000.0, 21000.0], [0.0, 1000.0]);
    let t0 = Instant::now();
    let d = diagnose(&model, &samples, &opts).map_err(|e| anyhow::anyhow!(e.0))?;
    let ms = t0.elapsed().as_secs_f64() * 1e3;
    let iso = d
        .iso
        .as_ref()
        .ok_or_else(|| anyhow::anyhow!("not read as an ISO 230-2 table"))?;
    let find = |k: &str| iso.findings().find(|f| f.kind == k && f.named);
    let b = find("backlash");
    let drift = find("thermal_drift");
    Ok(json!({
        "file": "tests/data/iso230/muts_b02_x.csv",
        "backlash_um": b.map(|f| f.value),
        "backlash_se_um": b.map(|f| f.se),
        "backlash_by_hand_um": -25.4,
        "drift_named": drift.is_some(),
        "drift_um_per_cycle": drift.and_then(|f| f.extra.get("rate_um_per_cycle").and_then(Value::as_f64)),
        "heldout_rms_before_um": d.heldout_rms_before_um,
        "heldout_rms_after_um": d.heldout_rms_after_um,
        "diagnosis_ms": ms,
    }))
}

/// The figures as one JSON object: `seeds` seeds of each of the generator's four designs.
pub(super) fn run(seeds: u64) -> anyhow::Result<Value> {
    let t0 = Instant::now();
    let muts = muts_x()?;
    let t1 = Instant::now();
    let t = othergen::sweep(
        0..seeds,
        &[0, 1, 2, 3],
        othergen::KINDS,
        othergen::PAIRS.len(),
    );
    let sweep_s = t1.elapsed().as_secs_f64();
    let rate = |(n, h): (usize, usize)| json!({"n": n, "named": h, "rate": if n > 0 { h as f64 / n as f64 } else { f64::NAN }});
    let per_kind: serde_json::Map<String, Value> = t
        .single
        .iter()
        .map(|(k, &v)| (k.clone(), rate(v)))
        .collect();
    let kinds_75 = t.single_rates().iter().filter(|(_, r)| *r >= 0.75).count();
    let cases = t.single.values().map(|v| v.0).sum::<usize>() + t.pairs.0 + t.nulls.0 + t.outside.0;
    Ok(json!({
        "benchmark": "gap",
        "muts_x": muts,
        "othergen": {
            "generator": "tests/common/othergen.rs",
            "designs": 4,
            "seeds_per_design": seeds,
            "singles_by_kind": per_kind,
            "singles": rate(t.singles_total()),
            "kinds_named_in_75pct": format!("{kinds_75}/{}", t.single.len()),
            "pairs_both_named": rate(t.pairs),
            "nulls_with_a_named_effect": rate(t.nulls),
            "outside_library_misnamed": rate(t.outside),
            "misses": t.log,
            "cases": cases,
            "sweep_s": sweep_s,
            "ms_per_diagnosis": 1e3 * sweep_s / cases.max(1) as f64,
        },
        "runtime_s": t0.elapsed().as_secs_f64(),
    }))
}
