//! Where the reference is at each tick: the clip's frames (or those of a [`LiveSource`]: a
//! teleoperator's stream, a motion generator's plans), held at the first frame while the start-up
//! ramp ψ rises, then played, then held, blended to the default pose or looped at the end; and the
//! frames ahead the policy looks at, in its joint order. Every buffer is sized at construction.

use std::time::Instant;

use human::live::{LiveReader, TRACKER_VALUES};

use std::path::{Path, PathBuf};

use policy::PolicyLayout;
use policy::onnx::OnnxModel;
use robots::Robot;

use crate::clip::{Clip, Reference};
use crate::error::PlayError;
use crate::generator::PlanReader;
use crate::motion::{Alignment, EmbeddedMotion, MODEL_MISMATCH_M, MotionFrame, worst_body_mismatch};
use crate::options::{EndMode, PlayOptions};
use policy::ReferenceView;

/// The reference frames the observation sees at one tick, policy order.
#[derive(Debug)]
struct Frames {
    q: Vec<Vec<f64>>,
    qd: Vec<Vec<f64>>,
    root: Vec<[f64; 7]>,
    /// The root's linear and angular velocity per frame, world frame.
    root_lin_vel: Vec<[f64; 3]>,
    root_ang_vel: Vec<[f64; 3]>,
    body: Vec<Vec<f64>>,
    /// The anchor of this tick, aligned.
    anchor: [f64; 7],
    /// The `ref_keypoints` values per frame.
    keypoints: Vec<Vec<f64>>,
}

impl ReferenceView for Frames {
    fn joint_pos(&self, offset: usize) -> &[f64] {
        &self.q[offset.min(self.q.len() - 1)]
    }
    fn joint_vel(&self, offset: usize) -> &[f64] {
        &self.qd[offset.min(self.qd.len() - 1)]
    }
    fn root_pose(&self, offset: usize) -> [f64; 7] {
        self.root[offset.min(self.root.len() - 1)]
    }
    fn body_pos(&self, offset: usize) -> &[f64] {
        &self.body[offset.min(self.body.len() - 1)]
    }
    fn anchor_pose(&self) -> [f64; 7] {
        self.anchor
    }
    fn keypoints(&self, offset: usize) -> &[f64] {
        &self.keypoints[offset.min(self.keypoints.len() - 1)]
    }
    fn root_lin_vel(&self, offset: usize) -> [f64; 3] {
        self.root_lin_vel[offset.min(self.root_lin_vel.len() - 1)]
    }
    fn root_ang_vel(&self, offset: usize) -> [f64; 3] {
        self.root_ang_vel[offset.min(self.root_ang_vel.len() - 1)]
    }
}

/// What a [`LiveSource`] did with a tick.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Fed {
    /// It wrote the one-frame table the cursor plays (its row 0: joints, velocities, root).
    Table,
    /// It filled every frame ahead itself.
    Frames,
}

/// The frames ahead of a tick, policy order, for a source that fills them itself.
#[derive(Debug)]
pub struct FramesAhead<'a> {
    /// Joint positions per frame.
    pub q: &'a mut [Vec<f64>],
    /// Joint velocities per frame.
    pub qd: &'a mut [Vec<f64>],
    /// Root poses per frame.
    pub root: &'a mut [[f64; 7]],
    /// Root velocities per frame, world frame, m/s.
    pub root_lin_vel: &'a mut [[f64; 3]],
    /// Root angular velocities per frame, world frame, rad/s.
    pub root_ang_vel: &'a mut [[f64; 3]],
}

/// A reference computed while the run goes: a teleoperator's stream, a motion generator's plans.
/// The cursor keeps the timing (ramp, end, soft stop, look-ahead); the source says what the
/// reference is now — it feeds the one-frame table the cursor plays, or fills the frames ahead
/// itself. A new kind of source implements this and changes neither the cursor nor the loop.
/// Called on the loop's thread every tick: no allocation, no lock.
pub trait LiveSource: std::fmt::Debug + Send {
    /// This tick's reference, `t` s of motion time after the ramp, frames `dt` apart;
    /// `robot_index[p]` is the robot joint of policy joint `p`; `table` is the one-frame
    /// reference (robot order).
    fn feed(
        &mut self,
        t: f64,
        dt: f64,
        robot_index: &[usize],
        table: &mut Reference,
        ahead: FramesAhead<'_>,
    ) -> Fed;

