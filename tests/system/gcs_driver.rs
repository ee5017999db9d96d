//! The Rust C-863 driver against the simulated C-863, over a pty (opened like a serial device)
//! and over TCP: the normal sequence, soft limits, and every injected fault.
use std::time::{Duration, Instant};

use csmetro_gcs::{C863Config, RefMode, C863};
use csmetro_hal::{Axis, AxisError};
use csmetro_sim::SimStage;
use csmetro_sim::{AxisId, Effect, EffectKind, StageModel};
use csmetro_sim::{ControllerConfig, Fault, SimController};

#[derive(Debug, Clone, Copy)]
enum Link {
    Pty,
    Tcp,
}

const BOTH: [Link; 2] = [Link::Pty, Link::Tcp];

/// Time scale 50: the 3 mm FNL reference takes 60 ms, a 1 mm move about 15 ms.
async fn start_with(link: Link, model: StageModel) -> (SimController, C863Config) {
    let cfg = ControllerConfig::default();
    let stage = SimStage::new(
        model,
        50.0,
        [cfg.start_mm; 2],
        cfg.velocity_mm_s,
        cfg.acceleration_mm_s2,
    );
    let sim = match link {
        Link::Pty => SimController::start_pty(stage, AxisId::X, cfg, None).await,
        Link::Tcp => {
            SimController::start_tcp(stage, AxisId::X, cfg, "127.0.0.1:0".parse().unwrap()).await
        }
    }
    .unwrap();
    let base = match link {
        Link::Pty => C863Config::serial(sim.endpoint().to_string()),
        Link::Tcp => C863Config::tcp(sim.endpoint().to_string()),
    };
    let cfg = C863Config {
        reference: RefMode::Fnl,
        soft_limits_um: (500.0, 14_500.0),
        reply_timeout_ms: 150,
        retries: 2,
        reconnect_attempts: 20,
        reconnect_delay_ms: 50,
        poll_interval_ms: 2,
        ..base
    };
    (sim, cfg)
}

async fn start(link: Link) -> (SimController, C863Config) {
    start_with(link, StageModel::default()).await
}

async fn referenced(link: Link) -> (SimController, C863) {
    let (sim, cfg) = start(link).await;
    let mut d = C863::connect(cfg).await.unwrap();
    d.reference(Duration::from_secs(10)).await.unwrap();
    (sim, d)
}

#[tokio::test]
async fn identify_reference_move_and_read_position() {
    for link in BOTH {
        let (sim, cfg) = start(link).await;
        let mut d = C863::connect(cfg).await.unwrap();
        let info = d.identify().await.unwrap();
        assert_eq!(
            info.idn.split(',').nth(1).map(str::trim),
            Some("C-863.11"),
            "{link:?}"
        );
        assert_eq!(info.stage, "M-111.1DG");
        assert_eq!(info.travel_um, (0.0, 15_000.0));
        d.reference(Duration::from_secs(10)).await.unwrap();
        assert!(
            d.position_um().await.unwrap().abs() < 1e-6,
            "FNL ends at 0 mm"
        );
        d.move_to(5_000.0).await.unwrap();
        d.wait_on_target(Duration::from_secs(10)).await.unwrap();
        assert!(
            (d.position_um().await.unwrap() - 5_000.0).abs() < 1e-6,
            "{link:?}"
        );
        d.move_to(1234.567).await.unwrap();
        d.wait_on_target(Duration::from_secs(10)).await.unwrap();
        assert!(
            (d.position_um().await.unwrap() - 1234.567).abs() < 1e-6,
            "sub-µm targets survive mm on the wire"
        );
        let log = sim.controller().command_log();
        let mov = log
            .iter()
            .position(|c| c == "MOV 1 5")
            .expect("MOV in mm on the wire");
        assert_eq!(log[mov + 1], "ERR?", "every setter is followed by ERR?");
        sim.shutdown().await;
    }
}

