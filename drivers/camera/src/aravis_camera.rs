//! GigE Vision / USB3 Vision cameras through libaravis 0.8.
//!
//! One `grab` = drain stale buffers (waiting, bounded, for the late frames of timed-out grabs),
//! software trigger, wait (bounded) for the buffer, reject older exposures (arrival before the
//! trigger, block id not newer than the last frame returned), check its status. Missing packets
//! and timeouts are errors. When the camera drops (trigger refused, heartbeat lost, or a timeout
//! after which the camera no longer lists us as its controller), the driver reopens it with
//! bounded attempts and backoff and retries the grab once.
use std::ffi::CStr;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use aravis::glib::prelude::Cast;
use aravis::prelude::*;
use aravis::{
    Buffer, BufferPayloadType, BufferStatus, GvStream, GvStreamOption, GvStreamSocketBuffer, Stream,
};
use csmetro_hal::{Camera, CameraError, Frame, Pixels};
use tracing::{info, warn};

use crate::config::{CameraConfig, CameraId, CameraLimits, PixelFormat, Roi};

/// Buffers queued on the stream: one in flight plus slack for a late frame after a timeout.
const N_BUFFERS: usize = 4;
/// GigE Vision bootstrap register: control channel privilege (bits 0-1: exclusive/control).
const GVBS_CCP: u64 = 0x0a00;

/// Aravis's global device list is not thread-safe.
static DEVICE_LIST: Mutex<()> = Mutex::new(());

/// A camera driven through Aravis. See the module docs for the grab and reconnect policy.
#[allow(missing_debug_implementations)] // holds GObject handles only
pub struct AravisCamera {
    config: CameraConfig,
    session: Option<Session>,
    identity: Identity,
    limits: CameraLimits,
    reconnects: u32,
}

#[derive(Debug, Clone, PartialEq)]
struct Identity {
    vendor: String,
    model: String,
    serial: String,
    /// The GenICam DeviceID feature (often the serial; not Aravis's `<vendor>-<model>-<serial>`).
    device_id: String,
}

/// One open connection: camera, stream and queued buffers, acquisition running.
struct Session {
    camera: aravis::Camera,
    stream: Stream,
    /// Set by Aravis's heartbeat thread (`control-lost`) or by us when the camera stopped answering.
    lost: Arc<AtomicBool>,
    is_gv: bool,
    roi: Roi,
    format: PixelFormat,
    exposure_us: f64,
    /// Timed-out triggers whose frames may still arrive: the next grab waits for them (bounded)
    /// and throws them away, since one arriving after its trigger would pass the time check.
    owed: u32,
    /// GigE Vision block id of the last frame returned: an id at or before it is an older
    /// exposure whatever its arrival time.
    last_id: Option<u64>,
}

/// Longest wait, at the start of a grab, for the late frames of earlier timed-out grabs.
const LATE_FRAME_WAIT: Duration = Duration::from_secs(2);

/// Whether block id `id` is not newer than `last` (16-bit GVSP ids wrap at 65535, skipping 0).
fn not_newer(id: u64, last: u64) -> bool {
    if id <= 0xFFFF && last <= 0xFFFF {
        (last.wrapping_sub(id) & 0xFFFF) < 0x8000
    } else {
        id <= last
    }
}

/// Why one grab attempt failed.
enum GrabFailure {
    /// The camera did not take the trigger: it is gone or no longer ours.
    Control(String),
    /// An error to hand to the caller as is.
    Frame(CameraError),
}

fn msg(e: aravis::glib::Error) -> String {
    e.message().to_string()
}

impl AravisCamera {
    /// Open the camera, check the configuration against its feature bounds, apply it and start
    /// a triggered acquisition. One attempt: a camera that is not there is reported at once.
    pub fn open(config: CameraConfig) -> Result<Self, CameraError> {
        config.validate()?;
        let (session, identity, limits) = Session::connect(&config)?;
        info!(camera = %identity.serial, "camera open");
        Ok(AravisCamera {
            config,
            session: Some(session),
            identity,
            limits,
            reconnects: 0,
        })
    }

