//! State machine: the error codes and motion a client depends on.
use super::*;
use csmetro_gcs::ServerCodec;
use tokio_util::codec::Decoder;

/// Time scale 100: a 1 s physical move takes 10 ms.
fn ctl() -> Controller {
    let stage = SimStage::new(crate::StageModel::default(), 100.0, [0.0, 0.0], 1.5, 5.0);
    Controller::new(stage, AxisId::X, ControllerConfig::default())
}

/// Sends one command line (or control byte) and returns the reply text.
fn send(c: &Controller, text: &[u8]) -> String {
    let mut buf = BytesMut::from(text);
    let mut out = String::new();
    while let Some(req) = ServerCodec::default().decode(&mut buf).unwrap() {
        let o = c.handle(&req);
        out.extend(o.bytes.iter().map(|&b| b as char));
    }
    out
}

use bytes::BytesMut;

fn err(c: &Controller) -> i32 {
    send(c, b"ERR?\n").trim().parse().unwrap()
}

fn wait_until(c: &Controller, cmd: &[u8], want: &str) {
    let t0 = std::time::Instant::now();
    while send(c, cmd) != want {
        assert!(
            t0.elapsed() < Duration::from_secs(5),
            "never got {want:?} for {cmd:?}"
        );
        std::thread::sleep(Duration::from_millis(1));
    }
}

fn referenced() -> Controller {
    let c = ctl();
    send(&c, b"SVO 1 1\nFNL 1\n");
    wait_until(&c, b"\x07", "\u{B1}\n");
    assert_eq!(err(&c), 0);
    c
}

#[test]
fn identity_and_travel_model_the_c863_11_with_m111() {
    let c = ctl();
    assert!(send(&c, b"*IDN?\n").split(',').nth(1).unwrap().trim() == "C-863.11");
    assert_eq!(send(&c, b"CSV?\n"), "2.0\n");
    assert_eq!(send(&c, b"SAI? ALL\n"), "1\n");
    assert_eq!(send(&c, b"TMN? 1\n"), "1=0.000000\n");
    assert_eq!(send(&c, b"TMX? 1\n"), "1=15.000000\n");
    assert_eq!(send(&c, b"CST? 1\n"), "1=M-111.1DG\n");
    let help = send(&c, b"HLP?\n");
    assert!(
        help.ends_with("end of help\n") && help.matches(" \n").count() > 10,
        "{help}"
    );
}

#[test]
fn unknown_command_and_bad_arguments_latch_their_codes() {
    let c = ctl();
    for (cmd, code) in [
        (&b"FOO\n"[..], 2),
        (b"MOV 1\n", 1),
        (b"MOV 1 x\n", 25),
        (b"SVO 1 3\n", 17),
        (b"SVO 2 1\n", 15),
        (b"VEL 1 99\n", 8),
        (b"VEL 1 -1\n", 17),
        (b"ACC 1 0\n", 17),
        (b"SPA 1 0x9999 1\n", 54),
        (b"POS?\r\n", 1),
    ] {
        assert_eq!(send(&c, cmd), "", "{cmd:?} must not answer");
        assert_eq!(err(&c), code, "{cmd:?}");
        assert_eq!(err(&c), 0, "ERR? clears the error");
    }
    assert_eq!(
        send(&c, b"POS? 2\n"),
        "",
        "query of an unknown axis is not answered"
    );
    assert_eq!(err(&c), 15);
}

#[test]
fn error_is_the_last_one_until_read() {
    let c = ctl();
    send(&c, b"FOO\nMOV 1 x\n");
    assert_eq!(err(&c), 25);
}

#[test]
fn move_needs_servo_and_reference_and_stays_in_travel() {
    let c = ctl();
    send(&c, b"MOV 1 1\n");
    assert_eq!(err(&c), 5, "servo off");
    send(&c, b"FRF 1\n");
    assert_eq!(err(&c), 5, "reference with servo off");
    send(&c, b"SVO 1 1\nMOV 1 1\n");
    assert_eq!(err(&c), 5, "unreferenced");
    let c = referenced();
    send(&c, b"MOV 1 15.001\n");
    assert_eq!(err(&c), 7);
    assert_eq!(
        send(&c, b"MOV? 1\n"),
        "1=0.000000000\n",
        "refused move changes nothing"
    );
}

