//! The safety side of the loop: the state machine's modes and causes, the checks that trip it, and
//! the governor every command passes (position limits with margin, rate limit, torque bounds).

use robots::JointConfig;

/// Where the controller is. The discriminant is what recordings store.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
pub enum Mode {
    /// Torque off, nothing commanded.
    Off = 0,
    /// Every device answered with the right identity.
    Ready = 1,
    /// Ramping to the default pose at reduced gains.
    SoftStart = 2,
    /// The policy is in command.
    Running = 3,
    /// Holding (after a fault) or blending to the default pose (after a stop request).
    Stopping = 4,
    /// kp = 0, kd > 0: the joints are damped, then torque goes off.
    Damped = 5,
}

impl Mode {
    /// Every mode, in discriminant order.
    pub const ALL: [Self; 6] = [
        Self::Off,
        Self::Ready,
        Self::SoftStart,
        Self::Running,
        Self::Stopping,
        Self::Damped,
    ];

    /// The mode a recording stored as `code`.
    pub fn from_code(code: u8) -> Option<Self> {
        Self::ALL.get(usize::from(code)).copied()
    }
}

/// A joint's name inside a [`Cause`]: held inline, so causes stay `Copy` and a check that trips
/// allocates nothing. Names longer than its room are cut at a character boundary.
#[derive(Clone, Copy, PartialEq, Eq)]
pub struct JointName {
    bytes: [u8; JointName::ROOM],
    len: u8,
}

impl JointName {
    const ROOM: usize = 48;

    /// `name`, cut to the room there is.
    pub fn new(name: &str) -> Self {
        let mut end = name.len().min(Self::ROOM);
        while !name.is_char_boundary(end) {
            end -= 1;
        }
        let mut bytes = [0; Self::ROOM];
        bytes[..end].copy_from_slice(&name.as_bytes()[..end]);
        Self {
            bytes,
            len: end as u8,
        }
    }

    /// The name.
    pub fn as_str(&self) -> &str {
        std::str::from_utf8(&self.bytes[..usize::from(self.len)]).unwrap_or("?")
    }
}

impl Default for JointName {
    fn default() -> Self {
        Self::new("")
    }
}

impl std::fmt::Debug for JointName {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{:?}", self.as_str())
    }
}

impl std::fmt::Display for JointName {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

/// Why a transition happened.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Cause {
    /// All devices answered with the configured identities.
    DevicesIdentified,
    /// The run starts.
    Start,
    /// Start-up ramp finished.
    SoftStartDone,
    /// The clip (and its end hold or blend) finished.
    ClipFinished,
    /// The run's time budget (`--max-seconds`) ran out.
    TimeUp,
    /// SIGINT, SIGTERM or an e-stop input asked to stop.
    StopRequested,
    /// A joint's feedback was stale for the allowed bus cycles (its bus damped itself).
    StaleFeedback {
        /// Robot joint index.
        joint: usize,
        /// Its name.
        name: JointName,
        /// Consecutive bus cycles without a reply when the tick read it.
        cycles: u32,
    },
    /// The IMU stopped delivering samples.
    StaleImu {
        /// Consecutive reads without a sample.
        ticks: u32,
    },
    /// A device reports a fault bit.
    DeviceFault {
        /// Robot joint index.
        joint: usize,
        /// Its name.
        name: JointName,
    },
    /// A reading no working device gives (a joint far beyond its range or faster than its motor
    /// can turn, a gyro beyond any IMU's range, a quaternion that is no rotation): a device fault,
    /// whatever its checksum said.
    ImplausibleFeedback {
        /// The joint (robot index), or none for the IMU.
        joint: Option<usize>,
        /// The joint's name (the IMU's: "IMU").
        name: JointName,
        /// What was read.
        what: &'static str,
        /// Its value.
        value: f64,
        /// The plausible bound it passed.
        bound: f64,
    },
    /// NaN or infinity in the state, observation or action.
    NonFinite {
        /// Where.
        what: &'static str,
    },
    /// The base tilted beyond the limit.
    Tilt {
        /// Angle from upright, rad.
        angle: f64,
    },
    /// Too many consecutive deadline overruns.
    Overruns {
        /// How many in a row.
        count: u32,
    },
    /// A joint stayed far from its target (blocked, or its zero or direction is wrong).
    TrackingError {
        /// Robot joint index.
        joint: usize,
        /// Its name.
        name: JointName,
        /// Target minus measured position, rad.
        error: f64,
        /// The joint's threshold, rad, and how long it may be exceeded, s.
        limit: f64,
        limit_s: f64,
    },
    /// The accelerometer read far beyond anything a robot feels, tick after tick.
    ImuSaturated {
        /// Its reading, g.
        g: f64,
        /// Ticks in a row.
        ticks: u32,
    },
    /// The mirrored simulation diverged (unstable or non-finite physics).
    SimulationFailed,
    /// A mirror served in real time fell behind the wall clock (its host did not give its physics or
    /// its servers the CPU in time) and a device's feedback went stale for it: the mirror's failure,
    /// not the device's.
    MirrorBehind {
        /// How far behind, ms.
        ms: u32,
        /// What went stale: a joint's name, or the IMU's.
        stale: JointName,
        /// A joint went stale (its bus damped itself): the rest damp at once.
        joint: bool,
    },
    /// The state estimate a policy reads is not usable, and why.
    EstimateInvalid(world::estimator::EstimateProblem),
    /// An e-stop input fired.
    EStop,
    /// A bus failed as a whole.
    BusFailure,
    /// The hold before damping ended.
    HoldDone,
    /// Damping ended; torque goes off.
    DampingDone,
}

