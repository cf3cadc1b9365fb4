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
    // One packet's poses fit the decoder's fixed room; every pose it kept is finite.
    assert!(accepted <= 32);
    let finite =
        |f: &human::body_map::Frame| f.pos.iter().chain(f.rot.iter().flatten()).all(|v| v.is_finite());
    for track in &tracks.devices {
        assert!(track.samples.iter().flatten().all(|(_, f)| finite(f)));
    }
    assert!(
        tracks
            .skeleton
            .bones
            .iter()
            .chain([&tracks.skeleton.root])
            .flatten()
            .all(finite)
    );
}
