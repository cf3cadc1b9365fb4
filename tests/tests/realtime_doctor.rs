//! `doctor --realtime` on machines described by their `/proc` and `/sys` (`--root`): a stock kernel
//! on a laptop-like board with nothing set up, and a prepared robot computer. Every item gets its
//! verdict and, where it falls short, its fix; nothing under the root is changed.

use std::path::Path;

use test_support::bin::run;

/// Writes `files` (path, contents) under `root`.
fn machine(root: &Path, files: &[(&str, &str)]) {
    for (path, text) in files {
        let p = root.join(path);
        std::fs::create_dir_all(p.parent().unwrap()).unwrap();
        std::fs::write(p, text).unwrap();
    }
}

/// Every file under `root` with its contents and modification time.
fn snapshot(root: &Path) -> Vec<(String, Vec<u8>, std::time::SystemTime)> {
    let mut out = Vec::new();
    let mut stack = vec![root.to_path_buf()];
    while let Some(dir) = stack.pop() {
        for e in std::fs::read_dir(&dir).unwrap().flatten() {
            let p = e.path();
            if p.is_dir() {
                stack.push(p);
            } else {
                let m = std::fs::metadata(&p).unwrap().modified().unwrap();
                out.push((p.display().to_string(), std::fs::read(&p).unwrap(), m));
            }
        }
    }
    out.sort();
    out
}

/// The line of `item` in the report: its verdict and what was found, and the fix line after it.
fn item<'a>(out: &'a str, name: &str) -> (&'a str, Option<&'a str>) {
    let mut lines = out.lines().skip_while(|l| !l.trim_start().starts_with(name));
    let line = lines.next().unwrap_or_else(|| panic!("no {name} in:\n{out}"));
    let fix = lines.next().filter(|l| l.trim_start().starts_with("fix:"));
    (line, fix)
}

#[test]
fn a_stock_machine_gets_each_shortfall_named_with_its_fix_and_nothing_is_changed() {
    let root = std::env::temp_dir().join(format!("rt-stock-{}", std::process::id()));
    machine(
        &root,
        &[
            (
                "proc/version",
                "Linux version 6.1.0-18-arm64 (debian-kernel@lists.debian.org) #1 SMP Debian 6.1.76-1\n",
            ),
            (
                "proc/self/limits",
                "Limit                     Soft Limit           Hard Limit           Units\n\
                 Max locked memory         65536                65536                bytes\n\
                 Max realtime priority     0                    0\n",
            ),
            (
                "proc/self/status",
                "Name:\trobodeploy\nUid:\t1000\t1000\t1000\t1000\n",
            ),
            ("proc/cmdline", "console=ttyS0 root=/dev/mmcblk0p2\n"),
            (
                "sys/devices/system/cpu/cpu0/cpufreq/scaling_governor",
                "powersave\n",
            ),
            (
                "sys/devices/system/cpu/cpu1/cpufreq/scaling_governor",
                "ondemand\n",
            ),
            ("sys/devices/system/cpu/isolated", "\n"),
            ("sys/bus/usb-serial/devices/ttyUSB0/latency_timer", "16\n"),
            ("sys/class/net/can0/type", "280\n"),
            ("sys/class/net/can0/operstate", "down\n"),
            ("sys/class/net/eth0/type", "1\n"),
        ],
    );
    let before = snapshot(&root);
    let (ok, out, err) = run(&["doctor", "--realtime", "--root", root.to_str().unwrap()]);
    assert!(!ok, "{out}");
    assert!(err.contains("7 item(s) fall short"), "{out}{err}");
    for (name, found, fix) in [
        ("kernel", "6.1.0-18-arm64 (not PREEMPT_RT)", "PREEMPT_RT kernel"),
        ("SCHED_FIFO", "realtime priority limit 0", "rtprio 95"),
        (
            "memory locking",
            "locked memory limit 64 KiB",
            "memlock unlimited",
        ),
        (
            "CPU governor",
            "cpu0 powersave, cpu1 ondemand",
            "frequency-set -g performance",
        ),
        ("isolated cores", "no isolated CPU", "isolcpus="),
        ("serial latency", "ttyUSB0 16 ms", "latency_timer"),
        ("SocketCAN", "can0 down", "ip link set <can> up type can bitrate"),
    ] {
        let (line, fix_line) = item(&out, name);
        assert!(line.contains("SHORT") && line.contains(found), "{name}: {line}");
        assert!(
            fix_line.is_some_and(|f| f.contains(fix)),
            "{name}: {fix_line:?}\n{out}"
        );
    }
    // Read, never written: contents and times as they were.
    assert_eq!(snapshot(&root), before);
    std::fs::remove_dir_all(&root).unwrap();
}

