//! One bus cycle, the same in lockstep and on a thread of its own: take the policy's newest
//! targets, command the joints (held or ramped between policy ticks, or damped by the bus itself
//! after a fault), read their state back, and judge staleness at the bus's own rate.
//!
//! Times are [`Duration`]s since the link's epoch (the lockstep clock's start, or the instant the
//! link was built on the wall clock). A joint's sample time is the start of the cycle that
//! brought it: the device measured within that cycle's wire time, so ages are never understated.

use std::sync::Arc;
use std::time::Duration;

use crossbeam::queue::ArrayQueue;
use robots::{BusTiming, Interpolation, TorqueHold};

use crate::bus_robot::JointBus;
use crate::link::IoError;
use crate::state::{JointTarget, RobotState};

/// Cycles in a row a joint may stay silent before its bus damps itself.
pub const STALE_CYCLES: u32 = 2;

/// Share of a bus period a cycle may wait for its replies; the rest is margin before the next.
pub const REPLY_SHARE: f64 = 0.9;

/// Buckets of [`CycleTimes`], 20 µs each.
const BUCKETS: usize = 1000;
const BUCKET: Duration = Duration::from_micros(20);

/// A fixed histogram of cycle times (20 µs buckets to 20 ms, and one for anything longer): what a
/// bench reads percentiles from without the cycle allocating.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CycleTimes {
    counts: [u32; BUCKETS + 1],
    total: u64,
}

impl Default for CycleTimes {
    fn default() -> Self {
        Self {
            counts: [0; BUCKETS + 1],
            total: 0,
        }
    }
}

impl CycleTimes {
    fn record(&mut self, d: Duration) {
        let k = ((d.as_nanos() / BUCKET.as_nanos()) as usize).min(BUCKETS);
        self.counts[k] = self.counts[k].saturating_add(1);
        self.total += 1;
    }

    /// The `p`-quantile (0–1), to the bucket's upper edge; `None` before the first cycle or
    /// beyond the last bucket.
    pub fn quantile(&self, p: f64) -> Option<Duration> {
        if self.total == 0 {
            return None;
        }
        let want = ((p.clamp(0.0, 1.0) * self.total as f64).ceil() as u64).max(1);
        let mut seen = 0u64;
        for (k, &c) in self.counts.iter().enumerate() {
            seen += u64::from(c);
            if seen >= want {
                return (k < BUCKETS).then(|| BUCKET * (k as u32 + 1));
            }
        }
        None
    }

    /// Cycles recorded.
    pub fn count(&self) -> u64 {
        self.total
    }
}

/// What a bus did since the link was built.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct BusStats {
    /// Cycles run.
    pub cycles: u64,
    /// Cycles that started after their slot had passed (the previous one ran long).
    pub overruns: u64,
    /// How long the last cycle took, send to last reply.
    pub last_cycle: Duration,
    /// Every cycle's duration.
    pub cycle_times: CycleTimes,
    /// From the policy's write to the start of the cycle that sent it, per write.
    pub command_latency: CycleTimes,
    /// The cycle in which the bus damped itself (a joint silent for [`STALE_CYCLES`] cycles, or
    /// faulted), if it did.
    pub damped_at_cycle: Option<u64>,
    /// When that cycle started.
    pub damped_at: Option<Duration>,
    /// The first cycle that sent damping.
    pub damping_sent_at_cycle: Option<u64>,
    /// Commands whose PD target was pulled in so their torque stayed within the joint's limit.
    pub torque_bounded: u64,
}

/// Most joints a [`CycleRecord`] carries (a bus with more records its first ones).
pub const MAX_RECORDED_JOINTS: usize = 32;

