//! Policies as BeyondMimic and mjlab export them (fixtures in that convention, written by
//! scripts/gen_tracking_export.py): the contract comes from the ONNX metadata, the reference from
//! the motion the graph carries, the anchor terms from the robot's kinematics.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::AtomicBool;

use controller::player::{PlayOptions, PlaySummary};
use controller::reference::ReferenceSource;
use controller::sim::lockstep_player;
use controller::telemetry::{Backpressure, TelemetrySink};
use policy::PolicyLayout;
use robots::{Robot, reference_robot_path};
use sim2real::config::{MirrorConfig, StartPose};
use test_support::fixtures::fixture;

#[global_allocator]
static ALLOC: test_support::alloc::CountingAllocator = test_support::alloc::CountingAllocator;

fn squat() -> PathBuf {
    reference_robot_path().with_file_name("clips/squat.csv")
}

/// The export's layout, bound to its model, and the motion it carries.
fn load(export: &Path, start_step: usize) -> (Robot, PolicyLayout, controller::clip::Reference) {
    let robot = Robot::load(&reference_robot_path()).unwrap();
    let mut layout = PolicyLayout::load(export, &robot).unwrap();
    let (reference, source) =
        controller::reference::load_reference(None, &squat(), &mut layout, &robot, start_step).unwrap();
    assert!(matches!(source, ReferenceSource::Embedded { .. }), "{source}");
    (robot, layout, reference)
}

fn play(export: &Path, mirror: MirrorConfig, record: Option<&Path>) -> (PolicyLayout, PlaySummary) {
    let (robot, layout, reference) = load(export, 0);
    let kept = layout.clone();
    let (p, mut clock, _w) = lockstep_player(
        robot,
        layout,
        reference,
        PlayOptions::default(),
        mirror,
        Arc::new(AtomicBool::new(false)),
    )
    .unwrap();
    let mut p = match record {
        Some(path) => {
            let info = p.recording_info();
            p.with_telemetry(TelemetrySink::start(path, 64, Backpressure::Block, &info).unwrap())
        }
        None => p,
    };
    (kept, p.run(&mut clock).unwrap())
}

fn assert_tracks(s: &PlaySummary) {
    assert!(s.success(), "{s}");
    assert!(s.joint_rmse.to_degrees() < 3.0, "{s}");
    assert_eq!(s.body_rmse.len(), 9, "{s}");
    for (body, e) in &s.body_rmse {
        assert!(*e < 0.04, "{body}: {:.1} cm\n{s}", e * 100.0);
    }
    let mean = s.body_rmse.iter().map(|b| b.1).sum::<f64>() / 9.0;
    assert!(mean < 0.02, "{s}");
}

#[test]
fn each_export_variant_plays_on_the_mirror_without_a_manifest_and_tracks() {
    for name in [
        "rd_biped_tracking.onnx",
        "rd_biped_tracking_wose.onnx",
        "rd_biped_tracking_history.onnx",
    ] {
        let (layout, s) = play(&fixture(name), MirrorConfig::default(), None);
        assert_eq!(
            layout.manifest.joints.first().map(String::as_str),
            Some("head_yaw"),
            "{name}: the metadata's joint order (the MJCF's), not robot.toml's"
        );
        assert_tracks(&s);
        assert!((s.played - 1.0).abs() < 1e-9, "{name}: {s}");
    }
}

#[test]
fn the_reference_is_put_under_a_robot_that_starts_1_m_away_and_turned_90_degrees() {
    let mirror = MirrorConfig {
        start: StartPose {
            position: [0.6, -0.8],
            yaw_deg: 90.0,
            ..StartPose::default()
        },
        ..MirrorConfig::default()
    };
    let path = std::env::temp_dir().join(format!("tracking-aligned-{}.mcap", std::process::id()));
    let (_, s) = play(&fixture("rd_biped_tracking.onnx"), mirror, Some(&path));
    // Bodies are compared with the aligned reference: without the alignment every one of them
    // would be a metre off.
    assert_tracks(&s);
    let root = s.root_rmse.expect("the mirror knows the root");
    assert!(root < 0.03, "{s}");
    // The first tracked tick: the reference anchor lies on the robot's, in heading and on the
    // floor plane.
    let first = first_anchors(&path);
    let (robot, reference) = (&first[..7], &first[7..]);
    let horizontal = ((robot[0] - reference[0]).powi(2) + (robot[1] - reference[1]).powi(2)).sqrt();
    assert!(horizontal < 0.005, "{first:?}");
    let heading = |p: &[f64]| robots::spatial::heading_of_quat([p[3], p[4], p[5], p[6]]);
    let turn = (heading(robot) - heading(reference)).abs();
    assert!(turn.to_degrees() < 1.0, "{first:?}");
    assert!((heading(robot).to_degrees() - 90.0).abs() < 2.0, "{first:?}");
    // The report reads the same body errors back from the recording.
    let dir = path.with_extension("report");
    let r = analysis::report::write_report(&path, &dir).unwrap();
    assert_eq!(r.body_rmse_cm.len(), 9);
    for (body, e) in &s.body_rmse {
        let reported = r.body_rmse_cm[body];
        assert!(
            (reported - 100.0 * e).abs() < 0.05,
            "{body}: {reported} cm vs {e} m"
        );
    }
    assert_eq!(r.anchor_rmse_cm, Some(r.body_rmse_cm["torso"]));
    std::fs::remove_dir_all(&dir).unwrap();
    std::fs::remove_file(&path).unwrap();
}

