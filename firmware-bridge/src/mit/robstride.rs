//! Robstride motors in their factory protocol (CAN 2.0B, 1 Mbit/s): the frame layout shared by the
//! host driver and the emulated firmware.
//!
//! Every frame has a 29-bit ID `comm_type << 24 | data2 << 8 | target`: `target` is the motor's
//! CAN ID on frames to a motor and the host's on frames from one; `data2` (16 bits) depends on
//! the type. Types: 0 get ID, 1 control, 2 feedback, 3 enable, 4 stop, 6 set zero, 7 set CAN ID,
//! 0x11 read parameter, 0x12 write parameter, 0x15 fault report.
//!
//! - Control (1): `data2` = feed-forward torque as u16; data = big-endian u16 angle, velocity, kp,
//!   kd, each mapped linearly onto 0…65535 over the model's range (angle ±4π).
//! - Feedback (2): `data2` = motor ID (bits 8–15 of the ID), fault bits (16 undervoltage,
//!   17 overcurrent, 18 overtemperature, 19 magnetic encoder, 20 hall encoder, 21 uncalibrated)
//!   and mode (bits 22–23: 0 reset, 1 calibration, 2 run); data = big-endian u16 angle,
//!   velocity, torque, and temperature × 10 (°C).
//! - Enable (3), stop (4, data[0] = 1 also clears faults), set zero (6, data[0] = 1): `data2` =
//!   host ID; each is answered with a feedback frame.
//! - Parameters (0x11 read, 0x12 write): `data2` = host ID; index u16 little-endian in bytes 0–1,
//!   value little-endian in bytes 4–7. A read is answered on type 0x11 (`data2` = motor ID, and
//!   bit 16 set when the index is not readable); a write with a feedback frame.
//! - Get ID (0): answered on type 0 with `data2` = motor ID, target 0xFE, data = the MCU's
//!   64-bit unique ID.

use super::codec::{
    CodecError, MitCommand, MitReply, MotorFault, SpecialFrame, float_to_uint, uint_to_float,
};
use super::models::MotorModel;
use crate::can::{CanFrame, CanId};

/// Communication types (bits 24–28 of the ID).
pub mod comm {
    /// Get the device ID.
    pub const GET_ID: u8 = 0x00;
    /// Operation-control command.
    pub const CONTROL: u8 = 0x01;
    /// State feedback.
    pub const FEEDBACK: u8 = 0x02;
    /// Enable (run).
    pub const ENABLE: u8 = 0x03;
    /// Stop (reset mode).
    pub const STOP: u8 = 0x04;
    /// Set the mechanical zero.
    pub const SET_ZERO: u8 = 0x06;
    /// Set the CAN ID.
    pub const SET_CAN_ID: u8 = 0x07;
    /// Read one parameter.
    pub const READ_PARAM: u8 = 0x11;
    /// Write one parameter (not saved).
    pub const WRITE_PARAM: u8 = 0x12;
    /// Fault report.
    pub const FAULT_REPORT: u8 = 0x15;
}

/// Fault bits of a feedback frame's `data2` high byte (ID bits 16–21).
pub mod fault_bit {
    /// Undervoltage.
    pub const UNDERVOLTAGE: u8 = 1 << 0;
    /// Overcurrent.
    pub const OVERCURRENT: u8 = 1 << 1;
    /// Overtemperature.
    pub const OVERTEMPERATURE: u8 = 1 << 2;
    /// Magnetic encoder fault.
    pub const MAGNETIC_ENCODER: u8 = 1 << 3;
    /// Hall encoder fault.
    pub const HALL_ENCODER: u8 = 1 << 4;
    /// Not calibrated.
    pub const UNCALIBRATED: u8 = 1 << 5;
}

/// Mode states of a feedback frame (ID bits 22–23).
pub mod mode {
    /// Reset: torque off.
    pub const RESET: u8 = 0;
    /// Calibrating.
    pub const CALIBRATION: u8 = 1;
    /// Running: torque on.
    pub const RUN: u8 = 2;
}

