//! `csmetro gap` judged on data it was not made with: a second generator (tests/common/gapgen.rs)
//! written from the prediction contract, with the contract's layout (3 x lines + 1 y line, random
//! targets), ISO 230-2 fixed targets and single lines, two base models, and effects inside and
//! outside the library. `full_sweep` (ignored; run it in release) prints the rates the issue's
//! targets are about; the other tests run a few cases in a debug build.
use crate::gapgen;

use csmetro::gap::{diagnose, Diagnosis, Options};
use csmetro_sim::{AxisId, Effect, EffectKind, StageModel};
use gapgen::*;

/// A known base: the model's own cyclic error and backlash, in both descriptions.
fn base(which: usize) -> (StageModel, Vec<Eff>) {
    let mut m = StageModel::new(TRAVEL_X, TRAVEL_Y);
    let mut e = Vec::new();
    m.push(Effect::new(
        AxisId::X,
        EffectKind::LeadscrewCyclic {
            period_um: 400.0,
            cos_um: vec![0.4],
            sin_um: vec![0.2],
        },
    ));
    e.push(Eff::Cyclic {
        axis: AxisId::X,
        period_um: 400.0,
        cos_um: vec![0.4],
        sin_um: vec![0.2],
    });
    m.push(Effect::new(
        AxisId::X,
        EffectKind::Backlash { reversal_um: 1.5 },
    ));
    e.push(Eff::Backlash {
        axis: AxisId::X,
        reversal_um: 1.5,
    });
    if which == 1 {
        m.push(Effect::new(
            AxisId::Y,
            EffectKind::LeadscrewCyclic {
                period_um: 400.0,
                cos_um: vec![-0.3, 0.1],
                sin_um: vec![0.25, 0.0],
            },
        ));
        e.push(Eff::Cyclic {
            axis: AxisId::Y,
            period_um: 400.0,
            cos_um: vec![-0.3, 0.1],
            sin_um: vec![0.25, 0.0],
        });
        m.push(Effect::new(
            AxisId::Y,
            EffectKind::Backlash { reversal_um: 0.8 },
        ));
        e.push(Eff::Backlash {
            axis: AxisId::Y,
            reversal_um: 0.8,
        });
        m.push(Effect::new(
            AxisId::X,
            EffectKind::Scale {
                ppm: 25.0,
                ref_um: 0.0,
            },
        ));
        e.push(Eff::Scale {
            axis: AxisId::X,
            ppm: 25.0,
        });
    }
    (m, e)
}

/// Whether the diagnosis names `kind axis`: as a pick or in a tie of a pick (a withheld backlash
/// is named by a hysteresis of its axis, which contains it).
fn names(d: &Diagnosis, kind: &str, axis: &str) -> bool {
    d.added.iter().any(|a| {
        (a.kind == kind && a.axis == axis)
            || (kind == "backlash" && a.kind == "hysteresis" && a.axis == axis)
            || a.ties
                .iter()
                .any(|t| t.members.iter().any(|(k, x)| k == kind && x == axis))
    })
}

fn picks(d: &Diagnosis) -> String {
    d.added
        .iter()
        .map(|a| {
            let t: Vec<String> = a.ties.iter().map(|t| t.label()).collect();
            format!(
                "{} {}{}",
                a.kind,
                a.axis,
                if t.is_empty() {
                    String::new()
                } else {
                    format!(" [ties {}]", t.join("; "))
                }
            )
        })
        .collect::<Vec<_>>()
        .join(", ")
}

fn label(e: &Eff) -> (&'static str, &'static str) {
    e.label().expect("library effect")
}

#[derive(Default, Debug)]
struct Tally {
    single: (usize, usize),
    pairs: (usize, usize),
    nulls: (usize, usize),
    outside: (usize, usize),
    outside_mis: usize,
    closed: Vec<f64>,
    log: Vec<String>,
}

