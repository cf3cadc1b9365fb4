//! Run telemetry: the MCAP a run writes is read back by Python's `mcap` package, and a full ring
//! counts its drops.

use std::sync::Arc;
use std::sync::atomic::AtomicBool;

use controller::clip::{Clip, Reference};
use controller::player::PlayOptions;
use controller::sim::lockstep_player;
use controller::telemetry::{Backpressure, TelemetrySink, TickRecord};
use policy::PolicyLayout;
use robot_link::RobotLink;
use robots::{Robot, reference_robot_path};
use sim2real::config::MirrorConfig;

/// What `tests/python/SCRIPT FILE` prints, as JSON (the script must succeed).
fn python_json(script: &str, file: &std::path::Path) -> serde_json::Value {
    let script = test_support::fixtures::workspace_root()
        .join("tests/python")
        .join(script);
    let out = std::process::Command::new(test_support::fixtures::venv_python())
        .arg(script)
        .arg(file)
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    serde_json::from_slice(&out.stdout).unwrap()
}

#[test]
fn a_recorded_run_reads_back_in_python_with_the_reported_counts() {
    let robot = Robot::load(&reference_robot_path()).unwrap();
    let layout = PolicyLayout::load(
        &reference_robot_path().with_file_name("policies/reference_follower.toml"),
        &robot,
    )
    .unwrap();
    let clip = Clip::load(&reference_robot_path().with_file_name("clips/wave_and_look.csv")).unwrap();
    let reference = Reference::from_clip(&clip, &robot, 50.0).unwrap();
    let path = std::env::temp_dir().join(format!("run-{}.mcap", std::process::id()));
    let names: Vec<String> = robot.config.joints.iter().map(|j| j.name.clone()).collect();
    let mjcf = robot.mjcf_path.clone();
    let mjcf_joints: Vec<String> = robot.config.joints.iter().map(|j| j.mjcf_joint.clone()).collect();
    let (p, mut clock, _w) = lockstep_player(
        robot,
        layout,
        reference,
        PlayOptions::default(),
        MirrorConfig::default(),
        Arc::new(AtomicBool::new(false)),
    )
    .unwrap();
    let info = controller::telemetry::RecordingInfo {
        joint_names: names.clone(),
        root_frame: "pelvis".into(),
        kinematics: Some((mjcf.clone(), mjcf_joints.clone())),
        bus_names: p.link().bus_names().to_vec(),
        observation_len: p.recording_info().observation_len,
        ..Default::default()
    };
    let sink = TelemetrySink::start(&path, 64, Backpressure::Block, &info).unwrap();
    let mut p = p.with_telemetry(sink);
    let summary = p.run(&mut clock).unwrap();
    let t = summary.telemetry.expect("recorded");
    assert_eq!(
        (t.pushed, t.written, t.dropped),
        (summary.ticks, summary.ticks, 0)
    );

    let v = python_json("read_mcap.py", &path);
    for (topic, n) in &t.messages {
        assert_eq!(v["counts"][topic].as_u64(), Some(*n), "topic {topic}: {v}");
    }
    assert_eq!(v["counts"]["/joint_state"].as_u64(), Some(summary.ticks));
    // Viewers' schemas: Foxglove's well-known ones, and the project's own typed ones.
    assert_eq!(v["schemas"]["/tf"], "foxglove.FrameTransforms");
    assert_eq!(v["schemas"]["/robot"], "foxglove.SceneUpdate");
    assert_eq!(v["schemas"]["/log"], "foxglove.Log");
    assert_eq!(v["schemas"]["/joint_state"], "robodeploy.JointStates");
    assert_eq!(v["schemas"]["/policy"], "robodeploy.PolicyStep");
    assert_eq!(v["metadata"]["/timing"]["bus_names"], "can0,can1,dxl0");
    // One frame-transform message a tick: the world → root frame, then every link below it.
    assert_eq!(v["counts"]["/tf"].as_u64(), Some(summary.ticks));
    let first_tf = v["first"]["/tf"]["transforms"].as_array().unwrap();
    assert_eq!(
        (
            first_tf[0]["parent_frame_id"].as_str(),
            first_tf[0]["child_frame_id"].as_str()
        ),
        (Some("world"), Some("pelvis"))
    );
    assert_eq!(first_tf.len(), 22, "root + 21 links");
    let frames: Vec<&str> = v["tf_children"]
        .as_array()
        .unwrap()
        .iter()
        .map(|f| f.as_str().unwrap())
        .collect();
    assert!(
        frames.contains(&"left_foot") && frames.contains(&"head"),
        "{frames:?}"
    );
    // The robot's geometry once, an entity locked to each link's frame: the 3D view shows the
    // robot, not bare axes.
    assert_eq!(v["counts"]["/robot"].as_u64(), Some(1));
    let scene: Vec<&str> = v["scene_frames"]
        .as_array()
        .unwrap()
        .iter()
        .map(|f| f.as_str().unwrap())
        .collect();
    for body in ["pelvis", "torso", "head", "left_foot", "right_shin"] {
        assert!(scene.contains(&body), "{body} not in the scene: {scene:?}");
    }
    let pelvis = &v["first"]["/robot"]["entities"][0];
    assert_eq!(pelvis["frame_locked"], true, "{pelvis}");
    // Joints are named in every message.
    let joints = v["first"]["/joint_state"]["joints"].as_array().unwrap();
    assert_eq!(joints.len(), 20);
    assert_eq!(joints[0]["name"], "left_hip_yaw");
    assert_eq!(v["counts"]["/log"], v["counts"]["/safety"]);
    let modes: Vec<&str> = v["modes"]
        .as_array()
        .unwrap()
        .iter()
        .map(|m| m.as_str().unwrap())
        .collect();
    // Ready lasts no longer than tick 0, so the first recorded mode is SoftStart.
    assert_eq!(modes, ["SoftStart", "Running", "Stopping", "Damped", "Off"]);

    // Rerun imports the same file with its own MCAP decoders: the links' transforms as
    // Transform3D, the safety log as TextLog, the joint states as named, plottable scalars.
    let rerun = python_json("rerun_import.py", &path);
    assert_eq!(
        rerun["rows"]["/joint_state"].as_u64(),
        Some(summary.ticks),
        "{rerun}"
    );
    assert_eq!(rerun["rows"]["/tf"].as_u64(), Some(22 * summary.ticks), "{rerun}");
    let has = |path: &str, component: &str| {
        rerun["components"][path]
            .as_array()
            .is_some_and(|c| c.iter().any(|n| n == component))
    };
    assert!(
        has("/tf", "Transform3D:translation") && has("/tf", "Transform3D:quaternion"),
        "{rerun}"
    );
    assert!(has("/log", "TextLog:text"), "{rerun}");
    let edges: Vec<(String, String)> = serde_json::from_value(rerun["frames"].clone()).unwrap();
    for edge in [
        ("world", "pelvis"),
        ("left_ankle_link", "left_foot"),
        ("head_yaw_link", "head"),
    ] {
        assert!(
            edges.contains(&(edge.0.to_owned(), edge.1.to_owned())),
            "{edge:?} not in {edges:?}"
        );
    }
    let mut sorted = names.clone();
    sorted.sort();
    assert_eq!(rerun["joints"], serde_json::json!(sorted));
    assert_eq!(rerun["samples"].as_u64(), Some(summary.ticks));
    assert_eq!(rerun["finite"], true);
    // The robot's URDF on /robot_description (ROS 2's std_msgs/msg/String): Rerun builds the
    // robot's geometry from it, each link's shapes in the frame `/tf` moves.
    assert_eq!(v["schemas"]["/robot_description"], "std_msgs/msg/String");
    assert_eq!(v["counts"]["/robot_description"].as_u64(), Some(1));
    let urdf_frames: Vec<String> = serde_json::from_value(rerun["urdf_frames"].clone()).unwrap();
    for body in ["pelvis", "torso", "head", "left_foot", "right_shin"] {
        assert!(
            urdf_frames.iter().any(|f| f == body),
            "{body} has no geometry: {urdf_frames:?}"
        );
    }
    assert_eq!(
        rerun["urdf_shapes"],
        serde_json::json!(["Boxes3D", "Cylinders3D", "Ellipsoids3D"])
    );
    // Joint positions plottable by name with no code: ROS 2's sensor_msgs/msg/JointState on
    // /joint_states becomes one named scalar series per joint, value for value /joint_state's.
    assert_eq!(v["schemas"]["/joint_states"], "sensor_msgs/msg/JointState");
    // Python's own ROS 2 decoder (mcap-ros2-support) reads both from their ros2msg schemas.
    assert_eq!(v["first"]["/joint_states"]["name"], serde_json::json!(names));
    let urdf = v["first"]["/robot_description"]["data"].as_str().unwrap();
    assert!(
        urdf.starts_with("<?xml") && urdf.contains("<joint name=\"left_knee\" type=\"revolute\">"),
        "{urdf}"
    );
    assert_eq!(rerun["series"]["names"], serde_json::json!(names));
    assert_eq!(rerun["series"]["rows"].as_u64(), Some(summary.ticks));
    assert_eq!(rerun["series"]["agree"], true, "{}", rerun["series"]);
    std::fs::remove_file(&path).unwrap();
}

