//! Run telemetry as MCAP: the loop fills a fixed-size [`TickRecord`] and pushes it into a
//! preallocated ring (a bounded channel); a logger thread encodes JSON messages and writes an
//! lz4-compressed MCAP file that Foxglove, Rerun and Python's `mcap` read.
//!
//! In wall-clock runs the loop never waits for the logger: a full ring drops the record and counts
//! it. In lockstep runs simulated time can wait, so the loop blocks instead and nothing is dropped.

use robot_link::{CycleRecord, MAX_RECORDED_JOINTS};
use robots::spatial;
use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::io::BufWriter;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};

use robot_link::IMU_HISTORY;

/// Most joints a record carries.
pub const MAX_JOINTS: usize = 48;
/// Most observation values a record carries (longer observations are truncated in the log).
pub const MAX_OBS: usize = 512;
/// A tick's state estimate for the recording.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct EstimateRecord {
    /// The robot has an estimator.
    pub present: bool,
    /// What it said.
    pub estimate: crate::estimator::Estimate,
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
    /// Observation values in use.
    pub obs_len: u16,
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
    /// Commanded targets: q, qd, kp, kd, tau.
    pub target: [[f64; 5]; MAX_JOINTS],
    /// Commanded torque on/off.
    pub enabled: [bool; MAX_JOINTS],
    /// Reference positions, rad.
    pub reference_q: [f32; MAX_JOINTS],
    /// Reference root pose `[x, y, z, w, qx, qy, qz]`.
    pub reference_root: [f64; 7],
    /// Whether the reference is the clip itself (not the start-up ramp or the end).
    pub tracking: bool,
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
    /// Raw policy actions (policy order).
    pub action: [f32; MAX_JOINTS],
    /// The observation the policy saw.
    pub obs: [f32; MAX_OBS],
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
}

impl Default for TickRecord {
    fn default() -> Self {
        Self {
            tick: 0,
            time_ns: 0,
            mode: 0,
            joints: 0,
            feet: 0,
            obs_len: 0,
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
            target: [[0.0; 5]; MAX_JOINTS],
            enabled: [false; MAX_JOINTS],
            reference_q: [0.0; MAX_JOINTS],
            reference_root: [0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0],
            tracking: false,
            anchors: None,
            estimate: EstimateRecord::default(),
            imu_samples: [[0.0; 11]; IMU_HISTORY],
            imu_sample_count: 0,
            body_errors: [0.0; MAX_BODIES],
            bodies: 0,
            action: [0.0; MAX_JOINTS],
            obs: [0.0; MAX_OBS],
            commands: [0.0; human::commands::MAX_COMMANDS],
            command_count: 0,
            io_us: 0.0,
            compute_us: 0.0,
            bus_us: [0.0; 8],
            buses: 0,
            cause: [0; 64],
            cause_len: 0,
            cause_fault: false,
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
    /// Whether the reference was the clip itself.
    pub tracking: bool,
    /// The robot's anchor and the reference's, when the policy observes one.
    pub anchors: Option<([f64; 7], [f64; 7])>,
    /// Position errors of the tracked motion bodies, m (empty when unknown).
    pub body_errors: &'a [f64],
    /// The state estimate, for a robot with an estimator.
    pub estimate: Option<&'a crate::estimator::Estimate>,
    /// Ground truth in the estimate's frame: root pose and base-frame velocity (simulation).
    pub truth_in_world: Option<([f64; 7], [f64; 3])>,
    /// Raw actions.
    pub actions: &'a [f32],
    /// The observation.
    pub obs: &'a [f32],
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
        let b = v.body_errors.len().min(MAX_BODIES);
        r.bodies = b as u8;
        for (slot, e) in r.body_errors.iter_mut().zip(&v.body_errors[..b]) {
            *slot = *e as f32;
        }
        let m = v.actions.len().min(MAX_JOINTS);
        r.action[..m].copy_from_slice(&v.actions[..m]);
        let k = v.obs.len().min(MAX_OBS);
        r.obs_len = k as u16;
        r.obs[..k].copy_from_slice(&v.obs[..k]);
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
        let b = v.bus_times.len().min(r.bus_us.len());
        r.buses = b as u8;
        for (slot, t) in r.bus_us.iter_mut().zip(&v.bus_times[..b]) {
            *slot = t.as_secs_f32() * 1e6;
        }
        r.io_us = v.io.as_secs_f32() * 1e6;
        r.compute_us = v.compute.as_secs_f32() * 1e6;
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
    #[error("{0}")]
    Kinematics(String),
    /// The logger thread could not start, or died.
    #[error("telemetry logger: {0}")]
    Logger(String),
}

/// Target size of a recording's chunks, bytes (~0.3 s of a 50 Hz run).
const CHUNK_BYTES: u64 = 64 * 1024;

/// What the ring does when the logger falls behind.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Backpressure {
    /// Wait (lockstep: simulated time can wait).
    Block,
    /// Drop the record and count it (wall clock: the loop never waits for the disk).
    Drop,
}

/// What the logger wrote.
#[derive(Debug, Clone, PartialEq, Eq)]
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
        )
    }
}

