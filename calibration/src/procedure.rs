//! The guided calibration: identity check, joint zero and direction from two jig settings (torque
//! off throughout), IMU gyro bias, gravity check and mounting from two static poses. Every step is
//! announced and confirmed; an abort (the operator, or the `abort` flag at any tick) puts the robot
//! into damping and returns without a result, so nothing is written.

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use firmware_bridge::dxl::models as dxl_models;
use robots::calibration::{Calibration, ImuCalibration, JointCalibration};
use robots::{BusKind, Robot, spatial};

use crate::log::CommandLog;
use crate::operator::{Aborted, Operator, Request};
use robot_link::{DeviceIdentity, JointTarget, RobotState};

use crate::rig::{Rig, RigError};
use crate::solve::{self, JointMapping};

/// Standard gravity, m/s².
pub const GRAVITY: f64 = 9.806_65;

/// How the procedure runs.
#[derive(Debug, Clone, PartialEq)]
pub struct Options {
    /// How far the second jig setting turns each joint from the first, rad.
    pub jig_step: f64,
    /// Kept between a jig setting and the joint's limits, rad.
    pub limit_margin: f64,
    /// Wait after each new pose before measuring.
    pub settle: Duration,
    /// Averaging window per pose.
    pub average: Duration,
    /// Still period for the gyro bias and the gravity check.
    pub imu_still: Duration,
    /// Forward tilt of the second IMU pose, deg.
    pub imu_tilt_deg: f64,
    /// Measured ratio vs gear, relative.
    pub gear_tolerance: f64,
    /// |measured gravity| vs standard, relative (uncalibrated accelerometers are off by up to
    /// ~0.05 g per axis).
    pub gravity_tolerance: f64,
    /// Largest angle between the accelerometer's and the AHRS's vertical, deg.
    pub gravity_direction_deg: f64,
}

impl Default for Options {
    fn default() -> Self {
        Self {
            jig_step: 0.15,
            limit_margin: 0.05,
            settle: Duration::from_millis(500),
            average: Duration::from_millis(500),
            imu_still: Duration::from_secs(2),
            imu_tilt_deg: 30.0,
            gear_tolerance: 0.1,
            gravity_tolerance: 0.1,
            gravity_direction_deg: 6.0,
        }
    }
}

