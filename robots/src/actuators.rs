//! How the trainer's simulation turned a joint's command into torque (robot.toml `[[actuators]]`),
//! so the mirror can do the same: the motor firmware's own loop, a PD law computed every physics
//! step (explicit, or with its damping implicit in MuJoCo's integrator), a DC motor's torque–speed
//! saturation, and an actuation delay. Names and laws as mjlab and Isaac Lab document their
//! actuator configurations (`IdealPDActuator`, `ImplicitActuator`, `DCMotor`, `DelayedPDActuator`).

use crate::config::{BusKind, JointConfig, RobotConfig, check_range, matches_pattern};

/// The law that makes a joint's torque from its command.
#[derive(
    Debug, Clone, Copy, Default, PartialEq, Eq, serde::Deserialize, schemars::JsonSchema, serde::Serialize,
)]
#[serde(rename_all = "snake_case")]
pub enum ActuatorModel {
    /// The emulated device's own loop at its inner rate: an MIT motor's PD at the firmware
    /// period, a serial servo's position control (the model's `<position>` actuator capped at the
    /// servo's torque, where the model has one).
    #[default]
    Firmware,
    /// `τ = kp (q* − q) + kd (q̇* − q̇) + τ_ff`, computed every physics step from the newest
    /// command and clipped to the effort limit (Isaac Lab's ideal PD, holosoma's MuJoCo loop).
    ExplicitPd,
    /// The same law with its damping `kd` handed to MuJoCo's integrator, which treats joint
    /// damping implicitly (a `<position>` actuator's stability at large steps; mjlab's default).
    ImplicitPd,
    /// Explicit PD whose torque is bounded by a DC motor's torque–speed line: at most
    /// `saturation_effort (1 − q̇ / velocity_limit)` in the direction of motion, within the
    /// effort limit (Isaac Lab's `DCMotor`).
    DcMotor,
}

impl ActuatorModel {
    /// The name robot.toml uses.
    pub fn name(self) -> &'static str {
        match self {
            Self::Firmware => "firmware",
            Self::ExplicitPd => "explicit_pd",
            Self::ImplicitPd => "implicit_pd",
            Self::DcMotor => "dc_motor",
        }
    }

    /// Whether the mirror computes this law itself every physics step from the device's command
    /// (rather than taking the firmware's torque).
    pub fn per_physics_step(self) -> bool {
        self != Self::Firmware
    }

    /// Whether a bus of `kind` can provide it: a PD law needs the stiffness and damping that only
    /// MIT-mode frames carry; serial servos close their own loop.
    pub fn provided_by(self, kind: BusKind) -> bool {
        match kind {
            // Unitree's boards run the same impedance law on each motor.
            BusKind::MitCan | BusKind::UnitreeDds => true,
            BusKind::Dynamixel | BusKind::Feetech => self == Self::Firmware,
            BusKind::ImuSerial => false,
        }
    }
}

/// The actuator of a joint or group (robot.toml `[[actuators]]`). A later entry wins over an
/// earlier one, field by field, for the joints both match.
#[derive(Debug, Clone, PartialEq, serde::Deserialize, schemars::JsonSchema, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct ActuatorGroup {
    /// Joint names or patterns (`*` matches any run of characters).
    pub joints: Vec<String>,
    /// The law (default `firmware`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub model: Option<ActuatorModel>,
    /// Largest torque, N·m at the joint (0–10 000); default, and never beyond: the joint's
    /// `torque_limit` (within the motor's own range).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub effort_limit: Option<f64>,
    /// `dc_motor`: stall torque of the torque–speed line, N·m at the joint (0–10 000).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub saturation_effort: Option<f64>,
    /// `dc_motor`: speed at which the line reaches zero torque, rad/s at the joint (0.1–1000).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub velocity_limit: Option<f64>,
    /// Actuation delay, whole physics steps, drawn per run from `[min, max]` (0–100): the command
    /// acts this many steps after it arrived (Isaac Lab's delayed PD).
    #[serde(
        default,
        skip_serializing_if = "Option::is_none",
        deserialize_with = "min_max"
    )]
    pub delay_steps: Option<[u32; 2]>,
}

/// A `[min, max]` pair, exactly two values (TOML's reader would drop a third silently).
fn min_max<'de, D: serde::Deserializer<'de>>(d: D) -> Result<Option<[u32; 2]>, D::Error> {
    let values = <Vec<u32> as serde::Deserialize>::deserialize(d)?;
    match values[..] {
        [lo, hi] => Ok(Some([lo, hi])),
        _ => Err(serde::de::Error::custom(format!(
            "delay_steps: expected [min, max], got {} value(s): {values:?}",
            values.len()
        ))),
    }
}

