//! Offline retargeting: a human BVH recording onto the robot, through the retargeting map of its
//! robot.toml (nominal calibration in a T-pose or the first frame) and inverse kinematics on its
//! MuJoCo model, with the joints inside their limits and the soles kept out of the floor. The
//! result is a clip in the controller's CSV format.

use std::fmt::Write as _;

use crate::body_map::{Frame, PairParams, RetargetMap};
use robots::spatial::{self, Mat3};
use robots::{HumanBody, Robot};

use super::ik::{Ik, IkGoal};
use crate::HumanError;
use motion::bvh::{Bvh, Dialect, Pose};

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
        (Dialect::Cmu, H::Chest) => "Spine1",
        (Dialect::Bandai, H::Chest) => "Chest",
        (Dialect::Cmu, H::LeftHip) => "LeftUpLeg",
        (Dialect::Cmu, H::RightHip) => "RightUpLeg",
        (Dialect::Bandai, H::LeftHip) => "UpperLeg_L",
        (Dialect::Bandai, H::RightHip) => "UpperLeg_R",
        (Dialect::Cmu, H::LeftShoulder) => "LeftArm",
        (Dialect::Cmu, H::RightShoulder) => "RightArm",
        (Dialect::Bandai, H::LeftShoulder) => "UpperArm_L",
        (Dialect::Bandai, H::RightShoulder) => "UpperArm_R",
    }
}

/// The BVH joint whose orientation a body takes, where it is not its own: a robot's rigid sole
/// lies like the human forefoot (the toes' segment), flat on the floor through toe-off while the
/// heel rises (GMR's feet follow the toes' orientation too).
fn orientation_joint(dialect: Dialect, body: HumanBody) -> Option<&'static str> {
    use HumanBody as H;
    match (dialect, body) {
        (Dialect::Cmu, H::LeftFoot) => Some("LeftToeBase"),
        (Dialect::Cmu, H::RightFoot) => Some("RightToeBase"),
        (Dialect::Bandai, H::LeftFoot) => Some("Toes_L"),
        (Dialect::Bandai, H::RightFoot) => Some("Toes_R"),
        _ => None,
    }
}

/// A recording turned to face +x (the rotation) and moved over the origin (where its root was,
/// after the turn).
type Alignment = (Mat3, [f64; 3]);

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

/// Retargets `bvh` onto `robot`, the map calibrated on the clip's own nominal frame.
pub fn retarget(robot: &Robot, bvh: &Bvh, options: &RetargetOptions) -> Result<Retargeted, HumanError> {
    retarget_calibrated(robot, bvh, bvh, options)
}

