//! The WIT AHRS serial stream: any bytes, in any chunking, through the decoder.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| fuzz_targets::wit_stream::run(data));
