//! Offline retargeting: a human BVH recording onto the robot, through the retargeting map of its
//! robot.toml (nominal calibration in a T-pose or the first frame) and inverse kinematics on its
//! MuJoCo model, with the joints inside their limits and the soles kept out of the floor. The
//! result is a clip in the controller's CSV format.

use std::fmt::Write as _;

use crate::body_map::{Frame, PairParams, RetargetMap};
pub use crate::body_map::{HUMAN_BODIES, HumanPose};
use robots::spatial::{self, Mat3};
use robots::{HumanBody, Robot};

use super::ik::{Ik, IkGoal};
use crate::HumanError;
use motion::bvh::{Bvh, Dialect, Pose};

/// The BVH joint standing for a human body, per dialect.
pub fn bvh_joint(dialect: Dialect, body: HumanBody) -> &'static str {
    use HumanBody as H;
    match (dialect, body) {
        (Dialect::Cmu, H::Root) | (Dialect::Bandai, H::Root) => "Hips",
        (Dialect::Cmu, H::Head) | (Dialect::Bandai, H::Head) => "Head",
        (Dialect::Cmu, H::LeftHand) => "LeftHand",
        (Dialect::Cmu, H::RightHand) => "RightHand",
        (Dialect::Cmu, H::LeftElbow) => "LeftForeArm",
        (Dialect::Cmu, H::RightElbow) => "RightForeArm",
        (Dialect::Cmu, H::LeftFoot) => "LeftFoot",
        (Dialect::Cmu, H::RightFoot) => "RightFoot",
        (Dialect::Cmu, H::LeftKnee) => "LeftLeg",
        (Dialect::Cmu, H::RightKnee) => "RightLeg",
        (Dialect::Bandai, H::LeftHand) => "Hand_L",
        (Dialect::Bandai, H::RightHand) => "Hand_R",
        (Dialect::Bandai, H::LeftElbow) => "LowerArm_L",
        (Dialect::Bandai, H::RightElbow) => "LowerArm_R",
        (Dialect::Bandai, H::LeftFoot) => "Foot_L",
        (Dialect::Bandai, H::RightFoot) => "Foot_R",
        (Dialect::Bandai, H::LeftKnee) => "LowerLeg_L",
        (Dialect::Bandai, H::RightKnee) => "LowerLeg_R",
        (Dialect::Cmu, H::Chest) => "Spine1",
        (Dialect::Bandai, H::Chest) => "Chest",
        (Dialect::Cmu, H::LeftHip) => "LeftUpLeg",
        (Dialect::Cmu, H::RightHip) => "RightUpLeg",
        (Dialect::Bandai, H::LeftHip) => "UpperLeg_L",
        (Dialect::Bandai, H::RightHip) => "UpperLeg_R",
        (Dialect::Cmu, H::LeftShoulder) => "LeftArm",
        (Dialect::Cmu, H::RightShoulder) => "RightArm",
        (Dialect::Bandai, H::LeftShoulder) => "UpperArm_L",
        (Dialect::Bandai, H::RightShoulder) => "UpperArm_R",
    }
}

/// The BVH joint whose orientation a body takes, where it is not its own: a robot's rigid sole
/// lies like the human forefoot (the toes' segment), flat on the floor through toe-off while the
/// heel rises (GMR's feet follow the toes' orientation too).
pub(crate) fn orientation_joint(dialect: Dialect, body: HumanBody) -> Option<&'static str> {
    use HumanBody as H;
    match (dialect, body) {
        (Dialect::Cmu, H::LeftFoot) => Some("LeftToeBase"),
        (Dialect::Cmu, H::RightFoot) => Some("RightToeBase"),
        (Dialect::Bandai, H::LeftFoot) => Some("Toes_L"),
        (Dialect::Bandai, H::RightFoot) => Some("Toes_R"),
        _ => None,
    }
}

/// A recording turned to face +x (the rotation) and moved over the origin (where its root was,
/// after the turn).
type Alignment = (Mat3, [f64; 3]);

/// The thighs' roots, whose line gives a skeleton's heading.
fn hips(dialect: Dialect) -> [&'static str; 2] {
    match dialect {
        Dialect::Cmu => ["LeftUpLeg", "RightUpLeg"],
        Dialect::Bandai => ["UpperLeg_L", "UpperLeg_R"],
    }
}

/// The robot's pose matching the human's nominal frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Nominal {
    /// robot.toml's `[retarget] tpose` (the human's nominal frame is a T-pose).
    Tpose,
    /// The default standing pose (the human's nominal frame stands with the arms down).
    Default,
}

/// How to retarget.
#[derive(Debug, Clone, PartialEq)]
pub struct RetargetOptions {
    /// Output rate, Hz.
    pub rate_hz: f64,
    /// The BVH frame whose pose matches the robot's nominal pose.
    pub nominal_frame: usize,
    /// The first BVH frame of the clip (CMU trials hold their T-pose for one frame only).
    pub start_frame: usize,
    /// Which robot pose that is.
    pub nominal: Nominal,
    /// IK iterations per output frame (the first frame gets twenty times as many).
    pub iterations: usize,
    /// Gaussian smoothing of the human motion before retargeting, σ in seconds (0: none).
    pub smoothing_s: f64,
    /// What of the performer is used: the whole skeleton, or only where a headset, two
    /// controllers and two foot trackers would be (the rest estimated as live five-point
    /// teleoperation does).
    pub wearing: crate::sparse::Wearing,
}

impl Default for RetargetOptions {
    fn default() -> Self {
        Self {
            rate_hz: 50.0,
            nominal_frame: 0,
            start_frame: 0,
            nominal: Nominal::Tpose,
            iterations: 12,
            smoothing_s: 0.08,
            wearing: crate::sparse::Wearing::WholeBody,
        }
    }
}

/// A retargeted motion.
#[derive(Debug, Clone, PartialEq)]
pub struct Retargeted {
    /// Frame times, s.
    pub times: Vec<f64>,
    /// Root poses `[x, y, z, w, qx, qy, qz]`.
    pub root: Vec<[f64; 7]>,
    /// Joints (policy order), per frame.
    pub q: Vec<Vec<f64>>,
    /// The global scale of the map.
    pub scale: f64,
    /// Largest distance between a paired robot frame and its target, m (position pairs).
    pub worst_position_error: f64,
    /// Mean of it.
    pub mean_position_error: f64,
    /// Per position pair: robot frame name, mean and worst distance from its target, m.
    pub pair_errors: Vec<(String, f64, f64)>,
    /// Per frame, which feet the human had planted (pairs' order of [`Retargeter::feet`]).
    pub planted: Vec<[bool; 2]>,
    /// How well the result follows the human, measured on the result.
    pub report: RetargetReport,
}

