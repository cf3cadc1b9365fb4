//! Retargeted clips as their files hold them: root poses and joint angles per frame, every value
//! checked (the controller maps a clip onto a robot and resamples it).
//!
//! CSV layout: `#` comment lines, then a header `time,root_x,root_y,root_z,root_qw,root_qx,root_qy,
//! root_qz,<joint>,<joint>,…` (joint names as in robot.toml), then one row per frame with `time` in
//! seconds, strictly increasing.
//!
//! NPZ layout (named arrays, as retargeting tools in Python write them): `joint_names` (J strings),
//! `joint_pos` (T × J), `root_pos` (T × 3), `root_quat` (T × 4, w x y z), and either `fps` (a scalar)
//! or `time` (T).
//!
//! Motion files of other tools, described by a sidecar `<name>.motion.toml` beside them
//! ([`MotionSidecar`]: frame rate, joint columns, quaternion order, root body):
//! - BeyondMimic / mjlab motion NPZ: `fps`, `joint_pos` (T × J, no joint names: the sidecar's
//!   `joints`, or the robot's order without one), `body_pos_w` (T × B × 3) and `body_quat_w`
//!   (T × B × 4, w x y z), the root being body `root_body` (0); their velocity arrays are not read
//!   (velocities come from the resampled positions).
//! - Headerless CSV (the LAFAN1 humanoid retargets): per row root x y z, the root quaternion in the
//!   sidecar's `quaternion` order (`"xyzw"` there), then the joints; `fps` and `joints` from the
//!   sidecar.
//! - GMR's motions ([`crate::gmr`]), pickled (`.pkl`) or as an NPZ with `dof_pos` and `root_rot`:
//!   joints in the robot's order unless the sidecar names them.
//!
//! A root that starts upside down is refused: the usual sign of a quaternion read in the wrong order.

use std::path::{Path, PathBuf};

/// A clip as read from its file.
#[derive(Debug, Clone, PartialEq)]
pub struct Clip {
    /// The file.
    pub path: PathBuf,
    /// Joint names of the columns.
    pub joints: Vec<String>,
    /// Frame times, s.
    pub times: Vec<f64>,
    /// Root poses `[x, y, z, w, qx, qy, qz]` per frame.
    pub root: Vec<[f64; 7]>,
    /// Joint angles per frame, `joints.len()` per row.
    pub q: Vec<f64>,
    /// The columns are the robot's joints in its order (a motion file that names none).
    pub robot_order: bool,
}

/// One frame of a motion file: time (s), root position, root quaternion `[w, x, y, z]`, joints.
type Frame<'a> = (f64, [f64; 3], [f64; 4], &'a [f64]);

/// What a `<name>.motion.toml` says about the motion file beside it.
#[derive(Debug, Clone, PartialEq, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MotionSidecar {
    /// Frames per second (headerless CSV: required; 1–1000).
    pub fps: Option<f64>,
    /// Joint names of the joint columns, in order (robot.toml names); none: the robot's order.
    pub joints: Option<Vec<String>>,
    /// Order of the root quaternion in the file (headerless CSV: required).
    pub quaternion: Option<QuaternionOrder>,
    /// Index of the root body in a motion NPZ's body arrays.
    #[serde(default)]
    pub root_body: usize,
}

/// Order of a quaternion's components in a file.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum QuaternionOrder {
    /// Scalar first (MuJoCo, Isaac Lab, this project).
    Wxyz,
    /// Scalar last (SciPy, Unity, the LAFAN1 retargets).
    Xyzw,
}

/// The sidecar of motion file `path`: `<stem>.motion.toml` beside it.
pub fn sidecar_path(path: &Path) -> PathBuf {
    path.with_extension("motion.toml")
}

/// A clip that cannot be used: the file, where, what.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{file}: {place}: {message}")]
pub struct ClipError {
    /// The clip file.
    pub file: PathBuf,
    /// Line, column or frame.
    pub place: String,
    /// What is wrong.
    pub message: String,
}

