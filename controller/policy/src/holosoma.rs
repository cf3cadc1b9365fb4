//! holosoma's exports (holosoma / holosoma-inference, Apache-2.0): facts of its convention, as its
//! deployment code applies them.
//!
//! - Metadata values are JSON: `dof_names` (joint order), `kp`, `kd` (lists), `command_ranges`,
//!   and for whole-body tracking `experiment_config`, the whole training configuration.
//! - The observation is the `actor_obs` group's terms **sorted by name** and concatenated (not in
//!   the order the configuration lists them), each stacked over the group's `history_length`,
//!   oldest first, multiplied by its `scale`; nothing is clipped at deployment.
//! - A position action is `default + scale ⊙ a` with `a` clipped to `action_clip_value`; the scale
//!   is the metadata's `action_scale` when there is one, else — when the configuration says
//!   `action_scales_by_effort_limit_over_p_gain` — per joint `action_scale × effort / kp`.
//! - The whole-body-tracking export carries its motion: inputs `obs`, `time_step`; outputs
//!   `actions`, `joint_pos`, `joint_vel`, `ref_pos_xyz` [1, 3] and `ref_quat_xyzw` [1, 4] — the
//!   anchor body's (`body_name_ref`) pose, quaternion **x y z w** — for frame `time_step`. The call
//!   gets the frame this tick plays; its outputs are what the next observation sees.
//! - Terms (`holosoma.managers.observation.terms.wbt:NAME`): `motion_command` (the frame's joint
//!   positions then velocities), `motion_ref_ori_b` (first two columns of R(q_robot⁻¹ ⊗ q_ref) of
//!   the anchor, row by row; yaw offsets removed at start), `motion_ref_pos_b`, `base_ang_vel`,
//!   `base_lin_vel`, `projected_gravity`, `dof_pos` (relative to the default pose), `dof_vel`,
//!   `actions` (the last clipped raw action).

use serde_json::Value;

use crate::contract::{ActionScale, HistoryOrder, PolicyManifest, Shaping, Term};
use crate::export::{Metadata, Problem};

/// The metadata key that marks a holosoma export.
pub const JOINTS_KEY: &str = "dof_names";

/// Whether `meta` is a holosoma export's.
pub fn is_holosoma(meta: &Metadata<'_>) -> bool {
    meta.text(JOINTS_KEY).is_some()
}

fn json(meta: &Metadata<'_>, key: &str) -> Result<Option<Value>, Problem> {
    let Some(text) = meta.text(key) else {
        return Ok(None);
    };
    serde_json::from_str(text)
        .map(Some)
        .map_err(|e| (format!("ONNX metadata {key}"), format!("is not JSON: {e}")))
}

/// `value` at the slash-separated `path` of the training configuration.
fn at<'a>(config: &'a Value, path: &str) -> Result<&'a Value, Problem> {
    path.split('/').try_fold(config, |v, k| v.get(k)).ok_or_else(|| {
        (
            "ONNX metadata experiment_config".to_owned(),
            format!("has no {path}"),
        )
    })
}

fn numbers(v: &Value, place: &str, n: usize) -> Result<Vec<f64>, Problem> {
    let list: Option<Vec<f64>> = v
        .as_array()
        .and_then(|a| a.iter().map(Value::as_f64).collect::<Option<Vec<_>>>());
    match list {
        Some(l) if l.len() == n && l.iter().all(|x| x.is_finite()) => Ok(l),
        Some(l) if l.len() != n => Err((place.to_owned(), format!("{} values for {n} joints", l.len()))),
        _ => Err((place.to_owned(), format!("{v} is not a list of finite numbers"))),
    }
}

/// A yes/no of the training configuration, absent = no; anything but true or false is refused
/// (a "yes" read as false would silently change the actions).
fn flag(config: &Value, path: &str) -> Result<bool, Problem> {
    match path.split('/').try_fold(config, |v, k| v.get(k)) {
        None | Some(Value::Null) => Ok(false),
        Some(Value::Bool(b)) => Ok(*b),
        Some(v) => Err((
            format!("ONNX metadata experiment_config {path}"),
            format!("{v} is not true or false"),
        )),
    }
}

