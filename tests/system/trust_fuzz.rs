//! The campaign parser and the samples CSV reader on random and mutated input: an error, never
//! a panic or a hang.
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use csmetro::campaign::spec::Campaign;
use csmetro::grid::Grid;
use csmetro::samples::parse_samples_csv;
use proptest::prelude::*;

fn config_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("config/campaigns")
}

fn shipped() -> Vec<String> {
    ["demo-sim.toml", "gap-lines.toml", "lab-xy-real.toml"]
        .iter()
        .map(|f| std::fs::read_to_string(config_dir().join(f)).unwrap())
        .collect()
}

/// One edit of a byte string: flip, insert, delete, or duplicate a span.
#[derive(Debug, Clone)]
enum Edit {
    Set(usize, u8),
    Insert(usize, Vec<u8>),
    Delete(usize, usize),
    Repeat(usize, usize),
}

fn edit() -> impl Strategy<Value = Edit> {
    // Bytes a TOML file is made of, so mutations reach the validator, not only the lexer.
    let byte = prop_oneof![
        Just(b'0'),
        Just(b'9'),
        Just(b'-'),
        Just(b'.'),
        Just(b'e'),
        Just(b'"'),
        Just(b'['),
        Just(b']'),
        Just(b','),
        Just(b'='),
        Just(b'\n'),
        Just(b'#'),
        any::<u8>(),
    ];
    prop_oneof![
        (any::<usize>(), byte.clone()).prop_map(|(i, b)| Edit::Set(i, b)),
        (any::<usize>(), prop::collection::vec(byte, 1..8)).prop_map(|(i, b)| Edit::Insert(i, b)),
        (any::<usize>(), 1usize..40).prop_map(|(i, n)| Edit::Delete(i, n)),
        (any::<usize>(), 1usize..40).prop_map(|(i, n)| Edit::Repeat(i, n)),
    ]
}

fn apply(text: &str, edits: &[Edit]) -> String {
    let mut b = text.as_bytes().to_vec();
    for e in edits {
        let at = |i: usize| if b.is_empty() { 0 } else { i % b.len() };
        match e {
            Edit::Set(i, v) => {
                let i = at(*i);
                if let Some(x) = b.get_mut(i) {
                    *x = *v;
                }
            }
            Edit::Insert(i, v) => {
                let i = at(*i);
                b.splice(i..i, v.iter().copied());
            }
            Edit::Delete(i, n) => {
                let i = at(*i);
                let end = (i + n).min(b.len());
                b.drain(i..end);
            }
            Edit::Repeat(i, n) => {
                let i = at(*i);
                let end = (i + n).min(b.len());
                let span = b[i..end].to_vec();
                b.splice(end..end, span);
            }
        }
    }
    String::from_utf8_lossy(&b).into_owned()
}

fn parse_quickly(text: &str) {
    let t0 = Instant::now();
    match Campaign::parse(text, "fuzz.toml", &config_dir()) {
        Ok(c) => {
            assert!(!c.axes().is_empty());
            for a in c.axes() {
                assert!(a.grid.n <= csmetro::grid::MAX_GRID_POINTS);
                assert!(a.m <= a.grid.n);
            }
        }
        Err(e) => assert!(e.to_string().starts_with("fuzz.toml:"), "{e}"),
    }
    assert!(t0.elapsed() < Duration::from_secs(5), "{:?}", t0.elapsed());
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 256, failure_persistence: None, ..ProptestConfig::default() })]

    #[test]
    fn mutated_shipped_campaigns_never_panic(file in 0usize..3, edits in prop::collection::vec(edit(), 1..6)) {
        let text = apply(&shipped()[file], &edits);
        parse_quickly(&text);
    }

    #[test]
    fn random_text_never_panics(text in "\\PC{0,400}") {
        parse_quickly(&text);
    }

    #[test]
    fn numbers_anywhere_in_an_axis_never_panic(
        start in prop_oneof![Just(0.0f64), -1e300f64..1e300, Just(f64::MIN_POSITIVE)],
        step in prop_oneof![Just(1e-7f64), Just(5e-324f64), 1e-9f64..1e4, Just(-1.0f64)],
        end in prop_oneof![Just(9500.0f64), -1e6f64..1e6, Just(1e300f64)],
        m in prop_oneof![Just(0u64), 0u64..5000, Just(u64::MAX / 2)],
    ) {
        let text = format!(
            "[campaign]\nname = \"f\"\n[hardware]\nkind = \"sim\"\n[axes.x]\n\
             range_um = [{start:e}, {end:e}]\nstep_um = {step:e}\nother_at_um = 0.0\nm = {m}\n"
        );
        parse_quickly(&text);
    }

    #[test]
    fn samples_csv_never_panics(edits in prop::collection::vec(edit(), 0..6), rows in 0usize..50) {
        let grid: Grid = "0:5:500".parse().unwrap();
        let mut text = String::from("position_um,error_um\n");
        for i in 0..rows {
            text.push_str(&format!("{},{}\n", (i * 5) % 505, i as f64 * 0.1));
        }
        let text = apply(&text, &edits);
        let t0 = Instant::now();
        if let Ok(s) = parse_samples_csv(&text, &grid) {
            prop_assert!(s.len() >= 2 && s.len() <= grid.n);
            prop_assert!(s.idx.windows(2).all(|w| w[0] < w[1]));
        }
        prop_assert!(t0.elapsed() < Duration::from_secs(2));
    }
}
