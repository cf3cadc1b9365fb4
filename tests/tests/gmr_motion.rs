//! GMR's retargeted motions read in Rust: the TWIST2 clips field for field against NumPy's own
//! reading of the same pickles, the NPZ variant the same motion, and broken files refused by file
//! and field.

use std::path::{Path, PathBuf};

use motion::gmr::GmrMotion;
use test_support::fixtures::{twist2_dir, venv_python};

/// What NumPy reads from a GMR file: fps, shapes, and every value of the three arrays.
fn numpy_reads(path: &Path) -> serde_json::Value {
    let script = r#"
import json, pickle, sys
import numpy as np
with open(sys.argv[1], "rb") as f:
    m = pickle.load(f)
print(json.dumps({
    "fps": float(m["fps"]),
    "root_pos": np.asarray(m["root_pos"], dtype=float).ravel().tolist(),
    "root_rot": np.asarray(m["root_rot"], dtype=float).ravel().tolist(),
    "dof_pos": np.asarray(m["dof_pos"], dtype=float).ravel().tolist(),
    "dofs": int(m["dof_pos"].shape[1]),
    "bodies": list(m.get("link_body_list", [])),
    "has_body_positions": "local_body_pos" in m,
}))
"#;
    let out = std::process::Command::new(venv_python())
        .args(["-c", script])
        .arg(path)
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    serde_json::from_slice(&out.stdout).unwrap()
}

fn clips(dir: &Path) -> Vec<PathBuf> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(dir.join("example_motions"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "pkl"))
        .collect();
    v.sort();
    v
}

#[test]
fn every_twist2_clip_reads_as_numpy_reads_it() {
    let Some(dir) = twist2_dir() else { return };
    let files = clips(&dir);
    assert_eq!(files.len(), 8, "{files:?}");
    for path in files {
        let m = GmrMotion::load_pickle(&path).unwrap();
        let py = numpy_reads(&path);
        assert_eq!(m.fps, py["fps"].as_f64().unwrap(), "{}", path.display());
        assert_eq!(m.dofs, 29);
        assert_eq!(m.dofs as u64, py["dofs"].as_u64().unwrap());
        let numbers = |k: &str| -> Vec<f64> {
            py[k]
                .as_array()
                .unwrap()
                .iter()
                .map(|v| v.as_f64().unwrap())
                .collect()
        };
        let pos: Vec<f64> = m.root_pos.iter().flatten().copied().collect();
        assert_eq!(pos, numbers("root_pos"), "{}", path.display());
        assert_eq!(m.dof_pos, numbers("dof_pos"), "{}", path.display());
        // x y z w in the file, w x y z here.
        let xyzw: Vec<f64> = m.root_rot.iter().flat_map(|q| [q[1], q[2], q[3], q[0]]).collect();
        for (a, b) in xyzw.iter().zip(numbers("root_rot")) {
            assert!((a - b).abs() < 1e-6, "{}: {a} vs {b}", path.display());
        }
        let bodies: Vec<String> = py["bodies"]
            .as_array()
            .unwrap()
            .iter()
            .map(|b| b.as_str().unwrap().to_owned())
            .collect();
        assert_eq!(m.bodies, bodies);
        assert_eq!(m.has_body_positions, py["has_body_positions"].as_bool().unwrap());
        // As a clip: the robot's joint order, seconds from the file's rate.
        let clip = motion::Clip::load(&path).unwrap();
        assert!(clip.robot_order);
        assert_eq!(clip.times.len(), m.frames());
        assert!((clip.duration() - (m.frames() - 1) as f64 / m.fps).abs() < 1e-9);
    }
}

#[test]
fn the_npz_variant_is_the_same_motion() {
    let Some(dir) = twist2_dir() else { return };
    let pkl = dir.join("example_motions/0807_yanjie_walk_001.pkl");
    let npz = std::env::temp_dir().join(format!("gmr-{}.npz", std::process::id()));
    let script = r#"
import pickle, sys
import numpy as np
with open(sys.argv[1], "rb") as f:
    m = pickle.load(f)
np.savez(sys.argv[2], fps=m["fps"], root_pos=m["root_pos"], root_rot=m["root_rot"], dof_pos=m["dof_pos"])
"#;
    test_support::fixtures::run_python(script, &[pkl.as_os_str(), npz.as_os_str()]);
    let a = motion::Clip::load(&pkl).unwrap();
    let b = motion::Clip::load(&npz).unwrap();
    std::fs::remove_file(&npz).unwrap();
    assert_eq!((a.times, a.root, a.q), (b.times, b.root, b.q));
}

