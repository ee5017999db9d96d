//! Abort and stop halt motion: the engine, on simulated C-863s over pseudo-terminals, is asked
//! to abort (or stop, as at a service shutdown) mid-sweep; both axes get a stop command, no move
//! follows it, the stage is at rest, and the campaign is short of its plan.
use std::collections::BTreeMap;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use csmetro::campaign::engine::{Control, EndState, Engine, Recorder};
use csmetro::campaign::plan::plan;
use csmetro::campaign::rig;
use csmetro::campaign::spec::Campaign;
use csmetro::types::{RunKey, SampleRecord};
use csmetro_hal::{Axis, AxisError, AxisInfo};
use tokio::sync::watch;

type Log = Arc<Mutex<Vec<String>>>;

/// Passes every call to the real (GCS) axis and logs moves and stops.
struct Logged {
    name: &'static str,
    inner: Option<Box<dyn Axis>>,
    log: Log,
}

impl Logged {
    fn axis(&mut self) -> &mut dyn Axis {
        self.inner.as_deref_mut().expect("wrapped axis")
    }
    fn note(&self, what: String) {
        self.log
            .lock()
            .unwrap()
            .push(format!("{} {what}", self.name));
    }
}

#[async_trait::async_trait]
impl Axis for Logged {
    async fn identify(&mut self) -> Result<AxisInfo, AxisError> {
        self.axis().identify().await
    }
    async fn reference(&mut self, timeout: Duration) -> Result<(), AxisError> {
        self.axis().reference(timeout).await
    }
    async fn move_to(&mut self, target_um: f64) -> Result<(), AxisError> {
        self.note(format!("move {target_um}"));
        self.axis().move_to(target_um).await
    }
    async fn wait_on_target(&mut self, timeout: Duration) -> Result<(), AxisError> {
        self.axis().wait_on_target(timeout).await
    }
    async fn position_um(&mut self) -> Result<f64, AxisError> {
        self.axis().position_um().await
    }
    async fn stop(&mut self) -> Result<(), AxisError> {
        self.note("stop".into());
        self.axis().stop().await
    }
    fn soft_limits_um(&self) -> (f64, f64) {
        self.inner.as_ref().expect("wrapped axis").soft_limits_um()
    }
}

/// Counts samples and sends `halt` after `after` of them, as an operator would.
struct Halting {
    n: usize,
    after: usize,
    halt: Control,
    control: watch::Sender<Control>,
    log: Log,
}

impl Recorder for Halting {
    fn sample(&mut self, _: &SampleRecord) -> Result<bool, csmetro::store::StoreError> {
        self.n += 1;
        if self.n == self.after {
            self.log
                .lock()
                .unwrap()
                .push(format!("{:?} requested", self.halt));
            self.control.send_replace(self.halt);
        }
        Ok(true)
    }
    fn event(&mut self, _: &str, _: serde_json::Value) {}
    fn run_done(&mut self, _: RunKey) {}
    fn cv_error_um(&mut self, _: RunKey) -> Option<f64> {
        None
    }
}

const CAMPAIGN: &str = r#"
[campaign]
name = "halt"
[hardware]
kind = "sim"
optics = { width = 640, height = 640 }
[hardware.sim]
time_scale = 1000
transport = "pty"
[axes.x]
range_um = [2000.0, 4000.0]
step_um = 5.0
other_at_um = 2100.0
[sampling]
m = 100
full_scan = true
[acquisition]
settle_s = 1.0
dwell_s = 0.2
"#;

async fn halt_mid_sweep(halt: Control) -> (EndState, Vec<String>, usize, [f64; 2], [f64; 2]) {
    let c = Campaign::parse(CAMPAIGN, "halt.toml", std::path::Path::new(".")).unwrap();
    let p = plan(&c);
    let mut rig = rig::build(&c).await.unwrap();
    let log: Log = Arc::default();
    for (name, slot) in [("x", &mut rig.x), ("y", &mut rig.y)] {
        let mut wrapped: Box<dyn Axis> = Box::new(Logged {
            name,
            inner: None,
            log: log.clone(),
        });
        std::mem::swap(slot, &mut wrapped);
        *slot = Box::new(Logged {
            name,
            inner: Some(wrapped),
            log: log.clone(),
        });
    }
    let (tx, rx) = watch::channel(Control::Run);
    let mut rec = Halting {
        n: 0,
        after: 25,
        halt,
        control: tx,
        log: log.clone(),
    };
    let outcome = {
        let mut e = Engine::new(&c, &mut rig, &mut rec, rx, BTreeMap::new());
        e.run(&p).await.unwrap()
    };
    // At rest: the controllers report the same position 50 ms (50 s simulated) apart.
    let a = [
        rig.x.position_um().await.unwrap(),
        rig.y.position_um().await.unwrap(),
    ];
    tokio::time::sleep(Duration::from_millis(50)).await;
    let b = [
        rig.x.position_um().await.unwrap(),
        rig.y.position_um().await.unwrap(),
    ];
    rig.close().await;
    let entries = log.lock().unwrap().clone();
    (outcome.end, entries, rec.n.min(p.total()), a, b)
}

fn check(end: EndState, want: EndState, log: &[String], a: [f64; 2], b: [f64; 2]) {
    assert_eq!(end, want);
    let req = log
        .iter()
        .position(|l| l.ends_with("requested"))
        .expect("halt requested");
    let after = &log[req + 1..];
    for ax in ["x", "y"] {
        let stop = after
            .iter()
            .position(|l| *l == format!("{ax} stop"))
            .unwrap_or_else(|| panic!("{ax} stopped after the request: {after:?}"));
        assert!(
            !after[stop..]
                .iter()
                .any(|l| l.starts_with(&format!("{ax} move"))),
            "{ax} moved after its stop: {after:?}"
        );
    }
    // Points already in flight may land, but no new target is started: at most the pipeline.
    let moves_after = after.iter().filter(|l| l.contains("move")).count();
    assert!(moves_after <= 2, "{moves_after} moves after the request");
    assert_eq!(a, b, "stage at rest");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn abort_stops_both_axes_and_nothing_moves_after() {
    let (end, log, n, a, b) = halt_mid_sweep(Control::Abort).await;
    check(end, EndState::Aborted, &log, a, b);
    assert!(n < 300, "stopped short of the plan: {n}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn stop_for_shutdown_also_stops_motion_but_ends_resumable() {
    let (end, log, _, a, b) = halt_mid_sweep(Control::Stop).await;
    check(end, EndState::Stopped, &log, a, b);
}
