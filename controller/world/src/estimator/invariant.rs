//! The contact-aided invariant extended Kalman filter (Hartley et al., "Contact-aided invariant
//! extended Kalman filtering for robot state estimation", IJRR 2020), in its right-invariant form
//! with IMU biases: orientation, velocity, position and the feet live on the group SE₂₊ₖ(3), so
//! the error of the legs' measurements (a foot relative to the base, the base velocity from a
//! standing foot) does not depend on the estimate — the linearisation that the linear filter's
//! given orientation hides is exact here, and orientation is estimated (gyro propagated, tilt
//! corrected through the legs and gravity) rather than taken from the IMU's own fusion.
//!
//! Error convention: the truth is `exp(ξ) · X̂`; a correction `δ` moves the estimate to
//! `exp(δ) · X̂`. State order in `ξ`: rotation, velocity, position, feet, gyro bias, accel bias.

use glam::{DMat3, DVec3};
use robots::spatial::{self, Mat3};

use super::kalman::Covariance;
use super::{EstimatorConfig, Filter, MAX_FEET};

const TH: usize = 0;
const V: usize = 3;
const P: usize = 6;
const FEET: usize = 9;

#[derive(Debug, Clone)]
pub(super) struct InvariantFilter {
    config: EstimatorConfig,
    feet: usize,
    /// Where the gyro and accelerometer biases sit in the error state.
    bg: usize,
    ba: usize,
    r: DMat3,
    v: DVec3,
    p: DVec3,
    d: [DVec3; MAX_FEET],
    gyro_bias: DVec3,
    accel_bias: DVec3,
    gravity: DVec3,
    /// The IMU's own orientation this tick.
    imu: DMat3,
    cov: Covariance,
    /// The correction this tick's measurements add up to, applied at `finish`.
    delta: Vec<f64>,
    fault: bool,
}

fn v3(s: &[f64]) -> DVec3 {
    DVec3::new(s[0], s[1], s[2])
}

fn skew(a: DVec3) -> DMat3 {
    DMat3::from_cols(
        DVec3::new(0.0, a.z, -a.y),
        DVec3::new(-a.z, 0.0, a.x),
        DVec3::new(a.y, -a.x, 0.0),
    )
}

impl InvariantFilter {
    pub(super) fn new(config: EstimatorConfig, feet: usize, gravity: [f64; 3]) -> Self {
        let bg = FEET + 3 * feet;
        let n = bg + 6;
        Self {
            config,
            feet,
            bg,
            ba: bg + 3,
            r: DMat3::IDENTITY,
            v: DVec3::ZERO,
            p: DVec3::ZERO,
            d: [DVec3::ZERO; MAX_FEET],
            gyro_bias: DVec3::ZERO,
            accel_bias: DVec3::ZERO,
            gravity: DVec3::from(gravity),
            imu: DMat3::IDENTITY,
            cov: Covariance::new(n),
            delta: vec![0.0; n],
            fault: false,
        }
    }

    fn measure(&mut self, h: &[(usize, f64)], innovation: f64, r: f64) {
        let innovation = innovation - Covariance::predicted(h, &self.delta);
        self.fault |= !self.cov.update(h, innovation, r, &mut self.delta);
    }

