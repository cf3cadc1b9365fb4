//! The robot as a URDF, written from the model MuJoCo compiled, for the viewers that read a
//! robot's description from `/robot_description` (Rerun's MCAP importer, Foxglove's URDF layer,
//! RViz): one link per body of the robot's tree, named as the body (the frames `/tf` moves), one
//! joint per body below the root — revolute or continuous for a hinge, prismatic for a slide,
//! fixed otherwise — and each visible geom as a visual.
//!
//! URDF has boxes, spheres, cylinders and meshes by file: a capsule is drawn as a cylinder over
//! its whole length, an ellipsoid as the sphere of its largest radius, a mesh as its bounding box
//! (the recording carries no mesh files; the Foxglove scene on `/robot` has the exact meshes).
//! A joint's axis passes through its child link's origin (an MJCF hinge placed off its body's
//! origin is drawn about the origin; `/tf` carries the true poses each tick).

use std::fmt::Write as _;

use mujoco_rs::mujoco_c::mjtJoint as J;
use mujoco_rs::prelude::MjModel;
use mujoco_rs::wrappers::mj_model::MjtObjBase;
use robots::spatial;

use crate::robot3d::{Shape, Visual, visuals};

/// The URDF of the tree under `root_body`, the robot named `name`; each MJCF joint named as
/// `joint_name` maps it (robot.toml's names for its joints).
pub fn urdf(model: &MjModel, name: &str, root_body: usize, joint_name: &dyn Fn(&str) -> String) -> String {
    let body_name = |b: usize| {
        model
            .id_to_name(MjtObjBase::mjOBJ_BODY, b)
            .map_or_else(|| format!("body{b}"), str::to_owned)
    };
    let nbody = usize::try_from(model.ffi().nbody).unwrap_or(0);
    let bodies: Vec<usize> = (1..nbody)
        .filter(|&b| sim2real::placement::in_tree(model, b, root_body))
        .collect();
    let all = visuals(model, root_body);
    let mut out = String::new();
    let _ = writeln!(out, "<?xml version=\"1.0\"?>\n<robot name=\"{}\">", xml(name));
    for &b in &bodies {
        let _ = writeln!(out, "  <link name=\"{}\">", xml(&body_name(b)));
        for v in all.iter().filter(|v| v.body == b) {
            visual(&mut out, model, v);
        }
        out.push_str("  </link>\n");
    }
    for &b in bodies.iter().filter(|&&b| b != root_body) {
        let parent = usize::try_from(model.body_parentid()[b]).unwrap_or(0);
        let count = usize::try_from(model.body_jntnum()[b]).unwrap_or(0);
        let first = usize::try_from(model.body_jntadr()[b]).ok();
        let single = first.filter(|_| count == 1);
        let kind = single.map(|j| model.jnt_type()[j]);
        let (urdf_kind, joint) = match (kind, single) {
            (Some(J::mjJNT_HINGE), Some(j)) if model.jnt_limited()[j] => ("revolute", Some(j)),
            (Some(J::mjJNT_HINGE), Some(j)) => ("continuous", Some(j)),
            (Some(J::mjJNT_SLIDE), Some(j)) => ("prismatic", Some(j)),
            _ => ("fixed", None),
        };
        let name = match joint.and_then(|j| model.id_to_name(MjtObjBase::mjOBJ_JOINT, j)) {
            Some(n) => joint_name(n),
            None => format!("{}_fixed", body_name(b)),
        };
        let p = model.body_pos()[b];
        let q = model.body_quat()[b];
        let _ = writeln!(out, "  <joint name=\"{}\" type=\"{urdf_kind}\">", xml(&name));
        let _ = writeln!(
            out,
            "    <parent link=\"{}\"/>\n    <child link=\"{}\"/>",
            xml(&body_name(parent)),
            xml(&body_name(b))
        );
        origin(&mut out, "    ", [p[0], p[1], p[2], q[0], q[1], q[2], q[3]]);
        if let Some(j) = joint {
            let a = model.jnt_axis()[j];
            let _ = writeln!(out, "    <axis xyz=\"{} {} {}\"/>", a[0], a[1], a[2]);
            if urdf_kind != "continuous" {
                let [lo, hi] = model.jnt_range()[j];
                let effort = if model.jnt_actfrclimited()[j] {
                    let [a, b] = model.jnt_actfrcrange()[j];
                    a.abs().max(b.abs())
                } else {
                    0.0
                };
                let _ = writeln!(
                    out,
                    "    <limit lower=\"{lo}\" upper=\"{hi}\" effort=\"{effort}\" velocity=\"0\"/>"
                );
            }
        }
        out.push_str("  </joint>\n");
    }
    out.push_str("</robot>\n");
    out
}

/// One geom as a `<visual>`.
fn visual(out: &mut String, model: &MjModel, v: &Visual) {
    let mut at = v.at;
    let geometry = match v.shape {
        Shape::Box(h) => format!("<box size=\"{} {} {}\"/>", 2.0 * h[0], 2.0 * h[1], 2.0 * h[2]),
        Shape::Sphere(r) => format!("<sphere radius=\"{r}\"/>"),
        Shape::Ellipsoid(r) => format!("<sphere radius=\"{}\"/>", r[0].max(r[1]).max(r[2])),
        Shape::Cylinder(r, half) => format!("<cylinder radius=\"{r}\" length=\"{}\"/>", 2.0 * half),
        Shape::Capsule(r, half) => format!("<cylinder radius=\"{r}\" length=\"{}\"/>", 2.0 * (half + r)),
        Shape::Mesh => {
            let Some(vertices) = sim2real::placement::mesh_vertices(model, v.geom).filter(|v| !v.is_empty())
            else {
                return;
            };
            let mut lo = [f64::INFINITY; 3];
            let mut hi = [f64::NEG_INFINITY; 3];
            for p in vertices {
                for k in 0..3 {
                    lo[k] = lo[k].min(f64::from(p[k]));
                    hi[k] = hi[k].max(f64::from(p[k]));
                }
            }
            // The box's centre, in the geom's frame, moved into the body's.
            let centre = spatial::scale(spatial::add(lo, hi), 0.5);
            let c = spatial::add(
                [at[0], at[1], at[2]],
                spatial::quat_rotate([at[3], at[4], at[5], at[6]], centre),
            );
            at[..3].copy_from_slice(&c);
            format!(
                "<box size=\"{} {} {}\"/>",
                hi[0] - lo[0],
                hi[1] - lo[1],
                hi[2] - lo[2]
            )
        }
    };
    let _ = writeln!(out, "    <visual>");
    origin(out, "      ", at);
    let [r, g, b, a] = v.rgba;
    let _ = writeln!(
        out,
        "      <geometry>{geometry}</geometry>\n      <material name=\"geom{}\"><color rgba=\"{r} {g} {b} {a}\"/></material>\n    </visual>",
        v.geom
    );
}

/// `<origin>` of a pose `[x, y, z, w, qx, qy, qz]`: URDF's roll, pitch, yaw are about the fixed
/// x, y, z axes in turn, the Z-Y-X angles of `spatial`.
fn origin(out: &mut String, indent: &str, at: [f64; 7]) {
    let rpy = spatial::rpy_of_quat([at[3], at[4], at[5], at[6]]);
    let _ = writeln!(
        out,
        "{indent}<origin xyz=\"{} {} {}\" rpy=\"{} {} {}\"/>",
        at[0], at[1], at[2], rpy[0], rpy[1], rpy[2]
    );
}

/// Text safe inside an XML attribute.
fn xml(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('"', "&quot;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
}
