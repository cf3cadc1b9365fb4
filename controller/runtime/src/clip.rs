//! A clip resampled to the control rate, in the robot's joint order, ready to track: mapped to
//! the robot's joints by name (linear for joints, slerp for the root rotation), with velocities by
//! the policy's rule, and checked against the robot's limits before anything moves. The motion
//! files themselves are read by the `motion` crate (re-exported here).

pub use ::motion::clip::*;
use policy::VelocityRule;
use robots::Robot;

/// How far beyond a joint's limit a clip's angle may lie and count as on it (floating-point
/// rounding of a retargeter that clamps to the limits), rad.
pub const LIMIT_ROUNDING: f64 = 1e-9;

/// A clip resampled to the control rate, in the robot's joint order, ready to track.
#[derive(Debug, Clone, PartialEq)]
pub struct Reference {
    /// Joints.
    pub n: usize,
    /// Control rate, Hz.
    pub rate_hz: f64,
    /// Joint positions per tick, `n` per tick.
    pub q: Vec<f64>,
    /// Joint velocities per tick.
    pub qd: Vec<f64>,
    /// Root poses per tick.
    pub root: Vec<[f64; 7]>,
    /// The root's linear velocity per tick, world frame, m/s.
    pub root_lin_vel: Vec<[f64; 3]>,
    /// The root's angular velocity per tick, world frame, rad/s.
    pub root_ang_vel: Vec<[f64; 3]>,
    /// Robot joints the clip does not name (held at the default pose).
    pub held_joints: Vec<String>,
    /// Bodies whose positions [`Self::body_pos`] holds (filled when a policy asks for them).
    pub bodies: Vec<String>,
    /// Body positions per tick relative to the reference root in its heading frame, 3 per body.
    pub body_pos: Vec<f64>,
    /// Bodies the motion tracks (a tracking policy's `body_names`), whose world poses
    /// [`Self::motion_poses`] holds.
    pub motion_bodies: Vec<String>,
    /// World poses `[x, y, z, w, qx, qy, qz]` of the motion bodies, per tick.
    pub motion_poses: Vec<[f64; 7]>,
    /// Which motion body is the anchor.
    pub anchor: Option<usize>,
    /// Robot frames a live source places on its operator (a whole-body teleoperation's key
    /// bodies), measured against the robot's own in its root's frame each tick.
    pub live_bodies: Vec<String>,
    /// 2D keypoint references beside the joints (Mimic2DM), at the same ticks.
    pub keypoints: Option<crate::keypoints::track::KeypointReference>,
}

impl Reference {
    /// Ticks.
    pub fn len(&self) -> usize {
        self.root.len()
    }

    /// Whether it has no ticks.
    pub fn is_empty(&self) -> bool {
        self.root.is_empty()
    }

    /// Joint positions at tick `k` (clamped to the last).
    pub fn q_at(&self, k: usize) -> &[f64] {
        let k = k.min(self.len() - 1);
        &self.q[k * self.n..(k + 1) * self.n]
    }

    /// World poses of the motion bodies at tick `k` (clamped to the last).
    pub fn motion_poses_at(&self, k: usize) -> &[[f64; 7]] {
        let w = self.motion_bodies.len();
        let k = k.min(self.len() - 1);
        &self.motion_poses[k * w..(k + 1) * w]
    }

    /// Body positions at tick `k` (clamped to the last), 3 per body of [`Self::bodies`].
    pub fn body_pos_at(&self, k: usize) -> &[f64] {
        let w = 3 * self.bodies.len();
        let k = k.min(self.len() - 1);
        &self.body_pos[k * w..(k + 1) * w]
    }

    /// Joint velocities at tick `k` (clamped to the last).
    pub fn qd_at(&self, k: usize) -> &[f64] {
        let k = k.min(self.len() - 1);
        &self.qd[k * self.n..(k + 1) * self.n]
    }

