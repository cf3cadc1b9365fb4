//! How a run goes ([`PlayOptions`]) and what it was run from ([`RunMetadata`]): one serde
//! struct each, recorded with the run and read back by a replay.

use std::path::PathBuf;

use crate::safety::SafetyLimits;

/// What happens when the clip ends.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum EndMode {
    /// Hold the last frame for a moment, then stop.
    #[default]
    Hold,
    /// Blend back to the default pose, then stop.
    Blend,
    /// Start the clip again (until stopped).
    Loop,
    /// Blend to the default pose and stand there under the policy until the operator stops.
    Stand,
}

/// What the robot does once the run is asked to stop softly (Ctrl-C, `--max-seconds`, the
/// clip's end). A soft stop first settles the robot under the policy — a tracking policy's
/// reference holds the frame the stop came at and blends to the standing pose, a command-driven
/// policy's commands ramp to rest — over `settle_s`; then this. Faults always damp at once.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum OnStop {
    /// Damp and let go (a robot on a stand, an arm; a humanoid folds up).
    #[default]
    Damp,
    /// Stay standing under the policy until the operator stops again (a second Ctrl-C) or
    /// `stand_s` has passed; then damp.
    #[serde(alias = "stand")]
    Stay,
    /// Blend slowly into robot.toml's `sit_keyframe` on the joints' PD (a controlled sit-down),
    /// then damp.
    Sit,
    /// The harness the run started in takes the robot's weight, then damp (the mirror's rope
    /// catches it; on the robot the operator has the crane take it).
    Harness,
}

/// How a run goes. Recorded with every run (as part of [`RunMetadata`]) and read back by replays.
/// Where a harness start is: the rope lowering the robot, the operator's word awaited (on
/// hardware, or when a run asks for it), the robot settling on its feet on the motion's first
/// frame, then free — the motion plays. Recorded on `/log` as each begins.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum HarnessPhase {
    /// Not a harness start.
    #[default]
    None,
    /// The harness lowers the robot (the policy in control, the commands at rest).
    Lowering,
    /// Hanging or standing until the operator says the robot is on its feet.
    WaitingForOperator,
    /// On its feet, settling on the motion's first frame.
    Settling,
    /// The harness slack, the motion playing.
    Free,
}

impl std::fmt::Display for HarnessPhase {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Self::None => "none",
            Self::Lowering => "lowering the robot onto its feet",
            Self::WaitingForOperator => {
                "waiting for the operator's word that the robot is on its feet (LOWERED)"
            }
            Self::Settling => "on its feet, settling on the motion's first frame",
            Self::Free => "free: the motion plays",
        })
    }
}

#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PlayOptions {
    /// How the policy takes the robot: `pd` (the soft start below first), `policy` (from the first
    /// tick), `harness` (from the first tick, lowered by a harness). None: robot.toml's `[start]`
    /// (mode, PD ramp and harness all taken from there).
    #[serde(default)]
    pub start: Option<robots::StartMode>,
    /// Soft start (`pd`): time to reach the default pose, s.
    pub soft_start_s: f64,
    /// Soft start gain factor.
    pub soft_start_gain: f64,
    /// ψ ramp with the clip held at its first frame, s (0–60). None: the policy's own
    /// (`[reference] hold_s`, else 1.5 s for a policy that observes ψ and 0 for any other).
    #[serde(default)]
    pub ramp_s: Option<f64>,
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
    /// The frame of a motion-carrying export the run starts from.
    #[serde(default)]
    pub start_step: usize,
    /// Where the terms that need the robot's place in the world (base velocity and height,
    /// foot contacts, anchor position) come from.
    #[serde(default)]
    pub estimator: EstimatorKind,
    /// What a soft stop ends in.
    #[serde(default)]
    pub on_stop: OnStop,
    /// With [`OnStop::Stay`]: stand at most this long, s (none: until stopped again).
    #[serde(default)]
    pub stand_s: Option<f64>,
    /// With [`OnStop::Sit`]: the sit-down's length, s.
    #[serde(default = "default_sit_s")]
    pub sit_s: f64,
    /// A soft stop's settling under the policy (reference to the standing pose, commands to
    /// rest), s.
    #[serde(default = "default_settle_s")]
    pub settle_s: f64,
}