#[tokio::test]
async fn each_reference_mode_ends_at_its_switch() {
    for (mode, at_um) in [
        (RefMode::Frf, 7_500.0),
        (RefMode::Fnl, 0.0),
        (RefMode::Fpl, 15_000.0),
    ] {
        let (sim, cfg) = start(Link::Pty).await;
        let mut d = C863::connect(C863Config {
            reference: mode,
            ..cfg
        })
        .await
        .unwrap();
        assert!(!d.is_referenced().await.unwrap());
        d.reference(Duration::from_secs(10)).await.unwrap();
        assert!(d.is_referenced().await.unwrap() && d.is_ready().await.unwrap());
        assert!(
            (d.position_um().await.unwrap() - at_um).abs() < 1e-6,
            "{mode:?}"
        );
        let log = sim.controller().command_log();
        assert!(
            log.iter().any(|c| c == &format!("{} 1", mode.mnemonic())),
            "{log:?}"
        );
        assert!(log.iter().any(|c| c == "#7"), "waited on #7");
    }
}

#[tokio::test]
async fn reference_timeout_is_bounded_and_stops_the_stage() {
    let (sim, cfg) = start(Link::Tcp).await;
    let mut d = C863::connect(cfg).await.unwrap(); // FNL from 3 mm: 60 ms real
                                                   // Bounded: a typed timeout (how long the host took is not the driver's behaviour).
    assert!(matches!(
        d.reference(Duration::from_millis(10)).await,
        Err(AxisError::Timeout { .. })
    ));
    assert!(!d.is_moving().await.unwrap() && !d.is_referenced().await.unwrap());
    drop(sim);
}

#[tokio::test]
async fn controller_reports_encoder_while_true_position_carries_the_model_error() {
    let model = StageModel::default().with(Effect::new(
        AxisId::X,
        EffectKind::Backlash { reversal_um: 2.0 },
    ));
    let (sim, cfg) = start_with(Link::Tcp, model).await;
    let mut d = C863::connect(cfg).await.unwrap();
    d.reference(Duration::from_secs(10)).await.unwrap();
    d.move_to(4_000.0).await.unwrap();
    d.wait_on_target(Duration::from_secs(10)).await.unwrap();
    assert!((d.position_um().await.unwrap() - 4_000.0).abs() < 1e-6);
    let (x, _) = sim.stage().true_position_um();
    assert!(
        (x - 4_001.0).abs() < 1e-9,
        "forward approach: +b/2, got {x}"
    );
    d.move_to(3_000.0).await.unwrap();
    d.wait_on_target(Duration::from_secs(10)).await.unwrap();
    let (x, _) = sim.stage().true_position_um();
    assert!(
        (x - 2_999.0).abs() < 1e-9,
        "backward approach: -b/2, got {x}"
    );
}

#[tokio::test]
async fn target_outside_soft_limits_is_refused_without_sending_anything() {
    for link in BOTH {
        let (sim, mut d) = referenced(link).await;
        let before = sim.command_count();
        for t in [14_500.1, 100.0, f64::NAN, f64::INFINITY] {
            match d.move_to(t).await {
                Err(AxisError::OutsideSoftLimits { lo_um, hi_um, .. }) => {
                    assert_eq!((lo_um, hi_um), (500.0, 14_500.0))
                }
                other => panic!("{t}: {other:?}"),
            }
        }
        assert_eq!(
            sim.command_count(),
            before,
            "{link:?}: nothing reached the controller"
        );
        assert_eq!(d.soft_limits_um(), (500.0, 14_500.0));
    }
}

#[tokio::test]
async fn controller_refusals_are_typed_errors() {
    let (sim, mut cfg) = start(Link::Tcp).await;
    cfg.soft_limits_um = (-1_000.0, 20_000.0); // wider than the travel: the controller refuses
    let mut d = C863::connect(cfg).await.unwrap();
    assert!(
        matches!(d.move_to(1_000.0).await, Err(AxisError::NotReferenced)),
        "servo off, unreferenced"
    );
    d.reference(Duration::from_secs(10)).await.unwrap();
    match d.move_to(16_000.0).await {
        Err(AxisError::Controller { code: 7, message }) => {
            assert!(message.contains("out of limits"))
        }
        other => panic!("{other:?}"),
    }
    assert!(
        d.position_um().await.unwrap().abs() < 1e-6,
        "the refused move did not move"
    );
    drop(sim);
}

