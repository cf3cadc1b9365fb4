//! The robot in 3D for Foxglove and Rerun: every link's frame by forward kinematics of the
//! recorded joints (`/tf`, `foxglove.FrameTransforms`), and the robot's geometry from its MJCF
//! as scene entities locked to those frames (`/robot`, `foxglove.SceneUpdate`): boxes, spheres,
//! ellipsoids, cylinders, capsules (a cylinder and two spheres) and meshes (triangle lists), in
//! the MJCF's colours.
//!
//! A scene update rather than an exported URDF: the geometry comes from the model MuJoCo
//! compiled (the same one the mirror and the kinematics use: meshes already centred, fromto
//! capsules resolved, defaults applied), it travels inside the recording and the live stream,
//! so any copy of the file shows the robot without the robot's folder beside it.

use std::path::Path;

use foxglove::schemas as fg;
use mujoco_rs::mujoco_c::_mjtGeomBase as G;
use std::sync::Arc;

use mujoco_rs::prelude::{MjData, MjModel};
use robots::spatial;

use crate::{fg_pose, fg_time};

/// Why the robot's model cannot give its links' frames and geometry.
#[derive(Debug, thiserror::Error)]
pub enum Robot3dError {
    /// MuJoCo could not load the model.
    #[error(transparent)]
    Mujoco(#[from] sim2real::mujoco::MujocoError),
    /// The model lacks the root or a joint the run names.
    #[error("{source} ({})", mjcf.display())]
    Model {
        /// The MJCF file.
        mjcf: std::path::PathBuf,
        /// What it lacks.
        source: sim2real::model_index::ModelIndexError,
    },
}

/// Forward kinematics of the recorded joints: each link's pose in its parent's frame.
pub struct Links {
    data: MjData<Arc<MjModel>>,
    root_qpos: usize,
    joint_qpos: Vec<usize>,
    /// The world→root transform and one per link below the root, parent → child; poses
    /// overwritten each tick.
    transforms: fg::FrameTransforms,
    /// (parent body, child body) of `transforms[1..]`.
    pairs: Vec<(usize, usize)>,
    root_body: usize,
    /// The MJCF joints in robot order.
    mjcf_joints: Vec<String>,
    /// Links fixed to their parent (no joint between): their frames never change.
    fixed: Vec<String>,
}

impl Links {
    /// The links of `mjcf`, whose joints `joints` are in robot order; the root body is `root`.
    pub fn new(mjcf: &Path, joints: &[String], root: &str) -> Result<(Self, fg::SceneUpdate), Robot3dError> {
        Self::of_model(mjcf, Arc::new(sim2real::mujoco::load_model(mjcf)?), joints, root)
    }

    /// [`Self::new`] on `model`, `mjcf` compiled already (a run's own model: not compiled twice).
    pub fn of_model(
        mjcf: &Path,
        model: Arc<MjModel>,
        joints: &[String],
        root: &str,
    ) -> Result<(Self, fg::SceneUpdate), Robot3dError> {
        use mujoco_rs::wrappers::mj_model::MjtObjBase;
        let joints: Vec<&str> = joints.iter().map(String::as_str).collect();
        let index = sim2real::model_index::ModelIndex::new(&model, root, &joints, &[]).map_err(|source| {
            Robot3dError::Model {
                mjcf: mjcf.to_path_buf(),
                source,
            }
        })?;
        let (root_body, root_qpos) = (index.root_body, index.root.qpos);
        let name = |b: usize| {
            model
                .id_to_name(MjtObjBase::mjOBJ_BODY, b)
                .unwrap_or("world")
                .to_owned()
        };
        let frame = |parent: String, child: String| fg::FrameTransform {
            parent_frame_id: parent,
            child_frame_id: child,
            ..Default::default()
        };
        let mut transforms = vec![frame("world".into(), name(root_body))];
        let mut pairs = Vec::new();
        let mut fixed = Vec::new();
        for b in (1..model.ffi().nbody as usize).filter(|&b| b != root_body) {
            let p = model.body_parentid()[b] as usize;
            transforms.push(frame(name(p), name(b)));
            pairs.push((p, b));
            if model.body_jntnum()[b] == 0 {
                fixed.push(name(b));
            }
        }
        let scene = scene(&model, root_body, &name);
        let links = Self {
            data: MjData::new(model),
            root_qpos,
            joint_qpos: index.joints.iter().map(|j| j.qpos).collect(),
            transforms: fg::FrameTransforms { transforms },
            pairs,
            root_body,
            mjcf_joints: joints.iter().map(|j| (*j).to_owned()).collect(),
            fixed,
        };
        Ok((links, scene))
    }

