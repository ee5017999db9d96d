#![doc = include_str!("../README.md")]
pub mod config;
pub mod source;

#[cfg(feature = "aravis")]
pub mod aravis_camera;
#[cfg(feature = "aravis")]
pub mod fake_gv;

pub use config::{CameraConfig, CameraId, CameraLimits, ConfigError, PixelFormat, Roi};
pub use source::{FrameSource, SourceCamera};

#[cfg(feature = "aravis")]
pub use aravis_camera::AravisCamera;
#[cfg(feature = "aravis")]
pub use fake_gv::{FakeGvCamera, FakeGvOptions};
