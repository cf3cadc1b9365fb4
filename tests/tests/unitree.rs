//! The `unitree_hg` messages as Unitree's own SDK reads them: robodeploy's packed layout read back
//! by the SDK's struct formats into every field in IDL order, its CRC equal to the SDK's, and its
//! CDR (what DDS carries) read by the SDK's IDL classes and written back byte for byte.

use firmware_bridge::unitree::hg::{LowCmd, LowState, MOTORS, Sealed as _};
use serde_json::{Value, json};

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
        cases.push(json!({"kind": "LowCmd", "packed_hex": hex(&packed), "cdr_hex": hex(&cdr), "fields": fields}));
        let (state, fields) = low_state(&mut d);
        let mut packed = [0u8; LowState::PACKED_LEN];
        state.pack(&mut packed);
        state.write_cdr(&mut cdr);
        cases.push(json!({"kind": "LowState", "packed_hex": hex(&packed), "cdr_hex": hex(&cdr), "fields": fields}));
    }
    let path = std::env::temp_dir().join(format!("unitree-cases-{}.json", std::process::id()));
    std::fs::write(&path, serde_json::to_string(&cases).unwrap()).unwrap();
    let out = std::process::Command::new(test_support::fixtures::venv_python())
        .arg(test_support::fixtures::workspace_root().join("tests/python/unitree_crc.py"))
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