#[tokio::test]
async fn stop_halt_and_stp_stop_motion_and_clear_error_10() {
    let (sim, mut d) = referenced(Link::Pty).await;
    for which in 0..3 {
        d.move_to(14_000.0).await.unwrap();
        assert!(d.is_moving().await.unwrap(), "#5 reports motion");
        match which {
            0 => d.stop().await.unwrap(),
            1 => {
                // HLT decelerates: motion ends within v/dec = 0.3 s physical (6 ms real).
                d.halt().await.unwrap();
                d.wait_motion_done(Duration::from_secs(1)).await.unwrap();
            }
            _ => d.stop_all().await.unwrap(),
        }
        assert!(!d.is_moving().await.unwrap());
        assert_eq!(
            d.error_code().await.unwrap(),
            0,
            "error 10 was read and cleared"
        );
        d.move_to(1_000.0).await.unwrap();
        d.wait_on_target(Duration::from_secs(10)).await.unwrap();
    }
    let log = sim.controller().command_log();
    assert!(
        log.iter().any(|c| c == "#24")
            && log.iter().any(|c| c == "HLT 1")
            && log.iter().any(|c| c == "STP")
    );
}

#[tokio::test]
async fn wait_on_target_is_bounded_and_stops_the_stage_on_timeout() {
    let (sim, mut d) = referenced(Link::Tcp).await;
    d.move_to(14_000.0).await.unwrap(); // ~9.5 s physical, 190 ms real
    match d.wait_on_target(Duration::from_millis(30)).await {
        Err(AxisError::Timeout { .. }) => {}
        other => panic!("{other:?}"),
    }
    assert!(!d.is_moving().await.unwrap(), "stopped after the timeout");
    assert!(sim.controller().command_log().iter().any(|c| c == "#24"));
    d.move_to(1_000.0).await.unwrap();
    d.wait_motion_done(Duration::from_secs(10)).await.unwrap();
    assert!(
        (d.position_um().await.unwrap() - 1_000.0).abs() < 1e-6,
        "#5 reports the end of motion"
    );
}

#[tokio::test]
async fn addressed_frames_reach_only_the_addressed_controller() {
    let (_sim, cfg) = start(Link::Pty).await;
    let mut d = C863::connect(C863Config {
        address: Some(1),
        ..cfg.clone()
    })
    .await
    .unwrap();
    assert_eq!(d.identify().await.unwrap().stage, "M-111.1DG");
    drop(d);
    let mut d = C863::connect(C863Config {
        address: Some(2),
        retries: 0,
        ..cfg
    })
    .await
    .unwrap();
    assert!(
        matches!(d.identify().await, Err(AxisError::Timeout { .. })),
        "controller 1 stays silent"
    );
}

#[tokio::test]
async fn dropping_a_moving_driver_stops_the_stage() {
    for link in BOTH {
        let (sim, mut d) = referenced(link).await;
        d.move_to(14_000.0).await.unwrap();
        drop(d);
        let t = Instant::now();
        // A hang guard, not a timing: the stop is sent by the drop, at once.
        while !sim.controller().command_log().iter().any(|c| c == "#24") {
            assert!(
                t.elapsed() < Duration::from_secs(60),
                "{link:?}: no #24 after drop"
            );
            tokio::time::sleep(Duration::from_millis(2)).await;
        }
        let (x, _) = sim.stage().encoder_um();
        tokio::time::sleep(Duration::from_millis(20)).await;
        assert_eq!(
            sim.stage().encoder_um().0,
            x,
            "{link:?}: the stage no longer moves"
        );
    }
}

