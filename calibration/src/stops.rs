//! Zero and direction from the mechanical stops: each joint in turn is driven slowly, at low
//! stiffness and with its torque capped, onto both stops, while the others hold still. The
//! middle between the stops is the middle of the model's range; the direction comes from the
//! operator (encoders alone cannot tell a reversed motor from a reversed joint). The stops are
//! the only place the joint goes past its soft limits, at the capped torque.

use std::time::Duration;

use crate::log::MotionLimits;
use crate::operator::{Operator, Request};
use crate::procedure::{CalibrationError, JointResult, Session, capped_step};
use robot_link::JointTarget;

use crate::rig::Rig;
use crate::solve::JointMapping;

/// How gently the stops are found.
#[derive(Debug, Clone, PartialEq)]
pub struct StopOptions {
    /// Fraction of robot.toml's stiffness and damping.
    pub gain_fraction: f64,
    /// Fraction of each joint's torque limit a command may ask for.
    pub torque_fraction: f64,
    /// Joint speed, rad/s.
    pub speed: f64,
    /// The span between the stops vs the model's range, relative.
    pub span_tolerance: f64,
    /// Stalled this long at the torque cap = on the stop.
    pub stall: Duration,
}

impl Default for StopOptions {
    fn default() -> Self {
        Self {
            gain_fraction: 0.3,
            torque_fraction: 0.3,
            speed: 0.5,
            span_tolerance: 0.05,
            stall: Duration::from_millis(300),
        }
    }
}

impl StopOptions {
    /// Limits and gains in actuator units for a raw rig of `robot` (see [`crate::raw_robot`]):
    /// stiffness through the gear squared, torque and speed through the gear.
    pub fn actuator_limits(&self, robot: &robots::Robot) -> (MotionLimits, Vec<(f64, f64)>) {
        let joints = &robot.config.joints;
        let gains = joints
            .iter()
            .map(|j| {
                let g2 = j.gear * j.gear;
                (self.gain_fraction * j.kp / g2, self.gain_fraction * j.kd / g2)
            })
            .collect();
        let limits = MotionLimits {
            torque: joints
                .iter()
                .map(|j| self.torque_fraction * j.torque_limit / j.gear)
                .collect(),
            speed: joints.iter().map(|j| self.speed * j.gear).collect(),
        };
        (limits, gains)
    }

    /// `robot` with stiffness and damping scaled down: servos that take their gains at
    /// configuration (Dynamixel) then run at the gains the commands assume.
    pub fn low_gain_robot(&self, robot: &robots::Robot) -> robots::Robot {
        let mut r = robot.clone();
        for j in &mut r.config.joints {
            j.kp *= self.gain_fraction;
            j.kd *= self.gain_fraction;
        }
        r
    }
}

impl<R: Rig + ?Sized, O: Operator + ?Sized> Session<'_, R, O> {
    /// Step 2 (stops): each selected joint onto both stops and back. The rig must be a raw rig
    /// of [`StopOptions::low_gain_robot`].
    pub fn joints_from_stops(&mut self, options: &StopOptions) -> Result<Vec<JointResult>, CalibrationError> {
        self.operator.request(Request::Confirm {
            what: &format!(
                "Step 2/3 joints: robot hanging free on its stand; each joint in turn moves at \
                 {:.2} rad/s with ≤ {:.0} % of its torque limit onto both mechanical stops, the others \
                 holding still; you say which way it turned",
                options.speed,
                options.torque_fraction * 100.0
            ),
        })?;
        let (limits, gains) = options.actuator_limits(self.robot);
        let mut results = Vec::new();
        for j in 0..self.robot.config.joints.len() {
            if self.selected[j] {
                let mapping = self.find_stops(j, options, &limits, &gains)?;
                results.push(self.result_for(j, mapping)?);
            }
        }
        self.report_joints(&results);
        Ok(results)
    }

    fn find_stops(
        &mut self,
        j: usize,
        options: &StopOptions,
        limits: &MotionLimits,
        gains: &[(f64, f64)],
    ) -> Result<JointMapping, CalibrationError> {
        let joint = self.robot.config.joints[j].clone();
        let fail = |message: String| CalibrationError::Joint {
            joint: joint.name.clone(),
            message,
        };
        self.tick("stops", None)?;
        let start = self.sample.q.clone();
        self.operator.request(Request::Watch {
            index: j,
            joint: &joint.name,
        })?;
        let high = self.sweep(j, 1.0, &start, options, limits, gains)?;
        let direction = self.operator.direction_seen(j, &joint.name)?;
        let low = self.sweep(j, -1.0, &start, options, limits, gains)?;
        // Back to where it hung, then limp for the next joint.
        self.move_to("stops", &start, gains, limits, Duration::from_millis(200))?;
        let [qmin, qmax] = self.robot.mjcf_range(j).unwrap_or(joint.position_limits);
        let expected = joint.gear * (qmax - qmin);
        let span = high - low;
        if ((span - expected) / expected).abs() > options.span_tolerance {
            return Err(fail(format!(
                "the stops are {span:.3} rad apart on the actuator, the model's range needs {expected:.3}: \
                 something stopped the joint early (gravity beyond the torque cap, a cable, the \
                 stand), or the gear is wrong"
            )));
        }
        // The middle of the stops is the middle of the range: the joints press each stop equally
        // hard, so what they sink into the stops cancels.
        Ok(JointMapping {
            direction,
            zero: (high + low) / 2.0 - direction * joint.gear * (qmin + qmax) / 2.0,
        })
    }

    /// Drives joint `j` towards `sign` until it stalls at the torque cap; the others hold `hold`.
    /// Returns where it stalled (actuator rad).
    fn sweep(
        &mut self,
        j: usize,
        sign: f64,
        hold: &[f64],
        options: &StopOptions,
        limits: &MotionLimits,
        gains: &[(f64, f64)],
    ) -> Result<f64, CalibrationError> {
        let dt = self.rig.period().as_secs_f64();
        let joint = &self.robot.config.joints[j];
        let span = self
            .robot
            .mjcf_range(j)
            .map_or(2.0 * std::f64::consts::PI, |[a, b]| b - a)
            * joint.gear;
        let max_ticks =
            ((1.5 * span / limits.speed[j]) / dt) as usize + self.ticks_in(Duration::from_secs(3));
        let stall_ticks = self.ticks_in(options.stall).max(1);
        let mut target = self.move_start("stops")?;
        let mut cmd = vec![JointTarget::default(); target.len()];
        let mut stalled = 0;
        for _ in 0..max_ticks {
            self.check_feedback()?;
            for k in 0..target.len() {
                let goal = if k == j {
                    target[k] + sign * limits.speed[k] * dt
                } else {
                    hold[k]
                };
                cmd[k] = capped_step(target[k], goal, &self.sample, k, gains[k], limits, dt);
                target[k] = cmd[k].q;
            }
            // At the cap the target cannot lead further: the joint is pushing on something.
            let (kp, kd) = gains[j];
            let lead = sign * (target[j] - self.sample.q[j]);
            let pressing = kp * lead - sign * kd * self.sample.qd[j] > 0.9 * limits.torque[j];
            self.tick("stops", Some(&cmd))?;
            let slow = self.sample.qd[j].abs() < 0.05 * limits.speed[j];
            stalled = if pressing && slow { stalled + 1 } else { 0 };
            if stalled >= stall_ticks {
                return Ok(self.sample.q[j]);
            }
        }
        Err(CalibrationError::Joint {
            joint: joint.name.clone(),
            message: format!("found no stop within {:.1} rad of travel", 1.5 * span),
        })
    }
}
