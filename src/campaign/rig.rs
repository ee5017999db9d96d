//! The devices a campaign runs on, behind the `csmetro-hal` traits: two axes, a camera and a
//! clock. `sim` builds simulated C-863s (served over a pty or TCP and driven by the same GCS
//! driver as real ones) and a simulated camera looking at the simulated stage.
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use csmetro_gcs::{C863Config, C863};
use csmetro_hal::{Axis, AxisError, Camera, CameraError};
use csmetro_ppp::{DecodeConfig, Decoder, Pattern, PatternError};
use csmetro_sim::SimCamera;
use csmetro_sim::SimStage;
use csmetro_sim::StageModel;
use csmetro_sim::{ControllerConfig, Endpoint, RandomFaults, SimController};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

use super::spec::{Campaign, HardwareKind, SimTransport};
use crate::types::AxisId;

/// Why a rig (or one of its devices) could not be built.
#[derive(Debug, thiserror::Error)]
pub enum RigError {
    #[error(transparent)]
    Pattern(#[from] PatternError),
    #[error("the campaign's stage model was not validated")]
    ModelNotValidated,
    #[error("cannot start the simulated C-863 of axis {axis}: {source}")]
    SimStart {
        axis: AxisId,
        source: std::io::Error,
    },
    #[error("cannot connect to the simulated C-863 of axis {axis}: {source}")]
    SimConnect { axis: AxisId, source: AxisError },
    #[error(transparent)]
    Noise(#[from] rand_distr::NormalError),
    /// The simulated camera refused its optics.
    #[error(transparent)]
    SimCamera(CameraError),
    #[error("no [hardware.controllers.{0}]")]
    NoController(AxisId),
    /// A real controller that did not connect (the pre-flight names the axis itself).
    #[error("{0}")]
    Connect(AxisError),
    #[error("axis {axis}: {source}")]
    Axis { axis: AxisId, source: AxisError },
    #[error("a real campaign needs [hardware.camera]")]
    NoCamera,
    #[error("camera: {0}")]
    Camera(CameraError),
    /// A device the pre-flight took out of [`Devices`] (never reported).
    #[error("taken by the pre-flight")]
    Taken,
}

/// Physical time: the wall clock on hardware, the scaled simulator clock in simulation.
#[derive(Debug, Clone, Copy)]
pub enum TimeBase {
    Real,
    Sim { scale: f64 },
}

impl TimeBase {
    /// Wall time that a physical wait of `s` seconds takes.
    pub fn wall(&self, s: f64) -> Duration {
        match self {
            TimeBase::Real => Duration::from_secs_f64(s.max(0.0)),
            TimeBase::Sim { scale } => Duration::from_secs_f64((s / scale).max(0.0)),
        }
    }
    /// Physical seconds elapsed since `t0` (wall time times the scale in simulation).
    pub fn physical_since(&self, t0: Instant) -> f64 {
        let w = t0.elapsed().as_secs_f64();
        match self {
            TimeBase::Real => w,
            TimeBase::Sim { scale } => w * scale,
        }
    }
}

/// A campaign's physical time, s, shared with the simulated camera (f64 bits).
#[derive(Debug, Clone, Default)]
pub struct PhysicalClock(Arc<AtomicU64>);

impl PhysicalClock {
    pub fn get(&self) -> f64 {
        f64::from_bits(self.0.load(Ordering::Relaxed))
    }
    pub fn set(&self, s: f64) {
        self.0.store(s.to_bits(), Ordering::Relaxed)
    }
}

pub struct Rig {
    pub x: Box<dyn Axis>,
    pub y: Box<dyn Axis>,
    /// Taken out while a blocking trigger runs.
    pub camera: Option<Box<dyn Camera>>,
    pub decoder: Arc<Decoder>,
    pub time: TimeBase,
    /// Physical time one frame takes when the camera cannot tell (simulation), s.
    pub frame_time_s: Option<f64>,
    pub clock: PhysicalClock,
    /// The simulator's stage model: ground truth of a simulated campaign.
    pub truth: Option<Arc<StageModel>>,
    /// What the rig is (for the record).
    pub describe: String,
    /// Motion parameters of the simulated axes (physical move time).
    pub motion: Option<SimMotion>,
    /// Simulation: the stage's true position (x, y), µm, at each camera trigger, in order.
    pub triggers: Option<TriggerLog>,
    sims: Vec<SimController>,
}

/// The true positions the simulated camera was triggered at (no measurement noise), µm.
#[derive(Debug, Clone, Default)]
pub struct TriggerLog(Arc<Mutex<Vec<(f64, f64)>>>);

impl TriggerLog {
    fn push(&self, p: (f64, f64)) {
        self.0.lock().unwrap_or_else(|e| e.into_inner()).push(p);
    }
    /// Number of triggers so far.
    pub fn len(&self) -> usize {
        self.0.lock().unwrap_or_else(|e| e.into_inner()).len()
    }
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
    /// Mean true position over the triggers from number `from` on, None if there were none.
    pub fn mean_since(&self, from: usize) -> Option<(f64, f64)> {
        let v = self.0.lock().unwrap_or_else(|e| e.into_inner());
        let s = v.get(from..).filter(|s| !s.is_empty())?;
        let n = s.len() as f64;
        let (x, y) = s.iter().fold((0.0, 0.0), |a, p| (a.0 + p.0, a.1 + p.1));
        Some((x / n, y / n))
    }
}

/// Seed of one axis's random faults: the two controllers must not fail in lockstep.
pub fn axis_fault_seed(seed: u64, axis: AxisId) -> u64 {
    seed.wrapping_mul(0x9E37_79B9_7F4A_7C15)
        .wrapping_add(match axis {
            AxisId::X => 0x51,
            AxisId::Y => 0x52,
        })
}

#[derive(Debug, Clone, Copy)]
pub struct SimMotion {
    pub velocity_mm_s: f64,
    pub acceleration_mm_s2: f64,
    /// On-target settling window time of the controller, s.
    pub settle_s: f64,
}

/// Trapezoidal move time over `d_mm` at velocity `v` (mm/s) and acceleration `a` (mm/s²), s.
pub fn trapezoid_s(d_mm: f64, v: f64, a: f64) -> f64 {
    if d_mm <= 0.0 {
        0.0
    } else if d_mm < v * v / a {
        2.0 * (d_mm / a).sqrt()
    } else {
        d_mm / v + v / a
    }
}

impl Rig {
    /// Physical time of a move of `d_um` that started (wall) at `t0` and is now on target.
    /// Hardware: the wall time. Simulation: the stage's motion and settling time plus the
    /// unscaled wall time of the exchanges (a real line takes about as long), never the
    /// exchange time multiplied by the time scale.
    pub fn motion_s(&self, _axis: AxisId, d_um: f64, t0: Instant) -> f64 {
        match (self.time, self.motion) {
            (TimeBase::Sim { .. }, Some(m)) => {
                trapezoid_s(d_um / 1000.0, m.velocity_mm_s, m.acceleration_mm_s2)
                    + m.settle_s
                    + t0.elapsed().as_secs_f64()
            }
            _ => self.time.physical_since(t0),
        }
    }

    pub fn axis(&mut self, a: AxisId) -> &mut dyn Axis {
        match a {
            AxisId::X => self.x.as_mut(),
            AxisId::Y => self.y.as_mut(),
        }
    }

    /// Stops both axes (best effort, each bounded by the driver's timeouts).
    pub async fn stop_all(&mut self) {
        for a in [AxisId::X, AxisId::Y] {
            if let Err(e) = self.axis(a).stop().await {
                tracing::warn!(axis = %a, error = %e, "stop failed");
            }
        }
    }

    /// Shuts the simulators down (after the axes were stopped).
    pub async fn close(mut self) {
        for s in self.sims.drain(..) {
            s.shutdown().await;
        }
    }
}

/// Builds the rig of a campaign.
pub async fn build(c: &Campaign) -> Result<Rig, RigError> {
    let h = &c.spec().hardware;
    let pattern = Pattern::new(h.pattern.clone())?;
    let decoder = Arc::new(Decoder::new(
        pattern.clone(),
        DecodeConfig::for_optics(&pattern, &h.optics),
    ));
    match h.kind {
        HardwareKind::Sim => build_sim(c, pattern, decoder).await,
        HardwareKind::Real => build_real(c, decoder).await,
    }
}

/// The simulated devices of a `kind = "sim"` campaign, serving and connected, not yet boxed.
struct SimParts {
    x: C863,
    y: C863,
    camera: SimCamera,
    sims: Vec<SimController>,
    model: StageModel,
    clock: PhysicalClock,
    triggers: TriggerLog,
}

/// `faults`: whether the controllers strike `[hardware.sim.faults]` (a soak's random faults are
/// the campaign's to meet, not the pre-flight's).
async fn sim_parts(c: &Campaign, pattern: Pattern, faults: bool) -> Result<SimParts, RigError> {
    let s = &c.spec().hardware.sim;
    // The model validation loaded (and, for a submitted file, confined): never read again.
    let model = match (&s.model, c.model()) {
        (Some(_), Some(m)) => m.model.clone(),
        (Some(_), None) => return Err(RigError::ModelNotValidated),
        (None, _) => StageModel::default(),
    };
    let start_mm = [
        (c.axis(AxisId::X).map_or(0.0, |a| a.grid.start_um)) / 1000.0,
        (c.axis(AxisId::Y).map_or(0.0, |a| a.grid.start_um)) / 1000.0,
    ];
    let stage = SimStage::new(
        model.clone(),
        s.time_scale,
        start_mm,
        s.velocity_mm_s,
        s.acceleration_mm_s2,
    );
    let mut sims = Vec::new();
    let mut axes: Vec<C863> = Vec::new();
    for (a, limits) in [
        (AxisId::X, s.soft_limits_x_um),
        (AxisId::Y, s.soft_limits_y_um),
    ] {
        let cfg = ControllerConfig {
            travel_mm: s.travel_mm,
            velocity_mm_s: s.velocity_mm_s,
            acceleration_mm_s2: s.acceleration_mm_s2,
            start_mm: start_mm[if a == AxisId::X { 0 } else { 1 }],
            reference_switch_mm: (s.travel_mm[0] + s.travel_mm[1]) / 2.0,
            random_faults: s.faults.as_ref().filter(|_| faults).map(|f| RandomFaults {
                seed: axis_fault_seed(f.seed, a),
                ..f.clone()
            }),
            ..ControllerConfig::default()
        };
        let sim = match s.transport {
            SimTransport::Pty => SimController::start_pty(stage.clone(), a, cfg, None).await,
            SimTransport::Tcp => {
                SimController::start_tcp(stage.clone(), a, cfg, "127.0.0.1:0".parse().unwrap())
                    .await
            }
        }
        .map_err(|source| RigError::SimStart { axis: a, source })?;
        let mut dc = match sim.endpoint() {
            Endpoint::Tcp(addr) => C863Config::tcp(addr.to_string()),
            Endpoint::Pty(path) => C863Config::serial(path.display().to_string()),
        };
        dc.soft_limits_um = (limits[0], limits[1]);
        // Simulated time runs fast: poll at the pace of the scaled motion.
        dc.poll_interval_ms = 1;
        let drv = C863::connect(dc)
            .await
            .map_err(|source| RigError::SimConnect { axis: a, source })?;
        axes.push(drv);
        sims.push(sim);
    }
    let clock = PhysicalClock::default();
    let source_stage = stage.clone();
    let source_clock = clock.clone();
    let triggers = TriggerLog::default();
    let source_log = triggers.clone();
    let noise = model.noise_sigma_um();
    let rng = Mutex::new(ChaCha8Rng::seed_from_u64(s.seed));
    let normal = Normal::new(0.0, noise.max(0.0))?;
    let source = move || {
        let (x, y) = source_stage.true_position_at_um(Some(source_clock.get()));
        source_log.push((x, y));
        if noise > 0.0 {
            let mut r = rng.lock().unwrap_or_else(|e| e.into_inner());
            (x + normal.sample(&mut *r), y + normal.sample(&mut *r))
        } else {
            (x, y)
        }
    };
    let optics = s
        .render_optics
        .clone()
        .unwrap_or_else(|| c.spec().hardware.optics.clone());
    let rot_stage = stage.clone();
    let camera = SimCamera::new(pattern, optics, Box::new(source))
        .map_err(RigError::SimCamera)?
        .with_seed(s.seed)
        .with_rotation(Box::new(move || rot_stage.rotation_urad() * 1e-3));
    let y = axes.pop().expect("two axes");
    let x = axes.pop().expect("two axes");
    Ok(SimParts {
        x,
        y,
        camera,
        sims,
        model,
        clock,
        triggers,
    })
}

async fn build_sim(c: &Campaign, pattern: Pattern, decoder: Arc<Decoder>) -> Result<Rig, RigError> {
    let s = &c.spec().hardware.sim;
    let SimParts {
        x,
        y,
        camera,
        sims,
        model,
        clock,
        triggers,
    } = sim_parts(c, pattern, true).await?;
    Ok(Rig {
        describe: format!(
            "simulated: 2 x C-863.11 over {:?}, time scale {}{}, {}",
            s.transport,
            s.time_scale,
            s.faults.as_ref().map_or(String::new(), |f| format!(
                ", random faults (seed {})",
                f.seed
            )),
            camera.describe()
        ),
        x: Box::new(x),
        y: Box::new(y),
        camera: Some(Box::new(camera)),
        decoder,
        time: TimeBase::Sim {
            scale: s.time_scale,
        },
        frame_time_s: Some(s.frame_time_s),
        clock,
        truth: Some(Arc::new(model)),
        motion: Some(SimMotion {
            velocity_mm_s: s.velocity_mm_s,
            acceleration_mm_s2: s.acceleration_mm_s2,
            settle_s: ControllerConfig::default().settle_time_s,
        }),
        triggers: Some(triggers),
        sims,
    })
}

/// A rig's devices opened one by one for the pre-flight check, each with its own outcome.
/// Opening sends nothing to a controller; the simulators of a `kind = "sim"` campaign serve
/// until [`Devices::close`].
pub struct Devices {
    pub x: Result<C863, RigError>,
    pub y: Result<C863, RigError>,
    pub camera: Result<Box<dyn Camera>, RigError>,
    pub decoder: Arc<Decoder>,
    sims: Vec<SimController>,
}

impl Devices {
    /// Shuts the simulators down.
    pub async fn close(self) {
        let Devices { x, y, sims, .. } = self;
        drop((x, y));
        for s in sims {
            s.shutdown().await;
        }
    }
}

/// Opens the devices of a campaign without commanding anything. A real controller's port is
/// opened, and each of its exchanges tried, at most `reconnect_attempts` + 1 times (a
/// pre-flight reports a missing or silent controller quickly).
pub async fn open_devices(c: &Campaign, reconnect_attempts: u32) -> Result<Devices, RigError> {
    let h = &c.spec().hardware;
    let pattern = Pattern::new(h.pattern.clone())?;
    let decoder = Arc::new(Decoder::new(
        pattern.clone(),
        DecodeConfig::for_optics(&pattern, &h.optics),
    ));
    match h.kind {
        HardwareKind::Sim => {
            let p = sim_parts(c, pattern, false).await?;
            Ok(Devices {
                x: Ok(p.x),
                y: Ok(p.y),
                camera: Ok(Box::new(p.camera)),
                decoder,
                sims: p.sims,
            })
        }
        HardwareKind::Real => {
            let connect = |a: AxisId| async move {
                let mut cfg = h
                    .controllers
                    .get(a.as_str())
                    .cloned()
                    .ok_or(RigError::NoController(a))?;
                cfg.reconnect_attempts = cfg.reconnect_attempts.min(reconnect_attempts);
                cfg.retries = cfg.retries.min(reconnect_attempts);
                C863::connect(cfg).await.map_err(RigError::Connect)
            };
            Ok(Devices {
                x: connect(AxisId::X).await,
                y: connect(AxisId::Y).await,
                camera: real_camera(c),
                decoder,
                sims: Vec::new(),
            })
        }
    }
}

async fn build_real(c: &Campaign, decoder: Arc<Decoder>) -> Result<Rig, RigError> {
    let h = &c.spec().hardware;
    let connect = |a: AxisId| async move {
        let cfg = h
            .controllers
            .get(a.as_str())
            .cloned()
            .ok_or(RigError::NoController(a))?;
        C863::connect(cfg)
            .await
            .map_err(|source| RigError::Axis { axis: a, source })
    };
    let x = connect(AxisId::X).await?;
    let y = connect(AxisId::Y).await?;
    let camera = real_camera(c)?;
    Ok(Rig {
        describe: format!("PI C-863 x2, {}", camera.describe()),
        x: Box::new(x),
        y: Box::new(y),
        camera: Some(camera),
        decoder,
        time: TimeBase::Real,
        frame_time_s: None,
        clock: PhysicalClock::default(),
        truth: None,
        motion: None,
        triggers: None,
        sims: Vec::new(),
    })
}

fn real_camera(c: &Campaign) -> Result<Box<dyn Camera>, RigError> {
    let cfg = c.spec().hardware.camera.clone().ok_or(RigError::NoCamera)?;
    csmetro_camera::open_camera(cfg).map_err(RigError::Camera)
}
