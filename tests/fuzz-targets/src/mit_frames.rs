//! Motor frames on CAN, MIT mode and Robstride's factory protocol: the first four bytes as an
//! identifier (11- or 29-bit by its top bit), up to 8 more as data, taken by every motor model as
//! a request (the firmware's side) and as a reply (the host's side). Decoded values stay inside
//! the model's ranges; an emulated motor answers only with frames its host decodes.

use firmware_bridge::can::{CanFrame, CanId};
use firmware_bridge::mit::codec::{MotorRequest, SpecialFrame, decode_reply_frame, decode_request};
use firmware_bridge::mit::firmware::{MitFirmwareConfig, MitMotorFirmware};
use firmware_bridge::plant::InertiaPlant;
use firmware_bridge::time::SimInstant;

/// One input.
pub fn run(bytes: &[u8]) {
    if bytes.len() < 4 {
        return;
    }
    let raw = u32::from_le_bytes([bytes[0], bytes[1], bytes[2], bytes[3]]);
    let id = if raw & 0x8000_0000 != 0 {
        CanId::Extended(raw & 0x1FFF_FFFF)
    } else {
        CanId::Standard((raw & 0x7FF) as u16)
    };
    let data = &bytes[4..bytes.len().min(12)];
    let Some(frame) = CanFrame::new(id, data) else {
        return;
    };
    let _ = SpecialFrame::parse(data);
    let plant = InertiaPlant::new(0.01, 0.05, 0.0, 0.0);
    for model in firmware_bridge::mit::models::builtin() {
        let motor = (raw & 0x7F) as u8;
        if let Some(MotorRequest::Command(c)) = decode_request(model, motor, &frame) {
            assert!(c.p.abs() <= model.p_max + 1e-9 && c.kp <= model.kp_max + 1e-9);
        }
        if let Some((_, r)) = decode_reply_frame(model, &frame) {
            assert!(r.v.abs() <= model.v_max + 1e-9 && r.t.abs() <= model.t_max + 1e-9);
        }
        let mut fw = MitMotorFirmware::new(MitFirmwareConfig::new(motor, model));
        if let Some(answer) = fw.on_frame(SimInstant::ZERO, &frame, &plant) {
            // State answers decode on the host; Robstride's get-ID and parameter answers are
            // their own types.
            let other = matches!(
                firmware_bridge::mit::robstride::split_id(answer.id()),
                Some((0x00 | 0x11, _, _))
            );
            assert!(
                other || decode_reply_frame(model, &answer).is_some(),
                "{answer:?}"
            );
        }
    }
}
