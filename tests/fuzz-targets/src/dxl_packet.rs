//! Dynamixel Protocol 2.0, both sides: any byte stream through the streaming decoder, and every
//! packet it finds handed to an emulated XM430 servo as an instruction.

use firmware_bridge::dxl::packet::{Decoded, decode};
use firmware_bridge::dxl::servo::{ServoConfig, XSeriesServo};
use firmware_bridge::time::SimInstant;

/// One input.
pub fn run(data: &[u8]) {
    let model = firmware_bridge::dxl::models::find("XM430-W350").expect("built-in model");
    let mut servo = XSeriesServo::new(model, ServoConfig::new(1));
    let mut scratch = [0u8; 1024];
    let mut input = data;
    while !input.is_empty() {
        let used = match decode(input, &mut scratch) {
            Decoded::Packet(packet, used) => {
                let _ = servo.handle(&packet, SimInstant::ZERO);
                used
            }
            Decoded::Incomplete { skip } => {
                if skip == 0 {
                    break;
                }
                skip
            }
            Decoded::Invalid(_, _, skip) => skip.max(1),
        };
        input = &input[used.min(input.len())..];
    }
}
