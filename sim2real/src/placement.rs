//! Where a robot's geometry reaches lowest, from the compiled model: each collision geom of the
//! robot's tree by its shape — mesh vertices in the mesh's own frame, boxes by their corners,
//! capsules and cylinders by their ends — never the floor's or the world's geoms.

use mujoco_rs::mujoco_c::_mjtGeomBase as G;
use mujoco_rs::prelude::{MjData, MjModel};
use mujoco_rs::wrappers::mj_model::traits::ModelType;

/// The lowest world height (m) any collision geom of the tree rooted at `root_body` reaches in
/// `data`'s current kinematics (call after `forward`), or `None` when the tree has no collision
/// geometry.
pub fn lowest_point<M: ModelType>(data: &MjData<M>, root_body: usize) -> Option<f64> {
    let model = data.model();
    let ngeom = usize::try_from(model.ffi().ngeom).unwrap_or(0);
    let mut lowest = f64::INFINITY;
    for g in 0..ngeom {
        let body = usize::try_from(model.geom_bodyid()[g]).unwrap_or(0);
        if body == 0 || !collides(model, g) || !in_tree(model, body, root_body) {
            continue;
        }
        let Some(low) = world_support_point(data, g, [0.0, 0.0, -1.0]) else {
            continue;
        };
        lowest = lowest.min(low[2]);
    }
    lowest.is_finite().then_some(lowest)
}

/// Whether `body` is `root` or one of its descendants (body 0 is the world).
pub fn in_tree(model: &MjModel, mut body: usize, root: usize) -> bool {
    loop {
        if body == root {
            return true;
        }
        if body == 0 {
            return false;
        }
        body = usize::try_from(model.body_parentid()[body]).unwrap_or(0);
    }
}

/// How far geom `g` reaches from its centre along the unit direction `d` (in the geom's own
/// frame): its support function, exact for spheres, capsules, cylinders, boxes, ellipsoids and
/// meshes (their vertices, stored in the geom's frame once compiled). `None` for shapes without
/// an extent to stand on (planes, height fields).
pub fn reach(model: &MjModel, g: usize, d: [f64; 3]) -> Option<f64> {
    let p = support_point(model, g, d)?;
    Some(p[0] * d[0] + p[1] * d[1] + p[2] * d[2])
}

/// The point of geom `g` furthest along the unit direction `d`, both in the geom's own frame
/// (a tie, such as a box face square to `d`, gives the middle of the tied points). `None` for
/// planes and height fields.
pub fn support_point(model: &MjModel, g: usize, d: [f64; 3]) -> Option<[f64; 3]> {
    let s = model.geom_size()[g];
    let sign = |x: f64| if x == 0.0 { 0.0 } else { x.signum() };
    Some(match model.geom_type()[g] {
        G::mjGEOM_SPHERE => d.map(|x| s[0] * x),
        // Capsules and cylinders have their axis along z, half-length `s[1]`.
        G::mjGEOM_CAPSULE => [s[0] * d[0], s[0] * d[1], s[0] * d[2] + s[1] * sign(d[2])],
        G::mjGEOM_CYLINDER => {
            let across = (d[0] * d[0] + d[1] * d[1]).sqrt();
            let rim = if across > 0.0 { s[0] / across } else { 0.0 };
            [rim * d[0], rim * d[1], s[1] * sign(d[2])]
        }
        G::mjGEOM_BOX => [s[0] * sign(d[0]), s[1] * sign(d[1]), s[2] * sign(d[2])],
        G::mjGEOM_ELLIPSOID => {
            let norm = (0..3).map(|k| (s[k] * d[k]).powi(2)).sum::<f64>().sqrt();
            if norm == 0.0 {
                return Some([0.0; 3]);
            }
            [0, 1, 2].map(|k| s[k] * s[k] * d[k] / norm)
        }
        G::mjGEOM_MESH => mesh_vertices(model, g)?
            .iter()
            .map(|v| v.map(f64::from))
            .max_by(|a, b| {
                let along = |v: &[f64; 3]| v[0] * d[0] + v[1] * d[1] + v[2] * d[2];
                along(a).total_cmp(&along(b))
            })?,
        _ => return None,
    })
}

/// The point of geom `g` furthest along the unit world direction `d`, in world coordinates, in
/// `data`'s current kinematics (call after `forward`).
pub fn world_support_point<M: ModelType>(data: &MjData<M>, g: usize, d: [f64; 3]) -> Option<[f64; 3]> {
    // Row-major rotation, geom to world: the direction in the geom's frame is Rᵀ·d.
    let r = data.geom_xmat()[g];
    let local = [0, 1, 2].map(|c| r[c] * d[0] + r[3 + c] * d[1] + r[6 + c] * d[2]);
    let p = support_point(data.model(), g, local)?;
    let x = data.geom_xpos()[g];
    Some([0, 1, 2].map(|row| x[row] + r[3 * row] * p[0] + r[3 * row + 1] * p[1] + r[3 * row + 2] * p[2]))
}

/// The vertices of mesh geom `g`, in the geom's own frame.
pub fn mesh_vertices(model: &MjModel, g: usize) -> Option<&[[f32; 3]]> {
    if model.geom_type()[g] != G::mjGEOM_MESH {
        return None;
    }
    let mesh = usize::try_from(model.geom_dataid()[g]).ok()?;
    let start = usize::try_from(model.mesh_vertadr()[mesh]).ok()?;
    let count = usize::try_from(model.mesh_vertnum()[mesh]).ok()?;
    model.mesh_vert().get(start..start + count)
}

/// Whether geom `g` takes part in collisions (visual-only geoms have neither bit).
pub fn collides(model: &MjModel, g: usize) -> bool {
    model.geom_contype()[g] != 0 || model.geom_conaffinity()[g] != 0
}
