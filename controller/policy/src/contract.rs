//! The policy contract as data: a manifest (TOML beside the ONNX file) declares the joint order,
//! the observation terms in order with their scaling and history, and how actions become joint
//! targets. [`PolicyLayout`] resolves it against a robot and checks it against the ONNX shapes;
//! [`ObservationBuilder`] fills the observation each tick without allocating.

use std::ops::Range;
use std::path::{Path, PathBuf};

use crate::TRACKER_VALUES;
use crate::commands::CommandSpec;

use robots::Robot;

/// One observation term, as trainers name them.
#[derive(Debug, Clone, PartialEq, serde::Deserialize, schemars::JsonSchema, serde::Serialize)]
#[serde(tag = "term", rename_all = "snake_case", deny_unknown_fields)]
pub enum Term {
    /// IMU angular velocity, rad/s (IMU axes).
    Gyro(#[serde(default)] Shaping),
    /// IMU specific force, m/s².
    Accelerometer(#[serde(default)] Shaping),
    /// Gravity direction in the base frame (unit vector), from the IMU orientation.
    ProjectedGravity(#[serde(default)] Shaping),
    /// Base orientation quaternion `[w, x, y, z]`.
    BaseOrientation(#[serde(default)] Shaping),
    /// Base height above the floor, m (simulation ground truth only).
    BaseHeight(#[serde(default)] Shaping),
    /// Base linear velocity in the base frame, m/s (simulation ground truth only).
    BaseLinVel(#[serde(default)] Shaping),
    /// Joint positions, rad, in policy order (minus the default pose when `relative`).
    JointPos {
        /// Subtract the default pose.
        #[serde(default)]
        relative: bool,
        /// Scaling.
        #[serde(flatten)]
        shaping: Shaping,
    },
    /// Joint velocities, rad/s.
    JointVel(#[serde(default)] Shaping),
    /// The last `k` raw actions, newest first.
    LastActions {
        /// How many steps.
        #[serde(default = "one")]
        k: usize,
        /// Scaling.
        #[serde(flatten)]
        shaping: Shaping,
    },
    /// The joint targets applied last tick, rad.
    LastTargets(#[serde(default)] Shaping),
    /// Foot contact flags (simulation ground truth only).
    FootContacts(#[serde(default)] Shaping),
    /// Commands (e.g. the velocity command of a locomotion policy): constants, or with the
    /// manifest's `[commands]` the live commands of an operator (keyboard, gamepad, UDP,
    /// `--command`), starting at these values (default: the section's defaults).
    Command {
        /// The values.
        #[serde(default)]
        values: Vec<f64>,
        /// Scaling.
        #[serde(flatten)]
        shaping: Shaping,
    },
    /// `[cos, sin]` (or `[sin, cos]`) of a gait phase: `2π (k + a) / P` at the policy's `k`-th
    /// step (0 at the first), `a` = 1 when the phase advances before the observation is built
    /// (a counter incremented at the top of the step), `P` the period in ticks.
    Phase {
        /// Period, s (give this or `period_ticks`).
        #[serde(default)]
        period_s: Option<f64>,
        /// Period, policy ticks.
        #[serde(default)]
        period_ticks: Option<u64>,
        /// The phase advances before the first observation (pre-increment).
        #[serde(default)]
        advance_first: bool,
        /// `[sin, cos]` instead of `[cos, sin]`.
        #[serde(default)]
        sin_first: bool,
        /// Scaling.
        #[serde(flatten)]
        shaping: Shaping,
    },
    /// holosoma's two-leg gait phase: `sin` or `cos` of each leg's phase (left first). The
    /// phases start at `[0, π]` and advance `2π dt / period_s` before each observation, wrapped
    /// to [−π, π); while the velocity command is at rest (its norm below `standing_below`) both
    /// hold at π, and the gait restarts at `[0, π]` when it moves again.
    GaitPhase {
        /// `sin` or `cos`.
        part: Trig,
        /// The gait's period, s.
        period_s: f64,
        /// The command norm under which the robot stands.
        #[serde(default = "standing_below")]
        standing_below: f64,
        /// Scaling.
        #[serde(flatten)]
        shaping: Shaping,
    },
    /// The start-up ramp ψ, 0 → 1.
    Ramp(#[serde(default)] Shaping),
    /// Reference joint positions at the current and future frames (offsets in ticks).
    RefJointPos {
        /// Frame offsets, in control ticks.
        #[serde(default = "current_frame")]
        frames: Vec<usize>,
        /// Subtract the default pose.
        #[serde(default)]
        relative: bool,
        /// Scaling.
        #[serde(flatten)]
        shaping: Shaping,
    },
    /// Reference joint velocities at the given frames.
    RefJointVel {
        /// Frame offsets, in control ticks.
        #[serde(default = "current_frame")]
        frames: Vec<usize>,
        /// Scaling.
        #[serde(flatten)]
        shaping: Shaping,
    },
    /// Reference root pose relative to the robot's root in its heading frame: position (3) and
    /// the first two columns of the relative rotation (6), per frame (ground truth of the robot's
    /// root needed).
    RefRootPose {
        /// Frame offsets, in control ticks.
        #[serde(default = "current_frame")]
        frames: Vec<usize>,
        /// Scaling.
        #[serde(flatten)]
        shaping: Shaping,
    },
    /// VR tracker poses (the sparse-input policy's `o_user`): headset, left and right controller,
    /// each position (3) and the first two columns of its rotation (6), in the robot's heading
    /// frame at the map's scale; zeros for a missing device. Teleoperation only. With
    /// `history = 2` the policy sees them at t and t − 1.
    TrackerPoses {
        /// Only the headset (9 values instead of 27).
        #[serde(default)]
        headset_only: bool,
        /// Scaling.
        #[serde(flatten)]
        shaping: Shaping,
    },
    /// The reference motion's joint positions then velocities at this tick, policy order (the
    /// `command` of a motion-tracking export).
    MotionCommand(#[serde(default)] Shaping),
    /// The reference anchor's position in the robot anchor's frame (3): needs the robot's
    /// position (simulation ground truth; a state estimator on hardware).
    MotionAnchorPosB(#[serde(default)] Shaping),
    /// The first two columns of `R(q_robot_anchor⁻¹ ⊗ q_ref_anchor)`, row by row (6).
    MotionAnchorOriB(#[serde(default)] Shaping),
    /// Angular velocity of the root body in its own frame (the gyro, turned from the IMU's
    /// frame into the root's).
    BaseAngVel(#[serde(default)] Shaping),
    /// The frame of the motion a tracking export carries that the next call should return
    /// (goes to the model's `time_step` input).
    TimeStep(#[serde(default)] Shaping),
    /// 2D keypoint references (Mimic2DM) at the current and future frames: per frame, per view
    /// (camera) and per keypoint `(u, v, confidence)`, the pixel mapped to [−1, 1] across the
    /// image (`2u/width − 1`, `2v/height − 1`); an unseen keypoint is `(0, 0, 0)`. Needs a run
    /// with keypoint references (`play --keypoints`).
    RefKeypoints {
        /// The views, by camera name.
        views: Vec<String>,
        /// The keypoints, by name (the robot's `[keypoints]` map says where each is on it).
        keypoints: Vec<String>,
        /// Frame offsets, in control ticks.
        #[serde(default = "current_frame")]
        frames: Vec<usize>,
        /// Scaling.
        #[serde(flatten)]
        shaping: Shaping,
    },
    /// The robot's own keypoints seen through the same cameras: forward kinematics of the
    /// measured joints placed by the base estimate, projected; per view and keypoint `(u, v,
    /// visible)` in the same [−1, 1] image coordinates, `(0, 0, 0)` when off the image.
    Keypoints {
        /// The views, by camera name.
        views: Vec<String>,
        /// The keypoints, by name.
        keypoints: Vec<String>,
        /// Scaling.
        #[serde(flatten)]
        shaping: Shaping,
    },
    /// Positions of the reference's bodies (forward kinematics of the robot model at the
    /// reference pose) relative to the reference root, in the reference's heading frame: 3 per
    /// body per frame.
    RefBodyPos {
        /// MJCF body names.
        bodies: Vec<String>,
        /// Frame offsets, in control ticks.
        #[serde(default = "current_frame")]
        frames: Vec<usize>,
        /// Scaling.
        #[serde(flatten)]
        shaping: Shaping,
    },
    /// The reference root's linear velocity, m/s, in `frame` (the reference's own: it needs
    /// nothing of the robot), the components `axes` names, per frame. Velocities follow the
    /// manifest's `[reference] velocities` rule.
    RefRootLinVel {
        /// Frame offsets, in control ticks.
        #[serde(default = "current_frame")]
        frames: Vec<usize>,
        /// The frame the velocity is expressed in.
        #[serde(default)]
        frame: RootFrame,
        /// Which components, in order: a subset of `"xyz"` (e.g. `"xy"`).
        #[serde(default = "all_axes")]
        axes: String,
        /// Scaling.
        #[serde(flatten)]
        shaping: Shaping,
    },
    /// The reference root's angular velocity, rad/s, in `frame`, the components `axes` names
    /// (`"z"`: the yaw rate), per frame.
    RefRootAngVel {
        /// Frame offsets, in control ticks.
        #[serde(default = "current_frame")]
        frames: Vec<usize>,
        /// The frame the velocity is expressed in.
        #[serde(default)]
        frame: RootFrame,
        /// Which components, in order: a subset of `"xyz"`.
        #[serde(default = "all_axes")]
        axes: String,
        /// Scaling.
        #[serde(flatten)]
        shaping: Shaping,
    },
    /// The reference root's height: its absolute z in the motion's world, m, per frame.
    RefRootHeight {
        /// Frame offsets, in control ticks.
        #[serde(default = "current_frame")]
        frames: Vec<usize>,
        /// Scaling.
        #[serde(flatten)]
        shaping: Shaping,
    },
    /// Euler angles of the reference root's orientation (Z-Y-X: roll = atan2(2(wx+yz),
    /// 1−2(x²+y²)), pitch = asin(2(wy−zx)), yaw about +z), rad, the ones `angles` names, per frame.
    RefRootRpy {
        /// Frame offsets, in control ticks.
        #[serde(default = "current_frame")]
        frames: Vec<usize>,
        /// Which angles, in order: a subset of `"rpy"` (e.g. `"rp"`: roll and pitch).
        #[serde(default = "all_angles")]
        angles: String,
        /// Scaling.
        #[serde(flatten)]
        shaping: Shaping,
    },
    /// The reference root's orientation `[w, x, y, z]` (w ≥ 0), in the motion's world or in its
    /// own heading frame (its yaw taken out: the tilt alone), per frame.
    RefRootQuat {
        /// Frame offsets, in control ticks.
        #[serde(default = "current_frame")]
        frames: Vec<usize>,
        /// `world` or `heading` (`own` is the identity and refused).
        #[serde(default)]
        frame: RootFrame,
        /// Scaling.
        #[serde(flatten)]
        shaping: Shaping,
    },
    /// Euler angles (Z-Y-X, as [`Term::RefRootRpy`]) of the robot base's orientation from the
    /// IMU, rad, the ones `angles` names (default `"rp"`: roll and pitch).
    BaseRpy {
        /// Which angles, in order: a subset of `"rpy"`.
        #[serde(default = "roll_pitch")]
        angles: String,
        /// Scaling.
        #[serde(flatten)]
        shaping: Shaping,
    },
}

/// The frame a reference root term is expressed in.
#[derive(
    Debug, Clone, Copy, Default, PartialEq, Eq, serde::Deserialize, schemars::JsonSchema, serde::Serialize,
)]
#[serde(rename_all = "snake_case")]
pub enum RootFrame {
    /// The reference root's own frame: a world vector turned by the inverse of its orientation.
    #[default]
    Own,
    /// The reference root's heading frame: turned by the inverse of its yaw only.
    Heading,
    /// The motion's world frame.
    World,
}

fn all_axes() -> String {
    "xyz".into()
}

fn all_angles() -> String {
    "rpy".into()
}

fn roll_pitch() -> String {
    "rp".into()
}

/// The indices a selection such as `"xy"` of `"xyz"` (or `"rp"` of `"rpy"`) names, in order.
pub fn selection(chosen: &str, of: &str) -> impl Iterator<Item = usize> {
    chosen
        .bytes()
        .filter_map(move |c| of.bytes().position(|o| o == c))
}

/// Whether `chosen` is a non-empty selection of distinct letters of `of`.
fn valid_selection(chosen: &str, of: &str) -> bool {
    !chosen.is_empty()
        && chosen.bytes().all(|c| of.as_bytes().contains(&c))
        && chosen
            .bytes()
            .enumerate()
            .all(|(i, c)| !chosen.as_bytes()[..i].contains(&c))
}

fn one() -> usize {
    1
}

fn current_frame() -> Vec<usize> {
    vec![0]
}

/// `(value − offset) · scale`, then clipped, with `history` stacked copies (newest first).
#[derive(Debug, Clone, PartialEq, serde::Deserialize, schemars::JsonSchema, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct Shaping {
    /// Multiplier.
    #[serde(default = "unit")]
    pub scale: f64,
    /// Subtracted before scaling.
    #[serde(default)]
    pub offset: f64,
    /// Symmetric clip after scaling.
    #[serde(default)]
    pub clip: Option<f64>,
    /// Stacked past values (1: current only).
    #[serde(default = "one")]
    pub history: usize,
    /// The ONNX input this term goes to, for models with several named inputs (default: the
    /// input named `obs`, else the model's first input).
    #[serde(default)]
    pub input: Option<String>,
    /// A multiplier per value, replacing `scale` (one per value of a history step).
    #[serde(default)]
    pub scales: Option<Vec<f64>>,
    /// An offset per value, replacing `offset` (one per value of a history step).
    #[serde(default)]
    pub offsets: Option<Vec<f64>>,
    /// The order of the stacked history.
    #[serde(default)]
    pub history_order: HistoryOrder,
}

/// Which function of an angle a term observes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Deserialize, schemars::JsonSchema, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Trig {
    /// The sine.
    Sin,
    /// The cosine.
    Cos,
}

fn standing_below() -> f64 {
    0.01
}

/// The state behind [`Term::GaitPhase`]: each leg's phase, advanced once per policy step before
/// the observation is built.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GaitClock {
    /// Each leg's phase, rad in [−π, π).
    pub phase: [f64; 2],
    step: f64,
    standing_below: f64,
    standing: bool,
}

impl GaitClock {
    /// The clock of `layout`'s gait phase terms (all alike), if it has any.
    pub fn of(layout: &PolicyLayout) -> Option<Self> {
        layout.slots.iter().find_map(|s| match s.term {
            Term::GaitPhase {
                period_s,
                standing_below,
                ..
            } => Some(Self {
                phase: [0.0, std::f64::consts::PI],
                step: std::f64::consts::TAU / (period_s * layout.manifest.rate_hz),
                standing_below,
                standing: false,
            }),
            _ => None,
        })
    }

    /// One policy step: advance, then hold at π while `command` rests, restart when it moves.
    pub fn advance(&mut self, command: &[f64]) {
        use std::f64::consts::{PI, TAU};
        for p in &mut self.phase {
            *p = (*p + self.step + PI).rem_euclid(TAU) - PI;
        }
        let norm = command.iter().map(|c| c * c).sum::<f64>().sqrt();
        if norm < self.standing_below {
            self.phase = [PI, PI];
            self.standing = true;
        } else if self.standing {
            self.phase = [0.0, PI];
            self.standing = false;
        }
    }
}

/// How a term's history is stacked.
#[derive(
    Debug, Clone, Copy, Default, PartialEq, Eq, serde::Deserialize, schemars::JsonSchema, serde::Serialize,
)]
#[serde(rename_all = "snake_case")]
pub enum HistoryOrder {
    /// The current value first (this project's manifests).
    #[default]
    NewestFirst,
    /// The current value last (Isaac Lab's and mjlab's history buffers).
    OldestFirst,
}

fn unit() -> f64 {
    1.0
}

impl Default for Shaping {
    fn default() -> Self {
        Self {
            scale: 1.0,
            offset: 0.0,
            clip: None,
            history: 1,
            input: None,
            scales: None,
            offsets: None,
            history_order: HistoryOrder::NewestFirst,
        }
    }
}

impl Term {
    /// The term's scaling.
    pub fn shaping(&self) -> &Shaping {
        match self {
            Self::Gyro(s)
            | Self::Accelerometer(s)
            | Self::ProjectedGravity(s)
            | Self::BaseOrientation(s)
            | Self::BaseHeight(s)
            | Self::BaseLinVel(s)
            | Self::JointVel(s)
            | Self::LastTargets(s)
            | Self::FootContacts(s)
            | Self::Ramp(s)
            | Self::MotionCommand(s)
            | Self::MotionAnchorPosB(s)
            | Self::MotionAnchorOriB(s)
            | Self::BaseAngVel(s)
            | Self::TimeStep(s) => s,
            Self::JointPos { shaping, .. }
            | Self::LastActions { shaping, .. }
            | Self::Command { shaping, .. }
            | Self::Phase { shaping, .. }
            | Self::GaitPhase { shaping, .. }
            | Self::RefJointPos { shaping, .. }
            | Self::RefJointVel { shaping, .. }
            | Self::RefRootPose { shaping, .. }
            | Self::RefBodyPos { shaping, .. }
            | Self::RefKeypoints { shaping, .. }
            | Self::Keypoints { shaping, .. }
            | Self::TrackerPoses { shaping, .. }
            | Self::RefRootLinVel { shaping, .. }
            | Self::RefRootAngVel { shaping, .. }
            | Self::RefRootHeight { shaping, .. }
            | Self::RefRootRpy { shaping, .. }
            | Self::RefRootQuat { shaping, .. }
            | Self::BaseRpy { shaping, .. } => shaping,
        }
    }

    /// The term's name in the manifest.
    pub fn name(&self) -> &'static str {
        match self {
            Self::Gyro(_) => "gyro",
            Self::Accelerometer(_) => "accelerometer",
            Self::ProjectedGravity(_) => "projected_gravity",
            Self::BaseOrientation(_) => "base_orientation",
            Self::BaseHeight(_) => "base_height",
            Self::BaseLinVel(_) => "base_lin_vel",
            Self::JointPos { .. } => "joint_pos",
            Self::JointVel(_) => "joint_vel",
            Self::LastActions { .. } => "last_actions",
            Self::LastTargets(_) => "last_targets",
            Self::FootContacts(_) => "foot_contacts",
            Self::Command { .. } => "command",
            Self::Phase { .. } => "phase",
            Self::GaitPhase { .. } => "gait_phase",
            Self::Ramp(_) => "ramp",
            Self::RefJointPos { .. } => "ref_joint_pos",
            Self::RefJointVel { .. } => "ref_joint_vel",
            Self::RefRootPose { .. } => "ref_root_pose",
            Self::RefBodyPos { .. } => "ref_body_pos",
            Self::RefKeypoints { .. } => "ref_keypoints",
            Self::Keypoints { .. } => "keypoints",
            Self::TrackerPoses { .. } => "tracker_poses",
            Self::MotionCommand(_) => "motion_command",
            Self::MotionAnchorPosB(_) => "motion_anchor_pos_b",
            Self::MotionAnchorOriB(_) => "motion_anchor_ori_b",
            Self::BaseAngVel(_) => "base_ang_vel",
            Self::TimeStep(_) => "time_step",
            Self::RefRootLinVel { .. } => "ref_root_lin_vel",
            Self::RefRootAngVel { .. } => "ref_root_ang_vel",
            Self::RefRootHeight { .. } => "ref_root_height",
            Self::RefRootRpy { .. } => "ref_root_rpy",
            Self::RefRootQuat { .. } => "ref_root_quat",
            Self::BaseRpy { .. } => "base_rpy",
        }
    }

    /// Values per history step, for `joints` joints and `feet` feet.
    pub fn width(&self, joints: usize, feet: usize) -> usize {
        match self {
            Self::Gyro(_)
            | Self::Accelerometer(_)
            | Self::ProjectedGravity(_)
            | Self::BaseLinVel(_)
            | Self::BaseAngVel(_)
            | Self::MotionAnchorPosB(_) => 3,
            Self::BaseOrientation(_) => 4,
            Self::MotionAnchorOriB(_) => 6,
            Self::MotionCommand(_) => 2 * joints,
            Self::BaseHeight(_) | Self::Ramp(_) | Self::TimeStep(_) => 1,
            Self::JointPos { .. } | Self::JointVel(_) | Self::LastTargets(_) => joints,
            Self::LastActions { k, .. } => joints * k,
            Self::FootContacts(_) => feet,
            Self::Command { values, .. } => values.len(),
            Self::Phase { .. } | Self::GaitPhase { .. } => 2,
            Self::RefJointPos { frames, .. } | Self::RefJointVel { frames, .. } => joints * frames.len(),
            Self::RefRootPose { frames, .. } => 9 * frames.len(),
            Self::RefBodyPos { bodies, frames, .. } => 3 * bodies.len() * frames.len(),
            Self::RefKeypoints {
                views,
                keypoints,
                frames,
                ..
            } => 3 * views.len() * keypoints.len() * frames.len(),
            Self::Keypoints { views, keypoints, .. } => 3 * views.len() * keypoints.len(),
            Self::TrackerPoses { headset_only, .. } => {
                if *headset_only {
                    9
                } else {
                    TRACKER_VALUES
                }
            }
            Self::RefRootLinVel { frames, axes, .. } | Self::RefRootAngVel { frames, axes, .. } => {
                axes.len() * frames.len()
            }
            Self::RefRootHeight { frames, .. } => frames.len(),
            Self::RefRootRpy { frames, angles, .. } => angles.len() * frames.len(),
            Self::RefRootQuat { frames, .. } => 4 * frames.len(),
            Self::BaseRpy { angles, .. } => angles.len(),
        }
    }

    /// Whether the term needs state a real robot cannot measure without a state estimator.
    pub fn needs_ground_truth(&self) -> bool {
        matches!(
            self,
            Self::BaseHeight(_)
                | Self::BaseLinVel(_)
                | Self::FootContacts(_)
                | Self::RefRootPose { .. }
                | Self::MotionAnchorPosB(_)
        )
    }

    /// Whether the term needs the pose of the reference's anchor and of the robot's.
    pub fn needs_anchor(&self) -> bool {
        matches!(self, Self::MotionAnchorPosB(_) | Self::MotionAnchorOriB(_))
    }
}

/// Policy rates the loop runs, Hz.
pub const RATE_HZ: std::ops::RangeInclusive<f64> = 1.0..=1000.0;

/// Past actions a `last_actions` term may stack.
pub const MAX_PAST_ACTIONS: usize = 16;

/// Ticks ahead a reference term may look.
pub const MAX_FRAMES_AHEAD: usize = 64;

/// The documented ranges of a term's own fields (its shaping is checked by the caller).
fn check_term(term: &Term) -> Result<(), TermFieldError> {
    let s = term.shaping();
    if let Some(c) = s.clip
        && !(c.is_finite() && c > 0.0)
    {
        return Err(TermFieldError::new(
            "clip",
            format!("clip = {c} must be a positive number"),
        ));
    }
    if !(s.scale.abs() <= 1e6 && s.offset.abs() <= 1e6) {
        return Err(TermFieldError::new(
            "scale",
            format!("scale {} / offset {} beyond ±1e6", s.scale, s.offset),
        ));
    }
    match term {
        Term::LastActions { k, .. } if !(1..=MAX_PAST_ACTIONS).contains(k) => Err(TermFieldError::new(
            "k",
            format!("k = {k} is outside [1, {MAX_PAST_ACTIONS}]"),
        )),
        Term::RefJointPos { frames, .. }
        | Term::RefJointVel { frames, .. }
        | Term::RefRootPose { frames, .. }
        | Term::RefBodyPos { frames, .. }
        | Term::RefKeypoints { frames, .. }
        | Term::RefRootLinVel { frames, .. }
        | Term::RefRootAngVel { frames, .. }
        | Term::RefRootHeight { frames, .. }
        | Term::RefRootRpy { frames, .. }
        | Term::RefRootQuat { frames, .. }
            if frames.is_empty() || frames.iter().any(|&f| f > MAX_FRAMES_AHEAD - 1) =>
        {
            Err(TermFieldError::new(
                "frames",
                format!(
                    "frames {frames:?}: one to many offsets, each at most {} ticks ahead",
                    MAX_FRAMES_AHEAD - 1
                ),
            ))
        }
        Term::RefRootLinVel { axes, .. } | Term::RefRootAngVel { axes, .. }
            if !valid_selection(axes, "xyz") =>
        {
            Err(TermFieldError::new(
                "axes",
                format!("axes = {axes:?}: one to three distinct letters of \"xyz\""),
            ))
        }
        Term::RefRootRpy { angles, .. } | Term::BaseRpy { angles, .. } if !valid_selection(angles, "rpy") => {
            Err(TermFieldError::new(
                "angles",
                format!("angles = {angles:?}: one to three distinct letters of \"rpy\" (roll, pitch, yaw)"),
            ))
        }
        Term::RefRootQuat {
            frame: RootFrame::Own,
            ..
        } => Err(TermFieldError::new(
            "frame",
            "frame = \"own\": the root's orientation in its own frame is the identity; give \"world\" or \"heading\"",
        )),
        Term::Command { values, .. } if values.iter().any(|v| !v.is_finite()) || values.len() > 64 => Err(
            TermFieldError::new("values", format!("values {values:?}: at most 64 finite numbers")),
        ),
        Term::GaitPhase {
            period_s,
            standing_below,
            ..
        } if !(period_s.is_finite()
            && (0.05..=60.0).contains(period_s)
            && standing_below.is_finite()
            && (0.0..=1.0).contains(standing_below)) =>
        {
            Err(TermFieldError::new(
                "period_s",
                format!(
                    "period_s = {period_s} (0.05–60 s) or standing_below = {standing_below} (0–1) is out of range"
                ),
            ))
        }
        Term::Phase {
            period_s,
            period_ticks,
            ..
        } => match (period_s, period_ticks) {
            (Some(p), None) if !(0.01..=3600.0).contains(p) => Err(TermFieldError::new(
                "period_s",
                format!("period_s = {p} is outside [0.01, 3600] s"),
            )),
            (None, Some(p)) if !(1..=1_000_000).contains(p) => Err(TermFieldError::new(
                "period_ticks",
                format!("period_ticks = {p} is outside [1, 1000000]"),
            )),
            (Some(_), Some(_)) | (None, None) => Err(TermFieldError::new(
                "period_s",
                "give exactly one of period_s and period_ticks",
            )),
            _ => Ok(()),
        },
        _ => Ok(()),
    }
}

/// A term's own field outside its documented range; the message names field, value and range.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{message}")]
pub struct TermFieldError {
    /// The field.
    pub field: &'static str,
    /// Its value against the range.
    pub message: String,
}

impl TermFieldError {
    fn new(field: &'static str, message: impl Into<String>) -> Self {
        Self {
            field,
            message: message.into(),
        }
    }
}

/// How actions become joint commands.
#[derive(Debug, Clone, Copy, PartialEq, serde::Deserialize, schemars::JsonSchema, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum ActionKind {
    /// Position setpoints: `default + scale · a`, sent with the robot's PD gains.
    Position,
    /// Normalised torques: `a · τ_max` per joint.
    Torque,
}

/// Scale of position actions.
#[derive(Debug, Clone, PartialEq, serde::Deserialize, schemars::JsonSchema, serde::Serialize)]
#[serde(untagged)]
pub enum ActionScale {
    /// The same for every joint.
    One(f64),
    /// Per joint, policy order.
    PerJoint(Vec<f64>),
}

impl ActionScale {
    /// Joint `i`'s scale (policy order; NaN past a list's end).
    pub fn of(&self, i: usize) -> f64 {
        match self {
            Self::One(s) => *s,
            Self::PerJoint(v) => v.get(i).copied().unwrap_or(f64::NAN),
        }
    }
}

impl Default for ActionSpec {
    fn default() -> Self {
        Self {
            kind: ActionKind::Position,
            scale: None,
            clip: None,
            rate_limit: None,
            lowpass_hz: None,
        }
    }
}

/// The action side of the contract.
#[derive(Debug, Clone, PartialEq, serde::Deserialize, schemars::JsonSchema, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct ActionSpec {
    /// What an action means.
    pub kind: ActionKind,
    /// Scale of a position action, rad per unit: one number, or one per joint in policy order
    /// (default: the ONNX metadata's `action_scale`; neither is an error).
    #[serde(default)]
    pub scale: Option<ActionScale>,
    /// Clip of the raw action.
    #[serde(default)]
    pub clip: Option<f64>,
    /// Largest change of a position target, rad/s.
    #[serde(default)]
    pub rate_limit: Option<f64>,
    /// First-order low-pass cut-off on targets, Hz.
    #[serde(default)]
    pub lowpass_hz: Option<f64>,
}

/// A policy manifest. Every field but `onnx` may be left to the ONNX file's metadata, as
/// training frameworks export it (see [`export`]).
#[derive(Debug, Clone, PartialEq, serde::Deserialize, schemars::JsonSchema, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct PolicyManifest {
    /// What this policy is (shown by `check` and `play`; default: the metadata's `run_path`).
    #[serde(default)]
    pub description: String,
    /// ONNX file, relative to the manifest.
    pub onnx: PathBuf,
    /// Control rate the policy was trained at, Hz, as the manifest gives it (`rate_hz`, 1–1000;
    /// none: the robot's `control_rate_hz`).
    #[serde(default, rename = "rate_hz", skip_serializing_if = "Option::is_none")]
    pub declared_rate_hz: Option<f64>,
    /// The rate the policy runs at: the declared one, else the robot's (set when the manifest is
    /// resolved against a robot).
    #[serde(skip)]
    pub rate_hz: f64,
    /// Joint names in the policy's order, mapped to the robot's joints by name (default: the
    /// ONNX metadata's `joint_names`).
    #[serde(default)]
    pub joints: Vec<String>,
    /// The pose actions are relative to, policy order (default: metadata `default_joint_pos`,
    /// else the robot's default pose).
    #[serde(default)]
    pub default_pose: Option<Vec<f64>>,
    /// PD stiffness per joint, policy order (default: metadata `joint_stiffness`, else robot.toml).
    #[serde(default)]
    pub stiffness: Option<Vec<f64>>,
    /// PD damping per joint, policy order (default: metadata `joint_damping`, else robot.toml).
    #[serde(default)]
    pub damping: Option<Vec<f64>>,
    /// Action mapping (default: position actions).
    #[serde(default)]
    pub action: ActionSpec,
    /// Observation terms, in order (default: the metadata's `observation_names`).
    #[serde(default)]
    pub observation: Vec<Term>,
    /// The body the reference motion is anchored to, for `motion_anchor_*` terms (default: the
    /// metadata's `anchor_body_name`).
    #[serde(default)]
    pub anchor_body: Option<String>,
    /// The bodies the reference motion tracks, MJCF names (default: the metadata's
    /// `body_names`): their position errors are reported.
    #[serde(default)]
    pub motion_bodies: Vec<String>,
    /// Live commands of a command-driven policy (its `command` term): names, ranges, ramps,
    /// keys, gamepad axes.
    #[serde(default)]
    pub commands: Option<CommandSpec>,
    /// The observation as blocks: the network's input is these blocks, in this order (give
    /// `observation` or `layout` with `block`, not both).
    #[serde(default)]
    pub layout: Vec<String>,
    /// Named blocks: a list of terms, the blocks `of` names laid end to end, or past copies of
    /// them (`frames`, `lag`, `order`, `fill`). A block may only name blocks defined above it.
    #[serde(default)]
    pub block: Vec<Block>,
    /// How the reference is played to this policy: its first-frame hold and how its velocities
    /// are computed.
    #[serde(default)]
    pub reference: ReferenceSpec,
}

/// One named block of the observation.
#[derive(Debug, Clone, PartialEq, serde::Deserialize, schemars::JsonSchema, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct Block {
    /// Its name (letters, digits, `_`), unique in the manifest.
    pub name: String,
    /// Its terms, in order (a block of terms).
    #[serde(default)]
    pub terms: Vec<Term>,
    /// The blocks it is made of, end to end (a block of blocks); with `frames`, the block whose
    /// past values it holds.
    #[serde(default)]
    pub of: Vec<String>,
    /// Past copies of `of`: how many ticks (1–64; none: the values of this tick).
    #[serde(default)]
    pub frames: Option<usize>,
    /// How many ticks back the newest copy is (default 1: the previous tick, the current one
    /// left out; 0: the current tick included). `frames + lag − 1` is at most 64.
    #[serde(default)]
    pub lag: Option<usize>,
    /// The copies' order (default `oldest_first`).
    #[serde(default)]
    pub order: Option<HistoryOrder>,
    /// What a copy holds for a tick before the policy's first (default `zeros`).
    #[serde(default)]
    pub fill: Option<HistoryFill>,
}

impl Block {
    /// How many ticks back the newest copy is.
    pub fn lag(&self) -> usize {
        self.lag.unwrap_or(1)
    }

    /// The copies' order.
    pub fn order(&self) -> HistoryOrder {
        self.order.unwrap_or(HistoryOrder::OldestFirst)
    }

    /// What a copy holds before the first tick.
    pub fn fill(&self) -> HistoryFill {
        self.fill.unwrap_or_default()
    }
}

/// What a block's history holds for ticks before the policy's first.
#[derive(
    Debug, Clone, Copy, Default, PartialEq, Eq, serde::Deserialize, schemars::JsonSchema, serde::Serialize,
)]
#[serde(rename_all = "snake_case")]
pub enum HistoryFill {
    /// Zeros (Isaac Lab's and TWIST2's history buffers at an episode's start).
    #[default]
    Zeros,
    /// The first tick's values.
    First,
}

/// Deepest history a block may hold, ticks.
pub const MAX_BLOCK_HISTORY: usize = 64;

/// How the reference is played to a policy.
#[derive(Debug, Clone, Default, PartialEq, serde::Deserialize, schemars::JsonSchema, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct ReferenceSpec {
    /// Seconds the reference holds its first frame after the policy takes control (0–60;
    /// default: 1.5 s for a policy that observes the start-up ramp ψ, which asks for it; 0 for
    /// every other: the motion moves from the first tick, as trainers play it). `play --ramp`
    /// overrides it.
    #[serde(default)]
    pub hold_s: Option<f64>,
    /// How the reference's velocities (joints, root) are computed.
    #[serde(default)]
    pub velocities: VelocityRule,
    /// What `check` does with a clip the robot could not follow exactly (the floor penetrated,
    /// feet that cannot carry the motion, torques beyond the motors).
    #[serde(default)]
    pub feasibility: Feasibility,
}

