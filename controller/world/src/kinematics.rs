//! The robot as it measures itself through its own model, once per tick: the anchor's pose, the
//! tracked bodies, the root's rate, the feet and their soles' contact points, the legs' Jacobians
//! for the estimator, and the robot's keypoints.

use std::sync::Arc;

use mujoco_rs::prelude::{MjData, MjModel};
use mujoco_rs::wrappers::mj_model::MjtObjBase;
use robots::{Robot, spatial};
use sim2real::model_index::{self, ModelIndex};

/// The robot's model could not give the reference's body positions.
#[derive(Debug, thiserror::Error)]
pub enum KinematicsError {
    /// MuJoCo could not load the model.
    #[error(transparent)]
    Model(#[from] sim2real::mujoco::MujocoError),
    /// The model lacks a body or joint the robot names.
    #[error(transparent)]
    Names(#[from] model_index::ModelIndexError),
    /// A keypoint the robot does not map.
    #[error("{0}")]
    Frame(String),
}

/// The robot as it measures itself, through its own model, once per tick: the joints as
/// measured, the root turned so the IMU's frame has the IMU's orientation, and placed where the
/// run knows the robot is (simulation ground truth; the model's origin otherwise). Gives the
/// anchor's pose, the tracked bodies' positions and the root's angular velocity. Allocates
/// nothing per tick (MuJoCo's kinematics works in its own arena).
pub struct RobotKinematics {
    data: MjData<Arc<MjModel>>,
    root_qpos: usize,
    joint_qpos: Vec<usize>,
    imu: model_index::FrameId,
    anchor: Option<usize>,
    bodies: Vec<usize>,
    /// The robot's feet (robot.toml order), and how far each foot's origin sits above its sole.
    feet: Vec<usize>,
    /// Each foot's sole: the points of its geoms that can touch the floor, in its own frame.
    soles: Vec<Sole>,
    /// Each foot's leg: the degrees of freedom between the root and the foot, each with its
    /// robot joint.
    legs: Vec<Vec<(usize, usize)>>,
    /// Each leg's weight (every body below the root on the foot's side: hip to toe), N.
    leg_weights: Vec<f64>,
    /// Scratch for a point's Jacobian (3 × nv).
    jac: Vec<f64>,
    /// Root degrees of freedom in `qvel`, and the joints'.
    root_dof: usize,
    joint_dof: Vec<usize>,
    /// Root → world, this tick.
    root_rotation: [f64; 4],
    root_position: [f64; 3],
    /// The IMU frame's orientation in the root's frame, this tick.
    imu_in_root: [f64; 4],
    /// Keypoints on the robot (robot.toml `[keypoints]`): frame and offset in it.
    keypoints: Vec<(model_index::FrameId, [f64; 3])>,
}

impl std::fmt::Debug for RobotKinematics {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RobotKinematics")
            .field("anchor", &self.anchor)
            .field("bodies", &self.bodies)
            .finish_non_exhaustive()
    }
}

impl RobotKinematics {
    /// Kinematics of `robot` for `anchor` and `bodies` (MJCF body names).
    pub fn new(robot: &Robot, anchor: Option<&str>, bodies: &[String]) -> Result<Self, KinematicsError> {
        let model = robot.shared_model()?;
        let index = ModelIndex::of_robot(&model, robot)?;
        let imu = model_index::frame(&model, &robot.config.imu.site)?;
        let anchor = anchor.map(|a| model_index::body(&model, a)).transpose()?;
        let bodies = bodies
            .iter()
            .map(|b| model_index::body(&model, b))
            .collect::<Result<Vec<_>, _>>()?;
        let soles = index.feet.iter().map(|&f| Sole::of(&model, f)).collect();
        let legs = index
            .feet
            .iter()
            .map(|&foot| {
                let mut dofs = Vec::new();
                let mut body = foot;
                while body != index.root_body && body != 0 {
                    let (adr, num) = (model.body_dofadr()[body], model.body_dofnum()[body]);
                    for dof in adr.max(0) as usize..(adr.max(0) + num) as usize {
                        if let Some(r) = index.joints.iter().position(|j| j.dof == dof) {
                            dofs.push((dof, r));
                        }
                    }
                    body = model.body_parentid()[body] as usize;
                }
                dofs
            })
            .collect();
        let g = spatial::norm(model.opt().gravity);
        let parents = model.body_parentid();
        let masses = model.body_mass();
        let leg_weights = index
            .feet
            .iter()
            .map(|&foot| {
                // The leg's top: the highest body on the foot's path with no other foot below it
                // (a waist carrying both legs is not one leg's).
                let ancestors = |mut b: usize| {
                    let mut up = Vec::new();
                    while b != 0 {
                        up.push(b);
                        b = parents[b] as usize;
                    }
                    up
                };
                let others: Vec<usize> = index
                    .feet
                    .iter()
                    .filter(|&&f| f != foot)
                    .flat_map(|&f| ancestors(f))
                    .collect();
                let mut top = foot;
                loop {
                    let parent = parents[top] as usize;
                    if parent == 0 || parent == index.root_body || others.contains(&parent) {
                        break;
                    }
                    top = parent;
                }
                let below_top = |mut b: usize| loop {
                    if b == top {
                        return true;
                    }
                    if b == 0 || b == index.root_body {
                        return false;
                    }
                    b = parents[b] as usize;
                };
                (0..masses.len())
                    .filter(|&b| below_top(b))
                    .map(|b| masses[b])
                    .sum::<f64>()
                    * g
            })
            .collect();
        let nv = model.ffi().nv as usize;
        Ok(Self {
            root_qpos: index.root.qpos,
            joint_qpos: index.joints.iter().map(|j| j.qpos).collect(),
            root_dof: index.root.dof,
            joint_dof: index.joints.iter().map(|j| j.dof).collect(),
            feet: index.feet.clone(),
            soles,
            legs,
            leg_weights,
            jac: vec![0.0; 3 * nv],
            data: MjData::new(model),
            imu,
            anchor,
            bodies,
            root_rotation: [1.0, 0.0, 0.0, 0.0],
            root_position: [0.0; 3],
            imu_in_root: [1.0, 0.0, 0.0, 0.0],
            keypoints: Vec::new(),
        })
    }