/// Records written and messages per topic, as the logger thread returns them.
type Written = (u64, BTreeMap<String, u64>);

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
    /// The robot's MJCF and its joint names in robot order: with them the logger also writes a
    /// `foxglove.FrameTransform` per link (forward kinematics of the measured joints).
    pub kinematics: Option<(PathBuf, Vec<String>)>,
    /// Joints of each bus (robot indices), in the order of `bus_names`: with them the recording
    /// gets a `/bus/<name>` channel per bus for its cycles ([`TelemetrySink::push_cycle`]).
    pub bus_cycles: Option<Vec<Vec<usize>>>,
    /// The motion bodies whose position errors `/policy` carries (`body_errors_m`), and which
    /// of them is the anchor.
    pub motion_bodies: Vec<String>,
    /// The anchor's index in `motion_bodies`.
    pub anchor: Option<usize>,
    /// The live commands `/policy` carries (`commands`): each one's name and meaning
    /// (`lin_vel_x`, `lin_vel_y`, `ang_vel_z`, `other`).
    pub commands: Vec<(String, human::commands::CommandKind)>,
    /// A live view that serves every channel as it is written.
    pub live: Option<Arc<crate::live::LiveView>>,
}

/// What travels through the ring: a tick, or one bus cycle.
#[derive(Debug, Clone, Copy)]
#[allow(clippy::large_enum_variant)] // Both live in preallocated ring slots, never on their own.
enum Record {
    Tick(TickRecord),
    Cycle(CycleRecord),
}

const BUS_CYCLE_SCHEMA: &str = r#"{"type":"object","description":"One bus cycle: what the bus read and commanded. Joint names in the channel's joint_names metadata; angles rad, speeds rad/s, torques N·m, gains N·m/rad and N·m·s/rad.","properties":{"cycle":{"type":"integer"},"took_us":{"type":"number","description":"send to last reply"},"overruns":{"type":"integer","description":"slots lost so far"},"damped":{"type":"boolean","description":"the bus is damping itself"},"q":{"type":"array","items":{"type":"number"}},"qd":{"type":"array","items":{"type":"number"}},"tau":{"type":"array","items":{"type":"number"}},"missed":{"type":"array","items":{"type":"number"}},"command_q":{"type":"array","items":{"type":"number"}},"command_qd":{"type":"array","items":{"type":"number"}},"kp":{"type":"array","items":{"type":"number"}},"kd":{"type":"array","items":{"type":"number"}},"command_tau":{"type":"array","items":{"type":"number"}},"enabled":{"type":"array","items":{"type":"number"}}}}"#;

/// One bus cycle as the `/bus/<name>` message.
fn encode_cycle(out: &mut String, c: &CycleRecord) {
    let n = usize::from(c.joints);
    let _ = write!(
        out,
        "{{\"cycle\":{},\"took_us\":{},\"overruns\":{},\"damped\":{},",
        c.cycle, c.took_us, c.overruns, c.damped
    );
    array64(out, "q", c.q[..n].iter().map(|&v| f64::from(v)));
    out.push(',');
    array64(out, "qd", c.qd[..n].iter().map(|&v| f64::from(v)));
    out.push(',');
    array64(out, "tau", c.tau[..n].iter().map(|&v| f64::from(v)));
    out.push(',');
    array64(out, "missed", c.missed[..n].iter().map(|&m| f64::from(m)));
    for (k, key) in ["command_q", "command_qd", "kp", "kd", "command_tau"]
        .into_iter()
        .enumerate()
    {
        out.push(',');
        array64(out, key, c.command[..n].iter().map(|cmd| f64::from(cmd[k])));
    }
    out.push(',');
    array64(
        out,
        "enabled",
        c.enabled[..n].iter().map(|&b| f64::from(u8::from(b))),
    );
    out.push('}');
}

