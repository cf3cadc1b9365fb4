//! Forward kinematics of a reference on the robot's own model: where each named body is when the
//! robot stands in the reference's pose, for policies that observe reference body positions.

use robots::{Robot, spatial};
use sim2real::model_index::{self, ModelIndex};

use crate::clip::Reference;

/// The robot's model could not give the reference's body positions.
#[derive(Debug, thiserror::Error)]
pub enum KinematicsError {
    /// MuJoCo could not load the model.
    #[error(transparent)]
    Model(#[from] sim2real::mujoco::MujocoError),
    /// The model lacks a body or joint the robot names.
    #[error(transparent)]
    Names(#[from] model_index::ModelIndexError),
}

/// Positions of `bodies` at every tick of `reference`, relative to the reference root in its
/// heading frame (yaw only): `ticks × bodies × 3` values.
pub fn body_positions(
    robot: &Robot,
    reference: &Reference,
    bodies: &[String],
) -> Result<Vec<f64>, KinematicsError> {
    let model = sim2real::mujoco::load_model(&robot.mjcf_path)?;
    let index = ModelIndex::of_robot(&model, robot)?;
    let body_ids = bodies
        .iter()
        .map(|b| model_index::body(&model, b))
        .collect::<Result<Vec<_>, _>>()?;
    let root_qpos = index.root.qpos;
    let joint_qpos: Vec<usize> = index.joints.iter().map(|j| j.qpos).collect();
    let mut data = model.make_data();
    let mut out = Vec::with_capacity(reference.len() * bodies.len() * 3);
    for k in 0..reference.len() {
        let r = reference.root[k];
        data.qpos_mut()[root_qpos..root_qpos + 7].copy_from_slice(&r);
        for (&adr, &q) in joint_qpos.iter().zip(reference.q_at(k)) {
            data.qpos_mut()[adr] = q;
        }
        data.kinematics();
        // Into the root's heading frame (yaw only).
        let unturn = spatial::yaw(-spatial::heading_of_quat([r[3], r[4], r[5], r[6]]));
        for &b in &body_ids {
            let d = spatial::sub(data.xpos()[b], [r[0], r[1], r[2]]);
            out.extend_from_slice(&spatial::mat_apply(&unturn, d));
        }
    }
    Ok(out)
}
