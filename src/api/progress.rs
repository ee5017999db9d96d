//! Elapsed time and ETA of the attempt the service is running: measured from the attempt's
//! first sample (start-up excluded), paused time left out.

/// When an attempt started and how fast it measures: the ETA's inputs.
#[derive(Debug, Clone, Copy, Default)]
pub(crate) struct Progress {
    /// Wall clock at launch, s since the epoch.
    pub(crate) started_unix_s: f64,
    /// Samples stored before this attempt.
    pub(crate) stored_at_start: u64,
    /// (wall clock, samples stored) at the attempt's first sample: the rate is measured from
    /// there, so the rig's start-up (connection, homing) does not slow it.
    pub(crate) first_sample: Option<(f64, u64)>,
    /// Time spent paused since the first sample, s, and when the current pause began.
    pub(crate) paused_s: f64,
    pub(crate) paused_since: Option<f64>,
}

impl Progress {
    pub(crate) fn new(stored_at_start: u64) -> Self {
        Progress {
            started_unix_s: crate::store::now_unix_s(),
            stored_at_start,
            ..Progress::default()
        }
    }

    pub(crate) fn pause(&mut self, now: f64) {
        self.paused_since.get_or_insert(now);
    }

    pub(crate) fn resume(&mut self, now: f64) {
        if let Some(t) = self.paused_since.take() {
            // Pauses before the first sample do not enter the rate.
            if self.first_sample.is_some() {
                self.paused_s += (now - t).max(0.0);
            }
        }
    }

    /// (elapsed_s, eta_s) at `now` with `stored` of `planned` samples committed.
    pub(crate) fn estimate(
        &self,
        now: f64,
        stored: u64,
        planned: u64,
        running: bool,
    ) -> (f64, Option<f64>) {
        let elapsed = (now - self.started_unix_s).max(0.0);
        let eta = self.first_sample.and_then(|(t0, n0)| {
            let paused = self.paused_s + self.paused_since.map_or(0.0, |p| (now - p).max(0.0));
            let dt = now - t0 - paused;
            let done = stored.saturating_sub(n0);
            if !running || done == 0 || dt <= 0.0 {
                return None;
            }
            let left = planned.saturating_sub(stored) as f64;
            Some(left * dt / done as f64)
        });
        (elapsed, eta)
    }
}

#[cfg(test)]
mod tests {
    use super::Progress;

    fn at(started: f64, stored_at_start: u64) -> Progress {
        Progress {
            started_unix_s: started,
            stored_at_start,
            ..Progress::default()
        }
    }

    #[test]
    fn eta_is_the_rate_since_the_first_sample_times_what_is_left() {
        // 10 s of start-up, then 2 samples/s after 100 resumed ones: 10 s in, 20 more stored.
        let mut p = at(1000.0, 100);
        assert_eq!(p.estimate(1005.0, 100, 200, true), (5.0, None));
        p.first_sample = Some((1010.0, 101));
        let (el, eta) = p.estimate(1020.0, 121, 200, true);
        assert_eq!(el, 20.0);
        // 20 samples in 10 s, 79 left: 39.5 s.
        assert!((eta.unwrap() - 39.5).abs() < 1e-9, "{eta:?}");
        // Not running (paused, reconstructing): no ETA; nothing left: 0.
        assert_eq!(p.estimate(1020.0, 121, 200, false).1, None);
        assert_eq!(p.estimate(1020.0, 200, 200, true).1, Some(0.0));
    }

    #[test]
    fn paused_time_does_not_slow_the_rate() {
        let mut p = at(0.0, 0);
        p.first_sample = Some((0.0, 1));
        p.pause(10.0);
        // While paused: the 50 s of pause so far are left out.
        let (_, eta) = p.estimate(60.0, 11, 21, true);
        assert!((eta.unwrap() - 10.0).abs() < 1e-9, "{eta:?}");
        p.resume(100.0);
        // 90 s paused; 20 s measuring (0-10 s, 100-110 s) for 40 samples: 2 samples/s,
        // 10 left: 5 s.
        let (el, eta) = p.estimate(110.0, 41, 51, true);
        assert_eq!(el, 110.0);
        assert!((eta.unwrap() - 5.0).abs() < 1e-9, "{eta:?}");
    }
}
