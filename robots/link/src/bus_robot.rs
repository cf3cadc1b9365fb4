//! Every bus driver of a robot description behind one read/write pair, in the robot's joint order.
//! The same code drives the mirror in lockstep, the mirror over real wires, and the hardware; only
//! the transports differ.
//!
//! One round trip per device per tick, on every bus:
//! - MIT-mode CAN motors answer only commands, so the *write* is the exchange: each motor gets its
//!   command and the reply it triggers is the state the next *read* returns (measured when the
//!   command arrived, one tick before the read). A read sends nothing.
//! - Dynamixel servos are read with one sync read (the read is the round trip) and commanded with
//!   one sync write, which has no reply.

use std::time::{Duration, Instant};

use firmware_bridge::can::CanBus;
use firmware_bridge::dxl::driver::{DxlBusDriver, DxlCommand, DxlDriverOptions};
use firmware_bridge::dxl::models as dxl_models;
use firmware_bridge::dxl::table::addr;
use firmware_bridge::dxl::transport::DxlTransport;
use firmware_bridge::feetech::driver::{FeetechBusDriver, FeetechDriverOptions, FeetechTransport};
use firmware_bridge::imu::reader::ImuReader;
use firmware_bridge::mit::codec::MotorFault;
use firmware_bridge::mit::driver::{JointCommand, MitBusDriver};
use firmware_bridge::serial::ByteStream;
use firmware_bridge::unitree::host::{HgDriver, LowLevelPort};
use robots::{BusKind, Robot, drivers};
use triple_buffer::triple_buffer;

use crate::clock::TickClock;
use crate::cycle::{BusStats, CycleLog, CycleRecord, Cycler, copy_joints};
use crate::imu_cycle::{BoardImu, ImuCycle, ImuInput, ImuWorker};
use crate::link::{IoError, RobotLink};
use crate::state::{DeviceIdentity, JointTarget, RobotState};
use crate::unitree_bus::HgBus;
use crate::workers::Worker;

/// How long identification waits for the IMU's first sample.
const IMU_FIRST_SAMPLE: Duration = Duration::from_millis(500);

/// Buses one robot may have (more are refused at set-up).
pub const MAX_BUSES: usize = 16;

/// The ports of a robot's buses, in robot.toml order per kind.
#[derive(Debug)]
pub struct BusPorts<C, D, F, U, S> {
    /// One port per `mit_can` bus, by name.
    pub can: Vec<(String, C)>,
    /// One port per `dynamixel` bus, by name.
    pub dxl: Vec<(String, D)>,
    /// One port per `feetech` bus, by name.
    pub feetech: Vec<(String, F)>,
    /// One port per `unitree_dds` bus, by name.
    pub unitree: Vec<(String, U)>,
    /// The IMU stream, when the IMU has a line of its own (`None`: it is a Unitree board's).
    pub imu: Option<S>,
}

/// One bus of joints as its cycles drive it.
pub(crate) trait JointBus: Send + std::fmt::Debug {
    /// Checks the devices answer with their identities; leaves them limp.
    fn identify(&mut self) -> Result<(), IoError>;
    /// Reads the bus's joints at once (a whole round trip) into `state` (robot order).
    fn sample(&mut self, state: &mut RobotState) -> Result<(), IoError>;
    /// The first half of a cycle: sends the joints their targets (robot order) and asks for their
    /// state.
    fn send(&mut self, targets: &[JointTarget]) -> Result<(), IoError>;
    /// The second half: takes the replies (until all are in or their deadline passes) into
    /// `state` (robot order).
    fn receive(&mut self, state: &mut RobotState) -> Result<(), IoError>;
    /// Torque off.
    fn torque_off(&mut self) -> Result<(), IoError>;
    /// Who each device says it is (after [`Self::identify`]), appended to `out`.
    fn identities(&mut self, bus: &str, out: &mut Vec<DeviceIdentity>) -> Result<(), IoError>;
}

/// One bus: its driver, the robot index of each of its joints, its command buffer, torque state.
#[derive(Debug)]
struct Bus<Driver, Command> {
    driver: Driver,
    joints: Vec<usize>,
    commands: Vec<Command>,
    enabled: bool,
    /// Commands went out and their replies are still to be taken.
    pending: bool,
}

