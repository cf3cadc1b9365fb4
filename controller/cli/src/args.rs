//! Argument parsers the bus tools share: `ID:MODEL` device specs and `FIRST-LAST` ID ranges.

/// A flag refused after parsing, where judging it needs the other flags or a file: exit 2
/// (bad input), like a value clap refuses.
#[derive(Debug, thiserror::Error)]
#[error("--{flag}{why}")]
pub struct FlagError {
    /// The flag, without its dashes.
    pub flag: String,
    /// What is wrong, as it follows the flag's name (" 12345: …", ": …", " is …").
    pub why: String,
}

impl FlagError {
    pub fn new(flag: impl Into<String>, why: impl std::fmt::Display) -> Self {
        Self {
            flag: flag.into(),
            why: why.to_string(),
        }
    }
}

/// Parses `ID:MODEL` with the ID in `ids` and the model among `known`; `what` names the device
/// kind in messages ("motor", "servo").
pub fn id_and_model(
    s: &str,
    what: &str,
    ids: std::ops::RangeInclusive<u8>,
    known: &[&str],
) -> Result<(u8, String), String> {
    let example = format!("{}:{}", ids.start().max(&1), known.first().unwrap_or(&"MODEL"));
    let (id, model) = s
        .split_once(':')
        .ok_or_else(|| format!("'{s}': expected ID:MODEL, e.g. {example}"))?;
    let id: u8 = id.parse().ok().filter(|id| ids.contains(id)).ok_or_else(|| {
        format!(
            "'{s}': {what} ID '{id}' is not a number {}-{}",
            ids.start(),
            ids.end()
        )
    })?;
    if !known.contains(&model) {
        return Err(format!(
            "'{s}': unknown {what} model '{model}' (known: {})",
            known.join(", ")
        ));
    }
    Ok((id, model.to_owned()))
}

/// Parses `FIRST-LAST` (or one ID) with `LAST <= max`.
pub fn id_range(s: &str, max: u8) -> Result<(u8, u8), String> {
    let (a, b) = s.split_once('-').unwrap_or((s, s));
    let parse = |x: &str| {
        x.trim()
            .parse::<u8>()
            .map_err(|_| format!("'{s}': expected FIRST-LAST, e.g. 1-{max}"))
    };
    let (a, b) = (parse(a)?, parse(b)?);
    if a > b || b > max {
        return Err(format!("'{s}': need FIRST <= LAST <= {max}"));
    }
    Ok((a, b))
}

/// SIGINT/SIGTERM caught for a server, so it can print its summary and end cleanly instead of
/// dying mid-write. Installed before the server says it is serving: a signal sent as soon as that
/// line appears must find the handler in place.
#[derive(Debug)]
pub struct StopSignal(std::sync::Arc<std::sync::atomic::AtomicBool>);

impl StopSignal {
    /// Installs the handlers.
    pub fn install() -> anyhow::Result<Self> {
        let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
        for signal in [signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM] {
            signal_hook::flag::register(signal, std::sync::Arc::clone(&stop))
                .map_err(|e| anyhow::anyhow!("cannot install the stop signal handlers: {e}"))?;
        }
        Ok(Self(stop))
    }

    /// Waits until `seconds` pass (`None`: for ever) or a signal arrives; says which.
    pub fn wait(&self, seconds: Option<u64>) -> &'static str {
        let until = seconds.map(|s| std::time::Instant::now() + std::time::Duration::from_secs(s));
        loop {
            if self.0.load(std::sync::atomic::Ordering::Relaxed) {
                return "stopped by a signal";
            }
            if until.is_some_and(|u| std::time::Instant::now() >= u) {
                return "time is up";
            }
            std::thread::sleep(std::time::Duration::from_millis(50));
        }
    }
}

/// A reason given on the command line (`--force`): 1–500 characters, not only blanks.
pub fn reason(text: &str) -> Result<String, String> {
    let t = text.trim();
    if t.is_empty() || t.chars().count() > 500 {
        Err("give a reason of 1 to 500 characters (it is recorded in the run)".into())
    } else {
        Ok(t.to_owned())
    }
}

/// A flag's number, refused (by clap, naming the flag) unless finite and within `[lo, hi]`.
pub fn within(lo: f64, hi: f64) -> impl Fn(&str) -> Result<f64, String> + Clone + Send + Sync + 'static {
    move |text: &str| {
        let v: f64 = text
            .trim()
            .parse()
            .map_err(|_| format!("{text:?} is not a number"))?;
        if v.is_finite() && (lo..=hi).contains(&v) {
            Ok(v)
        } else {
            Err(format!(
                "{} is outside [{}, {}]",
                robots::num(v),
                robots::num(lo),
                robots::num(hi)
            ))
        }
    }
}

