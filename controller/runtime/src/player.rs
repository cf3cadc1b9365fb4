//! The control loop: read → check → observe → infer → act → govern → write, once per policy tick,
//! under the state machine of [`crate::safety`]. The parts live in their own modules — where the
//! reference is ([`crate::reference`]), the observation ([`crate::policy`]), the action mapping
//! and governor ([`crate::action`]), the safety checks ([`crate::safety::SafetyMonitor`]), the
//! run's measurements ([`crate::metrics`]) and its record ([`crate::telemetry`]); this file only
//! sequences them (its error, [`PlayError`], lives below everything it calls). Every buffer is sized before the first tick; a steady-state tick allocates
//! nothing and takes no lock.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use human::commands::{CommandReader, LiveCommands};
use robot_link::{GroundTruth, JointTarget, RobotLink, RobotState, TickClock};
use robots::{Robot, spatial};

use crate::action::ActionMapper;
use crate::clip::Reference;
use crate::keypoints::track::KeypointTrack;
use crate::lifecycle::{Lifecycle, Machine};
use crate::metrics::{AfterControl, RunMetrics};
pub use crate::metrics::{Histogram, PlaySummary};
use crate::motion::{Alignment, EmbeddedMotion};
use crate::options::EstimatorKind;
pub use crate::options::{EndMode, HarnessPhase, PlayOptions};
use crate::reference::{LiveSource, ReferenceCursor};
use crate::safety::{Cause, Mode, SafetyMonitor, Transition, govern_position, target_range, tilt_of};
use crate::telemetry::{TelemetrySink, TickRecord, TickView};
use crate::world_stage::WorldStage;
use policy::onnx::OnnxModel;
use policy::{ObsInputs, ObservationBuilder, PolicyLayout, Term};
use world::RobotKinematics;
use world::estimator::{Estimate, Estimator};

pub use crate::error::PlayError;

/// The controller of one run.
#[derive(Debug)]
pub struct Player<L: RobotLink> {
    robot: Robot,
    options: PlayOptions,
    io: L,
    dt: f64,
    tick: u64,
    metrics: RunMetrics,
    /// The base's height on the last tick the run had the robot under control (simulation).
    last_controlled_height: Option<f64>,
    /// What the robot reported this tick and what it is commanded (robot order).
    state: RobotState,
    targets: Vec<JointTarget>,
    telemetry: Option<TelemetrySink>,
    record: Box<TickRecord>,
    world: WorldStage,
    reference: ReferenceStage,
    lifecycle: Lifecycle,
    policy: PolicyStage,
    /// Where the run publishes its tick for a progress display (one relaxed store a tick).
    progress: Option<Arc<std::sync::atomic::AtomicU64>>,
}

/// The reference stage of a run: where the reference is this tick, and how the robot's tracked
/// bodies and anchor compare with it.
#[derive(Debug)]
struct ReferenceStage {
    cursor: ReferenceCursor,
    /// The reference of the previous tick and, per joint, the reference at its sample's time.
    previous_reference: Vec<f64>,
    aligned_reference: Vec<f64>,
    /// This tick's sample entered the run's tracking metrics, against `aligned_reference` and
    /// this reference root: what the tick's record says, so a report made from the recording
    /// measures the same window against the same reference as the loop's summary.
    tracked: Option<[f64; 7]>,
    /// The robot's anchor and the reference's as the last policy tick observed them.
    anchors: Option<([f64; 7], [f64; 7])>,
    /// Position error of each tracked motion body at the last policy tick, m (simulation).
    body_errors: Vec<f64>,
    /// Whether `body_errors` holds this run's errors (ground truth and tracked bodies).
    has_body_errors: bool,
    /// Where the reference's `live_bodies` start among the kinematics' tracked bodies, and how
    /// many there are (a live source's operator measured against the robot).
    operator_bodies: Option<(usize, usize)>,
}

/// The policy stage of a run: the contract, the model, the observation and its buffers (policy
/// order), the action mapping, and what a command-driven or motion-carrying policy adds.
#[derive(Debug)]
struct PolicyStage {
    layout: PolicyLayout,
    model: OnnxModel,
    obs_builder: ObservationBuilder,
    mapper: ActionMapper,
    /// The motion a tracking export carries, when the policy is one.
    embedded: Option<EmbeddedMotion>,
    policy_q: Vec<f64>,
    policy_qd: Vec<f64>,
    policy_default: Vec<f64>,
    policy_last_targets: Vec<f64>,
    obs: Vec<f32>,
    /// The live commands of a command-driven policy (the manifest's `[commands]`).
    commands: Option<LiveCommands>,
    /// The policy observes no reference: the run stands in for a clip with the default pose and
    /// measures where the robot goes instead of how it tracks.
    command_driven: bool,
    /// Steps the policy took since it took control (its phase counter).
    policy_steps: u64,
    /// The policy drove the robot this tick (its metrics' window).
    ran: bool,
    /// The gait phase of a policy that observes one.
    gait: Option<policy::GaitClock>,
}

