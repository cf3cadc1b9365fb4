//! The control loop: read → estimate → observe → infer → act → limit → write, once per policy tick,
//! under the state machine of [`crate::safety`]. Every buffer is sized before the first tick; a
//! steady-state tick allocates nothing.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use robots::Robot;

use crate::clip::Reference;
use crate::onnx::OnnxModel;
use crate::policy::{ActionKind, ObsInputs, ObservationBuilder, PolicyLayout, ReferenceView, Term};
use crate::safety::{Cause, Mode, SafetyLimits, Transition, govern_position, govern_torque, tilt_of};
use human::live::{LiveReader, TRACKER_VALUES};
use robot_link::{GroundTruth, IoError, JointTarget, RobotLink, RobotState, TickClock};

/// What happens when the clip ends.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum EndMode {
    /// Hold the last frame for a moment, then stop.
    #[default]
    Hold,
    /// Blend back to the default pose, then stop.
    Blend,
    /// Start the clip again (until stopped).
    Loop,
}

/// How a run goes.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PlayOptions {
    /// Soft start: time to reach the default pose, s.
    pub soft_start_s: f64,
    /// Soft start gain factor.
    pub soft_start_gain: f64,
    /// ψ ramp with the clip held at its first frame, s.
    pub ramp_s: f64,
    /// What happens at the end of the clip.
    pub end: EndMode,
    /// End hold or blend time, s.
    pub end_s: f64,
    /// Damping time before torque off, s.
    pub damping_s: f64,
    /// Safety thresholds.
    pub limits: SafetyLimits,
    /// Stop after this many ticks in any case (loops, tests).
    pub max_ticks: Option<u64>,
}

impl PlayOptions {
    /// The options as text pairs (recorded with a run, read back by a replay).
    pub fn to_pairs(self) -> Vec<(String, String)> {
        let l = &self.limits;
        [
            ("soft_start_s", format!("{:?}", self.soft_start_s)),
            ("soft_start_gain", format!("{:?}", self.soft_start_gain)),
            ("ramp_s", format!("{:?}", self.ramp_s)),
            ("end", format!("{:?}", self.end)),
            ("end_s", format!("{:?}", self.end_s)),
            ("damping_s", format!("{:?}", self.damping_s)),
            ("stale_ticks", l.stale_ticks.to_string()),
            ("tilt", format!("{:?}", l.tilt)),
            ("overruns", l.overruns.to_string()),
            ("position_margin", format!("{:?}", l.position_margin)),
            ("tracking_error", format!("{:?}", l.tracking_error)),
            ("tracking_ticks", l.tracking_ticks.to_string()),
            (
                "max_ticks",
                self.max_ticks.map_or(String::new(), |m| m.to_string()),
            ),
        ]
        .into_iter()
        .map(|(k, v)| (k.to_owned(), v))
        .collect()
    }

    /// Reads options written by [`Self::to_pairs`]; missing keys keep their defaults.
    pub fn from_pairs(get: impl Fn(&str) -> Option<String>) -> Result<Self, String> {
        let mut o = Self::default();
        let num = |k: &str, into: &mut f64| -> Result<(), String> {
            if let Some(v) = get(k) {
                *into = v
                    .parse()
                    .map_err(|_| format!("option {k} = {v:?} is not a number"))?;
            }
            Ok(())
        };
        num("soft_start_s", &mut o.soft_start_s)?;
        num("soft_start_gain", &mut o.soft_start_gain)?;
        num("ramp_s", &mut o.ramp_s)?;
        num("end_s", &mut o.end_s)?;
        num("damping_s", &mut o.damping_s)?;
        num("tilt", &mut o.limits.tilt)?;
        num("position_margin", &mut o.limits.position_margin)?;
        num("tracking_error", &mut o.limits.tracking_error)?;
        if let Some(v) = get("tracking_ticks") {
            o.limits.tracking_ticks = v.parse().map_err(|_| format!("option tracking_ticks = {v:?}"))?;
        }
        if let Some(v) = get("end") {
            o.end = match v.as_str() {
                "Hold" => EndMode::Hold,
                "Blend" => EndMode::Blend,
                "Loop" => EndMode::Loop,
                other => return Err(format!("option end = {other:?} is not Hold, Blend or Loop")),
            };
        }
        if let Some(v) = get("stale_ticks") {
            o.limits.stale_ticks = v.parse().map_err(|_| format!("option stale_ticks = {v:?}"))?;
        }
        if let Some(v) = get("overruns") {
            o.limits.overruns = v.parse().map_err(|_| format!("option overruns = {v:?}"))?;
        }
        if let Some(v) = get("max_ticks").filter(|v| !v.is_empty()) {
            o.max_ticks = Some(v.parse().map_err(|_| format!("option max_ticks = {v:?}"))?);
        }
        Ok(o)
    }
}

