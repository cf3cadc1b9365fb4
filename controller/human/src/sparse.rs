//! The whole body from what a VR operator wears: a headset, two controllers and a tracker on each
//! foot (five points). A general tracker needs every key body; these are estimated from the five.
//! Proportions come from the T-pose's stature (anthropometric averages):
//!
//! - each ankle is where its tracker puts it (the tracker's place on the foot measured in the
//!   T-pose: the ankles on the floor under the hips), the body's heading between the feet's;
//! - the pelvis stands under the head joint, the trunk leaning as far as the head's reach beyond
//!   the feet and its drop allow (a bow keeps the pelvis over the feet), as low as the head is
//!   below its T-pose height (a crouch bends the knees), never higher than the legs reach;
//! - arms and legs by two-bone inverse kinematics: knees bend forward, elbows down, out and away
//!   from where the hand points; an arm's roll about its own axis is not seen, so a retargeter
//!   follows the arms' positions only ([`GUESSED_ORIENTATIONS`]).
//!
//! Three points (no foot trackers) are not offered: with the legs from a stepping rule, the
//! estimate was 22–26 cm RMS from a performer's true pelvis and feet and TWIST2 fell on both
//! CMU takes; with the feet tracked it tracks them to the end.
//!
//! Everything is a frame in the operator's world (x forward, y left, z up, the floor at z = 0),
//! as [`HumanPose`] takes it; nothing is allocated per frame.

use robots::HumanBody;
use robots::spatial::{self, Mat3};

use crate::body_map::{Frame, HumanPose, UserCalibration, joint_from_device};

/// Segment proportions of a standing adult, fractions of stature (Drillis and Contini's averages,
/// as Winter's *Biomechanics* tabulates them).
mod proportion {
    /// Hip joints' height (the greater trochanter).
    pub const HIP_HEIGHT: f64 = 0.530;
    /// Half the distance between the hip joints.
    pub const HIP_HALF_WIDTH: f64 = 0.055;
    /// Shoulder joints' height.
    pub const SHOULDER_HEIGHT: f64 = 0.818;
    /// Half the distance between the shoulder joints.
    pub const SHOULDER_HALF_WIDTH: f64 = 0.110;
    /// Upper chest's height.
    pub const CHEST_HEIGHT: f64 = 0.720;
    /// Upper arm, forearm.
    pub const UPPER_ARM: f64 = 0.186;
    pub const FOREARM: f64 = 0.146;
    /// Thigh, shank.
    pub const THIGH: f64 = 0.245;
    pub const SHANK: f64 = 0.246;
    /// Ankle joints' height.
    pub const ANKLE_HEIGHT: f64 = 0.039;
}

/// What the operator wears: where the body a retargeter takes comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Wearing {
    /// The whole skeleton (VMC bones and root: a motion-capture suit, full-body tracking; a BVH).
    #[default]
    WholeBody,
    /// A headset, two controllers and a tracker on each foot: the rest estimated ([`SparseBody`]).
    FivePoint,
}

impl Wearing {
    /// How many devices the operator wears ([`Devices`]' first ones); none for a skeleton.
    pub fn devices(self) -> usize {
        match self {
            Self::WholeBody => 0,
            Self::FivePoint => 5,
        }
    }
}

/// The pelvis follows where the head puts it with this time constant, s: a head bobs and nods
/// where hips do not.
pub const PELVIS_SMOOTHING_S: f64 = 0.15;

/// Bodies whose orientation the estimate guesses (an arm's roll about its own axis is not seen):
/// a retargeter follows their positions only ([`crate::retarget::Retargeter::positions_only`]).
pub const GUESSED_ORIENTATIONS: [HumanBody; 4] = [
    HumanBody::LeftShoulder,
    HumanBody::RightShoulder,
    HumanBody::LeftElbow,
    HumanBody::RightElbow,
];

/// How much the hand's roll sets the elbow's hinge axis where the arm is nearly straight (the
/// bend's own axis is as long as the sine of the elbow's angle).
pub const HINGE_FROM_HAND: f64 = 0.2;

