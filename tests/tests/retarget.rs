//! Offline retargeting of real human motion capture (CMU) onto the reference robot.

use controller::clip::{Clip, Reference};
use human::retarget::{RetargetOptions, retarget};
use motion::bvh::Bvh;
use robots::Robot;

fn mocap(name: &str) -> std::path::PathBuf {
    test_support::fixtures::workspace_root()
        .join("data/mocap")
        .join(name)
}

#[test]
fn a_cmu_recording_becomes_a_clip_the_checker_accepts() {
    let robot = Robot::load(&robots::reference_robot_path()).unwrap();
    let bvh = Bvh::load(&mocap("cmu_13_26_direct-traffic-wave.bvh")).unwrap();
    let options = RetargetOptions {
        start_frame: 1,
        ..RetargetOptions::default()
    };
    let m = retarget(&robot, &bvh, &options).unwrap();
    // 25.2 s at 50 Hz; scale from hip heights (1.05 m → 0.46 m).
    assert_eq!(m.times.len(), 1262);
    assert!((m.scale - 0.44).abs() < 0.02, "scale {}", m.scale);
    // The body follows: the pelvis within 1.5 cm of where the scaled human's maps, the feet
    // within 2.5 cm (a planted foot is held where it stands, up to PLANT_DRIFT on the human's
    // scale from the human's creeping foot; a foot whose target would put its sole into the
    // floor stays on it), hands (the robot's arms are relatively short) within 8 cm on average.
    for (frame, mean, worst) in &m.pair_errors {
        let bound = if frame.ends_with("hand") {
            0.08
        } else if frame.ends_with("foot") {
            0.025
        } else {
            0.015
        };
        assert!(*mean < bound, "{frame}: mean {mean:.3} m (worst {worst:.3})");
    }
    // The clip checker: within every joint's position and speed limit (the loader refuses
    // anything else), no ground penetration, no self-penetration, no saturated motor.
    let path = std::env::temp_dir().join(format!("retarget-{}.csv", std::process::id()));
    std::fs::write(&path, m.to_csv(&robot, &["test".into()])).unwrap();
    let clip = Clip::load(&path).unwrap();
    let reference = Reference::from_clip(&clip, &robot, 50.0).unwrap();
    let quality = analysis::motion_check::analyze(&robot, &reference).unwrap();
    assert_eq!(quality.penetration_ticks, 0, "{quality}");
    assert!(quality.problems().is_empty(), "{:?}", quality.problems());
    let _ = std::fs::remove_file(&path);
}

#[test]
fn the_cli_writes_and_checks_the_clip_and_names_bad_input() {
    let out = std::env::temp_dir().join(format!("retarget-cli-{}.csv", std::process::id()));
    let run = |args: &[&str]| {
        let o = test_support::bin::robodeploy().args(args).output().unwrap();
        (
            o.status.success(),
            format!(
                "{}{}",
                String::from_utf8_lossy(&o.stdout),
                String::from_utf8_lossy(&o.stderr)
            ),
        )
    };
    let bvh = mocap("cmu_13_26_direct-traffic-wave.bvh");
    let (ok, text) = run(&[
        "retarget",
        "--bvh",
        bvh.to_str().unwrap(),
        "--start-frame",
        "1",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(ok, "{text}");
    assert!(
        text.contains("ground penetration > 1 cm: 0 of 1262 ticks"),
        "{text}"
    );
    // The shipped clip is what this command makes.
    let shipped = robots::reference_robot_path().with_file_name("clips/cmu_traffic_wave.csv");
    let body = |p: &std::path::Path| {
        std::fs::read_to_string(p)
            .unwrap()
            .lines()
            .filter(|l| !l.starts_with('#'))
            .map(str::to_owned)
            .collect::<Vec<_>>()
    };
    assert_eq!(
        body(&out),
        body(&shipped),
        "regenerate robots/biped/clips/cmu_traffic_wave.csv"
    );

    let broken = std::env::temp_dir().join(format!("broken-{}.bvh", std::process::id()));
    std::fs::write(&broken, "HIERARCHY\nROOT Hips\n{\nOFFSET 0 0\n").unwrap();
    let (ok, text) = run(&[
        "retarget",
        "--bvh",
        broken.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(
        !ok && text.contains(":4:") && text.contains("expected 3 finite numbers"),
        "{text}"
    );
    // A calibrating recording that is broken, or of another skeleton, is named by its flag.
    let (ok, text) = run(&[
        "retarget",
        "--bvh",
        bvh.to_str().unwrap(),
        "--nominal-from",
        broken.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(
        !ok && text.contains("--nominal-from") && text.contains(":4:"),
        "{text}"
    );
    let other = std::env::temp_dir().join(format!("other-{}.bvh", std::process::id()));
    std::fs::write(
        &other,
        "HIERARCHY\nROOT Hips\n{\nOFFSET 0 0 0\nCHANNELS 6 Xposition Yposition Zposition Zrotation Yrotation Xrotation\n\
         JOINT LeftHand\n{\nOFFSET 1 0 0\nCHANNELS 3 Zrotation Yrotation Xrotation\nEnd Site\n{\nOFFSET 1 0 0\n}\n}\n}\n\
         MOTION\nFrames: 1\nFrame Time: 0.01\n0 18 0 0 0 0 0 0 0\n",
    )
    .unwrap();
    let (ok, text) = run(&[
        "retarget",
        "--bvh",
        bvh.to_str().unwrap(),
        "--nominal-from",
        other.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(
        !ok && text.contains("--nominal-from") && text.contains("skeleton"),
        "{text}"
    );
    let _ = std::fs::remove_file(&other);
    let _ = std::fs::remove_file(&broken);
    let _ = std::fs::remove_file(&out);
}

#[test]
fn a_retargeting_map_out_of_range_is_refused_by_field() {
    let path = robots::reference_robot_path();
    let text = std::fs::read_to_string(&path).unwrap();
    let root_pair = "human = \"root\"\nframe = \"pelvis\"\n";
    assert!(
        text.contains(root_pair),
        "rd-biped's root pair changed: update this test"
    );
    for (extra, field, says) in [
        ("scale = 5.0\n", "retarget.pairs[0].scale", "outside 0.3–3"),
        ("scale = 0.0\n", "retarget.pairs[0].scale", "outside 0.3–3"),
        (
            "posture = { position_weight = -1.0 }\n",
            "retarget.pairs[0].posture",
            "must be ≥ 0",
        ),
        ("posture = { weight = 1.0 }\n", "weight", "unknown field"),
    ] {
        let edited = text.replacen(root_pair, &format!("{root_pair}{extra}"), 1);
        let err = Robot::from_str(&path, &edited).unwrap_err().to_string();
        assert!(err.contains(field) && err.contains(says), "{extra}: {err}");
    }
}