/// The loop's end of the telemetry ring.
#[derive(Debug)]
pub struct TelemetrySink {
    tx: Option<crossbeam::channel::Sender<Record>>,
    backpressure: Backpressure,
    pushed: u64,
    dropped: Arc<AtomicU64>,
    logger: Option<std::thread::JoinHandle<Result<Written, TelemetryError>>>,
    path: PathBuf,
}

/// Topics, their JSON schemas, and how a record becomes their messages.
const TOPICS: [(&str, &str); 9] = [
    (
        "/joint_state",
        r#"{"type":"object","properties":{"q":{"type":"array","items":{"type":"number"}},"qd":{"type":"array","items":{"type":"number"}},"tau":{"type":"array","items":{"type":"number"}},"missed":{"type":"array","items":{"type":"number"},"description":"bus cycles in a row without a reply"},"stale":{"type":"array","items":{"type":"number"},"description":"1: the joint's bus damped itself for its silence"},"age_ms":{"type":"array","items":{"type":"number"},"description":"age of each joint's sample when the tick read it, ms"}}}"#,
    ),
    (
        "/command",
        r#"{"type":"object","properties":{"q":{"type":"array","items":{"type":"number"}},"kp":{"type":"array","items":{"type":"number"}},"reference_q":{"type":"array","items":{"type":"number"}}}}"#,
    ),
    (
        "/policy",
        r#"{"type":"object","properties":{"obs":{"type":"array","items":{"type":"number"}},"action":{"type":"array","items":{"type":"number"}},"robot_anchor":{"type":"array","items":{"type":"number"},"description":"the robot's anchor body in the world, x y z qw qx qy qz (tracking policies)"},"reference_anchor":{"type":"array","items":{"type":"number"},"description":"the reference's anchor, aligned to the robot, x y z qw qx qy qz"},"body_errors_m":{"type":"array","items":{"type":"number"},"description":"position error of each motion body (channel metadata motion_bodies), m, simulation"},"commands":{"type":"array","items":{"type":"number"},"description":"the live commands in force (command-driven policies), in the manifest's [commands] order and units"}}}"#,
    ),
    (
        "/safety",
        r#"{"type":"object","properties":{"tick":{"type":"integer"},"mode":{"type":"string"},"cause":{"type":"string"},"fault":{"type":"boolean"}}}"#,
    ),
    (
        "/imu",
        r#"{"type":"object","properties":{"gyro":{"type":"array","items":{"type":"number"}},"accel":{"type":"array","items":{"type":"number"}},"quat":{"type":"array","items":{"type":"number"}},"age_ms":{"type":"number","description":"age of the sample when the tick read it, ms"}}}"#,
    ),
    (
        "/timing",
        r#"{"type":"object","properties":{"io_us":{"type":"number"},"compute_us":{"type":"number"},"bus_us":{"type":"array","items":{"type":"number"}}}}"#,
    ),
    ("/tf", FRAME_TRANSFORM_SCHEMA),
    (
        "/replay",
        r#"{"type":"object","description":"full-precision loop inputs and outputs of one tick, for robodeploy replay"}"#,
    ),
    ("/estimator", ESTIMATOR_SCHEMA),
];

