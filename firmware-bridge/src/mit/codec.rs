//! MIT-mode frame codec, shared by the host driver and the emulated firmware.
//!
//! Command (8 bytes, CAN ID = motor ID), big-endian bit fields:
//! `p[15:8] p[7:0] v[11:4] v[3:0]|kp[11:8] kp[7:0] kd[11:4] kd[3:0]|t[11:8] t[7:0]`.
//! Each field maps linearly: `u = trunc((clamp(x) − lo)·(2^bits − 1)/(hi − lo))`.
//!
//! The same impedance command travels in Robstride's factory protocol too (29-bit IDs, 16-bit
//! fields: [`super::robstride`]); the frame-level functions at the end of this file
//! ([`command_frame`], [`special_frame`], [`reply_frame`], [`decode_reply_frame`]) pick the
//! layout by the model's family, so the driver and the firmware are one for every family.

use super::models::{MotorFamily, MotorModel};
use crate::can::{CanFrame, CanId};

/// A command in the motor's own units (output shaft): position, velocity, gains, feed-forward torque.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct MitCommand {
    /// Position setpoint, rad.
    pub p: f64,
    /// Velocity setpoint, rad/s.
    pub v: f64,
    /// Stiffness, N·m/rad.
    pub kp: f64,
    /// Damping, N·m·s/rad.
    pub kd: f64,
    /// Feed-forward torque, N·m.
    pub t: f64,
}

/// The special frames every MIT-mode firmware understands (payload `FF×7` + code).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SpecialFrame {
    /// `…FC`: enter motor mode (torque on).
    Enable,
    /// `…FD`: leave motor mode (torque off).
    Disable,
    /// `…FE`: take the current position as zero.
    SetZero,
}

impl SpecialFrame {
    /// The eight payload bytes.
    pub const fn bytes(self) -> [u8; 8] {
        let code = match self {
            Self::Enable => 0xFC,
            Self::Disable => 0xFD,
            Self::SetZero => 0xFE,
        };
        [0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, code]
    }

    /// Recognises a special frame's payload.
    pub fn parse(data: &[u8]) -> Option<Self> {
        match data {
            [0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFC] => Some(Self::Enable),
            [0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFD] => Some(Self::Disable),
            [0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFE] => Some(Self::SetZero),
            _ => None,
        }
    }
}

/// A fault a motor reports, as its family encodes it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[non_exhaustive]
pub enum MotorFault {
    /// No fault.
    #[default]
    None,
    /// Winding over-temperature.
    OverTemperature,
    /// Over-current.
    OverCurrent,
    /// Supply over-voltage.
    OverVoltage,
    /// Supply under-voltage.
    UnderVoltage,
    /// Encoder fault.
    Encoder,
    /// Driver MOSFET over-temperature.
    MosOverTemperature,
    /// Stalled / locked rotor.
    Stall,
    /// The motor's own command-timeout fired (DaMiao "communication lost").
    CommunicationLost,
    /// Overload.
    Overload,
    /// The encoder was never calibrated (Robstride reports it).
    Uncalibrated,
    /// A code this driver does not know.
    Unknown(u8),
}

impl std::fmt::Display for MotorFault {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::None => f.write_str("none"),
            Self::OverTemperature => f.write_str("winding over-temperature"),
            Self::OverCurrent => f.write_str("over-current"),
            Self::OverVoltage => f.write_str("supply over-voltage"),
            Self::UnderVoltage => f.write_str("supply under-voltage"),
            Self::Encoder => f.write_str("encoder fault"),
            Self::MosOverTemperature => f.write_str("driver over-temperature"),
            Self::Stall => f.write_str("stall"),
            Self::CommunicationLost => f.write_str("command timeout (communication lost)"),
            Self::Overload => f.write_str("overload"),
            Self::Uncalibrated => f.write_str("encoder not calibrated"),
            Self::Unknown(code) => write!(f, "fault code {code} (unknown to this driver)"),
        }
    }
}

impl MotorFault {
    /// CubeMars error byte (0 none … 7 stall).
    pub const fn from_cubemars(code: u8) -> Self {
        match code {
            0 => Self::None,
            1 => Self::OverTemperature,
            2 => Self::OverCurrent,
            3 => Self::OverVoltage,
            4 => Self::UnderVoltage,
            5 => Self::Encoder,
            6 => Self::MosOverTemperature,
            7 => Self::Stall,
            c => Self::Unknown(c),
        }
    }

