//! A Foxglove layout for a robot's recordings and live view (`robodeploy layout`): the robot in 3D
//! following its root, a tab per bus with a tracking plot per joint (measured, commanded and
//! reference position, and the joint's limits as reference lines), the safety state machine's
//! timeline with the safety log, where each tick's time went, and a tab for a motion
//! generator's status and the 2D keypoint errors (when a run has them). Import it in Foxglove with
//! Layouts → Import from file.
//!
//! Message paths pick joints by name (`/joint_state.joints[:]{name=="left_knee"}.position`), so a
//! layout keeps working when a robot.toml reorders its joints.

use serde_json::{Value, json};

/// One joint as the layout plots it.
#[derive(Debug, Clone)]
pub struct LayoutJoint {
    /// The joint's name.
    pub name: String,
    /// Its bus.
    pub bus: String,
    /// Position limits, rad.
    pub limits: [f64; 2],
}

/// The layout for a robot whose root frame is `root`, with `joints` in robot order; the keypoint
/// plot marks errors over `keypoint_failure_px` as failures.
pub fn foxglove_layout(robot: &str, root: &str, joints: &[LayoutJoint], keypoint_failure_px: f64) -> Value {
    let mut panels = serde_json::Map::new();
    let mut buses: Vec<&str> = Vec::new();
    for j in joints {
        if !buses.contains(&j.bus.as_str()) {
            buses.push(&j.bus);
        }
    }
    let tabs: Vec<Value> = buses
        .iter()
        .map(|bus| {
            let ids: Vec<String> = joints
                .iter()
                .filter(|j| j.bus == *bus)
                .map(|j| {
                    let id = format!("Plot!{}", j.name);
                    panels.insert(id.clone(), joint_plot(j));
                    id
                })
                .collect();
            json!({"title": bus, "layout": mosaic(&ids, "column")})
        })
        .collect();
    // A last tab for runs on other references: a motion generator's plans, 2D keypoints.
    let mut tabs = tabs;
    panels.insert(
        "StateTransitions!generator".into(),
        json!({"paths": [{"value": "/policy.generated.status", "timestampMethod": "receiveTime",
                          "label": "generated reference"}],
               "isSynced": true}),
    );
    panels.insert(
        "Plot!generator".into(),
        json!({
            "title": "generator: time past its plan (s), blend to standby (0–1), step latency (s)",
            "paths": [
                series("/policy.generated.past_plan_s", "past the plan", "#f5774d"),
                series("/policy.generated.standby_weight", "standby", "#e05d5d"),
                series("/policy.generated.step_latency_s", "step latency", "#4e98e2"),
            ],
            "showLegend": true, "legendDisplay": "floating", "isSynced": true,
            "xAxisVal": "timestamp", "showXAxisLabels": true, "showYAxisLabels": true,
        }),
    );
    panels.insert(
        "Plot!keypoints".into(),
        json!({
            "title": "2D keypoints: reprojection error (px) of the first two views",
            "paths": [
                series("/policy.keypoint_errors[0].mean_px", "view 1 mean", "#4e98e2"),
                series("/policy.keypoint_errors[0].max_px", "view 1 max", "#e05d5d"),
                series("/policy.keypoint_errors[1].mean_px", "view 2 mean", "#9ad86e"),
                series("/policy.keypoint_errors[1].max_px", "view 2 max", "#f5a623"),
            ],
            "referenceLines": [{"value": keypoint_failure_px, "color": "#e05d5d"}],
            "showLegend": true, "legendDisplay": "floating", "isSynced": true,
            "xAxisVal": "timestamp", "showXAxisLabels": true, "showYAxisLabels": true,
        }),
    );
    tabs.push(json!({"title": "generator & keypoints", "layout": {
        "direction": "column", "first": "StateTransitions!generator",
        "second": {"direction": "column", "first": "Plot!generator", "second": "Plot!keypoints",
                   "splitPercentage": 50},
        "splitPercentage": 20}}));
    panels.insert("Tab!joints".into(), json!({"activeTabIdx": 0, "tabs": tabs}));
    panels.insert(
        "3D!robot".into(),
        json!({
            "followMode": "follow-position",
            "followTf": root,
            "scene": {"backgroundColor": "#1e2430"},
            "cameraState": {"distance": 2.2, "perspective": true, "phi": 65, "thetaOffset": 35,
                            "targetOffset": [0, 0, 0], "fovy": 45, "near": 0.01, "far": 100},
            "topics": {
                "/robot": {"visible": true},
                "/anchor/robot": {"visible": true, "type": "axis", "axisScale": 0.3},
                "/anchor/reference": {"visible": true, "type": "arrow", "color": "#f5a623"},
            },
            "transforms": {"labelSize": 0.03, "axisScale": 0.6},
            "layers": {"grid": {"layerId": "foxglove.Grid", "visible": true, "frameId": "world",
                                "size": 10, "divisions": 20, "lineWidth": 1, "color": "#ffffff33",
                                "position": [0, 0, 0], "rotation": [0, 0, 0]}},
        }),
    );
    panels.insert(
        "StateTransitions!safety".into(),
        json!({"paths": [{"value": "/safety.mode", "timestampMethod": "receiveTime", "label": "mode"}],
               "isSynced": true}),
    );
    panels.insert(
        "Log!safety".into(),
        json!({"searchTerms": [], "minLogLevel": 1, "topicToRender": "/log"}),
    );
    panels.insert(
        "Plot!timing".into(),
        json!({
            "title": "tick time (µs)",
            "paths": [
                series("/timing.compute_us", "compute", "#4e98e2"),
                series("/timing.io_us", "bus I/O", "#f5774d"),
            ],
            "showLegend": true, "legendDisplay": "floating", "isSynced": true,
            "xAxisVal": "timestamp", "showXAxisLabels": true, "showYAxisLabels": true,
        }),
    );
    json!({
        "configById": panels,
        "globalVariables": {},
        "userNodes": {},
        "playbackConfig": {"speed": 1},
        "layout": {
            "direction": "row",
            "first": {"direction": "column", "first": "3D!robot", "second": {
                "direction": "column", "first": "StateTransitions!safety",
                "second": {"direction": "row", "first": "Log!safety", "second": "Plot!timing"},
                "splitPercentage": 40}, "splitPercentage": 60},
            "second": "Tab!joints",
            "splitPercentage": 45,
        },
        "robodeploy": {"robot": robot, "made_by": "robodeploy layout"},
    })
}