    /// `P ← Φ P Φᵀ` with `Φ = I + A·dt`, `A` the error's dynamics: rotation error feeds the
    /// velocity through gravity, velocity the position, and the gyro bias every block through
    /// the rotation (each by `−[x]×·R`), the accelerometer bias the velocity (`−R`). `A` is
    /// sparse, so Φ is applied to the columns, then to the rows, in place.
    fn propagate_covariance(&mut self, dt: f64) {
        let n = self.cov.n;
        let r = self.r;
        let g = skew(self.gravity);
        let (vr, pr) = (skew(self.v) * r, skew(self.p) * r);
        let dr: [DMat3; MAX_FEET] = std::array::from_fn(|f| skew(self.d[f]) * r);
        let (bg, ba, feet) = (self.bg, self.ba, self.feet);
        let p = &mut self.cov.p;
        // Pass 0 works on columns (element `i·n + j` is row `i` of column `j`), pass 1 on rows.
        for pass in 0..2 {
            for j in 0..n {
                let at = |i: usize| if pass == 0 { i * n + j } else { j * n + i };
                let get =
                    |p: &[f64], first: usize| DVec3::new(p[at(first)], p[at(first + 1)], p[at(first + 2)]);
                let (th, v, pos, b_g, b_a) = (get(p, TH), get(p, V), get(p, P), get(p, bg), get(p, ba));
                let set = |p: &mut [f64], first: usize, x: DVec3| {
                    p[at(first)] = x.x;
                    p[at(first + 1)] = x.y;
                    p[at(first + 2)] = x.z;
                };
                set(p, TH, th - dt * (r * b_g));
                set(p, V, v + dt * (g * th - vr * b_g - r * b_a));
                set(p, P, pos + dt * (v - pr * b_g));
                for (f, dr) in dr.iter().enumerate().take(feet) {
                    let d = get(p, FEET + 3 * f);
                    set(p, FEET + 3 * f, d - dt * (*dr * b_g));
                }
            }
        }
    }

    /// The process noise: the gyro's noise turns every block about the origin (block `(i, j)` is
    /// `σ²·Sᵢ·Sⱼᵀ` with `S` the identity for the rotation, `[x]×` for velocity, position and
    /// feet), the accelerometer's moves the velocity, slip the feet, the biases walk.
    fn add_process_noise(&mut self, dt: f64, foot_walk: &[f64; MAX_FEET]) {
        let c = &self.config;
        let blocks = 3 + self.feet;
        let s = |b: usize| match b {
            0 => DMat3::IDENTITY,
            1 => skew(self.v),
            2 => skew(self.p),
            f => skew(self.d[f - 3]),
        };
        let gyro = c.gyro_noise.powi(2) * dt;
        for bi in 0..blocks {
            let si = s(bi);
            for bj in 0..blocks {
                let q = si * s(bj).transpose() * gyro;
                for (k, col) in [q.x_axis, q.y_axis, q.z_axis].iter().enumerate() {
                    for (m, value) in col.to_array().iter().enumerate() {
                        let (row, column) = (3 * bi + m, 3 * bj + k);
                        self.cov.p[row * self.cov.n + column] += value;
                    }
                }
            }
        }
        for k in 0..3 {
            self.cov.add_variance(V + k, c.accel_noise.powi(2) * dt);
            self.cov.add_variance(self.bg + k, c.gyro_bias_walk.powi(2) * dt);
            self.cov.add_variance(self.ba + k, c.bias_walk.powi(2) * dt);
        }
        for (f, walk) in foot_walk.iter().enumerate().take(self.feet) {
            for k in 0..3 {
                self.cov.add_variance(FEET + 3 * f + k, walk * walk * dt);
            }
        }
    }
}

impl Filter for InvariantFilter {
    fn rotation(&self) -> Mat3 {
        spatial::rows(self.r)
    }

    fn set_attitude(&mut self, imu: &Mat3) {
        self.imu = spatial::mat(imu);
    }

    fn start(&mut self, imu: &Mat3, base: [f64; 3], feet_body: &[[f64; 3]]) {
        self.r = spatial::mat(imu);
        self.v = DVec3::ZERO;
        self.p = DVec3::from(base);
        for (f, body) in feet_body.iter().enumerate().take(self.feet) {
            self.d[f] = self.p + self.r * DVec3::from(*body);
        }
        self.gyro_bias = DVec3::ZERO;
        self.accel_bias = DVec3::ZERO;
        let (bg, ba) = (self.bg, self.ba);
        // Tilt from the IMU's own fusion (a tenth of a degree or so); the heading defines the
        // world, so it starts certain.
        self.cov.reset(|i| match i {
            TH | 1 => 0.002f64.powi(2),
            2 => 1e-8,
            _ if i < P => 1e-4,
            _ if i < FEET => 1e-6,
            _ if i < bg => 1e-4,
            _ if i < ba => 0.01f64.powi(2),
            _ => 0.3f64.powi(2),
        });
        self.delta.fill(0.0);
        self.fault = false;
    }

