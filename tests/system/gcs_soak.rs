//! The C-863 driver under random and scripted reply faults never takes a late reply for the
//! answer to a later request: every answer is compared with the reply the simulator produced
//! for the request the driver sent last.
use std::time::Duration;

use csmetro_gcs::{AxisQuery, Command, ControlByte};
use csmetro_gcs::{C863Config, C863};
use csmetro_hal::Axis;
use csmetro_sim::SimStage;
use csmetro_sim::{soak_gcs, BindingCheck, SoakOptions};
use csmetro_sim::{AxisId, StageModel};
use csmetro_sim::{ControllerConfig, Fault, FaultSpec, RandomFaults, SimController};

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn soak_under_random_faults_accepts_no_stale_reply() {
    let mut opts = SoakOptions::new(500, 11);
    opts.reply_timeout_ms = 80;
    opts.faults = RandomFaults {
        seed: 11,
        delay_rate: 0.12,
        delay_ms: [20, 300], // mostly past the 80 ms timeout
        drop_rate: 0.015,
        garbage_rate: 0.015,
        ..RandomFaults::default()
    };
    let r = soak_gcs(&opts).await.unwrap();
    println!("{r:?}");
    assert!(
        r.faults.delay >= 5 && r.faults.drop >= 3 && r.faults.garbage >= 3,
        "faults really struck: {:?}",
        r.faults
    );
    assert!(r.link.resyncs > 0 && r.link.discarded > 0, "{:?}", r.link);
    assert_eq!(r.misaligned, 0, "the check itself is bound");
    assert!(
        r.answers_checked >= 350 && r.unchecked == 0,
        "checked {} unchecked {}",
        r.answers_checked,
        r.unchecked
    );
    assert_eq!(r.stale_accepted, 0, "{r:?}");
    assert_eq!(r.garbled_accepted, 0, "{r:?}");
}

/// The reported configuration, timeouts scaled down (800 ms delays past a 500 ms timeout
/// become 240 past 150): three late replies in a row after command 20.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn three_late_replies_in_a_row_are_never_taken_for_later_answers() {
    let mut stale = 0;
    for trial in 0..8u64 {
        let cfg = ControllerConfig {
            faults: vec![FaultSpec {
                fault: Fault::DelayReply { ms: 240, count: 3 },
                after_commands: 20 + trial,
            }],
            ..ControllerConfig::default()
        };
        let stage = SimStage::new(
            StageModel::default(),
            100.0,
            [cfg.start_mm; 2],
            cfg.velocity_mm_s,
            cfg.acceleration_mm_s2,
        );
        let sim = SimController::start_pty(stage, AxisId::X, cfg, None)
            .await
            .unwrap();
        sim.controller().keep_exchanges(4096);
        let mut d = C863::connect(C863Config {
            reply_timeout_ms: 150,
            ..C863Config::serial(sim.endpoint().to_string())
        })
        .await
        .unwrap();
        d.identify().await.unwrap();
        let q = |query| Command::Query {
            query,
            axes: vec!["1".into()],
        };
        let cmds = [
            q(AxisQuery::Pos),
            Command::Control(ControlByte::Ready),
            q(AxisQuery::Ont),
            Command::Err,
            q(AxisQuery::Tmx),
            Command::Csv,
        ];
        let mut chk = BindingCheck::default();
        for i in 0..36 {
            let cmd = &cmds[i % cmds.len()];
            if let Ok(r) = d.query(cmd).await {
                chk.expect(d.stats().frames_sent, cmd, &r);
            }
        }
        chk.settle(sim.controller(), Duration::from_secs(5)).await;
        assert_eq!(sim.controller().fault_counts().delay, 3, "trial {trial}");
        assert_eq!((chk.misaligned, chk.unchecked()), (0, 0), "trial {trial}");
        assert!(chk.checked >= 30, "trial {trial}: {}", chk.checked);
        stale += chk.stale + chk.garbled;
        sim.shutdown().await;
    }
    assert_eq!(stale, 0, "stale answers over 8 trials");
}
