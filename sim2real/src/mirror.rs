//! The mirror: a robot's MuJoCo model behind its buses. Every joint is driven by the emulated
//! firmware of its real actuator (MIT-mode motor on a virtual CAN bus, Dynamixel servo on a serial
//! line), the IMU streams WIT packets on its own line, and the controller reaches all of them
//! through the same host ports it would use on hardware.
//!
//! Time is one event loop over physics steps, firmware periods, frame and byte arrivals, IMU
//! outputs and scheduled faults. In lockstep it advances only when a host port waits, so a run
//! is a pure function of its seed; `sim serve` drives the same loop from the wall clock.

use std::sync::atomic::{AtomicBool, AtomicU32, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use firmware_bridge::can::virtual_bus::{LockstepCanPort, VirtualCanBus, VirtualCanNode};
use firmware_bridge::dxl::servo::{ReplyFault, ServoConfig, XSeriesServo};
use firmware_bridge::dxl::table::hw;
use firmware_bridge::dxl::transport::LockstepDxlPort;
use firmware_bridge::dxl::wire::{ServoChain, SimDxlWire, WireTiming};
use firmware_bridge::feetech::driver::LockstepFeetechPort;
use firmware_bridge::feetech::servo::{StsConfig, StsServo};
use firmware_bridge::feetech::wire::{FeetechChain, SimFeetechWire};
use firmware_bridge::half_duplex::LineDevices;
use firmware_bridge::imu::bno055::{self, Bno055};
use firmware_bridge::imu::emulator::{ImuEmulatorConfig, ImuTruth, WitImuEmulator};
use firmware_bridge::mit::codec::MotorFault;
use firmware_bridge::mit::firmware::{InjectedFaults, MitFirmwareConfig, MitMotorFirmware, PdLaw};
use firmware_bridge::plant::MotorPlant;
use firmware_bridge::serial::{LockstepStream, SerialSimWorld, StreamLine};
use firmware_bridge::time::SimWorld;
use firmware_bridge::time::{SimInstant, SimRng};
use firmware_bridge::unitree::board::{BoardConfig, BoardFault, BoardMotor, UnitreeBoard};
use firmware_bridge::unitree::hg::ImuState as UnitreeImu;
use firmware_bridge::unitree::lockstep::{LockstepUnitreePort, UnitreeWorld};
use mujoco_rs::prelude::*;
use mujoco_rs::wrappers::mj_model::traits::ModelType;
use robot_link::{ImuSample, JointTarget, RobotState};
use robots::spatial::{quat_conj, quat_mul, quat_of_rpy, quat_rotate};
use robots::{ActuatorModel, ActuatorOf, BusKind, Robot};

use crate::config::{FaultKind, Fidelity, MirrorConfig, Range};
use crate::model_index::{self, ModelIndex};
use crate::mujoco::MujocoError;

/// Why a mirror could not be built.
#[derive(Debug, thiserror::Error)]
pub enum MirrorError {
    /// MuJoCo refused the model.
    #[error(transparent)]
    Mujoco(#[from] MujocoError),
    /// The robot and its model disagree.
    #[error("{0}")]
    Robot(String),
}

/// One joint as the mirror sees it: where it lives in MuJoCo and how its actuator meets it.
#[derive(Debug, Clone)]
struct MirrorJoint {
    qpos: usize,
    dof: usize,
    /// Actuator angle = zero_offset + direction · gear · joint angle.
    direction: f64,
    gear: f64,
    zero_offset: f64,
    strength: f64,
    /// A `<position>` actuator of the model driving this joint: it gets the firmware's goal.
    actuator: Option<usize>,
    /// The trainer's actuator law (robot.toml `[[actuators]]`).
    law: ActuatorOf,
    /// The commands of the last `delay + 1` physics steps, newest at `head` (laws the mirror
    /// computes each step; allocated once).
    delayed: Vec<Option<PdLaw>>,
    head: usize,
    /// The joint's passive damping in the model (after randomisation), N·m·s/rad; an implicit PD
    /// adds its own to it.
    passive_damping: f64,
    /// A speed no motor of this joint reaches ([`BLOW_UP_SHARE`] × its velocity limit), rad/s: a
    /// simulation that puts the joint there has blown up.
    blow_up_speed: f64,
    /// robot.toml's name, for messages.
    name: String,
}

/// A joint moving faster than this many times its velocity limit means the simulation blew up (the
/// model is not stable at its step), found before its accelerometer reads tens of g.
pub const BLOW_UP_SHARE: f64 = 10.0;

impl MirrorJoint {
    /// Takes this physics step's command and returns the one that acts now: `delay` steps old.
    fn delay(&mut self, law: Option<PdLaw>) -> Option<PdLaw> {
        let n = self.delayed.len();
        self.head = (self.head + 1) % n;
        self.delayed[self.head] = law;
        self.delayed[(self.head + 1) % n]
    }

    /// The joint torque of a law the mirror computes every physics step, at joint angle `q` and
    /// speed `qd`, within the motor's clamp, the effort limit and a DC motor's torque–speed line.
    fn stepped_torque(&self, law: &PdLaw, q: f64, qd: f64) -> f64 {
        let to_joint = self.direction * self.gear;
        let motor = law.torque(self.zero_offset + to_joint * q, to_joint * qd);
        let limit = self.law.limit(law.limit * self.gear);
        let (low, high) = self.law.torque_bounds(qd, limit);
        (to_joint * motor).clamp(low, high) * self.strength
    }
}

/// The actuator-side view of a joint that firmware reads and drives.
#[derive(Debug, Clone, Copy, Default)]
struct ActuatorPlant {
    q: f64,
    qd: f64,
    torque: f64,
    /// The firmware's position goal (actuator frame), for models with position actuators.
    goal: Option<f64>,
    /// The most torque the firmware lets its motor give, N·m (actuator side).
    torque_cap: f64,
    /// The motor's impedance law while its torque is on (MIT motors).
    law: Option<PdLaw>,
    /// The stiffness and damping of the device's position loop (actuator side), which a
    /// position actuator of the model applies in its stead: the gains robot.toml had written.
    stiffness: Option<[f64; 2]>,
}

impl MotorPlant for ActuatorPlant {
    fn position(&self) -> f64 {
        self.q
    }
    fn velocity(&self) -> f64 {
        self.qd
    }
    fn apply_torque(&mut self, torque: f64) {
        self.torque = torque;
    }
}

#[derive(Debug)]
struct MitMotor {
    node: VirtualCanNode,
    firmware: MitMotorFirmware,
    joint: usize,
}

#[derive(Debug)]
struct CanLine {
    name: String,
    bus: VirtualCanBus,
    motors: Vec<MitMotor>,
}

/// A Unitree robot's board: its motors on their joints (`joints[k]` is motor `k`'s).
#[derive(Debug)]
struct UnitreeLine {
    name: String,
    board: UnitreeBoard,
    joints: Vec<usize>,
}

#[derive(Debug)]
struct DxlLine {
    name: String,
    wire: SimDxlWire,
    joints: Vec<usize>,
}

#[derive(Debug)]
struct FeetechLine {
    name: String,
    wire: SimFeetechWire,
    joints: Vec<usize>,
}

#[derive(Debug)]
struct Imu {
    emulator: WitImuEmulator,
    line: StreamLine,
    /// A part the host asks (BNO055): its registers take the emulator's samples.
    chip: Option<Bno055>,
    /// What the line does to the chip's answers this output period (faults).
    answers: ChipAnswers,
    reply: Vec<u8>,
    gyro: usize,
    accel: usize,
    quat: usize,
    /// Rotation from the site's axes to the IMU's axes (inverse mounting).
    mount: [f64; 4],
    /// The IMU is a Unitree board's (`unitree` line number): its samples go into the board's
    /// state, not onto a line.
    board: Option<usize>,
}

/// What reaches the host of a register-read IMU's answers while a fault lasts.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum ChipAnswers {
    Given,
    /// Nothing comes back (lost or gone).
    Dropped,
    /// Reads answer with the part's read-fail status (its report of a failed transfer).
    ReadFail,
}

#[derive(Debug, Clone, Copy)]
struct Gantry {
    pos: [f64; 3],
    quat: [f64; 4],
    /// Springs on the base's position (N/m) and orientation (N·m/rad), sized for the robot held
    /// (its dampers are the root's joint damping).
    stiffness: [f64; 2],
}

/// A harness: a rope from a crane's hook to the robot's root, taut while it carries weight and
/// slack once the feet do. The hook lowers on a smooth schedule from where the robot hangs at the
/// start to well below where the rope goes slack on a standing robot.
#[derive(Debug, Clone, Copy)]
struct Harness {
    /// Where the root hangs at the start (the rope carrying the whole weight).
    hang: [f64; 3],
    upright: [f64; 4],
    /// The hook's whole travel, m, and its time, s.
    travel: f64,
    lower_s: f64,
    /// Simulated time the hook began to come down: the first step any joint was driven (the
    /// controller took the robot), s.
    lowering_since: Option<f64>,
    /// When the crane began to hoist again (a stop that hands the robot to the harness), and the
    /// height at which the rope then carries the whole weight where the robot stands.
    hoisting: Option<(f64, f64)>,
    /// Robot mass, kg, and the rope's spring, damper (N/m, N·s/m), the pendulum's horizontal
    /// spring and damper, the straps' orientation spring and damper — all scaled by the share of
    /// the weight the rope carries.
    mass: f64,
    gains: [f64; 6],
    /// The root's own damping in the model (its six degrees of freedom), which the harness's
    /// dampers add to.
    root_damping: [f64; 6],
}

/// The rope's stretch under the robot's whole weight sets its stiffness: g / ω².
const HARNESS_OMEGA: f64 = 20.0;
const HARNESS_ZETA: f64 = 0.7;
/// The rope's length from hook to root, m: the pendulum that centres a hanging robot.
const HARNESS_ROPE_M: f64 = 1.5;
/// How far below the taut point the hook ends, m: slack through a dance's deepest squat.
const HARNESS_SLACK_M: f64 = 0.5;
/// Natural frequency of the straps that keep a hanging robot upright, rad/s.
const HARNESS_STRAPS_OMEGA: f64 = 8.0;
const GRAVITY: f64 = 9.81;

/// How stiff the gantry is: the held robot's natural frequency on it, rad/s, and its damping
/// ratio. Gains follow from the robot's mass and inertia, so a 2 kg robot and a 17 kg one sit
/// alike on the stand, and the explicit damping stays far inside its stable step.
const GANTRY_OMEGA: f64 = 35.0;
const GANTRY_ZETA: f64 = 0.7;

/// Counters of a mirror run.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct MirrorStats {
    /// Physics steps taken.
    pub physics_steps: u64,
    /// Firmware periods run.
    pub firmware_ticks: u64,
    /// IMU output cycles sent.
    pub imu_outputs: u64,
    /// Scheduled faults applied.
    pub faults_applied: usize,
    /// CPU time spent inside the mirror (physics, firmware, wires), for benches that separate
    /// the controller's share.
    pub busy: Duration,
    /// Of `busy`, the time in MuJoCo's own step.
    pub physics: Duration,
}

