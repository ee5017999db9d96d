//! In-process camera drawing its frames from a closure: the simulated twin of a real camera,
//! and a mock for tests (errors can be queued).
use std::collections::VecDeque;
use std::sync::Arc;
use std::time::{Duration, Instant};

use csmetro_hal::{Camera, CameraError, Frame, Pixels};

use crate::config::PixelFormat;

/// Draws one frame into a row-major buffer of `width * height` pixels: one byte per pixel for
/// Mono8, two little-endian bytes per pixel for Mono12/Mono16 (`buf.len() / (width * height)`
/// tells which). Called on the camera's thread, so it must be quick and must not block for long.
pub type FrameSource = Arc<dyn Fn(&mut [u8], usize, usize) + Send + Sync>;

/// A [`Camera`] whose every grab calls its [`FrameSource`] once.
pub struct SourceCamera {
    source: FrameSource,
    width: usize,
    height: usize,
    format: PixelFormat,
    start: Instant,
    frames: u64,
    faults: VecDeque<CameraError>,
    name: String,
}

impl std::fmt::Debug for SourceCamera {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SourceCamera")
            .field("name", &self.name)
            .field("frames", &self.frames)
            .field("queued_faults", &self.faults.len())
            .finish_non_exhaustive()
    }
}

impl SourceCamera {
    /// A `width` x `height` camera delivering `format` frames drawn by `source`.
    pub fn new(width: usize, height: usize, format: PixelFormat, source: FrameSource) -> Self {
        SourceCamera {
            source,
            width,
            height,
            format,
            start: Instant::now(),
            frames: 0,
            faults: VecDeque::new(),
            name: format!("in-process source camera {width}x{height} {format:?}"),
        }
    }

    /// Make a later grab fail: queued errors are returned first, one per grab, in order
    /// (to test how callers handle timeouts, incomplete frames, disconnects).
    pub fn push_fault(&mut self, error: CameraError) {
        self.faults.push_back(error);
    }

    /// Frames delivered so far.
    pub fn frames(&self) -> u64 {
        self.frames
    }

    /// Replace the frame source (e.g. to move the simulated stage's pattern).
    pub fn set_source(&mut self, source: FrameSource) {
        self.source = source;
    }
}

impl Camera for SourceCamera {
    fn grab(&mut self, _timeout: Duration) -> Result<Frame, CameraError> {
        if let Some(e) = self.faults.pop_front() {
            return Err(e);
        }
        let n = self.width * self.height;
        let mut buf = vec![0u8; n * self.format.bytes_per_pixel()];
        // A panicking source is a bug in the caller's renderer, not a camera fault: report it
        // as an error rather than tearing down the service thread.
        let drawn = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
            (self.source)(&mut buf, self.width, self.height)
        }));
        if drawn.is_err() {
            return Err(CameraError::Other("frame source panicked".into()));
        }
        self.frames += 1;
        let pixels = match self.format {
            PixelFormat::Mono8 => Pixels::Mono8(buf),
            PixelFormat::Mono12 | PixelFormat::Mono16 => Pixels::Mono16(
                buf.chunks_exact(2)
                    .map(|b| u16::from_le_bytes([b[0], b[1]]))
                    .collect(),
            ),
        };
        Ok(Frame {
            width: self.width,
            height: self.height,
            bit_depth: self.format.bit_depth(),
            pixels,
            timestamp_s: self.start.elapsed().as_secs_f64(),
        })
    }

    fn describe(&self) -> String {
        self.name.clone()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::atomic::{AtomicU64, Ordering};

    fn counter_source() -> (FrameSource, Arc<AtomicU64>) {
        let n = Arc::new(AtomicU64::new(0));
        let n2 = n.clone();
        let src: FrameSource = Arc::new(move |buf: &mut [u8], w: usize, _h: usize| {
            let k = n2.fetch_add(1, Ordering::SeqCst);
            for (i, p) in buf.iter_mut().enumerate() {
                *p = ((i % w) as u64 + 3 * (i / w) as u64 + k) as u8;
            }
        });
        (src, n)
    }

    #[test]
    fn mono8_frames_are_what_the_source_drew_one_call_per_grab() {
        let (src, calls) = counter_source();
        let mut cam = SourceCamera::new(7, 5, PixelFormat::Mono8, src);
        let mut last_t = -1.0;
        for k in 0..3u64 {
            let f = cam.grab(Duration::from_millis(10)).unwrap();
            assert_eq!((f.width, f.height, f.bit_depth), (7, 5, 8));
            let Pixels::Mono8(p) = &f.pixels else {
                panic!("expected Mono8")
            };
            assert_eq!(p.len(), 35);
            assert_eq!(p[0], k as u8);
            assert_eq!(p[7 + 2], (2 + 3 + k) as u8);
            assert!(f.timestamp_s > last_t);
            last_t = f.timestamp_s;
        }
        assert_eq!(calls.load(Ordering::SeqCst), 3);
        assert_eq!(cam.frames(), 3);
    }

    #[test]
    fn mono12_is_little_endian_words_with_bit_depth_12() {
        let src: FrameSource = Arc::new(|buf: &mut [u8], _w, _h| {
            for (i, px) in buf.chunks_exact_mut(2).enumerate() {
                px.copy_from_slice(&((i as u16 * 1000) & 0x0fff).to_le_bytes());
            }
        });
        let mut cam = SourceCamera::new(4, 1, PixelFormat::Mono12, src);
        let f = cam.grab(Duration::from_millis(10)).unwrap();
        assert_eq!(f.bit_depth, 12);
        assert_eq!(f.pixels, Pixels::Mono16(vec![0, 1000, 2000, 3000]));
        assert_eq!(f.to_f32(), vec![0.0, 1000.0, 2000.0, 3000.0]);
    }

    #[test]
    fn queued_faults_come_first_then_frames_resume() {
        let (src, calls) = counter_source();
        let mut cam = SourceCamera::new(2, 2, PixelFormat::Mono8, src);
        cam.push_fault(CameraError::Timeout(Duration::from_millis(5)));
        cam.push_fault(CameraError::Incomplete("missing packets".into()));
        assert!(matches!(
            cam.grab(Duration::ZERO),
            Err(CameraError::Timeout(_))
        ));
        assert!(matches!(
            cam.grab(Duration::ZERO),
            Err(CameraError::Incomplete(_))
        ));
        assert_eq!(
            calls.load(Ordering::SeqCst),
            0,
            "a faulted grab draws nothing"
        );
        assert!(cam.grab(Duration::ZERO).is_ok());
    }

    #[test]
    fn a_panicking_source_is_an_error_not_a_crash() {
        let src: FrameSource = Arc::new(|_b: &mut [u8], _w, _h| panic!("renderer bug"));
        let mut cam = SourceCamera::new(2, 2, PixelFormat::Mono8, src);
        assert!(matches!(
            cam.grab(Duration::ZERO),
            Err(CameraError::Other(_))
        ));
        let (ok, _) = counter_source();
        cam.set_source(ok);
        assert!(cam.grab(Duration::ZERO).is_ok());
    }

    #[test]
    fn is_usable_as_a_boxed_camera() {
        let (src, _) = counter_source();
        let mut cam: Box<dyn Camera> = Box::new(SourceCamera::new(3, 2, PixelFormat::Mono8, src));
        assert!(cam.describe().contains("3x2"));
        assert_eq!(cam.grab(Duration::ZERO).unwrap().to_f32().len(), 6);
    }
}
