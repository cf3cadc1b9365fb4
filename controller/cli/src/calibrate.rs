//! `robodeploy calibrate`: identity check, joint zeros and directions, IMU, and verification, on
//! the mirror (default) or the hardware.

use std::path::PathBuf;
use std::sync::atomic::AtomicBool;
use std::sync::{Arc, Mutex, PoisonError};
use std::time::Duration;

use crate::console::ConsoleOperator;
use anyhow::{Context, Result, bail};

use crate::args::FlagError;
use calibration::operator::Operator;
use calibration::procedure::{Method, Options, Outcome, Plan, Session};
use calibration::rig::LinkRig;
use calibration::rig::Rig;
use calibration::run::{rig_robot, run_calibration};
use calibration::solve;
use calibration::stops::StopOptions;
use calibration::verify::{VerifyOptions, VerifyReport, verify};
use clap::{Args, Subcommand};
use firmware_bridge::dxl::models as dxl_models;
use robot_link::WallClock;
use robots::{BusKind, Robot};
use sim2real::config::MirrorConfig;
use sim2real::hands::MirrorHands;
use sim2real::link::{LockstepClock, lockstep_robot};
use sim2real::mirror::Mirror;

use crate::sim::load_mirror_config;

/// `calibrate` subcommands.
#[derive(Debug, Subcommand)]
pub enum CalibrateCommand {
    /// Ask every device who it is: model, firmware, current limit (torque off).
    Identify(Target),
    /// Calibrate joints and IMU; writes calibration.toml beside robot.toml.
    ///
    /// The whole procedure: identity check (nothing enabled on a mismatch); each joint's direction
    /// and zero, by the jig (default: torque off throughout; setting A = the default pose, B =
    /// each joint turned 0.15 rad) or by the mechanical stops (each joint driven at 0.5 rad/s with
    /// ≤ 30 % of its torque onto both stops; you say which way it turned); Dynamixel Homing
    /// Offsets chosen so no encoder wraps inside its joint's range; the IMU's gyro and
    /// accelerometer bias and gravity check from 2 s still, and its mounting from upright and
    /// tilted ~30° forward. Writes calibration.toml beside robot.toml only when every step
    /// succeeded (the old one becomes calibration.previous.toml), and a tick log (CSV). Ctrl-C
    /// aborts into damping.
    Run(RunArgs),
    /// Check a calibration: a gentle move to the default pose, errors reported.
    ///
    /// With the calibration in place, move to the default pose on the stand at 30 % stiffness,
    /// ≤ 0.3 rad/s and ≤ 25 % torque; report each joint's error and the IMU's tilt, then go limp.
    Verify(VerifyArgs),
}

/// Which robot, and where it runs.
#[derive(Debug, Args)]
pub struct Target {
    /// The robot description (its calibration.toml, if any, is merged).
    #[arg(long, default_value_os_t = robots::locate::default_robot())]
    robot: PathBuf,
    /// On the robot's own buses instead of the mirror. Every step is then confirmed at the
    /// terminal.
    #[arg(long)]
    hardware: bool,
    /// Mirror settings (TOML). Its [hardware] table sets the machine's true offsets, directions
    /// and IMU mounting, hidden from the procedure: what a calibration must find.
    #[arg(long, conflicts_with = "hardware")]
    mirror: Option<PathBuf>,
    /// Confirm every step without asking (mirror only: on hardware a person confirms each step).
    #[arg(long)]
    yes: bool,
    /// Recording and live view, as for `play` (default: out/runs/ROBOT-calibrate.mcap): each
    /// tick's measured joints, IMU and targets, the robot in 3D.
    #[command(flatten)]
    record: crate::play::RecordArgs,
}

