//! rd-biped with its left leg on Robstride motors, for the test files that run it.

/// rd-biped's file with the six motors of can0 (the left leg) swapped for Robstrides of the same
/// class in their factory protocol; the right leg stays on MIT mode.
pub fn left_leg_on_robstride(text: &str) -> String {
    text.split("[[joints]]")
        .map(|block| {
            if block.contains("bus = \"can0\"") {
                block
                    .replace("model = \"AK80-9\"", "model = \"RS02\"")
                    .replace("model = \"AK10-9\"", "model = \"RS03\"")
                    .replace("model = \"DM-J4340\"", "model = \"RS03\"")
                    .replace("model = \"DM-J4310\"", "model = \"RS00\"")
            } else {
                block.to_owned()
            }
        })
        .collect::<Vec<_>>()
        .join("[[joints]]")
}
