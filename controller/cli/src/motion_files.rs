//! `robodeploy motion info FILE`: what a motion file holds and how it maps onto a robot.

use std::path::PathBuf;

use anyhow::Result;
use clap::Subcommand;
use controller::clip::{Clip, Reference};
use motion::gmr::{GmrMotion, is_pickle};
use robots::Robot;
use robots::spatial::heading_of_quat;

/// Motion file tools.
#[derive(Debug, Subcommand)]
pub enum MotionCommand {
    /// What a motion file holds — its format, frames and rate, joint columns, root path, bodies —
    /// and, with --robot, how its columns map onto that robot's joints and whether every frame
    /// lies within the joints' limits. Reads CSV clips (with or without a sidecar), NPZ clips,
    /// BeyondMimic/mjlab motion NPZ, and GMR's pickles (`.pkl`) and NPZ. Moves nothing.
    Info {
        /// The motion file.
        file: PathBuf,
        /// A robot to map it onto (robot.toml).
        #[arg(long)]
        robot: Option<PathBuf>,
        /// Control rate to resample at when mapping onto the robot, Hz (default: the robot's).
        #[arg(long, value_parser = crate::args::within(1.0, 1000.0))]
        rate: Option<f64>,
    },
}

/// Runs a `motion` subcommand.
pub fn run(cmd: MotionCommand) -> Result<()> {
    let MotionCommand::Info { file, robot, rate } = cmd;
    let clip = Clip::load(&file)?;
    let format = if is_pickle(&file) {
        let m = GmrMotion::load_pickle(&file)?;
        let bodies = if m.bodies.is_empty() {
            "no body list".to_owned()
        } else {
            format!(
                "{} bodies{} ({}{})",
                m.bodies.len(),
                if m.has_body_positions {
                    " with positions per frame"
                } else {
                    ""
                },
                m.bodies.iter().take(6).cloned().collect::<Vec<_>>().join(", "),
                if m.bodies.len() > 6 { ", …" } else { "" }
            )
        };
        format!("GMR motion (Python pickle; root quaternion x y z w in the file); {bodies}")
    } else if file.extension().is_some_and(|e| e.eq_ignore_ascii_case("npz")) {
        "NumPy NPZ".to_owned()
    } else {
        "CSV".to_owned()
    };
    let frames = clip.times.len();
    println!("file   {}: {format}", file.display());
    println!(
        "       {frames} frames over {:.3} s ({:.3} frames/s), {} joint columns{}",
        clip.duration(),
        (frames - 1) as f64 / clip.duration(),
        clip.joints.len(),
        if clip.robot_order {
            " in the robot's joint order (the file names none)"
        } else {
            ""
        }
    );
    let (first, last) = (clip.root[0], clip.root[frames - 1]);
    let heading = |p: [f64; 7]| heading_of_quat([p[3], p[4], p[5], p[6]]).to_degrees();
    let path: f64 = clip
        .root
        .windows(2)
        .map(|w| (w[1][0] - w[0][0]).hypot(w[1][1] - w[0][1]))
        .sum();
    let (lo, hi) = clip
        .root
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), r| {
            (lo.min(r[2]), hi.max(r[2]))
        });
    println!(
        "root   starts at ({:.2}, {:.2}, {:.2}) m heading {:.0}°, ends at ({:.2}, {:.2}, {:.2}) m heading {:.0}°; \
         {path:.2} m walked over the floor, height {lo:.3}–{hi:.3} m",
        first[0],
        first[1],
        first[2],
        heading(first),
        last[0],
        last[1],
        last[2],
        heading(last)
    );
    let Some(robot_path) = robot else {
        return Ok(());
    };
    let robot = Robot::load(&robot_path)?;
    let names: Vec<&str> = if clip.robot_order {
        robot.config.joints.iter().map(|j| j.name.as_str()).collect()
    } else {
        clip.joints.iter().map(String::as_str).collect()
    };
    println!(
        "robot  {} ({} joints): the {} columns are {}",
        robot.config.name,
        robot.config.joints.len(),
        clip.joints.len(),
        if clip.robot_order {
            "its joints in its order".to_owned()
        } else {
            "named in the file".to_owned()
        }
    );
    println!("       {}", names.join(", "));
    let rate = rate.unwrap_or(robot.config.control_rate_hz);
    let reference = Reference::from_clip(&clip, &robot, rate)?;
    if !reference.held_joints.is_empty() {
        println!(
            "       not in the file, held at the default pose: {}",
            reference.held_joints.join(", ")
        );
    }
    println!(
        "ok     {} ticks at {rate} Hz, every frame within the joints' position and speed limits \
         (`check --clip` judges it on the robot's model)",
        reference.len()
    );
    Ok(())
}