    /// Tracks these keypoints of `robot`'s `[keypoints]` map (by name), in this order.
    pub fn track_keypoints(&mut self, robot: &Robot, names: &[String]) -> Result<(), KinematicsError> {
        let model = self.data.model();
        let mut keypoints = Vec::with_capacity(names.len());
        for name in names {
            let k = robot.config.keypoints.get(name).ok_or_else(|| {
                KinematicsError::Frame(format!("keypoint {name:?} is not in robot.toml's [keypoints]"))
            })?;
            keypoints.push((model_index::frame(model, k.frame())?, k.offset()));
        }
        self.keypoints = keypoints;
        Ok(())
    }

    /// World position of tracked keypoint `k` with the root at `root_position` (this tick's
    /// orientation and joints).
    pub fn keypoint_position_from(&self, k: usize, root_position: [f64; 3]) -> [f64; 3] {
        let (frame, offset) = self.keypoints[k];
        let (p, m) = match frame {
            model_index::FrameId::Body(b) => (self.data.xpos()[b], self.data.xmat()[b]),
            model_index::FrameId::Site { site, .. } => {
                (self.data.site_xpos()[site], self.data.site_xmat()[site])
            }
        };
        let rows = [[m[0], m[1], m[2]], [m[3], m[4], m[5]], [m[6], m[7], m[8]]];
        let p = spatial::add(p, spatial::mat_apply(&rows, offset));
        spatial::add(spatial::quat_rotate(self.root_rotation, p), root_position)
    }

    /// Where the root is placed this tick (the origin when unknown).
    pub fn root_position(&self) -> [f64; 3] {
        self.root_position
    }