/// What a clip's physical findings mean for a policy.
#[derive(
    Debug, Clone, Copy, Default, PartialEq, Eq, serde::Deserialize, schemars::JsonSchema, serde::Serialize,
)]
#[serde(rename_all = "snake_case")]
pub enum Feasibility {
    /// Refused: the policy plays its reference as given (a reference follower, an export's own
    /// motion).
    #[default]
    Refuse,
    /// Reported, not refused: a tracker trained on retargeted human motion, whose references
    /// all penetrate the floor, slide and ask for more than the motors have, follows them as well
    /// as the robot can and is judged by how it tracks. Joint and speed limits still refuse.
    Report,
}

/// How a reference's velocities are computed; trainers differ.
#[derive(
    Debug, Clone, Copy, Default, PartialEq, Eq, serde::Deserialize, schemars::JsonSchema, serde::Serialize,
)]
#[serde(rename_all = "snake_case")]
pub enum VelocityRule {
    /// Central differences over the reference resampled at the control rate (one-sided at the
    /// ends); the root's rotation on SO(3).
    #[default]
    ControlTicks,
    /// Central differences over the motion file's own frames (`numpy.gradient`: one-sided at the
    /// ends; the root's rotation on SO(3): the rotation vector of `q[i+1]·q[i−1]⁻¹` over 2·dt),
    /// blended linearly between frames like the positions (TWIST2's motion library).
    MotionFrames,
}

