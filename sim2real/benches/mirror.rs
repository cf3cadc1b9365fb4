//! Bench: how much faster than real time the lockstep mirror runs the reference biped.
//!
//! The full path is in the loop: MuJoCo at 1 kHz, 12 emulated MIT motors and 8 emulated
//! Dynamixel servos at 1 kHz, the emulated IMU at 200 Hz, and a 50 Hz host that encodes and
//! decodes every CAN frame, Dynamixel packet and IMU packet through the real drivers. One core.
//!
//! 2. Each shipped robot (rd-biped, rd-mini, and holosoma's G1 when installed), standing on its
//!    default pose: the whole lockstep mirror (physics, emulated firmware, wires, the host's real
//!    drivers at 50 Hz) against bare MuJoCo stepping of the same compiled model for the same
//!    simulated time with the robot's PD in a plain loop, as a trainer steps it (a model left
//!    without control falls in a heap whose contacts cost another amount of solver time) — what
//!    the mirror adds to the physics.
//!
//!    The same on a direct mirror (`Fidelity::Direct`: the commands on MuJoCo, no buses).
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

/// Where a lockstep run's time went: wall time, MuJoCo's steps, and the rest of the mirror
/// (firmware, wires, IMU); the remainder is the host (drivers and the loop around them).
struct Shares {
    wall: Duration,
    physics: Duration,
    mirror: Duration,
    steps: u64,
}

/// The lockstep mirror of `robot` holding its default pose for `seconds`.
fn mirrored(robot: &Robot, seconds: f64) -> Shares {
    let mut host = MirrorHost::start(robot.clone(), MirrorConfig::default()).unwrap();
    let tick = Duration::from_millis(20);
    let ticks = (seconds / tick.as_secs_f64()).round() as u32;
    let q: Vec<f64> = robot.config.joints.iter().map(|j| j.default_position).collect();
    let start = host.now();
    let before = host.world.lock().unwrap().stats();
    let wall = Instant::now();
    for k in 1..=ticks {
        host.command_positions(robot, &q).unwrap();
        host.wait_until(start + tick * k);
    }
    let took = wall.elapsed();
    let after = host.world.lock().unwrap().stats();
    Shares {
        wall: took,
        physics: after.physics - before.physics,
        mirror: (after.busy - before.busy) - (after.physics - before.physics),
        steps: after.physics_steps - before.physics_steps,
    }
}

/// The same, on a direct mirror (no buses): each tick the pose as a PD command with robot.toml's
/// gains, the state read back.
fn direct(robot: &Robot, seconds: f64) -> Shares {
    use firmware_bridge::time::SimWorld;
    let config = MirrorConfig {
        fidelity: sim2real::config::Fidelity::Direct,
        ..MirrorConfig::default()
    };
    let mut world = sim2real::mirror::Mirror::new(robot.clone(), config).unwrap();
    let targets: Vec<robot_link::JointTarget> = robot
        .config
        .joints
        .iter()
        .map(|j| robot_link::JointTarget {
            q: j.default_position,
            kp: j.kp,
            kd: j.kd,
            enabled: true,
            ..robot_link::JointTarget::default()
        })
        .collect();
    let mut state = robot_link::RobotState::new(targets.len());
    let tick = Duration::from_millis(20);
    let ticks = (seconds / tick.as_secs_f64()).round() as u32;
    let start = world.now();
    let before = world.stats();
    let wall = Instant::now();
    for k in 1..=ticks {
        world.command_directly(&targets);
        while world.now() < start + tick * k {
            world.step_until(start + tick * k);
        }
        world.read_directly(&mut state);
    }
    let took = wall.elapsed();
    let after = world.stats();
    Shares {
        wall: took,
        physics: after.physics - before.physics,
        mirror: (after.busy - before.busy) - (after.physics - before.physics),
        steps: after.physics_steps - before.physics_steps,
    }
}

fn main() {
    let quick = !std::env::args().any(|a| a == "--bench");
    robots_against_bare_physics(if quick { 1.0 } else { 20.0 });
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

fn robots_against_bare_physics(seconds: f64) {
    const ROUNDS: usize = 10;
    let root = test_support::fixtures::workspace_root();
    println!();
    println!(
        "the lockstep mirror against bare MuJoCo stepping, standing, one core: best of {ROUNDS} \
         alternating rounds of {:.1} s each (a busy machine only ever adds time)",
        seconds / ROUNDS as f64
    );
    println!(
        "{:>10} {:>8} {:>16} {:>18} {:>8}",
        "robot", "step ms", "bare µs/step", "mirror µs/step", "ratio"
    );
    for path in [
        "robots/biped/robot.toml",
        "robots/mini/robot.toml",
        "robots/g1/robot.toml",
    ] {
        let Ok(robot) = Robot::load(&root.join(path)) else {
            println!("{path:>10}: not installed (scripts/setup)");
            continue;
        };
        let per_step = |took: Duration, steps: u64| took.as_secs_f64() * 1e6 / steps as f64;
        let mut per_bare = f64::INFINITY;
        let mut per_direct = f64::INFINITY;
        let mut best: Option<Shares> = None;
        for _ in 0..ROUNDS {
            let (took, steps) = sim2real::floor::bare_hold(&robot, seconds / ROUNDS as f64).unwrap();
            per_bare = per_bare.min(per_step(took, steps));
            let d = direct(&robot, seconds / ROUNDS as f64);
            per_direct = per_direct.min(per_step(d.wall, d.steps));
            let m = mirrored(&robot, seconds / ROUNDS as f64);
            if best
                .as_ref()
                .is_none_or(|b| per_step(m.wall, m.steps) < per_step(b.wall, b.steps))
            {
                best = Some(m);
            }
        }
        let m = best.expect("at least one round");
        let per_mirror = per_step(m.wall, m.steps);
        let (physics, mirror) = (per_step(m.physics, m.steps), per_step(m.mirror, m.steps));
        println!(
            "{:>10} {:>8} {per_bare:>16.1} {per_mirror:>18.1} {:>7.2}×   of which MuJoCo {physics:.1}, \
             firmware and wires {mirror:.1}, host {:.1} µs/step; direct {per_direct:.1} µs/step ({:.2}×)",
            robot.config.name,
            robot.model().unwrap().opt().timestep * 1000.0,
            per_mirror / per_bare,
            per_mirror - physics - mirror,
            per_direct / per_bare,
        );
    }
}
