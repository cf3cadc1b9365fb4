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
    let keypoints = dir.join("squat.csv");
    squat_keypoints(&biped("cameras.toml"), &keypoints);
    let cameras = controller::keypoints::camera::load_cameras(&biped("cameras.toml")).unwrap();
    let clip = controller::keypoints::clip::KeypointClip::load_csv(&keypoints, &cameras).unwrap();
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
    let keypoints = dir.join("squat.csv");
    squat_keypoints(&biped("cameras.toml"), &keypoints);
    let cameras = controller::keypoints::camera::load_cameras(&biped("cameras.toml")).unwrap();
    let clip = controller::keypoints::clip::KeypointClip::load_csv(&keypoints, &cameras).unwrap();
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