    /// The CubeMars error byte for this fault.
    pub const fn to_cubemars(self) -> u8 {
        match self {
            Self::None | Self::CommunicationLost => 0,
            Self::OverTemperature => 1,
            Self::OverCurrent | Self::Overload => 2,
            Self::OverVoltage => 3,
            Self::UnderVoltage => 4,
            Self::Encoder | Self::Uncalibrated => 5,
            Self::MosOverTemperature => 6,
            Self::Stall => 7,
            Self::Unknown(c) => c,
        }
    }

    /// DaMiao state nibble: 0 disabled, 1 enabled, 8.. faults. Returns (fault, enabled).
    pub const fn from_damiao(nibble: u8) -> (Self, Option<bool>) {
        match nibble {
            0 => (Self::None, Some(false)),
            1 => (Self::None, Some(true)),
            8 => (Self::OverVoltage, None),
            9 => (Self::UnderVoltage, None),
            0xA => (Self::OverCurrent, None),
            0xB => (Self::MosOverTemperature, None),
            0xC => (Self::OverTemperature, None),
            0xD => (Self::CommunicationLost, None),
            0xE => (Self::Overload, None),
            c => (Self::Unknown(c), None),
        }
    }

    /// The DaMiao state nibble for this fault and enable state.
    pub const fn to_damiao(self, enabled: bool) -> u8 {
        match self {
            Self::None => enabled as u8,
            Self::OverVoltage => 8,
            Self::UnderVoltage => 9,
            Self::OverCurrent | Self::Stall => 0xA,
            Self::MosOverTemperature => 0xB,
            Self::OverTemperature | Self::Encoder | Self::Uncalibrated => 0xC,
            Self::CommunicationLost => 0xD,
            Self::Overload => 0xE,
            Self::Unknown(c) => c & 0x0F,
        }
    }
}

/// A decoded reply.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct MitReply {
    /// The motor ID the reply names.
    pub motor_id: u8,
    /// Position, rad.
    pub p: f64,
    /// Velocity, rad/s.
    pub v: f64,
    /// Torque (from the current), N·m.
    pub t: f64,
    /// Winding or rotor temperature, °C, where the family reports it.
    pub temperature: Option<f64>,
    /// Driver (MOSFET) temperature, °C, where the family reports it.
    pub mos_temperature: Option<f64>,
    /// Reported fault.
    pub fault: MotorFault,
    /// Torque on/off, where the family reports it.
    pub enabled: Option<bool>,
}

/// A frame that does not decode.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum CodecError {
    /// Wrong number of data bytes.
    #[error("expected {expected} data bytes, got {actual}")]
    WrongLength {
        /// What the format needs.
        expected: usize,
        /// What arrived.
        actual: usize,
    },
    /// A command field is NaN or infinite: it is never packed.
    #[error("command field {field} is not finite")]
    NotFinite {
        /// `p`, `v`, `kp`, `kd` or `t`.
        field: &'static str,
    },
}

/// `x` clamped to `[lo, hi]` and quantised to `bits` bits.
pub fn float_to_uint(x: f64, lo: f64, hi: f64, bits: u32) -> u16 {
    let span = hi - lo;
    let max = f64::from((1u32 << bits) - 1);
    let x = x.clamp(lo, hi);
    ((x - lo) * max / span) as u16
}

/// The inverse of [`float_to_uint`]: the value a quantised field stands for.
pub fn uint_to_float(u: u16, lo: f64, hi: f64, bits: u32) -> f64 {
    let max = f64::from((1u32 << bits) - 1);
    f64::from(u) * (hi - lo) / max + lo
}

/// True when packing `cmd` for `model` had to clamp a field.
pub fn needs_clamp(model: &MotorModel, cmd: &MitCommand) -> bool {
    cmd.p.abs() > model.p_max
        || cmd.v.abs() > model.v_max
        || !(0.0..=model.kp_max).contains(&cmd.kp)
        || !(0.0..=model.kd_max).contains(&cmd.kd)
        || cmd.t.abs() > model.t_max
}

