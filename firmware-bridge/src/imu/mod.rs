//! IMUs on serial lines: the WIT Motion standard protocol (host decoder and encoder), an emulated
//! AHRS with the noise, bias and rate of the real part, and the host reader the controller uses.

pub mod emulator;
pub mod reader;
pub mod wit;
