//! An in-process CAN bus on simulated time, for unit tests and the lockstep mirror.
//!
//! Frames are serialised on the wire as on a real bus: each occupies [`wire_time::frame_time`] at
//! the bus bitrate, starts when the wire is free, and reaches every other node when it ends. Nodes
//! have bounded receive FIFOs (overflow drops the frame and counts it, as a controller does) and
//! bounded transmit queues (a send beyond them is refused, as a kernel's full queue refuses it).
//! Faults from a [`CanFaultPlan`] drop, delay, corrupt or truncate frames, or put the bus off.
//!
//! The bus does not advance time itself: whoever owns the simulated world does (see
//! [`crate::time::SimInstant`] and [`LockstepCanPort`]).

use std::collections::VecDeque;
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Duration;

use super::wire_time::{bits_time, frame_bits};
use super::{CanBus, CanError, CanFrame, CanId};
use crate::time::{SimInstant, SimRng, SimWorld};

/// Receive FIFO depth of each node.
pub const RX_FIFO_DEPTH: usize = 256;

/// Frames a node may have waiting for the wire (a SocketCAN interface's transmit queue, as
/// `txqueuelen 1000` sets it): a sender beyond it is refused, so no sender (a flooding client, one
/// that left) can fill the wire's future with more than ~0.13 s of frames at 1 Mbit/s. Deep
/// enough for a mirror whose simulated wire lags the wall clock on a loaded machine (64 was not).
pub const TX_QUEUE_FRAMES: usize = 1024;

/// A fault applied to frames on the wire.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum CanFaultKind {
    /// The frame never arrives (lost in a connector, filtered by a dead transceiver).
    Drop,
    /// The frame arrives this much later than the wire allows (a busy gateway, a slow adapter).
    Delay(Duration),
    /// The frame fails its CRC at the receivers: an error frame follows and the sender retransmits,
    /// so it arrives one frame time (plus the 20-bit error frame) later, as the CAN protocol does.
    CrcError,
    /// The frame arrives with only this many of its data bytes (a device sending short frames).
    Truncate(u8),
}

/// One fault rule: which frames, when, how often, what happens.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CanFaultRule {
    /// Frames with this identifier only, or every frame.
    pub id: Option<CanId>,
    /// Active from this time on.
    pub from: SimInstant,
    /// Active until this time (exclusive); `None` for ever.
    pub until: Option<SimInstant>,
    /// Chance that a matching frame is hit.
    pub probability: f64,
    /// What happens to a hit frame.
    pub kind: CanFaultKind,
}

/// Faults scheduled on one bus.
#[derive(Debug, Clone, Default)]
pub struct CanFaultPlan {
    /// Frame faults, checked in order; the first hit applies.
    pub rules: Vec<CanFaultRule>,
    /// Bus-off windows: from, until. While off, sends fail and nothing is delivered.
    pub bus_off: Vec<(SimInstant, SimInstant)>,
    /// Seed of the fault dice.
    pub seed: u64,
}

/// Counters of one bus, for telemetry and tests.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct CanBusStats {
    /// Frames put on the wire.
    pub frames: u64,
    /// Bits those frames occupied.
    pub bits: u64,
    /// Frames lost to a fault.
    pub dropped: u64,
    /// Frames delayed by a fault (including CRC retransmissions).
    pub delayed: u64,
    /// Frames truncated by a fault.
    pub truncated: u64,
    /// Frames lost because a receiver's FIFO was full.
    pub rx_overflow: u64,
    /// Sends refused while bus-off.
    pub refused_bus_off: u64,
    /// Sends refused because the sender's transmit queue was full.
    pub refused_queue_full: u64,
}

#[derive(Debug)]
struct Node {
    rx: VecDeque<(SimInstant, CanFrame)>,
    /// When each of its frames not yet off the wire ends.
    tx: VecDeque<SimInstant>,
}

#[derive(Debug)]
struct Medium {
    name: String,
    bitrate: u32,
    now: SimInstant,
    busy_until: SimInstant,
    nodes: Vec<Node>,
    faults: CanFaultPlan,
    rng: SimRng,
    stats: CanBusStats,
}

