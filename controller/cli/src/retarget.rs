//! `robodeploy retarget`: a human BVH recording onto the robot, as a clip, checked.

use std::path::PathBuf;

use anyhow::{Context, Result, bail};
use clap::Args;
use controller::clip::{Clip, Reference};
use human::retarget::{RetargetOptions, retarget_calibrated};
use motion::bvh::Bvh;
use robots::Robot;

/// Arguments of `retarget`.
#[derive(Debug, Args)]
pub struct RetargetArgs {
    /// The human recording (BVH; CMU and Bandai-Namco skeletons are known).
    #[arg(long)]
    bvh: PathBuf,
    /// The robot (its robot.toml's [retarget] section pairs human and robot bodies).
    #[arg(long, default_value_os_t = robots::locate::default_robot())]
    robot: PathBuf,
    /// The policy that will track the clip (default: the robot's own, robot.toml's `policy`):
    /// a policy whose manifest says `[reference] feasibility = "report"` tracks kinematic
    /// references, so what the robot could not follow exactly is reported, not refused.
    #[arg(long)]
    policy: Option<PathBuf>,
    /// Where to write the clip (CSV).
    #[arg(long, default_value = "out/clips/retargeted.csv")]
    out: PathBuf,
    /// Clip rate, Hz.
    #[arg(long, default_value_t = 50.0, value_parser = crate::args::within(1.0, 1000.0))]
    rate: f64,
    /// The recording's frame that matches the robot's nominal pose (CMU trials start in a T-pose).
    #[arg(long, default_value_t = 0, value_parser = crate::args::frame_index)]
    nominal_frame: usize,
    /// Calibrate on another recording of the same skeleton (its --nominal-frame): a T-pose or
    /// standing take of the same performer, for clips that start moving (a walk that starts
    /// mid-stride has no frame matching the robot's pose). Default: the clip itself.
    #[arg(long, value_name = "BVH")]
    nominal_from: Option<PathBuf>,
    /// The recording's first frame in the clip (CMU trials start with a one-frame T-pose: 1).
    #[arg(long, default_value_t = 0, value_parser = crate::args::frame_index)]
    start_frame: usize,
    /// The robot's nominal pose: robot.toml's T-pose, or its default standing pose (for
    /// recordings that start standing with the arms down).
    #[arg(long, value_enum, default_value_t = crate::args::NominalArg::Tpose)]
    nominal: crate::args::NominalArg,
    /// Inverse-kinematics iterations per frame.
    #[arg(long, default_value_t = 12, value_parser = crate::args::whole_within(1, 1000))]
    iterations: u64,
    /// Gaussian smoothing of the human motion before retargeting, σ in seconds (0: none): mocap jitter would otherwise
    /// ask the motors for accelerations they do not have.
    #[arg(long, default_value_t = 0.08, value_parser = crate::args::within(0.0, 1.0))]
    smoothing: f64,
    /// What of the performer is retargeted: `whole-body` (every joint of the recording) or
    /// `five-point` (only where a headset, two controllers and two foot trackers would be on the
    /// performer, the rest of the body estimated as `teleop --body five-point` does live): a
    /// preview of what a VR operator wearing them makes the robot do. Five points calibrate on a
    /// T-pose (`--nominal tpose`, the nominal frame).
    #[arg(long, value_enum, default_value_t = WearingArg::WholeBody)]
    wearing: WearingArg,
    /// Also write the retargeting report as JSON here: the key bodies' distance from the scaled
    /// human, the feet's sliding while the human's stand planted, soles into the floor, time per
    /// frame, and the clip's check (`check --clip`'s figures).
    #[arg(long, value_name = "JSON")]
    report: Option<PathBuf>,
}

