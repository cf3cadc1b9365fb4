//! A network of a test's own: a new network namespace with only the loopback interface, up and
//! with multicast on (DDS discovery), so whatever the test's processes open or send stays inside.

use std::process::Command;

/// `script` (bash) in a new network namespace with only loopback up: unprivileged (a user
/// namespace) where the kernel allows it, else as root.
///
/// # Panics
/// When the kernel refuses both.
pub fn in_private_network(script: &str) -> Command {
    let works = |flag: &str| {
        Command::new("unshare")
            .args([flag, "true"])
            .status()
            .is_ok_and(|s| s.success())
    };
    let flag = ["-rn", "-n"].into_iter().find(|f| works(f)).unwrap_or_else(|| {
        panic!("this test needs a network namespace of its own (unshare -rn or -n): the kernel refused both")
    });
    let mut c = Command::new("unshare");
    c.args([
        flag,
        "bash",
        "-c",
        &format!("ip link set lo up && ip link set lo multicast on && {script}"),
    ]);
    c
}
