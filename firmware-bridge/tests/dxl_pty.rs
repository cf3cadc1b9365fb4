//! The emulated servos served on a pseudo-terminal, in wall-clock time, to unmodified clients:
//! this project's driver on the `dynamixel2` crate, and ROBOTIS's Python `dynamixel-sdk`.

use std::sync::{Arc, Mutex};
use std::time::Duration;

use firmware_bridge::dxl::driver::{DxlBusDriver, DxlCommand, DxlDriverOptions, DxlJointConfig};
use firmware_bridge::dxl::models::find;
use firmware_bridge::dxl::transport::SerialDxlPort;
use firmware_bridge::dxl::wire::{DxlRig, WireTiming};
use firmware_bridge::serial::PtyServer;

const BAUD: u32 = 1_000_000;

fn serve(models: &[&str]) -> (Arc<Mutex<DxlRig>>, PtyServer) {
    let servos: Vec<_> = models
        .iter()
        .enumerate()
        .map(|(i, m)| (i as u8 + 1, find(m).unwrap()))
        .collect();
    let rig = DxlRig::bench(&servos, WireTiming::new(BAUD), Duration::from_micros(500));
    let world = Arc::new(Mutex::new(rig));
    let pty = PtyServer::spawn(Arc::clone(&world), 0, Duration::from_micros(200)).unwrap();
    (world, pty)
}

/// This project's driver on the served line: servo 1 (`models[0]`) and servo 2 (`models[1]`).
fn shoulder_and_elbow(pty: &PtyServer, models: [&str; 2]) -> DxlBusDriver<SerialDxlPort> {
    let port = SerialDxlPort::open(pty.path(), BAUD).unwrap();
    let joints = vec![
        DxlJointConfig::new("shoulder", 1, models[0]),
        DxlJointConfig::new("elbow", 2, models[1]),
    ];
    let options = DxlDriverOptions {
        // A pseudo-terminal and a loaded test machine need more than a USB adapter's margin.
        reply_slack: Duration::from_millis(30),
        ..DxlDriverOptions::default()
    };
    DxlBusDriver::new(port, joints, options).unwrap()
}

#[test]
fn the_dynamixel2_driver_drives_emulated_servos_through_a_serial_device() {
    let models = ["XM430-W350", "XL430-W250"];
    let (world, pty) = serve(&models);
    let mut d = shoulder_and_elbow(&pty, models);
    d.configure().unwrap();
    d.enable().unwrap();
    let commands = [0.4, -0.6].map(|q| DxlCommand { q, current: 0.0 });
    let start = std::time::Instant::now();
    let mut fresh = 0;
    while start.elapsed() < Duration::from_millis(800) {
        fresh += d.cycle(&commands).unwrap().fresh;
        std::thread::sleep(Duration::from_millis(10));
    }
    assert!(fresh > 20, "only {fresh} fresh joint states");
    for (fb, c) in d.feedback().iter().zip(commands) {
        assert!((fb.q - c.q).abs() < 0.03, "q = {} for goal {}", fb.q, c.q);
    }
    d.disable().unwrap();
    // The broadcast has no answer: wait (bounded) until the served servo has taken it.
    let give_up = std::time::Instant::now() + Duration::from_secs(10);
    while world.lock().unwrap().servo(0).torque_enabled() {
        assert!(std::time::Instant::now() < give_up, "torque still on");
        std::thread::yield_now();
    }
}