/// Runs `retarget`.
pub fn run(args: &RetargetArgs) -> Result<()> {
    let robot = Robot::load(&args.robot)?;
    let bvh = Bvh::load(&args.bvh)?;
    println!(
        "{}: {} skeleton, {} joints, {} frames at {:.0} Hz ({:.1} s)",
        args.bvh.display(),
        match bvh.dialect {
            motion::bvh::Dialect::Cmu => "CMU",
            motion::bvh::Dialect::Bandai => "Bandai-Namco",
        },
        bvh.joints.len(),
        bvh.frames(),
        1.0 / bvh.frame_time,
        (bvh.frames() - 1) as f64 * bvh.frame_time
    );
    let options = RetargetOptions {
        rate_hz: args.rate,
        nominal_frame: args.nominal_frame,
        start_frame: args.start_frame,
        nominal: args.nominal.into(),
        iterations: args.iterations as usize,
        smoothing_s: args.smoothing,
        wearing: match args.wearing {
            WearingArg::WholeBody => human::sparse::Wearing::WholeBody,
            WearingArg::FivePoint => human::sparse::Wearing::FivePoint,
        },
    };
    let bar = indicatif::ProgressBar::new_spinner().with_message("retargeting");
    let started = std::time::Instant::now();
    let calibration = match &args.nominal_from {
        Some(path) => Some(Bvh::load(path).with_context(|| format!("--nominal-from {}", path.display()))?),
        None => None,
    };
    let motion = retarget_calibrated(&robot, &bvh, calibration.as_ref().unwrap_or(&bvh), &options)
        .with_context(|| match &args.nominal_from {
            Some(path) => format!("--nominal-from {}", path.display()),
            None => format!("--bvh {}", args.bvh.display()),
        })?;
    bar.finish_and_clear();
    println!(
        "retargeted onto {}: scale {:.3}, {} frames at {} Hz in {:.1} s; paired frames off their targets by {:.1} cm on average, {:.1} cm at worst",
        robot.config.name,
        motion.scale,
        motion.times.len(),
        args.rate,
        started.elapsed().as_secs_f64(),
        motion.mean_position_error * 100.0,
        motion.worst_position_error * 100.0
    );
    let header = [
        format!(
            "{}: retargeted by `robodeploy retarget` from {}",
            robot.config.name,
            args.bvh
                .file_name()
                .map_or_else(String::new, |f| f.to_string_lossy().into_owned())
        ),
        format!(
            "nominal frame {}{} ↔ robot {}, scale {:.4}; root quaternion is w, x, y, z",
            args.nominal_frame,
            args.nominal_from
                .as_ref()
                .and_then(|p| p.file_name())
                .map_or_else(String::new, |f| format!(" of {}", f.to_string_lossy())),
            match args.nominal {
                crate::args::NominalArg::Tpose => "T-pose",
                crate::args::NominalArg::Default => "default pose",
            },
            motion.scale
        ),
    ];
    if let Some(dir) = args.out.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    }
    std::fs::write(&args.out, motion.to_csv(&robot, &header))
        .with_context(|| format!("cannot write {}", args.out.display()))?;
    println!("wrote {}", args.out.display());
    println!("retargeting (the robot against the scaled human):");
    print!("{}", motion.report);

    // The clip checker, as `check --clip` runs it.
    let clip = Clip::load(&args.out)?;
    let reference = Reference::from_clip(&clip, &robot, args.rate)?;
    let quality = analysis::motion_check::analyze(&robot, &reference)?;
    println!("clip quality on the robot model:");
    print!("{quality}");
    if let Some(path) = &args.report {
        let json = serde_json::json!({
            "bvh": args.bvh,
            "robot": robot.config.name,
            "retarget": motion.report,
            "clip": quality,
        });
        std::fs::write(path, serde_json::to_string_pretty(&json)? + "\n")
            .with_context(|| format!("--report {}: cannot write", path.display()))?;
        println!("wrote {}", path.display());
    }
    let problems = quality.problems();
    let policy = args.policy.clone().or_else(|| robot.default_policy());
    let reported = match &policy {
        Some(path) => {
            let layout = policy::PolicyLayout::load(path, &robot)
                .with_context(|| format!("--policy {}", path.display()))?;
            (layout.manifest.reference.feasibility == policy::Feasibility::Report).then_some(layout.path)
        }
        None => None,
    };
    if let (false, Some(manifest)) = (problems.is_empty(), reported) {
        println!(
            "the robot could not follow this clip exactly ({}); reported, not refused: the policy \
             tracks kinematic references ({}: [reference] feasibility = \"report\")",
            problems.join("; "),
            manifest.display()
        );
    } else if !problems.is_empty() {
        bail!(
            "{}: the clip has problems:\n  {}",
            args.out.display(),
            problems.join("\n  ")
        );
    }
    Ok(())
}

/// `--wearing`'s values.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
enum WearingArg {
    WholeBody,
    FivePoint,
}