impl std::fmt::Display for Cause {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::DevicesIdentified => write!(f, "all devices answered"),
            Self::Start => write!(f, "start"),
            Self::SoftStartDone => write!(f, "soft start done"),
            Self::ClipFinished => write!(f, "clip finished"),
            Self::TimeUp => write!(f, "run time up"),
            Self::StopRequested => write!(f, "stop requested"),
            Self::StaleFeedback { joint, name, cycles } => {
                write!(f, "joint {name} ({joint}): no feedback for {cycles} bus cycles")
            }
            Self::StaleImu { ticks: u32::MAX } => write!(f, "IMU: never sent a sample"),
            Self::StaleImu { ticks } => write!(f, "IMU: no sample for {ticks} ticks"),
            Self::DeviceFault { joint, name } => write!(f, "joint {name} ({joint}): device fault"),
            Self::ImplausibleFeedback {
                joint,
                name,
                what,
                value,
                bound,
            } => {
                match joint {
                    Some(j) => write!(f, "joint {name} ({j}): ")?,
                    None => write!(f, "{name}: ")?,
                }
                write!(
                    f,
                    "implausible {what} {value:.4e} (a working device reads within {bound:.1}): device fault"
                )
            }
            Self::NonFinite { what } => write!(f, "non-finite {what}"),
            Self::Tilt { angle } => write!(f, "base tilted {:.0}°", angle.to_degrees()),
            Self::Overruns { count } => write!(f, "{count} deadline overruns in a row"),
            Self::TrackingError {
                joint,
                name,
                error,
                limit,
                limit_s,
            } => write!(
                f,
                "joint {name} ({joint}): {:.0}° from its target, beyond its {:.0}° for more than {limit_s} s",
                error.to_degrees(),
                limit.to_degrees()
            ),
            Self::ImuSaturated { g, ticks } => write!(
                f,
                "IMU: the accelerometer reads {g:.1} g for {ticks} ticks (saturated or broken; a robot feels about 1 g)"
            ),
            Self::SimulationFailed => write!(f, "the mirror's simulation diverged"),
            Self::MirrorBehind { ms, stale, .. } => write!(
                f,
                "the mirror fell {ms} ms behind real time (its host did not give its physics or its \
                 servers the CPU in time): {stale}'s replies went stale or its emulated watchdog fired \
                 for it, not for a fault of its own"
            ),
            Self::EstimateInvalid(why) => write!(f, "the state estimate the policy reads is invalid: {why}"),
            Self::EStop => write!(f, "e-stop"),
            Self::BusFailure => write!(f, "bus failure"),
            Self::HoldDone => write!(f, "hold or blend done"),
            Self::DampingDone => write!(f, "damping done"),
        }
    }
}

