//! The observation, filled each tick without allocating: what it is built from ([`ObsInputs`],
//! the reference frames through [`ReferenceView`]), the per-layout histories
//! ([`ObservationBuilder`]), and the geometry terms share (projected gravity, poses in the robot's
//! heading frame, the motion anchor's position and orientation in the robot anchor's frame).

use crate::TRACKER_VALUES;
use robots::spatial;

use std::ops::Range;

use crate::contract::{HistoryFill, HistoryOrder, PolicyLayout, RootFrame, Term, TermSlot, Trig, selection};

/// What the observation is built from at one tick, in policy joint order.
#[derive(Debug, Clone, Copy)]
pub struct ObsInputs<'a> {
    /// IMU angular velocity.
    pub gyro: [f64; 3],
    /// IMU specific force.
    pub accel: [f64; 3],
    /// Base orientation `[w, x, y, z]`.
    pub quat: [f64; 4],
    /// Joint positions.
    pub q: &'a [f64],
    /// Joint velocities.
    pub qd: &'a [f64],
    /// Default pose.
    pub default_q: &'a [f64],
    /// Raw actions of past ticks, newest first, `k × n` values.
    pub past_actions: &'a [f32],
    /// Targets applied last tick.
    pub last_targets: &'a [f64],
    /// Policy steps taken before this one since the policy took control (0 at its first).
    pub step: u64,
    /// The policy's period, s.
    pub dt: f64,
    /// The live commands of this tick (with the manifest's `[commands]`), replacing the
    /// `command` term's values.
    pub command: Option<&'a [f64]>,
    /// Start-up ramp.
    pub ramp: f64,
    /// Reference joint positions per frame offset: `ref_q(offset)` → n values.
    pub reference: &'a dyn ReferenceView,
    /// Simulation ground truth, when the policy asks for it.
    pub truth: Option<SimTruth<'a>>,
    /// VR tracker poses (teleoperation), see [`Term::TrackerPoses`].
    pub trackers: Option<&'a [f64; TRACKER_VALUES]>,
    /// The root body's angular velocity in its own frame.
    pub base_ang_vel: [f64; 3],
    /// The robot's anchor body in the world `[x, y, z, w, qx, qy, qz]` (the position only where
    /// the run knows the robot's).
    pub robot_anchor: [f64; 7],
    /// The motion frame the next call should return (`time_step`).
    pub time_step: f64,
    /// The robot's keypoints through the cameras, as the `keypoints` term lays them out.
    pub robot_keypoints: &'a [f64],
    /// Each leg's gait phase, rad ([`GaitClock`]; zeros without one).
    pub gait: [f64; 2],
}

/// What only a simulation knows of the robot, for the terms that observe it.
#[derive(Debug, Clone, Copy)]
pub struct SimTruth<'a> {
    /// Root pose `[x, y, z, w, qx, qy, qz]`.
    pub root_pose: [f64; 7],
    /// Root linear velocity in the base frame, m/s.
    pub base_lin_vel: [f64; 3],
    /// Foot contacts, in the robot's foot order.
    pub foot_contacts: &'a [bool],
}

/// Reference frames the observation can look at.
pub trait ReferenceView: std::fmt::Debug {
    /// Joint positions `offset` ticks ahead (policy order).
    fn joint_pos(&self, offset: usize) -> &[f64];
    /// Joint velocities `offset` ticks ahead (policy order).
    fn joint_vel(&self, offset: usize) -> &[f64];
    /// Root pose `offset` ticks ahead: `[x, y, z, w, qx, qy, qz]`.
    fn root_pose(&self, offset: usize) -> [f64; 7];
    /// Positions of the reference bodies `offset` ticks ahead, 3 per body, relative to the
    /// reference root in its heading frame (bodies in the order the reference was built with).
    fn body_pos(&self, offset: usize) -> &[f64];
    /// The reference's anchor body in the world, aligned to the robot: `[x, y, z, w, qx, qy, qz]`.
    fn anchor_pose(&self) -> [f64; 7];
    /// The 2D keypoint references `offset` ticks ahead, as the `ref_keypoints` term lays them
    /// out (views × keypoints × `(u, v, confidence)`, image coordinates in [−1, 1]).
    fn keypoints(&self, offset: usize) -> &[f64];
    /// The root's linear velocity `offset` ticks ahead, world frame, m/s.
    fn root_lin_vel(&self, offset: usize) -> [f64; 3];
    /// The root's angular velocity `offset` ticks ahead, world frame, rad/s.
    fn root_ang_vel(&self, offset: usize) -> [f64; 3];
}

