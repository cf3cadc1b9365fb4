//! Run reports, made from a run's MCAP: tracking per joint over time, root position and orientation
//! error against ReActor's bounds (1 m, 45°), the verdict as tracking trainers end an episode, RMSE of
//! root position (cm), root orientation (deg) and joints (deg), jitter (mean |d³q/dt³|), loop timing,
//! bus misses and safety events. Written as `report.html` — one self-contained page: the verdict,
//! the safety timeline, pictures of the moments that matter, every joint's tracking with its limits,
//! root, bodies, estimator and timing plots (`plotters`, SVG), the safety phases shaded behind
//! each — with its plots also as SVG files in `plots/`, `summary.md` and `summary.json`.

use crate::recording::RecordingError;
use plot::PlotError;
use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::Path;

use controller::metrics::{
    EPISODE_GRAVITY_Z, EPISODE_HEIGHT_M, Jitter, episode_error, root_error, tracking_success,
};

mod frames;
mod plot;

use crate::AnalysisError;
use telemetry_schema as pb;

/// The headline numbers of a run.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct RunSummary {
    /// Ticks recorded.
    pub ticks: usize,
    /// Ticks tracking the clip (the metrics' window).
    pub tracking_ticks: usize,
    /// Joint RMSE per joint, deg.
    pub joint_rmse_deg: BTreeMap<String, f64>,
    /// Joint RMSE over all joints, deg.
    pub joints_rmse_deg: f64,
    /// Root position RMSE, cm (simulation runs).
    pub root_position_rmse_cm: Option<f64>,
    /// Root orientation RMSE, deg (simulation runs).
    pub root_orientation_rmse_deg: Option<f64>,
    /// Whether the base fell (tilt beyond the run's limit; simulation runs).
    pub fell: Option<bool>,
    /// Whether a fault stopped the run.
    pub safety_stop: bool,
    /// Share of the reference played (when the recording says how long it was).
    pub played: Option<f64>,
    /// Success: no fall, no safety stop, the reference played to its end, and (simulation) the
    /// root's height and tilt as a tracking trainer judges an episode — [`tracking_success`]; and a
    /// recording that says all of it (finished, with its `/replay` channel). Never for a run
    /// whose end is not in the file.
    pub success: bool,
    /// Where the recording stops without its footer (the run was killed, or its disk filled):
    /// what happened after is unknown. None: the logger finished the file.
    pub recording_cut_at: Option<usize>,
    /// The recording has its `/replay` channel (the run's options, the reference's length, the
    /// truth): without it, whether the robot fell and how much it played are unknown.
    pub replay_recorded: bool,
    /// Why the run is not a success, in words (empty when it is).
    pub failures: Vec<String>,
    /// Mean magnitude of the third time derivative of joint positions, rad/s³ (the robot's, over
    /// the tracking window).
    pub jitter: f64,
    /// The same of the reference (e.g. what a motion generator produced), rad/s³; none for a
    /// command-driven run (no reference).
    pub reference_jitter: Option<f64>,
    /// A generated reference (`play --generator`): the generator's steps and how it kept up.
    pub generator: Option<GeneratorFigures>,
    /// 2D keypoint references (`play --keypoints`): the robot's keypoints against them, per view.
    pub keypoints: Vec<KeypointFigures>,
    /// With two views or more: the triangulated error, mean over the measured ticks, mm.
    pub triangulated_mm: Option<f64>,
    /// Ticks where some joint's feedback was missing.
    pub bus_miss_ticks: usize,
    /// Safety transitions: tick, mode, cause.
    pub safety_events: Vec<(u64, String, String)>,
    /// Bus I/O per tick: p50, p99, max, µs.
    pub io_us: [f64; 3],
    /// Compute per tick: p50, p99, max, µs.
    pub compute_us: [f64; 3],
    /// Position RMSE of each tracked motion body over the tracking window, cm (simulation runs
    /// of policies that track bodies).
    pub body_rmse_cm: BTreeMap<String, f64>,
    /// The anchor body's, cm.
    pub anchor_rmse_cm: Option<f64>,
    /// The state estimate against the truth over the whole run (simulation runs with an
    /// estimator).
    pub estimator: Option<EstimatorFigures>,
    /// Ticks the estimate ran with the robot held (a harness, a gantry): not compared.
    pub estimator_held_ticks: usize,
    /// A command-driven run (no clip): where the robot went against its commands, while the
    /// policy was in control (simulation runs). Such a run has no clip-tracking numbers.
    pub locomotion: Option<controller::metrics::LocomotionSummary>,
}

/// What a motion generator did over a run, from `/policy`'s `generated`.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct GeneratorFigures {
    /// Steps seen (distinct plans the loop read).
    pub steps: u64,
    /// Their inference time: p50, p99, max, µs.
    pub latency_us: [f64; 3],
    /// Ticks inside a plan, on the forecast, past the forecast's bound.
    pub fresh_ticks: usize,
    /// (See `fresh_ticks`.)
    pub forecast_ticks: usize,
    /// (See `fresh_ticks`.)
    pub standby_ticks: usize,
}

/// One view's reprojection error over a run, from `/policy`'s `keypoint_errors`.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct KeypointFigures {
    /// The camera.
    pub view: String,
    /// Mean of the ticks' mean errors, and the largest error, px.
    pub mean_px: f64,
    /// (See `mean_px`.)
    pub max_px: f64,
    /// Ticks measured, and those over 100 px.
    pub ticks: usize,
    /// (See `ticks`.)
    pub failed_ticks: usize,
}

/// How well the state estimate followed the simulation's truth, from a recording's `/estimator`.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct EstimatorFigures {
    /// Ticks with a valid estimate and the truth beside it.
    pub ticks: usize,
    /// Base velocity RMSE (base axes), m/s.
    pub velocity_rmse: f64,
    /// Base height RMSE, mm.
    pub height_rmse_mm: f64,
    /// Base position error at the end, cm.
    pub final_position_error_cm: f64,
    /// Share of foot-ticks whose contact agreed with the truth, %.
    pub contact_agreement_pct: f64,
}

/// One tick of the estimate against the truth.
#[derive(Debug, Clone, Copy)]
struct EstimateTick {
    time: f64,
    /// Base velocity error, m/s.
    velocity: f64,
    /// Height error (estimate − truth), m.
    height: f64,
    /// Position error, m.
    position: f64,
    /// Feet whose contact agreed, of those compared.
    agree: usize,
    compared: usize,
}

