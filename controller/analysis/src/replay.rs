//! Replay: a recorded run's inputs (every bus reading, the IMU, the simulator's ground truth, stop
//! requests) fed through the same controller code, tick by tick, with every command it sends
//! compared bit for bit against the recording. The run's files and options come from the
//! recording's `/replay` channel metadata.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::time::Duration;

use robots::Robot;

use controller::options::RunMetadata;

use crate::AnalysisError;
use crate::recording::RecordingError;
use controller::player::Player;
use policy::PolicyLayout;
use robot_link::GroundTruth;
use robot_link::TickClock;
use robot_link::{IoError, JointTarget, RobotLink, RobotState};

/// One recorded tick: what the loop read, and what it sent.
#[derive(Debug, Clone, PartialEq)]
pub struct RecordedTick {
    /// Run time, ns.
    pub time_ns: u64,
    /// The state the buses and IMU delivered.
    pub state: RobotState,
    /// Simulator ground truth, when there was one.
    pub truth: Option<GroundTruth>,
    /// Whether a stop had been requested.
    pub stop: bool,
    /// The targets sent.
    pub targets: Vec<JointTarget>,
    /// The live commands in force (command-driven policies; empty without).
    pub commands: Vec<f64>,
}

/// A recording read back.
#[derive(Debug, Clone, PartialEq)]
pub struct Recording {
    /// How to rebuild the run: file paths and options.
    pub run: BTreeMap<String, String>,
    /// The ticks, in order.
    pub ticks: Vec<RecordedTick>,
}

fn numbers(v: &serde_json::Value, key: &str) -> Result<Vec<f64>, RecordingError> {
    let bad = |reason: String| RecordingError::decode("/replay", reason);
    v[key]
        .as_array()
        .ok_or_else(|| bad(format!("message without {key:?}")))?
        .iter()
        .map(|x| {
            if x.is_null() {
                Ok(f64::NAN)
            } else {
                x.as_f64()
                    .ok_or_else(|| bad(format!("{key}: {x} is not a number")))
            }
        })
        .collect()
}

