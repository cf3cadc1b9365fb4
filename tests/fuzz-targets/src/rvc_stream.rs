//! The BNO08x UART-RVC stream: any bytes, in any chunking, through the decoder. Every sample must
//! be finite (it reaches the estimator and the policy), its quaternion a unit one.

use firmware_bridge::imu::rvc::RvcDecoder;

/// One input.
pub fn run(data: &[u8]) {
    let mut decoder = RvcDecoder::new();
    for chunk in data.chunks(7) {
        decoder.feed(chunk, |s| {
            assert!(
                s.quat
                    .iter()
                    .chain(&s.gyro)
                    .chain(&s.accel)
                    .all(|v| v.is_finite())
            );
            let norm = s.quat.iter().map(|q| q * q).sum::<f64>();
            assert!((norm - 1.0).abs() < 1e-9, "{:?}", s.quat);
        });
    }
}
