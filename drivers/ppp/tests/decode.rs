//! Render → decode behaviour the metrology depends on: sub-pixel linearity, repeatability,
//! the whole stage range with rotation, and rejection (never a silently wrong position).
use csmetro_hal::{Frame, Pixels};
use csmetro_ppp::render;
use csmetro_ppp::selftest::{self, RANGE_X_UM, RANGE_Y_UM};
use csmetro_ppp::{
    read_png, write_png, DecodeConfig, Decoder, Optics, Pattern, PatternConfig, Pose,
};

fn setup() -> (Decoder, Optics) {
    let pattern = Pattern::new(PatternConfig::default()).unwrap();
    let optics = Optics::default();
    (
        Decoder::new(pattern.clone(), DecodeConfig::for_optics(&pattern, &optics)),
        optics,
    )
}

const UM_PER_PX: f64 = 0.465;

fn assert_decodes(dec: &Decoder, optics: &Optics, pose: Pose, seed: u64, tol_px: f64) {
    let r = dec.decode(&render(dec.pattern(), optics, pose, seed));
    assert!(r.ok, "{pose:?} rejected: {:?}", r.reason);
    let (ex, ey) = (
        (r.x_um - pose.x_um) / UM_PER_PX,
        (r.y_um - pose.y_um) / UM_PER_PX,
    );
    assert!(
        ex.abs() < tol_px && ey.abs() < tol_px,
        "{pose:?}: error ({ex:.5}, {ey:.5}) px"
    );
    assert!(
        (r.theta_mrad - pose.theta_mrad).abs() < 0.01,
        "{pose:?}: theta {}",
        r.theta_mrad
    );
    assert!(
        (r.period_px - 4.0 / UM_PER_PX).abs() < 1e-3,
        "period {}",
        r.period_px
    );
}

#[test]
fn sub_pixel_steps_over_one_period_are_linear() {
    let (dec, mut optics) = setup();
    optics.read_noise = 0.0;
    let lin = selftest::linearity(&dec, &optics, Pose::new(5000.0, 2000.0, 0.0), 0.25, 1);
    assert_eq!(lin.rejected, 0);
    assert!(lin.steps >= 35, "a full period of 8.6 px in 0.25 px steps");
    assert!(
        lin.max_residual_x_px <= 1e-3 && lin.max_residual_y_px <= 1e-3,
        "{lin:?}"
    );
    assert!(
        lin.scale_error_x.abs() < 2e-4 && lin.scale_error_y.abs() < 2e-4,
        "{lin:?}"
    );
}

#[test]
fn repeatability_at_fixed_pose_with_1px_psf_and_1pct_noise() {
    let (dec, optics) = setup();
    let p = selftest::precision(&dec, &optics, Pose::new(3210.7, 1234.3, 3.0), 16, 5);
    assert_eq!(p.rejected, 0);
    assert!(p.std_x_px <= 1e-3 && p.std_y_px <= 1e-3, "{p:?}");
    // Accuracy (mean error) of a few nm: the coded dots are not a perfect grating.
    assert!(
        p.bias_x_px.abs() < 5e-3 && p.bias_y_px.abs() < 5e-3,
        "{p:?}"
    );
}

#[test]
fn range_edges_and_corners_decode() {
    let (dec, optics) = setup();
    let mut seed = 0;
    for &x in &[0.0, RANGE_X_UM] {
        for &y in &[0.0, RANGE_Y_UM] {
            for &t in &[-20.0, 20.0] {
                seed += 1;
                assert_decodes(&dec, &optics, Pose::new(x, y, t), seed, 0.01);
            }
        }
    }
}

#[test]
fn rotation_within_20_mrad_is_measured() {
    let (dec, optics) = setup();
    for (i, t) in [-20.0, -12.5, -3.3, 0.0, 0.7, 9.9, 20.0]
        .into_iter()
        .enumerate()
    {
        assert_decodes(&dec, &optics, Pose::new(2468.2, 1357.9, t), i as u64, 0.01);
    }
}

#[test]
fn period_boundaries_do_not_slip_a_period() {
    // Positions just either side of a lattice line (phase ±π) must not lose or gain a period.
    let (dec, optics) = setup();
    for (i, x) in [1000.0, 1001.999, 1002.0, 1002.001, 1003.999, 1004.0]
        .into_iter()
        .enumerate()
    {
        assert_decodes(
            &dec,
            &optics,
            Pose::new(x, 3001.999 + 0.001 * i as f64, 1.0),
            i as u64,
            0.01,
        );
    }
}

#[test]
fn random_poses_over_the_range_decode_right() {
    let (dec, optics) = setup();
    let s = selftest::sweep(&dec, &optics, 24, false, 11, 2);
    assert_eq!(s.wrong, 0, "{s:?}");
    assert_eq!(s.right, s.frames, "nominal frames must all decode: {s:?}");
    assert!(s.max_error_px < 0.01, "{s:?}");
}

#[test]
fn degraded_frames_are_right_or_rejected() {
    let (dec, optics) = setup();
    let s = selftest::sweep(&dec, &optics, 40, true, 12, 2);
    assert_eq!(s.wrong, 0, "silently wrong: {s:?}");
    assert!(
        s.right > 0 && s.rejected > 0,
        "the sweep should contain both outcomes: {s:?}"
    );
}

