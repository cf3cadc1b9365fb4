//! Run telemetry as MCAP: the loop fills a fixed-size [`TickRecord`] and pushes it into a
//! preallocated ring (a bounded channel); a logger thread turns each record into typed protobuf
//! messages — Foxglove's well-known schemas where one fits (`/tf` frame transforms, `/robot` the
//! robot's geometry, `/anchor/*` poses, `/log`), the project's own documented ones elsewhere
//! (`telemetry-schema`: joint states, commands, policy I/O, safety, IMU, timing, estimate, bus
//! cycles) — and writes an lz4-compressed MCAP file that Foxglove, Rerun and Python's `mcap`
//! read, and the live view serves. `/replay` keeps the loop's inputs at full precision (JSON)
//! for `robodeploy replay`.
//!
//! In wall-clock runs the loop never waits for the logger: a full ring drops the record and counts
//! it. In lockstep runs simulated time can wait, so the loop blocks instead and nothing is dropped.

mod messages;
mod ros2;

pub use ros2::Ros2Config;

use robot_link::CycleRecord;
use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::io::BufWriter;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};

use robot_link::IMU_HISTORY;

/// Most joints a record carries.
pub const MAX_JOINTS: usize = 48;
/// A tick's state estimate for the recording.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct EstimateRecord {
    /// The robot has an estimator.
    pub present: bool,
    /// What it said.
    pub estimate: world::estimator::Estimate,
    /// Ground truth in the estimate's frame, root pose and base-frame velocity (simulation).
    pub truth: Option<([f64; 7], [f64; 3])>,
}

/// Tracked motion bodies a tick record holds errors for.
pub const MAX_BODIES: usize = 32;

/// Most feet a record carries.
pub const MAX_FEET: usize = 8;

/// Everything the loop knows at the end of one tick, in fixed-size arrays (robot joint order).
/// Inputs (what the buses, the IMU and the simulator said) and outputs (the targets sent) are kept
/// at full precision, so a replay can feed the same inputs and compare outputs bit for bit.
#[derive(Debug, Clone, Copy)]
pub struct TickRecord {
    /// Tick number.
    pub tick: u64,
    /// Run time at the tick, ns.
    pub time_ns: u64,
    /// Safety mode (as its name's index in [`MODE_NAMES`]).
    pub mode: u8,
    /// Joints in use.
    pub joints: u16,
    /// Feet in use.
    pub feet: u8,
    /// Measured positions, rad.
    pub q: [f64; MAX_JOINTS],
    /// Measured velocities, rad/s.
    pub qd: [f64; MAX_JOINTS],
    /// Measured torques, N·m.
    pub tau: [f64; MAX_JOINTS],
    /// Consecutive bus cycles without a reply per joint.
    pub missed: [u32; MAX_JOINTS],
    /// The joint's bus damped itself for its silence (latched until torque goes off).
    pub stale: [bool; MAX_JOINTS],
    /// Age of each joint's sample when the tick read it, ms.
    pub age_ms: [f32; MAX_JOINTS],
    /// Device fault flags per joint.
    pub faulted: [bool; MAX_JOINTS],
    /// IMU gyro, accelerometer, orientation `[w, x, y, z]`.
    pub imu: [f64; 10],
    /// Consecutive reads without an IMU sample.
    pub imu_missed: u32,
    /// Age of the IMU sample when the tick read it, ms.
    pub imu_age_ms: f32,
    /// Ground-truth base pose `[x, y, z, w, qx, qy, qz]` (simulation), NaN when unknown.
    pub base_pose: [f64; 7],
    /// Ground-truth base linear velocity in the base frame.
    pub base_lin_vel: [f64; 3],
    /// Ground-truth foot contacts.
    pub foot_contacts: [bool; MAX_FEET],
    /// Whether a stop had been requested when the tick ran.
    pub stop_requested: bool,
    /// Whether the simulation had diverged (ground truth says so).
    pub simulation_failed: bool,
    /// How far a mirror served in real time was behind the wall clock, µs.
    pub mirror_behind_us: u64,
    /// Commanded targets: q, qd, kp, kd, tau.
    pub target: [[f64; 5]; MAX_JOINTS],
    /// Commanded torque on/off.
    pub enabled: [bool; MAX_JOINTS],
    /// Reference positions, rad.
    pub reference_q: [f32; MAX_JOINTS],
    /// Reference root pose `[x, y, z, w, qx, qy, qz]`.
    pub reference_root: [f64; 7],
    /// Whether the tick's sample entered the run's tracking metrics (the clip itself, not the
    /// start-up ramp or the end).
    pub tracking: bool,
    /// Whether the policy drove the robot this tick (running, or settling under it after a
    /// stop): the window of a command-driven run's figures.
    pub policy_ran: bool,
    /// The robot's anchor and the reference's (aligned), `[x, y, z, w, qx, qy, qz]`, when the
    /// policy observes an anchor.
    pub anchors: Option<([f64; 7], [f64; 7])>,
    /// The state estimate of the tick (and, in simulation, the truth in its frame).
    pub estimate: EstimateRecord,
    /// The IMU samples the tick integrated: time s, gyro, accel, quaternion (11 values each).
    pub imu_samples: [[f64; 11]; IMU_HISTORY],
    /// Samples in use.
    pub imu_sample_count: u8,
    /// Position error of each tracked motion body, m (simulation), `bodies` in use.
    pub body_errors: [f32; MAX_BODIES],
    /// Tracked bodies with an error this tick.
    pub bodies: u8,
    /// A generated reference: where it stood.
    pub generated: Option<crate::generator::GeneratedTick>,
    /// 2D keypoint errors per view (mean, max, mean du, mean dv px; keypoints compared),
    /// `keypoint_views` in use (0: not measured this tick).
    pub keypoint_errors: [[f32; 5]; crate::keypoints::track::MAX_VIEWS],
    /// Views in use.
    pub keypoint_views: u8,
    /// The triangulated keypoint error, mm (NaN without).
    pub triangulated_mm: f32,
    /// Raw policy actions (policy order).
    pub action: [f32; MAX_JOINTS],
    /// The live commands in force (command-driven policies), `command_count` in use.
    pub commands: [f64; human::commands::MAX_COMMANDS],
    /// Commands in use.
    pub command_count: u8,
    /// Bus I/O time of the tick, µs.
    pub io_us: f32,
    /// Compute time, µs.
    pub compute_us: f32,
    /// Time each bus took (read + write), µs, in [`RecordingInfo::bus_names`] order.
    pub bus_us: [f32; 8],
    /// Buses in use.
    pub buses: u8,
    /// The cause of the latest transition, UTF-8, `cause_len` bytes.
    pub cause: [u8; 64],
    /// Bytes of `cause` in use.
    pub cause_len: u8,
    /// Whether that cause is a fault (a safety stop), not the normal course of a run.
    pub cause_fault: bool,
    /// A harness start's phase.
    pub harness: crate::options::HarnessPhase,
}

