//! Pictures of a mirror run, ray-cast on the CPU with MuJoCo's own `mj_ray`.
//!
//! MuJoCo's renderer needs an OpenGL context (EGL or OSMesa, a GPU or their Debian packages);
//! the test machines and most CI runners have neither. Casting one ray per pixel through
//! `mj_ray` uses the exact collision geometry of the model (meshes included) and needs nothing
//! but the library already loaded, at a few hundred milliseconds per small frame: enough for a
//! person to check what the robot did.

use std::path::Path;

use mujoco_rs::prelude::*;
use mujoco_rs::wrappers::mj_model::traits::ModelType;

/// A camera orbiting the robot's root.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CameraSpec {
    /// Image width, px.
    pub width: u32,
    /// Image height, px.
    pub height: u32,
    /// Distance from the look-at point, m.
    pub distance: f64,
    /// Azimuth around the vertical, rad (0: looking along +x from behind… see `look_from`).
    pub azimuth: f64,
    /// Elevation above the horizon, rad.
    pub elevation: f64,
    /// Vertical field of view, rad.
    pub fovy: f64,
}

impl Default for CameraSpec {
    fn default() -> Self {
        Self {
            width: 480,
            height: 360,
            distance: 1.6,
            azimuth: 0.6,
            elevation: 0.25,
            fovy: 45f64.to_radians(),
        }
    }
}

/// An RGB image.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Image {
    /// Width, px.
    pub width: u32,
    /// Height, px.
    pub height: u32,
    /// Row-major RGB bytes.
    pub rgb: Vec<u8>,
}

impl Image {
    /// Writes the image as a PNG file.
    pub fn save_png(&self, path: &Path) -> std::io::Result<()> {
        std::fs::write(path, self.to_png()?)
    }

    /// The image as PNG bytes.
    pub fn to_png(&self) -> std::io::Result<Vec<u8>> {
        let mut bytes = Vec::new();
        let mut encoder = png::Encoder::new(&mut bytes, self.width, self.height);
        encoder.set_color(png::ColorType::Rgb);
        encoder.set_depth(png::BitDepth::Eight);
        let mut writer = encoder.write_header().map_err(std::io::Error::other)?;
        writer
            .write_image_data(&self.rgb)
            .map_err(std::io::Error::other)?;
        writer.finish().map_err(std::io::Error::other)?;
        Ok(bytes)
    }

    /// Fraction of pixels that differ from the background colour of the sky.
    pub fn coverage(&self, sky: [u8; 3]) -> f64 {
        let px = self.rgb.chunks_exact(3).filter(|p| *p != sky).count();
        px as f64 / (f64::from(self.width) * f64::from(self.height))
    }
}

/// The sky colour of rendered images.
pub const SKY: [u8; 3] = [200, 215, 235];

/// Renders `data` from `camera`, looking at `target` (world coordinates).
pub fn render<M: ModelType>(data: &mut MjData<M>, camera: &CameraSpec, target: [f64; 3]) -> Image {
    let (ce, se) = (camera.elevation.cos(), camera.elevation.sin());
    let (ca, sa) = (camera.azimuth.cos(), camera.azimuth.sin());
    // Camera looks at the target from the front-right, above.
    let forward = [-ce * ca, -ce * sa, -se];
    let eye = [
        target[0] - camera.distance * forward[0],
        target[1] - camera.distance * forward[1],
        target[2] - camera.distance * forward[2],
    ];
    let right = normalize(cross(forward, [0.0, 0.0, 1.0]));
    let up = cross(right, forward);
    let light = normalize([0.3, -0.5, 1.0]);
    let half_h = (camera.fovy / 2.0).tan();
    let half_w = half_h * f64::from(camera.width) / f64::from(camera.height);
    let mut rgb = Vec::with_capacity((camera.width * camera.height * 3) as usize);
    let rgba: Vec<[f32; 4]> = data.model().geom_rgba().to_vec();
    let planes: Vec<bool> = data
        .model()
        .geom_type()
        .iter()
        .map(|t| *t == mujoco_rs::mujoco_c::_mjtGeomBase::mjGEOM_PLANE)
        .collect();
    for y in 0..camera.height {
        for x in 0..camera.width {
            let u = (2.0 * (f64::from(x) + 0.5) / f64::from(camera.width) - 1.0) * half_w;
            let v = (1.0 - 2.0 * (f64::from(y) + 0.5) / f64::from(camera.height)) * half_h;
            let dir = normalize([
                forward[0] + u * right[0] + v * up[0],
                forward[1] + u * right[1] + v * up[1],
                forward[2] + u * right[2] + v * up[2],
            ]);
            let mut normal = [0.0; 3];
            let (geom, dist) = data.ray(&eye, &dir, None, true, None, Some(&mut normal));
            let Some(g) = geom.filter(|_| dist >= 0.0) else {
                rgb.extend_from_slice(&SKY);
                continue;
            };
            let hit = [
                eye[0] + dist * dir[0],
                eye[1] + dist * dir[1],
                eye[2] + dist * dir[2],
            ];
            let lit = dot(normal, light).max(0.0);
            // Shadow: anything between the hit point and the light.
            let start = [
                hit[0] + 1e-4 * normal[0],
                hit[1] + 1e-4 * normal[1],
                hit[2] + 1e-4 * normal[2],
            ];
            let (blocker, _) = data.ray(&start, &light, None, true, None, None);
            let shade = 0.35 + 0.65 * if blocker.is_some() { 0.3 * lit } else { lit };
            let c = rgba[g];
            let checker = if planes[g] && ((hit[0].floor() + hit[1].floor()) as i64).rem_euclid(2) == 0 {
                0.85
            } else {
                1.0
            };
            for channel in &c[..3] {
                rgb.push((f64::from(*channel) * shade * checker * 255.0).clamp(0.0, 255.0) as u8);
            }
        }
    }
    Image {
        width: camera.width,
        height: camera.height,
        rgb,
    }
}

fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

fn normalize(a: [f64; 3]) -> [f64; 3] {
    let n = dot(a, a).sqrt().max(1e-12);
    [a[0] / n, a[1] / n, a[2] / n]
}
