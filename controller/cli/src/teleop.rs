//! `robodeploy teleop` and `robodeploy vr send`: drive the robot live from VR trackers (VMC over
//! UDP), and stream a recorded session as such a tracker.

use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::atomic::AtomicBool;
use std::sync::{Arc, Mutex};

use anyhow::{Context, Result, bail};

use crate::args::FlagError;
use clap::{Args, Subcommand};
use controller::clip::Reference;
use controller::player::{EndMode, PlayOptions, Player};
use human::teleop::{Teleop, TeleopOptions, TeleopStatus};
use human::vmc::{Resampler, Serials, VMC_PORT, VmcReceiver};
use human::vr_send::{SendOptions, send};
use motion::bvh::Bvh;
use policy::{PolicyLayout, Term};
use robots::Robot;
use sim2real::mirror::Mirror;

use crate::sim::load_mirror_config;

/// Arguments of `teleop`.
#[derive(Debug, Args)]
pub struct TeleopArgs {
    /// The robot description (its [retarget] section pairs the user's head and hands with robot frames).
    #[arg(long, default_value_os_t = robots::locate::default_robot())]
    robot: PathBuf,
    /// A reference-tracking policy (its reference comes live from the trackers).
    /// Default: the policy robot.toml names (`policy = "policies/…"`).
    #[arg(long)]
    policy: Option<PathBuf>,
    /// Where to listen for VMC (OSC over UDP). Loopback unless you name another address.
    #[arg(long, default_value_t = SocketAddr::from(([127, 0, 0, 1], VMC_PORT)))]
    listen: SocketAddr,
    /// Serial of the left controller (default: any serial containing "left").
    #[arg(long)]
    left_serial: Option<String>,
    /// Serial of the right controller (default: any serial containing "right").
    #[arg(long)]
    right_serial: Option<String>,
    /// Serial of the left foot tracker, with `--body five-point` (default: any tracker serial
    /// containing "left").
    #[arg(long)]
    left_foot_serial: Option<String>,
    /// Serial of the right foot tracker (default: any tracker serial containing "right").
    #[arg(long)]
    right_foot_serial: Option<String>,
    /// Only the headset: the arms stay in the standby pose.
    #[arg(long, conflicts_with = "body")]
    headset_only: bool,
    /// What the operator wears. `devices`: a headset and two controllers; the head and hands
    /// drive the arms and head, the legs stand (a reference follower). `five-point`: those and a
    /// tracker on each foot; the feet where the trackers are, the rest of the body estimated
    /// (pelvis under the head within the legs' reach, arms by two-bone IK) and retargeted whole,
    /// for a general tracker. `full`: the whole skeleton's bones (a motion-capture suit) are
    /// retargeted onto the robot frame by frame (robot.toml's [retarget] map, as `retarget` does
    /// offline), root and every joint, for a general tracker such as TWIST2. For `five-point`
    /// and `full` the T-pose calibrates the map on the operator, and devices or bodies not sent
    /// are named.
    #[arg(long, value_enum, default_value_t = crate::args::BodyArg::Devices)]
    body: crate::args::BodyArg,
    /// Seconds the user holds the T-pose at the start.
    #[arg(long, default_value_t = 0.5, value_parser = crate::args::within(0.1, 60.0))]
    tpose: f64,
    /// Seconds without tracker data after which the stream counts as lost.
    #[arg(long, default_value_t = 0.5, value_parser = crate::args::within(0.02, 60.0))]
    lost_after: f64,
    /// Seconds to blend back to the standby pose after a loss.
    #[arg(long, default_value_t = 1.0, value_parser = crate::args::within(0.0, 60.0))]
    blend: f64,
    /// Stop (softly) after this many seconds; otherwise Ctrl-C.
    #[arg(long, value_parser = crate::args::within(0.02, 86_400.0))]
    max_seconds: Option<f64>,
    /// Run on the robot's own buses instead of the mirror.
    #[arg(long)]
    hardware: bool,
    /// Mirror settings (TOML).
    #[arg(long, conflicts_with = "hardware")]
    mirror: Option<PathBuf>,
    #[command(flatten)]
    rec: crate::play::RecordArgs,
}

/// `vr` subcommands.
#[derive(Debug, Subcommand)]
pub enum VrCommand {
    /// Stream a BVH recording as a VR user: headset and controllers synthesised from its head and
    /// hands (fixed device offsets, noise), or with `--body full` the whole skeleton's bones as a
    /// motion-capture suit sends them, as VMC over UDP at a headset's rate, starting with the
    /// recording's first frame held as the T-pose.
    Send(SendArgs),
}