/// Fills observations for one layout; histories live in buffers made once. Each term definition
/// is computed once a tick into its place in `live` (with its own stacked history); every slot
/// that shows it — in several blocks, or as a past copy — is copied from there or from the
/// definition's ring of past ticks.
#[derive(Debug)]
pub struct ObservationBuilder {
    terms: Vec<Term>,
    /// Each definition's range in `live`.
    live_ranges: Vec<Range<usize>>,
    live: Vec<f32>,
    /// The first tick's `live`, for copies filled with it.
    first: Vec<f32>,
    /// Past ticks of each definition that delayed slots read: `depth[i]` copies of its values,
    /// tick `t` at `t % depth[i]`, from `ring_start[i]`.
    ring: Vec<f32>,
    ring_start: Vec<usize>,
    depth: Vec<usize>,
    slots: Vec<TermSlot>,
    scratch: Vec<f64>,
    /// Observations built so far.
    ticks: usize,
}

impl ObservationBuilder {
    /// A builder for `layout`.
    pub fn new(layout: &PolicyLayout) -> Self {
        let terms: Vec<Term> = layout.terms.iter().map(|d| d.term.clone()).collect();
        let mut widths = vec![0; terms.len()];
        let mut depth = vec![0; terms.len()];
        for s in &layout.slots {
            widths[s.source] = s.range.len();
            if s.delay > 0 {
                depth[s.source] = depth[s.source].max(s.delay + 1);
            }
        }
        let mut live_ranges = Vec::with_capacity(terms.len());
        let mut ring_start = Vec::with_capacity(terms.len());
        let (mut at, mut ring_at) = (0, 0);
        for (w, d) in widths.iter().zip(&depth) {
            live_ranges.push(at..at + w);
            ring_start.push(ring_at);
            at += w;
            ring_at += w * d;
        }
        let widest = layout.slots.iter().map(|s| s.width).max().unwrap_or(0);
        Self {
            terms,
            live_ranges,
            live: vec![0.0; at],
            first: vec![0.0; at],
            ring: vec![0.0; ring_at],
            ring_start,
            depth,
            slots: layout.slots.clone(),
            scratch: vec![0.0; widest],
            ticks: 0,
        }
    }