#[tokio::test]
async fn dropped_reply_is_retried_or_times_out_in_bounded_time() {
    for link in BOTH {
        let (sim, mut d) = referenced(link).await;
        sim.inject(Fault::DropReply { count: 1 });
        assert!(
            d.position_um().await.unwrap().abs() < 1e-6,
            "{link:?}: retried"
        );
        // More drops than retries: a typed timeout, bounded by (1 + retries) reply timeouts.
        sim.inject(Fault::DropReply { count: 10 });
        // Bounded by (1 + retries) reply timeouts: the timeout each attempt waited is typed.
        match d.position_um().await {
            Err(AxisError::Timeout { after, .. }) => assert_eq!(after, Duration::from_millis(150)),
            other => panic!("{link:?}: {other:?}"),
        }
        // Resync after a failure never mistakes a stale reply for the next one.
        sim.inject(Fault::DropReply { count: 0 });
        let mut ok = false;
        for _ in 0..10 {
            if d.position_um().await.is_ok() {
                ok = true;
                break;
            }
        }
        assert!(ok, "{link:?}: recovers once replies flow again");
        d.move_to(2_000.0).await.unwrap();
        d.wait_on_target(Duration::from_secs(10)).await.unwrap();
        assert!((d.position_um().await.unwrap() - 2_000.0).abs() < 1e-6);
    }
}

#[tokio::test]
async fn delayed_reply_is_not_taken_for_the_next_one() {
    for link in BOTH {
        let (sim, mut d) = referenced(link).await;
        d.move_to(3_000.0).await.unwrap();
        d.wait_on_target(Duration::from_secs(10)).await.unwrap();
        // The ONT? reply comes 400 ms late (after the 150 ms timeout): the driver resyncs,
        // retries, and the late `1=1` is discarded rather than read as the POS? answer.
        sim.inject(Fault::DelayReply { ms: 400, count: 1 });
        assert!(d.on_target().await.unwrap(), "{link:?}");
        assert!(
            (d.position_um().await.unwrap() - 3_000.0).abs() < 1e-6,
            "{link:?}"
        );
        assert_eq!(d.error_code().await.unwrap(), 0);
        assert!(
            (d.position_um().await.unwrap() - 3_000.0).abs() < 1e-6,
            "{link:?}: still in step"
        );
    }
}

#[tokio::test]
async fn garbage_reply_is_a_protocol_error_then_recovered() {
    for link in BOTH {
        let (sim, mut cfg) = start(link).await;
        cfg.retries = 0;
        let mut d = C863::connect(cfg).await.unwrap();
        sim.inject(Fault::Garbage { count: 1 });
        match d.identify().await {
            Err(AxisError::Protocol(m)) => assert!(m.contains("CSV?"), "{m}"),
            other => panic!("{link:?}: {other:?}"),
        }
        assert_eq!(d.identify().await.unwrap().stage, "M-111.1DG");
        // With retries, garbage in the middle of a sequence is absorbed.
        let (sim, cfg) = start(link).await;
        let mut d = C863::connect(cfg).await.unwrap();
        sim.inject(Fault::Garbage { count: 2 });
        d.reference(Duration::from_secs(10)).await.unwrap();
        assert!(d.position_um().await.unwrap().abs() < 1e-6);
    }
}

#[tokio::test]
async fn motion_error_1024_is_reported_while_waiting() {
    for link in BOTH {
        let (sim, mut d) = referenced(link).await;
        sim.inject(Fault::Error {
            code: 1024,
            during_motion: true,
        });
        d.move_to(10_000.0).await.unwrap();
        match d.wait_on_target(Duration::from_secs(10)).await {
            Err(AxisError::Controller {
                code: 1024,
                message,
            }) => {
                assert!(message.starts_with("motion error"), "{message}")
            }
            other => panic!("{link:?}: {other:?}"),
        }
        let p = d.position_um().await.unwrap();
        assert!(p > 0.0 && p < 10_000.0, "stopped on the way: {p}");
        // Recovery is the user's call: servo on again and move.
        d.set_servo(true).await.unwrap();
        d.move_to(1_000.0).await.unwrap();
        d.wait_on_target(Duration::from_secs(10)).await.unwrap();
    }
}