impl<L: RobotLink> Player<L> {
    /// Prepares a run: checks the policy against its model, sizes every buffer.
    pub fn new(
        robot: Robot,
        mut layout: PolicyLayout,
        mut reference: Reference,
        options: PlayOptions,
        mut io: L,
        stop: Arc<AtomicBool>,
    ) -> Result<Self, PlayError> {
        let mut model = OnnxModel::load(&layout.onnx_path)?;
        // The robot's own margin inside its joint limits, where robot.toml gives one; its start
        // when the run names none.
        let mut options = options.resolved_for(&robot);
        if !(options.soft_start_s.is_finite()
            && (0.1..=30.0).contains(&options.soft_start_s)
            && (0.0..=1.0).contains(&options.soft_start_gain))
        {
            return Err(PlayError::Setup(format!(
                "soft start of {} s at gain {} (0.1–30 s, 0–1)",
                options.soft_start_s, options.soft_start_gain
            )));
        }
        if !(options.settle_s.is_finite() && (0.02..=30.0).contains(&options.settle_s)) {
            return Err(PlayError::Setup(format!(
                "settle_s = {} s is outside [0.02, 30]",
                options.settle_s
            )));
        }
        if options.on_stop == crate::options::OnStop::Harness
            && options.start_mode(&robot) != robots::StartMode::Harness
        {
            return Err(PlayError::Setup(format!(
                "on-stop harness: the run does not start in a harness ({} start); start it with --start \
                 harness (or robot.toml [start] mode = \"harness\"), or stop another way",
                options.start_mode(&robot).name()
            )));
        }
        // The first-frame hold: the operator's, else the policy's own.
        let mut hold = options.ramp_s.unwrap_or_else(|| layout.hold_s());
        if options.start_mode(&robot) == robots::StartMode::Harness {
            // The motion waits on its first frame while the harness lowers the robot and it
            // settles on its feet.
            let h = robot.config.start.harness;
            hold = hold.max(h.lower_s + h.settle_s);
        }
        options.ramp_s = Some(hold);
        if let Some(m) = robot.config.position_margin {
            options.limits.position_margin = m;
        }
        if let Some(t) = robot.config.safety.tilt {
            options.limits.tilt = t;
        }
        if options.limits.stale_cycles == 0 {
            return Err(PlayError::Setup(
                "limits.stale_cycles = 0: at least 1 cycle".into(),
            ));
        }
        // The buses judge staleness themselves, at their rate, by the run's limit.
        io.set_stale_cycles(options.limits.stale_cycles);
        // Reference body positions, by forward kinematics, when the policy observes them.
        let mut body_lists = layout.slots.iter().filter_map(|s| match &s.term {
            Term::RefBodyPos { bodies, .. } => Some(bodies.clone()),
            _ => None,
        });
        if let Some(bodies) = body_lists.next() {
            if body_lists.any(|b| b != bodies) {
                return Err(PlayError::Setup(
                    "all ref_body_pos terms must name the same bodies".into(),
                ));
            }
            reference.body_pos = crate::fk::body_positions(&robot, &reference, &bodies)?;
            reference.bodies = bodies;
        }
        let body_width = 3 * reference.bodies.len();
        layout.bind_model(model.inputs(), model.output().1)?;
        let mut embedded = EmbeddedMotion::find(&mut model, &layout, options.start_step)?;
        if let Some(e) = &embedded
            && reference.len() != e.frames - e.start_step
        {
            return Err(PlayError::Setup(format!(
                "{} carries a motion of {} frames from step {}; the reference given has {} ticks                  (play the export's own motion)",
                layout.onnx_path.display(),
                e.frames,
                e.start_step,
                reference.len()
            )));
        }
        let mut kinematics = motion_setup(&robot, &layout, &mut reference, embedded.is_some())?;
        let keypoints = keypoint_setup(&robot, &layout, &mut reference, &mut kinematics)?;
        let estimator = match &kinematics {
            Some(k) if k.feet() > 0 => Some(Estimator::new(
                options.estimator.config(&robot.config.estimator),
                k.feet(),
                k.gravity(),
                k.weight(),
                robot.config.imu.rate_hz,
            )),
            _ => None,
        };
        if (layout.manifest.rate_hz - reference.rate_hz).abs() > 1e-9 {
            return Err(PlayError::Setup(format!(
                "reference resampled at {} Hz for a {} Hz policy",
                reference.rate_hz, layout.manifest.rate_hz
            )));
        }
        let n = robot.config.joints.len();
        let frames = layout
            .slots
            .iter()
            .filter_map(|s| match &s.term {
                Term::RefJointPos { frames, .. }
                | Term::RefJointVel { frames, .. }
                | Term::RefRootPose { frames, .. }
                | Term::RefBodyPos { frames, .. } => frames.iter().max().copied(),
                _ => None,
            })
            .max()
            .unwrap_or(0)
            + 1;
        if frames > policy::MAX_FRAMES_AHEAD {
            return Err(PlayError::Setup(format!(
                "the policy looks {frames} frames ahead; at most {}",
                policy::MAX_FRAMES_AHEAD
            )));
        }
        let k_actions = layout
            .slots
            .iter()
            .map(|s| match &s.term {
                Term::LastActions { k, .. } => *k,
                _ => 0,
            })
            .max()
            .unwrap_or(0);
        let dt = 1.0 / layout.manifest.rate_hz;
        let default_q = layout.default_q.clone();
        let mut metrics = RunMetrics::default();
        metrics.track_bodies(&reference.motion_bodies, reference.anchor);
        metrics.track_jitter(n);
        let command_driven = !layout.reads_reference();
        let stop_pose = match options.on_stop {
            crate::options::OnStop::Sit => {
                let name = robot.config.sit_keyframe.as_deref().ok_or_else(|| {
                    PlayError::Setup(format!(
                        "on-stop sit: {} names no sit_keyframe (a keyframe of its model to sit down into)",
                        robot.path.display()
                    ))
                })?;
                robot.keyframe_joints(name).ok_or_else(|| {
                    PlayError::Setup(format!("on-stop sit: the model has no keyframe {name:?}"))
                })?
            }
            _ => layout.default_q.clone(),
        };
        if !(options.sit_s.is_finite() && (0.1..=60.0).contains(&options.sit_s))
            || options
                .stand_s
                .is_some_and(|s| !(s.is_finite() && (0.0..=86_400.0).contains(&s)))
        {
            return Err(PlayError::Setup(format!(
                "sit_s = {} (0.1–60 s) or stand_s = {:?} (0–86400 s) out of range",
                options.sit_s, options.stand_s
            )));
        }
        let commands = match (&layout.manifest.commands, layout.command_values()) {
            (Some(spec), Some(initial)) => Some(LiveCommands::new(spec, initial, None, dt)),
            _ => None,
        };
        if command_driven {
            let kinds = commands.as_ref().map(|c| c.spec().kinds()).unwrap_or_default();
            metrics.locomotion = Some(crate::metrics::LocomotionMetrics::new(&kinds));
        }
        let tracked_bodies = reference.motion_bodies.len();
        metrics.track_operator(&reference.live_bodies);
        let operator_bodies = match (&kinematics, reference.live_bodies.len()) {
            (Some(k), n) if n > 0 => Some((k.tracked_bodies() - n, n)),
            _ => None,
        };
        if let Some(e) = &mut embedded {
            // The first tick observes the first frame: one call before anything moves.
            e.seek(&mut model, e.start_step)?;
        }
        let mut cursor = ReferenceCursor::new(reference, frames, body_width, &default_q, &options, dt);
        if let Some(k) = &keypoints {
            cursor.set_keypoints(k.reference_obs_all().to_vec(), k.obs_width());
        }
        Ok(Self {
            world: WorldStage {
                kinematics,
                keypoints,
                keypoints_measured: false,
                estimator,
                estimate: Estimate::default(),
                observed: GroundTruth {
                    foot_contacts: vec![false; robot.config.feet.len()],
                    ..GroundTruth::default()
                },
                world_valid: false,
                reads_world: layout.needs_ground_truth(),
                truth_to_world: Alignment::default(),
                truth_mapped: false,
                truth: GroundTruth {
                    foot_contacts: vec![false; robot.config.feet.len()],
                    ..GroundTruth::default()
                },
            },
            reference: ReferenceStage {
                cursor,
                previous_reference: default_q.clone(),
                aligned_reference: default_q.clone(),
                tracked: None,
                anchors: None,
                body_errors: vec![0.0; tracked_bodies],
                has_body_errors: false,
                operator_bodies,
            },
            progress: None,
            lifecycle: Lifecycle {
                monitor: {
                    let (limits, tracking) = options.limits.for_robot(&robot, dt);
                    let names: Vec<String> = robot.config.joints.iter().map(|j| j.name.clone()).collect();
                    SafetyMonitor::new(limits, tracking, &names, dt, robot.config.imu.rate_hz).with_plausible(
                        robot
                            .config
                            .joints
                            .iter()
                            .map(crate::safety::PlausibleJoint::of)
                            .collect(),
                    )
                },
                stop,
                estop: None,
                stop_seen: false,
                machine: Machine {
                    mode: Mode::Off,
                    ticks: 0,
                    transitions: Vec::with_capacity(64),
                    pending: None,
                },
                start_pose: default_q.clone(),
                stop_pose,
                standing_since: None,
                stop_under_policy: false,
                harness_hoist: None,
                lowered: None,
                harness_phase: HarnessPhase::None,
            },
            policy: PolicyStage {
                embedded,
                mapper: ActionMapper::new(n, k_actions, &default_q),
                obs_builder: ObservationBuilder::new(&layout),
                obs: vec![0.0; layout.obs_len],
                model,
                policy_q: vec![0.0; n],
                policy_qd: vec![0.0; n],
                policy_default: layout.robot_index.iter().map(|&r| default_q[r]).collect(),
                policy_last_targets: vec![0.0; n],
                commands,
                command_driven,
                policy_steps: 0,
                ran: false,
                gait: policy::GaitClock::of(&layout),
                layout,
            },
            dt,
            metrics,
            last_controlled_height: None,
            options,
            io,
            tick: 0,
            state: RobotState::new(n),
            targets: vec![JointTarget::default(); n],
            telemetry: None,
            record: Box::default(),
            robot,
        })
    }

