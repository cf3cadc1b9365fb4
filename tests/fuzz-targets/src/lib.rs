//! The fuzz targets' bodies: every parser that takes bytes from outside, with what must hold of
//! whatever it accepts. `tests/fuzz` wraps each in a cargo-fuzz target (nightly, libFuzzer);
//! the test suite replays every committed corpus through them on stable, in the one build
//! (`tests/tests/fuzz_corpora.rs`).

pub mod bno055_uart;
pub mod bvh_text;
pub mod clip_csv;
pub mod coco_image_ids;
pub mod dds_samples;
pub mod dxl_packet;
pub mod feetech_packets;
pub mod gmr_pickle;
pub mod holosoma_metadata;
pub mod keypoint_inputs;
pub mod live_client_messages;
pub mod mcap_recording;
pub mod mirror_toml;
pub mod mit_frames;
pub mod motion_csv;
pub mod npy_array;
pub mod onnx_metadata;
pub mod osc_vmc;
pub mod policy_toml;
pub mod robot_toml;
pub mod rvc_stream;
pub mod socketcand_text;
pub mod udp_command;
pub mod wit_stream;

/// A target: one input through its parser.
pub type Target = fn(&[u8]);

/// Every target by name (its folder under `tests/fuzz/corpus`).
pub const TARGETS: &[(&str, Target)] = &[
    ("bno055_uart", bno055_uart::run),
    ("bvh_text", bvh_text::run),
    ("clip_csv", clip_csv::run),
    ("coco_image_ids", coco_image_ids::run),
    ("dxl_packet", dxl_packet::run),
    ("feetech_packets", feetech_packets::run),
    ("gmr_pickle", gmr_pickle::run),
    ("dds_samples", dds_samples::run),
    ("holosoma_metadata", holosoma_metadata::run),
    ("keypoint_inputs", keypoint_inputs::run),
    ("live_client_messages", live_client_messages::run),
    ("mcap_recording", mcap_recording::run),
    ("mirror_toml", mirror_toml::run),
    ("mit_frames", mit_frames::run),
    ("motion_csv", motion_csv::run),
    ("npy_array", npy_array::run),
    ("onnx_metadata", onnx_metadata::run),
    ("osc_vmc", osc_vmc::run),
    ("policy_toml", policy_toml::run),
    ("robot_toml", robot_toml::run),
    ("rvc_stream", rvc_stream::run),
    ("socketcand_text", socketcand_text::run),
    ("udp_command", udp_command::run),
    ("wit_stream", wit_stream::run),
];

/// A walking policy's live commands (forward, leftward, turning), for the targets that feed them.
pub fn walk_commands() -> human::commands::CommandSpec {
    human::commands::CommandSpec {
        names: vec!["lin_vel_x".into(), "lin_vel_y".into(), "ang_vel_z".into()],
        ranges: vec![[-0.5, 1.0], [-0.3, 0.3], [-1.0, 1.0]],
        default: None,
        ramp: None,
        step: None,
        kinds: None,
        gamepad: None,
        timeout_s: 0.5,
    }
}

/// What must hold of every IMU sample a decoder accepts: finite readings and a unit quaternion.
///
/// # Panics
/// When it does not.
pub fn assert_imu_sample_sound(s: &firmware_bridge::imu::wit::ImuSample) {
    assert!(
        s.quat
            .iter()
            .chain(&s.gyro)
            .chain(&s.accel)
            .all(|v| v.is_finite())
    );
    let norm = s.quat.iter().map(|q| q * q).sum::<f64>();
    assert!((norm - 1.0).abs() < 1e-9, "{:?}", s.quat);
}

/// The reference robot, loaded once per process.
///
/// # Panics
/// When the checkout's reference robot does not load (the fuzzing is then meaningless).
pub fn reference_robot() -> &'static robots::Robot {
    static ROBOT: std::sync::OnceLock<robots::Robot> = std::sync::OnceLock::new();
    ROBOT.get_or_init(|| {
        robots::Robot::load(&robots::reference_robot_path()).expect("the reference robot loads")
    })
}