#[tokio::test]
async fn injected_error_code_fails_the_next_setter() {
    let (sim, mut d) = referenced(Link::Tcp).await;
    sim.inject(Fault::Error {
        code: 17,
        during_motion: false,
    });
    match d.set_servo(true).await {
        Err(AxisError::Controller { code: 17, message }) => {
            assert_eq!(message, "parameter out of range")
        }
        other => panic!("{other:?}"),
    }
    // A latched 1024 switches the servo off: the next move is refused (5 is the last error).
    sim.inject(Fault::Error {
        code: 1024,
        during_motion: false,
    });
    assert!(matches!(
        d.move_to(2_000.0).await,
        Err(AxisError::NotReferenced)
    ));
    d.set_servo(true).await.unwrap();
    d.move_to(2_000.0).await.unwrap();
    d.wait_on_target(Duration::from_secs(10)).await.unwrap();
}

#[tokio::test]
async fn port_that_vanishes_and_comes_back_is_reopened() {
    for link in BOTH {
        let (sim, mut d) = referenced(link).await;
        d.move_to(2_000.0).await.unwrap();
        d.wait_on_target(Duration::from_secs(10)).await.unwrap();
        sim.inject(Fault::Vanish { ms: 300 });
        // The command that triggers the vanish gets no reply; the driver reopens the port
        // (bounded attempts) once it is back and carries on.
        assert!(
            (d.position_um().await.unwrap() - 2_000.0).abs() < 1e-6,
            "{link:?}"
        );
        d.move_to(3_000.0).await.unwrap();
        d.wait_on_target(Duration::from_secs(10)).await.unwrap();
        assert!((d.position_um().await.unwrap() - 3_000.0).abs() < 1e-6);
    }
}

#[tokio::test]
async fn port_that_stays_away_gives_io_error_after_bounded_attempts() {
    for link in BOTH {
        let (sim, mut cfg) = start(link).await;
        cfg.reconnect_attempts = 3;
        cfg.retries = 1;
        let mut d = C863::connect(cfg.clone()).await.unwrap();
        sim.inject(Fault::Vanish { ms: 60_000 });
        // Bounded by the attempts, which the error counts.
        match d.identify().await {
            Err(AxisError::Io(m)) => assert!(m.contains("gave up after 4 attempts"), "{m}"),
            other => panic!("{link:?}: {other:?}"),
        }
        match C863::connect(cfg).await {
            Err(AxisError::Io(_)) => {}
            other => panic!(
                "{link:?}: connect to a vanished port: {:?}",
                other.map(|_| ())
            ),
        }
    }
}

#[tokio::test]
async fn a_request_dropped_before_its_reply_does_not_answer_the_next_one() {
    // An abort drops the driver's future mid-exchange: the POS? reply still comes, later.
    // Taken as the answer to the next query of the same shape, it would be a wrong value;
    // the next request resyncs first instead.
    use csmetro_gcs::{AxisQuery, Command};
    for link in BOTH {
        let (sim, mut d) = referenced(link).await;
        d.move_to(3_000.0).await.unwrap();
        d.wait_on_target(Duration::from_secs(10)).await.unwrap();
        let tmx = Command::Query {
            query: AxisQuery::Tmx,
            axes: vec!["1".into()],
        };
        let want = d.query(&tmx).await.unwrap().axis_f64("1").unwrap();
        assert_ne!(want, 3.0);
        sim.inject(Fault::DelayReply { ms: 100, count: 1 });
        let cut = tokio::time::timeout(Duration::from_millis(30), d.position_um()).await;
        assert!(
            cut.is_err(),
            "{link:?}: POS? should still wait for its reply"
        );
        let r = d.query(&tmx).await.unwrap();
        assert_eq!(r.axis_f64("1").unwrap(), want, "{link:?}: {r:?}");
        // A stop right after a cut exchange goes out and stops.
        d.stop().await.unwrap();
        assert!(!d.is_moving().await.unwrap());
    }
}