/// One bus cycle as telemetry records it: what the bus read and commanded, and how long it took.
/// Fixed size: cycles hand it to the loop through a preallocated queue.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CycleRecord {
    /// The bus's index in [`crate::RobotLink::bus_names`].
    pub bus: u8,
    /// Joints recorded.
    pub joints: u8,
    /// The cycle's number on its bus.
    pub cycle: u64,
    /// When it started (the link's time), ns.
    pub started_ns: u64,
    /// Send to last reply, µs.
    pub took_us: f32,
    /// Slots lost so far.
    pub overruns: u64,
    /// The bus is damping itself.
    pub damped: bool,
    /// Robot index of each joint.
    pub index: [u16; MAX_RECORDED_JOINTS],
    /// Measured position (rad), velocity (rad/s), torque (N·m).
    pub q: [f32; MAX_RECORDED_JOINTS],
    pub qd: [f32; MAX_RECORDED_JOINTS],
    pub tau: [f32; MAX_RECORDED_JOINTS],
    /// Cycles in a row without a reply.
    pub missed: [u32; MAX_RECORDED_JOINTS],
    /// Commanded `[q, qd, kp, kd, tau]`, and torque on.
    pub command: [[f32; 5]; MAX_RECORDED_JOINTS],
    pub enabled: [bool; MAX_RECORDED_JOINTS],
}

impl Default for CycleRecord {
    fn default() -> Self {
        Self {
            bus: 0,
            joints: 0,
            cycle: 0,
            started_ns: 0,
            took_us: 0.0,
            overruns: 0,
            damped: false,
            index: [0; MAX_RECORDED_JOINTS],
            q: [0.0; MAX_RECORDED_JOINTS],
            qd: [0.0; MAX_RECORDED_JOINTS],
            tau: [0.0; MAX_RECORDED_JOINTS],
            missed: [0; MAX_RECORDED_JOINTS],
            command: [[0.0; 5]; MAX_RECORDED_JOINTS],
            enabled: [false; MAX_RECORDED_JOINTS],
        }
    }
}

/// Where a bus's cycle records wait for the loop: a preallocated queue; a full queue drops the
/// newest and counts it.
#[derive(Debug)]
pub(crate) struct CycleLog {
    pub(crate) queue: ArrayQueue<CycleRecord>,
    pub(crate) lost: std::sync::atomic::AtomicU64,
}

impl CycleLog {
    pub(crate) fn new(capacity: usize) -> Arc<Self> {
        Arc::new(Self {
            queue: ArrayQueue::new(capacity.max(1)),
            lost: std::sync::atomic::AtomicU64::new(0),
        })
    }
}

/// One bus with its schedule and what it commands between policy ticks.
#[derive(Debug)]
pub(crate) struct Cycler {
    pub(crate) bus: Box<dyn JointBus>,
    /// The robot indices of its joints.
    pub(crate) joints: Vec<usize>,
    pub(crate) timing: BusTiming,
    policy_period: Duration,
    /// Damping per joint when the bus damps itself (robot order).
    damping_kd: Vec<f64>,
    /// How each joint's torque limit is held (robot order), when this bus's devices run the PD
    /// law themselves (MIT motors, Unitree's boards): every command is bounded against the newest
    /// measured state so the PD torque it asks for stays within it.
    torque_hold: Option<Vec<TorqueHold>>,
    /// The policy's newest targets, when it issued them and their number.
    order: Vec<JointTarget>,
    issued_at: Duration,
    order_seq: u64,
    /// Where a ramp starts: what was commanded when the newest targets came.
    from: Vec<JointTarget>,
    /// What the last cycle commanded.
    pub(crate) sent: Vec<JointTarget>,
    /// The state the bus's cycles read (its joints only), with each joint's sample time.
    pub(crate) state: RobotState,
    pub(crate) sampled_at: Vec<Duration>,
    /// The bus damps itself until torque goes off.
    pub(crate) damped: bool,
    /// Joints whose fault made the bus damp itself.
    fault_latched: Vec<bool>,
    /// Cycles in a row a joint may stay silent before the bus damps itself.
    pub(crate) stale_cycles: u32,
    pub(crate) stats: BusStats,
    started: Duration,
    /// The newest targets have not gone out yet.
    order_unsent: bool,
    /// Where each cycle is recorded, when telemetry asks for it; the bus's index.
    pub(crate) log: Option<(Arc<CycleLog>, u8)>,
    record: CycleRecord,
}

