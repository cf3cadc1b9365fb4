//! Pictures of a run at the moments that matter: the robot's own model posed as the recording
//! says (the simulator's base pose, the measured joints), drawn by the mirror's ray caster.

use std::path::Path;

use mujoco_rs::prelude::MjData;
use sim2real::render::{CameraSpec, render};

/// One picture to draw: its caption, the base pose `[x, y, z, w, qx, qy, qz]`, the joints in
/// robot order.
pub(super) struct Moment {
    pub caption: String,
    pub base: [f64; 7],
    pub q: Vec<f64>,
}

/// Why the pictures of a run could not be drawn.
#[derive(Debug, thiserror::Error)]
pub(super) enum FramesError {
    #[error(transparent)]
    Robot(#[from] robots::RobotError),
    #[error(transparent)]
    Mujoco(#[from] sim2real::mujoco::MujocoError),
    #[error(transparent)]
    Model(#[from] sim2real::model_index::ModelIndexError),
    #[error("PNG encoding: {0}")]
    Png(std::io::Error),
}

/// PNGs of `moments` of the robot at `robot_toml`, captioned.
pub(super) fn render_moments(
    robot_toml: &Path,
    moments: &[Moment],
) -> Result<Vec<(String, Vec<u8>)>, FramesError> {
    let robot = robots::Robot::load(robot_toml)?;
    let model = robot.shared_model()?;
    let index = sim2real::model_index::ModelIndex::of_robot(&model, &robot)?;
    let root = index.root.qpos;
    let adr: Vec<usize> = index.joints.iter().map(|j| j.qpos).collect();
    let mut data = MjData::new(model);
    let camera = CameraSpec {
        width: 360,
        height: 270,
        distance: 1.8,
        ..CameraSpec::default()
    };
    let mut out = Vec::with_capacity(moments.len());
    for m in moments {
        let qpos = data.qpos_mut();
        qpos[root..root + 7].copy_from_slice(&m.base);
        for (&a, &v) in adr.iter().zip(&m.q) {
            if v.is_finite() {
                qpos[a] = v;
            }
        }
        data.kinematics();
        let target = [m.base[0], m.base[1], m.base[2] - 0.1];
        let png = render(&mut data, &camera, target)
            .to_png()
            .map_err(FramesError::Png)?;
        out.push((m.caption.clone(), png));
    }
    Ok(out)
}