/// Refuses a command with a NaN or infinite field, naming it: such a command is never packed.
pub fn check_finite(cmd: &MitCommand) -> Result<(), CodecError> {
    let fields = [
        ("p", cmd.p),
        ("v", cmd.v),
        ("kp", cmd.kp),
        ("kd", cmd.kd),
        ("t", cmd.t),
    ];
    match fields.into_iter().find(|(_, v)| !v.is_finite()) {
        Some((field, _)) => Err(CodecError::NotFinite { field }),
        None => Ok(()),
    }
}

/// Packs a command, clamping every field to the model's range. Refuses NaN and infinities.
pub fn pack_command(model: &MotorModel, cmd: &MitCommand) -> Result<[u8; 8], CodecError> {
    check_finite(cmd)?;
    let p = float_to_uint(cmd.p, -model.p_max, model.p_max, 16);
    let v = float_to_uint(cmd.v, -model.v_max, model.v_max, 12);
    let kp = float_to_uint(cmd.kp, 0.0, model.kp_max, 12);
    let kd = float_to_uint(cmd.kd, 0.0, model.kd_max, 12);
    let t = float_to_uint(cmd.t, -model.t_max, model.t_max, 12);
    Ok([
        (p >> 8) as u8,
        p as u8,
        (v >> 4) as u8,
        (((v & 0xF) << 4) | (kp >> 8)) as u8,
        kp as u8,
        (kd >> 4) as u8,
        (((kd & 0xF) << 4) | (t >> 8)) as u8,
        t as u8,
    ])
}

/// Unpacks a command (the firmware's side).
pub fn unpack_command(model: &MotorModel, data: &[u8]) -> Result<MitCommand, CodecError> {
    let d: &[u8; 8] = data.try_into().map_err(|_| CodecError::WrongLength {
        expected: 8,
        actual: data.len(),
    })?;
    let p = u16::from_be_bytes([d[0], d[1]]);
    let v = (u16::from(d[2]) << 4) | (u16::from(d[3]) >> 4);
    let kp = (u16::from(d[3] & 0xF) << 8) | u16::from(d[4]);
    let kd = (u16::from(d[5]) << 4) | (u16::from(d[6]) >> 4);
    let t = (u16::from(d[6] & 0xF) << 8) | u16::from(d[7]);
    Ok(MitCommand {
        p: uint_to_float(p, -model.p_max, model.p_max, 16),
        v: uint_to_float(v, -model.v_max, model.v_max, 12),
        kp: uint_to_float(kp, 0.0, model.kp_max, 12),
        kd: uint_to_float(kd, 0.0, model.kd_max, 12),
        t: uint_to_float(t, -model.t_max, model.t_max, 12),
    })
}

/// Data length of a reply in `family`'s format.
pub const fn reply_len(family: MotorFamily) -> usize {
    match family {
        MotorFamily::MiniCheetah => 6,
        MotorFamily::Cubemars | MotorFamily::Damiao | MotorFamily::Robstride => 8,
    }
}

fn temperature_byte(celsius: Option<f64>) -> u8 {
    celsius.map_or(0, |c| c.round().clamp(0.0, 255.0) as u8)
}

/// Packs an MIT-mode reply payload (the firmware's side). Returns the buffer and its length.
pub fn pack_reply(model: &MotorModel, r: &MitReply) -> ([u8; 8], usize) {
    let p = float_to_uint(r.p, -model.p_max, model.p_max, 16);
    let v = float_to_uint(r.v, -model.v_max, model.v_max, 12);
    let t = float_to_uint(r.t, -model.t_max, model.t_max, 12);
    let mut out = [
        (r.motor_id),
        (p >> 8) as u8,
        p as u8,
        (v >> 4) as u8,
        (((v & 0xF) << 4) | (t >> 8)) as u8,
        t as u8,
        0,
        0,
    ];
    match model.family {
        // Robstride's state frame is another layout: see `reply_frame`.
        MotorFamily::MiniCheetah | MotorFamily::Robstride => {}
        MotorFamily::Cubemars => {
            out[6] = temperature_byte(r.temperature);
            out[7] = r.fault.to_cubemars();
        }
        MotorFamily::Damiao => {
            out[0] = (r.fault.to_damiao(r.enabled.unwrap_or(false)) << 4) | (r.motor_id & 0x0F);
            out[6] = temperature_byte(r.mos_temperature);
            out[7] = temperature_byte(r.temperature);
        }
    }
    (out, reply_len(model.family))
}

