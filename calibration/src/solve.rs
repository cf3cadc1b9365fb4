//! The arithmetic of calibration, free of buses: a joint's direction and zero from two jig poses,
//! where to put an encoder's wrap point, and the IMU's mounting from two gravity directions.

use firmware_bridge::dxl::models as dxl_models;

/// A joint's actuator mapping: actuator angle = `zero` + `direction` · gear · joint angle.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct JointMapping {
    /// +1 or -1.
    pub direction: f64,
    /// Actuator angle at joint zero, rad.
    pub zero: f64,
}

/// Direction and zero from the actuator angles `theta` read with the joint clamped at `q` in two
/// poses. The measured ratio must match the gear within `tolerance` (relative): anything else means
/// the joint slipped in the jig, or the gear or the jig pose is wrong.
pub fn joint_from_two_poses(
    q: [f64; 2],
    theta: [f64; 2],
    gear: f64,
    tolerance: f64,
) -> Result<JointMapping, SolveError> {
    let dq = q[1] - q[0];
    if dq.abs() < 1e-3 {
        return Err(SolveError(format!(
            "the two jig poses differ by only {dq:.4} rad"
        )));
    }
    let ratio = (theta[1] - theta[0]) / dq;
    if ((ratio.abs() - gear) / gear).abs() > tolerance {
        return Err(SolveError(format!(
            "the actuator turned {:.4} rad for {dq:.4} rad of joint (ratio {ratio:.3}, gear {gear}): \
             the joint slipped in the jig, or the gear is wrong",
            theta[1] - theta[0]
        )));
    }
    let direction = ratio.signum();
    Ok(JointMapping {
        direction,
        zero: theta[0] - direction * gear * q[0],
    })
}

/// Where a joint's range lies on the actuator, rad: the actuator angles of both ends, low first.
pub fn actuator_range(mapping: JointMapping, gear: f64, range: [f64; 2]) -> [f64; 2] {
    let a = mapping.zero + mapping.direction * gear * range[0];
    let b = mapping.zero + mapping.direction * gear * range[1];
    [a.min(b), a.max(b)]
}

/// A Dynamixel joint's Homing Offset (ticks) that puts the middle of its range at the encoder's
/// centre (2048), so the wrap point (0/4095) sits half a turn from the middle of the range.
/// `mapping.zero` is measured with Homing Offset 0. Returns the offset and the new zero (rad,
/// relative to tick 2048, Homing Offset included). Refuses ranges wider than a turn.
pub fn dynamixel_homing(mapping: JointMapping, range: [f64; 2]) -> Result<(i32, f64), SolveError> {
    let [lo, hi] = actuator_range(mapping, 1.0, range);
    let per_tick = dxl_models::rad_per_tick();
    let span_ticks = (hi - lo) / per_tick;
    if span_ticks >= 4096.0 - 2.0 * WRAP_MARGIN_TICKS {
        return Err(SolveError(format!(
            "the joint's range spans {span_ticks:.0} ticks: more than one turn of the encoder"
        )));
    }
    let centre_ticks = 2048.0 + (lo + hi) / 2.0 / per_tick;
    let homing = (2048.0 - centre_ticks).round() as i32;
    Ok((homing, mapping.zero + f64::from(homing) * per_tick))
}

/// Ticks kept between a Dynamixel joint's range and the wrap point.
pub const WRAP_MARGIN_TICKS: f64 = 64.0;

/// An MIT motor's range must stay inside the protocol's position field (±`p_max`), where the
/// 16-bit value wraps; a margin of 5 % is kept.
pub fn check_mit_range(
    mapping: JointMapping,
    gear: f64,
    range: [f64; 2],
    p_max: f64,
) -> Result<(), SolveError> {
    let [lo, hi] = actuator_range(mapping, gear, range);
    let limit = 0.95 * p_max;
    if lo < -limit || hi > limit {
        return Err(SolveError(format!(
            "on the motor the joint's range is [{lo:.3}, {hi:.3}] rad, crossing the position field's \
             wrap at ±{p_max} rad: set the motor's zero near the middle of the joint's range (MIT \
             set-zero frame, joint in the jig), then calibrate again"
        )));
    }
    Ok(())
}

use robots::spatial::{self, Mat3, angle_between, cross, unit};

/// Why measured poses do not give an answer (too close together, out of range), for a person.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{0}")]
pub struct SolveError(pub String);

/// TRIAD: the rotation R with `R·u1 = r1` exactly and `R·u2` as close to `r2` as the angle
/// between them allows (`u` measured in one frame, `r` the same directions in the other).
pub fn triad(u1: [f64; 3], u2: [f64; 3], r1: [f64; 3], r2: [f64; 3]) -> Mat3 {
    let basis = |a: [f64; 3], b: [f64; 3]| {
        let t1 = unit(a);
        let t2 = unit(cross(a, b));
        [t1, t2, cross(t1, t2)]
    };
    let (m, n) = (basis(u1, u2), basis(r1, r2));
    // R = N · Mᵀ, with the basis vectors as columns of M and N.
    let mut r = [[0.0; 3]; 3];
    for (i, row) in r.iter_mut().enumerate() {
        for (j, v) in row.iter_mut().enumerate() {
            *v = (0..3).map(|k| n[k][i] * m[k][j]).sum();
        }
    }
    r
}