/// The robot's and the reference's anchor of the first policy tick a recording holds.
fn first_anchors(path: &Path) -> Vec<f64> {
    let script = "import json,sys\nfrom mcap.reader import make_reader\n\
        from mcap_protobuf.decoder import DecoderFactory\n\
        r=make_reader(open(sys.argv[1],'rb'),decoder_factories=[DecoderFactory()])\n\
        pose=lambda p:[p.position.x,p.position.y,p.position.z,p.orientation.w,p.orientation.x,p.orientation.y,p.orientation.z]\n\
        for _,c,m,d in r.iter_decoded_messages(topics=['/policy']):\n\
        \x20   if d.HasField('robot_anchor'):\n\
        \x20       print(json.dumps(pose(d.robot_anchor)+pose(d.reference_anchor))); break\n";
    let out = std::process::Command::new(test_support::fixtures::venv_python())
        .args(["-c", script])
        .arg(path)
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    serde_json::from_slice(&out.stdout).unwrap()
}

#[test]
fn anchor_terms_and_the_command_match_numpy_and_onnx_runtime_on_a_recorded_run() {
    for (name, has_pos) in [
        ("rd_biped_tracking.onnx", true),
        ("rd_biped_tracking_wose.onnx", false),
    ] {
        let path = std::env::temp_dir().join(format!("tracking-{}-{name}.mcap", std::process::id()));
        let mirror = MirrorConfig {
            start: StartPose {
                position: [0.3, 0.2],
                yaw_deg: -40.0,
                ..StartPose::default()
            },
            ..MirrorConfig::default()
        };
        let (layout, s) = play(&fixture(name), mirror, Some(&path));
        assert_tracks(&s);
        let at = |term: &str| {
            layout
                .slots
                .iter()
                .find(|s| s.term.name() == term)
                .map_or(-1, |s| s.range.start as i64)
        };
        assert_eq!(at("motion_anchor_pos_b") >= 0, has_pos);
        let script = test_support::fixtures::workspace_root().join("tests/python/check_tracking_export.py");
        let out = std::process::Command::new(test_support::fixtures::venv_python())
            .arg(script)
            .arg(&path)
            .arg(fixture(name))
            .args(
                [
                    at("motion_anchor_ori_b"),
                    at("motion_anchor_pos_b"),
                    at("motion_command"),
                    20,
                    (layout.hold_s() * 50.0).round() as i64,
                ]
                .map(|v| v.to_string()),
            )
            .output()
            .unwrap();
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
        let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
        assert!(v["ticks"].as_u64().unwrap() > 300, "{v}");
        assert!(v["ori_max_err"].as_f64().unwrap() < 1e-6, "{name}: {v}");
        assert!(v["pos_max_err"].as_f64().unwrap() < 1e-6, "{name}: {v}");
        // Every policy tick observed the export's own frame for its time, none early or late.
        assert_eq!(v["frames_mismatched"], 0, "{name}: {v}");
        assert_eq!(v["frames_matched"], v["ticks"], "{name}: {v}");
        std::fs::remove_file(&path).unwrap();
    }
}

#[test]
fn a_run_can_start_part_way_into_the_motion() {
    let (_, _, whole) = load(&fixture("rd_biped_tracking_wose.onnx"), 0);
    let (_, _, tail) = load(&fixture("rd_biped_tracking_wose.onnx"), 100);
    assert_eq!(tail.len(), whole.len() - 100);
    assert_eq!(tail.q_at(0), whole.q_at(100));
}