#[test]
fn an_overflowing_ring_counts_every_dropped_record() {
    let path = std::env::temp_dir().join(format!("overflow-{}.mcap", std::process::id()));
    let mut sink = TelemetrySink::start(
        &path,
        2,
        Backpressure::Drop,
        &controller::telemetry::RecordingInfo {
            joint_names: vec!["j".into()],
            root_frame: "base".into(),
            observation_len: 512,
            ..Default::default()
        },
    )
    .unwrap();
    let mut r = TickRecord {
        joints: 1,
        ..TickRecord::default()
    };
    let obs = [0.5f32; 512];
    // Pushing far faster than encoding a 512-value observation can keep up with.
    for k in 0..5000 {
        r.tick = k;
        r.time_ns = k * 1000;
        sink.push_with(&r, &obs);
    }
    let report = sink.finish().unwrap();
    assert_eq!(report.pushed, 5000);
    assert!(report.dropped > 0, "{report:?}");
    assert_eq!(report.written + report.dropped, report.pushed);
    assert!(
        report
            .to_string()
            .contains(&format!("{} dropped", report.dropped))
    );
    std::fs::remove_file(&path).unwrap();
}

#[test]
fn ten_minutes_of_records_at_500_hz_lose_nothing_in_lockstep() {
    // The lockstep loop's recorder blocks instead of dropping: 10 minutes of 500 Hz records of the
    // reference robot's size (20 joints, 127 observations) pushed faster than the logger encodes.
    let dir = std::env::temp_dir().join(format!("long-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let names: Vec<String> = (0..20).map(|i| format!("j{i}")).collect();
    let path = dir.join("long.mcap");
    let mut sink = TelemetrySink::start(
        &path,
        1024,
        Backpressure::Block,
        &controller::telemetry::RecordingInfo {
            joint_names: names.clone(),
            root_frame: "pelvis".into(),
            observation_len: 127,
            ..Default::default()
        },
    )
    .unwrap();
    let ticks: u64 = 10 * 60 * 500;
    let mut r = TickRecord {
        joints: 20,
        mode: 3,
        ..TickRecord::default()
    };
    let mut obs = [0.0f32; 127];
    for k in 0..ticks {
        r.tick = k;
        r.time_ns = k * 2_000_000;
        r.q[k as usize % 20] = k as f64 * 1e-6;
        obs[k as usize % 127] = k as f32;
        sink.push_with(&r, &obs);
    }
    let report = sink.finish().unwrap();
    assert_eq!((report.pushed, report.written, report.dropped), (ticks, ticks, 0));
    assert_eq!(report.messages["/joint_state"], ticks);
    // Read back: every tick's joint state is in the file.
    let bytes = std::fs::read(&path).unwrap();
    let count = mcap::MessageStream::new(&bytes)
        .unwrap()
        .filter(|m| m.as_ref().unwrap().channel.topic == "/joint_state")
        .count();
    assert_eq!(count as u64, ticks);
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn ten_minutes_of_a_500_hz_bus_recorded_from_the_loop_lose_nothing_in_lockstep() {
    // The reference robot with both CAN buses at 500 Hz (1.62 ms of wire time in 2 ms), the loop
    // recording every bus cycle: a real 500 Hz stream per CAN bus through the loop's ring.
    let text = std::fs::read_to_string(reference_robot_path())
        .unwrap()
        .replacen("name = \"can0\"", "name = \"can0\"\nrate_hz = 500.0", 1)
        .replacen("name = \"can1\"", "name = \"can1\"\nrate_hz = 500.0", 1);
    let robot = Robot::from_str(&reference_robot_path(), &text).unwrap();
    let layout = PolicyLayout::load(
        &reference_robot_path().with_file_name("policies/reference_follower.toml"),
        &robot,
    )
    .unwrap();
    let clip = Clip::load(&reference_robot_path().with_file_name("clips/squat.csv")).unwrap();
    let reference = Reference::from_clip(&clip, &robot, layout.manifest.rate_hz).unwrap();
    let ticks: u64 = 10 * 60 * 50;
    let options = PlayOptions {
        end: controller::player::EndMode::Loop,
        max_ticks: Some(ticks),
        ..PlayOptions::default()
    };
    let (p, mut clock, _world) = lockstep_player(
        robot.clone(),
        layout,
        reference,
        options,
        MirrorConfig::default(),
        Arc::new(AtomicBool::new(false)),
    )
    .unwrap();
    let mut p = p;
    assert!(p.record_bus_cycles());
    let dir = std::env::temp_dir().join(format!("bus-rate-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("bus.mcap");
    let buses = p.link().bus_names().to_vec();
    let info = controller::telemetry::RecordingInfo {
        joint_names: p.joint_names(),
        root_frame: p.root_frame(),
        bus_names: buses.clone(),
        bus_cycles: Some(
            buses
                .iter()
                .map(|b| robot.joints_on(b).map(|(i, _)| i).collect())
                .collect(),
        ),
        ..Default::default()
    };
    let sink = TelemetrySink::start(&path, 1024, Backpressure::Block, &info).unwrap();
    let mut p = p.with_telemetry(sink);
    let s = p.run(&mut clock).unwrap();
    let report = s.telemetry.unwrap();
    assert_eq!(report.dropped, 0, "{report:?}");
    assert_eq!(report.written, report.pushed);
    let can0 = report.messages["/bus/can0"];
    // 500 Hz for the whole run: ten cycles per tick waited for (the last tick has no wait).
    let seconds = s.ticks as f64 / 50.0;
    assert!(
        (can0 as f64 - 500.0 * seconds).abs() <= 20.0,
        "{can0} cycles in {seconds} s"
    );
    assert_eq!(report.messages["/bus/can1"], can0);
    // Every cycle is in the file, numbered without a gap.
    let bytes = std::fs::read(&path).unwrap();
    let mut next = 0;
    for m in mcap::MessageStream::new(&bytes).unwrap() {
        let m = m.unwrap();
        if m.channel.topic == "/bus/can0" {
            let v = <telemetry_schema::BusCycle as prost::Message>::decode(&m.data[..]).unwrap();
            assert_eq!(v.cycle, next);
            assert_eq!(v.joints.len(), 6, "{v:?}");
            next += 1;
        }
    }
    assert_eq!(next, can0);
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_recording_carries_the_files_it_was_made_from_and_is_never_overwritten_silently() {
    let dir = std::env::temp_dir().join(format!("telemetry-files-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let record = dir.join("run.mcap");
    let play = |extra: &[&str]| {
        let mut args = vec!["play", "--max-seconds", "1"];
        args.extend_from_slice(extra);
        test_support::bin::robodeploy()
            .args(&args)
            .current_dir(&dir)
            .output()
            .unwrap()
    };
    let out = play(&["--record", record.to_str().unwrap()]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    // robot.toml, the manifest and the clip ride along as attachments; a `run` record names them.
    let bytes = std::fs::read(&record).unwrap();
    let summary = mcap::Summary::read(&bytes).unwrap().expect("a summary");
    let names: Vec<&str> = summary
        .attachment_indexes
        .iter()
        .map(|a| a.name.as_str())
        .collect();
    assert_eq!(
        names,
        [
            "robot/robot.toml",
            "robot/biped.xml",
            "policy/reference_follower.toml",
            "clip/squat.csv"
        ],
        "{names:?}"
    );
    let attached = mcap::read::attachment(&bytes, &summary.attachment_indexes[0]).unwrap();
    assert_eq!(
        attached.data.as_ref(),
        std::fs::read(reference_robot_path()).unwrap().as_slice()
    );
    let run = summary
        .metadata_indexes
        .iter()
        .find(|m| m.name == "run")
        .expect("a run record");
    let run = mcap::read::metadata(&bytes, run).unwrap();
    assert_eq!(run.metadata["clip"], "squat.csv");
    assert!(
        run.metadata["options"].contains("\"estimator\""),
        "{:?}",
        run.metadata
    );
    // The same path again: refused by name, the first recording intact; --overwrite replaces it.
    let out = play(&["--record", record.to_str().unwrap()]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success() && stderr.contains("--overwrite"),
        "{stderr}"
    );
    assert_eq!(std::fs::read(&record).unwrap(), bytes);
    let out = play(&["--record", record.to_str().unwrap(), "--overwrite"]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    // Default paths: the second run takes the next name.
    for _ in 0..2 {
        assert!(play(&[]).status.success());
    }
    let runs = dir.join("out/runs");
    assert!(runs.join("rd-biped-squat.mcap").exists() && runs.join("rd-biped-squat-2.mcap").exists());
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_recording_is_written_as_its_settings_say_and_the_run_says_what_it_cost() {
    let dir = std::env::temp_dir().join(format!("telemetry-settings-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let record = dir.join("run.mcap");
    let out = test_support::bin::robodeploy()
        .args(["play", "--max-seconds", "2", "--record"])
        .arg(&record)
        .args([
            "--record-compression",
            "zstd",
            "--record-level",
            "1",
            "--record-chunk-kib",
            "16",
        ])
        .args(["--record-every", "/tf=5", "--record-every", "/imu=0"])
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let bytes = std::fs::read(&record).unwrap();
    let summary = mcap::Summary::read(&bytes).unwrap().expect("a summary");
    // Every chunk zstd, none much over 16 KiB before compression but for the one carrying the
    // robot's geometry.
    assert!(
        summary.chunk_indexes.len() > 10,
        "{} chunks",
        summary.chunk_indexes.len()
    );
    assert!(summary.chunk_indexes.iter().all(|c| c.compression == "zstd"));
    let small = summary
        .chunk_indexes
        .iter()
        .filter(|c| c.uncompressed_size < 2 * 16 * 1024)
        .count();
    assert!(
        small + 1 >= summary.chunk_indexes.len(),
        "{small} of {}",
        summary.chunk_indexes.len()
    );
    let mut counts = std::collections::BTreeMap::<String, u64>::new();
    for m in mcap::MessageStream::new(&bytes).unwrap() {
        *counts.entry(m.unwrap().channel.topic.clone()).or_default() += 1;
    }
    let ticks = counts["/replay"];
    assert!(ticks >= 100, "{counts:?}");
    assert_eq!(counts["/joint_state"], ticks, "{counts:?}");
    assert_eq!(counts["/tf"], ticks.div_ceil(5), "{counts:?}");
    assert!(!counts.contains_key("/imu"), "{counts:?}");
    // The run says what it held: its peak and MuJoCo's share of it.
    let memory = stdout
        .lines()
        .find(|l| l.starts_with("memory: peak "))
        .unwrap_or_else(|| panic!("{stdout}"));
    assert!(memory.contains("MuJoCo's model and data"), "{memory}");
    // The run says what it wrote and what that cost.
    let cost = stdout
        .lines()
        .find(|l| l.starts_with("recording cost: "))
        .unwrap_or_else(|| panic!("{stdout}"));
    assert!(
        cost.contains("(zstd level 1 in 16 KiB chunks, /tf every 5 ticks, /imu off)")
            && cost.contains("s of CPU")
            && cost.contains("handing records over"),
        "{cost}"
    );
    let mb: f64 = cost["recording cost: ".len()..]
        .split(" MB")
        .next()
        .unwrap()
        .parse()
        .unwrap();
    assert!(
        (mb - bytes.len() as f64 / 1e6).abs() < 0.051,
        "{cost}: {} bytes",
        bytes.len()
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

/// The fields of `message` (a `robodeploy.*` or nested type) in the recordings' descriptor set.
fn fields_of(message: &str) -> Vec<(String, String)> {
    let fds =
        <prost_types::FileDescriptorSet as prost::Message>::decode(telemetry_schema::DESCRIPTOR_SET).unwrap();
    let ours = fds.file.iter().find(|f| f.package() == "robodeploy").unwrap();
    let name = message
        .trim_start_matches(".robodeploy.")
        .trim_start_matches("robodeploy.");
    let m = ours
        .message_type
        .iter()
        .find(|m| m.name() == name)
        .unwrap_or_else(|| panic!("no message {message}"));
    m.field
        .iter()
        .map(|f| (f.name().to_owned(), f.type_name().to_owned()))
        .collect()
}

#[test]
fn the_shipped_foxglove_layouts_are_what_the_command_writes_and_every_plot_reads_a_recorded_field() {
    let root = test_support::fixtures::workspace_root();
    // The channels a recording of the reference robot has, and their schemas.
    let dir = std::env::temp_dir().join(format!("layout-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let run = dir.join("run.mcap");
    let out = test_support::bin::robodeploy()
        .args(["play", "--max-seconds", "0.5", "--record"])
        .arg(&run)
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let bytes = std::fs::read(&run).unwrap();
    let mut schemas = std::collections::BTreeMap::new();
    for m in mcap::MessageStream::new(&bytes).unwrap() {
        let m = m.unwrap();
        let schema = m
            .channel
            .schema
            .as_ref()
            .map(|s| s.name.clone())
            .unwrap_or_default();
        schemas.insert(m.channel.topic.clone(), schema);
    }
    for (robot, shipped) in [
        (
            "robots/biped/robot.toml",
            "docs/guide/src/foxglove/rd-biped.layout.json",
        ),
        (
            "robots/mini/robot.toml",
            "docs/guide/src/foxglove/rd-mini.layout.json",
        ),
    ] {
        let out = test_support::bin::robodeploy()
            .args(["layout", "--robot"])
            .arg(root.join(robot))
            .output()
            .unwrap();
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
        let written = String::from_utf8(out.stdout).unwrap();
        assert_eq!(
            written,
            std::fs::read_to_string(root.join(shipped)).unwrap(),
            "{shipped} is stale: regenerate it with `robodeploy layout --robot {robot} -o {shipped}`"
        );
        let joints: Vec<String> = Robot::load(&root.join(robot))
            .unwrap()
            .config
            .joints
            .iter()
            .map(|j| j.name.clone())
            .collect();
        let layout: serde_json::Value = serde_json::from_str(&written).unwrap();
        let paths = viewers::layout::message_paths(&layout);
        assert!(paths.len() >= 3 * joints.len(), "{} paths", paths.len());
        for path in paths {
            // `/topic.field[:]{name=="joint"}.field`: the topic is recorded, each field is in
            // its message, the filter names one of the robot's joints.
            let (topic, rest) = path.split_once('.').unwrap();
            let schema = schemas
                .get(topic)
                .unwrap_or_else(|| panic!("{path}: {topic} is not recorded"));
            let mut message = schema.clone();
            for part in rest.split('.') {
                let (field, filter) = match part.split_once("[:]") {
                    Some((f, filter)) => (f, Some(filter)),
                    // An element by index: `keypoint_errors[0]`.
                    None => (part.split_once('[').map_or(part, |(f, _)| f), None),
                };
                let fields = fields_of(&message);
                let (_, type_name) = fields
                    .iter()
                    .find(|(n, _)| n == field)
                    .unwrap_or_else(|| panic!("{path}: {message} has no field {field}"));
                if let Some(filter) = filter {
                    let joint = filter.trim_start_matches("{name==\"").trim_end_matches("\"}");
                    assert!(joints.iter().any(|j| j == joint), "{path}: no joint {joint}");
                }
                message = type_name.clone();
            }
        }
    }
    std::fs::remove_dir_all(&dir).unwrap();
}
