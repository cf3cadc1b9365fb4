//! How a mirror run is set up: seed, gantry, firmware rate, randomisation and scheduled faults.
//! Loaded from TOML (`[mirror]` tables of a run config) or built in code.

use std::time::Duration;

/// A uniform range `[lo, hi]` a quantity is drawn from once per run.
#[derive(Debug, Clone, Copy, PartialEq, serde::Deserialize, schemars::JsonSchema, serde::Serialize)]
pub struct Range(pub f64, pub f64);

impl Range {
    /// The degenerate range `[v, v]`.
    pub const fn fixed(v: f64) -> Self {
        Self(v, v)
    }
}

/// What is randomised per run (each joint/body draws its own factor).
#[derive(Debug, Clone, PartialEq, serde::Deserialize, schemars::JsonSchema, serde::Serialize)]
#[serde(default, deny_unknown_fields)]
pub struct Randomization {
    /// Scale of every body's mass.
    pub mass_scale: Range,
    /// Scale of every joint's friction loss and damping.
    pub friction_scale: Range,
    /// Scale of every actuator's torque (motor strength).
    pub strength_scale: Range,
    /// USB adapter latency on serial lines, µs.
    pub usb_latency_us: Range,
    /// Scale of the IMU's noise and bias.
    pub imu_noise_scale: f64,
    /// The IMU's gyro bias drifts by this, °/s per √s (a random walk; its heading drifts with
    /// it). 0: constant biases.
    pub imu_gyro_bias_walk_dps: f64,
    /// The IMU's accelerometer bias drifts by this, m/s² per √s.
    pub imu_accel_bias_walk: f64,
}

impl Default for Randomization {
    fn default() -> Self {
        Self {
            mass_scale: Range::fixed(1.0),
            friction_scale: Range::fixed(1.0),
            strength_scale: Range::fixed(1.0),
            usb_latency_us: Range::fixed(0.0),
            imu_noise_scale: 1.0,
            imu_gyro_bias_walk_dps: 0.0,
            imu_accel_bias_walk: 0.0,
        }
    }
}

/// A fault the mirror applies at a given simulated time.
#[derive(Debug, Clone, PartialEq, serde::Deserialize, schemars::JsonSchema, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct ScheduledFault {
    /// When, seconds after the start.
    pub at_s: f64,
    /// The joint (robot.toml name) whose device misbehaves, or `"imu"` for the IMU.
    pub joint: String,
    /// What happens.
    pub fault: FaultKind,
}

/// A constant force on the robot's root body for a while: a shove, a bump, a tug on the gantry.
#[derive(Debug, Clone, Copy, PartialEq, serde::Deserialize, schemars::JsonSchema, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct Push {
    /// When it starts, seconds after the start: [0, 86400].
    pub at_s: f64,
    /// How long it lasts, s: [0.001, 5].
    pub duration_s: f64,
    /// The force in the world frame (x forward, z up), N: each component within ±2000.
    pub force_n: [f64; 3],
}

/// Faults a device can be made to show.
#[derive(Debug, Clone, Copy, PartialEq, serde::Deserialize, schemars::JsonSchema, serde::Serialize)]
#[serde(rename_all = "snake_case", tag = "kind")]
pub enum FaultKind {
    /// The device stops answering for `count` packets/frames (`None`: for good; at least 1).
    /// MIT motors still act on what they hear; the IMU loses `count` output cycles.
    Silent {
        /// How many answers are lost.
        count: Option<u32>,
    },
    /// The device's answers carry a bad CRC for `count` answers (at least 1). On CAN the
    /// controller drops such frames, so the host sees lost replies.
    CorruptCrc {
        /// How many answers.
        count: u32,
    },
    /// The device overheats (Dynamixel hardware error / motor over-temperature fault).
    Overheat,
    /// The device loses power for good.
    Vanish,
}

/// What the real machine is like where it differs from its description: the values a
/// calibration must find. The mirror builds its physics from these; the host never sees them.
#[derive(Debug, Clone, Default, PartialEq, serde::Deserialize, schemars::JsonSchema, serde::Serialize)]
#[serde(default, deny_unknown_fields)]
pub struct HardwareTruth {
    /// Per joint (robot.toml name): the actuator's true zero offset and direction.
    pub joints: std::collections::BTreeMap<String, TrueJoint>,
    /// The IMU's true mounting, roll/pitch/yaw in degrees.
    pub imu_mounting_rpy_deg: Option<[f64; 3]>,
}

/// A joint's true actuator mapping.
#[derive(Debug, Clone, Copy, PartialEq, serde::Deserialize, schemars::JsonSchema, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct TrueJoint {
    /// Actuator angle at joint zero, rad.
    pub zero_offset: f64,
    /// +1 or -1.
    pub direction: f64,
}

