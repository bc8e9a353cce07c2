//! Waiting for the other process: busy-poll a few microseconds, then poll yielding the core
//! between polls, then sleep between polls, so a side that waits long does not starve the
//! other on a small machine.
//!
//! The pure spin is kept short on purpose: when the scheduler puts both processes on one
//! core, a spinning waiter keeps the other from running for the whole spin (a 50 µs spin
//! made every lockstep tick ~100 µs slower in that case); a yield hands the core over at
//! once and costs about a microsecond when the other process runs elsewhere.

use std::time::{Duration, Instant};

/// How long a wait spins before yielding, and yields before sleeping.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Waiter {
    started: Instant,
    /// Pure spinning up to here (default 5 µs).
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
            spin: Duration::from_micros(5),
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
