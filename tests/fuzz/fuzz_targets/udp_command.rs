//! Operator command datagrams from the network (`play --command-udp`): any bytes through the
//! versioned message parser. An accepted message's commands must lie within the manifest's ranges
//! (they reach the policy as they are).
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| fuzz_targets::udp_command::run(data));
