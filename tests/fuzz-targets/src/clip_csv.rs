//! Retargeted clips as CSV: any text through the parser; an accepted clip has a finite duration.

/// One input.
pub fn run(data: &[u8]) {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    if let Ok(clip) = controller::clip::Clip::parse_csv(std::path::Path::new("fuzz.csv"), text) {
        assert!(clip.duration().is_finite());
    }
}
