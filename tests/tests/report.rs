//! A run's report says what the run said: `play --record --report` prints its summary and writes
//! the report from the recording, and every figure both give is the same number — one window
//! (the ticks whose samples entered the loop's metrics), one reference (what each sample was
//! compared with) — for a clip that plays, a clip that ends in a fall, and a command-driven walk.

use test_support::bin::run;
use test_support::fixtures::workspace_root;

/// Runs `play` with `args`, recording and reporting into `dir`; its stdout and the report's
/// summary.json.
fn play_and_report(dir: &std::path::Path, args: &[&str]) -> (String, serde_json::Value) {
    std::fs::create_dir_all(dir).unwrap();
    let record = dir.join("run.mcap");
    let report = dir.join("report");
    let mut all = vec!["play"];
    all.extend_from_slice(args);
    all.extend_from_slice(&[
        "--record",
        record.to_str().unwrap(),
        "--report",
        report.to_str().unwrap(),
    ]);
    let (_, stdout, stderr) = run(&all);
    let text = std::fs::read_to_string(report.join("summary.json"))
        .unwrap_or_else(|e| panic!("no summary.json ({e}):\n{stdout}{stderr}"));
    (stdout, serde_json::from_str(&text).unwrap())
}

/// The number after `prefix` on the line that starts with it.
fn printed(stdout: &str, prefix: &str) -> f64 {
    let line = stdout
        .lines()
        .find_map(|l| l.trim_start().strip_prefix(prefix))
        .unwrap_or_else(|| panic!("no {prefix:?} in:\n{stdout}"));
    line.trim()
        .split(|c: char| !(c.is_ascii_digit() || c == '.' || c == '-' || c == '+'))
        .find(|w| !w.is_empty())
        .and_then(|w| w.parse().ok())
        .unwrap_or_else(|| panic!("no number after {prefix:?}: {line}"))
}

/// Whether `a` (printed with `decimals`) is `b` rounded the same way.
fn same(a: f64, b: f64, decimals: i32) -> bool {
    let scale = 10f64.powi(decimals);
    (a * scale).round() == (b * scale).round()
}

fn scratch(name: &str) -> std::path::PathBuf {
    std::env::temp_dir().join(format!("report-{name}-{}", std::process::id()))
}