/// The joint index that stands for the IMU in a fault schedule (`joint = "imu"`).
const IMU_TARGET: usize = usize::MAX;

/// A fault on the emulated IMU.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum ImuFault {
    None,
    /// The next this many output cycles are lost.
    Lost(u32),
    /// The next this many output cycles fail their checksums.
    Corrupt(u32),
    /// No output any more.
    Gone,
}

/// The robot variant an emulated Unitree board reports in `mode_machine` (echoed by the host).
const UNITREE_MODE_MACHINE: u8 = 5;
/// The supply voltage an emulated Unitree board's motors report, V (a charged 13-cell pack).
const UNITREE_SUPPLY_V: f32 = 54.6;

/// The mirror's foot switches: per foot (robot.toml `feet` order), whether it has one and the touch
/// sensor standing for it (its `sensordata` address and closing force; `None`: the foot's contacts
/// with anything), and the bits the last physics step closed (bit `f`: foot `f`).
#[derive(Debug)]
struct SwitchWiring {
    wired: Vec<bool>,
    touch: Vec<Option<(usize, f64)>>,
    closed: Arc<AtomicU32>,
}

/// Most feet the mirror's switches publish (bits of one word).
pub const MAX_SWITCHED_FEET: usize = 32;

/// The mirrored robot.
#[derive(Debug)]
pub struct Mirror {
    robot: Robot,
    config: MirrorConfig,
    data: MjData<Box<MjModel>>,
    joints: Vec<MirrorJoint>,
    plants: Vec<ActuatorPlant>,
    can: Vec<CanLine>,
    dxl: Vec<DxlLine>,
    /// Feetech lines: serial lines after the Dynamixel ones.
    feetech: Vec<FeetechLine>,
    /// Unitree boards.
    unitree: Vec<UnitreeLine>,
    imu: Imu,
    /// The newest IMU sample a Unitree board puts in its state.
    board_imu: UnitreeImu,
    gantry: Option<Gantry>,
    harness: Option<Harness>,
    /// The physics waits for the controller's first drive ([`MirrorConfig::hold_until_driven`]).
    held: bool,
    /// Raised by the controller when a stop hands the robot to the harness: the crane hoists.
    hoist: Arc<AtomicBool>,
    /// The robot's foot switches as the simulation closes them, published every physics step.
    switches: Option<SwitchWiring>,
    /// Joint angles a jig holds the joints at (policy order), if any.
    jig: Option<Vec<f64>>,
    root_qpos: usize,
    root_dof: usize,
    root_body: usize,
    feet: Vec<usize>,
    /// Set when the simulation diverged; physics stops there.
    diverged: Option<String>,
    /// A fault scheduled on the IMU.
    imu_fault: ImuFault,
    now: SimInstant,
    physics_dt: Duration,
    next_physics: SimInstant,
    firmware_period: Duration,
    next_firmware: SimInstant,
    faults: Vec<(SimInstant, usize, FaultKind)>,
    /// Pushes on the root: start, end, world force (N).
    pushes: Vec<(SimInstant, SimInstant, [f64; 3])>,
    next_fault: usize,
    peak_torque: f64,
    /// The largest torque each torque-driven joint received at a physics step, N·m (joint side).
    peak_joint_torque: Vec<f64>,
    stats: MirrorStats,
    /// The direct fidelity's exchange with the host (none: the wires).
    direct: Option<Direct>,
}

/// What a direct mirror ([`crate::config::Fidelity::Direct`]) keeps for its host in place of
/// buses: the joints' torque limits its commands are held to, the IMU's samples since the last
/// read.
#[derive(Debug)]
struct Direct {
    /// Each joint's torque limit (robot.toml), N·m.
    torque_limits: Vec<f64>,
    samples: Vec<ImuSample>,
    latest: ImuSample,
    /// A joint has been commanded with torque on.
    driven: bool,
}

/// IMU samples a direct mirror keeps between two reads (the oldest give way).
const DIRECT_SAMPLES: usize = 256;

/// Names the mirror gives the IMU sensors it adds to a model that has none on the IMU's site.
pub const ADDED_IMU_SENSORS: [&str; 3] = [
    "robodeploy_imu_gyro",
    "robodeploy_imu_accelerometer",
    "robodeploy_imu_orientation",
];

/// The robot's compiled model (robot.toml's joint dynamics and [sim] applied) with the IMU's three
/// sensors, and their names: the model's own
/// (robot.toml's names, or the ones on the IMU site), and through MuJoCo's model-editing API a
/// gyro, an accelerometer or a frame orientation on the IMU site for each the model lacks.
fn model_with_imu_sensors(robot: &Robot) -> Result<(MjModel, [String; 3]), MirrorError> {
    use mujoco_rs::mujoco_c::mjtSensor;
    use mujoco_rs::prelude::SpecItem;
    let found = robot.imu_sensors();
    if let [Some(g), Some(a), Some(o)] = &found {
        return Ok((robot.model()?, [g.clone(), a.clone(), o.clone()]));
    }
    let mut spec = robot.spec()?;
    let kinds = [
        mjtSensor::mjSENS_GYRO,
        mjtSensor::mjSENS_ACCELEROMETER,
        mjtSensor::mjSENS_FRAMEQUAT,
    ];
    let mut names = [String::new(), String::new(), String::new()];
    for (((have, kind), added), name) in found.iter().zip(kinds).zip(ADDED_IMU_SENSORS).zip(&mut names) {
        *name = match have {
            Some(n) => n.clone(),
            None => {
                spec.add_sensor()
                    .with_type(kind)
                    .with_objtype(MjtObjBase::mjOBJ_SITE)
                    .with_objname(&robot.config.imu.site)
                    .set_name(added)
                    .map_err(|e| MirrorError::Robot(format!("cannot add IMU sensor {added}: {e}")))?;
                added.to_owned()
            }
        };
    }
    let model = spec.compile().map_err(|e| {
        MirrorError::Robot(format!(
            "{}: cannot compile with the IMU sensors added: {e}",
            robot.mjcf_path.display()
        ))
    })?;
    Ok((model, names))
}

/// `qpos` (the whole model's) in the start pose: the run's `joints` where it gives them, else
/// robot.toml's keyframe, else the default joint angles, at the joints' addresses `joint_qpos`
/// (robot order); the root is left as it is.
fn start_pose(robot: &Robot, joints: Option<&[f64]>, joint_qpos: &[usize], qpos: &mut [f64]) {
    if let Some(joints) = joints {
        for (&a, &q) in joint_qpos.iter().zip(joints) {
            qpos[a] = q;
        }
        return;
    }
    match robot.start_keyframe() {
        Some(k) if k.qpos.len() == qpos.len() => qpos.copy_from_slice(&k.qpos),
        _ => {
            for (&a, cfg) in joint_qpos.iter().zip(&robot.config.joints) {
                qpos[a] = cfg.default_position;
            }
        }
    }
}

/// The control of position actuator `a` that tracks `goal` (joint angle) with the model's own
/// gains but never asks more torque of the joint than the firmware's motor gives
/// (`torque_cap`, actuator side): the force the actuator would make, clamped, and turned back
/// into the setpoint that makes it.
fn capped_position_control(
    data: &MjData<Box<MjModel>>,
    a: usize,
    j: &MirrorJoint,
    goal: f64,
    torque_cap: f64,
) -> f64 {
    let m = data.model();
    let kp = m.actuator_gainprm()[a][0];
    let bias = m.actuator_biasprm()[a];
    let gear = m.actuator_gear()[a][0];
    let (length, velocity) = (gear * data.qpos()[j.qpos], gear * data.qvel()[j.dof]);
    let free = bias[0] + bias[1] * length + bias[2] * velocity;
    let limit = (torque_cap * j.gear / gear.abs()).max(0.0);
    // The setpoint is an actuator length: gear × joint angle.
    if kp <= 0.0 {
        // No stiffness (a servo told to damp only): the setpoint moves nothing; keep it the goal.
        return gear * goal;
    }
    let force = (kp * gear * goal + free).clamp(-limit, limit);
    (force - free) / kp
}

/// Gives position actuator `a` the stiffness and damping `[kp, kd]` at its joint (N·m/rad,
/// N·m·s/rad), where they differ from its own: through the actuator's gear `g` it pushes with
/// `kp / g²` per unit of length.
fn set_position_gains(data: &mut MjData<Box<MjModel>>, a: usize, [kp, kd]: [f64; 2]) {
    let m = data.model();
    let g2 = m.actuator_gear()[a][0].powi(2);
    let (kp, kv) = (kp / g2, kd / g2);
    if m.actuator_gainprm()[a][0] != kp || m.actuator_biasprm()[a][2] != -kv {
        // SAFETY: values of existing arrays change; no size, index or address does (the
        // actuator's gain and bias types stay those of a position actuator).
        #[allow(unsafe_code)]
        unsafe {
            let model = data.model_mut();
            model.actuator_gainprm_mut()[a][0] = kp;
            model.actuator_biasprm_mut()[a][1] = -kp;
            model.actuator_biasprm_mut()[a][2] = -kv;
        }
    }
}

/// Sets the damping of degree of freedom `dof` in the model `data` steps, where it differs.
fn set_dof_damping(data: &mut MjData<Box<MjModel>>, dof: usize, damping: f64) {
    if data.model().dof_damping()[dof] != damping {
        // SAFETY: one value of an existing array changes; no size, index or address does.
        #[allow(unsafe_code)]
        let model = unsafe { data.model_mut() };
        model.dof_damping_mut()[dof] = damping;
    }
}

/// The mass (kg) of the tree rooted at `root_body` and its mean moment of inertia about the root
/// (kg·m²), in `data`'s present pose.
fn held_mass_and_inertia<M: ModelType>(data: &MjData<M>, root_body: usize) -> (f64, f64) {
    let m = data.model();
    let root = data.xpos()[root_body];
    let (mut mass, mut inertia) = (0.0, 0.0);
    for b in 1..m.ffi().nbody as usize {
        if !crate::placement::in_tree(m, b, root_body) {
            continue;
        }
        let bm = m.body_mass()[b];
        let d = data.xipos()[b];
        let r2 = (0..3).map(|i| (d[i] - root[i]).powi(2)).sum::<f64>();
        let own = m.body_inertia()[b];
        mass += bm;
        // Averaged over the three axes: ⅔ m r² from the offset, a third of the trace.
        inertia += 2.0 / 3.0 * bm * r2 + (own[0] + own[1] + own[2]) / 3.0;
    }
    (mass.max(1e-3), inertia.max(1e-6))
}