    /// Poses the model: `imu_quat` the IMU frame's measured orientation, `q` and `qd` the joints
    /// (robot order), `root_position` where the root is, if known.
    pub fn update(&mut self, imu_quat: [f64; 4], q: &[f64], qd: &[f64], root_position: Option<[f64; 3]>) {
        // The model at its origin, unturned and still: every frame's pose and velocity is then
        // relative to the root.
        let r = self.root_qpos;
        let qpos = self.data.qpos_mut();
        qpos[r..r + 7].copy_from_slice(&[0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0]);
        for (&adr, &v) in self.joint_qpos.iter().zip(q) {
            qpos[adr] = v;
        }
        let d = self.root_dof;
        let qvel = self.data.qvel_mut();
        qvel[d..d + 6].fill(0.0);
        for (&adr, &v) in self.joint_dof.iter().zip(qd) {
            qvel[adr] = v;
        }
        self.data.kinematics();
        if !self.feet.is_empty() {
            // Velocities, and the bias forces (gravity, Coriolis) the legs' loads are read against.
            self.data.com_pos();
            self.data.fwd_velocity();
        }
        let m = match self.imu {
            model_index::FrameId::Body(b) => self.data.xmat()[b],
            model_index::FrameId::Site { site, .. } => self.data.site_xmat()[site],
        };
        self.imu_in_root =
            spatial::quat_of_mat(&[[m[0], m[1], m[2]], [m[3], m[4], m[5]], [m[6], m[7], m[8]]]);
        self.root_rotation =
            spatial::quat_normalize(spatial::quat_mul(imu_quat, spatial::quat_conj(self.imu_in_root)));
        self.set_root_position(root_position);
    }

    /// Places the root, when its position is known (else at the origin).
    pub fn set_root_position(&mut self, root_position: Option<[f64; 3]>) {
        self.root_position = root_position.unwrap_or([0.0; 3]);
    }

    /// The model's gravity, m/s².
    pub fn gravity(&self) -> [f64; 3] {
        self.data.model().opt().gravity
    }

    /// World position of tracked body `k` with the root at `root_position` (this tick's
    /// orientation and joints).
    pub fn body_position_from(&self, k: usize, root_position: [f64; 3]) -> [f64; 3] {
        let p = self.data.xpos()[self.bodies[k]];
        spatial::add(spatial::quat_rotate(self.root_rotation, p), root_position)
    }

    /// Tracked body `k`'s position in the root's frame (this tick's joints).
    pub fn body_in_root(&self, k: usize) -> [f64; 3] {
        self.data.xpos()[self.bodies[k]]
    }

    /// How many bodies it tracks.
    pub fn tracked_bodies(&self) -> usize {
        self.bodies.len()
    }

    /// World pose of a body posed relative to the root.
    fn world(&self, body: usize) -> [f64; 7] {
        let (p, q) = (self.data.xpos()[body], self.data.xquat()[body]);
        let p = spatial::add(spatial::quat_rotate(self.root_rotation, p), self.root_position);
        let q = spatial::quat_mul(self.root_rotation, q);
        [p[0], p[1], p[2], q[0], q[1], q[2], q[3]]
    }

    /// The anchor's world pose `[x, y, z, w, qx, qy, qz]` (the root's without an anchor).
    pub fn anchor_pose(&self) -> [f64; 7] {
        match self.anchor {
            Some(a) => self.world(a),
            None => {
                let (p, q) = (self.root_position, self.root_rotation);
                [p[0], p[1], p[2], q[0], q[1], q[2], q[3]]
            }
        }
    }

    /// The root's orientation in the world this tick (from the IMU).
    pub fn root_rotation(&self) -> [f64; 4] {
        self.root_rotation
    }

    /// Feet (robot.toml's `feet`).
    pub fn feet(&self) -> usize {
        self.feet.len()
    }

    /// Foot `k`'s origin relative to the root, in the root's frame.
    pub fn foot_in_root(&self, k: usize) -> [f64; 3] {
        self.data.xpos()[self.feet[k]]
    }

