#![doc = include_str!("../README.md")]
// Lints: the workspace wall (Cargo.toml `[workspace.lints]`), plus docs on everything public.
#![warn(missing_docs)]

use std::time::Duration;

use serde::{Deserialize, Serialize};

/// A stage axis.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum AxisId {
    /// The X axis.
    X,
    /// The Y axis.
    Y,
}

impl AxisId {
    /// Lowercase name, `x` or `y` (as in JSON and the CLI).
    pub fn as_str(self) -> &'static str {
        match self {
            AxisId::X => "x",
            AxisId::Y => "y",
        }
    }
    /// The other axis of the XY pair.
    pub fn other(self) -> AxisId {
        match self {
            AxisId::X => AxisId::Y,
            AxisId::Y => AxisId::X,
        }
    }
    /// `x` or `y`, any case, surrounding blanks ignored.
    pub fn parse(s: &str) -> Option<AxisId> {
        match s.trim().to_ascii_lowercase().as_str() {
            "x" => Some(AxisId::X),
            "y" => Some(AxisId::Y),
            _ => None,
        }
    }
}

impl std::fmt::Display for AxisId {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

/// Direction of the last approach to a target: +1 forward (increasing position), -1 backward.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Direction {
    /// Approach from below: increasing position.
    Forward,
    /// Approach from above: decreasing position.
    Backward,
}

impl Direction {
    /// +1.0 forward, -1.0 backward (the `d` of the stage model).
    pub fn sign(self) -> f64 {
        match self {
            Direction::Forward => 1.0,
            Direction::Backward => -1.0,
        }
    }
    /// Lowercase name, `forward` or `backward` (as in JSON).
    pub fn as_str(self) -> &'static str {
        match self {
            Direction::Forward => "forward",
            Direction::Backward => "backward",
        }
    }
}

/// What an axis controller says about itself after connecting.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct AxisInfo {
    /// Identification line (`*IDN?` for a C-863).
    pub idn: String,
    /// Stage name (`CST?`), e.g. `M-111.1DG`.
    pub stage: String,
    /// Hardware travel range reported by the controller, µm.
    pub travel_um: (f64, f64),
}

/// Errors an axis driver reports. Every variant says what to do next in its message.
#[derive(Debug, thiserror::Error)]
pub enum AxisError {
    /// Refused before anything was sent: the target lies outside the configured soft limits.
    #[error("target {target_um} µm is outside the soft limits [{lo_um}, {hi_um}] µm; not moved")]
    OutsideSoftLimits {
        /// Requested target, µm.
        target_um: f64,
        /// Lower soft limit, µm.
        lo_um: f64,
        /// Upper soft limit, µm.
        hi_um: f64,
    },
    /// The controller reported an error code (GCS `ERR?`).
    #[error("controller error {code}: {message}")]
    Controller {
        /// GCS error code.
        code: i32,
        /// The code's text from the GCS error table.
        message: String,
    },
    /// No (complete) reply in time.
    #[error("timeout after {:.3} s waiting for {what}", after.as_secs_f64())]
    Timeout {
        /// What was awaited (the request or condition).
        what: String,
        /// How long was waited.
        after: Duration,
    },
    /// A reply that does not parse as the protocol says.
    #[error("protocol error: {0}")]
    Protocol(String),
    /// The port or connection failed (and bounded reconnects did not help).
    #[error("I/O error: {0}")]
    Io(String),
    /// The axis must be referenced (and servo on) before absolute moves.
    #[error("axis not referenced; run the reference move first")]
    NotReferenced,
}