fn number(v: &Value, place: &str) -> Result<f64, Problem> {
    v.as_f64()
        .filter(|x| x.is_finite())
        .ok_or_else(|| (place.to_owned(), format!("{v} is not a finite number")))
}

/// The term a holosoma observation function stands for.
fn term_of(func: &str) -> Result<Term, UnknownFunction> {
    let name = func.rsplit(':').next().unwrap_or(func);
    let s = Shaping::default();
    Ok(match name {
        "motion_command" => Term::MotionCommand(s),
        "motion_ref_ori_b" => Term::MotionAnchorOriB(s),
        "motion_ref_pos_b" => Term::MotionAnchorPosB(s),
        "base_ang_vel" => Term::BaseAngVel(s),
        "base_lin_vel" => Term::BaseLinVel(s),
        "projected_gravity" => Term::ProjectedGravity(s),
        "dof_pos" => Term::JointPos {
            relative: true,
            shaping: s,
        },
        "dof_vel" => Term::JointVel(s),
        "actions" => Term::LastActions { k: 1, shaping: s },
        _ => return Err(UnknownFunction(func.to_owned())),
    })
}

/// A holosoma observation function robodeploy does not build.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error(
    "holosoma observation function {0:?} ({name}) is not one robodeploy builds; write a manifest with its terms",
    name = .0.rsplit(':').next().unwrap_or(.0)
)]
struct UnknownFunction(String);

/// The `actor_obs` group as the deployment code concatenates it: terms sorted by name.
fn observation(config: &Value) -> Result<Vec<Term>, Problem> {
    let group = at(config, "observation/groups/actor_obs")?;
    let terms = group.get("terms").and_then(Value::as_object).ok_or((
        "ONNX metadata experiment_config".to_owned(),
        "observation/groups/actor_obs has no terms".to_owned(),
    ))?;
    let history = match group.get("history_length") {
        None => 1,
        Some(h) => match h.as_u64() {
            Some(h @ 0..=64) => (h as usize).max(1),
            _ => {
                return Err((
                    "ONNX metadata experiment_config".into(),
                    format!("observation/groups/actor_obs/history_length = {h} is not in [0, 64]"),
                ));
            }
        },
    };
    let mut names: Vec<&String> = terms.keys().collect();
    names.sort();
    let mut out = Vec::with_capacity(names.len() + 1);
    for name in names {
        let place = format!("ONNX metadata experiment_config observation/groups/actor_obs/terms/{name}");
        let spec = &terms[name];
        let func = spec.get("func").and_then(Value::as_str).unwrap_or(name);
        let mut term = term_of(func).map_err(|e| (place.clone(), e.to_string()))?;
        let scale = match spec.get("scale") {
            None | Some(Value::Null) => 1.0,
            Some(v) => number(v, &format!("{place}/scale"))?,
        };
        if spec.get("clip").is_some_and(|c| !c.is_null()) {
            return Err((
                format!("{place}/clip"),
                "a clipped term: robodeploy does not know how holosoma applies it; write a manifest".into(),
            ));
        }
        let sh = super::export::term_shaping(&mut term);
        sh.scale = scale;
        sh.history = history;
        sh.history_order = HistoryOrder::OldestFirst;
        out.push(term);
    }
    out.push(Term::TimeStep(Shaping {
        input: Some(super::export::TIME_STEP_INPUT.to_owned()),
        ..Shaping::default()
    }));
    Ok(out)
}

