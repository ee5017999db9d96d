//! Simulated camera: renders the PPP pattern at the stage's TRUE position at the instant of
//! each software trigger, with the optics and noise of [`csmetro_ppp::Optics`].
//!
//! The position comes from a [`PositionSource`] (any `FnMut() -> (x_um, y_um)` closure works),
//! normally the simulated stage's true position, so the decoded frame measures what the
//! stage really did, errors included.
use std::time::{Duration, Instant};

use csmetro_hal::{Camera, CameraError, Frame, PendingFrame};
use csmetro_ppp::render;
use csmetro_ppp::{Optics, Pattern, Pose};

/// The true stage position (µm) at the current instant.
pub trait PositionSource: Send {
    /// `(x, y)` true position now, µm.
    fn position_um(&mut self) -> (f64, f64);
}

impl<F: FnMut() -> (f64, f64) + Send> PositionSource for F {
    fn position_um(&mut self) -> (f64, f64) {
        self()
    }
}

/// An in-process camera looking at the pattern carried by the stage.
pub struct SimCamera {
    pattern: Pattern,
    optics: Optics,
    theta_mrad: f64,
    /// The carriage's rotation at the trigger, mrad, added to the fixed angle.
    rotation: Option<Box<dyn FnMut() -> f64 + Send>>,
    source: Box<dyn PositionSource>,
    seed: u64,
    frames: u64,
    t0: Instant,
}

impl SimCamera {
    /// A camera with `optics` looking at `pattern`; refuses optics it cannot render.
    pub fn new(
        pattern: Pattern,
        optics: Optics,
        source: Box<dyn PositionSource>,
    ) -> Result<Self, CameraError> {
        optics.validate().map_err(CameraError::Setting)?;
        Ok(Self {
            pattern,
            optics,
            theta_mrad: 0.0,
            rotation: None,
            source,
            seed: 0,
            frames: 0,
            t0: Instant::now(),
        })
    }

    /// In-plane angle of the pattern under the camera, mrad (fixed mounting error).
    pub fn with_theta_mrad(mut self, theta_mrad: f64) -> Self {
        self.theta_mrad = theta_mrad;
        self
    }

    /// Seed of the noise and dust (frame `k` uses `seed + k`, so runs are reproducible).
    pub fn with_seed(mut self, seed: u64) -> Self {
        self.seed = seed;
        self
    }

    /// Changes the optics (e.g. defocus, noise) for the following frames.
    pub fn set_optics(&mut self, optics: Optics) -> Result<(), CameraError> {
        optics.validate().map_err(CameraError::Setting)?;
        self.optics = optics;
        Ok(())
    }

    /// The optics used for the next frame.
    pub fn optics(&self) -> &Optics {
        &self.optics
    }

    /// The stage's in-plane rotation (mrad, sampled at each trigger) turns the pattern too.
    pub fn with_rotation(mut self, rotation_mrad: Box<dyn FnMut() -> f64 + Send>) -> Self {
        self.rotation = Some(rotation_mrad);
        self
    }

    /// The pattern's angle under the camera now, mrad.
    fn angle_mrad(&mut self) -> f64 {
        self.theta_mrad + self.rotation.as_mut().map_or(0.0, |r| r())
    }

    /// Frames delivered so far.
    pub fn frame_count(&self) -> u64 {
        self.frames
    }
}

impl Camera for SimCamera {
    /// Samples the true position at the trigger, renders, and fails with `Timeout` when the
    /// render took longer than `timeout` (a late frame is never delivered as if on time).
    fn grab(&mut self, timeout: Duration) -> Result<Frame, CameraError> {
        let start = Instant::now();
        let (x_um, y_um) = self.source.position_um();
        if !(x_um.is_finite() && y_um.is_finite()) {
            return Err(CameraError::Other(format!(
                "position source gave ({x_um}, {y_um})"
            )));
        }
        let timestamp_s = start.duration_since(self.t0).as_secs_f64();
        let pose = Pose::new(x_um, y_um, self.angle_mrad());
        let mut frame = render(
            &self.pattern,
            &self.optics,
            pose,
            self.seed.wrapping_add(self.frames),
        );
        self.frames += 1;
        if start.elapsed() > timeout {
            return Err(CameraError::Timeout(timeout));
        }
        frame.timestamp_s = timestamp_s;
        Ok(frame)
    }