/// One motorized linear axis, positions in µm.
///
/// Implementations check soft limits *before* sending a move and never wait without a timeout.
#[async_trait::async_trait]
pub trait Axis: Send {
    /// Connect-time identification.
    async fn identify(&mut self) -> Result<AxisInfo, AxisError>;
    /// Servo on and reference move (as configured: FRF, FNL or FPL for a C-863); returns when referenced.
    async fn reference(&mut self, timeout: Duration) -> Result<(), AxisError>;
    /// Start an absolute move to `target_um`. Refused without motion outside the soft limits.
    async fn move_to(&mut self, target_um: f64) -> Result<(), AxisError>;
    /// Wait until the controller reports on-target, at most `timeout`.
    async fn wait_on_target(&mut self, timeout: Duration) -> Result<(), AxisError>;
    /// Position as the controller believes it (its encoder), µm.
    async fn position_um(&mut self) -> Result<f64, AxisError>;
    /// Stop motion now (best effort; safe to call at any time).
    async fn stop(&mut self) -> Result<(), AxisError>;
    /// Configured soft limits, µm (lo, hi).
    fn soft_limits_um(&self) -> (f64, f64);
}

/// Pixel data of one camera frame, row-major, `width * height` values.
#[derive(Debug, Clone, PartialEq)]
pub enum Pixels {
    /// 8-bit pixels.
    Mono8(Vec<u8>),
    /// Mono10/12/16 delivered in 16-bit words; `bit_depth` says how many bits are significant.
    Mono16(Vec<u16>),
}

/// One frame as delivered by a camera.
#[derive(Debug, Clone, PartialEq)]
pub struct Frame {
    /// Width, pixels.
    pub width: usize,
    /// Height, pixels.
    pub height: usize,
    /// Significant bits per pixel (8 to 16).
    pub bit_depth: u8,
    /// The pixel values, row-major.
    pub pixels: Pixels,
    /// Device or host timestamp, seconds (monotonic within one camera session).
    pub timestamp_s: f64,
}

impl Frame {
    /// Pixel values as f32 (0..2^bit_depth - 1), the decoder's working type.
    pub fn to_f32(&self) -> Vec<f32> {
        match &self.pixels {
            Pixels::Mono8(p) => p.iter().map(|&v| v as f32).collect(),
            Pixels::Mono16(p) => p.iter().map(|&v| v as f32).collect(),
        }
    }
}

/// Camera errors. Frames with missing packets or timeouts are errors, never silent.
#[derive(Debug, thiserror::Error)]
pub enum CameraError {
    /// No frame arrived within the given time.
    #[error("no frame within {:.3} s", .0.as_secs_f64())]
    Timeout(Duration),
    /// The frame arrived with missing packets or lines.
    #[error("incomplete frame: {0}")]
    Incomplete(String),
    /// The camera is absent or its connection was lost.
    #[error("camera not found or disconnected: {0}")]
    Disconnected(String),
    /// The camera refused a setting (exposure, ROI, pixel format).
    #[error("camera setting refused: {0}")]
    Setting(String),
    /// Any other camera failure.
    #[error("camera error: {0}")]
    Other(String),
    /// This build lacks the camera's backend (a cargo feature): the configuration's problem,
    /// not the camera's.
    #[error("camera error: this csmetro was built without the `{0}` camera backend: rebuild with `--features {0}`")]
    NotCompiled(&'static str),
}

/// The rest of a triggered exposure: run it (on any thread) to get the frame.
pub type PendingFrame = Box<dyn FnOnce() -> Result<Frame, CameraError> + Send>;

/// A triggered area camera (software trigger: one `grab` = one new exposure).
pub trait Camera: Send {
    /// Trigger one exposure and return its frame, waiting at most `timeout`.
    fn grab(&mut self, timeout: Duration) -> Result<Frame, CameraError>;
    /// Trigger one exposure; returns once the exposure is taken (the stage may move on) with
    /// the work still needed to deliver the frame. The default grabs the whole frame at once;
    /// the simulated camera defers its rendering so that callers can overlap it with motion.
    fn trigger(&mut self, timeout: Duration) -> Result<PendingFrame, CameraError> {
        let frame = self.grab(timeout)?;
        Ok(Box::new(move || Ok(frame)))
    }
    /// Human-readable identity (vendor, model, serial).
    fn describe(&self) -> String;
}
