//! Bench: the mirror at the physics floor (issue 53). Whole policy runs in lockstep, one core, per
//! robot: robodeploy's mirror over its wires (firmware, buses, drivers: the default), the same with
//! its recording, the direct mirror (`--fidelity direct`: the trainer's actuator law on MuJoCo, no
//! buses), against bare MuJoCo stepping the same model at the same step for the same simulated
//! time (`sim2real::floor::bare_hold`, the floor) and the project's plain Python loop (MuJoCo +
//! ONNX Runtime in a plain loop: `tests/python/plain_loop.py` for the small bipeds' walking policy,
//! `tests/python/holosoma_reference.py` for holosoma's G1 dance at either step; none is written for
//! rd-biped's clip follower). Every figure is wall time per simulated second, the median of
//! alternating rounds (the start-up not included: it has its own column), and the wires run's time
//! split into MuJoCo's step, the emulated devices and wires, and the host (drivers, observation,
//! policy, safety, the loop).
//!
//! Run: `cargo bench -p controller --bench floor` (3 rounds of whole runs); the smoke run of
//! `cargo test --benches` plays 2 s of each once. Words after `--` pick the robots whose names
//! contain one of them: `cargo bench -p controller --bench floor -- rd-mini`.

use std::process::Command;
use std::sync::Arc;
use std::sync::atomic::AtomicBool;
use std::time::Instant;

use controller::options::{EndMode, OnStop};
use controller::player::PlayOptions;
use controller::telemetry::{Backpressure, TelemetrySink};
use policy::PolicyLayout;
use robots::Robot;
use sim2real::config::{Fidelity, MirrorConfig};
use test_support::fixtures::{venv_python, workspace_root};
use test_support::zoo::ZooRobot;

const DANCE: &str = ".local/holosoma-inference/models/wbt/ppo_g1_29dof_dancing.onnx";

/// One robot and policy the bench runs.
struct Case {
    name: String,
    robot: Robot,
    policy: std::path::PathBuf,
    clip: Option<std::path::PathBuf>,
    command: Option<Vec<f64>>,
    /// Simulated seconds of policy control (the start's lead-in comes on top).
    seconds: f64,
    python: Option<Python>,
}

/// How the Python loop runs a case.
enum Python {
    /// `plain_loop.py ROBOT MANIFEST --command … --seconds …`.
    Plain { robot: std::path::PathBuf },
    /// `holosoma_reference.py dance --physics-dt STEP`.
    Holosoma { step: f64 },
}

/// What one robodeploy run measured.
#[derive(Debug, Clone, Copy, Default)]
struct Run {
    simulated: f64,
    start_up: f64,
    wall: f64,
    physics: f64,
    devices: f64,
    recording_cpu: f64,
}

fn robodeploy(case: &Case, fidelity: Fidelity, record: bool) -> Run {
    let loaded = Instant::now();
    let robot = case.robot.clone();
    let mut layout = PolicyLayout::load(&case.policy, &robot).unwrap();
    if let Some(c) = &case.command {
        layout.set_command(c).unwrap();
    }
    let (reference, _) =
        controller::reference::load_reference(case.clip.as_deref(), &case.policy, &mut layout, &robot, 0)
            .unwrap();
    let rate = layout.manifest.rate_hz;
    let h = robot.config.start.harness;
    let lead_in = if robot.config.start.mode == robots::StartMode::Harness {
        ((h.lower_s + h.settle_s) * rate).round() as u64
    } else {
        0
    };
    // A command-driven run goes on until stopped; at the end the robot stays standing under
    // the policy (a humanoid damped at the stop would fold, a cost no floor has).
    let options = PlayOptions {
        max_ticks: Some(lead_in + (case.seconds * rate).round() as u64),
        end: if case.command.is_some() {
            EndMode::Stand
        } else {
            EndMode::Hold
        },
        on_stop: OnStop::Stay,
        stand_s: Some(0.0),
        ..PlayOptions::default()
    };
    let mirror = MirrorConfig {
        fidelity,
        ..MirrorConfig::default()
    };
    let stop = Arc::new(AtomicBool::new(false));
    let path = std::env::temp_dir().join(format!("floor-bench-{}.mcap", std::process::id()));
    let summary;
    let world;
    let start_up;
    let wall;
    let mut recording_cpu = 0.0;
    macro_rules! play {
        ($made:expr) => {{
            let (mut player, mut clock, w) = $made.unwrap();
            if record {
                let info = player.recording_info();
                player = player
                    .with_telemetry(TelemetrySink::start(&path, 1024, Backpressure::Block, &info).unwrap());
            }
            start_up = loaded.elapsed().as_secs_f64();
            let before = w.lock().unwrap().stats();
            let began = Instant::now();
            summary = player.run(&mut clock).unwrap();
            wall = began.elapsed().as_secs_f64();
            let after = w.lock().unwrap().stats();
            world = (after.physics - before.physics, after.busy - before.busy);
        }};
    }
    match fidelity {
        Fidelity::Direct => play!(controller::sim::direct_player(
            robot, layout, reference, options, mirror, stop
        )),
        _ => play!(controller::sim::lockstep_player(
            robot, layout, reference, options, mirror, stop
        )),
    }
    if summary.fell {
        println!("  ({}: the robot fell in this run)", case.name);
    }
    if let Some(t) = &summary.telemetry {
        recording_cpu = t.cost.thread_cpu_s;
        let _ = std::fs::remove_file(&path);
    }
    let (physics, busy) = (world.0.as_secs_f64(), world.1.as_secs_f64());
    Run {
        simulated: summary.ticks as f64 / rate,
        start_up,
        wall,
        physics,
        devices: busy - physics,
        recording_cpu,
    }
}

