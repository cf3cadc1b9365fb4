//! `robot.toml`: joints in policy order, buses, IMU, feet and root, checked against the MJCF beside it
//! and against the actuator models of `firmware-bridge`.

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};
use std::sync::{Arc, OnceLock};

use mujoco_rs::prelude::MjModel;

use firmware_bridge::{dxl, feetech, mit};

use crate::mjcf::{self, MjcfSummary};

/// A bus of the robot.
#[derive(Debug, Clone, PartialEq, serde::Deserialize, schemars::JsonSchema, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct BusConfig {
    /// Name joints refer to, e.g. `can0`.
    pub name: String,
    /// What runs on it.
    pub kind: BusKind,
    /// Device on the real robot: a SocketCAN interface (`can0`), a serial device path, or the
    /// network interface the robot is on (`unitree_dds`: `eth0`, `enp3s0`).
    pub device: String,
    /// Bit rate (CAN), baud rate (serial), or the network link's speed in bit/s (`unitree_dds`:
    /// 1000000000 for gigabit Ethernet; it sets the wire time of a cycle).
    pub rate: u32,
    /// Bus cycles per second: every device gets one round trip per cycle, on the bus's own
    /// thread. Default: the fastest of [`DEFAULT_BUS_RATES_HZ`] whose worst-case wire time fills
    /// at most [`DEFAULT_BUS_LOAD`] of the period. Range: the policy's rate to 10 kHz, and the
    /// wire must carry a cycle within the period.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rate_hz: Option<f64>,
    /// What the joints are commanded between policy ticks: the newest target held, or a ramp
    /// from the previous target to the newest over one policy period (gains ramp with it).
    #[serde(default)]
    pub interpolation: Interpolation,
    /// The devices' own command timeout, ms: torque drops when no command arrived for this long
    /// (MIT firmware timeout, Dynamixel Bus Watchdog). At least two bus periods, at most 10 s;
    /// Dynamixel counts it in 20 ms steps (20–2540 ms). Default: [`default_command_timeout`].
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub command_timeout_ms: Option<f64>,
    /// Dynamixel only: read the servos' state with Fast Sync Read (one status packet for all,
    /// X-series firmware 45 and later) instead of one status each — less wire time per cycle.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub fast_reads: bool,
    /// `unitree_dds` only: the DDS domain the robot's board is on, 0–232 (default 0, as the
    /// robot ships).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub domain: Option<u32>,
    /// `unitree_dds` only: the robot's low-level message family (default `unitree_hg`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub family: Option<UnitreeFamily>,
}

/// The low-level message family of a Unitree robot's board.
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, Default, serde::Deserialize, schemars::JsonSchema, serde::Serialize,
)]
#[serde(rename_all = "snake_case")]
pub enum UnitreeFamily {
    /// `unitree_hg`: G1 and H1-2 (35 motor slots, `LowCmd_`/`LowState_` of `unitree_hg::msg::dds_`).
    #[default]
    UnitreeHg,
}

/// Largest DDS domain id robot.toml accepts (RTPS's port mapping stays below 65536).
pub const MAX_DDS_DOMAIN: u32 = 232;

/// Bytes a `unitree_hg` command and state add on the wire beyond their CDR: RTPS header and data
/// submessage, UDP, IPv4 and Ethernet framing.
const DDS_FRAMING_BYTES: u64 = 20 + 24 + 8 + 20 + 38;

/// Bus rates tried for a default, fastest first, Hz.
pub const DEFAULT_BUS_RATES_HZ: [f64; 6] = [1000.0, 500.0, 250.0, 200.0, 100.0, 50.0];

/// Share of a bus period the worst-case time of a default-rate cycle may fill. Half: the rest is
/// for what the wire time leaves out — a host that is not real-time, USB CAN adapters (about
/// 1 ms per direction), firmware reply delays — so a cycle late by as much as its own length
/// still keeps its slot.
pub const DEFAULT_BUS_LOAD: f64 = 0.5;

/// Fastest bus rate robot.toml accepts, Hz.
pub const MAX_BUS_RATE_HZ: f64 = 10_000.0;

/// What a bus commands between policy ticks.
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, Default, serde::Deserialize, schemars::JsonSchema, serde::Serialize,
)]
#[serde(rename_all = "snake_case")]
pub enum Interpolation {
    /// The newest target until the next one.
    #[default]
    Hold,
    /// From the previous target to the newest over one policy period.
    Linear,
}

/// How one bus is scheduled: resolved from robot.toml and its defaults.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BusTiming {
    /// Cycles per second.
    pub rate_hz: f64,
    /// One cycle.
    pub period: std::time::Duration,
    /// Worst-case wire time of one cycle (zero for a stream the host only reads).
    pub wire_time: std::time::Duration,
    /// What the host's adapter adds to a round trip (a USB serial adapter's latency timer).
    pub adapter_latency: std::time::Duration,
    /// Between policy ticks.
    pub interpolation: Interpolation,
    /// The devices' own command timeout.
    pub command_timeout: std::time::Duration,
}

/// Latency a USB serial adapter adds to each direction of a Dynamixel round trip: the FTDI
/// latency timer at its lowest setting (Linux `low_latency`), 1 ms.
pub const SERIAL_ADAPTER_LATENCY: std::time::Duration = std::time::Duration::from_millis(1);

impl BusTiming {
    /// Wire time plus the adapter's latency: how long a cycle takes at best.
    pub fn round_trip(&self) -> std::time::Duration {
        self.wire_time + self.adapter_latency
    }

    /// Share of the period the wire is busy, 0–1.
    pub fn load(&self) -> f64 {
        self.wire_time.as_secs_f64() / self.period.as_secs_f64()
    }
}

/// The command timeout a bus gets when robot.toml names none: ten bus periods, at least 20 ms
/// (a Dynamixel Bus Watchdog step), rounded up to whole 20 ms steps on Dynamixel lines.
pub fn default_command_timeout(kind: BusKind, period: std::time::Duration) -> std::time::Duration {
    let ms = (period.as_secs_f64() * 10.0 * 1e3).max(20.0);
    let ms = if kind == BusKind::Dynamixel {
        (ms / 20.0).ceil() * 20.0
    } else {
        ms.ceil()
    };
    std::time::Duration::from_millis(ms as u64)
}

/// The protocol of a bus.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Deserialize, schemars::JsonSchema, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum BusKind {
    /// MIT-mode motors on CAN.
    MitCan,
    /// Dynamixel Protocol 2.0 servos on a half-duplex serial line.
    Dynamixel,
    /// Feetech STS servos on a half-duplex serial line. They have no command watchdog: a servo
    /// holds its last goal when the host goes quiet.
    Feetech,
    /// An IMU streaming on a serial line.
    ImuSerial,
    /// A Unitree robot's own board over DDS on Ethernet (`rt/lowcmd`, `rt/lowstate`): joint
    /// `id`s are the motors' indices in the messages, and the robot's IMU can be read from its
    /// state (`[imu] bus` naming this bus).
    UnitreeDds,
}

/// One actuated joint, in the policy's order.
#[derive(Debug, Clone, PartialEq, serde::Deserialize, schemars::JsonSchema, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct JointConfig {
    /// Name the policy and telemetry use.
    pub name: String,
    /// Joint name in the MJCF.
    pub mjcf_joint: String,
    /// Bus name.
    pub bus: String,
    /// Device ID on that bus.
    pub id: u8,
    /// Motor or servo model (`firmware-bridge` tables).
    pub model: String,
    /// +1 or -1: joint sign relative to the actuator's.
    pub direction: f64,
    /// Actuator angle at joint zero, rad (MIT: motor angle; Dynamixel: converted to ticks).
    pub zero_offset: f64,
    /// Dynamixel only: Homing Offset (ticks) the driver programs, keeping the encoder's wrap
    /// point outside the joint's range. Calibration sets it.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub homing_offset_ticks: i32,
    /// Actuator turns per joint turn (1 for direct drive).
    pub gear: f64,
    /// Joint position limits, rad.
    pub position_limits: [f64; 2],
    /// Joint speed limit, rad/s.
    pub velocity_limit: f64,
    /// Joint torque limit, N·m.
    pub torque_limit: f64,
    /// Default (standing) joint angle, rad.
    pub default_position: f64,
    /// Joint stiffness, N·m/rad.
    pub kp: f64,
    /// Joint damping, N·m·s/rad.
    pub kd: f64,
}

/// The IMU.
#[derive(Debug, Clone, PartialEq, serde::Deserialize, schemars::JsonSchema, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct ImuConfig {
    /// Bus name (an `imu_serial` bus).
    pub bus: String,
    /// What it speaks: `wit` (WIT Motion AHRS streaming, default), `bno08x_rvc` (a BNO08x
    /// streaming in UART-RVC mode: 100 Hz, 115200 baud) or `bno055` (a BNO055 on its UART, set
    /// to IMU fusion mode and read at `rate_hz` ≤ 100 Hz, 115200 baud).
    #[serde(default, skip_serializing_if = "is_wit")]
    pub protocol: firmware_bridge::imu::ImuProtocol,
    /// Site in the MJCF where the IMU sits.
    pub site: String,
    /// Output rate, Hz.
    pub rate_hz: f64,
    /// Rotation from the IMU's axes to the site's axes, roll/pitch/yaw in degrees.
    pub mounting_rpy_deg: [f64; 3],
    /// Gyro bias to subtract, rad/s (from calibration).
    #[serde(default)]
    pub gyro_bias: [f64; 3],
    /// Accelerometer bias to subtract, m/s² (from calibration).
    #[serde(default)]
    pub accel_bias: [f64; 3],
    /// The model's gyro sensor the mirror's IMU reads (default: the model's gyro on `site`, else
    /// one the mirror adds there).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub gyro: Option<String>,
    /// The model's accelerometer sensor (default: the one on `site`, else one the mirror adds).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub accelerometer: Option<String>,
    /// The model's orientation sensor, a `framequat` (default: the one on `site`, else one the
    /// mirror adds).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub orientation: Option<String>,
}

fn is_wit(p: &firmware_bridge::imu::ImuProtocol) -> bool {
    *p == firmware_bridge::imu::ImuProtocol::Wit
}

/// The three sensors of the IMU in the model, by the kind MJCF gives them.
pub const IMU_SENSOR_KINDS: [(&str, &str); 3] = [
    ("gyro", "gyro"),
    ("accelerometer", "accelerometer"),
    ("orientation", "framequat"),
];

/// Where the mirror's IMU reads each of its values: the model's sensors by name, or `None` for one
/// the mirror adds to the IMU site (the model has none there). Order: gyro, accelerometer,
/// orientation.
pub type ImuSensorNames = [Option<String>; 3];