    /// The ground's vertical push on foot `k`, N, from the joint torques the legs report
    /// (`tau`, robot order): the static balance of the leg, `Jᵀ f = bias − τ`, solved for the
    /// force `f` at `point`, the foot's contact point relative to the root ([`Self::foot_contact`]),
    /// in least squares. NaN without three leg joints.
    #[allow(
        unsafe_code,
        reason = "MuJoCo's mj_jac into a buffer this struct owns (the safe wrapper allocates)"
    )]
    pub fn foot_load(&mut self, k: usize, point: [f64; 3], tau: &[f64]) -> f64 {
        let leg = &self.legs[k];
        if leg.len() < 3 {
            return f64::NAN;
        }
        let nv = self.jac.len() / 3;
        // SAFETY: model and data are live and matched; `jac` holds 3 × nv values; `point` is a
        // 3-vector; the body id comes from the model.
        unsafe {
            mujoco_rs::mujoco_c::mj_jac(
                self.data.model().ffi(),
                self.data.ffi(),
                self.jac.as_mut_ptr(),
                std::ptr::null_mut(),
                &point,
                self.feet[k] as i32,
            );
        }
        let bias = self.data.qfrc_bias();
        // Normal equations (J Jᵀ) f = J (bias − τ) over the leg's degrees of freedom.
        let (mut jjt, mut rhs) = ([[0.0; 3]; 3], [0.0; 3]);
        for &(dof, joint) in leg {
            let b = bias[dof] - tau.get(joint).copied().unwrap_or(f64::NAN);
            for (r, (row, rhs_r)) in jjt.iter_mut().zip(rhs.iter_mut()).enumerate() {
                let jr = self.jac[r * nv + dof];
                *rhs_r += jr * b;
                for (c, cell) in row.iter_mut().enumerate() {
                    *cell += jr * self.jac[c * nv + dof];
                }
            }
        }
        let inverse = spatial::rows(spatial::mat(&jjt).inverse());
        let f = spatial::mat_apply(&inverse, rhs);
        spatial::quat_rotate(self.root_rotation, f)[2]
    }

    /// What the estimator takes from the legs this tick (every foot's place, contact point and
    /// its speed, sole depth, load from the joint torques `tau` (robot order), leg weight), as
    /// posed by [`Self::update`]; no foot switches.
    pub fn legs(&mut self, tau: &[f64]) -> crate::estimator::LegKinematics {
        let mut legs = crate::estimator::LegKinematics::default();
        for f in 0..self.feet().min(crate::estimator::MAX_FEET) {
            legs.position[f] = self.foot_in_root(f);
            (legs.contact[f], legs.contact_velocity[f]) = self.foot_contact(f);
            legs.sole_depth[f] = self.sole_depth(f);
            legs.load[f] = self.foot_load(f, legs.contact[f], tau);
            legs.leg_weight[f] = self.leg_weight(f);
        }
        legs
    }

    /// Leg `k`'s weight (hip to toe), N: what a swinging leg's own dynamics can make its load
    /// read, the scale of the contact thresholds.
    pub fn leg_weight(&self, k: usize) -> f64 {
        self.leg_weights[k]
    }

    /// The robot's weight, N.
    pub fn weight(&self) -> f64 {
        let m = self.data.model();
        m.body_mass().iter().sum::<f64>() * spatial::norm(m.opt().gravity)
    }

    /// How far foot `k`'s origin sits above the lowest point of its geoms (its sole), in its own
    /// frame.
    pub fn sole_depth(&self, k: usize) -> f64 {
        -self.soles[k].points[..self.soles[k].len]
            .iter()
            .map(|p| p[2])
            .fold(0.0, f64::min)
    }

    /// Where foot `k` touches the floor and how that point moves, relative to the root in the
    /// root's frame: the middle of the sole points lowest in the world (within 5 mm of the
    /// lowest) — the sole's centre when the foot is flat, its edge when it rolls onto it, which
    /// stays put while the origin moves.
    pub fn foot_contact(&self, k: usize) -> ([f64; 3], [f64; 3]) {
        let (body, sole) = (self.feet[k], &self.soles[k]);
        let (x, m) = (self.data.xpos()[body], self.data.xmat()[body]);
        let r = [[m[0], m[1], m[2]], [m[3], m[4], m[5]], [m[6], m[7], m[8]]];
        let mut points = [[0.0; 3]; MAX_SOLE_POINTS];
        let mut lowest = f64::INFINITY;
        for (out, p) in points.iter_mut().zip(&sole.points[..sole.len]) {
            *out = spatial::add(x, spatial::mat_apply(&r, *p));
            lowest = lowest.min(spatial::quat_rotate(self.root_rotation, *out)[2]);
        }
        let (mut sum, mut count) = ([0.0; 3], 0.0f64);
        for p in &points[..sole.len] {
            if spatial::quat_rotate(self.root_rotation, *p)[2] <= lowest + PATCH_BAND_M {
                sum = spatial::add(sum, *p);
                count += 1.0;
            }
        }
        let c = spatial::scale(sum, 1.0 / count.max(1.0));
        let v = self.data.object_velocity(MjtObjBase::mjOBJ_BODY, body, false);
        let velocity = spatial::add(
            [v[3], v[4], v[5]],
            spatial::cross([v[0], v[1], v[2]], spatial::sub(c, x)),
        );
        (c, velocity)
    }

    /// A vector in the IMU's frame (a gyro reading), in the root's frame.
    pub fn imu_to_root(&self, v: [f64; 3]) -> [f64; 3] {
        spatial::quat_rotate(self.imu_in_root, v)
    }
}

