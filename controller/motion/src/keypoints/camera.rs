//! Pinhole cameras with radial distortion, placed in the robot's world frame, from a TOML file:
//!
//! ```toml
//! [[camera]]
//! name = "front"
//! width = 1280                 # image size, px (1–16384)
//! height = 720
//! fx = 900.0                   # focal lengths, px (> 0)
//! fy = 900.0
//! cx = 640.0                   # principal point, px (inside the image)
//! cy = 360.0
//! k1 = 0.0                     # radial distortion (optional, each within ±10)
//! k2 = 0.0
//! position = [2.5, 0.0, 1.0]   # the camera's centre in the world, m (within ±1000)
//! look_at = [0.0, 0.0, 0.6]    # where it looks (the image's up is the world's +z) …
//! # orientation = [w, x, y, z] # … or its frame's orientation in the world (a unit quaternion)
//! ```
//!
//! The camera frame is OpenCV's: x right, y down, z forward (out of the lens).

use std::path::Path;

use robots::{FileError, spatial};

/// One camera, checked.
#[derive(Debug, Clone, PartialEq)]
pub struct Camera {
    /// Its name (a view of a keypoint clip).
    pub name: String,
    /// Image size, px.
    pub width: u32,
    pub height: u32,
    /// Focal lengths and principal point, px.
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
    /// Radial distortion: `r' = r (1 + k1 r² + k2 r⁴)` on normalised coordinates.
    pub k1: f64,
    pub k2: f64,
    /// The camera's centre in the world, m.
    pub position: [f64; 3],
    /// The camera frame's axes in the world (row-major: column k is camera axis k).
    pub rotation: spatial::Mat3,
}

/// A camera's name is a label in a recording's channels and a report: at most this long.
pub const MAX_NAME_CHARS: usize = 64;

#[derive(Debug, serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct CameraFile {
    camera: Vec<CameraSpec>,
}

#[derive(Debug, serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct CameraSpec {
    name: String,
    width: u32,
    height: u32,
    fx: f64,
    fy: f64,
    cx: f64,
    cy: f64,
    #[serde(default)]
    k1: f64,
    #[serde(default)]
    k2: f64,
    position: [f64; 3],
    look_at: Option<[f64; 3]>,
    orientation: Option<[f64; 4]>,
}

/// Reads the cameras of `path`, each checked; the error names the camera and field.
pub fn load_cameras(path: &Path) -> Result<Vec<Camera>, FileError> {
    let text = robots::read_text(path).map_err(|m| FileError::new(path, m))?;
    cameras_from_str(path, &text)
}

/// [`load_cameras`] from text already read.
pub fn cameras_from_str(path: &Path, text: &str) -> Result<Vec<Camera>, FileError> {
    let file: CameraFile = toml::from_str(text).map_err(|e| FileError::new(path, e.to_string()))?;
    if file.camera.is_empty() {
        return Err(FileError::new(path, "no [[camera]]"));
    }
    let mut cameras: Vec<Camera> = Vec::with_capacity(file.camera.len());
    for (i, c) in file.camera.into_iter().enumerate() {
        // A name too long to be one is not echoed back whole.
        let shown: String = c.name.chars().take(MAX_NAME_CHARS).collect();
        let at = |field: &str| format!("camera[{i}] ({shown}).{field}");
        let bad = |field: &str, m: String| FileError::new(path, format!("{}: {m}", at(field)));
        if c.name.is_empty() || c.name.chars().count() > MAX_NAME_CHARS || c.name.contains(['/', ',']) {
            return Err(bad(
                "name",
                format!(
                    "{} characters: 1–{MAX_NAME_CHARS}, without '/' or ','",
                    c.name.chars().count()
                ),
            ));
        }
        if cameras.iter().any(|k| k.name == c.name) {
            return Err(bad("name", "another camera has this name".into()));
        }
        for (field, v) in [("width", c.width), ("height", c.height)] {
            if !(1..=16_384).contains(&v) {
                return Err(bad(field, format!("{v} px is outside 1–16384")));
            }
        }
        for (field, v) in [("fx", c.fx), ("fy", c.fy)] {
            if !(v.is_finite() && v > 0.0 && v <= 1e6) {
                return Err(bad(
                    field,
                    format!("{v}: a focal length is positive (px, up to 10⁶)"),
                ));
            }
        }
        for (field, v, size) in [("cx", c.cx, c.width), ("cy", c.cy, c.height)] {
            if !(v.is_finite() && (0.0..=f64::from(size)).contains(&v)) {
                return Err(bad(field, format!("{v} px is outside the image (0–{size})")));
            }
        }
        for (field, v) in [("k1", c.k1), ("k2", c.k2)] {
            if !(v.is_finite() && v.abs() <= 10.0) {
                return Err(bad(field, format!("{v} is outside ±10")));
            }
        }
        if c.position.iter().any(|v| !(v.is_finite() && v.abs() <= 1000.0)) {
            return Err(bad("position", format!("{:?}: each within ±1000 m", c.position)));
        }
        let rotation = match (c.look_at, c.orientation) {
            (Some(target), None) => look_at(c.position, target).map_err(|e| bad("look_at", e.to_string()))?,
            (None, Some(q)) => {
                let norm = q.iter().map(|v| v * v).sum::<f64>().sqrt();
                if !norm.is_finite() || (norm - 1.0).abs() > 1e-3 {
                    return Err(bad(
                        "orientation",
                        format!(
                            "{q:?} is not a rotation: a unit quaternion [w, x, y, z] (its norm is {norm})"
                        ),
                    ));
                }
                spatial::mat_of_quat(spatial::quat_normalize(q))
            }
            _ => {
                return Err(bad(
                    "look_at",
                    "give exactly one of look_at and orientation".into(),
                ));
            }
        };
        cameras.push(Camera {
            name: c.name,
            width: c.width,
            height: c.height,
            fx: c.fx,
            fy: c.fy,
            cx: c.cx,
            cy: c.cy,
            k1: c.k1,
            k2: c.k2,
            position: c.position,
            rotation,
        });
    }
    Ok(cameras)
}

