//! ROS 2 from a run (`play --ros2`): a peer made of Cyclone DDS and ROS 2's type names only
//! (`tests/python/ros2_client.py`, in a network namespace of the test's own), subscribing with
//! ROS 2's default (reliable) profile as tf2, RViz and diagnostic_aggregator do, receives the run's
//! `/joint_states`, `/tf`, `/robot_description` (joining late) and `/diagnostics`, and walks the G1
//! through `/cmd_vel`; bad ROS 2 settings are refused by name.

use serde_json::Value;
use test_support::bin::{robodeploy_path, run};
use test_support::fixtures::workspace_root;

#[test]
fn a_cyclone_dds_peer_with_ros2_names_sees_the_run_and_walks_the_g1_through_cmd_vel() {
    let g1 = workspace_root().join("robots/g1/robot.toml");
    let record = std::env::temp_dir().join(format!("ros2-run-{}.mcap", std::process::id()));
    let mut args = vec![
        "0.5".to_owned(),
        "--".to_owned(),
        robodeploy_path().display().to_string(),
    ];
    args.extend(
        [
            "play",
            "--robot",
            &g1.display().to_string(),
            "--wall",
            "--ros2",
            "--cmd-vel",
        ]
        .into_iter()
        .chain([
            "--max-seconds",
            "14",
            "--record",
            &record.display().to_string(),
            "--overwrite",
        ])
        .map(str::to_owned),
    );
    let verdict = test_support::netns::python_verdict("tests/python/ros2_client.py", &args);
    let v: Value = serde_json::from_str(&verdict).unwrap_or_else(|e| panic!("{e}: {verdict}"));
    let n = |k: &str| v[k].as_u64().unwrap_or_else(|| panic!("{k}: {v}"));
    let run: Vec<&str> = v["stdout"]
        .as_array()
        .unwrap()
        .iter()
        .filter_map(Value::as_str)
        .collect();
    let run_text = run.join("\n");
    // A machine starved by the suite around it (or by the peer's own start-up beside the run) may
    // end a wall-clock run early with a device stop (the robot's correct answer to late feedback)
    // or an overrun stop (to its own late ticks: seen here with the tick start p99 at 40 ms). The
    // topics are checked either way, over the ticks the run made; the walk only on a full run.
    let starved = v["exit"] == 3
        && (run_text.contains("): device fault")
            || run_text.contains("): no feedback for")
            || run_text.contains("deadline overruns in a row"));
    if starved {
        let lateness = run
            .iter()
            .find(|l| l.starts_with("tick start lateness"))
            .unwrap_or(&"(no lateness line)");
        eprintln!("the machine starved the wall-clock run into a safety stop (allowed): {lateness}");
    }
    // The joints by name, every tick the peer was there for (it joins within the first second or
    // so), in robot.toml's order.
    let ticks: u64 = run
        .iter()
        .find_map(|l| l.strip_prefix("ran "))
        .and_then(|l| l.split_whitespace().next())
        .and_then(|w| w.parse().ok())
        .unwrap_or_else(|| panic!("no tick count:\n{run_text}"));
    let joined_for = if starved { ticks / 2 } else { ticks * 3 / 4 };
    // Read as ROS 2 subscribes by default (reliable), and best effort beside it.
    assert!(
        (starved || ticks >= 200)
            && n("joint_states") >= joined_for
            && n("joint_states_best_effort") >= joined_for,
        "{ticks} ticks: {v}"
    );
    let robot = robots::Robot::load(&g1).unwrap();
    let names: Vec<&str> = robot.config.joints.iter().map(|j| j.name.as_str()).collect();
    let got: Vec<&str> = v["joint_names"]
        .as_array()
        .unwrap()
        .iter()
        .filter_map(Value::as_str)
        .collect();
    assert_eq!(got, names, "{v}");
    assert_eq!(v["positions_finite"], Value::Bool(true), "{v}");
    // A wall-clock run is stamped in Unix time: no /clock.
    assert_eq!(n("clock"), 0, "{v}");
    // Every link's frame, the root in `world`.
    assert!(n("tf") >= joined_for, "{ticks} ticks: {v}");
    let frames = v["frames"].as_array().unwrap();
    assert!(frames.len() >= 30 && frames.iter().any(|f| f == "pelvis"), "{v}");
    assert!(
        v["tf_parents"].as_array().unwrap().iter().any(|f| f == "world"),
        "{v}"
    );
    // Health once a second and at each change of mode, for the robot by name.
    assert!(n("diagnostics") >= ticks / 50 / 2, "{ticks} ticks: {v}");
    let loop_messages = v["loop_messages"].to_string();
    assert!(loop_messages.contains("Running: start"), "{v}");
    assert_eq!(v["loop_hardware"], serde_json::json!(["g1"]), "{v}");
    if starved {
        let _ = std::fs::remove_file(&record);
        return;
    }
    // The URDF, to a reader that joined seconds after it was published (transient local; a run
    // a starved machine stopped early may be over before it joins).
    assert_eq!(v["description_has_robot"], Value::Bool(true), "{v}");
    // The frames fixed to their parents (the G1's foot contact points) once on /tf_static, to a
    // reader joining late, and not every tick on /tf.
    let fixed = ["left_foot_contact_point", "right_foot_contact_point"];
    assert_eq!(v["static_frames"], serde_json::json!(fixed), "{v}");
    assert!(
        frames.iter().all(|f| !fixed.contains(&f.as_str().unwrap_or(""))),
        "{v}"
    );
    assert!(n("description_chars") > 10_000, "{v}");
    // /cmd_vel drove the policy: the commands were taken and the robot walked forward.
    let accepted: u64 = run
        .iter()
        .filter(|l| l.contains(" accepted"))
        .find_map(|l| l.strip_prefix("commands: "))
        .and_then(|l| l.split_whitespace().next())
        .and_then(|w| w.parse().ok())
        .unwrap_or_else(|| panic!("no command count:\n{run_text}"));
    assert!(accepted >= 100, "{run_text}");
    assert_eq!(v["exit"], 0, "{run_text}");
    assert!(run_text.contains("fell: no"), "{run_text}");
    let forward = run.iter().find(|l| l.starts_with("forward")).unwrap();
    let numbers: Vec<f64> = forward
        .split(|c: char| !(c.is_ascii_digit() || c == '.' || c == '-' || c == '+'))
        .filter_map(|w| w.parse().ok())
        .collect();
    assert!(numbers[0] > 0.25 && numbers[1] > 0.15, "{forward}");
    let _ = std::fs::remove_file(&record);
}