impl Default for TickRecord {
    fn default() -> Self {
        Self {
            tick: 0,
            time_ns: 0,
            mode: 0,
            joints: 0,
            feet: 0,
            q: [0.0; MAX_JOINTS],
            qd: [0.0; MAX_JOINTS],
            tau: [0.0; MAX_JOINTS],
            missed: [0; MAX_JOINTS],
            stale: [false; MAX_JOINTS],
            age_ms: [0.0; MAX_JOINTS],
            faulted: [false; MAX_JOINTS],
            imu: [0.0; 10],
            imu_missed: 0,
            imu_age_ms: 0.0,
            base_pose: [f64::NAN; 7],
            base_lin_vel: [0.0; 3],
            foot_contacts: [false; MAX_FEET],
            stop_requested: false,
            simulation_failed: false,
            mirror_behind_us: 0,
            target: [[0.0; 5]; MAX_JOINTS],
            enabled: [false; MAX_JOINTS],
            reference_q: [0.0; MAX_JOINTS],
            reference_root: [0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0],
            tracking: false,
            policy_ran: false,
            anchors: None,
            estimate: EstimateRecord::default(),
            imu_samples: [[0.0; 11]; IMU_HISTORY],
            imu_sample_count: 0,
            body_errors: [0.0; MAX_BODIES],
            bodies: 0,
            generated: None,
            keypoint_errors: [[0.0; 5]; crate::keypoints::track::MAX_VIEWS],
            keypoint_views: 0,
            triangulated_mm: f32::NAN,
            action: [0.0; MAX_JOINTS],
            commands: [0.0; human::commands::MAX_COMMANDS],
            command_count: 0,
            io_us: 0.0,
            compute_us: 0.0,
            bus_us: [0.0; 8],
            buses: 0,
            cause: [0; 64],
            cause_len: 0,
            cause_fault: false,
            harness: crate::options::HarnessPhase::None,
        }
    }
}

/// Names of the modes, by [`TickRecord::mode`].
pub const MODE_NAMES: [&str; 6] = ["Off", "Ready", "SoftStart", "Running", "Stopping", "Damped"];

/// What the loop knows at the end of a tick, for its record.
#[derive(Debug, Clone, Copy)]
pub struct TickView<'a> {
    /// Tick number.
    pub tick: u64,
    /// Run time.
    pub now: std::time::Duration,
    /// Safety mode.
    pub mode: crate::safety::Mode,
    /// The measured state.
    pub state: &'a robot_link::RobotState,
    /// The targets sent.
    pub targets: &'a [robot_link::JointTarget],
    /// The reference, robot order.
    pub reference_q: &'a [f64],
    /// The reference root pose.
    pub reference_root: [f64; 7],
    /// Whether the tick's sample entered the tracking metrics.
    pub tracking: bool,
    /// Whether the policy drove the robot this tick.
    pub policy_ran: bool,
    /// The robot's anchor and the reference's, when the policy observes one.
    pub anchors: Option<([f64; 7], [f64; 7])>,
    /// Position errors of the tracked motion bodies, m (empty when unknown).
    pub body_errors: &'a [f64],
    /// A generated reference: where it stood.
    pub generated: Option<crate::generator::GeneratedTick>,
    /// The 2D keypoint errors of this tick per view (empty when not measured).
    pub keypoint_errors: &'a [crate::keypoints::track::ViewTick],
    /// This tick's triangulated keypoint error, mm.
    pub triangulated_mm: Option<f64>,
    /// The state estimate, for a robot with an estimator.
    pub estimate: Option<&'a world::estimator::Estimate>,
    /// Ground truth in the estimate's frame: root pose and base-frame velocity (simulation).
    pub truth_in_world: Option<([f64; 7], [f64; 3])>,
    /// Raw actions.
    pub actions: &'a [f32],
    /// The live commands in force (empty without).
    pub commands: &'a [f64],
    /// Simulation ground truth (its pose counts only with `has_truth`).
    pub truth: &'a robot_link::GroundTruth,
    /// Whether the clock had ground truth this tick.
    pub has_truth: bool,
    /// Whether a stop had been requested.
    pub stop_requested: bool,
    /// Time each bus took.
    pub bus_times: &'a [std::time::Duration],
    /// Bus I/O of the tick.
    pub io: std::time::Duration,
    /// Compute of the tick.
    pub compute: std::time::Duration,
    /// The latest transition's cause.
    pub cause: Option<crate::safety::Cause>,
    /// A harness start's phase.
    pub harness: crate::options::HarnessPhase,
}

impl TickRecord {
    /// Copies `v` into this record (no allocation; lengths are capped at the record's sizes).
    pub fn fill(&mut self, v: &TickView<'_>) {
        let (state, r) = (v.state, self);
        let n = state.q.len().min(MAX_JOINTS);
        r.tick = v.tick;
        r.time_ns = v.now.as_nanos() as u64;
        r.mode = v.mode as u8;
        r.joints = n as u16;
        for i in 0..n {
            r.q[i] = state.q[i];
            r.qd[i] = state.qd[i];
            r.tau[i] = state.tau[i];
            r.missed[i] = state.missed[i];
            r.stale[i] = state.stale[i];
            r.age_ms[i] = (state.age[i].as_secs_f64() * 1e3) as f32;
            r.faulted[i] = state.faulted[i];
            let t = &v.targets[i];
            r.target[i] = [t.q, t.qd, t.kp, t.kd, t.tau];
            r.enabled[i] = t.enabled;
            r.reference_q[i] = v.reference_q[i] as f32;
        }
        r.reference_root = v.reference_root;
        r.tracking = v.tracking;
        r.policy_ran = v.policy_ran;
        r.anchors = v.anchors;
        r.estimate = match v.estimate {
            Some(e) => EstimateRecord {
                present: true,
                estimate: *e,
                truth: v.truth_in_world,
            },
            None => EstimateRecord::default(),
        };
        let samples = &state.imu_samples;
        r.imu_sample_count = samples.len().min(IMU_HISTORY) as u8;
        for (slot, s) in r.imu_samples.iter_mut().zip(samples) {
            slot[0] = s.at.as_secs_f64();
            slot[1..4].copy_from_slice(&s.gyro);
            slot[4..7].copy_from_slice(&s.accel);
            slot[7..].copy_from_slice(&s.quat);
        }
        r.generated = v.generated;
        let views = v.keypoint_errors.len().min(r.keypoint_errors.len());
        r.keypoint_views = views as u8;
        for (slot, e) in r.keypoint_errors.iter_mut().zip(&v.keypoint_errors[..views]) {
            *slot = [
                e.mean_px as f32,
                e.max_px as f32,
                e.mean_du_px as f32,
                e.mean_dv_px as f32,
                e.compared as f32,
            ];
        }
        r.triangulated_mm = v.triangulated_mm.map_or(f32::NAN, |m| m as f32);
        let b = v.body_errors.len().min(MAX_BODIES);
        r.bodies = b as u8;
        for (slot, e) in r.body_errors.iter_mut().zip(&v.body_errors[..b]) {
            *slot = *e as f32;
        }
        let m = v.actions.len().min(MAX_JOINTS);
        r.action[..m].copy_from_slice(&v.actions[..m]);
        let c = v.commands.len().min(r.commands.len());
        r.command_count = c as u8;
        r.commands[..c].copy_from_slice(&v.commands[..c]);
        r.imu[..3].copy_from_slice(&state.gyro);
        r.imu[3..6].copy_from_slice(&state.accel);
        r.imu[6..].copy_from_slice(&state.quat);
        r.imu_missed = state.imu_missed;
        r.imu_age_ms = (state.imu_age.as_secs_f64() * 1e3) as f32;
        let t = v.truth;
        r.base_pose = if v.has_truth { t.root_pose } else { [f64::NAN; 7] };
        r.base_lin_vel = t.base_lin_vel;
        let feet = t.foot_contacts.len().min(MAX_FEET);
        r.feet = feet as u8;
        r.foot_contacts[..feet].copy_from_slice(&t.foot_contacts[..feet]);
        r.stop_requested = v.stop_requested;
        r.simulation_failed = v.has_truth && t.simulation_failed;
        r.mirror_behind_us = if v.has_truth {
            u64::try_from(t.mirror_behind.as_micros()).unwrap_or(u64::MAX)
        } else {
            0
        };
        let b = v.bus_times.len().min(r.bus_us.len());
        r.buses = b as u8;
        for (slot, t) in r.bus_us.iter_mut().zip(&v.bus_times[..b]) {
            *slot = t.as_secs_f32() * 1e6;
        }
        r.io_us = v.io.as_secs_f32() * 1e6;
        r.compute_us = v.compute.as_secs_f32() * 1e6;
        r.harness = v.harness;
        if let Some(cause) = v.cause {
            use std::io::Write as _;
            let mut cursor = std::io::Cursor::new(&mut r.cause[..]);
            let _ = write!(cursor, "{cause}");
            r.cause_len = cursor.position() as u8;
            r.cause_fault = cause.is_fault();
        }
    }
}

