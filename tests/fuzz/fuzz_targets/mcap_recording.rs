//! Recorded runs (MCAP) as `report`, `replay` and `compare` read them: any bytes through the chunk
//! check and the message walk.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| fuzz_targets::mcap_recording::run(data));
