//! Inverse kinematics on the robot's own MuJoCo model: damped least squares on MuJoCo's Jacobians
//! (`mj_jac`) of the frames the retargeting map pairs, weighted per frame, within the joints'
//! limits. The root is free (offline retargeting) or held (teleoperation); joints may be locked.

use std::sync::Arc;

use crate::body_map::Frame;
use mujoco_rs::prelude::{MjData, MjModel};
use robots::spatial;
use robots::{OrientationCompare, Robot};
use sim2real::model_index::{self, FrameId};

use crate::HumanError;

/// Where a frame is on the model.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum FrameRef {
    Body(usize),
    Site { site: usize, body: usize },
}

/// A frame's goal, with the weights of its position and orientation errors.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct IkGoal {
    /// Where the frame should be.
    pub frame: Frame,
    /// Weight of the position error (0: free).
    pub position_weight: f64,
    /// Weight of the orientation error (0: free).
    pub orientation_weight: f64,
}

#[derive(Debug, Clone, Copy)]
struct Slot {
    qpos: usize,
    dof: usize,
    limits: [f64; 2],
    locked: bool,
}

/// A solver for one robot and one set of frames.
#[derive(Debug)]
pub struct Ik {
    data: MjData<Arc<MjModel>>,
    frames: Vec<FrameRef>,
    root: Option<(usize, usize)>,
    joints: Vec<Slot>,
    compare: Vec<(OrientationCompare, [f64; 3])>,
    /// Damping λ of the least squares.
    pub damping: f64,
    /// Largest joint step per iteration, rad.
    pub max_step: f64,
    /// Weight of keeping the colliding geoms out of the floor (0: the floor is not looked at).
    pub floor_weight: f64,
    /// Weight of each joint's distance from its anchor, per radian (0: none).
    pub anchor_weight: f64,
    anchor: Vec<f64>,
    /// Per body, the active degrees of freedom that move it (its chain up to the world).
    chains: Vec<Vec<usize>>,
    system: NormalEquations,
    dq: Vec<f64>,
    qpos: Vec<f64>,
}

impl Ik {
    /// A solver on `robot`'s MJCF for `frames` (body or site names). `free_root`: the root moves
    /// too; `locked`: robot joints (policy order) the solver leaves where they are.
    pub fn new(
        robot: &Robot,
        frames: &[String],
        free_root: bool,
        locked: &[usize],
    ) -> Result<Self, HumanError> {
        let model = robot.shared_model()?;
        let frames = frames
            .iter()
            .map(|f| match model_index::frame(&model, f) {
                Ok(FrameId::Body(b)) => Ok(FrameRef::Body(b)),
                Ok(FrameId::Site { site, body }) => Ok(FrameRef::Site { site, body }),
                Err(e) => Err(HumanError::Model(e)),
            })
            .collect::<Result<Vec<_>, _>>()?;
        // A fixed-base model (no free root) solves with the root where the model puts it.
        let root_body = model_index::body(&model, &robot.config.root_body)?;
        let root_joint = model.body_jntadr()[root_body];
        let root = (root_joint >= 0).then(|| {
            let j = root_joint as usize;
            (model.jnt_qposadr()[j] as usize, model.jnt_dofadr()[j] as usize)
        });
        let joints = robot
            .config
            .joints
            .iter()
            .enumerate()
            .map(|(k, j)| {
                let ids = model_index::joint(&model, &j.mjcf_joint)?;
                Ok(Slot {
                    qpos: ids.qpos,
                    dof: ids.dof,
                    limits: j.position_limits,
                    locked: locked.contains(&k),
                })
            })
            .collect::<Result<Vec<_>, HumanError>>()?;
        let nv = model.ffi().nv as usize;
        let mut active = vec![false; nv];
        if let (true, Some((_, dof))) = (free_root, root) {
            active[dof..dof + 6].fill(true);
        }
        for s in &joints {
            active[s.dof] = !s.locked;
        }
        let chains: Vec<Vec<usize>> = (0..model.ffi().nbody as usize)
            .map(|b| {
                let mut dofs: Vec<usize> = chain_dofs(&model, b).into_iter().filter(|&d| active[d]).collect();
                dofs.sort_unstable();
                dofs
            })
            .collect();
        let nq = model.ffi().nq as usize;
        let n_joints = joints.len();
        let mut data = MjData::new(model);
        data.kinematics();
        Ok(Self {
            data,
            compare: vec![(OrientationCompare::Full, [1.0, 0.0, 0.0]); frames.len()],
            frames,
            root,
            joints,
            damping: 0.05,
            max_step: 0.2,
            floor_weight: 0.0,
            anchor_weight: 0.0,
            anchor: vec![0.0; n_joints],
            chains,
            system: NormalEquations::new(nv),
            dq: vec![0.0; nv],
            qpos: vec![0.0; nq],
        })
    }

