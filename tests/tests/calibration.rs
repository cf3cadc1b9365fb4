//! Calibration on the mirror: a machine whose offsets, directions and IMU mounting differ from its
//! description (hidden in the mirror's hardware truth) is calibrated through the real bus drivers,
//! with the simulated jig and stand worked by the operator's "hands".

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, PoisonError};
use std::time::Duration;

use calibration::operator::{Aborted, Operator, Request, Silent};
use calibration::procedure::{CalibrationError, Method, Options, Outcome, Plan, Session};
use calibration::rig::LinkRig;
use calibration::run::{rig_robot, run_calibration};
use calibration::solve;
use calibration::stops::StopOptions;
use calibration::verify::{VerifyOptions, verify};
use firmware_bridge::dxl::models as dxl_models;
use robots::{BusKind, Robot};
use sim2real::config::{HardwareTruth, MirrorConfig, TrueJoint};
use sim2real::hands::MirrorHands;
use sim2real::link::{LockstepClock, lockstep_robot};
use sim2real::mirror::Mirror;

const PERIOD: Duration = Duration::from_millis(20);

/// A copy of the reference robot's robot.toml in a fresh folder (calibration writes beside it),
/// the folder removed when the copy goes out of scope.
struct RobotCopy(PathBuf);

impl std::ops::Deref for RobotCopy {
    type Target = Path;
    fn deref(&self) -> &Path {
        &self.0
    }
}

impl AsRef<std::ffi::OsStr> for RobotCopy {
    fn as_ref(&self) -> &std::ffi::OsStr {
        self.0.as_os_str()
    }
}

impl Drop for RobotCopy {
    fn drop(&mut self) {
        if let Some(dir) = self.0.parent() {
            let _ = std::fs::remove_dir_all(dir);
        }
    }
}