/// Why calibration stopped without a result.
#[derive(Debug, thiserror::Error)]
pub enum CalibrationError {
    /// The operator or the abort flag stopped it; the robot was put into damping.
    #[error("aborted: the robot was put into damping and nothing was written")]
    Aborted,
    /// The robot's buses failed.
    #[error(transparent)]
    Rig(#[from] RigError),
    /// A joint could not be calibrated.
    #[error("{joint}: {message}")]
    Joint {
        /// The joint.
        joint: String,
        /// What went wrong.
        message: String,
    },
    /// The IMU could not be calibrated.
    #[error("IMU: {0}")]
    Imu(String),
    /// The results could not be saved.
    #[error("cannot save the calibration: {0}")]
    Save(robots::FileError),
}

impl From<robots::FileError> for CalibrationError {
    fn from(e: robots::FileError) -> Self {
        Self::Save(e)
    }
}

impl From<Aborted> for CalibrationError {
    fn from(_: Aborted) -> Self {
        Self::Aborted
    }
}

/// A joint's result.
#[derive(Debug, Clone, PartialEq)]
pub struct JointResult {
    /// Joint name.
    pub name: String,
    /// Measured mapping (Homing Offset included for Dynamixel joints).
    pub calibration: JointCalibration,
    /// What robot.toml (or the previous calibration) said.
    pub before: JointCalibration,
}

/// The IMU's result.
#[derive(Debug, Clone, PartialEq)]
pub struct ImuResult {
    /// Mounting and gyro bias.
    pub calibration: ImuCalibration,
    /// |mean specific force| while still, m/s².
    pub gravity: f64,
    /// Gyro noise while still (standard deviation, largest axis), rad/s.
    pub gyro_noise: f64,
    /// Tilt between the two poses as measured, deg.
    pub tilt_deg: f64,
}

/// What a calibration found.
#[derive(Debug, Clone, PartialEq)]
pub struct Outcome {
    /// Who answered.
    pub identities: Vec<DeviceIdentity>,
    /// The joints calibrated, robot order.
    pub joints: Vec<JointResult>,
    /// The IMU, when it was calibrated.
    pub imu: Option<ImuResult>,
}

impl Outcome {
    /// The calibration file's content: what this run measured over what `previous` held.
    pub fn calibration(&self, note: &str, previous: Option<Calibration>) -> Calibration {
        let mut c = previous.unwrap_or_default();
        c.note = note.to_owned();
        for j in &self.joints {
            c.joints.insert(j.name.clone(), j.calibration);
        }
        if let Some(imu) = &self.imu {
            c.imu = Some(imu.calibration);
        }
        c
    }
}

/// How joints find their zero and direction.
#[derive(Debug, Clone, PartialEq)]
pub enum Method {
    /// Two jig settings, torque off throughout.
    Jig,
    /// Each joint driven slowly onto both its mechanical stops at low torque; the operator says
    /// which way it turned.
    Stops(crate::stops::StopOptions),
}

/// What a run calibrates.
#[derive(Debug, Clone, PartialEq)]
pub struct Plan {
    /// How.
    pub method: Method,
    /// Only these joints (by name), and no IMU; `None`: every joint and the IMU.
    pub joints: Option<Vec<String>>,
}

impl Default for Plan {
    fn default() -> Self {
        Self {
            method: Method::Jig,
            joints: None,
        }
    }
}

/// The robot as a raw rig sees it: every joint in actuator units (direction +1, zero 0, gear 1, no
/// Homing Offset) and the IMU in its own axes without bias correction. Calibration measures on
/// this, so nothing it finds depends on what robot.toml guessed.
pub fn raw_robot(robot: &Robot) -> Robot {
    let mut raw = robot.clone();
    for j in &mut raw.config.joints {
        j.direction = 1.0;
        j.zero_offset = 0.0;
        j.gear = 1.0;
        j.homing_offset_ticks = 0;
    }
    raw.config.imu.mounting_rpy_deg = [0.0; 3];
    raw.config.imu.gyro_bias = [0.0; 3];
    raw.config.imu.accel_bias = [0.0; 3];
    raw
}

/// One run of the procedure.
#[derive(Debug)]
pub struct Session<'a, R: ?Sized, O: ?Sized> {
    pub(crate) robot: &'a Robot,
    pub(crate) rig: &'a mut R,
    pub(crate) operator: &'a mut O,
    pub(crate) abort: &'a AtomicBool,
    /// Every tick, as sent and measured.
    pub log: CommandLog,
    pub(crate) sample: RobotState,
    /// Time of [`Self::sample`] since the rig started.
    pub(crate) sample_time: Duration,
    pub(crate) options: Options,
    /// The joints this run calibrates.
    pub(crate) selected: Vec<bool>,
    /// The targets of the last tick, if it commanded any: the next move starts from them.
    pub(crate) last_targets: Option<Vec<f64>>,
}

/// Means over a still window.
#[derive(Debug, Clone, PartialEq)]
pub struct Window {
    /// Joint positions, rad.
    pub q: Vec<f64>,
    /// Angular velocity, rad/s.
    pub gyro: [f64; 3],
    gyro_sq: [f64; 3],
    /// Specific force, m/s².
    pub accel: [f64; 3],
    /// "Up" in the IMU's axes by the AHRS's attitude (unit length after the window).
    pub up: [f64; 3],
    /// Fresh IMU samples in the window.
    pub imu_samples: usize,
    ticks: usize,
}

impl Window {
    fn new(n: usize) -> Self {
        Self {
            q: vec![0.0; n],
            gyro: [0.0; 3],
            gyro_sq: [0.0; 3],
            accel: [0.0; 3],
            up: [0.0; 3],
            imu_samples: 0,
            ticks: 0,
        }
    }

