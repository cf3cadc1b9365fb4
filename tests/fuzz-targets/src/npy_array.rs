//! NumPy `.npy` arrays (the members of an `.npz` clip): any bytes through the header and data
//! parser, which must refuse impossible shapes rather than allocate them.

/// One input.
pub fn run(data: &[u8]) {
    let _ = controller::npy::parse_npy(data);
}
