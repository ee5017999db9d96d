//! What the FireWire backend decides without touching libdc1394: which Format7 mode and colour
//! coding to use, how to trigger, how a frame's bytes become pixels, and the grab policy (which
//! frame answers which trigger), written against a small device trait so that it is tested
//! with a scripted device here and driven by libdc1394 in `firewire`.
use std::time::Duration;

use csmetro_hal::{CameraError, Frame, Pixels};

use crate::config::{ConfigError, PixelFormat, Roi, TriggerSource};

/// libdc1394 `DC1394_VIDEO_MODE_FORMAT7_0`; the eight Format7 modes follow it.
pub(crate) const VIDEO_MODE_FORMAT7_0: u32 = 88;
/// Number of Format7 modes (`DC1394_VIDEO_MODE_FORMAT7_NUM`).
pub(crate) const FORMAT7_MODES: u32 = 8;
/// `DC1394_COLOR_CODING_MONO8`.
pub(crate) const COLOR_CODING_MONO8: u32 = 352;
/// `DC1394_COLOR_CODING_MONO16`.
pub(crate) const COLOR_CODING_MONO16: u32 = 357;
/// `DC1394_TRIGGER_SOURCE_0`: the first external trigger input.
pub(crate) const TRIGGER_SOURCE_0: u32 = 576;
/// `DC1394_TRIGGER_SOURCE_SOFTWARE` (IIDC 1.31).
pub(crate) const TRIGGER_SOURCE_SOFTWARE: u32 = 580;

/// Longest wait, at the start of a grab, for the late frames of earlier timed-out grabs.
pub(crate) const LATE_FRAME_WAIT: Duration = Duration::from_secs(2);
/// Poll interval while waiting for a frame (libdc1394's blocking dequeue has no timeout).
pub(crate) const POLL_INTERVAL: Duration = Duration::from_millis(1);

/// IIDC colour coding delivering this pixel format (IIDC has no unpacked 12-bit mono coding).
pub(crate) fn coding_of(format: PixelFormat) -> Option<u32> {
    match format {
        PixelFormat::Mono8 => Some(COLOR_CODING_MONO8),
        PixelFormat::Mono16 => Some(COLOR_CODING_MONO16),
        PixelFormat::Mono12 => None,
    }
}

/// GenICam-style name of an IIDC mono coding, for messages and `CameraLimits::pixel_formats`.
pub(crate) fn coding_name(coding: u32) -> Option<&'static str> {
    match coding {
        COLOR_CODING_MONO8 => Some("Mono8"),
        COLOR_CODING_MONO16 => Some("Mono16"),
        _ => None,
    }
}

/// Whether `mode` is one of the Format7 (scalable, ROI) modes.
pub(crate) fn is_format7(mode: u32) -> bool {
    (VIDEO_MODE_FORMAT7_0..VIDEO_MODE_FORMAT7_0 + FORMAT7_MODES).contains(&mode)
}

/// The Format7 mode to capture `format` in: the lowest-numbered supported Format7 mode that
/// offers its coding (Format7_0 is the full-resolution, unbinned mode on IIDC cameras; higher
/// modes bin or skip). `codings_of(mode)` lists a mode's colour codings.
pub(crate) fn select_format7_mode(
    supported: &[u32],
    codings_of: &mut dyn FnMut(u32) -> Vec<u32>,
    format: PixelFormat,
) -> Result<(u32, u32), ConfigError> {
    let coding = coding_of(format).ok_or_else(|| {
        ConfigError(format!(
            "pixel format {} has no IIDC coding: use mono8 or mono16",
            format.genicam_name()
        ))
    })?;
    let mut modes: Vec<u32> = supported
        .iter()
        .copied()
        .filter(|m| is_format7(*m))
        .collect();
    modes.sort_unstable();
    modes.dedup();
    if modes.is_empty() {
        return Err(ConfigError(
            "the camera offers no Format7 mode (needed for a region of interest)".into(),
        ));
    }
    let mut offered = Vec::new();
    for m in modes {
        let codings = codings_of(m);
        if codings.contains(&coding) {
            return Ok((m, coding));
        }
        offered.extend(codings.into_iter().filter_map(coding_name));
    }
    offered.sort_unstable();
    offered.dedup();
    Err(ConfigError(format!(
        "pixel format {} is not offered by any Format7 mode of the camera (mono codings \
         offered: {})",
        format.genicam_name(),
        if offered.is_empty() {
            "none".to_string()
        } else {
            offered.join(", ")
        }
    )))
}