    fn add(&mut self, s: &RobotState) {
        self.ticks += 1;
        for (m, q) in self.q.iter_mut().zip(&s.q) {
            *m += q;
        }
        if s.imu_missed == 0 {
            self.imu_samples += 1;
            for i in 0..3 {
                self.gyro[i] += s.gyro[i];
                self.gyro_sq[i] += s.gyro[i] * s.gyro[i];
                self.accel[i] += s.accel[i];
            }
            // The AHRS's world z in its own axes: Rᵀ·ẑ of its attitude quaternion.
            let [w, x, y, z] = s.quat;
            let up = [
                2.0 * (x * z - w * y),
                2.0 * (y * z + w * x),
                1.0 - 2.0 * (x * x + y * y),
            ];
            for (sum, u) in self.up.iter_mut().zip(up) {
                *sum += u;
            }
        }
    }

    fn finish(&mut self) {
        let t = self.ticks.max(1) as f64;
        self.q.iter_mut().for_each(|q| *q /= t);
        let k = self.imu_samples.max(1) as f64;
        for i in 0..3 {
            self.gyro[i] /= k;
            self.gyro_sq[i] /= k;
            self.accel[i] /= k;
        }
        if self.imu_samples > 0 {
            self.up = spatial::unit(self.up);
        }
    }

    /// Gyro standard deviation, largest axis, rad/s.
    pub fn gyro_noise(&self) -> f64 {
        (0..3)
            .map(|i| (self.gyro_sq[i] - self.gyro[i] * self.gyro[i]).max(0.0).sqrt())
            .fold(0.0, f64::max)
    }
}

impl<'a, R: Rig + ?Sized, O: Operator + ?Sized> Session<'a, R, O> {
    /// A session on `rig` (built from [`raw_robot`] for [`Self::calibrate`]).
    pub fn new(
        robot: &'a Robot,
        rig: &'a mut R,
        operator: &'a mut O,
        abort: &'a AtomicBool,
        options: Options,
    ) -> Self {
        let n = robot.config.joints.len();
        Self {
            robot,
            rig,
            operator,
            abort,
            log: CommandLog::new(robot.config.joints.iter().map(|j| j.name.clone()).collect()),
            sample: RobotState::new(n),
            sample_time: Duration::ZERO,
            options,
            selected: vec![true; n],
            last_targets: None,
        }
    }

    /// The last reading.
    pub fn sample(&self) -> &RobotState {
        &self.sample
    }

    /// Runs every step of `plan`. On any error after the identity check the robot is put into
    /// damping.
    pub fn calibrate(&mut self, plan: &Plan) -> Result<Outcome, CalibrationError> {
        if let Some(names) = &plan.joints {
            let joints = &self.robot.config.joints;
            if let Some(unknown) = names.iter().find(|n| !joints.iter().any(|j| &j.name == *n)) {
                return Err(CalibrationError::Joint {
                    joint: unknown.clone(),
                    message: format!("not a joint of {}", self.robot.config.name),
                });
            }
            self.selected = joints.iter().map(|j| names.contains(&j.name)).collect();
        }
        let identities = self.identify()?;
        let result = self.joints_and_imu(plan);
        if result.is_err() {
            self.rig.damp()?;
        }
        let (joints, imu) = result?;
        Ok(Outcome {
            identities,
            joints,
            imu,
        })
    }

    fn joints_and_imu(
        &mut self,
        plan: &Plan,
    ) -> Result<(Vec<JointResult>, Option<ImuResult>), CalibrationError> {
        let joints = match &plan.method {
            Method::Jig => self.joints_from_jig()?,
            Method::Stops(options) => self.joints_from_stops(options)?,
        };
        let imu = match plan.joints {
            None => Some(self.imu(matches!(plan.method, Method::Jig))?),
            Some(_) => None,
        };
        self.operator.request(Request::ReleaseJig)?;
        self.ticks("release", 5, None)?;
        Ok((joints, imu))
    }