const ROOT_COLUMNS: [&str; 8] = [
    "time", "root_x", "root_y", "root_z", "root_qw", "root_qx", "root_qy", "root_qz",
];

impl Clip {
    /// Reads a clip: `.pkl` as GMR's pickle, `.npz` by its named arrays, anything else as CSV.
    pub fn load(path: &Path) -> Result<Self, ClipError> {
        let sidecar = Self::read_sidecar(path)?;
        if crate::gmr::is_pickle(path) {
            crate::gmr::GmrMotion::load_pickle(path)?.into_clip(path, sidecar.and_then(|s| s.joints))
        } else if path.extension().is_some_and(|e| e.eq_ignore_ascii_case("npz")) {
            Self::load_npz_with(path, sidecar)
        } else if let Some(sidecar) = sidecar {
            Self::load_headerless_csv(path, &sidecar)
        } else {
            Self::load_csv(path)
        }
    }

    /// The sidecar beside `path`, if there is one, checked.
    fn read_sidecar(path: &Path) -> Result<Option<MotionSidecar>, ClipError> {
        let side = sidecar_path(path);
        if !side.exists() {
            return Ok(None);
        }
        let err = |place: &str, message: String| ClipError {
            file: side.clone(),
            place: place.to_owned(),
            message,
        };
        let text = robots::read_text(&side).map_err(|m| err("file", m.to_string()))?;
        MotionSidecar::parse(&side, &text).map(Some)
    }
}

impl MotionSidecar {
    /// Parses and checks a sidecar's text, as if read from `path`.
    pub fn parse(path: &Path, text: &str) -> Result<Self, ClipError> {
        let err = |place: &str, message: String| ClipError {
            file: path.to_path_buf(),
            place: place.to_owned(),
            message,
        };
        let s: MotionSidecar = toml::from_str(text).map_err(|e| err("toml", e.message().to_owned()))?;
        if let Some(fps) = s.fps
            && !(fps.is_finite() && (1.0..=1000.0).contains(&fps))
        {
            return Err(err("fps", format!("{} is outside [1, 1000]", robots::num(fps))));
        }
        if let Some(joints) = &s.joints {
            if joints.is_empty() {
                return Err(err("joints", "names no joint".into()));
            }
            if let Some((k, name)) = joints.iter().enumerate().find(|(k, n)| joints[..*k].contains(n)) {
                return Err(err(&format!("joints[{k}]"), format!("{name:?} is named twice")));
            }
        }
        Ok(s)
    }
}

impl Clip {
    /// Joint names for `count` columns: the sidecar's, or numbered names (`joint 0`, …) marking
    /// columns that are the robot's joints in its order (named at mapping, see `robot_order`).
    fn column_names(
        path: &Path,
        sidecar: Option<&MotionSidecar>,
        count: usize,
    ) -> Result<(Vec<String>, bool), ClipError> {
        match sidecar.and_then(|s| s.joints.clone()) {
            Some(names) if names.len() == count => Ok((names, false)),
            Some(names) => Err(ClipError {
                file: sidecar_path(path),
                place: "joints".into(),
                message: format!(
                    "names {} joints; the motion file has {count} joint columns",
                    names.len()
                ),
            }),
            None => Ok(((0..count).map(|k| format!("joint {k}")).collect(), true)),
        }
    }

    /// A headerless CSV described by its sidecar.
    fn load_headerless_csv(path: &Path, sidecar: &MotionSidecar) -> Result<Self, ClipError> {
        let text = robots::read_text(path).map_err(|message| ClipError {
            file: path.to_path_buf(),
            place: "file".into(),
            message: message.to_string(),
        })?;
        Self::parse_headerless_csv(path, &text, sidecar)
    }

