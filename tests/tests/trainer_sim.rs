//! The trainer's simulation in the mirror: joint dynamics (armature, friction loss, damping) per
//! joint or group and physics settings from robot.toml, applied to the compiled model — never to
//! the user's files — used by the mirror and the motion check, shown by `check`, bad values named.

use std::path::{Path, PathBuf};
use std::time::Duration;

use robots::Robot;
use sim2real::config::MirrorConfig;
use sim2real::host::MirrorHost;
use sim2real::model_index::ModelIndex;
use test_support::bin::run_within;
use test_support::fixtures::workspace_root;

mod robstride_biped;

/// rd-biped's robot.toml with `extra` appended, written as `dir/name` (its MJCF where it is).
fn biped_with(dir: &Path, name: &str, extra: &str) -> PathBuf {
    let original = workspace_root().join("robots/biped");
    let text = test_support::fixtures::policy_from(
        &std::fs::read_to_string(original.join("robot.toml")).unwrap(),
        &original,
    )
    .replace(
        "mjcf = \"biped.xml\"",
        &format!("mjcf = {:?}", original.join("biped.xml")),
    );
    std::fs::create_dir_all(dir).unwrap();
    let path = dir.join(name);
    std::fs::write(&path, format!("{text}\n{extra}")).unwrap();
    path
}

const DYNAMICS: &str = r#"
[[joint_dynamics]]
joints = ["*hip*", "*knee*"]
armature = 0.02
frictionloss = 0.3

[[joint_dynamics]]
joints = ["*knee"]
armature = 0.05
damping = 0.7

[sim]
timestep = 0.0005
integrator = "implicitfast"
iterations = 20
solver = "cg"
cone = "elliptic"
impratio = 10.0
"#;