/// Why a `look_at` target gives no camera orientation.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
enum LookAtError {
    #[error("{0:?} is not a point")]
    NotAPoint([f64; 3]),
    #[error("the camera looks at its own centre")]
    OwnCentre,
    #[error("straight up or down: give an orientation instead")]
    Vertical,
}

/// The camera frame at `eye` looking at `target`, the image's up along the world's +z.
fn look_at(eye: [f64; 3], target: [f64; 3]) -> Result<spatial::Mat3, LookAtError> {
    if target.iter().any(|v| !v.is_finite()) {
        return Err(LookAtError::NotAPoint(target));
    }
    let forward = spatial::sub(target, eye);
    let n = spatial::norm(forward);
    if n < 1e-6 {
        return Err(LookAtError::OwnCentre);
    }
    let z = spatial::scale(forward, 1.0 / n);
    let right = spatial::cross(z, [0.0, 0.0, 1.0]);
    if spatial::norm(right) < 1e-6 {
        return Err(LookAtError::Vertical);
    }
    let x = spatial::scale(right, 1.0 / spatial::norm(right));
    let y = spatial::cross(z, x);
    Ok([[x[0], y[0], z[0]], [x[1], y[1], z[1]], [x[2], y[2], z[2]]])
}

impl Camera {
    /// `p` (world, m) in the camera frame.
    pub fn to_camera(&self, p: [f64; 3]) -> [f64; 3] {
        spatial::mat_apply(
            &spatial::transpose(&self.rotation),
            spatial::sub(p, self.position),
        )
    }

    /// The pixel `p` (world, m) lands on, with distortion; `None` behind the lens.
    pub fn project(&self, p: [f64; 3]) -> Option<[f64; 2]> {
        let c = self.to_camera(p);
        if c[2] <= 1e-9 {
            return None;
        }
        let (x, y) = (c[0] / c[2], c[1] / c[2]);
        let d = self.distortion(x * x + y * y);
        Some([self.fx * x * d + self.cx, self.fy * y * d + self.cy])
    }

    fn distortion(&self, r2: f64) -> f64 {
        1.0 + self.k1 * r2 + self.k2 * r2 * r2
    }

    /// Whether pixel `uv` lies on the image.
    pub fn sees(&self, uv: [f64; 2]) -> bool {
        (0.0..=f64::from(self.width)).contains(&uv[0]) && (0.0..=f64::from(self.height)).contains(&uv[1])
    }

    /// The world direction (unit) of the ray through pixel `uv`, the distortion undone.
    pub fn ray(&self, uv: [f64; 2]) -> [f64; 3] {
        let (xd, yd) = ((uv[0] - self.cx) / self.fx, (uv[1] - self.cy) / self.fy);
        // Fixed point on r: distorted = undistorted · d(r²); converges for the small k of lenses.
        let (mut x, mut y) = (xd, yd);
        for _ in 0..20 {
            let d = self.distortion(x * x + y * y);
            (x, y) = (xd / d, yd / d);
        }
        let dir = spatial::mat_apply(&self.rotation, [x, y, 1.0]);
        spatial::scale(dir, 1.0 / spatial::norm(dir))
    }
}

