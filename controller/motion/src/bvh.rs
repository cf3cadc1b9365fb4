//! BVH motion capture: the hierarchy, the motion, and forward kinematics into the robot's frame
//! (metres, Z up, X forward at the first frame).
//!
//! Two dialects are known by their joint names, because they disagree on basics: CMU (units of
//! 0.056444 m, only the root has position channels) and Bandai-Namco (centimetres, every joint has
//! six channels and its position channels *replace* the OFFSET). Both are Y up.

use std::path::{Path, PathBuf};

use robots::spatial::{self, IDENTITY, Mat3, mat_apply as apply, mat_mul as mul, transpose};

/// One joint of the hierarchy.
#[derive(Debug, Clone, PartialEq)]
pub struct BvhJoint {
    /// Name.
    pub name: String,
    /// Parent index (`None` for the root).
    pub parent: Option<usize>,
    /// OFFSET, file units.
    pub offset: [f64; 3],
    /// Channels in file order.
    pub channels: Vec<Channel>,
    /// Index of the first channel in a motion row.
    pub first_channel: usize,
}

/// A BVH channel.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Channel {
    /// Translation along an axis (0 = X, 1 = Y, 2 = Z).
    Position(usize),
    /// Rotation about an axis, degrees.
    Rotation(usize),
}

/// Which skeleton convention a file follows.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Dialect {
    /// CMU Graphics Lab (ASF/AMC converted): 0.056444 m per unit.
    Cmu,
    /// Bandai-Namco Research Motiondataset: centimetres, position channels replace offsets.
    Bandai,
}

/// A parsed BVH file.
#[derive(Debug, Clone, PartialEq)]
pub struct Bvh {
    /// Joints, parents before children.
    pub joints: Vec<BvhJoint>,
    /// Seconds per frame.
    pub frame_time: f64,
    /// Channel values, `frames × channels`.
    pub motion: Vec<f64>,
    /// Channels per frame.
    pub channels: usize,
    /// The convention (from the joint names).
    pub dialect: Dialect,
}

/// Global poses of every joint at one frame, robot frame (metres, Z up).
#[derive(Debug, Clone, PartialEq)]
pub struct Pose {
    /// Positions, per joint.
    pub pos: Vec<[f64; 3]>,
    /// Orientations, per joint.
    pub rot: Vec<Mat3>,
}

/// Most frames a recording may have (an hour at 120 Hz).
pub const MAX_FRAMES: usize = 432_000;

/// Frame times a recording may have, s (1000 Hz to 1 Hz).
pub const FRAME_TIME_S: std::ops::RangeInclusive<f64> = 0.001..=1.0;

/// Longest recording, s.
pub const MAX_DURATION_S: f64 = 3600.0;

/// The largest magnitude of an OFFSET or channel value (centimetres or degrees): a kilometre, or
/// a thousand turns; beyond, the file is not a capture (a body scaled to nothing around it).
pub const MAX_VALUE: f64 = 1e5;

/// A BVH file that cannot be read or is malformed, named with its line.
#[derive(Debug, thiserror::Error)]
pub enum BvhError {
    /// The file is malformed.
    #[error("{}:{line}: {message}", file.display())]
    Malformed {
        /// The file.
        file: PathBuf,
        /// Its line (1-based; 0: the file as a whole).
        line: usize,
        /// What is wrong.
        message: String,
    },
    /// The file cannot be read.
    #[error("{}: {source}", file.display())]
    Read {
        /// The file.
        file: PathBuf,
        /// Why.
        source: std::io::Error,
    },
}

fn err(path: &Path, line: usize, message: impl std::fmt::Display) -> BvhError {
    BvhError::Malformed {
        file: path.to_path_buf(),
        line,
        message: message.to_string(),
    }
}

impl Bvh {
    /// Reads and parses `path`.
    pub fn load(path: &Path) -> Result<Self, BvhError> {
        robots::check_regular_file(path).map_err(|message| BvhError::Malformed {
            file: path.to_path_buf(),
            line: 0,
            message: message.to_string(),
        })?;
        let text = std::fs::read_to_string(path).map_err(|source| BvhError::Read {
            file: path.to_path_buf(),
            source,
        })?;
        Self::parse(path, &text)
    }