impl Cause {
    /// Whether the robot goes straight to damping, without a hold: a joint's bus has damped
    /// itself already (stale or faulted device), or a device reads what none can (holding a
    /// position on a broken encoder's word could throw the joint), and the rest follow within
    /// the tick.
    pub fn damps_at_once(&self) -> bool {
        matches!(
            self,
            Self::StaleFeedback { .. }
                | Self::DeviceFault { .. }
                | Self::ImplausibleFeedback { .. }
                | Self::MirrorBehind { joint: true, .. }
        )
    }

    /// Whether this is a fault (as opposed to the normal course of a run).
    pub fn is_fault(&self) -> bool {
        !matches!(
            self,
            Self::DevicesIdentified
                | Self::Start
                | Self::SoftStartDone
                | Self::ClipFinished
                | Self::TimeUp
                | Self::StopRequested
                | Self::HoldDone
                | Self::DampingDone
        )
    }
}

/// One transition of the state machine.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Transition {
    /// Control tick.
    pub tick: u64,
    /// From.
    pub from: Mode,
    /// To.
    pub to: Mode,
    /// Why.
    pub cause: Cause,
}

/// Thresholds of the safety checks.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SafetyLimits {
    /// Bus cycles in a row without a reply that make a joint stale: its bus damps itself at
    /// once, and the loop damps the rest (links without bus cycles, such as a replay, are judged
    /// by the loop on the counts they report). At least 1.
    #[serde(alias = "stale_ticks")]
    pub stale_cycles: u32,
    /// Largest base tilt from upright, rad.
    pub tilt: f64,
    /// Overruns in a row that stop the robot.
    pub overruns: u32,
    /// Margin inside the joint position limits, rad.
    pub position_margin: f64,
    /// Largest tolerated distance of a joint from its position target, rad …
    pub tracking_error: f64,
    /// … for more than this many ticks in a row (robot.toml `[safety]` gives joints their own).
    pub tracking_ticks: u32,
}

/// One joint's tracking-error stop: its threshold, rad, and the ticks it may be exceeded.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TrackingLimit {
    /// Largest distance from the target, rad.
    pub error: f64,
    /// Ticks in a row beyond it that stop the robot.
    pub ticks: u32,
}

impl SafetyLimits {
    /// The limits with robot.toml's `[safety]` taken in (its tilt), and each joint's
    /// tracking-error stop for a loop ticking every `dt` s.
    pub fn for_robot(mut self, robot: &robots::Robot, dt: f64) -> (Self, Vec<TrackingLimit>) {
        let safety = &robot.config.safety;
        if let Some(t) = safety.tilt {
            self.tilt = t;
        }
        let per_joint = safety
            .tracking_limits(
                &robot.config.joints,
                self.tracking_error,
                f64::from(self.tracking_ticks) * dt,
            )
            .into_iter()
            .map(|(error, s)| TrackingLimit {
                error,
                ticks: (s / dt).round().max(1.0) as u32,
            })
            .collect();
        (self, per_joint)
    }
}

impl Default for SafetyLimits {
    fn default() -> Self {
        Self {
            stale_cycles: robot_link::STALE_CYCLES,
            tilt: 0.8,
            overruns: 5,
            position_margin: 0.02,
            tracking_error: 0.5,
            tracking_ticks: 25,
        }
    }
}

/// Angle between the base's z axis and the vertical, from the IMU orientation `[w, x, y, z]`.
pub fn tilt_of(q: [f64; 4]) -> f64 {
    robots::spatial::angle_between(robots::spatial::quat_rotate(q, [0.0, 0.0, 1.0]), [0.0, 0.0, 1.0])
}

