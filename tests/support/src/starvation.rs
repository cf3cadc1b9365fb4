//! How starved the host is while a real-time test runs, two ways: the kernel's CPU pressure
//! (`/proc/pressure/cpu`, the share of the time some runnable task waited for a core: about 0.2
//! while a real-time play runs on an idle 2-core machine, 0.8–1.0 with other work holding both
//! cores), and a thread that asks to wake every millisecond and notes how late it woke (within a
//! few hundred microseconds when idle, tens of milliseconds when starved). A starved host may make
//! a served mirror miss its answers and a real-time run stop, correctly. A test that needs real
//! time measures this beside its run and judges only unstarved runs.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::{Duration, Instant};

/// Wake-up lateness beyond which a real-time run of the project counts as starved: two cycles of
/// a 250 Hz bus.
pub const STARVED: Duration = Duration::from_millis(8);

/// CPU pressure (share of the time) beyond which a run counts as starved.
pub const STARVED_PRESSURE: f64 = 0.5;

/// What a meter saw.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Starvation {
    /// The worst wake-up lateness of a 1 ms sleep.
    pub worst_wake: Duration,
    /// The share of the time some runnable task waited for a core (none where the kernel does
    /// not report pressure).
    pub pressure: Option<f64>,
}

impl Starvation {
    /// Whether a real-time run beside it was starved.
    pub fn starved(&self) -> bool {
        self.worst_wake >= STARVED || self.pressure.is_some_and(|p| p > STARVED_PRESSURE)
    }
}

impl std::fmt::Display for Starvation {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "a 1 ms sleep woke {:.1} ms late",
            self.worst_wake.as_secs_f64() * 1e3
        )?;
        if let Some(p) = self.pressure {
            write!(f, ", tasks waited for a core {:.0} % of the time", p * 100.0)?;
        }
        Ok(())
    }
}

/// The kernel's total time (µs) some task waited for a CPU, if it reports it.
fn cpu_pressure_total_us() -> Option<u64> {
    let text = std::fs::read_to_string("/proc/pressure/cpu").ok()?;
    let some = text.lines().find(|l| l.starts_with("some "))?;
    some.split_whitespace()
        .find_map(|kv| kv.strip_prefix("total="))?
        .parse()
        .ok()
}

/// A running meter; [`StarvationMeter::stop`] gives what it saw.
#[derive(Debug)]
pub struct StarvationMeter {
    stop: Arc<AtomicBool>,
    worst_ns: Arc<AtomicU64>,
    thread: Option<std::thread::JoinHandle<()>>,
    started: Instant,
    pressure_at_start: Option<u64>,
}

impl StarvationMeter {
    /// Starts measuring.
    ///
    /// # Panics
    /// When no thread can be started.
    pub fn start() -> Self {
        let stop = Arc::new(AtomicBool::new(false));
        let worst_ns = Arc::new(AtomicU64::new(0));
        let (s, w) = (Arc::clone(&stop), Arc::clone(&worst_ns));
        let thread = std::thread::Builder::new()
            .name("starvation-meter".into())
            .spawn(move || {
                let period = Duration::from_millis(1);
                while !s.load(Ordering::Relaxed) {
                    let asked = Instant::now();
                    std::thread::sleep(period);
                    let late = asked.elapsed().saturating_sub(period);
                    w.fetch_max(late.as_nanos() as u64, Ordering::Relaxed);
                }
            })
            .expect("a thread for the starvation meter");
        Self {
            stop,
            worst_ns,
            thread: Some(thread),
            started: Instant::now(),
            pressure_at_start: cpu_pressure_total_us(),
        }
    }

    /// Stops measuring; what it saw.
    pub fn stop(mut self) -> Starvation {
        self.finish()
    }

    fn finish(&mut self) -> Starvation {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
        let wall_us = self.started.elapsed().as_secs_f64() * 1e6;
        let pressure = self
            .pressure_at_start
            .zip(cpu_pressure_total_us())
            .map(|(a, b)| (b.saturating_sub(a) as f64 / wall_us.max(1.0)).min(1.0));
        Starvation {
            worst_wake: Duration::from_nanos(self.worst_ns.load(Ordering::Relaxed)),
            pressure,
        }
    }
}

impl Drop for StarvationMeter {
    fn drop(&mut self) {
        self.finish();
    }
}

/// Runs `attempt` beside a [`StarvationMeter`] up to three times: the first result of an
/// unstarved attempt ([`Starvation::starved`]) is returned whatever it is; a starved
/// attempt's result is returned only when `acceptable` (a run that ended as it should), else it
/// is said and tried again. None, said, when every attempt was starved and failed.
pub fn judged_unstarved<T>(
    what: &str,
    mut attempt: impl FnMut() -> T,
    acceptable: impl Fn(&T) -> bool,
) -> Option<T> {
    for n in 1..=3 {
        let meter = StarvationMeter::start();
        let result = attempt();
        let seen = meter.stop();
        if !seen.starved() || acceptable(&result) {
            return Some(result);
        }
        eprintln!(
            "{what}, attempt {n}: the host was starved ({seen}) and the run did not end as it should: trying again"
        );
    }
    eprintln!("skipped: {what}: the host was starved in all 3 attempts");
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_run_is_starved_by_late_wake_ups_or_by_pressure() {
        let quiet = Starvation {
            worst_wake: Duration::from_micros(300),
            pressure: Some(0.2),
        };
        assert!(!quiet.starved());
        assert!(
            Starvation {
                pressure: Some(0.9),
                ..quiet
            }
            .starved()
        );
        assert!(
            Starvation {
                worst_wake: Duration::from_millis(12),
                pressure: None,
            }
            .starved()
        );
        assert_eq!(
            quiet.to_string(),
            "a 1 ms sleep woke 0.3 ms late, tasks waited for a core 20 % of the time"
        );
    }
}