/// Serial line numbers: Dynamixel lines first (in robot.toml order), then the IMU.
impl Mirror {
    /// Builds the mirror of `robot`: loads and randomises its model, places it in its default
    /// pose standing on the floor (or on the gantry), and wires emulated devices to every bus.
    pub fn new(robot: Robot, config: MirrorConfig) -> Result<Self, MirrorError> {
        if config.fidelity == Fidelity::Direct && !config.faults.is_empty() {
            return Err(MirrorError::Robot(format!(
                "{} scheduled fault(s): faults act on devices and wires, which a mirror of direct \
                 fidelity does not have (use the wires, or pushes, which act on the robot)",
                config.faults.len()
            )));
        }
        let (mut model, imu_sensors) = model_with_imu_sensors(&robot)?;
        if let Some(q) = &config.start_joints
            && (q.len() != robot.config.joints.len() || q.iter().any(|x| !x.is_finite()))
        {
            return Err(MirrorError::Robot(format!(
                "a start pose of {} angles (finite ones) for {} joints",
                q.len(),
                robot.config.joints.len()
            )));
        }
        let mut rng = SimRng::new(config.seed);
        let mut draw = |r: Range| r.0 + (r.1 - r.0) * rng.next_f64();
        let rnd = config.randomization.clone();
        let nbody = model.ffi().nbody as usize;
        for b in 1..nbody {
            let scale = draw(rnd.mass_scale);
            model.body_mass_mut()[b] *= scale;
            for k in 0..3 {
                model.body_inertia_mut()[b][k] *= scale;
            }
        }
        // A slope: the world's planes (the floor) turned about x, then y.
        let [roll, pitch] = config.floor_tilt_deg.map(f64::to_radians);
        if roll != 0.0 || pitch != 0.0 {
            let tilt = quat_of_rpy(roll, pitch, 0.0);
            for g in 0..model.ffi().ngeom as usize {
                if model.body_weldid()[model.geom_bodyid()[g] as usize] == 0
                    && model.geom_type()[g] == mujoco_rs::mujoco_c::_mjtGeomBase::mjGEOM_PLANE
                {
                    let q = model.geom_quat()[g];
                    model.geom_quat_mut()[g] = quat_mul(tilt, q);
                }
            }
        }
        let physics_dt = Duration::try_from_secs_f64(model.ffi().opt.timestep)
            .ok()
            .filter(|d| !d.is_zero())
            .ok_or_else(|| {
                MirrorError::Robot(format!(
                    "the model's timestep {} is not a step",
                    model.ffi().opt.timestep
                ))
            })?;
        let firmware_period = match config.firmware_period_us {
            0 => physics_dt,
            us => Duration::from_micros(us),
        };
        let index = ModelIndex::of_robot(&model, &robot).map_err(|e| MirrorError::Robot(e.to_string()))?;
        let mut joints = Vec::with_capacity(robot.config.joints.len());
        for (j, ids) in robot.config.joints.iter().zip(&index.joints) {
            let id = ids.id;
            // A position servo in the model: joint transmission, gain = -bias (kp), no velocity bias.
            let actuator = (0..model.ffi().nu as usize).find(|&a| {
                model.actuator_trntype()[a] == MjtTrn::mjTRN_JOINT
                    && model.actuator_trnid()[a][0] == id as i32
                    && model.actuator_biasprm()[a][1] < 0.0
                    && (model.actuator_gainprm()[a][0] + model.actuator_biasprm()[a][1]).abs() < 1e-9
            });
            let truth = config.hardware.joints.get(&j.name);
            let law = robot.config.actuator_of(&j.name);
            if law.model.per_physics_step() && actuator.is_some() {
                return Err(MirrorError::Robot(format!(
                    "joint {}: robot.toml's actuator model {} computes a torque, but the model \
                     drives the joint with a <position> actuator",
                    j.name,
                    law.model.name()
                )));
            }
            let [lo, hi] = law.delay_steps.map(f64::from);
            let delay = draw(Range(lo, hi + 1.0)).floor().min(hi) as usize;
            joints.push(MirrorJoint {
                qpos: ids.qpos,
                dof: ids.dof,
                direction: truth.map_or(j.direction, |t| t.direction),
                gear: j.gear,
                // A description's Dynamixel zero counts the Homing Offset the driver programs;
                // the horn's physical angle does not.
                zero_offset: truth.map_or(
                    robots::calibration::physical_zero(j.zero_offset, j.homing_offset_ticks),
                    |t| t.zero_offset,
                ),
                strength: draw(rnd.strength_scale),
                actuator,
                law,
                delayed: vec![None; delay + 1],
                head: 0,
                passive_damping: 0.0,
                blow_up_speed: BLOW_UP_SHARE * j.velocity_limit,
                name: j.name.clone(),
            });
        }
        for j in &mut joints {
            let scale = draw(rnd.friction_scale);
            model.dof_frictionloss_mut()[j.dof] *= scale;
            model.dof_damping_mut()[j.dof] *= scale;
            j.passive_damping = model.dof_damping()[j.dof];
        }
        let sensor = |name: &str| {
            model_index::sensor_address(&model, name).map_err(|e| MirrorError::Robot(e.to_string()))
        };
        let [gyro, accel, quat] = &imu_sensors;
        let (gyro, accel, quat) = (sensor(gyro)?, sensor(accel)?, sensor(quat)?);
        let (root_qpos, root_dof, root_body) = (index.root.qpos, index.root.dof, index.root_body);
        let feet = index.feet.clone();

        // Devices on every bus.
        let mut can = Vec::new();
        let mut dxl_lines = Vec::new();
        let mut feetech_lines = Vec::new();
        let mut unitree = Vec::new();
        let latency = Duration::from_micros(draw(rnd.usb_latency_us).max(0.0) as u64);
        for bus in &robot.config.buses {
            match bus.kind {
                BusKind::MitCan => {
                    let wire = VirtualCanBus::new(&bus.name, bus.rate);
                    let motors = robot
                        .joints_on(&bus.name)
                        .map(|(i, j)| {
                            let m = robot.mit_model(&j.model).expect("checked at load");
                            MitMotor {
                                node: wire.attach(),
                                firmware: MitMotorFirmware::new(MitFirmwareConfig {
                                    // As the motor was set up for this robot.
                                    command_timeout: robot.bus_timing(&bus.name).map(|t| t.command_timeout),
                                    ..MitFirmwareConfig::new(j.id, m)
                                }),
                                joint: i,
                            }
                        })
                        .collect();
                    can.push(CanLine {
                        name: bus.name.clone(),
                        bus: wire,
                        motors,
                    });
                }
                BusKind::Dynamixel => {
                    let mut servos = Vec::new();
                    let mut idx = Vec::new();
                    for (i, j) in robot.joints_on(&bus.name) {
                        let m = robot.dxl_model(&j.model).expect("checked at load");
                        let mut cfg = ServoConfig::new(j.id).on_line(bus.rate, config.servo_return_delay());
                        // The robot supplies its servos at their rated voltage.
                        cfg.supply_voltage = m.nominal_voltage;
                        cfg.control_period = firmware_period;
                        servos.push(XSeriesServo::new(m, cfg));
                        idx.push(i);
                    }
                    let timing = WireTiming {
                        baud: bus.rate,
                        usb_latency: latency,
                    };
                    dxl_lines.push(DxlLine {
                        name: bus.name.clone(),
                        wire: SimDxlWire::new(ServoChain::new(servos, timing)),
                        joints: idx,
                    });
                }
                BusKind::Feetech => {
                    let baud_index =
                        firmware_bridge::feetech::table::index_of_baud(bus.rate).expect("checked at load");
                    let mut servos = Vec::new();
                    let mut idx = Vec::new();
                    for (i, j) in robot.joints_on(&bus.name) {
                        let m = robot.feetech_model(&j.model).expect("checked at load");
                        servos.push(StsServo::new(
                            m,
                            StsConfig {
                                baud_index,
                                control_period: firmware_period,
                                ..StsConfig::new(j.id, m)
                            },
                        ));
                        idx.push(i);
                    }
                    let timing = WireTiming {
                        baud: bus.rate,
                        usb_latency: latency,
                    };
                    feetech_lines.push(FeetechLine {
                        name: bus.name.clone(),
                        wire: SimFeetechWire::new(FeetechChain::new(servos, timing)),
                        joints: idx,
                    });
                }
                BusKind::UnitreeDds => {
                    let timing = robot.bus_timing(&bus.name).expect("checked at load");
                    let (joints, motors): (Vec<_>, Vec<_>) = robot
                        .joints_on(&bus.name)
                        .map(|(i, j)| {
                            let m = robot.mit_model(&j.model).expect("checked at load");
                            let firmware = MitFirmwareConfig {
                                command_timeout: Some(timing.command_timeout),
                                ..MitFirmwareConfig::new(j.id, m)
                            };
                            (
                                i,
                                BoardMotor {
                                    slot: usize::from(j.id),
                                    firmware,
                                },
                            )
                        })
                        .unzip();
                    let board = UnitreeBoard::new(
                        BoardConfig {
                            motors,
                            state_period: timing.period,
                            mode_machine: UNITREE_MODE_MACHINE,
                            supply_voltage: UNITREE_SUPPLY_V,
                        },
                        SimInstant::ZERO,
                    );
                    unitree.push(UnitreeLine {
                        name: bus.name.clone(),
                        board,
                        joints,
                    });
                }
                BusKind::ImuSerial => {}
            }
        }
        let imu_cfg = &robot.config.imu;
        let imu_bus = robot.bus(&imu_cfg.bus).expect("checked at load");
        let n = rnd.imu_noise_scale;
        let d = ImuEmulatorConfig::default();
        let emulator = WitImuEmulator::speaking(
            imu_cfg.protocol,
            ImuEmulatorConfig {
                rate_hz: imu_cfg.rate_hz,
                gyro_noise: d.gyro_noise * n,
                gyro_bias: d.gyro_bias * n,
                accel_noise: d.accel_noise * n,
                accel_bias: d.accel_bias * n,
                attitude_noise: d.attitude_noise * n,
                gyro_bias_walk: rnd.imu_gyro_bias_walk_dps.to_radians(),
                accel_bias_walk: rnd.imu_accel_bias_walk,
            },
            config.seed ^ 0x1u64.rotate_left(40),
        );
        let [r, p, y] = config
            .hardware
            .imu_mounting_rpy_deg
            .unwrap_or(imu_cfg.mounting_rpy_deg)
            .map(f64::to_radians);
        let mounting = quat_of_rpy(r, p, y);
        let imu = Imu {
            chip: (imu_cfg.protocol == firmware_bridge::imu::ImuProtocol::Bno055).then(Bno055::new),
            answers: ChipAnswers::Given,
            reply: Vec::with_capacity(2 * bno055::MAX_LEN),
            emulator,
            line: StreamLine::new(imu_bus.rate),
            gyro,
            accel,
            quat,
            mount: [mounting[0], -mounting[1], -mounting[2], -mounting[3]],
            board: unitree.iter().position(|u| u.name == imu_cfg.bus),
        };

        let mut faults = Vec::new();
        for f in &config.faults {
            let joint =
                if f.joint == "imu" {
                    IMU_TARGET
                } else {
                    robot.config.joints.iter().position(|j| j.name == f.joint).ok_or_else(|| {
                    MirrorError::Robot(format!(
                        "scheduled fault names unknown joint {:?} (a joint of robot.toml, or \"imu\")",
                        f.joint
                    ))
                })?
                };
            if let FaultKind::Silent { count: Some(0) } | FaultKind::CorruptCrc { count: 0 } = f.fault {
                return Err(MirrorError::Robot(format!(
                    "scheduled fault for {:?}: count = 0 is no fault (leave count out: for good)",
                    f.joint
                )));
            }
            if joint == IMU_TARGET && imu.board.is_some() {
                return Err(MirrorError::Robot(
                    "scheduled fault for \"imu\": the IMU is the Unitree board's, in its state; schedule \
                     the board's faults on one of its joints (silent with a count: the states stop)"
                        .into(),
                ));
            }
            if joint == IMU_TARGET && f.fault == FaultKind::Overheat {
                return Err(MirrorError::Robot(
                    "scheduled fault for \"imu\": the IMU has no overheat fault (silent, corrupt_crc, vanish)".into(),
                ));
            }
            let at = Duration::try_from_secs_f64(f.at_s).map_err(|_| {
                MirrorError::Robot(format!(
                    "scheduled fault for {:?}: at_s = {} is not a time",
                    f.joint, f.at_s
                ))
            })?;
            faults.push((SimInstant::ZERO + at, joint, f.fault));
        }
        faults.sort_by_key(|f| f.0);
        let mut pushes = Vec::with_capacity(config.pushes.len());
        for (k, p) in config.pushes.iter().enumerate() {
            let time = |s: f64| {
                Duration::try_from_secs_f64(s)
                    .map(|d| SimInstant::ZERO + d)
                    .map_err(|_| MirrorError::Robot(format!("pushes[{k}]: {s} s is not a time")))
            };
            pushes.push((time(p.at_s)?, time(p.at_s + p.duration_s)?, p.force_n));
        }

        if config.gantry {
            // The stand's dampers act on the root's own degrees of freedom, where MuJoCo
            // integrates joint damping implicitly: as an explicit force they would act on the
            // root body alone (a humanoid's light pelvis) and diverge at a 2 ms step. Sized, like
            // the springs, for the robot in its start pose.
            let (mass, inertia) = {
                let mut posed = model.make_data();
                let joint_qpos: Vec<usize> = joints.iter().map(|j| j.qpos).collect();
                start_pose(
                    &robot,
                    config.start_joints.as_deref(),
                    &joint_qpos,
                    posed.qpos_mut(),
                );
                posed.forward();
                held_mass_and_inertia(&posed, root_body)
            };
            let d = root_dof;
            let damping = model.dof_damping_mut();
            damping[d..d + 3].fill(2.0 * GANTRY_ZETA * mass * GANTRY_OMEGA);
            damping[d + 3..d + 6].fill(2.0 * GANTRY_ZETA * inertia * GANTRY_OMEGA);
        }
        let data = MjData::new(Box::new(model));
        let n_joints = joints.len();
        let mut mirror = Self {
            robot,
            config,
            data,
            joints,
            plants: vec![ActuatorPlant::default(); n_joints],
            can,
            dxl: dxl_lines,
            feetech: feetech_lines,
            unitree,
            imu,
            board_imu: UnitreeImu {
                quaternion: [1.0, 0.0, 0.0, 0.0],
                ..UnitreeImu::default()
            },
            gantry: None,
            harness: None,
            held: false,
            hoist: Arc::new(AtomicBool::new(false)),
            switches: None,
            jig: None,
            root_qpos,
            root_dof,
            root_body,
            feet,
            diverged: None,
            imu_fault: ImuFault::None,
            now: SimInstant::ZERO,
            physics_dt,
            next_physics: SimInstant::ZERO,
            firmware_period,
            next_firmware: SimInstant::ZERO,
            faults,
            pushes,
            next_fault: 0,
            peak_torque: 0.0,
            peak_joint_torque: vec![0.0; n_joints],
            stats: MirrorStats::default(),
            direct: None,
        };
        if mirror.config.fidelity == Fidelity::Direct {
            mirror.direct = Some(Direct {
                torque_limits: mirror
                    .robot
                    .config
                    .joints
                    .iter()
                    .map(|j| j.torque_limit)
                    .collect(),
                samples: Vec::with_capacity(DIRECT_SAMPLES),
                latest: ImuSample::default(),
                driven: false,
            });
        }
        mirror.held = mirror.config.hold_until_driven;
        mirror.place_in_default_pose();
        if mirror.direct.is_some() {
            // The host's first read finds the IMU's start-up reading, as a device answers one.
            mirror.data.forward();
            mirror.sample_imu_directly(SimInstant::ZERO);
        }
        Ok(mirror)
    }

