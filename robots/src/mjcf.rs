//! What a robot description needs to know about its MJCF, read without MuJoCo: joint names, types
//! and ranges, bodies, sites, position actuators and the mesh files the model refers to.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use crate::FileError;

/// A joint declared in the MJCF.
#[derive(Debug, Clone, PartialEq)]
pub struct MjcfJoint {
    /// `type` attribute (hinge when absent).
    pub kind: String,
    /// `range`, when given.
    pub range: Option<(f64, f64)>,
}

/// The parts of an MJCF file the robot description cross-checks.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct MjcfSummary {
    /// Joints by name.
    pub joints: BTreeMap<String, MjcfJoint>,
    /// Body names.
    pub bodies: Vec<String>,
    /// Site names.
    pub sites: Vec<String>,
    /// Joints driven by `<position>` actuators.
    pub position_actuated: Vec<String>,
    /// Mesh files, resolved against the model's folder and `meshdir`.
    pub mesh_files: Vec<PathBuf>,
    /// Whether the model has a free joint (a floating base).
    pub floating: bool,
}

/// Reads `path`. Errors name the file and what is wrong.
pub fn summarize(path: &Path) -> Result<MjcfSummary, FileError> {
    summarize_text(path).map_err(|message| FileError {
        path: path.to_path_buf(),
        message,
    })
}

fn summarize_text(path: &Path) -> Result<MjcfSummary, String> {
    let text = crate::read_text(path)?;
    let doc = roxmltree::Document::parse(&text).map_err(|e| format!("not valid XML: {e}"))?;
    let root = doc.root_element();
    if root.tag_name().name() != "mujoco" {
        return Err(format!(
            "root element is <{}>, not <mujoco>",
            root.tag_name().name()
        ));
    }
    let folder = path.parent().unwrap_or(Path::new("."));
    let meshdir = root
        .descendants()
        .find(|n| n.has_tag_name("compiler"))
        .and_then(|n| n.attribute("meshdir"))
        .map_or_else(|| folder.to_path_buf(), |d| folder.join(d));
    // MJCF angles are degrees unless the compiler says radian.
    let degrees = root
        .descendants()
        .find(|n| n.has_tag_name("compiler"))
        .and_then(|n| n.attribute("angle"))
        .is_none_or(|a| a != "radian");
    let scale = if degrees {
        std::f64::consts::PI / 180.0
    } else {
        1.0
    };
    let mut s = MjcfSummary::default();
    for node in root.descendants().filter(roxmltree::Node::is_element) {
        let name = node.attribute("name").map(str::to_owned);
        match node.tag_name().name() {
            "freejoint" => s.floating = true,
            "joint" if node.ancestors().any(|a| a.has_tag_name("body")) => {
                let kind = node.attribute("type").unwrap_or("hinge").to_owned();
                s.floating |= kind == "free";
                let range = node.attribute("range").and_then(parse_pair).map(|(a, b)| {
                    if kind == "hinge" {
                        (a * scale, b * scale)
                    } else {
                        (a, b)
                    }
                });
                if let Some(name) = name {
                    s.joints.insert(name, MjcfJoint { kind, range });
                }
            }
            "body" => s.bodies.extend(name),
            "site" => s.sites.extend(name),
            "position" if node.ancestors().any(|a| a.has_tag_name("actuator")) => {
                s.position_actuated
                    .extend(node.attribute("joint").map(str::to_owned));
            }
            "mesh" if node.ancestors().any(|a| a.has_tag_name("asset")) => {
                if let Some(file) = node.attribute("file") {
                    s.mesh_files.push(meshdir.join(file));
                }
            }
            _ => {}
        }
    }
    Ok(s)
}

fn parse_pair(text: &str) -> Option<(f64, f64)> {
    let mut it = text.split_whitespace().map(str::parse::<f64>);
    match (it.next(), it.next(), it.next()) {
        (Some(Ok(a)), Some(Ok(b)), None) => Some((a, b)),
        _ => None,
    }
}