impl Default for PlayOptions {
    fn default() -> Self {
        Self {
            soft_start_s: 1.0,
            soft_start_gain: 0.3,
            ramp_s: 1.5,
            end: EndMode::Hold,
            end_s: 0.5,
            damping_s: 0.5,
            limits: SafetyLimits::default(),
            max_ticks: None,
        }
    }
}

/// A histogram of durations in 10 µs bins up to 40 ms, preallocated.
#[derive(Debug, Clone)]
pub struct Histogram {
    bins: Vec<u32>,
    count: u64,
    max: Duration,
}

const BIN: Duration = Duration::from_micros(10);

impl Default for Histogram {
    fn default() -> Self {
        Self {
            bins: vec![0; 4000],
            count: 0,
            max: Duration::ZERO,
        }
    }
}

impl Histogram {
    /// Adds a sample (no allocation).
    pub fn record(&mut self, d: Duration) {
        let i = ((d.as_nanos() / BIN.as_nanos()) as usize).min(self.bins.len() - 1);
        self.bins[i] += 1;
        self.count += 1;
        self.max = self.max.max(d);
    }

    /// The `p`-quantile (upper edge of its bin, never above the largest sample).
    pub fn quantile(&self, p: f64) -> Duration {
        let want = (p * self.count as f64).ceil().max(1.0) as u64;
        let mut seen = 0u64;
        for (i, &c) in self.bins.iter().enumerate() {
            seen += u64::from(c);
            if seen >= want {
                return (BIN * (i as u32 + 1)).min(self.max);
            }
        }
        self.max
    }

    /// Largest sample.
    pub fn max(&self) -> Duration {
        self.max
    }

    /// Samples.
    pub fn count(&self) -> u64 {
        self.count
    }
}

impl std::fmt::Display for Histogram {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "p50 {:.0} µs, p99 {:.0} µs, max {:.0} µs over {} ticks",
            self.quantile(0.5).as_secs_f64() * 1e6,
            self.quantile(0.99).as_secs_f64() * 1e6,
            self.max.as_secs_f64() * 1e6,
            self.count
        )
    }
}

/// What a run did.
#[derive(Debug, Clone)]
pub struct PlaySummary {
    /// Ticks run.
    pub ticks: u64,
    /// Simulated or wall seconds covered.
    pub duration_s: f64,
    /// Ticks that missed their deadline (wall clock only).
    pub overruns: u64,
    /// Joint tracking RMSE over the clip, rad (NaN when the run never reached the clip).
    pub joint_rmse: f64,
    /// Root position RMSE over the clip, m (when the root is known: simulation).
    pub root_rmse: Option<f64>,
    /// Whether the robot fell (tilt beyond the limit).
    pub fell: bool,
    /// Policy ticks where the governor changed a command (limit, speed or torque saturation).
    pub limited_ticks: u64,
    /// The state machine's course.
    pub transitions: Vec<Transition>,
    /// Per-tick compute time (observe, infer, limit).
    pub compute: Histogram,
    /// Per-tick bus time (read + write).
    pub io: Histogram,
    /// How late each tick started after its deadline.
    pub jitter: Histogram,
    /// With a live reference: from the arrival of the input a tick used to its bus write.
    pub live_latency: Option<Histogram>,
    /// What the telemetry logger wrote, when recording.
    pub telemetry: Option<crate::telemetry::TelemetryReport>,
}

impl std::fmt::Display for PlaySummary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(
            f,
            "ran {} ticks ({:.2} s), {} overruns",
            self.ticks, self.duration_s, self.overruns
        )?;
        writeln!(f, "joint tracking RMSE: {:.2}°", self.joint_rmse.to_degrees())?;
        if let Some(r) = self.root_rmse {
            writeln!(f, "root position RMSE:  {:.1} cm", r * 100.0)?;
        }
        writeln!(f, "fell: {}", if self.fell { "YES" } else { "no" })?;
        writeln!(
            f,
            "ticks where the governor limited a command: {}",
            self.limited_ticks
        )?;
        writeln!(f, "compute per tick: {}", self.compute)?;
        writeln!(f, "bus I/O per tick: {}", self.io)?;
        writeln!(f, "tick start lateness: {}", self.jitter)?;
        if let Some(l) = &self.live_latency {
            writeln!(f, "tracker input → bus command: {l}")?;
        }
        if let Some(t) = &self.telemetry {
            writeln!(f, "{t}")?;
        }
        writeln!(f, "state machine:")?;
        for t in &self.transitions {
            writeln!(f, "  tick {:>5}: {:?} → {:?} ({})", t.tick, t.from, t.to, t.cause)?;
        }
        Ok(())
    }
}

/// The reference as the observation sees it at one tick.
#[derive(Debug)]
struct RefCursor {
    /// Robot-order reference of the current tick (blended during ramps).
    current_q: Vec<f64>,
    current_qd: Vec<f64>,
    /// Policy-order copies handed to the observation.
    policy_q: Vec<Vec<f64>>,
    policy_qd: Vec<Vec<f64>>,
    root: Vec<[f64; 7]>,
    body: Vec<Vec<f64>>,
}