/// Why a recording could not be written.
#[derive(Debug, thiserror::Error)]
pub enum TelemetryError {
    /// The file could not be created.
    #[error("cannot create {}: {source}", path.display())]
    Create {
        /// The recording.
        path: PathBuf,
        /// Why.
        source: std::io::Error,
    },
    /// The MCAP writer failed.
    #[error("{}: {message}", path.display())]
    Write {
        /// The recording.
        path: PathBuf,
        /// The writer's message.
        message: String,
    },
    /// The robot's model could not give the per-link frames.
    #[error(transparent)]
    Robot3d(#[from] viewers::robot3d::Robot3dError),
    /// The logger thread could not start, or died.
    #[error("telemetry logger: {0}")]
    Logger(String),
    /// The ROS 2 topics could not be set up.
    #[error("--ros2: {0}")]
    Ros2(#[from] dds::DdsError),
}

/// Target size of a recording's chunks, bytes by default (~0.3 s of a 50 Hz run).
pub const CHUNK_BYTES: u64 = 64 * 1024;

/// How a recording's chunks are compressed (MCAP's own compressions: every MCAP reader opens them).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub enum RecordingCompression {
    /// Stored as written: the least CPU, the largest file.
    None,
    /// LZ4 (the default): fast, about half the size.
    #[default]
    Lz4,
    /// Zstandard: a third of LZ4's size or less, more CPU on the recording's thread.
    Zstd,
}

impl RecordingCompression {
    /// Its name, as `--record-compression` takes it.
    pub fn name(self) -> &'static str {
        match self {
            Self::None => "none",
            Self::Lz4 => "lz4",
            Self::Zstd => "zstd",
        }
    }

    /// The highest level it takes (0 is always its default).
    pub fn max_level(self) -> u32 {
        match self {
            Self::None => 0,
            Self::Lz4 => 12,
            Self::Zstd => 19,
        }
    }
}

/// Channels whose rate a recording may lower (`--record-every TOPIC=N`): the per-tick streams a
/// viewer plots. `/replay` (every tick: `replay` feeds it back), the events (`/safety`, `/log`)
/// and what is written once (`/robot`, `/robot_description`) are always written whole.
pub const THINNABLE_TOPICS: [&str; 10] = [
    "/joint_state",
    "/joint_states",
    "/command",
    "/policy",
    "/imu",
    "/timing",
    "/estimator",
    "/tf",
    "/anchor/robot",
    "/anchor/reference",
];

/// How a recording is written: its compression, its chunks, and which channels at what rate. The
/// default writes every channel every tick, LZ4 in 64 KiB chunks.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RecordingSettings {
    pub compression: RecordingCompression,
    /// The compressor's level, 0 for its default (LZ4 up to 12, Zstandard up to 19).
    pub level: u32,
    /// Target chunk size, bytes: a crash loses at most the chunk being built; larger chunks
    /// compress better.
    pub chunk_bytes: u64,
    /// Channels written every N ticks instead of every tick (0: not at all), of
    /// [`THINNABLE_TOPICS`]. The live view and ROS 2 get what the file gets, except ROS 2's
    /// `/tf` and `/joint_states`, which keep the tick rate.
    pub every: Vec<(String, u32)>,
}

impl Default for RecordingSettings {
    fn default() -> Self {
        Self {
            compression: RecordingCompression::default(),
            level: 0,
            chunk_bytes: CHUNK_BYTES,
            every: Vec::new(),
        }
    }
}

impl RecordingSettings {
    /// How often `topic` is written, ticks (0: never).
    fn every(&self, topic: &str) -> u32 {
        self.every
            .iter()
            .rev()
            .find(|(t, _)| t == topic)
            .map_or(1, |&(_, n)| n)
    }
}

impl std::fmt::Display for RecordingSettings {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}", self.compression.name())?;
        if self.level > 0 {
            write!(f, " level {}", self.level)?;
        }
        write!(f, " in {} KiB chunks", self.chunk_bytes / 1024)?;
        for (topic, n) in &self.every {
            match n {
                0 => write!(f, ", {topic} off")?,
                n => write!(f, ", {topic} every {n} ticks")?,
            }
        }
        Ok(())
    }
}

/// What the ring does when the logger falls behind.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Backpressure {
    /// Wait (lockstep: simulated time can wait).
    Block,
    /// Drop the record and count it (wall clock: the loop never waits for the disk).
    Drop,
}

/// What the logger wrote.
#[derive(Debug, Clone, PartialEq)]
pub struct TelemetryReport {
    /// The MCAP file.
    pub path: PathBuf,
    /// Records pushed by the loop.
    pub pushed: u64,
    /// Records written.
    pub written: u64,
    /// Records dropped because the ring was full.
    pub dropped: u64,
    /// Messages per topic.
    pub messages: BTreeMap<String, u64>,
    /// What it cost.
    pub cost: RecordingCost,
}

/// What a recording cost the run.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct RecordingCost {
    /// How it was written.
    pub settings: RecordingSettings,
    /// The file's size, bytes.
    pub bytes: u64,
    /// The run time it covers, s.
    pub run_s: f64,
    /// CPU time of the recording's own thread (encoding, compression, writing), s.
    pub thread_cpu_s: f64,
    /// Time the loop spent handing records over (copying into the ring; in lockstep also
    /// waiting for a full ring), s.
    pub loop_s: f64,
}

impl std::fmt::Display for TelemetryReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "telemetry: {} ({} records written, {} dropped, {} topics)",
            self.path.display(),
            self.written,
            self.dropped,
            self.messages.len()
        )?;
        let c = &self.cost;
        let per_s = |v: f64| if c.run_s > 0.0 { 1000.0 * v / c.run_s } else { 0.0 };
        write!(
            f,
            "\nrecording cost: {:.1} MB ({}); its thread {:.2} s of CPU ({:.1} ms per run second), \
             the loop {:.3} s handing records over ({:.2} ms per run second)",
            c.bytes as f64 / 1e6,
            c.settings,
            c.thread_cpu_s,
            per_s(c.thread_cpu_s),
            c.loop_s,
            per_s(c.loop_s)
        )
    }
}

