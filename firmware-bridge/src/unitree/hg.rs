//! `unitree_hg`: the low-level messages of the G1 and H1-2 (`unitree_hg::msg::dds_::LowCmd_`,
//! `LowState_`), 35 motor slots each, and their packed layout for the CRC.

use dds::cdr::{CdrError, CdrReader, CdrWriter};

use super::crc_of_packed;

/// The DDS type of [`LowCmd`].
pub const LOW_CMD_TYPE: &str = "unitree_hg::msg::dds_::LowCmd_";
/// The DDS type of [`LowState`].
pub const LOW_STATE_TYPE: &str = "unitree_hg::msg::dds_::LowState_";

/// Motor slots in every message of the family (a robot uses the first ones it has).
pub const MOTORS: usize = 35;

/// One motor's command.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct MotorCmd {
    /// 0: off (brake), 1: on (FOC control).
    pub mode: u8,
    /// Position target, rad.
    pub q: f32,
    /// Velocity target, rad/s.
    pub dq: f32,
    /// Feed-forward torque, N·m.
    pub tau: f32,
    /// Position gain, N·m/rad.
    pub kp: f32,
    /// Velocity gain, N·m·s/rad.
    pub kd: f32,
    /// Reserved.
    pub reserve: u32,
}

/// `rt/lowcmd`: every motor's command, the machine's modes, and the CRC over all of it.
#[derive(Debug, Clone, PartialEq)]
pub struct LowCmd {
    /// Parallel-mechanism (ankle, waist) control mode: 0 pitch/roll, 1 the motors' A/B.
    pub mode_pr: u8,
    /// The robot variant the board reports (`LowState::mode_machine`), echoed back.
    pub mode_machine: u8,
    /// Commands by motor index.
    pub motor_cmd: [MotorCmd; MOTORS],
    /// Reserved.
    pub reserve: [u32; 4],
    /// The CRC ([`Self::seal`] sets it).
    pub crc: u32,
}

impl Default for LowCmd {
    fn default() -> Self {
        Self {
            mode_pr: 0,
            mode_machine: 0,
            motor_cmd: [MotorCmd::default(); MOTORS],
            reserve: [0; 4],
            crc: 0,
        }
    }
}

/// A message that carries Unitree's CRC over its packed layout: a command with a wrong one is
/// ignored by the robot, a state with a wrong one is not to be believed.
pub trait Sealed {
    /// Packs the message into the front of `out` (room for the largest of the family); returns
    /// its length.
    fn packed(&self, out: &mut [u8; LowState::PACKED_LEN]) -> usize;
    /// Where the CRC is kept.
    fn crc_field(&mut self) -> &mut u32;
    /// The CRC it carries.
    fn crc(&self) -> u32;

    /// The CRC this message should carry.
    fn compute_crc(&self) -> u32 {
        let mut out = [0u8; LowState::PACKED_LEN];
        let len = self.packed(&mut out);
        crc_of_packed(&out[..len])
    }

    /// Sets the CRC.
    fn seal(&mut self) {
        *self.crc_field() = self.compute_crc();
    }

    /// Whether the CRC it carries is right.
    fn crc_ok(&self) -> bool {
        self.crc() == self.compute_crc()
    }
}

/// Where a message's fields go, in IDL order: its packed C layout (the padding C puts between
/// fields, written out) or its CDR (aligned by the encoding itself). One walk over the fields
/// serves both, so the two layouts cannot disagree on order.
trait FieldSink {
    fn u8(&mut self, v: u8);
    fn i16(&mut self, v: i16);
    fn u32(&mut self, v: u32);
    fn f32(&mut self, v: f32);
    fn octets(&mut self, v: &[u8]);
    /// C's padding before the next field (CDR's alignment covers it).
    fn pad(&mut self, n: usize);
}

/// Writes little-endian fields at their C offsets.
struct Packer<'a> {
    out: &'a mut [u8],
    at: usize,
}

impl FieldSink for Packer<'_> {
    fn octets(&mut self, b: &[u8]) {
        self.out[self.at..self.at + b.len()].copy_from_slice(b);
        self.at += b.len();
    }
    fn pad(&mut self, n: usize) {
        self.out[self.at..self.at + n].fill(0);
        self.at += n;
    }
    fn u8(&mut self, v: u8) {
        self.octets(&[v]);
    }
    fn f32(&mut self, v: f32) {
        self.octets(&v.to_le_bytes());
    }
    fn u32(&mut self, v: u32) {
        self.octets(&v.to_le_bytes());
    }
    fn i16(&mut self, v: i16) {
        self.octets(&v.to_le_bytes());
    }
}

impl FieldSink for CdrWriter<'_> {
    fn u8(&mut self, v: u8) {
        CdrWriter::u8(self, v);
    }
    fn i16(&mut self, v: i16) {
        CdrWriter::i16(self, v);
    }
    fn u32(&mut self, v: u32) {
        CdrWriter::u32(self, v);
    }
    fn f32(&mut self, v: f32) {
        CdrWriter::f32(self, v);
    }
    fn octets(&mut self, v: &[u8]) {
        CdrWriter::octets(self, v);
    }
    fn pad(&mut self, _: usize) {}
}