/// Parameter indices the emulated firmware and the driver use (the motor's parameter table).
pub mod param {
    /// Control mode: 0 operation control (the impedance law), 1 position, 2 velocity, 3 current.
    pub const RUN_MODE: u16 = 0x7005;
    /// Torque limit, N·m (f32).
    pub const LIMIT_TORQUE: u16 = 0x700B;
    /// Mechanical position, rad (f32, read-only).
    pub const MECH_POS: u16 = 0x7019;
    /// Filtered q-axis current, A (f32, read-only).
    pub const IQF: u16 = 0x701A;
    /// Mechanical velocity, rad/s (f32, read-only).
    pub const MECH_VEL: u16 = 0x701B;
    /// Bus voltage, V (f32, read-only).
    pub const VBUS: u16 = 0x701C;
}

/// The host CAN ID the factory tools use; robot.toml's `reply_id` may set another.
pub const DEFAULT_HOST_ID: u8 = 0xFD;

/// The 29-bit identifier of a frame of type `comm` with `data2` to `target`.
pub const fn frame_id(comm: u8, data2: u16, target: u8) -> CanId {
    CanId::Extended(((comm as u32 & 0x1F) << 24) | ((data2 as u32) << 8) | target as u32)
}

/// An identifier's type, `data2` and target, or `None` for a standard (11-bit) one.
pub const fn split_id(id: CanId) -> Option<(u8, u16, u8)> {
    match id {
        CanId::Extended(raw) => Some(((raw >> 24) as u8 & 0x1F, (raw >> 8) as u16, raw as u8)),
        CanId::Standard(_) => None,
    }
}

fn be(d: &[u8], at: usize) -> u16 {
    u16::from_be_bytes([d[at], d[at + 1]])
}

/// A control frame to `motor_id`, every field clamped to `model`'s range. Refuses NaN.
pub fn pack_control(model: &MotorModel, motor_id: u8, cmd: &MitCommand) -> Result<CanFrame, CodecError> {
    super::codec::check_finite(cmd)?;
    let t = float_to_uint(cmd.t, -model.t_max, model.t_max, 16);
    let mut data = [0u8; 8];
    for (k, u) in [
        float_to_uint(cmd.p, -model.p_max, model.p_max, 16),
        float_to_uint(cmd.v, -model.v_max, model.v_max, 16),
        float_to_uint(cmd.kp, 0.0, model.kp_max, 16),
        float_to_uint(cmd.kd, 0.0, model.kd_max, 16),
    ]
    .into_iter()
    .enumerate()
    {
        data[2 * k..2 * k + 2].copy_from_slice(&u.to_be_bytes());
    }
    Ok(CanFrame::new8(frame_id(comm::CONTROL, t, motor_id), data))
}

/// The command in a control frame (the firmware's side).
pub fn unpack_control(model: &MotorModel, data2: u16, data: &[u8]) -> Result<MitCommand, CodecError> {
    if data.len() != 8 {
        return Err(CodecError::WrongLength {
            expected: 8,
            actual: data.len(),
        });
    }
    Ok(MitCommand {
        p: uint_to_float(be(data, 0), -model.p_max, model.p_max, 16),
        v: uint_to_float(be(data, 2), -model.v_max, model.v_max, 16),
        kp: uint_to_float(be(data, 4), 0.0, model.kp_max, 16),
        kd: uint_to_float(be(data, 6), 0.0, model.kd_max, 16),
        t: uint_to_float(data2, -model.t_max, model.t_max, 16),
    })
}

/// The frame for `which` from host `host_id` to `motor_id`.
pub const fn special(which: SpecialFrame, motor_id: u8, host_id: u8) -> CanFrame {
    let (comm, first) = match which {
        SpecialFrame::Enable => (comm::ENABLE, 0),
        SpecialFrame::Disable => (comm::STOP, 0),
        SpecialFrame::SetZero => (comm::SET_ZERO, 1),
    };
    CanFrame::new8(
        frame_id(comm, host_id as u16, motor_id),
        [first, 0, 0, 0, 0, 0, 0, 0],
    )
}