/// What the logger thread returns: records written, messages per topic, the run time the last
/// record was at (ns) and the thread's CPU time (s).
type Written = (u64, BTreeMap<String, u64>, u64, f64);

/// CPU time of the calling thread, s.
fn thread_cpu_s() -> f64 {
    let t = rustix::time::clock_gettime(rustix::time::ClockId::ThreadCPUTime);
    t.tv_sec as f64 + t.tv_nsec as f64 * 1e-9
}

/// What a recording says about itself.
#[derive(Debug, Clone, Default)]
pub struct RecordingInfo {
    /// Joint names, robot order.
    pub joint_names: Vec<String>,
    /// The base frame's name.
    pub root_frame: String,
    /// How to rebuild the run (files, options), for replays.
    pub run: Option<crate::options::RunMetadata>,
    /// Ticks of the reference at the policy rate (how much of it a run played is reported).
    pub reference_ticks: Option<usize>,
    /// Bus names, in the order of [`TickRecord::bus_us`].
    pub bus_names: Vec<String>,
    /// The robot's MJCF and its joint names in robot order: with them the logger also writes
    /// every link's frame (`/tf`, forward kinematics of the measured joints) and the robot's
    /// geometry (`/robot`).
    pub kinematics: Option<(PathBuf, Vec<String>)>,
    /// That MJCF as the run compiled it (`Robot::shared_model`), when it did: the logger's links
    /// use it instead of compiling the model again.
    pub model: Option<Arc<mujoco_rs::prelude::MjModel>>,
    /// Joints of each bus (robot indices), in the order of `bus_names`: with them the recording
    /// gets a `/bus/<name>` channel per bus for its cycles ([`TelemetrySink::push_cycle`]).
    pub bus_cycles: Option<Vec<Vec<usize>>>,
    /// The motion bodies whose position errors `/policy` carries (`body_errors_m`), and which
    /// of them is the anchor.
    pub motion_bodies: Vec<String>,
    /// The anchor's index in `motion_bodies`.
    pub anchor: Option<usize>,
    /// The views of the 2D keypoint references whose errors `/policy` carries.
    pub keypoint_views: Vec<String>,
    /// The live commands `/policy` carries (`commands`): each one's name and meaning
    /// (`lin_vel_x`, `lin_vel_y`, `ang_vel_z`, `other`).
    pub commands: Vec<(String, human::commands::CommandKind)>,
    /// A live view that serves every channel as it is written.
    pub live: Option<Arc<viewers::live::LiveView>>,
    /// ROS 2 topics of the run (`/joint_states`, `/tf`, `/robot_description`, `/diagnostics`).
    pub ros2: Option<Ros2Config>,
    /// The robot's feet (robot.toml order), named in `/estimator`.
    pub foot_names: Vec<String>,
    /// What the recording's times are.
    pub clock: RecordingClock,
    /// The commit of the tool that writes it (the binary's build), beside its version.
    pub commit: Option<String>,
    /// Values of the policy's observation: `/policy` carries it whole, through buffers of this
    /// size made when the recording starts (0: no observation recorded).
    pub observation_len: usize,
    /// How the file is written.
    pub settings: RecordingSettings,
}

/// The tool that writes recordings, as the file's header and its `robodeploy` metadata name it.
pub const WRITER: &str = concat!("robodeploy ", env!("CARGO_PKG_VERSION"));

/// The MCAP profile of robodeploy's recordings: protobuf channels (their descriptor sets in the
/// schemas) and the JSON `/replay` channel, as `telemetry.proto` and the README describe them.
pub const PROFILE: &str = "robodeploy";

/// What travels through the ring: a tick with its observation (a buffer of the pool), or one bus
/// cycle.
#[derive(Debug, Clone)]
#[allow(clippy::large_enum_variant)] // Both live in preallocated ring slots, never on their own.
enum Record {
    Tick(TickRecord, Option<Vec<f32>>),
    Cycle(CycleRecord),
}

/// `/replay`'s JSON schema: the loop's inputs and outputs at full precision, for `robodeploy
/// replay` (the project's own reader; viewers use the typed channels).
const REPLAY_SCHEMA: &str = r#"{"type":"object","description":"Full-precision loop inputs and outputs of one tick, for robodeploy replay: tick, time_ns (the run's own time), the measured joints and IMU, ground truth, the targets sent. Robot joint order (channel metadata joint_names); SI units; poses x y z qw qx qy qz."}"#;

/// The schema of a `telemetry-schema` message.
fn ours<M: prost::Name>() -> foxglove::Schema {
    foxglove::Schema::new(M::full_name(), "protobuf", telemetry_schema::DESCRIPTOR_SET)
}

/// The schema of a ROS 2 message: its type name and `ros2msg` definition (messages in CDR).
fn ros2(name: &str, definition: &str) -> foxglove::Schema {
    foxglove::Schema::new(name, "ros2msg", definition.as_bytes().to_vec())
}

/// The schema of a Foxglove well-known message.
fn well_known<M: foxglove::Encode>() -> foxglove::Schema {
    M::get_schema().expect("Foxglove's well-known schemas carry their descriptors")
}

/// A channel of the recording and, with a live view, of the live stream.
struct Channel {
    id: u16,
    topic: String,
    live: Option<Arc<foxglove::RawChannel>>,
    /// Written every this many ticks (0: never).
    every: u32,
}

impl Channel {
    /// Whether tick `tick` is written on it.
    fn due(&self, tick: u64) -> bool {
        self.every != 0 && tick.is_multiple_of(u64::from(self.every))
    }
}

/// The MCAP writer and the live view, fed the same encoded bytes; counts what it wrote.
struct Out<W: std::io::Write + std::io::Seek> {
    mcap: std::mem::ManuallyDrop<mcap::Writer<W>>,
    live: Option<Arc<viewers::live::LiveView>>,
    ros2: Option<ros2::Ros2Topics>,
    sequence: u32,
    counts: BTreeMap<String, u64>,
    settings: RecordingSettings,
    buf: Vec<u8>,
}

impl<W: std::io::Write + std::io::Seek> Out<W> {
    /// Adds a channel on `topic` (protobuf messages unless the schema is a JSON schema).
    fn channel(
        &mut self,
        topic: &str,
        schema: &foxglove::Schema,
        metadata: &BTreeMap<String, String>,
    ) -> Result<Channel, mcap::McapError> {
        let encoding = match schema.encoding.as_str() {
            "jsonschema" => "json",
            "ros2msg" => "cdr",
            _ => "protobuf",
        };
        let schema_id = self
            .mcap
            .add_schema(&schema.name, &schema.encoding, &schema.data)?;
        let id = self.mcap.add_channel(schema_id, topic, encoding, metadata)?;
        let live = self
            .live
            .as_ref()
            .and_then(|l| l.channel(topic, schema, encoding, metadata));
        Ok(Channel {
            id,
            topic: topic.to_owned(),
            live,
            every: self.settings.every(topic),
        })
    }

