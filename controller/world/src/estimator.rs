//! State estimation from what the robot measures: the base's position, velocity and orientation,
//! the IMU's biases and the feet's positions, by one of two filters (robot.toml `[estimator]
//! filter`): the contact-aided invariant EKF ([`invariant`], the default) or the linear Kalman
//! filter ([`linear`]). Every IMU sample propagates; every tick the legs correct: each foot's
//! position relative to the base from the joints (forward kinematics of the robot's model), and
//! for each foot on the ground, the base velocity that keeps it still. A foot in the air gets a
//! large process noise, so it follows the kinematics without moving the base.
//!
//! Contact, the held robot and the gates are decided here, the same for both filters. Contact
//! comes from foot switches where the robot has them, otherwise from the legs: a foot lands when
//! it comes back within `contact_on_m` of the height it last stood at, slowly, and takes a share
//! of the weight (the ground's push on it, from the joint torques the buses report) above what it
//! reads in the air (learned from the robot's own steps); it lifts off when it rises beyond
//! `contact_off_m` or carries almost nothing (hysteresis on both). Those
//! heights and the speed are scaled to the robot's own standing height when the filter starts.
//!
//! The world frame is the robot's start: the base above the origin, the floor at z = 0 under
//! feet that stand on it, the IMU's heading. Nothing is allocated after construction.

mod invariant;
mod kalman;
mod linear;

use robots::spatial::{self, Mat3};

use invariant::InvariantFilter;
use linear::LinearFilter;

pub use robots::{EstimatorConfig, FilterKind};

/// Feet the filter tracks at most.
pub const MAX_FEET: usize = 4;

/// What the filter says this tick.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Estimate {
    /// Base (root body) position in the world, m.
    pub position: [f64; 3],
    /// Base velocity in the world, m/s.
    pub velocity: [f64; 3],
    /// Base velocity in the base's own frame, m/s.
    pub velocity_base: [f64; 3],
    /// Base orientation `[w, x, y, z]`, base to world: the invariant filter's own; the linear
    /// filter's is the IMU's.
    pub orientation: [f64; 4],
    /// Standard deviations of position and velocity (world axes).
    pub position_std: [f64; 3],
    /// …
    pub velocity_std: [f64; 3],
    /// Accelerometer bias estimate, m/s² (base axes).
    pub accel_bias: [f64; 3],
    /// Feet on the ground (robot.toml order; `feet` of them in use).
    pub contacts: [bool; MAX_FEET],
    /// The load on each foot from the joint torques, N (NaN: unknown).
    pub loads: [f64; MAX_FEET],
    /// Feet in use.
    pub feet: usize,
    /// The robot is held (its feet carry almost none of its weight): the estimate is the filter
    /// running in the air, for a policy that observes it; nothing to compare with the ground.
    pub held: bool,
    /// The filter that made it.
    pub filter: FilterKind,
    /// The outputs can be used: initialised, fed finite, fresh data.
    pub valid: bool,
    /// Why not, when they cannot.
    pub problem: Option<EstimateProblem>,
}

/// Why the state estimate a policy reads is not usable.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum EstimateProblem {
    /// It never started: the IMU gave no orientation yet, or the robot was falling and never held
    /// still long enough since.
    NotInitialised,
    /// It was fed non-finite data, or diverged.
    NonFinite,
    /// The IMU's samples stopped coming.
    StaleImu,
    /// The run reads ground truth (or has no estimator: a robot without feet) and none came.
    NoGroundTruth,
}

impl std::fmt::Display for EstimateProblem {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Self::NotInitialised => {
                "it never started (no IMU orientation yet, or a robot falling at start that has not held still since)"
            }
            Self::NonFinite => "it was fed non-finite values or diverged",
            Self::StaleImu => "the IMU's samples stopped coming",
            Self::NoGroundTruth => "the run reads the simulation's ground truth and there is none",
        })
    }
}

impl Default for Estimate {
    fn default() -> Self {
        Self {
            position: [0.0; 3],
            velocity: [0.0; 3],
            velocity_base: [0.0; 3],
            orientation: spatial::QUAT_IDENTITY,
            position_std: [0.0; 3],
            velocity_std: [0.0; 3],
            accel_bias: [0.0; 3],
            contacts: [false; MAX_FEET],
            loads: [f64::NAN; MAX_FEET],
            feet: 0,
            held: false,
            filter: FilterKind::default(),
            valid: false,
            problem: Some(EstimateProblem::NotInitialised),
        }
    }
}

/// The legs as the kinematics sees them this tick, in the base's frame.
#[derive(Debug, Clone, Copy)]
pub struct LegKinematics {
    /// Foot origins relative to the base.
    pub position: [[f64; 3]; MAX_FEET],
    /// Where each foot would touch the floor (its sole's lowest points) relative to the base.
    pub contact: [[f64; 3]; MAX_FEET],
    /// That point's velocity relative to the base (the joints moving, the base still).
    pub contact_velocity: [[f64; 3]; MAX_FEET],
    /// How far each foot's origin sits above its sole.
    pub sole_depth: [f64; MAX_FEET],
    /// Foot switches, where the robot has them.
    pub switches: Option<[bool; MAX_FEET]>,
    /// The ground's vertical push on each foot from the legs' joint torques, N (NaN: unknown).
    pub load: [f64; MAX_FEET],
    /// Each leg's weight, hip to toe, N (0: unknown): a swinging leg's own dynamics read as a
    /// load of about this much, so the contact thresholds scale with it.
    pub leg_weight: [f64; MAX_FEET],
}

impl Default for LegKinematics {
    fn default() -> Self {
        Self {
            position: [[0.0; 3]; MAX_FEET],
            contact: [[0.0; 3]; MAX_FEET],
            contact_velocity: [[0.0; 3]; MAX_FEET],
            sole_depth: [0.0; MAX_FEET],
            switches: None,
            load: [f64::NAN; MAX_FEET],
            leg_weight: [0.0; MAX_FEET],
        }
    }
}