#[derive(Debug, Default)]
struct Series {
    time: Vec<f64>,
    q: Vec<Vec<f64>>,
    reference_q: Vec<Vec<f64>>,
    reference_root: Vec<[f64; 7]>,
    tracking: Vec<bool>,
    base_pose: Vec<[f64; 7]>,
    missed: Vec<bool>,
    io: Vec<f64>,
    compute: Vec<f64>,
    safety: Vec<(u64, String, String)>,
    joints: Vec<String>,
    /// A safety transition had a fault as its cause.
    faulted: bool,
    /// The first such cause.
    fault_cause: Option<String>,
    /// Ticks of the reference, when the recording says.
    reference_ticks: Option<usize>,
    /// The run's tilt limit, rad (the default when the recording does not say).
    tilt_limit: f64,
    /// Each tick with a valid estimate and the truth beside it.
    estimator: Vec<EstimateTick>,
    /// Ticks the estimate says the robot was held.
    estimator_held: usize,
    /// Tracked motion bodies, their anchor, and their position errors per tick (m).
    motion_bodies: Vec<String>,
    anchor_body: Option<String>,
    body_errors: Vec<Vec<f64>>,
    /// The run played no clip (a command-driven policy).
    command_driven: bool,
    /// How the file ends.
    ending: Option<crate::recording::Ending>,
    /// `/replay` messages seen.
    replay_messages: usize,
    /// What its commands mean, and per `/policy` message whether the policy ran and the commands.
    command_kinds: Vec<controller::metrics::CommandKind>,
    running: Vec<bool>,
    commands: Vec<Vec<f64>>,
    /// When each safety transition happened, s (beside `safety`).
    safety_time: Vec<f64>,
    /// The buses' names and each tick's time per bus, µs.
    bus_names: Vec<String>,
    bus_us: Vec<Vec<f64>>,
    /// How the run was made, its files found from the recording's folder.
    run: Option<controller::options::RunMetadata>,
    /// Per `/policy` message: a generated reference's status, step and step latency (s).
    generated: Vec<Option<(String, u64, f64)>>,
    /// Per `/policy` message: the keypoint errors per view (view, mean, max px) and the
    /// triangulated error (mm).
    keypoint_errors: Vec<Vec<(String, f64, f64)>>,
    triangulated_mm: Vec<Option<f64>>,
}

fn floats(v: &serde_json::Value) -> Vec<f64> {
    v.as_array().map_or_else(Vec::new, |a| {
        a.iter().map(|x| x.as_f64().unwrap_or(f64::NAN)).collect()
    })
}

/// A typed message of `m`'s channel.
fn decode<M: prost::Message + Default>(m: &crate::recording::Message<'_>) -> Result<M, RecordingError> {
    M::decode(m.data).map_err(|e| RecordingError::decode(m.topic, e))
}

/// `[x, y, z]` of a message vector (NaN when absent).
fn xyz(v: Option<&pb::Vector3>) -> [f64; 3] {
    v.map_or([f64::NAN; 3], |v| [v.x, v.y, v.z])
}

/// `[x, y, z, w, qx, qy, qz]` of a message pose (NaN when absent).
fn pose7(p: Option<&pb::Pose>) -> [f64; 7] {
    let Some(p) = p else { return [f64::NAN; 7] };
    let [x, y, z] = xyz(p.position.as_ref());
    let q = p.orientation.unwrap_or_default();
    [x, y, z, q.w, q.x, q.y, q.z]
}

fn read(path: &Path) -> Result<Series, AnalysisError> {
    let unreadable = |e| AnalysisError::recording(path, e);
    let bytes = crate::recording::read(path).map_err(unreadable)?;
    let mut s = Series {
        tilt_limit: controller::safety::SafetyLimits::default().tilt,
        ..Series::default()
    };
    // Times from the run's start: a wall-clock recording's are Unix times.
    let mut t0: Option<u64> = None;
    let ending = crate::recording::for_each_message(&bytes, |m| {
        let zero = *t0.get_or_insert(m.log_time);
        let time = |log_time: u64| log_time.saturating_sub(zero) as f64 * 1e-9;
        match m.topic {
            "/joint_state" => {
                let v: pb::JointStates = decode(&m)?;
                if s.joints.is_empty() {
                    s.joints = v.joints.iter().map(|j| j.name.clone()).collect();
                }
                s.time.push(time(m.log_time));
                s.q.push(v.joints.iter().map(|j| j.position).collect());
                s.missed.push(v.joints.iter().any(|j| j.missed > 0));
            }
            "/command" => {
                let v: pb::JointCommands = decode(&m)?;
                s.reference_q.push(v.joints.iter().map(|j| j.reference).collect());
                s.reference_root.push(pose7(v.reference_root.as_ref()));
                s.tracking.push(v.tracking);
            }
            "/replay" => {
                let v: serde_json::Value =
                    serde_json::from_slice(m.data).map_err(|e| RecordingError::decode(m.topic, e))?;
                if s.base_pose.is_empty() {
                    let meta = &m.metadata;
                    s.reference_ticks = meta.get("reference_ticks").and_then(|n| n.parse().ok());
                    let run = meta
                        .get("run")
                        .and_then(|j| controller::options::RunMetadata::from_json(j).ok())
                        .map(|r| r.resolved_from(path.parent().unwrap_or(Path::new("."))));
                    s.tilt_limit = run.as_ref().map_or(s.tilt_limit, |r| r.options.limits.tilt);
                    s.command_driven = run
                        .as_ref()
                        .is_some_and(|r| r.clip.is_none() && r.generator.is_none());
                    s.run = run;
                }
                s.replay_messages += 1;
                let p = floats(&v["base_pose"]);
                s.base_pose
                    .push(std::array::from_fn(|i| p.get(i).copied().unwrap_or(f64::NAN)));
            }
            "/policy" => {
                let v: pb::PolicyStep = decode(&m)?;
                if s.motion_bodies.is_empty() {
                    s.motion_bodies = m
                        .metadata
                        .get("motion_bodies")
                        .map_or_else(Vec::new, |n| n.split(',').map(str::to_owned).collect());
                    s.anchor_body = m.metadata.get("anchor_body").cloned();
                    s.command_kinds = m.metadata.get("command_kinds").map_or_else(Vec::new, |k| {
                        k.split(',')
                            .map(|k| {
                                serde_json::from_value(serde_json::Value::String(k.to_owned()))
                                    .unwrap_or(controller::metrics::CommandKind::Other)
                            })
                            .collect()
                    });
                }
                s.body_errors
                    .push(v.body_errors.iter().map(|b| b.error_m).collect());
                // The policy drove the robot (running, or settling after a stop; recordings
                // made before `policy_ran` say running only).
                s.running.push(v.running || v.policy_ran);
                s.commands.push(v.commands.iter().map(|c| c.value).collect());
                s.generated.push(
                    v.generated
                        .as_ref()
                        .map(|g| (g.status.clone(), g.step, g.step_latency_s)),
                );
                s.keypoint_errors.push(
                    v.keypoint_errors
                        .iter()
                        .map(|e| (e.view.clone(), e.mean_px, e.max_px))
                        .collect(),
                );
                s.triangulated_mm.push(v.triangulated_mm);
            }
            "/estimator" => {
                let v: pb::StateEstimate = decode(&m)?;
                s.estimator_held += usize::from(v.held);
                let Some(truth) = v.truth_position.as_ref().filter(|_| v.valid) else {
                    return Ok(());
                };
                let distance = |a: [f64; 3], b: [f64; 3]| {
                    a.iter().zip(b).map(|(x, y)| (x - y).powi(2)).sum::<f64>().sqrt()
                };
                let (p, t) = (xyz(v.position.as_ref()), xyz(Some(truth)));
                let compared: Vec<(bool, bool)> = v
                    .feet
                    .iter()
                    .filter_map(|f| f.truth_contact.map(|t| (f.contact, t)))
                    .collect();
                // The run's own comparison (world axes) where the recording has it; base axes
                // in recordings made before it did.
                let velocity = match &v.truth_velocity {
                    Some(t) => distance(xyz(v.velocity.as_ref()), xyz(Some(t))),
                    None => distance(xyz(v.velocity_base.as_ref()), xyz(v.truth_velocity_base.as_ref())),
                };
                s.estimator.push(EstimateTick {
                    time: time(m.log_time),
                    velocity,
                    height: p[2] - t[2],
                    position: distance(p, t),
                    agree: compared.iter().filter(|(a, b)| a == b).count(),
                    compared: compared.len(),
                });
            }
            "/timing" => {
                let v: pb::TickTiming = decode(&m)?;
                s.io.push(f64::from(v.io_us));
                s.compute.push(f64::from(v.compute_us));
                if s.bus_names.is_empty() {
                    s.bus_names = v.buses.iter().map(|b| b.bus.clone()).collect();
                }
                s.bus_us.push(v.buses.iter().map(|b| f64::from(b.us)).collect());
            }
            "/safety" => {
                let v: pb::SafetyTransition = decode(&m)?;
                if v.fault && !s.faulted {
                    s.fault_cause = Some(v.cause.clone());
                }
                s.faulted |= v.fault;
                s.safety_time.push(time(m.log_time));
                s.safety.push((v.tick, v.mode, v.cause));
            }
            _ => {}
        }
        Ok(())
    })
    .map_err(unreadable)?;
    s.ending = Some(ending);
    if s.q.is_empty() {
        return Err(AnalysisError::file(path, "no /joint_state messages"));
    }
    Ok(s)
}

