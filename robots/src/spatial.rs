//! The project's one spatial-math module: rotations, quaternions and frames, computed by `glam`.
//!
//! Conventions, the same everywhere in the project (and MuJoCo's):
//! - quaternions are stored as `[w, x, y, z]` arrays (scalar first), unit length;
//! - rotation matrices are stored row-major as `[[f64; 3]; 3]` ([`Mat3`]), acting on column vectors;
//! - roll/pitch/yaw are Z-Y-X intrinsic: `R = Rz(yaw) · Ry(pitch) · Rx(roll)`;
//! - the world is z-up; a heading is the yaw of a frame's x axis about +z.
//!
//! The arrays are what files, telemetry and MuJoCo hold; the arithmetic is glam's. Code that does a
//! lot of math at once may convert with [`quat`], [`wxyz`], [`mat`] and [`rows`] and use glam's
//! types directly.

pub use glam::{DMat3, DQuat, DVec3, EulerRot};

/// A rotation matrix, row-major.
pub type Mat3 = [[f64; 3]; 3];

/// The identity rotation.
pub const IDENTITY: Mat3 = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];

/// The identity quaternion `[w, x, y, z]`.
pub const QUAT_IDENTITY: [f64; 4] = [1.0, 0.0, 0.0, 0.0];

/// glam's quaternion of `[w, x, y, z]`.
#[inline]
pub fn quat(q: [f64; 4]) -> DQuat {
    DQuat::from_xyzw(q[1], q[2], q[3], q[0])
}

/// `[w, x, y, z]` of glam's quaternion.
#[inline]
pub fn wxyz(q: DQuat) -> [f64; 4] {
    [q.w, q.x, q.y, q.z]
}

/// glam's matrix of a row-major rotation.
#[inline]
pub fn mat(r: &Mat3) -> DMat3 {
    DMat3::from_cols_array_2d(r).transpose()
}

/// The row-major array of glam's matrix.
#[inline]
pub fn rows(m: DMat3) -> Mat3 {
    m.transpose().to_cols_array_2d()
}

/// Hamilton product `a ⊗ b`.
#[inline]
pub fn quat_mul(a: [f64; 4], b: [f64; 4]) -> [f64; 4] {
    wxyz(quat(a) * quat(b))
}

/// The inverse of a unit quaternion.
#[inline]
pub fn quat_conj(q: [f64; 4]) -> [f64; 4] {
    [q[0], -q[1], -q[2], -q[3]]
}

/// `q` scaled to unit length, with `w ≥ 0` (the same rotation, one representative).
pub fn quat_normalize(q: [f64; 4]) -> [f64; 4] {
    let n = quat(q).normalize();
    wxyz(if n.w < 0.0 { -n } else { n })
}

/// Rotates `v` by the unit quaternion `q`.
#[inline]
pub fn quat_rotate(q: [f64; 4], v: [f64; 3]) -> [f64; 3] {
    (quat(q) * DVec3::from(v)).into()
}

/// The quaternion of roll, pitch, yaw (rad).
pub fn quat_of_rpy(roll: f64, pitch: f64, yaw: f64) -> [f64; 4] {
    wxyz(DQuat::from_euler(EulerRot::ZYX, yaw, pitch, roll))
}

/// Roll, pitch, yaw (rad) of a quaternion; pitch in [−π/2, π/2].
pub fn rpy_of_quat(q: [f64; 4]) -> [f64; 3] {
    let (yaw, pitch, roll) = quat(q).to_euler(EulerRot::ZYX);
    [roll, pitch, yaw]
}

/// Spherical interpolation of unit quaternions along the short arc.
pub fn slerp(a: [f64; 4], b: [f64; 4], t: f64) -> [f64; 4] {
    wxyz(quat(a).slerp(quat(b), t))
}

/// The rotation matrix of a unit quaternion.
#[inline]
pub fn mat_of_quat(q: [f64; 4]) -> Mat3 {
    rows(DMat3::from_quat(quat(q)))
}

/// The unit quaternion (`w ≥ 0`) of a rotation matrix.
pub fn quat_of_mat(r: &Mat3) -> [f64; 4] {
    quat_normalize(wxyz(DQuat::from_mat3(&mat(r))))
}

/// The rotation of roll, pitch, yaw (rad).
pub fn mat_of_rpy(rpy: [f64; 3]) -> Mat3 {
    rows(DMat3::from_euler(EulerRot::ZYX, rpy[2], rpy[1], rpy[0]))
}