impl Medium {
    fn bus_off_at(&self, t: SimInstant) -> bool {
        self.faults
            .bus_off
            .iter()
            .any(|&(from, until)| t >= from && t < until)
    }

    fn fault_for(&mut self, frame: &CanFrame, t: SimInstant) -> Option<CanFaultKind> {
        for i in 0..self.faults.rules.len() {
            let rule = self.faults.rules[i];
            let active = t >= rule.from && rule.until.is_none_or(|u| t < u);
            if active && rule.id.is_none_or(|id| id == frame.id()) && self.rng.chance(rule.probability) {
                return Some(rule.kind);
            }
        }
        None
    }

    fn transmit(&mut self, from: usize, frame: &CanFrame) -> Result<(), CanError> {
        if self.bus_off_at(self.now) {
            self.stats.refused_bus_off += 1;
            return Err(CanError::BusOff {
                bus: self.name.clone(),
            });
        }
        let now = self.now;
        let queue = &mut self.nodes[from].tx;
        while queue.front().is_some_and(|&end| end <= now) {
            queue.pop_front();
        }
        if queue.len() >= TX_QUEUE_FRAMES {
            self.stats.refused_queue_full += 1;
            return Err(CanError::TxQueueFull {
                bus: self.name.clone(),
            });
        }
        let start = self.now.max(self.busy_until);
        // The frame's bits once (the stuffing walk is the bus's dearest sum).
        let bits = frame_bits(frame);
        let mut end = start + bits_time(bits, self.bitrate);
        self.busy_until = end;
        self.nodes[from].tx.push_back(end);
        self.stats.frames += 1;
        self.stats.bits += u64::from(bits);
        let mut delivered = *frame;
        match self.fault_for(frame, start) {
            Some(CanFaultKind::Drop) => {
                self.stats.dropped += 1;
                return Ok(());
            }
            Some(CanFaultKind::Delay(d)) => {
                self.stats.delayed += 1;
                end = end + d;
            }
            Some(CanFaultKind::CrcError) => {
                self.stats.delayed += 1;
                let resend = bits_time(bits, self.bitrate) + bits_time(20, self.bitrate);
                end = end + resend;
                self.busy_until = self.busy_until + resend;
            }
            Some(CanFaultKind::Truncate(n)) => {
                self.stats.truncated += 1;
                let n = usize::from(n).min(frame.dlc());
                delivered = CanFrame::new(frame.id(), &frame.data()[..n]).unwrap_or(*frame);
            }
            None => {}
        }
        if self.bus_off_at(end) {
            self.stats.dropped += 1;
            return Ok(());
        }
        for (i, node) in self.nodes.iter_mut().enumerate() {
            if i == from {
                continue;
            }
            if node.rx.len() >= RX_FIFO_DEPTH {
                self.stats.rx_overflow += 1;
                continue;
            }
            // Keep each FIFO ordered by arrival; only delayed frames land out of order.
            let pos = node.rx.iter().rposition(|(t, _)| *t <= end).map_or(0, |p| p + 1);
            node.rx.insert(pos, (end, delivered));
        }
        Ok(())
    }
}

/// An in-process CAN bus. Cloning gives another handle to the same wire.
#[derive(Debug, Clone)]
pub struct VirtualCanBus {
    medium: Arc<Mutex<Medium>>,
}

impl VirtualCanBus {
    /// A bus named `name` at `bitrate` bit/s, with no nodes and no faults.
    pub fn new(name: &str, bitrate: u32) -> Self {
        Self::with_faults(name, bitrate, CanFaultPlan::default())
    }

    /// A bus with scheduled faults.
    pub fn with_faults(name: &str, bitrate: u32, faults: CanFaultPlan) -> Self {
        let rng = SimRng::new(faults.seed);
        Self {
            medium: Arc::new(Mutex::new(Medium {
                name: name.to_owned(),
                bitrate,
                now: SimInstant::ZERO,
                busy_until: SimInstant::ZERO,
                nodes: Vec::new(),
                faults,
                rng,
                stats: CanBusStats::default(),
            })),
        }
    }

