//! IMUs on serial lines: the WIT Motion standard protocol and the BNO08x's UART-RVC stream (host
//! decoders and encoders), an emulated AHRS with the noise, bias and rate of the real part, and
//! the host reader the controller uses.

pub mod bno055;
pub mod emulator;
pub mod reader;
pub mod rvc;
pub mod wit;

/// What an IMU streams on its serial line.
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, Default, serde::Deserialize, schemars::JsonSchema, serde::Serialize,
)]
#[serde(rename_all = "snake_case")]
pub enum ImuProtocol {
    /// WIT Motion's 11-byte packets (acceleration, angular velocity, angles, quaternion).
    #[default]
    Wit,
    /// A BNO08x in UART-RVC mode: 19-byte frames of attitude and acceleration at 100 Hz,
    /// 115200 baud (the angular velocity derived from consecutive attitudes).
    Bno08xRvc,
    /// A BNO055 on its UART: the host sets IMU fusion mode, then reads the data registers (at
    /// most 100 Hz, 115200 baud).
    Bno055,
}

/// The smallest step of each output a part reports, SI units: what two readings of the same
/// state can differ by.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Resolution {
    /// Angular velocity, rad/s.
    pub gyro: f64,
    /// Acceleration, m/s².
    pub accel: f64,
    /// A component of the orientation quaternion.
    pub quaternion: f64,
}

impl ImuProtocol {
    /// The resolution of the part's outputs as its protocol carries them.
    pub fn resolution(self) -> Resolution {
        match self {
            Self::Wit => Resolution {
                gyro: wit::GYRO_RESOLUTION,
                accel: wit::ACCEL_RESOLUTION,
                quaternion: wit::QUATERNION_RESOLUTION,
            },
            // RVC carries angles; the angular velocity is an attitude difference over one frame,
            // and a quaternion component moves by half an angle's step.
            Self::Bno08xRvc => Resolution {
                gyro: rvc::ANGLE_RESOLUTION * rvc::RATE_HZ,
                accel: rvc::ACCEL_RESOLUTION,
                quaternion: 0.5 * rvc::ANGLE_RESOLUTION,
            },
            Self::Bno055 => Resolution {
                gyro: bno055::GYRO_LSB,
                accel: bno055::ACCEL_LSB,
                quaternion: bno055::QUAT_LSB,
            },
        }
    }

    /// The line speed the part runs at, when fixed.
    pub fn fixed_baud(self) -> Option<u32> {
        match self {
            Self::Wit => None,
            Self::Bno08xRvc => Some(rvc::BAUD),
            Self::Bno055 => Some(bno055::BAUD),
        }
    }
}