/// The first-frame hold a policy asks for when neither it nor the operator gives one: ψ-observing
/// policies were trained with the reference held while ψ rises.
pub const RAMP_HOLD_S: f64 = 1.5;

impl PolicyManifest {
    /// A manifest that leaves everything to the metadata of `onnx`.
    pub fn for_onnx(onnx: PathBuf) -> Self {
        Self {
            description: String::new(),
            onnx,
            declared_rate_hz: None,
            rate_hz: 0.0,
            joints: Vec::new(),
            default_pose: None,
            stiffness: None,
            damping: None,
            action: ActionSpec::default(),
            observation: Vec::new(),
            anchor_body: None,
            motion_bodies: Vec::new(),
            commands: None,
            layout: Vec::new(),
            block: Vec::new(),
            reference: ReferenceSpec::default(),
        }
    }
}

/// A manifest that does not fit: the file, the place, what is wrong.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{file}: {place}: {message}")]
pub struct PolicyError {
    /// The manifest.
    pub file: PathBuf,
    /// Field path.
    pub place: String,
    /// What is wrong.
    pub message: String,
}

/// Fills what the manifest leaves out from the ONNX file's metadata (see [`export`]); the file
/// is opened only when something is left out.
fn fill_from_metadata(m: &mut PolicyManifest, onnx: &Path) -> Result<(), (String, String)> {
    let needs_anchor = m
        .observation
        .iter()
        .chain(m.block.iter().flat_map(|b| &b.terms))
        .any(Term::needs_anchor)
        && m.anchor_body.is_none();
    let needs = m.joints.is_empty()
        || m.action.scale.is_none()
        || m.default_pose.is_none()
        || m.stiffness.is_none()
        || m.damping.is_none()
        || (m.observation.is_empty() && m.block.is_empty())
        || needs_anchor;
    if !needs {
        return Ok(());
    }
    let facts = crate::onnx::read_facts(onnx).map_err(|e| ("onnx".to_owned(), e.to_string()))?;
    crate::export::fill(m, &facts)
}

