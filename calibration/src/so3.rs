//! Rotations and vectors in 3D, as plain arrays (rows for matrices, `[w, x, y, z]` quaternions):
//! the few operations calibration and retargeting need.

/// A 3×3 rotation, rows.
pub type Mat3 = [[f64; 3]; 3];

/// The identity rotation.
pub const IDENTITY: Mat3 = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];

/// `a · b`.
pub fn mul(a: &Mat3, b: &Mat3) -> Mat3 {
    [0, 1, 2].map(|i| [0, 1, 2].map(|j| (0..3).map(|k| a[i][k] * b[k][j]).sum()))
}

/// `r · v`.
pub fn apply(r: &Mat3, v: [f64; 3]) -> [f64; 3] {
    [0, 1, 2].map(|i| (0..3).map(|k| r[i][k] * v[k]).sum())
}

/// `rᵀ`.
pub fn transpose(r: &Mat3) -> Mat3 {
    [0, 1, 2].map(|i| [0, 1, 2].map(|j| r[j][i]))
}

/// `a × b`.
pub fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

/// `a + b`.
pub fn add(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}

/// `a − b`.
pub fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

/// `k · a`.
pub fn scale(a: [f64; 3], k: f64) -> [f64; 3] {
    [a[0] * k, a[1] * k, a[2] * k]
}

/// `a · b`.
pub fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// |a|.
pub fn norm(a: [f64; 3]) -> f64 {
    dot(a, a).sqrt()
}

/// `a` scaled to length 1.
pub fn unit(a: [f64; 3]) -> [f64; 3] {
    scale(a, 1.0 / norm(a))
}

/// The exponential map: rotation vector (axis · angle) to rotation.
pub fn exp(w: [f64; 3]) -> Mat3 {
    let angle = norm(w);
    if angle < 1e-12 {
        return IDENTITY;
    }
    let [x, y, z] = scale(w, 1.0 / angle);
    let (s, c) = angle.sin_cos();
    let t = 1.0 - c;
    [
        [t * x * x + c, t * x * y - s * z, t * x * z + s * y],
        [t * x * y + s * z, t * y * y + c, t * y * z - s * x],
        [t * x * z - s * y, t * y * z + s * x, t * z * z + c],
    ]
}

/// The logarithm: rotation to rotation vector (angle ≤ π).
pub fn log(r: &Mat3) -> [f64; 3] {
    let q = quat_of(r);
    let v = [q[1], q[2], q[3]];
    let s = norm(v);
    if s < 1e-12 {
        return [0.0; 3];
    }
    // quat_of keeps w ≥ 0: the short way round.
    scale(v, 2.0 * s.atan2(q[0]) / s)
}

/// The rotation of a unit quaternion `[w, x, y, z]`.
pub fn mat_of_quat(q: [f64; 4]) -> Mat3 {
    let [w, x, y, z] = q;
    [
        [
            1.0 - 2.0 * (y * y + z * z),
            2.0 * (x * y - w * z),
            2.0 * (x * z + w * y),
        ],
        [
            2.0 * (x * y + w * z),
            1.0 - 2.0 * (x * x + z * z),
            2.0 * (y * z - w * x),
        ],
        [
            2.0 * (x * z - w * y),
            2.0 * (y * z + w * x),
            1.0 - 2.0 * (x * x + y * y),
        ],
    ]
}

/// The unit quaternion `[w, x, y, z]` (w ≥ 0) of a rotation.
pub fn quat_of(r: &Mat3) -> [f64; 4] {
    let trace = r[0][0] + r[1][1] + r[2][2];
    let q = if trace > 0.0 {
        let s = (trace + 1.0).sqrt() * 2.0;
        [
            0.25 * s,
            (r[2][1] - r[1][2]) / s,
            (r[0][2] - r[2][0]) / s,
            (r[1][0] - r[0][1]) / s,
        ]
    } else if r[0][0] > r[1][1] && r[0][0] > r[2][2] {
        let s = (1.0 + r[0][0] - r[1][1] - r[2][2]).sqrt() * 2.0;
        [
            (r[2][1] - r[1][2]) / s,
            0.25 * s,
            (r[0][1] + r[1][0]) / s,
            (r[0][2] + r[2][0]) / s,
        ]
    } else if r[1][1] > r[2][2] {
        let s = (1.0 + r[1][1] - r[0][0] - r[2][2]).sqrt() * 2.0;
        [
            (r[0][2] - r[2][0]) / s,
            (r[0][1] + r[1][0]) / s,
            0.25 * s,
            (r[1][2] + r[2][1]) / s,
        ]
    } else {
        let s = (1.0 + r[2][2] - r[0][0] - r[1][1]).sqrt() * 2.0;
        [
            (r[1][0] - r[0][1]) / s,
            (r[0][2] + r[2][0]) / s,
            (r[1][2] + r[2][1]) / s,
            0.25 * s,
        ]
    };
    let n = (q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]).sqrt();
    let sign = if q[0] < 0.0 { -1.0 } else { 1.0 };
    q.map(|c| sign * c / n)
}

/// The heading (yaw about +Z) of a rotation's x axis, rad.
pub fn heading(r: &Mat3) -> f64 {
    r[1][0].atan2(r[0][0])
}

/// The rotation about +Z by `yaw`.
pub fn yaw(yaw: f64) -> Mat3 {
    exp([0.0, 0.0, yaw])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn exp_log_and_quaternions_agree() {
        for w in [
            [0.3, -0.2, 0.9],
            [0.0, 0.0, 3.0],
            [1e-9, 0.0, 0.0],
            [-2.0, 1.0, 0.5],
        ] {
            let r = exp(w);
            let back = exp(log(&r));
            let err: f64 = (0..3)
                .map(|i| (0..3).map(|j| (r[i][j] - back[i][j]).abs()).sum::<f64>())
                .sum();
            assert!(err < 1e-9, "{w:?}");
            let q = mat_of_quat(quat_of(&r));
            let err: f64 = (0..3)
                .map(|i| (0..3).map(|j| (r[i][j] - q[i][j]).abs()).sum::<f64>())
                .sum();
            assert!(err < 1e-9, "{w:?}");
        }
        assert!((heading(&yaw(1.2)) - 1.2).abs() < 1e-12);
        // A quarter turn about z takes x to y.
        let v = apply(&exp([0.0, 0.0, std::f64::consts::FRAC_PI_2]), [1.0, 0.0, 0.0]);
        assert!((v[1] - 1.0).abs() < 1e-12);
    }
}
