//! NumPy `.npy` arrays (the members of an `.npz` clip): any bytes through the header and data
//! parser, which must refuse impossible shapes rather than allocate them.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let _ = controller::npy::parse_npy(data);
});
