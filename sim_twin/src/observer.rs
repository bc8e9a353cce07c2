//! Watching a served twin: what a twin process (`amstack twin serve`) shows of its own truth
//! while another process flies it — the live view, a log. The servers call an observer on
//! their loop's thread after each reset and each step; an observer must not block (it copies
//! what it needs and hands it on).

use platform::ActuatorCommand;

use crate::Twin;

/// Hears a served twin's resets and steps.
pub trait TwinObserver: std::fmt::Debug {
    /// The twin was reset (a session or an episode starts, or the observer was just attached):
    /// `twin` holds the start state, its scene, its task.
    fn reset(&mut self, twin: &Twin) {
        let _ = twin;
    }

    /// The twin stepped one control period with `command`: `twin` holds the state after it.
    fn stepped(&mut self, twin: &Twin, command: &ActuatorCommand) {
        let _ = (twin, command);
    }
}