#[test]
fn the_report_of_a_played_clip_gives_the_runs_own_figures() {
    let dir = scratch("squat");
    let clip = workspace_root().join("robots/biped/clips/squat.csv");
    let (out, s) = play_and_report(&dir, &["--clip", clip.to_str().unwrap()]);
    assert!(out.contains("result: finished"), "{out}");
    let check = |what: &str, printed_value: f64, reported: f64, decimals: i32| {
        assert!(
            same(printed_value, reported, decimals),
            "{what}: play printed {printed_value}, the report says {reported}\n{out}\n{s}"
        );
    };
    check(
        "joint RMSE",
        printed(&out, "joint tracking RMSE:"),
        s["joints_rmse_deg"].as_f64().unwrap(),
        2,
    );
    check(
        "root RMSE",
        printed(&out, "root position RMSE:"),
        s["root_position_rmse_cm"].as_f64().unwrap(),
        1,
    );
    check(
        "played",
        printed(&out, "reference played:"),
        100.0 * s["played"].as_f64().unwrap(),
        0,
    );
    check(
        "reference jitter",
        printed(&out, "jitter (mean |d³q/dt³|): reference"),
        s["reference_jitter"].as_f64().unwrap(),
        1,
    );
    let robot_jitter: f64 = out
        .lines()
        .filter(|l| l.starts_with("jitter"))
        .find_map(|l| l.split("robot ").nth(1))
        .and_then(|v| v.split_whitespace().next()?.parse().ok())
        .unwrap();
    check("robot jitter", robot_jitter, s["jitter"].as_f64().unwrap(), 1);
    // The loop's times, one computation for the run and its report (10 µs bins at their upper
    // edge against exact samples printed compute p99 70 µs where the report said 47).
    for (line, key) in [
        ("compute per tick:", "compute_us"),
        ("bus I/O per tick:", "io_us"),
    ] {
        let text = out
            .lines()
            .find(|l| l.starts_with(line))
            .unwrap_or_else(|| panic!("{out}"));
        for (k, label) in ["p50", "p99", "max"].iter().enumerate() {
            let value: f64 = text
                .split(&format!("{label} "))
                .nth(1)
                .and_then(|v| v.split_whitespace().next()?.parse().ok())
                .unwrap_or_else(|| panic!("{label} in {text}"));
            check(&format!("{key} {label}"), value, s[key][k].as_f64().unwrap(), 0);
        }
    }
    assert_eq!(s["success"], true, "{s}");
    // The per-bus plot says what it shows (each bus's cycle on the wire, not the loop's bus I/O
    // of the table), with each bus's mean in its legend.
    let html = std::fs::read_to_string(dir.join("report/report.html")).unwrap();
    assert!(html.contains("bus cycle time, each bus"), "no per-bus plot title");
    assert!(!html.contains("bus I/O per tick, each bus"));
    assert!(html.contains("can0 (mean ") && html.contains("dxl0 (mean "));
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn the_report_of_a_fall_gives_the_runs_figures_and_names_its_cause_once() {
    // A shove of 400 N for 0.3 s, 3 s in: rd-biped falls over mid-squat.
    let dir = scratch("fall");
    std::fs::create_dir_all(&dir).unwrap();
    let mirror = dir.join("shove.toml");
    std::fs::write(
        &mirror,
        "[[pushes]]\nat_s = 3.0\nduration_s = 0.3\nforce_n = [400.0, 0.0, 0.0]\n",
    )
    .unwrap();
    let clip = workspace_root().join("robots/biped/clips/squat.csv");
    let (out, s) = play_and_report(
        &dir,
        &[
            "--clip",
            clip.to_str().unwrap(),
            "--mirror",
            mirror.to_str().unwrap(),
        ],
    );
    assert!(out.contains("fell: YES"), "{out}");
    assert!(
        same(
            printed(&out, "joint tracking RMSE:"),
            s["joints_rmse_deg"].as_f64().unwrap(),
            2
        ),
        "{out}\n{s}"
    );
    assert!(
        same(
            printed(&out, "root position RMSE:"),
            s["root_position_rmse_cm"].as_f64().unwrap(),
            1
        ),
        "{out}\n{s}"
    );
    assert!(
        same(
            printed(&out, "reference played:"),
            100.0 * s["played"].as_f64().unwrap(),
            0
        ),
        "{out}\n{s}"
    );
    assert_eq!(s["fell"], true, "{s}");
    // The banner: the fault that stopped the robot (the tilt, as the result line says), not the
    // hold that followed it; how much played, once.
    let cause = out
        .lines()
        .find_map(|l| l.strip_prefix("result: safety stop at tick "))
        .and_then(|l| l.split_once(": "))
        .map(|(_, cause)| cause.to_owned())
        .unwrap_or_else(|| panic!("no safety stop:\n{out}"));
    assert!(cause.starts_with("base tilted"), "{out}");
    let html = std::fs::read_to_string(dir.join("report/report.html")).unwrap();
    let banner = html
        .split("<div class=\"verdict bad\">")
        .nth(1)
        .and_then(|b| b.split("</div>").next())
        .unwrap_or_else(|| panic!("no failure banner"));
    assert!(banner.contains(&format!("safety stop: {cause}")), "{banner}");
    assert!(!banner.contains("hold or blend done"), "{banner}");
    assert_eq!(banner.matches("played").count(), 1, "{banner}");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn the_report_of_a_walk_gives_the_course_the_run_printed_and_no_clip_figures() {
    let dir = scratch("walk");
    let robot = workspace_root().join("robots/g1/robot.toml");
    let policy = workspace_root().join("robots/g1/policies/holosoma_loco_ppo.toml");
    let (out, s) = play_and_report(
        &dir,
        &[
            "--robot",
            robot.to_str().unwrap(),
            "--policy",
            policy.to_str().unwrap(),
            "--command",
            "0,0.5,0",
            "--max-seconds",
            "6",
        ],
    );
    assert!(out.contains("result: finished"), "{out}");
    // The estimate's figures: one computation (the report once compared base-frame velocities
    // where the run compares world-frame ones: 0.274 against 0.276 m/s).
    let estimate = out
        .lines()
        .find(|l| l.starts_with("state estimate"))
        .unwrap_or_else(|| panic!("{out}"));
    let printed_rmse: f64 = estimate
        .split("velocity RMSE ")
        .nth(1)
        .and_then(|v| v.split_whitespace().next()?.parse().ok())
        .unwrap_or_else(|| panic!("{estimate}"));
    let reported = s["estimator"]["velocity_rmse"]
        .as_f64()
        .unwrap_or_else(|| panic!("{s}"));
    assert!(same(printed_rmse, reported, 3), "{estimate}\n{}", s["estimator"]);
    let l = &s["locomotion"];
    let distance = out
        .lines()
        .find_map(|l| l.strip_prefix("distance: "))
        .unwrap_or_else(|| panic!("no distance:\n{out}"));
    let numbers: Vec<f64> = distance
        .split(|c: char| !(c.is_ascii_digit() || c == '.' || c == '-' || c == '+'))
        .filter_map(|w| w.parse().ok())
        .collect();
    assert!(
        same(numbers[0], l["distance_m"].as_f64().unwrap(), 2),
        "{out}\n{l}"
    );
    assert!(
        same(numbers[1], l["displacement_m"].as_f64().unwrap(), 2),
        "{out}\n{l}"
    );
    assert!(
        same(numbers[2], l["heading_change"].as_f64().unwrap().to_degrees(), 1),
        "{out}\n{l}"
    );
    let forward = out.lines().find(|l| l.starts_with("forward")).unwrap();
    let f: Vec<f64> = forward
        .split(|c: char| !(c.is_ascii_digit() || c == '.' || c == '-' || c == '+'))
        .filter_map(|w| w.parse().ok())
        .collect();
    assert!(
        same(f[0], l["commanded"][0].as_f64().unwrap(), 3),
        "{forward}\n{l}"
    );
    assert!(
        same(f[1], l["achieved"][0].as_f64().unwrap(), 3),
        "{forward}\n{l}"
    );
    assert!(
        same(
            printed(&out, "jitter (mean |d³q/dt³|): robot"),
            s["jitter"].as_f64().unwrap(),
            1
        ),
        "{out}\n{s}"
    );
    // Nothing of a clip: no joint error against a made-up reference, no share played, no NaN.
    assert!(
        !out.contains("NaN") && !out.contains("joint tracking RMSE") && !out.contains("reference played"),
        "{out}"
    );
    assert!(s["played"].is_null() && s["reference_jitter"].is_null(), "{s}");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_recording_names_the_tool_its_commit_and_carries_the_robots_model() {
    let dir = scratch("meta");
    std::fs::create_dir_all(&dir).unwrap();
    let record = dir.join("run.mcap");
    let (ok, out, err) = run(&["play", "--max-seconds", "1", "--record", record.to_str().unwrap()]);
    assert!(ok, "{out}{err}");
    let bytes = std::fs::read(&record).unwrap();
    // The header: the project's profile, the tool and the commit it was built from.
    let header = mcap::read::LinearReader::new(&bytes)
        .unwrap()
        .find_map(|r| match r {
            Ok(mcap::records::Record::Header(h)) => Some(h),
            _ => None,
        })
        .expect("a header");
    assert_eq!(header.profile, "robodeploy");
    assert!(
        header
            .library
            .starts_with(concat!("robodeploy ", env!("CARGO_PKG_VERSION"), " (commit ")),
        "{}",
        header.library
    );
    let summary = mcap::Summary::read(&bytes).unwrap().expect("a summary");
    let index = summary
        .metadata_indexes
        .iter()
        .find(|m| m.name == "robodeploy")
        .expect("a robodeploy metadata record");
    let meta = mcap::read::metadata(&bytes, index).unwrap().metadata;
    assert_eq!(meta["version"], env!("CARGO_PKG_VERSION"));
    // (Built outside a git checkout, the commit is unknown, and says so.)
    let commit = &meta["commit"];
    if workspace_root().join(".git").exists() {
        assert!(
            commit.len() == 12 && commit.chars().all(|c| c.is_ascii_hexdigit()),
            "{commit}"
        );
    } else {
        assert_eq!(commit, "unknown");
    }
    assert!(header.library.contains(commit.as_str()));
    // The MJCF the run used, beside robot.toml, as it is on disk.
    let model = summary
        .attachment_indexes
        .iter()
        .find(|a| a.name == "robot/biped.xml")
        .expect("the MJCF attached");
    assert_eq!(model.media_type, "application/xml");
    let attached = mcap::read::attachment(&bytes, model).unwrap();
    assert_eq!(
        &attached.data[..],
        &std::fs::read(workspace_root().join("robots/biped/biped.xml")).unwrap()[..]
    );
    // No channel declared that carries nothing: the follower tracks no anchor.
    let topics: Vec<&str> = summary.channels.values().map(|c| c.topic.as_str()).collect();
    assert!(!topics.iter().any(|t| t.starts_with("/anchor")), "{topics:?}");
    let stats = summary.stats.as_ref().unwrap();
    assert_eq!(stats.channel_count as usize, topics.len());
    for c in summary.channels.values() {
        assert!(
            stats.channel_message_counts.get(&c.id).is_some_and(|&n| n > 0),
            "{} declared, never written",
            c.topic
        );
    }
    std::fs::remove_dir_all(&dir).unwrap();
}