/// The fault bits for `fault`.
pub const fn fault_bits(fault: MotorFault) -> u8 {
    match fault {
        MotorFault::None | MotorFault::CommunicationLost => 0,
        MotorFault::UnderVoltage => fault_bit::UNDERVOLTAGE,
        MotorFault::OverCurrent | MotorFault::Overload | MotorFault::Stall => fault_bit::OVERCURRENT,
        MotorFault::OverTemperature | MotorFault::MosOverTemperature => fault_bit::OVERTEMPERATURE,
        MotorFault::Encoder => fault_bit::MAGNETIC_ENCODER,
        MotorFault::Uncalibrated => fault_bit::UNCALIBRATED,
        MotorFault::OverVoltage | MotorFault::Unknown(_) => fault_bit::OVERCURRENT,
    }
}

/// The fault the bits report (the first set, in bit order).
pub const fn fault_of(bits: u8) -> MotorFault {
    if bits & fault_bit::UNDERVOLTAGE != 0 {
        MotorFault::UnderVoltage
    } else if bits & fault_bit::OVERCURRENT != 0 {
        MotorFault::OverCurrent
    } else if bits & fault_bit::OVERTEMPERATURE != 0 {
        MotorFault::OverTemperature
    } else if bits & (fault_bit::MAGNETIC_ENCODER | fault_bit::HALL_ENCODER) != 0 {
        MotorFault::Encoder
    } else if bits & fault_bit::UNCALIBRATED != 0 {
        MotorFault::Uncalibrated
    } else if bits != 0 {
        MotorFault::Unknown(bits)
    } else {
        MotorFault::None
    }
}

/// A feedback frame from `r.motor_id` to `host_id` (the firmware's side).
pub fn pack_feedback(model: &MotorModel, host_id: u8, r: &MitReply) -> CanFrame {
    let mode = if r.enabled == Some(true) {
        mode::RUN
    } else {
        mode::RESET
    };
    let data2 = u16::from(r.motor_id) | u16::from(fault_bits(r.fault) | mode << 6) << 8;
    let temperature = (r.temperature.unwrap_or(0.0) * 10.0).round().clamp(0.0, 65535.0) as u16;
    let mut data = [0u8; 8];
    for (k, u) in [
        float_to_uint(r.p, -model.p_max, model.p_max, 16),
        float_to_uint(r.v, -model.v_max, model.v_max, 16),
        float_to_uint(r.t, -model.t_max, model.t_max, 16),
        temperature,
    ]
    .into_iter()
    .enumerate()
    {
        data[2 * k..2 * k + 2].copy_from_slice(&u.to_be_bytes());
    }
    CanFrame::new8(frame_id(comm::FEEDBACK, data2, host_id), data)
}

/// A feedback frame decoded (the host's side): `None` when `frame` is not a feedback frame of
/// eight bytes.
pub fn unpack_feedback(model: &MotorModel, frame: &CanFrame) -> Option<MitReply> {
    let (comm, data2, _) = split_id(frame.id())?;
    let d = frame.data();
    if comm != comm::FEEDBACK || d.len() != 8 {
        return None;
    }
    let status = (data2 >> 8) as u8;
    Some(MitReply {
        motor_id: data2 as u8,
        p: uint_to_float(be(d, 0), -model.p_max, model.p_max, 16),
        v: uint_to_float(be(d, 2), -model.v_max, model.v_max, 16),
        t: uint_to_float(be(d, 4), -model.t_max, model.t_max, 16),
        temperature: Some(f64::from(be(d, 6)) / 10.0),
        mos_temperature: None,
        fault: fault_of(status & 0x3F),
        enabled: Some(status >> 6 == mode::RUN),
    })
}

/// A parameter read request.
pub const fn read_param(motor_id: u8, host_id: u8, index: u16) -> CanFrame {
    let i = index.to_le_bytes();
    CanFrame::new8(
        frame_id(comm::READ_PARAM, host_id as u16, motor_id),
        [i[0], i[1], 0, 0, 0, 0, 0, 0],
    )
}

/// A parameter write request with a 4-byte little-endian value.
pub const fn write_param(motor_id: u8, host_id: u8, index: u16, value: [u8; 4]) -> CanFrame {
    let i = index.to_le_bytes();
    CanFrame::new8(
        frame_id(comm::WRITE_PARAM, host_id as u16, motor_id),
        [i[0], i[1], 0, 0, value[0], value[1], value[2], value[3]],
    )
}