/// The checks that stop a run, on the measured state each tick: e-stop, stale or faulted devices,
/// a silent IMU, non-finite readings, tilt, joints stuck far from their targets, overruns, a stop
/// request. Reads only the loop's own buffers: no lock, no I/O, no allocation.
#[derive(Debug)]
pub struct SafetyMonitor {
    limits: SafetyLimits,
    /// Each joint's tracking-error stop, and its name.
    tracking: Vec<TrackingLimit>,
    names: Vec<JointName>,
    /// The loop's period, s.
    dt: f64,
    /// IMU staleness limit in ticks: two of its periods, at least two ticks and the joints' limit.
    imu_limit: u32,
    /// Ticks in a row each joint has been beyond the tracking limit.
    off_target: Vec<u32>,
    /// Deadline overruns in a row.
    overrun_run: u32,
    /// Ticks in a row the accelerometer read beyond [`SATURATED_G`].
    saturated_run: u32,
    /// What each joint can read at all (none: not checked).
    plausible: Vec<PlausibleJoint>,
}

/// The readings a working joint gives: its position within its limits widened by
/// [`PLAUSIBLE_POSITION_MARGIN`], its speed and torque within [`PLAUSIBLE_FACTOR`] times its
/// limits.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PlausibleJoint {
    /// Positions, rad.
    pub position: [f64; 2],
    /// Largest speed, rad/s.
    pub speed: f64,
    /// Largest torque, N·m.
    pub torque: f64,
}

/// How far beyond its limits a joint may read before the reading is no joint's, rad: half a turn
/// (limits narrower than the mechanism, a fall, an encoder's turn count are all well within it).
pub const PLAUSIBLE_POSITION_MARGIN: f64 = std::f64::consts::PI;
/// How many times its speed and torque limits a joint may read (a fall's impacts, a motor whose
/// range is wider than its limit).
pub const PLAUSIBLE_FACTOR: f64 = 10.0;
/// The fastest turn a robot's IMU reads, rad/s (4000 °/s: beyond every MEMS gyro's range).
pub const PLAUSIBLE_GYRO: f64 = 70.0;
/// How far an orientation quaternion's norm may be from 1.
pub const PLAUSIBLE_QUAT_NORM: f64 = 0.1;

impl PlausibleJoint {
    /// For joint `j` of robot.toml.
    pub fn of(j: &JointConfig) -> Self {
        let [lo, hi] = j.position_limits;
        Self {
            position: [lo - PLAUSIBLE_POSITION_MARGIN, hi + PLAUSIBLE_POSITION_MARGIN],
            speed: PLAUSIBLE_FACTOR * j.velocity_limit,
            torque: PLAUSIBLE_FACTOR * j.torque_limit,
        }
    }
}

/// An accelerometer reading this many g for longer than the IMU's staleness limit is saturated
/// or broken: a robot's impacts pass in milliseconds, standing and walking feel about one g.
pub const SATURATED_G: f64 = 8.0;

/// Ticks in a row without a new IMU sample before the IMU counts as stale — for the safety stop
/// and for the state estimate alike (one limit: an estimate that gave up after 2 ticks stopped
/// wall-clock runs of a slow IMU the monitor would have let go on): the joints' allowance
/// (`stale_cycles`), at least 2 ticks, and [`IMU_STALE_PERIODS`] of the IMU's own periods.
pub fn imu_stale_ticks(limits: &SafetyLimits, dt: f64, imu_rate_hz: f64) -> u32 {
    limits
        .stale_cycles
        .max(2)
        .max((IMU_STALE_PERIODS / (dt * imu_rate_hz)).ceil() as u32)
}

/// The IMU's own periods without a sample it may miss (a slow IMU over a serial line on a busy
/// machine drops a few; the joints get as many of their bus's cycles on the wall clock).
pub const IMU_STALE_PERIODS: f64 = 8.0;

impl SafetyMonitor {
    /// The IMU's stale limit, ticks ([`imu_stale_ticks`]).
    pub fn imu_limit(&self) -> u32 {
        self.imu_limit
    }