    /// Writes the observation for `inputs` into `obs` (the layout's length).
    pub fn build(&mut self, inputs: &ObsInputs<'_>, obs: &mut [f32]) {
        let filled = self.ticks > 0;
        for (term, r) in self.terms.iter().zip(&self.live_ranges) {
            let live = &mut self.live[r.clone()];
            let sh = term.shaping();
            let w = live.len() / sh.history;
            // Age the term's own history: move older copies one step away from the current
            // value's place.
            let current = match sh.history_order {
                HistoryOrder::NewestFirst => {
                    if sh.history > 1 {
                        live.copy_within(..live.len() - w, w);
                    }
                    0
                }
                HistoryOrder::OldestFirst => {
                    if sh.history > 1 {
                        live.copy_within(w.., 0);
                    }
                    live.len() - w
                }
            };
            let v = &mut self.scratch[..w];
            fill_term(term, inputs, v);
            for (i, (o, &x)) in live[current..current + w].iter_mut().zip(v.iter()).enumerate() {
                let scale = sh.scales.as_ref().map_or(sh.scale, |s| s[i]);
                let offset = sh.offsets.as_ref().map_or(sh.offset, |o| o[i]);
                let y = (x - offset) * scale;
                *o = sh.clip.map_or(y, |c| y.clamp(-c, c)) as f32;
            }
            if !filled && sh.history > 1 {
                // First tick: the term's history starts full of the current value.
                for k in 0..sh.history {
                    if k * w != current {
                        live.copy_within(current..current + w, k * w);
                    }
                }
            }
        }
        if !filled {
            self.first.copy_from_slice(&self.live);
        }
        for (i, r) in self.live_ranges.iter().enumerate() {
            let d = self.depth[i];
            if d > 0 {
                let at = self.ring_start[i] + (self.ticks % d) * r.len();
                self.ring[at..at + r.len()].copy_from_slice(&self.live[r.clone()]);
            }
        }
        for s in &self.slots {
            let r = self.live_ranges[s.source].clone();
            let out = &mut obs[s.range.clone()];
            if s.delay == 0 {
                out.copy_from_slice(&self.live[r]);
            } else if self.ticks >= s.delay {
                let d = self.depth[s.source];
                let at = self.ring_start[s.source] + ((self.ticks - s.delay) % d) * r.len();
                out.copy_from_slice(&self.ring[at..at + r.len()]);
            } else {
                match s.fill {
                    HistoryFill::Zeros => out.fill(0.0),
                    HistoryFill::First => out.copy_from_slice(&self.first[r]),
                }
            }
        }
        self.ticks += 1;
    }
}