/// The angle of the rotation taking `a` to `b`, rad.
pub fn rotation_between(a: &Mat3, b: &Mat3) -> f64 {
    spatial::norm(spatial::log(&spatial::mat_mul(&spatial::transpose(a), b)))
}

/// The IMU's mounting (IMU axes → base axes) from the mean specific force (the "up" direction in
/// IMU axes) with the base upright and with the base pitched forward (nose down) about its y axis.
/// Returns the rotation and the measured tilt between the poses, rad.
pub fn imu_mounting(up_upright: [f64; 3], up_pitched: [f64; 3]) -> Result<(Mat3, f64), SolveError> {
    let alpha = angle_between(up_upright, up_pitched);
    if alpha < 10f64.to_radians() {
        return Err(SolveError(format!(
            "the two poses differ by only {:.1}° of tilt: tilt the robot at least 10° (20–40° is best)",
            alpha.to_degrees()
        )));
    }
    // Pitching forward by α about base y turns "up", seen from the base, to (−sin α, 0, cos α).
    let r2 = [-alpha.sin(), 0.0, alpha.cos()];
    Ok((triad(up_upright, up_pitched, [0.0, 0.0, 1.0], r2), alpha))
}

#[cfg(test)]
mod tests {
    use super::*;

    use robots::spatial::{mat_apply as apply, transpose};

    #[test]
    fn two_poses_give_direction_and_zero_for_both_signs() {
        for (direction, zero, gear) in [(1.0, 0.3, 1.0), (-1.0, -1.2, 1.0), (-1.0, 2.0, 1.5)] {
            let q = [0.1, 0.3];
            let theta = q.map(|q| zero + direction * gear * q);
            let m = joint_from_two_poses(q, theta, gear, 0.1).unwrap();
            assert_eq!(m.direction, direction);
            assert!((m.zero - zero).abs() < 1e-12);
        }
    }

    #[test]
    fn a_slipped_joint_or_a_wrong_gear_is_refused() {
        let e = joint_from_two_poses([0.0, 0.2], [0.0, 0.05], 1.0, 0.1).unwrap_err();
        assert!(e.0.contains("slipped"), "{e}");
        assert!(joint_from_two_poses([0.0, 0.0], [0.0, 0.2], 1.0, 0.1).is_err());
    }

    #[test]
    fn homing_centres_the_range_away_from_the_wrap() {
        let per_tick = dxl_models::rad_per_tick();
        // The range [-1.5, 1.5] lands at actuator [1.0, 4.0] rad: ticks 2700–4655, across 4095.
        let m = JointMapping {
            direction: 1.0,
            zero: 2.5,
        };
        let (homing, zero) = dynamixel_homing(m, [-1.5, 1.5]).unwrap();
        let ticks = |q: f64| 2048.0 + (zero + q) / per_tick;
        assert!(ticks(-1.5) > WRAP_MARGIN_TICKS && ticks(1.5) < 4095.0 - WRAP_MARGIN_TICKS);
        assert!((ticks(0.0) - 2048.0).abs() <= 0.5);
        assert_eq!(homing, (-2.5 / per_tick).round() as i32);
        assert!(dynamixel_homing(m, [-3.2, 3.2]).is_err());
    }

    #[test]
    fn mit_ranges_beyond_the_position_field_are_refused() {
        let m = JointMapping {
            direction: -1.0,
            zero: 11.0,
        };
        assert!(
            check_mit_range(m, 1.0, [-2.0, 0.5], 12.5)
                .unwrap_err()
                .0
                .contains("wrap")
        );
        assert!(
            check_mit_range(
                JointMapping {
                    direction: 1.0,
                    zero: 0.2
                },
                1.0,
                [-2.0, 2.0],
                12.5
            )
            .is_ok()
        );
    }

    #[test]
    fn mounting_is_recovered_from_two_gravity_directions() {
        let truth = spatial::mat_of_rpy([0.4, -1.0, 2.5]); // IMU → base
        let to_imu = transpose(&truth);
        let alpha = 0.5_f64;
        let up1 = apply(&to_imu, [0.0, 0.0, 1.0]);
        let up2 = apply(&to_imu, [-alpha.sin(), 0.0, alpha.cos()]);
        let (r, tilt) = imu_mounting(up1, up2).unwrap();
        assert!(rotation_between(&r, &truth) < 1e-9);
        assert!((tilt - alpha).abs() < 1e-12);
        assert!(imu_mounting(up1, up1).is_err());
    }
}
