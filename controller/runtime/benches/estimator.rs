//! Bench: the state estimator against the mirror's truth over the shipped clips × seeds, with
//! randomisation on (mass ±5 %, friction ±20 %, motor strength 90–100 %, IMU noise and bias ×1.5,
//! the IMU's biases drifting), through the real buses and the emulated IMU; and its compute per
//! tick (every IMU sample since the last tick propagated, the legs' correction).
//!
//! Targets (issue 18): standing drift < 2 cm/min, squat height RMSE < 1 cm and vertical velocity
//! RMSE < 0.05 m/s, marching contacts ≥ 98 % and velocity RMSE < 0.05 m/s. Issue 33, per robot on
//! its own policy (rd-mini, G1, T1; standing, walking with turns, walking pushed sideways, IMU noise
//! ×1.5 and both biases drifting): velocity RMSE ≤ 0.05 m/s, height RMSE ≤ 1 cm, drift ≤ 2 % of
//! the distance walked, contacts agree ≥ 97 %. Issue 50: the same on the robot zoo
//! (`test_support::zoo`: rd-mini, a Feetech biped, an 11 kg biped on 5 N·m-clipped MIT motors, no
//! foot switches) walking on rd-mini's walking fixture. Tables a person reads.
//!
//! Run: `cargo bench -p controller --bench estimator` (8 seeds for rd-biped's clips, 3 per walking
//! robot, 20 s runs, both filters side by side); as a test (`cargo test --benches`) 1 seed and 6 s
//! runs of the default filter. `-- --bench --filter linear|invariant` runs one filter,
//! `--walking` only the walking robots.

use std::path::{Path, PathBuf};
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
use test_support::zoo::ZooRobot;
use world::estimator::{Estimator, EstimatorConfig, FilterKind, LegKinematics};

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

/// Tick `tick`'s four samples of a 200 Hz IMU on a robot standing still, into `e`.
fn imu_samples_of_tick(e: &mut Estimator, tick: u64) {
    for k in 0..4 {
        e.propagate(&robot_link::ImuSample {
            gyro: [0.001, -0.002, 0.0],
            accel: [0.05, -0.02, 9.81],
            quat: [1.0, 0.0, 0.0, 0.0],
            at: std::time::Duration::from_micros(5_000 * (4 * tick + k)),
        });
    }
}

fn compute_per_tick(filter: FilterKind) -> Summary {
    let config = EstimatorConfig {
        filter,
        ..EstimatorConfig::default()
    };
    let mut e = Estimator::new(config, 2, [0.0, 0.0, -9.81], 160.0, 200.0);
    let legs = LegKinematics {
        position: [[0.0, 0.07, -0.4], [0.0, -0.07, -0.4], [0.0; 3], [0.0; 3]],
        contact: [[0.02, 0.07, -0.44], [0.02, -0.07, -0.44], [0.0; 3], [0.0; 3]],
        sole_depth: [0.04; 4],
        ..LegKinematics::default()
    };
    let mut samples = Vec::with_capacity(10_000);
    for tick in 0..11_000u64 {
        let t0 = Instant::now();
        imu_samples_of_tick(&mut e, tick);
        let estimate = e.correct(&legs, true);
        if tick >= 1000 {
            samples.push(t0.elapsed());
        }
        std::hint::black_box(estimate);
    }
    Summary::of(&mut samples).unwrap()
}

/// The world stage's work per tick on `robot`'s own model, timed: the kinematics posed from
/// joints moving about the default pose, every foot's place, contact point and load (the legs'
/// Jacobians), and the estimator (4 IMU samples and the legs' correction), as the loop runs it.
fn world_per_tick(robot: &Robot, filter: FilterKind) -> Summary {
    let mut k = world::RobotKinematics::new(robot, None, &[]).unwrap();
    let config = EstimatorConfig {
        filter,
        ..robot.config.estimator
    };
    let feet = k.feet().min(world::estimator::MAX_FEET);
    let mut e = Estimator::new(config, feet, k.gravity(), k.weight(), 200.0);
    let pose: Vec<f64> = robot.config.joints.iter().map(|j| j.default_position).collect();
    let (mut q, qd, tau) = (pose.clone(), vec![0.1; pose.len()], vec![1.0; pose.len()]);
    let mut samples = Vec::with_capacity(10_000);
    for tick in 0..11_000u64 {
        for (i, (x, p)) in q.iter_mut().zip(&pose).enumerate() {
            *x = p + 0.05 * (tick as f64 * 0.1 + i as f64).sin();
        }
        let t0 = Instant::now();
        k.update([1.0, 0.0, 0.0, 0.0], &q, &qd, None);
        imu_samples_of_tick(&mut e, tick);
        let legs = k.legs(&tau);
        let estimate = e.correct(&legs, true);
        if tick >= 1000 {
            samples.push(t0.elapsed());
        }
        std::hint::black_box(estimate);
    }
    Summary::of(&mut samples).unwrap()
}

