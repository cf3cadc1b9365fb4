//! rd-mini on Feetech servos, for the test files that run it.

/// rd-mini's file with every servo swapped for a Feetech STS3215 (12 V) on a 1 Mbit/s line, its
/// speed and torque limits brought within the servo's.
pub fn on_feetech(text: &str) -> String {
    let mut s = text
        .replace("kind = \"dynamixel\"", "kind = \"feetech\"")
        .replace("rate = 4000000", "rate = 1000000")
        .replace("fast_reads = true\n", "")
        .replace("velocity_limit = 6.0", "velocity_limit = 4.5")
        .replace("torque_limit = 3.5", "torque_limit = 2.9");
    for m in ["XL430-W250", "XM430-W350"] {
        s = s.replace(&format!("model = \"{m}\""), "model = \"STS3215-12V\"");
    }
    s
}
