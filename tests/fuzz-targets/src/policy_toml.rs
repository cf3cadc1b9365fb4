//! Policy manifests: any text through the typed deserializer and every range and cross-check
//! against the reference robot (joint names, rates, terms, scales, clips, action mapping, gains
//! against the motors). The same text as a motion generator's description: what is accepted is
//! within its documented ranges. The manifest's path points nowhere, so a manifest that leaves fields to the
//! ONNX file's metadata is refused for the missing file rather than loading a model per input.

/// One input.
pub fn run(data: &[u8]) {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let path = std::path::Path::new("/nonexistent/robodeploy-fuzz/policy.toml");
    if let Ok(layout) = policy::PolicyLayout::parse(path, text, crate::reference_robot()) {
        assert_eq!(
            layout.manifest.joints.len(),
            crate::reference_robot().config.joints.len()
        );
    }
    let generator = std::path::Path::new("/nonexistent/robodeploy-fuzz/generator.toml");
    if let Ok(d) = controller::generator::GeneratorDescription::from_str(generator, text) {
        assert!((1..=256).contains(&d.history) && (1..=256).contains(&d.horizon));
        assert!((1.0..=1000.0).contains(&d.frame_hz) && !d.joints.is_empty());
        if let Some(c) = &d.command {
            assert!((1..=16).contains(&c.names.len()) && c.check(&c.values).is_ok());
        }
    }
}
