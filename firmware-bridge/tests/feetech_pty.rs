//! The emulated Feetech servos served on a pseudo-terminal in wall-clock time to Feetech's own
//! Python SDK (`feetech-servo-sdk`): ping, read, write, sync write and sync read.

use std::sync::{Arc, Mutex};
use std::time::Duration;

use firmware_bridge::feetech::models::find;
use firmware_bridge::feetech::wire::FeetechRig;
use firmware_bridge::serial::PtyServer;

const BAUD: u32 = 1_000_000;

#[test]
fn feetechs_sdk_pings_reads_writes_and_syncs_the_emulated_servos() {
    let m = find("STS3215").unwrap();
    let world = Arc::new(Mutex::new(FeetechRig::bench(&[(1, m), (2, m), (3, m)], BAUD)));
    let pty = PtyServer::spawn(Arc::clone(&world), 0, Duration::from_micros(200)).unwrap();
    let script =
        test_support::fixtures::workspace_root().join("firmware-bridge/tests/python/feetech_sdk_client.py");
    let out = std::process::Command::new(test_support::fixtures::venv_python())
        .arg(script)
        .args([pty.path(), &BAUD.to_string(), "1", "2", "3"])
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value = serde_json::from_str(&stdout).unwrap();
    for id in ["1", "2", "3"] {
        assert_eq!(v["ping"][id]["model"], 777, "{v}");
    }
    assert_eq!(v["ping"]["9"]["ok"], false, "no servo 9: {v}");
    assert_eq!(v["lock"]["value"], 1, "{v}");
    assert_eq!(v["return_delay"]["value"], 5, "{v}");
    assert_eq!(v["sync_write"], true, "{v}");
    assert_eq!(v["sync_read_ok"], true, "{v}");
    for id in ["1", "2", "3"] {
        let (present, goal) = (
            v["present"][id].as_i64().unwrap(),
            v["goals"][id].as_i64().unwrap(),
        );
        assert!(
            (present - goal).abs() <= 15,
            "servo {id}: present {present}, goal {goal}: {v}"
        );
    }
    assert_eq!(v["status"], 0, "{v}");
    let w = world.lock().unwrap();
    assert_eq!(w.wire().chain().stats().checksum_errors, 0);
}
