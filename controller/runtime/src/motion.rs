//! The reference motion's anchor and the motion a tracking export carries.
//!
//! A motion-tracking policy observes the reference relative to the robot through one body, the
//! anchor (`motion_anchor_pos_b`, `motion_anchor_ori_b`). When a run starts, the reference is
//! moved so its first anchor frame lies on the robot's anchor, in heading and on the floor
//! ([`Alignment`]); every later reference pose gets the same transform.
//!
//! BeyondMimic and mjlab exports bake the motion into the ONNX graph: with input `time_step`, the
//! outputs `joint_pos`, `joint_vel` [1, J], `body_pos_w` [1, B, 3], `body_quat_w` [1, B, 4]
//! (w x y z) are the motion's frame `min(time_step, T − 1)`. holosoma's whole-body-tracking
//! exports return the anchor alone: `ref_pos_xyz` [1, 3], `ref_quat_xyzw` [1, 4] (x y z w). [`EmbeddedMotion`] finds those
//! outputs, reads the whole motion out once before anything moves (for checks, the clip's length
//! and the frames a policy looks ahead), and gives each tick the frame its call returned.

use robots::{Robot, spatial};

use crate::clip::Reference;
use policy::onnx::OnnxModel;
use policy::{PolicyLayout, Term};

/// Why the motion a tracking export carries could not be found or read.
#[derive(Debug, thiserror::Error)]
pub enum MotionError {
    /// The export's outputs or the policy's terms do not hold a motion as its convention says
    /// (the message names the export, the output and what was expected).
    #[error("{0}")]
    Export(String),
    /// ONNX Runtime failed on a call.
    #[error(transparent)]
    Onnx(#[from] policy::onnx::OnnxError),
    /// The robot's model could not place the motion's root.
    #[error(transparent)]
    Kinematics(#[from] world::KinematicsError),
}

/// The transform that puts a reference onto the robot: a turn about the vertical through the
/// reference's first anchor position, then a horizontal shift.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Alignment {
    turn: [f64; 4],
    from: [f64; 3],
    to: [f64; 3],
}

impl Default for Alignment {
    fn default() -> Self {
        Self {
            turn: [1.0, 0.0, 0.0, 0.0],
            from: [0.0; 3],
            to: [0.0; 3],
        }
    }
}

impl Alignment {
    /// Moves the reference anchor's first pose `first` onto the robot's anchor `robot`: the same
    /// heading (yaw only: the reference keeps its own lean), and, when the robot's position is
    /// known, the same horizontal position. The height is kept: robot and reference stand on the
    /// same floor, and moving the reference by the robot's standing height would bake a crouch
    /// into the whole motion.
    pub fn new(first: [f64; 7], robot: [f64; 7], robot_position_known: bool) -> Self {
        let heading = |p: [f64; 7]| spatial::heading_of_quat([p[3], p[4], p[5], p[6]]);
        let turn = spatial::quat_of_rpy(0.0, 0.0, heading(robot) - heading(first));
        let from = [first[0], first[1], first[2]];
        let to = if robot_position_known {
            [robot[0], robot[1], first[2]]
        } else {
            from
        };
        Self { turn, from, to }
    }

    /// A world vector (a velocity) of the reference turned with it.
    pub fn turn_vector(&self, v: [f64; 3]) -> [f64; 3] {
        spatial::quat_rotate(self.turn, v)
    }

    /// The heading change, rad.
    pub fn yaw(&self) -> f64 {
        spatial::heading_of_quat(self.turn)
    }

    /// A point of the robot's world back in the reference's own frame (the inverse of
    /// [`Self::apply`] for positions).
    pub fn undo_point(&self, p: [f64; 3]) -> [f64; 3] {
        spatial::add(
            spatial::quat_rotate(spatial::quat_conj(self.turn), spatial::sub(p, self.to)),
            self.from,
        )
    }

    /// A pose of the robot's world back in the reference's own frame (the inverse of
    /// [`Self::apply`]).
    pub fn undo(&self, pose: [f64; 7]) -> [f64; 7] {
        let p = self.undo_point([pose[0], pose[1], pose[2]]);
        let q = spatial::quat_mul(
            spatial::quat_conj(self.turn),
            [pose[3], pose[4], pose[5], pose[6]],
        );
        [p[0], p[1], p[2], q[0], q[1], q[2], q[3]]
    }