fn fill_term(term: &Term, x: &ObsInputs<'_>, v: &mut [f64]) {
    let n = x.q.len();
    match term {
        Term::Gyro(_) => v.copy_from_slice(&x.gyro),
        Term::Accelerometer(_) => v.copy_from_slice(&x.accel),
        Term::ProjectedGravity(_) => v.copy_from_slice(&projected_gravity(x.quat)),
        Term::BaseOrientation(_) => v.copy_from_slice(&x.quat),
        Term::BaseHeight(_) => v[0] = x.truth.map_or(0.0, |t| t.root_pose[2]),
        Term::BaseLinVel(_) => v.copy_from_slice(&x.truth.map_or([0.0; 3], |t| t.base_lin_vel)),
        Term::JointPos { relative, .. } => {
            for ((o, q), d) in v.iter_mut().zip(x.q).zip(x.default_q) {
                *o = q - if *relative { *d } else { 0.0 };
            }
        }
        Term::JointVel(_) => v.copy_from_slice(x.qd),
        Term::LastActions { k, .. } => {
            for (o, a) in v.iter_mut().zip(x.past_actions.iter().take(k * n)) {
                *o = f64::from(*a);
            }
        }
        Term::LastTargets(_) => v.copy_from_slice(x.last_targets),
        Term::TrackerPoses { .. } => match x.trackers {
            Some(t) => v.copy_from_slice(&t[..v.len()]),
            None => v.fill(0.0),
        },
        Term::FootContacts(_) => {
            for (o, c) in v.iter_mut().zip(x.truth.map_or(&[][..], |t| t.foot_contacts)) {
                *o = f64::from(u8::from(*c));
            }
        }
        Term::Command { values, .. } => v.copy_from_slice(x.command.unwrap_or(values)),
        Term::Phase {
            period_s,
            period_ticks,
            advance_first,
            sin_first,
            ..
        } => {
            let period = period_ticks.map_or_else(|| period_s.unwrap_or(1.0) / x.dt, |p| p as f64);
            let k = x.step + u64::from(*advance_first);
            // The phase within its cycle: exact at every whole period however long the run.
            let a = std::f64::consts::TAU * ((k as f64 % period) / period);
            let (c, s) = (a.cos(), a.sin());
            (v[0], v[1]) = if *sin_first { (s, c) } else { (c, s) };
        }
        Term::GaitPhase { part, .. } => {
            for (o, p) in v.iter_mut().zip(x.gait) {
                *o = match part {
                    Trig::Sin => p.sin(),
                    Trig::Cos => p.cos(),
                };
            }
        }
        Term::Ramp(_) => v[0] = x.ramp,
        Term::RefJointPos { frames, relative, .. } => {
            for (f, &offset) in frames.iter().enumerate() {
                let r = x.reference.joint_pos(offset);
                for i in 0..n {
                    v[f * n + i] = r[i] - if *relative { x.default_q[i] } else { 0.0 };
                }
            }
        }
        Term::RefJointVel { frames, .. } => {
            for (f, &offset) in frames.iter().enumerate() {
                v[f * n..(f + 1) * n].copy_from_slice(x.reference.joint_vel(offset));
            }
        }
        Term::RefRootPose { frames, .. } => {
            let robot = x
                .truth
                .map_or([0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0], |t| t.root_pose);
            for (f, &offset) in frames.iter().enumerate() {
                v[f * 9..(f + 1) * 9]
                    .copy_from_slice(&relative_pose_in_heading(robot, x.reference.root_pose(offset)));
            }
        }
        Term::MotionCommand(_) => {
            v[..n].copy_from_slice(x.reference.joint_pos(0));
            v[n..].copy_from_slice(x.reference.joint_vel(0));
        }
        Term::MotionAnchorPosB(_) => {
            v.copy_from_slice(&anchor_pos_b(x.robot_anchor, x.reference.anchor_pose()));
        }
        Term::MotionAnchorOriB(_) => {
            let (r, m) = (x.robot_anchor, x.reference.anchor_pose());
            v.copy_from_slice(&anchor_ori_b([r[3], r[4], r[5], r[6]], [m[3], m[4], m[5], m[6]]));
        }
        Term::BaseAngVel(_) => v.copy_from_slice(&x.base_ang_vel),
        Term::TimeStep(_) => v[0] = x.time_step,
        Term::RefBodyPos { bodies, frames, .. } => {
            let w = 3 * bodies.len();
            for (f, &offset) in frames.iter().enumerate() {
                v[f * w..(f + 1) * w].copy_from_slice(&x.reference.body_pos(offset)[..w]);
            }
        }
        Term::RefKeypoints { frames, .. } => {
            let w = v.len() / frames.len();
            for (f, &offset) in frames.iter().enumerate() {
                v[f * w..(f + 1) * w].copy_from_slice(&x.reference.keypoints(offset)[..w]);
            }
        }
        Term::Keypoints { .. } => v.copy_from_slice(&x.robot_keypoints[..v.len()]),
        Term::RefRootLinVel {
            frames, frame, axes, ..
        }
        | Term::RefRootAngVel {
            frames, frame, axes, ..
        } => {
            let w = axes.len();
            for (f, &offset) in frames.iter().enumerate() {
                let world = match term {
                    Term::RefRootLinVel { .. } => x.reference.root_lin_vel(offset),
                    _ => x.reference.root_ang_vel(offset),
                };
                let p = x.reference.root_pose(offset);
                let e = in_root_frame(*frame, [p[3], p[4], p[5], p[6]], world);
                for (o, a) in v[f * w..(f + 1) * w].iter_mut().zip(selection(axes, "xyz")) {
                    *o = e[a];
                }
            }
        }
        Term::RefRootHeight { frames, .. } => {
            for (o, &offset) in v.iter_mut().zip(frames) {
                *o = x.reference.root_pose(offset)[2];
            }
        }
        Term::RefRootRpy { frames, angles, .. } => {
            let w = angles.len();
            for (f, &offset) in frames.iter().enumerate() {
                let p = x.reference.root_pose(offset);
                let rpy = spatial::rpy_of_quat([p[3], p[4], p[5], p[6]]);
                for (o, a) in v[f * w..(f + 1) * w].iter_mut().zip(selection(angles, "rpy")) {
                    *o = rpy[a];
                }
            }
        }
        Term::RefRootQuat { frames, frame, .. } => {
            for (f, &offset) in frames.iter().enumerate() {
                let p = x.reference.root_pose(offset);
                let q = [p[3], p[4], p[5], p[6]];
                let q = match frame {
                    RootFrame::Heading => {
                        let yaw = -spatial::heading_of_quat(q);
                        spatial::quat_mul([(yaw / 2.0).cos(), 0.0, 0.0, (yaw / 2.0).sin()], q)
                    }
                    RootFrame::World | RootFrame::Own => q,
                };
                v[f * 4..(f + 1) * 4].copy_from_slice(&spatial::quat_normalize(q));
            }
        }
        Term::BaseRpy { angles, .. } => {
            let rpy = spatial::rpy_of_quat(x.quat);
            for (o, a) in v.iter_mut().zip(selection(angles, "rpy")) {
                *o = rpy[a];
            }
        }
    }
}