/// A BVH skeleton's joints for the human bodies: each body at its joint, turned as its
/// orientation joint (the feet as the toes).
#[derive(Debug, Clone)]
pub struct BvhBodies {
    joints: Vec<(HumanBody, usize, usize)>,
}

impl BvhBodies {
    /// The bodies `bvh` has joints for; `needed` must all be there (named in the error).
    pub fn new(bvh: &Bvh, needed: &[HumanBody]) -> Result<Self, HumanError> {
        use HumanBody as H;
        let all = [
            H::Root,
            H::Head,
            H::LeftHand,
            H::RightHand,
            H::LeftElbow,
            H::RightElbow,
            H::LeftFoot,
            H::RightFoot,
            H::LeftKnee,
            H::RightKnee,
            H::Chest,
            H::LeftHip,
            H::RightHip,
            H::LeftShoulder,
            H::RightShoulder,
        ];
        let mut joints = Vec::new();
        for body in all {
            let name = bvh_joint(bvh.dialect, body);
            match bvh.joint(name) {
                Some(j) => {
                    let turned = orientation_joint(bvh.dialect, body)
                        .and_then(|n| bvh.joint(n))
                        .unwrap_or(j);
                    joints.push((body, j, turned));
                }
                None if needed.contains(&body) => {
                    return Err(HumanError::map(format!(
                        "the recording has no {name} joint for {body:?}"
                    )));
                }
                None => {}
            }
        }
        Ok(Self { joints })
    }

    /// The bodies of a pose of the skeleton.
    pub fn pose(&self, pose: &Pose) -> HumanPose {
        let mut out = HumanPose::default();
        for &(body, j, turned) in &self.joints {
            out.set(
                body,
                Frame {
                    pos: pose.pos[j],
                    rot: pose.rot[turned],
                },
            );
        }
        out
    }
}

/// How the retargeter runs, whatever feeds it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RetargeterOptions {
    /// Which robot pose the human's nominal pose matches.
    pub nominal: Nominal,
    /// IK iterations per frame (the first frame gets twenty times as many).
    pub iterations: usize,
}

/// A human foot below this height over its floor, m, moving slower than [`PLANT_SPEED`], is
/// planted; it lifts above [`LIFT_HEIGHT`] or faster than [`LIFT_SPEED`] (hysteresis: a foot
/// rolling over its heel does not flicker).
pub const PLANT_HEIGHT: f64 = 0.05;
/// See [`PLANT_HEIGHT`], m/s (horizontal).
pub const PLANT_SPEED: f64 = 0.25;
/// See [`PLANT_HEIGHT`], m.
pub const LIFT_HEIGHT: f64 = 0.08;
/// See [`PLANT_HEIGHT`], m/s.
pub const LIFT_SPEED: f64 = 0.5;
/// After a lift the robot's foot catches up with the human's over this long, s (where the two
/// parted while planted).
pub const CATCH_UP_S: f64 = 0.2;
/// How far a planted robot foot may stay from where the human's foot maps, m on the human's
/// scale.
pub const PLANT_DRIFT: f64 = 0.04;
/// Putting planted feet back after smoothing: weight of each leg joint's change from its
/// smoothed angle, per radian, against 10 per metre of the foot's distance from where it stood.
const REPLANT_ANCHOR_WEIGHT: f64 = 0.5;
/// A planted foot's position weighs this many times its pair's own.
pub const PLANTED_WEIGHT: f64 = 4.0;

/// One foot pair's planting state.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Foot {
    /// The human foot's floor: its height when standing, m.
    floor: f64,
    /// Where the robot's foot stands while planted (x, y), its goal's offset from the human's
    /// mapped foot, and the human foot's last position.
    planted: Option<[f64; 2]>,
    offset: [f64; 2],
    last: Option<[f64; 3]>,
}

/// Human poses onto the robot, one frame at a time, on GMR's recipe: the map calibrated on the
/// human's nominal pose (rest-pose alignment, scale by height, per body group), then per frame
/// two inverse-kinematics stages on the robot's model (posture, then every pair's weights),
/// within joint limits and motor speeds, soles out of the floor, planted feet held where they
/// stand. Causal: offline retargeting and a live operator run the same steps.
#[derive(Debug)]
pub struct Retargeter {
    pairs: Vec<robots::BodyPair>,
    root_pair: usize,
    ik: Ik,
    target: Vec<Frame>,
    position_map: RetargetMap,
    orientation_map: RetargetMap,
    alignment: Alignment,
    feet: Vec<(usize, Foot)>,
    two_stages: bool,
    iterations: usize,
    velocity_limits: Vec<f64>,
    q: Vec<f64>,
    started: bool,
    goals: Vec<IkGoal>,
    posture: Vec<IkGoal>,
    /// Each pair's place on the scaled human this frame.
    human: Vec<[f64; 3]>,
    /// Per pair: squared, plain and worst distance from its goal, frames.
    errors: Vec<(f64, f64, f64, usize)>,
}

/// The heading of a pose from its thighs' line (or the root's forward axis), as a turn about z.
fn heading_of(pose: &HumanPose) -> Option<f64> {
    match (pose.get(HumanBody::LeftHip), pose.get(HumanBody::RightHip)) {
        (Some(l), Some(r)) => {
            let lateral = spatial::sub(l.pos, r.pos);
            Some(lateral[1].atan2(lateral[0]) - std::f64::consts::FRAC_PI_2)
        }
        _ => pose.get(HumanBody::Root).map(|r| spatial::heading(&r.rot)),
    }
}

impl Retargeter {
    /// Follows only the positions of `bodies`, not their orientations: a source that estimates
    /// them (a limb's roll about its own axis, which five points do not see) would
    /// otherwise turn the robot's limb where the person's did not.
    pub fn positions_only(&mut self, bodies: &[HumanBody]) {
        for p in self.pairs.iter_mut().filter(|p| bodies.contains(&p.human)) {
            p.orientation_weight = 0.0;
            if let Some(w) = &mut p.posture {
                w.orientation_weight = 0.0;
            }
        }
    }