/// Fills what `m` leaves out from a holosoma export's metadata. A tracking export without its
/// training configuration (holosoma's FastSAC dance export) is refused rather than guessed: the
/// configuration is where its observation layout, standing pose and action scale are.
pub fn fill(m: &mut PolicyManifest, meta: &Metadata<'_>, has_time_step: bool) -> Result<(), Problem> {
    let names: Vec<String> = match json(meta, JOINTS_KEY)? {
        Some(Value::Array(a)) => a
            .iter()
            .map(|v| v.as_str().map(str::to_owned))
            .collect::<Option<_>>()
            .ok_or((
                "ONNX metadata dof_names".to_owned(),
                "is not a list of names".to_owned(),
            ))?,
        _ => return Err(("ONNX metadata dof_names".into(), "is not a list of names".into())),
    };
    if m.joints.is_empty() {
        m.joints = names.clone();
    }
    let n = m.joints.len();
    if m.joints != names {
        return Err((
            "joints".into(),
            "differ from the export's dof_names: a holosoma export's gains and scales follow dof_names, so \
             leave joints out"
                .into(),
        ));
    }
    // Another list of the joints, where an export carries one, must be dof_names' order: the
    // gains and scales follow one order, and two orders leave which one ambiguous.
    if let Some(other) = json(meta, "joint_names")? {
        let other: Option<Vec<&str>> = other
            .as_array()
            .map(|a| a.iter().filter_map(Value::as_str).collect());
        if other.as_ref().is_none_or(|o| *o != names) {
            return Err((
                "ONNX metadata joint_names".into(),
                "differ from dof_names (another order, or other joints): which order the gains and \
                 actions follow is ambiguous"
                    .into(),
            ));
        }
    }
    let kp = match json(meta, "kp")? {
        Some(v) => Some(numbers(&v, "ONNX metadata kp", n)?),
        None => None,
    };
    let config = json(meta, "experiment_config")?;
    if let (Some(kp), Some(stiffness)) = (
        &kp,
        config
            .as_ref()
            .and_then(|c| at(c, "robot/control/stiffness").ok()),
    ) {
        agree_with_stiffness(&m.joints, kp, stiffness)?;
    }
    if m.stiffness.is_none() {
        m.stiffness = kp.clone();
    }
    if m.damping.is_none() {
        m.damping = match json(meta, "kd")? {
            Some(v) => Some(numbers(&v, "ONNX metadata kd", n)?),
            None => None,
        };
    }
    let missing_config = |what: &str| {
        (
            what.to_owned(),
            "missing, and this holosoma export carries no experiment_config metadata (its training \
             configuration, where the observation layout, standing pose and action scale are): give them \
             in a manifest"
                .to_owned(),
        )
    };
    if m.description.is_empty() {
        m.description = match meta.text("wandb_run_path") {
            Some(run) => format!("holosoma export (run {})", run.trim_matches('"')),
            None => "holosoma export".to_owned(),
        };
    }
    if m.action.scale.is_none() {
        let stated = meta
            .text("action_scale")
            .map(|text| stated_action_scale(text, n))
            .transpose()?;
        let configured = match &config {
            Some(c) if stated.is_none() || at(c, "robot/control/action_scale").is_ok() => {
                Some(configured_action_scale(c, kp.as_deref(), &m.joints)?)
            }
            _ => None,
        };
        m.action.scale = Some(match (stated, configured) {
            (Some(stated), Some(configured)) => {
                if let Some(i) = (0..n).find(|&i| {
                    let (a, b) = (stated.of(i), configured.of(i));
                    (a - b).abs() > 1e-6 * a.abs().max(b.abs())
                }) {
                    return Err((
                        "ONNX metadata action_scale".into(),
                        format!(
                            "{} for {} contradicts the experiment_config's {} (robot/control): which one \
                             the policy was trained with is not known",
                            stated.of(i),
                            m.joints[i],
                            configured.of(i)
                        ),
                    ));
                }
                stated
            }
            (Some(scale), None) | (None, Some(scale)) => scale,
            (None, None) => return Err(missing_config("action.scale")),
        });
    }
    if m.action.clip.is_none()
        && let Some(config) = &config
        && let Ok(control) = at(config, "robot/control")
        && flag(config, "robot/control/clip_actions")?
    {
        m.action.clip = Some(number(
            at(control, "action_clip_value")?,
            "experiment_config robot/control/action_clip_value",
        )?);
    }
    if m.default_pose.is_none() {
        let config = config.as_ref().ok_or_else(|| missing_config("default_pose"))?;
        let angles = at(config, "robot/init_state/default_joint_angles")?;
        let pose = m
            .joints
            .iter()
            .map(|j| {
                angles.get(j).and_then(Value::as_f64).ok_or_else(|| {
                    (
                        "ONNX metadata experiment_config".to_owned(),
                        format!("robot/init_state/default_joint_angles has no {j}"),
                    )
                })
            })
            .collect::<Result<Vec<_>, _>>()?;
        m.default_pose = Some(pose);
    }
    if m.observation.is_empty() && m.block.is_empty() {
        let config = config.as_ref().ok_or_else(|| missing_config("observation"))?;
        if !has_time_step {
            return Err((
                "observation".into(),
                "a holosoma export with a training configuration but no time_step input: robodeploy reads \
                 holosoma's whole-body-tracking exports; write a manifest for this one"
                    .into(),
            ));
        }
        m.observation = observation(config)?;
    }
    if m.anchor_body.is_none()
        && let Some(config) = &config
    {
        let refs = at(
            config,
            "command/setup_terms/motion_command/params/motion_config/body_name_ref",
        )?;
        m.anchor_body = refs
            .as_array()
            .and_then(|a| a.first())
            .and_then(Value::as_str)
            .map(str::to_owned);
    }
    if m.motion_bodies.is_empty()
        && let Some(a) = &m.anchor_body
    {
        // The export returns the anchor's pose only.
        m.motion_bodies = vec![a.clone()];
    }
    Ok(())
}