    /// The configuration it was opened with.
    pub fn config(&self) -> &CameraConfig {
        &self.config
    }
    /// Bounds the camera reported at the last (re)connect.
    pub fn limits(&self) -> &CameraLimits {
        &self.limits
    }
    /// The camera's serial number.
    pub fn serial(&self) -> &str {
        &self.identity.serial
    }
    /// Successful reconnects since open.
    pub fn reconnects(&self) -> u32 {
        self.reconnects
    }
    /// Exposure the camera reports after the last write, µs (cameras quantize it).
    pub fn exposure_us(&self) -> Option<f64> {
        self.session.as_ref().map(|s| s.exposure_us)
    }
    /// Aravis stream counters since the stream started: (completed, failures, underruns).
    pub fn stream_statistics(&self) -> Option<(u64, u64, u64)> {
        self.session.as_ref().map(|s| s.stream.statistics())
    }

    /// Grab with the configured frame timeout.
    pub fn grab_default(&mut self) -> Result<Frame, CameraError> {
        self.grab(self.config.frame_timeout())
    }

    /// Change the exposure (checked against the camera's bounds first). Returns what the camera
    /// reports back, µs.
    pub fn set_exposure_us(&mut self, exposure_us: f64) -> Result<f64, CameraError> {
        let mut cfg = self.config.clone();
        cfg.exposure_us = exposure_us;
        cfg.validate_against(&self.limits)?;
        let session = self.session_or_reconnect()?;
        let actual = apply_exposure(&session.camera, exposure_us)?;
        session.exposure_us = actual;
        self.config = cfg;
        Ok(actual)
    }

    /// Change the region of interest (`None`: full sensor). The payload size changes, so the
    /// camera is reopened with the new configuration.
    pub fn set_roi(&mut self, roi: Option<Roi>) -> Result<(), CameraError> {
        let mut cfg = self.config.clone();
        cfg.roi = roi;
        cfg.validate_against(&self.limits)?;
        // Release the camera before reopening it, so this client is not its own competitor.
        self.session = None;
        let (session, identity, limits) = Session::connect(&cfg)?;
        self.check_same_camera(&identity)?;
        self.session = Some(session);
        self.limits = limits;
        self.config = cfg;
        Ok(())
    }

    fn check_same_camera(&self, identity: &Identity) -> Result<(), CameraError> {
        if identity.serial != self.identity.serial {
            return Err(CameraError::Disconnected(format!(
                "expected camera serial {}, but {} answers as serial {}",
                self.identity.serial, self.config.id, identity.serial
            )));
        }
        Ok(())
    }

    fn session_or_reconnect(&mut self) -> Result<&mut Session, CameraError> {
        let usable = self
            .session
            .as_ref()
            .is_some_and(|s| !s.lost.load(Ordering::SeqCst));
        if !usable {
            self.reconnect()?;
        }
        self.session
            .as_mut()
            .ok_or_else(|| CameraError::Disconnected("no camera session".into()))
    }

    /// Drop the session and reopen with bounded attempts and backoff.
    fn reconnect(&mut self) -> Result<(), CameraError> {
        if let Some(old) = self.session.take() {
            // Skip talking to a camera known to be gone (each write would wait for timeouts).
            old.lost.store(true, Ordering::SeqCst);
        }
        let attempts = self.config.reconnect_attempts;
        let mut last = String::from("reconnect_attempts = 0");
        for attempt in 0..attempts {
            // Backoff first: a camera that just dropped (or a client that just died holding
            // control, released by the camera only after its heartbeat timeout, ~3 s) needs time.
            std::thread::sleep(self.config.reconnect_backoff(attempt));
            match Session::connect(&self.config) {
                Ok((session, identity, limits)) => {
                    self.check_same_camera(&identity)?;
                    self.session = Some(session);
                    self.limits = limits;
                    self.reconnects += 1;
                    info!(camera = %self.identity.serial, attempt, "camera reconnected");
                    return Ok(());
                }
                // The camera is back but refuses our settings: retrying will not help.
                Err(e @ CameraError::Setting(_)) => return Err(e),
                Err(e) => {
                    warn!(camera = %self.identity.serial, attempt, error = %e, "reconnect failed");
                    last = e.to_string();
                }
            }
        }
        Err(CameraError::Disconnected(format!(
            "camera serial {} ({}) dropped and {attempts} reconnect attempts failed; last error: \
             {last}",
            self.identity.serial, self.config.id
        )))
    }
}

