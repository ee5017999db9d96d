//! The two readers `csmetro gap` feeds on untrusted files — the stage-model TOML and the campaign
//! CSV — on random and mutated input: never a panic, never a hang, and whatever they accept is sane
//! (a model writes back to itself; samples are finite with run ids >= 0).
use std::path::Path;
use std::time::{Duration, Instant};

use csmetro::gap::data::{parse_csv, simulate_campaign, to_csv_string, CampaignSpec};
use csmetro_sim::StageModel;
use proptest::prelude::*;

/// A hang guard, not a timing: a debug build parses any of these in milliseconds, a loaded host
/// in well under this; a parse still running after it is a loop.
const BUDGET: Duration = Duration::from_secs(60);

fn shipped_models() -> Vec<String> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("config/sim");
    let mut v: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "toml"))
        .map(|p| std::fs::read_to_string(p).unwrap())
        .collect();
    v.sort();
    assert!(v.len() >= 3);
    v
}

fn valid_csv() -> String {
    let spec = CampaignSpec {
        runs: 2,
        targets_per_line: 5,
        static_positions: 2,
        ..Default::default()
    };
    to_csv_string(&simulate_campaign(&StageModel::default(), &spec, None))
}

/// Byte edits: (position, byte, 0 replace / 1 insert / 2 delete); positions wrap.
fn mutate(text: &str, edits: &[(usize, u8, u8)]) -> String {
    let mut b = text.as_bytes().to_vec();
    for &(pos, byte, op) in edits {
        let i = if b.is_empty() { 0 } else { pos % b.len() };
        match op {
            0 if !b.is_empty() => b[i] = byte,
            1 => b.insert(i, byte),
            _ if !b.is_empty() => {
                b.remove(i);
            }
            _ => {}
        }
    }
    String::from_utf8_lossy(&b).into_owned()
}

/// Bytes a mutation draws from: mostly the syntax and digits of the formats.
fn edit_byte() -> impl Strategy<Value = u8> {
    prop_oneof![
        4 => prop::sample::select(b"0123456789.-+eE,=[]\"\n #xyinf_".to_vec()),
        1 => any::<u8>(),
    ]
}

fn edits() -> impl Strategy<Value = Vec<(usize, u8, u8)>> {
    prop::collection::vec((any::<usize>(), edit_byte(), 0u8..3), 1..8)
}

fn check_model(text: &str) -> Result<(), TestCaseError> {
    let t0 = Instant::now();
    let r = StageModel::from_toml_str(text);
    prop_assert!(t0.elapsed() < BUDGET, "{:?} on\n{text}", t0.elapsed());
    match r {
        Ok(m) => match StageModel::from_toml_str(&m.to_toml_string()) {
            Ok(again) => prop_assert_eq!(again, m),
            Err(e) => prop_assert!(false, "written back, then refused: {}", e),
        },
        Err(e) => {
            let msg = e.to_string();
            prop_assert_eq!(msg.trim().lines().count(), 1, "one line: {}", msg);
        }
    }
    Ok(())
}

fn check_csv(text: &str) -> Result<(), TestCaseError> {
    let t0 = Instant::now();
    let r = parse_csv("d.csv", text);
    prop_assert!(t0.elapsed() < BUDGET, "{:?}", t0.elapsed());
    match r {
        Ok(samples) => {
            for s in samples {
                prop_assert!(s.run >= 0);
                for v in [
                    s.target_x_um,
                    s.target_y_um,
                    s.time_s,
                    s.meas_x_um,
                    s.meas_y_um,
                ] {
                    prop_assert!(v.is_finite());
                }
            }
        }
        Err(e) => {
            let e = e.to_string();
            prop_assert!(e.starts_with("d.csv:"), "{}", e);
            prop_assert_eq!(e.lines().count(), 1, "one line: {}", e);
        }
    }
    Ok(())
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 192, ..ProptestConfig::default() })]

    #[test]
    fn model_reader_survives_mutated_shipped_models(which in 0usize..3, e in edits()) {
        let models = shipped_models();
        check_model(&mutate(&models[which % models.len()], &e))?;
    }

    #[test]
    fn model_reader_survives_random_text(text in "(\\[\\[effect\\]\\]\n|\\[stage\\]\n|kind = \"[a-z_]{1,12}\"\n|[a-z_]{1,10} = [-0-9.e\\[\\], ]{0,24}\n|\\PC{0,12})*") {
        check_model(&text)?;
    }

    #[test]
    fn csv_reader_survives_mutated_campaigns(e in edits()) {
        check_csv(&mutate(&valid_csv(), &e))?;
    }

    #[test]
    fn csv_reader_survives_random_text(text in "(run,axis,direction,target_x_um,target_y_um,time_s,meas_x_um,meas_y_um\n|[-0-9.a-z,]{0,40}\n|\\PC{0,16})*") {
        check_csv(&text)?;
    }
}