/// Arguments of `vr send`.
#[derive(Debug, Args)]
pub struct SendArgs {
    /// The recording (its first frame should be a T-pose: CMU trials are).
    #[arg(long)]
    bvh: PathBuf,
    /// Where to send.
    #[arg(long, default_value_t = SocketAddr::from(([127, 0, 0, 1], VMC_PORT)))]
    to: SocketAddr,
    /// Packets per second.
    #[arg(long, default_value_t = 72.0, value_parser = crate::args::within(1.0, 1000.0))]
    rate: f64,
    /// Seconds the T-pose is held first.
    #[arg(long, default_value_t = 1.5, value_parser = crate::args::within(0.0, 60.0))]
    tpose: f64,
    /// First frame of the motion after the T-pose.
    #[arg(long, default_value_t = 1, value_parser = crate::args::frame_index)]
    start_frame: usize,
    /// Stop after this many seconds (T-pose included).
    #[arg(long, value_parser = crate::args::within(0.01, 86_400.0))]
    seconds: Option<f64>,
    /// Position noise (standard deviation), mm.
    #[arg(long, default_value_t = 2.0, value_parser = crate::args::within(0.0, 100.0))]
    noise_mm: f64,
    /// What is sent: a headset and two controllers, or the whole skeleton's bones.
    #[arg(long, value_enum, default_value_t = crate::args::BodyArg::Devices)]
    body: crate::args::BodyArg,
    /// Past the recording's end, play its motion again (with --seconds, a session of any length).
    #[arg(long = "loop")]
    looped: bool,
}

/// Runs a `vr` subcommand.
pub fn vr(cmd: VrCommand) -> Result<()> {
    let VrCommand::Send(args) = cmd;
    let bvh = Bvh::load(&args.bvh)?;
    if !(args.rate.is_finite() && (1.0..=1000.0).contains(&args.rate)) {
        return Err(FlagError::new("rate", format!(" {} is not a tracker rate", args.rate)).into());
    }
    let options = SendOptions {
        rate_hz: args.rate,
        tpose_s: args.tpose,
        start_frame: args.start_frame,
        seconds: args.seconds,
        noise_m: args.noise_mm / 1000.0,
        body: args.body.into(),
        looped: args.looped,
        ..SendOptions::default()
    };
    let stop = Arc::new(AtomicBool::new(false));
    for signal in [signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM] {
        signal_hook::flag::register(signal, Arc::clone(&stop))
            .context("cannot install the stop signal handlers")?;
    }
    println!(
        "sending {} to udp://{} at {} Hz: T-pose for {} s, then the motion",
        args.bvh.display(),
        args.to,
        args.rate,
        args.tpose
    );
    let bar = indicatif::ProgressBar::new(bvh.frames() as u64).with_message("frames");
    let packets = send(&bvh, args.to, &options, &stop, &mut |_, frame| {
        bar.set_position(frame as u64);
    })?;
    bar.finish_and_clear();
    println!("sent {packets} packets");
    Ok(())
}

