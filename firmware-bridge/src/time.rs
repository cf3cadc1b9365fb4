//! Simulated time for mock buses and emulated firmware: the [`SimInstant`] clock, the
//! [`SimWorld`] that owns it (advanced by host ports in lockstep), the [`WallClockRunner`] that
//! runs a world in real time, and the seeded [`SimRng`].
//!
//! Transports name their own `Instant` type (see [`crate::can::CanBus`]): hardware uses
//! [`std::time::Instant`], mock buses in lockstep use [`SimInstant`], so the same driver code runs
//! on the robot, against the mirror, and in replay.

use std::ops::{Add, Sub};
use std::time::Duration;

/// A point on a simulated clock, in nanoseconds since the simulation started.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Default)]
pub struct SimInstant(u64);

impl SimInstant {
    /// The start of simulated time.
    pub const ZERO: Self = Self(0);

    /// `nanos` after the start.
    pub const fn from_nanos(nanos: u64) -> Self {
        Self(nanos)
    }

    /// Nanoseconds since the start.
    pub const fn as_nanos(self) -> u64 {
        self.0
    }

    /// Seconds since the start.
    pub fn as_secs_f64(self) -> f64 {
        self.0 as f64 * 1e-9
    }

    /// Time since `earlier`, or zero when `earlier` is later.
    pub fn saturating_since(self, earlier: Self) -> Duration {
        Duration::from_nanos(self.0.saturating_sub(earlier.0))
    }
}

impl Add<Duration> for SimInstant {
    type Output = Self;
    fn add(self, d: Duration) -> Self {
        Self(
            self.0
                .saturating_add(u64::try_from(d.as_nanos()).unwrap_or(u64::MAX)),
        )
    }
}

impl Sub for SimInstant {
    type Output = Duration;
    /// Saturating difference: a later `rhs` gives zero.
    fn sub(self, rhs: Self) -> Duration {
        self.saturating_since(rhs)
    }
}

/// Operations a transport's `Instant` type offers the drivers.
pub trait BusInstant:
    Copy + Ord + Add<Duration, Output = Self> + Sub<Output = Duration> + std::fmt::Debug
{
}

impl BusInstant for SimInstant {}
impl BusInstant for std::time::Instant {}

/// A small deterministic PRNG (SplitMix64) for noise and fault injection: same seed, same run.
#[derive(Debug, Clone)]
pub struct SimRng(u64);

impl SimRng {
    /// A generator seeded with `seed`.
    pub const fn new(seed: u64) -> Self {
        Self(seed)
    }

    /// The next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in `[0, 1)`.
    pub fn next_f64(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
    }

    /// True with probability `p`.
    pub fn chance(&mut self, p: f64) -> bool {
        p > 0.0 && self.next_f64() < p
    }

    /// Standard normal (Box–Muller).
    pub fn gaussian(&mut self) -> f64 {
        let u1 = self.next_f64().max(f64::MIN_POSITIVE);
        let u2 = self.next_f64();
        (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
    }
}

/// A simulated world that owns time: physics, firmware and the wires between them.
///
/// Host ports advance it only while the controller waits, so simulated time moves in lockstep
/// with the controller, deterministically.
pub trait SimWorld {
    /// The world's clock.
    fn now(&self) -> SimInstant;

