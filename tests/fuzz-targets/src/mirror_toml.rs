//! Mirror settings (`--mirror FILE`): any text through the typed deserializer and, when it parses,
//! the range check against the reference robot (joints named, periods, noise, latencies, masses).

use sim2real::config::MirrorConfig;

/// One input.
pub fn run(data: &[u8]) {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    if let Ok(config) = toml::from_str::<MirrorConfig>(text) {
        let _ = config.check(crate::reference_robot());
    }
}
