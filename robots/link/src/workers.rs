//! Bus workers: each bus of a [`crate::BusRobot`] serviced on its own thread, so the tick's I/O
//! phase costs the slowest bus, not the sum.
//!
//! The loop and a worker share no lock: one preallocated [`Slot`] (state, targets, timing) travels
//! with each request to the worker and back with its answer, through two one-place lock-free
//! queues; each side parks until the other unparks it. (Blocking channels allocate a waiter
//! context per wait; parking does not.) Nothing is allocated per tick.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::thread::Thread;
use std::time::{Duration, Instant};

use crossbeam::queue::ArrayQueue;

use crate::bus_robot::JointBus;
use crate::link::IoError;
use crate::state::{JointTarget, RobotState};

/// What a bus worker is asked to do.
#[derive(Debug, Clone, Copy)]
pub(crate) enum Op {
    Identify,
    Read,
    Write,
    TorqueOff,
}

/// The buffers one request carries: the state a read fills, the targets a write sends, and how
/// long the bus took.
#[derive(Debug)]
pub(crate) struct Slot {
    pub(crate) state: RobotState,
    pub(crate) targets: Vec<JointTarget>,
    pub(crate) elapsed: Duration,
}

/// A request, with the thread to wake when it is answered.
type Request = (Op, Box<Slot>, Thread);
type Answer = (Result<(), IoError>, Box<Slot>);

/// What the loop and one worker share.
#[derive(Debug)]
struct Mailbox {
    requests: ArrayQueue<Request>,
    answers: ArrayQueue<Answer>,
    stop: AtomicBool,
}

/// A bus serviced on its own thread.
#[derive(Debug)]
pub(crate) struct Worker {
    mailbox: Arc<Mailbox>,
    /// The slot, while the loop holds it (between requests).
    pub(crate) slot: Option<Box<Slot>>,
    pub(crate) joints: Vec<usize>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl Worker {
    /// Starts the thread `bus-{index}` for `bus` (its joints `joints` of `n`); `on_start` runs first
    /// on the new thread (real-time set-up, instrumentation).
    pub(crate) fn spawn(
        mut bus: Box<dyn JointBus>,
        joints: Vec<usize>,
        n: usize,
        index: usize,
        on_start: fn(),
    ) -> std::io::Result<Self> {
        let mailbox = Arc::new(Mailbox {
            requests: ArrayQueue::new(1),
            answers: ArrayQueue::new(1),
            stop: AtomicBool::new(false),
        });
        let shared = Arc::clone(&mailbox);
        let thread = std::thread::Builder::new()
            .name(format!("bus-{index}"))
            .spawn(move || {
                on_start();
                loop {
                    let Some((op, mut slot, waiting)) = shared.requests.pop() else {
                        if shared.stop.load(Ordering::Acquire) {
                            break;
                        }
                        std::thread::park();
                        continue;
                    };
                    let started = Instant::now();
                    let r = match op {
                        Op::Identify => bus.identify(),
                        Op::Read => bus.read(&mut slot.state),
                        Op::Write => bus.write(&slot.targets),
                        Op::TorqueOff => bus.torque_off(),
                    };
                    slot.elapsed = started.elapsed();
                    // One request is out at a time, so its answer always has a place.
                    let _ = shared.answers.push((r, slot));
                    waiting.unpark();
                }
            })?;
        Ok(Self {
            mailbox,
            slot: Some(Box::new(Slot {
                state: RobotState::new(n),
                targets: vec![JointTarget::default(); n],
                elapsed: Duration::ZERO,
            })),
            joints,
            thread: Some(thread),
        })
    }

    /// The slot, to fill targets before a write or read a state after a read.
    pub(crate) fn slot(&mut self) -> Option<&mut Slot> {
        self.slot.as_deref_mut()
    }

    /// Hands the slot to the worker with `op`.
    pub(crate) fn send(&mut self, op: Op) -> Result<(), IoError> {
        let stopped = || IoError::Setup("a bus thread stopped".into());
        let thread = self
            .thread
            .as_ref()
            .filter(|t| !t.is_finished())
            .ok_or_else(stopped)?;
        let slot = self.slot.take().ok_or_else(stopped)?;
        if let Err((_, slot, _)) = self.mailbox.requests.push((op, slot, std::thread::current())) {
            self.slot = Some(slot);
            return Err(stopped());
        }
        thread.thread().unpark();
        Ok(())
    }

    /// Waits for the worker's answer and takes the slot back.
    pub(crate) fn wait(&mut self) -> Result<(), IoError> {
        loop {
            if let Some((r, slot)) = self.mailbox.answers.pop() {
                self.slot = Some(slot);
                return r;
            }
            if self
                .thread
                .as_ref()
                .is_none_or(std::thread::JoinHandle::is_finished)
            {
                // The thread ended without answering (it panicked): its bus is gone.
                return Err(IoError::Setup("a bus thread stopped".into()));
            }
            // Parks until the worker unparks this thread (a spurious wake-up just loops).
            std::thread::park_timeout(Duration::from_millis(100));
        }
    }
}

impl Drop for Worker {
    fn drop(&mut self) {
        self.mailbox.stop.store(true, Ordering::Release);
        if let Some(t) = self.thread.take() {
            t.thread().unpark();
            let _ = t.join();
        }
    }
}
