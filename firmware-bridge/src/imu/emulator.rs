//! An emulated WIT-protocol AHRS: truth from the simulator in, a serial byte stream out, with
//! white noise, a constant per-unit bias, quantisation and the configured output rate.

use std::time::Duration;

use super::ImuProtocol;
use super::wit::{self, ImuSample, PACKET_LEN};
use crate::time::{SimInstant, SimRng};

/// Noise and rate of the emulated part.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ImuEmulatorConfig {
    /// Output rate, Hz.
    pub rate_hz: f64,
    /// Gyro white noise, rad/s (1σ per sample).
    pub gyro_noise: f64,
    /// Gyro bias bound, rad/s (each unit draws a constant bias within ±this).
    pub gyro_bias: f64,
    /// Accelerometer white noise, m/s² (1σ).
    pub accel_noise: f64,
    /// Accelerometer bias bound, m/s².
    pub accel_bias: f64,
    /// Orientation noise, rad (1σ, small-angle about each axis).
    pub attitude_noise: f64,
    /// Gyro bias random walk, rad/s per √s (0: a constant bias). Without a magnetometer the
    /// AHRS integrates the z bias into its heading, which drifts with it.
    pub gyro_bias_walk: f64,
    /// Accelerometer bias random walk, m/s² per √s.
    pub accel_bias_walk: f64,
}

impl Default for ImuEmulatorConfig {
    /// Figures of a WT901-class MEMS part: ~0.05 °/s gyro noise at 200 Hz, ~0.3 °/s bias,
    /// ~0.01 g accel noise, ~0.05 g bias, ~0.1° attitude noise.
    fn default() -> Self {
        Self {
            rate_hz: 200.0,
            gyro_noise: 0.05_f64.to_radians(),
            gyro_bias: 0.3_f64.to_radians(),
            accel_noise: 0.01 * wit::G,
            accel_bias: 0.05 * wit::G,
            attitude_noise: 0.1_f64.to_radians(),
            gyro_bias_walk: 0.0,
            accel_bias_walk: 0.0,
        }
    }
}

/// What the emulated IMU measures, in its own axes.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct ImuTruth {
    /// Angular velocity, rad/s.
    pub gyro: [f64; 3],
    /// Specific force, m/s².
    pub accel: [f64; 3],
    /// Orientation `[w, x, y, z]`, sensor to world.
    pub quat: [f64; 4],
}

/// Bytes the longest output cycle of any protocol takes.
pub const MAX_CYCLE_BYTES: usize = 4 * PACKET_LEN;

/// One emulated IMU, speaking `protocol`.
#[derive(Debug, Clone)]
pub struct WitImuEmulator {
    config: ImuEmulatorConfig,
    protocol: ImuProtocol,
    /// The RVC frame index.
    index: u8,
    rng: SimRng,
    gyro_bias: [f64; 3],
    accel_bias: [f64; 3],
    /// Heading error the drifting z bias has built up, rad.
    yaw_drift: f64,
    initial_gyro_z: f64,
    next_output: SimInstant,
}

impl WitImuEmulator {
    /// A unit whose biases are drawn from `seed`, speaking WIT.
    pub fn new(config: ImuEmulatorConfig, seed: u64) -> Self {
        Self::speaking(ImuProtocol::Wit, config, seed)
    }

    /// A unit speaking `protocol` (a BNO08x in RVC mode streams at its fixed 100 Hz).
    pub fn speaking(protocol: ImuProtocol, config: ImuEmulatorConfig, seed: u64) -> Self {
        let config = match protocol {
            ImuProtocol::Wit => config,
            // The fused rotation vector moves smoothly sample to sample (its error is a slow
            // drift, not white noise): a hundredth of a degree, its output step.
            ImuProtocol::Bno08xRvc => ImuEmulatorConfig {
                rate_hz: super::rvc::RATE_HZ,
                attitude_noise: config.attitude_noise.min(0.01_f64.to_radians()),
                ..config
            },
            // The BNO055's fusion output: 100 Hz, attitude smooth at its 1/16° step.
            ImuProtocol::Bno055 => ImuEmulatorConfig {
                rate_hz: super::bno055::RATE_HZ,
                attitude_noise: config.attitude_noise.min(0.03_f64.to_radians()),
                ..config
            },
        };
        let mut rng = SimRng::new(seed);
        let mut draw = |bound: f64| [0; 3].map(|_| (2.0 * rng.next_f64() - 1.0) * bound);
        let gyro_bias = draw(config.gyro_bias);
        let accel_bias = draw(config.accel_bias);
        Self {
            config,
            protocol,
            index: 0,
            rng,
            gyro_bias,
            accel_bias,
            yaw_drift: 0.0,
            initial_gyro_z: gyro_bias[2],
            next_output: SimInstant::ZERO,
        }
    }

    /// The output period.
    pub fn period(&self) -> Duration {
        Duration::from_nanos((1e9 / self.config.rate_hz).round() as u64)
    }

    /// When the next output cycle is due.
    pub fn next_output(&self) -> SimInstant {
        self.next_output
    }

    /// The protocol it speaks.
    pub fn protocol(&self) -> ImuProtocol {
        self.protocol
    }