    /// The VR trackers' values for the `tracker_poses` term, where the source has them.
    fn trackers(&self) -> Option<&[f64; TRACKER_VALUES]> {
        None
    }

    /// The arrival of the input behind the command about to be sent, once per input (the
    /// input-to-command latency).
    fn take_input_arrival(&mut self) -> Option<Instant> {
        None
    }

    /// Where the source placed its operator's key bodies this tick (the reference's
    /// `live_bodies`, in the reference root's frame), while it follows one.
    fn operator_bodies(&self) -> Option<&[[f64; 3]]> {
        None
    }

    /// A motion generator's plans (counts, changes, status), for its telemetry and summary.
    fn plans(&self) -> Option<&PlanReader> {
        None
    }
}

// A motion generator's plans, sampled at each tick.
impl LiveSource for PlanReader {
    /// This tick's frame and those ahead, each sampled from the newest plan at its time; the
    /// root stays the standby's.
    fn feed(
        &mut self,
        t: f64,
        dt: f64,
        robot_index: &[usize],
        table: &mut Reference,
        ahead: FramesAhead<'_>,
    ) -> Fed {
        self.begin_tick(t, dt);
        for f in 0..ahead.q.len() {
            let (q, qd) = self.sample(t + f as f64 * dt);
            for (p, &r) in robot_index.iter().enumerate() {
                ahead.q[f][p] = q[r];
                ahead.qd[f][p] = qd[r];
            }
            ahead.root[f] = table.root[0];
            ahead.root_lin_vel[f] = [0.0; 3];
            ahead.root_ang_vel[f] = [0.0; 3];
        }
        Fed::Frames
    }

    fn plans(&self) -> Option<&PlanReader> {
        Some(self)
    }
}

/// A teleoperator's stream: each tick the newest frame another thread retargeted, lock-free.
#[derive(Debug)]
pub struct TeleopStream {
    reader: LiveReader,
    /// Arrival of the input behind this tick's frame, when no command used it yet.
    source: Option<Instant>,
    /// The input the last command used.
    used: Option<Instant>,
    trackers: [f64; TRACKER_VALUES],
    /// The operator's key bodies of the newest frame (the first `bodies_len`).
    bodies: [[f64; 3]; MAX_LIVE_BODIES],
    bodies_len: usize,
}

/// The most key bodies a live source places on its operator.
pub const MAX_LIVE_BODIES: usize = 32;

impl TeleopStream {
    /// The stream `reader` hands over.
    pub fn new(reader: LiveReader) -> Self {
        Self {
            reader,
            source: None,
            used: None,
            trackers: [0.0; TRACKER_VALUES],
            bodies: [[0.0; 3]; MAX_LIVE_BODIES],
            bodies_len: 0,
        }
    }
}

impl LiveSource for TeleopStream {
    /// The newest frame, for now and every frame ahead (a live stream has no future).
    fn feed(
        &mut self,
        _t: f64,
        _dt: f64,
        robot_index: &[usize],
        table: &mut Reference,
        ahead: FramesAhead<'_>,
    ) -> Fed {
        let frame = self.reader.latest();
        let n = table.n;
        table.q[..n].copy_from_slice(&frame.q);
        table.qd[..n].copy_from_slice(&frame.qd);
        table.root[0] = frame.root;
        for f in 0..ahead.q.len() {
            for (p, &r) in robot_index.iter().enumerate() {
                ahead.q[f][p] = frame.q[r];
                ahead.qd[f][p] = frame.qd[r];
            }
            ahead.root[f] = frame.root;
            ahead.root_lin_vel[f] = frame.root_lin_vel;
            ahead.root_ang_vel[f] = frame.root_ang_vel;
        }
        self.trackers = frame.trackers;
        self.bodies_len = frame.bodies.len().min(MAX_LIVE_BODIES);
        self.bodies[..self.bodies_len].copy_from_slice(&frame.bodies[..self.bodies_len]);
        // Latency counts to the first command that uses an input, not the ones after it.
        self.source = frame.source.filter(|s| Some(*s) != self.used);
        Fed::Frames
    }

    fn trackers(&self) -> Option<&[f64; TRACKER_VALUES]> {
        Some(&self.trackers)
    }

    fn operator_bodies(&self) -> Option<&[[f64; 3]]> {
        (self.bodies_len > 0).then(|| &self.bodies[..self.bodies_len])
    }

    fn take_input_arrival(&mut self) -> Option<Instant> {
        let source = self.source.take()?;
        self.used = Some(source);
        Some(source)
    }
}

