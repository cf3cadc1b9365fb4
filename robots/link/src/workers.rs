//! Bus workers: each bus of a [`crate::BusRobot`] cycling on its own thread at its own rate, on
//! absolute deadlines like the loop's.
//!
//! The loop and a worker share no lock: the policy's targets go to the worker and the worker's
//! newest complete state comes back through one triple buffer each way (`triple_buffer`: the
//! writer never waits, the reader always gets the newest whole value). Both sides copy into
//! buffers sized at start-up: nothing is allocated per cycle or per tick. A bus error travels
//! through a one-place lock-free queue.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use crossbeam::queue::ArrayQueue;
use triple_buffer::{Input, Output, triple_buffer};

use crate::clock::{TickClock, WallClock};
use crate::cycle::{BusStats, Cycler};
use crate::link::IoError;
use crate::state::{JointTarget, RobotState};

/// How long after the policy's first write the bus cycles' grid falls: room for the writes'
/// jitter from tick to tick.
const ALIGN_MARGIN: Duration = Duration::from_micros(200);

/// The policy's targets for a worker.
#[derive(Debug, Clone)]
pub(crate) struct Order {
    /// Increases with every write.
    pub(crate) seq: u64,
    /// When the policy issued them (since the link's epoch).
    pub(crate) issued_at: Duration,
    /// Robot order.
    pub(crate) targets: Vec<JointTarget>,
    /// Torque off, now (the end of a run, or a failed bus).
    pub(crate) torque_off: bool,
}

/// A worker's newest complete cycle.
#[derive(Debug, Clone)]
pub(crate) struct Published {
    pub(crate) state: RobotState,
    pub(crate) sampled_at: Vec<Duration>,
    pub(crate) stats: BusStats,
    /// The newest order the worker acted on.
    pub(crate) seen: u64,
    /// The newest torque-off order carried out.
    pub(crate) torque_off_done: u64,
}

/// A bus cycling on its own thread.
#[derive(Debug)]
pub(crate) struct Worker {
    pub(crate) joints: Vec<usize>,
    orders: Input<Order>,
    published: Output<Published>,
    errors: Arc<ArrayQueue<IoError>>,
    stop: Arc<AtomicBool>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl Worker {
    /// Starts the thread `bus-{index}` cycling `cycler` from `epoch`; `on_start` runs first on
    /// the new thread (real-time set-up, instrumentation).
    pub(crate) fn spawn(
        mut cycler: Cycler,
        epoch: Instant,
        index: usize,
        on_start: fn(),
    ) -> std::io::Result<Self> {
        let n = cycler.sent.len();
        let (orders, mut order_out) = triple_buffer(&Order {
            seq: 0,
            issued_at: Duration::ZERO,
            targets: vec![JointTarget::default(); n],
            torque_off: false,
        });
        let (mut publish, published) = triple_buffer(&Published {
            state: cycler.state.clone(),
            sampled_at: cycler.sampled_at.clone(),
            stats: cycler.stats,
            seen: 0,
            torque_off_done: 0,
        });
        let errors = Arc::new(ArrayQueue::new(1));
        let stop = Arc::new(AtomicBool::new(false));
        let joints = cycler.joints.clone();
        let (shared_errors, shared_stop) = (Arc::clone(&errors), Arc::clone(&stop));
        let thread = std::thread::Builder::new()
            .name(format!("bus-{index}"))
            .spawn(move || {
                on_start();
                // Sleep without the loop's final spin: a bus cycle starting 100 µs late costs
                // nothing, and two cores are shared with the mirror and the loop.
                let mut clock = WallClock::since(epoch).without_spin();
                let period = cycler.timing.period;
                let mut next = clock.elapsed();
                let mut aligned = false;
                let mut torque_off_done = 0;
                let report = |r: Result<(), IoError>| {
                    if let Err(e) = r {
                        // The loop reads one at a time; while one waits, later ones add nothing.
                        let _ = shared_errors.push(e);
                    }
                };
                while !shared_stop.load(Ordering::Acquire) {
                    clock.wait_until(next);
                    let order = order_out.read();
                    cycler.take_order(order.seq, order.issued_at, &order.targets);
                    if order.torque_off && order.seq != torque_off_done {
                        report(cycler.bus.torque_off());
                        torque_off_done = order.seq;
                    }
                    let seen = order.seq;
                    let issued_at = order.issued_at;
                    let now = clock.elapsed();
                    report(cycler.start(now));
                    report(cycler.finish(|| clock.elapsed()));
                    let out = publish.input_buffer_mut();
                    out.state.copy_from(&cycler.state);
                    out.sampled_at.copy_from_slice(&cycler.sampled_at);
                    out.stats = cycler.stats;
                    out.seen = seen;
                    out.torque_off_done = torque_off_done;
                    publish.publish();
                    // The next slot on the grid; slots that passed while this cycle ran are lost.
                    next += period;
                    let late = clock.elapsed();
                    if !aligned && seen > 0 {
                        // The grid moves to just after the policy's writes (which come on the
                        // policy's own absolute deadlines): new targets go out within a margin of
                        // being issued, not up to a bus period later.
                        aligned = true;
                        let origin = issued_at + ALIGN_MARGIN.min(period / 10);
                        let slots = late.saturating_sub(origin).as_nanos() / period.as_nanos() + 1;
                        next = origin + period * slots as u32;
                    } else if next <= late {
                        let behind = (late - next).as_nanos() / period.as_nanos() + 1;
                        cycler.stats.overruns += behind as u64;
                        next += period * behind as u32;
                    }
                }
            })?;
        Ok(Self {
            joints,
            orders,
            published,
            errors,
            stop,
            thread: Some(thread),
        })
    }

    /// Hands the worker targets number `seq` (robot order).
    pub(crate) fn order(&mut self, seq: u64, issued_at: Duration, targets: &[JointTarget], torque_off: bool) {
        let o = self.orders.input_buffer_mut();
        o.seq = seq;
        o.issued_at = issued_at;
        o.targets.copy_from_slice(targets);
        o.torque_off = torque_off;
        self.orders.publish();
    }

    /// The worker's newest complete cycle.
    pub(crate) fn newest(&mut self) -> &Published {
        self.published.read()
    }

    /// The worker's joints (robot indices) and its newest complete cycle.
    pub(crate) fn joints_and_newest(&mut self) -> (&[usize], &Published) {
        (&self.joints, self.published.read())
    }

    /// A bus error the worker met since the last call, or that its thread ended.
    pub(crate) fn error(&self) -> Option<IoError> {
        if let Some(e) = self.errors.pop() {
            return Some(e);
        }
        self.thread
            .as_ref()
            .is_none_or(std::thread::JoinHandle::is_finished)
            .then(|| IoError::Setup("a bus thread stopped".into()))
    }
}

impl Drop for Worker {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Release);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}
