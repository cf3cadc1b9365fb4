//! The robot link on the mirror: the robot's real bus drivers on the mirror's ports, in lockstep
//! (simulated time advances only while the host waits on its buses or for its next tick) or served
//! in real time over real wires, and the clocks that go with each.

use std::net::{IpAddr, Ipv4Addr};
use std::sync::atomic::{AtomicU32, Ordering};
use std::sync::{Arc, Mutex, PoisonError};
use std::time::Duration;

use firmware_bridge::can::socketcand::SocketcandClient;
use firmware_bridge::dxl::driver::DxlDriverOptions;
use firmware_bridge::dxl::transport::SerialDxlPort;
use firmware_bridge::feetech::driver::SerialFeetechPort;
use firmware_bridge::serial::{DeviceStream, LockstepStream};
use firmware_bridge::time::SimInstant;
use firmware_bridge::time::SimWorld;
use firmware_bridge::unitree::wire::DdsLowLevelPort;
use robot_link::{
    BusPorts, BusRobot, GroundTruth, IoError, JointTarget, RobotLink, RobotState, TickClock, WallClock,
};
use robots::Robot;

use crate::mirror::Mirror;
use crate::serve::ServedMirror;

/// The robot's buses on a mirror in lockstep.
pub type LockstepRobot = BusRobot<LockstepStream<Mirror>>;

/// The robot's buses on a served mirror, over socketcand and pseudo-terminals.
pub type WiredRobot = BusRobot<DeviceStream>;

/// Reply timeout of MIT motors in lockstep (simulated time).
const LOCKSTEP_REPLY: Duration = Duration::from_millis(2);

/// Drivers on every bus of `world`, in lockstep.
pub fn lockstep_robot(robot: &Robot, world: &Arc<Mutex<Mirror>>) -> Result<LockstepRobot, IoError> {
    let ports = Mirror::host_ports(world);
    let options = DxlDriverOptions {
        expected_return_delay: Duration::ZERO,
        ..DxlDriverOptions::default()
    };
    let link = BusRobot::new(
        robot,
        BusPorts {
            can: ports.can,
            dxl: ports.dxl,
            feetech: ports.feetech,
            unitree: ports.unitree,
            imu: ports.imu,
        },
        LOCKSTEP_REPLY,
        options,
    )?;
    with_mirror_switches(link, robot, world)
}

/// The robot on a direct mirror ([`crate::config::Fidelity::Direct`]): the loop's commands go
/// straight to the simulation's actuator laws and its state comes straight back, in lockstep
/// with [`LockstepClock`]; no device to identify, no bus to cycle.
#[derive(Debug)]
pub struct DirectRobot {
    world: Arc<Mutex<Mirror>>,
    switches: Option<MirrorSwitches>,
    feet: usize,
    joints: usize,
}

/// The link of a direct mirror; refused for a mirror with wires.
pub fn direct_robot(robot: &Robot, world: &Arc<Mutex<Mirror>>) -> Result<DirectRobot, IoError> {
    let mut w = world
        .lock()
        .map_err(|_| IoError::Setup("the mirror's lock is poisoned".into()))?;
    if !w.read_directly(&mut RobotState::new(robot.config.joints.len())) {
        return Err(IoError::Setup(
            "the mirror has wires: a direct link needs a mirror of direct fidelity".into(),
        ));
    }
    let switches = if robot.config.contacts.is_empty() {
        None
    } else {
        Some(MirrorSwitches {
            closed: w.foot_switches().map_err(IoError::Setup)?,
        })
    };
    drop(w);
    Ok(DirectRobot {
        world: Arc::clone(world),
        switches,
        feet: robot.config.feet.len(),
        joints: robot.config.joints.len(),
    })
}

impl RobotLink for DirectRobot {
    fn identify(&mut self) -> Result<(), IoError> {
        Ok(())
    }

    fn read(&mut self, state: &mut RobotState) -> Result<(), IoError> {
        self.world
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .read_directly(state);
        match &mut self.switches {
            Some(s) => {
                use robot_link::contacts::ContactSource;
                state.foot_switches.resize(self.feet, false);
                s.read(&mut state.foot_switches)?;
            }
            None => state.foot_switches.clear(),
        }
        Ok(())
    }

    fn write(&mut self, targets: &[JointTarget]) -> Result<(), IoError> {
        self.world
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .command_directly(targets);
        Ok(())
    }