/// The reference's cursor.
#[derive(Debug)]
pub struct ReferenceCursor {
    reference: Reference,
    frames: Frames,
    /// Robot-order reference of the current tick (blended during ramps and at the end).
    current_q: Vec<f64>,
    /// Policy ticks since the clip (its ramp) started.
    tick: usize,
    ramp_ticks: usize,
    end_ticks: usize,
    end: EndMode,
    /// A source computing the reference while the run goes, when the clip is not it.
    source: Option<Box<dyn LiveSource>>,
    /// The policy's period, s.
    dt: f64,
    /// Where the motion was put for this run (set when a run starts tracking an anchor).
    alignment: Option<Alignment>,
    /// The motion bodies' poses of this tick, aligned.
    motion_now: Vec<[f64; 7]>,
    /// The `ref_keypoints` values of every tick of the reference, `width` each.
    keypoint_obs: Vec<f64>,
    /// A soft stop: the tick it came at and the frame it holds; the reference then blends from
    /// that frame (`cut_q`, policy order) to the default pose.
    cut: Option<(usize, usize)>,
    cut_q: Vec<f64>,
    /// Ticks the blend to the default pose takes after a cut.
    settle_ticks: usize,
}

impl ReferenceCursor {
    /// A cursor over `reference` for a policy that looks `frames` ticks ahead (at least 1), with
    /// `body_width` reference body values per frame, ticking every `dt` seconds.
    pub fn new(
        reference: Reference,
        frames: usize,
        body_width: usize,
        default_q: &[f64],
        options: &PlayOptions,
        dt: f64,
    ) -> Self {
        let n = default_q.len();
        Self {
            frames: Frames {
                q: vec![vec![0.0; n]; frames],
                qd: vec![vec![0.0; n]; frames],
                root: vec![[0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0]; frames],
                root_lin_vel: vec![[0.0; 3]; frames],
                root_ang_vel: vec![[0.0; 3]; frames],
                body: vec![vec![0.0; body_width]; frames],
                anchor: [0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0],
                keypoints: vec![Vec::new(); frames],
            },
            keypoint_obs: Vec::new(),
            alignment: None,
            motion_now: vec![[0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0]; reference.motion_bodies.len()],
            current_q: default_q.to_vec(),
            tick: 0,
            ramp_ticks: (options.ramp_s.unwrap_or(0.0) / dt).round() as usize,
            end_ticks: (options.end_s / dt).round() as usize,
            end: options.end,
            source: None,
            dt,
            reference,
            cut: None,
            cut_q: vec![0.0; n],
            settle_ticks: (options.settle_s / dt).round().max(1.0) as usize,
        }
    }

    /// A soft stop: from this tick the reference holds the frame it is on (every frame ahead
    /// too, still) and blends from there to the default pose; the clip is over.
    pub fn cut_here(&mut self) {
        if self.cut.is_some() {
            return;
        }
        self.cut = Some((self.tick, self.frame_at(self.tick)));
        self.cut_q.copy_from_slice(&self.frames.q[0]);
        let (first, ahead) = self.frames.q.split_at_mut(1);
        for q in ahead {
            q.copy_from_slice(&first[0]);
        }
        for qd in &mut self.frames.qd {
            qd.fill(0.0);
        }
        self.frames.root_lin_vel.fill([0.0; 3]);
        self.frames.root_ang_vel.fill([0.0; 3]);
        let (first, ahead) = self.frames.root.split_at_mut(1);
        ahead.fill(first[0]);
        let (first, ahead) = self.frames.body.split_at_mut(1);
        for b in ahead {
            b.copy_from_slice(&first[0]);
        }
        let (first, ahead) = self.frames.keypoints.split_at_mut(1);
        for k in ahead {
            k.copy_from_slice(&first[0]);
        }
    }

    /// Whether a soft stop cut the reference.
    pub fn is_cut(&self) -> bool {
        self.cut.is_some()
    }

    /// Gives the `ref_keypoints` term its values: `width` per tick of the reference.
    pub fn set_keypoints(&mut self, values: Vec<f64>, width: usize) {
        for f in &mut self.frames.keypoints {
            *f = vec![0.0; width];
        }
        self.keypoint_obs = values;
    }

    /// Takes each tick's reference from `source` instead of the clip (its clock starts when the
    /// ramp ends).
    pub fn set_source(&mut self, source: Box<dyn LiveSource>) {
        self.source = Some(source);
    }