impl Cycler {
    pub(crate) fn new(
        bus: Box<dyn JointBus>,
        joints: Vec<usize>,
        timing: BusTiming,
        policy_period: Duration,
        damping_kd: Vec<f64>,
        torque_hold: Option<Vec<TorqueHold>>,
    ) -> Self {
        let n = damping_kd.len();
        Self {
            bus,
            joints,
            timing,
            policy_period,
            damping_kd,
            torque_hold,
            order: vec![JointTarget::default(); n],
            issued_at: Duration::ZERO,
            order_seq: 0,
            from: vec![JointTarget::default(); n],
            sent: vec![JointTarget::default(); n],
            state: RobotState::new(n),
            sampled_at: vec![Duration::ZERO; n],
            damped: false,
            fault_latched: vec![false; n],
            stale_cycles: STALE_CYCLES,
            stats: BusStats::default(),
            started: Duration::ZERO,
            order_unsent: false,
            log: None,
            record: CycleRecord::default(),
        }
    }

    /// How long a cycle waits for its replies at most.
    pub(crate) fn reply_window(timing: &BusTiming) -> Duration {
        timing.period.mul_f64(REPLY_SHARE)
    }

    /// When a scheduled cycle's replies are expected in: its round trip with a margin, within
    /// the reply window. (Replies still missing then are waited for, up to the window.)
    pub(crate) fn replies_expected(timing: &BusTiming) -> Duration {
        let margin = Duration::from_micros(100).max(timing.period / 20);
        (timing.round_trip() + margin).min(Self::reply_window(timing))
    }

    /// Takes the policy's targets number `seq`, issued at `issued_at` (robot order). A ramp
    /// starts from what the bus commands now.
    pub(crate) fn take_order(&mut self, seq: u64, issued_at: Duration, targets: &[JointTarget]) {
        if seq == self.order_seq {
            return;
        }
        self.order_seq = seq;
        self.issued_at = issued_at;
        self.order_unsent = true;
        for &i in &self.joints {
            self.from[i] = self.sent[i];
            self.order[i] = targets[i];
        }
    }

    /// Reads the bus's joints at once (after identify, before cycles run), stamped `now`.
    pub(crate) fn sample(&mut self, now: Duration) -> Result<(), IoError> {
        self.bus.sample(&mut self.state)?;
        self.stamp(now);
        Ok(())
    }

    /// The first half of a cycle at `now`: the commands go out.
    pub(crate) fn start(&mut self, now: Duration) -> Result<(), IoError> {
        self.started = now;
        if std::mem::take(&mut self.order_unsent) {
            self.stats
                .command_latency
                .record(now.saturating_sub(self.issued_at));
        }
        let linear = self.timing.interpolation == Interpolation::Linear;
        // The ramp reaches the newest target in the last cycle before the next policy tick.
        let since = now.saturating_sub(self.issued_at) + self.timing.period;
        let alpha = (since.as_secs_f64() / self.policy_period.as_secs_f64()).min(1.0);
        let mut damping = false;
        for &i in &self.joints {
            let (t, f) = (self.order[i], self.from[i]);
            self.sent[i] = if self.damped && t.enabled {
                damping = true;
                let kd = if self.sent[i].kd > 0.0 {
                    self.sent[i].kd
                } else {
                    self.damping_kd[i]
                };
                JointTarget {
                    q: self.sent[i].q,
                    kd,
                    enabled: true,
                    ..JointTarget::default()
                }
            } else if linear && t.enabled && f.enabled {
                let lerp = |a: f64, b: f64| a + (b - a) * alpha;
                JointTarget {
                    q: lerp(f.q, t.q),
                    qd: lerp(f.qd, t.qd),
                    kp: lerp(f.kp, t.kp),
                    kd: lerp(f.kd, t.kd),
                    tau: lerp(f.tau, t.tau),
                    enabled: true,
                }
            } else {
                t
            };
        }
        if let Some(holds) = &self.torque_hold {
            for &i in &self.joints {
                if bound_pd(
                    &mut self.sent[i],
                    self.state.q[i],
                    self.state.qd[i],
                    holds[i],
                    self.timing.period.as_secs_f64(),
                ) {
                    self.stats.torque_bounded += 1;
                }
            }
        }
        if damping && self.stats.damping_sent_at_cycle.is_none() {
            self.stats.damping_sent_at_cycle = Some(self.stats.cycles);
        }
        self.bus.send(&self.sent)
    }

