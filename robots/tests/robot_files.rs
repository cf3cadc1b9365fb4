//! The reference robot loads; broken robot files fail naming the file, the place and the value.

use std::path::{Path, PathBuf};

use robots::{BusKind, Robot, reference_robot_path};

fn reference_text() -> String {
    std::fs::read_to_string(reference_robot_path()).unwrap()
}

/// Checks `text` as if it were the reference robot.toml (so the MJCF beside it is found).
fn load_variant(text: &str) -> Result<Robot, robots::RobotError> {
    Robot::from_str(&reference_robot_path(), text)
}

#[test]
fn the_reference_biped_loads_with_twenty_joints_on_three_buses() {
    let robot = Robot::load(&reference_robot_path()).unwrap();
    let c = &robot.config;
    assert_eq!(c.joints.len(), 20);
    assert_eq!(robot.joints_on("can0").count(), 6);
    assert_eq!(robot.joints_on("can1").count(), 6);
    assert_eq!(robot.joints_on("dxl0").count(), 8);
    assert_eq!(robot.bus("imu0").unwrap().kind, BusKind::ImuSerial);
    assert!(robot.mjcf.floating);
    assert_eq!(c.joints[3].name, "left_knee");
}

fn expect_error(text: &str, needles: &[&str]) {
    let e = load_variant(text).unwrap_err().to_string();
    assert!(
        e.starts_with(&reference_robot_path().display().to_string()),
        "{e}"
    );
    for n in needles {
        assert!(e.contains(n), "{e}\n  should contain {n:?}");
    }
}

#[test]
fn an_unknown_mjcf_joint_is_named() {
    let text = reference_text().replacen("mjcf_joint = \"left_knee\"", "mjcf_joint = \"left_kneee\"", 1);
    expect_error(
        &text,
        &[
            "joints[3] (left_knee).mjcf_joint",
            "\"left_kneee\" is not a joint of the MJCF",
        ],
    );
}

#[test]
fn a_duplicate_id_on_a_bus_is_named() {
    let text = reference_text().replacen("bus = \"can0\"\nid = 2", "bus = \"can0\"\nid = 1", 1);
    expect_error(
        &text,
        &["joints[1] (left_hip_roll).id", "1 is used twice on bus can0"],
    );
}

#[test]
fn limits_beyond_the_motor_are_named_with_the_motor() {
    // The DM-J4310 ankle-roll motor gives 10 N·m.
    let text = reference_text().replacen("torque_limit = 8.0", "torque_limit = 12.0", 1);
    expect_error(
        &text,
        &["joints[5] (left_ankle_roll).torque_limit", "12", "DM-J4310", "10"],
    );
    let text = reference_text().replacen("velocity_limit = 7.5", "velocity_limit = 9.0", 1);
    expect_error(&text, &["(left_ankle_pitch).velocity_limit", "DM-J4340"]);
    let text = reference_text().replacen("position_limits = [0.0, 2.2]", "position_limits = [0.0, 2.5]", 1);
    expect_error(
        &text,
        &["(left_knee).position_limits", "leaves the MJCF joint range"],
    );
}

