//! Offline retargeting: a human BVH recording onto the robot, through the retargeting map of its
//! robot.toml (nominal calibration in a T-pose or the first frame) and inverse kinematics on its
//! MuJoCo model, with the joints inside their limits and the soles kept out of the floor. The
//! result is a clip in the controller's CSV format.

use std::fmt::Write as _;

use crate::body_map::{Frame, PairParams, RetargetMap};
use robots::spatial;
use robots::{HumanBody, Robot};

use super::bvh::{Bvh, Dialect, Pose};
use super::ik::{Ik, IkGoal};
use crate::HumanError;

/// The BVH joint standing for a human body, per dialect.
pub fn bvh_joint(dialect: Dialect, body: HumanBody) -> &'static str {
    use HumanBody as H;
    match (dialect, body) {
        (Dialect::Cmu, H::Root) | (Dialect::Bandai, H::Root) => "Hips",
        (Dialect::Cmu, H::Head) | (Dialect::Bandai, H::Head) => "Head",
        (Dialect::Cmu, H::LeftHand) => "LeftHand",
        (Dialect::Cmu, H::RightHand) => "RightHand",
        (Dialect::Cmu, H::LeftElbow) => "LeftForeArm",
        (Dialect::Cmu, H::RightElbow) => "RightForeArm",
        (Dialect::Cmu, H::LeftFoot) => "LeftFoot",
        (Dialect::Cmu, H::RightFoot) => "RightFoot",
        (Dialect::Cmu, H::LeftKnee) => "LeftLeg",
        (Dialect::Cmu, H::RightKnee) => "RightLeg",
        (Dialect::Bandai, H::LeftHand) => "Hand_L",
        (Dialect::Bandai, H::RightHand) => "Hand_R",
        (Dialect::Bandai, H::LeftElbow) => "LowerArm_L",
        (Dialect::Bandai, H::RightElbow) => "LowerArm_R",
        (Dialect::Bandai, H::LeftFoot) => "Foot_L",
        (Dialect::Bandai, H::RightFoot) => "Foot_R",
        (Dialect::Bandai, H::LeftKnee) => "LowerLeg_L",
        (Dialect::Bandai, H::RightKnee) => "LowerLeg_R",
    }
}

/// The thighs' roots, whose line gives a skeleton's heading.
fn hips(dialect: Dialect) -> [&'static str; 2] {
    match dialect {
        Dialect::Cmu => ["LeftUpLeg", "RightUpLeg"],
        Dialect::Bandai => ["UpperLeg_L", "UpperLeg_R"],
    }
}

/// The robot's pose matching the human's nominal frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Nominal {
    /// robot.toml's `[retarget] tpose` (the human's nominal frame is a T-pose).
    Tpose,
    /// The default standing pose (the human's nominal frame stands with the arms down).
    Default,
}

/// How to retarget.
#[derive(Debug, Clone, PartialEq)]
pub struct RetargetOptions {
    /// Output rate, Hz.
    pub rate_hz: f64,
    /// The BVH frame whose pose matches the robot's nominal pose.
    pub nominal_frame: usize,
    /// The first BVH frame of the clip (CMU trials hold their T-pose for one frame only).
    pub start_frame: usize,
    /// Which robot pose that is.
    pub nominal: Nominal,
    /// IK iterations per output frame (the first frame gets twenty times as many).
    pub iterations: usize,
    /// Gaussian smoothing of the result, σ in seconds (0: none).
    pub smoothing_s: f64,
}

impl Default for RetargetOptions {
    fn default() -> Self {
        Self {
            rate_hz: 50.0,
            nominal_frame: 0,
            start_frame: 0,
            nominal: Nominal::Tpose,
            iterations: 12,
            smoothing_s: 0.08,
        }
    }
}

/// A retargeted motion.
#[derive(Debug, Clone, PartialEq)]
pub struct Retargeted {
    /// Frame times, s.
    pub times: Vec<f64>,
    /// Root poses `[x, y, z, w, qx, qy, qz]`.
    pub root: Vec<[f64; 7]>,
    /// Joints (policy order), per frame.
    pub q: Vec<Vec<f64>>,
    /// The global scale of the map.
    pub scale: f64,
    /// Largest distance between a paired robot frame and its target, m (position pairs).
    pub worst_position_error: f64,
    /// Mean of it.
    pub mean_position_error: f64,
    /// Per position pair: robot frame name, mean and worst distance from its target, m.
    pub pair_errors: Vec<(String, f64, f64)>,
}