    /// Samples the true position now and defers the rendering to the returned job.
    fn trigger(&mut self, timeout: Duration) -> Result<PendingFrame, CameraError> {
        let start = Instant::now();
        let (x_um, y_um) = self.source.position_um();
        if !(x_um.is_finite() && y_um.is_finite()) {
            return Err(CameraError::Other(format!(
                "position source gave ({x_um}, {y_um})"
            )));
        }
        let timestamp_s = start.duration_since(self.t0).as_secs_f64();
        let pose = Pose::new(x_um, y_um, self.angle_mrad());
        let (pattern, optics) = (self.pattern.clone(), self.optics.clone());
        let seed = self.seed.wrapping_add(self.frames);
        self.frames += 1;
        Ok(Box::new(move || {
            let t = Instant::now();
            let mut frame = render(&pattern, &optics, pose, seed);
            if t.elapsed() > timeout {
                return Err(CameraError::Timeout(timeout));
            }
            frame.timestamp_s = timestamp_s;
            Ok(frame)
        }))
    }

    fn describe(&self) -> String {
        format!(
            "simulated PPP camera {}x{} Mono{}, {} µm pixels, {}x objective, PSF {} px, noise {}",
            self.optics.width,
            self.optics.height,
            self.optics.bit_depth,
            self.optics.pixel_pitch_um,
            self.optics.magnification,
            self.optics.psf_sigma_px,
            self.optics.read_noise
        )
    }
}

#[cfg(test)]
mod tests {
    use std::sync::{Arc, Mutex};

    use csmetro_ppp::{DecodeConfig, Decoder, PatternConfig};

    use super::*;

    fn pattern() -> Pattern {
        Pattern::new(PatternConfig::default()).unwrap()
    }

    #[test]
    fn frames_show_the_true_position_at_each_trigger() {
        let truth = Arc::new(Mutex::new((1500.25, 2750.5)));
        let shared = truth.clone();
        let source = move || *shared.lock().unwrap();
        let optics = Optics::default();
        let mut cam = SimCamera::new(pattern(), optics.clone(), Box::new(source))
            .unwrap()
            .with_theta_mrad(4.0);
        let dec = Decoder::new(pattern(), DecodeConfig::for_optics(&pattern(), &optics));
        let mut last_t = -1.0;
        for (x, y) in [(1500.25, 2750.5), (8000.0, 100.0), (8000.3, 100.7)] {
            *truth.lock().unwrap() = (x, y);
            let f = cam.grab(Duration::from_secs(30)).unwrap();
            assert!(f.timestamp_s > last_t);
            last_t = f.timestamp_s;
            let r = dec.decode(&f);
            assert!(r.ok, "{:?}", r.reason);
            assert!(
                (r.x_um - x).abs() < 0.005 && (r.y_um - y).abs() < 0.005,
                "({}, {}) vs ({x}, {y})",
                r.x_um,
                r.y_um
            );
            assert!((r.theta_mrad - 4.0).abs() < 0.01);
        }
        assert_eq!(cam.frame_count(), 3);
    }

    #[test]
    fn successive_frames_have_fresh_noise_and_late_frames_time_out() {
        let mut cam =
            SimCamera::new(pattern(), Optics::default(), Box::new(|| (10.0, 10.0))).unwrap();
        let a = cam.grab(Duration::from_secs(30)).unwrap();
        let b = cam.grab(Duration::from_secs(30)).unwrap();
        assert_ne!(
            a.pixels, b.pixels,
            "read noise must differ between exposures"
        );
        assert!(matches!(
            cam.grab(Duration::ZERO),
            Err(CameraError::Timeout(_))
        ));
        let bad = Optics {
            bit_depth: 10,
            ..Optics::default()
        };
        assert!(matches!(cam.set_optics(bad), Err(CameraError::Setting(_))));
    }
}