    /// `pose` moved with the reference.
    pub fn apply(&self, pose: [f64; 7]) -> [f64; 7] {
        let p = spatial::add(
            spatial::quat_rotate(self.turn, spatial::sub([pose[0], pose[1], pose[2]], self.from)),
            self.to,
        );
        let q = spatial::quat_mul(self.turn, [pose[3], pose[4], pose[5], pose[6]]);
        [p[0], p[1], p[2], q[0], q[1], q[2], q[3]]
    }
}

/// How a tracking export carries its motion: its output names, quaternion order and which frame
/// each call is given.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MotionConvention {
    /// BeyondMimic and mjlab: every tracked body, w x y z; the call gets the frame the next tick
    /// plays.
    BeyondMimic,
    /// holosoma: the anchor body only, x y z w; the call gets the frame this tick plays, so the
    /// observation sees each frame one tick later (as holosoma's deployment code does).
    Holosoma,
}

impl MotionConvention {
    /// Output names: joint positions, joint velocities, body positions, body orientations.
    pub fn outputs(self) -> [&'static str; 4] {
        match self {
            Self::BeyondMimic => ["joint_pos", "joint_vel", "body_pos_w", "body_quat_w"],
            Self::Holosoma => ["joint_pos", "joint_vel", "ref_pos_xyz", "ref_quat_xyzw"],
        }
    }

    /// The convention whose body outputs `names` has (BeyondMimic's when neither's are there).
    fn of(names: &[&str]) -> Self {
        let holosoma = Self::Holosoma.outputs();
        if names.iter().any(|n| holosoma[2..].contains(n)) {
            Self::Holosoma
        } else {
            Self::BeyondMimic
        }
    }

    /// The model's output shapes for `j` joints and `b` bodies.
    fn shapes(self, j: usize, b: usize) -> [Vec<i64>; 4] {
        let (j, b) = (j as i64, b as i64);
        match self {
            Self::BeyondMimic => [vec![1, j], vec![1, j], vec![1, b, 3], vec![1, b, 4]],
            Self::Holosoma => [vec![1, j], vec![1, j], vec![1, 3], vec![1, 4]],
        }
    }
}

/// How far from 1 the norm of a motion's quaternion may be (float32 tables).
const UNIT_TOLERANCE: f64 = 1e-3;

/// Most frames an embedded motion may have (6 hours at 50 Hz).
pub const MAX_FRAMES: usize = 1 << 20;

/// One frame as a call returned it, joints in policy order.
#[derive(Debug, Clone, Copy)]
pub struct MotionFrame<'a> {
    /// Joint positions.
    pub joint_pos: &'a [f32],
    /// Joint velocities.
    pub joint_vel: &'a [f32],
    /// Body positions, 3 per body.
    pub body_pos: &'a [f32],
    /// Body orientations, 4 per body (w x y z, or x y z w when `xyzw`).
    pub body_quat: &'a [f32],
    /// The quaternions are x y z w (holosoma).
    pub xyzw: bool,
}

impl MotionFrame<'_> {
    /// Pose of body `b`, `[x, y, z, w, qx, qy, qz]`.
    pub fn body_pose(&self, b: usize) -> [f64; 7] {
        let p = &self.body_pos[3 * b..3 * b + 3];
        let q = &self.body_quat[4 * b..4 * b + 4];
        let wxyz = if self.xyzw {
            [q[3], q[0], q[1], q[2]]
        } else {
            [q[0], q[1], q[2], q[3]]
        };
        let q = spatial::quat_normalize(wxyz.map(f64::from));
        [
            f64::from(p[0]),
            f64::from(p[1]),
            f64::from(p[2]),
            q[0],
            q[1],
            q[2],
            q[3],
        ]
    }
}

/// The motion an export carries, and where its frames come out of the model.
#[derive(Debug, Clone)]
pub struct EmbeddedMotion {
    /// Which export convention it follows.
    pub convention: MotionConvention,
    /// Extra-output indices of the joint positions, velocities, body positions, orientations.
    outputs: [usize; 4],
    /// Bodies per frame.
    pub bodies: usize,
    /// Frames of the motion.
    pub frames: usize,
    /// The frame the run starts from.
    pub start_step: usize,
    /// Index of the `time_step` value in the model's concatenated inputs.
    time_step_at: usize,
    obs: Vec<f32>,
    actions: Vec<f32>,
}

