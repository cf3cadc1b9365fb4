//! The manifest's `[commands]`: the live commands a command-driven policy (a velocity-command
//! "joystick" policy) observes — their names and meanings, ranges, defaults, ramps, key steps and
//! gamepad axes. Where the values come from (keyboard, gamepad, UDP) is the `human` crate's.

/// Commands a manifest may declare.
pub const MAX_COMMANDS: usize = 8;

/// What a command means, for the run's metrics (commanded against achieved).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Deserialize, schemars::JsonSchema, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum CommandKind {
    /// Forward speed in the robot's heading frame, m/s.
    LinVelX,
    /// Leftward speed in the robot's heading frame, m/s.
    LinVelY,
    /// Turning rate about the vertical, rad/s (left positive).
    AngVelZ,
    /// Anything else (a height, a gait index, …).
    Other,
}

impl CommandKind {
    /// The meaning of a command called `name`, by the names training frameworks use.
    pub fn of_name(name: &str) -> Self {
        match name.to_ascii_lowercase().as_str() {
            "lin_vel_x" | "vx" | "x_vel" | "vel_x" | "forward" | "base_lin_vel_x" => Self::LinVelX,
            "lin_vel_y" | "vy" | "y_vel" | "vel_y" | "lateral" | "base_lin_vel_y" => Self::LinVelY,
            "ang_vel_z" | "wz" | "yaw_rate" | "ang_vel_yaw" | "heading_rate" | "base_ang_vel_z" => {
                Self::AngVelZ
            }
            _ => Self::Other,
        }
    }
}

/// A gamepad axis, as `gilrs` names the standard layout's.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Deserialize, schemars::JsonSchema, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum PadAxis {
    /// Left stick, right positive.
    LeftX,
    /// Left stick, up positive.
    LeftY,
    /// Right stick, right positive.
    RightX,
    /// Right stick, up positive.
    RightY,
}

/// Which gamepad axis drives a command, and in which sense.
#[derive(Debug, Clone, Copy, PartialEq, serde::Deserialize, schemars::JsonSchema, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct AxisBinding {
    /// The axis.
    pub axis: PadAxis,
    /// Flip it (a stick pushed right commands a negative, rightward `lin_vel_y`).
    #[serde(default)]
    pub invert: bool,
}

/// The manifest's `[commands]`: the live commands of a command-driven policy.
#[derive(Debug, Clone, PartialEq, serde::Deserialize, schemars::JsonSchema, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct CommandSpec {
    /// Names, in the order the policy's `command` term observes them (at most [`MAX_COMMANDS`]).
    pub names: Vec<String>,
    /// `[low, high]` per command: what every source is clamped to and `--command` must respect.
    pub ranges: Vec<[f64; 2]>,
    /// The commands before any source speaks, and after one falls silent (default: 0, or the
    /// range's nearest end when 0 is outside it).
    #[serde(default)]
    pub default: Option<Vec<f64>>,
    /// Fastest change per command, units per second (default: none, commands jump).
    #[serde(default)]
    pub ramp: Option<Vec<f64>>,
    /// What one key press adds, per command (default: a tenth of the range's larger end).
    #[serde(default)]
    pub step: Option<Vec<f64>>,
    /// What each command means (default: from its name: `lin_vel_x`, `lin_vel_y`, `ang_vel_z`
    /// and their common aliases, else `other`).
    #[serde(default)]
    pub kinds: Option<Vec<CommandKind>>,
    /// Gamepad axis per command (default: left stick up → command 0, left stick left →
    /// command 1, right stick left → command 2).
    #[serde(default)]
    pub gamepad: Option<Vec<AxisBinding>>,
    /// A gamepad or UDP source silent this long (s) hands back to the defaults (0.05–10).
    #[serde(default = "default_timeout_s")]
    pub timeout_s: f64,
}

fn default_timeout_s() -> f64 {
    0.5
}