/// A robot description.
#[derive(Debug, Clone, PartialEq, serde::Deserialize, schemars::JsonSchema, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct RobotConfig {
    /// Robot name.
    pub name: String,
    /// MJCF file, relative to the robot.toml.
    pub mjcf: PathBuf,
    /// The floating base body.
    pub root_body: String,
    /// Foot bodies (contact, gantry height).
    pub feet: Vec<String>,
    /// Policy rate, Hz.
    pub control_rate_hz: f64,
    /// The policy a run takes when none is given (`--policy`): a manifest or an export, relative
    /// to the robot.toml. Checked when a run takes it (a robot.toml copied away from its policies
    /// still loads for what needs no policy: calibration, bus scans).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub policy: Option<PathBuf>,
    /// How far inside each joint's position limits the governor keeps targets, rad (0–0.2, and
    /// less than half of every joint's range). Default 0.02.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub position_margin: Option<f64>,
    /// Buses.
    pub buses: Vec<BusConfig>,
    /// IMU.
    pub imu: ImuConfig,
    /// Joints in policy order.
    pub joints: Vec<JointConfig>,
    /// How human motion maps onto this robot (retargeting, teleoperation).
    #[serde(default)]
    pub retarget: Option<RetargetConfig>,
    /// Which body or site of the model stands for each named 2D keypoint, for references seen by
    /// cameras (`nose = "head"`, or `nose = { frame = "head", offset = [0.06, 0, 0] }`): the names
    /// a pose estimator writes (COCO's 17, or any).
    #[serde(default, skip_serializing_if = "std::collections::BTreeMap::is_empty")]
    pub keypoints: std::collections::BTreeMap<String, KeypointFrame>,
    /// The model's keyframe the mirror starts the robot in (joints, and the base's position
    /// across the floor and heading), placed on the floor by its geometry. Default: the default
    /// pose, upright.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub start_keyframe: Option<String>,
    /// The model's keyframe whose joint angles a controlled sit-down ends in (`play --on-stop
    /// sit`), before the joints go limp.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sit_keyframe: Option<String>,
    /// MIT-mode motor models of this robot's own, beside the shipped table (a name here
    /// shadows a shipped one).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub mit_models: Vec<MitModelConfig>,
    /// Serial servo variants of this robot's own: a shipped Dynamixel model with other motor
    /// constants (a winding, a gearing, a supply voltage), speaking as the shipped one.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub servo_models: Vec<ServoModelConfig>,
    /// Foot switches on Linux GPIO lines, for the state estimator's contacts (none: contact is
    /// estimated from the legs' kinematics).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub contacts: Vec<ContactSwitch>,
    /// How a run hands the robot to the policy: on the joints' PD first, the policy from its
    /// first tick on the floor, or the policy from its first tick in a harness that lowers the
    /// robot onto its feet.
    #[serde(default, skip_serializing_if = "StartConfig::is_default")]
    pub start: StartConfig,
    /// Safety thresholds of this robot (the run's defaults where it gives none).
    #[serde(default, skip_serializing_if = "SafetyConfig::is_default")]
    pub safety: SafetyConfig,
    /// Joint dynamics the trainer's simulation gives the joints (rotor armature, friction,
    /// damping), per joint or group; applied to the compiled model, never to the MJCF file.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub joint_dynamics: Vec<JointDynamics>,
    /// Physics settings of the trainer's simulation (the model's own where none).
    #[serde(default, skip_serializing_if = "SimConfig::is_default")]
    pub sim: SimConfig,
    /// How the trainer's simulation made each joint's torque from its command, per joint or
    /// group (the mirror does the same; the real robot's firmware is what it is).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub actuators: Vec<crate::actuators::ActuatorGroup>,
    /// The state estimator's noises and thresholds (`[estimator]`, every field optional; each
    /// one's default and range are in its own entry below).
    #[serde(default, skip_serializing_if = "crate::EstimatorConfig::is_default")]
    pub estimator: crate::EstimatorConfig,
}

/// Joint dynamics for a joint or a group (robot.toml `[[joint_dynamics]]`): what a trainer such as
/// mjlab adds per actuator group to a model that lacks it. A later entry wins over an earlier one,
/// field by field, for the joints both match.
#[derive(Debug, Clone, PartialEq, serde::Deserialize, schemars::JsonSchema, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct JointDynamics {
    /// Joint names or patterns (`*` matches any run of characters: `"*knee*"`).
    pub joints: Vec<String>,
    /// Rotor inertia reflected through the gearing, kg·m² (0–10).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub armature: Option<f64>,
    /// Dry friction, N·m (0–1000).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub frictionloss: Option<f64>,
    /// Viscous damping, N·m·s/rad (0–1000).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub damping: Option<f64>,
}

/// One joint's dynamics after every `[[joint_dynamics]]` entry (none: the model's own).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct JointDynamicsOf {
    /// Armature, kg·m².
    pub armature: Option<f64>,
    /// Friction loss, N·m.
    pub frictionloss: Option<f64>,
    /// Damping, N·m·s/rad.
    pub damping: Option<f64>,
}

/// MuJoCo's numerical integrators (robot.toml `[sim] integrator`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Deserialize, schemars::JsonSchema, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Integrator {
    /// Semi-implicit Euler.
    Euler,
    /// Fourth-order Runge-Kutta.
    Rk4,
    /// Implicit in velocity.
    Implicit,
    /// Implicit in velocity, without the Coriolis terms' derivatives (mjlab's and holosoma's).
    Implicitfast,
}

/// Physics settings (robot.toml `[sim]`): the trainer's, where the model file differs.
#[derive(
    Debug, Clone, Copy, Default, PartialEq, serde::Deserialize, schemars::JsonSchema, serde::Serialize,
)]
#[serde(default, deny_unknown_fields)]
pub struct SimConfig {
    /// Physics step, s (0.0001 up to the policy period, a whole number of steps per period).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub timestep: Option<f64>,
    /// Integrator.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub integrator: Option<Integrator>,
    /// Constraint solver iterations (1–1000).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub iterations: Option<u32>,
    /// Constraint solver.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub solver: Option<Solver>,
    /// Friction cone of the contacts.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub cone: Option<FrictionCone>,
    /// Ratio of frictional to normal constraint impedance (1–100): above 1, contacts slip less.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub impratio: Option<f64>,
}

/// MuJoCo's constraint solvers (robot.toml `[sim] solver`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Deserialize, schemars::JsonSchema, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Solver {
    /// Projected Gauss-Seidel.
    Pgs,
    /// Conjugate gradient.
    Cg,
    /// Newton.
    Newton,
}

/// MuJoCo's friction cones (robot.toml `[sim] cone`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Deserialize, schemars::JsonSchema, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum FrictionCone {
    /// Pyramidal (MuJoCo's default).
    Pyramidal,
    /// Elliptic.
    Elliptic,
}

impl SimConfig {
    /// Whether nothing is set.
    pub fn is_default(&self) -> bool {
        *self == Self::default()
    }

    /// Checks every field against its documented range; `period` is the policy's, s.
    pub fn check(&self, period: f64) -> Result<(), (String, String)> {
        if let Some(t) = self.timestep {
            if !(t.is_finite() && (0.0001..=period + 1e-12).contains(&t)) {
                return Err((
                    "sim.timestep".into(),
                    format!(
                        "{} s is outside [0.0001, {}] (the policy period)",
                        crate::num(t),
                        crate::num(period)
                    ),
                ));
            }
            let steps = period / t;
            if (steps - steps.round()).abs() > 1e-6 {
                return Err((
                    "sim.timestep".into(),
                    format!(
                        "{} s does not divide the policy period {} s into whole steps",
                        crate::num(t),
                        crate::num(period)
                    ),
                ));
            }
        }
        if let Some(i) = self.iterations
            && !(1..=1000).contains(&i)
        {
            return Err(("sim.iterations".into(), format!("{i} is outside [1, 1000]")));
        }
        if let Some(r) = self.impratio
            && !(r.is_finite() && (1.0..=100.0).contains(&r))
        {
            return Err((
                "sim.impratio".into(),
                format!("{} is outside [1, 100]", crate::num(r)),
            ));
        }
        Ok(())
    }
}

impl JointDynamics {
    /// Checks every field against its documented range and every pattern against `joints`.
    fn check(list: &[Self], joints: &[JointConfig]) -> Result<(), (String, String)> {
        for (i, d) in list.iter().enumerate() {
            let at = |field: &str| format!("joint_dynamics[{i}].{field}");
            if d.joints.is_empty() {
                return Err((at("joints"), "names no joint".into()));
            }
            for p in &d.joints {
                if !joints.iter().any(|j| matches_pattern(p, &j.name)) {
                    return Err((at("joints"), format!("{p:?} matches no joint of the robot")));
                }
            }
            if d.armature.is_none() && d.frictionloss.is_none() && d.damping.is_none() {
                return Err((
                    at("joints"),
                    "sets nothing: give armature, frictionloss or damping".into(),
                ));
            }
            for (field, value, hi, unit) in [
                ("armature", d.armature, 10.0, "kg·m²"),
                ("frictionloss", d.frictionloss, 1000.0, "N·m"),
                ("damping", d.damping, 1000.0, "N·m·s/rad"),
            ] {
                check_range(&at(field), value, 0.0, hi, unit)?;
            }
        }
        Ok(())
    }
}

impl RobotConfig {
    /// The dynamics `[[joint_dynamics]]` gives joint `name`, field by field (the last entry
    /// matching it that sets a field wins).
    pub fn joint_dynamics_of(&self, name: &str) -> JointDynamicsOf {
        let mut out = JointDynamicsOf::default();
        for d in self
            .joint_dynamics
            .iter()
            .filter(|d| d.joints.iter().any(|p| matches_pattern(p, name)))
        {
            out.armature = d.armature.or(out.armature);
            out.frictionloss = d.frictionloss.or(out.frictionloss);
            out.damping = d.damping.or(out.damping);
        }
        out
    }
}

/// A robot's own safety thresholds (robot.toml `[safety]`).
#[derive(Debug, Clone, Default, PartialEq, serde::Deserialize, schemars::JsonSchema, serde::Serialize)]
#[serde(default, deny_unknown_fields)]
pub struct SafetyConfig {
    /// Largest base tilt from upright before the robot is stopped, rad (0.1–1.5; default 0.8).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub tilt: Option<f64>,
    /// How far a joint may stay from its position target, rad (0.05–3), before the
    /// tracking-error stop fires (default 0.5) …
    #[serde(skip_serializing_if = "Option::is_none")]
    pub tracking_error: Option<f64>,
    /// … for longer than this, s (0.02–10; default 0.5). Counted only while the policy is in
    /// control.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub tracking_s: Option<f64>,
    /// Per joint or joint group: `joints` names or patterns (`*` matches any run of characters:
    /// `"*ankle*"`), with their own `error` and `seconds`. A later rule wins over an earlier one
    /// for the joints both match.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub tracking: Vec<TrackingRule>,
    /// Where a policy's position targets may lie.
    #[serde(skip_serializing_if = "PositionTargets::is_inside")]
    pub position_targets: PositionTargets,
}

/// Where the governor lets a policy's position targets lie.
#[derive(
    Debug, Clone, Copy, Default, PartialEq, Eq, serde::Deserialize, schemars::JsonSchema, serde::Serialize,
)]
#[serde(rename_all = "snake_case")]
pub enum PositionTargets {
    /// Inside each joint's position limits, less the margin.
    #[default]
    InsideLimits,
    /// Beyond a limit by at most what the joint's torque limit reaches at its stiffness
    /// (τ_max / kp): the joint's PD then pushes towards that limit with at most its torque limit,
    /// as the trainer's simulation let the policy do (policies trained with targets unclipped
    /// press ankles and waist against their limits on purpose).
    TorqueReach,
}

impl PositionTargets {
    fn is_inside(&self) -> bool {
        *self == Self::InsideLimits
    }
}

/// The tracking-error stop's threshold for some joints.
#[derive(Debug, Clone, PartialEq, serde::Deserialize, schemars::JsonSchema, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct TrackingRule {
    /// Joint names or patterns (`*` matches any run of characters).
    pub joints: Vec<String>,
    /// Largest distance from the target, rad (0.05–3).
    pub error: f64,
    /// For longer than this, s (0.02–10).
    pub seconds: f64,
}

/// An optional field of robot.toml within `[lo, hi]` (finite), or `(field, message)` naming its
/// value and the range.
pub(crate) fn check_range(
    field: &str,
    value: Option<f64>,
    lo: f64,
    hi: f64,
    unit: &str,
) -> Result<(), (String, String)> {
    match value {
        Some(v) if !(v.is_finite() && (lo..=hi).contains(&v)) => Err((
            field.to_owned(),
            format!(
                "{} {unit} is outside [{}, {}]",
                crate::num(v),
                crate::num(lo),
                crate::num(hi)
            ),
        )),
        _ => Ok(()),
    }
}