    /// Calibrates the map on `nominal`, the human in the pose that matches the robot's
    /// `options.nominal` pose (a T-pose, or standing), feet on the floor. Every body the
    /// robot's `[retarget]` pairs must be seen.
    pub fn new(robot: &Robot, nominal: &HumanPose, options: RetargeterOptions) -> Result<Self, HumanError> {
        let config = robot.config.retarget.as_ref().ok_or_else(|| {
            HumanError::map(format!(
                "{}: no [retarget] section: which robot body stands for which human one?",
                robot.path.display()
            ))
        })?;
        let root_pair = config
            .pairs
            .iter()
            .position(|p| p.human == HumanBody::Root)
            .ok_or_else(|| HumanError::map("[retarget] pairs no robot frame with the root"))?;
        if let Some(p) = config.pairs.iter().find(|p| nominal.get(p.human).is_none()) {
            return Err(HumanError::map(format!(
                "the source does not see the {:?} that robot.toml pairs with {}",
                p.human, p.frame
            )));
        }
        if heading_of(nominal).is_none() {
            return Err(HumanError::map(
                "the source sees neither thighs nor a root to tell its heading",
            ));
        }
        let frames: Vec<String> = config.pairs.iter().map(|p| p.frame.clone()).collect();
        let mut ik = Ik::new(robot, &frames, true, &[])?;
        // Soles stay out of the floor by moving the foot (its pitch, the leg), not by lifting the
        // whole robot off the other, planted foot: twice the heaviest pair's weight.
        ik.floor_weight = 2.0
            * config
                .pairs
                .iter()
                .map(|p| p.position_weight.max(p.orientation_weight))
                .fold(1.0, f64::max);
        for (k, p) in config.pairs.iter().enumerate() {
            ik.set_compare(k, p.orientation_compare, p.twist_axis);
        }
        // The robot in its nominal pose, soles on the floor.
        let q: Vec<f64> = robot
            .config
            .joints
            .iter()
            .map(|j| match options.nominal {
                Nominal::Tpose => config.tpose.get(&j.name).copied().unwrap_or(0.0),
                Nominal::Default => j.default_position,
            })
            .collect();
        ik.standing_root(&q);
        let target: Vec<Frame> = (0..frames.len()).map(|k| ik.frame(k)).collect();
        let mut me = Self {
            pairs: config.pairs.clone(),
            root_pair,
            ik,
            target,
            position_map: RetargetMap {
                scale: 1.0,
                z_shift: 0.0,
                pairs: Vec::new(),
            },
            orientation_map: RetargetMap {
                scale: 1.0,
                z_shift: 0.0,
                pairs: Vec::new(),
            },
            alignment: (spatial::IDENTITY, [0.0; 3]),
            feet: Vec::new(),
            two_stages: config.pairs.iter().any(|p| p.posture.is_some()),
            iterations: options.iterations.max(1),
            velocity_limits: robot.config.joints.iter().map(|j| j.velocity_limit).collect(),
            q,
            started: false,
            goals: Vec::with_capacity(frames.len()),
            posture: Vec::with_capacity(frames.len()),
            human: Vec::with_capacity(frames.len()),
            errors: vec![(0.0, 0.0, 0.0, 0); frames.len()],
        };
        me.align_to(nominal);
        let params: Vec<PairParams> = me
            .pairs
            .iter()
            .map(|p| PairParams {
                p_pos: p.p_pos,
                p_ori: p.p_ori,
            })
            .collect();
        let map = |frame: &dyn Fn(usize) -> Frame| {
            let source: Vec<Frame> = (0..me.pairs.len()).map(frame).collect();
            RetargetMap::nominal(
                source[root_pair].pos[2],
                me.target[root_pair].pos[2],
                &source,
                &me.target,
                &params,
                0.0,
            )
        };
        let position_map = map(&|b| me.heading_frame(nominal, b))?;
        let orientation_map = map(&|b| me.body_frame(nominal, b))?;
        me.position_map = position_map;
        me.orientation_map = orientation_map;
        me.feet = (0..me.pairs.len())
            .filter(|&b| matches!(me.pairs[b].human, HumanBody::LeftFoot | HumanBody::RightFoot))
            .map(|b| {
                (
                    b,
                    Foot {
                        floor: me.body_frame(nominal, b).pos[2],
                        planted: None,
                        offset: [0.0; 2],
                        last: None,
                    },
                )
            })
            .collect();
        Ok(me)
    }

    /// Turns the source's world so that `pose` faces +x with its root over the origin (a clip
    /// calibrated on another recording starts where it starts).
    pub fn align_to(&mut self, pose: &HumanPose) {
        let turn = spatial::yaw(-heading_of(pose).unwrap_or(0.0));
        let root = pose
            .get(HumanBody::Root)
            .map_or([0.0; 3], |r| spatial::mat_apply(&turn, r.pos));
        self.alignment = (turn, root);
    }

    /// Sets each foot's floor, the human foot's height when standing, m (pairs of [`Self::feet`]).
    pub fn set_feet_floor(&mut self, floors: &[f64]) {
        for ((_, f), &z) in self.feet.iter_mut().zip(floors) {
            f.floor = z;
        }
    }

    /// The robot frames of the feet pairs, in the order of the planted flags.
    pub fn feet(&self) -> Vec<String> {
        self.feet
            .iter()
            .map(|(b, _)| self.pairs[*b].frame.clone())
            .collect()
    }

    /// The map's global scale (robot root height over the human's).
    pub fn scale(&self) -> f64 {
        self.position_map.scale
    }

    /// A source frame in the aligned world.
    fn aligned(&self, f: &Frame) -> Frame {
        let (turn, origin) = &self.alignment;
        let mut pos = spatial::mat_apply(turn, f.pos);
        pos[0] -= origin[0];
        pos[1] -= origin[1];
        Frame {
            pos,
            rot: spatial::mat_mul(turn, &f.rot),
        }
    }

    /// Pair `b`'s body, aligned, its offset from the root scaled by the pair's factor (limbs of
    /// other proportions).
    fn body_frame(&self, pose: &HumanPose, b: usize) -> Frame {
        let pair = &self.pairs[b];
        let (Some(f), Some(root)) = (pose.get(pair.human), pose.get(self.pairs[self.root_pair].human)) else {
            return self.target[b];
        };
        let (mut f, root) = (self.aligned(f), self.aligned(root));
        f.pos = spatial::add(
            root.pos,
            spatial::scale(spatial::sub(f.pos, root.pos), pair.scale),
        );
        f
    }

