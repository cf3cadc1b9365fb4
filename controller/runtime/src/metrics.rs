//! What a run measures about itself: durations as preallocated histograms, tracking errors,
//! overruns and governor saturation, and the summary printed at the end.

use std::time::Duration;

pub use human::commands::CommandKind;
use robots::spatial;

pub use crate::histogram::Histogram;
use crate::safety::Transition;

/// Distance (m) and rotation angle (rad) between two root poses `[x, y, z, w, qx, qy, qz]`.
pub fn root_error(a: [f64; 7], b: [f64; 7]) -> (f64, f64) {
    let d = spatial::norm(spatial::sub([a[0], a[1], a[2]], [b[0], b[1], b[2]]));
    let rel = spatial::quat_mul(
        spatial::quat_conj([a[3], a[4], a[5], a[6]]),
        [b[3], b[4], b[5], b[6]],
    );
    (d, spatial::norm(spatial::quat_log(rel)))
}

/// How motion-tracking trainers end an episode (BeyondMimic's and mjlab's terminations on the
/// anchor, here the root): its height more than this far from the reference's, m…
pub const EPISODE_HEIGHT_M: f64 = 0.25;
/// …or the vertical component of gravity in its frame more than this from the reference's (a tilt
/// the reference does not have).
pub const EPISODE_GRAVITY_Z: f64 = 0.8;

/// A root pose against the reference's as a tracking trainer judges an episode: the height
/// difference, m, and the difference of gravity's vertical component in either frame. Drift over
/// the floor and yaw are not errors: a tracker that observes no world position drifts as in its
/// trainer's own simulation. Poses `[x, y, z, w, qx, qy, qz]`.
pub fn episode_error(a: [f64; 7], b: [f64; 7]) -> (f64, f64) {
    // Gravity's vertical component in a body's frame is −R_zz.
    let r_zz = |p: [f64; 7]| {
        let n = p[3] * p[3] + p[4] * p[4] + p[5] * p[5] + p[6] * p[6];
        1.0 - 2.0 * (p[4] * p[4] + p[5] * p[5]) / n
    };
    ((a[2] - b[2]).abs(), (r_zz(a) - r_zz(b)).abs())
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
    /// The tick the mirror's simulation was found diverged (a model unstable at its step): what
    /// the run read before it stopped may be the blow-up's, not a robot's.
    pub simulation_failed_at: Option<u64>,
    /// The most a mirror served in real time fell behind the wall clock (zero in lockstep).
    pub mirror_behind_max: Duration,
    /// The robot's model has a floor (without one a robot falls through the world upright, and
    /// neither `fell` nor the root's errors say anything).
    pub floor: bool,
    /// What the robot did once the run had handed it over (damped, or let go), in simulation.
    pub after_control: Option<AfterControl>,
    /// Policy ticks where the governor changed a command (limit, speed or torque saturation).
    pub limited_ticks: u64,
    /// Of those, ticks where it only brought position targets into their joints' range (what a
    /// trainer's joint limits do to the same targets).
    pub into_range_ticks: u64,
    /// Policy ticks the governor saw.
    pub governed_ticks: u64,
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
    /// Largest root position (m) and orientation (rad) error over the clip (simulation).
    pub root_max_error: Option<(f64, f64)>,
    /// Largest [`episode_error`]s over the clip: height (m), gravity's vertical component
    /// (simulation).
    pub episode_max_error: Option<(f64, f64)>,
    /// Share of the reference played (1 = to its end; live references count as played).
    pub played: f64,
    /// Position RMSE of each tracked motion body over the clip, m (simulation).
    pub body_rmse: Vec<(String, f64)>,
    /// Which of them is the anchor.
    pub anchor: Option<usize>,
    /// RMS distance of each key body from where a live source placed it on its operator, in the
    /// root's frame, m, and the ticks measured (whole-body teleoperation).
    pub operator_rmse: Vec<(String, f64)>,
    /// (See `operator_rmse`.)
    pub operator_ticks: u64,
    /// The state estimate against the simulation's truth (runs with both).
    pub estimator: Option<EstimatorAccuracy>,
    /// Ticks the estimator ran with the robot held (a harness, a gantry): not compared.
    pub estimator_held_ticks: u64,
    /// A command-driven run (no clip): where the robot went against its commands. Such a run
    /// reports no clip-tracking numbers.
    pub locomotion: Option<LocomotionSummary>,
    /// The jitter (mean |d³q/dt³|, rad/s³) of the reference and of the robot's joints over the
    /// tracked ticks.
    pub jitter_rad_s3: Option<(Option<f64>, f64)>,
    /// A generated reference: the generator's steps, latency and lateness.
    pub generator: Option<crate::generator::GeneratorSummary>,
    /// 2D keypoint references: the robot's keypoints against them.
    pub keypoints: Option<crate::keypoints::track::KeypointSummary>,
    /// The commands' sources: what they accepted and dropped (with live commands).
    pub command_sources: Option<String>,
    /// What the telemetry logger wrote, when recording.
    pub telemetry: Option<crate::telemetry::TelemetryReport>,
    /// Why the recording failed, if it did (the run itself went on).
    pub telemetry_error: Option<String>,
    /// The policy ran on its commands, with no clip (its figures are the course it walked).
    pub command_driven: bool,
}