/// Reads the `/replay` channel of an MCAP file written by `play`.
pub fn read_recording(path: &Path) -> Result<Recording, AnalysisError> {
    let bytes = crate::recording::read(path).map_err(|e| AnalysisError::recording(path, e))?;
    let mut run = BTreeMap::new();
    let mut ticks = Vec::new();
    crate::recording::for_each_message(&bytes, |m| {
        if m.topic != "/replay" {
            return Ok(());
        }
        if run.is_empty() {
            run = m.metadata.clone();
        }
        let v: serde_json::Value =
            serde_json::from_slice(m.data).map_err(|e| RecordingError::decode("/replay", e))?;
        let (q, qd, tau) = (numbers(&v, "q")?, numbers(&v, "qd")?, numbers(&v, "tau")?);
        let n = q.len();
        let mut state = RobotState::new(n);
        state.q = q;
        state.qd = qd;
        state.tau = tau;
        state.missed = numbers(&v, "missed")?.iter().map(|&m| m as u32).collect();
        state.faulted = numbers(&v, "faulted")?.iter().map(|&f| f != 0.0).collect();
        // Recordings from before multi-rate buses have neither: nothing stale, age unknown (0).
        if v.get("stale").is_some() {
            state.stale = numbers(&v, "stale")?.iter().map(|&f| f != 0.0).collect();
            state.age = numbers(&v, "age_ms")?
                .iter()
                .map(|&ms| Duration::try_from_secs_f64(ms / 1e3).unwrap_or_default())
                .collect();
        }
        let imu = numbers(&v, "imu")?;
        for (key, want) in [
            ("qd", n),
            ("tau", n),
            ("missed", n),
            ("faulted", n),
            ("target", 5 * n),
            ("enabled", n),
        ] {
            let got = numbers(&v, key)?.len();
            if got != want {
                return Err(RecordingError::decode(
                    "/replay",
                    format!("tick {}: {key} has {got} values for {n} joints", v["tick"]),
                ));
            }
        }
        for (key, got) in [("stale", state.stale.len()), ("age_ms", state.age.len())] {
            if got != n {
                return Err(RecordingError::decode(
                    "/replay",
                    format!("tick {}: {key} has {got} values for {n} joints", v["tick"]),
                ));
            }
        }
        if imu.len() != 10 {
            return Err(RecordingError::decode(
                "/replay",
                format!("imu has {} values", imu.len()),
            ));
        }
        state.gyro = [imu[0], imu[1], imu[2]];
        state.accel = [imu[3], imu[4], imu[5]];
        state.quat = [imu[6], imu[7], imu[8], imu[9]];
        state.imu_missed = v["imu_missed"].as_u64().unwrap_or(0) as u32;
        // The IMU samples the tick integrated (recordings before the estimator have none).
        let samples = if v.get("imu_samples").is_some() {
            numbers(&v, "imu_samples")?
        } else {
            Vec::new()
        };
        if samples.len() % 11 != 0 || samples.len() / 11 > robot_link::IMU_HISTORY {
            return Err(RecordingError::decode(
                "/replay",
                format!(
                    "tick {}: imu_samples has {} values (11 per sample, at most {})",
                    v["tick"],
                    samples.len(),
                    robot_link::IMU_HISTORY
                ),
            ));
        }
        state.imu_samples = samples
            .chunks_exact(11)
            .map(|s| robot_link::ImuSample {
                at: Duration::try_from_secs_f64(s[0]).unwrap_or_default(),
                gyro: [s[1], s[2], s[3]],
                accel: [s[4], s[5], s[6]],
                quat: [s[7], s[8], s[9], s[10]],
            })
            .collect();
        let pose = numbers(&v, "base_pose")?;
        let lin = numbers(&v, "base_lin_vel")?;
        if pose.len() != 7 || lin.len() != 3 {
            return Err(RecordingError::decode(
                "/replay",
                format!(
                    "tick {}: base_pose has {} values (7), base_lin_vel {} (3)",
                    v["tick"],
                    pose.len(),
                    lin.len()
                ),
            ));
        }
        let truth = (!pose[0].is_nan()).then(|| -> Result<GroundTruth, RecordingError> {
            Ok(GroundTruth {
                root_pose: std::array::from_fn(|i| pose[i]),
                base_lin_vel: [lin[0], lin[1], lin[2]],
                foot_contacts: numbers(&v, "feet")?.iter().map(|&f| f != 0.0).collect(),
                simulation_failed: v["simulation_failed"].as_bool().unwrap_or(false),
                mirror_behind: Duration::from_micros(v["mirror_behind_us"].as_u64().unwrap_or(0)),
            })
        });
        let t = numbers(&v, "target")?;
        let enabled = numbers(&v, "enabled")?;
        let targets = (0..n)
            .map(|i| JointTarget {
                q: t[5 * i],
                qd: t[5 * i + 1],
                kp: t[5 * i + 2],
                kd: t[5 * i + 3],
                tau: t[5 * i + 4],
                enabled: enabled[i] != 0.0,
            })
            .collect();
        ticks.push(RecordedTick {
            // The run's own time (a wall-clock recording's log times are Unix times).
            time_ns: v["time_ns"].as_u64().unwrap_or(m.log_time),
            state,
            truth: truth.transpose()?,
            stop: v["stop"].as_bool().unwrap_or(false),
            targets,
            commands: if v.get("commands").is_some() {
                numbers(&v, "commands")?
            } else {
                Vec::new()
            },
        });
        Ok(())
    })
    .map_err(|e| AnalysisError::recording(path, e))?;
    if ticks.is_empty() {
        return Err(AnalysisError::file(
            path,
            "no /replay messages (record with robodeploy play)",
        ));
    }
    Ok(Recording { run, ticks })
}