/// Sole points a foot keeps at most.
const MAX_SOLE_POINTS: usize = 8;

/// Sole points this close to the lowest one touch the floor with it, m.
const PATCH_BAND_M: f64 = 0.005;

/// The points of a foot that can touch the floor, in its own frame: of each collision geom, the
/// four corners of a box's lowest face, a mesh's extreme vertices (front, back, sides) among
/// those within the patch band of its lowest, and the lowest point along the body's z of other
/// shapes (`sim2real::placement::reach`).
#[derive(Debug, Clone, Copy)]
struct Sole {
    points: [[f64; 3]; MAX_SOLE_POINTS],
    len: usize,
}

impl Sole {
    fn of(model: &MjModel, body: usize) -> Self {
        use mujoco_rs::mujoco_c::_mjtGeomBase as G;
        use sim2real::placement::{collides, mesh_vertices, reach};
        let mut sole = Self {
            points: [[0.0; 3]; MAX_SOLE_POINTS],
            len: 0,
        };
        fn push(sole: &mut Sole, p: [f64; 3]) {
            if sole.len < MAX_SOLE_POINTS {
                sole.points[sole.len] = p;
                sole.len += 1;
            }
        }
        for g in 0..model.ffi().ngeom as usize {
            if model.geom_bodyid()[g] as usize != body || !collides(model, g) {
                continue;
            }
            let (p, q, s) = (model.geom_pos()[g], model.geom_quat()[g], model.geom_size()[g]);
            let m = spatial::mat_of_quat(q);
            match model.geom_type()[g] {
                G::mjGEOM_BOX => {
                    let mut corners = [[0.0; 3]; 8];
                    for (k, c) in corners.iter_mut().enumerate() {
                        let sign = |bit: usize| if k & bit == 0 { -1.0 } else { 1.0 };
                        let local = [sign(1) * s[0], sign(2) * s[1], sign(4) * s[2]];
                        *c = spatial::add(p, spatial::mat_apply(&m, local));
                    }
                    corners.sort_by(|a, b| a[2].total_cmp(&b[2]));
                    corners[..4].iter().for_each(|c| push(&mut sole, *c));
                }
                G::mjGEOM_MESH => {
                    let in_body = |v: &[f32; 3]| spatial::add(p, spatial::mat_apply(&m, v.map(f64::from)));
                    let Some(vertices) = mesh_vertices(model, g) else {
                        continue;
                    };
                    let lowest = vertices
                        .iter()
                        .map(|v| in_body(v)[2])
                        .fold(f64::INFINITY, f64::min);
                    let flat = vertices
                        .iter()
                        .map(in_body)
                        .filter(|v| v[2] <= lowest + PATCH_BAND_M);
                    // Front, back, left, right of the flat part: the patch's extent.
                    let mut extreme = [[0.0; 3], [0.0; 3], [0.0; 3], [0.0; 3]];
                    let mut best = [f64::NEG_INFINITY; 4];
                    for v in flat {
                        for (k, score) in [v[0], -v[0], v[1], -v[1]].into_iter().enumerate() {
                            if score > best[k] {
                                (best[k], extreme[k]) = (score, v);
                            }
                        }
                    }
                    extreme.iter().for_each(|c| push(&mut sole, [c[0], c[1], lowest]));
                }
                _ => {
                    // The body's down in the geom's frame: minus the third row of its rotation.
                    let Some(extent) = reach(model, g, [-m[2][0], -m[2][1], -m[2][2]]) else {
                        continue;
                    };
                    push(&mut sole, [p[0], p[1], p[2] - extent]);
                }
            }
        }
        if sole.len == 0 {
            push(&mut sole, [0.0; 3]);
        }
        sole
    }
}