    /// Step 1: every device answers with its configured model; torque stays off.
    pub fn identify(&mut self) -> Result<Vec<DeviceIdentity>, CalibrationError> {
        // Nothing moves and no torque is on: asked of nobody, so it runs without a terminal too.
        self.operator
            .say("Step 1/3 identity: ping every device, read model, firmware and current limit (no torque)");
        let ids = self.rig.identify()?;
        self.operator.say(&format!(
            "  {:<20} {:<5} {:>3}  {:<11} {:<34} {:>5} {:>9} {:>9}",
            "joint", "bus", "id", "model", "answer", "fw", "I lim A", "τ lim N·m"
        ));
        for d in &ids {
            self.operator.say(&format!(
                "  {:<20} {:<5} {:>3}  {:<11} {:<34} {:>5} {:>9} {:>9.1}",
                d.joint,
                d.bus,
                d.id,
                d.model,
                d.answer,
                d.firmware.map_or("-".into(), |f| f.to_string()),
                d.current_limit_a.map_or("-".into(), |a| format!("{a:.2}")),
                d.torque_limit_nm
            ));
        }
        Ok(ids)
    }

    /// Runs `count` ticks sending `targets` (limp when `None`).
    fn ticks(
        &mut self,
        step: &'static str,
        count: usize,
        targets: Option<&[JointTarget]>,
    ) -> Result<(), CalibrationError> {
        for _ in 0..count {
            self.tick(step, targets)?;
        }
        Ok(())
    }

    pub(crate) fn tick(
        &mut self,
        step: &'static str,
        targets: Option<&[JointTarget]>,
    ) -> Result<(), CalibrationError> {
        if self.abort.load(Ordering::Relaxed) {
            return Err(CalibrationError::Aborted);
        }
        self.log.record(step, self.sample_time, &self.sample, targets);
        self.last_targets = targets.map(|t| t.iter().map(|t| t.q).collect());
        self.sample_time = self.rig.tick(targets, &mut self.sample)?;
        Ok(())
    }

    /// Where a move starts: the last commanded targets, or (after a limp tick) where the joints are.
    pub(crate) fn move_start(&mut self, step: &'static str) -> Result<Vec<f64>, CalibrationError> {
        match self.last_targets.clone() {
            Some(t) => Ok(t),
            None => {
                self.tick(step, None)?;
                Ok(self.sample.q.clone())
            }
        }
    }

    pub(crate) fn ticks_in(&self, d: Duration) -> usize {
        (d.as_secs_f64() / self.rig.period().as_secs_f64()).ceil() as usize
    }

    /// Waits `settle`, then averages joints and IMU over `window` (all limp).
    fn measure(&mut self, step: &'static str, window: Duration) -> Result<Window, CalibrationError> {
        let settle = self.ticks_in(self.options.settle);
        self.ticks(step, settle, None)?;
        let mut w = Window::new(self.robot.config.joints.len());
        let count = self.ticks_in(window).max(1);
        for k in 0..count {
            self.tick(step, None)?;
            self.operator.progress(step, (k + 1) as f64 / count as f64);
            self.check_feedback()?;
            w.add(&self.sample);
        }
        w.finish();
        Ok(w)
    }

    pub(crate) fn check_feedback(&self) -> Result<(), CalibrationError> {
        for (j, joint) in self.robot.config.joints.iter().enumerate() {
            if self.sample.missed[j] > 2 {
                return Err(CalibrationError::Joint {
                    joint: joint.name.clone(),
                    message: format!("no feedback for {} ticks", self.sample.missed[j]),
                });
            }
            if self.sample.faulted[j] {
                return Err(CalibrationError::Joint {
                    joint: joint.name.clone(),
                    message: "the device reports a fault".into(),
                });
            }
        }
        Ok(())
    }

    /// The two jig settings: A = the default pose, B = A turned by `jig_step` per joint (away from
    /// the nearer limit).
    pub fn jig_settings(&self) -> [Vec<f64>; 2] {
        let joints = &self.robot.config.joints;
        let a: Vec<f64> = joints.iter().map(|j| j.default_position).collect();
        let b = joints
            .iter()
            .zip(&self.selected)
            .map(|(j, &selected)| {
                if !selected {
                    return j.default_position;
                }
                let [lo, hi] = j.position_limits;
                let (step, margin) = (self.options.jig_step, self.options.limit_margin);
                let up = j.default_position + step;
                if up <= hi - margin {
                    up
                } else {
                    (j.default_position - step).max(lo + margin)
                }
            })
            .collect();
        [a, b]
    }