/// A foot on the floor plane: its ankle's place and its yaw.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Foot {
    at: [f64; 2],
    yaw: f64,
}

/// A foot tracker's place on its foot, measured in the T-pose.
#[derive(Debug, Clone, Copy, PartialEq)]
struct FootTracker {
    /// The ankle joint in the tracker's frame.
    ankle: [f64; 3],
    /// The foot's heading less the tracker's, rad.
    yaw: f64,
}

/// The whole body from five points, frame by frame.
#[derive(Debug, Clone)]
pub struct SparseBody {
    user: UserCalibration,
    /// Where the foot trackers sit on the feet.
    trackers: [FootTracker; 2],
    /// The feet where their trackers last put them, and their ankles' heights, m.
    feet: [Foot; 2],
    ankle_z: [f64; 2],
    /// The head joint's height in the T-pose, m.
    head_height: f64,
    heading: f64,
    /// The pelvis's floor position last frame.
    pelvis: Option<[f64; 2]>,
}

/// Where the devices are: headset, left and right controller, left and right foot tracker (world
/// frames; [`crate::vmc::Device`]'s order).
pub type Devices = [Option<Frame>; 5];

impl SparseBody {
    /// Starts from the T-pose the calibration was taken in (`devices` then); `None` unless the
    /// headset and both foot trackers are there.
    pub fn new(user: UserCalibration, devices: &Devices) -> Option<Self> {
        let hmd = devices[0]?;
        let head = joint_from_device(&hmd, user.head);
        let heading = spatial::heading(&hmd.rot);
        let ankle_z = user.stature * proportion::ANKLE_HEIGHT;
        // In the T-pose the ankles stand on the floor under the hips, which are under the head
        // joint: a foot tracker's ankle is that far ahead, as far to the side as the tracker.
        let forward = [heading.cos(), heading.sin()];
        let tracker = |t: Frame| {
            let ahead = (t.pos[0] - head[0]) * forward[0] + (t.pos[1] - head[1]) * forward[1];
            let ankle = [
                t.pos[0] - ahead * forward[0],
                t.pos[1] - ahead * forward[1],
                ankle_z,
            ];
            FootTracker {
                ankle: spatial::mat_apply(&spatial::transpose(&t.rot), spatial::sub(ankle, t.pos)),
                yaw: wrap(heading - spatial::heading(&t.rot)),
            }
        };
        let mut body = Self {
            user,
            trackers: [tracker(devices[3]?), tracker(devices[4]?)],
            feet: [Foot {
                at: [head[0], head[1]],
                yaw: heading,
            }; 2],
            ankle_z: [ankle_z; 2],
            head_height: head[2],
            heading,
            pelvis: None,
        };
        body.track_feet(devices);
        Some(body)
    }

    /// The feet where their trackers put them; a foot whose tracker is not seen stays where it
    /// was. Returns whether both were seen.
    fn track_feet(&mut self, devices: &Devices) -> bool {
        let mut both = true;
        for side in 0..2 {
            let Some(t) = devices[3 + side] else {
                both = false;
                continue;
            };
            let ankle = joint_from_device(&t, self.trackers[side].ankle);
            self.feet[side] = Foot {
                at: [ankle[0], ankle[1]],
                yaw: wrap(spatial::heading(&t.rot) + self.trackers[side].yaw),
            };
            self.ankle_z[side] = ankle[2];
        }
        both
    }