impl std::fmt::Display for PlaySummary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(
            f,
            "ran {} ticks ({:.2} s), {} overruns",
            self.ticks, self.duration_s, self.overruns
        )?;
        // What fits the run: a command-driven one has no clip to track, a run that never
        // tracked has no error — said, never a NaN.
        match (&self.locomotion, self.command_driven) {
            (Some(l), _) => write!(f, "{l}")?,
            (None, true) => writeln!(
                f,
                "distance: not measured (the policy never drove the robot with its pose known)"
            )?,
            (None, false) if self.joint_rmse.is_nan() => {
                writeln!(f, "joint tracking RMSE: none (no tick tracked the reference)")?;
            }
            (None, false) => writeln!(f, "joint tracking RMSE: {:.2}°", self.joint_rmse.to_degrees())?,
        }
        if let Some(c) = &self.command_sources {
            writeln!(f, "commands: {c}")?;
        }
        if let Some(r) = self.root_rmse {
            writeln!(f, "root position RMSE:  {:.1} cm", r * 100.0)?;
        }
        if !self.body_rmse.is_empty() {
            let worst = self
                .body_rmse
                .iter()
                .max_by(|a, b| a.1.total_cmp(&b.1))
                .expect("not empty");
            writeln!(
                f,
                "body position RMSE:  {:.1} cm mean over {} bodies, worst {} {:.1} cm",
                100.0 * self.body_rmse.iter().map(|b| b.1).sum::<f64>() / self.body_rmse.len() as f64,
                self.body_rmse.len(),
                worst.0,
                100.0 * worst.1
            )?;
            if let Some(a) = self.anchor {
                let (name, e) = &self.body_rmse[a];
                writeln!(f, "anchor ({name}) RMSE: {:.1} cm", 100.0 * e)?;
            }
        }
        if !self.operator_rmse.is_empty() {
            let each: Vec<String> = self
                .operator_rmse
                .iter()
                .map(|(b, e)| format!("{b} {:.1}", 100.0 * e))
                .collect();
            writeln!(
                f,
                "key bodies from the operator (scaled, in the root's frame), cm RMS over {} ticks: {}",
                self.operator_ticks,
                each.join(", ")
            )?;
        }
        match (&self.estimator, self.estimator_held_ticks) {
            (Some(e), 0) => writeln!(f, "state estimate ({}): {e}", e.filter)?,
            (Some(e), held) => writeln!(
                f,
                "state estimate ({}): {e} (after {held} ticks held off the ground, not compared)",
                e.filter
            )?,
            (None, 0) => {}
            (None, _) => writeln!(
                f,
                "state estimate: the robot was held the whole run (its feet never carried its weight): \
                 no ground to compare it on"
            )?,
        }
        if self.floor {
            writeln!(f, "fell: {}", if self.fell { "YES" } else { "no" })?;
            if self.mirror_behind_max > Duration::ZERO {
                writeln!(
                    f,
                    "mirror: at most {:.1} ms behind real time",
                    self.mirror_behind_max.as_secs_f64() * 1000.0
                )?;
            }
            if let Some(tick) = self.simulation_failed_at {
                writeln!(
                    f,
                    "mirror: the simulation diverged at tick {tick}: the model is not stable at its physics \
                     step (`robodeploy check` settles it and names the joints); what the run read before \
                     stopping came from the blow-up, not from a robot"
                )?;
            }
            if let Some(a) = &self.after_control {
                writeln!(
                    f,
                    "after control ended ({:.2} s watched, not counted as a fall): the base sank {:.1} cm \
                     and tilted up to {:.0}°",
                    a.ticks as f64 * self.duration_s / self.ticks.max(1) as f64,
                    100.0 * a.sank(),
                    a.max_tilt.to_degrees()
                )?;
            }
        } else {
            writeln!(
                f,
                "fell: cannot tell, no floor in the model (the robot falls through the world upright; \
                 its root errors say nothing)"
            )?;
        }
        if self.command_driven {
            writeln!(
                f,
                "success (no fall, no safety stop): {}",
                if self.success() { "yes" } else { "NO" }
            )?;
        } else {
            match self.generator.as_ref().filter(|g| g.never_came()) {
                Some(g) => writeln!(
                    f,
                    "reference played: none — the generator produced no usable plan ({} steps, {} failed)",
                    g.worker.steps, g.worker.failed
                )?,
                None => writeln!(f, "reference played: {:.0} %", 100.0 * self.played)?,
            }
            writeln!(
                f,
                "success (as tracking trainers end an episode: no fall, no safety stop, played to the end, \
                 root height within {EPISODE_HEIGHT_M} m of the reference's and gravity's vertical \
                 component within {EPISODE_GRAVITY_Z}): {}",
                if self.success() { "yes" } else { "NO" }
            )?;
            if let Some((d, a)) = self.root_max_error {
                writeln!(
                    f,
                    "root within 1 m and 45° of the reference (ReActor's bound, drift over the floor \
                     included; not the verdict): {} (at most {:.2} m, {:.0}°)",
                    if d <= ROOT_SUCCESS_M && a <= ROOT_SUCCESS_RAD {
                        "yes"
                    } else {
                        "no"
                    },
                    d,
                    a.to_degrees()
                )?;
            }
        }
        if self.into_range_ticks > 0 {
            writeln!(
                f,
                "ticks where the governor limited a command: {} of {} ({} only into the joints' range, as the \
                 trainer's joint limits end the same targets)",
                self.limited_ticks, self.governed_ticks, self.into_range_ticks
            )?;
        } else {
            writeln!(
                f,
                "ticks where the governor limited a command: {} of {}",
                self.limited_ticks, self.governed_ticks
            )?;
        }
        if self.governor_saturated() {
            writeln!(f, "governor: {}", self.saturation())?;
        }
        writeln!(f, "compute per tick: {}", self.compute)?;
        writeln!(f, "bus I/O per tick: {}", self.io)?;
        writeln!(f, "tick start lateness: {}", self.jitter)?;
        match self.jitter_rad_s3 {
            Some((Some(r), q)) => writeln!(
                f,
                "jitter (mean |d³q/dt³|): reference {r:.1} rad/s³, robot {q:.1} rad/s³"
            )?,
            Some((None, q)) => writeln!(f, "jitter (mean |d³q/dt³|): robot {q:.1} rad/s³")?,
            None => {}
        }
        if let Some(g) = &self.generator {
            write!(f, "{g}")?;
        }
        if let Some(k) = &self.keypoints {
            write!(f, "{k}")?;
        }
        if let Some(l) = self.live_latency.as_ref().filter(|l| l.count() > 0) {
            writeln!(f, "tracker input → bus command: {l}")?;
        }
        if let Some(t) = &self.telemetry {
            writeln!(f, "{t}")?;
        }
        if let Some(e) = &self.telemetry_error {
            writeln!(f, "telemetry: FAILED: {e}")?;
        }
        writeln!(f, "state machine:")?;
        for t in &self.transitions {
            writeln!(f, "  tick {:>5}: {:?} → {:?} ({})", t.tick, t.from, t.to, t.cause)?;
        }
        Ok(())
    }
}