    /// Writes `data` on `channel` at `time_ns`, numbered and counted under its topic.
    fn bytes(&mut self, channel: &Channel, time_ns: u64, data: &[u8]) -> Result<(), mcap::McapError> {
        self.sequence = self.sequence.wrapping_add(1);
        let header = mcap::records::MessageHeader {
            channel_id: channel.id,
            sequence: self.sequence,
            log_time: time_ns,
            publish_time: time_ns,
        };
        self.mcap.write_to_known_channel(&header, data)?;
        if let Some(live) = &channel.live {
            viewers::live::publish(live, data, time_ns);
        }
        match self.counts.get_mut(&channel.topic) {
            Some(n) => *n += 1,
            None => {
                self.counts.insert(channel.topic.clone(), 1);
            }
        }
        Ok(())
    }

    /// Encodes `message` and writes it on `channel`.
    fn message(
        &mut self,
        channel: &Channel,
        time_ns: u64,
        message: &impl prost::Message,
    ) -> Result<(), mcap::McapError> {
        let mut buf = std::mem::take(&mut self.buf);
        buf.clear();
        message
            .encode(&mut buf)
            .map_err(|e| mcap::McapError::Io(std::io::Error::other(e)))?;
        let written = self.bytes(channel, time_ns, &buf);
        self.buf = buf;
        written
    }
}

/// The loop's end of the telemetry ring.
#[derive(Debug)]
pub struct TelemetrySink {
    tx: Option<crossbeam::channel::Sender<Record>>,
    /// Free observation buffers, and where a refused record's goes back.
    pool: crossbeam::channel::Receiver<Vec<f32>>,
    pool_tx: crossbeam::channel::Sender<Vec<f32>>,
    /// Whether the pool was filled (the recording takes observations).
    observations: bool,
    backpressure: Backpressure,
    pushed: u64,
    dropped: Arc<AtomicU64>,
    logger: Option<std::thread::JoinHandle<Result<Written, TelemetryError>>>,
    path: PathBuf,
    settings: RecordingSettings,
    /// Time spent in the push calls.
    handing: std::time::Duration,
}

/// The files a run was made from, inside its recording so it travels with them: robot.toml and
/// the robot's MJCF (the file robot.toml names; meshes it includes are not), the policy (manifest
/// or export metadata file), the clip, as attachments under their file names; and a `run`
/// metadata record naming them (file names only) with the run's options. A file that cannot be
/// read is left out with a warning: the recording still starts.
fn attach_run_files<W: std::io::Write + std::io::Seek>(
    writer: &mut mcap::Writer<W>,
    run: &crate::options::RunMetadata,
    mjcf: Option<&Path>,
    clock: RecordingClock,
) -> Result<(), mcap::McapError> {
    let name = |p: &Path| {
        p.file_name()
            .map_or_else(String::new, |n| n.to_string_lossy().into_owned())
    };
    let mut record = BTreeMap::new();
    let files = [
        ("robot", Some(run.robot.as_path())),
        ("model", mjcf),
        ("policy", Some(run.policy.as_path())),
        ("clip", run.clip.as_deref()),
    ];
    for (role, path) in files {
        let Some(path) = path else { continue };
        // A policy given as its ONNX export carries weights, not a description: named, not attached.
        let is_model = path.extension().is_some_and(|e| e == "onnx");
        record.insert(role.to_owned(), name(path));
        // The MJCF travels with robot.toml, under the robot's name.
        let role = if role == "model" { "robot" } else { role };
        if is_model {
            continue;
        }
        match std::fs::read(path) {
            Ok(data) => writer.attach(&mcap::Attachment {
                log_time: 0,
                create_time: 0,
                name: format!("{role}/{}", name(path)),
                media_type: match path.extension().and_then(|e| e.to_str()) {
                    Some("toml") => "application/toml",
                    Some("csv") => "text/csv",
                    Some("xml") => "application/xml",
                    _ => "application/octet-stream",
                }
                .to_owned(),
                data: data.into(),
            })?,
            Err(e) => tracing::warn!("recording: {} not attached: {e}", path.display()),
        }
    }
    record.insert(
        "options".to_owned(),
        serde_json::to_string(&run.options).unwrap_or_default(),
    );
    record.insert("time".to_owned(), clock.describe().to_owned());
    writer.write_metadata(&mcap::records::Metadata {
        name: "run".to_owned(),
        metadata: record,
    })
}

/// Nanoseconds since the Unix epoch now.
fn unix_now_ns() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| u64::try_from(d.as_nanos()).unwrap_or(u64::MAX))
}

impl TelemetrySink {
    /// Creates `path` and starts the logger with a ring of `capacity` records. `joint_names`
    /// (robot order) go into the channels' metadata; `root_frame` names the base frame.
    pub fn start(
        path: &Path,
        capacity: usize,
        backpressure: Backpressure,
        info: &RecordingInfo,
    ) -> Result<Self, TelemetryError> {
        let file = std::fs::File::create(path).map_err(|source| TelemetryError::Create {
            path: path.to_path_buf(),
            source,
        })?;
        Self::start_in(file, path, capacity, backpressure, info)
    }