#[test]
fn joint_dynamics_and_physics_from_robot_toml_reach_the_mirror_and_check() {
    let dir = std::env::temp_dir().join(format!("robodeploy-trainer-sim-{}", std::process::id()));
    let path = biped_with(&dir, "robot.toml", DYNAMICS);
    let mjcf_before = std::fs::read(workspace_root().join("robots/biped/biped.xml")).unwrap();
    let robot = Robot::load(&path).unwrap();
    let model = robot.model().unwrap();
    let index = ModelIndex::of_robot(&model, &robot).unwrap();
    let dof = |name: &str| {
        let i = robot.config.joints.iter().position(|j| j.name == name).unwrap();
        index.joints[i].dof
    };
    // A later entry wins field by field; joints no entry names keep the model's values.
    let plain = Robot::load(&workspace_root().join("robots/biped/robot.toml"))
        .unwrap()
        .model()
        .unwrap();
    let (hip, knee, ankle) = (dof("left_hip_pitch"), dof("left_knee"), dof("left_ankle_pitch"));
    assert_eq!(model.dof_armature()[hip], 0.02);
    assert_eq!(model.dof_frictionloss()[hip], 0.3);
    assert_eq!(model.dof_damping()[hip], plain.dof_damping()[hip]);
    assert_eq!(model.dof_armature()[knee], 0.05);
    assert_eq!(model.dof_frictionloss()[knee], 0.3);
    assert_eq!(model.dof_damping()[knee], 0.7);
    assert_eq!(model.dof_armature()[ankle], plain.dof_armature()[ankle]);
    assert_eq!(model.opt().timestep, 0.0005);
    assert_eq!(model.opt().iterations, 20);
    assert_eq!(model.opt().impratio, 10.0);
    assert_eq!(robots::mjcf::solver_name(model.opt().solver), "cg");
    assert_eq!(robots::mjcf::cone_name(model.opt().cone), "elliptic");
    assert_eq!(
        robots::Integrator::of_mujoco(model.opt().integrator),
        Some(robots::Integrator::Implicitfast)
    );
    // The mirror steps the physics at robot.toml's step: 40 steps per 20 ms tick.
    let mut host = MirrorHost::start(robot.clone(), MirrorConfig::default()).unwrap();
    let start = host.now();
    let before = host.world.lock().unwrap().stats().physics_steps;
    let q: Vec<f64> = robot.config.joints.iter().map(|j| j.default_position).collect();
    for k in 1..=10u32 {
        host.command_positions(&robot, &q).unwrap();
        host.wait_until(start + Duration::from_millis(20) * k);
    }
    let steps = host.world.lock().unwrap().stats().physics_steps - before;
    assert!((399..=401).contains(&steps), "{steps} physics steps in 10 ticks");
    // `check` shows them, marked as robot.toml's.
    let (code, out, err) = run_within(
        &["check", "--robot", path.to_str().unwrap()],
        Duration::from_secs(120),
    );
    assert_eq!(code, Some(0), "{out}{err}");
    assert!(
        out.contains("physics: 0.5 ms step, implicitfast, 20 solver iterations (robot.toml [sim] over the model's); 40 steps per policy tick"),
        "{out}"
    );
    assert!(
        out.contains("contacts: cg solver, elliptic friction cones, impratio 10"),
        "{out}"
    );
    // And what holds each joint's torque limit.
    assert!(
        out.contains("motor torque limit: AK10-9 40 N·m of the motor's 65 N·m: every command bounded over its bus cycle"),
        "{out}"
    );
    let knees = out
        .lines()
        .find(|l| l.contains("joint dynamics") && l.ends_with("left_knee, right_knee"))
        .unwrap_or("");
    assert!(
        knees.contains("(robot.toml): armature 0.05 kg·m², frictionloss 0.3 N·m, damping 0.7 N·m·s/rad"),
        "{out}"
    );
    // The user's files are untouched.
    assert_eq!(
        std::fs::read(workspace_root().join("robots/biped/biped.xml")).unwrap(),
        mjcf_before
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn bad_joint_dynamics_and_physics_are_refused_by_field_and_nothing_moves() {
    let dir = std::env::temp_dir().join(format!("robodeploy-trainer-sim-bad-{}", std::process::id()));
    let cases = [
        (
            "[[joint_dynamics]]\njoints = [\"*knee*\"]\narmature = -0.01\n",
            "joint_dynamics[0].armature: -0.01 kg·m² is outside [0, 10]",
        ),
        (
            "[[joint_dynamics]]\njoints = [\"*knee*\"]\ndamping = nan\n",
            "joint_dynamics[0].damping: NaN N·m·s/rad is outside [0, 1000]",
        ),
        (
            "[[joint_dynamics]]\njoints = [\"*elbow*\", \"*flipper*\"]\narmature = 0.01\n",
            "joint_dynamics[0].joints: \"*flipper*\" matches no joint of the robot",
        ),
        (
            "[[joint_dynamics]]\njoints = [\"*knee*\"]\n",
            "joint_dynamics[0].joints: sets nothing",
        ),
        (
            "[sim]\ntimestep = 0.0\n",
            "sim.timestep: 0 s is outside [0.0001, 0.02]",
        ),
        (
            "[sim]\ntimestep = 0.05\n",
            "sim.timestep: 0.05 s is outside [0.0001, 0.02]",
        ),
        (
            "[sim]\ntimestep = 0.003\n",
            "sim.timestep: 0.003 s does not divide the policy period 0.02 s",
        ),
        ("[sim]\nintegrator = \"verlet\"\n", "unknown variant `verlet`"),
        ("[sim]\nimpratio = 0.5\n", "sim.impratio: 0.5 is outside [1, 100]"),
        (
            "[[actuators]]\njoints = [\"*\"]\nmodel = \"explicit_pd\"\n",
            "actuators[0].model: explicit_pd: joint left_shoulder_pitch sits on a Dynamixel bus, which cannot provide it",
        ),
        (
            "[[actuators]]\njoints = [\"*knee\"]\nmodel = \"dc_motor\"\nsaturation_effort = 60.0\n",
            "actuators[0].model: dc_motor for joint left_knee needs saturation_effort and velocity_limit",
        ),
        (
            "[[actuators]]\njoints = [\"*knee\"]\nmodel = \"servo_magic\"\n",
            "unknown variant `servo_magic`",
        ),
        (
            "[[actuators]]\njoints = [\"*knee\"]\ndelay_steps = [2, 2]\n",
            "actuators[0].delay_steps: joint left_knee: a delay needs a law the mirror computes",
        ),
        (
            "[[actuators]]\njoints = [\"*knee\"]\nmodel = \"explicit_pd\"\ndelay_steps = [3, 1]\n",
            "actuators[0].delay_steps: [3, 1] is not a range within [0, 100] steps",
        ),
        (
            "[[actuators]]\njoints = [\"*knee\"]\nmodel = \"explicit_pd\"\ndelay_steps = [1, 2, 3]\n",
            "delay_steps: expected [min, max], got 3 value(s): [1, 2, 3]",
        ),
        (
            "[[actuators]]\njoints = [\"*knee\"]\nmodel = \"explicit_pd\"\nsaturation_effort = 20.0\n",
            "actuators[0].saturation_effort: joint left_knee: only dc_motor has a torque–speed line, and its law is explicit_pd",
        ),
        (
            "[[actuators]]\njoints = [\"*knee\"]\nmodel = \"dc_motor\"\nsaturation_effort = 60.0\nvelocity_limit = 20.0\n\n\
             [[actuators]]\njoints = [\"left_knee\"]\nmodel = \"implicit_pd\"\n",
            "actuators[0].saturation_effort: joint left_knee: only dc_motor has a torque–speed line, and its law is implicit_pd",
        ),
        (
            "[[actuators]]\njoints = [\"*knee\"]\nmodel = \"explicit_pd\"\neffort_limit = -1.0\n",
            "actuators[0].effort_limit: -1 N·m is outside [0, 10000]",
        ),
        (
            "[[actuators]]\njoints = [\"*tail*\"]\nmodel = \"explicit_pd\"\n",
            "actuators[0].joints: \"*tail*\" matches no joint of the robot",
        ),
        // The estimator's settings (issue 33), by field.
        (
            "[estimator]\nfloor_noise = -0.01\n",
            "estimator.floor_noise: -0.01 m is outside [0, 1]",
        ),
        (
            "[estimator]\ncontact_on_m = 0.05\n",
            "estimator.contact_off_m: 0.02 m is below contact_on_m = 0.05 m",
        ),
        ("[estimator]\nfloor = 0.0\n", "unknown field `floor`"),
    ];
    for (i, (extra, want)) in cases.iter().enumerate() {
        let path = biped_with(&dir, &format!("bad{i}.toml"), extra);
        let (code, out, err) = run_within(
            &[
                "play",
                "--robot",
                path.to_str().unwrap(),
                "--no-record",
                "--max-seconds",
                "1",
            ],
            Duration::from_secs(120),
        );
        assert_eq!(code, Some(2), "{want}: {out}{err}");
        assert!(err.contains(want), "wanted {want:?} in: {err}");
        assert!(!out.contains("Running"), "{want}: something moved: {out}");
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

/// holosoma's G1 robot.toml with `extra` appended, written as `dir/name`.
fn g1_with(dir: &Path, name: &str, extra: &str) -> PathBuf {
    let root = workspace_root();
    let text = std::fs::read_to_string(root.join("robots/g1/robot.toml"))
        .unwrap()
        .replace("mjcf = \"../../", &format!("mjcf = \"{}/", root.display()));
    std::fs::create_dir_all(dir).unwrap();
    let path = dir.join(name);
    std::fs::write(&path, format!("{text}\n{extra}")).unwrap();
    path
}

#[test]
fn the_g1_holds_still_on_the_gantry_with_its_armature_and_check_names_the_instability_without() {
    use sim2real::stability::{Hold, settle};
    // As shipped (the model's armature, its 2 ms step): still on the gantry and in the harness;
    // with its armature even at holosoma's 5 ms.
    let dir = std::env::temp_dir().join(format!("robodeploy-trainer-sim-g1-{}", std::process::id()));
    let shipped = Robot::load(&workspace_root().join("robots/g1/robot.toml")).unwrap();
    let at_5ms = Robot::load(&g1_with(&dir, "g1-5ms.toml", "[sim]\ntimestep = 0.005\n")).unwrap();
    for robot in [&shipped, &at_5ms] {
        for hold in [Hold::Gantry, Hold::Start] {
            let s = settle(robot, hold).unwrap();
            assert!(s.stable(), "{s}");
        }
    }
    // Without armature at 5 ms the joints diverge at once: `check` refuses the robot, naming
    // the joint MuJoCo found and what to change.
    let bare = g1_with(
        &dir,
        "g1-bare.toml",
        "[[joint_dynamics]]\njoints = [\"*\"]\narmature = 0.0\n\n[sim]\ntimestep = 0.005\n",
    );
    let policy = workspace_root().join("robots/g1/policies/holosoma_loco_ppo.toml");
    let on_bare = [
        "--robot",
        bare.to_str().unwrap(),
        "--policy",
        policy.to_str().unwrap(),
    ];
    let (code, out, err) = run_within(&[&["check"][..], &on_bare].concat(), Duration::from_secs(120));
    assert_eq!(code, Some(2), "bad input: {out}{err}");
    let line = out
        .lines()
        .find(|l| l.contains("stability on the gantry"))
        .unwrap_or("");
    assert!(
        line.contains("unstable at the 5 ms step")
            && (line.contains("at joint ") || line.contains("times its velocity limit"))
            && line.contains("armature"),
        "{out}"
    );
    assert!(
        err.contains("the robot's model is not stable at its physics step"),
        "{err}"
    );
    // Played anyway, the run says the mirror blew up, not only what its IMU read then.
    let (code, out, err) = run_within(
        &[&["play"][..], &on_bare, &["--max-seconds", "2", "--no-record"]].concat(),
        Duration::from_secs(120),
    );
    assert_eq!(code, Some(3), "{out}{err}");
    assert!(
        out.contains("mirror: the simulation diverged at tick") && out.contains("`robodeploy check`"),
        "{out}"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_floor_inside_a_static_body_is_the_floor() {
    // rd-biped's scene with its floor plane moved into a static body named `floor`.
    let dir = std::env::temp_dir().join(format!("robodeploy-trainer-sim-floor-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let source = workspace_root().join("robots/biped");
    let xml = std::fs::read_to_string(source.join("biped.xml")).unwrap();
    let plane = xml
        .lines()
        .find(|l| l.contains("name=\"floor\""))
        .unwrap()
        .trim()
        .to_owned();
    let moved = xml.replace(
        &plane,
        &format!(
            "<body name=\"floor\" pos=\"0 0 0\">{}</body>",
            plane.replace("name=\"floor\"", "name=\"ground\"")
        ),
    );
    std::fs::write(dir.join("biped.xml"), moved).unwrap();
    std::fs::copy(source.join("robot.toml"), dir.join("robot.toml")).unwrap();
    let robot = Robot::load(&dir.join("robot.toml")).unwrap();
    assert_eq!(robot.mjcf.floor, vec!["ground".to_owned()]);
    // The mirror stands the robot on it.
    let s = sim2real::stability::settle(&robot, sim2real::stability::Hold::Start).unwrap();
    assert!(s.stable(), "{s}");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn compare_judges_imu_terms_by_each_robots_own_imu() {
    // rd-biped's WIT AHRS and rd-mini's BNO08x in RVC mode: the gyro term (scale 0.25 on rd-mini)
    // is judged by what each part can tell apart — and a BNO055 by its own steps.
    let wit = Robot::load(&workspace_root().join("robots/biped/robot.toml")).unwrap();
    let biped_layout = policy::PolicyLayout::load(
        &workspace_root().join("robots/biped/policies/reference_follower.toml"),
        &wit,
    )
    .unwrap();
    let q = analysis::compare::quanta(&biped_layout, &wit);
    let gyro = biped_layout
        .slots
        .iter()
        .find(|s| s.term.name() == "gyro")
        .unwrap();
    assert_eq!(
        q[gyro.range.start],
        Some(firmware_bridge::imu::wit::GYRO_RESOLUTION * 0.25)
    );

    let mini = Robot::load(&workspace_root().join("robots/mini/robot.toml")).unwrap();
    let layout = policy::PolicyLayout::load(
        &workspace_root().join("robots/mini/policies/stand_walk.toml"),
        &mini,
    )
    .unwrap();
    let slot = layout
        .slots
        .iter()
        .find(|s| s.term.name() == "base_ang_vel")
        .unwrap();
    let rvc = firmware_bridge::imu::ImuProtocol::Bno08xRvc.resolution();
    assert_eq!(
        analysis::compare::quanta(&layout, &mini)[slot.range.start],
        Some(rvc.gyro * 0.25)
    );
    // The same robot with a BNO055 on its line.
    let dir = std::env::temp_dir().join(format!("robodeploy-trainer-sim-imu-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let text = std::fs::read_to_string(workspace_root().join("robots/mini/robot.toml"))
        .unwrap()
        .replace("protocol = \"bno08x_rvc\"", "protocol = \"bno055\"");
    for entry in std::fs::read_dir(workspace_root().join("robots/mini")).unwrap() {
        let p = entry.unwrap().path();
        if p.is_file() && p.file_name().is_some_and(|n| n != "robot.toml") {
            std::fs::copy(&p, dir.join(p.file_name().unwrap())).unwrap();
        }
    }
    std::fs::create_dir_all(dir.join("meshes")).unwrap();
    for entry in std::fs::read_dir(workspace_root().join("robots/mini/meshes")).unwrap() {
        let p = entry.unwrap().path();
        std::fs::copy(&p, dir.join("meshes").join(p.file_name().unwrap())).unwrap();
    }
    std::fs::write(dir.join("robot.toml"), text).unwrap();
    let bno055 = Robot::load(&dir.join("robot.toml")).unwrap();
    let q = analysis::compare::quanta(&layout, &bno055);
    assert_eq!(
        q[slot.range.start],
        Some(firmware_bridge::imu::bno055::GYRO_LSB * 0.25)
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

/// `robot`'s mirror in lockstep with the robot held on the gantry, feet off the floor.
fn on_gantry(robot: &Robot) -> MirrorHost {
    MirrorHost::start(
        robot.clone(),
        MirrorConfig {
            gantry: true,
            ..MirrorConfig::default()
        },
    )
    .unwrap()
}

/// `joint` of `robot` on the gantry, told to swing `swing` rad at the robot's stiffness and
/// stopped dead mid-swing by an obstacle (the jig) after three ticks: its speed then, and the
/// largest torque it got at any physics step after (the motors' inner rate), N·m.
fn swing_into_an_obstacle(robot: &Robot, joint: &str, swing: f64) -> (f64, f64) {
    let i = robot.config.joints.iter().position(|j| j.name == joint).unwrap();
    let mut host = on_gantry(robot);
    let mut q: Vec<f64> = robot.config.joints.iter().map(|j| j.default_position).collect();
    q[i] += swing;
    let start = host.now();
    let period = Duration::from_millis(20);
    let mut speed = 0.0;
    for k in 1..=25u32 {
        host.command_positions(robot, &q).unwrap();
        if k == 3 {
            let mut w = host.world.lock().unwrap();
            speed = w.data().qvel()[ModelIndex::of_robot(w.data().model(), robot).unwrap().joints[i].dof];
            let here: Vec<f64> = w.joint_positions().collect();
            w.set_jig(Some(here));
            w.reset_peak_joint_torques();
        }
        host.wait_until(start + period * k);
    }
    let peak = host.world.lock().unwrap().peak_joint_torques()[i];
    (speed, peak)
}

#[test]
fn joints_stopped_mid_swing_by_an_obstacle_stay_within_their_torque_limits() {
    // Each bus family: the bus bounds each command at its cycle (MIT), the motor its own
    // limit_torque (Robstride), or the servo's own
    // current or torque limit holds (Dynamixel, Feetech); either way the torque the joint gets
    // between bus cycles stays within its limit (2 % for the devices' steps). rd-biped's knee
    // (AK10-9, 40 N·m, below the motor's own) peaked at 65 N·m before the bound looked across
    // the whole cycle.
    let biped = Robot::load(&workspace_root().join("robots/biped/robot.toml")).unwrap();
    let mini_dir = workspace_root().join("robots/mini");
    let feetech_text =
        test_support::zoo::on_feetech(&std::fs::read_to_string(mini_dir.join("robot.toml")).unwrap());
    let on_feetech = Robot::from_str(&mini_dir.join("robot.toml"), &feetech_text).unwrap();
    let biped_path = workspace_root().join("robots/biped/robot.toml");
    let on_robstride = Robot::from_str(
        &biped_path,
        &robstride_biped::left_leg_on_robstride(&std::fs::read_to_string(&biped_path).unwrap()),
    )
    .unwrap();
    for (robot, joint, swing) in [
        (&biped, "left_knee", 1.2),
        // An RS03 (60 N·m) holding the knee's 40 N·m in its own limit_torque.
        (&on_robstride, "left_knee", 1.2),
        (&biped, "left_elbow", -1.0),
        (&on_feetech, "l_knee", 1.0),
    ] {
        let limit = robot
            .config
            .joints
            .iter()
            .find(|j| j.name == joint)
            .unwrap()
            .torque_limit;
        let (speed, peak) = swing_into_an_obstacle(robot, joint, swing);
        eprintln!(
            "{} {joint}: swinging at {speed:.1} rad/s, peak {peak:.2} N·m against {limit}",
            robot.config.name
        );
        assert!(speed.abs() > 1.0, "{joint} was swinging: {speed} rad/s");
        assert!(
            peak > 0.8 * limit,
            "{joint} pushed against the obstacle: {peak:.2} N·m"
        );
        assert!(
            peak <= 1.02 * limit,
            "{joint}: {peak:.2} N·m against a {limit} N·m limit"
        );
    }
}

/// robot.toml `text` with the first `from` after joint `joint`'s name replaced by `to`.
fn in_joint(text: &str, joint: &str, from: &str, to: &str) -> String {
    let start = text.find(&format!("name = \"{joint}\"")).unwrap();
    let at = start + text[start..].find(from).unwrap();
    format!("{}{to}{}", &text[..at], &text[at + from.len()..])
}

/// rd-biped's left knee on the gantry, told to swing `swing` rad at the robot's stiffness, under
/// robot.toml with `extra` and the knee's torque limit at `limit` N·m (40 in the file): its
/// angle and speed every 2 ms for 0.2 s.
fn knee_swing(dir: &Path, name: &str, extra: &str, swing: f64, limit: f64) -> Vec<(f64, f64)> {
    let path = biped_with(dir, name, extra);
    let text = std::fs::read_to_string(&path).unwrap();
    let text = in_joint(
        &text,
        "left_knee",
        "torque_limit = 40.0",
        &format!("torque_limit = {limit:?}"),
    );
    let robot = Robot::from_str(&path, &text).unwrap();
    let i = robot
        .config
        .joints
        .iter()
        .position(|j| j.name == "left_knee")
        .unwrap();
    let mut host = on_gantry(&robot);
    let dof = {
        let w = host.world.lock().unwrap();
        ModelIndex::of_robot(w.data().model(), &robot).unwrap().joints[i]
    };
    let mut q: Vec<f64> = robot.config.joints.iter().map(|j| j.default_position).collect();
    q[i] += swing;
    let start = host.now();
    let mut trace = Vec::new();
    for k in 1..=100u32 {
        if k % 10 == 1 {
            host.command_positions(&robot, &q).unwrap();
        }
        host.wait_until(start + Duration::from_millis(2) * k);
        let w = host.world.lock().unwrap();
        trace.push((w.data().qpos()[dof.qpos], w.data().qvel()[dof.dof]));
    }
    trace
}

#[test]
fn the_trainers_actuator_law_drives_the_mirrors_joints() {
    let dir = std::env::temp_dir().join(format!("robodeploy-actuators-{}", std::process::id()));
    let law = |model: &str, more: &str| {
        format!("[[actuators]]\njoints = [\"left_knee\"]\nmodel = \"{model}\"\n{more}")
    };
    // The knee's limit at the AK10-9's own 65 N·m: the motor's clamp and the law's are one.
    const MOTOR: f64 = 65.0;
    let firmware = knee_swing(&dir, "firmware.toml", "", 1.2, MOTOR);
    let explicit = knee_swing(&dir, "explicit.toml", &law("explicit_pd", ""), 1.2, MOTOR);
    let implicit = knee_swing(&dir, "implicit.toml", &law("implicit_pd", ""), 1.2, MOTOR);
    // At the file's 40 N·m the trainer's law clips there, every physics step.
    let clipped = knee_swing(&dir, "clipped.toml", &law("explicit_pd", ""), 1.2, 40.0);
    let dc = knee_swing(
        &dir,
        "dc.toml",
        &law("dc_motor", "saturation_effort = 40.0\nvelocity_limit = 3.0\n"),
        1.2,
        MOTOR,
    );
    let delayed = knee_swing(
        &dir,
        "delayed.toml",
        &law("explicit_pd", "delay_steps = [10, 10]\n"),
        1.2,
        MOTOR,
    );
    let fastest = |t: &[(f64, f64)]| t.iter().map(|s| s.1.abs()).fold(0.0, f64::max);
    let apart = |a: &[(f64, f64)], b: &[(f64, f64)]| {
        a.iter()
            .zip(b)
            .map(|(x, y)| (x.0 - y.0).abs())
            .fold(0.0, f64::max)
    };
    // When the swing is a tenth of its way (ms, between the 2 ms samples).
    let tenth = |t: &[(f64, f64)]| {
        let gone = |k: usize| (t[k].0 - t[0].0).abs();
        let k = (0..t.len()).position(|k| gone(k) > 0.12).unwrap();
        2.0 * (k as f64 - (gone(k) - 0.12) / (gone(k) - gone(k - 1)))
    };
    eprintln!(
        "fastest: firmware {:.2}, explicit {:.2}, implicit {:.2}, dc motor {:.2}, delayed {:.2} rad/s; \
         explicit vs firmware {:.2e} rad, implicit vs explicit {:.4} rad, a tenth of the swing at {:.2} ms delayed, {:.2} ms not",
        fastest(&firmware),
        fastest(&explicit),
        fastest(&implicit),
        fastest(&dc),
        fastest(&delayed),
        apart(&explicit, &firmware),
        apart(&implicit, &explicit),
        tenth(&delayed),
        tenth(&explicit),
    );
    // The motor's own PD at a firmware period of one physics step is the trainer's explicit PD.
    assert!(apart(&explicit, &firmware) < 1e-9);
    // Damping handed to the integrator: the same law, a different numerical scheme.
    let implicit_gap = apart(&implicit, &explicit);
    assert!(implicit_gap > 0.0 && implicit_gap < 0.05, "{implicit_gap}");
    assert!(
        fastest(&clipped) < 0.95 * fastest(&explicit),
        "{} vs {}",
        fastest(&clipped),
        fastest(&explicit)
    );
    // A DC motor gives no torque beyond its no-load speed.
    assert!(fastest(&firmware) > 4.0);
    assert!(fastest(&dc) < 3.0 * 1.05, "{}", fastest(&dc));
    // Ten 1-ms steps' delay: the swing reaches a tenth of its way 10 ms later (the rest of the
    // hanging body, undelayed, moves it by a fraction of a millisecond).
    let lag = tenth(&delayed) - tenth(&explicit);
    assert!((lag - 10.0).abs() < 1.0, "{lag} ms");
    assert!(fastest(&delayed) > 4.0);
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_position_actuator_of_the_model_pushes_with_the_gains_robot_toml_writes_into_the_servo() {
    // rd-mini's MJCF gives its knees <position> actuators at kp 14, kv 0.3. robot.toml's knee
    // gains go into the servo (Dynamixel's Position P/D, Feetech's P/D) as the hardware gets
    // them; the mirror's actuator must push with those, not the file's.
    let dir = workspace_root().join("robots/mini");
    let dxl_text = std::fs::read_to_string(dir.join("robot.toml")).unwrap();
    for (bus, text) in [
        ("dynamixel", dxl_text.clone()),
        ("feetech", test_support::zoo::on_feetech(&dxl_text)),
    ] {
        let text = in_joint(&text, "l_knee", "kp = 14.0\nkd = 0.3", "kp = 28.0\nkd = 0.6");
        let robot = Robot::from_str(&dir.join("robot.toml"), &text).unwrap();
        let i = robot
            .config
            .joints
            .iter()
            .position(|j| j.name == "l_knee")
            .unwrap();
        let mut host = on_gantry(&robot);
        let q: Vec<f64> = robot.config.joints.iter().map(|j| j.default_position).collect();
        let start = host.now();
        for k in 1..=5u32 {
            host.command_positions(&robot, &q).unwrap();
            host.wait_until(start + Duration::from_millis(20) * k);
        }
        let w = host.world.lock().unwrap();
        let m = w.data().model();
        let id = ModelIndex::of_robot(m, &robot).unwrap().joints[i].id;
        let a = (0..m.ffi().nu as usize)
            .find(|&a| m.actuator_trnid()[a][0] == id as i32)
            .unwrap();
        let g2 = m.actuator_gear()[a][0].powi(2);
        let (kp, kd) = (m.actuator_gainprm()[a][0] * g2, -m.actuator_biasprm()[a][2] * g2);
        eprintln!(
            "{bus}: the knee's actuator at kp {kp:.2} N·m/rad, kd {kd:.3} N·m·s/rad (robot.toml 28, 0.6)"
        );
        // Within the registers' resolution (Feetech's P and D are bytes).
        assert!((kp - 28.0).abs() < 0.05 * 28.0, "{bus}: kp {kp}");
        assert_eq!(-m.actuator_biasprm()[a][1] * g2, kp);
        assert!((kd - 0.6).abs() < 0.1 * 0.6, "{bus}: kd {kd}");
    }
}