/// How a run ended. Exit statuses and reports go by it.
/// The robot after the run had handed it over (the damping at its end, or a damped stop): no
/// fall is counted there, so the run says what happened instead.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AfterControl {
    /// The base's height on the last tick under control, m.
    pub handed_over_at: f64,
    /// The lowest the base went afterwards, m.
    pub lowest: f64,
    /// The most the base tilted afterwards, rad.
    pub max_tilt: f64,
    /// Ticks watched after control ended.
    pub ticks: u64,
}

impl AfterControl {
    /// How far the base sank after control ended, m.
    pub fn sank(&self) -> f64 {
        (self.handed_over_at - self.lowest).max(0.0)
    }
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub enum RunOutcome {
    /// The reference played to its end (or the tick budget ran out) without a fault.
    Finished,
    /// The operator stopped it: SIGINT/SIGTERM (a soft stop) or the e-stop.
    StoppedByOperator {
        /// Tick of the stop.
        tick: u64,
        /// Why.
        cause: crate::safety::Cause,
    },
    /// A fault stopped it, or the robot fell.
    SafetyStop {
        /// Tick of the stop (the last tick for a fall noticed without a stop).
        tick: u64,
        /// Why (`None`: the base fell).
        cause: Option<crate::safety::Cause>,
    },
}

impl std::fmt::Display for RunOutcome {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Finished => write!(f, "finished"),
            Self::StoppedByOperator { tick, cause } => {
                write!(f, "stopped by the operator at tick {tick}: {cause}")
            }
            Self::SafetyStop { tick, cause: Some(c) } => write!(f, "safety stop at tick {tick}: {c}"),
            Self::SafetyStop { tick, cause: None } => {
                write!(f, "safety stop: the base fell (by tick {tick})")
            }
        }
    }
}

impl PlaySummary {
    /// How the run ended: the first stop that was not the clip's own end decides; a fall is a
    /// safety stop even when nothing else stopped the run.
    pub fn outcome(&self) -> RunOutcome {
        use crate::safety::Cause;
        let stop = self
            .transitions
            .iter()
            .find(|t| t.cause.is_fault() || t.cause == Cause::StopRequested);
        match stop {
            Some(t) if matches!(t.cause, Cause::StopRequested | Cause::EStop) => {
                if self.fell {
                    RunOutcome::SafetyStop {
                        tick: t.tick,
                        cause: None,
                    }
                } else {
                    RunOutcome::StoppedByOperator {
                        tick: t.tick,
                        cause: t.cause,
                    }
                }
            }
            Some(t) => RunOutcome::SafetyStop {
                tick: t.tick,
                cause: Some(t.cause),
            },
            None if self.fell => RunOutcome::SafetyStop {
                tick: self.ticks,
                cause: None,
            },
            None => RunOutcome::Finished,
        }
    }
}