/// One sweep on the given layout maker: `n` cases per category.
fn sweep(n: usize, seed: u64, iso: bool, verbose: bool) -> Tally {
    let mut rng = Rng::new(seed);
    let mut t = Tally::default();
    let opts = Options::default();
    let layout = |rng: &mut Rng| {
        if iso {
            iso_layout(41, &[600.0, 2100.0, 3600.0], 21, rng)
        } else {
            contract_layout(120, 80, rng)
        }
    };
    let camp = Campaign::default();
    let gap_closed = |d: &Diagnosis| d.added.last().and_then(|a| a.gap_closed).unwrap_or(0.0);
    for i in 0..n {
        // Single.
        let (kind, axis) = GROUPS[i % GROUPS.len()];
        let (model, mut truth) = base(rng.pick(2));
        let lines = layout(&mut rng);
        let shape = random_library_effect(kind, axis, &mut rng);
        let peak = visible_peak(&shape, &lines, &camp);
        let e = shape.times(rng.range(0.2, 1.2) / peak);
        let (k, a) = label(&e);
        // Amplitudes as the issue saw them: 0.3-0.7 µm peak once line offsets are removed.
        let peak = visible_peak(&e, &lines, &camp);
        let e = if (0.3..0.7).contains(&peak) {
            e
        } else {
            e.times(0.5 / peak)
        };
        truth.push(e);
        let d = diagnose(&model, &generate(&truth, &lines, &camp, rng.u64()), &opts).unwrap();
        let ok = names(&d, k, a);
        t.single.0 += 1;
        t.single.1 += usize::from(ok);
        t.closed.push(gap_closed(&d));
        if !ok || verbose {
            t.log
                .push(format!("single {k} {a}: {} -> {}", ok, picks(&d)));
        }
    }
    for _ in 0..n {
        // Pairs: two different groups, not both scales of the confounded camera set, not
        // backlash and hysteresis of one axis.
        let ga = GROUPS[rng.pick(GROUPS.len())];
        let gb = loop {
            let g = GROUPS[rng.pick(GROUPS.len())];
            let conf = |x: &str| matches!(x, "scale" | "camera_scale");
            let bh = |x: &str| matches!(x, "backlash" | "hysteresis");
            if g != ga && !(conf(g.0) && conf(ga.0)) && !(bh(g.0) && bh(ga.0) && g.1 == ga.1) {
                break g;
            }
        };
        let (model, mut truth) = base(rng.pick(2));
        let lines = layout(&mut rng);
        let mut want = Vec::new();
        for (kind, axis) in [ga, gb] {
            let shape = random_library_effect(kind, axis, &mut rng);
            let peak = visible_peak(&shape, &lines, &camp);
            let e = shape.times(rng.range(0.2, 1.2) / peak);
            want.push(label(&e));
            truth.push(e);
        }
        let d = diagnose(&model, &generate(&truth, &lines, &camp, rng.u64()), &opts).unwrap();
        let ok = want.iter().all(|(k, a)| names(&d, k, a));
        t.pairs.0 += 1;
        t.pairs.1 += usize::from(ok);
        t.closed.push(gap_closed(&d));
        if !ok || verbose {
            t.log.push(format!("pair {want:?}: {ok} -> {}", picks(&d)));
        }
    }
    for _ in 0..n {
        let (model, truth) = base(rng.pick(2));
        let lines = layout(&mut rng);
        let d = diagnose(&model, &generate(&truth, &lines, &camp, rng.u64()), &opts).unwrap();
        t.nulls.0 += 1;
        t.nulls.1 += usize::from(!d.added.is_empty());
        if !d.added.is_empty() || verbose {
            t.log.push(format!("null -> {}", picks(&d)));
        }
    }
    for i in 0..n {
        let (model, mut truth) = base(rng.pick(2));
        let lines = layout(&mut rng);
        let axis = if rng.sign() > 0.0 {
            AxisId::X
        } else {
            AxisId::Y
        };
        let tr = if axis == AxisId::X {
            TRAVEL_X
        } else {
            TRAVEL_Y
        };
        let shape = match i % 3 {
            0 => Eff::Defect {
                axis,
                on_other: rng.sign() > 0.0,
                center_um: rng.range(tr[0] + 0.2 * tr[1], 0.8 * tr[1]),
                height_um: rng.sign(),
                width_um: rng.range(80.0, 200.0),
            },
            1 => Eff::TimeSine {
                comp: axis,
                amp_um: 1.0,
                period_s: rng.range(500.0, 1500.0),
                phase: rng.range(0.0, std::f64::consts::TAU),
            },
            _ => Eff::Periodic {
                axis,
                period_um: rng.range(600.0, 1100.0),
                amp_um: 1.0,
                phase: rng.range(0.0, std::f64::consts::TAU),
            },
        };
        let peak = visible_peak(&shape, &lines, &camp);
        truth.push(shape.times(rng.range(0.2, 1.2) / peak));
        let d = diagnose(&model, &generate(&truth, &lines, &camp, rng.u64()), &opts).unwrap();
        let flagged = d.unexplained.significant;
        let mis = !d.added.is_empty();
        t.outside.0 += 1;
        t.outside.1 += usize::from(flagged && !mis);
        t.outside_mis += usize::from(mis);
        if !flagged || mis || verbose {
            t.log.push(format!(
                "outside #{}: flagged {flagged} -> {}",
                i % 3,
                picks(&d)
            ));
        }
    }
    t
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    if v.is_empty() {
        f64::NAN
    } else {
        v[v.len() / 2]
    }
}

