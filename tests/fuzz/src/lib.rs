//! What several fuzz targets share.

/// The reference robot, loaded once per fuzzing process.
///
/// # Panics
/// When the checkout's reference robot does not load (the fuzzing is then meaningless).
pub fn reference_robot() -> &'static robots::Robot {
    static ROBOT: std::sync::OnceLock<robots::Robot> = std::sync::OnceLock::new();
    ROBOT.get_or_init(|| {
        robots::Robot::load(&robots::reference_robot_path()).expect("the reference robot loads")
    })
}