#[test]
fn robotis_dynamixel_sdk_pings_reads_writes_and_syncs_the_emulated_servos() {
    let (_world, pty) = serve(&["XM430-W350", "XM430-W350", "XL430-W250"]);
    let script =
        test_support::fixtures::workspace_root().join("firmware-bridge/tests/python/dxl_sdk_client.py");
    let out = std::process::Command::new(test_support::fixtures::venv_python())
        .arg(script)
        .args([pty.path(), &BAUD.to_string()])
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value = serde_json::from_str(&stdout).unwrap();
    let ping = &v["ping"];
    assert_eq!(ping["1"]["model"], 1020);
    assert_eq!(ping["2"]["model"], 1020);
    assert_eq!(ping["3"]["model"], 1060);
    assert_eq!(ping["9"]["ok"], false, "no servo 9");
    let ok = |key: &str| v[key]["ok"] == true && v[key]["error"] == 0;
    assert!(ok("torque_before") && v["torque_before"]["value"] == 0);
    assert!(ok("mode_write_torque_off") && v["mode_read_back"]["value"] == 4 && ok("mode_restore"));
    // The manual's error numbers: 4 data range, 7 access (EEPROM with torque on), 6 data limit.
    assert_eq!(v["mode_out_of_range"]["error"], 4);
    assert!(ok("torque_on_1") && ok("torque_on_2") && ok("torque_on_3"));
    assert_eq!(v["eeprom_with_torque_on"]["error"], 7);
    assert_eq!(v["goal_beyond_limit"]["error"], 6);
    assert_eq!(v["sync_write"], true);
    assert_eq!(v["sync_read_ok"], true);
    for id in ["1", "2", "3"] {
        let (present, goal) = (
            v["present"][id].as_i64().unwrap(),
            v["goals"][id].as_i64().unwrap(),
        );
        assert!(
            (present - goal).abs() <= 25,
            "servo {id}: present {present}, goal {goal}"
        );
    }
    assert!(ok("hardware_error") && v["hardware_error"]["value"] == 0);
    // Fast sync read and fast bulk read: one status packet, read by the SDK's own parser.
    assert_eq!(v["fast_sync_read_ok"], true, "{v}");
    for id in ["1", "2", "3"] {
        let (fast, present) = (
            v["fast_present"][id].as_i64().unwrap(),
            v["present"][id].as_i64().unwrap(),
        );
        assert!(
            (fast - present).abs() <= 5,
            "servo {id}: fast {fast}, sync {present}"
        );
    }
    assert_eq!(v["fast_bulk_read_ok"], true, "{v}");
    let position = v["fast_bulk"]["position_1"].as_i64().unwrap();
    assert!((position - v["present"]["1"].as_i64().unwrap()).abs() <= 5, "{v}");
    assert_eq!(v["fast_bulk"]["model_2"], 1020);
    assert_eq!(v["fast_bulk"]["temperature_3"], 25);
}

#[test]
fn a_client_that_floods_and_never_reads_neither_stalls_nor_kills_the_line() {
    use firmware_bridge::dxl::packet::{BROADCAST_ID, encode_instruction, inst};
    use std::io::Write;
    let models = ["XM430-W350", "XL430-W250"];
    let (world, pty) = serve(&models);
    {
        // Broadcast pings (every servo answers) between line noise, far faster than 1 Mbaud
        // carries them, from a client that never reads an answer.
        let mut flood = serialport::new(pty.path(), BAUD)
            .timeout(Duration::from_secs(5))
            .open_native()
            .unwrap();
        let mut chunk = Vec::new();
        let mut ping = [0u8; 16];
        let n = encode_instruction(BROADCAST_ID, inst::PING, &[], &mut ping).unwrap();
        for i in 0..400u32 {
            chunk.extend_from_slice(&ping[..n]);
            chunk.extend((0..7).map(|k| (i * 31 + k * 17) as u8));
        }
        let give_up = std::time::Instant::now() + Duration::from_secs(20);
        while pty.dropped() == 0 || world.lock().unwrap().wire().overflowed() == 0 {
            assert!(std::time::Instant::now() < give_up, "no overflow after 20 s");
            flood.write_all(&chunk).unwrap();
        }
    }
    // The line is still served: a well-behaved client drives the servos.
    let mut d = shoulder_and_elbow(&pty, models);
    let give_up = std::time::Instant::now() + Duration::from_secs(20);
    // The flood's queued bytes drain first; configuration succeeds once the line is quiet.
    while let Err(e) = d.configure() {
        assert!(
            std::time::Instant::now() < give_up,
            "the line never recovered: {e}"
        );
    }
    d.enable().unwrap();
    let commands = [0.3, -0.2].map(|q| DxlCommand { q, current: 0.0 });
    let mut fresh = 0;
    while fresh < 20 {
        assert!(std::time::Instant::now() < give_up, "only {fresh} fresh states");
        fresh += d.cycle(&commands).unwrap().fresh;
    }
}

#[test]
fn bytes_that_need_stuffing_after_another_ff_cross_the_serial_line_intact() {
    // FF FF FF FD: a velocity of −1 before a position ending in FD looks like this on the wire.
    // The stuffed FD must go in after the second FF of the three, both ways (dynamixel2 0.9.1's
    // own framing missed it and handed the status out a byte long).
    use firmware_bridge::dxl::table::addr;
    let models = ["XM430-W350", "XL430-W250"];
    let (_world, pty) = serve(&models);
    let mut d = shoulder_and_elbow(&pty, models);
    for data in [
        [0xFF, 0xFF, 0xFF, 0xFD],
        [0xFF, 0xFF, 0xFD, 0xFD],
        [0xFD, 0xFF, 0xFF, 0xFD],
    ] {
        d.write(2, addr::INDIRECT_DATA_1 + 4, &data).unwrap();
        let mut back = [0u8; 4];
        d.read(2, addr::INDIRECT_DATA_1 + 4, &mut back).unwrap();
        assert_eq!(back, data);
    }
}