    /// Runs the world's next event if it is due no later than `limit`, else moves the clock to
    /// `limit`. Returns the new time.
    fn step_until(&mut self, limit: SimInstant) -> SimInstant;
}

/// Puts the calling thread under SCHED_FIFO at `priority` (1–99): the kernel runs it before every
/// normally scheduled thread. Refused without CAP_SYS_NICE or an rtprio limit that allows it.
pub fn set_fifo_priority(priority: i32) -> std::io::Result<()> {
    let param = libc::sched_param {
        sched_priority: priority,
    };
    #[allow(unsafe_code, reason = "one POSIX call with plain-value arguments")]
    // SAFETY: pid 0 is the calling thread; `param` is a valid sched_param.
    let r = unsafe { libc::sched_setscheduler(0, libc::SCHED_FIFO, &param) };
    if r == 0 {
        Ok(())
    } else {
        Err(std::io::Error::last_os_error())
    }
}

/// The SCHED_FIFO priority of a served mirror's threads (its physics, its servers): above every
/// normal thread, so a busy host does not slow the simulated robot down (a real robot's firmware
/// runs on its own chips), below a `--realtime` controller's loop (80) and bus threads (85).
pub const MIRROR_PRIORITY: i32 = 60;

/// Asks for [`MIRROR_PRIORITY`] for the calling thread of a served mirror; where the host refuses
/// (no CAP_SYS_NICE), says so once and runs on at normal priority — its lateness is then measured
/// ([`StarvationProbe`]) and named.
pub fn serve_in_real_time() {
    static SAID: std::sync::Once = std::sync::Once::new();
    if let Err(e) = set_fifo_priority(MIRROR_PRIORITY) {
        SAID.call_once(|| {
            tracing::info!(
                "the served mirror's threads run at normal priority (SCHED_FIFO {MIRROR_PRIORITY} refused: {e}): \
                 a busy host delays them; grant CAP_SYS_NICE or an rtprio limit to keep them on time"
            );
        });
    }
}

/// Runs a simulated world in real time on its own thread, for serving it over real wires
/// (socketcand, pseudo-terminals) to a controller in another process.
#[derive(Debug)]
pub struct WallClockRunner {
    stop: std::sync::Arc<std::sync::atomic::AtomicBool>,
    thread: Option<std::thread::JoinHandle<()>>,
    start: std::time::Instant,
}

impl WallClockRunner {
    /// Starts stepping `world` so that its clock follows the wall clock from now on, checking
    /// every `resolution`.
    pub fn spawn<W: SimWorld + Send + 'static>(
        world: std::sync::Arc<std::sync::Mutex<W>>,
        resolution: Duration,
    ) -> std::io::Result<Self> {
        let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
        let start = std::time::Instant::now();
        let flag = std::sync::Arc::clone(&stop);
        let thread = std::thread::Builder::new()
            .name("sim-wall-clock".into())
            .spawn(move || {
                serve_in_real_time();
                let origin = world
                    .lock()
                    .unwrap_or_else(std::sync::PoisonError::into_inner)
                    .now();
                while !flag.load(std::sync::atomic::Ordering::Relaxed) {
                    let target = origin + start.elapsed();
                    {
                        let mut w = world.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
                        while w.now() < target {
                            w.step_until(target);
                        }
                    }
                    std::thread::sleep(resolution);
                }
            })?;
        Ok(Self {
            stop,
            thread: Some(thread),
            start,
        })
    }

    /// Wall time since the runner started: the timestamp for frames served to clients.
    pub fn elapsed(&self) -> Duration {
        self.start.elapsed()
    }
}

/// How long this host keeps a normal thread waiting beyond a 1 ms sleep: a probe thread beside a
/// served mirror's threads (its physics, its serial and CAN servers), which wait as long. A mirror
/// whose threads are held off the CPU answers that much late, however fast its physics is.
#[derive(Debug)]
pub struct StarvationProbe {
    shared: std::sync::Arc<ProbeShared>,
    thread: Option<std::thread::JoinHandle<()>>,
}

#[derive(Debug)]
struct ProbeShared {
    start: std::time::Instant,
    stop: std::sync::atomic::AtomicBool,
    /// The worst wait of the current and the previous window, µs (slot = window index % 2).
    worst_us: [std::sync::atomic::AtomicU64; 2],
    /// When the probe last woke, µs since `start`.
    woke_us: std::sync::atomic::AtomicU64,
}

/// The probe's sleep and the window its worst waits are kept over.
const PROBE_SLEEP: Duration = Duration::from_millis(1);
const PROBE_WINDOW_US: u64 = 250_000;