const ESTIMATOR_SCHEMA: &str = r#"{"type":"object","description":"The state estimate of the tick (world frame: the robot's start; floor at z = 0), with its standard deviations; in simulation the ground truth in the same frame beside it.","properties":{"valid":{"type":"boolean"},"position":{"type":"array","items":{"type":"number"},"description":"base position, m"},"velocity":{"type":"array","items":{"type":"number"},"description":"base velocity, world axes, m/s"},"velocity_base":{"type":"array","items":{"type":"number"},"description":"base velocity, base axes, m/s"},"position_std":{"type":"array","items":{"type":"number"}},"velocity_std":{"type":"array","items":{"type":"number"}},"accel_bias":{"type":"array","items":{"type":"number"},"description":"accelerometer bias, base axes, m/s²"},"contacts":{"type":"array","items":{"type":"number"},"description":"1: the foot is on the ground (robot.toml feet order)"},"loads":{"type":"array","items":{"type":"number"},"description":"the ground's vertical push on each foot from the joint torques, N"},"truth_position":{"type":"array","items":{"type":"number"}},"truth_velocity_base":{"type":"array","items":{"type":"number"}},"truth_contacts":{"type":"array","items":{"type":"number"}}}}"#;

/// `foxglove.FrameTransform` as a JSON schema (the names Foxglove's 3D panel matches).
const FRAME_TRANSFORM_SCHEMA: &str = r#"{"title":"foxglove.FrameTransform","type":"object","properties":{"timestamp":{"type":"object","properties":{"sec":{"type":"integer"},"nsec":{"type":"integer"}}},"parent_frame_id":{"type":"string"},"child_frame_id":{"type":"string"},"translation":{"type":"object","properties":{"x":{"type":"number"},"y":{"type":"number"},"z":{"type":"number"}}},"rotation":{"type":"object","properties":{"x":{"type":"number"},"y":{"type":"number"},"z":{"type":"number"},"w":{"type":"number"}}}}}"#;

/// What the logger has written: the running message sequence number and a count per topic.
#[derive(Default)]
struct Sent {
    sequence: u32,
    counts: BTreeMap<String, u64>,
}

impl Sent {
    /// Writes one JSON message on a known channel, numbered and counted under its topic.
    fn write<W: std::io::Write + std::io::Seek>(
        &mut self,
        writer: &mut mcap::Writer<W>,
        channel_id: u16,
        topic: &str,
        time_ns: u64,
        json: &str,
    ) -> Result<(), mcap::McapError> {
        self.sequence = self.sequence.wrapping_add(1);
        let header = mcap::records::MessageHeader {
            channel_id,
            sequence: self.sequence,
            log_time: time_ns,
            publish_time: time_ns,
        };
        writer.write_to_known_channel(&header, json.as_bytes())?;
        *self.counts.entry(topic.to_owned()).or_default() += 1;
        Ok(())
    }
}

