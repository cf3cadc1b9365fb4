//! The contract of a policy as training frameworks export it: BeyondMimic (whole_body_tracking)
//! and mjlab write the joint order, gains, default pose, action scale and observation terms into
//! the ONNX file's metadata properties. This module reads them and fills what a manifest leaves
//! out, so an export runs as it comes out of training.
//!
//! The encoding (facts of the exporters): lists are joined with `,`; numbers are written with 3
//! decimals (`0.250`); a list inside a list (a per-value scale, a clip interval) is written as
//! Python prints it (`[-inf, inf]`), or as `lo;hi` by some versions. Keys: `joint_names`,
//! `joint_stiffness`, `joint_damping`, `default_joint_pos`, `action_scale`, `command_names`,
//! `observation_names`, `observation_history_lengths` (BeyondMimic), `observation_terms_scale`,
//! `observation_terms_clip`, `observation_terms_history_length` (newer mjlab; 0 means none),
//! `anchor_body_name`, `body_names`, `run_path`. holosoma's exports have a convention of their own
//! ([`super::holosoma`]).

use std::collections::BTreeMap;

use crate::contract::{ActionScale, HistoryOrder, PolicyManifest, Shaping, Term};

/// Where a value came from and what is wrong with it: `(place, message)`.
pub type Problem = (String, String);

/// The observation term names a tracking or locomotion export may list, in the frameworks'
/// spelling.
pub const KNOWN_TERMS: [&str; 9] = [
    "command",
    "motion_anchor_pos_b",
    "motion_anchor_ori_b",
    "base_lin_vel",
    "base_ang_vel",
    "projected_gravity",
    "joint_pos",
    "joint_vel",
    "actions",
];

/// The ONNX input a tracking export reads the motion's frame from.
pub const TIME_STEP_INPUT: &str = "time_step";

/// The metadata, with typed readers that name the key in their errors.
#[derive(Debug)]
pub struct Metadata<'a>(pub &'a BTreeMap<String, String>);

/// One element of a metadata list: a number, or a bracketed list / `lo;hi` pair of numbers.
#[derive(Debug, Clone, PartialEq)]
pub enum Element {
    /// A number.
    Number(f64),
    /// Several.
    List(Vec<f64>),
}

fn number(key: &str, text: &str) -> Result<f64, Problem> {
    let t = text.trim();
    let v = match t {
        "inf" | "+inf" => f64::INFINITY,
        "-inf" => f64::NEG_INFINITY,
        _ => t
            .parse::<f64>()
            .map_err(|_| (format!("ONNX metadata {key}"), format!("{t:?} is not a number")))?,
    };
    if v.is_nan() {
        return Err((format!("ONNX metadata {key}"), "NaN is not a value".into()));
    }
    Ok(v)
}

/// Splits `text` at the commas outside brackets.
fn split_top(text: &str) -> Vec<&str> {
    let (mut depth, mut start, mut out) = (0i32, 0, Vec::new());
    for (i, c) in text.char_indices() {
        match c {
            '[' | '(' => depth += 1,
            ']' | ')' => depth -= 1,
            ',' if depth == 0 => {
                out.push(&text[start..i]);
                start = i + 1;
            }
            _ => {}
        }
    }
    out.push(&text[start..]);
    out
}

impl Metadata<'_> {
    /// The raw text of `key`.
    pub fn text(&self, key: &str) -> Option<&str> {
        self.0.get(key).map(String::as_str)
    }

    /// A list of names.
    pub fn names(&self, key: &str) -> Option<Vec<String>> {
        self.text(key).map(|t| {
            t.split(',')
                .map(|s| s.trim().to_owned())
                .filter(|s| !s.is_empty())
                .collect()
        })
    }

    /// A list of finite numbers.
    pub fn numbers(&self, key: &str) -> Result<Option<Vec<f64>>, Problem> {
        let Some(t) = self.text(key) else {
            return Ok(None);
        };
        let values = split_top(t)
            .into_iter()
            .map(|v| number(key, v))
            .collect::<Result<Vec<_>, _>>()?;
        if let Some(v) = values.iter().find(|v| !v.is_finite()) {
            return Err((
                format!("ONNX metadata {key}"),
                format!("{v} is not a finite number"),
            ));
        }
        Ok(Some(values))
    }

    /// A list whose elements may be lists.
    pub fn elements(&self, key: &str) -> Result<Option<Vec<Element>>, Problem> {
        let Some(t) = self.text(key) else {
            return Ok(None);
        };
        split_top(t)
            .into_iter()
            .map(|e| {
                let e = e.trim();
                let inner = e
                    .strip_prefix('[')
                    .and_then(|x| x.strip_suffix(']'))
                    .or_else(|| e.strip_prefix('(').and_then(|x| x.strip_suffix(')')));
                match inner {
                    Some(list) => list
                        .split(',')
                        .map(|v| number(key, v))
                        .collect::<Result<_, _>>()
                        .map(Element::List),
                    None if e.contains(';') => e
                        .split(';')
                        .map(|v| number(key, v))
                        .collect::<Result<_, _>>()
                        .map(Element::List),
                    None => number(key, e).map(Element::Number),
                }
            })
            .collect::<Result<Vec<_>, _>>()
            .map(Some)
    }

    /// A per-term list, checked to have one element per observation term.
    fn per_term(&self, key: &str, terms: usize) -> Result<Option<Vec<Element>>, Problem> {
        let Some(v) = self.elements(key)? else {
            return Ok(None);
        };
        if v.len() != terms {
            return Err((
                format!("ONNX metadata {key}"),
                format!("{} values for {terms} observation_names", v.len()),
            ));
        }
        Ok(Some(v))
    }
}