    /// The second half of the cycle that started last: the replies, and the bus's own check
    /// (`now` tells the time once the replies are in).
    pub(crate) fn finish(&mut self, now: impl FnOnce() -> Duration) -> Result<(), IoError> {
        let r = self.bus.receive(&mut self.state);
        let took = now().saturating_sub(self.started);
        self.stats.last_cycle = took;
        self.stats.cycle_times.record(took);
        let started = self.started;
        self.stamp(started);
        let driven = self.joints.iter().any(|&i| self.order[i].enabled);
        let s = &mut self.state;
        let mut trips = false;
        for &i in &self.joints {
            if !driven {
                s.stale[i] = false;
                self.fault_latched[i] = false;
                continue;
            }
            // What made the bus damp itself stays visible to the loop until torque goes off.
            s.stale[i] |= s.missed[i] >= self.stale_cycles;
            self.fault_latched[i] |= s.faulted[i];
            s.faulted[i] = self.fault_latched[i];
            trips |= s.stale[i] || s.faulted[i];
        }
        if !driven {
            self.damped = false;
        } else if trips && !self.damped {
            self.damped = true;
            self.stats.damped_at_cycle.get_or_insert(self.stats.cycles);
            self.stats.damped_at.get_or_insert(started);
        }
        self.log_cycle(took);
        self.stats.cycles += 1;
        r
    }

    /// Hands this cycle to telemetry, if it records cycles (a full queue drops and counts it).
    fn log_cycle(&mut self, took: Duration) {
        let Some((log, bus)) = &self.log else { return };
        let r = &mut self.record;
        r.bus = *bus;
        r.cycle = self.stats.cycles;
        r.started_ns = self.started.as_nanos() as u64;
        r.took_us = took.as_secs_f32() * 1e6;
        r.overruns = self.stats.overruns;
        r.damped = self.damped;
        let n = self.joints.len().min(MAX_RECORDED_JOINTS);
        r.joints = n as u8;
        for (k, &i) in self.joints.iter().take(n).enumerate() {
            let (s, c) = (&self.state, &self.sent[i]);
            r.index[k] = i as u16;
            r.q[k] = s.q[i] as f32;
            r.qd[k] = s.qd[i] as f32;
            r.tau[k] = s.tau[i] as f32;
            r.missed[k] = s.missed[i];
            r.command[k] = [c.q, c.qd, c.kp, c.kd, c.tau].map(|v| v as f32);
            r.enabled[k] = c.enabled;
        }
        if log.queue.push(*r).is_err() {
            log.lost.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        }
    }

    /// Marks fresh joints as sampled at `at`.
    fn stamp(&mut self, at: Duration) {
        for &i in &self.joints {
            if self.state.missed[i] == 0 {
                self.sampled_at[i] = at;
            }
        }
    }

    /// Copies this bus's joints into `state`, with their ages at `now`.
    pub(crate) fn copy_into(&self, state: &mut RobotState, now: Duration) {
        copy_joints(&self.joints, &self.state, &self.sampled_at, state, now);
    }
}