/// An IMU's mounting and biases within their documented ranges: angles within ±360°, gyro
/// biases within ±10 rad/s, accelerometer biases within ±50 m/s² (a saturated part reads ±16 g).
pub(crate) fn check_imu_mounting(
    prefix: &str,
    rpy_deg: [f64; 3],
    gyro_bias: [f64; 3],
    accel_bias: [f64; 3],
) -> Result<(), (String, String)> {
    for (field, v, bound, unit) in [
        ("mounting_rpy_deg", rpy_deg, 360.0, "°"),
        ("gyro_bias", gyro_bias, 10.0, "rad/s"),
        ("accel_bias", accel_bias, 50.0, "m/s²"),
    ] {
        if let Some(x) = v.iter().find(|x| !(x.is_finite() && x.abs() <= bound)) {
            return Err((
                format!("{prefix}.{field}"),
                format!("{} {unit} is outside ±{}", crate::num(*x), crate::num(bound)),
            ));
        }
    }
    Ok(())
}

/// Whether `name` matches `pattern`, where `*` stands for any run of characters.
pub fn matches_pattern(pattern: &str, name: &str) -> bool {
    let parts: Vec<&str> = pattern.split('*').collect();
    if parts.len() == 1 {
        return pattern == name;
    }
    let (first, last) = (parts[0], parts[parts.len() - 1]);
    if !name.starts_with(first) || name.len() < first.len() + last.len() || !name.ends_with(last) {
        return false;
    }
    let mut rest = &name[first.len()..name.len() - last.len()];
    for part in &parts[1..parts.len() - 1] {
        match rest.find(part) {
            Some(i) => rest = &rest[i + part.len()..],
            None => return false,
        }
    }
    true
}

impl SafetyConfig {
    fn is_default(&self) -> bool {
        *self == Self::default()
    }

    /// Each joint's tracking-error threshold (rad) and time (s), robot.toml order, from the rules
    /// over the given defaults.
    pub fn tracking_limits(&self, joints: &[JointConfig], error: f64, seconds: f64) -> Vec<(f64, f64)> {
        let base = (
            self.tracking_error.unwrap_or(error),
            self.tracking_s.unwrap_or(seconds),
        );
        joints
            .iter()
            .map(|j| {
                self.tracking
                    .iter()
                    .rev()
                    .find(|r| r.joints.iter().any(|p| matches_pattern(p, &j.name)))
                    .map_or(base, |r| (r.error, r.seconds))
            })
            .collect()
    }

    /// Checks every field against its documented range and every pattern against `joints`.
    pub fn check(&self, joints: &[JointConfig]) -> Result<(), (String, String)> {
        let within = |field: String, v: f64, lo: f64, hi: f64, unit: &str| {
            if v.is_finite() && (lo..=hi).contains(&v) {
                Ok(())
            } else {
                Err((
                    field,
                    format!(
                        "{} {unit} is outside [{}, {}]",
                        crate::num(v),
                        crate::num(lo),
                        crate::num(hi)
                    ),
                ))
            }
        };
        if let Some(t) = self.tilt {
            within("safety.tilt".into(), t, 0.1, 1.5, "rad")?;
        }
        if let Some(e) = self.tracking_error {
            within("safety.tracking_error".into(), e, 0.05, 3.0, "rad")?;
        }
        if let Some(s) = self.tracking_s {
            within("safety.tracking_s".into(), s, 0.02, 10.0, "s")?;
        }
        for (i, r) in self.tracking.iter().enumerate() {
            within(format!("safety.tracking[{i}].error"), r.error, 0.05, 3.0, "rad")?;
            within(
                format!("safety.tracking[{i}].seconds"),
                r.seconds,
                0.02,
                10.0,
                "s",
            )?;
            if r.joints.is_empty() {
                return Err((format!("safety.tracking[{i}].joints"), "names no joint".into()));
            }
            for p in &r.joints {
                if !joints.iter().any(|j| matches_pattern(p, &j.name)) {
                    return Err((
                        format!("safety.tracking[{i}].joints"),
                        format!("{p:?} matches no joint of the robot"),
                    ));
                }
            }
        }
        Ok(())
    }
}

/// How a run hands the robot to the policy (robot.toml `[start]`).
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, Default, serde::Deserialize, schemars::JsonSchema, serde::Serialize,
)]
#[serde(rename_all = "snake_case")]
pub enum StartMode {
    /// The policy is in control from its first tick while a harness (a gantry crane's rope)
    /// holds the robot at standing height and lowers it onto its feet, then goes slack. On the
    /// robot the operator lowers it and confirms.
    Harness,
    /// The policy is in control from its first tick, the robot on the floor.
    Policy,
    /// The joints' PD ramps the robot into the default pose at reduced gains first (a robot that
    /// stands on its joints' stiffness alone), then the policy takes over.
    #[default]
    Pd,
}

impl StartMode {
    /// The name robot.toml and `--start` use.
    pub fn name(self) -> &'static str {
        match self {
            Self::Harness => "harness",
            Self::Policy => "policy",
            Self::Pd => "pd",
        }
    }
}

/// The start (robot.toml `[start]`): the mode, the PD soft start's length and gains, the harness.
#[derive(Debug, Clone, Copy, PartialEq, serde::Deserialize, schemars::JsonSchema, serde::Serialize)]
#[serde(default, deny_unknown_fields)]
pub struct StartConfig {
    /// Which start a run takes unless `play --start` says otherwise.
    pub mode: StartMode,
    /// `pd`: time to reach the default pose, s (0.1–30).
    pub pd_s: f64,
    /// `pd`: the gains' share at the start of the ramp, rising to 1 (0–1).
    pub pd_gain: f64,
    /// `harness`: how the harness lowers the robot.
    pub harness: HarnessConfig,
}

impl Default for StartConfig {
    fn default() -> Self {
        Self {
            mode: StartMode::Pd,
            pd_s: 1.0,
            pd_gain: 0.3,
            harness: HarnessConfig::default(),
        }
    }
}

impl StartConfig {
    fn is_default(&self) -> bool {
        *self == Self::default()
    }
}

/// Highest a harness may hold the soles above the floor, m: a gantry crane's hook travel over a
/// standing robot. Higher, a robot let down onto a policy that expects the floor drops.
pub const MAX_HARNESS_LIFT_M: f64 = 0.3;

/// The harness of a `harness` start.
#[derive(Debug, Clone, Copy, PartialEq, serde::Deserialize, schemars::JsonSchema, serde::Serialize)]
#[serde(default, deny_unknown_fields)]
pub struct HarnessConfig {
    /// The soles hang this far above the floor when the run begins, m (0–[`MAX_HARNESS_LIFT_M`]).
    pub lift_m: f64,
    /// Time the harness takes to lower the robot until the rope is slack, s (0.2–30).
    pub lower_s: f64,
    /// Time the policy stands on the reference's first frame once lowered, before the motion
    /// plays, s (0–30).
    pub settle_s: f64,
}

impl Default for HarnessConfig {
    fn default() -> Self {
        Self {
            lift_m: 0.03,
            lower_s: 2.0,
            settle_s: 1.0,
        }
    }
}

impl StartConfig {
    /// Checks every field against its documented range: `Err((field, message))`.
    pub fn check(&self) -> Result<(), (String, String)> {
        let within = |field: &str, v: f64, lo: f64, hi: f64, unit: &str| {
            if v.is_finite() && (lo..=hi).contains(&v) {
                Ok(())
            } else {
                Err((
                    format!("start.{field}"),
                    format!(
                        "{} {unit} is outside [{}, {}]",
                        crate::num(v),
                        crate::num(lo),
                        crate::num(hi)
                    ),
                ))
            }
        };
        within("pd_s", self.pd_s, 0.1, 30.0, "s")?;
        within("pd_gain", self.pd_gain, 0.0, 1.0, "")?;
        let h = &self.harness;
        within("harness.lift_m", h.lift_m, 0.0, MAX_HARNESS_LIFT_M, "m")?;
        within("harness.lower_s", h.lower_s, 0.2, 30.0, "s")?;
        within("harness.settle_s", h.settle_s, 0.0, 30.0, "s")
    }
}

/// An MIT-mode motor model as a robot.toml defines it: the ranges its firmware maps the 16- and
/// 12-bit command and reply fields onto (position, velocity and torque symmetric about zero,
/// gains from zero), and its reply format.
#[derive(Debug, Clone, PartialEq, serde::Deserialize, schemars::JsonSchema, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct MitModelConfig {
    /// The name joints' `model` refers to.
    pub name: String,
    /// Reply format: `cubemars`, `damiao` or `mini_cheetah`.
    pub reply: mit::models::MotorFamily,
    /// Position range, rad: `[-p_max, p_max]`.
    pub position: [f64; 2],
    /// Velocity range, rad/s: `[-v_max, v_max]`.
    pub velocity: [f64; 2],
    /// Torque range, N·m: `[-t_max, t_max]` (also the firmware's clamp).
    pub torque: [f64; 2],
    /// Stiffness range, N·m/rad: `[0, kp_max]`.
    pub kp: [f64; 2],
    /// Damping range, N·m·s/rad: `[0, kd_max]`.
    pub kd: [f64; 2],
    /// Torque the motor sustains without overheating, N·m (0 < rated ≤ t_max).
    pub rated_torque: f64,
}

impl MitModelConfig {
    /// The model, or the field that is wrong and why.
    pub fn model(&self) -> Result<mit::models::MotorModel, (&'static str, String)> {
        let symmetric = |field: &'static str, [lo, hi]: [f64; 2]| {
            if !(lo.is_finite() && hi.is_finite() && lo < hi) {
                return Err((field, format!("[{lo}, {hi}] is not a range (low < high, finite)")));
            }
            if lo != -hi {
                return Err((
                    field,
                    format!("[{lo}, {hi}]: MIT mode maps it symmetric about zero, give [-{hi}, {hi}]"),
                ));
            }
            Ok(hi)
        };
        let from_zero = |field: &'static str, [lo, hi]: [f64; 2]| {
            if !(lo.is_finite() && hi.is_finite() && lo < hi) {
                return Err((field, format!("[{lo}, {hi}] is not a range (low < high, finite)")));
            }
            if lo != 0.0 {
                return Err((field, format!("[{lo}, {hi}]: gains start at 0, give [0, {hi}]")));
            }
            Ok(hi)
        };
        let model = mit::models::MotorModel {
            name: self.name.clone(),
            family: self.reply,
            p_max: symmetric("position", self.position)?,
            v_max: symmetric("velocity", self.velocity)?,
            t_max: symmetric("torque", self.torque)?,
            kp_max: from_zero("kp", self.kp)?,
            kd_max: from_zero("kd", self.kd)?,
            rated_torque: self.rated_torque,
        };
        if !(model.rated_torque > 0.0 && model.rated_torque <= model.t_max) {
            return Err((
                "rated_torque",
                format!(
                    "{} must be in (0, {}] (the torque range)",
                    model.rated_torque, model.t_max
                ),
            ));
        }
        Ok(model)
    }
}

/// A serial servo variant as a robot.toml defines it: a shipped model (its protocol, control
/// table and identity) with the motor constants of the variant the robot carries. Each given
/// constant must be a positive number; the ones left out are the shipped model's.
#[derive(Debug, Clone, PartialEq, serde::Deserialize, schemars::JsonSchema, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct ServoModelConfig {
    /// The name joints' `model` refers to.
    pub name: String,
    /// The shipped model it is a variant of (what the bus identifies).
    pub base: String,
    /// Supply voltage the constants refer to (and the mirror supplies), V.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub nominal_voltage: Option<f64>,
    /// Output torque at stall, N·m.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub stall_torque: Option<f64>,
    /// Current at stall, A.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub stall_current: Option<f64>,
    /// Output speed without load, rpm.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub no_load_speed: Option<f64>,
}

/// A serial servo variant of the robot's own, on its base's family.
#[derive(Debug, Clone, PartialEq)]
pub enum ServoVariant {
    /// A Dynamixel variant.
    Dynamixel(dxl::models::DxlModel),
    /// A Feetech (STS/SCS) variant.
    Feetech(feetech::models::FeetechModel),
}