/// What the report says of a run whose robot was held throughout (a gantry, a harness never let go).
const HELD_THROUGHOUT: &str = "the robot was held the whole run (its feet never carried its weight): no ground to compare the estimate on";

/// The ticks held before the estimate could be compared, when there were any.
fn held_note(held: usize) -> String {
    if held > 0 {
        format!(" after {held} ticks held off the ground, not compared")
    } else {
        String::new()
    }
}

/// p50, p99 and max of per-tick times in µs, as the run's own summary computes them (the same
/// histogram: the run and its report print one number).
fn quantiles(v: &[f64]) -> [f64; 3] {
    if v.is_empty() {
        return [0.0; 3];
    }
    let mut h = controller::metrics::Histogram::default();
    for &us in v {
        h.record_us(us);
    }
    [
        h.quantile_us(0.5),
        h.quantile_us(0.99),
        h.max().as_secs_f64() * 1e6,
    ]
}

/// A command-driven run's measure over the ticks its policy ran, and per tick the commanded and
/// achieved forward speed and turning rate: (time, commanded, achieved).
#[allow(clippy::type_complexity)]
fn locomotion_course(
    s: &Series,
) -> (
    Option<controller::metrics::LocomotionSummary>,
    Vec<(f64, [f64; 2], [f64; 2])>,
) {
    let mut l = controller::metrics::LocomotionMetrics::new(&s.command_kinds);
    let [forward, _, turning] = l.slots();
    let mut course = Vec::new();
    // From the first tick: the run's own metrics take the pose of the first tick the policy ran
    // (a step needs the one before it, so the first gives none and its dt is not used).
    for k in 0..s.q.len() {
        let (Some(&pose), true) = (s.base_pose.get(k), s.running.get(k).copied().unwrap_or(false)) else {
            continue;
        };
        let dt = if k == 0 { 0.0 } else { s.time[k] - s.time[k - 1] };
        if (k > 0 && (dt.is_nan() || dt <= 0.0)) || pose[0].is_nan() {
            continue;
        }
        let commands = s.commands.get(k).map_or(&[][..], Vec::as_slice);
        if let Some(a) = l.add(pose, commands, dt) {
            let c = |slot: Option<usize>| slot.and_then(|i| commands.get(i).copied()).unwrap_or(f64::NAN);
            course.push((s.time[k], [c(forward), c(turning)], [a[0], a[2]]));
        }
    }
    (l.summary(), course)
}

/// A generated reference's figures: steps by their number, latency over the distinct steps.
fn generator_figures(s: &Series) -> Option<GeneratorFigures> {
    let ticks: Vec<&(String, u64, f64)> = s.generated.iter().flatten().collect();
    if ticks.is_empty() {
        return None;
    }
    let mut steps: BTreeMap<u64, f64> = BTreeMap::new();
    for (_, step, latency) in &ticks {
        if *step > 0 {
            steps.insert(*step, latency * 1e6);
        }
    }
    let latencies: Vec<f64> = steps.values().copied().collect();
    let count = |status: &str| ticks.iter().filter(|(s, _, _)| s == status).count();
    Some(GeneratorFigures {
        steps: steps.len() as u64,
        latency_us: quantiles(&latencies),
        fresh_ticks: count("fresh"),
        forecast_ticks: count("forecast"),
        standby_ticks: count("standby"),
    })
}

/// Each view's reprojection error over the ticks that measured it.
fn keypoint_figures(s: &Series) -> Vec<KeypointFigures> {
    let mut views: Vec<KeypointFigures> = Vec::new();
    for tick in &s.keypoint_errors {
        for (view, mean, max) in tick {
            let f = match views.iter_mut().find(|f| &f.view == view) {
                Some(f) => f,
                None => {
                    views.push(KeypointFigures {
                        view: view.clone(),
                        mean_px: 0.0,
                        max_px: 0.0,
                        ticks: 0,
                        failed_ticks: 0,
                    });
                    views.last_mut().expect("just pushed")
                }
            };
            f.mean_px += mean;
            f.max_px = f.max_px.max(*max);
            f.ticks += 1;
            f.failed_ticks += usize::from(*max > controller::keypoints::FAILURE_PX);
        }
    }
    for f in &mut views {
        f.mean_px /= f.ticks.max(1) as f64;
    }
    views
}

