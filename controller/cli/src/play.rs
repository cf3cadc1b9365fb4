//! `robodeploy play` and `robodeploy check`: run a policy on a clip, or validate the three files.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

use anyhow::{Context, Result, bail};

use crate::args::FlagError;
use clap::Args;
use robots::Robot;

use crate::sim::load_mirror_config;
use controller::clip::Reference;
use controller::generator::{Generator, GeneratorOptions, GeneratorSummary, GeneratorWorker};
use controller::player::{PlayOptions, PlaySummary, Player};
use controller::reference::ReferenceSource;
use controller::sim::{direct_player, lockstep_player, wired_player};
use controller::telemetry::{Backpressure, TelemetrySink};
use policy::PolicyLayout;
use robot_link::RobotLink;

/// Arguments of `play`.
#[derive(Debug, Args)]
pub struct PlayArgs {
    #[command(flatten)]
    files: Files,
    /// Run on the robot's own buses (robot.toml devices) instead of the mirror.
    #[arg(help_heading = "Where it runs", long, conflicts_with = "wall")]
    hardware: bool,
    /// Run the mirror in real time behind real wires (socketcand, pseudo-terminals) and connect
    /// to it as to hardware.
    #[arg(help_heading = "Where it runs", long)]
    wall: bool,
    /// Mirror settings (seed, gantry, randomisation, faults), TOML.
    #[arg(help_heading = "Where it runs", long)]
    mirror: Option<PathBuf>,
    /// Hold the mirrored robot on a gantry.
    #[arg(help_heading = "Where it runs", long)]
    gantry: bool,
    /// How much of the robot the mirror is (default: the --mirror file's `fidelity`, else wires):
    /// wires — every device's firmware behind its bus protocol, the host's real drivers; direct —
    /// each joint's command applied to MuJoCo as the trainer's actuator law (robot.toml
    /// [[actuators]], explicit PD within the torque limit where none is given), no buses: the
    /// physics floor, for validating motion libraries. Lockstep only.
    #[arg(help_heading = "Where it runs", long, value_enum, conflicts_with = "hardware")]
    fidelity: Option<crate::args::FidelityArg>,
    /// Play a clip that `check` refuses (the robot could not follow it: floor penetrated, feet
    /// that cannot carry it, torques beyond the motors), saying why; the reason is recorded in
    /// the run. Without it `play` refuses what `check` refuses.
    #[arg(help_heading = "What to run", long, value_name = "REASON", value_parser = crate::args::reason)]
    force: Option<String>,
    /// How the policy takes the robot (default: robot.toml's [start] mode, else pd): harness —
    /// in control from the first tick while a harness lowers the robot onto its feet; policy —
    /// from the first tick on the floor; pd — the joints' PD brings it to the default pose first.
    #[arg(help_heading = "How the run goes", long, value_enum)]
    start: Option<crate::args::StartArg>,
    /// What to do when the clip ends.
    #[arg(help_heading = "How the run goes", long, value_enum, default_value_t = crate::args::EndArg::Hold)]
    end: crate::args::EndArg,
    /// What a soft stop (Ctrl-C, --max-seconds, the clip's end) ends in. First the policy settles
    /// the robot for --settle seconds (the reference held where the stop came and blended to the
    /// standing pose; commands ramped to rest); then: damp (let go), stay (standing under the
    /// policy until a second Ctrl-C or --stand-for), sit (a slow sit-down on the joints' PD into
    /// robot.toml's sit_keyframe, then let go) or harness (the harness the run started in takes
    /// the weight, then let go). Faults damp at once whatever this says.
    #[arg(help_heading = "How the run goes", long, value_enum, default_value_t = crate::args::OnStopArg::Damp)]
    on_stop: crate::args::OnStopArg,
    /// How long a soft stop settles the robot under the policy before --on-stop, s (0.02–30).
    #[arg(help_heading = "How the run goes", long, default_value_t = 1.0, value_parser = crate::args::within(0.02, 30.0))]
    settle: f64,
    /// With --on-stop stay: stand at most this long, s (default: until stopped again; refused
    /// with any other --on-stop, where it would do nothing).
    #[arg(help_heading = "How the run goes", long, value_parser = crate::args::within(0.0, 86_400.0))]
    stand_for: Option<f64>,
    /// With --on-stop sit: how long the sit-down takes, s (0.1–60).
    #[arg(help_heading = "How the run goes", long, default_value_t = 3.0, value_parser = crate::args::within(0.1, 60.0))]
    sit_seconds: f64,
    /// Seconds the reference holds its first frame after the policy takes control, while the
    /// start-up ramp ψ rises (0–60; default: the policy's `[reference] hold_s`, else 1.5 s for a
    /// policy that observes ψ and 0 for any other: the motion moves from the first tick).
    #[arg(help_heading = "How the run goes", long, value_parser = crate::args::within(0.0, 60.0))]
    ramp: Option<f64>,
    /// Where the base velocity and height, foot contacts and anchor position a policy observes
    /// come from: the state estimator on the IMU and leg kinematics (`kf`: the filter robot.toml's
    /// [estimator] filter names, the invariant EKF unless it says otherwise; `invariant` or
    /// `linear` choose one for this run; recorded on /estimator with the mirror's truth beside
    /// it), or the mirror's ground truth. The hardware always runs the estimator.
    #[arg(help_heading = "How the run goes", long, value_enum, default_value_t = crate::args::EstimatorArg::Kf)]
    estimator: crate::args::EstimatorArg,
    /// Stop (softly) after this many seconds of the run, whatever the clip.
    #[arg(help_heading = "How the run goes", long, value_parser = crate::args::within(0.02, 86_400.0))]
    max_seconds: Option<f64>,
    /// Bus cycles in a row a joint may stay silent before its bus damps itself and the robot
    /// stops (1–100). Default: 2; 8 with --wall, whose mirror is served on this machine and
    /// competes with the loop for its cores (late, not lost).
    #[arg(help_heading = "How the run goes", long, value_parser = crate::args::whole_within(1, 100))]
    stale_cycles: Option<u64>,
    /// Real-time set-up: the loop thread under SCHED_FIFO, memory locked, pinned to the last CPU;
    /// each bus thread under SCHED_FIFO above the loop. Steps the system refuses are reported and
    /// skipped.
    #[arg(help_heading = "Where it runs", long)]
    realtime: bool,
    /// Listen for an e-stop on this UDP address (a datagram `ESTOP` damps the robot at once).
    #[arg(help_heading = "E-stop and harness", long)]
    estop_udp: Option<std::net::SocketAddr>,
    /// With a harness start: the operator's word that the robot stands on its feet, a datagram
    /// `LOWERED` on this UDP address. Until it comes the policy holds the robot on the motion's
    /// first frame; then it settles and the motion plays. On the hardware, Enter on this
    /// terminal says it too; on the mirror, this rehearses the start.
    #[arg(help_heading = "E-stop and harness", long, value_name = "ADDR")]
    lowered_udp: Option<std::net::SocketAddr>,
    /// Values of the policy's `command` term (e.g. a velocity command `0.3,0,0`), replacing the
    /// manifest's constants; with a `[commands]` section each must lie within its range, and a
    /// live source below starts from them.
    #[arg(
        help_heading = "Operator commands",
        long,
        value_delimiter = ',',
        allow_hyphen_values = true
    )]
    command: Option<Vec<f64>>,
    #[command(flatten)]
    live: crate::commands::CommandArgs,
    #[command(flatten)]
    rec: RecordArgs,
    /// After the run, write its report (plots, summary) into this folder.
    #[arg(help_heading = "Recording and report", long, conflicts_with = "no_record")]
    report: Option<PathBuf>,
    #[command(flatten)]
    generator: GeneratorArgs,
    #[command(flatten)]
    keypoints: KeypointArgs,
}

/// 2D keypoint references beside the clip (`play --keypoints`).
#[derive(Debug, Args)]
#[command(next_help_heading = "2D keypoint references")]
struct KeypointArgs {
    /// 2D keypoint references of the clip (Mimic2DM): the project's CSV (what `robodeploy
    /// project` writes: time_s, then VIEW/KEYPOINT/u,v,confidence) or a pose estimator's COCO
    /// JSON (one view: --view, --person, --fps). Resampled to the policy's ticks; the policy's
    /// ref_keypoints/keypoints terms see them, and every tracked tick measures the robot's
    /// keypoints (robot.toml [keypoints], projected) against them: reprojection error per view,
    /// ticks over 100 px, the triangulated error with two views. Needs --cameras.
    #[arg(long, value_name = "FILE", requires = "cameras", conflicts_with = "generator")]
    keypoints: Option<PathBuf>,
    /// The cameras of the keypoint references (TOML [[camera]]: intrinsics, distortion, pose in
    /// the clip's world), e.g. robots/biped/cameras.toml.
    #[arg(long, value_name = "FILE", requires = "keypoints")]
    cameras: Option<PathBuf>,
    /// With COCO references: the camera that filmed them (default: the only camera).
    #[arg(long, requires = "keypoints")]
    view: Option<String>,
    /// With COCO references: the person to follow, by track_id.
    #[arg(long, requires = "keypoints")]
    person: Option<u64>,
    /// With COCO references: the video's frames per second.
    #[arg(long, default_value_t = 30.0, value_parser = crate::args::within(1.0, 1000.0))]
    fps: f64,
}