/// One command-driven run of `robot`'s `policy` from its own start (a harness for the humanoids):
/// `command` (the manifest's order) for `seconds`, pushed sideways at a third and two thirds of
/// the run when `pushed` (0.1 s at half the robot's weight: 0.5 m/s sideways for its mass).
fn walk(
    robot: &Path,
    policy: &Path,
    command: &[f64],
    seconds: f64,
    pushed: bool,
    seed: u64,
    filter: FilterKind,
) -> controller::metrics::PlaySummary {
    let mut loaded = Robot::load(robot).unwrap();
    loaded.config.estimator.filter = filter;
    let mut layout = PolicyLayout::load(policy, &loaded).unwrap();
    layout.set_command(command).unwrap();
    let onnx = layout.onnx_path.clone();
    let (reference, _) = controller::reference::load_reference(None, &onnx, &mut layout, &loaded, 0).unwrap();
    let weight = world::RobotKinematics::new(&loaded, None, &[]).unwrap().weight();
    let mut mirror = randomized(seed);
    if pushed {
        mirror.pushes = [1.0 / 3.0, 2.0 / 3.0]
            .iter()
            .enumerate()
            .map(|(i, at)| sim2real::config::Push {
                at_s: at * seconds,
                duration_s: 0.1,
                force_n: [0.0, if i == 0 { 0.5 } else { -0.5 } * weight, 0.0],
            })
            .collect();
    }
    let options = PlayOptions {
        max_ticks: Some((seconds * 50.0) as u64),
        end: controller::player::EndMode::Stand,
        ..PlayOptions::default()
    };
    let (mut p, mut clock, _w) = lockstep_player(
        loaded,
        layout,
        reference,
        options,
        mirror,
        Arc::new(AtomicBool::new(false)),
    )
    .unwrap();
    p.run(&mut clock).unwrap()
}

/// A robot's name, its robot.toml and policy, and the walking command in the manifest's order.
type WalkingRobot = (String, (PathBuf, PathBuf), Option<Vec<f64>>);

fn walking_robots(quick: bool, filters: &[FilterKind]) {
    let (seeds, seconds) = if quick { (1, 6.0) } else { (3, 20.0) };
    let shipped = |robot: &str, policy: &str| {
        let dir = test_support::fixtures::workspace_root()
            .join("robots")
            .join(robot);
        (dir.join("robot.toml"), dir.join("policies").join(policy))
    };
    let mut robots: Vec<WalkingRobot> = vec![
        // holosoma's order: turning rate, forward, leftward.
        (
            "g1".into(),
            shipped("g1", "holosoma_loco_ppo.toml"),
            Some(vec![0.3, 0.5, 0.0]),
        ),
        (
            "t1".into(),
            shipped("t1", "holosoma_loco_ppo.toml"),
            Some(vec![0.3, 0.5, 0.0]),
        ),
    ];
    // The zoo (no foot switches) on rd-mini's walking fixture: forward speed only.
    let zoo = std::env::temp_dir().join(format!("estimator-bench-zoo-{}", std::process::id()));
    for robot in ZooRobot::ALL {
        let paths = (robot.write(&zoo), ZooRobot::walking_policy());
        robots.push((robot.name().into(), paths, Some(vec![0.2])));
    }
    println!("\nthe world stage per tick on each robot's own model (kinematics, legs, estimator):");
    for (robot, (robot_toml, _), _) in &robots {
        let loaded = Robot::load(robot_toml).unwrap();
        for &filter in filters {
            println!(
                "{robot:<14} {:<10} {}",
                filter_name(filter),
                world_per_tick(&loaded, filter)
            );
        }
    }
    println!(
        "\nwalking robots on their own policies, randomised mirror, {seeds} seeds × {seconds} s (median / worst):\n\
         {:<14} {:<20} {:<10} {:>9} {:>16} {:>16} {:>18} {:>16}",
        "robot",
        "scenario",
        "filter",
        "walked m",
        "vel RMSE m/s",
        "height RMSE mm",
        "drift % (cm)",
        "contacts %"
    );
    for (robot, (robot_toml, policy), walking) in robots {
        let still = vec![0.0; walking.as_ref().map_or(3, Vec::len)];
        let mut scenarios = vec![
            ("standing", still.clone(), false),
            ("standing, pushed", still, true),
        ];
        if let Some(w) = walking {
            scenarios.push(("walking", w.clone(), false));
            scenarios.push(("walking, pushed", w, true));
        }
        for ((name, command, pushed), &filter) in
            scenarios.iter().flat_map(|s| filters.iter().map(move |f| (s, f)))
        {
            let runs: Vec<_> = (0..seeds)
                .map(|seed| walk(&robot_toml, &policy, command, seconds, *pushed, seed, filter))
                .collect();
            let filter = filter_name(filter);
            let fell = runs.iter().filter(|s| s.fell).count();
            let measured: Vec<(f64, controller::metrics::EstimatorAccuracy)> = runs
                .iter()
                .filter(|s| !s.fell)
                .filter_map(|s| Some((s.locomotion.as_ref()?.distance_m, s.estimator?)))
                .collect();
            if measured.is_empty() {
                println!("{robot:<14} {name:<20} {filter:<10} fell in all {seeds} runs");
                continue;
            }
            let stat = |f: &dyn Fn(&(f64, controller::metrics::EstimatorAccuracy)) -> f64,
                        worst_is_max: bool| {
                let mut v: Vec<f64> = measured.iter().map(f).collect();
                v.sort_by(f64::total_cmp);
                let worst = if worst_is_max { v[v.len() - 1] } else { v[0] };
                (v[v.len() / 2], worst)
            };
            let pair = |(m, w): (f64, f64), digits: usize| format!("{m:.digits$} / {w:.digits$}");
            let walked = stat(&|(d, _)| *d, true).0;
            let drift = if walked > 1.0 {
                let (m, w) = stat(&|(d, e)| 100.0 * e.final_position_error / d, true);
                format!("{m:.2} / {w:.2} %")
            } else {
                let (m, w) = stat(&|(_, e)| 100.0 * e.final_position_error, true);
                format!("({m:.1} / {w:.1} cm)")
            };
            println!(
                "{robot:<14} {name:<20} {filter:<10} {walked:>9.2} {:>16} {:>16} {:>18} {:>16}{}",
                pair(stat(&|(_, e)| e.velocity_rmse, true), 3),
                pair(stat(&|(_, e)| 1000.0 * e.height_rmse, true), 1),
                drift,
                pair(stat(&|(_, e)| 100.0 * e.contact_agreement, false), 1),
                if fell > 0 {
                    format!("  ({fell} fell, not counted)")
                } else {
                    String::new()
                },
            );
        }
    }
}