    /// [`Self::start`] into an already open (empty, writable) `file` at `path`: for a file the
    /// caller holds a lock on for the length of the run.
    pub fn start_in(
        file: std::fs::File,
        path: &Path,
        capacity: usize,
        backpressure: Backpressure,
        info: &RecordingInfo,
    ) -> Result<Self, TelemetryError> {
        let wrote = |e: &dyn std::fmt::Display| TelemetryError::Write {
            path: path.to_path_buf(),
            message: e.to_string(),
        };
        let (tx, rx) = crossbeam::channel::bounded::<Record>(capacity.max(1));
        // The observations' buffers, one per ring slot, made now: a tick copies its observation
        // into a free one, the logger hands it back once written.
        let (pool_tx, pool) = crossbeam::channel::bounded::<Vec<f32>>(capacity.max(1));
        if info.observation_len > 0 {
            for _ in 0..capacity.max(1) {
                let _ = pool_tx.try_send(Vec::with_capacity(info.observation_len));
            }
        }
        let returned = pool_tx.clone();
        // Small chunks: a crash (SIGKILL, power) loses at most the chunk being built, ~0.3 s of
        // a 50 Hz run; `analysis::recording` reads everything before it.
        let writer = mcap::WriteOptions::new()
            .compression(match info.settings.compression {
                RecordingCompression::None => None,
                RecordingCompression::Lz4 => Some(mcap::Compression::Lz4),
                RecordingCompression::Zstd => Some(mcap::Compression::Zstd),
            })
            .compression_level(info.settings.level)
            // Compressed on the recording's own thread: zstd's worker threads would take cores
            // from the loop and hide what the recording costs.
            .compression_threads(0)
            .chunk_size(Some(info.settings.chunk_bytes))
            .profile(PROFILE)
            .library(match &info.commit {
                Some(c) => format!("{WRITER} (commit {c})"),
                None => WRITER.to_owned(),
            })
            .create(BufWriter::new(file))
            .map_err(|e| wrote(&e))?;
        // After a failed write the mcap writer panics when dropped (it finishes the file in Drop):
        // it is only ever dropped after a successful finish, and leaked on the error paths.
        let ros2 = match &info.ros2 {
            Some(config) => Some(ros2::Ros2Topics::open(
                config,
                &info.bus_names,
                info.clock == RecordingClock::Simulated,
            )?),
            None => None,
        };
        let mut out = Out {
            mcap: std::mem::ManuallyDrop::new(writer),
            live: info.live.clone(),
            ros2,
            sequence: 0,
            counts: BTreeMap::new(),
            settings: info.settings.clone(),
            buf: Vec::with_capacity(16 * 1024),
        };
        // Who wrote it: the version and the commit it was built from.
        let mut writer_record =
            BTreeMap::from([("version".to_owned(), env!("CARGO_PKG_VERSION").to_owned())]);
        writer_record.insert(
            "commit".to_owned(),
            info.commit.clone().unwrap_or_else(|| "unknown".to_owned()),
        );
        out.mcap
            .write_metadata(&mcap::records::Metadata {
                name: "robodeploy".to_owned(),
                metadata: writer_record,
            })
            .map_err(|e| wrote(&e))?;
        if let Some(run) = &info.run {
            let mjcf = info.kinematics.as_ref().map(|(m, _)| m.as_path());
            attach_run_files(&mut out.mcap, run, mjcf, info.clock).map_err(|e| wrote(&e))?;
        }
        let dir = path.parent().unwrap_or(Path::new("."));
        let channels = TickChannels::add(&mut out, info, dir).map_err(|e| wrote(&e))?;
        let mut messages = messages::Messages::new(info);
        // The robot in 3D: its links' frames and its geometry, when the model is known.
        let mut robot = match &info.kinematics {
            Some((mjcf, joints)) => {
                let (links, scene) = match &info.model {
                    Some(model) => {
                        viewers::robot3d::Links::of_model(mjcf, model.clone(), joints, &info.root_frame)?
                    }
                    None => viewers::robot3d::Links::new(mjcf, joints, &info.root_frame)?,
                };
                let name = mjcf
                    .file_stem()
                    .map_or_else(|| "robot".into(), |s| s.to_string_lossy());
                let urdf = links.urdf(&name, &info.joint_names);
                if let Some(ros) = &mut out.ros2 {
                    ros.set_fixed_frames(links.fixed_frames());
                }
                Some((links, scene, urdf))
            }
            None => None,
        };
        let clock = info.clock;
        let file_path = path.to_path_buf();
        let failed = move |e: &dyn std::fmt::Display| TelemetryError::Write {
            path: file_path.clone(),
            message: e.to_string(),
        };
        let logger = std::thread::Builder::new()
            .name("telemetry".into())
            .spawn(move || {
                let mut written = 0u64;
                let mut text = String::with_capacity(16 * 1024);
                // The run's time 0 on the recording's clock, set by the first record.
                let mut origin: Option<u64> = None;
                let mut last_ns = 0;
                while let Ok(record) = rx.recv() {
                    let run_ns = match &record {
                        Record::Tick(r, _) => r.time_ns,
                        Record::Cycle(c) => c.started_ns,
                    };
                    last_ns = last_ns.max(run_ns);
                    let zero = match origin {
                        Some(zero) => zero,
                        None => {
                            let zero = clock.origin(run_ns);
                            out.mcap
                                .write_metadata(&mcap::records::Metadata {
                                    name: "clock".to_owned(),
                                    metadata: [
                                        ("time".to_owned(), clock.describe().to_owned()),
                                        ("origin_unix_ns".to_owned(), zero.to_string()),
                                    ]
                                    .into(),
                                })
                                .map_err(|e| failed(&e))?;
                            origin = Some(zero);
                            zero
                        }
                    };
                    let t = zero + run_ns;
                    written += 1;
                    match record {
                        Record::Cycle(c) => {
                            if let (Some(m), Some(channel)) =
                                (messages.bus_cycle(&c, t), channels.buses.get(usize::from(c.bus)))
                            {
                                out.message(channel, t, m).map_err(|e| failed(&e))?;
                            }
                        }
                        Record::Tick(r, obs) => {
                            let seen = obs.as_deref().unwrap_or(&[]);
                            channels
                                .write(&mut out, &mut messages, robot.as_mut(), &mut text, (&r, seen), t)
                                .map_err(|e| failed(&e))?;
                            if let Some(b) = obs {
                                let _ = returned.try_send(b);
                            }
                        }
                    }
                }
                let Out { mut mcap, counts, .. } = out;
                mcap.finish().map_err(|e| failed(&e))?;
                drop(std::mem::ManuallyDrop::into_inner(mcap));
                Ok((written, counts, last_ns, thread_cpu_s()))
            })
            .map_err(|e| TelemetryError::Logger(e.to_string()))?;
        Ok(Self {
            tx: Some(tx),
            pool,
            pool_tx,
            observations: info.observation_len > 0,
            backpressure,
            pushed: 0,
            dropped: Arc::new(AtomicU64::new(0)),
            logger: Some(logger),
            path: path.to_path_buf(),
            settings: info.settings.clone(),
            handing: std::time::Duration::ZERO,
        })
    }

    /// Hands a record to the logger (no allocation; blocks or drops per the backpressure).
    pub fn push(&mut self, record: &TickRecord) {
        self.push_with(record, &[]);
    }

    /// [`Self::push`] with the tick's observation, whole: copied into a buffer the recording
    /// made at its start (none free in a wall-clock run: the tick is recorded without it; a
    /// recording started without [`RecordingInfo::observation_len`] records none).
    pub fn push_with(&mut self, record: &TickRecord, obs: &[f32]) {
        let began = std::time::Instant::now();
        let buffer = if obs.is_empty() || !self.observations {
            None
        } else {
            let free = match self.backpressure {
                Backpressure::Block => self.pool.recv().ok(),
                Backpressure::Drop => self.pool.try_recv().ok(),
            };
            free.map(|mut b| {
                b.clear();
                b.extend_from_slice(obs);
                b
            })
        };
        self.send(Record::Tick(*record, buffer));
        self.handing += began.elapsed();
    }

    /// Hands one bus cycle to the logger, like [`Self::push`] (recorded on `/bus/<name>` when
    /// the recording was started with [`RecordingInfo::bus_cycles`]).
    pub fn push_cycle(&mut self, record: &CycleRecord) {
        let began = std::time::Instant::now();
        self.send(Record::Cycle(*record));
        self.handing += began.elapsed();
    }

    fn send(&mut self, record: Record) {
        let Some(tx) = &self.tx else { return };
        self.pushed += 1;
        let refused = match self.backpressure {
            Backpressure::Block => tx.send(record).err().map(|e| e.into_inner()),
            Backpressure::Drop => tx.try_send(record).err().map(|e| e.into_inner()),
        };
        if let Some(record) = refused {
            self.dropped.fetch_add(1, Ordering::Relaxed);
            // Its observation's buffer goes back to the pool.
            if let Record::Tick(_, Some(b)) = record {
                let _ = self.pool_tx.try_send(b);
            }
        }
    }

    /// Closes the ring, waits for the logger to write everything, finishes the file.
    pub fn finish(mut self) -> Result<TelemetryReport, TelemetryError> {
        self.tx.take();
        let (written, messages, last_ns, thread_cpu_s) =
            self.logger.take().map_or(Ok((0, BTreeMap::new(), 0, 0.0)), |h| {
                h.join()
                    .map_err(|_| TelemetryError::Logger("the thread panicked".into()))?
            })?;
        Ok(TelemetryReport {
            path: self.path.clone(),
            pushed: self.pushed,
            written,
            dropped: self.dropped.load(Ordering::Relaxed),
            messages,
            cost: RecordingCost {
                settings: self.settings.clone(),
                bytes: std::fs::metadata(&self.path).map_or(0, |m| m.len()),
                run_s: last_ns as f64 * 1e-9,
                thread_cpu_s,
                loop_s: self.handing.as_secs_f64(),
            },
        })
    }
}