/// The terms a manifest defines, each once, with where: its `observation` list, or the lists of
/// its blocks of terms (whose names and kinds are checked here).
fn term_definitions(m: &mut PolicyManifest) -> Result<Vec<TermDef>, (String, String)> {
    let e = |place: String, message: String| Err((place, message));
    if m.block.is_empty() {
        if !m.layout.is_empty() {
            return e(
                "layout".into(),
                "names blocks, but the manifest defines no [[block]]".into(),
            );
        }
        return Ok(m
            .observation
            .iter()
            .enumerate()
            .map(|(i, t)| TermDef {
                place: format!("observation[{i}] ({})", t.name()),
                term: t.clone(),
            })
            .collect());
    }
    if !m.observation.is_empty() {
        return e(
            "observation".into(),
            "give the observation as a list of terms ([[observation]]) or as blocks (layout and \
             [[block]]), not both"
                .into(),
        );
    }
    if m.layout.is_empty() {
        return e(
            "layout".into(),
            "missing: name the blocks the network's input is made of, in order (layout = [\"current\", …])"
                .into(),
        );
    }
    let mut defs = Vec::new();
    for (bi, b) in m.block.iter().enumerate() {
        let place = |field: &str| format!("block[{bi}] ({}).{field}", b.name);
        let good_name = !b.name.is_empty()
            && b.name.len() <= 64
            && b.name.bytes().all(|c| c.is_ascii_alphanumeric() || c == b'_');
        if !good_name {
            return e(
                format!("block[{bi}].name"),
                format!("{:?}: 1–64 letters, digits or _", b.name),
            );
        }
        if let Some(j) = m.block[..bi].iter().position(|o| o.name == b.name) {
            return e(place("name"), format!("block[{j}] has the same name"));
        }
        match (b.terms.is_empty(), b.of.is_empty()) {
            (false, false) => {
                return e(
                    place("of"),
                    "a block holds terms or other blocks (`of`), not both".into(),
                );
            }
            (true, true) => {
                return e(
                    place("terms"),
                    "the block holds no terms and no blocks (`of`)".into(),
                );
            }
            _ => {}
        }
        if b.frames.is_none() && (b.lag.is_some() || b.order.is_some() || b.fill.is_some()) {
            return e(
                place("frames"),
                "lag, order and fill describe a history: give `frames` (how many past copies)".into(),
            );
        }
        if let Some(f) = b.frames {
            if b.of.is_empty() {
                return e(place("of"), "a history needs the block it copies (`of`)".into());
            }
            if !(1..=MAX_BLOCK_HISTORY).contains(&f) {
                return e(
                    place("frames"),
                    format!("{f} is outside [1, {MAX_BLOCK_HISTORY}]"),
                );
            }
            if b.lag() + f - 1 > MAX_BLOCK_HISTORY {
                return e(
                    place("lag"),
                    format!(
                        "lag {} with {f} frames reaches {} ticks back, beyond the {MAX_BLOCK_HISTORY} a history holds",
                        b.lag(),
                        b.lag() + f - 1
                    ),
                );
            }
        }
        for (k, name) in b.of.iter().enumerate() {
            if !m.block[..bi].iter().any(|o| &o.name == name) {
                let known: Vec<&str> = m.block[..bi].iter().map(|o| o.name.as_str()).collect();
                return e(
                    format!("block[{bi}] ({}).of[{k}]", b.name),
                    format!(
                        "no block {name:?} above this one (a block names blocks defined before it: {})",
                        if known.is_empty() {
                            "none".into()
                        } else {
                            known.join(", ")
                        }
                    ),
                );
            }
        }
        for (ti, t) in b.terms.iter().enumerate() {
            defs.push(TermDef {
                place: format!("block[{bi}] ({}).terms[{ti}] ({})", b.name, t.name()),
                term: t.clone(),
            });
        }
    }
    for (i, name) in m.layout.iter().enumerate() {
        if !m.block.iter().any(|b| &b.name == name) {
            let known: Vec<&str> = m.block.iter().map(|b| b.name.as_str()).collect();
            return e(
                format!("layout[{i}]"),
                format!("no block {name:?} (blocks: {})", known.join(", ")),
            );
        }
    }
    Ok(defs)
}