/// The Python loop's own timing of its loop: (simulated s, wall s, start-up s).
fn python(case: &Case, how: &Python) -> Option<(f64, f64, f64)> {
    let root = workspace_root();
    let mut cmd = Command::new(venv_python());
    match how {
        Python::Plain { robot } => {
            cmd.arg(root.join("tests/python/plain_loop.py"))
                .arg(robot)
                .arg(&case.policy)
                .arg("--seconds")
                .arg(case.seconds.to_string());
            if let Some(c) = &case.command {
                cmd.arg("--command").args(c.iter().map(f64::to_string));
            }
        }
        Python::Holosoma { step } => {
            // 0: the whole motion.
            let frames = if case.seconds >= 131.5 {
                0
            } else {
                (case.seconds * 50.0).round() as usize
            };
            cmd.arg(root.join("tests/python/holosoma_reference.py"))
                .args(["dance", "--hold", "0", "--frames", &frames.to_string()])
                .args(["--physics-dt", &step.to_string()])
                .arg("--robot-dir")
                .arg(root.join(".local/holosoma"))
                .arg("--policy-dir")
                .arg(root.join(".local/holosoma-inference"));
        }
    }
    let began = Instant::now();
    let out = cmd.output().ok()?;
    let process = began.elapsed().as_secs_f64();
    if !out.status.success() {
        println!(
            "  (the Python loop failed: {})",
            String::from_utf8_lossy(&out.stderr).trim()
        );
        return None;
    }
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).ok()?;
    let wall = v["wall_s"].as_f64()?;
    Some((v["simulated_s"].as_f64()?, wall, process - wall))
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn cases(seconds: f64) -> Vec<Case> {
    let root = workspace_root();
    let mut cases = Vec::new();
    let biped = root.join("robots/biped");
    cases.push(Case {
        name: "rd-biped, squat clip (1 ms)".into(),
        robot: Robot::load(&biped.join("robot.toml")).unwrap(),
        policy: biped.join("policies/reference_follower.toml"),
        clip: Some(biped.join("clips/squat.csv")),
        command: None,
        seconds: seconds.min(6.0),
        python: None,
    });
    let mini = root.join("robots/mini/robot.toml");
    let walk = ZooRobot::walking_policy();
    cases.push(Case {
        name: "rd-mini (Dynamixel), walk".into(),
        robot: Robot::load(&mini).unwrap(),
        policy: walk.clone(),
        clip: None,
        command: Some(vec![0.2]),
        seconds,
        python: Some(Python::Plain { robot: mini.clone() }),
    });
    let zoo = std::env::temp_dir().join(format!("floor-bench-zoo-{}", std::process::id()));
    let feetech = ZooRobot::FeetechBiped.write(&zoo);
    cases.push(Case {
        name: "Feetech biped (zoo), walk".into(),
        robot: Robot::load(&feetech).unwrap(),
        policy: walk,
        clip: None,
        command: Some(vec![0.2]),
        seconds,
        python: Some(Python::Plain { robot: feetech }),
    });
    let g1 = root.join("robots/g1/robot.toml");
    if root.join(DANCE).exists() {
        let text = std::fs::read_to_string(&g1).unwrap();
        for step in [0.002, 0.005] {
            let robot = if step == 0.002 {
                Robot::load(&g1).unwrap()
            } else {
                Robot::from_str(&g1, &format!("{text}\n[sim]\ntimestep = {step}\n")).unwrap()
            };
            cases.push(Case {
                name: format!("G1 dance ({} ms)", step * 1000.0),
                robot,
                policy: root.join(DANCE),
                clip: None,
                command: None,
                // The whole dance in a full run (a stop mid-dance can topple the robot).
                seconds: if seconds >= 20.0 { 131.5 } else { seconds * 6.0 },
                python: Some(Python::Holosoma { step }),
            });
        }
    } else {
        println!("holosoma's G1 dance is not installed (scripts/setup): its rows are left out");
    }
    cases
}