impl KeypointArgs {
    /// What `--keypoints` names, when given.
    fn source(&self) -> Option<controller::keypoints::clip::KeypointSource> {
        Some(controller::keypoints::clip::KeypointSource {
            keypoints: self.keypoints.clone()?,
            cameras: self.cameras.clone()?,
            view: self.view.clone(),
            person: self.person,
            fps: self.fps,
        })
    }
}

/// Adds `--keypoints` to the run's reference.
fn load_keypoint_references(args: &KeypointArgs, l: &mut Loaded) -> Result<()> {
    let Some(source) = args.source() else {
        return Ok(());
    };
    let (cameras, clip) = source.load()?;
    l.reference.keypoints = Some(
        controller::keypoints::track::KeypointReference::new(
            &clip,
            &cameras,
            l.layout.manifest.rate_hz,
            l.reference.len(),
        )
        .with_context(|| format!("--keypoints {}", source.keypoints.display()))?,
    );
    println!(
        "keypoints {}: {} frames, {} keypoints in {} views ({})",
        source.keypoints.display(),
        clip.len(),
        clip.names.len(),
        clip.views.len(),
        clip.views.join(", ")
    );
    Ok(())
}

/// An online motion generator as the reference (`play --generator`).
#[derive(Debug, Args)]
#[command(next_help_heading = "Motion generator")]
struct GeneratorArgs {
    /// Track what an online motion generator produces instead of a clip: its description (TOML
    /// beside its ONNX file: input/output names, history N, horizon K, frame rate, joints, seed
    /// clip). It runs on its own thread, K frames a step, resampled to the policy's rate; the run
    /// goes on until Ctrl-C or --max-seconds. E.g. robots/biped/generators/squat_ar.toml.
    #[arg(long, value_name = "TOML", conflicts_with = "clip")]
    generator: Option<PathBuf>,
    /// When the generator is late, carry the reference on by its recent velocity this long, s.
    #[arg(long, default_value_t = 0.2, requires = "generator", value_parser = crate::args::within(0.0, 2.0))]
    generator_forecast: f64,
    /// Then blend to the standby pose over this long (and back when plans return), s.
    #[arg(long, default_value_t = 1.0, requires = "generator", value_parser = crate::args::within(0.05, 10.0))]
    generator_blend: f64,
    /// The generator's command (its description's [command]: e.g. a target velocity or a style
    /// index), one value per name, replacing the description's values. The squat generator
    /// takes its intensity: 1 squats, 0 settles into the standing pose.
    #[arg(
        long,
        value_name = "V,…",
        requires = "generator",
        value_delimiter = ',',
        allow_hyphen_values = true
    )]
    generator_command: Option<Vec<f64>>,
    /// Fault injection: the generator stalls once it has produced this many seconds of motion.
    #[arg(long, value_name = "S", requires = "generator", value_parser = crate::args::within(0.0, 86_400.0))]
    generator_stall_after: Option<f64>,
}

/// A run's generator, loaded; started once its player is built.
struct PendingGenerator {
    generator: Generator,
    options: GeneratorOptions,
}

impl PendingGenerator {
    /// Starts the worker and hands its plans to `player`.
    fn attach<L: RobotLink>(self, player: Player<L>) -> Result<(Player<L>, GeneratorWorker, (f64, usize))> {
        let standby = player.layout_default_q().to_vec();
        let rate = (
            self.generator.description.frame_hz,
            self.generator.description.horizon,
        );
        let (worker, plans) = self
            .generator
            .start(&standby, self.options, player.lookahead_s())?;
        Ok((player.with_source(plans), worker, rate))
    }
}

/// Loads `--generator` and puts its standby reference in place of the clip.
fn load_generator(args: &GeneratorArgs, l: &mut Loaded) -> Result<Option<PendingGenerator>> {
    let Some(path) = &args.generator else {
        return Ok(None);
    };
    let mut generator = Generator::load(path, &l.robot)?;
    if let Some(values) = &args.generator_command {
        generator.set_command(values).context("--generator-command")?;
    }
    controller::generator::check_policy(&l.layout).map_err(|e| anyhow::anyhow!("--generator: {e}"))?;
    l.reference = Reference::hold(&l.layout.default_q, generator.root(), l.layout.manifest.rate_hz);
    l.source = ReferenceSource::Generated(path.clone());
    let d = &generator.description;
    println!(
        "generator {}: {} → {} frames at {} Hz ({} Hz steps), {} joints",
        path.display(),
        d.history,
        d.horizon,
        d.frame_hz,
        d.frame_hz / d.horizon as f64,
        d.joints.len()
    );
    let (names, values) = generator.command();
    if !names.is_empty() {
        let pairs: Vec<String> = names
            .iter()
            .zip(&values)
            .map(|(n, v)| format!("{n} = {v}"))
            .collect();
        println!("          command: {}", pairs.join(", "));
    }
    Ok(Some(PendingGenerator {
        generator,
        options: GeneratorOptions {
            forecast_s: args.generator_forecast,
            blend_s: args.generator_blend,
            stall_after_s: args.generator_stall_after,
        },
    }))
}

/// Runs `player` on `clock`, with `generator` feeding its reference when there is one.
fn run_with<L: RobotLink>(
    player: Player<L>,
    clock: &mut dyn robot_link::TickClock,
    generator: Option<PendingGenerator>,
) -> Result<PlaySummary> {
    let Some(g) = generator else {
        let mut player = player;
        return Ok(player.run(clock)?);
    };
    let (mut player, worker, (frame_hz, horizon)) = g.attach(player)?;
    let mut summary = player.run(clock)?;
    let plans = player
        .generated()
        .context("the generator's plans were not attached")?;
    summary.generator = Some(GeneratorSummary {
        counts: plans.counts(),
        events: plans.events().to_vec(),
        reached_standby: plans.reached_standby(),
        worker: worker.finish(),
        frame_hz,
        horizon,
    });
    Ok(summary)
}

