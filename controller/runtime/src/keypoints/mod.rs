//! 2D keypoint references (Mimic2DM): cameras in the robot's world, keypoint clips (COCO JSON
//! from pose estimators, the project's CSV), a 3D clip projected into keypoints through the
//! cameras, and how far a 3D motion is from 2D references — reprojection error per view (px),
//! the paper's failure criterion (max > 100 px), and with two views or more the 3D error (mm) of
//! the keypoints triangulated from them.
//!
//! Which point of the robot stands for each keypoint is robot.toml's `[keypoints]` map.

pub mod track;

// The files (cameras, keypoint clips) are the `motion` crate's.
pub use motion::keypoints::{camera, clip};

use robots::{Robot, spatial};

use crate::clip::Reference;
use camera::{Camera, triangulate};
use clip::{KeypointClip, MIN_CONFIDENCE};

/// The paper's failure criterion: a frame fails when a keypoint is further than this, px.
pub const FAILURE_PX: f64 = 100.0;

/// Why keypoints could not be made or compared.
#[derive(Debug, thiserror::Error)]
pub enum KeypointError {
    /// The robot has no keypoint map.
    #[error("{}: no [keypoints] map (which body or site stands for each keypoint name)", .0.display())]
    NoMap(std::path::PathBuf),
    /// The robot's model could not be posed.
    #[error(transparent)]
    Kinematics(#[from] world::KinematicsError),
    /// The reference names no keypoint the robot maps.
    #[error("the reference's keypoints ({0}) are none of the robot's [keypoints]")]
    NoCommonKeypoint(String),
    /// A keypoint clip without frames.
    #[error("the keypoint references have no frames")]
    NoFrames,
    /// More views than a run records.
    #[error("{0} views: a run takes at most {max}", max = track::MAX_VIEWS)]
    TooManyViews(usize),
    /// An observation term names a keypoint the reference or the robot lacks.
    #[error("keypoint {0:?}: not among the reference's keypoints that the robot's [keypoints] maps")]
    Unmapped(String),
    /// A view of the reference has no camera.
    #[error("view {view:?} has no camera (cameras: {known})")]
    NoCamera {
        /// The view.
        view: String,
        /// The cameras given.
        known: String,
    },
}

/// The camera of each view, by name; a view without one is refused, naming the cameras there are.
pub fn cameras_of<'a>(views: &[String], cameras: &'a [Camera]) -> Result<Vec<&'a Camera>, KeypointError> {
    views
        .iter()
        .map(|v| {
            cameras
                .iter()
                .find(|c| &c.name == v)
                .ok_or_else(|| KeypointError::NoCamera {
                    view: v.clone(),
                    known: cameras
                        .iter()
                        .map(|c| c.name.as_str())
                        .collect::<Vec<_>>()
                        .join(", "),
                })
        })
        .collect()
}

/// The robot's keypoints (robot.toml's `[keypoints]`, name order) in the world at every frame of
/// `reference`: names, and `frames × names` positions.
pub fn keypoint_positions(
    robot: &Robot,
    reference: &Reference,
) -> Result<(Vec<String>, Vec<[f64; 3]>), KeypointError> {
    let map = &robot.config.keypoints;
    if map.is_empty() {
        return Err(KeypointError::NoMap(robot.path.clone()));
    }
    let frames: Vec<String> = map.values().map(|k| k.frame().to_owned()).collect();
    let poses = crate::fk::body_poses(robot, reference, &frames)?;
    let offsets: Vec<[f64; 3]> = map.values().map(robots::KeypointFrame::offset).collect();
    let positions = poses
        .chunks(map.len())
        .flat_map(|frame| {
            frame.iter().zip(&offsets).map(|(p, &o)| {
                let at = spatial::quat_rotate([p[3], p[4], p[5], p[6]], o);
                spatial::add([p[0], p[1], p[2]], at)
            })
        })
        .collect();
    Ok((map.keys().cloned().collect(), positions))
}