    /// Hands a stop with [`OnStop::Harness`] the mirror's crane: raising the flag hoists it.
    ///
    /// [`OnStop::Harness`]: crate::options::OnStop::Harness
    pub fn with_harness_hoist(mut self, hoist: Arc<AtomicBool>) -> Self {
        self.lifecycle.harness_hoist = Some(hoist);
        self
    }

    /// Has a harness start wait for the operator's word that the robot stands on its feet (the
    /// flag raised): the policy keeps control, the motion holds its first frame and the commands
    /// rest until then; the settling time counts from the word. Without a harness start, no
    /// effect.
    pub fn with_lowered_signal(mut self, lowered: Arc<AtomicBool>) -> Self {
        self.lifecycle.lowered = Some(lowered);
        self
    }

    /// Where a harness start is (`HarnessPhase::None` for other starts).
    pub fn harness_phase(&self) -> HarnessPhase {
        if self.options.start != Some(robots::StartMode::Harness) {
            return HarnessPhase::None;
        }
        let h = self.robot.config.start.harness;
        let lowering = (h.lower_s / self.dt).round() as usize;
        let tick = self.reference.cursor.tick();
        let waiting = self
            .lifecycle
            .lowered
            .as_ref()
            .is_some_and(|f| !f.load(Ordering::Relaxed));
        if tick < lowering {
            HarnessPhase::Lowering
        } else if waiting {
            HarnessPhase::WaitingForOperator
        } else if self.reference.cursor.in_ramp() {
            HarnessPhase::Settling
        } else {
            HarnessPhase::Free
        }
    }

    /// Takes the commands of a command-driven policy from a live source (keyboard, gamepad,
    /// UDP): each policy tick the newest targets, clamped to the manifest's ranges and ramped.
    /// Without one the commands stay at their initial values (`--command`, the defaults).
    pub fn with_commands(mut self, reader: CommandReader) -> Result<Self, PlayError> {
        let (Some(spec), Some(initial)) = (
            &self.policy.layout.manifest.commands,
            self.policy.layout.command_values(),
        ) else {
            return Err(PlayError::Setup(format!(
                "{}: the policy has no [commands] section, so nothing takes live commands",
                self.policy.layout.path.display()
            )));
        };
        self.policy.commands = Some(LiveCommands::new(spec, initial, Some(reader), self.dt));
        Ok(self)
    }

    /// Sets the commands in force to `values` from now on, bypassing sources and ramps (a replay
    /// feeding back what a run recorded). No effect without `[commands]`.
    pub fn set_commands(&mut self, values: &[f64]) {
        if let Some(c) = &mut self.policy.commands {
            c.set(values);
        }
    }

    /// The live commands in force (with the manifest's `[commands]`).
    pub fn commands(&self) -> Option<&[f64]> {
        self.policy.commands.as_ref().map(LiveCommands::current)
    }

    /// Whether the policy observes no reference (it runs with no clip, on its commands).
    pub fn is_command_driven(&self) -> bool {
        self.policy.command_driven
    }

    /// Publishes each finished tick's number in `ticks` (a relaxed store: nothing waits), for a
    /// progress display on another thread.
    pub fn with_progress(mut self, ticks: Arc<std::sync::atomic::AtomicU64>) -> Self {
        self.progress = Some(ticks);
        self
    }

    /// An e-stop input: when the flag is set, the robot goes to damping at once (a fault, unlike
    /// the soft stop of SIGINT).
    pub fn with_estop(mut self, flag: Arc<AtomicBool>) -> Self {
        self.lifecycle.estop = Some(flag);
        self
    }

    /// Takes the reference from `source` instead of the clip's frames: a teleoperator's stream
    /// ([`crate::reference::TeleopStream`]), a motion generator's plans
    /// ([`crate::generator::PlanReader`]), or any other [`LiveSource`]. Pair it with a one-frame
    /// reference (the standby pose) and [`EndMode::Loop`].
    pub fn with_source(mut self, source: impl LiveSource + 'static) -> Self {
        self.reference.cursor.set_source(Box::new(source));
        self
    }

    /// The observation the policy saw at the last policy tick.
    pub fn observation(&self) -> &[f32] {
        &self.policy.obs
    }

    /// The reference of the last tick, robot order.
    pub fn reference_q(&self) -> &[f64] {
        self.reference.cursor.current_q()
    }

    /// The 2D keypoint errors per view of the last tick (empty when it measured none).
    pub fn keypoint_errors(&self) -> &[crate::keypoints::track::ViewTick] {
        match &self.world.keypoints {
            Some(k) if self.world.keypoints_measured => k.errors(),
            _ => &[],
        }
    }

    /// The policy's default pose, robot order (a generated reference's standby).
    pub fn layout_default_q(&self) -> &[f64] {
        &self.policy.layout.default_q
    }

    /// How far ahead of its tick the policy reads the reference, s (what a generator must cover).
    pub fn lookahead_s(&self) -> f64 {
        self.reference.cursor.lookahead_s()
    }

    /// The generated reference's plans (counts, changes, status), with a generator.
    pub fn generated(&self) -> Option<&crate::generator::PlanReader> {
        self.reference.cursor.generated()
    }

    /// Records every tick as MCAP through `sink`.
    pub fn with_telemetry(mut self, sink: TelemetrySink) -> Self {
        self.telemetry = Some(sink);
        self
    }

    /// Stops recording: waits for the logger and returns what it wrote.
    pub fn finish_telemetry(
        &mut self,
    ) -> Option<Result<crate::telemetry::TelemetryReport, crate::telemetry::TelemetryError>> {
        self.telemetry.take().map(TelemetrySink::finish)
    }

    /// The robot link the loop drives.
    pub fn link(&self) -> &L {
        &self.io
    }

    /// The robot.
    pub fn robot(&self) -> &Robot {
        &self.robot
    }

    /// The robot's name.
    pub fn robot_name(&self) -> &str {
        &self.robot.config.name
    }

    /// Joint names, robot order.
    pub fn joint_names(&self) -> Vec<String> {
        self.robot.config.joints.iter().map(|j| j.name.clone()).collect()
    }

    /// The robot's base frame name.
    pub fn root_frame(&self) -> String {
        self.robot.config.root_body.clone()
    }

    /// The current mode.
    pub fn mode(&self) -> Mode {
        self.lifecycle.machine.mode
    }

    /// Transitions so far.
    pub fn transitions(&self) -> &[Transition] {
        &self.lifecycle.machine.transitions
    }

    /// The last measured state (robot order).
    pub fn state(&self) -> &RobotState {
        &self.state
    }

    /// The last commanded targets (robot order).
    pub fn targets(&self) -> &[JointTarget] {
        &self.targets
    }