/// How a run is recorded and watched (`play`, `teleop`).
#[derive(Debug, Args)]
#[command(next_help_heading = "Recording and report")]
pub struct RecordArgs {
    /// Record the run as MCAP here (default: out/runs/ROBOT-CLIP.mcap, or the next free name;
    /// opens in Foxglove).
    #[arg(long)]
    pub(crate) record: Option<PathBuf>,
    /// Do not record the run.
    #[arg(long, conflicts_with = "record")]
    pub(crate) no_record: bool,
    /// With --record: replace a recording already at that path (without it, the run refuses).
    #[arg(long, requires = "record")]
    pub(crate) overwrite: bool,
    /// Also record every bus cycle (what each bus read and commanded, its cycle time and misses)
    /// on a `/bus/<name>` channel per bus, at the bus's own rate.
    #[arg(long, conflicts_with = "no_record")]
    pub(crate) record_bus_rate: bool,
    /// Serve the run live to Foxglove (Open connection → Foxglove WebSocket → the printed
    /// ws:// URL): every channel of the recording, as it is written. On 127.0.0.1:8765 unless
    /// given another address (127.0.0.1:0: any free port); the recording's own layout works live.
    #[arg(long = "live", value_name = "ADDR", num_args = 0..=1, default_missing_value = "127.0.0.1:8765", conflicts_with = "no_record")]
    pub(crate) live_view: Option<std::net::SocketAddr>,
    /// With --live: wait this long for a viewer to subscribe before the robot starts, s (0: do
    /// not wait; Ctrl-C stops waiting).
    #[arg(long, default_value_t = 60, requires = "live_view", value_parser = crate::args::whole_within(0, 3600))]
    pub(crate) live_wait: u64,
    /// Publish the run on ROS 2's topics, as ROS 2's DDS middlewares name them: /joint_states
    /// (sensor_msgs/msg/JointState), /tf (tf2_msgs/msg/TFMessage, every link), /robot_description
    /// (std_msgs/msg/String, the URDF, transient local) and /diagnostics
    /// (diagnostic_msgs/msg/DiagnosticArray, once a second). On network interface IFACE (default
    /// lo: this machine only; name the interface of the network ROS 2 runs on). From the
    /// recording's thread, so a run with --ros2 records. With --cmd-vel, /cmd_vel drives the
    /// policy's commands.
    #[arg(long, value_name = "IFACE", num_args = 0..=1, default_missing_value = "lo", conflicts_with = "no_record")]
    pub(crate) ros2: Option<String>,
    /// With --ros2: the DDS domain (ROS 2's ROS_DOMAIN_ID), 0–232.
    #[arg(long, default_value_t = 0, requires = "ros2", value_parser = crate::args::whole_within(0, 232))]
    pub(crate) ros2_domain: u64,
    /// How the recording's chunks are compressed: lz4 (fast, about half the size), zstd (a
    /// third of lz4's size or less, more CPU on the recording's own thread), none. Every MCAP
    /// reader opens all three. The run's last lines say what the recording cost.
    #[arg(long, value_name = "KIND", default_value = "lz4", value_parser = ["none", "lz4", "zstd"], conflicts_with = "no_record")]
    pub(crate) record_compression: String,
    /// The compressor's level: 0 its default, lz4 1–12, zstd 1–19 (higher: smaller, slower).
    #[arg(long, default_value_t = 0, value_parser = crate::args::whole_within(0, 19), conflicts_with = "no_record")]
    pub(crate) record_level: u64,
    /// Target size of the recording's chunks, KiB (4–65536): a crash loses at most the chunk
    /// being built (64 KiB: ~0.3 s of a 50 Hz run); larger chunks compress better.
    #[arg(long, value_name = "KIB", default_value_t = 64, value_parser = crate::args::whole_within(4, 65_536), conflicts_with = "no_record")]
    pub(crate) record_chunk_kib: u64,
    /// Write a channel every N ticks instead of every tick (0: not at all), repeatable:
    /// `--record-every /tf=5 --record-every /joint_states=0`. Channels: /joint_state,
    /// /joint_states, /command, /policy, /imu, /timing, /estimator, /tf, /anchor/robot,
    /// /anchor/reference. /replay, /safety, /log, /robot and /robot_description are always
    /// whole (replay and report read them). The live view gets what the file gets.
    #[arg(long, value_name = "TOPIC=N", value_parser = record_every, conflicts_with = "no_record")]
    pub(crate) record_every: Vec<(String, u32)>,
}

/// `--record-every`'s `TOPIC=N`: a channel of [`controller::telemetry::THINNABLE_TOPICS`], N in
/// 0–10000 ticks.
fn record_every(text: &str) -> Result<(String, u32), String> {
    let (topic, n) = text
        .split_once('=')
        .ok_or_else(|| format!("{text:?} is not TOPIC=N (e.g. /tf=5)"))?;
    if !controller::telemetry::THINNABLE_TOPICS.contains(&topic) {
        return Err(format!(
            "{topic:?} is not a channel whose rate can change; one of {}",
            controller::telemetry::THINNABLE_TOPICS.join(", ")
        ));
    }
    let n = crate::args::whole_within(0, 10_000)(n)?;
    Ok((topic.to_owned(), u32::try_from(n).unwrap_or(u32::MAX)))
}

impl RecordArgs {
    /// The recording's settings, the level checked against the compression.
    pub(crate) fn settings(&self) -> Result<controller::telemetry::RecordingSettings, FlagError> {
        use controller::telemetry::RecordingCompression as C;
        let compression = match self.record_compression.as_str() {
            "none" => C::None,
            "zstd" => C::Zstd,
            _ => C::Lz4,
        };
        let level = u32::try_from(self.record_level).unwrap_or(u32::MAX);
        if level > compression.max_level() {
            let why = match compression {
                C::None => format!(" {level}: --record-compression none has no level"),
                _ => format!(
                    " {level}: {} takes 0–{}",
                    compression.name(),
                    compression.max_level()
                ),
            };
            return Err(FlagError::new("record-level", why));
        }
        Ok(controller::telemetry::RecordingSettings {
            compression,
            level,
            chunk_bytes: self.record_chunk_kib * 1024,
            every: self.record_every.clone(),
        })
    }

    /// Where --ros2 publishes (and --cmd-vel listens).
    pub(crate) fn ros2_dds(&self) -> Option<dds::DdsConfig> {
        self.ros2.as_ref().map(|interface| dds::DdsConfig {
            domain: u32::try_from(self.ros2_domain).unwrap_or(u32::MAX),
            interface: interface.clone(),
        })
    }
}

/// Arguments of `check`.
#[derive(Debug, Args)]
pub struct CheckArgs {
    #[command(flatten)]
    files: Files,
    /// Also write the clip's quality on the robot model as JSON here (penetration, sliding,
    /// floating, limit and speed margins, torque use, and the problems that refuse it), written
    /// whether or not the clip passes. What `robodeploy-ray check` gathers over a clip library.
    #[arg(long, value_name = "FILE")]
    json: Option<PathBuf>,
}

#[derive(Debug, Args)]
#[command(next_help_heading = "What to run")]
struct Files {
    /// The robot description.
    #[arg(long, default_value_os_t = robots::locate::default_robot())]
    robot: PathBuf,
    /// The policy: a manifest (TOML beside its ONNX file), or an ONNX export whose metadata
    /// carries the contract, as BeyondMimic and mjlab write it (joint_names, gains,
    /// default_joint_pos, action_scale, observation_names, anchor_body_name, body_names): no
    /// manifest needed. A manifest naming such an export may override any of its fields.
    /// Default: the policy robot.toml names (`policy = "policies/…"`).
    #[arg(long)]
    policy: Option<PathBuf>,
    /// The clip. CSV: `time,root_x,root_y,root_z,root_qw,root_qx,root_qy,root_qz,<joints…>` (joints
    /// named as in robot.toml, quaternion w x y z). NPZ: `joint_names`, `joint_pos`, `root_pos`,
    /// `root_quat` (w x y z), `fps` or `time`. Other tools' motion files with a `<name>.motion.toml`
    /// beside them (fps, joints, quaternion order, root body): BeyondMimic/mjlab motion NPZ
    /// (`fps`, `joint_pos`, `body_pos_w`, `body_quat_w` w x y z) and headerless CSV rows of root
    /// x y z, quaternion, joints (the LAFAN1 retargets: `quaternion = "xyzw"`).
    /// Default: the motion the policy's export carries (its `time_step` input and motion
    /// outputs), else robots/biped/clips/squat.csv.
    #[arg(long)]
    clip: Option<PathBuf>,
    /// The frame of the motion the policy's export carries that the run starts from.
    #[arg(long, default_value_t = 0, value_parser = crate::args::whole_within(0, controller::motion::MAX_FRAMES as u64))]
    start_step: u64,
}

impl Files {
    /// The clip file a run names (the export itself when it plays the export's motion).
    fn default_clip() -> PathBuf {
        robots::locate::default_clip()
    }
}

struct Loaded {
    robot: Robot,
    layout: PolicyLayout,
    reference: Reference,
    source: ReferenceSource,
}

fn load(files: &Files) -> Result<Loaded> {
    let robot = Robot::load(&files.robot)?;
    let policy = crate::args::policy_of(files.policy.as_deref(), &robot)?;
    let mut layout = PolicyLayout::load(&policy, &robot)?;
    let (reference, source) = controller::reference::load_reference(
        files.clip.as_deref(),
        &Files::default_clip(),
        &mut layout,
        &robot,
        files.start_step as usize,
    )?;
    Ok(Loaded {
        robot,
        layout,
        reference,
        source,
    })
}