fn filter_name(filter: FilterKind) -> &'static str {
    match filter {
        FilterKind::Linear => "linear",
        FilterKind::Invariant => "invariant",
    }
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let quick = !args.iter().any(|a| a == "--bench");
    let filters: Vec<FilterKind> = match args.iter().position(|a| a == "--filter").map(|i| args.get(i + 1)) {
        Some(Some(f)) if f == "linear" => vec![FilterKind::Linear],
        Some(Some(f)) if f == "invariant" => vec![FilterKind::Invariant],
        _ if quick => vec![FilterKind::default()],
        _ => vec![FilterKind::Invariant, FilterKind::Linear],
    };
    if args.iter().any(|a| a == "--walking") {
        walking_robots(quick, &filters);
        return;
    }
    let seeds = if quick { 3 } else { 8 };
    let reference = Robot::load(&reference_robot_path()).unwrap();
    for &filter in &filters {
        println!(
            "state estimator compute per tick (4 IMU samples + the legs, 2 feet), {}: {}",
            filter_name(filter),
            compute_per_tick(filter)
        );
    }
    println!(
        "rd-biped on the randomised mirror, {seeds} seeds per clip (median / worst over seeds):\n\
         {:<22} {:<10} {:>16} {:>16} {:>16} {:>16} {:>12}",
        "clip", "filter", "vel RMSE m/s", "vert vel m/s", "height RMSE mm", "end error cm", "contacts %"
    );
    let clips = reference_robot_path().with_file_name("clips");
    let fixtures = test_support::fixtures::workspace_root().join("tests/fixtures/motion");
    for path in [
        clips.join("squat.csv"),
        fixtures.join("march.csv"),
        clips.join("wave_and_look.csv"),
        clips.join("cmu_traffic_wave.csv"),
    ] {
        for &filter in &filters {
            let clip = path.file_name().unwrap().to_string_lossy().into_owned();
            let (mut rows, mut fell) = (Vec::new(), 0);
            let mut robot = reference.clone();
            robot.config.estimator.filter = filter;
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
            let filter = filter_name(filter);
            if rows.is_empty() {
                println!(
                    "{clip:<22} {filter:<10} the robot fell in all {seeds} runs (the follower cannot balance this clip)"
                );
                continue;
            }
            let stat = |f: &dyn Fn(&controller::metrics::EstimatorAccuracy) -> f64, worst_is_max: bool| {
                let mut v: Vec<f64> = rows.iter().map(f).collect();
                v.sort_by(f64::total_cmp);
                let worst = if worst_is_max { v[v.len() - 1] } else { v[0] };
                format!("{:.3} / {:.3}", v[v.len() / 2], worst)
            };
            println!(
                "{:<22} {filter:<10} {:>16} {:>16} {:>16} {:>16} {:>12}{}",
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
    walking_robots(quick, &filters);
}
