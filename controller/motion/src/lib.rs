//! Motion files as retargeters and trainers write them, read and checked without Python: clips
//! as CSV (with a header, or headerless with a sidecar), NumPy's NPY/NPZ ([`npy`]: a clip's named
//! arrays, BeyondMimic and mjlab motions), and GMR's retargeted motions ([`gmr`]: its pickle, read
//! by the restricted unpickler [`pickle`], and the same fields in an NPZ). Each becomes a [`Clip`]
//! (root poses and joint angles per frame, in the file's own joint order); mapping it onto a robot
//! and resampling it is the controller's. Human motion capture is here too: BVH ([`bvh`]: CMU's
//! and Bandai-Namco's skeletons, forward kinematics into the robot's axes), which retargeting reads.

pub mod bvh;
pub mod clip;
pub mod gmr;
pub mod keypoints;
pub mod npy;
pub mod pickle;

pub use clip::*;
