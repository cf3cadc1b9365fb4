//! Bosch BNO055 over its UART: a register-access protocol the host drives.
//!
//! Write: `AA 00 REG LEN DATA…`, answered `EE 01` (write success) or `EE STATUS`. Read:
//! `AA 01 REG LEN`, answered `BB LEN DATA…` or `EE STATUS`. Statuses: 01 write success, 02 read
//! fail, 03 write fail, 04 invalid address, 05 write disabled, 06 wrong start byte, 07 bus
//! over-run, 08 maximum length, 09 minimum length, 0A character timeout. At most 128 bytes a
//! transfer. Registers used here (page 0): CHIP_ID 0x00 (0xA0), ACC_DATA 0x08 (x, y, z: `i16`,
//! 1 m/s² = 100 LSB), MAG_DATA 0x0E, GYR_DATA 0x14 (1 °/s = 16 LSB), EUL_DATA 0x1A (heading, roll,
//! pitch: 1° = 16 LSB), QUA_DATA 0x20 (w, x, y, z: 1 = 2¹⁴ LSB), TEMP 0x34, SYS_STATUS 0x39,
//! OPR_MODE 0x3D (CONFIG 0x00, IMU 0x08: accelerometer and gyroscope fused, no magnetometer;
//! NDOF 0x0C), SYS_TRIGGER 0x3F (0x20 restarts the chip: 650 ms deaf), PAGE_ID 0x07 (page 1
//! holds the sensors' configuration: ACC_Config 0x08, MAG_Config 0x09, GYR_Config 0x0A/0x0B).
//! Configuration registers are writable in CONFIG mode only; the data registers read zero there.
//! A mode change takes 7 ms (from CONFIG) or 19 ms (to CONFIG), during which the old mode holds.
//! Fusion runs at 100 Hz.

use std::time::Duration;

use super::wit::{DecoderStats, ImuSample};
use crate::time::SimInstant;

/// Request start byte.
pub const START: u8 = 0xAA;
/// Read response start byte.
pub const READ_RESPONSE: u8 = 0xBB;
/// Status response start byte.
pub const STATUS_RESPONSE: u8 = 0xEE;
/// Write and read operation bytes.
pub const WRITE: u8 = 0x00;
/// Read operation byte.
pub const READ: u8 = 0x01;
/// Longest transfer, bytes.
pub const MAX_LEN: usize = 128;
/// The chip's line speed, baud.
pub const BAUD: u32 = 115_200;
/// The fusion output rate, Hz.
pub const RATE_HZ: f64 = 100.0;

/// Response statuses.
pub mod status {
    /// Write success.
    pub const WRITE_SUCCESS: u8 = 0x01;
    /// Read failed.
    pub const READ_FAIL: u8 = 0x02;
    /// Write failed (a register not writable in this mode).
    pub const WRITE_FAIL: u8 = 0x03;
    /// Address outside the register map.
    pub const INVALID_ADDRESS: u8 = 0x04;
    /// Register not writable.
    pub const WRITE_DISABLED: u8 = 0x05;
    /// A request that does not start with 0xAA.
    pub const WRONG_START_BYTE: u8 = 0x06;
    /// Length above 128.
    pub const MAX_LENGTH: u8 = 0x08;
    /// Length 0.
    pub const MIN_LENGTH: u8 = 0x09;
}

/// Registers.
pub mod reg {
    /// Chip ID (reads 0xA0).
    pub const CHIP_ID: u8 = 0x00;
    /// Acceleration x LSB: the 32-byte data block starts here.
    pub const ACC_DATA: u8 = 0x08;
    /// Angular velocity x LSB.
    pub const GYR_DATA: u8 = 0x14;
    /// Euler angles (heading) LSB.
    pub const EUL_DATA: u8 = 0x1A;
    /// Quaternion w LSB.
    pub const QUA_DATA: u8 = 0x20;
    /// Temperature.
    pub const TEMP: u8 = 0x34;
    /// System status (5: fusion running).
    pub const SYS_STATUS: u8 = 0x39;
    /// Unit selection.
    pub const UNIT_SEL: u8 = 0x3B;
    /// Operation mode.
    pub const OPR_MODE: u8 = 0x3D;
    /// Power mode.
    pub const PWR_MODE: u8 = 0x3E;
    /// System trigger.
    pub const SYS_TRIGGER: u8 = 0x3F;
    /// Page select.
    pub const PAGE_ID: u8 = 0x07;
}