/// The files a run was made from, inside its recording so it travels with them: robot.toml, the
/// policy (manifest or export metadata file), the clip, as attachments under their file names;
/// and a `run` metadata record naming them (file names only) with the run's options. A file
/// that cannot be read is left out with a warning: the recording still starts.
fn attach_run_files<W: std::io::Write + std::io::Seek>(
    writer: &mut mcap::Writer<W>,
    run: &crate::options::RunMetadata,
) -> Result<(), mcap::McapError> {
    let name = |p: &Path| {
        p.file_name()
            .map_or_else(String::new, |n| n.to_string_lossy().into_owned())
    };
    let mut record = BTreeMap::new();
    let files = [
        ("robot", Some(&run.robot)),
        ("policy", Some(&run.policy)),
        ("clip", run.clip.as_ref()),
    ];
    for (role, path) in files {
        let Some(path) = path else { continue };
        // A policy given as its ONNX export carries weights, not a description: named, not attached.
        let is_model = path.extension().is_some_and(|e| e == "onnx");
        record.insert(role.to_owned(), name(path));
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
    writer.write_metadata(&mcap::records::Metadata {
        name: "run".to_owned(),
        metadata: record,
    })
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
        let (joint_names, root_frame, run) = (&info.joint_names, info.root_frame.as_str(), &info.run);
        let (tx, rx) = crossbeam::channel::bounded::<Record>(capacity.max(1));
        // Small chunks: a crash (SIGKILL, power) loses at most the chunk being built, ~0.3 s of
        // a 50 Hz run; `analysis::recording` reads everything before it.
        let writer = mcap::WriteOptions::new()
            .compression(Some(mcap::Compression::Lz4))
            .chunk_size(Some(CHUNK_BYTES))
            .profile("")
            .create(BufWriter::new(file))
            .map_err(|e| wrote(&e))?;
        // After a failed write the mcap writer panics when dropped (it finishes the file in Drop):
        // it is only ever dropped after a successful finish, and leaked on the error paths.
        let mut writer = std::mem::ManuallyDrop::new(writer);
        let meta: BTreeMap<String, String> = [("joint_names".to_owned(), joint_names.join(","))].into();
        // The replay channel also says how to rebuild the run: files and options.
        let mut policy_meta = meta.clone();
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
        let mut timing_meta = meta.clone();
        timing_meta.insert("bus_names".into(), info.bus_names.join(","));
        let mut replay_meta = meta.clone();
        if let Some(run) = run {
            replay_meta.insert("run".into(), run.to_json());
        }
        if let Some(n) = info.reference_ticks {
            replay_meta.insert("reference_ticks".into(), n.to_string());
        }
        if let Some(run) = run {
            attach_run_files(&mut writer, run).map_err(|e| wrote(&e))?;
        }
        let mut channels = Vec::with_capacity(TOPICS.len());
        let mut live = Vec::with_capacity(TOPICS.len());
        for (topic, schema) in TOPICS {
            let name = if topic == "/tf" {
                "foxglove.FrameTransform"
            } else {
                topic.trim_start_matches('/')
            };
            let schema_id = writer
                .add_schema(name, "jsonschema", schema.as_bytes())
                .map_err(|e| wrote(&e))?;
            let m = match topic {
                "/replay" => &replay_meta,
                "/timing" => &timing_meta,
                "/policy" => &policy_meta,
                _ => &meta,
            };
            channels.push(
                writer
                    .add_channel(schema_id, topic, "json", m)
                    .map_err(|e| wrote(&e))?,
            );
            live.push(info.live.as_ref().and_then(|l| l.channel(topic, name, schema, m)));
        }
        // One channel per bus for its cycles, when asked for: its joints' names in the metadata.
        let mut bus_channels = Vec::new();
        if let Some(joints) = &info.bus_cycles {
            let schema = writer
                .add_schema("bus_cycle", "jsonschema", BUS_CYCLE_SCHEMA.as_bytes())
                .map_err(|e| wrote(&e))?;
            for (name, joints) in info.bus_names.iter().zip(joints) {
                let names: Vec<&str> = joints
                    .iter()
                    .take(MAX_RECORDED_JOINTS)
                    .filter_map(|&i| joint_names.get(i).map(String::as_str))
                    .collect();
                let m: BTreeMap<String, String> = [("joint_names".to_owned(), names.join(","))].into();
                let topic = format!("/bus/{name}");
                let id = writer
                    .add_channel(schema, &topic, "json", &m)
                    .map_err(|e| wrote(&e))?;
                let on_air = info
                    .live
                    .as_ref()
                    .and_then(|l| l.channel(&topic, "bus_cycle", BUS_CYCLE_SCHEMA, &m));
                bus_channels.push((id, topic, on_air));
            }
        }
        let root = root_frame.to_owned();
        let kinematics = info.kinematics.clone();
        // The live view lives as long as the logger that feeds it.
        let on_air = info.live.clone();
        let file_path = path.to_path_buf();
        let failed = move |e: &dyn std::fmt::Display| TelemetryError::Write {
            path: file_path.clone(),
            message: e.to_string(),
        };
        let logger = std::thread::Builder::new()
            .name("telemetry".into())
            .spawn(move || {
                let _on_air = on_air;
                let mut links = match &kinematics {
                    Some((mjcf, joints)) => Some(Links::new(mjcf, joints, &root)?),
                    None => None,
                };
                let tf_index = TOPICS.iter().position(|t| t.0 == "/tf").expect("a /tf topic");
                let (tf, live_tf) = (channels[tf_index], live[tf_index].clone());
                let mut sent = Sent::default();
                let mut written = 0u64;
                let mut text = String::with_capacity(16 * 1024);
                let mut last_mode = u8::MAX;
                while let Ok(record) = rx.recv() {
                    let r = match record {
                        Record::Tick(r) => r,
                        Record::Cycle(c) => {
                            if let Some((id, topic, on_air)) = bus_channels.get(usize::from(c.bus)) {
                                text.clear();
                                encode_cycle(&mut text, &c);
                                sent.write(&mut writer, *id, topic, c.started_ns, &text)
                                    .map_err(|e| failed(&e))?;
                                if let Some(channel) = on_air {
                                    crate::live::publish(channel, &text, c.started_ns);
                                }
                            }
                            written += 1;
                            continue;
                        }
                    };
                    for (k, (topic, _)) in TOPICS.iter().enumerate() {
                        text.clear();
                        let wrote = encode(&mut text, k, &r, &root, &mut last_mode);
                        if !wrote {
                            continue;
                        }
                        sent.write(&mut writer, channels[k], topic, r.time_ns, &text)
                            .map_err(|e| failed(&e))?;
                        if let Some(channel) = &live[k] {
                            crate::live::publish(channel, &text, r.time_ns);
                        }
                    }
                    if let Some(links) = &mut links
                        && !r.base_pose[0].is_nan()
                    {
                        for i in 0..links.update(&r) {
                            text.clear();
                            links.encode(&mut text, i, r.time_ns);
                            sent.write(&mut writer, tf, "/tf", r.time_ns, &text)
                                .map_err(|e| failed(&e))?;
                            if let Some(channel) = &live_tf {
                                crate::live::publish(channel, &text, r.time_ns);
                            }
                        }
                    }
                    written += 1;
                }
                writer.finish().map_err(|e| failed(&e))?;
                drop(std::mem::ManuallyDrop::into_inner(writer));
                Ok((written, sent.counts))
            })
            .map_err(|e| TelemetryError::Logger(e.to_string()))?;
        Ok(Self {
            tx: Some(tx),
            backpressure,
            pushed: 0,
            dropped: Arc::new(AtomicU64::new(0)),
            logger: Some(logger),
            path: path.to_path_buf(),
        })
    }

    /// Hands a record to the logger (no allocation; blocks or drops per the backpressure).
    pub fn push(&mut self, record: &TickRecord) {
        self.send(Record::Tick(*record));
    }

    /// Hands one bus cycle to the logger, like [`Self::push`] (recorded on `/bus/<name>` when
    /// the recording was started with [`RecordingInfo::bus_cycles`]).
    pub fn push_cycle(&mut self, record: &CycleRecord) {
        self.send(Record::Cycle(*record));
    }

    fn send(&mut self, record: Record) {
        let Some(tx) = &self.tx else { return };
        self.pushed += 1;
        let full = match self.backpressure {
            Backpressure::Block => tx.send(record).is_err(),
            Backpressure::Drop => tx.try_send(record).is_err(),
        };
        if full {
            self.dropped.fetch_add(1, Ordering::Relaxed);
        }
    }

    /// Closes the ring, waits for the logger to write everything, finishes the file.
    pub fn finish(mut self) -> Result<TelemetryReport, TelemetryError> {
        self.tx.take();
        let (written, messages) = self.logger.take().map_or(Ok((0, BTreeMap::new())), |h| {
            h.join()
                .map_err(|_| TelemetryError::Logger("the thread panicked".into()))?
        })?;
        Ok(TelemetryReport {
            path: self.path.clone(),
            pushed: self.pushed,
            written,
            dropped: self.dropped.load(Ordering::Relaxed),
            messages,
        })
    }
}