fn summarize(s: &Series) -> RunSummary {
    let n = s.joints.len().max(s.q.first().map_or(0, Vec::len));
    // The metrics' window: the ticks tracking the clip; for a command-driven run (no clip) the
    // ticks its policy ran, over which only the robot's own motion is measured.
    let window: Vec<usize> = (0..s.q.len())
        .filter(|&k| {
            if s.command_driven {
                s.running.get(k).copied().unwrap_or(false)
            } else {
                s.tracking.get(k).copied().unwrap_or(false)
            }
        })
        .collect();
    let reference_window: &[usize] = if s.command_driven { &[] } else { &window };
    let mut per_joint = vec![0.0; n];
    for &k in &window {
        for (j, sum) in per_joint.iter_mut().enumerate() {
            let reference = s
                .reference_q
                .get(k)
                .and_then(|r| r.get(j))
                .copied()
                .unwrap_or(f64::NAN);
            let e = s.q[k][j] - reference;
            *sum += e * e;
        }
    }
    let count = window.len().max(1) as f64;
    let joint_rmse_deg = s
        .joints
        .iter()
        .zip(&per_joint)
        .map(|(name, sq)| (name.clone(), (sq / count).sqrt().to_degrees()))
        .collect();
    let joints_rmse_deg = (per_joint.iter().sum::<f64>() / (count * n.max(1) as f64))
        .sqrt()
        .to_degrees();
    let has_truth = s.base_pose.iter().any(|p| !p[0].is_nan());
    let (mut pos_sq, mut ori_sq, mut root_max) = (0.0, 0.0, (0.0f64, 0.0f64));
    let mut episode_max = (0.0f64, 0.0f64);
    for &k in reference_window {
        let (Some(p), Some(r)) = (s.base_pose.get(k), s.reference_root.get(k)) else {
            continue;
        };
        let (d, a) = root_error(*p, *r);
        pos_sq += d * d;
        ori_sq += a * a;
        root_max = (root_max.0.max(d), root_max.1.max(a));
        let (h, g) = episode_error(*p, *r);
        episode_max = (episode_max.0.max(h), episode_max.1.max(g));
    }
    // Fell: the base tilted beyond the run's limit while in control (simulation truth).
    let fell = has_truth.then(|| fall_tick(s).is_some());
    // A command-driven run plays no reference.
    let played = s
        .reference_ticks
        .filter(|_| !s.command_driven)
        .map(|n| (window.len() as f64 / n.max(1) as f64).min(1.0));
    let recording_cut_at = match s.ending {
        Some(crate::recording::Ending::Cut { at }) => Some(at),
        _ => None,
    };
    let replay_recorded = s.replay_messages > 0;
    // A verdict needs the whole run in the file: what is not there is not a success.
    let known = recording_cut_at.is_none() && replay_recorded;
    let success = known
        && if s.command_driven {
            !fell.unwrap_or(false) && !s.faulted
        } else {
            tracking_success(
                fell.unwrap_or(false),
                s.faulted,
                played,
                has_truth.then_some(episode_max),
            )
        };
    // Jitter (the loop's own measure): third differences over runs of consecutive ticks.
    let (mut robot_jitter, mut reference_jitter) = (Jitter::new(n), Jitter::new(n));
    let mut previous: Option<usize> = None;
    for &k in &window {
        if previous.is_none_or(|p| p + 1 != k) {
            robot_jitter.restart();
            reference_jitter.restart();
        }
        let dt = previous.map_or(0.0, |p| s.time[k] - s.time[p]);
        previous = Some(k);
        robot_jitter.push(&s.q[k], dt);
        if let Some(r) = s.reference_q.get(k) {
            reference_jitter.push(r, dt);
        }
    }
    // Tracked bodies: their position errors over the window.
    let mut body_sq = vec![(0.0, 0usize); s.motion_bodies.len()];
    for &k in &window {
        for (sum, &e) in body_sq
            .iter_mut()
            .zip(s.body_errors.get(k).map_or(&[][..], Vec::as_slice))
        {
            if e.is_finite() {
                sum.0 += e * e;
                sum.1 += 1;
            }
        }
    }
    let body_rmse_cm: BTreeMap<String, f64> = s
        .motion_bodies
        .iter()
        .zip(&body_sq)
        .filter(|(_, (_, n))| *n > 0)
        .map(|(b, (sq, n))| (b.clone(), (sq / *n as f64).sqrt() * 100.0))
        .collect();
    let anchor_rmse_cm = s.anchor_body.as_ref().and_then(|a| body_rmse_cm.get(a).copied());
    let estimator = (!s.estimator.is_empty()).then(|| {
        let n = s.estimator.len() as f64;
        let rms = |f: &dyn Fn(&EstimateTick) -> f64| {
            (s.estimator.iter().map(|e| f(e).powi(2)).sum::<f64>() / n).sqrt()
        };
        let (agree, compared) = s
            .estimator
            .iter()
            .fold((0, 0), |(a, c), e| (a + e.agree, c + e.compared));
        EstimatorFigures {
            ticks: s.estimator.len(),
            velocity_rmse: rms(&|e| e.velocity),
            height_rmse_mm: 1000.0 * rms(&|e| e.height),
            final_position_error_cm: 100.0 * s.estimator.last().map_or(0.0, |e| e.position),
            contact_agreement_pct: if compared > 0 {
                100.0 * agree as f64 / compared as f64
            } else {
                100.0
            },
        }
    });
    // A command-driven run: the same measure the loop keeps, over the ticks the policy ran.
    let locomotion = (s.command_driven && has_truth)
        .then(|| locomotion_course(s).0)
        .flatten();
    RunSummary {
        locomotion,
        estimator,
        estimator_held_ticks: s.estimator_held,
        body_rmse_cm,
        anchor_rmse_cm,
        ticks: s.q.len(),
        tracking_ticks: window.len(),
        // Against a made-up reference (the default pose), joint errors mean nothing.
        joint_rmse_deg: if s.command_driven {
            BTreeMap::new()
        } else {
            joint_rmse_deg
        },
        joints_rmse_deg: if s.command_driven {
            f64::NAN
        } else {
            joints_rmse_deg
        },
        root_position_rmse_cm: (has_truth && !s.command_driven).then(|| (pos_sq / count).sqrt() * 100.0),
        root_orientation_rmse_deg: (has_truth && !s.command_driven)
            .then(|| (ori_sq / count).sqrt().to_degrees()),
        fell,
        safety_stop: s.faulted,
        played,
        success,
        recording_cut_at,
        replay_recorded,
        failures: Vec::new(),
        jitter: robot_jitter.mean().unwrap_or(0.0),
        reference_jitter: if s.command_driven {
            None
        } else {
            reference_jitter.mean()
        },
        generator: generator_figures(s),
        keypoints: keypoint_figures(s),
        triangulated_mm: {
            let mm: Vec<f64> = s.triangulated_mm.iter().flatten().copied().collect();
            (!mm.is_empty()).then(|| mm.iter().sum::<f64>() / mm.len() as f64)
        },
        bus_miss_ticks: s.missed.iter().filter(|&&m| m).count(),
        safety_events: s.safety.clone(),
        io_us: quantiles(&s.io),
        compute_us: quantiles(&s.compute),
    }
}

