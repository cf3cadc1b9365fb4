//! Calibration on the controller's bus drivers: a [`Rig`] over a [`BusRobot`] and its clock (the
//! hardware, or the mirror in lockstep), a console operator, and the run that writes the results.

use std::io::{BufRead, Write as _};
use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;
use std::time::Duration;

use calibration::operator::{Aborted, Operator, Request};
use calibration::procedure::{CalibrationError, Options, Outcome, Plan, Session};
use calibration::rig::{DeviceIdentity, Rig, RigError, Sample, Target};
use firmware_bridge::serial::ByteStream;
use robots::Robot;

use crate::player::TickClock;
use crate::robot_io::{BusRobot, IoError, JointTarget, RobotState};

/// The message of an error and of every error under it.
pub fn error_chain(e: &dyn std::error::Error) -> String {
    let mut s = e.to_string();
    let mut source = e.source();
    while let Some(inner) = source {
        s.push_str(": ");
        s.push_str(&inner.to_string());
        source = inner.source();
    }
    s
}

fn bus_error(e: &IoError) -> RigError {
    RigError::Bus(error_chain(e))
}

/// A calibration rig on the controller's bus drivers.
#[derive(Debug)]
pub struct BusRig<S: ByteStream, C: TickClock> {
    io: BusRobot<S>,
    clock: C,
    period: Duration,
    deadline: Duration,
    state: RobotState,
    targets: Vec<JointTarget>,
    damping: Vec<f64>,
    torque_used: bool,
}

impl<S: ByteStream, C: TickClock> BusRig<S, C> {
    /// A rig for `robot` (the robot `io` was built for) ticking at `period` on `clock`.
    pub fn new(io: BusRobot<S>, clock: C, period: Duration, robot: &Robot) -> Self {
        let n = robot.config.joints.len();
        Self {
            io,
            clock,
            period,
            deadline: Duration::ZERO,
            state: RobotState::new(n),
            targets: vec![JointTarget::default(); n],
            damping: robot.config.joints.iter().map(|j| j.kd).collect(),
            torque_used: false,
        }
    }

    fn exchange(&mut self) -> Result<(), RigError> {
        self.io.write(&self.targets).map_err(|e| bus_error(&e))?;
        self.deadline = self.deadline.max(self.clock.elapsed()) + self.period;
        self.clock.wait_until(self.deadline);
        self.io.read(&mut self.state).map_err(|e| bus_error(&e))
    }
}

impl<S: ByteStream, C: TickClock> Rig for BusRig<S, C> {
    fn period(&self) -> Duration {
        self.period
    }

    fn identify(&mut self) -> Result<Vec<DeviceIdentity>, RigError> {
        self.io
            .identify()
            .map_err(|e| RigError::Identity(error_chain(&e)))?;
        self.io
            .identities()
            .map_err(|e| RigError::Identity(error_chain(&e)))
    }

    fn tick(&mut self, targets: Option<&[Target]>, sample: &mut Sample) -> Result<(), RigError> {
        match targets {
            Some(t) => {
                self.torque_used = true;
                for (out, t) in self.targets.iter_mut().zip(t) {
                    *out = JointTarget {
                        q: t.q,
                        qd: 0.0,
                        kp: t.kp,
                        kd: t.kd,
                        tau: 0.0,
                        enabled: true,
                    };
                }
            }
            None => self.targets.fill(JointTarget::default()),
        }
        self.exchange()?;
        let s = &self.state;
        sample.t = self.clock.elapsed();
        sample.q.copy_from_slice(&s.q);
        sample.qd.copy_from_slice(&s.qd);
        sample.tau.copy_from_slice(&s.tau);
        sample.missed.copy_from_slice(&s.missed);
        sample.faulted.copy_from_slice(&s.faulted);
        sample.gyro = s.gyro;
        sample.accel = s.accel;
        sample.quat = s.quat;
        sample.imu_missed = s.imu_missed;
        Ok(())
    }

    fn damp(&mut self) -> Result<(), RigError> {
        if self.torque_used {
            // Damping for half a second (MIT: kp = 0, kd > 0; servos limp), then torque off.
            for (t, &kd) in self.targets.iter_mut().zip(&self.damping) {
                *t = JointTarget {
                    q: 0.0,
                    qd: 0.0,
                    kp: 0.0,
                    kd,
                    tau: 0.0,
                    enabled: true,
                };
            }
            let ticks = (0.5 / self.period.as_secs_f64()).ceil() as usize;
            for _ in 0..ticks {
                if self.exchange().is_err() {
                    break;
                }
            }
        }
        self.targets.fill(JointTarget::default());
        self.io.torque_off().map_err(|e| bus_error(&e))
    }
}

/// The person at the terminal: each step is explained and confirmed with Enter (`q` aborts);
/// `yes` answers every question (allowed in the mirror only).
#[derive(Debug)]
pub struct ConsoleOperator {
    yes: bool,
    bar: Option<(String, indicatif::ProgressBar)>,
}

impl ConsoleOperator {
    /// A console operator; `yes` confirms everything without asking.
    pub fn new(yes: bool) -> Self {
        Self { yes, bar: None }
    }