    /// The links fixed to their parent (no joint between), by name: frames that never change,
    /// for ROS 2's `/tf_static`.
    pub fn fixed_frames(&self) -> &[String] {
        &self.fixed
    }

    /// The robot as a URDF (`crate::urdf`) named `robot`, its joints named `names` (robot order,
    /// robot.toml's names for the MJCF joints this was made with).
    pub fn urdf(&self, robot: &str, names: &[String]) -> String {
        let rename = |mjcf: &str| match self.mjcf_joints.iter().position(|j| j == mjcf) {
            Some(i) => names.get(i).cloned().unwrap_or_else(|| mjcf.to_owned()),
            None => mjcf.to_owned(),
        };
        crate::urdf::urdf(self.data.model(), robot, self.root_body, &rename)
    }

    /// Every link's frame for `q` (robot order) with the root at `root_pose` `[x, y, z, w, qx,
    /// qy, qz]` in the world, stamped `stamp`.
    pub fn update(&mut self, root_pose: [f64; 7], q: &[f64], stamp: u64) -> &fg::FrameTransforms {
        let qpos = self.data.qpos_mut();
        qpos[self.root_qpos..self.root_qpos + 7].copy_from_slice(&root_pose);
        for (&adr, &v) in self.joint_qpos.iter().zip(q) {
            qpos[adr] = v;
        }
        self.data.kinematics();
        let (xpos, xquat) = (self.data.xpos(), self.data.xquat());
        let time = fg_time(stamp);
        let [root, links @ ..] = self.transforms.transforms.as_mut_slice() else {
            unreachable!("the world→root transform is always there")
        };
        set(root, root_pose, time);
        for (t, &(p, b)) in links.iter_mut().zip(&self.pairs) {
            // The child in its parent's frame.
            let inv = spatial::quat_conj(xquat[p]);
            let at = spatial::quat_rotate(inv, spatial::sub(xpos[b], xpos[p]));
            let q = spatial::quat_mul(inv, xquat[b]);
            set(t, [at[0], at[1], at[2], q[0], q[1], q[2], q[3]], time);
        }
        &self.transforms
    }
}

fn set(t: &mut fg::FrameTransform, p: [f64; 7], time: Option<fg::Timestamp>) {
    let pose = fg_pose(p);
    t.timestamp = time;
    t.translation = pose.position;
    t.rotation = pose.orientation;
}

impl std::fmt::Debug for Links {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Links")
            .field("frames", &self.transforms.transforms.len())
            .finish_non_exhaustive()
    }
}

/// A geom's shape, sizes in metres.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) enum Shape {
    /// Half extents.
    Box([f64; 3]),
    /// Radius.
    Sphere(f64),
    /// Radii.
    Ellipsoid([f64; 3]),
    /// Radius and half length along the geom's z.
    Cylinder(f64, f64),
    /// Radius and half length of the axis between the caps' centres (the geom's z).
    Capsule(f64, f64),
    /// The model's mesh of the geom, its vertices in the geom's frame.
    Mesh,
}

/// One visible geom of the robot: on which body, where in the body's frame (`[x, y, z, w, qx,
/// qy, qz]`), its colour and shape.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Visual {
    pub body: usize,
    pub geom: usize,
    pub at: [f64; 7],
    pub rgba: [f32; 4],
    pub shape: Shape,
}

/// The robot's visible geoms: the tree under `root_body`, in the model's order; geoms with zero
/// alpha, planes and height fields left out. What both the scene and the URDF show.
pub(crate) fn visuals(model: &MjModel, root_body: usize) -> Vec<Visual> {
    let ngeom = usize::try_from(model.ffi().ngeom).unwrap_or(0);
    let mut out = Vec::new();
    for g in 0..ngeom {
        let body = usize::try_from(model.geom_bodyid()[g]).unwrap_or(0);
        if body == 0 || !sim2real::placement::in_tree(model, body, root_body) {
            continue;
        }
        let rgba = match usize::try_from(model.geom_matid()[g]) {
            Ok(m) => model.mat_rgba()[m],
            Err(_) => model.geom_rgba()[g],
        };
        if rgba[3] <= 0.0 {
            continue;
        }
        let s = model.geom_size()[g];
        let shape = match model.geom_type()[g] {
            G::mjGEOM_BOX => Shape::Box(s),
            G::mjGEOM_SPHERE => Shape::Sphere(s[0]),
            G::mjGEOM_ELLIPSOID => Shape::Ellipsoid(s),
            G::mjGEOM_CYLINDER => Shape::Cylinder(s[0], s[1]),
            G::mjGEOM_CAPSULE => Shape::Capsule(s[0], s[1]),
            G::mjGEOM_MESH => Shape::Mesh,
            _ => continue,
        };
        let (p, q) = (model.geom_pos()[g], model.geom_quat()[g]);
        out.push(Visual {
            body,
            geom: g,
            at: [p[0], p[1], p[2], q[0], q[1], q[2], q[3]],
            rgba,
            shape,
        });
    }
    out
}

