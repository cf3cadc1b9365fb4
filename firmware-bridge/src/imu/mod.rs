//! IMUs on serial lines: the WIT Motion standard protocol and the BNO08x's UART-RVC stream (host
//! decoders and encoders), an emulated AHRS with the noise, bias and rate of the real part, and
//! the host reader the controller uses.

pub mod bno055;
pub mod emulator;
pub mod reader;
pub mod rvc;
pub mod wit;

/// What an IMU streams on its serial line.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Deserialize, serde::Serialize)]
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

impl ImuProtocol {
    /// The line speed the part runs at, when fixed.
    pub fn fixed_baud(self) -> Option<u32> {
        match self {
            Self::Wit => None,
            Self::Bno08xRvc => Some(rvc::BAUD),
            Self::Bno055 => Some(bno055::BAUD),
        }
    }
}
