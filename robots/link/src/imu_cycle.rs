//! The IMU line at its own rate: each poll drains what the line brought (so the adapter's buffer
//! never fills between policy ticks), keeps the newest sample in the base's axes and stamps when
//! it arrived. The policy tick reads the newest; in lockstep the poll is an event of the bus
//! schedule, on the wall clock a thread of its own.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use crossbeam::queue::ArrayQueue;
use firmware_bridge::imu::reader::ImuReader;
use firmware_bridge::imu::wit::ImuSample;
use firmware_bridge::serial::ByteStream;
use robots::spatial;
use triple_buffer::{Output, triple_buffer};

use crate::IMU_HISTORY;
use crate::clock::{TickClock, WallClock};

/// The newest IMU sample in the base's axes.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct ImuNewest {
    pub(crate) gyro: [f64; 3],
    pub(crate) accel: [f64; 3],
    pub(crate) quat: [f64; 4],
    /// Samples taken so far: a tick that sees the same count saw no new sample.
    pub(crate) count: u64,
    /// When the newest arrived (the link's time).
    pub(crate) arrived_at: Duration,
    /// The last [`IMU_HISTORY`] samples: sample number `c` sits at `c % IMU_HISTORY`.
    pub(crate) recent: [crate::ImuSample; IMU_HISTORY],
}

impl ImuNewest {
    /// The samples after number `seen` up to the newest, oldest first, into `out` (at most
    /// [`IMU_HISTORY`]: the newest of a longer gap).
    pub(crate) fn samples_since(&self, seen: u64, out: &mut Vec<crate::ImuSample>) {
        out.clear();
        let first = seen.max(self.count.saturating_sub(IMU_HISTORY as u64)) + 1;
        for c in first..=self.count {
            out.push(self.recent[(c % IMU_HISTORY as u64) as usize]);
        }
    }
}

impl Default for ImuNewest {
    fn default() -> Self {
        Self {
            gyro: [0.0; 3],
            accel: [0.0; 3],
            quat: [1.0, 0.0, 0.0, 0.0],
            count: 0,
            arrived_at: Duration::ZERO,
            recent: [crate::ImuSample::default(); IMU_HISTORY],
        }
    }
}

/// The newest IMU sample of a Unitree board's state, as its bus hands it over.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub(crate) struct BoardImu {
    pub(crate) sample: ImuSample,
    /// States taken so far: a poll that sees the same count saw no new sample.
    pub(crate) count: u64,
}

/// Where the IMU's samples come from.
#[derive(Debug)]
pub(crate) enum ImuInput<S: ByteStream> {
    /// A part streaming on its own line.
    Line {
        reader: Box<ImuReader<S>>,
        last: Option<S::Instant>,
    },
    /// The IMU in a Unitree board's state, from the bus that takes it.
    Board { newest: Output<BoardImu>, last: u64 },
}

/// The IMU's reader, its calibration and its poll period.
#[derive(Debug)]
pub(crate) struct ImuCycle<S: ByteStream> {
    input: ImuInput<S>,
    /// Mounting (IMU axes to base axes) and biases, from the robot's calibration.
    mount: [f64; 4],
    gyro_bias: [f64; 3],
    accel_bias: [f64; 3],
    pub(crate) period: Duration,
    pub(crate) newest: ImuNewest,
}

impl<S: ByteStream> ImuCycle<S> {
    pub(crate) fn new(
        input: ImuInput<S>,
        mounting_rpy_deg: [f64; 3],
        gyro_bias: [f64; 3],
        accel_bias: [f64; 3],
        period: Duration,
    ) -> Self {
        let [r, p, y] = mounting_rpy_deg.map(f64::to_radians);
        Self {
            input,
            mount: spatial::quat_of_rpy(r, p, y),
            gyro_bias,
            accel_bias,
            period,
            newest: ImuNewest::default(),
        }
    }