/// How each exposure is started on the camera.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum TriggerPlan {
    /// IIDC 1.31 software trigger: trigger mode 0, source software, one write per grab.
    SoftwareSource,
    /// Cameras without a software trigger source: transmission off, one one-shot per grab.
    OneShot,
    /// Trigger mode 0 on external input 0: the grab waits for the next exposure.
    External,
}

impl TriggerPlan {
    /// Whether a grab issues the trigger itself (so a timed-out grab owes a late frame).
    pub(crate) fn driver_triggers(self) -> bool {
        !matches!(self, TriggerPlan::External)
    }
}

/// The trigger plan for what the configuration asks, given the trigger sources the camera
/// lists and whether it can take one-shot commands.
pub(crate) fn plan_trigger(
    want: TriggerSource,
    sources: &[u32],
    one_shot_capable: bool,
) -> Result<TriggerPlan, ConfigError> {
    match want {
        TriggerSource::Software if sources.contains(&TRIGGER_SOURCE_SOFTWARE) => {
            Ok(TriggerPlan::SoftwareSource)
        }
        TriggerSource::Software if one_shot_capable => Ok(TriggerPlan::OneShot),
        TriggerSource::Software => Err(ConfigError(
            "the camera has neither a software trigger source nor one-shot capture".into(),
        )),
        // Cameras before IIDC 1.31 list no sources but have input 0.
        TriggerSource::External if sources.is_empty() || sources.contains(&TRIGGER_SOURCE_0) => {
            Ok(TriggerPlan::External)
        }
        TriggerSource::External => Err(ConfigError(
            "the camera has no external trigger input 0".into(),
        )),
    }
}

/// The Format7 geometry of a mode: its largest image and the steps sizes and offsets take.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct Format7Geometry {
    pub(crate) max_width: u32,
    pub(crate) max_height: u32,
    pub(crate) unit_width: u32,
    pub(crate) unit_height: u32,
    pub(crate) unit_x: u32,
    pub(crate) unit_y: u32,
}

impl Format7Geometry {
    /// As `CameraLimits` (the configuration checks them), with the offered formats and the
    /// shutter range, µs.
    pub(crate) fn limits(
        &self,
        pixel_formats: Vec<String>,
        exposure_bounds_us: (f64, f64),
    ) -> crate::config::CameraLimits {
        let one = |v: u32| v.max(1);
        crate::config::CameraLimits {
            sensor_width: self.max_width,
            sensor_height: self.max_height,
            width_bounds: (one(self.unit_width), self.max_width),
            height_bounds: (one(self.unit_height), self.max_height),
            // IIDC 1.30 cameras do not report offset units: libdc1394 then gives 0, and the
            // size units apply (the standard's rule).
            x_increment: one(if self.unit_x == 0 {
                self.unit_width
            } else {
                self.unit_x
            }),
            y_increment: one(if self.unit_y == 0 {
                self.unit_height
            } else {
                self.unit_y
            }),
            width_increment: one(self.unit_width),
            height_increment: one(self.unit_height),
            exposure_bounds_us,
            pixel_formats,
        }
    }
}