/// Roll, pitch, yaw (rad) of a rotation matrix.
pub fn rpy_of_mat(r: &Mat3) -> [f64; 3] {
    let (yaw, pitch, roll) = mat(r).to_euler(EulerRot::ZYX);
    [roll, pitch, yaw]
}

/// `a · b`.
#[inline]
pub fn mat_mul(a: &Mat3, b: &Mat3) -> Mat3 {
    rows(mat(a) * mat(b))
}

/// `r · v`.
#[inline]
pub fn mat_apply(r: &Mat3, v: [f64; 3]) -> [f64; 3] {
    (mat(r) * DVec3::from(v)).into()
}

/// `rᵀ`, the inverse of a rotation.
#[inline]
pub fn transpose(r: &Mat3) -> Mat3 {
    [
        [r[0][0], r[1][0], r[2][0]],
        [r[0][1], r[1][1], r[2][1]],
        [r[0][2], r[1][2], r[2][2]],
    ]
}

/// The exponential map: rotation vector (axis · angle) to rotation.
pub fn exp(w: [f64; 3]) -> Mat3 {
    rows(DMat3::from_quat(DQuat::from_scaled_axis(DVec3::from(w))))
}

/// The left Jacobian of the rotation group at `w`: how a rotation vector's increment moves the
/// translations carried with it (`exp` of SE(3) and its extensions is `[exp(w), J(w)·t]`).
pub fn so3_left_jacobian(w: [f64; 3]) -> Mat3 {
    let w = DVec3::from(w);
    let angle = w.length();
    let k = DMat3::from_cols(
        DVec3::new(0.0, w.z, -w.y),
        DVec3::new(-w.z, 0.0, w.x),
        DVec3::new(w.y, -w.x, 0.0),
    );
    // Series below a small angle: (1 − cos φ)/φ² → ½, (φ − sin φ)/φ³ → ⅙.
    let (a, b) = if angle < 1e-6 {
        (0.5, 1.0 / 6.0)
    } else {
        (
            (1.0 - angle.cos()) / angle.powi(2),
            (angle - angle.sin()) / angle.powi(3),
        )
    };
    rows(DMat3::IDENTITY + k * a + k * k * b)
}

/// The logarithm: rotation to rotation vector, angle in [0, π] (the short way round).
pub fn log(r: &Mat3) -> [f64; 3] {
    quat_log(quat_of_mat(r))
}

/// The rotation vector (axis · angle, angle in [0, π]) of a unit quaternion. The half-angle from
/// atan2 keeps tiny rotations exact (glam's axis-angle snaps those to zero).
pub fn quat_log(q: [f64; 4]) -> [f64; 3] {
    let q = quat(quat_normalize(q));
    let v = q.xyz();
    let s = v.length();
    if s < 1e-15 {
        return [0.0; 3];
    }
    (v * (2.0 * s.atan2(q.w) / s)).into()
}

/// The heading (yaw about +z) of a rotation's x axis, rad.
#[inline]
pub fn heading(r: &Mat3) -> f64 {
    r[1][0].atan2(r[0][0])
}

/// The heading (yaw about +z) of a quaternion's x axis, rad.
pub fn heading_of_quat(q: [f64; 4]) -> f64 {
    let x = quat(q) * DVec3::X;
    x.y.atan2(x.x)
}

/// The rotation about +z by `yaw`.
pub fn yaw(yaw: f64) -> Mat3 {
    rows(DMat3::from_rotation_z(yaw))
}

/// `a + b`.
#[inline]
pub fn add(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    (DVec3::from(a) + DVec3::from(b)).into()
}

/// `a − b`.
#[inline]
pub fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    (DVec3::from(a) - DVec3::from(b)).into()
}

/// `k · a`.
#[inline]
pub fn scale(a: [f64; 3], k: f64) -> [f64; 3] {
    (DVec3::from(a) * k).into()
}

/// `a · b`.
#[inline]
pub fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    DVec3::from(a).dot(DVec3::from(b))
}

/// `a × b`.
#[inline]
pub fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    DVec3::from(a).cross(DVec3::from(b)).into()
}

/// `|a|`.
#[inline]
pub fn norm(a: [f64; 3]) -> f64 {
    DVec3::from(a).length()
}

/// `a / |a|`.
#[inline]
pub fn unit(a: [f64; 3]) -> [f64; 3] {
    DVec3::from(a).normalize().into()
}