    /// Parses a headerless motion CSV's text (as if read from `path`) as its sidecar describes.
    pub fn parse_headerless_csv(path: &Path, text: &str, sidecar: &MotionSidecar) -> Result<Self, ClipError> {
        let side_err = |place: &str, message: &str| ClipError {
            file: sidecar_path(path),
            place: place.to_owned(),
            message: message.to_owned(),
        };
        let fps = sidecar
            .fps
            .ok_or_else(|| side_err("fps", "a headerless CSV needs its frame rate"))?;
        let order = sidecar.quaternion.ok_or_else(|| {
            side_err(
                "quaternion",
                "a headerless CSV needs its quaternion order (\"xyzw\" or \"wxyz\")",
            )
        })?;
        let mut rows = Vec::new();
        let mut width = None;
        for (n, line) in text
            .lines()
            .enumerate()
            .filter(|(_, l)| !l.trim().is_empty() && !l.starts_with('#'))
        {
            let row: Result<Vec<f64>, _> = line.split(',').map(|c| c.trim().parse::<f64>()).collect();
            let row = row.map_err(|e| ClipError {
                file: path.to_path_buf(),
                place: format!("line {}", n + 1),
                message: format!("{e} (a headerless motion CSV holds numbers only)"),
            })?;
            if *width.get_or_insert(row.len()) != row.len() || row.len() <= 7 {
                return Err(ClipError {
                    file: path.to_path_buf(),
                    place: format!("line {}", n + 1),
                    message: format!(
                        "{} values; rows hold root x y z, a quaternion, then the same joints",
                        row.len()
                    ),
                });
            }
            rows.push(row);
        }
        let joints = width.unwrap_or(0).saturating_sub(7);
        let (names, robot_order) = Self::column_names(path, Some(sidecar), joints)?;
        let mut frames = Vec::with_capacity(rows.len());
        for (k, r) in rows.iter().enumerate() {
            let quat = match order {
                QuaternionOrder::Wxyz => [r[3], r[4], r[5], r[6]],
                QuaternionOrder::Xyzw => [r[6], r[3], r[4], r[5]],
            };
            frames.push((k as f64 / fps, [r[0], r[1], r[2]], quat, &r[7..]));
        }
        Self::from_frames(path, names, robot_order, &frames)
    }