/// Bounds the torque the PD law of `t` asks for to the joint's limit as `hold` says. Over the
/// cycle ([`TorqueHold::OverCycle`]), as the motor runs it at its inner rate until the next
/// command: at the measured `q`, `qd`; where the joint gets in `horizon` seconds at that speed;
/// and at both places stopped dead (an obstacle takes the damping's braking away). At the
/// measurement ([`TorqueHold::ClipAtMeasurement`], the trainer's clip): at `q`, `qd` only. The
/// position target is pulled into the range that keeps every one of them within the limit; if
/// damping and feed-forward alone exceed it at the measurement, the damping is scaled down.
/// Returns whether `t` changed.
fn bound_pd(t: &mut JointTarget, q: f64, qd: f64, hold: TorqueHold, horizon: f64) -> bool {
    let (limit, states) = match hold {
        TorqueHold::MotorRange => return false,
        TorqueHold::ClipAtMeasurement(limit) => (limit, 1),
        TorqueHold::OverCycle(limit) => (limit, 4),
    };
    if !(t.enabled && q.is_finite() && qd.is_finite()) {
        return false;
    }
    let ahead = q + qd * horizon;
    let states = &[(q, qd), (ahead, qd), (q, 0.0), (ahead, 0.0)][..states];
    let rest = |t: &JointTarget, v: f64| t.kd * (t.qd - v) + t.tau;
    let torque = |t: &JointTarget, (at, v): (f64, f64)| t.kp * (t.q - at) + rest(t, v);
    if states.iter().all(|&s| torque(t, s).abs() <= limit) {
        return false;
    }
    if t.kp > 0.0 {
        // Targets within the limit at every state: the intersection of their ranges.
        let (mut lo, mut hi) = (f64::NEG_INFINITY, f64::INFINITY);
        for &(at, v) in states {
            lo = lo.max(at + (-limit - rest(t, v)) / t.kp);
            hi = hi.min(at + (limit - rest(t, v)) / t.kp);
        }
        t.q = if lo <= hi {
            t.q.clamp(lo, hi)
        } else {
            // No target serves them all (damping alone is beyond the limit at some state):
            // bound at the measurement, towards the joint.
            let wanted = (t.kp * (t.q - q) + rest(t, qd)).clamp(-limit, limit);
            (q + (wanted - rest(t, qd)) / t.kp).clamp(q.min(t.q), q.max(t.q))
        };
    }
    let left = torque(t, (q, qd));
    let damping = t.kd * (t.qd - qd);
    if left.abs() > limit && damping != 0.0 {
        // Damping (and feed-forward) alone are beyond the limit: scale the damping down.
        let room = (limit - (t.kp * (t.q - q) + t.tau).abs()).max(0.0);
        t.kd *= (room / damping.abs()).min(1.0);
    }
    true
}

