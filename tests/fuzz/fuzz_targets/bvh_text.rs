//! BVH motion files: any text through the parser; an accepted file has frames whose poses can be
//! taken without a panic.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| fuzz_targets::bvh_text::run(data));