impl<C: CanBus + Send + std::fmt::Debug> JointBus for Bus<MitBusDriver<C>, JointCommand>
where
    C::Instant: Send,
{
    fn identify(&mut self) -> Result<(), IoError> {
        self.driver.disable_all()?;
        // Motors whose protocol carries a torque limit hold the joint's between commands.
        self.driver.write_torque_limits()?;
        self.enabled = false;
        Ok(())
    }

    fn sample(&mut self, state: &mut RobotState) -> Result<(), IoError> {
        // The replies to the identify's disable frames (or the last cycle) are the reading.
        for (f, &i) in self.driver.feedback().iter().zip(&self.joints) {
            state.q[i] = f.q;
            state.qd[i] = f.qd;
            state.tau[i] = f.tau;
            state.missed[i] = f.missed_cycles;
            state.faulted[i] = !matches!(f.fault, MotorFault::None);
        }
        Ok(())
    }

    fn send(&mut self, targets: &[JointTarget]) -> Result<(), IoError> {
        let want = self.joints.iter().any(|&i| targets[i].enabled);
        if want != self.enabled {
            if want {
                self.driver.enable_all()?;
            } else if let Err(e) = self.driver.disable_all() {
                // On the way down every motor that still listens is off; a silent one cannot be
                // reached, and that must not stop the others from being switched off.
                tracing::warn!("torque off: {e}");
            }
            self.enabled = want;
        }
        for (c, &i) in self.commands.iter_mut().zip(&self.joints) {
            let t = targets[i];
            *c = if t.enabled {
                JointCommand {
                    q: t.q,
                    qd: t.qd,
                    kp: t.kp,
                    kd: t.kd,
                    tau: t.tau,
                }
            } else {
                JointCommand::default()
            };
        }
        // MIT motors answer commands only: the command is the request for state.
        self.driver.send_commands(&self.commands)?;
        self.pending = true;
        Ok(())
    }

    fn receive(&mut self, state: &mut RobotState) -> Result<(), IoError> {
        if std::mem::take(&mut self.pending) {
            self.driver.collect_replies()?;
        }
        self.sample(state)
    }

    fn torque_off(&mut self) -> Result<(), IoError> {
        self.commands.fill(JointCommand::default());
        self.enabled = false;
        self.pending = false;
        self.driver.disable_all()?;
        Ok(())
    }

    fn identities(&mut self, bus: &str, out: &mut Vec<DeviceIdentity>) -> Result<(), IoError> {
        // The MIT protocol has no identity query: a reply in the model's format from the right
        // reply ID is the identity (Robstride's feedback names the host ID it answers); version
        // and limits come from the model table.
        for i in 0..self.driver.joints().len() {
            let identity = self.driver.robstride_identity(i)?;
            let (j, f) = (&self.driver.joints()[i], &self.driver.feedback()[i]);
            let answer = match (identity, j.model.family) {
                _ if f.is_stale() => "no reply".into(),
                (Some(who), _) => format!("{} uid {:016X}", j.model.name, who.uid),
                (None, firmware_bridge::mit::models::MotorFamily::Robstride) => {
                    format!("{} feedback, no get-ID answer", j.model.name)
                }
                (None, _) => format!("{} reply from 0x{:03X}", j.model.name, j.reply_id),
            };
            out.push(DeviceIdentity {
                joint: j.name.clone(),
                bus: bus.to_owned(),
                id: j.motor_id,
                model: j.model.name.clone(),
                answer,
                firmware: None,
                current_limit_a: None,
                torque_limit_nm: identity.map_or(j.model.t_max, |who| who.torque_limit),
            });
        }
        Ok(())
    }
}

/// What a serial-servo bus needs of its driver to switch torque and read in two halves.
trait SerialServos {
    fn enable(&mut self) -> Result<(), IoError>;
    fn disable(&mut self) -> Result<(), IoError>;
    fn request_state(&mut self) -> Result<(), IoError>;
    fn collect_state(&mut self) -> Result<(), IoError>;
}

macro_rules! serial_servos {
    ($driver:ident, $transport:ident) => {
        impl<T: $transport> SerialServos for $driver<T> {
            fn enable(&mut self) -> Result<(), IoError> {
                Ok($driver::enable(self)?)
            }
            fn disable(&mut self) -> Result<(), IoError> {
                Ok($driver::disable(self)?)
            }
            fn request_state(&mut self) -> Result<(), IoError> {
                Ok($driver::request_state(self)?)
            }
            fn collect_state(&mut self) -> Result<(), IoError> {
                $driver::collect_state(self)?;
                Ok(())
            }
        }
    };
}

serial_servos!(DxlBusDriver, DxlTransport);
serial_servos!(FeetechBusDriver, FeetechTransport);

/// Torque on a serial-servo bus (Dynamixel, Feetech): switched only when the wish changes, and
/// the state asked for in `send` and collected in `receive`.
#[derive(Debug, Default)]
struct ServoTorque {
    enabled: bool,
    /// A state request went out and its answers are still to be taken.
    pending: bool,
}

impl ServoTorque {
    /// Torque to `want` (after the goals were written), then the state request.
    fn switch_and_request(&mut self, driver: &mut impl SerialServos, want: bool) -> Result<(), IoError> {
        if want != self.enabled {
            if want {
                driver.enable()?;
            } else {
                driver.disable()?;
            }
            self.enabled = want;
        }
        driver.request_state()?;
        self.pending = true;
        Ok(())
    }

    /// The answers to the last request, if one is out.
    fn collect(&mut self, driver: &mut impl SerialServos) -> Result<(), IoError> {
        if std::mem::take(&mut self.pending) {
            driver.collect_state()?;
        }
        Ok(())
    }

    /// Torque off now, nothing pending.
    fn off(&mut self, driver: &mut impl SerialServos) -> Result<(), IoError> {
        self.enabled = false;
        self.pending = false;
        driver.disable()
    }
}

/// A Dynamixel line: the servos run their own position loop, so the loop's stiffness and damping
/// become the servos' Position P/D gains (written only when they change) and their torque limit
/// the goal current of current-based position control.
#[derive(Debug)]
struct DxlBus<D: DxlTransport> {
    driver: DxlBusDriver<D>,
    joints: Vec<usize>,
    commands: Vec<DxlCommand>,
    /// Each joint's servo model (a robot's own variant where it has one).
    models: Vec<dxl_models::DxlModel>,
    /// Goal current per joint, A: its torque limit (ignored by servos without current control).
    current_caps: Vec<f64>,
    /// Stiffness and damping the servos hold now (NaN: unknown, write before use).
    gains_held: Vec<(f64, f64)>,
    gains: Vec<[u16; 3]>,
    /// Torque on or off, and a state request awaiting its answer.
    torque: ServoTorque,
}

