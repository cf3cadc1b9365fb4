//! VMC over OSC datagrams from the network: any bytes through the OSC parser and the VMC decoder.
//! Accepted poses must be finite (a NaN pose would reach the retargeting IK).
#![no_main]

use human::vmc::{Counters, Serials, Tracks, decode};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
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
});
