//! robot.toml: any text through the typed deserializer (the MJCF cross-checks need files, which
//! the whole-path tests cover).

/// One input.
pub fn run(data: &[u8]) {
    if let Ok(text) = std::str::from_utf8(data) {
        let _ = toml::from_str::<robots::RobotConfig>(text);
    }
}