/// One frame as the device handed it over (bytes copied out of the DMA ring).
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct RawFrame {
    /// Host time the frame's transmission began, µs since the Unix epoch (libdc1394's
    /// `timestamp`, from the bus cycle timer on the juju stack; 0 if it could not tell).
    pub(crate) timestamp_us: u64,
    pub(crate) width: u32,
    pub(crate) height: u32,
    pub(crate) position: (u32, u32),
    pub(crate) color_coding: u32,
    /// Bytes per image line (may exceed width * bytes per pixel).
    pub(crate) stride: u32,
    /// 16-bit codings only: whether the words are little-endian (IIDC sends big-endian).
    pub(crate) little_endian: bool,
    /// libdc1394 flagged the frame as corrupt (lost packets).
    pub(crate) corrupt: bool,
    pub(crate) data: Vec<u8>,
}

/// Pixels of a raw frame, checked against what was configured.
pub(crate) fn convert_frame(
    raw: &RawFrame,
    roi: Roi,
    format: PixelFormat,
) -> Result<Frame, CameraError> {
    if raw.corrupt {
        return Err(CameraError::Incomplete(format!(
            "libdc1394 flagged the frame captured at {} µs as corrupt",
            raw.timestamp_us
        )));
    }
    let want_coding = coding_of(format)
        .ok_or_else(|| CameraError::Setting("Mono12 has no IIDC coding".into()))?;
    if (raw.width, raw.height) != (roi.width, roi.height)
        || raw.position != (roi.x, roi.y)
        || raw.color_coding != want_coding
    {
        return Err(CameraError::Other(format!(
            "frame is {}x{} at ({}, {}) coding {}; configured {}x{} at ({}, {}) {}",
            raw.width,
            raw.height,
            raw.position.0,
            raw.position.1,
            raw.color_coding,
            roi.width,
            roi.height,
            roi.x,
            roi.y,
            format.genicam_name()
        )));
    }
    let (w, h) = (roi.width as usize, roi.height as usize);
    let bpp = format.bytes_per_pixel();
    let line = w * bpp;
    let stride = (raw.stride as usize).max(line);
    let need = stride * (h.saturating_sub(1)) + line;
    if h > 0 && raw.data.len() < need {
        return Err(CameraError::Incomplete(format!(
            "{} bytes of image data, {need} expected",
            raw.data.len()
        )));
    }
    let rows = (0..h).map(|r| &raw.data[r * stride..r * stride + line]);
    let pixels = match format {
        PixelFormat::Mono8 => Pixels::Mono8(rows.flatten().copied().collect()),
        PixelFormat::Mono12 | PixelFormat::Mono16 => {
            let word = |b: &[u8]| {
                if raw.little_endian {
                    u16::from_le_bytes([b[0], b[1]])
                } else {
                    u16::from_be_bytes([b[0], b[1]])
                }
            };
            Pixels::Mono16(rows.flat_map(|r| r.chunks_exact(2).map(word)).collect())
        }
    };
    Ok(Frame {
        width: w,
        height: h,
        bit_depth: format.bit_depth(),
        pixels,
        timestamp_s: raw.timestamp_us as f64 * 1e-6,
    })
}

/// The few device operations the grab policy needs.
pub(crate) trait IidcDevice {
    /// Start one exposure (a no-op for an external trigger).
    fn trigger(&mut self) -> Result<(), CameraError>;
    /// The oldest captured frame, handed back to the ring at once; `None` if there is none.
    fn poll(&mut self) -> Result<Option<RawFrame>, CameraError>;
    /// Host time on the clock of frame timestamps, µs since the Unix epoch.
    fn now_us(&self) -> u64;
    /// Wait a little before polling again.
    fn pause(&mut self, d: Duration);
}

/// The grab policy: a frame is returned only if it was captured after this grab's trigger and
/// after the last frame returned; frames still owed by timed-out grabs are waited for (bounded)
/// and thrown away first, since one of them arriving after the next trigger would pass the
/// time check.
#[derive(Debug, Clone, Default)]
pub(crate) struct GrabPolicy {
    owed: u32,
    last_us: Option<u64>,
}

