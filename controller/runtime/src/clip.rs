//! Retargeted clips: loaded from CSV, mapped to the robot's joints by name, resampled to the control
//! rate (linear for joints, slerp for the root rotation), with velocities, and checked against the
//! robot's limits before anything moves.
//!
//! CSV layout: `#` comment lines, then a header `time,root_x,root_y,root_z,root_qw,root_qx,root_qy,
//! root_qz,<joint>,<joint>,…` (joint names as in robot.toml), then one row per frame with `time` in
//! seconds, strictly increasing.
//!
//! NPZ layout (named arrays, as retargeting tools in Python write them): `joint_names` (J strings),
//! `joint_pos` (T × J), `root_pos` (T × 3), `root_quat` (T × 4, w x y z), and either `fps` (a scalar)
//! or `time` (T).

use std::path::{Path, PathBuf};

use robots::Robot;

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
    /// Reads a clip: `.npz` by its named arrays, anything else as CSV.
    pub fn load(path: &Path) -> Result<Self, ClipError> {
        if path.extension().is_some_and(|e| e.eq_ignore_ascii_case("npz")) {
            Self::load_npz(path)
        } else {
            Self::load_csv(path)
        }
    }

    /// Reads an NPZ clip.
    pub fn load_npz(path: &Path) -> Result<Self, ClipError> {
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

    /// Reads a CSV clip.
    pub fn load_csv(path: &Path) -> Result<Self, ClipError> {
        let text = robots::read_text(path).map_err(|message| ClipError {
            file: path.to_path_buf(),
            place: "file".into(),
            message,
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
}

/// Longest clip, s (an hour; longer programs are several clips).
pub const MAX_CLIP_S: f64 = 3600.0;

/// Largest time between two frames of a clip, s.
pub const MAX_FRAME_GAP_S: f64 = 10.0;

/// A clip resampled to the control rate, in the robot's joint order, ready to track.
#[derive(Debug, Clone, PartialEq)]
pub struct Reference {
    /// Joints.
    pub n: usize,
    /// Control rate, Hz.
    pub rate_hz: f64,
    /// Joint positions per tick, `n` per tick.
    pub q: Vec<f64>,
    /// Joint velocities per tick.
    pub qd: Vec<f64>,
    /// Root poses per tick.
    pub root: Vec<[f64; 7]>,
    /// Robot joints the clip does not name (held at the default pose).
    pub held_joints: Vec<String>,
    /// Bodies whose positions [`Self::body_pos`] holds (filled when a policy asks for them).
    pub bodies: Vec<String>,
    /// Body positions per tick relative to the reference root in its heading frame, 3 per body.
    pub body_pos: Vec<f64>,
}

impl Reference {
    /// Ticks.
    pub fn len(&self) -> usize {
        self.root.len()
    }

    /// Whether it has no ticks.
    pub fn is_empty(&self) -> bool {
        self.root.is_empty()
    }

    /// Joint positions at tick `k` (clamped to the last).
    pub fn q_at(&self, k: usize) -> &[f64] {
        let k = k.min(self.len() - 1);
        &self.q[k * self.n..(k + 1) * self.n]
    }

    /// Body positions at tick `k` (clamped to the last), 3 per body of [`Self::bodies`].
    pub fn body_pos_at(&self, k: usize) -> &[f64] {
        let w = 3 * self.bodies.len();
        let k = k.min(self.len() - 1);
        &self.body_pos[k * w..(k + 1) * w]
    }

    /// Joint velocities at tick `k` (clamped to the last).
    pub fn qd_at(&self, k: usize) -> &[f64] {
        let k = k.min(self.len() - 1);
        &self.qd[k * self.n..(k + 1) * self.n]
    }

    /// A one-frame reference holding `q` (robot order) at `root`: the frame a live source
    /// overwrites every tick.
    pub fn hold(q: &[f64], root: [f64; 7], rate_hz: f64) -> Self {
        Self {
            n: q.len(),
            rate_hz,
            q: q.to_vec(),
            qd: vec![0.0; q.len()],
            root: vec![root],
            held_joints: Vec::new(),
            bodies: Vec::new(),
            body_pos: Vec::new(),
        }
    }

    /// Maps `clip` onto `robot` and resamples it to `rate_hz`; refuses a clip the robot cannot
    /// follow, naming the first offending frame.
    pub fn from_clip(clip: &Clip, robot: &Robot, rate_hz: f64) -> Result<Self, ClipError> {
        let err = |place: String, message: String| ClipError {
            file: clip.path.clone(),
            place,
            message,
        };
        let joints = &robot.config.joints;
        let n = joints.len();
        for name in &clip.joints {
            if !joints.iter().any(|j| &j.name == name) {
                return Err(err(
                    "header".into(),
                    format!("column {name:?} is not a joint of robot {}", robot.config.name),
                ));
            }
        }
        let column: Vec<Option<usize>> = joints
            .iter()
            .map(|j| clip.joints.iter().position(|c| c == &j.name))
            .collect();
        let held_joints = joints
            .iter()
            .zip(&column)
            .filter(|(_, c)| c.is_none())
            .map(|(j, _)| j.name.clone())
            .collect();
        let m = clip.joints.len();
        let ticks = (clip.duration() * rate_hz).floor() as usize + 1;
        let mut q = Vec::with_capacity(ticks * n);
        let mut root = Vec::with_capacity(ticks);
        let mut src = 0;
        for k in 0..ticks {
            let t = clip.times[0] + k as f64 / rate_hz;
            while src + 2 < clip.times.len() && clip.times[src + 1] <= t {
                src += 1;
            }
            let (t0, t1) = (clip.times[src], clip.times[src + 1]);
            let a = ((t - t0) / (t1 - t0)).clamp(0.0, 1.0);
            for (j, c) in joints.iter().zip(&column) {
                q.push(match c {
                    Some(c) => clip.q[src * m + c] * (1.0 - a) + clip.q[(src + 1) * m + c] * a,
                    None => j.default_position,
                });
            }
            let (r0, r1) = (clip.root[src], clip.root[src + 1]);
            let quat = robots::spatial::slerp([r0[3], r0[4], r0[5], r0[6]], [r1[3], r1[4], r1[5], r1[6]], a);
            root.push([
                r0[0] * (1.0 - a) + r1[0] * a,
                r0[1] * (1.0 - a) + r1[1] * a,
                r0[2] * (1.0 - a) + r1[2] * a,
                quat[0],
                quat[1],
                quat[2],
                quat[3],
            ]);
        }
        let mut qd = vec![0.0; q.len()];
        for k in 0..ticks {
            let (a, b) = (k.saturating_sub(1), (k + 1).min(ticks - 1));
            let dt = (b - a) as f64 / rate_hz;
            if dt > 0.0 {
                for i in 0..n {
                    qd[k * n + i] = (q[b * n + i] - q[a * n + i]) / dt;
                }
            }
        }
        let reference = Self {
            n,
            rate_hz,
            q,
            qd,
            root,
            held_joints,
            bodies: Vec::new(),
            body_pos: Vec::new(),
        };
        // Can the robot follow it? Positions first (the clearer message), then speeds; each
        // names the first offending frame.
        for k in 0..ticks {
            for (i, j) in joints.iter().enumerate() {
                let x = reference.q[k * n + i];
                let [lo, hi] = j.position_limits;
                if x < lo || x > hi {
                    return Err(err(
                        format!("t = {:.3} s (tick {k})", k as f64 / rate_hz),
                        format!("{} = {x:.3} rad is outside its limits [{lo}, {hi}]", j.name),
                    ));
                }
            }
        }
        for k in 0..ticks {
            for (i, j) in joints.iter().enumerate() {
                let v = reference.qd[k * n + i];
                if v.abs() > j.velocity_limit {
                    return Err(err(
                        format!("t = {:.3} s (tick {k})", k as f64 / rate_hz),
                        format!(
                            "{} moves at {:.2} rad/s, beyond its limit {} rad/s",
                            j.name,
                            v.abs(),
                            j.velocity_limit
                        ),
                    ));
                }
            }
        }
        Ok(reference)
    }
}
