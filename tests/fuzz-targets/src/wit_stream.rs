//! The WIT AHRS serial stream: any bytes, in any chunking, through the decoder.

use firmware_bridge::imu::wit::WitDecoder;

/// One input.
pub fn run(data: &[u8]) {
    let mut decoder = WitDecoder::default();
    let mut samples = 0usize;
    for chunk in data.chunks(5) {
        decoder.feed(chunk, |s| {
            assert!(s.quat.iter().all(|q| q.is_finite()));
            samples += 1;
        });
    }
    let _ = samples;
}
