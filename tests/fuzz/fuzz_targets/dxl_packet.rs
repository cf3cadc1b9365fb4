//! Dynamixel Protocol 2.0, both sides: any byte stream through the streaming decoder, and every
//! packet it finds handed to an emulated XM430 servo as an instruction.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| fuzz_targets::dxl_packet::run(data));
