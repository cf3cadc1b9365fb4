//! ONNX metadata as training frameworks export it (one `key<TAB>value` per line; the first byte
//! says whether the model has a `time_step` input): the typed readers and the contract they
//! fill, then — when the metadata filled the whole manifest — every range and cross-check of the
//! manifest against the reference robot, as `play --policy export.onnx` runs them.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| fuzz_targets::onnx_metadata::run(data));
