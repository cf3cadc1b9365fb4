//! MIT-mode CAN frames: any 0–8 data bytes as a command and as a reply, for every motor model, and
//! as a special frame.
#![no_main]

use firmware_bridge::mit::codec::{SpecialFrame, unpack_command, unpack_reply};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let data = &data[..data.len().min(8)];
    for model in firmware_bridge::mit::models::builtin() {
        let _ = unpack_command(model, data);
        let _ = unpack_reply(model, data);
    }
    let _ = SpecialFrame::parse(data);
});
