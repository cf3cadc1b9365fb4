//! MuJoCo as this project pins it: version check and model loading with errors that say what to do
//! (owned by `robots::mjcf`, which compiles every robot's model), and a model's sizes.

use mujoco_rs::prelude::MjModel;
use mujoco_rs::wrappers::mj_model::MjtObjBase;

pub use robots::mjcf::{
    MujocoError, PINNED_MUJOCO_VERSION, check_version, load_model, load_model_str, loaded_version,
    loaded_version_string,
};

/// Sizes of a model, named as MuJoCo names them.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ModelSizes {
    /// Generalised coordinates.
    pub nq: usize,
    /// Degrees of freedom.
    pub nv: usize,
    /// Actuators.
    pub nu: usize,
    /// Bodies, world included.
    pub nbody: usize,
    /// Joints.
    pub njnt: usize,
    /// Physics time step, seconds.
    pub timestep: f64,
}

/// Reads the sizes of a loaded model.
pub fn sizes(model: &MjModel) -> ModelSizes {
    let m = model.ffi();
    let count = |n: i64| usize::try_from(n).unwrap_or(0);
    ModelSizes {
        nq: count(m.nq),
        nv: count(m.nv),
        nu: count(m.nu),
        nbody: count(m.nbody),
        njnt: count(m.njnt),
        timestep: m.opt.timestep,
    }
}

/// Names of a model's joints, in MuJoCo's order.
pub fn joint_names(model: &MjModel) -> Vec<String> {
    (0..sizes(model).njnt)
        .map(|id| {
            model
                .id_to_name(MjtObjBase::mjOBJ_JOINT, id)
                .unwrap_or("")
                .to_owned()
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use mujoco_rs::prelude::MjData;

    const PENDULUM: &str = r#"
        <mujoco>
          <option timestep="0.001"/>
          <worldbody>
            <body name="link" pos="0 0 1">
              <joint name="hinge" type="hinge" axis="0 1 0" damping="0"/>
              <geom type="sphere" pos="0 0 -0.5" size="0.01" mass="1"/>
            </body>
          </worldbody>
        </mujoco>"#;

    #[test]
    fn pinned_library_is_loaded() {
        assert_eq!(loaded_version(), PINNED_MUJOCO_VERSION);
        assert_eq!(loaded_version_string(), "3.17.0");
        check_version().unwrap();
    }

    #[test]
    fn pendulum_swings_with_the_period_physics_predicts() {
        let model = load_model_str(PENDULUM).unwrap();
        let s = sizes(&model);
        assert_eq!((s.nq, s.nv, s.nu, s.njnt), (1, 1, 0, 1));
        assert_eq!(joint_names(&model), ["hinge"]);
        let mut data: MjData<&MjModel> = model.make_data();
        // Small release angle: a point mass at L swings with period 2π·sqrt(L/g).
        data.qpos_mut()[0] = 0.05;
        let mut crossings = Vec::new();
        let mut prev = data.qpos()[0];
        while data.time() < 3.0 {
            data.step();
            let q = data.qpos()[0];
            if prev > 0.0 && q <= 0.0 {
                crossings.push(data.time());
            }
            prev = q;
        }
        let period = crossings[1] - crossings[0];
        let expected = 2.0 * std::f64::consts::PI * (0.5 / 9.81_f64).sqrt();
        assert!((period - expected).abs() < 0.01, "period {period} vs {expected}");
    }

    #[test]
    fn malformed_model_is_a_clear_error() {
        let err =
            load_model_str("<mujoco><worldbody><body><joint type=\"bogus\"/></body></worldbody></mujoco>")
                .unwrap_err();
        assert!(
            err.to_string().contains("cannot load MJCF model <inline>"),
            "{err}"
        );
    }
}