/// How often the live view gets the robot's geometry again, ticks (a viewer that connects late
/// sees the robot within a second at 50 Hz; the file has it once).
const SCENE_EVERY: u64 = 50;

/// The channels a tick is written on.
struct TickChannels {
    joint_state: Channel,
    command: Channel,
    policy: Channel,
    safety: Channel,
    log: Channel,
    imu: Channel,
    timing: Channel,
    estimator: Channel,
    tf: Channel,
    robot: Channel,
    /// ROS 2's conventions, which Rerun, Foxglove and RViz read without a layout: the robot's
    /// URDF (`std_msgs/msg/String`, once) and its joints by name (`sensor_msgs/msg/JointState`).
    robot_description: Option<Channel>,
    joint_states: Channel,
    /// The robot's anchor and the reference's, declared only for a run whose reference has one.
    anchors: Option<(Channel, Channel)>,
    replay: Channel,
    buses: Vec<Channel>,
}

impl TickChannels {
    fn add<W: std::io::Write + std::io::Seek>(
        out: &mut Out<W>,
        info: &RecordingInfo,
        recording_dir: &Path,
    ) -> Result<Self, mcap::McapError> {
        use foxglove::schemas as fg;
        use telemetry_schema as pb;
        let none = BTreeMap::new();
        let names: BTreeMap<String, String> = [("joint_names".to_owned(), info.joint_names.join(","))].into();
        // What analysis reads besides the messages: bodies and commands of /policy, buses of
        // /timing, how to rebuild the run on /replay.
        let mut policy_meta = BTreeMap::new();
        if !info.motion_bodies.is_empty() {
            policy_meta.insert("motion_bodies".into(), info.motion_bodies.join(","));
        }
        if let Some(a) = info.anchor.and_then(|a| info.motion_bodies.get(a)) {
            policy_meta.insert("anchor_body".into(), a.clone());
        }
        if !info.commands.is_empty() {
            let names: Vec<&str> = info.commands.iter().map(|(n, _)| n.as_str()).collect();
            let kinds: Vec<String> = info
                .commands
                .iter()
                .map(|(_, k)| {
                    serde_json::to_string(k)
                        .unwrap_or_default()
                        .trim_matches('"')
                        .to_owned()
                })
                .collect();
            policy_meta.insert("command_names".into(), names.join(","));
            policy_meta.insert("command_kinds".into(), kinds.join(","));
        }
        let timing_meta: BTreeMap<String, String> =
            [("bus_names".to_owned(), info.bus_names.join(","))].into();
        let mut replay_meta = names.clone();
        if let Some(run) = &info.run {
            // Its files named from the recording's folder: no absolute path in the file.
            replay_meta.insert("run".into(), run.relative_to(recording_dir).to_json());
        }
        if let Some(n) = info.reference_ticks {
            replay_meta.insert("reference_ticks".into(), n.to_string());
        }
        let replay = foxglove::Schema::new("replay", "jsonschema", REPLAY_SCHEMA.as_bytes());
        let mut buses = Vec::new();
        for name in info.bus_cycles.iter().flat_map(|_| &info.bus_names) {
            buses.push(out.channel(&format!("/bus/{name}"), &ours::<pb::BusCycle>(), &none)?);
        }
        Ok(Self {
            joint_state: out.channel("/joint_state", &ours::<pb::JointStates>(), &none)?,
            command: out.channel("/command", &ours::<pb::JointCommands>(), &none)?,
            policy: out.channel("/policy", &ours::<pb::PolicyStep>(), &policy_meta)?,
            safety: out.channel("/safety", &ours::<pb::SafetyTransition>(), &none)?,
            log: out.channel("/log", &well_known::<fg::Log>(), &none)?,
            imu: out.channel("/imu", &ours::<pb::ImuReading>(), &none)?,
            timing: out.channel("/timing", &ours::<pb::TickTiming>(), &timing_meta)?,
            estimator: out.channel("/estimator", &ours::<pb::StateEstimate>(), &none)?,
            tf: out.channel("/tf", &well_known::<fg::FrameTransforms>(), &none)?,
            robot: out.channel("/robot", &well_known::<fg::SceneUpdate>(), &none)?,
            robot_description: match info.kinematics {
                Some(_) => Some(out.channel(
                    "/robot_description",
                    &ros2("std_msgs/msg/String", telemetry_schema::ros2::STRING_DEFINITION),
                    &none,
                )?),
                None => None,
            },
            joint_states: out.channel(
                "/joint_states",
                &ros2(
                    "sensor_msgs/msg/JointState",
                    telemetry_schema::ros2::JOINT_STATE_DEFINITION,
                ),
                &none,
            )?,
            anchors: match info.anchor {
                Some(_) => Some((
                    out.channel("/anchor/robot", &well_known::<fg::PoseInFrame>(), &none)?,
                    out.channel("/anchor/reference", &well_known::<fg::PoseInFrame>(), &none)?,
                )),
                None => None,
            },
            replay: out.channel("/replay", &replay, &replay_meta)?,
            buses,
        })
    }

