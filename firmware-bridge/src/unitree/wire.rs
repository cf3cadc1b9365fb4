//! Unitree's low-level link over DDS: `rt/lowcmd` and `rt/lowstate`, on the robot's network
//! interface and domain. Both ends: the host's port ([`DdsLowLevelPort`]) and the server that puts
//! an emulated board on the network ([`BoardServer`]).
//!
//! The middleware allocates for each sample it sends or takes, so it runs on an I/O thread of its
//! own; the link's cycle hands it commands and takes states through triple buffers and an event
//! loop waker, which allocate nothing.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use crossbeam::queue::ArrayQueue;
use dds::mio::{Events, Poll, Token, Waker};
use dds::{DdsConfig, DdsError, Delivery, Participant};
use triple_buffer::{Input, Output, triple_buffer};

use super::hg::{LOW_CMD_TYPE, LOW_STATE_TYPE, LowCmd, LowState};
use super::host::LowLevelPort;
use super::lockstep::UnitreeWorld;

/// The command topic.
pub const LOW_CMD_TOPIC: &str = "rt/lowcmd";
/// The state topic.
pub const LOW_STATE_TOPIC: &str = "rt/lowstate";

const SAMPLES: Token = Token(0);
const WAKE: Token = Token(1);

/// One sample's bytes in a fixed buffer (a triple buffer's slot: copied, never allocated).
#[derive(Debug, Clone, Copy)]
struct Slot<const N: usize> {
    bytes: [u8; N],
    len: usize,
    /// Samples written so far; a reader that saw this number saw this sample.
    sequence: u64,
    /// When it arrived.
    arrived: Option<std::time::Instant>,
}

impl<const N: usize> Default for Slot<N> {
    fn default() -> Self {
        Self {
            bytes: [0; N],
            len: 0,
            sequence: 0,
            arrived: None,
        }
    }
}

impl<const N: usize> Slot<N> {
    /// Copies `sample` in (cut to the slot: a longer one is not the message it should be).
    fn fill(&mut self, sample: &[u8], sequence: u64) {
        self.len = sample.len().min(N);
        self.bytes[..self.len].copy_from_slice(&sample[..self.len]);
        self.sequence = sequence;
        self.arrived = Some(std::time::Instant::now());
    }

    fn bytes(&self) -> &[u8] {
        &self.bytes[..self.len]
    }
}

/// Room for a state: a longer sample is cut and fails its checks.
type StateSlot = Slot<{ LowState::CDR_LEN + 64 }>;
type CmdSlot = Slot<{ LowCmd::CDR_LEN + 64 }>;

/// The I/O thread, stopped and joined on drop.
#[derive(Debug)]
struct IoThread {
    stop: Arc<AtomicBool>,
    waker: Arc<Waker>,
    errors: Arc<ArrayQueue<String>>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl IoThread {
    /// Runs `each` on a new thread named `name` whenever a sample arrives, the waker is woken or
    /// `tick` passes, until stopped. `each` returns an error to report (the thread goes on).
    fn spawn(
        name: &str,
        mut subscription: dds::Subscription,
        tick: Duration,
        mut each: impl FnMut(&mut dds::Subscription) -> Result<(), String> + Send + 'static,
    ) -> Result<Self, DdsError> {
        let io = |e: std::io::Error| DdsError::Middleware(format!("{name} thread: {e}"));
        let mut poll = Poll::new().map_err(io)?;
        subscription.register(poll.registry(), SAMPLES).map_err(io)?;
        let waker = Arc::new(Waker::new(poll.registry(), WAKE).map_err(io)?);
        let stop = Arc::new(AtomicBool::new(false));
        let errors = Arc::new(ArrayQueue::new(4));
        let (thread_stop, thread_errors) = (Arc::clone(&stop), Arc::clone(&errors));
        let thread = std::thread::Builder::new()
            .name(name.into())
            .spawn(move || {
                let mut events = Events::with_capacity(8);
                while !thread_stop.load(Ordering::Acquire) {
                    if let Err(e) = poll.poll(&mut events, Some(tick))
                        && e.kind() != std::io::ErrorKind::Interrupted
                    {
                        let _ = thread_errors.push(format!("poll: {e}"));
                    }
                    if let Err(e) = each(&mut subscription) {
                        let _ = thread_errors.push(e);
                    }
                }
                // The topics before the participant `each` holds (RustDDS complains otherwise).
                drop(subscription);
                drop(each);
            })
            .map_err(io)?;
        Ok(Self {
            stop,
            waker,
            errors,
            thread: Some(thread),
        })
    }

    /// An error of the thread since the last call, or that it ended.
    fn error(&self) -> Option<std::io::Error> {
        if let Some(e) = self.errors.pop() {
            return Some(std::io::Error::other(e));
        }
        self.thread
            .as_ref()
            .is_none_or(std::thread::JoinHandle::is_finished)
            .then(|| std::io::Error::other("the DDS thread stopped"))
    }
}

impl Drop for IoThread {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Release);
        let _ = self.waker.wake();
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// The host's end of the link over DDS.
#[derive(Debug)]
pub struct DdsLowLevelPort {
    commands: Input<CmdSlot>,
    states: Output<StateSlot>,
    sent: u64,
    seen: u64,
    io: IoThread,
}

impl DdsLowLevelPort {
    /// Joins the robot's domain on its interface, publishes `rt/lowcmd` and subscribes
    /// `rt/lowstate`.
    pub fn open(config: &DdsConfig) -> Result<Self, DdsError> {
        let participant = Participant::join(config)?;
        let publication = participant.publication(LOW_CMD_TOPIC, LOW_CMD_TYPE, Delivery::Stream)?;
        let subscription = participant.subscription(LOW_STATE_TOPIC, LOW_STATE_TYPE, Delivery::Stream)?;
        let (commands, mut pending) = triple_buffer(&CmdSlot::default());
        let (mut arrived, states) = triple_buffer(&StateSlot::default());
        let mut published = 0;
        let mut taken = 0;
        let io = IoThread::spawn(
            "unitree-dds",
            subscription,
            Duration::from_millis(100),
            move |sub| {
                // The participant lives as long as its topics.
                let _ = &participant;
                let newest = pending.read();
                if newest.sequence != published {
                    published = newest.sequence;
                    publication.publish(newest.bytes()).map_err(|e| e.to_string())?;
                }
                sub.take_all(&mut |sample| {
                    taken += 1;
                    arrived.input_buffer_mut().fill(sample, taken);
                    arrived.publish();
                })
                .map_err(|e| e.to_string())?;
                Ok(())
            },
        )?;
        Ok(Self {
            commands,
            states,
            sent: 0,
            seen: 0,
            io,
        })
    }
}

impl LowLevelPort for DdsLowLevelPort {
    fn send(&mut self, cdr: &[u8]) -> std::io::Result<()> {
        if let Some(e) = self.io.error() {
            return Err(e);
        }
        self.sent += 1;
        self.commands.input_buffer_mut().fill(cdr, self.sent);
        self.commands.publish();
        self.io.waker.wake()
    }