/// Retargets `bvh` onto `robot`.
pub fn retarget(robot: &Robot, bvh: &Bvh, options: &RetargetOptions) -> Result<Retargeted, HumanError> {
    let config = robot.config.retarget.as_ref().ok_or_else(|| {
        HumanError::map(format!(
            "{}: no [retarget] section: which robot body stands for which human one?",
            robot.path.display()
        ))
    })?;
    if options.nominal_frame >= bvh.frames() || options.start_frame + 1 >= bvh.frames() {
        return Err(HumanError::map(format!(
            "nominal frame {} and start frame {}, but the recording has {} frames",
            options.nominal_frame,
            options.start_frame,
            bvh.frames()
        )));
    }
    if !(options.rate_hz.is_finite() && options.rate_hz > 0.0) {
        return Err(HumanError::map(format!(
            "rate {} Hz is not a rate",
            options.rate_hz
        )));
    }
    let human: Vec<usize> = config
        .pairs
        .iter()
        .map(|p| {
            let name = bvh_joint(bvh.dialect, p.human);
            bvh.joint(name).ok_or_else(|| {
                HumanError::map(format!("the recording has no {name} joint for {:?}", p.human))
            })
        })
        .collect::<Result<_, _>>()?;
    let [lh, rh] = hips(bvh.dialect).map(|n| bvh.joint(n));
    let (Some(lh), Some(rh)) = (lh, rh) else {
        return Err(HumanError::map(
            "the recording has no thigh joints to tell its heading",
        ));
    };
    let root_pair = config
        .pairs
        .iter()
        .position(|p| p.human == HumanBody::Root)
        .ok_or_else(|| HumanError::map("[retarget] pairs no robot frame with the root"))?;

    // The human, turned to face +x and moved over the origin at the nominal frame.
    let nominal = bvh.pose(options.nominal_frame);
    let lateral = spatial::sub(nominal.pos[lh], nominal.pos[rh]);
    let align = spatial::yaw(-(lateral[1].atan2(lateral[0]) - std::f64::consts::FRAC_PI_2));
    let origin = spatial::mat_apply(&align, nominal.pos[human[root_pair]]);
    let frame_of = |pose: &Pose, j: usize| {
        let mut pos = spatial::mat_apply(&align, pose.pos[j]);
        pos[0] -= origin[0];
        pos[1] -= origin[1];
        Frame {
            pos,
            rot: spatial::mat_mul(&align, &pose.rot[j]),
        }
    };

    // The robot in its nominal pose, soles on the floor.
    let frames: Vec<String> = config.pairs.iter().map(|p| p.frame.clone()).collect();
    let mut ik = Ik::new(robot, &frames, true, &[])?;
    for (k, p) in config.pairs.iter().enumerate() {
        ik.set_compare(k, p.orientation_compare, p.twist_axis);
    }
    let mut q: Vec<f64> = robot
        .config
        .joints
        .iter()
        .map(|j| match options.nominal {
            Nominal::Tpose => config.tpose.get(&j.name).copied().unwrap_or(0.0),
            Nominal::Default => j.default_position,
        })
        .collect();
    ik.set_pose([0.0, 0.0, 1.0, 1.0, 0.0, 0.0, 0.0], &q);
    let drop = ik.lowest_point();
    ik.lift(-drop);
    let target: Vec<Frame> = (0..frames.len()).map(|k| ik.frame(k)).collect();
    // Position-only pairs (hands) carry their nominal offset in the pelvis' frame: the offset
    // stands for different body proportions, which turn with the body, not with the wrist.
    let root_joint = human[root_pair];
    let position_only: Vec<bool> = config.pairs.iter().map(|p| p.orientation_weight == 0.0).collect();
    let source_frame = |pose: &Pose, b: usize| {
        let mut f = frame_of(pose, human[b]);
        if position_only[b] {
            f.rot = frame_of(pose, root_joint).rot;
        }
        f
    };
    let source: Vec<Frame> = (0..human.len()).map(|b| source_frame(&nominal, b)).collect();
    let params: Vec<PairParams> = config
        .pairs
        .iter()
        .map(|p| PairParams {
            p_pos: p.p_pos,
            p_ori: p.p_ori,
        })
        .collect();
    let map = RetargetMap::nominal(
        source[root_pair].pos[2],
        target[root_pair].pos[2],
        &source,
        &target,
        &params,
        0.0,
    )?;

    let duration = (bvh.frames() - 1 - options.start_frame) as f64 * bvh.frame_time;
    let dt = 1.0 / options.rate_hz;
    let speed: Vec<f64> = robot
        .config
        .joints
        .iter()
        .map(|j| 0.9 * j.velocity_limit * dt)
        .collect();
    let mut previous: Option<Vec<f64>> = None;
    let ticks = (duration * options.rate_hz).floor() as usize + 1;
    let mut out = Retargeted {
        times: Vec::with_capacity(ticks),
        root: Vec::with_capacity(ticks),
        q: Vec::with_capacity(ticks),
        scale: map.scale,
        worst_position_error: 0.0,
        mean_position_error: 0.0,
        pair_errors: config
            .pairs
            .iter()
            .filter(|p| p.position_weight > 0.0)
            .map(|p| (p.frame.clone(), 0.0, 0.0))
            .collect(),
    };
    let mut error_sum = 0.0;
    let mut error_count = 0usize;
    for k in 0..ticks {
        let t = k as f64 / options.rate_hz;
        let frame = (options.start_frame + (t / bvh.frame_time).round() as usize).min(bvh.frames() - 1);
        let pose = bvh.pose(frame);
        let goals: Vec<IkGoal> = config
            .pairs
            .iter()
            .enumerate()
            .map(|(b, p)| IkGoal {
                frame: map.map(b, &source_frame(&pose, b)),
                position_weight: p.position_weight,
                orientation_weight: p.orientation_weight,
            })
            .collect();
        let iterations = if k == 0 {
            20 * options.iterations
        } else {
            options.iterations
        };
        ik.solve(&goals, iterations);
        // Within the motors' speed: no joint moves further per frame than 90 % of its limit.
        ik.joints(&mut q);
        if let Some(prev) = &previous {
            for ((v, p), s) in q.iter_mut().zip(prev).zip(&speed) {
                *v = v.clamp(p - s, p + s);
            }
            let root = ik.root();
            ik.set_pose(root, &q);
        }
        // Feet out of the floor: lift the whole robot by what its lowest sole sinks in.
        let sink = ik.lowest_point();
        if sink < 0.0 {
            ik.lift(-sink);
        }
        let mut slot = 0;
        for (b, g) in goals.iter().enumerate() {
            if g.position_weight > 0.0 {
                let e = spatial::norm(spatial::sub(ik.frame(b).pos, g.frame.pos));
                out.worst_position_error = out.worst_position_error.max(e);
                let pair = &mut out.pair_errors[slot];
                pair.1 += e / ticks as f64;
                pair.2 = pair.2.max(e);
                slot += 1;
                error_sum += e;
                error_count += 1;
            }
        }
        ik.joints(&mut q);
        previous = Some(q.clone());
        out.times.push(t);
        out.root.push(ik.root());
        out.q.push(q.clone());
    }
    out.mean_position_error = error_sum / error_count.max(1) as f64;
    smooth(&mut out, options.smoothing_s * options.rate_hz);
    // Smoothing may lower a sole a little: lift those frames back out of the floor.
    for (root, q) in out.root.iter_mut().zip(&out.q) {
        ik.set_pose(*root, q);
        let sink = ik.lowest_point();
        if sink < 0.0 {
            root[2] -= sink;
        }
    }
    Ok(out)
}

