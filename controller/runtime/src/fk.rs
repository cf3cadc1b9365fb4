//! Forward kinematics of a reference on the robot's own model: where each named body is when the
//! robot stands in the reference's pose, for policies that observe reference body positions.

use mujoco_rs::prelude::MjData;
use robots::{Robot, spatial};
use sim2real::model_index::{self, ModelIndex};

use crate::clip::Reference;
use world::KinematicsError;

/// Positions of `bodies` at every tick of `reference`, relative to the reference root in its
/// heading frame (yaw only): `ticks × bodies × 3` values.
pub fn body_positions(
    robot: &Robot,
    reference: &Reference,
    bodies: &[String],
) -> Result<Vec<f64>, KinematicsError> {
    let poses = body_poses(robot, reference, bodies)?;
    let mut out = Vec::with_capacity(poses.len() * 3);
    for (k, frame) in poses.chunks(bodies.len().max(1)).enumerate() {
        let r = reference.root[k];
        // Into the root's heading frame (yaw only).
        let unturn = spatial::yaw(-spatial::heading_of_quat([r[3], r[4], r[5], r[6]]));
        for p in frame {
            let d = spatial::sub([p[0], p[1], p[2]], [r[0], r[1], r[2]]);
            out.extend_from_slice(&spatial::mat_apply(&unturn, d));
        }
    }
    Ok(out)
}

/// World poses `[x, y, z, w, qx, qy, qz]` of `bodies` (bodies, or sites) at every tick of
/// `reference` (the robot's model posed as the reference): `ticks × bodies` poses.
pub fn body_poses(
    robot: &Robot,
    reference: &Reference,
    bodies: &[String],
) -> Result<Vec<[f64; 7]>, KinematicsError> {
    let model = robot.shared_model()?;
    let index = ModelIndex::of_robot(&model, robot)?;
    let frames = bodies
        .iter()
        .map(|b| model_index::frame(&model, b))
        .collect::<Result<Vec<_>, _>>()?;
    let mut data = MjData::new(model.clone());
    let mut out = Vec::with_capacity(reference.len() * bodies.len());
    for k in 0..reference.len() {
        let r = index.root.qpos;
        data.qpos_mut()[r..r + 7].copy_from_slice(&reference.root[k]);
        for (j, &q) in index.joints.iter().zip(reference.q_at(k)) {
            data.qpos_mut()[j.qpos] = q;
        }
        data.kinematics();
        for &f in &frames {
            let (p, q) = match f {
                model_index::FrameId::Body(b) => (data.xpos()[b], data.xquat()[b]),
                model_index::FrameId::Site { site, .. } => {
                    let m = data.site_xmat()[site];
                    let rows = [[m[0], m[1], m[2]], [m[3], m[4], m[5]], [m[6], m[7], m[8]]];
                    (data.site_xpos()[site], spatial::quat_of_mat(&rows))
                }
            };
            out.push([p[0], p[1], p[2], q[0], q[1], q[2], q[3]]);
        }
    }
    Ok(out)
}

/// The root's world pose at every tick of `reference` given the world poses of `body` (one per
/// tick, `[x, y, z, w, qx, qy, qz]`): the model posed in each tick's joint angles says where `body`
/// sits on the root, and the root is put where that places `body` on its given pose. For exports
/// that give an anchor's pose and not the root's (holosoma's torso).
pub fn root_poses_from_body(
    robot: &Robot,
    reference: &Reference,
    body: &str,
    poses: &[[f64; 7]],
) -> Result<Vec<[f64; 7]>, KinematicsError> {
    let model = robot.shared_model()?;
    let index = ModelIndex::of_robot(&model, robot)?;
    let b = model_index::body(&model, body)?;
    let mut data = MjData::new(model.clone());
    let r = index.root.qpos;
    let mut out = Vec::with_capacity(poses.len());
    for (k, pose) in poses.iter().enumerate() {
        data.qpos_mut()[r..r + 7].copy_from_slice(&[0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0]);
        for (j, &q) in index.joints.iter().zip(reference.q_at(k)) {
            data.qpos_mut()[j.qpos] = q;
        }
        data.kinematics();
        // The body in the root's frame, then root = body ∘ (body in root)⁻¹.
        let (p_rb, q_rb) = (data.xpos()[b], data.xquat()[b]);
        let q_wb = [pose[3], pose[4], pose[5], pose[6]];
        let q_wr = spatial::quat_normalize(spatial::quat_mul(q_wb, spatial::quat_conj(q_rb)));
        let p_wr = spatial::sub([pose[0], pose[1], pose[2]], spatial::quat_rotate(q_wr, p_rb));
        out.push([p_wr[0], p_wr[1], p_wr[2], q_wr[0], q_wr[1], q_wr[2], q_wr[3]]);
    }
    Ok(out)
}