    fn newest_state(&mut self, out: &mut Vec<u8>) -> std::io::Result<bool> {
        let newest = self.states.read();
        if newest.sequence == self.seen {
            return Ok(false);
        }
        self.seen = newest.sequence;
        out.clear();
        out.extend_from_slice(newest.bytes());
        Ok(true)
    }

    fn wait_state(&mut self, within: Duration) -> std::io::Result<bool> {
        let start = std::time::Instant::now();
        while start.elapsed() < within {
            if self.states.read().sequence != self.seen {
                return Ok(true);
            }
            if let Some(e) = self.io.error() {
                return Err(e);
            }
            std::thread::sleep(Duration::from_micros(200));
        }
        Ok(self.states.read().sequence != self.seen)
    }

    fn state_age(&mut self) -> Option<Duration> {
        self.states.read().arrived.map(|at| at.elapsed())
    }
}

/// An emulated board on the network: its states published as the world makes them, commands
/// handed to it as they arrive.
#[derive(Debug)]
pub struct BoardServer {
    _io: IoThread,
}

impl BoardServer {
    /// Serves board `line` of `world` on the interface and domain of `config`.
    pub fn spawn<W: UnitreeWorld + Send + 'static>(
        world: Arc<Mutex<W>>,
        line: usize,
        config: &DdsConfig,
    ) -> Result<Self, DdsError> {
        let participant = Participant::join(config)?;
        let publication = participant.publication(LOW_STATE_TOPIC, LOW_STATE_TYPE, Delivery::Stream)?;
        let subscription = participant.subscription(LOW_CMD_TOPIC, LOW_CMD_TYPE, Delivery::Stream)?;
        let mut published = 0;
        let mut state = Vec::with_capacity(LowState::CDR_LEN);
        // Every 250 µs at most between a state made and its publication (a 2 ms period).
        let io = IoThread::spawn(
            "unitree-board",
            subscription,
            Duration::from_micros(250),
            move |sub| {
                let _ = &participant;
                let lock = || world.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
                sub.take_all(&mut |sample| {
                    let mut w = lock();
                    let now = w.now();
                    w.board_mut(line).receive(now, sample);
                })
                .map_err(|e| e.to_string())?;
                {
                    let mut w = lock();
                    let (cdr, sequence) = w.board_mut(line).state_cdr();
                    if sequence == published {
                        return Ok(());
                    }
                    published = sequence;
                    state.clear();
                    state.extend_from_slice(cdr);
                }
                publication.publish(&state).map_err(|e| e.to_string())
            },
        )?;
        Ok(Self { _io: io })
    }
}