/// Arguments of `calibrate run`.
#[derive(Debug, Args)]
pub struct RunArgs {
    #[command(flatten)]
    target: Target,
    /// The tick log (CSV: every command and reading).
    #[arg(long, default_value = "out/calibration/calibrate-log.csv")]
    log: PathBuf,
    /// How joints find their zero: two jig settings (torque off), or the mechanical stops.
    #[arg(long, value_enum, default_value_t = MethodArg::Jig)]
    method: MethodArg,
    /// Calibrate only this joint (repeat for more); the IMU and the other joints keep what the
    /// calibration file holds.
    #[arg(long = "joint", value_name = "NAME")]
    joints: Vec<String>,
}

/// `--method`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
enum MethodArg {
    /// Two jig settings, torque off throughout.
    Jig,
    /// Both mechanical stops at low torque and speed.
    Stops,
}

/// Arguments of `calibrate verify`.
#[derive(Debug, Args)]
pub struct VerifyArgs {
    #[command(flatten)]
    target: Target,
    /// Fail when a joint ends farther than this from the default pose, deg.
    #[arg(long, default_value_t = 3.0, value_parser = crate::args::within(0.01, 45.0))]
    tolerance_deg: f64,
    /// The tick log (CSV: every command and reading).
    #[arg(long, default_value = "out/calibration/verify-log.csv")]
    log: PathBuf,
}

/// Tick period of calibration.
const PERIOD: Duration = Duration::from_millis(20);

/// Runs a `calibrate` subcommand.
pub fn run(cmd: CalibrateCommand) -> Result<()> {
    let abort = Arc::new(AtomicBool::new(false));
    for signal in [signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM] {
        signal_hook::flag::register(signal, Arc::clone(&abort))
            .context("cannot install the abort signal handlers")?;
    }
    match cmd {
        CalibrateCommand::Identify(t) => {
            let robot = load(&t)?;
            with_rig(
                &t,
                &calibration::raw_robot(&robot),
                &robot,
                &abort,
                |rig, op, _| {
                    let mut session = Session::new(&robot, rig, op, &abort, Options::default());
                    session.identify()?;
                    Ok(())
                },
            )
        }
        CalibrateCommand::Run(args) => calibrate(&args, &abort),
        CalibrateCommand::Verify(args) => verify_pose(&args, &abort),
    }
}

fn load(t: &Target) -> Result<Robot> {
    if t.yes && t.hardware {
        return Err(FlagError::new(
            "yes",
            " is for the mirror only: on hardware every step is confirmed by the person at the robot",
        )
        .into());
    }
    Ok(Robot::load(&t.robot)?)
}

/// Where the run happens: the mirror's world (with its hidden truth) or the hardware.
type MirrorWorld = Option<(Arc<Mutex<Mirror>>, MirrorConfig)>;

/// Builds the rig for `rig_robot` (the robot as the drivers see it) on the mirror of `robot`, or
/// on the hardware, and hands it with an operator to `body`.
fn with_rig(
    t: &Target,
    rig_robot: &Robot,
    robot: &Robot,
    abort: &AtomicBool,
    body: impl FnOnce(&mut dyn Rig, &mut dyn Operator, &MirrorWorld) -> Result<()>,
) -> Result<()> {
    if t.hardware {
        let io = robot_link::hardware::open_sequential(rig_robot)?;
        let mut rig = LinkRig::new(io, WallClock::start(), PERIOD, rig_robot);
        let mut op = ConsoleOperator::new(false);
        return watched(t, rig_robot, abort, &mut rig, |rig| body(rig, &mut op, &None));
    }
    let mut config = match &t.mirror {
        Some(p) => load_mirror_config(p, robot)?,
        None => MirrorConfig::default(),
    };
    // Calibration happens on the stand.
    config.gantry = true;
    let world = Arc::new(Mutex::new(
        Mirror::new(robot.clone(), config.clone()).context("cannot build the mirror")?,
    ));
    let io = lockstep_robot(rig_robot, &world)?;
    let mut rig = LinkRig::new(io, LockstepClock::new(Arc::clone(&world)), PERIOD, rig_robot);
    let mut op = MirrorHands::new(Arc::clone(&world), ConsoleOperator::new(t.yes));
    let mirror = Some((world, config));
    watched(t, rig_robot, abort, &mut rig, |rig| body(rig, &mut op, &mirror))
}

