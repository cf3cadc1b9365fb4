//! Rate-limited warnings: a flood of bad input (junk datagrams, garbage on a socket) becomes one
//! log line per interval per kind, with the count of what was left out — never a line per packet.
//! The threads that take such input are on the safety path (e-stop) or serve devices; logging must
//! not be what slows them.

use std::time::{Duration, Instant};

/// One kind of warning, logged at most once per interval.
#[derive(Debug, Clone)]
pub struct RateLimit {
    interval: Duration,
    last: Option<Instant>,
    suppressed: u64,
}

impl RateLimit {
    /// At most one line per `interval`.
    pub const fn new(interval: Duration) -> Self {
        Self {
            interval,
            last: None,
            suppressed: 0,
        }
    }

    /// One line per second.
    pub const fn per_second() -> Self {
        Self::new(Duration::from_secs(1))
    }

    /// Whether a line may be written now; `Some(n)`: yes, with `n` occurrences left out since the
    /// last line. `None`: this occurrence is counted and left out.
    pub fn allow(&mut self, now: Instant) -> Option<u64> {
        if self.last.is_some_and(|t| now.duration_since(t) < self.interval) {
            self.suppressed += 1;
            return None;
        }
        self.last = Some(now);
        Some(std::mem::take(&mut self.suppressed))
    }
}

/// A [`RateLimit`] shared between threads that never waits: if another thread is deciding right
/// now, this occurrence is left out (a warning is not worth blocking a device thread for).
#[derive(Debug)]
pub struct SharedRateLimit(std::sync::Mutex<RateLimit>);

impl SharedRateLimit {
    /// At most one line per second.
    pub const fn per_second() -> Self {
        Self(std::sync::Mutex::new(RateLimit::per_second()))
    }

    /// [`RateLimit::allow`] at the current time, without waiting for the lock.
    pub fn allow_now(&self) -> Option<u64> {
        match self.0.try_lock() {
            Ok(mut l) => l.allow(Instant::now()),
            Err(std::sync::TryLockError::Poisoned(p)) => p.into_inner().allow(Instant::now()),
            Err(std::sync::TryLockError::WouldBlock) => None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_flood_becomes_one_line_per_interval_with_a_count() {
        let mut limit = RateLimit::per_second();
        let t0 = Instant::now();
        assert_eq!(limit.allow(t0), Some(0));
        for k in 1..=999u32 {
            assert_eq!(limit.allow(t0 + Duration::from_micros(u64::from(k))), None);
        }
        assert_eq!(limit.allow(t0 + Duration::from_millis(1001)), Some(999));
        assert_eq!(limit.allow(t0 + Duration::from_millis(1002)), None);
    }
}
