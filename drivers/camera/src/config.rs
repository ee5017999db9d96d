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
/// or `id = { device_id = "Basler-40123456" }` (the id `arv-tool-0.8` prints).
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum CameraId {
    /// GigE Vision camera at this IPv4 address (no discovery broadcast needed).
    Ip(Ipv4Addr),
    /// Device serial number, found by discovery on all interfaces.
    Serial(String),
    /// Aravis device id, `<vendor>-<model>-<serial>` or `<vendor>-<serial>`.
    DeviceId(String),
}

impl fmt::Display for CameraId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            CameraId::Ip(ip) => write!(f, "ip {ip}"),
            CameraId::Serial(s) => write!(f, "serial {s}"),
            CameraId::DeviceId(d) => write!(f, "device id {d}"),
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
            id,
            pixel_format: default_pixel_format(),
            exposure_us,
            roi: None,
            frame_timeout_ms: default_frame_timeout_ms(),
            reconnect_attempts: default_reconnect_attempts(),
            reconnect_backoff_ms: default_reconnect_backoff_ms(),
            packet_size: default_packet_size(),
            socket_buffer_bytes: None,
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
    fn config_error_is_a_setting_error() {
        let e: CameraError = ConfigError("nope".into()).into();
        assert!(matches!(e, CameraError::Setting(m) if m == "nope"));
    }
}
