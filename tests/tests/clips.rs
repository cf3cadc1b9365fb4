//! Clips in both formats: NumPy itself writes an NPZ of a shipped CSV clip, and both load to the same
//! reference; broken files are named.

use controller::clip::{Clip, Reference};
use robots::{Robot, reference_robot_path};

fn csv() -> std::path::PathBuf {
    reference_robot_path().with_file_name("clips/squat.csv")
}

/// Writes `path` as an NPZ with NumPy, from the CSV clip.
fn numpy_npz(path: &std::path::Path, extra: &str) {
    let script = format!(
        r#"
import numpy as np
rows = [l for l in open({csv:?}) if not l.startswith('#')]
header = rows[0].strip().split(',')
data = np.array([[float(x) for x in r.split(',')] for r in rows[1:]])
arrays = dict(joint_names=np.array(header[8:]), joint_pos=data[:, 8:].astype(np.float32),
              root_pos=data[:, 1:4], root_quat=data[:, 4:8], fps=np.array(30.0))
{extra}
np.savez_compressed({out:?}, **arrays)
"#,
        csv = csv().display().to_string(),
        out = path.display().to_string(),
    );
    let out = std::process::Command::new(test_support::fixtures::venv_python())
        .args(["-c", &script])
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
}

#[test]
fn an_npz_written_by_numpy_loads_like_its_csv() {
    let robot = Robot::load(&reference_robot_path()).unwrap();
    let path = std::env::temp_dir().join(format!("squat-{}.npz", std::process::id()));
    numpy_npz(&path, "");
    let from_npz = Reference::from_clip(&Clip::load(&path).unwrap(), &robot, 50.0).unwrap();
    let from_csv = Reference::from_clip(&Clip::load(&csv()).unwrap(), &robot, 50.0).unwrap();
    assert_eq!(from_npz.len(), from_csv.len());
    // float32 angles, and frame times k/30 s instead of the CSV's 4-decimal times.
    for (a, b) in from_npz.q.iter().zip(&from_csv.q) {
        assert!((a - b).abs() < 2e-4, "{a} vs {b}");
    }
    assert_eq!(from_npz.held_joints, from_csv.held_joints);
    std::fs::remove_file(&path).unwrap();
}

#[test]
fn broken_npz_clips_name_the_array() {
    let path = std::env::temp_dir().join(format!("broken-{}.npz", std::process::id()));
    numpy_npz(&path, "del arrays['root_quat']");
    let e = Clip::load(&path).unwrap_err().to_string();
    assert!(e.contains("root_quat: array missing"), "{e}");
    numpy_npz(&path, "arrays['root_pos'] = arrays['root_pos'][:, :2]");
    let e = Clip::load(&path).unwrap_err().to_string();
    assert!(e.contains("root_pos: has shape [211, 2], expected (T, 3)"), "{e}");
    std::fs::write(&path, b"not a zip").unwrap();
    let e = Clip::load(&path).unwrap_err().to_string();
    assert!(e.contains("not an .npz (zip) file"), "{e}");
    std::fs::remove_file(&path).unwrap();
}

#[test]
fn broken_csv_clips_name_the_line() {
    let path = std::env::temp_dir().join(format!("broken-{}.csv", std::process::id()));
    let text = std::fs::read_to_string(csv()).unwrap();
    let mut lines: Vec<&str> = text.lines().collect();
    lines[10] = "0.5,0,0,0.4,1,0,0,0,nan";
    std::fs::write(&path, lines.join("\n")).unwrap();
    let e = Clip::load(&path).unwrap_err().to_string();
    assert!(
        e.contains("line 11:") && e.contains("values for 26 columns"),
        "{e}"
    );
    std::fs::remove_file(&path).unwrap();
}

fn motion_fixture(name: &str) -> std::path::PathBuf {
    test_support::fixtures::workspace_root()
        .join("tests/fixtures/motion")
        .join(name)
}

/// The squat's reference from `path`, against the shipped CSV's: joints and root within `tol`.
fn same_reference_as_the_squat(path: &std::path::Path, tol: f64) {
    let robot = Robot::load(&reference_robot_path()).unwrap();
    let clip = Clip::load(path).unwrap();
    let from_file = Reference::from_clip(&clip, &robot, 50.0).unwrap();
    let from_csv = Reference::from_clip(&Clip::load(&csv()).unwrap(), &robot, 50.0).unwrap();
    assert_eq!(from_file.len(), from_csv.len(), "{}", path.display());
    for (a, b) in from_file.q.iter().zip(&from_csv.q) {
        assert!((a - b).abs() < tol, "{}: {a} vs {b}", path.display());
    }
    for (a, b) in from_file.root.iter().zip(&from_csv.root) {
        for (x, y) in a.iter().zip(b) {
            assert!((x - y).abs() < tol, "{}: root {a:?} vs {b:?}", path.display());
        }
    }
    assert_eq!(from_file.held_joints, from_csv.held_joints);
}