/// What the estimator asks of a filter: the IMU propagates it, the legs correct it (a tick's
/// measurements between `begin` and `finish`, in the base's frame; each filter turns them into
/// its world), and it reports the base.
trait Filter {
    /// Base to world, as the filter has it.
    fn rotation(&self) -> Mat3;
    /// The IMU's own orientation this tick (the linear filter's; the invariant filter keeps its own).
    fn set_attitude(&mut self, imu: &Mat3);
    /// Starts at rest: the base at `base`, each foot where the legs put it, the IMU's orientation.
    fn start(&mut self, imu: &Mat3, base: [f64; 3], feet_body: &[[f64; 3]]);
    /// One IMU sample of `dt` seconds (gyro, rad/s, and specific force, m/s², base axes); each
    /// foot's position walks by `foot_walk`, m/√s.
    fn propagate(&mut self, gyro: [f64; 3], accel: [f64; 3], dt: f64, foot_walk: &[f64; MAX_FEET]);
    fn begin(&mut self);
    /// Foot `f`'s origin relative to the base, base axes, with this variance per axis.
    fn foot(&mut self, f: usize, body: [f64; 3], variance: f64);
    /// The base's velocity in its own axes (from a standing foot).
    fn base_velocity(&mut self, body: [f64; 3], variance: f64);
    /// Foot `f`'s origin at this world height.
    fn floor(&mut self, f: usize, height: f64, variance: f64);
    fn finish(&mut self);
    /// Foot `f` left the ground: where it is no longer says anything about the base.
    fn release_foot(&mut self, f: usize, variance: f64);
    fn position(&self) -> [f64; 3];
    fn velocity(&self) -> [f64; 3];
    fn position_std(&self) -> [f64; 3];
    fn velocity_std(&self) -> [f64; 3];
    fn accel_bias(&self) -> [f64; 3];
    /// Whether a measurement failed or the state went non-finite since the last call.
    fn take_fault(&mut self) -> bool;
}

#[derive(Debug, Clone)]
#[allow(
    clippy::large_enum_variant,
    reason = "one per run, made once: nothing to save by boxing"
)]
enum Filters {
    Linear(LinearFilter),
    Invariant(InvariantFilter),
}

impl Filters {
    fn get(&self) -> &dyn Filter {
        match self {
            Self::Linear(f) => f,
            Self::Invariant(f) => f,
        }
    }

    fn get_mut(&mut self) -> &mut dyn Filter {
        match self {
            Self::Linear(f) => f,
            Self::Invariant(f) => f,
        }
    }
}

/// The estimator: a filter, the contacts, the held robot.
#[derive(Debug, Clone)]
pub struct Estimator {
    config: EstimatorConfig,
    feet: usize,
    filter: Filters,
    gravity: [f64; 3],
    /// The robot's weight, N.
    weight: f64,
    /// The latest IMU orientation and rate (base axes).
    quat: [f64; 4],
    gyro: [f64; 3],
    last_sample: Option<std::time::Duration>,
    /// The IMU's orientation is known: a sample was integrated, or the start-up reading seeded it.
    attitude_known: bool,
    /// The first IMU reading was of a robot something carries (not falling): the filter starts on
    /// that tick. A robot dropped at start waits for [`STILL_S`] of rest instead.
    start_at_rest: Option<bool>,
    nominal_dt: f64,
    contacts: [bool; MAX_FEET],
    /// The height each foot's sole last stood at.
    ground: [f64; MAX_FEET],
    initialised: bool,
    /// IMU samples in a row that looked like standing still (specific force ≈ g, slow turn):
    /// a robot is judged held only after [`STILL_S`] of them, not in the middle of a drop.
    still: u32,
    /// Inputs were bad this tick (non-finite or stale).
    input_fault: bool,
    /// The feet carry (almost) none of the robot's weight: the filter starts again when they do.
    held: bool,
    /// A rig (the start's harness) holds the robot, as the run says; `rig_was`: it did last tick.
    rig: bool,
    rig_was: bool,
    /// Ticks in a row on which every standing foot's velocity was refused.
    refused_ticks: u32,
    /// The contact heights and speed scaled to this robot (learned when the filter first starts).
    thresholds: Option<ContactThresholds>,
    /// What each foot's load reads while the legs put it clearly in the air, learned over the run.
    air_load: [AirLoad; MAX_FEET],
}

/// What a foot's load reads while it is in the air: a swinging leg's own dynamics and the
/// actuator's reading error, learned from the robot's own steps (the loads of the last
/// [`AIR_LOAD_WINDOW`] ticks a foot spent in the air, the tick before each landing left out). A
/// landing must rise above its upper decile; a load that falls back into it has lifted off.
#[derive(Debug, Clone, Copy)]
struct AirLoad {
    loads: [f64; AIR_LOAD_WINDOW],
    len: usize,
    next: usize,
    /// The load of the last tick the foot spent in the air, kept once the next tick is in the
    /// air too (a landing's first tick already carries some weight).
    pending: Option<f64>,
    ceiling: Option<f64>,
}

/// Ticks in the air remembered per foot, and how many before the air load is used.
const AIR_LOAD_WINDOW: usize = 128;
const AIR_LOAD_SAMPLES: usize = 20;

impl Default for AirLoad {
    fn default() -> Self {
        Self {
            loads: [0.0; AIR_LOAD_WINDOW],
            len: 0,
            next: 0,
            pending: None,
            ceiling: None,
        }
    }
}

impl AirLoad {
    /// This tick's decision: the foot is in the air (or not) with this load.
    fn update(&mut self, in_air: bool, load: f64) {
        if let Some(l) = self.pending.take()
            && in_air
        {
            self.loads[self.next] = l;
            self.next = (self.next + 1) % AIR_LOAD_WINDOW;
            self.len = (self.len + 1).min(AIR_LOAD_WINDOW);
            if self.len >= AIR_LOAD_SAMPLES {
                let mut sorted = self.loads;
                let sorted = &mut sorted[..self.len];
                let k = self.len * 9 / 10;
                let (_, p90, _) = sorted.select_nth_unstable_by(k, f64::total_cmp);
                self.ceiling = Some(*p90);
            }
        }
        if in_air && load.is_finite() {
            self.pending = Some(load);
        }
    }
}