impl LowCmd {
    /// Bytes of the packed (C) layout.
    pub const PACKED_LEN: usize = 1004;
    /// Bytes of its CDR, the encapsulation header included.
    pub const CDR_LEN: usize = 1004;

    /// Every field in IDL order into `sink`.
    fn fields(&self, sink: &mut impl FieldSink) {
        sink.u8(self.mode_pr);
        sink.u8(self.mode_machine);
        sink.pad(2);
        for m in &self.motor_cmd {
            sink.u8(m.mode);
            sink.pad(3);
            for v in [m.q, m.dq, m.tau, m.kp, m.kd] {
                sink.f32(v);
            }
            sink.u32(m.reserve);
        }
        for r in self.reserve {
            sink.u32(r);
        }
        sink.u32(self.crc);
    }

    /// The message in the SDK's C layout, as the CRC reads it.
    pub fn pack(&self, out: &mut [u8; Self::PACKED_LEN]) {
        let mut p = Packer { out, at: 0 };
        self.fields(&mut p);
        debug_assert_eq!(p.at, Self::PACKED_LEN);
    }

    /// The message as DDS carries it (CDR, into `buf`).
    pub fn write_cdr(&self, buf: &mut Vec<u8>) {
        self.fields(&mut CdrWriter::new(buf));
    }

    /// The message from its CDR.
    pub fn read_cdr(sample: &[u8]) -> Result<Self, CdrError> {
        let mut r = CdrReader::new(sample)?;
        let mut out = Self {
            mode_pr: r.u8()?,
            mode_machine: r.u8()?,
            ..Self::default()
        };
        for m in &mut out.motor_cmd {
            *m = MotorCmd {
                mode: r.u8()?,
                q: r.f32()?,
                dq: r.f32()?,
                tau: r.f32()?,
                kp: r.f32()?,
                kd: r.f32()?,
                reserve: r.u32()?,
            };
        }
        for v in &mut out.reserve {
            *v = r.u32()?;
        }
        out.crc = r.u32()?;
        Ok(out)
    }
}

impl Sealed for LowCmd {
    fn packed(&self, out: &mut [u8; LowState::PACKED_LEN]) -> usize {
        let (head, _) = out.split_at_mut(Self::PACKED_LEN);
        self.pack(head.try_into().expect("the first PACKED_LEN bytes"));
        Self::PACKED_LEN
    }
    fn crc_field(&mut self) -> &mut u32 {
        &mut self.crc
    }
    fn crc(&self) -> u32 {
        self.crc
    }
}

/// The IMU of the robot's torso (`IMUState_`).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct ImuState {
    /// Orientation, w x y z.
    pub quaternion: [f32; 4],
    /// Angular rate, rad/s.
    pub gyroscope: [f32; 3],
    /// Specific force, m/s².
    pub accelerometer: [f32; 3],
    /// Roll, pitch, yaw, rad.
    pub rpy: [f32; 3],
    /// °C.
    pub temperature: i16,
}

/// One motor's state.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct MotorState {
    /// The mode it runs in.
    pub mode: u8,
    /// Position, rad.
    pub q: f32,
    /// Velocity, rad/s.
    pub dq: f32,
    /// Acceleration, rad/s².
    pub ddq: f32,
    /// Estimated torque, N·m.
    pub tau_est: f32,
    /// Winding and case temperature, °C.
    pub temperature: [i16; 2],
    /// Supply voltage, V.
    pub vol: f32,
    /// Sensor words.
    pub sensor: [u32; 2],
    /// Error and status bits.
    pub motorstate: u32,
    /// Reserved.
    pub reserve: [u32; 4],
}

/// `rt/lowstate`: the IMU, every motor's state, the remote's bytes, and the CRC.
#[derive(Debug, Clone, PartialEq)]
pub struct LowState {
    /// Firmware version words.
    pub version: [u32; 2],
    /// Parallel-mechanism control mode (see [`LowCmd::mode_pr`]).
    pub mode_pr: u8,
    /// The robot variant.
    pub mode_machine: u8,
    /// Milliseconds counter of the board.
    pub tick: u32,
    /// The torso's IMU.
    pub imu_state: ImuState,
    /// States by motor index.
    pub motor_state: [MotorState; MOTORS],
    /// The wireless remote's raw bytes.
    pub wireless_remote: [u8; 40],
    /// Reserved.
    pub reserve: [u32; 4],
    /// The CRC.
    pub crc: u32,
}

impl Default for LowState {
    fn default() -> Self {
        Self {
            version: [0; 2],
            mode_pr: 0,
            mode_machine: 0,
            tick: 0,
            imu_state: ImuState::default(),
            motor_state: [MotorState::default(); MOTORS],
            wireless_remote: [0; 40],
            reserve: [0; 4],
            crc: 0,
        }
    }
}

impl LowState {
    /// Bytes of the packed (C) layout.
    pub const PACKED_LEN: usize = 2092;
    /// Bytes of its CDR, the encapsulation header included.
    pub const CDR_LEN: usize = 2092;