/// One joint's tracking plot: measured, commanded and reference position, its limits.
fn joint_plot(j: &LayoutJoint) -> Value {
    let pick = |topic: &str, field: &str| format!("{topic}.joints[:]{{name==\"{}\"}}.{field}", j.name);
    json!({
        "title": format!("{} (rad)", j.name),
        "paths": [
            series(&pick("/joint_state", "position"), "measured", "#4e98e2"),
            series(&pick("/command", "position"), "command", "#f5774d"),
            series(&pick("/command", "reference"), "reference", "#9ad86e"),
        ],
        "minYValue": j.limits[0] - 0.05,
        "maxYValue": j.limits[1] + 0.05,
        "referenceLines": [
            {"value": j.limits[0], "color": "#e05d5d"},
            {"value": j.limits[1], "color": "#e05d5d"},
        ],
        "showLegend": false, "isSynced": true, "xAxisVal": "timestamp",
        "showXAxisLabels": false, "showYAxisLabels": true,
    })
}

fn series(path: &str, label: &str, color: &str) -> Value {
    json!({"value": path, "enabled": true, "timestampMethod": "receiveTime", "label": label, "color": color})
}

/// A balanced mosaic of `ids` split along `direction`.
fn mosaic(ids: &[String], direction: &str) -> Value {
    match ids {
        [] => Value::Null,
        [one] => json!(one),
        _ => {
            let (a, b) = ids.split_at(ids.len() / 2);
            json!({
                "direction": direction,
                "first": mosaic(a, direction),
                "second": mosaic(b, direction),
                "splitPercentage": 100.0 * a.len() as f64 / ids.len() as f64,
            })
        }
    }
}

/// The message paths of `layout`'s panels, for checking them against the recording's schemas.
pub fn message_paths(layout: &Value) -> Vec<String> {
    let mut out = Vec::new();
    if let Some(panels) = layout["configById"].as_object() {
        for config in panels.values() {
            for p in config["paths"].as_array().into_iter().flatten() {
                if let Some(v) = p["value"].as_str() {
                    out.push(v.to_owned());
                }
            }
        }
    }
    out
}
