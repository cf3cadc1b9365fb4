//! The emulated BNO055 served on a pseudo-terminal in wall-clock time to Adafruit's own driver
//! (`adafruit-circuitpython-bno055`, its UART class): restart, page 1 configuration, mode
//! changes with their datasheet waits, and every output read back in the driver's units.

use std::sync::{Arc, Mutex};
use std::time::Duration;

use firmware_bridge::imu::bno055::Bno055Bench;
use firmware_bridge::imu::wit::ImuSample;
use firmware_bridge::serial::PtyServer;

#[test]
fn adafruits_driver_configures_and_reads_the_emulated_bno055() {
    let (roll, pitch, yaw) = (10f64.to_radians(), -5f64.to_radians(), 30f64.to_radians());
    // The attitude as a quaternion (z-y-x), and gravity as the tilted part feels it.
    let (cr, sr) = ((roll / 2.0).cos(), (roll / 2.0).sin());
    let (cp, sp) = ((pitch / 2.0).cos(), (pitch / 2.0).sin());
    let (cy, sy) = ((yaw / 2.0).cos(), (yaw / 2.0).sin());
    let quat = [
        cr * cp * cy + sr * sp * sy,
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
    ];
    let sample = ImuSample {
        accel: [0.85, 1.68, 9.62],
        gyro: [0.1, -0.2, 0.3],
        quat,
        rpy: [roll, pitch, yaw],
        temperature: 30.0,
    };
    let world = Arc::new(Mutex::new(Bno055Bench::new(sample)));
    let pty = PtyServer::spawn(Arc::clone(&world), 0, Duration::from_micros(200)).unwrap();
    let script =
        test_support::fixtures::workspace_root().join("firmware-bridge/tests/python/bno055_client.py");
    let out = std::process::Command::new(test_support::fixtures::venv_python())
        .arg(script)
        .arg(pty.path())
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value = serde_json::from_str(&stdout).unwrap();
    let list = |key: &str| -> Vec<f64> {
        v[key]
            .as_array()
            .unwrap_or_else(|| panic!("{key} in {v}"))
            .iter()
            .map(|x| x.as_f64().unwrap_or_else(|| panic!("{key} in {v}")))
            .collect()
    };
    // NDOF (0x0C), the driver's ranges (±4 g: 1, ±2000 °/s: 0) read back from page 1.
    assert_eq!(v["mode"], 0x0C, "{v}");
    assert_eq!(
        (v["accel_range"].clone(), v["gyro_range"].clone()),
        (1.into(), 0.into())
    );
    assert_eq!(v["temperature"], 30);
    let near = |got: &[f64], want: &[f64], step: f64| {
        got.len() == want.len() && got.iter().zip(want).all(|(g, w)| (g - w).abs() <= step)
    };
    assert!(near(&list("acceleration"), &sample.accel, 0.01), "{v}");
    assert!(near(&list("gyro"), &sample.gyro, 0.0011), "{v}");
    // Euler: heading, roll, pitch in degrees, 1/16° steps.
    assert!(near(&list("euler"), &[30.0, 10.0, -5.0], 1.0 / 16.0), "{v}");
    assert!(near(&list("quaternion"), &quat, 1.0 / 16384.0), "{v}");
}