    /// The start: robot.toml's keyframe, else the default joint angles upright; placed by the
    /// compiled geometry with its lowest point on the floor, or lifted 5 cm and held when on the
    /// gantry.
    fn place_in_default_pose(&mut self) {
        let r = self.root_qpos;
        let joint_qpos: Vec<usize> = self.joints.iter().map(|j| j.qpos).collect();
        start_pose(
            &self.robot,
            self.config.start_joints.as_deref(),
            &joint_qpos,
            self.data.qpos_mut(),
        );
        self.data.forward();
        let lift = if self.config.gantry {
            0.05
        } else if let Some(h) = self.config.harness {
            h.lift_m
        } else {
            self.config.start.height_m
        };
        if let Some(lowest) = crate::placement::lowest_point(&self.data, self.root_body) {
            self.data.qpos_mut()[r + 2] += lift - lowest;
        }
        // The configured start: moved on the floor and turned about the vertical.
        let start = self.config.start;
        let qpos = self.data.qpos_mut();
        qpos[r] += start.position[0];
        qpos[r + 1] += start.position[1];
        let turned = quat_mul(
            quat_of_rpy(0.0, 0.0, start.yaw_deg.to_radians()),
            [qpos[r + 3], qpos[r + 4], qpos[r + 5], qpos[r + 6]],
        );
        qpos[r + 3..r + 7].copy_from_slice(&turned);
        self.data.forward();
        if self.config.gantry {
            let q = self.data.qpos();
            let r = self.root_qpos;
            let (mass, inertia) = self.held_mass_and_inertia();
            let w = GANTRY_OMEGA;
            self.gantry = Some(Gantry {
                pos: [q[r], q[r + 1], q[r + 2]],
                quat: [q[r + 3], q[r + 4], q[r + 5], q[r + 6]],
                stiffness: [mass * w * w, inertia * w * w],
            });
        }
        if let (Some(h), false) = (self.config.harness, self.config.gantry) {
            let q = self.data.qpos();
            let r = self.root_qpos;
            let (mass, inertia) = self.held_mass_and_inertia();
            let k = mass * HARNESS_OMEGA * HARNESS_OMEGA;
            let k_pendulum = mass * GRAVITY / HARNESS_ROPE_M;
            let k_straps = inertia * HARNESS_STRAPS_OMEGA * HARNESS_STRAPS_OMEGA;
            self.harness = Some(Harness {
                hang: [q[r], q[r + 1], q[r + 2]],
                upright: [q[r + 3], q[r + 4], q[r + 5], q[r + 6]],
                // From carrying the whole weight (stretched by g/ω²) to slack below a robot
                // standing on the floor.
                travel: h.lift_m + GRAVITY / (HARNESS_OMEGA * HARNESS_OMEGA) + HARNESS_SLACK_M,
                lower_s: h.lower_s,
                lowering_since: None,
                hoisting: None,
                mass,
                gains: [
                    k,
                    2.0 * HARNESS_ZETA * (k * mass).sqrt(),
                    k_pendulum,
                    2.0 * HARNESS_ZETA * (k_pendulum * mass).sqrt(),
                    k_straps,
                    2.0 * HARNESS_ZETA * (k_straps * inertia).sqrt(),
                ],
                root_damping: std::array::from_fn(|i| self.data.model().dof_damping()[self.root_dof + i]),
            });
        }
        self.sync_plants();
    }

    /// The crane's hoist signal when the robot hangs in a harness: the controller raises it and
    /// the crane takes the robot's weight where it stands, over the lowering time.
    pub fn harness_hoist(&self) -> Option<Arc<AtomicBool>> {
        self.harness.map(|_| Arc::clone(&self.hoist))
    }

    /// The share of the robot's weight the harness carries now (0 when slack or without one).
    pub fn harness_load(&self) -> Option<f64> {
        self.harness.map(|h| self.harness_wrench(h).3)
    }

    /// The robot's foot switches (robot.toml `[[contacts]]`) as the simulation closes them: a
    /// word whose bit `f` is foot `f`'s switch, published after every physics step, so a loop on
    /// another thread reads it without the mirror's lock. Wired on the first call.
    pub fn foot_switches(&mut self) -> Result<Arc<AtomicU32>, String> {
        if let Some(w) = &self.switches {
            return Ok(Arc::clone(&w.closed));
        }
        let c = &self.robot.config;
        if c.feet.len() > MAX_SWITCHED_FEET {
            return Err(format!(
                "{} feet: the mirror's switches publish at most {MAX_SWITCHED_FEET}",
                c.feet.len()
            ));
        }
        let model = self.data.model();
        let mut touch = Vec::with_capacity(c.feet.len());
        for f in &c.feet {
            let sw = c.contacts.iter().find(|s| s.foot == *f);
            touch.push(
                match sw.and_then(|s| s.sensor.as_ref().map(|n| (n, s.threshold_n))) {
                    Some((name, threshold)) => Some((
                        model_index::sensor_address(model, name).map_err(|e| e.to_string())?,
                        threshold,
                    )),
                    None => None,
                },
            );
        }
        let wiring = SwitchWiring {
            wired: c
                .feet
                .iter()
                .map(|f| c.contacts.iter().any(|s| s.foot == *f))
                .collect(),
            touch,
            closed: Arc::new(AtomicU32::new(0)),
        };
        let closed = Arc::clone(&wiring.closed);
        self.switches = Some(wiring);
        self.publish_switches();
        Ok(closed)
    }