/// Writes the report of the run `log` into `dir`; returns the summary.
pub fn write_report(log: &Path, dir: &Path) -> Result<RunSummary, AnalysisError> {
    let s = read(log)?;
    let mut summary = summarize(&s);
    summary.failures = failures(&s, &summary);
    std::fs::create_dir_all(dir).map_err(|e| AnalysisError::write(dir, e))?;
    let json = serde_json::to_string_pretty(&summary)
        .map_err(|e| AnalysisError::write(&dir.join("summary.json"), std::io::Error::other(e)))?;
    let write =
        |name: &Path, text: &str| std::fs::write(name, text).map_err(|e| AnalysisError::write(name, e));
    write(&dir.join("summary.json"), &json)?;
    let mut md = format!("# Run report: {}\n\n", log.display());
    let _ = writeln!(md, "| metric | value |\n|---|---|");
    let _ = writeln!(
        md,
        "| ticks (tracking) | {} ({}) |",
        summary.ticks, summary.tracking_ticks
    );
    match &summary.locomotion {
        Some(l) => {
            let _ = writeln!(
                md,
                "| distance travelled / from the start | {:.2} m / {:.2} m |\n| heading turned | {:+.1}° |",
                l.distance_m,
                l.displacement_m,
                l.heading_change.to_degrees()
            );
            for (k, (name, unit)) in [("forward", "m/s"), ("leftward", "m/s"), ("turning", "rad/s")]
                .iter()
                .enumerate()
            {
                let commanded =
                    l.commanded[k].map_or("not commanded".to_owned(), |c| format!("{c:+.3} {unit}"));
                let _ = writeln!(
                    md,
                    "| {name}: commanded / achieved | {commanded} / {:+.3} {unit} |",
                    l.achieved[k]
                );
            }
        }
        None => {
            let _ = writeln!(md, "| joint RMSE | {:.2}° |", summary.joints_rmse_deg);
        }
    }
    if let (Some(p), Some(o)) = (summary.root_position_rmse_cm, summary.root_orientation_rmse_deg) {
        let _ = writeln!(
            md,
            "| root position RMSE | {p:.1} cm |\n| root orientation RMSE | {o:.1}° |"
        );
    }
    let yes = |b: bool| if b { "yes" } else { "NO" };
    if let Some(at) = summary.recording_cut_at {
        let _ = writeln!(
            md,
            "| recording | CUT at byte {at}: the run's end is not in the file |"
        );
    }
    if let Some(fell) = summary.fell {
        let _ = writeln!(md, "| fell | {} |", if fell { "YES" } else { "no" });
    }
    let _ = writeln!(
        md,
        "| safety stop | {} |",
        if summary.safety_stop { "YES" } else { "no" }
    );
    if summary.locomotion.is_some() {
        let _ = writeln!(
            md,
            "| success (no fall, no safety stop) | {} |",
            yes(summary.success)
        );
    } else {
        if let Some(p) = summary.played {
            let _ = writeln!(md, "| reference played | {:.0} % |", 100.0 * p);
        }
        let _ = writeln!(
            md,
            "| success (as tracking trainers end an episode: no fall, no safety stop, played to the end, root height within 0.25 m and gravity's vertical component within 0.8 of the reference's) | {} |",
            yes(summary.success)
        );
    }
    let _ = writeln!(md, "| jitter (mean \\|d³q/dt³\\|) | {} |", jitter_text(&summary));
    if let Some(g) = &summary.generator {
        let _ = writeln!(
            md,
            "| generator: steps, latency p50 / p99 | {}, {:.0} / {:.0} µs |",
            g.steps, g.latency_us[0], g.latency_us[1]
        );
        let _ = writeln!(
            md,
            "| generated reference: fresh / forecast / standby ticks | {} / {} / {} |",
            g.fresh_ticks, g.forecast_ticks, g.standby_ticks
        );
    }
    for k in &summary.keypoints {
        let _ = writeln!(
            md,
            "| keypoints {}: reprojection mean / max, ticks over 100 px | {:.1} / {:.1} px, {} of {} |",
            k.view, k.mean_px, k.max_px, k.failed_ticks, k.ticks
        );
    }
    if let Some(mm) = summary.triangulated_mm {
        let _ = writeln!(md, "| keypoints triangulated from the views | {mm:.1} mm |");
    }
    let _ = writeln!(md, "| ticks with bus misses | {} |", summary.bus_miss_ticks);
    let _ = writeln!(
        md,
        "| bus I/O p50 / p99 / max | {:.0} / {:.0} / {:.0} µs |",
        summary.io_us[0], summary.io_us[1], summary.io_us[2]
    );
    let _ = writeln!(
        md,
        "| compute p50 / p99 / max | {:.0} / {:.0} / {:.0} µs |",
        summary.compute_us[0], summary.compute_us[1], summary.compute_us[2]
    );
    if let Some(a) = summary.anchor_rmse_cm {
        let _ = writeln!(
            md,
            "| anchor ({}) position RMSE | {a:.1} cm |",
            s.anchor_body.as_deref().unwrap_or("?")
        );
    }
    if let Some(e) = &summary.estimator {
        let _ = writeln!(
            md,
            "| state estimate vs truth | velocity RMSE {:.3} m/s, height RMSE {:.1} mm, position error {:.1} cm at the end, contacts agree {:.1} % ({} ticks){} |",
            e.velocity_rmse,
            e.height_rmse_mm,
            e.final_position_error_cm,
            e.contact_agreement_pct,
            e.ticks,
            held_note(summary.estimator_held_ticks)
        );
    } else if summary.estimator_held_ticks > 0 {
        let _ = writeln!(md, "| state estimate vs truth | {HELD_THROUGHOUT} |");
    }
    let _ = writeln!(md, "\n## Safety events\n");
    for (tick, mode, cause) in &summary.safety_events {
        let _ = writeln!(md, "- tick {tick}: {mode} ({cause})");
    }
    if !summary.joint_rmse_deg.is_empty() {
        let _ = writeln!(md, "\n## Joint RMSE\n");
    }
    for (j, e) in &summary.joint_rmse_deg {
        let _ = writeln!(md, "- {j}: {e:.2}°");
    }
    if !summary.body_rmse_cm.is_empty() {
        let _ = writeln!(md, "\n## Tracked bodies: position RMSE\n");
        for (b, e) in &summary.body_rmse_cm {
            let _ = writeln!(md, "- {b}: {e:.1} cm");
        }
    }
    write(&dir.join("summary.md"), &md)?;

    let (html, plots) = page(log, &s, &summary).map_err(|m| AnalysisError::file(log, m))?;
    write(&dir.join("report.html"), &html)?;
    // Each plot also as its own SVG file, for documents that embed pictures.
    let plot_dir = dir.join("plots");
    std::fs::create_dir_all(&plot_dir).map_err(|e| AnalysisError::write(&plot_dir, e))?;
    for (name, svg) in &plots {
        write(&plot_dir.join(format!("{name}.svg")), svg)?;
    }
    Ok(summary)
}

/// HTML-escaped text.
fn escape(text: &str) -> String {
    text.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
}

/// The safety state machine's phases over the run.
fn phases(s: &Series) -> Vec<plot::Phase> {
    let end = s.time.last().copied().unwrap_or(0.0);
    s.safety
        .iter()
        .zip(&s.safety_time)
        .enumerate()
        .map(|(i, ((_, mode, _), &from))| plot::Phase {
            from,
            to: s.safety_time.get(i + 1).copied().unwrap_or(end).max(from),
            mode: mode.clone(),
        })
        .collect()
}

/// The first tick whose base tilted past the run's limit while the soft start, the policy or the
/// soft stop had the robot (simulation): the loop's own measure — a robot folding up under
/// damping after the run handed over has not fallen.
fn fall_tick(s: &Series) -> Option<usize> {
    s.base_pose.iter().enumerate().position(|(k, p)| {
        !p[0].is_nan()
            && in_control(s, k)
            && controller::safety::tilt_of([p[3], p[4], p[5], p[6]]) > s.tilt_limit
    })
}

/// Whether the soft start, the policy or the soft stop had the robot at tick `k` (the mode the
/// tick began in, from the safety transitions).
fn in_control(s: &Series, k: usize) -> bool {
    s.safety
        .iter()
        .take_while(|(tick, _, _)| (*tick as usize) < k)
        .last()
        .is_some_and(|(_, mode, _)| matches!(mode.as_str(), "SoftStart" | "Running" | "Stopping"))
}

/// The tracking tick with the largest mean joint error.
fn worst_tick(s: &Series) -> Option<usize> {
    let error = |k: usize| {
        let (q, r) = (&s.q[k], s.reference_q.get(k)?);
        let e: f64 = q.iter().zip(r).map(|(a, b)| (a - b).abs()).sum();
        Some(e / q.len().max(1) as f64)
    };
    (0..s.q.len())
        .filter(|&k| s.tracking.get(k).copied().unwrap_or(false))
        .filter_map(|k| error(k).map(|e| (k, e)))
        .max_by(|a, b| a.1.total_cmp(&b.1))
        .map(|(k, _)| k)
}

/// The run's jitter and, with a reference, the reference's.
fn jitter_text(summary: &RunSummary) -> String {
    match summary.reference_jitter {
        Some(r) => format!("robot {:.2}, reference {r:.2} rad/s³", summary.jitter),
        None => format!("robot {:.2} rad/s³", summary.jitter),
    }
}