/// The metadata's own `action_scale`: JSON (a number or a list), or comma-separated numbers.
fn stated_action_scale(text: &str, n: usize) -> Result<ActionScale, Problem> {
    match serde_json::from_str::<Value>(text) {
        Ok(v @ Value::Array(_)) => Ok(ActionScale::PerJoint(numbers(
            &v,
            "ONNX metadata action_scale",
            n,
        )?)),
        Ok(v) => Ok(ActionScale::One(number(&v, "ONNX metadata action_scale")?)),
        Err(_) => {
            let v: Result<Vec<f64>, _> = text.split(',').map(|t| t.trim().parse::<f64>()).collect();
            match v {
                Ok(v) if v.len() == n => Ok(ActionScale::PerJoint(v)),
                Ok(v) if v.len() == 1 => Ok(ActionScale::One(v[0])),
                _ => Err((
                    "ONNX metadata action_scale".into(),
                    format!("{text:?} is not 1 or {n} numbers"),
                )),
            }
        }
    }
}

/// The action scale the training configuration gives: `robot/control/action_scale`, per joint
/// × effort limit / kp where `action_scales_by_effort_limit_over_p_gain` says so.
fn configured_action_scale(
    config: &Value,
    kp: Option<&[f64]>,
    joints: &[String],
) -> Result<ActionScale, Problem> {
    let n = joints.len();
    let control = at(config, "robot/control")?;
    let scale = number(
        at(control, "action_scale")?,
        "experiment_config robot/control/action_scale",
    )?;
    at(control, "action_scales_by_effort_limit_over_p_gain")?;
    if !flag(config, "robot/control/action_scales_by_effort_limit_over_p_gain")? {
        return Ok(ActionScale::One(scale));
    }
    let effort = numbers(
        at(config, "robot/dof_effort_limit_list")?,
        "ONNX metadata experiment_config robot/dof_effort_limit_list",
        n,
    )?;
    let kp = kp.ok_or(("ONNX metadata kp".to_owned(), "missing".to_owned()))?;
    if let Some(i) = kp.iter().position(|k| *k <= 0.0) {
        return Err((
            "ONNX metadata kp".into(),
            format!(
                "{} of {} is not positive: no action scale effort / kp",
                kp[i], joints[i]
            ),
        ));
    }
    Ok(ActionScale::PerJoint(
        effort.iter().zip(kp).map(|(e, k)| scale * e / k).collect(),
    ))
}