    /// The generator's plans, when a generator supplies the frames.
    pub fn generated(&self) -> Option<&PlanReader> {
        self.source.as_deref().and_then(LiveSource::plans)
    }

    /// How far ahead of its tick the policy reads the reference, s.
    pub fn lookahead_s(&self) -> f64 {
        (self.frames.q.len() - 1) as f64 * self.dt
    }

    /// Whether frames come from a live source (a teleoperator or a generator).
    pub fn is_live(&self) -> bool {
        self.source.is_some()
    }

    /// The clip's frames.
    pub fn reference(&self) -> &Reference {
        &self.reference
    }

    /// Starts the clip (its ramp) over.
    pub fn restart(&mut self) {
        self.tick = 0;
    }

    /// The start-up ramp is on (the reference held at its first frame).
    pub fn in_ramp(&self) -> bool {
        self.tick < self.ramp_ticks
    }

    /// Policy ticks since the clip started.
    pub fn tick(&self) -> usize {
        self.tick
    }

    /// Moves to the next tick.
    pub fn step(&mut self) {
        self.tick += 1;
    }

    /// The reference frame tick `tick` plays (held at the first during the ramp, at the last
    /// after the end, wrapped when looping).
    pub fn frame_at(&self, tick: usize) -> usize {
        if let Some((_, frame)) = self.cut {
            return frame;
        }
        let base = tick.saturating_sub(self.ramp_ticks);
        let len = self.reference.len();
        if self.end == EndMode::Loop {
            base % len
        } else {
            base.min(len - 1)
        }
    }

    /// The frame the next tick plays.
    pub fn next_frame(&self) -> usize {
        self.frame_at(self.tick + 1)
    }

    /// The anchor's first pose, unaligned: from `embedded` (the frame a tracking export's call
    /// returned) or the reference's table. None without an anchor.
    pub fn first_anchor(&self, embedded: Option<&MotionFrame<'_>>) -> Option<[f64; 7]> {
        let a = self.reference.anchor?;
        Some(match embedded {
            Some(f) => f.body_pose(a),
            None => self.reference.motion_poses_at(0)[a],
        })
    }

    /// Puts the motion where `alignment` says, from this tick on.
    pub fn align(&mut self, alignment: Alignment) {
        self.alignment = Some(alignment);
    }

    /// Where the motion was put, once a run started tracking its anchor.
    pub fn alignment(&self) -> Option<Alignment> {
        self.alignment
    }

    /// The motion bodies' poses of this tick, aligned (empty without motion bodies).
    pub fn motion_now(&self) -> &[[f64; 7]] {
        &self.motion_now
    }

    /// The clip proper is playing (not its ramp, not its end).
    pub fn in_clip(&self) -> bool {
        self.cut.is_none()
            && self.tick >= self.ramp_ticks
            && (self.is_live() || self.tick < self.ramp_ticks + self.reference.len())
    }

    /// Whether the tick just taken tracked the clip (what a recording marks as tracking).
    pub fn tracked(&self) -> bool {
        self.cut.is_none()
            && self.tick > self.ramp_ticks
            && (self.is_live() || self.tick <= self.ramp_ticks + self.reference.len())
    }

    /// The clip, ramp and end included, is over (never for a loop).
    pub fn finished(&self) -> bool {
        if self.cut.is_some() {
            return false;
        }
        match self.end {
            EndMode::Loop | EndMode::Stand => false,
            EndMode::Hold | EndMode::Blend => {
                self.tick >= self.ramp_ticks + self.reference.len() + self.end_ticks
            }
        }
    }

    /// The reference of this tick, robot order.
    pub fn current_q(&self) -> &[f64] {
        &self.current_q
    }

    /// The reference root pose of this tick.
    pub fn current_root(&self) -> [f64; 7] {
        self.frames.root[0]
    }

    /// The frames the observation sees.
    pub fn view(&self) -> &dyn ReferenceView {
        &self.frames
    }

    /// The live devices' values for the `tracker_poses` term, with a live source.
    pub fn trackers(&self) -> Option<&[f64; TRACKER_VALUES]> {
        self.source.as_deref().and_then(LiveSource::trackers)
    }

    /// Where the live source placed its operator's key bodies this tick, while it follows one.
    pub fn operator_bodies(&self) -> Option<&[[f64; 3]]> {
        self.source.as_deref().and_then(LiveSource::operator_bodies)
    }

    /// The arrival of the input behind the command about to be sent, once per input.
    pub fn take_live_source(&mut self) -> Option<Instant> {
        self.source.as_mut()?.take_input_arrival()
    }