/// Why a run failed, in words (empty when it succeeded).
fn failures(s: &Series, summary: &RunSummary) -> Vec<String> {
    let mut why = Vec::new();
    if let Some(at) = summary.recording_cut_at {
        let last = s.time.last().copied().unwrap_or(0.0);
        why.push(format!(
            "the recording is cut at byte {at} ({last:.2} s in; the run was killed or its disk filled): how it ended is unknown"
        ));
    }
    if !summary.replay_recorded {
        why.push("no /replay channel: whether the robot fell and how much it played are unknown".into());
    }
    if summary.fell == Some(true) {
        let at = fall_tick(s)
            .and_then(|k| s.time.get(k))
            .map_or(String::new(), |t| format!(" at {t:.2} s"));
        why.push(format!("fell{at}"));
    }
    if summary.safety_stop {
        // The fault that stopped the robot, not the hold that followed it.
        let cause = s.fault_cause.as_deref().unwrap_or("a fault");
        why.push(format!("safety stop: {cause}"));
    }
    if let Some(p) = summary.played.filter(|&p| p < 0.999) {
        why.push(format!("played {:.0} % of the reference", 100.0 * p));
    }
    if why.is_empty() && !summary.success {
        why.push(format!(
            "the root's height left the reference's by more than {EPISODE_HEIGHT_M} m or it tilted where the reference did not (gravity's vertical component off by more than {EPISODE_GRAVITY_Z})"
        ));
    }
    why
}

