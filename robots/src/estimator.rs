//! The state estimator's settings as robot.toml's `[estimator]` gives them (every field optional,
//! the defaults below): its noises, its contact thresholds, how it tells a held robot. The
//! filter itself is `world::estimator`.

/// Which filter estimates the base.
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, Default, serde::Deserialize, schemars::JsonSchema, serde::Serialize,
)]
#[serde(rename_all = "lowercase")]
pub enum FilterKind {
    /// The linear Kalman filter (Bloesch et al. 2012, linear form): orientation from the IMU's
    /// own fusion, position, velocity, accelerometer bias and feet estimated.
    Linear,
    /// The contact-aided invariant EKF (Hartley et al. 2020): orientation estimated too, from
    /// the gyro and the legs, with both IMU biases; its leg measurements' error does not depend
    /// on the estimate.
    #[default]
    Invariant,
}

impl std::fmt::Display for FilterKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Self::Linear => "linear Kalman filter",
            Self::Invariant => "invariant EKF",
        })
    }
}

/// The filter's noises and the contact thresholds.
#[derive(Debug, Clone, Copy, PartialEq, serde::Deserialize, schemars::JsonSchema, serde::Serialize)]
#[serde(default, deny_unknown_fields)]
pub struct EstimatorConfig {
    /// `"invariant"` (the default) or `"linear"`.
    pub filter: FilterKind,
    /// Gyro white noise, rad/s/√Hz (the invariant filter integrates the gyro).
    pub gyro_noise: f64,
    /// Gyro bias random walk, rad/s/√s.
    pub gyro_bias_walk: f64,
    /// The IMU's own fused orientation as a measurement of the invariant filter's, rad (1σ per
    /// axis); 0: not used. Standing still, tilt and accelerometer bias cannot be told apart
    /// from the legs alone, and the gyro's heading bias not at all; the IMU's fusion (levelled
    /// by gravity, its gyro bias taken at start) tells them.
    pub imu_attitude_noise: f64,
    /// Accelerometer white noise, m/s²/√Hz.
    pub accel_noise: f64,
    /// Accelerometer bias random walk, m/s²/√s.
    pub bias_walk: f64,
    /// A standing foot's drift, m/√s (slip).
    pub stance_foot_walk: f64,
    /// A foot in the air, m/√s: large, so it follows the kinematics alone.
    pub swing_foot_walk: f64,
    /// Leg kinematics: foot position relative to the base, m (1σ).
    pub kinematic_position_noise: f64,
    /// Leg kinematics: base velocity from a standing foot, m/s (1σ).
    pub kinematic_velocity_noise: f64,
    /// A foot lands within this height of where it last stood, m (for a robot standing
    /// `contact_scale_height_m` high).
    pub contact_on_m: f64,
    /// A foot lifts off beyond this height, m (likewise scaled).
    pub contact_off_m: f64,
    /// A landing foot moves slower than this, m/s (likewise scaled).
    pub contact_speed: f64,
    /// The standing height the three above are given for, m: its base above its soles. The
    /// estimator scales them to the robot's own standing height when it starts (heights in
    /// proportion, the speed by the square root, as in dynamically similar gaits): a 25 cm
    /// biped's feet lift millimetres where a humanoid's lift centimetres. 0: taken as given.
    pub contact_scale_height_m: f64,
    /// Where the legs' torques give a foot's load: it lands once carrying this share of the
    /// robot's weight…
    pub contact_load: f64,
    /// …and lifts off below this share.
    pub contact_unload: f64,
    /// A foot moving faster than `contact_speed` lifts off below this share of its leg's own
    /// weight: what the torques of a swinging leg read as a load (its inertia, unmodelled
    /// friction), so the threshold scales with the leg.
    pub leg_unload: f64,
    /// A foot carrying more than this share of the robot's weight stands (lands, or stays
    /// down), however high the legs put it or however fast: the ground pushes on nothing else.
    pub carrying: f64,
    /// The robot is held (a harness, a gantry, a hand) while its feet together carry less than
    /// this share of its weight…
    pub held_below: f64,
    /// …and stands once they carry more than this share: the filter starts again there, the
    /// floor under its feet.
    pub standing_above: f64,
    /// A standing foot's base velocity further than this many standard deviations from the
    /// filter's (Mahalanobis distance over the three axes) is not taken: a foot that slips,
    /// pivots, or reads as loaded in the air (a fast swing's torques). Every standing foot refused
    /// for five (`world::estimator::MAX_REFUSED_TICKS`) in a row is taken again, so the filter cannot lock itself out.
    pub velocity_gate: f64,
    /// The floor is level: a standing foot's sole is at the height the robot first stood on,
    /// within this much, m (1σ); 0: no such assumption (uneven ground: the height then rests on
    /// where each foot landed alone, and drifts).
    pub floor_noise: f64,
}