    /// Positions the frames for this tick and returns ψ (0 → 1 over the ramp). `default_q` is
    /// robot order; `robot_index[p]` is the robot joint of policy joint `p`. `embedded`: this
    /// tick's frame as a tracking export's last call returned it (it replaces the table's
    /// current frame; frames ahead come from the table read out of the same export).
    pub fn update(
        &mut self,
        default_q: &[f64],
        robot_index: &[usize],
        embedded: Option<&MotionFrame<'_>>,
    ) -> f64 {
        if let Some((at, _)) = self.cut {
            // A soft stop: the held frame, blending to the default pose.
            let settle = self.settle_ticks as f64;
            for (f, q) in self.frames.q.iter_mut().enumerate() {
                let blend = ((self.tick - at + f + 1) as f64 / settle).min(1.0);
                for ((v, &held), &r) in q.iter_mut().zip(&self.cut_q).zip(robot_index) {
                    *v = held + (default_q[r] - held) * blend;
                }
            }
            for (p, &r) in robot_index.iter().enumerate() {
                self.current_q[r] = self.frames.q[0][p];
            }
            return 1.0;
        }
        let (ramp, len) = (self.ramp_ticks, self.reference.len());
        let psi = if ramp == 0 {
            1.0
        } else {
            (self.tick as f64 / ramp as f64).min(1.0)
        };
        let base = self.tick.saturating_sub(ramp);
        if let Some(source) = &mut self.source {
            let ahead = FramesAhead {
                q: &mut self.frames.q,
                qd: &mut self.frames.qd,
                root: &mut self.frames.root,
                root_lin_vel: &mut self.frames.root_lin_vel,
                root_ang_vel: &mut self.frames.root_ang_vel,
            };
            let fed = source.feed(
                base as f64 * self.dt,
                self.dt,
                robot_index,
                &mut self.reference,
                ahead,
            );
            if fed == Fed::Frames {
                for (p, &r) in robot_index.iter().enumerate() {
                    self.current_q[r] = self.frames.q[0][p];
                }
                return psi;
            }
        }
        let base = if self.end == EndMode::Loop {
            base % len
        } else {
            base
        };
        let end_ticks = self.end_ticks.max(1);
        let moving = |k: usize| self.tick >= ramp && k < len;
        for f in 0..self.frames.q.len() {
            let k = base + f;
            let (q, qd) = (self.reference.q_at(k), self.reference.qd_at(k));
            let blend = if matches!(self.end, EndMode::Blend | EndMode::Stand) && k >= len {
                ((k - len + 1) as f64 / end_ticks as f64).min(1.0)
            } else {
                0.0
            };
            let called = embedded.filter(|_| f == 0);
            for (p, &r) in robot_index.iter().enumerate() {
                let (q, qd) = called.map_or((q[r], qd[r]), |e| {
                    (f64::from(e.joint_pos[p]), f64::from(e.joint_vel[p]))
                });
                self.frames.q[f][p] = q + (default_q[r] - q) * blend;
                self.frames.qd[f][p] = if moving(k) { qd } else { 0.0 };
            }
            let root = self.reference.root[k.min(len - 1)];
            self.frames.root[f] = self.alignment.map_or(root, |a| a.apply(root));
            // The root's velocities: the motion's while it moves, none while held.
            let (lin, ang) = if moving(k) {
                let turn = |v: [f64; 3]| self.alignment.map_or(v, |a| a.turn_vector(v));
                let at = k.min(len - 1);
                (
                    turn(self.reference.root_lin_vel[at]),
                    turn(self.reference.root_ang_vel[at]),
                )
            } else {
                ([0.0; 3], [0.0; 3])
            };
            self.frames.root_lin_vel[f] = lin;
            self.frames.root_ang_vel[f] = ang;
            if !self.reference.bodies.is_empty() {
                self.frames.body[f].copy_from_slice(self.reference.body_pos_at(k));
            }
            let w = self.frames.keypoints[f].len();
            if w > 0 {
                let at = k.min(len - 1) * w;
                self.frames.keypoints[f].copy_from_slice(&self.keypoint_obs[at..at + w]);
            }
        }
        for (p, &r) in robot_index.iter().enumerate() {
            self.current_q[r] = self.frames.q[0][p];
        }
        if !self.motion_now.is_empty() {
            let align = self.alignment.unwrap_or_default();
            let k = base.min(len - 1);
            for (b, now) in self.motion_now.iter_mut().enumerate() {
                let pose = match embedded {
                    Some(e) => e.body_pose(b),
                    None => self.reference.motion_poses_at(k)[b],
                };
                *now = align.apply(pose);
            }
            if let Some(a) = self.reference.anchor {
                self.frames.anchor = self.motion_now[a];
            }
        }
        psi
    }
}