impl<D: DxlTransport> DxlBus<D> {
    fn new(driver: DxlBusDriver<D>, joints: Vec<usize>, robot: &Robot) -> Result<Self, IoError> {
        let n = joints.len();
        let mut models = Vec::with_capacity(n);
        let mut current_caps = Vec::with_capacity(n);
        for &i in &joints {
            let j = &robot.config.joints[i];
            let model = robot.dxl_model(&j.model).ok_or_else(|| {
                IoError::Setup(format!("joint {}: {} is no Dynamixel model", j.name, j.model))
            })?;
            current_caps.push(drivers::goal_current_for(j.torque_limit, model));
            models.push(model.clone());
        }
        Ok(Self {
            driver,
            joints,
            commands: vec![DxlCommand::default(); n],
            models,
            current_caps,
            gains_held: vec![(f64::NAN, f64::NAN); n],
            gains: vec![[0; 3]; n],
            torque: ServoTorque::default(),
        })
    }

    fn copy_feedback(&self, state: &mut RobotState) {
        for (f, &i) in self.driver.feedback().iter().zip(&self.joints) {
            state.q[i] = f.q;
            state.qd[i] = f.qd;
            state.tau[i] = f.tau;
            state.missed[i] = f.missed_cycles;
            state.faulted[i] = f.hardware_error != 0;
        }
    }

    /// Writes the P/D gains of `targets` when any joint's stiffness or damping changed.
    fn update_gains(&mut self, targets: &[JointTarget]) -> Result<(), IoError> {
        let changed = self
            .joints
            .iter()
            .zip(&self.gains_held)
            .any(|(&i, &(kp, kd))| targets[i].kp != kp || targets[i].kd != kd);
        if !changed {
            return Ok(());
        }
        for (k, &i) in self.joints.iter().enumerate() {
            let t = &targets[i];
            self.gains[k] = drivers::position_gains_for(t.kp, t.kd, &self.models[k]);
        }
        self.driver.write_gains(&self.gains)?;
        for (held, &i) in self.gains_held.iter_mut().zip(&self.joints) {
            *held = (targets[i].kp, targets[i].kd);
        }
        Ok(())
    }
}

impl<D: DxlTransport + Send + std::fmt::Debug> JointBus for DxlBus<D>
where
    D::Instant: Send,
{
    fn identify(&mut self) -> Result<(), IoError> {
        self.driver.configure()?;
        self.gains_held.fill((f64::NAN, f64::NAN));
        self.torque.enabled = false;
        Ok(())
    }

    fn sample(&mut self, state: &mut RobotState) -> Result<(), IoError> {
        self.driver.read_state()?;
        self.copy_feedback(state);
        Ok(())
    }

    fn send(&mut self, targets: &[JointTarget]) -> Result<(), IoError> {
        // Torque on while every joint is commanded; kp = 0 with kd > 0 is damping (D gain alone
        // acts on the servo's speed). Feed-forward torque cannot reach a position servo: policies
        // that need it are refused when they load.
        let want = self.joints.iter().all(|&i| targets[i].enabled);
        for ((c, &i), &cap) in self.commands.iter_mut().zip(&self.joints).zip(&self.current_caps) {
            *c = DxlCommand {
                q: targets[i].q,
                current: cap,
            };
        }
        if want {
            // Gains and goals first, so torque comes on towards the target with the asked gains.
            self.update_gains(targets)?;
            self.driver.write_goals(&self.commands)?;
        }
        self.torque.switch_and_request(&mut self.driver, want)
    }

    fn receive(&mut self, state: &mut RobotState) -> Result<(), IoError> {
        self.torque.collect(&mut self.driver)?;
        self.copy_feedback(state);
        Ok(())
    }

    fn torque_off(&mut self) -> Result<(), IoError> {
        self.torque.off(&mut self.driver)
    }

    fn identities(&mut self, bus: &str, out: &mut Vec<DeviceIdentity>) -> Result<(), IoError> {
        for k in 0..self.driver.joints().len() {
            let j = self.driver.joints()[k].clone();
            let (number, firmware) = self.driver.ping(j.id)?;
            let model = self.models.get(k);
            let current_limit_a = match model {
                Some(m) if m.current_sensing => {
                    let mut raw = [0u8; 2];
                    self.driver.read(j.id, addr::CURRENT_LIMIT, &mut raw)?;
                    Some(f64::from(u16::from_le_bytes(raw)) * dxl_models::CURRENT_UNIT_A)
                }
                _ => None,
            };
            let found =
                dxl_models::find_by_number(number).map_or(String::from("unknown"), |m| m.name.clone());
            out.push(DeviceIdentity {
                joint: j.name.clone(),
                bus: bus.to_owned(),
                id: j.id,
                model: model.map_or_else(|| j.model.clone(), |m| m.name.clone()),
                answer: format!("model {number} ({found})"),
                firmware: Some(firmware),
                current_limit_a,
                torque_limit_nm: model.map_or(0.0, |m| m.stall_torque),
            });
        }
        Ok(())
    }
}

