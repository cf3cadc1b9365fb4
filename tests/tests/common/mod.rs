//! What several whole-path test files share: a robot at rest, as the observation builder sees it.

use policy::{ObsInputs, ReferenceView};

/// A reference that stands still at the pose it holds, its root `height` m up.
#[derive(Debug)]
pub struct Still {
    pub q: Vec<f64>,
    pub height: f64,
}

impl ReferenceView for Still {
    fn joint_pos(&self, _: usize) -> &[f64] {
        &self.q
    }
    fn joint_vel(&self, _: usize) -> &[f64] {
        &self.q
    }
    fn root_pose(&self, _: usize) -> [f64; 7] {
        [0.0, 0.0, self.height, 1.0, 0.0, 0.0, 0.0]
    }
    fn body_pos(&self, _: usize) -> &[f64] {
        &[]
    }
    fn anchor_pose(&self) -> [f64; 7] {
        [0.0, 0.0, self.height, 1.0, 0.0, 0.0, 0.0]
    }
    fn keypoints(&self, _: usize) -> &[f64] {
        &[]
    }
    fn root_lin_vel(&self, _: usize) -> [f64; 3] {
        [0.0; 3]
    }
    fn root_ang_vel(&self, _: usize) -> [f64; 3] {
        [0.0; 3]
    }
}

/// The inputs of a robot at rest and upright at `still`'s pose (all joints at `zeros`, past
/// actions `past`): override the fields a test is about.
pub fn at_rest<'a>(zeros: &'a [f64], past: &'a [f32], still: &'a Still) -> ObsInputs<'a> {
    ObsInputs {
        gyro: [0.0; 3],
        accel: [0.0; 3],
        quat: [1.0, 0.0, 0.0, 0.0],
        q: zeros,
        qd: zeros,
        default_q: zeros,
        past_actions: past,
        last_targets: zeros,
        step: 0,
        dt: 0.02,
        command: None,
        ramp: 1.0,
        reference: still,
        truth: None,
        trackers: None,
        base_ang_vel: [0.0; 3],
        robot_anchor: still.anchor_pose(),
        time_step: 0.0,
        robot_keypoints: &[],
        gait: [0.0; 2],
    }
}
