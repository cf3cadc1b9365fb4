//! `robodeploy layout`: the Foxglove layout for a robot's recordings and live view.

use std::path::PathBuf;

use anyhow::{Context, Result};
use clap::Args;
use viewers::layout::{LayoutJoint, foxglove_layout};

/// Arguments of `layout`.
#[derive(Debug, Args)]
pub struct LayoutArgs {
    /// The robot description whose joints, buses and limits the plots show.
    #[arg(long, default_value_os_t = robots::locate::default_robot())]
    robot: PathBuf,
    /// Where to write the layout (JSON); standard output when not given.
    #[arg(long, short)]
    output: Option<PathBuf>,
}

/// Runs `layout`.
pub fn run(args: &LayoutArgs) -> Result<()> {
    let robot = robots::Robot::load(&args.robot)?;
    let text = layout_json(&robot)?;
    match &args.output {
        Some(path) => {
            std::fs::write(path, &text)
                .with_context(|| format!("--output {}: cannot write", path.display()))?;
            eprintln!(
                "layout: {} (Foxglove: Layouts → Import from file; then open a recording or `play --live`)",
                path.display()
            );
        }
        None => print!("{text}"),
    }
    Ok(())
}

/// The layout of `robot` as the file holds it.
pub fn layout_json(robot: &robots::Robot) -> Result<String> {
    let joints: Vec<LayoutJoint> = robot
        .config
        .joints
        .iter()
        .map(|j| LayoutJoint {
            name: j.name.clone(),
            bus: j.bus.clone(),
            limits: j.position_limits,
        })
        .collect();
    let layout = foxglove_layout(
        &robot.config.name,
        &robot.config.root_body,
        &joints,
        controller::keypoints::FAILURE_PX,
    );
    Ok(serde_json::to_string_pretty(&layout)? + "\n")
}
