//! A whole body as VMC sends it: a humanoid's bones under Unity's `HumanBodyBones` names, each
//! pose local to its parent bone, under the skeleton's root (`/VMC/Ext/Root/Pos`,
//! `/VMC/Ext/Bone/Pos`). Forward kinematics over the humanoid hierarchy gives every bone in the
//! world, and so the human bodies the retargeting map pairs. A bone that was not sent is the
//! identity: a sender that skips one sends its children relative to the nearest bone it sent.
//! Everything here is in robot axes (x forward, y left, z up); [`crate::vmc`] converts Unity's.

use crate::body_map::{Frame, HumanPose};
use robots::HumanBody;
use robots::spatial;

/// The bones used, Unity's names, parents before children.
pub const BONES: [&str; 22] = [
    "Hips",
    "Spine",
    "Chest",
    "UpperChest",
    "Neck",
    "Head",
    "LeftShoulder",
    "LeftUpperArm",
    "LeftLowerArm",
    "LeftHand",
    "RightShoulder",
    "RightUpperArm",
    "RightLowerArm",
    "RightHand",
    "LeftUpperLeg",
    "LeftLowerLeg",
    "LeftFoot",
    "LeftToes",
    "RightUpperLeg",
    "RightLowerLeg",
    "RightFoot",
    "RightToes",
];

/// Each bone's parent in Unity's humanoid hierarchy (`None`: the hips, under the root).
const PARENT: [Option<usize>; 22] = [
    None,
    Some(0),
    Some(1),
    Some(2),
    Some(3),
    Some(4),
    Some(3),
    Some(6),
    Some(7),
    Some(8),
    Some(3),
    Some(10),
    Some(11),
    Some(12),
    Some(0),
    Some(14),
    Some(15),
    Some(16),
    Some(0),
    Some(18),
    Some(19),
    Some(20),
];

/// The human body each bone stands for, and the bone whose orientation it takes (the feet lie as
/// their toes, as the BVH skeletons' do).
pub const BODIES: [(HumanBody, usize, usize); 15] = [
    (HumanBody::Root, 0, 0),
    (HumanBody::Chest, 2, 2),
    (HumanBody::Head, 5, 5),
    (HumanBody::LeftShoulder, 7, 7),
    (HumanBody::LeftElbow, 8, 8),
    (HumanBody::LeftHand, 9, 9),
    (HumanBody::RightShoulder, 11, 11),
    (HumanBody::RightElbow, 12, 12),
    (HumanBody::RightHand, 13, 13),
    (HumanBody::LeftHip, 14, 14),
    (HumanBody::LeftKnee, 15, 15),
    (HumanBody::LeftFoot, 16, 17),
    (HumanBody::RightHip, 18, 18),
    (HumanBody::RightKnee, 19, 19),
    (HumanBody::RightFoot, 20, 21),
];

/// The index of a bone by its Unity name.
pub fn bone_index(name: &str) -> Option<usize> {
    BONES.iter().position(|b| *b == name)
}

/// A skeleton as received: the root's world frame and each bone's frame local to its parent.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Skeleton {
    /// The skeleton's root in the world (identity when never sent).
    pub root: Option<Frame>,
    /// Per bone of [`BONES`], local to its parent.
    pub bones: [Option<Frame>; 22],
}

fn compose(parent: &Frame, local: &Frame) -> Frame {
    Frame {
        pos: spatial::add(parent.pos, spatial::mat_apply(&parent.rot, local.pos)),
        rot: spatial::mat_mul(&parent.rot, &local.rot),
    }
}

const IDENTITY: Frame = Frame {
    pos: [0.0; 3],
    rot: spatial::IDENTITY,
};