impl Camera for AravisCamera {
    fn grab(&mut self, timeout: Duration) -> Result<Frame, CameraError> {
        let session = self.session_or_reconnect()?;
        let failure = match session.grab(timeout) {
            Ok(frame) => return Ok(frame),
            Err(GrabFailure::Frame(CameraError::Timeout(t))) => {
                // A timeout is also what a restarted camera looks like (it forgot our stream
                // settings); tell the two apart by asking whether we still hold control.
                if session.still_in_control() {
                    return Err(CameraError::Timeout(t));
                }
                "no frame and the camera no longer lists us as its controller".to_string()
            }
            Err(GrabFailure::Frame(e)) => return Err(e),
            Err(GrabFailure::Control(m)) => m,
        };
        warn!(camera = %self.identity.serial, reason = %failure, "camera dropped; reconnecting");
        self.reconnect()?;
        let session = self
            .session
            .as_mut()
            .ok_or_else(|| CameraError::Disconnected("no camera session".into()))?;
        match session.grab(timeout) {
            Ok(frame) => Ok(frame),
            Err(GrabFailure::Frame(e)) => Err(e),
            Err(GrabFailure::Control(m)) => Err(CameraError::Disconnected(m)),
        }
    }

    fn describe(&self) -> String {
        let Identity {
            vendor,
            model,
            serial,
            device_id,
        } = &self.identity;
        format!(
            "{vendor} {model} serial {serial} (DeviceID {device_id}, opened by {})",
            self.config.id
        )
    }
}