#[test]
fn referencing_takes_time_and_reports_busy() {
    let c = ctl(); // starts at 3 mm; FRF goes to 7.5 mm at 1 mm/s: 4.5 s physical = 45 ms real
    send(&c, b"SVO 1 1\nFRF 1\n");
    assert_eq!(send(&c, b"\x07"), "\u{B0}\n");
    assert_eq!(send(&c, b"FRF? 1\n"), "1=0\n");
    wait_until(&c, b"\x07", "\u{B1}\n");
    assert_eq!(send(&c, b"FRF? 1\n"), "1=1\n");
    assert_eq!(send(&c, b"POS? 1\n"), "1=7.500000000\n");
}

#[test]
fn move_is_trapezoidal_then_on_target_after_settling() {
    let c = referenced();
    send(&c, b"MOV 1 7.5\n");
    assert_eq!(err(&c), 0);
    assert_eq!(send(&c, b"\x05"), "1\n");
    assert_eq!(send(&c, b"ONT? 1\n"), "1=0\n");
    let p: f64 = send(&c, b"POS? 1\n").trim()[2..].parse().unwrap();
    assert!((0.0..7.5).contains(&p), "{p}");
    wait_until(&c, b"ONT? 1\n", "1=1\n");
    assert_eq!(send(&c, b"\x05"), "0\n");
    assert_eq!(send(&c, b"POS? 1\n"), "1=7.500000000\n");
    let s = u32::from_str_radix(send(&c, b"\x04").trim().trim_start_matches("0x"), 16).unwrap();
    assert_eq!(
        s & (1 << 15 | 1 << 13 | 1 << 12),
        1 << 15 | 1 << 12,
        "on target, not moving, servo on"
    );
}

#[test]
fn stops_latch_error_10() {
    for stop in [&b"HLT 1\n"[..], b"STP\n", b"\x18"] {
        let c = referenced();
        send(&c, b"MOV 1 14\n");
        assert_eq!(send(&c, stop), "", "stops have no reply");
        if stop.starts_with(b"HLT") {
            wait_until(&c, b"\x05", "0\n"); // HLT decelerates (at most 1.5/5 s = 3 ms real)
        }
        assert_eq!(send(&c, b"\x05"), "0\n", "{stop:?}");
        assert_eq!(err(&c), 10, "{stop:?}");
        assert_ne!(
            send(&c, b"POS? 1\n"),
            "1=14.000000000\n",
            "stopped short of the target"
        );
    }
}

#[test]
fn spa_accepts_decimal_and_hex_ids() {
    let c = ctl();
    assert_eq!(send(&c, b"SPA? 1 0x3C\n"), "1 0x3C=M-111.1DG\n");
    send(&c, b"SPA 1 60 M-111.2DG\n");
    assert_eq!(err(&c), 0);
    assert_eq!(send(&c, b"CST? 1\n"), "1=M-111.2DG\n");
    send(&c, b"SPA 1 0x15 10\n");
    assert_eq!(send(&c, b"TMX? 1\n"), "1=10.000000\n");
    send(&c, b"SPA 1 0x15 5 1 0x36 abc\n");
    assert_eq!(err(&c), 25);
    assert_eq!(
        send(&c, b"TMX? 1\n"),
        "1=10.000000\n",
        "a refused line changes nothing"
    );
}

#[test]
fn addressed_frames_get_addressed_replies_and_others_are_ignored() {
    let c = ctl();
    assert_eq!(send(&c, b"1 0 CSV?\n"), "0 1 2.0\n");
    assert_eq!(send(&c, b"2 0 CSV?\n"), "");
}

#[test]
fn injected_motion_error_stops_the_move_and_switches_servo_off() {
    let c = referenced();
    c.inject(Fault::Error {
        code: 1024,
        during_motion: true,
    });
    send(&c, b"MOV 1 10\n");
    wait_until(&c, b"SVO? 1\n", "1=0\n");
    assert_eq!(err(&c), 1024);
    assert_eq!(send(&c, b"ONT? 1\n"), "1=0\n");
    let p: f64 = send(&c, b"POS? 1\n").trim()[2..].parse().unwrap();
    assert!(p > 0.0 && p < 10.0, "stopped halfway: {p}");
}