    /// Parses BVH text; errors name the file and line.
    pub fn parse(path: &Path, text: &str) -> Result<Self, BvhError> {
        let mut lines = text.lines().enumerate().map(|(i, l)| (i + 1, l.trim()));
        let mut joints: Vec<BvhJoint> = Vec::new();
        let mut stack: Vec<Option<usize>> = Vec::new();
        let mut pending: Option<(String, bool)> = None; // name, is end site
        let mut channels = 0;
        let mut in_end = 0usize;
        let mut last = 0;
        let (first, head) = lines.next().ok_or_else(|| err(path, 1, "empty file"))?;
        if head != "HIERARCHY" {
            return Err(err(path, first, format!("expected HIERARCHY, found {head:?}")));
        }
        for (n, line) in lines.by_ref() {
            last = n;
            let mut words = line.split_whitespace();
            let Some(word) = words.next() else { continue };
            match word {
                "ROOT" | "JOINT" => {
                    let name = words.next().ok_or_else(|| err(path, n, "joint without a name"))?;
                    if (word == "ROOT") != joints.is_empty() {
                        return Err(err(path, n, "exactly one ROOT, first"));
                    }
                    pending = Some((name.to_owned(), false));
                }
                "End" => pending = Some((String::new(), true)),
                "{" => match pending.take() {
                    Some((_, true)) => {
                        in_end += 1;
                        stack.push(None);
                    }
                    Some((name, false)) => {
                        let parent = stack.iter().rev().flatten().next().copied();
                        joints.push(BvhJoint {
                            name,
                            parent,
                            offset: [0.0; 3],
                            channels: Vec::new(),
                            first_channel: channels,
                        });
                        stack.push(Some(joints.len() - 1));
                    }
                    None => return Err(err(path, n, "'{' without ROOT, JOINT or End Site")),
                },
                "}" => {
                    match stack.pop() {
                        Some(None) => in_end -= 1,
                        Some(Some(_)) => {}
                        None => return Err(err(path, n, "unbalanced '}'")),
                    }
                    if stack.is_empty() {
                        break;
                    }
                }
                "OFFSET" => {
                    let v = floats(words, 3, path, n)?;
                    if in_end == 0 {
                        let j = stack
                            .last()
                            .copied()
                            .flatten()
                            .ok_or_else(|| err(path, n, "OFFSET outside a joint"))?;
                        joints[j].offset = [v[0], v[1], v[2]];
                    }
                }
                "CHANNELS" => {
                    let j = stack
                        .last()
                        .copied()
                        .flatten()
                        .ok_or_else(|| err(path, n, "CHANNELS outside a joint"))?;
                    let count: usize = words
                        .next()
                        .and_then(|c| c.parse().ok())
                        .ok_or_else(|| err(path, n, "CHANNELS needs a count"))?;
                    let list = words
                        .map(|w| match w {
                            "Xposition" => Ok(Channel::Position(0)),
                            "Yposition" => Ok(Channel::Position(1)),
                            "Zposition" => Ok(Channel::Position(2)),
                            "Xrotation" => Ok(Channel::Rotation(0)),
                            "Yrotation" => Ok(Channel::Rotation(1)),
                            "Zrotation" => Ok(Channel::Rotation(2)),
                            other => Err(err(path, n, format!("unknown channel {other:?}"))),
                        })
                        .collect::<Result<Vec<_>, _>>()?;
                    if list.len() != count {
                        return Err(err(path, n, format!("CHANNELS {count} lists {}", list.len())));
                    }
                    joints[j].first_channel = channels;
                    channels += count;
                    joints[j].channels = list;
                }
                other => return Err(err(path, n, format!("unexpected {other:?} in HIERARCHY"))),
            }
        }
        if joints.is_empty() || !stack.is_empty() {
            return Err(err(path, last, "the HIERARCHY is incomplete"));
        }
        let mut next = |what: &str| -> Result<(usize, &str), BvhError> {
            lines
                .by_ref()
                .find(|(_, l)| !l.is_empty())
                .ok_or_else(|| err(path, last, format!("missing {what}")))
        };
        let (n, motion) = next("MOTION")?;
        if motion != "MOTION" {
            return Err(err(path, n, format!("expected MOTION, found {motion:?}")));
        }
        let (n, frames_line) = next("Frames:")?;
        let frames: usize = frames_line
            .strip_prefix("Frames:")
            .and_then(|v| v.trim().parse().ok())
            .filter(|f| (1..=MAX_FRAMES).contains(f))
            .ok_or_else(|| {
                err(
                    path,
                    n,
                    format!("expected 'Frames: N' with N in [1, {MAX_FRAMES}]"),
                )
            })?;
        let (n, time_line) = next("Frame Time:")?;
        let frame_time: f64 = time_line
            .strip_prefix("Frame Time:")
            .and_then(|v| v.trim().parse().ok())
            .filter(|t: &f64| FRAME_TIME_S.contains(t))
            .ok_or_else(|| {
                err(
                    path,
                    n,
                    format!(
                        "expected 'Frame Time: SECONDS' in [{}, {}]",
                        FRAME_TIME_S.start(),
                        FRAME_TIME_S.end()
                    ),
                )
            })?;
        if frames as f64 * frame_time > MAX_DURATION_S {
            return Err(err(
                path,
                n,
                format!("{frames} frames of {frame_time} s: a recording lasts at most {MAX_DURATION_S} s"),
            ));
        }
        // The rows that follow are counted, not trusted: reserve no more than the text can hold.
        let mut motion = Vec::with_capacity((frames * channels).min(text.len() / 2));
        let mut rows = 0;
        for (n, line) in lines {
            if line.is_empty() {
                continue;
            }
            let before = motion.len();
            for w in line.split_whitespace() {
                let v: f64 = w
                    .parse()
                    .map_err(|_| err(path, n, format!("{w:?} is not a number")))?;
                if !v.is_finite() {
                    return Err(err(path, n, format!("{w} is not finite")));
                }
                if v.abs() > MAX_VALUE {
                    return Err(err(
                        path,
                        n,
                        format!("{w} is outside ±{MAX_VALUE:e} (cm or degrees)"),
                    ));
                }
                motion.push(v);
            }
            if motion.len() - before != channels {
                return Err(err(
                    path,
                    n,
                    format!(
                        "{} values, the hierarchy has {channels} channels",
                        motion.len() - before
                    ),
                ));
            }
            rows += 1;
        }
        if rows != frames {
            return Err(err(
                path,
                last,
                format!("Frames: {frames}, but {rows} rows follow"),
            ));
        }
        let has = |name: &str| joints.iter().any(|j| j.name == name);
        let dialect = if has("joint_Root") && has("Hand_L") {
            Dialect::Bandai
        } else if has("Hips") && has("LeftHand") {
            Dialect::Cmu
        } else {
            return Err(err(
                path,
                0,
                format!(
                    "unknown skeleton (root {:?}): known are CMU (Hips, LeftHand, …) and Bandai (joint_Root, Hand_L, …)",
                    joints[0].name
                ),
            ));
        };
        Ok(Self {
            joints,
            frame_time,
            motion,
            channels,
            dialect,
        })
    }