/// A foot lands within `on` m of where it last stood, moving slower than `speed` m/s, and lifts
/// off beyond `off` m: the configured values scaled to the robot's standing height.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ContactThresholds {
    pub on: f64,
    pub off: f64,
    pub speed: f64,
}

impl ContactThresholds {
    /// `config`'s thresholds for a robot whose base stands `height` m above its soles.
    pub fn scaled(config: &EstimatorConfig, height: f64) -> Self {
        let reference = config.contact_scale_height_m;
        let s = if reference > 0.0 && height.is_finite() && height > 0.0 {
            height / reference
        } else {
            1.0
        };
        Self {
            on: config.contact_on_m * s,
            off: config.contact_off_m * s,
            speed: config.contact_speed * s.sqrt(),
        }
    }
}

/// A foot whose load fell to its air load lifts off once it moves faster than this share of a
/// landing's speed, or rises: a foot rolling onto its toe at the end of a step reads almost
/// nothing while it still touches.
const LIFT_SPEED_SHARE: f64 = 0.5;

/// The air load is used once below this share of a foot's share of the weight: an actuator
/// whose reading swings wider in the air (coarse steps, lag) cannot tell, and the legs decide.
const AIR_LOAD_TRUST: f64 = 0.5;

/// Ticks the filter may refuse every standing foot's velocity in a row (then it takes them).
pub const MAX_REFUSED_TICKS: u32 = 5;

/// How long the IMU must look still before a robot whose feet carry no weight is judged held, s.
const STILL_S: f64 = 0.2;

/// Samples of a longer gap are integrated as this many nominal periods at most.
const MAX_GAP_PERIODS: f64 = 4.0;

impl Estimator {
    /// An estimator for `feet` feet (at most [`MAX_FEET`]), gravity `gravity` (the model's), a
    /// robot weighing `weight` N, an IMU streaming at `imu_rate_hz`; `config.filter` chooses the
    /// filter.
    pub fn new(
        config: EstimatorConfig,
        feet: usize,
        gravity: [f64; 3],
        weight: f64,
        imu_rate_hz: f64,
    ) -> Self {
        let feet = feet.min(MAX_FEET);
        Self {
            config,
            feet,
            filter: match config.filter {
                FilterKind::Linear => Filters::Linear(LinearFilter::new(config, feet, gravity)),
                FilterKind::Invariant => Filters::Invariant(InvariantFilter::new(config, feet, gravity)),
            },
            gravity,
            weight,
            quat: [1.0, 0.0, 0.0, 0.0],
            gyro: [0.0; 3],
            last_sample: None,
            attitude_known: false,
            start_at_rest: None,
            rig: false,
            rig_was: false,
            nominal_dt: 1.0 / imu_rate_hz.max(1.0),
            contacts: [true; MAX_FEET],
            ground: [0.0; MAX_FEET],
            initialised: false,
            still: 0,
            input_fault: false,
            held: false,
            refused_ticks: 0,
            thresholds: None,
            air_load: [AirLoad::default(); MAX_FEET],
        }
    }

    /// The contact thresholds in use (none before the filter first started).
    pub fn contact_thresholds(&self) -> Option<ContactThresholds> {
        self.thresholds
    }

    /// The filter this estimator runs.
    pub fn filter(&self) -> FilterKind {
        self.config.filter
    }

    /// Starts over: the next tick initialises again.
    pub fn reset(&mut self) {
        self.initialised = false;
        self.last_sample = None;
        self.still = 0;
        self.held = false;
    }

    /// Whether the robot is held, from the share of its weight its feet carry (with
    /// hysteresis) while the IMU says something else carries it (still, feeling gravity: not a
    /// push, a fall or a jump, whose feet are unloaded too); unknown loads (a robot whose buses
    /// report no torque) never say held. True on the tick a held robot stands again.
    fn update_held(&mut self, legs: &LegKinematics, still: bool) -> bool {
        // What the run knows beats what the loads suggest: held while the rig holds it, on its
        // feet again the tick the rig lets go.
        let released = self.rig_was && !self.rig;
        self.rig_was = self.rig;
        if self.rig {
            self.held = true;
            return false;
        }
        if released {
            self.held = false;
            return true;
        }
        let loads = &legs.load[..self.feet];
        if self.feet == 0 || loads.iter().any(|l| !l.is_finite()) || self.weight <= 0.0 {
            self.held = false;
            return false;
        }
        let share = loads.iter().map(|l| l.max(0.0)).sum::<f64>() / self.weight;
        let was = self.held;
        self.held = if was {
            share < self.config.standing_above
        } else {
            share < self.config.held_below && still
        };
        was && !self.held
    }

    /// Whether a rig (a harness start's harness, while it lowers the robot) holds the robot: the
    /// estimate says held and takes no foot as standing until the rig lets go, then starts again
    /// with the floor under the feet.
    pub fn hold_by_rig(&mut self, held: bool) {
        self.rig = held;
    }

    /// The IMU's orientation and rate as the robot answered at start-up, before any sample was
    /// integrated (the first tick's read may bring none): enough to start the filter on that
    /// tick. Ignored once a sample came, or when not finite.
    pub fn seed_attitude(&mut self, quat: [f64; 4], gyro: [f64; 3], accel: [f64; 3]) {
        let finite = quat.iter().chain(&gyro).chain(&accel).all(|v| v.is_finite());
        let norm = quat.iter().map(|v| v * v).sum::<f64>().sqrt();
        if self.last_sample.is_none() && finite && norm > 0.5 {
            self.quat = spatial::quat_normalize(quat);
            self.gyro = gyro;
            self.attitude_known = true;
            let supported = self.supported(accel);
            self.start_at_rest.get_or_insert(supported);
        }
    }

