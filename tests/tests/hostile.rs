//! Hostile and careless input, as regression tests: every case ends in a clear error that names the
//! file and field (or the flag), exit status 2 (bad input), within a bound — never a panic, an
//! abort or a hang. The inputs are the ones that once did.

use std::ffi::OsString;
use std::path::{Path, PathBuf};
use std::time::Duration;

use test_support::bin::run_within;

/// A scratch folder for one test.
fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("hostile-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn biped(file: &str) -> PathBuf {
    robots::reference_robot_path().with_file_name(file)
}

/// Runs robodeploy with `args`; asserts a bad-input refusal whose message contains `needle`.
fn refused<S: AsRef<std::ffi::OsStr>>(args: &[S], needle: &str) {
    let (code, stdout, stderr) = run_within(args, Duration::from_secs(120));
    let shown: Vec<String> = args
        .iter()
        .map(|a| a.as_ref().to_string_lossy().into_owned())
        .collect();
    assert!(!stderr.contains("panicked"), "{shown:?} panicked:\n{stderr}");
    assert_eq!(code, Some(2), "{shown:?}: status {code:?}\n{stdout}{stderr}");
    assert!(
        stderr.contains(needle),
        "{shown:?}: expected {needle:?} in:\n{stderr}"
    );
}

fn args(list: &[&dyn AsRef<std::ffi::OsStr>]) -> Vec<OsString> {
    list.iter().map(|a| a.as_ref().to_owned()).collect()
}

/// The reference follower's manifest with `from` replaced by `to`, beside a copy of its model.
fn manifest(dir: &Path, name: &str, from: &str, to: &str) -> PathBuf {
    let text = std::fs::read_to_string(biped("policies/reference_follower.toml")).unwrap();
    assert!(text.contains(from), "{from:?} not in the manifest");
    let path = dir.join(format!("{name}.toml"));
    std::fs::write(&path, text.replacen(from, to, 1)).unwrap();
    let onnx = dir.join("reference_follower.onnx");
    if !onnx.exists() {
        std::fs::copy(biped("policies/reference_follower.onnx"), onnx).unwrap();
    }
    path
}