impl GrabPolicy {
    pub(crate) fn grab(
        &mut self,
        dev: &mut dyn IidcDevice,
        plan: TriggerPlan,
        roi: Roi,
        format: PixelFormat,
        timeout: Duration,
    ) -> Result<Frame, CameraError> {
        let us = |d: Duration| d.as_micros().min(u128::from(u64::MAX / 2)) as u64;
        // Late frames of timed-out grabs, then whatever else is queued.
        let late_until = dev.now_us() + us(timeout.min(LATE_FRAME_WAIT));
        loop {
            match dev.poll()? {
                Some(_) => self.owed = self.owed.saturating_sub(1),
                None if self.owed == 0 || dev.now_us() >= late_until => break,
                None => dev.pause(POLL_INTERVAL),
            }
        }
        self.owed = 0;
        let trigger_us = dev.now_us();
        let deadline = trigger_us + us(timeout);
        dev.trigger()?;
        loop {
            match dev.poll()? {
                Some(mut raw) => {
                    // libdc1394 (juju) stamps a frame with the host time its transmission
                    // began, or 0 when it cannot read the bus cycle timer: no time check then
                    // (the drain above and the owed frames still apply), stamped on arrival.
                    if raw.timestamp_us == 0 {
                        raw.timestamp_us = dev.now_us().max(self.last_us.map_or(0, |l| l + 1));
                    } else if raw.timestamp_us < trigger_us
                        || self.last_us.is_some_and(|l| raw.timestamp_us <= l)
                    {
                        continue;
                    }
                    let frame = convert_frame(&raw, roi, format);
                    if frame.is_ok() {
                        self.last_us = Some(raw.timestamp_us);
                    }
                    return frame;
                }
                None if dev.now_us() >= deadline => {
                    if plan.driver_triggers() {
                        self.owed += 1;
                    }
                    return Err(CameraError::Timeout(timeout));
                }
                None => dev.pause(POLL_INTERVAL),
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::VecDeque;

    const ROI: Roi = Roi {
        x: 8,
        y: 4,
        width: 4,
        height: 2,
    };

    fn raw(ts: u64, data: Vec<u8>, coding: u32, stride: u32) -> RawFrame {
        RawFrame {
            timestamp_us: ts,
            width: ROI.width,
            height: ROI.height,
            position: (ROI.x, ROI.y),
            color_coding: coding,
            stride,
            little_endian: false,
            corrupt: false,
            data,
        }
    }

    #[test]
    fn format7_mode_is_the_lowest_one_offering_the_coding() {
        let modes = [64, 90, 89, 88];
        let mut codings = |m: u32| match m {
            88 => vec![COLOR_CODING_MONO8, 361],
            89 => vec![COLOR_CODING_MONO8, COLOR_CODING_MONO16],
            90 => vec![COLOR_CODING_MONO16],
            _ => panic!("asked the codings of non-Format7 mode {m}"),
        };
        assert_eq!(
            select_format7_mode(&modes, &mut codings, PixelFormat::Mono8).unwrap(),
            (88, COLOR_CODING_MONO8)
        );
        assert_eq!(
            select_format7_mode(&modes, &mut codings, PixelFormat::Mono16).unwrap(),
            (89, COLOR_CODING_MONO16)
        );
        let e = select_format7_mode(&[88], &mut |_| vec![COLOR_CODING_MONO8, 361], {
            PixelFormat::Mono16
        })
        .unwrap_err();
        assert!(
            e.0.contains("Mono16 is not offered") && e.0.contains("offered: Mono8"),
            "{e}"
        );
        let e = select_format7_mode(&[64, 70], &mut |_| vec![], PixelFormat::Mono8).unwrap_err();
        assert!(e.0.contains("no Format7 mode"), "{e}");
        assert!(select_format7_mode(&[88], &mut |_| vec![], PixelFormat::Mono12).is_err());
    }

    #[test]
    fn trigger_plan_prefers_the_software_source_then_one_shot() {
        let sw = [TRIGGER_SOURCE_0, TRIGGER_SOURCE_SOFTWARE];
        assert_eq!(
            plan_trigger(TriggerSource::Software, &sw, true).unwrap(),
            TriggerPlan::SoftwareSource
        );
        assert_eq!(
            plan_trigger(TriggerSource::Software, &[TRIGGER_SOURCE_0], true).unwrap(),
            TriggerPlan::OneShot
        );
        assert!(plan_trigger(TriggerSource::Software, &[TRIGGER_SOURCE_0], false).is_err());
        assert_eq!(
            plan_trigger(TriggerSource::External, &[], false).unwrap(),
            TriggerPlan::External
        );
        assert!(plan_trigger(TriggerSource::External, &[TRIGGER_SOURCE_SOFTWARE], true).is_err());
        assert!(TriggerPlan::OneShot.driver_triggers());
        assert!(!TriggerPlan::External.driver_triggers());
    }

    #[test]
    fn format7_units_become_roi_increments() {
        let g = Format7Geometry {
            max_width: 1292,
            max_height: 964,
            unit_width: 4,
            unit_height: 2,
            unit_x: 0,
            unit_y: 2,
        };
        let l = g.limits(vec!["Mono8".into()], (10.0, 6.7e7));
        assert_eq!((l.sensor_width, l.sensor_height), (1292, 964));
        assert_eq!(l.width_bounds, (4, 1292));
        // No offset unit reported: the width unit applies.
        assert_eq!((l.x_increment, l.y_increment), (4, 2));
        let mut cfg =
            crate::config::CameraConfig::new(crate::config::CameraId::Guid("0x1".into()), 100.0);
        cfg.backend = crate::config::CameraBackend::Firewire;
        cfg.roi = Some(Roi {
            x: 2,
            y: 0,
            width: 640,
            height: 480,
        });
        assert!(cfg
            .validate_against(&l)
            .unwrap_err()
            .0
            .contains("roi x = 2"));
        cfg.roi = Some(Roi {
            x: 4,
            y: 2,
            width: 642,
            height: 480,
        });
        assert!(cfg
            .validate_against(&l)
            .unwrap_err()
            .0
            .contains("roi width = 642"));
        cfg.roi = Some(Roi {
            x: 652,
            y: 484,
            width: 640,
            height: 480,
        });
        cfg.validate_against(&l).unwrap();
    }

    #[test]
    fn mono16_is_big_endian_unless_the_frame_says_little() {
        // Two rows of 4 pixels, words written big-endian by an independent encoder.
        let words: [u16; 8] = [0x0102, 0xfffe, 0x8000, 0x00ff, 1, 2, 3, 0xabcd];
        let be: Vec<u8> = words.iter().flat_map(|w| w.to_be_bytes()).collect();
        let f = convert_frame(
            &raw(5, be, COLOR_CODING_MONO16, 8),
            ROI,
            PixelFormat::Mono16,
        )
        .unwrap();
        assert_eq!(f.pixels, Pixels::Mono16(words.to_vec()));
        assert_eq!((f.width, f.height, f.bit_depth), (4, 2, 16));
        assert!((f.timestamp_s - 5e-6).abs() < 1e-12);

        let le: Vec<u8> = words.iter().flat_map(|w| w.to_le_bytes()).collect();
        let mut r = raw(5, le, COLOR_CODING_MONO16, 8);
        r.little_endian = true;
        let f = convert_frame(&r, ROI, PixelFormat::Mono16).unwrap();
        assert_eq!(f.pixels, Pixels::Mono16(words.to_vec()));
    }

    #[test]
    fn padded_lines_are_cut_to_the_roi_width() {
        // Stride 6 for 4 Mono8 pixels: 2 padding bytes per line (0xEE), none after the last.
        let data = vec![1, 2, 3, 4, 0xEE, 0xEE, 5, 6, 7, 8];
        let f = convert_frame(
            &raw(1, data, COLOR_CODING_MONO8, 6),
            ROI,
            PixelFormat::Mono8,
        )
        .unwrap();
        assert_eq!(f.pixels, Pixels::Mono8(vec![1, 2, 3, 4, 5, 6, 7, 8]));
        // One byte short of the last line.
        let e = convert_frame(
            &raw(1, vec![0; 9], COLOR_CODING_MONO8, 6),
            ROI,
            PixelFormat::Mono8,
        )
        .unwrap_err();
        assert!(matches!(e, CameraError::Incomplete(_)), "{e}");
    }

    #[test]
    fn wrong_geometry_coding_or_corruption_are_errors() {
        let ok = raw(1, vec![0; 8], COLOR_CODING_MONO8, 4);
        convert_frame(&ok, ROI, PixelFormat::Mono8).unwrap();
        let mut r = ok.clone();
        r.position = (0, 0);
        assert!(matches!(
            convert_frame(&r, ROI, PixelFormat::Mono8),
            Err(CameraError::Other(_))
        ));
        let mut r = ok.clone();
        r.color_coding = COLOR_CODING_MONO16;
        assert!(convert_frame(&r, ROI, PixelFormat::Mono8).is_err());
        let mut r = ok.clone();
        r.corrupt = true;
        assert!(matches!(
            convert_frame(&r, ROI, PixelFormat::Mono8),
            Err(CameraError::Incomplete(_))
        ));
    }

    /// A scripted camera on a simulated clock: each trigger schedules a frame `latency_us`
    /// later (or never, for dropped triggers); frames carry their capture time and the number
    /// of the trigger that made them in their first byte. Extra frames can be queued with an
    /// arrival time different from their stamp.
    struct Scripted {
        now: u64,
        latency_us: VecDeque<Option<u64>>,
        /// (arrival, stamp, trigger number)
        pending: Vec<(u64, u64, u8)>,
        triggers: u8,
    }

    impl Scripted {
        fn new(latencies: &[Option<u64>]) -> Self {
            Scripted {
                now: 1_000_000,
                latency_us: latencies.iter().copied().collect(),
                pending: Vec::new(),
                triggers: 0,
            }
        }
    }

    impl IidcDevice for Scripted {
        fn trigger(&mut self) -> Result<(), CameraError> {
            self.triggers += 1;
            if let Some(Some(l)) = self.latency_us.pop_front() {
                self.pending
                    .push((self.now + l, self.now + l, self.triggers));
            }
            Ok(())
        }
        fn poll(&mut self) -> Result<Option<RawFrame>, CameraError> {
            self.pending.sort_unstable();
            match self.pending.first() {
                Some(&(arrive, stamp, k)) if arrive <= self.now => {
                    self.pending.remove(0);
                    Ok(Some(raw(stamp, vec![k; 8], COLOR_CODING_MONO8, 4)))
                }
                _ => Ok(None),
            }
        }
        fn now_us(&self) -> u64 {
            self.now
        }
        fn pause(&mut self, d: Duration) {
            self.now += d.as_micros() as u64;
        }
    }

    fn trigger_of(f: &Frame) -> u8 {
        match &f.pixels {
            Pixels::Mono8(p) => p[0],
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn each_frame_answers_its_own_trigger_even_after_a_timeout() {
        // Trigger 1: 5 ms. Trigger 2: 103 ms, just after the 100 ms timeout, so it arrives
        // after trigger 3 was sent and before trigger 3's own frame (5 ms).
        let mut dev = Scripted::new(&[Some(5_000), Some(103_000), Some(5_000)]);
        let mut p = GrabPolicy::default();
        let t = Duration::from_millis(100);
        let grab = |dev: &mut Scripted, p: &mut GrabPolicy| {
            p.grab(dev, TriggerPlan::SoftwareSource, ROI, PixelFormat::Mono8, t)
        };
        assert_eq!(trigger_of(&grab(&mut dev, &mut p).unwrap()), 1);
        assert!(matches!(
            grab(&mut dev, &mut p),
            Err(CameraError::Timeout(_))
        ));
        // The late frame of trigger 2 arrives during the next grab: never returned as its frame.
        assert_eq!(trigger_of(&grab(&mut dev, &mut p).unwrap()), 3);
        assert_eq!(dev.triggers, 3);
    }

    #[test]
    fn an_external_trigger_timeout_owes_nothing() {
        let mut dev = Scripted::new(&[None]);
        let mut p = GrabPolicy::default();
        let t = Duration::from_millis(30);
        assert!(p
            .grab(&mut dev, TriggerPlan::External, ROI, PixelFormat::Mono8, t)
            .is_err());
        // The next pulse's frame, 1 ms into the next grab, is that grab's exposure.
        dev.pending.push((dev.now + 1_000, dev.now + 1_000, 7));
        let before = dev.now;
        let f = p
            .grab(&mut dev, TriggerPlan::External, ROI, PixelFormat::Mono8, t)
            .unwrap();
        assert_eq!(trigger_of(&f), 7);
        assert!(dev.now - before < 5_000, "no wait for an owed frame");
    }

    #[test]
    fn a_dropped_trigger_costs_one_timeout_and_a_bounded_wait() {
        let mut dev = Scripted::new(&[None, Some(2_000)]);
        let mut p = GrabPolicy::default();
        let t = Duration::from_millis(50);
        assert!(matches!(
            p.grab(&mut dev, TriggerPlan::OneShot, ROI, PixelFormat::Mono8, t),
            Err(CameraError::Timeout(_))
        ));
        let before = dev.now;
        let f = p
            .grab(&mut dev, TriggerPlan::OneShot, ROI, PixelFormat::Mono8, t)
            .unwrap();
        assert_eq!(trigger_of(&f), 2);
        // Waited for the owed frame at most min(timeout, LATE_FRAME_WAIT), then 2 ms.
        assert!(
            dev.now - before <= 50_000 + 2_000 + 2_000,
            "{}",
            dev.now - before
        );
    }

    #[test]
    fn unstamped_frames_are_taken_and_stamped_on_arrival() {
        let mut dev = Scripted::new(&[]);
        let t0 = dev.now;
        // A frame with no stamp (libdc1394 could not read the cycle timer), 2 ms in.
        dev.pending.push((t0 + 2_000, 0, 42));
        let mut p = GrabPolicy::default();
        let f = p
            .grab(
                &mut dev,
                TriggerPlan::SoftwareSource,
                ROI,
                PixelFormat::Mono8,
                Duration::from_millis(20),
            )
            .unwrap();
        assert_eq!(trigger_of(&f), 42);
        let ts = (f.timestamp_s * 1e6).round() as u64;
        assert!((t0 + 2_000..=t0 + 3_000).contains(&ts), "{ts}");
    }

    #[test]
    fn frames_stamped_before_the_trigger_or_not_after_the_last_are_skipped() {
        let mut dev = Scripted::new(&[Some(1_000)]);
        let t0 = dev.now;
        let mut p = GrabPolicy {
            owed: 0,
            last_us: Some(t0 + 700),
        };
        // Both arrive after the queue was drained and the trigger sent: one exposed before the
        // trigger, one not newer than the last frame returned.
        dev.pending.push((t0 + 500, t0 - 10, 98));
        dev.pending.push((t0 + 600, t0 + 700, 97));
        let f = p
            .grab(
                &mut dev,
                TriggerPlan::SoftwareSource,
                ROI,
                PixelFormat::Mono8,
                Duration::from_millis(20),
            )
            .unwrap();
        assert_eq!(trigger_of(&f), 1);
        assert_eq!(p.last_us, Some(t0 + 1_000));
        assert!(dev.pending.is_empty());
    }
}