fn default_settle_s() -> f64 {
    1.0
}

fn default_sit_s() -> f64 {
    3.0
}

impl PlayOptions {
    /// The options with the start resolved against `robot`: a run that names no start takes
    /// robot.toml's `[start]` whole (mode and PD ramp).
    pub fn resolved_for(mut self, robot: &robots::Robot) -> Self {
        if self.start.is_none() {
            let s = robot.config.start;
            self.start = Some(s.mode);
            self.soft_start_s = s.pd_s;
            self.soft_start_gain = s.pd_gain;
        }
        self
    }

    /// Each option within the range `play` takes it in (the flags' own ranges; the rest from
    /// robot.toml's): options read back from a recording are checked as the flags are. The
    /// error names the option.
    pub fn check(&self) -> Result<(), (String, String)> {
        let l = &self.limits;
        for (name, value, lo, hi) in [
            ("soft_start_s", self.soft_start_s, 0.0, 60.0),
            ("soft_start_gain", self.soft_start_gain, 0.0, 1.0),
            ("ramp_s", self.ramp_s.unwrap_or(0.0), 0.0, 60.0),
            ("end_s", self.end_s, 0.0, 60.0),
            ("damping_s", self.damping_s, 0.0, 60.0),
            ("sit_s", self.sit_s, 0.1, 60.0),
            ("settle_s", self.settle_s, 0.02, 30.0),
            ("stand_s", self.stand_s.unwrap_or(0.0), 0.0, 86_400.0),
            ("limits.tilt", l.tilt, 0.0, std::f64::consts::PI),
            ("limits.position_margin", l.position_margin, 0.0, 0.2),
            ("limits.tracking_error", l.tracking_error, 0.0, 100.0),
        ] {
            if !(value.is_finite() && (lo..=hi).contains(&value)) {
                return Err((
                    name.to_owned(),
                    format!(
                        "{} is outside [{}, {}]",
                        robots::num(value),
                        robots::num(lo),
                        robots::num(hi)
                    ),
                ));
            }
        }
        for (name, value, lo, hi) in [
            ("limits.stale_cycles", l.stale_cycles, 1, 100),
            ("limits.overruns", l.overruns, 1, 1_000_000),
            ("limits.tracking_ticks", l.tracking_ticks, 1, 1_000_000),
        ] {
            if !(lo..=hi).contains(&value) {
                return Err((name.to_owned(), format!("{value} is outside [{lo}, {hi}]")));
            }
        }
        Ok(())
    }

    /// The start mode (robot.toml's when the run names none).
    pub fn start_mode(&self, robot: &robots::Robot) -> robots::StartMode {
        self.start.unwrap_or(robot.config.start.mode)
    }
}

/// The source of the robot's place in the world.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum EstimatorKind {
    /// The state estimator on the measured data (what hardware runs), the filter robot.toml's
    /// `[estimator] filter` names.
    #[default]
    Kf,
    /// The same with the invariant EKF, whatever robot.toml says.
    Invariant,
    /// The same with the linear Kalman filter, whatever robot.toml says.
    Linear,
    /// The simulation's ground truth (the mirror only).
    GroundTruth,
}

impl EstimatorKind {
    /// The estimator's settings: robot.toml's, with the filter this run asks for.
    pub fn config(self, robot: &robots::EstimatorConfig) -> robots::EstimatorConfig {
        let filter = match self {
            Self::Invariant => robots::FilterKind::Invariant,
            Self::Linear => robots::FilterKind::Linear,
            Self::Kf | Self::GroundTruth => robot.filter,
        };
        robots::EstimatorConfig { filter, ..*robot }
    }
}

impl Default for PlayOptions {
    fn default() -> Self {
        Self {
            start: None,
            soft_start_s: 1.0,
            soft_start_gain: 0.3,
            ramp_s: None,
            end: EndMode::Hold,
            end_s: 0.5,
            damping_s: 0.5,
            limits: SafetyLimits::default(),
            max_ticks: None,
            start_step: 0,
            estimator: EstimatorKind::Kf,
            on_stop: OnStop::Damp,
            stand_s: None,
            sit_s: default_sit_s(),
            settle_s: default_settle_s(),
        }
    }
}

