//! Where a robot's geometry reaches lowest, from the compiled model: each collision geom of the
//! robot's tree by its shape — mesh vertices in the mesh's own frame, boxes by their corners,
//! capsules and cylinders by their ends — never the floor's or the world's geoms.

use mujoco_rs::mujoco_c::_mjtGeomBase as G;
use mujoco_rs::prelude::{MjData, MjModel};

/// The lowest world height (m) any collision geom of the tree rooted at `root_body` reaches in
/// `data`'s current kinematics (call after `forward`), or `None` when the tree has no collision
/// geometry.
pub fn lowest_point(data: &MjData<Box<MjModel>>, root_body: usize) -> Option<f64> {
    let model = data.model();
    let ngeom = usize::try_from(model.ffi().ngeom).unwrap_or(0);
    let mut lowest = f64::INFINITY;
    for g in 0..ngeom {
        let body = usize::try_from(model.geom_bodyid()[g]).unwrap_or(0);
        if body == 0 || !collides(model, g) || !in_tree(model, body, root_body) {
            continue;
        }
        let p = data.geom_xpos()[g];
        // Row-major: R[row][col] at 3·row + col; the world's down in the geom's frame is minus
        // the matrix's third row.
        let r = data.geom_xmat()[g];
        let Some(down) = reach(model, g, [-r[6], -r[7], -r[8]]) else {
            continue;
        };
        let low = p[2] - down;
        lowest = lowest.min(low);
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
    let s = model.geom_size()[g];
    let across = (d[0] * d[0] + d[1] * d[1]).sqrt();
    Some(match model.geom_type()[g] {
        G::mjGEOM_SPHERE => s[0],
        G::mjGEOM_CAPSULE => s[0] + s[1] * d[2].abs(),
        G::mjGEOM_CYLINDER => s[0] * across + s[1] * d[2].abs(),
        G::mjGEOM_BOX => (0..3).map(|k| s[k] * d[k].abs()).sum(),
        G::mjGEOM_ELLIPSOID => (0..3).map(|k| (s[k] * d[k]).powi(2)).sum::<f64>().sqrt(),
        G::mjGEOM_MESH => mesh_vertices(model, g)?
            .iter()
            .map(|v| f64::from(v[0]) * d[0] + f64::from(v[1]) * d[1] + f64::from(v[2]) * d[2])
            .max_by(f64::total_cmp)?,
        _ => return None,
    })
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