/// The report page and its plots (name, SVG).
fn page(log: &Path, s: &Series, summary: &RunSummary) -> Result<(String, Vec<(String, String)>), PlotError> {
    use plot::{BLUE, GREEN, Line, MEASURED, ORANGE, REFERENCE, TimePlot};
    let phases = phases(s);
    let mut plots: Vec<(String, String)> = Vec::new();
    let mut add = |name: &str, svg: String| -> String {
        plots.push((name.to_owned(), svg.clone()));
        svg
    };
    let series = |values: &dyn Fn(usize) -> f64| -> Vec<(f64, f64)> {
        s.time.iter().enumerate().map(|(k, &t)| (t, values(k))).collect()
    };
    let name = |p: &Option<std::path::PathBuf>| {
        p.as_ref()
            .and_then(|p| p.file_name())
            .map_or("?".to_owned(), |n| n.to_string_lossy().into_owned())
    };
    let mut html = String::from(concat!(
        "<!doctype html><html><head><meta charset=\"utf-8\"><title>robodeploy run report</title><style>",
        "body{font-family:'DejaVu Sans',sans-serif;max-width:1280px;margin:1em auto;color:#222}",
        ".verdict{padding:.8em 1.2em;border-radius:6px;font-size:1.4em;margin:.5em 0}",
        ".ok{background:#dff3df;border:1px solid #6b6}.bad{background:#f8dcdc;border:1px solid #c66}",
        ".grid{display:flex;flex-wrap:wrap;gap:4px}.grid svg{border:1px solid #ddd}",
        "figure{display:inline-block;margin:4px}figcaption{font-size:.85em;color:#555}",
        "table{border-collapse:collapse}td{padding:2px 10px;border-bottom:1px solid #eee}",
        ".key span{display:inline-block;padding:0 .5em;margin-right:.4em;border-radius:3px}",
        "</style></head><body>\n"
    ));
    let run = s.run.as_ref();
    let _ = writeln!(
        html,
        "<h1>Run report</h1><p>{} — robot <b>{}</b>, policy <b>{}</b>, {}</p>",
        escape(&log.display().to_string()),
        escape(&name(&run.map(|r| r.robot.clone()))),
        escape(&name(&run.map(|r| r.policy.clone()))),
        if s.command_driven {
            "driven by live commands".to_owned()
        } else if let Some(g) = run.and_then(|r| r.generator.clone()) {
            format!("motion generator <b>{}</b>", escape(&name(&Some(g))))
        } else {
            format!("clip <b>{}</b>", escape(&name(&run.and_then(|r| r.clip.clone()))))
        }
    );
    // The verdict: the reliability issue's success criterion, and why not.
    let why = failures(s, summary);
    // (A failure says how much played among its reasons.)
    let played = summary.played.map_or(String::new(), |p| {
        format!(" · played {:.0} % of the reference", 100.0 * p)
    });
    if summary.success {
        let _ = writeln!(html, "<div class=\"verdict ok\">✔ Success{played}</div>");
    } else {
        let _ = writeln!(
            html,
            "<div class=\"verdict bad\">✘ Failed: {}</div>",
            escape(&why.join("; "))
        );
    }
    let _ = write!(html, "<table>");
    let mut row = |k: &str, v: String| {
        let _ = write!(html, "<tr><td>{k}</td><td>{}</td></tr>", escape(&v));
    };
    row(
        "ticks (tracking)",
        format!("{} ({})", summary.ticks, summary.tracking_ticks),
    );
    if !s.command_driven {
        row("joint RMSE", format!("{:.2}°", summary.joints_rmse_deg));
    }
    if let (Some(p), Some(o)) = (summary.root_position_rmse_cm, summary.root_orientation_rmse_deg) {
        row("root RMSE", format!("{p:.1} cm, {o:.1}°"));
    }
    if let Some(fell) = summary.fell {
        row("fell", if fell { "YES".into() } else { "no".into() });
    }
    row(
        "safety stop",
        if summary.safety_stop {
            "YES".into()
        } else {
            "no".into()
        },
    );
    row("jitter (mean |d³q/dt³|)", jitter_text(summary));
    if let Some(g) = &summary.generator {
        row(
            "generator: steps, step latency p50 / p99 / max",
            format!(
                "{}, {:.0} / {:.0} / {:.0} µs",
                g.steps, g.latency_us[0], g.latency_us[1], g.latency_us[2]
            ),
        );
        row(
            "generated reference: fresh / forecast / standby ticks",
            format!("{} / {} / {}", g.fresh_ticks, g.forecast_ticks, g.standby_ticks),
        );
    }
    for k in &summary.keypoints {
        row(
            &format!("keypoints {}: reprojection mean / max", k.view),
            format!(
                "{:.1} / {:.1} px; {} of {} ticks over 100 px",
                k.mean_px, k.max_px, k.failed_ticks, k.ticks
            ),
        );
    }
    if let Some(mm) = summary.triangulated_mm {
        row("keypoints triangulated from the views", format!("{mm:.1} mm"));
    }
    row("ticks with bus misses", summary.bus_miss_ticks.to_string());
    row(
        "compute p50 / p99 / max",
        format!(
            "{:.0} / {:.0} / {:.0} µs",
            summary.compute_us[0], summary.compute_us[1], summary.compute_us[2]
        ),
    );
    row(
        "bus I/O p50 / p99 / max",
        format!(
            "{:.0} / {:.0} / {:.0} µs",
            summary.io_us[0], summary.io_us[1], summary.io_us[2]
        ),
    );
    if let Some(e) = &summary.estimator {
        row(
            "state estimate vs truth",
            format!(
                "velocity {:.3} m/s, height {:.1} mm RMSE; {:.1} cm off at the end; contacts agree {:.1} %{}",
                e.velocity_rmse,
                e.height_rmse_mm,
                e.final_position_error_cm,
                e.contact_agreement_pct,
                held_note(summary.estimator_held_ticks)
            ),
        );
    } else if summary.estimator_held_ticks > 0 {
        row("state estimate vs truth", HELD_THROUGHOUT.to_owned());
    }
    html.push_str("</table>\n");

    // The safety timeline, its key and events.
    html.push_str("<h2>Safety</h2><p class=\"key\">");
    for mode in ["Ready", "SoftStart", "Running", "Stopping", "Damped"] {
        if let Some(c) = plot::mode_color(mode) {
            let _ = write!(
                html,
                "<span style=\"background:rgb({},{},{})\">{mode}</span>",
                c.0, c.1, c.2
            );
        }
    }
    html.push_str("— the same shading lies behind every time plot below.</p>\n");
    html.push_str(&add("safety", plot::timeline(&phases, (1200, 90))?));
    html.push_str("<ul>");
    for ((tick, mode, cause), t) in s.safety.iter().zip(&s.safety_time) {
        let _ = write!(
            html,
            "<li>{t:.2} s (tick {tick}): {mode} — {}</li>",
            escape(cause)
        );
    }
    html.push_str("</ul>\n");

    // Pictures at the moments that matter (simulation runs: the base pose is known).
    let mut moments = Vec::new();
    let has_truth = s.base_pose.iter().any(|p| !p[0].is_nan());
    if has_truth && !s.q.is_empty() {
        // A recording cut short may hold fewer of one channel than another: every index is checked.
        let at = |k: usize| s.time.get(k).copied().unwrap_or(f64::NAN);
        // The moment the policy took the robot (the clip proper may begin later, after the
        // start-up ramp: the timeline above says when).
        let start = s.running.iter().position(|&t| t).unwrap_or(0);
        let mut pick = vec![(format!("the policy takes over, {:.2} s", at(start)), start)];
        if let Some(k) = worst_tick(s) {
            pick.push((format!("worst tracking, {:.2} s", at(k)), k));
        }
        match fall_tick(s) {
            Some(k) => pick.push((format!("fell, {:.2} s", at(k)), k)),
            None => {
                let k = s.q.len().min(s.base_pose.len()).saturating_sub(1);
                pick.push((format!("end, {:.2} s", at(k)), k));
            }
        }
        moments = pick
            .into_iter()
            .filter_map(|(caption, k)| {
                let (base, q) = (s.base_pose.get(k)?, s.q.get(k)?);
                (!base[0].is_nan()).then(|| frames::Moment {
                    caption,
                    base: *base,
                    q: q.clone(),
                })
            })
            .collect();
    }
    html.push_str("<h2>Moments</h2>\n");
    match (run, moments.is_empty()) {
        (_, true) => {
            html.push_str("<p>No pictures: the recording has no simulator pose (a hardware run).</p>\n");
        }
        (None, false) => html.push_str("<p>No pictures: the recording does not say which robot ran.</p>\n"),
        (Some(run), false) => match frames::render_moments(&run.robot, &moments) {
            Ok(pictures) => {
                use base64::Engine as _;
                for (caption, png) in pictures {
                    let data = base64::engine::general_purpose::STANDARD.encode(png);
                    let _ = writeln!(
                        html,
                        "<figure><img alt=\"{0}\" src=\"data:image/png;base64,{data}\"><figcaption>{0}</figcaption></figure>",
                        escape(&caption)
                    );
                }
            }
            Err(e) => {
                let _ = writeln!(html, "<p>No pictures: {}</p>", escape(&e.to_string()));
            }
        },
    }

    // Every joint, small multiples: reference, measured, limits.
    let limits: Vec<Option<[f64; 2]>> = match run.map(|r| robots::Robot::load(&r.robot)) {
        Some(Ok(robot)) => s
            .joints
            .iter()
            .map(|n| {
                robot
                    .config
                    .joints
                    .iter()
                    .find(|j| &j.name == n)
                    .map(|j| j.position_limits)
            })
            .collect(),
        _ => vec![None; s.joints.len()],
    };
    let _ = writeln!(
        html,
        "<h2>Joint tracking</h2><p class=\"key\"><span style=\"color:#787878\">━ {}</span><span style=\"color:#cd2d2d\">━ measured</span><span style=\"color:#c81e1e\">╌ position limits</span></p><div class=\"grid\">",
        if s.command_driven {
            "default pose"
        } else {
            "reference"
        }
    );
    for (j, joint) in s.joints.iter().enumerate() {
        let svg = plot::time_plot(
            &TimePlot {
                title: joint,
                y_desc: "rad",
                lines: vec![
                    Line {
                        label: "reference",
                        color: REFERENCE,
                        points: series(&|k| {
                            s.reference_q
                                .get(k)
                                .and_then(|r| r.get(j))
                                .copied()
                                .unwrap_or(f64::NAN)
                        }),
                    },
                    Line {
                        label: "measured",
                        color: MEASURED,
                        points: series(&|k| s.q[k].get(j).copied().unwrap_or(f64::NAN)),
                    },
                ],
                limits: limits
                    .get(j)
                    .copied()
                    .flatten()
                    .map_or_else(Vec::new, |l| l.to_vec()),
                size: (310, 190),
                legend: false,
            },
            &phases,
        )?;
        html.push_str(&add(&format!("joint-{joint}"), svg));
    }
    html.push_str("</div>\n");

    if s.command_driven {
        let (_, course) = locomotion_course(s);
        html.push_str("<h2>Commanded against achieved</h2>\n");
        for (k, (title, unit)) in [("forward speed", "speed (m/s)"), ("turning rate", "rate (rad/s)")]
            .iter()
            .enumerate()
        {
            let svg = plot::time_plot(
                &TimePlot {
                    title,
                    y_desc: unit,
                    lines: vec![
                        Line {
                            label: "commanded",
                            color: REFERENCE,
                            points: course.iter().map(|(t, c, _)| (*t, c[k])).collect(),
                        },
                        Line {
                            label: "achieved",
                            color: MEASURED,
                            points: course.iter().map(|(t, _, a)| (*t, a[k])).collect(),
                        },
                    ],
                    limits: Vec::new(),
                    size: (620, 260),
                    legend: true,
                },
                &phases,
            )?;
            html.push_str(&add(&format!("command-{k}"), svg));
        }
    }
    if summary.root_position_rmse_cm.is_some() {
        // Over the tracking window: before it the reference is the start-up ramp, not the clip.
        let error = |k: usize| {
            let tracking = s.tracking.get(k).copied().unwrap_or(false);
            s.base_pose
                .get(k)
                .zip(s.reference_root.get(k))
                .filter(|_| tracking)
                .map_or((f64::NAN, f64::NAN), |(p, r)| root_error(*p, *r))
        };
        // The success bounds drawn when the error comes near them; they would flatten a small one.
        let bound = |limit: f64, values: &[(f64, f64)]| {
            let worst = values
                .iter()
                .map(|v| v.1)
                .filter(|v| v.is_finite())
                .fold(0.0, f64::max);
            if worst > 0.2 * limit {
                vec![limit]
            } else {
                Vec::new()
            }
        };
        let position = series(&|k| 100.0 * error(k).0);
        let orientation = series(&|k| error(k).1.to_degrees());
        let (position_bound, orientation_bound) = (bound(100.0, &position), bound(45.0, &orientation));
        html.push_str("<h2>Root against the reference</h2>\n");
        let svg = plot::time_plot(
            &TimePlot {
                title: "root position error",
                y_desc: "cm",
                lines: vec![Line {
                    label: "position",
                    color: BLUE,
                    points: position,
                }],
                limits: position_bound,
                size: (620, 260),
                legend: true,
            },
            &phases,
        )?;
        html.push_str(&add("root-position-error", svg));
        let svg = plot::time_plot(
            &TimePlot {
                title: "root orientation error",
                y_desc: "deg",
                lines: vec![Line {
                    label: "orientation",
                    color: ORANGE,
                    points: orientation,
                }],
                limits: orientation_bound,
                size: (620, 260),
                legend: true,
            },
            &phases,
        )?;
        html.push_str(&add("root-orientation-error", svg));
        html.push_str("<p>Over the tracking window. ReActor's bounds (1 m, 45°; drift over the floor included, so not the verdict) are drawn dashed once the error comes within a fifth of them.</p>\n");
    }
    if !summary.body_rmse_cm.is_empty() {
        let anchor = s
            .anchor_body
            .as_ref()
            .and_then(|a| s.motion_bodies.iter().position(|b| b == a));
        let per_tick = |f: &dyn Fn(&[f64]) -> f64| -> Vec<(f64, f64)> {
            s.time
                .iter()
                .zip(&s.body_errors)
                .map(|(&t, e)| (t, if e.is_empty() { f64::NAN } else { 100.0 * f(e) }))
                .collect()
        };
        let mut lines = vec![
            Line {
                label: "mean",
                color: BLUE,
                points: per_tick(&|e| e.iter().sum::<f64>() / e.len() as f64),
            },
            Line {
                label: "worst",
                color: MEASURED,
                points: per_tick(&|e| e.iter().copied().fold(0.0, f64::max)),
            },
        ];
        if let Some(a) = anchor {
            lines.push(Line {
                label: "anchor",
                color: GREEN,
                points: per_tick(&|e| e.get(a).copied().unwrap_or(f64::NAN)),
            });
        }
        let svg = plot::time_plot(
            &TimePlot {
                title: "tracked bodies: position error",
                y_desc: "cm",
                lines,
                limits: Vec::new(),
                size: (620, 260),
                legend: true,
            },
            &phases,
        )?;
        html.push_str(&add("bodies", svg));
    }
    if !summary.keypoints.is_empty() {
        html.push_str("<h2>2D keypoints</h2>\n");
        let labels: Vec<(String, String)> = summary
            .keypoints
            .iter()
            .map(|k| (format!("{} mean", k.view), format!("{} max", k.view)))
            .collect();
        let colours = [(BLUE, MEASURED), (GREEN, ORANGE)];
        let mut lines = Vec::new();
        for (v, (k, (mean_label, max_label))) in summary.keypoints.iter().zip(&labels).enumerate() {
            let per_tick = |pick: &dyn Fn(&(String, f64, f64)) -> f64| -> Vec<(f64, f64)> {
                s.time
                    .iter()
                    .zip(&s.keypoint_errors)
                    .map(|(&t, e)| (t, e.iter().find(|e| e.0 == k.view).map_or(f64::NAN, pick)))
                    .collect()
            };
            let (mean_colour, max_colour) = colours[v % colours.len()];
            lines.push(Line {
                label: mean_label,
                color: mean_colour,
                points: per_tick(&|e| e.1),
            });
            lines.push(Line {
                label: max_label,
                color: max_colour,
                points: per_tick(&|e| e.2),
            });
        }
        let worst = summary.keypoints.iter().map(|k| k.max_px).fold(0.0, f64::max);
        let svg = plot::time_plot(
            &TimePlot {
                title: "the robot's keypoints against the 2D references: reprojection error",
                y_desc: "px",
                lines,
                // The paper's failure criterion, once the error comes near it.
                limits: if worst > 0.2 * controller::keypoints::FAILURE_PX {
                    vec![controller::keypoints::FAILURE_PX]
                } else {
                    Vec::new()
                },
                size: (620, 260),
                legend: true,
            },
            &phases,
        )?;
        html.push_str(&add("keypoints", svg));
        html.push_str("<p>Each tick tracking the reference: the robot's keypoints (robot.toml [keypoints], forward kinematics of the measured joints placed by the simulator's truth) projected through each camera, against that view's references. A tick fails at 100 px (dashed once the error comes within a fifth of it).</p>\n");
    }
    if summary.estimator.is_some() {
        html.push_str("<h2>State estimate against the simulator's truth</h2>\n");
        let points =
            |f: &dyn Fn(&EstimateTick) -> f64| s.estimator.iter().map(|e| (e.time, f(e))).collect::<Vec<_>>();
        let svg = plot::time_plot(
            &TimePlot {
                title: "estimate error",
                y_desc: "m/s · cm",
                lines: vec![
                    Line {
                        label: "velocity (m/s)",
                        color: MEASURED,
                        points: points(&|e| e.velocity),
                    },
                    Line {
                        label: "height (cm)",
                        color: BLUE,
                        points: points(&|e| 100.0 * e.height.abs()),
                    },
                    Line {
                        label: "position (cm)",
                        color: GREEN,
                        points: points(&|e| 100.0 * e.position),
                    },
                ],
                limits: Vec::new(),
                size: (620, 260),
                legend: true,
            },
            &phases,
        )?;
        html.push_str(&add("estimator", svg));
    }
    html.push_str("<h2>Timing</h2>\n");
    let svg = plot::time_plot(
        &TimePlot {
            title: "compute per tick",
            y_desc: "µs",
            lines: vec![Line {
                label: "compute",
                color: ORANGE,
                points: series(&|k| s.compute.get(k).copied().unwrap_or(f64::NAN)),
            }],
            limits: Vec::new(),
            size: (620, 260),
            legend: true,
        },
        &phases,
    )?;
    html.push_str(&add("timing-compute", svg));
    let colors = [BLUE, GREEN, MEASURED, ORANGE, REFERENCE];
    // Each bus's own cycle (its round trips on the wire), not the loop's bus I/O of the table:
    // the legend gives each bus's mean, so lines that lie on one another still read apart.
    let bus_labels: Vec<String> = s
        .bus_names
        .iter()
        .enumerate()
        .map(|(b, bus)| {
            let times: Vec<f64> = s
                .bus_us
                .iter()
                .filter_map(|v| v.get(b).copied())
                .filter(|t| t.is_finite())
                .collect();
            let mean = times.iter().sum::<f64>() / times.len().max(1) as f64;
            format!("{bus} (mean {:.2} ms)", mean / 1e3)
        })
        .collect();
    let bus_lines: Vec<Line<'_>> = bus_labels
        .iter()
        .enumerate()
        .map(|(b, label)| Line {
            label,
            color: colors[b % colors.len()],
            points: series(&|k| {
                s.bus_us
                    .get(k)
                    .and_then(|v| v.get(b))
                    .copied()
                    .unwrap_or(f64::NAN)
            }),
        })
        .collect();
    let svg = plot::time_plot(
        &TimePlot {
            title: "bus cycle time, each bus (round trips on the wire)",
            y_desc: "µs",
            lines: bus_lines,
            limits: Vec::new(),
            size: (620, 260),
            legend: true,
        },
        &phases,
    )?;
    html.push_str(&add("timing-buses", svg));
    html.push_str("</body></html>\n");
    Ok((html, plots))
}
