//! Waiting for the other process: busy-poll first (a round trip costs microseconds), then
//! yield the core, then sleep, so a side that waits long does not starve the other on a
//! small machine.

use std::time::{Duration, Instant};

/// How long a wait spins before yielding, and yields before sleeping.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Waiter {
    started: Instant,
    /// Pure spinning up to here (default 50 µs).
    pub spin: Duration,
    /// Yielding the core up to here (default 2 ms), then sleeping `sleep` per poll.
    pub yield_until: Duration,
    /// Sleep per poll after that (default 50 µs).
    pub sleep: Duration,
}

impl Waiter {
    /// A wait starting now, with the default phases.
    pub fn start() -> Self {
        Self {
            started: Instant::now(),
            spin: Duration::from_micros(50),
            yield_until: Duration::from_millis(2),
            sleep: Duration::from_micros(50),
        }
    }

    /// Time waited so far.
    pub fn elapsed(&self) -> Duration {
        self.started.elapsed()
    }

    /// One pause between two polls.
    pub fn pause(&self) {
        let waited = self.elapsed();
        if waited < self.spin {
            std::hint::spin_loop();
        } else if waited < self.yield_until {
            std::thread::yield_now();
        } else {
            std::thread::sleep(self.sleep);
        }
    }
}