/// Runs `check`.
pub fn check(args: &CheckArgs) -> Result<()> {
    let l = load(&args.files)?;
    println!(
        "robot  {} ({} joints) — {}",
        l.robot.config.name,
        l.robot.config.joints.len(),
        l.robot.path.display()
    );
    if let Some(c) = &l.robot.calibration {
        println!("       calibration merged from {}", c.display());
    }
    print_model(&l.robot)?;
    // The model at its step, settled before anything depends on it.
    let mut unstable = Vec::new();
    for hold in [
        sim2real::stability::Hold::Gantry,
        sim2real::stability::Hold::Start,
    ] {
        let settle = sim2real::stability::settle(&l.robot, hold)?;
        println!("       stability {settle}");
        if !settle.stable() {
            unstable.push(settle.to_string());
        }
    }
    if !unstable.is_empty() {
        // Bad input (exit 2): the model or its step is wrong, as a bad field would be.
        return Err(robots::FileError::new(
            &l.robot.mjcf_path,
            format!(
                "the robot's model is not stable at its physics step:\n  {}",
                unstable.join("\n  ")
            ),
        )
        .into());
    }
    for b in &l.robot.config.buses {
        if let Some(line) = crate::bus::schedule(&l.robot, &b.name) {
            println!("       {:<6} {line}", b.name);
        }
    }
    let start = l.robot.config.start;
    println!(
        "       start: {}",
        describe_start(&l.robot, start.mode, start.pd_s)
    );
    println!("policy {}", l.layout.path.display());
    println!(
        "       {}",
        l.layout
            .manifest
            .description
            .split_whitespace()
            .collect::<Vec<_>>()
            .join(" ")
    );
    println!(
        "       {} Hz, {} actions, observation of {} values:",
        l.layout.manifest.rate_hz,
        crate::args::file_name_of(&l.layout.manifest.action.kind),
        l.layout.obs_len
    );
    print!("{}", l.layout.describe());
    print!("{}", l.layout.describe_action());
    if let Some(a) = &l.layout.manifest.anchor_body {
        println!("       anchor body {a}");
    }
    if !l.layout.manifest.motion_bodies.is_empty() {
        println!(
            "       motion bodies {}",
            l.layout.manifest.motion_bodies.join(", ")
        );
    }
    if let Some(m) = world_terms_note(&l.layout, &l.robot, controller::options::EstimatorKind::Kf) {
        println!("       note: {m}");
    }
    if let Some(spec) = &l.layout.manifest.commands {
        println!("       live commands (play --command, --keyboard, --gamepad, --command-udp):");
        let initial = l.layout.command_values().unwrap_or(&[]);
        let ramps = spec.ramp.clone().unwrap_or_default();
        for (k, ((name, [lo, hi]), kind)) in spec.names.iter().zip(&spec.ranges).zip(spec.kinds()).enumerate()
        {
            println!(
                "         {name:<12} [{lo}, {hi}] ({}), starts at {}, key step {}, ramp {}",
                crate::args::file_name_of(&kind),
                initial.get(k).copied().unwrap_or(0.0),
                spec.steps()[k],
                ramps.get(k).map_or("none".to_owned(), |r| format!("{r}/s"))
            );
        }
        println!(
            "         a silent gamepad or UDP source hands back to the defaults after {} s",
            spec.timeout_s
        );
    }
    match &l.source {
        ReferenceSource::Commands => {
            println!(
                "clip   none: the policy observes no reference; `play` runs it on its commands until stopped"
            );
            println!("ok: nothing moved");
            return Ok(());
        }
        ReferenceSource::Clip(clip) => println!(
            "clip   {}: {:.2} s at {} frames → {} ticks at {} Hz, within every joint and speed limit",
            clip.path.display(),
            clip.duration(),
            clip.times.len(),
            l.reference.len(),
            l.reference.rate_hz
        ),
        source => {
            println!(
                "clip   {source}: {} ticks ({:.2} s) at {} Hz, within every joint and speed limit",
                l.reference.len(),
                l.reference.len() as f64 / l.reference.rate_hz,
                l.reference.rate_hz
            );
            if let Some((body, d, frame)) = controller::motion::worst_body_mismatch(&l.robot, &l.reference)? {
                println!(
                    "       its body poses against the robot's model at its joints: worst {body} {:.2} cm (frame {frame})",
                    100.0 * d
                );
            }
        }
    }
    if !l.reference.held_joints.is_empty() {
        println!(
            "       joints not in the clip, held at the default pose: {}",
            l.reference.held_joints.join(", ")
        );
    }
    let quality = analysis::motion_check::analyze(&l.robot, &l.reference)?;
    println!("clip quality on the robot model:");
    print!("{quality}");
    let problems = quality.problems();
    if let Some(path) = &args.json {
        let json = serde_json::json!({
            "clip": l.source.path().map(|p| p.display().to_string()),
            "quality": quality,
            "problems": problems,
        });
        std::fs::write(path, format!("{json}\n"))
            .with_context(|| format!("--json: cannot write {}", path.display()))?;
    }
    if !problems.is_empty() {
        if l.layout.manifest.reference.feasibility == policy::Feasibility::Report {
            println!(
                "       the robot could not follow this clip exactly ({}); reported, not refused: the \
                 policy tracks kinematic references ({}: [reference] feasibility = \"report\")",
                problems.len(),
                l.layout.path.display()
            );
        } else {
            bail!(
                "{}: the robot should not play this clip:\n  {}",
                l.source,
                problems.join("\n  ")
            );
        }
    }
    println!("ok: nothing moved");
    Ok(())
}

/// What MuJoCo compiled of the robot's model: floor, actuators per joint, sensors, keyframes,
/// and where the mirror's IMU reads.
fn print_model(robot: &Robot) -> Result<()> {
    let m = &robot.mjcf;
    let list = |v: Vec<String>| {
        if v.is_empty() {
            "none".to_owned()
        } else {
            v.join(", ")
        }
    };
    println!(
        "model  {} as MuJoCo compiled it: {} bodies, {} joints, {} meshes; floor: {}",
        robot.mjcf_path.display(),
        m.bodies.len(),
        m.joints.len(),
        m.meshes,
        if m.floor.is_empty() {
            "none — no floor in the model: a robot not held falls through the world, and a run \
             cannot tell whether it fell"
                .to_owned()
        } else {
            list(m.floor.clone())
        }
    );
    let mut kinds = std::collections::BTreeMap::<&str, Vec<&str>>::new();
    let mut bare = Vec::new();
    for j in &robot.config.joints {
        let mut acts = m.actuators_of(&j.mjcf_joint).peekable();
        if acts.peek().is_none() {
            bare.push(j.name.as_str());
        }
        for a in acts {
            kinds.entry(a.kind.name()).or_default().push(j.name.as_str());
        }
    }
    for (kind, joints) in &kinds {
        println!("       {} {kind} actuators: {}", joints.len(), joints.join(", "));
    }
    if !bare.is_empty() {
        println!(
            "       joints without an actuator in the model (the mirror applies the firmware's torque): {}",
            bare.join(", ")
        );
    }
    println!(
        "       sensors: {}",
        list(
            m.sensors
                .iter()
                .map(|s| format!("{} ({})", s.name, s.kind))
                .collect()
        )
    );
    let start = robot.config.start_keyframe.as_deref();
    println!(
        "       keyframes: {}",
        list(
            m.keyframes
                .iter()
                .map(|k| if Some(k.name.as_str()) == start {
                    format!("{} (the mirror's start)", k.name)
                } else {
                    k.name.clone()
                })
                .collect()
        )
    );
    let imu = robot.imu_sensors();
    let named: Vec<String> = robots::IMU_SENSOR_KINDS
        .iter()
        .zip(&imu)
        .map(|((field, _), s)| match s {
            Some(name) => format!("{field} {name}"),
            None => format!("{field} (none on the site: the mirror adds one)"),
        })
        .collect();
    println!(
        "       imu on site {}: {}",
        robot.config.imu.site,
        named.join(", ")
    );
    print_dynamics(robot)?;
    print_actuators(robot);
    print_servo_caps(robot);
    Ok(())
}

/// The law that turns each joint's command into torque in the mirror (robot.toml `[[actuators]]`,
/// the trainer's), with its effort limit and delay.
fn print_actuators(robot: &Robot) {
    let lines = robot.config.joints.iter().filter_map(|j| {
        let bus = robot.bus(&j.bus)?;
        let a = robot.config.actuator_of(&j.name);
        let ours = if robot.config.actuators.is_empty() {
            ""
        } else {
            " (robot.toml)"
        };
        let text = match (a.model, bus.kind) {
            (robots::ActuatorModel::Firmware, robots::BusKind::MitCan) => {
                "firmware: the motor's own PD at its firmware rate".to_string()
            }
            (robots::ActuatorModel::Firmware, _) => "firmware: the servo's own position loop".to_string(),
            (model, _) => {
                let range = robot
                    .mit_model(&j.model)
                    .map_or(f64::INFINITY, |m| m.t_max * j.gear);
                let limit = a.limit(range);
                let curve = match (a.saturation_effort, a.velocity_limit) {
                    (Some(stall), Some(speed)) if model == robots::ActuatorModel::DcMotor => {
                        format!(", torque–speed line {stall} N·m at rest to 0 at {speed} rad/s")
                    }
                    _ => String::new(),
                };
                let [lo, hi] = a.delay_steps;
                let delay = match (lo, hi) {
                    (0, 0) => String::new(),
                    (l, h) if l == h => format!(", delayed {l} physics steps"),
                    (l, h) => format!(", delayed {l}–{h} physics steps (drawn per run)"),
                };
                format!(
                    "{} every physics step, effort limit {limit} N·m{curve}{delay}",
                    model.name()
                )
            }
        };
        Some((format!("actuator{ours}: {text}"), j.name.as_str()))
    });
    print_grouped(lines);
}

