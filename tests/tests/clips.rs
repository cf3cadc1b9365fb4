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
