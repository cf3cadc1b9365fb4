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

/// Runs the project's Python `script` (a path in the checkout) with `args` in a network of its
/// own, from the checkout; returns the last line it printed (the script's verdict).
///
/// # Panics
/// When it fails, with everything it printed.
pub fn python_verdict(script: &str, args: &[String]) -> String {
    let root = crate::fixtures::workspace_root();
    let mut line = format!(
        "{} {}",
        crate::fixtures::venv_python().display(),
        root.join(script).display()
    );
    for a in args {
        line.push(' ');
        line.push_str(a);
    }
    let out = in_private_network(&line).current_dir(&root).output().unwrap();
    let (stdout, stderr) = (
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr),
    );
    assert!(out.status.success(), "{script}: {stdout}\n{stderr}");
    stdout
        .lines()
        .last()
        .unwrap_or_else(|| panic!("{script} printed nothing:\n{stderr}"))
        .to_owned()
}