/// A tracking run's success as its trainer would have let the episode run: no fall, no safety
/// stop, the reference played to its end, and (when the root is known) its [`episode_error`]s
/// never beyond [`EPISODE_HEIGHT_M`] and [`EPISODE_GRAVITY_Z`]. Reports and batch tables both
/// decide by this.
pub fn tracking_success(
    fell: bool,
    safety_stop: bool,
    played: Option<f64>,
    episode_max_error: Option<(f64, f64)>,
) -> bool {
    !fell
        && !safety_stop
        && played.is_none_or(|p| p >= 1.0 - 1e-9)
        && episode_max_error.is_none_or(|(h, g)| h <= EPISODE_HEIGHT_M && g <= EPISODE_GRAVITY_Z)
}

/// ReActor's bound on the root's position error, m (reported beside the verdict).
pub const ROOT_SUCCESS_M: f64 = 1.0;
/// ReActor's bound on the root's orientation error, rad (45°).
pub const ROOT_SUCCESS_RAD: f64 = std::f64::consts::FRAC_PI_4;

/// A run in which the governor changed more than this share of the policy's commands did not
/// run the policy: the limits did.
pub const SATURATED_SHARE: f64 = 0.5;

impl PlaySummary {
    /// Whether the run counts as a success ([`tracking_success`]; and the policy, not the
    /// governor, commanded the robot).
    pub fn success(&self) -> bool {
        tracking_success(
            self.fell,
            matches!(self.outcome(), RunOutcome::SafetyStop { .. }),
            Some(self.played),
            self.episode_max_error,
        ) && self.shortfall().is_none()
    }

    /// What kept a run that finished from doing what it was asked, if anything: the governor
    /// commanded instead of the policy, or the generated reference never came.
    pub fn shortfall(&self) -> Option<String> {
        if self.governor_saturated() {
            return Some(self.saturation());
        }
        self.generator.as_ref().filter(|g| g.never_came()).map(|g| {
            format!(
                "the generated reference never came: {} steps, {} failed (the robot stood on standby)",
                g.worker.steps, g.worker.failed
            )
        })
    }

    /// The governor changed more than [`SATURATED_SHARE`] of the policy's commands (over at
    /// least 10 of them) beyond bringing targets into their joints' range, which the trainer's
    /// joint limits do as well: the policy's actions do not fit the robot.
    pub fn governor_saturated(&self) -> bool {
        self.governed_ticks >= 10
            && self.unfitting_ticks() as f64 > SATURATED_SHARE * self.governed_ticks as f64
    }

    /// Ticks the governor changed for more than the joints' range.
    fn unfitting_ticks(&self) -> u64 {
        self.limited_ticks - self.into_range_ticks.min(self.limited_ticks)
    }

    /// What a saturated governor means, for the verdict.
    pub fn saturation(&self) -> String {
        format!(
            "the governor limited {:.0} % of the policy's commands ({} of {} ticks, beyond bringing targets \
             into their joints' range): its actions do not fit this robot (action scale, default pose, joint \
             order?)",
            100.0 * self.unfitting_ticks() as f64 / self.governed_ticks.max(1) as f64,
            self.unfitting_ticks(),
            self.governed_ticks
        )
    }
}

/// What a command-driven run (no clip) did: where the robot went against what it was commanded.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct LocomotionSummary {
    /// Policy ticks measured.
    pub ticks: u64,
    /// Length of the base's path over the floor, m.
    pub distance_m: f64,
    /// From the first measured position to the last, m.
    pub displacement_m: f64,
    /// Heading turned through, rad (left positive, unwrapped: two turns are 4π).
    pub heading_change: f64,
    /// Mean commanded forward, leftward speed (m/s) and turning rate (rad/s), for the commands
    /// the manifest has (`None` where it has no such command).
    pub commanded: [Option<f64>; 3],
    /// Mean achieved forward, leftward speed and turning rate, in the heading frame.
    pub achieved: [f64; 3],
    /// RMS of commanded − achieved per tick, for the commanded ones.
    pub error_rms: [Option<f64>; 3],
}

impl std::fmt::Display for LocomotionSummary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(
            f,
            "distance: {:.2} m travelled, {:.2} m from the start, heading turned {:+.1}°",
            self.distance_m,
            self.displacement_m,
            self.heading_change.to_degrees()
        )?;
        for (k, (name, unit)) in [("forward", "m/s"), ("leftward", "m/s"), ("turning", "rad/s")]
            .iter()
            .enumerate()
        {
            match (self.commanded[k], self.error_rms[k]) {
                (Some(c), Some(e)) => writeln!(
                    f,
                    "{name:<9} commanded {c:+.3} {unit}, achieved {:+.3} {unit} (RMS error {e:.3})",
                    self.achieved[k]
                )?,
                _ => writeln!(
                    f,
                    "{name:<9} achieved {:+.3} {unit} (not commanded)",
                    self.achieved[k]
                )?,
            }
        }
        Ok(())
    }
}