/// A Feetech line: the servos run their own position loop, so the loop's stiffness and damping
/// become their P/D coefficients (written when they change) and each joint's torque limit their
/// Torque Limit (set once). Feed-forward torque cannot reach them, as with Dynamixel.
#[derive(Debug)]
struct FeetechBus<F: FeetechTransport> {
    driver: FeetechBusDriver<F>,
    joints: Vec<usize>,
    goals: Vec<f64>,
    /// Stiffness and damping the servos hold now (NaN: unknown, write before use).
    gains_held: Vec<(f64, f64)>,
    gains: Vec<[u8; 2]>,
    /// Torque on or off, and a state request awaiting its answer.
    torque: ServoTorque,
}

impl<F: FeetechTransport> FeetechBus<F> {
    fn new(driver: FeetechBusDriver<F>, joints: Vec<usize>) -> Self {
        let n = joints.len();
        Self {
            driver,
            joints,
            goals: vec![0.0; n],
            gains_held: vec![(f64::NAN, f64::NAN); n],
            gains: vec![[0; 2]; n],
            torque: ServoTorque::default(),
        }
    }

    fn copy_feedback(&self, state: &mut RobotState) {
        use firmware_bridge::feetech::packet::error;
        let faults =
            error::VOLTAGE | error::ANGLE_SENSOR | error::OVERHEAT | error::OVERCURRENT | error::OVERLOAD;
        for (f, &i) in self.driver.feedback().iter().zip(&self.joints) {
            state.q[i] = f.q;
            state.qd[i] = f.qd;
            state.tau[i] = f.tau;
            state.missed[i] = f.missed_cycles;
            state.faulted[i] = f.status & faults != 0;
        }
    }
}

impl<F: FeetechTransport + Send + std::fmt::Debug> JointBus for FeetechBus<F>
where
    F::Instant: Send,
{
    fn identify(&mut self) -> Result<(), IoError> {
        self.driver.configure()?;
        self.gains_held.fill((f64::NAN, f64::NAN));
        self.torque.enabled = false;
        Ok(())
    }

    fn sample(&mut self, state: &mut RobotState) -> Result<(), IoError> {
        self.driver.read_state()?;
        self.copy_feedback(state);
        Ok(())
    }

    fn send(&mut self, targets: &[JointTarget]) -> Result<(), IoError> {
        let want = self.joints.iter().all(|&i| targets[i].enabled);
        for (g, &i) in self.goals.iter_mut().zip(&self.joints) {
            *g = targets[i].q;
        }
        if want {
            let changed = self
                .joints
                .iter()
                .zip(&self.gains_held)
                .any(|(&i, &(kp, kd))| targets[i].kp != kp || targets[i].kd != kd);
            if changed {
                for (k, &i) in self.joints.iter().enumerate() {
                    let model = &self.driver.joints()[k].model;
                    self.gains[k] =
                        firmware_bridge::feetech::driver::gains_for(targets[i].kp, targets[i].kd, model);
                }
                self.driver.write_gains(&self.gains)?;
                for (held, &i) in self.gains_held.iter_mut().zip(&self.joints) {
                    *held = (targets[i].kp, targets[i].kd);
                }
            }
            self.driver.write_goals(&self.goals)?;
        }
        self.torque.switch_and_request(&mut self.driver, want)
    }

    fn receive(&mut self, state: &mut RobotState) -> Result<(), IoError> {
        self.torque.collect(&mut self.driver)?;
        self.copy_feedback(state);
        Ok(())
    }

    fn torque_off(&mut self) -> Result<(), IoError> {
        self.torque.off(&mut self.driver)
    }

    fn identities(&mut self, bus: &str, out: &mut Vec<DeviceIdentity>) -> Result<(), IoError> {
        for k in 0..self.driver.joints().len() {
            let j = self.driver.joints()[k].clone();
            let found = self.driver.ping(j.id)?;
            let mut limit = [0u8; 2];
            if found.is_some() {
                self.driver.read(
                    j.id,
                    firmware_bridge::feetech::table::addr::TORQUE_LIMIT,
                    &mut limit,
                )?;
            }
            let limit = f64::from(u16::from_le_bytes(limit).min(1000)) / 1000.0;
            out.push(DeviceIdentity {
                joint: j.name.clone(),
                bus: bus.to_owned(),
                id: j.id,
                model: j.model.name.clone(),
                answer: match found {
                    Some((number, [major, minor])) => format!("model {number}, firmware {major}.{minor}"),
                    None => "no reply".into(),
                },
                firmware: found.map(|(_, fw)| fw[0]),
                current_limit_a: None,
                torque_limit_nm: limit * j.model.stall_torque,
            });
        }
        Ok(())
    }
}

impl<S: ByteStream + std::fmt::Debug> RobotLink for BusRobot<S>
where
    S::Instant: std::fmt::Debug,
{
    fn identify(&mut self) -> Result<(), IoError> {
        BusRobot::identify(self)
    }
    fn read(&mut self, state: &mut RobotState) -> Result<(), IoError> {
        BusRobot::read(self, state)
    }
    fn write(&mut self, targets: &[JointTarget]) -> Result<(), IoError> {
        BusRobot::write(self, targets)
    }
    fn wait_until(&mut self, clock: &mut dyn TickClock, deadline: Duration) -> bool {
        BusRobot::wait_until(self, clock, deadline)
    }
    fn torque_off(&mut self) -> Result<(), IoError> {
        BusRobot::torque_off(self)
    }
    fn identities(&mut self) -> Result<Vec<DeviceIdentity>, IoError> {
        BusRobot::identities(self)
    }
    fn bus_names(&self) -> &[String] {
        &self.names
    }
    fn bus_times(&self) -> &[Duration] {
        &self.times
    }
    fn bus_stats(&self) -> &[BusStats] {
        &self.stats
    }
    fn record_cycles(&mut self, capacity: usize) -> bool {
        BusRobot::record_cycles(self, capacity)
    }
    fn set_stale_cycles(&mut self, cycles: u32) {
        BusRobot::set_stale_cycles(self, cycles);
    }
    fn drain_cycles(&mut self, sink: &mut dyn FnMut(&CycleRecord)) -> u64 {
        BusRobot::drain_cycles(self, sink)
    }
}