impl ServoModelConfig {
    /// The variant, on a shipped Dynamixel or Feetech base, or the field that is wrong and why.
    pub fn model(&self) -> Result<ServoVariant, (&'static str, String)> {
        let figure = |field: &'static str, v: f64| {
            if v.is_finite() && v > 0.0 && v <= 1e4 {
                Ok(v)
            } else {
                Err((field, format!("{} must be a positive number", crate::num(v))))
            }
        };
        let given = [
            ("nominal_voltage", self.nominal_voltage),
            ("stall_torque", self.stall_torque),
            ("stall_current", self.stall_current),
            ("no_load_speed", self.no_load_speed),
        ];
        if let Some(base) = dxl::models::find(&self.base) {
            let mut m = base.clone();
            m.name = self.name.clone();
            let slots = [
                &mut m.nominal_voltage,
                &mut m.stall_torque,
                &mut m.stall_current,
                &mut m.no_load_speed,
            ];
            for ((field, v), slot) in given.into_iter().zip(slots) {
                if let Some(v) = v {
                    *slot = figure(field, v)?;
                }
            }
            return Ok(ServoVariant::Dynamixel(m));
        }
        if let Some(base) = feetech::models::find(&self.base) {
            let mut m = base.clone();
            m.name = self.name.clone();
            // The table keeps no-load speed in rad/s; robot.toml gives rpm for every family.
            let rpm = std::f64::consts::TAU / 60.0;
            let slots = [
                (&mut m.nominal_voltage, 1.0),
                (&mut m.stall_torque, 1.0),
                (&mut m.stall_current, 1.0),
                (&mut m.no_load_speed, rpm),
            ];
            for ((field, v), (slot, unit)) in given.into_iter().zip(slots) {
                if let Some(v) = v {
                    *slot = figure(field, v)? * unit;
                }
            }
            return Ok(ServoVariant::Feetech(m));
        }
        let known: Vec<&str> = dxl::models::builtin()
            .iter()
            .map(|m| m.name.as_str())
            .chain(feetech::models::builtin().iter().map(|m| m.name.as_str()))
            .collect();
        Err((
            "base",
            format!(
                "{:?} is not a shipped servo model (known: {})",
                self.base,
                known.join(", ")
            ),
        ))
    }
}

/// A foot switch on a GPIO line (the Linux character-device interface).
#[derive(Debug, Clone, PartialEq, serde::Deserialize, schemars::JsonSchema, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct ContactSwitch {
    /// The foot (one of `feet`).
    pub foot: String,
    /// The GPIO chip's character device, e.g. `/dev/gpiochip0`.
    pub chip: PathBuf,
    /// The line's offset on the chip (0–1023).
    pub line: u32,
    /// The switch pulls the line low when the foot is down.
    #[serde(default)]
    pub active_low: bool,
    /// The model's `touch` sensor that stands for this switch in the mirror (default: the
    /// foot's contacts with anything, as the simulation has them).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sensor: Option<String>,
    /// Force (N) on the touch sensor above which the switch reads closed (0–1000, default 2).
    #[serde(default = "default_touch_threshold")]
    pub threshold_n: f64,
}

fn default_touch_threshold() -> f64 {
    2.0
}

/// A human body the retargeting map knows (BVH skeletons and VR trackers are mapped onto these).
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Deserialize, schemars::JsonSchema, serde::Serialize,
)]
#[serde(rename_all = "snake_case")]
pub enum HumanBody {
    /// The pelvis (the root pair).
    Root,
    /// Skull base.
    Head,
    /// Left wrist.
    LeftHand,
    /// Right wrist.
    RightHand,
    /// Left elbow.
    LeftElbow,
    /// Right elbow.
    RightElbow,
    /// Left ankle.
    LeftFoot,
    /// Right ankle.
    RightFoot,
    /// Left knee.
    LeftKnee,
    /// Right knee.
    RightKnee,
    /// Upper chest (the torso above the waist).
    Chest,
    /// Left hip joint (the thigh).
    LeftHip,
    /// Right hip joint (the thigh).
    RightHip,
    /// Left shoulder joint (the upper arm).
    LeftShoulder,
    /// Right shoulder joint (the upper arm).
    RightShoulder,
}

/// The point of the model a keypoint is: a body's or site's origin, or a point offset from it in
/// its frame (m, each within ±0.5).
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize, schemars::JsonSchema)]
#[serde(untagged)]
pub enum KeypointFrame {
    /// The frame's origin.
    Origin(String),
    /// A point in the frame.
    Offset {
        /// Body or site.
        frame: String,
        /// Where in it, m.
        #[serde(default)]
        offset: [f64; 3],
    },
}

impl KeypointFrame {
    /// The body or site.
    pub fn frame(&self) -> &str {
        match self {
            Self::Origin(f) | Self::Offset { frame: f, .. } => f,
        }
    }

    /// The point in the frame, m.
    pub fn offset(&self) -> [f64; 3] {
        match self {
            Self::Origin(_) => [0.0; 3],
            Self::Offset { offset, .. } => *offset,
        }
    }
}

/// One body pair of the retargeting map.
#[derive(Debug, Clone, PartialEq, serde::Deserialize, schemars::JsonSchema, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct BodyPair {
    /// The human body.
    pub human: HumanBody,
    /// The robot frame: a body or a site of the MJCF.
    pub frame: String,
    /// Weight of its position in inverse kinematics (0: ignored).
    #[serde(default)]
    pub position_weight: f64,
    /// Weight of its orientation in inverse kinematics (0: ignored).
    #[serde(default)]
    pub orientation_weight: f64,
    /// Position tuning in nominal coordinates, m (|p_pos| ≤ 0.5).
    #[serde(default)]
    pub p_pos: [f64; 3],
    /// Orientation tuning, rotation vector, rad (|p_ori| ≤ 0.5).
    #[serde(default)]
    pub p_ori: [f64; 3],
    /// Which part of the orientation error counts, for frames with fewer rotational DoF than
    /// the human body: all of it, only the swing (twist about `twist_axis` ignored), or only the
    /// twist.
    #[serde(default)]
    pub orientation_compare: OrientationCompare,
    /// The twist axis in the robot frame's own coordinates.
    #[serde(default = "x_axis")]
    pub twist_axis: [f64; 3],
    /// This body's scale about the root, as a factor of the map's scale (root heights): limbs
    /// of other proportions than the human's (GMR scales arms and legs apart), 0.3–3.
    #[serde(default = "unit_scale")]
    pub scale: f64,
    /// Its weights in the first, posture stage of inverse kinematics (GMR's first table: mostly
    /// orientations, the feet's positions), solved before the weights above refine it. Absent
    /// on every pair: one stage.
    #[serde(default)]
    pub posture: Option<StageWeights>,
}

fn unit_scale() -> f64 {
    1.0
}

/// A pair's weights in one stage of inverse kinematics.
#[derive(Debug, Clone, Copy, PartialEq, serde::Deserialize, schemars::JsonSchema, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct StageWeights {
    /// Weight of the position (0: ignored).
    #[serde(default)]
    pub position_weight: f64,
    /// Weight of the orientation (0: ignored).
    #[serde(default)]
    pub orientation_weight: f64,
}

fn x_axis() -> [f64; 3] {
    [1.0, 0.0, 0.0]
}

/// Which part of an orientation error inverse kinematics compares (swing–twist decomposition).
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, Default, serde::Deserialize, schemars::JsonSchema, serde::Serialize,
)]
#[serde(rename_all = "snake_case")]
pub enum OrientationCompare {
    /// The whole rotation.
    #[default]
    Full,
    /// Everything but the twist about the axis.
    Swing,
    /// Only the twist about the axis.
    Twist,
}

/// How human motion maps onto the robot.
#[derive(Debug, Clone, PartialEq, serde::Deserialize, schemars::JsonSchema, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct RetargetConfig {
    /// The robot's pose matching a human T-pose, by joint name (joints not named: 0 rad).
    #[serde(default)]
    pub tpose: std::collections::BTreeMap<String, f64>,
    /// Body pairs; exactly one has `human = "root"`.
    pub pairs: Vec<BodyPair>,
}

/// Gains from outside robot.toml (a policy manifest) that the joint's actuator cannot hold.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{joint}: {message}")]
pub struct GainsOutOfRange {
    /// The joint.
    pub joint: String,
    /// The actuator's ranges against the gains.
    pub message: String,
}

/// A robot description that failed to load: the file, the place in it, and what is wrong.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{file}: {place}: {message}")]
pub struct RobotError {
    /// The file.
    pub file: PathBuf,
    /// Field path, e.g. `joints[3] (left_knee).model`.
    pub place: String,
    /// What is wrong, with the value.
    pub message: String,
}

/// A loaded, checked robot: its description, where it came from, and its MJCF summary.
#[derive(Debug, Clone, PartialEq)]
pub struct Robot {
    /// The description.
    pub config: RobotConfig,
    /// The robot.toml path.
    pub path: PathBuf,
    /// The MJCF path (resolved).
    pub mjcf_path: PathBuf,
    /// What the MJCF declares.
    pub mjcf: MjcfSummary,
    /// The robot's own MIT-mode models (robot.toml's `mit_models`), checked.
    pub mit_models: Vec<mit::models::MotorModel>,
    /// The robot's own servo variants (robot.toml's `servo_models`), checked, with the shipped
    /// model each speaks as.
    pub servo_models: Vec<(dxl::models::DxlModel, String)>,
    /// The robot's own Feetech servo variants (`[[servo_models]]` on a Feetech base).
    pub feetech_models: Vec<feetech::models::FeetechModel>,
    /// The calibration.toml merged over the description, when there was one.
    pub calibration: Option<PathBuf>,
    /// The model [`Robot::model`] compiled, once per loaded robot (clones share it).
    compiled: CompiledModel,
}

/// A robot's compiled model, shared by its clones: compiling an MJCF takes a large share of a
/// run's start, and every part of a run (mirror, kinematics, checks) needs the same model. The
/// description is not edited after loading (edits make a new robot: [`Robot::from_str`]).
#[derive(Clone, Default)]
struct CompiledModel(Arc<OnceLock<Arc<MjModel>>>);

impl std::fmt::Debug for CompiledModel {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(if self.0.get().is_some() {
            "compiled"
        } else {
            "not compiled yet"
        })
    }
}

/// Two robots are the same by their description; whether one compiled its model yet is not part
/// of what it is.
impl PartialEq for CompiledModel {
    fn eq(&self, _: &Self) -> bool {
        true
    }
}

impl Robot {
    /// The policy robot.toml names for runs that give none, resolved beside it.
    pub fn default_policy(&self) -> Option<PathBuf> {
        self.config
            .policy
            .as_ref()
            .map(|p| self.path.parent().unwrap_or(Path::new(".")).join(p))
    }

    /// The robot's model as its trainer simulated it, editable before compiling: the MJCF with
    /// robot.toml's `[[joint_dynamics]]` and `[sim]` applied (the file itself untouched).
    pub fn spec(&self) -> Result<mujoco_rs::prelude::MjSpec, mjcf::MujocoError> {
        let mut spec = mjcf::load_spec(&self.mjcf_path)?;
        mjcf::apply_trainer_settings(&mut spec, &self.config)?;
        Ok(spec)
    }

    /// [`Self::spec`], compiled: the model every simulation and check of this robot uses, as a
    /// copy of its own (a simulation changes its model's damping). See [`Self::shared_model`].
    pub fn model(&self) -> Result<MjModel, mjcf::MujocoError> {
        Ok(MjModel::clone(&*self.shared_model()?))
    }