/// What each joint may push with and what holds it there: a serial servo's Torque Limit (the
/// joint's `torque_limit`, written by the driver) beside its stall torque and, where the model
/// drives the joint with a `<position>` actuator of its own, that actuator's force range (the
/// mirror caps it at the servo's limit); an MIT-mode motor's range and the bus's bound.
fn print_servo_caps(robot: &Robot) {
    let mut lines: Vec<(String, &str)> = Vec::new();
    for j in &robot.config.joints {
        let Some(bus) = robot.bus(&j.bus) else { continue };
        let stall = match bus.kind {
            robots::BusKind::Dynamixel => robot.dxl_model(&j.model).map(|m| m.stall_torque),
            robots::BusKind::Feetech => robot.feetech_model(&j.model).map(|m| m.stall_torque),
            _ => None,
        };
        let Some(stall) = stall else { continue };
        let model_range = robot
            .mjcf
            .actuators
            .iter()
            .filter(|a| a.joint.as_deref() == Some(j.mjcf_joint.as_str()))
            .filter(|a| matches!(a.kind, robots::mjcf::ActuatorKind::Position { .. }))
            .find_map(|a| a.force_range.map(|(lo, hi)| lo.abs().max(hi.abs())));
        let capped = match model_range {
            Some(r) if r > j.torque_limit => {
                format!("; the model's <position> actuator allows {r} N·m: capped")
            }
            Some(r) => format!("; the model's <position> actuator allows {r} N·m"),
            None => String::new(),
        };
        let text = format!(
            "{} {} N·m (the {}'s stall torque {} N·m × gear {}){capped}",
            j.model, j.torque_limit, j.model, stall, j.gear
        );
        lines.push((format!("servo torque limit: {text}"), j.name.as_str()));
    }
    print_grouped(lines);
    // MIT-mode motors: how the bus holds the joint's limit where it lies below the motor's range
    // (robots::TorqueHold); Robstride motors also hold it in their own limit_torque.
    let mut lines: Vec<(String, &str)> = Vec::new();
    for j in &robot.config.joints {
        if robot
            .bus(&j.bus)
            .is_none_or(|b| b.kind != robots::BusKind::MitCan)
        {
            continue;
        }
        let Some(motor) = robot.mit_model(&j.model) else {
            continue;
        };
        let range = motor.t_max * j.gear;
        let written = if motor.family == firmware_bridge::mit::models::MotorFamily::Robstride {
            ", written to its limit_torque"
        } else {
            ""
        };
        let text = match robot.torque_hold(j) {
            robots::TorqueHold::MotorRange => {
                format!("{} {} N·m: the motor's own range", j.model, j.torque_limit)
            }
            robots::TorqueHold::ClipAtMeasurement(l) => format!(
                "{} {l} N·m of the motor's {range} N·m: each bus cycle clips the torque at the measured \
                 state, as the trainer's {} law clipped it every physics step{written}",
                j.model,
                robot.config.actuator_of(&j.name).model.name()
            ),
            robots::TorqueHold::OverCycle(l) => format!(
                "{} {l} N·m of the motor's {range} N·m: every command bounded over its bus cycle{written}",
                j.model
            ),
        };
        lines.push((format!("motor torque limit: {text}"), j.name.as_str()));
    }
    print_grouped(lines);
}

/// The physics and the joints' dynamics as the mirror and the motion check compile them: the
/// model's own, or robot.toml's `[sim]` and `[[joint_dynamics]]` where it sets them.
fn print_dynamics(robot: &Robot) -> Result<()> {
    let model = robot.model()?;
    let opt = model.opt();
    let integrator = robots::Integrator::of_mujoco(opt.integrator).map_or("another integrator", |i| i.name());
    let from = if robot.config.sim.is_default() {
        "the model's"
    } else {
        "robot.toml [sim] over the model's"
    };
    println!(
        "       physics: {} ms step, {integrator}, {} solver iterations ({from}); {} steps per policy tick",
        1000.0 * opt.timestep,
        opt.iterations,
        ((1.0 / robot.config.control_rate_hz) / opt.timestep).round()
    );
    println!(
        "       contacts: {} solver, {} friction cones, impratio {}",
        robots::mjcf::solver_name(opt.solver),
        robots::mjcf::cone_name(opt.cone),
        opt.impratio
    );
    // Joints grouped by their compiled armature, friction loss and damping.
    let index = sim2real::model_index::ModelIndex::of_robot(&model, robot)?;
    let lines = robot.config.joints.iter().zip(&index.joints).map(|(j, ids)| {
        let d = ids.dof;
        let ours = robot.config.joint_dynamics_of(&j.name) != robots::JointDynamicsOf::default();
        let text = format!(
            "joint dynamics{}: armature {} kg·m², frictionloss {} N·m, damping {} N·m·s/rad",
            if ours { " (robot.toml)" } else { "" },
            model.dof_armature()[d],
            model.dof_frictionloss()[d],
            model.dof_damping()[d]
        );
        (text, j.name.as_str())
    });
    print_grouped(lines);
    Ok(())
}

/// Prints one line per distinct text, naming the joints that share it, in first-seen order.
fn print_grouped<'a>(lines: impl IntoIterator<Item = (String, &'a str)>) {
    let mut groups: Vec<(String, Vec<&str>)> = Vec::new();
    for (text, joint) in lines {
        match groups.iter_mut().find(|(t, _)| *t == text) {
            Some((_, joints)) => joints.push(joint),
            None => groups.push((text, vec![joint])),
        }
    }
    for (text, joints) in groups {
        println!("       {text} — {}", joints.join(", "));
    }
}

/// Adds the recorder, the e-stop and the live commands a run asked for.
fn with_estop<L: RobotLink>(
    player: Player<L>,
    args: &PlayArgs,
    options: &PlayOptions,
    source: &ReferenceSource,
    commands: Option<human::commands::CommandReader>,
    viewer: Option<std::sync::mpsc::SyncSender<[f64; 6]>>,
) -> Result<Player<L>> {
    let mut player = with_recorder(player, args, options, source, viewer)?;
    let keyboard = commands.is_some() && args.live.keyboard;
    if let Some(reader) = commands {
        player = player.with_commands(reader)?;
    }
    player = with_lowered_word(player, args, keyboard)?;
    let Some(addr) = args.estop_udp else {
        return Ok(player);
    };
    let (flag, local) =
        controller::estop::listen(addr).with_context(|| format!("cannot listen for the e-stop on {addr}"))?;
    println!("e-stop: send ESTOP to udp://{local}");
    Ok(player.with_estop(flag))
}

/// A harness start on the hardware (or rehearsed with `--lowered-udp`) waits for the operator's
/// word that the robot stands on its feet: `LOWERED` over UDP, or Enter on the console.
fn with_lowered_word<L: RobotLink>(player: Player<L>, args: &PlayArgs, keyboard: bool) -> Result<Player<L>> {
    use std::io::IsTerminal as _;
    if player.harness_phase() == controller::player::HarnessPhase::None {
        // `play` refused --lowered-udp for such a run already.
        return Ok(player);
    }
    if let Some(addr) = args.lowered_udp {
        let (flag, local) = controller::estop::listen_for(addr, "LOWERED", "lowered")
            .with_context(|| format!("--lowered-udp: cannot listen on {addr}"))?;
        println!("harness: when the robot stands on its feet, send LOWERED to udp://{local}");
        return Ok(player.with_lowered_signal(flag));
    }
    if !args.hardware {
        // The mirror's harness lowers the robot by itself.
        return Ok(player);
    }
    if keyboard || !std::io::stdin().is_terminal() {
        bail!(
            "--start harness on the hardware waits for the operator's word that the robot stands on its feet: \
             press Enter on a terminal (not while --keyboard reads it), or give --lowered-udp ADDR"
        );
    }
    let flag = Arc::new(AtomicBool::new(false));
    let set = Arc::clone(&flag);
    std::thread::Builder::new()
        .name("lowered-console".into())
        .spawn(move || {
            let mut line = String::new();
            if std::io::stdin().read_line(&mut line).is_ok_and(|n| n > 0) {
                set.store(true, Ordering::Relaxed);
            }
        })
        .context("cannot start the console thread")?;
    println!("harness: lower the robot onto its feet with the crane, then press Enter here");
    Ok(player.with_lowered_signal(flag))
}