    /// The nominal position offsets stand for other body proportions (an ankle lower, hips
    /// wider), which turn with the body's heading, not with the limb: a foot pitching about its
    /// ankle leaves the ankle where it is. So positions map in the heading frame, orientations
    /// in each body's own frame.
    fn heading_frame(&self, pose: &HumanPose, b: usize) -> Frame {
        Frame {
            pos: self.body_frame(pose, b).pos,
            rot: spatial::mat_mul(&self.alignment.0, &spatial::yaw(heading_of(pose).unwrap_or(0.0))),
        }
    }

    /// Pair `b`'s goal for the human in `pose`, before planting.
    fn goal_frame(&self, pose: &HumanPose, b: usize) -> Frame {
        let body = self.body_frame(pose, b);
        let mut pos = self.position_map.map(b, &self.heading_frame(pose, b)).pos;
        // Feet: their height above the floor is the human's above theirs, scaled.
        if let Some((_, foot)) = self.feet.iter().find(|(f, _)| *f == b) {
            pos[2] = self.target[b].pos[2] + self.position_map.scale * (body.pos[2] - foot.floor);
        }
        Frame {
            pos,
            rot: self.orientation_map.map(b, &body).rot,
        }
    }

    /// Retargets one human pose, `dt` seconds after the previous one; returns which feet the
    /// human had planted. The robot's pose is then [`Self::root`] and [`Self::joints`].
    pub fn step(&mut self, pose: &HumanPose, dt: f64) -> [bool; 2] {
        self.goals.clear();
        self.human.clear();
        for (b, p) in self.pairs.iter().enumerate() {
            let frame = self.goal_frame(pose, b);
            self.human.push(frame.pos);
            self.goals.push(IkGoal {
                frame,
                position_weight: p.position_weight,
                orientation_weight: p.orientation_weight,
            });
        }
        // Planted feet: a human foot on its floor and still holds the robot's where it stood.
        let mut planted = [false; 2];
        for (slot, k) in (0..self.feet.len()).enumerate() {
            let b = self.feet[k].0;
            let human = self.body_frame(pose, b).pos;
            let goal = &mut self.goals[b];
            let foot = &mut self.feet[k].1;
            let speed = foot.last.map_or(f64::INFINITY, |l| {
                ((human[0] - l[0]).powi(2) + (human[1] - l[1]).powi(2)).sqrt() / dt.max(1e-6)
            });
            foot.last = Some(human);
            let above = human[2] - foot.floor;
            let on = match foot.planted {
                Some(_) => above <= LIFT_HEIGHT && speed <= LIFT_SPEED,
                None => above <= PLANT_HEIGHT && speed <= PLANT_SPEED,
            };
            match (on, foot.planted) {
                // Where the robot's foot is (it may trail the human's): planted there, it does
                // not slide to catch up.
                (true, None) if self.started => {
                    let at = self.ik.frame(b).pos;
                    foot.planted = Some([at[0], at[1]]);
                }
                (true, None) => {
                    foot.planted = Some([goal.frame.pos[0], goal.frame.pos[1]]);
                }
                (false, Some(_)) => foot.planted = None,
                _ => {}
            }
            if let Some(at) = &mut foot.planted {
                // A human foot that creeps while planted (a pivot, mocap drift) drags the robot's
                // along once the two are PLANT_DRIFT (scaled) apart: held, not left behind.
                let mut offset = [at[0] - goal.frame.pos[0], at[1] - goal.frame.pos[1]];
                let (apart, most) = (offset[0].hypot(offset[1]), PLANT_DRIFT * self.position_map.scale);
                if apart > most {
                    offset = offset.map(|o| o * most / apart);
                    *at = [goal.frame.pos[0] + offset[0], goal.frame.pos[1] + offset[1]];
                }
                foot.offset = offset;
                goal.position_weight *= PLANTED_WEIGHT;
            } else {
                let keep = (1.0 - dt / CATCH_UP_S).max(0.0);
                foot.offset = foot.offset.map(|o| o * keep);
            }
            goal.frame.pos[0] += foot.offset[0];
            goal.frame.pos[1] += foot.offset[1];
            if slot < 2 {
                planted[slot] = foot.planted.is_some();
            }
        }
        let iterations = if self.started {
            self.iterations
        } else {
            20 * self.iterations
        };
        // GMR's two stages where the map names a posture stage: the posture first (orientations,
        // the feet), then every pair's own weights refine it.
        if self.two_stages {
            self.posture.clear();
            for (g, p) in self.goals.iter().zip(&self.pairs) {
                let w = p.posture.unwrap_or(robots::StageWeights {
                    position_weight: 0.0,
                    orientation_weight: 0.0,
                });
                self.posture.push(IkGoal {
                    position_weight: w.position_weight,
                    orientation_weight: w.orientation_weight,
                    ..*g
                });
            }
            self.ik.solve(&self.posture, iterations);
        }
        self.ik.solve(&self.goals, iterations);
        // Within the motors' speed: no joint moves further per frame than 90 % of its limit.
        if self.started {
            let mut q = std::mem::take(&mut self.q);
            let before = q.clone();
            self.ik.joints(&mut q);
            for ((v, p), limit) in q.iter_mut().zip(&before).zip(&self.velocity_limits) {
                let s = 0.9 * limit * dt;
                *v = v.clamp(p - s, p + s);
            }
            let root = self.ik.root();
            self.ik.set_pose(root, &q);
            self.q = q;
        }
        // Feet out of the floor: lift the whole robot by what its lowest sole sinks in.
        let sink = self.ik.lowest_point();
        if sink < 0.0 {
            self.ik.lift(-sink);
        }
        // Against the scaled human, not the planted goal.
        for (b, h) in self.human.iter().enumerate() {
            let e = spatial::norm(spatial::sub(self.ik.frame(b).pos, *h));
            let acc = &mut self.errors[b];
            *acc = (acc.0 + e * e, acc.1 + e, acc.2.max(e), acc.3 + 1);
        }
        self.ik.joints(&mut self.q);
        self.started = true;
        planted
    }

    /// The robot's root pose `[x, y, z, w, qx, qy, qz]` after the last step.
    pub fn root(&self) -> [f64; 7] {
        self.ik.root()
    }

    /// The robot's joints (policy order) after the last step.
    pub fn joints(&self) -> &[f64] {
        &self.q
    }

