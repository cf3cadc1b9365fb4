//! The BNO08x UART-RVC stream: any bytes, in any chunking, through the decoder. Every sample must
//! be finite (it reaches the estimator and the policy), its quaternion a unit one.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| fuzz_targets::rvc_stream::run(data));