/// `positions` (`times.len() × names.len()`, world) seen by each camera: a keypoint behind a
/// camera or off its image is unseen (confidence 0).
pub fn project(cameras: &[Camera], names: &[String], times: &[f64], positions: &[[f64; 3]]) -> KeypointClip {
    let mut points = Vec::with_capacity(times.len() * cameras.len() * names.len());
    for frame in positions.chunks(names.len().max(1)).take(times.len()) {
        for c in cameras {
            for &p in frame {
                points.push(match c.project(p).filter(|uv| c.sees(*uv)) {
                    Some([u, v]) => [u, v, 1.0],
                    None => [f64::NAN, f64::NAN, 0.0],
                });
            }
        }
    }
    KeypointClip {
        views: cameras.iter().map(|c| c.name.clone()).collect(),
        names: names.to_vec(),
        times: times.to_vec(),
        points,
    }
}

/// How far the projected motion is from one view's references.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct ViewError {
    /// The view.
    pub view: String,
    /// Mean and largest distance over every keypoint seen in both, px.
    pub mean_px: f64,
    pub max_px: f64,
    /// Keypoint pairs compared.
    pub compared: usize,
    /// Frames whose largest distance is over [`FAILURE_PX`].
    pub failed_frames: usize,
}

/// The motion's keypoints against 2D references.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Comparison {
    /// Per view.
    pub views: Vec<ViewError>,
    /// With two views or more: the references triangulated against the motion's keypoints, mean
    /// and largest, mm, and how many keypoints were triangulated.
    pub triangulated_mm: Option<(f64, f64, usize)>,
    /// Frames compared (the shorter of the two).
    pub frames: usize,
    /// Reference keypoints the robot does not map (left out).
    pub unmapped: Vec<String>,
}

/// Compares `positions` (`frames × names`, world) frame by frame with `reference` through
/// `cameras` (one per view, by name).
pub fn compare(
    reference: &KeypointClip,
    cameras: &[Camera],
    names: &[String],
    positions: &[[f64; 3]],
) -> Result<Comparison, KeypointError> {
    let view_cameras = cameras_of(&reference.views, cameras)?;
    // Reference keypoint → the robot's.
    let pairs: Vec<(usize, usize)> = reference
        .names
        .iter()
        .enumerate()
        .filter_map(|(r, n)| names.iter().position(|m| m == n).map(|k| (r, k)))
        .collect();
    if pairs.is_empty() {
        return Err(KeypointError::NoCommonKeypoint(reference.names.join(", ")));
    }
    let unmapped = reference
        .names
        .iter()
        .filter(|n| !names.contains(n))
        .cloned()
        .collect();
    let n = names.len().max(1);
    let frames = reference.len().min(positions.len() / n);
    let mut views: Vec<ViewError> = reference
        .views
        .iter()
        .map(|v| ViewError {
            view: v.clone(),
            mean_px: 0.0,
            max_px: 0.0,
            compared: 0,
            failed_frames: 0,
        })
        .collect();
    let (mut sum_mm, mut max_mm, mut triangulated) = (0.0, 0.0f64, 0usize);
    for f in 0..frames {
        let world = &positions[f * n..(f + 1) * n];
        for (v, camera) in view_cameras.iter().enumerate() {
            let seen = reference.at(f, v);
            let mut worst = 0.0f64;
            for &(r, k) in &pairs {
                let p = seen[r];
                let Some(uv) = (p[2] > MIN_CONFIDENCE)
                    .then_some(())
                    .and(camera.project(world[k]))
                else {
                    continue;
                };
                let d = (uv[0] - p[0]).hypot(uv[1] - p[1]);
                let e = &mut views[v];
                e.mean_px += d;
                e.max_px = e.max_px.max(d);
                e.compared += 1;
                worst = worst.max(d);
            }
            if worst > FAILURE_PX {
                views[v].failed_frames += 1;
            }
        }
        for &(r, k) in &pairs {
            let rays: Vec<(&Camera, [f64; 2])> = view_cameras
                .iter()
                .enumerate()
                .filter_map(|(v, c)| {
                    let p = reference.at(f, v)[r];
                    (p[2] > MIN_CONFIDENCE).then_some((*c, [p[0], p[1]]))
                })
                .collect();
            if let Some(x) = triangulate(&rays) {
                let d = 1000.0 * spatial::norm(spatial::sub(x, world[k]));
                sum_mm += d;
                max_mm = max_mm.max(d);
                triangulated += 1;
            }
        }
    }
    for e in &mut views {
        e.mean_px /= e.compared.max(1) as f64;
    }
    Ok(Comparison {
        views,
        triangulated_mm: (triangulated > 0).then(|| (sum_mm / triangulated as f64, max_mm, triangulated)),
        frames,
        unmapped,
    })
}