impl Session {
    fn connect(config: &CameraConfig) -> Result<(Session, Identity, CameraLimits), CameraError> {
        let camera = open_device(&config.id)?;
        let text = |r: Result<aravis::glib::GString, aravis::glib::Error>| {
            r.map(|s| s.to_string()).unwrap_or_default()
        };
        let identity = Identity {
            vendor: text(camera.vendor_name()),
            model: text(camera.model_name()),
            serial: text(camera.device_serial_number()),
            device_id: text(camera.device_id()),
        };
        if let CameraId::Serial(want) = &config.id {
            if &identity.serial != want {
                return Err(CameraError::Disconnected(format!(
                    "asked for serial {want}, opened serial {}",
                    identity.serial
                )));
            }
        }
        let is_gv = camera.is_gv_device();
        let setting = |what: &str, e: aravis::glib::Error| {
            CameraError::Setting(format!("{what}: {}", msg(e)))
        };
        // The camera keeps settings from earlier clients: stop whatever it was doing and put
        // the offsets at 0, so the width/height bounds read below are those of the sensor.
        // Best effort: a camera without offsets still gets its ROI validated and read back.
        let _ = camera.stop_acquisition();
        let _ = camera.set_integer("OffsetX", 0);
        let _ = camera.set_integer("OffsetY", 0);
        let limits = read_limits(&camera)?;
        config.validate_against(&limits)?;

        camera
            .set_pixel_format_from_string(config.pixel_format.genicam_name())
            .map_err(|e| setting("PixelFormat", e))?;
        let roi = config.effective_roi(&limits);
        let as_i32 = |v: u32| i32::try_from(v).unwrap_or(i32::MAX);
        camera
            .set_region(
                as_i32(roi.x),
                as_i32(roi.y),
                as_i32(roi.width),
                as_i32(roi.height),
            )
            .map_err(|e| setting("region", e))?;
        // Read back: a camera may clamp or ignore a value without an error.
        let got = camera
            .region()
            .map_err(|e| setting("region read-back", e))?;
        if got
            != (
                as_i32(roi.x),
                as_i32(roi.y),
                as_i32(roi.width),
                as_i32(roi.height),
            )
        {
            return Err(CameraError::Setting(format!(
                "camera applied region {got:?} instead of {roi:?}"
            )));
        }
        let fmt = camera
            .pixel_format_as_string()
            .map_err(|e| setting("PixelFormat read-back", e))?;
        if fmt.as_str() != config.pixel_format.genicam_name() {
            return Err(CameraError::Setting(format!(
                "camera applied pixel format {fmt} instead of {}",
                config.pixel_format.genicam_name()
            )));
        }
        let exposure_us = apply_exposure(&camera, config.exposure_us)?;
        camera
            .set_trigger("Software")
            .map_err(|e| setting("software trigger mode", e))?;

        if is_gv {
            // Must precede create_stream. The packet socket needs CAP_NET_RAW and receives
            // nothing on loopback; the plain UDP socket works everywhere.
            camera.gv_set_stream_options(GvStreamOption::PACKET_SOCKET_DISABLED);
            let packet = i32::try_from(config.packet_size).unwrap_or(i32::MAX);
            camera
                .gv_set_packet_size(packet)
                .map_err(|e| setting("GevSCPSPacketSize", e))?;
            let got = camera
                .gv_get_packet_size()
                .map_err(|e| setting("GevSCPSPacketSize read-back", e))?;
            if got != config.packet_size {
                return Err(CameraError::Setting(format!(
                    "camera applied packet size {got} instead of {} bytes",
                    config.packet_size
                )));
            }
        }
        let payload = camera
            .payload()
            .map_err(|e| CameraError::Other(format!("PayloadSize: {}", msg(e))))?;
        let stream = camera
            .create_stream()
            .map_err(|e| CameraError::Other(format!("create stream: {}", msg(e))))?;
        if let Some(gv) = stream.downcast_ref::<GvStream>() {
            // The default socket buffer drops packets of large frames; Auto sizes it to the payload.
            match config.socket_buffer_bytes {
                None => gv.set_socket_buffer(GvStreamSocketBuffer::Auto),
                Some(bytes) => {
                    gv.set_socket_buffer_size(i32::try_from(bytes).unwrap_or(i32::MAX));
                    gv.set_socket_buffer(GvStreamSocketBuffer::Fixed);
                }
            }
        }
        for _ in 0..N_BUFFERS {
            stream.push_buffer(Buffer::new_allocate(payload as usize));
        }
        let lost = Arc::new(AtomicBool::new(false));
        if let Some(device) = camera.device() {
            let flag = lost.clone();
            device.connect_control_lost(move |_| flag.store(true, Ordering::SeqCst));
        }
        camera
            .start_acquisition()
            .map_err(|e| CameraError::Other(format!("AcquisitionStart: {}", msg(e))))?;
        let mut session = Session {
            camera,
            stream,
            lost,
            is_gv,
            roi,
            format: config.pixel_format,
            exposure_us,
            owed: 0,
            last_id: None,
        };
        // Aravis sizes the stream socket buffer only when the first packet of the first frame
        // arrives, so that frame can overflow the default buffer and lose packets. Grab one
        // throw-away frame now; its outcome does not matter (a lost one is filtered out later).
        let _ = session.grab(config.frame_timeout());
        Ok((session, identity, limits))
    }