    /// A reading of a robot something carries (the floor, a rig, a hand), not one falling: a
    /// specific force of at least 40 % of gravity's. A robot placed on the floor reads less than
    /// g for its first milliseconds while it settles; a dropped one reads almost nothing.
    fn supported(&self, accel: [f64; 3]) -> bool {
        spatial::norm(accel) > 0.4 * spatial::norm(self.gravity)
    }

    /// A reading like rest: the specific force is gravity's (within 10 %), the turn slow.
    fn resting(&self, accel: [f64; 3], gyro: [f64; 3]) -> bool {
        let g = spatial::norm(self.gravity);
        (spatial::norm(accel) - g).abs() < 0.1 * g && spatial::norm(gyro) < 0.3
    }

    /// Integrates one IMU sample (base axes): propagates the state and its covariance.
    pub fn propagate(&mut self, sample: &robot_link::ImuSample) {
        let finite = sample
            .gyro
            .iter()
            .chain(&sample.accel)
            .chain(&sample.quat)
            .all(|v| v.is_finite());
        if !finite {
            self.input_fault = true;
            return;
        }
        let dt = match self.last_sample {
            Some(t) => sample
                .at
                .saturating_sub(t)
                .as_secs_f64()
                .clamp(0.0, MAX_GAP_PERIODS * self.nominal_dt),
            None => self.nominal_dt,
        };
        self.last_sample = Some(sample.at);
        self.attitude_known = true;
        self.quat = spatial::quat_normalize(sample.quat);
        self.gyro = sample.gyro;
        let resting = self.resting(sample.accel, sample.gyro);
        let supported = self.supported(sample.accel);
        self.start_at_rest.get_or_insert(supported);
        self.still = if resting { self.still.saturating_add(1) } else { 0 };
        if !self.initialised || dt == 0.0 {
            return;
        }
        let c = &self.config;
        let foot_walk = std::array::from_fn(|f| {
            if self.contacts[f] {
                c.stance_foot_walk
            } else {
                c.swing_foot_walk
            }
        });
        let filter = self.filter.get_mut();
        filter.set_attitude(&spatial::mat_of_quat(self.quat));
        filter.propagate(sample.gyro, sample.accel, dt, &foot_walk);
    }

    /// Corrects with this tick's leg kinematics. `imu_fresh`: the IMU delivered recently.
    pub fn correct(&mut self, legs: &LegKinematics, imu_fresh: bool) -> Estimate {
        let finite = legs.position[..self.feet]
            .iter()
            .chain(&legs.contact[..self.feet])
            .chain(&legs.contact_velocity[..self.feet])
            .flatten()
            .all(|v| v.is_finite());
        if !finite {
            self.input_fault = true;
        }
        let imu_r = spatial::mat_of_quat(self.quat);
        self.filter.get_mut().set_attitude(&imu_r);
        // At rest: still for a while, or a start that began carried (judged on its first reading).
        let rest_start = !self.initialised && self.start_at_rest == Some(true);
        let settled = f64::from(self.still) * self.nominal_dt >= STILL_S || rest_start;
        // Lowered onto its feet (from a harness, a gantry, a hand): the filter that ran in the
        // air starts over with the floor under the feet that now carry the robot.
        let landed = finite && self.update_held(legs, settled);
        // The filter starts on the first tick the IMU's orientation is known and its reading was
        // of a carried robot: it puts the legs in the world, and every start mode starts at rest
        // (standing, or hanging in the harness), so a policy in control from tick 0 reads a valid
        // estimate from tick 0. A robot dropped at start waits until it has been still a while.
        // A rig's robot starts held, whatever it reads: it starts over when the rig lets go.
        let first = !self.initialised && self.attitude_known && (settled || self.rig);
        if finite && (first || (self.initialised && landed)) {
            self.initialise(legs, &imu_r);
        }
        if self.initialised && finite {
            let stood = self.update_contacts(legs, &imu_r);
            self.measure_legs(legs, &stood);
            // A foot that just landed stands at this height until it lifts off again (latched:
            // a foot that rises slowly must not carry its ground up with it).
            let base_z = self.filter.get().position()[2];
            for f in (0..self.feet).filter(|&f| self.contacts[f] && !stood[f]) {
                self.ground[f] = base_z + spatial::mat_apply(&imu_r, legs.contact[f])[2];
            }
        }
        let problem = if !self.initialised {
            Some(EstimateProblem::NotInitialised)
        } else if self.filter.get_mut().take_fault() || self.input_fault {
            Some(EstimateProblem::NonFinite)
        } else if !imu_fresh {
            Some(EstimateProblem::StaleImu)
        } else {
            None
        };
        let valid = problem.is_none();
        self.input_fault = false;
        let filter = self.filter.get();
        let velocity = filter.velocity();
        let mut contacts = [false; MAX_FEET];
        contacts[..self.feet].copy_from_slice(&self.contacts[..self.feet]);
        Estimate {
            position: filter.position(),
            velocity,
            velocity_base: spatial::mat_apply(&spatial::transpose(&filter.rotation()), velocity),
            orientation: spatial::quat_of_mat(&filter.rotation()),
            position_std: filter.position_std(),
            velocity_std: filter.velocity_std(),
            accel_bias: filter.accel_bias(),
            contacts,
            loads: legs.load,
            feet: self.feet,
            held: self.held,
            filter: self.config.filter,
            valid,
            problem,
        }
    }

