//! Motion files of other tools: a sidecar `<name>.motion.toml` and the headerless CSV it
//! describes (the input is the sidecar's text, a NUL byte, the CSV's text). An accepted clip has
//! a finite duration and unit root quaternions.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| fuzz_targets::motion_csv::run(data));
