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
        let collides = model.geom_contype()[g] != 0 || model.geom_conaffinity()[g] != 0;
        if body == 0 || !collides || !in_tree(model, body, root_body) {
            continue;
        }
        let p = data.geom_xpos()[g];
        // Row-major: R[row][col] at 3·row + col; column k is the geom's k-th axis in the world.
        let r = data.geom_xmat()[g];
        let axis_z = |k: usize| r[6 + k];
        let size = model.geom_size()[g];
        let low = match model.geom_type()[g] {
            G::mjGEOM_SPHERE => p[2] - size[0],
            G::mjGEOM_CAPSULE => p[2] - size[1] * axis_z(2).abs() - size[0],
            G::mjGEOM_CYLINDER => {
                let tilt = (1.0 - axis_z(2) * axis_z(2)).max(0.0).sqrt();
                p[2] - size[1] * axis_z(2).abs() - size[0] * tilt
            }
            G::mjGEOM_BOX => p[2] - (0..3).map(|k| size[k] * axis_z(k).abs()).sum::<f64>(),
            G::mjGEOM_ELLIPSOID => p[2] - (0..3).map(|k| (size[k] * axis_z(k)).powi(2)).sum::<f64>().sqrt(),
            G::mjGEOM_MESH => match mesh_lowest(model, g, p, &r) {
                Some(z) => z,
                None => continue,
            },
            // Planes, height fields and the rest have no extent a robot stands on.
            _ => continue,
        };
        lowest = lowest.min(low);
    }
    lowest.is_finite().then_some(lowest)
}

/// Whether `body` is `root` or one of its descendants.
fn in_tree(model: &MjModel, mut body: usize, root: usize) -> bool {
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

/// The lowest world height of mesh geom `g`'s vertices (stored in the geom's frame once compiled).
fn mesh_lowest(model: &MjModel, g: usize, p: [f64; 3], r: &[f64; 9]) -> Option<f64> {
    let mesh = usize::try_from(model.geom_dataid()[g]).ok()?;
    let start = usize::try_from(model.mesh_vertadr()[mesh]).ok()?;
    let count = usize::try_from(model.mesh_vertnum()[mesh]).ok()?;
    model.mesh_vert()[start..start + count]
        .iter()
        .map(|v| p[2] + r[6] * f64::from(v[0]) + r[7] * f64::from(v[1]) + r[8] * f64::from(v[2]))
        .min_by(f64::total_cmp)
}
