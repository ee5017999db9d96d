//! Camera configuration and its validation.
//!
//! Aravis writes out-of-range feature values without complaint (the camera clamps or ignores
//! them), so every setting is checked here: once on its own ([`CameraConfig::validate`]) and
//! once against the bounds the camera reports ([`CameraConfig::validate_against`]).
use std::fmt;
use std::net::Ipv4Addr;
use std::time::Duration;

use csmetro_hal::CameraError;
use serde::{Deserialize, Serialize};

/// How to find the camera. In TOML: `id = { ip = "192.168.1.20" }`, `id = { serial = "40123456" }`
/// or `id = { device_id = "Basler-40123456" }` (the id `arv-tool-0.8` prints) for the Aravis
/// backend; `id = { guid = "0x000a47010e0a1b2c" }` (the 64-bit IEEE 1394 GUID, hex, colons
/// allowed) for the FireWire backend.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum CameraId {
    /// GigE Vision camera at this IPv4 address (no discovery broadcast needed).
    Ip(Ipv4Addr),
    /// Device serial number, found by discovery on all interfaces.
    Serial(String),
    /// Aravis device id, `<vendor>-<model>-<serial>` or `<vendor>-<serial>`.
    DeviceId(String),
    /// IEEE 1394 GUID of an IIDC camera, hex (`0x000a47010e0a1b2c` or `00:0a:47:01:0e:0a:1b:2c`).
    Guid(String),
}

/// Parses an IEEE 1394 GUID written in hex: 16 digits at most, optional `0x`, optional `:`/`-`
/// separators (a GUID is 64 bits: TOML integers stop at 2^63 - 1, so it is written as a string).
pub fn parse_guid(s: &str) -> Result<u64, ConfigError> {
    let t = s.trim();
    let t = t
        .strip_prefix("0x")
        .or_else(|| t.strip_prefix("0X"))
        .unwrap_or(t);
    let digits: String = t.chars().filter(|c| *c != ':' && *c != '-').collect();
    if digits.is_empty() || digits.len() > 16 || !digits.chars().all(|c| c.is_ascii_hexdigit()) {
        return Err(ConfigError(format!(
            "camera guid {s:?} is not a 64-bit hex GUID (e.g. \"0x000a47010e0a1b2c\")"
        )));
    }
    u64::from_str_radix(&digits, 16).map_err(|e| ConfigError(format!("camera guid {s:?}: {e}")))
}

/// Which library drives the camera: `aravis` (GigE Vision / USB3 Vision) or `firewire`
/// (IEEE 1394 IIDC through libdc1394). Each needs the cargo feature of the same name.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum CameraBackend {
    /// GigE Vision / USB3 Vision through libaravis (cargo feature `aravis`).
    #[default]
    Aravis,
    /// IEEE 1394 IIDC through libdc1394 (cargo feature `firewire`).
    Firewire,
}

impl CameraBackend {
    /// Every backend, compiled in or not.
    pub const ALL: [CameraBackend; 2] = [CameraBackend::Aravis, CameraBackend::Firewire];

    /// Its name in configuration files, which is also the cargo feature that builds it.
    pub fn name(self) -> &'static str {
        match self {
            CameraBackend::Aravis => "aravis",
            CameraBackend::Firewire => "firewire",
        }
    }

    /// Whether this build of the crate contains the backend.
    pub fn compiled(self) -> bool {
        match self {
            CameraBackend::Aravis => cfg!(feature = "aravis"),
            CameraBackend::Firewire => cfg!(feature = "firewire"),
        }
    }
}

impl fmt::Display for CameraBackend {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// What starts an exposure.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum TriggerSource {
    /// The driver triggers each exposure itself (one grab = one exposure).
    #[default]
    Software,
    /// A hardware line (IIDC trigger source 0, rising edge) starts each exposure; a grab
    /// returns the first frame exposed after it began. FireWire backend only.
    External,
}

