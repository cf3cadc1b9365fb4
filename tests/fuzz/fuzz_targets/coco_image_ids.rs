//! COCO results lists whose image ids the fuzzer chooses (numbers, and names with the number
//! inside: "cam2_frame_0012.jpg", leading zeros, several digit runs, huge numbers), the rest
//! well-formed. Whatever is accepted is timed by the ids' numbers: one frame per number from the
//! first to the last, at 1/fps apart, each id's detection in its own frame and every gap unseen.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| fuzz_targets::coco_image_ids::run(data));