/// Operation modes.
pub mod mode {
    /// Configuration: no data.
    pub const CONFIG: u8 = 0x00;
    /// Accelerometer and gyroscope fused (relative heading).
    pub const IMU: u8 = 0x08;
    /// Nine degrees of freedom.
    pub const NDOF: u8 = 0x0C;
}

/// Bytes of the data block the host reads each cycle: ACC_DATA 0x08 through QUA_DATA's end 0x27.
pub const DATA_BLOCK: usize = 0x28 - 0x08;

/// The read request for the data block.
pub const READ_DATA_BLOCK: [u8; 4] = [START, READ, reg::ACC_DATA, DATA_BLOCK as u8];

/// The write request that starts fusion without the magnetometer.
pub const START_IMU_MODE: [u8; 5] = [START, WRITE, reg::OPR_MODE, 1, mode::IMU];

/// One step of each output.
pub const ACCEL_LSB: f64 = 1.0 / 100.0;
/// Angular velocity per LSB, rad/s.
pub const GYRO_LSB: f64 = std::f64::consts::PI / 180.0 / 16.0;
/// Quaternion component per LSB.
pub const QUAT_LSB: f64 = 1.0 / 16384.0;
/// Euler angle per LSB, rad.
pub const EULER_LSB: f64 = std::f64::consts::PI / 180.0 / 16.0;

fn put(regs: &mut [u8], at: u8, v: f64, lsb: f64) {
    let raw = (v / lsb).round().clamp(-32768.0, 32767.0) as i16;
    regs[usize::from(at)..usize::from(at) + 2].copy_from_slice(&raw.to_le_bytes());
}

fn get(block: &[u8], at: usize) -> f64 {
    f64::from(i16::from_le_bytes([block[at], block[at + 1]]))
}

/// The sample in a data block read from ACC_DATA (32 bytes), or `None` when its quaternion is not
/// one (a chip in CONFIG mode reads all zeros: it restarted, or was never set).
pub fn decode_block(block: &[u8; DATA_BLOCK]) -> Option<ImuSample> {
    let o = |r: u8| usize::from(r - reg::ACC_DATA);
    let accel = [0, 2, 4].map(|k| get(block, o(reg::ACC_DATA) + k) * ACCEL_LSB);
    let gyro = [0, 2, 4].map(|k| get(block, o(reg::GYR_DATA) + k) * GYRO_LSB);
    let quat = [0, 2, 4, 6].map(|k| get(block, o(reg::QUA_DATA) + k) * QUAT_LSB);
    let euler = [0, 2, 4].map(|k| get(block, o(reg::EUL_DATA) + k) * EULER_LSB);
    // The chip's unit quaternion is within a few LSB of norm 1; anything else is not an attitude.
    let norm = quat.iter().map(|q| q * q).sum::<f64>().sqrt();
    if (norm - 1.0).abs() > 0.01 {
        return None;
    }
    Some(ImuSample {
        accel,
        gyro,
        quat: quat.map(|q| q / norm),
        // Heading, roll, pitch on the chip; roll, pitch, yaw here.
        rpy: [euler[1], euler[2], euler[0]],
        temperature: f64::NAN,
    })
}

/// Page 1 registers writable in CONFIG mode: the sensors' configuration, interrupt settings.
const PAGE1_CONFIG: std::ops::RangeInclusive<u8> = 0x08..=0x1F;
/// Page 0 registers writable in CONFIG mode: units, axis remap, offsets and radii.
const PAGE0_CONFIG: [std::ops::RangeInclusive<u8>; 2] = [reg::UNIT_SEL..=0x42, 0x55..=0x6A];
/// SYS_TRIGGER's bit that restarts the chip.
const RST_SYS: u8 = 0x20;
/// How long a restart keeps the chip deaf (power-on reset to normal mode, datasheet table 0-2:
/// 650 ms typical).
const RESET_TIME: Duration = Duration::from_millis(650);