    fn grab(&mut self, timeout: Duration) -> Result<Frame, GrabFailure> {
        // A frame that arrived after an earlier grab gave up must not pass for this one. Frames
        // still owed by timed-out grabs are waited for, or one of them, sent after this grab's
        // trigger, would be taken for its exposure; a camera that dropped the trigger never
        // sends one, so the wait is bounded.
        let until = Instant::now() + timeout.min(LATE_FRAME_WAIT);
        loop {
            let b = if self.owed > 0 {
                let left = until.saturating_duration_since(Instant::now());
                self.stream.timeout_pop_buffer(left.as_micros() as u64)
            } else {
                self.stream.try_pop_buffer()
            };
            let Some(b) = b else { break };
            self.owed = self.owed.saturating_sub(1);
            self.stream.push_buffer(b);
        }
        self.owed = 0;
        let deadline = Instant::now() + timeout;
        let trigger_ns = SystemTime::now()
            .duration_since(UNIX_EPOCH)
            .map(|d| d.as_nanos() as u64)
            .unwrap_or(0);
        if let Err(e) = self.camera.software_trigger() {
            self.lost.store(true, Ordering::SeqCst);
            return Err(GrabFailure::Control(format!(
                "software trigger: {}",
                msg(e)
            )));
        }
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            let Some(buffer) = self
                .stream
                .timeout_pop_buffer(left.as_micros().min(u128::from(u64::MAX)) as u64)
            else {
                self.owed += 1;
                return Err(GrabFailure::Frame(CameraError::Timeout(timeout)));
            };
            // Aravis stamps a buffer (host wall clock) when its first packet arrives: anything
            // older than the trigger belongs to an earlier exposure still in flight then.
            // (0: the stream does not stamp buffers; nothing to compare.)
            let stamped = buffer.system_timestamp();
            let id = buffer.frame_id();
            // Block id 0 is not a valid GVSP id (some transports leave it unset): no check then.
            let stale = id != 0 && self.last_id.is_some_and(|last| not_newer(id, last));
            if stale || (stamped != 0 && stamped < trigger_ns) {
                self.stream.push_buffer(buffer);
                if Instant::now() >= deadline {
                    self.owed += 1;
                    return Err(GrabFailure::Frame(CameraError::Timeout(timeout)));
                }
                continue;
            }
            let frame = self.to_frame(&buffer);
            self.stream.push_buffer(buffer);
            if frame.is_ok() {
                self.last_id = Some(id);
            }
            return frame.map_err(GrabFailure::Frame);
        }
    }

    fn to_frame(&self, buffer: &Buffer) -> Result<Frame, CameraError> {
        let status = buffer.status();
        if status != BufferStatus::Success {
            return Err(CameraError::Incomplete(format!(
                "buffer status {status:?} (frame {})",
                buffer.frame_id()
            )));
        }
        if buffer.payload_type() != BufferPayloadType::Image {
            return Err(CameraError::Other(format!(
                "payload type {:?}, expected an image",
                buffer.payload_type()
            )));
        }
        let (w, h) = (buffer.image_width(), buffer.image_height());
        let fmt = buffer.image_pixel_format();
        let want_fmt = match self.format {
            PixelFormat::Mono8 => aravis::PixelFormat::MONO_8,
            PixelFormat::Mono12 => aravis::PixelFormat::MONO_12,
            PixelFormat::Mono16 => aravis::PixelFormat::MONO_16,
        };
        if (w, h) != (self.roi.width as i32, self.roi.height as i32) || fmt != want_fmt {
            return Err(CameraError::Other(format!(
                "frame is {w}x{h} format 0x{:08x}; configured {}x{} {}",
                fmt.raw(),
                self.roi.width,
                self.roi.height,
                self.format.genicam_name()
            )));
        }
        let (width, height) = (self.roi.width as usize, self.roi.height as usize);
        let data = buffer.image_data();
        let need = width * height * self.format.bytes_per_pixel();
        if data.len() < need {
            return Err(CameraError::Incomplete(format!(
                "{} bytes of image data, {need} expected",
                data.len()
            )));
        }
        let pixels = match self.format {
            PixelFormat::Mono8 => Pixels::Mono8(data[..need].to_vec()),
            PixelFormat::Mono12 | PixelFormat::Mono16 => Pixels::Mono16(
                data[..need]
                    .chunks_exact(2)
                    .map(|b| u16::from_le_bytes([b[0], b[1]]))
                    .collect(),
            ),
        };
        let ts = match buffer.timestamp() {
            0 => buffer.system_timestamp(),
            t => t,
        };
        Ok(Frame {
            width,
            height,
            bit_depth: self.format.bit_depth(),
            pixels,
            timestamp_s: ts as f64 * 1e-9,
        })
    }

    /// True unless the camera fails to answer or shows no controller (it restarted).
    fn still_in_control(&self) -> bool {
        if self.lost.load(Ordering::SeqCst) {
            return false;
        }
        if !self.is_gv {
            return true;
        }
        let Some(device) = self.camera.device() else {
            return false;
        };
        match device.read_register(GVBS_CCP) {
            Ok((_, ccp)) if ccp & 0b11 != 0 => true,
            _ => {
                self.lost.store(true, Ordering::SeqCst);
                false
            }
        }
    }
}

