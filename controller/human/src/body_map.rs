//! The human side of calibration. The retargeting map of ReActor (Müller et al. 2026, eqs. 8–13):
//! a global scale from root heights and, per body pair, the nominal offset of the scaled source
//! frame from the target frame in the nominal pose (e.g. a T-pose), with small tuning parameters.
//! And a VR user's device-to-joint offsets, measured once in a T-pose, so headsets and controllers
//! of any size and grip stand for the same body joints.

use robots::HumanBody;
use robots::spatial::{self, Mat3};

use crate::HumanError;

/// A rigid frame: position and orientation (world, or a heading frame).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Frame {
    /// Position, m.
    pub pos: [f64; 3],
    /// Orientation.
    pub rot: Mat3,
}

/// The number of [`HumanBody`] kinds.
pub const HUMAN_BODIES: usize = 15;

/// Where a source sees each human body: frames in its world (x forward, y left, z up, m; the
/// floor at z = 0), `None` where it sees none. Indexed by `HumanBody as usize`.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct HumanPose {
    /// Per body kind.
    pub bodies: [Option<Frame>; HUMAN_BODIES],
}

impl HumanPose {
    /// Body `b`'s frame, if seen.
    pub fn get(&self, b: HumanBody) -> Option<&Frame> {
        self.bodies[b as usize].as_ref()
    }

    /// Sets body `b`'s frame.
    pub fn set(&mut self, b: HumanBody, frame: Frame) {
        self.bodies[b as usize] = Some(frame);
    }
}

/// The tuning parameters of one body pair (local nominal coordinates).
#[derive(Debug, Clone, Copy, PartialEq, Default, serde::Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct PairParams {
    /// Position shift, m (|p_pos| ≤ 0.5).
    pub p_pos: [f64; 3],
    /// Orientation shift, rotation vector, rad (|p_ori| ≤ 0.5).
    pub p_ori: [f64; 3],
}

/// One body pair's map.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PairMap {
    /// `x_nom = R_srcᵀ (x_tgt − s·x_src)` in the nominal pose.
    pub x_nom: [f64; 3],
    /// `R_nom = R_srcᵀ R_tgt` in the nominal pose.
    pub r_nom: Mat3,
    /// Tuning.
    pub params: PairParams,
}

/// The map from a source body (human, tracker) to the target (robot), for every pair.
#[derive(Debug, Clone, PartialEq)]
pub struct RetargetMap {
    /// `s = h_target / h_source`.
    pub scale: f64,
    /// Vertical shift `z_nom + p_z`, m.
    pub z_shift: f64,
    /// Per pair.
    pub pairs: Vec<PairMap>,
}

impl RetargetMap {
    /// The map from the nominal pose: root heights `h_source`, `h_target`, and each pair's source and
    /// target frames in that pose (same order as `params`).
    pub fn nominal(
        h_source: f64,
        h_target: f64,
        source: &[Frame],
        target: &[Frame],
        params: &[PairParams],
        z_shift: f64,
    ) -> Result<Self, HumanError> {
        if !(h_source.is_finite() && h_source > 0.0 && h_target.is_finite() && h_target > 0.0) {
            return Err(HumanError::map(format!(
                "root heights must be positive: source {h_source} m, target {h_target} m"
            )));
        }
        if source.len() != target.len() || source.len() != params.len() {
            return Err(HumanError::map(
                "one source frame, one target frame and one parameter set per pair",
            ));
        }
        for (k, p) in params.iter().enumerate() {
            if spatial::norm(p.p_pos) > 0.5 || spatial::norm(p.p_ori) > 0.5 {
                return Err(HumanError::map(format!(
                    "pair {k}: |p_pos| and |p_ori| must be ≤ 0.5"
                )));
            }
        }
        let scale = h_target / h_source;
        let pairs = source
            .iter()
            .zip(target)
            .zip(params)
            .map(|((s, t), &params)| {
                let rt = spatial::transpose(&s.rot);
                PairMap {
                    x_nom: spatial::mat_apply(&rt, spatial::sub(t.pos, spatial::scale(s.pos, scale))),
                    r_nom: spatial::mat_mul(&rt, &t.rot),
                    params,
                }
            })
            .collect();
        Ok(Self {
            scale,
            z_shift,
            pairs,
        })
    }

