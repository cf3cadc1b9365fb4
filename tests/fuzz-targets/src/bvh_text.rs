//! BVH motion files: any text through the parser; an accepted file has frames whose poses can be
//! taken without a panic.

/// One input.
pub fn run(data: &[u8]) {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    if let Ok(bvh) = motion::bvh::Bvh::parse(std::path::Path::new("fuzz.bvh"), text) {
        assert!(bvh.frames() >= 1);
        let _ = bvh.pose(0);
        let _ = bvh.pose(bvh.frames() - 1);
    }
}