impl CommandSpec {
    /// Checks every documented range. `Err((field, message))`.
    pub fn check(&self) -> Result<(), (String, String)> {
        let n = self.names.len();
        let field = |f: &str| format!("commands.{f}");
        if n == 0 || n > MAX_COMMANDS {
            return Err((field("names"), format!("{n} commands: one to {MAX_COMMANDS}")));
        }
        for (i, name) in self.names.iter().enumerate() {
            if name.is_empty() || self.names[..i].contains(name) {
                return Err((field("names"), format!("{name:?} is empty or named twice")));
            }
        }
        let same_length = |what: &str, len: usize| {
            if len == n {
                Ok(())
            } else {
                Err((field(what), format!("{len} entries for {n} commands")))
            }
        };
        same_length("ranges", self.ranges.len())?;
        for (name, [lo, hi]) in self.names.iter().zip(&self.ranges) {
            if !(lo.is_finite() && hi.is_finite() && lo <= hi && lo.abs() <= 1e6 && hi.abs() <= 1e6) {
                return Err((
                    field("ranges"),
                    format!("{name}: [{lo}, {hi}] is not an interval (low ≤ high, finite, within ±1e6)"),
                ));
            }
        }
        if let Some(d) = &self.default {
            same_length("default", d.len())?;
            self.check_values(d)
                .map_err(|e| (field("default"), e.to_string()))?;
        }
        for (what, values) in [("ramp", &self.ramp), ("step", &self.step)] {
            if let Some(v) = values {
                same_length(what, v.len())?;
                if let Some((name, x)) = self
                    .names
                    .iter()
                    .zip(v)
                    .find(|(_, x)| !(x.is_finite() && **x > 0.0 && **x <= 1e6))
                {
                    return Err((field(what), format!("{name}: {x} is not in (0, 1e6]")));
                }
            }
        }
        if let Some(k) = &self.kinds {
            same_length("kinds", k.len())?;
        }
        if let Some(g) = &self.gamepad {
            same_length("gamepad", g.len())?;
        }
        if !(0.05..=10.0).contains(&self.timeout_s) {
            return Err((
                field("timeout_s"),
                format!("{} s is outside [0.05, 10]", self.timeout_s),
            ));
        }
        Ok(())
    }

    /// Whether `values` are as many as the commands and each within its range; the message names
    /// the first that is not.
    pub fn check_values(&self, values: &[f64]) -> Result<(), CommandValuesError> {
        if values.len() != self.names.len() {
            return Err(CommandValuesError::Count {
                given: values.len(),
                names: self.names.clone(),
            });
        }
        for ((name, &[lo, hi]), &value) in self.names.iter().zip(&self.ranges).zip(values) {
            if !(value.is_finite() && (lo..=hi).contains(&value)) {
                return Err(CommandValuesError::OutOfRange {
                    name: name.clone(),
                    value,
                    range: [lo, hi],
                });
            }
        }
        Ok(())
    }

    /// The commands before any source speaks.
    pub fn defaults(&self) -> Vec<f64> {
        self.default
            .clone()
            .unwrap_or_else(|| self.ranges.iter().map(|&[lo, hi]| 0.0f64.clamp(lo, hi)).collect())
    }

    /// Key press increments.
    pub fn steps(&self) -> Vec<f64> {
        self.step.clone().unwrap_or_else(|| {
            self.ranges
                .iter()
                .map(|[lo, hi]| lo.abs().max(hi.abs()) / 10.0)
                .map(|s| if s > 0.0 { s } else { 1.0 })
                .collect()
        })
    }

    /// What each command means.
    pub fn kinds(&self) -> Vec<CommandKind> {
        self.kinds
            .clone()
            .unwrap_or_else(|| self.names.iter().map(|n| CommandKind::of_name(n)).collect())
    }

    /// The gamepad axis of each command (`None`: no axis drives it).
    pub fn gamepad_bindings(&self) -> Vec<Option<AxisBinding>> {
        match &self.gamepad {
            Some(g) => g.iter().copied().map(Some).collect(),
            None => {
                let standard = [
                    AxisBinding {
                        axis: PadAxis::LeftY,
                        invert: false,
                    },
                    AxisBinding {
                        axis: PadAxis::LeftX,
                        invert: true,
                    },
                    AxisBinding {
                        axis: PadAxis::RightX,
                        invert: true,
                    },
                ];
                (0..self.names.len()).map(|i| standard.get(i).copied()).collect()
            }
        }
    }

    /// `values` clamped into the ranges.
    pub fn clamp(&self, values: &mut [f64]) {
        for (v, [lo, hi]) in values.iter_mut().zip(&self.ranges) {
            *v = if v.is_finite() {
                v.clamp(*lo, *hi)
            } else {
                0.0f64.clamp(*lo, *hi)
            };
        }
    }
}

/// Command values that do not fit the manifest's `[commands]`.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CommandValuesError {
    /// Not one value per command.
    #[error("{given} values for {} commands ({})", names.len(), names.join(", "))]
    Count {
        /// Values given.
        given: usize,
        /// The commands, in order.
        names: Vec<String>,
    },
    /// A value outside its command's range (or not finite).
    #[error("{name} = {value} is outside its range [{}, {}]", range[0], range[1])]
    OutOfRange {
        /// The command.
        name: String,
        /// The value given.
        value: f64,
        /// The range, low and high.
        range: [f64; 2],
    },
}
