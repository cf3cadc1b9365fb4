//! Retargeted clips as CSV: any text through the parser; an accepted clip has a finite duration.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| fuzz_targets::clip_csv::run(data));