    /// Per position pair since the start: robot frame, human body, and the robot frame's mean,
    /// RMS and worst distance from the scaled human's, m.
    pub fn key_body_errors(&self) -> Vec<KeyBodyError> {
        self.pairs
            .iter()
            .zip(&self.errors)
            .filter(|(p, _)| p.position_weight > 0.0)
            .map(|(p, &(sq, sum, worst, n))| KeyBodyError {
                frame: p.frame.clone(),
                human: p.human,
                mean: sum / n.max(1) as f64,
                rms: (sq / n.max(1) as f64).sqrt(),
                worst,
            })
            .collect()
    }

    /// Where the scaled human put each position pair's body at the last step, in the frame of
    /// the robot's root then (the pairs of [`key_bodies`], in order).
    pub fn operator_in_root(&self, out: &mut Vec<[f64; 3]>) {
        out.clear();
        let root = self.ik.root();
        let back = spatial::quat_conj([root[3], root[4], root[5], root[6]]);
        for (p, h) in self.pairs.iter().zip(&self.human) {
            if p.position_weight > 0.0 {
                let rel = spatial::sub(*h, [root[0], root[1], root[2]]);
                out.push(spatial::quat_rotate(back, rel));
            }
        }
    }

    /// The solver on the robot's model (for measuring a pose).
    pub fn ik_mut(&mut self) -> &mut Ik {
        &mut self.ik
    }
}

/// The robot frames of the retargeting map's position pairs: the key bodies placed on the human.
pub fn key_bodies(robot: &Robot) -> Vec<String> {
    robot
        .config
        .retarget
        .as_ref()
        .map(|c| {
            c.pairs
                .iter()
                .filter(|p| p.position_weight > 0.0)
                .map(|p| p.frame.clone())
                .collect()
        })
        .unwrap_or_default()
}

/// How far one paired robot frame stayed from the scaled human body, m.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct KeyBodyError {
    /// The robot frame.
    pub frame: String,
    /// The human body it follows.
    pub human: HumanBody,
    /// Mean distance, m.
    pub mean: f64,
    /// Root mean square, m.
    pub rms: f64,
    /// Largest, m.
    pub worst: f64,
}

/// Spread of a per-frame figure: median, 90th and 99th percentile, largest.
#[derive(Debug, Clone, Copy, PartialEq, Default, serde::Serialize)]
pub struct Spread {
    /// Median.
    pub median: f64,
    /// 90th percentile.
    pub p90: f64,
    /// 99th percentile.
    pub p99: f64,
    /// Largest.
    pub max: f64,
    /// Samples.
    pub samples: usize,
}

impl Spread {
    /// Of `values` (sorted here).
    pub fn of(values: &mut [f64]) -> Self {
        if values.is_empty() {
            return Self::default();
        }
        values.sort_by(f64::total_cmp);
        let at = |p: f64| values[((values.len() - 1) as f64 * p).round() as usize];
        Self {
            median: at(0.5),
            p90: at(0.9),
            p99: at(0.99),
            max: values[values.len() - 1],
            samples: values.len(),
        }
    }
}

/// How well a retargeted motion follows its human, measured on the result (GMR's and
/// holosoma-retargeting's kinds of figures).
#[derive(Debug, Clone, PartialEq, Default, serde::Serialize)]
pub struct RetargetReport {
    /// Frames.
    pub frames: usize,
    /// Frame rate, Hz.
    pub rate_hz: f64,
    /// The map's global scale.
    pub scale: f64,
    /// Per position pair, before smoothing.
    pub key_bodies: Vec<KeyBodyError>,
    /// The robot's feet's horizontal speed while the human's foot stands planted, m/s.
    pub foot_sliding: Spread,
    /// Share of foot-frames planted.
    pub planted_share: f64,
    /// Deepest any colliding geom reaches into the floor, m (0: none).
    pub deepest_penetration: f64,
    /// Retargeting time per frame after the first, s.
    pub frame_time: Spread,
}

impl std::fmt::Display for RetargetReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(
            f,
            "  feet planted in {:.0} % of foot-frames; sliding while planted: median {:.2} cm/s, p90 {:.2}, max {:.1} cm/s",
            100.0 * self.planted_share,
            100.0 * self.foot_sliding.median,
            100.0 * self.foot_sliding.p90,
            100.0 * self.foot_sliding.max
        )?;
        writeln!(
            f,
            "  soles into the floor: {:.2} cm at most",
            100.0 * self.deepest_penetration
        )?;
        for k in &self.key_bodies {
            writeln!(
                f,
                "  {} ({:?}) from the scaled human: {:.1} cm RMS, {:.1} cm worst",
                k.frame,
                k.human,
                100.0 * k.rms,
                100.0 * k.worst
            )?;
        }
        writeln!(
            f,
            "  time per frame: median {:.3} ms, p99 {:.3} ms, max {:.3} ms",
            1e3 * self.frame_time.median,
            1e3 * self.frame_time.p99,
            1e3 * self.frame_time.max
        )
    }
}

/// Retargets `bvh` onto `robot`, the map calibrated on the clip's own nominal frame.
pub fn retarget(robot: &Robot, bvh: &Bvh, options: &RetargetOptions) -> Result<Retargeted, HumanError> {
    retarget_calibrated(robot, bvh, bvh, options)
}

