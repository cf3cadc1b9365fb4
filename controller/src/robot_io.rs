//! The robot as the loop sees it: every bus driver of a robot description behind one read/write
//! pair, in the robot's joint order. The same code drives the mirror in lockstep, the mirror over
//! real wires, and the hardware; only the transports differ.

use firmware_bridge::can::CanBus;
use firmware_bridge::dxl::driver::{DxlBusDriver, DxlCommand, DxlDriverOptions, DxlError};
use firmware_bridge::dxl::transport::DxlTransport;
use firmware_bridge::imu::reader::ImuReader;
use firmware_bridge::mit::codec::MotorFault;
use firmware_bridge::mit::driver::{JointCommand, MitBusDriver, MitError};
use std::sync::{Arc, Mutex, PoisonError};
use std::time::{Duration, Instant};

use calibration::rig::DeviceIdentity;
use firmware_bridge::dxl::models as dxl_models;
use firmware_bridge::dxl::table::addr;
use firmware_bridge::serial::ByteStream;
use robots::{BusKind, Robot, drivers};

/// A joint command in robot order: PD target and feed-forward torque.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct JointTarget {
    /// Position target, rad.
    pub q: f64,
    /// Velocity target, rad/s.
    pub qd: f64,
    /// Stiffness, N·m/rad.
    pub kp: f64,
    /// Damping, N·m·s/rad.
    pub kd: f64,
    /// Feed-forward torque, N·m.
    pub tau: f64,
    /// Torque on. Off: the joint is limp.
    pub enabled: bool,
}

/// The robot's measured state, robot joint order.
#[derive(Debug, Clone, PartialEq)]
pub struct RobotState {
    /// Joint positions, rad.
    pub q: Vec<f64>,
    /// Joint velocities, rad/s.
    pub qd: Vec<f64>,
    /// Joint torques (estimates), N·m.
    pub tau: Vec<f64>,
    /// Consecutive reads without fresh feedback, per joint.
    pub missed: Vec<u32>,
    /// A device reports a fault, per joint.
    pub faulted: Vec<bool>,
    /// IMU angular velocity, rad/s.
    pub gyro: [f64; 3],
    /// IMU specific force, m/s².
    pub accel: [f64; 3],
    /// IMU orientation `[w, x, y, z]`.
    pub quat: [f64; 4],
    /// Consecutive reads without a new IMU sample.
    pub imu_missed: u32,
}

impl RobotState {
    /// A state for `n` joints, nothing measured yet.
    pub fn new(n: usize) -> Self {
        Self {
            q: vec![0.0; n],
            qd: vec![0.0; n],
            tau: vec![0.0; n],
            missed: vec![u32::MAX; n],
            faulted: vec![false; n],
            gyro: [0.0; 3],
            accel: [0.0; 3],
            quat: [1.0, 0.0, 0.0, 0.0],
            imu_missed: u32::MAX,
        }
    }
}