/// A lockstep run (simulated time, faster than real time) publishes `/clock`, and its messages are
/// stamped on that clock: a node with `use_sim_time` follows the run.
#[test]
fn a_lockstep_run_publishes_its_simulated_time_on_clock() {
    let record = std::env::temp_dir().join(format!("ros2-clock-{}.mcap", std::process::id()));
    let args: Vec<String> = ["0.0", "--", &robodeploy_path().display().to_string()]
        .into_iter()
        .chain([
            "play",
            "--ros2",
            "--end",
            "loop",
            "--max-seconds",
            "240",
            "--overwrite",
        ])
        .map(str::to_owned)
        .chain(["--record".to_owned(), record.display().to_string()])
        .collect();
    let verdict = test_support::netns::python_verdict("tests/python/ros2_client.py", &args);
    let v: Value = serde_json::from_str(&verdict).unwrap_or_else(|e| panic!("{e}: {verdict}"));
    assert_eq!(v["exit"], 0, "{v}");
    let seconds = |k: &str| -> Vec<f64> {
        v[k].as_array()
            .unwrap_or_else(|| panic!("{k}: {v}"))
            .iter()
            .filter_map(Value::as_f64)
            .collect()
    };
    let (clock, stamps) = (seconds("clock_s"), seconds("joint_state_stamps_s"));
    assert!(clock.len() >= 50, "{} clock samples: {v}", clock.len());
    // Simulated time from the run's start, never back.
    assert!(clock.iter().all(|&t| (0.0..=241.0).contains(&t)), "{clock:?}");
    assert!(clock.windows(2).all(|w| w[1] > w[0]), "{clock:?}");
    // The joints are stamped on that clock (the peer keeps what arrived between its polls of each).
    let both = stamps
        .iter()
        .filter(|s| clock.iter().any(|c| (*c - **s).abs() < 1e-9))
        .count();
    assert!(both >= 50, "{both} joint states at a /clock time: {v}");
    let _ = std::fs::remove_file(&record);
}

#[test]
fn bad_ros2_settings_are_refused_by_name() {
    let g1 = workspace_root().join("robots/g1/robot.toml");
    let g1 = g1.to_str().unwrap();
    let (ok, out, err) = run(&["play", "--robot", g1, "--ros2", "rdnosuch0", "--max-seconds", "1"]);
    assert!(!ok, "{out}");
    assert!(
        err.contains("--ros2") && err.contains("\"rdnosuch0\" does not exist"),
        "{err}"
    );
    assert!(!out.contains("ran "), "the run started: {out}");
    let (ok, _, err) = run(&["play", "--robot", g1, "--ros2", "--ros2-domain", "300"]);
    assert!(!ok && err.contains("--ros2-domain"), "{err}");
    let (ok, _, err) = run(&["play", "--robot", g1, "--cmd-vel"]);
    assert!(!ok && err.contains("--ros2"), "{err}");
    let (ok, _, err) = run(&["play", "--robot", g1, "--ros2", "--no-record"]);
    assert!(!ok && err.contains("--no-record"), "{err}");
}