    /// Frames.
    pub fn frames(&self) -> usize {
        self.motion.len() / self.channels.max(1)
    }

    /// Metres per file unit.
    pub fn unit(&self) -> f64 {
        match self.dialect {
            Dialect::Cmu => 0.056_444,
            Dialect::Bandai => 0.01,
        }
    }

    /// Index of joint `name`.
    pub fn joint(&self, name: &str) -> Option<usize> {
        self.joints.iter().position(|j| j.name == name)
    }

    /// Global poses at `frame`, in the file's frame converted to Z up (x_robot = z_file,
    /// y_robot = x_file, z_robot = y_file) and metres.
    pub fn pose(&self, frame: usize) -> Pose {
        let row = &self.motion[frame * self.channels..(frame + 1) * self.channels];
        let n = self.joints.len();
        let mut pos = vec![[0.0; 3]; n];
        let mut rot = vec![IDENTITY; n];
        let unit = self.unit();
        for (i, j) in self.joints.iter().enumerate() {
            let mut offset = j.offset;
            let mut local = IDENTITY;
            for (k, c) in j.channels.iter().enumerate() {
                let v = row[j.first_channel + k];
                match *c {
                    // Position channels replace the OFFSET (Bandai; CMU's root offset is zero).
                    Channel::Position(a) => offset[a] = v,
                    Channel::Rotation(a) => local = mul(&local, &axis_rotation(a, v.to_radians())),
                }
            }
            let offset = to_robot(offset).map(|x| x * unit);
            let local = conjugate_to_robot(&local);
            match j.parent {
                None => {
                    pos[i] = offset;
                    rot[i] = local;
                }
                Some(p) => {
                    let o = apply(&rot[p], offset);
                    pos[i] = [pos[p][0] + o[0], pos[p][1] + o[1], pos[p][2] + o[2]];
                    rot[i] = mul(&rot[p], &local);
                }
            }
        }
        Pose { pos, rot }
    }