/// Decodes an MIT-mode reply payload (the host's side).
pub fn unpack_reply(model: &MotorModel, data: &[u8]) -> Result<MitReply, CodecError> {
    let expected = reply_len(model.family);
    if data.len() != expected {
        return Err(CodecError::WrongLength {
            expected,
            actual: data.len(),
        });
    }
    let p = u16::from_be_bytes([data[1], data[2]]);
    let v = (u16::from(data[3]) << 4) | (u16::from(data[4]) >> 4);
    let t = (u16::from(data[4] & 0xF) << 8) | u16::from(data[5]);
    let mut r = MitReply {
        motor_id: data[0],
        p: uint_to_float(p, -model.p_max, model.p_max, 16),
        v: uint_to_float(v, -model.v_max, model.v_max, 12),
        t: uint_to_float(t, -model.t_max, model.t_max, 12),
        ..MitReply::default()
    };
    match model.family {
        MotorFamily::MiniCheetah | MotorFamily::Robstride => {}
        MotorFamily::Cubemars => {
            r.temperature = Some(f64::from(data[6]));
            r.fault = MotorFault::from_cubemars(data[7]);
        }
        MotorFamily::Damiao => {
            r.motor_id = data[0] & 0x0F;
            (r.fault, r.enabled) = MotorFault::from_damiao(data[0] >> 4);
            r.mos_temperature = Some(f64::from(data[6]));
            r.temperature = Some(f64::from(data[7]));
        }
    }
    Ok(r)
}

/// The command frame for motor `motor_id` of `model`, every field clamped to its range.
pub fn command_frame(model: &MotorModel, motor_id: u8, cmd: &MitCommand) -> Result<CanFrame, CodecError> {
    match model.family {
        MotorFamily::Robstride => super::robstride::pack_control(model, motor_id, cmd),
        _ => Ok(CanFrame::new8(
            CanId::Standard(u16::from(motor_id)),
            pack_command(model, cmd)?,
        )),
    }
}

/// The frame that enables, disables or zeroes motor `motor_id`; `reply_id` is the host's ID
/// where the protocol names it (Robstride).
pub fn special_frame(model: &MotorModel, motor_id: u8, reply_id: u16, which: SpecialFrame) -> CanFrame {
    match model.family {
        MotorFamily::Robstride => super::robstride::special(which, motor_id, reply_id as u8),
        _ => CanFrame::new8(CanId::Standard(u16::from(motor_id)), which.bytes()),
    }
}

/// What a frame to a motor asks of it (the firmware's side).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum MotorRequest {
    /// An impedance command.
    Command(MitCommand),
    /// Enable, disable or set zero; `clear_faults` for Robstride's stop with data[0] = 1.
    Special {
        /// Which.
        which: SpecialFrame,
        /// The request also clears latched faults.
        clear_faults: bool,
    },
    /// A Robstride request beyond the impedance loop: its type, `data2` and data.
    Other {
        /// Communication type.
        comm: u8,
        /// The identifier's `data2`.
        data2: u16,
    },
}

/// The request in `frame` when it is addressed to motor `motor_id` of `model`; `None` for frames
/// to others and frames the firmware ignores (a wrong length).
pub fn decode_request(model: &MotorModel, motor_id: u8, frame: &CanFrame) -> Option<MotorRequest> {
    match model.family {
        MotorFamily::Robstride => {
            use super::robstride::comm;
            let (kind, data2, target) = super::robstride::split_id(frame.id())?;
            if target != motor_id {
                return None;
            }
            let first = frame.data().first().copied().unwrap_or(0);
            let special = |which, clear_faults| Some(MotorRequest::Special { which, clear_faults });
            match kind {
                comm::CONTROL => super::robstride::unpack_control(model, data2, frame.data())
                    .ok()
                    .map(MotorRequest::Command),
                comm::ENABLE => special(SpecialFrame::Enable, false),
                comm::STOP => special(SpecialFrame::Disable, first == 1),
                comm::SET_ZERO if first == 1 => special(SpecialFrame::SetZero, false),
                _ => Some(MotorRequest::Other { comm: kind, data2 }),
            }
        }
        _ => {
            if frame.id() != CanId::Standard(u16::from(motor_id)) {
                return None;
            }
            match SpecialFrame::parse(frame.data()) {
                Some(which) => Some(MotorRequest::Special {
                    which,
                    clear_faults: false,
                }),
                None => unpack_command(model, frame.data())
                    .ok()
                    .map(MotorRequest::Command),
            }
        }
    }
}