    /// Closes each wired foot's switch as the simulation has it now.
    fn publish_switches(&mut self) {
        let Some(w) = &self.switches else { return };
        let mut feet = [false; MAX_SWITCHED_FEET];
        let n = w.wired.len();
        let (mut pose, mut velocity) = ([0.0; 7], [0.0; 3]);
        self.ground_truth(&mut pose, &mut velocity, &mut feet[..n]);
        let sensors = self.data.sensordata();
        let mut bits = 0u32;
        for (f, (&wired, touch)) in w.wired.iter().zip(&w.touch).enumerate() {
            let closed = match touch {
                Some((address, threshold)) => sensors[*address] > *threshold,
                None => feet[f],
            };
            if wired && closed {
                bits |= 1 << f;
            }
        }
        w.closed.store(bits, Ordering::Release);
    }

    /// The harness's springs' force and torque on the root (world frame), the dampers on the
    /// root's six degrees of freedom (N·s/m, N·m·s/rad), and the share of the weight it carries:
    /// a rope pulls only, and the pendulum and straps act with the load it carries. The dampers
    /// go to MuJoCo as joint damping, which it integrates implicitly: a damper on the light
    /// pelvis, tuned for the whole robot, would otherwise blow up at a trainer's 5 ms step.
    fn harness_wrench(&self, h: Harness) -> ([f64; 3], [f64; 3], [f64; 6], f64) {
        let r = self.root_qpos;
        let q = self.data.qpos();
        let now = self.data.time();
        let smooth = |since: f64| {
            let s = ((now - since) / h.lower_s).clamp(0.0, 1.0);
            s * s * (3.0 - 2.0 * s)
        };
        let [k, c, kh, ch, kr, cr] = h.gains;
        // Height at which the rope just goes taut: the hanging height plus its stretch under the
        // whole weight, minus how far the hook has come down — and, hoisting, back up to where it
        // carries the robot's weight.
        let lowered = h.lowering_since.map_or(0.0, smooth) * h.travel;
        let low = h.hang[2] + GRAVITY / (HARNESS_OMEGA * HARNESS_OMEGA) - lowered;
        let taut = match h.hoisting {
            Some((since, carry)) => low + (carry - low) * smooth(since),
            None => low,
        };
        let stretch = taut - q[r + 2];
        let pull = if stretch > 0.0 { k * stretch } else { 0.0 };
        let load = (pull / (h.mass * GRAVITY)).min(1.5);
        let mut force = [0.0, 0.0, pull];
        for i in 0..2 {
            force[i] = load * kh * (h.hang[i] - q[r + i]);
        }
        let cur = [q[r + 3], q[r + 4], q[r + 5], q[r + 6]];
        let err = quat_mul(h.upright, quat_conj(cur));
        let sign = if err[0] < 0.0 { -2.0 } else { 2.0 };
        let torque: [f64; 3] = std::array::from_fn(|i| load * kr * sign * err[i + 1]);
        let rope = if stretch > 0.0 { c } else { 0.0 };
        let damping = [load * ch, load * ch, rope, load * cr, load * cr, load * cr];
        (force, torque, damping, load)
    }

    /// The robot it mirrors.
    pub fn robot(&self) -> &Robot {
        &self.robot
    }

    /// The run's setup.
    pub fn config(&self) -> &MirrorConfig {
        &self.config
    }

    /// MuJoCo's state (for telemetry, rendering, tests).
    pub fn data(&self) -> &MjData<Box<MjModel>> {
        &self.data
    }

    /// The largest torque any actuator applied so far, N·m (actuator side).
    pub fn peak_actuator_torque(&self) -> f64 {
        self.peak_torque
    }

    /// The largest torque each joint received at any physics step since the last
    /// [`Self::reset_peak_joint_torques`] (the motors' applied torque, or the force of the model's
    /// own servo actuator through its gear), N·m on the joint side, robot order.
    pub fn peak_joint_torques(&self) -> &[f64] {
        &self.peak_joint_torque
    }

    /// Starts the per-joint torque peaks over.
    pub fn reset_peak_joint_torques(&mut self) {
        self.peak_joint_torque.fill(0.0);
    }

    /// Clamps the joints into a jig at `pose` (robot joint order), or releases them (`None`).
    pub fn set_jig(&mut self, pose: Option<Vec<f64>>) {
        if let Some(p) = &pose {
            for (j, &q) in self.joints.iter().zip(p) {
                self.data.qpos_mut()[j.qpos] = q;
                self.data.qvel_mut()[j.dof] = 0.0;
            }
            self.data.forward();
            self.sync_plants();
        }
        self.jig = pose;
    }

    /// Turns the gantry-held base to roll/pitch/yaw (rad) about its held position, as a person
    /// tilting the robot on its stand would. No effect without a gantry.
    pub fn set_gantry_rpy(&mut self, rpy: [f64; 3]) {
        if let Some(g) = &mut self.gantry {
            g.quat = quat_of_rpy(rpy[0], rpy[1], rpy[2]);
        }
    }

    /// A picture of the robot now, the camera looking at its root.
    pub fn render(&mut self, camera: &crate::render::CameraSpec) -> crate::render::Image {
        let root = self.root_pose();
        crate::render::render(&mut self.data, camera, [root[0], root[1], root[2] - 0.05])
    }

    /// Counters.
    pub fn stats(&self) -> MirrorStats {
        self.stats
    }

    /// Policy joints driven through the model's own position actuators.
    pub fn position_actuated_joints(&self) -> usize {
        self.joints.iter().filter(|j| j.actuator.is_some()).count()
    }

    /// The model's position actuator that drives joint `j` (robot order), if one does.
    pub fn joint_actuator(&self, j: usize) -> Option<usize> {
        self.joints.get(j).and_then(|joint| joint.actuator)
    }