/// A flag's whole number, refused unless within `[lo, hi]`.
pub fn whole_within(
    lo: u64,
    hi: u64,
) -> impl Fn(&str) -> Result<u64, String> + Clone + Send + Sync + 'static {
    move |text: &str| {
        let v: u64 = text
            .trim()
            .parse()
            .map_err(|_| format!("{text:?} is not a whole number"))?;
        if (lo..=hi).contains(&v) {
            Ok(v)
        } else {
            Err(format!("{v} is outside [{lo}, {hi}]"))
        }
    }
}

/// A frame index of a motion file: `[0, motion::bvh::MAX_FRAMES)` (the file's own length is
/// checked when it loads).
pub fn frame_index(text: &str) -> Result<usize, String> {
    let max = motion::bvh::MAX_FRAMES as u64 - 1;
    whole_within(0, max)(text).map(|v| v as usize)
}

/// Parallel jobs: 1–256.
pub fn jobs(text: &str) -> Result<usize, String> {
    whole_within(1, 256)(text).map(|v| v as usize)
}

/// What happens when the clip ends (`--end`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum EndArg {
    /// Hold the last frame for a moment, then stop.
    Hold,
    /// Blend back to the default pose, then stop.
    Blend,
    /// Start the clip again (until stopped).
    Loop,
    /// Blend to the default pose and stand there under the policy until stopped (Ctrl-C,
    /// e-stop, --max-seconds).
    Stand,
}

impl From<EndArg> for controller::player::EndMode {
    fn from(a: EndArg) -> Self {
        match a {
            EndArg::Hold => Self::Hold,
            EndArg::Blend => Self::Blend,
            EndArg::Loop => Self::Loop,
            EndArg::Stand => Self::Stand,
        }
    }
}

/// What a soft stop ends in (`--on-stop`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum OnStopArg {
    /// Damp and let go (a humanoid folds up).
    Damp,
    /// Stay standing under the policy until stopped again (or --stand-for), then damp.
    #[value(alias = "stand")]
    Stay,
    /// Sit down slowly on the joints' PD into robot.toml's sit_keyframe, then let go.
    Sit,
    /// The harness the run started in takes the weight, then damp (--start harness).
    Harness,
}

impl From<OnStopArg> for controller::options::OnStop {
    fn from(a: OnStopArg) -> Self {
        match a {
            OnStopArg::Damp => Self::Damp,
            OnStopArg::Stay => Self::Stay,
            OnStopArg::Sit => Self::Sit,
            OnStopArg::Harness => Self::Harness,
        }
    }
}

/// How much of the robot the mirror is (`--fidelity`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum FidelityArg {
    /// Every device's firmware behind its bus protocol, the host's real drivers on the wires.
    Wires,
    /// The trainer's actuator law applied to MuJoCo, no buses, firmware or wires: the physics
    /// floor, for validating motion libraries (lockstep only).
    Direct,
}

impl From<FidelityArg> for sim2real::config::Fidelity {
    fn from(a: FidelityArg) -> Self {
        match a {
            FidelityArg::Wires => Self::Wires,
            FidelityArg::Direct => Self::Direct,
        }
    }
}

/// How the policy takes the robot (`--start`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum StartArg {
    /// The policy in control from its first tick while a harness lowers the robot onto its feet
    /// (the mirror hangs it from a crane's rope; on the robot, the operator lowers it).
    Harness,
    /// The policy in control from its first tick, the robot on the floor.
    Policy,
    /// The joints' PD brings the robot into the default pose first (robot.toml [start] pd_s,
    /// pd_gain), then the policy takes over: for robots that stand on their joints alone.
    Pd,
}

impl From<StartArg> for robots::StartMode {
    fn from(a: StartArg) -> Self {
        match a {
            StartArg::Harness => Self::Harness,
            StartArg::Policy => Self::Policy,
            StartArg::Pd => Self::Pd,
        }
    }
}

/// Where the world terms of the observation come from (`--estimator`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum EstimatorArg {
    /// The state estimator on what the robot measures (IMU, joints): what the hardware runs,
    /// with the filter robot.toml's `[estimator] filter` names (the invariant EKF by default).
    Kf,
    /// The state estimator with the contact-aided invariant EKF.
    Invariant,
    /// The state estimator with the linear Kalman filter.
    Linear,
    /// The simulation's ground truth (the mirror only).
    GroundTruth,
}