    /// What a recording of this run says of it: joint names, root frame, buses, the robot's
    /// kinematics (for the `/tf` links), the reference's length, the motion bodies. The caller
    /// adds how the run was made and the bus cycles, where it has them.
    pub fn recording_info(&self) -> crate::telemetry::RecordingInfo {
        let (bodies, anchor) = self.motion_bodies();
        crate::telemetry::RecordingInfo {
            joint_names: self.joint_names(),
            root_frame: self.root_frame(),
            run: None,
            reference_ticks: Some(self.reference_ticks()),
            bus_names: self.io.bus_names().to_vec(),
            kinematics: Some((
                self.robot.mjcf_path.clone(),
                self.robot
                    .config
                    .joints
                    .iter()
                    .map(|j| j.mjcf_joint.clone())
                    .collect(),
            )),
            model: self.robot.shared_model().ok(),
            bus_cycles: None,
            motion_bodies: bodies.to_vec(),
            anchor,
            keypoint_views: self
                .world
                .keypoints
                .as_ref()
                .map_or_else(Vec::new, KeypointTrack::views),
            commands: self.policy.commands.as_ref().map_or_else(Vec::new, |c| {
                c.spec().names.iter().cloned().zip(c.spec().kinds()).collect()
            }),
            live: None,
            ros2: None,
            foot_names: self.robot.config.feet.clone(),
            clock: crate::telemetry::RecordingClock::Simulated,
            commit: None,
            observation_len: self.policy.obs.len(),
            settings: crate::telemetry::RecordingSettings::default(),
        }
    }

    /// The motion bodies the run measures, and which is the anchor.
    pub fn motion_bodies(&self) -> (&[String], Option<usize>) {
        let r = self.reference.cursor.reference();
        (&r.motion_bodies, r.anchor)
    }

    /// Ticks of the reference at the policy rate.
    pub fn reference_ticks(&self) -> usize {
        self.reference.cursor.reference().len()
    }

    /// Ticks run.
    pub fn ticks(&self) -> u64 {
        self.tick
    }

    fn go(&mut self, to: Mode, cause: Cause) {
        let m = &mut self.lifecycle.machine;
        if m.transitions.len() < m.transitions.capacity() {
            m.transitions.push(Transition {
                tick: self.tick,
                from: m.mode,
                to,
                cause,
            });
        }
        if cause.is_fault() {
            tracing::warn!(tick = self.tick, from = ?m.mode, to = ?to, "{cause}");
        } else {
            tracing::info!(tick = self.tick, from = ?m.mode, to = ?to, "{cause}");
        }
        m.mode = to;
        m.ticks = 0;
    }

    /// Records every bus cycle for telemetry (before the devices are identified): the
    /// recording's `/bus/<name>` channels. False when the link has no bus cycles.
    pub fn record_bus_cycles(&mut self) -> bool {
        // A tick's worth of cycles of the fastest bus, many times over: the loop drains every tick.
        self.io.record_cycles(1024)
    }

    /// Checks every device and goes to Ready.
    pub fn identify(&mut self) -> Result<(), PlayError> {
        self.io.identify()?;
        self.io.read(&mut self.state)?;
        self.go(Mode::Ready, Cause::DevicesIdentified);
        Ok(())
    }

    /// Runs to the end (Off), waiting on `clock` between ticks.
    pub fn run(&mut self, clock: &mut dyn TickClock) -> Result<PlaySummary, PlayError> {
        if self.lifecycle.machine.mode == Mode::Off {
            self.identify()?;
        }
        let period = Duration::from_nanos((self.dt * 1e9).round() as u64);
        let start = clock.elapsed();
        while self.lifecycle.machine.mode != Mode::Off {
            self.step(clock)?;
            if let Some(p) = &self.progress {
                p.store(self.tick, Ordering::Relaxed);
            }
            let deadline = start + period * (self.tick as u32);
            let missed = self.io.wait_until(clock, deadline);
            if missed {
                self.metrics.overruns += 1;
            }
            self.lifecycle.monitor.deadline(missed);
            self.metrics
                .jitter
                .record(clock.elapsed().saturating_sub(deadline));
        }
        let mut summary = self.summary(clock.elapsed() - start);
        // A failed recording (a full disk) does not undo the run: the summary says both.
        match self.finish_telemetry() {
            Some(Ok(report)) => summary.telemetry = Some(report),
            Some(Err(e)) => summary.telemetry_error = Some(e.to_string()),
            None => {}
        }
        Ok(summary)
    }

    /// Lets time pass until `deadline` on `clock`, the buses cycling on the way (for callers
    /// that drive [`Self::step`] themselves); returns whether the deadline had passed.
    pub fn wait_until(&mut self, clock: &mut dyn TickClock, deadline: Duration) -> bool {
        self.io.wait_until(clock, deadline)
    }

