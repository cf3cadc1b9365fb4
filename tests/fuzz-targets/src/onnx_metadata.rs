//! ONNX metadata as training frameworks export it (one `key<TAB>value` per line; the first byte
//! says whether the model has a `time_step` input): the typed readers and the contract they
//! fill, then — when the metadata filled the whole manifest — every range and cross-check of the
//! manifest against the reference robot, as `play --policy export.onnx` runs them.

use std::collections::BTreeMap;

use policy::PolicyManifest;
use policy::export::{ModelFacts, fill};

/// One input.
pub fn run(data: &[u8]) {
    let Some((&first, rest)) = data.split_first() else {
        return;
    };
    let Ok(text) = std::str::from_utf8(rest) else {
        return;
    };
    let metadata: BTreeMap<String, String> = text
        .lines()
        .filter_map(|l| l.split_once('\t'))
        .map(|(k, v)| (k.to_owned(), v.to_owned()))
        .collect();
    let inputs = if first & 1 == 1 {
        vec!["obs".to_owned(), "time_step".to_owned()]
    } else {
        vec!["obs".to_owned()]
    };
    let mut manifest = PolicyManifest::for_onnx("/nonexistent/robodeploy-fuzz/export.onnx".into());
    if fill(&mut manifest, &ModelFacts { metadata, inputs }).is_err() {
        return;
    }
    let Ok(text) = toml::to_string(&manifest) else {
        return;
    };
    let path = std::path::Path::new("/nonexistent/robodeploy-fuzz/policy.toml");
    if let Ok(layout) = policy::PolicyLayout::parse(path, &text, crate::reference_robot()) {
        assert_eq!(layout.action_scale.len(), layout.robot_index.len());
    }
}