    /// The body for this frame, `dt` s after the last; `None` without a headset.
    pub fn pose(&mut self, devices: &Devices, dt: f64) -> Option<HumanPose> {
        let hmd = devices[0]?;
        let h = self.user.stature;
        let head = joint_from_device(&hmd, self.user.head);
        if self.track_feet(devices) {
            // The pelvis faces between its feet.
            let [l, r] = self.feet.map(|f| f.yaw);
            self.heading = wrap(l + wrap(r - l) / 2.0);
        }
        let turn = spatial::yaw(self.heading);
        let local = |v: [f64; 3]| spatial::mat_apply(&turn, v);
        let (under, pelvis_z) = self.pelvis_under(head);
        let pelvis_floor = match self.pelvis {
            Some(last) => {
                let a = (dt / PELVIS_SMOOTHING_S).min(1.0);
                [0, 1].map(|k| last[k] + a * (under[k] - last[k]))
            }
            None => under,
        };
        self.pelvis = Some(pelvis_floor);
        // The legs reach the pelvis from the feet (a head raised on tiptoe does not lift it off).
        let leg = h * (proportion::THIGH + proportion::SHANK);
        let hip = |side: usize, z: f64| {
            let sign = if side == 0 { 1.0 } else { -1.0 };
            spatial::add(
                [pelvis_floor[0], pelvis_floor[1], z],
                local([0.0, sign * h * proportion::HIP_HALF_WIDTH, 0.0]),
            )
        };
        let pelvis_z = (0..2).fold(pelvis_z, |z, side| {
            let (hip, foot) = (hip(side, 0.0), self.feet[side].at);
            let across = (hip[0] - foot[0]).powi(2) + (hip[1] - foot[1]).powi(2);
            z.min(self.ankle_z[side] + (leg * leg - across).max(0.0).sqrt())
        });

        let mut pose = HumanPose::default();
        let at = |p: [f64; 3], rot: Mat3| Frame { pos: p, rot };
        let pelvis = [pelvis_floor[0], pelvis_floor[1], pelvis_z];
        pose.set(HumanBody::Root, at(pelvis, turn));
        // The trunk leans from the pelvis to the head joint.
        let up = spatial::unit(spatial::sub(head, pelvis));
        let trunk = frame_from_z_x(up, local([1.0, 0.0, 0.0]));
        let along = |height: f64| {
            let s = (height - proportion::HIP_HEIGHT) / (self.head_height / h - proportion::HIP_HEIGHT);
            spatial::add(pelvis, spatial::scale(spatial::sub(head, pelvis), s))
        };
        pose.set(HumanBody::Chest, at(along(proportion::CHEST_HEIGHT), trunk));
        pose.set(HumanBody::Head, at(head, hmd.rot));
        let shoulder_mid = along(proportion::SHOULDER_HEIGHT);
        let side_axis = spatial::mat_apply(&trunk, [0.0, 1.0, 0.0]);
        let arms = [
            (HumanBody::LeftShoulder, HumanBody::LeftElbow, HumanBody::LeftHand),
            (
                HumanBody::RightShoulder,
                HumanBody::RightElbow,
                HumanBody::RightHand,
            ),
        ];
        for (side, (shoulder_body, elbow_body, hand_body)) in arms.into_iter().enumerate() {
            let sign = if side == 0 { 1.0 } else { -1.0 };
            let shoulder = spatial::add(
                shoulder_mid,
                spatial::scale(side_axis, sign * h * proportion::SHOULDER_HALF_WIDTH),
            );
            let Some(device) = devices[1 + side] else {
                continue;
            };
            let offset = if side == 0 {
                self.user.left
            } else {
                self.user.right
            };
            // Elbows hang down and out, away from where the hand points (a controller is held
            // across the palm: its forward axis leaves the elbow behind).
            let hand_forward = spatial::mat_apply(&device.rot, [1.0, 0.0, 0.0]);
            let pole = spatial::sub(
                spatial::add([0.0, 0.0, -1.0], spatial::scale(side_axis, sign * 0.5)),
                hand_forward,
            );
            let (elbow, wrist) = two_bone(
                shoulder,
                joint_from_device(&device, offset),
                h * proportion::UPPER_ARM,
                h * proportion::FOREARM,
                pole,
            );
            // Both segments turn about the elbow's hinge: the axis the bend shows, or where the
            // arm is straight, the one the hand's roll gives (palm down in the T-pose: vertical).
            let (upper_dir, fore_dir) = (
                spatial::unit(spatial::sub(elbow, shoulder)),
                spatial::unit(spatial::sub(wrist, elbow)),
            );
            let hand_up = spatial::mat_apply(&device.rot, [0.0, 0.0, 1.0]);
            let hinge = spatial::add(
                spatial::cross(upper_dir, fore_dir),
                spatial::scale(hand_up, -sign * HINGE_FROM_HAND),
            );
            pose.set(shoulder_body, at(shoulder, frame_from_x_z(upper_dir, hinge)));
            pose.set(elbow_body, at(elbow, frame_from_x_z(fore_dir, hinge)));
            pose.set(hand_body, at(wrist, device.rot));
        }
        let legs = [
            (HumanBody::LeftHip, HumanBody::LeftKnee, HumanBody::LeftFoot),
            (HumanBody::RightHip, HumanBody::RightKnee, HumanBody::RightFoot),
        ];
        for (side, (hip_body, knee_body, foot_body)) in legs.into_iter().enumerate() {
            let hip = hip(side, pelvis_z);
            let foot = self.feet[side];
            let ankle = [foot.at[0], foot.at[1], self.ankle_z[side]];
            // Knees bend forward.
            let forward = spatial::mat_apply(&spatial::yaw(foot.yaw), [1.0, 0.0, 0.0]);
            let (knee, ankle) = two_bone(hip, ankle, h * proportion::THIGH, h * proportion::SHANK, forward);
            pose.set(
                hip_body,
                at(hip, frame_from_z_x(spatial::sub(hip, knee), forward)),
            );
            pose.set(
                knee_body,
                at(knee, frame_from_z_x(spatial::sub(knee, ankle), forward)),
            );
            pose.set(foot_body, at(ankle, spatial::yaw(foot.yaw)));
        }
        Some(pose)
    }