    /// Where pair `b`'s target frame goes when its source frame is `m` (eqs. 10 and 11).
    pub fn map(&self, b: usize, m: &Frame) -> Frame {
        let p = &self.pairs[b];
        let local = spatial::add(spatial::mat_apply(&p.r_nom, p.params.p_pos), p.x_nom);
        let mut pos = spatial::add(
            spatial::mat_apply(&m.rot, local),
            spatial::scale(m.pos, self.scale),
        );
        pos[2] += self.z_shift;
        Frame {
            pos,
            rot: spatial::mat_mul(&spatial::mat_mul(&m.rot, &p.r_nom), &spatial::exp(p.params.p_ori)),
        }
    }

    /// Pair `b`'s target velocity and angular velocity for a source moving at `v`, `w` (eqs. 12, 13).
    pub fn map_velocity(&self, b: usize, m: &Frame, v: [f64; 3], w: [f64; 3]) -> ([f64; 3], [f64; 3]) {
        let p = &self.pairs[b];
        let lever = spatial::mat_apply(
            &m.rot,
            spatial::add(spatial::mat_apply(&p.r_nom, p.params.p_pos), p.x_nom),
        );
        (
            spatial::add(spatial::cross(w, lever), spatial::scale(v, self.scale)),
            w,
        )
    }
}

/// The offset of a body joint from the device that stands for it, in the device's frame.
pub fn device_offset(device: &Frame, joint: [f64; 3]) -> [f64; 3] {
    spatial::mat_apply(&spatial::transpose(&device.rot), spatial::sub(joint, device.pos))
}

/// Where the joint is, given its device and the offset measured in the T-pose.
pub fn joint_from_device(device: &Frame, offset: [f64; 3]) -> [f64; 3] {
    spatial::add(device.pos, spatial::mat_apply(&device.rot, offset))
}

/// Body proportions of a standing adult, as fractions of stature (anthropometric averages): what a
/// T-pose calibration assumes about where joints sit relative to the devices.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Template {
    /// Eye height / stature.
    pub eye_height: f64,
    /// Head joint (skull base) behind and below the eyes, / stature: (forward, up).
    pub head_from_eyes: [f64; 2],
    /// Controller grip beyond the wrist along the arm, / stature.
    pub grip_beyond_wrist: f64,
}

impl Default for Template {
    fn default() -> Self {
        Self {
            eye_height: 0.936,
            head_from_eyes: [-0.05, -0.04],
            grip_beyond_wrist: 0.05,
        }
    }
}

/// A VR user's T-pose calibration: stature, and each device's offset to its joint.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct UserCalibration {
    /// Estimated stature, m.
    pub stature: f64,
    /// Headset → head joint, in the headset's frame.
    pub head: [f64; 3],
    /// Left controller → left wrist.
    pub left: [f64; 3],
    /// Right controller → right wrist.
    pub right: [f64; 3],
}