    /// One tick: read, check, compute, write.
    pub fn step(&mut self, clock: &dyn TickClock) -> Result<(), PlayError> {
        let t0 = Instant::now();
        let read = self.io.read(&mut self.state);
        let t_read = t0.elapsed();
        self.reference.tracked = None;
        self.policy.ran = false;
        let has_truth = clock.ground_truth(&mut self.world.truth);
        let c0 = Instant::now();
        if let Err(e) = read {
            self.fail(Cause::BusFailure);
            self.metrics.io.record(t_read + c0.elapsed());
            self.tick += 1;
            let _ = self.io.torque_off();
            self.go(Mode::Off, Cause::BusFailure);
            return Err(e.into());
        }
        self.lifecycle.stop_seen = self.lifecycle.stop.load(Ordering::Relaxed);
        let estop = self
            .lifecycle
            .estop
            .as_ref()
            .is_some_and(|f| f.load(Ordering::Relaxed));
        // A mirror whose simulation blew up is named before what its sensors then read.
        if has_truth && self.world.truth.simulation_failed {
            self.metrics.simulation_failed_at.get_or_insert(self.tick);
            self.fail(Cause::SimulationFailed);
        }
        if has_truth {
            self.metrics.mirror_behind_max =
                self.metrics.mirror_behind_max.max(self.world.truth.mirror_behind);
        }
        if let Some(cause) = self.lifecycle.monitor.check(
            self.lifecycle.machine.mode,
            &self.state,
            &self.targets,
            estop,
            self.lifecycle.stop_seen,
        ) {
            // A served mirror that fell behind real time answers late: stale feedback is its.
            let behind = if has_truth {
                self.world.truth.mirror_behind
            } else {
                Duration::ZERO
            };
            self.fail(cause.blaming_a_late_mirror(behind));
        }
        if has_truth {
            // A fall counts while the soft start, the policy or the soft stop is in control; a
            // robot folding up under damping after the run has handed over has not fallen.
            let in_control = matches!(
                self.lifecycle.machine.mode,
                Mode::SoftStart | Mode::Running | Mode::Stopping
            );
            let p = self.world.truth.root_pose;
            let tilt = tilt_of([p[3], p[4], p[5], p[6]]);
            self.metrics.fell |= in_control && tilt > self.options.limits.tilt;
            // Handed over (damped, let go): watched and said, not counted.
            if in_control {
                self.last_controlled_height = Some(p[2]);
            } else if let Some(height) = self.last_controlled_height {
                let a = self.metrics.after_control.get_or_insert(AfterControl {
                    handed_over_at: height,
                    lowest: p[2],
                    max_tilt: tilt,
                    ticks: 0,
                });
                a.lowest = a.lowest.min(p[2]);
                a.max_tilt = a.max_tilt.max(tilt);
                a.ticks += 1;
            }
        }
        // The operator's word counts once the robot is down: one that comes while the harness
        // still lowers it is dropped (and said), so it cannot release the motion later.
        if self.harness_phase() == HarnessPhase::Lowering
            && let Some(f) = &self.lifecycle.lowered
            && f.swap(false, Ordering::Relaxed)
        {
            tracing::warn!(
                tick = self.tick,
                "the operator's word that the robot stands came while the harness was still \
                 lowering it: ignored; say it again once the robot stands"
            );
        }
        // The harness holds the robot while it lowers it (and until the operator's word).
        let rig_holds = matches!(
            self.harness_phase(),
            HarnessPhase::Lowering | HarnessPhase::WaitingForOperator
        );
        self.world.update(
            &self.state,
            has_truth,
            self.options.estimator == EstimatorKind::GroundTruth,
            rig_holds,
            self.lifecycle.monitor.imu_limit(),
            &mut self.metrics,
        );
        self.advance(has_truth);
        let compute = c0.elapsed();
        self.metrics.compute.record(compute);
        let w0 = Instant::now();
        let write = self.io.write(&self.targets);
        let io = t_read + w0.elapsed();
        self.metrics.io.record(io);
        if let Some(source) = self.reference.cursor.take_live_source() {
            self.metrics.live_latency.record(source.elapsed());
        }
        if let Some(sink) = &mut self.telemetry {
            self.record.fill(&TickView {
                tick: self.tick,
                now: clock.elapsed(),
                mode: self.lifecycle.machine.mode,
                state: &self.state,
                targets: &self.targets,
                // A tracked tick records what its errors were measured against (the reference
                // at each sample's time, the root before the cursor moved on), the root in the
                // truth's frame beside the true pose; other ticks the reference in force.
                reference_q: if self.reference.tracked.is_some() {
                    &self.reference.aligned_reference
                } else {
                    self.reference.cursor.current_q()
                },
                reference_root: self.world.truth_to_world.undo(
                    self.reference
                        .tracked
                        .unwrap_or_else(|| self.reference.cursor.current_root()),
                ),
                tracking: self.reference.tracked.is_some(),
                policy_ran: self.policy.ran,
                anchors: self.reference.anchors,
                body_errors: if self.reference.has_body_errors {
                    &self.reference.body_errors
                } else {
                    &[]
                },
                estimate: self.world.estimator.as_ref().map(|_| &self.world.estimate),
                generated: self
                    .reference
                    .cursor
                    .generated()
                    .map(crate::generator::PlanReader::tick),
                keypoint_errors: match &self.world.keypoints {
                    Some(k) if self.world.keypoints_measured => k.errors(),
                    _ => &[],
                },
                triangulated_mm: self
                    .world
                    .keypoints
                    .as_ref()
                    .filter(|_| self.world.keypoints_measured)
                    .and_then(KeypointTrack::triangulated_mm),
                // Held off the ground, the estimate has no truth to be compared with.
                truth_in_world: (has_truth && self.world.truth_mapped).then(|| {
                    let t = self.world.truth_to_world.apply(self.world.truth.root_pose);
                    (t, self.world.truth.base_lin_vel)
                }),
                actions: self.policy.mapper.actions(),
                commands: self
                    .policy
                    .commands
                    .as_ref()
                    .map_or(&[][..], LiveCommands::current),
                truth: &self.world.truth,
                has_truth,
                stop_requested: self.lifecycle.stop_seen,
                bus_times: self.io.bus_times(),
                io,
                compute,
                cause: self.lifecycle.machine.transitions.last().map(|t| t.cause),
                harness: self.lifecycle.harness_phase,
            });
            sink.push_with(&self.record, &self.policy.obs);
            // The buses' cycles since the last tick, when the recording asked for them.
            self.io.drain_cycles(&mut |c| sink.push_cycle(c));
        }
        self.tick += 1;
        self.lifecycle.machine.ticks += 1;
        if let Err(e) = write {
            self.fail(Cause::BusFailure);
            return Err(e.into());
        }
        Ok(())
    }

    /// A fault: hold (if running), then damping, then off; straight to damping when a bus has
    /// damped itself.
    fn fail(&mut self, cause: Cause) {
        match self.lifecycle.machine.mode {
            // A bus damped itself already: the rest follow now, no hold.
            Mode::SoftStart | Mode::Running | Mode::Stopping
                if cause.damps_at_once()
                    && !self.lifecycle.machine.pending.is_some_and(|c| c.damps_at_once()) =>
            {
                self.go(Mode::Damped, cause);
            }
            Mode::Running if !cause.is_fault() => {
                self.go(Mode::Stopping, cause);
                self.begin_soft_stop();
            }
            Mode::SoftStart | Mode::Running => self.go(Mode::Stopping, cause),
            Mode::Stopping
                if !self.lifecycle.machine.pending.is_some_and(|c| c.is_fault()) && cause.is_fault() =>
            {
                // A fault during a soft stop cuts it short.
                self.go(Mode::Damped, cause);
            }
            _ => {}
        }
        self.lifecycle.machine.pending = Some(cause);
    }

    /// The state machine: fills `targets` for this tick.
    fn advance(&mut self, has_truth: bool) {
        let elapsed = self.lifecycle.machine.ticks as f64 * self.dt;
        match self.lifecycle.machine.mode {
            Mode::Off => {}
            Mode::Ready if self.options.start != Some(robots::StartMode::Pd) => {
                // The policy takes the robot from its first tick (on the floor, or in the
                // harness that lowers it).
                self.lifecycle.start_pose.copy_from_slice(&self.state.q);
                // Nothing was commanded yet: the governor's speed limit starts from where the
                // joints are.
                for (t, &q) in self.targets.iter_mut().zip(&self.state.q) {
                    t.q = q;
                }
                self.take_control(Cause::Start, has_truth);
            }
            Mode::Ready => {
                self.lifecycle.start_pose.copy_from_slice(&self.state.q);
                self.go(Mode::SoftStart, Cause::Start);
                self.soft_start_targets();
            }
            Mode::SoftStart if elapsed >= self.options.soft_start_s => {
                self.take_control(Cause::SoftStartDone, has_truth);
            }
            Mode::SoftStart => self.soft_start_targets(),
            Mode::Running if self.clip_done() => {
                let cause = if self.reference.cursor.finished() {
                    Cause::ClipFinished
                } else {
                    Cause::TimeUp
                };
                self.go(Mode::Stopping, cause);
                self.lifecycle.machine.pending = Some(cause);
                self.begin_soft_stop();
                self.stopping_targets(has_truth);
            }
            Mode::Running => self.policy_tick(has_truth),
            Mode::Stopping => self.stopping_targets(has_truth),
            Mode::Damped if elapsed >= self.options.damping_s => {
                for t in &mut self.targets {
                    t.enabled = false;
                }
                self.go(Mode::Off, Cause::DampingDone);
            }
            Mode::Damped => self.damping_targets(),
        }
    }

