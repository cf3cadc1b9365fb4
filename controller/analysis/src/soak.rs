//! Soak: a long stretch of simulated time on the mirror in lockstep, episode after episode, with
//! random references, run lengths, shoves and device faults (every kind, random joints and the IMU,
//! random times). A robot that starts on its joints' PD tracks random clips on its gantry (the
//! reference follower has no balance); a robot that starts in a harness is lowered to the floor
//! under its policy, walks on random commands (a command-driven policy) or plays the motion its
//! export carries, and is stopped by the operator the robot.toml's ways (damp, stay, sit, back into
//! the harness). It checks what must hold whatever happens: every command inside the joint's
//! position, speed and torque limits; every fault reaching the safe state within its bound; no
//! stop without a cause (a fall counts as caused only after a shove); no record lost from a
//! lockstep recording.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::AtomicBool;
use std::time::Duration;

use controller::clip::Reference;
use controller::options::{EndMode, OnStop, PlayOptions};
use controller::reference::{ReferenceSource, load_reference};
use controller::safety::{Cause, Mode};
use controller::sim::lockstep_player;
use controller::telemetry::{Backpressure, RecordingInfo, TelemetrySink};
use firmware_bridge::time::SimRng;
use policy::PolicyLayout;
use robots::{Robot, StartMode};
use sim2real::config::{FaultKind, MirrorConfig, Push, ScheduledFault};

use crate::AnalysisError;

/// Ticks from a fault's injection to the loop's stop that every fault must meet: the staleness
/// limit (2 ticks) plus one tick to see the reading and one for the transition.
pub const REACTION_BOUND_TICKS: u64 = 6;

/// What a soak runs.
#[derive(Debug, Clone)]
pub struct SoakSpec<'a> {
    /// The robot.
    pub robot: &'a Robot,
    /// The policy manifest.
    pub policy: &'a Path,
    /// Clips to draw from. None: the policy's own reference (its commands, or the motion its
    /// export carries), else every clip beside the robot.
    pub clips: &'a [PathBuf],
    /// Simulated time to cover, s.
    pub seconds: f64,
    /// Seed of every draw.
    pub seed: u64,
    /// Folder for the episodes' recordings (each checked for lost records, then removed).
    pub scratch: &'a Path,
}

/// One kind of fault's figures.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct FaultFigures {
    /// Injected.
    pub injected: usize,
    /// Reached the safe state within [`REACTION_BOUND_TICKS`].
    pub stopped_in_bound: usize,
    /// Slowest reaction, ticks.
    pub worst_ticks: u64,
}

/// What a soak found.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct SoakReport {
    /// Episodes run.
    pub episodes: usize,
    /// Ticks run.
    pub ticks: u64,
    /// Simulated time covered, s.
    pub simulated_s: f64,
    /// Per fault kind (and target: `joint` or `imu`).
    pub faults: BTreeMap<String, FaultFigures>,
    /// Shoves on the root (30–150 N for 0.05–0.3 s, any horizontal direction).
    pub pushes: usize,
    /// Episodes that ended in a safety stop no injected fault or shove explains.
    pub unexplained_stops: Vec<String>,
    /// Episodes in which the robot fell (a tilt stop) after a shove: a defined end, counted.
    pub falls_after_push: usize,
    /// Operator stops per way of stopping (`damp`, `stay`, `sit`, `harness`).
    pub operator_stops: BTreeMap<&'static str, usize>,
    /// Faults injected once the robot was already damped (nothing left to stop).
    pub faults_after_damping: usize,
    /// Faults that did not reach the safe state in bound (episode, kind, reaction).
    pub late: Vec<String>,
    /// Commands outside a joint's limits (must be 0).
    pub commands_outside_limits: u64,
    /// The first few of them, described.
    pub violations: Vec<String>,
    /// Records the lockstep recordings lost (must be 0).
    pub records_lost: u64,
}

impl SoakReport {
    /// Whether everything that must hold held.
    pub fn passed(&self) -> bool {
        self.late.is_empty()
            && self.commands_outside_limits == 0
            && self.records_lost == 0
            && self.unexplained_stops.is_empty()
    }
}