#[test]
fn broken_gmr_files_are_refused_by_file_and_field() {
    let dir = std::env::temp_dir().join(format!("gmr-broken-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    // Each: a change to a good motion, and the field the error must name.
    let cases = [
        ("no_fps", "del m['fps']", "fps", "missing"),
        (
            "rot_shape",
            "m['root_rot'] = m['root_rot'][:, :3]",
            "root_rot",
            "expected (20, 4)",
        ),
        (
            "nan",
            "m['dof_pos'][7, 3] = np.nan",
            "dof_pos[7][3]",
            "not finite",
        ),
        (
            "frames",
            "m['dof_pos'] = m['dof_pos'][:5]",
            "dof_pos",
            "expected (20, D)",
        ),
        ("fps_range", "m['fps'] = 0.0", "fps", "outside [1, 1000]"),
        (
            "not_unit",
            "m['root_rot'][3] = [0, 0, 0, 2]",
            "root_rot[3]",
            "norm 2.0000",
        ),
        (
            "strings",
            "m['dof_pos'] = np.array([['a'] * 29] * 20, dtype=object)",
            "dof_pos",
            "Python objects",
        ),
    ];
    let script = r#"
import pickle, sys
import numpy as np
m = {"fps": np.float64(30.0), "root_pos": np.zeros((20, 3)), "root_rot": np.tile([0.0, 0.0, 0.0, 1.0], (20, 1)),
     "dof_pos": np.zeros((20, 29)), "link_body_list": ["pelvis"], "local_body_pos": np.zeros((20, 1, 3), dtype=np.float32)}
exec(sys.argv[2])
with open(sys.argv[1], "wb") as f:
    pickle.dump(m, f)
"#;
    let good = dir.join("good.pkl");
    test_support::fixtures::run_python(script, &[good.as_os_str(), "pass".as_ref()]);
    assert_eq!(GmrMotion::load_pickle(&good).unwrap().frames(), 20);
    // The same motion pickled at protocols 2 (bytes through _codecs.encode) and 5 (NumPy's
    // buffers through _frombuffer) reads the same.
    for proto in [2, 5] {
        let other = dir.join(format!("protocol_{proto}.pkl"));
        let dump = script.replace(
            "pickle.dump(m, f)",
            &format!("pickle.dump(m, f, protocol={proto})"),
        );
        test_support::fixtures::run_python(&dump, &[other.as_os_str(), "pass".as_ref()]);
        assert_eq!(
            GmrMotion::load_pickle(&other).unwrap(),
            GmrMotion::load_pickle(&good).unwrap(),
            "protocol {proto}"
        );
    }
    for (name, change, field, words) in cases {
        let path = dir.join(format!("{name}.pkl"));
        test_support::fixtures::run_python(script, &[path.as_os_str(), change.as_ref()]);
        let e = motion::Clip::load(&path).unwrap_err();
        assert!(
            e.file == path && e.place == field && e.message.contains(words),
            "{name}: wanted {field}: …{words}…, got {e}"
        );
    }
    // Not a pickle at all, and a pickle cut short.
    std::fs::write(dir.join("text.pkl"), "time,root_x\n").unwrap();
    let e = motion::Clip::load(&dir.join("text.pkl")).unwrap_err();
    assert_eq!(e.place, "pickle", "{e}");
    let bytes = std::fs::read(&good).unwrap();
    std::fs::write(dir.join("cut.pkl"), &bytes[..bytes.len() / 2]).unwrap();
    let e = motion::Clip::load(&dir.join("cut.pkl")).unwrap_err();
    assert!(e.place == "pickle" && e.message.contains("ends inside"), "{e}");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn motion_info_says_what_a_gmr_file_holds_and_how_it_maps_onto_the_robot() {
    let Some(dir) = twist2_dir() else { return };
    let root = test_support::fixtures::workspace_root();
    let file = dir.join("example_motions/0807_yanjie_walk_001.pkl");
    let robot = root.join("robots/g1-twist2/robot.toml");
    let (ok, out, err) = test_support::bin::run(&[
        "motion".as_ref(),
        "info".as_ref(),
        file.as_os_str(),
        "--robot".as_ref(),
        robot.as_os_str(),
    ]);
    assert!(ok, "{out}\n{err}");
    for words in [
        "GMR motion (Python pickle",
        "38 bodies with positions per frame",
        "416 frames over 13.891 s",
        "29 joint columns in the robot's joint order",
        "robot  g1-twist2 (29 joints)",
        "695 ticks at 50 Hz, every frame within the joints' position and speed limits",
    ] {
        assert!(out.contains(words), "{words:?} in\n{out}");
    }
    // A broken file: refused by file and field, exit 2 (bad input).
    let bad = std::env::temp_dir().join(format!("gmr-info-{}.pkl", std::process::id()));
    std::fs::write(&bad, b"\x80\x04}\x94.").unwrap();
    let (ok, _, err) = test_support::bin::run(&["motion".as_ref(), "info".as_ref(), bad.as_os_str()]);
    std::fs::remove_file(&bad).unwrap();
    assert!(!ok && err.contains("fps: missing"), "{err}");
}