    /// The policy takes control: from the default pose as its last action, the reference from
    /// its start.
    fn take_control(&mut self, cause: Cause, has_truth: bool) {
        self.policy.mapper.reset(&self.policy.layout.default_q);
        self.reference.cursor.restart();
        self.policy.policy_steps = 0;
        self.policy.gait = policy::GaitClock::of(&self.policy.layout);
        self.go(Mode::Running, cause);
        self.policy_tick(has_truth);
    }

    fn soft_start_targets(&mut self) {
        let s = ((self.lifecycle.machine.ticks + 1) as f64 * self.dt / self.options.soft_start_s).min(1.0);
        let g = self.options.soft_start_gain + (1.0 - self.options.soft_start_gain) * s;
        let margin = self.options.limits.position_margin;
        for (i, j) in self.robot.config.joints.iter().enumerate() {
            let q = self.lifecycle.start_pose[i]
                + (self.policy.layout.default_q[i] - self.lifecycle.start_pose[i]) * s;
            self.targets[i] = JointTarget {
                q: q.clamp(j.position_limits[0] + margin, j.position_limits[1] - margin),
                qd: 0.0,
                kp: self.policy.layout.kp[i] * g,
                kd: self.policy.layout.kd[i],
                tau: 0.0,
                enabled: true,
            };
        }
    }

    /// A soft stop while the policy is in control: it stays in control, the reference held where
    /// the stop came and blended to the standing pose, the commands ramped to rest.
    fn begin_soft_stop(&mut self) {
        self.lifecycle.stop_under_policy = true;
        self.reference.cursor.cut_here();
        let settle = (self.options.settle_s / self.dt).round().max(1.0) as u32;
        if let Some(c) = &mut self.policy.commands {
            c.wind_down(settle);
        }
    }

    /// After a fault: hold one tick, then damp. After a stop request or the clip's end with the
    /// policy in control: the policy settles the robot (reference to the standing pose, commands
    /// to rest) for `settle_s`, then [`OnStop`] says what follows — damp, stay under the policy
    /// until the operator stops again, sit down on the joints' PD, or let the harness take the
    /// weight. A stop before the policy took control blends the PD targets to the default pose.
    ///
    /// [`OnStop`]: crate::options::OnStop
    fn stopping_targets(&mut self, has_truth: bool) {
        use crate::options::OnStop;
        let soft = self.lifecycle.machine.pending.is_some_and(|c| !c.is_fault());
        let ticks = |s: f64, dt: f64| (s / dt).round().max(1.0) as u64;
        if !soft {
            if self.lifecycle.machine.ticks >= 1 {
                self.go(Mode::Damped, Cause::HoldDone);
                self.damping_targets();
            } else {
                self.hold_targets();
            }
            return;
        }
        if !self.lifecycle.stop_under_policy {
            // The PD soft start was still on: blend its targets to the default pose, then damp.
            let stop_ticks = ticks(self.options.end_s, self.dt);
            if self.lifecycle.machine.ticks >= stop_ticks {
                self.go(Mode::Damped, Cause::HoldDone);
                self.damping_targets();
            } else {
                self.blend_targets(stop_ticks - self.lifecycle.machine.ticks);
            }
            return;
        }
        let settle = ticks(self.options.settle_s, self.dt);
        if self.lifecycle.machine.ticks < settle {
            self.policy_tick(has_truth);
            return;
        }
        let stay = |p: &mut Self| {
            let since = *p.lifecycle.standing_since.get_or_insert_with(|| {
                // A fresh stop request ends the stay: the one that began it is spent.
                p.lifecycle.stop.store(false, Ordering::Relaxed);
                p.tick
            });
            let stood = (p.tick - since) as f64 * p.dt;
            let again = p.lifecycle.stop_seen && p.tick > since;
            if !again && p.options.stand_s.is_none_or(|s| stood < s) {
                p.policy_tick(has_truth);
            } else {
                p.go(Mode::Damped, Cause::HoldDone);
                p.damping_targets();
            }
        };
        match self.options.on_stop {
            OnStop::Stay => stay(self),
            OnStop::Harness => match &self.lifecycle.harness_hoist {
                // The mirror's crane takes the weight while the policy keeps the robot standing.
                Some(hoist) => {
                    if !hoist.swap(true, Ordering::Relaxed) {
                        tracing::info!(tick = self.tick, "harness: the crane takes the robot's weight");
                    }
                    let hoisting = ticks(self.robot.config.start.harness.lower_s, self.dt);
                    if self.lifecycle.machine.ticks - settle < hoisting {
                        self.policy_tick(has_truth);
                    } else {
                        self.go(Mode::Damped, Cause::HoldDone);
                        self.damping_targets();
                    }
                }
                // On the robot the operator has the crane take the weight, then stops again.
                None => {
                    if self.lifecycle.standing_since.is_none() {
                        tracing::warn!(
                            tick = self.tick,
                            "harness: take the robot's weight with the crane, then stop again (Ctrl-C or the e-stop)"
                        );
                    }
                    stay(self);
                }
            },
            OnStop::Sit => {
                let sit = ticks(self.options.sit_s, self.dt);
                let done = self.lifecycle.machine.ticks - settle;
                if done >= sit {
                    self.go(Mode::Damped, Cause::HoldDone);
                    self.damping_targets();
                } else {
                    self.blend_targets(sit - done);
                }
            }
            OnStop::Damp => {
                self.go(Mode::Damped, Cause::HoldDone);
                self.damping_targets();
            }
        }
    }

    /// One step of a PD blend from where the targets are to the stop pose (the default pose, or
    /// the sit keyframe), `left` ticks before it ends.
    fn blend_targets(&mut self, left: u64) {
        self.hold_targets();
        let a = 1.0 / left.max(1) as f64;
        let margin = self.options.limits.position_margin;
        let joints = &self.robot.config.joints;
        for ((t, d), j) in self.targets.iter_mut().zip(&self.lifecycle.stop_pose).zip(joints) {
            // The blend is governed from the previous target like any command: far from the
            // stop pose with few ticks left it would otherwise outrun the joint's speed.
            let wanted = t.q + (d - t.q) * a;
            let range = target_range(j, margin, robots::PositionTargets::InsideLimits, 0.0);
            t.q = govern_position(j, t.q, wanted, self.dt, range, None);
        }
    }

    fn hold_targets(&mut self) {
        for (i, t) in self.targets.iter_mut().enumerate() {
            t.kp = self.policy.layout.kp[i];
            t.kd = self.policy.layout.kd[i];
            t.qd = 0.0;
            t.tau = 0.0;
            t.enabled = true;
        }
    }

    fn damping_targets(&mut self) {
        for ((t, &kd), j) in self
            .targets
            .iter_mut()
            .zip(&self.policy.layout.kd)
            .zip(&self.robot.config.joints)
        {
            // Without stiffness the position does nothing, but what leaves the controller stays
            // inside the joint's limits all the same (a target past them under torque reach).
            let [lo, hi] = j.position_limits;
            *t = JointTarget {
                q: if t.q.is_finite() {
                    t.q.clamp(lo, hi)
                } else {
                    j.default_position
                },
                kd,
                enabled: true,
                ..JointTarget::default()
            };
        }
    }

    fn clip_done(&self) -> bool {
        self.options.max_ticks.is_some_and(|m| self.tick >= m) || self.reference.cursor.finished()
    }