/// Retargets `bvh` onto `robot`, the map calibrated on the nominal frame of `calibration` (a
/// recording of the same skeleton: a T-pose or standing take of the same performer, for clips
/// that start moving — a walk that starts mid-stride has no frame that matches the robot's pose).
pub fn retarget_calibrated(
    robot: &Robot,
    bvh: &Bvh,
    calibration: &Bvh,
    options: &RetargetOptions,
) -> Result<Retargeted, HumanError> {
    let config = robot.config.retarget.as_ref().ok_or_else(|| {
        HumanError::map(format!(
            "{}: no [retarget] section: which robot body stands for which human one?",
            robot.path.display()
        ))
    })?;
    if options.nominal_frame >= calibration.frames() || options.start_frame + 1 >= bvh.frames() {
        return Err(HumanError::map(format!(
            "nominal frame {} (of {} frames) and start frame {} (of {} frames) are not frames of the recordings",
            options.nominal_frame,
            calibration.frames(),
            options.start_frame,
            bvh.frames()
        )));
    }
    if calibration.dialect != bvh.dialect || calibration.joints.len() != bvh.joints.len() {
        return Err(HumanError::map(format!(
            "the calibrating recording's skeleton ({:?}, {} joints) is not the clip's ({:?}, {} joints)",
            calibration.dialect,
            calibration.joints.len(),
            bvh.dialect,
            bvh.joints.len()
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

    // A recording turned to face +x and moved over the origin at one of its frames: the
    // nominal frame of the recording that calibrates the map, the clip's own for the clip.
    let aligned_at = |pose: &Pose| {
        let lateral = spatial::sub(pose.pos[lh], pose.pos[rh]);
        let rot = spatial::yaw(-(lateral[1].atan2(lateral[0]) - std::f64::consts::FRAC_PI_2));
        let origin = spatial::mat_apply(&rot, pose.pos[human[root_pair]]);
        (rot, origin)
    };
    let nominal = calibration.pose(options.nominal_frame);
    let calibrated = aligned_at(&nominal);
    let clip_alignment = if std::ptr::eq(calibration, bvh) {
        calibrated
    } else {
        aligned_at(&bvh.pose(options.start_frame))
    };
    let frame_of = |(align, origin): &Alignment, pose: &Pose, j: usize| {
        let mut pos = spatial::mat_apply(align, pose.pos[j]);
        pos[0] -= origin[0];
        pos[1] -= origin[1];
        Frame {
            pos,
            rot: spatial::mat_mul(align, &pose.rot[j]),
        }
    };

    // The robot in its nominal pose, soles on the floor.
    let frames: Vec<String> = config.pairs.iter().map(|p| p.frame.clone()).collect();
    let mut ik = Ik::new(robot, &frames, true, &[])?;
    // Soles stay out of the floor by moving the foot (its pitch, the leg), not by lifting the
    // whole robot off the other, planted foot: twice the heaviest pair's weight.
    ik.floor_weight = 2.0
        * config
            .pairs
            .iter()
            .map(|p| p.position_weight.max(p.orientation_weight))
            .fold(1.0, f64::max);
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
    // Each body's offset from the root scaled by its pair's factor (limbs of other proportions).
    let root_joint = human[root_pair];
    let turned_by: Vec<usize> = config
        .pairs
        .iter()
        .zip(&human)
        .map(|(p, &j)| {
            orientation_joint(bvh.dialect, p.human)
                .and_then(|n| bvh.joint(n))
                .unwrap_or(j)
        })
        .collect();
    let body_frame = |al: &Alignment, pose: &Pose, b: usize| {
        let mut f = frame_of(al, pose, human[b]);
        f.rot = frame_of(al, pose, turned_by[b]).rot;
        let root = frame_of(al, pose, root_joint);
        let factor = config.pairs[b].scale;
        f.pos = spatial::add(root.pos, spatial::scale(spatial::sub(f.pos, root.pos), factor));
        f
    };
    // The nominal position offsets stand for other body proportions (an ankle lower, hips
    // wider), which turn with the body's heading, not with the limb: a foot pitching about its
    // ankle leaves the ankle where it is. So positions map in the heading frame (the thighs'
    // line), orientations in each body's own frame.
    let heading_frame = |al: &Alignment, pose: &Pose, b: usize| {
        let lateral = spatial::sub(frame_of(al, pose, lh).pos, frame_of(al, pose, rh).pos);
        Frame {
            pos: body_frame(al, pose, b).pos,
            rot: spatial::yaw(lateral[1].atan2(lateral[0]) - std::f64::consts::FRAC_PI_2),
        }
    };
    let params: Vec<PairParams> = config
        .pairs
        .iter()
        .map(|p| PairParams {
            p_pos: p.p_pos,
            p_ori: p.p_ori,
        })
        .collect();
    let nominal_map = |frame: &dyn Fn(&Alignment, &Pose, usize) -> Frame| {
        let source: Vec<Frame> = (0..human.len())
            .map(|b| frame(&calibrated, &nominal, b))
            .collect();
        RetargetMap::nominal(
            source[root_pair].pos[2],
            target[root_pair].pos[2],
            &source,
            &target,
            &params,
            0.0,
        )
    };
    let (position_map, orientation_map) = (nominal_map(&heading_frame)?, nominal_map(&body_frame)?);
    // Feet: their height above the floor is the human's above theirs (the foot's lowest 5 % over
    // the clip), scaled — not the nominal frame's, which may be mid-stride.
    let duration = (bvh.frames() - 1 - options.start_frame) as f64 * bvh.frame_time;
    let ticks = (duration * options.rate_hz).floor() as usize + 1;
    let feet_floor: Vec<Option<f64>> = config
        .pairs
        .iter()
        .enumerate()
        .map(|(b, p)| {
            matches!(p.human, HumanBody::LeftFoot | HumanBody::RightFoot).then(|| {
                let mut z: Vec<f64> = (0..ticks)
                    .map(|k| {
                        let pose = bvh.pose_at(options.start_frame, k as f64 / options.rate_hz);
                        body_frame(&clip_alignment, &pose, b).pos[2]
                    })
                    .collect();
                z.sort_by(f64::total_cmp);
                z[z.len() / 20]
            })
        })
        .collect();
    let goal_frame = |pose: &Pose, b: usize| {
        let mut pos = position_map.map(b, &heading_frame(&clip_alignment, pose, b)).pos;
        if let Some(floor) = feet_floor[b] {
            let above = body_frame(&clip_alignment, pose, b).pos[2] - floor;
            pos[2] = target[b].pos[2] + position_map.scale * above;
        }
        Frame {
            pos,
            rot: orientation_map.map(b, &body_frame(&clip_alignment, pose, b)).rot,
        }
    };
    let map = &position_map;
    // GMR's two stages where the map names a posture stage: the posture first (orientations,
    // the feet), then every pair's own weights refine it.
    let two_stages = config.pairs.iter().any(|p| p.posture.is_some());

    let dt = 1.0 / options.rate_hz;
    let speed: Vec<f64> = robot
        .config
        .joints
        .iter()
        .map(|j| 0.9 * j.velocity_limit * dt)
        .collect();
    let mut previous: Option<Vec<f64>> = None;
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
        let pose = bvh.pose_at(options.start_frame, t);
        let goals: Vec<IkGoal> = config
            .pairs
            .iter()
            .enumerate()
            .map(|(b, p)| IkGoal {
                frame: goal_frame(&pose, b),
                position_weight: p.position_weight,
                orientation_weight: p.orientation_weight,
            })
            .collect();
        let iterations = if k == 0 {
            20 * options.iterations
        } else {
            options.iterations
        };
        if two_stages {
            let posture: Vec<IkGoal> = goals
                .iter()
                .zip(&config.pairs)
                .map(|(g, p)| {
                    let w = p.posture.unwrap_or(robots::StageWeights {
                        position_weight: 0.0,
                        orientation_weight: 0.0,
                    });
                    IkGoal {
                        position_weight: w.position_weight,
                        orientation_weight: w.orientation_weight,
                        ..*g
                    }
                })
                .collect();
            ik.solve(&posture, iterations);
        }
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