/// Retargets `bvh` onto `robot`, the map calibrated on the nominal frame of `calibration` (a
/// recording of the same skeleton: a T-pose or standing take of the same performer, for clips
/// that start moving — a walk that starts mid-stride has no frame that matches the robot's pose).
pub fn retarget_calibrated(
    robot: &Robot,
    bvh: &Bvh,
    calibration: &Bvh,
    options: &RetargetOptions,
) -> Result<Retargeted, HumanError> {
    let config = robot.config.retarget.as_ref().ok_or_else(|| {
        HumanError::map(format!(
            "{}: no [retarget] section: which robot body stands for which human one?",
            robot.path.display()
        ))
    })?;
    if options.nominal_frame >= calibration.frames() || options.start_frame + 1 >= bvh.frames() {
        return Err(HumanError::map(format!(
            "nominal frame {} (of {} frames) and start frame {} (of {} frames) are not frames of the recordings",
            options.nominal_frame,
            calibration.frames(),
            options.start_frame,
            bvh.frames()
        )));
    }
    if calibration.dialect != bvh.dialect || calibration.joints.len() != bvh.joints.len() {
        return Err(HumanError::map(format!(
            "the calibrating recording's skeleton ({:?}, {} joints) is not the clip's ({:?}, {} joints)",
            calibration.dialect,
            calibration.joints.len(),
            bvh.dialect,
            bvh.joints.len()
        )));
    }
    if !(options.rate_hz.is_finite() && options.rate_hz > 0.0) {
        return Err(HumanError::map(format!(
            "rate {} Hz is not a rate",
            options.rate_hz
        )));
    }
    let mut needed: Vec<HumanBody> = config.pairs.iter().map(|p| p.human).collect();
    if hips(bvh.dialect).iter().any(|n| bvh.joint(n).is_none()) {
        return Err(HumanError::map(
            "the recording has no thigh joints to tell its heading",
        ));
    }
    needed.extend([HumanBody::LeftHip, HumanBody::RightHip]);
    let bodies = BvhBodies::new(bvh, &needed)?;
    let duration = (bvh.frames() - 1 - options.start_frame) as f64 * bvh.frame_time;
    let ticks = (duration * options.rate_hz).floor() as usize + 1;
    let (nominal, mut poses) = match options.wearing {
        crate::sparse::Wearing::WholeBody => {
            let poses: Vec<HumanPose> = (0..ticks)
                .map(|k| bodies.pose(&bvh.pose_at(options.start_frame, k as f64 / options.rate_hz)))
                .collect();
            (bodies.pose(&calibration.pose(options.nominal_frame)), poses)
        }
        worn => sparse_poses(bvh, calibration, options, worn.devices(), ticks)?,
    };
    let mut retargeter = Retargeter::new(
        robot,
        &nominal,
        RetargeterOptions {
            nominal: options.nominal,
            iterations: options.iterations,
        },
    )?;
    if options.wearing != crate::sparse::Wearing::WholeBody {
        retargeter.positions_only(&crate::sparse::GUESSED_ORIENTATIONS);
    }
    if !std::ptr::eq(calibration, bvh) {
        retargeter.align_to(&poses[0]);
    }
    smooth_poses(&mut poses, options.smoothing_s * options.rate_hz);
    // Feet: their floor is the foot's lowest 5 % over the clip, not the nominal frame's, which
    // may be mid-stride.
    let floors: Vec<f64> = retargeter
        .feet
        .iter()
        .map(|&(b, _)| {
            let mut z: Vec<f64> = poses.iter().map(|p| retargeter.body_frame(p, b).pos[2]).collect();
            z.sort_by(f64::total_cmp);
            z[z.len() / 20]
        })
        .collect();
    retargeter.set_feet_floor(&floors);

    let dt = 1.0 / options.rate_hz;
    let mut out = Retargeted {
        times: Vec::with_capacity(ticks),
        root: Vec::with_capacity(ticks),
        q: Vec::with_capacity(ticks),
        scale: retargeter.scale(),
        worst_position_error: 0.0,
        mean_position_error: 0.0,
        pair_errors: Vec::new(),
        planted: Vec::with_capacity(ticks),
        report: RetargetReport::default(),
    };
    let mut times = Vec::with_capacity(ticks);
    for (k, pose) in poses.iter().enumerate() {
        let started = std::time::Instant::now();
        let planted = retargeter.step(pose, dt);
        times.push(started.elapsed().as_secs_f64());
        out.times.push(k as f64 * dt);
        out.root.push(retargeter.root());
        out.q.push(retargeter.joints().to_vec());
        out.planted.push(planted);
    }
    let key_bodies = retargeter.key_body_errors();
    out.pair_errors = key_bodies
        .iter()
        .map(|k| (k.frame.clone(), k.mean, k.worst))
        .collect();
    out.worst_position_error = key_bodies.iter().map(|k| k.worst).fold(0.0, f64::max);
    out.mean_position_error = key_bodies.iter().map(|k| k.mean).sum::<f64>() / key_bodies.len().max(1) as f64;
    let feet = retargeter.feet();
    smooth_keeping_planted_feet(robot, &mut out, &feet, options.smoothing_s * options.rate_hz)?;
    // Smoothing may lower a sole a little: lift those frames back out of the floor.
    let ik = retargeter.ik_mut();
    for (root, q) in out.root.iter_mut().zip(&out.q) {
        ik.set_pose(*root, q);
        let sink = ik.lowest_point();
        if sink < 0.0 {
            root[2] -= sink;
        }
    }
    out.report = measure(&mut retargeter, &out, key_bodies, &mut times);
    Ok(out)
}

/// The bodies a five-point operator's estimate gives for `bvh`: the first `worn` of a
/// headset, two controllers and two foot trackers where a VR rig would put them on the performer
/// ([`crate::vr_send::Rig`], measured on the calibrating recording's nominal frame, a T-pose), the
/// rest of the body from them ([`crate::sparse::SparseBody`], calibrated there). Returns the
/// nominal pose and one per tick.
fn sparse_poses(
    bvh: &Bvh,
    calibration: &Bvh,
    options: &RetargetOptions,
    worn: usize,
    ticks: usize,
) -> Result<(HumanPose, Vec<HumanPose>), HumanError> {
    let rig = crate::vr_send::Rig::new(calibration)?;
    let wear = |devices: [Frame; 5]| {
        let mut k = 0;
        devices.map(|d| {
            k += 1;
            (k <= worn).then_some(d)
        })
    };
    let tpose = wear(rig.devices(calibration, options.nominal_frame));
    let [Some(hmd), Some(left), Some(right), ..] = &tpose else {
        unreachable!("every device is placed")
    };
    let user = crate::body_map::UserCalibration::from_tpose(
        hmd,
        left,
        right,
        &crate::body_map::Template::default(),
    )?;
    let dt = 1.0 / options.rate_hz;
    let missing = || HumanError::map("no headset to estimate the body from");
    let mut body = crate::sparse::SparseBody::new(user, &tpose).ok_or_else(missing)?;
    let nominal = body.clone().pose(&tpose, dt).ok_or_else(missing)?;
    let poses = (0..ticks)
        .map(|k| {
            let devices = wear(rig.devices_in(&bvh.pose_at(options.start_frame, k as f64 * dt)));
            body.pose(&devices, dt).ok_or_else(missing)
        })
        .collect::<Result<Vec<_>, _>>()?;
    Ok((nominal, poses))
}

