//! GMR's retargeted motions (General Motion Retargeting, and the trackers trained on its output):
//! a dict of NumPy arrays, pickled or in an NPZ —
//! `fps` (a number), `root_pos` (N × 3, m, world), `root_rot` (N × 4, quaternion **x y z w**),
//! `dof_pos` (N × D, rad, the robot's joint order), and optionally `local_body_pos` (N × B × 3)
//! with `link_body_list` (B body names). Every field is checked, the file and field named on error.

use std::path::Path;

use crate::clip::{Clip, ClipError, MAX_CLIP_S};
use crate::npy::NpyArray;
use crate::pickle::{self, Value};

/// A GMR motion as the file holds it.
#[derive(Debug, Clone, PartialEq)]
pub struct GmrMotion {
    /// Frames per second.
    pub fps: f64,
    /// Root positions per frame, m.
    pub root_pos: Vec<[f64; 3]>,
    /// Root orientations per frame, `[w, x, y, z]` (turned from the file's x y z w).
    pub root_rot: Vec<[f64; 4]>,
    /// Joint angles, `dofs` per frame.
    pub dof_pos: Vec<f64>,
    /// Joints per frame.
    pub dofs: usize,
    /// The bodies `local_body_pos` holds, if the file lists them.
    pub bodies: Vec<String>,
    /// Whether the file has body positions per frame.
    pub has_body_positions: bool,
}

/// The fields a GMR file holds, for errors.
const FIELDS: &str =
    "fps, root_pos, root_rot (x y z w), dof_pos; optionally local_body_pos and link_body_list";

impl GmrMotion {
    /// Reads a GMR pickle.
    pub fn load_pickle(path: &Path) -> Result<Self, ClipError> {
        let err = |place: &str, message: String| ClipError {
            file: path.to_path_buf(),
            place: place.to_owned(),
            message,
        };
        let bytes = std::fs::read(path).map_err(|e| err("file", e.to_string()))?;
        Self::from_pickle(path, &bytes)
    }

    /// Reads a GMR pickle's `bytes`, as if from `path`.
    pub fn from_pickle(path: &Path, bytes: &[u8]) -> Result<Self, ClipError> {
        let err = |place: &str, message: String| ClipError {
            file: path.to_path_buf(),
            place: place.to_owned(),
            message,
        };
        let v = pickle::read(bytes).map_err(|e| err("pickle", e.to_string()))?;
        if !matches!(v, Value::Dict(_)) {
            return Err(err(
                "pickle",
                format!("holds {}, not a dict of {FIELDS}", v.kind()),
            ));
        }
        let array = |name: &str| -> Result<Option<pickle::Array>, ClipError> {
            v.get(name)
                .map(|x| pickle::ndarray(x).map_err(|m| err(name, m)))
                .transpose()
        };
        let bodies = match v.get("link_body_list") {
            None => Vec::new(),
            Some(Value::List(items) | Value::Tuple(items)) => items
                .iter()
                .map(|i| i.as_str().map(str::to_owned))
                .collect::<Option<Vec<_>>>()
                .ok_or_else(|| err("link_body_list", "holds something that is not a string".into()))?,
            Some(other) => {
                return Err(err(
                    "link_body_list",
                    format!("is {}, not a list of names", other.kind()),
                ));
            }
        };
        Self::check(path, Fields::read(array)?, bodies)
    }

    /// Reads the same fields from an NPZ.
    pub fn from_npz(
        path: &Path,
        arrays: &std::collections::BTreeMap<String, NpyArray>,
    ) -> Result<Self, ClipError> {
        let err = |place: &str, message: String| ClipError {
            file: path.to_path_buf(),
            place: place.to_owned(),
            message,
        };
        let array = |name: &str| -> Result<Option<pickle::Array>, ClipError> {
            match arrays.get(name) {
                None => Ok(None),
                Some(NpyArray::Numbers { shape, data }) => Ok(Some(pickle::Array {
                    shape: shape.clone(),
                    data: data.clone(),
                })),
                Some(NpyArray::Strings { .. }) => Err(err(name, "holds strings, expected numbers".into())),
            }
        };
        let bodies = match arrays.get("link_body_list") {
            None => Vec::new(),
            Some(NpyArray::Strings { data, .. }) => data.clone(),
            Some(NpyArray::Numbers { .. }) => {
                return Err(err("link_body_list", "holds numbers, expected names".into()));
            }
        };
        Self::check(path, Fields::read(array)?, bodies)
    }