    /// Joint angles in policy order, rad (ground truth, for tests and validation).
    pub fn joint_positions(&self) -> impl Iterator<Item = f64> + '_ {
        self.joints.iter().map(|j| self.data.qpos()[j.qpos])
    }

    /// Root position and orientation `[x, y, z, qw, qx, qy, qz]`.
    pub fn root_pose(&self) -> [f64; 7] {
        let q = self.data.qpos();
        std::array::from_fn(|i| q[self.root_qpos + i])
    }

    /// Ground truth a state estimator would provide: root pose `[x, y, z, w, qx, qy, qz]`, root
    /// linear velocity in the base frame, and whether each foot (robot.toml order) touches anything.
    pub fn ground_truth(&self, root_pose: &mut [f64; 7], base_lin_vel: &mut [f64; 3], feet: &mut [bool]) {
        // (The caller also asks [`Self::diverged`]: a diverged mirror's truth is not the robot's.)
        *root_pose = self.root_pose();
        let v = self.data.qvel();
        // The free joint's linear velocity is in the world frame; rotate it into the base.
        let dof = self.root_dof;
        let world = [v[dof], v[dof + 1], v[dof + 2]];
        let q = [root_pose[3], -root_pose[4], -root_pose[5], -root_pose[6]];
        *base_lin_vel = quat_rotate(q, world);
        feet.fill(false);
        let model = self.data.model();
        for c in self.data.contact() {
            for g in c.geom {
                if g < 0 {
                    continue;
                }
                let body = model.geom_bodyid()[g as usize];
                if let Some(k) = self.feet.iter().position(|&f| f as i32 == body)
                    && k < feet.len()
                {
                    feet[k] = true;
                }
            }
        }
    }

    /// CAN bus `name` of the mirror.
    pub fn can_bus(&self, name: &str) -> Option<&VirtualCanBus> {
        self.can.iter().find(|c| c.name == name).map(|c| &c.bus)
    }

    /// The serial line number of Dynamixel bus `name`.
    pub fn dxl_line(&self, name: &str) -> Option<usize> {
        self.dxl.iter().position(|d| d.name == name)
    }

    /// The serial line number of Feetech bus `name` (after the Dynamixel lines).
    pub fn feetech_line(&self, name: &str) -> Option<usize> {
        self.feetech
            .iter()
            .position(|d| d.name == name)
            .map(|k| self.dxl.len() + k)
    }

    /// The serial line number of the IMU.
    pub fn imu_line(&self) -> usize {
        self.dxl.len() + self.feetech.len()
    }

    /// The Feetech servo driving policy joint `joint`, to inspect or inject faults.
    pub fn sts_servo_mut(&mut self, joint: usize) -> Option<&mut StsServo> {
        let (line, k) = self
            .feetech
            .iter()
            .enumerate()
            .find_map(|(l, d)| d.joints.iter().position(|&j| j == joint).map(|k| (l, k)))?;
        Some(&mut self.feetech[line].wire.chain_mut().servos_mut()[k])
    }

    /// The Dynamixel servo driving policy joint `joint`, to inspect or inject faults.
    pub fn servo_mut(&mut self, joint: usize) -> Option<&mut XSeriesServo> {
        let (line, k) = self
            .dxl
            .iter()
            .enumerate()
            .find_map(|(l, d)| d.joints.iter().position(|&j| j == joint).map(|k| (l, k)))?;
        Some(&mut self.dxl[line].wire.chain_mut().servos_mut()[k])
    }

    /// The Unitree board driving policy joint `joint`, and the joint's motor on it.
    fn unitree_motor(&mut self, joint: usize) -> Option<(&mut UnitreeLine, usize)> {
        self.unitree
            .iter_mut()
            .find_map(|u| u.joints.iter().position(|&j| j == joint).map(move |k| (u, k)))
    }

    /// The number of Unitree board `name`.
    pub fn unitree_line(&self, name: &str) -> Option<usize> {
        self.unitree.iter().position(|u| u.name == name)
    }

    /// Unitree board number `line`.
    pub fn unitree_board(&self, line: usize) -> Option<&UnitreeBoard> {
        self.unitree.get(line).map(|u| &u.board)
    }

    /// The MIT motor firmware driving policy joint `joint`.
    pub fn motor_mut(&mut self, joint: usize) -> Option<&mut MitMotorFirmware> {
        self.can
            .iter_mut()
            .flat_map(|c| c.motors.iter_mut())
            .find(|m| m.joint == joint)
            .map(|m| &mut m.firmware)
    }

    fn sync_plants(&mut self) {
        let (q, qd) = (self.data.qpos(), self.data.qvel());
        for (p, j) in self.plants.iter_mut().zip(&self.joints) {
            p.q = j.zero_offset + j.direction * j.gear * q[j.qpos];
            p.qd = j.direction * j.gear * qd[j.dof];
        }
    }

    fn run_firmware(&mut self, t: SimInstant) {
        self.sync_plants();
        for line in &mut self.can {
            for m in &mut line.motors {
                m.firmware
                    .tick(t, self.firmware_period, &mut self.plants[m.joint]);
                self.plants[m.joint].goal = m.firmware.position_goal();
                self.plants[m.joint].torque_cap = m.firmware.torque_cap();
                let law = m.firmware.pd_law();
                self.plants[m.joint].law = law;
                self.plants[m.joint].stiffness = law.map(|l| [l.kp, l.kd]);
            }
        }
        for line in &mut self.unitree {
            for (m, &j) in line.board.motors_mut().iter_mut().zip(&line.joints) {
                m.tick(t, self.firmware_period, &mut self.plants[j]);
                self.plants[j].goal = m.position_goal();
                self.plants[j].torque_cap = m.torque_cap();
                let law = m.pd_law();
                self.plants[j].law = law;
                self.plants[j].stiffness = law.map(|l| [l.kp, l.kd]);
            }
        }
        for line in &mut self.dxl {
            for (servo, &j) in line.wire.chain_mut().servos_mut().iter_mut().zip(&line.joints) {
                servo.tick(t, &mut self.plants[j]);
                self.plants[j].goal = servo.position_goal();
                self.plants[j].torque_cap = servo.torque_cap();
                self.plants[j].stiffness = Some(servo.position_stiffness());
            }
        }
        for line in &mut self.feetech {
            for (servo, &j) in line.wire.chain_mut().servos_mut().iter_mut().zip(&line.joints) {
                servo.tick(t, &mut self.plants[j]);
                self.plants[j].goal = servo.position_goal();
                self.plants[j].torque_cap = servo.torque_cap();
                self.plants[j].stiffness = Some(servo.position_stiffness());
            }
        }
        self.stats.firmware_ticks += 1;
    }

    /// Motors whose law the mirror computes every physics step report the torque that acted
    /// (within the effort limit), as their current sensors would, not their own law's.
    fn sense_stepped_torques(&mut self) {
        let (joints, plants) = (&self.joints, &self.plants);
        for m in self.can.iter_mut().flat_map(|c| c.motors.iter_mut()) {
            if joints[m.joint].law.model.per_physics_step() {
                m.firmware.sense_torque(plants[m.joint].torque);
            }
        }
        for line in &mut self.unitree {
            for (m, &j) in line.board.motors_mut().iter_mut().zip(&line.joints) {
                if joints[j].law.model.per_physics_step() {
                    m.sense_torque(plants[j].torque);
                }
            }
        }
    }

    /// Serial servos whose joint the model's own position actuator drives report the torque that
    /// actuator gave (their current and load registers), not their emulated loop's: the two
    /// differ, and a reading of a torque that never acted tells the estimator of loads that are
    /// not there.
    fn sense_servo_torques(&mut self) {
        let (data, joints) = (&self.data, &self.joints);
        let acted = |j: usize| {
            let joint = &joints[j];
            joint.actuator.map(|a| {
                let joint_torque = data.actuator_force()[a] * data.model().actuator_gear()[a][0];
                joint_torque / (joint.direction * joint.gear)
            })
        };
        for line in &mut self.dxl {
            for (servo, &j) in line.wire.chain_mut().servos_mut().iter_mut().zip(&line.joints) {
                if let Some(t) = acted(j) {
                    servo.sense_torque(t);
                }
            }
        }
        for line in &mut self.feetech {
            for (servo, &j) in line.wire.chain_mut().servos_mut().iter_mut().zip(&line.joints) {
                if let Some(t) = acted(j) {
                    servo.sense_torque(t);
                }
            }
        }
    }

    /// Whether any joint is driven: a motor gives torque or a servo has a goal.
    fn driven(&self) -> bool {
        self.direct.as_ref().is_some_and(|d| d.driven)
            || self.plants.iter().any(|p| p.torque != 0.0 || p.goal.is_some())
    }

    fn step_physics(&mut self) {
        if self.held {
            if !self.driven() {
                // Still waiting for the controller: the robot stays as placed.
                self.stats.physics_steps += 1;
                return;
            }
            self.held = false;
        }
        let direct = self.direct.is_some();
        // Torques (or position goals) from the firmware's last period.
        let mut stepped_laws = false;
        for (i, (j, p)) in self.joints.iter_mut().zip(&mut self.plants).enumerate() {
            if j.law.model.per_physics_step() || (direct && j.actuator.is_none()) {
                // The trainer's law, from the command that acts at this step.
                let (q, qd) = (self.data.qpos()[j.qpos], self.data.qvel()[j.dof]);
                let law = j.delay(p.law);
                let torque = law.map_or(0.0, |l| j.stepped_torque(&l, q, qd));
                // What acted, at the motor: the torque its current sensor reports.
                p.torque = torque / (j.direction * j.gear);
                stepped_laws = true;
                self.peak_torque = self.peak_torque.max((torque / j.gear).abs());
                self.peak_joint_torque[i] = self.peak_joint_torque[i].max(torque.abs());
                let mut damping = j.passive_damping;
                let mut applied = torque;
                if let (ActuatorModel::ImplicitPd, Some(l)) = (j.law.model, law) {
                    // MuJoCo integrates joint damping implicitly: the law's damping moves there
                    // and its explicit share is given back, so the joint feels the same law.
                    let kd = l.kd * j.gear * j.gear * j.strength;
                    damping += kd;
                    applied += kd * qd;
                }
                set_dof_damping(&mut self.data, j.dof, damping);
                self.data.qfrc_applied_mut()[j.dof] = applied;
                continue;
            }
            match j.actuator {
                Some(a) => {
                    // The model's own servo tracks the firmware's goal; with no goal (torque
                    // off) it holds where the joint is, as a position actuator cannot go limp.
                    let q = self.data.qpos()[j.qpos];
                    let goal = p.goal.map_or(q, |g| (g - j.zero_offset) / (j.direction * j.gear));
                    if let Some(stiffness) = p.stiffness {
                        set_position_gains(&mut self.data, a, stiffness.map(|k| k * j.gear * j.gear));
                    }
                    let ctrl = capped_position_control(&self.data, a, j, goal, p.torque_cap);
                    self.data.ctrl_mut()[a] = ctrl;
                    self.data.qfrc_applied_mut()[j.dof] = 0.0;
                }
                None => {
                    self.peak_torque = self.peak_torque.max(p.torque.abs());
                    let joint_torque = j.direction * j.gear * p.torque * j.strength;
                    self.peak_joint_torque[i] = self.peak_joint_torque[i].max(joint_torque.abs());
                    self.data.qfrc_applied_mut()[j.dof] = joint_torque;
                }
            }
        }
        if stepped_laws && !direct {
            self.sense_stepped_torques();
        }
        if let Some(g) = self.gantry {
            self.hold_on_gantry(g);
        } else if let Some(h) = &mut self.harness {
            if h.lowering_since.is_none() && self.plants.iter().any(|p| p.torque != 0.0 || p.goal.is_some()) {
                h.lowering_since = Some(self.data.time());
            }
            if h.hoisting.is_none() && self.hoist.load(Ordering::Relaxed) {
                // The crane moves over the robot and takes its weight where it stands.
                let q = self.data.qpos();
                let r = self.root_qpos;
                h.hang[0] = q[r];
                h.hang[1] = q[r + 1];
                h.hoisting = Some((
                    self.data.time(),
                    q[r + 2] + GRAVITY / (HARNESS_OMEGA * HARNESS_OMEGA),
                ));
            }
            let h = *h;
            let (force, torque, damping, _) = self.harness_wrench(h);
            let x = &mut self.data.xfrc_applied_mut()[self.root_body];
            x[..3].copy_from_slice(&force);
            x[3..].copy_from_slice(&torque);
            for (i, (d, base)) in damping.iter().zip(h.root_damping).enumerate() {
                set_dof_damping(&mut self.data, self.root_dof + i, base + d);
            }
        } else if !self.pushes.is_empty() {
            self.data.xfrc_applied_mut()[self.root_body] = [0.0; 6];
        }
        self.apply_pushes();
        if self.jig.is_some() {
            // The clamp carries the joints' load (gravity, Coriolis; the motors push against it),
            // so the limbs do not swing inside the step and shake the base.
            for j in &self.joints {
                let bias = self.data.qfrc_bias()[j.dof];
                self.data.qfrc_applied_mut()[j.dof] = bias;
            }
        }
        if self.diverged.is_some() {
            // A diverged simulation stays where it stopped: stepping it on only resets it again
            // and again (MuJoCo's answer to NaN), which would look like a robot that moves.
            self.stats.physics_steps += 1;
            return;
        }
        let stepping = std::time::Instant::now();
        self.data.step();
        self.stats.physics += stepping.elapsed();
        // What the model's own servos gave this step, joint side (the motors' torques are
        // counted where they are applied, above).
        for (i, j) in self.joints.iter().enumerate() {
            if let Some(a) = j.actuator {
                let m = self.data.model();
                let torque = (self.data.actuator_force()[a] * m.actuator_gear()[a][0]).abs();
                self.peak_joint_torque[i] = self.peak_joint_torque[i].max(torque);
            }
        }
        self.sense_servo_torques();
        if let Some(why) = self.divergence() {
            tracing::warn!(
                "mirror: the simulation diverged at t = {:.3} s: {why}",
                self.data.time()
            );
            self.diverged = Some(format!("at t = {:.3} s: {why}", self.data.time()));
        }
        if let Some(jig) = &self.jig {
            // A jig is rigid: the joints are where it puts them, whatever the motors do.
            for (j, &q) in self.joints.iter().zip(jig) {
                self.data.qpos_mut()[j.qpos] = q;
                self.data.qvel_mut()[j.dof] = 0.0;
            }
        }
        self.publish_switches();
        self.stats.physics_steps += 1;
    }

    /// Why the simulation can no longer be trusted, if it cannot: MuJoCo's own instability
    /// warnings (bad position, velocity or acceleration, which it answers by resetting), or a
    /// state that is no longer finite.
    fn divergence(&self) -> Option<String> {
        use mujoco_rs::mujoco_c::mjtWarning as W;
        let warnings = &self.data.ffi().warning;
        for (w, what) in [
            (W::mjWARN_BADQPOS, "bad joint positions"),
            (W::mjWARN_BADQVEL, "bad joint velocities"),
            (W::mjWARN_BADQACC, "bad joint accelerations (unstable)"),
        ] {
            let warning = &warnings[w as usize];
            if warning.number > 0 {
                // MuJoCo notes the degree of freedom it found bad: name its joint.
                let model = self.data.model();
                let joint = usize::try_from(warning.lastinfo)
                    .ok()
                    .and_then(|dof| model.dof_jntid().get(dof).copied())
                    .and_then(|j| model.id_to_name(MjtObjBase::mjOBJ_JOINT, usize::try_from(j).ok()?))
                    .filter(|name| !name.is_empty());
                return Some(match joint {
                    Some(name) => format!("MuJoCo warned of {what} at joint {name}"),
                    None => format!("MuJoCo warned of {what}"),
                });
            }
        }
        let finite = |v: &[f64]| v.iter().all(|x| x.is_finite());
        if !(finite(self.data.qpos()) && finite(self.data.qvel())) {
            return Some("the state is not finite".to_owned());
        }
        let qvel = self.data.qvel();
        self.joints
            .iter()
            .find(|j| qvel[j.dof].abs() > j.blow_up_speed)
            .map(|j| {
                format!(
                    "joint {} moves at {:.0} rad/s, more than {BLOW_UP_SHARE} times its velocity limit \
                     (no motor does: the simulation blew up)",
                    j.name,
                    qvel[j.dof].abs()
                )
            })
    }

    /// Bytes MuJoCo holds for this mirror: the compiled model's buffer, and the data's buffer and
    /// arena (contacts, constraints) — what a bare MuJoCo loop of the same model holds too.
    pub fn mujoco_bytes(&self) -> usize {
        let size = |n: i64| usize::try_from(n).unwrap_or(0);
        let data = self.data.ffi();
        size(self.data.model().ffi().nbuffer) + size(data.nbuffer) + size(data.narena)
    }

    /// Why the simulation stopped being trustworthy, if it did (then it no longer moves).
    pub fn diverged(&self) -> Option<&str> {
        self.diverged.as_deref()
    }

    /// Adds the pushes active now to the root's applied force (after the gantry wrote its own).
    fn apply_pushes(&mut self) {
        let now = self.now;
        for &(start, end, force) in &self.pushes {
            if start <= now && now < end {
                let x = &mut self.data.xfrc_applied_mut()[self.root_body];
                for (xi, fi) in x.iter_mut().zip(force) {
                    *xi += fi;
                }
            }
        }
    }

    /// The robot's mass (kg) and its mean moment of inertia about the root (kg·m²), in the
    /// present pose.
    fn held_mass_and_inertia(&self) -> (f64, f64) {
        held_mass_and_inertia(&self.data, self.root_body)
    }

    fn hold_on_gantry(&mut self, g: Gantry) {
        let r = self.root_qpos;
        let q = self.data.qpos();
        let [k, kr] = g.stiffness;
        // The springs only: the damping is the root's joint damping (set with the stand).
        let force: [f64; 3] = std::array::from_fn(|i| k * (g.pos[i] - q[r + i]));
        // Orientation error as a rotation vector (world frame).
        let cur = [q[r + 3], q[r + 4], q[r + 5], q[r + 6]];
        let err = quat_mul(g.quat, quat_conj(cur));
        let s = if err[0] < 0.0 { -2.0 } else { 2.0 };
        let torque: [f64; 3] = std::array::from_fn(|i| kr * s * err[i + 1]);
        let x = &mut self.data.xfrc_applied_mut()[self.root_body];
        x[..3].copy_from_slice(&force);
        x[3..].copy_from_slice(&torque);
    }

    fn output_imu(&mut self, t: SimInstant) {
        let s = self.data.sensordata();
        let i = &self.imu;
        let site_gyro = [s[i.gyro], s[i.gyro + 1], s[i.gyro + 2]];
        let site_accel = [s[i.accel], s[i.accel + 1], s[i.accel + 2]];
        let site_quat = [s[i.quat], s[i.quat + 1], s[i.quat + 2], s[i.quat + 3]];
        let truth = ImuTruth {
            gyro: quat_rotate(i.mount, site_gyro),
            accel: quat_rotate(i.mount, site_accel),
            quat: quat_mul(site_quat, quat_conj(i.mount)),
        };
        if self.imu.board.is_some() {
            // The board's IMU: the part's sample goes into the board's next state.
            let x = self.imu.emulator.sample(t, &truth);
            let narrow = |from: &[f64], to: &mut [f32]| {
                for (t, f) in to.iter_mut().zip(from) {
                    *t = *f as f32;
                }
            };
            let b = &mut self.board_imu;
            narrow(&x.quat, &mut b.quaternion);
            narrow(&x.gyro, &mut b.gyroscope);
            narrow(&x.accel, &mut b.accelerometer);
            narrow(&x.rpy, &mut b.rpy);
            b.temperature = x.temperature.round() as i16;
            self.stats.imu_outputs += 1;
            return;
        }
        let mut cycle = [0u8; firmware_bridge::imu::emulator::MAX_CYCLE_BYTES];
        let n = match &mut self.imu.chip {
            Some(chip) => {
                chip.update(t, &self.imu.emulator.sample(t, &truth));
                0
            }
            None => self.imu.emulator.output(t, &truth, &mut cycle),
        };
        let bytes = &mut cycle[..n];
        // The part keeps its schedule (and its noise draws) whatever is lost on the way.
        self.imu.answers = ChipAnswers::Given;
        match self.imu_fault {
            ImuFault::None => {}
            ImuFault::Gone => {
                self.imu.answers = ChipAnswers::Dropped;
                return;
            }
            ImuFault::Lost(n) | ImuFault::Corrupt(n) => {
                let corrupt = matches!(self.imu_fault, ImuFault::Corrupt(_));
                self.imu.answers = if corrupt {
                    ChipAnswers::ReadFail
                } else {
                    ChipAnswers::Dropped
                };
                // A streaming part's packets of the cycle each fail their checksum (the last
                // byte of each); a register-read part has no output cycle to spoil.
                let packet = match self.imu.emulator.protocol() {
                    firmware_bridge::imu::ImuProtocol::Wit => Some(firmware_bridge::imu::wit::PACKET_LEN),
                    firmware_bridge::imu::ImuProtocol::Bno08xRvc => {
                        Some(firmware_bridge::imu::rvc::FRAME_LEN)
                    }
                    firmware_bridge::imu::ImuProtocol::Bno055 => None,
                };
                if let Some(packet) = packet.filter(|_| corrupt) {
                    for sum in bytes.iter_mut().skip(packet - 1).step_by(packet) {
                        *sum = sum.wrapping_add(1);
                    }
                }
                let left = n.saturating_sub(1);
                self.imu_fault = match left {
                    0 => ImuFault::None,
                    k if corrupt => ImuFault::Corrupt(k),
                    k => ImuFault::Lost(k),
                };
                if !corrupt {
                    return;
                }
            }
        }
        if !bytes.is_empty() {
            self.imu.line.device_transmit(t, bytes);
        }
        self.stats.imu_outputs += 1;
    }

    fn apply_fault(&mut self, joint: usize, fault: FaultKind) {
        if let Some((line, k)) = self.unitree_motor(joint) {
            // One state carries every motor of the board: lost and corrupted replies are the
            // board's states; a motor alone can drop out or overheat.
            let slot = line.board.config().motors[k].slot;
            line.board.inject(match fault {
                FaultKind::Silent { count: None } | FaultKind::Vanish => BoardFault::MotorLost(slot),
                FaultKind::Silent { count: Some(n) } => BoardFault::SilentState(Some(n)),
                FaultKind::CorruptCrc { count } => BoardFault::CorruptCrc(count),
                FaultKind::Overheat => BoardFault::Overheat(slot),
            });
        } else if let Some(servo) = self.sts_servo_mut(joint) {
            match fault {
                FaultKind::Silent { count } => servo.inject(ReplyFault::Silent, count),
                FaultKind::CorruptCrc { count } => servo.inject(ReplyFault::CorruptCrc, Some(count)),
                FaultKind::Overheat => servo.raise_error(firmware_bridge::feetech::packet::error::OVERHEAT),
                FaultKind::Vanish => servo.vanish(),
            }
        } else if let Some(servo) = self.servo_mut(joint) {
            match fault {
                FaultKind::Silent { count } => servo.inject(ReplyFault::Silent, count),
                FaultKind::CorruptCrc { count } => servo.inject(ReplyFault::CorruptCrc, Some(count)),
                FaultKind::Overheat => servo.raise_hardware_error(hw::OVERHEAT),
                FaultKind::Vanish => servo.vanish(),
            }
        } else if let Some(motor) = self.motor_mut(joint) {
            // CAN frames carry a hardware CRC: a corrupted reply is dropped by the controller
            // and never reaches the host, so it counts as a lost reply.
            let injected = match fault {
                FaultKind::Silent { count: None } | FaultKind::Vanish => InjectedFaults {
                    silent: true,
                    ..InjectedFaults::default()
                },
                FaultKind::Silent { count: Some(n) } | FaultKind::CorruptCrc { count: n } => InjectedFaults {
                    lost_replies: n,
                    ..InjectedFaults::default()
                },
                FaultKind::Overheat => InjectedFaults {
                    fault: Some(MotorFault::OverTemperature),
                    ..InjectedFaults::default()
                },
            };
            motor.inject(injected);
        } else if joint == IMU_TARGET {
            self.imu_fault = match fault {
                FaultKind::Silent { count: None } | FaultKind::Vanish => ImuFault::Gone,
                FaultKind::Silent { count: Some(n) } => ImuFault::Lost(n),
                FaultKind::CorruptCrc { count } => ImuFault::Corrupt(count),
                FaultKind::Overheat => ImuFault::None,
            };
        }
        self.stats.faults_applied += 1;
    }

    /// Host ports on every bus of the mirror, sharing it in lockstep.
    pub fn host_ports(world: &Arc<Mutex<Self>>) -> HostPorts {
        let w = world.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
        let can = w
            .can
            .iter()
            .map(|c| {
                (
                    c.name.clone(),
                    LockstepCanPort::new(c.bus.attach(), Arc::clone(world)),
                )
            })
            .collect();
        let dxl = w
            .dxl
            .iter()
            .enumerate()
            .map(|(i, d)| {
                let baud = d.wire.chain().timing().baud;
                (d.name.clone(), LockstepDxlPort::new(Arc::clone(world), i, baud))
            })
            .collect();
        let feetech = w
            .feetech
            .iter()
            .enumerate()
            .map(|(i, d)| {
                let baud = d.wire.chain().timing().baud;
                (
                    d.name.clone(),
                    LockstepFeetechPort::new(Arc::clone(world), w.dxl.len() + i, baud),
                )
            })
            .collect();
        let unitree = w
            .unitree
            .iter()
            .enumerate()
            .map(|(i, u)| (u.name.clone(), LockstepUnitreePort::new(Arc::clone(world), i)))
            .collect();
        // A board's IMU comes in its state, not on a line.
        let imu = w
            .imu
            .board
            .is_none()
            .then(|| LockstepStream::new(Arc::clone(world), w.imu_line()));
        HostPorts {
            can,
            dxl,
            feetech,
            unitree,
            imu,
        }
    }
}

