//! Opening a camera on the backend its configuration names, whichever backends this build has.
use csmetro_hal::{Camera, CameraError};

use crate::config::{CameraBackend, CameraConfig, CameraId};

/// A camera found on one backend, with the id that opens it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct CameraInfo {
    /// The backend that found it.
    pub backend: CameraBackend,
    /// What to write as `id` in `[hardware.camera]` to open it.
    pub id: CameraId,
    /// Vendor, model and serial / GUID, as the camera reports them.
    pub description: String,
}

/// The cameras on every backend compiled into this build, in `CameraBackend::ALL` order; a
/// backend this build lacks is listed with the `not_compiled` error.
pub fn list_cameras() -> Vec<(CameraBackend, Result<Vec<CameraInfo>, CameraError>)> {
    CameraBackend::ALL
        .into_iter()
        .map(|b| (b, list_backend(b)))
        .collect()
}

fn list_backend(backend: CameraBackend) -> Result<Vec<CameraInfo>, CameraError> {
    match backend {
        #[cfg(feature = "aravis")]
        CameraBackend::Aravis => Ok(crate::aravis_camera::list_aravis_cameras()
            .into_iter()
            .map(|c| CameraInfo {
                backend,
                id: CameraId::DeviceId(c.device_id.clone()),
                description: format!(
                    "{} {} serial {} ({} {})",
                    c.vendor, c.model, c.serial, c.protocol, c.address
                ),
            })
            .collect()),
        #[cfg(feature = "firewire")]
        CameraBackend::Firewire => Ok(crate::firewire::list_iidc_cameras()?
            .into_iter()
            .map(|c| CameraInfo {
                backend,
                id: CameraId::Guid(format!("0x{:016x}", c.guid)),
                description: format!("{} {} (IIDC unit {})", c.vendor, c.model, c.unit),
            })
            .collect()),
        #[allow(unreachable_patterns)] // every backend compiled in
        other => Err(not_compiled(other)),
    }
}

/// Opens the camera `config` describes on its backend. A backend this build lacks is an error
/// naming the cargo feature (campaign validation refuses such files before anything opens).
pub fn open_camera(config: CameraConfig) -> Result<Box<dyn Camera>, CameraError> {
    config.validate()?;
    match config.backend {
        #[cfg(feature = "aravis")]
        CameraBackend::Aravis => {
            crate::aravis_camera::AravisCamera::open(config).map(|c| Box::new(c) as Box<dyn Camera>)
        }
        #[cfg(feature = "firewire")]
        CameraBackend::Firewire => {
            crate::firewire::FirewireCamera::open(config).map(|c| Box::new(c) as Box<dyn Camera>)
        }
        #[allow(unreachable_patterns)] // every backend compiled in
        other => Err(not_compiled(other)),
    }
}

/// The error of a backend this build does not contain.
pub fn not_compiled(backend: CameraBackend) -> CameraError {
    CameraError::NotCompiled(backend.name())
}