impl From<EstimatorArg> for controller::options::EstimatorKind {
    fn from(a: EstimatorArg) -> Self {
        match a {
            EstimatorArg::Kf => Self::Kf,
            EstimatorArg::Invariant => Self::Invariant,
            EstimatorArg::Linear => Self::Linear,
            EstimatorArg::GroundTruth => Self::GroundTruth,
        }
    }
}

/// The robot's pose matching the human's nominal frame (`--nominal`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum NominalArg {
    /// robot.toml's `[retarget] tpose` (the human's nominal frame is a T-pose).
    Tpose,
    /// The default standing pose (the human's nominal frame stands with the arms down).
    Default,
}

impl From<NominalArg> for human::retarget::Nominal {
    fn from(a: NominalArg) -> Self {
        match a {
            NominalArg::Tpose => Self::Tpose,
            NominalArg::Default => Self::Default,
        }
    }
}

/// What a VR operator wears, as the sender sends it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum BodyArg {
    /// A headset and two controllers (VMC `/VMC/Ext/Hmd/Pos`, `/VMC/Ext/Con/Pos`): the head and
    /// arms follow by inverse kinematics, the legs stand.
    Devices,
    /// A headset, two controllers and a tracker on each foot (VMC `/VMC/Ext/Tra/Pos`; serials
    /// containing "left"/"right", or `--left-foot-serial`/`--right-foot-serial`): the feet where
    /// the trackers put them (their place on the foot measured in the T-pose), the pelvis under the
    /// head within the legs' reach, the arms by two-bone IK; retargeted whole like `full`.
    FivePoint,
    /// The whole body (VMC `/VMC/Ext/Root/Pos` and `/VMC/Ext/Bone/Pos`, Unity's humanoid bone
    /// names: a motion-capture suit, full-body tracking): retargeted whole onto the robot, every
    /// joint and the root, for a general tracker.
    Full,
}

impl From<BodyArg> for human::vr_send::BodySet {
    fn from(a: BodyArg) -> Self {
        match a {
            BodyArg::Devices => Self::Devices,
            BodyArg::FivePoint => Self::DevicesAndFeet,
            BodyArg::Full => Self::Skeleton,
        }
    }
}

/// The name a value goes by in the project's files (its serde name), for messages to people.
pub fn file_name_of<T: serde::Serialize>(value: &T) -> String {
    serde_json::to_string(value)
        .unwrap_or_default()
        .trim_matches('"')
        .to_owned()
}

/// The policy of a run: `--policy` when given, else the one robot.toml names (`policy = …`).
pub fn policy_of(
    given: Option<&std::path::Path>,
    robot: &robots::Robot,
) -> Result<std::path::PathBuf, FlagError> {
    match given {
        Some(p) => Ok(p.to_path_buf()),
        None => match robots::locate::bundle_policy_for(&robot.path).or_else(|| robot.default_policy()) {
            Some(p) if p.is_file() => Ok(p),
            Some(p) => Err(FlagError::new(
                "policy",
                format!(
                    " is not given, and the policy {} names ({}) is not a file",
                    robot.path.display(),
                    p.display()
                ),
            )),
            None => Err(FlagError::new(
                "policy",
                format!(
                    " is not given and {} names no policy of its own (add `policy = \"policies/NAME.toml\"` to it)",
                    robot.path.display()
                ),
            )),
        },
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn specs_and_ranges_parse_or_say_why_not() {
        assert_eq!(
            id_and_model("3:AK80-9", "motor", 1..=127, &["AK80-9"]),
            Ok((3, "AK80-9".into()))
        );
        assert!(
            id_and_model("0:AK80-9", "motor", 1..=127, &["AK80-9"])
                .unwrap_err()
                .contains("not a number 1-127")
        );
        assert!(
            id_and_model("3:AK99", "motor", 1..=127, &["AK80-9"])
                .unwrap_err()
                .contains("unknown motor model 'AK99'")
        );
        assert!(
            id_and_model("3", "servo", 0..=252, &["XM430-W350"])
                .unwrap_err()
                .contains("e.g. 1:XM430-W350")
        );
        assert_eq!(id_range("1-16", 127), Ok((1, 16)));
        assert_eq!(id_range("5", 127), Ok((5, 5)));
        assert!(id_range("9-3", 127).unwrap_err().contains("FIRST <= LAST <= 127"));
    }
}