/// The controller's ends of a mirror's buses in lockstep.
#[derive(Debug)]
pub struct HostPorts {
    /// CAN buses by name.
    pub can: Vec<(String, LockstepCanPort<Mirror>)>,
    /// Dynamixel lines by name.
    pub dxl: Vec<(String, LockstepDxlPort<Mirror>)>,
    /// Feetech lines by name.
    pub feetech: Vec<(String, LockstepFeetechPort<Mirror>)>,
    /// Unitree boards by name.
    pub unitree: Vec<(String, LockstepUnitreePort<Mirror>)>,
    /// The IMU's byte stream (`None`: the IMU is a Unitree board's).
    pub imu: Option<LockstepStream<Mirror>>,
}

impl UnitreeWorld for Mirror {
    fn board_mut(&mut self, line: usize) -> &mut UnitreeBoard {
        &mut self.unitree[line].board
    }
}

impl SimWorld for Mirror {
    fn now(&self) -> SimInstant {
        self.now
    }

    fn step_until(&mut self, limit: SimInstant) -> SimInstant {
        let started = std::time::Instant::now();
        let t = self.step_once(limit);
        self.stats.busy += started.elapsed();
        t
    }
}

impl Mirror {
    fn step_once(&mut self, limit: SimInstant) -> SimInstant {
        if self.direct.is_some() {
            return self.step_direct(limit);
        }
        let now = self.now;
        let mut t = limit
            .min(self.next_physics)
            .min(self.next_firmware)
            .min(self.imu.emulator.next_output());
        for line in &self.can {
            if let Some((a, _)) = line.bus.next_arrival_among(line.motors.iter().map(|m| &m.node)) {
                t = t.min(a);
            }
        }
        for line in &self.dxl {
            if let Some(e) = line.wire.next_event(now) {
                t = t.min(e);
            }
        }
        for line in &self.feetech {
            if let Some(e) = line.wire.next_event(now) {
                t = t.min(e);
            }
        }
        if let Some(e) = self.imu.line.next_event(now) {
            t = t.min(e);
        }
        if let Some(f) = self.faults.get(self.next_fault) {
            t = t.min(f.0);
        }
        for line in &self.unitree {
            t = t.min(line.board.next_state());
        }
        let t = t.max(now);
        self.now = t;
        for line in &mut self.can {
            line.bus.set_now(t);
            // Frames due by now, in their order of arrival.
            while let Some((a, i)) = line.bus.next_arrival_among(line.motors.iter().map(|m| &m.node))
                && a <= t
            {
                let m = &mut line.motors[i];
                let Some(frame) = m.node.try_recv() else { break };
                if let Some(reply) = m.firmware.on_frame(t, &frame, &self.plants[m.joint]) {
                    // A send refused while bus-off is lost, as on a real bus.
                    let _ = m.node.send(&reply);
                }
            }
        }
        for line in &mut self.dxl {
            line.wire.advance(t);
        }
        for line in &mut self.feetech {
            line.wire.advance(t);
        }
        while let Some(&(at, joint, fault)) = self.faults.get(self.next_fault) {
            if at > t {
                break;
            }
            self.next_fault += 1;
            self.apply_fault(joint, fault);
        }
        if t >= self.next_firmware {
            self.run_firmware(t);
            self.next_firmware = self.next_firmware + self.firmware_period;
        }
        if t >= self.next_physics {
            self.step_physics();
            self.next_physics = self.next_physics + self.physics_dt;
        }
        if t >= self.imu.emulator.next_output() {
            self.output_imu(t);
        }
        for line in &mut self.unitree {
            let plants = &self.plants;
            let joints = &line.joints;
            line.board.publish(t, &self.board_imu, &mut |k| {
                (plants[joints[k]].q, plants[joints[k]].qd)
            });
        }
        t
    }
}