impl Drop for Session {
    fn drop(&mut self) {
        if !self.lost.load(Ordering::SeqCst) {
            let _ = self.camera.stop_acquisition();
        }
    }
}

/// Write the exposure (auto off where the camera has it) and return what the camera reports.
fn apply_exposure(camera: &aravis::Camera, exposure_us: f64) -> Result<f64, CameraError> {
    if camera.is_exposure_auto_available().unwrap_or(false) {
        camera
            .set_exposure_time_auto(aravis::Auto::Off)
            .map_err(|e| CameraError::Setting(format!("ExposureAuto: {}", msg(e))))?;
    }
    camera
        .set_exposure_time(exposure_us)
        .map_err(|e| CameraError::Setting(format!("exposure time: {}", msg(e))))?;
    let actual = camera
        .exposure_time()
        .map_err(|e| CameraError::Setting(format!("exposure read-back: {}", msg(e))))?;
    if (actual - exposure_us).abs() > 1.0_f64.max(0.01 * exposure_us) {
        // Within the bounds (checked before) a camera may still quantize the value.
        warn!(
            requested = exposure_us,
            applied = actual,
            "camera quantized the exposure"
        );
    }
    Ok(actual)
}

fn read_limits(camera: &aravis::Camera) -> Result<CameraLimits, CameraError> {
    let bad = |what: &str, e: aravis::glib::Error| {
        CameraError::Other(format!("reading {what} from the camera: {}", msg(e)))
    };
    let u = |v: i32| u32::try_from(v).unwrap_or(0);
    let inc = |r: Result<i32, aravis::glib::Error>| r.map(|v| u(v).max(1)).unwrap_or(1);
    let (sw, sh) = camera
        .sensor_size()
        .map_err(|e| bad("SensorWidth/Height", e))?;
    let (wmin, wmax) = camera.width_bounds().map_err(|e| bad("Width bounds", e))?;
    let (hmin, hmax) = camera
        .height_bounds()
        .map_err(|e| bad("Height bounds", e))?;
    Ok(CameraLimits {
        sensor_width: u(sw),
        sensor_height: u(sh),
        width_bounds: (u(wmin), u(wmax)),
        height_bounds: (u(hmin), u(hmax)),
        x_increment: inc(camera.x_offset_increment()),
        y_increment: inc(camera.y_offset_increment()),
        width_increment: inc(camera.width_increment()),
        height_increment: inc(camera.height_increment()),
        exposure_bounds_us: camera
            .exposure_time_bounds()
            .map_err(|e| bad("exposure bounds", e))?,
        pixel_formats: camera
            .dup_available_pixel_formats_as_strings()
            .map_err(|e| bad("pixel formats", e))?
            .into_iter()
            .map(|s| s.to_string())
            .collect(),
    })
}

fn open_device(id: &CameraId) -> Result<aravis::Camera, CameraError> {
    let name = match id {
        CameraId::Ip(ip) => ip.to_string(),
        CameraId::DeviceId(d) => d.clone(),
        CameraId::Serial(s) => device_id_for_serial(s)?,
        // Refused by validation; kept an error rather than a panic.
        CameraId::Guid(_) => {
            return Err(CameraError::Setting(format!(
                "{id} names an IEEE 1394 camera, which Aravis cannot open"
            )))
        }
    };
    aravis::Camera::new(Some(&name))
        .map_err(|e| CameraError::Disconnected(format!("cannot open camera {id}: {}", msg(e))))
}

