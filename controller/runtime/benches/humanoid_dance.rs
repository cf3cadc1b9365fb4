//! Bench: holosoma's G1 dance in lockstep on the mirror against the project's Python reference
//! loop (`tests/python/holosoma_reference.py`), on the same machine in the same run.
//!
//! - robodeploy: the whole path — harness start, the ONNX policy and its observation, five
//!   MIT-mode CAN buses at 500 Hz encoded and decoded through the real drivers, 29 emulated
//!   motors, the emulated IMU, MuJoCo at the scene's 2 ms step — one core, no real time.
//! - Python: plain MuJoCo at holosoma's 5 ms step, the trainer's PD in numpy, ONNX Runtime; no
//!   buses, no safety, no telemetry.
//!
//! Both play the motion from its first frame (robodeploy after its harness lowering, Python after
//! a 1 s hold); the table gives wall time per simulated second, so unequal lead-ins compare.
//! `cargo bench` plays all 6 574 frames (131.5 s); the smoke run of `cargo test --benches` the
//! first 250 (5 s).
//!
//! Run: `cargo bench -p controller --bench humanoid_dance`

use std::process::Command;
use std::sync::Arc;
use std::sync::atomic::AtomicBool;
use std::time::Instant;

use controller::player::PlayOptions;
use controller::sim::lockstep_player;
use policy::PolicyLayout;
use robots::Robot;
use sim2real::config::MirrorConfig;
use test_support::fixtures::{venv_python, workspace_root};

const DANCE: &str = ".local/holosoma-inference/models/wbt/ppo_g1_29dof_dancing.onnx";

/// robodeploy's lockstep run of the first `frames` frames: (simulated s, wall s, physics steps).
fn robodeploy(frames: usize) -> (f64, f64, u64) {
    let root = workspace_root();
    let robot = Robot::load(&root.join("robots/g1/robot.toml")).unwrap();
    let mut layout = PolicyLayout::load(&root.join(DANCE), &robot).unwrap();
    let (reference, _) =
        controller::reference::load_reference(None, &root.join(DANCE), &mut layout, &robot, 0).unwrap();
    // The harness start's lead-in, then the frames asked for (the run stops softly after).
    let h = robot.config.start.harness;
    let lead_in = ((h.lower_s + h.settle_s) * 50.0).round() as u64;
    let options = PlayOptions {
        max_ticks: (frames < reference.len()).then_some(lead_in + frames as u64),
        ..PlayOptions::default()
    };
    let (mut player, mut clock, world) = lockstep_player(
        robot,
        layout,
        reference,
        options,
        MirrorConfig::default(),
        Arc::new(AtomicBool::new(false)),
    )
    .unwrap();
    let wall = Instant::now();
    let summary = player.run(&mut clock).unwrap();
    let took = wall.elapsed().as_secs_f64();
    let steps = world.lock().unwrap().stats().physics_steps;
    assert!(!summary.fell, "the G1 fell in the bench run");
    (summary.ticks as f64 * 0.02, took, steps)
}

/// The Python loop's physics step (holosoma's), s.
const PYTHON_STEP_S: f64 = 0.005;

/// The Python loop's own measurement of the first `frames` frames: (simulated s, wall s).
fn python(frames: usize) -> (f64, f64) {
    let root = workspace_root();
    let out = Command::new(venv_python())
        .arg(root.join("tests/python/holosoma_reference.py"))
        .args(["dance", "--frames", &frames.to_string()])
        .arg("--robot-dir")
        .arg(root.join(".local/holosoma"))
        .arg("--policy-dir")
        .arg(root.join(".local/holosoma-inference"))
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert!(!v["fell"].as_bool().unwrap(), "the Python loop fell: {v}");
    (v["simulated_s"].as_f64().unwrap(), v["wall_s"].as_f64().unwrap())
}

fn main() {
    let full = std::env::args().any(|a| a == "--bench");
    if !workspace_root().join(DANCE).exists() {
        println!("holosoma's dance export is not installed: run scripts/setup");
        return;
    }
    let frames = if full { 6574 } else { 250 };
    println!("holosoma's G1 dance, first {frames} frames, one core, lockstep (no real time)");
    let (sim_r, wall_r, steps) = robodeploy(frames);
    let (sim_p, wall_p) = python(frames);
    println!(
        "{:<44} {:>8} {:>8} {:>12} {:>14}",
        "loop", "sim s", "wall s", "× real time", "wall s / sim s"
    );
    let row = |name: &str, sim: f64, wall: f64| {
        println!(
            "{name:<44} {sim:>8.1} {wall:>8.2} {:>12.1} {:>14.3}",
            sim / wall,
            wall / sim
        );
    };
    row("robodeploy: buses, firmware, 2 ms physics", sim_r, wall_r);
    row("Python reference: plain MuJoCo, 5 ms physics", sim_p, wall_p);
    let steps_p = sim_p / PYTHON_STEP_S;
    println!(
        "robodeploy costs {:.2}× the Python loop per simulated second; per physics step, all in, {:.0} µs ({steps} steps) against {:.0} µs ({steps_p:.0} steps): {:.2}×",
        (wall_r / sim_r) / (wall_p / sim_p),
        wall_r * 1e6 / steps as f64,
        wall_p * 1e6 / steps_p,
        (wall_r / steps as f64) / (wall_p / steps_p)
    );
}
