//! A real GigE Vision camera on the loopback interface, served in-process by Aravis's fake GV
//! camera, whose frames are drawn by a [`FrameSource`]. Clients (our [`crate::AravisCamera`],
//! `arv-tool-0.8`, another process) see an ordinary GigE Vision device, so tests exercise
//! discovery, GVCP control, GVSP streaming and buffer handling exactly as with hardware.
//!
//! Only one fake GV camera can listen on one IP (GVCP port 3956): tests must share one.
//!
//! ```no_run
//! use std::sync::Arc;
//! use std::time::Duration;
//! use csmetro_camera::{AravisCamera, FakeGvCamera, FrameSource};
//! use csmetro_hal::Camera;
//!
//! // Draw every frame (here: mid-grey); a simulation renders the pattern at the stage position.
//! let source: FrameSource = Arc::new(|buf: &mut [u8], _width, _height| buf.fill(128));
//! let fake = FakeGvCamera::start(source)?; // 127.0.0.1, serial CSMFAKE01, 1024x768 Mono8
//! let mut camera = AravisCamera::open(fake.camera_config(1000.0))?; // by IP, 1 ms exposure
//! let frame = camera.grab(Duration::from_secs(1))?;
//! assert_eq!((frame.width, frame.height), (1024, 768));
//! # Ok::<(), csmetro_hal::CameraError>(())
//! ```
use std::ffi::c_void;
use std::net::{Ipv4Addr, UdpSocket};
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};

use aravis::glib::translate::ToGlibPtr;
use aravis::{FakeCamera, GvFakeCamera};
use csmetro_hal::CameraError;

use crate::config::{CameraConfig, CameraId};
use crate::source::FrameSource;

/// GigE Vision control protocol port.
const GVCP_PORT: u16 = 3956;

// Register map of Aravis's fake camera (arvfakecamera.h); stable across 0.8.x.
const REG_WIDTH: u32 = 0x100;
const REG_HEIGHT: u32 = 0x104;
const REG_SENSOR_HEIGHT: u32 = 0x118;
const REG_SENSOR_WIDTH: u32 = 0x11c;
const REG_X_OFFSET: u32 = 0x130;
const REG_Y_OFFSET: u32 = 0x134;

/// How to start a [`FakeGvCamera`].
#[derive(Debug, Clone, PartialEq)]
pub struct FakeGvOptions {
    /// Loopback address to serve on (other addresses are refused: tests stay on this machine).
    pub ip: Ipv4Addr,
    /// Serial number (at most 15 characters); the device id becomes `Aravis-Fake-<serial>`.
    pub serial: String,
    /// Sensor width, pixels.
    pub sensor_width: u32,
    /// Sensor height, pixels.
    pub sensor_height: u32,
    /// How often the fake camera polls for a software trigger. Aravis's default of 25 Hz adds
    /// up to 40 ms of latency to every triggered frame.
    pub trigger_frequency_hz: f64,
}

impl Default for FakeGvOptions {
    fn default() -> Self {
        FakeGvOptions {
            ip: Ipv4Addr::LOCALHOST,
            serial: FakeGvCamera::DEFAULT_SERIAL.to_string(),
            sensor_width: 1024,
            sensor_height: 768,
            trigger_frequency_hz: 1000.0,
        }
    }
}

/// State shared with the fill callback, which runs on the fake camera's thread.
struct FillState {
    /// The `ArvFakeCamera*` (kept alive by `FakeGvCamera::fake`), as an integer so the state is
    /// Send + Sync; only used to read its payload size.
    fake: usize,
    source: Mutex<FrameSource>,
    drawn: AtomicU64,
    panics: AtomicU64,
    undersized: AtomicU64,
}

/// A fake GigE Vision camera on loopback. Dropping it stops the camera.
#[allow(missing_debug_implementations)] // holds GObject handles only
pub struct FakeGvCamera {
    gv: GvFakeCamera,
    fake: FakeCamera,
    state: Arc<FillState>,
    options: FakeGvOptions,
}

impl FakeGvCamera {
    /// Serial of a camera started with the default options.
    pub const DEFAULT_SERIAL: &'static str = "CSMFAKE01";

    /// Start serving with the default options (127.0.0.1, [`Self::DEFAULT_SERIAL`], 1024x768).
    pub fn start(source: FrameSource) -> Result<Self, CameraError> {
        Self::start_with(FakeGvOptions::default(), source)
    }