/// Runs `body` on `rig`, recorded and served live as `t` asks.
fn watched(
    t: &Target,
    robot: &Robot,
    abort: &AtomicBool,
    rig: &mut dyn Rig,
    body: impl FnOnce(&mut dyn Rig) -> Result<()>,
) -> Result<()> {
    anyhow::ensure!(
        !t.record.record_bus_rate,
        "--record-bus-rate: a calibration has no bus cycles to record"
    );
    let info = controller::telemetry::RecordingInfo {
        joint_names: robot.config.joints.iter().map(|j| j.name.clone()).collect(),
        root_frame: robot.config.root_body.clone(),
        kinematics: Some((
            robot.mjcf_path.clone(),
            robot.config.joints.iter().map(|j| j.mjcf_joint.clone()).collect(),
        )),
        model: robot.shared_model().ok(),
        commit: Some(env!("ROBODEPLOY_COMMIT").to_owned()),
        ..Default::default()
    };
    let sink = crate::play::start_recording(
        &t.record,
        info,
        &robot.config.name,
        "calibrate",
        t.hardware,
        abort,
        None,
    )?;
    let Some(sink) = sink else {
        return body(rig);
    };
    let n = robot.config.joints.len();
    let mut recorded = RecordedRig {
        rig,
        sink,
        record: Box::default(),
        limp: vec![robot_link::JointTarget::default(); n],
        reference: vec![0.0; n],
        tick: 0,
        truth: robot_link::GroundTruth::default(),
    };
    let result = body(&mut recorded);
    let report = recorded.sink.finish()?;
    if report.written == 0 {
        // Nothing happened that a recording could show (an identity check, an abort at the first
        // question): no empty file left behind.
        let _ = std::fs::remove_file(&report.path);
    } else {
        println!("{report}");
    }
    result
}

/// A calibration rig recorded like a run: each tick's measured state and the targets sent, the
/// mode `Running` while joints are commanded and `Off` while they are limp.
struct RecordedRig<'a> {
    rig: &'a mut dyn Rig,
    sink: controller::telemetry::TelemetrySink,
    record: Box<controller::telemetry::TickRecord>,
    limp: Vec<robot_link::JointTarget>,
    /// The targets' positions (the run's "reference"), reused.
    reference: Vec<f64>,
    tick: u64,
    truth: robot_link::GroundTruth,
}

impl Rig for RecordedRig<'_> {
    fn period(&self) -> Duration {
        self.rig.period()
    }

    fn identify(&mut self) -> Result<Vec<robot_link::DeviceIdentity>, calibration::rig::RigError> {
        self.rig.identify()
    }

    fn tick(
        &mut self,
        targets: Option<&[robot_link::JointTarget]>,
        state: &mut robot_link::RobotState,
    ) -> Result<Duration, calibration::rig::RigError> {
        let now = self.rig.tick(targets, state)?;
        let sent = targets.unwrap_or(&self.limp);
        for (r, (t, q)) in self.reference.iter_mut().zip(sent.iter().zip(&state.q)) {
            *r = if targets.is_some() { t.q } else { *q };
        }
        let view = controller::telemetry::TickView {
            tick: self.tick,
            now,
            mode: if targets.is_some() {
                controller::safety::Mode::Running
            } else {
                controller::safety::Mode::Off
            },
            state,
            targets: sent,
            reference_q: &self.reference,
            reference_root: [0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0],
            tracking: false,
            policy_ran: false,
            anchors: None,
            body_errors: &[],
            generated: None,
            keypoint_errors: &[],
            triangulated_mm: None,
            estimate: None,
            truth_in_world: None,
            actions: &[],
            commands: &[],
            truth: &self.truth,
            has_truth: false,
            stop_requested: false,
            bus_times: &[],
            io: Duration::ZERO,
            compute: Duration::ZERO,
            cause: None,
            harness: controller::options::HarnessPhase::None,
        };
        self.record.fill(&view);
        self.sink.push(&self.record);
        self.tick += 1;
        Ok(now)
    }

    fn damp(&mut self) -> Result<(), calibration::rig::RigError> {
        self.rig.damp()
    }
}