/// Gaussian smoothing (σ in frames) of joints and root position, zero phase; root orientations are
/// averaged as quaternions and renormalised. Averages of in-limit angles stay in their limits and
/// no speed grows, so the limits the solver kept still hold.
fn smooth(m: &mut Retargeted, sigma: f64) {
    if sigma <= 0.0 || m.q.len() < 3 {
        return;
    }
    let half = (3.0 * sigma).ceil() as isize;
    let weights: Vec<f64> = (-half..=half)
        .map(|k| (-0.5 * (k as f64 / sigma).powi(2)).exp())
        .collect();
    let n = m.q.len() as isize;
    let at = |k: isize| k.clamp(0, n - 1) as usize;
    let (q, root) = (m.q.clone(), m.root.clone());
    for i in 0..n {
        let mut total = 0.0;
        let mut acc_q = vec![0.0; q[0].len()];
        let mut acc_r = [0.0; 7];
        let reference = root[i as usize];
        for (w, k) in weights.iter().zip(-half..=half) {
            let j = at(i + k);
            total += w;
            for (a, v) in acc_q.iter_mut().zip(&q[j]) {
                *a += w * v;
            }
            // Quaternions on the same hemisphere as this frame's before averaging.
            let r = root[j];
            let sign = if (3..7).map(|c| r[c] * reference[c]).sum::<f64>() < 0.0 {
                -1.0
            } else {
                1.0
            };
            for c in 0..7 {
                acc_r[c] += w * if c >= 3 { sign * r[c] } else { r[c] };
            }
        }
        let norm = (3..7).map(|c| acc_r[c] * acc_r[c]).sum::<f64>().sqrt();
        for (c, v) in acc_r.iter_mut().enumerate() {
            *v /= if c >= 3 { norm } else { total };
        }
        m.q[i as usize] = acc_q.iter().map(|a| a / total).collect();
        m.root[i as usize] = acc_r;
    }
}

impl Retargeted {
    /// The clip as CSV (the controller's clip format), with `header` lines as comments.
    pub fn to_csv(&self, robot: &Robot, header: &[String]) -> String {
        let mut s = String::new();
        for h in header {
            let _ = writeln!(s, "# {h}");
        }
        s.push_str("time,root_x,root_y,root_z,root_qw,root_qx,root_qy,root_qz");
        for j in &robot.config.joints {
            let _ = write!(s, ",{}", j.name);
        }
        s.push('\n');
        for ((t, r), q) in self.times.iter().zip(&self.root).zip(&self.q) {
            let _ = write!(s, "{t:.4}");
            for v in r {
                let _ = write!(s, ",{v:.6}");
            }
            for v in q {
                let _ = write!(s, ",{v:.6}");
            }
            s.push('\n');
        }
        s
    }
}
