//! Unitree's low-level link. The `unitree_hg` messages as Unitree's own SDK reads them (robodeploy's
//! packed layout read back by the SDK's struct formats into every field in IDL order, its CRC equal
//! to the SDK's, its CDR read by the SDK's IDL classes and written back byte for byte); the SDK
//! itself, over Cyclone DDS, as the emulated G1's client; the G1 on its link, in lockstep and over
//! DDS in real time; bad link settings refused by name.

use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::AtomicBool;
use std::time::Duration;

use controller::player::{PlayOptions, Player};
use controller::safety::{Cause, Mode};
use firmware_bridge::unitree::hg::{LowCmd, LowState, MOTORS, Sealed as _};
use policy::PolicyLayout;
use robots::Robot;
use serde_json::{Value, json};
use sim2real::config::{FaultKind, MirrorConfig, ScheduledFault};
use test_support::fixtures::workspace_root;

#[global_allocator]
static ALLOC: test_support::alloc::CountingAllocator = test_support::alloc::CountingAllocator;

/// A deterministic stream of varied values (no two fields alike, signs and magnitudes mixed).
struct Draw(u64);

impl Draw {
    fn next(&mut self) -> u64 {
        self.0 = self
            .0
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1_442_695_040_888_963_407);
        self.0 >> 33
    }
    fn f32(&mut self) -> f32 {
        (self.next() % 2_000_001) as f32 / 1000.0 - 1000.0
    }
    fn u32(&mut self) -> u32 {
        self.next() as u32
    }
    fn u8(&mut self) -> u8 {
        self.next() as u8
    }
    fn i16(&mut self) -> i16 {
        self.next() as i16
    }
}

fn low_cmd(d: &mut Draw) -> (LowCmd, Vec<Value>) {
    let mut c = LowCmd {
        mode_pr: d.u8(),
        mode_machine: d.u8(),
        ..LowCmd::default()
    };
    let mut fields = vec![json!(c.mode_pr), json!(c.mode_machine)];
    for m in c.motor_cmd.iter_mut() {
        m.mode = d.u8();
        m.q = d.f32();
        m.dq = d.f32();
        m.tau = d.f32();
        m.kp = d.f32();
        m.kd = d.f32();
        m.reserve = d.u32();
        fields.extend([
            json!(m.mode),
            json!(m.q),
            json!(m.dq),
            json!(m.tau),
            json!(m.kp),
            json!(m.kd),
        ]);
        fields.push(json!(m.reserve));
    }
    for r in c.reserve.iter_mut() {
        *r = d.u32();
        fields.push(json!(*r));
    }
    c.seal();
    fields.push(json!(c.crc));
    (c, fields)
}

fn low_state(d: &mut Draw) -> (LowState, Vec<Value>) {
    let mut s = LowState {
        version: [d.u32(), d.u32()],
        mode_pr: d.u8(),
        mode_machine: d.u8(),
        tick: d.u32(),
        ..LowState::default()
    };
    let mut fields = vec![
        json!(s.version[0]),
        json!(s.version[1]),
        json!(s.mode_pr),
        json!(s.mode_machine),
        json!(s.tick),
    ];
    let imu = &mut s.imu_state;
    for v in imu
        .quaternion
        .iter_mut()
        .chain(imu.gyroscope.iter_mut())
        .chain(imu.accelerometer.iter_mut())
        .chain(imu.rpy.iter_mut())
    {
        *v = d.f32();
        fields.push(json!(*v));
    }
    imu.temperature = d.i16();
    fields.push(json!(imu.temperature));
    for m in s.motor_state.iter_mut() {
        m.mode = d.u8();
        fields.push(json!(m.mode));
        for v in [&mut m.q, &mut m.dq, &mut m.ddq, &mut m.tau_est] {
            *v = d.f32();
            fields.push(json!(*v));
        }
        m.temperature = [d.i16(), d.i16()];
        m.vol = d.f32();
        fields.extend([json!(m.temperature[0]), json!(m.temperature[1]), json!(m.vol)]);
        for v in m
            .sensor
            .iter_mut()
            .chain(std::iter::once(&mut m.motorstate))
            .chain(m.reserve.iter_mut())
        {
            *v = d.u32();
            fields.push(json!(*v));
        }
    }
    for b in s.wireless_remote.iter_mut() {
        *b = d.u8();
        fields.push(json!(*b));
    }
    for r in s.reserve.iter_mut() {
        *r = d.u32();
        fields.push(json!(*r));
    }
    s.seal();
    fields.push(json!(s.crc));
    (s, fields)
}

fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

#[test]
fn packed_messages_and_their_crc_are_what_unitrees_sdk_computes() {
    assert_eq!(MOTORS, 35);
    let mut d = Draw(7);
    let mut cases = Vec::new();
    let mut cdr = Vec::new();
    for _ in 0..8 {
        let (cmd, fields) = low_cmd(&mut d);
        let mut packed = [0u8; LowCmd::PACKED_LEN];
        cmd.pack(&mut packed);
        cmd.write_cdr(&mut cdr);
        cases.push(
            json!({"kind": "LowCmd", "packed_hex": hex(&packed), "cdr_hex": hex(&cdr), "fields": fields}),
        );
        let (state, fields) = low_state(&mut d);
        let mut packed = [0u8; LowState::PACKED_LEN];
        state.pack(&mut packed);
        state.write_cdr(&mut cdr);
        cases.push(
            json!({"kind": "LowState", "packed_hex": hex(&packed), "cdr_hex": hex(&cdr), "fields": fields}),
        );
    }
    let path = std::env::temp_dir().join(format!("unitree-cases-{}.json", std::process::id()));
    std::fs::write(&path, serde_json::to_string(&cases).unwrap()).unwrap();
    let out = std::process::Command::new(test_support::fixtures::venv_python())
        .arg(workspace_root().join("tests/python/unitree_crc.py"))
        .arg(&path)
        .output()
        .unwrap();
    std::fs::remove_file(&path).unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let verdict: Value = serde_json::from_slice(&out.stdout).unwrap();
    let results = verdict["results"].as_array().unwrap();
    assert_eq!(results.len(), 16, "{verdict}");
    for r in results {
        assert_eq!(
            (&r["size"], &r["fields"], &r["crc"], &r["cdr"]),
            (&json!(true), &json!(true), &json!(true), &json!(true)),
            "{verdict}"
        );
    }
}

fn g1() -> PathBuf {
    workspace_root().join("robots/g1/robot.toml")
}

/// The G1 with holosoma's dance export (its contract and the motion it carries).
fn g1_dance() -> (Robot, PolicyLayout, controller::clip::Reference) {
    let robot = Robot::load(&g1()).unwrap();
    let dance = workspace_root().join(".local/holosoma-inference/models/wbt/ppo_g1_29dof_dancing.onnx");
    let mut layout = PolicyLayout::load(&dance, &robot).unwrap();
    let (reference, _) = controller::reference::load_reference(None, &dance, &mut layout, &robot, 0).unwrap();
    (robot, layout, reference)
}

#[test]
fn unitrees_own_sdk_reads_the_emulated_g1_moves_a_joint_and_its_wrong_crcs_are_ignored() {
    // The SDK client and the served mirror in a network namespace of the test's own: DDS
    // discovery's multicast never leaves it.
    let (slot, target) = (18, 1.2); // left_elbow_joint, from its 0.6 rad standing angle
    let verdict = test_support::netns::python_verdict(
        "tests/python/unitree_sdk_client.py",
        &[
            test_support::bin::robodeploy_path().display().to_string(),
            g1().display().to_string(),
            slot.to_string(),
            target.to_string(),
        ],
    );
    let v: Value = serde_json::from_str(&verdict).unwrap_or_else(|e| panic!("{e}: {verdict}"));
    let f = |k: &str| v[k].as_f64().unwrap_or_else(|| panic!("{k}: {v}"));
    // 500 Hz, every state's CRC as the SDK computes it, the IMU's quaternion a unit one, the
    // motors at ambient on a 54.6 V supply, the variant the board reports.
    assert!((400.0..=560.0).contains(&f("states_per_s")), "{v}");
    assert_eq!(v["crc_ok"], json!(true), "{v}");
    assert!((f("quat_norm") - 1.0).abs() < 1e-3, "{v}");
    assert_eq!(
        (f("temperature"), v["mode_machine"].as_u64()),
        (25.0, Some(5)),
        "{v}"
    );
    assert!((f("voltage") - 54.6).abs() < 1e-3, "{v}");
    // The joint went where LowCmd asked (a stiffness of 60 against the forearm's weight), torque
    // on; held on its gantry, the accelerometer feels the stand hold the robot against gravity.
    assert!((f("start_q") - 0.6).abs() < 0.05, "{v}");
    assert!((f("moved_q") - target).abs() < 0.15, "{v}");
    assert_eq!(v["moved_mode"], json!(1), "{v}");
    assert!((f("accel_norm") - 9.81).abs() < 1.0, "{v}");
    // Commands with a wrong CRC were not taken: the motors timed out (mode 0, Unitree's
    // command-timeout bit), and the board counted the refusals.
    assert_eq!(v["after_bad_mode"], json!(0), "{v}");
    assert_eq!(v["after_bad_status"], json!(0x4000_0000u32), "{v}");
    let counts = v["server"]
        .as_array()
        .unwrap()
        .iter()
        .filter_map(|l| l.as_str())
        .find(|l| l.starts_with("unitree lowlevel:"))
        .unwrap_or_else(|| panic!("no board counts: {v}"))
        .to_owned();
    let number = |after: &str| -> u64 {
        let (head, _) = counts.split_once(after).unwrap_or_else(|| panic!("{counts}"));
        head.rsplit(|c: char| !c.is_ascii_digit())
            .find(|w| !w.is_empty())
            .unwrap()
            .parse()
            .unwrap()
    };
    assert!(number(" commands taken") >= 50, "{counts}");
    assert!(number(" refused for their CRC") >= 10, "{counts}");
    assert_eq!(number(" malformed"), 0, "{counts}");
}