    /// Waits (bounded by `within` of the stream's clock) for the part's first sample, then keeps
    /// it, stamped `now`.
    /// (A board's IMU came with the bus's first state.)
    pub(crate) fn wait_first(&mut self, within: Duration, now: Duration) -> std::io::Result<()> {
        if let ImuInput::Line { reader, .. } = &mut self.input {
            reader.wait_first(within)?;
        }
        self.poll(now)
    }

    /// Drains the line (or looks at the board's newest); a new sample is kept, stamped `now`.
    pub(crate) fn poll(&mut self, now: Duration) -> std::io::Result<()> {
        let sample = match &mut self.input {
            ImuInput::Line { reader, last } => match reader.poll()? {
                Some(r) if Some(r.received_at) != *last => {
                    *last = Some(r.received_at);
                    Some(r.sample)
                }
                _ => None,
            },
            ImuInput::Board { newest, last } => {
                let b = *newest.read();
                (b.count != *last).then(|| {
                    *last = b.count;
                    b.sample
                })
            }
        };
        if let Some(sample) = sample {
            // Into the base's axes: bias off, then the mounting rotation.
            let m = self.mount;
            let n = &mut self.newest;
            n.gyro = spatial::quat_rotate(m, spatial::sub(sample.gyro, self.gyro_bias));
            n.accel = spatial::quat_rotate(m, spatial::sub(sample.accel, self.accel_bias));
            n.quat = spatial::quat_mul(sample.quat, spatial::quat_conj(m));
            n.count += 1;
            n.arrived_at = now;
            n.recent[(n.count % IMU_HISTORY as u64) as usize] = crate::ImuSample {
                gyro: n.gyro,
                accel: n.accel,
                quat: n.quat,
                at: now,
            };
        }
        Ok(())
    }
}

/// The IMU polled on a thread of its own, at its period on the wall clock.
#[derive(Debug)]
pub(crate) struct ImuWorker {
    newest: Output<ImuNewest>,
    errors: Arc<ArrayQueue<std::io::Error>>,
    stop: Arc<AtomicBool>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl ImuWorker {
    /// Starts the thread `imu` polling `cycle` from `epoch`; `on_start` runs first on it.
    pub(crate) fn spawn<S>(mut cycle: ImuCycle<S>, epoch: Instant, on_start: fn()) -> std::io::Result<Self>
    where
        S: ByteStream + Send + 'static,
        S::Instant: Send,
    {
        let (mut publish, newest) = triple_buffer(&cycle.newest);
        let errors = Arc::new(ArrayQueue::new(1));
        let stop = Arc::new(AtomicBool::new(false));
        let (shared_errors, shared_stop) = (Arc::clone(&errors), Arc::clone(&stop));
        let thread = std::thread::Builder::new().name("imu".into()).spawn(move || {
            on_start();
            let mut clock = WallClock::since(epoch).without_spin();
            let mut next = clock.elapsed();
            while !shared_stop.load(Ordering::Acquire) {
                clock.wait_until(next);
                if let Err(e) = cycle.poll(clock.elapsed()) {
                    let _ = shared_errors.push(e);
                }
                *publish.input_buffer_mut() = cycle.newest;
                publish.publish();
                next += cycle.period;
                // Polls that fell behind are not made up: the next one drains the line.
                next = next.max(clock.elapsed());
            }
        })?;
        Ok(Self {
            newest,
            errors,
            stop,
            thread: Some(thread),
        })
    }

    /// The newest sample the thread has.
    pub(crate) fn newest(&mut self) -> ImuNewest {
        *self.newest.read()
    }

    /// An error of the line since the last call, or that the thread ended.
    pub(crate) fn error(&self) -> Option<std::io::Error> {
        if let Some(e) = self.errors.pop() {
            return Some(e);
        }
        self.thread
            .as_ref()
            .is_none_or(std::thread::JoinHandle::is_finished)
            .then(|| std::io::Error::other("the IMU thread stopped"))
    }
}

impl Drop for ImuWorker {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Release);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}
