//! DDS samples from the network: Unitree's `rt/lowcmd`/`rt/lowstate` and ROS 2's `/cmd_vel`
//! through their CDR readers (see the target's body in tests/fuzz-targets).
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| fuzz_targets::dds_samples::run(data));