/// The robot's visible geometry: one entity per body of the tree under `root_body`, locked to
/// the body's frame.
fn scene(model: &MjModel, root_body: usize, name: &dyn Fn(usize) -> String) -> fg::SceneUpdate {
    let mut entities: Vec<fg::SceneEntity> = Vec::new();
    for v in visuals(model, root_body) {
        let color = Some(fg::Color {
            r: f64::from(v.rgba[0]),
            g: f64::from(v.rgba[1]),
            b: f64::from(v.rgba[2]),
            a: f64::from(v.rgba[3]),
        });
        let frame = name(v.body);
        let entity = match entities.iter().position(|e| e.frame_id == frame) {
            Some(k) => &mut entities[k],
            None => {
                entities.push(fg::SceneEntity {
                    frame_id: frame.clone(),
                    id: frame,
                    frame_locked: true,
                    ..Default::default()
                });
                entities.last_mut().expect("just pushed")
            }
        };
        let at = v.at;
        let size = |x: f64, y: f64, z: f64| Some(fg::Vector3 { x, y, z });
        match v.shape {
            Shape::Box(h) => entity.cubes.push(fg::CubePrimitive {
                pose: Some(fg_pose(at)),
                size: size(2.0 * h[0], 2.0 * h[1], 2.0 * h[2]),
                color,
            }),
            Shape::Sphere(r) => entity.spheres.push(fg::SpherePrimitive {
                pose: Some(fg_pose(at)),
                size: size(2.0 * r, 2.0 * r, 2.0 * r),
                color,
            }),
            Shape::Ellipsoid(r) => entity.spheres.push(fg::SpherePrimitive {
                pose: Some(fg_pose(at)),
                size: size(2.0 * r[0], 2.0 * r[1], 2.0 * r[2]),
                color,
            }),
            Shape::Cylinder(r, half) | Shape::Capsule(r, half) => {
                entity.cylinders.push(fg::CylinderPrimitive {
                    pose: Some(fg_pose(at)),
                    size: size(2.0 * r, 2.0 * r, 2.0 * half),
                    bottom_scale: 1.0,
                    top_scale: 1.0,
                    color,
                });
                if matches!(v.shape, Shape::Capsule(..)) {
                    // The caps: spheres at the ends of the axis (the geom's z).
                    let q = [at[3], at[4], at[5], at[6]];
                    for end in [-half, half] {
                        let c = spatial::add([at[0], at[1], at[2]], spatial::quat_rotate(q, [0.0, 0.0, end]));
                        entity.spheres.push(fg::SpherePrimitive {
                            pose: Some(fg_pose([c[0], c[1], c[2], 1.0, 0.0, 0.0, 0.0])),
                            size: size(2.0 * r, 2.0 * r, 2.0 * r),
                            color,
                        });
                    }
                }
            }
            Shape::Mesh => {
                if let Some(triangles) = mesh(model, v.geom, at, color) {
                    entity.triangles.push(triangles);
                }
            }
        }
    }
    fg::SceneUpdate {
        deletions: Vec::new(),
        entities,
    }
}

/// Mesh geom `g` as an indexed triangle list, its vertices in the geom's frame placed at `at`.
fn mesh(
    model: &MjModel,
    g: usize,
    at: [f64; 7],
    color: Option<fg::Color>,
) -> Option<fg::TriangleListPrimitive> {
    let vertices = sim2real::placement::mesh_vertices(model, g)?;
    let m = usize::try_from(model.geom_dataid()[g]).ok()?;
    let start = usize::try_from(model.mesh_faceadr()[m]).ok()?;
    let count = usize::try_from(model.mesh_facenum()[m]).ok()?;
    let faces = model.mesh_face().get(start..start + count)?;
    let indices = faces
        .iter()
        .flatten()
        .map(|&i| u32::try_from(i).ok().filter(|&i| (i as usize) < vertices.len()))
        .collect::<Option<Vec<u32>>>()?;
    Some(fg::TriangleListPrimitive {
        pose: Some(fg_pose(at)),
        points: vertices
            .iter()
            .map(|v| fg::Point3 {
                x: f64::from(v[0]),
                y: f64::from(v[1]),
                z: f64::from(v[2]),
            })
            .collect(),
        color,
        colors: Vec::new(),
        indices,
    })
}
