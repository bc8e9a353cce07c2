//! Realtime honesty: a twin on the wall clock that cannot keep up says so. Over each window of
//! wall time (1 s) the real-time factor is the twin time advanced divided by the wall time
//! elapsed; below [`SLOW_FACTOR`] the window is reported. The twin never skips a step to
//! catch up: it runs at the slower pace (its next step is due one period after the late
//! one), and with `--realtime-policy fail` the autopilot stops instead.
//!
//! Pure: wall and twin times arrive as arguments.

use std::time::{Duration, Instant};

/// A window slower than this fraction of the wall clock is reported.
pub const SLOW_FACTOR: f64 = 0.98;
/// The window, wall clock.
pub const WINDOW: Duration = Duration::from_secs(1);

/// What a slow realtime twin does.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum RealtimePolicy {
    /// Report the factor once per window and keep running at the slower pace.
    #[default]
    Warn,
    /// Stop serving with an error.
    Fail,
}

impl RealtimePolicy {
    /// `warn` or `fail`.
    pub fn parse(s: &str) -> Result<Self, String> {
        match s {
            "warn" => Ok(Self::Warn),
            "fail" => Ok(Self::Fail),
            other => Err(format!("'{other}': expected warn or fail")),
        }
    }
}

/// The real-time factor over wall-clock windows.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RealtimeMonitor {
    start: Option<(Instant, f64)>,
}

impl Default for RealtimeMonitor {
    fn default() -> Self {
        Self::new()
    }
}

impl RealtimeMonitor {
    /// Not started.
    pub fn new() -> Self {
        Self { start: None }
    }

    /// Forgets the window (the twin stopped running on the clock).
    pub fn reset(&mut self) {
        self.start = None;
    }

    /// At wall time `now` with the twin at `twin_time_s`: the window's factor when a window
    /// just closed and it was slower than [`SLOW_FACTOR`].
    pub fn update(&mut self, now: Instant, twin_time_s: f64) -> Option<f64> {
        let Some((t0, twin0)) = self.start else {
            self.start = Some((now, twin_time_s));
            return None;
        };
        let wall = now.duration_since(t0);
        if wall < WINDOW {
            return None;
        }
        self.start = Some((now, twin_time_s));
        let factor = (twin_time_s - twin0) / wall.as_secs_f64();
        (factor.is_finite() && factor < SLOW_FACTOR).then_some(factor)
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used, reason = "tests: a failed set-up fails loudly")]
mod tests {
    use super::*;

    #[test]
    fn a_slow_window_is_reported_once_and_a_fast_one_not_at_all() {
        let mut m = RealtimeMonitor::new();
        let t0 = Instant::now();
        assert_eq!(m.update(t0, 0.0), None);
        assert_eq!(m.update(t0 + Duration::from_millis(500), 0.45), None);
        let f = m.update(t0 + Duration::from_secs(1), 0.87).unwrap();
        assert!((f - 0.87).abs() < 1e-9);
        // The next window on time.
        assert_eq!(m.update(t0 + Duration::from_secs(2), 1.87), None);
        assert_eq!(RealtimePolicy::parse("fail"), Ok(RealtimePolicy::Fail));
        assert!(RealtimePolicy::parse("maybe").is_err());
    }
}