    fn torque_off(&mut self) -> Result<(), IoError> {
        let limp = vec![JointTarget::default(); self.joints];
        self.write(&limp)
    }
}

/// A robot with foot switches (robot.toml `[[contacts]]`) gets the mirror's behind the same trait
/// as GPIO lines, in lockstep and on the wall clock alike.
fn with_mirror_switches<S: firmware_bridge::serial::ByteStream>(
    link: BusRobot<S>,
    robot: &Robot,
    world: &Arc<Mutex<Mirror>>,
) -> Result<BusRobot<S>, IoError> {
    if robot.config.contacts.is_empty() {
        return Ok(link);
    }
    let closed = world
        .lock()
        .map_err(|_| IoError::Setup("the mirror's lock is poisoned".into()))?
        .foot_switches()
        .map_err(IoError::Setup)?;
    Ok(link.with_contacts(Box::new(MirrorSwitches { closed })))
}

/// Foot switches on the mirror: the word of closed switches the mirror publishes after every
/// physics step (read without its lock: the loop never waits for the simulation's thread).
#[derive(Debug)]
struct MirrorSwitches {
    closed: Arc<AtomicU32>,
}

impl robot_link::contacts::ContactSource for MirrorSwitches {
    fn read(&mut self, out: &mut [bool]) -> Result<(), IoError> {
        let bits = self.closed.load(Ordering::Acquire);
        for (f, o) in out.iter_mut().enumerate() {
            *o = f < 32 && bits & (1 << f) != 0;
        }
        Ok(())
    }
}

/// Drivers on every bus of a served mirror, connected as to hardware, each bus on its own thread.
pub fn wired_robot(robot: &Robot, served: &ServedMirror) -> Result<WiredRobot, IoError> {
    wired_robot_with(robot, served, || {})
}

/// [`wired_robot`], running `on_start` first on each bus thread.
pub fn wired_robot_with(robot: &Robot, served: &ServedMirror, on_start: fn()) -> Result<WiredRobot, IoError> {
    let ep = served.endpoints();
    let mut can = Vec::new();
    for (name, addr) in &ep.can {
        let client = SocketcandClient::connect(addr, name, Duration::from_secs(2))
            .map_err(|e| IoError::Setup(format!("{name} at {addr}: {e}")))?;
        can.push((name.clone(), client));
    }
    let mut dxl = Vec::new();
    for (name, path) in &ep.dxl {
        let rate = robot.bus(name).map_or(1_000_000, |b| b.rate);
        dxl.push((
            name.clone(),
            SerialDxlPort::open(path, rate).map_err(|e| IoError::Setup(format!("{path}: {e}")))?,
        ));
    }
    let mut feetech = Vec::new();
    for (name, path) in &ep.feetech {
        let rate = robot.bus(name).map_or(1_000_000, |b| b.rate);
        feetech.push((
            name.clone(),
            SerialFeetechPort::open(path, rate).map_err(|e| IoError::Setup(format!("{path}: {e}")))?,
        ));
    }
    let mut unitree = Vec::new();
    for (name, config) in &ep.unitree {
        let port = DdsLowLevelPort::open(config).map_err(|e| {
            IoError::Setup(format!(
                "{name} on {} (domain {}): {e}",
                config.interface, config.domain
            ))
        })?;
        unitree.push((name.clone(), port));
    }
    let imu = match &ep.imu {
        Some(path) => {
            let imu_rate = robot.bus(&robot.config.imu.bus).map_or(921_600, |b| b.rate);
            Some(DeviceStream::open(path, imu_rate).map_err(|e| IoError::Setup(format!("{path}: {e}")))?)
        }
        None => None,
    };
    let options = DxlDriverOptions {
        // A pseudo-terminal on a busy machine needs more margin than a USB adapter.
        reply_slack: Duration::from_millis(5),
        ..DxlDriverOptions::default()
    };
    // Buses on their own threads: the tick's I/O costs the slowest bus.
    let link = BusRobot::new(
        robot,
        BusPorts {
            can,
            dxl,
            feetech,
            unitree,
            imu,
        },
        Duration::from_millis(20),
        options,
    )?;
    with_mirror_switches(link, robot, &served.world)?.parallel_with(on_start)
}