#[test]
fn reply_faults_drop_garble_and_delay() {
    let c = ctl();
    c.inject(Fault::DropReply { count: 1 });
    assert_eq!(send(&c, b"CSV?\n"), "");
    assert_eq!(send(&c, b"CSV?\n"), "2.0\n");
    c.inject(Fault::Garbage { count: 1 });
    assert_eq!(send(&c, b"CSV?\n").chars().count(), GARBAGE.len());
    let mut buf = BytesMut::from(&b"CSV?\n"[..]);
    c.inject(Fault::DelayReply { ms: 30, count: 1 });
    let req = ServerCodec::default().decode(&mut buf).unwrap().unwrap();
    assert_eq!(c.handle(&req).delay, Duration::from_millis(30));
}

#[test]
fn faults_parse_from_toml() {
    let cfg: ControllerConfig = toml::from_str(
        r#"
        velocity_mm_s = 1.0
        [[faults]]
        kind = "error"
        code = 1024
        after_commands = 3
        [[faults]]
        kind = "vanish"
        ms = 200
        "#,
    )
    .unwrap();
    assert_eq!(
        cfg.faults[0].fault,
        Fault::Error {
            code: 1024,
            during_motion: false
        }
    );
    assert_eq!(cfg.faults[0].after_commands, 3);
    assert_eq!(cfg.faults[1].fault, Fault::Vanish { ms: 200 });
    assert!(
        toml::from_str::<ControllerConfig>("speed = 3").is_err(),
        "unknown keys are refused"
    );
}

fn with_random(rf: RandomFaults) -> Controller {
    let stage = SimStage::new(crate::StageModel::default(), 100.0, [0.0, 0.0], 1.5, 5.0);
    Controller::new(
        stage,
        AxisId::X,
        ControllerConfig {
            random_faults: Some(rf),
            ..ControllerConfig::default()
        },
    )
}

fn csv_outcomes(c: &Controller, n: usize) -> Vec<Outcome> {
    (0..n)
        .map(|_| {
            let mut buf = BytesMut::from(&b"CSV?\n"[..]);
            let req = ServerCodec::default().decode(&mut buf).unwrap().unwrap();
            c.handle(&req)
        })
        .collect()
}

#[test]
fn random_faults_strike_at_their_rates_and_repeat_with_their_seed() {
    let rf = RandomFaults {
        seed: 7,
        delay_rate: 0.2,
        delay_ms: [5, 9],
        drop_rate: 0.1,
        garbage_rate: 0.1,
        ..RandomFaults::default()
    };
    let c = with_random(rf.clone());
    let out = csv_outcomes(&c, 2000);
    let n = c.fault_counts();
    // Binomial(2000, p) stays within ±5 sd: drop 200 ± 67; garbage 0.9·0.1·2000 = 180 ± 67;
    // delays counted on sent replies only: 0.2·0.9·2000 = 360 ± 86.
    assert!((133..=267).contains(&n.drop), "{n:?}");
    assert!((113..=247).contains(&n.garbage), "{n:?}");
    assert!((274..=446).contains(&n.delay), "{n:?}");
    assert_eq!((n.error, n.vanish), (0, 0));
    let dropped = out.iter().filter(|o| o.bytes.is_empty()).count() as u64;
    let garbled = out.iter().filter(|o| o.bytes == GARBAGE).count() as u64;
    assert_eq!(
        (dropped, garbled),
        (n.drop, n.garbage),
        "counts are what struck"
    );
    assert!(out
        .iter()
        .all(|o| o.delay.is_zero() || (5..=9).contains(&o.delay.as_millis())));
    assert_eq!(
        csv_outcomes(&with_random(rf.clone()), 2000),
        out,
        "same seed, same faults"
    );
    assert_ne!(
        csv_outcomes(&with_random(RandomFaults { seed: 8, ..rf }), 2000),
        out
    );
}