    /// Every field in IDL order into `sink`.
    fn fields(&self, sink: &mut impl FieldSink) {
        for v in self.version {
            sink.u32(v);
        }
        sink.u8(self.mode_pr);
        sink.u8(self.mode_machine);
        sink.pad(2);
        sink.u32(self.tick);
        let imu = &self.imu_state;
        for v in imu
            .quaternion
            .iter()
            .chain(&imu.gyroscope)
            .chain(&imu.accelerometer)
            .chain(&imu.rpy)
        {
            sink.f32(*v);
        }
        sink.i16(imu.temperature);
        sink.pad(2);
        for m in &self.motor_state {
            sink.u8(m.mode);
            sink.pad(3);
            for v in [m.q, m.dq, m.ddq, m.tau_est] {
                sink.f32(v);
            }
            sink.i16(m.temperature[0]);
            sink.i16(m.temperature[1]);
            sink.f32(m.vol);
            for v in m.sensor.iter().chain([m.motorstate].iter()).chain(&m.reserve) {
                sink.u32(*v);
            }
        }
        sink.octets(&self.wireless_remote);
        for r in self.reserve {
            sink.u32(r);
        }
        sink.u32(self.crc);
    }

    /// The message in the SDK's C layout, as the CRC reads it.
    pub fn pack(&self, out: &mut [u8; Self::PACKED_LEN]) {
        let mut p = Packer { out, at: 0 };
        self.fields(&mut p);
        debug_assert_eq!(p.at, Self::PACKED_LEN);
    }

    /// The message as DDS carries it (CDR, into `buf`).
    pub fn write_cdr(&self, buf: &mut Vec<u8>) {
        self.fields(&mut CdrWriter::new(buf));
    }

    /// The message from its CDR.
    pub fn read_cdr(sample: &[u8]) -> Result<Self, CdrError> {
        let mut r = CdrReader::new(sample)?;
        let mut out = Self::default();
        for v in &mut out.version {
            *v = r.u32()?;
        }
        out.mode_pr = r.u8()?;
        out.mode_machine = r.u8()?;
        out.tick = r.u32()?;
        let imu = &mut out.imu_state;
        for v in imu
            .quaternion
            .iter_mut()
            .chain(&mut imu.gyroscope)
            .chain(&mut imu.accelerometer)
            .chain(&mut imu.rpy)
        {
            *v = r.f32()?;
        }
        imu.temperature = r.i16()?;
        for m in &mut out.motor_state {
            m.mode = r.u8()?;
            m.q = r.f32()?;
            m.dq = r.f32()?;
            m.ddq = r.f32()?;
            m.tau_est = r.f32()?;
            m.temperature = [r.i16()?, r.i16()?];
            m.vol = r.f32()?;
            m.sensor = [r.u32()?, r.u32()?];
            m.motorstate = r.u32()?;
            for v in &mut m.reserve {
                *v = r.u32()?;
            }
        }
        r.octets(&mut out.wireless_remote)?;
        for v in &mut out.reserve {
            *v = r.u32()?;
        }
        out.crc = r.u32()?;
        Ok(out)
    }
}

impl Sealed for LowState {
    fn packed(&self, out: &mut [u8; LowState::PACKED_LEN]) -> usize {
        self.pack(out);
        Self::PACKED_LEN
    }
    fn crc_field(&mut self) -> &mut u32 {
        &mut self.crc
    }
    fn crc(&self) -> u32 {
        self.crc
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_sealed_message_checks_and_any_changed_field_breaks_its_crc() {
        let mut cmd = LowCmd::default();
        cmd.motor_cmd[4].q = 0.25;
        cmd.motor_cmd[4].kp = 60.0;
        cmd.seal();
        assert!(cmd.crc_ok());
        cmd.motor_cmd[34].kd = 1.0;
        assert!(!cmd.crc_ok(), "the last motor slot is covered");
        let mut state = LowState::default();
        state.imu_state.quaternion = [1.0, 0.0, 0.0, 0.0];
        state.seal();
        assert!(state.crc_ok());
        state.reserve[3] = 1;
        assert!(!state.crc_ok(), "the last word before the CRC is covered");
    }

    #[test]
    fn cdr_round_trips_at_the_sizes_of_the_sdk_and_short_samples_are_refused() {
        let mut cmd = LowCmd {
            mode_machine: 5,
            ..LowCmd::default()
        };
        cmd.motor_cmd[34].kd = 2.5;
        cmd.seal();
        let mut buf = Vec::new();
        cmd.write_cdr(&mut buf);
        // The SDK's serializer writes 1004 and 2092 bytes (header included).
        assert_eq!(buf.len(), LowCmd::CDR_LEN);
        assert_eq!(LowCmd::read_cdr(&buf), Ok(cmd));
        assert!(LowCmd::read_cdr(&buf[..1000]).is_err());
        let mut state = LowState::default();
        state.imu_state.temperature = -3;
        state.motor_state[0].temperature = [40, 41];
        state.wireless_remote[39] = 9;
        state.seal();
        state.write_cdr(&mut buf);
        assert_eq!(buf.len(), LowState::CDR_LEN);
        assert_eq!(LowState::read_cdr(&buf), Ok(state));
    }
}