/// Running sums of a command-driven run, fed each policy tick with the base's world pose.
#[derive(Debug, Clone, Default)]
pub struct LocomotionMetrics {
    /// Which command index drives forward, leftward speed and turning.
    slots: [Option<usize>; 3],
    start: Option<[f64; 3]>,
    last: Option<([f64; 3], f64)>,
    ticks: u64,
    distance: f64,
    heading: f64,
    sum_commanded: [f64; 3],
    sum_achieved: [f64; 3],
    sq_error: [f64; 3],
}

impl LocomotionMetrics {
    /// Metrics for commands of these kinds.
    pub fn new(kinds: &[CommandKind]) -> Self {
        use human::commands::CommandKind as K;
        let find = |k: K| kinds.iter().position(|&x| x == k);
        Self {
            slots: [find(K::LinVelX), find(K::LinVelY), find(K::AngVelZ)],
            ..Self::default()
        }
    }

    /// One policy tick `dt` after the last: the base's world pose `[x, y, z, w, qx, qy, qz]` and
    /// the commands in force. Returns the forward and leftward speed and turning rate achieved
    /// since the last tick (none at the first).
    pub fn add(&mut self, pose: [f64; 7], commands: &[f64], dt: f64) -> Option<[f64; 3]> {
        let p = [pose[0], pose[1], pose[2]];
        let yaw = spatial::heading_of_quat([pose[3], pose[4], pose[5], pose[6]]);
        self.start.get_or_insert(p);
        let mut step = None;
        if let Some((q, last_yaw)) = self.last {
            let (dx, dy) = (p[0] - q[0], p[1] - q[1]);
            let turned = wrap_angle(yaw - last_yaw);
            // Speeds in the heading frame halfway through the step.
            let mid = last_yaw + turned / 2.0;
            let achieved = [
                (dx * mid.cos() + dy * mid.sin()) / dt,
                (-dx * mid.sin() + dy * mid.cos()) / dt,
                turned / dt,
            ];
            self.distance += dx.hypot(dy);
            self.heading += turned;
            self.ticks += 1;
            for (k, a) in achieved.into_iter().enumerate() {
                self.sum_achieved[k] += a;
                if let Some(c) = self.slots[k].and_then(|i| commands.get(i)) {
                    self.sum_commanded[k] += c;
                    self.sq_error[k] += (c - a).powi(2);
                }
            }
            step = Some(achieved);
        }
        self.last = Some((p, yaw));
        step
    }

    /// Which command index drives forward speed, leftward speed and turning, where one does.
    pub fn slots(&self) -> [Option<usize>; 3] {
        self.slots
    }

    /// What the run did, once it measured a step.
    pub fn summary(&self) -> Option<LocomotionSummary> {
        let n = self.ticks as f64;
        let (start, (end, _)) = (self.start?, self.last?);
        (self.ticks > 0).then(|| LocomotionSummary {
            ticks: self.ticks,
            distance_m: self.distance,
            displacement_m: (end[0] - start[0]).hypot(end[1] - start[1]),
            heading_change: self.heading,
            commanded: std::array::from_fn(|k| self.slots[k].map(|_| self.sum_commanded[k] / n)),
            achieved: self.sum_achieved.map(|s| s / n),
            error_rms: std::array::from_fn(|k| self.slots[k].map(|_| (self.sq_error[k] / n).sqrt())),
        })
    }
}

/// An angle in (−π, π].
fn wrap_angle(a: f64) -> f64 {
    let t = std::f64::consts::TAU;
    a - t * ((a + std::f64::consts::PI) / t).floor()
}

/// Sums of the estimator's errors against the truth, tick by tick.
#[derive(Debug, Clone, Default)]
struct EstimatorErrors {
    ticks: u64,
    sq_velocity: f64,
    sq_vertical_velocity: f64,
    sq_height: f64,
    position_error: f64,
    max_position_error: f64,
    feet_agreeing: u64,
    feet_compared: u64,
    held_ticks: u64,
    filter: world::estimator::FilterKind,
}

/// How well the state estimate followed the simulation's truth over a run.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct EstimatorAccuracy {
    /// The filter that made the estimate.
    pub filter: world::estimator::FilterKind,
    /// Ticks compared (the estimate valid, the truth known).
    pub ticks: u64,
    /// Base velocity RMSE (norm of the error vector), m/s.
    pub velocity_rmse: f64,
    /// Vertical velocity RMSE, m/s.
    pub vertical_velocity_rmse: f64,
    /// Base height RMSE, m.
    pub height_rmse: f64,
    /// Base position error at the end, m (drift from the start).
    pub final_position_error: f64,
    /// Largest base position error, m.
    pub max_position_error: f64,
    /// Share of foot-ticks whose contact agreed with the truth.
    pub contact_agreement: f64,
}

