//! `calibration.toml` beside a robot.toml: what calibration measured (joint zero offsets and
//! directions, IMU mounting and gyro bias). Loading a robot merges it over the description; writing
//! it keeps the previous file and replaces atomically, so an interrupted write never leaves a half
//! file behind.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use crate::FileError;

/// One joint's measured actuator mapping.
#[derive(Debug, Clone, Copy, PartialEq, serde::Deserialize, schemars::JsonSchema, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct JointCalibration {
    /// Actuator angle at joint zero, rad.
    pub zero_offset: f64,
    /// +1 or -1.
    pub direction: f64,
    /// Dynamixel Homing Offset, ticks (0 for other actuators).
    #[serde(default)]
    pub homing_offset_ticks: i32,
}

impl JointCalibration {
    /// The actuator's physical angle at joint zero, rad: the zero with the Homing Offset (which
    /// only shifts what a Dynamixel reports) taken out.
    pub fn physical_zero(&self) -> f64 {
        physical_zero(self.zero_offset, self.homing_offset_ticks)
    }
}

/// `zero_offset` with a Dynamixel Homing Offset of `homing_ticks` taken out, rad.
pub fn physical_zero(zero_offset: f64, homing_ticks: i32) -> f64 {
    zero_offset - f64::from(homing_ticks) * firmware_bridge::dxl::models::rad_per_tick()
}

/// The IMU's measured mounting and bias.
#[derive(Debug, Clone, Copy, PartialEq, serde::Deserialize, schemars::JsonSchema, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct ImuCalibration {
    /// Rotation from the IMU's axes to the site's axes, roll/pitch/yaw in degrees.
    pub mounting_rpy_deg: [f64; 3],
    /// Gyro bias to subtract, rad/s.
    pub gyro_bias: [f64; 3],
    /// Accelerometer bias to subtract, m/s².
    #[serde(default)]
    pub accel_bias: [f64; 3],
}

/// A calibration file.
#[derive(Debug, Clone, Default, PartialEq, serde::Deserialize, schemars::JsonSchema, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct Calibration {
    /// When and how it was made (free text).
    #[serde(default)]
    pub note: String,
    /// Per joint, by robot.toml name.
    #[serde(default)]
    pub joints: BTreeMap<String, JointCalibration>,
    /// The IMU.
    #[serde(default)]
    pub imu: Option<ImuCalibration>,
}

/// Where a robot's calibration lives: `calibration.toml` beside its robot.toml.
pub fn path_for(robot_toml: &Path) -> PathBuf {
    robot_toml.with_file_name("calibration.toml")
}

/// Where the previous calibration is kept when a new one is written.
pub fn previous_path_for(robot_toml: &Path) -> PathBuf {
    robot_toml.with_file_name("calibration.previous.toml")
}

impl Calibration {
    /// Reads `path`; a missing file is no calibration (`Ok(None)`).
    pub fn read(path: &Path) -> Result<Option<Self>, FileError> {
        if path.exists() {
            crate::check_regular_file(path).map_err(|m| FileError::new(path, m))?;
        }
        match std::fs::read_to_string(path) {
            Ok(text) => toml::from_str(&text)
                .map(Some)
                .map_err(|e| FileError::new(path, e.message())),
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(None),
            Err(e) => Err(FileError::new(path, format!("cannot read: {e}"))),
        }
    }

    /// Writes beside `robot_toml`: the old file becomes `calibration.previous.toml`, the new one
    /// is written to a temporary file first and renamed into place.
    pub fn write_beside(&self, robot_toml: &Path) -> Result<PathBuf, FileError> {
        let path = path_for(robot_toml);
        let text = toml::to_string_pretty(self).map_err(|e| FileError::new(&path, e.to_string()))?;
        let tmp = path.with_extension("toml.partial");
        std::fs::write(&tmp, text).map_err(|e| FileError::new(&tmp, e.to_string()))?;
        if path.exists() {
            let previous = previous_path_for(robot_toml);
            std::fs::copy(&path, &previous).map_err(|e| {
                FileError::new(&path, format!("cannot keep it as {}: {e}", previous.display()))
            })?;
        }
        std::fs::rename(&tmp, &path).map_err(|e| FileError::new(&path, e.to_string()))?;
        Ok(path)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scratch(name: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("robots-cal-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let src = crate::reference_robot_path();
        for file in ["robot.toml", "biped.xml"] {
            std::fs::copy(src.with_file_name(file), dir.join(file)).unwrap();
        }
        dir.join("robot.toml")
    }

    #[test]
    fn a_written_calibration_is_merged_and_the_previous_one_kept() {
        let robot_toml = scratch("merge");
        let mut c = Calibration::default();
        c.joints.insert(
            "left_knee".into(),
            JointCalibration {
                zero_offset: 0.25,
                direction: -1.0,
                homing_offset_ticks: 0,
            },
        );
        c.write_beside(&robot_toml).unwrap();
        assert!(!previous_path_for(&robot_toml).exists());
        let robot = crate::Robot::load(&robot_toml).unwrap();
        let knee = robot
            .config
            .joints
            .iter()
            .find(|j| j.name == "left_knee")
            .unwrap();
        assert_eq!((knee.zero_offset, knee.direction), (0.25, -1.0));
        let first = std::fs::read_to_string(path_for(&robot_toml)).unwrap();
        c.note = "second".into();
        c.write_beside(&robot_toml).unwrap();
        assert_eq!(
            std::fs::read_to_string(previous_path_for(&robot_toml)).unwrap(),
            first
        );
        let _ = std::fs::remove_dir_all(robot_toml.parent().unwrap());
    }

    #[test]
    fn a_bad_calibration_file_is_refused_with_its_place() {
        let robot_toml = scratch("bad");
        std::fs::write(
            path_for(&robot_toml),
            "[joints.tail]\nzero_offset = 0.1\ndirection = 1.0\n",
        )
        .unwrap();
        let e = crate::Robot::load(&robot_toml).unwrap_err().to_string();
        assert!(e.contains("calibration.toml") && e.contains("joints.tail"), "{e}");
        std::fs::write(path_for(&robot_toml), "[joints.left_knee]\nzero_offset = \"x\"\n").unwrap();
        let e = crate::Robot::load(&robot_toml).unwrap_err().to_string();
        assert!(e.contains("calibration.toml"), "{e}");
        let _ = std::fs::remove_dir_all(robot_toml.parent().unwrap());
    }
}