    /// The robot joints (policy order) on the kinematic chain of frame `k`.
    pub fn joints_moving_frame(&self, k: usize) -> Vec<usize> {
        let body = match self.frames[k] {
            FrameRef::Body(b) => b,
            FrameRef::Site { body, .. } => body,
        };
        let dofs = chain_dofs(self.data.model(), body);
        (0..self.joints.len())
            .filter(|&j| dofs.contains(&self.joints[j].dof))
            .collect()
    }

    /// The robot joints (policy order) on the kinematic chain of any of the frames.
    pub fn joints_moving_frames(&self) -> Vec<usize> {
        let mut all: Vec<usize> = (0..self.frames.len())
            .flat_map(|k| self.joints_moving_frame(k))
            .collect();
        all.sort_unstable();
        all.dedup();
        all
    }

    /// Compares only part of frame `k`'s orientation error: the swing (ignoring the twist about
    /// `axis`, in the frame's coordinates) or the twist — for robot frames with fewer rotational
    /// DoF than the human body they follow.
    pub fn set_compare(&mut self, k: usize, mode: OrientationCompare, axis: [f64; 3]) {
        self.compare[k] = (mode, spatial::unit(axis));
    }

    /// Sets the root pose `[x, y, z, w, qx, qy, qz]` and the joints (policy order).
    pub fn set_pose(&mut self, root: [f64; 7], q: &[f64]) {
        if let Some((adr, _)) = self.root {
            self.data.qpos_mut()[adr..adr + 7].copy_from_slice(&root);
        }
        for (s, &v) in self.joints.iter().zip(q) {
            self.data.qpos_mut()[s.qpos] = v;
        }
        self.data.kinematics();
    }

    /// The joints (policy order) that [`Self::anchor_weight`] holds towards.
    pub fn set_anchor(&mut self, q: &[f64]) {
        self.anchor.copy_from_slice(q);
    }

    /// The root pose.
    pub fn root(&self) -> [f64; 7] {
        let mut r = [0.0; 7];
        if let Some((adr, _)) = self.root {
            r.copy_from_slice(&self.data.qpos()[adr..adr + 7]);
        }
        r
    }

    /// The joints (policy order) into `q`.
    pub fn joints(&self, q: &mut [f64]) {
        for (s, out) in self.joints.iter().zip(q) {
            *out = self.data.qpos()[s.qpos];
        }
    }

    /// Where frame `k` is now.
    pub fn frame(&self, k: usize) -> Frame {
        let (pos, m) = match self.frames[k] {
            FrameRef::Body(b) => (self.data.xpos()[b], self.data.xmat()[b]),
            FrameRef::Site { site, .. } => (self.data.site_xpos()[site], self.data.site_xmat()[site]),
        };
        Frame {
            pos,
            rot: [[m[0], m[1], m[2]], [m[3], m[4], m[5]], [m[6], m[7], m[8]]],
        }
    }

    /// The model's data (after the last solve or pose).
    pub fn data(&self) -> &MjData<Arc<MjModel>> {
        &self.data
    }

    /// The lowest point of the robot's colliding geoms (boxes: their corners; others: their
    /// radius) in the current pose, m: below 0 the soles are in the floor.
    pub fn lowest_point(&self) -> f64 {
        let model = self.data.model();
        (0..model.ffi().ngeom as usize)
            .filter_map(|g| self.geom_bottom(g))
            .fold(f64::INFINITY, f64::min)
    }

    /// How low colliding geom `g` of a robot body reaches (boxes: their corners; others: their
    /// radius), m; `None` for the world's geoms and those that collide with nothing.
    fn geom_bottom(&self, g: usize) -> Option<f64> {
        let model = self.data.model();
        if model.geom_contype()[g] == 0 || model.geom_bodyid()[g] == 0 {
            return None;
        }
        let (c, m, s) = (
            self.data.geom_xpos()[g],
            self.data.geom_xmat()[g],
            model.geom_size()[g],
        );
        // Half extent along world z: Σ |R_zk| · size_k for a box (type 6); the radius otherwise.
        let extent = match model.geom_type()[g] as i32 {
            6 => (0..3).map(|k| m[6 + k].abs() * s[k]).sum::<f64>(),
            _ => s[0],
        };
        Some(c[2] - extent)
    }

