//! Every tick of a calibration, as sent and as measured: written as CSV beside the results, so the
//! limits can be checked after the fact by anyone.

use std::fmt::Write as _;
use std::path::Path;

use std::time::Duration;

use robot_link::{JointTarget, RobotState};

/// The motion limits of a calibration, per joint in the rig's units.
#[derive(Debug, Clone, PartialEq)]
pub struct MotionLimits {
    /// Largest torque a command may ask for (PD law on the measured state), N·m.
    pub torque: Vec<f64>,
    /// Largest speed of a commanded target, rad/s.
    pub speed: Vec<f64>,
}

/// One tick: what was measured before the command, and the command.
#[derive(Debug, Clone, PartialEq)]
struct Row {
    t: f64,
    step: &'static str,
    q: Vec<f64>,
    qd: Vec<f64>,
    targets: Option<Vec<JointTarget>>,
}

/// The first command of a log beyond the motion limits: when, which joint, by how much.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{0}")]
pub struct LimitViolation(pub String);

/// The ticks of a calibration.
#[derive(Debug, Clone, Default)]
pub struct CommandLog {
    joints: Vec<String>,
    rows: Vec<Row>,
}

impl CommandLog {
    /// A log for these joints.
    pub fn new(joints: Vec<String>) -> Self {
        Self {
            joints,
            rows: Vec::new(),
        }
    }

    /// Records a tick: the state the command was computed from, and the command (`None`: limp).
    pub fn record(
        &mut self,
        step: &'static str,
        t: Duration,
        state: &RobotState,
        targets: Option<&[JointTarget]>,
    ) {
        self.rows.push(Row {
            t: t.as_secs_f64(),
            step,
            q: state.q.clone(),
            qd: state.qd.clone(),
            targets: targets.map(<[JointTarget]>::to_vec),
        });
    }

    /// Ticks recorded.
    pub fn len(&self) -> usize {
        self.rows.len()
    }

    /// No ticks recorded.
    pub fn is_empty(&self) -> bool {
        self.rows.is_empty()
    }

    /// The first command beyond `limits`, if any: the torque its PD law asks for on the state it
    /// was computed from, and the speed of its target against the previous one.
    pub fn check(&self, limits: &MotionLimits, period: f64) -> Result<(), LimitViolation> {
        let mut previous: Option<&[JointTarget]> = None;
        for row in &self.rows {
            let Some(targets) = &row.targets else {
                previous = None;
                continue;
            };
            for (j, t) in targets.iter().enumerate() {
                let torque = t.kp * (t.q - row.q[j]) - t.kd * row.qd[j];
                if torque.abs() > limits.torque[j] * (1.0 + 1e-9) {
                    return Err(LimitViolation(format!(
                        "t = {:.3} s ({}): {} asked for {torque:.3} N·m, limit {:.3}",
                        row.t, row.step, self.joints[j], limits.torque[j]
                    )));
                }
                if let Some(p) = previous {
                    let speed = (t.q - p[j].q).abs() / period;
                    if speed > limits.speed[j] * (1.0 + 1e-9) {
                        return Err(LimitViolation(format!(
                            "t = {:.3} s ({}): {} target moved at {speed:.3} rad/s, limit {:.3}",
                            row.t, row.step, self.joints[j], limits.speed[j]
                        )));
                    }
                }
            }
            previous = Some(targets);
        }
        Ok(())
    }

    /// Writes the log as CSV: `t,step,joint,q,qd,target,kp,kd` (target, kp, kd empty when limp).
    pub fn write_csv(&self, path: &Path) -> Result<(), robots::FileError> {
        let mut out = String::from("t,step,joint,q,qd,target,kp,kd\n");
        for row in &self.rows {
            for (j, name) in self.joints.iter().enumerate() {
                let _ = write!(
                    out,
                    "{:.4},{},{name},{:.6},{:.6},",
                    row.t, row.step, row.q[j], row.qd[j]
                );
                match &row.targets {
                    Some(t) => {
                        let _ = writeln!(out, "{:.6},{:.4},{:.4}", t[j].q, t[j].kp, t[j].kd);
                    }
                    None => out.push_str(",,\n"),
                }
            }
        }
        if let Some(dir) = path.parent() {
            std::fs::create_dir_all(dir).map_err(|e| robots::FileError::new(dir, e.to_string()))?;
        }
        std::fs::write(path, out).map_err(|e| robots::FileError::new(path, e.to_string()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample(q: f64) -> RobotState {
        let mut s = RobotState::new(1);
        s.q[0] = q;
        s.qd[0] = 0.0;
        s
    }

    #[test]
    fn commands_beyond_the_limits_are_found() {
        let limits = MotionLimits {
            torque: vec![1.0],
            speed: vec![0.5],
        };
        let mut log = CommandLog::new(vec!["knee".into()]);
        let t = |q| JointTarget {
            q,
            kp: 10.0,
            enabled: true,
            ..JointTarget::default()
        };
        log.record("move", Duration::ZERO, &sample(0.0), Some(&[t(0.05)]));
        log.record("move", Duration::ZERO, &sample(0.0), Some(&[t(0.06)]));
        log.record("hold", Duration::ZERO, &sample(0.0), None);
        assert!(log.check(&limits, 0.02).is_ok());
        log.record("move", Duration::ZERO, &sample(0.0), Some(&[t(0.2)]));
        assert!(log.check(&limits, 0.02).unwrap_err().0.contains("2.000 N·m"));
        let mut fast = CommandLog::new(vec!["knee".into()]);
        fast.record("move", Duration::ZERO, &sample(0.0), Some(&[t(0.0)]));
        fast.record("move", Duration::ZERO, &sample(0.0), Some(&[t(0.02)]));
        assert!(fast.check(&limits, 0.02).unwrap_err().0.contains("1.000 rad/s"));
    }
}