    /// A one-frame reference holding `q` (robot order) at `root`: the frame a live source
    /// overwrites every tick.
    pub fn hold(q: &[f64], root: [f64; 7], rate_hz: f64) -> Self {
        Self {
            n: q.len(),
            rate_hz,
            q: q.to_vec(),
            qd: vec![0.0; q.len()],
            root: vec![root],
            root_lin_vel: vec![[0.0; 3]],
            root_ang_vel: vec![[0.0; 3]],
            held_joints: Vec::new(),
            bodies: Vec::new(),
            body_pos: Vec::new(),
            motion_bodies: Vec::new(),
            live_bodies: Vec::new(),
            motion_poses: Vec::new(),
            anchor: None,
            keypoints: None,
        }
    }

    /// Maps `clip` onto `robot` and resamples it to `rate_hz`, velocities by central
    /// differences over the resampled ticks; refuses a clip the robot cannot follow, naming the
    /// first offending frame.
    pub fn from_clip(clip: &Clip, robot: &Robot, rate_hz: f64) -> Result<Self, ClipError> {
        Self::from_clip_with(clip, robot, rate_hz, VelocityRule::ControlTicks)
    }

    /// `clip` as `layout`'s policy plays it: at its rate, with its velocity rule.
    pub fn for_policy(clip: &Clip, robot: &Robot, layout: &policy::PolicyLayout) -> Result<Self, ClipError> {
        Self::from_clip_with(
            clip,
            robot,
            layout.manifest.rate_hz,
            layout.manifest.reference.velocities,
        )
    }

