//! `robodeploy project`: a 3D clip seen by cameras as 2D keypoints, and a 3D clip measured against
//! 2D keypoint references (the pose estimator's COCO JSON, or keypoints this command wrote).

use std::path::PathBuf;

use anyhow::{Context, Result};
use clap::Args;
use controller::clip::{Clip, Reference};
use controller::keypoints::camera::load_cameras;
use controller::keypoints::clip::KeypointSource;
use controller::keypoints::{FAILURE_PX, compare, keypoint_positions, project};

/// Arguments of `project`.
#[derive(Debug, Args)]
pub struct ProjectArgs {
    /// The 3D clip (CSV, NPZ, or a motion file with its sidecar).
    #[arg(long)]
    clip: PathBuf,
    /// The robot: its [keypoints] map says which body or site stands for each keypoint.
    #[arg(long, default_value_os_t = robots::locate::default_robot())]
    robot: PathBuf,
    /// The cameras (TOML: [[camera]] with intrinsics, distortion and a pose in the world).
    #[arg(long)]
    camera: PathBuf,
    /// Frames per second of the keypoints written (without --against).
    #[arg(long, default_value_t = 30.0, value_parser = crate::args::within(1.0, 1000.0))]
    rate: f64,
    /// Where to write the keypoints (CSV: time_s, then VIEW/KEYPOINT/u,v,confidence).
    #[arg(long, short, default_value = "out/keypoints/keypoints.csv")]
    output: PathBuf,
    /// Instead of writing keypoints, measure the clip against these 2D references: keypoints
    /// this command wrote (CSV), or a pose estimator's COCO JSON (one view; see --view, --person,
    /// --fps). Prints the reprojection error per view, the frames over 100 px, and with two views
    /// or more the error of the keypoints triangulated from them.
    #[arg(long, value_name = "REF")]
    against: Option<PathBuf>,
    /// With a COCO reference: the camera it was filmed by (default: the only camera).
    #[arg(long)]
    view: Option<String>,
    /// With a COCO reference: the person to follow, by track_id (needed when a frame has several).
    #[arg(long)]
    person: Option<u64>,
    /// With a COCO reference: the video's frames per second.
    #[arg(long, default_value_t = 30.0, value_parser = crate::args::within(1.0, 1000.0))]
    fps: f64,
    /// With --against: also write the comparison as JSON here.
    #[arg(long, requires = "against")]
    json: Option<PathBuf>,
}

/// Runs `project`.
pub fn run(args: &ProjectArgs) -> Result<()> {
    let robot = robots::Robot::load(&args.robot)?;
    let cameras = load_cameras(&args.camera)?;
    let clip = Clip::load(&args.clip)?;
    let reference = match &args.against {
        Some(path) => {
            let source = KeypointSource {
                keypoints: path.clone(),
                cameras: args.camera.clone(),
                view: args.view.clone(),
                person: args.person,
                fps: args.fps,
            };
            Some(
                source
                    .load()
                    .with_context(|| format!("--against {}", path.display()))?
                    .1,
            )
        }
        None => None,
    };
    // The 3D clip sampled at the references' frames (or at --rate).
    let rate = match &reference {
        Some(r) if r.len() > 1 => 1.0 / (r.times[1] - r.times[0]),
        _ => args.rate,
    };
    let motion = Reference::from_clip(&clip, &robot, rate)?;
    let (names, positions) = keypoint_positions(&robot, &motion)?;
    let times: Vec<f64> = (0..motion.len()).map(|k| k as f64 / rate).collect();
    match &reference {
        None => {
            let keypoints = project(&cameras, &names, &times, &positions);
            if let Some(dir) = args.output.parent().filter(|d| !d.as_os_str().is_empty()) {
                std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
            }
            keypoints.write_csv(&args.output)?;
            println!(
                "{}: {} frames at {rate} Hz, {} keypoints, {} views",
                args.output.display(),
                keypoints.len(),
                names.len(),
                cameras.len()
            );
            for (v, camera) in cameras.iter().enumerate() {
                let seen = (0..keypoints.len())
                    .flat_map(|f| keypoints.at(f, v))
                    .filter(|p| p[2] > 0.0)
                    .count();
                let total = keypoints.len() * names.len();
                println!(
                    "  {}: {:.1} % of the keypoints on the image",
                    camera.name,
                    100.0 * seen as f64 / total.max(1) as f64
                );
            }
        }
        Some(reference) => {
            let c = compare(reference, &cameras, &names, &positions)?;
            println!(
                "{} against {}: {} frames",
                args.clip.display(),
                args.against
                    .as_ref()
                    .map_or(String::new(), |p| p.display().to_string()),
                c.frames
            );
            for v in &c.views {
                println!(
                    "  view {}: reprojection error mean {:.2} px, max {:.2} px ({} keypoints); frames over {FAILURE_PX} px: {}",
                    v.view, v.mean_px, v.max_px, v.compared, v.failed_frames
                );
            }
            match c.triangulated_mm {
                Some((mean, max, n)) => println!(
                    "  triangulated from the views: 3D error mean {mean:.1} mm, max {max:.1} mm ({n} keypoints)"
                ),
                None => println!("  one view: no triangulated 3D error (it takes two)"),
            }
            if !c.unmapped.is_empty() {
                println!(
                    "  not in the robot's [keypoints], left out: {}",
                    c.unmapped.join(", ")
                );
            }
            if let Some(path) = &args.json {
                std::fs::write(path, serde_json::to_string_pretty(&c)?)
                    .with_context(|| format!("--json {}: cannot write", path.display()))?;
            }
        }
    }
    Ok(())
}