/// Every bus of a robot, each cycling at its own rate under the policy: in one thread on a
/// schedule of simulated time (lockstep: deterministic), or each on a thread of its own on the
/// wall clock.
#[derive(Debug)]
pub struct BusRobot<S: ByteStream> {
    /// Buses served in this thread, with their next start and the finish of a cycle in flight.
    cyclers: Vec<Cycler>,
    next_start: Vec<Duration>,
    in_flight: Vec<Option<Duration>>,
    /// Buses on threads of their own.
    workers: Vec<Worker>,
    /// Threads asked for (with what runs first on each), started once the devices are identified.
    threads: Option<fn()>,
    identified: bool,
    /// The link's time: the tick clock's in this thread, or since `epoch` with workers.
    now: Duration,
    scheduled: bool,
    epoch: Instant,
    /// The number of the newest targets.
    seq: u64,
    /// Targets with torque off, for the end.
    off: Vec<JointTarget>,
    /// The first error a scheduled cycle met, for the next read.
    error: Option<IoError>,
    /// The IMU polled in this thread (lockstep), or on a thread of its own.
    imu: Option<ImuCycle<S>>,
    imu_worker: Option<ImuWorker>,
    imu_next: Duration,
    /// Samples the loop has seen.
    imu_seen: u64,
    /// Foot switches, when the robot has them, and how many feet.
    contacts: Option<Box<dyn crate::contacts::ContactSource>>,
    feet: usize,
    names: Vec<String>,
    times: Vec<Duration>,
    stats: Vec<BusStats>,
    /// Each bus's cycle records, when telemetry asked for them.
    logs: Vec<std::sync::Arc<CycleLog>>,
}