impl fmt::Display for CameraId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            CameraId::Ip(ip) => write!(f, "ip {ip}"),
            CameraId::Serial(s) => write!(f, "serial {s}"),
            CameraId::DeviceId(d) => write!(f, "device id {d}"),
            CameraId::Guid(g) => match parse_guid(g) {
                Ok(v) => write!(f, "guid 0x{v:016x}"),
                Err(_) => write!(f, "guid {g}"),
            },
        }
    }
}

/// Pixel formats the service decodes. Mono12 and Mono16 arrive as one little-endian 16-bit word
/// per pixel (not the packed variants). Mono16 is accepted because Aravis's fake GigE Vision
/// camera offers Mono16 but not Mono12, so it is the 16-bit path CI can exercise end to end.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum PixelFormat {
    /// 8 bits per pixel.
    Mono8,
    /// 12 significant bits in a little-endian 16-bit word.
    Mono12,
    /// 16 bits, little-endian.
    Mono16,
}

impl PixelFormat {
    /// GenICam `PixelFormat` enumeration entry name.
    pub fn genicam_name(self) -> &'static str {
        match self {
            PixelFormat::Mono8 => "Mono8",
            PixelFormat::Mono12 => "Mono12",
            PixelFormat::Mono16 => "Mono16",
        }
    }
    /// Significant bits per pixel (the `bit_depth` of a frame).
    pub fn bit_depth(self) -> u8 {
        match self {
            PixelFormat::Mono8 => 8,
            PixelFormat::Mono12 => 12,
            PixelFormat::Mono16 => 16,
        }
    }
    /// Bytes per pixel on the wire.
    pub fn bytes_per_pixel(self) -> usize {
        match self {
            PixelFormat::Mono8 => 1,
            PixelFormat::Mono12 | PixelFormat::Mono16 => 2,
        }
    }
}

/// Region of interest on the sensor, pixels.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Roi {
    /// Left column (OffsetX).
    pub x: u32,
    /// Top row (OffsetY).
    pub y: u32,
    /// Width, pixels.
    pub width: u32,
    /// Height, pixels.
    pub height: u32,
}

/// Configuration of one camera.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraConfig {
    /// The library that drives the camera (default `aravis`, which older files assume).
    #[serde(default)]
    pub backend: CameraBackend,
    /// How to find the camera.
    pub id: CameraId,
    /// Pixel format asked of the camera.
    #[serde(default = "default_pixel_format")]
    pub pixel_format: PixelFormat,
    /// Exposure time, µs.
    pub exposure_us: f64,
    /// Region of interest; `None` means the full sensor.
    #[serde(default)]
    pub roi: Option<Roi>,
    /// Longest wait for one frame after its trigger, ms.
    #[serde(default = "default_frame_timeout_ms")]
    pub frame_timeout_ms: u64,
    /// How many times to try reopening a camera that dropped (0: never).
    #[serde(default = "default_reconnect_attempts")]
    pub reconnect_attempts: u32,
    /// Wait before the first reopen attempt, ms; doubled after each failure (capped at 8x).
    #[serde(default = "default_reconnect_backoff_ms")]
    pub reconnect_backoff_ms: u64,
    /// GigE Vision stream packet size, bytes. 1400 fits any 1500-byte MTU path; jumbo frames
    /// need a fixed large socket buffer as well.
    #[serde(default = "default_packet_size")]
    pub packet_size: u32,
    /// GigE Vision stream socket receive buffer, bytes. `None` (default): sized to one frame by
    /// Aravis. Jumbo packets on a real link want a fixed large buffer (e.g. 4 MiB); the kernel
    /// caps it at `net.core.rmem_max`.
    #[serde(default)]
    pub socket_buffer_bytes: Option<u32>,
    /// What starts an exposure (`software`, the default, or `external`: FireWire backend only).
    #[serde(default)]
    pub trigger: TriggerSource,
    /// Gain, dB (absolute IIDC gain; FireWire backend only). `None`: left as the camera has it.
    #[serde(default)]
    pub gain_db: Option<f64>,
}

