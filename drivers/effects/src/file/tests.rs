//! The model-file reader and writer: lines in errors, bounds, defaults, round trips.
use super::*;
use crate::{Component, SampleContext};

fn ctx(moving: AxisId, d: f64, x: f64, y: f64) -> SampleContext {
    SampleContext {
        moving,
        direction: d,
        target_x_um: x,
        target_y_um: y,
        time_s: 0.0,
    }
}

/// `line N:` of an error from `from_toml_str`.
fn err_line(text: &str) -> (usize, String) {
    match StageModel::from_toml_str(text).unwrap_err() {
        ModelError::Line { line, message } => (line, message),
        other => panic!("no line in {other}"),
    }
}

#[test]
fn errors_name_the_line_of_the_key_or_the_effect() {
    let head = "[stage]\ntravel_x_um = [0.0, 9500.0]\n\n[[effect]]\nkind = \"scale\"\naxis = \"x\"\nppm = 1\n\n";
    // Lines 9.. are the second effect.
    let (l, m) = err_line(&format!(
        "{head}[[effect]]\nkind = \"backlash\"\naxis = \"x\"\nreversal_um = 1\nslope = 2\n"
    ));
    assert_eq!(l, 13, "{m}");
    assert!(m.contains("unknown parameter `slope`"), "{m}");
    let (l, m) = err_line(&format!(
        "{head}[[effect]]\nkind = \"harmonic\"\naxis = \"x\"\nperiod_um = -4\n"
    ));
    assert_eq!(l, 12, "{m}");
    assert!(m.contains("`period_um` must be > 0"), "{m}");
    let (l, m) = err_line(&format!(
        "{head}[[effect]]\naxis = \"x\"\nkind = \"warp\"\n"
    ));
    assert_eq!((l, m.contains("unknown kind `warp`")), (11, true), "{m}");
    let (l, m) = err_line(&format!(
        "{head}[[effect]]\nkind = \"backlash\"\naxis = \"x\"\n"
    ));
    assert!(
        (9..=11).contains(&l) && m.contains("reversal_um"),
        "{l}: {m}"
    );
    let (l, m) = err_line(&format!(
        "{head}[[effect]]\nkind = \"backlash\"\naxis = \"z\"\n"
    ));
    assert_eq!(l, 11, "{m}");
    let (l, m) = err_line("[stage]\ntravel_x_um = [0.0, 9500.0]\ntravel_y_um = [5.0, 1.0]\n");
    assert_eq!(l, 3, "{m}");
    assert!(m.contains("travel_y_um"), "{m}");
    let (l, _) = err_line(&format!("{head}[[effect]]\nkind = \"scale\"\nppm = = 3\n"));
    assert_eq!(l, 11);
    let (l, m) = err_line(&format!(
        "{head}[[effect]]\nkind = \"noise\"\nsigma_um = nan\n"
    ));
    assert_eq!(l, 11, "{m}");
    assert!(m.contains("finite"), "{m}");
    // A value of the wrong type: serde does not name the key, the reader does.
    let (l, m) = err_line(&format!(
        "{head}[[effect]]\nkind = \"scale\"\naxis = \"x\"\nppm = \"abc\"\nref_um = 3\n"
    ));
    assert_eq!(l, 12, "{m}");
    assert!(m.contains("`ppm`") && m.contains("invalid type"), "{m}");
    let (l, m) = err_line(&format!(
        "{head}[[effect]]\nkind = \"harmonic\"\naxis = \"x\"\nperiod_um = 3\ncomponent = \"up\"\n"
    ));
    assert_eq!(l, 13, "{m}");
    assert!(m.contains("`component`"), "{m}");
}

