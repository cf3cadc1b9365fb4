//! MIT-mode CAN motors (CubeMars AK, DaMiao DM-J, Mini Cheetah firmware): model table, codec,
//! host driver, emulated firmware, and a rig that runs emulated motors on virtual buses.

pub mod codec;
pub mod driver;
pub mod firmware;
pub mod models;
pub mod rig;