/// The term an export's observation name stands for (`command` is the reference motion's joint
/// positions and velocities when the export's command is `motion`).
fn term_of(name: &str, commands: &[String]) -> Result<Term, TermNotBuilt> {
    let s = Shaping::default();
    Ok(match name {
        "command" if commands.is_empty() || commands.iter().any(|c| c == "motion") => Term::MotionCommand(s),
        "command" => {
            return Err(TermNotBuilt::CommandNotMotion(commands.join(",")));
        }
        "motion_anchor_pos_b" => Term::MotionAnchorPosB(s),
        "motion_anchor_ori_b" => Term::MotionAnchorOriB(s),
        "base_lin_vel" => Term::BaseLinVel(s),
        "base_ang_vel" => Term::BaseAngVel(s),
        "projected_gravity" => Term::ProjectedGravity(s),
        "joint_pos" | "joint_pos_rel" => Term::JointPos {
            relative: true,
            shaping: s,
        },
        "joint_vel" | "joint_vel_rel" => Term::JointVel(s),
        "actions" | "last_action" => Term::LastActions { k: 1, shaping: s },
        other => return Err(TermNotBuilt::Unknown(other.to_owned())),
    })
}

/// An export's observation name that robodeploy cannot build by itself.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
enum TermNotBuilt {
    /// `command` of a command that is not a motion: its values are the user's to give.
    #[error(
        "the `command` term of command {0:?} is not a motion; give its values in a manifest \
         ([[observation]] term = \"command\", values = […])"
    )]
    CommandNotMotion(String),
    /// A name outside [`KNOWN_TERMS`].
    #[error("unknown observation term {0:?}; robodeploy builds {known} (or write a manifest)", known = KNOWN_TERMS.join(", "))]
    Unknown(String),
}