fn micros(d: Duration) -> u64 {
    u64::try_from(d.as_micros()).unwrap_or(u64::MAX)
}

impl StarvationProbe {
    /// Starts probing.
    pub fn spawn() -> std::io::Result<Self> {
        use std::sync::atomic::Ordering::Relaxed;
        let shared = std::sync::Arc::new(ProbeShared {
            start: std::time::Instant::now(),
            stop: std::sync::atomic::AtomicBool::new(false),
            worst_us: Default::default(),
            woke_us: std::sync::atomic::AtomicU64::new(0),
        });
        let s = std::sync::Arc::clone(&shared);
        let thread = std::thread::Builder::new()
            .name("mirror-probe".into())
            .spawn(move || {
                // At the mirror's threads' priority: it waits as they do.
                serve_in_real_time();
                let mut window = 0;
                while !s.stop.load(Relaxed) {
                    let asked = std::time::Instant::now();
                    std::thread::sleep(PROBE_SLEEP);
                    let late_us = micros(asked.elapsed().saturating_sub(PROBE_SLEEP));
                    let now_us = micros(s.start.elapsed());
                    let this = now_us / PROBE_WINDOW_US;
                    let slot = &s.worst_us[usize::from(this % 2 == 1)];
                    if this == window {
                        slot.fetch_max(late_us, Relaxed);
                    } else {
                        window = this;
                        slot.store(late_us, Relaxed);
                    }
                    s.woke_us.store(now_us, Relaxed);
                }
            })?;
        Ok(Self {
            shared,
            thread: Some(thread),
        })
    }

    /// A handle that reads the probe from another thread.
    pub fn reader(&self) -> StarvationReader {
        StarvationReader {
            shared: std::sync::Arc::clone(&self.shared),
        }
    }
}

/// Reads a [`StarvationProbe`].
#[derive(Debug, Clone)]
pub struct StarvationReader {
    shared: std::sync::Arc<ProbeShared>,
}

impl StarvationReader {
    /// The longest a normal thread waited beyond its wake-up over the last quarter to half a
    /// second, or has been waiting now.
    pub fn recent(&self) -> Duration {
        use std::sync::atomic::Ordering::Relaxed;
        let s = &self.shared;
        let worst = s.worst_us[0].load(Relaxed).max(s.worst_us[1].load(Relaxed));
        let waiting = micros(s.start.elapsed())
            .saturating_sub(s.woke_us.load(Relaxed))
            .saturating_sub(micros(PROBE_SLEEP));
        Duration::from_micros(worst.max(waiting))
    }
}

impl Drop for StarvationProbe {
    fn drop(&mut self) {
        self.shared.stop.store(true, std::sync::atomic::Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

impl Drop for WallClockRunner {
    fn drop(&mut self) {
        self.stop.store(true, std::sync::atomic::Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sim_instant_arithmetic_saturates() {
        let t = SimInstant::from_nanos(1_000) + Duration::from_micros(2);
        assert_eq!(t.as_nanos(), 3_000);
        assert_eq!(t - SimInstant::from_nanos(500), Duration::from_nanos(2_500));
        assert_eq!(SimInstant::ZERO - t, Duration::ZERO);
    }

    #[test]
    fn rng_is_deterministic_and_uniform_enough() {
        let (mut a, mut b) = (SimRng::new(42), SimRng::new(42));
        let xs: Vec<f64> = (0..10_000).map(|_| a.next_f64()).collect();
        assert!(
            xs.iter()
                .zip((0..10_000).map(|_| b.next_f64()))
                .all(|(x, y)| x.to_bits() == y.to_bits())
        );
        let mean = xs.iter().sum::<f64>() / xs.len() as f64;
        assert!((mean - 0.5).abs() < 0.02, "{mean}");
        assert!(xs.iter().all(|x| (0.0..1.0).contains(x)));
        assert_ne!(SimRng::new(1).next_u64(), SimRng::new(2).next_u64());
    }
}