    fn check(path: &Path, f: Fields, bodies: Vec<String>) -> Result<Self, ClipError> {
        let err = |place: &str, message: String| ClipError {
            file: path.to_path_buf(),
            place: place.to_owned(),
            message,
        };
        let need = |name: &str, a: Option<pickle::Array>| {
            a.ok_or_else(|| err(name, format!("missing (a GMR motion holds {FIELDS})")))
        };
        let fps = need("fps", f.fps)?;
        let fps = match fps.data.as_slice() {
            [x] if fps.shape.iter().all(|&d| d == 1) => *x,
            _ => {
                return Err(err(
                    "fps",
                    format!("has shape {:?}, expected one number", fps.shape),
                ));
            }
        };
        if !(fps.is_finite() && (1.0..=1000.0).contains(&fps)) {
            return Err(err("fps", format!("{} is outside [1, 1000]", robots::num(fps))));
        }
        let root_pos = need("root_pos", f.root_pos)?;
        let frames = match root_pos.shape.as_slice() {
            [n, 3] => *n,
            s => return Err(err("root_pos", format!("has shape {s:?}, expected (N, 3)"))),
        };
        if frames < 2 {
            return Err(err(
                "root_pos",
                format!("{frames} frames; a motion needs at least 2"),
            ));
        }
        if (frames - 1) as f64 / fps > MAX_CLIP_S {
            return Err(err(
                "root_pos",
                format!("{frames} frames at {fps} fps last longer than {MAX_CLIP_S} s"),
            ));
        }
        let root_rot = need("root_rot", f.root_rot)?;
        if root_rot.shape != [frames, 4] {
            return Err(err(
                "root_rot",
                format!(
                    "has shape {:?}, expected ({frames}, 4) like root_pos",
                    root_rot.shape
                ),
            ));
        }
        let dof_pos = need("dof_pos", f.dof_pos)?;
        let dofs = match dof_pos.shape.as_slice() {
            [n, d] if *n == frames && *d > 0 => *d,
            s => {
                return Err(err(
                    "dof_pos",
                    format!("has shape {s:?}, expected ({frames}, D) like root_pos"),
                ));
            }
        };
        for (name, a, width) in [
            ("root_pos", &root_pos, 3),
            ("root_rot", &root_rot, 4),
            ("dof_pos", &dof_pos, dofs),
        ] {
            if let Some(i) = a.data.iter().position(|x| !x.is_finite()) {
                return Err(err(
                    &format!("{name}[{}][{}]", i / width, i % width),
                    format!("{} is not finite", a.data[i]),
                ));
            }
        }
        let mut rot = Vec::with_capacity(frames);
        for (k, q) in root_rot.data.chunks_exact(4).enumerate() {
            let norm = q.iter().map(|x| x * x).sum::<f64>().sqrt();
            if (norm - 1.0).abs() > 1e-3 {
                return Err(err(
                    &format!("root_rot[{k}]"),
                    format!("{q:?} has norm {norm:.4}, not 1 (a quaternion x y z w)"),
                ));
            }
            // x y z w in the file, w x y z here.
            rot.push([q[3] / norm, q[0] / norm, q[1] / norm, q[2] / norm]);
        }
        let has_body_positions = match f.local_body_pos {
            None => false,
            Some(a) => match a.shape.as_slice() {
                [n, b, 3] if *n == frames && (bodies.is_empty() || *b == bodies.len()) => true,
                s => {
                    return Err(err(
                        "local_body_pos",
                        format!(
                            "has shape {s:?}, expected ({frames}, {}, 3)",
                            if bodies.is_empty() {
                                "B".into()
                            } else {
                                bodies.len().to_string()
                            }
                        ),
                    ));
                }
            },
        };
        Ok(Self {
            fps,
            root_pos: root_pos
                .data
                .chunks_exact(3)
                .map(|p| [p[0], p[1], p[2]])
                .collect(),
            root_rot: rot,
            dof_pos: dof_pos.data,
            dofs,
            bodies,
            has_body_positions,
        })
    }

    /// Frames.
    pub fn frames(&self) -> usize {
        self.root_pos.len()
    }

    /// The motion as a clip of `path`, its joint columns named `joints` (e.g. from a sidecar) or
    /// the robot's joints in its order.
    pub fn into_clip(self, path: &Path, joints: Option<Vec<String>>) -> Result<Clip, ClipError> {
        let (names, robot_order) = match joints {
            Some(names) if names.len() == self.dofs => (names, false),
            Some(names) => {
                return Err(ClipError {
                    file: crate::clip::sidecar_path(path),
                    place: "joints".into(),
                    message: format!(
                        "names {} joints; the motion has {} in dof_pos",
                        names.len(),
                        self.dofs
                    ),
                });
            }
            None => ((0..self.dofs).map(|k| format!("joint {k}")).collect(), true),
        };
        let frames: Vec<_> = (0..self.frames())
            .map(|k| {
                (
                    k as f64 / self.fps,
                    self.root_pos[k],
                    self.root_rot[k],
                    &self.dof_pos[k * self.dofs..(k + 1) * self.dofs],
                )
            })
            .collect();
        Clip::from_frames(path, names, robot_order, &frames)
    }
}

/// The arrays of a GMR file, each where present.
struct Fields {
    fps: Option<pickle::Array>,
    root_pos: Option<pickle::Array>,
    root_rot: Option<pickle::Array>,
    dof_pos: Option<pickle::Array>,
    local_body_pos: Option<pickle::Array>,
}

impl Fields {
    /// Each field by its name from `array` (a pickle's or an NPZ's).
    fn read(array: impl Fn(&str) -> Result<Option<pickle::Array>, ClipError>) -> Result<Self, ClipError> {
        Ok(Self {
            fps: array("fps")?,
            root_pos: array("root_pos")?,
            root_rot: array("root_rot")?,
            dof_pos: array("dof_pos")?,
            local_body_pos: array("local_body_pos")?,
        })
    }
}

/// Whether `path` names a pickle (`.pkl`, `.pickle`).
pub fn is_pickle(path: &Path) -> bool {
    path.extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| e.eq_ignore_ascii_case("pkl") || e.eq_ignore_ascii_case("pickle"))
}
