//! The physics floor: bare MuJoCo stepping of a robot's compiled model, as a trainer's loop steps
//! it, with nothing of the mirror around it. Benches measure the mirror against it.

use std::time::{Duration, Instant};

use robots::Robot;

use crate::model_index::ModelIndex;

/// Steps `robot`'s compiled model for `seconds` of simulated time holding its default pose, as a
/// trainer's loop does: the robot's PD on every joint each physics step in plain Rust (position
/// actuators of the model get the pose as their control), standing on the floor (a model left
/// without control falls in a heap whose contacts cost another amount of solver time). Returns the
/// wall time and the physics steps taken.
pub fn bare_hold(robot: &Robot, seconds: f64) -> Result<(Duration, u64), String> {
    let model = robot.model().map_err(|e| e.to_string())?;
    let index = ModelIndex::of_robot(&model, robot).map_err(|e| e.to_string())?;
    let mut data = model.make_data();
    for (j, ids) in robot.config.joints.iter().zip(&index.joints) {
        data.qpos_mut()[ids.qpos] = j.default_position;
    }
    data.forward();
    let low = crate::placement::lowest_point(&data, index.root_body).unwrap_or(0.0);
    data.qpos_mut()[index.root.qpos + 2] -= low;
    // The model's own position actuators, by the joint they drive.
    let actuated: Vec<Option<usize>> = index
        .joints
        .iter()
        .map(|ids| {
            (0..model.ffi().nu as usize).find(|&a| {
                model.actuator_trnid()[a][0] == ids.id as i32 && model.actuator_biasprm()[a][1] < 0.0
            })
        })
        .collect();
    let steps = (seconds / model.opt().timestep).round() as u64;
    let wall = Instant::now();
    for _ in 0..steps {
        for ((j, ids), a) in robot.config.joints.iter().zip(&index.joints).zip(&actuated) {
            match *a {
                Some(a) => data.ctrl_mut()[a] = j.default_position,
                None => {
                    let (q, qd) = (data.qpos()[ids.qpos], data.qvel()[ids.dof]);
                    data.qfrc_applied_mut()[ids.dof] = j.kp * (j.default_position - q) - j.kd * qd;
                }
            }
        }
        data.step();
    }
    Ok((wall.elapsed(), steps))
}