/// One joint's actuator after every `[[actuators]]` entry.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct ActuatorOf {
    /// The law.
    pub model: ActuatorModel,
    /// Effort limit, N·m at the joint: robot.toml's, within the joint's `torque_limit` (none for a
    /// name that is no joint of the robot: the motor's).
    pub effort_limit: Option<f64>,
    /// DC motor stall torque, N·m at the joint.
    pub saturation_effort: Option<f64>,
    /// DC motor zero-torque speed, rad/s at the joint.
    pub velocity_limit: Option<f64>,
    /// Delay range, physics steps.
    pub delay_steps: [u32; 2],
}

/// The largest actuation delay robot.toml may ask, physics steps.
pub const MAX_DELAY_STEPS: u32 = 100;

impl ActuatorOf {
    /// The effort limit in force, N·m at the joint: robot.toml's, never beyond the motor's
    /// `motor_range` (its torque clamp through the gearing).
    pub fn limit(&self, motor_range: f64) -> f64 {
        self.effort_limit.map_or(motor_range, |e| e.min(motor_range))
    }

    /// The DC motor's torque bounds at joint speed `qd` (rad/s), within `limit`: `(low, high)`.
    /// Other laws: `(-limit, limit)`.
    pub fn torque_bounds(&self, qd: f64, limit: f64) -> (f64, f64) {
        match (self.model, self.saturation_effort, self.velocity_limit) {
            (ActuatorModel::DcMotor, Some(stall), Some(speed)) => (
                (stall * (-1.0 - qd / speed)).clamp(-limit, 0.0),
                (stall * (1.0 - qd / speed)).clamp(0.0, limit),
            ),
            _ => (-limit, limit),
        }
    }
}

impl RobotConfig {
    /// The actuator `[[actuators]]` gives joint `name`, field by field (the last entry matching
    /// it that sets a field wins).
    pub fn actuator_of(&self, name: &str) -> ActuatorOf {
        let mut out = ActuatorOf::default();
        for a in self
            .actuators
            .iter()
            .filter(|a| a.joints.iter().any(|p| matches_pattern(p, name)))
        {
            out.model = a.model.unwrap_or(out.model);
            out.effort_limit = a.effort_limit.or(out.effort_limit);
            out.saturation_effort = a.saturation_effort.or(out.saturation_effort);
            out.velocity_limit = a.velocity_limit.or(out.velocity_limit);
            out.delay_steps = a.delay_steps.unwrap_or(out.delay_steps);
        }
        // Every torque the robot gives stays within the joint's limit, the trainer's clip too.
        if let Some(j) = self.joints.iter().find(|j| j.name == name) {
            out.effort_limit = Some(out.effort_limit.map_or(j.torque_limit, |e| e.min(j.torque_limit)));
        }
        out
    }
}

/// How a joint's torque limit is held where a motor runs the PD law itself (MIT-mode motors,
/// Unitree's boards) and its own clamp is wider than the limit.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum TorqueHold {
    /// The motor's range (through the gear) lies within the limit: its own clamp holds it at
    /// every step of its law, and commands pass unchanged.
    MotorRange,
    /// The trainer's clip: robot.toml declares a PD law computed every physics step (`[[actuators]]`),
    /// whose torque the trainer clipped at each step's state; each bus cycle (the real robot's
    /// physics step) clips the torque its command asks for at the measured state, and nothing
    /// else. N·m at the joint.
    ClipAtMeasurement(f64),
    /// The motor's own loop (`firmware`), whose stiffness the policy relies on between commands:
    /// every command is bounded so its PD stays within the limit over the whole coming cycle,
    /// moving on or stopped dead by an obstacle. N·m at the joint.
    OverCycle(f64),
}

impl TorqueHold {
    /// The limit the bus holds, N·m at the joint (none: the motor's own range holds it).
    pub fn limit(self) -> Option<f64> {
        match self {
            Self::MotorRange => None,
            Self::ClipAtMeasurement(l) | Self::OverCycle(l) => Some(l),
        }
    }
}

impl crate::Robot {
    /// How joint `j`'s torque limit is held on its bus (see [`TorqueHold`]); joints whose
    /// devices cap their own torque (serial servos) are `MotorRange`.
    pub fn torque_hold(&self, j: &JointConfig) -> TorqueHold {
        match self.mit_model(&j.model) {
            Some(m) if m.t_max * j.gear.abs() > j.torque_limit + 1e-9 => {
                if self.config.actuator_of(&j.name).model.per_physics_step() {
                    TorqueHold::ClipAtMeasurement(j.torque_limit)
                } else {
                    TorqueHold::OverCycle(j.torque_limit)
                }
            }
            _ => TorqueHold::MotorRange,
        }
    }
}

