//! Soak: a long stretch of simulated time on the mirror in lockstep (on its gantry), episode after
//! episode, with random clips, random run lengths and random device faults (every kind, random
//! joints and the IMU, random times). It checks what must hold whatever happens: every command inside the
//! joint's position, speed and torque limits; every fault reaching the safe state within its
//! bound; no record lost from a lockstep recording.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::AtomicBool;
use std::time::Duration;

use controller::clip::{Clip, Reference};
use controller::options::{EndMode, PlayOptions};
use controller::safety::Mode;
use controller::sim::lockstep_player;
use controller::telemetry::{Backpressure, RecordingInfo, TelemetrySink};
use firmware_bridge::time::SimRng;
use policy::PolicyLayout;
use robots::Robot;
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
    /// Clips to draw from.
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
    /// Episodes without a fault that ended in a safety stop anyway.
    pub unexplained_stops: Vec<String>,
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
        writeln!(f, "  pushes: {}", self.pushes)?;
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

/// Runs the soak.
pub fn soak(spec: &SoakSpec<'_>, progress: &dyn Fn(f64)) -> Result<SoakReport, AnalysisError> {
    let robot = spec.robot;
    let layout = PolicyLayout::load(spec.policy, robot)?;
    let mut references = Vec::with_capacity(spec.clips.len());
    for c in spec.clips {
        references.push(Reference::from_clip(
            &Clip::load(c)?,
            robot,
            layout.manifest.rate_hz,
        )?);
    }
    let joints: Vec<String> = robot.config.joints.iter().map(|j| j.name.clone()).collect();
    let dt = 1.0 / layout.manifest.rate_hz;
    let mut rng = SimRng::new(spec.seed);
    // Pushes draw from their own stream, so a seed's faults are the same with or without them.
    let mut push_rng = SimRng::new(spec.seed ^ 0x5055_5348);
    let mut report = SoakReport::default();
    std::fs::create_dir_all(spec.scratch).map_err(|e| AnalysisError::write(spec.scratch, e))?;
    while report.simulated_s < spec.seconds {
        let episode = report.episodes;
        report.episodes += 1;
        let ticks = 200 + (rng.next_f64() * 600.0) as u64;
        let clip = ((rng.next_f64() * references.len() as f64) as usize).min(references.len() - 1);
        let fault = (rng.next_f64() < 0.8).then(|| draw_fault(&mut rng, &joints, ticks, dt));
        let pushes = draw_pushes(&mut push_rng, ticks, dt);
        report.pushes += pushes.len();
        // On the gantry: the reference follower has no balance of its own (a trained policy
        // would), and what is tested here is the path from a device fault to the safe state.
        let mirror = MirrorConfig {
            seed: rng.next_u64(),
            gantry: true,
            faults: fault.iter().map(|(f, _)| f.clone()).collect(),
            pushes,
            ..MirrorConfig::default()
        };
        let options = PlayOptions {
            end: EndMode::Loop,
            max_ticks: Some(ticks),
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
        let path = spec.scratch.join(format!("episode-{episode}.mcap"));
        let info = RecordingInfo {
            joint_names: joints.clone(),
            root_frame: robot.config.root_body.clone(),
            ..RecordingInfo::default()
        };
        let sink = TelemetrySink::start(&path, 256, Backpressure::Block, &info)
            .map_err(controller::player::PlayError::from)?;
        let mut p = p.with_telemetry(sink);
        p.identify()?;
        // The policy rate is checked to [1, 1000] Hz when the manifest loads.
        let period = Duration::from_nanos((dt * 1e9).round() as u64);
        let mut previous: Vec<Option<f64>> = vec![None; joints.len()];
        while p.mode() != Mode::Off {
            p.step(&clock)?;
            let moving = matches!(p.mode(), Mode::Running | Mode::Stopping);
            for (k, (t, j)) in p.targets().iter().zip(&robot.config.joints).enumerate() {
                if !t.enabled {
                    previous[k] = None;
                    continue;
                }
                let [lo, hi] = j.position_limits;
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
                            "episode {episode}, tick {}: {}: {why}",
                            p.ticks(),
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
        match (&fault, stop) {
            (Some((f, kind)), stop) => {
                // The tick whose window holds the fault's time: its bus exchange may already
                // see the fault (a reply due a few ms into the tick), so reactions count from it.
                let at = (f.at_s / dt).floor() as u64;
                let figures = report.faults.entry(kind.clone()).or_default();
                figures.injected += 1;
                match stop {
                    Some((tick, _)) if tick >= at && tick - at <= REACTION_BOUND_TICKS => {
                        figures.stopped_in_bound += 1;
                        figures.worst_ticks = figures.worst_ticks.max(tick - at);
                    }
                    Some((tick, cause)) => report.late.push(format!(
                        "episode {episode}: {kind} at tick {at}: stopped at tick {tick} ({cause})"
                    )),
                    None => report
                        .late
                        .push(format!("episode {episode}: {kind} at tick {at}: never stopped")),
                }
            }
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