    /// Where the pelvis is for a head joint at `head`: its floor position and height. The trunk
    /// (hips to head joint, straight) leans as far as both the head's reach beyond the feet and its
    /// drop allow — a bow keeps the pelvis over the feet; the drop it leaves is a crouch (the
    /// pelvis lower, no higher than standing); a head ahead that has not dropped carries the
    /// pelvis along (the feet step after it).
    fn pelvis_under(&self, head: [f64; 3]) -> ([f64; 2], f64) {
        let h = self.user.stature;
        let trunk = self.head_height - h * proportion::HIP_HEIGHT;
        let [left, right] = self.feet;
        let support = [0, 1].map(|k| (left.at[k] + right.at[k]) / 2.0);
        let ahead = [head[0] - support[0], head[1] - support[1]];
        let reach = (ahead[0] * ahead[0] + ahead[1] * ahead[1]).sqrt();
        let drop = (self.head_height - head[2]).max(0.0);
        let lean = (reach / trunk)
            .min(1.0)
            .asin()
            .min((1.0 - drop / trunk).clamp(-1.0, 1.0).acos());
        let back = if reach > 1e-9 {
            trunk * lean.sin() / reach
        } else {
            0.0
        };
        let floor = [head[0] - ahead[0] * back, head[1] - ahead[1] * back];
        (
            floor,
            (head[2] - trunk * lean.cos()).min(h * proportion::HIP_HEIGHT),
        )
    }
}

/// An angle in (−π, π].
fn wrap(a: f64) -> f64 {
    let t = std::f64::consts::TAU;
    a - t * ((a + std::f64::consts::PI) / t).floor()
}