impl UserCalibration {
    /// From the devices' poses (robot axes: x forward, z up) while the user stands in a T-pose:
    /// stature from the headset's height, the head joint behind and below the eyes, each wrist
    /// short of its controller along the outstretched arm.
    pub fn from_tpose(
        hmd: &Frame,
        left: &Frame,
        right: &Frame,
        template: &Template,
    ) -> Result<Self, HumanError> {
        let stature = hmd.pos[2] / template.eye_height;
        if !(1.0..=2.3).contains(&stature) {
            return Err(HumanError::Calibration(format!(
                "a headset {:.2} m above the floor is not a standing adult (stature {stature:.2} m): stand up straight for the T-pose",
                hmd.pos[2]
            )));
        }
        let heading = spatial::yaw(spatial::heading(&hmd.rot));
        let [fwd, up] = template.head_from_eyes;
        let head = spatial::add(
            hmd.pos,
            spatial::mat_apply(&heading, [fwd * stature, 0.0, up * stature]),
        );
        let span = spatial::norm(spatial::sub(left.pos, right.pos));
        if span < 0.8 * stature {
            return Err(HumanError::Calibration(format!(
                "controllers {span:.2} m apart: hold both arms straight out to the sides for the T-pose"
            )));
        }
        let wrist = |c: &Frame| {
            let mut out = spatial::sub(c.pos, head);
            out[2] = 0.0;
            spatial::sub(
                c.pos,
                spatial::scale(spatial::unit(out), template.grip_beyond_wrist * stature),
            )
        };
        Ok(Self {
            stature,
            head: device_offset(hmd, head),
            left: device_offset(left, wrist(left)),
            right: device_offset(right, wrist(right)),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn close(a: [f64; 3], b: [f64; 3]) -> bool {
        spatial::norm(spatial::sub(a, b)) < 1e-9
    }

    #[test]
    fn the_nominal_pose_maps_onto_the_target_and_motion_scales() {
        let src = [
            Frame {
                pos: [0.0, 0.0, 1.0],
                rot: spatial::IDENTITY,
            },
            Frame {
                pos: [0.1, 0.8, 1.4],
                rot: spatial::exp([0.0, 0.0, 0.3]),
            },
        ];
        let tgt = [
            Frame {
                pos: [0.0, 0.0, 0.5],
                rot: spatial::exp([0.1, 0.0, 0.0]),
            },
            Frame {
                pos: [0.02, 0.3, 0.66],
                rot: spatial::IDENTITY,
            },
        ];
        let params = [PairParams::default(); 2];
        let map = RetargetMap::nominal(1.0, 0.5, &src, &tgt, &params, 0.0).unwrap();
        assert_eq!(map.scale, 0.5);
        for b in 0..2 {
            let g = map.map(b, &src[b]);
            assert!(close(g.pos, tgt[b].pos), "pair {b}: {:?}", g.pos);
            assert!(
                spatial::norm(spatial::log(&spatial::mat_mul(
                    &spatial::transpose(&g.rot),
                    &tgt[b].rot
                ))) < 1e-9
            );
        }
        // The source root walks 1 m forward: the target root goes 0.5 m.
        let moved = Frame {
            pos: [1.0, 0.0, 1.0],
            rot: spatial::IDENTITY,
        };
        assert!(close(map.map(0, &moved).pos, [0.5, 0.0, 0.5]));
        // Turning in place swings the nominal offset around (eq. 12's lever arm).
        let (v, w) = map.map_velocity(1, &src[1], [0.0; 3], [0.0, 0.0, 1.0]);
        assert_eq!(w, [0.0, 0.0, 1.0]);
        let lever = spatial::sub(map.map(1, &src[1]).pos, spatial::scale(src[1].pos, 0.5));
        assert!(close(v, spatial::cross([0.0, 0.0, 1.0], lever)));
        // Tuning parameters are bounded.
        let big = [PairParams {
            p_pos: [0.6, 0.0, 0.0],
            p_ori: [0.0; 3],
        }; 2];
        assert!(RetargetMap::nominal(1.0, 0.5, &src, &tgt, &big, 0.0).is_err());
    }

    #[test]
    fn tpose_offsets_put_the_joints_back_under_the_devices() {
        let t = Template::default();
        let stature = 1.70;
        // Devices as a user of 1.70 m holds them, facing +y.
        let face = spatial::yaw(std::f64::consts::FRAC_PI_2);
        let hmd = Frame {
            pos: [0.0, 0.0, t.eye_height * stature],
            rot: face,
        };
        let left = Frame {
            pos: [-0.85, 0.0, 1.40],
            rot: spatial::exp([0.2, 0.1, 0.0]),
        };
        let right = Frame {
            pos: [0.85, 0.0, 1.40],
            rot: spatial::IDENTITY,
        };
        let cal = UserCalibration::from_tpose(&hmd, &left, &right, &t).unwrap();
        assert!((cal.stature - stature).abs() < 1e-9);
        // The wrists sit inside the controllers, towards the body.
        let lw = joint_from_device(&left, cal.left);
        let grip = spatial::norm(spatial::sub(lw, left.pos));
        assert!(
            (grip - t.grip_beyond_wrist * stature).abs() < 1e-9 && lw[0] > -0.85,
            "{lw:?}"
        );
        // The head joint is behind the eyes (the user faces +y, so behind is −y).
        let head = joint_from_device(&hmd, cal.head);
        assert!(head[1] < 0.0 && head[2] < hmd.pos[2]);
        // Sitting on the floor, or arms down, is refused.
        let low = Frame {
            pos: [0.0, 0.0, 0.5],
            rot: face,
        };
        assert!(UserCalibration::from_tpose(&low, &left, &right, &t).is_err());
        let down = Frame {
            pos: [-0.2, 0.0, 0.9],
            rot: spatial::IDENTITY,
        };
        assert!(
            UserCalibration::from_tpose(&hmd, &down, &right, &t)
                .unwrap_err()
                .to_string()
                .contains("arms straight")
        );
    }
}