    fn propagate(&mut self, gyro: [f64; 3], accel: [f64; 3], dt: f64, foot_walk: &[f64; MAX_FEET]) {
        self.propagate_covariance(dt);
        self.add_process_noise(dt, foot_walk);
        let omega = DVec3::from(gyro) - self.gyro_bias;
        let a = self.r * (DVec3::from(accel) - self.accel_bias) + self.gravity;
        self.p += self.v * dt + 0.5 * a * dt * dt;
        self.v += a * dt;
        self.r *= spatial::mat(&spatial::exp((omega * dt).into()));
    }

    fn begin(&mut self) {
        self.delta.fill(0.0);
    }

    fn foot(&mut self, f: usize, body: [f64; 3], variance: f64) {
        let z = self.r * DVec3::from(body) - (self.d[f] - self.p);
        for k in 0..3 {
            self.measure(&[(FEET + 3 * f + k, 1.0), (P + k, -1.0)], z[k], variance);
        }
    }

    fn base_velocity(&mut self, body: [f64; 3], variance: f64) {
        let z = self.r * DVec3::from(body) - self.v;
        for k in 0..3 {
            self.measure(&[(V + k, 1.0)], z[k], variance);
        }
    }

    fn floor(&mut self, f: usize, height: f64, variance: f64) {
        // A tilt of the world about its origin moves a far foot's height: d_z's error is
        // θₓ·d_y − θ_y·dₓ + δd_z.
        let d = self.d[f];
        self.measure(
            &[(TH, d.y), (TH + 1, -d.x), (FEET + 3 * f + 2, 1.0)],
            height - d.z,
            variance,
        );
    }

    fn finish(&mut self) {
        // The IMU's own orientation is exp(θ)·R̂, the error θ in the world's axes.
        let noise = self.config.imu_attitude_noise;
        if noise > 0.0 {
            let theta = spatial::log(&spatial::rows(self.imu * self.r.transpose()));
            for (k, angle) in theta.into_iter().enumerate() {
                self.measure(&[(TH + k, 1.0)], angle, noise * noise);
            }
        }
        let x = &self.delta;
        let theta = v3(&x[TH..]);
        let turn = spatial::mat(&spatial::exp(theta.into()));
        let jacobian = spatial::mat(&spatial::so3_left_jacobian(theta.into()));
        self.r = turn * self.r;
        self.v = turn * self.v + jacobian * v3(&x[V..]);
        self.p = turn * self.p + jacobian * v3(&x[P..]);
        for f in 0..self.feet {
            self.d[f] = turn * self.d[f] + jacobian * v3(&x[FEET + 3 * f..]);
        }
        self.gyro_bias += v3(&x[self.bg..]);
        self.accel_bias += v3(&x[self.ba..]);
        // Keep R a rotation against rounding.
        self.r = spatial::mat(&spatial::mat_of_quat(spatial::quat_of_mat(&spatial::rows(
            self.r,
        ))));
        self.delta.fill(0.0);
        self.cov.symmetrise();
    }

    fn release_foot(&mut self, f: usize, variance: f64) {
        self.cov.forget(FEET + 3 * f, variance);
    }

    fn position(&self) -> [f64; 3] {
        (self.p + v3(&self.delta[P..])).into()
    }

    fn velocity(&self) -> [f64; 3] {
        (self.v + v3(&self.delta[V..])).into()
    }

    fn position_std(&self) -> [f64; 3] {
        std::array::from_fn(|k| self.cov.std(P + k))
    }

    fn velocity_std(&self) -> [f64; 3] {
        std::array::from_fn(|k| self.cov.std(V + k))
    }

    fn accel_bias(&self) -> [f64; 3] {
        self.accel_bias.into()
    }

    fn take_fault(&mut self) -> bool {
        let finite = [self.v, self.p, self.gyro_bias, self.accel_bias]
            .iter()
            .chain(&self.d)
            .all(|x| x.is_finite())
            && self.r.is_finite()
            && self.cov.is_finite();
        let fault = self.fault || !finite;
        self.fault = false;
        fault
    }
}
