//! Motion files of other tools: a sidecar `<name>.motion.toml` and the headerless CSV it
//! describes (the input is the sidecar's text, a NUL byte, the CSV's text). An accepted clip has
//! a finite duration and unit root quaternions.

/// One input.
pub fn run(data: &[u8]) {
    let Some(split) = data.iter().position(|&b| b == 0) else {
        return;
    };
    let (Ok(side), Ok(csv)) = (
        std::str::from_utf8(&data[..split]),
        std::str::from_utf8(&data[split + 1..]),
    ) else {
        return;
    };
    let path = std::path::Path::new("fuzz.csv");
    let Ok(sidecar) = controller::clip::MotionSidecar::parse(&controller::clip::sidecar_path(path), side)
    else {
        return;
    };
    if let Ok(clip) = controller::clip::Clip::parse_headerless_csv(path, csv, &sidecar) {
        assert!(clip.duration().is_finite());
        for r in &clip.root {
            let n = (r[3] * r[3] + r[4] * r[4] + r[5] * r[5] + r[6] * r[6]).sqrt();
            assert!((n - 1.0).abs() < 1e-9, "{r:?}");
        }
    }
}
