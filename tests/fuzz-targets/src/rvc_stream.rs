//! The BNO08x UART-RVC stream: any bytes, in any chunking, through the decoder. Every sample must
//! be finite (it reaches the estimator and the policy), its quaternion a unit one.

use firmware_bridge::imu::rvc::RvcDecoder;

/// One input.
pub fn run(data: &[u8]) {
    let mut decoder = RvcDecoder::new();
    for chunk in data.chunks(7) {
        decoder.feed(chunk, |s| {
            crate::assert_imu_sample_sound(s);
        });
    }
}