/// A world vector `v` expressed in `frame` of a root oriented `q` (`[w, x, y, z]`).
pub fn in_root_frame(frame: RootFrame, q: [f64; 4], v: [f64; 3]) -> [f64; 3] {
    match frame {
        RootFrame::Own => spatial::quat_rotate(spatial::quat_conj(q), v),
        RootFrame::Heading => spatial::mat_apply(&spatial::yaw(-spatial::heading_of_quat(q)), v),
        RootFrame::World => v,
    }
}

/// Gravity's direction in the base frame for orientation `q` (`[w, x, y, z]`, base to world).
pub fn projected_gravity(q: [f64; 4]) -> [f64; 3] {
    spatial::quat_rotate(spatial::quat_conj(q), [0.0, 0.0, -1.0])
}

/// Target pose relative to the robot, expressed in the robot's heading frame (yaw only):
/// position (3) and the first two columns of the relative rotation (6).
pub fn relative_pose_in_heading(robot: [f64; 7], target: [f64; 7]) -> [f64; 9] {
    let rr = spatial::mat_of_quat([robot[3], robot[4], robot[5], robot[6]]);
    let unturn = spatial::yaw(-spatial::heading(&rr));
    let p = spatial::mat_apply(
        &unturn,
        spatial::sub([target[0], target[1], target[2]], [robot[0], robot[1], robot[2]]),
    );
    let rt = spatial::mat_of_quat([target[3], target[4], target[5], target[6]]);
    // R_rel = R_robotᵀ R_target.
    let rel = spatial::mat_mul(&spatial::transpose(&rr), &rt);
    [
        p[0], p[1], p[2], rel[0][0], rel[1][0], rel[2][0], rel[0][1], rel[1][1], rel[2][1],
    ]
}

/// The reference anchor's position in the robot anchor's frame. Poses are `[x, y, z, w, qx, qy,
/// qz]` in the world.
pub fn anchor_pos_b(robot: [f64; 7], reference: [f64; 7]) -> [f64; 3] {
    let q = [robot[3], robot[4], robot[5], robot[6]];
    spatial::quat_rotate(
        spatial::quat_conj(q),
        spatial::sub(
            [reference[0], reference[1], reference[2]],
            [robot[0], robot[1], robot[2]],
        ),
    )
}