/// The slots, the blocks and the observation's length.
type LaidOut = (Vec<TermSlot>, Vec<BlockSpan>, usize);

/// Longest observation a layout may build, values.
pub const MAX_OBSERVATION: usize = 65_536;

/// The observation's slots and blocks, in order: the terms of the `observation` list, or the
/// layout's blocks unfolded (a block of blocks end to end, a history's copies each delayed).
fn lay_out(m: &PolicyManifest, defs: &[TermDef], widths: &[usize]) -> Result<LaidOut, (String, String)> {
    let mut out = Unfold {
        m,
        defs,
        widths,
        first_def: Vec::new(),
        slots: Vec::new(),
        blocks: Vec::new(),
        at: 0,
    };
    if m.block.is_empty() {
        for source in 0..defs.len() {
            out.push_slot(source, 0, HistoryFill::Zeros)?;
        }
        out.blocks.push(BlockSpan {
            name: "observation".into(),
            range: 0..out.at,
            depth: 0,
        });
    } else {
        let mut first = 0;
        for b in &m.block {
            out.first_def.push(first);
            first += b.terms.len();
        }
        for name in &m.layout {
            let b = m.block.iter().position(|b| &b.name == name).unwrap_or(0);
            out.unfold(b, 0, HistoryFill::Zeros, 0, name.clone())?;
        }
    }
    Ok((out.slots, out.blocks, out.at))
}

/// The state of [`lay_out`].
struct Unfold<'a> {
    m: &'a PolicyManifest,
    defs: &'a [TermDef],
    widths: &'a [usize],
    /// Each block's first term definition.
    first_def: Vec<usize>,
    slots: Vec<TermSlot>,
    blocks: Vec<BlockSpan>,
    at: usize,
}

impl Unfold<'_> {
    fn push_slot(&mut self, source: usize, delay: usize, fill: HistoryFill) -> Result<(), (String, String)> {
        let term = &self.defs[source].term;
        let width = self.widths[source];
        let len = width * term.shaping().history;
        if self.at + len > MAX_OBSERVATION {
            return Err((
                "layout".into(),
                format!("the observation grows beyond {MAX_OBSERVATION} values"),
            ));
        }
        self.slots.push(TermSlot {
            term: term.clone(),
            range: self.at..self.at + len,
            width,
            source,
            delay,
            fill,
        });
        self.at += len;
        Ok(())
    }

    /// Lays block `b` out `delay` ticks old, under the name `name` at nesting `depth`.
    fn unfold(
        &mut self,
        b: usize,
        delay: usize,
        fill: HistoryFill,
        depth: usize,
        name: String,
    ) -> Result<(), (String, String)> {
        let block = &self.m.block[b];
        let span = self.blocks.len();
        self.blocks.push(BlockSpan {
            name,
            range: self.at..self.at,
            depth,
        });
        let children = |s: &Self, of: &str| s.m.block[..b].iter().position(|o| o.name == of).unwrap_or(0);
        match block.frames {
            None if block.of.is_empty() => {
                for k in 0..block.terms.len() {
                    self.push_slot(self.first_def[b] + k, delay, fill)?;
                }
            }
            None => {
                for of in &block.of {
                    let c = children(self, of);
                    self.unfold(c, delay, fill, depth + 1, of.clone())?;
                }
            }
            Some(frames) => {
                for j in 0..frames {
                    let back = match block.order() {
                        HistoryOrder::OldestFirst => block.lag() + frames - 1 - j,
                        HistoryOrder::NewestFirst => block.lag() + j,
                    };
                    if delay + back > MAX_BLOCK_HISTORY {
                        return Err((
                            format!("block[{b}] ({}).frames", block.name),
                            format!(
                                "nested histories reach {} ticks back; at most {MAX_BLOCK_HISTORY}",
                                delay + back
                            ),
                        ));
                    }
                    let copy = self.blocks.len();
                    self.blocks.push(BlockSpan {
                        name: format!("{}[t-{}]", block.name, delay + back),
                        range: self.at..self.at,
                        depth: depth + 1,
                    });
                    for of in &block.of {
                        let c = children(self, of);
                        self.unfold(c, delay + back, block.fill(), depth + 2, of.clone())?;
                    }
                    self.blocks[copy].range.end = self.at;
                }
            }
        }
        self.blocks[span].range.end = self.at;
        Ok(())
    }
}

/// The anchor and the motion's bodies must be bodies of the robot's compiled model.
fn check_bodies(robot: &Robot, m: &PolicyManifest) -> Result<(), (String, String)> {
    let missing = |name: &str| !robot.mjcf.bodies.iter().any(|b| b == name);
    if let Some(a) = &m.anchor_body
        && missing(a)
    {
        return Err((
            "anchor_body".into(),
            format!("{a:?} is not a body of {}", robot.mjcf_path.display()),
        ));
    }
    let absent: Vec<&str> = m
        .motion_bodies
        .iter()
        .map(String::as_str)
        .filter(|b| missing(b))
        .collect();
    if !absent.is_empty() {
        return Err((
            "motion_bodies".into(),
            format!(
                "not bodies of {}: {}",
                robot.mjcf_path.display(),
                absent.join(", ")
            ),
        ));
    }
    Ok(())
}

/// One term's slot in the observation vector.
#[derive(Debug, Clone, PartialEq)]
pub struct TermSlot {
    /// The term.
    pub term: Term,
    /// Its index range in the observation.
    pub range: Range<usize>,
    /// Values per history step.
    pub width: usize,
    /// Which term definition fills it ([`PolicyLayout::terms`]): each is computed once a tick,
    /// however many slots show it.
    pub source: usize,
    /// How many ticks old its values are (0: this tick's).
    pub delay: usize,
    /// What it holds for ticks before the policy's first (delayed slots).
    pub fill: HistoryFill,
}

