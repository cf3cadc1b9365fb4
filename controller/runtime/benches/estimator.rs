//! Bench: the state estimator against the mirror's truth over the shipped clips × seeds, with
//! randomisation on (mass ±5 %, friction ±20 %, motor strength 90–100 %, IMU noise and bias ×1.5,
//! the IMU's biases drifting), through the real buses and the emulated IMU; and its compute per
//! tick (every IMU sample since the last tick propagated, the legs' correction).
//!
//! Targets (issue 18): standing drift < 2 cm/min, squat height RMSE < 1 cm and vertical velocity
//! RMSE < 0.05 m/s, marching contacts ≥ 98 % and velocity RMSE < 0.05 m/s; a table a person reads.
//!
//! Run: `cargo bench -p controller --bench estimator` (3 seeds; 8 with `--bench`).

use std::sync::Arc;
use std::sync::atomic::AtomicBool;
use std::time::Instant;

use controller::clip::{Clip, Reference};
use controller::player::PlayOptions;
use controller::sim::lockstep_player;
use policy::PolicyLayout;
use robots::{Robot, reference_robot_path};
use sim2real::config::{MirrorConfig, Randomization, Range};
use test_support::stats::Summary;
use world::estimator::{Estimator, EstimatorConfig, LegKinematics};

fn randomized(seed: u64) -> MirrorConfig {
    MirrorConfig {
        seed,
        randomization: Randomization {
            mass_scale: Range(0.95, 1.05),
            friction_scale: Range(0.8, 1.2),
            strength_scale: Range(0.9, 1.0),
            usb_latency_us: Range(0.0, 1000.0),
            imu_noise_scale: 1.5,
            imu_gyro_bias_walk_dps: 0.01,
            imu_accel_bias_walk: 0.005,
        },
        ..MirrorConfig::default()
    }
}

fn compute_per_tick() -> Summary {
    let mut e = Estimator::new(EstimatorConfig::default(), 2, [0.0, 0.0, -9.81], 160.0, 200.0);
    let legs = LegKinematics {
        position: [[0.0, 0.07, -0.4], [0.0, -0.07, -0.4], [0.0; 3], [0.0; 3]],
        contact: [[0.02, 0.07, -0.44], [0.02, -0.07, -0.44], [0.0; 3], [0.0; 3]],
        sole_depth: [0.04; 4],
        ..LegKinematics::default()
    };
    let mut samples = Vec::with_capacity(10_000);
    for tick in 0..11_000u64 {
        let t0 = Instant::now();
        for k in 0..4 {
            e.propagate(&robot_link::ImuSample {
                gyro: [0.001, -0.002, 0.0],
                accel: [0.05, -0.02, 9.81],
                quat: [1.0, 0.0, 0.0, 0.0],
                at: std::time::Duration::from_micros(5_000 * (4 * tick + k)),
            });
        }
        let estimate = e.correct(&legs, true);
        if tick >= 1000 {
            samples.push(t0.elapsed());
        }
        std::hint::black_box(estimate);
    }
    Summary::of(&mut samples).unwrap()
}

fn main() {
    let quick = !std::env::args().any(|a| a == "--bench");
    let seeds = if quick { 3 } else { 8 };
    let robot = Robot::load(&reference_robot_path()).unwrap();
    println!(
        "state estimator compute per tick (4 IMU samples + the legs, 2 feet): {}",
        compute_per_tick()
    );
    println!(
        "rd-biped on the randomised mirror, {seeds} seeds per clip (median / worst over seeds):\n\
         {:<22} {:>16} {:>16} {:>16} {:>16} {:>12}",
        "clip", "vel RMSE m/s", "vert vel m/s", "height RMSE mm", "end error cm", "contacts %"
    );
    let clips = reference_robot_path().with_file_name("clips");
    let fixtures = test_support::fixtures::workspace_root().join("tests/fixtures/motion");
    for path in [
        clips.join("squat.csv"),
        fixtures.join("march.csv"),
        clips.join("wave_and_look.csv"),
        clips.join("cmu_traffic_wave.csv"),
    ] {
        let clip = path.file_name().unwrap().to_string_lossy().into_owned();
        let (mut rows, mut fell) = (Vec::new(), 0);
        for seed in 0..seeds {
            let layout = PolicyLayout::load(
                &reference_robot_path().with_file_name("policies/reference_follower.toml"),
                &robot,
            )
            .unwrap();
            let c = Clip::load(&path).unwrap();
            let reference = Reference::from_clip(&c, &robot, 50.0).unwrap();
            let (mut p, mut clock, _w) = lockstep_player(
                robot.clone(),
                layout,
                reference,
                PlayOptions::default(),
                randomized(seed),
                Arc::new(AtomicBool::new(false)),
            )
            .unwrap();
            let s = p.run(&mut clock).unwrap();
            // A robot that fell is not a state to estimate: those runs are counted, not measured.
            match s.estimator {
                Some(e) if !s.fell => rows.push(e),
                _ => fell += 1,
            }
        }
        if rows.is_empty() {
            println!("{clip:<22} the robot fell in all {seeds} runs (the follower cannot balance this clip)");
            continue;
        }
        let stat = |f: &dyn Fn(&controller::metrics::EstimatorAccuracy) -> f64, worst_is_max: bool| {
            let mut v: Vec<f64> = rows.iter().map(f).collect();
            v.sort_by(f64::total_cmp);
            let worst = if worst_is_max { v[v.len() - 1] } else { v[0] };
            format!("{:.3} / {:.3}", v[v.len() / 2], worst)
        };
        println!(
            "{:<22} {:>16} {:>16} {:>16} {:>16} {:>12}{}",
            clip,
            stat(&|e| e.velocity_rmse, true),
            stat(&|e| e.vertical_velocity_rmse, true),
            stat(&|e| 1000.0 * e.height_rmse, true),
            stat(&|e| 100.0 * e.final_position_error, true),
            stat(&|e| 100.0 * e.contact_agreement, false),
            if fell > 0 {
                format!("  ({fell} of {seeds} runs fell, not counted)")
            } else {
                String::new()
            },
        );
    }
}
