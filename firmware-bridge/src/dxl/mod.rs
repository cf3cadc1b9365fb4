//! Dynamixel Protocol 2.0 (serial, half duplex): the packet codec both sides share, the host
//! driver, emulated X-series servos and the wires between them.
//!
//! - [`packet`]: CRC-16, byte stuffing, instruction and status packets (no allocation).
//! - [`table`], [`models`]: the X-series control table and the servo models as data.
//! - [`servo`]: emulated servo firmware.
//! - [`wire`]: servos on a line in simulated time, a test rig, and a pseudo-terminal server.
//! - [`transport`]: the host's view of a line: `dynamixel2` on a serial device, or lockstep sim.
//! - [`driver`]: scan, configure, enable, and the per-tick sync write + sync read in joint units.

pub mod driver;
pub mod models;
pub mod packet;
pub mod servo;
pub mod table;
pub mod transport;
pub mod wire;