    /// The pose `t` seconds after frame `first`, between the two frames around it: positions
    /// interpolated linearly, orientations along the shortest arc (a clip resampled at another
    /// rate moves smoothly instead of holding frames). Past the last frame: the last frame.
    pub fn pose_at(&self, first: usize, t: f64) -> Pose {
        let x = (first as f64 + t.max(0.0) / self.frame_time).min((self.frames() - 1) as f64);
        let k = x.floor() as usize;
        let w = x - k as f64;
        let a = self.pose(k);
        if w < 1e-9 || k + 1 >= self.frames() {
            return a;
        }
        let b = self.pose(k + 1);
        Pose {
            pos: a
                .pos
                .iter()
                .zip(&b.pos)
                .map(|(p, q)| [0, 1, 2].map(|i| p[i] + w * (q[i] - p[i])))
                .collect(),
            rot: a
                .rot
                .iter()
                .zip(&b.rot)
                .map(|(p, q)| {
                    spatial::mat_of_quat(spatial::slerp(
                        spatial::quat_of_mat(p),
                        spatial::quat_of_mat(q),
                        w,
                    ))
                })
                .collect(),
        }
    }
}

/// `n` finite numbers from the rest of line `line` of `path`.
fn floats<'a>(
    words: impl Iterator<Item = &'a str>,
    n: usize,
    path: &Path,
    line: usize,
) -> Result<Vec<f64>, BvhError> {
    let v = words
        .map(|w| {
            w.parse::<f64>()
                .map_err(|_| err(path, line, format_args!("{w:?} is not a number")))
        })
        .collect::<Result<Vec<_>, _>>()?;
    if v.len() != n || v.iter().any(|x| !x.is_finite()) {
        return Err(err(path, line, format_args!("expected {n} finite numbers")));
    }
    if let Some(x) = v.iter().find(|x| x.abs() > MAX_VALUE) {
        return Err(err(
            path,
            line,
            format_args!("{x} is outside ±{MAX_VALUE:e} (cm or degrees)"),
        ));
    }
    Ok(v)
}

fn axis_rotation(axis: usize, a: f64) -> Mat3 {
    let (s, c) = a.sin_cos();
    match axis {
        0 => [[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]],
        1 => [[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]],
        _ => [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]],
    }
}

/// File axes (Y up) to robot axes (Z up): a cyclic permutation, so a proper rotation.
fn to_robot(v: [f64; 3]) -> [f64; 3] {
    [v[2], v[0], v[1]]
}

