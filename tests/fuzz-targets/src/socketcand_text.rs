//! socketcand's text protocol: any bytes through the framer, every message parsed.

use firmware_bridge::can::socketcand::{Framer, parse};

/// One input.
pub fn run(data: &[u8]) {
    let mut framer = Framer::default();
    for chunk in data.chunks(7) {
        framer.push(chunk);
        while let Some((span, is_message)) = framer.next_span() {
            if is_message && let Ok(text) = std::str::from_utf8(framer.bytes(span.clone())) {
                let _ = parse(text);
            }
            framer.consume(span.end);
        }
    }
}