/// The report of a retargeted motion, measured on its frames.
fn measure(
    retargeter: &mut Retargeter,
    motion: &Retargeted,
    key_bodies: Vec<KeyBodyError>,
    times: &mut [f64],
) -> RetargetReport {
    let dt = motion.times.get(1).map_or(1.0, |t| t - motion.times[0]);
    let feet: Vec<usize> = retargeter.feet.iter().map(|(b, _)| *b).take(2).collect();
    let mut slides = Vec::new();
    let mut deepest: f64 = 0.0;
    let mut previous: Option<Vec<[f64; 3]>> = None;
    let (mut planted, mut foot_frames) = (0usize, 0usize);
    for (k, (root, q)) in motion.root.iter().zip(&motion.q).enumerate() {
        let ik = retargeter.ik_mut();
        ik.set_pose(*root, q);
        deepest = deepest.max(-ik.lowest_point());
        let now: Vec<[f64; 3]> = feet.iter().map(|&b| ik.frame(b).pos).collect();
        for (f, p) in now.iter().enumerate() {
            foot_frames += 1;
            let on = motion.planted[k][f] && k > 0 && motion.planted[k - 1][f];
            if motion.planted[k][f] {
                planted += 1;
            }
            if let (true, Some(prev)) = (on, &previous) {
                slides.push(((p[0] - prev[f][0]).powi(2) + (p[1] - prev[f][1]).powi(2)).sqrt() / dt);
            }
        }
        previous = Some(now);
    }
    RetargetReport {
        frames: motion.times.len(),
        rate_hz: 1.0 / dt,
        scale: motion.scale,
        key_bodies,
        foot_sliding: Spread::of(&mut slides),
        planted_share: planted as f64 / foot_frames.max(1) as f64,
        deepest_penetration: deepest,
        // The first frame solves from the nominal pose with many more iterations.
        frame_time: Spread::of(times.get_mut(1..).unwrap_or_default()),
    }
}

/// Gaussian smoothing (σ in frames) of the human's bodies, zero phase: positions averaged,
/// orientations averaged as quaternions (on one hemisphere) and renormalised. Smoothing the
/// human, not the robot's result, keeps what the solver kept: a planted foot stays planted, the
/// joints within their limits and speeds.
fn smooth_poses(poses: &mut [HumanPose], sigma: f64) {
    if sigma <= 0.0 || poses.len() < 3 {
        return;
    }
    let half = (3.0 * sigma).ceil() as isize;
    let weights: Vec<f64> = (-half..=half)
        .map(|k| (-0.5 * (k as f64 / sigma).powi(2)).exp())
        .collect();
    let n = poses.len() as isize;
    let source = poses.to_vec();
    for i in 0..n {
        for b in 0..HUMAN_BODIES {
            let Some(centre) = source[i as usize].bodies[b] else {
                continue;
            };
            let reference = spatial::quat_of_mat(&centre.rot);
            let (mut pos, mut quat, mut total) = ([0.0; 3], [0.0; 4], 0.0);
            for (w, k) in weights.iter().zip(-half..=half) {
                let Some(f) = source[(i + k).clamp(0, n - 1) as usize].bodies[b] else {
                    continue;
                };
                total += w;
                pos = spatial::add(pos, spatial::scale(f.pos, *w));
                let q = spatial::quat_of_mat(&f.rot);
                let sign = if (0..4).map(|c| q[c] * reference[c]).sum::<f64>() < 0.0 {
                    -w
                } else {
                    *w
                };
                for c in 0..4 {
                    quat[c] += sign * q[c];
                }
            }
            poses[i as usize].bodies[b] = Some(Frame {
                pos: spatial::scale(pos, 1.0 / total),
                rot: spatial::mat_of_quat(spatial::quat_normalize(quat)),
            });
        }
    }
}

/// Smooths the result ([`smooth`]) and puts each planted foot back where the solver held it:
/// the legs of planted feet re-solved, root and every other joint as smoothed. Averaging a stance
/// with the swings around it would otherwise drag the planted foot along.
fn smooth_keeping_planted_feet(
    robot: &Robot,
    m: &mut Retargeted,
    feet: &[String],
    sigma: f64,
) -> Result<(), HumanError> {
    if sigma <= 0.0 || m.q.len() < 3 || feet.is_empty() {
        return Ok(());
    }
    let ik = Ik::new(robot, feet, false, &[])?;
    let legs: Vec<usize> = (0..feet.len()).flat_map(|f| ik.joints_moving_frame(f)).collect();
    let others: Vec<usize> = (0..m.q[0].len()).filter(|j| !legs.contains(j)).collect();
    let mut ik = Ik::new(robot, feet, false, &others)?;
    let held: Vec<Vec<Frame>> = m
        .root
        .iter()
        .zip(&m.q)
        .map(|(root, q)| {
            ik.set_pose(*root, q);
            (0..feet.len()).map(|f| ik.frame(f)).collect()
        })
        .collect();
    smooth(m, sigma);
    let mut goals = Vec::with_capacity(feet.len());
    ik.anchor_weight = REPLANT_ANCHOR_WEIGHT;
    for (((planted, held), root), q) in m.planted.iter().zip(&held).zip(&m.root).zip(&mut m.q) {
        if !planted.iter().any(|p| *p) {
            continue;
        }
        goals.clear();
        goals.extend(held.iter().enumerate().map(|(f, frame)| {
            let on = planted.get(f).copied().unwrap_or(false);
            IkGoal {
                frame: *frame,
                position_weight: if on { 10.0 } else { 0.0 },
                orientation_weight: if on { 2.0 } else { 0.0 },
            }
        }));
        ik.set_pose(*root, q);
        // Near the smoothed pose: a straight knee does not flip to reach a millimetre further.
        ik.set_anchor(q);
        ik.solve(&goals, 8);
        ik.joints(q);
    }
    Ok(())
}