    /// A monitor for the joints `names` with their tracking-error stops, a loop ticking every
    /// `dt` s and an IMU at `imu_rate_hz`.
    pub fn new(
        limits: SafetyLimits,
        tracking: Vec<TrackingLimit>,
        names: &[String],
        dt: f64,
        imu_rate_hz: f64,
    ) -> Self {
        Self {
            imu_limit: imu_stale_ticks(&limits, dt, imu_rate_hz),
            limits,
            off_target: vec![0; tracking.len()],
            tracking,
            names: names.iter().map(|n| JointName::new(n)).collect(),
            dt,
            overrun_run: 0,
            saturated_run: 0,
            plausible: Vec::new(),
        }
    }

    /// Judges every joint's reading against what it can read at all (robot joint order).
    pub fn with_plausible(mut self, joints: Vec<PlausibleJoint>) -> Self {
        self.plausible = joints;
        self
    }

    /// The first reading no working device gives, if any.
    fn implausible(&self, s: &robot_link::RobotState) -> Option<Cause> {
        let at = |joint: usize, what, value: f64, bound: f64| Cause::ImplausibleFeedback {
            joint: Some(joint),
            name: self.name(joint),
            what,
            value,
            bound,
        };
        for (j, p) in self.plausible.iter().enumerate() {
            let (q, qd, tau) = (s.q[j], s.qd[j], s.tau.get(j).copied().unwrap_or(0.0));
            if !(p.position[0]..=p.position[1]).contains(&q) {
                let bound = if q < p.position[0] {
                    p.position[0]
                } else {
                    p.position[1]
                };
                return Some(at(j, "position (rad)", q, bound));
            }
            if qd.abs() > p.speed {
                return Some(at(j, "speed (rad/s)", qd, p.speed));
            }
            if tau.abs() > p.torque {
                return Some(at(j, "torque (N·m)", tau, p.torque));
            }
        }
        let imu = |what, value: f64, bound: f64| Cause::ImplausibleFeedback {
            joint: None,
            name: JointName::new("IMU"),
            what,
            value,
            bound,
        };
        let spin = robots::spatial::norm(s.gyro);
        if spin > PLAUSIBLE_GYRO {
            return Some(imu("turn rate (rad/s)", spin, PLAUSIBLE_GYRO));
        }
        let norm = s.quat.iter().map(|v| v * v).sum::<f64>().sqrt();
        if (norm - 1.0).abs() > PLAUSIBLE_QUAT_NORM {
            return Some(imu(
                "orientation quaternion norm",
                norm,
                1.0 + PLAUSIBLE_QUAT_NORM,
            ));
        }
        None
    }

    /// The joint's name (empty past the robot's joints).
    fn name(&self, joint: usize) -> JointName {
        self.names.get(joint).copied().unwrap_or_default()
    }

    /// Notes whether the last tick missed its deadline.
    pub fn deadline(&mut self, missed: bool) {
        self.overrun_run = if missed { self.overrun_run + 1 } else { 0 };
    }