/// The observation terms the metadata lists, with history, scale and clip where it gives them;
/// a `time_step` term for the model's `time_step` input when it has one.
fn observation(meta: &Metadata<'_>, has_time_step: bool) -> Result<Vec<Term>, Problem> {
    let names = meta.names("observation_names").ok_or((
        "observation".to_owned(),
        "missing, and the ONNX file has no observation_names metadata".to_owned(),
    ))?;
    let commands = meta.names("command_names").unwrap_or_default();
    let n = names.len();
    // BeyondMimic's key and mjlab's: an export carrying both must say the same in both, or
    // which one the training used is unknown.
    let history = match (
        meta.per_term("observation_terms_history_length", n)?,
        meta.per_term("observation_history_lengths", n)?,
    ) {
        (Some(a), Some(b)) if a != b => {
            return Err((
                "ONNX metadata observation_terms_history_length".to_owned(),
                format!(
                    "{a:?} disagrees with observation_history_lengths {b:?}: which history did the training use?"
                ),
            ));
        }
        (Some(h), _) => Some(("observation_terms_history_length", h)),
        (None, h) => h.map(|h| ("observation_history_lengths", h)),
    };
    let scales = meta.per_term("observation_terms_scale", n)?;
    let clips = meta.per_term("observation_terms_clip", n)?;
    let mut terms = Vec::with_capacity(n + 1);
    for (i, name) in names.iter().enumerate() {
        let place = || format!("ONNX metadata observation_names[{i}]");
        let mut term = term_of(name, &commands).map_err(|e| (place(), e.to_string()))?;
        let sh = term_shaping(&mut term);
        if let Some((key, h)) = &history {
            match h[i] {
                Element::Number(v) if v.fract() == 0.0 && (0.0..=64.0).contains(&v) => {
                    // 0 and 1 both mean the current value only.
                    sh.history = (v as usize).max(1);
                    sh.history_order = HistoryOrder::OldestFirst;
                }
                ref e => {
                    return Err((
                        format!("ONNX metadata {key}[{i}] ({name})"),
                        format!("{e:?} is not a history length in [0, 64]"),
                    ));
                }
            }
        }
        if let Some(s) = &scales {
            match &s[i] {
                Element::Number(v) => sh.scale = *v,
                Element::List(v) if v.iter().all(|x| (x - v[0]).abs() < 1e-12) && !v.is_empty() => {
                    sh.scale = v[0];
                }
                Element::List(v) => sh.scales = Some(v.clone()),
            }
        }
        if let Some(c) = &clips {
            let place = format!("ONNX metadata observation_terms_clip[{i}] ({name})");
            match &c[i] {
                Element::List(v) if v.len() == 2 && v[0] == f64::NEG_INFINITY && v[1] == f64::INFINITY => {}
                // The frameworks clip the raw value, then scale it; this loop scales, then clips.
                Element::List(v)
                    if v.len() == 2
                        && v[1].is_finite()
                        && (v[0] + v[1]).abs() < 1e-9
                        && sh.scales.is_none() =>
                {
                    sh.clip = Some(v[1] * sh.scale.abs());
                }
                e => {
                    return Err((
                        place,
                        format!(
                            "{e:?}: robodeploy clips symmetrically, [-c, c] or [-inf, inf], and not \
                             together with a scale per value"
                        ),
                    ));
                }
            }
        }
        terms.push(term);
    }
    if has_time_step {
        terms.push(Term::TimeStep(Shaping {
            input: Some(TIME_STEP_INPUT.to_owned()),
            ..Shaping::default()
        }));
    }
    Ok(terms)
}

/// The shaping of a term an export's metadata can name.
pub(super) fn term_shaping(term: &mut Term) -> &mut Shaping {
    match term {
        Term::MotionCommand(s)
        | Term::MotionAnchorPosB(s)
        | Term::MotionAnchorOriB(s)
        | Term::BaseLinVel(s)
        | Term::BaseAngVel(s)
        | Term::ProjectedGravity(s)
        | Term::JointVel(s) => s,
        Term::JointPos { shaping, .. } | Term::LastActions { shaping, .. } => shaping,
        _ => unreachable!("term_of makes only the terms above"),
    }
}

/// What the model file says of itself: its metadata and input names.
#[derive(Debug, Clone, Default)]
pub struct ModelFacts {
    /// Custom metadata properties.
    pub metadata: BTreeMap<String, String>,
    /// Input names, in the model's order.
    pub inputs: Vec<String>,
}