/// The first two columns of `R(q_robot⁻¹ ⊗ q_reference)`, row by row: `r00, r01, r10, r11, r20,
/// r21`.
pub fn anchor_ori_b(robot: [f64; 4], reference: [f64; 4]) -> [f64; 6] {
    let m = spatial::mat_of_quat(spatial::quat_mul(spatial::quat_conj(robot), reference));
    [m[0][0], m[0][1], m[1][0], m[1][1], m[2][0], m[2][1]]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn projected_gravity_points_down_when_level_and_sideways_when_rolled() {
        let g = projected_gravity([1.0, 0.0, 0.0, 0.0]);
        assert_eq!(g, [0.0, 0.0, -1.0]);
        // Rolled 90° about x: gravity appears along -y of the base.
        let h = std::f64::consts::FRAC_1_SQRT_2;
        let g = projected_gravity([h, h, 0.0, 0.0]);
        assert!((g[1] + 1.0).abs() < 1e-12 && g[2].abs() < 1e-12, "{g:?}");
    }

    #[test]
    fn a_target_ahead_of_a_turned_robot_is_ahead_in_its_heading_frame() {
        let h = std::f64::consts::FRAC_1_SQRT_2;
        // Robot at origin facing +y (yaw 90°); target 1 m along +y, same orientation.
        let robot = [0.0, 0.0, 0.5, h, 0.0, 0.0, h];
        let target = [0.0, 1.0, 0.5, h, 0.0, 0.0, h];
        let r = relative_pose_in_heading(robot, target);
        assert!((r[0] - 1.0).abs() < 1e-12 && r[1].abs() < 1e-12);
        assert!(
            (r[3] - 1.0).abs() < 1e-12 && (r[7] - 1.0).abs() < 1e-12,
            "identity rotation: {r:?}"
        );
    }

    const H: f64 = std::f64::consts::FRAC_1_SQRT_2;

    #[test]
    fn a_velocity_reads_in_the_roots_own_frame_its_heading_frame_or_the_world() {
        // A root yawed 90° (facing +y), then rolled 90° about its own x (its left side up):
        // moving along world +y is moving forward.
        let yawed = [H, 0.0, 0.0, H];
        let q = spatial::quat_mul(yawed, [H, H, 0.0, 0.0]);
        let v = [0.0, 2.0, 0.0];
        let close = |a: [f64; 3], b: [f64; 3]| a.iter().zip(b).all(|(x, y)| (x - y).abs() < 1e-12);
        assert!(close(in_root_frame(RootFrame::World, q, v), [0.0, 2.0, 0.0]));
        assert!(close(in_root_frame(RootFrame::Heading, q, v), [2.0, 0.0, 0.0]));
        assert!(close(in_root_frame(RootFrame::Own, q, v), [2.0, 0.0, 0.0]));
        // Upward: the heading frame keeps it up, the rolled root sees it along its own +y.
        let up = [0.0, 0.0, 1.0];
        assert!(close(in_root_frame(RootFrame::Heading, q, up), up));
        assert!(close(in_root_frame(RootFrame::Own, q, up), [0.0, 1.0, 0.0]));
    }

    #[test]
    fn anchor_terms_are_zero_and_identity_when_robot_and_reference_coincide() {
        let pose = [0.3, -0.2, 0.9, H, 0.0, H, 0.0];
        assert_eq!(anchor_pos_b(pose, pose), [0.0; 3]);
        let o = anchor_ori_b([H, 0.0, H, 0.0], [H, 0.0, H, 0.0]);
        for (v, want) in o.iter().zip([1.0, 0.0, 0.0, 1.0, 0.0, 0.0]) {
            assert!((v - want).abs() < 1e-12, "{o:?}");
        }
    }

    #[test]
    fn the_reference_ahead_of_a_turned_robot_is_ahead_in_its_frame() {
        // Robot facing +y at the origin; reference 1 m along +y: 1 m along the robot's x.
        let robot = [0.0, 0.0, 0.0, H, 0.0, 0.0, H];
        let p = anchor_pos_b(robot, [0.0, 1.0, 0.0, 1.0, 0.0, 0.0, 0.0]);
        assert!((p[0] - 1.0).abs() < 1e-12 && p[1].abs() < 1e-12, "{p:?}");
        // Reference facing +x, robot facing +y: relative yaw −90°: r01 = sin 90° = 1.
        let o = anchor_ori_b([H, 0.0, 0.0, H], [1.0, 0.0, 0.0, 0.0]);
        assert!((o[1] - 1.0).abs() < 1e-12 && (o[2] + 1.0).abs() < 1e-12, "{o:?}");
    }
}