    fn lock(&self) -> MutexGuard<'_, Medium> {
        // A panic while holding the lock leaves plain data behind; keep using it.
        self.medium
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
    }

    /// Attaches a node (a host adapter or a device) and returns its handle.
    pub fn attach(&self) -> VirtualCanNode {
        let mut m = self.lock();
        m.nodes.push(Node {
            rx: VecDeque::with_capacity(RX_FIFO_DEPTH),
            tx: VecDeque::with_capacity(TX_QUEUE_FRAMES),
        });
        VirtualCanNode {
            bus: self.clone(),
            index: m.nodes.len() - 1,
        }
    }

    /// Moves the wire's clock to `t` (never backwards). Called by the simulated world.
    pub fn set_now(&self, t: SimInstant) {
        let mut m = self.lock();
        m.now = m.now.max(t);
    }

    /// The wire's clock.
    pub fn now(&self) -> SimInstant {
        self.lock().now
    }

    /// Among `nodes` (this bus's), the one whose next frame arrives first, and when: one look at
    /// the wire for many nodes (ties go to the earlier node).
    pub fn next_arrival_among<'a>(
        &self,
        nodes: impl IntoIterator<Item = &'a VirtualCanNode>,
    ) -> Option<(SimInstant, usize)> {
        let m = self.lock();
        let mut first: Option<(SimInstant, usize)> = None;
        for (i, node) in nodes.into_iter().enumerate() {
            if let Some(&(t, _)) = m.nodes[node.index].rx.front()
                && first.is_none_or(|(f, _)| t < f)
            {
                first = Some((t, i));
            }
        }
        first
    }

    /// Counters so far.
    pub fn stats(&self) -> CanBusStats {
        self.lock().stats
    }

    /// The bus name.
    pub fn name(&self) -> String {
        self.lock().name.clone()
    }

    /// Replaces the fault plan (the dice keep their state).
    pub fn set_faults(&self, faults: CanFaultPlan) {
        self.lock().faults = faults;
    }
}

/// One node's connection to a [`VirtualCanBus`].
#[derive(Debug, Clone)]
pub struct VirtualCanNode {
    bus: VirtualCanBus,
    index: usize,
}

impl VirtualCanNode {
    /// Puts `frame` on the wire at the wire's current time.
    pub fn send(&self, frame: &CanFrame) -> Result<(), CanError> {
        self.bus.lock().transmit(self.index, frame)
    }

    /// The oldest frame that has arrived by the wire's current time.
    pub fn try_recv(&self) -> Option<CanFrame> {
        let mut m = self.bus.lock();
        let now = m.now;
        let rx = &mut m.nodes[self.index].rx;
        match rx.front() {
            Some(&(t, _)) if t <= now => rx.pop_front().map(|(_, f)| f),
            _ => None,
        }
    }

    /// When the next frame for this node arrives, if one is on its way.
    pub fn next_arrival(&self) -> Option<SimInstant> {
        self.bus.lock().nodes[self.index].rx.front().map(|&(t, _)| t)
    }

    /// The bus this node is on.
    pub fn bus(&self) -> &VirtualCanBus {
        &self.bus
    }
}

/// The controller's adapter on a virtual bus in a lockstep world: receiving with a deadline runs
/// the world forward event by event until a frame arrives or the deadline passes.
#[derive(Debug)]
pub struct LockstepCanPort<W> {
    node: VirtualCanNode,
    world: Arc<Mutex<W>>,
}

impl<W: SimWorld> LockstepCanPort<W> {
    /// A port for `node`, advancing `world` while it waits.
    pub fn new(node: VirtualCanNode, world: Arc<Mutex<W>>) -> Self {
        Self { node, world }
    }

    fn world(&self) -> MutexGuard<'_, W> {
        self.world
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
    }
}

impl<W: SimWorld> CanBus for LockstepCanPort<W> {
    type Instant = SimInstant;

    fn now(&self) -> SimInstant {
        self.world().now()
    }

    fn send(&mut self, frame: &CanFrame) -> Result<(), CanError> {
        let now = self.world().now();
        self.node.bus().set_now(now);
        self.node.send(frame)
    }

