//! `calibrate verify`: with the calibration in place, move the robot (hanging on its stand) to its
//! default pose at low stiffness, low speed and low torque, and report each joint's error against
//! the pose it was sent to, and the base's tilt as the IMU sees it (upright on the stand: 0°).

use std::time::Duration;

use robots::{Robot, spatial};

use crate::log::MotionLimits;
use crate::operator::{Operator, Request};
use crate::procedure::{CalibrationError, Session};
use crate::rig::Rig;

/// How gently verification moves.
#[derive(Debug, Clone, PartialEq)]
pub struct VerifyOptions {
    /// Fraction of robot.toml's stiffness and damping.
    pub gain_fraction: f64,
    /// Fraction of each joint's torque limit a command may ask for.
    pub torque_fraction: f64,
    /// Target speed limit, rad/s.
    pub speed: f64,
    /// Hold at the pose before measuring.
    pub hold: Duration,
}

impl Default for VerifyOptions {
    fn default() -> Self {
        Self {
            gain_fraction: 0.3,
            torque_fraction: 0.25,
            speed: 0.3,
            hold: Duration::from_millis(1500),
        }
    }
}

impl VerifyOptions {
    /// The motion limits for `robot`'s joints.
    pub fn limits(&self, robot: &Robot) -> MotionLimits {
        MotionLimits {
            torque: robot
                .config
                .joints
                .iter()
                .map(|j| self.torque_fraction * j.torque_limit)
                .collect(),
            speed: vec![self.speed; robot.config.joints.len()],
        }
    }

    /// `robot` with its stiffness and damping scaled down: build the verification rig from it, so
    /// servos that take their gains at configuration run at the same low gains.
    pub fn low_gain_robot(&self, robot: &Robot) -> Robot {
        let mut r = robot.clone();
        for j in &mut r.config.joints {
            j.kp *= self.gain_fraction;
            j.kd *= self.gain_fraction;
        }
        r
    }
}

/// One joint at the default pose.
#[derive(Debug, Clone, PartialEq)]
pub struct JointCheck {
    /// Joint name.
    pub name: String,
    /// Where it was sent, rad.
    pub target: f64,
    /// Where its encoder says it is, rad.
    pub measured: f64,
    /// For a joint with a mirror twin (`left_…`/`right_…`): its error minus the twin's mirrored
    /// error, rad. Gravity sag at low stiffness is symmetric; a wrong zero is not.
    pub asymmetry: Option<f64>,
    /// Where it truly is (simulation only), rad.
    pub truth: Option<f64>,
}

impl JointCheck {
    /// Measured minus target, rad.
    pub fn error(&self) -> f64 {
        self.measured - self.target
    }
}

/// What verification found.
#[derive(Debug, Clone, PartialEq)]
pub struct VerifyReport {
    /// Per joint, robot order.
    pub joints: Vec<JointCheck>,
    /// Base tilt from the IMU's gravity direction (upright on the stand: 0), deg.
    pub imu_tilt_deg: f64,
}

/// Runs the verification on `session` (its rig built from [`VerifyOptions::low_gain_robot`] of the
/// calibrated robot): identity check, then the move; ends in damping.
///
/// `truth` is asked for the true joint angles at the end of the hold (the mirror knows them; on
/// hardware it returns `None`).
pub fn verify<R: Rig + ?Sized, O: Operator + ?Sized>(
    session: &mut Session<'_, R, O>,
    robot: &Robot,
    options: &VerifyOptions,
    truth: &mut dyn FnMut() -> Option<Vec<f64>>,
) -> Result<VerifyReport, CalibrationError> {
    let limits = options.limits(robot);
    session.identify()?;
    session.operator().request(Request::Confirm {
        what: &format!(
            "Verify: the robot hangs free on its stand; every joint moves to the default pose at \
             {:.0} % stiffness, ≤ {:.2} rad/s, ≤ {:.0} % of its torque limit, holds, then goes limp",
            options.gain_fraction * 100.0,
            options.speed,
            options.torque_fraction * 100.0
        ),
    })?;
    session.operator().request(Request::ReleaseJig)?;
    session.operator().request(Request::HoldBase {
        label: "upright",
        rpy_deg: [0.0; 3],
    })?;
    let goal: Vec<f64> = robot.config.joints.iter().map(|j| j.default_position).collect();
    let gains: Vec<(f64, f64)> = robot.config.joints.iter().map(|j| (j.kp, j.kd)).collect();
    let window = match session.move_to("verify", &goal, &gains, &limits, options.hold) {
        Ok(w) => w,
        Err(e) => {
            session.damp()?;
            return Err(e);
        }
    };
    let truth = truth();
    session.damp()?;
    let joints = &robot.config.joints;
    let errors: Vec<f64> = joints
        .iter()
        .zip(&window.q)
        .map(|(j, q)| q - j.default_position)
        .collect();
    let joints = joints
        .iter()
        .enumerate()
        .map(|(k, j)| JointCheck {
            name: j.name.clone(),
            target: j.default_position,
            measured: window.q[k],
            asymmetry: twin(robot, k).map(|(t, sign)| errors[k] - sign * errors[t]),
            truth: truth.as_ref().and_then(|t| t.get(k).copied()),
        })
        .collect();
    Ok(VerifyReport {
        joints,
        imu_tilt_deg: spatial::angle_between(window.accel, [0.0, 0.0, 1.0]).to_degrees(),
    })
}

/// The mirror twin of joint `k` (`left_x` ↔ `right_x`) and the sign between their angles:
/// −1 when their defaults or limits are mirrored (roll, yaw), +1 otherwise (pitch).
pub fn twin(robot: &Robot, k: usize) -> Option<(usize, f64)> {
    let joints = &robot.config.joints;
    let name = &joints[k].name;
    let other = if let Some(rest) = name.strip_prefix("left_") {
        format!("right_{rest}")
    } else {
        format!("left_{}", name.strip_prefix("right_")?)
    };
    let t = joints.iter().position(|j| j.name == other)?;
    let (a, b) = (&joints[k], &joints[t]);
    let mirrored = |x: f64, y: f64| (x + y).abs() < 1e-9 && x.abs() > 1e-9;
    let [alo, ahi] = a.position_limits;
    let [blo, bhi] = b.position_limits;
    let limits_mirrored = (alo + bhi).abs() < 1e-9 && (ahi + blo).abs() < 1e-9 && (alo - blo).abs() > 1e-9;
    let sign = if mirrored(a.default_position, b.default_position) || limits_mirrored {
        -1.0
    } else {
        1.0
    };
    Some((t, sign))
}
