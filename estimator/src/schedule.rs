//! A sensor's sample schedule on a float clock: a sample is due on the first call at or after
//! each scheduled time, the next one a period after the scheduled one (one period from now
//! after a long pause), as the pose sensor captures.

use crate::sensors::TIME_EPSILON_S;

/// When the next sample of a sensor at a fixed rate is due.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub(crate) struct Schedule {
    next_s: Option<f64>,
}

impl Schedule {
    /// Whether a sample is due at `time_s` for a sensor of period `period_s`; if so, the
    /// schedule moves on one period.
    pub(crate) fn due(&mut self, time_s: f64, period_s: f64) -> bool {
        let due = self.next_s.unwrap_or(time_s);
        if time_s + TIME_EPSILON_S < due {
            return false;
        }
        let next = due + period_s;
        self.next_s = Some(if next + TIME_EPSILON_S < time_s {
            time_s + period_s
        } else {
            next
        });
        true
    }
}
