//! socketcand's text protocol: any bytes through the framer, every message parsed.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| fuzz_targets::socketcand_text::run(data));
