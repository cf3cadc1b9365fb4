//! Policy manifests: any text through the typed deserializer and every range and cross-check
//! against the reference robot (joint names, rates, terms, scales, clips, action mapping, gains
//! against the motors). The same text as a motion generator's description: what is accepted is
//! within its documented ranges. The manifest's path points nowhere, so a manifest that leaves fields to the
//! ONNX file's metadata is refused for the missing file rather than loading a model per input.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| fuzz_targets::policy_toml::run(data));