impl ReferenceView for RefCursor {
    fn joint_pos(&self, offset: usize) -> &[f64] {
        &self.policy_q[offset.min(self.policy_q.len() - 1)]
    }
    fn joint_vel(&self, offset: usize) -> &[f64] {
        &self.policy_qd[offset.min(self.policy_qd.len() - 1)]
    }
    fn root_pose(&self, offset: usize) -> [f64; 7] {
        self.root[offset.min(self.root.len() - 1)]
    }
    fn body_pos(&self, offset: usize) -> &[f64] {
        &self.body[offset.min(self.body.len() - 1)]
    }
}

/// The controller of one run.
#[derive(Debug)]
pub struct Player<L: RobotLink> {
    robot: Robot,
    layout: PolicyLayout,
    model: OnnxModel,
    obs_builder: ObservationBuilder,
    reference: Reference,
    options: PlayOptions,
    io: L,
    stop: Arc<AtomicBool>,
    estop: Option<Arc<AtomicBool>>,
    /// The stop flag as this tick's checks saw it (recorded, so a replay sees the same).
    stop_seen: bool,
    dt: f64,
    // State machine.
    mode: Mode,
    mode_ticks: u64,
    tick: u64,
    clip_tick: usize,
    transitions: Vec<Transition>,
    pending_cause: Option<Cause>,
    // Buffers, robot order unless named policy_.
    state: RobotState,
    targets: Vec<JointTarget>,
    start_pose: Vec<f64>,
    default_q: Vec<f64>,
    filtered: Vec<f64>,
    cursor: RefCursor,
    policy_q: Vec<f64>,
    policy_qd: Vec<f64>,
    policy_default: Vec<f64>,
    policy_last_targets: Vec<f64>,
    past_actions: Vec<f32>,
    obs: Vec<f32>,
    actions: Vec<f32>,
    truth: GroundTruth,
    // Metrics.
    sq_joint_error: f64,
    joint_samples: u64,
    sq_root_error: f64,
    root_samples: u64,
    overruns: u64,
    overrun_run: u32,
    /// Ticks in a row each joint has been beyond the tracking limit.
    off_target: Vec<u32>,
    limited_ticks: u64,
    fell: bool,
    compute: Histogram,
    io_time: Histogram,
    jitter: Histogram,
    telemetry: Option<crate::telemetry::TelemetrySink>,
    record: Box<crate::telemetry::TickRecord>,
    live: Option<LiveReader>,
    live_source: Option<Instant>,
    live_used: Option<Instant>,
    live_latency: Histogram,
    live_trackers: [f64; TRACKER_VALUES],
}

