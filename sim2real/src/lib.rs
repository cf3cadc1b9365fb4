//! The mirrored simulator: the robot as the controller sees it through its buses, with emulated
//! firmware driving MuJoCo behind mock wires.

pub mod config;
pub mod floor;
pub mod hands;
pub mod host;
pub mod link;
pub mod mirror;
pub mod model_index;
pub mod mujoco;
pub mod placement;
pub mod render;
pub mod serve;
pub mod stability;