fn with_recorder<L: RobotLink>(
    player: Player<L>,
    args: &PlayArgs,
    options: &PlayOptions,
    source: &ReferenceSource,
    viewer: Option<std::sync::mpsc::SyncSender<[f64; 6]>>,
) -> Result<Player<L>> {
    let policy = crate::args::policy_of(args.files.policy.as_deref(), player.robot())?;
    let stem = source
        .path()
        .unwrap_or(&policy)
        .file_stem()
        .map_or("run".into(), |s| s.to_string_lossy().into_owned());
    let absolute = |p: &PathBuf| std::fs::canonicalize(p).unwrap_or_else(|_| p.clone());
    let run = controller::options::RunMetadata {
        robot: absolute(&args.files.robot),
        policy: absolute(&policy),
        // What the run played: the clip, the export's own motion, a generator, or nothing
        // (commands).
        clip: match source {
            ReferenceSource::Generated(_) => None,
            s => s.path().map(|p| absolute(&p.to_path_buf())),
        },
        command: args.command.clone(),
        command_source: args.live.source(),
        generator: args.generator.generator.as_ref().map(absolute),
        keypoints: args.keypoints.source().map(|k| k.map_paths(absolute)),
        options: *options,
        forced: args.force.clone(),
        recorded_in: None,
    };
    record(player, &args.rec, run, &stem, args.wall || args.hardware, viewer)
}

/// Adds a recorder (and a live view) as `rec` asks to `player`, whose run `run` describes; the
/// default recording is `out/runs/ROBOT-STEM.mcap` or the next free name. Real-time runs drop
/// records rather than wait for the disk.
pub(crate) fn record<L: RobotLink>(
    mut player: Player<L>,
    rec: &RecordArgs,
    run: controller::options::RunMetadata,
    stem: &str,
    real_time: bool,
    viewer: Option<std::sync::mpsc::SyncSender<[f64; 6]>>,
) -> Result<Player<L>> {
    if rec.no_record {
        return Ok(player);
    }
    let bus_cycles = if rec.record_bus_rate {
        anyhow::ensure!(
            player.record_bus_cycles(),
            "--record-bus-rate: this run has no bus cycles to record"
        );
        let robot = player.robot();
        Some(
            player
                .link()
                .bus_names()
                .iter()
                .map(|b| robot.joints_on(b).map(|(i, _)| i).collect())
                .collect(),
        )
    } else {
        None
    };
    let info = controller::telemetry::RecordingInfo {
        run: Some(run),
        bus_cycles,
        commit: Some(env!("ROBODEPLOY_COMMIT").to_owned()),
        ..player.recording_info()
    };
    let robot = player.robot_name().to_owned();
    let sink = start_recording(rec, info, &robot, stem, real_time, player.stop_flag(), viewer)?;
    Ok(match sink {
        Some(sink) => player.with_telemetry(sink),
        None => player,
    })
}

/// The recording (and live view) `rec` asks for, of a run of `robot` that `info` describes (its
/// clock is set here from `real_time`); none with `--no-record`. The default file is
/// `out/runs/ROBOT-STEM.mcap` or the next free name. With `--live-wait`, waits for a viewer
/// (or `stop`) before returning.
pub(crate) fn start_recording(
    rec: &RecordArgs,
    info: controller::telemetry::RecordingInfo,
    robot: &str,
    stem: &str,
    real_time: bool,
    stop: &AtomicBool,
    viewer: Option<std::sync::mpsc::SyncSender<[f64; 6]>>,
) -> Result<Option<TelemetrySink>> {
    if rec.no_record {
        return Ok(None);
    }
    let settings = rec.settings()?;
    let (path, claimed) = match &rec.record {
        Some(p) => {
            if let Some(dir) = p.parent().filter(|d| !d.as_os_str().is_empty()) {
                std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
            }
            // Locked for the length of the run, like the default names: two runs given one path
            // would write one file at once and leave it corrupt.
            let file = std::fs::OpenOptions::new()
                .write(true)
                .create(true)
                .truncate(false)
                .open(p)
                .with_context(|| format!("cannot open {}", p.display()))?;
            if file.try_lock().is_err() {
                return Err(FlagError::new(
                    "record",
                    format!(
                        " {}: another run is recording into it now; give another path",
                        p.display()
                    ),
                )
                .into());
            }
            if !rec.overwrite && holds_a_recording(p) {
                return Err(FlagError::new(
                    "record",
                    format!(
                        " {}: a recording is there already; give another path, or --overwrite",
                        p.display()
                    ),
                )
                .into());
            }
            if file.metadata().is_ok_and(|m| m.is_file()) {
                file.set_len(0)
                    .with_context(|| format!("cannot empty {}", p.display()))?;
            }
            (p.clone(), Some(file))
        }
        None => {
            let (path, file) = claim(Path::new("out/runs"), &format!("{robot}-{stem}"))?;
            (path, Some(file))
        }
    };
    let backpressure = if real_time {
        Backpressure::Drop
    } else {
        Backpressure::Block
    };
    let live = match rec.live_view {
        Some(addr) => {
            // What the run is, for the viewer's Parameters panel: the recording's own records.
            let mut about = vec![
                (
                    "robodeploy/version".to_owned(),
                    env!("CARGO_PKG_VERSION").to_owned(),
                ),
                (
                    "robodeploy/commit".to_owned(),
                    info.commit.clone().unwrap_or_else(|| "unknown".to_owned()),
                ),
                ("run/robot_name".to_owned(), robot.to_owned()),
            ];
            if let Some(run) = &info.run {
                let file = |p: &Path| p.display().to_string();
                about.push(("run/robot".to_owned(), file(&run.robot)));
                about.push(("run/policy".to_owned(), file(&run.policy)));
                if let Some(clip) = &run.clip {
                    about.push(("run/clip".to_owned(), file(clip)));
                }
            }
            Some(Arc::new(viewers::live::LiveView::serve_about(
                addr,
                &format!("robodeploy: {robot}"),
                about,
                viewer,
            )?))
        }
        None => None,
    };
    let info = controller::telemetry::RecordingInfo {
        live: live.clone(),
        ros2: rec.ros2_dds().map(|dds| controller::telemetry::Ros2Config {
            dds,
            robot: robot.to_owned(),
        }),
        clock: if real_time {
            controller::telemetry::RecordingClock::WallClock
        } else {
            controller::telemetry::RecordingClock::Simulated
        },
        settings,
        ..info
    };
    let sink = match claimed {
        Some(file) => TelemetrySink::start_in(file, &path, 1024, backpressure, &info)?,
        None => TelemetrySink::start(&path, 1024, backpressure, &info)?,
    };
    if let Some(live) = &live {
        // The channels are up: a viewer can subscribe before the robot starts.
        println!(
            "live: {} (Foxglove: Open connection → Foxglove WebSocket)",
            live.url()
        );
        if rec.live_wait > 0 {
            println!(
                "live: waiting up to {} s for a viewer (Ctrl-C to stop)",
                rec.live_wait
            );
            let seen = live.wait_for_viewer(std::time::Duration::from_secs(rec.live_wait), stop);
            println!(
                "live: {}",
                if seen {
                    "a viewer subscribed; starting"
                } else {
                    "no viewer; starting anyway"
                }
            );
        }
    }
    Ok(Some(sink))
}

/// Which terms of `layout` read the robot's place in the world, and where it comes from.
fn world_terms_note(
    layout: &PolicyLayout,
    robot: &Robot,
    estimator: controller::options::EstimatorKind,
) -> Option<String> {
    let terms: Vec<&str> = layout
        .slots
        .iter()
        .filter(|s| s.term.needs_ground_truth())
        .map(|s| s.term.name())
        .collect();
    (!terms.is_empty()).then(|| {
        let source = if estimator == controller::options::EstimatorKind::GroundTruth {
            "the mirror's ground truth (--estimator ground-truth)".to_owned()
        } else if robot.config.feet.is_empty() {
            "nothing: the robot names no feet for the estimator's leg kinematics".to_owned()
        } else {
            "the state estimator (IMU and leg kinematics)".to_owned()
        };
        format!(
            "{} read{} the robot's place in the world: from {source}",
            terms.join(", "),
            if terms.len() == 1 { "s" } else { "" }
        )
    })
}

/// What a run plays, for its first line.
fn what_plays(l: &Loaded) -> String {
    match &l.source {
        ReferenceSource::Commands | ReferenceSource::Generated(_) => {
            format!("{} until stopped (Ctrl-C)", l.source)
        }
        source => format!("{source} ({} ticks)", l.reference.len()),
    }
}