#[test]
fn on_its_link_the_g1_ticks_without_allocating_and_a_motor_dropping_out_damps_it_within_two_link_cycles() {
    use firmware_bridge::time::{SimInstant, SimWorld};
    use robot_link::{RobotLink, TickClock};
    use test_support::alloc::count_allocations;
    let (robot, layout, reference) = g1_dance();
    let knee = robot
        .config
        .joints
        .iter()
        .position(|j| j.name == "left_knee_joint")
        .unwrap();
    // 7 ms after a policy tick's instant, inside a 2 ms link cycle, the dance well under way.
    let dropout = Duration::from_millis(6007);
    let mirror = MirrorConfig {
        faults: vec![ScheduledFault {
            at_s: dropout.as_secs_f64(),
            joint: "left_knee_joint".into(),
            fault: FaultKind::Vanish,
        }],
        ..MirrorConfig::default()
    };
    let (mut p, mut clock, world) = controller::sim::lockstep_player(
        robot,
        layout,
        reference,
        PlayOptions::default(),
        mirror,
        Arc::new(AtomicBool::new(false)),
    )
    .unwrap();
    let period = Duration::from_millis(20);
    let tick = |p: &mut Player<sim2real::link::LockstepRobot>, clock: &mut sim2real::link::LockstepClock| {
        p.step(clock).unwrap();
        p.wait_until(clock, period * p.ticks() as u32);
    };
    p.identify().unwrap();
    while p.ticks() < 250 {
        tick(&mut p, &mut clock);
    }
    assert_eq!(p.mode(), Mode::Running, "{:?}", p.transitions());
    // The link in lockstep runs on the loop's thread: the whole tick, link included.
    let (_, stats) = count_allocations(|| {
        for _ in 0..40 {
            tick(&mut p, &mut clock);
        }
    });
    assert!(stats.is_zero(), "{stats:?}");
    while p.mode() != Mode::Off {
        tick(&mut p, &mut clock);
    }
    let s = p.summary_so_far();
    let mirror_now = world.lock().unwrap().now().saturating_since(SimInstant::ZERO);
    let offset = mirror_now - clock.elapsed();
    let bus = p.link().bus_names().iter().position(|n| n == "lowlevel").unwrap();
    let stats = p.link().bus_stats()[bus];
    let link_period = p.robot().bus_timing("lowlevel").unwrap().period;
    assert_eq!(link_period, Duration::from_millis(2));
    // The first state after the dropout says so (Unitree's lost-motor bit): its cycle damps the
    // board's joints.
    let detected = stats.damped_at.expect("the link damped itself") + offset;
    assert!(detected > dropout, "{detected:?}");
    assert!(
        detected - dropout <= link_period * 2,
        "damped {:?} after the dropout",
        detected - dropout
    );
    // The loop damps everything at its next tick, straight from Running.
    let damped = s
        .transitions
        .iter()
        .find(|t| t.to == Mode::Damped)
        .expect("damping");
    assert_eq!(damped.from, Mode::Running, "{s}");
    assert!(
        matches!(damped.cause, Cause::DeviceFault { joint, .. } if joint == knee),
        "{s}"
    );
    let damped_at = period * damped.tick as u32 + offset;
    assert!(damped_at > detected && damped_at - detected <= period, "{s}");
}

