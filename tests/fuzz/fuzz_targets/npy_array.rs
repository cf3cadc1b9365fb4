//! NumPy `.npy` arrays (the members of an `.npz` clip): any bytes through the header and data
//! parser, which must refuse impossible shapes rather than allocate them.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| fuzz_targets::npy_array::run(data));