    fn recv_until(&mut self, deadline: SimInstant) -> Result<Option<CanFrame>, CanError> {
        loop {
            if let Some(frame) = self.node.try_recv() {
                return Ok(Some(frame));
            }
            let mut world = self
                .world
                .lock()
                .unwrap_or_else(std::sync::PoisonError::into_inner);
            if world.now() >= deadline {
                return Ok(None);
            }
            let limit = self.node.next_arrival().map_or(deadline, |t| t.min(deadline));
            let from = world.now();
            let now = world.step_until(limit.max(from));
            drop(world);
            self.node.bus().set_now(now);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A world with nothing in it but a clock and the wires.
    struct EmptyWorld {
        now: SimInstant,
        bus: VirtualCanBus,
    }

    impl SimWorld for EmptyWorld {
        fn now(&self) -> SimInstant {
            self.now
        }
        fn step_until(&mut self, limit: SimInstant) -> SimInstant {
            self.now = limit;
            self.bus.set_now(limit);
            limit
        }
    }

    fn frame(id: u16, b: u8) -> CanFrame {
        CanFrame::new8(CanId::standard(id).unwrap(), [b; 8])
    }

    #[test]
    fn a_flooding_sender_is_refused_beyond_its_transmit_queue_and_its_backlog_drains_at_once() {
        let bus = VirtualCanBus::new("can0", 1_000_000);
        let (flood, host) = (bus.attach(), bus.attach());
        // A client queueing 100 000 frames at once: a queue's worth go, the rest are refused.
        let sent = (0..100_000)
            .filter(|&k| flood.send(&frame(0x7FF, k as u8)).is_ok())
            .count();
        assert_eq!(sent, TX_QUEUE_FRAMES);
        assert_eq!(bus.stats().refused_queue_full, 100_000 - TX_QUEUE_FRAMES as u64);
        // What it left behind occupies the wire ~0.13 s (it used to be 13 s): a frame sent now
        // ends within 0.2 s, and by then the sender may queue again.
        host.send(&frame(1, 0xAA)).unwrap();
        let mut w = EmptyWorld {
            now: SimInstant::ZERO,
            bus: bus.clone(),
        };
        w.step_until(SimInstant::ZERO + Duration::from_millis(200));
        assert!(bus.lock().busy_until <= SimInstant::ZERO + Duration::from_millis(200));
        assert!(flood.send(&frame(0x7FF, 0)).is_ok());
    }

    #[test]
    fn frames_are_serialised_on_the_wire_and_reach_every_other_node() {
        let bus = VirtualCanBus::new("can0", 1_000_000);
        let (a, b, c) = (bus.attach(), bus.attach(), bus.attach());
        a.send(&frame(1, 0x55)).unwrap();
        a.send(&frame(2, 0x55)).unwrap();
        // Nothing has arrived at t = 0.
        assert!(b.try_recv().is_none());
        let first = b.next_arrival().unwrap();
        assert_eq!(first.as_nanos(), u64::from(frame_bits(&frame(1, 0x55))) * 1000);
        bus.set_now(SimInstant::from_nanos(1_000_000));
        assert_eq!(b.try_recv().unwrap().id(), CanId::Standard(1));
        assert_eq!(b.try_recv().unwrap().id(), CanId::Standard(2));
        assert_eq!(c.try_recv().unwrap().id(), CanId::Standard(1));
        assert!(a.try_recv().is_none(), "a sender does not receive its own frames");
        let s = bus.stats();
        assert_eq!(s.frames, 2);
    }

    #[test]
    fn faults_drop_delay_truncate_and_bus_off() {
        let id = CanId::standard(7).unwrap();
        let plan = CanFaultPlan {
            rules: vec![
                CanFaultRule {
                    id: Some(id),
                    from: SimInstant::ZERO,
                    until: None,
                    probability: 1.0,
                    kind: CanFaultKind::Drop,
                },
                CanFaultRule {
                    id: Some(CanId::standard(8).unwrap()),
                    from: SimInstant::ZERO,
                    until: None,
                    probability: 1.0,
                    kind: CanFaultKind::Delay(Duration::from_millis(3)),
                },
                CanFaultRule {
                    id: Some(CanId::standard(9).unwrap()),
                    from: SimInstant::ZERO,
                    until: None,
                    probability: 1.0,
                    kind: CanFaultKind::Truncate(5),
                },
            ],
            bus_off: vec![(
                SimInstant::from_nanos(10_000_000),
                SimInstant::from_nanos(20_000_000),
            )],
            seed: 1,
        };
        let bus = VirtualCanBus::with_faults("can0", 1_000_000, plan);
        let (a, b) = (bus.attach(), bus.attach());
        a.send(&frame(7, 1)).unwrap();
        a.send(&frame(8, 2)).unwrap();
        a.send(&frame(9, 3)).unwrap();
        bus.set_now(SimInstant::from_nanos(2_000_000));
        let short = b.try_recv().unwrap();
        assert_eq!((short.id(), short.dlc()), (CanId::Standard(9), 5));
        assert!(b.try_recv().is_none(), "the delayed frame is still on its way");
        bus.set_now(SimInstant::from_nanos(4_000_000));
        assert_eq!(b.try_recv().unwrap().id(), CanId::Standard(8));
        assert!(b.try_recv().is_none(), "frame 7 was dropped");

        bus.set_now(SimInstant::from_nanos(15_000_000));
        assert!(matches!(a.send(&frame(1, 0)), Err(CanError::BusOff { .. })));
        bus.set_now(SimInstant::from_nanos(20_000_000));
        a.send(&frame(1, 0)).unwrap();
        let s = bus.stats();
        assert_eq!(
            (s.dropped, s.delayed, s.truncated, s.refused_bus_off),
            (1, 1, 1, 1)
        );
    }

    #[test]
    fn crc_errors_cost_a_retransmission() {
        let plan = CanFaultPlan {
            rules: vec![CanFaultRule {
                id: None,
                from: SimInstant::ZERO,
                until: None,
                probability: 1.0,
                kind: CanFaultKind::CrcError,
            }],
            ..CanFaultPlan::default()
        };
        let clean = VirtualCanBus::new("a", 1_000_000);
        let noisy = VirtualCanBus::with_faults("b", 1_000_000, plan);
        let arrival = |bus: &VirtualCanBus| {
            let (tx, rx) = (bus.attach(), bus.attach());
            tx.send(&frame(1, 0xAA)).unwrap();
            rx.next_arrival().unwrap()
        };
        let (t_clean, t_noisy) = (arrival(&clean), arrival(&noisy));
        assert_eq!(
            t_noisy - t_clean,
            super::super::wire_time::frame_time(&frame(1, 0xAA), 1_000_000) + Duration::from_micros(20)
        );
    }

    #[test]
    fn receive_fifo_overflow_is_counted() {
        let bus = VirtualCanBus::new("can0", 1_000_000);
        let (a, _b) = (bus.attach(), bus.attach());
        // The receiver never reads; the sender waits out its full transmit queue.
        let (mut sent, mut t) = (0, SimInstant::ZERO);
        while sent < RX_FIFO_DEPTH + 3 {
            match a.send(&frame(1, 0)) {
                Ok(()) => sent += 1,
                Err(CanError::TxQueueFull { .. }) => {
                    t = t + Duration::from_millis(1);
                    bus.set_now(t);
                }
                Err(e) => panic!("{e}"),
            }
        }
        assert_eq!(bus.stats().rx_overflow, 3);
    }

    #[test]
    fn lockstep_port_waits_in_simulated_time_only() {
        let bus = VirtualCanBus::new("can0", 1_000_000);
        let world = Arc::new(Mutex::new(EmptyWorld {
            now: SimInstant::ZERO,
            bus: bus.clone(),
        }));
        let mut port = LockstepCanPort::new(bus.attach(), world.clone());
        let peer = bus.attach();
        let wall = std::time::Instant::now();
        // Nothing arrives: the port returns exactly at the deadline, in simulated time.
        let deadline = SimInstant::from_nanos(5_000_000_000);
        assert_eq!(port.recv_until(deadline).unwrap(), None);
        assert_eq!(port.now(), deadline);
        assert!(wall.elapsed() < Duration::from_secs(1), "lockstep must not sleep");
        // A frame sent by a peer is received at its arrival time, before the deadline.
        peer.send(&frame(3, 1)).unwrap();
        let got = port
            .recv_until(deadline + Duration::from_secs(1))
            .unwrap()
            .unwrap();
        assert_eq!(got.id(), CanId::Standard(3));
        assert!(port.now() < deadline + Duration::from_millis(1));
    }
}
