//! robot.toml: any text through the typed deserializer (the MJCF cross-checks need files, which
//! the whole-path tests cover).
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| fuzz_targets::robot_toml::run(data));