impl Default for EstimatorConfig {
    fn default() -> Self {
        Self {
            filter: FilterKind::default(),
            gyro_noise: 0.005,
            gyro_bias_walk: 1e-4,
            imu_attitude_noise: 0.02,
            accel_noise: 0.2,
            bias_walk: 0.005,
            stance_foot_walk: 0.0005,
            swing_foot_walk: 2.0,
            kinematic_position_noise: 0.003,
            kinematic_velocity_noise: 0.03,
            contact_on_m: 0.012,
            contact_off_m: 0.02,
            contact_speed: 0.35,
            contact_scale_height_m: 0.75,
            contact_load: 0.03,
            contact_unload: 0.01,
            leg_unload: 0.5,
            carrying: 0.25,
            velocity_gate: 5.0,
            held_below: 0.2,
            standing_above: 0.6,
            floor_noise: 0.005,
        }
    }
}

impl EstimatorConfig {
    /// Whether every field is its default (robot.toml then leaves `[estimator]` out).
    pub fn is_default(&self) -> bool {
        *self == Self::default()
    }

    /// Each field within its documented range; the error names the field under `[estimator]`.
    pub fn check(&self) -> Result<(), (String, String)> {
        use crate::config::check_range;
        let field = |f: &str| format!("estimator.{f}");
        for (name, value, lo, hi, unit) in [
            ("gyro_noise", self.gyro_noise, 1e-6, 1.0, "rad/s/√Hz"),
            ("gyro_bias_walk", self.gyro_bias_walk, 0.0, 0.1, "rad/s/√s"),
            ("imu_attitude_noise", self.imu_attitude_noise, 0.0, 1.0, "rad"),
            ("accel_noise", self.accel_noise, 1e-4, 10.0, "m/s²/√Hz"),
            ("bias_walk", self.bias_walk, 0.0, 1.0, "m/s²/√s"),
            ("stance_foot_walk", self.stance_foot_walk, 0.0, 1.0, "m/√s"),
            ("swing_foot_walk", self.swing_foot_walk, 1e-3, 100.0, "m/√s"),
            (
                "kinematic_position_noise",
                self.kinematic_position_noise,
                1e-5,
                0.5,
                "m",
            ),
            (
                "kinematic_velocity_noise",
                self.kinematic_velocity_noise,
                1e-4,
                5.0,
                "m/s",
            ),
            ("contact_on_m", self.contact_on_m, 0.0, 0.5, "m"),
            ("contact_off_m", self.contact_off_m, 0.0, 0.5, "m"),
            ("contact_speed", self.contact_speed, 0.0, 10.0, "m/s"),
            (
                "contact_scale_height_m",
                self.contact_scale_height_m,
                0.0,
                5.0,
                "m",
            ),
            (
                "contact_load",
                self.contact_load,
                0.0,
                1.0,
                "(share of the weight)",
            ),
            (
                "contact_unload",
                self.contact_unload,
                0.0,
                1.0,
                "(share of the weight)",
            ),
            (
                "leg_unload",
                self.leg_unload,
                0.0,
                10.0,
                "(share of the leg's weight)",
            ),
            (
                "carrying",
                self.carrying,
                0.0,
                10.0,
                "(share of the weight; above 1: never)",
            ),
            ("velocity_gate", self.velocity_gate, 1.0, 1e6, "σ"),
            ("held_below", self.held_below, 0.0, 1.0, "(share of the weight)"),
            (
                "standing_above",
                self.standing_above,
                0.0,
                1.0,
                "(share of the weight)",
            ),
            ("floor_noise", self.floor_noise, 0.0, 1.0, "m"),
        ] {
            check_range(&field(name), Some(value), lo, hi, unit)?;
        }
        if self.contact_off_m < self.contact_on_m {
            return Err((
                field("contact_off_m"),
                format!(
                    "{} m is below contact_on_m = {} m: a foot would lift off where it lands",
                    crate::num(self.contact_off_m),
                    crate::num(self.contact_on_m)
                ),
            ));
        }
        if self.contact_unload > self.contact_load || self.held_below > self.standing_above {
            return Err((
                field(if self.contact_unload > self.contact_load {
                    "contact_unload"
                } else {
                    "held_below"
                }),
                "the lower threshold of a pair is above the upper one (contact_unload ≤ contact_load, held_below ≤ standing_above)"
                    .into(),
            ));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_defaults_pass_and_each_bad_field_is_named() {
        assert!(EstimatorConfig::default().check().is_ok());
        let bad = |text: &str| {
            let c: EstimatorConfig = toml::from_str(text).unwrap();
            c.check().unwrap_err().0
        };
        assert_eq!(bad("accel_noise = 0.0"), "estimator.accel_noise");
        assert_eq!(bad("velocity_gate = nan"), "estimator.velocity_gate");
        assert_eq!(bad("held_below = 0.7"), "estimator.held_below");
        assert_eq!(bad("contact_unload = 0.5"), "estimator.contact_unload");
        assert_eq!(bad("gyro_noise = -1.0"), "estimator.gyro_noise");
        let linear: EstimatorConfig = toml::from_str("filter = \"linear\"").unwrap();
        assert_eq!(linear.filter, FilterKind::Linear);
        assert!(toml::from_str::<EstimatorConfig>("filter = \"ukf\"").is_err());
        let no_floor: EstimatorConfig = toml::from_str("floor_noise = 0.0").unwrap();
        assert!(no_floor.check().is_ok() && no_floor.floor_noise == 0.0);
    }
}
