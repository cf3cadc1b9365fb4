//! robodeploy-ray on a local Ray cluster (head and two worker nodes, started by the test inside a
//! network namespace of its own, so everything Ray opens is on 127.0.0.1): the distributed batch
//! equals `robodeploy batch` on one machine number for number, through a worker killed mid-task and
//! a driver stopped half-way and resumed; the distributed clip check equals the local one. The
//! steps and their checks are in `tests/python/ray_cluster_check.py`.

use std::process::Stdio;
use std::time::{Duration, Instant};

use test_support::fixtures::workspace_root;
use test_support::netns::in_private_network;

#[test]
fn a_ray_cluster_runs_the_batch_like_one_machine_through_a_killed_worker_and_a_resume() {
    let root = workspace_root();
    let work = std::env::temp_dir().join(format!("ray-cluster-{}", std::process::id()));
    let script = format!(
        "{} {} --binary {} --work {}",
        root.join(".local/venv/bin/python").display(),
        root.join("tests/python/ray_cluster_check.py").display(),
        test_support::bin::robodeploy_path().display(),
        work.display()
    );
    let mut child = in_private_network(&script)
        .current_dir(&root)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    // Bounded: the cluster's start, three distributed jobs and the local references take ~30 s.
    let give_up = Instant::now() + Duration::from_secs(600);
    while child.try_wait().unwrap().is_none() {
        assert!(
            Instant::now() < give_up,
            "the Ray cluster check took over 10 minutes"
        );
        std::thread::sleep(Duration::from_millis(100));
    }
    let out = child.wait_with_output().unwrap();
    let (stdout, stderr) = (
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr),
    );
    assert!(out.status.success(), "{stdout}\n{stderr}");
    let figures: serde_json::Value = serde_json::from_str(stdout.lines().last().unwrap_or("{}")).unwrap();
    assert!(figures["killed_worker_pid"].as_u64().is_some(), "{figures}");
    assert!(
        figures["resumed_after"].as_u64().is_some_and(|n| n > 0 && n < 12),
        "{figures}"
    );
    std::fs::remove_dir_all(&work).unwrap();
}