    /// The root pose that stands the robot in pose `q` with its lowest point on the floor, at the
    /// origin, facing +x.
    pub fn standing_root(&mut self, q: &[f64]) -> [f64; 7] {
        self.set_pose([0.0, 0.0, 1.0, 1.0, 0.0, 0.0, 0.0], q);
        let drop = self.lowest_point();
        self.lift(-drop);
        self.root()
    }

    /// Moves the root up by `dz` (to lift the feet out of the floor).
    pub fn lift(&mut self, dz: f64) {
        if let Some((adr, _)) = self.root {
            self.data.qpos_mut()[adr + 2] += dz;
            self.data.kinematics();
        }
    }

    /// Runs `iterations` damped least-squares steps towards `goals` (one per frame); returns the
    /// weighted error left.
    ///
    /// Each step solves `(JᵀJ + λ²I) dq = Jᵀe` over the model's degrees of freedom, the rows added
    /// over the columns of their own kinematic chain only (a frame's Jacobian is zero off it): the
    /// same step as `Jᵀ(JJᵀ + λ²I)⁻¹e`, in a system of the model's size rather than the goals'.
    pub fn solve(&mut self, goals: &[IkGoal], iterations: usize) -> f64 {
        let nv = self.dq.len();
        let mut residual = 0.0;
        for _ in 0..iterations {
            self.data.kinematics();
            self.data.com_pos();
            self.system.normal.fill(0.0);
            self.system.rhs.fill(0.0);
            let mut squared = 0.0;
            for (k, g) in goals.iter().enumerate() {
                let now = self.frame(k);
                let body = match self.frames[k] {
                    FrameRef::Body(b) => b,
                    FrameRef::Site { body, .. } => body,
                };
                let (jp, jr) = self.data.jac(true, true, &now.pos, body);
                let e_pos = spatial::sub(g.frame.pos, now.pos);
                let mut e_rot = spatial::log(&spatial::mat_mul(&g.frame.rot, &spatial::transpose(&now.rot)));
                // Swing or twist only: project error and Jacobian on (or off) the twist axis.
                let project: Option<[[f64; 3]; 3]> = match self.compare[k] {
                    (OrientationCompare::Full, _) => None,
                    (mode, axis) => {
                        let a = spatial::mat_apply(&now.rot, axis);
                        let along = [0, 1, 2].map(|i| [0, 1, 2].map(|j| a[i] * a[j]));
                        Some(match mode {
                            OrientationCompare::Twist => along,
                            _ => [0, 1, 2]
                                .map(|i| [0, 1, 2].map(|j| f64::from(u8::from(i == j)) - along[i][j])),
                        })
                    }
                };
                if let Some(p) = &project {
                    e_rot = spatial::mat_apply(p, e_rot);
                }
                let chain = &self.chains[body];
                for i in 0..3 {
                    if g.position_weight > 0.0 {
                        squared += self
                            .system
                            .add(chain, g.position_weight, |c| jp[i * nv + c], e_pos[i]);
                    }
                    if g.orientation_weight > 0.0 {
                        let column = |c| match &project {
                            Some(p) => (0..3).map(|m| p[i][m] * jr[m * nv + c]).sum(),
                            None => jr[i * nv + c],
                        };
                        squared += self.system.add(chain, g.orientation_weight, column, e_rot[i]);
                    }
                }
            }
            // The floor: one row per geom below it, pushing it up (a one-sided goal, so only
            // the geoms in the floor count; the frames' goals pick how the robot gets out).
            if self.floor_weight > 0.0 {
                for g in 0..self.data.model().ffi().ngeom as usize {
                    let Some(bottom) = self.geom_bottom(g).filter(|b| *b < 0.0) else {
                        continue;
                    };
                    let body = self.data.model().geom_bodyid()[g] as usize;
                    let at = self.data.geom_xpos()[g];
                    let (jp, _) = self.data.jac(true, false, &at, body);
                    let chain = &self.chains[body];
                    squared += self
                        .system
                        .add(chain, self.floor_weight, |c| jp[2 * nv + c], -bottom);
                }
            }
            // Every joint held towards its anchor (the previous frame): where the goals leave a
            // choice (a straight knee at its limit, a singular arm), the pose does not jump.
            if self.anchor_weight > 0.0 {
                let w2 = self.anchor_weight * self.anchor_weight;
                for (s, a) in self.joints.iter().zip(&self.anchor) {
                    if !s.locked {
                        let e = a - self.data.qpos()[s.qpos];
                        self.system.normal[s.dof * nv + s.dof] += w2;
                        self.system.rhs[s.dof] += w2 * e;
                        squared += w2 * e * e;
                    }
                }
            }
            residual = squared.sqrt();
            for c in 0..nv {
                self.system.normal[c * nv + c] += self.damping * self.damping;
            }
            self.dq.copy_from_slice(&self.system.rhs);
            cholesky_solve(&mut self.system.normal, nv, &mut self.dq);
            let largest = self.dq.iter().fold(0.0f64, |m, d| m.max(d.abs()));
            if largest > self.max_step {
                let k = self.max_step / largest;
                self.dq.iter_mut().for_each(|d| *d *= k);
            }
            self.qpos.copy_from_slice(self.data.qpos());
            self.data.model().integrate_pos(&mut self.qpos, &self.dq, 1.0);
            for s in &self.joints {
                self.qpos[s.qpos] = self.qpos[s.qpos].clamp(s.limits[0], s.limits[1]);
            }
            self.data.qpos_mut().copy_from_slice(&self.qpos);
        }
        self.data.kinematics();
        residual
    }
}