impl std::fmt::Display for EstimatorAccuracy {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        if self.ticks == 0 {
            return f.write_str(
                "never valid while the robot stood (it did not start, or the run ended first): no figures",
            );
        }
        write!(
            f,
            "velocity RMSE {:.3} m/s (vertical {:.3}), height RMSE {:.1} mm, position error {:.1} cm at the end \
             ({:.1} cm max), contacts agree {:.1} % over {} ticks",
            self.velocity_rmse,
            self.vertical_velocity_rmse,
            1000.0 * self.height_rmse,
            100.0 * self.final_position_error,
            100.0 * self.max_position_error,
            100.0 * self.contact_agreement,
            self.ticks
        )
    }
}

/// The jitter of a motion (Mimic2DM's smoothness metric): the mean magnitude of the joints'
/// third time derivative, |d³q/dt³| over joints and samples, rad/s³, from third differences of
/// samples `dt` apart. Keeps the last three samples (sized at the first), allocating nothing after.
#[derive(Debug, Clone, Default)]
pub struct Jitter {
    /// The last three samples, newest first, per joint.
    past: Vec<[f64; 3]>,
    seen: usize,
    sum: f64,
    count: u64,
}

impl Jitter {
    /// For `n` joints.
    pub fn new(n: usize) -> Self {
        Self {
            past: vec![[0.0; 3]; n],
            ..Self::default()
        }
    }

    /// Adds the next sample, `dt` s after the last.
    pub fn push(&mut self, q: &[f64], dt: f64) {
        for (p, &x) in self.past.iter_mut().zip(q) {
            if self.seen >= 3 {
                let d3 = x - 3.0 * p[0] + 3.0 * p[1] - p[2];
                self.sum += d3.abs() / (dt * dt * dt);
                self.count += 1;
            }
            *p = [x, p[0], p[1]];
        }
        self.seen += 1;
    }

    /// Starts over (a gap in the samples).
    pub fn restart(&mut self) {
        self.seen = 0;
    }

    /// The mean |d³q/dt³|, rad/s³, once four samples were seen.
    pub fn mean(&self) -> Option<f64> {
        (self.count > 0).then(|| self.sum / self.count as f64)
    }
}

/// The running sums behind a [`PlaySummary`], updated in the tick without allocating.
#[derive(Debug, Clone, Default)]
pub struct RunMetrics {
    sq_joint_error: f64,
    joint_samples: u64,
    sq_root_error: f64,
    root_samples: u64,
    root_max: (f64, f64),
    episode_max: (f64, f64),
    /// Reference ticks played (in the clip proper).
    pub played_ticks: u64,
    /// Ticks that missed their deadline.
    pub overruns: u64,
    /// Policy ticks where the governor changed a command.
    pub limited_ticks: u64,
    /// Of those, ticks where it only brought targets into their joints' range.
    pub into_range_ticks: u64,
    /// Policy ticks the governor saw.
    pub governed_ticks: u64,
    /// The base tilted beyond the limit at some point.
    pub fell: bool,
    /// The tick the mirror's simulation was found diverged, if it was.
    pub simulation_failed_at: Option<u64>,
    /// The most a mirror served in real time fell behind the wall clock.
    pub mirror_behind_max: Duration,
    /// The robot after the run handed it over (simulation).
    pub after_control: Option<AfterControl>,
    /// Compute per tick.
    pub compute: Histogram,
    /// Bus I/O per tick.
    pub io: Histogram,
    /// Tick start lateness.
    pub jitter: Histogram,
    /// Live input arrival to bus write.
    pub live_latency: Histogram,
    /// The state estimate against the simulation's truth.
    estimator: EstimatorErrors,
    /// A command-driven run's course.
    pub locomotion: Option<LocomotionMetrics>,
    /// The motion's tracked bodies, their summed squared position errors, and the anchor.
    bodies: Vec<String>,
    sq_body_error: Vec<f64>,
    body_samples: u64,
    anchor: Option<usize>,
    /// A live source's key bodies and their summed squared distances from the operator's.
    operator_bodies: Vec<String>,
    sq_operator_error: Vec<f64>,
    operator_samples: u64,
    /// The reference's and the robot's jitter over the tracked ticks.
    pub reference_jitter: Jitter,
    /// (See `reference_jitter`.)
    pub robot_jitter: Jitter,
}

impl RunMetrics {
    /// Sizes the jitter sums for `n` joints.
    pub fn track_jitter(&mut self, n: usize) {
        self.reference_jitter = Jitter::new(n);
        self.robot_jitter = Jitter::new(n);
    }

    /// Adds one tick's joint errors (measured − reference) and, in simulation, the root's
    /// (measured and reference root poses `[x, y, z, w, qx, qy, qz]`).
    pub fn add_tracking(&mut self, q: &[f64], reference: &[f64], root: Option<([f64; 7], [f64; 7])>) {
        for (a, b) in q.iter().zip(reference) {
            self.sq_joint_error += (a - b) * (a - b);
        }
        self.joint_samples += q.len() as u64;
        self.played_ticks += 1;
        if let Some((measured, wanted)) = root {
            let (d, a) = root_error(measured, wanted);
            self.sq_root_error += d * d;
            self.root_samples += 1;
            self.root_max = (self.root_max.0.max(d), self.root_max.1.max(a));
            let (h, g) = episode_error(measured, wanted);
            self.episode_max = (self.episode_max.0.max(h), self.episode_max.1.max(g));
        }
    }