/// An emulated BNO055 on its UART.
#[derive(Debug, Clone)]
pub struct Bno055 {
    /// Register pages 0 and 1 (PAGE_ID, 0x07, selects; it reads the same on both).
    pages: [[u8; 0x80]; 2],
    rx: Vec<u8>,
    /// A mode being entered, and when it is in force.
    switching: Option<(u8, SimInstant)>,
    /// Restarting until then: bytes arriving are lost, nothing answers.
    resetting_until: Option<SimInstant>,
    /// The sensors' newest measurement (fused as soon as a fusion mode is in force).
    measured: ImuSample,
}

impl Default for Bno055 {
    fn default() -> Self {
        Self::new()
    }
}

impl Bno055 {
    /// A chip after power-up: CONFIG mode, idle, page 0.
    pub fn new() -> Self {
        let mut pages = [[0u8; 0x80]; 2];
        let p0 = &mut pages[0];
        p0[usize::from(reg::CHIP_ID)] = 0xA0;
        p0[0x01] = 0xFB; // accelerometer ID
        p0[0x02] = 0x32; // magnetometer ID
        p0[0x03] = 0x0F; // gyroscope ID
        p0[0x41] = 0x24; // AXIS_MAP_CONFIG
        let p1 = &mut pages[1];
        p1[0x08] = 0x0D; // ACC_Config: ±4 g, 62.5 Hz, normal
        p1[0x09] = 0x6D; // MAG_Config
        p1[0x0A] = 0x38; // GYR_Config_0: ±2000 °/s, 32 Hz
        p1[0x0C] = 0x00; // ACC_Sleep_Config
        Self {
            pages,
            rx: Vec::with_capacity(2 * MAX_LEN),
            switching: None,
            resetting_until: None,
            measured: ImuSample::default(),
        }
    }

    fn page(&self) -> usize {
        usize::from(self.pages[0][usize::from(reg::PAGE_ID)] & 1)
    }

    /// The operation mode in force at `now`.
    pub fn mode(&mut self, now: SimInstant) -> u8 {
        if let Some((m, at)) = self.switching
            && now >= at
        {
            self.pages[0][usize::from(reg::OPR_MODE)] = m;
            self.pages[0][usize::from(reg::SYS_STATUS)] = if m == mode::CONFIG { 0 } else { 5 };
            self.switching = None;
            self.publish();
        }
        self.pages[0][usize::from(reg::OPR_MODE)]
    }

    /// A measurement at `now`: the data registers take it in a fusion mode.
    pub fn update(&mut self, now: SimInstant, sample: &ImuSample) {
        self.measured = *sample;
        self.mode(now);
        self.publish();
    }

    /// The newest measurement into the data registers (zero in CONFIG mode).
    fn publish(&mut self) {
        let sample = self.measured;
        let r = &mut self.pages[0];
        if r[usize::from(reg::OPR_MODE)] == mode::CONFIG {
            r[usize::from(reg::ACC_DATA)..=usize::from(reg::TEMP)].fill(0);
            return;
        }
        for k in 0..3u8 {
            put(r, reg::ACC_DATA + 2 * k, sample.accel[usize::from(k)], ACCEL_LSB);
            put(r, reg::GYR_DATA + 2 * k, sample.gyro[usize::from(k)], GYRO_LSB);
        }
        let [roll, pitch, yaw] = sample.rpy;
        for (k, v) in [yaw, roll, pitch].into_iter().enumerate() {
            put(r, reg::EUL_DATA + 2 * k as u8, v, EULER_LSB);
        }
        for (k, v) in sample.quat.into_iter().enumerate() {
            put(r, reg::QUA_DATA + 2 * k as u8, v, QUAT_LSB);
        }
        r[usize::from(reg::TEMP)] = 30;
    }