#[test]
fn random_error_latches_its_code_and_switches_faults_off_on_request() {
    let c = with_random(RandomFaults {
        error_rate: 1.0,
        error_code: 1024,
        ..RandomFaults::default()
    });
    send(&c, b"SVO 1 1\n");
    send(&c, b"CSV?\n");
    c.set_random_faults(None);
    assert_eq!(
        send(&c, b"SVO? 1\n"),
        "1=0\n",
        "1024 switches the servo off"
    );
    assert_eq!(err(&c), 1024);
    assert_eq!(c.fault_counts().error, 1);
}

#[test]
fn random_fault_config_reads_from_toml_and_bad_values_are_refused() {
    let cfg: ControllerConfig =
        toml::from_str("[random_faults]\nseed = 3\ndrop_rate = 0.5\ndelay_ms = [1, 2]\n").unwrap();
    let rf = cfg.random_faults.unwrap();
    assert_eq!((rf.seed, rf.drop_rate, rf.delay_ms), (3, 0.5, [1, 2]));
    assert_eq!(rf.validate(), Ok(()));
    for bad in [
        RandomFaults {
            drop_rate: 1.5,
            ..RandomFaults::default()
        },
        RandomFaults {
            delay_rate: f64::NAN,
            ..RandomFaults::default()
        },
        RandomFaults {
            delay_ms: [9, 2],
            ..RandomFaults::default()
        },
        RandomFaults {
            vanish_ms: MAX_RANDOM_FAULT_MS + 1,
            ..RandomFaults::default()
        },
    ] {
        assert!(bad.validate().is_err(), "{bad:?}");
    }
    assert!(toml::from_str::<ControllerConfig>("[random_faults]\nrate = 1\n").is_err());
}

#[test]
fn exchanges_pair_each_request_with_its_reply_and_what_was_sent() {
    let c = ctl();
    send(&c, b"CSV?\n");
    assert!(c.drain_exchanges().is_empty(), "off by default");
    c.keep_exchanges(2);
    c.inject(Fault::Garbage { count: 1 });
    send(&c, b"POS? 1\nSVO 1 1\n\x07");
    let ex = c.drain_exchanges();
    assert_eq!(ex.len(), 2, "capped, oldest dropped");
    assert_eq!((ex[0].seq, ex[0].request.as_str()), (3, "SVO 1 1"));
    assert!(ex[0].reply.is_empty() && ex[0].sent.is_empty());
    assert_eq!((ex[1].seq, ex[1].request.as_str()), (4, "#7"));
    assert_eq!(
        (ex[1].reply.as_slice(), ex[1].sent.as_slice()),
        (&b"\xb1\n"[..], &b"\xb1\n"[..])
    );
    c.inject(Fault::Garbage { count: 1 });
    send(&c, b"CSV?\n");
    let ex = c.drain_exchanges();
    assert_eq!(
        (ex[0].reply.as_slice(), ex[0].sent.as_slice()),
        (&b"2.0\n"[..], GARBAGE)
    );
}

#[test]
fn stale_pty_links_of_dead_processes_are_removed_and_live_ones_kept() {
    let dir = std::env::temp_dir().join(format!("csmetro-links-test-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    // A pid that is surely gone: a child that has exited and been reaped.
    let mut child = std::process::Command::new("true").spawn().unwrap();
    let dead = child.id();
    child.wait().unwrap();
    let me = std::process::id();
    let mk = |name: String| {
        let p = dir.join(name);
        let _ = std::fs::remove_file(&p);
        std::os::unix::fs::symlink("/dev/null", &p).unwrap();
        p
    };
    let stale = mk(format!("csmetro-c863-{dead}-0"));
    let stale_tmp = mk(format!("csmetro-c863-{dead}-3.new"));
    let live = mk(format!("csmetro-c863-{me}-0"));
    let other = mk(format!("csmetro-c863-x{dead}-0"));
    let plain = dir.join(format!("csmetro-c863-{dead}-1"));
    std::fs::write(&plain, b"not a link").unwrap();
    assert_eq!(remove_stale_links(&dir), 2);
    assert!(!stale.exists() && stale.symlink_metadata().is_err());
    assert!(stale_tmp.symlink_metadata().is_err());
    assert!(live.symlink_metadata().is_ok(), "its process is alive");
    assert!(other.symlink_metadata().is_ok(), "not a name we make");
    assert!(plain.exists(), "only symlinks are removed");
    std::fs::remove_dir_all(&dir).unwrap();
}