fn default_pixel_format() -> PixelFormat {
    PixelFormat::Mono8
}
fn default_frame_timeout_ms() -> u64 {
    1000
}
fn default_reconnect_attempts() -> u32 {
    3
}
fn default_reconnect_backoff_ms() -> u64 {
    500
}
fn default_packet_size() -> u32 {
    1400
}

/// Longest frame timeout accepted: a grab must never look like a hang.
pub(crate) const MAX_FRAME_TIMEOUT_MS: u64 = 60_000;
/// Most reconnect attempts accepted (bounds the time a dropped camera can block a grab).
pub(crate) const MAX_RECONNECT_ATTEMPTS: u32 = 20;
/// Longest base backoff accepted, ms.
pub(crate) const MAX_RECONNECT_BACKOFF_MS: u64 = 10_000;
/// GigE Vision packet sizes accepted, bytes (576: minimum IPv4 datagram; 9000: jumbo frame).
pub(crate) const PACKET_SIZE_RANGE: (u32, u32) = (576, 9000);

/// Largest stream socket buffer accepted, bytes.
pub(crate) const MAX_SOCKET_BUFFER_BYTES: u32 = 256 << 20;

/// Feature bounds read from a camera, against which a configuration is checked.
#[derive(Debug, Clone, PartialEq)]
pub struct CameraLimits {
    /// Sensor size, pixels (`SensorWidth`, `SensorHeight`).
    pub sensor_width: u32,
    /// See `sensor_width`.
    pub sensor_height: u32,
    /// (min, max) of the `Width` / `Height` features.
    pub width_bounds: (u32, u32),
    /// See `width_bounds`.
    pub height_bounds: (u32, u32),
    /// Increments of OffsetX, OffsetY, Width, Height (1 where the camera does not say).
    pub x_increment: u32,
    /// See `x_increment`.
    pub y_increment: u32,
    /// See `x_increment`.
    pub width_increment: u32,
    /// See `x_increment`.
    pub height_increment: u32,
    /// (min, max) exposure, µs.
    pub exposure_bounds_us: (f64, f64),
    /// GenICam names of the pixel formats the camera offers (e.g. "Mono8").
    pub pixel_formats: Vec<String>,
}

/// A configuration the service must not apply. The message says what to change.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{0}")]
pub struct ConfigError(pub String);

impl From<ConfigError> for CameraError {
    fn from(e: ConfigError) -> Self {
        CameraError::Setting(e.0)
    }
}

impl CameraConfig {
    /// A configuration with the defaults for everything but the id and exposure.
    pub fn new(id: CameraId, exposure_us: f64) -> Self {
        CameraConfig {
            backend: CameraBackend::default(),
            id,
            pixel_format: default_pixel_format(),
            exposure_us,
            roi: None,
            frame_timeout_ms: default_frame_timeout_ms(),
            reconnect_attempts: default_reconnect_attempts(),
            reconnect_backoff_ms: default_reconnect_backoff_ms(),
            packet_size: default_packet_size(),
            socket_buffer_bytes: None,
            trigger: TriggerSource::default(),
            gain_db: None,
        }
    }

    /// Longest wait for one frame after its trigger.
    pub fn frame_timeout(&self) -> Duration {
        Duration::from_millis(self.frame_timeout_ms)
    }

    /// Wait before reopen attempt `attempt` (0-based): base * 2^attempt, capped at 8x base.
    pub fn reconnect_backoff(&self, attempt: u32) -> Duration {
        Duration::from_millis(self.reconnect_backoff_ms << attempt.min(3))
    }