/// Gaussian smoothing (σ in frames) of joints and root position, zero phase; root orientations are
/// averaged as quaternions and renormalised. Averages of in-limit angles stay in their limits and
/// no speed grows, so the limits the solver kept still hold.
fn smooth(m: &mut Retargeted, sigma: f64) {
    if sigma <= 0.0 || m.q.len() < 3 {
        return;
    }
    let half = (3.0 * sigma).ceil() as isize;
    let weights: Vec<f64> = (-half..=half)
        .map(|k| (-0.5 * (k as f64 / sigma).powi(2)).exp())
        .collect();
    let n = m.q.len() as isize;
    let at = |k: isize| k.clamp(0, n - 1) as usize;
    let (q, root) = (m.q.clone(), m.root.clone());
    for i in 0..n {
        let mut total = 0.0;
        let mut acc_q = vec![0.0; q[0].len()];
        let mut acc_r = [0.0; 7];
        let reference = root[i as usize];
        for (w, k) in weights.iter().zip(-half..=half) {
            let j = at(i + k);
            total += w;
            for (a, v) in acc_q.iter_mut().zip(&q[j]) {
                *a += w * v;
            }
            // Quaternions on the same hemisphere as this frame's before averaging.
            let r = root[j];
            let sign = if (3..7).map(|c| r[c] * reference[c]).sum::<f64>() < 0.0 {
                -1.0
            } else {
                1.0
            };
            for c in 0..7 {
                acc_r[c] += w * if c >= 3 { sign * r[c] } else { r[c] };
            }
        }
        let norm = (3..7).map(|c| acc_r[c] * acc_r[c]).sum::<f64>().sqrt();
        for (c, v) in acc_r.iter_mut().enumerate() {
            *v /= if c >= 3 { norm } else { total };
        }
        m.q[i as usize] = acc_q.iter().map(|a| a / total).collect();
        m.root[i as usize] = acc_r;
    }
}

impl Retargeted {
    /// The clip as CSV (the controller's clip format), with `header` lines as comments.
    pub fn to_csv(&self, robot: &Robot, header: &[String]) -> String {
        let mut s = String::new();
        for h in header {
            let _ = writeln!(s, "# {h}");
        }
        s.push_str("time,root_x,root_y,root_z,root_qw,root_qx,root_qy,root_qz");
        for j in &robot.config.joints {
            let _ = write!(s, ",{}", j.name);
        }
        s.push('\n');
        for ((t, r), q) in self.times.iter().zip(&self.root).zip(&self.q) {
            let _ = write!(s, "{t:.4}");
            for v in r {
                let _ = write!(s, ",{v:.6}");
            }
            for v in q {
                let _ = write!(s, ",{v:.6}");
            }
            s.push('\n');
        }
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// rd-biped's paired frames in its T-pose, standing, as a human twice its size would stand
    /// in them (soles on the floor).
    fn giant(robot: &Robot) -> HumanPose {
        let config = robot.config.retarget.as_ref().unwrap();
        let frames: Vec<String> = config.pairs.iter().map(|p| p.frame.clone()).collect();
        let mut ik = Ik::new(robot, &frames, true, &[]).unwrap();
        let q: Vec<f64> = robot
            .config
            .joints
            .iter()
            .map(|j| config.tpose.get(&j.name).copied().unwrap_or(0.0))
            .collect();
        ik.standing_root(&q);
        let mut pose = HumanPose::default();
        for (k, p) in config.pairs.iter().enumerate() {
            let f = ik.frame(k);
            pose.set(
                p.human,
                Frame {
                    pos: spatial::scale(f.pos, 2.0),
                    rot: f.rot,
                },
            );
        }
        pose
    }

    /// `pose` with the body above the legs moved `by` metres to the left, the feet where they are.
    fn swayed(pose: &HumanPose, by: f64) -> HumanPose {
        let mut out = *pose;
        for b in [
            HumanBody::Root,
            HumanBody::Head,
            HumanBody::LeftHand,
            HumanBody::RightHand,
        ] {
            if let Some(f) = out.bodies[b as usize].as_mut() {
                f.pos[1] += by;
            }
        }
        out
    }

    fn foot_xy(r: &mut Retargeter, foot: usize) -> [f64; 2] {
        let b = r.feet[foot].0;
        let p = r.ik_mut().frame(b).pos;
        [p[0], p[1]]
    }

    #[test]
    fn a_planted_foot_stays_while_the_body_sways_and_a_step_moves_it() {
        let robot = Robot::load(&robots::reference_robot_path()).unwrap();
        let nominal = giant(&robot);
        let mut r = Retargeter::new(
            &robot,
            &nominal,
            RetargeterOptions {
                nominal: Nominal::Tpose,
                iterations: 12,
            },
        )
        .unwrap();
        assert!((r.scale() - 0.5).abs() < 1e-9, "{}", r.scale());
        let dt = 0.02;
        r.step(&nominal, dt);
        let start = [foot_xy(&mut r, 0), foot_xy(&mut r, 1)];
        let root0 = r.root();
        // The human sways 6 cm sideways over a second, feet still: both planted, the robot's
        // feet do not move while its pelvis follows (3 cm on its scale).
        for k in 1..=50 {
            let pose = swayed(&nominal, 0.06 * f64::from(k) / 50.0);
            assert_eq!(r.step(&pose, dt), [true, true], "tick {k}");
        }
        for (f, was) in start.iter().enumerate() {
            let now = foot_xy(&mut r, f);
            let moved = (now[0] - was[0]).hypot(now[1] - was[1]);
            assert!(moved < 1e-3, "foot {f} slid {moved} m");
        }
        let sway = r.root()[1] - root0[1];
        assert!((sway - 0.03).abs() < 0.01, "pelvis swayed {sway} m");
        // The left foot steps 20 cm forward (lifted 10 cm on the way): unplanted while it moves,
        // planted where it lands, the robot's foot 10 cm on (within PLANT_DRIFT of it).
        let mut pose = swayed(&nominal, 0.06);
        let planted_foot = nominal.get(HumanBody::LeftFoot).unwrap().pos;
        let mut lifted = false;
        for k in 1..=25 {
            let s = f64::from(k) / 25.0;
            let foot = pose.bodies[HumanBody::LeftFoot as usize].as_mut().unwrap();
            foot.pos[0] = planted_foot[0] + 0.2 * s;
            foot.pos[2] = planted_foot[2] + 0.1 * (std::f64::consts::PI * s).sin();
            lifted |= !r.step(&pose, dt)[0];
        }
        assert!(lifted, "the stepping foot was let go");
        for _ in 0..25 {
            r.step(&pose, dt);
        }
        assert_eq!(r.step(&pose, dt), [true, true]);
        let stepped = foot_xy(&mut r, 0)[0] - start[0][0];
        assert!((stepped - 0.1).abs() < PLANT_DRIFT * 0.5, "stepped {stepped} m");
        let right = foot_xy(&mut r, 1);
        assert!(
            (right[0] - start[1][0]).hypot(right[1] - start[1][1]) < 1e-3,
            "the other foot stayed"
        );
    }
}