fn rejected(dec: &Decoder, frame: &Frame, what: &str) -> String {
    let r = dec.decode(frame);
    assert!(!r.ok, "{what} decoded to ({}, {})", r.x_um, r.y_um);
    assert!(
        r.x_um.is_nan() && r.y_um.is_nan(),
        "{what}: a rejected frame carries no position"
    );
    r.reason.expect("a rejection has a reason")
}

#[test]
fn blank_frame_is_rejected() {
    let (dec, mut optics) = setup();
    optics.foreground = optics.background; // no contrast: illumination and noise only
    optics.gradient = [0.3, -0.2];
    let reason = rejected(
        &dec,
        &render(dec.pattern(), &optics, Pose::new(100.0, 100.0, 0.0), 3),
        "blank",
    );
    assert!(reason.contains("carrier"), "{reason}");
}

#[test]
fn heavy_defocus_is_rejected() {
    let (dec, mut optics) = setup();
    optics.psf_sigma_px = 3.0;
    optics.defocus_radius_px = 6.0;
    rejected(
        &dec,
        &render(dec.pattern(), &optics, Pose::new(4000.0, 2000.0, 0.0), 3),
        "defocused",
    );
}

#[test]
fn dust_gives_right_or_rejected_and_heavy_dust_is_rejected() {
    let (dec, mut optics) = setup();
    let pose = Pose::new(4000.0, 2000.0, 0.0);
    // Many large particles: the decoder may still read enough code, but never a wrong position.
    optics.dust_count = 400;
    optics.dust_radius_px = [20.0, 45.0];
    for seed in 0..4 {
        let r = dec.decode(&render(dec.pattern(), &optics, pose, seed));
        assert!(
            !r.ok || ((r.x_um - pose.x_um).abs() < 0.05 && (r.y_um - pose.y_um).abs() < 0.05),
            "{r:?}"
        );
    }
    // Nearly every lattice site covered: nothing left to decode.
    optics.dust_count = 3000;
    rejected(
        &dec,
        &render(dec.pattern(), &optics, pose, 4),
        "buried in dust",
    );
}

#[test]
fn wrong_patterns_are_rejected() {
    let (dec, optics) = setup();
    let cfg = PatternConfig::default();
    let grid = Pattern::full_grid(cfg.clone()).unwrap();
    let reason = rejected(
        &dec,
        &render(&grid, &optics, Pose::new(4000.0, 2000.0, 2.0), 1),
        "full grid",
    );
    assert!(reason.contains("orientation"), "{reason}");
    let other_code = Pattern::new(PatternConfig {
        code_bits: 11,
        ..cfg.clone()
    })
    .unwrap();
    for (i, x) in [1000.0, 3000.0, 5000.0, 7000.0].into_iter().enumerate() {
        rejected(
            &dec,
            &render(
                &other_code,
                &optics,
                Pose::new(x, 2000.0 + 500.0 * i as f64, 0.0),
                2,
            ),
            "11-bit code",
        );
    }
    let other_period = Pattern::new(PatternConfig {
        period_um: 5.5,
        ..cfg
    })
    .unwrap();
    rejected(
        &dec,
        &render(&other_period, &optics, Pose::new(4000.0, 2000.0, 0.0), 2),
        "5.5 µm period",
    );
}

#[test]
fn truncated_frame_is_rejected_not_panicking() {
    let (dec, _) = setup();
    let f = Frame {
        width: 1024,
        height: 768,
        bit_depth: 8,
        pixels: Pixels::Mono8(vec![0; 1000]),
        timestamp_s: 0.0,
    };
    rejected(&dec, &f, "truncated");
    let small = Frame {
        width: 100,
        height: 80,
        bit_depth: 8,
        pixels: Pixels::Mono8(vec![7; 8000]),
        timestamp_s: 0.0,
    };
    rejected(&dec, &small, "too small");
}

#[test]
fn png_round_trip_8_and_12_bit_decodes_the_same() {
    let (dec, mut optics) = setup();
    let dir = std::env::temp_dir().join(format!("csmetro-ppp-io-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    for depth in [8u8, 12] {
        optics.bit_depth = depth;
        let frame = render(dec.pattern(), &optics, Pose::new(777.7, 333.3, -4.0), 9);
        let path = dir.join(format!("f{depth}.png"));
        write_png(&path, &frame).unwrap();
        let back = read_png(&path).unwrap();
        assert_eq!(back.bit_depth, depth);
        assert_eq!(back.pixels, frame.pixels);
        let (a, b) = (dec.decode(&frame), dec.decode(&back));
        assert!(a.ok && b.ok && a.x_um == b.x_um && a.y_um == b.y_um);
    }
    std::fs::remove_dir_all(&dir).ok();
}

/// A 640 x 640 region of interest sees ~25 code bits per axis; where they are mostly zeros
/// (y ≈ 2370 µm) the code-column x code-row class is nearly as dark as the orientation corner.
/// Such frames must still decode right, all along the Y stroke the demo campaign measures.
#[test]
fn small_roi_decodes_where_the_visible_code_is_sparse() {
    let pattern = Pattern::new(PatternConfig::default()).unwrap();
    let optics = Optics {
        width: 640,
        height: 640,
        ..Optics::default()
    };
    let dec = Decoder::new(pattern.clone(), DecodeConfig::for_optics(&pattern, &optics));
    let sparse = (0..=16).map(|k| 2340.0 + 5.0 * k as f64);
    let stroke = (0..=42).map(|k| 100.0 * k as f64);
    for (n, y) in sparse.chain(stroke).enumerate() {
        assert_decodes(&dec, &optics, Pose::new(4750.0, y, 0.0), n as u64, 0.05);
    }
}
