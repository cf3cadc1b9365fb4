//! robot.toml: any text through the typed deserializer (the MJCF cross-checks need files, which
//! the whole-path tests cover).
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if let Ok(text) = std::str::from_utf8(data) {
        let _ = toml::from_str::<robots::RobotConfig>(text);
    }
});