/// Silent cycles tolerated by default over a mirror served on this machine: its socket and
/// pseudo-terminal threads share the cores with the loop and answer 10–20 ms late now and then.
const WALL_STALE_CYCLES: u32 = 8;

/// What runs first on each bus thread: real-time set-up with `--realtime`.
fn bus_threads(realtime: bool) -> fn() {
    if realtime {
        controller::realtime::bus_thread
    } else {
        || {}
    }
}

/// Runs `play`.
pub fn play(args: &PlayArgs) -> Result<std::process::ExitCode> {
    args.rec.settings()?;
    let mut l = load(&args.files)?;
    // A command-driven policy plays no clip: nothing ends for --end to act on.
    if matches!(l.source, ReferenceSource::Commands) && args.end != crate::args::EndArg::Hold {
        let end = clap::ValueEnum::to_possible_value(&args.end)
            .map_or_else(String::new, |v| v.get_name().to_owned());
        return Err(FlagError::new(
            "end",
            format!(
                " {end}: this run plays no clip (a command-driven policy runs on its commands until stopped); \
                 what the robot does when stopped is --on-stop's"
            ),
        )
        .into());
    }
    // What check refuses, play refuses before anything moves, unless forced for a reason.
    if let ReferenceSource::Clip(_) = &l.source
        && l.layout.manifest.reference.feasibility == policy::Feasibility::Refuse
    {
        let problems = analysis::motion_check::analyze(&l.robot, &l.reference)?.problems();
        match (&args.force, problems.is_empty()) {
            (_, true) => {}
            (Some(reason), false) => println!(
                "{}: check refuses this clip ({}); played anyway, forced: {reason}",
                l.source,
                problems.join("; ")
            ),
            (None, false) => {
                return Err(FlagError::new(
                    "force",
                    format!(
                        ": {}: the robot should not play this clip (`check` says the same):\n  {}\n\
                         nothing moved; --force REASON plays it anyway and records why",
                        l.source,
                        problems.join("\n  ")
                    ),
                )
                .into());
            }
        }
    }
    if let Some(c) = &l.robot.calibration {
        println!("{}: calibration merged from {}", l.robot.config.name, c.display());
    }
    let generator = load_generator(&args.generator, &mut l)?;
    load_keypoint_references(&args.keypoints, &mut l)?;
    if let Some(values) = &args.command {
        l.layout.set_command(values).with_context(|| {
            let given: Vec<String> = values.iter().map(f64::to_string).collect();
            format!("--command {}", given.join(","))
        })?;
    }
    let rate = l.layout.manifest.rate_hz;
    let max_ticks = match args.max_seconds {
        Some(s) if s.is_finite() && s > 0.0 => Some((s * rate).round() as u64),
        Some(s) => return Err(FlagError::new("max-seconds", format!(" {s} is not a duration")).into()),
        None => None,
    };
    if let Some(iface) = &args.rec.ros2
        && let Err(e) = dds::interface_addresses(iface)
    {
        return Err(FlagError::new("ros2", format!(": {e}")).into());
    }
    if let (Some(estop), Some(lowered)) = (args.estop_udp, args.lowered_udp)
        && estop == lowered
    {
        return Err(FlagError::new(
            "lowered-udp",
            format!(" {lowered} is --estop-udp's address too: each listens on a port of its own"),
        )
        .into());
    }
    if args.stand_for.is_some() && args.on_stop != crate::args::OnStopArg::Stay {
        let on_stop = clap::ValueEnum::to_possible_value(&args.on_stop)
            .map_or_else(String::new, |v| v.get_name().to_owned());
        return Err(FlagError::new(
            "stand-for",
            format!(": only with --on-stop stay (this run's soft stop ends in --on-stop {on_stop}, which stands not at all)"),
        )
        .into());
    }
    if args.hardware && args.estimator == crate::args::EstimatorArg::GroundTruth {
        return Err(FlagError::new(
            "estimator",
            " ground-truth: the hardware has no ground truth; it runs the estimator (kf, invariant or linear)",
        )
        .into());
    }
    let mut options = PlayOptions {
        estimator: args.estimator.into(),
        start_step: args.files.start_step as usize,
        ramp_s: args.ramp,
        end: args.end.into(),
        on_stop: args.on_stop.into(),
        settle_s: args.settle,
        stand_s: args.stand_for,
        sit_s: args.sit_seconds,
        max_ticks,
        limits: controller::safety::SafetyLimits {
            stale_cycles: args.stale_cycles.map_or(
                if args.wall {
                    WALL_STALE_CYCLES
                } else {
                    robot_link::STALE_CYCLES
                },
                |c| c as u32,
            ),
            ..Default::default()
        },
        ..PlayOptions::default()
    }
    .resolved_for(&l.robot);
    if let Some(start) = args.start {
        options.start = Some(start.into());
    }
    if args.lowered_udp.is_some() && options.start_mode(&l.robot) != robots::StartMode::Harness {
        return Err(controller::player::PlayError::Setup(
            "--lowered-udp: this run does not start in a harness (--start harness, or robot.toml [start] mode = \"harness\")"
                .into(),
        )
        .into());
    }
    if options.start_mode(&l.robot) == robots::StartMode::Harness && args.gantry {
        let harness = if args.start.is_some() {
            "--start harness"
        } else {
            "robot.toml's [start] mode = \"harness\" (--start pd or --start policy overrides it)"
        };
        return Err(controller::player::PlayError::Setup(format!(
            "{harness} with --gantry: the robot hangs in the harness or sits on the gantry, not both"
        ))
        .into());
    }
    println!(
        "start: {}",
        describe_start(&l.robot, options.start_mode(&l.robot), options.soft_start_s)
    );
    if args.realtime {
        let cpus = std::thread::available_parallelism().map_or(1, std::num::NonZero::get);
        for step in controller::realtime::setup(80, Some(cpus - 1)).steps {
            eprintln!("realtime: {step}");
        }
    }
    let stop = Arc::new(AtomicBool::new(false));
    for signal in [signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM] {
        signal_hook::flag::register(signal, Arc::clone(&stop))
            .context("cannot install the stop signal handlers")?;
    }
    if matches!(l.source, ReferenceSource::Commands) {
        // Nothing ends a command-driven run but the operator (Ctrl-C, the e-stop) or
        // --max-seconds: the robot stands on its commands until then.
        options.end = controller::player::EndMode::Stand;
    }
    if generator.is_some() {
        // A generator's motion has no end: the run goes on until stopped.
        options.end = controller::player::EndMode::Loop;
    }
    let initial = l.layout.command_values().unwrap_or(&[]).to_vec();
    let commands = crate::commands::start(
        &args.live,
        l.layout.manifest.commands.as_ref(),
        &initial,
        args.rec.ros2_dds().as_ref(),
    )?;
    let (reader, command_source) = commands.map_or((None, None), |(r, s)| (Some(r), Some(s)));
    let viewer = command_source.as_ref().and_then(|s| s.viewer.clone());
    if args.hardware {
        if l.robot.config.feet.is_empty()
            && let Some(m) = world_terms_note(&l.layout, &l.robot, options.estimator)
        {
            bail!("{}: {m}", l.layout.path.display());
        }
        println!("{}: {} on the hardware", l.robot.config.name, what_plays(&l));
        let io = robot_link::hardware::open_with(&l.robot, bus_threads(args.realtime))?;
        let mut clock = robot_link::WallClock::start();
        let player = with_estop(
            Player::new(l.robot, l.layout, l.reference, options, io, stop)?,
            args,
            &options,
            &l.source,
            reader,
            viewer.clone(),
        )?;
        let mut summary = run_with(player, &mut clock, generator)?;
        summary.command_sources = command_source.map(|s| s.stats.to_string());
        print!("{summary}");
        return Ok(finish(&summary));
    }
    let mut config = match &args.mirror {
        Some(p) => load_mirror_config(p, &l.robot)?,
        None => sim2real::config::MirrorConfig::default(),
    };
    config.gantry |= args.gantry;
    if let Some(f) = args.fidelity {
        config.fidelity = f.into();
    }
    let direct = config.fidelity == sim2real::config::Fidelity::Direct;
    if direct && args.wall {
        return Err(FlagError::new(
            "wall",
            ": a mirror of direct fidelity has no wires to run in real time behind (drop --fidelity direct or the mirror file's fidelity = \"direct\")",
        )
        .into());
    }
    if let Some(m) = world_terms_note(&l.layout, &l.robot, options.estimator) {
        eprintln!("note: {m}");
    }
    // The wires a served mirror puts its buses on, by kind.
    let wires = {
        let mut w: Vec<&str> = Vec::new();
        for b in &l.robot.config.buses {
            let wire = match b.kind {
                robots::BusKind::MitCan => "socketcand",
                robots::BusKind::UnitreeDds => "DDS",
                _ => "pseudo-terminals",
            };
            if !w.contains(&wire) {
                w.push(wire);
            }
        }
        w.join(", ")
    };
    println!(
        "{}: {} on the mirror{}",
        l.robot.config.name,
        what_plays(&l),
        if args.wall {
            format!(" in real time over {wires}")
        } else if direct {
            " in lockstep, direct: the trainer's actuator law on MuJoCo, no buses".to_owned()
        } else {
            " in lockstep".to_owned()
        }
    );
    // What MuJoCo itself holds, beside the run's peak: what a run holds beyond a bare loop.
    let mujoco_bytes: Option<usize>;
    let summary: PlaySummary = if args.wall {
        let (player, mut clock, served) = wired_player(
            l.robot,
            l.layout,
            l.reference,
            options,
            config,
            stop,
            bus_threads(args.realtime),
        )?;
        let player = with_estop(player, args, &options, &l.source, reader, viewer.clone())?;
        let summary = run_with(player, &mut clock, generator)?;
        mujoco_bytes = Some(mujoco_bytes_of(&served.world));
        summary
    } else {
        // Lockstep runs as fast as it computes, with nothing to watch: their progress is shown.
        let total = options.max_ticks.or_else(|| {
            let finite = matches!(
                options.end,
                controller::player::EndMode::Hold | controller::player::EndMode::Blend
            );
            // The start ramp, the reference, its end, the soft stop's settling and the damping.
            let hold = options.ramp_s.unwrap_or_else(|| l.layout.hold_s());
            let seconds = hold + options.end_s + options.settle_s + options.damping_s;
            (finite && generator.is_none())
                .then(|| l.reference.len() as u64 + (seconds * l.layout.manifest.rate_hz).round() as u64)
        });
        let ticks = Arc::new(std::sync::atomic::AtomicU64::new(0));
        let _progress = crate::console::Watch::start(
            Arc::clone(&ticks),
            crate::console::Progress::new("play", "ticks", total),
        );
        if direct {
            let (player, mut clock, world) =
                direct_player(l.robot, l.layout, l.reference, options, config, stop)?;
            let player = with_estop(player, args, &options, &l.source, reader, viewer.clone())?;
            let summary = run_with(player.with_progress(ticks), &mut clock, generator)?;
            mujoco_bytes = Some(mujoco_bytes_of(&world));
            summary
        } else {
            let (player, mut clock, world) =
                lockstep_player(l.robot, l.layout, l.reference, options, config, stop)?;
            let player = with_estop(player, args, &options, &l.source, reader, viewer.clone())?;
            let summary = run_with(player.with_progress(ticks), &mut clock, generator)?;
            mujoco_bytes = Some(mujoco_bytes_of(&world));
            summary
        }
    };
    let mut summary = summary;
    summary.command_sources = command_source.map(|s| s.stats.to_string());
    print!("{summary}");
    print_memory(mujoco_bytes);
    if let (Some(dir), Some(t)) = (&args.report, &summary.telemetry) {
        let r = analysis::report::write_report(&t.path, dir)?;
        let headline = match &r.locomotion {
            Some(l) => format!("{:.2} m travelled", l.distance_m),
            None => format!("joint RMSE {:.2}°", r.joints_rmse_deg),
        };
        println!("report: {} ({headline})", dir.join("report.html").display());
    }
    Ok(finish(&summary))
}