    /// Builds a clip from `(time, root position, root quaternion w x y z, joints)` frames through
    /// the CSV checks, refusing a root that starts upside down.
    pub(crate) fn from_frames(
        path: &Path,
        joints: Vec<String>,
        robot_order: bool,
        frames: &[Frame<'_>],
    ) -> Result<Self, ClipError> {
        let mut text = String::new();
        text.push_str("time,root_x,root_y,root_z,root_qw,root_qx,root_qy,root_qz,");
        text.push_str(&joints.join(","));
        text.push('\n');
        for (t, pos, quat, q) in frames {
            let row: Vec<String> = std::iter::once(*t)
                .chain(pos.iter().copied())
                .chain(quat.iter().copied())
                .chain(q.iter().copied())
                .map(|x| format!("{x:?}"))
                .collect();
            text.push_str(&row.join(","));
            text.push('\n');
        }
        let mut clip = Self::parse_csv(path, &text)?;
        clip.robot_order = robot_order;
        if let Some(message) = upside_down(clip.root[0]) {
            return Err(ClipError {
                file: path.to_path_buf(),
                place: "frame 0".into(),
                message,
            });
        }
        Ok(clip)
    }

    /// Reads an NPZ clip (with the sidecar beside it, if any).
    pub fn load_npz(path: &Path) -> Result<Self, ClipError> {
        Self::load_npz_with(path, Self::read_sidecar(path)?)
    }

    fn load_npz_with(path: &Path, sidecar: Option<MotionSidecar>) -> Result<Self, ClipError> {
        use crate::npy::NpyArray;
        let err = |place: &str, message: String| ClipError {
            file: path.to_path_buf(),
            place: place.to_owned(),
            message,
        };
        let arrays = crate::npy::read_npz(path).map_err(|e| err("file", e.message))?;
        let numbers = |name: &str, cols: Option<usize>| -> Result<(usize, Vec<f64>), ClipError> {
            match arrays.get(name) {
                Some(NpyArray::Numbers { shape, data }) => match (shape.as_slice(), cols) {
                    ([t, c], Some(want)) if *c == want => Ok((*t, data.clone())),
                    ([t], None) => Ok((*t, data.clone())),
                    ([], None) => Ok((1, data.clone())),
                    (s, _) => Err(err(
                        name,
                        format!(
                            "has shape {s:?}, expected {}",
                            cols.map_or("(T,)".into(), |c| format!("(T, {c})"))
                        ),
                    )),
                },
                Some(NpyArray::Strings { .. }) => Err(err(name, "holds strings, expected numbers".into())),
                None => Err(err(
                    name,
                    "array missing (need joint_names, joint_pos, root_pos, root_quat, fps or time)".into(),
                )),
            }
        };
        if arrays.contains_key("body_pos_w") && !arrays.contains_key("root_pos") {
            return Self::beyondmimic_npz(path, &arrays, sidecar.as_ref());
        }
        if arrays.contains_key("dof_pos") && arrays.contains_key("root_rot") {
            return crate::gmr::GmrMotion::from_npz(path, &arrays)?
                .into_clip(path, sidecar.and_then(|s| s.joints));
        }
        let joints = match arrays.get("joint_names") {
            Some(NpyArray::Strings { data, .. }) => data.clone(),
            Some(_) => return Err(err("joint_names", "is not a string array".into())),
            None => return Err(err("joint_names", "array missing".into())),
        };
        let (t, q) = numbers("joint_pos", Some(joints.len()))?;
        let (t_pos, pos) = numbers("root_pos", Some(3))?;
        let (t_quat, quat) = numbers("root_quat", Some(4))?;
        if t_pos != t || t_quat != t {
            return Err(err(
                "root_pos",
                format!("joint_pos has {t} frames, root_pos {t_pos}, root_quat {t_quat}"),
            ));
        }
        let times: Vec<f64> = if arrays.contains_key("time") {
            let (tt, times) = numbers("time", None)?;
            if tt != t {
                return Err(err("time", format!("{tt} values for {t} frames")));
            }
            times
        } else {
            let (_, fps) = numbers("fps", None)?;
            let fps = fps.first().copied().unwrap_or(0.0);
            if !(fps.is_finite() && fps > 0.0) {
                return Err(err("fps", format!("{fps} is not a frame rate")));
            }
            (0..t).map(|k| k as f64 / fps).collect()
        };
        // The CSV reader checks every row; reuse it through the same text layout.
        let mut text = String::new();
        text.push_str("time,root_x,root_y,root_z,root_qw,root_qx,root_qy,root_qz,");
        text.push_str(&joints.join(","));
        text.push('\n');
        for k in 0..t {
            let row: Vec<String> = std::iter::once(times[k])
                .chain(pos[3 * k..3 * k + 3].iter().copied())
                .chain(quat[4 * k..4 * k + 4].iter().copied())
                .chain(q[joints.len() * k..joints.len() * (k + 1)].iter().copied())
                .map(|x| format!("{x:?}"))
                .collect();
            text.push_str(&row.join(","));
            text.push('\n');
        }
        Self::parse_csv(path, &text)
    }

    /// A BeyondMimic / mjlab motion NPZ: joints from `joint_pos`, the root from body `root_body`.
    fn beyondmimic_npz(
        path: &Path,
        arrays: &std::collections::BTreeMap<String, crate::npy::NpyArray>,
        sidecar: Option<&MotionSidecar>,
    ) -> Result<Self, ClipError> {
        use crate::npy::NpyArray;
        let err = |place: &str, message: String| ClipError {
            file: path.to_path_buf(),
            place: place.to_owned(),
            message,
        };
        let numbers = |name: &str| match arrays.get(name) {
            Some(NpyArray::Numbers { shape, data }) => Ok((shape.as_slice(), data.as_slice())),
            Some(NpyArray::Strings { .. }) => Err(err(name, "holds strings, expected numbers".into())),
            None => Err(err(
                name,
                "array missing (a motion NPZ has fps, joint_pos, body_pos_w, body_quat_w)".into(),
            )),
        };
        let fps = match numbers("fps")? {
            ([] | [1], [fps]) => *fps,
            (s, _) => return Err(err("fps", format!("has shape {s:?}, expected one value"))),
        };
        if !(fps.is_finite() && (1.0..=1000.0).contains(&fps)) {
            return Err(err("fps", format!("{} is outside [1, 1000]", robots::num(fps))));
        }
        // The file's own rate decides; a sidecar that says another would play it at the wrong
        // speed if it were believed, and is wrong if not.
        if let Some(said) = sidecar.and_then(|s| s.fps)
            && (said - fps).abs() > 1e-6 * fps
        {
            return Err(ClipError {
                file: sidecar_path(path),
                place: "fps".into(),
                message: format!(
                    "{} disagrees with the NPZ's own fps = {} (leave it out for a motion NPZ)",
                    robots::num(said),
                    robots::num(fps)
                ),
            });
        }
        let (t, j, q) = match numbers("joint_pos")? {
            (&[t, j], q) if j > 0 => (t, j, q),
            (s, _) => return Err(err("joint_pos", format!("has shape {s:?}, expected (T, J)"))),
        };
        let root = sidecar.map_or(0, |s| s.root_body);
        let body = |name: &str, width: usize| match numbers(name)? {
            (&[tt, b, w], data) if tt == t && w == width && root < b => Ok((b, data)),
            (&[tt, b, w], _) if tt == t && w == width => Err(ClipError {
                file: sidecar.map_or(path.to_path_buf(), |_| sidecar_path(path)),
                place: "root_body".into(),
                message: format!("body {root} of {b} in {name}"),
            }),
            (s, _) => Err(err(name, format!("has shape {s:?}, expected ({t}, B, {width})"))),
        };
        let (b, pos) = body("body_pos_w", 3)?;
        let (_, quat) = body("body_quat_w", 4)?;
        let (names, robot_order) = Self::column_names(path, sidecar, j)?;
        let frames: Vec<_> = (0..t)
            .map(|k| {
                let p = (k * b + root) * 3;
                let r = (k * b + root) * 4;
                (
                    k as f64 / fps,
                    [pos[p], pos[p + 1], pos[p + 2]],
                    [quat[r], quat[r + 1], quat[r + 2], quat[r + 3]],
                    &q[k * j..(k + 1) * j],
                )
            })
            .collect();
        Self::from_frames(path, names, robot_order, &frames)
    }

    /// Reads a CSV clip.
    pub fn load_csv(path: &Path) -> Result<Self, ClipError> {
        let text = robots::read_text(path).map_err(|message| ClipError {
            file: path.to_path_buf(),
            place: "file".into(),
            message: message.to_string(),
        })?;
        Self::parse_csv(path, &text)
    }

    /// Parses CSV text as if read from `path`.
    pub fn parse_csv(path: &Path, text: &str) -> Result<Self, ClipError> {
        let err = |place: String, message: String| ClipError {
            file: path.to_path_buf(),
            place,
            message,
        };
        let mut lines = text
            .lines()
            .enumerate()
            .filter(|(_, l)| !l.trim().is_empty() && !l.starts_with('#'));
        let (header_line, header) = lines
            .next()
            .ok_or_else(|| err("file".into(), "no header line".into()))?;
        let cols: Vec<&str> = header.split(',').map(str::trim).collect();
        if cols.len() <= ROOT_COLUMNS.len() || cols[..ROOT_COLUMNS.len()] != ROOT_COLUMNS {
            return Err(err(
                format!("line {}", header_line + 1),
                format!(
                    "header must start with {} and name at least one joint",
                    ROOT_COLUMNS.join(",")
                ),
            ));
        }
        let joints: Vec<String> = cols[ROOT_COLUMNS.len()..]
            .iter()
            .map(|s| (*s).to_owned())
            .collect();
        if let Some((k, name)) = joints
            .iter()
            .enumerate()
            .find(|(k, name)| joints[..*k].contains(name))
        {
            return Err(err(
                format!("line {}", header_line + 1),
                format!(
                    "column {} names joint {name:?} a second time",
                    ROOT_COLUMNS.len() + k + 1
                ),
            ));
        }
        let mut clip = Self {
            path: path.to_path_buf(),
            joints,
            times: Vec::new(),
            root: Vec::new(),
            q: Vec::new(),
            robot_order: false,
        };
        for (i, line) in lines {
            let place = || format!("line {}", i + 1);
            let values: Vec<&str> = line.split(',').map(str::trim).collect();
            if values.len() != cols.len() {
                return Err(err(
                    place(),
                    format!("{} values for {} columns", values.len(), cols.len()),
                ));
            }
            let mut row = Vec::with_capacity(values.len());
            for (v, name) in values.iter().zip(&cols) {
                let x: f64 = v
                    .parse()
                    .map_err(|_| err(place(), format!("{name} = {v:?} is not a number")))?;
                if !x.is_finite() {
                    return Err(err(place(), format!("{name} = {v} is not finite")));
                }
                row.push(x);
            }
            if let Some(&last) = clip.times.last()
                && row[0] <= last
            {
                return Err(err(
                    place(),
                    format!("time {} does not increase (previous {last})", row[0]),
                ));
            }
            if let Some(&last) = clip.times.last()
                && row[0] - last > MAX_FRAME_GAP_S
            {
                return Err(err(
                    place(),
                    format!(
                        "time {} is {} s after the previous frame: frames are at most {MAX_FRAME_GAP_S} s apart",
                        robots::num(row[0]),
                        robots::num(row[0] - last)
                    ),
                ));
            }
            if let Some(&first) = clip.times.first()
                && row[0] - first > MAX_CLIP_S
            {
                return Err(err(
                    place(),
                    format!(
                        "time {}: a clip lasts at most {MAX_CLIP_S} s",
                        robots::num(row[0])
                    ),
                ));
            }
            if let Some((name, x)) = cols[1..4]
                .iter()
                .zip(&row[1..4])
                .find(|(_, x)| x.abs() > MAX_ROOT_M)
            {
                return Err(err(
                    place(),
                    format!("{name} = {} m is outside ±{MAX_ROOT_M} m", robots::num(*x)),
                ));
            }
            if let Some((name, x)) = cols[ROOT_COLUMNS.len()..]
                .iter()
                .zip(&row[ROOT_COLUMNS.len()..])
                .find(|(_, x)| x.abs() > MAX_JOINT_RAD)
            {
                return Err(err(
                    place(),
                    format!("{name} = {} rad is outside ±{MAX_JOINT_RAD} rad", robots::num(*x)),
                ));
            }
            let quat = [row[4], row[5], row[6], row[7]];
            let norm = quat.iter().map(|x| x * x).sum::<f64>().sqrt();
            if (norm - 1.0).abs() > 1e-3 {
                return Err(err(place(), format!("root quaternion has norm {norm:.4}, not 1")));
            }
            clip.times.push(row[0]);
            clip.root.push([
                row[1],
                row[2],
                row[3],
                quat[0] / norm,
                quat[1] / norm,
                quat[2] / norm,
                quat[3] / norm,
            ]);
            clip.q.extend_from_slice(&row[ROOT_COLUMNS.len()..]);
        }
        if clip.times.len() < 2 {
            return Err(err(
                "file".into(),
                format!("{} frames; a clip needs at least 2", clip.times.len()),
            ));
        }
        Ok(clip)
    }

    /// Duration, s.
    pub fn duration(&self) -> f64 {
        self.times[self.times.len() - 1] - self.times[0]
    }

    /// Velocities per frame of the file: central differences over the neighbouring frames
    /// (`numpy.gradient` for evenly spaced frames), one-sided at the ends; the root's rotation on
    /// SO(3) (the rotation vector of `q[i+1]·q[i−1]⁻¹` over their time apart), world frame.
    pub fn frame_velocities(&self) -> FrameVelocities {
        let (frames, m) = (self.times.len(), self.joints.len());
        let mut v = FrameVelocities {
            qd: vec![0.0; frames * m],
            lin: vec![[0.0; 3]; frames],
            ang: vec![[0.0; 3]; frames],
        };
        for i in 0..frames {
            let (a, b) = (i.saturating_sub(1), (i + 1).min(frames - 1));
            let dt = self.times[b] - self.times[a];
            for j in 0..m {
                v.qd[i * m + j] = (self.q[b * m + j] - self.q[a * m + j]) / dt;
            }
            (v.lin[i], v.ang[i]) = root_velocity(self.root[a], self.root[b], dt);
        }
        v
    }
}

/// The root's linear and angular velocities (world frame) at each of `root`'s ticks, `rate_hz`
/// apart: central differences, one-sided at the ends (a single tick: at rest).
pub fn tick_root_velocities(root: &[[f64; 7]], rate_hz: f64) -> (Vec<[f64; 3]>, Vec<[f64; 3]>) {
    let ticks = root.len();
    (0..ticks)
        .map(|k| {
            let (a, b) = (k.saturating_sub(1), (k + 1).min(ticks - 1));
            if b > a {
                root_velocity(root[a], root[b], (b - a) as f64 / rate_hz)
            } else {
                ([0.0; 3], [0.0; 3])
            }
        })
        .unzip()
}

/// A motion file's velocities per frame ([`Clip::frame_velocities`]).
#[derive(Debug, Clone, PartialEq)]
pub struct FrameVelocities {
    /// Joint velocities, the clip's columns per frame, rad/s.
    pub qd: Vec<f64>,
    /// Root linear velocity, world frame, m/s.
    pub lin: Vec<[f64; 3]>,
    /// Root angular velocity, world frame, rad/s.
    pub ang: Vec<[f64; 3]>,
}

/// The root's linear and angular velocity (world frame) between poses `a` and `b` (`[x, y, z,
/// w, qx, qy, qz]`) `dt` s apart: the position's difference, and the rotation vector of
/// `q_b·q_a⁻¹`, over `dt`.
pub fn root_velocity(a: [f64; 7], b: [f64; 7], dt: f64) -> ([f64; 3], [f64; 3]) {
    use robots::spatial::{quat_conj, quat_log, quat_mul, scale, sub};
    let lin = scale(sub([b[0], b[1], b[2]], [a[0], a[1], a[2]]), 1.0 / dt);
    let turn = quat_mul([b[3], b[4], b[5], b[6]], quat_conj([a[3], a[4], a[5], a[6]]));
    (lin, scale(quat_log(turn), 1.0 / dt))
}

/// Longest clip, s (an hour; longer programs are several clips).
pub const MAX_CLIP_S: f64 = 3600.0;

/// How far from the clip's origin its root may go, m: a motion capture volume, or an hour's walk.
pub const MAX_ROOT_M: f64 = 10_000.0;

/// The largest joint angle a clip may hold, rad (the joint's own range is `check`'s business).
pub const MAX_JOINT_RAD: f64 = 100.0;

/// Largest time between two frames of a clip, s.
pub const MAX_FRAME_GAP_S: f64 = 10.0;

/// Why a root pose `[x, y, z, w, qx, qy, qz]` that starts a motion looks wrong: upside down, the
/// usual sign of a quaternion read in the wrong order.
pub fn upside_down(root: [f64; 7]) -> Option<String> {
    let q = [root[3], root[4], root[5], root[6]];
    let up = robots::spatial::quat_rotate(q, [0.0, 0.0, 1.0]);
    (up[2] < 0.0).then(|| {
        format!(
            "the root starts upside down (its z axis points {:.2} down): is the quaternion order right? \
             (read as w x y z: {q:?})",
            -up[2]
        )
    })
}
