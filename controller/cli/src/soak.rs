//! `robodeploy soak`: hours of simulated faults on the mirror, and the figures that must hold.

use std::path::PathBuf;

use anyhow::Result;
use clap::Args;
use robots::Robot;

/// Run a soak on the mirror in lockstep: episodes of random clips and lengths with random device
/// faults (silent, corrupt, overheating or vanishing motors, servos and the IMU at random times),
/// checking that every command stays inside the joint's limits, that every fault reaches the
/// safe state within 6 ticks, and that no record is lost from the recordings.
#[derive(Debug, Args)]
pub struct SoakArgs {
    /// Robot description.
    #[arg(long, default_value_os_t = robots::reference_robot_path())]
    robot: PathBuf,
    /// Policy manifest.
    #[arg(long, default_value_os_t = robots::reference_robot_path().with_file_name("policies/reference_follower.toml"))]
    policy: PathBuf,
    /// Clips to draw from (default: every clip beside the robot).
    #[arg(long, num_args = 1..)]
    clips: Vec<PathBuf>,
    /// Simulated minutes to cover.
    #[arg(long, default_value_t = 60.0, value_parser = crate::args::within(0.1, 24.0 * 60.0))]
    minutes: f64,
    /// Seed of every draw: the same seed gives the same soak.
    #[arg(long, default_value_t = 1)]
    seed: u64,
}

/// Runs `soak`; fails (exit 3) when anything that must hold did not.
pub fn run(args: &SoakArgs) -> Result<std::process::ExitCode> {
    let robot = Robot::load(&args.robot)?;
    let clips = if args.clips.is_empty() {
        let mut found: Vec<PathBuf> = std::fs::read_dir(robot.path.with_file_name("clips"))?
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.extension().is_some_and(|x| x == "csv"))
            .collect();
        found.sort();
        found
    } else {
        args.clips.clone()
    };
    anyhow::ensure!(!clips.is_empty(), "no clips to soak with (--clips)");
    let scratch = std::env::temp_dir().join(format!("robodeploy-soak-{}", std::process::id()));
    let bar = indicatif::ProgressBar::new(1000);
    bar.set_style(
        indicatif::ProgressStyle::with_template("soak [{bar:40}] {percent:>3}% {elapsed}")
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    let report = analysis::soak::soak(
        &analysis::soak::SoakSpec {
            robot: &robot,
            policy: &args.policy,
            clips: &clips,
            seconds: args.minutes * 60.0,
            seed: args.seed,
            scratch: &scratch,
        },
        &|done| bar.set_position((done * 1000.0) as u64),
    );
    bar.finish_and_clear();
    let _ = std::fs::remove_dir_all(&scratch);
    let report = report?;
    println!("{report}");
    Ok(std::process::ExitCode::from(if report.passed() {
        crate::exit::FINISHED
    } else {
        crate::exit::SAFETY_STOP
    }))
}
