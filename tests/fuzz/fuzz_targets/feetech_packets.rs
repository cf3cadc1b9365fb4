//! Feetech serial bus traffic from both ends: any bytes, in any chunking, into the host's status
//! decoder (a status is whole and its parameters within the packet) and into a line of emulated
//! STS servos (every answer a well-formed status packet with a good checksum).
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| fuzz_targets::feetech_packets::run(data));