/// The normal equations of one damped least-squares step, `JᵀJ` and `Jᵀe` (nv × nv, nv).
#[derive(Debug)]
struct NormalEquations {
    nv: usize,
    normal: Vec<f64>,
    rhs: Vec<f64>,
    /// One row of the Jacobian on a chain's columns.
    row: Vec<f64>,
}

impl NormalEquations {
    fn new(nv: usize) -> Self {
        Self {
            nv,
            normal: vec![0.0; nv * nv],
            rhs: vec![0.0; nv],
            row: vec![0.0; nv],
        }
    }

    /// Adds the row `weight · column(c)` over the columns `chain` (the Jacobian is zero off its
    /// chain) with its error `weight · err`; returns the squared weighted error.
    fn add(&mut self, chain: &[usize], weight: f64, column: impl Fn(usize) -> f64, err: f64) -> f64 {
        let err = weight * err;
        for (r, &c) in self.row.iter_mut().zip(chain) {
            *r = weight * column(c);
        }
        let nv = self.nv;
        for (a, (&ca, &va)) in chain.iter().zip(&self.row).enumerate() {
            self.rhs[ca] += va * err;
            for (&cb, &vb) in chain[..=a].iter().zip(&self.row) {
                self.normal[ca * nv + cb] += va * vb;
                if ca != cb {
                    self.normal[cb * nv + ca] += va * vb;
                }
            }
        }
        err * err
    }
}

/// The degrees of freedom that move `body`: its own and its ancestors' up to the world.
fn chain_dofs(model: &MjModel, mut body: usize) -> Vec<usize> {
    let mut dofs = Vec::new();
    while body != 0 {
        let (first, count) = (model.body_dofadr()[body], model.body_dofnum()[body]);
        if first >= 0 {
            dofs.extend(first as usize..first as usize + count as usize);
        }
        body = model.body_parentid()[body] as usize;
    }
    dofs
}

