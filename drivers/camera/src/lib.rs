#![doc = include_str!("../README.md")]
// Lints: the workspace wall (Cargo.toml `[workspace.lints]`), plus docs on everything public.
#![warn(missing_docs, missing_debug_implementations)]

mod config;
mod source;

// The FFI boundary with libaravis: the only modules of this crate allowed `unsafe`.
#[cfg(feature = "aravis")]
#[allow(unsafe_code)]
mod aravis_camera;
#[cfg(feature = "aravis")]
#[allow(unsafe_code)]
mod fake_gv;

pub use config::{CameraConfig, CameraId, CameraLimits, ConfigError, PixelFormat, Roi};
pub use source::{FrameSource, SourceCamera};

#[cfg(feature = "aravis")]
pub use aravis_camera::AravisCamera;
#[cfg(feature = "aravis")]
pub use fake_gv::{FakeGvCamera, FakeGvOptions};
