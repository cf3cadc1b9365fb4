//! Device protocols, written once and used from both sides of the wire.
//!
//! The host drivers the controller uses and the emulated firmware the mirrored simulator runs are
//! built on the same codecs, over small transport traits, so a bus can be real hardware, an
//! in-process loopback or a wire to another process without `#[cfg]` inside a driver.
//!
//! - [`can`]: CAN frames, the [`can::CanBus`] transport trait, SocketCAN, socketcand, virtual buses.
//! - [`dxl`]: Dynamixel Protocol 2.0: codec, host driver, emulated X-series servos.
//! - [`feetech`]: Feetech STS servos: codec, control table, host driver, emulated servos.
//! - [`half_duplex`]: serial servo lines whatever the protocol: host ports, the simulated wire.
//! - [`imu`]: serial IMUs (WIT AHRS, BNO08x RVC, BNO055): decoders, emulated parts, host reader.
//! - [`mit`]: MIT-mode and Robstride CAN motors: codecs, host driver, emulated firmware.
//! - [`plant`]: what emulated firmware drives.
//! - [`ratelimit`]: warnings about floods of bad input, one line per interval with a count.
//! - [`serial`]: serial lines to simulated worlds, byte streams, the pseudo-terminal server.
//! - [`time`]: simulated time and deterministic randomness.

pub mod can;
pub mod dxl;
pub mod feetech;
pub mod half_duplex;
pub mod imu;
pub mod mit;
pub mod plant;
pub mod ratelimit;
pub mod serial;
pub mod time;
pub mod unitree;