/// A term as the manifest defines it, and where.
#[derive(Debug, Clone, PartialEq)]
pub struct TermDef {
    /// The term.
    pub term: Term,
    /// Where the manifest defines it (`observation[3] (joint_pos)`, `block[1] (proprio).terms[2]
    /// (joint_vel)`).
    pub place: String,
}

/// A block of the observation and the values it spans.
#[derive(Debug, Clone, PartialEq)]
pub struct BlockSpan {
    /// The block's name, with the copy's tick for a history's copies (`history[t-3]`).
    pub name: String,
    /// Its index range in the observation.
    pub range: Range<usize>,
    /// Nesting depth (0: a block of the layout).
    pub depth: usize,
}

/// A manifest resolved against a robot.
#[derive(Debug, Clone, PartialEq)]
pub struct PolicyLayout {
    /// The manifest.
    pub manifest: PolicyManifest,
    /// The manifest file.
    pub path: PathBuf,
    /// The ONNX file (resolved).
    pub onnx_path: PathBuf,
    /// For each policy joint, the robot joint index.
    pub robot_index: Vec<usize>,
    /// Terms with their ranges, in the observation's order (a term shown in several blocks, or
    /// as past copies, has a slot for each place).
    pub slots: Vec<TermSlot>,
    /// The term definitions the slots show, each computed once a tick.
    pub terms: Vec<TermDef>,
    /// The blocks, outermost first (one `observation` block for a manifest of plain terms).
    pub blocks: Vec<BlockSpan>,
    /// Observation length.
    pub obs_len: usize,
    /// The pose actions and relative terms refer to, robot order.
    pub default_q: Vec<f64>,
    /// Stiffness per joint, robot order.
    pub kp: Vec<f64>,
    /// Damping per joint, robot order.
    pub kd: Vec<f64>,
    /// Scale of position actions per joint, robot order.
    pub action_scale: Vec<f64>,
}

/// How far outside its joint limits an exported default pose may lie and be clamped: the
/// exporters round to 3 decimals.
pub const METADATA_ROUNDING: f64 = 5e-4;

impl PolicyLayout {
    /// Loads `path` and resolves it against `robot`. `path` is a manifest (TOML), or an ONNX
    /// export whose metadata carries the whole contract (no manifest).
    pub fn load(path: &Path, robot: &Robot) -> Result<Self, PolicyError> {
        if path.extension().is_some_and(|e| e.eq_ignore_ascii_case("onnx")) {
            let file = path.file_name().map(PathBuf::from).unwrap_or_default();
            return Self::resolve(path, PolicyManifest::for_onnx(file), robot);
        }
        let text = robots::read_text(path).map_err(|message| PolicyError {
            file: path.to_path_buf(),
            place: "file".to_owned(),
            message: message.to_string(),
        })?;
        Self::parse(path, &text, robot)
    }

    /// Resolves the manifest `text` (read from `path`, which names it in errors and locates the
    /// ONNX file beside it) against `robot`.
    pub fn parse(path: &Path, text: &str, robot: &Robot) -> Result<Self, PolicyError> {
        let err = |place: &str, message: String| PolicyError {
            file: path.to_path_buf(),
            place: place.to_owned(),
            message,
        };
        let manifest: PolicyManifest = toml::from_str(text).map_err(|e| {
            let line = e
                .span()
                .map_or(0, |s| text[..s.start.min(text.len())].matches('\n').count() + 1);
            err(&format!("line {line}"), e.message().to_owned())
        })?;
        Self::resolve(path, manifest, robot)
    }

    /// Resolves `manifest` (from `path`) against `robot`, filling what it leaves out from the
    /// ONNX file's metadata.
    fn resolve(path: &Path, mut manifest: PolicyManifest, robot: &Robot) -> Result<Self, PolicyError> {
        let err = |place: &str, message: String| PolicyError {
            file: path.to_path_buf(),
            place: place.to_owned(),
            message,
        };
        let onnx_path = path.parent().unwrap_or(Path::new(".")).join(&manifest.onnx);
        fill_from_metadata(&mut manifest, &onnx_path).map_err(|(place, m)| err(&place, m))?;
        manifest.rate_hz = manifest.declared_rate_hz.unwrap_or(robot.config.control_rate_hz);
        let names: Vec<&str> = robot.config.joints.iter().map(|j| j.name.as_str()).collect();
        let mut robot_index = Vec::with_capacity(manifest.joints.len());
        for (i, name) in manifest.joints.iter().enumerate() {
            let Some(r) = names.iter().position(|n| n == name) else {
                return Err(err(
                    &format!("joints[{i}]"),
                    format!("{name:?} is not a joint of robot {}", robot.config.name),
                ));
            };
            if robot_index.contains(&r) {
                return Err(err(&format!("joints[{i}]"), format!("{name:?} is listed twice")));
            }
            robot_index.push(r);
        }
        if robot_index.len() != names.len() {
            let missing: Vec<_> = names
                .iter()
                .enumerate()
                .filter(|(r, _)| !robot_index.contains(r))
                .map(|(_, n)| *n)
                .collect();
            return Err(err(
                "joints",
                format!("robot joints not driven by the policy: {}", missing.join(", ")),
            ));
        }
        if !(RATE_HZ.contains(&manifest.rate_hz)) {
            return Err(err(
                "rate_hz",
                format!(
                    "{} Hz is outside [{}, {}]",
                    robots::num(manifest.rate_hz),
                    RATE_HZ.start(),
                    RATE_HZ.end()
                ),
            ));
        }
        if (manifest.rate_hz - robot.config.control_rate_hz).abs() > 1e-9 {
            return Err(err(
                "rate_hz",
                format!(
                    "{} Hz, but {} runs its loop at control_rate_hz = {} Hz",
                    robots::num(manifest.rate_hz),
                    robot.config.name,
                    robots::num(robot.config.control_rate_hz)
                ),
            ));
        }
        let a = &manifest.action;
        let nyquist = manifest.rate_hz / 2.0;
        let scales = match &a.scale {
            // Torques are a share of each joint's limit: no scale.
            None if a.kind == ActionKind::Torque => vec![1.0; manifest.joints.len()],
            // A scale changes what the robot does: a missing one is an error, never 1.
            None => {
                return Err(err(
                    "action.scale",
                    "missing: the manifest's [action] gives no scale and the ONNX file has no \
                     action_scale metadata (a training export writes it); give it as `scale = …` \
                     (one number, or one per joint)"
                        .to_owned(),
                ));
            }
            Some(ActionScale::One(v)) => vec![*v; manifest.joints.len()],
            Some(ActionScale::PerJoint(v)) if v.len() == manifest.joints.len() => v.clone(),
            Some(ActionScale::PerJoint(v)) => {
                return Err(err(
                    "action.scale",
                    format!("{} values for {} joints", v.len(), manifest.joints.len()),
                ));
            }
        };
        for (p, v) in scales.iter().enumerate() {
            if !(1e-6..=10.0).contains(v) {
                let place = match a.scale {
                    Some(ActionScale::PerJoint(_)) => format!("action.scale[{p}] ({})", manifest.joints[p]),
                    _ => "action.scale".to_owned(),
                };
                return Err(err(&place, format!("{} is outside [1e-06, 10]", robots::num(*v))));
            }
        }
        for (field, v, range) in [
            ("action.clip", a.clip, 1e-6..=100.0),
            ("action.rate_limit", a.rate_limit, 1e-3..=100.0),
            ("action.lowpass_hz", a.lowpass_hz, 0.1..=nyquist),
        ] {
            if let Some(v) = v
                && !range.contains(&v)
            {
                return Err(err(
                    field,
                    format!(
                        "{} is outside [{}, {}]",
                        robots::num(v),
                        range.start(),
                        range.end()
                    ),
                ));
            }
        }
        // What the buses can honour: serial servos (Dynamixel, Feetech) run their own position
        // loop (gains and a torque cap), they take no torque commands.
        if a.kind == ActionKind::Torque
            && let Some(j) = robot.config.joints.iter().find(|j| {
                robot
                    .bus(&j.bus)
                    .is_some_and(|b| matches!(b.kind, robots::BusKind::Dynamixel | robots::BusKind::Feetech))
            })
        {
            return Err(err(
                "action.kind",
                format!(
                    "torque actions cannot drive joint {} ({} on serial servo bus {}): its servo \
                     takes position goals with gains, not torque commands",
                    j.name, j.model, j.bus
                ),
            ));
        }
        if let Some(spec) = &manifest.commands {
            spec.check().map_err(|(place, m)| err(&place, m))?;
        }
        let n = names.len();
        let feet = robot.config.feet.len();
        let mut defs = term_definitions(&mut manifest).map_err(|(place, m)| err(&place, m))?;
        for TermDef { term, place } in &mut defs {
            let Term::Command { values, .. } = term else {
                continue;
            };
            let place = format!("{place}.values");
            match &manifest.commands {
                Some(spec) if values.is_empty() => *values = spec.defaults(),
                Some(spec) => spec
                    .check_values(values)
                    .map_err(|e| err(&place, e.to_string()))?,
                None if values.is_empty() => {
                    return Err(err(
                        &place,
                        "no values, and no [commands] section to take them from".into(),
                    ));
                }
                None => {}
            }
        }
        if manifest.commands.is_some()
            && defs
                .iter()
                .filter(|d| matches!(d.term, Term::Command { .. }))
                .count()
                != 1
        {
            return Err(err(
                "commands",
                "live commands need exactly one `command` term in the observation".into(),
            ));
        }
        let mut widths = Vec::with_capacity(defs.len());
        for (i, TermDef { term, place }) in defs.iter().enumerate() {
            let s = term.shaping();
            check_term(term).map_err(|e| err(place, e.to_string()))?;
            // The same term twice in one list is a paste error; the same term in two blocks is
            // what blocks are for.
            let list = |p: &str| p.rsplit_once('[').map_or(String::new(), |(l, _)| l.to_owned());
            if let Some(j) = defs[..i]
                .iter()
                .position(|d| &d.term == term && list(&d.place) == list(place))
            {
                return Err(err(
                    place,
                    format!(
                        "the same term as {}: a term is observed once in a list (a copy pasted twice?)",
                        defs[j].place
                    ),
                ));
            }
            if let Term::GaitPhase {
                period_s,
                standing_below,
                ..
            } = term
                && let Some(first) = defs.iter().find_map(|d| match d.term {
                    Term::GaitPhase {
                        period_s,
                        standing_below,
                        ..
                    } => Some((period_s, standing_below)),
                    _ => None,
                })
                && first != (*period_s, *standing_below)
            {
                return Err(err(
                    place,
                    "every gait_phase term reads the same gait: give them one period_s and standing_below"
                        .into(),
                ));
            }
            if s.history == 0 || s.history > 64 || !(s.scale.is_finite() && s.offset.is_finite()) {
                return Err(err(
                    place,
                    format!(
                        "history {} / scale {} / offset {} not allowed",
                        s.history, s.scale, s.offset
                    ),
                ));
            }
            if !manifest.block.is_empty() && s.input.is_some() {
                return Err(err(
                    place,
                    "input: a layout of blocks fills the model's one observation input".into(),
                ));
            }
            let width = term.width(n, feet);
            if width == 0 {
                return Err(err(place, "the term has no values".into()));
            }
            for (field, values) in [("scales", &s.scales), ("offsets", &s.offsets)] {
                if let Some(v) = values
                    && (v.len() != width || v.iter().any(|x| !x.is_finite() || x.abs() > 1e6))
                {
                    return Err(err(
                        place,
                        format!(
                            "{field}: {width} finite values within ±1e6 needed, one per value, got {}",
                            v.len()
                        ),
                    ));
                }
            }
            if let Term::RefBodyPos { bodies, .. } = term
                && let Some(b) = bodies.iter().find(|b| !robot.mjcf.bodies.contains(b))
            {
                return Err(err(
                    place,
                    format!("{b:?} is not a body of {}", robot.mjcf_path.display()),
                ));
            }
            widths.push(width);
        }
        if let Some(d) = defs.iter().find(|d| d.term.needs_anchor())
            && manifest.anchor_body.is_none()
        {
            return Err(err(
                &d.place,
                "needs the motion's anchor body: give anchor_body (exports: anchor_body_name)".into(),
            ));
        }
        if let Some(h) = manifest.reference.hold_s
            && !(h.is_finite() && (0.0..=60.0).contains(&h))
        {
            return Err(err(
                "reference.hold_s",
                format!("{} is outside [0, 60] s", robots::num(h)),
            ));
        }
        let (slots, blocks, at) = lay_out(&manifest, &defs, &widths).map_err(|(place, m)| err(&place, m))?;
        if manifest.anchor_body.is_some() || !manifest.motion_bodies.is_empty() {
            check_bodies(robot, &manifest).map_err(|(place, m)| err(&place, m))?;
        }
        // Per-joint vectors in robot order: the policy's where it declares them, else the robot's.
        let joints = &robot.config.joints;
        let per_joint = |field: &str, given: &Option<Vec<f64>>, robot_value: &dyn Fn(usize) -> f64| {
            let mut out: Vec<f64> = (0..joints.len()).map(robot_value).collect();
            if let Some(values) = given {
                if values.len() != robot_index.len() {
                    return Err(err(
                        field,
                        format!("{} values for {} joints", values.len(), robot_index.len()),
                    ));
                }
                for (p, (&r, &v)) in robot_index.iter().zip(values).enumerate() {
                    if !v.is_finite() {
                        return Err(err(&format!("{field}[{p}]"), format!("{v} is not finite")));
                    }
                    out[r] = v;
                }
            }
            Ok(out)
        };
        let mut default_q = per_joint("default_pose", &manifest.default_pose, &|r| {
            joints[r].default_position
        })?;
        // An exported default pose is rounded to 3 decimals: a joint at its limit may come out
        // just beyond it.
        for (q, j) in default_q.iter_mut().zip(joints) {
            let [lo, hi] = j.position_limits;
            if (lo - METADATA_ROUNDING..=hi + METADATA_ROUNDING).contains(q) {
                *q = q.clamp(lo, hi);
            }
        }
        let mut action_scale = vec![1.0; joints.len()];
        for (&r, &v) in robot_index.iter().zip(&scales) {
            action_scale[r] = v;
        }
        let kp = per_joint("stiffness", &manifest.stiffness, &|r| joints[r].kp)?;
        let kd = per_joint("damping", &manifest.damping, &|r| joints[r].kd)?;
        for (r, j) in joints.iter().enumerate() {
            let [lo, hi] = j.position_limits;
            if !(lo..=hi).contains(&default_q[r]) {
                return Err(err(
                    "default_pose",
                    format!("{} = {} is outside its limits [{lo}, {hi}]", j.name, default_q[r]),
                ));
            }
            if kp[r] < 0.0 || kd[r] < 0.0 {
                return Err(err(
                    "stiffness",
                    format!("{}: kp {} / kd {} must not be negative", j.name, kp[r], kd[r]),
                ));
            }
            robot
                .check_gains(j, kp[r], kd[r])
                .map_err(|e| err("stiffness", e.to_string()))?;
        }
        Ok(Self {
            manifest,
            path: path.to_path_buf(),
            onnx_path,
            robot_index,
            slots,
            terms: defs,
            blocks,
            obs_len: at,
            default_q,
            kp,
            kd,
            action_scale,
        })
    }