/// The state frame a motor of `model` answers with, on `reply_id` (the host's ID for Robstride).
pub fn reply_frame(model: &MotorModel, reply_id: u16, r: &MitReply) -> CanFrame {
    match model.family {
        MotorFamily::Robstride => super::robstride::pack_feedback(model, reply_id as u8, r),
        _ => {
            let (bytes, len) = pack_reply(model, r);
            let id = CanId::standard(reply_id & 0x7FF).unwrap_or(CanId::Standard(0));
            CanFrame::new(id, &bytes[..len]).unwrap_or_else(|| CanFrame::new8(id, bytes))
        }
    }
}

/// A state frame decoded (the host's side) as a motor of `model` sends it: the ID it names the
/// host by (the reply ID; for Robstride the target byte) and the reply. `None` when it is not
/// one (another layout, a wrong length).
pub fn decode_reply_frame(model: &MotorModel, frame: &CanFrame) -> Option<(u16, MitReply)> {
    match (model.family, frame.id()) {
        (MotorFamily::Robstride, id) => {
            let (_, _, host) = super::robstride::split_id(id)?;
            Some((u16::from(host), super::robstride::unpack_feedback(model, frame)?))
        }
        (_, CanId::Standard(raw)) => Some((raw, unpack_reply(model, frame.data()).ok()?)),
        (_, CanId::Extended(_)) => None,
    }
}

