//! The motion check on dynamic motions and real feet: the torques it estimates for a jump against
//! those a simulated rollout of the same jump applied, foot heights by the soles' real shapes, and
//! what it reports of a motion the feet cannot carry.

use std::path::{Path, PathBuf};

use analysis::motion_check::{self, MotionQuality};
use controller::clip::{Clip, Reference};
use mujoco_rs::prelude::MjData;
use mujoco_rs::wrappers::mj_model::traits::ModelType;
use robots::Robot;
use sim2real::model_index::ModelIndex;
use test_support::fixtures::workspace_root;

const RATE_HZ: f64 = 50.0;

/// A clip of `frames` (root pose and joints in robot order, one per tick at [`RATE_HZ`]), mapped
/// onto `robot` and checked.
fn check(robot: &Robot, frames: &[([f64; 7], Vec<f64>)]) -> MotionQuality {
    let clip = Clip {
        path: PathBuf::from("made-by-the-test.csv"),
        joints: robot.config.joints.iter().map(|j| j.name.clone()).collect(),
        times: (0..frames.len()).map(|k| k as f64 / RATE_HZ).collect(),
        root: frames.iter().map(|f| f.0).collect(),
        q: frames.iter().flat_map(|f| f.1.clone()).collect(),
        robot_order: false,
    };
    let reference = Reference::from_clip(&clip, robot, RATE_HZ).unwrap();
    motion_check::analyze(robot, &reference).unwrap()
}

/// Root pose and joints (robot order) of `data`.
fn frame<M: ModelType>(data: &MjData<M>, index: &ModelIndex) -> ([f64; 7], Vec<f64>) {
    let qpos = data.qpos();
    let mut root = [0.0; 7];
    root.copy_from_slice(&qpos[index.root.qpos..index.root.qpos + 7]);
    (root, index.joints.iter().map(|j| qpos[j.qpos]).collect())
}

/// `data` at the robot's default pose, its lowest point on the floor.
fn standing<M: ModelType>(robot: &Robot, data: &mut MjData<M>, index: &ModelIndex) {
    let r = index.root.qpos;
    data.qpos_mut()[r..r + 7].copy_from_slice(&[0.0, 0.0, 1.0, 1.0, 0.0, 0.0, 0.0]);
    for (j, ids) in robot.config.joints.iter().zip(&index.joints) {
        data.qpos_mut()[ids.qpos] = j.default_position;
    }
    data.forward();
    let low = sim2real::placement::lowest_point(data, index.root_body).unwrap();
    data.qpos_mut()[r + 2] -= low;
    data.forward();
}

/// Ease in and out from 0 to 1 over `x` in [0, 1].
fn smooth(x: f64) -> f64 {
    let x = x.clamp(0.0, 1.0);
    x * x * (3.0 - 2.0 * x)
}

/// The legs' crouch of a jump at time `t`: 0 standing, positive bent, negative stretched beyond
/// standing. Crouch 0.6 s, push off in 0.15 s, tuck in the air, land bent and stand up.
fn crouch(t: f64) -> f64 {
    let (deep, stretched, landing) = (0.7, -0.4, 0.3);
    match t {
        t if t < 0.4 => 0.0,
        t if t < 1.0 => deep * smooth((t - 0.4) / 0.6),
        t if t < 1.15 => deep + (stretched - deep) * smooth((t - 1.0) / 0.15),
        t if t < 1.4 => stretched + (landing - stretched) * smooth((t - 1.15) / 0.25),
        t => landing * (1.0 - smooth((t - 1.4) / 0.8)),
    }
}

