//! VMC over OSC datagrams from the network: any bytes through the OSC parser and the VMC decoder.
//! Accepted poses must be finite (a NaN pose would reach the retargeting IK).
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| fuzz_targets::osc_vmc::run(data));