/// The metadata's kp against the training configuration's `robot/control/stiffness` (keys are
/// parts of joint names, as holosoma matches them: the longest key a joint's name contains).
fn agree_with_stiffness(joints: &[String], kp: &[f64], stiffness: &Value) -> Result<(), Problem> {
    let Some(table) = stiffness.as_object() else {
        return Ok(());
    };
    for (joint, &k) in joints.iter().zip(kp) {
        let Some((key, value)) = table
            .iter()
            .filter(|(key, _)| joint.contains(key.as_str()))
            .max_by_key(|(key, _)| key.len())
        else {
            continue;
        };
        let Some(value) = value.as_f64() else { continue };
        if (value - k).abs() > 1e-6 * value.abs().max(k.abs()) {
            return Err((
                "ONNX metadata kp".into(),
                format!(
                    "{k} for {joint} contradicts the experiment_config's stiffness {value} (robot/control/stiffness \
                     {key:?}): which gains the policy was trained with is not known"
                ),
            ));
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use std::collections::BTreeMap;

    use super::*;

    fn meta(config: Option<&str>) -> BTreeMap<String, String> {
        let mut m = BTreeMap::new();
        m.insert("dof_names".into(), r#"["hip", "knee"]"#.into());
        m.insert("kp".into(), "[40.0, 100.0]".into());
        m.insert("kd".into(), "[2.0, 5.0]".into());
        if let Some(c) = config {
            m.insert("experiment_config".into(), c.into());
        }
        m
    }

    const CONFIG: &str = r#"{
        "robot": {
            "dof_effort_limit_list": [88.0, 139.0],
            "init_state": {"default_joint_angles": {"knee": 0.6, "hip": -0.3}},
            "control": {"action_scale": 0.25, "action_scales_by_effort_limit_over_p_gain": true,
                        "clip_actions": true, "action_clip_value": 100.0}
        },
        "observation": {"groups": {"actor_obs": {
            "history_length": 1,
            "terms": {
                "motion_command": {"func": "x.wbt:motion_command", "scale": 1.0, "clip": null},
                "motion_ref_ori_b": {"func": "x.wbt:motion_ref_ori_b", "scale": 1.0, "clip": null},
                "base_ang_vel": {"func": "x.wbt:base_ang_vel", "scale": 0.5, "clip": null},
                "dof_pos": {"func": "x.wbt:dof_pos", "scale": 1.0, "clip": null},
                "dof_vel": {"func": "x.wbt:dof_vel", "scale": 0.05, "clip": null},
                "actions": {"func": "x.wbt:actions", "scale": 1.0, "clip": null}
            }
        }}},
        "command": {"setup_terms": {"motion_command": {"params": {"motion_config": {"body_name_ref": ["torso_link"]}}}}}
    }"#;

    fn filled(config: Option<&str>) -> Result<PolicyManifest, Problem> {
        let m = meta(config);
        let mut manifest = PolicyManifest::for_onnx("p.onnx".into());
        fill(&mut manifest, &Metadata(&m), true).map(|()| manifest)
    }

    #[test]
    fn the_observation_is_the_actor_terms_sorted_by_name_with_their_scales() {
        let m = filled(Some(CONFIG)).unwrap();
        let names: Vec<_> = m.observation.iter().map(Term::name).collect();
        assert_eq!(
            names,
            [
                "last_actions",
                "base_ang_vel",
                "joint_pos",
                "joint_vel",
                "motion_command",
                "motion_anchor_ori_b",
                "time_step"
            ]
        );
        assert_eq!(m.observation[1].shaping().scale, 0.5);
        assert_eq!(m.observation[3].shaping().scale, 0.05);
        assert_eq!(m.observation[6].shaping().input.as_deref(), Some("time_step"));
    }

    #[test]
    fn the_action_scale_is_a_quarter_of_effort_over_stiffness_per_joint() {
        let m = filled(Some(CONFIG)).unwrap();
        let Some(ActionScale::PerJoint(s)) = &m.action.scale else {
            panic!("{:?}", m.action.scale);
        };
        assert!((s[0] - 0.25 * 88.0 / 40.0).abs() < 1e-12 && (s[1] - 0.25 * 139.0 / 100.0).abs() < 1e-12);
        assert_eq!(m.action.clip, Some(100.0));
        // The standing pose by name, in the export's joint order.
        assert_eq!(m.default_pose, Some(vec![-0.3, 0.6]));
        assert_eq!(
            (m.stiffness.clone(), m.damping.clone()),
            (Some(vec![40.0, 100.0]), Some(vec![2.0, 5.0]))
        );
        assert_eq!(m.anchor_body.as_deref(), Some("torso_link"));
        assert_eq!(m.motion_bodies, ["torso_link"]);
    }

    #[test]
    fn an_export_without_its_configuration_is_refused_naming_what_is_missing() {
        let (place, message) = filled(None).unwrap_err();
        assert_eq!(place, "action.scale");
        assert!(message.contains("no experiment_config"), "{message}");
        // With its own action_scale it still lacks the standing pose.
        let mut m = meta(None);
        m.insert("action_scale".into(), "0.25".into());
        let mut manifest = PolicyManifest::for_onnx("p.onnx".into());
        let (place, _) = fill(&mut manifest, &Metadata(&m), true).unwrap_err();
        assert_eq!(place, "default_pose");
    }

    #[test]
    fn bad_metadata_is_named_by_key() {
        let mut m = meta(Some(CONFIG));
        m.insert("kp".into(), "[40.0]".into());
        let mut manifest = PolicyManifest::for_onnx("p.onnx".into());
        let (place, message) = fill(&mut manifest, &Metadata(&m), true).unwrap_err();
        assert_eq!(
            (place.as_str(), message.as_str()),
            ("ONNX metadata kp", "1 values for 2 joints")
        );
        let config = CONFIG.replace(
            "\"clip\": null},\n                \"dof_vel\"",
            "\"clip\": 5.0},\n                \"dof_vel\"",
        );
        let (place, _) = filled(Some(&config)).unwrap_err();
        assert!(place.ends_with("terms/dof_pos/clip"), "{place}");
        // A yes/no that is neither is refused, not read as no.
        let config = CONFIG.replace(
            "\"action_scales_by_effort_limit_over_p_gain\": true",
            "\"action_scales_by_effort_limit_over_p_gain\": \"yes\"",
        );
        assert_ne!(config, CONFIG);
        let (place, message) = filled(Some(&config)).unwrap_err();
        assert_eq!(
            (place.as_str(), message.as_str()),
            (
                "ONNX metadata experiment_config robot/control/action_scales_by_effort_limit_over_p_gain",
                "\"yes\" is not true or false"
            )
        );
        let config = CONFIG.replace("x.wbt:dof_vel", "x.wbt:feet_air_time");
        let (place, message) = filled(Some(&config)).unwrap_err();
        assert!(
            place.ends_with("terms/dof_vel") && message.contains("feet_air_time"),
            "{place}: {message}"
        );
    }

    #[test]
    fn contradictions_between_the_metadata_and_its_training_configuration_are_refused() {
        // kp against the configuration's stiffness (keys are parts of joint names).
        let with_stiffness = CONFIG.replace(
            r#""control": {"#,
            r#""control": {"stiffness": {"hip": 40.0, "knee": 90.0}, "#,
        );
        let (key, why) = filled(Some(&with_stiffness)).unwrap_err();
        assert_eq!(key, "ONNX metadata kp");
        assert!(
            why.contains("100 for knee contradicts the experiment_config's stiffness 90"),
            "{why}"
        );
        let agreeing = with_stiffness.replace("\"knee\": 90.0", "\"knee\": 100.0");
        assert!(filled(Some(&agreeing)).is_ok());
        // A top-level action_scale against the configured one (0.25 × effort / kp).
        let mut m = meta(Some(CONFIG));
        m.insert("action_scale".into(), "0.25".into());
        let mut manifest = PolicyManifest::for_onnx("p.onnx".into());
        let (key, why) = fill(&mut manifest, &Metadata(&m), true).unwrap_err();
        assert_eq!(key, "ONNX metadata action_scale");
        assert!(
            why.contains("0.25 for hip contradicts the experiment_config's 0.55"),
            "{why}"
        );
        m.insert("action_scale".into(), "[0.55, 0.3475]".into());
        let mut manifest = PolicyManifest::for_onnx("p.onnx".into());
        assert!(fill(&mut manifest, &Metadata(&m), true).is_ok());
        // joint_names in another order than dof_names.
        let mut m = meta(Some(CONFIG));
        m.insert("joint_names".into(), r#"["knee", "hip"]"#.into());
        let mut manifest = PolicyManifest::for_onnx("p.onnx".into());
        let (key, _) = fill(&mut manifest, &Metadata(&m), true).unwrap_err();
        assert_eq!(key, "ONNX metadata joint_names");
        m.insert("joint_names".into(), r#"["hip", "knee"]"#.into());
        let mut manifest = PolicyManifest::for_onnx("p.onnx".into());
        assert!(fill(&mut manifest, &Metadata(&m), true).is_ok());
    }
}