    /// Produces the output cycle due at `now` from `truth` into `out`; returns its length (44
    /// bytes of WIT packets, one 19-byte RVC frame, or nothing for a part the host asks, whose
    /// registers [`Self::sample`] fills).
    pub fn output(&mut self, now: SimInstant, truth: &ImuTruth, out: &mut [u8; MAX_CYCLE_BYTES]) -> usize {
        let sample = self.sample(now, truth);
        match self.protocol {
            ImuProtocol::Wit => {
                wit::encode_cycle(&sample, out);
                out.len()
            }
            ImuProtocol::Bno08xRvc => {
                let [roll, pitch, yaw] = sample.rpy;
                let frame = super::rvc::encode(self.index, [yaw, pitch, roll], sample.accel);
                self.index = self.index.wrapping_add(1);
                out[..frame.len()].copy_from_slice(&frame);
                frame.len()
            }
            ImuProtocol::Bno055 => 0,
        }
    }

    /// The output cycle due at `now` from `truth`, as the part measures it (noise, biases,
    /// drift), in SI units.
    pub fn sample(&mut self, now: SimInstant, truth: &ImuTruth) -> ImuSample {
        self.next_output = self.next_output.max(now) + self.period();
        let c = self.config;
        let dt = self.period().as_secs_f64();
        if c.gyro_bias_walk > 0.0 || c.accel_bias_walk > 0.0 {
            for i in 0..3 {
                self.gyro_bias[i] += c.gyro_bias_walk * dt.sqrt() * self.rng.gaussian();
                self.accel_bias[i] += c.accel_bias_walk * dt.sqrt() * self.rng.gaussian();
            }
            // Relative to the bias it started with: a calibrated heading drifts by the change.
            self.yaw_drift += (self.gyro_bias[2] - self.initial_gyro_z) * dt;
        }
        let mut noise = |sigma: f64| sigma * self.rng.gaussian();
        let gyro = [0, 1, 2].map(|i| truth.gyro[i] + self.gyro_bias[i] + noise(c.gyro_noise));
        let accel = [0, 1, 2].map(|i| truth.accel[i] + self.accel_bias[i] + noise(c.accel_noise));
        let tilt = [0; 3].map(|_| noise(c.attitude_noise) / 2.0);
        let (half_s, half_c) = (0.5 * self.yaw_drift).sin_cos();
        let drifted = [
            half_c * truth.quat[0] - half_s * truth.quat[3],
            half_c * truth.quat[1] - half_s * truth.quat[2],
            half_c * truth.quat[2] + half_s * truth.quat[1],
            half_c * truth.quat[3] + half_s * truth.quat[0],
        ];
        let (quat, rpy) = reported_attitude(drifted, tilt);
        ImuSample {
            accel,
            gyro,
            quat,
            rpy,
            temperature: 35.0,
        }
    }
}

/// The attitude the AHRS reports: `truth` turned by a small error rotation (first-order
/// quaternion `[1, tilt]`), unit length, `w ≥ 0`; and its roll, pitch, yaw (Z-Y-X intrinsic).
fn reported_attitude(truth: [f64; 4], tilt: [f64; 3]) -> ([f64; 4], [f64; 3]) {
    let q = glam::DQuat::from_xyzw(truth[1], truth[2], truth[3], truth[0])
        * glam::DQuat::from_xyzw(tilt[0], tilt[1], tilt[2], 1.0);
    let q = q.normalize();
    let q = if q.w < 0.0 { -q } else { q };
    let (yaw, pitch, roll) = q.to_euler(glam::EulerRot::ZYX);
    ([q.w, q.x, q.y, q.z], [roll, pitch, yaw])
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::imu::wit::WitDecoder;

    #[test]
    fn noise_and_bias_have_the_configured_size_and_the_seed_decides_them() {
        let truth = ImuTruth {
            gyro: [0.0; 3],
            accel: [0.0, 0.0, wit::G],
            quat: [1.0, 0.0, 0.0, 0.0],
        };
        let mut imu = WitImuEmulator::new(ImuEmulatorConfig::default(), 11);
        let mut d = WitDecoder::new();
        let mut gyro_x = Vec::new();
        let mut bytes = [0u8; 44];
        for k in 0..2000u64 {
            imu.output(SimInstant::from_nanos(k * 5_000_000), &truth, &mut bytes);
            d.feed(&bytes, |s| gyro_x.push(s.gyro[0]));
        }
        assert_eq!(gyro_x.len(), 2000);
        let mean = gyro_x.iter().sum::<f64>() / 2000.0;
        let sd = (gyro_x.iter().map(|g| (g - mean).powi(2)).sum::<f64>() / 2000.0).sqrt();
        let c = ImuEmulatorConfig::default();
        assert!(
            mean.abs() <= c.gyro_bias + 3.0 * c.gyro_noise / 40.0 && mean.abs() > 1e-5,
            "bias {mean}"
        );
        assert!((sd - c.gyro_noise).abs() < 0.25 * c.gyro_noise, "noise {sd}");
        assert_ne!(WitImuEmulator::new(c, 12).gyro_bias, imu.gyro_bias);
        assert_eq!(WitImuEmulator::new(c, 11).gyro_bias, imu.gyro_bias);
    }
}
