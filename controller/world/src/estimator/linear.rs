//! The linear Kalman filter of legged robots (Bloesch et al., "State Estimation for Legged
//! Robots", RSS 2012, in its linear form): base position and velocity, accelerometer bias and
//! the feet's positions in the world, the orientation taken from the IMU. Linear because the
//! IMU's orientation is given, not estimated.

use robots::spatial::{self, Mat3};

use super::kalman::Covariance;
use super::{EstimatorConfig, Filter, MAX_FEET};

const P: usize = 0;
const V: usize = 3;
const B: usize = 6;
const FEET: usize = 9;

#[derive(Debug, Clone)]
pub(super) struct LinearFilter {
    config: EstimatorConfig,
    feet: usize,
    x: Vec<f64>,
    cov: Covariance,
    /// The IMU's orientation (base to world).
    r: Mat3,
    gravity: [f64; 3],
    fault: bool,
}

impl LinearFilter {
    pub(super) fn new(config: EstimatorConfig, feet: usize, gravity: [f64; 3]) -> Self {
        let n = FEET + 3 * feet;
        Self {
            config,
            feet,
            x: vec![0.0; n],
            cov: Covariance::new(n),
            r: spatial::IDENTITY,
            gravity,
            fault: false,
        }
    }

    fn measure(&mut self, h: &[(usize, f64)], y: f64, r: f64) {
        let innovation = y - Covariance::predicted(h, &self.x);
        self.fault |= !self.cov.update(h, innovation, r, &mut self.x);
    }
}

impl Filter for LinearFilter {
    fn rotation(&self) -> Mat3 {
        self.r
    }

    fn set_attitude(&mut self, imu: &Mat3) {
        self.r = *imu;
    }

    fn start(&mut self, imu: &Mat3, base: [f64; 3], feet_body: &[[f64; 3]]) {
        self.r = *imu;
        self.x.fill(0.0);
        self.x[P..P + 3].copy_from_slice(&base);
        for (f, body) in feet_body.iter().enumerate().take(self.feet) {
            let w = spatial::add(base, spatial::mat_apply(imu, *body));
            self.x[FEET + 3 * f..FEET + 3 * f + 3].copy_from_slice(&w);
        }
        self.cov.reset(|i| match i {
            _ if i < V => 1e-6,
            _ if i < B => 1e-4,
            _ if i < FEET => 0.3f64.powi(2),
            _ => 1e-4,
        });
        self.fault = false;
    }

    fn propagate(&mut self, _gyro: [f64; 3], accel: [f64; 3], dt: f64, foot_walk: &[f64; MAX_FEET]) {
        let r = self.r;
        let bias = [self.x[B], self.x[B + 1], self.x[B + 2]];
        let a = spatial::add(spatial::mat_apply(&r, spatial::sub(accel, bias)), self.gravity);
        for (k, ak) in a.iter().enumerate() {
            self.x[P + k] += self.x[V + k] * dt + 0.5 * ak * dt * dt;
            self.x[V + k] += ak * dt;
        }
        // P ← F P Fᵀ + Q. F is the identity but for three blocks (p/v: dt·I, p/b: −½dt²·R,
        // v/b: −dt·R), so only the rows, then the columns, of p and v change.
        let n = self.cov.n;
        let p = &mut self.cov.p;
        let (h, q) = (dt, -0.5 * dt * dt);
        for j in 0..n {
            let bias_r: [f64; 3] =
                std::array::from_fn(|k| (0..3).map(|m| r[k][m] * p[(B + m) * n + j]).sum());
            for (k, br) in bias_r.iter().enumerate() {
                let (pk, vk) = (p[(P + k) * n + j], p[(V + k) * n + j]);
                p[(P + k) * n + j] = pk + h * vk + q * br;
                p[(V + k) * n + j] = vk - dt * br;
            }
        }
        for i in 0..n {
            let row = i * n;
            let bias_r: [f64; 3] = std::array::from_fn(|k| (0..3).map(|m| r[k][m] * p[row + B + m]).sum());
            for (k, br) in bias_r.iter().enumerate() {
                let (pk, vk) = (p[row + P + k], p[row + V + k]);
                p[row + P + k] = pk + h * vk + q * br;
                p[row + V + k] = vk - dt * br;
            }
        }
        let c = &self.config;
        for k in 0..3 {
            self.cov.add_variance(V + k, c.accel_noise.powi(2) * dt);
            self.cov
                .add_variance(P + k, c.accel_noise.powi(2) * dt.powi(3) / 3.0);
            self.cov.add_variance(B + k, c.bias_walk.powi(2) * dt);
        }
        for (foot, walk) in foot_walk.iter().enumerate().take(self.feet) {
            for k in 0..3 {
                self.cov.add_variance(FEET + 3 * foot + k, walk * walk * dt);
            }
        }
    }

    fn begin(&mut self) {}

    fn foot(&mut self, f: usize, body: [f64; 3], variance: f64) {
        let world = spatial::mat_apply(&self.r, body);
        for (k, y) in world.into_iter().enumerate() {
            self.measure(&[(FEET + 3 * f + k, 1.0), (P + k, -1.0)], y, variance);
        }
    }

    fn base_velocity(&mut self, body: [f64; 3], variance: f64) {
        let world = spatial::mat_apply(&self.r, body);
        for (k, y) in world.into_iter().enumerate() {
            self.measure(&[(V + k, 1.0)], y, variance);
        }
    }

    fn floor(&mut self, f: usize, height: f64, variance: f64) {
        self.measure(&[(FEET + 3 * f + 2, 1.0)], height, variance);
    }

    fn finish(&mut self) {
        self.cov.symmetrise();
    }

    fn release_foot(&mut self, f: usize, variance: f64) {
        self.cov.forget(FEET + 3 * f, variance);
    }

    fn position(&self) -> [f64; 3] {
        [self.x[P], self.x[P + 1], self.x[P + 2]]
    }

    fn velocity(&self) -> [f64; 3] {
        [self.x[V], self.x[V + 1], self.x[V + 2]]
    }

    fn position_std(&self) -> [f64; 3] {
        std::array::from_fn(|k| self.cov.std(P + k))
    }

    fn velocity_std(&self) -> [f64; 3] {
        std::array::from_fn(|k| self.cov.std(V + k))
    }

    fn accel_bias(&self) -> [f64; 3] {
        [self.x[B], self.x[B + 1], self.x[B + 2]]
    }

    fn take_fault(&mut self) -> bool {
        let fault = self.fault || !(self.x.iter().all(|v| v.is_finite()) && self.cov.is_finite());
        self.fault = false;
        fault
    }
}