/// The direct fidelity: no bus, firmware or wire; the host's commands act on MuJoCo through the
/// trainer's actuator law, the IMU's samples go to the host as they are drawn.
impl Mirror {
    fn step_direct(&mut self, limit: SimInstant) -> SimInstant {
        let now = self.now;
        let mut t = limit.min(self.next_physics).min(self.imu.emulator.next_output());
        if let Some(f) = self.faults.get(self.next_fault) {
            t = t.min(f.0);
        }
        let t = t.max(now);
        self.now = t;
        while let Some(&(at, joint, fault)) = self.faults.get(self.next_fault) {
            if at > t {
                break;
            }
            self.next_fault += 1;
            self.apply_fault(joint, fault);
        }
        if t >= self.next_physics {
            self.sync_plants();
            self.step_physics();
            self.next_physics = self.next_physics + self.physics_dt;
        }
        if t >= self.imu.emulator.next_output() {
            self.sample_imu_directly(t);
        }
        t
    }

    /// The IMU's sample drawn from the model's sensors at its site (noise and biases as the
    /// device's), kept for the host's next read.
    fn sample_imu_directly(&mut self, t: SimInstant) {
        let s = self.data.sensordata();
        let i = &self.imu;
        let truth = ImuTruth {
            gyro: [s[i.gyro], s[i.gyro + 1], s[i.gyro + 2]],
            accel: [s[i.accel], s[i.accel + 1], s[i.accel + 2]],
            quat: [s[i.quat], s[i.quat + 1], s[i.quat + 2], s[i.quat + 3]],
        };
        let x = self.imu.emulator.sample(t, &truth);
        self.stats.imu_outputs += 1;
        if let Some(d) = &mut self.direct {
            let sample = ImuSample {
                gyro: x.gyro,
                accel: x.accel,
                quat: x.quat,
                at: Duration::from_nanos(t.as_nanos()),
            };
            if d.samples.len() == DIRECT_SAMPLES {
                d.samples.remove(0);
            }
            d.samples.push(sample);
            d.latest = sample;
        }
    }

    /// A direct mirror takes the loop's commands (robot order), each as a law in its actuator's
    /// frame: the motors' laws the mirror computes every physics step until the next command, and
    /// the model's position servos' goals and gains; false on a mirror with wires.
    pub fn command_directly(&mut self, targets: &[JointTarget]) -> bool {
        let Some(d) = &mut self.direct else { return false };
        for ((j, p), (t, &limit)) in self
            .joints
            .iter()
            .zip(&mut self.plants)
            .zip(targets.iter().zip(&d.torque_limits))
        {
            let to = j.direction * j.gear;
            let law = t.enabled.then(|| PdLaw {
                p: j.zero_offset + to * t.q,
                v: to * t.qd,
                kp: t.kp / (j.gear * j.gear),
                kd: t.kd / (j.gear * j.gear),
                t: t.tau / to,
                limit: limit / j.gear,
            });
            p.law = law;
            p.torque_cap = limit / j.gear;
            if j.actuator.is_some() {
                p.goal = law.filter(|l| l.kp > 0.0).map(|l| l.p);
                p.stiffness = law.map(|l| [l.kp, l.kd]);
                p.torque = 0.0;
            }
        }
        d.driven |= targets.iter().any(|t| t.enabled);
        true
    }

    /// A direct mirror's state for the loop (robot order: joint angles, speeds and the torques
    /// that acted; the IMU's samples since the last read); false on a mirror with wires.
    pub fn read_directly(&mut self, state: &mut RobotState) -> bool {
        let Some(d) = &mut self.direct else { return false };
        let (q, qd) = (self.data.qpos(), self.data.qvel());
        for (k, (j, p)) in self.joints.iter().zip(&self.plants).enumerate() {
            state.q[k] = q[j.qpos];
            state.qd[k] = qd[j.dof];
            state.tau[k] = match j.actuator {
                Some(a) => self.data.actuator_force()[a] * self.data.model().actuator_gear()[a][0],
                None => j.direction * j.gear * p.torque * j.strength,
            };
        }
        state.missed.fill(0);
        state.faulted.fill(false);
        state.stale.fill(false);
        state.age.fill(Duration::ZERO);
        state.imu_samples.clear();
        state.imu_samples.extend_from_slice(&d.samples);
        d.samples.clear();
        state.gyro = d.latest.gyro;
        state.accel = d.latest.accel;
        state.quat = d.latest.quat;
        state.imu_missed = 0;
        state.imu_age = Duration::ZERO;
        true
    }
}

impl SerialSimWorld for Mirror {
    fn host_transmit(&mut self, line: usize, bytes: &[u8]) {
        if let Some(d) = self.dxl.get_mut(line) {
            d.wire.host_transmit(self.now, bytes);
            return;
        }
        if let Some(f) = line
            .checked_sub(self.dxl.len())
            .and_then(|k| self.feetech.get_mut(k))
        {
            f.wire.host_transmit(self.now, bytes);
            return;
        }
        // A streaming IMU ignores what the host sends; a register-read one answers once the
        // request has crossed the wire.
        let imu = &mut self.imu;
        let Some(chip) = &mut imu.chip else { return };
        let arrived = self.now + imu.line.wire_time(bytes.len());
        imu.reply.clear();
        chip.receive(arrived, bytes, &mut imu.reply);
        match imu.answers {
            ChipAnswers::Given => imu.line.device_transmit(arrived, &imu.reply),
            ChipAnswers::Dropped => {}
            ChipAnswers::ReadFail if imu.reply.first() == Some(&bno055::READ_RESPONSE) => {
                imu.line
                    .device_transmit(arrived, &[bno055::STATUS_RESPONSE, bno055::status::READ_FAIL]);
            }
            ChipAnswers::ReadFail => imu.line.device_transmit(arrived, &imu.reply),
        }
    }

    fn host_receive(&mut self, line: usize, out: &mut Vec<u8>) {
        let dxl = self.dxl.len();
        if let Some(d) = self.dxl.get_mut(line) {
            d.wire.host_receive(self.now, out);
        } else if let Some(f) = line.checked_sub(dxl).and_then(|k| self.feetech.get_mut(k)) {
            f.wire.host_receive(self.now, out);
        } else {
            self.imu.line.host_receive(self.now, out);
        }
    }
}
