//! Bench: how much faster than real time the lockstep mirror runs the reference biped.
//!
//! The full path is in the loop: MuJoCo at 1 kHz, 12 emulated MIT motors and 8 emulated
//! Dynamixel servos at 1 kHz, the emulated IMU at 200 Hz, and a 50 Hz host that encodes and
//! decodes every CAN frame, Dynamixel packet and IMU packet through the real drivers. One core.
//!
//! Run: `cargo bench -p sim2real --bench mirror`

use std::time::{Duration, Instant};

use robots::{Robot, reference_robot_path};
use sim2real::config::MirrorConfig;
use sim2real::host::MirrorHost;

fn run(seconds: f64, gantry: bool) -> (Duration, u64) {
    let robot = Robot::load(&reference_robot_path()).unwrap();
    let mut host = MirrorHost::start(
        robot.clone(),
        MirrorConfig {
            gantry,
            ..MirrorConfig::default()
        },
    )
    .unwrap();
    let tick = Duration::from_millis(20);
    let ticks = (seconds / tick.as_secs_f64()).round() as u32;
    let start = host.now();
    let mut q: Vec<f64> = robot.config.joints.iter().map(|j| j.default_position).collect();
    let base = q.clone();
    let wall = Instant::now();
    for k in 1..=ticks {
        // A gentle arm wave keeps the servos working.
        let phase = f64::from(k) * tick.as_secs_f64() * std::f64::consts::TAU * 0.5;
        for (i, j) in robot.config.joints.iter().enumerate() {
            if j.name.contains("shoulder_pitch") {
                q[i] = base[i] + 0.3 * phase.sin();
            }
        }
        host.command_positions(&robot, &q).unwrap();
        host.wait_until(start + tick * k);
    }
    let took = wall.elapsed();
    let steps = host.world.lock().unwrap().stats().physics_steps;
    (took, steps)
}

fn main() {
    let quick = !std::env::args().any(|a| a == "--bench");
    let seconds = if quick { 2.0 } else { 30.0 };
    println!("rd-biped mirror in lockstep: 1 kHz physics + firmware, 50 Hz host through the real drivers");
    println!(
        "{:>10} {:>10} {:>12} {:>14} {:>16}",
        "mode", "sim s", "wall s", "× real time", "µs/physics step"
    );
    for (mode, gantry) in [("standing", false), ("gantry", true)] {
        let (took, steps) = run(seconds, gantry);
        println!(
            "{mode:>10} {seconds:>10.1} {:>12.3} {:>14.1} {:>16.1}",
            took.as_secs_f64(),
            seconds / took.as_secs_f64(),
            took.as_secs_f64() * 1e6 / steps as f64
        );
    }
}