    /// Writes tick `r` at time `t` on every channel that has something from it.
    fn write<W: std::io::Write + std::io::Seek>(
        &self,
        out: &mut Out<W>,
        m: &mut messages::Messages,
        robot: Option<&mut (viewers::robot3d::Links, foxglove::schemas::SceneUpdate, String)>,
        text: &mut String,
        (r, obs): (&TickRecord, &[f32]),
        t: u64,
    ) -> Result<(), mcap::McapError> {
        use foxglove::schemas as fg;
        let tick = r.tick;
        if self.joint_state.due(tick) {
            out.message(&self.joint_state, t, m.joint_state(r, t))?;
        }
        if self.joint_states.due(tick) || out.ros2.is_some() {
            let mut buf = std::mem::take(&mut out.buf);
            m.joint_states_cdr(r, t, &mut buf);
            if let Some(ros) = &mut out.ros2 {
                ros.clock(t);
                ros.joint_states(&buf);
                ros.diagnostics(t, r);
            }
            let written = if self.joint_states.due(tick) {
                out.bytes(&self.joint_states, t, &buf)
            } else {
                Ok(())
            };
            out.buf = buf;
            written?;
        }
        if self.command.due(tick) {
            out.message(&self.command, t, m.command(r, t))?;
        }
        if self.policy.due(tick) {
            out.message(&self.policy, t, m.policy(r, obs, t))?;
        }
        if let Some((transition, log)) = m.safety(r, t) {
            out.message(&self.safety, t, &transition)?;
            out.message(&self.log, t, &log)?;
        }
        if let Some(log) = m.generated_log(r, t) {
            out.message(&self.log, t, &log)?;
        }
        if let Some(log) = m.harness_log(r, t) {
            out.message(&self.log, t, &log)?;
        }
        if self.imu.due(tick) {
            out.message(&self.imu, t, m.imu(r, t))?;
        }
        if self.timing.due(tick) {
            out.message(&self.timing, t, m.timing(r, t))?;
        }
        if self.estimator.due(tick)
            && let Some(estimate) = m.estimate(r, t)
        {
            out.message(&self.estimator, t, estimate)?;
        }
        if let (Some((robot, reference)), Some((robot_channel, reference_channel))) =
            (r.anchors, &self.anchors)
        {
            for (channel, p) in [(robot_channel, robot), (reference_channel, reference)] {
                if !channel.due(tick) {
                    continue;
                }
                let pose = fg::PoseInFrame {
                    timestamp: viewers::fg_time(t),
                    frame_id: "world".into(),
                    pose: Some(viewers::fg_pose(p)),
                };
                out.message(channel, t, &pose)?;
            }
        }
        if let Some((links, scene, urdf)) = robot {
            let first = !out.counts.contains_key("/robot");
            if let (true, Some(channel)) = (first, &self.robot_description) {
                let mut buf = Vec::new();
                telemetry_schema::ros2::encode_string(&mut buf, urdf);
                out.bytes(channel, t, &buf)?;
                if let Some(ros) = &mut out.ros2 {
                    ros.robot_description(&buf);
                }
            }
            if first || r.tick.is_multiple_of(SCENE_EVERY) {
                for e in &mut scene.entities {
                    e.timestamp = viewers::fg_time(t);
                }
                if first {
                    out.message(&self.robot, t, scene)?;
                } else if let Some(live) = &self.robot.live {
                    // Late viewers of the live stream: the file has the scene once.
                    let mut buf = Vec::new();
                    prost::Message::encode(&*scene, &mut buf)
                        .map_err(|e| mcap::McapError::Io(std::io::Error::other(e)))?;
                    viewers::live::publish(live, &buf, t);
                    if let Some(live) = self.robot_description.as_ref().and_then(|c| c.live.as_ref()) {
                        telemetry_schema::ros2::encode_string(&mut buf, urdf);
                        viewers::live::publish(live, &buf, t);
                    }
                }
            }
            if self.tf.due(tick) || out.ros2.is_some() {
                let root = root_pose(r);
                let frames = links.update(root, &r.q[..usize::from(r.joints)], t);
                if let Some(ros) = &mut out.ros2 {
                    ros.tf(t, frames);
                }
                if self.tf.due(tick) {
                    out.message(&self.tf, t, frames)?;
                }
            }
        }
        text.clear();
        replay_json(text, r);
        out.bytes(&self.replay, t, text.as_bytes())
    }
}

/// Where the root is drawn: the simulator's truth, else the state estimate's position, with the
/// IMU's orientation (the world origin without an estimate).
fn root_pose(r: &TickRecord) -> [f64; 7] {
    if !r.base_pose[0].is_nan() {
        return r.base_pose;
    }
    let p = if r.estimate.present && r.estimate.estimate.valid {
        r.estimate.estimate.position
    } else {
        [0.0; 3]
    };
    let q = [r.imu[6], r.imu[7], r.imu[8], r.imu[9]];
    let unit = (q.iter().map(|v| v * v).sum::<f64>() - 1.0).abs() < 1e-3;
    let q = if unit { q } else { [1.0, 0.0, 0.0, 0.0] };
    [p[0], p[1], p[2], q[0], q[1], q[2], q[3]]
}

/// What a recording's times are.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub enum RecordingClock {
    /// Simulated time from 0 (lockstep runs: faster or slower than real time).
    #[default]
    Simulated,
    /// Unix time: the run's own time plus the wall-clock moment it started (wall-clock and
    /// hardware runs).
    WallClock,
}

impl RecordingClock {
    /// Unix time of the run's time 0, given that the run is at `run_ns` now.
    fn origin(self, run_ns: u64) -> u64 {
        match self {
            Self::Simulated => 0,
            Self::WallClock => unix_now_ns().saturating_sub(run_ns),
        }
    }

    /// As the recording's metadata says it.
    fn describe(self) -> &'static str {
        match self {
            Self::Simulated => "simulated",
            Self::WallClock => "wall-clock",
        }
    }
}
/// A JSON array named `name`; non-finite values as null. `{:?}` prints the shortest text that
/// reads back to the same bits (for f32 and f64 alike).
/// `"name":[v, …]` with each finite value in its shortest round-trip form, `null` otherwise.
fn json_array(out: &mut String, name: &str, values: impl IntoIterator<Item = f64>) {
    let _ = write!(out, "\"{name}\":[");
    let mut text = zmij::Buffer::new();
    for (i, v) in values.into_iter().enumerate() {
        if i > 0 {
            out.push(',');
        }
        out.push_str(if v.is_finite() {
            text.format_finite(v)
        } else {
            "null"
        });
    }
    out.push(']');
}

fn array64(out: &mut String, name: &str, values: impl IntoIterator<Item = f64>) {
    json_array(out, name, values);
}

/// The measured joint state of `r`'s first `n` joints: the `/joint_state` message, and what
/// `/replay` feeds back.
fn joint_state_fields(out: &mut String, r: &TickRecord, n: usize) {
    array64(out, "q", r.q[..n].iter().copied());
    out.push(',');
    array64(out, "qd", r.qd[..n].iter().copied());
    out.push(',');
    array64(out, "tau", r.tau[..n].iter().copied());
    out.push(',');
    array64(out, "missed", r.missed[..n].iter().map(|&m| f64::from(m)));
    out.push(',');
    array64(out, "stale", r.stale[..n].iter().map(|&b| f64::from(u8::from(b))));
    out.push(',');
    array64(out, "age_ms", r.age_ms[..n].iter().map(|&a| f64::from(a)));
}

/// `,"commands":[…]` when the tick had live commands.
fn commands_field(out: &mut String, r: &TickRecord) {
    if r.command_count > 0 {
        out.push(',');
        array64(
            out,
            "commands",
            r.commands[..usize::from(r.command_count)].iter().copied(),
        );
    }
}

/// The `/replay` message of `r`: everything `robodeploy replay` feeds back, at full precision.
fn replay_json(out: &mut String, r: &TickRecord) {
    let n = usize::from(r.joints);
    let f = usize::from(r.feet);
    let _ = write!(
        out,
        "{{\"tick\":{},\"time_ns\":{},\"imu_missed\":{},\"stop\":{},\"simulation_failed\":{},\"mirror_behind_us\":{},",
        r.tick, r.time_ns, r.imu_missed, r.stop_requested, r.simulation_failed, r.mirror_behind_us
    );
    joint_state_fields(out, r, n);
    out.push(',');
    array64(
        out,
        "faulted",
        r.faulted[..n].iter().map(|&b| f64::from(u8::from(b))),
    );
    out.push(',');
    array64(out, "imu", r.imu.iter().copied());
    out.push(',');
    array64(
        out,
        "imu_samples",
        r.imu_samples[..usize::from(r.imu_sample_count)]
            .iter()
            .flatten()
            .copied(),
    );
    commands_field(out, r);
    out.push(',');
    array64(out, "base_pose", r.base_pose.iter().copied());
    out.push(',');
    array64(out, "base_lin_vel", r.base_lin_vel.iter().copied());
    out.push(',');
    array64(
        out,
        "feet",
        r.foot_contacts[..f].iter().map(|&b| f64::from(u8::from(b))),
    );
    out.push(',');
    array64(
        out,
        "target",
        r.target[..n].iter().flat_map(|t| t.iter().copied()),
    );
    out.push(',');
    array64(
        out,
        "enabled",
        r.enabled[..n].iter().map(|&b| f64::from(u8::from(b))),
    );
    out.push('}');
}
