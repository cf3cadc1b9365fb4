//! Dynamixel Protocol 2.0 (serial, half duplex). So far: the packet codec both sides share.
//! The host driver and emulated X-series servos build on it.

pub mod packet;
