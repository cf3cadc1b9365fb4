//! Foot switches: whether each foot is on the ground, read every tick from wherever the robot
//! has them — GPIO lines on Linux (the character-device interface, `gpiocdev`) on hardware, the
//! simulation's contacts behind the same trait on a mirror.

use std::fmt::Debug;

use robots::Robot;

use crate::IoError;

/// A source of foot-switch states, robot.toml's `feet` order.
pub trait ContactSource: Debug + Send {
    /// Reads every foot's switch into `out` (one per foot).
    fn read(&mut self, out: &mut [bool]) -> Result<(), IoError>;
}

/// Foot switches on GPIO lines, as robot.toml's `[[contacts]]` configures them.
#[derive(Debug)]
pub struct GpioContacts {
    /// Per configured switch: its request, line and foot index.
    lines: Vec<(gpiocdev::Request, u32, usize)>,
}

impl GpioContacts {
    /// Requests every configured line as an input; None when the robot has no switches. The
    /// error names the robot.toml entry and the device.
    pub fn open(robot: &Robot) -> Result<Option<Self>, IoError> {
        if robot.config.contacts.is_empty() {
            return Ok(None);
        }
        let mut lines = Vec::with_capacity(robot.config.contacts.len());
        for (i, sw) in robot.config.contacts.iter().enumerate() {
            let foot = robot
                .config
                .feet
                .iter()
                .position(|f| *f == sw.foot)
                .ok_or_else(|| IoError::Setup(format!("contacts[{i}]: {:?} is not a foot", sw.foot)))?;
            let mut builder = gpiocdev::Request::builder();
            builder
                .on_chip(&sw.chip)
                .with_consumer("robodeploy")
                .with_line(sw.line)
                .as_input();
            if sw.active_low {
                builder.as_active_low();
            }
            let request = builder.request().map_err(|e| {
                IoError::Open(format!(
                    "{}: contacts[{i}] ({} switch): GPIO {} line {}: {e}",
                    robot.path.display(),
                    sw.foot,
                    sw.chip.display(),
                    sw.line
                ))
            })?;
            lines.push((request, sw.line, foot));
        }
        Ok(Some(Self { lines }))
    }
}

impl ContactSource for GpioContacts {
    fn read(&mut self, out: &mut [bool]) -> Result<(), IoError> {
        for (request, line, foot) in &self.lines {
            let v = request
                .value(*line)
                .map_err(|e| IoError::Open(format!("GPIO line {line}: {e}")))?;
            if let Some(o) = out.get_mut(*foot) {
                *o = v == gpiocdev::line::Value::Active;
            }
        }
        Ok(())
    }
}
