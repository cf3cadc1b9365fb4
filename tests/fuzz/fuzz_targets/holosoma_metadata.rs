//! holosoma's export metadata with the training configuration (`experiment_config`, JSON) the
//! fuzzer writes, beside valid joint names and gains for the reference robot: the convention's
//! reader fills the contract (terms sorted by name, scales, history, the action scale from effort
//! over stiffness, the standing pose by name, the anchor body) or names what is wrong; what it
//! fills passes or fails the manifest's checks against the robot, never panics.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| fuzz_targets::holosoma_metadata::run(data));