    /// The first reason to stop in `mode` given the measured `state` and the `targets` last sent.
    pub fn check(
        &mut self,
        mode: Mode,
        state: &robot_link::RobotState,
        targets: &[robot_link::JointTarget],
        estop: bool,
        stop_requested: bool,
    ) -> Option<Cause> {
        // Joints under stiffness that stay far from their targets (blocked, or zero/direction
        // wrong), counted while the policy is in control: a PD start on a robot that cannot stand
        // on its joints alone sags far from its targets without anything being wrong.
        let tracking = mode == Mode::Running;
        for (((count, t), &q), limit) in self
            .off_target
            .iter_mut()
            .zip(targets)
            .zip(&state.q)
            .zip(&self.tracking)
        {
            let off = tracking && t.enabled && t.kp > 0.0 && (t.q - q).abs() > limit.error;
            *count = if off { count.saturating_add(1) } else { 0 };
        }
        let g = robots::spatial::norm(state.accel) / 9.80665;
        // Counted from the first tick, so a stream saturated from the start stops the soft start
        // before it commands anything.
        self.saturated_run = if g > SATURATED_G {
            self.saturated_run.saturating_add(1)
        } else {
            0
        };
        if !matches!(mode, Mode::SoftStart | Mode::Running | Mode::Stopping) {
            return None;
        }
        if estop {
            return Some(Cause::EStop);
        }
        let (s, lim) = (state, &self.limits);
        if let Some(joint) = (0..s.missed.len()).find(|&j| s.stale[j] || s.missed[j] >= lim.stale_cycles) {
            return Some(Cause::StaleFeedback {
                joint,
                name: self.name(joint),
                cycles: s.missed[joint].max(lim.stale_cycles),
            });
        }
        if let Some(joint) = s.faulted.iter().position(|&f| f) {
            return Some(Cause::DeviceFault {
                joint,
                name: self.name(joint),
            });
        }
        if s.imu_missed > self.imu_limit {
            return Some(Cause::StaleImu { ticks: s.imu_missed });
        }
        if self.saturated_run > self.imu_limit {
            return Some(Cause::ImuSaturated {
                g,
                ticks: self.saturated_run,
            });
        }
        let finite = |v: &[f64]| v.iter().all(|x| x.is_finite());
        if !(finite(&s.q) && finite(&s.qd) && finite(&s.gyro) && finite(&s.quat)) {
            return Some(Cause::NonFinite { what: "state" });
        }
        if let Some(cause) = self.implausible(s) {
            return Some(cause);
        }
        let tilt = tilt_of(s.quat);
        if tilt > lim.tilt {
            return Some(Cause::Tilt { angle: tilt });
        }
        if let Some(joint) = self
            .off_target
            .iter()
            .zip(&self.tracking)
            .position(|(&t, limit)| t > limit.ticks)
        {
            let limit = self.tracking[joint];
            return Some(Cause::TrackingError {
                joint,
                name: self.name(joint),
                error: targets[joint].q - s.q[joint],
                limit: limit.error,
                limit_s: f64::from(limit.ticks) * self.dt,
            });
        }
        if self.overrun_run >= lim.overruns {
            return Some(Cause::Overruns {
                count: self.overrun_run,
            });
        }
        if stop_requested && mode != Mode::Stopping {
            return Some(Cause::StopRequested);
        }
        None
    }
}

/// A mirror this far behind real time when a device's feedback goes stale is blamed for it: its
/// devices answer that late, beyond what a working line's jitter explains.
pub const MIRROR_BEHIND_BLAME: std::time::Duration = std::time::Duration::from_millis(5);

impl Cause {
    /// This cause as the served mirror's, where it is a stale or faulted device's and the mirror
    /// was `behind` real time by more than [`MIRROR_BEHIND_BLAME`] (a late mirror answers late, and
    /// its emulated watchdogs fire when it catches up in a burst).
    pub fn blaming_a_late_mirror(self, behind: std::time::Duration) -> Self {
        if behind <= MIRROR_BEHIND_BLAME {
            return self;
        }
        let ms = u32::try_from(behind.as_millis()).unwrap_or(u32::MAX);
        match self {
            Self::StaleFeedback { name, .. } => Self::MirrorBehind {
                ms,
                stale: name,
                joint: true,
            },
            Self::StaleImu { .. } => Self::MirrorBehind {
                ms,
                stale: JointName::new("IMU"),
                joint: false,
            },
            // An emulated motor whose commands' watchdog fired because its clock jumped ahead
            // when the late mirror caught up.
            Self::DeviceFault { name, .. } => Self::MirrorBehind {
                ms,
                stale: name,
                joint: true,
            },
            other => other,
        }
    }
}

/// Where a joint's position targets may lie: inside its limits less `margin`, or with
/// [`robots::PositionTargets::TorqueReach`] beyond them by as far as its torque limit reaches at
/// stiffness `kp` (no farther: past that the PD's torque saturates anyway).
pub fn target_range(j: &JointConfig, margin: f64, targets: robots::PositionTargets, kp: f64) -> [f64; 2] {
    let [lo, hi] = j.position_limits;
    match targets {
        robots::PositionTargets::TorqueReach if kp > 0.0 => {
            let reach = j.torque_limit / kp;
            [lo - reach, hi + reach]
        }
        _ => [lo + margin, hi - margin],
    }
}