    /// Checks that need no camera.
    pub fn validate(&self) -> Result<(), ConfigError> {
        self.validate_backend()?;
        match &self.id {
            CameraId::Ip(ip) if ip.is_unspecified() || ip.is_broadcast() || ip.is_multicast() => {
                return Err(ConfigError(format!(
                    "camera ip {ip} is not a unicast address"
                )));
            }
            CameraId::Serial(s) | CameraId::DeviceId(s) if s.trim().is_empty() => {
                return Err(ConfigError(format!("camera {} is empty", self.id)));
            }
            _ => {}
        }
        if !(self.exposure_us.is_finite() && self.exposure_us > 0.0) {
            return Err(ConfigError(format!(
                "exposure_us = {} must be a positive number of microseconds",
                self.exposure_us
            )));
        }
        if let Some(r) = self.roi {
            if r.width == 0 || r.height == 0 {
                return Err(ConfigError(format!(
                    "roi {}x{} is empty; width and height must be at least 1",
                    r.width, r.height
                )));
            }
        }
        if self.frame_timeout_ms == 0 || self.frame_timeout_ms > MAX_FRAME_TIMEOUT_MS {
            return Err(ConfigError(format!(
                "frame_timeout_ms = {} must be in 1..={MAX_FRAME_TIMEOUT_MS}",
                self.frame_timeout_ms
            )));
        }
        if self.reconnect_attempts > MAX_RECONNECT_ATTEMPTS {
            return Err(ConfigError(format!(
                "reconnect_attempts = {} must be at most {MAX_RECONNECT_ATTEMPTS}",
                self.reconnect_attempts
            )));
        }
        if self.reconnect_backoff_ms > MAX_RECONNECT_BACKOFF_MS {
            return Err(ConfigError(format!(
                "reconnect_backoff_ms = {} must be at most {MAX_RECONNECT_BACKOFF_MS}",
                self.reconnect_backoff_ms
            )));
        }
        let (lo, hi) = PACKET_SIZE_RANGE;
        if !(lo..=hi).contains(&self.packet_size) {
            return Err(ConfigError(format!(
                "packet_size = {} must be in {lo}..={hi} bytes",
                self.packet_size
            )));
        }
        if let Some(b) = self.socket_buffer_bytes {
            if b < self.packet_size || b > MAX_SOCKET_BUFFER_BYTES {
                return Err(ConfigError(format!(
                    "socket_buffer_bytes = {b} must hold at least one packet ({} bytes) and be \
                     at most {MAX_SOCKET_BUFFER_BYTES}",
                    self.packet_size
                )));
            }
        }
        Ok(())
    }

    /// The settings each backend understands: an id it can open, a pixel format it delivers,
    /// the trigger and gain controls it implements.
    fn validate_backend(&self) -> Result<(), ConfigError> {
        match self.backend {
            CameraBackend::Aravis => {
                if let CameraId::Guid(_) = self.id {
                    return Err(ConfigError(
                        "id = { guid = ... } names an IEEE 1394 camera: set backend = \"firewire\""
                            .into(),
                    ));
                }
                if self.trigger == TriggerSource::External {
                    return Err(ConfigError(
                        "trigger = \"external\" is implemented by the firewire backend only".into(),
                    ));
                }
                if self.gain_db.is_some() {
                    return Err(ConfigError(
                        "gain_db is implemented by the firewire backend only".into(),
                    ));
                }
            }
            CameraBackend::Firewire => {
                let CameraId::Guid(g) = &self.id else {
                    return Err(ConfigError(format!(
                        "the firewire backend opens cameras by GUID: id = {{ guid = \"0x...\" }} \
                         (`csmetro camera list` prints them), not by {}",
                        self.id
                    )));
                };
                parse_guid(g)?;
                if self.pixel_format == PixelFormat::Mono12 {
                    return Err(ConfigError(
                        "IIDC has no unpacked Mono12 coding: use pixel_format = \"mono16\"".into(),
                    ));
                }
                if let Some(g) = self.gain_db {
                    if !(g.is_finite() && (-60.0..=60.0).contains(&g)) {
                        return Err(ConfigError(format!(
                            "gain_db = {g} must be a number of dB in [-60, 60]"
                        )));
                    }
                }
            }
        }
        Ok(())
    }

