//! Motor frames on CAN, MIT mode and Robstride's factory protocol: the first four bytes as an
//! identifier (11- or 29-bit by its top bit), up to 8 more as data, taken by every motor model as
//! a request (the firmware's side) and as a reply (the host's side). Decoded values stay inside
//! the model's ranges; an emulated motor answers only with frames its host decodes.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| fuzz_targets::mit_frames::run(data));