/// Angle between two directions, rad.
pub fn angle_between(a: [f64; 3], b: [f64; 3]) -> f64 {
    DVec3::from(a).angle_between(DVec3::from(b))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn close(a: &Mat3, b: &Mat3) -> bool {
        (0..3).all(|i| (0..3).all(|j| (a[i][j] - b[i][j]).abs() < 1e-9))
    }

    #[test]
    fn exp_log_matrices_and_quaternions_agree() {
        for w in [
            [0.3, -0.2, 0.9],
            [0.0, 0.0, 3.0],
            [1e-9, 0.0, 0.0],
            [-2.0, 1.0, 0.5],
        ] {
            let r = exp(w);
            assert!(close(&r, &exp(log(&r))), "{w:?}");
            assert!(close(&r, &mat_of_quat(quat_of_mat(&r))), "{w:?}");
        }
        assert!((heading(&yaw(1.2)) - 1.2).abs() < 1e-12);
        // The left Jacobian is the derivative of exp: exp(w + ε) ≈ exp(J(w)·ε) · exp(w).
        let (w, e) = ([0.4, -0.7, 0.2], [1e-6, 2e-6, -1e-6]);
        let moved = mat_mul(&exp(mat_apply(&so3_left_jacobian(w), e)), &exp(w));
        assert!(
            (0..3).all(|i| (0..3).all(|j| (moved[i][j] - exp(add(w, e))[i][j]).abs() < 1e-11)),
            "{moved:?}"
        );
        assert!((heading_of_quat(quat_of_mat(&yaw(-2.5))) + 2.5).abs() < 1e-12);
        // A quarter turn about z takes x to y; rows are rows.
        let r = exp([0.0, 0.0, std::f64::consts::FRAC_PI_2]);
        assert!((mat_apply(&r, [1.0, 0.0, 0.0])[1] - 1.0).abs() < 1e-12);
        assert!((r[1][0] - 1.0).abs() < 1e-12);
    }

    #[test]
    fn rpy_is_z_y_x_intrinsic_and_round_trips() {
        let rpy = [0.3, -0.2, 1.1];
        let q = quat_of_rpy(rpy[0], rpy[1], rpy[2]);
        let by_hand = mat_mul(
            &mat_mul(&exp([0.0, 0.0, rpy[2]]), &exp([0.0, rpy[1], 0.0])),
            &exp([rpy[0], 0.0, 0.0]),
        );
        assert!(close(&mat_of_quat(q), &by_hand));
        assert!(close(&mat_of_rpy(rpy), &by_hand));
        for (a, b) in rpy_of_quat(q).iter().zip(rpy) {
            assert!((a - b).abs() < 1e-12);
        }
        for (a, b) in rpy_of_mat(&by_hand).iter().zip(rpy) {
            assert!((a - b).abs() < 1e-12);
        }
        let v = [0.2, -1.0, 0.4];
        let (a, b) = (quat_rotate(q, v), mat_apply(&by_hand, v));
        assert!((0..3).all(|i| (a[i] - b[i]).abs() < 1e-12));
    }

    #[test]
    fn slerp_halfway_between_identity_and_a_quarter_turn_is_an_eighth_turn() {
        let h = std::f64::consts::FRAC_1_SQRT_2;
        let q = slerp(QUAT_IDENTITY, [h, 0.0, 0.0, h], 0.5);
        let angle = 2.0 * q[3].atan2(q[0]);
        assert!((angle - std::f64::consts::FRAC_PI_4).abs() < 1e-12, "{q:?}");
        // The short arc: −b is the same rotation as b.
        let q = slerp(QUAT_IDENTITY, [-h, 0.0, 0.0, -h], 0.5);
        assert!(
            (2.0 * q[3].atan2(q[0]).abs() - std::f64::consts::FRAC_PI_4).abs() < 1e-12,
            "{q:?}"
        );
    }

    #[test]
    fn hamilton_product_composes_rotations() {
        let (a, b) = (quat_of_rpy(0.1, 0.2, 0.3), quat_of_rpy(-0.4, 0.5, 0.6));
        let v = [1.0, 2.0, 3.0];
        let (x, y) = (quat_rotate(quat_mul(a, b), v), quat_rotate(a, quat_rotate(b, v)));
        assert!((0..3).all(|i| (x[i] - y[i]).abs() < 1e-12));
        let n = quat_normalize([-2.0, 0.0, 0.0, 0.0]);
        assert_eq!(n, QUAT_IDENTITY);
    }
}