/// What MuJoCo holds for a run's mirror.
fn mujoco_bytes_of(world: &std::sync::Mutex<sim2real::mirror::Mirror>) -> usize {
    world
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner)
        .mujoco_bytes()
}

/// The run's peak resident memory (`VmHWM`), and how much of it MuJoCo's model and data are: what
/// the run holds beyond a bare MuJoCo loop of the same model.
fn print_memory(mujoco_bytes: Option<usize>) {
    let peak_kib = std::fs::read_to_string("/proc/self/status").ok().and_then(|s| {
        s.lines()
            .find_map(|l| l.strip_prefix("VmHWM:"))
            .and_then(|v| v.split_whitespace().next()?.parse::<u64>().ok())
    });
    let mib = |bytes: f64| bytes / (1024.0 * 1024.0);
    match (peak_kib, mujoco_bytes) {
        (Some(peak), Some(mj)) => println!(
            "memory: peak {:.0} MiB resident; MuJoCo's model and data {:.0} MiB of it",
            mib(peak as f64 * 1024.0),
            mib(mj as f64)
        ),
        (Some(peak), None) => println!("memory: peak {:.0} MiB resident", mib(peak as f64 * 1024.0)),
        _ => {}
    }
}

/// How a run's start reads: the mode and what it does, in the robot's figures.
fn describe_start(robot: &Robot, mode: robots::StartMode, pd_s: f64) -> String {
    let h = robot.config.start.harness;
    match mode {
        robots::StartMode::Harness => format!(
            "harness — the policy in control from the first tick; the robot hangs {:.0} cm above the \
             floor, is lowered over {} s and stands {} s on the reference's first frame before it plays",
            100.0 * h.lift_m,
            h.lower_s,
            h.settle_s
        ),
        robots::StartMode::Policy => "policy — in control from the first tick, on the floor".to_owned(),
        robots::StartMode::Pd => format!(
            "pd — the joints' PD brings the robot to the default pose over {pd_s} s (gains from {:.0} %), \
             then the policy takes over",
            100.0 * robot.config.start.pd_gain
        ),
    }
}

/// Whether `path` holds a recording worth keeping: a file with at least one message, or any
/// other file with something in it (not ours to judge). An empty file, or the header of a run
/// that failed before its first tick, is not.
fn holds_a_recording(path: &Path) -> bool {
    match std::fs::metadata(path) {
        // Devices and pipes are not recordings (and reading one may never end).
        Ok(m) if !m.is_file() || m.len() == 0 => return false,
        // A header and the run's files take a few hundred kilobytes at most.
        Ok(m) if m.len() > 4 << 20 => return true,
        Ok(_) => {}
        Err(_) => return false,
    }
    let Ok(bytes) = std::fs::read(path) else {
        return false;
    };
    let mut messages = 0usize;
    match analysis::recording::for_each_message(&bytes, |_| {
        messages += 1;
        Ok(())
    }) {
        Ok(_) => messages > 0,
        // Cut before its first message.
        Err(analysis::recording::RecordingError::Cut(_)) => false,
        // Not a recording we can read (another kind of file, damage): kept.
        Err(_) => true,
    }
}

/// A recording file this run alone writes: `DIR/STEM.mcap`, or `STEM-2.mcap`, … when another run
/// is writing it (each run holds an exclusive lock on its file until it ends), emptied for this run.
fn claim(dir: &Path, stem: &str) -> Result<(PathBuf, std::fs::File)> {
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    for n in 1..10_000u32 {
        let name = if n == 1 {
            format!("{stem}.mcap")
        } else {
            format!("{stem}-{n}.mcap")
        };
        let path = dir.join(name);
        // A new file or the next name: an earlier run's recording is never overwritten, and two
        // runs starting at once cannot both take a name (the create is atomic).
        match std::fs::OpenOptions::new()
            .write(true)
            .create_new(true)
            .open(&path)
        {
            Ok(file) => {
                file.try_lock()
                    .map_err(|e| anyhow::anyhow!("{e}"))
                    .with_context(|| format!("cannot lock {}", path.display()))?;
                return Ok((path, file));
            }
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => {}
            Err(e) => return Err(e).with_context(|| format!("cannot create {}", path.display())),
        }
    }
    bail!(
        "{}: ten thousand recordings of {stem} already; move some away",
        dir.display()
    )
}

/// Prints how the run ended, last, and returns the exit status that says so.
pub fn finish(summary: &PlaySummary) -> std::process::ExitCode {
    let outcome = summary.outcome();
    match (&summary.telemetry_error, outcome) {
        (Some(e), controller::metrics::RunOutcome::Finished) => {
            println!("result: finished, but the recording failed: {e}");
            std::process::ExitCode::from(crate::exit::IO_FAILURE)
        }
        (None, controller::metrics::RunOutcome::Finished) if summary.shortfall().is_some() => {
            println!(
                "result: finished, but {}",
                summary.shortfall().unwrap_or_default()
            );
            std::process::ExitCode::from(crate::exit::FAILED)
        }
        _ => {
            println!("result: {outcome}");
            crate::exit::of_outcome(&outcome)
        }
    }
}