    /// Counts a tick the estimator ran with the robot held (nothing to compare).
    pub fn add_held_tick(&mut self) {
        self.estimator.held_ticks += 1;
    }

    /// Adds one tick of the estimate against the truth in the estimate's frame: its world
    /// position, world velocity and the feet's contacts.
    pub fn add_estimate(
        &mut self,
        estimate: &world::estimator::Estimate,
        truth_position: [f64; 3],
        truth_velocity: [f64; 3],
        truth_contacts: &[bool],
    ) {
        use robots::spatial::{dot, norm, sub};
        let e = &mut self.estimator;
        e.filter = estimate.filter;
        let dv = sub(estimate.velocity, truth_velocity);
        e.ticks += 1;
        e.sq_velocity += dot(dv, dv);
        e.sq_vertical_velocity += dv[2] * dv[2];
        let dz = estimate.position[2] - truth_position[2];
        e.sq_height += dz * dz;
        e.position_error = norm(sub(estimate.position, truth_position));
        e.max_position_error = e.max_position_error.max(e.position_error);
        for (c, t) in estimate.contacts[..estimate.feet].iter().zip(truth_contacts) {
            e.feet_compared += 1;
            e.feet_agreeing += u64::from(c == t);
        }
    }

    /// Measures the position errors of these motion bodies (one of them the anchor).
    pub fn track_bodies(&mut self, names: &[String], anchor: Option<usize>) {
        self.bodies = names.to_vec();
        self.sq_body_error = vec![0.0; names.len()];
        self.anchor = anchor;
    }

    /// Measures the distance of these robot frames from a live operator's.
    pub fn track_operator(&mut self, names: &[String]) {
        self.operator_bodies = names.to_vec();
        self.sq_operator_error = vec![0.0; names.len()];
    }

    /// Adds one tick's distances of the key bodies from the operator's, m, in their order.
    pub fn add_operator(&mut self, errors: impl Iterator<Item = f64>) {
        for (sum, e) in self.sq_operator_error.iter_mut().zip(errors) {
            *sum += e * e;
        }
        self.operator_samples += 1;
    }

    /// Adds one tick's position errors of the tracked bodies, m, in their order.
    pub fn add_bodies(&mut self, errors: impl Iterator<Item = f64>) {
        for (sum, e) in self.sq_body_error.iter_mut().zip(errors) {
            *sum += e * e;
        }
        self.body_samples += 1;
    }

