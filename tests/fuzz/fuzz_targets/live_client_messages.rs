//! What a viewer may send the live server (subprotocol, text and binary frames, pings, close):
//! whatever it sent, the next well-behaved viewer gets the server's info, the channel and its
//! messages.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| fuzz_targets::live_client_messages::run(data));