impl ActuatorGroup {
    /// Checks every entry's fields against their ranges and patterns against `joints`, then every
    /// joint's resolved actuator against its bus: `(field, message)` on the first fault.
    pub(crate) fn check(config: &RobotConfig, joints: &[JointConfig]) -> Result<(), (String, String)> {
        for (i, a) in config.actuators.iter().enumerate() {
            let at = |field: &str| format!("actuators[{i}].{field}");
            if a.joints.is_empty() {
                return Err((at("joints"), "names no joint".into()));
            }
            for p in &a.joints {
                if !joints.iter().any(|j| matches_pattern(p, &j.name)) {
                    return Err((at("joints"), format!("{p:?} matches no joint of the robot")));
                }
            }
            for (field, value, lo, hi, unit) in [
                ("effort_limit", a.effort_limit, 0.0, 10_000.0, "N·m"),
                ("saturation_effort", a.saturation_effort, 0.0, 10_000.0, "N·m"),
                ("velocity_limit", a.velocity_limit, 0.1, 1000.0, "rad/s"),
            ] {
                check_range(&at(field), value, lo, hi, unit)?;
            }
            if let Some([lo, hi]) = a.delay_steps
                && (lo > hi || hi > MAX_DELAY_STEPS)
            {
                return Err((
                    at("delay_steps"),
                    format!("[{lo}, {hi}] is not a range within [0, {MAX_DELAY_STEPS}] steps"),
                ));
            }
        }
        for j in joints {
            let a = config.actuator_of(&j.name);
            let kind = config.buses.iter().find(|b| b.name == j.bus).map(|b| b.kind);
            let entry = || {
                let last = config
                    .actuators
                    .iter()
                    .rposition(|a| a.joints.iter().any(|p| matches_pattern(p, &j.name)));
                format!("actuators[{}]", last.unwrap_or(0))
            };
            if let Some(kind) = kind
                && !a.model.provided_by(kind)
            {
                return Err((
                    format!("{}.model", entry()),
                    format!(
                        "{}: joint {} sits on a {kind:?} bus, which cannot provide it (its servos \
                         take position goals and close their own loop): use firmware",
                        a.model.name(),
                        j.name
                    ),
                ));
            }
            if a.model == ActuatorModel::DcMotor
                && (a.saturation_effort.is_none() || a.velocity_limit.is_none())
            {
                return Err((
                    format!("{}.model", entry()),
                    format!(
                        "dc_motor for joint {} needs saturation_effort and velocity_limit",
                        j.name
                    ),
                ));
            }
            if a.model != ActuatorModel::DcMotor
                && let Some(field) = [
                    ("saturation_effort", a.saturation_effort),
                    ("velocity_limit", a.velocity_limit),
                ]
                .iter()
                .find_map(|(f, v)| v.map(|_| *f))
            {
                let last = config.actuators.iter().rposition(|g| {
                    g.joints.iter().any(|p| matches_pattern(p, &j.name))
                        && match field {
                            "saturation_effort" => g.saturation_effort.is_some(),
                            _ => g.velocity_limit.is_some(),
                        }
                });
                return Err((
                    format!("actuators[{}].{field}", last.unwrap_or(0)),
                    format!(
                        "joint {}: only dc_motor has a torque–speed line, and its law is {}",
                        j.name,
                        a.model.name()
                    ),
                ));
            }
            if a.model == ActuatorModel::Firmware && a.delay_steps != [0, 0] {
                return Err((
                    format!("{}.delay_steps", entry()),
                    format!(
                        "joint {}: a delay needs a law the mirror computes (explicit_pd, implicit_pd \
                         or dc_motor); with firmware the bus's own timing is the delay",
                        j.name
                    ),
                ));
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_dc_motor_gives_less_torque_the_faster_it_turns_with_the_motion() {
        let a = ActuatorOf {
            model: ActuatorModel::DcMotor,
            saturation_effort: Some(100.0),
            velocity_limit: Some(10.0),
            ..ActuatorOf::default()
        };
        assert_eq!(a.torque_bounds(0.0, 80.0), (-80.0, 80.0));
        assert_eq!(a.torque_bounds(5.0, 80.0), (-80.0, 50.0));
        assert_eq!(a.torque_bounds(-5.0, 80.0), (-50.0, 80.0));
        // Beyond its no-load speed the motor only brakes.
        assert_eq!(a.torque_bounds(12.0, 80.0), (-80.0, 0.0));
        let pd = ActuatorOf::default();
        assert_eq!(pd.torque_bounds(12.0, 80.0), (-80.0, 80.0));
    }
}