    /// [`Self::spec`], compiled once per loaded robot and shared by every reader that does not
    /// change it (kinematics, inverse kinematics, views: robot.toml's settings change no geometry).
    pub fn shared_model(&self) -> Result<Arc<MjModel>, mjcf::MujocoError> {
        if let Some(model) = self.compiled.0.get() {
            return Ok(model.clone());
        }
        let model = if self.config.joint_dynamics.is_empty() && self.config.sim.is_default() {
            mjcf::load_model(&self.mjcf_path)?
        } else {
            self.spec()?.compile().map_err(|e| mjcf::MujocoError::Model {
                path: self.mjcf_path.display().to_string(),
                reason: format!("with robot.toml's joint dynamics and [sim] applied: {e}"),
            })?
        };
        Ok(self.compiled.0.get_or_init(|| Arc::new(model)).clone())
    }

    /// Loads and checks `path` (a robot.toml).
    pub fn load(path: &Path) -> Result<Self, RobotError> {
        let err = |place: &str, message: String| RobotError {
            file: path.to_path_buf(),
            place: place.to_owned(),
            message,
        };
        let text = crate::read_text(path).map_err(|m| err("file", m.to_string()))?;
        Self::from_str(path, &text)
    }

    /// Checks a description given as text, as if read from `path`.
    pub fn from_str(path: &Path, text: &str) -> Result<Self, RobotError> {
        let err = |place: &str, message: String| RobotError {
            file: path.to_path_buf(),
            place: place.to_owned(),
            message,
        };
        // A model given where its description belongs: say what is expected, not a TOML error.
        if text.trim_start().starts_with('<') {
            return Err(err(
                "file",
                "is XML (an MJCF model?); a robot is described by a robot.toml that names its model \
                 (`mjcf = \"scene.xml\"`), its buses and its joints: see robots/*/robot.toml"
                    .into(),
            ));
        }
        let mut config: RobotConfig = toml::from_str(text).map_err(|e| {
            let span = e
                .span()
                .map(|s| line_of(text, s.start))
                .map_or(String::new(), |l| format!("line {l}"));
            err(&span, e.message().to_owned())
        })?;
        // What calibration measured overrides the description.
        let cal_path = crate::calibration::path_for(path);
        let calibration = crate::calibration::Calibration::read(&cal_path)
            .map_err(|e| err("calibration", e.to_string()))?;
        let merged = calibration.is_some().then(|| cal_path.clone());
        if let Some(cal) = calibration {
            for (name, c) in &cal.joints {
                let j = config
                    .joints
                    .iter_mut()
                    .find(|j| &j.name == name)
                    .ok_or_else(|| RobotError {
                        file: cal_path.clone(),
                        place: format!("joints.{name}"),
                        message: "not a joint of this robot".into(),
                    })?;
                j.zero_offset = c.zero_offset;
                j.direction = c.direction;
                j.homing_offset_ticks = c.homing_offset_ticks;
            }
            if let Some(imu) = cal.imu {
                check_imu_mounting("imu", imu.mounting_rpy_deg, imu.gyro_bias, imu.accel_bias).map_err(
                    |(place, message)| RobotError {
                        file: cal_path.clone(),
                        place,
                        message,
                    },
                )?;
                config.imu.mounting_rpy_deg = imu.mounting_rpy_deg;
                config.imu.gyro_bias = imu.gyro_bias;
                config.imu.accel_bias = imu.accel_bias;
            }
        }
        let mjcf_path = path.parent().unwrap_or(Path::new(".")).join(&config.mjcf);
        // The model is compiled once: the file as it is where robot.toml changes none of its
        // settings, else the file with them applied (what every simulation of it uses; they change
        // no geometry, so it summarises the same). Where that fails, the file alone is compiled to
        // say whether the file or robot.toml's settings are at fault.
        let compiled = CompiledModel::default();
        let applied = (!(config.joint_dynamics.is_empty() && config.sim.is_default()))
            .then(|| {
                let mut spec = mjcf::load_spec(&mjcf_path).ok()?;
                mjcf::apply_trainer_settings(&mut spec, &config).ok()?;
                spec.compile().ok()
            })
            .flatten();
        let mjcf = match applied {
            Some(model) => {
                let summary = mjcf::summarize_model(&model);
                let _ = compiled.0.set(Arc::new(model));
                summary
            }
            None => {
                let raw = mjcf::load_model(&mjcf_path).map_err(|e| {
                    err(
                        "mjcf",
                        crate::FileError::new(&mjcf_path, mjcf::compile_message(e)).to_string(),
                    )
                })?;
                let summary = mjcf::summarize_model(&raw);
                if config.joint_dynamics.is_empty() && config.sim.is_default() {
                    let _ = compiled.0.set(Arc::new(raw));
                }
                summary
            }
        };
        let mut mit_models = Vec::with_capacity(config.mit_models.len());
        for (i, m) in config.mit_models.iter().enumerate() {
            let at = |field: &str| format!("mit_models[{i}] ({}).{field}", m.name);
            if m.name.is_empty() || config.mit_models[..i].iter().any(|o| o.name == m.name) {
                return Err(err(
                    &at("name"),
                    format!("{:?} is empty or defined twice", m.name),
                ));
            }
            mit_models.push(m.model().map_err(|(field, message)| err(&at(field), message))?);
        }
        let mut servo_models = Vec::with_capacity(config.servo_models.len());
        let mut feetech_models = Vec::new();
        for (i, m) in config.servo_models.iter().enumerate() {
            let at = |field: &str| format!("servo_models[{i}] ({}).{field}", m.name);
            if m.name.is_empty() || config.servo_models[..i].iter().any(|o| o.name == m.name) {
                return Err(err(
                    &at("name"),
                    format!("{:?} is empty or defined twice", m.name),
                ));
            }
            match m.model().map_err(|(field, message)| err(&at(field), message))? {
                ServoVariant::Dynamixel(model) => servo_models.push((model, m.base.clone())),
                ServoVariant::Feetech(model) => feetech_models.push(model),
            }
        }
        let robot = Self {
            config,
            path: path.to_path_buf(),
            mjcf_path,
            mjcf,
            mit_models,
            servo_models,
            feetech_models,
            calibration: merged,
            compiled,
        };
        robot.check().map_err(|(place, message)| err(&place, message))?;
        Ok(robot)
    }

    /// The MJCF range of joint `joint` (robot order), rad: where its mechanical stops are.
    pub fn mjcf_range(&self, joint: usize) -> Option<[f64; 2]> {
        let j = self.config.joints.get(joint)?;
        let (lo, hi) = self.mjcf.joints.get(&j.mjcf_joint)?.range?;
        Some([lo, hi])
    }

    /// The model's sensors the mirror's IMU reads (checked at load).
    pub fn imu_sensors(&self) -> ImuSensorNames {
        self.resolve_imu_sensors().unwrap_or_default()
    }

    /// robot.toml's IMU sensor names checked against the model (the kind, and the IMU's site),
    /// or the model's own sensors of each kind on the IMU site.
    fn resolve_imu_sensors(&self) -> Result<ImuSensorNames, (String, String)> {
        let imu = &self.config.imu;
        let m = &self.mjcf;
        let named = [&imu.gyro, &imu.accelerometer, &imu.orientation];
        let mut out: ImuSensorNames = Default::default();
        for ((field, kind), (name, slot)) in IMU_SENSOR_KINDS.iter().zip(named.into_iter().zip(&mut out)) {
            let on_site = |s: &&mjcf::MjcfSensor| s.kind == *kind && s.object.as_deref() == Some(&imu.site);
            *slot = match name {
                None => m.sensors.iter().find(on_site).map(|s| s.name.clone()),
                Some(name) => {
                    let Some(sensor) = m.sensor(name) else {
                        let of_kind: Vec<&str> = m
                            .sensors
                            .iter()
                            .filter(|s| s.kind == *kind)
                            .map(|s| s.name.as_str())
                            .collect();
                        return Err((
                            format!("imu.{field}"),
                            format!(
                                "{name:?} is not a sensor of the MJCF (its {kind} sensors: {})",
                                if of_kind.is_empty() {
                                    "none".into()
                                } else {
                                    of_kind.join(", ")
                                }
                            ),
                        ));
                    };
                    if sensor.kind != *kind {
                        return Err((
                            format!("imu.{field}"),
                            format!("{name:?} is a {} sensor, not a {kind}", sensor.kind),
                        ));
                    }
                    if !on_site(&sensor) {
                        return Err((
                            format!("imu.{field}"),
                            format!(
                                "{name:?} sits on {:?}, not on the IMU's site {:?}",
                                sensor.object.as_deref().unwrap_or("?"),
                                imu.site
                            ),
                        ));
                    }
                    Some(name.clone())
                }
            };
        }
        Ok(out)
    }

    /// The keyframe the mirror starts in, if robot.toml names one (checked at load).
    pub fn start_keyframe(&self) -> Option<&mjcf::MjcfKeyframe> {
        self.mjcf.keyframe(self.config.start_keyframe.as_deref()?)
    }

    /// The joint angles (robot order) keyframe `name` holds, when the model has it.
    pub fn keyframe_joints(&self, name: &str) -> Option<Vec<f64>> {
        let key = self.mjcf.keyframe(name)?;
        self.config
            .joints
            .iter()
            .map(|j| {
                self.mjcf
                    .joints
                    .get(&j.mjcf_joint)
                    .and_then(|mj| key.qpos.get(mj.qpos))
                    .copied()
            })
            .collect()
    }

    /// The keyframes robot.toml names exist, and put every joint inside its position limits.
    fn check_keyframes(&self) -> Result<(), (String, String)> {
        for (field, name) in [
            ("start_keyframe", &self.config.start_keyframe),
            ("sit_keyframe", &self.config.sit_keyframe),
        ] {
            if let Some(name) = name {
                self.check_keyframe(field, name)?;
            }
        }
        Ok(())
    }

    fn check_keyframe(&self, field: &str, name: &str) -> Result<(), (String, String)> {
        let field = || field.to_owned();
        let Some(key) = self.mjcf.keyframe(name) else {
            let names: Vec<&str> = self.mjcf.keyframes.iter().map(|k| k.name.as_str()).collect();
            return Err((
                field(),
                format!(
                    "{name:?} is not a keyframe of the MJCF (its keyframes: {})",
                    if names.is_empty() {
                        "none".into()
                    } else {
                        names.join(", ")
                    }
                ),
            ));
        };
        for j in &self.config.joints {
            let Some(q) = self
                .mjcf
                .joints
                .get(&j.mjcf_joint)
                .and_then(|mj| key.qpos.get(mj.qpos))
            else {
                continue;
            };
            let [lo, hi] = j.position_limits;
            if !(lo..=hi).contains(q) {
                return Err((
                    field(),
                    format!(
                        "{name:?} puts joint {} at {q:.4} rad, outside its position_limits [{lo}, {hi}]",
                        j.name
                    ),
                ));
            }
        }
        Ok(())
    }

    /// The smallest step joint `j`'s bus reports of its position (rad) and velocity (rad/s), at
    /// the joint: an MIT reply's 16- and 12-bit fields over the model's ranges, a Dynamixel's
    /// encoder tick and velocity unit, through the gear. `None` for a joint the robot lacks.
    pub fn joint_resolution(&self, j: usize) -> Option<[f64; 2]> {
        let joint = self.config.joints.get(j)?;
        let (position, velocity) = match self.bus(&joint.bus)?.kind {
            BusKind::MitCan => {
                let m = self.mit_model(&joint.model)?;
                (2.0 * m.p_max / 65535.0, 2.0 * m.v_max / 4095.0)
            }
            BusKind::Dynamixel => (
                dxl::models::rad_per_tick(),
                dxl::models::rad_s_per_velocity_unit(),
            ),
            // Position in ticks, speed in ticks per second.
            BusKind::Feetech => (feetech::table::rad_per_tick(), feetech::table::rad_per_tick()),
            // float32 fields: an ulp at the largest angles and speeds a joint reaches (±8).
            BusKind::UnitreeDds => (8.0 * f64::from(f32::EPSILON), 8.0 * f64::from(f32::EPSILON)),
            BusKind::ImuSerial => return None,
        };
        Some([position / joint.gear, velocity / joint.gear])
    }

