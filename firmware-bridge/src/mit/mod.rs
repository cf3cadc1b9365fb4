//! Impedance-controlled CAN motors: MIT mode (CubeMars AK, DaMiao DM-J, Mini Cheetah firmware) and
//! Robstride's factory protocol. Model table, codecs, host driver, emulated firmware, and a rig
//! that runs emulated motors on virtual buses.

pub mod codec;
pub mod driver;
pub mod firmware;
pub mod models;
pub mod rig;
pub mod robstride;