#[test]
fn motion_files_of_beyondmimic_and_the_lafan1_retargets_load_like_the_clip_they_came_from() {
    // Fixtures written by scripts/gen_motion_fixtures.py from the squat (float32 NPZ, 6-decimal
    // CSV, frame times k/30 s instead of the CSV's 4-decimal times).
    same_reference_as_the_squat(&motion_fixture("squat_beyondmimic.npz"), 3e-4);
    same_reference_as_the_squat(&motion_fixture("squat_lafan1.csv"), 3e-4);
    // Without its sidecar, a motion NPZ holds the robot's joints in its order: the squat's 18
    // columns (no head) cannot be rd-biped's 20, and that is said.
    let dir = std::env::temp_dir().join(format!("motion-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let bare = dir.join("bare.npz");
    std::fs::copy(motion_fixture("squat_beyondmimic.npz"), &bare).unwrap();
    let clip = Clip::load(&bare).unwrap();
    assert!(clip.robot_order);
    let robot = Robot::load(&reference_robot_path()).unwrap();
    let e = Reference::from_clip(&clip, &robot, 50.0).unwrap_err().to_string();
    assert!(
        e.contains("bare.npz: joints: 18 joint columns and no names") && e.contains("rd-biped has 20 joints"),
        "{e}"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn motion_files_with_a_wrong_or_missing_description_are_named() {
    let dir = std::env::temp_dir().join(format!("motion-bad-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let csv_text = std::fs::read_to_string(motion_fixture("squat_lafan1.csv")).unwrap();
    let sidecar = std::fs::read_to_string(motion_fixture("squat_lafan1.motion.toml")).unwrap();
    let case = |name: &str, rows: &str, side: &str| -> String {
        let path = dir.join(format!("{name}.csv"));
        std::fs::write(&path, rows).unwrap();
        std::fs::write(dir.join(format!("{name}.motion.toml")), side).unwrap();
        match Clip::load(&path) {
            Ok(_) => panic!("{name}: loaded"),
            Err(e) => e.to_string(),
        }
    };
    let e = case("nofps", &csv_text, &sidecar.replace("fps = 30.0\n", ""));
    assert!(
        e.contains("nofps.motion.toml: fps: a headerless CSV needs its frame rate"),
        "{e}"
    );
    let e = case(
        "noorder",
        &csv_text,
        &sidecar.replace("quaternion = \"xyzw\"\n", ""),
    );
    assert!(e.contains("noorder.motion.toml: quaternion"), "{e}");
    let e = case("fps", &csv_text, &sidecar.replace("fps = 30.0", "fps = 0.0"));
    assert!(e.contains("fps.motion.toml: fps: 0 is outside [1, 1000]"), "{e}");
    let e = case("unknown", &csv_text, &format!("{sidecar}speed = 2\n"));
    assert!(
        e.contains("unknown.motion.toml: toml: unknown field `speed`"),
        "{e}"
    );
    let e = case("fewer", &csv_text, &sidecar.replace(", \"right_elbow\"", ""));
    assert!(
        e.contains("fewer.motion.toml: joints: names 17 joints; the motion file has 18 joint columns"),
        "{e}"
    );
    let e = case(
        "twice",
        &csv_text,
        &sidecar.replace("\"right_knee\"", "\"left_knee\""),
    );
    assert!(e.contains("is named twice"), "{e}");
    let e = case("ragged", &format!("{csv_text}1,2,3\n"), &sidecar);
    assert!(e.contains("ragged.csv: line 212: 3 values"), "{e}");
    // A root yawed 120°, x y z w; read as w x y z it turns upside down: named, at frame 0.
    let (s, c) = (60f64.to_radians().sin(), 60f64.to_radians().cos());
    let row = |t: usize| {
        format!(
            "0,0,{},0,0,{s},{c},{}\n",
            0.45 + t as f64 * 1e-3,
            vec!["0"; 18].join(",")
        )
    };
    let rows: String = (0..3).map(row).collect();
    let e = case("order", &rows, &sidecar.replace("\"xyzw\"", "\"wxyz\""));
    assert!(
        e.contains("order.csv: frame 0: the root starts upside down") && e.contains("quaternion order"),
        "{e}"
    );
    let path = dir.join("right.csv");
    std::fs::write(&path, &rows).unwrap();
    std::fs::write(dir.join("right.motion.toml"), &sidecar).unwrap();
    let clip = Clip::load(&path).unwrap();
    assert!((clip.root[0][3] - c).abs() < 1e-12 && (clip.root[0][6] - s).abs() < 1e-12);
    // A motion NPZ whose root body is not among its bodies.
    let npz = dir.join("root.npz");
    std::fs::copy(motion_fixture("squat_beyondmimic.npz"), &npz).unwrap();
    let side = std::fs::read_to_string(motion_fixture("squat_beyondmimic.motion.toml")).unwrap();
    std::fs::write(
        dir.join("root.motion.toml"),
        side.replace("root_body = 0", "root_body = 3"),
    )
    .unwrap();
    let e = Clip::load(&npz).unwrap_err().to_string();
    assert!(
        e.contains("root.motion.toml: root_body: body 3 of 3 in body_pos_w"),
        "{e}"
    );
    // A sidecar rate that disagrees with the NPZ's own: refused, not played at either speed.
    let npz = dir.join("rate.npz");
    std::fs::copy(motion_fixture("squat_beyondmimic.npz"), &npz).unwrap();
    std::fs::write(dir.join("rate.motion.toml"), format!("fps = 50.0\n{side}")).unwrap();
    let e = Clip::load(&npz).unwrap_err().to_string();
    assert!(
        e.contains("rate.motion.toml: fps: 50 disagrees with the NPZ's own fps = 30"),
        "{e}"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}