/// What a run was made from: the files, the command values and the options. A recording carries
/// it as JSON, so a replay rebuilds exactly the same run.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RunMetadata {
    /// The robot description (robot.toml).
    pub robot: PathBuf,
    /// The policy manifest.
    pub policy: PathBuf,
    /// The clip (none: a command-driven policy ran on its commands).
    #[serde(default)]
    pub clip: Option<PathBuf>,
    /// Command values given on the command line, if any.
    #[serde(default)]
    pub command: Option<Vec<f64>>,
    /// Where live commands came from (`keyboard`, `gamepad`, `udp ADDR`), if anywhere; the
    /// commands themselves are recorded tick by tick on `/policy`.
    #[serde(default)]
    pub command_source: Option<String>,
    /// The motion generator the run tracked instead of a clip (its description).
    #[serde(default)]
    pub generator: Option<PathBuf>,
    /// The 2D keypoint references played beside the clip, and their cameras.
    #[serde(default)]
    pub keypoints: Option<crate::keypoints::clip::KeypointSource>,
    /// The options.
    pub options: PlayOptions,
    /// Why the run played a clip `check` refuses (`play --force REASON`), if it did.
    #[serde(default)]
    pub forced: Option<String>,
    /// The folder the recording was written in (absolute): where the files named relative to
    /// it are looked for when the recording has moved since.
    #[serde(default)]
    pub recorded_in: Option<PathBuf>,
}

impl RunMetadata {
    /// The metadata as JSON (full float precision).
    pub fn to_json(&self) -> String {
        serde_json::to_string(self).unwrap_or_default()
    }

    /// Metadata written by [`Self::to_json`].
    pub fn from_json(text: &str) -> Result<Self, serde_json::Error> {
        serde_json::from_str(text)
    }

    /// The same run with its files named relative to `dir` (the recording's folder): a
    /// recording names no absolute path, and still finds its files when the project it was made
    /// in moves, or is replayed from another working directory.
    pub fn relative_to(&self, dir: &std::path::Path) -> Self {
        let absolute = |p: &std::path::Path| std::path::absolute(p).unwrap_or_else(|_| p.to_path_buf());
        let base = absolute(dir);
        let relative = |p: &PathBuf| pathdiff::diff_paths(absolute(p), &base).unwrap_or_else(|| p.clone());
        Self {
            robot: relative(&self.robot),
            policy: relative(&self.policy),
            clip: self.clip.as_ref().map(relative),
            generator: self.generator.as_ref().map(relative),
            keypoints: self.keypoints.as_ref().map(|k| k.map_paths(relative)),
            recorded_in: Some(base.clone()),
            ..self.clone()
        }
    }