impl EmbeddedMotion {
    /// The motion `model` carries, if it has the four motion outputs (checked against `layout`'s
    /// joints and motion bodies, its `time_step` term bound). `start_step`: where runs start.
    pub fn find(
        model: &mut OnnxModel,
        layout: &PolicyLayout,
        start_step: usize,
    ) -> Result<Option<Self>, MotionError> {
        let names: Vec<&str> = model.extra_outputs().iter().map(|o| o.0.as_str()).collect();
        let convention = MotionConvention::of(&names);
        let wanted = convention.outputs();
        let present: Vec<Option<usize>> = wanted.iter().map(|o| names.iter().position(|n| n == o)).collect();
        if present.iter().all(Option::is_none) {
            if start_step != 0 {
                return Err(MotionError::Export(format!(
                    "--start-step {start_step}: {} carries no motion",
                    layout.onnx_path.display()
                )));
            }
            return Ok(None);
        }
        let mut outputs = [0; 4];
        for (k, p) in present.iter().enumerate() {
            outputs[k] = p.ok_or_else(|| {
                MotionError::Export(format!(
                    "{} has motion outputs but not {:?} (a tracking export has {})",
                    layout.onnx_path.display(),
                    wanted[k],
                    wanted.join(", ")
                ))
            })?;
        }
        let shape = |k: usize| &model.extra_outputs()[outputs[k]].1;
        let j = layout.robot_index.len();
        let b = layout.manifest.motion_bodies.len();
        if convention == MotionConvention::Holosoma && b != 1 {
            return Err(MotionError::Export(format!(
                "{}: a holosoma export returns one body's pose (the anchor), but the policy names {b} motion \
                 bodies",
                layout.onnx_path.display()
            )));
        }
        let expect = convention.shapes(j, b);
        for (k, want) in expect.iter().enumerate() {
            if shape(k) != want {
                return Err(MotionError::Export(format!(
                    "{}: output {} has shape {:?}, but the policy has {j} joints and {b} motion bodies \
                     (body_names) so {want:?} is expected",
                    layout.onnx_path.display(),
                    wanted[k],
                    shape(k)
                )));
            }
        }
        let time_step_at = layout
            .slots
            .iter()
            .find(|s| matches!(s.term, Term::TimeStep(_)))
            .map(|s| s.range.start)
            .ok_or_else(|| {
                MotionError::Export(format!(
                    "{} carries a motion but the policy has no time_step term to choose its frame",
                    layout.onnx_path.display()
                ))
            })?;
        let mut motion = Self {
            convention,
            outputs,
            bodies: b,
            frames: 0,
            start_step,
            time_step_at,
            obs: vec![0.0; layout.obs_len],
            actions: vec![0.0; model.output().1],
        };
        motion.frames = motion.count_frames(model)?;
        if start_step >= motion.frames {
            return Err(MotionError::Export(format!(
                "--start-step {start_step}: the motion {} carries has {} frames",
                layout.onnx_path.display(),
                motion.frames
            )));
        }
        Ok(Some(motion))
    }

    /// Runs the model on a zero observation for frame `step`; its outputs then hold that frame.
    pub fn seek(&mut self, model: &mut OnnxModel, step: usize) -> Result<(), MotionError> {
        self.obs.fill(0.0);
        self.obs[self.time_step_at] = step as f32;
        Ok(model.run(&self.obs, &mut self.actions)?)
    }

