//! The BNO055's UART protocol from both ends: any bytes from a chip through the host's reader
//! (every sample finite, its quaternion a unit one), and any bytes from a host into the emulated
//! chip (every answer a well-formed response, nothing else).

use firmware_bridge::imu::bno055::{Bno055, Bno055Host, READ_RESPONSE, STATUS_RESPONSE};
use firmware_bridge::time::SimInstant;

/// One input.
pub fn run(data: &[u8]) {
    let mut host = Bno055Host::new(100.0);
    let mut t = 0.0;
    for chunk in data.chunks(9) {
        let _ = host.request(t);
        t += 0.003;
        host.feed(chunk, |s| {
            crate::assert_imu_sample_sound(s);
        });
    }
    let mut chip = Bno055::new();
    let mut out = Vec::new();
    for (k, chunk) in data.chunks(5).enumerate() {
        out.clear();
        chip.receive(SimInstant::from_nanos(k as u64 * 1_000_000), chunk, &mut out);
        let mut rest = &out[..];
        while !rest.is_empty() {
            match rest[0] {
                STATUS_RESPONSE => rest = &rest[2..],
                READ_RESPONSE => {
                    let len = usize::from(rest[1]);
                    assert!((1..=128).contains(&len));
                    rest = &rest[2 + len..];
                }
                other => panic!("answer starts with {other:#04x}"),
            }
        }
    }
}