    /// Which feet stand this tick (the IMU's orientation puts the legs in the world): each
    /// foot's height above where it last stood, its speed, its load. A foot that leaves the
    /// ground is released in the filter. Returns the contacts before.
    fn update_contacts(&mut self, legs: &LegKinematics, r: &Mat3) -> [bool; MAX_FEET] {
        let omega = self.gyro;
        // A foot's height above where it last stood is measured against another standing foot
        // where there is one (the legs alone, the base cancels), else through the base's
        // estimated height.
        let patch_z = |f: usize| spatial::mat_apply(r, legs.contact[f])[2];
        let standing = self.contacts;
        let (base, base_velocity) = (self.filter.get().position(), self.filter.get().velocity());
        // Each point's velocity relative to the base, in the world's axes (the legs alone).
        let relative = |f: usize| {
            spatial::mat_apply(
                r,
                spatial::add(spatial::cross(omega, legs.contact[f]), legs.contact_velocity[f]),
            )
        };
        let world_speed = |f: usize| spatial::norm(spatial::add(base_velocity, relative(f)));
        let t = self
            .thresholds
            .unwrap_or_else(|| ContactThresholds::scaled(&self.config, 0.0));
        for f in 0..self.feet {
            self.contacts[f] = match legs.switches {
                _ if self.rig => false,
                Some(s) => s[f],
                None => {
                    let other = (0..self.feet).find(|&j| j != f && standing[j]);
                    let height = match other {
                        Some(j) => patch_z(f) - patch_z(j) + self.ground[j] - self.ground[f],
                        None => base[2] + patch_z(f) - self.ground[f],
                    };
                    let speed = world_speed(f);
                    // The legs' torques, where they tell: an unloaded foot is not standing
                    // (it hovers, or is about to lift), a landing one takes weight.
                    let (c, load, leg) = (&self.config, legs.load[f], legs.leg_weight[f]);
                    let air = self.air_load[f]
                        .ceiling
                        .filter(|&a| a < AIR_LOAD_TRUST * self.weight / self.feet as f64);
                    let unloaded = load.is_finite() && load < c.contact_unload * self.weight;
                    let airborne_load = air.is_some_and(|a| load.is_finite() && load < a);
                    // Lighter than a swinging leg's own reading, and moving: lifting off (a
                    // foot unloading slowly in place still touches).
                    let lifting = (load.is_finite() && load < c.leg_unload * leg && speed > t.speed)
                        || (airborne_load && (speed > LIFT_SPEED_SHARE * t.speed || height > t.on));
                    let loaded = !load.is_finite()
                        || (load > c.contact_load * self.weight && air.is_none_or(|a| load > a));
                    let carrying = load.is_finite() && load > c.carrying * self.weight;
                    if self.contacts[f] {
                        carrying || (height < t.off && !unloaded && !lifting)
                    } else {
                        carrying || (height < t.on && speed < t.speed && loaded)
                    }
                }
            };
        }
        if legs.switches.is_none() && !self.rig {
            // Two standing feet do not move apart (within twice a landing's speed: soles roll
            // and flex): where the legs say they do (a kick whose torques read as a load, a
            // foot dragged along), the one moving faster in the world is in the air. Judged by
            // the legs alone, so a wrong velocity cannot confirm itself.
            let feet = self.feet;
            loop {
                let apart = (0..feet)
                    .flat_map(|f| (f + 1..feet).map(move |j| (f, j)))
                    .filter(|&(f, j)| self.contacts[f] && self.contacts[j])
                    .find(|&(f, j)| spatial::norm(spatial::sub(relative(f), relative(j))) > 2.0 * t.speed);
                let Some((f, j)) = apart else { break };
                let moving = if world_speed(f) > world_speed(j) { f } else { j };
                self.contacts[moving] = false;
            }
        }
        for f in 0..self.feet {
            self.air_load[f].update(!self.contacts[f], legs.load[f]);
        }
        for f in (0..self.feet).filter(|&f| standing[f] && !self.contacts[f]) {
            self.filter
                .get_mut()
                .release_foot(f, self.config.swing_foot_walk.powi(2));
        }
        standing
    }

    /// The legs' measurements: every foot's place relative to the base; standing feet on the
    /// level floor (those that stood before this tick too); each standing foot's velocity
    /// (gated) for the base's.
    fn measure_legs(&mut self, legs: &LegKinematics, stood: &[bool; MAX_FEET]) {
        let c = self.config;
        let (feet, contacts, held, omega) = (self.feet, self.contacts, self.held, self.gyro);
        let r_v = c.kinematic_velocity_noise.powi(2);
        // Refused for too long, the legs are believed again until they agree with the filter.
        let trust_all = self.refused_ticks >= MAX_REFUSED_TICKS;
        let filter = self.filter.get_mut();
        // Each standing foot's velocity for the base's: where the foot touches stays still, so
        // the base moves opposite to that point's motion relative to it (a foot rolling onto
        // its edge keeps the edge still). Gated against the filter's: a foot whose velocity is
        // refused slips, and is let go where it stood, so its place does not drag the base either.
        // A foot that lands this tick gives none yet: its sole is still stopping.
        let (r, v, std) = (filter.rotation(), filter.velocity(), filter.velocity_std());
        let mut taken = [None; MAX_FEET];
        let (mut standing_feet, mut outside) = (0, 0);
        for f in (0..feet).filter(|&f| contacts[f] && stood[f]) {
            standing_feet += 1;
            let body = spatial::scale(
                spatial::add(spatial::cross(omega, legs.contact[f]), legs.contact_velocity[f]),
                -1.0,
            );
            let world = spatial::mat_apply(&r, body);
            let distance2: f64 = (0..3)
                .map(|k| (world[k] - v[k]).powi(2) / (std[k].powi(2) + r_v))
                .sum();
            if distance2 > c.velocity_gate.powi(2) {
                outside += 1;
                if !trust_all {
                    filter.release_foot(f, c.swing_foot_walk.powi(2));
                    continue;
                }
            }
            taken[f] = Some(body);
        }
        filter.begin();
        for f in 0..feet {
            filter.foot(f, legs.position[f], c.kinematic_position_noise.powi(2));
        }
        // A level floor: a standing sole is at the height the robot first stood on (z = 0),
        // which makes the height observable; without it, the height drifts.
        if c.floor_noise > 0.0 && !held {
            for f in (0..feet).filter(|&f| contacts[f] && stood[f] && taken[f].is_some()) {
                let sole_below_origin =
                    spatial::mat_apply(&r, spatial::sub(legs.contact[f], legs.position[f]))[2];
                filter.floor(f, -sole_below_origin, c.floor_noise.powi(2));
            }
        }
        for body in taken[..feet].iter().flatten() {
            filter.base_velocity(*body, r_v);
        }
        filter.finish();
        self.refused_ticks = if standing_feet > 0 && outside == standing_feet {
            self.refused_ticks.saturating_add(1)
        } else {
            0
        };
    }