    /// The frame the last call of `model` returned.
    pub fn frame<'a>(&self, model: &'a OnnxModel) -> MotionFrame<'a> {
        MotionFrame {
            joint_pos: model.extra_output(self.outputs[0]),
            joint_vel: model.extra_output(self.outputs[1]),
            body_pos: model.extra_output(self.outputs[2]),
            body_quat: model.extra_output(self.outputs[3]),
            xyzw: self.convention == MotionConvention::Holosoma,
        }
    }

    fn snapshot(&mut self, model: &mut OnnxModel, step: usize) -> Result<Vec<f32>, MotionError> {
        self.seek(model, step)?;
        let f = self.frame(model);
        Ok([f.joint_pos, f.joint_vel, f.body_pos, f.body_quat].concat())
    }

    /// The motion's length `T`: the graph returns frame `min(time_step, T − 1)`, so `T − 1` is
    /// the first step from which every later step returns the same frame (found by bisection
    /// against a step far beyond any motion). A motion that ends on a frame held exactly still
    /// counts that hold once: the frames it drops are identical to the last.
    fn count_frames(&mut self, model: &mut OnnxModel) -> Result<usize, MotionError> {
        let last = self.snapshot(model, MAX_FRAMES)?;
        let (mut lo, mut hi) = (0usize, MAX_FRAMES);
        if self.snapshot(model, 0)? == last {
            return Ok(1);
        }
        // Invariant: frame lo differs from the last, frame hi equals it.
        while hi - lo > 1 {
            let mid = lo + (hi - lo) / 2;
            if self.snapshot(model, mid)? == last {
                hi = mid;
            } else {
                lo = mid;
            }
        }
        if hi >= MAX_FRAMES {
            return Err(MotionError::Export(format!(
                "the embedded motion is longer than {MAX_FRAMES} frames"
            )));
        }
        Ok(hi + 1)
    }

    /// Reads the motion out from `start_step` to its end as a reference at the policy's rate
    /// (joints in robot order; the root is the robot's root body where the export tracks it,
    /// else the anchor), then seeks back to `start_step`.
    pub fn read(
        &mut self,
        model: &mut OnnxModel,
        layout: &PolicyLayout,
        robot: &Robot,
    ) -> Result<Reference, MotionError> {
        let n = robot.config.joints.len();
        let ticks = self.frames - self.start_step;
        let bodies = &layout.manifest.motion_bodies;
        let root_body = bodies
            .iter()
            .position(|b| *b == robot.config.root_body)
            .or_else(|| {
                layout
                    .manifest
                    .anchor_body
                    .as_ref()
                    .and_then(|a| bodies.iter().position(|b| b == a))
            })
            .unwrap_or(0);
        let mut reference = Reference {
            n,
            rate_hz: layout.manifest.rate_hz,
            q: Vec::with_capacity(ticks * n),
            qd: Vec::with_capacity(ticks * n),
            root: Vec::with_capacity(ticks),
            root_lin_vel: Vec::new(),
            root_ang_vel: Vec::new(),
            held_joints: Vec::new(),
            bodies: Vec::new(),
            body_pos: Vec::new(),
            motion_bodies: bodies.clone(),
            live_bodies: Vec::new(),
            motion_poses: Vec::with_capacity(ticks * bodies.len()),
            anchor: layout
                .manifest
                .anchor_body
                .as_ref()
                .and_then(|a| bodies.iter().position(|b| b == a)),
            keypoints: None,
        };
        let mut q = vec![0.0; n];
        let mut qd = vec![0.0; n];
        for step in self.start_step..self.frames {
            self.seek(model, step)?;
            let f = self.frame(model);
            for (p, &r) in layout.robot_index.iter().enumerate() {
                q[r] = f64::from(f.joint_pos[p]);
                qd[r] = f64::from(f.joint_vel[p]);
            }
            if let Some(bad) = q.iter().chain(&qd).position(|v| !v.is_finite()) {
                return Err(MotionError::Export(format!(
                    "frame {step} of the embedded motion has a non-finite joint value ({bad})"
                )));
            }
            for (b, name) in bodies.iter().enumerate() {
                let q = &f.body_quat[4 * b..4 * b + 4];
                let norm = q.iter().map(|v| f64::from(*v).powi(2)).sum::<f64>().sqrt();
                if !((1.0 - UNIT_TOLERANCE)..=(1.0 + UNIT_TOLERANCE)).contains(&norm) {
                    return Err(MotionError::Export(format!(
                        "frame {step} of the embedded motion: body {name}'s {} {q:?} has norm {norm:.4}, \
                         not a unit quaternion",
                        self.convention.outputs()[3]
                    )));
                }
                let pose = f.body_pose(b);
                if pose.iter().any(|v| !v.is_finite()) {
                    return Err(MotionError::Export(format!(
                        "frame {step} of the embedded motion: body {name} has a non-finite or zero pose"
                    )));
                }
                reference.motion_poses.push(pose);
            }
            reference.q.extend_from_slice(&q);
            reference.qd.extend_from_slice(&qd);
            reference.root.push(f.body_pose(root_body));
        }
        if !bodies.contains(&robot.config.root_body)
            && let Some(a) = reference.anchor
        {
            // The export does not say where the root is: it follows from the anchor's pose and
            // the joints, through the robot's model.
            let anchor: Vec<[f64; 7]> = reference
                .motion_poses
                .iter()
                .skip(a)
                .step_by(bodies.len())
                .copied()
                .collect();
            reference.root = crate::fk::root_poses_from_body(robot, &reference, &bodies[a], &anchor)?;
        }
        if let Some(m) = reference.root.first().and_then(|r| crate::clip::upside_down(*r)) {
            return Err(MotionError::Export(format!(
                "the motion {} carries: {m}",
                layout.onnx_path.display()
            )));
        }
        (reference.root_lin_vel, reference.root_ang_vel) =
            crate::clip::tick_root_velocities(&reference.root, reference.rate_hz);
        self.seek(model, self.start_step)?;
        Ok(reference)
    }

    /// The `time_step` value of a tick's call, given the frame this tick plays and the frame the
    /// next one plays (counted from the start step): the convention says which it asks for.
    pub fn time_step(&self, this: usize, next: usize) -> f64 {
        let k = match self.convention {
            MotionConvention::BeyondMimic => next,
            MotionConvention::Holosoma => this,
        };
        (self.start_step + k) as f64
    }
}