/// How the governor bounds a policy's position targets: the margin inside the limits, or how far
/// past them a target may lie ([`target_range`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TargetRule {
    /// Margin inside the joint limits, rad.
    pub margin: f64,
    /// Where targets may lie.
    pub targets: robots::PositionTargets,
}

impl TargetRule {
    /// The range of joint `j`'s targets at stiffness `kp`.
    pub fn range(&self, j: &JointConfig, kp: f64) -> [f64; 2] {
        target_range(j, self.margin, self.targets, kp)
    }
}

/// Clamps a position target into `range` (see [`target_range`]) and the joint's speed limit from
/// the previous target over `dt`; returns the target sent.
pub fn govern_position(
    j: &JointConfig,
    previous: f64,
    wanted: f64,
    dt: f64,
    range: [f64; 2],
    rate_limit: Option<f64>,
) -> f64 {
    let max_step = rate_limit.unwrap_or(j.velocity_limit).min(j.velocity_limit) * dt;
    // A previous target that is not a number (a replay's missing reading) bounds nothing; it
    // must not panic the loop. A wanted NaN stays NaN for the caller's non-finite check.
    let stepped = if previous.is_finite() && max_step.is_finite() && max_step >= 0.0 {
        wanted.clamp(previous - max_step, previous + max_step)
    } else {
        wanted
    };
    stepped.clamp(range[0], range[1])
}