    /// [`Self::from_clip`] with the velocities computed by `rule`.
    pub fn from_clip_with(
        clip: &Clip,
        robot: &Robot,
        rate_hz: f64,
        rule: VelocityRule,
    ) -> Result<Self, ClipError> {
        let err = |place: String, message: String| ClipError {
            file: clip.path.clone(),
            place,
            message,
        };
        let joints = &robot.config.joints;
        let n = joints.len();
        // A motion file that names no joints holds the robot's, in its order.
        let robot_names: Vec<String>;
        let names = if clip.robot_order {
            if clip.joints.len() != n {
                return Err(err(
                    "joints".into(),
                    format!(
                        "{} joint columns and no names (no joints in {}): robot {} has {n} joints",
                        clip.joints.len(),
                        sidecar_path(&clip.path).display(),
                        robot.config.name
                    ),
                ));
            }
            robot_names = joints.iter().map(|j| j.name.clone()).collect();
            &robot_names
        } else {
            &clip.joints
        };
        for name in names {
            if !joints.iter().any(|j| &j.name == name) {
                return Err(err(
                    "header".into(),
                    format!("column {name:?} is not a joint of robot {}", robot.config.name),
                ));
            }
        }
        let column: Vec<Option<usize>> = joints
            .iter()
            .map(|j| names.iter().position(|c| c == &j.name))
            .collect();
        let held_joints = joints
            .iter()
            .zip(&column)
            .filter(|(_, c)| c.is_none())
            .map(|(j, _)| j.name.clone())
            .collect();
        let m = clip.joints.len();
        let ticks = (clip.duration() * rate_hz).floor() as usize + 1;
        let mut q = Vec::with_capacity(ticks * n);
        let mut qd = Vec::with_capacity(ticks * n);
        let mut root = Vec::with_capacity(ticks);
        let mut root_lin_vel = Vec::with_capacity(ticks);
        let mut root_ang_vel = Vec::with_capacity(ticks);
        // The motion's own velocities per frame, blended like the positions (motion_frames).
        let frame_velocities = (rule == VelocityRule::MotionFrames).then(|| clip.frame_velocities());
        let mut src = 0;
        for k in 0..ticks {
            let t = clip.times[0] + k as f64 / rate_hz;
            while src + 2 < clip.times.len() && clip.times[src + 1] <= t {
                src += 1;
            }
            let (t0, t1) = (clip.times[src], clip.times[src + 1]);
            let a = ((t - t0) / (t1 - t0)).clamp(0.0, 1.0);
            for (j, c) in joints.iter().zip(&column) {
                q.push(match c {
                    Some(c) => clip.q[src * m + c] * (1.0 - a) + clip.q[(src + 1) * m + c] * a,
                    None => j.default_position,
                });
            }
            if let Some(v) = &frame_velocities {
                let lerp3 = |x: [f64; 3], y: [f64; 3]| std::array::from_fn(|i| x[i] * (1.0 - a) + y[i] * a);
                for c in &column {
                    qd.push(c.map_or(0.0, |c| {
                        v.qd[src * m + c] * (1.0 - a) + v.qd[(src + 1) * m + c] * a
                    }));
                }
                root_lin_vel.push(lerp3(v.lin[src], v.lin[src + 1]));
                root_ang_vel.push(lerp3(v.ang[src], v.ang[src + 1]));
            }
            let (r0, r1) = (clip.root[src], clip.root[src + 1]);
            let quat = robots::spatial::slerp([r0[3], r0[4], r0[5], r0[6]], [r1[3], r1[4], r1[5], r1[6]], a);
            root.push([
                r0[0] * (1.0 - a) + r1[0] * a,
                r0[1] * (1.0 - a) + r1[1] * a,
                r0[2] * (1.0 - a) + r1[2] * a,
                quat[0],
                quat[1],
                quat[2],
                quat[3],
            ]);
        }
        if frame_velocities.is_none() {
            qd = vec![0.0; q.len()];
            for k in 0..ticks {
                let (a, b) = (k.saturating_sub(1), (k + 1).min(ticks - 1));
                let dt = (b - a) as f64 / rate_hz;
                if dt > 0.0 {
                    for i in 0..n {
                        qd[k * n + i] = (q[b * n + i] - q[a * n + i]) / dt;
                    }
                }
            }
            (root_lin_vel, root_ang_vel) = tick_root_velocities(&root, rate_hz);
        }
        // A retargeter that clamps to the limits leaves values a rounding beyond them.
        for (k, x) in q.iter_mut().enumerate() {
            let [lo, hi] = joints[k % n].position_limits;
            if (lo - LIMIT_ROUNDING..lo).contains(x) || (hi..hi + LIMIT_ROUNDING).contains(x) {
                *x = x.clamp(lo, hi);
            }
        }
        let reference = Self {
            n,
            rate_hz,
            q,
            qd,
            root,
            root_lin_vel,
            root_ang_vel,
            held_joints,
            bodies: Vec::new(),
            body_pos: Vec::new(),
            motion_bodies: Vec::new(),
            live_bodies: Vec::new(),
            motion_poses: Vec::new(),
            anchor: None,
            keypoints: None,
        };
        // Can the robot follow it? Positions first (the clearer message), then speeds; each
        // names the first offending frame.
        for k in 0..ticks {
            for (i, j) in joints.iter().enumerate() {
                let x = reference.q[k * n + i];
                let [lo, hi] = j.position_limits;
                if x < lo || x > hi {
                    return Err(err(
                        format!("t = {:.3} s (tick {k})", k as f64 / rate_hz),
                        format!("{} = {x:.3} rad is outside its limits [{lo}, {hi}]", j.name),
                    ));
                }
            }
        }
        for k in 0..ticks {
            for (i, j) in joints.iter().enumerate() {
                let v = reference.qd[k * n + i];
                if v.abs() > j.velocity_limit {
                    return Err(err(
                        format!("t = {:.3} s (tick {k})", k as f64 / rate_hz),
                        format!(
                            "{} moves at {:.2} rad/s, beyond its limit {} rad/s",
                            j.name,
                            v.abs(),
                            j.velocity_limit
                        ),
                    ));
                }
            }
        }
        Ok(reference)
    }
}