/// Why a run could not start or continue.
#[derive(Debug, thiserror::Error)]
pub enum PlayError {
    /// The buses.
    #[error(transparent)]
    Io(#[from] IoError),
    /// The policy.
    #[error(transparent)]
    Onnx(#[from] crate::onnx::OnnxError),
    /// The policy manifest.
    #[error(transparent)]
    Policy(#[from] crate::policy::PolicyError),
    /// Something else, described.
    #[error("{0}")]
    Setup(String),
}

const MAX_FRAMES_AHEAD: usize = 64;

impl<L: RobotLink> Player<L> {
    /// Prepares a run: checks the policy against its model, sizes every buffer.
    pub fn new(
        robot: Robot,
        mut layout: PolicyLayout,
        mut reference: Reference,
        options: PlayOptions,
        io: L,
        stop: Arc<AtomicBool>,
    ) -> Result<Self, PlayError> {
        let model = OnnxModel::load(&layout.onnx_path)?;
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
            reference.body_pos =
                crate::fk::body_positions(&robot, &reference, &bodies).map_err(PlayError::Setup)?;
            reference.bodies = bodies;
        }
        let body_width = 3 * reference.bodies.len();
        layout.bind_model(model.inputs(), model.output().1)?;
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
        if frames > MAX_FRAMES_AHEAD {
            return Err(PlayError::Setup(format!(
                "the policy looks {frames} frames ahead; at most {MAX_FRAMES_AHEAD}"
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
            .unwrap_or(0)
            .max(1);
        let default_q: Vec<f64> = layout.default_q.clone();
        let policy_default = layout.robot_index.iter().map(|&r| default_q[r]).collect();
        let obs_builder = ObservationBuilder::new(&layout);
        let obs_len = layout.obs_len;
        Ok(Self {
            dt: 1.0 / layout.manifest.rate_hz,
            cursor: RefCursor {
                current_q: default_q.clone(),
                current_qd: vec![0.0; n],
                policy_q: vec![vec![0.0; n]; frames],
                policy_qd: vec![vec![0.0; n]; frames],
                root: vec![[0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0]; frames],
                body: vec![vec![0.0; body_width]; frames],
            },
            obs_builder,
            model,
            options,
            io,
            stop,
            estop: None,
            stop_seen: false,
            mode: Mode::Off,
            mode_ticks: 0,
            tick: 0,
            clip_tick: 0,
            transitions: Vec::with_capacity(64),
            pending_cause: None,
            state: RobotState::new(n),
            targets: vec![JointTarget::default(); n],
            start_pose: default_q.clone(),
            filtered: default_q.clone(),
            policy_q: vec![0.0; n],
            policy_qd: vec![0.0; n],
            policy_default,
            policy_last_targets: vec![0.0; n],
            past_actions: vec![0.0; k_actions * n],
            obs: vec![0.0; obs_len],
            actions: vec![0.0; n],
            truth: GroundTruth {
                foot_contacts: vec![false; robot.config.feet.len()],
                ..GroundTruth::default()
            },
            default_q,
            sq_joint_error: 0.0,
            joint_samples: 0,
            sq_root_error: 0.0,
            root_samples: 0,
            overruns: 0,
            overrun_run: 0,
            off_target: vec![0; n],
            limited_ticks: 0,
            fell: false,
            compute: Histogram::default(),
            io_time: Histogram::default(),
            jitter: Histogram::default(),
            live: None,
            live_source: None,
            live_used: None,
            live_trackers: [0.0; TRACKER_VALUES],
            live_latency: Histogram::default(),
            telemetry: None,
            record: Box::default(),
            robot,
            layout,
            reference,
        })
    }

    /// An e-stop input: when the flag is set, the robot goes to damping at once (a fault, unlike
    /// the soft stop of SIGINT).
    pub fn with_estop(mut self, flag: Arc<AtomicBool>) -> Self {
        self.estop = Some(flag);
        self
    }

    /// Records every tick into `sink` (see [`crate::telemetry`]).
    /// Tracks a reference another thread computes live (teleoperation) instead of the clip's
    /// frames: each tick copies `live` into the reference's one frame (no allocation). Pair it with
    /// a one-frame reference and [`EndMode::Loop`].
    pub fn with_live(mut self, live: LiveReader) -> Self {
        self.live = Some(live);
        self
    }

    /// Records every tick as MCAP through `sink`.
    pub fn with_telemetry(mut self, sink: crate::telemetry::TelemetrySink) -> Self {
        self.telemetry = Some(sink);
        self
    }

    /// Stops recording: waits for the logger and returns what it wrote.
    pub fn finish_telemetry(&mut self) -> Option<Result<crate::telemetry::TelemetryReport, String>> {
        self.telemetry.take().map(crate::telemetry::TelemetrySink::finish)
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
        self.mode
    }

    /// Transitions so far.
    pub fn transitions(&self) -> &[Transition] {
        &self.transitions
    }

    /// The last measured state (robot order).
    pub fn state(&self) -> &RobotState {
        &self.state
    }

    /// The last commanded targets (robot order).
    pub fn targets(&self) -> &[JointTarget] {
        &self.targets
    }

    /// Ticks run.
    pub fn ticks(&self) -> u64 {
        self.tick
    }

    fn go(&mut self, to: Mode, cause: Cause) {
        if self.transitions.len() < self.transitions.capacity() {
            self.transitions.push(Transition {
                tick: self.tick,
                from: self.mode,
                to,
                cause,
            });
        }
        if cause.is_fault() {
            tracing::warn!(tick = self.tick, from = ?self.mode, to = ?to, "{cause}");
        } else {
            tracing::info!(tick = self.tick, from = ?self.mode, to = ?to, "{cause}");
        }
        self.mode = to;
        self.mode_ticks = 0;
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
        if self.mode == Mode::Off {
            self.identify()?;
        }
        let period = Duration::from_nanos((self.dt * 1e9).round() as u64);
        let start = clock.elapsed();
        while self.mode != Mode::Off {
            self.step(clock)?;
            let deadline = start + period * (self.tick as u32);
            if clock.wait_until(deadline) {
                self.overruns += 1;
                self.overrun_run += 1;
            } else {
                self.overrun_run = 0;
            }
            self.jitter.record(clock.elapsed().saturating_sub(deadline));
        }
        let mut summary = self.summary(clock.elapsed() - start);
        summary.telemetry = self.finish_telemetry().transpose().map_err(PlayError::Setup)?;
        Ok(summary)
    }

    /// One tick: read, check, compute, write.
    pub fn step(&mut self, clock: &dyn TickClock) -> Result<(), PlayError> {
        let t0 = Instant::now();
        let read = self.io.read(&mut self.state);
        let t_read = t0.elapsed();
        let has_truth = clock.ground_truth(&mut self.truth);
        let c0 = Instant::now();
        if let Err(e) = read {
            self.fail(Cause::BusFailure);
            self.finish_io(t_read, c0, Some(e))?;
            return Ok(());
        }
        self.stop_seen = self.stop.load(Ordering::Relaxed);
        self.count_off_target();
        if let Some(cause) = self.check_state() {
            self.fail(cause);
        }
        if has_truth
            && tilt_of([
                self.truth.root_pose[3],
                self.truth.root_pose[4],
                self.truth.root_pose[5],
                self.truth.root_pose[6],
            ]) > self.options.limits.tilt
        {
            self.fell = true;
        }
        self.advance(has_truth);
        let compute = c0.elapsed();
        self.compute.record(compute);
        let w0 = Instant::now();
        let write = self.io.write(&self.targets);
        let io = t_read + w0.elapsed();
        self.io_time.record(io);
        if let Some(source) = self.live_source.take() {
            self.live_latency.record(source.elapsed());
            self.live_used = Some(source);
        }
        if self.telemetry.is_some() {
            self.fill_record(clock.elapsed(), io, compute, has_truth);
            if let Some(t) = &mut self.telemetry {
                t.push(&self.record);
            }
        }
        self.tick += 1;
        self.mode_ticks += 1;
        if let Err(e) = write {
            self.fail(Cause::BusFailure);
            return Err(e.into());
        }
        Ok(())
    }

    fn fill_record(&mut self, now: Duration, io: Duration, compute: Duration, has_truth: bool) {
        use crate::telemetry::{MAX_JOINTS, MAX_OBS};
        let r = &mut *self.record;
        let n = self.state.q.len().min(MAX_JOINTS);
        r.tick = self.tick;
        r.time_ns = now.as_nanos() as u64;
        r.mode = match self.mode {
            Mode::Off => 0,
            Mode::Ready => 1,
            Mode::SoftStart => 2,
            Mode::Running => 3,
            Mode::Stopping => 4,
            Mode::Damped => 5,
        };
        r.joints = n as u16;
        for i in 0..n {
            r.q[i] = self.state.q[i];
            r.qd[i] = self.state.qd[i];
            r.tau[i] = self.state.tau[i];
            r.missed[i] = self.state.missed[i];
            r.faulted[i] = self.state.faulted[i];
            let t = &self.targets[i];
            r.target[i] = [t.q, t.qd, t.kp, t.kd, t.tau];
            r.enabled[i] = t.enabled;
            r.reference_q[i] = self.cursor.current_q[i] as f32;
        }
        r.reference_root = self.cursor.root[0];
        let ramp = (self.options.ramp_s / self.dt).round() as usize;
        r.tracking = self.mode == Mode::Running
            && self.clip_tick > ramp
            && self.clip_tick <= ramp + self.reference.len();
        let m = self.actions.len().min(MAX_JOINTS);
        r.action[..m].copy_from_slice(&self.actions[..m]);
        let k = self.obs.len().min(MAX_OBS);
        r.obs_len = k as u16;
        r.obs[..k].copy_from_slice(&self.obs[..k]);
        r.imu[..3].copy_from_slice(&self.state.gyro);
        r.imu[3..6].copy_from_slice(&self.state.accel);
        r.imu[6..].copy_from_slice(&self.state.quat);
        r.imu_missed = self.state.imu_missed;
        r.base_pose = if has_truth {
            self.truth.root_pose
        } else {
            [f64::NAN; 7]
        };
        r.base_lin_vel = self.truth.base_lin_vel;
        let feet = self.truth.foot_contacts.len().min(crate::telemetry::MAX_FEET);
        r.feet = feet as u8;
        r.foot_contacts[..feet].copy_from_slice(&self.truth.foot_contacts[..feet]);
        r.stop_requested = self.stop_seen;
        let times = self.io.bus_times();
        let b = times.len().min(r.bus_us.len());
        r.buses = b as u8;
        for (slot, t) in r.bus_us.iter_mut().zip(&times[..b]) {
            *slot = t.as_secs_f32() * 1e6;
        }
        r.io_us = io.as_secs_f32() * 1e6;
        r.compute_us = compute.as_secs_f32() * 1e6;
        if let Some(t) = self.transitions.last() {
            use std::io::Write as _;
            let mut cursor = std::io::Cursor::new(&mut r.cause[..]);
            let _ = write!(cursor, "{}", t.cause);
            r.cause_len = cursor.position() as u8;
        }
    }

    fn finish_io(&mut self, t_read: Duration, c0: Instant, e: Option<IoError>) -> Result<(), PlayError> {
        self.io_time.record(t_read + c0.elapsed());
        self.tick += 1;
        let _ = self.io.torque_off();
        self.go(Mode::Off, Cause::BusFailure);
        e.map_or(Ok(()), |e| Err(e.into()))
    }

    /// A fault: hold (if running), then damping, then off.
    fn fail(&mut self, cause: Cause) {
        match self.mode {
            Mode::SoftStart | Mode::Running => self.go(Mode::Stopping, cause),
            Mode::Stopping if !self.pending_cause.is_some_and(|c| c.is_fault()) && cause.is_fault() => {
                // A fault during a soft stop cuts it short.
                self.go(Mode::Damped, cause);
            }
            _ => {}
        }
        self.pending_cause = Some(cause);
    }

    fn check_state(&self) -> Option<Cause> {
        if !matches!(self.mode, Mode::SoftStart | Mode::Running | Mode::Stopping) {
            return None;
        }
        if self.estop.as_ref().is_some_and(|f| f.load(Ordering::Relaxed)) {
            return Some(Cause::EStop);
        }
        let s = &self.state;
        let lim = &self.options.limits;
        if let Some(joint) = s.missed.iter().position(|&m| m > lim.stale_ticks) {
            return Some(Cause::StaleFeedback {
                joint,
                ticks: s.missed[joint],
            });
        }
        if let Some(joint) = s.faulted.iter().position(|&f| f) {
            return Some(Cause::DeviceFault { joint });
        }
        // The IMU may be slower than the loop: allow two of its periods, at least the joints' limit.
        let imu_limit = lim
            .stale_ticks
            .max((2.0 / (self.dt * self.robot.config.imu.rate_hz)).ceil() as u32);
        if s.imu_missed > imu_limit {
            return Some(Cause::StaleImu { ticks: s.imu_missed });
        }
        let finite = |v: &[f64]| v.iter().all(|x| x.is_finite());
        if !(finite(&s.q) && finite(&s.qd) && finite(&s.gyro) && finite(&s.quat)) {
            return Some(Cause::NonFinite { what: "state" });
        }
        let tilt = tilt_of(s.quat);
        if tilt > lim.tilt {
            return Some(Cause::Tilt { angle: tilt });
        }
        if let Some(joint) = self.off_target.iter().position(|&t| t > lim.tracking_ticks) {
            return Some(Cause::TrackingError {
                joint,
                error: self.targets[joint].q - s.q[joint],
            });
        }
        if self.overrun_run >= lim.overruns {
            return Some(Cause::Overruns {
                count: self.overrun_run,
            });
        }
        if self.stop_seen && self.mode != Mode::Stopping {
            return Some(Cause::StopRequested);
        }
        None
    }

    /// Counts, per joint, the ticks in a row its measured position has been beyond the tracking
    /// limit from the position target it was sent (joints under stiffness only).
    fn count_off_target(&mut self) {
        let tracking = matches!(self.mode, Mode::SoftStart | Mode::Running);
        let limit = self.options.limits.tracking_error;
        for ((count, t), &q) in self.off_target.iter_mut().zip(&self.targets).zip(&self.state.q) {
            let off = tracking && t.enabled && t.kp > 0.0 && (t.q - q).abs() > limit;
            *count = if off { count.saturating_add(1) } else { 0 };
        }
    }

    /// The state machine: fills `targets` for this tick.
    fn advance(&mut self, has_truth: bool) {
        let joints = &self.robot.config.joints;
        match self.mode {
            Mode::Off => {}
            Mode::Ready => {
                self.start_pose.copy_from_slice(&self.state.q);
                self.go(Mode::SoftStart, Cause::Start);
                self.soft_start_targets();
            }
            Mode::SoftStart => {
                if self.mode_ticks as f64 * self.dt >= self.options.soft_start_s {
                    self.filtered.copy_from_slice(&self.default_q);
                    self.clip_tick = 0;
                    self.go(Mode::Running, Cause::SoftStartDone);
                    self.policy_tick(has_truth);
                } else {
                    self.soft_start_targets();
                }
            }
            Mode::Running => {
                if self.clip_done() {
                    self.go(Mode::Stopping, Cause::ClipFinished);
                    self.pending_cause = Some(Cause::ClipFinished);
                    self.hold_targets();
                } else {
                    self.policy_tick(has_truth);
                }
            }
            Mode::Stopping => {
                let soft = self.pending_cause.is_some_and(|c| !c.is_fault());
                let stop_ticks = if soft {
                    (self.options.end_s / self.dt).round() as u64
                } else {
                    1
                };
                if self.mode_ticks >= stop_ticks {
                    self.go(Mode::Damped, Cause::HoldDone);
                    self.damping_targets();
                } else if soft {
                    // Blend towards the default pose from where the targets are.
                    let a = 1.0 / (stop_ticks - self.mode_ticks) as f64;
                    let margin = self.options.limits.position_margin;
                    for ((t, d), j) in self.targets.iter_mut().zip(&self.default_q).zip(joints) {
                        t.q += (d - t.q) * a;
                        t.q = govern_position(j, t.q, t.q, self.dt, margin, None);
                    }
                } else {
                    self.hold_targets();
                }
            }
            Mode::Damped => {
                if self.mode_ticks as f64 * self.dt >= self.options.damping_s {
                    for t in &mut self.targets {
                        t.enabled = false;
                    }
                    self.go(Mode::Off, Cause::DampingDone);
                } else {
                    self.damping_targets();
                }
            }
        }
    }

    fn soft_start_targets(&mut self) {
        let s = ((self.mode_ticks + 1) as f64 * self.dt / self.options.soft_start_s).min(1.0);
        let g = self.options.soft_start_gain + (1.0 - self.options.soft_start_gain) * s;
        for (i, j) in self.robot.config.joints.iter().enumerate() {
            let q = self.start_pose[i] + (self.default_q[i] - self.start_pose[i]) * s;
            self.targets[i] = JointTarget {
                q: q.clamp(
                    j.position_limits[0] + self.options.limits.position_margin,
                    j.position_limits[1] - self.options.limits.position_margin,
                ),
                qd: 0.0,
                kp: self.layout.kp[i] * g,
                kd: self.layout.kd[i],
                tau: 0.0,
                enabled: true,
            };
        }
    }

    fn hold_targets(&mut self) {
        for (i, t) in self.targets.iter_mut().enumerate() {
            t.kp = self.layout.kp[i];
            t.kd = self.layout.kd[i];
            t.qd = 0.0;
            t.tau = 0.0;
            t.enabled = true;
        }
    }

    fn damping_targets(&mut self) {
        for (t, &kd) in self.targets.iter_mut().zip(&self.layout.kd) {
            *t = JointTarget {
                q: t.q,
                qd: 0.0,
                kp: 0.0,
                kd,
                tau: 0.0,
                enabled: true,
            };
        }
    }

    fn clip_done(&self) -> bool {
        if self.options.max_ticks.is_some_and(|m| self.tick >= m) {
            return true;
        }
        let ramp = (self.options.ramp_s / self.dt).round() as usize;
        let end = match self.options.end {
            EndMode::Loop => return false,
            EndMode::Hold | EndMode::Blend => (self.options.end_s / self.dt).round() as usize,
        };
        self.clip_tick >= ramp + self.reference.len() + end
    }

    /// Where the reference is at this tick: ramp (held first frame, ψ rising), clip, end.
    fn update_reference(&mut self) -> f64 {
        if let Some(live) = &mut self.live {
            let frame = live.latest();
            let n = self.reference.n;
            self.reference.q[..n].copy_from_slice(&frame.q);
            self.reference.qd[..n].copy_from_slice(&frame.qd);
            self.reference.root[0] = frame.root;
            self.live_trackers = frame.trackers;
            // Latency counts to the first command that uses an input, not the ones after it.
            self.live_source = frame.source.filter(|s| Some(*s) != self.live_used);
        }
        let ramp = (self.options.ramp_s / self.dt).round() as usize;
        let len = self.reference.len();
        let psi = if ramp == 0 {
            1.0
        } else {
            (self.clip_tick as f64 / ramp as f64).min(1.0)
        };
        let base = self.clip_tick.saturating_sub(ramp);
        let base = if self.options.end == EndMode::Loop {
            base % len
        } else {
            base
        };
        let end_ticks = ((self.options.end_s / self.dt).round() as usize).max(1);
        let frames = self.cursor.policy_q.len();
        for f in 0..frames {
            let k = base + f;
            let (q, qd) = (self.reference.q_at(k), self.reference.qd_at(k));
            let blend = if self.options.end == EndMode::Blend && k >= len {
                ((k - len + 1) as f64 / end_ticks as f64).min(1.0)
            } else {
                0.0
            };
            for (p, &r) in self.layout.robot_index.iter().enumerate() {
                let moving = self.clip_tick >= ramp && k < len;
                self.cursor.policy_q[f][p] = q[r] + (self.default_q[r] - q[r]) * blend;
                self.cursor.policy_qd[f][p] = if moving { qd[r] } else { 0.0 };
            }
            self.cursor.root[f] = self.reference.root[k.min(len - 1)];
            if !self.reference.bodies.is_empty() {
                self.cursor.body[f].copy_from_slice(self.reference.body_pos_at(k));
            }
            if f == 0 {
                for (p, &r) in self.layout.robot_index.iter().enumerate() {
                    self.cursor.current_q[r] = self.cursor.policy_q[0][p];
                    self.cursor.current_qd[r] = self.cursor.policy_qd[0][p];
                }
            }
        }

        psi
    }

    fn policy_tick(&mut self, has_truth: bool) {
        let psi = self.update_reference();
        let idx = &self.layout.robot_index;
        for (p, &r) in idx.iter().enumerate() {
            self.policy_q[p] = self.state.q[r];
            self.policy_qd[p] = self.state.qd[r];
            self.policy_last_targets[p] = self.targets[r].q;
        }
        let inputs = ObsInputs {
            gyro: self.state.gyro,
            accel: self.state.accel,
            quat: self.state.quat,
            q: &self.policy_q,
            qd: &self.policy_qd,
            default_q: &self.policy_default,
            past_actions: &self.past_actions,
            last_targets: &self.policy_last_targets,
            time_s: self.clip_tick as f64 * self.dt,
            ramp: psi,
            reference: &self.cursor,
            truth: has_truth.then_some(&self.truth),
            trackers: self.live.is_some().then_some(&self.live_trackers),
        };
        self.obs_builder.build(&inputs, &mut self.obs);
        if !self.obs.iter().all(|x| x.is_finite()) {
            self.fail(Cause::NonFinite { what: "observation" });
            self.hold_targets();
            return;
        }
        if self.model.run(&self.obs, &mut self.actions).is_err()
            || !self.actions.iter().all(|a| a.is_finite())
        {
            self.fail(Cause::NonFinite { what: "action" });
            self.hold_targets();
            return;
        }
        // Remember actions, newest first.
        let n = self.actions.len();
        let kept = self.past_actions.len() - n;
        self.past_actions.copy_within(..kept, n);
        self.past_actions[..n].copy_from_slice(&self.actions);
        let spec = &self.layout.manifest.action;
        let alpha = spec.lowpass_hz.map_or(1.0, |fc| {
            let rc = 1.0 / (std::f64::consts::TAU * fc);
            self.dt / (rc + self.dt)
        });
        let margin = self.options.limits.position_margin;
        let mut limited = 0u64;
        for (p, &r) in idx.iter().enumerate() {
            let j = &self.robot.config.joints[r];
            let a = f64::from(self.actions[p]);
            let a = spec.clip.map_or(a, |c| a.clamp(-c, c));
            self.targets[r] = match spec.kind {
                ActionKind::Position => {
                    let wanted = self.default_q[r] + spec.scale.unwrap_or(1.0) * a;
                    self.filtered[r] += alpha * (wanted - self.filtered[r]);
                    let previous = self.targets[r].q;
                    let governed =
                        govern_position(j, previous, self.filtered[r], self.dt, margin, spec.rate_limit);
                    if governed != self.filtered[r] {
                        limited += 1;
                    }
                    JointTarget {
                        q: governed,
                        qd: 0.0,
                        kp: self.layout.kp[r],
                        kd: self.layout.kd[r],
                        tau: 0.0,
                        enabled: true,
                    }
                }
                ActionKind::Torque => JointTarget {
                    q: self.state.q[r],
                    qd: 0.0,
                    kp: 0.0,
                    kd: 0.0,
                    tau: {
                        let tau = govern_torque(j, a * j.torque_limit);
                        if tau != a * j.torque_limit {
                            limited += 1;
                        }
                        tau
                    },
                    enabled: true,
                },
            };
        }
        if limited > 0 {
            self.limited_ticks += 1;
        }
        // Tracking error against the clip (not during the ramp or the end).
        let ramp = (self.options.ramp_s / self.dt).round() as usize;
        if self.clip_tick >= ramp && self.clip_tick < ramp + self.reference.len() {
            for i in 0..self.state.q.len() {
                let e = self.state.q[i] - self.cursor.current_q[i];
                self.sq_joint_error += e * e;
            }
            self.joint_samples += self.state.q.len() as u64;
            if has_truth {
                let r = self.cursor.root[0];
                let t = self.truth.root_pose;
                let e2 = (0..3).map(|k| (t[k] - r[k]).powi(2)).sum::<f64>();
                self.sq_root_error += e2;
                self.root_samples += 1;
            }
        }
        self.clip_tick += 1;
    }

    fn summary(&self, took: Duration) -> PlaySummary {
        PlaySummary {
            ticks: self.tick,
            duration_s: took.as_secs_f64(),
            overruns: self.overruns,
            joint_rmse: if self.joint_samples > 0 {
                (self.sq_joint_error / self.joint_samples as f64).sqrt()
            } else {
                f64::NAN
            },
            root_rmse: (self.root_samples > 0)
                .then(|| (self.sq_root_error / self.root_samples as f64).sqrt()),
            fell: self.fell,
            limited_ticks: self.limited_ticks,
            transitions: self.transitions.clone(),
            compute: self.compute.clone(),
            io: self.io_time.clone(),
            jitter: self.jitter.clone(),
            live_latency: self.live.is_some().then(|| self.live_latency.clone()),
            telemetry: None,
        }
    }

    /// Asks for a soft stop (what SIGINT does).
    pub fn request_stop(&self) {
        self.stop.store(true, Ordering::Relaxed);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn histogram_quantiles_bracket_the_samples() {
        let mut h = Histogram::default();
        for us in 1..=100u64 {
            h.record(Duration::from_micros(us));
        }
        assert_eq!(h.count(), 100);
        // 10 µs bins, upper edges: the median sample (50 µs) lies in the [50, 60) µs bin.
        assert_eq!(h.quantile(0.5), Duration::from_micros(60));
        assert_eq!(h.quantile(0.99), Duration::from_micros(100));
        assert_eq!(h.max(), Duration::from_micros(100));
        let mut idle = Histogram::default();
        idle.record(Duration::ZERO);
        assert_eq!(idle.quantile(0.99), Duration::ZERO);
    }
}
