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
use firmware_bridge::imu::reader::ImuReader;
use firmware_bridge::mit::codec::MotorFault;
use firmware_bridge::mit::driver::{JointCommand, MitBusDriver};
use firmware_bridge::serial::ByteStream;
use robots::{BusKind, Robot, drivers, spatial};

use crate::link::{IoError, RobotLink};
use crate::state::{DeviceIdentity, JointTarget, RobotState};
use crate::workers::{Op, Worker};

/// Buses one robot may have (more are refused at set-up).
pub const MAX_BUSES: usize = 16;

/// The ports of a robot's buses, in robot.toml order per kind.
#[derive(Debug)]
pub struct BusPorts<C, D, S> {
    /// One port per `mit_can` bus, by name.
    pub can: Vec<(String, C)>,
    /// One port per `dynamixel` bus, by name.
    pub dxl: Vec<(String, D)>,
    /// The IMU stream.
    pub imu: S,
}

/// One bus of joints as the loop drives it.
pub(crate) trait JointBus: Send + std::fmt::Debug {
    /// Checks the devices answer with their identities; leaves them limp.
    fn identify(&mut self) -> Result<(), IoError>;
    /// Reads the bus's joints into `state` (robot order).
    fn read(&mut self, state: &mut RobotState) -> Result<(), IoError>;
    /// Sends the bus's joints their targets (robot order).
    fn write(&mut self, targets: &[JointTarget]) -> Result<(), IoError>;
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
}