/// The middle joint of a two-bone chain from `root` to `target` (bones `a`, `b` long), bent
/// towards `pole`; straight towards a target out of reach. Returns (middle, target).
fn two_bone(root: [f64; 3], target: [f64; 3], a: f64, b: f64, pole: [f64; 3]) -> ([f64; 3], [f64; 3]) {
    let to = spatial::sub(target, root);
    let reach = spatial::norm(to).clamp(1e-6, (a + b) * 0.999_999);
    let dir = if spatial::norm(to) > 1e-9 {
        spatial::unit(to)
    } else {
        [0.0, 0.0, -1.0]
    };
    // The middle joint: along the chain by the law of cosines, off it towards the pole.
    let along = (a * a - b * b + reach * reach) / (2.0 * reach);
    let off = (a * a - along * along).max(0.0).sqrt();
    let bend = spatial::sub(pole, spatial::scale(dir, spatial::dot(pole, dir)));
    let bend = if spatial::norm(bend) > 1e-9 {
        spatial::unit(bend)
    } else {
        spatial::unit(spatial::cross(dir, [0.0, 1.0, 0.0]))
    };
    let middle = spatial::add(
        root,
        spatial::add(spatial::scale(dir, along), spatial::scale(bend, off)),
    );
    (middle, target)
}

/// The rotation whose x axis is `x` and whose z axis is as close to `z` as it can be.
fn frame_from_x_z(x: [f64; 3], z: [f64; 3]) -> Mat3 {
    let x = spatial::unit(x);
    let y = spatial::unit(spatial::cross(z, x));
    let z = spatial::cross(x, y);
    columns(x, y, z)
}

/// The rotation whose z axis is `z` and whose x axis is as close to `x` as it can be.
fn frame_from_z_x(z: [f64; 3], x: [f64; 3]) -> Mat3 {
    let z = spatial::unit(z);
    let y = spatial::unit(spatial::cross(z, x));
    let x = spatial::cross(y, z);
    columns(x, y, z)
}