impl<S: ByteStream> BusRobot<S> {
    /// Drivers for `robot` on `ports`, each bus at the rate robot.toml gives it; no reply is
    /// waited for longer than `reply_timeout` or [`crate::cycle::REPLY_SHARE`] of the bus's period. Nothing is
    /// sent yet.
    pub fn new<C, D, F, U>(
        robot: &Robot,
        ports: BusPorts<C, D, F, U, S>,
        reply_timeout: Duration,
        dxl: DxlDriverOptions,
    ) -> Result<Self, IoError>
    where
        C: CanBus + Send + std::fmt::Debug + 'static,
        C::Instant: Send,
        D: DxlTransport + Send + std::fmt::Debug + 'static,
        D::Instant: Send,
        F: FeetechTransport + Send + std::fmt::Debug + 'static,
        F::Instant: Send,
        U: LowLevelPort + 'static,
    {
        let n = robot.config.joints.len();
        let policy_period =
            Duration::try_from_secs_f64(1.0 / robot.config.control_rate_hz).map_err(|_| {
                IoError::Setup(format!(
                    "control_rate_hz {} is not a rate",
                    robot.config.control_rate_hz
                ))
            })?;
        let damping_kd: Vec<f64> = robot.config.joints.iter().map(|j| j.kd).collect();
        // How each joint's limit is held where a motor runs the PD law (robots::TorqueHold): by
        // its own clamp, by the trainer's clip at each cycle, or over the whole cycle.
        let torque_hold: Vec<robots::TorqueHold> =
            robot.config.joints.iter().map(|j| robot.torque_hold(j)).collect();
        let timing = |name: &str| {
            robot
                .bus_timing(name)
                .ok_or_else(|| IoError::Setup(format!("bus {name} is not in robot {}", robot.config.name)))
        };
        let mut cyclers = Vec::new();
        let mut names = Vec::new();
        // MIT motors run the PD law with nothing but their model's maximum to cap it: their
        // commands are bounded to each joint's torque limit. Dynamixel servos get the limit as
        // their goal current (current-based position control).
        let mut add = |bus: Box<dyn JointBus>, joints: Vec<usize>, timing, name, bound_torque: bool| {
            cyclers.push(Cycler::new(
                bus,
                joints,
                timing,
                policy_period,
                damping_kd.clone(),
                bound_torque.then(|| torque_hold.clone()),
            ));
            names.push(name);
        };
        for (name, port) in ports.can {
            check_kind(robot, &name, BusKind::MitCan)?;
            let timing = timing(&name)?;
            let (idx, cfg): (Vec<_>, Vec<_>) = robot
                .joints_on(&name)
                .map(|(i, j)| (i, drivers::mit_joint(robot, j)))
                .unzip();
            // A bus whose cycle takes longer on the wire than the reply timeout still gets its
            // replies: the wait covers the round trip with a margin, within the cycle's share.
            let window = reply_timeout
                .max(timing.round_trip().mul_f64(1.5))
                .min(Cycler::reply_window(&timing));
            let bus = Bus {
                driver: MitBusDriver::new(port, cfg, window)?,
                joints: idx.clone(),
                commands: vec![JointCommand::default(); idx.len()],
                enabled: false,
                pending: false,
            };
            add(Box::new(bus), idx, timing, name, true);
        }
        for (name, port) in ports.dxl {
            check_kind(robot, &name, BusKind::Dynamixel)?;
            let timing = timing(&name)?;
            let (idx, cfg): (Vec<_>, Vec<_>) = robot
                .joints_on(&name)
                .map(|(i, j)| (i, drivers::dxl_joint(robot, j)))
                .unzip();
            let options = DxlDriverOptions {
                max_reply_wait: Some(Cycler::reply_window(&timing)),
                watchdog: Some(timing.command_timeout),
                fast_reads: robot.bus(&name).is_some_and(|b| b.fast_reads),
                ..dxl
            };
            let bus = DxlBus::new(DxlBusDriver::new(port, cfg, options)?, idx.clone(), robot)?;
            add(Box::new(bus), idx, timing, name, false);
        }
        for (name, port) in ports.feetech {
            check_kind(robot, &name, BusKind::Feetech)?;
            let timing = timing(&name)?;
            let (idx, cfg): (Vec<_>, Vec<_>) = robot
                .joints_on(&name)
                .map(|(i, j)| (i, drivers::feetech_joint(robot, j)))
                .unzip();
            let options = FeetechDriverOptions {
                reply_slack: dxl.reply_slack,
            };
            let bus = FeetechBus::new(FeetechBusDriver::new(port, cfg, options)?, idx.clone());
            add(Box::new(bus), idx, timing, name, false);
        }
        let mut board_imu = None;
        for (name, port) in ports.unitree {
            check_kind(robot, &name, BusKind::UnitreeDds)?;
            let timing = timing(&name)?;
            let (idx, cfg): (Vec<_>, Vec<_>) = robot
                .joints_on(&name)
                .map(|(i, j)| (i, drivers::mit_joint(robot, j)))
                .unzip();
            let bus_config = robot.bus(&name).expect("checked above");
            let imu = (robot.config.imu.bus == name).then(|| {
                let (input, output) = triple_buffer(&BoardImu::default());
                board_imu = Some(output);
                input
            });
            let bus = HgBus {
                driver: HgDriver::new(port, cfg, timing.period)
                    .map_err(|e| IoError::Setup(format!("bus {name}: {e}")))?,
                commands: vec![None; idx.len()],
                joints: idx.clone(),
                imu,
                source: format!(
                    "rt/lowstate on {}, domain {}",
                    bus_config.device,
                    bus_config.domain.unwrap_or(0)
                ),
            };
            // The board's motors hold each joint's torque limit at every step of their law, as
            // MIT motors do.
            add(Box::new(bus), idx, timing, name, true);
        }
        if cyclers.len() > MAX_BUSES {
            return Err(IoError::Setup(format!(
                "{} buses; at most {MAX_BUSES} are supported",
                cyclers.len()
            )));
        }
        let covered: usize = cyclers.iter().map(|c| c.joints.len()).sum();
        if covered != n {
            return Err(IoError::Setup(format!(
                "the ports reach {covered} of the robot's {n} joints"
            )));
        }
        let k = cyclers.len();
        Ok(Self {
            cyclers,
            next_start: vec![Duration::ZERO; k],
            in_flight: vec![None; k],
            workers: Vec::new(),
            threads: None,
            identified: false,
            now: Duration::ZERO,
            scheduled: false,
            epoch: Instant::now(),
            seq: 0,
            off: vec![JointTarget::default(); n],
            error: None,
            imu: Some(ImuCycle::new(
                match (ports.imu, board_imu) {
                    (_, Some(newest)) => ImuInput::Board { newest, last: 0 },
                    (Some(stream), None) => ImuInput::Line {
                        reader: Box::new(ImuReader::speaking_at(
                            robot.config.imu.protocol,
                            stream,
                            robot.config.imu.rate_hz,
                        )),
                        last: None,
                    },
                    (None, None) => {
                        return Err(IoError::Setup(format!(
                            "the IMU's bus {} has no port",
                            robot.config.imu.bus
                        )));
                    }
                },
                robot.config.imu.mounting_rpy_deg,
                robot.config.imu.gyro_bias,
                robot.config.imu.accel_bias,
                timing(&robot.config.imu.bus)?.period,
            )),
            imu_worker: None,
            imu_next: Duration::ZERO,
            imu_seen: 0,
            contacts: None,
            feet: robot.config.feet.len(),
            times: vec![Duration::ZERO; k],
            stats: vec![BusStats::default(); k],
            logs: Vec::new(),
            names,
        })
    }

    /// Reads the feet's switches from `source` with every read (robot.toml `feet` order).
    pub fn with_contacts(mut self, source: Box<dyn crate::contacts::ContactSource>) -> Self {
        self.contacts = Some(source);
        self
    }

    /// Cycles in a row a joint may stay silent before its bus damps itself (at least 1); set
    /// before the buses get threads of their own.
    pub fn set_stale_cycles(&mut self, cycles: u32) {
        for c in &mut self.cyclers {
            c.stale_cycles = cycles.max(1);
        }
    }

    /// Records every cycle of every bus, up to `capacity` per bus between drains; only before
    /// the buses get threads of their own (false after).
    pub fn record_cycles(&mut self, capacity: usize) -> bool {
        if !self.workers.is_empty() {
            return false;
        }
        self.logs.clear();
        for (k, c) in self.cyclers.iter_mut().enumerate() {
            let log = CycleLog::new(capacity);
            c.log = Some((std::sync::Arc::clone(&log), k as u8));
            self.logs.push(log);
        }
        true
    }