#[test]
fn a_jump_s_torques_agree_with_a_simulated_rollout_of_it() {
    // The rollout: holosoma's G1 (MuJoCo at the scene's 2 ms step) jumps on stiff joint PD
    // (legs and waist 300 N·m/rad, 8 N·m·s/rad; the arms at the robot's gains), every torque clipped to the
    // joint's limit and applied as a generalised force. The clip is what the robot did, at 50 Hz.
    let robot = Robot::load(&workspace_root().join("robots/g1/robot.toml")).unwrap();
    let model = robot.model().unwrap();
    let index = ModelIndex::of_robot(&model, &robot).unwrap();
    let mut data = model.make_data();
    standing(&robot, &mut data, &index);
    let joints = &robot.config.joints;
    let stiff = |name: &str| ["hip", "knee", "ankle", "waist"].iter().any(|p| name.contains(p));
    let gains: Vec<(f64, f64)> = joints
        .iter()
        .map(|j| {
            if stiff(&j.name) {
                (300.0, 8.0)
            } else {
                (j.kp, j.kd)
            }
        })
        .collect();
    let target = |t: f64| -> Vec<f64> {
        let c = crouch(t);
        // Hips take 74 % of the knee's bend and ankles the rest: the trunk stays over the feet.
        joints
            .iter()
            .map(|j| match j.name.as_str() {
                n if n.ends_with("hip_pitch_joint") => j.default_position - 0.74 * c,
                n if n.ends_with("knee_joint") => j.default_position + c,
                n if n.ends_with("ankle_pitch_joint") => j.default_position - 0.26 * c,
                _ => j.default_position,
            })
            .collect()
    };
    let step = model.opt().timestep;
    let substeps = (1.0 / RATE_HZ / step).round() as usize;
    let mut frames = Vec::new();
    // Mean torque applied over each tick, robot order.
    let mut applied: Vec<Vec<f64>> = Vec::new();
    let mut highest = 0.0f64;
    let (mut airborne_ticks, mut landed_ticks) = (0, 0);
    // The clip ends 0.3 s after landing, or before anything but a foot touches the floor (the
    // check knows only feet; a fall after landing does not belong in it).
    let body = |g: i32| model.geom_bodyid()[g as usize] as usize;
    let foot_geom = |g: i32| index.feet.contains(&body(g));
    while landed_ticks < (0.3 * RATE_HZ) as usize {
        let floor: Vec<[i32; 2]> = data
            .contact()
            .iter()
            .map(|c| c.geom)
            .filter(|g| body(g[0]) == 0 || body(g[1]) == 0)
            .collect();
        let only_feet = floor.iter().all(|g| foot_geom(g[0]) || foot_geom(g[1]));
        assert!(
            only_feet,
            "the rollout fell before it landed (t = {:.2} s)",
            data.time()
        );
        frames.push(frame(&data, &index));
        highest = highest.max(data.qpos()[index.root.qpos + 2]);
        if floor.is_empty() {
            airborne_ticks += 1;
        } else if airborne_ticks > 0 {
            landed_ticks += 1;
        }
        let mut mean = vec![0.0; joints.len()];
        for _ in 0..substeps {
            let goal = target(data.time());
            for (i, (j, ids)) in joints.iter().zip(&index.joints).enumerate() {
                let (kp, kd) = gains[i];
                let tau = (kp * (goal[i] - data.qpos()[ids.qpos]) - kd * data.qvel()[ids.dof])
                    .clamp(-j.torque_limit, j.torque_limit);
                data.qfrc_applied_mut()[ids.dof] = tau;
                mean[i] += tau / substeps as f64;
            }
            data.step();
        }
        applied.push(mean);
    }
    let ticks = frames.len();
    let start_height = frames[0].0[2];
    assert!(
        highest - start_height > 0.05 && airborne_ticks >= 5,
        "the rollout is a jump: {:.3} m up, {airborne_ticks} ticks in the air",
        highest - start_height
    );
    let quality = check(&robot, &frames);
    // A real jump needs no help from anything but the floor under its feet (a lone frame at
    // take-off or touch-down may miss its contact by a tick).
    assert!(
        quality.problems().iter().all(|p| !p.contains("cannot carry")) && quality.unsupported_ticks <= 2,
        "{quality}"
    );
    // The check's estimate at tick k uses the motion's accelerations over the ticks either side;
    // the rollout's torque over the same 40 ms is the mean of the two ticks around it.
    let n = joints.len();
    let mut report = String::new();
    for (i, j) in joints.iter().enumerate() {
        let heavy = ["hip_pitch", "knee", "ankle_pitch"]
            .iter()
            .any(|p| j.name.contains(p));
        if !heavy {
            continue;
        }
        let measured: Vec<f64> = (1..ticks - 1)
            .map(|k| 0.5 * (applied[k - 1][i] + applied[k][i]))
            .collect();
        let estimated: Vec<f64> = (1..ticks - 1).map(|k| quality.torque[k * n + i]).collect();
        let peak = |v: &[f64]| v.iter().fold(0.0f64, |m, x| m.max(x.abs()));
        let rms = |v: &[f64]| (v.iter().map(|x| x * x).sum::<f64>() / v.len() as f64).sqrt();
        let (pm, pe, rm, re) = (peak(&measured), peak(&estimated), rms(&measured), rms(&estimated));
        report.push_str(&format!(
            "{}: peak {pe:.1} estimated, {pm:.1} applied; rms {re:.1} estimated, {rm:.1} applied\n",
            j.name
        ));
        assert!(
            pe <= 1.5 * pm && pm <= 1.5 * pe && re <= 1.5 * rm && rm <= 1.5 * re,
            "{}: the estimate is not within 1.5× of the rollout\n{report}",
            j.name
        );
    }
    eprintln!("{report}");
}