impl std::fmt::Display for SoakReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(
            f,
            "soak: {} episodes, {} ticks, {:.0} s simulated",
            self.episodes, self.ticks, self.simulated_s
        )?;
        writeln!(
            f,
            "  {:<28} {:>8} {:>15} {:>12}",
            "fault", "injected", "safe in bound", "worst ticks"
        )?;
        for (kind, x) in &self.faults {
            writeln!(
                f,
                "  {kind:<28} {:>8} {:>15} {:>12}",
                x.injected, x.stopped_in_bound, x.worst_ticks
            )?;
        }
        writeln!(
            f,
            "  pushes: {} ({} ended in a fall)",
            self.pushes, self.falls_after_push
        )?;
        if !self.operator_stops.is_empty() {
            let ways: Vec<String> = self
                .operator_stops
                .iter()
                .map(|(way, n)| format!("{way} {n}"))
                .collect();
            writeln!(f, "  operator stops: {}", ways.join(", "))?;
        }
        if self.faults_after_damping > 0 {
            writeln!(
                f,
                "  faults injected after the robot was damped: {}",
                self.faults_after_damping
            )?;
        }
        writeln!(f, "  commands outside limits: {}", self.commands_outside_limits)?;
        writeln!(f, "  records lost: {}", self.records_lost)?;
        for v in self
            .violations
            .iter()
            .chain(&self.late)
            .chain(&self.unexplained_stops)
        {
            writeln!(f, "  ! {v}")?;
        }
        write!(f, "  {}", if self.passed() { "PASSED" } else { "FAILED" })
    }
}

/// None, one or two random shoves for an episode that runs `ticks` ticks at `dt`.
fn draw_pushes(rng: &mut SimRng, ticks: u64, dt: f64) -> Vec<Push> {
    let n = usize::from(rng.next_f64() < 0.5) + usize::from(rng.next_f64() < 0.2);
    let last = (ticks as f64 * dt - 1.0).max(2.6);
    (0..n)
        .map(|_| {
            let at_s = 2.5 + rng.next_f64() * (last - 2.5);
            let duration_s = 0.05 + rng.next_f64() * 0.25;
            let angle = rng.next_f64() * std::f64::consts::TAU;
            let newtons = 30.0 + rng.next_f64() * 120.0;
            Push {
                at_s,
                duration_s,
                force_n: [newtons * angle.cos(), newtons * angle.sin(), 0.0],
            }
        })
        .collect()
}

/// A random fault for an episode that runs `ticks` ticks at `dt`, on one of `joints` or the IMU.
fn draw_fault(rng: &mut SimRng, joints: &[String], ticks: u64, dt: f64) -> (ScheduledFault, String) {
    let imu = rng.next_f64() < 0.15;
    let kinds = if imu { 4 } else { 5 };
    let pick = (rng.next_f64() * f64::from(kinds)) as u32;
    let count = |lo: f64, hi: f64, rng: &mut SimRng| (lo + rng.next_f64() * (hi - lo)) as u32;
    // Counts long enough to outlast the staleness limits (a joint answers once a tick, the IMU
    // four times): shorter losses are tolerated by design, not faults.
    let fault = match (pick, imu) {
        (0, _) => FaultKind::Silent { count: None },
        (1, false) => FaultKind::Silent {
            count: Some(count(5.0, 50.0, rng)),
        },
        (1, true) => FaultKind::Silent {
            count: Some(count(20.0, 200.0, rng)),
        },
        (2, false) => FaultKind::CorruptCrc {
            count: count(5.0, 50.0, rng),
        },
        (2, true) => FaultKind::CorruptCrc {
            count: count(20.0, 200.0, rng),
        },
        (3, _) => FaultKind::Vanish,
        _ => FaultKind::Overheat,
    };
    let target = if imu {
        "imu".to_owned()
    } else {
        joints[((rng.next_f64() * joints.len() as f64) as usize).min(joints.len() - 1)].clone()
    };
    // After the soft start and ramp (2.5 s), at least a second before the end.
    let last = (ticks as f64 * dt - 1.0).max(2.6);
    let at_s = 2.5 + rng.next_f64() * (last - 2.5);
    let kind = format!(
        "{} on {}",
        match fault {
            FaultKind::Silent { count: None } => "silent",
            FaultKind::Silent { .. } => "silent for a while",
            FaultKind::CorruptCrc { .. } => "corrupt replies",
            FaultKind::Overheat => "overheat",
            FaultKind::Vanish => "vanish",
        },
        if imu { "the IMU" } else { "a joint" }
    );
    (
        ScheduledFault {
            at_s,
            joint: target,
            fault,
        },
        kind,
    )
}