    /// The serial servo model called `name`: the robot's own variant, else the shipped table's.
    pub fn dxl_model(&self, name: &str) -> Option<&dxl::models::DxlModel> {
        self.servo_models
            .iter()
            .find(|(m, _)| m.name == name)
            .map(|(m, _)| m)
            .or_else(|| dxl::models::find(name))
    }

    /// The shipped servo model `name` speaks as on the bus (itself, or a variant's base).
    pub fn dxl_protocol_model<'a>(&'a self, name: &'a str) -> &'a str {
        self.servo_models
            .iter()
            .find(|(m, _)| m.name == name)
            .map_or(name, |(_, base)| base.as_str())
    }

    /// The Feetech servo model called `name`: the robot's own variant, else the shipped table's.
    pub fn feetech_model(&self, name: &str) -> Option<&feetech::models::FeetechModel> {
        self.feetech_models
            .iter()
            .find(|m| m.name == name)
            .or_else(|| feetech::models::find(name))
    }

    /// The MIT-mode motor model called `name`: the robot's own, else the shipped table's.
    pub fn mit_model(&self, name: &str) -> Option<&mit::models::MotorModel> {
        self.mit_models
            .iter()
            .find(|m| m.name == name)
            .or_else(|| mit::models::find(name))
    }

    /// Whether `kp`/`kd` (joint side) fit `j`'s actuator: the error names the actuator's ranges.
    /// For gains that come from elsewhere (a policy manifest) than robot.toml.
    pub fn check_gains(&self, j: &JointConfig, kp: f64, kd: f64) -> Result<(), GainsOutOfRange> {
        let Some(bus) = self.bus(&j.bus) else {
            return Ok(());
        };
        let probe = JointConfig { kp, kd, ..j.clone() };
        match check_actuator(
            &probe,
            bus.kind,
            &self.mit_models,
            &self.servo_models,
            &self.feetech_models,
        ) {
            Err(("kp", message)) => Err(GainsOutOfRange {
                joint: j.name.clone(),
                message,
            }),
            _ => Ok(()),
        }
    }

    /// The bus called `name`.
    pub fn bus(&self, name: &str) -> Option<&BusConfig> {
        self.config.buses.iter().find(|b| b.name == name)
    }

