//! Mirror settings (`--mirror FILE`): any text through the typed deserializer and, when it parses,
//! the range check against the reference robot (joints named, periods, noise, latencies, masses).
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| fuzz_targets::mirror_toml::run(data));
