//! 2D keypoint references as files: the cameras that saw them (`cameras.toml`: intrinsics, pose
//! in the robot's world, and the geometry of seeing — projection, triangulation) and the keypoint
//! clips themselves (COCO JSON from pose estimators, the project's CSV). What a run does with them
//! is the controller's (`controller::keypoints`).

pub mod camera;
pub mod clip;