    /// The files of a run read from a recording in `dir`, as paths to open (undoes
    /// [`Self::relative_to`]; absolute paths of older recordings stay as they are). A file not
    /// found beside a recording that has moved is taken from where the recording was written,
    /// and the log says so.
    pub fn resolved_from(&self, dir: &std::path::Path) -> Self {
        let resolve = |p: &PathBuf| {
            if !p.is_relative() {
                return p.clone();
            }
            let here = dir.join(p);
            match &self.recorded_in {
                Some(origin) if !here.exists() && origin.join(p).exists() => {
                    let there = origin.join(p);
                    tracing::warn!(
                        "{} is not beside the recording (it moved from {}): using {}",
                        here.display(),
                        origin.display(),
                        there.display()
                    );
                    there
                }
                _ => here,
            }
        };
        Self {
            robot: resolve(&self.robot),
            policy: resolve(&self.policy),
            clip: self.clip.as_ref().map(resolve),
            generator: self.generator.as_ref().map(resolve),
            keypoints: self.keypoints.as_ref().map(|k| k.map_paths(resolve)),
            ..self.clone()
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn run_files_are_named_from_the_recordings_folder_and_found_again_from_there() {
        let here = std::env::current_dir().unwrap();
        let m = RunMetadata {
            clip: Some("/elsewhere/clip.csv".into()),
            ..files(
                here.join("robots/biped/robot.toml"),
                "robots/biped/policies/p.toml".into(),
            )
        };
        let dir = here.join("out/runs");
        let stored = m.relative_to(&dir);
        assert_eq!(stored.robot, PathBuf::from("../../robots/biped/robot.toml"));
        assert_eq!(stored.policy, PathBuf::from("../../robots/biped/policies/p.toml"));
        assert!(stored.clip.as_ref().unwrap().is_relative(), "{stored:?}");
        let back = stored.resolved_from(&dir);
        for (a, b) in [
            (&back.robot, &m.robot),
            (back.clip.as_ref().unwrap(), m.clip.as_ref().unwrap()),
        ] {
            assert_eq!(normalize(a), normalize(&std::path::absolute(b).unwrap()));
        }
    }

    #[test]
    fn a_recording_moved_to_another_folder_finds_its_files_where_it_was_written() {
        let root = std::env::temp_dir().join(format!("run-moved-{}", std::process::id()));
        let (project, elsewhere) = (root.join("project"), root.join("results/2026"));
        std::fs::create_dir_all(project.join("out")).unwrap();
        std::fs::create_dir_all(&elsewhere).unwrap();
        std::fs::write(project.join("robot.toml"), "").unwrap();
        let m = files(project.join("robot.toml"), project.join("policy.toml"));
        let stored = m.relative_to(&project.join("out"));
        let moved = stored.resolved_from(&elsewhere);
        assert_eq!(normalize(&moved.robot), project.join("robot.toml"));
        // A file found nowhere keeps the path beside the recording (the error names it there).
        assert_eq!(moved.policy, elsewhere.join("../policy.toml"));
        std::fs::remove_dir_all(&root).unwrap();
    }

    /// A run of `robot` and `policy` with nothing else.
    fn files(robot: PathBuf, policy: PathBuf) -> RunMetadata {
        RunMetadata {
            robot,
            policy,
            clip: None,
            command: None,
            command_source: None,
            generator: None,
            keypoints: None,
            options: PlayOptions::default(),
            forced: None,
            recorded_in: None,
        }
    }

    /// `a/b/../c` → `a/c`, lexically.
    fn normalize(p: &std::path::Path) -> PathBuf {
        let mut out = PathBuf::new();
        for c in p.components() {
            match c {
                std::path::Component::ParentDir => {
                    out.pop();
                }
                other => out.push(other),
            }
        }
        out
    }

    #[test]
    fn run_metadata_round_trips_through_json_exactly() {
        let m = RunMetadata {
            robot: "robots/biped/robot.toml".into(),
            policy: "p.toml".into(),
            clip: Some("c.csv".into()),
            command_source: None,
            command: Some(vec![0.1, -2.5e-7]),
            generator: None,
            keypoints: Some(crate::keypoints::clip::KeypointSource {
                keypoints: "k.json".into(),
                cameras: "cams.toml".into(),
                view: Some("front".into()),
                person: Some(7),
                fps: 29.97,
            }),
            options: PlayOptions {
                soft_start_s: 0.1 + 0.2,
                end: EndMode::Blend,
                max_ticks: Some(7),
                ..PlayOptions::default()
            },
            forced: Some("the operator watches it on the gantry".into()),
            recorded_in: Some("/data/runs".into()),
        };
        assert_eq!(RunMetadata::from_json(&m.to_json()).unwrap(), m);
        // Options a recording leaves out keep their defaults; unknown ones are refused.
        let partial = r#"{"robot":"r","policy":"p","clip":"c","options":{"ramp_s":2.0}}"#;
        let m = RunMetadata::from_json(partial).unwrap();
        assert_eq!(m.options.ramp_s, Some(2.0));
        assert_eq!(m.options.end_s, PlayOptions::default().end_s);
        let unknown = r#"{"robot":"r","policy":"p","clip":"c","options":{"ramp":2.0}}"#;
        assert!(
            RunMetadata::from_json(unknown)
                .unwrap_err()
                .to_string()
                .contains("ramp")
        );
    }
}
