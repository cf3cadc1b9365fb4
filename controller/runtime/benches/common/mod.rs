//! What the controller's benches share: the reference robot, its reference-following policy and
//! the squat clip; the same squat as a motion-tracking export (a fixture of
//! scripts/gen_tracking_export.py).

use controller::clip::{Clip, Reference};
use controller::policy::PolicyLayout;
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

/// The reference robot and the squat as a BeyondMimic-convention export carrying its motion
/// (`.local/fixtures/rd_biped_tracking.onnx`, made by `scripts/setup`), with that motion.
pub fn tracking_export() -> (Robot, PolicyLayout, Reference) {
    let robot = Robot::load(&reference_robot_path()).unwrap();
    let export = test_support::fixtures::fixture("rd_biped_tracking.onnx");
    let mut layout = PolicyLayout::load(&export, &robot).unwrap();
    let model = controller::onnx::OnnxModel::load(&export).unwrap();
    layout.bind_model(model.inputs(), model.output().1).unwrap();
    let squat = reference_robot_path().with_file_name("clips/squat.csv");
    let (reference, _) = controller::motion::load_reference(None, &squat, &layout, &robot, 0).unwrap();
    (robot, layout, reference)
}