#[test]
fn a_prepared_robot_computer_passes_every_item() {
    let root = std::env::temp_dir().join(format!("rt-ready-{}", std::process::id()));
    machine(
        &root,
        &[
            (
                "proc/version",
                "Linux version 6.1.0-18-rt-arm64 #1 SMP PREEMPT_RT Debian 6.1.76-1\n",
            ),
            ("sys/kernel/realtime", "1\n"),
            (
                "proc/self/limits",
                "Max locked memory         unlimited            unlimited            bytes\n\
                 Max realtime priority     95                   95\n",
            ),
            ("proc/self/status", "Uid:\t1000\t1000\t1000\t1000\n"),
            ("proc/cmdline", "isolcpus=3 nohz_full=3 rcu_nocbs=3\n"),
            (
                "sys/devices/system/cpu/cpu0/cpufreq/scaling_governor",
                "performance\n",
            ),
            (
                "sys/devices/system/cpu/cpu3/cpufreq/scaling_governor",
                "performance\n",
            ),
            ("sys/devices/system/cpu/isolated", "3\n"),
            ("sys/bus/usb-serial/devices/ttyUSB0/latency_timer", "1\n"),
            ("sys/class/net/can0/type", "280\n"),
            ("sys/class/net/can0/operstate", "up\n"),
        ],
    );
    let (ok, out, err) = run(&["doctor", "--realtime", "--root", root.to_str().unwrap()]);
    assert!(ok, "{out}{err}");
    assert!(out.contains("every item as the real-time loop wants it"), "{out}");
    assert!(
        item(&out, "isolated cores")
            .0
            .contains("isolated CPUs 3, nohz_full=3"),
        "{out}"
    );
    assert!(!out.contains("fix:"), "{out}");
    std::fs::remove_dir_all(&root).unwrap();
}

/// A captured root with traps in it — a FIFO where a file should be (opening it for reading waits
/// for a writer forever), a link to `/dev/zero` (reads forever): each is skipped, the report
/// comes back at once, and the items they stood for are judged as unknown.
#[test]
fn fifos_and_endless_devices_under_the_root_are_skipped_not_read_forever() {
    let root = std::env::temp_dir().join(format!("rt-traps-{}", std::process::id()));
    machine(
        &root,
        &[(
            "proc/self/limits",
            "Max locked memory         unlimited            unlimited            bytes\n",
        )],
    );
    let fifo = root.join("proc/cmdline");
    let made = std::process::Command::new("mkfifo").arg(&fifo).status().unwrap();
    assert!(made.success());
    let governor = root.join("sys/devices/system/cpu/cpu0/cpufreq/scaling_governor");
    std::fs::create_dir_all(governor.parent().unwrap()).unwrap();
    std::os::unix::fs::symlink("/dev/zero", &governor).unwrap();
    std::os::unix::fs::symlink("/dev/zero", root.join("proc/version")).unwrap();
    let (code, out, err) = test_support::bin::run_within(
        &["doctor", "--realtime", "--root", root.to_str().unwrap()],
        std::time::Duration::from_secs(60),
    );
    assert!(code.is_some(), "{out}{err}");
    assert!(!err.contains("panicked"), "{err}");
    assert!(out.contains("CPU governor"), "{out}");
    std::fs::remove_dir_all(&root).unwrap();
}

/// Limits that are no numbers are unknown, not "unlimited"; a `--root` that is not there is a bad
/// flag, not a machine with nothing in it.
#[test]
fn garbled_limits_are_unknown_and_a_missing_root_is_refused() {
    let root = std::env::temp_dir().join(format!("rt-garbled-{}", std::process::id()));
    machine(
        &root,
        &[(
            "proc/self/limits",
            "Max locked memory         lots                 lots                 bytes\n\
             Max realtime priority     -\n",
        )],
    );
    // Unknown items are not a pass: the doctor exits 1, as for any shortfall.
    let (ok, out, err) = run(&["doctor", "--realtime", "--root", root.to_str().unwrap()]);
    assert!(!ok && !err.contains("panicked"), "{out}{err}");
    let (memlock, _) = item(&out, "memory locking");
    assert!(
        memlock.contains("\"Max locked memory\" reads \"lots\", not a number")
            && !memlock.contains("unlimited"),
        "{out}"
    );
    let (rtprio, _) = item(&out, "SCHED_FIFO");
    assert!(rtprio.contains("not a number"), "{out}");
    std::fs::remove_dir_all(&root).unwrap();

    let (code, out, err) = test_support::bin::run_within(
        &["doctor", "--realtime", "--root", "/nonexistent/robot-computer"],
        std::time::Duration::from_secs(60),
    );
    assert_eq!(code, Some(2), "{out}{err}");
    assert!(
        err.contains("--root /nonexistent/robot-computer: no such directory"),
        "{err}"
    );
    assert!(!out.contains("SCHED_FIFO"), "{out}");
}
