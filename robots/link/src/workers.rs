//! Bus workers: each bus of a [`crate::BusRobot`] serviced on its own thread, so the tick's I/O
//! phase costs the slowest bus, not the sum.

use std::sync::{Arc, Mutex, PoisonError};
use std::time::{Duration, Instant};

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

/// Buffers a worker and the loop share.
#[derive(Debug)]
pub(crate) struct Slot {
    pub(crate) state: RobotState,
    pub(crate) targets: Vec<JointTarget>,
    pub(crate) elapsed: Duration,
}

/// A bus serviced on its own thread, so the I/O phase costs the slowest bus, not the sum.
#[derive(Debug)]
pub(crate) struct Worker {
    pub(crate) ops: Option<crossbeam::channel::Sender<Op>>,
    pub(crate) done: crossbeam::channel::Receiver<Result<(), IoError>>,
    slot: Arc<Mutex<Slot>>,
    pub(crate) joints: Vec<usize>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl Worker {
    pub(crate) fn spawn(
        mut bus: Box<dyn JointBus>,
        joints: Vec<usize>,
        n: usize,
        index: usize,
    ) -> std::io::Result<Self> {
        let (ops, rx) = crossbeam::channel::bounded::<Op>(1);
        let (tx, done) = crossbeam::channel::bounded::<Result<(), IoError>>(1);
        let slot = Arc::new(Mutex::new(Slot {
            state: RobotState::new(n),
            targets: vec![JointTarget::default(); n],
            elapsed: Duration::ZERO,
        }));
        let shared = Arc::clone(&slot);
        let thread = std::thread::Builder::new()
            .name(format!("bus-{index}"))
            .spawn(move || {
                while let Ok(op) = rx.recv() {
                    let mut s = shared.lock().unwrap_or_else(PoisonError::into_inner);
                    let Slot {
                        state,
                        targets,
                        elapsed,
                    } = &mut *s;
                    let started = Instant::now();
                    let r = match op {
                        Op::Identify => bus.identify(),
                        Op::Read => bus.read(state),
                        Op::Write => bus.write(targets),
                        Op::TorqueOff => bus.torque_off(),
                    };
                    *elapsed = started.elapsed();
                    drop(s);
                    if tx.send(r).is_err() {
                        break;
                    }
                }
            })?;
        Ok(Self {
            ops: Some(ops),
            done,
            slot,
            joints,
            thread: Some(thread),
        })
    }

    pub(crate) fn lock(&self) -> std::sync::MutexGuard<'_, Slot> {
        self.slot.lock().unwrap_or_else(PoisonError::into_inner)
    }
}

impl Drop for Worker {
    fn drop(&mut self) {
        // Closing the channel ends the worker's loop.
        self.ops.take();
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}