/// Clamps a feed-forward torque into the joint's torque limit.
pub fn govern_torque(j: &JointConfig, tau: f64) -> f64 {
    tau.clamp(-j.torque_limit, j.torque_limit)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;

    #[test]
    fn stale_feedback_from_a_mirror_behind_real_time_is_the_mirrors() {
        let stale = Cause::StaleFeedback {
            joint: 3,
            name: JointName::new("left_knee"),
            cycles: 8,
        };
        // On time, or within a line's jitter: the joint's.
        assert_eq!(stale.blaming_a_late_mirror(Duration::ZERO), stale);
        assert_eq!(stale.blaming_a_late_mirror(MIRROR_BEHIND_BLAME), stale);
        // 40 ms behind: the mirror's, and the robot still damps at once as for the joint.
        let blamed = stale.blaming_a_late_mirror(Duration::from_millis(40));
        assert!(
            matches!(
                blamed,
                Cause::MirrorBehind {
                    ms: 40,
                    joint: true,
                    ..
                }
            ),
            "{blamed:?}"
        );
        assert!(blamed.damps_at_once() && blamed.is_fault());
        assert!(
            blamed
                .to_string()
                .starts_with("the mirror fell 40 ms behind real time"),
            "{blamed}"
        );
        let imu = Cause::StaleImu { ticks: 3 }.blaming_a_late_mirror(Duration::from_millis(40));
        assert!(imu.to_string().contains("IMU's replies went stale"), "{imu}");
        let fault = Cause::DeviceFault {
            joint: 4,
            name: JointName::new("left_ankle_pitch"),
        };
        assert!(matches!(
            fault.blaming_a_late_mirror(Duration::from_millis(40)),
            Cause::MirrorBehind { joint: true, .. }
        ));
        assert_eq!(fault.blaming_a_late_mirror(Duration::from_millis(1)), fault);
        // Other causes stay theirs.
        let tilt = Cause::Tilt { angle: 1.0 };
        assert_eq!(tilt.blaming_a_late_mirror(Duration::from_millis(40)), tilt);
    }

    #[test]
    fn the_governor_never_panics_on_a_target_that_is_not_a_number() {
        let j = joint();
        let range = [-1.0, 1.0];
        assert_eq!(govern_position(&j, f64::NAN, 0.5, 0.02, range, None), 0.5);
        assert_eq!(govern_position(&j, f64::NAN, 5.0, 0.02, range, None), 1.0);
        assert!(govern_position(&j, 0.0, f64::NAN, 0.02, range, None).is_nan());
        assert_eq!(govern_position(&j, 0.0, 0.5, 0.02, range, None), 0.2);
    }

    #[test]
    fn a_saturated_accelerometer_stops_the_soft_start_and_an_impact_does_not() {
        let mut monitor = SafetyMonitor::new(SafetyLimits::default(), Vec::new(), &[], 0.02, 200.0);
        let mut state = robot_link::RobotState::new(0);
        state.imu_missed = 0;
        // An impact: 12 g for one tick, then gravity again.
        state.accel = [0.0, 0.0, 12.0 * 9.81];
        assert_eq!(monitor.check(Mode::Running, &state, &[], false, false), None);
        state.accel = [0.0, 0.0, 9.81];
        assert_eq!(monitor.check(Mode::Running, &state, &[], false, false), None);
        // A stream stuck at full scale from the first tick: refused as soon as the soft start
        // would begin.
        let mut monitor = SafetyMonitor::new(SafetyLimits::default(), Vec::new(), &[], 0.02, 200.0);
        state.accel = [32.0 * 9.81, 0.0, 0.0];
        for _ in 0..5 {
            assert_eq!(monitor.check(Mode::Ready, &state, &[], false, false), None);
        }
        let cause = monitor.check(Mode::SoftStart, &state, &[], false, false);
        assert!(matches!(cause, Some(Cause::ImuSaturated { .. })), "{cause:?}");
        assert!(cause.unwrap().to_string().contains("reads 32.0 g"));
    }

    #[test]
    fn an_imu_that_never_sent_says_never_not_four_billion_ticks() {
        assert_eq!(
            Cause::StaleImu { ticks: u32::MAX }.to_string(),
            "IMU: never sent a sample"
        );
        assert_eq!(
            Cause::StaleImu { ticks: 3 }.to_string(),
            "IMU: no sample for 3 ticks"
        );
    }

    fn joint() -> JointConfig {
        JointConfig {
            name: "knee".into(),
            mjcf_joint: "knee".into(),
            bus: "can0".into(),
            id: 1,
            model: "AK10-9".into(),
            direction: 1.0,
            zero_offset: 0.0,
            homing_offset_ticks: 0,
            gear: 1.0,
            position_limits: [0.0, 2.0],
            velocity_limit: 10.0,
            torque_limit: 30.0,
            default_position: 0.5,
            kp: 100.0,
            kd: 2.0,
        }
    }

    #[test]
    fn targets_stay_inside_limits_and_speed() {
        let j = joint();
        let inside = target_range(&j, 0.02, robots::PositionTargets::InsideLimits, 100.0);
        // Beyond the upper limit: clamped to limit − margin.
        assert_eq!(govern_position(&j, 1.97, 5.0, 0.02, inside, None), 1.98);
        // A jump of 1 rad in one 20 ms tick at 10 rad/s: 0.2 rad.
        assert!((govern_position(&j, 1.0, 0.0, 0.02, inside, None) - 0.8).abs() < 1e-12);
        // A tighter policy rate limit wins.
        assert!((govern_position(&j, 1.0, 0.0, 0.02, inside, Some(5.0)) - 0.9).abs() < 1e-12);
        // Torque reach: 30 N·m at 100 N·m/rad reaches 0.3 rad past either limit, and no farther.
        let reach = target_range(&j, 0.02, robots::PositionTargets::TorqueReach, 100.0);
        assert_eq!(reach, [-0.3, 2.3]);
        assert!((govern_position(&j, 2.25, 5.0, 0.02, reach, None) - 2.3).abs() < 1e-12);
        // Without stiffness (a torque-controlled joint) the target stays inside.
        assert_eq!(
            target_range(&j, 0.02, robots::PositionTargets::TorqueReach, 0.0),
            inside
        );
        assert_eq!(govern_torque(&j, -100.0), -30.0);
    }

    #[test]
    fn tilt_is_the_angle_from_upright() {
        assert_eq!(tilt_of([1.0, 0.0, 0.0, 0.0]), 0.0);
        let a: f64 = 0.3;
        let t = tilt_of([(a / 2.0).cos(), (a / 2.0).sin(), 0.0, 0.0]);
        assert!((t - a).abs() < 1e-12);
        // Yaw is not tilt.
        assert!(tilt_of([(a / 2.0).cos(), 0.0, 0.0, (a / 2.0).sin()]) < 1e-12);
    }
}