    fn ask(&mut self, prompt: &str) -> Result<(), Aborted> {
        self.finish_bar();
        if self.yes {
            println!("{prompt} [--yes]");
            return Ok(());
        }
        print!("{prompt} [Enter: go on, q: abort] ");
        let _ = std::io::stdout().flush();
        let mut line = String::new();
        match std::io::stdin().lock().read_line(&mut line) {
            Ok(n) if n > 0 && !matches!(line.trim(), "q" | "Q" | "n" | "N" | "no" | "abort") => Ok(()),
            _ => Err(Aborted),
        }
    }

    fn finish_bar(&mut self) {
        if let Some((_, bar)) = self.bar.take() {
            bar.finish_and_clear();
        }
    }
}

impl Operator for ConsoleOperator {
    fn request(&mut self, request: Request<'_>) -> Result<(), Aborted> {
        match request {
            Request::Confirm { what } => self.ask(&format!("\n{what}.\nGo ahead?")),
            Request::ClampJig { label, joints, pose } => {
                let mut text = format!("Clamp the robot in jig setting {label}:");
                for (name, q) in joints.iter().zip(pose) {
                    text.push_str(&format!("\n  {name:<20} {:>8.2}°", q.to_degrees()));
                }
                self.ask(&format!("{text}\nEvery joint clamped?"))
            }
            Request::ReleaseJig => self.ask("Take the robot out of the jig; it hangs on its stand. Done?"),
            Request::Watch { joint, .. } => self.ask(&format!(
                "Watch {joint}: it will move slowly under low torque until it rests on its stops. Ready?"
            )),
            Request::HoldBase { label, rpy_deg } => self.ask(&format!(
                "Hold the robot's base still {label} (roll {:.0}°, pitch {:.0}°, yaw {:.0}°). Still?",
                rpy_deg[0], rpy_deg[1], rpy_deg[2]
            )),
        }
    }

    fn direction_seen(&mut self, _index: usize, joint: &str) -> Result<f64, Aborted> {
        self.finish_bar();
        if self.yes {
            // Nobody answers for the person here: only the mirror's hands can see.
            return Err(Aborted);
        }
        loop {
            print!("Did {joint} turn in its positive direction (the model's axis)? [+/-, q: abort] ");
            let _ = std::io::stdout().flush();
            let mut line = String::new();
            match std::io::stdin().lock().read_line(&mut line) {
                Ok(n) if n > 0 => match line.trim() {
                    "+" | "y" | "yes" => return Ok(1.0),
                    "-" | "n" | "no" => return Ok(-1.0),
                    "q" | "abort" => return Err(Aborted),
                    _ => continue,
                },
                _ => return Err(Aborted),
            }
        }
    }

    fn say(&mut self, line: &str) {
        self.finish_bar();
        println!("{line}");
    }

    fn progress(&mut self, step: &str, done: f64) {
        if self.bar.as_ref().is_none_or(|(s, _)| s != step) {
            self.finish_bar();
            let bar = indicatif::ProgressBar::new(100).with_message(step.to_owned());
            bar.set_style(
                indicatif::ProgressStyle::with_template("  {msg:<14} [{bar:30}] {percent:>3}%")
                    .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
            );
            self.bar = Some((step.to_owned(), bar));
        }
        if let Some((_, bar)) = &self.bar {
            bar.set_position((done * 100.0).round() as u64);
        }
    }
}

/// Where a calibration run left its files.
#[derive(Debug, Clone, PartialEq)]
pub struct Written {
    /// The new calibration file.
    pub calibration: PathBuf,
    /// The previous one, if there was one.
    pub previous: Option<PathBuf>,
}

/// The robot a calibration rig for `plan` is built from: actuator units ([`calibration::raw_robot`]),
/// at the low gains the stop method moves with.
pub fn rig_robot(robot: &Robot, plan: &Plan) -> Robot {
    match &plan.method {
        calibration::procedure::Method::Jig => calibration::raw_robot(robot),
        calibration::procedure::Method::Stops(o) => calibration::raw_robot(&o.low_gain_robot(robot)),
    }
}

/// Runs `plan` on `robot` with `rig` (built from [`rig_robot`]) and, only when every step
/// succeeded, writes `calibration.toml` beside robot.toml: this run's results over what the file
/// held (the previous file kept as `calibration.previous.toml`). The tick log goes to `log` in
/// every case.
#[allow(clippy::too_many_arguments)]
pub fn run_calibration<R: Rig + ?Sized, O: Operator + ?Sized>(
    robot: &Robot,
    rig: &mut R,
    operator: &mut O,
    abort: &AtomicBool,
    plan: &Plan,
    options: Options,
    log: Option<&Path>,
    note: &str,
) -> Result<(Outcome, Written), CalibrationError> {
    let mut session = Session::new(robot, rig, operator, abort, options);
    let outcome = session.calibrate(plan);
    if let Some(Err(e)) = log.map(|path| session.log.write_csv(path)) {
        session.operator().say(&format!("cannot write the tick log: {e}"));
    }
    let outcome = outcome?;
    let path = robots::calibration::path_for(&robot.path);
    let old = robots::calibration::Calibration::read(&path).map_err(CalibrationError::Save)?;
    let previous = old
        .is_some()
        .then(|| robots::calibration::previous_path_for(&robot.path));
    let calibration = outcome
        .calibration(note, old)
        .write_beside(&robot.path)
        .map_err(|m| CalibrationError::Save(format!("cannot write the calibration: {m}")))?;
    Ok((
        outcome,
        Written {
            calibration,
            previous,
        },
    ))
}