fn robot_copy(name: &str) -> RobotCopy {
    let dir = std::env::temp_dir().join(format!("robodeploy-cal-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let src = robots::reference_robot_path();
    std::fs::copy(src.with_file_name("biped.xml"), dir.join("biped.xml")).unwrap();
    let text = std::fs::read_to_string(&src).unwrap();
    std::fs::write(
        dir.join("robot.toml"),
        test_support::fixtures::policy_from(&text, src.parent().unwrap()),
    )
    .unwrap();
    RobotCopy(dir.join("robot.toml"))
}

/// A machine unlike its description: flipped directions and offsets on both bus kinds (one puts
/// a servo's range across its encoder's wrap point), and an IMU turned on its mount.
fn hidden_truth() -> HardwareTruth {
    let j = |zero_offset: f64, direction: f64| TrueJoint {
        zero_offset,
        direction,
    };
    HardwareTruth {
        joints: [
            ("left_knee", j(0.8, -1.0)),
            ("right_hip_pitch", j(-1.3, -1.0)),
            ("left_ankle_roll", j(0.05, 1.0)),
            ("right_hip_yaw", j(0.4, 1.0)), // robot.toml says -1
            ("left_shoulder_pitch", j(2.5, -1.0)),
            ("right_elbow", j(-0.7, 1.0)),
            ("right_shoulder_roll", j(-2.9, -1.0)),
            ("head_yaw", j(0.31, -1.0)),
        ]
        .into_iter()
        .map(|(n, t)| (n.to_owned(), t))
        .collect(),
        imu_mounting_rpy_deg: Some([12.0, -25.0, 140.0]),
    }
}

fn mirror_config(truth: HardwareTruth) -> MirrorConfig {
    MirrorConfig {
        seed: 11,
        gantry: true,
        hardware: truth,
        ..MirrorConfig::default()
    }
}

type World = Arc<Mutex<Mirror>>;

/// The mirror of `robot` with `config`, and a rig for `rig_robot` on it.
fn rig_on(
    robot: &Robot,
    rig_robot: &Robot,
    config: MirrorConfig,
) -> (LinkRig<sim2real::link::LockstepRobot, LockstepClock>, World) {
    let world = Arc::new(Mutex::new(Mirror::new(robot.clone(), config).unwrap()));
    let io = lockstep_robot(rig_robot, &world).unwrap();
    let rig = LinkRig::new(io, LockstepClock::new(Arc::clone(&world)), PERIOD, rig_robot);
    (rig, world)
}

fn lock(w: &World) -> std::sync::MutexGuard<'_, Mirror> {
    w.lock().unwrap_or_else(PoisonError::into_inner)
}

/// Calibrates the machine `truth` described by `path`; `abort_at` interrupts at a jig setting or
/// stand pose (see [`AbortAt`]).
fn calibrate(
    path: &Path,
    truth: HardwareTruth,
    plan: &Plan,
    abort_at: Option<AbortAt>,
    abort: &AtomicBool,
    log: &Path,
) -> (Result<Outcome, CalibrationError>, World) {
    let robot = Robot::load(path).unwrap();
    let raw = rig_robot(&robot, plan);
    let (mut rig, world) = rig_on(&robot, &raw, mirror_config(truth));
    let mut hands = Interrupted {
        at: abort_at,
        hands: MirrorHands::new(Arc::clone(&world), Silent::default()),
    };
    let result = run_calibration(
        &robot,
        &mut rig,
        &mut hands,
        abort,
        plan,
        Options::default(),
        Some(log),
        "test",
    )
    .map(|(o, _)| o);
    (result, world)
}

#[test]
fn hidden_offsets_directions_and_imu_mounting_are_recovered_and_verified() {
    let path = robot_copy("recover");
    let truth = hidden_truth();
    let robot = Robot::load(&path).unwrap();
    let log = path.with_file_name("log.csv");
    let jig = Plan::default();
    let (outcome, world) = calibrate(&path, truth.clone(), &jig, None, &AtomicBool::new(false), &log);
    let outcome = outcome.unwrap();
    // Torque stayed off the whole time: no actuator ever pushed.
    assert_eq!(lock(&world).peak_actuator_torque(), 0.0);

    let per_tick = dxl_models::rad_per_tick();
    for (j, r) in robot.config.joints.iter().zip(&outcome.joints) {
        let t = truth.joints.get(&j.name).copied().unwrap_or(TrueJoint {
            zero_offset: j.zero_offset,
            direction: j.direction,
        });
        let c = r.calibration;
        assert_eq!(c.direction, t.direction, "{}", j.name);
        if robot.bus(&j.bus).unwrap().kind == BusKind::Dynamixel {
            // The servo reads zero_ticks at joint zero once the Homing Offset is programmed.
            let ticks = (c.physical_zero() - t.zero_offset) / per_tick;
            assert!(ticks.abs() <= 2.0, "{}: {ticks:.2} ticks off", j.name);
            // The wrap point is outside the joint's range (with the margin).
            let range = robot
                .mjcf_range(robot.config.joints.iter().position(|x| x.name == j.name).unwrap())
                .unwrap();
            for q in range {
                let reading = 2048.0 + (c.zero_offset + c.direction * q) / per_tick;
                assert!(
                    (64.0..=4031.0).contains(&reading),
                    "{}: {reading} ticks at {q} rad",
                    j.name
                );
            }
        } else {
            assert!(
                (c.zero_offset - t.zero_offset).abs() <= 0.005,
                "{}: {} vs {}",
                j.name,
                c.zero_offset,
                t.zero_offset
            );
        }
    }
    let imu_result = outcome.imu.clone().expect("a whole-robot run calibrates the IMU");
    let imu = imu_result.calibration.mounting_rpy_deg.map(f64::to_radians);
    let true_imu = truth.imu_mounting_rpy_deg.unwrap().map(f64::to_radians);
    let err = solve::rotation_between(
        &robots::spatial::mat_of_rpy(imu),
        &robots::spatial::mat_of_rpy(true_imu),
    );
    assert!(
        err.to_degrees() < 1.0,
        "IMU mounting {:.3}° off",
        err.to_degrees()
    );
    assert!((imu_result.gravity - 9.81).abs() < 1.0);

    // The file is beside robot.toml, and loading the robot merges it.
    let merged = Robot::load(&path).unwrap();
    for (j, r) in merged.config.joints.iter().zip(&outcome.joints) {
        assert_eq!(
            (j.direction, j.zero_offset, j.homing_offset_ticks),
            (
                r.calibration.direction,
                r.calibration.zero_offset,
                r.calibration.homing_offset_ticks
            )
        );
    }
    assert_eq!(
        merged.config.imu.mounting_rpy_deg,
        imu_result.calibration.mounting_rpy_deg
    );
    // The tick log has every tick, all of them limp.
    let text = std::fs::read_to_string(&log).unwrap();
    assert!(text.lines().count() > 20 * 100);
    assert!(
        text.lines().skip(1).all(|l| l.ends_with(",,")),
        "a command was sent during calibration"
    );

    // Verify on a fresh power-up of the same machine: the calibrated encoders agree with the
    // truth, and no command exceeded the verification limits.
    let options = VerifyOptions::default();
    let low = options.low_gain_robot(&merged);
    let (mut rig, world) = rig_on(&merged, &low, mirror_config(truth));
    let abort = AtomicBool::new(false);
    let mut hands = MirrorHands::new(Arc::clone(&world), Silent::default());
    let mut session = Session::new(&low, &mut rig, &mut hands, &abort, Options::default());
    let w = Arc::clone(&world);
    let mut true_q = || Some(lock(&w).joint_positions().collect::<Vec<_>>());
    let report = verify(&mut session, &low, &options, &mut true_q).unwrap();
    session
        .log
        .check(&options.limits(&low), PERIOD.as_secs_f64())
        .unwrap();
    for j in &report.joints {
        let off = (j.measured - j.truth.unwrap()).abs().to_degrees();
        assert!(off < 0.5, "{}: encoder and truth differ by {off:.2}°", j.name);
        assert!(
            j.asymmetry.is_none_or(|a| a.abs().to_degrees() < 1.0),
            "{}: asymmetric by {:?}",
            j.name,
            j.asymmetry
        );
    }
    assert!(report.imu_tilt_deg < 1.0, "tilt {}", report.imu_tilt_deg);
    // The same limits, against what the motors actually did (MIT torque at the motor: the joint
    // limit through the gear; the firmware's damping adds a little on top of the command).
    let worst_motor_limit = low
        .config
        .joints
        .iter()
        .map(|j| options.torque_fraction * j.torque_limit / j.gear)
        .fold(0.0, f64::max);
    assert!(lock(&world).peak_actuator_torque() <= worst_motor_limit * 1.2);
}

/// Where to interrupt: at the request labelled `label` the operator says no; or, with `flag`, the
/// abort flag is raised instead (as Ctrl-C would) and the procedure notices it on its next tick.
struct AbortAt {
    label: &'static str,
    flag: Option<Arc<AtomicBool>>,
}

/// The mirror's hands, with an operator who may interrupt.
struct Interrupted<O> {
    at: Option<AbortAt>,
    hands: O,
}

impl<O: Operator> Operator for Interrupted<O> {
    fn request(&mut self, r: Request<'_>) -> Result<(), Aborted> {
        let label = match r {
            Request::ClampJig { label, .. } | Request::HoldBase { label, .. } => Some(label),
            _ => None,
        };
        if let Some(at) = self.at.as_ref().filter(|a| Some(a.label) == label) {
            match &at.flag {
                None => return Err(Aborted),
                Some(f) => f.store(true, Ordering::Relaxed),
            }
        }
        self.hands.request(r)
    }
    fn direction_seen(&mut self, index: usize, joint: &str) -> Result<f64, Aborted> {
        self.hands.direction_seen(index, joint)
    }
    fn say(&mut self, line: &str) {
        self.hands.say(line);
    }
}

#[test]
fn an_interrupted_calibration_keeps_the_previous_file_and_ends_limp() {
    let path = robot_copy("abort");
    let cal = robots::calibration::path_for(&path);
    let previous =
        "note = \"the previous calibration\"\n\n[joints.left_knee]\nzero_offset = 0.01\ndirection = 1.0\n";
    std::fs::write(&cal, previous).unwrap();
    for (label, flag) in [
        ("B", None),
        ("tilted forward", Some(Arc::new(AtomicBool::new(false)))),
    ] {
        let abort = flag.clone().unwrap_or_else(|| Arc::new(AtomicBool::new(false)));
        let at = AbortAt { label, flag };
        let log = path.with_file_name("abort-log.csv");
        let (result, world) = calibrate(&path, hidden_truth(), &Plan::default(), Some(at), &abort, &log);
        assert!(
            matches!(result, Err(CalibrationError::Aborted)),
            "{label}: {result:?}"
        );
        assert_eq!(std::fs::read_to_string(&cal).unwrap(), previous, "{label}");
        assert!(!robots::calibration::previous_path_for(&path).exists());
        assert!(!cal.with_extension("toml.partial").exists());
        // What was recorded up to the abort is kept.
        assert!(std::fs::read_to_string(&log).unwrap().lines().count() > 20);
        let mut w = lock(&world);
        let robot = w.robot().clone();
        for (k, j) in robot.config.joints.iter().enumerate() {
            match robot.bus(&j.bus).unwrap().kind {
                BusKind::Dynamixel => assert!(!w.servo_mut(k).unwrap().torque_enabled(), "{}", j.name),
                _ => assert!(!w.motor_mut(k).unwrap().enabled(), "{}", j.name),
            }
        }
    }
}

#[test]
fn a_wrong_model_stops_calibration_before_anything_is_enabled() {
    let path = robot_copy("identity");
    let robot = Robot::load(&path).unwrap();
    // The description says XL430 where the machine has an XM430.
    let mut wrong = calibration::raw_robot(&robot);
    let k = wrong
        .config
        .joints
        .iter()
        .position(|j| j.name == "left_elbow")
        .unwrap();
    wrong.config.joints[k].model = "XL430-W250".into();
    let (mut rig, world) = rig_on(&robot, &wrong, mirror_config(HardwareTruth::default()));
    let abort = AtomicBool::new(false);
    let mut hands = MirrorHands::new(Arc::clone(&world), Silent::default());
    let err = run_calibration(
        &wrong,
        &mut rig,
        &mut hands,
        &abort,
        &Plan::default(),
        Options::default(),
        None,
        "x",
    )
    .unwrap_err();
    let msg = err.to_string();
    assert!(msg.contains("left_elbow") && msg.contains("XL430-W250"), "{msg}");
    assert!(!robots::calibration::path_for(&path).exists());
    assert_eq!(lock(&world).peak_actuator_torque(), 0.0);
}

#[test]
fn the_stop_method_finds_zeros_and_directions_within_its_torque_and_speed_caps() {
    let path = robot_copy("stops");
    let truth = hidden_truth();
    let robot = Robot::load(&path).unwrap();
    // Joints free to reach both stops while the robot hangs on its stand (flipped and offset
    // ones among them, on both bus kinds).
    let names = [
        "right_hip_yaw",
        "left_knee",
        "left_elbow",
        "right_elbow",
        "head_yaw",
    ];
    let options = StopOptions::default();
    let plan = Plan {
        method: Method::Stops(options.clone()),
        joints: Some(names.iter().map(|n| (*n).to_owned()).collect()),
    };
    let log = path.with_file_name("stops-log.csv");
    let abort = AtomicBool::new(false);
    let raw = rig_robot(&robot, &plan);
    let (mut rig, world) = rig_on(&robot, &raw, mirror_config(truth.clone()));
    let mut hands = MirrorHands::new(Arc::clone(&world), Silent::default());
    let mut session = Session::new(&robot, &mut rig, &mut hands, &abort, Options::default());
    let outcome = session.calibrate(&plan).unwrap();
    // Every command within the caps, checked over the log (actuator units of the raw rig).
    let (limits, _) = options.actuator_limits(&robot);
    session.log.check(&limits, PERIOD.as_secs_f64()).unwrap();
    assert!(session.log.len() > 500);
    drop(session);
    let worst_cap = robot
        .config
        .joints
        .iter()
        .filter(|j| names.contains(&j.name.as_str()))
        .map(|j| options.torque_fraction * j.torque_limit / j.gear)
        .fold(0.0, f64::max);
    assert!(lock(&world).peak_actuator_torque() <= worst_cap * 1.2);
    assert_eq!(outcome.joints.len(), names.len());
    assert!(outcome.imu.is_none());
    let per_tick = dxl_models::rad_per_tick();
    for r in &outcome.joints {
        let j = robot.config.joints.iter().find(|j| j.name == r.name).unwrap();
        let t = truth.joints.get(&j.name).copied().unwrap_or(TrueJoint {
            zero_offset: j.zero_offset,
            direction: j.direction,
        });
        let c = r.calibration;
        assert_eq!(c.direction, t.direction, "{}", j.name);
        if robot.bus(&j.bus).unwrap().kind == BusKind::Dynamixel {
            let ticks = (c.physical_zero() - t.zero_offset) / per_tick;
            assert!(ticks.abs() <= 2.0, "{}: {ticks:.2} ticks off", j.name);
        } else {
            assert!((c.zero_offset - t.zero_offset).abs() <= 0.005, "{}", j.name);
        }
    }

    // A limb that gravity holds below its stop is refused by name, not calibrated wrongly.
    let plan = Plan {
        method: Method::Stops(options),
        joints: Some(vec!["left_hip_roll".into()]),
    };
    let (result, world) = calibrate(&path, truth, &plan, None, &abort, &log);
    let msg = result.unwrap_err().to_string();
    assert!(
        msg.contains("left_hip_roll") && msg.contains("stopped the joint early"),
        "{msg}"
    );
    assert!(!robots::calibration::path_for(&path).exists());
    let mut w = lock(&world);
    let k = robot
        .config
        .joints
        .iter()
        .position(|j| j.name == "left_hip_roll")
        .unwrap();
    assert!(!w.motor_mut(k).unwrap().enabled(), "the robot ends limp");
}

use test_support::bin::robodeploy;

#[test]
fn the_cli_calibrates_verifies_and_refuses_what_it_must() {
    let path = robot_copy("cli");
    let truth = path.with_file_name("truth.toml");
    let config = mirror_config(hidden_truth());
    std::fs::write(&truth, toml::to_string(&config).unwrap()).unwrap();
    let run = |args: &[&str], stdin: &str| {
        let mut child = robodeploy()
            .args(args)
            .arg("--robot")
            .arg(&path)
            .stdin(std::process::Stdio::piped())
            .stdout(std::process::Stdio::piped())
            .stderr(std::process::Stdio::piped())
            .spawn()
            .unwrap();
        use std::io::Write as _;
        child.stdin.take().unwrap().write_all(stdin.as_bytes()).unwrap();
        let out = child.wait_with_output().unwrap();
        let text = format!(
            "{}{}",
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        );
        (out.status.success(), text)
    };
    let log = path.with_file_name("cli-log.csv");
    let log = log.to_str().unwrap();
    let truth = truth.to_str().unwrap();

    // The identity check moves nothing and asks nothing: it runs with no terminal and no answers
    // (standard input empty), prints every device, and leaves no empty recording behind.
    let identify_record = path.with_file_name("identify.mcap");
    let (ok, text) = run(
        &[
            "calibrate",
            "identify",
            "--record",
            identify_record.to_str().unwrap(),
        ],
        "",
    );
    assert!(ok, "{text}");
    assert!(
        text.contains("Step 1/3 identity") && text.contains("left_knee"),
        "{text}"
    );
    assert!(
        !identify_record.exists(),
        "an identity check records no ticks: no file"
    );
    // A step that needs an answer, with standard input ended: said, not taken as a yes.
    let (ok, text) = run(
        &["calibrate", "run", "--mirror", truth, "--log", log, "--no-record"],
        "",
    );
    assert!(!ok && text.contains("standard input ended"), "{text}");
    assert!(!robots::calibration::path_for(&path).exists());

    // Without --yes the person is asked; "q" at the first question aborts, nothing written.
    let (ok, text) = run(
        &["calibrate", "run", "--mirror", truth, "--log", log, "--no-record"],
        "q\n",
    );
    assert!(!ok && text.contains("aborted"), "{text}");
    assert!(!robots::calibration::path_for(&path).exists());

    // Uncalibrated, the machine (on its stand) cannot play the squat: it ends in damping early.
    let play = ["play", "--mirror", truth, "--no-record"];
    let (_, text) = run(&play, "");
    assert!(
        text.contains("→ Damped") && !text.contains("clip finished"),
        "{text}"
    );

    // Recorded and served live like a run: the robot's joints, frames and geometry, and when
    // its joints were commanded (Running) or limp (Off) — a jig calibration never commands one.
    let recording = path.with_file_name("calibrate.mcap");
    let (ok, text) = run(
        &[
            "calibrate",
            "run",
            "--mirror",
            truth,
            "--yes",
            "--log",
            log,
            "--record",
            recording.to_str().unwrap(),
            "--live",
            "127.0.0.1:0",
            "--live-wait",
            "0",
        ],
        "",
    );
    assert!(ok, "{text}");
    assert!(text.contains("directions wrong: 0"), "{text}");
    assert!(text.contains("live: ws://127.0.0.1:"), "{text}");
    assert!(robots::calibration::path_for(&path).exists());
    let bytes = analysis::recording::read(&recording).unwrap();
    let (mut states, mut frames, mut scene, mut modes) = (0, 0, 0, Vec::new());
    analysis::recording::for_each_message(&bytes, |m| {
        match m.topic {
            "/joint_state" => states += 1,
            "/tf" => frames += 1,
            "/robot" => scene += 1,
            "/safety" => {
                let t = <telemetry_schema::SafetyTransition as prost::Message>::decode(m.data).unwrap();
                modes.push(t.mode);
            }
            _ => {}
        }
        Ok(())
    })
    .unwrap();
    assert!(
        states > 100 && frames == states && scene == 1,
        "{states} {frames} {scene}"
    );
    assert_eq!(modes, ["Off"]);

    // Calibrated, the same machine plays it as well as the nominal robot does.
    let (ok, text) = run(&play, "");
    assert!(ok && text.contains("clip finished"), "{text}");
    let rmse: f64 = text
        .lines()
        .find_map(|l| l.strip_prefix("joint tracking RMSE:"))
        .and_then(|v| v.trim().trim_end_matches('°').parse().ok())
        .unwrap_or(f64::NAN);
    assert!(rmse < 3.0, "joint RMSE {rmse}°\n{text}");

    let (ok, text) = run(
        &[
            "calibrate",
            "verify",
            "--mirror",
            truth,
            "--yes",
            "--log",
            log,
            "--no-record",
        ],
        "",
    );
    assert!(
        ok && text.contains("verified") && text.contains("every command stayed within the limits"),
        "{text}"
    );

    // Calibrating again keeps the first result as the previous file.
    let first = std::fs::read_to_string(robots::calibration::path_for(&path)).unwrap();
    let (ok, text) = run(
        &[
            "calibrate",
            "run",
            "--mirror",
            truth,
            "--yes",
            "--log",
            log,
            "--no-record",
        ],
        "",
    );
    assert!(ok && text.contains("kept the previous calibration"), "{text}");
    assert_eq!(
        std::fs::read_to_string(robots::calibration::previous_path_for(&path)).unwrap(),
        first
    );

    let (ok, text) = run(&["calibrate", "run", "--hardware", "--yes"], "");
    assert!(!ok && text.contains("--yes is for the mirror only"), "{text}");
}