/// rd-biped's model with both soles replaced by `sole` (the geom's shape attributes) and `asset`
/// added, written beside a copy of its robot.toml.
fn biped_with_soles(dir: &Path, sole: &str, asset: &str) -> Robot {
    let source = workspace_root().join("robots/biped");
    std::fs::create_dir_all(dir).unwrap();
    let box_sole = r#"type="box" size="0.09 0.04 0.012" pos="0.02 0 -0.028""#;
    let xml = std::fs::read_to_string(source.join("biped.xml")).unwrap();
    assert_eq!(xml.matches(box_sole).count(), 2, "rd-biped's soles changed");
    let xml = xml.replace(box_sole, sole).replacen(
        "<worldbody>",
        &format!("<asset>{asset}</asset>\n  <worldbody>"),
        1,
    );
    std::fs::write(dir.join("biped.xml"), xml).unwrap();
    std::fs::copy(source.join("robot.toml"), dir.join("robot.toml")).unwrap();
    Robot::load(&dir.join("robot.toml")).unwrap()
}

#[test]
fn soles_on_the_floor_read_zero_for_box_capsule_sphere_and_mesh_feet() {
    let base = std::env::temp_dir().join(format!("motion-check-soles-{}", std::process::id()));
    // A mesh sole: a wedge, wider on top than at its flat bottom, 2.4 cm deep.
    let wedge = "<mesh name=\"wedge\" vertex=\"-0.07 -0.03 -0.04  0.11 -0.03 -0.04  0.11 0.03 -0.04  -0.07 0.03 -0.04  -0.07 -0.04 -0.016  0.11 -0.04 -0.016  0.11 0.04 -0.016  -0.07 0.04 -0.016\"/>";
    let shapes = [
        (
            "box",
            r#"type="box" size="0.09 0.04 0.012" pos="0.02 0 -0.028""#,
            "",
        ),
        (
            "capsule",
            r#"type="capsule" size="0.015" fromto="-0.06 0 -0.03 0.1 0 -0.03""#,
            "",
        ),
        ("sphere", r#"type="sphere" size="0.03" pos="0.02 0 -0.02""#, ""),
        ("mesh", r#"type="mesh" mesh="wedge""#, wedge),
    ];
    for (shape, sole, asset) in shapes {
        let robot = biped_with_soles(&base.join(shape), sole, asset);
        let model = robot.model().unwrap();
        let index = ModelIndex::of_robot(&model, &robot).unwrap();
        let mut data = model.make_data();
        standing(&robot, &mut data, &index);
        // MuJoCo's own collision distance is the truth: move the robot until the left sole
        // touches the floor (bisection on the root's height).
        let by_name = |name: &str| {
            model
                .name_to_id(mujoco_rs::wrappers::mj_model::MjtObjBase::mjOBJ_GEOM, name)
                .unwrap() as usize
        };
        let (sole_geom, floor) = (by_name("left_sole"), by_name("floor"));
        let z = index.root.qpos + 2;
        let (mut lo, mut hi) = (data.qpos()[z] - 0.05, data.qpos()[z] + 0.05);
        for _ in 0..60 {
            let mid = 0.5 * (lo + hi);
            data.qpos_mut()[z] = mid;
            data.forward();
            if data.geom_distance(sole_geom, floor, 0.2, None) > 0.0 {
                hi = mid;
            } else {
                lo = mid;
            }
        }
        data.qpos_mut()[z] = hi;
        data.forward();
        let standing_frame = frame(&data, &index);
        let quality = check(&robot, &vec![standing_frame.clone(); 25]);
        assert!(
            quality.foot_floating.abs() < 0.001,
            "{shape} soles on the floor read {:.2} cm\n{quality}",
            100.0 * quality.foot_floating
        );
        assert_eq!(quality.penetration_ticks, 0, "{shape}\n{quality}");
        assert_eq!(
            quality.support_ticks, 25,
            "{shape}: stands on its feet\n{quality}"
        );
        assert_eq!(quality.unsupported_ticks, 0, "{shape}\n{quality}");
        // Lifted 5 cm the same pose floats: nothing carries it, and the check says so.
        let mut floating = standing_frame;
        floating.0[2] += 0.05;
        let quality = check(&robot, &vec![floating; 25]);
        assert_eq!(quality.support_ticks, 0, "{shape}\n{quality}");
        let problems = quality.problems().join("\n");
        assert!(
            problems.contains("the feet cannot carry the motion in 25 of 25 ticks"),
            "{shape}: {problems}"
        );
    }
    let _ = std::fs::remove_dir_all(&base);
}