/// A rotation expressed in file axes, expressed in robot axes: P·R·Pᵀ.
fn conjugate_to_robot(r: &Mat3) -> Mat3 {
    const P: Mat3 = [[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
    mul(&mul(&P, r), &transpose(&P))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn data(name: &str) -> PathBuf {
        test_support::fixtures::workspace_root()
            .join("data/mocap")
            .join(name)
    }

    #[test]
    fn cmu_and_bandai_stand_at_human_heights() {
        let cmu = Bvh::load(&data("cmu_13_26_direct-traffic-wave.bvh")).unwrap();
        assert_eq!(cmu.dialect, Dialect::Cmu);
        assert_eq!(cmu.frames(), 3029);
        let p = cmu.pose(0);
        let hips = p.pos[cmu.joint("Hips").unwrap()][2];
        let head = p.pos[cmu.joint("Head").unwrap()][2];
        assert!((hips - 1.05).abs() < 0.03, "hips {hips}");
        assert!((head - 1.47).abs() < 0.06, "head {head}");
        // Frame 0 is a T-pose: hands level with the shoulders, far apart.
        let (l, r) = (
            p.pos[cmu.joint("LeftHand").unwrap()],
            p.pos[cmu.joint("RightHand").unwrap()],
        );
        let span = ((l[0] - r[0]).powi(2) + (l[1] - r[1]).powi(2)).sqrt();
        assert!(span > 1.2, "hand span {span}");
    }

    #[test]
    fn bandai_position_channels_replace_the_offset() {
        // Bandai's layout (every joint six channels, Z X Y), cut to three joints: the Hips' OFFSET
        // says 93 cm, its position channels say 90; the channels win.
        let text = "HIERARCHY\nROOT joint_Root\n{\nOFFSET 0 0 0\nCHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation\n\
            JOINT Hips\n{\nOFFSET -0.7 93.3 -2.0\nCHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation\n\
            JOINT Hand_L\n{\nOFFSET 10 0 0\nCHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation\n\
            End Site\n{\nOFFSET 0 0 0\n}\n}\n}\n}\nMOTION\nFrames: 1\nFrame Time: 0.0333333\n\
            0 0 0 0 0 0  0 90 0 0 0 0  20 0 0 0 0 0\n";
        let b = Bvh::parse(Path::new("bandai.bvh"), text).unwrap();
        assert_eq!(b.dialect, Dialect::Bandai);
        let p = b.pose(0);
        assert!((p.pos[1][2] - 0.90).abs() < 1e-9, "hips {:?}", p.pos[1]);
        // The hand's channels say 20 cm along file X (robot Y), not its OFFSET's 10.
        assert!((p.pos[2][1] - 0.20).abs() < 1e-9, "hand {:?}", p.pos[2]);
    }

    #[test]
    fn a_pose_between_frames_is_interpolated_and_the_last_frame_holds() {
        // One root, two frames 0.1 s apart: x from 0 to 10 cm, yaw (file Y) from 0 to 90°.
        let text = "HIERARCHY\nROOT Hips\n{\nOFFSET 0 0 0\nCHANNELS 6 Xposition Yposition Zposition Zrotation Yrotation Xrotation\n\
            JOINT LeftHand\n{\nOFFSET 1 0 0\nCHANNELS 3 Zrotation Yrotation Xrotation\nEnd Site\n{\nOFFSET 1 0 0\n}\n}\n}\n\
            MOTION\nFrames: 2\nFrame Time: 0.1\n0 0 0 0 0 0 0 0 0\n10 0 0 0 90 0 0 0 0\n";
        let b = Bvh::parse(Path::new("two.bvh"), text).unwrap();
        let unit = b.unit();
        let quarter = b.pose_at(0, 0.025);
        // File X is the robot's Y.
        assert!(
            (quarter.pos[0][1] - 2.5 * unit).abs() < 1e-12,
            "{:?}",
            quarter.pos[0]
        );
        // A quarter of the way along the arc: 22.5° about the vertical.
        let yaw = spatial::heading(&quarter.rot[0]);
        assert!((yaw.abs() - 22.5f64.to_radians()).abs() < 1e-9, "yaw {yaw}");
        assert_eq!(b.pose_at(0, 0.0), b.pose(0));
        assert_eq!(b.pose_at(0, 5.0), b.pose(1));
        assert_eq!(b.pose_at(1, 0.0), b.pose(1));
    }

    #[test]
    fn broken_files_are_refused_with_their_line() {
        let path = Path::new("bad.bvh");
        let good = "HIERARCHY\nROOT Hips\n{\nOFFSET 0 0 0\nCHANNELS 6 Xposition Yposition Zposition Zrotation Yrotation Xrotation\nJOINT LeftHand\n{\nOFFSET 1 0 0\nCHANNELS 3 Zrotation Yrotation Xrotation\nEnd Site\n{\nOFFSET 1 0 0\n}\n}\n}\nMOTION\nFrames: 1\nFrame Time: 0.01\n0 18 0 0 0 0 0 0 0\n";
        if let Err(e) = Bvh::parse(path, good) {
            panic!("{e}");
        }
        let e = Bvh::parse(path, &good.replace("0 18 0 0 0 0 0 0 0", "0 18 0 0 0 0 0 0"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("bad.bvh:19") && e.contains("8 values"), "{e}");
        let e = Bvh::parse(path, &good.replace("Frames: 1", "Frames: 2"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("Frames: 2, but 1 rows"), "{e}");
        // Finite but absurd: a channel of 1e300 made a clip scaled to nothing.
        let e = Bvh::parse(path, &good.replace("0 18 0 0 0 0 0 0 0", "0 1e300 0 0 0 0 0 0 0"))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("bad.bvh:19") && e.contains("1e300 is outside ±1e5"),
            "{e}"
        );
        let e = Bvh::parse(
            path,
            &good.replace("OFFSET 1 0 0\nCHANNELS", "OFFSET 1e9 0 0\nCHANNELS"),
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("bad.bvh:8") && e.contains("outside ±1e5"), "{e}");
        let e = Bvh::parse(
            path,
            &good.replace(
                "Zrotation Yrotation Xrotation\nEnd",
                "Zrotation Wrotation Xrotation\nEnd",
            ),
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains(":9:") && e.contains("Wrotation"), "{e}");
        let e = Bvh::parse(path, &good.replace("0 18 0 0", "0 NaN 0 0"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("not finite") || e.contains("not a number"), "{e}");
        assert!(Bvh::parse(path, "").is_err());
        assert!(
            Bvh::parse(path, &good.replace("LeftHand", "Paw"))
                .unwrap_err()
                .to_string()
                .contains("unknown skeleton")
        );
    }
}