impl Skeleton {
    /// Every sent bone in the world; `None` where a bone was not sent.
    pub fn world(&self) -> [Option<Frame>; 22] {
        let mut chain = [IDENTITY; 22];
        let mut out = [None; 22];
        for b in 0..BONES.len() {
            let parent = PARENT[b].map_or(self.root.unwrap_or(IDENTITY), |p| chain[p]);
            chain[b] = match &self.bones[b] {
                Some(local) => compose(&parent, local),
                None => parent,
            };
            out[b] = self.bones[b].map(|_| chain[b]);
        }
        out
    }

    /// The human bodies the sent bones give.
    pub fn human_pose(&self) -> HumanPose {
        let world = self.world();
        let mut pose = HumanPose::default();
        for (body, at, turned) in BODIES {
            if let Some(f) = world[at] {
                pose.set(
                    body,
                    Frame {
                        pos: f.pos,
                        rot: world[turned].unwrap_or(f).rot,
                    },
                );
            }
        }
        pose
    }

    /// The skeleton whose sent bones are at `world` (robot axes), the root at the world's origin:
    /// each bone local to its nearest sent ancestor, as a sender sends it.
    pub fn from_world(world: &[Option<Frame>; 22]) -> Self {
        let mut bones = [None; 22];
        for (b, f) in world.iter().enumerate() {
            let Some(f) = f else { continue };
            let mut up = PARENT[b];
            while let Some(p) = up.filter(|&p| world[p].is_none()) {
                up = PARENT[p];
            }
            let parent = up.and_then(|p| world[p]).unwrap_or(IDENTITY);
            let back = spatial::transpose(&parent.rot);
            bones[b] = Some(Frame {
                pos: spatial::mat_apply(&back, spatial::sub(f.pos, parent.pos)),
                rot: spatial::mat_mul(&back, &f.rot),
            });
        }
        Self {
            root: Some(IDENTITY),
            bones,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bones_sent_relative_to_their_nearest_sent_ancestor_come_back_where_they_were() {
        // A chain with gaps: the spine, neck and shoulders are not sent.
        let mut world = [None; 22];
        let at = |p: [f64; 3], w: [f64; 3]| {
            Some(Frame {
                pos: p,
                rot: spatial::exp(w),
            })
        };
        world[0] = at([0.1, -0.2, 0.95], [0.0, 0.0, 0.4]);
        world[2] = at([0.12, -0.2, 1.25], [0.1, 0.05, 0.4]);
        world[5] = at([0.13, -0.18, 1.6], [0.0, 0.3, 0.5]);
        world[9] = at([0.2, 0.6, 1.4], [0.7, -0.2, 0.1]);
        world[16] = at([0.05, -0.1, 0.08], [0.0, 0.2, 0.3]);
        world[17] = at([0.2, -0.1, 0.02], [0.0, 0.0, 0.3]);
        let skeleton = Skeleton::from_world(&world);
        let back = skeleton.world();
        for (b, (want, got)) in world.iter().zip(&back).enumerate() {
            match (want, got) {
                (Some(w), Some(g)) => {
                    let e = spatial::norm(spatial::sub(w.pos, g.pos));
                    let r = spatial::norm(spatial::log(&spatial::mat_mul(
                        &spatial::transpose(&w.rot),
                        &g.rot,
                    )));
                    assert!(e < 1e-12 && r < 1e-12, "{}: {e} m, {r} rad", BONES[b]);
                }
                (None, None) => {}
                _ => panic!(
                    "{}: sent {} came back {}",
                    BONES[b],
                    want.is_some(),
                    got.is_some()
                ),
            }
        }
        // The bodies: the foot at the ankle, turned as the toes; the knees not sent.
        let pose = skeleton.human_pose();
        let foot = pose.get(HumanBody::LeftFoot).unwrap();
        assert_eq!(foot.pos, back[16].unwrap().pos);
        assert_eq!(foot.rot, back[17].unwrap().rot);
        // A body whose bone was not sent is not seen (the retargeter names it at the T-pose).
        assert!(pose.get(HumanBody::LeftKnee).is_none() && pose.get(HumanBody::LeftHand).is_some());
    }
}