    /// The robot stands on its feet at the world's origin: the base above them so the soles
    /// touch z = 0, still.
    fn initialise(&mut self, legs: &LegKinematics, r: &Mat3) {
        let feet = self.feet;
        let height = (0..feet)
            .map(|f| legs.sole_depth[f] - spatial::mat_apply(r, legs.position[f])[2])
            .sum::<f64>()
            / feet.max(1) as f64;
        let base = [0.0, 0.0, height];
        self.thresholds
            .get_or_insert_with(|| ContactThresholds::scaled(&self.config, height));
        self.filter.get_mut().start(r, base, &legs.position[..feet]);
        for f in 0..feet {
            self.ground[f] = height + spatial::mat_apply(r, legs.contact[f])[2];
        }
        self.contacts = [true; MAX_FEET];
        self.initialised = true;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;

    #[test]
    fn the_air_load_is_the_upper_decile_of_a_foot_in_the_air_without_the_tick_before_a_landing() {
        let mut air = AirLoad::default();
        // Swings reading 0..=9 N, each ended by a landing whose first tick reads 50 N and a
        // stance of 100 N.
        for _ in 0..AIR_LOAD_WINDOW {
            for load in 0..10 {
                air.update(true, f64::from(load));
            }
            air.update(true, 50.0);
            air.update(false, 100.0);
            air.update(false, 100.0);
        }
        assert_eq!(air.ceiling, Some(9.0), "{air:?}");
        // Too few samples: not used yet.
        let mut short = AirLoad::default();
        for _ in 0..AIR_LOAD_SAMPLES {
            short.update(true, 1.0);
        }
        assert_eq!(short.ceiling, None);
        short.update(true, 1.0);
        assert_eq!(short.ceiling, Some(1.0));
    }

    /// Each test of the filters' behaviour runs on both.
    fn both_filters() -> [EstimatorConfig; 2] {
        [FilterKind::Invariant, FilterKind::Linear].map(|filter| EstimatorConfig {
            filter,
            ..EstimatorConfig::default()
        })
    }

    fn sample(k: u64, accel: [f64; 3]) -> robot_link::ImuSample {
        robot_link::ImuSample {
            gyro: [0.0; 3],
            accel,
            quat: [1.0, 0.0, 0.0, 0.0],
            at: Duration::from_millis(5 * k),
        }
    }

    /// One policy tick at a time on an IMU at rest: four 200 Hz samples of gravity, then the legs.
    fn still_imu_ticks() -> impl FnMut(&mut Estimator, &LegKinematics) -> Estimate {
        let mut tick = 0u64;
        move |e, legs| {
            for k in 0..4 {
                e.propagate(&sample(4 * tick + k, [0.0, 0.0, 9.81]));
            }
            tick += 1;
            e.correct(legs, true)
        }
    }

    /// A 160 N robot's weight.
    const WEIGHT: f64 = 160.0;

    /// An estimator that has stood still 60 ticks on two feet each carrying half the weight; its
    /// legs, and the ticks of a still IMU that go on.
    fn settled_on_both_feet(
        config: EstimatorConfig,
    ) -> (
        Estimator,
        LegKinematics,
        impl FnMut(&mut Estimator, &LegKinematics) -> Estimate,
    ) {
        let mut e = Estimator::new(config, 2, [0.0, 0.0, -9.81], WEIGHT, 200.0);
        let mut legs = standing_legs();
        legs.load = [0.5 * WEIGHT, 0.5 * WEIGHT, 0.0, 0.0];
        let mut step = still_imu_ticks();
        for _ in 0..60 {
            step(&mut e, &legs);
        }
        (e, legs, step)
    }

    fn standing_legs() -> LegKinematics {
        LegKinematics {
            position: [[0.0, 0.1, -0.4], [0.0, -0.1, -0.4], [0.0; 3], [0.0; 3]],
            contact: [[0.0, 0.1, -0.44], [0.0, -0.1, -0.44], [0.0; 3], [0.0; 3]],
            sole_depth: [0.04; MAX_FEET],
            ..LegKinematics::default()
        }
    }

    #[test]
    fn a_robot_standing_still_stays_put_and_learns_its_accelerometer_bias() {
        for config in both_filters() {
            let mut e = Estimator::new(config, 2, [0.0, 0.0, -9.81], 160.0, 200.0);
            let legs = standing_legs();
            // The accelerometer reads gravity plus a bias of 0.3 m/s² along x.
            let mut last = Estimate::default();
            for tick in 0..3000u64 {
                for k in 0..4 {
                    e.propagate(&sample(4 * tick + k, [0.3, 0.0, 9.81]));
                }
                last = e.correct(&legs, true);
            }
            assert!(last.valid);
            assert!((last.position[2] - 0.44).abs() < 1e-3, "{last:?}");
            assert!(
                spatial::norm([last.position[0], last.position[1], 0.0]) < 0.01,
                "{last:?}"
            );
            assert!(spatial::norm(last.velocity) < 0.01, "{last:?}");
            assert!((last.accel_bias[0] - 0.3).abs() < 0.05, "{last:?}");
            assert_eq!(&last.contacts[..2], &[true, true]);
        }
    }

    #[test]
    fn a_lifted_foot_is_in_the_air_and_lands_again() {
        for config in both_filters() {
            let mut e = Estimator::new(config, 2, [0.0, 0.0, -9.81], 160.0, 200.0);
            let mut legs = standing_legs();
            let mut step = still_imu_ticks();
            for _ in 0..50 {
                step(&mut e, &legs);
            }
            legs.position[0][2] = -0.35;
            legs.contact[0][2] = -0.39;
            let up = step(&mut e, &legs);
            assert_eq!(&up.contacts[..2], &[false, true], "{up:?}");
            assert!(
                (up.position[2] - 0.44).abs() < 2e-3,
                "the standing foot holds the base: {up:?}"
            );
            legs.position[0][2] = -0.4;
            legs.contact[0][2] = -0.44;
            let down = step(&mut e, &legs);
            assert_eq!(&down.contacts[..2], &[true, true], "{down:?}");
        }
    }

    #[test]
    fn a_robot_held_in_the_air_says_so_and_starts_again_on_its_feet_on_the_floor() {
        for config in both_filters() {
            let weight = 160.0;
            let mut e = Estimator::new(config, 2, [0.0, 0.0, -9.81], weight, 200.0);
            let mut legs = standing_legs();
            let mut step = still_imu_ticks();
            // Hanging 10 cm up in a harness: the legs carry nothing.
            legs.load = [1.0, 1.0, 0.0, 0.0];
            let mut held = Estimate::default();
            for _ in 0..60 {
                held = step(&mut e, &legs);
            }
            assert!(held.valid && held.held, "{held:?}");
            // Lowered: the feet take the weight, the filter starts again with its soles at z = 0.
            legs.load = [0.5 * weight, 0.5 * weight, 0.0, 0.0];
            let mut down = Estimate::default();
            for _ in 0..100 {
                down = step(&mut e, &legs);
            }
            assert!(down.valid && !down.held, "{down:?}");
            assert!((down.position[2] - 0.44).abs() < 1e-3, "{down:?}");
            // Half the weight on the feet is not yet standing after being held (hysteresis)…
            legs.load = [0.01 * weight, 0.01 * weight, 0.0, 0.0];
            assert!(step(&mut e, &legs).held);
            legs.load = [0.25 * weight, 0.25 * weight, 0.0, 0.0];
            assert!(step(&mut e, &legs).held, "50 % of the weight after being held");
            legs.load = [0.4 * weight, 0.4 * weight, 0.0, 0.0];
            assert!(!step(&mut e, &legs).held);
        }
    }

    /// Steps in place for `steps` steps with an accelerometer reading `accel_z` upward (a bias
    /// the filter must learn), each foot lifted 5 cm in turn; the height error at the end, m.
    fn stepping_height_error(config: EstimatorConfig, steps: u64, accel_z: f64) -> f64 {
        let mut e = Estimator::new(config, 2, [0.0, 0.0, -9.81], 160.0, 200.0);
        let mut tick = 0u64;
        let mut step = |e: &mut Estimator, legs: &LegKinematics, accel: f64| {
            for k in 0..4 {
                e.propagate(&sample(4 * tick + k, [0.0, 0.0, accel]));
            }
            tick += 1;
            e.correct(legs, true)
        };
        let standing = standing_legs();
        for _ in 0..60 {
            step(&mut e, &standing, 9.81);
        }
        let mut last = Estimate::default();
        for n in 0..steps {
            let mut lifted = standing;
            let f = (n % 2) as usize;
            lifted.position[f][2] += 0.05;
            lifted.contact[f][2] += 0.05;
            for _ in 0..15 {
                step(&mut e, &lifted, accel_z);
            }
            for _ in 0..10 {
                last = step(&mut e, &standing, accel_z);
            }
        }
        (last.position[2] - 0.44).abs()
    }

    #[test]
    fn stepping_in_place_the_level_floor_keeps_the_height_the_landings_alone_lose() {
        for config in both_filters() {
            let on_floor = stepping_height_error(config, 200, 10.01);
            let landings_only = stepping_height_error(
                EstimatorConfig {
                    floor_noise: 0.0,
                    ..config
                },
                200,
                10.01,
            );
            assert!(on_floor < 2e-3, "{on_floor}");
            assert!(landings_only > 2.0 * on_floor, "{landings_only} vs {on_floor}");
        }
    }

    #[test]
    fn a_light_foot_lifts_off_when_it_moves_and_keeps_touching_while_it_unloads_in_place() {
        for config in both_filters() {
            let weight = 160.0;
            let run = |up_speed: f64| {
                let mut e = Estimator::new(config, 2, [0.0, 0.0, -9.81], weight, 200.0);
                let mut legs = standing_legs();
                legs.leg_weight = [36.0, 36.0, 0.0, 0.0];
                legs.load = [0.5 * weight, 0.5 * weight, 0.0, 0.0];
                let mut last = Estimate::default();
                for tick in 0..70u64 {
                    if tick >= 60 {
                        // Foot 0 carries 10 N (above 1 % of the weight, under half its leg's weight)…
                        legs.load = [10.0, weight - 10.0, 0.0, 0.0];
                        // …and rises at `up_speed` (the legs' own motion, relative to the base).
                        legs.contact_velocity[0] = [0.0, 0.0, up_speed];
                    }
                    for k in 0..4 {
                        e.propagate(&sample(4 * tick + k, [0.0, 0.0, 9.81]));
                    }
                    last = e.correct(&legs, true);
                }
                last.contacts[0]
            };
            assert!(!run(0.5), "lifting at 0.5 m/s: off the ground");
            assert!(run(0.0), "unloading in place: still touching");
        }
    }

    #[test]
    fn a_kick_whose_torques_read_as_a_load_is_in_the_air_and_does_not_move_the_base() {
        for config in both_filters() {
            let (mut e, mut legs, mut step) = settled_on_both_feet(config);
            // Foot 0 swings forward at 2 m/s relative to the still base, its leg's torques
            // reading as much load as the standing foot's: it kicks, the base stays.
            let mut last = Estimate::default();
            for _ in 0..10 {
                legs.contact_velocity[0] = [2.0, 0.0, 0.0];
                legs.position[0][0] += 2.0 * 0.02;
                legs.contact[0][0] += 2.0 * 0.02;
                last = step(&mut e, &legs);
                assert_eq!(&last.contacts[..2], &[false, true], "{last:?}");
            }
            assert!(spatial::norm(last.velocity) < 0.05, "{last:?}");
        }
    }

    #[test]
    fn a_foot_carrying_a_quarter_of_the_weight_stands_wherever_the_legs_put_it() {
        for config in both_filters() {
            let (mut e, mut legs, mut step) = settled_on_both_feet(config);
            // Foot 0 lifted 5 cm, unloaded: in the air.
            legs.position[0][2] += 0.05;
            legs.contact[0][2] += 0.05;
            legs.load = [0.0, WEIGHT, 0.0, 0.0];
            assert!(!step(&mut e, &legs).contacts[0]);
            // It carries 30 % of the weight while the kinematics still put it 3 cm up (a step down,
            // a compliant sole): standing.
            legs.position[0][2] -= 0.02;
            legs.contact[0][2] -= 0.02;
            legs.load = [0.3 * WEIGHT, 0.7 * WEIGHT, 0.0, 0.0];
            assert!(step(&mut e, &legs).contacts[0]);
        }
    }

    #[test]
    fn a_foot_that_slips_for_a_few_ticks_does_not_drag_the_velocity_and_a_lasting_one_is_taken() {
        for config in both_filters() {
            let run = |slip_ticks: u64| {
                let mut e = Estimator::new(config, 2, [0.0, 0.0, -9.81], 160.0, 200.0);
                let mut legs = standing_legs();
                let mut last = Estimate::default();
                for tick in 0..(60 + slip_ticks) {
                    // Both feet's kinematics say the base moves at 2 m/s while the IMU feels nothing.
                    let slipping = tick >= 60;
                    for f in 0..2 {
                        legs.contact_velocity[f] = if slipping { [-2.0, 0.0, 0.0] } else { [0.0; 3] };
                    }
                    for k in 0..4 {
                        e.propagate(&sample(4 * tick + k, [0.0, 0.0, 9.81]));
                    }
                    last = e.correct(&legs, true);
                }
                last.velocity[0]
            };
            assert!(run(3).abs() < 0.05, "{}", run(3));
            let lasting = run(u64::from(MAX_REFUSED_TICKS) + 20);
            assert!(lasting > 0.5, "a lasting disagreement is believed: {lasting}");
        }
    }

    #[test]
    fn a_biased_gyro_does_not_tilt_the_invariant_filter() {
        // Standing still for a minute on a gyro biased 0.5 °/s about x and y: integrated alone,
        // 42° of tilt. The legs, gravity and the IMU's own tilt hold it level.
        let bias = 0.5f64.to_radians();
        let mut e = Estimator::new(EstimatorConfig::default(), 2, [0.0, 0.0, -9.81], 160.0, 200.0);
        assert_eq!(e.filter(), FilterKind::Invariant);
        let legs = standing_legs();
        let mut last = Estimate::default();
        for tick in 0..3000u64 {
            for k in 0..4 {
                e.propagate(&robot_link::ImuSample {
                    gyro: [bias, -bias, 0.0],
                    ..sample(4 * tick + k, [0.0, 0.0, 9.81])
                });
            }
            last = e.correct(&legs, true);
        }
        let up = spatial::quat_rotate(last.orientation, [0.0, 0.0, 1.0]);
        let tilt = spatial::angle_between(up, [0.0, 0.0, 1.0]).to_degrees();
        assert!(last.valid && tilt < 0.5, "tilt {tilt}°: {last:?}");
        assert!(spatial::norm(last.velocity) < 0.01, "{last:?}");
        assert!((last.position[2] - 0.44).abs() < 2e-3, "{last:?}");
    }

    #[test]
    fn non_finite_or_stale_input_makes_the_estimate_invalid() {
        for config in both_filters() {
            let mut e = Estimator::new(config, 2, [0.0, 0.0, -9.81], 160.0, 200.0);
            let legs = standing_legs();
            // Not before an IMU sample came; from the first one on (a policy in control from
            // tick 0 reads it), whether or not the IMU has looked still yet.
            assert_eq!(
                e.correct(&legs, true).problem,
                Some(EstimateProblem::NotInitialised)
            );
            e.propagate(&sample(0, [0.0, 0.0, 9.81]));
            assert!(e.correct(&legs, true).valid, "valid from the first sample");
            e.propagate(&sample(39, [0.0, 0.0, 9.81]));
            assert!(e.correct(&legs, true).valid);
            e.propagate(&sample(40, [f64::NAN, 0.0, 9.81]));
            assert!(!e.correct(&legs, true).valid);
            e.propagate(&sample(41, [0.0, 0.0, 9.81]));
            assert!(e.correct(&legs, true).valid, "a good sample again: valid again");
            assert!(!e.correct(&legs, false).valid, "stale IMU");
            let mut bad = legs;
            bad.contact_velocity[1][0] = f64::INFINITY;
            assert!(!e.correct(&bad, true).valid);
        }
    }

    #[test]
    fn a_robot_falling_at_start_waits_until_it_has_held_still() {
        for config in both_filters() {
            let mut e = Estimator::new(config, 2, [0.0, 0.0, -9.81], 160.0, 200.0);
            let legs = standing_legs();
            // Dropped: free fall reads no specific force.
            for k in 0..10 {
                e.propagate(&sample(k, [0.0, 0.0, 0.1]));
            }
            assert_eq!(
                e.correct(&legs, true).problem,
                Some(EstimateProblem::NotInitialised)
            );
            // On the floor: 0.2 s of rest (40 samples at 200 Hz) before it starts.
            for k in 10..49 {
                e.propagate(&sample(k, [0.0, 0.0, 9.81]));
            }
            assert!(!e.correct(&legs, true).valid, "not settled yet");
            e.propagate(&sample(49, [0.0, 0.0, 9.81]));
            assert!(e.correct(&legs, true).valid);
        }
    }
}