#[test]
fn a_missing_mesh_and_a_broken_mjcf_are_named() {
    let dir = std::env::temp_dir().join(format!("robots-mesh-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let xml = std::fs::read_to_string(reference_robot_path().with_file_name("biped.xml")).unwrap();
    let with_mesh = xml.replacen(
        "<worldbody>",
        "<asset><mesh name=\"shell\" file=\"meshes/shell.stl\"/></asset>\n  <worldbody>",
        1,
    );
    std::fs::write(dir.join("biped.xml"), with_mesh).unwrap();
    let toml_path: PathBuf = dir.join("robot.toml");
    let e = Robot::from_str(&toml_path, &reference_text())
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("mesh file") && e.contains("meshes/shell.stl") && e.contains("cannot read"),
        "{e}"
    );
    std::fs::write(dir.join("biped.xml"), "<mujoco><worldbody>").unwrap();
    let e = Robot::from_str(&toml_path, &reference_text())
        .unwrap_err()
        .to_string();
    assert!(e.contains("biped.xml: not valid XML"), "{e}");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn type_errors_and_unknown_fields_name_the_line() {
    let text = reference_text().replacen("kp = 60.0", "kp = \"stiff\"", 1);
    expect_error(&text, &["line ", "invalid type"]);
    let text = reference_text().replacen("zero_offset = 0.0", "zero_ofset = 0.0", 1);
    expect_error(&text, &["unknown field `zero_ofset`"]);
    let e = Robot::load(Path::new("/nonexistent/robot.toml"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("/nonexistent/robot.toml: file: cannot read"), "{e}");
}

#[test]
fn unknown_models_and_buses_are_named() {
    let text = reference_text().replacen("model = \"AK10-9\"", "model = \"XM430-W350\"", 1);
    expect_error(
        &text,
        &[
            "(left_hip_pitch).model",
            "\"XM430-W350\" is not an MIT-mode motor",
        ],
    );
    let text = reference_text().replacen("bus = \"dxl0\"", "bus = \"dxl9\"", 1);
    expect_error(&text, &[".bus", "\"dxl9\" is not a bus"]);
}

#[test]
fn a_bad_retargeting_map_is_named() {
    let text = reference_text().replacen("frame = \"left_hand\"", "frame = \"left_paw\"", 1);
    expect_error(
        &text,
        &[
            "retarget.pairs[2].frame",
            "\"left_paw\" is neither a body nor a site",
        ],
    );
    let text = reference_text().replacen("human = \"root\"", "human = \"head\"", 1);
    expect_error(&text, &["retarget.pairs[1].human", "paired twice"]);
    let text = reference_text().replacen("left_shoulder_roll = 1.5708", "left_shoulder_roll = 2.5", 1);
    expect_error(
        &text,
        &["retarget.tpose.left_shoulder_roll", "outside the joint's limits"],
    );
    let text = reference_text().replacen("human = \"left_hand\"", "human = \"left_paw\"", 1);
    expect_error(&text, &["left_paw"]);
}

#[test]
fn each_bus_gets_the_fastest_rate_its_wire_carries() {
    let robot = Robot::load(&reference_robot_path()).unwrap();
    // Six MIT motors on 1 Mbit/s CAN: 12 frames of at most 135 bits = 1.62 ms: 81 % of 2 ms
    // (500 Hz) is more than half; 250 Hz leaves 40 %.
    let can = robot.bus_timing("can0").unwrap();
    assert_eq!(can.rate_hz, 250.0);
    assert_eq!(can.wire_time.as_micros(), 1620);
    assert!((can.load() - 0.405).abs() < 1e-9);
    // Eight servos at 4 Mbaud: sync write 70 B + sync read 22 B + 8 statuses of 27 B = 308 B,
    // 0.77 ms, plus 1 ms of USB adapter latency: 1.77 ms is more than half of 2 ms; 250 Hz.
    // The reference robot sets 100 Hz (room for a pseudo-terminal's latency); the default is
    // what the same line gets without it.
    assert_eq!(robot.bus_timing("dxl0").unwrap().rate_hz, 100.0);
    let default = load_variant(&reference_text().replacen("rate_hz = 100.0", "", 1)).unwrap();
    let dxl = default.bus_timing("dxl0").unwrap();
    assert_eq!(dxl.wire_time.as_micros(), 770);
    assert_eq!(dxl.round_trip().as_micros(), 1770);
    assert_eq!(dxl.rate_hz, 250.0);
    // The IMU line is only read: 1 kHz.
    assert_eq!(robot.bus_timing("imu0").unwrap().rate_hz, 1000.0);
    // Ten periods, whole 20 ms steps on the Dynamixel line.
    assert_eq!(can.command_timeout.as_millis(), 40);
    assert_eq!(dxl.command_timeout.as_millis(), 40);
}

#[test]
fn bus_rates_and_timeouts_the_wire_or_the_policy_cannot_keep_are_named() {
    let set = |bus: &str, line: &str| {
        reference_text().replacen(
            &format!("name = \"{bus}\""),
            &format!("name = \"{bus}\"\n{line}"),
            1,
        )
    };
    // 1 kHz leaves 1 ms; six motors need 1.62 ms.
    expect_error(
        &set("can0", "rate_hz = 1000.0"),
        &["buses[0] (can0).rate_hz", "1000 Hz", "1.620 ms of wire time"],
    );
    // Slower than the 50 Hz policy.
    expect_error(
        &set("can1", "rate_hz = 25.0"),
        &["buses[1] (can1).rate_hz", "25 Hz is outside [50"],
    );
    expect_error(&set("can1", "rate_hz = nan"), &["buses[1] (can1).rate_hz", "NaN"]);
    // A timeout under two bus periods (4 ms at 250 Hz).
    expect_error(
        &set("can0", "command_timeout_ms = 7.0"),
        &["buses[0] (can0).command_timeout_ms", "7 ms is outside [8.000"],
    );
    expect_error(
        &set("dxl0", "command_timeout_ms = 30.0"),
        &["buses[2] (dxl0).command_timeout_ms", "20 ms steps"],
    );
    expect_error(
        &set("imu0", "interpolation = \"linear\""),
        &["buses[3] (imu0).interpolation"],
    );
    // A bus too slow for the policy at any rate: 6 motors at 125 kbit/s need 12.96 ms; a
    // 100 Hz policy leaves 10 ms.
    let slow = set("can0", "").replacen("rate = 1000000", "rate = 125000", 1);
    let fast_policy = slow.replacen("control_rate_hz = 50.0", "control_rate_hz = 100.0", 1);
    expect_error(&fast_policy, &["buses[0] (can0).rate", "12.960 ms of wire time"]);
    // The same line under the 50 Hz policy runs at 50 Hz.
    let robot = load_variant(&slow).unwrap();
    assert_eq!(robot.bus_timing("can0").unwrap().rate_hz, 50.0);
    // A policy faster than a configured bus.
    let policy_faster =
        set("can0", "rate_hz = 100.0").replacen("control_rate_hz = 50.0", "control_rate_hz = 200.0", 1);
    expect_error(
        &policy_faster,
        &["buses[0] (can0).rate_hz", "100 Hz is outside [200"],
    );
}

#[test]
fn a_position_margin_the_joints_cannot_give_is_named() {
    let with = |m: &str| {
        reference_text().replacen(
            "control_rate_hz = 50.0",
            &format!("control_rate_hz = 50.0\nposition_margin = {m}"),
            1,
        )
    };
    assert_eq!(
        load_variant(&with("0.05")).unwrap().config.position_margin,
        Some(0.05)
    );
    expect_error(
        &with("-0.01"),
        &["position_margin", "-0.01 rad is outside [0, 0.2]"],
    );
    expect_error(&with("nan"), &["position_margin", "NaN"]);
    // left_hip_roll spans 0.8 rad: a 0.2 rad margin leaves 0.4; the narrowest joint decides.
    let narrow = with("0.15").replacen(
        "position_limits = [-0.3, 0.5]",
        "position_limits = [-0.1, 0.1]",
        1,
    );
    expect_error(
        &narrow,
        &[
            "position_margin",
            "0.15 rad leaves nothing of joint left_hip_roll's 0.200 rad range",
        ],
    );
}

#[test]
fn the_compiled_model_is_summarised_with_its_sensors_actuators_and_floor() {
    let robot = Robot::load(&reference_robot_path()).unwrap();
    let m = &robot.mjcf;
    assert_eq!(m.floor.len(), 1, "{:?}", m.floor);
    let gyro = m.sensor("imu_gyro").unwrap();
    assert_eq!((gyro.kind, gyro.object.as_deref()), ("gyro", Some("imu")));
    // The IMU's sensors are found on its site, whatever their names.
    assert_eq!(
        robot.imu_sensors(),
        [
            Some("imu_gyro".into()),
            Some("imu_accel".into()),
            Some("imu_quat".into())
        ]
    );
    let knee = &m.joints["left_knee"];
    assert_eq!(knee.kind, robots::mjcf::JointKind::Hinge);
    assert_eq!(knee.range, Some((0.0, 2.2)));
}

#[test]
fn imu_sensor_names_and_a_start_keyframe_the_model_lacks_are_named() {
    let with =
        |extra: &str| reference_text().replacen("site = \"imu\"\n", &format!("site = \"imu\"\n{extra}\n"), 1);
    expect_error(
        &with("gyro = \"body_gyro\""),
        &[
            "imu.gyro",
            "\"body_gyro\" is not a sensor of the MJCF",
            "imu_gyro",
        ],
    );
    expect_error(
        &with("accelerometer = \"imu_gyro\""),
        &["imu.accelerometer", "is a gyro sensor, not a accelerometer"],
    );
    let keyed = reference_text().replacen(
        "control_rate_hz = 50.0",
        "control_rate_hz = 50.0\nstart_keyframe = \"home\"",
        1,
    );
    expect_error(
        &keyed,
        &["start_keyframe", "\"home\" is not a keyframe of the MJCF", "none"],
    );
}

/// rd-biped with its left knee on a motor model robot.toml defines itself, `ranges` replacing
/// the model's ranges.
fn with_own_knee_motor(ranges: &str) -> String {
    let own =
        format!("\n[[mit_models]]\nname = \"RD-X10\"\nreply = \"cubemars\"\n{ranges}\nrated_torque = 20.0\n");
    let text = reference_text().replacen(
        "name = \"left_knee\"\nmjcf_joint = \"left_knee\"\nbus = \"can0\"\nid = 4\nmodel = \"AK10-9\"",
        "name = \"left_knee\"\nmjcf_joint = \"left_knee\"\nbus = \"can0\"\nid = 4\nmodel = \"RD-X10\"",
        1,
    );
    // Top-level tables go before the first array of tables.
    text.replacen("\n[[buses]]", &format!("{own}\n[[buses]]"), 1)
}

const RD_X10: &str = "position = [-12.5, 12.5]\nvelocity = [-30.0, 30.0]\ntorque = [-45.0, 45.0]\nkp = [0.0, 500.0]\nkd = [0.0, 5.0]";

#[test]
fn a_robot_may_define_its_own_mit_motor_model_checked_like_the_shipped_ones() {
    let robot = load_variant(&with_own_knee_motor(RD_X10)).unwrap();
    let m = robot.mit_model("RD-X10").unwrap();
    assert_eq!((m.p_max, m.v_max, m.t_max, m.kp_max), (12.5, 30.0, 45.0, 500.0));
    // The shipped table is still there for the other joints.
    assert_eq!(robot.mit_model("AK10-9").unwrap().t_max, 65.0);
    // Limits beyond the model name it, as for a shipped model.
    let weak = RD_X10.replace("[-45.0, 45.0]", "[-30.0, 30.0]");
    expect_error(
        &with_own_knee_motor(&weak).replace("rated_torque = 20.0", "rated_torque = 10.0"),
        &["joints[3] (left_knee).torque_limit", "RD-X10", "30"],
    );
    // Inverted, lopsided and nonsense ranges are named by field.
    expect_error(
        &with_own_knee_motor(&RD_X10.replace("[-12.5, 12.5]", "[12.5, -12.5]")),
        &["mit_models[0] (RD-X10).position", "[12.5, -12.5] is not a range"],
    );
    expect_error(
        &with_own_knee_motor(&RD_X10.replace("[-30.0, 30.0]", "[-10.0, 30.0]")),
        &["mit_models[0] (RD-X10).velocity", "symmetric about zero"],
    );
    expect_error(
        &with_own_knee_motor(&RD_X10.replace("kd = [0.0, 5.0]", "kd = [1.0, 5.0]")),
        &["mit_models[0] (RD-X10).kd", "gains start at 0"],
    );
    expect_error(
        &with_own_knee_motor(RD_X10).replace("rated_torque = 20.0", "rated_torque = 50.0"),
        &["mit_models[0] (RD-X10).rated_torque", "(0, 45]"],
    );
}

#[test]
fn a_servo_variant_is_checked_against_its_own_constants() {
    let variant = |extra: &str| {
        reference_text()
            .replacen("id = 8\nmodel = \"XL430-W250\"", "id = 8\nmodel = \"XL-SLOW\"", 1)
            .replacen(
                "\n[[buses]]",
                &format!(
                    "\n[[servo_models]]\nname = \"XL-SLOW\"\nbase = \"XL430-W250\"\n{extra}\n\n[[buses]]"
                ),
                1,
            )
    };
    // 30 rpm is 3.14 rad/s: head_pitch's 6 rad/s is beyond it, named with the variant.
    expect_error(
        &variant("no_load_speed = 30.0"),
        &["joints[19] (head_pitch).velocity_limit", "XL-SLOW", "3.14"],
    );
    expect_error(
        &variant("stall_torque = -1.0"),
        &[
            "servo_models[0] (XL-SLOW).stall_torque",
            "-1 must be a positive number",
        ],
    );
    expect_error(
        &variant("").replacen("base = \"XL430-W250\"", "base = \"AX-12\"", 1),
        &[
            "servo_models[0] (XL-SLOW).base",
            "\"AX-12\" is not a shipped servo model",
            "XL430-W250",
        ],
    );
    // Within its constants it loads, and speaks as the shipped model.
    let robot = load_variant(&variant("no_load_speed = 61.0")).unwrap();
    assert_eq!(robot.dxl_protocol_model("XL-SLOW"), "XL430-W250");
}
