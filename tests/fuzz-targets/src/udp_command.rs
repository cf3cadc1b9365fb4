//! Operator command datagrams from the network (`play --command-udp`): any bytes through the
//! versioned message parser. An accepted message's commands must lie within the manifest's ranges
//! (they reach the policy as they are).

use human::commands::{Newest, parse_datagram};

/// One input.
pub fn run(data: &[u8]) {
    let spec = crate::walk_commands();
    for newest in [None, Some(Newest { session: 0, seq: 10 })] {
        if let Ok(m) = parse_datagram(&spec, data, newest) {
            assert!(spec.check_values(&m.command).is_ok(), "{:?}", m.command);
            // Ten is inside the window: only a newer one, or another session's, is taken.
            assert!(newest.is_none_or(|n| m.seq > n.seq || m.session != n.session));
        }
    }
}