/// Solves `a x = b` in place for a symmetric positive definite `a` (n × n, row major).
fn cholesky_solve(a: &mut [f64], n: usize, b: &mut [f64]) {
    for j in 0..n {
        let mut d = a[j * n + j];
        for k in 0..j {
            d -= a[j * n + k] * a[j * n + k];
        }
        let d = d.max(1e-12).sqrt();
        a[j * n + j] = d;
        for i in j + 1..n {
            let mut s = a[i * n + j];
            for k in 0..j {
                s -= a[i * n + k] * a[j * n + k];
            }
            a[i * n + j] = s / d;
        }
    }
    for i in 0..n {
        let mut s = b[i];
        for k in 0..i {
            s -= a[i * n + k] * b[k];
        }
        b[i] = s / a[i * n + i];
    }
    for i in (0..n).rev() {
        let mut s = b[i];
        for k in i + 1..n {
            s -= a[k * n + i] * b[k];
        }
        b[i] = s / a[i * n + i];
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn swing_only_ignores_the_twist_the_head_cannot_make() {
        let robot = Robot::load(&robots::reference_robot_path()).unwrap();
        let mut ik = Ik::new(&robot, &["head".to_owned()], false, &[]).unwrap();
        let q0: Vec<f64> = robot.config.joints.iter().map(|j| j.default_position).collect();
        ik.set_pose([0.0, 0.0, 0.46, 1.0, 0.0, 0.0, 0.0], &q0);
        ik.set_compare(0, OrientationCompare::Swing, [1.0, 0.0, 0.0]);
        let goal = |rot| IkGoal {
            frame: Frame { pos: [0.0; 3], rot },
            position_weight: 0.0,
            orientation_weight: 1.0,
        };
        // A pure roll (twist about the face's forward axis): nothing to do, nothing moves.
        let residual = ik.solve(&[goal(spatial::exp([0.4, 0.0, 0.0]))], 20);
        assert!(residual < 1e-9, "{residual}");
        let mut q = q0.clone();
        ik.joints(&mut q);
        assert_eq!(q, q0);
        // Roll plus a turn to the left: the yaw is followed, the roll ignored.
        let residual = ik.solve(
            &[goal(spatial::mat_mul(
                &spatial::exp([0.0, 0.0, 0.5]),
                &spatial::exp([0.4, 0.0, 0.0]),
            ))],
            50,
        );
        ik.joints(&mut q);
        let yaw = robot
            .config
            .joints
            .iter()
            .position(|j| j.name == "head_yaw")
            .unwrap();
        assert!(
            (q[yaw] - 0.5).abs() < 0.02 && residual < 1e-3,
            "yaw {} residual {residual}",
            q[yaw]
        );
    }

    #[test]
    fn cholesky_solves_a_small_system() {
        let mut a = vec![4.0, 2.0, 0.6, 2.0, 5.0, 1.0, 0.6, 1.0, 3.0];
        let x = [1.0, -2.0, 0.5];
        let mut b: Vec<f64> = (0..3)
            .map(|i| (0..3).map(|k| a[i * 3 + k] * x[k]).sum())
            .collect();
        cholesky_solve(&mut a, 3, &mut b);
        assert!(b.iter().zip(x).all(|(u, v)| (u - v).abs() < 1e-12), "{b:?}");
    }

    #[test]
    fn a_hand_reaches_a_reachable_point_within_limits() {
        let robot = Robot::load(&robots::reference_robot_path()).unwrap();
        let frames = vec!["left_hand".to_owned()];
        let mut ik = Ik::new(&robot, &frames, false, &[]).unwrap();
        let q0: Vec<f64> = robot.config.joints.iter().map(|j| j.default_position).collect();
        ik.set_pose([0.0, 0.0, 0.46, 1.0, 0.0, 0.0, 0.0], &q0);
        // A point forward of the left shoulder, at shoulder height, the arm's length away.
        let shoulder = [0.0, 0.14, 0.46 + 0.05 + 0.17];
        let goal = IkGoal {
            frame: Frame {
                pos: [shoulder[0] + 0.25, shoulder[1], shoulder[2] - 0.05],
                rot: spatial::IDENTITY,
            },
            position_weight: 1.0,
            orientation_weight: 0.0,
        };
        let residual = ik.solve(&[goal], 50);
        assert!(residual < 0.005, "residual {residual}");
        let mut q = q0.clone();
        ik.joints(&mut q);
        for (j, v) in robot.config.joints.iter().zip(&q) {
            assert!(
                *v >= j.position_limits[0] && *v <= j.position_limits[1],
                "{}",
                j.name
            );
        }
        // The legs, not asked for anything, did not move; the root is held.
        assert_eq!(&q[..12], &q0[..12]);
    }

    #[test]
    fn a_sole_in_the_floor_is_pushed_out_by_the_leg_not_the_body() {
        let robot = Robot::load(&robots::reference_robot_path()).unwrap();
        let frames = vec!["pelvis".to_owned()];
        let mut ik = Ik::new(&robot, &frames, true, &[]).unwrap();
        let q0: Vec<f64> = robot.config.joints.iter().map(|j| j.default_position).collect();
        let root = ik.standing_root(&q0);
        // Hold the pelvis where it stands and ask for it 3 cm lower: the soles would go into
        // the floor with it.
        let mut goal_root = root;
        goal_root[2] -= 0.03;
        let goal = IkGoal {
            frame: Frame {
                pos: [goal_root[0], goal_root[1], goal_root[2]],
                rot: ik.frame(0).rot,
            },
            position_weight: 1.0,
            orientation_weight: 1.0,
        };
        ik.solve(&[goal], 60);
        let sunk = ik.lowest_point();
        assert!(sunk < -0.02, "without the floor the soles sink: {sunk}");
        ik.set_pose(root, &q0);
        ik.floor_weight = 10.0;
        ik.solve(&[goal], 60);
        let lowest = ik.lowest_point();
        assert!(lowest > -0.003, "with the floor the soles stay on it: {lowest}");
        // The pelvis went down anyway: the knees bent for it.
        assert!(
            (ik.frame(0).pos[2] - goal_root[2]).abs() < 0.01,
            "{:?}",
            ik.frame(0).pos
        );
    }
}