/// Serves `mirror` on loopback (free ports) for a wired run.
pub fn serve_locally(mirror: Mirror) -> std::io::Result<ServedMirror> {
    ServedMirror::start(mirror, IpAddr::V4(Ipv4Addr::LOCALHOST), 0)
}

/// Fills `truth` from the mirror under one lock; returns the mirror's time then.
fn truth_of(world: &Arc<Mutex<Mirror>>, truth: &mut GroundTruth) -> SimInstant {
    let w = world.lock().unwrap_or_else(PoisonError::into_inner);
    w.ground_truth(
        &mut truth.root_pose,
        &mut truth.base_lin_vel,
        &mut truth.foot_contacts,
    );
    truth.simulation_failed = w.diverged().is_some();
    w.now()
}

/// The mirror's clock, advanced by the loop.
#[derive(Debug)]
pub struct LockstepClock {
    world: Arc<Mutex<Mirror>>,
    start: SimInstant,
}

impl LockstepClock {
    /// Starts at the mirror's current time.
    pub fn new(world: Arc<Mutex<Mirror>>) -> Self {
        let start = world.lock().unwrap_or_else(PoisonError::into_inner).now();
        Self { world, start }
    }
}

impl TickClock for LockstepClock {
    fn elapsed(&self) -> Duration {
        self.world.lock().unwrap_or_else(PoisonError::into_inner).now() - self.start
    }

    fn wait_until(&mut self, deadline: Duration) -> bool {
        let mut w = self.world.lock().unwrap_or_else(PoisonError::into_inner);
        let target = self.start + deadline;
        let late = w.now() > target;
        while w.now() < target {
            w.step_until(target);
        }
        late
    }

    fn ground_truth(&self, truth: &mut GroundTruth) -> bool {
        truth_of(&self.world, truth);
        true
    }
}

/// The wall clock of a served mirror, with the mirror's ground truth and how late it is: its
/// simulation behind real time, or its threads kept off the CPU.
#[derive(Debug)]
pub struct ServedClock {
    wall: WallClock,
    world: Arc<Mutex<Mirror>>,
    /// The mirror's time when the clock started.
    origin: SimInstant,
    starvation: Option<firmware_bridge::time::StarvationReader>,
}

impl ServedClock {
    /// Starts now.
    pub fn new(world: Arc<Mutex<Mirror>>) -> Self {
        let origin = world.lock().unwrap_or_else(PoisonError::into_inner).now();
        Self {
            wall: WallClock::start(),
            world,
            origin,
            starvation: None,
        }
    }

    /// Starts now on `served`, whose threads' starvation counts as lateness too.
    pub fn of(served: &ServedMirror) -> Self {
        Self {
            starvation: Some(served.starvation()),
            ..Self::new(Arc::clone(&served.world))
        }
    }
}

impl TickClock for ServedClock {
    fn elapsed(&self) -> Duration {
        self.wall.elapsed()
    }

    fn wait_until(&mut self, deadline: Duration) -> bool {
        self.wall.wait_until(deadline)
    }

    fn ground_truth(&self, truth: &mut GroundTruth) -> bool {
        let simulated = truth_of(&self.world, truth) - self.origin;
        let starved = self.starvation.as_ref().map_or(Duration::ZERO, |s| s.recent());
        truth.mirror_behind = self.wall.elapsed().saturating_sub(simulated).max(starved);
        true
    }
}

/// The mirror in lockstep, paced by the wall clock: the mirror runs to each deadline, then the
/// loop waits for the same deadline in real time. Live inputs (trackers) arrive in real time, so a
/// teleoperated mirror must keep pace with them; the buses stay deterministic in-process.
#[derive(Debug)]
pub struct PacedLockstepClock {
    sim: LockstepClock,
    wall: WallClock,
}

impl PacedLockstepClock {
    /// Starts now, at the mirror's current time.
    pub fn new(world: Arc<Mutex<Mirror>>) -> Self {
        Self {
            sim: LockstepClock::new(world),
            wall: WallClock::start(),
        }
    }
}

impl TickClock for PacedLockstepClock {
    fn elapsed(&self) -> Duration {
        self.wall.elapsed()
    }

    fn wait_until(&mut self, deadline: Duration) -> bool {
        self.sim.wait_until(deadline);
        self.wall.wait_until(deadline)
    }

    fn ground_truth(&self, truth: &mut GroundTruth) -> bool {
        self.sim.ground_truth(truth)
    }
}