    fn policy_tick(&mut self, has_truth: bool) {
        self.world.keypoints_measured = false;
        let frame = self.policy.embedded.as_ref().map(|e| e.frame(&self.policy.model));
        let (mut robot_anchor, mut base_ang_vel) = ([0.0; 7], self.state.gyro);
        robot_anchor[3..].copy_from_slice(&self.state.quat);
        if let Some(k) = &self.world.kinematics {
            robot_anchor = k.anchor_pose();
            base_ang_vel = k.imu_to_root(self.state.gyro);
        }
        if self.world.reads_world && !self.world.world_valid {
            let why = match &self.world.estimator {
                Some(_) if self.options.estimator != EstimatorKind::GroundTruth => self
                    .world
                    .estimate
                    .problem
                    .unwrap_or(world::estimator::EstimateProblem::NotInitialised),
                _ => world::estimator::EstimateProblem::NoGroundTruth,
            };
            self.fail(Cause::EstimateInvalid(why));
            self.hold_targets();
            return;
        }
        if self.reference.cursor.tick() == 0
            && let Some(first) = self.reference.cursor.first_anchor(frame.as_ref())
        {
            // The run starts tracking: the motion is put under the robot.
            let alignment = Alignment::new(first, robot_anchor, self.world.world_valid);
            tracing::info!(
                yaw_deg = alignment.yaw().to_degrees(),
                "reference aligned to the robot's anchor"
            );
            self.reference.cursor.align(alignment);
        }
        let psi = self.reference.cursor.update(
            &self.policy.layout.default_q,
            &self.policy.layout.robot_index,
            frame.as_ref(),
        );
        if let (Some(track), Some(k)) = (&mut self.world.keypoints, &self.world.kinematics) {
            // The robot's keypoints in the reference's frame (where its cameras are): placed by
            // the estimate for the observation, by the simulation's truth for the errors.
            let alignment = self.reference.cursor.alignment();
            let undo = |p: [f64; 3]| alignment.map_or(p, |a| a.undo_point(p));
            let observed = k.root_position();
            let measured = if has_truth {
                let t = self.world.truth_to_world.apply(self.world.truth.root_pose);
                [t[0], t[1], t[2]]
            } else {
                observed
            };
            track.set_positions(
                |i| undo(k.keypoint_position_from(i, observed)),
                |i| undo(k.keypoint_position_from(i, measured)),
            );
        }
        let next = self.reference.cursor.next_frame();
        let this = self.reference.cursor.frame_at(self.reference.cursor.tick());
        let time_step = self
            .policy
            .embedded
            .as_ref()
            .map_or(next as f64, |e| e.time_step(this, next));
        for (p, &r) in self.policy.layout.robot_index.iter().enumerate() {
            self.policy.policy_q[p] = self.state.q[r];
            self.policy.policy_qd[p] = self.state.qd[r];
            self.policy.policy_last_targets[p] = self.targets[r].q;
        }
        // After a harness start the commands rest while the robot is lowered and settles.
        let rest = self.options.start == Some(robots::StartMode::Harness) && self.reference.cursor.in_ramp();
        let command = self
            .policy
            .commands
            .as_mut()
            .map(|c| if rest { c.rest() } else { c.update(Instant::now()) });
        if let Some(g) = &mut self.policy.gait {
            g.advance(command.unwrap_or(&[]));
        }
        let inputs = ObsInputs {
            gyro: self.state.gyro,
            accel: self.state.accel,
            quat: self.state.quat,
            q: &self.policy.policy_q,
            qd: &self.policy.policy_qd,
            default_q: &self.policy.policy_default,
            past_actions: self.policy.mapper.past(),
            last_targets: &self.policy.policy_last_targets,
            step: self.policy.policy_steps,
            dt: self.dt,
            command,
            ramp: psi,
            reference: self.reference.cursor.view(),
            truth: self.world.world_valid.then_some(policy::SimTruth {
                root_pose: self.world.observed.root_pose,
                base_lin_vel: self.world.observed.base_lin_vel,
                foot_contacts: &self.world.observed.foot_contacts,
            }),
            trackers: self.reference.cursor.trackers(),
            base_ang_vel,
            robot_anchor,
            time_step,
            robot_keypoints: self
                .world
                .keypoints
                .as_ref()
                .map_or(&[][..], KeypointTrack::robot_obs),
            gait: self.policy.gait.map_or([0.0; 2], |g| g.phase),
        };
        self.policy.obs_builder.build(&inputs, &mut self.policy.obs);
        if self.reference.cursor.reference().anchor.is_some() {
            self.reference.anchors = Some((robot_anchor, self.reference.cursor.view().anchor_pose()));
        }
        if !self.policy.obs.iter().all(|x| x.is_finite()) {
            self.fail(Cause::NonFinite { what: "observation" });
            self.hold_targets();
            return;
        }
        if self
            .policy
            .model
            .run(&self.policy.obs, self.policy.mapper.actions_mut())
            .is_err()
            || !self.policy.mapper.actions().iter().all(|a| a.is_finite())
        {
            self.fail(Cause::NonFinite { what: "action" });
            self.hold_targets();
            return;
        }
        let limited = self.policy.mapper.map(
            &self.policy.layout,
            &self.robot.config.joints,
            &self.state.q,
            &mut self.targets,
            self.dt,
            crate::safety::TargetRule {
                margin: self.options.limits.position_margin,
                targets: self.robot.config.safety.position_targets,
            },
        );
        self.metrics.governed_ticks += 1;
        if limited.limited > 0 {
            self.metrics.limited_ticks += 1;
            if limited.into_range == limited.limited {
                self.metrics.into_range_ticks += 1;
            }
        }
        // Where each tracked body is against the reference's (simulation: the robot's place is
        // known).
        self.reference.has_body_errors = false;
        if let (true, Some(k)) = (has_truth, &self.world.kinematics) {
            let now = self.reference.cursor.motion_now();
            let t = self.world.truth_to_world.apply(self.world.truth.root_pose);
            for (b, e) in self.reference.body_errors.iter_mut().enumerate() {
                // Where the body really is: the true root, the measured joints.
                let p = k.body_position_from(b, [t[0], t[1], t[2]]);
                *e = spatial::norm(spatial::sub(p, [now[b][0], now[b][1], now[b][2]]));
            }
            self.reference.has_body_errors = !self.reference.body_errors.is_empty();
        }
        // A live operator's key bodies against the robot's, each in its own root's frame (the
        // robot's from its measured joints): how closely the robot follows the person.
        if let (Some(k), Some((first, n)), Some(op)) = (
            &self.world.kinematics,
            self.reference.operator_bodies,
            self.reference.cursor.operator_bodies(),
        ) && op.len() == n
        {
            self.metrics.add_operator(
                op.iter()
                    .enumerate()
                    .map(|(b, o)| spatial::norm(spatial::sub(k.body_in_root(first + b), *o))),
            );
        }
        // Tracking error against the clip (not during the ramp or the end).
        // Each joint's sample is compared with the reference at the time it was taken (`age`
        // before the tick, between this tick's frame and the last): the error of the motion, not
        // of how old the feedback is.
        let current = self.reference.cursor.current_q();
        for (((r, &now), &before), &age) in self
            .reference
            .aligned_reference
            .iter_mut()
            .zip(current)
            .zip(&self.reference.previous_reference)
            .zip(&self.state.age)
        {
            let back = (age.as_secs_f64() / self.dt).min(1.0);
            *r = now + (before - now) * back;
        }
        if self.reference.cursor.in_clip() && !self.policy.command_driven {
            let reference_root = self.reference.cursor.current_root();
            let root = has_truth.then(|| {
                (
                    self.world.truth_to_world.apply(self.world.truth.root_pose),
                    reference_root,
                )
            });
            self.metrics
                .add_tracking(&self.state.q, &self.reference.aligned_reference, root);
            self.reference.tracked = Some(reference_root);
            // The reference as the samples were compared with it: like against like.
            self.metrics
                .reference_jitter
                .push(&self.reference.aligned_reference, self.dt);
            self.metrics.robot_jitter.push(&self.state.q, self.dt);
            if self.reference.has_body_errors {
                self.metrics
                    .add_bodies(self.reference.body_errors.iter().copied());
            }
            if let Some(track) = &mut self.world.keypoints {
                track.measure(self.reference.cursor.frame_at(self.reference.cursor.tick()));
                self.world.keypoints_measured = true;
            }
        }
        self.reference.previous_reference.copy_from_slice(current);
        let phase = self.harness_phase();
        if phase != self.lifecycle.harness_phase {
            tracing::info!(tick = self.tick, "harness: {phase}");
            self.lifecycle.harness_phase = phase;
        }
        // Waiting for the operator's word, the cursor stays where the settling begins (a stop
        // holds the frame it is on anyway).
        if phase != HarnessPhase::WaitingForOperator || self.reference.cursor.is_cut() {
            self.reference.cursor.step();
        }
        self.policy.policy_steps += 1;
        self.policy.ran = true;
        if self.policy.command_driven {
            // A walk's smoothness: the robot's own jitter over the ticks the policy drove it.
            self.metrics.robot_jitter.push(&self.state.q, self.dt);
        }
        // Where the robot went: the simulation's truth where there is one, else the estimate.
        let pose = if has_truth {
            Some(self.world.truth.root_pose)
        } else {
            self.world.world_valid.then_some(self.world.observed.root_pose)
        };
        if let (Some(l), Some(pose)) = (&mut self.metrics.locomotion, pose) {
            let commands = self
                .policy
                .commands
                .as_ref()
                .map_or(&[][..], LiveCommands::current);
            let _ = l.add(pose, commands, self.dt);
        }
    }