    /// Step 2: directions and zeros from two jig settings, torque off on every joint.
    pub fn joints_from_jig(&mut self) -> Result<Vec<JointResult>, CalibrationError> {
        self.operator.request(Request::Confirm {
            what: "Step 2/3 joints: torque stays OFF; clamp the robot in jig setting A, then B; \
                   each joint's encoder is read in both",
        })?;
        let names: Vec<String> = self.robot.config.joints.iter().map(|j| j.name.clone()).collect();
        let settings = self.jig_settings();
        let mut theta = [Vec::new(), Vec::new()];
        for (k, (label, pose)) in ["A", "B"].iter().zip(&settings).enumerate() {
            self.operator.request(Request::ClampJig {
                label,
                joints: &names,
                pose,
            })?;
            theta[k] = self.measure("jig", self.options.average)?.q;
        }
        let mut results = Vec::new();
        for (j, joint) in self.robot.config.joints.iter().enumerate() {
            if !self.selected[j] {
                continue;
            }
            let mapping = solve::joint_from_two_poses(
                [settings[0][j], settings[1][j]],
                [theta[0][j], theta[1][j]],
                joint.gear,
                self.options.gear_tolerance,
            )
            .map_err(|solve::SolveError(message)| CalibrationError::Joint {
                joint: joint.name.clone(),
                message,
            })?;
            results.push(self.result_for(j, mapping)?);
        }
        self.report_joints(&results);
        Ok(results)
    }

    /// A joint's result from its measured mapping: Dynamixel joints get the Homing Offset that
    /// keeps the encoder's wrap outside their range; MIT joints must fit the position field.
    pub(crate) fn result_for(
        &self,
        j: usize,
        mapping: JointMapping,
    ) -> Result<JointResult, CalibrationError> {
        let joint = &self.robot.config.joints[j];
        let fail = |solve::SolveError(message)| CalibrationError::Joint {
            joint: joint.name.clone(),
            message,
        };
        let range = self.robot.mjcf_range(j).unwrap_or(joint.position_limits);
        let calibration = match self.robot.bus(&joint.bus).map(|b| b.kind) {
            // Serial servos: a reading shift keeps the range clear of the encoder's wrap.
            Some(kind @ (BusKind::Dynamixel | BusKind::Feetech)) => {
                let (homing, zero) = solve::dynamixel_homing(mapping, range).map_err(fail)?;
                if kind == BusKind::Feetech && homing.abs() > robots::config::FEETECH_HOMING_OFFSET_MAX {
                    return Err(fail(solve::SolveError(format!(
                        "the homing offset it needs, {homing} ticks, is beyond the servo's ±2047"
                    ))));
                }
                JointCalibration {
                    zero_offset: zero,
                    direction: mapping.direction,
                    homing_offset_ticks: homing,
                }
            }
            _ => {
                let p_max = self
                    .robot
                    .mit_model(&joint.model)
                    .map_or(f64::INFINITY, |m| m.p_max);
                solve::check_mit_range(mapping, joint.gear, range, p_max).map_err(fail)?;
                JointCalibration {
                    zero_offset: mapping.zero,
                    direction: mapping.direction,
                    homing_offset_ticks: 0,
                }
            }
        };
        Ok(JointResult {
            name: joint.name.clone(),
            calibration,
            before: JointCalibration {
                zero_offset: joint.zero_offset,
                direction: joint.direction,
                homing_offset_ticks: joint.homing_offset_ticks,
            },
        })
    }

