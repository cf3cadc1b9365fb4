//! 2D keypoint inputs: any text as a camera file, as the project's keypoint CSV (checked against
//! the shipped cameras, then resampled to a run's ticks) and as a pose estimator's COCO JSON (by
//! person and without). Whatever is
//! accepted is whole: every frame has every view's keypoints, confidences within [0, 1], and every
//! keypoint seen lies on its camera's image.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| fuzz_targets::keypoint_inputs::run(data));