fn report(name: &str, t: &Tally) -> String {
    let r = |x: (usize, usize)| {
        format!(
            "{}/{} ({:.0} %)",
            x.1,
            x.0,
            100.0 * x.1 as f64 / x.0.max(1) as f64
        )
    };
    format!(
        "{name}: single {} pairs {} null false attributions {} outside flagged-not-misattributed {} (misattributed {}) median gap closed {:.2}",
        r(t.single),
        r(t.pairs),
        r(t.nulls),
        r(t.outside),
        t.outside_mis,
        median(t.closed.clone())
    )
}

/// The figures on the independent generator (release: about a minute per layout).
/// `cargo test --release --test system gap_independent:: -- --ignored --nocapture`
#[test]
#[ignore]
fn full_sweep() {
    let n: usize = std::env::var("GAP_SWEEP_CASES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(38);
    for (name, iso) in [
        ("contract layout", false),
        ("ISO 230-2 fixed targets", true),
    ] {
        let t = sweep(n, 35, iso, false);
        for l in &t.log {
            println!("  {l}");
        }
        println!("{}", report(name, &t));
    }
}

/// The effects the issue saw rejected at 10-20 σ on the contract layout (4 runs, σ = 0.05 µm),
/// one case each, and a null: named (or in a tie), nothing added without a gap.
#[test]
fn effects_rejected_before_are_named_on_the_contract_layout() {
    let mut rng = Rng::new(35);
    let lines = contract_layout(120, 80, &mut rng);
    let camp = Campaign::default();
    let cases: Vec<Eff> = vec![
        // The squareness: −164 µrad, 0.69 µm over the y stroke.
        Eff::Squareness { urad: -164.0 },
        Eff::Cyclic {
            axis: AxisId::X,
            period_um: 400.0 / 28.4,
            cos_um: vec![0.3],
            sin_um: vec![-0.2],
        },
        Eff::Hysteresis {
            axis: AxisId::Y,
            b0_um: 0.2,
            b1_um: 0.5,
        },
        Eff::Yaw {
            axis: AxisId::X,
            urad: [40.0, -120.0],
        },
        Eff::Thermal {
            comp: AxisId::X,
            amp_um: 0.8,
            tau_s: 1500.0,
            rate_um_per_h: 0.1,
        },
    ];
    for (i, e) in cases.into_iter().enumerate() {
        let (model, mut truth) = base(i % 2);
        let (k, a) = label(&e);
        // Amplitudes as the issue saw them: 0.3-0.7 µm peak once line offsets are removed.
        let peak = visible_peak(&e, &lines, &camp);
        let e = if (0.3..0.7).contains(&peak) {
            e
        } else {
            e.times(0.5 / peak)
        };
        truth.push(e);
        let d = diagnose(
            &model,
            &generate(&truth, &lines, &camp, 100 + i as u64),
            &Options::default(),
        )
        .unwrap();
        assert!(names(&d, k, a), "{k} {a} not named: {}", d.summary());
        assert_eq!(d.added.len(), 1, "{k} {a}: {}", d.summary());
        let closed = d.added[0].gap_closed.unwrap_or(0.0);
        assert!(closed > 0.8, "{k} {a}: gap closed {closed}");
    }
    let (model, truth) = base(1);
    let d = diagnose(
        &model,
        &generate(&truth, &lines, &camp, 7),
        &Options::default(),
    )
    .unwrap();
    assert!(d.added.is_empty(), "null: {}", d.summary());
}