    pub(crate) fn report_joints(&mut self, results: &[JointResult]) {
        self.operator.say(&format!(
            "  {:<20} {:>4} {:>11} {:>8}   (before: {:>4} {:>11} {:>8})",
            "joint", "dir", "zero rad", "homing", "dir", "zero rad", "homing"
        ));
        for r in results {
            let (c, b) = (r.calibration, r.before);
            self.operator.say(&format!(
                "  {:<20} {:>+4.0} {:>11.5} {:>8}   (before: {:>+4.0} {:>11.5} {:>8})",
                r.name,
                c.direction,
                c.zero_offset,
                c.homing_offset_ticks,
                b.direction,
                b.zero_offset,
                b.homing_offset_ticks
            ));
        }
    }

    /// Step 3: gyro bias and gravity from a still period upright, mounting from upright and tilted
    /// forward. With `in_jig` the robot is clamped at setting A, one rigid body on its stand.
    pub fn imu(&mut self, in_jig: bool) -> Result<ImuResult, CalibrationError> {
        let tilt = self.options.imu_tilt_deg;
        self.operator.request(Request::Confirm {
            what: &format!(
                "Step 3/3 IMU: hold the robot still and upright on its stand, then tilted about \
                 {tilt:.0}° forward (nose down); torque stays OFF"
            ),
        })?;
        let settings = self.jig_settings();
        let names: Vec<String> = self.robot.config.joints.iter().map(|j| j.name.clone()).collect();
        if in_jig {
            self.operator.request(Request::ClampJig {
                label: "A",
                joints: &names,
                pose: &settings[0],
            })?;
        }
        self.operator.request(Request::HoldBase {
            label: "upright",
            rpy_deg: [0.0; 3],
        })?;
        let upright = self.measure("imu upright", self.options.imu_still)?;
        self.operator.request(Request::HoldBase {
            label: "tilted forward",
            rpy_deg: [0.0, tilt, 0.0],
        })?;
        let tilted = self.measure("imu tilted", self.options.average.max(Duration::from_secs(1)))?;
        self.operator.request(Request::HoldBase {
            label: "upright",
            rpy_deg: [0.0; 3],
        })?;
        if upright.imu_samples < 10 || tilted.imu_samples < 10 {
            return Err(CalibrationError::Imu(format!(
                "only {} and {} samples arrived while still: is the IMU streaming?",
                upright.imu_samples, tilted.imu_samples
            )));
        }
        // Gravity check: the accelerometer agrees with the AHRS attitude, in size and direction.
        let gravity = spatial::norm(upright.accel);
        let disagreement = spatial::angle_between(upright.accel, upright.up).to_degrees();
        if ((gravity - GRAVITY) / GRAVITY).abs() > self.options.gravity_tolerance
            || disagreement > self.options.gravity_direction_deg
        {
            return Err(CalibrationError::Imu(format!(
                "gravity check: |a| = {gravity:.3} m/s² ({disagreement:.1}° from the AHRS's vertical) \
                 while still, expected {GRAVITY:.3} ± {:.0} % within {}°: accelerometer fault, or \
                 the robot was moving",
                self.options.gravity_tolerance * 100.0,
                self.options.gravity_direction_deg
            )));
        }
        let accel_bias = [0, 1, 2].map(|i| upright.accel[i] - GRAVITY * upright.up[i]);
        let gyro_noise = upright.gyro_noise();
        // Mounting from the attitude's vertical (the fused attitude does not carry the
        // accelerometer's bias).
        let (mounting, tilt_measured) =
            solve::imu_mounting(upright.up, tilted.up).map_err(|e| CalibrationError::Imu(e.0))?;
        let rpy = spatial::rpy_of_mat(&mounting).map(f64::to_degrees);
        let result = ImuResult {
            calibration: ImuCalibration {
                mounting_rpy_deg: rpy,
                gyro_bias: upright.gyro,
                accel_bias,
            },
            gravity,
            gyro_noise,
            tilt_deg: tilt_measured.to_degrees(),
        };
        self.operator.say(&format!(
            "  IMU: |g| = {gravity:.3} m/s², accel bias [{:+.3} {:+.3} {:+.3}] m/s², gyro bias \
             [{:+.4} {:+.4} {:+.4}] rad/s (noise {gyro_noise:.4}), tilt {:.1}°, mounting roll {:.2}° \
             pitch {:.2}° yaw {:.2}°",
            accel_bias[0],
            accel_bias[1],
            accel_bias[2],
            upright.gyro[0],
            upright.gyro[1],
            upright.gyro[2],
            result.tilt_deg,
            rpy[0],
            rpy[1],
            rpy[2]
        ));
        Ok(result)
    }