    /// The run's summary so far, for callers that drive [`Self::step`] themselves (no wall
    /// time: they kept the clock).
    pub fn summary_so_far(&self) -> PlaySummary {
        self.summary(Duration::ZERO)
    }

    fn summary(&self, took: Duration) -> PlaySummary {
        let mut summary = self.metrics.summary(
            self.tick,
            took,
            &self.lifecycle.machine.transitions,
            self.reference.cursor.is_live(),
            self.reference.cursor.reference().len(),
        );
        summary.keypoints = self.world.keypoints.as_ref().map(KeypointTrack::summary);
        summary.floor = !self.robot.mjcf.floor.is_empty();
        summary
    }

    /// Asks for a soft stop (what SIGINT does).
    /// Whether a stop has been asked for (signal, e-stop or [`Self::request_stop`]).
    pub fn stop_flag(&self) -> &AtomicBool {
        &self.lifecycle.stop
    }

    /// Asks the run to stop, as Ctrl-C does.
    pub fn request_stop(&self) {
        self.lifecycle.stop.store(true, Ordering::Relaxed);
    }
}

/// The run's 2D keypoint references: checked against the policy's keypoint terms (which must
/// all name the same views and keypoints) and the robot's map, their keypoints added to the
/// robot's kinematics (made for them when the run had none).
fn keypoint_setup(
    robot: &Robot,
    layout: &PolicyLayout,
    reference: &mut Reference,
    kinematics: &mut Option<RobotKinematics>,
) -> Result<Option<KeypointTrack>, PlayError> {
    let terms: Vec<(&[String], &[String])> = layout
        .slots
        .iter()
        .filter_map(|s| match &s.term {
            Term::RefKeypoints { views, keypoints, .. } | Term::Keypoints { views, keypoints, .. } => {
                Some((views.as_slice(), keypoints.as_slice()))
            }
            _ => None,
        })
        .collect();
    if terms.windows(2).any(|w| w[0] != w[1]) {
        return Err(PlayError::Setup(format!(
            "{}: the ref_keypoints and keypoints terms must name the same views and keypoints",
            layout.path.display()
        )));
    }
    let Some(keypoints) = reference.keypoints.take() else {
        return if terms.is_empty() {
            Ok(None)
        } else {
            Err(PlayError::Setup(format!(
                "{} observes 2D keypoints: give the run keypoint references and their cameras (play --keypoints FILE --cameras FILE)",
                layout.path.display()
            )))
        };
    };
    if keypoints.ticks != reference.len() {
        return Err(PlayError::Setup(format!(
            "keypoint references of {} ticks beside a reference of {}",
            keypoints.ticks,
            reference.len()
        )));
    }
    let (views, names) = terms.first().copied().unwrap_or_default();
    let mapped: Vec<String> = robot.config.keypoints.keys().cloned().collect();
    if mapped.is_empty() {
        return Err(PlayError::Setup(
            crate::keypoints::KeypointError::NoMap(robot.path.clone()).to_string(),
        ));
    }
    let track = KeypointTrack::new(keypoints, &mapped, views, names)
        .map_err(|e| PlayError::Setup(format!("keypoint references: {e}")))?;
    let k = match kinematics {
        Some(k) => k,
        None => kinematics.insert(RobotKinematics::new(robot, None, &[])?),
    };
    k.track_keypoints(robot, track.names())?;
    Ok(Some(track))
}

/// What a policy tracking a motion needs beyond the clip: the motion bodies' world poses on the
/// reference (by forward kinematics of a clip; an export's own motion carries them) and the
/// robot's kinematics, when the policy observes an anchor or the root's rate or tracks bodies.
fn motion_setup(
    robot: &Robot,
    layout: &PolicyLayout,
    reference: &mut Reference,
    embedded: bool,
) -> Result<Option<RobotKinematics>, PlayError> {
    let m = &layout.manifest;
    let mut bodies = m.motion_bodies.clone();
    if let Some(a) = &m.anchor_body
        && !bodies.contains(a)
    {
        if embedded {
            return Err(PlayError::Setup(format!(
                "anchor body {a:?} is not among the bodies the export's motion carries (body_names: {})",
                bodies.join(", ")
            )));
        }
        bodies.push(a.clone());
    }
    if !embedded && !bodies.is_empty() {
        reference.motion_poses = crate::fk::body_poses(robot, reference, &bodies)?;
        reference.anchor = m
            .anchor_body
            .as_ref()
            .and_then(|a| bodies.iter().position(|b| b == a));
        reference.motion_bodies = bodies.clone();
    }
    // A live source's key bodies are measured on the robot after the motion's own.
    let live = &reference.live_bodies;
    let mut tracked = bodies.clone();
    tracked.extend(live.iter().cloned());
    // The estimator needs the legs: every robot with feet gets its kinematics.
    let needs = !tracked.is_empty()
        || !robot.config.feet.is_empty()
        || layout
            .slots
            .iter()
            .any(|s| s.term.needs_anchor() || matches!(s.term, Term::BaseAngVel(_)));
    Ok(if needs {
        Some(RobotKinematics::new(robot, m.anchor_body.as_deref(), &tracked)?)
    } else {
        None
    })
}