#[test]
fn a_manifest_may_override_the_exports_fields() {
    let robot = Robot::load(&reference_robot_path()).unwrap();
    let dir = std::env::temp_dir().join(format!("tracking-manifest-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let export = fixture("rd_biped_tracking_wose.onnx");
    let write = |text: &str| {
        let path = dir.join("policy.toml");
        std::fs::write(
            &path,
            format!("onnx = {:?}\n{text}", export.display().to_string()),
        )
        .unwrap();
        PolicyLayout::load(&path, &robot)
    };
    let layout = write("[action]\nkind = \"position\"\nscale = 0.1\nrate_limit = 6.0\n").unwrap();
    assert!(layout.action_scale.iter().all(|&s| s == 0.1));
    assert_eq!(layout.manifest.action.rate_limit, Some(6.0));
    assert_eq!(layout.manifest.anchor_body.as_deref(), Some("torso"));
    let e = write("anchor_body = \"chest\"\n").unwrap_err().to_string();
    assert!(
        e.contains("anchor_body") && e.contains("\"chest\" is not a body"),
        "{e}"
    );
    let e = write("motion_bodies = [\"pelvis\", \"tail\"]\n")
        .unwrap_err()
        .to_string();
    assert!(e.contains("motion_bodies") && e.contains("tail"), "{e}");
    // A NUL byte in a name (MuJoCo's names are C strings) names no body; found by fuzzing.
    let e = write("motion_bodies = [\"pe\\u0000\"]\n")
        .unwrap_err()
        .to_string();
    assert!(e.contains("motion_bodies: not bodies of"), "{e}");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn what_a_run_cannot_provide_or_does_not_fit_is_refused_before_anything_moves() {
    let run = |args: &[&str]| {
        let (ok, _, err) = test_support::bin::run(args);
        (ok, err)
    };
    let full = fixture("rd_biped_tracking.onnx");
    let full = full.to_str().unwrap();
    // The anchor position and base velocity come from the estimator on hardware: there is no
    // ground truth there.
    let (code, err) = run(&[
        "play",
        "--hardware",
        "--estimator",
        "ground-truth",
        "--policy",
        full,
        "--no-record",
    ]);
    assert!(!code);
    assert!(err.contains("the hardware has no ground truth"), "{err}");
    // A clip beside an export that carries its motion: one of them would be ignored.
    let squat = squat();
    let (code, err) = run(&[
        "play",
        "--policy",
        full,
        "--clip",
        squat.to_str().unwrap(),
        "--no-record",
    ]);
    assert!(!code);
    assert!(err.contains("carries its own motion"), "{err}");
    // An export whose body quaternions are x y z w: its bodies do not fit the model at its
    // joints.
    let xyzw = fixture("rd_biped_tracking_xyzw.onnx");
    let (code, err) = run(&["check", "--policy", xyzw.to_str().unwrap()]);
    assert!(!code);
    assert!(
        err.contains("does not fit the robot's model") && err.contains("quaternion order"),
        "{err}"
    );
    // A start beyond the motion.
    let (code, err) = run(&["play", "--policy", full, "--start-step", "5000", "--no-record"]);
    assert!(!code);
    assert!(
        err.contains("--start-step 5000") && err.contains("frames"),
        "{err}"
    );
}

#[test]
fn a_steady_state_tick_with_the_exports_motion_and_kinematics_allocates_nothing() {
    use controller::safety::Mode;
    let (robot, layout, reference) = load(&fixture("rd_biped_tracking.onnx"), 0);
    let (mut p, mut clock, _w) = lockstep_player(
        robot,
        layout,
        reference,
        PlayOptions::default(),
        MirrorConfig::default(),
        Arc::new(AtomicBool::new(false)),
    )
    .unwrap();
    p.identify().unwrap();
    let period = std::time::Duration::from_millis(20);
    let mut ticks = |range: std::ops::RangeInclusive<u32>| {
        for k in range {
            p.step(&clock).unwrap();
            p.wait_until(&mut clock, period * k);
        }
    };
    ticks(1..=80);
    let (_, stats) = test_support::alloc::count_allocations(|| ticks(81..=180));
    assert_eq!(p.mode(), Mode::Running);
    assert!(stats.is_zero(), "{stats:?}");
}

#[test]
fn an_anchor_above_the_imus_body_is_reached_through_the_joints_between() {
    use robots::spatial;
    use world::RobotKinematics;
    let robot = Robot::load(&reference_robot_path()).unwrap();
    // The head sits above the pelvis (the IMU's body) through head_yaw (about z) and head_pitch.
    let mut k = RobotKinematics::new(&robot, Some("head"), &["head".to_owned()]).unwrap();
    let head_yaw = robot
        .config
        .joints
        .iter()
        .position(|j| j.name == "head_yaw")
        .unwrap();
    let mut q = vec![0.0; robot.config.joints.len()];
    q[head_yaw] = 0.5;
    let imu = spatial::quat_of_rpy(0.0, 0.0, std::f64::consts::FRAC_PI_2);
    k.update(imu, &q, &vec![0.0; q.len()], Some([1.0, 2.0, 0.0]));
    let a = k.anchor_pose();
    let heading = spatial::heading_of_quat([a[3], a[4], a[5], a[6]]);
    assert!(
        (heading - (std::f64::consts::FRAC_PI_2 + 0.5)).abs() < 1e-9,
        "{a:?}"
    );
    // Straight above the root (head on the torso's axis), at the root's place.
    assert!(
        (a[0] - 1.0).abs() < 1e-9 && (a[1] - 2.0).abs() < 1e-9 && a[2] > 0.2,
        "{a:?}"
    );
    // The gyro turns from the IMU's frame into the root's (the same frame here).
    assert_eq!(k.imu_to_root([0.1, 0.2, 0.3]), [0.1, 0.2, 0.3]);
}

#[test]
fn a_recorded_export_run_replays_bit_for_bit() {
    // Through the CLI: the recording names the export as the run's clip, and replay plays the
    // motion it carries again.
    let path = std::env::temp_dir().join(format!("tracking-replay-{}.mcap", std::process::id()));
    // The full variant: the anchor position and base velocity come from the state estimator,
    // which the replay feeds the recorded IMU samples again.
    let export = fixture("rd_biped_tracking.onnx");
    let (ok, _, err) = test_support::bin::run(&[
        "play",
        "--policy",
        export.to_str().unwrap(),
        "--start-step",
        "40",
        "--record",
        path.to_str().unwrap(),
    ]);
    assert!(ok, "{err}");
    let report = analysis::replay::replay(&path).unwrap();
    assert!(report.ticks > 300, "{report}");
    assert!(report.first_difference.is_none(), "{report}");
    std::fs::remove_file(&path).unwrap();
}

#[test]
fn an_exported_default_pose_just_past_a_limit_by_the_rounding_is_clamped() {
    let robot = Robot::load(&reference_robot_path()).unwrap();
    let follower = reference_robot_path().with_file_name("policies/reference_follower.toml");
    let text = std::fs::read_to_string(&follower).unwrap().replace(
        "reference_follower.onnx",
        follower.with_extension("onnx").to_str().unwrap(),
    );
    let (head, tables) = text.split_once("\n[").unwrap();
    let manifest = |hip_yaw: f64| {
        let mut pose = vec!["0.0".to_owned(); 20];
        pose[0] = format!("{hip_yaw}");
        format!(
            "{head}\ndefault_pose = [{}]\nstiffness = [{}]\ndamping = [{}]\n\n[{tables}",
            pose.join(", "),
            ["20.0"; 20].join(", "),
            ["1.0"; 20].join(", ")
        )
    };
    // left_hip_yaw's limits are ±0.5 rad: 0.5004 is 0.500 written with 3 decimals, then rounded up.
    let layout = PolicyLayout::parse(&follower, &manifest(0.5004), &robot).unwrap();
    assert_eq!(layout.default_q[0], 0.5);
    let e = PolicyLayout::parse(&follower, &manifest(0.502), &robot)
        .unwrap_err()
        .to_string();
    assert!(e.contains("default_pose") && e.contains("left_hip_yaw"), "{e}");
}

#[test]
fn an_export_without_its_action_scale_is_refused_by_name_not_played_at_scale_1() {
    // The export as a trainer might write it but for one key: `action_scale` (its real scales
    // are 0.025–0.087 rad; 1 would swing every joint tens of degrees too far).
    let dir = std::env::temp_dir().join(format!("robodeploy-no-scale-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let stripped = dir.join("no_action_scale.onnx");
    let script = "import onnx, sys\n\
                  m = onnx.load(sys.argv[1])\n\
                  keep = [p for p in m.metadata_props if p.key != 'action_scale']\n\
                  assert len(keep) < len(m.metadata_props)\n\
                  del m.metadata_props[:]\n\
                  m.metadata_props.extend(keep)\n\
                  onnx.save(m, sys.argv[2])\n";
    let export = fixture("rd_biped_tracking.onnx");
    test_support::fixtures::run_python(script, &[export.as_os_str(), stripped.as_os_str()]);
    let policy = stripped.to_str().unwrap();
    for args in [
        &["check", "--policy", policy][..],
        &["play", "--policy", policy, "--no-record"],
    ] {
        let command = args[0];
        let (code, out, err) = test_support::bin::run_within(args, std::time::Duration::from_secs(120));
        assert_eq!(code, Some(2), "{command}: {out}{err}");
        assert!(err.contains("action.scale: missing"), "{command}: {err}");
        assert!(!out.contains("Running"), "{command}: something moved: {out}");
    }
    std::fs::remove_dir_all(&dir).unwrap();
}