/// How far a motion's body may lie from where the robot's model puts it at the motion's root
/// pose and joint positions, m.
pub const MODEL_MISMATCH_M: f64 = 0.05;

/// The motion body farthest from where the robot's model puts it, given the motion's own root
/// pose and joint positions: `(body, distance m, frame)`; None without motion bodies. The
/// frameworks computed their body poses with the same kinematics, so a large distance means the
/// motion was read wrong.
pub fn worst_body_mismatch(
    robot: &Robot,
    reference: &Reference,
) -> Result<Option<(String, f64, usize)>, world::KinematicsError> {
    let bodies = &reference.motion_bodies;
    // The model is posed from the motion's root: only a motion that tracks the root body says
    // where that is.
    if !bodies.contains(&robot.config.root_body) {
        return Ok(None);
    }
    let model = crate::fk::body_poses(robot, reference, bodies)?;
    let mut worst: Option<(String, f64, usize)> = None;
    for (k, (m, r)) in model.iter().zip(&reference.motion_poses).enumerate() {
        let d = spatial::norm(spatial::sub([m[0], m[1], m[2]], [r[0], r[1], r[2]]));
        if worst.as_ref().is_none_or(|w| d > w.1) {
            worst = Some((bodies[k % bodies.len()].clone(), d, k / bodies.len()));
        }
    }
    Ok(worst)
}

#[cfg(test)]
mod tests {
    use super::*;

    const H: f64 = std::f64::consts::FRAC_1_SQRT_2;

    #[test]
    fn the_first_anchor_frame_lands_on_the_robot_in_heading_and_on_the_floor() {
        // Reference anchor at (2, 0, 0.8) facing +x; robot anchor at (0, 1, 0.7) facing +y.
        let first = [2.0, 0.0, 0.8, 1.0, 0.0, 0.0, 0.0];
        let robot = [0.0, 1.0, 0.7, H, 0.0, 0.0, H];
        let a = Alignment::new(first, robot, true);
        let moved = a.apply(first);
        assert!(
            (moved[0]).abs() < 1e-12 && (moved[1] - 1.0).abs() < 1e-12,
            "{moved:?}"
        );
        assert!((moved[2] - 0.8).abs() < 1e-12, "height kept: {moved:?}");
        assert!((a.yaw() - std::f64::consts::FRAC_PI_2).abs() < 1e-12);
        // A later frame 1 m ahead of the first (along +x) ends up 1 m along the robot's +y.
        let later = a.apply([3.0, 0.0, 0.8, 1.0, 0.0, 0.0, 0.0]);
        assert!(
            (later[0]).abs() < 1e-12 && (later[1] - 2.0).abs() < 1e-12,
            "{later:?}"
        );
        // Its orientation turned with it.
        assert!((spatial::heading_of_quat([later[3], later[4], later[5], later[6]]) - a.yaw()).abs() < 1e-12);
    }
}