/// Where a run's reference comes from.
#[derive(Debug)]
pub enum ReferenceSource {
    /// A clip file.
    Clip(Clip),
    /// No clip: a command-driven policy observes no reference; it stands in for one with the
    /// default pose and runs on its commands until stopped.
    Commands,
    /// The motion the policy's export carries.
    Embedded {
        /// The export.
        onnx: PathBuf,
        /// Its frames.
        frames: usize,
        /// The frame the run starts from.
        start_step: usize,
    },
    /// An online motion generator (its description file).
    Generated(PathBuf),
}

impl ReferenceSource {
    /// The file the reference came from (a run's recording names it); none for commands.
    pub fn path(&self) -> Option<&Path> {
        match self {
            Self::Clip(c) => Some(&c.path),
            Self::Embedded { onnx, .. } => Some(onnx),
            Self::Generated(description) => Some(description),
            Self::Commands => None,
        }
    }
}

impl std::fmt::Display for ReferenceSource {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Clip(c) => write!(f, "{}", c.path.display()),
            Self::Commands => write!(f, "no clip (a command-driven policy, on its commands)"),
            Self::Generated(d) => write!(f, "the motion generator {} (online)", d.display()),
            Self::Embedded {
                onnx,
                frames,
                start_step,
            } => write!(
                f,
                "the motion {} carries ({frames} frames, from step {start_step})",
                onnx.display()
            ),
        }
    }
}

fn same_file(a: &Path, b: &Path) -> bool {
    match (std::fs::canonicalize(a), std::fs::canonicalize(b)) {
        (Ok(a), Ok(b)) => a == b,
        _ => a == b,
    }
}

/// The reference of a run: the motion the policy's export carries (from `start_step`), else
/// the clip at `clip`; with no clip, a command-driven policy (one that observes no reference)
/// holds the default pose, and any other plays `default_clip`. A clip given for an export that
/// carries its own motion is refused: one of them would be ignored. Binds `layout` to its model
/// on the way (its terms' sizes checked against the model's inputs and outputs).
pub fn load_reference(
    clip: Option<&Path>,
    default_clip: &Path,
    layout: &mut PolicyLayout,
    robot: &Robot,
    start_step: usize,
) -> Result<(Reference, ReferenceSource), PlayError> {
    let mut model = OnnxModel::load(&layout.onnx_path)?;
    layout.bind_model(model.inputs(), model.output().1)?;
    let layout = &*layout;
    if let Some(mut motion) = EmbeddedMotion::find(&mut model, layout, start_step)? {
        if let Some(c) = clip.filter(|c| !same_file(c, &layout.onnx_path)) {
            return Err(PlayError::Setup(format!(
                "{} carries its own motion; leave out the clip {} (or export the policy without one)",
                layout.onnx_path.display(),
                c.display()
            )));
        }
        let reference = motion.read(&mut model, layout, robot)?;
        if let Some((body, error, frame)) = worst_body_mismatch(robot, &reference)?
            && error > MODEL_MISMATCH_M
        {
            return Err(PlayError::Setup(format!(
                "the motion {} carries does not fit the robot's model: at frame {frame}, body {body} \
                 lies {:.1} cm from where the model puts it at the motion's own root pose and joint \
                 positions (at most {:.0} cm): a wrong quaternion order (w x y z expected), joint \
                 order or body names, or another robot's motion",
                layout.onnx_path.display(),
                100.0 * error,
                100.0 * MODEL_MISMATCH_M
            )));
        }
        return Ok((
            reference,
            ReferenceSource::Embedded {
                onnx: layout.onnx_path.clone(),
                frames: motion.frames,
                start_step,
            },
        ));
    }
    if clip.is_none() && !layout.reads_reference() {
        // Nothing to track: the default pose, upright, is the reference the loop holds.
        let reference = Reference::hold(
            &layout.default_q,
            [0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0],
            layout.manifest.rate_hz,
        );
        return Ok((reference, ReferenceSource::Commands));
    }
    let clip = Clip::load(clip.unwrap_or(default_clip))?;
    let reference = Reference::for_policy(&clip, robot, layout)?;
    Ok((reference, ReferenceSource::Clip(clip)))
}