impl<C: CanBus + Send + std::fmt::Debug> JointBus for Bus<MitBusDriver<C>, JointCommand>
where
    C::Instant: Send,
{
    fn identify(&mut self) -> Result<(), IoError> {
        self.driver.disable_all()?;
        self.enabled = false;
        Ok(())
    }

    fn read(&mut self, state: &mut RobotState) -> Result<(), IoError> {
        // The replies to the last write (or to the identify's disable frames) are the reading.
        for (f, &i) in self.driver.feedback().iter().zip(&self.joints) {
            state.q[i] = f.q;
            state.qd[i] = f.qd;
            state.tau[i] = f.tau;
            state.missed[i] = f.missed_cycles;
            state.faulted[i] = !matches!(f.fault, MotorFault::None);
        }
        Ok(())
    }

    fn write(&mut self, targets: &[JointTarget]) -> Result<(), IoError> {
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
        self.driver.cycle(&self.commands)?;
        Ok(())
    }

    fn torque_off(&mut self) -> Result<(), IoError> {
        self.commands.fill(JointCommand::default());
        self.enabled = false;
        self.driver.disable_all()?;
        Ok(())
    }

    fn identities(&mut self, bus: &str, out: &mut Vec<DeviceIdentity>) -> Result<(), IoError> {
        // The MIT protocol has no identity query: a reply in the model's format from the right
        // reply ID is the identity; version and limits come from the model table.
        for (j, f) in self.driver.joints().iter().zip(self.driver.feedback()) {
            out.push(DeviceIdentity {
                joint: j.name.clone(),
                bus: bus.to_owned(),
                id: j.motor_id,
                model: j.model.name.clone(),
                answer: if f.is_stale() {
                    "no reply".into()
                } else {
                    format!("{} reply from 0x{:03X}", j.model.name, j.reply_id)
                },
                firmware: None,
                current_limit_a: None,
                torque_limit_nm: j.model.t_max,
            });
        }
        Ok(())
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
    models: Vec<&'static dxl_models::DxlModel>,
    /// Goal current per joint, A: its torque limit (ignored by servos without current control).
    current_caps: Vec<f64>,
    /// Stiffness and damping the servos hold now (NaN: unknown, write before use).
    gains_held: Vec<(f64, f64)>,
    gains: Vec<[u16; 3]>,
    enabled: bool,
}

impl<D: DxlTransport> DxlBus<D> {
    fn new(driver: DxlBusDriver<D>, joints: Vec<usize>, robot: &Robot) -> Result<Self, IoError> {
        let n = joints.len();
        let mut models = Vec::with_capacity(n);
        let mut current_caps = Vec::with_capacity(n);
        for &i in &joints {
            let j = &robot.config.joints[i];
            let model = dxl_models::find(&j.model).ok_or_else(|| {
                IoError::Setup(format!("joint {}: {} is no Dynamixel model", j.name, j.model))
            })?;
            models.push(model);
            current_caps.push(drivers::goal_current_for(j.torque_limit, model));
        }
        Ok(Self {
            driver,
            joints,
            commands: vec![DxlCommand::default(); n],
            models,
            current_caps,
            gains_held: vec![(f64::NAN, f64::NAN); n],
            gains: vec![[0; 3]; n],
            enabled: false,
        })
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
            self.gains[k] = drivers::position_gains_for(t.kp, t.kd, self.models[k]);
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
        self.enabled = false;
        Ok(())
    }

    fn read(&mut self, state: &mut RobotState) -> Result<(), IoError> {
        self.driver.read_state()?;
        for (f, &i) in self.driver.feedback().iter().zip(&self.joints) {
            state.q[i] = f.q;
            state.qd[i] = f.qd;
            state.tau[i] = f.tau;
            state.missed[i] = f.missed_cycles;
            state.faulted[i] = f.hardware_error != 0;
        }
        Ok(())
    }

    fn write(&mut self, targets: &[JointTarget]) -> Result<(), IoError> {
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
        if want != self.enabled {
            if want {
                self.driver.enable()?;
            } else {
                self.driver.disable()?;
            }
            self.enabled = want;
        }
        Ok(())
    }

    fn torque_off(&mut self) -> Result<(), IoError> {
        self.enabled = false;
        self.driver.disable()?;
        Ok(())
    }

    fn identities(&mut self, bus: &str, out: &mut Vec<DeviceIdentity>) -> Result<(), IoError> {
        for k in 0..self.driver.joints().len() {
            let j = self.driver.joints()[k].clone();
            let (number, firmware) = self.driver.ping(j.id)?;
            let model = dxl_models::find(&j.model);
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
                model: j.model.clone(),
                answer: format!("model {number} ({found})"),
                firmware: Some(firmware),
                current_limit_a,
                torque_limit_nm: model.map_or(0.0, |m| m.stall_torque),
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
}

/// Every bus of a robot, in sequence (lockstep: deterministic) or in parallel (wall clock).
#[derive(Debug)]
pub struct BusRobot<S: ByteStream> {
    buses: Vec<(Box<dyn JointBus>, Vec<usize>)>,
    workers: Vec<Worker>,
    imu: ImuReader<S>,
    last_imu: Option<S::Instant>,
    /// IMU mounting (IMU axes to base axes) and gyro bias, from the robot's calibration.
    imu_mount: [f64; 4],
    gyro_bias: [f64; 3],
    accel_bias: [f64; 3],
    n: usize,
    names: Vec<String>,
    times: Vec<Duration>,
}

impl<S: ByteStream> BusRobot<S> {
    /// Drivers for `robot` on `ports`. Nothing is sent yet.
    pub fn new<C, D>(
        robot: &Robot,
        ports: BusPorts<C, D, S>,
        reply_timeout: Duration,
        dxl: DxlDriverOptions,
    ) -> Result<Self, IoError>
    where
        C: CanBus + Send + std::fmt::Debug + 'static,
        C::Instant: Send,
        D: DxlTransport + Send + std::fmt::Debug + 'static,
        D::Instant: Send,
    {
        let mut buses: Vec<(Box<dyn JointBus>, Vec<usize>)> = Vec::new();
        let mut names = Vec::new();
        for (name, port) in ports.can {
            check_kind(robot, &name, BusKind::MitCan)?;
            let (idx, cfg): (Vec<_>, Vec<_>) = robot
                .joints_on(&name)
                .map(|(i, j)| (i, drivers::mit_joint(j)))
                .unzip();
            let n = idx.len();
            let bus = Bus {
                driver: MitBusDriver::new(port, cfg, reply_timeout)?,
                joints: idx.clone(),
                commands: vec![JointCommand::default(); n],
                enabled: false,
            };
            buses.push((Box::new(bus), idx));
            names.push(name);
        }
        for (name, port) in ports.dxl {
            check_kind(robot, &name, BusKind::Dynamixel)?;
            let (idx, cfg): (Vec<_>, Vec<_>) = robot
                .joints_on(&name)
                .map(|(i, j)| (i, drivers::dxl_joint(j)))
                .unzip();
            let bus = DxlBus::new(DxlBusDriver::new(port, cfg, dxl)?, idx.clone(), robot)?;
            buses.push((Box::new(bus), idx));
            names.push(name);
        }
        if buses.len() > MAX_BUSES {
            return Err(IoError::Setup(format!(
                "{} buses; at most {MAX_BUSES} are supported",
                buses.len()
            )));
        }
        let covered: usize = buses.iter().map(|b| b.1.len()).sum();
        let n = robot.config.joints.len();
        if covered != n {
            return Err(IoError::Setup(format!(
                "the ports reach {covered} of the robot's {n} joints"
            )));
        }
        Ok(Self {
            buses,
            workers: Vec::new(),
            imu: ImuReader::new(ports.imu),
            last_imu: None,
            imu_mount: {
                let [r, p, y] = robot.config.imu.mounting_rpy_deg.map(f64::to_radians);
                spatial::quat_of_rpy(r, p, y)
            },
            gyro_bias: robot.config.imu.gyro_bias,
            accel_bias: robot.config.imu.accel_bias,
            n,
            times: vec![Duration::ZERO; names.len()],
            names,
        })
    }

    /// Moves each bus onto its own thread: reads and writes of all buses then overlap.
    pub fn parallel(self) -> Result<Self, IoError> {
        self.parallel_with(|| {})
    }

    /// [`Self::parallel`], running `on_start` first on each bus thread (real-time set-up of the
    /// thread, or instrumentation in tests).
    pub fn parallel_with(mut self, on_start: fn()) -> Result<Self, IoError> {
        for (i, (bus, joints)) in std::mem::take(&mut self.buses).into_iter().enumerate() {
            let w = Worker::spawn(bus, joints, self.n, i, on_start)
                .map_err(|e| IoError::Setup(format!("cannot start a bus thread: {e}")))?;
            self.workers.push(w);
        }
        Ok(self)
    }

    /// Runs `op` on every worker at once and waits for all; the first error wins.
    fn fan_out(&mut self, op: Op) -> Result<(), IoError> {
        let mut first = None;
        let mut sent = [false; MAX_BUSES];
        for (w, sent) in self.workers.iter_mut().zip(&mut sent) {
            match w.send(op) {
                Ok(()) => *sent = true,
                Err(e) => {
                    first.get_or_insert(e);
                }
            }
        }
        for (w, _) in self.workers.iter_mut().zip(sent).filter(|(_, s)| *s) {
            if let Err(e) = w.wait() {
                first.get_or_insert(e);
            }
        }
        first.map_or(Ok(()), Err)
    }

    /// Checks every device answers with the right identity and configures the servos (torque
    /// off). MIT motors are asked with a *disable* frame, which also leaves them limp.
    pub fn identify(&mut self) -> Result<(), IoError> {
        for (b, _) in &mut self.buses {
            b.identify()?;
        }
        self.fan_out(Op::Identify)
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
        for ((b, _), name) in self.buses.iter_mut().zip(&self.names) {
            b.identities(name, &mut out)?;
        }
        Ok(out)
    }

    /// Reads every bus and the IMU into `state`.
    pub fn read(&mut self, state: &mut RobotState) -> Result<(), IoError> {
        for ((b, _), t) in self.buses.iter_mut().zip(&mut self.times) {
            let started = Instant::now();
            b.read(state)?;
            *t = started.elapsed();
        }
        if !self.workers.is_empty() {
            let r = self.fan_out(Op::Read);
            for (w, t) in self.workers.iter_mut().zip(&mut self.times) {
                let joints = &w.joints;
                let Some(s) = w.slot.as_deref() else { continue };
                *t = s.elapsed;
                for &i in joints {
                    state.q[i] = s.state.q[i];
                    state.qd[i] = s.state.qd[i];
                    state.tau[i] = s.state.tau[i];
                    state.missed[i] = s.state.missed[i];
                    state.faulted[i] = s.state.faulted[i];
                }
            }
            r?;
        }
        match self.imu.poll()? {
            Some(r) if Some(r.received_at) != self.last_imu => {
                self.last_imu = Some(r.received_at);
                // Into the base's axes: bias off, then the mounting rotation.
                let m = self.imu_mount;
                state.gyro = spatial::quat_rotate(m, spatial::sub(r.sample.gyro, self.gyro_bias));
                state.accel = spatial::quat_rotate(m, spatial::sub(r.sample.accel, self.accel_bias));
                state.quat = spatial::quat_mul(r.sample.quat, spatial::quat_conj(m));
                state.imu_missed = 0;
            }
            _ => state.imu_missed = state.imu_missed.saturating_add(1),
        }
        Ok(())
    }

    /// Sends every joint its target (robot order), switching torque on or off per bus as needed.
    pub fn write(&mut self, targets: &[JointTarget]) -> Result<(), IoError> {
        for ((b, _), t) in self.buses.iter_mut().zip(&mut self.times) {
            let started = Instant::now();
            b.write(targets)?;
            *t += started.elapsed();
        }
        if self.workers.is_empty() {
            return Ok(());
        }
        for w in &mut self.workers {
            if let Some(s) = w.slot() {
                s.targets.copy_from_slice(targets);
            }
        }
        let r = self.fan_out(Op::Write);
        for (w, t) in self.workers.iter_mut().zip(&mut self.times) {
            if let Some(s) = w.slot() {
                *t += s.elapsed;
            }
        }
        r
    }

    /// Torque off everywhere (best effort on every bus, first error reported).
    pub fn torque_off(&mut self) -> Result<(), IoError> {
        let mut first: Option<IoError> = None;
        for (b, _) in &mut self.buses {
            if let Err(e) = b.torque_off() {
                first.get_or_insert(e);
            }
        }
        if let Err(e) = self.fan_out(Op::TorqueOff) {
            first.get_or_insert(e);
        }
        first.map_or(Ok(()), Err)
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