fn calibrate(args: &RunArgs, abort: &AtomicBool) -> Result<()> {
    let t = &args.target;
    let robot = load(t)?;
    let plan = Plan {
        method: match args.method {
            MethodArg::Jig => Method::Jig,
            MethodArg::Stops => Method::Stops(StopOptions::default()),
        },
        joints: (!args.joints.is_empty()).then(|| args.joints.clone()),
    };
    let raw = rig_robot(&robot, &plan);
    let place = if t.hardware { "hardware" } else { "mirror" };
    println!(
        "calibrating {} on the {place}: {}",
        robot.config.name,
        robot.path.display()
    );
    with_rig(t, &raw, &robot, abort, |rig, op, world| {
        let method = format!("{:?}", args.method).to_lowercase();
        let note = format!("robodeploy calibrate run on the {place}, {method} method");
        let result = run_calibration(
            &robot,
            rig,
            op,
            abort,
            &plan,
            Options::default(),
            Some(&args.log),
            &note,
        );
        println!("tick log: {}", args.log.display());
        let (outcome, written) = result?;
        println!("wrote {}", written.calibration.display());
        if let Some(p) = written.previous {
            println!("kept the previous calibration as {}", p.display());
        }
        if let Some((_, config)) = world {
            print_against_truth(&robot, config, &outcome);
        }
        Ok(())
    })
}

/// In the mirror: how far the results are from the machine's hidden truth.
fn print_against_truth(robot: &Robot, config: &MirrorConfig, outcome: &Outcome) {
    let per_tick = dxl_models::rad_per_tick();
    println!("against the mirror's hidden truth:");
    let mut worst = [0.0f64; 2];
    let mut flipped = 0;
    for r in &outcome.joints {
        let Some(j) = robot.config.joints.iter().find(|j| j.name == r.name) else {
            continue;
        };
        let truth = config.hardware.joints.get(&j.name);
        // Without an entry the machine is as described (a Dynamixel zero counts its Homing Offset).
        let described = robots::calibration::physical_zero(j.zero_offset, j.homing_offset_ticks);
        let (dir, zero) = truth.map_or((j.direction, described), |t| (t.direction, t.zero_offset));
        let c = r.calibration;
        flipped += usize::from(c.direction != dir);
        match robot.bus(&j.bus).map(|b| b.kind) {
            Some(BusKind::Dynamixel | BusKind::Feetech) => {
                let ticks = ((c.physical_zero() - zero) / per_tick).abs();
                worst[0] = worst[0].max(ticks);
            }
            _ => worst[1] = worst[1].max((c.zero_offset - zero).abs()),
        }
    }
    println!(
        "  directions wrong: {flipped}; worst zero error: {:.2} ticks (serial servos), {:.5} rad (MIT)",
        worst[0], worst[1]
    );
    if let Some(imu) = &outcome.imu {
        let truth = config
            .hardware
            .imu_mounting_rpy_deg
            .unwrap_or(robot.config.imu.mounting_rpy_deg);
        let err = solve::rotation_between(
            &robots::spatial::mat_of_rpy(truth.map(f64::to_radians)),
            &robots::spatial::mat_of_rpy(imu.calibration.mounting_rpy_deg.map(f64::to_radians)),
        );
        println!("  IMU mounting error: {:.3}°", err.to_degrees());
    }
}