/// The first place a replayed command differs from the recording.
#[derive(Debug, Clone, PartialEq)]
pub struct Difference {
    /// Tick.
    pub tick: usize,
    /// Robot joint index.
    pub joint: usize,
    /// Which command field.
    pub field: &'static str,
    /// What the replay sent.
    pub replayed: f64,
    /// What the recording says was sent.
    pub recorded: f64,
}

/// Feeds recorded readings to the loop and checks what it writes.
#[derive(Debug)]
pub struct ReplayLink {
    ticks: Arc<Vec<RecordedTick>>,
    reads: Arc<AtomicUsize>,
    writes: usize,
    skip_count: bool,
    first_difference: Option<Difference>,
}

impl RobotLink for ReplayLink {
    fn identify(&mut self) -> Result<(), IoError> {
        // The read that follows identification is not a tick's read.
        self.skip_count = true;
        Ok(())
    }

    fn read(&mut self, state: &mut RobotState) -> Result<(), IoError> {
        let k = self.reads.load(Ordering::Relaxed);
        let tick = self
            .ticks
            .get(k)
            .ok_or_else(|| IoError::Setup(format!("the recording ends at tick {k}")))?;
        state.clone_from(&tick.state);
        if self.skip_count {
            self.skip_count = false;
        } else {
            self.reads.fetch_add(1, Ordering::Relaxed);
        }
        Ok(())
    }

    fn write(&mut self, targets: &[JointTarget]) -> Result<(), IoError> {
        let k = self.writes;
        self.writes += 1;
        let Some(recorded) = self.ticks.get(k) else {
            return Ok(());
        };
        if self.first_difference.is_some() {
            return Ok(());
        }
        for (j, (a, b)) in targets.iter().zip(&recorded.targets).enumerate() {
            let fields = [
                ("q", a.q, b.q),
                ("qd", a.qd, b.qd),
                ("kp", a.kp, b.kp),
                ("kd", a.kd, b.kd),
                ("tau", a.tau, b.tau),
            ];
            let enabled = (
                "enabled",
                f64::from(u8::from(a.enabled)),
                f64::from(u8::from(b.enabled)),
            );
            if let Some(&(field, replayed, rec)) = fields
                .iter()
                .chain(std::iter::once(&enabled))
                .find(|(_, x, y)| x.to_bits() != y.to_bits())
            {
                self.first_difference = Some(Difference {
                    tick: k,
                    joint: j,
                    field,
                    replayed,
                    recorded: rec,
                });
                break;
            }
        }
        Ok(())
    }

    fn torque_off(&mut self) -> Result<(), IoError> {
        Ok(())
    }
}

/// The recording's clock and ground truth.
#[derive(Debug)]
struct ReplayClock {
    ticks: Arc<Vec<RecordedTick>>,
    reads: Arc<AtomicUsize>,
}

impl TickClock for ReplayClock {
    fn elapsed(&self) -> Duration {
        let k = self.reads.load(Ordering::Relaxed).saturating_sub(1);
        Duration::from_nanos(self.ticks.get(k).map_or(0, |t| t.time_ns))
    }

    fn wait_until(&mut self, _deadline: Duration) -> bool {
        false
    }

    fn ground_truth(&self, truth: &mut GroundTruth) -> bool {
        // Called after the tick's read: the tick is the one just read.
        let k = self.reads.load(Ordering::Relaxed).saturating_sub(1);
        match self.ticks.get(k).and_then(|t| t.truth.as_ref()) {
            Some(t) => {
                truth.clone_from(t);
                true
            }
            None => false,
        }
    }
}

/// What a replay found.
#[derive(Debug, Clone, PartialEq)]
pub struct ReplayReport {
    /// The recording.
    pub path: PathBuf,
    /// Ticks replayed.
    pub ticks: usize,
    /// The first command that differs, if any.
    pub first_difference: Option<Difference>,
    /// Joint names, robot order (for messages).
    pub joints: Vec<String>,
}