    /// Moves to `goal` (robot order) within `limits`, starting from where the joints are: the
    /// target advances at most `limits.speed[j]` per second and never leads the measured position by
    /// more than the torque limit allows at the given gains; then holds for `hold` and returns the
    /// means over the hold.
    pub fn move_to(
        &mut self,
        step: &'static str,
        goal: &[f64],
        gains: &[(f64, f64)],
        limits: &crate::log::MotionLimits,
        hold: Duration,
    ) -> Result<Window, CalibrationError> {
        let dt = self.rig.period().as_secs_f64();
        let n = goal.len();
        let mut target = self.move_start(step)?;
        let mut cmd = vec![JointTarget::default(); n];
        let hold_ticks = self.ticks_in(hold).max(1);
        let mut window = Window::new(n);
        let max_ticks = self.ticks_in(Duration::from_secs(60));
        for _ in 0..max_ticks {
            self.check_feedback()?;
            let mut arrived = true;
            for j in 0..n {
                cmd[j] = capped_step(target[j], goal[j], &self.sample, j, gains[j], limits, dt);
                target[j] = cmd[j].q;
                arrived &= (target[j] - goal[j]).abs() < 1e-9;
            }
            self.tick(step, Some(&cmd))?;
            if arrived {
                window.add(&self.sample);
                self.operator
                    .progress(step, window.ticks as f64 / hold_ticks as f64);
                if window.ticks >= hold_ticks {
                    window.finish();
                    return Ok(window);
                }
            }
        }
        Err(CalibrationError::Joint {
            joint: "(all)".into(),
            message: format!("did not reach the pose within 60 s ({step})"),
        })
    }

    /// Puts the robot into damping (the safe end of a verification or an abort).
    pub fn damp(&mut self) -> Result<(), CalibrationError> {
        self.rig.damp()?;
        Ok(())
    }

    /// The operator.
    pub fn operator(&mut self) -> &mut O {
        self.operator
    }
}

/// One tick of a capped move of joint `j` from its last target `previous` towards `goal`: the
/// target moves at most the speed limit, leads the measured position by no more than the torque
/// cap allows (PD law `kp·(target − q) − kd·qd` on the measured state), and where the joint is
/// pushed away faster than the target may follow, the gains of this tick are scaled down instead,
/// so both limits hold for every command.
pub(crate) fn capped_step(
    previous: f64,
    goal: f64,
    state: &RobotState,
    j: usize,
    (kp, kd): (f64, f64),
    limits: &crate::log::MotionLimits,
    dt: f64,
) -> JointTarget {
    let (cap, step_max) = (limits.torque[j], limits.speed[j] * dt);
    let (q, qd) = (state.q[j], state.qd[j]);
    let wanted = previous + (goal - previous).clamp(-step_max, step_max);
    let above = (cap + kd * qd).max(0.0) / kp.max(1e-9);
    let below = (cap - kd * qd).max(0.0) / kp.max(1e-9);
    let target = wanted
        .clamp(q - below, q + above)
        .clamp(previous - step_max, previous + step_max);
    let torque = (kp * (target - q) - kd * qd).abs();
    let scale = if torque > cap { cap / torque } else { 1.0 };
    JointTarget {
        q: target,
        kp: kp * scale,
        kd: kd * scale,
        enabled: true,
        ..JointTarget::default()
    }
}

/// The calibrated joint's mapping, for comparisons.
pub fn mapping_of(c: &JointCalibration) -> JointMapping {
    JointMapping {
        direction: c.direction,
        zero: c.zero_offset,
    }
}

/// Encoder ticks per radian of a Dynamixel servo.
pub fn dxl_ticks_per_rad() -> f64 {
    1.0 / dxl_models::rad_per_tick()
}