    /// Bytes from the host, arrived by `now`; complete requests are answered into `out`.
    pub fn receive(&mut self, now: SimInstant, bytes: &[u8], out: &mut Vec<u8>) {
        if let Some(until) = self.resetting_until {
            if now < until {
                return;
            }
            *self = Self::new();
        }
        self.rx.extend_from_slice(bytes);
        loop {
            let Some(&first) = self.rx.first() else { return };
            if first != START {
                self.rx.remove(0);
                out.extend_from_slice(&[STATUS_RESPONSE, status::WRONG_START_BYTE]);
                continue;
            }
            if self.rx.len() < 4 {
                return;
            }
            let (op, at, len) = (self.rx[1], self.rx[2], usize::from(self.rx[3]));
            let need = if op == WRITE { 4 + len } else { 4 };
            if self.rx.len() < need {
                return;
            }
            // A copy on the stack: the answer reads the request while it changes registers.
            let mut data = [0u8; 255];
            data[..need - 4].copy_from_slice(&self.rx[4..need]);
            self.rx.drain(..need);
            self.answer(now, op, at, &data[..need - 4], len, out);
            if self.resetting_until.is_some() {
                // What followed the restart request is lost with it.
                self.rx.clear();
                return;
            }
        }
    }

    fn answer(&mut self, now: SimInstant, op: u8, at: u8, data: &[u8], len: usize, out: &mut Vec<u8>) {
        let fail = |out: &mut Vec<u8>, s: u8| out.extend_from_slice(&[STATUS_RESPONSE, s]);
        if len == 0 {
            return fail(out, status::MIN_LENGTH);
        }
        if len > MAX_LEN {
            return fail(out, status::MAX_LENGTH);
        }
        let range = usize::from(at)..usize::from(at) + len;
        if range.end > 0x80 {
            return fail(out, status::INVALID_ADDRESS);
        }
        let in_config = self.mode(now) == mode::CONFIG;
        match op {
            READ => {
                out.extend_from_slice(&[READ_RESPONSE, len as u8]);
                let page = self.page();
                out.extend_from_slice(&self.pages[page][range]);
            }
            WRITE => {
                for (k, &v) in data.iter().enumerate() {
                    let r = at + k as u8;
                    let config = match self.page() {
                        0 => PAGE0_CONFIG.iter().any(|c| c.contains(&r)),
                        _ => PAGE1_CONFIG.contains(&r),
                    };
                    match r {
                        reg::PAGE_ID => {
                            self.pages[0][usize::from(r)] = v & 1;
                            self.pages[1][usize::from(r)] = v & 1;
                        }
                        reg::OPR_MODE if self.page() == 0 => {
                            // Into a fusion mode 7 ms, back to CONFIG 19 ms (datasheet table 3-6).
                            let took = if v & 0x0F == mode::CONFIG { 19 } else { 7 };
                            self.switching = Some((v & 0x0F, now + Duration::from_millis(took)));
                        }
                        reg::SYS_TRIGGER if self.page() == 0 && v & RST_SYS != 0 => {
                            // The chip restarts at once: no answer.
                            self.resetting_until = Some(now + RESET_TIME);
                            return;
                        }
                        reg::PWR_MODE | reg::SYS_TRIGGER if self.page() == 0 => {
                            self.pages[0][usize::from(r)] = v;
                        }
                        _ if config => {
                            if !in_config {
                                return fail(out, status::WRITE_FAIL);
                            }
                            let page = self.page();
                            self.pages[page][usize::from(r)] = v;
                        }
                        _ => return fail(out, status::WRITE_DISABLED),
                    }
                }
                fail(out, status::WRITE_SUCCESS);
            }
            _ => fail(out, status::WRONG_START_BYTE),
        }
    }
}

/// A BNO055 alone on a serial line in its own simulated time, holding still at a fixed attitude:
/// a bench for serving the emulated chip to programs that open a serial device.
#[derive(Debug)]
pub struct Bno055Bench {
    chip: Bno055,
    line: crate::serial::StreamLine,
    sample: ImuSample,
    now: SimInstant,
    next_output: SimInstant,
    reply: Vec<u8>,
}

impl Bno055Bench {
    /// The chip reporting `sample` at every fusion output.
    pub fn new(sample: ImuSample) -> Self {
        Self {
            chip: Bno055::new(),
            line: crate::serial::StreamLine::new(BAUD),
            sample,
            now: SimInstant::ZERO,
            next_output: SimInstant::ZERO,
            reply: Vec::with_capacity(2 * MAX_LEN),
        }
    }
}

impl crate::time::SimWorld for Bno055Bench {
    fn now(&self) -> SimInstant {
        self.now
    }