    /// The region this configuration asks for on a camera with these limits.
    pub fn effective_roi(&self, limits: &CameraLimits) -> Roi {
        self.roi.unwrap_or(Roi {
            x: 0,
            y: 0,
            width: limits.sensor_width,
            height: limits.sensor_height,
        })
    }

    /// All checks, including those against the bounds the camera reports.
    pub fn validate_against(&self, limits: &CameraLimits) -> Result<(), ConfigError> {
        self.validate()?;
        let name = self.pixel_format.genicam_name();
        if !limits.pixel_formats.iter().any(|p| p == name) {
            return Err(ConfigError(format!(
                "pixel format {name} is not offered by the camera (it offers: {})",
                limits.pixel_formats.join(", ")
            )));
        }
        let (emin, emax) = limits.exposure_bounds_us;
        if self.exposure_us < emin || self.exposure_us > emax {
            return Err(ConfigError(format!(
                "exposure_us = {} is outside the camera's range [{emin}, {emax}] µs",
                self.exposure_us
            )));
        }
        let r = self.effective_roi(limits);
        let (sw, sh) = (limits.sensor_width, limits.sensor_height);
        check_axis(
            "width",
            r.width,
            limits.width_bounds,
            limits.width_increment,
        )?;
        check_axis(
            "height",
            r.height,
            limits.height_bounds,
            limits.height_increment,
        )?;
        check_increment("x", r.x, limits.x_increment)?;
        check_increment("y", r.y, limits.y_increment)?;
        if u64::from(r.x) + u64::from(r.width) > u64::from(sw)
            || u64::from(r.y) + u64::from(r.height) > u64::from(sh)
        {
            return Err(ConfigError(format!(
                "roi x={} y={} {}x{} does not fit the {sw}x{sh} sensor",
                r.x, r.y, r.width, r.height
            )));
        }
        Ok(())
    }
}

fn check_axis(what: &str, v: u32, (lo, hi): (u32, u32), inc: u32) -> Result<(), ConfigError> {
    if v < lo || v > hi {
        return Err(ConfigError(format!(
            "roi {what} = {v} is outside the camera's range [{lo}, {hi}]"
        )));
    }
    check_increment(what, v, inc)
}