fn verify_pose(args: &VerifyArgs, abort: &AtomicBool) -> Result<()> {
    let t = &args.target;
    let robot = load(t)?;
    if !robots::calibration::path_for(&robot.path).exists() {
        println!(
            "note: no {} yet; verifying robot.toml's values",
            robots::calibration::path_for(&robot.path).display()
        );
    }
    let options = VerifyOptions::default();
    let low = options.low_gain_robot(&robot);
    let mut result = None;
    with_rig(t, &low, &robot, abort, |rig, op, world| {
        let period = rig.period().as_secs_f64();
        let mut session = Session::new(&low, rig, op, abort, Options::default());
        let mut truth = || {
            world.as_ref().map(|(w, _)| {
                w.lock()
                    .unwrap_or_else(PoisonError::into_inner)
                    .joint_positions()
                    .collect()
            })
        };
        let report = verify(&mut session, &low, &options, &mut truth);
        if let Err(e) = session.log.write_csv(&args.log) {
            eprintln!("cannot write the tick log: {e}");
        }
        let report = report?;
        let checked = session.log.check(&options.limits(&low), period);
        print_verify(&report);
        println!("tick log: {} ({} ticks)", args.log.display(), session.log.len());
        match checked {
            Ok(()) => println!("every command stayed within the limits"),
            Err(e) => bail!("a command exceeded the verification limits: {e}"),
        }
        result = Some(report);
        Ok(())
    })?;
    let report = result.context("verification did not run")?;
    // Gravity sag at low stiffness is expected; a wrong zero shows as asymmetry between twins,
    // and in the mirror as a difference from the truth.
    let worst_asymmetry = report
        .joints
        .iter()
        .filter_map(|j| j.asymmetry)
        .map(f64::abs)
        .fold(0.0, f64::max);
    let worst_truth = report
        .joints
        .iter()
        .filter_map(|j| j.truth.map(|t| (j.measured - t).abs()))
        .fold(0.0, f64::max);
    let tolerance = args.tolerance_deg.to_radians();
    if worst_asymmetry > tolerance || worst_truth > tolerance {
        bail!(
            "verification failed: worst asymmetry {:.2}°, worst encoder-vs-true {:.2}° (tolerance {}°)",
            worst_asymmetry.to_degrees(),
            worst_truth.to_degrees(),
            args.tolerance_deg
        );
    }
    println!(
        "verified: worst asymmetry {:.2}°{}",
        worst_asymmetry.to_degrees(),
        if report.joints.iter().any(|j| j.truth.is_some()) {
            format!(", worst encoder-vs-true {:.3}°", worst_truth.to_degrees())
        } else {
            String::new()
        }
    );
    Ok(())
}

fn print_verify(report: &VerifyReport) {
    let sim = report.joints.iter().any(|j| j.truth.is_some());
    println!(
        "{:<20} {:>9} {:>10} {:>8} {:>10}{}",
        "joint",
        "target °",
        "measured °",
        "error °",
        "asymm. °",
        if sim { "     true °  enc-true °" } else { "" }
    );
    let deg = |x: f64| format!("{:.2}", x.to_degrees());
    for j in &report.joints {
        let mut line = format!(
            "{:<20} {:>9} {:>10} {:>8} {:>10}",
            j.name,
            deg(j.target),
            deg(j.measured),
            deg(j.error()),
            j.asymmetry.map_or("-".into(), deg)
        );
        if let Some(t) = j.truth {
            line.push_str(&format!(" {:>10} {:>11}", deg(t), deg(j.measured - t)));
        }
        println!("{line}");
    }
    println!(
        "(error: gravity sag at {:.0} % stiffness is expected; asymmetry between twins is not)",
        VerifyOptions::default().gain_fraction * 100.0
    );
    println!(
        "IMU: base tilt {:.2}° from upright (on the stand: expect ~0)",
        report.imu_tilt_deg
    );
}