    /// Hands every cycle recorded since the last call to `sink`, bus by bus; returns the
    /// records lost so far (queues full).
    pub fn drain_cycles(&mut self, sink: &mut dyn FnMut(&CycleRecord)) -> u64 {
        let mut lost = 0;
        for log in &self.logs {
            while let Some(r) = log.queue.pop() {
                sink(&r);
            }
            lost += log.lost.load(std::sync::atomic::Ordering::Relaxed);
        }
        lost
    }

    fn start_threads(&mut self) -> Result<(), IoError> {
        let Some(on_start) = self.threads.take() else {
            return Ok(());
        };
        for (i, c) in std::mem::take(&mut self.cyclers).into_iter().enumerate() {
            let w = Worker::spawn(c, self.epoch, i, on_start)
                .map_err(|e| IoError::Setup(format!("cannot start a bus thread: {e}")))?;
            self.workers.push(w);
        }
        Ok(())
    }

    /// Checks every device answers with the right identity and configures the servos (torque
    /// off), then reads every joint once; buses meant for threads of their own start cycling
    /// there. MIT motors are asked with a *disable* frame, which also leaves them limp.
    pub fn identify(&mut self) -> Result<(), IoError> {
        if !self.workers.is_empty() {
            return Err(IoError::Setup(
                "devices are identified before the buses get their threads".into(),
            ));
        }
        for c in &mut self.cyclers {
            c.bus.identify()?;
            c.sample(self.now)?;
        }
        // A part the host configures first (BNO055) answers after a few round trips; a silent
        // one is left to the safety layer, which stops on a stale IMU. With a thread of its own
        // the IMU is waited for too: a first tick before its first poll would read "never sent".
        if let Some(imu) = &mut self.imu {
            imu.wait_first(IMU_FIRST_SAMPLE, self.now)?;
        } else if let Some(w) = &mut self.imu_worker {
            let give_up = Instant::now() + IMU_FIRST_SAMPLE;
            while w.newest().count == 0 && Instant::now() < give_up {
                std::thread::sleep(Duration::from_micros(200));
            }
        }
        self.identified = true;
        self.start_threads()
    }

    /// Who each device says it is, robot bus order (after [`Self::identify`]). Buses moved onto
    /// threads by [`Self::parallel`] are not asked.
    pub fn identities(&mut self) -> Result<Vec<DeviceIdentity>, IoError> {
        if !self.workers.is_empty() {
            return Err(IoError::Setup(
                "identities are read before the buses get their threads".into(),
            ));
        }
        let mut out = Vec::new();
        for (c, name) in self.cyclers.iter_mut().zip(&self.names) {
            c.bus.identities(name, &mut out)?;
        }
        Ok(out)
    }

    /// The newest complete state of every bus and the IMU into `state`, with each joint's age.
    pub fn read(&mut self, state: &mut RobotState) -> Result<(), IoError> {
        if let Some(e) = self.error.take() {
            return Err(e);
        }
        for ((c, t), s) in self.cyclers.iter().zip(&mut self.times).zip(&mut self.stats) {
            c.copy_into(state, self.now);
            *t = c.stats.last_cycle;
            *s = c.stats;
        }
        if !self.workers.is_empty() {
            let now = self.epoch.elapsed();
            self.now = now;
            for ((w, t), s) in self.workers.iter_mut().zip(&mut self.times).zip(&mut self.stats) {
                if let Some(e) = w.error() {
                    return Err(e);
                }
                let (joints, p) = w.joints_and_newest();
                copy_joints(joints, &p.state, &p.sampled_at, state, now);
                *t = p.stats.last_cycle;
                *s = p.stats;
            }
        }
        let newest = match (&mut self.imu_worker, &self.imu) {
            (Some(w), _) => {
                if let Some(e) = w.error() {
                    return Err(IoError::Imu(e));
                }
                w.newest()
            }
            (None, Some(c)) => c.newest,
            (None, None) => return Err(IoError::Setup("the IMU has no reader".into())),
        };
        newest.samples_since(self.imu_seen, &mut state.imu_samples);
        match &mut self.contacts {
            Some(c) => {
                state.foot_switches.resize(self.feet, false);
                c.read(&mut state.foot_switches)?;
            }
            None => state.foot_switches.clear(),
        }
        if newest.count != self.imu_seen {
            self.imu_seen = newest.count;
            state.gyro = newest.gyro;
            state.accel = newest.accel;
            state.quat = newest.quat;
            state.imu_missed = 0;
        } else {
            state.imu_missed = state.imu_missed.saturating_add(1);
        }
        state.imu_age = self.now.saturating_sub(newest.arrived_at);
        Ok(())
    }

    /// Hands every bus the policy's targets (robot order); each bus commands them from its next
    /// cycle on, switching torque on or off as needed.
    pub fn write(&mut self, targets: &[JointTarget]) -> Result<(), IoError> {
        self.seq += 1;
        for c in &mut self.cyclers {
            c.take_order(self.seq, self.now, targets);
        }
        if !self.workers.is_empty() {
            let now = self.epoch.elapsed();
            for w in &mut self.workers {
                w.order(self.seq, now, targets, false);
            }
        }
        Ok(())
    }

