//! holosoma's export metadata with the training configuration (`experiment_config`, JSON) the
//! fuzzer writes, beside valid joint names and gains for the reference robot: the convention's
//! reader fills the contract (terms sorted by name, scales, history, the action scale from effort
//! over stiffness, the standing pose by name, the anchor body) or names what is wrong; what it
//! fills passes or fails the manifest's checks against the robot, never panics.

use std::collections::BTreeMap;

use policy::PolicyManifest;
use policy::export::{ModelFacts, fill};

/// One input.
pub fn run(data: &[u8]) {
    let Ok(config) = std::str::from_utf8(data) else {
        return;
    };
    let robot = crate::reference_robot();
    let names: Vec<String> = robot
        .config
        .joints
        .iter()
        .map(|j| format!("{:?}", j.name))
        .collect();
    let n = names.len();
    let mut metadata = BTreeMap::new();
    metadata.insert("dof_names".to_owned(), format!("[{}]", names.join(", ")));
    metadata.insert("kp".to_owned(), format!("[{}]", vec!["40.0"; n].join(", ")));
    metadata.insert("kd".to_owned(), format!("[{}]", vec!["2.0"; n].join(", ")));
    metadata.insert("experiment_config".to_owned(), config.to_owned());
    let facts = ModelFacts {
        metadata,
        inputs: vec!["obs".to_owned(), "time_step".to_owned()],
    };
    let mut manifest = PolicyManifest::for_onnx("/nonexistent/robodeploy-fuzz/export.onnx".into());
    if fill(&mut manifest, &facts).is_err() {
        return;
    }
    let Ok(text) = toml::to_string(&manifest) else {
        return;
    };
    let path = std::path::Path::new("/nonexistent/robodeploy-fuzz/policy.toml");
    if let Ok(layout) = policy::PolicyLayout::parse(path, &text, robot) {
        assert_eq!(layout.action_scale.len(), layout.robot_index.len());
    }
}