fn check_increment(what: &str, v: u32, inc: u32) -> Result<(), ConfigError> {
    if inc > 1 && !v.is_multiple_of(inc) {
        return Err(ConfigError(format!(
            "roi {what} = {v} is not a multiple of the camera's increment {inc}"
        )));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn limits() -> CameraLimits {
        CameraLimits {
            sensor_width: 1024,
            sensor_height: 768,
            width_bounds: (16, 1024),
            height_bounds: (16, 768),
            x_increment: 4,
            y_increment: 2,
            width_increment: 8,
            height_increment: 2,
            exposure_bounds_us: (10.0, 1e6),
            pixel_formats: vec!["Mono8".into(), "Mono12".into()],
        }
    }

    fn cfg() -> CameraConfig {
        CameraConfig::new(CameraId::Ip(Ipv4Addr::new(192, 168, 7, 2)), 500.0)
    }

    fn err(c: &CameraConfig) -> String {
        c.validate_against(&limits()).unwrap_err().0
    }

    #[test]
    fn toml_with_defaults_parses_and_validates() {
        let c: CameraConfig = toml::from_str(
            r#"
            id = { serial = "40123456" }
            pixel_format = "mono12"
            exposure_us = 250.0
            roi = { x = 64, y = 32, width = 512, height = 256 }
            "#,
        )
        .unwrap();
        assert_eq!(c.id, CameraId::Serial("40123456".into()));
        assert_eq!(c.pixel_format, PixelFormat::Mono12);
        assert_eq!(c.frame_timeout(), Duration::from_secs(1));
        assert_eq!(c.packet_size, 1400);
        c.validate_against(&limits()).unwrap();
        // Round trip through TOML keeps every field.
        let back: CameraConfig = toml::from_str(&toml::to_string(&c).unwrap()).unwrap();
        assert_eq!(back, c);
    }

    #[test]
    fn unknown_fields_and_formats_are_rejected_when_parsing() {
        assert!(toml::from_str::<CameraConfig>(
            "id = { ip = \"10.0.0.2\" }\nexposure_us = 1.0\nexposure = 2"
        )
        .is_err());
        assert!(toml::from_str::<CameraConfig>(
            "id = { ip = \"10.0.0.2\" }\nexposure_us = 1.0\npixel_format = \"rgb8\""
        )
        .is_err());
        assert!(
            toml::from_str::<CameraConfig>("id = { ip = \"10.0.0.300\" }\nexposure_us = 1.0")
                .is_err()
        );
    }

    #[test]
    fn static_checks() {
        let mut c = cfg();
        c.exposure_us = 0.0;
        assert!(c.validate().unwrap_err().0.contains("exposure_us"));
        c.exposure_us = f64::NAN;
        assert!(c.validate().is_err());
        let mut c = cfg();
        c.frame_timeout_ms = 0;
        assert!(c.validate().unwrap_err().0.contains("frame_timeout_ms"));
        c.frame_timeout_ms = MAX_FRAME_TIMEOUT_MS + 1;
        assert!(c.validate().is_err());
        let mut c = cfg();
        c.packet_size = 9001;
        assert!(c.validate().unwrap_err().0.contains("packet_size"));
        let mut c = cfg();
        c.socket_buffer_bytes = Some(1000);
        assert!(c.validate().unwrap_err().0.contains("socket_buffer_bytes"));
        c.socket_buffer_bytes = Some(4 << 20);
        c.validate().unwrap();
        let mut c = cfg();
        c.reconnect_attempts = MAX_RECONNECT_ATTEMPTS + 1;
        assert!(c.validate().unwrap_err().0.contains("reconnect_attempts"));
        let mut c = cfg();
        c.id = CameraId::Serial("  ".into());
        assert!(c.validate().is_err());
        c.id = CameraId::Ip(Ipv4Addr::BROADCAST);
        assert!(c.validate().is_err());
        let mut c = cfg();
        c.roi = Some(Roi {
            x: 0,
            y: 0,
            width: 0,
            height: 10,
        });
        assert!(c.validate().unwrap_err().0.contains("empty"));
        cfg().validate().unwrap();
    }

    #[test]
    fn checks_against_camera_bounds() {
        let mut c = cfg();
        c.exposure_us = 5.0;
        assert!(err(&c).contains("outside the camera's range [10, 1000000]"));
        c.exposure_us = 2e6;
        assert!(err(&c).contains("exposure_us"));

        let mut c = cfg();
        c.pixel_format = PixelFormat::Mono16;
        assert!(err(&c).contains("Mono16 is not offered"));

        let roi = |x, y, width, height| {
            Some(Roi {
                x,
                y,
                width,
                height,
            })
        };
        let mut c = cfg();
        c.roi = roi(0, 0, 1032, 64);
        assert!(err(&c).contains("roi width = 1032 is outside"));
        c.roi = roi(0, 0, 8, 64);
        assert!(err(&c).contains("roi width = 8 is outside"));
        c.roi = roi(0, 0, 100, 64);
        assert!(err(&c).contains("multiple of the camera's increment 8"));
        c.roi = roi(2, 0, 64, 64);
        assert!(err(&c).contains("roi x = 2"));
        c.roi = roi(0, 1, 64, 64);
        assert!(err(&c).contains("roi y = 1"));
        c.roi = roi(512, 0, 520, 64);
        assert!(err(&c).contains("does not fit the 1024x768 sensor"));
        c.roi = roi(512, 512, 512, 256);
        c.validate_against(&limits()).unwrap();
        c.roi = None;
        assert_eq!(
            c.effective_roi(&limits()),
            Roi {
                x: 0,
                y: 0,
                width: 1024,
                height: 768
            }
        );
        c.validate_against(&limits()).unwrap();
    }

    #[test]
    fn backoff_doubles_and_is_capped() {
        let mut c = cfg();
        c.reconnect_backoff_ms = 100;
        let ms: Vec<u128> = (0..6).map(|a| c.reconnect_backoff(a).as_millis()).collect();
        assert_eq!(ms, vec![100, 200, 400, 800, 800, 800]);
    }

    #[test]
    fn backend_defaults_to_aravis_and_firewire_needs_a_guid() {
        // Files written before the backend key keep their meaning.
        let c: CameraConfig =
            toml::from_str("id = { ip = \"10.0.0.2\" }\nexposure_us = 100.0").unwrap();
        assert_eq!(c.backend, CameraBackend::Aravis);
        assert_eq!(c.trigger, TriggerSource::Software);
        c.validate().unwrap();

        let fw: CameraConfig = toml::from_str(
            "backend = \"firewire\"\nid = { guid = \"00:0a:47:01:0e:0a:1b:2c\" }\n\
             pixel_format = \"mono16\"\nexposure_us = 8000.0\ntrigger = \"external\"\ngain_db = 6.0",
        )
        .unwrap();
        fw.validate().unwrap();
        assert_eq!(fw.id.to_string(), "guid 0x000a47010e0a1b2c");
        assert!(toml::from_str::<CameraConfig>(
            "backend = \"usb2\"\nid = { ip = \"10.0.0.2\" }\nexposure_us = 1.0"
        )
        .is_err());

        let mut c = fw.clone();
        c.id = CameraId::Serial("50-0536876543".into());
        assert!(c.validate().unwrap_err().0.contains("by GUID"));
        c.id = CameraId::Guid("0xnothex".into());
        assert!(c
            .validate()
            .unwrap_err()
            .0
            .contains("not a 64-bit hex GUID"));
        let mut c = fw.clone();
        c.pixel_format = PixelFormat::Mono12;
        assert!(c.validate().unwrap_err().0.contains("mono16"));
        let mut c = fw.clone();
        c.gain_db = Some(f64::INFINITY);
        assert!(c.validate().unwrap_err().0.contains("gain_db"));

        // The Aravis backend refuses what only the FireWire backend implements.
        let mut c = fw.clone();
        c.backend = CameraBackend::Aravis;
        assert!(c
            .validate()
            .unwrap_err()
            .0
            .contains("backend = \"firewire\""));
        let mut c = cfg();
        c.trigger = TriggerSource::External;
        assert!(c
            .validate()
            .unwrap_err()
            .0
            .contains("firewire backend only"));
        let mut c = cfg();
        c.gain_db = Some(3.0);
        assert!(c
            .validate()
            .unwrap_err()
            .0
            .contains("firewire backend only"));
    }

    #[test]
    fn guids_parse_in_the_usual_spellings() {
        let want = 0x000a_4701_0e0a_1b2c_u64;
        for s in [
            "0x000a47010e0a1b2c",
            "000A47010E0A1B2C",
            "00:0a:47:01:0e:0a:1b:2c",
            " 0xa47010e0a1b2c ",
        ] {
            assert_eq!(parse_guid(s).unwrap(), want, "{s}");
        }
        assert_eq!(parse_guid("0xffffffffffffffff").unwrap(), u64::MAX);
        for bad in ["", "0x", "0x1ffffffffffffffff", "guid", "12 34"] {
            assert!(parse_guid(bad).is_err(), "{bad:?}");
        }
    }

    #[test]
    fn config_error_is_a_setting_error() {
        let e: CameraError = ConfigError("nope".into()).into();
        assert!(matches!(e, CameraError::Setting(m) if m == "nope"));
    }
}