/// The references a soak draws from: the clips given; none given, the policy's own (its commands,
/// the motion its export carries), else every clip beside the robot.
fn soak_references(
    spec: &SoakSpec<'_>,
    layout: &mut PolicyLayout,
) -> Result<(Vec<Reference>, bool), AnalysisError> {
    let robot = spec.robot;
    let mut references = Vec::with_capacity(spec.clips.len().max(1));
    if !spec.clips.is_empty() {
        for c in spec.clips {
            references.push(load_reference(Some(c), c, layout, robot, 0)?.0);
        }
        return Ok((references, false));
    }
    let beside = robot.path.with_file_name("clips");
    let mut clips: Vec<PathBuf> = std::fs::read_dir(&beside)
        .map(|d| {
            d.filter_map(|e| e.ok().map(|e| e.path()))
                .filter(|p| p.extension().is_some_and(|x| x == "csv"))
                .collect()
        })
        .unwrap_or_default();
    clips.sort();
    let (first, source) = match load_reference(None, clips.first().unwrap_or(&beside), layout, robot, 0) {
        Err(_) if clips.is_empty() => {
            return Err(AnalysisError::Mismatch(format!(
                "no clips to soak with: {} tracks a reference, and {} holds no CSV clip (give --clips)",
                spec.policy.display(),
                beside.display()
            )));
        }
        other => other?,
    };
    let commands = matches!(source, ReferenceSource::Commands);
    if !matches!(source, ReferenceSource::Clip(_)) {
        return Ok((vec![first], commands));
    }
    for c in &clips {
        references.push(load_reference(Some(c), c, layout, robot, 0)?.0);
    }
    Ok((references, false))
}

/// Random targets within `share` of each command's range.
fn draw_commands(rng: &mut SimRng, ranges: &[[f64; 2]], share: f64, out: &mut [f64]) {
    for (o, [lo, hi]) in out.iter_mut().zip(ranges) {
        *o = share * (lo + rng.next_f64() * (hi - lo));
    }
}

/// The ways an operator may stop this robot.
fn stop_ways(robot: &Robot) -> Vec<OnStop> {
    let mut ways = vec![OnStop::Damp, OnStop::Stay];
    if robot.config.sit_keyframe.is_some() {
        ways.push(OnStop::Sit);
    }
    if robot.config.start.mode == StartMode::Harness {
        ways.push(OnStop::Harness);
    }
    ways
}

fn way_name(way: OnStop) -> &'static str {
    match way {
        OnStop::Damp => "damp",
        OnStop::Stay => "stay",
        OnStop::Sit => "sit",
        OnStop::Harness => "harness",
    }
}