/// Why the buses failed as a whole (single-device trouble shows in [`RobotState`]).
#[derive(Debug, thiserror::Error)]
pub enum IoError {
    /// A CAN bus failed.
    #[error("CAN")]
    Mit(#[from] MitError),
    /// A Dynamixel bus failed.
    #[error("Dynamixel")]
    Dxl(#[from] DxlError),
    /// The IMU stream failed.
    #[error("IMU")]
    Imu(#[from] std::io::Error),
    /// The robot description and the ports do not fit.
    #[error("{0}")]
    Setup(String),
}

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
pub trait JointBus: Send + std::fmt::Debug {
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
        // MIT motors answer commands: repeating the last one is the read.
        self.driver.cycle(&self.commands)?;
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

impl<D: DxlTransport + Send + std::fmt::Debug> JointBus for Bus<DxlBusDriver<D>, DxlCommand>
where
    D::Instant: Send,
{
    fn identify(&mut self) -> Result<(), IoError> {
        self.driver.configure()?;
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
        // Dynamixel position servos have no pure-damping mode: joints asked for kp = 0 go limp
        // (the gearbox resists), which is the damped state for these joints.
        let want = self
            .joints
            .iter()
            .all(|&i| targets[i].enabled && targets[i].kp > 0.0);
        for (c, &i) in self.commands.iter_mut().zip(&self.joints) {
            *c = DxlCommand {
                q: targets[i].q,
                current: 0.0,
            };
        }
        if want {
            // Goals first, so torque comes on towards the target, not a stale goal.
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

/// What a bus worker is asked to do.
#[derive(Debug, Clone, Copy)]
enum Op {
    Identify,
    Read,
    Write,
    TorqueOff,
}

/// Buffers a worker and the loop share.
#[derive(Debug)]
struct Slot {
    state: RobotState,
    targets: Vec<JointTarget>,
    elapsed: Duration,
}

/// A bus serviced on its own thread, so the I/O phase costs the slowest bus, not the sum.
#[derive(Debug)]
struct Worker {
    ops: Option<crossbeam::channel::Sender<Op>>,
    done: crossbeam::channel::Receiver<Result<(), IoError>>,
    slot: Arc<Mutex<Slot>>,
    joints: Vec<usize>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl Worker {
    fn spawn(
        mut bus: Box<dyn JointBus>,
        joints: Vec<usize>,
        n: usize,
        index: usize,
    ) -> std::io::Result<Self> {
        let (ops, rx) = crossbeam::channel::bounded::<Op>(1);
        let (tx, done) = crossbeam::channel::bounded::<Result<(), IoError>>(1);
        let slot = Arc::new(Mutex::new(Slot {
            state: RobotState::new(n),
            targets: vec![JointTarget::default(); n],
            elapsed: Duration::ZERO,
        }));
        let shared = Arc::clone(&slot);
        let thread = std::thread::Builder::new()
            .name(format!("bus-{index}"))
            .spawn(move || {
                while let Ok(op) = rx.recv() {
                    let mut s = shared.lock().unwrap_or_else(PoisonError::into_inner);
                    let Slot {
                        state,
                        targets,
                        elapsed,
                    } = &mut *s;
                    let started = Instant::now();
                    let r = match op {
                        Op::Identify => bus.identify(),
                        Op::Read => bus.read(state),
                        Op::Write => bus.write(targets),
                        Op::TorqueOff => bus.torque_off(),
                    };
                    *elapsed = started.elapsed();
                    drop(s);
                    if tx.send(r).is_err() {
                        break;
                    }
                }
            })?;
        Ok(Self {
            ops: Some(ops),
            done,
            slot,
            joints,
            thread: Some(thread),
        })
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, Slot> {
        self.slot.lock().unwrap_or_else(PoisonError::into_inner)
    }
}

impl Drop for Worker {
    fn drop(&mut self) {
        // Closing the channel ends the worker's loop.
        self.ops.take();
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// The robot as the loop drives it: identify, read, write, torque off. [`BusRobot`] is the real
/// thing (on hardware or a mirror); a replay feeds a recording through the same loop.
pub trait RobotLink: std::fmt::Debug {
    /// Checks every device answers with the right identity; leaves them limp.
    fn identify(&mut self) -> Result<(), IoError>;
    /// Reads every bus and the IMU into `state`.
    fn read(&mut self, state: &mut RobotState) -> Result<(), IoError>;
    /// Sends every joint its target (robot order).
    fn write(&mut self, targets: &[JointTarget]) -> Result<(), IoError>;
    /// Torque off everywhere.
    fn torque_off(&mut self) -> Result<(), IoError>;
    /// Bus names, in the order of [`Self::bus_times`].
    fn bus_names(&self) -> &[String] {
        &[]
    }
    /// Time each bus took in the last read + write.
    fn bus_times(&self) -> &[Duration] {
        &[]
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
            let n = idx.len();
            let bus = Bus {
                driver: DxlBusDriver::new(port, cfg, dxl)?,
                joints: idx.clone(),
                commands: vec![DxlCommand::default(); n],
                enabled: false,
            };
            buses.push((Box::new(bus), idx));
            names.push(name);
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
                sim2real::mirror::quat_rpy(r, p, y)
            },
            gyro_bias: robot.config.imu.gyro_bias,
            accel_bias: robot.config.imu.accel_bias,
            n,
            times: vec![Duration::ZERO; names.len()],
            names,
        })
    }

    /// Moves each bus onto its own thread: reads and writes of all buses then overlap.
    pub fn parallel(mut self) -> Result<Self, IoError> {
        for (i, (bus, joints)) in std::mem::take(&mut self.buses).into_iter().enumerate() {
            let w = Worker::spawn(bus, joints, self.n, i)
                .map_err(|e| IoError::Setup(format!("cannot start a bus thread: {e}")))?;
            self.workers.push(w);
        }
        Ok(self)
    }

    /// Runs `op` on every worker at once and waits for all; the first error wins.
    fn fan_out(&mut self, op: Op) -> Result<(), IoError> {
        for w in &self.workers {
            if let Some(ops) = &w.ops {
                ops.send(op)
                    .map_err(|_| IoError::Setup("a bus thread stopped".into()))?;
            }
        }
        let mut first = None;
        for w in &self.workers {
            match w.done.recv() {
                Ok(Ok(())) => {}
                Ok(Err(e)) => {
                    first.get_or_insert(e);
                }
                Err(_) => {
                    first.get_or_insert(IoError::Setup("a bus thread stopped".into()));
                }
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
            for (w, t) in self.workers.iter().zip(&mut self.times) {
                let s = w.lock();
                *t = s.elapsed;
                for &i in &w.joints {
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
                let minus = |v: [f64; 3], b: [f64; 3]| [v[0] - b[0], v[1] - b[1], v[2] - b[2]];
                state.gyro = sim2real::mirror::rotate(m, minus(r.sample.gyro, self.gyro_bias));
                state.accel = sim2real::mirror::rotate(m, minus(r.sample.accel, self.accel_bias));
                state.quat = firmware_bridge::imu::emulator::mul(r.sample.quat, [m[0], -m[1], -m[2], -m[3]]);
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
        for w in &self.workers {
            w.lock().targets.copy_from_slice(targets);
        }
        let r = self.fan_out(Op::Write);
        for (w, t) in self.workers.iter().zip(&mut self.times) {
            *t += w.lock().elapsed;
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