fn columns(x: [f64; 3], y: [f64; 3], z: [f64; 3]) -> Mat3 {
    [[x[0], y[0], z[0]], [x[1], y[1], z[1]], [x[2], y[2], z[2]]]
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::body_map::Template;

    const H: f64 = 1.75;
    /// The head joint behind the eyes (the template's), so the feet stand under it.
    const BEHIND: f64 = -0.05 * H;

    /// Ankles under the hips of a body at x.
    fn feet_at(x: f64) -> [[f64; 3]; 2] {
        [[x + BEHIND, H * 0.055, 0.0], [x + BEHIND, -H * 0.055, 0.0]]
    }

    /// A 1.75 m operator in a T-pose with the head and hands at `at`, the head `drop` m lower and
    /// turned `look`; foot trackers 6 cm ahead of and 5 cm above their ankles at `feet` (x, y,
    /// height above standing), the left turned `left_yaw`.
    fn devices(at: [f64; 2], drop: f64, look: f64, feet: [[f64; 3]; 2], left_yaw: f64) -> Devices {
        let place = |v: [f64; 3]| [at[0] + v[0], at[1] + v[1], v[2]];
        let hand = |y: f64| Frame {
            pos: place([0.0, y, 0.80 * H - drop]),
            rot: spatial::IDENTITY,
        };
        let tracker = |p: [f64; 3], yaw: f64| {
            let rot = spatial::yaw(yaw);
            Frame {
                pos: spatial::add(
                    [p[0], p[1], H * 0.039 + p[2]],
                    spatial::mat_apply(&rot, [0.06, 0.0, 0.05]),
                ),
                rot,
            }
        };
        [
            Some(Frame {
                pos: place([0.0, 0.0, 0.936 * H - drop]),
                rot: spatial::yaw(look),
            }),
            Some(hand(0.85)),
            Some(hand(-0.85)),
            Some(tracker(feet[0], left_yaw)),
            Some(tracker(feet[1], 0.0)),
        ]
    }

    fn standing() -> Devices {
        devices([0.0, 0.0], 0.0, 0.0, feet_at(0.0), 0.0)
    }

    fn body() -> SparseBody {
        let d = standing();
        let [Some(hmd), Some(left), Some(right), ..] = &d else {
            unreachable!()
        };
        let user = UserCalibration::from_tpose(hmd, left, right, &Template::default()).unwrap();
        SparseBody::new(user, &d).unwrap()
    }

    fn at(p: &HumanPose, b: HumanBody) -> [f64; 3] {
        p.get(b).unwrap().pos
    }

    fn near(a: [f64; 3], b: [f64; 3]) -> bool {
        spatial::norm(spatial::sub(a, b)) < 1e-9
    }

    #[test]
    fn standing_every_body_is_there_the_ankles_under_the_hips_and_the_legs_straight() {
        let mut b = body();
        let p = b.pose(&standing(), 0.02).unwrap();
        assert!(p.bodies.iter().all(Option::is_some), "{p:?}");
        assert!(near(at(&p, HumanBody::LeftFoot), [BEHIND, H * 0.055, H * 0.039]));
        let leg = at(&p, HumanBody::LeftHip)[2] - at(&p, HumanBody::LeftFoot)[2];
        assert!((leg - H * (0.530 - 0.039)).abs() < 1e-9, "{leg}");
        // A look around turns neither the pelvis nor the feet.
        let look = devices([0.0, 0.0], 0.0, 1.0, feet_at(0.0), 0.0);
        let p = b.pose(&look, 0.02).unwrap();
        assert!(spatial::heading(&p.get(HumanBody::Root).unwrap().rot).abs() < 1e-9);
        assert!(spatial::heading(&p.get(HumanBody::Head).unwrap().rot) > 0.99);
    }

    #[test]
    fn a_lifted_foot_is_where_its_tracker_says_and_the_legs_reach_the_pelvis() {
        let mut b = body();
        // The left foot 20 cm up and 30 cm ahead, turned 0.4 rad.
        let lifted = devices(
            [0.0, 0.0],
            0.0,
            0.0,
            [[BEHIND + 0.3, 0.1, 0.2], feet_at(0.0)[1]],
            0.4,
        );
        let p = (0..50).map(|_| b.pose(&lifted, 0.02).unwrap()).last().unwrap();
        let left = p.get(HumanBody::LeftFoot).unwrap();
        assert!(
            near(left.pos, [BEHIND + 0.3, 0.1, H * 0.039 + 0.2]),
            "{:?}",
            left.pos
        );
        assert!((spatial::heading(&left.rot) - 0.4).abs() < 1e-9);
        assert!((b.heading - 0.2).abs() < 1e-9, "between the feet: {}", b.heading);
        let leg = H * (0.245 + 0.246);
        for (hip, ankle) in [
            (HumanBody::LeftHip, HumanBody::LeftFoot),
            (HumanBody::RightHip, HumanBody::RightFoot),
        ] {
            let reach = spatial::norm(spatial::sub(at(&p, hip), at(&p, ankle)));
            assert!(reach <= leg + 1e-6, "{hip:?}: {reach}");
        }
        // A long stride with the head upright between the feet: the pelvis cannot stay at
        // standing height over feet 80 cm apart.
        let stride = devices([0.3, 0.0], 0.0, 0.0, [[0.7, 0.1, 0.0], [-0.1, -0.1, 0.0]], 0.0);
        let p = (0..50).map(|_| b.pose(&stride, 0.02).unwrap()).last().unwrap();
        let right = spatial::norm(spatial::sub(
            at(&p, HumanBody::RightHip),
            at(&p, HumanBody::RightFoot),
        ));
        assert!(right <= leg + 1e-6, "{right}");
        assert!(at(&p, HumanBody::Root)[2] < H * 0.53 - 0.02);
    }

    #[test]
    fn a_crouch_bends_the_knees_and_a_bow_leans_the_trunk_over_the_feet() {
        let mut b = body();
        let pelvis = at(&b.pose(&standing(), 0.02).unwrap(), HumanBody::Root);
        // Crouching 30 cm: the pelvis drops as much, the feet stay on the floor.
        let low = devices([0.0, 0.0], 0.3, 0.0, feet_at(0.0), 0.0);
        let p = (0..50).map(|_| b.pose(&low, 0.02).unwrap()).last().unwrap();
        assert!((at(&p, HumanBody::Root)[2] - (pelvis[2] - 0.3)).abs() < 0.01);
        assert!((at(&p, HumanBody::LeftFoot)[2] - H * 0.039).abs() < 1e-9);
        let knee = at(&p, HumanBody::LeftKnee);
        assert!(knee[0] > BEHIND + 0.1, "the knee bends forward: {knee:?}");
        // Bowing 40° about the hips: the head joint swings forward and down, the pelvis stays.
        let mut b = body();
        let trunk = b.head_height - H * 0.53;
        let a = 40f64.to_radians();
        for k in 0..=50 {
            let s = f64::from(k) / 50.0;
            let (ahead, drop) = (trunk * (s * a).sin(), trunk * (1.0 - (s * a).cos()));
            let bow = devices([ahead, 0.0], drop, 0.0, feet_at(0.0), 0.0);
            let root = at(&b.pose(&bow, 0.02).unwrap(), HumanBody::Root);
            assert!(spatial::norm(spatial::sub(root, pelvis)) < 0.02, "{s}: {root:?}");
        }
    }

    /// The estimate against the performer's own bodies on a real take (CMU 13_26, directing
    /// traffic: arms up, turning, stepping), devices where a rig puts them: the hands are the
    /// controllers', the feet the trackers', the rest estimated — what the retargeter then
    /// follows. Errors are after the constant offset of each body (the T-pose's difference
    /// between a skeleton's joint and the anthropometric one, which the map's calibration takes).
    #[test]
    fn on_a_real_take_the_estimate_stays_near_the_performers_bodies() {
        let path =
            test_support::fixtures::workspace_root().join("data/mocap/cmu_13_26_direct-traffic-wave.bvh");
        let bvh = motion::bvh::Bvh::load(&path).unwrap();
        let bodies = [
            HumanBody::Root,
            HumanBody::LeftHand,
            HumanBody::LeftElbow,
            HumanBody::LeftKnee,
            HumanBody::LeftFoot,
            HumanBody::RightFoot,
        ];
        let truth = crate::retarget::BvhBodies::new(&bvh, &bodies).unwrap();
        let rig = crate::vr_send::Rig::new(&bvh).unwrap();
        let t = rig.devices(&bvh, 0).map(Some);
        let [Some(hmd), Some(left), Some(right), ..] = &t else {
            unreachable!()
        };
        let user = UserCalibration::from_tpose(hmd, left, right, &Template::default()).unwrap();
        let mut b = SparseBody::new(user, &t).unwrap();
        let mut errors = vec![Vec::new(); bodies.len()];
        for f in 1..bvh.frames() {
            let p = b.pose(&rig.devices(&bvh, f).map(Some), bvh.frame_time).unwrap();
            let real = truth.pose(&bvh.pose(f));
            for (k, body) in bodies.iter().enumerate() {
                let (est, real) = (p.get(*body).unwrap(), real.get(*body).unwrap());
                // In the body's heading frame: a constant offset there is a proportion.
                let back = spatial::transpose(&spatial::yaw(b.heading));
                errors[k].push(spatial::mat_apply(&back, spatial::sub(est.pos, real.pos)));
            }
        }
        let rms: Vec<f64> = errors
            .iter()
            .map(|e| {
                let n = e.len() as f64;
                let mean = [0, 1, 2].map(|i| e.iter().map(|v| v[i]).sum::<f64>() / n);
                (e.iter()
                    .map(|v| spatial::norm(spatial::sub(*v, mean)).powi(2))
                    .sum::<f64>()
                    / n)
                    .sqrt()
            })
            .collect();
        eprintln!("{:?}", bodies.iter().zip(&rms).collect::<Vec<_>>());
        // Measured: root 0.066, hand 0.012, elbow 0.079, knee 0.045, feet 0.013 m.
        for (body, (rms, most)) in bodies
            .iter()
            .zip(rms.iter().zip([0.09, 0.02, 0.10, 0.07, 0.025, 0.025]))
        {
            assert!(*rms <= most, "{body:?}: {rms:.3} m RMS");
        }
    }
}
