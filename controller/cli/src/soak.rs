//! `robodeploy soak`: hours of simulated faults on the mirror, and the figures that must hold.

use std::path::PathBuf;

use anyhow::Result;
use clap::Args;
use robots::Robot;

/// Run a soak on the mirror in lockstep: episodes of random lengths with random device faults
/// (silent, corrupt, overheating or vanishing motors, servos and the IMU at random times) and
/// shoves, checking that every command stays inside the joint's limits, that every fault reaches
/// the safe state within 6 ticks, that nothing stops without a cause, and that no record is lost
/// from the recordings.
///
/// A robot that starts on its PD plays random clips on its gantry. A robot that starts in a
/// harness (a humanoid) is lowered under its policy, walks on random commands or plays its
/// export's motion, and is stopped every way robot.toml allows (damp, stay, sit, back into the
/// harness): `soak --robot robots/g1/robot.toml --policy robots/g1/policies/holosoma_loco_ppo.toml`.
#[derive(Debug, Args)]
pub struct SoakArgs {
    /// Robot description.
    #[arg(long, default_value_os_t = robots::locate::default_robot())]
    robot: PathBuf,
    /// Policy manifest.
    /// Default: the policy robot.toml names (`policy = "policies/…"`).
    #[arg(long)]
    policy: Option<PathBuf>,
    /// Clips to draw from (default: the policy's own reference — its commands, or the motion its
    /// export carries — else every clip beside the robot).
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
    let policy = crate::args::policy_of(args.policy.as_deref(), &robot)?;
    let scratch = std::env::temp_dir().join(format!("robodeploy-soak-{}", std::process::id()));
    let bar = indicatif::ProgressBar::new(1000);
    bar.set_style(
        indicatif::ProgressStyle::with_template("soak [{bar:40}] {percent:>3}% {elapsed}")
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    let report = analysis::soak::soak(
        &analysis::soak::SoakSpec {
            robot: &robot,
            policy: &policy,
            clips: &args.clips,
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
