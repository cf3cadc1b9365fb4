//! The robot as the loop sees it: every bus driver of a robot description behind one read/write
//! pair, in the robot's joint order. The same code drives the mirror in lockstep, the mirror over
//! real wires, and the hardware; only the transports differ.

use firmware_bridge::can::CanBus;
use firmware_bridge::dxl::driver::{DxlBusDriver, DxlCommand, DxlDriverOptions, DxlError};
use firmware_bridge::dxl::transport::DxlTransport;
use firmware_bridge::imu::reader::ImuReader;
use firmware_bridge::mit::codec::MotorFault;
use firmware_bridge::mit::driver::{JointCommand, MitBusDriver, MitError};
use firmware_bridge::serial::ByteStream;
use robots::{BusKind, Robot, drivers};
use std::time::Duration;

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

/// Every bus of a robot.
#[derive(Debug)]
pub struct BusRobot<C: CanBus, D: DxlTransport, S: ByteStream> {
    mit: Vec<Bus<MitBusDriver<C>, JointCommand>>,
    dxl: Vec<Bus<DxlBusDriver<D>, DxlCommand>>,
    imu: ImuReader<S>,
    last_imu: Option<S::Instant>,
}

/// One bus: its driver, the robot index of each of its joints, its command buffer, torque state.
#[derive(Debug)]
struct Bus<Driver, Command> {
    driver: Driver,
    joints: Vec<usize>,
    commands: Vec<Command>,
    enabled: bool,
}

impl<C: CanBus, D: DxlTransport, S: ByteStream> BusRobot<C, D, S> {
    /// Drivers for `robot` on `ports`. Nothing is sent yet.
    pub fn new(
        robot: &Robot,
        ports: BusPorts<C, D, S>,
        reply_timeout: Duration,
        dxl: DxlDriverOptions,
    ) -> Result<Self, IoError> {
        let mut mit = Vec::new();
        for (name, port) in ports.can {
            check_kind(robot, &name, BusKind::MitCan)?;
            let (idx, cfg): (Vec<_>, Vec<_>) = robot
                .joints_on(&name)
                .map(|(i, j)| (i, drivers::mit_joint(j)))
                .unzip();
            let n = idx.len();
            mit.push(Bus {
                driver: MitBusDriver::new(port, cfg, reply_timeout)?,
                joints: idx,
                commands: vec![JointCommand::default(); n],
                enabled: false,
            });
        }
        let mut dxl_drivers = Vec::new();
        for (name, port) in ports.dxl {
            check_kind(robot, &name, BusKind::Dynamixel)?;
            let (idx, cfg): (Vec<_>, Vec<_>) = robot
                .joints_on(&name)
                .map(|(i, j)| (i, drivers::dxl_joint(j)))
                .unzip();
            let n = idx.len();
            dxl_drivers.push(Bus {
                driver: DxlBusDriver::new(port, cfg, dxl)?,
                joints: idx,
                commands: vec![DxlCommand::default(); n],
                enabled: false,
            });
        }
        let covered: usize = mit.iter().map(|b| b.joints.len()).sum::<usize>()
            + dxl_drivers.iter().map(|b| b.joints.len()).sum::<usize>();
        if covered != robot.config.joints.len() {
            return Err(IoError::Setup(format!(
                "the ports reach {covered} of the robot's {} joints",
                robot.config.joints.len()
            )));
        }
        Ok(Self {
            mit,
            dxl: dxl_drivers,
            imu: ImuReader::new(ports.imu),
            last_imu: None,
        })
    }

    /// Checks every device answers with the right identity and configures the servos (torque
    /// off). MIT motors are asked with a *disable* frame, which also leaves them limp.
    pub fn identify(&mut self) -> Result<(), IoError> {
        for b in &mut self.mit {
            b.driver.disable_all()?;
            b.enabled = false;
        }
        for b in &mut self.dxl {
            b.driver.configure()?;
            b.enabled = false;
        }
        Ok(())
    }

    /// Reads every bus (MIT motors by repeating the last command) and the IMU into `state`.
    pub fn read(&mut self, state: &mut RobotState) -> Result<(), IoError> {
        for b in &mut self.mit {
            b.driver.cycle(&b.commands)?;
            for (f, &i) in b.driver.feedback().iter().zip(&b.joints) {
                state.q[i] = f.q;
                state.qd[i] = f.qd;
                state.tau[i] = f.tau;
                state.missed[i] = f.missed_cycles;
                state.faulted[i] = !matches!(f.fault, MotorFault::None);
            }
        }
        for b in &mut self.dxl {
            b.driver.read_state()?;
            for (f, &i) in b.driver.feedback().iter().zip(&b.joints) {
                state.q[i] = f.q;
                state.qd[i] = f.qd;
                state.tau[i] = f.tau;
                state.missed[i] = f.missed_cycles;
                state.faulted[i] = f.hardware_error != 0;
            }
        }
        match self.imu.poll()? {
            Some(r) if Some(r.received_at) != self.last_imu => {
                self.last_imu = Some(r.received_at);
                state.gyro = r.sample.gyro;
                state.accel = r.sample.accel;
                state.quat = r.sample.quat;
                state.imu_missed = 0;
            }
            _ => state.imu_missed = state.imu_missed.saturating_add(1),
        }
        Ok(())
    }

    /// Sends every joint its target (robot order), switching torque on or off per bus as needed.
    pub fn write(&mut self, targets: &[JointTarget]) -> Result<(), IoError> {
        for b in &mut self.mit {
            let want = b.joints.iter().any(|&i| targets[i].enabled);
            if want != b.enabled {
                if want {
                    b.driver.enable_all()?;
                } else {
                    b.driver.disable_all()?;
                }
                b.enabled = want;
            }
            for (c, &i) in b.commands.iter_mut().zip(&b.joints) {
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
            b.driver.cycle(&b.commands)?;
        }
        for b in &mut self.dxl {
            // Dynamixel position servos have no pure-damping mode: joints asked for kp = 0 go
            // limp (the gearbox resists), which is the damped state for these joints.
            let want = b
                .joints
                .iter()
                .all(|&i| targets[i].enabled && targets[i].kp > 0.0);
            for (c, &i) in b.commands.iter_mut().zip(&b.joints) {
                *c = DxlCommand {
                    q: targets[i].q,
                    current: 0.0,
                };
            }
            if want {
                // Goals first, so torque comes on towards the target, not a stale goal.
                b.driver.write_goals(&b.commands)?;
            }
            if want != b.enabled {
                if want {
                    b.driver.enable()?;
                } else {
                    b.driver.disable()?;
                }
                b.enabled = want;
            }
        }
        Ok(())
    }

    /// Torque off everywhere (best effort on every bus, first error reported).
    pub fn torque_off(&mut self) -> Result<(), IoError> {
        let mut first: Option<IoError> = None;
        for b in &mut self.mit {
            b.commands.fill(JointCommand::default());
            b.enabled = false;
            if let Err(e) = b.driver.disable_all() {
                first.get_or_insert(e.into());
            }
        }
        for b in &mut self.dxl {
            b.enabled = false;
            if let Err(e) = b.driver.disable() {
                first.get_or_insert(e.into());
            }
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
