//! The compiled model's ids for one robot, resolved once: the root body and its free joint, each
//! robot joint's joint id and its qpos/dof addresses (robot joint order), the feet. Everything that
//! works on the robot's MuJoCo model (mirror, kinematics, IK, motion checks, telemetry) starts
//! from here; nothing looks a name up per step.

use mujoco_rs::prelude::{MjModel, MjtJoint};
use mujoco_rs::wrappers::mj_model::MjtObjBase;
use robots::Robot;

/// A name the compiled model does not have, or a root that cannot float.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ModelIndexError {
    /// No object of that kind and name.
    #[error("the model has no {kind} {name:?}")]
    Missing {
        /// `body`, `joint`, `site` or `body or site`.
        kind: &'static str,
        /// The name asked for.
        name: String,
    },
    /// The root body has no free joint.
    #[error("root body {0:?} has no free joint")]
    RootNotFree(String),
}

/// One robot joint in the compiled model.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct JointIds {
    /// Joint id.
    pub id: usize,
    /// Address of its position in `qpos`.
    pub qpos: usize,
    /// Address of its velocity in `qvel` (its degree of freedom).
    pub dof: usize,
}

/// A frame the robot names: a body, or a site on a body.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FrameId {
    /// A body.
    Body(usize),
    /// A site, and the body it sits on.
    Site {
        /// Site id.
        site: usize,
        /// Its body.
        body: usize,
    },
}

/// The robot's ids in one compiled model.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ModelIndex {
    /// The root (floating base) body.
    pub root_body: usize,
    /// The root's free joint: position `[x, y, z, w, qx, qy, qz]` at `qpos`, velocity at `dof`.
    pub root: JointIds,
    /// The robot's joints, robot order.
    pub joints: Vec<JointIds>,
    /// Foot bodies, robot.toml order.
    pub feet: Vec<usize>,
}

impl ModelIndex {
    /// The ids of `robot` in `model` (the robot's own MJCF, compiled).
    pub fn of_robot(model: &MjModel, robot: &Robot) -> Result<Self, ModelIndexError> {
        let joints: Vec<&str> = robot
            .config
            .joints
            .iter()
            .map(|j| j.mjcf_joint.as_str())
            .collect();
        let feet: Vec<&str> = robot.config.feet.iter().map(String::as_str).collect();
        Self::new(model, &robot.config.root_body, &joints, &feet)
    }

    /// The ids of a root body with a free joint, of `joints` (MJCF joint names) and `feet`.
    pub fn new(model: &MjModel, root: &str, joints: &[&str], feet: &[&str]) -> Result<Self, ModelIndexError> {
        let root_body = body(model, root)?;
        let root_joint = model.body_jntadr()[root_body];
        if root_joint < 0 || model.jnt_type()[root_joint as usize] != MjtJoint::mjJNT_FREE {
            return Err(ModelIndexError::RootNotFree(root.to_owned()));
        }
        Ok(Self {
            root_body,
            root: joint_ids(model, root_joint as usize),
            joints: joints
                .iter()
                .map(|name| joint(model, name))
                .collect::<Result<_, _>>()?,
            feet: feet.iter().map(|f| body(model, f)).collect::<Result<_, _>>()?,
        })
    }
}

fn joint_ids(model: &MjModel, id: usize) -> JointIds {
    JointIds {
        id,
        qpos: model.jnt_qposadr()[id] as usize,
        dof: model.jnt_dofadr()[id] as usize,
    }
}

/// The id of `name` among objects of `kind`; a name with a NUL byte names nothing (MuJoCo's
/// names are C strings).
fn id_of(model: &MjModel, kind: MjtObjBase, name: &str) -> Option<usize> {
    if name.contains('\0') {
        return None;
    }
    model.name_to_id(kind, name)
}

/// A body's id.
pub fn body(model: &MjModel, name: &str) -> Result<usize, ModelIndexError> {
    id_of(model, MjtObjBase::mjOBJ_BODY, name).ok_or_else(|| ModelIndexError::Missing {
        kind: "body",
        name: name.to_owned(),
    })
}

/// A joint's ids.
pub fn joint(model: &MjModel, name: &str) -> Result<JointIds, ModelIndexError> {
    id_of(model, MjtObjBase::mjOBJ_JOINT, name)
        .map(|id| joint_ids(model, id))
        .ok_or_else(|| ModelIndexError::Missing {
            kind: "joint",
            name: name.to_owned(),
        })
}

/// A sensor's address in `sensordata`.
pub fn sensor_address(model: &MjModel, name: &str) -> Result<usize, ModelIndexError> {
    id_of(model, MjtObjBase::mjOBJ_SENSOR, name)
        .map(|id| model.sensor_adr()[id] as usize)
        .ok_or_else(|| ModelIndexError::Missing {
            kind: "sensor",
            name: name.to_owned(),
        })
}

/// A body, else a site, of that name.
pub fn frame(model: &MjModel, name: &str) -> Result<FrameId, ModelIndexError> {
    if let Some(b) = id_of(model, MjtObjBase::mjOBJ_BODY, name) {
        return Ok(FrameId::Body(b));
    }
    id_of(model, MjtObjBase::mjOBJ_SITE, name)
        .map(|site| FrameId::Site {
            site,
            body: model.site_bodyid()[site] as usize,
        })
        .ok_or_else(|| ModelIndexError::Missing {
            kind: "body or site",
            name: name.to_owned(),
        })
}