/// The point closest to the rays through `pixels` of their cameras (least squares, two rays or
/// more that are not parallel).
pub fn triangulate(pixels: &[(&Camera, [f64; 2])]) -> Option<[f64; 3]> {
    if pixels.len() < 2 {
        return None;
    }
    // Σ (I − d dᵀ) X = Σ (I − d dᵀ) c over the rays (centre c, direction d).
    let mut a = glam::DMat3::ZERO;
    let mut b = glam::DVec3::ZERO;
    for (camera, uv) in pixels {
        let d = glam::DVec3::from(camera.ray(*uv));
        let m = glam::DMat3::IDENTITY - glam::DMat3::from_cols(d * d.x, d * d.y, d * d.z);
        a += m;
        b += m * glam::DVec3::from(camera.position);
    }
    if a.determinant().abs() < 1e-9 {
        return None;
    }
    Some((a.inverse() * b).to_array())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn camera(k1: f64) -> Camera {
        let text = format!(
            "[[camera]]\nname = \"c\"\nwidth = 100\nheight = 100\nfx = 100.0\nfy = 100.0\ncx = 50.0\ncy = 50.0\nk1 = {k1}\nposition = [0.0, 0.0, 0.0]\norientation = [1.0, 0.0, 0.0, 0.0]\n"
        );
        cameras_from_str(Path::new("c.toml"), &text).unwrap().remove(0)
    }

    #[test]
    fn a_point_lands_where_the_pinhole_and_its_distortion_put_it() {
        // (0.5, −0.25, 2) in the camera: x' = 0.25, y' = −0.125.
        let p = camera(0.0).project([0.5, -0.25, 2.0]).unwrap();
        assert_eq!(p, [75.0, 37.5]);
        // r² = 0.078125, 1 + k1 r² = 1.0078125.
        let p = camera(0.1).project([0.5, -0.25, 2.0]).unwrap();
        assert!(
            (p[0] - 75.195_312_5).abs() < 1e-12 && (p[1] - 37.402_343_75).abs() < 1e-12,
            "{p:?}"
        );
        assert_eq!(camera(0.0).project([0.0, 0.0, -1.0]), None, "behind the lens");
        // The ray through a distorted pixel points back at the point.
        let d = camera(0.1).ray(p);
        let want = spatial::scale([0.25, -0.125, 1.0], 1.0 / spatial::norm([0.25, -0.125, 1.0]));
        assert!(spatial::norm(spatial::sub(d, want)) < 1e-9, "{d:?}");
    }

    #[test]
    fn look_at_puts_the_target_on_the_principal_point_with_the_world_up_the_image() {
        let text = "[[camera]]\nname = \"f\"\nwidth = 640\nheight = 480\nfx = 500.0\nfy = 500.0\ncx = 320.0\ncy = 240.0\nposition = [2.0, 0.0, 1.0]\nlook_at = [0.0, 0.0, 1.0]\n";
        let c = cameras_from_str(Path::new("f.toml"), text).unwrap().remove(0);
        assert_eq!(
            c.project([0.0, 0.0, 1.0])
                .map(|p| p.map(|v| (v * 1e9).round() / 1e9)),
            Some([320.0, 240.0])
        );
        let above = c.project([0.0, 0.0, 1.5]).unwrap();
        assert!(
            above[1] < 240.0,
            "higher in the world is higher in the image: {above:?}"
        );
        // Looking along −x, the world's +y is to the camera's right.
        let left = c.project([0.0, 0.5, 1.0]).unwrap();
        assert!(left[0] > 320.0, "{left:?}");
    }

    #[test]
    fn a_camera_name_that_is_no_label_is_refused_without_being_echoed() {
        let text = |name: &str| {
            format!(
                "[[camera]]\nname = \"{name}\"\nwidth = 640\nheight = 480\nfx = 500.0\nfy = 500.0\ncx = 320.0\ncy = 240.0\nposition = [2.0, 0.0, 1.0]\nlook_at = [0.0, 0.0, 1.0]\n"
            )
        };
        let long = "x".repeat(1 << 20);
        let e = cameras_from_str(Path::new("c.toml"), &text(&long))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains(".name: 1048576 characters: 1–64"),
            "{}",
            &e[..e.len().min(300)]
        );
        assert!(e.len() < 400, "the name is not echoed whole: {} bytes", e.len());
        for bad in ["", "a/b", "a,b"] {
            assert!(
                cameras_from_str(Path::new("c.toml"), &text(bad)).is_err(),
                "{bad:?}"
            );
        }
        assert!(cameras_from_str(Path::new("c.toml"), &text(&"x".repeat(64))).is_ok());
    }

    #[test]
    fn two_views_triangulate_a_point_back() {
        let text = "[[camera]]\nname = \"a\"\nwidth = 640\nheight = 480\nfx = 500.0\nfy = 500.0\ncx = 320.0\ncy = 240.0\nk1 = -0.1\nposition = [2.0, 0.0, 1.0]\nlook_at = [0.0, 0.0, 1.0]\n\
                    [[camera]]\nname = \"b\"\nwidth = 640\nheight = 480\nfx = 400.0\nfy = 400.0\ncx = 320.0\ncy = 240.0\nposition = [0.0, 2.0, 1.2]\nlook_at = [0.0, 0.0, 0.8]\n";
        let cams = cameras_from_str(Path::new("ab.toml"), text).unwrap();
        let x = [0.1, -0.2, 0.9];
        let seen: Vec<(&Camera, [f64; 2])> = cams.iter().map(|c| (c, c.project(x).unwrap())).collect();
        let back = triangulate(&seen).unwrap();
        assert!(spatial::norm(spatial::sub(back, x)) < 1e-9, "{back:?}");
        assert_eq!(triangulate(&seen[..1]), None, "one ray is not enough");
    }
}