#[test]
fn load_names_the_file_and_the_line() {
    let dir = std::env::temp_dir().join(format!("csmetro-model-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let p = dir.join("m.toml");
    std::fs::write(
        &p,
        "[[effect]]\nkind = \"backlash\"\naxis = \"x\"\nreversal = 1\n",
    )
    .unwrap();
    let e = StageModel::load(&p).unwrap_err().to_string();
    std::fs::remove_dir_all(&dir).unwrap();
    assert!(e.starts_with(&format!("{}:4: ", p.display())), "{e}");
    assert_eq!(e.lines().count(), 1, "{e}");
}

#[test]
fn absurd_sizes_are_refused() {
    let keys: String = (0..40).map(|i| format!("k{i} = {i}\n")).collect();
    let (l, m) = err_line(&format!(
        "[[effect]]\nkind = \"scale\"\naxis = \"x\"\n{keys}"
    ));
    assert_eq!(l, 1, "{m}");
    assert!(m.contains("at most 32"), "{m}");
    let dir = std::env::temp_dir().join(format!("csmetro-big-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let p = dir.join("big.toml");
    std::fs::write(&p, "# padding\n".repeat(200_000)).unwrap();
    let e = StageModel::load(&p).unwrap_err().to_string();
    std::fs::remove_dir_all(&dir).unwrap();
    assert!(
        e.contains("big.toml") && e.contains("at most 1048576"),
        "{e}"
    );
    let many: Vec<String> = (0..1000).map(|i| format!("{}.0", i % 7)).collect();
    let (l, m) = err_line(&format!(
        "[[effect]]\nkind = \"leadscrew_cyclic\"\naxis = \"x\"\ncos_um = [{}]\n",
        many.join(", ")
    ));
    assert_eq!(l, 4, "{m}");
    assert!(
        m.contains("cos_um") && m.contains(&MAX_TERMS.to_string()),
        "{m}"
    );
    let ok: Vec<String> = (0..MAX_TERMS).map(|_| "0.1".to_string()).collect();
    StageModel::from_toml_str(&format!(
        "[[effect]]\nkind = \"leadscrew_cyclic\"\naxis = \"x\"\ncos_um = [{}]\n",
        ok.join(", ")
    ))
    .unwrap();
    let one = "[[effect]]\nkind = \"backlash\"\naxis = \"x\"\nreversal_um = 1\n";
    StageModel::from_toml_str(&one.repeat(MAX_EFFECTS)).unwrap();
    let (l, m) = err_line(&one.repeat(MAX_EFFECTS + 1));
    assert_eq!(l, 4 * MAX_EFFECTS + 1, "{m}");
    assert!(m.contains(&MAX_EFFECTS.to_string()), "{m}");
    let (l, m) = err_line("[stage]\ntravel_x_um = [0.0, 1e12]\n");
    assert_eq!(l, 2, "{m}");
    let (_, m) = err_line(
        "[[effect]]\nkind = \"roughness\"\naxis = \"x\"\nsigma_um = 0.1\ncorr_um = 5\ntravel_um = [0, 5e9]\n",
    );
    assert!(m.contains("travel_um"), "{m}");
}

/// One effect of every kind, parameters away from their defaults.
fn every_kind() -> StageModel {
    let x = AxisId::X;
    let y = AxisId::Y;
    let kinds = [
        (
            x,
            EffectKind::Scale {
                ppm: 12.5,
                ref_um: 100.0,
            },
        ),
        (
            y,
            EffectKind::LeadscrewCyclic {
                period_um: 500.0,
                cos_um: vec![0.4, 0.1],
                sin_um: vec![0.2],
            },
        ),
        (
            x,
            EffectKind::MotorCyclic {
                period_um: 14.1,
                cos_um: vec![],
                sin_um: vec![0.03],
            },
        ),
        (x, EffectKind::Backlash { reversal_um: 1.5 }),
        (
            y,
            EffectKind::Hysteresis {
                b0_um: 0.7,
                b1_um: -0.2,
            },
        ),
        (
            x,
            EffectKind::Straightness {
                legendre_um: vec![0.3, -0.1, 0.05],
            },
        ),
        (
            x,
            EffectKind::YawAbbe {
                yaw_urad: [20.0, -5.0],
                offset_um: 2100.0,
            },
        ),
        (y, EffectKind::Squareness { angle_urad: 60.0 }),
        (x, EffectKind::CameraRotation { angle_urad: -3.0 }),
        (x, EffectKind::CameraScale { ppm: 4.0 }),
        (
            x,
            EffectKind::ThermalDrift {
                component: y,
                amp_um: 0.5,
                tau_s: 900.0,
                rate_um_per_h: 0.1,
            },
        ),
        (x, EffectKind::Noise { sigma_um: 0.05 }),
        (
            y,
            EffectKind::LeadscrewModulated {
                period_um: 400.0,
                amp_um: vec![1.2, 0.35],
                phase_rad: vec![2.1, 0.4],
                env_linear: 0.1,
                env_wave_amp: 0.12,
                env_wave_period_um: 2600.0,
                env_wave_phase_rad: 0.7,
                phase_drift_rad: 0.25,
            },
        ),
        (
            x,
            EffectKind::Harmonic {
                component: Component::Other,
                period_um: 1450.0,
                cos_um: vec![-0.15],
                sin_um: vec![0.19, 0.01],
            },
        ),
        (
            y,
            EffectKind::Legendre {
                component: Component::Axis,
                coef_um: vec![0.0, -0.8],
            },
        ),
        (
            x,
            EffectKind::Defect {
                component: Component::Other,
                center_um: 2187.0,
                height_um: 0.57,
                sigma_um: 27.9,
            },
        ),
        (
            x,
            EffectKind::Roughness {
                component: Component::Axis,
                sigma_um: 0.085,
                corr_um: 12.0,
                seed: u64::MAX - 7,
            },
        ),
    ];
    let mut m = StageModel::new([-50.0, 9450.0], [0.0, 4200.0]);
    for (i, (axis, kind)) in kinds.into_iter().enumerate() {
        let e = Effect::new(axis, kind);
        m.push(if i == 4 {
            e.with_travel([100.0, 4000.0])
        } else {
            e
        });
    }
    assert_eq!(m.effects.len(), LIBRARY_KINDS.len() + SIM_ONLY_KINDS.len());
    m
}

#[test]
fn every_kind_round_trips_through_toml() {
    let m = every_kind();
    let text = m.to_toml_string();
    let again = StageModel::from_toml_str(&text).unwrap_or_else(|e| panic!("{e}\n{text}"));
    assert_eq!(m, again);
    assert_eq!(again.to_toml_string(), text);
    for (x, y, d, t) in [(10.0, 20.0, 1.0, 0.0), (4321.0, 1234.0, -1.0, 600.0)] {
        for moving in [AxisId::X, AxisId::Y] {
            let c = SampleContext {
                time_s: t,
                ..ctx(moving, d, x, y)
            };
            assert_eq!(m.deviation(&c), again.deviation(&c));
        }
    }
}

#[test]
fn file_defaults_are_the_documented_ones() {
    let m = StageModel::from_toml_str(
        "[[effect]]\nkind = \"leadscrew_cyclic\"\naxis = \"X\"\ncos_um = [1]\n\
         [[effect]]\nkind = \"thermal_drift\"\naxis = \"y\"\n\
         [[effect]]\nkind = \"yaw_abbe\"\naxis = \"x\"\nyaw_urad = [3]\n\
         [[effect]]\nkind = \"harmonic\"\naxis = \"y\"\nperiod_um = 50\n",
    )
    .unwrap();
    let kinds: Vec<&EffectKind> = m.effects.iter().map(|e| &e.kind).collect();
    assert_eq!(
        kinds,
        [
            &EffectKind::LeadscrewCyclic {
                period_um: 400.0,
                cos_um: vec![1.0],
                sin_um: vec![]
            },
            &EffectKind::ThermalDrift {
                component: AxisId::Y,
                amp_um: 0.0,
                tau_s: 1800.0,
                rate_um_per_h: 0.0
            },
            &EffectKind::YawAbbe {
                yaw_urad: [3.0, 0.0],
                offset_um: 0.0
            },
            &EffectKind::Harmonic {
                component: Component::Axis,
                period_um: 50.0,
                cos_um: vec![],
                sin_um: vec![]
            },
        ]
    );
    assert_eq!(m.effects[0].axis, AxisId::X);
}

/// Every model file the repository ships loads, and writes back to the same model.
#[test]
fn shipped_models_load_and_round_trip() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config/sim");
    let mut n = 0;
    for entry in std::fs::read_dir(&dir).unwrap() {
        let p = entry.unwrap().path();
        if p.extension().is_some_and(|e| e == "toml") {
            let m = StageModel::load(&p).unwrap_or_else(|e| panic!("{e}"));
            let again = StageModel::from_toml_str(&m.to_toml_string()).unwrap();
            assert_eq!(m, again, "{}", p.display());
            n += 1;
        }
    }
    assert!(n >= 3, "config/sim has its models");
}

/// A model path naming a device, a directory or a kernel file is refused before any read:
/// `/dev/zero` never ends and `/proc` files report a size of 0.
#[test]
fn non_regular_files_are_refused_without_reading() {
    let t0 = std::time::Instant::now();
    for p in ["/dev/zero", "/proc/self/environ", "/tmp"] {
        let e = StageModel::load(std::path::Path::new(p))
            .unwrap_err()
            .to_string();
        assert!(e.contains("not a regular file"), "{p}: {e}");
    }
    assert!(t0.elapsed().as_secs_f64() < 2.0);
}