/// Runs the soak.
pub fn soak(spec: &SoakSpec<'_>, progress: &dyn Fn(f64)) -> Result<SoakReport, AnalysisError> {
    let robot = spec.robot;
    let mut layout = PolicyLayout::load(spec.policy, robot)?;
    let (references, command_driven) = soak_references(spec, &mut layout)?;
    let joints: Vec<String> = robot.config.joints.iter().map(|j| j.name.clone()).collect();
    let dt = 1.0 / layout.manifest.rate_hz;
    // A robot that starts on its PD tracks on its gantry: the reference follower has no balance of
    // its own, and what is tested there is the path from a device fault to the safe state. A
    // harness start is the policy's from the rope to the floor and back: no gantry.
    let harness = robot.config.start.mode == StartMode::Harness;
    let settle_ticks = if harness {
        let h = robot.config.start.harness;
        ((h.lower_s + h.settle_s) / dt).ceil() as u64
    } else {
        0
    };
    let ways = stop_ways(robot);
    let rule = robot.config.safety.position_targets;
    let ranges: Vec<[f64; 2]> = layout
        .manifest
        .commands
        .as_ref()
        .map(|c| c.ranges.clone())
        .unwrap_or_default();
    let mut rng = SimRng::new(spec.seed);
    // Pushes draw from their own stream, so a seed's faults are the same with or without them.
    let mut push_rng = SimRng::new(spec.seed ^ 0x5055_5348);
    let mut report = SoakReport::default();
    std::fs::create_dir_all(spec.scratch).map_err(|e| AnalysisError::write(spec.scratch, e))?;
    let mut targets = vec![0.0; ranges.len()];
    while report.simulated_s < spec.seconds {
        let episode = report.episodes;
        report.episodes += 1;
        let ticks = settle_ticks + 200 + (rng.next_f64() * 600.0) as u64;
        let clip = ((rng.next_f64() * references.len() as f64) as usize).min(references.len() - 1);
        let fault = (rng.next_f64() < 0.8).then(|| draw_fault(&mut rng, &joints, ticks, dt));
        let pushes = draw_pushes(&mut push_rng, ticks, dt);
        report.pushes += pushes.len();
        let first_push_tick = pushes.iter().map(|p| (p.at_s / dt).floor() as u64).min();
        let mirror = MirrorConfig {
            seed: rng.next_u64(),
            gantry: !harness,
            faults: fault.iter().map(|(f, _)| f.clone()).collect(),
            pushes,
            ..MirrorConfig::default()
        };
        let way = if harness {
            ways[((rng.next_f64() * ways.len() as f64) as usize).min(ways.len() - 1)]
        } else {
            OnStop::Damp
        };
        let options = PlayOptions {
            end: if harness { EndMode::Stand } else { EndMode::Loop },
            max_ticks: Some(ticks),
            on_stop: way,
            stand_s: (way == OnStop::Stay).then(|| 0.5 + 2.5 * rng.next_f64()),
            ..PlayOptions::default()
        };
        let stop = Arc::new(AtomicBool::new(false));
        let (p, mut clock, _world) = lockstep_player(
            robot.clone(),
            layout.clone(),
            references[clip].clone(),
            options,
            mirror,
            stop,
        )?;
        let mut writer = None;
        let p = if command_driven {
            let (w, reader) = human::commands::command_channel(ranges.len());
            writer = Some(w);
            p.with_commands(reader)?
        } else {
            p
        };
        let path = spec.scratch.join(format!("episode-{episode}.mcap"));
        let info = RecordingInfo {
            joint_names: joints.clone(),
            root_frame: robot.config.root_body.clone(),
            observation_len: layout.obs_len,
            ..RecordingInfo::default()
        };
        let sink = TelemetrySink::start(&path, 256, Backpressure::Block, &info)
            .map_err(controller::player::PlayError::from)?;
        let mut p = p.with_telemetry(sink);
        p.identify()?;
        // The policy rate is checked to [1, 1000] Hz when the manifest loads.
        let period = Duration::from_nanos((dt * 1e9).round() as u64);
        let mut previous: Vec<Option<f64>> = vec![None; joints.len()];
        let fault_tick = fault.as_ref().map(|(f, _)| (f.at_s / dt).floor() as u64);
        let mut mode_at_fault = None;
        let mut next_command = settle_ticks;
        while p.mode() != Mode::Off {
            if let Some(w) = &mut writer
                && p.ticks() >= next_command
            {
                // A new walk every 1–3 s, within 60 % of the manifest's ranges (the ramps of
                // the manifest take it there).
                draw_commands(&mut rng, &ranges, 0.6, &mut targets);
                w.publish_lasting(&targets);
                next_command = p.ticks() + ((1.0 + 2.0 * rng.next_f64()) / dt) as u64;
            }
            if Some(p.ticks()) == fault_tick {
                mode_at_fault = Some(p.mode());
            }
            p.step(&clock)?;
            let moving = matches!(p.mode(), Mode::Running | Mode::Stopping);
            for (k, (t, j)) in p.targets().iter().zip(&robot.config.joints).enumerate() {
                if !t.enabled {
                    previous[k] = None;
                    continue;
                }
                // The robot's own rule for where targets may lie (inside the limits, or past
                // them as far as the torque limit reaches at this stiffness), without the margin.
                let [lo, hi] = controller::safety::target_range(j, 0.0, rule, t.kp);
                let speed = previous[k].map_or(0.0, |q| (t.q - q).abs() / dt);
                let bad = if !(t.q.is_finite() && t.kp.is_finite() && t.kd.is_finite() && t.tau.is_finite()) {
                    Some("not finite".to_owned())
                } else if !(lo - 1e-9..=hi + 1e-9).contains(&t.q) {
                    Some(format!("q {:.4} outside [{lo}, {hi}]", t.q))
                } else if moving && speed > j.velocity_limit * (1.0 + 1e-6) + 1e-9 {
                    Some(format!(
                        "target speed {speed:.3} rad/s beyond {}",
                        j.velocity_limit
                    ))
                } else if t.tau.abs() > j.torque_limit * (1.0 + 1e-9) {
                    Some(format!("torque {:.3} beyond {}", t.tau, j.torque_limit))
                } else {
                    None
                };
                if let Some(why) = bad {
                    report.commands_outside_limits += 1;
                    if report.violations.len() < 10 {
                        report.violations.push(format!(
                            "episode {episode}, tick {} ({:?}, kp {:.1}): {}: {why}",
                            p.ticks(),
                            p.mode(),
                            t.kp,
                            j.name
                        ));
                    }
                }
                previous[k] = Some(t.q);
            }
            p.wait_until(&mut clock, period * p.ticks() as u32);
        }
        report.ticks += p.ticks();
        report.simulated_s += p.ticks() as f64 * dt;
        let stop = p
            .transitions()
            .iter()
            .find(|t| t.cause.is_fault())
            .map(|t| (t.tick, t.cause));
        let operator_stopped = p
            .transitions()
            .iter()
            .any(|t| t.from == Mode::Running && !t.cause.is_fault());
        if harness && operator_stopped {
            *report.operator_stops.entry(way_name(way)).or_default() += 1;
        }
        // A tilt after a shove is the robot falling over: the stop it must make, explained.
        let pushed_over = |tick: u64, cause: Cause| {
            matches!(cause, Cause::Tilt { .. }) && first_push_tick.is_some_and(|at| at <= tick)
        };
        match (&fault, stop) {
            (Some((f, kind)), stop) => {
                // The tick whose window holds the fault's time: its bus exchange may already
                // see the fault (a reply due a few ms into the tick), so reactions count from it.
                let at = (f.at_s / dt).floor() as u64;
                match stop {
                    Some((tick, cause)) if tick < at => {
                        if pushed_over(tick, cause) {
                            report.falls_after_push += 1;
                        } else {
                            report.unexplained_stops.push(format!(
                                "episode {episode}: stopped at tick {tick} ({cause}), before the {kind} at tick {at}"
                            ));
                        }
                    }
                    _ if matches!(mode_at_fault, Some(Mode::Damped | Mode::Off) | None) => {
                        // Damped before the fault came (an operator's stop): nothing to stop.
                        report.faults_after_damping += 1;
                    }
                    Some((tick, _)) if tick >= at && tick - at <= REACTION_BOUND_TICKS => {
                        let figures = report.faults.entry(kind.clone()).or_default();
                        figures.injected += 1;
                        figures.stopped_in_bound += 1;
                        figures.worst_ticks = figures.worst_ticks.max(tick - at);
                    }
                    Some((tick, cause)) => {
                        report.faults.entry(kind.clone()).or_default().injected += 1;
                        report.late.push(format!(
                            "episode {episode}: {kind} at tick {at}: stopped at tick {tick} ({cause})"
                        ));
                    }
                    None => {
                        report.faults.entry(kind.clone()).or_default().injected += 1;
                        report
                            .late
                            .push(format!("episode {episode}: {kind} at tick {at}: never stopped"));
                    }
                }
            }
            (None, Some((tick, cause))) if pushed_over(tick, cause) => report.falls_after_push += 1,
            (None, Some((tick, cause))) => report.unexplained_stops.push(format!(
                "episode {episode}: no fault, stopped at tick {tick} ({cause})"
            )),
            (None, None) => {}
        }
        if let Some(Ok(t)) = p.finish_telemetry() {
            report.records_lost += t.dropped + t.pushed.saturating_sub(t.written);
        } else {
            report.records_lost += 1;
        }
        let _ = std::fs::remove_file(&path);
        progress((report.simulated_s / spec.seconds).min(1.0));
    }
    Ok(report)
}
