//! The example campaigns in `config/campaigns` are what users copy: each must validate as it is
//! (the simulated ones also run, in tests/campaign_run.rs and the README's main job).
use crate::common;

use csmetro::campaign::spec::{Campaign, HardwareKind};

#[test]
fn every_example_campaign_validates() {
    let dir = common::repo("config/campaigns");
    let mut seen = Vec::new();
    for e in std::fs::read_dir(&dir).unwrap() {
        let p = e.unwrap().path();
        if p.extension().is_some_and(|x| x == "toml") {
            let c = match Campaign::load(&p) {
                Ok(c) => c,
                // A real-rig template needs its camera backend compiled in (`--features aravis`):
                // without it, that is the one complaint, and the file is otherwise valid.
                Err(e) if e.message.contains("needs a csmetro built with --features") => {
                    let text = std::fs::read_to_string(&p).unwrap();
                    Campaign::parse_any_build(&text, &p.display().to_string(), &dir)
                        .unwrap_or_else(|e| panic!("{e}"))
                }
                Err(e) => panic!("{e}"),
            };
            seen.push((p.file_name().unwrap().to_string_lossy().to_string(), c));
        }
    }
    let kind = |name: &str| {
        seen.iter()
            .find(|(n, _)| n == name)
            .map(|(_, c)| c.spec().hardware.kind)
    };
    assert_eq!(kind("demo-sim.toml"), Some(HardwareKind::Sim));
    assert_eq!(kind("lab-xy-real.toml"), Some(HardwareKind::Real));
    // The lab template plans the paper's design: 300 + 300 on X and 150 + 150 on Y.
    let real = &seen
        .iter()
        .find(|(n, _)| n == "lab-xy-real.toml")
        .unwrap()
        .1;
    let plan = csmetro::campaign::plan::plan(real);
    assert_eq!(plan.total(), 900);
}