    /// Start serving with these options (the address must be a loopback one).
    pub fn start_with(options: FakeGvOptions, source: FrameSource) -> Result<Self, CameraError> {
        if !options.ip.is_loopback() {
            return Err(CameraError::Setting(format!(
                "fake GigE Vision camera must serve on a loopback address, not {}",
                options.ip
            )));
        }
        if options.serial.is_empty() || options.serial.len() > 15 {
            return Err(CameraError::Setting(format!(
                "fake camera serial {:?} must have 1 to 15 characters",
                options.serial
            )));
        }
        if options.sensor_width == 0 || options.sensor_height == 0 {
            return Err(CameraError::Setting(
                "fake camera sensor size is empty".into(),
            ));
        }
        if !(options.trigger_frequency_hz.is_finite() && options.trigger_frequency_hz > 0.0) {
            return Err(CameraError::Setting(
                "fake camera trigger frequency must be positive".into(),
            ));
        }
        let ip = options.ip.to_string();
        // Aravis only warns when the GVCP port is taken and then serves nothing; probe it first.
        if let Err(e) = UdpSocket::bind((options.ip, GVCP_PORT)) {
            return Err(CameraError::Other(format!(
                "fake GigE Vision camera cannot listen on {ip}:{GVCP_PORT}: {e} \
                 (is another one, or arv-fake-gv-camera, already serving there?)"
            )));
        }
        let gv = GvFakeCamera::new_full(Some(&ip), Some(&options.serial), None);
        if !gv.is_running() {
            return Err(CameraError::Other(format!(
                "fake GigE Vision camera did not start on {ip}:{GVCP_PORT}"
            )));
        }
        let fake = gv
            .fake_camera()
            .ok_or_else(|| CameraError::Other("fake GV camera has no fake camera".into()))?;
        fake.set_trigger_frequency(options.trigger_frequency_hz);
        for (reg, v) in [
            (REG_SENSOR_WIDTH, options.sensor_width),
            (REG_SENSOR_HEIGHT, options.sensor_height),
            (REG_X_OFFSET, 0),
            (REG_Y_OFFSET, 0),
            (REG_WIDTH, options.sensor_width),
            (REG_HEIGHT, options.sensor_height),
        ] {
            if !fake.write_register(reg, v) {
                return Err(CameraError::Other(format!(
                    "fake camera refused register 0x{reg:x} = {v}"
                )));
            }
        }
        let fake_ptr: *mut aravis_sys::ArvFakeCamera = fake.to_glib_none().0;
        let state = Arc::new(FillState {
            fake: fake_ptr as usize,
            source: Mutex::new(source),
            drawn: AtomicU64::new(0),
            panics: AtomicU64::new(0),
            undersized: AtomicU64::new(0),
        });
        // SAFETY: `state` outlives the registration: Drop resets the callback (under the fake
        // camera's fill mutex, so no call is in flight) before the Arc is released.
        unsafe {
            aravis_sys::arv_fake_camera_set_fill_pattern(
                fake.to_glib_none().0,
                Some(fill_callback),
                Arc::as_ptr(&state) as *mut c_void,
            );
        }
        Ok(FakeGvCamera {
            gv,
            fake,
            state,
            options,
        })
    }

    /// Address it serves on.
    pub fn ip(&self) -> Ipv4Addr {
        self.options.ip
    }
    /// Its serial number.
    pub fn serial(&self) -> &str {
        &self.options.serial
    }
    /// The id Aravis lists this camera under (what `arv-tool-0.8` prints).
    pub fn device_id(&self) -> String {
        format!("Aravis-Fake-{}", self.options.serial)
    }
    /// The options it was started with.
    pub fn options(&self) -> &FakeGvOptions {
        &self.options
    }
    /// Whether the fake camera is listening on its GVCP port.
    pub fn is_running(&self) -> bool {
        self.gv.is_running()
    }

    /// Draw the following frames with `source` instead.
    pub fn set_source(&self, source: FrameSource) {
        *lock(&self.state.source) = source;
    }

    /// Frames the source has drawn so far.
    pub fn frames_drawn(&self) -> u64 {
        self.state.drawn.load(Ordering::SeqCst)
    }
    /// Calls in which the source panicked (that frame is sent black).
    pub fn source_panics(&self) -> u64 {
        self.state.panics.load(Ordering::SeqCst)
    }
    /// Frames left undrawn because the fake camera's buffer was smaller than the image.
    pub fn undersized_buffers(&self) -> u64 {
        self.state.undersized.load(Ordering::SeqCst)
    }

    /// A configuration that opens this camera by IP with the given exposure.
    pub fn camera_config(&self, exposure_us: f64) -> CameraConfig {
        CameraConfig::new(CameraId::Ip(self.options.ip), exposure_us)
    }
}

impl Drop for FakeGvCamera {
    fn drop(&mut self) {
        // Back to Aravis's own pattern before `state` can be freed; this takes the fill mutex,
        // so it also waits for a frame being drawn right now.
        // SAFETY: `self.fake` is a live ArvFakeCamera (owned by `self`); a null callback and
        // data are what Aravis documents for "no fill pattern".
        unsafe {
            aravis_sys::arv_fake_camera_set_fill_pattern(
                self.fake.to_glib_none().0,
                None,
                std::ptr::null_mut(),
            );
        }
        // `gv` is dropped after this, which stops the fake camera's thread and closes its sockets.
    }
}

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    // A panic while holding this lock cannot leave the Arc inside inconsistent.
    m.lock().unwrap_or_else(|e| e.into_inner())
}