    /// Joints on bus `name`, with their policy index.
    pub fn joints_on<'a>(&'a self, name: &'a str) -> impl Iterator<Item = (usize, &'a JointConfig)> + 'a {
        self.config
            .joints
            .iter()
            .enumerate()
            .filter(move |(_, j)| j.bus == name)
    }

    fn check(&self) -> Result<(), (String, String)> {
        self.check_body()?;
        self.check_keyframes()?;
        self.check_bus_timing()?;
        self.check_retarget()?;
        self.check_keypoints()
    }

    fn check_keypoints(&self) -> Result<(), (String, String)> {
        for (name, k) in &self.config.keypoints {
            let at = format!("keypoints.{name}");
            if name.is_empty() || name.contains(['/', ',']) {
                return Err((at, "a keypoint name is not empty and has no '/' or ','".into()));
            }
            let frame = k.frame();
            if !self.mjcf.bodies.iter().any(|b| b == frame) && !self.mjcf.sites.iter().any(|s| s == frame) {
                return Err((at, format!("{frame:?} is neither a body nor a site of the model")));
            }
            if k.offset().iter().any(|v| !v.is_finite() || v.abs() > 0.5) {
                return Err((
                    format!("{at}.offset"),
                    format!("{:?}: each within ±0.5 m", k.offset()),
                ));
            }
        }
        Ok(())
    }

    /// Worst-case wire time of one cycle of bus `b` with the joints robot.toml puts on it (zero for
    /// the IMU stream, which the host only reads).
    pub fn bus_wire_time(&self, b: &BusConfig) -> std::time::Duration {
        let devices = self.joints_on(&b.name).count();
        match b.kind {
            BusKind::MitCan => {
                let robstride = self
                    .joints_on(&b.name)
                    .filter(|(_, j)| {
                        self.mit_model(&j.model)
                            .is_some_and(|m| m.family == mit::models::MotorFamily::Robstride)
                    })
                    .count();
                mit::driver::cycle_wire_time(devices - robstride, robstride, b.rate)
            }
            // The driver programs a Return Delay Time of 0.
            BusKind::Dynamixel if b.fast_reads => {
                dxl::driver::fast_cycle_wire_time(devices, b.rate, std::time::Duration::ZERO)
            }
            BusKind::Dynamixel => dxl::driver::cycle_wire_time(devices, b.rate, std::time::Duration::ZERO),
            BusKind::Feetech => feetech::driver::cycle_wire_time(devices, b.rate),
            // One command and one state a cycle, whatever the motors.
            BusKind::UnitreeDds => {
                let bits = 8
                    * (firmware_bridge::unitree::hg::LowCmd::CDR_LEN as u64
                        + firmware_bridge::unitree::hg::LowState::CDR_LEN as u64
                        + 2 * DDS_FRAMING_BYTES);
                std::time::Duration::from_nanos(bits * 1_000_000_000 / u64::from(b.rate.max(1)))
            }
            BusKind::ImuSerial => std::time::Duration::ZERO,
        }
    }

    /// How bus `name` is scheduled (robot.toml's values or their defaults); `None` for a bus the
    /// robot does not have. Valid for a loaded robot (checked at load).
    pub fn bus_timing(&self, name: &str) -> Option<BusTiming> {
        let b = self.bus(name)?;
        self.resolve_timing(b).ok()
    }

    /// Resolves `b`'s timing, or says what robot.toml field is wrong.
    fn resolve_timing(&self, b: &BusConfig) -> Result<BusTiming, (&'static str, String)> {
        let wire = self.bus_wire_time(b);
        let adapter_latency = match b.kind {
            BusKind::Dynamixel | BusKind::Feetech => SERIAL_ADAPTER_LATENCY,
            BusKind::MitCan | BusKind::ImuSerial | BusKind::UnitreeDds => std::time::Duration::ZERO,
        };
        let cycle = (wire + adapter_latency).as_secs_f64();
        let policy = self.config.control_rate_hz;
        let fits = |rate: f64| cycle <= DEFAULT_BUS_LOAD / rate;
        let rate_hz = match b.rate_hz {
            Some(r) => {
                if !(r.is_finite() && (policy..=MAX_BUS_RATE_HZ).contains(&r)) {
                    return Err((
                        "rate_hz",
                        format!(
                            "{} Hz is outside [{}, {}] (the policy's control_rate_hz to the fastest bus rate)",
                            crate::num(r),
                            crate::num(policy),
                            crate::num(MAX_BUS_RATE_HZ)
                        ),
                    ));
                }
                if cycle > 1.0 / r {
                    return Err((
                        "rate_hz",
                        format!(
                            "{} Hz leaves {:.3} ms per cycle, but one cycle takes {:.3} ms of wire time ({} devices at {} bit/s){}",
                            crate::num(r),
                            1e3 / r,
                            wire.as_secs_f64() * 1e3,
                            self.joints_on(&b.name).count(),
                            b.rate,
                            latency_note(adapter_latency)
                        ),
                    ));
                }
                r
            }
            None if b.kind == BusKind::ImuSerial => DEFAULT_BUS_RATES_HZ[0].max(policy),
            None => DEFAULT_BUS_RATES_HZ
                .iter()
                .copied()
                .filter(|&r| r >= policy)
                .find(|&r| fits(r))
                // A slow line still runs at the policy's rate if a cycle fits its period at all.
                .or_else(|| (cycle <= 1.0 / policy).then_some(policy))
                .ok_or_else(|| {
                    (
                        "rate",
                        format!(
                            "one cycle takes {:.3} ms of wire time ({} devices at {} bit/s){}: more than the policy's {:.3} ms period; use a faster line or split the bus",
                            wire.as_secs_f64() * 1e3,
                            self.joints_on(&b.name).count(),
                            b.rate,
                            latency_note(adapter_latency),
                            1e3 / policy
                        ),
                    )
                })?,
        };
        let period = std::time::Duration::from_nanos((1e9 / rate_hz).round() as u64);
        if b.kind == BusKind::Feetech && b.command_timeout_ms.is_some() {
            return Err((
                "command_timeout_ms",
                "Feetech STS servos have no command watchdog to set: leave it out".into(),
            ));
        }
        let command_timeout = match b.command_timeout_ms {
            None => default_command_timeout(b.kind, period),
            Some(ms) => {
                let least = period.as_secs_f64() * 2e3;
                if !(ms.is_finite() && ms >= least && ms <= 10_000.0) {
                    return Err((
                        "command_timeout_ms",
                        format!(
                            "{} ms is outside [{least:.3}, 10000]: at least two bus periods, or one late cycle drops torque",
                            crate::num(ms)
                        ),
                    ));
                }
                if b.kind == BusKind::Dynamixel && (!(20.0..=2540.0).contains(&ms) || ms % 20.0 != 0.0) {
                    return Err((
                        "command_timeout_ms",
                        format!(
                            "{} ms: the Bus Watchdog counts 20 ms steps from 20 to 2540 ms",
                            crate::num(ms)
                        ),
                    ));
                }
                // Finite and within [0, 10 s]: checked above.
                std::time::Duration::from_micros((ms * 1e3).round() as u64)
            }
        };
        if b.kind == BusKind::ImuSerial
            && (b.interpolation != Interpolation::Hold || b.command_timeout_ms.is_some())
        {
            return Err((
                "interpolation",
                "an IMU line carries no commands: interpolation and command_timeout_ms do not apply".into(),
            ));
        }
        Ok(BusTiming {
            rate_hz,
            period,
            wire_time: wire,
            adapter_latency,
            interpolation: b.interpolation,
            command_timeout,
        })
    }

    fn check_bus_timing(&self) -> Result<(), (String, String)> {
        for (i, b) in self.config.buses.iter().enumerate() {
            self.resolve_timing(b)
                .map_err(|(field, message)| (format!("buses[{i}] ({}).{field}", b.name), message))?;
        }
        Ok(())
    }

    fn check_retarget(&self) -> Result<(), (String, String)> {
        let Some(r) = &self.config.retarget else {
            return Ok(());
        };
        for (name, &q) in &r.tpose {
            let j = self
                .config
                .joints
                .iter()
                .find(|j| &j.name == name)
                .ok_or_else(|| {
                    (
                        format!("retarget.tpose.{name}"),
                        "not a joint of this robot".to_owned(),
                    )
                })?;
            let [lo, hi] = j.position_limits;
            if !(lo..=hi).contains(&q) {
                return Err((
                    format!("retarget.tpose.{name}"),
                    format!("{q} rad is outside the joint's limits [{lo}, {hi}]"),
                ));
            }
        }
        let mut seen = BTreeSet::new();
        for (i, p) in r.pairs.iter().enumerate() {
            let at = format!("retarget.pairs[{i}]");
            if !seen.insert(format!("{:?}", p.human)) {
                return Err((format!("{at}.human"), format!("{:?} is paired twice", p.human)));
            }
            if !self.mjcf.bodies.contains(&p.frame) && !self.mjcf.sites.contains(&p.frame) {
                return Err((
                    format!("{at}.frame"),
                    format!("{:?} is neither a body nor a site of the MJCF", p.frame),
                ));
            }
            let weights = [p.position_weight, p.orientation_weight];
            if weights.iter().any(|w| !(w.is_finite() && *w >= 0.0)) || weights == [0.0, 0.0] {
                return Err((at.clone(), "weights must be ≥ 0 and not both 0".to_owned()));
            }
            if let Some(stage) = &p.posture {
                let w = [stage.position_weight, stage.orientation_weight];
                if w.iter().any(|w| !(w.is_finite() && *w >= 0.0)) {
                    return Err((format!("{at}.posture"), format!("weights {w:?} must be ≥ 0")));
                }
            }
            if !(0.3..=3.0).contains(&p.scale) {
                return Err((format!("{at}.scale"), format!("{} is outside 0.3–3", p.scale)));
            }
            let norm = |v: [f64; 3]| (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
            if norm(p.twist_axis).is_nan() || norm(p.twist_axis) <= 1e-6 {
                return Err((
                    format!("{at}.twist_axis"),
                    format!("{:?} is not a direction", p.twist_axis),
                ));
            }
            if norm(p.p_pos) > 0.5 || norm(p.p_ori) > 0.5 {
                return Err((at.clone(), "|p_pos| and |p_ori| must be ≤ 0.5".to_owned()));
            }
        }
        if !r.pairs.iter().any(|p| p.human == HumanBody::Root) {
            return Err(("retarget.pairs".into(), "no pair has human = \"root\"".into()));
        }
        Ok(())
    }

    fn check_body(&self) -> Result<(), (String, String)> {
        let c = &self.config;
        let m = &self.mjcf;
        if !m.bodies.contains(&c.root_body) {
            return Err((
                "root_body".into(),
                format!("{:?} is not a body of the MJCF", c.root_body),
            ));
        }
        for (i, foot) in c.feet.iter().enumerate() {
            if !m.bodies.contains(foot) {
                return Err((
                    format!("feet[{i}]"),
                    format!("{foot:?} is not a body of the MJCF"),
                ));
            }
        }
        if c.feet.is_empty() {
            return Err((
                "feet".into(),
                "no feet: name the bodies the robot stands on".into(),
            ));
        }
        if !c.contacts.is_empty()
            && let Some(f) = c
                .feet
                .iter()
                .find(|f| !c.contacts.iter().any(|sw| sw.foot == **f))
        {
            return Err((
                "contacts".into(),
                format!("foot {f:?} has no switch: give every foot one, or none (contact is then estimated)"),
            ));
        }
        for (i, sw) in c.contacts.iter().enumerate() {
            if !c.feet.contains(&sw.foot) {
                return Err((
                    format!("contacts[{i}].foot"),
                    format!("{:?} is not one of feet ({})", sw.foot, c.feet.join(", ")),
                ));
            }
            if c.contacts[..i].iter().any(|o| o.foot == sw.foot) {
                return Err((
                    format!("contacts[{i}].foot"),
                    format!("{:?} has a switch already", sw.foot),
                ));
            }
            if let Some(name) = &sw.sensor {
                match m.sensor(name) {
                    Some(t) if t.kind == "touch" => {}
                    Some(t) => {
                        return Err((
                            format!("contacts[{i}].sensor"),
                            format!("{name:?} is a {} sensor, not a touch sensor", t.kind),
                        ));
                    }
                    None => {
                        let touch: Vec<&str> = m
                            .sensors
                            .iter()
                            .filter(|s| s.kind == "touch")
                            .map(|s| s.name.as_str())
                            .collect();
                        return Err((
                            format!("contacts[{i}].sensor"),
                            format!(
                                "{name:?} is not a sensor of the MJCF (its touch sensors: {})",
                                if touch.is_empty() {
                                    "none".into()
                                } else {
                                    touch.join(", ")
                                }
                            ),
                        ));
                    }
                }
            }
            if !(sw.threshold_n.is_finite() && (0.0..=1000.0).contains(&sw.threshold_n)) {
                return Err((
                    format!("contacts[{i}].threshold_n"),
                    format!("{} N is outside [0, 1000]", crate::num(sw.threshold_n)),
                ));
            }
            if sw.line > 1023 || sw.chip.as_os_str().is_empty() {
                return Err((
                    format!("contacts[{i}]"),
                    format!(
                        "chip {:?} line {}: a chip path and a line in [0, 1023]",
                        sw.chip, sw.line
                    ),
                ));
            }
        }
        c.start.check()?;
        c.estimator.check()?;
        c.safety.check(&c.joints)?;
        JointDynamics::check(&c.joint_dynamics, &c.joints)?;
        crate::actuators::ActuatorGroup::check(c, &c.joints)?;
        if !(1.0..=1000.0).contains(&c.control_rate_hz) {
            return Err((
                "control_rate_hz".into(),
                format!("{} Hz is outside [1, 1000]", crate::num(c.control_rate_hz)),
            ));
        }
        c.sim.check(1.0 / c.control_rate_hz)?;
        if let Some(m) = c.position_margin {
            let narrowest = c
                .joints
                .iter()
                .map(|j| (j.position_limits[1] - j.position_limits[0], &j.name))
                .min_by(|a, b| a.0.total_cmp(&b.0));
            if !(m.is_finite() && (0.0..=0.2).contains(&m)) {
                return Err((
                    "position_margin".into(),
                    format!("{} rad is outside [0, 0.2]", crate::num(m)),
                ));
            }
            if let Some((range, name)) = narrowest
                && 2.0 * m >= range
            {
                return Err((
                    "position_margin".into(),
                    format!(
                        "{} rad leaves nothing of joint {name}'s {range:.3} rad range",
                        crate::num(m)
                    ),
                ));
            }
        }
        let mut bus_names = BTreeSet::new();
        let mut devices = BTreeSet::new();
        // A part with one line speed (BNO0xx) or the WIT AHRS's list.
        let imu_baud = c.imu.protocol.fixed_baud().map(|b| [b]);
        for (i, b) in c.buses.iter().enumerate() {
            if !bus_names.insert(&b.name) {
                return Err((format!("buses[{i}].name"), format!("{:?} is used twice", b.name)));
            }
            if !devices.insert(&b.device) {
                return Err((
                    format!("buses[{i}] ({}).device", b.name),
                    format!("{:?} already carries another bus", b.device),
                ));
            }
            let rates: &[u32] = match b.kind {
                BusKind::MitCan => &CAN_BITRATES,
                BusKind::ImuSerial => imu_baud.as_ref().map_or(&WIT_BAUDS[..], |b| &b[..]),
                BusKind::Dynamixel | BusKind::UnitreeDds => &[],
                BusKind::Feetech => &feetech::table::BAUDS,
            };
            if !rates.is_empty() && !rates.contains(&b.rate) {
                return Err((
                    format!("buses[{i}] ({}).rate", b.name),
                    format!("{} is not one of {rates:?}", b.rate),
                ));
            }
            if b.kind == BusKind::Dynamixel && dxl::wire::code_of_baud(b.rate).is_none() {
                return Err((
                    format!("buses[{i}] ({}).rate", b.name),
                    format!("{} is not a Dynamixel X-series baud rate", b.rate),
                ));
            }
            if b.rate == 0 {
                return Err((format!("buses[{i}] ({}).rate", b.name), "0 is not a rate".into()));
            }
            if b.kind != BusKind::UnitreeDds && (b.domain.is_some() || b.family.is_some()) {
                let field = if b.domain.is_some() { "domain" } else { "family" };
                return Err((
                    format!("buses[{i}] ({}).{field}", b.name),
                    format!("{field} is for unitree_dds buses; this is a {:?} bus", b.kind),
                ));
            }
            if let Some(d) = b.domain
                && d > MAX_DDS_DOMAIN
            {
                return Err((
                    format!("buses[{i}] ({}).domain", b.name),
                    format!("{d} is outside [0, {MAX_DDS_DOMAIN}]"),
                ));
            }
            if b.fast_reads && b.kind != BusKind::Dynamixel {
                return Err((
                    format!("buses[{i}] ({}).fast_reads", b.name),
                    format!(
                        "fast reads are a Dynamixel instruction; this is a {:?} bus",
                        b.kind
                    ),
                ));
            }
        }
        let imu_bus = self
            .bus(&c.imu.bus)
            .ok_or_else(|| ("imu.bus".to_owned(), format!("{:?} is not a bus", c.imu.bus)))?;
        if !matches!(imu_bus.kind, BusKind::ImuSerial | BusKind::UnitreeDds) {
            return Err((
                "imu.bus".into(),
                format!(
                    "{:?} is a {:?} bus, not imu_serial (or unitree_dds, whose state carries the IMU)",
                    c.imu.bus, imu_bus.kind
                ),
            ));
        }
        if !m.sites.contains(&c.imu.site) {
            return Err((
                "imu.site".into(),
                format!("{:?} is not a site of the MJCF", c.imu.site),
            ));
        }
        self.resolve_imu_sensors()?;
        if c.imu.protocol == firmware_bridge::imu::ImuProtocol::Bno055
            && !(c.imu.rate_hz > 0.0 && c.imu.rate_hz <= firmware_bridge::imu::bno055::RATE_HZ)
        {
            return Err((
                "imu.rate_hz".into(),
                format!(
                    "{} Hz: a BNO055 fuses at {} Hz; read it at that rate or slower",
                    crate::num(c.imu.rate_hz),
                    firmware_bridge::imu::bno055::RATE_HZ
                ),
            ));
        }
        if c.imu.protocol == firmware_bridge::imu::ImuProtocol::Bno08xRvc
            && c.imu.rate_hz != firmware_bridge::imu::rvc::RATE_HZ
        {
            return Err((
                "imu.rate_hz".into(),
                format!(
                    "{} Hz: a BNO08x in UART-RVC mode streams at {} Hz",
                    crate::num(c.imu.rate_hz),
                    firmware_bridge::imu::rvc::RATE_HZ
                ),
            ));
        }
        if !(c.imu.rate_hz > 0.0 && c.imu.rate_hz <= 1000.0) {
            return Err((
                "imu.rate_hz".into(),
                format!("{} is outside (0, 1000]", c.imu.rate_hz),
            ));
        }
        check_imu_mounting("imu", c.imu.mounting_rpy_deg, c.imu.gyro_bias, c.imu.accel_bias)?;
        let mut names = BTreeSet::new();
        let mut ids = BTreeSet::new();
        let mut mjcf_joints = BTreeSet::new();
        for (i, j) in c.joints.iter().enumerate() {
            let at = |field: &str| format!("joints[{i}] ({}).{field}", j.name);
            if !names.insert(&j.name) {
                return Err((at("name"), format!("{:?} is used twice", j.name)));
            }
            let Some(mj) = m.joints.get(&j.mjcf_joint) else {
                return Err((
                    at("mjcf_joint"),
                    format!("{:?} is not a joint of the MJCF", j.mjcf_joint),
                ));
            };
            if mj.kind != mjcf::JointKind::Hinge {
                return Err((
                    at("mjcf_joint"),
                    format!("{:?} is a {} joint, not a hinge", j.mjcf_joint, mj.kind.name()),
                ));
            }
            if !mjcf_joints.insert(&j.mjcf_joint) {
                return Err((at("mjcf_joint"), format!("{:?} is driven twice", j.mjcf_joint)));
            }
            let Some(bus) = self.bus(&j.bus) else {
                return Err((at("bus"), format!("{:?} is not a bus", j.bus)));
            };
            if !ids.insert((&j.bus, j.id)) {
                return Err((at("id"), format!("{} is used twice on bus {}", j.id, j.bus)));
            }
            let ids = match bus.kind {
                // MIT-mode motor IDs fill 7 bits of the command's CAN ID; 0 is the master's.
                BusKind::MitCan => 1..=127,
                // 253 is reserved and 254 is broadcast in Dynamixel Protocol 2.0.
                BusKind::Dynamixel => 0..=252,
                // 254 is broadcast in Feetech's protocol.
                BusKind::Feetech => 0..=253,
                // The motor's index in Unitree's messages (35 slots).
                BusKind::UnitreeDds => 0..=(firmware_bridge::unitree::hg::MOTORS as u8 - 1),
                BusKind::ImuSerial => 0..=255,
            };
            if !ids.contains(&j.id) {
                return Err((
                    at("id"),
                    format!(
                        "{} is outside [{}, {}] for a {:?} bus",
                        j.id,
                        ids.start(),
                        ids.end(),
                        bus.kind
                    ),
                ));
            }
            let offset_max = if bus.kind == BusKind::Feetech {
                FEETECH_HOMING_OFFSET_MAX
            } else {
                HOMING_OFFSET_MAX
            };
            if !(-offset_max..=offset_max).contains(&j.homing_offset_ticks) {
                return Err((
                    at("homing_offset_ticks"),
                    format!(
                        "{} is outside the servo's [-{offset_max}, {offset_max}]",
                        j.homing_offset_ticks
                    ),
                ));
            }
            if j.direction.abs() != 1.0 {
                return Err((at("direction"), format!("{} (must be 1 or -1)", j.direction)));
            }
            if !(j.gear.is_finite() && j.gear > 0.0) {
                return Err((at("gear"), format!("{} is not a positive ratio", j.gear)));
            }
            let [lo, hi] = j.position_limits;
            if !(lo.is_finite() && hi.is_finite() && lo < hi) {
                return Err((at("position_limits"), format!("[{lo}, {hi}] is not an interval")));
            }
            if let Some((mlo, mhi)) = mj.range
                && (lo < mlo - 1e-9 || hi > mhi + 1e-9)
            {
                return Err((
                    at("position_limits"),
                    format!("[{lo}, {hi}] leaves the MJCF joint range [{mlo:.4}, {mhi:.4}]"),
                ));
            }
            if !(lo..=hi).contains(&j.default_position) {
                return Err((
                    at("default_position"),
                    format!("{} is outside the position limits", j.default_position),
                ));
            }
            for (field, v) in [
                ("velocity_limit", j.velocity_limit),
                ("torque_limit", j.torque_limit),
            ] {
                if !(v.is_finite() && v > 0.0) {
                    return Err((at(field), format!("{v} is not a positive limit")));
                }
            }
            for (field, v) in [("kp", j.kp), ("kd", j.kd), ("zero_offset", j.zero_offset)] {
                if !v.is_finite() || (field != "zero_offset" && v < 0.0) {
                    return Err((at(field), format!("{v} is not allowed")));
                }
            }
            check_actuator(
                j,
                bus.kind,
                &self.mit_models,
                &self.servo_models,
                &self.feetech_models,
            )
            .map_err(|(f, msg)| (at(f), msg))?;
        }
        Ok(())
    }
}