impl std::fmt::Display for ReplayReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match &self.first_difference {
            None => write!(
                f,
                "replayed {} ticks of {}: every command matches the recording bit for bit",
                self.ticks,
                self.path.display()
            ),
            Some(d) => write!(
                f,
                "replayed {} ticks of {}: first difference at tick {}, joint {} ({}) {}: replayed {:?}, recorded {:?}",
                self.ticks,
                self.path.display(),
                d.tick,
                d.joint,
                self.joints.get(d.joint).map_or("?", String::as_str),
                d.field,
                d.replayed,
                d.recorded
            ),
        }
    }
}

/// Replays `path` through the controller.
pub fn replay(path: &Path) -> Result<ReplayReport, AnalysisError> {
    let rec = read_recording(path)?;
    let run = rec
        .run
        .get("run")
        .ok_or_else(|| AnalysisError::file(path, "the recording does not say how it was run"))
        .and_then(|json| {
            RunMetadata::from_json(json).map_err(|e| AnalysisError::file(path, format!("run metadata: {e}")))
        })?
        .resolved_from(path.parent().unwrap_or(Path::new(".")));
    let robot = Robot::load(&run.robot).map_err(|e| AnalysisError::file(&run.robot, e.to_string()))?;
    let mut layout = PolicyLayout::load(&run.policy, &robot)?;
    if let Some(values) = &run.command {
        layout.set_command(values)?;
    }
    // The clip the run played, the motion its export carries (the recording names the export),
    // or none for a command-driven policy.
    if let Some(g) = &run.generator {
        return Err(AnalysisError::file(
            path,
            format!(
                "the run tracked the motion generator {}: its reference came from the worker's plans as they arrived, which the recorded inputs do not determine; a replay cannot reproduce it",
                g.display()
            ),
        ));
    }
    let (mut reference, _) = controller::reference::load_reference(
        run.clip.as_deref(),
        run.clip.as_deref().unwrap_or(&run.policy),
        &mut layout,
        &robot,
        run.options.start_step,
    )?;
    // The 2D keypoint references the run had beside its clip.
    if let Some(k) = &run.keypoints {
        let (cameras, clip) = k.load().map_err(|e| AnalysisError::file(&e.path, e.message))?;
        reference.keypoints = Some(
            controller::keypoints::track::KeypointReference::new(
                &clip,
                &cameras,
                layout.manifest.rate_hz,
                reference.len(),
            )
            .map_err(|e| AnalysisError::file(&k.keypoints, e.to_string()))?,
        );
    }
    let options = run.options;
    options
        .check()
        .map_err(|(field, m)| AnalysisError::file(path, format!("recorded run options: {field}: {m}")))?;
    let joints = robot.config.joints.iter().map(|j| j.name.clone()).collect();
    let ticks = Arc::new(rec.ticks);
    let reads = Arc::new(AtomicUsize::new(0));
    let link = ReplayLink {
        ticks: Arc::clone(&ticks),
        reads: Arc::clone(&reads),
        writes: 0,
        skip_count: false,
        first_difference: None,
    };
    let stop = Arc::new(AtomicBool::new(false));
    let mut player = Player::new(robot, layout, reference, options, link, Arc::clone(&stop))?;
    let clock = ReplayClock {
        ticks: Arc::clone(&ticks),
        reads,
    };
    player.identify()?;
    for t in ticks.iter() {
        stop.store(t.stop, Ordering::Relaxed);
        // Live commands as the run had them.
        if !t.commands.is_empty() {
            player.set_commands(&t.commands);
        }
        player.step(&clock)?;
    }
    Ok(ReplayReport {
        path: path.to_path_buf(),
        ticks: ticks.len(),
        first_difference: player.link().first_difference.clone(),
        joints,
    })
}