/// One camera Aravis discovered (GigE Vision on every interface, USB3 Vision).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct AravisCameraInfo {
    /// Aravis device id (`id = { device_id = "..." }`).
    pub device_id: String,
    /// Vendor name.
    pub vendor: String,
    /// Model name.
    pub model: String,
    /// Serial number (`id = { serial = "..." }`).
    pub serial: String,
    /// Transport address (IPv4 for GigE Vision).
    pub address: String,
    /// "GigEVision" or "USB3Vision".
    pub protocol: String,
}

/// Discover every camera Aravis can reach (empty: none).
pub fn list_aravis_cameras() -> Vec<AravisCameraInfo> {
    let _guard = DEVICE_LIST.lock().unwrap_or_else(|e| e.into_inner());
    let text = |p: *const std::ffi::c_char| {
        if p.is_null() {
            String::new()
        } else {
            // SAFETY: non-null strings from Aravis's device list, valid until the next update,
            // which our lock excludes.
            unsafe { CStr::from_ptr(p) }.to_string_lossy().into_owned()
        }
    };
    let mut out = Vec::new();
    // SAFETY: Aravis's global device list, accessed under DEVICE_LIST.
    unsafe {
        aravis_sys::arv_update_device_list();
        for i in 0..aravis_sys::arv_get_n_devices() {
            out.push(AravisCameraInfo {
                device_id: text(aravis_sys::arv_get_device_id(i)),
                vendor: text(aravis_sys::arv_get_device_vendor(i)),
                model: text(aravis_sys::arv_get_device_model(i)),
                serial: text(aravis_sys::arv_get_device_serial_nbr(i)),
                address: text(aravis_sys::arv_get_device_address(i)),
                protocol: text(aravis_sys::arv_get_device_protocol(i)),
            });
        }
    }
    out
}

/// Discover all cameras and return the device id of the one with this serial.
fn device_id_for_serial(serial: &str) -> Result<String, CameraError> {
    let _guard = DEVICE_LIST.lock().unwrap_or_else(|e| e.into_inner());
    let text = |p: *const std::ffi::c_char| {
        if p.is_null() {
            String::new()
        } else {
            // SAFETY: non-null strings from Aravis's device list, valid until the next update,
            // which our lock excludes.
            unsafe { CStr::from_ptr(p) }.to_string_lossy().into_owned()
        }
    };
    let mut seen = Vec::new();
    let mut found = Vec::new();
    // SAFETY: Aravis's global device list, accessed under DEVICE_LIST.
    unsafe {
        aravis_sys::arv_update_device_list();
        for i in 0..aravis_sys::arv_get_n_devices() {
            let s = text(aravis_sys::arv_get_device_serial_nbr(i));
            let id = text(aravis_sys::arv_get_device_id(i));
            if s == serial {
                found.push(id.clone());
            }
            seen.push(format!("{id} (serial {s})"));
        }
    }
    match found.len() {
        1 => Ok(found.remove(0)),
        0 => Err(CameraError::Disconnected(format!(
            "no camera with serial {serial}; discovered: [{}]",
            seen.join(", ")
        ))),
        _ => Err(CameraError::Setting(format!(
            "serial {serial} is ambiguous: {}; configure a device id instead",
            found.join(", ")
        ))),
    }
}

#[cfg(test)]
mod tests {
    use super::not_newer;

    #[test]
    fn block_ids_compare_across_the_16_bit_wrap() {
        assert!(not_newer(7, 7));
        assert!(not_newer(6, 7));
        assert!(!not_newer(8, 7));
        // GVSP 1.x ids run 1..=65535 and wrap: 1 after 65535 is newer, 65535 after 1 is older.
        assert!(!not_newer(1, 65_535));
        assert!(not_newer(65_535, 1));
        assert!(not_newer(65_530, 65_535));
        // 64-bit ids (GVSP 2.x) compare plainly.
        assert!(not_newer(70_000, 70_001));
        assert!(!not_newer(70_002, 70_001));
    }
}
