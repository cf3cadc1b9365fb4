//! 2D keypoint references: a clip seen by two cameras, reloaded, measured against itself, against
//! a biased camera, and against a pose estimator's COCO JSON with several people and missing
//! points; bad cameras and keypoints refused by name.

use std::path::{Path, PathBuf};

use test_support::bin::robodeploy;

fn biped(file: &str) -> PathBuf {
    robots::reference_robot_path().with_file_name(file)
}

fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("keypoints-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// `robodeploy project` with `args`: exit success, standard output and error.
fn project(args: &[&std::ffi::OsStr]) -> (bool, String) {
    let out = robodeploy().arg("project").args(args).output().unwrap();
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    (out.status.success(), text)
}

/// The squat projected through the shipped cameras into `dir`/squat.csv, read back.
fn projected_squat(dir: &Path) -> controller::keypoints::clip::KeypointClip {
    let keypoints = dir.join("squat.csv");
    squat_keypoints(&biped("cameras.toml"), &keypoints);
    let cameras = controller::keypoints::camera::load_cameras(&biped("cameras.toml")).unwrap();
    controller::keypoints::clip::KeypointClip::load_csv(&keypoints, &cameras).unwrap()
}

/// Projects the squat through `cameras` into `out`.
fn squat_keypoints(cameras: &Path, out: &Path) {
    let clip = biped("clips/squat.csv");
    let (ok, text) = project(&[
        "--clip".as_ref(),
        clip.as_os_str(),
        "--camera".as_ref(),
        cameras.as_os_str(),
        "-o".as_ref(),
        out.as_os_str(),
    ]);
    assert!(ok, "{text}");
}

/// The comparison of the squat against `reference` seen by `cameras` (extra args appended).
fn compare(cameras: &Path, reference: &Path, extra: &[&str], json: &Path) -> serde_json::Value {
    let clip = biped("clips/squat.csv");
    let mut args: Vec<&std::ffi::OsStr> = vec![
        "--clip".as_ref(),
        clip.as_os_str(),
        "--camera".as_ref(),
        cameras.as_os_str(),
        "--against".as_ref(),
        reference.as_os_str(),
        "--json".as_ref(),
        json.as_os_str(),
    ];
    args.extend(extra.iter().map(std::ffi::OsStr::new));
    let (ok, text) = project(&args);
    assert!(ok, "{text}");
    serde_json::from_str(&std::fs::read_to_string(json).unwrap()).unwrap()
}

#[test]
fn a_clip_seen_by_two_cameras_reloads_exactly_and_a_2_px_camera_bias_reads_as_2_px() {
    let dir = scratch("bias");
    let clip = projected_squat(&dir);
    let keypoints = dir.join("squat.csv");
    assert_eq!(clip.views, ["front", "side"]);
    assert_eq!(clip.names.len(), 17);
    assert_eq!(clip.len(), 211, "7 s at 30 Hz");

    // Against itself: nothing, in 2D and in 3D.
    let c = compare(&biped("cameras.toml"), &keypoints, &[], &dir.join("self.json"));
    for v in c["views"].as_array().unwrap() {
        assert!(v["max_px"].as_f64().unwrap() < 1e-6, "{v}");
        assert_eq!(v["compared"], 211 * 17);
    }
    assert!(c["triangulated_mm"][1].as_f64().unwrap() < 1e-3, "{c}");

    // The side camera's principal point 2 px to the right: 2 px on that view, none on the other.
    let text = std::fs::read_to_string(biped("cameras.toml")).unwrap();
    let side = text.rfind("cx = 640.0").unwrap();
    let biased = dir.join("biased.toml");
    std::fs::write(
        &biased,
        format!("{}cx = 642.0{}", &text[..side], &text[side + 10..]),
    )
    .unwrap();
    let c = compare(&biased, &keypoints, &[], &dir.join("biased.json"));
    let views = c["views"].as_array().unwrap();
    assert!(views[0]["max_px"].as_f64().unwrap() < 1e-6, "{c}");
    for field in ["mean_px", "max_px"] {
        let e = views[1][field].as_f64().unwrap();
        assert!((e - 2.0).abs() < 1e-6, "side {field} {e}");
    }
    assert_eq!(views[1]["failed_frames"], 0);
    // Triangulated through the wrong camera, the keypoints move a few millimetres.
    let mm = c["triangulated_mm"][0].as_f64().unwrap();
    assert!(mm > 0.5 && mm < 20.0, "{mm} mm");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn coco_keypoints_pick_the_person_by_id_and_skip_missing_and_unsure_points() {
    let dir = scratch("coco");
    let clip = projected_squat(&dir);
    // A pose estimator's results on the front camera's video: the robot as track 7 in COCO's
    // order, a passer-by as track 3; frame 10 without the robot, its left wrist never sure, its
    // nose missing every 5th frame.
    let coco = controller::keypoints::clip::COCO_KEYPOINTS;
    let mut detections = Vec::new();
    let mut expected = 0;
    for f in 0..clip.len() {
        let seen = clip.at(f, 0);
        let mut values = Vec::new();
        for name in coco {
            let k = clip.names.iter().position(|n| n == name).unwrap();
            let (u, v) = (seen[k][0], seen[k][1]);
            let confidence = match name {
                "left_wrist" => 0.02,
                "nose" if f % 5 == 0 => 0.0,
                _ => 0.9,
            };
            if confidence > 0.05 && f != 10 {
                expected += 1;
            }
            values.extend([u, v, confidence]);
        }
        if f != 10 {
            detections.push(serde_json::json!({"image_id": format!("frame_{f:04}.jpg"), "category_id": 1, "track_id": 7, "score": 0.95, "keypoints": values}));
        }
        let decoy: Vec<f64> = (0..17).flat_map(|i| [100.0 + f64::from(i), 200.0, 0.8]).collect();
        detections.push(serde_json::json!({"image_id": format!("frame_{f:04}.jpg"), "category_id": 1, "track_id": 3, "score": 0.7, "keypoints": decoy}));
    }
    let path = dir.join("results.json");
    std::fs::write(&path, serde_json::to_string(&detections).unwrap()).unwrap();
    let c = compare(
        &biped("cameras.toml"),
        &path,
        &["--view", "front", "--person", "7", "--fps", "30"],
        &dir.join("coco.json"),
    );
    let front = &c["views"][0];
    assert_eq!(front["view"], "front");
    assert_eq!(front["compared"].as_u64(), Some(expected), "{c}");
    assert!(front["max_px"].as_f64().unwrap() < 1e-6, "{c}");
    assert_eq!(c["triangulated_mm"], serde_json::Value::Null, "one view");

    // Without --person: which one is ambiguous, and said so.
    let squat = biped("clips/squat.csv");
    let cams = biped("cameras.toml");
    let base: Vec<&std::ffi::OsStr> = vec![
        "--clip".as_ref(),
        squat.as_os_str(),
        "--camera".as_ref(),
        cams.as_os_str(),
        "--against".as_ref(),
        path.as_os_str(),
        "--view".as_ref(),
        "front".as_ref(),
    ];
    let (ok, text) = project(&base);
    assert!(
        !ok && text.contains("2 people (ids 7, 3): pick one with --person ID"),
        "{text}"
    );
    // A keypoint off the image is refused by its image and name (an unsure one is not looked at).
    detections[0]["keypoints"][3] = serde_json::json!(5000.0);
    std::fs::write(&path, serde_json::to_string(&detections).unwrap()).unwrap();
    let mut args = base.clone();
    args.extend([std::ffi::OsStr::new("--person"), std::ffi::OsStr::new("7")]);
    let (ok, text) = project(&args);
    assert!(
        !ok && text.contains("image frame_0000.jpg, left_eye: (5000,")
            && text.contains("outside camera front's 1280×720 image"),
        "{text}"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn bad_cameras_and_keypoint_maps_are_refused_by_name() {
    let dir = scratch("bad");
    let good = std::fs::read_to_string(biped("cameras.toml")).unwrap();
    let squat = biped("clips/squat.csv");
    for (from, to, says) in [
        (
            "fx = 1000.0",
            "fx = -5.0",
            "camera[0] (front).fx: -5: a focal length is positive",
        ),
        (
            "fy = 800.0",
            "fy = 0.0",
            "camera[1] (side).fy: 0: a focal length is positive",
        ),
        (
            "look_at = [0.0, 0.0, 0.5]\n\n",
            "orientation = [1.0, 0.3, 0.0, 0.0]\n\n",
            "camera[0] (front).orientation: [1.0, 0.3, 0.0, 0.0] is not a rotation",
        ),
        (
            "cx = 640.0",
            "cx = 2000.0",
            "camera[0] (front).cx: 2000 px is outside the image (0–1280)",
        ),
        (
            "width = 1280",
            "width = 0",
            "camera[0] (front).width: 0 px is outside 1–16384",
        ),
        ("k1 = -0.05", "k1 = -0.05\nzoom = 2", "unknown field `zoom`"),
    ] {
        let path = dir.join("cams.toml");
        assert!(good.contains(from), "{from}");
        std::fs::write(&path, good.replacen(from, to, 1)).unwrap();
        let (ok, text) = project(&[
            "--clip".as_ref(),
            squat.as_os_str(),
            "--camera".as_ref(),
            path.as_os_str(),
        ]);
        assert!(!ok && text.contains(says), "{to}: {text}");
    }
    // A keypoint map naming a frame the model lacks.
    let robot = dir.join("robot.toml");
    let text = std::fs::read_to_string(robots::reference_robot_path())
        .unwrap()
        .replace("left_knee = \"left_shin\"", "left_knee = \"left_kneecap\"")
        .replace(
            "mjcf = \"biped.xml\"",
            &format!("mjcf = {:?}", biped("biped.xml").display().to_string()),
        );
    std::fs::write(&robot, text).unwrap();
    let err = robots::Robot::load(&robot).unwrap_err().to_string();
    assert!(
        err.contains("keypoints.left_knee") && err.contains("\"left_kneecap\" is neither a body nor a site"),
        "{err}"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

/// A lockstep run of the squat on the mirror, with `keypoints` (2D references made through
/// `project_through`) measured through `cameras`, under `policy`.
struct KeypointRun {
    player: controller::player::Player<sim2real::link::LockstepRobot>,
    clock: sim2real::link::LockstepClock,
    _world: std::sync::Arc<std::sync::Mutex<sim2real::mirror::Mirror>>,
}

fn keypoint_run(policy: &Path, project_through: &[Camera], cameras: &[Camera]) -> KeypointRun {
    use controller::clip::{Clip, Reference};
    use controller::keypoints::track::KeypointReference;
    let robot = robots::Robot::load(&robots::reference_robot_path()).unwrap();
    let layout = policy::PolicyLayout::load(policy, &robot).unwrap();
    let clip = Clip::load(&biped("clips/squat.csv")).unwrap();
    let mut reference = Reference::from_clip(&clip, &robot, layout.manifest.rate_hz).unwrap();
    // The 2D references as `robodeploy project` makes them: the clip at 30 Hz, projected.
    let at_30 = Reference::from_clip(&clip, &robot, 30.0).unwrap();
    let (names, positions) = controller::keypoints::keypoint_positions(&robot, &at_30).unwrap();
    let times: Vec<f64> = (0..at_30.len()).map(|k| k as f64 / 30.0).collect();
    let keypoints = controller::keypoints::project(project_through, &names, &times, &positions);
    reference.keypoints =
        Some(KeypointReference::new(&keypoints, cameras, layout.manifest.rate_hz, reference.len()).unwrap());
    let (player, clock, world) = on_the_mirror(robot, layout, reference).unwrap();
    KeypointRun {
        player,
        clock,
        _world: world,
    }
}

impl KeypointRun {
    fn tick(&mut self, k: u32) {
        self.player.step(&self.clock).unwrap();
        self.player
            .wait_until(&mut self.clock, std::time::Duration::from_millis(20) * k);
    }
}

use controller::keypoints::camera::Camera;

/// A lockstep run of `reference` under `layout` on the default mirror, default options.
fn on_the_mirror(
    robot: robots::Robot,
    layout: policy::PolicyLayout,
    reference: controller::clip::Reference,
) -> Result<controller::sim::LockstepRun, controller::player::PlayError> {
    controller::sim::lockstep_player(
        robot,
        layout,
        reference,
        controller::player::PlayOptions::default(),
        sim2real::config::MirrorConfig::default(),
        std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false)),
    )
}

fn cameras(path: &Path) -> Vec<Camera> {
    controller::keypoints::camera::load_cameras(path).unwrap()
}

#[test]
fn played_as_2d_references_the_robots_keypoints_are_measured_per_view_and_tick() {
    let cams = cameras(&biped("cameras.toml"));
    let policy =
        test_support::fixtures::workspace_root().join("tests/fixtures/policies/keypoint_follower.toml");
    let mut run = keypoint_run(&policy, &cams, &cams);
    run.player.identify().unwrap();
    let (mut measured, mut worst) = (0, [0.0f64; 2]);
    let layout = policy::PolicyLayout::load(
        &policy,
        &robots::Robot::load(&robots::reference_robot_path()).unwrap(),
    )
    .unwrap();
    let slot = |name: &str| {
        layout
            .slots
            .iter()
            .find(|s| s.term.name() == name)
            .unwrap()
            .range
            .clone()
    };
    let (reference_slot, robot_slot) = (slot("ref_keypoints"), slot("keypoints"));
    for k in 1..=480u32 {
        run.tick(k);
        let errors = run.player.keypoint_errors();
        if errors.is_empty() {
            continue;
        }
        measured += 1;
        assert_eq!(errors.len(), 2, "both views, every tracked tick");
        for (v, e) in errors.iter().enumerate() {
            assert_eq!(e.compared, 17, "tick {k} view {v}: every keypoint seen");
            worst[v] = worst[v].max(e.max_px);
        }
        // The observation: the references now (2 views × 5 keypoints × (u, v, c)) in [−1, 1]
        // image coordinates, all seen; the robot's own keypoints within a few pixels of them.
        let obs = run.player.observation();
        let now = &obs[reference_slot.start..reference_slot.start + 30];
        let robot = &obs[robot_slot.clone()];
        for (r, m) in now.chunks(3).zip(robot.chunks(3)) {
            assert_eq!((r[2], m[2]), (1.0, 1.0), "seen, on the image");
            assert!(r[0].abs() < 1.0 && r[1].abs() < 1.0, "{r:?}");
            // 0.03 of the half-width: 19 px on the 1280 px image.
            assert!(
                (r[0] - m[0]).abs() < 0.03 && (r[1] - m[1]).abs() < 0.05,
                "tick {k}: {r:?} vs {m:?}"
            );
        }
    }
    assert!(measured >= 340, "{measured} ticks measured (the clip is 351)");
    let summary = run.player.run(&mut run.clock).unwrap();
    let kp = summary.keypoints.expect("the summary has the keypoints");
    assert_eq!(kp.views.len(), 2);
    for v in &kp.views {
        assert!(v.mean_px < 6.0 && v.failed_ticks == 0, "{v:?}");
        assert_eq!(v.ticks, 351, "{v:?}");
    }
    assert!(worst.iter().all(|&w| w < 30.0), "{worst:?}");
    let (mm, _) = kp.triangulated_mm.expect("two views triangulate");
    assert!(mm < 25.0, "{mm} mm");
}

#[test]
fn a_2_px_camera_bias_in_the_references_reads_as_2_px_in_every_tick() {
    // The same run twice on the deterministic mirror: references made through the true
    // cameras, and through a front camera whose principal point is 2 px to the right.
    let cams = cameras(&biped("cameras.toml"));
    let mut biased = cams.clone();
    biased[0].cx += 2.0;
    let policy = biped("policies/reference_follower.toml");
    let (mut a, mut b) = (
        keypoint_run(&policy, &cams, &cams),
        keypoint_run(&policy, &biased, &cams),
    );
    a.player.identify().unwrap();
    b.player.identify().unwrap();
    let mut compared = 0;
    for k in 1..=490u32 {
        a.tick(k);
        b.tick(k);
        assert_eq!(
            a.player.state().q,
            b.player.state().q,
            "tick {k}: the same motion"
        );
        let (ea, eb) = (a.player.keypoint_errors(), b.player.keypoint_errors());
        assert_eq!(ea.len(), eb.len());
        if ea.is_empty() {
            continue;
        }
        compared += 1;
        // Robot − reference: the reference moved 2 px right, so the offset is 2 px less.
        let du = ea[0].mean_du_px - eb[0].mean_du_px;
        assert!(
            (du - 2.0).abs() < 1e-6,
            "tick {k}: front offset changed by {du} px"
        );
        assert!((ea[0].mean_dv_px - eb[0].mean_dv_px).abs() < 1e-9);
        assert!((eb[0].mean_px - ea[0].mean_px).abs() <= 2.0 + 1e-9);
        assert_eq!(ea[1], eb[1], "tick {k}: the side view is untouched");
    }
    assert!(compared >= 340, "{compared}");
}

#[test]
fn a_policy_observing_keypoints_without_references_is_refused() {
    use controller::clip::{Clip, Reference};
    let robot = robots::Robot::load(&robots::reference_robot_path()).unwrap();
    let policy =
        test_support::fixtures::workspace_root().join("tests/fixtures/policies/keypoint_follower.toml");
    let layout = policy::PolicyLayout::load(&policy, &robot).unwrap();
    let reference =
        Reference::from_clip(&Clip::load(&biped("clips/squat.csv")).unwrap(), &robot, 50.0).unwrap();
    let err = on_the_mirror(robot, layout, reference)
        .map(|_| ())
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("keypoint_follower.toml observes 2D keypoints") && err.contains("--keypoints"),
        "{err}"
    );
    // From the command line: a keypoint file without its cameras, and one naming no camera.
    let out = robodeploy()
        .args(["play", "--no-record", "--keypoints", "k.csv"])
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && text.contains("--cameras"), "{text}");
}

#[test]
fn play_with_keypoint_references_reports_each_view() {
    let dir = scratch("play");
    let keypoints = dir.join("squat.csv");
    squat_keypoints(&biped("cameras.toml"), &keypoints);
    let (record, report) = (dir.join("run.mcap"), dir.join("report"));
    let cameras = biped("cameras.toml");
    let policy =
        test_support::fixtures::workspace_root().join("tests/fixtures/policies/keypoint_follower.toml");
    let out = robodeploy()
        .arg("play")
        .arg("--policy")
        .arg(&policy)
        .arg("--keypoints")
        .arg(&keypoints)
        .arg("--cameras")
        .arg(&cameras)
        .arg("--record")
        .arg(&record)
        .arg("--report")
        .arg(&report)
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{text}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(
        text.contains("keypoints ") && text.contains("17 keypoints in 2 views (front, side)"),
        "{text}"
    );
    assert!(
        text.contains("2D keypoints (the robot's, projected, against the references):"),
        "{text}"
    );
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(report.join("summary.json")).unwrap()).unwrap();
    let views = summary["keypoints"].as_array().unwrap();
    assert_eq!(views.len(), 2, "{summary}");
    for v in views {
        assert_eq!(v["ticks"], 351, "{v}");
        assert_eq!(v["failed_ticks"], 0, "{v}");
        assert!(v["mean_px"].as_f64().unwrap() < 6.0, "{v}");
    }
    assert!(summary["triangulated_mm"].as_f64().unwrap() < 25.0, "{summary}");
    let html = std::fs::read_to_string(report.join("report.html")).unwrap();
    assert!(
        html.contains("<h2>2D keypoints</h2>") && html.contains("reprojection error"),
        "the plot"
    );
    // The recording names the references and cameras: a replay feeds the policy the same
    // keypoint observations and gets the same commands.
    let out = robodeploy().arg("replay").arg(&record).output().unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success() && text.contains("every command matches the recording bit for bit"),
        "{text}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    // A keypoint file whose view has no camera.
    let one = dir.join("one.toml");
    let text = std::fs::read_to_string(&cameras).unwrap();
    std::fs::write(&one, &text[..text.rfind("[[camera]]").unwrap()]).unwrap();
    let out = robodeploy()
        .args(["play", "--no-record", "--keypoints"])
        .arg(&keypoints)
        .arg("--cameras")
        .arg(&one)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && err.contains("side"), "{err}");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn references_with_no_keypoint_seen_are_refused_not_reported_as_0_px() {
    let dir = scratch("unseen");
    let (squat, cams) = (biped("clips/squat.csv"), biped("cameras.toml"));
    // COCO results of track 7 only, every keypoint sure.
    let detections: Vec<serde_json::Value> = (0..30)
        .map(|f| {
            let values: Vec<f64> = (0..17).flat_map(|i| [600.0 + f64::from(i), 300.0, 0.9]).collect();
            serde_json::json!({"image_id": f, "category_id": 1, "track_id": 7, "keypoints": values})
        })
        .collect();
    let coco = dir.join("results.json");
    std::fs::write(&coco, serde_json::to_string(&detections).unwrap()).unwrap();
    // The same with every confidence 0.
    let unsure: Vec<serde_json::Value> = detections
        .iter()
        .map(|d| {
            let mut d = d.clone();
            for k in d["keypoints"].as_array_mut().unwrap().chunks_mut(3) {
                k[2] = serde_json::json!(0.0);
            }
            d
        })
        .collect();
    let zero = dir.join("zero.json");
    std::fs::write(&zero, serde_json::to_string(&unsure).unwrap()).unwrap();
    for (file, person) in [(&coco, "9"), (&zero, "7")] {
        let args: Vec<&std::ffi::OsStr> = vec![
            "--clip".as_ref(),
            squat.as_os_str(),
            "--camera".as_ref(),
            cams.as_os_str(),
            "--against".as_ref(),
            file.as_os_str(),
            "--view".as_ref(),
            "front".as_ref(),
            "--person".as_ref(),
            person.as_ref(),
        ];
        let (ok, text) = project(&args);
        assert!(!ok, "{text}");
        assert!(text.contains("no keypoint is seen in any of its"), "{text}");
        assert!(!text.contains("0.00 px"), "{text}");
        // play --keypoints refuses them the same way, before anything moves.
        let policy =
            test_support::fixtures::workspace_root().join("tests/fixtures/policies/keypoint_follower.toml");
        let out = robodeploy()
            .arg("play")
            .arg("--policy")
            .arg(&policy)
            .arg("--keypoints")
            .arg(file)
            .arg("--cameras")
            .arg(&cams)
            .args([
                "--view",
                "front",
                "--person",
                person,
                "--fps",
                "30",
                "--no-record",
            ])
            .output()
            .unwrap();
        let (stdout, stderr) = (
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr),
        );
        assert_eq!(out.status.code(), Some(2), "{stdout}{stderr}");
        assert!(stderr.contains("no keypoint is seen in any of its"), "{stderr}");
        assert!(!stdout.contains("Running"), "{stdout}");
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn coco_frames_are_timed_by_their_image_id_so_a_skipped_frame_shifts_nothing() {
    let dir = scratch("coco-gap");
    let clip = projected_squat(&dir);
    // A detector's results on the front camera's video at 30 fps with frames 10–12 missing
    // altogether (no entry of anyone): numeric image ids, as COCO result lists have them.
    let coco = controller::keypoints::clip::COCO_KEYPOINTS;
    let mut detections = Vec::new();
    for f in (0..clip.len()).filter(|f| !(10..=12).contains(f)) {
        let seen = clip.at(f, 0);
        let values: Vec<f64> = coco
            .iter()
            .flat_map(|name| {
                let k = clip.names.iter().position(|n| n == name).unwrap();
                [seen[k][0], seen[k][1], 0.9]
            })
            .collect();
        detections.push(serde_json::json!({"image_id": f, "category_id": 1, "keypoints": values}));
    }
    let path = dir.join("results.json");
    std::fs::write(&path, serde_json::to_string(&detections).unwrap()).unwrap();
    let c = compare(
        &biped("cameras.toml"),
        &path,
        &["--view", "front", "--fps", "30"],
        &dir.join("coco.json"),
    );
    let front = &c["views"][0];
    assert!(front["compared"].as_u64().unwrap() > 0, "{c}");
    assert!(
        front["max_px"].as_f64().unwrap() < 1e-6,
        "every frame where it was: {c}"
    );
    // Two images numbered as one frame are refused by name.
    detections.push(serde_json::json!({"image_id": "frame_0003.png", "category_id": 1, "keypoints": detections[3]["keypoints"].clone()}));
    std::fs::write(&path, serde_json::to_string(&detections).unwrap()).unwrap();
    let squat = biped("clips/squat.csv");
    let cams = biped("cameras.toml");
    let (ok, text) = project(&[
        "--clip".as_ref(),
        squat.as_os_str(),
        "--camera".as_ref(),
        cams.as_os_str(),
        "--against".as_ref(),
        path.as_os_str(),
        "--view".as_ref(),
        "front".as_ref(),
    ]);
    assert!(
        !ok && text.contains("its frame number is another image's"),
        "{text}"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}