    /// Replaces the values of the (first) `command` term, e.g. from the command line. The count
    /// must match the manifest's.
    pub fn set_command(&mut self, values: &[f64]) -> Result<(), PolicyError> {
        let err = |message: String| PolicyError {
            file: self.path.clone(),
            place: "command".into(),
            message,
        };
        let Some(current) = self.command_values() else {
            return Err(err("the policy has no `command` term to set".into()));
        };
        if current.len() != values.len() || values.iter().any(|v| !v.is_finite()) {
            return Err(err(format!(
                "{} finite values needed, got {values:?}",
                current.len()
            )));
        }
        if let Some(spec) = &self.manifest.commands {
            spec.check_values(values).map_err(|e| PolicyError {
                file: self.path.clone(),
                place: "commands.ranges".into(),
                message: e.to_string(),
            })?;
        }
        // Every place the term shows (its definition, and each block or copy that shows it).
        let terms = self.slots.iter_mut().map(|s| &mut s.term);
        for term in terms.chain(self.terms.iter_mut().map(|d| &mut d.term)) {
            if let Term::Command { values: current, .. } = term {
                current.copy_from_slice(values);
            }
        }
        Ok(())
    }

    /// The values the `command` term starts with (what `--command` or the defaults set).
    pub fn command_values(&self) -> Option<&[f64]> {
        self.slots.iter().find_map(|s| match &s.term {
            Term::Command { values, .. } => Some(values.as_slice()),
            _ => None,
        })
    }

    /// Whether any term reads the reference (a clip, a motion, the start-up ramp ψ aside): a
    /// policy without one is command-driven and runs with no clip.
    pub fn reads_reference(&self) -> bool {
        self.slots.iter().any(|s| {
            matches!(
                s.term,
                Term::RefJointPos { .. }
                    | Term::RefJointVel { .. }
                    | Term::RefRootPose { .. }
                    | Term::RefBodyPos { .. }
                    | Term::RefKeypoints { .. }
                    | Term::MotionCommand(_)
                    | Term::MotionAnchorPosB(_)
                    | Term::MotionAnchorOriB(_)
                    | Term::TimeStep(_)
                    | Term::TrackerPoses { .. }
                    | Term::RefRootLinVel { .. }
                    | Term::RefRootAngVel { .. }
                    | Term::RefRootHeight { .. }
                    | Term::RefRootRpy { .. }
                    | Term::RefRootQuat { .. }
            )
        })
    }

    /// Seconds the reference holds its first frame after the policy takes control: the
    /// manifest's `[reference] hold_s`, else [`RAMP_HOLD_S`] for a policy that observes the
    /// start-up ramp ψ (trained with the reference held while ψ rises) and 0 for any other.
    pub fn hold_s(&self) -> f64 {
        self.manifest.reference.hold_s.unwrap_or_else(|| {
            if self.terms.iter().any(|d| matches!(d.term, Term::Ramp(_))) {
                RAMP_HOLD_S
            } else {
                0.0
            }
        })
    }

    /// What a slot is called where several show one term: the term's name for a plain list;
    /// with blocks, the layout block (or the history copy) it sits in, then the term —
    /// `current.ref_joint_pos`, `history[t-3].ref_joint_pos`, `future.ref_joint_pos`.
    pub fn slot_label(&self, slot: &TermSlot) -> String {
        if self.manifest.block.is_empty() {
            return slot.term.name().to_owned();
        }
        let at = slot.range.start;
        let holding = |b: &&BlockSpan| b.range.contains(&at);
        let place = self
            .blocks
            .iter()
            .filter(holding)
            .find(|b| b.name.contains("[t-"))
            .or_else(|| self.blocks.iter().filter(holding).find(|b| b.depth == 0))
            .map_or("observation", |b| b.name.as_str());
        format!("{place}.{}", slot.term.name())
    }

    /// Whether any term needs simulation ground truth.
    pub fn needs_ground_truth(&self) -> bool {
        self.slots.iter().any(|s| s.term.needs_ground_truth())
    }