    fn step_until(&mut self, limit: SimInstant) -> SimInstant {
        let next = self.line.next_event(self.now).map_or(limit, |t| t.min(limit));
        self.now = self.now.max(next.min(self.next_output));
        if self.now >= self.next_output {
            self.chip.update(self.now, &self.sample);
            self.next_output = self.next_output + Duration::from_millis(10); // 100 Hz
        }
        self.now
    }
}

impl crate::serial::SerialSimWorld for Bno055Bench {
    fn host_transmit(&mut self, _line: usize, bytes: &[u8]) {
        let arrived = self.now + self.line.wire_time(bytes.len());
        self.reply.clear();
        self.chip.receive(arrived, bytes, &mut self.reply);
        self.line.device_transmit(arrived, &self.reply);
    }

    fn host_receive(&mut self, _line: usize, out: &mut Vec<u8>) {
        self.line.host_receive(self.now, out);
    }
}

/// What the host's side of the protocol is doing.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum HostState {
    /// The mode write is to go out.
    Configure,
    /// Waiting for the mode write's acknowledgement, sent at this time (ns of the stream clock).
    AwaitAck,
    /// Running: a data read is out, or may go out.
    Reading,
}

/// The host's side: starts fusion (IMU mode), then reads the data block at the output rate.
#[derive(Debug)]
pub struct Bno055Host {
    state: HostState,
    /// Response bytes collected.
    rx: Vec<u8>,
    /// A read is out and unanswered since (stream time, s).
    outstanding: Option<f64>,
    last_request: f64,
    /// No read before the mode asked for is in force (7 ms after the write, and a margin).
    first_read_at: f64,
    period: f64,
    stats: DecoderStats,
    /// Requests that got no answer in time.
    timeouts: u64,
}

/// How long the host leaves the chip to enter fusion mode (7 ms) before reading, s.
const MODE_SWITCH_WAIT: f64 = 0.008;

/// How long the host waits for an answer before asking again, s.
const ANSWER_TIMEOUT: f64 = 0.05;

impl Bno055Host {
    /// Reading at `rate_hz` (at most the chip's 100 Hz).
    pub fn new(rate_hz: f64) -> Self {
        Self {
            state: HostState::Configure,
            rx: Vec::with_capacity(2 * MAX_LEN),
            outstanding: None,
            last_request: f64::NEG_INFINITY,
            first_read_at: 0.0,
            period: 1.0 / rate_hz.clamp(1.0, RATE_HZ),
            stats: DecoderStats::default(),
            timeouts: 0,
        }
    }

    /// Responses taken (`packets`), error statuses (`checksum_errors`: the part's own report of a
    /// failed transfer), bytes skipped, samples.
    pub fn stats(&self) -> DecoderStats {
        self.stats
    }

    /// Requests that got no answer within 50 ms.
    pub fn timeouts(&self) -> u64 {
        self.timeouts
    }