/// Copies `joints` of `from` (sampled at `sampled_at`) into `to`, with their ages at `now`.
pub(crate) fn copy_joints(
    joints: &[usize],
    from: &RobotState,
    sampled_at: &[Duration],
    to: &mut RobotState,
    now: Duration,
) {
    for &i in joints {
        to.q[i] = from.q[i];
        to.qd[i] = from.qd[i];
        to.tau[i] = from.tau[i];
        to.missed[i] = from.missed[i];
        to.faulted[i] = from.faulted[i];
        to.stale[i] = from.stale[i];
        to.age[i] = now.saturating_sub(sampled_at[i]);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 250 Hz bus cycle, s.
    const CYCLE: f64 = 0.004;

    #[test]
    fn a_pd_command_is_bounded_to_the_joints_torque_limit_over_its_cycle() {
        const OVER: TorqueHold = TorqueHold::OverCycle(40.0);
        let t = |q, kp, kd, tau| JointTarget {
            q,
            qd: 0.0,
            kp,
            kd,
            tau,
            enabled: true,
        };
        // 150 N·m/rad × 0.5 rad = 75 N·m against a 40 N·m limit: the target moves to 40/150 rad.
        let mut a = t(1.0, 150.0, 3.0, 0.0);
        assert!(bound_pd(&mut a, 0.5, 0.0, OVER, CYCLE));
        assert!((a.q - (0.5 + 40.0 / 150.0)).abs() < 1e-12 && a.kp == 150.0);
        // Within the limit: untouched.
        let mut b = t(0.6, 150.0, 3.0, 0.0);
        assert!(!bound_pd(&mut b, 0.5, 0.0, OVER, CYCLE));
        // Moving fast into the target's way: damping alone would give 3 × 20 = 60 N·m. The target
        // keeps the torque within the limit now, where the joint is at the cycle's end, and at
        // both places should the joint stop dead against an obstacle.
        let mut c = t(0.5, 150.0, 3.0, 0.0);
        assert!(bound_pd(&mut c, 0.5, -20.0, OVER, CYCLE));
        for (at, v) in [
            (0.5, -20.0),
            (0.5 - 20.0 * CYCLE, -20.0),
            (0.5, 0.0),
            (0.5 - 20.0 * CYCLE, 0.0),
        ] {
            let torque = c.kp * (c.q - at) + c.kd * (0.0 - v) + c.tau;
            assert!(torque.abs() <= 40.0 + 1e-9, "{torque} at {at}, {v}");
        }
        // The other direction, and torque off is never touched.
        let mut d = t(-1.0, 150.0, 3.0, 0.0);
        assert!(bound_pd(&mut d, 0.0, 0.0, OVER, CYCLE));
        assert!((d.q + 40.0 / 150.0).abs() < 1e-12);
        let mut off = JointTarget {
            enabled: false,
            ..t(5.0, 150.0, 3.0, 0.0)
        };
        assert!(!bound_pd(&mut off, 0.0, 0.0, OVER, CYCLE));
    }
    #[test]
    fn the_trainers_clip_bounds_the_torque_at_the_measured_state_only() {
        const CLIP: TorqueHold = TorqueHold::ClipAtMeasurement(40.0);
        let t = |q| JointTarget {
            q,
            kp: 150.0,
            kd: 3.0,
            enabled: true,
            ..JointTarget::default()
        };
        // 75 N·m asked at the measurement: clipped to 40 there, as the trainer clipped it.
        let mut a = t(1.0);
        assert!(bound_pd(&mut a, 0.5, 0.0, CLIP, CYCLE));
        assert!((a.kp * (a.q - 0.5) - 40.0).abs() < 1e-9);
        // Moving towards the target at 10 rad/s: 150 × 0.3 − 3 × 10 = 15 N·m at the measurement,
        // which the trainer's clip passes unchanged; the bound over the cycle moves it, since
        // stopped dead by an obstacle the joint would get 45 N·m.
        let mut b = t(0.8);
        assert!(!bound_pd(&mut b, 0.5, 10.0, CLIP, CYCLE));
        assert_eq!(b, t(0.8));
        assert!(bound_pd(&mut b, 0.5, 10.0, TorqueHold::OverCycle(40.0), CYCLE));
        // The motor's own range holds it: never touched.
        let mut d = t(5.0);
        assert!(!bound_pd(&mut d, 0.0, 0.0, TorqueHold::MotorRange, CYCLE));
    }

    #[test]
    fn cycle_time_quantiles_come_from_their_20_us_buckets() {
        let mut t = CycleTimes::default();
        assert_eq!(t.quantile(0.5), None);
        for us in 1..=100u64 {
            t.record(Duration::from_micros(us * 10));
        }
        // 10 µs … 1000 µs: the median 500 µs falls in the bucket ending at 520 µs, p99 990 µs at 1000.
        assert_eq!(t.quantile(0.5), Some(Duration::from_micros(520)));
        assert_eq!(t.quantile(0.99), Some(Duration::from_micros(1000)));
        t.record(Duration::from_secs(1));
        assert_eq!(t.count(), 101);
        assert_eq!(t.quantile(1.0), None, "beyond the last bucket");
    }
}