/// Fills every field `m` leaves out from the export's metadata. `Err((place, message))` names
/// the manifest field or the metadata key.
pub fn fill(m: &mut PolicyManifest, facts: &ModelFacts) -> Result<(), Problem> {
    let meta = Metadata(&facts.metadata);
    let has_time_step = facts.inputs.iter().any(|i| i == TIME_STEP_INPUT);
    if super::holosoma::is_holosoma(&meta) {
        return super::holosoma::fill(m, &meta, has_time_step);
    }
    let joints_from_metadata = m.joints.is_empty();
    if joints_from_metadata {
        m.joints = meta.names("joint_names").ok_or((
            "joints".to_owned(),
            "missing, and the ONNX file has no joint_names metadata".to_owned(),
        ))?;
    }
    let n = m.joints.len();
    let per_joint = |key: &str| -> Result<Option<Vec<f64>>, Problem> {
        let Some(v) = meta.numbers(key)? else {
            return Ok(None);
        };
        if v.len() != n {
            return Err((
                format!("ONNX metadata {key}"),
                format!("{} values for {n} joints ({})", v.len(), m.joints.join(",")),
            ));
        }
        Ok(Some(v))
    };
    if m.action.scale.is_none()
        && let Some(text) = meta.text("action_scale")
    {
        m.action.scale = Some(if split_top(text).len() == 1 {
            ActionScale::One(number("action_scale", text)?)
        } else {
            ActionScale::PerJoint(per_joint("action_scale")?.unwrap_or_default())
        });
    }
    if m.default_pose.is_none() {
        m.default_pose = per_joint("default_joint_pos")?;
    }
    if m.stiffness.is_none() {
        m.stiffness = per_joint("joint_stiffness")?;
    }
    if m.damping.is_none() {
        m.damping = per_joint("joint_damping")?;
    }
    if m.description.is_empty() {
        m.description = match meta.text("run_path") {
            Some(run) => format!("exported policy (run {run})"),
            None => "exported policy".to_owned(),
        };
    }
    if m.observation.is_empty() && m.block.is_empty() {
        m.observation = observation(&meta, has_time_step)?;
    }
    if m.anchor_body.is_none() {
        m.anchor_body = meta.text("anchor_body_name").map(|s| s.trim().to_owned());
    }
    if m.motion_bodies.is_empty() {
        m.motion_bodies = meta.names("body_names").unwrap_or_default();
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn meta(pairs: &[(&str, &str)]) -> BTreeMap<String, String> {
        pairs
            .iter()
            .map(|(k, v)| ((*k).to_owned(), (*v).to_owned()))
            .collect()
    }

    fn manifest() -> PolicyManifest {
        PolicyManifest::for_onnx("p.onnx".into())
    }

    fn facts(pairs: &[(&str, &str)], time_step: bool) -> ModelFacts {
        ModelFacts {
            metadata: meta(pairs),
            inputs: if time_step {
                vec!["obs".into(), "time_step".into()]
            } else {
                vec!["obs".into()]
            },
        }
    }

    const TRACKING: [(&str, &str); 9] = [
        ("joint_names", "a,b"),
        ("joint_stiffness", "40.000,20.500"),
        ("joint_damping", "1.000,0.500"),
        ("default_joint_pos", "0.100,-0.200"),
        ("action_scale", "0.439,0.250"),
        ("command_names", "motion"),
        (
            "observation_names",
            "command,motion_anchor_pos_b,motion_anchor_ori_b,base_lin_vel,base_ang_vel,joint_pos,joint_vel,actions",
        ),
        ("anchor_body_name", "torso_link"),
        ("body_names", "pelvis,torso_link"),
    ];

    #[test]
    fn a_tracking_export_fills_the_whole_contract() {
        let mut m = manifest();
        fill(&mut m, &facts(&TRACKING, true)).unwrap();
        assert_eq!(m.joints, ["a", "b"]);
        assert_eq!(m.stiffness, Some(vec![40.0, 20.5]));
        assert_eq!(m.action.scale, Some(ActionScale::PerJoint(vec![0.439, 0.25])));
        let names: Vec<_> = m.observation.iter().map(Term::name).collect();
        assert_eq!(
            names,
            [
                "motion_command",
                "motion_anchor_pos_b",
                "motion_anchor_ori_b",
                "base_lin_vel",
                "base_ang_vel",
                "joint_pos",
                "joint_vel",
                "last_actions",
                "time_step"
            ]
        );
        assert_eq!(m.observation[8].shaping().input.as_deref(), Some("time_step"));
        assert_eq!(m.anchor_body.as_deref(), Some("torso_link"));
        assert_eq!(m.motion_bodies, ["pelvis", "torso_link"]);
    }

    #[test]
    fn a_manifest_field_wins_over_the_metadata() {
        let mut m = manifest();
        m.action.scale = Some(ActionScale::One(0.5));
        m.stiffness = Some(vec![1.0, 2.0]);
        fill(&mut m, &facts(&TRACKING, true)).unwrap();
        assert_eq!(m.action.scale, Some(ActionScale::One(0.5)));
        assert_eq!(m.stiffness, Some(vec![1.0, 2.0]));
        assert_eq!(m.damping, Some(vec![1.0, 0.5]));
    }

    #[test]
    fn missing_keys_wrong_lengths_and_unknown_terms_are_named() {
        let mut pairs = TRACKING.to_vec();
        pairs.retain(|(k, _)| *k != "joint_names");
        let e = fill(&mut manifest(), &facts(&pairs, true)).unwrap_err();
        assert_eq!(e.0, "joints");
        assert!(e.1.contains("joint_names"), "{e:?}");

        let mut pairs = TRACKING.to_vec();
        pairs[1] = ("joint_stiffness", "40.000");
        let e = fill(&mut manifest(), &facts(&pairs, true)).unwrap_err();
        assert_eq!(e.0, "ONNX metadata joint_stiffness");
        assert!(e.1.contains("1 values for 2 joints"), "{e:?}");

        let mut pairs = TRACKING.to_vec();
        pairs[6] = ("observation_names", "command,feet_air_time");
        let e = fill(&mut manifest(), &facts(&pairs, true)).unwrap_err();
        assert_eq!(e.0, "ONNX metadata observation_names[1]");
        assert!(e.1.contains("\"feet_air_time\""), "{e:?}");

        let mut pairs = TRACKING.to_vec();
        pairs[3] = ("default_joint_pos", "0.100,zero");
        let e = fill(&mut manifest(), &facts(&pairs, true)).unwrap_err();
        assert_eq!(e.0, "ONNX metadata default_joint_pos");

        let mut pairs = TRACKING.to_vec();
        pairs.retain(|(k, _)| *k != "observation_names");
        let e = fill(&mut manifest(), &facts(&pairs, true)).unwrap_err();
        assert!(e.1.contains("observation_names"), "{e:?}");

        let mut pairs = TRACKING.to_vec();
        pairs[5] = ("command_names", "twist");
        let e = fill(&mut manifest(), &facts(&pairs, true)).unwrap_err();
        assert!(e.1.contains("not a motion"), "{e:?}");
    }

    #[test]
    fn newer_exports_give_history_scale_and_clip_per_term() {
        let mut pairs = TRACKING.to_vec();
        pairs[6] = ("observation_names", "base_ang_vel,joint_pos,joint_vel,actions");
        pairs.push(("observation_terms_history_length", "0.000,3.000,3.000,0.000"));
        pairs.push(("observation_terms_scale", "1.000,1.000,0.050,[1.0, 2.0]"));
        pairs.push((
            "observation_terms_clip",
            "[-inf, inf],-5.0;5.0,[-100.0, 100.0],[-inf, inf]",
        ));
        let mut m = manifest();
        fill(&mut m, &facts(&pairs, false)).unwrap();
        let sh: Vec<_> = m.observation.iter().map(Term::shaping).collect();
        assert_eq!(sh.len(), 4, "no time_step input, no time_step term");
        assert_eq!((sh[0].history, sh[1].history), (1, 3));
        assert_eq!(sh[1].history_order, HistoryOrder::OldestFirst);
        assert_eq!(sh[2].scale, 0.05);
        assert_eq!(sh[3].scales, Some(vec![1.0, 2.0]));
        assert_eq!((sh[0].clip, sh[1].clip), (None, Some(5.0)));
        // Clipped raw at ±100, then scaled by 0.05: ±5 after scaling.
        assert!((sh[2].clip.unwrap() - 5.0).abs() < 1e-12);

        pairs.retain(|(k, _)| *k != "observation_terms_clip");
        pairs.push((
            "observation_terms_clip",
            "[-inf, inf],[0.0, 5.0],[-inf, inf],[-inf, inf]",
        ));
        let e = fill(&mut manifest(), &facts(&pairs, false)).unwrap_err();
        assert!(e.0.contains("observation_terms_clip[1] (joint_pos)"), "{e:?}");

        pairs.retain(|(k, _)| *k != "observation_terms_scale");
        pairs.push(("observation_terms_scale", "1.000,1.000"));
        let e = fill(&mut manifest(), &facts(&pairs, false)).unwrap_err();
        assert_eq!(e.0, "ONNX metadata observation_terms_scale");
        assert!(e.1.contains("2 values for 4 observation_names"), "{e:?}");
    }

    #[test]
    fn the_two_frameworks_history_keys_must_agree() {
        let mut pairs = TRACKING.to_vec();
        pairs[6] = ("observation_names", "base_ang_vel,joint_pos,joint_vel,actions");
        pairs.push(("observation_terms_history_length", "0.000,3.000,3.000,0.000"));
        pairs.push(("observation_history_lengths", "0.000,3.000,3.000,0.000"));
        let mut m = manifest();
        fill(&mut m, &facts(&pairs, false)).unwrap();
        assert_eq!(m.observation[1].shaping().history, 3);
        pairs.pop();
        pairs.push(("observation_history_lengths", "0.000,5.000,3.000,0.000"));
        let e = fill(&mut manifest(), &facts(&pairs, false)).unwrap_err();
        assert_eq!(e.0, "ONNX metadata observation_terms_history_length");
        assert!(
            e.1.contains("disagrees with observation_history_lengths"),
            "{e:?}"
        );
    }

    #[test]
    fn a_single_action_scale_is_one_for_every_joint() {
        let mut pairs = TRACKING.to_vec();
        pairs[4] = ("action_scale", "0.25");
        let mut m = manifest();
        fill(&mut m, &facts(&pairs, true)).unwrap();
        assert_eq!(m.action.scale, Some(ActionScale::One(0.25)));
    }
}