    /// Fits the layout to the model: the terms of each ONNX input (by the terms' `input`, default
    /// the first) are laid out contiguously in the model's input order; each input's size and the
    /// action count must match.
    pub fn bind_model(&mut self, inputs: &[(String, usize)], output: usize) -> Result<(), PolicyError> {
        let err = |place: &str, message: String| PolicyError {
            file: self.path.clone(),
            place: place.to_owned(),
            message,
        };
        let names: Vec<&str> = inputs.iter().map(|i| i.0.as_str()).collect();
        for (k, s) in self.slots.iter().enumerate() {
            if let Some(name) = &s.term.shaping().input
                && !names.contains(&name.as_str())
            {
                return Err(err(
                    &format!("observation[{k}] ({})", s.term.name()),
                    format!(
                        "input {name:?} is not an input of {} (inputs: {})",
                        self.onnx_path.display(),
                        names.join(", ")
                    ),
                ));
            }
        }
        if inputs.len() > 1 && self.slots.iter().all(|s| s.term.shaping().input.is_none()) {
            return Err(err(
                "observation",
                format!(
                    "{} has inputs {}: give each term its `input`",
                    self.onnx_path.display(),
                    names.join(", ")
                ),
            ));
        }
        let mut at = 0;
        let mut ranges = vec![0..0; self.slots.len()];
        // Terms without an input go to the one named `obs`, else the first.
        let default_input = names.iter().position(|n| *n == "obs").unwrap_or(0);
        for (i, (name, len)) in inputs.iter().enumerate() {
            let start = at;
            for (k, s) in self.slots.iter().enumerate() {
                if s.term
                    .shaping()
                    .input
                    .as_deref()
                    .map_or(i == default_input, |n| n == name)
                {
                    let n = s.range.len();
                    ranges[k] = at..at + n;
                    at += n;
                }
            }
            if at - start != *len {
                return Err(err(
                    "observation",
                    format!(
                        "the terms of input {name:?} add up to {} values but {} takes {len}",
                        at - start,
                        self.onnx_path.display()
                    ),
                ));
            }
        }
        for (s, r) in self.slots.iter_mut().zip(ranges) {
            s.range = r;
        }
        if output != self.robot_index.len() {
            return Err(err(
                "joints",
                format!(
                    "{} joints but {} outputs {output} actions",
                    self.robot_index.len(),
                    self.onnx_path.display()
                ),
            ));
        }
        Ok(())
    }

    /// The resolved layout, one line per term.
    pub fn describe(&self) -> String {
        let mut out = String::new();
        let blocks = !self.manifest.block.is_empty();
        let mut next_block = 0;
        let mut top = 0..0;
        let mut shown: Vec<usize> = Vec::new();
        let mut depth = 0;
        // A history's copies after its first are one line each: what they hold is listed once.
        let (mut copies, mut folded) = (0, 0..0);
        for s in &self.slots {
            if blocks {
                // The blocks that start here, outermost first; a term a layout block already
                // showed (a history's older copies) is not listed again.
                while let Some(b) = self
                    .blocks
                    .get(next_block)
                    .filter(|b| b.range.start <= s.range.start)
                {
                    next_block += 1;
                    if b.depth == 0 {
                        top = b.range.clone();
                        shown.clear();
                        copies = 0;
                    }
                    if folded.contains(&b.range.start) {
                        continue;
                    }
                    out.push_str(&format!(
                        "  {:indent$}block {} [{}..{}) {} values\n",
                        "",
                        b.name,
                        b.range.start,
                        b.range.end,
                        b.range.len(),
                        indent = 2 * b.depth
                    ));
                    depth = b.depth + 1;
                    if b.name.contains("[t-") {
                        copies += 1;
                        if copies > 1 {
                            folded = b.range.clone();
                        }
                    }
                }
                if top.contains(&s.range.start) && shown.contains(&s.source) {
                    continue;
                }
                shown.push(s.source);
            }
            let sh = s.term.shaping();
            let scale = match &sh.scales {
                Some(v) => format!("scales {v:?}"),
                None => format!("scale {}", sh.scale),
            };
            let offset = match &sh.offsets {
                Some(v) => format!("offsets {v:?}"),
                None => format!("offset {}", sh.offset),
            };
            let mut extra = sh.clip.map_or(String::new(), |c| format!(" clip ±{c}"));
            if sh.history > 1 && sh.history_order == HistoryOrder::OldestFirst {
                extra.push_str(" oldest first");
            }
            match &s.term {
                Term::GaitPhase {
                    part,
                    period_s,
                    standing_below,
                    ..
                } => {
                    extra.push_str(&format!(
                        "  {} of each leg's phase (left, right), period {period_s} s, advanced before each \
                         observation, held at π while the command's norm is below {standing_below}",
                        match part {
                            Trig::Sin => "sin",
                            Trig::Cos => "cos",
                        }
                    ));
                }
                Term::Phase {
                    period_s,
                    period_ticks,
                    advance_first,
                    sin_first,
                    ..
                } => {
                    let period = period_ticks.map_or_else(
                        || format!("{} s", period_s.unwrap_or(0.0)),
                        |t| format!("{t} ticks"),
                    );
                    extra.push_str(&format!(
                        "  period {period}, {}, {}",
                        if *advance_first {
                            "advances before the first observation"
                        } else {
                            "0 at the first observation"
                        },
                        if *sin_first { "[sin, cos]" } else { "[cos, sin]" }
                    ));
                }
                Term::Command { values, .. } => {
                    let live = if self.manifest.commands.is_some() {
                        "live, starting at"
                    } else {
                        "constant"
                    };
                    extra.push_str(&format!("  {live} {values:?}"));
                }
                Term::JointPos { relative: true, .. } | Term::RefJointPos { relative: true, .. } => {
                    extra.push_str("  minus the default pose");
                }
                _ => {}
            }
            if let Some(i) = &sh.input {
                extra.push_str(&format!("  → input {i:?}"));
            }
            if s.delay > 0 {
                let fill = match s.fill {
                    HistoryFill::Zeros => "zeros",
                    HistoryFill::First => "the first tick's values",
                };
                extra.push_str(&format!("  {} ticks old ({fill} before)", s.delay));
            }
            extra.push_str(&match &s.term {
                Term::RefRootLinVel {
                    frames, frame, axes, ..
                }
                | Term::RefRootAngVel {
                    frames, frame, axes, ..
                } => {
                    let frame = match frame {
                        RootFrame::Own => "own",
                        RootFrame::Heading => "heading",
                        RootFrame::World => "world",
                    };
                    format!("  {axes} in the reference root's {frame} frame, frames {frames:?}")
                }
                Term::RefRootRpy { frames, angles, .. } => format!("  {angles}, frames {frames:?}"),
                Term::RefRootHeight { frames, .. }
                | Term::RefRootQuat { frames, .. }
                | Term::RefJointPos { frames, .. }
                | Term::RefJointVel { frames, .. } => format!("  frames {frames:?}"),
                Term::BaseRpy { angles, .. } => format!("  {angles} of the IMU's orientation"),
                _ => String::new(),
            });
            out.push_str(&format!(
                "  {:indent$}[{:>4}..{:<4}) {:<18} {:>3} × {} history  {scale} {offset}{extra}\n",
                "",
                s.range.start,
                s.range.end,
                s.term.name(),
                s.width,
                sh.history,
                indent = 2 * depth,
            ));
        }
        out
    }

    /// What the action side and the per-joint values resolved to, one line each: the joint
    /// mapping, the action mapping, the default pose and gains (policy order).
    pub fn describe_action(&self) -> String {
        let a = &self.manifest.action;
        let names = &self.manifest.joints;
        let per_joint = |v: &[f64]| {
            let first = v.first().copied().unwrap_or(0.0);
            if v.iter().all(|x| (x - first).abs() < 1e-12) {
                format!("{first} for every joint")
            } else {
                let p: Vec<String> = self.robot_index.iter().map(|&r| format!("{}", v[r])).collect();
                format!("[{}] (policy order)", p.join(", "))
            }
        };
        let mapping: Vec<String> = names
            .iter()
            .zip(&self.robot_index)
            .enumerate()
            .map(|(p, (n, &r))| if p == r { n.clone() } else { format!("{n}→{r}") })
            .collect();
        let mut out = format!(
            "  joints   {} in policy order (→ robot.toml index where it differs): {}\n",
            names.len(),
            mapping.join(", ")
        );
        out.push_str(&format!(
            "  action   {:?}: {}; scale {}; clip {}; rate limit {}; low-pass {}\n",
            a.kind,
            match a.kind {
                ActionKind::Position => "target = default pose + scale · action",
                ActionKind::Torque => "torque = action · the joint's torque limit",
            },
            per_joint(&self.action_scale),
            a.clip.map_or("none".into(), |c| format!("±{c}")),
            a.rate_limit.map_or("none".into(), |r| format!("{r} rad/s")),
            a.lowpass_hz.map_or("none".into(), |f| format!("{f} Hz")),
        ));
        fn from(given: bool, what: &'static str) -> &'static str {
            if given { "the policy's" } else { what }
        }
        out.push_str(&format!(
            "  default  {} ({})\n",
            per_joint(&self.default_q),
            from(
                self.manifest.default_pose.is_some(),
                "robot.toml's default_position"
            )
        ));
        out.push_str(&format!(
            "  gains    kp {} ({}); kd {} ({})\n",
            per_joint(&self.kp),
            from(self.manifest.stiffness.is_some(), "robot.toml's"),
            per_joint(&self.kd),
            from(self.manifest.damping.is_some(), "robot.toml's"),
        ));
        out
    }
}