#[test]
fn policy_manifests_with_absurd_numbers_are_refused_by_field() {
    let dir = scratch("policy");
    for (from, to, needle) in [
        (
            "k = 2",
            "k = 1000000000000000000",
            "(last_actions): k = 1000000000000000000 is outside [1, 16]",
        ),
        (
            "clip = 5.0",
            "clip = -1.0",
            "(joint_vel): clip = -1 must be a positive number",
        ),
        (
            "clip = 5.0",
            "clip = nan",
            "(joint_vel): clip = NaN must be a positive number",
        ),
        (
            "frames = [0, 5]",
            "frames = [0, 1000000000]",
            "(ref_joint_pos): frames [0, 1000000000]",
        ),
        (
            "rate_hz = 50.0",
            "rate_hz = 1e-9",
            "rate_hz: 1e-9 Hz is outside [1, 1000]",
        ),
        (
            "rate_limit = 6.0",
            "rate_limit = 6.0\nlowpass_hz = 1e-9",
            "action.lowpass_hz: 1e-9 is outside [0.1, 25]",
        ),
        ("scale = 1.0", "scale = 1e308", "action.scale: 1e308 is outside"),
        // Issue 34: 0 is not "unset", and a term pasted twice is not two terms.
        (
            "rate_hz = 50.0",
            "rate_hz = 0.0",
            "rate_hz: 0 Hz is outside [1, 1000]",
        ),
        (
            "[[observation]]\nterm = \"projected_gravity\"\n",
            "[[observation]]\nterm = \"projected_gravity\"\n\n[[observation]]\nterm = \"projected_gravity\"\n",
            "(projected_gravity): the same term as observation[",
        ),
    ] {
        let policy = manifest(&dir, "bad", from, to);
        refused(&args(&[&"check", &"--policy", &policy]), needle);
    }
    let stiff = manifest(
        &dir,
        "stiff",
        "[action]",
        "stiffness = [1e9, 1e9, 1e9, 1e9, 1e9, 1e9, 1e9, 1e9, 1e9, 1e9, 1e9, 1e9, 1e9, 1e9, 1e9, 1e9, 1e9, 1e9, 1e9, 1e9]\n\n[action]",
    );
    refused(
        &args(&[&"check", &"--policy", &stiff]),
        "stiffness: left_hip_yaw: kp",
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

/// The squat clip with its header and first frames, then `edit` applied to the rows.
fn clip(dir: &Path, name: &str, edit: impl Fn(&mut Vec<Vec<String>>, &mut Vec<String>)) -> PathBuf {
    let text = std::fs::read_to_string(biped("clips/squat.csv")).unwrap();
    let mut lines = text.lines().filter(|l| !l.starts_with('#'));
    let mut header: Vec<String> = lines.next().unwrap().split(',').map(str::to_owned).collect();
    let mut rows: Vec<Vec<String>> = lines
        .take(3)
        .map(|l| l.split(',').map(str::to_owned).collect())
        .collect();
    edit(&mut rows, &mut header);
    let path = dir.join(format!("{name}.csv"));
    let body: Vec<String> = std::iter::once(header.join(","))
        .chain(rows.iter().map(|r| r.join(",")))
        .collect();
    std::fs::write(&path, body.join("\n")).unwrap();
    path
}

#[test]
fn clips_with_huge_gaps_durations_or_twice_named_joints_are_refused() {
    let dir = scratch("clips");
    for (name, time, needle) in [
        (
            "gap300",
            "1e300",
            "time 1e300 is 1e300 s after the previous frame",
        ),
        (
            "gap1e9",
            "1e9",
            "s after the previous frame: frames are at most 10 s apart",
        ),
        ("long", "1e5", "frames are at most 10 s apart"),
    ] {
        let path = clip(&dir, name, |rows, _| rows[2][0] = time.into());
        refused(&args(&[&"check", &"--clip", &path]), needle);
    }
    // A root 1e300 m away in every row, a joint at 1e30 rad: refused by column, not played
    // with "inf cm" errors.
    let far = clip(&dir, "far", |rows, _| {
        for r in rows.iter_mut() {
            r[1] = "1e300".into();
        }
    });
    refused(
        &args(&[&"check", &"--clip", &far]),
        "root_x = 1e300 m is outside ±10000 m",
    );
    refused(
        &args(&[&"play", &"--clip", &far, &"--no-record"]),
        "root_x = 1e300 m is outside ±10000 m",
    );
    let wound = clip(&dir, "wound", |rows, _| rows[2][9] = "1e30".into());
    refused(&args(&[&"check", &"--clip", &wound]), "rad is outside ±100 rad");
    let twice = clip(&dir, "twice", |rows, header| {
        header.push(header[8].clone());
        for r in rows.iter_mut() {
            let v = r[8].clone();
            r.push(v);
        }
    });
    refused(
        &args(&[&"check", &"--clip", &twice]),
        "names joint \"left_hip_yaw\" a second time",
    );
    refused(
        &args(&[&"check", &"--clip", &"/dev/zero"]),
        "/dev/zero: file: not a regular file",
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

/// An `.npy` document with header `descr` and `shape`, and no data.
fn npy(descr: &str, shape: &str) -> Vec<u8> {
    let mut header = format!("{{'descr': '{descr}', 'fortran_order': False, 'shape': {shape}, }}");
    while (10 + header.len() + 1) % 64 != 0 {
        header.push(' ');
    }
    header.push('\n');
    let mut out = b"\x93NUMPY\x01\x00".to_vec();
    out.extend_from_slice(&(header.len() as u16).to_le_bytes());
    out.extend_from_slice(header.as_bytes());
    out
}

fn npz(path: &Path, name: &str, array: &[u8]) {
    use std::io::Write as _;
    let mut zip = zip::ZipWriter::new(std::fs::File::create(path).unwrap());
    zip.start_file(format!("{name}.npy"), zip::write::SimpleFileOptions::default())
        .unwrap();
    zip.write_all(array).unwrap();
    zip.finish().unwrap();
}

#[test]
fn npz_files_with_impossible_headers_are_refused() {
    let dir = scratch("npz");
    for (name, array, descr, shape, needle) in [
        ("u0", "joint_names", "<U0", "(2,)", "unsupported dtype \"<U0\""),
        ("short", "joint_names", "<", "(2,)", "unsupported dtype \"<\""),
        (
            "huge",
            "joint_pos",
            "<f8",
            "(4294967296, 4294967296, 4294967296)",
            "is too large",
        ),
    ] {
        let path = dir.join(format!("{name}.npz"));
        npz(&path, array, &npy(descr, shape));
        refused(&args(&[&"check", &"--clip", &path]), needle);
    }
    // An export with no values, or no rows, is nothing to compare against.
    let run = dir.join("run.mcap");
    let (code, _, stderr) = run_within(&args(&[&"play", &"--record", &run]), Duration::from_secs(300));
    assert_eq!(code, Some(0), "{stderr}");
    let zero = dir.join("zero.npz");
    npz(&zero, "obs", &npy("<f8", "(5, 0)"));
    refused(
        &args(&[&"compare", &run, &zero]),
        "obs must be a steps × values number array",
    );
    let empty = dir.join("empty.csv");
    std::fs::write(&empty, "\n").unwrap();
    refused(&args(&[&"compare", &run, &empty]), "no observations");
    std::fs::remove_dir_all(&dir).unwrap();
}

/// The CMU recording's hierarchy with a motion section of `frames` frames `time` apart.
fn bvh(dir: &Path, name: &str, frames: &str, time: &str) -> PathBuf {
    let text = std::fs::read_to_string(
        test_support::fixtures::workspace_root().join("data/mocap/cmu_13_26_direct-traffic-wave.bvh"),
    )
    .unwrap();
    let at = text.find("MOTION").unwrap();
    let row = text[at..].lines().nth(3).unwrap();
    let path = dir.join(format!("{name}.bvh"));
    std::fs::write(
        &path,
        format!(
            "{}MOTION\nFrames: {frames}\nFrame Time: {time}\n{row}\n{row}\n",
            &text[..at]
        ),
    )
    .unwrap();
    path
}

#[test]
fn bvh_recordings_with_absurd_frame_counts_or_times_are_refused() {
    let dir = scratch("bvh");
    let max = u64::MAX.to_string();
    for (name, frames, time, needle) in [
        ("zero", "0", "0.0083333", "'Frames: N' with N in [1, 432000]"),
        (
            "tera",
            "1000000000000",
            "0.0083333",
            "'Frames: N' with N in [1, 432000]",
        ),
        (
            "max",
            max.as_str(),
            "0.0083333",
            "'Frames: N' with N in [1, 432000]",
        ),
        ("slow", "2", "1e300", "'Frame Time: SECONDS' in [0.001, 1]"),
        ("slower", "2", "1e6", "'Frame Time: SECONDS' in [0.001, 1]"),
    ] {
        let path = bvh(&dir, name, frames, time);
        refused(
            &args(&[&"retarget", &"--bvh", &path, &"--out", &dir.join("x.csv")]),
            needle,
        );
        refused(
            &args(&[&"vr", &"send", &"--bvh", &path, &"--seconds", &"1"]),
            needle,
        );
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn flags_with_absurd_values_are_refused_by_name() {
    let bvh = test_support::fixtures::workspace_root().join("data/mocap/cmu_13_26_direct-traffic-wave.bvh");
    for (list, needle) in [
        (
            args(&[&"retarget", &"--bvh", &bvh, &"--rate", &"1e9"]),
            "'--rate <RATE>': 1e9 is outside [1, 1000]",
        ),
        (
            args(&[&"retarget", &"--bvh", &bvh, &"--smoothing", &"1e9"]),
            "'--smoothing <SMOOTHING>'",
        ),
        (
            args(&[&"play", &"--no-record", &"--ramp", &"1e300"]),
            "'--ramp <RAMP>': 1e300 is outside [0, 60]",
        ),
        (
            args(&[&"play", &"--no-record", &"--stale-cycles", &"0"]),
            "'--stale-cycles <STALE_CYCLES>'",
        ),
        (
            args(&[
                &"play",
                &"--robot",
                &test_support::fixtures::workspace_root().join("robots/mini/robot.toml"),
                &"--policy",
                &test_support::fixtures::workspace_root().join("robots/mini/policies/walk.toml"),
                &"--end",
                &"stand",
                &"--no-record",
            ]),
            "--end stand: this run plays no clip",
        ),
        (
            args(&[&"play", &"--record-every", &"/replay=2"]),
            "\"/replay\" is not a channel whose rate can change",
        ),
        (
            args(&[&"play", &"--record-every", &"/tf"]),
            "\"/tf\" is not TOPIC=N",
        ),
        (
            args(&[&"play", &"--record-every", &"/tf=-1"]),
            "'--record-every <TOPIC=N>'",
        ),
        (
            args(&[&"play", &"--record-chunk-kib", &"1"]),
            "'--record-chunk-kib <KIB>': 1 is outside [4, 65536]",
        ),
        (
            args(&[&"play", &"--record-level", &"15"]),
            "--record-level 15: lz4 takes 0–12",
        ),
        (
            args(&[&"play", &"--record-compression", &"none", &"--record-level", &"3"]),
            "--record-level 3: --record-compression none has no level",
        ),
        (
            args(&[&"sim", &"stand", &"--seconds", &"1e300"]),
            "'--seconds <SECONDS>'",
        ),
        (
            args(&[&"vr", &"send", &"--bvh", &bvh, &"--noise-mm", &"nan"]),
            "'--noise-mm <NOISE_MM>': NaN",
        ),
        (
            args(&[&"can", &"emulate", &"--motor", &"1:AK80-9", &"--bitrate", &"0"]),
            "'--bitrate <BITRATE>'",
        ),
        (
            args(&[&"play", &"--no-record", &"--max-seconds=-1"]),
            "'--max-seconds <MAX_SECONDS>': -1 is outside",
        ),
        (
            // usize::MAX: `start + 1` overflowed before the frame count was checked.
            args(&[
                &"retarget",
                &"--bvh",
                &bvh,
                &"--start-frame",
                &"18446744073709551615",
            ]),
            "'--start-frame <START_FRAME>': 18446744073709551615 is outside [0, 431999]",
        ),
        (
            args(&[&"batch", &"--jobs", &"0"]),
            "'--jobs <JOBS>': 0 is outside [1, 256]",
        ),
        // Judged after parsing, with the other flags: refused by name all the same (they were
        // exit 1).
        (
            args(&[
                &"dxl",
                &"emulate",
                &"--servo",
                &"1:XM430-W350",
                &"--baud",
                &"12345",
            ]),
            "--baud 12345: X-series servos support",
        ),
        (
            args(&[&"dxl", &"emulate", &"--servo", &"1:XM430-W350", &"--baud", &"0"]),
            "--baud 0:",
        ),
        (
            args(&[
                &"can",
                &"emulate",
                &"--motor",
                &"1:AK80-9",
                &"--motor",
                &"1:AK80-9",
            ]),
            "--motor: motor ID 1 is given twice",
        ),
        (
            args(&[
                &"feetech",
                &"emulate",
                &"--servo",
                &"1:STS3215",
                &"--servo",
                &"1:STS3215",
            ]),
            "--servo: servo ID 1 is given twice",
        ),
        // A flag that would do nothing is refused, not ignored.
        (
            args(&[&"play", &"--on-stop", &"damp", &"--stand-for", &"3"]),
            "--stand-for: only with --on-stop stay",
        ),
        (
            args(&[&"play", &"--stand-for", &"3"]),
            "--stand-for: only with --on-stop stay",
        ),
        (
            args(&[&"play", &"--ros2=robodeploy-no-such-if0"]),
            "--ros2: network interface \"robodeploy-no-such-if0\" does not exist",
        ),
        (
            args(&[
                &"play",
                &"--no-record",
                &"--start",
                &"harness",
                &"--estop-udp",
                &"127.0.0.1:9911",
                &"--lowered-udp",
                &"127.0.0.1:9911",
            ]),
            "--lowered-udp 127.0.0.1:9911 is --estop-udp's address too",
        ),
        // The harness start robot.toml asks for, named as such (no --start was given).
        (
            args(&[
                &"play",
                &"--robot",
                &test_support::fixtures::workspace_root().join("robots/g1/robot.toml"),
                &"--gantry",
            ]),
            "robot.toml's [start] mode = \"harness\"",
        ),
    ] {
        refused(&list, needle);
    }
}

#[test]
fn a_robot_file_pointing_at_a_device_is_refused_not_read_forever() {
    let dir = scratch("robot");
    let text = std::fs::read_to_string(robots::reference_robot_path())
        .unwrap()
        .replacen("mjcf = \"biped.xml\"", "mjcf = \"/dev/zero\"", 1);
    let path = dir.join("robot.toml");
    std::fs::write(&path, text).unwrap();
    refused(
        &args(&[&"check", &"--robot", &path]),
        "mjcf: /dev/zero: not a regular file",
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn corrupted_recordings_are_refused_by_report_replay_and_compare() {
    let dir = scratch("mcap");
    let run = dir.join("run.mcap");
    let (code, _, stderr) = run_within(&args(&[&"play", &"--record", &run]), Duration::from_secs(300));
    assert_eq!(code, Some(0), "{stderr}");
    let clean = std::fs::read(&run).unwrap();
    // Bits flipped across the file, lengths and compressed data included: each reader either
    // reads the file or refuses it, never crashes or runs out of memory.
    let flipped = dir.join("flipped.mcap");
    let step = (clean.len() / 24).max(1);
    for at in (8..clean.len()).step_by(step) {
        let mut bytes = clean.clone();
        bytes[at] ^= 0x40;
        std::fs::write(&flipped, &bytes).unwrap();
        for list in [
            args(&[&"report", &flipped, &"--out", &dir.join("report")]),
            args(&[&"replay", &flipped]),
            args(&[&"compare", &flipped, &run]),
        ] {
            let (code, _, stderr) = run_within(&list, Duration::from_secs(120));
            assert!(
                !stderr.contains("panicked") && matches!(code, Some(0 | 1 | 2 | 5)),
                "byte {at}: {list:?} ended with {code:?}:\n{stderr}"
            );
        }
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_recording_cut_by_sigkill_is_read_up_to_the_cut() {
    let dir = scratch("sigkill");
    let run = dir.join("run.mcap");
    let mut play = test_support::bin::Running::start(&args(&[&"play", &"--end", &"loop", &"--record", &run]));
    play.wait_for("soft start done", Duration::from_secs(120));
    // The logger writes behind the loop (it may lag a loaded machine by hundreds of ticks): kill
    // once the file holds some ticks, read as any reader would — not at a fixed moment.
    let give_up = std::time::Instant::now() + Duration::from_secs(120);
    while analysis::replay::read_recording(&run).map_or(0, |r| r.ticks.len()) < 30 {
        assert!(
            std::time::Instant::now() < give_up,
            "the recording never held 30 ticks"
        );
        // Polled, not waited on: a few milliseconds between reads leave the cores to the run.
        std::thread::sleep(Duration::from_millis(5));
    }
    let killed = std::process::Command::new("kill")
        .args(["-KILL", &play.id().to_string()])
        .status()
        .unwrap();
    assert!(killed.success());
    let _ = play.finish();
    let out = dir.join("report");
    let (code, _, stderr) = run_within(
        &args(&[&"report", &run, &"--out", &out]),
        Duration::from_secs(120),
    );
    assert_eq!(code, Some(0), "{stderr}");
    assert!(stderr.contains("the recording ends early"), "{stderr}");
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
    assert!(summary["ticks"].as_u64().unwrap() >= 30, "{summary}");
    let (code, stdout, stderr) = run_within(&args(&[&"replay", &run]), Duration::from_secs(120));
    assert_eq!(code, Some(0), "{stdout}{stderr}");
    // An independent reader gets the same ticks back: Python's `mcap`, record by record.
    let script = test_support::fixtures::workspace_root().join("tests/python/read_mcap.py");
    let out = std::process::Command::new(test_support::fixtures::venv_python())
        .arg(script)
        .arg(&run)
        .arg("--cut")
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let read: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(read["cut"], true, "{read}");
    assert_eq!(
        read["counts"]["/joint_state"].as_u64(),
        summary["ticks"].as_u64(),
        "{read}\n{summary}"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_full_disk_fails_the_recording_clearly_and_nothing_panics() {
    let (code, stdout, stderr) = run_within(
        &args(&[&"play", &"--record", &"/dev/full"]),
        Duration::from_secs(120),
    );
    assert!(!stderr.contains("panicked"), "{stderr}");
    assert_eq!(code, Some(5), "I/O failure: {stdout}{stderr}");
    assert!(stderr.contains("/dev/full"), "{stderr}");
}

#[test]
fn two_runs_at_once_never_write_the_same_default_recording() {
    let start = || {
        test_support::bin::Running::start(&args(&[
            &"play",
            &"--end",
            &"loop",
            &"--clip",
            &biped("clips/wave_and_look.csv"),
        ]))
    };
    let (mut a, mut b) = (start(), start());
    a.wait_for("soft start done", Duration::from_secs(120));
    b.wait_for("soft start done", Duration::from_secs(120));
    for p in [&a, &b] {
        let stopped = std::process::Command::new("kill")
            .args(["-INT", &p.id().to_string()])
            .status()
            .unwrap();
        assert!(stopped.success());
    }
    let file = |out: &str| {
        out.lines()
            .find_map(|l| l.strip_prefix("telemetry: "))
            .and_then(|l| l.split(' ').next())
            .unwrap_or_else(|| panic!("{out}"))
            .to_owned()
    };
    let (a, b) = (a.finish(), b.finish());
    let (fa, fb) = (file(&a.stdout), file(&b.stdout));
    assert_ne!(fa, fb, "both wrote {fa}");
    for f in [fa, fb] {
        let path = test_support::fixtures::workspace_root().join("tests").join(&f);
        let (code, _, stderr) = run_within(&args(&[&"replay", &path]), Duration::from_secs(120));
        assert_eq!(code, Some(0), "{f}: {stderr}");
    }
}

/// A copy of the reference robot's folder with `from` replaced by `to` in its robot.toml.
fn robot(dir: &Path, from: &str, to: &str) -> PathBuf {
    let src = robots::reference_robot_path();
    let folder = dir.join("robot");
    let _ = std::fs::remove_dir_all(&folder);
    std::fs::create_dir_all(&folder).unwrap();
    for entry in std::fs::read_dir(src.parent().unwrap()).unwrap() {
        let entry = entry.unwrap();
        if entry.file_type().unwrap().is_file() {
            std::fs::copy(entry.path(), folder.join(entry.file_name())).unwrap();
        }
    }
    let text =
        test_support::fixtures::policy_from(&std::fs::read_to_string(&src).unwrap(), src.parent().unwrap());
    assert!(text.contains(from), "{from:?} not in robot.toml");
    let path = folder.join("robot.toml");
    std::fs::write(&path, text.replacen(from, to, 1)).unwrap();
    path
}

#[test]
fn robot_files_with_impossible_ids_rates_devices_and_values_are_refused_by_field() {
    let dir = scratch("robotfile");
    for (from, to, needle) in [
        (
            "control_rate_hz = 50.0",
            "control_rate_hz = 1e-300",
            "control_rate_hz: 1e-300 Hz is outside [1, 1000]",
        ),
        (
            "feet = [\"left_foot\", \"right_foot\"]",
            "feet = []",
            "feet: no feet",
        ),
        (
            "device = \"can1\"",
            "device = \"can0\"",
            "(can1).device: \"can0\" already carries another bus",
        ),
        (
            "rate = 921600",
            "rate = 921601",
            "(imu0).rate: 921601 is not one of",
        ),
        (
            "rate = 1000000",
            "rate = 1000001",
            "(can0).rate: 1000001 is not one of",
        ),
        (
            "mounting_rpy_deg = [0.0, 0.0, 0.0]",
            "mounting_rpy_deg = [nan, 0.0, 0.0]",
            "imu.mounting_rpy_deg",
        ),
        // Issue 34: finite is not enough.
        (
            "mounting_rpy_deg = [0.0, 0.0, 0.0]",
            "mounting_rpy_deg = [1e308, 0.0, 0.0]",
            "imu.mounting_rpy_deg: 1e308 ° is outside ±360",
        ),
        (
            "bus = \"dxl0\"\nid = 1",
            "bus = \"dxl0\"\nid = 253",
            "(left_shoulder_pitch).id: 253 is outside [0, 252]",
        ),
        (
            "bus = \"can0\"\nid = 1",
            "bus = \"can0\"\nid = 0",
            "(left_hip_yaw).id: 0 is outside [1, 127]",
        ),
        (
            "bus = \"dxl0\"\nid = 1",
            "bus = \"dxl0\"\nid = 1\nhoming_offset_ticks = 99999999",
            "homing_offset_ticks: 99999999 is outside",
        ),
    ] {
        let path = robot(&dir, from, to);
        refused(&args(&[&"check", &"--robot", &path]), needle);
    }
    // A policy at another rate than the robot's loop.
    let path = robot(&dir, "control_rate_hz = 50.0", "control_rate_hz = 100.0");
    refused(
        &args(&[&"check", &"--robot", &path]),
        "rate_hz: 50 Hz, but rd-biped runs its loop at control_rate_hz = 100 Hz",
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn mirror_settings_out_of_their_ranges_are_refused_by_field() {
    let dir = scratch("mirrorfile");
    for (text, needle) in [
        (
            "firmware_period_us = 1",
            "firmware_period_us: 1 is outside [100, 10000]",
        ),
        (
            "[hardware.joints.left_knee]\nzero_offset = 0.1\ndirection = 0.0",
            "hardware.joints.left_knee.direction",
        ),
        (
            "[hardware.joints.tail]\nzero_offset = 0.1\ndirection = 1.0",
            "hardware.joints.tail: \"tail\" is not a joint",
        ),
        (
            "[randomization]\nimu_noise_scale = nan",
            "randomization.imu_noise_scale: NaN is outside",
        ),
        (
            "[randomization]\nusb_latency_us = [-5.0, 10.0]",
            "randomization.usb_latency_us",
        ),
        (
            "[randomization]\nmass_scale = [0.0, 0.0]",
            "randomization.mass_scale: [0, 0] is not an interval",
        ),
        (
            "[randomization]\nfriction_scale = [2.0, 1.0]",
            "randomization.friction_scale",
        ),
        (
            "[randomization]\nstrength_scale = [1e9, 1e9]",
            "randomization.strength_scale",
        ),
    ] {
        let path = dir.join("mirror.toml");
        std::fs::write(&path, text).unwrap();
        refused(&args(&[&"play", &"--no-record", &"--mirror", &path]), needle);
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_two_minute_soak_of_random_faults_keeps_every_command_in_limits_and_every_fault_in_bound() {
    let (code, stdout, stderr) = run_within(
        &args(&[&"soak", &"--minutes", &"2", &"--seed", &"7"]),
        Duration::from_secs(600),
    );
    assert_eq!(code, Some(0), "{stdout}{stderr}");
    assert_soak_held(&stdout);
}

/// What every soak must show: it passed with no command beyond limits and no record lost, more
/// than one kind of fault was injected, and the robot was shoved.
fn assert_soak_held(summary: &str) {
    assert!(
        summary.contains("commands outside limits: 0") && summary.contains("records lost: 0"),
        "{summary}"
    );
    assert!(summary.trim_end().ends_with("PASSED"), "{summary}");
    let kinds = summary
        .lines()
        .filter(|l| l.contains(" on a joint") || l.contains(" on the IMU"))
        .count();
    assert!(kinds >= 2, "{summary}");
    assert!(soak_pushes(summary) >= 1, "{summary}");
}

/// The shoves a soak's summary counts.
fn soak_pushes(summary: &str) -> usize {
    summary
        .lines()
        .find_map(|l| l.trim().strip_prefix("pushes: "))
        .and_then(|n| n.split_whitespace().next()?.parse().ok())
        .unwrap_or(0)
}

#[test]
fn a_soak_on_the_humanoid_goes_from_the_harness_to_walking_and_back_with_every_command_in_limits() {
    // The G1 on holosoma's walking policy: lowered from its harness, walked on random commands,
    // shoved, faulted, stopped every way its robot.toml allows. (Seed 1 damps the robot after a
    // stop with its ankle target held past the joint's limit under torque reach: clamped now.)
    let robot = test_support::fixtures::workspace_root().join("robots/g1/robot.toml");
    let policy = test_support::fixtures::workspace_root().join("robots/g1/policies/holosoma_loco_ppo.toml");
    let (code, stdout, stderr) = run_within(
        &args(&[
            &"soak",
            &"--robot",
            &robot,
            &"--policy",
            &policy,
            &"--minutes",
            &"2",
            &"--seed",
            &"1",
        ]),
        Duration::from_secs(600),
    );
    assert_eq!(code, Some(0), "{stdout}{stderr}");
    assert_soak_held(&stdout);
    // The operator stopped it more than one way, back into the harness among them.
    let stops = stdout
        .lines()
        .find_map(|l| l.trim().strip_prefix("operator stops: "))
        .unwrap_or_else(|| panic!("no operator stops:\n{stdout}"));
    assert!(stops.contains("harness") && stops.contains(','), "{stdout}");
}

#[test]
fn emulators_stop_cleanly_on_sigint_with_their_summary() {
    for (list, ready) in [
        (
            args(&[
                &"can",
                &"emulate",
                &"--listen",
                &"127.0.0.1:0",
                &"--motor",
                &"1:AK80-9",
            ]),
            "socketcand: serving",
        ),
        (
            args(&[&"dxl", &"emulate", &"--servo", &"1:XM430-W350"]),
            "dynamixel: serving",
        ),
        (args(&[&"sim", &"serve", &"--port", &"0"]), "imu"),
    ] {
        let mut server = test_support::bin::Running::start(&list);
        server.wait_for(ready, Duration::from_secs(120));
        let sent = std::process::Command::new("kill")
            .args(["-INT", &server.id().to_string()])
            .status()
            .unwrap();
        assert!(sent.success());
        let out = server.finish();
        assert_eq!(
            out.status.code(),
            Some(0),
            "{list:?}:\n{}{}",
            out.stdout,
            out.stderr
        );
        assert!(
            out.stdout.contains("stopped (stopped by a signal)"),
            "{list:?}:\n{}",
            out.stdout
        );
    }
}

/// Copies recording `from` to `to` with `edit` (Python, on `meta`: the `/replay` channel's
/// metadata, and `first`: its first message as JSON) applied, through Python's `mcap`.
fn rewrite_recording(from: &Path, to: &Path, edit: &str) {
    let script = format!(
        "import json, sys\n\
         from mcap.reader import make_reader\n\
         from mcap.writer import Writer\n\
         r = make_reader(open(sys.argv[1], 'rb'))\n\
         w = Writer(open(sys.argv[2], 'wb'))\n\
         w.start()\n\
         schemas, channels, firsts = {{}}, {{}}, set()\n\
         for schema, channel, message in r.iter_messages():\n\
         \x20   if schema is not None and schema.id not in schemas:\n\
         \x20       schemas[schema.id] = w.register_schema(schema.name, schema.encoding, schema.data)\n\
         \x20   if channel.id not in channels:\n\
         \x20       meta = dict(channel.metadata)\n\
         \x20       if channel.topic == '/replay':\n\
         \x20           run = json.loads(meta['run'])\n\
         \x20           {edit_meta}\n\
         \x20           meta['run'] = json.dumps(run)\n\
         \x20       channels[channel.id] = w.register_channel(channel.topic, channel.message_encoding, schemas.get(channel.schema_id, 0), meta)\n\
         \x20   data = message.data\n\
         \x20   if channel.topic == '/replay' and '/replay' not in firsts:\n\
         \x20       firsts.add('/replay')\n\
         \x20       first = json.loads(data)\n\
         \x20       {edit_first}\n\
         \x20       data = json.dumps(first).encode()\n\
         \x20   w.add_message(channels[channel.id], message.log_time, data, message.publish_time)\n\
         w.finish()\n",
        edit_meta = edit.split('|').next().unwrap_or("pass"),
        edit_first = edit.split('|').nth(1).unwrap_or("pass"),
    );
    test_support::fixtures::run_python(&script, &[from.as_os_str(), to.as_os_str()]);
}

#[test]
fn a_replay_of_absurd_recorded_options_or_a_missing_reading_is_refused_or_held_never_a_panic() {
    let dir = std::env::temp_dir().join(format!("robodeploy-replay-hostile-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let run = dir.join("run.mcap");
    let (code, out, err) = run_within(
        &args(&[&"play", &"--max-seconds", &"2", &"--record", &run]),
        Duration::from_secs(120),
    );
    assert_eq!(code, Some(0), "{out}{err}");
    // A ramp of 1e300 s (it overflowed the reference's tick count): refused by name, exit 2.
    let ramp = dir.join("ramp.mcap");
    rewrite_recording(&run, &ramp, "run['options']['ramp_s'] = 1e300|pass");
    let (code, out, err) = run_within(&args(&[&"replay", &ramp]), Duration::from_secs(120));
    assert_eq!(code, Some(2), "{out}{err}");
    assert!(
        err.contains("recorded run options: ramp_s: 1e300 is outside [0, 60]"),
        "{err}"
    );
    // The first tick's joint positions missing (null): no panic in the governor.
    let null = dir.join("null.mcap");
    rewrite_recording(&run, &null, "pass|first['q'] = [None] * len(first['q'])");
    let (code, out, err) = run_within(&args(&[&"replay", &null]), Duration::from_secs(120));
    assert!(!err.contains("panicked"), "{out}{err}");
    assert!(code.is_some_and(|c| c != 101), "{out}{err}");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_report_of_a_recording_without_its_end_or_its_replay_channel_is_no_success() {
    let dir = scratch("report-verdict");
    let run = dir.join("run.mcap");
    let (code, out, err) = run_within(&args(&[&"play", &"--record", &run]), Duration::from_secs(300));
    assert_eq!(code, Some(0), "{out}{err}");
    let report = |file: &Path| {
        let out_dir = dir.join("report");
        let (code, stdout, stderr) = run_within(
            &args(&[&"report", &file, &"--out", &out_dir]),
            Duration::from_secs(120),
        );
        assert_eq!(code, Some(0), "{stdout}{stderr}");
        let summary: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(out_dir.join("summary.json")).unwrap()).unwrap();
        (summary, stdout)
    };
    let (whole, stdout) = report(&run);
    assert_eq!(whole["success"], true, "the whole squat is a success: {stdout}");
    // The same file cut at 60 % (a SIGKILL, a full disk): its end is not in it.
    let bytes = std::fs::read(&run).unwrap();
    let cut = dir.join("cut.mcap");
    std::fs::write(&cut, &bytes[..bytes.len() * 6 / 10]).unwrap();
    let (summary, stdout) = report(&cut);
    assert_eq!(summary["success"], false, "{stdout}");
    assert!(summary["recording_cut_at"].is_u64(), "{summary}");
    assert!(
        stdout.contains("success: NO (the recording is cut at byte"),
        "{stdout}"
    );
    // Without its /replay channel, whether it fell and how much it played are unknown.
    let no_replay = dir.join("no-replay.mcap");
    test_support::fixtures::run_python(
        "import sys\n\
         from mcap.reader import make_reader\n\
         from mcap.writer import Writer\n\
         r = make_reader(open(sys.argv[1], 'rb'))\n\
         w = Writer(open(sys.argv[2], 'wb'))\n\
         w.start()\n\
         schemas, channels = {}, {}\n\
         for schema, channel, message in r.iter_messages():\n\
         \x20   if channel.topic == '/replay':\n\
         \x20       continue\n\
         \x20   if schema is not None and schema.id not in schemas:\n\
         \x20       schemas[schema.id] = w.register_schema(schema.name, schema.encoding, schema.data)\n\
         \x20   if channel.id not in channels:\n\
         \x20       channels[channel.id] = w.register_channel(channel.topic, channel.message_encoding, schemas.get(channel.schema_id, 0), dict(channel.metadata))\n\
         \x20   w.add_message(channels[channel.id], message.log_time, message.data, message.publish_time)\n\
         w.finish()\n",
        &[run.as_os_str(), no_replay.as_os_str()],
    );
    let (summary, stdout) = report(&no_replay);
    assert_eq!(summary["success"], false, "{stdout}");
    assert!(stdout.contains("no /replay channel"), "{stdout}");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_path_another_run_records_into_is_refused_and_a_failed_start_does_not_block_it() {
    let dir = scratch("record-lock");
    let x = dir.join("x.mcap");
    let mut a = test_support::bin::Running::start(&args(&[&"play", &"--end", &"loop", &"--record", &x]));
    a.wait_for("soft start done", Duration::from_secs(120));
    // A second run told to overwrite the file the first is writing: refused by name, nothing
    // written into it.
    let (code, out, err) = run_within(
        &args(&[&"play", &"--record", &x, &"--overwrite"]),
        Duration::from_secs(120),
    );
    assert_eq!(code, Some(2), "{out}{err}");
    assert!(err.contains("another run is recording into it now"), "{err}");
    let sent = std::process::Command::new("kill")
        .args(["-INT", &a.id().to_string()])
        .status()
        .unwrap();
    assert!(sent.success());
    let _ = a.finish();
    let (code, out, err) = run_within(&args(&[&"replay", &x]), Duration::from_secs(120));
    assert_eq!(code, Some(0), "the first run's recording is whole: {out}{err}");
    // What a run that failed before its first message leaves (an MCAP file with its header and
    // no message) is no recording to keep: it does not block the path.
    let y = dir.join("y.mcap");
    test_support::fixtures::run_python(
        "import sys\nfrom mcap.writer import Writer\nw = Writer(open(sys.argv[1], 'wb'))\nw.start()\nw.finish()\n",
        &[y.as_os_str()],
    );
    assert!(std::fs::metadata(&y).unwrap().len() > 0);
    let (code, out, err) = run_within(
        &args(&[&"play", &"--max-seconds", &"1", &"--record", &y]),
        Duration::from_secs(120),
    );
    assert_eq!(code, Some(0), "{out}{err}");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_recording_moved_to_another_folder_still_replays_and_compares_and_says_where_it_found_its_files() {
    let dir = scratch("moved");
    let run = dir.join("a/run.mcap");
    let (code, out, err) = run_within(
        &args(&[&"play", &"--max-seconds", &"1", &"--record", &run]),
        Duration::from_secs(120),
    );
    assert_eq!(code, Some(0), "{out}{err}");
    // Moved two folders deeper: the files it names relative to its old folder are not there.
    let moved = dir.join("b/c/d/run.mcap");
    std::fs::create_dir_all(moved.parent().unwrap()).unwrap();
    std::fs::rename(&run, &moved).unwrap();
    for list in [args(&[&"replay", &moved]), args(&[&"compare", &moved, &moved])] {
        let (code, out, err) = run_within(&list, Duration::from_secs(120));
        assert_eq!(code, Some(0), "{list:?}: {out}{err}");
        assert!(
            err.contains("is not beside the recording (it moved from"),
            "{list:?}: {err}"
        );
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_robot_names_its_own_policy_and_a_run_without_one_is_refused_by_name() {
    // rd-mini's own policy, not the reference robot's: checked without --policy.
    let mini = test_support::fixtures::workspace_root().join("robots/mini/robot.toml");
    let (code, stdout, stderr) = run_within(&args(&[&"check", &"--robot", &mini]), Duration::from_secs(120));
    assert_eq!(code, Some(0), "{stdout}{stderr}");
    assert!(
        stdout.contains("policy robots/mini/policies/stand_walk.toml")
            || stdout.contains("mini/policies/stand_walk.toml"),
        "{stdout}"
    );
    assert!(!stdout.contains("reference_follower"), "{stdout}");
    // A robot.toml naming no policy: a run without --policy is refused, naming the flag and the
    // file; one naming a policy that is not there is refused when a run takes it.
    let dir = scratch("default-policy");
    std::fs::copy(biped("biped.xml"), dir.join("biped.xml")).unwrap();
    let text = std::fs::read_to_string(biped("robot.toml")).unwrap();
    let line = "policy = \"policies/reference_follower.toml\"\n";
    assert!(text.contains(line));
    let none = dir.join("robot.toml");
    std::fs::write(&none, text.replace(line, "")).unwrap();
    refused(
        &args(&[&"play", &"--no-record", &"--robot", &none]),
        "--policy is not given and",
    );
    let gone = dir.join("gone.toml");
    std::fs::write(&gone, text.replace(line, "policy = \"policies/gone.toml\"\n")).unwrap();
    refused(&args(&[&"check", &"--robot", &gone]), "is not a file");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn play_refuses_a_clip_check_refuses_unless_forced_for_a_reason_it_records() {
    let dir = scratch("forced");
    // The squat with its root 8 cm lower all through: the feet go through the floor.
    let text = std::fs::read_to_string(biped("clips/squat.csv")).unwrap();
    let sunk: Vec<String> = text
        .lines()
        .map(|l| {
            let mut v: Vec<String> = l.split(',').map(str::to_owned).collect();
            if let Some(z) = v.get(3).and_then(|z| z.parse::<f64>().ok()) {
                v[3] = format!("{}", z - 0.08);
            }
            v.join(",")
        })
        .collect();
    let path = dir.join("sunk.csv");
    std::fs::write(&path, sunk.join("\n")).unwrap();
    let clip: OsString = path.clone().into();
    let (code, out, err) = run_within(
        &["check".into(), "--clip".into(), clip.clone()],
        Duration::from_secs(120),
    );
    assert_eq!(code, Some(1), "check refuses it: {out}{err}");
    assert!(err.contains("ground penetration"), "{err}");
    // play refuses it the same way, as bad input, before anything moves.
    let (code, out, err) = run_within(
        &["play".into(), "--clip".into(), clip.clone()],
        Duration::from_secs(120),
    );
    assert_eq!(code, Some(2), "{out}{err}");
    assert!(
        err.contains("ground penetration") && err.contains("nothing moved; --force REASON plays it anyway"),
        "{err}"
    );
    assert!(!out.lines().any(|l| l.starts_with("ran ")), "nothing ran: {out}");
    // Forced, it plays, says so, and the recording keeps the reason.
    let mcap = dir.join("forced.mcap");
    let (code, out, err) = run_within::<OsString>(
        &[
            "play".into(),
            "--clip".into(),
            clip,
            "--force".into(),
            "checking the refusal on the mirror".into(),
            "--max-seconds".into(),
            "1".into(),
            "--record".into(),
            mcap.clone().into(),
        ],
        Duration::from_secs(120),
    );
    assert_eq!(code, Some(0), "{out}{err}");
    assert!(
        out.contains("played anyway, forced: checking the refusal on the mirror"),
        "{out}"
    );
    let bytes = std::fs::read(&mcap).unwrap();
    let run = mcap::MessageStream::new(&bytes)
        .unwrap()
        .map(|m| m.unwrap())
        .find(|m| m.channel.topic == "/replay")
        .map(|m| m.channel.metadata["run"].clone())
        .unwrap();
    let run: serde_json::Value = serde_json::from_str(&run).unwrap();
    assert_eq!(run["forced"], "checking the refusal on the mirror", "{run}");
    // An empty reason is no reason.
    let (code, _, err) = run_within::<OsString>(
        &[
            "play".into(),
            "--clip".into(),
            path.into(),
            "--force".into(),
            " ".into(),
        ],
        Duration::from_secs(60),
    );
    assert_eq!(code, Some(2), "{err}");
    assert!(err.contains("--force"), "{err}");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_model_with_no_floor_is_named_by_check_and_play_says_it_cannot_tell_a_fall() {
    // rd-mini's own MJCF without the scene that adds its floor: nothing to stand on.
    let root = test_support::fixtures::workspace_root();
    let dir = std::env::temp_dir().join(format!("robodeploy-no-floor-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let text = std::fs::read_to_string(root.join("robots/mini/robot.toml")).unwrap();
    assert!(text.contains("mjcf = \"scene.xml\""));
    let toml = dir.join("robot.toml");
    let mjcf = root.join("robots/mini/mini.xml");
    std::fs::write(
        &toml,
        text.replace("mjcf = \"scene.xml\"", &format!("mjcf = {mjcf:?}")),
    )
    .unwrap();
    let policy = root.join("robots/mini/policies/stand_walk.toml");
    let (code, out, err) = run_within(
        &args(&[&"check", &"--robot", &toml, &"--policy", &policy]),
        Duration::from_secs(120),
    );
    assert_eq!(code, Some(0), "{out}{err}");
    assert!(out.contains("floor: none — no floor in the model"), "{out}");
    let (code, out, err) = run_within(
        &args(&[
            &"play",
            &"--no-record",
            &"--robot",
            &toml,
            &"--policy",
            &policy,
            &"--max-seconds",
            &"1",
        ]),
        Duration::from_secs(120),
    );
    assert_eq!(code, Some(0), "{out}{err}");
    assert!(out.contains("fell: cannot tell, no floor in the model"), "{out}");
    assert!(!out.contains("fell: no"), "{out}");
    std::fs::remove_dir_all(&dir).unwrap();
}
