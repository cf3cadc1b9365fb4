//! The tick clock: how a loop waits for its next tick, and what a simulated robot's clock can tell
//! besides the time.

use std::time::{Duration, Instant};

use crate::state::GroundTruth;

/// How the loop waits for the next tick and what ground truth it can see.
pub trait TickClock {
    /// Seconds since the run started.
    fn elapsed(&self) -> Duration;
    /// Waits until `deadline` (since the start); returns whether the deadline had already passed.
    fn wait_until(&mut self, deadline: Duration) -> bool;
    /// Simulation ground truth into `truth`, if this clock runs a simulation.
    fn ground_truth(&self, truth: &mut GroundTruth) -> bool;
}

/// The wall clock (hardware, or a mirror served in real time).
#[derive(Debug)]
pub struct WallClock {
    start: Instant,
    /// How long before a deadline sleeping stops and spinning starts.
    spin: Duration,
}

impl WallClock {
    /// Starts now.
    pub fn start() -> Self {
        Self::since(Instant::now())
    }

    /// Counting from `start`.
    pub fn since(start: Instant) -> Self {
        Self {
            start,
            // The scheduler's wake-up slack is ~50–100 µs.
            spin: Duration::from_micros(200),
        }
    }

    /// Sleeps all the way to each deadline (a wake-up may come ~100 µs late), leaving the CPU
    /// to others.
    pub fn without_spin(self) -> Self {
        Self {
            spin: Duration::ZERO,
            ..self
        }
    }
}

impl TickClock for WallClock {
    fn elapsed(&self) -> Duration {
        self.start.elapsed()
    }

    fn wait_until(&mut self, deadline: Duration) -> bool {
        let now = self.start.elapsed();
        if now >= deadline {
            return true;
        }
        // Sleep most of the way, then spin.
        let spin = self.spin;
        if deadline - now > spin {
            std::thread::sleep(deadline - now - spin);
        }
        while self.start.elapsed() < deadline {
            std::hint::spin_loop();
        }
        false
    }

    fn ground_truth(&self, _truth: &mut GroundTruth) -> bool {
        false
    }
}