#[test]
fn over_dds_in_real_time_the_g1_dances_and_its_loop_and_link_threads_allocate_nothing() {
    use test_support::alloc::{count_allocations, watch_this_thread, watched_heap_ops};
    let (robot, layout, reference) = g1_dance();
    // What is measured is allocation: late states on a busy machine are tolerated here (their
    // safety is tested in lockstep above and by the wall-clock runs of the shipped robots).
    let options = PlayOptions {
        limits: controller::safety::SafetyLimits {
            stale_cycles: 1000,
            overruns: 1000,
            tracking_ticks: 1000,
            ..Default::default()
        },
        ..PlayOptions::default()
    };
    // The board served over DDS on loopback; the link's bus thread has every heap operation
    // counted (the middleware's own threads allocate per sample, by its design).
    let (mut p, mut clock, served) = controller::sim::wired_player(
        robot,
        layout,
        reference,
        options,
        MirrorConfig::default(),
        Arc::new(AtomicBool::new(false)),
        watch_this_thread,
    )
    .unwrap();
    p.identify().unwrap();
    let period = Duration::from_millis(20);
    let mut tick = |p: &mut Player<sim2real::link::WiredRobot>| {
        p.step(&clock).unwrap();
        p.wait_until(&mut clock, period * p.ticks() as u32);
    };
    while p.ticks() < 200 {
        tick(&mut p);
    }
    assert_eq!(p.mode(), Mode::Running, "{:?}", p.transitions());
    let before = watched_heap_ops();
    let (_, stats) = count_allocations(|| {
        for _ in 0..100 {
            tick(&mut p);
        }
    });
    let on_link_thread = watched_heap_ops() - before;
    assert_eq!(p.mode(), Mode::Running, "{:?}", p.transitions());
    assert!(
        stats.is_zero() && on_link_thread == 0,
        "loop thread: {stats:?}; heap operations on the link's thread: {on_link_thread}"
    );
    // It went over the network: the board took the link's commands and published its states.
    let world = served.world.lock().unwrap();
    let board = world
        .unitree_board(world.unitree_line("lowlevel").unwrap())
        .unwrap()
        .stats();
    assert!(board.accepted > 1000 && board.bad_crc == 0, "{board:?}");
    let height = world.root_pose()[2];
    assert!(height > 0.6, "the G1's pelvis at {height} m: it fell");
}

#[test]
fn bad_link_settings_are_refused_by_name_and_nothing_is_sent() {
    let dir = std::env::temp_dir().join(format!("unitree-bad-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let text = std::fs::read_to_string(g1()).unwrap();
    let mjcf = workspace_root().join(".local/holosoma/data/robots/g1/scenes/scene_g1_29dof_wbt_plane.xml");
    let text = text.replace(
        "mjcf = \"../../.local/holosoma/data/robots/g1/scenes/scene_g1_29dof_wbt_plane.xml\"",
        &format!("mjcf = {:?}", mjcf.display().to_string()),
    );
    let check = |name: &str, edited: String, wants: &[&str]| {
        assert_ne!(edited, text, "{name}: the edit did not apply");
        let path = dir.join(format!("{name}.toml"));
        std::fs::write(&path, edited).unwrap();
        let (ok, out, err) = test_support::bin::run(&["check", "--robot", path.to_str().unwrap()]);
        assert!(!ok, "{name}: {out}");
        for w in wants {
            assert!(err.contains(w), "{name}: no {w:?} in: {err}");
        }
    };
    check(
        "domain",
        text.replace("domain = 0", "domain = 300"),
        &["buses[0] (lowlevel).domain", "300 is outside [0, 232]"],
    );
    check(
        "family",
        text.replace("family = \"unitree_hg\"", "family = \"unitree_go\""),
        &["unitree_go", "unitree_hg"],
    );
    // Two joints on one motor index; an index beyond the message's 35 slots.
    check(
        "collide",
        text.replacen("id = 1\n", "id = 0\n", 1),
        &["id", "0 is used twice on bus lowlevel"],
    );
    check(
        "slot",
        text.replacen("id = 28\n", "id = 35\n", 1),
        &["id", "35 is outside [0, 34]"],
    );
    // An interface the machine does not have: named with the machine's own, before anything is
    // sent.
    let path = dir.join("interface.toml");
    std::fs::write(&path, text.replace("device = \"eth0\"", "device = \"rdnosuch0\"")).unwrap();
    let (ok, out, err) = test_support::bin::run(&["bus", "scan", "--robot", path.to_str().unwrap()]);
    assert!(!ok, "{out}");
    assert!(
        err.contains("\"rdnosuch0\" does not exist") && err.contains("lo"),
        "{err}"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}
