//! rd-mini, the second robot, brought as a user brings theirs: a scene file that includes the
//! robot, degrees, default classes, mesh feet in millimetres, position actuators, its own sensor
//! names and a keyframe, a command-driven policy with no clip — and commands from the keyboard,
//! UDP and a gamepad.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use human::commands::{PadAxis, PadEvent, PadEvents};
use robots::Robot;
use test_support::bin::{Running, run_within};
use test_support::fixtures::{venv_python, workspace_root};

mod common;

#[global_allocator]
static ALLOC: test_support::alloc::CountingAllocator = test_support::alloc::CountingAllocator;

fn mini(file: &str) -> PathBuf {
    workspace_root().join("robots/mini").join(file)
}

fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("mini-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// rd-mini on its command-driven fixture in lockstep on the mirror, no clip, with `options`.
fn command_driven_player(
    options: controller::player::PlayOptions,
) -> (controller::sim::LockstepRun, human::commands::CommandSpec) {
    let robot = Robot::load(&mini("robot.toml")).unwrap();
    command_driven_player_on(robot, sim2real::config::MirrorConfig::default(), options)
}

/// `robot` (rd-mini or a variant of its file) on the command-driven fixture, on a mirror set by
/// `mirror`.
fn command_driven_player_on(
    robot: Robot,
    mirror: sim2real::config::MirrorConfig,
    options: controller::player::PlayOptions,
) -> (controller::sim::LockstepRun, human::commands::CommandSpec) {
    let mut layout = policy::PolicyLayout::load(&mini("policies/stand_walk.toml"), &robot).unwrap();
    let spec = layout.manifest.commands.clone().unwrap();
    let (reference, _) =
        controller::reference::load_reference(None, Path::new("unused"), &mut layout, &robot, 0).unwrap();
    let run = controller::sim::lockstep_player(
        robot,
        layout,
        reference,
        options,
        mirror,
        Arc::new(AtomicBool::new(false)),
    )
    .unwrap();
    (run, spec)
}

/// `play` on rd-mini's command-driven fixture, lockstep, recording into `record`.
fn play_args(record: &Path, seconds: &str, extra: &[&str]) -> Vec<String> {
    let mut args: Vec<String> = [
        "play",
        "--robot",
        mini("robot.toml").to_str().unwrap(),
        "--policy",
        mini("policies/stand_walk.toml").to_str().unwrap(),
        "--max-seconds",
        seconds,
        "--record",
        record.to_str().unwrap(),
    ]
    .iter()
    .map(|s| s.to_string())
    .collect();
    args.extend(extra.iter().map(|s| s.to_string()));
    args
}

/// The `/policy` messages of a recording: (running, observation, commands) per tick.
fn policy_ticks(path: &Path) -> Vec<(bool, Vec<f64>, Vec<f64>)> {
    let bytes = analysis::recording::read(path).unwrap();
    let mut out = Vec::new();
    analysis::recording::for_each_message(&bytes, |m| {
        if m.topic == "/policy" {
            let v = <telemetry_schema::PolicyStep as prost::Message>::decode(m.data).unwrap();
            out.push((
                v.running,
                v.observation.iter().map(|&x| f64::from(x)).collect(),
                v.commands.iter().map(|c| c.value).collect(),
            ));
        }
        Ok(())
    })
    .unwrap();
    out
}

#[test]
fn the_scene_loads_through_its_include_with_the_models_own_names() {
    let robot = Robot::load(&mini("robot.toml")).unwrap();
    let m = &robot.mjcf;
    assert_eq!(robot.config.joints.len(), 16);
    assert_eq!(m.floor, ["ground"]);
    assert_eq!(m.meshes, 2);
    assert_eq!(m.position_actuated().count(), 16);
    let keys: Vec<&str> = m.keyframes.iter().map(|k| k.name.as_str()).collect();
    assert_eq!(keys, ["home", "sit"]);
    // Degrees in the MJCF, radians compiled: the knee's 130°.
    let (_, hi) = m.joints["l_knee"].range.unwrap();
    assert!((hi - 130f64.to_radians()).abs() < 1e-12, "{hi}");
    assert_eq!(
        robot.imu_sensors(),
        [
            Some("body_gyro".into()),
            Some("body_acc".into()),
            Some("body_orientation".into())
        ]
    );
    assert_eq!(robot.start_keyframe().unwrap().qpos.len(), m.nq);
}

#[test]
fn the_mesh_feet_start_with_their_soles_on_the_floor() {
    use mujoco_rs::wrappers::mj_model::MjtObjBase;
    let robot = Robot::load(&mini("robot.toml")).unwrap();
    let key = robot.start_keyframe().unwrap().qpos.clone();
    let mirror =
        sim2real::mirror::Mirror::new(robot.clone(), sim2real::config::MirrorConfig::default()).unwrap();
    let data = mirror.data();
    let model = data.model();
    for sole in ["l_sole", "r_sole"] {
        let g = model.name_to_id(MjtObjBase::mjOBJ_GEOM, sole).unwrap();
        let r = data.geom_xmat()[g];
        // The vertex lowest in the world, from the mesh's own vertices.
        let down = sim2real::placement::reach(model, g, [-r[6], -r[7], -r[8]]).unwrap();
        let lowest = data.geom_xpos()[g][2] - down;
        assert!(
            lowest.abs() < 0.002,
            "{sole}: lowest point {:.4} m from the floor",
            lowest
        );
    }
    // The keyframe's joints, its base lowered onto the floor (it was 0.3 m up).
    let q = data.qpos();
    assert_eq!(&q[7..], &key[7..]);
    assert!(q[2] < 0.3 - 0.03, "base at {:.3} m", q[2]);
    // The position actuators' own geometry is the model's: the sole meshes are offset in their
    // bodies (the compiled geom sits 33.5 mm below the ankle).
    let g = model.name_to_id(MjtObjBase::mjOBJ_GEOM, "l_sole").unwrap();
    assert!(model.geom_pos()[g][2] < -0.03, "{:?}", model.geom_pos()[g]);
}

#[test]
fn it_stands_ten_seconds_on_a_command_driven_policy_with_no_clip() {
    let dir = scratch("stand");
    let record = dir.join("run.mcap");
    let (code, stdout, stderr) = run_within(&play_args(&record, "10", &[]), Duration::from_secs(300));
    assert_eq!(code, Some(0), "{stdout}{stderr}");
    assert!(stdout.contains("no clip (a command-driven policy"), "{stdout}");
    assert!(stdout.contains("fell: no"), "{stdout}");
    assert!(
        stdout.contains("success (no fall, no safety stop): yes"),
        "{stdout}"
    );
    assert!(stdout.contains("Running → Stopping (run time up)"), "{stdout}");
    // Through its stop to Off, the mirror's servos damping with no stiffness: MuJoCo was never
    // handed a NaN control (it prints a warning and resets its state).
    assert!(
        !format!("{stdout}{stderr}").contains("unstable"),
        "{stdout}{stderr}"
    );
    // No clip-tracking numbers against a made-up clip: where it went instead.
    assert!(!stdout.contains("joint tracking RMSE"), "{stdout}");
    let distance = stdout
        .lines()
        .find_map(|l| l.strip_prefix("distance: "))
        .and_then(|l| l.split(" m").next())
        .and_then(|d| d.parse::<f64>().ok())
        .unwrap_or_else(|| panic!("{stdout}"));
    assert!(distance < 0.05, "standing still, it went {distance} m");
    // Its report says the same: where it went, no joint errors against a made-up clip.
    let report = dir.join("report");
    let (code, out, err) = run_within(
        &[
            "report",
            record.to_str().unwrap(),
            "--out",
            report.to_str().unwrap(),
        ],
        Duration::from_secs(300),
    );
    assert_eq!(code, Some(0), "{out}{err}");
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(report.join("summary.json")).unwrap()).unwrap();
    assert!(summary["joints_rmse_deg"].is_null(), "{summary}");
    assert_eq!(summary["success"], true);
    assert!(
        summary["locomotion"]["distance_m"].as_f64().unwrap() < 0.05,
        "{summary}"
    );
    assert_eq!(summary["locomotion"]["commanded"][0], 0.0, "{summary}");
    let md = std::fs::read_to_string(report.join("summary.md")).unwrap();
    assert!(
        md.contains("| forward: commanded / achieved | +0.000 m/s /"),
        "{md}"
    );
    // The recording replays bit for bit (the commands it had are fed back).
    let (code, out, err) = run_within(&["replay", record.to_str().unwrap()], Duration::from_secs(300));
    assert_eq!(code, Some(0), "{out}{err}");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn keys_drive_the_commands_within_their_ranges_and_ramps() {
    let dir = scratch("keys");
    let record = dir.join("run.mcap");
    let mut p = Running::start_with_stdin(&play_args(&record, "30", &["--keyboard"]));
    p.wait_for("commands: keyboard", Duration::from_secs(120));
    // Forward three times (0.05 each), turn left twice (0.2 each), and once an unknown key.
    use std::io::Write;
    p.stdin().write_all(b"www\x1b[D\x1b[Dx").unwrap();
    p.stdin().flush().unwrap();
    let done = p.finish();
    assert!(done.status.success(), "{}{}", done.stdout, done.stderr);
    assert!(
        done.stdout.contains("commands: 5 accepted, 0 dropped"),
        "{}",
        done.stdout
    );
    let ticks = policy_ticks(&record);
    let running: Vec<&Vec<f64>> = ticks.iter().filter(|t| t.0).map(|t| &t.2).collect();
    let last = running.last().unwrap();
    assert!(
        (last[0] - 0.15).abs() < 1e-9 && last[1] == 0.0 && (last[2] - 0.4).abs() < 1e-9,
        "{last:?}"
    );
    // Ramped: at most 0.5 m/s² × 0.02 s and 2 rad/s² × 0.02 s per tick.
    for w in running.windows(2) {
        assert!((w[1][0] - w[0][0]).abs() <= 0.01 + 1e-12, "{w:?}");
        assert!((w[1][2] - w[0][2]).abs() <= 0.04 + 1e-12, "{w:?}");
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn datagrams_drive_the_commands_and_bad_ones_are_dropped_and_counted() {
    let dir = scratch("udp");
    let record = dir.join("run.mcap");
    let mut p = Running::start(&play_args(&record, "60", &["--command-udp", "127.0.0.1:0"]));
    let line = p.wait_for("commands: send to udp://", Duration::from_secs(120));
    let addr: std::net::SocketAddr = line.rsplit("udp://").next().unwrap().trim().parse().unwrap();
    let socket = std::net::UdpSocket::bind("127.0.0.1:0").unwrap();
    let send = |text: &str| {
        socket.send_to(text.as_bytes(), addr).unwrap();
    };
    send("not json");
    send(r#"{"version": 1, "seq": 1, "command": [0.9, 0.0, 0.0]}"#);
    send(r#"{"version": 2, "seq": 1, "command": [0.1, 0.0, 0.0]}"#);
    // The operator keeps sending (as a joystick bridge does) until the run ends.
    let stop = Arc::new(AtomicBool::new(false));
    let sender = {
        let stop = Arc::clone(&stop);
        let socket = socket.try_clone().unwrap();
        std::thread::Builder::new()
            .name("udp-operator".into())
            .spawn(move || {
                let mut seq = 10u64;
                while !stop.load(Ordering::Relaxed) {
                    let m = format!(r#"{{"version": 1, "seq": {seq}, "command": [0.2, 0.05, -0.4]}}"#);
                    let _ = socket.send_to(m.as_bytes(), addr);
                    seq += 1;
                    if seq == 12 {
                        // One from the past: dropped as out of order.
                        let _ =
                            socket.send_to(br#"{"version": 1, "seq": 3, "command": [0.0, 0.0, 0.0]}"#, addr);
                    }
                    std::thread::sleep(Duration::from_millis(10));
                }
            })
            .unwrap()
    };
    let done = p.finish();
    stop.store(true, Ordering::Relaxed);
    sender.join().unwrap();
    assert!(done.status.success(), "{}{}", done.stdout, done.stderr);
    let counts = done
        .stdout
        .lines()
        .find(|l| l.starts_with("commands: ") && l.contains("accepted"))
        .unwrap_or_else(|| panic!("{}", done.stdout));
    assert!(
        counts.contains("(2 malformed, 1 out of range, 1 out of order)"),
        "{counts}"
    );
    let ticks = policy_ticks(&record);
    let last = &ticks.iter().rfind(|t| t.0).unwrap().2;
    assert_eq!(last, &vec![0.2, 0.05, -0.4]);
    // Nothing outside the manifest's ranges ever reached the policy.
    assert!(
        ticks
            .iter()
            .all(|t| t.2.first().is_none_or(|&x| (-0.15..=0.25).contains(&x)))
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

/// A gamepad whose events a test scripts (as gilrs would deliver them).
struct ScriptedPad(std::sync::mpsc::Receiver<PadEvent>);

impl PadEvents for ScriptedPad {
    fn next(&mut self, timeout: Duration) -> Option<PadEvent> {
        self.0.recv_timeout(timeout).ok()
    }
}

#[test]
fn a_gamepads_sticks_drive_the_commands() {
    let ((player, mut clock, _world), spec) = command_driven_player(controller::player::PlayOptions {
        end: controller::player::EndMode::Stand,
        ..Default::default()
    });
    let (writer, reader) = human::commands::command_channel(spec.names.len());
    let mut player = player.with_commands(reader).unwrap();
    let (events, script) = std::sync::mpsc::sync_channel(16);
    let stats = Arc::new(human::commands::CommandStats::default());
    let pad_stop = Arc::new(AtomicBool::new(false));
    let pad = human::commands::spawn_gamepad(
        &spec,
        writer,
        ScriptedPad(script),
        Arc::clone(&stats),
        Arc::clone(&pad_stop),
    )
    .unwrap();
    // Left stick full forward, right stick half right.
    events.send(PadEvent::Axis(PadAxis::LeftY, 1.0)).unwrap();
    events.send(PadEvent::Axis(PadAxis::RightX, 0.5)).unwrap();
    while stats.accepted.load(Ordering::Relaxed) < 2 {
        std::thread::yield_now();
    }
    player.identify().unwrap();
    let period = Duration::from_millis(20);
    for _ in 0..200 {
        player.step(&clock).unwrap();
        player.wait_until(&mut clock, period * player.ticks() as u32);
    }
    // Full deflection is the end of the range; half right is half the rightward turning range.
    assert_eq!(player.commands().unwrap(), &[0.25, 0.0, -0.4]);
    // South resets to the defaults (the ramp brings them back).
    events.send(PadEvent::Reset).unwrap();
    while stats.accepted.load(Ordering::Relaxed) < 3 {
        std::thread::yield_now();
    }
    for _ in 0..100 {
        player.step(&clock).unwrap();
        player.wait_until(&mut clock, period * player.ticks() as u32);
    }
    assert_eq!(player.commands().unwrap(), &[0.0, 0.0, 0.0]);
    pad_stop.store(true, Ordering::Relaxed);
    pad.join().unwrap();
}

#[test]
fn the_phase_term_advances_before_the_first_observation_as_numpy_says() {
    let dir = scratch("phase");
    let record = dir.join("run.mcap");
    let (code, out, err) = run_within(&play_args(&record, "4", &[]), Duration::from_secs(300));
    assert_eq!(code, Some(0), "{out}{err}");
    let running: Vec<Vec<f64>> = policy_ticks(&record)
        .into_iter()
        .filter(|t| t.0)
        .map(|t| t.1[57..59].to_vec())
        .collect();
    assert!(running.len() > 100, "{} policy steps", running.len());
    let numpy = std::process::Command::new(venv_python())
        .arg(workspace_root().join("tests/python/phase_trace.py"))
        .args(["--period", "40", "--advance-first", "--steps"])
        .arg(running.len().to_string())
        .output()
        .unwrap();
    assert!(
        numpy.status.success(),
        "{}",
        String::from_utf8_lossy(&numpy.stderr)
    );
    let want: Vec<Vec<f64>> = serde_json::from_slice(&numpy.stdout).unwrap();
    for (k, (got, want)) in running.iter().zip(&want).enumerate() {
        for (g, w) in got.iter().zip(want) {
            assert!((g - w).abs() < 1e-6, "step {k}: {got:?} vs NumPy's {want:?}");
        }
    }
    // Pre-increment: the first observation is one step into the cycle, not at its start.
    assert!(
        (running[0][1] - (std::f64::consts::TAU / 40.0).sin()).abs() < 1e-6,
        "{:?}",
        running[0]
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn commands_outside_their_ranges_are_refused_by_name() {
    let dir = scratch("range");
    let record = dir.join("run.mcap");
    let (code, out, err) = run_within(
        &play_args(&record, "1", &["--command", "0.9,0,0"]),
        Duration::from_secs(120),
    );
    assert_eq!(code, Some(2), "{out}{err}");
    assert!(
        err.contains("--command 0.9,0,0")
            && err.contains("stand_walk.toml")
            && err.contains("lin_vel_x = 0.9 is outside its range [-0.15, 0.25]"),
        "{err}"
    );
    assert!(!record.exists(), "nothing ran, nothing was recorded");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn check_bus_scan_and_calibration_work_on_it_unchanged() {
    let robot = mini("robot.toml");
    let robot = robot.to_str().unwrap();
    let policy = mini("policies/stand_walk.toml");
    let (code, out, err) = run_within(
        &["check", "--robot", robot, "--policy", policy.to_str().unwrap()],
        Duration::from_secs(120),
    );
    assert_eq!(code, Some(0), "{out}{err}");
    for needle in [
        "floor: ground",
        "16 position actuators",
        "body_gyro (gyro)",
        "keyframes: home (the mirror's start), sit",
        "phase                2 × 1 history",
        "period 40 ticks, advances before the first observation",
        "lin_vel_x    [-0.15, 0.25]",
    ] {
        assert!(out.contains(needle), "{needle:?} not in:\n{out}");
    }
    let (code, out, err) = run_within(
        &["bus", "scan", "--sim", "--robot", robot],
        Duration::from_secs(120),
    );
    assert_eq!(code, Some(0), "{out}{err}");
    assert!(
        out.contains("every device of rd-mini answered as configured"),
        "{out}"
    );
    // Calibration writes beside a copy of the robot, not into the repository.
    let dir = scratch("calibrate");
    for f in ["robot.toml", "scene.xml", "mini.xml"] {
        std::fs::copy(mini(f), dir.join(f)).unwrap();
    }
    std::fs::create_dir_all(dir.join("meshes")).unwrap();
    for f in ["left_foot.stl", "right_foot.stl"] {
        std::fs::copy(mini("meshes").join(f), dir.join("meshes").join(f)).unwrap();
    }
    let copy = dir.join("robot.toml");
    let (code, out, err) = run_within(
        &["calibrate", "run", "--yes", "--robot", copy.to_str().unwrap()],
        Duration::from_secs(300),
    );
    assert_eq!(code, Some(0), "{out}{err}");
    assert!(out.contains("directions wrong: 0"), "{out}");
    assert!(dir.join("calibration.toml").exists());
    // Later runs say they merged it.
    let (code, out, err) = run_within(
        &[
            "check",
            "--robot",
            copy.to_str().unwrap(),
            "--policy",
            policy.to_str().unwrap(),
        ],
        Duration::from_secs(120),
    );
    assert_eq!(code, Some(0), "{out}{err}");
    assert!(
        out.contains("calibration merged from") && out.contains("calibration.toml"),
        "{out}"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn the_foot_meshes_are_what_the_script_makes() {
    let dir = scratch("meshes");
    let out = std::process::Command::new(venv_python())
        .arg(workspace_root().join("scripts/gen_mini_feet.py"))
        .arg(&dir)
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    for f in ["left_foot.stl", "right_foot.stl"] {
        assert_eq!(
            std::fs::read(dir.join(f)).unwrap(),
            std::fs::read(mini("meshes").join(f)).unwrap(),
            "{f}: run scripts/gen_mini_feet.py robots/mini/meshes"
        );
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn compare_aligns_a_trainers_trace_and_judges_each_term_against_the_buses_resolution() {
    let dir = scratch("compare");
    let run = dir.join("run.mcap");
    let (code, out, err) = run_within(
        &play_args(&run, "6", &["--command", "0.25,0,0.4"]),
        Duration::from_secs(300),
    );
    assert_eq!(code, Some(0), "{out}{err}");
    // The trainer's trace, as NumPy writes it: it starts 7 steps later, its joint angles read one
    // encoder tick apart on every other step, and its gravity is off by 0.01 from its step 150.
    let train = dir.join("train.csv");
    let script = format!(
        r#"
import numpy as np
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory
reader = make_reader(open({run:?}, "rb"), decoder_factories=[DecoderFactory()])
rows = [list(p.observation) for s, c, m, p in reader.iter_decoded_messages(topics=["/policy"]) if p.running]
obs = np.array(rows, dtype=np.float64)[7:]
obs[::2, 9:25] += 2 * np.pi / 4096
obs[150:, 3:6] += 0.01
np.savetxt({train:?}, obs.astype(np.float32), delimiter=",", header=",".join(f"o{{i}}" for i in range(obs.shape[1])))
"#,
        run = run.display().to_string(),
        train = train.display().to_string()
    );
    let py = std::process::Command::new(venv_python())
        .args(["-c", &script])
        .output()
        .unwrap();
    assert!(py.status.success(), "{}", String::from_utf8_lossy(&py.stderr));
    let compare = |extra: &[&str]| {
        let mut args = vec!["compare", run.to_str().unwrap(), train.to_str().unwrap()];
        args.extend_from_slice(extra);
        let (code, out, err) = run_within(&args, Duration::from_secs(120));
        assert_eq!(code, Some(0), "{out}{err}");
        out
    };
    let verdict = |out: &str, term: &str| {
        out.lines()
            .find(|l| l.starts_with(&format!("{term} ")))
            .unwrap_or_else(|| panic!("{term} missing:\n{out}"))
            .to_owned()
    };
    let out = compare(&["--align", "joint_pos"]);
    assert!(
        out.contains("aligned on joint_pos: step k of the run meets step k-7 of the other"),
        "{out}"
    );
    assert!(
        verdict(&out, "joint_pos").ends_with("within the buses' quantisation"),
        "{out}"
    );
    assert!(
        verdict(&out, "projected_gravity").ends_with("BEYOND the buses' quantisation"),
        "{out}"
    );
    assert!(
        verdict(&out, "command").ends_with("equal (not measured by a bus)"),
        "{out}"
    );
    // The same shift given, over the first 100 steps only: the gravity offset is not reached.
    let out = compare(&["--offset=-7", "--steps", "100"]);
    assert!(out.contains("compared 100 steps, offset -7"), "{out}");
    assert!(
        verdict(&out, "projected_gravity").ends_with("within the buses' quantisation"),
        "{out}"
    );
    // Unaligned, the gait's joints do not meet at all.
    let out = compare(&[]);
    assert!(
        verdict(&out, "joint_pos").ends_with("BEYOND the buses' quantisation"),
        "{out}"
    );
    // A term the policy lacks is named.
    let (code, _, err) = run_within(
        &[
            "compare",
            run.to_str().unwrap(),
            train.to_str().unwrap(),
            "--align",
            "joint_position",
        ],
        Duration::from_secs(120),
    );
    assert_eq!(code, Some(2), "{err}");
    assert!(
        err.contains("--align joint_position: not a term of the policy"),
        "{err}"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

/// The base's height (m) and tilt from upright (rad) at every tick of a recording (the mirror's
/// truth on `/replay`).
fn base_course(path: &Path) -> Vec<(f64, f64)> {
    let rec = analysis::replay::read_recording(path).unwrap();
    rec.ticks
        .iter()
        .map(|t| {
            let p = t.truth.as_ref().unwrap().root_pose;
            (p[2], controller::safety::tilt_of([p[3], p[4], p[5], p[6]]))
        })
        .collect()
}

#[test]
fn a_soft_stop_can_end_standing_or_in_a_controlled_sit_down() {
    let dir = scratch("on-stop");
    let course = |mode: &str| {
        let record = dir.join(format!("{mode}.mcap"));
        // Standing is bounded by --stand-for, which nothing else takes.
        let stand_for: &[&str] = if mode == "stand" {
            &["--stand-for", "5"]
        } else {
            &[]
        };
        let (code, out, err) = run_within(
            &play_args(&record, "3", &[&["--on-stop", mode][..], stand_for].concat()),
            Duration::from_secs(300),
        );
        assert_eq!(code, Some(0), "{out}{err}");
        assert!(out.contains("fell: no"), "{mode}: {out}");
        (base_course(&record), out)
    };
    // Policy until tick 150 (3 s), then the stop: 1 s settling under the policy, then the stay
    // (`stand`, its older name, still says the same).
    let (stand, out) = course("stand");
    let height = stand[140].0;
    assert!(out.contains("tick   450: Stopping → Damped"), "{out}");
    // Five seconds later it still stands where the policy left it.
    assert!(
        (stand[420].0 - height).abs() < 0.01,
        "{} vs {height}",
        stand[420].0
    );
    let (sit, out) = course("sit");
    assert!(out.contains("tick   350: Stopping → Damped"), "{out}");
    // After the settling, three seconds of sitting down: lower, still upright, no fall.
    assert!(
        sit[349].0 < height - 0.04,
        "sat to {:.3} from {height:.3}",
        sit[349].0
    );
    assert!(
        sit[150..350].iter().all(|(_, tilt)| *tilt < 0.3),
        "it tipped over sitting down"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_standing_robot_waits_for_a_second_stop_before_it_lets_go() {
    use controller::player::Player;
    use controller::safety::Mode;
    let ((mut player, mut clock, _world), _) = command_driven_player(controller::player::PlayOptions {
        end: controller::player::EndMode::Stand,
        on_stop: controller::options::OnStop::Stay,
        ..Default::default()
    });
    player.identify().unwrap();
    let period = Duration::from_millis(20);
    let mut tick = |p: &mut Player<_>| {
        p.step(&clock).unwrap();
        p.wait_until(&mut clock, period * p.ticks() as u32);
    };
    for _ in 0..100 {
        tick(&mut player);
    }
    assert_eq!(player.mode(), Mode::Running);
    player.request_stop();
    // The blend, then as long as nobody asks again (here 20 s): standing, torque on.
    for _ in 0..1000 {
        tick(&mut player);
        assert_eq!(player.mode(), Mode::Stopping);
    }
    player.request_stop();
    for _ in 0..3 {
        tick(&mut player);
    }
    assert_eq!(player.mode(), Mode::Damped);
}

#[test]
fn a_sit_down_needs_a_sit_keyframe_and_says_so() {
    let dir = scratch("nosit");
    let (code, out, err) = run_within(
        &[
            "play",
            "--on-stop",
            "sit",
            "--max-seconds",
            "1",
            "--record",
            dir.join("r.mcap").to_str().unwrap(),
        ],
        Duration::from_secs(120),
    );
    assert_eq!(code, Some(2), "{out}{err}");
    assert!(err.contains("names no sit_keyframe"), "{err}");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_steady_command_driven_tick_with_live_commands_and_recording_allocates_nothing() {
    use controller::safety::Mode;
    let ((player, mut clock, _world), _) = command_driven_player(controller::player::PlayOptions {
        end: controller::player::EndMode::Stand,
        ..Default::default()
    });
    let (mut writer, reader) = human::commands::command_channel(3);
    let dir = scratch("alloc");
    let info = player.recording_info();
    let sink = controller::telemetry::TelemetrySink::start(
        &dir.join("run.mcap"),
        256,
        controller::telemetry::Backpressure::Drop,
        &info,
    )
    .unwrap();
    let mut player = player.with_commands(reader).unwrap().with_telemetry(sink);
    player.identify().unwrap();
    let period = Duration::from_millis(20);
    let mut ticks =
        |p: &mut controller::player::Player<_>, w: &mut human::commands::CommandWriter, n: u32| {
            for k in 0..n {
                // The operator's source publishes every tick (on its own thread in a run).
                w.publish(&[0.2, 0.0, f64::from(k % 10) * 0.05]);
                p.step(&clock).unwrap();
                p.wait_until(&mut clock, period * p.ticks() as u32);
            }
        };
    ticks(&mut player, &mut writer, 80);
    assert_eq!(player.mode(), Mode::Running);
    let (_, stats) = test_support::alloc::count_allocations(|| ticks(&mut player, &mut writer, 100));
    assert_eq!(player.mode(), Mode::Running);
    assert!(stats.is_zero(), "{stats:?}");
    assert_eq!(player.commands().unwrap()[0], 0.2);
    drop(player);
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn per_value_scales_and_offsets_shape_a_term_and_wrong_lengths_are_named() {
    use policy::{ObsInputs, ObservationBuilder, PolicyLayout};
    let robot = Robot::load(&mini("robot.toml")).unwrap();
    let path = mini("policies/stand_walk.toml");
    let text = std::fs::read_to_string(&path).unwrap();
    let shaped = |shaping: &str| {
        text.replacen(
            "term = \"base_ang_vel\"\nscale = 0.25",
            &format!("term = \"base_ang_vel\"\n{shaping}"),
            1,
        )
    };
    let layout = PolicyLayout::parse(
        &path,
        &shaped("offsets = [1.0, 1.0, 1.0]\nscales = [1.0, 10.0, 100.0]"),
        &robot,
    )
    .unwrap();
    let zeros = vec![0.0; 16];
    let past = vec![0.0f32; 16];
    let mut obs = vec![0.0f32; layout.obs_len];
    let still = common::Still {
        q: zeros.clone(),
        height: 0.25,
    };
    ObservationBuilder::new(&layout).build(
        &ObsInputs {
            base_ang_vel: [1.0, 2.0, 3.0],
            ..common::at_rest(&zeros, &past, &still)
        },
        &mut obs,
    );
    // (value − offset) · scale, value by value.
    assert_eq!(&obs[..3], &[0.0, 10.0, 200.0]);
    let e = PolicyLayout::parse(&path, &shaped("offsets = [1.0, 1.0]"), &robot)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("observation[0] (base_ang_vel)") && e.contains("offsets: 3 finite values"),
        "{e}"
    );
}

#[test]
fn its_bno08x_streams_at_the_chips_own_rate_and_the_file_must_say_so() {
    // On the mirror: the RVC frames read back as upright, gravity up, the turn rate near zero.
    let robot = Robot::load(&mini("robot.toml")).unwrap();
    assert_eq!(
        robot.config.imu.protocol,
        firmware_bridge::imu::ImuProtocol::Bno08xRvc
    );
    let ((mut player, mut clock, _world), _) = command_driven_player(controller::player::PlayOptions {
        end: controller::player::EndMode::Stand,
        ..Default::default()
    });
    player.identify().unwrap();
    let period = Duration::from_millis(20);
    for _ in 0..100 {
        player.step(&clock).unwrap();
        player.wait_until(&mut clock, period * player.ticks() as u32);
    }
    let s = player.state();
    assert!((s.accel[2] - 9.81).abs() < 0.3, "{:?}", s.accel);
    assert!(s.gyro.iter().all(|g| g.abs() < 0.1), "{:?}", s.gyro);
    assert!(s.quat[0] > 0.99, "{:?}", s.quat);
    // The chip's rate and baud are fixed: a file that says otherwise is refused by name.
    let text = std::fs::read_to_string(mini("robot.toml")).unwrap();
    for (bad, needle) in [
        (
            text.replacen("rate_hz = 100.0\nmounting", "rate_hz = 200.0\nmounting", 1),
            "imu.rate_hz",
        ),
        (text.replacen("rate = 115200", "rate = 921600", 1), "(imu0).rate"),
    ] {
        let e = Robot::from_str(&mini("robot.toml"), &bad)
            .unwrap_err()
            .to_string();
        assert!(e.contains(needle), "{e}");
    }
}

#[test]
fn a_bno055_is_put_into_fusion_then_read_and_a_silent_one_stops_the_robot() {
    // rd-mini's file with a BNO055 on the IMU line: the host sets IMU mode, then asks for the
    // data registers at 100 Hz.
    let text = std::fs::read_to_string(mini("robot.toml")).unwrap().replacen(
        "protocol = \"bno08x_rvc\"",
        "protocol = \"bno055\"",
        1,
    );
    let robot = Robot::from_str(&mini("robot.toml"), &text).unwrap();
    assert_eq!(
        robot.config.imu.protocol,
        firmware_bridge::imu::ImuProtocol::Bno055
    );
    let gone_at = 2.5;
    let mirror = sim2real::config::MirrorConfig {
        faults: vec![sim2real::config::ScheduledFault {
            at_s: gone_at,
            joint: "imu".into(),
            fault: sim2real::config::FaultKind::Silent { count: None },
        }],
        ..Default::default()
    };
    let ((mut player, mut clock, _world), _) = command_driven_player_on(
        robot,
        mirror,
        controller::player::PlayOptions {
            end: controller::player::EndMode::Stand,
            ..Default::default()
        },
    );
    player.identify().unwrap();
    let period = Duration::from_millis(20);
    let tick = |player: &mut controller::player::Player<_>, clock: &mut _| {
        player.step(clock).unwrap();
        player.wait_until(clock, period * player.ticks() as u32);
    };
    for _ in 0..50 {
        tick(&mut player, &mut clock);
    }
    // Asking and answering in steady state allocate nothing, on the host or in the chip.
    let (_, stats) = test_support::alloc::count_allocations(|| {
        for _ in 0..50 {
            tick(&mut player, &mut clock);
        }
    });
    assert!(stats.is_zero(), "{stats:?}");
    let s = player.state();
    assert!(
        (s.accel[2] - 9.81).abs() < 0.3,
        "{:?} {:?} {:?}",
        s.accel,
        s.quat,
        player.transitions()
    );
    assert!(s.gyro.iter().all(|g| g.abs() < 0.1), "{:?}", s.gyro);
    assert!(s.quat[0] > 0.99, "{:?}", s.quat);
    assert_eq!(s.imu_missed, 0);
    assert!(
        player
            .transitions()
            .iter()
            .all(|t| t.to != controller::safety::Mode::Stopping)
    );
    // The chip stops answering: the loop stops on a stale IMU within its bound.
    for _ in 0..50 {
        tick(&mut player, &mut clock);
    }
    let stop = player
        .transitions()
        .iter()
        .find(|t| t.to == controller::safety::Mode::Stopping)
        .copied()
        .expect("a stop");
    assert!(
        matches!(stop.cause, controller::safety::Cause::StaleImu { .. }),
        "{stop:?}"
    );
    let gone_tick = (gone_at / 0.02) as u64;
    assert!(stop.tick > gone_tick && stop.tick <= gone_tick + 10, "{stop:?}");
    // The part reads at most at its 100 Hz fusion rate: a faster rate is refused by name.
    let e = Robot::from_str(
        &mini("robot.toml"),
        &text.replacen("rate_hz = 100.0\nmounting", "rate_hz = 200.0\nmounting", 1),
    )
    .unwrap_err()
    .to_string();
    assert!(e.contains("imu.rate_hz") && e.contains("BNO055"), "{e}");
}

#[test]
fn a_feetech_servo_variant_of_the_robots_own_runs_and_check_shows_its_limit() {
    // The STS3215 at 9 V: a variant the shipped table lacks, described in robot.toml on the
    // shipped STS3215-12V (what the bus identifies: model 777).
    let text = std::fs::read_to_string(mini("robot.toml")).unwrap();
    let variant = "\n[[servo_models]]\nname = \"STS3215-9V\"\nbase = \"STS3215-12V\"\nnominal_voltage = 9.0\nstall_torque = 2.3\nno_load_speed = 40.0\n";
    let text = test_support::zoo::on_feetech(&text)
        .replace("model = \"STS3215-12V\"", "model = \"STS3215-9V\"")
        .replace("torque_limit = 2.9", "torque_limit = 2.2")
        .replace("velocity_limit = 4.5", "velocity_limit = 4.0")
        + variant;
    let dir = std::env::temp_dir().join(format!("robodeploy-mini-sts9-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let robot_toml = dir.join("robot.toml");
    let root = mini("robot.toml").parent().unwrap().to_path_buf();
    let text = text.replace("mjcf = \"", &format!("mjcf = \"{}/", root.display()));
    std::fs::write(&robot_toml, &text).unwrap();
    let robot = Robot::load(&robot_toml).unwrap();
    let m = robot.feetech_model("STS3215-9V").unwrap();
    assert_eq!((m.model_number, m.stall_torque), (777, 2.3));
    // 40 rpm in robot.toml is the table's rad/s.
    assert!((m.no_load_speed - 40.0 * std::f64::consts::TAU / 60.0).abs() < 1e-12);
    // Beyond the variant's own figures is refused by them.
    let e = Robot::from_str(
        &robot_toml,
        &text.replace("torque_limit = 2.2", "torque_limit = 2.5"),
    )
    .unwrap_err()
    .to_string();
    assert!(e.contains("beyond the STS3215-9V's stall torque 2.3 N·m"), "{e}");
    // It stands on the mirror, its servos identifying as the base.
    let ((mut player, mut clock, _world), _) = command_driven_player_on(
        robot.clone(),
        sim2real::config::MirrorConfig::default(),
        controller::player::PlayOptions {
            end: controller::player::EndMode::Stand,
            max_ticks: Some(150),
            ..Default::default()
        },
    );
    player.identify().unwrap();
    let period = Duration::from_millis(20);
    while player.mode() != controller::safety::Mode::Off {
        player.step(&clock).unwrap();
        player.wait_until(&mut clock, period * player.ticks() as u32);
    }
    let s = player.summary_so_far();
    assert!(!s.fell, "{s}");
    // `check` says what each servo may push with.
    let (code, out, err) = run_within(
        &[
            "check",
            "--robot",
            robot_toml.to_str().unwrap(),
            "--policy",
            mini("policies/stand_walk.toml").to_str().unwrap(),
        ],
        Duration::from_secs(120),
    );
    assert_eq!(code, Some(0), "{out}{err}");
    assert!(
        out.contains(
            "servo torque limit: STS3215-9V 2.2 N·m (the STS3215-9V's stall torque 2.3 N·m × gear 1)"
        ),
        "{out}"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn on_feetech_servos_it_stands_its_servos_identify_and_a_vanished_one_stops_it() {
    use firmware_bridge::feetech::table::addr;
    let text = std::fs::read_to_string(mini("robot.toml")).unwrap();
    let robot = Robot::from_str(&mini("robot.toml"), &test_support::zoo::on_feetech(&text)).unwrap();
    assert_eq!(robot.bus("dxl0").unwrap().kind, robots::BusKind::Feetech);
    // `calibrate identify`'s question, answered by the emulated servos.
    {
        let world = Arc::new(std::sync::Mutex::new(
            sim2real::mirror::Mirror::new(robot.clone(), sim2real::config::MirrorConfig::default()).unwrap(),
        ));
        let mut link = sim2real::link::lockstep_robot(&robot, &world).unwrap();
        link.identify().unwrap();
        let ids = link.identities().unwrap();
        let knee = ids.iter().find(|d| d.joint == "l_knee").unwrap();
        assert_eq!(knee.answer, "model 777, firmware 3.10", "{knee:?}");
        // The joint's torque limit became the servo's Torque Limit.
        assert!((knee.torque_limit_nm - 2.9).abs() < 0.01, "{knee:?}");
    }
    let gone_at = 3.0;
    let mirror = sim2real::config::MirrorConfig {
        faults: vec![sim2real::config::ScheduledFault {
            at_s: gone_at,
            joint: "r_knee".into(),
            fault: sim2real::config::FaultKind::Vanish,
        }],
        ..Default::default()
    };
    let ((mut player, mut clock, world), _) = command_driven_player_on(
        robot.clone(),
        mirror,
        controller::player::PlayOptions {
            end: controller::player::EndMode::Stand,
            ..Default::default()
        },
    );
    player.identify().unwrap();
    let period = Duration::from_millis(20);
    let tick = |player: &mut controller::player::Player<_>, clock: &mut _| {
        player.step(clock).unwrap();
        player.wait_until(clock, period * player.ticks() as u32);
    };
    for _ in 0..140 {
        tick(&mut player, &mut clock);
    }
    assert_eq!(player.mode(), controller::safety::Mode::Running);
    let s = player.state();
    assert!(s.missed.iter().all(|&m| m == 0), "{:?}", s.missed);
    let knee = robot
        .config
        .joints
        .iter()
        .position(|j| j.name == "l_knee")
        .unwrap();
    {
        let mut w = world.lock().unwrap();
        let servo = w.sts_servo_mut(knee).unwrap();
        assert!(servo.torque_enabled());
        // The policy's stiffness arrived as the servo's P coefficient.
        assert!(servo.register(addr::P_GAIN) > 0);
    }
    // The right knee's servo loses power: stale within the bus's bound, the loop stops.
    for _ in 0..20 {
        tick(&mut player, &mut clock);
    }
    let stop = player
        .transitions()
        .iter()
        .find(|t| t.to == controller::safety::Mode::Stopping || t.to == controller::safety::Mode::Damped)
        .copied()
        .expect("a stop");
    assert!(
        matches!(stop.cause, controller::safety::Cause::StaleFeedback { .. }),
        "{stop:?}"
    );
    let gone_tick = (gone_at / 0.02) as u64;
    assert!(stop.tick > gone_tick && stop.tick <= gone_tick + 5, "{stop:?}");
    // What the servo cannot do is refused by field, before anything moves.
    let e = Robot::from_str(
        &mini("robot.toml"),
        &test_support::zoo::on_feetech(&text).replace("velocity_limit = 4.5", "velocity_limit = 6.0"),
    )
    .unwrap_err()
    .to_string();
    assert!(e.contains("velocity_limit") && e.contains("no-load speed"), "{e}");
    let e = Robot::from_str(
        &mini("robot.toml"),
        &test_support::zoo::on_feetech(&text)
            .replace("rate = 1000000", "rate = 1000000\ncommand_timeout_ms = 100.0"),
    )
    .unwrap_err()
    .to_string();
    assert!(
        e.contains("command_timeout_ms") && e.contains("no command watchdog"),
        "{e}"
    );
}