/// The index and value of a parameter frame (request or answer).
pub fn param_of(data: &[u8]) -> Option<(u16, [u8; 4])> {
    (data.len() == 8).then(|| {
        (
            u16::from_le_bytes([data[0], data[1]]),
            [data[4], data[5], data[6], data[7]],
        )
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mit::models::find;

    #[test]
    fn a_control_frame_is_laid_out_as_the_protocol_says() {
        let rs03 = find("RS03").unwrap();
        // Mid-range everywhere but kp at full scale; torque +60 N·m is 65535 in data2.
        let f = pack_control(
            rs03,
            0x7F,
            &MitCommand {
                p: 0.0,
                v: 0.0,
                kp: 5000.0,
                kd: 0.0,
                t: 60.0,
            },
        )
        .unwrap();
        assert_eq!(f.id(), CanId::Extended(0x01FF_FF7F));
        assert_eq!(f.data(), &[0x7F, 0xFF, 0x7F, 0xFF, 0xFF, 0xFF, 0x00, 0x00]);
        let back = unpack_control(rs03, 0xFFFF, f.data()).unwrap();
        assert!((back.kp - 5000.0).abs() < 1e-9 && (back.t - 60.0).abs() < 1e-9);
        assert!(back.p.abs() < 4.0 * std::f64::consts::PI / 65535.0 * 2.0);
        assert!(
            pack_control(
                rs03,
                1,
                &MitCommand {
                    p: f64::NAN,
                    ..MitCommand::default()
                }
            )
            .is_err()
        );
    }

    #[test]
    fn feedback_carries_id_faults_and_mode_in_its_identifier() {
        let rs01 = find("RS01").unwrap();
        let r = MitReply {
            motor_id: 5,
            p: 1.0,
            v: -2.0,
            t: 3.0,
            temperature: Some(31.4),
            mos_temperature: None,
            fault: MotorFault::OverTemperature,
            enabled: Some(true),
        };
        let f = pack_feedback(rs01, DEFAULT_HOST_ID, &r);
        // Type 2, mode run (2 << 22), overtemperature (bit 18), motor 5, host 0xFD.
        assert_eq!(
            f.id(),
            CanId::Extended(0x0200_0000 | 2 << 22 | 1 << 18 | 5 << 8 | 0xFD)
        );
        assert_eq!(&f.data()[6..], &314u16.to_be_bytes());
        let back = unpack_feedback(rs01, &f).unwrap();
        assert_eq!(
            (back.motor_id, back.fault, back.enabled),
            (5, MotorFault::OverTemperature, Some(true))
        );
        assert!((back.p - 1.0).abs() < 1e-3 && (back.v + 2.0).abs() < 2e-3 && (back.t - 3.0).abs() < 1e-3);
        assert_eq!(back.temperature, Some(31.4));
        assert_eq!(fault_of(fault_bit::UNCALIBRATED), MotorFault::Uncalibrated);
        assert_eq!(fault_of(fault_bit::HALL_ENCODER), MotorFault::Encoder);
    }

    #[test]
    fn special_and_parameter_frames_name_the_host_and_the_index() {
        let f = special(SpecialFrame::Enable, 3, 0xFD);
        assert_eq!((f.id(), f.data()), (CanId::Extended(0x0300_FD03), &[0u8; 8][..]));
        let f = special(SpecialFrame::SetZero, 3, 0xFD);
        assert_eq!((f.id(), f.data()[0]), (CanId::Extended(0x0600_FD03), 1));
        let f = write_param(3, 0xFD, param::LIMIT_TORQUE, 12.5f32.to_le_bytes());
        assert_eq!(f.id(), CanId::Extended(0x1200_FD03));
        assert_eq!(f.data(), &[0x0B, 0x70, 0, 0, 0x00, 0x00, 0x48, 0x41]);
        assert_eq!(param_of(f.data()), Some((0x700B, 12.5f32.to_le_bytes())));
        assert_eq!(
            split_id(read_param(3, 0xFD, param::VBUS).id()),
            Some((0x11, 0xFD, 3))
        );
    }
}
