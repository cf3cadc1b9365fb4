//! GMR's motion pickles: any bytes through the restricted unpickler and the motion's checks, which
//! must refuse (not build) memo bombs, deep nesting and lengths beyond the data; what they accept
//! is a motion a clip can be made of.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| fuzz_targets::gmr_pickle::run(data));