    /// What to send now (`now` in seconds of the stream's clock), if anything.
    pub fn request(&mut self, now: f64) -> Option<&'static [u8]> {
        if let Some(since) = self.outstanding {
            if now - since < ANSWER_TIMEOUT {
                return None;
            }
            self.timeouts += 1;
            self.outstanding = None;
            self.rx.clear();
            if self.state == HostState::AwaitAck {
                self.state = HostState::Configure;
            }
        }
        match self.state {
            HostState::Configure => {
                self.state = HostState::AwaitAck;
                self.outstanding = Some(now);
                self.first_read_at = now + MODE_SWITCH_WAIT;
                Some(&START_IMU_MODE)
            }
            HostState::AwaitAck => None,
            HostState::Reading if now >= self.first_read_at && now - self.last_request >= self.period => {
                self.last_request = now;
                self.outstanding = Some(now);
                Some(&READ_DATA_BLOCK)
            }
            HostState::Reading => None,
        }
    }

    /// Takes bytes from the chip; a complete data block becomes a sample.
    pub fn feed(&mut self, bytes: &[u8], mut on_sample: impl FnMut(&ImuSample)) {
        self.rx.extend_from_slice(bytes);
        loop {
            match self.rx.first() {
                None => return,
                Some(&STATUS_RESPONSE) if self.rx.len() >= 2 => {
                    let s = self.rx[1];
                    self.rx.drain(..2);
                    self.outstanding = None;
                    self.stats.packets += 1;
                    match (self.state, s) {
                        (HostState::AwaitAck, status::WRITE_SUCCESS) => self.state = HostState::Reading,
                        (HostState::AwaitAck, _) => {
                            self.stats.checksum_errors += 1;
                            self.state = HostState::Configure;
                        }
                        _ => self.stats.checksum_errors += 1,
                    }
                }
                Some(&READ_RESPONSE) if self.rx.len() >= 2 => {
                    let len = usize::from(self.rx[1]);
                    if self.rx.len() < 2 + len {
                        return;
                    }
                    self.stats.packets += 1;
                    if len == DATA_BLOCK {
                        let mut block = [0u8; DATA_BLOCK];
                        block.copy_from_slice(&self.rx[2..2 + len]);
                        match decode_block(&block) {
                            Some(sample) => {
                                self.stats.samples += 1;
                                on_sample(&sample);
                            }
                            None if self.state == HostState::Reading => {
                                // No attitude: the chip is out of fusion (it restarted). Set
                                // the mode again.
                                self.stats.checksum_errors += 1;
                                self.state = HostState::Configure;
                            }
                            None => self.stats.checksum_errors += 1,
                        }
                    } else {
                        self.stats.unknown_types += 1;
                    }
                    self.rx.drain(..2 + len);
                    self.outstanding = None;
                }
                Some(&STATUS_RESPONSE | &READ_RESPONSE) => return,
                Some(_) => {
                    // Junk before a response.
                    self.rx.remove(0);
                    self.stats.junk_bytes += 1;
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn at(ms: u64) -> SimInstant {
        SimInstant::from_nanos(ms * 1_000_000)
    }

    #[test]
    fn the_register_protocol_answers_as_the_datasheet_says() {
        let mut chip = Bno055::new();
        let mut out = Vec::new();
        // Read CHIP_ID: BB 01 A0.
        chip.receive(at(0), &[0xAA, 0x01, 0x00, 0x01], &mut out);
        assert_eq!(out, [0xBB, 0x01, 0xA0]);
        out.clear();
        // Data registers are zero in CONFIG mode; a write to one is refused.
        chip.receive(at(0), &[0xAA, 0x00, 0x08, 0x01, 0x05], &mut out);
        assert_eq!(out, [0xEE, status::WRITE_DISABLED]);
        out.clear();
        // Wrong start byte, zero length, beyond the map.
        chip.receive(
            at(0),
            &[0x55, 0xAA, 0x01, 0x08, 0x00, 0xAA, 0x01, 0x7F, 0x02],
            &mut out,
        );
        assert_eq!(out, [0xEE, 0x06, 0xEE, 0x09, 0xEE, 0x04]);
        out.clear();
        // Into IMU mode: acknowledged at once, in force 7 ms later.
        chip.receive(at(0), &START_IMU_MODE, &mut out);
        assert_eq!(out, [0xEE, 0x01]);
        assert_eq!(chip.mode(at(6)), mode::CONFIG);
        assert_eq!(chip.mode(at(7)), mode::IMU);
        let sample = ImuSample {
            accel: [0.1, -0.2, 9.81],
            gyro: [0.5, 0.0, -0.25],
            quat: [0.9238795, 0.0, 0.0, 0.3826834],
            rpy: [0.0, 0.0, std::f64::consts::FRAC_PI_4],
            temperature: 30.0,
        };
        chip.update(at(10), &sample);
        out.clear();
        chip.receive(at(10), &READ_DATA_BLOCK, &mut out);
        assert_eq!(out.len(), 2 + DATA_BLOCK);
        // 9.81 m/s² is 981 LSB; 0.5 rad/s is 458 LSB (28.65 °/s × 16).
        assert_eq!(i16::from_le_bytes([out[6], out[7]]), 981);
        assert_eq!(i16::from_le_bytes([out[2 + 12], out[2 + 13]]), 458);
        let mut block = [0u8; DATA_BLOCK];
        block.copy_from_slice(&out[2..]);
        let back = decode_block(&block).unwrap();
        assert!((back.accel[2] - 9.81).abs() < ACCEL_LSB);
        assert!((back.gyro[0] - 0.5).abs() < GYRO_LSB);
        assert!((back.quat[3] - 0.3826834).abs() < QUAT_LSB);
        // Configuration registers are writable only in CONFIG mode.
        out.clear();
        chip.receive(at(11), &[0xAA, 0x00, reg::UNIT_SEL, 0x01, 0x02], &mut out);
        assert_eq!(out, [0xEE, status::WRITE_FAIL]);
    }

    #[test]
    fn page_one_holds_the_sensor_configuration_and_a_restart_goes_deaf_then_back_to_defaults() {
        let mut chip = Bno055::new();
        let mut out = Vec::new();
        // Page 1's ACC_Config (0x0D by default), written in CONFIG mode and read back.
        chip.receive(at(0), &[0xAA, 0x00, reg::PAGE_ID, 0x01, 0x01], &mut out);
        chip.receive(at(0), &[0xAA, 0x01, 0x08, 0x01], &mut out);
        chip.receive(at(0), &[0xAA, 0x00, 0x08, 0x01, 0x0E], &mut out);
        chip.receive(at(0), &[0xAA, 0x01, 0x08, 0x01], &mut out);
        assert_eq!(out, [0xEE, 0x01, 0xBB, 0x01, 0x0D, 0xEE, 0x01, 0xBB, 0x01, 0x0E]);
        out.clear();
        // Back to page 0, restart: no answer, deaf for 650 ms, then as after power-up.
        chip.receive(at(1), &[0xAA, 0x00, reg::PAGE_ID, 0x01, 0x00], &mut out);
        chip.receive(at(1), &[0xAA, 0x00, reg::SYS_TRIGGER, 0x01, 0x20], &mut out);
        assert_eq!(out, [0xEE, 0x01]);
        out.clear();
        chip.receive(at(600), &[0xAA, 0x01, 0x00, 0x01], &mut out);
        assert!(out.is_empty());
        chip.receive(at(652), &[0xAA, 0x00, reg::PAGE_ID, 0x01, 0x01], &mut out);
        chip.receive(at(652), &[0xAA, 0x01, 0x08, 0x01], &mut out);
        assert_eq!(out, [0xEE, 0x01, 0xBB, 0x01, 0x0D]);
    }

    #[test]
    fn a_chip_that_restarts_under_the_host_is_set_to_fusion_again() {
        let mut chip = Bno055::new();
        let mut host = Bno055Host::new(100.0);
        let sample = ImuSample {
            accel: [0.0, 0.0, 9.81],
            quat: [1.0, 0.0, 0.0, 0.0],
            ..ImuSample::default()
        };
        let mut samples = 0;
        for ms in 0..2000u64 {
            if ms == 500 {
                // A brown-out: the chip comes back in CONFIG mode, its registers zero.
                chip = Bno055::new();
            }
            chip.update(at(ms), &sample);
            if let Some(req) = host.request(ms as f64 / 1e3) {
                let mut out = Vec::new();
                chip.receive(at(ms), req, &mut out);
                host.feed(&out, |s| {
                    samples += 1;
                    assert!((s.quat[0] - 1.0).abs() < 1e-9);
                });
            }
        }
        // One zero block, then the mode is set again and reading goes on.
        assert_eq!(host.stats().checksum_errors, 1);
        assert!(samples > 190, "{samples}");
    }

    #[test]
    fn the_host_starts_fusion_then_reads_at_its_rate() {
        let mut chip = Bno055::new();
        let mut host = Bno055Host::new(100.0);
        let sample = ImuSample {
            accel: [0.0, 0.0, 9.81],
            quat: [1.0, 0.0, 0.0, 0.0],
            ..ImuSample::default()
        };
        let mut samples = 0;
        for ms in 0..200u64 {
            chip.update(at(ms), &sample);
            if let Some(req) = host.request(ms as f64 / 1e3) {
                let mut out = Vec::new();
                chip.receive(at(ms), req, &mut out);
                host.feed(&out, |s| {
                    samples += 1;
                    assert!(ms < 10 || (s.accel[2] - 9.81).abs() < 0.01);
                });
            }
        }
        // One read per 10 ms once the mode is set.
        assert!((18..=20).contains(&samples), "{samples}");
        assert_eq!((host.stats().checksum_errors, host.timeouts()), (0, 0));
    }
}
