//! VMC over OSC datagrams from the network: any bytes through the OSC parser and the VMC decoder.
//! Accepted poses must be finite (a NaN pose would reach the retargeting IK).

use human::vmc::{Counters, Serials, Tracks, decode};

/// One input.
pub fn run(data: &[u8]) {
    let _ = human::osc::parse(data, &mut |m| {
        let _ = m.args().count();
    });
    let mut tracks = Tracks::default();
    let accepted = decode(
        data,
        &Serials::default(),
        std::time::Instant::now(),
        &mut tracks,
        &Counters::default(),
    );
    assert!(accepted <= 16);
}