    /// The summary of a run of `ticks` over `took`, of a reference `reference_ticks` long.
    pub fn summary(
        &self,
        ticks: u64,
        took: Duration,
        transitions: &[Transition],
        live: bool,
        reference_ticks: usize,
    ) -> PlaySummary {
        PlaySummary {
            ticks,
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
            simulation_failed_at: self.simulation_failed_at,
            mirror_behind_max: self.mirror_behind_max,
            floor: true,
            after_control: self.after_control,
            limited_ticks: self.limited_ticks,
            into_range_ticks: self.into_range_ticks,
            governed_ticks: self.governed_ticks,
            transitions: transitions.to_vec(),
            compute: self.compute.clone(),
            io: self.io.clone(),
            jitter: self.jitter.clone(),
            live_latency: live.then(|| self.live_latency.clone()),
            root_max_error: (self.root_samples > 0).then_some(self.root_max),
            episode_max_error: (self.root_samples > 0).then_some(self.episode_max),
            played: if live || self.locomotion.is_some() {
                1.0
            } else {
                (self.played_ticks as f64 / reference_ticks.max(1) as f64).min(1.0)
            },
            body_rmse: if self.body_samples > 0 {
                self.bodies
                    .iter()
                    .zip(&self.sq_body_error)
                    .map(|(b, s)| (b.clone(), (s / self.body_samples as f64).sqrt()))
                    .collect()
            } else {
                Vec::new()
            },
            anchor: self.anchor.filter(|_| self.body_samples > 0),
            operator_rmse: if self.operator_samples > 0 {
                self.operator_bodies
                    .iter()
                    .zip(&self.sq_operator_error)
                    .map(|(b, s)| (b.clone(), (s / self.operator_samples as f64).sqrt()))
                    .collect()
            } else {
                Vec::new()
            },
            operator_ticks: self.operator_samples,
            estimator: (self.estimator.ticks > 0).then(|| {
                let e = &self.estimator;
                let n = e.ticks as f64;
                EstimatorAccuracy {
                    filter: e.filter,
                    ticks: e.ticks,
                    velocity_rmse: (e.sq_velocity / n).sqrt(),
                    vertical_velocity_rmse: (e.sq_vertical_velocity / n).sqrt(),
                    height_rmse: (e.sq_height / n).sqrt(),
                    final_position_error: e.position_error,
                    max_position_error: e.max_position_error,
                    contact_agreement: if e.feet_compared > 0 {
                        e.feet_agreeing as f64 / e.feet_compared as f64
                    } else {
                        1.0
                    },
                }
            }),
            estimator_held_ticks: self.estimator.held_ticks,
            locomotion: self.locomotion.as_ref().and_then(LocomotionMetrics::summary),
            jitter_rad_s3: self
                .robot_jitter
                .mean()
                .map(|q| (self.reference_jitter.mean(), q)),
            command_driven: self.locomotion.is_some(),
            generator: None,
            keypoints: None,
            command_sources: None,
            telemetry: None,
            telemetry_error: None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn targets_only_brought_into_the_joints_range_do_not_make_the_governor_saturated() {
        // A spin kick whose targets pass the joints' range on 98 of 100 ticks: the trainer's joint
        // limits end them the same way, so the policy fits the robot.
        let mut m = RunMetrics {
            governed_ticks: 100,
            limited_ticks: 98,
            into_range_ticks: 98,
            ..RunMetrics::default()
        };
        let s = m.summary(100, Duration::from_secs(2), &[], false, 100);
        assert!(!s.governor_saturated() && s.shortfall().is_none());
        assert!(
            s.to_string()
                .contains("98 of 100 (98 only into the joints' range"),
            "{s}"
        );
        // Speed limits on 60 of them: that the trainer does not do.
        m.into_range_ticks = 38;
        let s = m.summary(100, Duration::from_secs(2), &[], false, 100);
        assert!(s.governor_saturated(), "{s}");
        assert!(s.saturation().contains("60 of 100 ticks"), "{}", s.saturation());
    }

    #[test]
    fn an_estimate_never_compared_prints_no_figures() {
        let never = EstimatorAccuracy {
            filter: world::estimator::FilterKind::default(),
            ticks: 0,
            velocity_rmse: f64::NAN,
            vertical_velocity_rmse: f64::NAN,
            height_rmse: f64::NAN,
            final_position_error: 0.0,
            max_position_error: 0.0,
            contact_agreement: f64::NAN,
        };
        let line = never.to_string();
        assert!(
            line.starts_with("never valid") && !line.contains("RMSE") && !line.contains("NaN"),
            "{line}"
        );
        let compared = EstimatorAccuracy {
            ticks: 10,
            velocity_rmse: 0.05,
            ..never
        };
        assert!(compared.to_string().starts_with("velocity RMSE 0.050 m/s"));
    }

    #[test]
    fn a_drifted_turned_root_is_a_success_a_fallen_or_sunk_one_is_not() {
        let reference = [0.0, 0.0, 0.8, 1.0, 0.0, 0.0, 0.0];
        // 3 m away over the floor and turned 120° about z: ReActor's bound fails, the trainer's holds.
        let h = (60f64).to_radians();
        let drifted = [3.0, 1.0, 0.8, h.cos(), 0.0, 0.0, h.sin()];
        let (d, a) = root_error(drifted, reference);
        assert!(d > ROOT_SUCCESS_M && a > ROOT_SUCCESS_RAD);
        let (height, gravity) = episode_error(drifted, reference);
        assert!(height < 1e-12 && gravity < 1e-12);
        assert!(tracking_success(false, false, Some(1.0), Some((height, gravity))));
        // 30 cm lower, or pitched 90° where the reference stands: the episode would have ended.
        let sunk = [0.0, 0.0, 0.5, 1.0, 0.0, 0.0, 0.0];
        assert!(!tracking_success(
            false,
            false,
            Some(1.0),
            Some(episode_error(sunk, reference))
        ));
        let p = (45f64).to_radians();
        let pitched = [0.0, 0.0, 0.8, p.cos(), 0.0, p.sin(), 0.0];
        let (_, gravity) = episode_error(pitched, reference);
        assert!((gravity - 1.0).abs() < 1e-12, "{gravity}");
        assert!(!tracking_success(false, false, Some(1.0), Some((0.0, gravity))));
    }

    #[test]
    fn jitter_is_the_mean_third_derivative() {
        // q = t³ has d³q/dt³ = 6 everywhere; a line has none.
        let dt = 0.02;
        let mut j = Jitter::new(2);
        for k in 0..50 {
            let t = f64::from(k) * dt;
            j.push(&[t * t * t, 3.0 * t], dt);
        }
        let mean = j.mean().unwrap();
        assert!((mean - 3.0).abs() < 1e-6, "(6 + 0) / 2 = 3, got {mean}");
        assert_eq!(Jitter::new(1).mean(), None);
    }

    #[test]
    fn histogram_quantiles_bracket_the_samples() {
        let mut h = Histogram::default();
        for us in 1..=100u64 {
            h.record(Duration::from_micros(us));
        }
        assert_eq!(h.count(), 100);
        // Nearest rank, to the microsecond: the 50th and the 99th sample.
        assert_eq!(h.quantile(0.5), Duration::from_micros(50));
        assert_eq!(h.quantile(0.99), Duration::from_micros(99));
        assert_eq!(h.max(), Duration::from_micros(100));
        let mut idle = Histogram::default();
        idle.record(Duration::ZERO);
        assert_eq!(idle.quantile(0.99), Duration::ZERO);
    }
}