    /// Lets time pass until `deadline` on `clock`. Buses served in this thread cycle on the way,
    /// in time order (a cycle's finish before another's start at the same instant; cycles due at
    /// `deadline` itself run after the tick, with its targets). Returns whether the deadline had
    /// passed already.
    pub fn wait_until(&mut self, clock: &mut dyn TickClock, deadline: Duration) -> bool {
        if self.cyclers.is_empty() {
            return clock.wait_until(deadline);
        }
        let late = clock.elapsed() > deadline;
        if !self.scheduled {
            // The schedule starts with the first wait: cycles fall on the policy's ticks.
            let now = clock.elapsed();
            self.next_start.fill(now);
            self.imu_next = now;
            self.scheduled = true;
        }
        loop {
            let mut next: Option<(Duration, usize, bool)> = None;
            for (k, (&start, &fin)) in self.next_start.iter().zip(&self.in_flight).enumerate() {
                let (t, finish) = fin.map_or((start, false), |f| (f, true));
                if next.is_none_or(|(bt, _, bf)| t < bt || (t == bt && finish && !bf)) {
                    next = Some((t, k, finish));
                }
            }
            let Some((t, k, finish)) = next else { break };
            // The IMU's poll, when it comes first (after finishes at the same instant).
            if let Some(imu) = &mut self.imu
                && self.imu_next < deadline
                && (self.imu_next < t || (self.imu_next == t && !finish))
            {
                let at = self.imu_next;
                clock.wait_until(at);
                self.now = at;
                self.imu_next = at + imu.period;
                if let Err(e) = imu.poll(at) {
                    self.error.get_or_insert(IoError::Imu(e));
                }
                continue;
            }
            if t >= deadline {
                break;
            }
            clock.wait_until(t);
            self.now = t;
            let c = &mut self.cyclers[k];
            let r = if finish {
                self.in_flight[k] = None;
                c.finish(|| clock.elapsed())
            } else {
                let period = c.timing.period;
                self.in_flight[k] = Some(t + Cycler::replies_expected(&c.timing));
                self.next_start[k] = t + period;
                // A cycle that blocked (a torque switch waits for its replies) pushes the
                // following ones out: count the slots lost.
                let now = clock.elapsed();
                if now > t + period {
                    let lost = ((now - t).as_nanos() / period.as_nanos()) as u32;
                    c.stats.overruns += u64::from(lost);
                    self.next_start[k] = t + period * (lost + 1);
                }
                c.start(t)
            };
            if let Err(e) = r {
                self.error.get_or_insert(e);
            }
        }
        let missed = clock.wait_until(deadline);
        self.now = deadline;
        late || missed
    }

    /// Torque off everywhere (best effort on every bus, first error reported); the buses keep
    /// cycling with torque off.
    pub fn torque_off(&mut self) -> Result<(), IoError> {
        let mut first: Option<IoError> = None;
        self.seq += 1;
        for c in &mut self.cyclers {
            c.take_order(self.seq, self.now, &self.off);
            if let Err(e) = c.bus.torque_off() {
                first.get_or_insert(e);
            }
        }
        if !self.workers.is_empty() {
            let now = self.epoch.elapsed();
            for w in &mut self.workers {
                w.order(self.seq, now, &self.off, true);
            }
            // Not in a tick: the end of a run, or a failed bus. Each worker gets a moment.
            let give_up = Instant::now() + Duration::from_secs(1);
            for (w, name) in self.workers.iter_mut().zip(&self.names) {
                while w.newest().torque_off_done < self.seq {
                    if let Some(e) = w.error() {
                        first.get_or_insert(e);
                        break;
                    }
                    if Instant::now() > give_up {
                        first.get_or_insert(IoError::Setup(format!(
                            "bus {name}: torque off not confirmed within 1 s"
                        )));
                        break;
                    }
                    std::thread::sleep(Duration::from_millis(1));
                }
            }
        }
        first.map_or(Ok(()), Err)
    }
}

impl<S: ByteStream + Send + 'static> BusRobot<S>
where
    S::Instant: Send,
{
    /// Moves each bus onto its own thread, cycling at its rate on the wall clock, once the
    /// devices are identified (at once, if they are); the IMU gets its thread now.
    pub fn parallel(self) -> Result<Self, IoError> {
        self.parallel_with(|| {})
    }

    /// [`Self::parallel`], running `on_start` first on each bus thread (real-time set-up of the
    /// thread, or instrumentation in tests).
    pub fn parallel_with(mut self, on_start: fn()) -> Result<Self, IoError> {
        self.epoch = Instant::now();
        self.now = Duration::ZERO;
        if let Some(imu) = self.imu.take() {
            let w = ImuWorker::spawn(imu, self.epoch, on_start)
                .map_err(|e| IoError::Setup(format!("cannot start the IMU thread: {e}")))?;
            self.imu_worker = Some(w);
        }
        self.threads = Some(on_start);
        if self.identified {
            self.start_threads()?;
        }
        Ok(self)
    }
}

fn check_kind(robot: &Robot, name: &str, kind: BusKind) -> Result<(), IoError> {
    match robot.bus(name) {
        Some(b) if b.kind == kind => Ok(()),
        Some(b) => Err(IoError::Setup(format!(
            "bus {name} is a {:?} bus, not {kind:?}",
            b.kind
        ))),
        None => Err(IoError::Setup(format!(
            "bus {name} is not in robot {}",
            robot.config.name
        ))),
    }
}