/// Runs `teleop`.
pub fn teleop(args: &TeleopArgs) -> Result<std::process::ExitCode> {
    args.rec.settings()?;
    let robot = Robot::load(&args.robot)?;
    let policy = crate::args::policy_of(args.policy.as_deref(), &robot)?;
    let mut layout = PolicyLayout::load(&policy, &robot)?;
    let model = policy::onnx::OnnxModel::load(&layout.onnx_path)?;
    layout.bind_model(model.inputs(), model.output().1)?;
    if layout
        .slots
        .iter()
        .any(|s| matches!(s.term, Term::RefBodyPos { .. }))
    {
        bail!(
            "{}: ref_body_pos terms need the whole clip ahead; a live reference has only the present",
            policy.display()
        );
    }
    for (what, v) in [
        ("tpose", args.tpose),
        ("lost-after", args.lost_after),
        ("blend", args.blend),
    ] {
        if !(v.is_finite() && v > 0.0) {
            return Err(FlagError::new(what, format!(" {v} is not a duration")).into());
        }
    }
    let rate = layout.manifest.rate_hz;
    let receiver = VmcReceiver::start(
        args.listen,
        Serials {
            left: args.left_serial.clone(),
            right: args.right_serial.clone(),
            left_foot: args.left_foot_serial.clone(),
            right_foot: args.right_foot_serial.clone(),
        },
    )
    .with_context(|| format!("cannot listen for VMC on {}", args.listen))?;
    let options = TeleopOptions {
        resampler: Resampler {
            lost_after: args.lost_after,
            ..Resampler::default()
        },
        tpose_s: args.tpose,
        blend_s: args.blend,
        rate_hz: rate,
        headset_only: args.headset_only,
        ..TeleopOptions::default()
    };
    let mut teleop = match args.body {
        crate::args::BodyArg::Devices => Teleop::start(&robot, &receiver, options)?,
        body => {
            use human::body_teleop::Wearing;
            let wearing = match body {
                crate::args::BodyArg::FivePoint => Wearing::FivePoint,
                _ => Wearing::WholeBody,
            };
            human::body_teleop::start(&robot, &receiver, options, wearing)?
        }
    };
    let mut reference = Reference::hold(&teleop.standby, teleop.root, rate);
    if args.body != crate::args::BodyArg::Devices {
        // The operator's key bodies, measured against the robot's.
        reference.live_bodies = human::retarget::key_bodies(&robot);
    }
    let live = teleop
        .live
        .take()
        .context("the teleoperation's live reference was taken already")?;
    let max_ticks = match args.max_seconds {
        Some(s) if s.is_finite() && s > 0.0 => Some((s * rate).round() as u64),
        Some(s) => return Err(FlagError::new("max-seconds", format!(" {s} is not a duration")).into()),
        None => None,
    };
    let play = PlayOptions {
        end: EndMode::Loop,
        max_ticks,
        ..PlayOptions::default()
    };
    let stop = Arc::new(AtomicBool::new(false));
    for signal in [signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM] {
        signal_hook::flag::register(signal, Arc::clone(&stop))
            .context("cannot install the stop signal handlers")?;
    }
    println!(
        "teleoperating {} ({}): listening for VMC on udp://{}; stand in a T-pose, arms straight out",
        robot.config.name,
        if args.hardware { "hardware" } else { "mirror" },
        receiver.local_addr()
    );
    let absolute = |p: &PathBuf| std::fs::canonicalize(p).unwrap_or_else(|_| p.clone());
    let run = controller::options::RunMetadata {
        robot: absolute(&args.robot),
        policy: absolute(&policy),
        clip: None,
        command: None,
        command_source: Some(format!("vmc udp://{}", receiver.local_addr())),
        generator: None,
        keypoints: None,
        options: play,
        forced: None,
        recorded_in: None,
    };
    // Teleoperation runs on the wall clock (paced on the mirror): records drop rather than wait.
    let rec = &args.rec;
    let summary = if args.hardware {
        let io = robot_link::hardware::open(&robot)?;
        let mut clock = robot_link::WallClock::start();
        let player = Player::new(robot, layout, reference, play, io, stop)?
            .with_source(controller::reference::TeleopStream::new(live));
        let mut player = crate::play::record(player, rec, run, "teleop", true, None)?;
        player.run(&mut clock)?
    } else {
        let config = match &args.mirror {
            Some(p) => load_mirror_config(p, &robot)?,
            None => sim2real::config::MirrorConfig::default(),
        };
        let world = Arc::new(Mutex::new(
            Mirror::new(robot.clone(), config).context("cannot build the mirror")?,
        ));
        let io = sim2real::link::lockstep_robot(&robot, &world)?;
        let mut clock = sim2real::link::PacedLockstepClock::new(Arc::clone(&world));
        let player = Player::new(robot, layout, reference, play, io, stop)?
            .with_source(controller::reference::TeleopStream::new(live));
        let mut player = crate::play::record(player, rec, run, "teleop", true, None)?;
        player.run(&mut clock)?
    };
    print!("{summary}");
    print_teleop(&teleop.status(), &receiver);
    Ok(crate::play::finish(&summary))
}

fn print_teleop(status: &TeleopStatus, receiver: &VmcReceiver) {
    let [packets, poses, malformed, oversized, range, ignored] = receiver.counters.snapshot();
    println!(
        "trackers: {packets} packets, {poses} poses; dropped: {malformed} malformed, {oversized} oversized, {range} out of range; {ignored} messages for other addresses ignored"
    );
    println!("teleoperation ({} updates):", status.updates);
    for c in &status.changes {
        println!("  {:>7.2} s: {} ({})", c.at.as_secs_f64(), c.phase, c.why);
    }
}