/// A mirror run's setup.
#[derive(Debug, Clone, PartialEq, Default, serde::Deserialize, schemars::JsonSchema, serde::Serialize)]
#[serde(default, deny_unknown_fields)]
pub struct MirrorConfig {
    /// Seed of every random draw (noise, randomisation): same seed, same run.
    pub seed: u64,
    /// Hold the root on a gantry (a stiff spring-damper) with the feet off the ground.
    pub gantry: bool,
    /// Hang the robot in a harness that lowers it onto its feet and goes slack (a `harness`
    /// start; robot.toml `[start.harness]`).
    pub harness: Option<robots::HarnessConfig>,
    /// Hold the physics still (the robot as placed, time not moving for it) until the controller
    /// first drives a joint: a robot is not left to fall while a controller connects, identifies
    /// its devices or waits for a viewer. Runs and served mirrors set it.
    pub hold_until_driven: bool,
    /// Period of the emulated firmware's control loops, µs (0: the physics step).
    pub firmware_period_us: u64,
    /// Return Delay Time the mirror's servos are set to, µs.
    pub servo_return_delay_us: u64,
    /// What to randomise.
    pub randomization: Randomization,
    /// Faults, in any order.
    pub faults: Vec<ScheduledFault>,
    /// Shoves on the robot's root body, in any order.
    pub pushes: Vec<Push>,
    /// The machine's true offsets, directions and IMU mounting (for calibration tests).
    pub hardware: HardwareTruth,
    /// Where the robot stands when the run begins.
    pub start: StartPose,
    /// The joint angles the robot starts in (robot.toml order) where a run gives them, instead
    /// of the default pose: a `policy` start places the robot in its reference's first frame, as
    /// trainers reset a tracking policy's episode to its motion.
    #[serde(skip)]
    pub start_joints: Option<Vec<f64>>,
    /// The floor tilted about the world's x and y axes, degrees (each within ±20): a slope.
    pub floor_tilt_deg: [f64; 2],
    /// How much of the robot the mirror is: `wires` (the default) emulates every device's
    /// firmware behind its bus protocol; `direct` applies each joint's command to MuJoCo as the
    /// trainer's actuator law (robot.toml `[[actuators]]`, explicit PD within the joint's torque
    /// limit where none is given; the model's own position servos take it as their goal and
    /// gains) with no bus, firmware or wire in between, the IMU's samples straight from the model
    /// (its noise kept): the physics floor, for validating motion libraries.
    pub fidelity: Fidelity,
}

/// The mirror's fidelity ([`MirrorConfig::fidelity`]).
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, Default, serde::Deserialize, schemars::JsonSchema, serde::Serialize,
)]
#[serde(rename_all = "lowercase")]
pub enum Fidelity {
    /// Every device's firmware behind its bus protocol, the host's real drivers on the wires.
    #[default]
    Wires,
    /// The trainer's actuator law on MuJoCo, no buses.
    Direct,
}

impl std::fmt::Display for Fidelity {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Self::Wires => "wires (emulated firmware behind each bus protocol)",
            Self::Direct => "direct (the trainer's actuator law on MuJoCo, no buses)",
        })
    }
}

/// Where the mirrored robot starts: a horizontal position, a heading, and a height to drop from.
#[derive(
    Debug, Clone, Copy, PartialEq, Default, serde::Deserialize, schemars::JsonSchema, serde::Serialize,
)]
#[serde(default, deny_unknown_fields)]
pub struct StartPose {
    /// x and y of the root, m (within ±100).
    pub position: [f64; 2],
    /// Heading about the vertical, degrees (within ±360).
    pub yaw_deg: f64,
    /// The soles start this far above the floor, m (0–2): the robot drops.
    pub height_m: f64,
}

impl MirrorConfig {
    /// The settings for a run (or a served mirror) that starts as `start` says: held still until
    /// the controller drives a joint, and for a `harness` start hanging in the robot's harness
    /// (unless on the gantry, or the settings give a harness of their own).
    pub fn for_run(mut self, robot: &robots::Robot, start: robots::StartMode) -> Self {
        self.hold_until_driven = true;
        if start == robots::StartMode::Harness && !self.gantry && self.harness.is_none() {
            self.harness = Some(robot.config.start.harness);
        }
        self
    }