/// Whether reply `r` (decoded as `model`) names motor `motor_id`: DaMiao has room for the ID's
/// low nibble only.
pub fn reply_names(model: &MotorModel, r: &MitReply, motor_id: u8) -> bool {
    match model.family {
        MotorFamily::Damiao => r.motor_id == motor_id & 0x0F,
        _ => r.motor_id == motor_id,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mit::models::{builtin, find};

    #[test]
    fn all_zero_command_on_a_symmetric_range_packs_to_the_known_vector() {
        for model in builtin() {
            let bytes = pack_command(model, &MitCommand::default()).unwrap();
            assert_eq!(
                bytes,
                [0x7F, 0xFF, 0x7F, 0xF0, 0x00, 0x00, 0x07, 0xFF],
                "{}",
                model.name
            );
        }
    }

    #[test]
    fn special_frames_are_the_documented_bytes() {
        assert_eq!(
            SpecialFrame::Enable.bytes(),
            [0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFC]
        );
        assert_eq!(SpecialFrame::Disable.bytes()[7], 0xFD);
        assert_eq!(SpecialFrame::SetZero.bytes()[7], 0xFE);
        for s in [SpecialFrame::Enable, SpecialFrame::Disable, SpecialFrame::SetZero] {
            assert_eq!(SpecialFrame::parse(&s.bytes()), Some(s));
        }
        assert_eq!(SpecialFrame::parse(&[0xFF; 7]), None);
    }

    #[test]
    fn commands_round_trip_within_one_quantum_for_every_model() {
        let mut rng = crate::time::SimRng::new(9);
        for m in builtin() {
            let q = |span: f64, bits: u32| span / f64::from((1u32 << bits) - 1);
            for _ in 0..2000 {
                let u = |rng: &mut crate::time::SimRng, lo: f64, hi: f64| lo + (hi - lo) * rng.next_f64();
                let cmd = MitCommand {
                    p: u(&mut rng, -m.p_max, m.p_max),
                    v: u(&mut rng, -m.v_max, m.v_max),
                    kp: u(&mut rng, 0.0, m.kp_max),
                    kd: u(&mut rng, 0.0, m.kd_max),
                    t: u(&mut rng, -m.t_max, m.t_max),
                };
                let back = unpack_command(m, &pack_command(m, &cmd).unwrap()).unwrap();
                assert!(
                    (back.p - cmd.p).abs() <= q(2.0 * m.p_max, 16),
                    "{} p {cmd:?} {back:?}",
                    m.name
                );
                assert!((back.v - cmd.v).abs() <= q(2.0 * m.v_max, 12), "{} v", m.name);
                assert!((back.kp - cmd.kp).abs() <= q(m.kp_max, 12), "{} kp", m.name);
                assert!((back.kd - cmd.kd).abs() <= q(m.kd_max, 12), "{} kd", m.name);
                assert!((back.t - cmd.t).abs() <= q(2.0 * m.t_max, 12), "{} t", m.name);
            }
        }
    }

    #[test]
    fn out_of_range_fields_are_clamped_and_nan_refused() {
        let m = find("DM-J4310").unwrap();
        let cmd = MitCommand {
            p: 100.0,
            v: -100.0,
            kp: 900.0,
            kd: -1.0,
            t: 50.0,
        };
        assert!(needs_clamp(m, &cmd));
        let back = unpack_command(m, &pack_command(m, &cmd).unwrap()).unwrap();
        assert_eq!(
            (back.p, back.v, back.kp, back.kd, back.t),
            (m.p_max, -m.v_max, m.kp_max, 0.0, m.t_max)
        );
        let nan = MitCommand {
            kd: f64::NAN,
            ..MitCommand::default()
        };
        assert_eq!(pack_command(m, &nan), Err(CodecError::NotFinite { field: "kd" }));
        assert!(unpack_command(m, &[0; 7]).is_err());
    }

    #[test]
    fn replies_round_trip_in_each_family_format() {
        for m in builtin() {
            let r = MitReply {
                motor_id: 5,
                p: 1.25,
                v: -3.0,
                t: 2.5,
                temperature: Some(41.0),
                mos_temperature: Some(37.0),
                fault: MotorFault::OverTemperature,
                enabled: Some(true),
            };
            let reply_id = m.family.default_reply_id(5);
            let frame = reply_frame(m, reply_id, &r);
            let (on, back) = decode_reply_frame(m, &frame).unwrap();
            assert_eq!((on, back.motor_id), (reply_id, 5));
            assert!((back.p - 1.25).abs() < 2.0 * m.p_max / 65535.0);
            assert!((back.v + 3.0).abs() < 2.0 * m.v_max / 4095.0);
            assert!((back.t - 2.5).abs() < 2.0 * m.t_max / 4095.0);
            assert_eq!(back.fault, MotorFault::OverTemperature, "{}", m.name);
            assert_eq!(back.temperature, Some(41.0));
            let short = CanFrame::new(frame.id(), &frame.data()[..frame.data().len() - 1]).unwrap();
            assert!(decode_reply_frame(m, &short).is_none());
        }
    }

    #[test]
    fn reply_byte_layout_matches_the_protocol() {
        // Mini Cheetah layout: id, p[15:8], p[7:0], v[11:4], v[3:0]|i[11:8], i[7:0].
        let m = MotorModel {
            family: MotorFamily::MiniCheetah,
            ..find("AK80-9").unwrap().clone()
        };
        let (bytes, len) = pack_reply(
            &m,
            &MitReply {
                motor_id: 3,
                ..MitReply::default()
            },
        );
        assert_eq!(&bytes[..len], &[0x03, 0x7F, 0xFF, 0x7F, 0xF7, 0xFF]);
    }

    #[test]
    fn random_payloads_never_panic_and_decode_in_range() {
        let mut rng = crate::time::SimRng::new(5);
        for m in builtin() {
            for _ in 0..5000 {
                let len = (rng.next_u64() % 10) as usize;
                let data: Vec<u8> = (0..len).map(|_| rng.next_u64() as u8).collect();
                if let Ok(c) = unpack_command(m, &data) {
                    assert!(c.p.abs() <= m.p_max + 1e-9 && c.kp <= m.kp_max + 1e-9);
                }
                if let Ok(r) = unpack_reply(m, &data) {
                    assert!(r.v.abs() <= m.v_max + 1e-9 && r.t.abs() <= m.t_max + 1e-9);
                }
            }
        }
    }
}
