#![doc = include_str!("../README.md")]
// Lints: the workspace wall (Cargo.toml `[workspace.lints]`), plus docs on everything public.
#![warn(missing_docs, missing_debug_implementations)]

mod backend;
mod config;
// The FireWire backend's decisions, tested without libdc1394.
#[cfg(any(feature = "firewire", test))]
mod iidc;
mod source;

// The FFI boundary with libaravis: the only modules of this crate allowed `unsafe`.
#[cfg(feature = "aravis")]
#[allow(unsafe_code)]
mod aravis_camera;
#[cfg(feature = "aravis")]
#[allow(unsafe_code)]
mod fake_gv;
// The FFI boundary with libdc1394 (IEEE 1394 IIDC).
#[cfg(feature = "firewire")]
#[allow(unsafe_code)]
mod firewire;

pub use backend::{list_cameras, not_compiled, open_camera, CameraInfo};
pub use config::{
    parse_guid, CameraBackend, CameraConfig, CameraId, CameraLimits, ConfigError, PixelFormat, Roi,
    TriggerSource,
};
pub use source::{FrameSource, SourceCamera};

#[cfg(feature = "aravis")]
pub use aravis_camera::{list_aravis_cameras, AravisCamera, AravisCameraInfo};
#[cfg(feature = "aravis")]
pub use fake_gv::{FakeGvCamera, FakeGvOptions};
#[cfg(feature = "firewire")]
pub use firewire::{list_iidc_cameras, FirewireCamera, IidcCameraInfo};