/// CAN bit rates the MIT-mode motors run at.
pub const CAN_BITRATES: [u32; 4] = [125_000, 250_000, 500_000, 1_000_000];

/// Baud rates of the WIT-protocol AHRS.
pub const WIT_BAUDS: [u32; 9] = [
    4800, 9600, 19_200, 38_400, 57_600, 115_200, 230_400, 460_800, 921_600,
];

/// Largest Homing Offset of an X-series servo, ticks (the control table's range).
pub const HOMING_OFFSET_MAX: i32 = 1_044_479;

/// Largest homing offset of a Feetech STS servo, ticks (11 bits and a sign).
pub const FEETECH_HOMING_OFFSET_MAX: i32 = 2047;

/// Joint limits must fit what the actuator can do (through the gear); `own` are the robot's own
/// MIT-mode models.
fn check_actuator(
    j: &JointConfig,
    kind: BusKind,
    own: &[mit::models::MotorModel],
    servos: &[(dxl::models::DxlModel, String)],
    feetech_own: &[feetech::models::FeetechModel],
) -> Result<(), (&'static str, String)> {
    match kind {
        BusKind::MitCan | BusKind::UnitreeDds => {
            let Some(motor) = own
                .iter()
                .find(|m| m.name == j.model)
                .or_else(|| mit::models::find(&j.model))
            else {
                let known: Vec<_> = own
                    .iter()
                    .chain(mit::models::builtin())
                    .map(|m| m.name.as_str())
                    .collect();
                return Err((
                    "model",
                    format!(
                        "{:?} is not an MIT-mode motor (known: {})",
                        j.model,
                        known.join(", ")
                    ),
                ));
            };
            let g = j.gear;
            let reach = |q: f64| (j.direction * q * g + j.zero_offset).abs() <= motor.p_max;
            if !(reach(j.position_limits[0]) && reach(j.position_limits[1])) {
                return Err((
                    "position_limits",
                    format!(
                        "{:?} need motor angles beyond ±{} rad of the {}",
                        j.position_limits, motor.p_max, motor.name
                    ),
                ));
            }
            if j.velocity_limit * g > motor.v_max {
                return Err((
                    "velocity_limit",
                    format!(
                        "{} rad/s needs {:.2} rad/s at the motor, beyond the {}'s {}",
                        j.velocity_limit,
                        j.velocity_limit * g,
                        motor.name,
                        motor.v_max
                    ),
                ));
            }
            if j.torque_limit / g > motor.t_max {
                return Err((
                    "torque_limit",
                    format!(
                        "{} N·m needs {:.2} N·m at the motor, beyond the {}'s {}",
                        j.torque_limit,
                        j.torque_limit / g,
                        motor.name,
                        motor.t_max
                    ),
                ));
            }
            if j.kp / (g * g) > motor.kp_max || j.kd / (g * g) > motor.kd_max {
                return Err((
                    "kp",
                    format!(
                        "kp {} / kd {} exceed the {}'s ranges (0–{}, 0–{}) at the motor",
                        j.kp, j.kd, motor.name, motor.kp_max, motor.kd_max
                    ),
                ));
            }
        }
        BusKind::Dynamixel => {
            let Some(servo) = servos
                .iter()
                .map(|(m, _)| m)
                .find(|m| m.name == j.model)
                .or_else(|| dxl::models::find(&j.model))
            else {
                let known: Vec<_> = servos
                    .iter()
                    .map(|(m, _)| m)
                    .chain(dxl::models::builtin())
                    .map(|m| m.name.as_str())
                    .collect();
                return Err((
                    "model",
                    format!(
                        "{:?} is not a Dynamixel servo (known: {})",
                        j.model,
                        known.join(", ")
                    ),
                ));
            };
            let no_load = servo.no_load_speed * std::f64::consts::TAU / 60.0;
            if j.velocity_limit * j.gear > no_load {
                return Err((
                    "velocity_limit",
                    format!(
                        "{} rad/s is beyond the {}'s no-load speed {no_load:.2} rad/s",
                        j.velocity_limit, servo.name
                    ),
                ));
            }
            if j.torque_limit / j.gear > servo.stall_torque {
                return Err((
                    "torque_limit",
                    format!(
                        "{} N·m is beyond the {}'s stall torque {} N·m",
                        j.torque_limit, servo.name, servo.stall_torque
                    ),
                ));
            }
        }
        BusKind::Feetech => {
            let Some(servo) = feetech_own
                .iter()
                .find(|m| m.name == j.model)
                .or_else(|| feetech::models::find(&j.model))
            else {
                let known: Vec<_> = feetech_own
                    .iter()
                    .chain(feetech::models::builtin())
                    .map(|m| m.name.as_str())
                    .collect();
                return Err((
                    "model",
                    format!(
                        "{:?} is not a Feetech servo (known: {})",
                        j.model,
                        known.join(", ")
                    ),
                ));
            };
            if j.velocity_limit * j.gear > servo.no_load_speed {
                return Err((
                    "velocity_limit",
                    format!(
                        "{} rad/s is beyond the {}'s no-load speed {:.2} rad/s",
                        j.velocity_limit, servo.name, servo.no_load_speed
                    ),
                ));
            }
            if j.torque_limit / j.gear > servo.stall_torque {
                return Err((
                    "torque_limit",
                    format!(
                        "{} N·m is beyond the {}'s stall torque {} N·m",
                        j.torque_limit, servo.name, servo.stall_torque
                    ),
                ));
            }
        }
        BusKind::ImuSerial => return Err(("bus", "joints cannot sit on an imu_serial bus".into())),
    }
    Ok(())
}

/// " plus … ms of USB adapter latency", where there is some.
fn latency_note(latency: std::time::Duration) -> String {
    if latency.is_zero() {
        String::new()
    } else {
        format!(
            " plus {:.3} ms of USB adapter latency",
            latency.as_secs_f64() * 1e3
        )
    }
}

fn line_of(text: &str, offset: usize) -> usize {
    text[..offset.min(text.len())].matches('\n').count() + 1
}

fn is_zero(v: &i32) -> bool {
    *v == 0
}

#[cfg(test)]
mod start_and_safety_tests {
    use super::*;

    fn joint(name: &str) -> JointConfig {
        JointConfig {
            name: name.into(),
            mjcf_joint: name.into(),
            bus: "can0".into(),
            id: 1,
            model: "AK80-9".into(),
            direction: 1.0,
            zero_offset: 0.0,
            homing_offset_ticks: 0,
            gear: 1.0,
            position_limits: [-1.0, 1.0],
            velocity_limit: 10.0,
            torque_limit: 10.0,
            default_position: 0.0,
            kp: 10.0,
            kd: 1.0,
        }
    }

    #[test]
    fn a_model_given_for_its_description_says_what_is_expected() {
        let e = Robot::from_str(Path::new("scene.xml"), "<mujoco model=\"g1\">\n</mujoco>\n").unwrap_err();
        assert_eq!(e.place, "file");
        assert!(e.message.contains("is XML (an MJCF model?)"), "{e}");
    }

    #[test]
    fn patterns_match_any_run_of_characters() {
        assert!(matches_pattern("*ankle*", "left_ankle_pitch_joint"));
        assert!(matches_pattern("waist_*", "waist_yaw_joint"));
        assert!(matches_pattern("*_joint", "knee_joint"));
        assert!(matches_pattern("knee", "knee"));
        assert!(!matches_pattern("knee", "left_knee"));
        assert!(!matches_pattern("*ankle*", "left_knee_joint"));
        assert!(matches_pattern("left_*_pitch*", "left_ankle_pitch_joint"));
        assert!(!matches_pattern("left_*_pitch*", "right_ankle_pitch_joint"));
    }

    #[test]
    fn each_joint_takes_the_last_rule_that_names_it_over_the_robots_defaults() {
        let joints = [joint("left_ankle_pitch"), joint("left_knee"), joint("waist_yaw")];
        let safety: SafetyConfig = toml::from_str(
            "tracking_s = 0.8\n\
             [[tracking]]\njoints = [\"*ankle*\", \"waist_*\"]\nerror = 0.8\nseconds = 1.0\n\
             [[tracking]]\njoints = [\"waist_yaw\"]\nerror = 1.2\nseconds = 2.0\n",
        )
        .unwrap();
        safety.check(&joints).unwrap();
        assert_eq!(
            safety.tracking_limits(&joints, 0.5, 0.5),
            [(0.8, 1.0), (0.5, 0.8), (1.2, 2.0)]
        );
    }

    #[test]
    fn out_of_range_starts_and_thresholds_are_named() {
        let start: StartConfig = toml::from_str("mode = \"harness\"\n[harness]\nlift_m = 0.5\n").unwrap();
        assert_eq!(start.check().unwrap_err().0, "start.harness.lift_m");
        let start: StartConfig = toml::from_str("pd_gain = 1.5\n").unwrap();
        assert_eq!(start.check().unwrap_err().0, "start.pd_gain");
        assert!(toml::from_str::<StartConfig>("mode = \"crane\"\n").is_err());
        let joints = [joint("knee")];
        for (text, field) in [
            ("tilt = 2.0", "safety.tilt"),
            ("tracking_error = 0.0", "safety.tracking_error"),
            (
                "[[tracking]]\njoints = [\"hip*\"]\nerror = 1.0\nseconds = 1.0",
                "safety.tracking[0].joints",
            ),
            (
                "[[tracking]]\njoints = [\"knee\"]\nerror = 1.0\nseconds = 20.0",
                "safety.tracking[0].seconds",
            ),
        ] {
            let safety: SafetyConfig = toml::from_str(text).unwrap();
            assert_eq!(safety.check(&joints).unwrap_err().0, field, "{text}");
        }
    }
}