    /// Checks every field against its documented range (`robot` names the joints), as a file of
    /// mirror settings must pass: `Err((field, message))`. Configurations built in code are
    /// trusted as they are (tests use extreme ones on purpose).
    pub fn check(&self, robot: &robots::Robot) -> Result<(), (String, String)> {
        let range = |field: &str, r: &Range, lo: f64, hi: f64| {
            if !(r.0.is_finite() && r.1.is_finite() && lo <= r.0 && r.0 <= r.1 && r.1 <= hi) {
                Err((
                    format!("randomization.{field}"),
                    format!(
                        "[{}, {}] is not an interval within [{}, {}]",
                        robots::num(r.0),
                        robots::num(r.1),
                        robots::num(lo),
                        robots::num(hi)
                    ),
                ))
            } else {
                Ok(())
            }
        };
        let r = &self.randomization;
        range("mass_scale", &r.mass_scale, 0.1, 10.0)?;
        range("friction_scale", &r.friction_scale, 0.0, 10.0)?;
        range("strength_scale", &r.strength_scale, 0.1, 2.0)?;
        range("usb_latency_us", &r.usb_latency_us, 0.0, 100_000.0)?;
        if !(0.0..=100.0).contains(&r.imu_noise_scale) {
            return Err((
                "randomization.imu_noise_scale".into(),
                format!("{} is outside [0, 100]", robots::num(r.imu_noise_scale)),
            ));
        }
        if self.firmware_period_us != 0 && !(100..=10_000).contains(&self.firmware_period_us) {
            return Err((
                "firmware_period_us".into(),
                format!(
                    "{} is outside [100, 10000] µs (0: the physics step)",
                    self.firmware_period_us
                ),
            ));
        }
        if self.servo_return_delay_us > 508 {
            return Err((
                "servo_return_delay_us".into(),
                format!("{} is beyond the servos' 508 µs", self.servo_return_delay_us),
            ));
        }
        if let Some(v) = self
            .start
            .position
            .iter()
            .find(|v| !(-100.0..=100.0).contains(*v))
        {
            return Err((
                "start.position".into(),
                format!("{} is outside [-100, 100] m", robots::num(*v)),
            ));
        }
        if !(0.0..=2.0).contains(&self.start.height_m) {
            return Err((
                "start.height_m".into(),
                format!("{} is outside [0, 2] m", robots::num(self.start.height_m)),
            ));
        }
        if let Some(v) = self.floor_tilt_deg.iter().find(|v| !(-20.0..=20.0).contains(*v)) {
            return Err((
                "floor_tilt_deg".into(),
                format!("{} is outside [-20, 20]°", robots::num(*v)),
            ));
        }
        for (field, v, hi) in [
            ("imu_gyro_bias_walk_dps", r.imu_gyro_bias_walk_dps, 10.0),
            ("imu_accel_bias_walk", r.imu_accel_bias_walk, 10.0),
        ] {
            if !(0.0..=hi).contains(&v) {
                return Err((
                    format!("randomization.{field}"),
                    format!("{} is outside [0, {hi}]", robots::num(v)),
                ));
            }
        }
        if !(-360.0..=360.0).contains(&self.start.yaw_deg) {
            return Err((
                "start.yaw_deg".into(),
                format!("{} is outside [-360, 360]°", robots::num(self.start.yaw_deg)),
            ));
        }
        for (k, f) in self.faults.iter().enumerate() {
            if !(0.0..=86_400.0).contains(&f.at_s) {
                return Err((
                    format!("faults[{k}].at_s"),
                    format!("{} is outside [0, 86400] s", robots::num(f.at_s)),
                ));
            }
        }
        for (k, p) in self.pushes.iter().enumerate() {
            let bad = |field: &str, m: String| Err((format!("pushes[{k}].{field}"), m));
            if !(0.0..=86_400.0).contains(&p.at_s) {
                return bad("at_s", format!("{} is outside [0, 86400] s", robots::num(p.at_s)));
            }
            if !(0.001..=5.0).contains(&p.duration_s) {
                return bad(
                    "duration_s",
                    format!("{} is outside [0.001, 5] s", robots::num(p.duration_s)),
                );
            }
            if let Some(f) = p.force_n.iter().find(|f| !(-2000.0..=2000.0).contains(*f)) {
                return bad("force_n", format!("{} is outside ±2000 N", robots::num(*f)));
            }
        }
        for (name, t) in &self.hardware.joints {
            let field = format!("hardware.joints.{name}");
            if robot.config.joints.iter().all(|j| &j.name != name) {
                return Err((field, format!("{name:?} is not a joint of {}", robot.config.name)));
            }
            if t.direction.abs() != 1.0 {
                return Err((
                    format!("{field}.direction"),
                    format!("{} (must be 1 or -1)", t.direction),
                ));
            }
            if !(t.zero_offset.is_finite() && t.zero_offset.abs() <= 4.0 * std::f64::consts::PI) {
                return Err((
                    format!("{field}.zero_offset"),
                    format!("{} is outside ±4π", t.zero_offset),
                ));
            }
        }
        if let Some(m) = self.hardware.imu_mounting_rpy_deg
            && m.iter().any(|v| !v.is_finite())
        {
            return Err((
                "hardware.imu_mounting_rpy_deg".into(),
                format!("{m:?} is not finite"),
            ));
        }
        Ok(())
    }

    /// The servos' Return Delay Time.
    pub fn servo_return_delay(&self) -> Duration {
        Duration::from_micros(self.servo_return_delay_us)
    }
}
