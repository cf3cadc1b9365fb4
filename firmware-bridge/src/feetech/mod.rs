//! Feetech STS serial bus servos (STS3215 and kin: Open Duck Mini, the LeRobot arms, many hobby
//! humanoids): the protocol's codec, the STS control table, models as data, emulated servos on a
//! simulated line, and the host driver.

pub mod driver;
pub mod models;
pub mod packet;
pub mod servo;
pub mod table;
pub mod wire;
