//! csmetro-camera: camera configuration, an in-process simulated camera ([`SourceCamera`]) and,
//! behind the `aravis` feature, a GigE Vision / USB3 Vision driver ([`AravisCamera`]) plus a
//! fake GigE Vision camera on 127.0.0.1 ([`FakeGvCamera`]) whose frames our code draws, so
//! tests go through the real Aravis client path.
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