fn main() {
    let full = std::env::args().any(|a| a == "--bench");
    let picked: Vec<String> = std::env::args().skip(1).filter(|a| !a.starts_with('-')).collect();
    let (rounds, seconds) = if full { (3, 20.0) } else { (1, 2.0) };
    println!(
        "the mirror at the physics floor: lockstep policy runs, one core, median of {rounds} alternating rounds;\n\
         ms of wall time per simulated second (start-up apart)\n"
    );
    println!(
        "{:<30} {:>6} | {:>8} {:>8} {:>8} | {:>8} {:>8} | {:>7} {:>7} {:>7} | {:>8} {:>8} {:>8}",
        "robot, motion (step)",
        "sim s",
        "wires",
        "+record",
        "direct",
        "floor",
        "Python",
        "w/floor",
        "d/floor",
        "w/Py",
        "start s",
        "Py load",
        "rec CPU"
    );
    let mut splits = Vec::new();
    let wanted = |c: &Case| picked.is_empty() || picked.iter().any(|p| c.name.contains(p.as_str()));
    for case in cases(seconds).into_iter().filter(wanted) {
        let (mut wires, mut recorded, mut direct, mut floor, mut py) =
            (Vec::new(), Vec::new(), Vec::new(), Vec::new(), Vec::new());
        let (mut last, mut py_start, mut rec_cpu) = (Run::default(), Vec::new(), Vec::new());
        for _ in 0..rounds {
            let w = robodeploy(&case, Fidelity::Wires, false);
            wires.push(w.wall / w.simulated);
            let r = robodeploy(&case, Fidelity::Wires, true);
            recorded.push(r.wall / r.simulated);
            rec_cpu.push(r.recording_cpu / r.simulated * 1000.0);
            let d = robodeploy(&case, Fidelity::Direct, false);
            direct.push(d.wall / d.simulated);
            let (took, _) = sim2real::floor::bare_hold(&case.robot, w.simulated).unwrap();
            floor.push(took.as_secs_f64() / w.simulated);
            if let Some(how) = &case.python
                && let Some((sim, wall, start)) = python(&case, how)
            {
                py.push(wall / sim);
                py_start.push(start);
            }
            last = w;
        }
        let ms = |v: &[f64]| 1000.0 * median(v.to_vec());
        let (w, r, d, f) = (ms(&wires), ms(&recorded), ms(&direct), ms(&floor));
        let p = (!py.is_empty()).then(|| ms(&py));
        let show = |v: Option<f64>, digits: usize| v.map_or("—".to_owned(), |v| format!("{v:.digits$}"));
        println!(
            "{:<30} {:>6.1} | {w:>8.1} {r:>8.1} {d:>8.1} | {f:>8.1} {:>8} | {:>7.2} {:>7.2} {:>7} | {:>8.2} {:>8} {:>8.1}",
            case.name,
            last.simulated,
            show(p, 1),
            w / f,
            d / f,
            show(p.map(|p| w / p), 2),
            last.start_up,
            show((!py_start.is_empty()).then(|| median(py_start.clone())), 2),
            median(rec_cpu),
        );
        splits.push((case.name, last));
    }
    println!(
        "\nw/floor, d/floor: the wires and direct runs against bare MuJoCo; w/Py: against the Python loop.\n\
         rec CPU: the recording thread's CPU, ms per simulated second (on the second core).\n\
         start s: robodeploy from reading the files to its first tick, in its process; Py load: the\n\
         Python process's time outside its loop (interpreter, imports, model and policy).\n\
         The floor holds the default pose; the runs move (a walk's or a dance's contacts cost the solver more).\n\n\
         where the wires run's time goes, ms per simulated second (the last round):"
    );
    println!(
        "{:<30} {:>8} {:>10} {:>10} {:>8}",
        "robot, motion (step)", "MuJoCo", "devices", "host", "total"
    );
    for (name, r) in splits {
        let per = |v: f64| 1000.0 * v / r.simulated;
        println!(
            "{name:<30} {:>8.1} {:>10.1} {:>10.1} {:>8.1}",
            per(r.physics),
            per(r.devices),
            per(r.wall - r.physics - r.devices),
            per(r.wall)
        );
    }
}
