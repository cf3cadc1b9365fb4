//! What the controller's benches share: the reference robot, its reference-following policy and
//! the squat clip.

use controller::clip::{Clip, Reference};
use policy::PolicyLayout;
use robots::{Robot, reference_robot_path};

/// The reference robot, the reference follower and the squat clip at the policy's rate.
pub fn files() -> (Robot, PolicyLayout, Reference) {
    let robot = Robot::load(&reference_robot_path()).unwrap();
    let layout = PolicyLayout::load(
        &reference_robot_path().with_file_name("policies/reference_follower.toml"),
        &robot,
    )
    .unwrap();
    let clip = Clip::load(&reference_robot_path().with_file_name("clips/squat.csv")).unwrap();
    let reference = Reference::from_clip(&clip, &robot, layout.manifest.rate_hz).unwrap();
    (robot, layout, reference)
}