/// Called by the fake camera (its own thread, fill mutex held) for every frame it sends.
unsafe extern "C" fn fill_callback(
    buffer: *mut aravis_sys::ArvBuffer,
    data: *mut c_void,
    _exposure_time_us: u32,
    _gain: u32,
    pixel_format: aravis_sys::ArvPixelFormat,
) {
    if buffer.is_null() || data.is_null() {
        return;
    }
    // SAFETY: `data` is the FillState registered in `start_with`, alive until Drop resets it.
    let state = unsafe { &*(data as *const FillState) };
    // A panic must not unwind into C (that aborts the whole process).
    // SAFETY: `buffer` is non-null and is the fake camera's buffer for this call; `state` is live.
    let outcome = catch_unwind(AssertUnwindSafe(|| unsafe {
        draw(state, buffer, pixel_format)
    }))
    .unwrap_or(Drawn::Panicked);
    let counter = match outcome {
        Drawn::Yes => &state.drawn,
        Drawn::Undersized => &state.undersized,
        Drawn::Panicked => &state.panics,
    };
    counter.fetch_add(1, Ordering::SeqCst);
}

enum Drawn {
    Yes,
    Undersized,
    Panicked,
}

/// Draw one frame into `buffer`.
unsafe fn draw(
    state: &FillState,
    buffer: *mut aravis_sys::ArvBuffer,
    pixel_format: aravis_sys::ArvPixelFormat,
) -> Drawn {
    // The buffer reports no size yet (its received size is set from what the default pattern
    // writes); the fake camera allocated it with, and checked it against, its payload size
    // before calling us, and sends exactly that many bytes.
    // SAFETY: `buffer` is the live ArvBuffer of this call and `state.fake` the live fake camera.
    let (width, height, data, size) = unsafe {
        let mut unused: usize = 0;
        (
            aravis_sys::arv_buffer_get_image_width(buffer),
            aravis_sys::arv_buffer_get_image_height(buffer),
            aravis_sys::arv_buffer_get_data(buffer, &mut unused),
            aravis_sys::arv_fake_camera_get_payload(state.fake as *mut aravis_sys::ArvFakeCamera),
        )
    };
    // ARV_PIXEL_FORMAT_BIT_PER_PIXEL: bits 16..23 of the GenICam pixel format code.
    let bytes_per_pixel = (((pixel_format >> 16) & 0xff) as usize).div_ceil(8).max(1);
    let (Ok(w), Ok(h)) = (usize::try_from(width), usize::try_from(height)) else {
        return Drawn::Undersized;
    };
    let need = w * h * bytes_per_pixel;
    if data.is_null() || need == 0 || size < need {
        return Drawn::Undersized;
    }
    let source = lock(&state.source).clone();
    // SAFETY: Aravis hands us its buffer of `size >= need` bytes for the duration of the call.
    let pixels = unsafe { std::slice::from_raw_parts_mut(data, need) };
    if catch_unwind(AssertUnwindSafe(|| source(pixels, w, h))).is_err() {
        // The buffer is reused and sent anyway: send black, never the previous frame again.
        pixels.fill(0);
        return Drawn::Panicked;
    }
    Drawn::Yes
}

#[cfg(test)]
mod tests {
    use super::*;

    fn blank() -> FrameSource {
        Arc::new(|b: &mut [u8], _w, _h| b.fill(0))
    }

    // These are refused before anything listens, so they do not touch the shared port.
    #[test]
    fn refuses_options_that_would_leave_loopback_or_break_the_camera() {
        let refused = |o: FakeGvOptions, what: &str| match FakeGvCamera::start_with(o, blank()) {
            Err(CameraError::Setting(m)) => assert!(m.contains(what), "{m}"),
            Err(e) => panic!("expected a setting error about {what}, got {e}"),
            Ok(_) => panic!("started with bad {what}"),
        };
        let d = FakeGvOptions::default;
        refused(
            FakeGvOptions {
                ip: Ipv4Addr::new(10, 0, 0, 1),
                ..d()
            },
            "loopback",
        );
        refused(
            FakeGvOptions {
                serial: "0123456789ABCDEF".into(),
                ..d()
            },
            "serial",
        );
        refused(
            FakeGvOptions {
                sensor_width: 0,
                ..d()
            },
            "sensor size",
        );
        refused(
            FakeGvOptions {
                trigger_frequency_hz: 0.0,
                ..d()
            },
            "trigger frequency",
        );
    }
}
