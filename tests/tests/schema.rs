//! `robodeploy schema`: the JSON Schemas users' editors check their files with must accept every
//! file the project ships and reject what the loaders reject, judged by an independent validator
//! (Python's `jsonschema`, draft 2020-12).

use std::path::{Path, PathBuf};
use std::process::Command;

use test_support::bin::run;
use test_support::fixtures::{venv_python, workspace_root};

/// Writes the schema of `of` into `dir` and returns its path.
fn schema_file(of: &str, dir: &Path) -> PathBuf {
    let path = dir.join(format!("{of}.schema.json"));
    let (ok, _, stderr) = run(&["schema", of, "--out", path.to_str().unwrap(), "--overwrite"]);
    assert!(ok, "schema {of}: {stderr}");
    path
}

/// Runs the validator: (passed, its report).
fn validate(schema: &Path, files: &[PathBuf]) -> (bool, String) {
    let out = Command::new(venv_python())
        .arg(workspace_root().join("scripts/check_schemas.py"))
        .arg(schema)
        .args(files)
        .output()
        .unwrap();
    let report = String::from_utf8_lossy(&out.stdout).into_owned() + &String::from_utf8_lossy(&out.stderr);
    (out.status.success(), report)
}

fn tomls_in(pattern_dirs: &[&str], name: impl Fn(&Path) -> bool) -> Vec<PathBuf> {
    let root = workspace_root();
    let mut files = Vec::new();
    for dir in pattern_dirs {
        for entry in std::fs::read_dir(root.join(dir)).unwrap() {
            let path = entry.unwrap().path();
            if path.extension().is_some_and(|e| e == "toml") && name(&path) {
                files.push(path);
            }
        }
    }
    files.sort();
    files
}

fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("robodeploy-schema-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

#[test]
fn every_shipped_file_is_valid_against_its_schema() {
    let dir = scratch("shipped");
    let robots = ["robots/biped", "robots/mini", "robots/g1", "robots/t1"];
    let policy_dirs: Vec<String> = robots.iter().map(|r| format!("{r}/policies")).collect();
    let mut policy_dirs: Vec<&str> = policy_dirs.iter().map(String::as_str).collect();
    policy_dirs.push("tests/fixtures/policies");
    let cases = [
        ("robot", tomls_in(&robots, |p| p.ends_with("robot.toml"))),
        ("policy", tomls_in(&policy_dirs, |_| true)),
        ("mirror", tomls_in(&["sim2real/configs"], |_| true)),
    ];
    for (of, files) in cases {
        assert!(files.len() >= 3, "{of}: {files:?}");
        let (ok, report) = validate(&schema_file(of, &dir), &files);
        assert!(ok, "{of}:\n{report}");
        assert_eq!(
            report.lines().filter(|l| l.starts_with("ok ")).count(),
            files.len(),
            "{report}"
        );
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn the_schema_rejects_what_the_loader_rejects_and_names_the_field() {
    let dir = scratch("rejects");
    let root = workspace_root();
    let biped = std::fs::read_to_string(root.join("robots/biped/robot.toml")).unwrap();
    let manifest =
        std::fs::read_to_string(root.join("robots/biped/policies/reference_follower.toml")).unwrap();
    // A misspelt field, a number given as text, a bus kind that does not exist, a manifest field
    // misspelt: each refused by both, with the field named.
    let cases = [
        (
            "robot",
            "typo.toml",
            biped.replacen("control_rate_hz", "control_rate_hzz", 1),
            "control_rate_hz",
        ),
        (
            "robot",
            "text.toml",
            biped.replacen("control_rate_hz = 50.0", "control_rate_hz = \"50\"", 1),
            "control_rate_hz",
        ),
        (
            "policy",
            "manifest.toml",
            format!("acton_scale = 0.5\n{manifest}"),
            "acton_scale",
        ),
    ];
    assert!(
        biped.contains("control_rate_hz = 50.0"),
        "the biped's rate line changed: update this test"
    );
    for (of, name, text, field) in cases {
        let file = dir.join(name);
        std::fs::write(&file, &text).unwrap();
        let (ok, report) = validate(&schema_file(of, &dir), std::slice::from_ref(&file));
        assert!(
            !ok && report.contains("FAIL") && report.contains(field),
            "{of} {name}: {report}"
        );
        // The loader refuses the same file.
        let loaded: Result<(), String> = match of {
            "robot" => toml::from_str::<robots::RobotConfig>(&text)
                .map(drop)
                .map_err(|e| e.to_string()),
            _ => toml::from_str::<policy::PolicyManifest>(&text)
                .map(drop)
                .map_err(|e| e.to_string()),
        };
        let err = loaded.expect_err(name);
        assert!(err.contains(field), "{name}: {err}");
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn the_reference_pages_name_every_table_of_the_schema() {
    for of in ["robot", "policy", "mirror", "calibration"] {
        let (ok, page, stderr) = run(&["schema", of, "--format", "markdown"]);
        assert!(ok, "{stderr}");
        let (ok, json, _) = run(&["schema", of]);
        assert!(ok);
        let schema: serde_json::Value = serde_json::from_str(&json).unwrap();
        for name in schema["$defs"].as_object().unwrap().keys() {
            assert!(
                page.contains(&format!("## {name} {{#{}}}", name.to_ascii_lowercase())),
                "{of}: {name}"
            );
        }
        // Every top-level field is in the first table.
        for field in schema["properties"].as_object().unwrap().keys() {
            assert!(page.contains(&format!("| `{field}` |")), "{of}: {field}");
        }
    }
}

#[test]
fn a_schema_is_not_written_over_an_existing_file_unless_asked() {
    let dir = scratch("overwrite");
    let robot = dir.join("robot.toml");
    std::fs::write(&robot, "name = \"mine\"\n").unwrap();
    let (code, out, err) = test_support::bin::run_within(
        &["schema", "robot", "--out", robot.to_str().unwrap()],
        std::time::Duration::from_secs(120),
    );
    assert_eq!(code, Some(2), "{out}{err}");
    assert!(err.contains("--out") && err.contains("--overwrite"), "{err}");
    assert_eq!(std::fs::read_to_string(&robot).unwrap(), "name = \"mine\"\n");
    let (ok, _, err) = run(&["schema", "robot", "--out", robot.to_str().unwrap(), "--overwrite"]);
    assert!(ok, "{err}");
    assert!(std::fs::read_to_string(&robot).unwrap().contains("\"$schema\""));
    std::fs::remove_dir_all(&dir).unwrap();
}
