//! The BNO055's UART protocol from both ends: any bytes from a chip through the host's reader
//! (every sample finite, its quaternion a unit one), and any bytes from a host into the emulated
//! chip (every answer a well-formed response, nothing else).
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| fuzz_targets::bno055_uart::run(data));