/// A JSON array named `name`; non-finite values as null. `{:?}` prints the shortest text that
/// reads back to the same bits (for f32 and f64 alike).
fn json_array<T: Copy + Into<f64> + std::fmt::Debug>(
    out: &mut String,
    name: &str,
    values: impl IntoIterator<Item = T>,
) {
    let _ = write!(out, "\"{name}\":[");
    for (i, v) in values.into_iter().enumerate() {
        if i > 0 {
            out.push(',');
        }
        if v.into().is_finite() {
            let _ = write!(out, "{v:?}");
        } else {
            out.push_str("null");
        }
    }
    out.push(']');
}

fn array64(out: &mut String, name: &str, values: impl IntoIterator<Item = f64>) {
    json_array(out, name, values);
}

fn array(out: &mut String, name: &str, values: &[f32]) {
    json_array(out, name, values.iter().copied());
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

/// Encodes topic `k` of `r` as JSON into `out`; false when the topic has nothing this tick.
fn encode(out: &mut String, k: usize, r: &TickRecord, root: &str, last_mode: &mut u8) -> bool {
    let n = usize::from(r.joints);
    out.push('{');
    match k {
        0 => {
            joint_state_fields(out, r, n);
        }
        1 => {
            array64(out, "q", r.target[..n].iter().map(|t| t[0]));
            out.push(',');
            array64(out, "kp", r.target[..n].iter().map(|t| t[2]));
            out.push(',');
            array(out, "reference_q", &r.reference_q[..n]);
            out.push(',');
            array64(out, "reference_root", r.reference_root.iter().copied());
            let _ = write!(out, ",\"tracking\":{}", r.tracking);
        }
        2 => {
            let _ = write!(out, "\"tick\":{},\"running\":{},", r.tick, r.mode == 3);
            array(out, "obs", &r.obs[..usize::from(r.obs_len)]);
            out.push(',');
            array(out, "action", &r.action[..n]);
            if let Some((robot, reference)) = r.anchors {
                out.push(',');
                array64(out, "robot_anchor", robot.iter().copied());
                out.push(',');
                array64(out, "reference_anchor", reference.iter().copied());
            }
            if r.bodies > 0 {
                out.push(',');
                array(out, "body_errors_m", &r.body_errors[..usize::from(r.bodies)]);
            }
            commands_field(out, r);
        }
        3 => {
            if r.mode == *last_mode {
                out.clear();
                return false;
            }
            *last_mode = r.mode;
            let name = MODE_NAMES.get(usize::from(r.mode)).copied().unwrap_or("?");
            let cause = std::str::from_utf8(&r.cause[..usize::from(r.cause_len)]).unwrap_or("?");
            let _ = write!(
                out,
                "\"tick\":{},\"mode\":\"{name}\",\"cause\":{cause:?},\"fault\":{}",
                r.tick, r.cause_fault
            );
        }
        4 => {
            array64(out, "gyro", r.imu[..3].iter().copied());
            out.push(',');
            array64(out, "accel", r.imu[3..6].iter().copied());
            out.push(',');
            array64(out, "quat", r.imu[6..10].iter().copied());
            let _ = write!(out, ",\"age_ms\":{}", r.imu_age_ms);
        }
        5 => {
            let _ = write!(out, "\"io_us\":{},\"compute_us\":{},", r.io_us, r.compute_us);
            array(out, "bus_us", &r.bus_us[..usize::from(r.buses)]);
        }
        7 => {
            let f = usize::from(r.feet);
            let _ = write!(
                out,
                "\"tick\":{},\"imu_missed\":{},\"stop\":{},\"simulation_failed\":{},",
                r.tick, r.imu_missed, r.stop_requested, r.simulation_failed
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
        }
        8 => {
            let e = &r.estimate;
            if !e.present {
                out.clear();
                return false;
            }
            let x = &e.estimate;
            let f = x.feet;
            let _ = write!(out, "\"valid\":{},", x.valid);
            for (name, v) in [
                ("position", x.position),
                ("velocity", x.velocity),
                ("velocity_base", x.velocity_base),
                ("position_std", x.position_std),
                ("velocity_std", x.velocity_std),
                ("accel_bias", x.accel_bias),
            ] {
                array64(out, name, v);
                out.push(',');
            }
            array64(
                out,
                "contacts",
                x.contacts[..f].iter().map(|&c| f64::from(u8::from(c))),
            );
            out.push(',');
            array64(out, "loads", x.loads[..f].iter().copied());
            if let Some((pose, vel)) = e.truth {
                out.push(',');
                array64(out, "truth_position", pose[..3].iter().copied());
                out.push(',');
                array64(out, "truth_velocity_base", vel);
                out.push(',');
                let feet = usize::from(r.feet).min(f);
                array64(
                    out,
                    "truth_contacts",
                    r.foot_contacts[..feet].iter().map(|&c| f64::from(u8::from(c))),
                );
            }
        }
        _ => {
            if r.base_pose[0].is_nan() {
                out.clear();
                return false;
            }
            let p = r.base_pose;
            let _ = write!(
                out,
                "\"timestamp\":{{\"sec\":{},\"nsec\":{}}},\"parent_frame_id\":\"world\",\"child_frame_id\":\"{root}\",\
                 \"translation\":{{\"x\":{},\"y\":{},\"z\":{}}},\"rotation\":{{\"x\":{},\"y\":{},\"z\":{},\"w\":{}}}",
                r.time_ns / 1_000_000_000,
                r.time_ns % 1_000_000_000,
                p[0],
                p[1],
                p[2],
                p[4],
                p[5],
                p[6],
                p[3]
            );
        }
    }
    out.push('}');
    true
}

/// Forward kinematics of the recorded joints for per-link frame transforms.
struct Links {
    data: mujoco_rs::prelude::MjData<Box<mujoco_rs::prelude::MjModel>>,
    root_qpos: usize,
    joint_qpos: Vec<usize>,
    /// (parent name, child name, parent body, child body) for every body but the world and root.
    pairs: Vec<(String, String, usize, usize)>,
    poses: Vec<([f64; 3], [f64; 4])>,
}

impl Links {
    fn new(mjcf: &Path, joints: &[String], root: &str) -> Result<Self, TelemetryError> {
        use mujoco_rs::wrappers::mj_model::MjtObjBase;
        let model =
            sim2real::mujoco::load_model(mjcf).map_err(|e| TelemetryError::Kinematics(e.to_string()))?;
        let joints: Vec<&str> = joints.iter().map(String::as_str).collect();
        let index = sim2real::model_index::ModelIndex::new(&model, root, &joints, &[])
            .map_err(|e| TelemetryError::Kinematics(format!("{e} ({})", mjcf.display())))?;
        let (root_body, root_qpos) = (index.root_body, index.root.qpos);
        let joint_qpos: Vec<usize> = index.joints.iter().map(|j| j.qpos).collect();
        let name = |b: usize| {
            model
                .id_to_name(MjtObjBase::mjOBJ_BODY, b)
                .unwrap_or("world")
                .to_owned()
        };
        let pairs: Vec<_> = (1..model.ffi().nbody as usize)
            .filter(|&b| b != root_body)
            .map(|b| {
                let p = model.body_parentid()[b] as usize;
                (name(p), name(b), p, b)
            })
            .collect();
        let n = pairs.len();
        Ok(Self {
            data: mujoco_rs::prelude::MjData::new(Box::new(model)),
            root_qpos,
            joint_qpos,
            pairs,
            poses: vec![([0.0; 3], [1.0, 0.0, 0.0, 0.0]); n],
        })
    }

    /// Computes every link's pose in its parent's frame; returns how many.
    fn update(&mut self, r: &TickRecord) -> usize {
        self.data.qpos_mut()[self.root_qpos..self.root_qpos + 7].copy_from_slice(&r.base_pose);
        for (i, &adr) in self.joint_qpos.iter().enumerate().take(usize::from(r.joints)) {
            self.data.qpos_mut()[adr] = r.q[i];
        }
        self.data.kinematics();
        let (xpos, xquat) = (self.data.xpos(), self.data.xquat());
        for (k, &(_, _, p, b)) in self.pairs.iter().enumerate() {
            // The child in its parent's frame.
            let inv = spatial::quat_conj(xquat[p]);
            self.poses[k] = (
                spatial::quat_rotate(inv, spatial::sub(xpos[b], xpos[p])),
                spatial::quat_mul(inv, xquat[b]),
            );
        }
        self.pairs.len()
    }

    fn encode(&self, out: &mut String, i: usize, time_ns: u64) {
        let (parent, child, _, _) = &self.pairs[i];
        let (t, q) = self.poses[i];
        let _ = write!(
            out,
            "{{\"timestamp\":{{\"sec\":{},\"nsec\":{}}},\"parent_frame_id\":\"{parent}\",\"child_frame_id\":\"{child}\",\
             \"translation\":{{\"x\":{},\"y\":{},\"z\":{}}},\"rotation\":{{\"x\":{},\"y\":{},\"z\":{},\"w\":{}}}}}",
            time_ns / 1_000_000_000,
            time_ns % 1_000_000_000,
            t[0],
            t[1],
            t[2],
            q[1],
            q[2],
            q[3],
            q[0]
        );
    }
}

impl std::fmt::Debug for Links {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Links")
            .field("links", &self.pairs.len())
            .finish_non_exhaustive()
    }
}
