//! Feetech serial bus traffic from both ends: any bytes, in any chunking, into the host's status
//! decoder (a status is whole and its parameters within the packet) and into a line of emulated
//! STS servos (every answer a well-formed status packet with a good checksum).

use firmware_bridge::feetech::models::find;
use firmware_bridge::feetech::packet::{self, Decoded, Feetech};
use firmware_bridge::feetech::servo::{StsConfig, StsServo};
use firmware_bridge::feetech::wire::FeetechChain;
use firmware_bridge::half_duplex::{LineDevices, ServoCodec, StatusDecode, WireTiming};
use firmware_bridge::time::SimInstant;

/// One input.
pub fn run(data: &[u8]) {
    let mut scratch = [0u8; 512];
    let mut at = 0;
    while at < data.len() {
        match Feetech::decode_status(&data[at..], &mut scratch) {
            StatusDecode::Status { params, used, .. } => {
                assert!(params.1 - params.0 + 6 <= used);
                at += used;
            }
            StatusDecode::Invalid { used, .. } => at += used.max(1),
            StatusDecode::Incomplete { .. } => break,
        }
    }
    let m = find("STS3215").unwrap();
    let servos = (1..=3)
        .map(|id| StsServo::new(m, StsConfig::new(id, m)))
        .collect();
    let mut chain = FeetechChain::new(servos, WireTiming::new(1_000_000));
    for (k, chunk) in data.chunks(11).enumerate() {
        chain.receive(chunk, SimInstant::from_nanos(k as u64 * 50_000));
    }
    chain.take_replies_due(
        SimInstant::from_nanos(u64::MAX / 2),
        &mut |_, bytes| match packet::decode(bytes) {
            Decoded::Packet { used, .. } => assert_eq!(used, bytes.len()),
            other => panic!("a servo sent {bytes:02X?}: {other:?}"),
        },
    );
}
